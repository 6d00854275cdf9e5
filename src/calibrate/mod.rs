//! Experiments (`../shared/formats/experiment.md`) and stiffness calibration.
//!
//! | file | what lives there |
//! |---|---|
//! | `experiment` | load cases, [`experiment::Experiment::read`] (SI at the edge, validation) |
//! | `measure` | the measured increments (rotation vector, translation) of a vertebra pair |
//! | `family` | [`family::ModelFamily`] (parameter vector -> system) and the stiffness parameterisations (`--params`: uniform, ratio, per-level, nonlinear:sinh/cubic, coupled) |
//! | `forms` | the non-linear (stiffening) and coupled (correlation) laws, shared with `diagnose` |
//! | `problem` | weighted residuals and their exact Jacobian (implicit differentiation) |

pub mod experiment;
pub mod family;
pub mod fit;
pub mod forms;
pub mod lhs;
pub mod measure;
pub mod problem;
pub mod report;
pub mod sensitivity;
pub mod setup;
pub mod validate;
