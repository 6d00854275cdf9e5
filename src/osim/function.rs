//! OpenSim functions of one variable (TransformAxis functions, coupler
//! functions, moving path point locations) with value and first/second
//! derivatives, matching OpenSim's definitions:
//!
//! - `Constant` c; `LinearFunction` coefficients [slope, intercept];
//! - `PolynomialFunction` coefficients highest order first;
//! - `MultiplierFunction` scale * inner function;
//! - `SimmSpline` and `NaturalCubicSpline`: OpenSim's cubic spline (the
//!   Forsythe-Malcolm-Moler construction: end third derivatives matched to
//!   divided differences of the end points); outside the knots the value is
//!   extrapolated linearly with the end slope, and d2 is 0;
//! - `PiecewiseLinearFunction`: linear interpolation, linear extrapolation
//!   with the end segments' slopes.
//!
//! Other classes are kept as [`Function::Unsupported`] (evaluating gives NaN;
//! check [`Function::is_supported`]).

use super::props::{fixed_prop, loc, opt_numbers};
use super::xml::Element;
use crate::error::{DataError, Error, Result};
use crate::util::scalar::Scalar;
use std::path::Path;

/// Tags of the OpenSim function classes (used to find a function element).
pub const FUNCTION_CLASSES: [&str; 13] = [
    "Constant",
    "LinearFunction",
    "PolynomialFunction",
    "MultiplierFunction",
    "SimmSpline",
    "NaturalCubicSpline",
    "PiecewiseLinearFunction",
    "PiecewiseConstantFunction",
    "GCVSpline",
    "StepFunction",
    "Sine",
    "ExpressionBasedFunction",
    "FunctionBasedPathSet",
];

/// Spaces of OpenSim's spline knots closer than this are widened (as OpenSim does).
const TINY_KNOT_GAP: f64 = 1e-7;
/// Abscissae this close to an end knot are treated as the end knot.
const ROUNDOFF: f64 = 2e-13;

/// A cubic spline through knots (OpenSim's SimmSpline / NaturalCubicSpline).
/// On segment k, f(x) = y_k + t (b_k + t (c_k + t d_k)) with t = x - x_k.
#[derive(Debug, Clone, PartialEq)]
pub struct CubicSpline {
    /// Knot abscissae, increasing.
    pub x: Vec<f64>,
    /// Knot values, one per abscissa.
    pub y: Vec<f64>,
    b: Vec<f64>,
    c: Vec<f64>,
    d: Vec<f64>,
}

impl CubicSpline {
    /// Build the spline; needs at least 2 knots, x non-decreasing, and
    /// x, y the same length (checked by the caller for messages).
    pub fn new(x: Vec<f64>, y: Vec<f64>) -> CubicSpline {
        let n = x.len();
        let mut s = CubicSpline {
            x,
            y,
            b: vec![0.0; n],
            c: vec![0.0; n],
            d: vec![0.0; n],
        };
        s.fit();
        s
    }

    fn fit(&mut self) {
        let n = self.x.len();
        if n < 2 {
            return;
        }
        let (x, y) = (&self.x, &self.y);
        let h: Vec<f64> = (0..n - 1)
            .map(|i| (x[i + 1] - x[i]).max(TINY_KNOT_GAP))
            .collect();
        if n == 2 {
            let slope = (y[1] - y[0]) / h[0];
            self.b = vec![slope; 2];
            self.c = vec![0.0; 2];
            self.d = vec![0.0; 2];
            return;
        }
        // Unknowns s_i (one third of the second derivative at knot i) solve a
        // symmetric tridiagonal system: diag[i], off-diagonal h[i], rhs[i].
        let last = n - 1;
        let mut diag = vec![0.0; n];
        let mut rhs = vec![0.0; n];
        let slope: Vec<f64> = (0..last).map(|i| (y[i + 1] - y[i]) / h[i]).collect();
        for i in 1..last {
            diag[i] = 2.0 * (h[i - 1] + h[i]);
            rhs[i] = slope[i] - slope[i - 1];
        }
        // End conditions: the third derivative at each end equals that of the
        // cubic through the four end points (divided differences).
        diag[0] = -h[0];
        diag[last] = -h[last - 1];
        if n > 3 {
            let gap = |a: usize, b: usize| (x[a] - x[b]).max(TINY_KNOT_GAP);
            let lo = rhs[2] / gap(3, 1) - rhs[1] / gap(2, 0);
            let hi = rhs[last - 1] / gap(last, n - 3) - rhs[n - 3] / gap(last - 1, n - 4);
            rhs[0] = lo * h[0] * h[0] / gap(3, 0);
            rhs[last] = -hi * h[last - 1] * h[last - 1] / gap(last, n - 4);
        }
        // Thomas algorithm (off-diagonal entries are h[i]).
        for i in 1..n {
            let m = h[i - 1] / diag[i - 1];
            diag[i] -= m * h[i - 1];
            rhs[i] -= m * rhs[i - 1];
        }
        let mut s = vec![0.0; n];
        s[last] = rhs[last] / diag[last];
        for i in (0..last).rev() {
            s[i] = (rhs[i] - h[i] * s[i + 1]) / diag[i];
        }
        let mut b = vec![0.0; n];
        let mut c = vec![0.0; n];
        let mut d = vec![0.0; n];
        for i in 0..last {
            b[i] = slope[i] - h[i] * (s[i + 1] + 2.0 * s[i]);
            d[i] = (s[i + 1] - s[i]) / h[i];
            c[i] = 3.0 * s[i];
        }
        b[last] = slope[last - 1] + h[last - 1] * (s[last - 1] + 2.0 * s[last]);
        c[last] = 3.0 * s[last];
        d[last] = d[last - 1];
        self.b = b;
        self.c = c;
        self.d = d;
    }

    /// Segment index for an abscissa inside [x0, x_{n-1}].
    fn segment(&self, x: f64) -> usize {
        opensim_segment(&self.x, x)
    }

    /// Derivative of order 0, 1 or 2 (2 for any higher order).
    pub fn eval_order(&self, x: f64, order: usize) -> f64 {
        let [v, d1, d2] = self.eval_all(x);
        match order {
            0 => v,
            1 => d1,
            _ => d2,
        }
    }

    /// Value, first and second derivative at `x`, generic over the scalar
    /// (a dual number carries its derivative through). Outside the knots the
    /// value is extrapolated linearly with the end slope (second derivative
    /// 0); an abscissa within round-off of an end knot is that knot. NaN
    /// below 2 knots.
    pub fn eval_all<T: Scalar>(&self, x: T) -> [T; 3] {
        let n = self.x.len();
        if n < 2 {
            return [T::c(f64::NAN); 3];
        }
        let xr = x.re();
        let (x0, xn) = (self.x[0], self.x[n - 1]);
        for (outside, i) in [(xr < x0, 0), (xr > xn, n - 1)] {
            if outside {
                let b = T::c(self.b[i]);
                return [T::c(self.y[i]) + (x - T::c(self.x[i])) * b, b, T::zero()];
            }
        }
        // At an end knot (within round-off) t is 0 in value, keeping x's derivative part.
        let (k, t) = match [(x0, 0usize), (xn, n - 1)]
            .into_iter()
            .find(|&(xe, _)| (xr - xe).abs() <= ROUNDOFF)
        {
            Some((_, i)) => (i, x - T::c(xr)),
            None => {
                let k = self.segment(xr);
                (k, x - T::c(self.x[k]))
            }
        };
        let (b, c, d) = (T::c(self.b[k]), T::c(self.c[k]), T::c(self.d[k]));
        [
            T::c(self.y[k]) + t * (b + t * (c + t * d)),
            b + t * (T::c(2.0) * c + T::c(3.0) * t * d),
            T::c(2.0) * c + T::c(6.0) * t * d,
        ]
    }
}

/// A function of one variable as OpenSim defines it.
#[derive(Debug, Clone, PartialEq)]
pub enum Function {
    /// `Constant`: the same value everywhere.
    Constant(f64),
    /// `LinearFunction`: slope * x + intercept.
    Linear {
        /// Derivative with respect to x.
        slope: f64,
        /// Value at x = 0.
        intercept: f64,
    },
    /// Coefficients, highest order first.
    Polynomial(Vec<f64>),
    /// `MultiplierFunction`: scale * inner(x).
    Multiplier {
        /// Factor applied to the inner function's value.
        scale: f64,
        /// The function being scaled.
        inner: Box<Function>,
    },
    /// `SimmSpline` or `NaturalCubicSpline` (same construction in OpenSim).
    Spline {
        /// The OpenSim class name it was read from.
        class: String,
        /// The spline through its knots.
        spline: CubicSpline,
    },
    /// `PiecewiseLinearFunction`: straight segments between points.
    PiecewiseLinear {
        /// Abscissae, increasing.
        x: Vec<f64>,
        /// Values, one per abscissa.
        y: Vec<f64>,
    },
    /// A class this tool does not evaluate (kept by class name).
    Unsupported {
        /// The OpenSim class name.
        class: String,
    },
}

impl Function {
    /// The function element inside `parent`: a direct child whose tag is a
    /// function class, or one inside a `<function>` wrapper (older files).
    pub fn element_in(parent: &Element) -> Option<&Element> {
        let direct = parent
            .elements()
            .find(|e| FUNCTION_CLASSES.contains(&e.name.as_str()));
        if direct.is_some() {
            return direct;
        }
        for wrapper in ["function", "coupled_coordinates_function"] {
            if let Some(w) = parent.child(wrapper) {
                if let Some(f) = w.elements().next() {
                    return Some(f);
                }
            }
        }
        None
    }

    /// Parse the function held in `parent` (see [`Function::element_in`]).
    pub fn from_parent(parent: &Element, file: &Path) -> Result<Function> {
        let e = Function::element_in(parent).ok_or_else(|| {
            Error::parse(
                file,
                loc(parent),
                "missing the function (e.g. <LinearFunction>, <SimmSpline>)",
            )
        })?;
        Function::from_element(e, file)
    }

    /// Parse a function element (its tag is the class).
    pub fn from_element(e: &Element, file: &Path) -> Result<Function> {
        Ok(match e.name.as_str() {
            "Constant" => {
                let v = opt_numbers(e, "value", file)?.unwrap_or_else(|| vec![0.0]);
                match v.as_slice() {
                    [c] => Function::Constant(*c),
                    _ => return Err(Error::parse(file, loc(e), "<value> must hold one number")),
                }
            }
            "LinearFunction" => {
                let c = fixed_prop(e, "coefficients", 2, file)?;
                Function::Linear {
                    slope: c[0],
                    intercept: c[1],
                }
            }
            "PolynomialFunction" => {
                let c = opt_numbers(e, "coefficients", file)?.unwrap_or_default();
                if c.is_empty() {
                    return Err(Error::parse(
                        file,
                        loc(e),
                        "polynomial without coefficients",
                    ));
                }
                Function::Polynomial(c)
            }
            "MultiplierFunction" => {
                let scale = super::props::f64_or(e, "scale", 1.0, file)?;
                let inner = Function::from_parent(e, file)?;
                Function::Multiplier {
                    scale,
                    inner: Box::new(inner),
                }
            }
            "SimmSpline" | "NaturalCubicSpline" | "PiecewiseLinearFunction" => {
                let (x, y) = knots(e, file)?;
                if e.name == "PiecewiseLinearFunction" {
                    Function::PiecewiseLinear { x, y }
                } else {
                    Function::Spline {
                        class: e.name.clone(),
                        spline: CubicSpline::new(x, y),
                    }
                }
            }
            other => Function::Unsupported {
                class: other.to_string(),
            },
        })
    }

    /// Whether [`eval`](Self::eval) gives real values for this function.
    pub fn is_supported(&self) -> bool {
        match self {
            Function::Unsupported { .. } => false,
            Function::Multiplier { inner, .. } => inner.is_supported(),
            _ => true,
        }
    }

    /// Value at `x`.
    pub fn eval(&self, x: f64) -> f64 {
        self.value_slope(x).0
    }

    /// First derivative d/dx at `x`.
    pub fn d1(&self, x: f64) -> f64 {
        self.value_slope(x).1
    }

    /// Second derivative d2/dx2 at `x`.
    pub fn d2(&self, x: f64) -> f64 {
        self.derivative(x, 2)
    }

    /// Value and first derivative at `x`, generic over the scalar so that
    /// dual numbers carry exact higher derivatives through (the solver's
    /// kinematics and bushing curves). NaN for an unsupported class.
    pub fn value_slope<T: Scalar>(&self, x: T) -> (T, T) {
        match self {
            Function::Constant(c) => (T::c(*c), T::zero()),
            Function::Linear { slope, intercept } => {
                (T::c(*slope) * x + T::c(*intercept), T::c(*slope))
            }
            Function::Polynomial(c) => (polynomial(c, x, 0), polynomial(c, x, 1)),
            Function::Multiplier { scale, inner } => {
                let (v, d) = inner.value_slope(x);
                (T::c(*scale) * v, T::c(*scale) * d)
            }
            Function::Spline { spline, .. } => {
                let [v, d, _] = spline.eval_all(x);
                (v, d)
            }
            Function::PiecewiseLinear { x: xs, y: ys } => piecewise_linear(xs, ys, x),
            Function::Unsupported { .. } => (T::c(f64::NAN), T::c(f64::NAN)),
        }
    }

    /// Derivative of order 0, 1 or 2 (higher orders are 0 except polynomials).
    pub fn derivative(&self, x: f64, order: usize) -> f64 {
        match (self, order) {
            (_, 0) => self.value_slope(x).0,
            (_, 1) => self.value_slope(x).1,
            (Function::Polynomial(c), _) => polynomial(c, x, order),
            (Function::Multiplier { scale, inner }, _) => scale * inner.derivative(x, order),
            (Function::Spline { spline, .. }, _) => spline.eval_order(x, order),
            (Function::Unsupported { .. }, _) => f64::NAN,
            _ => 0.0,
        }
    }

    /// Check the function's data for evaluation (lengths, strictly
    /// increasing abscissae, finite numbers, a supported class).
    pub fn validate(&self) -> std::result::Result<(), DataError> {
        let finite = DataError::check_finite;
        let increasing = |what: &'static str, x: &[f64]| {
            if x.windows(2).any(|w| w[1] <= w[0]) {
                return Err(DataError::NotIncreasing(what));
            }
            Ok(())
        };
        match self {
            Function::Constant(c) => finite("constant", &[*c]),
            Function::Linear { slope, intercept } => {
                finite("linear function", &[*slope, *intercept])
            }
            Function::Multiplier { scale, inner } => {
                finite("multiplier scale", &[*scale])?;
                inner.validate()
            }
            Function::Spline { spline, .. } => {
                let n = spline.x.len();
                if n < 2 || spline.y.len() != n {
                    return Err(DataError::Lengths { what: "spline", n });
                }
                for v in [&spline.x, &spline.y, &spline.b, &spline.c, &spline.d] {
                    finite("spline coefficients", v)?;
                }
                increasing("spline", &spline.x)
            }
            Function::PiecewiseLinear { x, y } => {
                if x.is_empty() || x.len() != y.len() {
                    return Err(DataError::Lengths {
                        what: "piecewise linear function",
                        n: x.len(),
                    });
                }
                finite("piecewise linear points", x)?;
                finite("piecewise linear points", y)?;
                increasing("piecewise linear function", x)
            }
            Function::Polynomial(cs) => finite("polynomial coefficients", cs),
            Function::Unsupported { class } => Err(DataError::Unsupported(class.clone())),
        }
    }
}

/// Derivative of order `order` of the polynomial with coefficients `c`
/// (highest order first): the coefficient list differentiated, then Horner.
fn polynomial<T: Scalar>(c: &[f64], x: T, order: usize) -> T {
    let Some(deg) = c.len().checked_sub(1) else {
        return T::zero();
    };
    let mut acc = T::zero();
    for (i, &ci) in c.iter().enumerate() {
        let p = deg - i; // power of this term
        if p < order {
            break;
        }
        let factor: f64 = (0..order).map(|k| (p - k) as f64).product();
        acc = acc * x + T::c(ci * factor);
    }
    acc
}

/// The segment k (x_k <= x <= x_k+1) OpenSim's bisection picks for x inside
/// the knots. At an interior knot either neighbour qualifies and the choice
/// depends on the bisection path; slopes of piecewise-linear functions differ
/// there, so the same path is followed.
fn opensim_segment(xs: &[f64], x: f64) -> usize {
    let n = xs.len();
    if n < 3 {
        return 0;
    }
    let (mut lo, mut hi) = (0usize, n);
    for _ in 0..64 {
        let k = (lo + hi) / 2;
        if k + 1 >= n {
            return n - 2;
        }
        if x < xs[k] {
            hi = k;
        } else if x > xs[k + 1] {
            lo = k;
        } else {
            return k;
        }
    }
    // Unsorted knots (refused by the reader) could loop: fall back.
    xs.partition_point(|&xi| xi <= x)
        .saturating_sub(1)
        .min(n - 2)
}

/// Value and slope of linear interpolation through the knots, extrapolated
/// with the end segments' slopes; NaN without knots.
fn piecewise_linear<T: Scalar>(xs: &[f64], ys: &[f64], x: T) -> (T, T) {
    let n = xs.len();
    if n == 0 {
        return (T::c(f64::NAN), T::c(f64::NAN));
    }
    if n == 1 {
        return (T::c(ys[0]), T::zero());
    }
    let xr = x.re();
    // Outside the knots the first/last segment extrapolates.
    let k = if xr < xs[0] {
        0
    } else if xr > xs[n - 1] {
        n - 2
    } else {
        opensim_segment(xs, xr)
    };
    let dx = xs[k + 1] - xs[k];
    let slope = if dx > 0.0 {
        (ys[k + 1] - ys[k]) / dx
    } else {
        0.0
    };
    (T::c(ys[k]) + T::c(slope) * (x - T::c(xs[k])), T::c(slope))
}

fn knots(e: &Element, file: &Path) -> Result<(Vec<f64>, Vec<f64>)> {
    let x = opt_numbers(e, "x", file)?
        .ok_or_else(|| Error::parse(file, loc(e), "missing required property <x>"))?;
    let y = opt_numbers(e, "y", file)?
        .ok_or_else(|| Error::parse(file, loc(e), "missing required property <y>"))?;
    if x.len() != y.len() {
        return Err(Error::parse(
            file,
            loc(e),
            format!("<x> has {} values but <y> has {}", x.len(), y.len()),
        ));
    }
    if x.len() < 2 {
        return Err(Error::parse(
            file,
            loc(e),
            "a spline needs at least 2 points",
        ));
    }
    if x.windows(2).any(|w| w[1] < w[0]) {
        return Err(Error::parse(
            file,
            loc(e),
            "<x> values must be non-decreasing",
        ));
    }
    Ok((x, y))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fd_check(f: &Function, xs: &[f64]) {
        for &x in xs {
            let h = 1e-6;
            let d1 = (f.eval(x + h) - f.eval(x - h)) / (2.0 * h);
            let d2 = (f.d1(x + h) - f.d1(x - h)) / (2.0 * h);
            assert!(
                (d1 - f.d1(x)).abs() < 1e-6 * (1.0 + d1.abs()),
                "d1 at {x}: {d1} vs {}",
                f.d1(x)
            );
            assert!(
                (d2 - f.d2(x)).abs() < 1e-5 * (1.0 + d2.abs()),
                "d2 at {x}: {d2} vs {}",
                f.d2(x)
            );
        }
    }

    #[test]
    fn polynomial_highest_order_first() {
        let p = Function::Polynomial(vec![1.0, 2.0, 3.0]);
        assert_eq!(p.eval(2.0), 11.0);
        assert_eq!(p.d1(2.0), 6.0);
        assert_eq!(p.d2(2.0), 2.0);
        fd_check(&p, &[-1.3, 0.0, 0.7]);
    }

    #[test]
    fn spline_interpolates_and_derivatives_match_fd() {
        let s = Function::Spline {
            class: "SimmSpline".into(),
            spline: CubicSpline::new(vec![0.0, 1.0, 2.0, 4.0, 5.5], vec![0.0, 1.0, 0.0, 3.0, 2.0]),
        };
        for (x, y) in [(0.0, 0.0), (1.0, 1.0), (2.0, 0.0), (4.0, 3.0), (5.5, 2.0)] {
            assert!((s.eval(x) - y).abs() < 1e-12);
        }
        fd_check(&s, &[0.3, 0.9, 1.5, 2.5, 3.9, 5.0]);
        // A spline through a cubic's samples reproduces the cubic (the end
        // conditions are exact for cubics).
        let cubic = |x: f64| 0.5 * x * x * x - x * x + 2.0;
        let xs = vec![-1.0, -0.2, 0.5, 1.0, 2.2, 3.0];
        let ys: Vec<f64> = xs.iter().map(|&x| cubic(x)).collect();
        let sp = CubicSpline::new(xs, ys);
        for x in [-0.7, 0.1, 0.8, 1.7, 2.9] {
            assert!((sp.eval_order(x, 0) - cubic(x)).abs() < 1e-12, "at {x}");
        }
    }

    #[test]
    fn multiplier_and_linear() {
        let m = Function::Multiplier {
            scale: -2.0,
            inner: Box::new(Function::Linear {
                slope: 3.0,
                intercept: 1.0,
            }),
        };
        assert_eq!(m.eval(1.0), -8.0);
        assert_eq!(m.d1(1.0), -6.0);
        assert_eq!(m.d2(1.0), 0.0);
        let pl = Function::PiecewiseLinear {
            x: vec![0.0, 1.0, 2.0, 4.0],
            y: vec![0.0, 1.0, 0.0, 3.0],
        };
        // Values OpenSim 4.6 gives for this function (checked by hand: linear
        // interpolation, end-slope extrapolation).
        for (x, v) in [(-1.0, -1.0), (0.5, 0.5), (3.0, 1.5), (5.0, 4.5)] {
            assert!((pl.eval(x) - v).abs() < 1e-15);
        }
    }

    #[test]
    fn invalid_data_is_typed() {
        let pl = |x: Vec<f64>, y: Vec<f64>| Function::PiecewiseLinear { x, y }.validate();
        assert_eq!(pl(vec![0.0, 1.0], vec![0.0, 1.0]), Ok(()));
        assert_eq!(
            pl(vec![0.0, 0.0], vec![0.0, 1.0]),
            Err(DataError::NotIncreasing("piecewise linear function"))
        );
        assert!(matches!(
            pl(vec![0.0, 1.0], vec![0.0]),
            Err(DataError::Lengths { n: 2, .. })
        ));
        assert!(matches!(
            pl(vec![0.0, f64::NAN], vec![0.0, 1.0]),
            Err(DataError::NotFinite(_))
        ));
        let m = Function::Multiplier {
            scale: f64::INFINITY,
            inner: Box::new(Function::Constant(1.0)),
        };
        assert_eq!(m.validate(), Err(DataError::NotFinite("multiplier scale")));
        let spline = |x: Vec<f64>| Function::Spline {
            class: "SimmSpline".into(),
            spline: CubicSpline::new(x, vec![0.0, 1.0, 0.5]),
        };
        assert_eq!(spline(vec![0.0, 1.0, 2.0]).validate(), Ok(()));
        assert_eq!(
            spline(vec![0.0, 1.0, 1.0]).validate(),
            Err(DataError::NotIncreasing("spline"))
        );
        let sine = Function::Multiplier {
            scale: 1.0,
            inner: Box::new(Function::Unsupported {
                class: "Sine".into(),
            }),
        };
        assert_eq!(sine.validate(), Err(DataError::Unsupported("Sine".into())));
    }

    /// The generic evaluation: with a dual number its derivative part is the
    /// slope, and its value and slope are those of the f64 evaluation, for
    /// every class, inside and outside the knots and at the end knots.
    #[test]
    fn value_slope_agrees_with_duals_and_f64() {
        use num_dual::Dual64;
        let fs = [
            Function::Linear {
                slope: 2.0,
                intercept: -1.0,
            },
            Function::Polynomial(vec![0.5, -1.0, 2.0, 3.0]),
            Function::Multiplier {
                scale: 1.5,
                inner: Box::new(Function::Polynomial(vec![1.0, 0.0, 0.0])),
            },
            Function::Spline {
                class: "NaturalCubicSpline".into(),
                spline: CubicSpline::new(vec![0.0, 1.0, 2.0, 2.5], vec![0.0, 1.0, 0.5, 0.7]),
            },
            Function::PiecewiseLinear {
                x: vec![0.0, 1.0, 3.0],
                y: vec![0.0, 2.0, 3.0],
            },
        ];
        for f in &fs {
            for &x in &[-0.5, 0.0, 0.3, 1.4, 2.5, 2.7] {
                let (v, dv) = f.value_slope(Dual64::new(x, 1.0));
                assert_eq!(v.re, f.eval(x), "{f:?} at {x}");
                assert_eq!(dv.re, f.d1(x), "{f:?} at {x}");
                assert!((v.eps - f.d1(x)).abs() < 1e-12, "{f:?} at {x}");
                assert!((dv.eps - f.d2(x)).abs() < 1e-12, "{f:?} at {x}");
            }
        }
    }
}
