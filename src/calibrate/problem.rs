//! The calibration problem: an experiment, a model family, the chosen DoFs
//! and weights, and the evaluation of the weighted residual vector
//! `r_i = sqrt(w_d) (predicted - measured)` (thesis Eqns 3.1 / 4.1:
//! cost = sum r_i^2) and its Jacobian with respect to the log-parameters.
//!
//! Each evaluation puts the parameters into the (reused) system, solves the
//! unloaded and every loaded equilibrium warm-started from the previous
//! solution of the same case, and differentiates implicitly:
//! `dq/dp = -T^{-1} d tau/d p` with the solver's factorised tangent `T`,
//! `d y/d q` by forward-mode dual numbers through the kinematics, and
//! `d p / d log p = p`.

use super::experiment::{Experiment, DOF_NAMES};
use super::family::ModelFamily;
use super::measure::{pair_increment, pair_increment_loaded, pair_increment_unloaded, Convention};
use crate::error::{Error, Result};
use crate::solver::kinematics;
use crate::solver::scalar::{d6_eps, D6};
use crate::solver::workspace::KinBuf;
use crate::solver::{BodyIndex, LoadSet, Pose, StaticOptions, System, Workspace};
use nalgebra::{DMatrix, DVector};
use std::sync::Arc;

/// Options of a calibration problem.
#[derive(Debug, Clone)]
pub struct ProblemOptions {
    /// DoFs (0..6) in the cost.
    pub dofs: Vec<usize>,
    /// Weight per DoF; `None` = 1 / (RMS measured motion in that DoF)^2.
    pub weights: [Option<f64>; 6],
    /// How the measured increments are formed.
    pub convention: Convention,
}

impl Default for ProblemOptions {
    fn default() -> Self {
        ProblemOptions {
            dofs: vec![0, 1, 2],
            weights: [None; 6],
            convention: Convention::Composed,
        }
    }
}

/// One residual: a measured cell.
#[derive(Debug, Clone)]
pub struct Cell {
    /// Row index in the experiment.
    pub row: usize,
    /// Case index.
    pub case: usize,
    /// DoF 0..6.
    pub dof: usize,
    /// Measured value (SI).
    pub measured: f64,
    /// sqrt of the weight.
    pub sqrt_w: f64,
    /// The weight is `1 / sd^2` of the cell's stated SD (the standard
    /// error for means over several specimens): its noise is known.
    pub stated: bool,
}

#[derive(Debug, Clone)]
struct RowBodies {
    upper: BodyIndex,
    lower: BodyIndex,
}

/// A calibration problem (immutable description); see [`Evaluator`] for the
/// mutable evaluation state.
#[derive(Clone)]
pub struct Problem {
    /// The experiment.
    pub exp: Arc<Experiment>,
    /// The model family.
    pub family: Arc<dyn ModelFamily>,
    /// Options.
    pub opts: ProblemOptions,
    /// The residual cells, in row-major (row, dof) order.
    pub cells: Vec<Cell>,
    /// Weights used per DoF (0 when not in the cost).
    pub weights: [f64; 6],
    sys: System,
    loads: Vec<LoadSet>,
    rows: Vec<RowBodies>,
}

impl std::fmt::Debug for Problem {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Problem")
            .field("experiment", &self.exp.name)
            .field("family", &self.family.label())
            .field("cells", &self.cells.len())
            .finish()
    }
}

impl Problem {
    /// Build from an experiment (its spec compiled into a system), a family and options.
    pub fn new(
        exp: Arc<Experiment>,
        family: Arc<dyn ModelFamily>,
        opts: ProblemOptions,
    ) -> Result<Problem> {
        let sys = System::new(&exp.spec)?;
        Problem::with_system(exp, family, opts, sys)
    }

    /// Build with a given system (e.g. one with perturbed joint frames).
    pub fn with_system(
        exp: Arc<Experiment>,
        family: Arc<dyn ModelFamily>,
        opts: ProblemOptions,
        sys: System,
    ) -> Result<Problem> {
        let ctx = format!("experiment {}", exp.dir.display());
        if opts.dofs.is_empty() {
            return Err(Error::invalid(ctx, "no DoF selected for the cost"));
        }
        let measured = exp.measured_dofs();
        for &d in &opts.dofs {
            if d >= 6 {
                return Err(Error::invalid(ctx, format!("DoF index {d} out of range")));
            }
            if !measured.contains(&d) {
                return Err(Error::invalid(
                    ctx,
                    format!(
                        "DoF {} is selected for the cost but kinematics.csv has no measured value in it (measured: {})",
                        DOF_NAMES[d],
                        measured.iter().map(|&m| DOF_NAMES[m]).collect::<Vec<_>>().join(",")
                    ),
                ));
            }
        }
        let fixed = exp.fixed_body.as_str();
        let loads = exp
            .cases
            .iter()
            .map(|c| {
                let l = c.loads(Some(fixed))?;
                sys.prepare_loads(&l)
                    .map_err(|e| Error::invalid(format!("case '{}'", c.id), e.to_string()))
            })
            .collect::<Result<Vec<_>>>()?;
        let rows = exp
            .rows
            .iter()
            .map(|r| {
                let find = |n: &str| {
                    sys.body_index(n).ok_or_else(|| {
                        Error::invalid(
                            ctx.clone(),
                            format!("body '{n}' is not in the solver system"),
                        )
                    })
                };
                Ok(RowBodies {
                    upper: find(&r.upper)?,
                    lower: find(&r.lower)?,
                })
            })
            .collect::<Result<Vec<_>>>()?;
        let mut weights = [0.0; 6];
        for &d in &opts.dofs {
            weights[d] = match opts.weights[d] {
                Some(w) => {
                    if !(w.is_finite() && w >= 0.0) {
                        return Err(Error::invalid(
                            "--weights",
                            format!(
                                "weight of {} must be finite and >= 0, got {w}",
                                DOF_NAMES[d]
                            ),
                        ));
                    }
                    w
                }
                None => {
                    let v: Vec<f64> = exp.rows.iter().filter_map(|r| r.values[d]).collect();
                    let rms = (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt();
                    if rms > 0.0 {
                        1.0 / (rms * rms)
                    } else {
                        return Err(Error::invalid(
                            ctx,
                            format!("the measured motion in {} is zero everywhere: give its weight with --weights", DOF_NAMES[d]),
                        ));
                    }
                }
            };
        }
        // a stated SD (sd_* cell or [measurement]) sets the weight when
        // --weights does not: 1 / SE^2 with SE = SD / sqrt(n_specimens)
        let se_div = (exp.measurement.n_specimens.unwrap_or(1).max(1) as f64).sqrt();
        let mut cells = Vec::new();
        for (ri, r) in exp.rows.iter().enumerate() {
            for &d in &opts.dofs {
                if let Some(m) = r.values[d] {
                    let sd = r.stated_sd(d, &exp.measurement).map(|s| s / se_div);
                    let stated = opts.weights[d].is_none() && sd.is_some();
                    cells.push(Cell {
                        row: ri,
                        case: r.case,
                        dof: d,
                        measured: m,
                        sqrt_w: match sd {
                            Some(s) if stated => 1.0 / s,
                            _ => weights[d].sqrt(),
                        },
                        stated,
                    });
                }
            }
        }
        if cells.is_empty() {
            return Err(Error::invalid(
                ctx,
                "no measured value in the selected DoFs",
            ));
        }
        Ok(Problem {
            exp,
            family,
            opts,
            cells,
            weights,
            sys,
            loads,
            rows,
        })
    }

    /// Number of parameters.
    pub fn n_params(&self) -> usize {
        self.family.params().len()
    }

    /// Bounds on the fitting scale (log of stiffness values, shape
    /// parameters as they are; see [`super::family::Scale`]).
    pub fn fit_bounds(&self) -> (Vec<f64>, Vec<f64>) {
        let p = self.family.params();
        (
            p.iter().map(|i| i.fit_bounds().0).collect(),
            p.iter().map(|i| i.fit_bounds().1).collect(),
        )
    }

    /// Parameter values of fitting coordinates `x`.
    pub fn values_of(&self, x: &[f64]) -> Vec<f64> {
        super::family::values_of(self.family.params(), x)
    }

    /// Fitting coordinates of parameter values `p`.
    pub fn fit_coords_of(&self, p: &[f64]) -> Vec<f64> {
        super::family::fit_coords_of(self.family.params(), p)
    }

    /// The base system (before any parameters are applied).
    pub fn system(&self) -> &System {
        &self.sys
    }

    /// A fresh evaluator (own system copy and workspaces).
    pub fn evaluator(&self) -> Evaluator {
        let n = self.sys.n_dofs();
        Evaluator {
            sys: self.sys.clone(),
            ws: Workspace::new(&self.sys),
            kd6: KinBuf::new(&self.sys),
            k64: KinBuf::new(&self.sys),
            q0: self.sys.default_q(),
            q1: vec![self.sys.default_q(); self.exp.cases.len()],
            pred0: None,
            pred1: vec![None; self.exp.cases.len()],
            dtau: DMatrix::zeros(n, self.n_params()),
            evaluations: 0,
        }
    }
}

/// Mutable evaluation state: a system copy, workspaces and warm starts.
#[derive(Debug, Clone)]
pub struct Evaluator {
    sys: System,
    ws: Workspace,
    kd6: KinBuf<D6>,
    k64: KinBuf<f64>,
    q0: DVector<f64>,
    q1: Vec<DVector<f64>>,
    /// Last sensitivities (parameters, dq/dp) of the unloaded and loaded
    /// solutions, for first-order predicted warm starts.
    pred0: Option<(Vec<f64>, DMatrix<f64>)>,
    pred1: Vec<Option<(Vec<f64>, DMatrix<f64>)>>,
    dtau: DMatrix<f64>,
    /// Residual evaluations done.
    pub evaluations: usize,
}

/// Predictions for every row: `(rx..tz)` in SI.
pub type Predictions = Vec<[f64; 6]>;

fn solve_warm(
    sys: &System,
    loads: &LoadSet,
    warm: &mut DVector<f64>,
    ws: &mut Workspace,
) -> Result<DVector<f64>> {
    let opts = StaticOptions::default();
    let sol = match sys.solve_static(loads, warm.as_slice(), ws, &opts) {
        Ok(s) => s,
        Err(_) => sys.solve_static(loads, sys.default_q().as_slice(), ws, &opts)?,
    };
    *warm = sol.q.clone();
    Ok(sol.q)
}

impl Evaluator {
    /// The evaluator's system (with the last parameters applied).
    pub fn system(&self) -> &System {
        &self.sys
    }

    fn poses(&mut self, q: &[f64]) -> Vec<Pose<f64>> {
        self.k64.q.copy_from_slice(q);
        kinematics::forward(&self.sys, &mut self.k64);
        self.k64.x_gb.clone()
    }

    /// `dy/dp` for the rows of one case (6 per row x n_params), by seeding
    /// the dual parts of the coordinates with the columns of `dq` (six
    /// parameters per kinematics pass). `loaded_varies` says whether `q_var`
    /// is the loaded (true) or unloaded configuration; the other one's poses
    /// are `fixed_poses`.
    #[allow(clippy::too_many_arguments)]
    fn dy_dp(
        &mut self,
        pb: &Problem,
        rows: &[usize],
        q_var: &[f64],
        dq: &DMatrix<f64>,
        fixed_poses: &[Pose<f64>],
        loaded_varies: bool,
        out: &mut DMatrix<f64>,
    ) {
        let np = dq.ncols();
        let conv = pb.opts.convention;
        let mut start = 0;
        while start < np {
            let width = (np - start).min(6);
            for (i, qi) in q_var.iter().enumerate() {
                let mut e = nalgebra::SVector::<f64, 6>::zeros();
                for k in 0..width {
                    e[k] = dq[(i, start + k)];
                }
                self.kd6.q[i] = D6::new(*qi, num_dual::Derivative::some(e));
            }
            kinematics::forward(&self.sys, &mut self.kd6);
            for (ri, &row) in rows.iter().enumerate() {
                let rb = &pb.rows[row];
                let inc = if loaded_varies {
                    pair_increment_loaded(
                        conv,
                        &fixed_poses[rb.upper.0],
                        &fixed_poses[rb.lower.0],
                        &self.kd6.x_gb[rb.upper.0],
                        &self.kd6.x_gb[rb.lower.0],
                    )
                } else {
                    pair_increment_unloaded(
                        conv,
                        &self.kd6.x_gb[rb.upper.0],
                        &self.kd6.x_gb[rb.lower.0],
                        &fixed_poses[rb.upper.0],
                        &fixed_poses[rb.lower.0],
                    )
                };
                for d in 0..6 {
                    let e = d6_eps(&inc[d]);
                    for k in 0..width {
                        out[(6 * ri + d, start + k)] += e[k];
                    }
                }
            }
            start += width;
        }
    }

    /// `dq/dp = -T^{-1} d tau/d p` with the tangent factorised by the last solve.
    #[allow(clippy::needless_range_loop)]
    fn dq_dp(
        &mut self,
        pb: &Problem,
        p: &[f64],
        q: &[f64],
        loads: &LoadSet,
    ) -> Result<DMatrix<f64>> {
        let n = self.sys.n_dofs();
        let np = p.len();
        pb.family
            .dtau_dp(p, &self.sys, q, loads, &mut self.ws, &mut self.dtau)?;
        let mut d = DMatrix::zeros(n, np);
        let mut col = vec![0.0; n];
        for j in 0..np {
            let mut any = false;
            for i in 0..n {
                col[i] = -self.dtau[(i, j)];
                any |= col[i] != 0.0;
            }
            if !any {
                continue;
            }
            self.sys.tangent_solve(&self.ws, &mut col)?;
            for i in 0..n {
                d[(i, j)] = col[i];
            }
        }
        Ok(d)
    }

    /// Solve every case for parameters `p` (natural units) and return the
    /// predicted increments of every row (no derivatives).
    pub fn predict(&mut self, pb: &Problem, p: &[f64]) -> Result<Predictions> {
        Ok(self.run(pb, p, false)?.0)
    }

    /// Weighted residuals at fitting coordinates `x` (log-parameters for
    /// stiffness values), and the Jacobian with respect to `x` when `jac`.
    pub fn residuals(
        &mut self,
        pb: &Problem,
        x: &[f64],
        jac: bool,
    ) -> Result<(DVector<f64>, Option<DMatrix<f64>>)> {
        let p = pb.values_of(x);
        let dp_dx: Vec<f64> = pb
            .family
            .params()
            .iter()
            .zip(&p)
            .map(|(i, v)| i.dvalue_dfit(*v))
            .collect();
        let (pred, dpred) = self.run(pb, &p, jac)?;
        let m = pb.cells.len();
        let np = p.len();
        let mut r = DVector::zeros(m);
        let mut jm = if jac {
            Some(DMatrix::zeros(m, np))
        } else {
            None
        };
        for (ci, c) in pb.cells.iter().enumerate() {
            r[ci] = c.sqrt_w * (pred[c.row][c.dof] - c.measured);
            if let (Some(j), Some(dp)) = (jm.as_mut(), dpred.as_ref()) {
                for k in 0..np {
                    j[(ci, k)] = c.sqrt_w * dp[(6 * c.row + c.dof, k)] * dp_dx[k];
                }
            }
        }
        Ok((r, jm))
    }

    /// Predictions and (optionally) their derivative w.r.t. p (6 rows per
    /// experiment row, row-major).
    fn run(
        &mut self,
        pb: &Problem,
        p: &[f64],
        jac: bool,
    ) -> Result<(Predictions, Option<DMatrix<f64>>)> {
        self.evaluations += 1;
        self.sys = pb.family.system(p, &self.sys)?;
        let np = p.len();
        let empty = LoadSet::empty();
        let mut q0_warm = self.predict_start(None, p);
        let q0 = solve_warm(&self.sys, &empty, &mut q0_warm, &mut self.ws).map_err(|e| {
            Error::numerical("unloaded equilibrium", format!("cannot be reached: {e}"))
        })?;
        self.q0 = q0.clone();
        let mut dq0: Option<DMatrix<f64>> = None;
        if jac {
            let d = self.dq_dp(pb, p, q0.as_slice(), &empty)?;
            self.pred0 = Some((p.to_vec(), d.clone()));
            if d.iter().any(|v| *v != 0.0) {
                dq0 = Some(d);
            }
        }
        let poses0 = self.poses(q0.as_slice());
        let nrows = pb.exp.rows.len();
        let mut pred = vec![[0.0; 6]; nrows];
        let mut dpred = if jac {
            Some(DMatrix::zeros(6 * nrows, np))
        } else {
            None
        };
        let mut case_rows: Vec<Vec<usize>> = vec![Vec::new(); pb.exp.cases.len()];
        for (ri, r) in pb.exp.rows.iter().enumerate() {
            if let Some(v) = case_rows.get_mut(r.case) {
                v.push(ri);
            }
        }
        for (ci, rows) in case_rows.iter().enumerate() {
            if rows.is_empty() {
                continue;
            }
            let loads = &pb.loads[ci];
            let mut warm = self.predict_start(Some(ci), p);
            let q1 = solve_warm(&self.sys, loads, &mut warm, &mut self.ws).map_err(|e| {
                Error::numerical(
                    format!("case '{}'", pb.exp.cases[ci].id),
                    format!("no equilibrium: {e}"),
                )
            })?;
            self.q1[ci] = q1.clone();
            let poses1 = self.poses(q1.as_slice());
            for &ri in rows {
                let rb = &pb.rows[ri];
                pred[ri] = pair_increment(
                    pb.opts.convention,
                    &poses0[rb.upper.0],
                    &poses0[rb.lower.0],
                    &poses1[rb.upper.0],
                    &poses1[rb.lower.0],
                );
            }
            if let Some(dp) = dpred.as_mut() {
                let dq1 = self.dq_dp(pb, p, q1.as_slice(), loads)?;
                let mut block = DMatrix::zeros(6 * rows.len(), np);
                self.dy_dp(pb, rows, q1.as_slice(), &dq1, &poses0, true, &mut block);
                if let Some(d0) = &dq0 {
                    self.dy_dp(pb, rows, q0.as_slice(), d0, &poses1, false, &mut block);
                }
                self.pred1[ci] = Some((p.to_vec(), dq1));
                for (k, &ri) in rows.iter().enumerate() {
                    for d in 0..6 {
                        for j in 0..np {
                            dp[(6 * ri + d, j)] = block[(6 * k + d, j)];
                        }
                    }
                }
            }
        }
        Ok((pred, dpred))
    }

    /// Warm start for a case (None = unloaded): the last solution moved to
    /// first order by the last sensitivities, `q + dq/dp (p - p_last)`.
    fn predict_start(&self, case: Option<usize>, p: &[f64]) -> DVector<f64> {
        let (q, pred) = match case {
            None => (&self.q0, &self.pred0),
            Some(c) => (&self.q1[c], &self.pred1[c]),
        };
        let mut out = q.clone();
        if let Some((pl, d)) = pred {
            if pl.len() == p.len() && d.nrows() == out.len() {
                for j in 0..p.len() {
                    let dp = p[j] - pl[j];
                    if dp != 0.0 {
                        for i in 0..out.len() {
                            out[i] += d[(i, j)] * dp;
                        }
                    }
                }
            }
        }
        out
    }
}
