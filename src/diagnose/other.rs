//! What the chosen model leaves of the held-out gap, and its structure:
//! the basis of the `other` verdict (something outside the vocabulary).
//!
//! The remaining held-out residuals `r` (noise units, each predicted by a
//! fit that never saw it) are tested against the noise: `sum r^2` against
//! a chi-square with one degree of freedom per cell. That test is only as
//! good as the noise estimate, and a noise estimated from the residuals of
//! a wrong model is inflated by its misfit; so the held-out and the
//! training residuals are also tested for **structure**: for each
//! grouping of the cells (by level, DoF, load axis, direction, load,
//! level and DoF, the DoF against the load axis with the residual times
//! the load's sign, the case, and the quarter of the protocol), whether
//! the group means are zero, by the F statistic
//! `F = (sum_g n_g m_g^2 / G) / (sum (r - m_g)^2 / (n - G))`, and how much
//! of the residuals the group means carry, the misfit ratio
//! `(sum r^2 / n) / (sum (r - m_g)^2 / (n - G))`; neither depends on the
//! noise scale. The smallest p-value (times the number of groupings) is
//! the structure's. A grouping counts only when its group means are also
//! significant against the noise (`sum n_g m_g^2` against a chi-square
//! with `G` dof): a deterministic pattern far below a stated noise is no
//! evidence of anything.

use super::design::{Design, AXIS_NAMES};
use super::fit::{Fitted, Weights};
use super::sim::Sim;
use crate::calibrate::experiment::DOF_NAMES;
use serde::Serialize;
use statrs::distribution::{ChiSquared, ContinuousCDF, FisherSnedecor};
use std::collections::BTreeMap;

/// One group of a grouping of the remaining residuals.
#[derive(Debug, Clone, Serialize)]
pub struct Group {
    /// The group's value of the grouping (a level, a DoF, ...).
    pub key: String,
    /// Number of residuals in the group.
    pub cells: usize,
    /// Mean residual (predicted - measured) in noise units (times the
    /// load's sign for the sign-aligned groupings).
    pub mean: f64,
    /// Share of the residuals' sum of squares carried by the group's mean
    /// (`n_g m_g^2 / sum r^2`).
    pub share: f64,
}

/// The structure of residuals under one grouping.
#[derive(Debug, Clone, Serialize)]
pub struct Structure {
    /// The grouping (`level`, `dof`, ...).
    pub by: String,
    /// `held_out` or `training` residuals.
    pub cells: &'static str,
    /// F statistic of the group means against the scatter within the groups.
    pub f: f64,
    /// p-value of zero group means against the scatter within the groups.
    pub p: f64,
    /// p-value of zero group means against the noise (the group means'
    /// chi-square `sum n_g m_g^2` against a chi-square with `G` dof).
    pub p_noise: f64,
    /// Mean square of the residuals over the mean square left within the
    /// groups (`(sum r^2 / n) / (sum (r - m_g)^2 / (n - G))`): about 1 for
    /// noise, large when the group means carry the residuals; it does not
    /// depend on the noise estimate.
    pub misfit: f64,
    /// Groups, the largest share first.
    pub groups: Vec<Group>,
}

/// What the chosen model leaves of the held-out gap.
#[derive(Debug, Clone, Serialize)]
pub struct Remaining {
    /// The model (family label, `baseline` when nothing was added).
    pub model: String,
    /// Number of held-out residuals.
    pub cells: usize,
    /// Held-out chi-square and its reduced value.
    pub chi2: f64,
    /// `chi2 / max(cells, 1)`.
    pub reduced_chi2: f64,
    /// P(chi-square of `cells` dof >= `chi2`): small when the remaining
    /// gap is above the noise.
    pub p_noise: f64,
    /// The baseline's held-out chi-square, and P(chi-square of `cells`
    /// dof >= it): small when the design sees a gap at all.
    pub baseline_chi2: f64,
    /// P(chi-square of `cells` dof >= `baseline_chi2`).
    pub baseline_p_noise: f64,
    /// Fraction of the baseline's held-out chi-square the model closes.
    pub closed: f64,
    /// Every grouping of the held-out and of the training residuals, the
    /// most significant first.
    pub structure: Vec<Structure>,
    /// The noise of the residuals was stated or assumed (not estimated
    /// from the residuals): group means must also stand out against it.
    pub noise_given: bool,
}

impl Remaining {
    /// The largest misfit ratio of the significant groupings of one set of
    /// residuals (`held_out` or `training`), as [`Remaining::structured_misfit`].
    pub fn misfit_of(&self, alpha: f64, cells: &str) -> f64 {
        let n = self.structure.len().max(1) as f64;
        self.structure
            .iter()
            .filter(|s| {
                s.cells == cells && s.p * n < alpha && (!self.noise_given || s.p_noise * n < alpha)
            })
            .map(|s| s.misfit)
            .fold(1.0, f64::max)
    }

    /// [`Remaining::structured_misfit`] with this outcome's noise.
    pub fn misfit(&self, alpha: f64) -> f64 {
        self.structured_misfit(alpha, self.noise_given)
    }
}

impl Remaining {
    /// The structure's p-value: the smallest over the groupings, times
    /// their number (Bonferroni).
    pub fn p_structure(&self) -> f64 {
        let n = self.structure.len().max(1) as f64;
        self.structure
            .first()
            .map(|s| (s.p * n).min(1.0))
            .unwrap_or(1.0)
    }

    /// The largest misfit ratio among the significant groupings (group
    /// means significant against the scatter within the groups and, when
    /// `against_noise`, against the noise too; p below `alpha` after the
    /// Bonferroni factor), 1 without one. A noise estimated from the
    /// residuals of a wrong model is inflated by its misfit, so only a
    /// stated or assumed noise is a fair second test.
    pub fn structured_misfit(&self, alpha: f64, against_noise: bool) -> f64 {
        let n = self.structure.len().max(1) as f64;
        self.structure
            .iter()
            .filter(|s| s.p * n < alpha && (!against_noise || s.p_noise * n < alpha))
            .map(|s| s.misfit)
            .fold(1.0, f64::max)
    }
}

/// A grouping: its name, the key of a cell, and whether the residual is
/// multiplied by the load's sign (a response odd in the load).
type Grouping = (&'static str, String, bool);

/// The key of a cell under each grouping.
fn keys(sim: &Sim, design: &Design, c: usize) -> Vec<Grouping> {
    let cell = &sim.cells[c];
    let info = &design.cases[cell.case];
    let level = sim.levels[cell.level].level.name.clone();
    let dof = DOF_NAMES[cell.dof];
    let axis = info.axis.map(|a| AXIS_NAMES[a]).unwrap_or("none");
    let sign = match info.sign {
        1 => "positive",
        -1 => "negative",
        _ => "none",
    };
    // the protocol in quarters (case order of the experiment file)
    let quarter = 4 * cell.case / design.cases.len().max(1);
    let load = format!("{} N m, follower {} N", info.magnitude, info.follower);
    vec![
        ("level", level.clone(), false),
        ("dof", dof.to_string(), false),
        ("load_axis", axis.to_string(), false),
        ("direction", sign.to_string(), false),
        ("load", load, false),
        ("level_dof", format!("{level} {dof}"), false),
        (
            "dof_by_load_axis_sign_aligned",
            format!("{axis}: {dof}"),
            true,
        ),
        ("case", design.cases[cell.case].id.clone(), false),
        ("protocol_quarter", format!("Q{}", quarter + 1), false),
    ]
}

/// The structure under one grouping of residuals `r` (keys `k`).
fn structure(by: &str, cells: &'static str, r: &[f64], k: &[String]) -> Structure {
    let mut groups: BTreeMap<&str, (usize, f64)> = BTreeMap::new();
    for (x, key) in r.iter().zip(k) {
        let g = groups.entry(key.as_str()).or_insert((0, 0.0));
        g.0 += 1;
        g.1 += x;
    }
    let total: f64 = r.iter().map(|x| x * x).sum::<f64>().max(1e-300);
    let mut out: Vec<Group> = groups
        .iter()
        .map(|(key, (n, s))| {
            let mean = s / *n as f64;
            Group {
                key: key.to_string(),
                cells: *n,
                mean,
                share: *n as f64 * mean * mean / total,
            }
        })
        .collect();
    let between: f64 = out.iter().map(|g| g.share * total).sum();
    let (g, n) = (out.len() as f64, r.len() as f64);
    let within = (total - between).max(1e-300);
    let dof = n - g;
    let (f, p, misfit) = if dof >= 1.0 {
        let f = (between / g) / (within / dof);
        let p = FisherSnedecor::new(g, dof).map(|d| d.sf(f)).unwrap_or(1.0);
        (f, p, (total / n) / (within / dof))
    } else {
        (0.0, 1.0, 1.0)
    };
    let p_noise = ChiSquared::new(g).map(|d| d.sf(between)).unwrap_or(1.0);
    out.sort_by(|a, b| b.share.total_cmp(&a.share).then(a.key.cmp(&b.key)));
    Structure {
        by: by.to_string(),
        cells,
        f,
        p,
        p_noise,
        misfit,
        groups: out,
    }
}

/// Every grouping's structure of the residuals `r` of `cells`.
fn structures(
    sim: &Sim,
    design: &Design,
    cells: &[usize],
    r: &[f64],
    what: &'static str,
) -> Vec<Structure> {
    let all_keys: Vec<Vec<Grouping>> = cells.iter().map(|&c| keys(sim, design, c)).collect();
    let n_groupings = all_keys.first().map(Vec::len).unwrap_or(0);
    (0..n_groupings)
        .map(|i| {
            let k: Vec<String> = all_keys.iter().map(|ks| ks[i].1.clone()).collect();
            let aligned: Vec<f64> = r
                .iter()
                .zip(cells)
                .zip(&all_keys)
                .map(|((x, &c), ks)| {
                    let sign = design.cases[sim.cells[c].case].sign;
                    if ks[i].2 && sign != 0 {
                        x * sign as f64
                    } else {
                        *x
                    }
                })
                .collect();
            structure(all_keys[0][i].0, what, &aligned, &k)
        })
        .filter(|s| s.groups.len() >= 2)
        .collect()
}

/// What `f` leaves of the held-out gap (`heldout` cells, weights `w`),
/// against the baseline's held-out chi-square `chi_b`, and the structure
/// of its held-out and training (`train` cells) residuals.
pub fn remaining(
    sim: &Sim,
    design: &Design,
    (train, heldout): (&[usize], &[usize]),
    (w, noise_given): (Weights, bool),
    f: &Fitted,
    chi_b: f64,
) -> Remaining {
    let res = |cells: &[usize], held: bool| -> Vec<f64> {
        cells
            .iter()
            .map(|&c| super::gap::residual(sim, f, c, held) * w.cell(&sim.cells[c]))
            .collect()
    };
    let r = res(heldout, true);
    let chi2: f64 = r.iter().map(|x| x * x).sum();
    let n = r.len().max(1);
    let sf = |x: f64| ChiSquared::new(n as f64).map(|d| d.sf(x)).unwrap_or(1.0);
    let mut all = structures(sim, design, heldout, &r, "held_out");
    all.extend(structures(
        sim,
        design,
        train,
        &res(train, false),
        "training",
    ));
    all.sort_by(|a, b| a.p.total_cmp(&b.p).then(a.by.cmp(&b.by)));
    Remaining {
        model: f.family.label(),
        cells: r.len(),
        chi2,
        reduced_chi2: chi2 / n as f64,
        p_noise: sf(chi2),
        baseline_chi2: chi_b,
        baseline_p_noise: sf(chi_b),
        closed: if chi_b > 0.0 { 1.0 - chi2 / chi_b } else { 0.0 },
        structure: all,
        noise_given,
    }
}

#[cfg(test)]
mod tests {
    use super::structure;

    #[test]
    fn structure_finds_a_shifted_group_and_not_noise() {
        // alternating noise of unit size: no group differs
        let r: Vec<f64> = (0..40)
            .map(|i| if i % 2 == 0 { 1.0 } else { -1.0 })
            .collect();
        let k: Vec<String> = (0..40).map(|i| format!("g{}", i / 10)).collect();
        let s = structure("level", "held_out", &r, &k);
        assert!(s.p > 0.5, "{}", s.p);
        // the third group shifted by 3: found, with most of the share
        let r2: Vec<f64> = r
            .iter()
            .enumerate()
            .map(|(i, x)| if i / 10 == 2 { x + 3.0 } else { *x })
            .collect();
        let s2 = structure("level", "held_out", &r2, &k);
        assert!(s2.p < 1e-6, "{}", s2.p);
        assert_eq!(s2.groups[0].key, "g2");
        assert!((s2.groups[0].mean - 3.0).abs() < 1e-12);
        // noise: misfit ratio about 1; the shift: mean square 1 + 9/4 over 1
        assert!(s.misfit < 1.2, "{}", s.misfit);
        assert!(
            (s2.misfit - 3.25 * 36.0 / 40.0).abs() < 1e-9,
            "{}",
            s2.misfit
        );
    }
}
