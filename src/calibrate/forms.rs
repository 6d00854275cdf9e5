//! Non-linear and coupled intervertebral stiffness forms as parametric
//! force laws, shared by calibration ([`super::family::StiffnessFamily`]
//! with `--params nonlinear:sinh|nonlinear:cubic|coupled`) and diagnosis
//! (`diagnose::family`). The names follow the stiffness table's forms
//! (`docs/stiffness-table.md`: `linear`, `nonlinear` with `sinh` / `cubic`
//! curves, `coupled`).
//!
//! Shape parameters are dimensionless and zero in the linear limit, so that
//! "no non-linearity / no coupling" lies inside the parameter box:
//!
//! - non-linear: the *stiffening* `s_d = K_d(th_ref,d) / K_d(0) - 1`, the
//!   relative increase of the tangent stiffness at a reference rotation
//!   `th_ref,d` (the largest measured rotation of the DoF). `cubic`:
//!   `M = k th + c th^3` with `c = s k / (3 th_ref^2)`; `sinh`:
//!   `M = k a sinh(th / a)` with `cosh(th_ref / a) = 1 + s`. Both have slope
//!   `k` at zero and are linear at `s = 0` (for `s` below
//!   [`SINH_SERIES_BELOW`] the sinh curve is represented by its cubic
//!   Taylor polynomial, equal to it to double precision).
//! - coupled: the rotational 3x3 block `K_ij = rho_ij sqrt(k_i k_j)` with
//!   the correlation matrix `rho` built from two correlations and one
//!   partial correlation (`rho_xy`, `rho_xz`, `rho_yz|x`, each in (-1, 1)):
//!   `rho_yz = rho_yz|x sqrt((1 - rho_xy^2)(1 - rho_xz^2)) + rho_xy rho_xz`,
//!   which makes every parameter vector of the box symmetric positive
//!   definite (no constraint needed).
//!
//! The builders are generic over [`Scalar`] so that calibration
//! differentiates them exactly with dual numbers.

use crate::solver::scalar::Scalar;
use crate::solver::{BushingModel, Curve};
use nalgebra::Matrix6;

/// Below this stiffening the sinh curve is replaced by its (exact to double
/// precision) cubic Taylor polynomial: `a` is then too large for `sinh(x/a)`
/// to be differentiated without cancellation.
const SINH_SERIES_BELOW: f64 = 1e-8;

/// Floor of the reference rotation (rad): 0.1 deg.
pub const MIN_REFERENCE_ROTATION: f64 = 0.1 * (std::f64::consts::PI / 180.0);

/// A non-linear curve kind of the stiffness table.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CurveForm {
    /// `k a sinh(th / a)` (neutral zone).
    Sinh,
    /// `k th + c th^3`.
    Cubic,
}

impl CurveForm {
    /// The table's curve kind name.
    pub fn name(&self) -> &'static str {
        match self {
            CurveForm::Sinh => "sinh",
            CurveForm::Cubic => "cubic",
        }
    }
}

/// Reference rotation per rotational DoF: the largest `|value|` (rad)
/// among `(dof, value)` pairs, at least [`MIN_REFERENCE_ROTATION`].
pub fn reference_rotations(values: impl IntoIterator<Item = (usize, f64)>) -> [f64; 3] {
    let mut m = [MIN_REFERENCE_ROTATION; 3];
    for (d, v) in values {
        if d < 3 && v.is_finite() {
            m[d] = m[d].max(v.abs());
        }
    }
    m
}

/// `acosh(1 + s)^2`, smooth (and exactly differentiable) down to `s = 0`.
fn acosh1p_sq<T: Scalar>(s: T) -> T {
    if s.re() < SINH_SERIES_BELOW {
        // 2 s - s^2 / 3 + 4 s^3 / 45 (next term ~ s^4: below 1e-32)
        s * (T::c(2.0) - s * (T::c(1.0 / 3.0) - s * T::c(4.0 / 45.0)))
    } else {
        let l = (s + (s * (T::c(2.0) + s)).sqrt()).ln_1p();
        l * l
    }
}

/// A parametric rotational curve: slope `k` at zero, stiffening `s` at
/// `th_ref`. Returns the curve's parameters in [`Curve::params`] order and
/// whether they are `(k, a)` of a sinh (`true`) or `(k, c)` of a cubic.
pub fn shaped_curve<T: Scalar>(form: CurveForm, k: T, s: T, th_ref: f64) -> ([T; 2], bool) {
    match form {
        CurveForm::Cubic => ([k, k * s / T::c(3.0 * th_ref * th_ref)], false),
        CurveForm::Sinh => {
            let l2 = acosh1p_sq(s);
            if s.re() < SINH_SERIES_BELOW {
                // k a sinh(x/a) = k x + k x^3 / (6 a^2) + O(x^5 / a^4)
                ([k, k * l2 / T::c(6.0 * th_ref * th_ref)], false)
            } else {
                ([k, T::c(th_ref) / l2.sqrt()], true)
            }
        }
    }
}

/// The [`Curve`] of [`shaped_curve`]'s output.
pub fn curve_of(params: [f64; 2], sinh: bool) -> Curve {
    if sinh {
        Curve::Sinh {
            k: params[0],
            a: params[1],
        }
    } else {
        Curve::Cubic {
            k: params[0],
            c: params[1],
        }
    }
}

/// Correlations `(rho_xy, rho_xz, rho_yz)` of the rotational DoFs from
/// `(rho_xy, rho_xz, rho_yz|x)` (partial correlation of y and z given x).
/// For arguments in (-1, 1) the 3x3 correlation matrix is positive definite.
pub fn correlations_from_partial<T: Scalar>(pc: [T; 3]) -> [T; 3] {
    let [xy, xz, p] = pc;
    let one = T::c(1.0);
    let yz = p * ((one - xy * xy) * (one - xz * xz)).sqrt() + xy * xz;
    [xy, xz, yz]
}

/// The 6x6 stiffness of diagonal `k` (deflection order rx..tz) with the
/// rotational correlations `rho = (rho_xy, rho_xz, rho_yz)`:
/// `K_ij = rho_ij sqrt(k_i k_j)` in the rotational block, translations
/// uncoupled. Row-major 36 values ([`BushingModel::stiffness_params`] order).
pub fn coupled_entries<T: Scalar>(k: &[T; 6], rho: [T; 3]) -> [T; 36] {
    let mut m = [T::c(0.0); 36];
    for d in 0..6 {
        m[7 * d] = k[d];
    }
    for (n, (i, j)) in [(0usize, 1usize), (0, 2), (1, 2)].into_iter().enumerate() {
        let v = rho[n] * (k[i] * k[j]).sqrt();
        m[6 * i + j] = v;
        m[6 * j + i] = v;
    }
    m
}

/// [`coupled_entries`] as a matrix.
pub fn coupled_matrix(k: &[f64; 6], rho: [f64; 3]) -> Matrix6<f64> {
    Matrix6::from_row_slice(&coupled_entries(k, rho))
}

/// A coupled bushing law from [`coupled_entries`].
pub fn coupled_model(entries: &[f64], damping: [f64; 6]) -> BushingModel {
    BushingModel::Coupled {
        stiffness: Matrix6::from_row_slice(entries),
        damping,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use num_dual::{Dual64, DualNum};

    #[test]
    fn stiffening_is_the_tangent_increase_at_the_reference_rotation() {
        let (k, th) = (40.0, 0.1);
        for s in [1e-9, 1e-7, 1e-3, 0.5, 2.0, 30.0] {
            for form in [CurveForm::Sinh, CurveForm::Cubic] {
                let (p, sinh) = shaped_curve(form, k, s, th);
                let c = curve_of(p, sinh);
                // tangent by central differences of the curve
                let h = 1e-6;
                let kt = (c.eval(th + h) - c.eval(th - h)) / (2.0 * h);
                let k0 = (c.eval(h) - c.eval(-h)) / (2.0 * h);
                assert!((k0 / k - 1.0).abs() < 1e-8, "{form:?} {s}: slope at 0 {k0}");
                assert!(
                    ((kt / k0 - 1.0) - s).abs() < 1e-7 * (1.0 + s),
                    "{form:?} {s}: K(th)/K(0) - 1 = {}",
                    kt / k0 - 1.0
                );
            }
        }
    }

    #[test]
    fn sinh_series_and_closed_form_agree_at_the_switch() {
        let th = 0.08;
        let lo = shaped_curve(CurveForm::Sinh, 30.0, SINH_SERIES_BELOW * 0.999_999, th);
        let hi = shaped_curve(CurveForm::Sinh, 30.0, SINH_SERIES_BELOW, th);
        let (a, b) = (curve_of(lo.0, lo.1), curve_of(hi.0, hi.1));
        for x in [-0.2, -0.05, 0.01, 0.1, 0.3] {
            let (ya, yb) = (a.eval(x), b.eval(x));
            assert!((ya - yb).abs() < 1e-13 * yb.abs(), "{x}: {ya} vs {yb}");
        }
        // the exact derivative in s (dual numbers) matches central
        // differences on both sides of the switch, and is continuous
        let m_at = |s: Dual64| -> Dual64 {
            let (p, sinh) = shaped_curve(CurveForm::Sinh, Dual64::from(30.0), s, th);
            let x = Dual64::from(th);
            if sinh {
                p[0] * p[1] * (x / p[1]).sinh()
            } else {
                p[0] * x + p[1] * x * x * x
            }
        };
        let mut exact = Vec::new();
        for s in [SINH_SERIES_BELOW * 0.5, SINH_SERIES_BELOW * 2.0, 0.01, 1.0] {
            let d = m_at(Dual64::new(s, 1.0)).eps;
            let h = 1e-3 * s;
            let fd = (m_at(Dual64::from(s + h)).re - m_at(Dual64::from(s - h)).re) / (2.0 * h);
            assert!((d / fd - 1.0).abs() < 1e-4, "s {s}: {d} vs {fd}");
            exact.push(d);
        }
        assert!((exact[0] / exact[1] - 1.0).abs() < 1e-6, "{exact:?}");
    }

    #[test]
    fn partial_correlations_always_give_positive_definite_matrices() {
        let k = [60.0, 300.0, 45.0, 1e5, 1e6, 1e5];
        let grid = [-0.95, -0.6, 0.0, 0.7, 0.95];
        for a in grid {
            for b in grid {
                for c in grid {
                    let rho = correlations_from_partial([a, b, c]);
                    assert!(rho.iter().all(|r| r.abs() < 1.0));
                    let m = coupled_matrix(&k, rho);
                    assert_eq!(m, m.transpose());
                    assert!(m.cholesky().is_some(), "{a} {b} {c}: {rho:?}");
                }
            }
        }
        assert_eq!(correlations_from_partial([0.3, -0.2, 0.0])[2], 0.3 * -0.2);
    }
}
