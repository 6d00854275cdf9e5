//! Forward kinematics, generic over the scalar: body poses in ground and the
//! motion subspace of every free degree of freedom (the spatial velocity of
//! the joint's child body per unit speed, as Plücker coordinates about the
//! ground origin in ground axes). With dual-number scalars the same code
//! yields exact derivatives (Jacobians, time derivatives of the subspace).

use super::scalar::{rot_axis, v3, Scalar};
use super::system::{AxisSource, Joint, KinBuf, Pose, System};
use nalgebra::{Matrix3, Vector3};

/// Compute `kb.x_gb` and `kb.h` from `kb.q`.
pub fn forward<T: Scalar>(sys: &System, kb: &mut KinBuf<T>) {
    for bi in 0..sys.bodies.len() {
        let b = &sys.bodies[bi];
        let x_gp = match b.parent {
            Some(p) => kb.x_gb[p],
            None => Pose::identity(),
        };
        let j = &b.joint;
        let range = j.dof_start..j.dof_start + j.dof_count;
        let q = kb.q.get(range.clone()).unwrap_or(&[]);
        let h = kb.h.get_mut(range).unwrap_or(&mut []);
        kb.x_gb[bi] = joint_forward(j, &x_gp, q, h);
    }
}

/// One joint: the child body's pose in ground from its parent's pose `x_gp`
/// and the joint's own free dofs `q` (`dof_count` values), and the joint's
/// motion subspace written into `h` (`dof_count` entries). Used per joint by
/// the structured statics tangent (parent pose held constant).
pub(crate) fn joint_forward<T: Scalar>(
    j: &Joint,
    x_gp: &Pose<T>,
    q: &[T],
    h: &mut [[Vector3<T>; 2]],
) -> Pose<T> {
    let x_gf = x_gp.compose_c(&j.x_pf);
    let mut val = [T::zero(); 6];
    let mut der: [Option<(usize, T)>; 6] = [None; 6];
    for (ai, ax) in j.axes.iter().enumerate() {
        match &ax.source {
            AxisSource::Fixed(v) => val[ai] = T::c(*v),
            AxisSource::Dof(k, f) => {
                let qk = q.get(*k).copied().unwrap_or_else(T::zero);
                let (v, d) = f.eval(qk);
                val[ai] = v;
                der[ai] = Some((*k, d));
            }
        }
    }
    // R_FM = R(a0,v0) R(a1,v1) R(a2,v2); the axes of the later rotations
    // expressed in F are e1 = R0 a1, e2 = R0 R1 a2.
    let is_zero = |ai: usize| matches!(j.axes[ai].source, AxisSource::Fixed(v) if v == 0.0);
    let e0: Vector3<T> = v3(&j.axes[0].unit);
    let mut r = if is_zero(0) {
        Matrix3::identity()
    } else {
        rot_axis(&j.axes[0].unit, val[0])
    };
    let e1: Vector3<T> = r * v3::<T>(&j.axes[1].unit);
    if !is_zero(1) {
        r *= rot_axis(&j.axes[1].unit, val[1]);
    }
    let e2: Vector3<T> = r * v3::<T>(&j.axes[2].unit);
    if !is_zero(2) {
        r *= rot_axis(&j.axes[2].unit, val[2]);
    }
    let mut p = Vector3::zeros();
    for ai in 3..6 {
        if !is_zero(ai) {
            p += v3::<T>(&j.axes[ai].unit) * val[ai];
        }
    }
    let x_gm = x_gf.compose(&Pose { r, p });
    // motion subspace
    let es = [e0, e1, e2];
    for k in 0..j.dof_count {
        let mut w_f = Vector3::zeros();
        let mut v_f = Vector3::zeros();
        for (ai, d) in der.iter().enumerate() {
            if let Some((kk, dv)) = d {
                if *kk == k {
                    if ai < 3 {
                        w_f += es[ai] * *dv;
                    } else {
                        v_f += v3::<T>(&j.axes[ai].unit) * *dv;
                    }
                }
            }
        }
        let w = x_gf.r * w_f;
        let v = x_gf.r * v_f - w.cross(&x_gm.p);
        if let Some(h) = h.get_mut(k) {
            *h = [w, v];
        }
    }
    x_gm.compose_c(&j.x_mb)
}
