//! The arithmetic of the held-out gap: a cell's residual (held out:
//! predicted by a fit that never saw the cell, out of fold in a K-fold
//! design), chi-square and RMSE over cells, the rotation cells. Where the
//! gap sits is [`super::outcome`]'s.

use super::fit::{Fitted, Weights};
use super::sim::Sim;

/// Residual of cell `c`: the held-out one (predicted without the cell)
/// when `held`, else the fit's own.
pub fn residual(sim: &Sim, f: &Fitted, c: usize, held: bool) -> f64 {
    if held {
        f.heldout_residual(sim, c)
    } else {
        f.residual(sim, c)
    }
}

/// Weighted sum of squares over `cells` (held-out residuals when `held`).
pub fn chi2_of(sim: &Sim, f: &Fitted, cells: &[usize], w: Weights, held: bool) -> f64 {
    cells
        .iter()
        .map(|&c| (residual(sim, f, c, held) * w.cell(&sim.cells[c])).powi(2))
        .sum()
}

/// RMSE (report units) over `cells` (held-out residuals when `held`).
pub fn rmse(sim: &Sim, f: &Fitted, cells: &[usize], held: bool) -> f64 {
    if cells.is_empty() {
        return f64::NAN;
    }
    let ss: f64 = cells
        .iter()
        .map(|&c| residual(sim, f, c, held).powi(2))
        .sum();
    (ss / cells.len() as f64).sqrt()
}

/// The rotational cells among `cells`.
pub fn rotations(sim: &Sim, cells: &[usize]) -> Vec<usize> {
    cells
        .iter()
        .copied()
        .filter(|&c| sim.cells[c].dof < 3)
        .collect()
}
