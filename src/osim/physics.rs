//! Physical validity at the model boundary: what a model may contain to be
//! a physical system at all (refused when read by `model`) and what is
//! legal but suspicious (named warnings, given for a whole model by
//! `lint::warnings`).
//!
//! Refused:
//! - a mass that is negative or not finite;
//! - an inertia that is not positive definite: the smallest principal
//!   moment must be > 0 (an all-zero inertia, a point mass or a massless
//!   body as in OpenSim's own example models, is allowed);
//! - a coordinate default beyond [`MAX_COORDINATE_DEFAULT`] (rad or m);
//! - a bushing stiffness or damping that is not finite or is larger than
//!   [`MAX_STIFFNESS`].
//!
//! Warned (OpenSim's own models contain them, e.g. the cyclist's toes):
//! - principal moments breaking the triangle inequality `I1 + I2 >= I3` by
//!   more than [`TRIANGLE_TOL`] (relative); `simulate --dynamic` refuses
//!   such a body, as its inertia is not that of any mass distribution;
//! - a coordinate default outside its range;
//! - a negative bushing stiffness (the equilibrium may be unstable).

use nalgebra::Matrix3;

/// Largest |default value| of a coordinate accepted (rad or m): a hundred
/// turns, far beyond any joint.
pub(crate) const MAX_COORDINATE_DEFAULT: f64 = 1e3;
/// Largest bushing stiffness (N/m, N m/rad) or damping accepted: six
/// orders above the stiffest intervertebral disc, still well inside f64.
pub const MAX_STIFFNESS: f64 = 1e12;
/// Relative tolerance of the triangle inequality of principal moments
/// (files round their inertias): `I1 + I2 >= I3 * (1 - TRIANGLE_TOL)`.
pub(crate) const TRIANGLE_TOL: f64 = 1e-6;

/// The symmetric inertia matrix of `[Ixx Iyy Izz Ixy Ixz Iyz]`.
pub(crate) fn inertia_matrix(i: &[f64; 6]) -> Matrix3<f64> {
    Matrix3::new(i[0], i[3], i[4], i[3], i[1], i[5], i[4], i[5], i[2])
}

/// Principal moments (ascending) of `[Ixx Iyy Izz Ixy Ixz Iyz]`.
pub fn principal_moments(i: &[f64; 6]) -> [f64; 3] {
    let e = inertia_matrix(i).symmetric_eigenvalues();
    let mut m = [e[0], e[1], e[2]];
    m.sort_by(f64::total_cmp);
    m
}

/// Why a body's mass and inertia are not physical, if they are not.
pub fn mass_error(mass: f64, inertia: &[f64; 6]) -> Option<String> {
    if !mass.is_finite() || mass < 0.0 {
        return Some(format!("mass {mass} must be finite and >= 0"));
    }
    if inertia.iter().any(|x| !x.is_finite()) {
        return Some(format!("inertia {inertia:?} is not finite"));
    }
    if inertia.iter().all(|&x| x == 0.0) {
        return None;
    }
    let m = principal_moments(inertia);
    (m[0] <= 0.0).then(|| {
        format!(
            "inertia [Ixx Iyy Izz Ixy Ixz Iyz] = {inertia:?} is not positive definite (principal moments {:.6e} {:.6e} {:.6e})",
            m[0], m[1], m[2]
        )
    })
}

/// Whether principal moments break the triangle inequality (beyond
/// [`TRIANGLE_TOL`]).
pub fn breaks_triangle(inertia: &[f64; 6]) -> bool {
    let m = principal_moments(inertia);
    m[0] + m[1] < m[2] * (1.0 - TRIANGLE_TOL)
}

/// Why a coordinate default is refused, if it is.
pub fn default_error(value: f64) -> Option<String> {
    (!value.is_finite() || value.abs() > MAX_COORDINATE_DEFAULT).then(|| {
        format!(
            "default_value {value:e} is not finite or beyond +-{MAX_COORDINATE_DEFAULT:e} (rad or m)"
        )
    })
}

/// Why a bushing stiffness or damping vector is refused, if it is.
pub fn stiffness_error(prop: &str, v: &[f64]) -> Option<String> {
    v.iter()
        .any(|x| !x.is_finite() || x.abs() > MAX_STIFFNESS)
        .then(|| format!("{prop} {v:?} is not finite or beyond +-{MAX_STIFFNESS:e}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inertia_rules() {
        // A solid box: positive definite, triangle holds.
        assert!(mass_error(1.0, &[2.0, 3.0, 4.0, 0.0, 0.0, 0.0]).is_none());
        assert!(!breaks_triangle(&[2.0, 3.0, 4.0, 0.0, 0.0, 0.0]));
        // Point mass and massless body.
        assert!(mass_error(1.0, &[0.0; 6]).is_none());
        // Negative moment, indefinite by products, negative mass, NaN.
        assert!(mass_error(1.0, &[-1.0, 3.0, 4.0, 0.0, 0.0, 0.0]).is_some());
        assert!(mass_error(1.0, &[1.0, 1.0, 1.0, 2.0, 0.0, 0.0]).is_some());
        assert!(mass_error(-1.0, &[1.0, 1.0, 1.0, 0.0, 0.0, 0.0]).is_some());
        assert!(mass_error(f64::NAN, &[1.0, 1.0, 1.0, 0.0, 0.0, 0.0]).is_some());
        // 1 + 2 < 4: no mass distribution.
        assert!(breaks_triangle(&[1.0, 2.0, 4.0, 0.0, 0.0, 0.0]));
        // A thin rod (1 + 1 = 2) holds within tolerance.
        assert!(!breaks_triangle(&[1.0, 1.0, 2.0, 0.0, 0.0, 0.0]));
    }

    #[test]
    fn bounds() {
        assert!(default_error(1e308).is_some());
        assert!(default_error(f64::NAN).is_some());
        assert!(default_error(0.3).is_none());
        assert!(stiffness_error("k", &[1e308, 0.0, 0.0]).is_some());
        assert!(stiffness_error("k", &[f64::INFINITY, 0.0, 0.0]).is_some());
        assert!(stiffness_error("k", &[-68.0, 2e6, 0.0]).is_none());
    }
}
