//! The outputs of `palpate`: the landmark CSV (with `# units:`, `# frame:`
//! and a `# source:` comment), the JSON report (every landmark with its
//! confidence and distance to the surface, every finding) and the figure
//! of the palpated levels (frontal and sagittal views).

use super::{Finding, Kind, Palpated};
use crate::landmarks::io::csv_string;
use crate::landmarks::{Code, Level, Units};
use crate::util::svg::{Figure, Series, Silhouette};
use nalgebra::Point3;
use plotters::style::RGBColor;

/// The landmark CSV text.
pub fn csv_text(p: &Palpated) -> String {
    let table = p
        .label_table
        .as_ref()
        .map(|t| format!(", label table {t}"))
        .unwrap_or_default();
    format!(
        "# source: osim-spine palpate of {} ({}{table})\n{}",
        p.source,
        kind_name(p.kind),
        csv_string(&p.set, p.units, p.frame)
    )
}

fn kind_name(k: Kind) -> &'static str {
    match k {
        Kind::MeshFolder => "mesh folder",
        Kind::LabelMap => "NIfTI label map",
    }
}

/// One landmark in the report.
#[derive(Debug, serde::Serialize)]
pub struct LandmarkEntry {
    /// Landmark name (e.g. `T7_SP`).
    pub name: String,
    /// Position in the output units and frame.
    pub position: [f64; 3],
    /// The palpation engine's confidence, 0..1.
    pub confidence: f64,
    /// Position uncertainty (output units): the label map's resolution
    /// (half its largest voxel edge; none for a mesh folder) and the
    /// landmark's `region_spread`, added in quadrature.
    pub uncertainty: Option<f64>,
    /// How far the landmark moves when the endplate regions' 40 deg bound
    /// moves by 8 deg either way (output units): large where the landmark
    /// hangs on a face near the bound, as a vertebra scaled differently
    /// along its axes, or another operator, could place it elsewhere.
    pub region_spread: f64,
    /// Distance to the level's surface (output units).
    pub distance_to_surface: Option<f64>,
    /// True when the confidence is below 0.5.
    pub uncertain: bool,
    /// Why the confidence is reduced, if it is.
    pub note: Option<String>,
}

/// One level in the report.
#[derive(Debug, serde::Serialize)]
pub struct LevelEntry {
    /// The level.
    pub level: Level,
    /// File or label the surface came from.
    pub origin: String,
    /// Vertebral centre (output units and frame) and its sphere radius.
    pub centre: [f64; 3],
    /// Radius of the centre's sphere (output units).
    pub centre_radius: f64,
    /// The level's landmarks.
    pub landmarks: Vec<LandmarkEntry>,
}

/// The JSON report.
#[derive(Debug, serde::Serialize)]
pub struct Report {
    /// The segmentation's file or folder name.
    pub source: String,
    /// Mesh folder or label map.
    pub kind: Kind,
    /// Label table used (label maps).
    pub label_table: Option<String>,
    /// Units of the positions written.
    pub units: Units,
    /// Frame of the positions written.
    pub frame: crate::landmarks::Frame,
    /// Axes of the segmentation itself.
    pub segmentation_frame: crate::landmarks::Frame,
    /// The label map's voxel size (edges along i, j, k, mm).
    pub resolution: Option<super::labelmap::Resolution>,
    /// Levels palpated, cranial to caudal.
    pub levels_palpated: Vec<Level>,
    /// Where `SR`, `SL`, `IR`, `IL` were taken: `furthest` (the literal
    /// furthest points of the endplate regions) or `rim-middle`.
    pub lateral_landmarks: super::Laterals,
    /// Number of warning findings.
    pub warnings: usize,
    /// Every finding.
    pub findings: Vec<Finding>,
    /// Every palpated level.
    pub levels: Vec<LevelEntry>,
}

/// Round to 1e-4 of the output unit (0.1 um in mm).
fn r4(x: f64) -> f64 {
    (x * 1e4).round() / 1e4
}

/// The report of a palpation.
pub fn report(p: &Palpated) -> Report {
    let s = 1.0 / p.units.to_metres();
    let to_out = p.frame.to_opensim().transpose() * p.world.to_opensim();
    let out = |q: &Point3<f64>| {
        let v = to_out * q.coords * s;
        [r4(v.x), r4(v.y), r4(v.z)]
    };
    let levels = p
        .levels
        .iter()
        .map(|r| LevelEntry {
            level: r.level,
            origin: r.origin.clone(),
            centre: out(&r.palpation.centre),
            centre_radius: r4(r.palpation.centre_radius * s),
            landmarks: r
                .palpation
                .landmarks
                .iter()
                .map(|(code, lm)| LandmarkEntry {
                    name: format!("{}_{code}", r.level),
                    position: out(&lm.point),
                    confidence: r4(lm.confidence),
                    uncertainty: Some(r4(p
                        .resolution
                        .map_or(0.0, |v| v.uncertainty_mm() * 1e-3)
                        .hypot(lm.spread)
                        * s)),
                    region_spread: r4(lm.spread * s),
                    distance_to_surface: r.distance.get(code).map(|d| r4(d * s)),
                    uncertain: lm.confidence < super::assemble::UNCERTAIN,
                    note: lm.note.clone(),
                })
                .collect(),
        })
        .collect();
    Report {
        source: p.source.clone(),
        kind: p.kind,
        label_table: p.label_table.clone(),
        units: p.units,
        frame: p.frame,
        segmentation_frame: p.world,
        resolution: p.resolution,
        levels_palpated: p.levels.iter().map(|r| r.level).collect(),
        lateral_landmarks: p.laterals,
        warnings: p
            .findings
            .iter()
            .filter(|f| f.severity == super::Severity::Warning)
            .count(),
        findings: p.findings.clone(),
        levels,
    }
}

/// The JSON text of the report.
pub fn json_text(p: &Palpated) -> String {
    serde_json::to_string_pretty(&report(p)).unwrap_or_else(|e| format!("{{\"error\": \"{e}\"}}"))
}

/// The figure (frontal, sagittal): each level's surface, its endplate and
/// pedicle landmarks and the vertebral centres, in the OpenSim frame
/// (relative to the sacrum's superior endplate centre when there is one).
pub fn figure(p: &Palpated) -> Vec<(String, String)> {
    let r = p.world.to_opensim();
    let origin = p
        .set
        .get(Level::S1, Code::SEC)
        .map(|o| o.coords)
        .unwrap_or_default();
    let os = |q: &Point3<f64>| Point3::from(r * q.coords - origin);
    let mut fig = Figure::new(format!("palpated levels of {}", p.source));
    fig.silhouettes.push(Silhouette {
        label: "surfaces".into(),
        colour: RGBColor(200, 200, 200),
        triangles: p
            .levels
            .iter()
            .flat_map(|l| l.mesh.triangle_corners().map(|t| t.map(|c| os(&c))))
            .collect(),
    });
    let groups: [(&str, RGBColor, &[Code]); 3] = [
        (
            "endplate centres",
            RGBColor(200, 30, 30),
            &[Code::SEC, Code::IEC],
        ),
        (
            "endplate extremes",
            RGBColor(30, 90, 200),
            &[
                Code::SA,
                Code::SP,
                Code::SR,
                Code::SL,
                Code::IA,
                Code::IP,
                Code::IR,
                Code::IL,
            ],
        ),
        (
            "pedicles",
            RGBColor(20, 150, 60),
            &[Code::PTR, Code::PTL, Code::PBR, Code::PBL],
        ),
    ];
    for (label, colour, codes) in groups {
        let points = p
            .set
            .points
            .iter()
            .filter(|(id, _)| codes.contains(&id.code))
            .map(|(_, q)| Point3::from(q.coords - origin))
            .collect();
        fig.series.push(Series {
            label: label.into(),
            colour,
            points,
            radius: 2,
            line: false,
        });
    }
    fig.series.push(Series {
        label: "vertebral centres".into(),
        colour: RGBColor(0, 0, 0),
        points: p.levels.iter().map(|l| os(&l.palpation.centre)).collect(),
        radius: 3,
        line: true,
    });
    fig.draw_both()
}
