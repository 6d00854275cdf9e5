//! Typed, read-only snapshot of the parts of an OpenSim 4.x model the tool
//! works on ([`Model`]), in SI units, validated: duplicate names in a set,
//! dangling socket paths, cyclic joint graphs, bodies without a joint path to
//! ground, non-numeric/NaN values and missing required properties are errors
//! naming the file and the element (with its line).
//!
//! Socket paths are resolved the way OpenSim resolves them: absolute
//! (`/bodyset/L5`, `/ground`), or relative to the component that owns the
//! socket (`ground_offset` inside a joint, `../../../bodyset/L5` from a
//! PhysicalOffsetFrame), with OpenSim's fallback of a unique component name
//! for bare names. Offset frames on offset frames are followed to the body.

use super::document::Document;
use super::function::Function;
use super::props::{
    bool_or, f64_or, f64_prop, fixed_prop, loc, opt_numbers, str_prop, vec3_or, vec3_prop,
};
use super::xml::Element;
use crate::error::{Error, Result};
use nalgebra::{Isometry3, Rotation3, Translation3, UnitQuaternion, Vector3};
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Rotation from body-fixed X-Y-Z angles: R = Rx(a) Ry(b) Rz(c).
pub fn body_fixed_xyz(angles: &Vector3<f64>) -> Rotation3<f64> {
    Rotation3::from_axis_angle(&Vector3::x_axis(), angles[0])
        * Rotation3::from_axis_angle(&Vector3::y_axis(), angles[1])
        * Rotation3::from_axis_angle(&Vector3::z_axis(), angles[2])
}

/// Body-fixed X-Y-Z angles of a rotation (`R = Rx(a) Ry(b) Rz(c)`, OpenSim's
/// `orientation`): the inverse of [`body_fixed_xyz`] away from gimbal lock.
/// (The solver's generic form, for dual numbers, is
/// `solver::scalar::body_xyz`, Simbody's formula; they agree to rounding.)
pub fn xyz_angles(r: &Rotation3<f64>) -> Vector3<f64> {
    let m = r.matrix();
    let b = m[(0, 2)].clamp(-1.0, 1.0).asin();
    let a = (-m[(1, 2)]).atan2(m[(2, 2)]);
    let c = (-m[(0, 1)]).atan2(m[(0, 0)]);
    Vector3::new(a, b, c)
}

/// Transform with translation `t` and body-fixed XYZ orientation `angles`.
pub(crate) fn frame_transform(t: &Vector3<f64>, angles: &Vector3<f64>) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::from(*t),
        UnitQuaternion::from_rotation_matrix(&body_fixed_xyz(angles)),
    )
}

/// How a coordinate moves its joint.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum MotionType {
    /// Moves the joint by a rotation (value in rad).
    Rotational,
    /// Moves the joint by a translation (value in m).
    Translational,
    /// Drives the joint through a coupling constraint.
    Coupled,
}

/// A generalized coordinate.
#[derive(Debug, Clone, PartialEq)]
pub struct Coordinate {
    /// Coordinate name.
    pub name: String,
    /// Joint owning the coordinate.
    pub joint: String,
    /// `default_value` (rad or m).
    pub default_value: f64,
    /// `default_speed_value` (rad/s or m/s).
    pub default_speed_value: f64,
    /// [min, max] (rad or m).
    pub range: [f64; 2],
    /// Whether the value is clamped to `range`.
    pub clamped: bool,
    /// Whether the coordinate is locked at its value.
    pub locked: bool,
    /// Whether the coordinate's motion is prescribed.
    pub prescribed: bool,
    /// Rotational, translational or coupled.
    pub motion_type: MotionType,
    /// Line of the element in the file.
    pub line: usize,
}

/// A PhysicalOffsetFrame: a fixed transform from its parent frame.
#[derive(Debug, Clone, PartialEq)]
pub struct OffsetFrame {
    /// Frame name.
    pub name: String,
    /// Absolute component path of this frame (e.g. `/jointset/j/L5_offset`).
    pub path: String,
    /// Socket text of the parent frame, as written.
    pub socket_parent: String,
    /// Origin in the parent frame (m).
    pub translation: Vector3<f64>,
    /// Body-fixed XYZ angles (rad).
    pub orientation: Vector3<f64>,
    /// Line of the element in the file.
    pub line: usize,
}

impl OffsetFrame {
    /// Transform of this frame in its parent frame.
    pub fn transform(&self) -> Isometry3<f64> {
        frame_transform(&self.translation, &self.orientation)
    }
}

/// Attached geometry of a frame.
#[derive(Debug, Clone, PartialEq)]
pub enum Geometry {
    /// A mesh file attached to the frame.
    Mesh {
        /// Geometry component name.
        name: String,
        /// `mesh_file` as written.
        mesh_file: String,
        /// Scale applied to the mesh along the frame's X, Y, Z.
        scale_factors: Vector3<f64>,
    },
    /// Another geometry class (Sphere, Cylinder, Brick, ...), kept by class.
    Other {
        /// OpenSim class name.
        class: String,
        /// Geometry component name.
        name: String,
    },
}

/// Shape of a wrap object.
#[derive(Debug, Clone, PartialEq)]
pub enum WrapShape {
    /// A WrapSphere.
    Sphere {
        /// Radius (m).
        radius: f64,
    },
    /// A WrapCylinder.
    Cylinder {
        /// Radius (m).
        radius: f64,
        /// Length along the cylinder's Z axis (m).
        length: f64,
    },
    /// Semi-axes.
    Ellipsoid {
        /// Semi-axes along X, Y, Z (m).
        dimensions: Vector3<f64>,
    },
    /// A WrapTorus.
    Torus {
        /// Inner radius (m).
        inner_radius: f64,
        /// Outer radius (m).
        outer_radius: f64,
    },
    /// Another wrap class, kept by name.
    Other {
        /// OpenSim class name.
        class: String,
    },
}

/// A wrap object fixed to a body (or ground).
#[derive(Debug, Clone, PartialEq)]
pub struct WrapObject {
    /// Wrap object name.
    pub name: String,
    /// Body (or "ground") the object is fixed to.
    pub body: String,
    /// Origin in the body frame (m).
    pub translation: Vector3<f64>,
    /// Orientation in the body frame: body-fixed X-Y-Z angles (rad).
    pub xyz_body_rotation: Vector3<f64>,
    /// `quadrant` as written (`all`, `+x`, `-y`, ...).
    pub quadrant: String,
    /// Whether the object is active.
    pub active: bool,
    /// Its shape and dimensions.
    pub shape: WrapShape,
}

impl WrapObject {
    /// OpenSim class name.
    pub fn class(&self) -> &str {
        match &self.shape {
            WrapShape::Sphere { .. } => "WrapSphere",
            WrapShape::Cylinder { .. } => "WrapCylinder",
            WrapShape::Ellipsoid { .. } => "WrapEllipsoid",
            WrapShape::Torus { .. } => "WrapTorus",
            WrapShape::Other { class } => class,
        }
    }
}

/// A rigid body.
#[derive(Debug, Clone, PartialEq)]
pub struct Body {
    /// Body name.
    pub name: String,
    /// Mass (kg).
    pub mass: f64,
    /// Centre of mass in the body frame (m).
    pub mass_center: Vector3<f64>,
    /// [Ixx Iyy Izz Ixy Ixz Iyz] about the mass center.
    pub inertia: [f64; 6],
    /// Attached geometry.
    pub geometry: Vec<Geometry>,
    /// Wrap objects fixed to the body.
    pub wrap_objects: Vec<WrapObject>,
    /// Line of the element in the file.
    pub line: usize,
}

/// One of the six axes of a CustomJoint's SpatialTransform.
#[derive(Debug, Clone, PartialEq)]
pub struct TransformAxis {
    /// rotation1..3, translation1..3.
    pub name: String,
    /// Names of the coordinates the function takes.
    pub coordinates: Vec<String>,
    /// Axis in the joint's parent frame (unit vector).
    pub axis: Vector3<f64>,
    /// Value (rad or m) as a function of the coordinates.
    pub function: Function,
}

/// Joint class and its class-specific data.
#[derive(Debug, Clone, PartialEq)]
pub enum JointKind {
    /// A WeldJoint (no coordinates).
    Weld,
    /// A PinJoint (one rotation about Z).
    Pin,
    /// A FreeJoint (X-Y-Z rotations, then translations).
    Free,
    /// rotation1, rotation2, rotation3, translation1, translation2, translation3.
    Custom {
        /// The six transform axes.
        axes: Vec<TransformAxis>,
    },
    /// Other joint classes, kept by class name.
    Other,
}

/// A joint with its frames and coordinates.
#[derive(Debug, Clone, PartialEq)]
pub struct Joint {
    /// Joint name.
    pub name: String,
    /// OpenSim class name.
    pub class: String,
    /// The class and its class-specific data.
    pub kind: JointKind,
    /// Socket texts as written.
    pub socket_parent_frame: String,
    /// Socket text of the child frame, as written.
    pub socket_child_frame: String,
    /// Offset frames the joint owns.
    pub frames: Vec<OffsetFrame>,
    /// The joint's coordinates in order.
    pub coordinates: Vec<Coordinate>,
    /// Line of the element in the file.
    pub line: usize,
}

/// Resolved frames of a joint.
#[derive(Debug, Clone, PartialEq)]
pub struct JointFrames {
    /// Joint name.
    pub joint: String,
    /// Name of the body (or ground) the parent frame is on.
    pub parent_body: String,
    /// Parent joint frame in the parent body.
    pub parent_in_body: Isometry3<f64>,
    /// Name of the body the child frame is on.
    pub child_body: String,
    /// Child joint frame in the child body.
    pub child_in_body: Isometry3<f64>,
}

/// A BushingForce (linear bushing between two frames).
#[derive(Debug, Clone, PartialEq)]
pub struct BushingForce {
    /// Force name.
    pub name: String,
    /// Socket text of frame 1, as written.
    pub socket_frame1: String,
    /// Socket text of frame 2, as written.
    pub socket_frame2: String,
    /// Offset frames the force owns.
    pub frames: Vec<OffsetFrame>,
    /// Nm/rad about X, Y, Z.
    pub rotational_stiffness: Vector3<f64>,
    /// N/m along X, Y, Z.
    pub translational_stiffness: Vector3<f64>,
    /// N m s/rad about X, Y, Z.
    pub rotational_damping: Vector3<f64>,
    /// N s/m along X, Y, Z.
    pub translational_damping: Vector3<f64>,
}

/// FunctionBased/ExpressionBased bushings: frames and property texts.
#[derive(Debug, Clone, PartialEq)]
pub struct OtherBushing {
    /// Force name.
    pub name: String,
    /// OpenSim class name.
    pub class: String,
    /// Socket text of frame 1, as written.
    pub socket_frame1: String,
    /// Socket text of frame 2, as written.
    pub socket_frame2: String,
    /// Offset frames the force owns.
    pub frames: Vec<OffsetFrame>,
    /// Every other property (tag, trimmed text) in file order.
    pub properties: Vec<(String, String)>,
    /// Properties holding a function (e.g. `m_x_theta_x_function` of a
    /// FunctionBasedBushingForce): (tag, parsed function), in file order.
    pub functions: Vec<(String, Function)>,
}

/// Kind of a path point.
#[derive(Debug, Clone, PartialEq)]
pub enum PathPointKind {
    /// A fixed point.
    Fixed,
    /// Active while the coordinate is inside `range`.
    Conditional {
        /// Name of the coordinate.
        coordinate: String,
        /// [min, max] of the coordinate (rad or m).
        range: [f64; 2],
    },
    /// Location given by functions of coordinates (x, y, z; each optional).
    Moving {
        /// X function and the name of its coordinate.
        x: Option<Box<(Function, String)>>,
        /// Y function and the name of its coordinate.
        y: Option<Box<(Function, String)>>,
        /// Z function and the name of its coordinate.
        z: Option<Box<(Function, String)>>,
    },
}

/// A path point of a GeometryPath.
#[derive(Debug, Clone, PartialEq)]
pub struct PathPoint {
    /// Path point name.
    pub name: String,
    /// Socket text of the frame it is fixed to, as written.
    pub socket_parent_frame: String,
    /// Location in that frame (m).
    pub location: Vector3<f64>,
    /// Fixed, conditional or moving.
    pub kind: PathPointKind,
}

/// A PathWrap of a GeometryPath.
#[derive(Debug, Clone, PartialEq)]
pub struct PathWrap {
    /// Name of the wrap object.
    pub wrap_object: String,
    /// `method` as written (e.g. `hybrid`).
    pub method: String,
    /// `range`: the path points between which the wrap applies (1-based; -1 -1 = all).
    pub range: [i64; 2],
}

/// A muscle (any class) with its path.
#[derive(Debug, Clone, PartialEq)]
pub struct Muscle {
    /// Muscle name.
    pub name: String,
    /// OpenSim class name.
    pub class: String,
    /// Maximum isometric force (N).
    pub max_isometric_force: f64,
    /// Optimal fibre length (m).
    pub optimal_fiber_length: f64,
    /// Tendon slack length (m).
    pub tendon_slack_length: f64,
    /// `pennation_angle_at_optimal` (or `pennation_angle` in old files).
    pub pennation_angle: Option<f64>,
    /// Path points in order.
    pub points: Vec<PathPoint>,
    /// Path wraps in order.
    pub wraps: Vec<PathWrap>,
}

/// A force element.
#[derive(Debug, Clone, PartialEq)]
pub enum Force {
    /// A BushingForce.
    Bushing(BushingForce),
    /// A FunctionBasedBushingForce or ExpressionBasedBushingForce.
    OtherBushing(OtherBushing),
    /// A muscle of any class.
    Muscle(Box<Muscle>),
    /// Another force class, kept by class and name.
    Other {
        /// OpenSim class name.
        class: String,
        /// Force name.
        name: String,
    },
}

impl Force {
    /// OpenSim class name.
    pub fn class(&self) -> &str {
        match self {
            Force::Bushing(_) => "BushingForce",
            Force::OtherBushing(b) => &b.class,
            Force::Muscle(m) => &m.class,
            Force::Other { class, .. } => class,
        }
    }
    /// Component name.
    pub fn name(&self) -> &str {
        match self {
            Force::Bushing(b) => &b.name,
            Force::OtherBushing(b) => &b.name,
            Force::Muscle(m) => &m.name,
            Force::Other { name, .. } => name,
        }
    }
}

/// A marker fixed to a frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Marker {
    /// Marker name.
    pub name: String,
    /// Socket text of the frame it is fixed to, as written.
    pub socket_parent_frame: String,
    /// Location in that frame (m).
    pub location: Vector3<f64>,
    /// `fixed` as written.
    pub fixed: bool,
}

/// A constraint.
#[derive(Debug, Clone, PartialEq)]
pub enum Constraint {
    /// A CoordinateCouplerConstraint.
    CoordinateCoupler {
        /// Constraint name.
        name: String,
        /// Names of the independent coordinates.
        independent: Vec<String>,
        /// Name of the dependent coordinate.
        dependent: String,
        /// The coupler function of the independent coordinates.
        function: Function,
        /// `scale_factor` applied to the function's value.
        scale_factor: f64,
        /// Whether the constraint is enforced.
        enforced: bool,
    },
    /// Another constraint class, kept by class and name.
    Other {
        /// OpenSim class name.
        class: String,
        /// Constraint name.
        name: String,
    },
}

/// Ground: its geometry and wrap objects.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Ground {
    /// Ground's name.
    pub name: String,
    /// Geometry attached to ground.
    pub geometry: Vec<Geometry>,
    /// Wrap objects fixed to ground.
    pub wrap_objects: Vec<WrapObject>,
}

/// A frame known to the model, for socket resolution.
#[derive(Debug, Clone, PartialEq)]
enum FrameNode {
    /// A body or ground (name).
    Body(String),
    /// An offset frame: (resolved parent path, transform in parent).
    Offset(String, Isometry3<f64>),
}

/// Typed snapshot of a model (SI units).
#[derive(Debug, Clone, PartialEq)]
pub struct Model {
    /// The file it was read from.
    pub file: PathBuf,
    /// Model name.
    pub name: String,
    /// Gravity in ground (m/s^2).
    pub gravity: Vector3<f64>,
    /// `credits` text, if any.
    pub credits: Option<String>,
    /// `publications` text, if any.
    pub publications: Option<String>,
    /// `length_units` (always `meters`: others are refused).
    pub length_units: String,
    /// `force_units` (always `N`: others are refused).
    pub force_units: String,
    /// Ground's geometry and wrap objects.
    pub ground: Ground,
    /// Bodies in file order.
    pub bodies: Vec<Body>,
    /// Joints in file order.
    pub joints: Vec<Joint>,
    /// Force elements in file order.
    pub forces: Vec<Force>,
    /// Markers in file order.
    pub markers: Vec<Marker>,
    /// Constraints in file order.
    pub constraints: Vec<Constraint>,
    /// Every frame by absolute path (ground, bodies, offset frames).
    frames: BTreeMap<String, FrameNode>,
    /// Coordinate name by absolute path.
    coordinate_paths: BTreeMap<String, String>,
}

struct Ctx<'a> {
    file: &'a Path,
}

impl Ctx<'_> {
    fn err(&self, e: &Element, msg: impl Into<String>) -> Error {
        Error::parse(self.file, loc(e), msg)
    }
}

/// Join an absolute component path and a socket path (absolute or relative).
fn join_path(owner: &str, socket: &str) -> Option<String> {
    let socket = socket.trim();
    let mut parts: Vec<&str> = if socket.starts_with('/') {
        Vec::new()
    } else {
        owner.split('/').filter(|s| !s.is_empty()).collect()
    };
    for seg in socket.split('/').filter(|s| !s.is_empty()) {
        match seg {
            "." => {}
            ".." => {
                parts.pop()?;
            }
            s => parts.push(s),
        }
    }
    Some(format!("/{}", parts.join("/")))
}

fn set_name(e: &Element) -> String {
    e.attr("name")
        .filter(|n| !n.is_empty())
        .map(str::to_string)
        .unwrap_or_else(|| e.name.to_lowercase())
}

/// The model's length and force units: only meters and N are supported.
fn read_units(m: &Element, cx: &Ctx) -> Result<(String, String)> {
    let length_units = str_prop(m, "length_units").unwrap_or_else(|| "meters".into());
    if !matches!(length_units.as_str(), "meters" | "m" | "meter") {
        let at = m.child("length_units").unwrap_or(m);
        return Err(cx.err(
            at,
            format!("length_units '{length_units}' is not supported: only meters (convert the model to meters first)"),
        ));
    }
    let force_units = str_prop(m, "force_units").unwrap_or_else(|| "N".into());
    if !matches!(force_units.as_str(), "N" | "newtons" | "Newtons") {
        let at = m.child("force_units").unwrap_or(m);
        return Err(cx.err(
            at,
            format!("force_units '{force_units}' is not supported: only N"),
        ));
    }
    Ok((length_units, force_units))
}

/// No two objects of one `*Set` share a name.
fn check_unique_names(m: &Element, cx: &Ctx) -> Result<()> {
    for set in m.elements().filter(|e| e.name.ends_with("Set")) {
        if let Some(objects) = set.child("objects") {
            let mut seen: BTreeMap<&str, &Element> = BTreeMap::new();
            for c in objects.elements() {
                let n = c.name_attr();
                if let Some(first) = seen.insert(n, c) {
                    return Err(cx.err(
                        c,
                        format!(
                            "duplicate name '{n}' in {} (first at line {})",
                            set.name, first.line
                        ),
                    ));
                }
            }
        }
    }
    Ok(())
}

impl Model {
    /// Build and validate the snapshot of a document.
    pub fn from_document(doc: &Document) -> Result<Model> {
        let file = doc.path();
        let cx = Ctx { file };
        let m = doc.model_element();
        // Units (meters, N only) and gravity.
        let (length_units, force_units) = read_units(m, &cx)?;
        let gravity = vec3_or(m, "gravity", Vector3::new(0.0, -9.80665, 0.0), file)?;
        // Duplicate names within each set.
        check_unique_names(m, &cx)?;
        let mut model = Model {
            file: file.to_path_buf(),
            name: m.name_attr().to_string(),
            gravity,
            credits: str_prop(m, "credits"),
            publications: str_prop(m, "publications"),
            length_units,
            force_units,
            ground: Ground {
                name: "ground".into(),
                ..Default::default()
            },
            bodies: vec![],
            joints: vec![],
            forces: vec![],
            markers: vec![],
            constraints: vec![],
            frames: BTreeMap::new(),
            coordinate_paths: BTreeMap::new(),
        };
        // Ground and its attachments.
        model
            .frames
            .insert("/ground".into(), FrameNode::Body("ground".into()));
        if let Some(g) = m.child("Ground") {
            model.ground.geometry = parse_geometry(g, &cx)?;
            model.ground.wrap_objects = parse_wraps(g, "ground", &cx)?;
        }
        // Every offset frame of the model, found by path.
        let mut offset_frames: Vec<(OffsetFrame, &Element)> = Vec::new();
        collect_offset_frames(m, &mut Vec::new(), &cx, &mut offset_frames)?;
        let frame_table = FrameTable::new(&offset_frames);
        // Bodies, then the parents of the offset frames once all frames are known.
        model.read_bodies(m, &cx)?;
        model.resolve_offset_frames(&offset_frames, &cx)?;
        // Joints with their coordinates (names unique model-wide).
        let jointset = model.read_joints(m, &cx, &frame_table)?;
        model.check_unique_coordinates()?;
        // Forces, markers, constraints.
        let forceset = m
            .child("ForceSet")
            .map(set_name)
            .unwrap_or_else(|| "forceset".into());
        for f in objects(m, "ForceSet") {
            let force = parse_force(f, &cx, &frame_table)?;
            model.forces.push(force);
        }
        for mk in objects(m, "MarkerSet") {
            model.markers.push(Marker {
                name: mk.name_attr().to_string(),
                socket_parent_frame: required_text(mk, "socket_parent_frame", &cx)?,
                location: vec3_or(mk, "location", Vector3::zeros(), file)?,
                fixed: bool_or(mk, "fixed", false, file)?,
            });
        }
        for c in objects(m, "ConstraintSet") {
            model.constraints.push(parse_constraint(c, &cx)?);
        }
        // Sockets resolve and the joint graph is a tree rooted at ground.
        model.validate(m, &jointset, &forceset, &cx)?;
        Ok(model)
    }

    /// The bodies of the BodySet (named, not `ground`, physical mass and
    /// inertia), registered as frames.
    fn read_bodies(&mut self, m: &Element, cx: &Ctx) -> Result<()> {
        let file = cx.file;
        for b in objects(m, "BodySet") {
            let name = b.name_attr().to_string();
            if name.is_empty() {
                return Err(cx.err(b, "body without a name"));
            }
            if name == "ground" {
                return Err(cx.err(b, "a body may not be named 'ground'"));
            }
            let mass = f64_prop(b, "mass", file)?;
            if mass < 0.0 {
                return Err(cx.err(b, format!("negative mass {mass}")));
            }
            let mass_center = vec3_or(b, "mass_center", Vector3::zeros(), file)?;
            let inertia = match opt_numbers(b, "inertia", file)? {
                Some(v) if v.len() == 6 => [v[0], v[1], v[2], v[3], v[4], v[5]],
                Some(v) => {
                    let at = b.child("inertia").unwrap_or(b);
                    return Err(cx.err(
                        at,
                        format!(
                            "inertia needs 6 numbers [Ixx Iyy Izz Ixy Ixz Iyz], found {}",
                            v.len()
                        ),
                    ));
                }
                None => [0.0; 6],
            };
            if let Some(why) = super::physics::mass_error(mass, &inertia) {
                return Err(cx.err(b, why));
            }
            let body_path = format!("/{}/{}", set_name(m.child("BodySet").unwrap_or(b)), name);
            self.frames.insert(body_path, FrameNode::Body(name.clone()));
            self.bodies.push(Body {
                geometry: parse_geometry(b, cx)?,
                wrap_objects: parse_wraps(b, &name, cx)?,
                name,
                mass,
                mass_center,
                inertia,
                line: b.line,
            });
        }
        Ok(())
    }

    /// Register the offset frames, then resolve each one's parent socket
    /// (parents may be offset frames themselves).
    fn resolve_offset_frames(
        &mut self,
        offset_frames: &[(OffsetFrame, &Element)],
        cx: &Ctx,
    ) -> Result<()> {
        for (f, _) in offset_frames {
            self.frames.insert(
                f.path.clone(),
                FrameNode::Offset(String::new(), f.transform()),
            );
        }
        let mut resolved: Vec<(String, String)> = Vec::new();
        for (f, el) in offset_frames {
            let parent = self
                .resolve_socket(&f.path, &f.socket_parent)
                .ok_or_else(|| {
                    cx.err(
                        el,
                        format!(
                            "socket_parent '{}' does not name a frame in the model",
                            f.socket_parent
                        ),
                    )
                })?;
            resolved.push((f.path.clone(), parent));
        }
        for (path, parent) in resolved {
            if let Some(FrameNode::Offset(p, _)) = self.frames.get_mut(&path) {
                *p = parent;
            }
        }
        Ok(())
    }

    /// The joints of the JointSet and the paths of their coordinates;
    /// returns the JointSet's path name.
    fn read_joints(&mut self, m: &Element, cx: &Ctx, frame_table: &FrameTable) -> Result<String> {
        let jointset = m
            .child("JointSet")
            .map(set_name)
            .unwrap_or_else(|| "jointset".into());
        for j in objects(m, "JointSet") {
            let joint = parse_joint(j, &format!("/{jointset}"), cx, frame_table)?;
            for c in &joint.coordinates {
                self.coordinate_paths.insert(
                    format!("/{jointset}/{}/{}", joint.name, c.name),
                    c.name.clone(),
                );
            }
            self.joints.push(joint);
        }
        Ok(jointset)
    }

    /// Coordinate names must be unique model-wide (OpenSim looks them up by name).
    fn check_unique_coordinates(&self) -> Result<()> {
        let mut coord_seen = BTreeSet::new();
        for j in &self.joints {
            for c in &j.coordinates {
                if !coord_seen.insert(c.name.clone()) {
                    return Err(Error::parse(
                        &self.file,
                        format!("<Coordinate name=\"{}\"> (line {})", c.name, c.line),
                        format!("duplicate coordinate name '{}' (joint {})", c.name, j.name),
                    ));
                }
            }
        }
        Ok(())
    }

    /// Resolve a socket path written in the component at `owner_path` to
    /// the absolute path of a known frame.
    fn resolve_socket(&self, owner_path: &str, socket: &str) -> Option<String> {
        if let Some(p) = join_path(owner_path, socket) {
            if self.frames.contains_key(&p) {
                return Some(p);
            }
        }
        // OpenSim's fallback: a bare name that names exactly one frame.
        let bare = socket.trim();
        if !bare.contains('/') && !bare.is_empty() {
            let hits: Vec<&String> = self
                .frames
                .keys()
                .filter(|k| k.rsplit('/').next() == Some(bare))
                .collect();
            if hits.len() == 1 {
                return Some(hits[0].clone());
            }
        }
        None
    }

    /// The body (or "ground") a frame path is fixed to, and the frame's
    /// transform in that body.
    pub fn frame_in_body(&self, frame_path: &str) -> Result<(String, Isometry3<f64>)> {
        let mut x = Isometry3::identity();
        let mut path = frame_path.to_string();
        for _ in 0..=self.frames.len() {
            match self.frames.get(&path) {
                Some(FrameNode::Body(name)) => return Ok((name.clone(), x)),
                Some(FrameNode::Offset(parent, t)) => {
                    x = t * x;
                    path = parent.clone();
                }
                None => {
                    return Err(Error::invalid(
                        self.file.display().to_string(),
                        format!("frame '{frame_path}' not found (via '{path}')"),
                    ))
                }
            }
        }
        Err(Error::invalid(
            self.file.display().to_string(),
            format!("offset frames around '{frame_path}' form a cycle"),
        ))
    }

    /// Resolve the socket `socket` of the component at `owner_path` to
    /// (body name, transform of the frame in that body).
    pub fn resolve_frame(
        &self,
        owner_path: &str,
        socket: &str,
    ) -> Result<(String, Isometry3<f64>)> {
        let p = self.resolve_socket(owner_path, socket).ok_or_else(|| {
            Error::invalid(
                self.file.display().to_string(),
                format!("socket path '{socket}' (from {owner_path}) does not name a frame"),
            )
        })?;
        self.frame_in_body(&p)
    }

    /// Each joint's parent and child bodies and its frames in them.
    pub fn joint_frames(&self) -> Result<Vec<JointFrames>> {
        self.joints
            .iter()
            .map(|j| {
                let owner = format!("/jointset/{}", j.name);
                let (pb, px) = self.resolve_frame(&owner, &j.socket_parent_frame)?;
                let (cb, cxf) = self.resolve_frame(&owner, &j.socket_child_frame)?;
                Ok(JointFrames {
                    joint: j.name.clone(),
                    parent_body: pb,
                    parent_in_body: px,
                    child_body: cb,
                    child_in_body: cxf,
                })
            })
            .collect()
    }

    /// Body and transform of a marker's frame.
    pub fn marker_frame(&self, marker: &Marker) -> Result<(String, Isometry3<f64>)> {
        self.resolve_frame(
            &format!("/markerset/{}", marker.name),
            &marker.socket_parent_frame,
        )
    }

    /// All coordinates in joint order.
    pub fn coordinates(&self) -> impl Iterator<Item = &Coordinate> {
        self.joints.iter().flat_map(|j| j.coordinates.iter())
    }

    /// Body by name.
    pub fn body(&self, name: &str) -> Option<&Body> {
        self.bodies.iter().find(|b| b.name == name)
    }

    /// Joint by name.
    pub fn joint(&self, name: &str) -> Option<&Joint> {
        self.joints.iter().find(|j| j.name == name)
    }

    /// Muscles in file order.
    pub fn muscles(&self) -> impl Iterator<Item = &Muscle> {
        self.forces.iter().filter_map(|f| match f {
            Force::Muscle(m) => Some(m.as_ref()),
            _ => None,
        })
    }

    /// Bushing forces in file order.
    pub fn bushings(&self) -> impl Iterator<Item = &BushingForce> {
        self.forces.iter().filter_map(|f| match f {
            Force::Bushing(b) => Some(b),
            _ => None,
        })
    }

    /// Every mesh file referenced (ground and bodies), with its body.
    pub fn mesh_files(&self) -> Vec<(String, String)> {
        let mut out = Vec::new();
        let all = std::iter::once(("ground", &self.ground.geometry))
            .chain(self.bodies.iter().map(|b| (b.name.as_str(), &b.geometry)));
        for (body, geoms) in all {
            for g in geoms {
                if let Geometry::Mesh { mesh_file, .. } = g {
                    if mesh_file.is_empty() {
                        continue;
                    }
                    out.push((body.to_string(), mesh_file.clone()));
                }
            }
        }
        out
    }

    fn validate(&self, m: &Element, jointset: &str, forceset: &str, cx: &Ctx) -> Result<()> {
        // Joint frames resolve, and each body is the child of one joint.
        let child_of = self.joint_parents(m, jointset, cx)?;
        // Every body reaches ground through the joints (no cycles).
        self.check_grounded(&child_of, cx)?;
        // Force sockets, path points and wrap objects resolve.
        let coords: BTreeSet<&str> = self.coordinates().map(|c| c.name.as_str()).collect();
        self.check_force_sockets(m, forceset, &coords, cx)?;
        // Marker frames and coupled coordinates resolve.
        for (mk, el) in self.markers.iter().zip(objects(m, "MarkerSet")) {
            if self
                .resolve_socket(&format!("/markerset/{}", mk.name), &mk.socket_parent_frame)
                .is_none()
            {
                return Err(cx.err(
                    el,
                    format!("socket_parent_frame '{}' does not name a frame in the model (dangling socket)", mk.socket_parent_frame),
                ));
            }
        }
        for (c, el) in self.constraints.iter().zip(objects(m, "ConstraintSet")) {
            if let Constraint::CoordinateCoupler {
                independent,
                dependent,
                ..
            } = c
            {
                for n in independent.iter().chain(std::iter::once(dependent)) {
                    if !coords.contains(n.as_str()) {
                        return Err(cx.err(el, format!("coordinate '{n}' is not in the model")));
                    }
                }
            }
        }
        Ok(())
    }

    /// Body -> (parent body, joint) of every joint, its sockets resolved:
    /// no joint connects a body to itself or has ground as child, and no
    /// body is the child of two joints.
    fn joint_parents(
        &self,
        m: &Element,
        jointset: &str,
        cx: &Ctx,
    ) -> Result<BTreeMap<String, (String, String)>> {
        let joint_els: Vec<&Element> = objects(m, "JointSet").collect();
        let mut child_of: BTreeMap<String, (String, String)> = BTreeMap::new(); // child -> (parent, joint)
        for (j, el) in self.joints.iter().zip(joint_els.iter()) {
            let owner = format!("/{jointset}/{}", j.name);
            let sockets = [
                ("socket_parent_frame", &j.socket_parent_frame),
                ("socket_child_frame", &j.socket_child_frame),
            ];
            let mut bodies = Vec::new();
            for (prop, s) in sockets {
                let p = self.resolve_socket(&owner, s).ok_or_else(|| {
                    cx.err(
                        el,
                        format!(
                            "{prop} '{s}' does not name a frame in the model (dangling socket)"
                        ),
                    )
                })?;
                bodies.push(
                    self.frame_in_body(&p)
                        .map_err(|e| cx.err(el, e.to_string()))?
                        .0,
                );
            }
            let (parent, child) = (bodies[0].clone(), bodies[1].clone());
            if parent == child {
                return Err(cx.err(el, format!("joint connects body '{parent}' to itself")));
            }
            if child == "ground" {
                return Err(cx.err(el, "ground cannot be the child of a joint"));
            }
            if let Some((_, other)) = child_of.insert(child.clone(), (parent, j.name.clone())) {
                return Err(cx.err(
                    el,
                    format!("body '{child}' is the child of two joints ('{other}' and '{}'): closed loops are not supported", j.name),
                ));
            }
        }
        Ok(child_of)
    }

    /// Every body has a joint path to ground, and none is its own ancestor.
    fn check_grounded(
        &self,
        child_of: &BTreeMap<String, (String, String)>,
        cx: &Ctx,
    ) -> Result<()> {
        let file = cx.file;
        // Bodies already shown to reach ground: each walk stops at one, so
        // the check is linear in the body count (a chain is not quadratic).
        let mut grounded: BTreeSet<String> = BTreeSet::new();
        for b in &self.bodies {
            let mut seen = BTreeSet::new();
            let mut cur = b.name.clone();
            while cur != "ground" && !grounded.contains(&cur) {
                if !seen.insert(cur.clone()) {
                    return Err(Error::parse(
                        file,
                        format!("<Body name=\"{}\"> (line {})", b.name, b.line),
                        format!(
                            "cyclic joint graph: body '{}' is its own ancestor (through '{}')",
                            cur,
                            seen.iter().cloned().collect::<Vec<_>>().join(", ")
                        ),
                    ));
                }
                match child_of.get(&cur) {
                    Some((parent, _)) => cur = parent.clone(),
                    None => {
                        return Err(Error::parse(
                            file,
                            format!("<Body name=\"{}\"> (line {})", b.name, b.line),
                            format!("body has no joint path to ground (body '{cur}' is not the child of any joint)"),
                        ));
                    }
                }
            }
            grounded.extend(seen);
        }
        Ok(())
    }

    /// Bushing frames, muscle path points (frames and coordinates) and the
    /// wrap objects of PathWraps resolve.
    fn check_force_sockets(
        &self,
        m: &Element,
        forceset: &str,
        coords: &BTreeSet<&str>,
        cx: &Ctx,
    ) -> Result<()> {
        let force_els: Vec<&Element> = objects(m, "ForceSet").collect();
        let wraps: BTreeSet<&str> = self
            .bodies
            .iter()
            .flat_map(|b| b.wrap_objects.iter())
            .chain(self.ground.wrap_objects.iter())
            .map(|w| w.name.as_str())
            .collect();
        for (f, el) in self.forces.iter().zip(force_els.iter()) {
            let owner = format!("/{forceset}/{}", f.name());
            let check = |prop: &str, s: &str| -> Result<()> {
                self.resolve_socket(&owner, s).map(|_| ()).ok_or_else(|| {
                    cx.err(
                        el,
                        format!(
                            "{prop} '{s}' does not name a frame in the model (dangling socket)"
                        ),
                    )
                })
            };
            match f {
                Force::Bushing(b) => {
                    check("socket_frame1", &b.socket_frame1)?;
                    check("socket_frame2", &b.socket_frame2)?;
                }
                Force::OtherBushing(b) => {
                    check("socket_frame1", &b.socket_frame1)?;
                    check("socket_frame2", &b.socket_frame2)?;
                }
                Force::Muscle(mu) => self.check_muscle(mu, &owner, coords, &wraps, el, cx)?,
                Force::Other { .. } => {}
            }
        }
        Ok(())
    }

    /// The path points of muscle `mu` (owned by `owner`) name frames and
    /// coordinates of the model; its PathWraps name wrap objects of a body.
    fn check_muscle(
        &self,
        mu: &Muscle,
        owner: &str,
        coords: &BTreeSet<&str>,
        wraps: &BTreeSet<&str>,
        el: &Element,
        cx: &Ctx,
    ) -> Result<()> {
        for p in &mu.points {
            let pp = format!("{owner}/path/{}", p.name);
            if self.resolve_socket(&pp, &p.socket_parent_frame).is_none() {
                return Err(cx.err(
                    el,
                    format!(
                        "path point '{}': socket_parent_frame '{}' does not name a frame in the model (dangling socket)",
                        p.name, p.socket_parent_frame
                    ),
                ));
            }
            let cs: Vec<&String> = match &p.kind {
                PathPointKind::Fixed => vec![],
                PathPointKind::Conditional { coordinate, .. } => vec![coordinate],
                PathPointKind::Moving { x, y, z } => [x, y, z]
                    .iter()
                    .filter_map(|o| o.as_ref().map(|b| &b.1))
                    .collect(),
            };
            for c in cs {
                let name = c.rsplit('/').next().unwrap_or(c);
                if !coords.contains(name) {
                    return Err(cx.err(
                        el,
                        format!("path point '{}': coordinate '{c}' is not in the model (dangling socket)", p.name),
                    ));
                }
            }
        }
        for w in &mu.wraps {
            if !wraps.contains(w.wrap_object.as_str()) {
                return Err(cx.err(
                    el,
                    format!(
                        "PathWrap names wrap object '{}', which no body has",
                        w.wrap_object
                    ),
                ));
            }
        }
        Ok(())
    }
}

/// Children of `<Set><objects>` of the Model.
fn objects<'a>(m: &'a Element, set: &str) -> impl Iterator<Item = &'a Element> {
    m.child(set)
        .and_then(|s| s.child("objects"))
        .into_iter()
        .flat_map(|o| o.elements())
}

fn required_text(e: &Element, prop: &str, cx: &Ctx) -> Result<String> {
    match e.child(prop) {
        Some(c) => {
            let t = c.text().trim().to_string();
            if t.is_empty() {
                Err(cx.err(c, format!("<{prop}> is empty")))
            } else {
                Ok(t)
            }
        }
        None => Err(cx.err(e, format!("missing required property <{prop}>"))),
    }
}

/// Every PhysicalOffsetFrame in the model with its absolute path.
fn collect_offset_frames<'a>(
    e: &'a Element,
    path: &mut Vec<String>,
    cx: &Ctx,
    out: &mut Vec<(OffsetFrame, &'a Element)>,
) -> Result<()> {
    for c in e.elements() {
        // Leaves (text-only properties) hold no components.
        if c.children
            .iter()
            .all(|n| !matches!(n, super::xml::Node::Element(_)))
        {
            continue;
        }
        // Path segment: sets use their name (default: lower-case class),
        // components their name; lists/properties add nothing.
        let seg = if c.name.ends_with("Set") && c.child("objects").is_some() {
            Some(set_name(c))
        } else {
            c.attr("name").filter(|n| !n.is_empty()).map(str::to_string)
        };
        let pushed = seg.is_some();
        if let Some(s) = seg {
            path.push(s);
        }
        if c.name == "PhysicalOffsetFrame" {
            let name = c.name_attr().to_string();
            if name.is_empty() {
                return Err(cx.err(c, "PhysicalOffsetFrame without a name"));
            }
            out.push((
                OffsetFrame {
                    name,
                    path: format!("/{}", path.join("/")),
                    socket_parent: required_text(c, "socket_parent", cx)?,
                    translation: vec3_or(c, "translation", Vector3::zeros(), cx.file)?,
                    orientation: vec3_or(c, "orientation", Vector3::zeros(), cx.file)?,
                    line: c.line,
                },
                c,
            ));
        }
        collect_offset_frames(c, path, cx, out)?;
        if pushed {
            path.pop();
        }
    }
    Ok(())
}

/// The offset frames of the document by the address of their element, so
/// a component's `<frames>` are found in constant time (a linear scan per
/// component made reading a long chain quadratic).
struct FrameTable<'a> {
    by_el: std::collections::HashMap<*const Element, &'a OffsetFrame>,
}

impl<'a> FrameTable<'a> {
    fn new(all: &'a [(OffsetFrame, &'a Element)]) -> Self {
        let by_el = all
            .iter()
            .map(|(o, el)| (*el as *const Element, o))
            .collect();
        FrameTable { by_el }
    }
}

fn frames_of(owner: &Element, all: &FrameTable) -> Vec<OffsetFrame> {
    let Some(list) = owner.child("frames") else {
        return vec![];
    };
    list.elements()
        .filter_map(|f| all.by_el.get(&(f as *const Element)).map(|o| (*o).clone()))
        .collect()
}

fn parse_geometry(frame: &Element, cx: &Ctx) -> Result<Vec<Geometry>> {
    let mut out = Vec::new();
    let Some(list) = frame.child("attached_geometry") else {
        return Ok(out);
    };
    for g in list.elements() {
        if g.name == "Mesh" {
            out.push(Geometry::Mesh {
                name: g.name_attr().to_string(),
                mesh_file: str_prop(g, "mesh_file").unwrap_or_default(),
                scale_factors: vec3_or(g, "scale_factors", Vector3::new(1.0, 1.0, 1.0), cx.file)?,
            });
        } else {
            out.push(Geometry::Other {
                class: g.name.clone(),
                name: g.name_attr().to_string(),
            });
        }
    }
    Ok(out)
}

fn parse_wraps(frame: &Element, body: &str, cx: &Ctx) -> Result<Vec<WrapObject>> {
    let mut out = Vec::new();
    let Some(list) = frame
        .child("WrapObjectSet")
        .and_then(|s| s.child("objects"))
    else {
        return Ok(out);
    };
    let f = cx.file;
    for w in list.elements() {
        let shape = match w.name.as_str() {
            "WrapSphere" => WrapShape::Sphere {
                radius: f64_or(w, "radius", 0.0, f)?,
            },
            "WrapCylinder" => WrapShape::Cylinder {
                radius: f64_or(w, "radius", 0.0, f)?,
                length: f64_or(w, "length", 0.0, f)?,
            },
            "WrapEllipsoid" => WrapShape::Ellipsoid {
                dimensions: vec3_or(w, "dimensions", Vector3::zeros(), f)?,
            },
            "WrapTorus" => WrapShape::Torus {
                inner_radius: f64_or(w, "inner_radius", 0.0, f)?,
                outer_radius: f64_or(w, "outer_radius", 0.0, f)?,
            },
            other => WrapShape::Other {
                class: other.into(),
            },
        };
        out.push(WrapObject {
            name: w.name_attr().to_string(),
            body: body.to_string(),
            translation: vec3_or(w, "translation", Vector3::zeros(), f)?,
            xyz_body_rotation: vec3_or(w, "xyz_body_rotation", Vector3::zeros(), f)?,
            quadrant: str_prop(w, "quadrant").unwrap_or_else(|| "all".into()),
            active: bool_or(w, "active", true, f)?,
            shape,
        });
    }
    Ok(out)
}

fn parse_joint(j: &Element, set_path: &str, cx: &Ctx, all_frames: &FrameTable) -> Result<Joint> {
    let f = cx.file;
    let name = j.name_attr().to_string();
    if name.is_empty() {
        return Err(cx.err(j, "joint without a name"));
    }
    let _ = set_path;
    let class = j.name.clone();
    let mut axes = Vec::new();
    let kind = match class.as_str() {
        "WeldJoint" => JointKind::Weld,
        "PinJoint" => JointKind::Pin,
        "FreeJoint" => JointKind::Free,
        "CustomJoint" => {
            let st = j
                .child("SpatialTransform")
                .ok_or_else(|| cx.err(j, "CustomJoint without a <SpatialTransform>"))?;
            for ax_name in [
                "rotation1",
                "rotation2",
                "rotation3",
                "translation1",
                "translation2",
                "translation3",
            ] {
                let ax = st
                    .elements()
                    .find(|e| e.name == "TransformAxis" && e.attr("name") == Some(ax_name))
                    .ok_or_else(|| {
                        cx.err(st, format!("missing <TransformAxis name=\"{ax_name}\">"))
                    })?;
                let coordinates: Vec<String> = ax
                    .child_text("coordinates")
                    .unwrap_or_default()
                    .split_whitespace()
                    .map(str::to_string)
                    .collect();
                let axis = vec3_prop(ax, "axis", f)?;
                if axis.norm() < 1e-12 {
                    return Err(cx.err(ax, "axis is the zero vector"));
                }
                let function = if Function::element_in(ax).is_some() {
                    Function::from_parent(ax, f)?
                } else if coordinates.is_empty() {
                    Function::Constant(0.0)
                } else {
                    return Err(cx.err(ax, "missing the function of the TransformAxis"));
                };
                if coordinates.len() > 1 {
                    return Err(cx.err(
                        ax,
                        "TransformAxis with more than one coordinate is not supported",
                    ));
                }
                axes.push(TransformAxis {
                    name: ax_name.to_string(),
                    coordinates,
                    axis,
                    function,
                });
            }
            JointKind::Custom { axes: axes.clone() }
        }
        _ => JointKind::Other,
    };
    let mut coordinates = Vec::new();
    if let Some(list) = j.child("coordinates") {
        for c in list.elements().filter(|e| e.name == "Coordinate") {
            let cname = c.name_attr().to_string();
            if cname.is_empty() {
                return Err(cx.err(c, "coordinate without a name"));
            }
            let range = match opt_numbers(c, "range", f)? {
                Some(v) if v.len() == 2 => [v[0], v[1]],
                Some(_) => {
                    return Err(cx.err(c.child("range").unwrap_or(c), "range needs 2 numbers"))
                }
                None => [-10.0, 10.0],
            };
            if range[0] > range[1] {
                return Err(cx.err(c, format!("range min {} > max {}", range[0], range[1])));
            }
            let motion_type = match str_prop(c, "motion_type").as_deref() {
                Some("rotational") => MotionType::Rotational,
                Some("translational") => MotionType::Translational,
                Some("coupled") => MotionType::Coupled,
                Some(other) if !other.is_empty() => {
                    return Err(cx.err(c, format!("unknown motion_type '{other}'")));
                }
                _ => motion_from_joint(&class, &axes, &cname, coordinates.len()),
            };
            let default_value = f64_or(c, "default_value", 0.0, f)?;
            if let Some(why) = super::physics::default_error(default_value) {
                return Err(cx.err(c, why));
            }
            coordinates.push(Coordinate {
                name: cname,
                joint: name.clone(),
                default_value,
                default_speed_value: f64_or(c, "default_speed_value", 0.0, f)?,
                range,
                clamped: bool_or(c, "clamped", false, f)?,
                locked: bool_or(c, "locked", false, f)?,
                prescribed: bool_or(c, "prescribed", false, f)?,
                motion_type,
                line: c.line,
            });
        }
    }
    if let JointKind::Custom { axes } = &kind {
        for ax in axes {
            for cn in &ax.coordinates {
                if !coordinates.iter().any(|c| &c.name == cn) {
                    return Err(cx.err(
                        j,
                        format!(
                            "TransformAxis {} uses coordinate '{cn}', which the joint does not own",
                            ax.name
                        ),
                    ));
                }
            }
        }
    }
    Ok(Joint {
        socket_parent_frame: required_text(j, "socket_parent_frame", cx)?,
        socket_child_frame: required_text(j, "socket_child_frame", cx)?,
        frames: frames_of(j, all_frames),
        name,
        class,
        kind,
        coordinates,
        line: j.line,
    })
}

fn motion_from_joint(class: &str, axes: &[TransformAxis], coord: &str, index: usize) -> MotionType {
    match class {
        "CustomJoint" => {
            let rot = axes[..3.min(axes.len())]
                .iter()
                .any(|a| a.coordinates.iter().any(|c| c == coord));
            let tr = axes
                .iter()
                .skip(3)
                .any(|a| a.coordinates.iter().any(|c| c == coord));
            match (rot, tr) {
                (true, true) => MotionType::Coupled,
                (false, true) => MotionType::Translational,
                _ => MotionType::Rotational,
            }
        }
        "SliderJoint" => MotionType::Translational,
        "FreeJoint" if index >= 3 => MotionType::Translational,
        "PlanarJoint" if index >= 1 => MotionType::Translational,
        _ => MotionType::Rotational,
    }
}

/// `b` when its stiffness and damping are finite and bounded
/// ([`super::physics::stiffness_error`]).
fn checked_bushing(b: BushingForce, fe: &Element, cx: &Ctx) -> Result<BushingForce> {
    let props = [
        ("rotational_stiffness", &b.rotational_stiffness),
        ("translational_stiffness", &b.translational_stiffness),
        ("rotational_damping", &b.rotational_damping),
        ("translational_damping", &b.translational_damping),
    ];
    for (prop, v) in props {
        if let Some(why) = super::physics::stiffness_error(prop, v.as_slice()) {
            return Err(cx.err(fe.child(prop).unwrap_or(fe), why));
        }
    }
    Ok(b)
}

fn parse_force(fe: &Element, cx: &Ctx, all_frames: &FrameTable) -> Result<Force> {
    let f = cx.file;
    let name = fe.name_attr().to_string();
    let class = fe.name.clone();
    Ok(match class.as_str() {
        "BushingForce" => Force::Bushing(checked_bushing(
            BushingForce {
                socket_frame1: required_text(fe, "socket_frame1", cx)?,
                socket_frame2: required_text(fe, "socket_frame2", cx)?,
                frames: frames_of(fe, all_frames),
                rotational_stiffness: vec3_or(fe, "rotational_stiffness", Vector3::zeros(), f)?,
                translational_stiffness: vec3_or(
                    fe,
                    "translational_stiffness",
                    Vector3::zeros(),
                    f,
                )?,
                rotational_damping: vec3_or(fe, "rotational_damping", Vector3::zeros(), f)?,
                translational_damping: vec3_or(fe, "translational_damping", Vector3::zeros(), f)?,
                name,
            },
            fe,
            cx,
        )?),
        "FunctionBasedBushingForce" | "ExpressionBasedBushingForce" => {
            Force::OtherBushing(OtherBushing {
                socket_frame1: required_text(fe, "socket_frame1", cx)?,
                socket_frame2: required_text(fe, "socket_frame2", cx)?,
                frames: frames_of(fe, all_frames),
                properties: fe
                    .elements()
                    .filter(|c| {
                        !matches!(
                            c.name.as_str(),
                            "socket_frame1" | "socket_frame2" | "frames"
                        )
                    })
                    .map(|c| (c.name.clone(), c.text().trim().to_string()))
                    .collect(),
                functions: fe
                    .elements()
                    .filter(|c| Function::element_in(c).is_some())
                    .map(|c| Ok((c.name.clone(), Function::from_parent(c, f)?)))
                    .collect::<Result<_>>()?,
                name,
                class,
            })
        }
        _ if fe.child("GeometryPath").is_some() && fe.child("max_isometric_force").is_some() => {
            let path = fe.child("GeometryPath").unwrap_or(fe);
            let pennation = match fe
                .child("pennation_angle_at_optimal")
                .or_else(|| fe.child("pennation_angle"))
            {
                Some(p) => Some(f64_prop(fe, &p.name, f)?),
                None => None,
            };
            Force::Muscle(Box::new(Muscle {
                max_isometric_force: f64_prop(fe, "max_isometric_force", f)?,
                optimal_fiber_length: f64_prop(fe, "optimal_fiber_length", f)?,
                tendon_slack_length: f64_prop(fe, "tendon_slack_length", f)?,
                pennation_angle: pennation,
                points: parse_path_points(path, cx)?,
                wraps: parse_path_wraps(path, cx)?,
                name,
                class,
            }))
        }
        _ => Force::Other { class, name },
    })
}

fn parse_path_points(path: &Element, cx: &Ctx) -> Result<Vec<PathPoint>> {
    let f = cx.file;
    let mut out = Vec::new();
    let Some(list) = path.child("PathPointSet").and_then(|s| s.child("objects")) else {
        return Err(cx.err(path, "GeometryPath without a <PathPointSet>"));
    };
    for p in list.elements() {
        let kind = match p.name.as_str() {
            "PathPoint" => PathPointKind::Fixed,
            "ConditionalPathPoint" => {
                let r = fixed_prop(p, "range", 2, f)?;
                PathPointKind::Conditional {
                    coordinate: required_text(p, "socket_coordinate", cx)?,
                    range: [r[0], r[1]],
                }
            }
            "MovingPathPoint" => {
                let axis = |loc_prop: &str, sock: &str| -> Result<Option<(Function, String)>> {
                    match p.child(loc_prop) {
                        Some(l) => Ok(Some((
                            Function::from_parent(l, f)?,
                            required_text(p, sock, cx)?,
                        ))),
                        None => Ok(None),
                    }
                };
                PathPointKind::Moving {
                    x: axis("x_location", "socket_x_coordinate")?.map(Box::new),
                    y: axis("y_location", "socket_y_coordinate")?.map(Box::new),
                    z: axis("z_location", "socket_z_coordinate")?.map(Box::new),
                }
            }
            other => return Err(cx.err(p, format!("unknown path point class '{other}'"))),
        };
        out.push(PathPoint {
            name: p.name_attr().to_string(),
            socket_parent_frame: required_text(p, "socket_parent_frame", cx)?,
            location: vec3_or(p, "location", Vector3::zeros(), f)?,
            kind,
        });
    }
    Ok(out)
}

fn parse_path_wraps(path: &Element, cx: &Ctx) -> Result<Vec<PathWrap>> {
    let f = cx.file;
    let mut out = Vec::new();
    let Some(list) = path.child("PathWrapSet").and_then(|s| s.child("objects")) else {
        return Ok(out);
    };
    for w in list.elements() {
        let range = match opt_numbers(w, "range", f)? {
            Some(v) if v.len() == 2 => [v[0] as i64, v[1] as i64],
            Some(_) => return Err(cx.err(w, "range needs 2 integers")),
            None => [-1, -1],
        };
        out.push(PathWrap {
            wrap_object: required_text(w, "wrap_object", cx)?,
            method: str_prop(w, "method").unwrap_or_else(|| "hybrid".into()),
            range,
        });
    }
    Ok(out)
}

fn parse_constraint(c: &Element, cx: &Ctx) -> Result<Constraint> {
    let f = cx.file;
    Ok(match c.name.as_str() {
        "CoordinateCouplerConstraint" => Constraint::CoordinateCoupler {
            name: c.name_attr().to_string(),
            independent: required_text(c, "independent_coordinate_names", cx)?
                .split_whitespace()
                .map(str::to_string)
                .collect(),
            dependent: required_text(c, "dependent_coordinate_name", cx)?,
            function: {
                let holder = c.child("coupled_coordinates_function").ok_or_else(|| {
                    cx.err(
                        c,
                        "missing required property <coupled_coordinates_function>",
                    )
                })?;
                let fe = holder
                    .elements()
                    .next()
                    .ok_or_else(|| cx.err(holder, "empty <coupled_coordinates_function>"))?;
                Function::from_element(fe, f)?
            },
            scale_factor: f64_or(c, "scale_factor", 1.0, f)?,
            enforced: bool_or(c, "isEnforced", true, f)?,
        },
        other => Constraint::Other {
            class: other.to_string(),
            name: c.name_attr().to_string(),
        },
    })
}

impl Document {
    /// Typed model snapshot (SI, validated). See [`Model`].
    pub fn model(&self) -> Result<Model> {
        Model::from_document(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn path_joining() {
        assert_eq!(
            join_path("/jointset/j", "ground_offset").unwrap(),
            "/jointset/j/ground_offset"
        );
        assert_eq!(
            join_path("/jointset/j/f", "../../../bodyset/L5").unwrap(),
            "/bodyset/L5"
        );
        assert_eq!(join_path("/jointset/j", "/ground").unwrap(), "/ground");
        assert_eq!(join_path("/bodyset/b/g", "..").unwrap(), "/bodyset/b");
        assert!(join_path("/a", "../../x").is_none());
    }

    #[test]
    fn xyz_angles_invert_body_fixed_xyz() {
        for v in [
            Vector3::new(0.1, -0.4, 0.7),
            Vector3::new(-1.2, 0.3, -2.9),
            Vector3::new(0.0, 0.0, 0.0),
        ] {
            let back = xyz_angles(&body_fixed_xyz(&v));
            assert!((back - v).norm() < 1e-12, "{v:?} -> {back:?}");
        }
    }

    #[test]
    fn body_fixed_xyz_order() {
        let a = Vector3::new(0.3, -0.2, 0.5);
        let r = body_fixed_xyz(&a);
        // R = Rx Ry Rz: rotating e_z by Rz leaves it, then Ry, then Rx.
        let rz_first = Rotation3::from_axis_angle(&Vector3::x_axis(), 0.3)
            * (Rotation3::from_axis_angle(&Vector3::y_axis(), -0.2) * Vector3::z());
        assert!((r * Vector3::z() - rz_first).norm() < 1e-15);
    }
}
