//! A landmark file's content as read, before validation: the names as
//! spelled, the coordinates in the file's units and frame, where each came
//! from. Readers ([`super::io`]) produce it; detection ([`super::detect`])
//! and validation ([`super::validate`]) consume it.

use super::{Frame, LandmarkId, Units};
use std::path::PathBuf;

/// File formats.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum FileFormat {
    /// Comma-separated values.
    Csv,
    /// A TRC motion-capture file.
    Trc,
    /// JSON.
    Json,
}

/// One point as written in the file.
#[derive(Debug, Clone, PartialEq)]
pub struct RawPoint {
    /// Name as spelled in the file.
    pub name: String,
    /// Parsed id, `None` when the name is not `<LEVEL>_<CODE>`.
    pub id: Option<LandmarkId>,
    /// `true` when the name is spelled exactly as the format says.
    pub canonical: bool,
    /// Coordinates in file units and file frame.
    pub xyz: [f64; 3],
    /// 1-based line in the file, when known.
    pub line: Option<usize>,
    /// The body whose frame the coordinates are in (CSV `body` column:
    /// a modeller's palpation of a model, `base --palpation`); `None`:
    /// the file's frame.
    pub body: Option<String>,
}

/// A landmark file's content before validation.
#[derive(Debug, Clone, PartialEq)]
pub struct RawLandmarks {
    /// The file read.
    pub path: PathBuf,
    /// Its format.
    pub format: FileFormat,
    /// Units the file declares, if any.
    pub declared_units: Option<Units>,
    /// Frame the file declares, if any.
    pub declared_frame: Option<Frame>,
    /// The points in file order.
    pub points: Vec<RawPoint>,
    /// Reader remarks (e.g. "TRC: mean of 3 frames").
    pub notes: Vec<String>,
}

/// One palpation of a repeated-palpation study.
#[derive(Debug, Clone, PartialEq)]
pub struct Palpation {
    /// Operator identifier.
    pub operator: String,
    /// Repetition number of that operator.
    pub repetition: u32,
    /// The landmark file read.
    pub raw: RawLandmarks,
}
