//! Units and frame detection from the anatomy.
//!
//! - **Units**: vertebral dimensions measured from the landmarks (endplate
//!   widths SR-SL / IR-IL, depths SA-SP / IA-IP, body heights SEC-IEC) are
//!   divided by the published means of their level
//!   ([`crate::anatomy`]); the median ratio is ~1 for metres and
//!   ~1000 for millimetres. A median ratio in [0.4, 2.5] says metres, in
//!   [400, 2500] millimetres; anything else (centimetres, inches, a corrupt
//!   file) is undetermined and refused.
//! - **Frame**: three anatomical directions are averaged over the spine (sum
//!   of unit vectors, so one bad vertebra does not flip the answer):
//!   superior (IEC->SEC, caudal->cranial level centres), anterior (pedicle
//!   mid-points -> endplate centres, SP->SA, IP->IA) and right (L->R pairs).
//!   Each named frame (LPS, RAS, opensim) maps them to OpenSim axes; it
//!   matches when every available direction lies within 60 degrees of its
//!   OpenSim axis. A missing direction is completed by the cross product of
//!   the two others; fewer than two directions leave the frame undetermined.
//!
//! A declared header that contradicts the detection is reported (and is an
//! error for [`super::RawLandmarks::to_set`]).

use super::raw::RawLandmarks;
use super::{Code, Frame, LandmarkId, Level, Units};
use crate::anatomy::DimensionTable;
use nalgebra::Vector3;
use std::collections::BTreeMap;

/// What the source declared, what the anatomy says, and what is used.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Detection {
    /// Units the file declares, if any.
    pub declared_units: Option<Units>,
    /// Units the anatomy indicates, if it can tell.
    pub detected_units: Option<Units>,
    /// Median ratio measured/published dimension, in file units per metre.
    pub units_ratio: Option<f64>,
    /// Why the units were detected as they were, for a reader.
    pub units_evidence: String,
    /// Units used to read the file (detected when declared ones contradict
    /// the anatomy; `None` when neither is available).
    pub units: Option<Units>,
    /// Frame the file declares, if any.
    pub declared_frame: Option<Frame>,
    /// Frame the anatomy indicates, if it can tell.
    pub detected_frame: Option<Frame>,
    /// Why the frame was detected as it was, for a reader.
    pub frame_evidence: String,
    /// Frame used (same rule as `units`).
    pub frame: Option<Frame>,
    /// The declared units do not fit the measured dimensions.
    pub units_contradicted: bool,
    /// The declared frame does not fit the anatomical directions.
    pub frame_contradicted: bool,
}

impl Detection {
    /// `true` when the declared units contradict the anatomy.
    pub fn units_conflict(&self) -> bool {
        self.units_contradicted
    }
    /// `true` when the declared frame contradicts the anatomy.
    pub fn frame_conflict(&self) -> bool {
        self.frame_contradicted
    }
    /// Messages for everything that makes the file ambiguous or
    /// contradictory (empty when the file is usable as it stands).
    pub fn problems(&self) -> Vec<String> {
        let mut v = Vec::new();
        if self.units_conflict() {
            v.push(format!(
                "declared units `{}` but {}",
                opt(self.declared_units),
                self.units_evidence
            ));
        } else if self.units.is_none() {
            v.push(format!(
                "units not declared and not detectable: {}",
                self.units_evidence
            ));
        }
        if self.frame_conflict() {
            v.push(format!(
                "declared frame `{}` but {}",
                opt(self.declared_frame),
                self.frame_evidence
            ));
        } else if self.frame.is_none() {
            v.push(format!(
                "frame not declared and not detectable: {}",
                self.frame_evidence
            ));
        }
        v
    }
    /// One-paragraph human summary (what was declared, detected, used).
    pub fn summary(&self) -> String {
        format!(
            "units: declared {}, detected {} ({}); frame: declared {}, detected {} ({})",
            opt(self.declared_units),
            opt(self.detected_units),
            self.units_evidence,
            opt(self.declared_frame),
            opt(self.detected_frame),
            self.frame_evidence
        )
    }
}

fn opt<T: std::fmt::Display>(x: Option<T>) -> String {
    x.map(|v| v.to_string()).unwrap_or_else(|| "none".into())
}

/// First occurrence of each valid landmark, file coordinates.
fn first_points(raw: &RawLandmarks) -> BTreeMap<LandmarkId, Vector3<f64>> {
    let mut m = BTreeMap::new();
    for p in &raw.points {
        if let Some(id) = p.id {
            m.entry(id).or_insert_with(|| Vector3::from(p.xyz));
        }
    }
    m
}

/// Detect units and frame for a raw file.
pub fn detect(raw: &RawLandmarks) -> Detection {
    let pts = first_points(raw);
    // Units: measured vertebral dimensions over their published means.
    let ratios = dimension_ratios(&pts);
    let ratio = crate::util::median(&ratios);
    let (detected_units, units_evidence) = units_of_ratio(ratio, ratios.len());
    // Declared units that the ratio contradicts give way to the detected ones.
    let units_contradicted = match (raw.declared_units, ratio) {
        (Some(Units::Metre), Some(r)) => !(0.4..=2.5).contains(&r),
        (Some(Units::Millimetre), Some(r)) => !(400.0..=2500.0).contains(&r),
        _ => false,
    };
    let units = if units_contradicted {
        detected_units
    } else {
        raw.declared_units.or(detected_units)
    };
    // Frame: the anatomical directions averaged over the spine, matched
    // against each named frame.
    let dirs = anatomical_directions(&pts);
    let (detected_frame, frame_evidence, frame_contradicted) =
        frame_of_directions(dirs, raw.declared_frame);
    // A contradicted declared frame gives way to the detected one.
    let frame = if frame_contradicted {
        detected_frame
    } else {
        raw.declared_frame.or(detected_frame)
    };
    Detection {
        declared_units: raw.declared_units,
        detected_units,
        units_ratio: ratio,
        units_evidence,
        units,
        declared_frame: raw.declared_frame,
        detected_frame,
        frame_evidence,
        frame,
        units_contradicted,
        frame_contradicted,
    }
}

/// Ratios measured / published mean of the endplate widths and depths and
/// the body heights (file units per metre).
fn dimension_ratios(pts: &BTreeMap<LandmarkId, Vector3<f64>>) -> Vec<f64> {
    let g = |l: Level, c: Code| pts.get(&LandmarkId::new(l, c)).copied();
    let mut ratios = Vec::new();
    let Ok(t) = DimensionTable::embedded() else {
        return ratios;
    };
    for l in Level::ALL {
        let d = t.level(l);
        let pairs = [
            (Code::SR, Code::SL, d.sup_ep_width.mean),
            (Code::IR, Code::IL, d.inf_ep_width.mean),
            (Code::SA, Code::SP, d.sup_ep_depth.mean),
            (Code::IA, Code::IP, d.inf_ep_depth.mean),
            (Code::SEC, Code::IEC, d.body_height().mean),
        ];
        for (a, b, expect) in pairs {
            if let (Some(pa), Some(pb)) = (g(l, a), g(l, b)) {
                if expect > 0.0 {
                    ratios.push((pa - pb).norm() / expect);
                }
            }
        }
    }
    ratios
}

/// Units detected from the median dimension ratio (of `n` measures), with
/// the evidence.
fn units_of_ratio(ratio: Option<f64>, n: usize) -> (Option<Units>, String) {
    match ratio {
        None => (
            None,
            "no endplate widths/depths or body heights to measure".to_string(),
        ),
        Some(r) if (0.4..=2.5).contains(&r) => (
            Some(Units::Metre),
            format!(
                "vertebral dimensions are {r:.2} x the published means if read as metres (median of {n} measures): metres"
            ),
        ),
        Some(r) if (400.0..=2500.0).contains(&r) => (
            Some(Units::Millimetre),
            format!(
                "vertebral dimensions are {:.2} x the published means if read as millimetres (median of {n} measures): millimetres",
                r / 1000.0
            ),
        ),
        Some(r) => (
            None,
            format!(
                "vertebral dimensions are {r:.3e} x the published means if read as metres, which fits neither m (~1) nor mm (~1000)"
            ),
        ),
    }
}

/// `v` normalised, `None` when zero or not finite.
fn unit(v: Vector3<f64>) -> Option<Vector3<f64>> {
    let n = v.norm();
    if n > 0.0 && n.is_finite() {
        Some(v / n)
    } else {
        None
    }
}

/// Anterior, superior and right in file axes (OpenSim x, y, z order): sums
/// of the unit vectors each vertebra gives, normalised (`None` when no
/// vertebra gives one).
fn anatomical_directions(pts: &BTreeMap<LandmarkId, Vector3<f64>>) -> [Option<Vector3<f64>>; 3] {
    let g = |l: Level, c: Code| pts.get(&LandmarkId::new(l, c)).copied();
    let mut sup = Vector3::zeros();
    let mut ant = Vector3::zeros();
    let mut right = Vector3::zeros();
    let levels: Vec<Level> = {
        let mut v: Vec<Level> = pts.keys().map(|k| k.level).collect();
        v.dedup();
        v
    };
    let centre = |l: Level| -> Option<Vector3<f64>> {
        match (g(l, Code::SEC), g(l, Code::IEC)) {
            (Some(a), Some(b)) => Some(0.5 * (a + b)),
            (Some(a), None) => Some(a),
            (None, Some(b)) => Some(b),
            _ => None,
        }
    };
    let mid = |a: Code, b: Code, l: Level| match (g(l, a), g(l, b)) {
        (Some(a), Some(b)) => Some(0.5 * (a + b)),
        _ => None,
    };
    let add = |acc: &mut Vector3<f64>, a: Option<Vector3<f64>>, b: Option<Vector3<f64>>| {
        if let (Some(a), Some(b)) = (a, b) {
            if let Some(u) = unit(a - b) {
                *acc += u;
            }
        }
    };
    for &l in &levels {
        // Superior: IEC -> SEC, pedicle bases -> tops.
        add(&mut sup, g(l, Code::SEC), g(l, Code::IEC));
        add(&mut sup, g(l, Code::PTR), g(l, Code::PBR));
        add(&mut sup, g(l, Code::PTL), g(l, Code::PBL));
        // Anterior: posterior -> anterior endplate points, pedicle mid-points
        // -> endplate centres.
        add(&mut ant, g(l, Code::SA), g(l, Code::SP));
        add(&mut ant, g(l, Code::IA), g(l, Code::IP));
        add(&mut ant, g(l, Code::SEC), mid(Code::PTR, Code::PTL, l));
        add(&mut ant, g(l, Code::IEC), mid(Code::PBR, Code::PBL, l));
        // Right: left -> right pairs.
        add(&mut right, g(l, Code::PTR), g(l, Code::PTL));
        add(&mut right, g(l, Code::PBR), g(l, Code::PBL));
        add(&mut right, g(l, Code::SR), g(l, Code::SL));
        add(&mut right, g(l, Code::IR), g(l, Code::IL));
        // Superior: caudal -> cranial level centres.
        if let Some(c) = l.caudal() {
            if levels.contains(&c) {
                add(&mut sup, centre(l), centre(c));
            }
        }
    }
    [unit(ant), unit(sup), unit(right)]
}

/// The named frame the directions fit best (each available direction within
/// 60 degrees of its OpenSim axis), the evidence, and whether `declared`
/// is contradicted.
fn frame_of_directions(
    mut dirs: [Option<Vector3<f64>>; 3],
    declared: Option<Frame>,
) -> (Option<Frame>, String, bool) {
    let available = dirs.iter().filter(|d| d.is_some()).count();
    if available < 2 {
        return (
            None,
            "fewer than two anatomical directions available (need endplate centres, pedicles or R/L pairs)".to_string(),
            false,
        );
    }
    // Complete a missing direction (right-handed: x = y cross z, ...).
    if dirs[0].is_none() {
        dirs[0] = dirs[1].zip(dirs[2]).and_then(|(y, z)| unit(y.cross(&z)));
    } else if dirs[1].is_none() {
        dirs[1] = dirs[2].zip(dirs[0]).and_then(|(z, x)| unit(z.cross(&x)));
    } else if dirs[2].is_none() {
        dirs[2] = dirs[0].zip(dirs[1]).and_then(|(x, y)| unit(x.cross(&y)));
    }
    let axes = [Vector3::x(), Vector3::y(), Vector3::z()];
    let mut best: Option<(Frame, f64)> = None;
    let mut declared_min = None;
    for f in Frame::ALL {
        let r = f.to_opensim();
        let cosines: Vec<f64> = dirs
            .iter()
            .zip(axes.iter())
            .filter_map(|(d, a)| d.map(|d| (r * d).dot(a)))
            .collect();
        let min = cosines.iter().copied().fold(f64::INFINITY, f64::min);
        if Some(f) == declared {
            declared_min = Some(min);
        }
        if min > 0.5 && best.is_none_or(|(_, m)| min > m) {
            best = Some((f, min));
        }
    }
    let describe = |d: Option<Vector3<f64>>| {
        d.map(|d| format!("({:.2}, {:.2}, {:.2})", d.x, d.y, d.z))
            .unwrap_or_else(|| "?".into())
    };
    let ev = format!(
        "anatomy in file axes: anterior {}, superior {}, right {}",
        describe(dirs[0]),
        describe(dirs[1]),
        describe(dirs[2])
    );
    let contradicted = declared_min.is_some_and(|m| m <= 0.5);
    match best {
        Some((f, m)) => (
            Some(f),
            format!(
                "{ev}: {f} (worst axis within {:.0} deg)",
                m.clamp(-1.0, 1.0).acos().to_degrees()
            ),
            contradicted,
        ),
        None => (
            None,
            format!("{ev}: matches none of LPS, RAS, opensim"),
            contradicted,
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn units_follow_the_dimension_ratio() {
        assert_eq!(units_of_ratio(Some(1.1), 30).0, Some(Units::Metre));
        assert_eq!(units_of_ratio(Some(950.0), 30).0, Some(Units::Millimetre));
        // centimetres fit neither
        let (u, why) = units_of_ratio(Some(95.0), 30);
        assert_eq!(u, None);
        assert!(why.contains("neither"), "{why}");
        assert_eq!(units_of_ratio(None, 0).0, None);
    }

    #[test]
    fn a_missing_direction_is_completed_and_the_frame_matched() {
        // OpenSim axes: anterior x, superior y; right z is completed.
        let dirs = [Some(Vector3::x()), Some(Vector3::y()), None];
        let (frame, why, contradicted) = frame_of_directions(dirs, Some(Frame::OpenSim));
        assert_eq!(frame, Some(Frame::OpenSim), "{why}");
        assert!(!contradicted);
        // the same anatomy declared as LPS is a contradiction
        let (_, _, contradicted) = frame_of_directions(dirs, Some(Frame::Lps));
        assert!(contradicted);
        // one direction is not enough
        let (frame, _, _) = frame_of_directions([Some(Vector3::x()), None, None], None);
        assert_eq!(frame, None);
    }
}
