//! Palpated landmark sets (`../shared/formats/landmarks.md`): reading CSV, TRC
//! and JSON, units and frame handling, checks and the statistics of repeated
//! palpations ([`stats`]; the `variability` study itself is
//! [`crate::evaluate::variability`]).
//!
//! | submodule | what lives there |
//! |---|---|
//! | (this file) | `Code` (and the landmark codes of each [`Level`], defined in [`crate::anatomy`]), `LandmarkId`, `Units`, `Frame`, `LandmarkSet` |
//! | [`io`] | readers (CSV, TRC, JSON) into `RawLandmarks`, the CSV writer |
//! | [`detect`] | units and frame detection from the anatomy (`Detection`) |
//! | [`frames`] | per-vertebra ISB-style local frames and dimensions |
//! | [`synth`] | synthetic landmark sets along a parametric spine curve |
//! | [`check`] | `osim-spine check`: findings with stable `LM0xx` codes |
//! | [`stats`] | ICC(2,1), Shapiro-Wilk, Friedman / Skillings-Mack, Nemenyi |
//! | [`metrics`] | spine shape from a set: Cobb angle, lordosis, kyphosis, apex, curve fits |
//! | [`radiograph`] | frontal radiograph landmarks (2-D endplate points, sacrum, femoral heads): reader and writer |
//!
//! Internally a set is in metres in the OpenSim frame (x anterior, y
//! superior, z right); the source's declared and detected units/frame are
//! kept in its [`detect::Detection`].

pub mod check;
pub mod detect;
pub mod frames;
pub mod io;
pub mod metrics;
pub mod radiograph;
pub mod raw;
pub mod stats;
pub mod synth;
pub mod validate;

use nalgebra::{Matrix3, Point3, Vector3};
use std::collections::BTreeMap;
use std::fmt;
use std::str::FromStr;

pub use crate::anatomy::Level;
pub use detect::Detection;
pub use io::{read_palpations, read_path, Palpation, RawLandmarks, RawPoint};

/// The protocol's landmark codes per level (see [`Code`]).
impl Level {
    /// Landmark codes the protocol requires at this level.
    pub fn required_codes(self) -> &'static [Code] {
        if self.is_sacrum() {
            &Code::SACRUM_REQUIRED
        } else {
            &Code::ALL
        }
    }

    /// Landmark codes allowed at this level (required + optional).
    pub fn allowed(self, code: Code) -> bool {
        if self.is_sacrum() {
            Code::SACRUM_REQUIRED.contains(&code) || matches!(code, Code::PTR | Code::PTL)
        } else {
            true
        }
    }
}

/// A landmark code within a vertebra (see the format document).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[allow(clippy::upper_case_acronyms)]
pub enum Code {
    /// Centre of the superior endplate.
    SEC,
    /// Centre of the inferior endplate.
    IEC,
    /// Top of the right pedicle arch.
    PTR,
    /// Top of the left pedicle arch.
    PTL,
    /// Base of the right pedicle arch.
    PBR,
    /// Base of the left pedicle arch.
    PBL,
    /// Most anterior point of the superior endplate.
    SA,
    /// Most posterior point of the superior endplate.
    SP,
    /// Most right point of the superior endplate.
    SR,
    /// Most left point of the superior endplate.
    SL,
    /// Most anterior point of the inferior endplate.
    IA,
    /// Most posterior point of the inferior endplate.
    IP,
    /// Most right point of the inferior endplate.
    IR,
    /// Most left point of the inferior endplate.
    IL,
}

impl Code {
    /// All 14 codes of a vertebra: 6 joint markers then 8 scaling markers.
    #[rustfmt::skip]
    pub const ALL: [Code; 14] = [
        Code::SEC, Code::IEC, Code::PTR, Code::PTL, Code::PBR, Code::PBL,
        Code::SA, Code::SP, Code::SR, Code::SL, Code::IA, Code::IP, Code::IR, Code::IL,
    ];
    /// Required on the sacrum (superior endplate of S1).
    pub const SACRUM_REQUIRED: [Code; 5] = [Code::SEC, Code::SA, Code::SP, Code::SR, Code::SL];

    /// The code's text as in landmark names.
    pub fn as_str(self) -> &'static str {
        match self {
            Code::SEC => "SEC",
            Code::IEC => "IEC",
            Code::PTR => "PTR",
            Code::PTL => "PTL",
            Code::PBR => "PBR",
            Code::PBL => "PBL",
            Code::SA => "SA",
            Code::SP => "SP",
            Code::SR => "SR",
            Code::SL => "SL",
            Code::IA => "IA",
            Code::IP => "IP",
            Code::IR => "IR",
            Code::IL => "IL",
        }
    }

    /// Joint markers (define joint poses) vs scaling markers.
    pub fn is_joint_marker(self) -> bool {
        matches!(
            self,
            Code::SEC | Code::IEC | Code::PTR | Code::PTL | Code::PBR | Code::PBL
        )
    }

    /// The left/right mirror code (`PTR` <-> `PTL`, ...), if any.
    pub fn mirror(self) -> Option<Code> {
        Some(match self {
            Code::PTR => Code::PTL,
            Code::PTL => Code::PTR,
            Code::PBR => Code::PBL,
            Code::PBL => Code::PBR,
            Code::SR => Code::SL,
            Code::SL => Code::SR,
            Code::IR => Code::IL,
            Code::IL => Code::IR,
            _ => return None,
        })
    }
}

impl fmt::Display for Code {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for Code {
    type Err = ();
    /// Case-insensitive.
    fn from_str(s: &str) -> Result<Self, ()> {
        let up = s.trim().to_ascii_uppercase();
        Code::ALL.into_iter().find(|c| c.as_str() == up).ok_or(())
    }
}

/// A landmark's identity: level + code, ordered cranial to caudal then by code.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct LandmarkId {
    /// The vertebral level.
    pub level: Level,
    /// The landmark code on that level.
    pub code: Code,
}

impl LandmarkId {
    /// The id of `code` on `level`.
    pub fn new(level: Level, code: Code) -> Self {
        LandmarkId { level, code }
    }
    /// Parse `<LEVEL>_<CODE>`. Returns the id and whether the spelling was
    /// canonical (exact upper case, no surrounding spaces).
    pub fn parse_name(name: &str) -> Option<(LandmarkId, bool)> {
        let t = name.trim();
        let (l, c) = t.split_once('_')?;
        let level: Level = l.parse().ok()?;
        let code: Code = c.parse().ok()?;
        let id = LandmarkId { level, code };
        let canonical = id.to_string() == name;
        Some((id, canonical))
    }
}

impl fmt::Display for LandmarkId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}_{}", self.level, self.code)
    }
}

/// Length units of a landmark file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum Units {
    /// Millimetres.
    #[serde(rename = "mm")]
    Millimetre,
    /// Metres.
    #[serde(rename = "m")]
    Metre,
}

impl Units {
    /// Metres per file unit.
    pub fn to_metres(self) -> f64 {
        match self {
            Units::Millimetre => 1e-3,
            Units::Metre => 1.0,
        }
    }
    /// Parse a units label (`mm`, `m`, also `millimeters`, `meters`).
    pub fn parse_label(s: &str) -> Option<Units> {
        match s.trim().to_ascii_lowercase().as_str() {
            "mm" | "millimeter" | "millimeters" | "millimetre" | "millimetres" => {
                Some(Units::Millimetre)
            }
            "m" | "meter" | "meters" | "metre" | "metres" => Some(Units::Metre),
            _ => None,
        }
    }
}

impl fmt::Display for Units {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Units::Millimetre => "mm",
            Units::Metre => "m",
        })
    }
}

/// Coordinate frame of a landmark file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum Frame {
    /// DICOM patient axes: x to the patient's left, y posterior, z superior.
    #[serde(rename = "LPS")]
    Lps,
    /// x right, y anterior, z superior.
    #[serde(rename = "RAS")]
    Ras,
    /// OpenSim: x anterior, y superior, z right.
    #[serde(rename = "opensim")]
    OpenSim,
}

impl Frame {
    /// Every frame a landmark file can be in.
    pub const ALL: [Frame; 3] = [Frame::Lps, Frame::Ras, Frame::OpenSim];

    /// Rotation taking file coordinates to OpenSim coordinates.
    pub fn to_opensim(self) -> Matrix3<f64> {
        match self {
            // os.x = -lps.y, os.y = lps.z, os.z = -lps.x
            Frame::Lps => Matrix3::new(0.0, -1.0, 0.0, 0.0, 0.0, 1.0, -1.0, 0.0, 0.0),
            // os.x = ras.y, os.y = ras.z, os.z = ras.x
            Frame::Ras => Matrix3::new(0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0),
            Frame::OpenSim => Matrix3::identity(),
        }
    }

    /// Parse a frame label (`LPS`, `RAS`, `opensim`; case-insensitive).
    pub fn parse_label(s: &str) -> Option<Frame> {
        match s.trim().to_ascii_lowercase().as_str() {
            "lps" => Some(Frame::Lps),
            "ras" => Some(Frame::Ras),
            "opensim" => Some(Frame::OpenSim),
            _ => None,
        }
    }
}

impl fmt::Display for Frame {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Frame::Lps => "LPS",
            Frame::Ras => "RAS",
            Frame::OpenSim => "opensim",
        })
    }
}

/// A validated landmark set: unique named points in metres, OpenSim frame.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct LandmarkSet {
    /// Points keyed by id (cranial to caudal, then code order).
    pub points: BTreeMap<LandmarkId, Point3<f64>>,
    /// What the source declared and what the anatomy says (None for sets
    /// built in memory).
    pub detection: Option<Detection>,
}

impl LandmarkSet {
    /// Empty set.
    pub fn new() -> Self {
        Self::default()
    }
    /// Insert or replace a point (metres, OpenSim frame).
    pub fn insert(&mut self, level: Level, code: Code, p: Point3<f64>) {
        self.points.insert(LandmarkId::new(level, code), p);
    }
    /// A point, if present.
    pub fn get(&self, level: Level, code: Code) -> Option<Point3<f64>> {
        self.points.get(&LandmarkId::new(level, code)).copied()
    }
    /// Levels present, cranial to caudal.
    pub fn levels(&self) -> Vec<Level> {
        let mut v: Vec<Level> = self.points.keys().map(|k| k.level).collect();
        v.dedup();
        v
    }
    /// Number of points.
    pub fn len(&self) -> usize {
        self.points.len()
    }
    /// `true` when empty.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }
    /// The same set moved by a rigid transform `p -> r p + t`.
    pub fn transformed(&self, r: &Matrix3<f64>, t: &Vector3<f64>) -> LandmarkSet {
        LandmarkSet {
            points: self
                .points
                .iter()
                .map(|(k, p)| (*k, Point3::from(r * p.coords + t)))
                .collect(),
            detection: self.detection.clone(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn level_names_round_trip_and_order() {
        for l in Level::ALL {
            assert_eq!(l.to_string().parse::<Level>(), Ok(l));
            assert_eq!(Level::from_body_name(&l.body_name()), Some(l));
        }
        assert!(Level::T12 < Level::L1 && Level::L5 < Level::S1);
        assert_eq!(Level::T12.caudal(), Some(Level::L1));
        assert_eq!(Level::T1.cranial(), None);
        assert_eq!(Level::L1.body_name(), "lumbar1");
        assert_eq!(Level::S1.body_name(), "sacrum");
    }

    #[test]
    fn landmark_names_parse() {
        let (id, canon) = LandmarkId::parse_name("L3_SEC").unwrap();
        assert_eq!(id, LandmarkId::new(Level::L3, Code::SEC));
        assert!(canon);
        let (_, canon) = LandmarkId::parse_name("l3_sec").unwrap();
        assert!(!canon);
        assert!(LandmarkId::parse_name("L6_SEC").is_none());
        assert!(LandmarkId::parse_name("L3SEC").is_none());
    }

    #[test]
    fn frames_are_proper_rotations_and_agree_on_anatomy() {
        // A point to the patient's right, anterior and superior of the origin
        // in each frame must map to (+, +, +) in OpenSim.
        let lps = Vector3::new(-1.0, -2.0, 3.0); // right=-x, anterior=-y, superior=+z
        let ras = Vector3::new(1.0, 2.0, 3.0);
        let os = Vector3::new(2.0, 3.0, 1.0);
        assert_eq!(Frame::Lps.to_opensim() * lps, os);
        assert_eq!(Frame::Ras.to_opensim() * ras, os);
        for f in Frame::ALL {
            assert!((f.to_opensim().determinant() - 1.0).abs() < 1e-12);
        }
    }
}

macro_rules! serialize_as_display {
    ($($t:ty),*) => {$(
        impl serde::Serialize for $t {
            fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
                s.collect_str(self)
            }
        }
    )*};
}
serialize_as_display!(Code, LandmarkId);
