//! The library's error type. Every error that comes from user input names the
//! file and, where known, the element, line or row, and says what was expected.

use std::path::PathBuf;

/// Result alias used across the library.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Errors raised by the library. Messages are written for the modeller who
/// has to fix the input: where (file, element/line) and what was expected.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// Reading or writing a file failed at the OS level. The OS error is
    /// part of the message (not a separate source, which a console
    /// printing the whole chain would repeat).
    #[error("{path}: {cause}")]
    Io {
        /// The file read or written.
        path: PathBuf,
        /// The OS error.
        cause: std::io::Error,
    },
    /// The content of a file is malformed or not what was expected.
    /// `location` is an element path, a line number or a row, as fits the format.
    #[error("{path}: {location}: {message}")]
    Parse {
        /// The malformed file.
        path: PathBuf,
        /// Where in the file (element path, `line N`, `row N`).
        location: String,
        /// What is wrong and what was expected.
        message: String,
    },
    /// The input is well-formed but not valid for the operation (bad values,
    /// inconsistent units, unknown names, ...).
    #[error("{context}: {message}")]
    Invalid {
        /// The input at fault (a file, a component, a table row).
        context: String,
        /// What is wrong and what was expected.
        message: String,
    },
    /// A numerical procedure failed (a fit that did not converge, a
    /// degenerate geometry, ...).
    #[error("{context}: {message}")]
    Numerical {
        /// The procedure that failed.
        context: String,
        /// How it failed.
        message: String,
    },
    /// The rigid-body solver failed in `context` (a case, a bushing, the
    /// static equilibrium, the integrator); `error` says how, typed.
    #[error("{context}: {error}")]
    Solver {
        /// Where the solver failed (a case, a bushing, the equilibrium, the integrator).
        context: String,
        /// How it failed.
        error: SolverError,
    },
}

/// How the rigid-body solver failed: callers match on the kind (a
/// calibration treats `GimbalLock` differently from `NoEquilibrium`), the
/// message says what to change.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SolverError {
    /// Newton's method used its iterations without reaching equilibrium.
    #[error(
        "no equilibrium found after {iterations} Newton iterations: the largest generalised force \
         residual is {residual:.3e} (coordinate '{coordinate}'); the loads may be too large for the \
         model to carry"
    )]
    NoEquilibrium {
        /// Newton iterations used.
        iterations: usize,
        /// Largest generalised force residual (N m or N, by coordinate).
        residual: f64,
        /// Name of the coordinate with that residual.
        coordinate: String,
    },
    /// The line search could not lower the residual.
    #[error(
        "no equilibrium found: the line search stalled at iteration {iteration} with largest \
         generalised force residual {residual:.3e} (the loads may be too large, or a bushing \
         approaches gimbal lock)"
    )]
    LineSearchStalled {
        /// Newton iteration at which the line search stalled.
        iteration: usize,
        /// Largest generalised force residual there (N m or N, by coordinate).
        residual: f64,
    },
    /// A continuation corrector converged too far from its prediction.
    #[error("the corrector moved {jump:.3} rad away from the predicted point")]
    CorrectorJump {
        /// Distance from the predicted point (rad).
        jump: f64,
    },
    /// Load continuation carried the loads up to the factor `reached` (of
    /// 1) and no further; `explanation` says why (limit point, last failure).
    #[error("{explanation}")]
    ContinuationStopped {
        /// Load factor reached, in [0, 1].
        reached: f64,
        /// Why continuation stopped there.
        explanation: String,
    },
    /// The tangent stiffness is singular (a free degree of freedom).
    #[error(
        "singular tangent stiffness at iteration {iteration}: a degree of freedom has no stiffness \
         (add a bushing, lock the coordinate or fix a body)"
    )]
    SingularTangent {
        /// Newton iteration at which the tangent was singular.
        iteration: usize,
    },
    /// The Newton step has a NaN or infinite entry.
    #[error("Newton step not finite at iteration {iteration}")]
    NonFiniteStep {
        /// Newton iteration that produced the step.
        iteration: usize,
    },
    /// A bushing's middle (Y) deflection angle reached the X-Y-Z singularity.
    #[error(
        "gimbal lock: the middle (Y) deflection angle is {angle_deg:.3} deg, at or beyond \
         +-{limit_deg:.0} deg where the X-Y-Z angles of OpenSim's BushingForce are singular"
    )]
    GimbalLock {
        /// The middle (Y) deflection angle (deg).
        angle_deg: f64,
        /// The largest accepted magnitude of that angle (deg).
        limit_deg: f64,
    },
    /// A joint's second rotation angle is at +-90 deg: the angular velocity
    /// does not determine the angle rates there.
    #[error(
        "joint '{joint}': its second rotation angle is {angle} rad (gimbal lock at +-90 degrees): \
         the angular velocity does not determine the angle rates there"
    )]
    JointGimbalLock {
        /// Name of the joint.
        joint: String,
        /// Its second rotation angle (rad).
        angle: f64,
    },
    /// The mass matrix could not be factored.
    #[error("mass matrix is not positive definite (a massless body on a free degree of freedom?)")]
    MassMatrixNotPositiveDefinite,
    /// The implicit integrator's stage coordinates diverged.
    #[error(
        "implicit step: the stage coordinates did not converge (angular velocity too large for the \
         time step): reduce the step size"
    )]
    StageNotConverged,
    /// The implicit integrator's Newton matrix is singular.
    #[error("singular Newton matrix in the implicit integrator")]
    SingularNewtonMatrix,
    /// The implicit step did not converge at step size `dt` (s).
    #[error("implicit step did not converge (dt = {dt} s): reduce the step size")]
    StepNotConverged {
        /// The step size tried (s).
        dt: f64,
    },
}

/// What is wrong with the numbers of a function, a stiffness curve or a
/// bushing law (their `validate`): callers match on the kind; the message
/// names the field.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DataError {
    /// A number of the named field is NaN or infinite.
    #[error("{0} not finite")]
    NotFinite(&'static str),
    /// The named arrays are empty or of different lengths (`n`: the
    /// abscissae's length).
    #[error("{what} needs equal non-empty arrays (x has {n})")]
    Lengths {
        /// Which function's arrays.
        what: &'static str,
        /// Number of abscissae.
        n: usize,
    },
    /// The named function's abscissae do not strictly increase.
    #[error("{0} abscissae must be strictly increasing")]
    NotIncreasing(&'static str),
    /// A function of an OpenSim class that is not evaluated (its class).
    #[error("function class {0} is not supported")]
    Unsupported(String),
    /// A sinh curve's scale `a` is zero.
    #[error("sinh curve needs a non-zero scale a")]
    ZeroSinhScale,
    /// The curve of one degree of freedom of a bushing law is invalid.
    #[error("curve {dof}: {error}")]
    Curve {
        /// The degree of freedom (`rx` .. `tz`).
        dof: &'static str,
        /// What is wrong with its curve.
        error: Box<DataError>,
    },
}

impl DataError {
    /// `Ok` when every number of `values` is finite, else `NotFinite(what)`.
    pub fn check_finite(what: &'static str, values: &[f64]) -> std::result::Result<(), DataError> {
        if values.iter().all(|x| x.is_finite()) {
            Ok(())
        } else {
            Err(DataError::NotFinite(what))
        }
    }
}

impl Error {
    /// I/O error on `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.into(),
            cause: source,
        }
    }
    /// Parse error in `path` at `location` (element path, `line N`, `row N`).
    pub fn parse(
        path: impl Into<PathBuf>,
        location: impl Into<String>,
        message: impl Into<String>,
    ) -> Self {
        Error::Parse {
            path: path.into(),
            location: location.into(),
            message: message.into(),
        }
    }
    /// Invalid input in `context` (a file, a component, a table row).
    pub fn invalid(context: impl Into<String>, message: impl Into<String>) -> Self {
        Error::Invalid {
            context: context.into(),
            message: message.into(),
        }
    }
    /// Solver failure `error` in `context`.
    pub fn solver(context: impl Into<String>, error: SolverError) -> Self {
        Error::Solver {
            context: context.into(),
            error,
        }
    }
    /// The solver failure this error carries, if it is one.
    pub fn solver_error(&self) -> Option<&SolverError> {
        match self {
            Error::Solver { error, .. } => Some(error),
            _ => None,
        }
    }
    /// Numerical failure in `context`.
    pub fn numerical(context: impl Into<String>, message: impl Into<String>) -> Self {
        Error::Numerical {
            context: context.into(),
            message: message.into(),
        }
    }
}
