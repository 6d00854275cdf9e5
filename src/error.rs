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
        path: PathBuf,
        cause: std::io::Error,
    },
    /// The content of a file is malformed or not what was expected.
    /// `location` is an element path, a line number or a row, as fits the format.
    #[error("{path}: {location}: {message}")]
    Parse {
        path: PathBuf,
        location: String,
        message: String,
    },
    /// The input is well-formed but not valid for the operation (bad values,
    /// inconsistent units, unknown names, ...).
    #[error("{context}: {message}")]
    Invalid { context: String, message: String },
    /// A numerical procedure failed (no equilibrium, singular system, ...).
    #[error("{context}: {message}")]
    Numerical { context: String, message: String },
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
    /// Numerical failure in `context`.
    pub fn numerical(context: impl Into<String>, message: impl Into<String>) -> Self {
        Error::Numerical {
            context: context.into(),
            message: message.into(),
        }
    }
}
