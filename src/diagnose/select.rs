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

pub use super::criteria::*;
use super::design::Design;
use super::family::{Effect, Family, Kind};
use super::fit::{kinds, Fitted, Weights};
use super::gap::{chi2_of, rmse, rotations};
use super::mixed::{self, fit_pairs, pair_shares, single_share, EffectShare, PairCtx, PairFit};
use super::noise;
use super::other::{remaining, Remaining};
pub use super::outcome::Outcome;
use super::sim::Sim;
use super::stages::{fit_design, progress_bar, FitCtx, Fits, Split};
use crate::calibrate::experiment::Experiment;
use crate::error::Result;
use statrs::distribution::{ChiSquared, ContinuousCDF};
use std::collections::BTreeMap;

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
    let chi_b_tr = chi2_of(sim, baseline, &split.train, w, false);
    let chi_b_ho = chi2_of(sim, baseline, &split.heldout, w, true);
    let ho_rot: Vec<usize> = rotations(sim, &split.heldout);
    let p0 = baseline.x.len();
    fits.iter()
        .map(|f| {
            let chi_tr = chi2_of(sim, f, &split.train, w, false);
            let chi_ho = chi2_of(sim, f, &split.heldout, w, true);
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
                label: f.family.label(),
                dofs: f.family.dofs.clone(),
                effect: f.family.kind.effect(),
                n_params: f.x.len(),
                chi2_train: chi_tr,
                chi2_heldout: chi_ho,
                heldout_rot_rmse: rmse(sim, f, &ho_rot, true),
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

/// The best variant of each effect (lowest training BIC), ranked by
/// score, the effects the design can test first: a candidate the design
/// cannot test is never ranked above one it can.
fn rank_effects(stats: &[CandidateStats], n_train: usize, design: &Design) -> Vec<usize> {
    let ln_n = (n_train.max(1) as f64).ln();
    let bic = |s: &CandidateStats| s.chi2_train + s.n_params as f64 * ln_n;
    let mut per_effect: BTreeMap<Effect, usize> = BTreeMap::new();
    for (i, s) in stats.iter().enumerate() {
        let e = per_effect.entry(s.effect).or_insert(i);
        if bic(s) < bic(&stats[*e]) {
            *e = i;
        }
    }
    // a table's per-DoF variants: the DoFs whose own parameter is
    // significant in training
    if design.by_level {
        for (e, best) in per_effect.iter_mut() {
            if let Some(i) = significant_dofs_variant(stats, *e) {
                *best = i;
            }
        }
    }
    let mut ranked: Vec<usize> = per_effect.values().copied().collect();
    let untestable = |i: &usize| design.is_untestable(stats[*i].effect.name());
    ranked.sort_by(|a, b| {
        untestable(a)
            .cmp(&untestable(b))
            .then(stats[*b].score.total_cmp(&stats[*a].score))
            .then(a.cmp(b))
    });
    ranked
}

/// Among the per-DoF variants of effect `e` (fitted on every subset of
/// DoFs), the one acting on exactly the DoFs whose single-DoF variant
/// improves the training fit significantly (`p < ALPHA`), chosen from the
/// training data alone: a trend in flexion and none in axial rotation is
/// fitted in flexion only. `None` when no single-DoF variant is
/// significant or the effect has no per-DoF variants.
fn significant_dofs_variant(stats: &[CandidateStats], e: Effect) -> Option<usize> {
    let of_e = || stats.iter().enumerate().filter(move |(_, s)| s.effect == e);
    let mut dofs: Vec<usize> = of_e()
        .filter(|(_, s)| s.dofs.len() == 1 && s.p_train < ALPHA)
        .map(|(_, s)| s.dofs[0])
        .collect();
    dofs.sort_unstable();
    if dofs.is_empty() {
        return None;
    }
    of_e().find(|(_, s)| s.dofs == dofs).map(|(i, _)| i)
}

/// The verdict, the chosen fit, the confidence and the reasons.
struct Decision {
    verdict: Verdict,
    chosen: Option<usize>,
    chosen_pair: Option<usize>,
    confidence: f64,
    reasons: Vec<String>,
    effects: Vec<EffectShare>,
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
                .map(|&c| f.heldout_residual(sim, c) * w.cell(&sim.cells[c]))
                .collect()
        };
        HeldoutResiduals {
            base: res(baseline),
            fits: fits.iter().map(res).collect(),
        }
    }
}

/// Everything a decision reads.
struct Evidence<'a> {
    sim: &'a Sim,
    w: Weights,
    design: &'a Design,
    split: &'a Split,
    stats: &'a [CandidateStats],
    ranked: &'a [usize],
    earning: &'a [usize],
    pairs: &'a [PairFit],
    /// Effects the design cannot test (not preload stiffening, whose
    /// absence of follower loads only leaves it untested).
    design_gaps: Vec<&'a (String, String)>,
    hr: HeldoutResiduals,
    /// The baseline's held-out chi-square.
    chi_b: f64,
}

impl Evidence<'_> {
    /// Cells held out.
    fn n_ho(&self) -> f64 {
        self.split.heldout.len().max(1) as f64
    }

    /// Fraction of the baseline's held-out excess over the noise
    /// (`chi_b - n`) that a model of held-out chi-square `chi` closes
    /// (1 when the baseline is within the noise).
    fn excess_closed(&self, chi: f64) -> f64 {
        let excess = self.chi_b - self.n_ho();
        if excess <= 0.0 {
            1.0
        } else {
            (self.chi_b - chi) / excess
        }
    }

    /// The fraction of the baseline's held-out excess over the noise that
    /// a model of held-out residuals `r` (noise units, one per held-out
    /// cell) closes on the cells of the rotational DoFs `dofs` (all cells
    /// when empty): in a table's design, what a per-DoF effect explains is
    /// judged where it acts.
    fn excess_closed_on(&self, r: &[f64], dofs: &[usize]) -> f64 {
        let on = |k: usize| {
            let d = self.sim.cells[self.split.heldout[k]].dof;
            dofs.is_empty() || dofs.contains(&d)
        };
        let (mut cb, mut cm, mut n) = (0.0, 0.0, 0.0);
        for (k, rm) in r.iter().enumerate().filter(|(k, _)| on(*k)) {
            cb += self.hr.base[k].powi(2);
            cm += rm.powi(2);
            n += 1.0;
        }
        if cb - n <= 0.0 {
            1.0
        } else {
            (cb - cm) / (cb - n)
        }
    }

    /// The DoFs a fit's effects act on (empty: all of them).
    fn model_dofs(&self, members: &[usize]) -> Vec<usize> {
        let mut out = Vec::new();
        for &m in members {
            if self.stats[m].dofs.is_empty() {
                return Vec::new();
            }
            out.extend(self.stats[m].dofs.iter().copied());
        }
        out.sort_unstable();
        out.dedup();
        out
    }

    /// The accepted pair with the lowest held-out chi-square (one that
    /// earns its parameters against the baseline when no single effect
    /// does).
    fn best_pair(&self) -> Option<usize> {
        (0..self.pairs.len())
            .filter(|&i| {
                let p = &self.pairs[i];
                p.accepted && (p.earns || !self.earning.is_empty())
            })
            .min_by(|&a, &b| {
                let (pa, pb) = (&self.pairs[a], &self.pairs[b]);
                pa.chi2_heldout.total_cmp(&pb.chi2_heldout)
            })
    }
}

/// A joint pose error with joint-centre offsets (fit `chosen`) seen
/// through follower loads only: as likely a misplaced follower guide, two
/// explanations the data cannot separate (confidence halved).
fn guides_confound(ev: &Evidence, verdict: Verdict, chosen: usize) -> bool {
    let offsets = ev.stats[chosen].family != Kind::JointRotation;
    verdict == Verdict::Effect(Effect::JointPoseError)
        && offsets
        && ev.design.offsets_confounded_with_guides()
}

/// Decide when some effect earns its parameters: the top one (with a
/// second effect when a pair of them is accepted), unless the runner-up
/// is as good or an untestable effect could carry the gap.
fn decide_effect(ev: &Evidence) -> Decision {
    let stats = ev.stats;
    // the best earning effect, else the better member of the pair that
    // earns on its own
    let top = match (ev.earning.first(), ev.best_pair()) {
        (Some(&t), _) => t,
        (None, Some(p)) => {
            let m = ev.pairs[p].members;
            if stats[m[0]].score >= stats[m[1]].score {
                m[0]
            } else {
                m[1]
            }
        }
        (None, None) => return decide_none(ev),
    };
    let t = (stats[top].chi2_heldout / ev.n_ho()).max(1.0);
    let mut confidence = calibrated_confidence(stats, ev.ranked, top, &ev.hr.fits, &ev.hr.base, t);
    let pair = ev.best_pair();
    let (effects, chosen, model_chi) = match pair {
        Some(p) => {
            let pf = &ev.pairs[p];
            let effects = pair_shares(pf, stats, ev.chi_b);
            let primary = pf.members[if stats[pf.members[0]].effect == effects[0].effect {
                0
            } else {
                1
            }];
            confidence = confidence.min(pf.win);
            (effects, primary, pf.chi2_heldout)
        }
        None => (
            vec![single_share(&stats[top], ev.chi_b)],
            top,
            stats[top].chi2_heldout,
        ),
    };
    let mut reasons = Vec::new();
    if let Some(&second) = ev.earning.get(1) {
        let both = pair.is_some_and(|p| {
            let m = ev.pairs[p].members;
            m.contains(&top) && m.contains(&second)
        });
        if !both && stats[top].score - stats[second].score < INDISTINGUISHABLE * t {
            reasons.push(format!(
                "{} and {} explain the gap equally well (scores {:.1} and {:.1})",
                stats[top].effect.name(),
                stats[second].effect.name(),
                stats[top].score,
                stats[second].score
            ));
        }
    }
    // an effect the design cannot test could carry the gap too: only a
    // model that closes most of the held-out excess over the noise excludes it
    let closed = if ev.design.by_level {
        // a table's design: judged on the DoFs the effects act on
        let (r, members) = match pair {
            Some(p) => {
                let f = &ev.pairs[p].fit;
                let r: Vec<f64> = ev
                    .split
                    .heldout
                    .iter()
                    .map(|&c| f.heldout_residual(ev.sim, c) * ev.w.cell(&ev.sim.cells[c]))
                    .collect();
                (r, ev.pairs[p].members.to_vec())
            }
            None => (ev.hr.fits[chosen].clone(), vec![chosen]),
        };
        ev.excess_closed_on(&r, &ev.model_dofs(&members))
    } else {
        ev.excess_closed(model_chi)
    };
    if closed < DECISIVE_SHRINK {
        for (e, why) in &ev.design_gaps {
            reasons.push(format!(
                "{e} cannot be tested ({why}) and {} closes only {:.0}% of the held-out gap above the noise",
                effects[0].effect.name(),
                100.0 * closed
            ));
        }
    }
    let verdict = if reasons.is_empty() {
        Verdict::Effect(stats[chosen].effect)
    } else {
        Verdict::Unidentifiable
    };
    if guides_confound(ev, verdict, chosen) {
        confidence *= 0.5;
        reasons.push("the joint-centre offsets rest on the follower-load cases: with no translation measured, joint centres moved relative to the follower guides cannot be told from guides placed off the joint centres (translations would separate them)".to_string());
    }
    Decision {
        verdict,
        chosen: Some(chosen),
        chosen_pair: pair,
        confidence,
        reasons,
        effects,
    }
}

/// Decide when no effect earns its parameters: `none`, or
/// `unidentifiable` when the design leaves an effect untestable and the
/// baseline's held-out gap is above the noise (with no gap there is
/// nothing to explain: `none`, naming what could not be tested).
fn decide_none(ev: &Evidence) -> Decision {
    // no gap above the noise: nothing to explain, whatever the design
    // cannot test (named in the reasons)
    let gap_seen = ChiSquared::new(ev.n_ho())
        .map(|c| c.sf(ev.chi_b) < ALPHA)
        .unwrap_or(true);
    if ev.design_gaps.is_empty() || !gap_seen {
        let t = (ev.chi_b / ev.n_ho()).max(1.0);
        // what the design saw only indirectly: none of it showed, but a
        // small one would not have
        let untested = ev.design_gaps.iter().map(|(e, why)| {
            format!("the nominal model fits within the noise, but {e} cannot be tested: {why}")
        });
        let weak = ev.design.weakly_tested.iter();
        let reasons = untested
            .chain(weak.map(|(e, why)| format!("{e} not seen; {why}")))
            .collect();
        return Decision {
            verdict: Verdict::None,
            chosen: None,
            chosen_pair: None,
            confidence: none_confidence(ev.stats, ev.ranked, &ev.hr.fits, &ev.hr.base, t),
            reasons,
            effects: Vec::new(),
        };
    }
    Decision {
        verdict: Verdict::Unidentifiable,
        chosen: ev.ranked.first().copied(),
        chosen_pair: None,
        confidence: 0.0,
        reasons: ev
            .design_gaps
            .iter()
            .map(|(e, why)| format!("{e} cannot be tested: {why}"))
            .collect(),
        effects: Vec::new(),
    }
}

/// `other` instead of the decision `d` when what the augmented model
/// leaves is structured and well above the noise: either the structured
/// part of its residuals is at least half the unstructured scatter (a
/// structured misfit ratio of [`OTHER_MISFIT`] or more, with p below
/// [`ALPHA`]; independent of the noise estimate, which a wrong model
/// inflates), or its held-out reduced chi-square reaches
/// [`OTHER_REDUCED_CHI2`] (p below [`ALPHA`]) with structure, after closing
/// less than [`OTHER_CLOSED`] of the baseline's. Otherwise the
/// confidence is scaled by the unstructured share of the residuals
/// (`1 / misfit`): significant structure says the named model may not be
/// the whole story.
fn other_or(d: Decision, rem: &Remaining) -> Decision {
    let misfit = rem.misfit(ALPHA);
    let p_structure = rem.p_structure();
    let above = rem.p_noise < ALPHA && rem.reduced_chi2 >= OTHER_REDUCED_CHI2;
    let large = above && rem.closed < OTHER_CLOSED && p_structure < ALPHA;
    // a model that closes nearly all of the gap and leaves less than twice
    // the noise variance explains it, whatever structure its small
    // residuals keep
    let explained = rem.closed >= EXPLAINED_CLOSED && rem.reduced_chi2 < EXPLAINED_REDUCED_CHI2;
    if explained || (misfit < OTHER_MISFIT && !large) {
        return Decision {
            confidence: d.confidence / misfit,
            ..d
        };
    }
    let s = &rem.structure[0];
    let top: Vec<String> = s
        .groups
        .iter()
        .take(3)
        .map(|g| {
            format!(
                "{} (mean {:+.1} noise SD, {:.0}%)",
                g.key,
                g.mean,
                100.0 * g.share
            )
        })
        .collect();
    let mut reasons = vec![format!(
        "what the best model ({}) leaves is structured: by {} of the {} residuals (misfit ratio {:.2}, p {:.1e}): {}; it closes {:.0}% of the held-out gap and leaves a reduced chi-square of {:.1}",
        rem.model,
        s.by,
        s.cells.replace('_', "-"),
        s.misfit,
        s.p,
        top.join(", "),
        100.0 * rem.closed,
        rem.reduced_chi2
    )];
    reasons.extend(d.reasons);
    Decision {
        verdict: Verdict::Other,
        confidence: 1.0 - p_structure,
        reasons,
        ..d
    }
}

/// Which DoFs (`rx .. tz`) each case measures at some level.
fn measured_dofs(sim: &Sim) -> Vec<[bool; 6]> {
    let mut m = vec![[false; 6]; sim.loads.len()];
    for c in &sim.cells {
        if let Some(x) = m.get_mut(c.case) {
            x[c.dof] = true;
        }
    }
    m
}

/// The measured rows `(case, level, DoFs)`, by level then case (each
/// level's rows together, the levels in order along the load path).
fn measured_rows(sim: &Sim) -> Vec<(usize, usize, Vec<usize>)> {
    let mut rows: BTreeMap<(usize, usize), Vec<usize>> = BTreeMap::new();
    for c in &sim.cells {
        rows.entry((c.level, c.case)).or_default().push(c.dof);
    }
    rows.into_iter().map(|((l, c), d)| (c, l, d)).collect()
}

/// The experiment as simulated, its design and split, and the noise known
/// before any fit.
struct Setup {
    sim: Sim,
    design: Design,
    split: Split,
    prior: [Option<Option<noise::ClassNoise>>; 2],
    /// Weights of the fits.
    fw: Weights,
    /// A published table's design: the effects it cannot test.
    table: Option<Vec<String>>,
    /// The specimens the cells are means over, when they are means.
    means_over: Option<u32>,
}

impl Setup {
    /// Simulate, analyse the design, and read the noise stated, assumed
    /// for means, or from replicates.
    fn new(exp: &Experiment) -> Result<Setup> {
        let mut sim = Sim::new(exp)?;
        // nothing moved above the noise: nothing to diagnose
        if let Some(why) = noise::no_motion(&sim, ALPHA) {
            return Err(crate::Error::invalid(
                format!("experiment {}", exp.dir.display()),
                why,
            ));
        }
        let mut design = Design::new(&exp.cases);
        design.note_measurement(&measured_dofs(&sim));
        // a published table (one magnitude, primary rotations): leave one
        // measured level out, or no trend to test over fewer than three
        let rows = measured_rows(&sim);
        let mut levels: Vec<usize> = rows.iter().map(|r| r.1).collect();
        levels.dedup();
        let table = design.is_table().then(|| {
            if design.leave_one_level_out(&levels) {
                let primary = sim.primary_dofs().map(|p| p.0);
                design.note_tilt(sim.tilt_spread, primary, super::sim::TILT_TOL_DEG);
            } else {
                design.note_few_levels(levels.len());
            }
            design.untestable_names()
        });
        // the folds over the measured rows
        design.assign_folds(&rows);
        let split = Split::of(&sim, &design);
        let means_over = noise::means_over(&exp.measurement);
        let assumed = noise::assume_spread_of_means(&mut sim, means_over);
        let prior = noise::prior(&sim, &exp.cases, assumed);
        let fw = noise::fit_weights(&prior);
        Ok(Setup {
            sim,
            design,
            split,
            prior,
            fw,
            table,
            means_over,
        })
    }

    /// Joint offsets are pose parameters (translations or follower loads
    /// can show them).
    fn offsets(&self) -> bool {
        self.sim.cells.iter().any(|c| c.dof >= 3) || self.design.has_follower
    }

    /// The progress bar over every fit of every run.
    fn progress(&self, opts: &Options) -> crate::util::progress::Bar {
        let n_kinds: usize = kinds(self.design.has_follower, self.table.as_deref())
            .into_iter()
            .map(|k| match self.table {
                Some(_) => Family::dof_subsets(k, &self.sim, [0.0; 3]).len(),
                None => 1,
            })
            .sum();
        let n_kinds = n_kinds as u64;
        let runs = self.design.folds as u64 + 1;
        // the baseline, and the second-stage variants outside a table's design
        let more = if self.table.is_some() {
            1
        } else {
            4 + self.offsets() as u64
        };
        progress_bar(opts, (n_kinds + more) * runs)
    }

    /// The fits' shared data: the training cells of the design.
    fn ctx<'a>(&'a self, opts: &Options, pb: &'a crate::util::progress::Bar) -> FitCtx<'a> {
        FitCtx {
            sim: &self.sim,
            train_cells: self.split.train.clone(),
            train_cases: self.design.train.clone(),
            has_follower: self.design.has_follower,
            w: self.fw,
            max_iterations: opts.max_iterations,
            pb,
            table: self.table.as_deref(),
        }
    }
}

/// The fit whose remaining gap decides `other`: the reported pair, the
/// chosen effect, else the best-ranked candidate (the baseline without one).
fn model_of<'a>(
    d: &Decision,
    fitted: &'a Fits,
    pairs: &'a [PairFit],
    ranked: &[usize],
) -> &'a Fitted {
    let pick = |i: Option<usize>| i.map(|i| &fitted.fits[i]).unwrap_or(&fitted.baseline);
    match (d.chosen_pair, d.verdict) {
        (Some(p), _) => &pairs[p].fit,
        (None, Verdict::Effect(_)) => pick(d.chosen),
        _ => pick(ranked.first().copied()),
    }
}

/// Run the diagnosis on an experiment.
pub fn diagnose(exp: &Experiment, opts: &Options) -> Result<Outcome> {
    let su = Setup::new(exp)?;
    let (sim, design, split) = (&su.sim, &su.design, &su.split);
    let pb = su.progress(opts);
    let ctx = su.ctx(opts, &pb);
    // baseline and candidates on the training cases (and per fold)
    let fitted = fit_design(&ctx, design, su.offsets())?;
    // the noise left to estimate: residuals of the best fit, or the floor
    let every: Vec<&Fitted> = fitted.fits.iter().chain([&fitted.baseline]).collect();
    let noise_model = noise::complete(su.prior, sim, &every, &split.train, su.fw);
    let w = noise_model.weights();
    // statistics, ranking, pairs of effects
    let stats = candidate_stats(sim, design, split, &fitted.baseline, &fitted.fits, w);
    let ranked = rank_effects(&stats, split.train.len(), design);
    let earning: Vec<usize> = ranked.iter().copied().filter(|&i| stats[i].earns).collect();
    let pairs = pairs_of(&ctx, design, split, &fitted, &stats, (&ranked, &earning), w);
    pb.finish_and_clear();
    // the verdict
    let ev = Evidence {
        sim,
        w,
        design,
        split,
        stats: &stats,
        ranked: &ranked,
        earning: &earning,
        pairs: &pairs,
        design_gaps: design
            .untestable
            .iter()
            .filter(|(e, _)| e != "preload_stiffening")
            .collect(),
        hr: HeldoutResiduals::of(sim, split, &fitted.baseline, &fitted.fits, w),
        chi_b: chi2_of(sim, &fitted.baseline, &split.heldout, w, true),
    };
    let d = if earning.is_empty() && ev.best_pair().is_none() {
        decide_none(&ev)
    } else {
        decide_effect(&ev)
    };
    // what the augmented model leaves, and `other` when it is a structured gap
    let model = model_of(&d, &fitted, &pairs, &ranked);
    let given = noise_model
        .rotation
        .is_some_and(|c| c.source != noise::NoiseSource::Residuals);
    let cells = (split.train.as_slice(), split.heldout.as_slice());
    let rem = remaining(sim, design, cells, (w, given), model, ev.chi_b);
    let mut d = other_or(d, &rem);
    if !fitted.dropped.is_empty() {
        d.reasons.push(format!(
            "left out of the comparison (a fit found no equilibrium for the parameters it tried): {}",
            fitted.dropped.join(", ")
        ));
    }
    // the reported model's ratios, with intervals widened by its training misfit
    let ratios = match d.verdict {
        Verdict::Effect(_) | Verdict::Other if d.chosen.is_some() => {
            let m = model_of(&d, &fitted, &pairs, &ranked);
            let dof = (split.train.len() as f64 - m.x.len() as f64).max(1.0);
            let red = chi2_of(sim, m, &split.train, w, false) / dof;
            super::ratios::of_fit(sim, m, red.sqrt())
        }
        _ => Vec::new(),
    };
    let assumptions = assumptions(&noise_model, su.means_over);
    let Setup { sim, design, .. } = su;
    Ok(Outcome {
        sim,
        design,
        noise: w,
        noise_model,
        baseline: fitted.baseline,
        fits: fitted.fits,
        stats,
        ranked,
        verdict: d.verdict,
        confidence: d.confidence,
        chosen: d.chosen,
        reasons: d.reasons,
        pairs,
        chosen_pair: d.chosen_pair,
        effects: d.effects,
        remaining: rem,
        ratios,
        assumptions,
    })
}

/// What the confidence rests on that the data do not give: an assumed
/// noise (the spread of means from a literature coefficient of
/// variation, or the rig floor).
fn assumptions(n: &noise::Noise, means_over: Option<u32>) -> Vec<String> {
    let mut out = Vec::new();
    for (c, what) in [(n.rotation, "rotations"), (n.translation, "translations")] {
        let Some(c) = c else { continue };
        match c.source {
            noise::NoiseSource::AssumedSpread => {
                let n = match means_over {
                    Some(1) => "n_specimens not stated: the SD of one specimen is used, not that of a mean".to_string(),
                    Some(n) => format!("divided by sqrt({n}) specimens"),
                    None => String::new(),
                };
                out.push(format!(
                    "the noise of the {what} is assumed, not stated: a between-specimen SD of {:.0}% of each mean ({}), {n}; the confidence rests on it (state sd_* columns to replace it)",
                    100.0 * noise::SPECIMEN_CV,
                    noise::SPECIMEN_CV_SOURCE
                ));
            }
            noise::NoiseSource::Floor => out.push(format!(
                "the noise of the {what} is the assumed rig repeatability floor {:.2} (Wilke et al. 1998), neither stated nor estimable from this design; the confidence rests on it",
                c.sigma
            )),
            _ => {}
        }
    }
    out
}

/// The pairs of the best earning effects, fitted and compared with the
/// best single one (none with fewer than two earning effects). In a
/// published table's design the trend and the shared asymmetry are always
/// fitted together too (each may fail to predict a level alone when the
/// table carries both), compared with the best single effect.
#[allow(clippy::too_many_arguments)]
fn pairs_of(
    ctx: &FitCtx,
    design: &Design,
    split: &Split,
    fitted: &Fits,
    stats: &[CandidateStats],
    (ranked, earning): (&[usize], &[usize]),
    w: Weights,
) -> Vec<PairFit> {
    let mut pairs = mixed::earning_pairs(earning);
    let best = |e: Effect| ranked.iter().copied().find(|&i| stats[i].effect == e);
    if design.by_level {
        let trend_asym = (
            best(Effect::LevelDependentStiffness),
            best(Effect::AsymmetricStiffness),
        );
        if let (Some(t), Some(a)) = trend_asym {
            if !pairs.iter().any(|p| p.contains(&t) && p.contains(&a)) {
                pairs.push([t, a]);
            }
        }
    }
    let Some(&top) = earning.first().or(ranked.first()) else {
        return Vec::new();
    };
    if pairs.is_empty() {
        return Vec::new();
    }
    ctx.pb.set_message("pairs of effects");
    let pc = PairCtx {
        sim: ctx.sim,
        split,
        w,
        stats,
        top,
        baseline: &fitted.baseline,
        table: design.by_level,
    };
    fit_pairs(ctx, design, fitted, &pc, &pairs)
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
