//! The measured quantities of `../shared/formats/experiment.md`, computed
//! from body poses, generic over the solver's scalar (so dual numbers give
//! their exact derivatives with respect to the coordinates).
//!
//! With `dR_b = R_b1 R_b0^T` (loaded 1, unloaded 0):
//! - [`Convention::Composed`] (the format's definition, the default):
//!   rotation `rotvec(dR_upper dR_lower^T)`, translation
//!   `(p_u1 - p_l1) - dR_lower (p_u0 - p_l0)`;
//! - [`Convention::Difference`] (the wording of `diagnose-dev/README.md`):
//!   rotation `rotvec(dR_upper) - rotvec(dR_lower)`, translation
//!   `(p_u1 - p_u0) - (p_l1 - p_l0)`.
//!
//! Both are on ground axes; they agree to first order in the rotations.

use crate::solver::scalar::Scalar;
use crate::solver::Pose;
use nalgebra::{Matrix3, Vector3};
use serde::Serialize;

/// How a pair's load-induced increment is formed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Convention {
    /// `rotvec(dR_u dR_l^T)` and `(p_u1 - p_l1) - dR_l (p_u0 - p_l0)`.
    #[default]
    Composed,
    /// `rotvec(dR_u) - rotvec(dR_l)` and `(p_u1 - p_u0) - (p_l1 - p_l0)`.
    Difference,
}

/// A convention name that is neither `composed` nor `difference`.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("expected 'composed' or 'difference', got '{0}'")]
pub struct UnknownConvention(pub String);

impl std::str::FromStr for Convention {
    type Err = UnknownConvention;
    fn from_str(s: &str) -> Result<Self, UnknownConvention> {
        match s {
            "composed" => Ok(Convention::Composed),
            "difference" => Ok(Convention::Difference),
            _ => Err(UnknownConvention(s.to_string())),
        }
    }
}

/// Rotation vector (axis times angle, angle in [0, pi)) of a rotation
/// matrix. Accurate for angles well below pi (inter-vertebral increments);
/// smooth at zero (series), so dual numbers differentiate it everywhere it
/// is used.
fn rotvec<T: Scalar>(r: &Matrix3<T>) -> Vector3<T> {
    let half = T::c(0.5);
    let v = Vector3::new(
        r[(2, 1)] - r[(1, 2)],
        r[(0, 2)] - r[(2, 0)],
        r[(1, 0)] - r[(0, 1)],
    ) * half;
    let c = (r[(0, 0)] + r[(1, 1)] + r[(2, 2)] - T::one()) * half;
    let s2 = v.dot(&v);
    if s2.re() < 1e-16 && c.re() > 0.0 {
        // theta / sin(theta) = 1 + s^2/6 + O(s^4)
        return v * (T::one() + s2 / T::c(6.0));
    }
    let s = s2.sqrt();
    let th = s.atan2(c);
    v * (th / s)
}

fn lift<T: Scalar>(x: &Pose<f64>) -> Pose<T> {
    Pose {
        r: x.r.map(T::c),
        p: x.p.map(T::c),
    }
}

/// The six increments `(rx, ry, rz, tx, ty, tz)` of a pair (SI units).
/// `u0, l0`: unloaded poses of upper and lower; `u1, l1`: loaded poses.
pub fn pair_increment<T: Scalar>(
    conv: Convention,
    u0: &Pose<T>,
    l0: &Pose<T>,
    u1: &Pose<T>,
    l1: &Pose<T>,
) -> [T; 6] {
    let du = u1.r * u0.r.transpose();
    let dl = l1.r * l0.r.transpose();
    let (rot, tr) = match conv {
        Convention::Composed => (
            rotvec(&(du * dl.transpose())),
            (u1.p - l1.p) - dl * (u0.p - l0.p),
        ),
        Convention::Difference => (rotvec(&du) - rotvec(&dl), (u1.p - u0.p) - (l1.p - l0.p)),
    };
    [rot.x, rot.y, rot.z, tr.x, tr.y, tr.z]
}

/// [`pair_increment`] with constant unloaded poses.
pub fn pair_increment_loaded<T: Scalar>(
    conv: Convention,
    u0: &Pose<f64>,
    l0: &Pose<f64>,
    u1: &Pose<T>,
    l1: &Pose<T>,
) -> [T; 6] {
    pair_increment(conv, &lift(u0), &lift(l0), u1, l1)
}

/// [`pair_increment`] with constant loaded poses.
pub fn pair_increment_unloaded<T: Scalar>(
    conv: Convention,
    u0: &Pose<T>,
    l0: &Pose<T>,
    u1: &Pose<f64>,
    l1: &Pose<f64>,
) -> [T; 6] {
    pair_increment(conv, u0, l0, &lift(u1), &lift(l1))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::osim::model::body_fixed_xyz;
    use nalgebra::{Rotation3, Unit};

    fn rot(axis: [f64; 3], angle: f64) -> Matrix3<f64> {
        *Rotation3::from_axis_angle(&Unit::new_normalize(Vector3::from(axis)), angle).matrix()
    }

    #[test]
    fn rotvec_matches_axis_angle() {
        for (axis, angle) in [
            ([1.0, 0.0, 0.0], 0.3),
            ([0.2, -1.0, 0.5], 1.2),
            ([0.0, 0.0, 1.0], 1e-9),
            ([1.0, 1.0, 1.0], 2.9),
        ] {
            let a = Unit::new_normalize(Vector3::from(axis));
            let v = rotvec(&rot(axis, angle));
            assert!((v - a.into_inner() * angle).norm() < 1e-12, "{v:?}");
        }
        assert_eq!(rotvec(&Matrix3::<f64>::identity()), Vector3::zeros());
    }

    #[test]
    fn rigid_motion_of_the_pair_gives_zero() {
        let u0 = Pose {
            r: body_fixed_xyz(&Vector3::new(0.1, 0.2, -0.1)).into_inner(),
            p: Vector3::new(0.01, 0.05, 0.0),
        };
        let l0 = Pose {
            r: body_fixed_xyz(&Vector3::new(0.0, 0.1, 0.05)).into_inner(),
            p: Vector3::new(0.0, 0.0, 0.01),
        };
        let g = Pose {
            r: rot([0.3, 1.0, -0.2], 0.4),
            p: Vector3::new(0.02, -0.01, 0.03),
        };
        let inc = pair_increment(
            Convention::Composed,
            &u0,
            &l0,
            &g.compose(&u0),
            &g.compose(&l0),
        );
        assert!(inc.iter().all(|v| v.abs() < 1e-12), "{inc:?}");
    }

    #[test]
    fn composed_equals_relative_rotation_on_lower_axes() {
        // rotvec(dRu dRl^T) = R_l1 rotvec(R_l0^T R_u0)^-1 ... checked via the
        // format's statement: relative rotation carried by the lower body's
        // loaded orientation.
        let u0 = Pose {
            r: body_fixed_xyz(&Vector3::new(0.1, 0.0, 0.0)).into_inner(),
            p: Vector3::zeros(),
        };
        let l0 = Pose::<f64>::identity();
        let l1 = Pose {
            r: rot([0.0, 0.0, 1.0], 0.2),
            p: Vector3::zeros(),
        };
        let rel = rot([1.0, 0.5, 0.0], 0.1); // extra rotation of upper in lower's frame
        let u1 = Pose {
            r: l1.r * rel * u0.r,
            p: Vector3::zeros(),
        };
        let inc = pair_increment(Convention::Composed, &u0, &l0, &u1, &l1);
        let expect = l1.r * rotvec(&rel);
        for k in 0..3 {
            assert!((inc[k] - expect[k]).abs() < 1e-12);
        }
        let d = pair_increment(Convention::Difference, &u0, &l0, &u1, &l1);
        // differ at second order only
        let diff = (0..3).map(|k| (d[k] - inc[k]).abs()).fold(0.0, f64::max);
        assert!(diff > 1e-6 && diff < 0.02, "{diff}");
    }
}
