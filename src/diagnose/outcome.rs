//! The outcome of a diagnosis: the data, the fits, the verdict and what
//! it rests on, and the held-out gap it leaves (which cells, the RMSEs,
//! where the baseline's gap sits).

use super::criteria::{CandidateStats, GapCell, LevelDofRmse, Share, Verdict};
use super::design::{Design, AXIS_NAMES};
use super::fit::{Fitted, Weights};
use super::gap::rmse;
use super::mixed::{EffectShare, PairFit};
use super::noise;
use super::other::Remaining;
use super::sim::Sim;
use crate::calibrate::experiment::{Experiment, DOF_NAMES};
use std::collections::BTreeMap;

/// The outcome of a diagnosis (everything reports need).
#[derive(Debug, Clone)]
pub struct Outcome {
    /// The simulated experiment.
    pub sim: Sim,
    /// The held-out design.
    pub design: Design,
    /// Weights (`1/sigma`, report units) of every chi-square.
    pub noise: Weights,
    /// The noise of each measured class and where it comes from.
    pub noise_model: noise::Noise,
    /// The fitted baseline.
    pub baseline: Fitted,
    /// Every fitted candidate family.
    pub fits: Vec<Fitted>,
    /// Statistics of each of `fits`, in the same order.
    pub stats: Vec<CandidateStats>,
    /// Best variant per effect (index into `fits`), ranked by score.
    pub ranked: Vec<usize>,
    /// `none`, an effect or `unidentifiable`.
    pub verdict: Verdict,
    /// Probability (0..1) that the verdict's score margins stay positive on new held-out data.
    pub confidence: f64,
    /// The family used for the held-out comparison and the improved model
    /// (None for `none`); the primary effect's when two are reported.
    pub chosen: Option<usize>,
    /// Why the verdict was reached, one sentence each.
    pub reasons: Vec<String>,
    /// Every pair of effects fitted together.
    pub pairs: Vec<PairFit>,
    /// The pair reported (index into `pairs`): the augmented model then
    /// carries both effects.
    pub chosen_pair: Option<usize>,
    /// `verdict.effects`: the effect(s) reported with the share of the
    /// held-out gap each explains (the primary first).
    pub effects: Vec<EffectShare>,
    /// What the augmented model leaves of the held-out gap, and its
    /// structure (the basis of `other`).
    pub remaining: Remaining,
    /// The fitted stiffness ratios of the reported model with their 95%
    /// intervals (empty for `none` and `unidentifiable`).
    pub ratios: Vec<super::ratios::Ratio>,
    /// What the verdict's confidence rests on that the data do not give
    /// (an assumed noise).
    pub assumptions: Vec<String>,
}

impl Outcome {
    /// Indices of held-out cells.
    pub fn heldout_cells(&self) -> Vec<usize> {
        let cells = &self.sim.cells;
        (0..cells.len())
            .filter(|&c| self.design.holds_out(cells[c].case, cells[c].level))
            .collect()
    }

    /// The augmented fit: the reported pair of effects, else the chosen
    /// family (the baseline when nothing is chosen).
    pub fn augmented(&self) -> &Fitted {
        if let Some(p) = self.chosen_pair.and_then(|p| self.pairs.get(p)) {
            return &p.fit;
        }
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
            rmse(&self.sim, &self.baseline, &rot, true),
            rmse(&self.sim, self.augmented(), &rot, true),
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
            rmse(&self.sim, &self.baseline, &tr, true),
            rmse(&self.sim, self.augmented(), &tr, true),
        ))
    }

    /// Cells of the baseline's held-out gap, by share of its chi-square.
    pub fn gap_cells(&self, exp: &Experiment) -> Vec<GapCell> {
        let cells = self.heldout_cells();
        let w = self.noise;
        let total: f64 = cells
            .iter()
            .map(|&c| {
                (self.baseline.heldout_residual(&self.sim, c) * w.cell(&self.sim.cells[c])).powi(2)
            })
            .sum();
        let mut out: Vec<GapCell> = cells
            .iter()
            .map(|&c| {
                let cell = &self.sim.cells[c];
                let r = self.baseline.heldout_residual(&self.sim, c);
                let l = &self.sim.levels[cell.level];
                GapCell {
                    upper: l.level.upper_body.clone(),
                    lower: l.level.lower_body.clone(),
                    level: l.level.name.clone(),
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
        let sq = |c: usize| {
            (self.baseline.heldout_residual(&self.sim, c) * w.cell(&self.sim.cells[c])).powi(2)
        };
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
        agg("by_level", &|c| {
            sim.levels[sim.cells[c].level].level.name.clone()
        });
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
        tables.insert(
            "by_sign_parity".to_string(),
            self.sign_parity(&cells, total),
        );
        tables
    }

    /// The odd part `(r+ - r-)/2` and even part `(r+ + r-)/2` of the
    /// baseline's held-out residuals over +/- pairs of cases (same axis,
    /// magnitude and follower load), and the unpaired rest, as shares of
    /// the held-out chi-square `total`.
    fn sign_parity(&self, cells: &[usize], total: f64) -> Vec<Share> {
        let (sim, info, w) = (&self.sim, &self.design.cases, self.noise);
        let sq =
            |c: usize| (self.baseline.heldout_residual(sim, c) * w.cell(&sim.cells[c])).powi(2);
        let (mut odd, mut even, mut unpaired) = (0.0, 0.0, 0.0);
        for &c in cells {
            let cell = &sim.cells[c];
            let ic = &info[cell.case];
            if ic.axis.is_none() {
                unpaired += sq(c) / total;
                continue;
            }
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
                    let rp = self.baseline.heldout_residual(sim, c) * wd;
                    let rm = self.baseline.heldout_residual(sim, o) * wd;
                    // r+^2 + r-^2 = 2 odd^2 + 2 even^2
                    odd += 2.0 * ((rp - rm) / 2.0).powi(2) / total;
                    even += 2.0 * ((rp + rm) / 2.0).powi(2) / total;
                }
                Some(_) => {}
                None => unpaired += sq(c) / total,
            }
        }
        [("odd", odd), ("even", even), ("unpaired", unpaired)]
            .map(|(key, share)| Share {
                key: key.into(),
                share,
            })
            .to_vec()
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
                let b = rmse(&self.sim, &self.baseline, &cs, true);
                let a = rmse(&self.sim, aug, &cs, true);
                out.push(LevelDofRmse {
                    level: l.level.name.clone(),
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
