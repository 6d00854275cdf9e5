//! Fitting a candidate family on the training cells: weighted least
//! squares by the bounded Levenberg-Marquardt of `util::lm`, with a
//! forward-difference Jacobian (the families move joint frames and
//! follower-load guide points, so the generic route through the predicted
//! increments is used; columns are evaluated in parallel, each from the
//! current equilibria as warm starts).

use super::family::{Family, Kind};
use super::sim::{Sim, Warm};
use crate::error::Result;
use crate::util::lm::{self, LmOptions};
use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

/// Weights of the residuals: `1/sigma` for rotations (1/deg) and translations (1/mm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Weights {
    /// Weight of a rotation residual (1/deg).
    pub rot: f64,
    /// Weight of a translation residual (1/mm).
    pub trans: f64,
}

impl Weights {
    /// Weight of a DoF.
    pub fn of(&self, dof: usize) -> f64 {
        if dof < 3 {
            self.rot
        } else {
            self.trans
        }
    }

    /// Weight of a cell: `1 / sd` of its stated SD, else its class's weight.
    pub fn cell(&self, c: &super::sim::Cell) -> f64 {
        match c.sd {
            Some(s) if s > 0.0 => 1.0 / s,
            _ => self.of(c.dof),
        }
    }
}

/// A fitted family.
#[derive(Debug, Clone)]
pub struct Fitted {
    /// The family fitted.
    pub family: Family,
    /// Best parameters.
    pub x: Vec<f64>,
    /// Predictions of every row of every case (report units).
    pub pred: Vec<[f64; 6]>,
    /// LM iterations.
    pub iterations: usize,
    /// Parameters on a bound at the end.
    pub at_bound: usize,
    /// Out-of-fold predictions of every row (K-fold designs: each row
    /// predicted by the fit of the fold that held it out); `None` for a
    /// single split, whose held-out cases `pred` already predicts unseen.
    pub heldout_pred: Option<Vec<[f64; 6]>>,
    /// Standard error of each parameter at the fit (Gauss-Newton:
    /// `sqrt(diag((J^T J)^-1))` of the weighted residuals, i.e. under the
    /// fit's noise weights; NaN where the data do not determine it).
    pub se: Vec<f64>,
}

impl Fitted {
    /// Residual (predicted - measured, report units) of a cell.
    pub fn residual(&self, sim: &Sim, cell: usize) -> f64 {
        let c = &sim.cells[cell];
        self.pred[c.row][c.dof] - c.measured
    }

    /// Residual of a held-out cell as predicted without it (out of fold).
    pub fn heldout_residual(&self, sim: &Sim, cell: usize) -> f64 {
        let c = &sim.cells[cell];
        let pred = self.heldout_pred.as_ref().unwrap_or(&self.pred);
        pred[c.row][c.dof] - c.measured
    }
}

/// Finite-difference step of parameter `j`.
fn fd_step(f: &Family, j: usize) -> f64 {
    1e-5 * ((f.hi[j] - f.lo[j]) * 0.5).max(1e-3)
}

/// Fit `family` on the training cells (indices into `sim.cells`) of the
/// training cases, then predict every case.
pub fn fit(
    sim: &Sim,
    family: Family,
    train_cells: &[usize],
    train_cases: &[usize],
    w: Weights,
    max_iterations: usize,
) -> Result<Fitted> {
    let mut warm: Warm = sim.warm();
    let resid = |pred: &[[f64; 6]]| -> DVector<f64> {
        DVector::from_iterator(
            train_cells.len(),
            train_cells.iter().map(|&ci| {
                let c = &sim.cells[ci];
                (pred[c.row][c.dof] - c.measured) * w.cell(c)
            }),
        )
    };
    let f = |x: &[f64], jac: bool| -> Result<(DVector<f64>, Option<DMatrix<f64>>)> {
        let sys = family.system(sim, x)?;
        let pred = sim.predict(&sys, train_cases, &mut warm)?;
        let r = resid(&pred);
        if !jac {
            return Ok((r, None));
        }
        let base_warm = warm.clone();
        let cols: Vec<Result<DVector<f64>>> = (0..x.len())
            .into_par_iter()
            .map(|j| {
                let h = fd_step(&family, j);
                let mut xp = x.to_vec();
                // step inwards when at the upper bound
                let h = if xp[j] + h > family.hi[j] { -h } else { h };
                xp[j] += h;
                let sys = family.system(sim, &xp)?;
                let mut wj = base_warm.clone();
                let pj = sim.predict(&sys, train_cases, &mut wj)?;
                Ok((resid(&pj) - &r) / h)
            })
            .collect();
        let mut jm = DMatrix::zeros(r.len(), x.len());
        for (j, c) in cols.into_iter().enumerate() {
            jm.set_column(j, &c?);
        }
        Ok((r, Some(jm)))
    };
    let opts = LmOptions {
        max_iterations,
        gtol: 1e-8,
        xtol: 1e-7,
        ftol: 1e-7,
        ..LmOptions::default()
    };
    let res = lm::minimize(f, &family.x0, &family.lo, &family.hi, &opts)?;
    let se = standard_errors(&res.jac);
    let sys = family.system(sim, &res.x)?;
    let all: Vec<usize> = (0..sim.loads.len()).collect();
    let mut wa = sim.warm();
    let pred = sim.predict(&sys, &all, &mut wa)?;
    Ok(Fitted {
        at_bound: res.at_bound.iter().filter(|b| **b).count(),
        family,
        x: res.x,
        pred,
        iterations: res.iterations,
        heldout_pred: None,
        se,
    })
}

/// Parameter standard errors from the weighted residuals' Jacobian:
/// `sqrt(diag((J^T J)^-1))`, NaN for all when `J^T J` is singular.
pub fn standard_errors(jac: &DMatrix<f64>) -> Vec<f64> {
    let n = jac.ncols();
    let jtj = jac.transpose() * jac;
    match jtj.try_inverse() {
        Some(c) => (0..n)
            .map(|i| {
                if c[(i, i)] >= 0.0 {
                    c[(i, i)].sqrt()
                } else {
                    f64::NAN
                }
            })
            .collect(),
        None => vec![f64::NAN; n],
    }
}

/// The kinds fitted first (in parallel); the pose family with offsets
/// and the local variants start from their results (see `select`).
/// Preload only with follower loads. A published-table design
/// (leave-one-level-out, `table`) fits only the families whose
/// parameters are shared by the levels or follow a trend along the spine
/// (a per-level parameter of a level held out is never seen), and drops
/// the effects in `untestable`.
pub fn kinds(has_follower: bool, table: Option<&[String]>) -> Vec<Kind> {
    if let Some(untestable) = table {
        let testable = |k: &Kind| !untestable.iter().any(|e| e == k.effect().name());
        let mut k: Vec<Kind> = [
            Kind::LevelTrend,
            Kind::NonlinearSinh,
            Kind::NonlinearCubic,
            Kind::AsymmetricBilinear,
            Kind::CoupledUniform,
        ]
        .into_iter()
        .filter(testable)
        .collect();
        if has_follower {
            k.push(Kind::Preload);
        }
        return k;
    }
    let mut k = vec![
        Kind::LevelScalar,
        Kind::LevelPerDof,
        Kind::NonlinearSinh,
        Kind::NonlinearCubic,
        Kind::AsymmetricBilinear,
        Kind::CoupledUniform,
        Kind::CoupledPerLevel,
        Kind::JointRotation,
    ];
    if has_follower {
        k.push(Kind::Preload);
    }
    k
}

/// The level whose per-level block matters most in a fitted per-level
/// family: the one whose block, reset to zero, raises the training sum of
/// squares most.
pub fn dominant_level(
    sim: &Sim,
    f: &Fitted,
    train_cells: &[usize],
    train_cases: &[usize],
    per: usize,
) -> Result<usize> {
    let mut best = (0usize, f64::NEG_INFINITY);
    let mut warm = sim.warm();
    for li in 0..sim.levels.len() {
        let mut x = f.x.clone();
        for k in 0..per {
            if let Some(v) = x.get_mut(3 + per * li + k) {
                *v = 0.0;
            }
        }
        let sys = f.family.system(sim, &x)?;
        let pred = sim.predict(&sys, train_cases, &mut warm)?;
        let sse: f64 = train_cells
            .iter()
            .map(|&ci| {
                let c = &sim.cells[ci];
                (pred[c.row][c.dof] - c.measured).powi(2)
            })
            .sum();
        if sse > best.1 {
            best = (li, sse);
        }
    }
    Ok(best.0)
}
