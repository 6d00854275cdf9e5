//! Expressions of an OpenSim 4.6 `ExpressionBasedBushingForce`: the subset of
//! Lepton's syntax that bushing expressions use, parsed once into a tree and
//! evaluated generically over the solver's scalar (so dual numbers give exact
//! tangents).
//!
//! Syntax (as Lepton reads it; whitespace is ignored, as OpenSim strips it):
//! numbers (`2`, `0.5`, `1.5e-3`, `2E2`); the deflection variables
//! `theta_x theta_y theta_z delta_x delta_y delta_z`; binary `+ - * / ^`
//! (`^` binds tighter than `*` `/`, which bind tighter than `+` `-`; `^` is
//! right-associative); unary minus (binding looser than `^`: `-x^2` is
//! `-(x^2)`); parentheses; and the functions `sqrt exp log sin cos tan asin
//! acos atan sinh cosh tanh abs square cube recip step` (one argument) and
//! `min max atan2` (two). `step(x)` is 1 for x >= 0, else 0 (Lepton's
//! definition). Anything else is a parse error naming the position.

use super::scalar::Scalar;
use std::fmt;

/// Index of a deflection variable in `(theta_x, theta_y, theta_z, delta_x, delta_y, delta_z)`.
pub const VARIABLES: [&str; 6] = [
    "theta_x", "theta_y", "theta_z", "delta_x", "delta_y", "delta_z",
];

/// One-argument functions.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fn1 {
    /// `sqrt(x)`.
    Sqrt,
    /// `exp(x)`.
    Exp,
    /// `log(x)`: the natural logarithm.
    Log,
    /// `sin(x)` (x in rad).
    Sin,
    /// `cos(x)` (x in rad).
    Cos,
    /// `tan(x)` (x in rad).
    Tan,
    /// `asin(x)`, in rad.
    Asin,
    /// `acos(x)`, in rad.
    Acos,
    /// `atan(x)`, in rad.
    Atan,
    /// `sinh(x)`.
    Sinh,
    /// `cosh(x)`.
    Cosh,
    /// `tanh(x)`.
    Tanh,
    /// `abs(x)`.
    Abs,
    /// `square(x)` = x^2.
    Square,
    /// `cube(x)` = x^3.
    Cube,
    /// `recip(x)` = 1/x.
    Recip,
    /// `step(x)`: 1 for x >= 0, else 0.
    Step,
}

/// Two-argument functions.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fn2 {
    /// `min(a, b)`.
    Min,
    /// `max(a, b)`.
    Max,
    /// `atan2(y, x)`: the angle of (x, y), in rad.
    Atan2,
}

/// Binary operators.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Op {
    /// `a + b`.
    Add,
    /// `a - b`.
    Sub,
    /// `a * b`.
    Mul,
    /// `a / b`.
    Div,
    /// `a ^ b`: a raised to the power b.
    Pow,
}

/// A parsed expression.
#[derive(Debug, Clone, PartialEq)]
pub enum Expr {
    /// A numeric literal.
    Num(f64),
    /// Deflection variable by index (see [`VARIABLES`]).
    Var(usize),
    /// Unary minus of the operand.
    Neg(Box<Expr>),
    /// A binary operation on two operands (left, right).
    Bin(Op, Box<Expr>, Box<Expr>),
    /// A one-argument function call.
    Call1(Fn1, Box<Expr>),
    /// A two-argument function call (first, second argument).
    Call2(Fn2, Box<Expr>, Box<Expr>),
}

/// A parse error: position (byte offset in the whitespace-stripped text) and message.
#[derive(Debug, Clone, PartialEq)]
pub struct ExprError {
    /// Byte offset of the error in the whitespace-stripped text.
    pub position: usize,
    /// What was expected or found there.
    pub message: String,
}

impl fmt::Display for ExprError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "at character {}: {}", self.position + 1, self.message)
    }
}

fn fn1(name: &str) -> Option<Fn1> {
    Some(match name {
        "sqrt" => Fn1::Sqrt,
        "exp" => Fn1::Exp,
        "log" => Fn1::Log,
        "sin" => Fn1::Sin,
        "cos" => Fn1::Cos,
        "tan" => Fn1::Tan,
        "asin" => Fn1::Asin,
        "acos" => Fn1::Acos,
        "atan" => Fn1::Atan,
        "sinh" => Fn1::Sinh,
        "cosh" => Fn1::Cosh,
        "tanh" => Fn1::Tanh,
        "abs" => Fn1::Abs,
        "square" => Fn1::Square,
        "cube" => Fn1::Cube,
        "recip" => Fn1::Recip,
        "step" => Fn1::Step,
        _ => return None,
    })
}

fn fn2(name: &str) -> Option<Fn2> {
    Some(match name {
        "min" => Fn2::Min,
        "max" => Fn2::Max,
        "atan2" => Fn2::Atan2,
        _ => return None,
    })
}

/// Maximum nesting depth accepted (hostile input).
const MAX_DEPTH: usize = 200;
/// Maximum expression length accepted (characters).
const MAX_LEN: usize = 100_000;

struct Parser<'a> {
    s: &'a [u8],
    i: usize,
    depth: usize,
}

impl Parser<'_> {
    fn err<T>(&self, msg: impl Into<String>) -> Result<T, ExprError> {
        Err(ExprError {
            position: self.i,
            message: msg.into(),
        })
    }
    fn peek(&self) -> Option<u8> {
        self.s.get(self.i).copied()
    }
    fn enter(&mut self) -> Result<(), ExprError> {
        self.depth += 1;
        if self.depth > MAX_DEPTH {
            return self.err("expression nested too deeply");
        }
        Ok(())
    }
    // sum := product (('+'|'-') product)*
    fn sum(&mut self) -> Result<Expr, ExprError> {
        self.enter()?;
        let mut a = self.product()?;
        while let Some(c) = self.peek() {
            let op = match c {
                b'+' => Op::Add,
                b'-' => Op::Sub,
                _ => break,
            };
            self.i += 1;
            let b = self.product()?;
            a = Expr::Bin(op, Box::new(a), Box::new(b));
        }
        self.depth -= 1;
        Ok(a)
    }
    // product := unary (('*'|'/') unary)*
    fn product(&mut self) -> Result<Expr, ExprError> {
        let mut a = self.unary()?;
        while let Some(c) = self.peek() {
            let op = match c {
                b'*' => Op::Mul,
                b'/' => Op::Div,
                _ => break,
            };
            self.i += 1;
            let b = self.unary()?;
            a = Expr::Bin(op, Box::new(a), Box::new(b));
        }
        Ok(a)
    }
    // unary := '-' unary | power
    fn unary(&mut self) -> Result<Expr, ExprError> {
        if self.peek() == Some(b'-') {
            self.i += 1;
            self.enter()?;
            let e = self.unary()?;
            self.depth -= 1;
            return Ok(Expr::Neg(Box::new(e)));
        }
        self.power()
    }
    // power := atom ('^' unary)?   (right-associative; exponent may be negated)
    fn power(&mut self) -> Result<Expr, ExprError> {
        let a = self.atom()?;
        if self.peek() == Some(b'^') {
            self.i += 1;
            self.enter()?;
            let b = self.unary()?;
            self.depth -= 1;
            return Ok(Expr::Bin(Op::Pow, Box::new(a), Box::new(b)));
        }
        Ok(a)
    }
    fn atom(&mut self) -> Result<Expr, ExprError> {
        match self.peek() {
            None => self.err("unexpected end of expression"),
            Some(b'(') => {
                self.i += 1;
                let e = self.sum()?;
                if self.peek() != Some(b')') {
                    return self.err("expected ')'");
                }
                self.i += 1;
                Ok(e)
            }
            Some(c) if c.is_ascii_digit() || c == b'.' => self.number(),
            Some(c) if c.is_ascii_alphabetic() || c == b'_' => {
                let start = self.i;
                while let Some(c) = self.peek() {
                    if c.is_ascii_alphanumeric() || c == b'_' {
                        self.i += 1;
                    } else {
                        break;
                    }
                }
                let name = std::str::from_utf8(&self.s[start..self.i]).unwrap_or("");
                if self.peek() == Some(b'(') {
                    self.i += 1;
                    let a = self.sum()?;
                    let e = if let Some(f) = fn1(name) {
                        Expr::Call1(f, Box::new(a))
                    } else if let Some(f) = fn2(name) {
                        if self.peek() != Some(b',') {
                            return self.err(format!("{name}() takes two arguments"));
                        }
                        self.i += 1;
                        let b = self.sum()?;
                        Expr::Call2(f, Box::new(a), Box::new(b))
                    } else {
                        self.i = start;
                        return self.err(format!("unknown function '{name}'"));
                    };
                    if self.peek() != Some(b')') {
                        return self.err("expected ')'");
                    }
                    self.i += 1;
                    Ok(e)
                } else if let Some(k) = VARIABLES.iter().position(|v| *v == name) {
                    Ok(Expr::Var(k))
                } else {
                    self.i = start;
                    self.err(format!(
                        "unknown variable '{name}' (a bushing expression may use {})",
                        VARIABLES.join(", ")
                    ))
                }
            }
            Some(c) => self.err(format!("unexpected character '{}'", c as char)),
        }
    }
    fn number(&mut self) -> Result<Expr, ExprError> {
        let start = self.i;
        while matches!(self.peek(), Some(c) if c.is_ascii_digit() || c == b'.') {
            self.i += 1;
        }
        if matches!(self.peek(), Some(b'e' | b'E')) {
            let save = self.i;
            self.i += 1;
            if matches!(self.peek(), Some(b'+' | b'-')) {
                self.i += 1;
            }
            if matches!(self.peek(), Some(c) if c.is_ascii_digit()) {
                while matches!(self.peek(), Some(c) if c.is_ascii_digit()) {
                    self.i += 1;
                }
            } else {
                self.i = save;
            }
        }
        let text = std::str::from_utf8(&self.s[start..self.i]).unwrap_or("");
        match text.parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(Expr::Num(v)),
            _ => {
                self.i = start;
                self.err(format!("'{text}' is not a number"))
            }
        }
    }
}

impl Expr {
    /// Parse an expression (whitespace is removed first, as OpenSim does).
    pub fn parse(text: &str) -> Result<Expr, ExprError> {
        let stripped: String = text.chars().filter(|c| !c.is_whitespace()).collect();
        if stripped.len() > MAX_LEN {
            return Err(ExprError {
                position: 0,
                message: format!("expression longer than {MAX_LEN} characters"),
            });
        }
        if stripped.is_empty() {
            return Err(ExprError {
                position: 0,
                message: "empty expression".into(),
            });
        }
        let mut p = Parser {
            s: stripped.as_bytes(),
            i: 0,
            depth: 0,
        };
        let e = p.sum()?;
        if p.i != p.s.len() {
            return p.err("unexpected text after the expression");
        }
        Ok(e)
    }

    /// Value at the deflection `q = (theta_x, theta_y, theta_z, delta_x, delta_y, delta_z)`.
    pub fn eval<T: Scalar>(&self, q: &[T; 6]) -> T {
        match self {
            Expr::Num(v) => T::c(*v),
            Expr::Var(k) => q.get(*k).copied().unwrap_or_else(T::zero),
            Expr::Neg(a) => -a.eval(q),
            Expr::Bin(op, a, b) => {
                let x = a.eval(q);
                let y = b.eval(q);
                match op {
                    Op::Add => x + y,
                    Op::Sub => x - y,
                    Op::Mul => x * y,
                    Op::Div => x / y,
                    Op::Pow => pow(x, y, b),
                }
            }
            Expr::Call1(f, a) => {
                let x = a.eval(q);
                match f {
                    Fn1::Sqrt => x.sqrt(),
                    Fn1::Exp => x.exp(),
                    Fn1::Log => x.ln(),
                    Fn1::Sin => x.sin(),
                    Fn1::Cos => x.cos(),
                    Fn1::Tan => x.tan(),
                    Fn1::Asin => x.asin(),
                    Fn1::Acos => x.acos(),
                    Fn1::Atan => x.atan(),
                    Fn1::Sinh => x.sinh(),
                    Fn1::Cosh => x.cosh(),
                    Fn1::Tanh => x.tanh(),
                    Fn1::Abs => {
                        if x.re() < 0.0 {
                            -x
                        } else {
                            x
                        }
                    }
                    Fn1::Square => x * x,
                    Fn1::Cube => x * x * x,
                    Fn1::Recip => T::one() / x,
                    Fn1::Step => {
                        if x.re() >= 0.0 {
                            T::one()
                        } else {
                            T::zero()
                        }
                    }
                }
            }
            Expr::Call2(f, a, b) => {
                let x = a.eval(q);
                let y = b.eval(q);
                match f {
                    Fn2::Min => {
                        if y.re() < x.re() {
                            y
                        } else {
                            x
                        }
                    }
                    Fn2::Max => {
                        if y.re() > x.re() {
                            y
                        } else {
                            x
                        }
                    }
                    Fn2::Atan2 => x.atan2(y),
                }
            }
        }
    }

    /// When the expression is a linear form `sum_j c_j v_j` of the variables
    /// (no constant term, every product with a constant factor), its
    /// coefficients; otherwise `None`.
    pub fn linear_coefficients(&self) -> Option<[f64; 6]> {
        let (c, k) = self.affine()?;
        (k == 0.0).then_some(c)
    }

    fn affine(&self) -> Option<([f64; 6], f64)> {
        Some(match self {
            Expr::Num(v) => ([0.0; 6], *v),
            Expr::Var(k) => {
                let mut c = [0.0; 6];
                *c.get_mut(*k)? = 1.0;
                (c, 0.0)
            }
            Expr::Neg(a) => {
                let (c, k) = a.affine()?;
                (c.map(|v| -v), -k)
            }
            Expr::Bin(op, a, b) => {
                let (ca, ka) = a.affine()?;
                let (cb, kb) = b.affine()?;
                let const_a = ca.iter().all(|v| *v == 0.0);
                let const_b = cb.iter().all(|v| *v == 0.0);
                match op {
                    Op::Add => (std::array::from_fn(|i| ca[i] + cb[i]), ka + kb),
                    Op::Sub => (std::array::from_fn(|i| ca[i] - cb[i]), ka - kb),
                    Op::Mul if const_a => (cb.map(|v| ka * v), ka * kb),
                    Op::Mul if const_b => (ca.map(|v| v * kb), ka * kb),
                    Op::Div if const_b => (ca.map(|v| v / kb), ka / kb),
                    _ => return None,
                }
            }
            _ => return None,
        })
    }
}

/// `x^y`: integer exponents by repeated multiplication (exact for duals and
/// as Lepton does for small integer powers), otherwise `exp(y ln x)`.
fn pow<T: Scalar>(x: T, y: T, yexpr: &Expr) -> T {
    if let Expr::Num(n) = yexpr {
        if n.fract() == 0.0 && n.abs() <= 16.0 {
            let k = n.abs() as i32;
            let mut r = T::one();
            for _ in 0..k {
                r *= x;
            }
            return if *n < 0.0 { T::one() / r } else { r };
        }
    }
    x.powf(y)
}

#[cfg(test)]
mod tests {
    use super::*;
    use num_dual::Dual64;

    fn ev(s: &str, q: [f64; 6]) -> f64 {
        Expr::parse(s).unwrap().eval(&q)
    }

    #[test]
    fn precedence_and_functions() {
        let q = [0.3, -0.2, 0.1, 0.01, -0.02, 0.03];
        assert_eq!(ev("1+2*3", q), 7.0);
        assert_eq!(ev("2^3^2", q), 512.0);
        assert_eq!(ev("-2^2", q), -4.0);
        assert_eq!(ev("2*-3", q), -6.0);
        assert_eq!(ev("8/2/2", q), 2.0);
        assert!(
            (ev("7*theta_x + 1.5e-1*theta_y - 2*sinh(theta_z/0.5)", q)
                - (7.0 * 0.3 + 0.15 * -0.2 - 2.0 * (0.1f64 / 0.5).sinh()))
            .abs()
                < 1e-15
        );
        assert_eq!(
            ev("1000*delta_y^3+2E2*delta_x", q),
            1000.0 * (-0.02f64).powi(3) + 2.0
        );
        assert_eq!(
            ev("max(theta_x,theta_y)+min(1,2)+step(-0.1)+step(0)", q),
            1.3 + 1.0
        );
        assert_eq!(ev("abs(theta_y)*square(2)*cube(1)", q), 0.2 * 4.0);
    }

    #[test]
    fn rejects_bad_text() {
        for bad in [
            "", "1+", "theta_q", "foo(1)", "(1", "1)", "1..2", "max(1)", "1#2", "2*", "e5",
        ] {
            assert!(Expr::parse(bad).is_err(), "accepted {bad:?}");
        }
        let deep = "(".repeat(1000) + "1" + &")".repeat(1000);
        assert!(Expr::parse(&deep).is_err());
    }

    #[test]
    fn linear_forms_are_recognised() {
        let e = Expr::parse("68.8*theta_x-0.5*theta_y+2*delta_z").unwrap();
        assert_eq!(
            e.linear_coefficients(),
            Some([68.8, -0.5, 0.0, 0.0, 0.0, 2.0])
        );
        assert_eq!(
            Expr::parse("0.0").unwrap().linear_coefficients(),
            Some([0.0; 6])
        );
        assert_eq!(
            Expr::parse("1+theta_x").unwrap().linear_coefficients(),
            None
        );
        assert_eq!(
            Expr::parse("theta_x*theta_y")
                .unwrap()
                .linear_coefficients(),
            None
        );
    }

    #[test]
    fn duals_give_derivatives() {
        let e = Expr::parse("3*sinh(theta_x/0.2)+theta_x^3").unwrap();
        let x = 0.13;
        let mut q = [Dual64::from_re(0.0); 6];
        q[0] = Dual64::new(x, 1.0);
        let v = e.eval(&q);
        let want = 3.0 / 0.2 * (x / 0.2).cosh() + 3.0 * x * x;
        assert!((v.eps - want).abs() < 1e-12);
    }
}
