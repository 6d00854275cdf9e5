//! Model accuracy against a patient's truth (`osim-spine evaluate`), the
//! metrics of the source thesis (chapter 5, Tables 5.6-5.8, Figures
//! 5.6-5.7).
//!
//! **Vertebral centre** ([`CentreDef`], the same definition for model and
//! truth): by default the midpoint of the vertebra's `SEC` and `IEC`
//! markers at the model's default pose, the centre of the vertebral body on
//! its endplate axis (for truth meshes: the volume centroid of each
//! vertebral-body mesh). This is robust to the quality of the base model's
//! wrap-sphere fits (on coarse meshes some sphere centres sit outside the
//! vertebral body, which would turn small rotation errors into large
//! position errors). `--centre sphere` uses the thesis's definition
//! instead: the centre of the vertebral-body wrap sphere
//! (`<LEVEL>_body_sphere`), and for truth meshes a sphere fitted to the
//! anterior wall ([`crate::mesh::anterior_body_nodes`] +
//! [`crate::mesh::fit_sphere`]). The truth is either a centres CSV
//! (`level,x,y,z` with mandatory `# units:` and `# frame:` headers, like
//! landmark files) or a folder of vertebral-body meshes
//! (`<LEVEL>*.stl|obj|vtp|ply`, units and frame given on the command line).
//!
//! **Common frame**: the truth is brought into the model's ground with the
//! generator's sacral registration (read from `<model stem>_report.json`
//! beside the model); then, per [`Align`], optionally superimposed:
//! `rigid` (default: least-squares rigid fit of the truth centres onto the
//! model centres, so that the errors describe the shape and not the
//! placement of the whole spine on the sacrum, which three noisy sacral
//! landmarks determine only to a few degrees), `l5` (thesis: translation
//! making the L5 centres coincide) or `sacrum` (the registration alone).
//! The RMSE in the sacral frame is always reported too when the
//! registration is known.
//!
//! Metrics ([`metrics`]): 3-D RMSE of the centres, per-level signed and
//! absolute errors per axis (AP = X, IS = Y, RL = Z), curve RMSE and R2 in
//! the sagittal and frontal planes, Cobb angle, end vertebrae and apex of
//! the main curve, lumbar lordosis and sacral slope; for several models the
//! median and IQR of each (Table 5.6), per-level medians and IQRs of the
//! absolute errors (Table 5.7), and mean, SD, min and max of the Cobb angle
//! and lordosis (Table 5.8).

pub use crate::landmarks::metrics;
pub mod palpations;
pub mod plot;
pub mod propagation;
pub mod variability;

pub use crate::base::centres::{model_centres, model_landmarks, CentreDef};

use crate::base::kin::Kinematics;
use crate::error::{Error, Result};
use crate::generate::Registration;
use crate::landmarks::{Frame, LandmarkSet, Level, Units};
use crate::osim::Document;
use crate::util::table::{comment_value, CsvItem, CsvReader};
use nalgebra::{Isometry3, Point3};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// A model to evaluate, at its default pose.
#[derive(Debug, Clone)]
pub struct ModelShape {
    /// The model file's path, as displayed.
    pub name: String,
    /// Vertebral centre per level, in ground (m).
    pub centres: BTreeMap<Level, Point3<f64>>,
    /// The model's landmark markers, in ground (m).
    pub landmarks: LandmarkSet,
    /// The generator's sacral registration (from its report), when known.
    pub registration: Option<Registration>,
}

/// The report written by `generate` beside `model` (`<stem>_report.json`).
pub fn report_path(model: &Path) -> PathBuf {
    let stem = model
        .file_stem()
        .map(|s| s.to_string_lossy().to_string())
        .unwrap_or_default();
    model.with_file_name(format!("{stem}_report.json"))
}

impl ModelShape {
    /// Centres and markers of an in-memory model at its default pose.
    pub fn from_document(
        doc: &Document,
        registration: Option<Registration>,
        def: CentreDef,
    ) -> Result<ModelShape> {
        let model = doc.model()?;
        let kin = Kinematics::new(&model)?;
        let poses = kin.body_poses(&kin.default_values())?;
        let centres = model_centres(&model, &poses, def)?;
        let name = doc.path().display().to_string();
        if centres.is_empty() {
            return Err(Error::invalid(
                name,
                "no vertebra bodies (thoracic1..12, lumbar1..5) with a wrap sphere or SEC/IEC markers",
            ));
        }
        let landmarks = model_landmarks(&model, &poses)?;
        Ok(ModelShape {
            name,
            centres,
            landmarks,
            registration,
        })
    }
}

/// Load a model's centres and markers at its default pose, and the
/// registration from its generate report when present.
pub fn load_model(path: &Path, def: CentreDef) -> Result<ModelShape> {
    let doc = Document::read(path)?;
    let rp = report_path(path);
    let registration = if rp.exists() {
        let text = crate::util::read_text_capped(
            &rp,
            crate::util::input::MAX_TABLE_BYTES,
            "generate reports",
        )?;
        let v: serde_json::Value = serde_json::from_str(&text)
            .map_err(|e| Error::parse(&rp, "file", format!("not JSON: {e}")))?;
        match v.get("registration") {
            Some(r) => Some(serde_json::from_value(r.clone()).map_err(|e| {
                Error::parse(&rp, "registration", format!("unexpected content: {e}"))
            })?),
            None => None,
        }
    } else {
        None
    };
    ModelShape::from_document(&doc, registration, def)
}

/// Truth data in OpenSim axes and metres (the patient's frame; see
/// [`Align`] for how it meets the model).
#[derive(Debug, Clone, Default)]
pub struct Truth {
    /// Where the truth was read from, as displayed.
    pub source: String,
    /// Vertebral centre per level, in the truth's frame (m).
    pub centres: BTreeMap<Level, Point3<f64>>,
    /// Palpated/true landmarks for the truth's Cobb angle and lordosis.
    pub landmarks: Option<LandmarkSet>,
}

/// Read a centres CSV (`level,x,y,z`; `# units:` and `# frame:` required).
pub fn read_centres_csv(path: &Path) -> Result<BTreeMap<Level, Point3<f64>>> {
    let text =
        crate::util::read_text_capped(path, crate::util::input::MAX_TABLE_BYTES, "truth files")?;
    parse_centres_csv(&text, path)
}

/// Parse centres CSV text (see [`read_centres_csv`]).
pub fn parse_centres_csv(text: &str, path: &Path) -> Result<BTreeMap<Level, Point3<f64>>> {
    let mut units = None;
    let mut frame = None;
    let mut header = false;
    let mut out = BTreeMap::new();
    for item in CsvReader::new(text, path) {
        let rec = match item? {
            CsvItem::Comment(c) => {
                let ln = c.line;
                if let Some(v) = comment_value(&c.text, "units") {
                    units = Some(Units::parse_label(v).ok_or_else(|| {
                        Error::parse(
                            path,
                            format!("line {ln}"),
                            format!("unknown units `{v}` (mm or m)"),
                        )
                    })?)
                } else if let Some(v) = comment_value(&c.text, "frame") {
                    frame = Some(Frame::parse_label(v).ok_or_else(|| {
                        Error::parse(
                            path,
                            format!("line {ln}"),
                            format!("unknown frame `{v}` (LPS, RAS or opensim)"),
                        )
                    })?)
                }
                continue;
            }
            CsvItem::Record(rec) => rec,
        };
        let ln = rec.line();
        let f: Vec<&str> = rec.cells().collect();
        if !header {
            if f.len() != 4 || !f[0].eq_ignore_ascii_case("level") {
                return Err(rec.error(
                    path,
                    format!(
                        "expected the header `level,x,y,z`, found `{}`",
                        rec.source()
                    ),
                ));
            }
            header = true;
            continue;
        }
        if f.len() != 4 {
            return Err(rec.error(path, format!("expected 4 fields, found {}", f.len())));
        }
        let level: Level = f[0].parse().map_err(|_| {
            Error::parse(
                path,
                format!("line {ln}"),
                format!("`{}` is not a level (T1..T12, L1..L5)", f[0]),
            )
        })?;
        let mut v = [0.0; 3];
        for k in 0..3 {
            v[k] = f[k + 1]
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(|| {
                    Error::parse(
                        path,
                        format!("line {ln}"),
                        format!(
                            "column {}: expected a finite number, found `{}`",
                            k + 2,
                            f[k + 1]
                        ),
                    )
                })?;
        }
        if out.insert(level, v).is_some() {
            return Err(Error::parse(
                path,
                format!("line {ln}"),
                format!("duplicate level {level}"),
            ));
        }
    }
    let units = units.ok_or_else(|| {
        Error::parse(
            path,
            "header",
            "missing `# units: mm|m` (centre files must declare their units)",
        )
    })?;
    let frame = frame.ok_or_else(|| {
        Error::parse(
            path,
            "header",
            "missing `# frame: LPS|RAS|opensim` (centre files must declare their frame)",
        )
    })?;
    if out.is_empty() {
        return Err(Error::parse(path, "file", "no centres"));
    }
    let r = frame.to_opensim();
    Ok(out
        .into_iter()
        .map(|(l, v)| {
            (
                l,
                Point3::from(r * nalgebra::Vector3::from(v) * units.to_metres()),
            )
        })
        .collect())
}

/// Write centres as CSV in the given units and frame (fixtures, tests).
pub fn centres_csv(centres: &BTreeMap<Level, Point3<f64>>, units: Units, frame: Frame) -> String {
    let back = frame.to_opensim().transpose();
    let s = 1.0 / units.to_metres();
    let mut out = format!("# units: {units}\n# frame: {frame}\nlevel,x,y,z\n");
    for (l, p) in centres {
        let v = back * p.coords * s;
        out.push_str(&format!(
            "{l},{},{},{}\n",
            crate::util::fmt_f64(v.x),
            crate::util::fmt_f64(v.y),
            crate::util::fmt_f64(v.z)
        ));
    }
    out
}

/// Truth centres from vertebral-body meshes in `dir` (`<LEVEL>*.{stl,obj,
/// vtp,ply}`, one per level) in the given units and frame, by `def`
/// (volume centroids, or sphere fits to the anterior walls: the thesis's
/// CT rule).
pub fn centres_from_meshes(
    dir: &Path,
    units: Units,
    frame: Frame,
    def: CentreDef,
) -> Result<BTreeMap<Level, Point3<f64>>> {
    let rd = std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))?;
    let mut files: Vec<PathBuf> = rd.filter_map(|e| e.ok().map(|e| e.path())).collect();
    files.sort();
    let r = frame.to_opensim();
    let s = units.to_metres();
    let mut out = BTreeMap::new();
    for f in files {
        let ext = f
            .extension()
            .and_then(|e| e.to_str())
            .map(|e| e.to_ascii_lowercase());
        if !matches!(ext.as_deref(), Some("stl" | "obj" | "vtp" | "ply")) {
            continue;
        }
        let stem = f
            .file_stem()
            .and_then(|s| s.to_str())
            .unwrap_or("")
            .to_ascii_uppercase();
        let token: String = stem
            .chars()
            .take_while(|c| c.is_ascii_alphanumeric())
            .collect();
        let Ok(level) = token.parse::<Level>() else {
            continue;
        };
        if level.is_sacrum() {
            continue;
        }
        let mesh = crate::mesh::read(&f)?;
        let moved = crate::mesh::TriMesh {
            vertices: mesh
                .vertices
                .iter()
                .map(|p| Point3::from(r * p.coords * s))
                .collect(),
            triangles: mesh.triangles.clone(),
        };
        let ctx = f.display().to_string();
        let centre = match def {
            CentreDef::Endplates => moved.volume_centroid().ok_or_else(|| {
                Error::invalid(&ctx, "no volume centroid (open or degenerate mesh)")
            })?,
            CentreDef::Sphere => {
                let frame = crate::mesh::AnatomicalFrame::opensim_body();
                let idx = crate::mesh::anterior_body_nodes(&moved, &frame)
                    .map_err(|e| Error::invalid(&ctx, e.to_string()))?;
                let nodes: Vec<Point3<f64>> = idx
                    .iter()
                    .filter_map(|i| moved.vertices.get(*i).copied())
                    .collect();
                crate::mesh::fit_sphere(&nodes)
                    .map_err(|e| Error::invalid(&ctx, format!("sphere fit: {e}")))?
                    .centre
            }
        };
        if out.insert(level, centre).is_some() {
            return Err(Error::invalid(&ctx, format!("a second mesh for {level}")));
        }
    }
    if out.is_empty() {
        return Err(Error::invalid(
            dir.display().to_string(),
            "no vertebral-body meshes named <LEVEL>*.stl|obj|vtp|ply",
        ));
    }
    Ok(out)
}

/// Load the truth of `evaluate`/`variability --truth`: a centres CSV, or a
/// folder of vertebral-body meshes (which need `units` and `frame`), plus
/// an optional truth landmark set (for the truth's Cobb angle, apex and
/// lordosis).
pub fn load_truth(
    path: &Path,
    units: Option<&str>,
    frame: Option<&str>,
    landmarks: Option<&Path>,
    def: CentreDef,
) -> Result<Truth> {
    let centres = if path.is_dir() {
        let units = units.and_then(Units::parse_label).ok_or_else(|| {
            Error::invalid("--truth-units", "truth meshes need --truth-units mm|m")
        })?;
        let frame = frame.and_then(Frame::parse_label).ok_or_else(|| {
            Error::invalid(
                "--truth-frame",
                "truth meshes need --truth-frame LPS|RAS|opensim",
            )
        })?;
        centres_from_meshes(path, units, frame, def)?
    } else {
        read_centres_csv(path)?
    };
    let landmarks = match landmarks {
        Some(p) => Some(crate::landmarks::io::load(p)?),
        None => None,
    };
    Ok(Truth {
        source: path.display().to_string(),
        centres,
        landmarks,
    })
}

/// Parse `--cobb-ends UPPER,LOWER` (upper at or above lower, not S1).
pub fn parse_cobb_ends(s: &str) -> Result<(Level, Level)> {
    let bad = || {
        Error::invalid(
            "--cobb-ends",
            format!("'{s}' is not UPPER,LOWER (e.g. T12,L4)"),
        )
    };
    let (a, b) = s.split_once(',').ok_or_else(bad)?;
    let (u, l): (Level, Level) = (
        a.trim().parse().map_err(|_| bad())?,
        b.trim().parse().map_err(|_| bad())?,
    );
    if u >= l || l.is_sacrum() {
        return Err(Error::invalid(
            "--cobb-ends",
            format!("'{s}': UPPER must be a vertebra above LOWER, and LOWER not S1 (e.g. T12,L4)"),
        ));
    }
    Ok((u, l))
}

/// How the truth is superimposed on the model after the registration.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Align {
    /// Least-squares rigid fit of the truth centres onto the model's.
    Rigid,
    /// Translation making the L5 centres coincide (thesis).
    L5,
    /// The generator's sacral registration only.
    Sacrum,
}

/// Per-level errors (model - truth, mm).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct LevelError {
    /// The vertebra.
    pub level: Level,
    /// Anterior-posterior error, along ground X (mm).
    pub ap_mm: f64,
    /// Inferior-superior error, along ground Y (mm).
    pub is_mm: f64,
    /// Right-left error, along ground Z (mm).
    pub rl_mm: f64,
    /// Distance between the model and truth centres (mm).
    pub distance_mm: f64,
}

/// Metrics of one model.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ModelMetrics {
    /// The model's name ([`ModelShape::name`]).
    pub model: String,
    /// How the truth was aligned to the model.
    pub align: Align,
    /// The model has a sacral registration.
    pub registration_known: bool,
    /// Errors per level present in both model and truth.
    pub levels: Vec<LevelError>,
    /// RMS of the centre distances over those levels (mm).
    pub centre_rmse_mm: f64,
    /// RMSE with the sacral registration alone (when known).
    pub centre_rmse_sacral_frame_mm: Option<f64>,
    /// Sagittal curve (X against Y) of the model centres compared with the truth's.
    pub sagittal: Option<metrics::CurveFit>,
    /// Frontal curve (Z against Y) of the model centres compared with the truth's.
    pub frontal: Option<metrics::CurveFit>,
    /// The model's Cobb angle over the truth's levels.
    pub cobb: Option<metrics::Cobb>,
    /// The truth's Cobb angle, from its landmarks.
    pub truth_cobb: Option<metrics::Cobb>,
    /// Model minus truth Cobb angle (deg).
    pub cobb_error_deg: Option<f64>,
    /// Apex level of the model's Cobb curve.
    pub apex: Option<Level>,
    /// Apex level of the truth's curve.
    pub truth_apex: Option<Level>,
    /// The model's lumbar lordosis (deg, negative = lordosis).
    pub lordosis_deg: Option<f64>,
    /// The truth's lumbar lordosis (deg, negative = lordosis).
    pub truth_lordosis_deg: Option<f64>,
    /// The model's sacral slope (deg).
    pub sacral_slope_deg: Option<f64>,
}

impl ModelShape {
    /// The generator's sacral registration (identity for a model without one).
    fn registration_isometry(&self) -> Isometry3<f64> {
        self.registration
            .as_ref()
            .map(|r| r.isometry())
            .unwrap_or_else(Isometry3::identity)
    }

    /// Levels with a centre in both the model and the truth, in level order.
    fn common_levels(&self, truth: &Truth) -> Vec<Level> {
        truth
            .centres
            .keys()
            .filter(|l| self.centres.contains_key(l))
            .copied()
            .collect()
    }
}

/// The transform taking the truth (its own frame, OpenSim axes, m) into
/// the model's ground: the generator's registration, then [`Align`].
pub fn truth_transform(m: &ModelShape, truth: &Truth, align: Align) -> Isometry3<f64> {
    let x_reg = m.registration_isometry();
    let common = m.common_levels(truth);
    let x_align = match align {
        Align::Sacrum => Isometry3::identity(),
        Align::L5 => {
            let l = if common.contains(&Level::L5) {
                Some(Level::L5)
            } else {
                common.last().copied()
            };
            match l.and_then(|l| Some((m.centres.get(&l)?, truth.centres.get(&l)?))) {
                Some((a, b)) => {
                    let b = x_reg * b;
                    Isometry3::translation(a.x - b.x, a.y - b.y, a.z - b.z)
                }
                None => Isometry3::identity(),
            }
        }
        Align::Rigid => {
            let src: Vec<Point3<f64>> = common.iter().map(|l| x_reg * truth.centres[l]).collect();
            let dst: Vec<Point3<f64>> = common.iter().map(|l| m.centres[l]).collect();
            if common.len() >= 3 {
                crate::mesh::umeyama(&src, &dst, false)
                    .map(|s| Isometry3::from_parts(s.translation.into(), s.rotation))
                    .unwrap_or_else(|_| Isometry3::identity())
            } else {
                Isometry3::identity()
            }
        }
    };
    x_align * x_reg
}

/// The landmarks of `set` at the levels the truth covers (its landmark
/// set's levels, else its centres' levels), S1 always kept.
fn at_truth_levels(set: &LandmarkSet, truth: &Truth) -> LandmarkSet {
    let levels: std::collections::BTreeSet<Level> = match &truth.landmarks {
        Some(t) => t.levels().into_iter().collect(),
        None => truth.centres.keys().copied().collect(),
    };
    at_levels(set, &levels)
}

/// The landmarks of `set` at `levels`, S1 always kept.
fn at_levels(set: &LandmarkSet, levels: &std::collections::BTreeSet<Level>) -> LandmarkSet {
    LandmarkSet {
        points: set
            .points
            .iter()
            .filter(|(id, _)| id.level.is_sacrum() || levels.contains(&id.level))
            .map(|(id, p)| (*id, *p))
            .collect(),
        detection: set.detection.clone(),
    }
}

/// Evaluate one model against the truth. `cobb_ends` fixes the end
/// vertebrae of the model's (and truth's) Cobb angle.
pub fn evaluate_model(
    m: &ModelShape,
    truth: &Truth,
    align: Align,
    cobb_ends: Option<(Level, Level)>,
) -> Result<ModelMetrics> {
    let x_reg = m.registration_isometry();
    let common = m.common_levels(truth);
    if common.is_empty() {
        return Err(Error::invalid(
            &m.name,
            format!("no level in common with the truth ({})", truth.source),
        ));
    }
    let reg_c: BTreeMap<Level, Point3<f64>> =
        truth.centres.iter().map(|(l, p)| (*l, x_reg * p)).collect();
    let rmse = |tc: &BTreeMap<Level, Point3<f64>>| {
        (common
            .iter()
            .map(|l| (m.centres[l] - tc[l]).norm_squared())
            .sum::<f64>()
            / common.len() as f64)
            .sqrt()
    };
    let sacral = m.registration.as_ref().map(|_| rmse(&reg_c) * 1e3);
    let x_t = truth_transform(m, truth, align);
    let tc: BTreeMap<Level, Point3<f64>> =
        truth.centres.iter().map(|(l, p)| (*l, x_t * p)).collect();
    let levels: Vec<LevelError> = common
        .iter()
        .map(|l| {
            let d = m.centres[l] - tc[l];
            LevelError {
                level: *l,
                ap_mm: d.x * 1e3,
                is_mm: d.y * 1e3,
                rl_mm: d.z * 1e3,
                distance_mm: d.norm() * 1e3,
            }
        })
        .collect();
    let samples = |c: &BTreeMap<Level, Point3<f64>>,
                   f: fn(&Point3<f64>) -> f64|
     -> Vec<(f64, f64)> { common.iter().map(|l| (c[l].y, f(&c[l]))).collect() };
    let sagittal = metrics::curve_compare(&samples(&tc, |p| p.x), &samples(&m.centres, |p| p.x));
    let frontal = metrics::curve_compare(&samples(&tc, |p| p.z), &samples(&m.centres, |p| p.z));
    // The model's angles over the truth's levels only (levels above a
    // field of view are not compared); the truth's from the truth alone,
    // in its own frame (the same for every model).
    // Model landmarks carried into the truth's frame (inverse alignment).
    let xi = x_t.inverse();
    let ml = at_truth_levels(&m.landmarks, truth).transformed(
        xi.rotation.to_rotation_matrix().matrix(),
        &xi.translation.vector,
    );
    let cobb = metrics::cobb(&ml, cobb_ends);
    let tl = truth.landmarks.as_ref();
    let truth_cobb = tl.and_then(|s| metrics::cobb(s, cobb_ends));
    let apex = cobb
        .as_ref()
        .and_then(|c| metrics::apex(&m.centres, c.upper, c.lower));
    let truth_apex = truth_cobb
        .as_ref()
        .or(cobb.as_ref())
        .and_then(|c| metrics::apex(&tc, c.upper, c.lower));
    Ok(ModelMetrics {
        model: m.name.clone(),
        align,
        registration_known: m.registration.is_some(),
        centre_rmse_mm: rmse(&tc) * 1e3,
        centre_rmse_sacral_frame_mm: sacral,
        levels,
        sagittal,
        frontal,
        cobb_error_deg: match (&cobb, &truth_cobb) {
            (Some(a), Some(b)) => Some(a.angle_deg - b.angle_deg),
            _ => None,
        },
        cobb,
        truth_cobb,
        apex,
        truth_apex,
        lordosis_deg: metrics::lordosis(&ml),
        truth_lordosis_deg: tl.and_then(metrics::lordosis),
        sacral_slope_deg: metrics::sacral_slope(&m.landmarks),
    })
}

/// Median and IQR.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct MedIqr {
    /// Median.
    pub median: f64,
    /// Interquartile range (type 7 quantiles).
    pub iqr: f64,
    /// Number of finite values.
    pub n: usize,
}

/// Mean, SD (n - 1), min, max.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct MeanSd {
    /// Mean.
    pub mean: f64,
    /// Sample standard deviation (n - 1; 0 for one value).
    pub sd: f64,
    /// Smallest value.
    pub min: f64,
    /// Largest value.
    pub max: f64,
    /// Number of finite values.
    pub n: usize,
}

/// Median and IQR (type 7) of the finite values (`None` when there are none).
pub fn med_iqr(v: &[f64]) -> Option<MedIqr> {
    let v: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    Some(MedIqr {
        median: crate::util::median(&v)?,
        iqr: crate::util::iqr(&v)?,
        n: v.len(),
    })
}

/// Mean, SD, min and max of the finite values (`None` when there are none).
pub fn mean_sd(v: &[f64]) -> Option<MeanSd> {
    let v: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return None;
    }
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let sd = if v.len() > 1 {
        (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt()
    } else {
        0.0
    };
    Some(MeanSd {
        mean,
        sd,
        min: v.iter().copied().fold(f64::MAX, f64::min),
        max: v.iter().copied().fold(f64::MIN, f64::max),
        n: v.len(),
    })
}

/// Per-level absolute errors across models (Table 5.7).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct LevelSummary {
    /// The vertebra.
    pub level: Level,
    /// |anterior-posterior error| across models (mm).
    pub ap_abs_mm: MedIqr,
    /// |inferior-superior error| across models (mm).
    pub is_abs_mm: MedIqr,
    /// |right-left error| across models (mm).
    pub rl_abs_mm: MedIqr,
}

/// Summary over several models (Tables 5.6-5.8).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Summary {
    /// Number of models.
    pub models: usize,
    /// Centre RMSE across models (mm).
    pub centre_rmse_mm: Option<MedIqr>,
    /// Sagittal curve RMSE across models (mm).
    pub sagittal_curve_rmse_mm: Option<MedIqr>,
    /// Frontal curve RMSE across models (mm).
    pub frontal_curve_rmse_mm: Option<MedIqr>,
    /// Sagittal curve R^2 across models.
    pub sagittal_r2: Option<MedIqr>,
    /// Frontal curve R^2 across models.
    pub frontal_r2: Option<MedIqr>,
    /// Absolute errors per level across models.
    pub levels: Vec<LevelSummary>,
    /// The models' Cobb angles (deg).
    pub cobb_deg: Option<MeanSd>,
    /// The models' lumbar lordosis (deg).
    pub lordosis_deg: Option<MeanSd>,
    /// Apex level -> number of models.
    #[serde(serialize_with = "crate::anatomy::serialize_by_name")]
    pub apex_counts: BTreeMap<Level, usize>,
}

/// Summarise several models' metrics.
pub fn summarise(all: &[ModelMetrics]) -> Summary {
    let col = |f: &dyn Fn(&ModelMetrics) -> Option<f64>| -> Vec<f64> {
        all.iter().filter_map(f).collect()
    };
    let mut per: BTreeMap<Level, [Vec<f64>; 3]> = BTreeMap::new();
    for m in all {
        for e in &m.levels {
            let s = per.entry(e.level).or_default();
            s[0].push(e.ap_mm.abs());
            s[1].push(e.is_mm.abs());
            s[2].push(e.rl_mm.abs());
        }
    }
    let mut apex_counts = BTreeMap::new();
    for m in all {
        if let Some(a) = &m.apex {
            *apex_counts.entry(*a).or_insert(0) += 1;
        }
    }
    Summary {
        models: all.len(),
        centre_rmse_mm: med_iqr(&col(&|m| Some(m.centre_rmse_mm))),
        sagittal_curve_rmse_mm: med_iqr(&col(&|m| m.sagittal.as_ref().map(|c| c.rmse_mm))),
        frontal_curve_rmse_mm: med_iqr(&col(&|m| m.frontal.as_ref().map(|c| c.rmse_mm))),
        sagittal_r2: med_iqr(&col(&|m| m.sagittal.as_ref().map(|c| c.r2))),
        frontal_r2: med_iqr(&col(&|m| m.frontal.as_ref().map(|c| c.r2))),
        levels: per
            .iter()
            .filter_map(|(l, v)| {
                Some(LevelSummary {
                    level: *l,
                    ap_abs_mm: med_iqr(&v[0])?,
                    is_abs_mm: med_iqr(&v[1])?,
                    rl_abs_mm: med_iqr(&v[2])?,
                })
            })
            .collect(),
        cobb_deg: mean_sd(&col(&|m| m.cobb.as_ref().map(|c| c.angle_deg))),
        lordosis_deg: mean_sd(&col(&|m| m.lordosis_deg)),
        apex_counts,
    }
}

/// Sign conventions and levels of the reported angles and errors.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Conventions {
    /// The axes and units of positions.
    pub axes: &'static str,
    /// Sign and axes of the errors.
    pub errors: &'static str,
    /// Definition and sign of the Cobb angle.
    pub cobb: &'static str,
    /// Definition and sign of the lordosis.
    pub lordosis: &'static str,
    /// Where the truth's angles come from.
    pub truth_metrics: &'static str,
}

/// The conventions written into every evaluation report.
pub const CONVENTIONS: Conventions = Conventions {
    axes: "OpenSim ground: X anterior, Y cranial, Z right (m internally, mm in the report)",
    errors: "model minus truth (ap_mm along X, is_mm along Y, rl_mm along Z; cobb_error_deg = model - truth)",
    cobb: "frontal-plane angle between the most tilted endplates (S1 excluded), signed: positive convex to the right; the model's over the truth's levels only",
    lordosis: "L1 superior endplate to S1 superior endplate, sagittal tilt of L1 minus that of S1 (deg); negative = lordosis",
    truth_metrics: "computed from the truth landmarks alone, in the truth's own frame (the same for every model); model landmarks are carried into that frame by the inverse alignment",
};

/// The full evaluation report.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct EvaluateReport {
    /// Where the truth was read from.
    pub truth: String,
    /// Definition of the vertebral centre used ([`centre_definition`]).
    pub vertebral_centre: &'static str,
    /// Sign conventions and levels of the angles ([`CONVENTIONS`]).
    pub conventions: Conventions,
    /// Metrics of each model.
    pub models: Vec<ModelMetrics>,
    /// Summary over the models.
    pub summary: Summary,
}

/// Definition text written into reports.
pub fn centre_definition(def: CentreDef) -> &'static str {
    match def {
        CentreDef::Endplates => "midpoint of the SEC and IEC markers at the default pose (truth meshes: volume centroid)",
        CentreDef::Sphere => "centre of the vertebral-body wrap sphere at the default pose (truth meshes: anterior-wall sphere fit)",
    }
}

/// Evaluate models against the truth; returns the report and the figures
/// `[(file name, svg)]`.
pub fn evaluate(
    models: &[ModelShape],
    truth: &Truth,
    align: Align,
    cobb_ends: Option<(Level, Level)>,
    def: CentreDef,
) -> Result<(EvaluateReport, Vec<(String, String)>)> {
    let mut all = Vec::new();
    for m in models {
        all.push(evaluate_model(m, truth, align, cobb_ends)?);
    }
    let summary = summarise(&all);
    let figures = figures(models, truth, align)?;
    Ok((
        EvaluateReport {
            truth: truth.source.clone(),
            conventions: CONVENTIONS,
            vertebral_centre: centre_definition(def),
            models: all,
            summary,
        },
        figures,
    ))
}

/// One two-point series per (model, level): model centre to truth centre.
fn error_vectors(models: &[ModelShape], tc: &BTreeMap<Level, Point3<f64>>) -> Vec<plot::Series> {
    let mut out = Vec::new();
    for m in models {
        for (l, p) in &m.centres {
            let Some(t) = tc.get(l) else { continue };
            out.push(plot::Series {
                label: if out.is_empty() {
                    "error (model to truth)".into()
                } else {
                    String::new()
                },
                colour: plotters::style::RGBColor(120, 120, 120),
                points: vec![*p, *t],
                radius: 0,
                line: true,
            });
        }
    }
    out
}

fn figures(models: &[ModelShape], truth: &Truth, align: Align) -> Result<Vec<(String, String)>> {
    use plot::Series;
    use plotters::style::RGBColor;
    // Truth in the first model's frame (figures are drawn in that frame).
    let Some(m0) = models.first() else {
        return Ok(Vec::new());
    };
    let mut series = Vec::new();
    let mut curves = Vec::new();
    for (k, m) in models.iter().enumerate() {
        let col = RGBColor(70 + (k * 37 % 120) as u8, 110, 220 - (k * 23 % 100) as u8);
        // Only the levels the truth has (the thesis's figures span the CT).
        let common: BTreeMap<Level, Point3<f64>> = m
            .centres
            .iter()
            .filter(|(l, _)| truth.centres.contains_key(l))
            .map(|(l, p)| (*l, *p))
            .collect();
        let pts: Vec<Point3<f64>> = common.values().copied().collect();
        series.push(Series {
            label: if k == 0 {
                "model centres".into()
            } else {
                String::new()
            },
            colour: col,
            points: pts.clone(),
            radius: 3,
            line: false,
        });
        curves.push(Series {
            label: if k == 0 {
                "model 4th-order fit".into()
            } else {
                String::new()
            },
            colour: col,
            points: poly_curve(&common),
            radius: 0,
            line: true,
        });
    }
    let x_t = truth_transform(m0, truth, align);
    let tc: BTreeMap<Level, Point3<f64>> =
        truth.centres.iter().map(|(l, p)| (*l, x_t * p)).collect();
    let red = RGBColor(220, 40, 40);
    // Truth first and larger, the models' centres on top, and an error
    // vector from each model centre to the truth's.
    let mut fig56 = vec![Series {
        label: "truth centres".into(),
        colour: red,
        points: tc.values().copied().collect(),
        radius: 5,
        line: false,
    }];
    fig56.extend(error_vectors(models, &tc));
    fig56.extend(series.clone_series());
    let mut fig57 = curves;
    fig57.push(Series {
        label: "truth centres".into(),
        colour: red,
        points: tc.values().copied().collect(),
        radius: 4,
        line: false,
    });
    fig57.push(Series {
        label: "truth 4th-order fit".into(),
        colour: red,
        points: poly_curve(&tc),
        radius: 0,
        line: true,
    });
    let mut out = Vec::new();
    for (name, s) in plot::labelled_views("vertebral centres (Fig. 5.6)", &fig56, &tc) {
        out.push((format!("centres_{name}.svg"), s));
    }
    for (name, s) in plot::views("4th-order curve fits (Fig. 5.7)", &fig57) {
        out.push((format!("curves_{name}.svg"), s));
    }
    Ok(out)
}

trait CloneSeries {
    fn clone_series(&self) -> Vec<plot::Series>;
}

impl CloneSeries for Vec<plot::Series> {
    fn clone_series(&self) -> Vec<plot::Series> {
        self.iter()
            .map(|s| plot::Series {
                label: s.label.clone(),
                colour: s.colour,
                points: s.points.clone(),
                radius: s.radius,
                line: s.line,
            })
            .collect()
    }
}

/// Points along the 4th-order fits X(Y) and Z(Y) of a set of centres.
fn poly_curve(c: &BTreeMap<Level, Point3<f64>>) -> Vec<Point3<f64>> {
    let h: Vec<f64> = c.values().map(|p| p.y).collect();
    let x: Vec<f64> = c.values().map(|p| p.x).collect();
    let z: Vec<f64> = c.values().map(|p| p.z).collect();
    let order = 4.min(h.len().saturating_sub(2));
    if order == 0 {
        return Vec::new();
    }
    let (Some(px), Some(pz)) = (
        metrics::polyfit(&h, &x, order),
        metrics::polyfit(&h, &z, order),
    ) else {
        return Vec::new();
    };
    let (lo, hi) = h
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), v| (a.min(*v), b.max(*v)));
    (0..=60)
        .map(|i| {
            let y = lo + (hi - lo) * i as f64 / 60.0;
            Point3::new(px.eval(y), y, pz.eval(y))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn centres_csv_with_bom_crlf_quotes_and_the_line_of_a_bad_cell() {
        let text = "\u{feff}# units: mm\r\n# frame: opensim\r\n\r\nlevel,x,y,z\r\n\"L1\", \"1\" ,2,3\r\n# the next level\r\nL2,4,5,6\r\n";
        let c = parse_centres_csv(text, Path::new("c.csv")).unwrap();
        assert_eq!(c.len(), 2);
        assert!((c[&Level::L1] - Point3::new(1e-3, 2e-3, 3e-3)).norm() < 1e-15);
        assert!((c[&Level::L2] - Point3::new(4e-3, 5e-3, 6e-3)).norm() < 1e-15);
        // `"4,5"` is one cell (not a fifth field), refused as a number on line 7
        let bad = text.replace("L2,4,5,6", "L2,\"4,5\",6,7");
        let e = parse_centres_csv(&bad, Path::new("c.csv"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("c.csv: line 7: column 2: expected a finite number, found `4,5`"),
            "{e}"
        );
    }
}
