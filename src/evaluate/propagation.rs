//! Propagation of palpation variability to the model (`osim-spine
//! variability`, thesis chapter 5, Tables 5.6-5.8): one patient model per
//! palpation ([`crate::generate`], in memory), each evaluated with
//! the metrics of [`crate::evaluate`] (vertebral-centre RMSE, per-level
//! errors, sagittal and frontal 4th-order curve RMSE and R2, Cobb angle,
//! apex, lumbar lordosis).
//!
//! **Reference.** With a truth (`--truth`: CT centres or vertebral-body
//! meshes, as `evaluate` takes them) every model is compared with it. Without,
//! the reference is the **consensus model**: the model generated from the
//! per-landmark median landmark set (coordinate-wise median over the
//! palpations holding the landmark; a landmark held by half of the
//! palpations or fewer is left out). Its centres and markers are brought
//! back into the palpations' frame through its own sacral registration, so
//! each palpation's model meets the reference through its own registration
//! exactly as it would meet a CT truth; the report names the reference used.
//! The consensus is generated in both cases (its automatic Cobb end
//! vertebrae are the default ends when no truth landmarks give them).
//!
//! **Cobb ends** are the same for every model (as in the thesis, which
//! measured T12-L4 on all models): `--cobb-ends`, else the automatic ends
//! of the reference (truth landmarks, else consensus model), else automatic
//! per model.
//!
//! **Groups** (thesis Table 5.6): `overall` (all models), `intra` (the
//! models of one operator with two or more repetitions) and `inter` (the
//! models of one repetition number that two or more operators have; the
//! thesis used the 3rd). Each gives the median and IQR (type 7) of every
//! metric, mean/SD/min/max of Cobb angle and lordosis (Table 5.8) and the
//! apex counts; `levels` gives Table 5.7 over all models.
//!
//! A palpation whose landmark set fails the generator's blocking checks
//! ([`crate::landmarks::check::GENERATE_BLOCKING`]) or whose generation or
//! evaluation fails is listed with its error and left out of the
//! statistics; only when every palpation fails is it an error. Models are
//! generated in parallel (rayon, the caller's thread pool) and collected in
//! palpation order, so the report is deterministic.

use super::palpations::PalpationSet;
use super::{
    centre_definition, evaluate_model, mean_sd, med_iqr, metrics, summarise, truth_transform,
    Align, CentreDef, LevelSummary, MeanSd, MedIqr, ModelMetrics, ModelShape, Truth,
};
use crate::error::{Error, Result};
use crate::generate::{generate, GenerateOptions, Generated, Method};
use crate::landmarks::check::{check_completeness, check_set, Severity, GENERATE_BLOCKING};
use crate::landmarks::{LandmarkId, LandmarkSet, Level};
use crate::osim::Document;
use nalgebra::Point3;
use rayon::prelude::*;
use std::collections::BTreeMap;

/// Options of [`propagate`].
#[derive(Debug, Clone)]
pub struct PropagationOptions {
    /// Vertebra pose fit of the generator.
    pub method: Method,
    /// External truth (CT); `None`: the consensus model is the reference.
    pub truth: Option<Truth>,
    /// Superimposition of the reference on each model (see [`Align`]).
    pub align: Align,
    /// Vertebral-centre definition (models and reference).
    pub centre: CentreDef,
    /// Fixed Cobb end vertebrae (upper, lower).
    pub cobb_ends: Option<(Level, Level)>,
    /// Progress bar on stderr (drawn only on a terminal, 4+ palpations).
    pub progress: bool,
    /// Keep the generated models (to write them).
    pub keep_models: bool,
}

impl Default for PropagationOptions {
    fn default() -> Self {
        PropagationOptions {
            method: Method::Lsq,
            truth: None,
            align: Align::Rigid,
            centre: CentreDef::default(),
            cobb_ends: None,
            progress: false,
            keep_models: false,
        }
    }
}

/// One palpation's model.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct PalpationModel {
    /// Operator identifier.
    pub operator: String,
    /// Repetition number of that operator.
    pub repetition: u32,
    /// The landmark file.
    pub source: String,
    /// Generated and evaluated.
    pub ok: bool,
    /// Why not, when not.
    pub error: Option<String>,
    /// Landmarks the generator rejected as outliers (`<LEVEL>_<CODE> (mm)`).
    pub outliers: Vec<String>,
    /// RMS landmark-to-model residual (mm).
    pub landmark_rms_mm: Option<f64>,
    /// The metrics against the reference (as `evaluate` reports them).
    pub metrics: Option<ModelMetrics>,
}

/// Median and IQR of the model metrics over a group of palpations.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct GroupSummary {
    /// `overall`, `intra` or `inter`.
    pub kind: String,
    /// `all`, `operator A` or `repetition 3`.
    pub within: String,
    /// Palpations in the group, and how many gave a model.
    pub palpations: usize,
    /// How many of them gave a model.
    pub models: usize,
    /// Vertebral centre RMSE against the reference (mm).
    pub centre_rmse_mm: Option<MedIqr>,
    /// Sagittal curve RMSE (mm).
    pub sagittal_curve_rmse_mm: Option<MedIqr>,
    /// Frontal curve RMSE (mm).
    pub frontal_curve_rmse_mm: Option<MedIqr>,
    /// Sagittal curve R^2.
    pub sagittal_r2: Option<MedIqr>,
    /// Frontal curve R^2.
    pub frontal_r2: Option<MedIqr>,
    /// Cobb angle (deg).
    pub cobb_deg: Option<MedIqr>,
    /// Lumbar lordosis (deg).
    pub lordosis_deg: Option<MedIqr>,
    /// Table 5.8.
    pub cobb_mean_sd_deg: Option<MeanSd>,
    /// Mean and SD of the lordosis (deg).
    pub lordosis_mean_sd_deg: Option<MeanSd>,
    /// Apex level -> number of models.
    #[serde(serialize_with = "crate::anatomy::serialize_by_name")]
    pub apex_counts: BTreeMap<Level, usize>,
}

/// The reference the models were compared with.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Reference {
    /// `truth` or `consensus`.
    pub kind: String,
    /// The reference's file.
    pub source: String,
    /// Levels with a reference centre.
    pub levels: Vec<Level>,
    /// The reference's own Cobb angle, apex and lordosis (truth landmarks
    /// or consensus model markers; `None` without them).
    pub cobb: Option<metrics::Cobb>,
    /// The reference's apex level.
    pub apex: Option<Level>,
    /// The reference's lumbar lordosis (deg).
    pub lordosis_deg: Option<f64>,
}

/// The consensus (per-landmark median) landmark set and its model.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Consensus {
    /// Number of landmarks in the consensus set.
    pub landmarks: usize,
    /// Landmarks held by half of the palpations or fewer (left out).
    pub left_out: Vec<String>,
    /// Whether its model could be generated, and the error when not.
    pub generated: bool,
    /// The generator's error, when it failed.
    pub error: Option<String>,
    /// Landmarks the generator rejected as outliers.
    pub outliers: Vec<String>,
}

/// The `model_propagation` section of the variability report.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ModelPropagation {
    /// What the models were compared with.
    pub reference: Reference,
    /// The consensus set and its model.
    pub consensus: Consensus,
    /// The generation method used for every model.
    pub method: Method,
    /// How each model was aligned with the reference.
    pub align: Align,
    /// How vertebral centres are defined.
    pub vertebral_centre: &'static str,
    /// The Cobb end vertebrae used for every model (`UPPER-LOWER`) and
    /// where they come from (`given`, `truth landmarks`, `consensus model`),
    /// or `automatic per model`.
    pub cobb_ends: String,
    /// Number of palpations.
    pub palpations: usize,
    /// Number of models generated.
    pub models: usize,
    /// Number of palpations whose model failed.
    pub failed: usize,
    /// Summaries over all, per operator and per repetition.
    pub groups: Vec<GroupSummary>,
    /// Per-level absolute errors over all models (Table 5.7).
    pub levels: Vec<LevelSummary>,
    /// One row per palpation, in input order.
    pub rows: Vec<PalpationModel>,
}

/// The result of [`propagate`]: the report section, and the generated
/// models (label, model) when [`PropagationOptions::keep_models`].
#[derive(Debug, Clone)]
pub struct Propagated {
    /// The report section.
    pub report: ModelPropagation,
    /// The generated models `(label, model)`; empty unless kept.
    pub models: Vec<(String, Generated)>,
}

/// Per-landmark median set: coordinate-wise median over the palpations
/// holding the landmark; landmarks held by at most half are left out.
fn median_set(pals: &[PalpationSet]) -> (LandmarkSet, Vec<LandmarkId>) {
    let mut pts: BTreeMap<LandmarkId, Vec<Point3<f64>>> = BTreeMap::new();
    for p in pals {
        for (id, q) in &p.set.points {
            pts.entry(*id).or_default().push(*q);
        }
    }
    let mut set = LandmarkSet::new();
    let mut left_out = Vec::new();
    for (id, v) in pts {
        if v.len() * 2 <= pals.len() {
            left_out.push(id);
            continue;
        }
        let coord = |k: usize| {
            let c: Vec<f64> = v.iter().map(|p| p.coords[k]).collect();
            crate::landmarks::stats::median(&c)
        };
        if let (Some(x), Some(y), Some(z)) = (coord(0), coord(1), coord(2)) {
            set.points.insert(id, Point3::new(x, y, z));
        } else {
            left_out.push(id);
        }
    }
    (set, left_out)
}

/// The blocking findings of the landmark checks on a resolved set
/// (those `generate` refuses a file for), as one message.
fn blocking_findings(set: &LandmarkSet) -> Option<String> {
    let lines = BTreeMap::new();
    let mut f = check_completeness(set, &lines);
    f.extend(check_set(set, &lines));
    let msgs: Vec<String> = f
        .iter()
        .filter(|f| f.severity == Severity::Error && GENERATE_BLOCKING.contains(&f.code.as_str()))
        .map(|f| format!("{} {}", f.code, f.message))
        .collect();
    (!msgs.is_empty()).then(|| {
        format!(
            "the landmark set fails its checks (see `osim-spine check`): {}",
            msgs.join("; ")
        )
    })
}

/// Check, generate (no self-check, no views) and take the shape of one
/// landmark set.
fn model_of(
    base: &Document,
    set: &LandmarkSet,
    label: &str,
    opts: &PropagationOptions,
) -> Result<(Generated, ModelShape)> {
    if let Some(msg) = blocking_findings(set) {
        return Err(Error::invalid(label, msg));
    }
    let g = generate(
        base,
        set,
        label,
        &GenerateOptions {
            method: opts.method,
            self_check: false,
            views: false,
            ..GenerateOptions::default()
        },
        None,
    )?;
    let mut shape =
        ModelShape::from_document(&g.doc, Some(g.report.registration.clone()), opts.centre)?;
    shape.name = label.to_string();
    Ok((g, shape))
}

/// The consensus model as a truth in the palpations' frame: its centres
/// and markers of the landmarked levels (and S1), moved back through its
/// own registration.
fn consensus_truth(g: &Generated, shape: &ModelShape, source: String) -> Truth {
    let back = g.report.registration.isometry().inverse();
    let landmarked = &g.report.levels_from_landmarks;
    Truth {
        source,
        centres: shape
            .centres
            .iter()
            .filter(|(l, _)| landmarked.contains(l))
            .map(|(l, p)| (*l, back * p))
            .collect(),
        // the landmarked levels only: the reference's Cobb and lordosis are
        // measured where the palpations are, as every model's are
        landmarks: Some(super::at_levels(
            &shape.landmarks.transformed(
                back.rotation.to_rotation_matrix().matrix(),
                &back.translation.vector,
            ),
            &landmarked.iter().copied().collect(),
        )),
    }
}

/// The label of a palpation (also its model's name).
pub fn label(p: &PalpationSet) -> String {
    format!("operator {} repetition {}", p.operator, p.repetition)
}

/// Generate and evaluate one model per palpation (see the module docs).
pub fn propagate(
    pals: &[PalpationSet],
    base: &Document,
    opts: &PropagationOptions,
) -> Result<Propagated> {
    if pals.is_empty() {
        return Err(Error::invalid("variability", "no palpations"));
    }
    // The consensus model, from the per-landmark median set.
    let (mset, left_out) = median_set(pals);
    let consensus = model_of(base, &mset, "consensus (per-landmark median)", opts);
    let cinfo = Consensus {
        landmarks: mset.len(),
        left_out: left_out.iter().map(|i| i.to_string()).collect(),
        generated: consensus.is_ok(),
        error: consensus.as_ref().err().map(|e| e.to_string()),
        outliers: consensus
            .as_ref()
            .map(|(g, _)| g.report.outliers.clone())
            .unwrap_or_default(),
    };
    // The reference: the truth, else the consensus model.
    let (truth, kind) = reference_of(pals, &consensus, opts)?;
    // The reference's Cobb, apex and lordosis, and the Cobb ends of every model.
    let reference = reference_metrics(&truth, kind, &consensus, opts);
    let ends = choose_cobb_ends(&reference.cobb, kind, &consensus, opts);
    let cobb_ends = match ends {
        (Some((u, l)), from) => format!("{u}-{l} ({from})"),
        (None, from) => from.to_string(),
    };
    // One model per palpation, evaluated against the reference.
    let results = palpation_models(pals, base, &truth, ends.0, opts);
    let (rows, models) = palpation_rows(pals, results, opts.keep_models);
    let ok = rows.iter().filter(|r| r.ok).count();
    if ok == 0 {
        return Err(no_model(&rows));
    }
    // Median and IQR overall, intra- and inter-operator; per level over all.
    let groups = groups_of(&rows);
    let all: Vec<ModelMetrics> = rows.iter().filter_map(|r| r.metrics.clone()).collect();
    let levels = summarise(&all).levels;
    Ok(Propagated {
        report: ModelPropagation {
            reference,
            consensus: cinfo,
            method: opts.method,
            align: opts.align,
            vertebral_centre: centre_definition(opts.centre),
            cobb_ends,
            palpations: pals.len(),
            models: ok,
            failed: pals.len() - ok,
            groups,
            levels,
            rows,
        },
        models,
    })
}

/// The consensus model's result: its generation and shape, or why it failed.
type ConsensusModel = Result<(Generated, ModelShape)>;

/// The reference of the model metrics and its kind: the given truth, else
/// the consensus model in the palpations' frame (an error when it failed).
fn reference_of(
    pals: &[PalpationSet],
    consensus: &ConsensusModel,
    opts: &PropagationOptions,
) -> Result<(Truth, &'static str)> {
    let csource = format!(
        "consensus model (per-landmark median of {} palpations)",
        pals.len()
    );
    match (&opts.truth, consensus) {
        (Some(t), _) => Ok((t.clone(), "truth")),
        (None, Ok((g, shape))) => Ok((consensus_truth(g, shape, csource), "consensus")),
        (None, Err(e)) => Err(Error::invalid(
            "variability",
            format!(
                "the consensus model (per-landmark median set), the reference of the model \
                 metrics without --truth, cannot be generated: {e}"
            ),
        )),
    }
}

/// The reference's Cobb, lordosis (measured in the reference's own frame,
/// as `evaluate` measures every model's, carried into that frame) and apex
/// (on the centres in the consensus model's frame, where the models are,
/// when it exists).
fn reference_metrics(
    truth: &Truth,
    kind: &str,
    consensus: &ConsensusModel,
    opts: &PropagationOptions,
) -> Reference {
    let x_ref = consensus
        .as_ref()
        .ok()
        .map(|(_, shape)| truth_transform(shape, truth, opts.align))
        .unwrap_or_else(nalgebra::Isometry3::identity);
    let ref_landmarks = truth.landmarks.as_ref();
    let ref_centres: BTreeMap<Level, Point3<f64>> =
        truth.centres.iter().map(|(l, p)| (*l, x_ref * p)).collect();
    let ref_cobb = ref_landmarks.and_then(|s| metrics::cobb(s, opts.cobb_ends));
    let ref_apex = ref_cobb
        .as_ref()
        .and_then(|c| metrics::apex(&ref_centres, c.upper, c.lower));
    Reference {
        kind: kind.into(),
        source: truth.source.clone(),
        levels: truth.centres.keys().copied().collect(),
        cobb: ref_cobb,
        apex: ref_apex,
        lordosis_deg: ref_landmarks.and_then(metrics::lordosis),
    }
}

/// The Cobb end vertebrae of every model and where they come from: given,
/// else the reference's, else the consensus model's, else none (automatic
/// per model).
fn choose_cobb_ends(
    ref_cobb: &Option<metrics::Cobb>,
    kind: &str,
    consensus: &ConsensusModel,
    opts: &PropagationOptions,
) -> (Option<(Level, Level)>, &'static str) {
    let ends = |c: &metrics::Cobb| (c.upper, c.lower);
    match opts.cobb_ends {
        Some(e) => (Some(e), "given"),
        None => match ref_cobb.as_ref().map(ends) {
            Some(e) if kind == "truth" => (Some(e), "truth landmarks"),
            Some(e) => (Some(e), "consensus model"),
            None => match consensus
                .as_ref()
                .ok()
                .and_then(|(_, s)| metrics::cobb(&s.landmarks, None))
                .as_ref()
                .map(ends)
            {
                Some(e) => (Some(e), "consensus model"),
                None => (None, "automatic per model"),
            },
        },
    }
}

/// Each palpation's model (generated in parallel, in palpation order) and
/// its metrics against `truth`.
fn palpation_models(
    pals: &[PalpationSet],
    base: &Document,
    truth: &Truth,
    ends: Option<(Level, Level)>,
    opts: &PropagationOptions,
) -> Vec<Result<(Generated, ModelMetrics)>> {
    let show = opts.progress && pals.len() >= 4;
    let bar = crate::util::progress::bar("variability", pals.len() as u64, "models", show);
    let results = pals
        .par_iter()
        .map(|p| {
            let name = label(p);
            let r = model_of(base, &p.set, &name, opts).and_then(|(g, shape)| {
                let m = evaluate_model(&shape, truth, opts.align, ends)?;
                Ok((g, m))
            });
            bar.inc(1);
            r
        })
        .collect();
    bar.finish_and_clear();
    results
}

/// Generated models to keep, labelled.
type KeptModels = Vec<(String, Generated)>;

/// One row per palpation (its metrics, or its error), and the models when
/// `keep_models`.
fn palpation_rows(
    pals: &[PalpationSet],
    results: Vec<Result<(Generated, ModelMetrics)>>,
    keep_models: bool,
) -> (Vec<PalpationModel>, KeptModels) {
    let mut rows = Vec::new();
    let mut models = Vec::new();
    for (p, r) in pals.iter().zip(results) {
        let source = p.source.display().to_string();
        match r {
            Ok((g, m)) => {
                rows.push(PalpationModel {
                    operator: p.operator.clone(),
                    repetition: p.repetition,
                    source,
                    ok: true,
                    error: None,
                    outliers: g.report.outliers.clone(),
                    landmark_rms_mm: Some(g.report.landmark_rms_mm),
                    metrics: Some(m),
                });
                if keep_models {
                    models.push((label(p), g));
                }
            }
            Err(e) => rows.push(PalpationModel {
                operator: p.operator.clone(),
                repetition: p.repetition,
                source,
                ok: false,
                error: Some(e.to_string()),
                outliers: Vec::new(),
                landmark_rms_mm: None,
                metrics: None,
            }),
        }
    }
    (rows, models)
}

/// The error when no palpation gave a model: every palpation's error.
fn no_model(rows: &[PalpationModel]) -> Error {
    let errs: Vec<String> = rows
        .iter()
        .map(|r| {
            format!(
                "{} ({}): {}",
                label_of(r),
                r.source,
                r.error.as_deref().unwrap_or("")
            )
        })
        .collect();
    Error::invalid(
        "variability",
        format!(
            "no palpation gave a model (use --no-models for the landmark statistics alone):\n  {}",
            errs.join("\n  ")
        ),
    )
}

/// The groups: overall, intra-operator (operators with two or more
/// repetitions), inter-operator (repetitions two or more operators have).
fn groups_of(rows: &[PalpationModel]) -> Vec<GroupSummary> {
    let mut groups = vec![group("overall", "all", &rows.iter().collect::<Vec<_>>())];
    let mut by_op: BTreeMap<&str, Vec<&PalpationModel>> = BTreeMap::new();
    let mut by_rep: BTreeMap<u32, Vec<&PalpationModel>> = BTreeMap::new();
    for r in rows {
        by_op.entry(r.operator.as_str()).or_default().push(r);
        by_rep.entry(r.repetition).or_default().push(r);
    }
    for (op, mut v) in by_op {
        if v.len() >= 2 {
            v.sort_by_key(|r| r.repetition);
            groups.push(group("intra", &format!("operator {op}"), &v));
        }
    }
    for (rep, mut v) in by_rep {
        if v.len() >= 2 {
            v.sort_by(|a, b| a.operator.cmp(&b.operator));
            groups.push(group("inter", &format!("repetition {rep}"), &v));
        }
    }
    groups
}

fn label_of(r: &PalpationModel) -> String {
    format!("operator {} repetition {}", r.operator, r.repetition)
}

/// Summary of one group of rows.
fn group(kind: &str, within: &str, rows: &[&PalpationModel]) -> GroupSummary {
    let ms: Vec<ModelMetrics> = rows.iter().filter_map(|r| r.metrics.clone()).collect();
    let s = summarise(&ms);
    let cobb: Vec<f64> = ms
        .iter()
        .filter_map(|m| m.cobb.as_ref().map(|c| c.angle_deg))
        .collect();
    let lord: Vec<f64> = ms.iter().filter_map(|m| m.lordosis_deg).collect();
    GroupSummary {
        kind: kind.into(),
        within: within.into(),
        palpations: rows.len(),
        models: ms.len(),
        centre_rmse_mm: s.centre_rmse_mm,
        sagittal_curve_rmse_mm: s.sagittal_curve_rmse_mm,
        frontal_curve_rmse_mm: s.frontal_curve_rmse_mm,
        sagittal_r2: s.sagittal_r2,
        frontal_r2: s.frontal_r2,
        cobb_deg: med_iqr(&cobb),
        lordosis_deg: med_iqr(&lord),
        cobb_mean_sd_deg: mean_sd(&cobb),
        lordosis_mean_sd_deg: mean_sd(&lord),
        apex_counts: s.apex_counts,
    }
}

/// Box plots of the model metrics over all models (`(file name, svg)`):
/// `model_errors_boxplot.svg` (centre RMSE, sagittal and frontal curve
/// RMSE, mm), `model_r2_boxplot.svg` (curve R2), `model_angles_boxplot.svg`
/// (Cobb angle, lordosis, deg) and `model_centre_rmse_groups.svg` (centre
/// RMSE per group).
pub fn boxplots(p: &ModelPropagation) -> Vec<(String, String)> {
    use crate::util::charts::{boxplot_svg, boxplot_svg_axis};
    let ms: Vec<&ModelMetrics> = p.rows.iter().filter_map(|r| r.metrics.as_ref()).collect();
    let col = |f: &dyn Fn(&ModelMetrics) -> Option<f64>| -> Vec<f64> {
        ms.iter().filter_map(|m| f(m)).collect()
    };
    let refname = if p.reference.kind == "truth" {
        "truth"
    } else {
        "consensus model"
    };
    let n = ms.len();
    let errors = boxplot_svg(
        &format!("Model errors vs the {refname} ({n} models)"),
        "mm",
        &[
            ("centre RMSE".into(), col(&|m| Some(m.centre_rmse_mm))),
            (
                "sagittal curve RMSE".into(),
                col(&|m| m.sagittal.as_ref().map(|c| c.rmse_mm)),
            ),
            (
                "frontal curve RMSE".into(),
                col(&|m| m.frontal.as_ref().map(|c| c.rmse_mm)),
            ),
        ],
    );
    let r2 = boxplot_svg_axis(
        &format!("Curve R2 vs the {refname} ({n} models)"),
        "R2",
        &[
            (
                "sagittal R2".into(),
                col(&|m| m.sagittal.as_ref().map(|c| c.r2)),
            ),
            (
                "frontal R2".into(),
                col(&|m| m.frontal.as_ref().map(|c| c.r2)),
            ),
        ],
        false,
    );
    let angles = boxplot_svg_axis(
        &format!(
            "Cobb angle ({}) and lumbar lordosis ({n} models)",
            p.cobb_ends
        ),
        "deg",
        &[
            (
                "Cobb angle".into(),
                col(&|m| m.cobb.as_ref().map(|c| c.angle_deg)),
            ),
            ("lordosis".into(), col(&|m| m.lordosis_deg)),
        ],
        false,
    );
    let groups: Vec<(String, Vec<f64>)> = p
        .groups
        .iter()
        .map(|g| {
            let name = match g.kind.as_str() {
                "overall" => "overall".to_string(),
                "intra" => format!("intra {}", g.within.trim_start_matches("operator ")),
                _ => format!("inter rep {}", g.within.trim_start_matches("repetition ")),
            };
            let v = p
                .rows
                .iter()
                .filter(|r| match g.kind.as_str() {
                    "overall" => true,
                    "intra" => g.within == format!("operator {}", r.operator),
                    _ => g.within == format!("repetition {}", r.repetition),
                })
                .filter_map(|r| r.metrics.as_ref().map(|m| m.centre_rmse_mm))
                .collect();
            (name, v)
        })
        .collect();
    let by_group = boxplot_svg(
        &format!("Vertebral-centre RMSE vs the {refname} per group"),
        "centre RMSE (mm)",
        &groups,
    );
    vec![
        ("model_errors_boxplot.svg".into(), errors),
        ("model_r2_boxplot.svg".into(), r2),
        ("model_angles_boxplot.svg".into(), angles),
        ("model_centre_rmse_groups.svg".into(), by_group),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::landmarks::Code;
    use std::path::PathBuf;

    #[test]
    fn median_set_takes_coordinate_medians_of_the_majority_landmarks() {
        let pal = |dx: f64, extra: bool| {
            let mut set = LandmarkSet::new();
            set.insert(Level::L1, Code::SEC, Point3::new(0.1 + dx, 0.2, -dx));
            if extra {
                set.insert(Level::L1, Code::IEC, Point3::new(1.0, 1.0, 1.0));
            }
            PalpationSet {
                operator: "A".into(),
                repetition: 1,
                source: PathBuf::from("x"),
                set,
            }
        };
        let pals = [pal(-0.003, false), pal(0.0, true), pal(0.010, false)];
        let (m, left_out) = median_set(&pals);
        assert_eq!(m.len(), 1);
        let p = m.get(Level::L1, Code::SEC).unwrap();
        assert!((p - Point3::new(0.1, 0.2, 0.0)).norm() < 1e-15);
        assert_eq!(left_out, vec![LandmarkId::new(Level::L1, Code::IEC)]);
    }
}
