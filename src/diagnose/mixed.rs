//! Mixed effects: two effects fitted together (one family with both
//! extensions, started from the two single-effect fits), kept when the
//! pair explains significantly more of the held-out gap than the best
//! single effect; and the share of the held-out gap each effect explains.
//!
//! **Shares.** With `c_0` the baseline's held-out chi-square, `c_A`, `c_B`
//! the single effects' and `c_AB` the pair's, the reduction `c_0 - c_AB`
//! is split between the two by their average contribution over both
//! orders of adding them (the Shapley value of a two-player game):
//! `s_A = ((c_0 - c_A) + (c_B - c_AB)) / (2 c_0)`, likewise `s_B`; the two
//! shares add up to the fraction of the held-out gap the pair closes.

use super::criteria::{win_probability, CandidateStats, ALPHA, HELDOUT_MIN};
use super::family::Effect;
use super::fit::{Fitted, Weights};
use super::gap::chi2_of;
use super::sim::Sim;
use super::stages::{fit_pair, FitCtx, Fits, Split};
use serde::Serialize;
use statrs::distribution::{ChiSquared, ContinuousCDF};

/// Effects that may be paired: the best few earning ones.
pub const PAIR_CANDIDATES: usize = 3;

/// Probability the pair's held-out margin over the best single effect
/// must reach (see [`win_probability`]).
pub const PAIR_WIN: f64 = 0.95;

/// A fitted pair of effects and its statistics.
#[derive(Debug, Clone)]
pub struct PairFit {
    /// The fitted mixed family.
    pub fit: Fitted,
    /// The two single fits it was started from (indices into the fits).
    pub members: [usize; 2],
    /// The two effects, in build order.
    pub effects: [Effect; 2],
    /// Weighted chi-square on the training cases.
    pub chi2_train: f64,
    /// Weighted chi-square on the held-out cases.
    pub chi2_heldout: f64,
    /// Training chi-square improvement over the better member, and its
    /// p-value (the other member's parameters as dof).
    pub dchi2_train: f64,
    /// The p-value of `dchi2_train`.
    pub p_train: f64,
    /// Held-out chi-square improvement over the best single effect.
    pub dchi2_heldout: f64,
    /// Probability that this improvement stays positive on new data.
    pub win: f64,
    /// Significantly better than the best single effect, in training and
    /// held out.
    pub accepted: bool,
    /// Earns its parameters against the baseline on its own (training
    /// improvement significant, held-out improvement above
    /// [`HELDOUT_MIN`]), as a single effect must.
    pub earns: bool,
}

/// One effect of `verdict.effects`.
#[derive(Debug, Clone, Serialize)]
pub struct EffectShare {
    /// The effect.
    pub effect: Effect,
    /// Family (variant) of the effect.
    pub family: String,
    /// Share of the baseline's held-out chi-square it explains.
    pub share: f64,
}

/// What the pair statistics compare with.
pub struct PairCtx<'a> {
    /// The simulated experiment.
    pub sim: &'a Sim,
    /// The training / held-out split.
    pub split: &'a Split,
    /// Residual weights.
    pub w: Weights,
    /// The single effects' statistics, in fit order.
    pub stats: &'a [CandidateStats],
    /// The best single effect (index into the fits).
    pub top: usize,
    /// The baseline fit.
    pub baseline: &'a Fitted,
    /// A published table's design (see [`pair_stats`]).
    pub table: bool,
}

/// The pairs of the best [`PAIR_CANDIDATES`] earning effects (`earning`,
/// ranked).
pub fn earning_pairs(earning: &[usize]) -> Vec<[usize; 2]> {
    let best: Vec<usize> = earning.iter().copied().take(PAIR_CANDIDATES).collect();
    let mut out = Vec::new();
    for i in 0..best.len() {
        for j in i + 1..best.len() {
            out.push([best[i], best[j]]);
        }
    }
    out
}

/// The pairs `pairs` (indices into the fits), fitted and compared with
/// the best single effect (a pair whose fit fails, e.g. a law with no
/// equilibrium, is left out).
pub fn fit_pairs(
    fctx: &FitCtx,
    design: &super::design::Design,
    fits: &Fits,
    pc: &PairCtx,
    pairs: &[[usize; 2]],
) -> Vec<PairFit> {
    let mut out = Vec::new();
    for &[a, b] in pairs {
        // a pair whose fit finds no equilibrium is not a candidate
        if let Ok(fit) = fit_pair(fctx, design, fits, a, b) {
            out.push(pair_stats(pc, fits, fit, [a, b]));
        }
    }
    out
}

/// The held-out residuals (noise units) of a fit.
fn heldout(pc: &PairCtx, f: &Fitted) -> Vec<f64> {
    pc.split
        .heldout
        .iter()
        .map(|&c| f.heldout_residual(pc.sim, c) * pc.w.cell(&pc.sim.cells[c]))
        .collect()
}

/// The statistics of a pair fit started from `members`.
fn pair_stats(pc: &PairCtx, fits: &Fits, fit: Fitted, members: [usize; 2]) -> PairFit {
    let (sim, split, w, stats) = (pc.sim, pc.split, pc.w, pc.stats);
    let chi_tr = chi2_of(sim, &fit, &split.train, w, false);
    let chi_ho = chi2_of(sim, &fit, &split.heldout, w, true);
    // against the better member in training: the other's parameters as dof
    let m = *members
        .iter()
        .min_by(|a, b| stats[**a].chi2_train.total_cmp(&stats[**b].chi2_train))
        .unwrap_or(&members[0]);
    let d_tr = stats[m].chi2_train - chi_tr;
    let dp = (fit.x.len().saturating_sub(stats[m].n_params)).max(1) as f64;
    let p_train = if d_tr > 0.0 {
        ChiSquared::new(dp).map(|c| c.sf(d_tr)).unwrap_or(1.0)
    } else {
        1.0
    };
    // against the best single effect on the held-out cells
    let d_ho = stats[pc.top].chi2_heldout - chi_ho;
    let n_ho = split.heldout.len().max(1) as f64;
    let (ra, rb) = (heldout(pc, &fit), heldout(pc, &fits.fits[pc.top]));
    let t = if pc.table {
        local_misfit(&ra, &rb)
    } else {
        (chi_ho / n_ho).max(1.0)
    };
    let win = win_probability(d_ho, &ra, &rb, t);
    // a table's few levels rarely make the margin sure: a significant pair
    // is reported with its win probability as the confidence's cap
    let sure = win >= PAIR_WIN || pc.table;
    let accepted = p_train < ALPHA && d_ho > HELDOUT_MIN * t && sure;
    // against the baseline, as a single effect earns its parameters
    let b_tr = chi2_of(sim, pc.baseline, &split.train, w, false) - chi_tr;
    let b_ho = chi2_of(sim, pc.baseline, &split.heldout, w, true) - chi_ho;
    let b_dp = (fit.x.len().saturating_sub(pc.baseline.x.len())).max(1) as f64;
    let b_p = if b_tr > 0.0 {
        ChiSquared::new(b_dp).map(|c| c.sf(b_tr)).unwrap_or(1.0)
    } else {
        1.0
    };
    let earns = b_p < ALPHA && b_ho > HELDOUT_MIN;
    PairFit {
        effects: [stats[members[0]].effect, stats[members[1]].effect],
        fit,
        members,
        chi2_train: chi_tr,
        chi2_heldout: chi_ho,
        dchi2_train: d_tr,
        p_train,
        dchi2_heldout: d_ho,
        win,
        accepted,
        earns,
    }
}

/// The held-out reduced chi-square of a model (residuals `ra`, noise
/// units) on the cells where its predictions differ from another's (`rb`),
/// at least 1: the misfit that bears on the comparison of the two (a
/// misfit both share, in cells neither changes, does not).
pub fn local_misfit(ra: &[f64], rb: &[f64]) -> f64 {
    let scale = ra.iter().chain(rb).fold(0.0f64, |m, v| m.max(v.abs()));
    let (mut ss, mut n) = (0.0, 0.0);
    for (a, b) in ra.iter().zip(rb) {
        if (a - b).abs() > 1e-9 * scale.max(1.0) {
            ss += a * a;
            n += 1.0;
        }
    }
    if n > 0.0 {
        (ss / n).max(1.0)
    } else {
        1.0
    }
}

/// The effects of a pair with the share of the held-out gap each explains
/// (the larger share first: the primary effect), given the baseline's
/// held-out chi-square `chi_b`.
pub fn pair_shares(p: &PairFit, stats: &[CandidateStats], chi_b: f64) -> Vec<EffectShare> {
    let [a, b] = p.members;
    let (ca, cb, cab) = (stats[a].chi2_heldout, stats[b].chi2_heldout, p.chi2_heldout);
    let denom = 2.0 * chi_b.max(1e-300);
    let mut v = vec![
        EffectShare {
            effect: stats[a].effect,
            family: stats[a].label.clone(),
            share: ((chi_b - ca) + (cb - cab)) / denom,
        },
        EffectShare {
            effect: stats[b].effect,
            family: stats[b].label.clone(),
            share: ((chi_b - cb) + (ca - cab)) / denom,
        },
    ];
    v.sort_by(|x, y| y.share.total_cmp(&x.share));
    v
}

/// A single effect's share of the held-out gap.
pub fn single_share(s: &CandidateStats, chi_b: f64) -> EffectShare {
    EffectShare {
        effect: s.effect,
        family: s.label.clone(),
        share: (chi_b - s.chi2_heldout) / chi_b.max(1e-300),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnose::family::Kind;

    fn stat(effect: Effect, chi2_heldout: f64) -> CandidateStats {
        CandidateStats {
            family: Kind::LevelScalar,
            label: "level_scalar".into(),
            dofs: vec![],
            effect,
            n_params: 3,
            chi2_train: 0.0,
            chi2_heldout,
            heldout_rot_rmse: 0.0,
            dchi2_train: 0.0,
            p_train: 1.0,
            dbic_train: 0.0,
            dchi2_heldout: 0.0,
            score: 0.0,
            earns: true,
            iterations: 0,
            params: Default::default(),
        }
    }

    #[test]
    fn shares_split_the_pair_reduction_by_average_contribution() {
        // baseline 100; A alone 40, B alone 80, both 10
        let stats = vec![
            stat(Effect::LevelDependentStiffness, 40.0),
            stat(Effect::CoupledStiffness, 80.0),
        ];
        let p = PairFit {
            fit: Fitted {
                family: crate::diagnose::family::Family {
                    kind: Kind::Baseline,
                    mask: vec![],
                    offsets: false,
                    names: vec![],
                    x0: vec![],
                    lo: vec![],
                    hi: vec![],
                    add: None,
                    dofs: vec![],
                },
                x: vec![],
                pred: vec![],
                iterations: 0,
                at_bound: 0,
                heldout_pred: None,
                se: vec![],
            },
            members: [0, 1],
            effects: [Effect::LevelDependentStiffness, Effect::CoupledStiffness],
            chi2_train: 0.0,
            chi2_heldout: 10.0,
            dchi2_train: 0.0,
            p_train: 0.0,
            dchi2_heldout: 30.0,
            win: 1.0,
            accepted: true,
            earns: true,
        };
        let s = pair_shares(&p, &stats, 100.0);
        // A: (60 + 70) / 200 = 0.65, B: (20 + 30) / 200 = 0.25; sum 0.9
        assert_eq!(s[0].effect, Effect::LevelDependentStiffness);
        assert!((s[0].share - 0.65).abs() < 1e-12);
        assert!((s[1].share - 0.25).abs() < 1e-12);
        assert!((s[0].share + s[1].share - 0.9).abs() < 1e-12);
    }
}
