//! Forward dynamics: mass matrix by the composite-rigid-body algorithm,
//! velocity-dependent terms by a recursive Newton-Euler pass (spatial vectors
//! as Plücker coordinates about the ground origin, ground axes; the time
//! derivative of each motion subspace comes exactly from a dual-number pass
//! along the speeds), generalised accelerations, energy bookkeeping, and an
//! implicit-midpoint integrator for stiff bushings.
//!
//! Everything here is in OpenSim's generalised speeds `u` (see
//! [`crate::solver::kinematics`]): for FreeJoint/BallJoint rotations `u` is
//! the angular velocity `w_FM` in F axes and `qdot = N(q) u`; the mass
//! matrix is `H_u^T I H_u`, accelerations are `udot`, and the integrator
//! advances `q` with `N(q) u`. For all other joints `u = qdot`.

use super::forces::{self, LoadSet};
use super::kinematics;
use super::linalg::{cholesky_in_place, cholesky_solve, DenseLu};
use super::scalar::Scalar;
use super::system::{BodyIndex, System};
use super::workspace::{SpatialInertia, Workspace};
use crate::error::{Error, Result, SolverError};
use nalgebra::{DVector, Matrix3, Vector3};
use num_dual::Dual64;

impl SpatialInertia {
    /// From mass, centre of mass in ground and inertia about it (ground axes).
    pub(crate) fn new(m: f64, c: &Vector3<f64>, i_c: &Matrix3<f64>) -> Self {
        let i = i_c + (Matrix3::identity() * c.dot(c) - c * c.transpose()) * m;
        SpatialInertia { m, h: c * m, i }
    }
    /// Momentum `I V` of the twist `V = (w, v_O)`.
    #[inline]
    pub(crate) fn mul(&self, v: &[Vector3<f64>; 2]) -> [Vector3<f64>; 2] {
        [
            self.i * v[0] + self.h.cross(&v[1]),
            v[1] * self.m - self.h.cross(&v[0]),
        ]
    }
    /// Adds another inertia about the same point (a composite body).
    pub(crate) fn add(&mut self, o: &SpatialInertia) {
        self.m += o.m;
        self.h += o.h;
        self.i += o.i;
    }
}

/// Spatial force cross product `V x* F`.
#[inline]
fn cross_force(v: &[Vector3<f64>; 2], f: &[Vector3<f64>; 2]) -> [Vector3<f64>; 2] {
    [v[0].cross(&f[0]) + v[1].cross(&f[1]), v[0].cross(&f[1])]
}

#[inline]
fn dot6(a: &[Vector3<f64>; 2], b: &[Vector3<f64>; 2]) -> f64 {
    a[0].dot(&b[0]) + a[1].dot(&b[1])
}

/// Energy of a state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Energy {
    /// Kinetic energy `1/2 u^T M u` (J).
    pub kinetic: f64,
    /// `-sum m g . c` (zero at the ground origin).
    pub gravity: f64,
    /// Bushing potential energy (`1/2 sum K q^2` for linear bushings; see
    /// [`crate::solver::law`] for the other laws).
    pub bushing: f64,
}

impl Energy {
    /// Kinetic plus gravitational plus bushing potential energy (J).
    pub fn total(&self) -> f64 {
        self.kinetic + self.gravity + self.bushing
    }
}

impl System {
    /// Spatial inertia of body `bi` at the poses in `ws.k64`.
    fn body_inertia(&self, ws: &Workspace, bi: usize) -> SpatialInertia {
        let b = &self.bodies[bi];
        let x = ws.k64.x_gb[bi];
        let c = x.point(&b.com);
        let ic = x.r * b.inertia * x.r.transpose();
        SpatialInertia::new(b.mass, &c, &ic)
    }

    /// Kinematics with speeds: fills poses and subspaces in `ws.k64`, the
    /// subspace time derivatives in `ws.hdot`, body twists in `ws.vel`, bias
    /// accelerations in `ws.acc`, and the applied wrenches (gravity, bushings
    /// with damping, loads) in `ws.k64.w`.
    fn velocity_pass(
        &self,
        q: &[f64],
        u: &[f64],
        loads: &LoadSet,
        ws: &mut Workspace,
    ) -> Result<()> {
        self.check_inputs(q, loads, ws)?;
        if u.len() != q.len() || u.iter().any(|v| !v.is_finite()) {
            return Err(Error::invalid(
                "solver",
                "speeds must be finite, one per coordinate",
            ));
        }
        self.qdot(q, u, &mut ws.qdot)?;
        for ((d, &qi), &ri) in ws.kd1.q.iter_mut().zip(q).zip(&ws.qdot) {
            *d = Dual64::new(qi, ri);
        }
        // subspaces per unit speed; their dual parts are time derivatives
        // because the dual directions are the coordinate rates
        kinematics::forward_speeds(self, &mut ws.kd1);
        for (bi, x) in ws.kd1.x_gb.iter().enumerate() {
            ws.k64.x_gb[bi] = x.re();
        }
        for (k, h) in ws.kd1.h.iter().enumerate() {
            ws.k64.h[k] = [h[0].map(|x| x.re), h[1].map(|x| x.re)];
            ws.hdot[k] = [h[0].map(|x| x.eps), h[1].map(|x| x.eps)];
        }
        for bi in 0..self.bodies.len() {
            let b = &self.bodies[bi];
            let (mut v, mut a) = match b.parent {
                Some(p) => (ws.vel[p.0], ws.acc[p.0]),
                None => ([Vector3::zeros(); 2], [Vector3::zeros(); 2]),
            };
            for k in b.joint.dofs() {
                let h = ws.k64.h[k];
                let hd = ws.hdot[k];
                v[0] += h[0] * u[k];
                v[1] += h[1] * u[k];
                a[0] += hd[0] * u[k];
                a[1] += hd[1] * u[k];
            }
            ws.vel[bi] = v;
            ws.acc[bi] = a;
        }
        // applied wrenches
        for w in ws.k64.w.iter_mut() {
            *w = [Vector3::zeros(), Vector3::zeros()];
        }
        forces::gravity_wrenches(self, &mut ws.k64);
        for (i, b) in self.bushings.iter().enumerate() {
            if b.fast.is_some() {
                continue;
            }
            let (_, _, qr, qt) = forces::bushing_deflection(b, &ws.kd1);
            if qr.y.re.abs() >= forces::GIMBAL_LIMIT {
                return Err(forces::GimbalLock {
                    bushing: i,
                    angle: qr.y.re,
                }
                .to_error(self));
            }
            let g = b
                .law
                .g(&[qr.x.re, qr.y.re, qr.z.re, qt.x.re, qt.y.re, qt.z.re]);
            let fr = Vector3::new(
                -(g[0] + b.c[0] * qr.x.eps),
                -(g[1] + b.c[1] * qr.y.eps),
                -(g[2] + b.c[2] * qr.z.eps),
            );
            let ft = Vector3::new(
                -(g[3] + b.c[3] * qt.x.eps),
                -(g[4] + b.c[4] * qt.y.eps),
                -(g[5] + b.c[5] * qt.z.eps),
            );
            let (x1, x2, qr64, _) = forces::bushing_deflection(b, &ws.k64);
            forces::bushing_apply(b, &x1, &x2, &qr64, &fr, &ft, &mut ws.k64.w);
        }
        forces::load_wrenches(loads, &mut ws.k64);
        Ok(())
    }

    /// Generalised accelerations `udot` at (q, u) under `loads`; `udot` has
    /// one entry per free dof. Speeds are OpenSim's generalised speeds
    /// (coordinate rates except FreeJoint/BallJoint rotations: see
    /// [`System::qdot`]).
    pub fn accelerations(
        &self,
        q: &[f64],
        u: &[f64],
        loads: &LoadSet,
        ws: &mut Workspace,
        udot: &mut [f64],
    ) -> Result<()> {
        let n = self.n_dofs();
        if udot.len() != n {
            return Err(Error::invalid(
                "solver",
                "accelerations: output has the wrong length",
            ));
        }
        self.velocity_pass(q, u, loads, ws)?;
        // w_b <- F_ext - (I A_bias + V x* I V), then project
        for bi in 0..self.bodies.len() {
            let ib = self.body_inertia(ws, bi);
            ws.comp[bi] = ib;
            let iv = ib.mul(&ws.vel[bi]);
            let ia = ib.mul(&ws.acc[bi]);
            let cf = cross_force(&ws.vel[bi], &iv);
            let w = &mut ws.k64.w[bi];
            w[0] -= ia[0] + cf[0];
            w[1] -= ia[1] + cf[1];
        }
        forces::project(self, &mut ws.k64);
        if self.any_euler_speeds {
            // fast-path bushings act on the coordinate rates: map their
            // generalised force onto the speeds (N^T f)
            ws.rhs.fill(0.0);
            forces::add_fast_bushings(self, q, Some(&ws.qdot), &mut ws.rhs)
                .map_err(|g| g.to_error(self))?;
            self.rate_forces_to_speeds(q, &mut ws.rhs)?;
            for (r, t) in ws.rhs.iter_mut().zip(&ws.k64.tau) {
                *r += t;
            }
        } else {
            forces::add_fast_bushings(self, q, Some(u), &mut ws.k64.tau)
                .map_err(|g| g.to_error(self))?;
            ws.rhs.copy_from_slice(&ws.k64.tau);
        }
        self.mass_matrix_from_comp(ws);
        if !cholesky_in_place(&mut ws.mass) {
            return Err(Error::solver(
                "dynamics",
                SolverError::MassMatrixNotPositiveDefinite,
            ));
        }
        cholesky_solve(&ws.mass, &mut ws.rhs);
        udot.copy_from_slice(&ws.rhs);
        Ok(())
    }

    /// CRBA with `ws.comp` holding each body's own inertia on entry
    /// (composite inertias on exit); subspaces from `ws.k64.h`.
    fn mass_matrix_from_comp(&self, ws: &mut Workspace) {
        for bi in (0..self.bodies.len()).rev() {
            if let Some(p) = self.bodies[bi].parent {
                let c = ws.comp[bi];
                ws.comp[p.0].add(&c);
            }
        }
        ws.mass.fill(0.0);
        for bi in 0..self.bodies.len() {
            let j = &self.bodies[bi].joint;
            for k in j.dofs() {
                let f = ws.comp[bi].mul(&ws.k64.h[k]);
                let mut a = Some(BodyIndex(bi));
                while let Some(ai) = a {
                    let ja = &self.bodies[ai.0].joint;
                    for l in ja.dofs() {
                        let v = dot6(&ws.k64.h[l], &f);
                        ws.mass[(l, k)] = v;
                        ws.mass[(k, l)] = v;
                    }
                    a = self.bodies[ai.0].parent;
                }
            }
        }
    }

    /// The mass matrix at q in the generalised speeds (kinetic energy
    /// `1/2 u^T M u`; a copy, for tests and inspection).
    pub fn mass_matrix(&self, q: &[f64], ws: &mut Workspace) -> Result<nalgebra::DMatrix<f64>> {
        self.check_workspace(ws)?;
        self.check_q(q)?;
        ws.k64.q.copy_from_slice(q);
        kinematics::forward_speeds(self, &mut ws.k64);
        for bi in 0..self.bodies.len() {
            ws.comp[bi] = self.body_inertia(ws, bi);
        }
        self.mass_matrix_from_comp(ws);
        Ok(ws.mass.clone())
    }

    /// Kinetic, gravitational and bushing potential energy at (q, u).
    pub fn energy(&self, q: &[f64], u: &[f64], ws: &mut Workspace) -> Result<Energy> {
        self.velocity_pass(q, u, &LoadSet::empty(), ws)?;
        let mut ke = 0.0;
        let mut pg = 0.0;
        for bi in 0..self.bodies.len() {
            let ib = self.body_inertia(ws, bi);
            ke += 0.5 * dot6(&ws.vel[bi], &ib.mul(&ws.vel[bi]));
            let c = ws.k64.x_gb[bi].point(&self.bodies[bi].com);
            pg -= self.bodies[bi].mass * self.gravity.dot(&c);
        }
        let mut pb = 0.0;
        for b in &self.bushings {
            let (_, _, qr, qt) = forces::bushing_deflection(b, &ws.k64);
            pb += b.law.potential(&[qr.x, qr.y, qr.z, qt.x, qt.y, qt.z]);
        }
        Ok(Energy {
            kinetic: ke,
            gravity: pg,
            bushing: pb,
        })
    }
}

/// Implicit-midpoint integrator (symplectic, A-stable; energy is conserved to
/// O(dt^2) without damping) with a Newton solve of the stage equation. The
/// Newton matrix uses a finite-difference Jacobian of the accelerations,
/// refreshed only when convergence slows. The stage coordinates solve
/// `yq = q + (dt/2) N(yq) yu` (a fixed point, exact in one pass when every
/// speed is a coordinate rate).
pub struct Integrator {
    /// Step size (s).
    pub dt: f64,
    /// Newton tolerance on the stage speeds (rad/s or m/s).
    pub tol: f64,
    n: usize,
    lu: DenseLu,
    have_jac: bool,
    /// The system the cached Jacobian belongs to (refreshed when it changes).
    jac_for: super::system::SystemId,
    a0: Vec<f64>,
    a1: Vec<f64>,
    yq: Vec<f64>,
    yu: Vec<f64>,
    g: Vec<f64>,
    tmpq: Vec<f64>,
    tmpu: Vec<f64>,
    /// Start of the current step, and rates scratch (angular-velocity speeds).
    q0: Vec<f64>,
    qd: Vec<f64>,
}

/// One output sample of a trajectory.
#[derive(Debug, Clone)]
pub struct Sample {
    /// Time of the sample (s).
    pub time: f64,
    /// Generalised coordinates at that time (rad or m per coordinate).
    pub q: DVector<f64>,
    /// Generalised speeds at that time (rad/s or m/s per speed).
    pub u: DVector<f64>,
}

impl Integrator {
    /// An integrator for `sys` with step `dt` (s) and the default Newton tolerance 1e-10.
    pub fn new(sys: &System, dt: f64) -> Self {
        let n = sys.n_dofs();
        Integrator {
            dt,
            tol: 1e-10,
            n,
            lu: DenseLu::new(n),
            have_jac: false,
            jac_for: sys.id(),
            a0: vec![0.0; n],
            a1: vec![0.0; n],
            yq: vec![0.0; n],
            yu: vec![0.0; n],
            g: vec![0.0; n],
            tmpq: vec![0.0; n],
            tmpu: vec![0.0; n],
            q0: vec![0.0; n],
            qd: vec![0.0; n],
        }
    }

    /// Stage coordinates `yq = q + h2 N(yq) yu`. With coordinate-rate speeds
    /// only, `yq = q + h2 yu` directly; otherwise a fixed-point iteration
    /// (a contraction for any step the Newton iteration converges with).
    fn stage_q(
        sys: &System,
        h2: f64,
        q: &[f64],
        yu: &[f64],
        yq: &mut [f64],
        qd: &mut [f64],
    ) -> Result<()> {
        for i in 0..q.len() {
            yq[i] = q[i] + h2 * yu[i];
        }
        if !sys.any_euler_speeds {
            return Ok(());
        }
        for _ in 0..100 {
            sys.qdot(yq, yu, qd)?;
            let mut change = 0.0f64;
            let mut scale = 1.0f64;
            for i in 0..q.len() {
                let v = q[i] + h2 * qd[i];
                change = change.max((v - yq[i]).abs());
                scale = scale.max(v.abs());
                yq[i] = v;
            }
            if change <= 4.0 * f64::EPSILON * scale {
                return Ok(());
            }
            if !change.is_finite() {
                break;
            }
        }
        Err(Error::solver("dynamics", SolverError::StageNotConverged))
    }

    /// Newton matrix `I - (h/2) [(h/2) A_q + A_u]` at the midpoint guess.
    fn jacobian(&mut self, sys: &System, loads: &LoadSet, ws: &mut Workspace) -> Result<()> {
        let n = self.n;
        let h2 = 0.5 * self.dt;
        sys.accelerations(&self.yq, &self.yu, loads, ws, &mut self.a0)?;
        for j in 0..n {
            let eq = 1e-7 * (1.0 + self.yq[j].abs());
            let eu = 1e-6 * (1.0 + self.yu[j].abs());
            self.tmpq.copy_from_slice(&self.yq);
            self.tmpu.copy_from_slice(&self.yu);
            // combined direction: d/dyu of a(q0 + h2 N yu, yu)
            self.tmpu[j] += eu;
            if sys.any_euler_speeds {
                Self::stage_q(sys, h2, &self.q0, &self.tmpu, &mut self.tmpq, &mut self.qd)?;
            } else {
                self.tmpq[j] += h2 * eu;
            }
            sys.accelerations(&self.tmpq, &self.tmpu, loads, ws, &mut self.a1)?;
            let _ = eq;
            for i in 0..n {
                let d = (self.a1[i] - self.a0[i]) / eu;
                self.lu.a[(i, j)] = if i == j { 1.0 } else { 0.0 } - h2 * d;
            }
        }
        if !self.lu.factor() {
            return Err(Error::solver("dynamics", SolverError::SingularNewtonMatrix));
        }
        self.have_jac = true;
        Ok(())
    }

    /// Advance (q, u) by one step of `dt`.
    pub fn step(
        &mut self,
        sys: &System,
        loads: &LoadSet,
        ws: &mut Workspace,
        q: &mut [f64],
        u: &mut [f64],
    ) -> Result<()> {
        let n = self.n;
        let h2 = 0.5 * self.dt;
        // a Jacobian of another parameter set is stale; another structure is refused
        if self.jac_for != sys.id() {
            if self.jac_for.structure != sys.id().structure {
                return Err(Error::invalid(
                    "dynamics",
                    "the integrator was made for another system (make one with Integrator::new for this system)",
                ));
            }
            self.have_jac = false;
            self.jac_for = sys.id();
        }
        // initial guess: explicit half step (the call checks q and u)
        sys.accelerations(q, u, loads, ws, &mut self.a0)?;
        self.q0.copy_from_slice(q);
        for i in 0..n {
            self.yu[i] = u[i] + h2 * self.a0[i];
        }
        Self::stage_q(sys, h2, q, &self.yu, &mut self.yq, &mut self.qd)?;
        let mut refreshed = false;
        if !self.have_jac {
            self.jacobian(sys, loads, ws)?;
            refreshed = true;
        }
        let mut it = 0;
        loop {
            Self::stage_q(sys, h2, q, &self.yu, &mut self.yq, &mut self.qd)?;
            sys.accelerations(&self.yq, &self.yu, loads, ws, &mut self.a1)?;
            for i in 0..n {
                self.g[i] = -(self.yu[i] - u[i] - h2 * self.a1[i]);
            }
            self.lu.solve_in_place(&mut self.g);
            let mut dmax = 0.0f64;
            let mut umax = 1.0f64;
            for i in 0..n {
                self.yu[i] += self.g[i];
                dmax = dmax.max(self.g[i].abs());
                umax = umax.max(self.yu[i].abs());
            }
            it += 1;
            if dmax <= self.tol * umax {
                break;
            }
            if !dmax.is_finite() || it > 12 {
                if refreshed {
                    return Err(Error::solver(
                        "dynamics",
                        SolverError::StepNotConverged { dt: self.dt },
                    ));
                }
                // refresh the Jacobian and restart from the explicit guess
                for i in 0..n {
                    self.yu[i] = u[i] + h2 * self.a0[i];
                }
                Self::stage_q(sys, h2, q, &self.yu, &mut self.yq, &mut self.qd)?;
                self.jacobian(sys, loads, ws)?;
                refreshed = true;
                it = 0;
            } else if it == 6 && !refreshed {
                self.jacobian(sys, loads, ws)?;
                refreshed = true;
            }
        }
        Self::stage_q(sys, h2, q, &self.yu, &mut self.yq, &mut self.qd)?;
        for i in 0..n {
            q[i] = 2.0 * self.yq[i] - q[i];
            u[i] = 2.0 * self.yu[i] - u[i];
        }
        Ok(())
    }

    /// Integrate from (q, u) over `duration`, sampling every `every` steps.
    #[allow(clippy::too_many_arguments)] // system, loads, workspace, start state, duration, sampling
    pub fn run(
        &mut self,
        sys: &System,
        loads: &LoadSet,
        ws: &mut Workspace,
        q0: &[f64],
        u0: &[f64],
        duration: f64,
        every: usize,
    ) -> Result<Vec<Sample>> {
        self.run_observed(sys, loads, ws, (q0, u0), duration, every, &mut |_, _| {})
    }

    /// [`Integrator::run`], calling `progress(step, steps)` after every
    /// step (for a progress bar). Refuses more than [`MAX_STEPS`] steps.
    #[allow(clippy::too_many_arguments)]
    pub fn run_observed(
        &mut self,
        sys: &System,
        loads: &LoadSet,
        ws: &mut Workspace,
        (q0, u0): (&[f64], &[f64]),
        duration: f64,
        every: usize,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<Vec<Sample>> {
        let steps = step_count(duration, self.dt)?;
        let mut q = q0.to_vec();
        let mut u = u0.to_vec();
        // At most MAX_SAMPLES samples are kept, however long the run.
        let every = every.max(1).max(steps / MAX_SAMPLES);
        let mut out = vec![Sample {
            time: 0.0,
            q: DVector::from_vec(q.clone()),
            u: DVector::from_vec(u.clone()),
        }];
        for s in 1..=steps {
            self.step(sys, loads, ws, &mut q, &mut u)?;
            progress(s, steps);
            if s % every == 0 || s == steps {
                out.push(Sample {
                    time: s as f64 * self.dt,
                    q: DVector::from_vec(q.clone()),
                    u: DVector::from_vec(u.clone()),
                });
            }
        }
        Ok(out)
    }
}

/// Most integration steps one run may take (a step cap: `--dynamic 1e9
/// --dt 1e-9` is refused up front instead of running for ever).
const MAX_STEPS: usize = 10_000_000;
/// Most samples one run keeps (longer runs sample more sparsely).
const MAX_SAMPLES: usize = 100_000;

/// Number of steps of `duration` at `dt`, refused beyond [`MAX_STEPS`].
pub fn step_count(duration: f64, dt: f64) -> Result<usize> {
    if !(dt > 0.0 && dt.is_finite() && duration >= 0.0 && duration.is_finite()) {
        return Err(Error::invalid(
            "dynamics",
            "time step and duration must be positive and finite",
        ));
    }
    let steps = (duration / dt).round();
    if steps > MAX_STEPS as f64 {
        return Err(Error::invalid(
            "dynamics",
            format!(
                "{duration} s at a time step of {dt} s is {steps:e} steps, more than the cap of {MAX_STEPS}; use a longer --dt or a shorter duration"
            ),
        ));
    }
    Ok(steps as usize)
}

#[allow(dead_code)]
fn _assert_scalar<T: Scalar>() {}
