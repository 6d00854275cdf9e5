//! The immutable, validated [`System`] compiled from a [`SystemSpec`]
//! (bodies in parent-before-child order, joints lowered to six function-based
//! axes, free degrees of freedom numbered joint by joint), its typed indices,
//! and its parameter variants (`with_*`: new systems, never a mutation). Its
//! scratch data is the `Workspace` (`workspace.rs`).

use super::law::Law;
use super::scalar::Scalar;
use super::spec::{
    BushingModel, CoordinateSpec, FrameSpec, Function, JointKind, JointSpec, SystemSpec,
    TransformAxis,
};
use crate::error::{Error, Result};
use nalgebra::{DVector, Isometry3, Matrix3, Vector3};
use std::sync::atomic::{AtomicU64, Ordering};

/// A rigid transform as rotation matrix + translation, generic scalar.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose<T: Scalar> {
    /// Rotation matrix from this frame's axes to the outer frame's.
    pub r: Matrix3<T>,
    /// Origin of this frame in the outer frame (m).
    pub p: Vector3<T>,
}

impl<T: Scalar> Pose<T> {
    /// The identity transform.
    pub fn identity() -> Self {
        Pose {
            r: Matrix3::identity(),
            p: Vector3::zeros(),
        }
    }
    /// `self * other`.
    #[inline]
    pub fn compose(&self, o: &Pose<T>) -> Pose<T> {
        Pose {
            r: self.r * o.r,
            p: self.p + self.r * o.p,
        }
    }
    /// `self * other` with a constant `other`.
    #[inline]
    pub fn compose_c(&self, o: &Pose<f64>) -> Pose<T> {
        let r = Matrix3::from_fn(|i, j| {
            self.r[(i, 0)] * T::c(o.r[(0, j)])
                + self.r[(i, 1)] * T::c(o.r[(1, j)])
                + self.r[(i, 2)] * T::c(o.r[(2, j)])
        });
        let p = self.p + self.r * super::scalar::v3::<T>(&o.p);
        Pose { r, p }
    }
    /// Map a point given in this frame to the outer frame.
    #[inline]
    pub fn point(&self, x: &Vector3<f64>) -> Vector3<T> {
        self.p + self.r * super::scalar::v3::<T>(x)
    }
    /// Value parts.
    pub fn re(&self) -> Pose<f64> {
        Pose {
            r: self.r.map(|x| x.re()),
            p: self.p.map(|x| x.re()),
        }
    }
}

impl Pose<f64> {
    /// The same transform as a rotation matrix and translation.
    fn from_isometry(x: &Isometry3<f64>) -> Self {
        Pose {
            r: *x.rotation.to_rotation_matrix().matrix(),
            p: x.translation.vector,
        }
    }
    /// The inverse transform.
    pub fn inverse(&self) -> Self {
        let rt = self.r.transpose();
        Pose {
            r: rt,
            p: -(rt * self.p),
        }
    }
}

/// Index of a body in system order (every parent before its children):
/// the index of the bodies of a [`System`] and of [`KinBuf::x_gb`](super::workspace::KinBuf::x_gb). The
/// bodies of a [`SystemSpec`] are numbered in spec order with plain
/// `usize`; [`System::new`] maps one order to the other.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize)]
#[serde(transparent)]
pub struct BodyIndex(pub usize);

/// Index of a free degree of freedom: the position in the vectors `q`,
/// `u` and `tau` of a [`System`]. The coordinates of a [`SystemSpec`] are
/// numbered in spec order with plain `usize` (a locked coordinate has no
/// degree of freedom).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct DofIndex(pub usize);

/// Index of a bushing in the order of [`System::bushing_names`] (the order
/// of the spec's bushings).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize)]
#[serde(transparent)]
pub struct BushingIndex(pub usize);

/// Where an axis' value comes from.
#[derive(Debug, Clone)]
pub(crate) enum AxisSource {
    /// Constant value (no coordinate, or a locked one).
    Fixed(f64),
    /// The joint's `k`-th degree of freedom through `function`.
    Dof(usize, Function),
}

/// A joint axis after lowering.
#[derive(Debug, Clone)]
pub(crate) struct Axis {
    pub unit: Vector3<f64>,
    pub source: AxisSource,
}

/// A compiled joint (the one whose child is the body it is stored with).
#[derive(Debug, Clone)]
pub(crate) struct Joint {
    pub name: String,
    pub x_pf: Pose<f64>,
    pub x_mb: Pose<f64>,
    pub x_bm: Pose<f64>,
    pub axes: [Axis; 6],
    /// First free dof of this joint in the dof vector.
    pub dof_start: usize,
    /// Number of free dofs.
    pub dof_count: usize,
    /// OpenSim FreeJoint/BallJoint speeds: the joint's first three dofs are
    /// body-fixed X-Y-Z angles whose generalised speeds are the angular
    /// velocity of M in F, F axes (`qdot = N(q) u`); false: `u = qdot`.
    pub euler_speeds: bool,
}

impl Joint {
    /// The joint's free dofs: their positions in `q`, `u` and `tau`.
    pub(crate) fn dofs(&self) -> std::ops::Range<usize> {
        self.dof_start..self.dof_start + self.dof_count
    }
}

/// A compiled body.
#[derive(Debug, Clone)]
pub(crate) struct Body {
    pub name: String,
    pub parent: Option<BodyIndex>,
    pub mass: f64,
    pub com: Vector3<f64>,
    pub inertia: Matrix3<f64>,
    pub joint: Joint,
}

/// A compiled bushing.
#[derive(Debug, Clone)]
pub(crate) struct Bushing {
    pub name: String,
    pub body1: Option<BodyIndex>,
    pub x_b1: Pose<f64>,
    pub body2: Option<BodyIndex>,
    pub x_b2: Pose<f64>,
    pub model: BushingModel,
    /// Compiled stiffness law `g(q)`.
    pub law: Law,
    /// Diagonal damping.
    pub c: [f64; 6],
    /// Fast path: the bushing sits on the frames of a joint whose six axes
    /// are X, Y, Z rotations then X, Y, Z translations, each the identity
    /// function of its own free dof; then the deflection is those dofs and
    /// its generalised force is exactly `-(g(q) + C u)` on them (first dof
    /// index stored here).
    pub fast: Option<usize>,
}

/// Identity of a built [`System`]: its structure (bodies, joints, degrees
/// of freedom: what a [`Workspace`](super::Workspace) is sized for and a
/// [`LoadSet`](super::LoadSet) is resolved against), its joint and bushing
/// frames, and its force laws. A factorised tangent is valid only for the
/// identity it was computed with. Frame and law ids are process-unique and
/// never written out.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SystemId {
    pub(crate) structure: u64,
    pub(crate) frames: u64,
    pub(crate) laws: u64,
}

static NEXT_ID: AtomicU64 = AtomicU64::new(1);

/// A process-unique id (equality checks only).
fn fresh_id() -> u64 {
    NEXT_ID.fetch_add(1, Ordering::Relaxed)
}

impl SystemId {
    /// A new identity: the structure is a fingerprint of the bodies, their
    /// tree and degrees of freedom (systems built separately from the same
    /// structure may share workspaces and loads); frames and laws are new.
    fn new(bodies: &[Body], n_dofs: usize, n_bushings: usize) -> Self {
        use std::hash::{Hash, Hasher};
        let mut h = std::collections::hash_map::DefaultHasher::new();
        (n_dofs, n_bushings, bodies.len()).hash(&mut h);
        for b in bodies {
            (&b.name, b.parent, b.joint.dof_start, b.joint.dof_count).hash(&mut h);
        }
        let id = fresh_id();
        SystemId {
            structure: h.finish(),
            frames: id,
            laws: id,
        }
    }
}

/// The immutable multibody system: never changed once built. Parameter
/// variants (bushing laws, joint frames) are new systems made by
/// [`System::with_bushing_model`], [`System::with_bushing_stiffness`] and
/// [`System::with_bushing_joint_frames`]; they share the structure, so
/// workspaces and loads can be reused across them.
#[derive(Debug, Clone)]
pub struct System {
    pub(crate) id: SystemId,
    pub(crate) bodies: Vec<Body>,
    pub(crate) coords: Vec<CoordinateSpec>,
    /// spec coordinate -> free dof index (None when locked or unused)
    pub(crate) coord_dof: Vec<Option<DofIndex>>,
    /// free dof -> spec coordinate
    pub(crate) dof_coord: Vec<usize>,
    /// free dof -> owning system body
    pub(crate) dof_body: Vec<BodyIndex>,
    /// dof drives a rotation axis
    pub(crate) dof_rotational: Vec<bool>,
    pub(crate) bushings: Vec<Bushing>,
    pub(crate) gravity: Vector3<f64>,
    /// Some joint has angular-velocity speeds (`Joint::euler_speeds`).
    pub(crate) any_euler_speeds: bool,
}

fn lower_joint(kind: &JointKind) -> [TransformAxis; 6] {
    let x = Vector3::x();
    let y = Vector3::y();
    let z = Vector3::z();
    let fixed = |a| TransformAxis::fixed(a);
    match kind {
        JointKind::Weld => [fixed(x), fixed(y), fixed(z), fixed(x), fixed(y), fixed(z)],
        JointKind::Pin { coord } => [
            TransformAxis::identity(z, *coord),
            fixed(x),
            fixed(y),
            fixed(x),
            fixed(y),
            fixed(z),
        ],
        JointKind::Universal { coords } => [
            TransformAxis::identity(x, coords[0]),
            TransformAxis::identity(y, coords[1]),
            fixed(z),
            fixed(x),
            fixed(y),
            fixed(z),
        ],
        JointKind::Slider { coord } => [
            fixed(x),
            fixed(y),
            fixed(z),
            TransformAxis::identity(x, *coord),
            fixed(y),
            fixed(z),
        ],
        JointKind::Free { coords } => [
            TransformAxis::identity(x, coords[0]),
            TransformAxis::identity(y, coords[1]),
            TransformAxis::identity(z, coords[2]),
            TransformAxis::identity(x, coords[3]),
            TransformAxis::identity(y, coords[4]),
            TransformAxis::identity(z, coords[5]),
        ],
        JointKind::Ball { coords } => [
            TransformAxis::identity(x, coords[0]),
            TransformAxis::identity(y, coords[1]),
            TransformAxis::identity(z, coords[2]),
            fixed(x),
            fixed(y),
            fixed(z),
        ],
        JointKind::Custom { axes } => (**axes).clone(),
    }
}

/// True when a lowered joint of kind Free or Ball keeps OpenSim's
/// angular-velocity speeds: its three rotation axes are X, Y, Z driven one
/// to one by its dofs 0, 1, 2. With a locked rotation coordinate (a
/// constraint on the angular velocity in OpenSim) the remaining dofs fall
/// back to coordinate-rate speeds.
fn has_euler_speeds(kind: &JointKind, axes: &[Axis; 6]) -> bool {
    if !matches!(kind, JointKind::Free { .. } | JointKind::Ball { .. }) {
        return false;
    }
    axes.iter().take(3).enumerate().all(|(ai, ax)| {
        matches!(&ax.source, AxisSource::Dof(k, Function::Linear { slope, intercept })
            if *k == ai && *slope == 1.0 && *intercept == 0.0)
    })
}

fn check_finite_pose(x: &Isometry3<f64>) -> bool {
    x.translation.vector.iter().all(|v| v.is_finite())
        && x.rotation.coords.iter().all(|v| v.is_finite())
}

/// Context of the errors of [`System::new`].
const CTX: &str = "system";

/// The joint of each spec body (the one whose child it is), checking the
/// joints' body indices, closed loops and finite frames.
fn joint_of_bodies(spec: &SystemSpec) -> Result<Vec<Option<usize>>> {
    let nb = spec.bodies.len();
    let mut joint_of = vec![None; nb];
    for (ji, j) in spec.joints.iter().enumerate() {
        if j.child >= nb {
            return Err(Error::invalid(
                CTX,
                format!(
                    "joint '{}': child body index {} out of range",
                    j.name, j.child
                ),
            ));
        }
        if let Some(p) = j.parent.filter(|&p| p >= nb) {
            return Err(Error::invalid(
                CTX,
                format!("joint '{}': parent body index {p} out of range", j.name),
            ));
        }
        if joint_of[j.child].is_some() {
            return Err(Error::invalid(
                CTX,
                format!("body '{}' is the child of more than one joint (closed loops are not supported)", spec.bodies[j.child].name),
            ));
        }
        if !check_finite_pose(&j.x_pf) || !check_finite_pose(&j.x_bm) {
            return Err(Error::invalid(
                CTX,
                format!("joint '{}': frame transform is not finite", j.name),
            ));
        }
        joint_of[j.child] = Some(ji);
    }
    Ok(joint_of)
}

/// Every body has a joint and finite mass properties (mass >= 0).
fn check_bodies(spec: &SystemSpec, joint_of: &[Option<usize>]) -> Result<()> {
    for (bi, b) in spec.bodies.iter().enumerate() {
        if joint_of[bi].is_none() {
            return Err(Error::invalid(
                CTX,
                format!(
                    "body '{}' has no joint to its parent (every body needs one)",
                    b.name
                ),
            ));
        }
        if !b.mass.is_finite()
            || b.mass < 0.0
            || !b.com.iter().all(|v| v.is_finite())
            || !b.inertia.iter().all(|v| v.is_finite())
        {
            return Err(Error::invalid(
                CTX,
                format!(
                    "body '{}': mass, centre of mass and inertia must be finite (mass >= 0)",
                    b.name
                ),
            ));
        }
    }
    Ok(())
}

/// Spec body indices with every parent before its children. The order is
/// that of repeated sweeps over the bodies in spec order, each placing the
/// bodies whose parent is placed (so a spec already in parent-first order
/// keeps its order): a body is placed in its parent's sweep when it comes
/// after its parent in the spec, else in the next one. Computed from the
/// tree in O(n log n); bodies never reached hang on a cycle.
fn topological_order(spec: &SystemSpec, joint_of: &[Option<usize>]) -> Result<Vec<usize>> {
    let nb = spec.bodies.len();
    // children of ground (index nb) and of every body
    let mut children: Vec<Vec<usize>> = vec![Vec::new(); nb + 1];
    for (bi, j) in joint_of.iter().enumerate() {
        let parent = j.and_then(|ji| spec.joints[ji].parent).unwrap_or(nb);
        children[parent].push(bi);
    }
    // sweep number of every body reachable from ground
    let mut sweep: Vec<Option<usize>> = vec![None; nb];
    let mut stack: Vec<(usize, usize)> = children[nb].iter().map(|&c| (c, 1)).collect();
    while let Some((b, s)) = stack.pop() {
        sweep[b] = Some(s);
        for &c in &children[b] {
            stack.push((c, s + usize::from(b > c)));
        }
    }
    let mut order: Vec<usize> = (0..nb).filter(|&b| sweep[b].is_some()).collect();
    order.sort_by_key(|&b| (sweep[b], b));
    if order.len() < nb {
        let stuck: Vec<&str> = (0..nb)
            .filter(|&i| sweep[i].is_none())
            .map(|i| spec.bodies[i].name.as_str())
            .collect();
        return Err(Error::invalid(
            CTX,
            format!(
                "bodies not connected to ground (cycle in the joint tree): {}",
                stuck.join(", ")
            ),
        ));
    }
    Ok(order)
}

/// Every coordinate default is finite.
fn check_coordinate_defaults(spec: &SystemSpec) -> Result<()> {
    for (ci, c) in spec.coordinates.iter().enumerate() {
        if !c.default.is_finite() {
            return Err(Error::invalid(
                CTX,
                format!("coordinate '{}' (#{ci}): default value not finite", c.name),
            ));
        }
    }
    Ok(())
}

/// Bodies in system order with their lowered joints, and the numbering of
/// the free dofs.
struct Lowered {
    bodies: Vec<Body>,
    coord_dof: Vec<Option<DofIndex>>,
    dof_coord: Vec<usize>,
    dof_body: Vec<BodyIndex>,
    dof_rotational: Vec<bool>,
}

impl Lowered {
    /// The axis source of a transform axis driven by coordinate `c` of the
    /// joint of system body `si` (`local`: the spec coordinates of this
    /// joint's dofs so far), numbering a new dof when `c` is new and free.
    #[allow(clippy::too_many_arguments)] // the joint, the axis, and the dof numbering state
    fn axis_source(
        &mut self,
        spec: &SystemSpec,
        js: &JointSpec,
        ai: usize,
        ta: &TransformAxis,
        owner: &mut [Option<BodyIndex>],
        si: BodyIndex,
        local: &mut Vec<usize>,
    ) -> Result<AxisSource> {
        let Some(c) = ta.coord else {
            return Ok(AxisSource::Fixed(ta.function.value_slope(0.0f64).0));
        };
        let Some(cs) = spec.coordinates.get(c) else {
            return Err(Error::invalid(
                CTX,
                format!(
                    "joint '{}': transform axis {} refers to coordinate #{c} which does not exist",
                    js.name,
                    ai + 1
                ),
            ));
        };
        match owner[c] {
            Some(o) if o != si => {
                return Err(Error::invalid(
                    CTX,
                    format!("coordinate '{}' is used by more than one joint", cs.name),
                ));
            }
            _ => owner[c] = Some(si),
        }
        if cs.locked {
            return Ok(AxisSource::Fixed(ta.function.value_slope(cs.default).0));
        }
        let dof_start = self.dof_coord.len() - local.len();
        let k = match local.iter().position(|&x| x == c) {
            Some(k) => k,
            None => {
                local.push(c);
                self.coord_dof[c] = Some(DofIndex(self.dof_coord.len()));
                self.dof_coord.push(c);
                self.dof_body.push(si);
                self.dof_rotational.push(false);
                local.len() - 1
            }
        };
        if ai < 3 {
            if let Some(r) = self.dof_rotational.get_mut(dof_start + k) {
                *r = true;
            }
        }
        Ok(AxisSource::Dof(k, ta.function.clone()))
    }
}

/// The six validated axes of a joint spec, their sources numbered into `lw`.
fn lower_axes(
    spec: &SystemSpec,
    js: &JointSpec,
    lw: &mut Lowered,
    owner: &mut [Option<BodyIndex>],
    si: BodyIndex,
    local: &mut Vec<usize>,
) -> Result<[Axis; 6]> {
    let mut axes: Vec<Axis> = Vec::with_capacity(6);
    for (ai, ta) in lower_joint(&js.kind).iter().enumerate() {
        let n = ta.axis.norm();
        if !n.is_finite() || n <= 1e-12 {
            return Err(Error::invalid(
                CTX,
                format!(
                    "joint '{}': transform axis {} has zero or non-finite direction",
                    js.name,
                    ai + 1
                ),
            ));
        }
        ta.function.validate().map_err(|m| {
            Error::invalid(
                CTX,
                format!("joint '{}': transform axis {}: {m}", js.name, ai + 1),
            )
        })?;
        let source = lw.axis_source(spec, js, ai, ta, owner, si, local)?;
        axes.push(Axis {
            unit: ta.axis / n,
            source,
        });
    }
    axes.try_into()
        .map_err(|_| Error::invalid(CTX, format!("joint '{}': needs six axes", js.name)))
}

/// Compile the bodies in system order: each body's joint lowered to six
/// axes, free dofs numbered joint by joint.
fn lower_bodies(
    spec: &SystemSpec,
    joint_of: &[Option<usize>],
    order: &[usize],
    body_map: &[BodyIndex],
) -> Result<Lowered> {
    let mut lw = Lowered {
        bodies: Vec::with_capacity(order.len()),
        coord_dof: vec![None; spec.coordinates.len()],
        dof_coord: Vec::new(),
        dof_body: Vec::new(),
        dof_rotational: Vec::new(),
    };
    let mut owner: Vec<Option<BodyIndex>> = vec![None; spec.coordinates.len()];
    for (si, &bi) in order.iter().enumerate() {
        let si = BodyIndex(si);
        let js = &spec.joints[joint_of[bi].unwrap_or(0)];
        let dof_start = lw.dof_coord.len();
        let mut local: Vec<usize> = Vec::new(); // spec coords of this joint's dofs
        let axes = lower_axes(spec, js, &mut lw, &mut owner, si, &mut local)?;
        let b = &spec.bodies[bi];
        let x_bm = Pose::from_isometry(&js.x_bm);
        let euler_speeds = has_euler_speeds(&js.kind, &axes);
        lw.bodies.push(Body {
            name: b.name.clone(),
            parent: js.parent.map(|p| body_map[p]),
            mass: b.mass,
            com: b.com,
            inertia: b.inertia,
            joint: Joint {
                name: js.name.clone(),
                x_pf: Pose::from_isometry(&js.x_pf),
                x_mb: x_bm.inverse(),
                x_bm,
                axes,
                dof_start,
                dof_count: local.len(),
                euler_speeds,
            },
        });
    }
    Ok(lw)
}

/// A bushing frame: its body in system indices (None = ground) and pose.
fn bushing_frame(
    f: &FrameSpec,
    name: &str,
    which: u8,
    body_map: &[BodyIndex],
) -> Result<(Option<BodyIndex>, Pose<f64>)> {
    let body = match f.body {
        None => None,
        Some(b) if b < body_map.len() => Some(body_map[b]),
        Some(b) => {
            return Err(Error::invalid(
                CTX,
                format!("bushing '{name}': frame{which} body index {b} out of range"),
            ));
        }
    };
    if !check_finite_pose(&f.transform) {
        return Err(Error::invalid(
            CTX,
            format!("bushing '{name}': frame{which} transform not finite"),
        ));
    }
    Ok((body, Pose::from_isometry(&f.transform)))
}

/// The first dof of the joint whose frames bushing frames `(body1, x_b1)`,
/// `(body2, x_b2)` are, when that joint's six axes are X, Y, Z rotations
/// then translations, each the identity of its own dof (see
/// `Bushing::fast`).
fn fast_path(
    bodies: &[Body],
    body1: Option<BodyIndex>,
    x_b1: &Pose<f64>,
    body2: Option<BodyIndex>,
    x_b2: &Pose<f64>,
) -> Option<usize> {
    let b = &bodies[body2?.0];
    let j = &b.joint;
    let same = |a: &Pose<f64>, b: &Pose<f64>| a.r == b.r && a.p == b.p;
    let unit = [Vector3::x(), Vector3::y(), Vector3::z()];
    let axes_ok = j.dof_count == 6
        && j.axes.iter().enumerate().all(|(ai, ax)| {
            ax.unit == unit[ai % 3]
                && matches!(&ax.source, AxisSource::Dof(k, Function::Linear { slope, intercept })
                    if *k == ai && *slope == 1.0 && *intercept == 0.0)
        });
    (b.parent == body1 && same(x_b1, &j.x_pf) && same(x_b2, &j.x_bm) && axes_ok)
        .then_some(j.dof_start)
}

/// Compile the bushings: frames, validated law, damping, fast path.
fn compile_bushings(
    spec: &SystemSpec,
    bodies: &[Body],
    body_map: &[BodyIndex],
) -> Result<Vec<Bushing>> {
    let mut bushings = Vec::with_capacity(spec.bushings.len());
    for bs in &spec.bushings {
        let (body1, x_b1) = bushing_frame(&bs.frame1, &bs.name, 1, body_map)?;
        let (body2, x_b2) = bushing_frame(&bs.frame2, &bs.name, 2, body_map)?;
        bs.model
            .validate()
            .map_err(|m| Error::invalid(CTX, format!("bushing '{}': {m}", bs.name)))?;
        bushings.push(Bushing {
            name: bs.name.clone(),
            fast: fast_path(bodies, body1, &x_b1, body2, &x_b2),
            body1,
            x_b1,
            body2,
            x_b2,
            c: bs.model.damping(),
            law: Law::from_model(&bs.model),
            model: bs.model.clone(),
        });
    }
    Ok(bushings)
}

impl System {
    /// Validate and compile a spec. Errors name the offending body, joint,
    /// coordinate or bushing.
    pub fn new(spec: &SystemSpec) -> Result<System> {
        // every body has exactly one joint to its parent
        let joint_of = joint_of_bodies(spec)?;
        check_bodies(spec, &joint_of)?;
        // parent before child
        let order = topological_order(spec, &joint_of)?;
        let mut body_map = vec![BodyIndex(0); spec.bodies.len()];
        for (si, &bi) in order.iter().enumerate() {
            body_map[bi] = BodyIndex(si);
        }
        check_coordinate_defaults(spec)?;
        // lower joints to six axes and number the free dofs
        let lowered = lower_bodies(spec, &joint_of, &order, &body_map)?;
        let bushings = compile_bushings(spec, &lowered.bodies, &body_map)?;
        if !spec.gravity.iter().all(|v| v.is_finite()) {
            return Err(Error::invalid(CTX, "gravity not finite"));
        }
        let Lowered {
            bodies,
            coord_dof,
            dof_coord,
            dof_body,
            dof_rotational,
        } = lowered;
        Ok(System {
            id: SystemId::new(&bodies, dof_coord.len(), bushings.len()),
            any_euler_speeds: bodies.iter().any(|b| b.joint.euler_speeds),
            bodies,
            coords: spec.coordinates.clone(),
            coord_dof,
            dof_coord,
            dof_body,
            dof_rotational,
            bushings,
            gravity: spec.gravity,
        })
    }

    /// The same system with every bushing on the general formula (no fast
    /// path); for validation.
    pub fn without_fast_paths(&self) -> Self {
        let mut out = self.clone();
        for b in out.bushings.iter_mut() {
            b.fast = None;
        }
        out.id.laws = fresh_id();
        out
    }

    /// This system's identity (see [`SystemId`]).
    pub fn id(&self) -> SystemId {
        self.id
    }

    /// Number of free degrees of freedom (generalised coordinates solved for).
    pub fn n_dofs(&self) -> usize {
        self.dof_coord.len()
    }
    /// Number of bodies (ground excluded).
    pub fn n_bodies(&self) -> usize {
        self.bodies.len()
    }
    /// Body names in system order (parent before child).
    pub fn body_names(&self) -> impl Iterator<Item = &str> {
        self.bodies.iter().map(|b| b.name.as_str())
    }
    /// System index of a body by name.
    pub fn body_index(&self, name: &str) -> Option<BodyIndex> {
        self.bodies
            .iter()
            .position(|b| b.name == name)
            .map(BodyIndex)
    }
    /// The force law of bushing `i`.
    pub fn bushing_model(&self, i: BushingIndex) -> Option<&BushingModel> {
        self.bushings.get(i.0).map(|b| &b.model)
    }
    /// Body moved by free dof `i`.
    pub fn dof_body(&self, i: DofIndex) -> Option<BodyIndex> {
        self.dof_body.get(i.0).copied()
    }
    /// True when body `i` hangs on ground through a joint without free dofs.
    pub fn is_welded_to_ground(&self, i: BodyIndex) -> bool {
        self.bodies
            .get(i.0)
            .map(|b| b.parent.is_none() && b.joint.dof_count == 0)
            .unwrap_or(false)
    }
    /// Bushing names in order.
    pub fn bushing_names(&self) -> impl Iterator<Item = &str> {
        self.bushings.iter().map(|b| b.name.as_str())
    }
    /// All coordinates of the spec, in spec order.
    pub fn coordinates(&self) -> &[CoordinateSpec] {
        &self.coords
    }
    /// Name of free dof `i`.
    pub fn dof_name(&self, i: DofIndex) -> &str {
        self.dof_coord
            .get(i.0)
            .and_then(|&c| self.coords.get(c))
            .map(|c| c.name.as_str())
            .unwrap_or("")
    }
    /// Free dof index of a coordinate by name (None when locked/unknown).
    pub fn dof_of(&self, coord_name: &str) -> Option<DofIndex> {
        let c = self.coords.iter().position(|c| c.name == coord_name)?;
        self.coord_dof.get(c).copied().flatten()
    }
    /// Gravity vector.
    pub fn gravity(&self) -> Vector3<f64> {
        self.gravity
    }
    /// Default free-dof vector (coordinate defaults).
    pub fn default_q(&self) -> DVector<f64> {
        DVector::from_iterator(
            self.n_dofs(),
            self.dof_coord.iter().map(|&c| self.coords[c].default),
        )
    }
    /// All coordinate values (spec order) for a free-dof vector: locked and
    /// unused coordinates keep their defaults.
    pub fn full_coordinates(&self, q: &[f64]) -> Vec<f64> {
        self.coords
            .iter()
            .zip(&self.coord_dof)
            .map(|(c, d)| match d {
                Some(i) => q.get(i.0).copied().unwrap_or(c.default),
                None => c.default,
            })
            .collect()
    }
    /// Free-dof vector from full coordinate values (spec order).
    pub fn dofs_from_full(&self, full: &[f64]) -> DVector<f64> {
        DVector::from_iterator(
            self.n_dofs(),
            self.dof_coord
                .iter()
                .map(|&c| full.get(c).copied().unwrap_or(self.coords[c].default)),
        )
    }
    /// Coordinates outside their range that are flagged `clamped`:
    /// (name, value, [min, max]).
    pub fn clamp_violations(&self, q: &[f64]) -> Vec<(String, f64, [f64; 2])> {
        let full = self.full_coordinates(q);
        self.coords
            .iter()
            .zip(full)
            .filter(|(c, v)| c.clamped && (*v < c.range[0] || *v > c.range[1]))
            .map(|(c, v)| (c.name.clone(), v, c.range))
            .collect()
    }
    /// Path of bodies from `b` up to the root (inclusive of b).
    pub(crate) fn path_to_root(&self, b: BodyIndex) -> Vec<BodyIndex> {
        let mut out = vec![b];
        let mut cur = b;
        while let Some(p) = self.bodies[cur.0].parent {
            out.push(p);
            cur = p;
        }
        out
    }
    /// Locks every coordinate of the joints between ground and `body`
    /// (fixing the body in its default pose) and returns the new system.
    pub fn with_body_fixed(spec: &SystemSpec, body: &str) -> Result<SystemSpec> {
        let Some(bi) = spec.bodies.iter().position(|b| b.name == body) else {
            return Err(Error::invalid(
                "--fixed",
                format!("no body named '{body}' in the model"),
            ));
        };
        let mut spec = spec.clone();
        let mut cur = Some(bi);
        let mut guard = 0;
        while let Some(b) = cur {
            guard += 1;
            if guard > spec.bodies.len() + 1 {
                return Err(Error::invalid("--fixed", "cycle in the joint tree"));
            }
            let Some(j) = spec.joints.iter().find(|j| j.child == b) else {
                break;
            };
            for ta in lower_joint(&j.kind) {
                if let Some(c) = ta.coord {
                    if let Some(cs) = spec.coordinates.get_mut(c) {
                        cs.locked = true;
                    }
                }
            }
            cur = j.parent;
        }
        Ok(spec)
    }
}

impl System {
    /// The same system with the force law of bushing `i` replaced
    /// (calibration makes thousands of such variants; the structure is
    /// shared, so workspaces and loads stay valid). The law is validated;
    /// frames and the fast path are unchanged.
    pub fn with_bushing_model(&self, i: BushingIndex, model: BushingModel) -> Result<System> {
        let mut out = self.clone();
        out.set_bushing_model(i, model)?;
        out.id.laws = fresh_id();
        Ok(out)
    }

    /// Replace a bushing law in place (only on a system under construction
    /// by one of the `with_*` methods).
    fn set_bushing_model(
        &mut self,
        BushingIndex(i): BushingIndex,
        model: BushingModel,
    ) -> Result<()> {
        let n = self.bushings.len();
        let Some(b) = self.bushings.get_mut(i) else {
            return Err(Error::invalid(
                "solver",
                format!("bushing index {i} out of range ({n} bushings)"),
            ));
        };
        model
            .validate()
            .map_err(|m| Error::invalid(format!("bushing '{}'", b.name), m.to_string()))?;
        b.law = super::law::Law::from_model(&model);
        b.c = model.damping();
        b.model = model;
        Ok(())
    }

    /// The same system with the diagonal stiffness `(rx, ry, rz, tx, ty,
    /// tz)` of linear bushing `i` replaced (an error for other laws),
    /// keeping its damping.
    pub fn with_bushing_stiffness(&self, i: BushingIndex, k: [f64; 6]) -> Result<System> {
        let model = self.linear_with_stiffness(i, k)?;
        self.with_bushing_model(i, model)
    }

    /// The same system with several bushing laws replaced at once (one
    /// copy for all of them).
    pub fn with_bushing_models(
        &self,
        models: impl IntoIterator<Item = (BushingIndex, BushingModel)>,
    ) -> Result<System> {
        let mut out = self.clone();
        for (i, model) in models {
            out.set_bushing_model(i, model)?;
        }
        out.id.laws = fresh_id();
        Ok(out)
    }

    /// The linear law of bushing `i` with its stiffness replaced by `k`.
    pub fn linear_with_stiffness(
        &self,
        BushingIndex(i): BushingIndex,
        k: [f64; 6],
    ) -> Result<BushingModel> {
        let Some(b) = self.bushings.get(i) else {
            return Err(Error::invalid(
                "solver",
                format!("bushing index {i} out of range"),
            ));
        };
        let BushingModel::Linear {
            rot_damping,
            trans_damping,
            ..
        } = &b.model
        else {
            return Err(Error::invalid(
                format!("bushing '{}'", b.name),
                "not a linear BushingForce: its stiffness is not six numbers",
            ));
        };
        let model = BushingModel::Linear {
            rot_stiffness: Vector3::new(k[0], k[1], k[2]),
            trans_stiffness: Vector3::new(k[3], k[4], k[5]),
            rot_damping: *rot_damping,
            trans_damping: *trans_damping,
        };
        Ok(model)
    }

    /// Poses `(X_B1F, X_B2M)` of bushing `i`'s two frames in their bodies.
    pub fn bushing_frames(&self, i: BushingIndex) -> Option<(Isometry3<f64>, Isometry3<f64>)> {
        let b = self.bushings.get(i.0)?;
        Some((pose_to_isometry(&b.x_b1), pose_to_isometry(&b.x_b2)))
    }

    /// True when bushing `i` sits on the two offset frames of the joint of
    /// its second body, with the joint's axes the identity functions of its
    /// six dofs (the intervertebral layout; see `Bushing::fast`).
    pub fn bushing_on_joint_frames(&self, i: BushingIndex) -> bool {
        self.bushings.get(i.0).is_some_and(|b| b.fast.is_some())
    }

    /// The same system with bushing `i`'s two frames moved: `x1` in the
    /// first body, `x2` in the second, together with the joint frames they
    /// sit on (the joint of the second body), so that the joint centre and
    /// axes move with the bushing. Only for bushings on their joint's frames
    /// ([`System::bushing_on_joint_frames`]). Loads prepared before keep
    /// their points on the bodies (see [`super::LoadSet`]).
    pub fn with_bushing_joint_frames(
        &self,
        BushingIndex(i): BushingIndex,
        x1: &Isometry3<f64>,
        x2: &Isometry3<f64>,
    ) -> Result<System> {
        let mut out = self.clone();
        out.set_bushing_joint_frames(i, x1, x2)?;
        out.id.frames = fresh_id();
        out.id.laws = fresh_id();
        Ok(out)
    }

    /// Move bushing and joint frames in place (construction only).
    fn set_bushing_joint_frames(
        &mut self,
        i: usize,
        x1: &Isometry3<f64>,
        x2: &Isometry3<f64>,
    ) -> Result<()> {
        let n = self.bushings.len();
        let Some(b) = self.bushings.get_mut(i) else {
            return Err(Error::invalid(
                "solver",
                format!("bushing index {i} out of range ({n} bushings)"),
            ));
        };
        let (Some(_), Some(c2)) = (b.fast, b.body2) else {
            return Err(Error::invalid(
                format!("bushing '{}'", b.name),
                "its frames are not the offset frames of a 6-dof joint: joint frames cannot move with it",
            ));
        };
        let (p1, p2) = (Pose::from_isometry(x1), Pose::from_isometry(x2));
        if !(p1
            .r
            .iter()
            .chain(p1.p.iter())
            .chain(p2.r.iter())
            .chain(p2.p.iter()))
        .all(|v| v.is_finite())
        {
            return Err(Error::invalid(
                format!("bushing '{}'", b.name),
                "frames must be finite",
            ));
        }
        b.x_b1 = p1;
        b.x_b2 = p2;
        let Some(body) = self.bodies.get_mut(c2.0) else {
            return Err(Error::invalid("solver", "bushing body out of range"));
        };
        body.joint.x_pf = p1;
        body.joint.x_mb = p2.inverse();
        body.joint.x_bm = p2;
        Ok(())
    }

    /// The two bodies (None = ground) a bushing connects.
    pub fn bushing_bodies(
        &self,
        i: BushingIndex,
    ) -> Option<(Option<BodyIndex>, Option<BodyIndex>)> {
        self.bushings.get(i.0).map(|b| (b.body1, b.body2))
    }

    /// Parent body of body `i` (None = ground or out of range).
    pub fn parent_of(&self, i: BodyIndex) -> Option<BodyIndex> {
        self.bodies.get(i.0).and_then(|b| b.parent)
    }
}

fn pose_to_isometry(x: &Pose<f64>) -> Isometry3<f64> {
    let rot = nalgebra::Rotation3::from_matrix_unchecked(x.r);
    Isometry3::from_parts(
        nalgebra::Translation3::from(x.p),
        nalgebra::UnitQuaternion::from_rotation_matrix(&rot),
    )
}
