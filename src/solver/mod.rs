//! Rigid-body solver: an immutable system description built from a model and
//! a reusable workspace; statics (Newton) and forward dynamics. As in
//! Pinocchio, the model (`system`) and the data (`workspace`) are two files
//! that depend on no algorithm; the algorithms take both.
//!
//! | file | what lives there |
//! |---|---|
//! | `spec` | [`SystemSpec`] (bodies, joints, coordinates, bushings, gravity) and [`Load`] |
//! | `system` | the model: [`System`] (validated, parent-before-child) and its construction and parameter variants, the two index spaces: [`BodyIndex`] (system order; spec bodies are plain `usize` in spec order) and [`DofIndex`] (free dofs; spec coordinates are plain `usize`) |
//! | `workspace` | the data: [`Workspace`], every scratch buffer of the algorithms below (kinematic buffers, tangents and their factors, dynamics buffers) |
//! | `linalg` | small dense factorisations (LU with partial pivoting, Cholesky) |
//! | `scalar` | scalar types (f64, dual numbers; the trait in `util::scalar`) and the kinematics' small generic helpers; transform-axis functions are `osim::function`'s |
//! | `kinematics` | body poses and motion subspaces, generic over the scalar |
//! | `law`, `expr` | bushing force laws (the data, [`Curve`] and [`BushingModel`], in `spec`) (linear, per-DoF curves, coupled 6x6, Lepton expressions) |
//! | `forces` | gravity, bushings (OpenSim 4.6 bushing classes), loads, projection |
//! | `statics` | Newton equilibrium with exact tangent, sensitivities |
//! | `tree` | structured O(n) statics tangent: assembly and block elimination on the body tree |
//! | `dynamics` | mass matrix, generalised accelerations, implicit integrator, energy |
//! | `from_model` | adapter from an OpenSim model document |
//! | `output` | body poses, bushing records, .sto and JSON writers |

pub mod dynamics;
pub mod examples;
pub mod expr;
pub mod forces;
pub mod from_model;
pub mod kinematics;
pub mod law;
pub(crate) mod linalg;
pub mod output;
pub mod scalar;
pub mod spec;
pub mod statics;
pub mod system;
pub mod tree;
pub mod workspace;

pub use crate::error::SolverError;
pub use forces::{LoadSet, GIMBAL_LIMIT};
pub use spec::{
    BodySpec, BushingModel, BushingSpec, CoordinateSpec, Curve, Expr, FrameSpec, Function,
    JointKind, JointSpec, Load, LoadFrame, SystemSpec, TransformAxis,
};
pub use statics::{StaticOptions, StaticSolution};
pub use system::{BodyIndex, BushingIndex, DofIndex, Pose, System, SystemId};
pub use tree::TangentMethod;
pub use workspace::Workspace;

#[cfg(test)]
mod tests;
