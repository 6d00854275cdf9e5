//! Validation of a calibration (thesis 4.2.6): leave-one-case-out (refit
//! without a case, predict it) and leave-one-specimen-out (predict each
//! specimen with the median parameters of the others' calibrations), both
//! reported as RMSE and normalised RMSE (RMSE / range of the measured
//! values) per level and DoF over the held-out predictions.

use super::fit::{self, error_table, ErrorTable, FitOptions};
use super::problem::Problem;
use crate::error::{Error, Result};
use rayon::prelude::*;
use serde::Serialize;
use std::sync::Arc;

/// One held-out case.
#[derive(Debug, Clone, Serialize)]
pub struct HeldOutCase {
    /// Id of the held-out load case.
    pub case: String,
    /// Parameters fitted without the case.
    pub params: Vec<f64>,
    /// Weighted cost of the held-out case's cells at those parameters.
    pub cost: f64,
}

/// Leave-one-case-out result.
#[derive(Debug, Clone, Serialize)]
pub struct LeaveOneCaseOut {
    /// One entry per held-out case.
    pub cases: Vec<HeldOutCase>,
    /// Errors of the held-out predictions per level (pair) and DoF.
    pub errors: ErrorTable,
}

/// Leave-one-case-out: for every case with measurements, calibrate on the
/// other cases (LM from `start`, single start: the full-data optimum is a
/// good start for the reduced problem) and predict the held-out case.
pub fn leave_one_case_out(
    pb: &Problem,
    start: &[f64],
    opts: &FitOptions,
) -> Result<LeaveOneCaseOut> {
    let used: Vec<usize> = (0..pb.exp.cases.len())
        .filter(|&c| pb.cells.iter().any(|cell| cell.case == c))
        .collect();
    if used.len() < 2 {
        return Err(Error::invalid(
            "leave-one-case-out",
            "needs at least two load cases with measurements",
        ));
    }
    let run = |&c: &usize| -> Result<(HeldOutCase, Vec<[f64; 6]>)> {
        let sub = Arc::new(pb.exp.subset(|i| i != c));
        let sub_pb =
            Problem::with_system(sub, pb.family.clone(), pb.opts.clone(), pb.system().clone())?;
        let mut ev = sub_pb.evaluator();
        let res = fit::fit_from(&sub_pb, &mut ev, start, &opts.lm)?;
        let params = sub_pb.values_of(&res.x);
        let mut full = pb.evaluator();
        let pred = full.predict(pb, &params)?;
        let cost = pb
            .cells
            .iter()
            .filter(|cell| cell.case == c)
            .map(|cell| (cell.sqrt_w * (pred[cell.row][cell.dof] - cell.measured)).powi(2))
            .sum();
        Ok((
            HeldOutCase {
                case: pb.exp.cases[c].id.clone(),
                params,
                cost,
            },
            pred,
        ))
    };
    let results: Vec<Result<(HeldOutCase, Vec<[f64; 6]>)>> = if opts.parallel {
        used.par_iter().map(run).collect()
    } else {
        used.iter().map(run).collect()
    };
    let mut cases = Vec::new();
    // held-out prediction of each row comes from the fit without its case
    let mut pred = vec![[0.0; 6]; pb.exp.rows.len()];
    for (k, r) in results.into_iter().enumerate() {
        let (h, p) = r?;
        let c = used[k];
        for (ri, row) in pb.exp.rows.iter().enumerate() {
            if row.case == c {
                pred[ri] = p[ri];
            }
        }
        cases.push(h);
    }
    Ok(LeaveOneCaseOut {
        cases,
        errors: error_table(pb, &pred, |_| true),
    })
}

/// One held-out specimen.
#[derive(Debug, Clone, Serialize)]
pub struct HeldOutSpecimen {
    /// Name of the held-out specimen's experiment.
    pub experiment: String,
    /// Median of the other specimens' calibrated parameters.
    pub params: Vec<f64>,
    /// Errors of its predictions at those parameters, per level (pair) and DoF.
    pub errors: ErrorTable,
}

/// Leave-one-specimen-out over calibrated specimens `(problem, best
/// parameters)`; every problem must have the same parameter names.
pub fn leave_one_specimen_out(items: &[(Problem, Vec<f64>)]) -> Result<Vec<HeldOutSpecimen>> {
    if items.len() < 2 {
        return Err(Error::invalid(
            "leave-one-specimen-out",
            "needs at least two experiments",
        ));
    }
    let names = |pb: &Problem| -> Vec<String> {
        pb.family.params().iter().map(|p| p.name.clone()).collect()
    };
    let first = names(&items[0].0);
    for (pb, _) in items.iter().skip(1) {
        if names(pb) != first {
            return Err(Error::invalid(
                "leave-one-specimen-out",
                format!(
                    "experiment {} has parameters [{}], the first has [{}]: the specimens must share the parameterisation (same levels)",
                    pb.exp.name,
                    names(pb).join(", "),
                    first.join(", ")
                ),
            ));
        }
    }
    let mut out = Vec::new();
    for (i, (pb, _)) in items.iter().enumerate() {
        let params: Vec<f64> = (0..first.len())
            .map(|k| {
                let v: Vec<f64> = items
                    .iter()
                    .enumerate()
                    .filter(|(j, _)| *j != i)
                    .filter_map(|(_, (_, p))| p.get(k).copied())
                    .collect();
                crate::util::median(&v).unwrap_or(f64::NAN)
            })
            .collect();
        let mut ev = pb.evaluator();
        let pred = ev.predict(pb, &params)?;
        out.push(HeldOutSpecimen {
            experiment: pb.exp.name.clone(),
            params,
            errors: error_table(pb, &pred, |_| true),
        });
    }
    Ok(out)
}
