//! The measurement noise every likelihood of the diagnosis uses, per class
//! of cells (rotations, translations), and where it comes from:
//!
//! 1. **stated**: the file gives it (`sd_*` cells, `[measurement]`
//!    `rotation_sd` / `translation_sd`); cells with their own `sd_*` are
//!    weighted by it, the others by the class value (the `[measurement]`
//!    value, else the median of the stated cells of the class);
//! 2. **replicates**: cases with identical loads give the pooled
//!    within-group SD of the measured cells;
//! 3. **residuals**: the best-fitting family's training residuals, when
//!    they keep at least [`MIN_RESIDUAL_DOF`] degrees of freedom and half
//!    the class's cells (a family that can nearly interpolate the training
//!    cells would report a noise near 0);
//! 4. **assumed spread of means**: cells that are means over several
//!    specimens (`n_specimens > 1`, or a `source` that says they are
//!    means) without a stated SD (a table of means cannot give its own
//!    noise) get the between-specimen SD [`SPECIMEN_CV`] of their value
//!    (a literature value, [`SPECIMEN_CV_SOURCE`]) over `sqrt(n)`; the rig
//!    floor is never used for a mean of specimens;
//! 5. **floor**: otherwise the rig repeatability floor [`FLOOR_DEG`] /
//!    [`FLOOR_MM`], named as an assumption in every report.
//!
//! A class that was not measured has no noise (and is never reported). No
//! estimate is below [`RESOLUTION`] (the 4-decimal precision the format's
//! files carry is far finer; an estimate of 0 would make every
//! chi-square infinite).

use super::fit::{Fitted, Weights};
use super::sim::Sim;
use crate::calibrate::experiment::LoadCase;
use serde::Serialize;

/// Rotation floor (deg) when the noise can neither be read nor estimated:
/// the order of the motion-measurement repeatability of in-vitro spine
/// rigs with optoelectronic or ultrasonic tracking (Wilke, Wenger, Claes
/// 1998, Eur Spine J 7:148, recommendations for in-vitro spine testing).
pub const FLOOR_DEG: f64 = 0.1;
/// Translation floor (mm), same source.
pub const FLOOR_MM: f64 = 0.1;
/// Smallest noise an estimate may give (deg or mm).
pub const RESOLUTION: f64 = 0.005;
/// Between-specimen coefficient of variation (SD / mean) of segmental
/// ranges of motion assumed for means without a stated SD: 0.40, the mean
/// SD/mean of an intact lumbar segment of ten cadaveric specimens under
/// pure moments of 7.5 N*m (flexion 3.7 +- 1.5, extension 3.3 +- 1.5,
/// lateral bending 7.6 +- 2.8, axial rotation 4.2 +- 1.8 deg: 0.41, 0.45,
/// 0.37, 0.43) in [`SPECIMEN_CV_SOURCE`].
pub const SPECIMEN_CV: f64 = 0.40;
/// Where [`SPECIMEN_CV`] comes from.
pub const SPECIMEN_CV_SOURCE: &str =
    "Niosi et al. 2006, Eur Spine J 15:913-922, intact L3-L4 of ten L2-L5 specimens, +-7.5 N*m";
/// Residual degrees of freedom an estimate from residuals needs.
pub const MIN_RESIDUAL_DOF: f64 = 10.0;

/// Where a class's noise comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum NoiseSource {
    /// `[measurement]` or `sd_*` values of the file.
    Stated,
    /// Pooled SD of replicated load cases.
    Replicates,
    /// Training residuals of the best-fitting family.
    Residuals,
    /// The rig repeatability floor (an assumption).
    Floor,
    /// Means over several specimens without a stated SD: an assumed
    /// between-specimen spread per cell (an assumption).
    AssumedSpread,
}

impl NoiseSource {
    /// Words for reports.
    pub fn describe(&self) -> String {
        match self {
            NoiseSource::Stated => "stated in the experiment (sd_* cells / [measurement])".into(),
            NoiseSource::Replicates => "pooled SD of replicated load cases".into(),
            NoiseSource::Residuals => "training residuals of the best-fitting family".into(),
            NoiseSource::Floor => {
                "ASSUMED: rig repeatability floor (Wilke et al. 1998); the design has no replicates and too few residual degrees of freedom to estimate it".into()
            }
            NoiseSource::AssumedSpread => format!(
                "ASSUMED: means over several specimens without a stated SD (a table of means cannot give its own noise): between-specimen SD taken as {:.0}% of each cell's value ({SPECIMEN_CV_SOURCE}), at least the rig floor, divided by sqrt(n_specimens)",
                100.0 * SPECIMEN_CV
            ),
        }
    }
}

/// The noise of one class of cells.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ClassNoise {
    /// SD (deg or mm) of the cells without their own `sd_*`.
    pub sigma: f64,
    /// Where `sigma` comes from.
    pub source: NoiseSource,
    /// Degrees of freedom of the estimate (0 when stated or assumed).
    pub dof: f64,
}

/// The noise of both classes (`None`: the class was not measured).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Noise {
    /// Rotation cells (deg).
    pub rotation: Option<ClassNoise>,
    /// Translation cells (mm).
    pub translation: Option<ClassNoise>,
}

impl Noise {
    /// Weights (`1/sigma`) for chi-squares; an unmeasured class weighs 1
    /// (it has no cell).
    pub fn weights(&self) -> Weights {
        let w = |c: Option<ClassNoise>| c.map(|c| 1.0 / c.sigma).unwrap_or(1.0);
        Weights {
            rot: w(self.rotation),
            trans: w(self.translation),
        }
    }
}

/// Cells of a class (`rot`: rotations).
fn class_cells(sim: &Sim, rot: bool) -> impl Iterator<Item = &super::sim::Cell> {
    sim.cells.iter().filter(move |c| (c.dof < 3) == rot)
}

/// Stated class SD (for the cells without their own): the median of the
/// cells' stated SDs (the `[measurement]` value when it is stated for
/// all); `None` when no cell of the class has one.
fn stated(sim: &Sim, rot: bool) -> Option<f64> {
    let sds: Vec<f64> = class_cells(sim, rot).filter_map(|c| c.sd).collect();
    crate::landmarks::stats::median(&sds)
}

/// Two cases with the same loads (replicates).
fn same_load(a: &LoadCase, b: &LoadCase) -> bool {
    a.body == b.body
        && a.moment == b.moment
        && a.moment_frame == b.moment_frame
        && a.force == b.force
        && a.force_point == b.force_point
        && a.force_frame == b.force_frame
        && a.follower_load == b.follower_load
}

/// Pooled within-replicate SD of a class and its degrees of freedom
/// (`None` without replicates).
fn replicates(sim: &Sim, cases: &[LoadCase], rot: bool) -> Option<(f64, f64)> {
    // group id of each case: the first case with the same loads
    let group: Vec<usize> = (0..cases.len())
        .map(|i| {
            (0..=i)
                .find(|&j| same_load(&cases[j], &cases[i]))
                .unwrap_or(i)
        })
        .collect();
    let mut sums: std::collections::BTreeMap<(usize, usize, usize), Vec<f64>> = Default::default();
    for c in class_cells(sim, rot) {
        let g = group.get(c.case).copied().unwrap_or(c.case);
        sums.entry((g, c.level, c.dof))
            .or_default()
            .push(c.measured);
    }
    let (mut ss, mut dof) = (0.0, 0.0);
    for v in sums.values().filter(|v| v.len() >= 2) {
        let m = v.iter().sum::<f64>() / v.len() as f64;
        ss += v.iter().map(|x| (x - m).powi(2)).sum::<f64>();
        dof += (v.len() - 1) as f64;
    }
    (dof >= 1.0).then(|| ((ss / dof).sqrt().max(RESOLUTION), dof))
}

/// The noise known before any fit: stated, or from replicates; `None`
/// for a measured class that needs an estimate from the residuals.
pub fn prior(sim: &Sim, cases: &[LoadCase], assumed: [bool; 2]) -> [Option<Option<ClassNoise>>; 2] {
    [(true, assumed[0]), (false, assumed[1])].map(|(rot, assumed)| {
        if class_cells(sim, rot).next().is_none() {
            return Some(None);
        }
        if let Some(s) = stated(sim, rot) {
            let source = if assumed {
                NoiseSource::AssumedSpread
            } else {
                NoiseSource::Stated
            };
            return Some(Some(ClassNoise {
                sigma: s.max(1e-12),
                source,
                dof: 0.0,
            }));
        }
        replicates(sim, cases, rot).map(|(sigma, dof)| {
            Some(ClassNoise {
                sigma,
                source: NoiseSource::Replicates,
                dof,
            })
        })
    })
}

/// How many specimens the cells are means over, when they are means:
/// `n_specimens > 1`, or a `source` that calls them means ("mean of ...",
/// "published means") without `n_specimens` (then 1: the SD of one
/// specimen, the conservative choice).
pub fn means_over(m: &crate::calibrate::experiment::MeasurementInfo) -> Option<u32> {
    let said = m.source.as_deref().is_some_and(|s| {
        let s = s.to_ascii_lowercase();
        s.contains("mean") || s.contains("published") || s.contains("average")
    });
    match m.n_specimens {
        Some(n) if n > 1 => Some(n),
        Some(_) => None,
        None => said.then_some(1),
    }
}

/// Cells that are means over `n` specimens ([`means_over`]) with no
/// stated SD get the assumed between-specimen spread [`SPECIMEN_CV`] of
/// their value (at least the floor), over `sqrt(n)`; returns the classes
/// so treated.
pub fn assume_spread_of_means(sim: &mut Sim, n_specimens: Option<u32>) -> [bool; 2] {
    let n = match n_specimens {
        Some(n) if n >= 1 => n as f64,
        _ => return [false; 2],
    };
    [true, false].map(|rot| {
        let open = class_cells(sim, rot).next().is_some() && stated(sim, rot).is_none();
        if open {
            let floor = if rot { FLOOR_DEG } else { FLOOR_MM };
            for c in sim
                .cells
                .iter_mut()
                .filter(|c| (c.dof < 3) == rot && c.sd.is_none())
            {
                c.sd = Some((SPECIMEN_CV * c.measured.abs()).max(floor) / n.sqrt());
            }
        }
        open
    })
}

/// Weights for the fits: the prior noise where known, 1 (report units)
/// where it will be estimated.
pub fn fit_weights(prior: &[Option<Option<ClassNoise>>; 2]) -> Weights {
    let w = |p: &Option<Option<ClassNoise>>| match p {
        Some(Some(c)) => 1.0 / c.sigma,
        _ => 1.0,
    };
    Weights {
        rot: w(&prior[0]),
        trans: w(&prior[1]),
    }
}

/// The noise of both classes: the prior where known, else the estimate
/// from the training residuals of the best-fitting of `fits` (lowest
/// weighted training sum of squares) when it has enough residual degrees
/// of freedom, else the floor.
pub fn complete(
    prior: [Option<Option<ClassNoise>>; 2],
    sim: &Sim,
    fits: &[&Fitted],
    train_cells: &[usize],
    w: Weights,
) -> Noise {
    let sse = |f: &Fitted| -> f64 {
        train_cells
            .iter()
            .map(|&c| (f.residual(sim, c) * w.cell(&sim.cells[c])).powi(2))
            .sum()
    };
    let best = fits.iter().min_by(|a, b| sse(a).total_cmp(&sse(b)));
    let n = train_cells.len().max(1) as f64;
    let [r, t] = [(true, prior[0]), (false, prior[1])].map(|(rot, p)| match p {
        Some(known) => known,
        None => Some(estimate(sim, best.copied(), train_cells, n, rot)),
    });
    Noise {
        rotation: r,
        translation: t,
    }
}

/// Residual estimate of one class, or the floor when the residual
/// degrees of freedom are too few.
fn estimate(
    sim: &Sim,
    best: Option<&Fitted>,
    train_cells: &[usize],
    n: f64,
    rot: bool,
) -> ClassNoise {
    let floor = ClassNoise {
        sigma: if rot { FLOOR_DEG } else { FLOOR_MM },
        source: NoiseSource::Floor,
        dof: 0.0,
    };
    let Some(f) = best else { return floor };
    let r: Vec<f64> = train_cells
        .iter()
        .filter(|&&c| (sim.cells[c].dof < 3) == rot)
        .map(|&c| f.residual(sim, c))
        .collect();
    let nc = r.len() as f64;
    let dof = nc - f.x.len() as f64 * nc / n;
    if dof < MIN_RESIDUAL_DOF || dof < 0.5 * nc {
        return floor;
    }
    let sse: f64 = r.iter().map(|x| x * x).sum();
    ClassNoise {
        sigma: (sse / dof).sqrt().max(RESOLUTION),
        source: NoiseSource::Residuals,
        dof,
    }
}

/// `Some(why)` when the measured cells are consistent with no motion at
/// all: their chi-square against zero, each cell weighed by its stated SD
/// (else the rig floor of its class: the smallest motion a rig resolves),
/// is not significant at `alpha`. Then every candidate, the baseline too,
/// fits the data within the noise and any verdict would be read from
/// noise (an all-zero table, a specimen that never moved).
pub fn no_motion(sim: &Sim, alpha: f64) -> Option<String> {
    use statrs::distribution::{ChiSquared, ContinuousCDF};
    let sd = |c: &super::sim::Cell| {
        c.sd.filter(|s| *s > 0.0)
            .unwrap_or(if c.dof < 3 { FLOOR_DEG } else { FLOOR_MM })
    };
    let n = sim.cells.len();
    let chi2: f64 = sim.cells.iter().map(|c| (c.measured / sd(c)).powi(2)).sum();
    let p = ChiSquared::new(n.max(1) as f64)
        .map(|d| d.sf(chi2))
        .unwrap_or(0.0);
    if p < alpha {
        return None;
    }
    let largest = |rot: bool| {
        class_cells(sim, rot)
            .map(|c| c.measured.abs())
            .fold(None, |m: Option<f64>, v| Some(m.map_or(v, |m| m.max(v))))
    };
    let mut parts = Vec::new();
    if let Some(r) = largest(true) {
        parts.push(format!(
            "largest rotation {r:.4} deg (noise {FLOOR_DEG} deg or the stated SD)"
        ));
    }
    if let Some(t) = largest(false) {
        parts.push(format!(
            "largest translation {t:.4} mm (noise {FLOOR_MM} mm or the stated SD)"
        ));
    }
    Some(format!(
        "no motion above the noise: the {n} measured values are consistent with nothing having moved ({}; chi-square {chi2:.2} on {n} degrees of freedom, p = {p:.2}); there is no gap to diagnose: check that kinematics.csv holds the motions the loads caused",
        parts.join(", ")
    ))
}
