//! Forward kinematics, generic over the scalar: body poses in ground and the
//! motion subspace of every free degree of freedom (the spatial velocity of
//! the joint's child body per unit speed, as Plücker coordinates about the
//! ground origin in ground axes). With dual-number scalars the same code
//! yields exact derivatives (Jacobians, time derivatives of the subspace).
//!
//! [`System::body_transforms`] and [`System::joint_transform`] are the f64
//! entry points for geometric work outside the solver (the base builder's
//! default and test poses, muscle paths, views): one forward kinematics for
//! the whole crate.
//!
//! Generalised speeds: `u = qdot` except for the rotational dofs of
//! FreeJoint/BallJoint (`Joint::euler_speeds`), whose speeds are OpenSim's
//! angular velocity `w_FM` in F axes. [`forward`] gives the motion subspace
//! per unit coordinate rate (`dV/dqdot`, what the statics project on);
//! [`forward_speeds`] the subspace per unit speed (`dV/du`, what the
//! dynamics use). [`System::qdot`] and [`System::speeds_from_qdot`] map
//! between the two.

use super::scalar::{rot_axis, v3, Scalar};
use super::system::{AxisSource, DofIndex, Joint, Pose, System};
use super::workspace::KinBuf;
use crate::error::{Error, Result, SolverError};
use nalgebra::{Isometry3, Matrix3, Matrix6, Rotation3, Translation3, UnitQuaternion, Vector3};
use num_dual::Dual64;

impl Pose<f64> {
    /// The same transform as an isometry.
    fn to_isometry(self) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::from(self.p),
            UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(self.r)),
        )
    }
}

impl System {
    /// Pose in ground (`X_GB`) of every body at the free dofs `q`, in
    /// system order (parent before child) with the body names. Allocates
    /// its own buffers: for occasional geometric work, not inner loops.
    pub fn body_transforms(&self, q: &[f64]) -> Result<Vec<(String, Isometry3<f64>)>> {
        self.check_q(q)?;
        let mut kb = KinBuf::<f64>::new(self);
        kb.q.copy_from_slice(q);
        forward(self, &mut kb);
        Ok(self
            .bodies
            .iter()
            .zip(&kb.x_gb)
            .map(|(b, x)| (b.name.clone(), x.to_isometry()))
            .collect())
    }

    /// The transform `X_FM` across the joint named `joint` (from its parent
    /// frame F to its child frame M) at the free dofs `q`.
    pub fn joint_transform(&self, joint: &str, q: &[f64]) -> Result<Isometry3<f64>> {
        self.check_q(q)?;
        let j = self
            .bodies
            .iter()
            .map(|b| &b.joint)
            .find(|j| j.name == joint)
            .ok_or_else(|| Error::invalid("solver", format!("no joint named '{joint}'")))?;
        let own = q.get(j.dofs()).unwrap_or(&[]);
        let mut local = [[Vector3::zeros(); 2]; 6];
        Ok(joint_local(j, own, &mut local).to_isometry())
    }
}

/// Compute `kb.x_gb` and `kb.h` from `kb.q`; `kb.h` per unit coordinate
/// rate (the statics' generalised forces are `h^T W`).
pub fn forward<T: Scalar>(sys: &System, kb: &mut KinBuf<T>) {
    forward_mode(sys, kb, false);
}

/// Like [`forward`] but `kb.h` per unit generalised speed (OpenSim's `u`):
/// for FreeJoint/BallJoint rotations the F axes themselves. Identical to
/// [`forward`] when no joint has angular-velocity speeds.
pub fn forward_speeds<T: Scalar>(sys: &System, kb: &mut KinBuf<T>) {
    forward_mode(sys, kb, sys.any_euler_speeds);
}

fn forward_mode<T: Scalar>(sys: &System, kb: &mut KinBuf<T>, speeds: bool) {
    for bi in 0..sys.bodies.len() {
        let b = &sys.bodies[bi];
        let x_gp = match b.parent {
            Some(p) => kb.x_gb[p.0],
            None => Pose::identity(),
        };
        let j = &b.joint;
        let range = j.dofs();
        let q = kb.q.get(range.clone()).unwrap_or(&[]);
        let h = kb.h.get_mut(range).unwrap_or(&mut []);
        kb.x_gb[bi] = joint_forward(j, &x_gp, q, h, speeds && j.euler_speeds);
    }
}

/// One joint: the child body's pose in ground from its parent's pose `x_gp`
/// and the joint's own free dofs `q` (`dof_count` values), and the joint's
/// motion subspace written into `h` (`dof_count` entries): per unit
/// coordinate rate, or with `w_speeds` the first three dofs per unit
/// angular velocity about F's X, Y, Z axes (FreeJoint/BallJoint speeds).
pub(crate) fn joint_forward<T: Scalar>(
    j: &Joint,
    x_gp: &Pose<T>,
    q: &[T],
    h: &mut [[Vector3<T>; 2]],
    w_speeds: bool,
) -> Pose<T> {
    let x_gf = x_gp.compose_c(&j.x_pf);
    let mut local = [[Vector3::zeros(); 2]; 6];
    let x_fm = joint_local(j, q, &mut local);
    if w_speeds {
        for (l, ax) in local.iter_mut().zip(&j.axes).take(3) {
            *l = [v3(&ax.unit), Vector3::zeros()];
        }
    }
    let x_gm = x_gf.compose(&x_fm);
    for (k, [w_f, v_f]) in local.iter().enumerate().take(j.dof_count) {
        let w = x_gf.r * w_f;
        let v = x_gf.r * v_f - w.cross(&x_gm.p);
        if let Some(h) = h.get_mut(k) {
            *h = [w, v];
        }
    }
    x_gm.compose_c(&j.x_mb)
}

/// The joint's own transform `X_FM` (mobilised frame in the parent-side
/// frame F) from its free dofs `q`, and per dof the angular and linear
/// velocity of M's origin in F axes per unit speed (`local[k] = [w_F, v_F]`;
/// rotations turn about M's origin, so `v_F` comes from the translation
/// axes only). Needs no parent pose: the structured statics tangent
/// differentiates it alone.
pub(crate) fn joint_local<T: Scalar>(
    j: &Joint,
    q: &[T],
    local: &mut [[Vector3<T>; 2]; 6],
) -> Pose<T> {
    let mut val = [T::zero(); 6];
    let mut der: [Option<(usize, T)>; 6] = [None; 6];
    for (ai, ax) in j.axes.iter().enumerate() {
        match &ax.source {
            AxisSource::Fixed(v) => val[ai] = T::c(*v),
            AxisSource::Dof(k, f) => {
                let qk = q.get(*k).copied().unwrap_or_else(T::zero);
                let (v, d) = f.value_slope(qk);
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
    // motion subspace in F
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
        if let Some(l) = local.get_mut(k) {
            *l = [w_f, v_f];
        }
    }
    Pose { r, p }
}

/// Joint-local part of the statics tangent, analytically: with the
/// subtree wrench held fixed in the joint's parent-side frame F (moment
/// `n_f` about F's origin and force `f_f`, F axes), the generalised force of
/// dof `k` is `w_k . (n_f - p_FM x f_f) + v_k . f_f` (`w_k`, `v_k` the
/// dof's rates from [`joint_local`]); `out[(k, m)]` receives its exact
/// derivative w.r.t. dof `m` (k, m < `dof_count`; the rest is zeroed).
/// Uses `d e_a / d val_b = e_b x e_a` for the rotation axes (b before a) and
/// the transform functions' second derivatives.
pub(crate) fn joint_local_tangent(
    j: &Joint,
    q: &[f64],
    n_f: &Vector3<f64>,
    f_f: &Vector3<f64>,
    out: &mut Matrix6<f64>,
) {
    *out = Matrix6::zeros();
    let n = j.dof_count.min(6);
    let mut val = [0.0f64; 6];
    let mut d1 = [0.0f64; 6];
    let mut d2 = [0.0f64; 6];
    let mut dof: [Option<usize>; 6] = [None; 6];
    for (ai, ax) in j.axes.iter().enumerate() {
        match &ax.source {
            AxisSource::Fixed(v) => val[ai] = *v,
            AxisSource::Dof(k, f) => {
                let qk = q.get(*k).copied().unwrap_or(0.0);
                let (v, d) = f.value_slope(Dual64::new(qk, 1.0));
                val[ai] = v.re;
                d1[ai] = d.re;
                d2[ai] = d.eps;
                dof[ai] = (*k < n).then_some(*k);
            }
        }
    }
    let is_zero = |ai: usize| matches!(j.axes[ai].source, AxisSource::Fixed(v) if v == 0.0);
    let mut e = [j.axes[0].unit; 3];
    let mut r = if is_zero(0) {
        Matrix3::identity()
    } else {
        rot_axis(&j.axes[0].unit, val[0])
    };
    e[1] = r * j.axes[1].unit;
    if !is_zero(1) {
        r *= rot_axis(&j.axes[1].unit, val[1]);
    }
    e[2] = r * j.axes[2].unit;
    let mut p = Vector3::zeros();
    let mut w = [Vector3::zeros(); 6];
    let mut v = [Vector3::zeros(); 6];
    for ai in 0..6 {
        if ai >= 3 && !is_zero(ai) {
            p += j.axes[ai].unit * val[ai];
        }
        if let Some(k) = dof[ai] {
            if ai < 3 {
                w[k] += e[ai] * d1[ai];
            } else {
                v[k] += j.axes[ai].unit * d1[ai];
            }
        }
    }
    let arm = n_f - p.cross(f_f);
    for ai in 0..6 {
        let Some(k) = dof[ai] else { continue };
        if ai < 3 {
            out[(k, k)] += d2[ai] * e[ai].dot(&arm);
            for bi in 0..ai {
                if let Some(m) = dof[bi] {
                    out[(k, m)] += d1[ai] * d1[bi] * e[bi].cross(&e[ai]).dot(&arm);
                }
            }
        } else {
            out[(k, k)] += d2[ai] * j.axes[ai].unit.dot(f_f);
        }
    }
    for k in 0..n {
        for m in 0..n {
            out[(k, m)] -= w[k].dot(&v[m].cross(f_f));
        }
    }
}

/// Cosine of the middle Euler angle below which the angle-rate map of a
/// FreeJoint/BallJoint is singular (gimbal lock at +-90 degrees).
const EULER_SINGULAR_COS: f64 = 1e-9;

/// `qdot = N(q) w` for body-fixed X-Y-Z angles `(q0, q1, .)` and the
/// angular velocity `w` in the outer (F) axes: the inverse of
/// `w = [x, Rx(q0) y, Rx(q0) Ry(q1) z] qdot`. None at gimbal lock.
pub(crate) fn euler_rates_from_w(q0: f64, q1: f64, w: &[f64; 3]) -> Option<[f64; 3]> {
    let (s0, c0) = q0.sin_cos();
    let (s1, c1) = q1.sin_cos();
    if c1.is_nan() || c1.abs() <= EULER_SINGULAR_COS {
        return None;
    }
    let r2 = (c0 * w[2] - s0 * w[1]) / c1;
    Some([w[0] - s1 * r2, c0 * w[1] + s0 * w[2], r2])
}

/// `w = E(q) qdot`, the angular velocity in F axes of body-fixed X-Y-Z
/// angle rates.
pub(crate) fn euler_w_from_rates(q0: f64, q1: f64, r: &[f64; 3]) -> [f64; 3] {
    let (s0, c0) = q0.sin_cos();
    let (s1, c1) = q1.sin_cos();
    [
        r[0] + s1 * r[2],
        c0 * r[1] - s0 * c1 * r[2],
        s0 * r[1] + c0 * c1 * r[2],
    ]
}

/// The generalised force on the angular-velocity speeds of a generalised
/// force `f` on the angle rates: `N^T f` (equal power). None at gimbal lock.
pub(crate) fn euler_force_to_speeds(q0: f64, q1: f64, f: &[f64; 3]) -> Option<[f64; 3]> {
    let (s0, c0) = q0.sin_cos();
    let (s1, c1) = q1.sin_cos();
    if c1.is_nan() || c1.abs() <= EULER_SINGULAR_COS {
        return None;
    }
    let g = (f[2] - s1 * f[0]) / c1;
    Some([f[0], c0 * f[1] - s0 * g, s0 * f[1] + c0 * g])
}

impl System {
    /// True when some generalised speeds are not coordinate rates
    /// (a FreeJoint or BallJoint: angular-velocity speeds as in OpenSim).
    pub fn has_angular_velocity_speeds(&self) -> bool {
        self.any_euler_speeds
    }

    /// True when free dof `i` is a rotational FreeJoint/BallJoint dof whose
    /// speed is an angular-velocity component rather than its rate.
    pub fn dof_speed_is_angular_velocity(&self, DofIndex(i): DofIndex) -> bool {
        self.dof_body
            .get(i)
            .and_then(|&b| self.bodies.get(b.0))
            .is_some_and(|b| b.joint.euler_speeds && i < b.joint.dof_start + 3)
    }

    fn check_qu(&self, q: &[f64], a: &[f64], out: &[f64]) -> Result<()> {
        self.check_q(q)?;
        if a.len() != q.len() || out.len() != q.len() || a.iter().any(|v| !v.is_finite()) {
            return Err(Error::invalid(
                "solver",
                "speeds and rates must be finite, one per free coordinate",
            ));
        }
        Ok(())
    }

    fn gimbal_error(&self, j: &Joint, q1: f64) -> Error {
        Error::solver(
            "solver",
            SolverError::JointGimbalLock {
                joint: j.name.clone(),
                angle: q1,
            },
        )
    }

    /// Coordinate rates from generalised speeds: `qdot = N(q) u` (the
    /// identity except for FreeJoint/BallJoint rotations, whose speeds are
    /// the angular velocity of M in F, F axes, as in OpenSim 4.6). Errors at
    /// a gimbal lock of such a joint.
    pub fn qdot(&self, q: &[f64], u: &[f64], qdot: &mut [f64]) -> Result<()> {
        self.check_qu(q, u, qdot)?;
        qdot.copy_from_slice(u);
        if !self.any_euler_speeds {
            return Ok(());
        }
        for b in &self.bodies {
            let j = &b.joint;
            if !j.euler_speeds {
                continue;
            }
            let s = j.dof_start;
            let w = [u[s], u[s + 1], u[s + 2]];
            let r = euler_rates_from_w(q[s], q[s + 1], &w)
                .ok_or_else(|| self.gimbal_error(j, q[s + 1]))?;
            qdot[s..s + 3].copy_from_slice(&r);
        }
        Ok(())
    }

    /// Generalised speeds from coordinate rates (the inverse of
    /// [`System::qdot`]; defined at every q).
    pub fn speeds_from_qdot(&self, q: &[f64], qdot: &[f64], u: &mut [f64]) -> Result<()> {
        self.check_qu(q, qdot, u)?;
        u.copy_from_slice(qdot);
        for b in &self.bodies {
            let j = &b.joint;
            if !j.euler_speeds {
                continue;
            }
            let s = j.dof_start;
            let r = [qdot[s], qdot[s + 1], qdot[s + 2]];
            u[s..s + 3].copy_from_slice(&euler_w_from_rates(q[s], q[s + 1], &r));
        }
        Ok(())
    }

    /// Turn a generalised force on the coordinate rates into the one on the
    /// generalised speeds, in place: `f <- N(q)^T f` (equal power).
    pub(crate) fn rate_forces_to_speeds(&self, q: &[f64], f: &mut [f64]) -> Result<()> {
        for b in &self.bodies {
            let j = &b.joint;
            if !j.euler_speeds {
                continue;
            }
            let s = j.dof_start;
            let r = euler_force_to_speeds(q[s], q[s + 1], &[f[s], f[s + 1], f[s + 2]])
                .ok_or_else(|| self.gimbal_error(j, q[s + 1]))?;
            f[s..s + 3].copy_from_slice(&r);
        }
        Ok(())
    }
}
