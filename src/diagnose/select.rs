//! The diagnosis procedure: baseline and candidate fits on the training
//! cases, the noise estimate, the selection statistics, the verdict, the
//! decomposition of the held-out gap and the held-out shrink.
//!
//! **Noise.** The residuals are in report units (deg, mm) weighted 1:1 for
//! the fits. The noise variance of each class (rotations, translations)
//! is estimated from the training residuals of the best-fitting family
//! (lowest training sum of squares), divided by its degrees of freedom
//! (`n_class - p n_class / n`); chi-squares below use these variances.
//!
//! **Criterion.** For each effect, the variant with the lowest training
//! BIC is kept. It *earns* its parameters when (a) the training
//! improvement over the baseline is significant, `P(chi2_dp > dchi2_train)
//! < alpha` with `alpha = 1e-4`, and (b) it predicts the held-out cases
//! better, `dchi2_heldout > 3.84`. Its score is `dchi2_heldout + dBIC_train`
//! (both twice a log-likelihood ratio over the baseline); `none` scores 0.
//! The confidence is calibrated on the held-out cases: for the winner
//! against each other effect (and `none`), the probability that its score
//! margin stays positive on new held-out data (standard error: the larger
//! of the noise-based one, inflated by the winner's held-out reduced
//! chi-square, and Vuong's pointwise one; see [`win_probability`]); the
//! confidence is the product of these. A margin
//! that is thin compared with how differently two effects predict the
//! unseen cases gives a value well below 1.
//!
//! **Unidentifiable.** (a) design: an effect the design cannot test
//! (single magnitude, single direction; not the absence of follower loads,
//! which only makes preload stiffening untestable and is reported in
//! `untestable`) and no effect earning its parameters, or the winner
//! closing less than [`DECISIVE_SHRINK`] of the held-out gap; (b) data: the
//! runner-up's score within [`INDISTINGUISHABLE`] of the winner's.

use super::design::{Design, AXIS_NAMES};
use super::family::{Effect, Family, Kind};
use super::fit::{dominant_level, fit, kinds, Fitted, Weights};
use super::noise;
use super::sim::Sim;
use crate::calibrate::experiment::{Experiment, DOF_NAMES};
use crate::error::Result;
use rayon::prelude::*;
use serde::Serialize;
use statrs::distribution::{ChiSquared, ContinuousCDF};
use std::collections::BTreeMap;

/// Training significance level.
pub const ALPHA: f64 = 1e-4;
/// Held-out chi-square improvement required (95% of chi2 with 1 dof).
pub const HELDOUT_MIN: f64 = 3.84;
/// Score margin under which the two best effects are indistinguishable.
pub const INDISTINGUISHABLE: f64 = 6.0;

/// Held-out shrink a candidate needs to be reported while some effect is
/// untestable by design.
pub const DECISIVE_SHRINK: f64 = 0.5;

/// Options.
#[derive(Debug, Clone)]
pub struct Options {
    /// LM iterations per fit.
    pub max_iterations: usize,
    /// Show progress on stderr.
    pub progress: bool,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            max_iterations: 40,
            progress: true,
        }
    }
}

/// The verdict of a diagnosis, serialised as the format's strings
/// (`none`, an effect name, `unidentifiable`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    /// Only parameter values are off.
    None,
    /// One effect of the vocabulary.
    Effect(Effect),
    /// The load cases cannot separate the candidates.
    Unidentifiable,
}

impl Verdict {
    /// The name in `diagnosis.json`.
    pub fn name(&self) -> &'static str {
        match self {
            Verdict::None => "none",
            Verdict::Effect(e) => e.name(),
            Verdict::Unidentifiable => "unidentifiable",
        }
    }
}

impl std::fmt::Display for Verdict {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl PartialEq<str> for Verdict {
    fn eq(&self, other: &str) -> bool {
        self.name() == other
    }
}

impl PartialEq<&str> for Verdict {
    fn eq(&self, other: &&str) -> bool {
        self.name() == *other
    }
}

impl PartialEq<String> for Verdict {
    fn eq(&self, other: &String) -> bool {
        self.name() == other
    }
}

impl Serialize for Verdict {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        s.serialize_str(self.name())
    }
}

/// Statistics of one fitted family.
#[derive(Debug, Clone, Serialize)]
pub struct CandidateStats {
    pub family: Kind,
    pub effect: Effect,
    pub n_params: usize,
    pub chi2_train: f64,
    pub chi2_heldout: f64,
    /// Rotation RMSE on the held-out cases (deg).
    pub heldout_rot_rmse: f64,
    /// Training chi-square improvement over the baseline.
    pub dchi2_train: f64,
    /// Its p-value (chi-square with the extra parameters as dof).
    pub p_train: f64,
    pub dbic_train: f64,
    pub dchi2_heldout: f64,
    pub score: f64,
    pub earns: bool,
    pub iterations: usize,
    pub params: BTreeMap<String, f64>,
}

/// A cell of the held-out gap.
#[derive(Debug, Clone, Serialize)]
pub struct GapCell {
    pub upper: String,
    pub lower: String,
    pub level: String,
    pub dof: String,
    pub case: String,
    /// Share of the held-out chi-square of the baseline.
    pub share: f64,
    /// Baseline residual (predicted - measured), deg or mm.
    pub residual: f64,
}

/// A row of an aggregate table.
#[derive(Debug, Clone, Serialize)]
pub struct Share {
    pub key: String,
    pub share: f64,
}

/// RMSE per level and DoF.
#[derive(Debug, Clone, Serialize)]
pub struct LevelDofRmse {
    pub level: String,
    pub dof: String,
    pub baseline_rmse: f64,
    pub augmented_rmse: f64,
    pub shrink: f64,
}

/// The outcome of a diagnosis (everything reports need).
#[derive(Debug, Clone)]
pub struct Outcome {
    pub sim: Sim,
    pub design: Design,
    /// Weights (`1/sigma`, report units) of every chi-square.
    pub noise: Weights,
    /// The noise of each measured class and where it comes from.
    pub noise_model: noise::Noise,
    pub baseline: Fitted,
    pub fits: Vec<Fitted>,
    pub stats: Vec<CandidateStats>,
    /// Best variant per effect (index into `fits`), ranked by score.
    pub ranked: Vec<usize>,
    /// `none`, an effect or `unidentifiable`.
    pub verdict: Verdict,
    pub confidence: f64,
    /// The family used for the held-out comparison and the improved model
    /// (None for `none`).
    pub chosen: Option<usize>,
    pub reasons: Vec<String>,
}

fn chi2_of(sim: &Sim, f: &Fitted, cells: &[usize], w: Weights) -> f64 {
    cells
        .iter()
        .map(|&c| (f.residual(sim, c) * w.cell(&sim.cells[c])).powi(2))
        .sum()
}

fn rmse(sim: &Sim, f: &Fitted, cells: &[usize]) -> f64 {
    if cells.is_empty() {
        return f64::NAN;
    }
    (cells
        .iter()
        .map(|&c| f.residual(sim, c).powi(2))
        .sum::<f64>()
        / cells.len() as f64)
        .sqrt()
}

/// Training and held-out cells (indices into `sim.cells`) of a design.
struct Split {
    train: Vec<usize>,
    heldout: Vec<usize>,
}

impl Split {
    fn of(sim: &Sim, design: &Design) -> Split {
        let in_train: Vec<bool> = (0..sim.loads.len())
            .map(|i| design.train.contains(&i))
            .collect();
        let (train, heldout) =
            (0..sim.cells.len()).partition(|&c| in_train.get(sim.cells[c].case) == Some(&true));
        Split { train, heldout }
    }
}

/// The progress bar (hidden without `opts.progress`).
fn progress_bar(opts: &Options, len: u64) -> indicatif::ProgressBar {
    if !opts.progress {
        return indicatif::ProgressBar::hidden();
    }
    let pb = indicatif::ProgressBar::new(len);
    pb.set_style(
        indicatif::ProgressStyle::with_template("diagnose {bar:30} {pos}/{len} fits {msg}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    pb.set_message("baseline");
    pb
}

/// What every fit of one diagnosis shares.
struct FitCtx<'a> {
    sim: &'a Sim,
    design: &'a Design,
    split: &'a Split,
    w: Weights,
    opts: &'a Options,
    pb: &'a indicatif::ProgressBar,
}

impl FitCtx<'_> {
    /// Fit families in parallel on the training cells.
    fn fit_all(&self, families: Vec<Family>) -> Result<Vec<Fitted>> {
        families
            .into_par_iter()
            .map(|f| {
                let r = fit(
                    self.sim,
                    f,
                    &self.split.train,
                    &self.design.train,
                    self.w,
                    self.opts.max_iterations,
                );
                self.pb.inc(1);
                r
            })
            .collect::<Vec<Result<Fitted>>>()
            .into_iter()
            .collect()
    }
}

/// Second stage, local pose: the pose family at the level that carries
/// most of the rotation-only pose fit, started from it.
fn local_pose_family(ctx: &FitCtx, rot: &Fitted, g: [f64; 3], offsets: bool) -> Result<Family> {
    let sim = ctx.sim;
    let lj = dominant_level(sim, rot, &ctx.split.train, &ctx.design.train, 3)?;
    let mut mask = vec![false; sim.levels.len()];
    mask[lj] = true;
    let mut loc = Family::masked(Kind::JointLocal, sim, g, mask, offsets);
    if let Some(x) = loc.x0.get_mut(..3) {
        x.copy_from_slice(&rot.x[..3]);
    }
    for k in 0..3 {
        if let (Some(v), Some(r)) = (loc.x0.get_mut(3 + k), rot.x.get(3 + 3 * lj + k)) {
            *v = *r;
        }
    }
    Ok(loc)
}

/// Second stage, pose with offsets, started from the rotation-only fit.
fn pose_offsets_family(sim: &Sim, rot: &Fitted, g: [f64; 3]) -> Family {
    let mut pose = Family::new(Kind::JointPose, sim, g);
    pose.x0[..3].copy_from_slice(&rot.x[..3]);
    for li in 0..sim.levels.len() {
        for k in 0..3 {
            pose.x0[3 + 6 * li + k] = rot.x[3 + 3 * li + k];
        }
    }
    pose
}

/// Second stage, per-level one-sided stiffening, started from the global
/// bilinear fit (a stiffer negative side, a < 0, lowers the global factor).
fn asym_per_level_family(sim: &Sim, ab: &Fitted, g: [f64; 3]) -> Family {
    let mut pl = Family::new(Kind::AsymmetricPerLevel, sim, g);
    for k in 0..3 {
        if let (Some(v), Some(r), Some(a)) = (pl.x0.get_mut(k), ab.x.get(k), ab.x.get(3 + k)) {
            *v = *r + a.min(0.0);
        }
    }
    for li in 0..sim.levels.len() {
        for k in 0..3 {
            if let (Some(v), Some(r)) = (pl.x0.get_mut(3 + 3 * li + k), ab.x.get(3 + k)) {
                *v = *r;
            }
        }
    }
    pl
}

/// Second stage, coupling at the level that carries most of the per-level
/// coupling fit, started from it.
fn local_coupling_family(ctx: &FitCtx, cp: &Fitted, g: [f64; 3]) -> Result<Family> {
    let sim = ctx.sim;
    let lc = dominant_level(sim, cp, &ctx.split.train, &ctx.design.train, 3)?;
    let mut mask = vec![false; sim.levels.len()];
    mask[lc] = true;
    let mut loc = Family::masked(Kind::CoupledLocal, sim, g, mask, false);
    for k in 0..6 {
        let src = if k < 3 { k } else { 3 + 3 * lc + (k - 3) };
        if let (Some(v), Some(r)) = (loc.x0.get_mut(k), cp.x.get(src)) {
            *v = *r;
        }
    }
    Ok(loc)
}

/// The second-stage families, each started from a first-stage fit.
fn stage2_families(
    ctx: &FitCtx,
    fits: &[Fitted],
    g: [f64; 3],
    offsets: bool,
) -> Result<Vec<Family>> {
    let find = |k: Kind| fits.iter().find(|f| f.family.kind == k);
    let mut out = Vec::new();
    if let Some(rot) = find(Kind::JointRotation) {
        out.push(local_pose_family(ctx, rot, g, offsets)?);
        if offsets {
            out.push(pose_offsets_family(ctx.sim, rot, g));
        }
    }
    if let Some(ab) = find(Kind::AsymmetricBilinear) {
        out.push(asym_per_level_family(ctx.sim, ab, g));
    }
    if let Some(cp) = find(Kind::CoupledPerLevel) {
        out.push(local_coupling_family(ctx, cp, g)?);
    }
    Ok(out)
}

/// Baseline and every candidate family fitted on the training cells.
fn fit_families(ctx: &FitCtx, offsets: bool) -> Result<(Fitted, Vec<Fitted>)> {
    let sim = ctx.sim;
    let baseline = ctx
        .fit_all(vec![Family::new(Kind::Baseline, sim, [0.0; 3])])?
        .remove(0);
    ctx.pb.set_message("candidates");
    let g = [baseline.x[0], baseline.x[1], baseline.x[2]];
    let first: Vec<Family> = kinds(ctx.design.has_follower)
        .into_iter()
        .map(|k| Family::new(k, sim, g))
        .collect();
    let mut fits = ctx.fit_all(first)?;
    ctx.pb.set_message("pose offsets, local variants");
    let more = ctx.fit_all(stage2_families(ctx, &fits, g, offsets)?)?;
    fits.extend(more);
    Ok((baseline, fits))
}

/// Selection statistics of every fit against the baseline (noise weights `w`).
fn candidate_stats(
    sim: &Sim,
    design: &Design,
    split: &Split,
    baseline: &Fitted,
    fits: &[Fitted],
    w: Weights,
) -> Vec<CandidateStats> {
    let n = split.train.len() as f64;
    let chi_b_tr = chi2_of(sim, baseline, &split.train, w);
    let chi_b_ho = chi2_of(sim, baseline, &split.heldout, w);
    let ho_rot: Vec<usize> = rotations(sim, &split.heldout);
    let p0 = baseline.x.len();
    fits.iter()
        .map(|f| {
            let chi_tr = chi2_of(sim, f, &split.train, w);
            let chi_ho = chi2_of(sim, f, &split.heldout, w);
            let dp = (f.x.len() - p0).max(1) as f64;
            let d_tr = chi_b_tr - chi_tr;
            let p_train = if d_tr > 0.0 {
                ChiSquared::new(dp).map(|c| c.sf(d_tr)).unwrap_or(1.0)
            } else {
                1.0
            };
            let dbic = d_tr - dp * n.ln();
            let d_ho = chi_b_ho - chi_ho;
            let untestable = design.is_untestable(f.family.kind.effect().name());
            CandidateStats {
                family: f.family.kind,
                effect: f.family.kind.effect(),
                n_params: f.x.len(),
                chi2_train: chi_tr,
                chi2_heldout: chi_ho,
                heldout_rot_rmse: rmse(sim, f, &ho_rot),
                dchi2_train: d_tr,
                p_train,
                dbic_train: dbic,
                dchi2_heldout: d_ho,
                score: d_ho + dbic,
                earns: !untestable && p_train < ALPHA && d_ho > HELDOUT_MIN,
                iterations: f.iterations,
                params: f.family.physical_params(sim, &f.x),
            }
        })
        .collect()
}

/// The rotational cells among `cells`.
fn rotations(sim: &Sim, cells: &[usize]) -> Vec<usize> {
    cells
        .iter()
        .copied()
        .filter(|&c| sim.cells[c].dof < 3)
        .collect()
}

/// The best variant of each effect (lowest training BIC), ranked by score.
fn rank_effects(stats: &[CandidateStats], n_train: usize) -> Vec<usize> {
    let ln_n = (n_train.max(1) as f64).ln();
    let bic = |s: &CandidateStats| s.chi2_train + s.n_params as f64 * ln_n;
    let mut per_effect: BTreeMap<Effect, usize> = BTreeMap::new();
    for (i, s) in stats.iter().enumerate() {
        let e = per_effect.entry(s.effect).or_insert(i);
        if bic(s) < bic(&stats[*e]) {
            *e = i;
        }
    }
    let mut ranked: Vec<usize> = per_effect.values().copied().collect();
    ranked.sort_by(|a, b| stats[*b].score.total_cmp(&stats[*a].score).then(a.cmp(b)));
    ranked
}

/// The verdict, the chosen fit, the confidence and the reasons.
struct Decision {
    verdict: Verdict,
    chosen: Option<usize>,
    confidence: f64,
    reasons: Vec<String>,
}

/// Held-out residuals (noise units) of the baseline and of every fit.
struct HeldoutResiduals {
    base: Vec<f64>,
    fits: Vec<Vec<f64>>,
}

impl HeldoutResiduals {
    fn of(sim: &Sim, split: &Split, baseline: &Fitted, fits: &[Fitted], w: Weights) -> Self {
        let res = |f: &Fitted| -> Vec<f64> {
            split
                .heldout
                .iter()
                .map(|&c| f.residual(sim, c) * w.cell(&sim.cells[c]))
                .collect()
        };
        HeldoutResiduals {
            base: res(baseline),
            fits: fits.iter().map(res).collect(),
        }
    }
}

/// Decide when some effect earns its parameters: the top one, unless the
/// runner-up is as good or an untestable effect could carry the gap.
/// `b_rot` is the baseline's held-out rotation RMSE.
fn decide_effect(
    split: &Split,
    b_rot: f64,
    stats: &[CandidateStats],
    ranked: &[usize],
    earning: &[usize],
    design_gaps: &[&(String, String)],
    hr: &HeldoutResiduals,
) -> Decision {
    let top = earning[0];
    let n_ho = split.heldout.len().max(1) as f64;
    let t = (stats[top].chi2_heldout / n_ho).max(1.0);
    let top_score = stats[top].score;
    let confidence = calibrated_confidence(stats, ranked, top, &hr.fits, &hr.base, t);
    let mut reasons = Vec::new();
    if let Some(&second) = earning.get(1) {
        if top_score - stats[second].score < INDISTINGUISHABLE * t {
            reasons.push(format!(
                "{} and {} explain the gap equally well (scores {:.1} and {:.1})",
                stats[top].effect.name(),
                stats[second].effect.name(),
                top_score,
                stats[second].score
            ));
        }
    }
    // an effect the design cannot test could carry the gap too: only a
    // candidate that closes most of the held-out gap excludes it
    let top_shrink = if b_rot > 0.0 {
        1.0 - stats[top].heldout_rot_rmse / b_rot
    } else {
        0.0
    };
    if top_shrink < DECISIVE_SHRINK {
        for (e, why) in design_gaps {
            reasons.push(format!(
                "{e} cannot be tested ({why}) and {} closes only {:.0}% of the held-out gap",
                stats[top].effect.name(),
                100.0 * top_shrink
            ));
        }
    }
    let verdict = if reasons.is_empty() {
        Verdict::Effect(stats[top].effect)
    } else {
        Verdict::Unidentifiable
    };
    Decision {
        verdict,
        chosen: Some(top),
        confidence,
        reasons,
    }
}

/// Decide when no effect earns its parameters: `none`, or
/// `unidentifiable` when the design leaves an effect untestable.
fn decide_none(
    split: &Split,
    stats: &[CandidateStats],
    ranked: &[usize],
    design_gaps: &[&(String, String)],
    hr: &HeldoutResiduals,
    chi_b_ho: f64,
) -> Decision {
    if design_gaps.is_empty() {
        let t = (chi_b_ho / split.heldout.len().max(1) as f64).max(1.0);
        return Decision {
            verdict: Verdict::None,
            chosen: None,
            confidence: none_confidence(stats, ranked, &hr.fits, &hr.base, t),
            reasons: Vec::new(),
        };
    }
    Decision {
        verdict: Verdict::Unidentifiable,
        chosen: ranked.first().copied(),
        confidence: 0.0,
        reasons: design_gaps
            .iter()
            .map(|(e, why)| format!("{e} cannot be tested: {why}"))
            .collect(),
    }
}

/// Run the diagnosis on an experiment.
pub fn diagnose(exp: &Experiment, opts: &Options) -> Result<Outcome> {
    let mut sim = Sim::new(exp)?;
    let design = Design::new(&exp.cases);
    let split = Split::of(&sim, &design);
    // noise stated, assumed for means, or from replicates (known before
    // any fit), and the fit weights
    let assumed = noise::assume_spread_of_means(&mut sim, exp.measurement.n_specimens);
    let prior = noise::prior(&sim, &exp.cases, assumed);
    let fw = noise::fit_weights(&prior);
    let offsets = sim.cells.iter().any(|c| c.dof >= 3) || design.has_follower;
    let n_kinds = kinds(design.has_follower).len() as u64;
    let pb = progress_bar(opts, n_kinds + 4 + offsets as u64);
    let ctx = FitCtx {
        sim: &sim,
        design: &design,
        split: &split,
        w: fw,
        opts,
        pb: &pb,
    };
    // baseline and candidates on the training cases
    let (baseline, fits) = fit_families(&ctx, offsets)?;
    pb.finish_and_clear();
    // the noise left to estimate: residuals of the best fit, or the floor
    let every: Vec<&Fitted> = fits.iter().chain(std::iter::once(&baseline)).collect();
    let noise_model = noise::complete(prior, &sim, &every, &split.train, fw);
    let w = noise_model.weights();
    // statistics, ranking and verdict
    let stats = candidate_stats(&sim, &design, &split, &baseline, &fits, w);
    let ranked = rank_effects(&stats, split.train.len());
    let earning: Vec<usize> = ranked.iter().copied().filter(|&i| stats[i].earns).collect();
    let design_gaps: Vec<&(String, String)> = design
        .untestable
        .iter()
        .filter(|(e, _)| e != "preload_stiffening")
        .collect();
    let hr = HeldoutResiduals::of(&sim, &split, &baseline, &fits, w);
    let d = if earning.is_empty() {
        let chi_b_ho = chi2_of(&sim, &baseline, &split.heldout, w);
        decide_none(&split, &stats, &ranked, &design_gaps, &hr, chi_b_ho)
    } else {
        let b_rot = rmse(&sim, &baseline, &rotations(&sim, &split.heldout));
        decide_effect(&split, b_rot, &stats, &ranked, &earning, &design_gaps, &hr)
    };
    Ok(Outcome {
        sim,
        design,
        noise: w,
        noise_model,
        baseline,
        fits,
        stats,
        ranked,
        verdict: d.verdict,
        confidence: d.confidence,
        chosen: d.chosen,
        reasons: d.reasons,
    })
}

/// Probability that the criterion difference `delta` (twice a log-likelihood
/// ratio, favouring the first of two models) would stay positive on new
/// held-out data, from the two models' held-out residuals `ra` and `rb`
/// (noise units). Two standard errors of the held-out chi-square
/// difference are computed and the larger one is used:
/// - noise: with `dp = ra - rb` the prediction differences, the variance
///   of the difference under the noise is `4 t sum(dp^2)`, `t >= 1` being
///   the held-out reduced chi-square of the first model (misfit on unseen
///   cases inflates the noise);
/// - pointwise (Vuong's test for non-nested models, as in cross-validated
///   model comparison): `sqrt(n) sd(rb^2 - ra^2)` over the `n` held-out
///   cells, which also counts the case-to-case variability of which model
///   fits better.
///
/// The probability is `Phi(delta / se)`.
pub fn win_probability(delta: f64, ra: &[f64], rb: &[f64], t: f64) -> f64 {
    use statrs::distribution::Normal;
    let n = ra.len().min(rb.len());
    let ss: f64 = ra.iter().zip(rb).map(|(a, b)| (a - b).powi(2)).sum();
    let se_noise = 2.0 * (t.max(1.0) * ss).sqrt();
    let se_point = if n >= 2 {
        let d: Vec<f64> = ra.iter().zip(rb).map(|(a, b)| b * b - a * a).collect();
        let m = d.iter().sum::<f64>() / n as f64;
        let var = d.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n as f64 - 1.0);
        (n as f64 * var).sqrt()
    } else {
        0.0
    };
    let se = se_noise.max(se_point);
    if se.is_nan() || se <= 1e-12 {
        return if delta > 0.0 {
            1.0
        } else if delta < 0.0 {
            0.0
        } else {
            0.5
        };
    }
    Normal::new(0.0, 1.0)
        .map(|n| n.cdf(delta / se))
        .unwrap_or(0.5)
}

/// The confidence of the winner `top`: the probability that it beats each
/// other effect's best variant and `none` on unseen cases, the comparisons
/// taken as independent (the product of [`win_probability`]). A margin
/// thin compared with how differently two effects predict the held-out
/// cases gives a value well below 1.
fn calibrated_confidence(
    stats: &[CandidateStats],
    ranked: &[usize],
    top: usize,
    pred_fit: &[Vec<f64>],
    pred_base: &[f64],
    t: f64,
) -> f64 {
    let empty = Vec::new();
    let pt = pred_fit.get(top).unwrap_or(&empty);
    let mut p = win_probability(stats[top].score, pt, pred_base, t);
    for &i in ranked.iter().filter(|&&i| i != top) {
        let pi = pred_fit.get(i).unwrap_or(&empty);
        p *= win_probability(stats[top].score - stats[i].score, pt, pi, t);
    }
    p
}

/// The confidence of `none`: the probability that no candidate beats the
/// baseline on unseen cases (product of [`win_probability`]), `t` being
/// the baseline's held-out reduced chi-square.
fn none_confidence(
    stats: &[CandidateStats],
    ranked: &[usize],
    pred_fit: &[Vec<f64>],
    pred_base: &[f64],
    t: f64,
) -> f64 {
    let empty = Vec::new();
    ranked
        .iter()
        .map(|&i| {
            let pi = pred_fit.get(i).unwrap_or(&empty);
            win_probability(-stats[i].score, pred_base, pi, t)
        })
        .product()
}

impl Outcome {
    /// Indices of held-out cells.
    pub fn heldout_cells(&self) -> Vec<usize> {
        let held: Vec<bool> = (0..self.sim.loads.len())
            .map(|i| self.design.heldout.contains(&i))
            .collect();
        (0..self.sim.cells.len())
            .filter(|&c| held[self.sim.cells[c].case])
            .collect()
    }

    /// The augmented fit (the baseline when nothing is chosen).
    pub fn augmented(&self) -> &Fitted {
        self.chosen
            .and_then(|i| self.fits.get(i))
            .unwrap_or(&self.baseline)
    }

    /// Held-out rotation RMSE (deg) of the baseline and the augmented model.
    pub fn heldout_rmse(&self) -> (f64, f64) {
        let rot: Vec<usize> = self
            .heldout_cells()
            .into_iter()
            .filter(|&c| self.sim.cells[c].dof < 3)
            .collect();
        (
            rmse(&self.sim, &self.baseline, &rot),
            rmse(&self.sim, self.augmented(), &rot),
        )
    }

    /// Held-out translation RMSE (mm), when measured.
    pub fn heldout_trans_rmse(&self) -> Option<(f64, f64)> {
        let tr: Vec<usize> = self
            .heldout_cells()
            .into_iter()
            .filter(|&c| self.sim.cells[c].dof >= 3)
            .collect();
        if tr.is_empty() {
            return None;
        }
        Some((
            rmse(&self.sim, &self.baseline, &tr),
            rmse(&self.sim, self.augmented(), &tr),
        ))
    }

    /// Cells of the baseline's held-out gap, by share of its chi-square.
    pub fn gap_cells(&self, exp: &Experiment) -> Vec<GapCell> {
        let cells = self.heldout_cells();
        let w = self.noise;
        let total: f64 = cells
            .iter()
            .map(|&c| (self.baseline.residual(&self.sim, c) * w.cell(&self.sim.cells[c])).powi(2))
            .sum();
        let mut out: Vec<GapCell> = cells
            .iter()
            .map(|&c| {
                let cell = &self.sim.cells[c];
                let r = self.baseline.residual(&self.sim, c);
                let l = &self.sim.levels[cell.level];
                GapCell {
                    upper: l.upper_name.clone(),
                    lower: l.lower_name.clone(),
                    level: l.name.clone(),
                    dof: DOF_NAMES[cell.dof].to_string(),
                    case: exp
                        .cases
                        .get(cell.case)
                        .map(|c| c.id.clone())
                        .unwrap_or_default(),
                    share: if total > 0.0 {
                        (r * w.cell(cell)).powi(2) / total
                    } else {
                        0.0
                    },
                    residual: r,
                }
            })
            .collect();
        out.sort_by(|a, b| b.share.total_cmp(&a.share).then(a.case.cmp(&b.case)));
        out
    }

    /// Aggregates of the baseline's held-out gap: by level, DoF, load axis,
    /// magnitude, and by sign parity (the odd part `(r+ - r-)/2` and even
    /// part `(r+ + r-)/2` of the residuals over +/- pairs of cases).
    pub fn gap_tables(&self) -> BTreeMap<String, Vec<Share>> {
        let cells = self.heldout_cells();
        let w = self.noise;
        let sq =
            |c: usize| (self.baseline.residual(&self.sim, c) * w.cell(&self.sim.cells[c])).powi(2);
        let total: f64 = cells.iter().map(|&c| sq(c)).sum::<f64>().max(1e-300);
        let mut tables = BTreeMap::new();
        let mut agg = |name: &str, key: &dyn Fn(usize) -> String| {
            let mut m: BTreeMap<String, f64> = BTreeMap::new();
            for &c in &cells {
                *m.entry(key(c)).or_insert(0.0) += sq(c) / total;
            }
            let mut v: Vec<Share> = m
                .into_iter()
                .map(|(key, share)| Share { key, share })
                .collect();
            v.sort_by(|a, b| b.share.total_cmp(&a.share).then(a.key.cmp(&b.key)));
            tables.insert(name.to_string(), v);
        };
        let sim = &self.sim;
        let info = &self.design.cases;
        agg("by_level", &|c| sim.levels[sim.cells[c].level].name.clone());
        agg("by_dof", &|c| DOF_NAMES[sim.cells[c].dof].to_string());
        agg("by_load_axis", &|c| {
            info[sim.cells[c].case]
                .axis
                .map(|a| AXIS_NAMES[a].to_string())
                .unwrap_or_else(|| "none".into())
        });
        agg("by_magnitude", &|c| {
            let i = &info[sim.cells[c].case];
            format!("{} N m, follower {} N", i.magnitude, i.follower)
        });
        // parity: pair each held-out case with its mirror (same axis, magnitude, follower, other sign)
        let mut odd = 0.0;
        let mut even = 0.0;
        let mut unpaired = 0.0;
        for &c in &cells {
            let cell = &sim.cells[c];
            let ic = &info[cell.case];
            let Some(_) = ic.axis else {
                unpaired += sq(c) / total;
                continue;
            };
            let mirror = cells.iter().copied().find(|&o| {
                let oc = &sim.cells[o];
                let io = &info[oc.case];
                oc.level == cell.level
                    && oc.dof == cell.dof
                    && io.axis == ic.axis
                    && io.sign == -ic.sign
                    && (io.magnitude - ic.magnitude).abs() < 1e-9
                    && (io.follower - ic.follower).abs() < 1e-9
            });
            match mirror {
                Some(o) if ic.sign > 0 => {
                    let wd = w.cell(cell);
                    let rp = self.baseline.residual(sim, c) * wd;
                    let rm = self.baseline.residual(sim, o) * wd;
                    // r+^2 + r-^2 = 2 odd^2 + 2 even^2
                    odd += 2.0 * ((rp - rm) / 2.0).powi(2) / total;
                    even += 2.0 * ((rp + rm) / 2.0).powi(2) / total;
                }
                Some(_) => {}
                None => unpaired += sq(c) / total,
            }
        }
        tables.insert(
            "by_sign_parity".to_string(),
            vec![
                Share {
                    key: "odd".into(),
                    share: odd,
                },
                Share {
                    key: "even".into(),
                    share: even,
                },
                Share {
                    key: "unpaired".into(),
                    share: unpaired,
                },
            ],
        );
        tables
    }

    /// RMSE per level and DoF on the held-out cases.
    pub fn per_level_dof(&self) -> Vec<LevelDofRmse> {
        let cells = self.heldout_cells();
        let aug = self.augmented();
        let mut out = Vec::new();
        for (li, l) in self.sim.levels.iter().enumerate() {
            for d in 0..6 {
                let cs: Vec<usize> = cells
                    .iter()
                    .copied()
                    .filter(|&c| self.sim.cells[c].level == li && self.sim.cells[c].dof == d)
                    .collect();
                if cs.is_empty() {
                    continue;
                }
                let b = rmse(&self.sim, &self.baseline, &cs);
                let a = rmse(&self.sim, aug, &cs);
                out.push(LevelDofRmse {
                    level: l.name.clone(),
                    dof: DOF_NAMES[d].to_string(),
                    baseline_rmse: b,
                    augmented_rmse: a,
                    shrink: if b > 0.0 { 1.0 - a / b } else { 0.0 },
                });
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::win_probability;

    #[test]
    fn win_probability_is_the_normal_cdf_of_the_margin_over_its_noise_se() {
        // model a fits every cell, b is off by one noise unit everywhere:
        // the chi-square difference n has noise SD 2 sqrt(n) (t = 1), and
        // the pointwise spread is zero, so P = Phi(delta / (2 sqrt(n)))
        let n = 16;
        let a = vec![0.0; n];
        let b = vec![1.0; n];
        let se = 2.0 * (n as f64).sqrt();
        // Phi(1) = 0.841345, Phi(0) = 0.5, Phi(-2) = 0.022750
        assert!((win_probability(se, &a, &b, 1.0) - 0.841345).abs() < 1e-5);
        assert!((win_probability(0.0, &a, &b, 1.0) - 0.5).abs() < 1e-12);
        assert!((win_probability(-2.0 * se, &a, &b, 1.0) - 0.022750).abs() < 1e-5);
        // misfit t = 4 doubles the SE
        assert!((win_probability(2.0 * se, &a, &b, 4.0) - 0.841345).abs() < 1e-5);
        // identical predictions: the sign of the margin decides
        assert_eq!(win_probability(3.0, &a, &a, 1.0), 1.0);
        assert_eq!(win_probability(-3.0, &a, &a, 1.0), 0.0);
    }

    #[test]
    fn a_thin_margin_between_different_predictions_is_not_confident() {
        // 90 cells; the two models disagree by 0.5 noise units per cell and
        // their held-out chi-squares differ by 26 (dev-24's margin)
        let a: Vec<f64> = (0..90)
            .map(|i| if i % 2 == 0 { 0.3 } else { -0.3 })
            .collect();
        let b: Vec<f64> = a.iter().map(|x| x + 0.5).collect();
        let p = win_probability(26.0, &a, &b, 1.0);
        // se = 2 sqrt(90 * 0.25) = 9.49: z = 2.74
        assert!(p > 0.99 && p < 0.999, "{p}");
        // the same margin with five times the disagreement: z = 0.55
        let c: Vec<f64> = a.iter().map(|x| x + 2.5).collect();
        let q = win_probability(26.0, &a, &c, 1.0);
        assert!(q < 0.75, "{q}");
        // heterogeneous per-cell differences widen the SE (Vuong)
        let d: Vec<f64> = (0..90).map(|i| if i < 3 { 6.0 } else { 0.0 }).collect();
        let z = vec![0.0; 90];
        let p_het = win_probability(26.0, &z, &d, 1.0);
        let se_point = {
            let v: Vec<f64> = d.iter().map(|x| x * x).collect();
            let m = v.iter().sum::<f64>() / 90.0;
            (90.0 * v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / 89.0).sqrt()
        };
        assert!(se_point > 2.0 * (108.0f64).sqrt());
        let want = statrs::distribution::ContinuousCDF::cdf(
            &statrs::distribution::Normal::new(0.0, 1.0).unwrap(),
            26.0 / se_point,
        );
        assert!((p_het - want).abs() < 1e-12);
    }
}
