//! Static equilibrium: Newton's method on the generalised applied force
//! `tau(q) = 0` (gravity, bushings, loads; speeds zero) with the exact
//! tangent `d tau / d q`, a step cap on rotations and a backtracking line
//! search on `||tau||`. Converges on residual AND step; failures (no
//! equilibrium, gimbal lock, singular tangent) are errors, never NaN.
//!
//! The Newton system is solved by one of two exact factorisations (see
//! [`TangentMethod`]):
//! - structured (default on tree-coupled systems, `tree`): per-joint blocks
//!   assembled from the residual evaluation already at hand, eliminated
//!   leaves-to-root; O(n) per iteration. On the 6-68 joint spine chains a
//!   cold solve costs about 7 us per joint (criterion, `benches/solver.rs`).
//! - dense (reference and fallback): one six-direction dual-number pass of
//!   the whole residual per joint (O(n^2)) and a dense LU (O(n^3)); used when
//!   a force element couples non-adjacent bodies, when a joint block of the
//!   structured elimination is singular, or on request.
//!
//! Both give the same Newton iterates to round-off (tests/solver_structured.rs)
//! and keep the factorisation of the last iteration for
//! [`System::tangent_solve`] (sensitivities).
//!
//! # When plain Newton fails: load continuation
//!
//! On long chains or under large loads the Newton iterates can run into a
//! region where the tangent is nearly singular or indefinite (a column
//! beyond its buckling load, a path that bends through large rotations)
//! and the line search on `||tau||` stalls at a local minimum of the merit
//! function that is no equilibrium. [`System::solve_static`] then falls
//! back to load continuation: the equilibria of
//! `H(q, s) = tau_s(q) - (1 - s) tau_0(q0) = 0` for load factors `s` from 0
//! to 1 (`tau_s`: gravity and loads scaled by `s`; the offset makes `q0` the
//! solution at `s = 0` and vanishes for undeflected bushings at the default
//! pose), each step a tangent predictor (`dq/ds = -T^-1 dH/ds`, rotation
//! capped) and a Newton corrector, halving the step on failure and doubling
//! it after easy ones. The last corrector solves the real problem (`s = 1`,
//! no offset), so the answer meets the same tolerances. When the loads
//! cannot be carried the error gives the load factor reached and, when the
//! path's slope `|dq/ds|` blew up, says it is a limit point (snap-through or
//! buckling). The fast path is unchanged: continuation costs nothing when
//! plain Newton converges. [`System::solve_static_continuation`] follows
//! the loading path directly.
//!
//! # Stability
//!
//! [`StaticSolution::stable`] reports whether the equilibrium is a strict
//! minimum of the potential energy (`-T` positive definite) when the loads
//! are conservative and the tangent symmetric, from the pivot blocks of the
//! structured elimination (inertia additivity, see `tree`) or a dense
//! Cholesky. Plain Newton converges to the nearest equilibrium, which can be
//! unstable: e.g. the base model under gravity alone with muscles off, where
//! the load path reaches a different, stable one (`tests/solver_continuation.rs`).

use super::forces::{self, GimbalLock, LoadSet, Resolved};
use super::kinematics;
use super::scalar::{d6_eps, d6_var, Scalar, D6};
use super::spec::LoadFrame;
use super::system::{DofIndex, System};
use super::tree::TangentMethod;
use super::workspace::{Factored, KinBuf, Workspace};
use crate::error::{Error, Result, SolverError};
use nalgebra::{DMatrix, DVector, Vector3};
use num_dual::Dual64;

/// Options of the static solver.
#[derive(Debug, Clone, Copy)]
pub struct StaticOptions {
    /// Maximum Newton iterations.
    pub max_iterations: usize,
    /// Converged when the largest generalised force residual (N or N m) is below this ...
    pub residual_tol: f64,
    /// ... and the largest Newton step component (rad or m) is below this.
    pub step_tol: f64,
    /// Largest change of a rotational coordinate in one step (rad).
    pub max_rotation_step: f64,
    /// How the Newton step factorises the tangent ([`TangentMethod::Auto`]:
    /// structured where possible; `Dense` is the reference it is tested against).
    pub tangent: TangentMethod,
}

impl Default for StaticOptions {
    fn default() -> Self {
        StaticOptions {
            max_iterations: 200,
            residual_tol: 1e-9,
            step_tol: 1e-10,
            max_rotation_step: 0.5,
            tangent: TangentMethod::Auto,
        }
    }
}

/// A static equilibrium.
#[derive(Debug, Clone)]
pub struct StaticSolution {
    /// Free dofs at equilibrium (see [`System::full_coordinates`]).
    pub q: DVector<f64>,
    /// Newton iterations taken.
    pub iterations: usize,
    /// Largest |generalised force| at `q`.
    pub residual_norm: f64,
    /// Whether the equilibrium is stable (a strict minimum of the potential
    /// energy: the tangent stiffness `-d tau / d q` is positive definite),
    /// when the energy criterion applies: Some for conservative loads
    /// (gravity, bushings with a symmetric tangent, ground-fixed forces),
    /// None with moments or follower loads (not conservative in 3-D) or a
    /// non-symmetric tangent. Read from the pivot blocks of the last
    /// factorisation (no extra factorisation on the structured path).
    pub stable: Option<bool>,
    /// Load-continuation steps taken (0 when plain Newton converged).
    pub continuation_steps: usize,
}

fn inf_norm(v: &[f64]) -> f64 {
    v.iter().fold(0.0f64, |m, x| m.max(x.abs()))
}
fn two_norm(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}

/// Continuation: first load-factor step.
const CONT_INITIAL_STEP: f64 = 0.25;
/// Continuation: smallest load-factor step before giving up.
const CONT_MIN_STEP: f64 = 1e-6;
/// Continuation: largest predicted change of a rotational coordinate in one step (rad).
const CONT_MAX_PREDICTED_ROTATION: f64 = 0.2;
/// Continuation: largest corrector move away from the predicted point (rad).
const CONT_MAX_CORRECTION: f64 = 0.1;
/// Continuation: Newton iterations of one corrector.
const CONT_CORRECTOR_ITERATIONS: usize = 15;
/// Continuation: step attempts in all.
const CONT_MAX_ATTEMPTS: usize = 2000;
/// Continuation: growth of the path slope `|dq/ds|` reported as a limit point.
const CONT_LIMIT_SLOPE_GROWTH: f64 = 20.0;

/// Outcome of one damped-Newton run.
enum Newton {
    Converged {
        iterations: usize,
        residual_norm: f64,
    },
    Failed {
        error: Error,
        /// Worth retrying by load continuation (stall, iteration limit, a
        /// singular tangent away from the start).
        recoverable: bool,
        iterations: usize,
    },
}

/// `tau -= offset` (no-op without an offset).
#[inline]
fn subtract(tau: &mut [f64], offset: Option<&[f64]>) {
    if let Some(o) = offset {
        for (t, c) in tau.iter_mut().zip(o) {
            *t -= c;
        }
    }
}

/// Loads scaled by the load factor `s`.
/// The state of a load continuation ([`System::solve_static_continuation`]):
/// the point `(q, s)` on the path of `H(q, s) = tau_s(q) - (1 - s) c = 0`
/// and the step control.
struct Continuation<'a> {
    sys: &'a System,
    loads: &'a LoadSet,
    /// The system without gravity, and the loads scaled to 0.
    sys0: System,
    loads0: LoadSet,
    /// The system with gravity scaled by the current load factor.
    sys_s: System,
    /// `tau_0(q0)`: the unloaded forces at the start.
    c: Vec<f64>,
    q: Vec<f64>,
    q_try: Vec<f64>,
    /// The path tangent `dq/ds` (or `-dH/ds` when the tangent is singular).
    v: Vec<f64>,
    offset: Vec<f64>,
    /// Load factor reached.
    s: f64,
    /// Next step length.
    ds: f64,
    iterations: usize,
    steps: usize,
    attempts: usize,
    /// Largest rotational `|dq/ds|` at the start and now.
    slope0: Option<f64>,
    slope: f64,
    singular: bool,
    was_stable: Option<bool>,
    lost_stability_at: Option<f64>,
}

/// The outcome of one continuation step.
enum Step {
    Accepted,
    /// At `s = 1`: the solution.
    Arrived(StaticSolution),
    /// No step possible; the last corrector failure.
    Stuck(Option<Error>),
}

impl<'a> Continuation<'a> {
    /// The path from `q0` at `s = 0`, after `first_iterations` Newton
    /// iterations of the plain solve.
    fn start(
        sys: &'a System,
        loads: &'a LoadSet,
        q0: &[f64],
        ws: &mut Workspace,
        first_iterations: usize,
    ) -> Result<Self> {
        let n = sys.n_dofs();
        let mut sys0 = sys.clone();
        sys0.gravity = Vector3::zeros();
        let loads0 = scaled_loads(loads, 0.0);
        ws.k64.q.copy_from_slice(q0);
        eval_tau(&sys0, &loads0, &mut ws.k64).map_err(|e| e.to_error(sys))?;
        Ok(Continuation {
            sys,
            loads,
            sys0,
            loads0,
            sys_s: sys.clone(),
            c: ws.k64.tau.clone(),
            q: q0.to_vec(),
            q_try: vec![0.0; n],
            v: vec![0.0; n],
            offset: vec![0.0; n],
            s: 0.0,
            ds: CONT_INITIAL_STEP,
            iterations: first_iterations,
            steps: 0,
            attempts: 0,
            slope0: None,
            slope: 0.0,
            singular: false,
            was_stable: None,
            lost_stability_at: None,
        })
    }

    /// The path tangent at `(q, s)`: `dq/ds = -T^-1 dH/ds` with
    /// `dH/ds = tau_1(q) - tau_0(q) + c`; whether `T` is singular, where the
    /// path first loses stability, and the slope.
    fn tangent(&mut self, ws: &mut Workspace, opts: &StaticOptions) -> Result<()> {
        let (sys, n) = (self.sys, self.q.len());
        ws.k64.q.copy_from_slice(&self.q);
        eval_tau(&self.sys0, &self.loads0, &mut ws.k64).map_err(|e| e.to_error(sys))?;
        self.v.copy_from_slice(&ws.k64.tau);
        eval_tau(sys, self.loads, &mut ws.k64).map_err(|e| e.to_error(sys))?;
        for i in 0..n {
            self.v[i] = -(ws.k64.tau[i] - self.v[i] + self.c[i]);
        }
        self.sys_s.gravity = sys.gravity * self.s;
        let loads_s = scaled_loads(self.loads, self.s);
        eval_tau(&self.sys_s, &loads_s, &mut ws.k64).map_err(|e| e.to_error(sys))?;
        ws.dq.copy_from_slice(&self.v);
        self.sys_s
            .factor_and_solve(&self.q, &loads_s, ws, opts.tangent)
            .map_err(|e| e.to_error(sys))?;
        self.singular = ws.factored == Factored::None || ws.dq.iter().any(|x| !x.is_finite());
        if !self.singular {
            self.v.copy_from_slice(&ws.dq);
            let st = self.sys_s.stability(&loads_s, ws);
            if self.was_stable == Some(true)
                && st == Some(false)
                && self.lost_stability_at.is_none()
            {
                self.lost_stability_at = Some(self.s);
            }
            self.was_stable = st;
        }
        self.slope = self.max_rotation(|i| self.v[i].abs());
        self.slope0.get_or_insert(self.slope);
        Ok(())
    }

    /// Largest `f(i)` over the rotational DoFs (0 without any).
    fn max_rotation(&self, f: impl Fn(usize) -> f64) -> f64 {
        (0..self.q.len())
            .filter(|&i| self.sys.dof_rotational[i])
            .fold(0.0f64, |m, i| m.max(f(i)))
    }

    /// Predictor-corrector attempts along the tangent until one is accepted
    /// (halving the step after each failure), the step is too small, or the
    /// attempts run out.
    fn step(&mut self, ws: &mut Workspace, opts: &StaticOptions) -> Step {
        let n = self.q.len();
        let mut last: Option<Error> = None;
        loop {
            self.attempts += 1;
            let mut h = self.ds.min(1.0 - self.s);
            if self.slope * h > CONT_MAX_PREDICTED_ROTATION {
                h = CONT_MAX_PREDICTED_ROTATION / self.slope;
            }
            if self.singular || h < CONT_MIN_STEP || self.attempts > CONT_MAX_ATTEMPTS {
                return Step::Stuck(last);
            }
            let s1 = if self.s + h >= 1.0 - 1e-12 {
                1.0
            } else {
                self.s + h
            };
            for i in 0..n {
                self.q_try[i] = self.q[i] + (s1 - self.s) * self.v[i];
            }
            let mut q_new = self.q_try.clone();
            match self.correct(s1, &mut q_new, ws, opts) {
                Ok(Newton::Converged {
                    iterations: it,
                    residual_norm,
                }) => {
                    self.iterations += it;
                    // the corrector must stay near the predicted point,
                    // or it has jumped to another equilibrium branch
                    let jump = self.max_rotation(|i| (q_new[i] - self.q_try[i]).abs());
                    if jump <= CONT_MAX_CORRECTION {
                        self.q.copy_from_slice(&q_new);
                        self.s = s1;
                        self.steps += 1;
                        self.ds = if it <= 4 { (2.0 * h).min(1.0) } else { h };
                        if self.s == 1.0 {
                            return Step::Arrived(StaticSolution {
                                q: DVector::from_vec(std::mem::take(&mut self.q)),
                                iterations: self.iterations,
                                residual_norm,
                                stable: self.sys.stability(self.loads, ws),
                                continuation_steps: self.steps,
                            });
                        }
                        return Step::Accepted;
                    }
                    last = Some(Error::solver(
                        "static equilibrium",
                        SolverError::CorrectorJump { jump },
                    ));
                }
                Ok(Newton::Failed {
                    error,
                    iterations: it,
                    ..
                }) => {
                    self.iterations += it;
                    last = Some(error);
                }
                Err(e) => last = Some(e),
            }
            self.ds = 0.5 * h;
        }
    }

    /// Newton corrector at load factor `s1` from the predicted point `q`:
    /// the real problem at `s1 = 1`, else the scaled one with its offset.
    fn correct(
        &mut self,
        s1: f64,
        q: &mut [f64],
        ws: &mut Workspace,
        opts: &StaticOptions,
    ) -> Result<Newton> {
        if s1 == 1.0 {
            return self.sys.corrector(self.loads, None, q, ws, opts);
        }
        self.sys_s.gravity = self.sys.gravity * s1;
        let loads_s1 = scaled_loads(self.loads, s1);
        for i in 0..self.q.len() {
            self.offset[i] = (1.0 - s1) * self.c[i];
        }
        self.sys_s
            .corrector(&loads_s1, Some(&self.offset), q, ws, opts)
    }

    /// The error when the path cannot go on: how far the loads were carried
    /// and why not further (a limit point, the last corrector failure),
    /// after the plain Newton failure `first`.
    fn failure(&self, first: Option<&Error>, last: Option<Error>) -> Error {
        let (s, steps, slope) = (self.s, self.steps, self.slope);
        let slope_start = self.slope0.unwrap_or(slope);
        let first = match first {
            Some(e) => format!("plain Newton failed ({e}); "),
            None => String::new(),
        };
        let mut msg = format!(
            "no equilibrium found: {first}load continuation (gravity \
             and loads scaled by a factor s from 0 to 1, {steps} steps) carried them up to s = {s:.4} \
             and could not go further"
        );
        if self.singular || slope > CONT_LIMIT_SLOPE_GROWTH * slope_start.max(1e-12) {
            msg.push_str(&format!(
                ": the equilibrium path reaches a limit point there (the tangent stiffness \
                 becomes singular; |dq/ds| grew from {slope_start:.3e} to {} rad per unit load factor), \
                 i.e. snap-through or buckling: the model cannot carry the full loads on this \
                 equilibrium branch",
                if self.singular {
                    "infinity".to_string()
                } else {
                    format!("{slope:.3e}")
                }
            ));
        } else if let Some(e) = last {
            msg.push_str(&format!(" (last corrector failure: {e})"));
        }
        if let Some(sl) = self.lost_stability_at {
            msg.push_str(&format!(
                "; the path had lost stability at s = {sl:.4} (the tangent stiffness was no longer \
                 positive definite)"
            ));
        }
        Error::solver(
            "static equilibrium",
            SolverError::ContinuationStopped {
                reached: s,
                explanation: msg,
            },
        )
    }
}

fn scaled_loads(loads: &LoadSet, s: f64) -> LoadSet {
    let items = loads
        .items
        .iter()
        .map(|l| match l {
            Resolved::Moment { body, vec, frame } => Resolved::Moment {
                body: *body,
                vec: vec * s,
                frame: *frame,
            },
            Resolved::Force {
                body,
                point,
                vec,
                frame,
            } => Resolved::Force {
                body: *body,
                point: *point,
                vec: vec * s,
                frame: *frame,
            },
            Resolved::Follower {
                upper,
                upper_pt,
                lower,
                lower_pt,
                magnitude,
            } => Resolved::Follower {
                upper: *upper,
                upper_pt: *upper_pt,
                lower: *lower,
                lower_pt: *lower_pt,
                magnitude: magnitude * s,
            },
        })
        .collect();
    LoadSet {
        items,
        resolved_for: loads.resolved_for,
    }
}

/// Stability from a dense tangent `T`: None when `T` is not symmetric to
/// round-off, else whether `-T` is positive definite (Cholesky).
fn dense_stability(t: &DMatrix<f64>) -> Option<bool> {
    let scale = t.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let asym = (t - t.transpose())
        .iter()
        .fold(0.0f64, |m, v| m.max(v.abs()));
    if asym.is_nan() || asym > 1e-9 * scale {
        return None;
    }
    Some((-(t + t.transpose()) * 0.5).cholesky().is_some())
}

pub(crate) fn eval_tau<T: Scalar>(
    sys: &System,
    loads: &LoadSet,
    kb: &mut KinBuf<T>,
) -> Result<(), GimbalLock> {
    kinematics::forward(sys, kb);
    forces::static_wrenches(sys, loads, kb)?;
    forces::project(sys, kb);
    forces::add_fast_bushings(sys, &kb.q, None, &mut kb.tau)?;
    Ok(())
}

impl System {
    /// Generalised applied force at `q` with zero speeds (gravity, bushing
    /// stiffness, loads): the static residual. Returned slice lives in `ws`.
    pub fn static_residual<'w>(
        &self,
        q: &[f64],
        loads: &LoadSet,
        ws: &'w mut Workspace,
    ) -> Result<&'w [f64]> {
        self.check_inputs(q, loads, ws)?;
        ws.k64.q.copy_from_slice(q);
        eval_tau(self, loads, &mut ws.k64).map_err(|g| g.to_error(self))?;
        Ok(&ws.k64.tau)
    }

    pub(crate) fn check_q(&self, q: &[f64]) -> Result<()> {
        if q.len() != self.n_dofs() {
            return Err(Error::invalid(
                "solver",
                format!("expected {} coordinates, got {}", self.n_dofs(), q.len()),
            ));
        }
        if let Some(i) = q.iter().position(|v| !v.is_finite()) {
            return Err(Error::invalid(
                "solver",
                format!("coordinate '{}' is not finite", self.dof_name(DofIndex(i))),
            ));
        }
        Ok(())
    }

    /// Fill `ws.lu.a` with the tangent `d tau / d q` at `q` (not factorised).
    pub(crate) fn eval_tangent(
        &self,
        q: &[f64],
        loads: &LoadSet,
        ws: &mut Workspace,
    ) -> Result<(), GimbalLock> {
        for bi in 0..self.bodies.len() {
            let j = &self.bodies[bi].joint;
            if j.dof_count == 0 {
                continue;
            }
            for (i, qi) in q.iter().enumerate() {
                ws.kd6.q[i] = D6::from_re(*qi);
            }
            for k in 0..j.dof_count.min(6) {
                let i = j.dof_start + k;
                ws.kd6.q[i] = d6_var(q[i], k);
            }
            eval_tau(self, loads, &mut ws.kd6)?;
            for (row, t) in ws.kd6.tau.iter().enumerate() {
                let e = d6_eps(t);
                for k in 0..j.dof_count.min(6) {
                    ws.lu.a[(row, j.dof_start + k)] = e[k];
                }
            }
        }
        Ok(())
    }

    /// Factorise the tangent at `q` and overwrite `ws.dq` with the solution
    /// of `T x = ws.dq`. `ws.k64` must hold the residual evaluation at `q`.
    /// Structured when the workspace allows it and the system is
    /// tree-coupled, dense otherwise or when a joint block of the structured
    /// elimination is singular. Leaves `ws.factored` at `None` when the
    /// tangent is singular.
    fn factor_and_solve(
        &self,
        q: &[f64],
        loads: &LoadSet,
        ws: &mut Workspace,
        method: TangentMethod,
    ) -> Result<(), GimbalLock> {
        ws.factored = Factored::None;
        ws.factored_for = Some(self.id);
        if method == TangentMethod::Auto && ws.tree.usable {
            ws.tree.assemble(self, loads, &ws.k64, &mut ws.kd6)?;
            if ws.tree.factor(self) {
                ws.tree.solve(self, &mut ws.dq);
                ws.factored = Factored::Tree;
                return Ok(());
            }
        }
        self.eval_tangent(q, loads, ws)?;
        if ws.lu.factor() {
            ws.lu.solve_in_place(&mut ws.dq);
            ws.factored = Factored::Dense;
        }
        Ok(())
    }

    /// Refuse a workspace or loads made for another system (see
    /// [`super::SystemId`]), and a non-finite or wrongly sized `q`.
    pub(crate) fn check_inputs(&self, q: &[f64], loads: &LoadSet, ws: &Workspace) -> Result<()> {
        self.check_workspace(ws)?;
        self.check_loads(loads)?;
        self.check_q(q)
    }

    /// The tangent `d tau / d q` at `q` as a new matrix (for inspection and tests).
    pub fn static_tangent(
        &self,
        q: &[f64],
        loads: &LoadSet,
        ws: &mut Workspace,
    ) -> Result<DMatrix<f64>> {
        self.check_inputs(q, loads, ws)?;
        self.eval_tangent(q, loads, ws)
            .map_err(|g| g.to_error(self))?;
        ws.factored = Factored::None;
        Ok(ws.lu.a.clone())
    }

    /// Solve for static equilibrium from the start `q0` (e.g. the default
    /// pose or a previous solution: warm start).
    ///
    /// Plain damped Newton first (the fast path). When its line search
    /// stalls or it runs out of iterations, the loads are applied by
    /// continuation instead (see [`System::solve_static`]'s module docs):
    /// equilibria at load factors `s` from 0 to 1, each from the previous
    /// one. An error then says which fraction of the loads could be carried
    /// and whether the equilibrium path reached a limit point.
    pub fn solve_static(
        &self,
        loads: &LoadSet,
        q0: &[f64],
        ws: &mut Workspace,
        opts: &StaticOptions,
    ) -> Result<StaticSolution> {
        self.check_inputs(q0, loads, ws)?;
        let n = self.n_dofs();
        ws.factored = Factored::None;
        let mut q: Vec<f64> = q0.to_vec();
        ws.k64.q.copy_from_slice(&q);
        eval_tau(self, loads, &mut ws.k64).map_err(|g| g.to_error(self))?;
        ws.r.copy_from_slice(&ws.k64.tau);
        if n == 0 {
            return Ok(StaticSolution {
                q: DVector::zeros(0),
                iterations: 0,
                residual_norm: 0.0,
                stable: Some(true),
                continuation_steps: 0,
            });
        }
        match self.newton(loads, None, &mut q, ws, opts, opts.max_iterations)? {
            Newton::Converged {
                iterations,
                residual_norm,
            } => Ok(StaticSolution {
                q: DVector::from_vec(q),
                iterations,
                residual_norm,
                stable: self.stability(loads, ws),
                continuation_steps: 0,
            }),
            Newton::Failed {
                error,
                recoverable: true,
                iterations,
            } => self.solve_by_continuation(loads, q0, ws, opts, Some(error), iterations),
            Newton::Failed { error, .. } => Err(error),
        }
    }

    /// Solve for static equilibrium by load continuation only (no plain
    /// Newton attempt first): the equilibrium reached by applying gravity
    /// and the loads gradually from `q0`, following the loading path (the
    /// physically loaded branch when `q0` is the unloaded pose). Plain
    /// [`System::solve_static`] may converge to another equilibrium, e.g.
    /// an unstable one nearer the start; compare [`StaticSolution::stable`].
    pub fn solve_static_continuation(
        &self,
        loads: &LoadSet,
        q0: &[f64],
        ws: &mut Workspace,
        opts: &StaticOptions,
    ) -> Result<StaticSolution> {
        self.check_inputs(q0, loads, ws)?;
        ws.factored = Factored::None;
        if self.n_dofs() == 0 {
            return Ok(StaticSolution {
                q: DVector::zeros(0),
                iterations: 0,
                residual_norm: 0.0,
                stable: Some(true),
                continuation_steps: 0,
            });
        }
        self.solve_by_continuation(loads, q0, ws, opts, None, 0)
    }

    /// Damped Newton on `tau(q) - offset = 0` from `q` (updated in place).
    /// On entry `ws.r` must hold the residual at `q` (offset subtracted).
    /// Errors (`Err`) only for a gimbal lock at an accepted point;
    /// convergence failures are [`Newton::Failed`].
    fn newton(
        &self,
        loads: &LoadSet,
        offset: Option<&[f64]>,
        q: &mut [f64],
        ws: &mut Workspace,
        opts: &StaticOptions,
        max_iterations: usize,
    ) -> Result<Newton> {
        let n = self.n_dofs();
        let ctx = "static equilibrium";
        let mut it = 0;
        loop {
            if it >= max_iterations {
                let (worst, val) = ws.r.iter().enumerate().fold((0, 0.0f64), |a, (i, v)| {
                    if v.abs() > a.1 {
                        (i, v.abs())
                    } else {
                        a
                    }
                });
                return Ok(Newton::Failed {
                    error: Error::solver(
                        ctx,
                        SolverError::NoEquilibrium {
                            iterations: it,
                            residual: val,
                            coordinate: self.dof_name(DofIndex(worst)).to_string(),
                        },
                    ),
                    recoverable: true,
                    iterations: it,
                });
            }
            for i in 0..n {
                ws.dq[i] = -ws.r[i];
            }
            self.factor_and_solve(q, loads, ws, opts.tangent)
                .map_err(|g| g.to_error(self))?;
            if ws.factored == Factored::None {
                return Ok(Newton::Failed {
                    error: Error::solver(ctx, SolverError::SingularTangent { iteration: it }),
                    // singular at the start: no stiffness, nothing to continue;
                    // later: a singular point of the path, continuation may pass it
                    recoverable: it > 0,
                    iterations: it,
                });
            }
            if ws.dq.iter().any(|v| !v.is_finite()) {
                return Ok(Newton::Failed {
                    error: Error::solver(ctx, SolverError::NonFiniteStep { iteration: it }),
                    recoverable: it > 0,
                    iterations: it,
                });
            }
            let r_inf = inf_norm(&ws.r);
            let step_inf = inf_norm(&ws.dq);
            it += 1;
            if r_inf <= opts.residual_tol && step_inf <= opts.step_tol {
                for i in 0..n {
                    q[i] += ws.dq[i];
                }
                ws.k64.q.copy_from_slice(q);
                eval_tau(self, loads, &mut ws.k64).map_err(|g| g.to_error(self))?;
                subtract(&mut ws.k64.tau, offset);
                ws.r.copy_from_slice(&ws.k64.tau);
                return Ok(Newton::Converged {
                    iterations: it,
                    residual_norm: inf_norm(&ws.r),
                });
            }
            // cap rotations
            let mut max_rot = 0.0f64;
            for i in 0..n {
                if self.dof_rotational[i] {
                    max_rot = max_rot.max(ws.dq[i].abs());
                }
            }
            let mut lambda = if max_rot > opts.max_rotation_step {
                opts.max_rotation_step / max_rot
            } else {
                1.0
            };
            let r0 = two_norm(&ws.r);
            loop {
                for i in 0..n {
                    ws.q_trial[i] = q[i] + lambda * ws.dq[i];
                }
                ws.k64.q.copy_from_slice(&ws.q_trial);
                let ok = eval_tau(self, loads, &mut ws.k64).is_ok();
                if ok {
                    subtract(&mut ws.k64.tau, offset);
                    let rt = two_norm(&ws.k64.tau);
                    if rt.is_finite() && rt <= (1.0 - 1e-4 * lambda) * r0 {
                        break;
                    }
                    // at the round-off floor: accept a tiny, non-increasing residual
                    if rt.is_finite() && rt <= r0 && inf_norm(&ws.k64.tau) <= opts.residual_tol {
                        break;
                    }
                }
                lambda *= 0.5;
                if lambda < 1e-10 {
                    if r_inf <= opts.residual_tol * 10.0 {
                        // cannot improve further: converged to round-off
                        return Ok(Newton::Converged {
                            iterations: it,
                            residual_norm: r_inf,
                        });
                    }
                    // a gimbal lock right at the current point is the real cause
                    ws.k64.q.copy_from_slice(q);
                    if let Err(g) = eval_tau(self, loads, &mut ws.k64) {
                        return Err(g.to_error(self));
                    }
                    return Ok(Newton::Failed {
                        error: Error::solver(
                            ctx,
                            SolverError::LineSearchStalled {
                                iteration: it,
                                residual: r_inf,
                            },
                        ),
                        recoverable: true,
                        iterations: it,
                    });
                }
            }
            q.copy_from_slice(&ws.q_trial);
            ws.r.copy_from_slice(&ws.k64.tau);
        }
    }

    /// Stability of the equilibrium whose tangent was factorised last, when
    /// the energy criterion applies (conservative loads and symmetric
    /// tangent): see [`StaticSolution::stable`].
    fn stability(&self, loads: &LoadSet, ws: &mut Workspace) -> Option<bool> {
        let conservative = loads.items.iter().all(|l| match l {
            // a force of fixed direction at a body point has the potential -F.p
            Resolved::Force { frame, .. } => *frame == LoadFrame::Ground,
            // moments and follower loads are not conservative in 3-D
            Resolved::Moment { .. } | Resolved::Follower { .. } => false,
        });
        if !conservative {
            return None;
        }
        match ws.factored {
            Factored::Tree => ws.tree.stability(self),
            Factored::Dense => {
                // the tangent at the last factorised point is gone (LU in
                // place): re-evaluate it at the solution, keep the factors
                let q: Vec<f64> = ws.k64.q.clone();
                let saved = ws.lu.clone();
                let stable = match self.eval_tangent(&q, loads, ws) {
                    Ok(()) => dense_stability(&ws.lu.a),
                    Err(_) => None,
                };
                ws.lu = saved;
                stable
            }
            Factored::None => None,
        }
    }

    /// The continuation fallback of [`System::solve_static`]: follow the
    /// equilibrium path of `H(q, s) = tau_s(q) - (1 - s) c = 0` from
    /// `(q0, 0)` to `s = 1`, where `tau_s` is the residual with gravity and
    /// loads scaled by `s` and `c = tau_0(q0)` (the bushing forces at the
    /// start with no load: zero for undeflected bushings at the default
    /// pose, so the path is then the physical loading path). Each step is a
    /// tangent predictor `q + h dq/ds`, `dq/ds = -T^-1 dH/ds`, with the
    /// predicted rotation capped, and a Newton corrector; a failed or
    /// branch-jumping corrector halves the step, an easy one doubles it.
    fn solve_by_continuation(
        &self,
        loads: &LoadSet,
        q0: &[f64],
        ws: &mut Workspace,
        opts: &StaticOptions,
        first: Option<Error>,
        first_iterations: usize,
    ) -> Result<StaticSolution> {
        // The start of the path: q0 at s = 0, c = tau_0(q0).
        let mut path = Continuation::start(self, loads, q0, ws, first_iterations)?;
        loop {
            // The path tangent dq/ds at (q, s), and its stability.
            path.tangent(ws, opts)?;
            // One accepted predictor-corrector step, or the end of the path.
            match path.step(ws, opts) {
                Step::Accepted => {}
                Step::Arrived(sol) => return Ok(sol),
                Step::Stuck(last) => return Err(path.failure(first.as_ref(), last)),
            }
        }
    }

    /// Newton corrector of a continuation step from `q` (residual evaluated
    /// here); a gimbal lock at the predicted point is a failed step.
    fn corrector(
        &self,
        loads: &LoadSet,
        offset: Option<&[f64]>,
        q: &mut [f64],
        ws: &mut Workspace,
        opts: &StaticOptions,
    ) -> Result<Newton> {
        ws.k64.q.copy_from_slice(q);
        eval_tau(self, loads, &mut ws.k64).map_err(|e| e.to_error(self))?;
        subtract(&mut ws.k64.tau, offset);
        ws.r.copy_from_slice(&ws.k64.tau);
        self.newton(
            loads,
            offset,
            q,
            ws,
            opts,
            CONT_CORRECTOR_ITERATIONS.min(opts.max_iterations),
        )
    }

    /// Solve `T x = rhs` in place with the factorised tangent `T = d tau / d q`
    /// of the last Newton iteration of [`System::solve_static`] (for
    /// sensitivities `dq/dp = -T^{-1} d tau / d p`).
    pub fn tangent_solve(&self, ws: &Workspace, rhs: &mut [f64]) -> Result<()> {
        self.check_workspace(ws)?;
        if ws.factored != Factored::None && ws.factored_for != Some(self.id) {
            return Err(Error::invalid(
                "solver",
                "the factorised tangent in the workspace belongs to another parameter set of this system: run solve_static with this system first",
            ));
        }
        if rhs.len() != self.n_dofs() {
            return Err(Error::invalid(
                "solver",
                format!(
                    "tangent_solve: expected {} right-hand-side entries, got {}",
                    self.n_dofs(),
                    rhs.len()
                ),
            ));
        }
        match ws.factored {
            Factored::Dense => ws.lu.solve_in_place(rhs),
            Factored::Tree => ws.tree.solve_alloc(self, rhs),
            Factored::None => {
                return Err(Error::invalid(
                    "solver",
                    "no factorised tangent available: run solve_static first",
                ))
            }
        }
        Ok(())
    }

    /// Total number of stiffness parameters of all bushings (the columns of
    /// [`System::dtau_dstiffness`]).
    pub fn n_stiffness_params(&self) -> usize {
        self.bushings
            .iter()
            .map(|b| b.model.n_stiffness_params())
            .sum()
    }

    /// `d tau / d p` at `q`: one column per bushing stiffness parameter,
    /// bushing-major, each bushing's parameters in the order of
    /// [`crate::solver::BushingModel::stiffness_params`] (for linear bushings
    /// the diagonal stiffness rx, ry, rz, tx, ty, tz). `out` must be
    /// `n_dofs x n_stiffness_params()`.
    pub fn dtau_dstiffness(
        &self,
        q: &[f64],
        ws: &mut Workspace,
        out: &mut DMatrix<f64>,
    ) -> Result<()> {
        self.check_workspace(ws)?;
        self.check_q(q)?;
        let n = self.n_dofs();
        if out.nrows() != n || out.ncols() != self.n_stiffness_params() {
            return Err(Error::invalid(
                "solver",
                "dtau_dstiffness: output matrix has the wrong shape",
            ));
        }
        let kb = &mut ws.k64;
        kb.q.copy_from_slice(q);
        kinematics::forward(self, kb);
        let mut col = 0;
        for (bi, b) in self.bushings.iter().enumerate() {
            let p = b.model.stiffness_params();
            let (x1, x2, qr, qt, d) = match b.fast {
                Some(s) => {
                    // the deflection angles as the fast path reads them
                    // (rx, rz wrapped into (-pi, pi], like add_fast_bushings)
                    let d: [f64; 6] = std::array::from_fn(|k| {
                        if k == 0 || k == 2 {
                            forces::wrap(q[s + k])
                        } else {
                            q[s + k]
                        }
                    });
                    (None, None, Vector3::zeros(), Vector3::zeros(), d)
                }
                None => {
                    let (x1, x2, qr, qt) = forces::bushing_deflection(b, kb);
                    (
                        Some(x1),
                        Some(x2),
                        qr,
                        qt,
                        [qr.x, qr.y, qr.z, qt.x, qt.y, qt.z],
                    )
                }
            };
            if d[1].abs() >= forces::GIMBAL_LIMIT {
                return Err(GimbalLock {
                    bushing: bi,
                    angle: d[1],
                }
                .to_error(self));
            }
            let dd: [Dual64; 6] = d.map(Dual64::from_re);
            for j in 0..p.len() {
                let pd: Vec<Dual64> = p
                    .iter()
                    .enumerate()
                    .map(|(i, v)| Dual64::new(*v, if i == j { 1.0 } else { 0.0 }))
                    .collect();
                let dg: [f64; 6] = b.law.g_with(&dd, &pd).map(|v| v.eps);
                for row in 0..n {
                    out[(row, col)] = 0.0;
                }
                match (b.fast, x1, x2) {
                    (Some(s), _, _) => {
                        for k in 0..6 {
                            out[(s + k, col)] = -dg[k];
                        }
                    }
                    (None, Some(x1), Some(x2)) => {
                        for w in kb.w.iter_mut() {
                            *w = [Vector3::zeros(), Vector3::zeros()];
                        }
                        let fr = Vector3::new(-dg[0], -dg[1], -dg[2]);
                        let ft = Vector3::new(-dg[3], -dg[4], -dg[5]);
                        forces::bushing_apply(b, &x1, &x2, &qr, &fr, &ft, &mut kb.w);
                        let _ = qt;
                        forces::project(self, kb);
                        for row in 0..n {
                            out[(row, col)] = kb.tau[row];
                        }
                    }
                    _ => {}
                }
                col += 1;
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod continuation_tests {
    use super::super::examples::spine_chain;
    use super::super::forces::GIMBAL_LIMIT;
    use super::super::spec::Load;
    use super::*;

    /// Smallest eigenvalue of the symmetric part of the stiffness `-T` from
    /// the dense reference tangent (independent of the tree pivots).
    fn min_stiffness_eig(sys: &System, loads: &LoadSet, q: &[f64]) -> (f64, f64) {
        let mut ws = Workspace::new(sys);
        let t = sys.static_tangent(q, loads, &mut ws).unwrap();
        let asym = (&t - t.transpose()).amax() / t.amax();
        let k = -(&t + t.transpose()) * 0.5;
        let e = k.symmetric_eigenvalues();
        (e.iter().copied().fold(f64::INFINITY, f64::min), asym)
    }

    /// 68 joints under full gravity: plain Newton's line search stalls (the
    /// column is far beyond its buckling load); continuation reaches a real
    /// equilibrium, stable by the dense tangent's eigenvalues.
    #[test]
    fn chain68_full_gravity_by_continuation() {
        let mut spec = spine_chain(68);
        spec.gravity = Vector3::new(0.0, -9.80665, 0.0);
        let sys = System::new(&spec).unwrap();
        let loads = LoadSet::empty();
        let mut ws = Workspace::new(&sys);
        let opts = StaticOptions::default();
        let sol = sys
            .solve_static(&loads, sys.default_q().as_slice(), &mut ws, &opts)
            .unwrap();
        assert!(sol.continuation_steps > 0);
        let r = sys
            .static_residual(sol.q.as_slice(), &loads, &mut ws)
            .unwrap();
        assert!(inf_norm(r) <= opts.residual_tol, "{}", inf_norm(r));
        let (min_eig, asym) = min_stiffness_eig(&sys, &loads, sol.q.as_slice());
        assert!(asym < 1e-12, "gravity tangent not symmetric: {asym:e}");
        assert_eq!(sol.stable, Some(min_eig > 0.0), "min eigenvalue {min_eig}");
        assert!(
            min_eig > 0.0,
            "continuation ended on an unstable equilibrium"
        );
    }

    /// The stability flag (from the tree pivots) agrees with the dense
    /// tangent's eigenvalues on chains below and beyond their buckling load
    /// under gravity (both outcomes occur).
    #[test]
    fn stability_flag_matches_dense_eigenvalues() {
        let mut seen = [false; 2];
        for n in [6usize, 12, 17, 34] {
            let mut spec = spine_chain(n);
            spec.gravity = Vector3::new(0.0, -9.80665, 0.0);
            let sys = System::new(&spec).unwrap();
            let loads = LoadSet::empty();
            for method in [TangentMethod::Auto, TangentMethod::Dense] {
                let mut ws = Workspace::new(&sys);
                let opts = StaticOptions {
                    tangent: method,
                    ..StaticOptions::default()
                };
                let sol = sys
                    .solve_static(&loads, sys.default_q().as_slice(), &mut ws, &opts)
                    .unwrap();
                let (min_eig, _) = min_stiffness_eig(&sys, &loads, sol.q.as_slice());
                assert!(min_eig.abs() > 1e-3, "{n}: too close to singular to judge");
                assert_eq!(
                    sol.stable,
                    Some(min_eig > 0.0),
                    "{n} joints {method:?}: min eigenvalue {min_eig}"
                );
                seen[(min_eig > 0.0) as usize] = true;
            }
        }
        assert!(
            seen[0] && seen[1],
            "both stable and unstable cases expected"
        );
    }

    /// Non-conservative loads (a moment): no energy criterion.
    #[test]
    fn stability_unknown_under_moments() {
        let sys = System::new(&spine_chain(6)).unwrap();
        let loads = sys
            .prepare_loads(&[Load::Moment {
                body: "v6".into(),
                vec: Vector3::new(0.0, 0.0, -7.5),
                frame: LoadFrame::Ground,
            }])
            .unwrap();
        let mut ws = Workspace::new(&sys);
        let sol = sys
            .solve_static(
                &loads,
                sys.default_q().as_slice(),
                &mut ws,
                &StaticOptions::default(),
            )
            .unwrap();
        assert_eq!(sol.stable, None);
        assert_eq!(sol.continuation_steps, 0);
    }

    /// A load that cannot be carried: a moment along the Y axis of the joint
    /// frame of a one-joint chain (gravity off; the frame is turned 0.06 rad
    /// about Z) turns the joint by exactly `ry = s M / k_y` (with rx = rz = 0
    /// the Y axis stays put and the moment has no X or Z component), so the
    /// equilibria end at the bushing's gimbal limit, at the load factor
    /// `s* = GIMBAL_LIMIT k_y / M`. The error must say how far the loads
    /// could be carried: `s*`.
    #[test]
    fn reports_the_load_factor_reached() {
        let sys = System::new(&spine_chain(1)).unwrap();
        let (m, ky) = (1000.0, 291.0);
        let loads = sys
            .prepare_loads(&[Load::Moment {
                body: "v1".into(),
                vec: Vector3::new(-(0.06f64.sin()), 0.06f64.cos(), 0.0) * m,
                frame: LoadFrame::Ground,
            }])
            .unwrap();
        let mut ws = Workspace::new(&sys);
        let err = sys
            .solve_static(
                &loads,
                sys.default_q().as_slice(),
                &mut ws,
                &StaticOptions::default(),
            )
            .unwrap_err()
            .to_string();
        let s_star = GIMBAL_LIMIT * ky / m;
        let reached: f64 = err
            .split("up to s = ")
            .nth(1)
            .and_then(|t| t.split_whitespace().next())
            .and_then(|t| t.parse().ok())
            .unwrap_or_else(|| panic!("no load factor in: {err}"));
        assert!(
            reached <= s_star + 1e-4 && reached > s_star - 2e-3,
            "reached {reached}, expected about {s_star}: {err}"
        );
    }
}
