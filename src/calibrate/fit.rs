//! Calibration: multi-start Levenberg-Marquardt on the log-parameters of a
//! [`Problem`] from a seeded Latin hypercube over the bounds, clustering of
//! the local minima, and the statistics of the best one (covariance,
//! correlations, confidence intervals, condition number, poorly determined
//! parameters with the singular directions that explain them).

use super::experiment::DOF_NAMES;
use super::family::{ParamInfo, Scale};
use super::lhs;
use super::problem::{Evaluator, Predictions, Problem};
use crate::error::{Error, Result};
use crate::util::lm::{self, LmOptions, LmStop};
use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;
use serde::Serialize;
use std::collections::BTreeMap;

/// Options of a calibration.
#[derive(Debug, Clone)]
pub struct FitOptions {
    /// Number of starts (the first is the nominal model when `nominal_start`).
    pub starts: usize,
    /// Also start from the nominal model (clamped into the bounds).
    pub nominal_start: bool,
    /// Seed of the Latin hypercube.
    pub seed: u64,
    /// LM settings.
    pub lm: LmOptions,
    /// Show a progress bar on stderr.
    pub progress: bool,
    /// Parallel starts (rayon; the thread count is the caller's pool).
    pub parallel: bool,
}

impl Default for FitOptions {
    fn default() -> Self {
        FitOptions {
            starts: 16,
            nominal_start: true,
            seed: 1,
            lm: LmOptions::default(),
            progress: false,
            parallel: true,
        }
    }
}

/// One start of the multi-start.
#[derive(Debug, Clone, Serialize)]
pub struct StartResult {
    /// Start point (natural units).
    pub start: Vec<f64>,
    /// End point (natural units); empty when the start failed.
    pub params: Vec<f64>,
    /// Cost `sum r^2` (thesis Eqn 3.1) at the end point.
    pub cost: f64,
    /// Levenberg-Marquardt iterations (accepted and rejected).
    pub iterations: usize,
    /// Residual evaluations of this start.
    pub evaluations: usize,
    /// Why the iteration stopped; `None` when the start failed.
    pub stop: Option<LmStop>,
    /// Projected gradient inf-norm at the end point (log-parameters).
    pub grad_inf: f64,
    /// Ended at a first-order point (small projected gradient); a start that
    /// did not (e.g. stalled where trial points have no equilibrium) is kept
    /// in the record but is not a local minimum.
    pub converged: bool,
    /// Index of the local minimum it reached.
    pub minimum: Option<usize>,
    /// The error message when the start failed.
    pub error: Option<String>,
}

/// A distinct local minimum (parameters differing by more than 1% relative
/// from every other one).
#[derive(Debug, Clone, Serialize)]
pub struct LocalMinimum {
    /// Parameters (natural units).
    pub params: Vec<f64>,
    /// Cost `sum r^2` there.
    pub cost: f64,
    /// Starts that ended here.
    pub starts: Vec<usize>,
}

/// Statistics of one parameter at the best minimum.
#[derive(Debug, Clone, Serialize)]
pub struct ParamEstimate {
    /// Parameter name (see [`ParamInfo::name`]).
    pub name: String,
    /// Unit of the value, e.g. `N*m/rad`.
    pub unit: String,
    /// Fitted value.
    pub value: f64,
    /// Value of the nominal model.
    pub nominal: f64,
    /// Lower bound of the fit.
    pub lower: f64,
    /// Upper bound of the fit.
    pub upper: f64,
    /// The scale the parameter is fitted on (`log`: stiffness values;
    /// `log1p`: stiffening; `linear`: coupling correlations).
    pub scale: Scale,
    /// Standard deviation on the fitting scale for `log` (SD of `ln p`,
    /// i.e. relative) and `log1p` (SD of `ln(1 + p)`) parameters, `sd / |p|`
    /// for linear-scale ones.
    pub rel_sd: f64,
    /// Standard deviation in the parameter's unit, first order.
    pub sd: f64,
    /// 95% confidence interval (t distribution on the fitting scale:
    /// multiplicative for `log`, multiplicative on `1 + p` for `log1p`,
    /// additive for `linear` parameters).
    pub ci95: [f64; 2],
    /// The value lies on a bound (within 1e-9 on the fitting scale).
    pub at_bound: bool,
}

/// A weakly determined direction of parameter space.
#[derive(Debug, Clone, Serialize)]
pub struct WeakDirection {
    /// Singular value of the weighted Jacobian (log-parameters).
    pub singular_value: f64,
    /// Relative to the largest.
    pub relative: f64,
    /// Parameters with |loading| >= 0.2, largest first.
    pub loadings: Vec<(String, f64)>,
}

/// A parameter the data do not determine well, and why.
#[derive(Debug, Clone, Serialize)]
pub struct PoorlyDetermined {
    /// Parameter name.
    pub name: String,
    /// Why it is poorly determined.
    pub reason: String,
}

/// Identifiability summary.
#[derive(Debug, Clone, Serialize)]
pub struct Identifiability {
    /// Largest / smallest singular value of the weighted log-parameter Jacobian.
    pub condition_number: f64,
    /// Singular values of that Jacobian, largest first.
    pub singular_values: Vec<f64>,
    /// Directions with relative singular value below 1e-3.
    pub weak_directions: Vec<WeakDirection>,
    /// Parameters the data do not determine well.
    pub poorly_determined: Vec<PoorlyDetermined>,
}

/// A finished calibration.
#[derive(Debug, Clone, Serialize)]
pub struct Calibration {
    /// Label of the stiffness parameterisation.
    pub family: String,
    /// Parameter names, in the order of every parameter vector.
    pub param_names: Vec<String>,
    /// Best parameters (natural units).
    pub best: Vec<f64>,
    /// Cost `sum_i w_i (p_i - m_i)^2` at the best parameters (SI units).
    pub cost: f64,
    /// Number of residuals and of parameters.
    pub n_residuals: usize,
    /// Number of parameters.
    pub n_params: usize,
    /// Residual variance `cost / (m - n)` (weighted units).
    pub s2: f64,
    /// Residual SD per DoF (rx..tz, SI; NaN when not in the cost), the
    /// noise level the covariance uses.
    pub residual_sd: [f64; 6],
    /// Statistics of each parameter at the best minimum.
    pub estimates: Vec<ParamEstimate>,
    /// Covariance of the fitting coordinates (log of stiffness values, linear-scale parameters as they are; the field keeps its historical name).
    pub covariance_log: Vec<Vec<f64>>,
    /// Correlation matrix of the fitting coordinates.
    pub correlation: Vec<Vec<f64>>,
    /// Conditioning of the weighted Jacobian and the weak directions.
    pub identifiability: Identifiability,
    /// Distinct local minima the starts reached.
    pub minima: Vec<LocalMinimum>,
    /// Every start of the multi-start.
    pub starts: Vec<StartResult>,
    /// Predicted increments of every row at the best parameters (SI).
    #[serde(skip)]
    pub predictions: Predictions,
    /// Total residual evaluations.
    pub evaluations: usize,
}

/// Start points (natural units): nominal (clamped) then Latin hypercube in log space.
fn start_points(pb: &Problem, opts: &FitOptions) -> Vec<Vec<f64>> {
    let (lo, hi) = pb.fit_bounds();
    let mut out = Vec::new();
    if opts.nominal_start && opts.starts > 0 {
        out.push(
            pb.family
                .params()
                .iter()
                .map(|p| p.nominal.clamp(p.lower, p.upper))
                .collect(),
        );
    }
    let n_lhs = opts.starts.saturating_sub(out.len());
    for x in lhs::in_box(n_lhs, &lo, &hi, opts.seed) {
        out.push(pb.values_of(&x));
    }
    out
}

/// Run LM from one start point (natural units).
pub fn fit_from(
    pb: &Problem,
    ev: &mut Evaluator,
    start: &[f64],
    lm_opts: &LmOptions,
) -> Result<lm::LmResult> {
    let (lo, hi) = pb.fit_bounds();
    let x0 = pb.fit_coords_of(start);
    lm::minimize(|x, j| ev.residuals(pb, x, j), &x0, &lo, &hi, lm_opts)
}

/// Check the problem before fitting: every case reaches equilibrium at the
/// start and every parameter moves at least one residual.
fn precheck(pb: &Problem, start: &[f64]) -> Result<()> {
    let mut ev = pb.evaluator();
    let x = pb.fit_coords_of(start);
    let (_, j) = ev.residuals(pb, &x, true).map_err(|e| {
        Error::numerical(
            format!("experiment {}", pb.exp.dir.display()),
            format!("the model at the start parameters cannot be solved: {e}"),
        )
    })?;
    let Some(j) = j else { return Ok(()) };
    let norms: Vec<f64> = (0..j.ncols()).map(|k| j.column(k).norm()).collect();
    let max = norms.iter().fold(0.0f64, |m, v| m.max(*v));
    let dead: Vec<String> = norms
        .iter()
        .enumerate()
        .filter(|(_, n)| **n <= 1e-12 * max.max(1e-300))
        .map(|(k, _)| pb.family.params()[k].name.clone())
        .collect();
    if !dead.is_empty() {
        return Err(Error::invalid(
            format!("experiment {}", pb.exp.dir.display()),
            format!(
                "parameter(s) {} affect no measured DoF in the cost (DoFs {}): measure those DoFs, add them with --dofs, or drop the parameters",
                dead.join(", "),
                pb.opts.dofs.iter().map(|&d| DOF_NAMES[d]).collect::<Vec<_>>().join(",")
            ),
        ));
    }
    Ok(())
}

/// Same minimum: fitting coordinates within `tol` (1% relative for
/// log-scale parameters, 1% on `1 + s` for stiffening, `tol` absolute for
/// correlations).
fn close(pb: &Problem, a: &[f64], b: &[f64], tol: f64) -> bool {
    let (xa, xb) = (pb.fit_coords_of(a), pb.fit_coords_of(b));
    xa.iter().zip(&xb).all(|(x, y)| (x - y).abs() <= tol)
}

/// Calibrate: multi-start LM, clustering, statistics at the best minimum.
pub fn calibrate(pb: &Problem, opts: &FitOptions) -> Result<Calibration> {
    let starts = start_points(pb, opts);
    if starts.is_empty() {
        return Err(Error::invalid("calibration", "--starts must be at least 1"));
    }
    precheck(pb, &starts[0])?;
    let bar = crate::util::progress::bar("calibrate", starts.len() as u64, "starts", opts.progress);
    let run = |s: &Vec<f64>| -> StartResult {
        let mut ev = pb.evaluator();
        let res = fit_from(pb, &mut ev, s, &opts.lm);
        bar.inc(1);
        match res {
            Ok(r) => StartResult {
                start: s.clone(),
                params: pb.values_of(&r.x),
                cost: 2.0 * r.cost,
                iterations: r.iterations,
                evaluations: ev.evaluations,
                stop: Some(r.stop),
                grad_inf: r.grad_inf,
                converged: r.converged(),
                minimum: None,
                error: None,
            },
            Err(e) => StartResult {
                start: s.clone(),
                params: Vec::new(),
                cost: f64::INFINITY,
                iterations: 0,
                evaluations: ev.evaluations,
                stop: None,
                grad_inf: f64::NAN,
                converged: false,
                minimum: None,
                error: Some(e.to_string()),
            },
        }
    };
    let mut results: Vec<StartResult> = if opts.parallel {
        starts.par_iter().map(run).collect()
    } else {
        starts.iter().map(run).collect()
    };
    bar.finish_and_clear();
    // cluster, best first
    // local minima: converged starts; if none converged, the best ends
    let mut order: Vec<usize> = (0..results.len())
        .filter(|&i| results[i].error.is_none() && results[i].converged)
        .collect();
    if order.is_empty() {
        order = (0..results.len())
            .filter(|&i| results[i].error.is_none())
            .collect();
    }
    if order.is_empty() {
        let msg = results
            .iter()
            .find_map(|r| r.error.clone())
            .unwrap_or_default();
        return Err(Error::numerical(
            "calibration",
            format!("every start failed; first error: {msg}"),
        ));
    }
    order.sort_by(|&a, &b| results[a].cost.total_cmp(&results[b].cost).then(a.cmp(&b)));
    let mut minima: Vec<LocalMinimum> = Vec::new();
    for &i in &order {
        let found = minima
            .iter()
            .position(|m| close(pb, &m.params, &results[i].params, 0.01));
        let k = match found {
            Some(k) => k,
            None => {
                minima.push(LocalMinimum {
                    params: results[i].params.clone(),
                    cost: results[i].cost,
                    starts: Vec::new(),
                });
                minima.len() - 1
            }
        };
        minima[k].starts.push(i);
        results[i].minimum = Some(k);
    }
    for m in minima.iter_mut() {
        m.starts.sort_unstable();
    }
    let best = minima[0].params.clone();
    let evaluations: usize = results.iter().map(|r| r.evaluations).sum();
    let mut ev = pb.evaluator();
    let mut cal = statistics(pb, &mut ev, &best)?;
    cal.minima = minima;
    cal.starts = results;
    cal.evaluations = evaluations + ev.evaluations;
    Ok(cal)
}

/// Statistics at parameters `p` (natural units), with no multi-start record.
pub fn statistics(pb: &Problem, ev: &mut Evaluator, p: &[f64]) -> Result<Calibration> {
    // Residuals, Jacobian (fitting coordinates) and predictions at `p`.
    let x = pb.fit_coords_of(p);
    let (r, j) = ev.residuals(pb, &x, true)?;
    let j = j.unwrap_or_else(|| DMatrix::zeros(r.len(), p.len()));
    let predictions = ev.predict(pb, p)?;
    let m = r.len();
    let n = p.len();
    let cost = r.norm_squared();
    let s2 = if m > n {
        cost / (m - n) as f64
    } else {
        f64::NAN
    };
    let info = pb.family.params();
    // Singular values and right singular vectors of the Jacobian.
    let svd = j.clone().svd(false, true);
    let sv: Vec<f64> = svd.singular_values.iter().copied().collect();
    let vt = svd.v_t.unwrap_or_else(|| DMatrix::identity(n, n));
    let smax = sv.iter().fold(0.0f64, |a, b| a.max(*b));
    let smin = sv.iter().fold(f64::INFINITY, |a, b| a.min(*b));
    // Residual variance per DoF, then the sandwich covariance.
    let (sigma2, count) = residual_variance(pb, &r, n);
    let cov = covariance(pb, &j, &sv, &vt, &sigma2, n);
    // Estimates with 95% intervals; poorly determined parameters (large SD,
    // at a bound, or loading a nearly singular direction).
    let tq = if m > n {
        use statrs::distribution::{ContinuousCDF, StudentsT};
        StudentsT::new(0.0, 1.0, (m - n) as f64)
            .map(|t| t.inverse_cdf(0.975))
            .unwrap_or(1.96)
    } else {
        f64::NAN
    };
    let (estimates, mut poorly) = estimates(info, p, &x, &cov, tq);
    let weak = weak_directions(info, &sv, &vt, &mut poorly);
    Ok(Calibration {
        family: pb.family.label(),
        param_names: info.iter().map(|i| i.name.clone()).collect(),
        best: p.to_vec(),
        cost,
        n_residuals: m,
        n_params: n,
        s2,
        residual_sd: std::array::from_fn(|d| {
            if count[d] > 0 {
                sigma2[d].sqrt()
            } else {
                f64::NAN
            }
        }),
        estimates,
        covariance_log: (0..n)
            .map(|a| (0..n).map(|b| cov[(a, b)]).collect())
            .collect(),
        correlation: correlation(&cov),
        identifiability: Identifiability {
            condition_number: if smin > 0.0 {
                smax / smin
            } else {
                f64::INFINITY
            },
            singular_values: sv,
            weak_directions: weak,
            poorly_determined: poorly,
        },
        minima: Vec::new(),
        starts: Vec::new(),
        predictions,
        evaluations: ev.evaluations,
    })
}

/// Residual variance per DoF from the unweighted residuals (corrected for
/// the `n` fitted parameters), and the residual count per DoF.
fn residual_variance(pb: &Problem, r: &DVector<f64>, n: usize) -> ([f64; 6], [usize; 6]) {
    let m = r.len();
    let mut sigma2 = [0.0f64; 6];
    let mut count = [0usize; 6];
    for (ci, c) in pb.cells.iter().enumerate() {
        if c.sqrt_w > 0.0 {
            sigma2[c.dof] += (r[ci] / c.sqrt_w).powi(2);
            count[c.dof] += 1;
        }
    }
    let dof_share = if m > n {
        (m - n) as f64 / m as f64
    } else {
        f64::NAN
    };
    for d in 0..6 {
        if count[d] > 0 {
            sigma2[d] /= count[d] as f64 * dof_share;
        }
    }
    (sigma2, count)
}

/// Covariance of the fitting coordinates: the sandwich A+ B A+ with
/// A = J^T J (weighted Jacobian) and B = sum_i w_i sigma_d(i)^2 J_i^T J_i,
/// the residual variance sigma_d^2 estimated per DoF from the unweighted
/// residuals (so that weights that are not 1/variance, e.g. the default
/// motion-based ones, still give honest intervals). With w = 1/sigma^2 it
/// reduces to s^2 (J^T J)^-1. Directions with tiny singular values have
/// unbounded variance.
fn covariance(
    pb: &Problem,
    j: &DMatrix<f64>,
    sv: &[f64],
    vt: &DMatrix<f64>,
    sigma2: &[f64; 6],
    n: usize,
) -> DMatrix<f64> {
    let smax = sv.iter().fold(0.0f64, |a, b| a.max(*b));
    let tiny = smax * 1e-10;
    let mut a_pinv = DMatrix::<f64>::zeros(n, n);
    for (k, &s) in sv.iter().enumerate() {
        if s > tiny {
            for a in 0..n {
                for b in 0..n {
                    a_pinv[(a, b)] += vt[(k, a)] * vt[(k, b)] / (s * s);
                }
            }
        }
    }
    let mut bmat = DMatrix::<f64>::zeros(n, n);
    for (ci, c) in pb.cells.iter().enumerate() {
        // a stated SD is the cell's noise (w sigma^2 = 1); otherwise the
        // residual estimate of its DoF
        let f = if c.stated {
            1.0
        } else {
            c.sqrt_w * c.sqrt_w * sigma2[c.dof]
        };
        for a in 0..n {
            let ja = j[(ci, a)];
            if ja == 0.0 {
                continue;
            }
            for b in 0..n {
                bmat[(a, b)] += f * ja * j[(ci, b)];
            }
        }
    }
    let mut cov = &a_pinv * bmat * &a_pinv;
    for (k, &s) in sv.iter().enumerate() {
        if s <= tiny {
            for a in 0..n {
                if vt[(k, a)].abs() > 1e-3 {
                    cov[(a, a)] = f64::INFINITY;
                }
            }
        }
    }
    cov
}

/// Each parameter's estimate (SD and 95% interval from the covariance `cov`
/// of the fitting coordinates `x`, t quantile `tq`), and those poorly
/// determined by their SD or a bound.
fn estimates(
    info: &[ParamInfo],
    p: &[f64],
    x: &[f64],
    cov: &DMatrix<f64>,
    tq: f64,
) -> (Vec<ParamEstimate>, Vec<PoorlyDetermined>) {
    let mut estimates = Vec::new();
    let mut poorly = Vec::new();
    for k in 0..p.len() {
        // SD on the fitting scale
        let sd = cov[(k, k)].max(0.0).sqrt();
        let (flo, fhi) = info[k].fit_bounds();
        let at_lower = x[k] <= flo + 1e-9;
        let at_bound = at_lower || x[k] >= fhi - 1e-9;
        let scale = info[k].scale;
        let (rel_sd, sd_value, ci95) = match scale {
            Scale::Log => (
                sd,
                p[k] * sd,
                [p[k] * (-tq * sd).exp(), p[k] * (tq * sd).exp()],
            ),
            Scale::Linear => (
                if p[k] != 0.0 {
                    sd / p[k].abs()
                } else {
                    f64::INFINITY
                },
                sd,
                [p[k] - tq * sd, p[k] + tq * sd],
            ),
            Scale::Log1p => (
                sd,
                (1.0 + p[k]) * sd,
                [
                    (1.0 + p[k]) * (-tq * sd).exp() - 1.0,
                    (1.0 + p[k]) * (tq * sd).exp() - 1.0,
                ],
            ),
        };
        estimates.push(ParamEstimate {
            name: info[k].name.clone(),
            unit: info[k].unit.clone(),
            value: p[k],
            nominal: info[k].nominal,
            lower: info[k].lower,
            upper: info[k].upper,
            scale,
            rel_sd,
            sd: sd_value,
            ci95,
            at_bound,
        });
        if let Some(reason) = poorly_determined(&info[k], sd, at_lower, at_bound) {
            poorly.push(PoorlyDetermined {
                name: info[k].name.clone(),
                reason,
            });
        }
    }
    (estimates, poorly)
}

/// Why parameter `info` (SD `sd` on its fitting scale, at its lower bound
/// / at a bound) is poorly determined, if it is.
fn poorly_determined(info: &ParamInfo, sd: f64, at_lower: bool, at_bound: bool) -> Option<String> {
    let scale = info.scale;
    let sd_text = if sd.is_finite() {
        match scale {
            Scale::Log => format!("relative SD {:.0}%", 100.0 * sd),
            Scale::Linear => format!("SD {sd:.3}"),
            Scale::Log1p => format!("SD of ln(1 + value) {sd:.3}"),
        }
    } else {
        "unbounded SD".into()
    };
    // poorly determined: SD above 0.5 on the fitting scale (a factor
    // e^(+-1) at 95% for stiffness); for stiffening, above 0.25 (the
    // data cannot tell linear from ~60% stiffening at the reference rotation)
    let limit = if scale == Scale::Log1p { 0.25 } else { 0.5 };
    if !sd.is_finite() || sd > limit {
        return Some(match scale {
            Scale::Log => format!("{sd_text} (> 50%): the data barely constrain it"),
            Scale::Linear | Scale::Log1p => format!(
                "{sd_text} (> {limit} on its fitting scale): the data cannot tell its value{}",
                if info.name.ends_with("_stiffening") {
                    " (the measured rotations do not show whether the stiffness changes with the rotation: too small, too few or too noisy)"
                } else {
                    ""
                }
            ),
        });
    }
    // a linear-scale parameter at its neutral value 0 (e.g. no
    // stiffening) is a determined answer, not a failure
    let neutral = scale != Scale::Log && at_lower && info.lower == 0.0;
    if !at_bound || neutral {
        return None;
    }
    Some(match scale {
        Scale::Log => format!(
            "at a literature bound ({} .. {} {}): the best fit wants a value outside the range",
            info.lower, info.upper, info.unit
        ),
        Scale::Linear | Scale::Log1p => format!(
            "at a bound of its range ({} .. {}): the best fit wants a value outside it",
            info.lower, info.upper
        ),
    })
}

/// Directions of the Jacobian with relative singular value below 1e-3 and
/// their loadings; parameters loading one (|loading| >= 0.2) are added to
/// `poorly` when not there yet.
fn weak_directions(
    info: &[ParamInfo],
    sv: &[f64],
    vt: &DMatrix<f64>,
    poorly: &mut Vec<PoorlyDetermined>,
) -> Vec<WeakDirection> {
    let n = info.len();
    let smax = sv.iter().fold(0.0f64, |a, b| a.max(*b));
    let mut weak = Vec::new();
    for (k, &s) in sv.iter().enumerate() {
        let rel = if smax > 0.0 { s / smax } else { 0.0 };
        if rel < 1e-3 {
            let mut load: Vec<(String, f64)> = (0..n)
                .filter(|&a| vt[(k, a)].abs() >= 0.2)
                .map(|a| (info[a].name.clone(), vt[(k, a)]))
                .collect();
            load.sort_by(|a, b| b.1.abs().total_cmp(&a.1.abs()).then(a.0.cmp(&b.0)));
            for (name, _) in &load {
                if !poorly.iter().any(|p| &p.name == name) {
                    poorly.push(PoorlyDetermined {
                        name: name.clone(),
                        reason: format!(
                            "loads a nearly singular direction of the Jacobian (relative singular value {rel:.1e})"
                        ),
                    });
                }
            }
            weak.push(WeakDirection {
                singular_value: s,
                relative: rel,
                loadings: load,
            });
        }
    }
    weak
}

/// Correlation matrix of a covariance (1 on the diagonal and NaN elsewhere
/// where a variance is zero or unbounded).
fn correlation(cov: &DMatrix<f64>) -> Vec<Vec<f64>> {
    let n = cov.nrows();
    let mut corr = vec![vec![0.0; n]; n];
    for a in 0..n {
        for b in 0..n {
            let d = (cov[(a, a)] * cov[(b, b)]).sqrt();
            corr[a][b] = if d > 0.0 && d.is_finite() {
                cov[(a, b)] / d
            } else if a == b {
                1.0
            } else {
                f64::NAN
            };
        }
    }
    corr
}

/// Root-mean-square errors of predictions against the measurements, per
/// level (pair) and DoF, in SI units, over the rows `rows` accepts.
#[derive(Debug, Clone, Serialize)]
pub struct ErrorTable {
    /// (upper/lower, dof) -> (RMSE SI, normalised RMSE = RMSE / measured range, n)
    pub entries: Vec<ErrorEntry>,
}

/// One entry of an [`ErrorTable`].
#[derive(Debug, Clone, Serialize)]
pub struct ErrorEntry {
    /// Vertebra pair, `upper/lower`.
    pub pair: String,
    /// Degree of freedom (`rx` .. `tz`).
    pub dof: String,
    /// Number of measured cells.
    pub n: usize,
    /// RMSE (rad or m).
    pub rmse: f64,
    /// RMSE divided by the range (max - min) of the measured values.
    pub nrmse: f64,
    /// RMSE in the experiment's unit (`unit`).
    pub rmse_in_unit: f64,
    /// `deg`/`rad` or `mm`/`m` as in `[units]`.
    pub unit: String,
}

impl ErrorTable {
    /// Pooled RMSE over all entries of rotational (`rot = true`) or
    /// translational DoFs, in the experiment's unit; NaN when there is none.
    pub fn pooled(&self, rot: bool) -> f64 {
        let (mut ss, mut n) = (0.0, 0usize);
        for e in &self.entries {
            if DOF_NAMES[..3].contains(&e.dof.as_str()) == rot {
                ss += e.rmse_in_unit.powi(2) * e.n as f64;
                n += e.n;
            }
        }
        if n == 0 {
            f64::NAN
        } else {
            (ss / n as f64).sqrt()
        }
    }
}

/// Error table of `pred` vs measured over the selected DoFs and rows.
pub fn error_table(pb: &Problem, pred: &[[f64; 6]], rows: impl Fn(usize) -> bool) -> ErrorTable {
    let mut acc: BTreeMap<(String, usize), (f64, usize, f64, f64)> = BTreeMap::new();
    for (ri, r) in pb.exp.rows.iter().enumerate() {
        if !rows(ri) {
            continue;
        }
        let Some(p) = pred.get(ri) else { continue };
        for &d in &pb.opts.dofs {
            if let Some(m) = r.values[d] {
                let e = acc
                    .entry((format!("{}/{}", r.upper, r.lower), d))
                    .or_insert((0.0, 0, f64::INFINITY, f64::NEG_INFINITY));
                e.0 += (p[d] - m).powi(2);
                e.1 += 1;
                e.2 = e.2.min(m);
                e.3 = e.3.max(m);
            }
        }
    }
    ErrorTable {
        entries: acc
            .into_iter()
            .map(|((pair, d), (ss, n, lo, hi))| {
                let rmse = (ss / n.max(1) as f64).sqrt();
                ErrorEntry {
                    pair,
                    dof: DOF_NAMES[d].into(),
                    n,
                    rmse,
                    nrmse: if hi > lo { rmse / (hi - lo) } else { f64::NAN },
                    rmse_in_unit: rmse * pb.exp.units.from_si(d),
                    unit: if d < 3 {
                        pb.exp.units.angle
                    } else {
                        pb.exp.units.length
                    }
                    .to_string(),
                }
            })
            .collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn poorly_determined_by_sd_or_bound_but_not_at_a_neutral_zero() {
        let k = ParamInfo::log("rx".into(), "N*m/rad", 1.0, 100.0, 10.0);
        // a relative SD of 20% is determined, 80% is not
        assert_eq!(poorly_determined(&k, 0.2, false, false), None);
        let why = poorly_determined(&k, 0.8, false, false).unwrap();
        assert!(why.contains("relative SD 80%"), "{why}");
        // on a literature bound: the fit wants a value outside the range
        let why = poorly_determined(&k, 0.2, true, true).unwrap();
        assert!(why.contains("literature bound"), "{why}");
        // a stiffening at its neutral lower bound 0 is a determined answer
        let s = ParamInfo {
            name: "rx_stiffening".into(),
            unit: "ratio".into(),
            lower: 0.0,
            upper: 4.0,
            nominal: 0.0,
            scale: Scale::Log1p,
            note: None,
        };
        assert_eq!(poorly_determined(&s, 0.1, true, true), None);
        let why = poorly_determined(&s, 0.3, true, true).unwrap();
        assert!(why.contains("the measured rotations do not show"), "{why}");
    }

    #[test]
    fn correlation_of_a_covariance() {
        let cov = DMatrix::from_row_slice(2, 2, &[4.0, 2.0, 2.0, 9.0]);
        let c = correlation(&cov);
        assert_eq!(c[0][0], 1.0);
        assert!((c[0][1] - 2.0 / 6.0).abs() < 1e-15);
        // an unbounded variance has no correlation
        let cov = DMatrix::from_row_slice(2, 2, &[f64::INFINITY, 0.0, 0.0, 1.0]);
        let c = correlation(&cov);
        assert_eq!(c[0][0], 1.0);
        assert!(c[0][1].is_nan());
    }
}
