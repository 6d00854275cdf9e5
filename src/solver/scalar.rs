//! The scalar types the solver's kinematics and force code is generic over:
//! `f64` for plain evaluation, and forward-mode dual numbers (num-dual) for
//! exact derivatives: `Dual64` (one direction, e.g. time derivatives along
//! the generalised speeds) and [`D6`] (six directions at once, one joint's
//! block of the statics tangent). The trait is `util::scalar`'s.

use nalgebra::{Matrix3, Vector3};
use num_dual::Derivative;

pub use crate::util::scalar::{Scalar, D6};

/// A `D6` with value `x` and unit derivative in direction `k` (< 6).
pub fn d6_var(x: f64, k: usize) -> D6 {
    let mut e = nalgebra::SVector::<f64, 6>::zeros();
    if let Some(v) = e.get_mut(k) {
        *v = 1.0;
    }
    D6::new(x, Derivative::some(e))
}

/// The derivative part of a `D6` (zeros when absent).
pub fn d6_eps(x: &D6) -> [f64; 6] {
    let m = x
        .eps
        .unwrap_generic(nalgebra::Const::<6>, nalgebra::Const::<1>);
    [m[0], m[1], m[2], m[3], m[4], m[5]]
}

/// Convert an f64 vector to scalar `T`.
#[inline]
pub fn v3<T: Scalar>(v: &Vector3<f64>) -> Vector3<T> {
    Vector3::new(T::c(v.x), T::c(v.y), T::c(v.z))
}

/// Convert an f64 matrix to scalar `T`.
#[inline]
pub fn m3<T: Scalar>(m: &Matrix3<f64>) -> Matrix3<T> {
    m.map(T::c)
}

/// Rotation matrix by `angle` about the unit `axis` (Rodrigues).
#[inline]
pub fn rot_axis<T: Scalar>(axis: &Vector3<f64>, angle: T) -> Matrix3<T> {
    let (s, c) = angle.sin_cos();
    let one = T::one();
    let t = one - c;
    let (x, y, z) = (T::c(axis.x), T::c(axis.y), T::c(axis.z));
    Matrix3::new(
        c + x * x * t,
        x * y * t - z * s,
        x * z * t + y * s,
        y * x * t + z * s,
        c + y * y * t,
        y * z * t - x * s,
        z * x * t - y * s,
        z * y * t + x * s,
        c + z * z * t,
    )
}

/// Body-fixed X-Y-Z angles of `r` (r = Rx(a) Ry(b) Rz(c)), as Simbody's
/// `convertRotationToBodyFixedXYZ` computes them away from gimbal lock,
/// generic over the scalar so that dual numbers differentiate through it
/// (the f64 form of the model files is `osim::model::xyz_angles`).
#[inline]
pub fn body_xyz<T: Scalar>(r: &Matrix3<T>) -> Vector3<T> {
    let half = T::c(0.5);
    let rsum = ((r[(0, 0)] * r[(0, 0)]
        + r[(0, 1)] * r[(0, 1)]
        + r[(1, 2)] * r[(1, 2)]
        + r[(2, 2)] * r[(2, 2)])
        * half)
        .sqrt();
    let t2 = r[(0, 2)].atan2(rsum);
    let t1 = (-r[(1, 2)]).atan2(r[(2, 2)]);
    let t3 = (-r[(0, 1)]).atan2(r[(0, 0)]);
    Vector3::new(t1, t2, t3)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn body_xyz_round_trip() {
        let a = Vector3::new(0.3, -0.7, 1.2);
        let r = crate::osim::model::body_fixed_xyz(&a).into_inner();
        let b = body_xyz(&r);
        assert!((a - b).norm() < 1e-14);
    }

    #[test]
    fn rodrigues_matches_axis_rotations() {
        let r = rot_axis(&Vector3::z(), 0.4f64);
        let e = nalgebra::Rotation3::from_axis_angle(&Vector3::z_axis(), 0.4);
        assert!((r - e.matrix()).norm() < 1e-15);
    }
}
