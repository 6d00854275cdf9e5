//! `osim-spine variability`: statistics of repeated palpations (thesis
//! chapter 5, "Evaluation of intra and inter-operator variability").
//!
//! Input: palpations (operator, repetition, landmark set). Axes follow the
//! thesis and the OpenSim frame: X anterior-posterior, Y inferior-superior,
//! Z left-right; values in millimetres. "Euclidean" is the distance of a
//! landmark from the study origin (the grand centroid of all landmarks of
//! all palpations), the thesis's "global position"; its IQR measures radial
//! dispersion, and its ICC is meaningful because targets differ.
//!
//! Report sections:
//! - `landmarks`: per landmark IQR in X, Y, Z and Euclidean over all palpations;
//! - `summary`: median and IQR of those IQRs, for all / joint / scaling
//!   markers (thesis Table 5.5);
//! - `icc`: ICC(2,1) per coordinate and Euclidean, joint and scaling
//!   markers separately; inter-operator for every repetition number that at
//!   least two operators have (the thesis used the 3rd), intra-operator for
//!   every operator with two or more repetitions; targets are the landmarks
//!   present in every palpation compared;
//! - `normality`: Shapiro-Wilk per landmark and coordinate;
//! - `friedman`: per marker type (code) and coordinate, blocked by level:
//!   inter-operator (groups = operators, one test per repetition) and
//!   intra-operator (groups = repetitions, one test per operator);
//!   Friedman when blocks are complete, Skillings-Mack otherwise
//!   ([`crate::landmarks::stats`]); when p < 0.05 the one-to-many Nemenyi test against
//!   the first operator / first repetition;
//! - `model_propagation` (with [`compute`]/[`run`] given a base model):
//!   the thesis's Tables 5.6-5.8, one generated model per palpation
//!   evaluated against the truth or the consensus model, median and IQR
//!   overall, intra- and inter-operator ([`crate::evaluate::propagation`]).
//!
//! Figures: [`crate::util::charts::boxplot_svg`] draws every box plot (the
//! per-landmark IQRs here, the model metrics in
//! [`crate::evaluate::propagation::boxplots`]).

pub use super::palpations::{load_palpations, PalpationSet};
use super::propagation::{self, ModelPropagation, PropagationOptions};
use crate::error::{Error, Result};
use crate::landmarks::stats::{self, Icc};
use crate::landmarks::{Code, LandmarkId, Level};
use crate::osim::Document;
use crate::util::write_all_or_nothing;
use nalgebra::Vector3;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

const AXES: [&str; 4] = ["X", "Y", "Z", "Euclidean"];

/// Per-landmark IQRs (mm).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct LandmarkIqr {
    /// The landmark.
    pub landmark: LandmarkId,
    /// Number of palpations holding it.
    pub n: usize,
    /// X, Y, Z, Euclidean.
    pub iqr_mm: [f64; 4],
}

/// Median and IQR of the per-landmark IQRs (Table 5.5).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct IqrSummary {
    /// Landmark group (`all`, `joint` or `scaling`).
    pub group: String,
    /// Axis (`X`, `Y`, `Z` or `Euclidean`).
    pub axis: String,
    /// Median of the per-landmark IQRs (mm).
    pub median_mm: f64,
    /// IQR of the per-landmark IQRs (mm).
    pub iqr_mm: f64,
    /// Largest per-landmark IQR (mm).
    pub max_mm: f64,
}

/// One ICC(2,1) analysis.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct IccEntry {
    /// `inter` or `intra`.
    pub kind: String,
    /// `repetition 3` or `operator A`.
    pub within: String,
    /// `joint` or `scaling`.
    pub group: String,
    /// Axis (`X`, `Y`, `Z` or `Euclidean`).
    pub axis: String,
    /// Number of targets (landmarks).
    pub targets: usize,
    /// Number of raters.
    pub raters: usize,
    /// The ICC(2,1) value.
    pub icc2_1: f64,
}

/// One Shapiro-Wilk test.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct NormalityEntry {
    /// The landmark tested.
    pub landmark: LandmarkId,
    /// Axis (`X`, `Y`, `Z` or `Euclidean`).
    pub axis: String,
    /// Sample size.
    pub n: usize,
    /// The W statistic.
    pub w: f64,
    /// p-value of normality.
    pub p: f64,
}

/// One post hoc comparison.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct PostHoc {
    /// The group compared.
    pub versus: String,
    /// The reference group.
    pub reference: String,
    /// The z statistic of the comparison.
    pub z: f64,
    /// Single-step adjusted two-sided p-value.
    pub p: f64,
}

/// One Friedman-type test.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct FriedmanEntry {
    /// `inter` or `intra`.
    pub kind: String,
    /// `repetition 3` or `operator A`.
    pub within: String,
    /// The landmark code tested.
    pub marker: Code,
    /// Axis (`X`, `Y`, `Z` or `Euclidean`).
    pub axis: String,
    /// `friedman` or `skillings-mack`.
    pub method: String,
    /// The test statistic.
    pub statistic: f64,
    /// Degrees of freedom.
    pub df: usize,
    /// p-value.
    pub p: f64,
    /// Blocks used.
    pub blocks: usize,
    /// The groups compared, the reference first.
    pub groups: Vec<String>,
    /// Nemenyi many-to-one against `groups[0]`, when p < 0.05.
    pub posthoc: Vec<PostHoc>,
}

/// The full report.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct VariabilityReport {
    /// Number of palpations.
    pub palpations: usize,
    /// Operator -> repetitions.
    pub operators: BTreeMap<String, Vec<u32>>,
    /// Units of the distances (`mm`).
    pub units: String,
    /// What the axes are.
    pub axes: String,
    /// Per-landmark IQRs.
    pub landmarks: Vec<LandmarkIqr>,
    /// Medians and IQRs of the per-landmark IQRs.
    pub summary: Vec<IqrSummary>,
    /// ICC(2,1) analyses.
    pub icc: Vec<IccEntry>,
    /// Shapiro-Wilk tests.
    pub normality: Vec<NormalityEntry>,
    /// Number of Shapiro-Wilk tests rejecting normality at 5%.
    pub normality_rejected_at_5pct: usize,
    /// Friedman-type tests.
    pub friedman: Vec<FriedmanEntry>,
    /// Thesis Tables 5.6-5.8: one model per palpation
    /// ([`crate::evaluate::propagation`]); `None` when not asked for.
    pub model_propagation: Option<ModelPropagation>,
    /// Remarks on the analysis.
    pub notes: Vec<String>,
    /// What makes the statistics doubtful (palpations with identical
    /// landmark sets).
    pub warnings: Vec<String>,
}

fn value(p: &nalgebra::Point3<f64>, origin: &Vector3<f64>, axis: usize) -> f64 {
    if axis < 3 {
        p.coords[axis] * 1e3
    } else {
        (p.coords - origin).norm() * 1e3
    }
}

/// (kind, within, labelled palpations in group order).
type Comparison<'a> = (String, String, Vec<(String, &'a PalpationSet)>);

/// Compute the report.
pub fn analyse(pals: &[PalpationSet]) -> Result<VariabilityReport> {
    if pals.len() < 2 {
        return Err(Error::invalid(
            "variability",
            format!("need at least 2 palpations, got {}", pals.len()),
        ));
    }
    // Operators and their repetitions.
    let mut operators: BTreeMap<String, Vec<u32>> = BTreeMap::new();
    for p in pals {
        operators
            .entry(p.operator.clone())
            .or_default()
            .push(p.repetition);
    }
    for v in operators.values_mut() {
        v.sort_unstable();
    }
    // Study origin (the grand centroid) and the landmarks palpated.
    let origin = grand_centroid(pals);
    let ids: Vec<LandmarkId> = {
        let mut v: Vec<LandmarkId> = pals
            .iter()
            .flat_map(|p| p.set.points.keys().copied())
            .collect();
        v.sort();
        v.dedup();
        v
    };
    // Per-landmark IQRs with normality tests, and their summary (Table 5.5).
    let (landmarks, normality) = landmark_iqrs(pals, &ids, &origin);
    let summary = iqr_summary(&landmarks);
    // Inter- and intra-operator comparisons: ICC(2,1) and Friedman tests.
    let mut icc = Vec::new();
    let mut friedman = Vec::new();
    for c in &comparisons(pals, &operators) {
        icc.extend(icc_entries(c, &ids, &origin));
        friedman.extend(friedman_entries(c, &ids, &origin));
    }
    let rejected = normality.iter().filter(|n| n.p < 0.05).count();
    Ok(VariabilityReport {
        palpations: pals.len(),
        operators,
        units: "mm".into(),
        axes: "X anterior-posterior, Y inferior-superior, Z left-right (OpenSim frame); Euclidean = distance from the grand centroid".into(),
        landmarks,
        summary,
        icc,
        normality,
        normality_rejected_at_5pct: rejected,
        friedman,
        model_propagation: None,
        notes: Vec::new(),
        warnings: identical_sets(pals),
    })
}

/// Palpations whose landmark sets are identical (every landmark, every
/// coordinate to the bit): a repetition that agrees to the last digit was
/// copied, not palpated again. One warning per group, at most
/// [`MAX_LISTED`] groups listed.
fn identical_sets(pals: &[PalpationSet]) -> Vec<String> {
    type Key = Vec<(LandmarkId, [u64; 3])>;
    let mut groups: BTreeMap<Key, Vec<&PalpationSet>> = BTreeMap::new();
    for p in pals {
        let key = p
            .set
            .points
            .iter()
            .map(|(id, q)| (*id, [q.x, q.y, q.z].map(f64::to_bits)))
            .collect();
        groups.entry(key).or_default().push(p);
    }
    let name = |p: &PalpationSet| {
        format!(
            "{} (operator {}, repetition {})",
            p.source.display(),
            p.operator,
            p.repetition
        )
    };
    let mut same: Vec<String> = groups
        .values()
        .filter(|g| g.len() > 1)
        .map(|g| {
            format!(
                "identical landmark sets (every coordinate equal): {}; a repeated palpation that agrees to the last digit was copied, and counts here as perfect agreement",
                g.iter().map(|p| name(p)).collect::<Vec<_>>().join(", ")
            )
        })
        .collect();
    if same.len() > MAX_LISTED {
        let more = same.len() - MAX_LISTED;
        same.truncate(MAX_LISTED);
        same.push(format!(
            "... and {more} more groups of identical landmark sets"
        ));
    }
    same
}

/// Most groups of identical sets listed one by one.
const MAX_LISTED: usize = 10;

/// Centroid of every landmark of every palpation.
fn grand_centroid(pals: &[PalpationSet]) -> Vector3<f64> {
    let mut sum = Vector3::zeros();
    let mut cnt = 0usize;
    for p in pals {
        for q in p.set.points.values() {
            sum += q.coords;
            cnt += 1;
        }
    }
    sum / cnt.max(1) as f64
}

/// IQR per axis of each landmark palpated at least twice, and a
/// Shapiro-Wilk test per axis of those palpated at least three times.
fn landmark_iqrs(
    pals: &[PalpationSet],
    ids: &[LandmarkId],
    origin: &Vector3<f64>,
) -> (Vec<LandmarkIqr>, Vec<NormalityEntry>) {
    let mut landmarks = Vec::new();
    let mut normality = Vec::new();
    for id in ids {
        let pts: Vec<_> = pals.iter().filter_map(|p| p.set.points.get(id)).collect();
        if pts.len() < 2 {
            continue;
        }
        let mut iqr = [0.0; 4];
        for (a, slot) in iqr.iter_mut().enumerate() {
            let vals: Vec<f64> = pts.iter().map(|q| value(q, origin, a)).collect();
            *slot = stats::iqr(&vals).unwrap_or(f64::NAN);
            if vals.len() >= 3 {
                if let Ok(sw) = stats::shapiro_wilk(&vals) {
                    normality.push(NormalityEntry {
                        landmark: *id,
                        axis: AXES[a].into(),
                        n: vals.len(),
                        w: sw.w,
                        p: sw.p,
                    });
                }
            }
        }
        landmarks.push(LandmarkIqr {
            landmark: *id,
            n: pts.len(),
            iqr_mm: iqr,
        });
    }
    (landmarks, normality)
}

/// Median, IQR and maximum of the per-landmark IQRs for all, joint and
/// scaling markers, per axis.
fn iqr_summary(landmarks: &[LandmarkIqr]) -> Vec<IqrSummary> {
    let mut summary = Vec::new();
    for (group, filt) in [
        ("all", None),
        ("joint", Some(true)),
        ("scaling", Some(false)),
    ] {
        for (a, axis) in AXES.iter().enumerate() {
            let v: Vec<f64> = landmarks
                .iter()
                .filter(|l| filt.is_none_or(|j| l.landmark.code.is_joint_marker() == j))
                .map(|l| l.iqr_mm[a])
                .collect();
            if let (Some(m), Some(q)) = (stats::median(&v), stats::iqr(&v)) {
                summary.push(IqrSummary {
                    group: group.into(),
                    axis: axis.to_string(),
                    median_mm: m,
                    iqr_mm: q,
                    max_mm: v.iter().copied().fold(f64::NEG_INFINITY, f64::max),
                });
            }
        }
    }
    summary
}

/// The comparisons: inter-operator per repetition number (operators in
/// name order), intra-operator per operator (repetitions in order); each
/// with at least two palpations.
fn comparisons<'a>(
    pals: &'a [PalpationSet],
    operators: &BTreeMap<String, Vec<u32>>,
) -> Vec<Comparison<'a>> {
    let mut comparisons: Vec<Comparison> = Vec::new();
    let reps: Vec<u32> = {
        let mut v: Vec<u32> = pals.iter().map(|p| p.repetition).collect();
        v.sort_unstable();
        v.dedup();
        v
    };
    for r in reps {
        let mut g: Vec<(String, &PalpationSet)> = pals
            .iter()
            .filter(|p| p.repetition == r)
            .map(|p| (format!("operator {}", p.operator), p))
            .collect();
        g.sort_by(|a, b| a.0.cmp(&b.0));
        if g.len() >= 2 {
            comparisons.push(("inter".into(), format!("repetition {r}"), g));
        }
    }
    for op in operators.keys() {
        let mut g: Vec<(String, &PalpationSet)> = pals
            .iter()
            .filter(|p| &p.operator == op)
            .map(|p| (format!("repetition {}", p.repetition), p))
            .collect();
        g.sort_by_key(|a| a.1.repetition);
        if g.len() >= 2 {
            comparisons.push(("intra".into(), format!("operator {op}"), g));
        }
    }
    comparisons
}

/// ICC(2,1) per marker group (joint, scaling) and axis of one comparison,
/// over the landmarks every palpation of it has (at least two).
fn icc_entries(c: &Comparison, ids: &[LandmarkId], origin: &Vector3<f64>) -> Vec<IccEntry> {
    let (kind, within, g) = c;
    let mut icc = Vec::new();
    for (group, joint) in [("joint", true), ("scaling", false)] {
        let targets: Vec<LandmarkId> = ids
            .iter()
            .filter(|i| i.code.is_joint_marker() == joint)
            .filter(|i| g.iter().all(|(_, p)| p.set.points.contains_key(i)))
            .copied()
            .collect();
        if targets.len() < 2 {
            continue;
        }
        for (a, axis) in AXES.iter().enumerate() {
            let rows: Vec<Vec<f64>> = targets
                .iter()
                .map(|t| {
                    g.iter()
                        .map(|(_, p)| value(&p.set.points[t], origin, a))
                        .collect()
                })
                .collect();
            if let Ok(Icc { icc2_1, n, k, .. }) = stats::icc(&rows) {
                icc.push(IccEntry {
                    kind: kind.clone(),
                    within: within.clone(),
                    group: group.into(),
                    axis: axis.to_string(),
                    targets: n,
                    raters: k,
                    icc2_1,
                });
            }
        }
    }
    icc
}

/// Friedman / Skillings-Mack tests per marker code and axis of one
/// comparison, blocked by level (blocks with two or more values), with the
/// Nemenyi many-to-one post hoc test when p < 0.05.
fn friedman_entries(
    c: &Comparison,
    ids: &[LandmarkId],
    origin: &Vector3<f64>,
) -> Vec<FriedmanEntry> {
    let (kind, within, g) = c;
    let mut friedman = Vec::new();
    let levels: Vec<Level> = {
        let mut v: Vec<Level> = ids.iter().map(|i| i.level).collect();
        v.dedup();
        v
    };
    for code in Code::ALL {
        for (a, axis) in AXES.iter().enumerate() {
            let y: Vec<Vec<Option<f64>>> = levels
                .iter()
                .map(|l| {
                    g.iter()
                        .map(|(_, p)| p.set.get(*l, code).map(|q| value(&q, origin, a)))
                        .collect()
                })
                .filter(|row: &Vec<Option<f64>>| row.iter().filter(|v| v.is_some()).count() >= 2)
                .collect();
            let Ok(t) = stats::friedman_blocked(&y) else {
                continue;
            };
            if !t.p.is_finite() {
                continue;
            }
            let names: Vec<String> = g.iter().map(|(n, _)| n.clone()).collect();
            let posthoc = if t.p < 0.05 {
                stats::nemenyi_many_one(&y)
                    .map(|v| {
                        v.into_iter()
                            .map(|m| PostHoc {
                                versus: names.get(m.group).cloned().unwrap_or_default(),
                                reference: names[0].clone(),
                                z: m.z,
                                p: m.p,
                            })
                            .collect()
                    })
                    .unwrap_or_default()
            } else {
                Vec::new()
            };
            friedman.push(FriedmanEntry {
                kind: kind.clone(),
                within: within.clone(),
                marker: code,
                axis: axis.to_string(),
                method: t.method,
                statistic: t.statistic,
                df: t.df,
                p: t.p,
                blocks: t.blocks,
                groups: names,
                posthoc,
            });
        }
    }
    friedman
}

/// SVG box plot of the per-landmark IQRs in X, Y, Z and Euclidean
/// (thesis Figure 5.5), drawn by [`crate::util::charts::boxplot_svg`].
fn iqr_boxplot_svg(report: &VariabilityReport) -> String {
    let series: Vec<(String, Vec<f64>)> = (0..4)
        .map(|a| {
            (
                AXES[a].to_string(),
                report
                    .landmarks
                    .iter()
                    .map(|l| l.iqr_mm[a])
                    .filter(|v| v.is_finite())
                    .collect(),
            )
        })
        .collect();
    crate::util::charts::boxplot_svg(
        &format!(
            "IQR of repeated palpations per landmark ({} palpations)",
            report.palpations
        ),
        "IQR (mm)",
        &series,
    )
}

/// Everything `variability` computes, not yet written.
#[derive(Debug, Clone)]
pub struct Computed {
    /// The report.
    pub report: VariabilityReport,
    /// `(file name, SVG)`: `iqr_boxplot.svg`, and the model box plots
    /// ([`propagation::boxplots`]) with the propagation.
    pub figures: Vec<(String, String)>,
    /// Generated models `(label, model)` when kept.
    pub models: Vec<(String, crate::generate::Generated)>,
}

/// Load the palpations and compute the statistics, and with `models`
/// (base model, options) the model propagation.
pub fn compute(
    paths: &[PathBuf],
    models: Option<(&Document, &PropagationOptions)>,
) -> Result<Computed> {
    let pals = load_palpations(paths)?;
    let mut report = analyse(&pals)?;
    let mut kept = Vec::new();
    match models {
        Some((base, opts)) => {
            let p = propagation::propagate(&pals, base, opts)?;
            if p.report.failed > 0 {
                report.notes.push(format!(
                    "{} of {} palpations gave no model (see model_propagation.rows)",
                    p.report.failed, p.report.palpations
                ));
            }
            report.model_propagation = Some(p.report);
            kept = p.models;
        }
        None => report
            .notes
            .push("model_propagation (thesis Tables 5.6-5.8) not computed (--no-models)".into()),
    }
    let mut figures = vec![("iqr_boxplot.svg".to_string(), iqr_boxplot_svg(&report))];
    if let Some(p) = &report.model_propagation {
        figures.extend(propagation::boxplots(p));
    }
    Ok(Computed {
        report,
        figures,
        models: kept,
    })
}

/// The files of a computed report, relative to the output folder:
/// `variability.json` and the figures.
pub fn output_files(c: &Computed) -> Result<Vec<(PathBuf, Vec<u8>)>> {
    let json = serde_json::to_string_pretty(&c.report)
        .map_err(|e| Error::invalid("variability report", e.to_string()))?;
    let mut out = vec![(PathBuf::from("variability.json"), json.into_bytes())];
    for (name, svg) in &c.figures {
        out.push((PathBuf::from(name), svg.clone().into_bytes()));
    }
    Ok(out)
}

/// Compute everything, then write `variability.json` and the figures
/// into `out_dir` (atomically, nothing written on error).
pub fn run(
    paths: &[PathBuf],
    out_dir: &Path,
    models: Option<(&Document, &PropagationOptions)>,
) -> Result<Computed> {
    let c = compute(paths, models)?;
    let files: Vec<(PathBuf, Vec<u8>)> = output_files(&c)?
        .into_iter()
        .map(|(p, b)| (out_dir.join(p), b))
        .collect();
    write_all_or_nothing(&files)?;
    Ok(c)
}
