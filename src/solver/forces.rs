//! Applied forces as body wrenches (moment about the ground origin, force;
//! ground axes), generic over the scalar: gravity, bushings (OpenSim 4.6
//! BushingForce and its function- and expression-based kin, see `law`), external loads (moments, point forces, follower loads), and
//! their projection onto the generalised coordinates.

use super::kinematics;
use super::scalar::{body_xyz, v3, Scalar};
use super::spec::{Load, LoadFrame};
use super::system::{BodyIndex, Bushing, Pose, System};
use super::workspace::KinBuf;
use crate::error::{Error, Result, SolverError};
use nalgebra::{Matrix3, Vector3};

/// Largest |middle angle| of a bushing's X-Y-Z deflection accepted (rad):
/// beyond it the angle-rate map is (nearly) singular.
pub const GIMBAL_LIMIT: f64 = 89.0 * std::f64::consts::PI / 180.0;

/// A bushing whose middle deflection angle reached the gimbal-lock limit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GimbalLock {
    /// Index of the bushing in [`System`] order.
    pub bushing: usize,
    /// The bushing's middle (Y) deflection angle when the limit was hit (rad).
    pub angle: f64,
}

impl GimbalLock {
    /// The typed solver error naming the bushing, with the angle and the limit in degrees.
    pub fn to_error(self, sys: &System) -> Error {
        let name = sys
            .bushings
            .get(self.bushing)
            .map(|b| b.name.as_str())
            .unwrap_or("?");
        Error::solver(
            format!("bushing '{name}'"),
            SolverError::GimbalLock {
                angle_deg: self.angle.to_degrees(),
                limit_deg: GIMBAL_LIMIT.to_degrees(),
            },
        )
    }
}

/// A load resolved against a system.
#[derive(Debug, Clone)]
pub(crate) enum Resolved {
    Moment {
        body: BodyIndex,
        vec: Vector3<f64>,
        frame: LoadFrame,
    },
    Force {
        body: BodyIndex,
        point: Vector3<f64>,
        vec: Vector3<f64>,
        frame: LoadFrame,
    },
    /// Pair of guide points: `upper` body point pushed towards `lower` body point.
    Follower {
        upper: BodyIndex,
        upper_pt: Vector3<f64>,
        lower: Option<BodyIndex>,
        lower_pt: Vector3<f64>,
        magnitude: f64,
    },
}

/// Loads resolved against a system (body names checked, follower guide
/// points placed in body coordinates). Valid for every system that shares
/// that system's structure (see [`super::SystemId`]): a variant with moved
/// joint frames keeps the guide points where they were placed on the
/// bodies, as the physical guides of a rig stay on the vertebrae. The empty
/// set fits every system.
#[derive(Debug, Clone, Default)]
pub struct LoadSet {
    pub(crate) items: Vec<Resolved>,
    /// Structure id of the system the loads were resolved for.
    pub(crate) resolved_for: Option<u64>,
}

impl LoadSet {
    /// No load.
    pub fn empty() -> Self {
        LoadSet::default()
    }
}

impl System {
    /// Refuse loads resolved for a system of another structure.
    pub(crate) fn check_loads(&self, loads: &LoadSet) -> Result<()> {
        match loads.resolved_for {
            Some(structure) if structure != self.id.structure => Err(Error::invalid(
                "solver",
                "the loads were prepared for another system (prepare them with this system's prepare_loads)",
            )),
            _ => Ok(()),
        }
    }
}

fn finite3(v: &Vector3<f64>) -> bool {
    v.iter().all(|x| x.is_finite())
}

impl System {
    /// Resolve loads: unknown bodies, ground and non-finite numbers are errors.
    pub fn prepare_loads(&self, loads: &[Load]) -> Result<LoadSet> {
        let find = |name: &str, what: &str| -> Result<BodyIndex> {
            self.body_index(name).ok_or_else(|| {
                let known: Vec<&str> = self.body_names().collect();
                Error::invalid(
                    format!("load {what}"),
                    format!(
                        "no body named '{name}' in the model (bodies: {})",
                        known.join(", ")
                    ),
                )
            })
        };
        let mut items = Vec::new();
        for l in loads {
            match l {
                Load::Moment { body, vec, frame } => {
                    if !finite3(vec) {
                        return Err(Error::invalid("load moment", "moment is not finite"));
                    }
                    items.push(Resolved::Moment {
                        body: find(body, "moment")?,
                        vec: *vec,
                        frame: *frame,
                    });
                }
                Load::Force {
                    body,
                    point_in_body,
                    vec,
                    frame,
                } => {
                    if !finite3(vec) || !finite3(point_in_body) {
                        return Err(Error::invalid("load force", "force or point is not finite"));
                    }
                    items.push(Resolved::Force {
                        body: find(body, "force")?,
                        point: *point_in_body,
                        vec: *vec,
                        frame: *frame,
                    });
                }
                Load::Follower {
                    from_body,
                    to_body,
                    magnitude,
                } => {
                    if !magnitude.is_finite() {
                        return Err(Error::invalid("follower load", "magnitude is not finite"));
                    }
                    if *magnitude == 0.0 {
                        continue;
                    }
                    let a = find(from_body, "follower (fixed body)")?;
                    let b = find(to_body, "follower (loaded body)")?;
                    self.follower_pairs(a, b, *magnitude, &mut items);
                }
            }
        }
        Ok(LoadSet {
            items,
            resolved_for: Some(self.id.structure),
        })
    }

    /// Guide-point pairs of every joint on the tree path between a and b,
    /// placed in the default pose.
    fn follower_pairs(&self, a: BodyIndex, b: BodyIndex, magnitude: f64, out: &mut Vec<Resolved>) {
        let pa = self.path_to_root(a);
        let pb = self.path_to_root(b);
        // joints on the path: child bodies below the lowest common ancestor
        let mut joints: Vec<BodyIndex> = Vec::new();
        for &x in &pa {
            if !pb.contains(&x) {
                joints.push(x);
            }
        }
        for &x in &pb {
            if !pa.contains(&x) {
                joints.push(x);
            }
        }
        joints.sort_unstable();
        let mut kb = KinBuf::<f64>::new(self);
        kb.q.copy_from_slice(self.default_q().as_slice());
        kinematics::forward(self, &mut kb);
        for c in joints {
            let body = &self.bodies[c.0];
            let x_gp = match body.parent {
                Some(p) => kb.x_gb[p.0],
                None => Pose::identity(),
            };
            let x_gf = x_gp.compose_c(&body.joint.x_pf);
            let x_gm = kb.x_gb[c.0].compose_c(&body.joint.x_bm);
            let y = x_gf.r.column(1).into_owned();
            let centre = x_gm.p;
            let up_g = centre + y * 0.010;
            let lo_g = centre - y * 0.010;
            let xc = kb.x_gb[c.0];
            let upper_pt = xc.r.transpose() * (up_g - xc.p);
            let lower_pt = x_gp.r.transpose() * (lo_g - x_gp.p);
            out.push(Resolved::Follower {
                upper: c,
                upper_pt,
                lower: body.parent,
                lower_pt,
                magnitude,
            });
        }
    }
}

#[inline]
fn add_wrench<T: Scalar>(
    w: &mut [[Vector3<T>; 2]],
    body: Option<BodyIndex>,
    point: &Vector3<T>,
    f: &Vector3<T>,
    m: &Vector3<T>,
) {
    if let Some(b) = body {
        if let Some(wb) = w.get_mut(b.0) {
            wb[0] += m + point.cross(f);
            wb[1] += f;
        }
    }
}

/// Pose of a frame fixed in a body (None = ground).
#[inline]
pub(crate) fn frame_pose<T: Scalar>(
    kb: &KinBuf<T>,
    body: Option<BodyIndex>,
    x: &Pose<f64>,
) -> Pose<T> {
    match body {
        Some(b) => kb.x_gb[b.0].compose_c(x),
        None => Pose {
            r: x.r.map(T::c),
            p: v3(&x.p),
        },
    }
}

/// Bushing deflection: (X_G1, X_G2, rotational angles, translation in frame 1).
#[inline]
pub(crate) fn bushing_deflection<T: Scalar>(
    b: &Bushing,
    kb: &KinBuf<T>,
) -> (Pose<T>, Pose<T>, Vector3<T>, Vector3<T>) {
    let x1 = frame_pose(kb, b.body1, &b.x_b1);
    let x2 = frame_pose(kb, b.body2, &b.x_b2);
    let r_fm = x1.r.transpose() * x2.r;
    let qr = body_xyz(&r_fm);
    let qt = x1.r.transpose() * (x2.p - x1.p);
    (x1, x2, qr, qt)
}

/// Transpose of the angle-rate map N (q' = N w, w in frame 2) times `f`.
#[inline]
pub(crate) fn n_transpose_mul<T: Scalar>(qr: &Vector3<T>, f: &Vector3<T>) -> Vector3<T> {
    let (s1, c1) = qr.y.sin_cos();
    let (s2, c2) = qr.z.sin_cos();
    let n = Matrix3::new(
        c2 / c1,
        -s2 / c1,
        T::zero(),
        s2,
        c2,
        T::zero(),
        -s1 * c2 / c1,
        s1 * s2 / c1,
        T::one(),
    );
    n.transpose() * f
}

/// Apply the generalised bushing force `(f_r, f_t)` as body wrenches.
#[inline]
pub(crate) fn bushing_apply<T: Scalar>(
    b: &Bushing,
    x1: &Pose<T>,
    x2: &Pose<T>,
    qr: &Vector3<T>,
    fr: &Vector3<T>,
    ft: &Vector3<T>,
    w: &mut [[Vector3<T>; 2]],
) {
    let m2 = x2.r * n_transpose_mul(qr, fr);
    let f2 = x1.r * ft;
    add_wrench(w, b.body2, &x2.p, &f2, &m2);
    add_wrench(w, b.body1, &x2.p, &(-f2), &(-m2));
}

/// Fill `kb.w` with the wrenches of gravity, bushings (stiffness only: the
/// static case) and loads at the current `kb.x_gb`.
pub(crate) fn static_wrenches<T: Scalar>(
    sys: &System,
    loads: &LoadSet,
    kb: &mut KinBuf<T>,
) -> Result<(), GimbalLock> {
    for w in kb.w.iter_mut() {
        *w = [Vector3::zeros(), Vector3::zeros()];
    }
    gravity_wrenches(sys, kb);
    for (i, b) in sys.bushings.iter().enumerate() {
        if b.fast.is_some() {
            continue;
        }
        let (x1, x2, qr, qt) = bushing_deflection(b, kb);
        if qr.y.re().abs() >= GIMBAL_LIMIT || !qr.y.re().is_finite() {
            return Err(GimbalLock {
                bushing: i,
                angle: qr.y.re(),
            });
        }
        let g = b.law.g(&[qr.x, qr.y, qr.z, qt.x, qt.y, qt.z]);
        let fr = Vector3::new(-g[0], -g[1], -g[2]);
        let ft = Vector3::new(-g[3], -g[4], -g[5]);
        bushing_apply(b, &x1, &x2, &qr, &fr, &ft, &mut kb.w);
    }
    load_wrenches(loads, kb);
    Ok(())
}

pub(crate) fn gravity_wrenches<T: Scalar>(sys: &System, kb: &mut KinBuf<T>) {
    if sys.gravity == Vector3::zeros() {
        return;
    }
    let g: Vector3<T> = v3(&sys.gravity);
    for (bi, b) in sys.bodies.iter().enumerate() {
        if b.mass == 0.0 {
            continue;
        }
        let c = kb.x_gb[bi].point(&b.com);
        let f = g * T::c(b.mass);
        add_wrench(&mut kb.w, Some(BodyIndex(bi)), &c, &f, &Vector3::zeros());
    }
}

pub(crate) fn load_wrenches<T: Scalar>(loads: &LoadSet, kb: &mut KinBuf<T>) {
    for l in &loads.items {
        match l {
            Resolved::Moment { body, vec, frame } => {
                let m = match frame {
                    LoadFrame::Ground => v3(vec),
                    LoadFrame::Body => kb.x_gb[body.0].r * v3::<T>(vec),
                };
                add_wrench(
                    &mut kb.w,
                    Some(*body),
                    &Vector3::zeros(),
                    &Vector3::zeros(),
                    &m,
                );
            }
            Resolved::Force {
                body,
                point,
                vec,
                frame,
            } => {
                let x = kb.x_gb[body.0];
                let f = match frame {
                    LoadFrame::Ground => v3(vec),
                    LoadFrame::Body => x.r * v3::<T>(vec),
                };
                let p = x.point(point);
                add_wrench(&mut kb.w, Some(*body), &p, &f, &Vector3::zeros());
            }
            Resolved::Follower {
                upper,
                upper_pt,
                lower,
                lower_pt,
                magnitude,
            } => {
                let pu = kb.x_gb[upper.0].point(upper_pt);
                let pl = match lower {
                    Some(l) => kb.x_gb[l.0].point(lower_pt),
                    None => v3(lower_pt),
                };
                let d = pu - pl;
                let n = d.norm();
                if n.re() <= 0.0 {
                    continue;
                }
                let f = d * (T::c(-*magnitude) / n);
                add_wrench(&mut kb.w, Some(*upper), &pu, &f, &Vector3::zeros());
                add_wrench(&mut kb.w, *lower, &pl, &(-f), &Vector3::zeros());
            }
        }
    }
}

/// Wrap an angle into (-pi, pi] (shifting by a constant keeps derivatives).
#[inline]
pub(crate) fn wrap<T: Scalar>(a: T) -> T {
    let r = a.re();
    if r > -std::f64::consts::PI && r <= std::f64::consts::PI {
        return a;
    }
    let tau = 2.0 * std::f64::consts::PI;
    a - T::c(tau * ((r + std::f64::consts::PI) / tau).floor())
}

/// Add the generalised forces of fast-path bushings (on their joint's own
/// XYZ frames): `-(g(q) + C u)` with the angles as the bushing reads them.
/// `u` = None for statics. Falls back to gimbal-lock detection like the
/// general path.
pub(crate) fn add_fast_bushings<T: Scalar>(
    sys: &System,
    q: &[T],
    u: Option<&[f64]>,
    tau: &mut [T],
) -> Result<(), GimbalLock> {
    for (i, b) in sys.bushings.iter().enumerate() {
        let Some(s) = b.fast else { continue };
        let q1 = q[s + 1].re();
        if q1.abs() >= GIMBAL_LIMIT || !q1.is_finite() {
            return Err(GimbalLock {
                bushing: i,
                angle: q1,
            });
        }
        let d: [T; 6] = std::array::from_fn(|k| {
            if k == 0 || k == 2 {
                wrap(q[s + k])
            } else {
                q[s + k]
            }
        });
        let g = b.law.g(&d);
        for k in 0..6 {
            let mut f = -g[k];
            if let Some(u) = u {
                f -= T::c(b.c[k] * u[s + k]);
            }
            tau[s + k] += f;
        }
    }
    Ok(())
}

/// Project body wrenches onto the free dofs: `kb.tau = H^T W_subtree`.
/// Consumes `kb.w` (subtree sums accumulate in place).
pub(crate) fn project<T: Scalar>(sys: &System, kb: &mut KinBuf<T>) {
    for bi in (0..sys.bodies.len()).rev() {
        let b = &sys.bodies[bi];
        let wb = kb.w[bi];
        let j = &b.joint;
        for k in j.dofs() {
            let h = kb.h[k];
            kb.tau[k] = h[0].dot(&wb[0]) + h[1].dot(&wb[1]);
        }
        if let Some(p) = b.parent {
            kb.w[p.0][0] += wb[0];
            kb.w[p.0][1] += wb[1];
        }
    }
}
