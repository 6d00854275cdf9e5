//! Evaluation of transform-axis functions ([`Function`]) and their first
//! derivative, generic over the scalar type so that dual numbers carry exact
//! higher derivatives through them.

use super::scalar::Scalar;
use super::spec::Function;
use crate::error::DataError;

/// Index `i` of the interval `[x_i, x_{i+1}]` holding `x` (clamped to the
/// end intervals); `xs` has at least 2 points, strictly increasing.
fn interval(xs: &[f64], x: f64) -> usize {
    let n = xs.len();
    if n < 2 {
        return 0;
    }
    // partition_point: first index with xs[i] > x
    let p = xs.partition_point(|&v| v <= x);
    p.saturating_sub(1).min(n - 2)
}

impl Function {
    /// Value and first derivative at `x`.
    pub fn eval<T: Scalar>(&self, x: T) -> (T, T) {
        match self {
            Function::Constant(c) => (T::c(*c), T::zero()),
            Function::Linear { slope, intercept } => {
                (x * T::c(*slope) + T::c(*intercept), T::c(*slope))
            }
            Function::Multiplier { scale, inner } => {
                let (v, d) = inner.eval(x);
                (v * T::c(*scale), d * T::c(*scale))
            }
            Function::Cubic { x: xs, y, b, c, d } => {
                let n = xs.len();
                let (Some(&x0), Some(&xn)) = (xs.first(), xs.last()) else {
                    return (T::zero(), T::zero());
                };
                let xr = x.re();
                if n == 1 {
                    return (T::c(y[0]), T::zero());
                }
                if xr < x0 {
                    return (T::c(y[0]) + (x - T::c(x0)) * T::c(b[0]), T::c(b[0]));
                }
                if xr > xn {
                    return (
                        T::c(y[n - 1]) + (x - T::c(xn)) * T::c(b[n - 1]),
                        T::c(b[n - 1]),
                    );
                }
                let i = interval(xs, xr);
                let dx = x - T::c(xs[i]);
                let (bi, ci, di) = (T::c(b[i]), T::c(c[i]), T::c(d[i]));
                let v = T::c(y[i]) + dx * (bi + dx * (ci + dx * di));
                let dv = bi + dx * (ci * T::c(2.0) + dx * di * T::c(3.0));
                (v, dv)
            }
            Function::PiecewiseLinear { x: xs, y } => {
                let n = xs.len();
                if n == 0 {
                    return (T::zero(), T::zero());
                }
                if n == 1 {
                    return (T::c(y[0]), T::zero());
                }
                let i = interval(xs, x.re());
                let slope = (y[i + 1] - y[i]) / (xs[i + 1] - xs[i]);
                (T::c(y[i]) + (x - T::c(xs[i])) * T::c(slope), T::c(slope))
            }
            Function::Polynomial(cs) => {
                // Horner for value and derivative.
                let mut v = T::zero();
                let mut dv = T::zero();
                for &ci in cs {
                    dv = dv * x + v;
                    v = v * x + T::c(ci);
                }
                (v, dv)
            }
        }
    }

    /// Check the function's data (lengths, increasing abscissae, finite numbers).
    pub fn validate(&self) -> Result<(), DataError> {
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
            Function::Cubic { x, y, b, c, d } => {
                let n = x.len();
                if n == 0 || y.len() != n || b.len() != n || c.len() != n || d.len() != n {
                    return Err(DataError::Lengths { what: "spline", n });
                }
                for v in [x, y, b, c, d] {
                    finite("spline coefficients", v)?;
                }
                increasing("spline", x)
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
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use num_dual::Dual64;

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
    }

    #[test]
    fn derivatives_agree_with_duals() {
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
            Function::Cubic {
                x: vec![0.0, 1.0, 2.0],
                y: vec![0.0, 1.0, 0.5],
                b: vec![1.0, 0.2, -0.4],
                c: vec![0.1, -0.5, 0.3],
                d: vec![-0.1, 0.2, 0.0],
            },
        ];
        for f in &fs {
            for &x in &[-0.5, 0.3, 1.4, 2.7] {
                let (v, dv) = f.eval(Dual64::new(x, 1.0));
                let (v64, dv64) = f.eval(x);
                assert!((v.re - v64).abs() < 1e-14);
                assert!((v.eps - dv64).abs() < 1e-12, "{f:?} at {x}");
                assert!((dv.re - dv64).abs() < 1e-14);
            }
        }
    }

    #[test]
    fn piecewise_linear_interpolates() {
        let f = Function::PiecewiseLinear {
            x: vec![0.0, 1.0, 3.0],
            y: vec![0.0, 2.0, 3.0],
        };
        assert!((f.eval(0.5f64).0 - 1.0).abs() < 1e-15);
        assert!((f.eval(2.0f64).0 - 2.5).abs() < 1e-15);
        assert!((f.eval(4.0f64).0 - 3.5).abs() < 1e-15);
    }
}
