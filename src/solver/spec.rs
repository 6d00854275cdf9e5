//! The solver's own input description ([`SystemSpec`]) and the load
//! description ([`Load`]). A spec is plain data: it says what the multibody
//! system is, in SI units, with indices instead of names where things refer
//! to each other. [`crate::solver::System::new`] validates and compiles it.
//!
//! Conventions (OpenSim 4.6 / Simbody, see `../shared/oracle/README.md`):
//! a joint connects frame F (fixed in the parent, pose `x_pf`) and frame M
//! (fixed in the child, pose `x_bm`); the child pose is
//! `X_GB = X_GP X_PF X_FM(q) inv(X_BM)`. Every joint kind is a special case
//! of the six-axis function-based transform of a CustomJoint:
//! `R_FM = R(a0, f0) R(a1, f1) R(a2, f2)` (each rotation about its axis in the
//! frame produced by the previous ones) and `p_FM = f3 a3 + f4 a4 + f5 a5`
//! (along F's axes), with unit axes.
//!
//! Generalised speeds `u` are the coordinate rates (`u = qdot`) for every
//! joint kind except [`JointKind::Free`] and [`JointKind::Ball`], whose
//! rotational speeds are OpenSim's: the angular velocity `w_FM` in F axes.

pub use super::expr::Expr;
pub use crate::osim::function::Function;
use nalgebra::{Isometry3, Matrix3, Matrix6, Vector3};

/// A whole multibody system: bodies, tree joints, coordinates, bushings, gravity.
#[derive(Debug, Clone)]
pub struct SystemSpec {
    /// Bodies (ground excluded). Index = body id used everywhere in the spec.
    pub bodies: Vec<BodySpec>,
    /// Tree joints, one per body (the joint whose child it is), any order.
    pub joints: Vec<JointSpec>,
    /// Generalised coordinates referenced by the joints' transform axes.
    pub coordinates: Vec<CoordinateSpec>,
    /// Bushing forces between pairs of frames.
    pub bushings: Vec<BushingSpec>,
    /// Gravity in ground (m/s^2).
    pub gravity: Vector3<f64>,
}

/// A rigid body.
#[derive(Debug, Clone)]
pub struct BodySpec {
    /// Body name (for messages and results).
    pub name: String,
    /// Mass (kg).
    pub mass: f64,
    /// Centre of mass in the body frame (m).
    pub com: Vector3<f64>,
    /// Inertia about the centre of mass, body axes (kg m^2).
    pub inertia: Matrix3<f64>,
}

/// A tree joint between `parent` (None = ground) and `child`.
#[derive(Debug, Clone)]
pub struct JointSpec {
    /// Joint name (for messages and results).
    pub name: String,
    /// Index of the parent body in [`SystemSpec::bodies`] (None = ground).
    pub parent: Option<usize>,
    /// Index of the child body in [`SystemSpec::bodies`].
    pub child: usize,
    /// Pose of the joint frame F in the parent body (X_PF).
    pub x_pf: Isometry3<f64>,
    /// Pose of the joint frame M in the child body (X_BM).
    pub x_bm: Isometry3<f64>,
    /// How M moves relative to F.
    pub kind: JointKind,
}

/// Joint kinds. All of them are lowered to six transform axes.
#[derive(Debug, Clone)]
pub enum JointKind {
    /// No relative motion.
    Weld,
    /// Rotation about F's Z axis (OpenSim PinJoint).
    Pin {
        /// Index of the angle's coordinate in [`SystemSpec::coordinates`].
        coord: usize,
    },
    /// Rotation about X then about the new Y (OpenSim UniversalJoint).
    Universal {
        /// Indices of the X and Y angles' coordinates.
        coords: [usize; 2],
    },
    /// Translation along F's X axis (OpenSim SliderJoint).
    Slider {
        /// Index of the translation's coordinate in [`SystemSpec::coordinates`].
        coord: usize,
    },
    /// OpenSim FreeJoint: body-fixed X-Y-Z rotations then translation
    /// along F's axes. As in OpenSim 4.6 (Simbody's Free mobilizer with
    /// Euler angles), the three rotational generalised speeds are the
    /// angular velocity of M in F expressed in F (`u_rot = w_FM`, not the
    /// angle rates: `qdot_rot = N(q) u_rot`); the translational speeds are
    /// the coordinate rates. See [`crate::solver::System::qdot`].
    Free {
        /// Indices of the X, Y, Z angles' then the X, Y, Z translations' coordinates.
        coords: [usize; 6],
    },
    /// OpenSim BallJoint: body-fixed X-Y-Z rotations, no translation; the
    /// generalised speeds are the angular velocity of M in F expressed in F
    /// (Simbody's Ball mobilizer with Euler angles), like [`JointKind::Free`].
    Ball {
        /// Indices of the X, Y, Z angles' coordinates.
        coords: [usize; 3],
    },
    /// OpenSim CustomJoint: rotation1..3 then translation1..3.
    Custom {
        /// rotation1..3 then translation1..3.
        axes: Box<[TransformAxis; 6]>,
    },
}

/// One of a CustomJoint's six transform axes.
#[derive(Debug, Clone)]
pub struct TransformAxis {
    /// Axis direction (normalised when the system is built).
    pub axis: Vector3<f64>,
    /// Coordinate driving the function, or None for a constant function.
    pub coord: Option<usize>,
    /// Function of the coordinate giving the angle (rad) or displacement (m).
    pub function: Function,
}

impl TransformAxis {
    /// An axis driven one-to-one by a coordinate.
    pub fn identity(axis: Vector3<f64>, coord: usize) -> Self {
        TransformAxis {
            axis,
            coord: Some(coord),
            function: Function::Linear {
                slope: 1.0,
                intercept: 0.0,
            },
        }
    }
    /// An axis that does not move.
    pub fn fixed(axis: Vector3<f64>) -> Self {
        TransformAxis {
            axis,
            coord: None,
            function: Function::Constant(0.0),
        }
    }
}

/// A generalised coordinate.
#[derive(Debug, Clone)]
pub struct CoordinateSpec {
    /// Coordinate name (for messages and results).
    pub name: String,
    /// Default value (rad or m); locked coordinates are held here.
    pub default: f64,
    /// Allowed range [min, max].
    pub range: [f64; 2],
    /// When true, a result outside `range` is reported.
    pub clamped: bool,
    /// When true, the coordinate is held at `default` (no degree of freedom).
    pub locked: bool,
}

/// A frame fixed in a body (None = ground) at a transform.
#[derive(Debug, Clone)]
pub struct FrameSpec {
    /// Index of the body in [`SystemSpec::bodies`] (None = ground).
    pub body: Option<usize>,
    /// X_BF: the frame's pose in its body.
    pub transform: Isometry3<f64>,
}

/// A bushing force between frame 1 (F) and frame 2 (M).
#[derive(Debug, Clone)]
pub struct BushingSpec {
    /// Bushing name (for messages and results).
    pub name: String,
    /// Frame 1 (F), the reference of the deflection.
    pub frame1: FrameSpec,
    /// Frame 2 (M), whose deflection in frame 1 is measured.
    pub frame2: FrameSpec,
    /// The force law.
    pub model: BushingModel,
}

/// Names of the six deflection components, in order.
pub const DOF_NAMES: [&str; 6] = ["rx", "ry", "rz", "tx", "ty", "tz"];

/// Force-deflection curve of one degree of freedom: `g(x)` (N m or N) for a
/// deflection `x` (rad or m); the generalised force is `-g(x)`.
#[derive(Debug, Clone, PartialEq)]
pub enum Curve {
    /// `k x`
    Linear {
        /// Stiffness (N m/rad or N/m).
        k: f64,
    },
    /// `k x + c x^3` (OpenSim PolynomialFunction `[c, 0, k, 0]`).
    Cubic {
        /// Linear stiffness (N m/rad or N/m).
        k: f64,
        /// Cubic coefficient (N m/rad^3 or N/m^3).
        c: f64,
    },
    /// Neutral-zone curve `k a sinh(x / a)`: slope `k` at zero, stiffening
    /// with the deflection on the scale `a` (rad or m).
    Sinh {
        /// Slope at zero deflection (N m/rad or N/m).
        k: f64,
        /// Deflection scale of the stiffening (rad or m).
        a: f64,
    },
    /// Slope `k_neg` for `x < 0` and `k_pos` for `x >= 0` (asymmetric).
    Bilinear {
        /// Slope for negative deflections (N m/rad or N/m).
        k_neg: f64,
        /// Slope for zero and positive deflections (N m/rad or N/m).
        k_pos: f64,
    },
    /// Any function of the deflection (points, splines, polynomials), as
    /// OpenSim evaluates it.
    Function(Function),
}

/// Bushing force laws acting on the deflection vector
/// `q = (rx, ry, rz, tx, ty, tz)`: body-fixed X-Y-Z angles of frame 2 in frame 1
/// and the origin of frame 2 in frame 1. Every law gives the generalised
/// force `f = -g(q) - C q'` with a diagonal damping `C`; see
/// [`crate::solver::law`] for `g` and the OpenSim class of each law. The
/// kinematics and the way `f` is applied (moment through the transpose of
/// the angle-rate map) are the same for every law.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
#[allow(clippy::large_enum_variant)] // laws are built once per bushing, never in hot loops
pub enum BushingModel {
    /// OpenSim BushingForce: `f = -(K q + C q')` element by element.
    Linear {
        /// Nm/rad about the X, Y, Z deflection angles.
        rot_stiffness: Vector3<f64>,
        /// N/m along X, Y, Z of frame 1.
        trans_stiffness: Vector3<f64>,
        /// Nm/(rad/s)
        rot_damping: Vector3<f64>,
        /// N/(m/s)
        trans_damping: Vector3<f64>,
    },
    /// OpenSim FunctionBasedBushingForce: `f_i = -curve_i(q_i) - c_i q_i'`.
    PerDof {
        /// One curve per DoF, in deflection order.
        curves: Box<[Curve; 6]>,
        /// Diagonal damping (Nm/(rad/s) for rx..rz, N/(m/s) for tx..tz).
        damping: [f64; 6],
    },
    /// Coupled linear stiffness: `f = -K q - C q'` with a 6x6 `K` (rows and
    /// columns in deflection order; Nm/rad, N/rad, Nm/m = N, N/m blocks).
    /// Written as an ExpressionBasedBushingForce with linear expressions.
    Coupled {
        /// The 6x6 stiffness `K`, deflection order.
        stiffness: Matrix6<f64>,
        /// Diagonal damping (Nm/(rad/s) for rx..rz, N/(m/s) for tx..tz).
        damping: [f64; 6],
    },
    /// OpenSim ExpressionBasedBushingForce: `f_i = -expr_i(q) - c_i q_i'`
    /// (`Mx, My, Mz, Fx, Fy, Fz` expressions of `theta_x .. delta_z`).
    Expression {
        /// `Mx, My, Mz, Fx, Fy, Fz` (N m, N) as expressions of the deflections.
        exprs: Box<[Expr; 6]>,
        /// Diagonal damping (Nm/(rad/s) for rx..rz, N/(m/s) for tx..tz).
        damping: [f64; 6],
    },
}

impl BushingModel {
    /// Number of stiffness parameters the law exposes for sensitivities.
    pub fn n_stiffness_params(&self) -> usize {
        self.stiffness_params().len()
    }
    /// Stiffness parameters: Linear: the diagonal `(rx, ry, rz, tx, ty, tz)`;
    /// PerDof: each curve's [`Curve::params`] in DoF order; Coupled: the 36
    /// entries of `K` row by row; Expression: none.
    pub fn stiffness_params(&self) -> Vec<f64> {
        match self {
            BushingModel::Linear {
                rot_stiffness: r,
                trans_stiffness: t,
                ..
            } => vec![r.x, r.y, r.z, t.x, t.y, t.z],
            BushingModel::PerDof { curves, .. } => curves.iter().flat_map(|c| c.params()).collect(),
            BushingModel::Coupled { stiffness, .. } => {
                let mut v = Vec::with_capacity(36);
                for i in 0..6 {
                    for j in 0..6 {
                        v.push(stiffness[(i, j)]);
                    }
                }
                v
            }
            BushingModel::Expression { .. } => vec![],
        }
    }
}

/// Axes in which a load vector is given.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LoadFrame {
    /// Fixed ground axes.
    Ground,
    /// The loaded body's axes (the load turns with the body).
    Body,
}

/// An external load. Bodies are named; [`crate::solver::System::prepare_loads`]
/// resolves them (unknown names are an error).
#[derive(Debug, Clone, PartialEq)]
pub enum Load {
    /// A pure moment (N m).
    Moment {
        /// Name of the loaded body.
        body: String,
        /// The moment (N m), in `frame`'s axes.
        vec: Vector3<f64>,
        /// Axes of `vec`.
        frame: LoadFrame,
    },
    /// A force (N) at a point fixed in the body (body frame, m).
    Force {
        /// Name of the loaded body.
        body: String,
        /// Point of application in the body frame (m).
        point_in_body: Vector3<f64>,
        /// The force (N), in `frame`'s axes.
        vec: Vector3<f64>,
        /// Axes of `vec`.
        frame: LoadFrame,
    },
    /// Compressive follower load (N) at every joint on the tree path between
    /// `from_body` (the fixed one) and `to_body` (the loaded one), as defined
    /// in `../shared/formats/experiment.md`: along the line between a guide
    /// point 10 mm cranial (joint frame +Y) of the joint centre fixed in the
    /// upper (child) body and one 10 mm caudal fixed in the lower (parent)
    /// body, both placed in the default pose.
    Follower {
        /// Name of the fixed end's body.
        from_body: String,
        /// Name of the loaded end's body.
        to_body: String,
        /// Compressive force at each joint (N).
        magnitude: f64,
    },
}
