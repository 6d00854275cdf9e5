//! Bushing force laws: the map from the deflection
//! `q = (rx, ry, rz, tx, ty, tz)` to the generalised stiffness force, as the
//! three OpenSim 4.6 bushing classes compute it, plus named per-DoF curves.
//!
//! Every law gives the generalised force `f = -g(q) - C q'` with a diagonal
//! damping `C`; `g` is the law's stiffness part:
//!
//! | [`BushingModel`] | `g(q)` | OpenSim 4.6 class |
//! |---|---|---|
//! | `Linear` | `K q` element by element | `BushingForce` |
//! | `PerDof` | `g_i = curve_i(q_i)` ([`Curve`]) | `FunctionBasedBushingForce` (the functions `m_x_theta_x_function` ..) |
//! | `Coupled` | `K q`, `K` a 6x6 matrix | `ExpressionBasedBushingForce` with linear expressions |
//! | `Expression` | `g_i = expr_i(q)` ([`Expr`]) | `ExpressionBasedBushingForce` (`Mx_expression` .. `Fz_expression`) |
//!
//! (OpenSim 4.6 evaluates `-functions(q) - C q'` for both function- and
//! expression-based bushings, with the damping applied: probed with the
//! Python bindings.) The kinematics of the deflection and the application of
//! `f` to the two bodies (moment through the transpose of the angle-rate
//! map) are the same for all laws and live in `forces`.
//!
//! Laws expose named parameters ([`BushingModel::stiffness_params`]) whose
//! sensitivities the statics compute with dual numbers. Adding a law is
//! adding a variant here (and, to write it into a model, in `personalise`).

use super::expr::Expr;
use super::scalar::Scalar;
use super::spec::{BushingModel, Curve};
use crate::error::DataError;
use nalgebra::Matrix6;

impl Curve {
    /// `g(x)`, generic over the scalar.
    #[inline]
    pub fn eval<T: Scalar>(&self, x: T) -> T {
        match self {
            Curve::Linear { k } => x * T::c(*k),
            Curve::Cubic { k, c } => x * T::c(*k) + x * x * x * T::c(*c),
            Curve::Sinh { k, a } => T::c(*k) * T::c(*a) * (x / T::c(*a)).sinh(),
            Curve::Bilinear { k_neg, k_pos } => {
                if x.re() < 0.0 {
                    x * T::c(*k_neg)
                } else {
                    x * T::c(*k_pos)
                }
            }
            Curve::Function(f) => f.value_slope(x).0,
        }
    }

    /// `g(x)` with the named parameters replaced by `p` (same order as
    /// [`Curve::params`]); `Function` curves ignore `p`.
    fn eval_with<T: Scalar>(&self, x: T, p: &[T]) -> T {
        let get = |i: usize| p.get(i).copied().unwrap_or_else(T::zero);
        match self {
            Curve::Linear { .. } => x * get(0),
            Curve::Cubic { .. } => x * get(0) + x * x * x * get(1),
            Curve::Sinh { .. } => get(0) * get(1) * (x / get(1)).sinh(),
            Curve::Bilinear { .. } => {
                if x.re() < 0.0 {
                    x * get(0)
                } else {
                    x * get(1)
                }
            }
            Curve::Function(f) => f.value_slope(x).0,
        }
    }

    /// Named parameters: `[k]`, `[k, c]`, `[k, a]`, `[k_neg, k_pos]`, none for functions.
    pub fn params(&self) -> Vec<f64> {
        match self {
            Curve::Linear { k } => vec![*k],
            Curve::Cubic { k, c } => vec![*k, *c],
            Curve::Sinh { k, a } => vec![*k, *a],
            Curve::Bilinear { k_neg, k_pos } => vec![*k_neg, *k_pos],
            Curve::Function(_) => vec![],
        }
    }

    /// Finite numbers and well-formed data (`a != 0` for sinh).
    pub fn validate(&self) -> Result<(), DataError> {
        if let Curve::Function(f) = self {
            return f.validate();
        }
        if !self.params().iter().all(|x| x.is_finite()) {
            return Err(DataError::NotFinite("curve parameters"));
        }
        if matches!(self, Curve::Sinh { a, .. } if *a == 0.0) {
            return Err(DataError::ZeroSinhScale);
        }
        Ok(())
    }
}

/// Compiled stiffness law of one bushing (see the module docs).
#[derive(Debug, Clone)]
pub(crate) enum Law {
    Linear([f64; 6]),
    PerDof(Box<[Curve; 6]>),
    Coupled(Box<Matrix6<f64>>),
    Expression(Box<[Expr; 6]>),
}

impl Law {
    pub(crate) fn from_model(m: &BushingModel) -> Law {
        match m {
            BushingModel::Linear {
                rot_stiffness: r,
                trans_stiffness: t,
                ..
            } => Law::Linear([r.x, r.y, r.z, t.x, t.y, t.z]),
            BushingModel::PerDof { curves, .. } => Law::PerDof(curves.clone()),
            BushingModel::Coupled { stiffness, .. } => Law::Coupled(Box::new(*stiffness)),
            BushingModel::Expression { exprs, .. } => Law::Expression(exprs.clone()),
        }
    }

    /// The stiffness part `g(q)` (the generalised force is `-g(q) - C q'`).
    #[inline]
    pub(crate) fn g<T: Scalar>(&self, q: &[T; 6]) -> [T; 6] {
        match self {
            Law::Linear(k) => std::array::from_fn(|i| q[i] * T::c(k[i])),
            Law::PerDof(c) => std::array::from_fn(|i| c[i].eval(q[i])),
            Law::Coupled(k) => std::array::from_fn(|i| {
                let mut s = T::zero();
                for j in 0..6 {
                    s += T::c(k[(i, j)]) * q[j];
                }
                s
            }),
            Law::Expression(e) => std::array::from_fn(|i| e[i].eval(q)),
        }
    }

    /// `g(q)` with the law's parameters replaced by `p` (see
    /// [`BushingModel::stiffness_params`] for their order).
    pub(crate) fn g_with<T: Scalar>(&self, q: &[T; 6], p: &[T]) -> [T; 6] {
        let get = |i: usize| p.get(i).copied().unwrap_or_else(T::zero);
        match self {
            Law::Linear(_) => std::array::from_fn(|i| q[i] * get(i)),
            Law::PerDof(c) => {
                let mut off = 0;
                std::array::from_fn(|i| {
                    let n = c[i].params().len();
                    let v = c[i].eval_with(q[i], p.get(off..off + n).unwrap_or(&[]));
                    off += n;
                    v
                })
            }
            Law::Coupled(_) => std::array::from_fn(|i| {
                let mut s = T::zero();
                for j in 0..6 {
                    s += get(6 * i + j) * q[j];
                }
                s
            }),
            Law::Expression(e) => std::array::from_fn(|i| e[i].eval(q)),
        }
    }

    /// Potential energy stored at `q`: the work of `g` along the straight
    /// path from 0 to `q` (exact for linear and coupled symmetric laws;
    /// 5-point Gauss-Legendre on 8 sub-intervals otherwise, which is exact
    /// for polynomial curves up to degree 9 and path-independent only when
    /// `g` is conservative).
    pub(crate) fn potential(&self, q: &[f64; 6]) -> f64 {
        match self {
            Law::Linear(k) => (0..6).map(|i| 0.5 * k[i] * q[i] * q[i]).sum(),
            Law::Coupled(k) => {
                let v = nalgebra::Vector6::from_row_slice(q);
                0.5 * v.dot(&(k.as_ref() * v))
            }
            _ => {
                const X: [f64; 5] = [
                    -0.906_179_845_938_664,
                    -0.538_469_310_105_683,
                    0.0,
                    0.538_469_310_105_683,
                    0.906_179_845_938_664,
                ];
                const W: [f64; 5] = [
                    0.236_926_885_056_189,
                    0.478_628_670_499_366,
                    0.568_888_888_888_889,
                    0.478_628_670_499_366,
                    0.236_926_885_056_189,
                ];
                let m = 8;
                let mut e = 0.0;
                for s in 0..m {
                    let (a, b) = (s as f64 / m as f64, (s + 1) as f64 / m as f64);
                    for (x, w) in X.iter().zip(&W) {
                        let t = 0.5 * (a + b) + 0.5 * (b - a) * x;
                        let qs: [f64; 6] = std::array::from_fn(|i| t * q[i]);
                        let g = self.g(&qs);
                        let dot: f64 = (0..6).map(|i| g[i] * q[i]).sum();
                        e += 0.5 * (b - a) * w * dot;
                    }
                }
                e
            }
        }
    }
}

impl BushingModel {
    /// Diagonal damping `(rx, ry, rz, tx, ty, tz)`.
    pub fn damping(&self) -> [f64; 6] {
        match self {
            BushingModel::Linear {
                rot_damping: r,
                trans_damping: t,
                ..
            } => [r.x, r.y, r.z, t.x, t.y, t.z],
            BushingModel::PerDof { damping, .. }
            | BushingModel::Coupled { damping, .. }
            | BushingModel::Expression { damping, .. } => *damping,
        }
    }

    /// Check the law's numbers (finite; curves well formed). Errors say which DoF.
    pub fn validate(&self) -> Result<(), DataError> {
        let finite = DataError::check_finite;
        finite("damping", &self.damping())?;
        match self {
            BushingModel::Linear { .. } => finite("stiffness", &self.stiffness_params()),
            BushingModel::PerDof { curves, .. } => {
                for (c, dof) in curves.iter().zip(super::spec::DOF_NAMES) {
                    c.validate().map_err(|e| DataError::Curve {
                        dof,
                        error: Box::new(e),
                    })?;
                }
                Ok(())
            }
            BushingModel::Coupled { stiffness, .. } => {
                finite("stiffness matrix", stiffness.as_slice())
            }
            BushingModel::Expression { .. } => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use num_dual::Dual64;

    #[test]
    fn curves_and_their_parameter_forms_agree() {
        let cs = [
            Curve::Linear { k: 51.0 },
            Curve::Cubic { k: 20.0, c: 3000.0 },
            Curve::Sinh { k: 68.8, a: 0.05 },
            Curve::Bilinear {
                k_neg: 30.0,
                k_pos: 80.0,
            },
        ];
        for c in &cs {
            let p = c.params();
            for x in [-0.2, -0.01, 0.0, 0.03, 0.15] {
                assert_eq!(c.eval(x), c.eval_with(x, &p), "{c:?} at {x}");
            }
        }
        // slope at zero is k for the named stiffening forms
        for c in &cs[..3] {
            let d = c.eval(Dual64::new(0.0, 1.0)).eps;
            assert!((d - c.params()[0]).abs() < 1e-12, "{c:?}");
        }
        assert_eq!(cs[3].eval(-0.1), -3.0);
        assert_eq!(cs[3].eval(0.1), 8.0);
    }

    #[test]
    fn potential_is_the_integral_of_the_force() {
        let law = Law::PerDof(Box::new([
            Curve::Cubic { k: 20.0, c: 3000.0 },
            Curve::Linear { k: 10.0 },
            Curve::Linear { k: 0.0 },
            Curve::Linear { k: 0.0 },
            Curve::Linear { k: 0.0 },
            Curve::Linear { k: 0.0 },
        ]));
        let q = [0.2, -0.1, 0.0, 0.0, 0.0, 0.0];
        let want = 10.0 * 0.04 + 750.0 * 0.0016 + 5.0 * 0.01;
        assert!((law.potential(&q) - want).abs() < 1e-13);
    }
}
