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

use super::forces::{self, GimbalLock, LoadSet};
use super::kinematics;
use super::scalar::{d6_eps, d6_var, Scalar, D6};
use super::system::{Factored, KinBuf, System, Workspace};
use super::tree::TangentMethod;
use crate::error::{Error, Result};
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
}

impl Default for StaticOptions {
    fn default() -> Self {
        StaticOptions {
            max_iterations: 200,
            residual_tol: 1e-9,
            step_tol: 1e-10,
            max_rotation_step: 0.5,
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
}

fn inf_norm(v: &[f64]) -> f64 {
    v.iter().fold(0.0f64, |m, x| m.max(x.abs()))
}
fn two_norm(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
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
        self.check_q(q)?;
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
                format!("coordinate '{}' is not finite", self.dof_name(i)),
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
    ) -> Result<(), GimbalLock> {
        ws.factored = Factored::None;
        if ws.method == TangentMethod::Auto && ws.tree.usable {
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

    /// The tangent `d tau / d q` at `q` as a new matrix (for inspection and tests).
    pub fn static_tangent(
        &self,
        q: &[f64],
        loads: &LoadSet,
        ws: &mut Workspace,
    ) -> Result<DMatrix<f64>> {
        self.check_q(q)?;
        self.eval_tangent(q, loads, ws)
            .map_err(|g| g.to_error(self))?;
        ws.factored = Factored::None;
        Ok(ws.lu.a.clone())
    }

    /// Solve for static equilibrium from the start `q0` (e.g. the default
    /// pose or a previous solution: warm start).
    pub fn solve_static(
        &self,
        loads: &LoadSet,
        q0: &[f64],
        ws: &mut Workspace,
        opts: &StaticOptions,
    ) -> Result<StaticSolution> {
        self.check_q(q0)?;
        let n = self.n_dofs();
        let ctx = "static equilibrium";
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
            });
        }
        let mut it = 0;
        loop {
            if it >= opts.max_iterations {
                let (worst, val) = ws.r.iter().enumerate().fold((0, 0.0f64), |a, (i, v)| {
                    if v.abs() > a.1 {
                        (i, v.abs())
                    } else {
                        a
                    }
                });
                return Err(Error::numerical(
                    ctx,
                    format!(
                        "no equilibrium found after {it} Newton iterations: the largest generalised force \
                         residual is {val:.3e} (coordinate '{}'); the loads may be too large for the model to carry",
                        self.dof_name(worst)
                    ),
                ));
            }
            for i in 0..n {
                ws.dq[i] = -ws.r[i];
            }
            self.factor_and_solve(&q, loads, ws)
                .map_err(|g| g.to_error(self))?;
            if ws.factored == Factored::None {
                return Err(Error::numerical(
                    ctx,
                    format!("singular tangent stiffness at iteration {it}: a degree of freedom has no stiffness (add a bushing, lock the coordinate or fix a body)"),
                ));
            }
            if ws.dq.iter().any(|v| !v.is_finite()) {
                return Err(Error::numerical(
                    ctx,
                    format!("Newton step not finite at iteration {it}"),
                ));
            }
            let r_inf = inf_norm(&ws.r);
            let step_inf = inf_norm(&ws.dq);
            it += 1;
            if r_inf <= opts.residual_tol && step_inf <= opts.step_tol {
                for i in 0..n {
                    q[i] += ws.dq[i];
                }
                ws.k64.q.copy_from_slice(&q);
                eval_tau(self, loads, &mut ws.k64).map_err(|g| g.to_error(self))?;
                ws.r.copy_from_slice(&ws.k64.tau);
                return Ok(StaticSolution {
                    q: DVector::from_vec(q),
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
                        return Ok(StaticSolution {
                            q: DVector::from_vec(q),
                            iterations: it,
                            residual_norm: r_inf,
                        });
                    }
                    // a gimbal lock right at the current point is the real cause
                    ws.k64.q.copy_from_slice(&q);
                    if let Err(g) = eval_tau(self, loads, &mut ws.k64) {
                        return Err(g.to_error(self));
                    }
                    return Err(Error::numerical(
                        ctx,
                        format!(
                            "no equilibrium found: the line search stalled at iteration {it} with largest \
                             generalised force residual {r_inf:.3e} (the loads may be too large, or a bushing \
                             approaches gimbal lock)"
                        ),
                    ));
                }
            }
            q.copy_from_slice(&ws.q_trial);
            ws.r.copy_from_slice(&ws.k64.tau);
        }
    }

    /// Solve `T x = rhs` in place with the factorised tangent `T = d tau / d q`
    /// of the last Newton iteration of [`System::solve_static`] (for
    /// sensitivities `dq/dp = -T^{-1} d tau / d p`).
    pub fn tangent_solve(&self, ws: &Workspace, rhs: &mut [f64]) -> Result<()> {
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
