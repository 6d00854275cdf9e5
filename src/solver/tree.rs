//! Structured O(n) statics tangent for tree-coupled systems: assembly of its
//! per-body blocks and an exact block elimination from the leaves to the
//! root (an "articulated stiffness" recursion, the statics analogue of the
//! articulated-body algorithm).
//!
//! # Why the tangent has tree structure
//!
//! The static residual of joint `b` is `tau_b = H_b^T W_b + f_b(q_b)` with
//! `H_b` the joint's motion subspace (6 x n_b, Plücker about the ground
//! origin), `W_b` the sum of the wrenches applied to the bodies of `b`'s
//! subtree, and `f_b` the generalised force of fast-path bushings. Perturbing
//! the coordinates moves body `c` by the twist `dx_c = dx_p + H_c dq_c`
//! (`p` its parent, ground fixed). Every force element depends on the poses
//! of at most two bodies; when those are always equal or parent and child
//! (gravity, moments, point forces, follower loads between adjacent bodies,
//! bushings between adjacent bodies or to ground), the wrench of body `c`
//! changes by `G_cc dx_c + G_cp dx_p + sum_d G_cd dx_d` (`d` its children),
//! and
//!
//! ```text
//! d tau_b = H_b^T ( dW_b - Fbar(W_b) dx_p ) + L_b dq_b
//! ```
//!
//! where `Fbar(W) a = crf(a) W` (the motion subspace turns with the parent)
//! and `L_b` holds the joint-local terms (`d H_b / d q_b` against `W_b`, and
//! `d f_b / d q_b`). The linear system `T dq = r` is thus a sparse system on
//! the tree in the unknowns `(dq_b, dx_b, dW_b)`; eliminating a subtree
//! leaves an affine map `dW_b + G_pb dx_b = Ka_b dx_p + za_b` (the
//! *articulated stiffness* `Ka_b`, 6 x 6). Leaves-to-root this costs one
//! n_b x n_b LU and a handful of 6 x 6 products per joint: O(n) per
//! factorisation and per solve, exact (Gaussian elimination in a tree order,
//! partial pivoting inside each joint block). `det T = prod det D_b`, so a
//! singular tangent shows up as a singular block; a block can also be
//! singular when the full tangent is not (pivoting across joints needed):
//! then the caller falls back to the dense LU.
//!
//! # Assembly
//!
//! All blocks are exact derivatives from forward-mode dual numbers, through
//! the same generic force code as the residual (so new force laws are
//! covered automatically):
//! - `G` blocks: the body poses are seeded with a six-direction twist
//!   perturbation `x_c(e) = exp(e) x_c`, all bodies of one colour at once;
//!   the colouring is a distance-2 colouring of the tree (a body, its parent,
//!   grandparent and siblings all differ), so the wrench derivative of every
//!   body is attributable to exactly one body of its neighbourhood. A chain
//!   needs three passes whatever its length.
//! - `L_b`: one dual pass of the joint's own kinematics (parent pose
//!   constant) and of the fast-path bushings, every joint seeded at once.
//!
//! Systems with a force element between non-adjacent bodies (e.g. a bushing
//! skipping a level) are not tree-coupled and use the dense tangent.

use super::forces::{self, GimbalLock, LoadSet, Resolved};
use super::kinematics;
use super::linalg::Lu6;
use super::scalar::{d6_eps, d6_var, D6};
use super::system::{BodyIndex, Pose, System};
use super::workspace::{KinBuf, TreeTangent};
use nalgebra::{Matrix3, Matrix6, SVector, Vector3, Vector6};
use num_dual::Derivative;

/// How the Newton step (and [`System::tangent_solve`]) factorises the
/// statics tangent.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum TangentMethod {
    /// Structured O(n) elimination on tree-coupled systems, dense LU
    /// otherwise or when a joint block needs pivoting across joints.
    #[default]
    Auto,
    /// Always assemble the dense tangent (one dual pass per joint) and
    /// factorise it with a dense LU: O(n^2) assembly, O(n^3) factorisation.
    Dense,
}

/// `[v]x`, the cross-product matrix.
#[inline]
fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// `Fbar(W)` with `crf(a) W = Fbar(W) a` for a wrench `W = (n, f)`:
/// `[[-[n]x, -[f]x], [-[f]x, 0]]`.
fn fbar(w: &[Vector3<f64>; 2]) -> Matrix6<f64> {
    let mut m = Matrix6::zeros();
    let sn = -skew(&w[0]);
    let sf = -skew(&w[1]);
    m.fixed_view_mut::<3, 3>(0, 0).copy_from(&sn);
    m.fixed_view_mut::<3, 3>(0, 3).copy_from(&sf);
    m.fixed_view_mut::<3, 3>(3, 0).copy_from(&sf);
    m
}

/// A dual number with value `re` and derivative `eps`.
#[inline]
fn d6(re: f64, eps: [f64; 6]) -> D6 {
    D6::new(re, Derivative::some(SVector::<f64, 6>::from(eps)))
}

/// `e_a x v` for the unit vector `e_a`.
#[inline]
fn unit_cross(a: usize, v: &Vector3<f64>) -> Vector3<f64> {
    match a {
        0 => Vector3::new(0.0, -v.z, v.y),
        1 => Vector3::new(v.z, 0.0, -v.x),
        _ => Vector3::new(-v.y, v.x, 0.0),
    }
}

/// The pose `exp(e) x` to first order in the twist `e = (w, v)` (ground
/// axes, about the ground origin) as six-direction dual numbers:
/// `R + [w]x R`, `p + w x p + v`.
fn perturbed(x: &Pose<f64>) -> Pose<D6> {
    let cols: [Vector3<f64>; 3] = [
        x.r.column(0).into_owned(),
        x.r.column(1).into_owned(),
        x.r.column(2).into_owned(),
    ];
    let wc: [[Vector3<f64>; 3]; 3] = [
        [
            unit_cross(0, &cols[0]),
            unit_cross(1, &cols[0]),
            unit_cross(2, &cols[0]),
        ],
        [
            unit_cross(0, &cols[1]),
            unit_cross(1, &cols[1]),
            unit_cross(2, &cols[1]),
        ],
        [
            unit_cross(0, &cols[2]),
            unit_cross(1, &cols[2]),
            unit_cross(2, &cols[2]),
        ],
    ];
    let r = Matrix3::from_fn(|i, j| {
        let w = &wc[j];
        d6(x.r[(i, j)], [w[0][i], w[1][i], w[2][i], 0.0, 0.0, 0.0])
    });
    let wp = [
        unit_cross(0, &x.p),
        unit_cross(1, &x.p),
        unit_cross(2, &x.p),
    ];
    let p = Vector3::from_fn(|i, _| {
        let mut e = [wp[0][i], wp[1][i], wp[2][i], 0.0, 0.0, 0.0];
        e[3 + i] = 1.0;
        d6(x.p[i], e)
    });
    Pose { r, p }
}

/// A constant pose as dual numbers.
#[inline]
fn constant(x: &Pose<f64>) -> Pose<D6> {
    Pose {
        r: x.r.map(D6::from_re),
        p: x.p.map(D6::from_re),
    }
}

/// The derivative of a dual wrench as a 6 x 6 matrix (rows: moment, force).
#[inline]
fn wrench_jacobian(w: &[Vector3<D6>; 2]) -> Matrix6<f64> {
    let mut m = Matrix6::zeros();
    for i in 0..3 {
        let a = d6_eps(&w[0][i]);
        let b = d6_eps(&w[1][i]);
        for k in 0..6 {
            m[(i, k)] = a[k];
            m[(3 + i, k)] = b[k];
        }
    }
    m
}

/// Mark the bodies whose poses [`forces::static_wrenches`] reads (and the
/// only ones it applies wrenches to): bodies with mass under gravity, the
/// bodies of general-path bushings, loaded bodies. Keep in step with
/// `static_wrenches` when adding force elements (the structured-vs-dense
/// tests catch a miss).
fn mark_touched(sys: &System, loads: &LoadSet, touched: &mut [bool]) {
    touched.fill(false);
    let mut mark = |b: Option<BodyIndex>| {
        if let Some(t) = b.and_then(|b| touched.get_mut(b.0)) {
            *t = true;
        }
    };
    if sys.gravity != Vector3::zeros() {
        for (bi, b) in sys.bodies.iter().enumerate() {
            if b.mass != 0.0 {
                mark(Some(BodyIndex(bi)));
            }
        }
    }
    for b in &sys.bushings {
        if b.fast.is_none() {
            mark(b.body1);
            mark(b.body2);
        }
    }
    for l in &loads.items {
        match l {
            Resolved::Moment { body, .. } | Resolved::Force { body, .. } => mark(Some(*body)),
            Resolved::Follower { upper, lower, .. } => {
                mark(Some(*upper));
                mark(*lower);
            }
        }
    }
}

impl TreeTangent {
    /// Assemble the blocks at the state of `k64` (which must hold a full
    /// residual evaluation: poses, motion subspaces, subtree wrenches after
    /// projection), using `kd6` as dual scratch.
    pub(crate) fn assemble(
        &mut self,
        sys: &System,
        loads: &LoadSet,
        k64: &KinBuf<f64>,
        kd6: &mut KinBuf<D6>,
    ) -> Result<(), GimbalLock> {
        let nb = sys.bodies.len();
        // motion subspaces, -Fbar of the subtree wrenches
        for bi in 0..nb {
            let j = &sys.bodies[bi].joint;
            let mut h = Matrix6::zeros();
            for k in 0..j.dof_count.min(6) {
                if let Some(hk) = k64.h.get(j.dof_start + k) {
                    h.fixed_view_mut::<3, 1>(0, k).copy_from(&hk[0]);
                    h.fixed_view_mut::<3, 1>(3, k).copy_from(&hk[1]);
                }
            }
            self.h[bi] = h;
            self.neg_fbar[bi] = -fbar(&k64.w[bi]);
        }
        // joint-local terms: seed every joint's own dofs at once
        for bi in 0..nb {
            let j = &sys.bodies[bi].joint;
            for k in 0..j.dof_count.min(6) {
                let i = j.dof_start + k;
                kd6.q[i] = d6_var(k64.q[i], k);
            }
        }
        for t in kd6.tau.iter_mut() {
            *t = D6::from_re(0.0);
        }
        forces::add_fast_bushings(sys, &kd6.q, None, &mut kd6.tau)?;
        for bi in 0..nb {
            let b = &sys.bodies[bi];
            let j = &b.joint;
            let n = j.dof_count.min(6);
            let mut l = Matrix6::zeros();
            if n > 0 {
                // h_k . W = w_k . (n' - p_FM x f_F) + v_k . f_F with the
                // joint-local rates (w_k, v_k) and p_FM, and the subtree
                // wrench in F: f_F = R_F^T f, n' = R_F^T (n - o_F x f).
                let x_gf = match b.parent {
                    Some(p) => k64.x_gb[p.0].compose_c(&j.x_pf),
                    None => j.x_pf,
                };
                let w = &k64.w[bi];
                let rt = x_gf.r.transpose();
                let f_f = rt * w[1];
                let n_f = rt * (w[0] - x_gf.p.cross(&w[1]));
                let range = j.dof_start..j.dof_start + n;
                kinematics::joint_local_tangent(j, &k64.q[range], &n_f, &f_f, &mut l);
                for k in 0..n {
                    let e = d6_eps(&kd6.tau[j.dof_start + k]);
                    for m in 0..n {
                        l[(k, m)] += e[m];
                    }
                }
            }
            self.local[bi] = l;
        }
        // wrench derivatives w.r.t. body twists, one pass per colour, only
        // over the bodies some force element reads (the others carry no
        // wrench and stale poses that nothing reads)
        mark_touched(sys, loads, &mut self.touched);
        for g in self
            .g_self
            .iter_mut()
            .chain(self.g_par.iter_mut())
            .chain(self.g_child.iter_mut())
        {
            *g = Matrix6::zeros();
        }
        for bi in 0..nb {
            if self.touched[bi] {
                kd6.x_gb[bi] = constant(&k64.x_gb[bi]);
            }
        }
        for colour in 0..self.n_colours {
            let mut any = false;
            for bi in 0..nb {
                if self.touched[bi] && self.colour[bi] == colour {
                    kd6.x_gb[bi] = perturbed(&k64.x_gb[bi]);
                    any = true;
                }
            }
            if !any {
                continue;
            }
            forces::static_wrenches(sys, loads, kd6)?;
            for bi in 0..nb {
                if !self.touched[bi] {
                    continue;
                }
                let parent = sys.bodies[bi].parent.map(|p| p.0);
                if self.colour[bi] == colour {
                    self.g_self[bi] = wrench_jacobian(&kd6.w[bi]);
                    if let Some(p) = parent.filter(|&p| self.touched[p]) {
                        self.g_child[bi] = wrench_jacobian(&kd6.w[p]);
                    }
                } else if let Some(p) = parent.filter(|&p| self.touched[p]) {
                    if self.colour[p] == colour {
                        self.g_par[bi] = wrench_jacobian(&kd6.w[bi]);
                    }
                }
            }
            for bi in 0..nb {
                if self.touched[bi] && self.colour[bi] == colour {
                    kd6.x_gb[bi] = constant(&k64.x_gb[bi]);
                }
            }
        }
        Ok(())
    }

    /// Factorise (leaves to root). False when a joint block is singular.
    pub(crate) fn factor(&mut self, sys: &System) -> bool {
        let nb = sys.bodies.len();
        for a in self.acc.iter_mut() {
            *a = Matrix6::zeros();
        }
        for bi in (0..nb).rev() {
            let n = sys.bodies[bi].joint.dof_count.min(6);
            let h = &self.h[bi];
            let kb = self.g_self[bi] + self.acc[bi];
            let htk = h.tr_mul(&kb);
            let mut d = htk * h + self.local[bi];
            for i in n..6 {
                d[(i, i)] = 1.0;
            }
            self.pivots[bi] = d;
            let Some(lu) = Lu6::factor(d, n) else {
                return false;
            };
            // V = -D^-1 H^T (K_b + G_bp - Fbar_b)
            let hte = htk + h.tr_mul(&(self.g_par[bi] + self.neg_fbar[bi]));
            let mut v = Matrix6::zeros();
            for c in 0..6 {
                let mut col: Vector6<f64> = -hte.column(c);
                lu.solve(&mut col);
                v.set_column(c, &col);
            }
            let p = kb + self.g_child[bi];
            let ph = p * h;
            if let Some(par) = sys.bodies[bi].parent {
                let ka = p + self.g_par[bi] + ph * v;
                self.acc[par.0] += ka;
            }
            self.lu[bi] = lu;
            self.v[bi] = v;
            self.ph[bi] = ph;
        }
        true
    }

    /// Stability of the equilibrium whose tangent `T` was last factorised
    /// (after a successful [`TreeTangent::factor`]). The elimination is
    /// Gaussian elimination of `T` in a leaves-to-root block order, so the
    /// pivot blocks `D_b` are Schur complements; when `T` is symmetric
    /// (conservative forces: `T = -Hess V`), Haynsworth's inertia additivity
    /// gives `inertia(T) = sum inertia(D_b)`, and the equilibrium is stable
    /// (`-T` positive definite, a strict minimum of the potential energy)
    /// exactly when every `-D_b` is positive definite. None when a pivot
    /// block is not symmetric to round-off (non-conservative forces, where
    /// the energy test does not apply).
    pub(crate) fn stability(&self, sys: &System) -> Option<bool> {
        let mut stable = true;
        for (bi, d) in self.pivots.iter().enumerate().take(sys.bodies.len()) {
            let n = sys.bodies[bi].joint.dof_count.min(6);
            if n == 0 {
                continue;
            }
            let scale = d.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let asym = (d - d.transpose())
                .iter()
                .fold(0.0f64, |m, v| m.max(v.abs()));
            if asym.is_nan() || asym > 1e-9 * scale {
                return None;
            }
            let mut m = -(d + d.transpose()) * 0.5;
            for i in n..6 {
                m[(i, i)] = 1.0;
            }
            if m.cholesky().is_none() {
                stable = false;
            }
        }
        Some(stable)
    }

    /// Solve `T x = rhs` in place with the factors (after a successful
    /// [`TreeTangent::factor`]), using the internal scratch.
    pub(crate) fn solve(&mut self, sys: &System, rhs: &mut [f64]) {
        let (mut z, mut u, mut dx) = (
            std::mem::take(&mut self.z),
            std::mem::take(&mut self.u),
            std::mem::take(&mut self.dx),
        );
        self.solve_with(sys, rhs, &mut z, &mut u, &mut dx);
        self.z = z;
        self.u = u;
        self.dx = dx;
    }

    /// Solve `T x = rhs` in place with caller-provided scratch (`n_bodies`
    /// entries each).
    pub(crate) fn solve_with(
        &self,
        sys: &System,
        rhs: &mut [f64],
        z: &mut [Vector6<f64>],
        u: &mut [Vector6<f64>],
        dx: &mut [Vector6<f64>],
    ) {
        let nb = sys.bodies.len();
        for zi in z.iter_mut() {
            *zi = Vector6::zeros();
        }
        for bi in (0..nb).rev() {
            let j = &sys.bodies[bi].joint;
            let n = j.dof_count.min(6);
            let mut r = Vector6::zeros();
            for k in 0..n {
                r[k] = rhs.get(j.dof_start + k).copied().unwrap_or(0.0);
            }
            let zb = z[bi];
            let mut ub = r - self.h[bi].transpose() * zb;
            for x in ub.iter_mut().skip(n) {
                *x = 0.0;
            }
            self.lu[bi].solve(&mut ub);
            u[bi] = ub;
            if let Some(p) = sys.bodies[bi].parent {
                let za = self.ph[bi] * ub + zb;
                z[p.0] += za;
            }
        }
        for bi in 0..nb {
            let b = &sys.bodies[bi];
            let dxp = match b.parent {
                Some(p) => dx[p.0],
                None => Vector6::zeros(),
            };
            let dq = u[bi] + self.v[bi] * dxp;
            dx[bi] = dxp + self.h[bi] * dq;
            let j = &b.joint;
            for k in 0..j.dof_count.min(6) {
                if let Some(x) = rhs.get_mut(j.dof_start + k) {
                    *x = dq[k];
                }
            }
        }
    }

    /// Solve without touching the workspace (for `&Workspace` callers).
    pub(crate) fn solve_alloc(&self, sys: &System, rhs: &mut [f64]) {
        let nb = sys.bodies.len();
        let mut z = vec![Vector6::zeros(); nb];
        let mut u = vec![Vector6::zeros(); nb];
        let mut dx = vec![Vector6::zeros(); nb];
        self.solve_with(sys, rhs, &mut z, &mut u, &mut dx);
    }
}

#[cfg(test)]
mod tests {
    use super::super::examples::{add_level, iso, spine_chain, thesis_bushing};
    use super::super::scalar::v3;
    use super::super::spec::{BodySpec, Load, LoadFrame, SystemSpec};
    use super::super::statics::eval_tau;
    use super::super::workspace::{distance2_colouring, tree_coupled, Workspace};
    use super::*;
    use nalgebra::{DMatrix, DVector};

    /// A chain of `n` with two side branches of two bodies on v2 (tests the
    /// colouring of a body with several children).
    fn branched(n: usize) -> SystemSpec {
        let mut spec = spine_chain(n);
        for side in [-1.0, 1.0] {
            let mut parent = 2; // v2
            for k in 0..2 {
                let name = format!("b{}{k}", if side < 0.0 { "l" } else { "r" });
                spec.bodies.push(BodySpec {
                    name: name.clone(),
                    mass: 0.3,
                    com: Vector3::new(0.0, 0.0, 0.01 * side),
                    inertia: Matrix3::identity() * 1e-4,
                });
                let child = spec.bodies.len() - 1;
                add_level(
                    &mut spec,
                    &format!("j_{name}"),
                    Some(parent),
                    child,
                    iso([0.0, 0.005, 0.03 * side], [0.1 * side, 0.0, 0.05]),
                    iso([0.0, -0.004, 0.0], [0.0, 0.02 * side, 0.0]),
                    thesis_bushing(),
                );
                parent = child;
            }
        }
        spec
    }

    fn all_loads(top: &str) -> Vec<Load> {
        vec![
            Load::Moment {
                body: top.into(),
                vec: Vector3::new(1.0, -2.0, 3.0),
                frame: LoadFrame::Body,
            },
            Load::Moment {
                body: "v2".into(),
                vec: Vector3::new(0.5, 0.0, -4.0),
                frame: LoadFrame::Ground,
            },
            Load::Force {
                body: "v3".into(),
                point_in_body: Vector3::new(0.01, 0.02, 0.0),
                vec: Vector3::new(5.0, -50.0, 2.0),
                frame: LoadFrame::Ground,
            },
            Load::Force {
                body: top.into(),
                point_in_body: Vector3::new(-0.02, 0.01, 0.005),
                vec: Vector3::new(-3.0, -20.0, 1.0),
                frame: LoadFrame::Body,
            },
            Load::Follower {
                from_body: "sacrum".into(),
                to_body: top.into(),
                magnitude: 300.0,
            },
        ]
    }

    /// Structured solve of `T x = b` against the dense LU of the dense
    /// dual-number tangent, at a deflected pose.
    fn check_against_dense(sys: &System, loads: &[Load], expect_tree: bool) {
        let loads = sys.prepare_loads(loads).unwrap();
        let mut ws = Workspace::new(sys);
        assert_eq!(ws.tree.usable, expect_tree);
        let n = sys.n_dofs();
        let q: Vec<f64> = (0..n)
            .map(|i| 0.1 * ((i * 7 % 11) as f64 / 11.0 - 0.5) * if i % 6 < 3 { 1.0 } else { 0.02 })
            .collect();
        let dense = sys.static_tangent(&q, &loads, &mut ws).unwrap();
        ws.k64.q.copy_from_slice(&q);
        eval_tau(sys, &loads, &mut ws.k64).unwrap();
        let mut tree = TreeTangent::new(sys);
        tree.assemble(sys, &loads, &ws.k64, &mut ws.kd6).unwrap();
        assert!(tree.factor(sys));
        let b: Vec<f64> = (0..n).map(|i| ((i * 5 % 7) as f64 - 3.0) * 0.7).collect();
        let mut x = b.clone();
        tree.solve(sys, &mut x);
        let xv = DVector::from_vec(x.clone());
        let bv = DVector::from_vec(b.clone());
        let res = (&dense * &xv - &bv).amax();
        let scale = dense.amax() * xv.amax();
        assert!(res <= 1e-13 * scale, "residual {res:e} vs scale {scale:e}");
        let lu = DMatrix::from(dense.clone()).lu();
        let xd = lu.solve(&bv).unwrap();
        let diff = (&xd - &xv).amax();
        assert!(diff <= 1e-9 * xd.amax(), "diff {diff:e} of {:e}", xd.amax());
        // the allocation-free and the allocating solves agree exactly
        let mut x2 = b.clone();
        tree.solve_alloc(sys, &mut x2);
        assert_eq!(x, x2);
    }

    #[test]
    fn structured_solve_matches_dense_chain() {
        // (joints, gravity, follower): without gravity and follower only the
        // loaded bodies carry wrenches (partial assembly)
        for (n, gravity, follower) in [
            (1usize, true, true),
            (2, true, true),
            (6, true, true),
            (17, true, true),
            (6, false, true),
            (17, false, false),
        ] {
            let mut spec = spine_chain(n);
            if gravity {
                spec.gravity = Vector3::new(0.0, -9.80665, 0.0);
            }
            let sys = System::new(&spec).unwrap();
            let top = format!("v{n}");
            let mut loads = all_loads(&top);
            if !follower {
                loads.retain(|l| !matches!(l, Load::Follower { .. }));
            }
            if n < 3 {
                loads.retain(|l| !matches!(l, Load::Force { body, .. } if body == "v3"));
            }
            if n < 2 {
                loads.retain(|l| !matches!(l, Load::Moment { body, .. } if body == "v2"));
            }
            check_against_dense(&sys, &loads, true);
        }
    }

    #[test]
    fn structured_solve_matches_dense_general_bushings() {
        let mut spec = spine_chain(6);
        spec.gravity = Vector3::new(0.0, -9.80665, 0.0);
        let sys = System::new(&spec).unwrap().without_fast_paths();
        check_against_dense(&sys, &all_loads("v6"), true);
    }

    #[test]
    fn structured_solve_matches_dense_branched_tree() {
        let mut spec = branched(5);
        spec.gravity = Vector3::new(0.0, -9.80665, 0.0);
        let sys = System::new(&spec).unwrap();
        let (colour, n_colours) = distance2_colouring(&sys);
        assert!(n_colours >= 3);
        // distance-2 property: parent, grandparent and siblings differ
        for (bi, b) in sys.bodies.iter().enumerate() {
            if let Some(p) = b.parent {
                assert_ne!(colour[bi], colour[p.0]);
                if let Some(gp) = sys.bodies[p.0].parent {
                    assert_ne!(colour[bi], colour[gp.0]);
                }
                for (si, s) in sys.bodies.iter().enumerate() {
                    if si != bi && s.parent == Some(p) {
                        assert_ne!(colour[bi], colour[si]);
                    }
                }
            }
        }
        let mut loads = all_loads("v5");
        loads.push(Load::Force {
            body: "bl1".into(),
            point_in_body: Vector3::new(0.0, 0.0, -0.02),
            vec: Vector3::new(0.0, -10.0, -5.0),
            frame: LoadFrame::Ground,
        });
        check_against_dense(&sys, &loads, true);
        check_against_dense(&sys.clone().without_fast_paths(), &loads, true);
    }

    /// The analytic joint-local tangent equals the dual-number derivative of
    /// `w_k . (n - p_FM x f) + v_k . f` on a joint with non-linear and
    /// coupled transform functions and a constant non-zero rotation.
    #[test]
    fn joint_local_tangent_matches_dual_numbers() {
        use super::super::spec::{CoordinateSpec, Function, JointKind, JointSpec, TransformAxis};
        let poly = |c: Vec<f64>| Function::Polynomial(c);
        let ax = |axis: Vector3<f64>, coord: Option<usize>, function: Function| TransformAxis {
            axis,
            coord,
            function,
        };
        let axes = Box::new([
            ax(
                Vector3::new(0.2, 1.0, 0.1),
                Some(0),
                poly(vec![0.5, -0.2, 1.0, 0.05]),
            ),
            ax(Vector3::z(), None, Function::Constant(0.3)),
            ax(
                Vector3::new(1.0, 0.0, 0.3),
                Some(1),
                Function::Multiplier {
                    scale: 1.5,
                    inner: Box::new(poly(vec![0.3, 0.7, -0.1])),
                },
            ),
            ax(Vector3::x(), Some(0), poly(vec![0.01, 0.02, 0.0])),
            ax(
                Vector3::new(0.0, 1.0, 0.2),
                Some(2),
                Function::Linear {
                    slope: 0.5,
                    intercept: 0.01,
                },
            ),
            ax(Vector3::z(), Some(1), poly(vec![-0.02, 0.01, 0.003])),
        ]);
        let coord = |name: &str| CoordinateSpec {
            name: name.into(),
            default: 0.0,
            range: [-1.0, 1.0],
            clamped: false,
            locked: false,
        };
        let spec = SystemSpec {
            bodies: vec![BodySpec {
                name: "b".into(),
                mass: 1.0,
                com: Vector3::zeros(),
                inertia: Matrix3::identity(),
            }],
            joints: vec![JointSpec {
                name: "j".into(),
                parent: None,
                child: 0,
                x_pf: iso([0.01, 0.02, 0.0], [0.1, 0.2, 0.3]),
                x_bm: iso([0.0, -0.01, 0.0], [0.0, 0.0, 0.0]),
                kind: JointKind::Custom { axes },
            }],
            coordinates: vec![coord("a"), coord("b"), coord("c")],
            bushings: vec![],
            gravity: Vector3::zeros(),
        };
        let sys = System::new(&spec).unwrap();
        let j = &sys.bodies[0].joint;
        assert_eq!(j.dof_count, 3);
        let q = [0.4, -0.3, 0.02];
        let n_f = Vector3::new(1.5, -2.0, 0.7);
        let f_f = Vector3::new(30.0, -120.0, 45.0);
        let mut l = Matrix6::zeros();
        kinematics::joint_local_tangent(j, &q, &n_f, &f_f, &mut l);
        let qd: Vec<D6> = q.iter().enumerate().map(|(k, v)| d6_var(*v, k)).collect();
        let mut rates = [[Vector3::<D6>::zeros(); 2]; 6];
        let x_fm = kinematics::joint_local(j, &qd, &mut rates);
        let f_d = v3::<D6>(&f_f);
        let arm = v3::<D6>(&n_f) - x_fm.p.cross(&f_d);
        let mut max_err = 0.0f64;
        let mut nonzero = 0;
        for (k, [wk, vk]) in rates.iter().enumerate().take(3) {
            let e = d6_eps(&(wk.dot(&arm) + vk.dot(&f_d)));
            for m in 0..3 {
                max_err = max_err.max((e[m] - l[(k, m)]).abs());
                nonzero += usize::from(e[m].abs() > 1e-6);
            }
        }
        // dof c only translates at a constant rate: its row is zero
        assert_eq!(nonzero, 6, "non-trivial test");
        assert!(max_err < 1e-12, "max error {max_err:e}");
    }

    #[test]
    fn bushing_skipping_a_level_is_not_tree_coupled() {
        let mut spec = spine_chain(4);
        let mut b = spec.bushings[2].clone();
        b.name = "skip".into();
        b.frame1.body = Some(1); // v1 -> v3
        spec.bushings.push(b);
        let sys = System::new(&spec).unwrap();
        assert!(!tree_coupled(&sys));
        let loads = sys
            .prepare_loads(&[Load::Moment {
                body: "v4".into(),
                vec: Vector3::new(0.0, 0.0, -5.0),
                frame: LoadFrame::Ground,
            }])
            .unwrap();
        let mut ws = Workspace::new(&sys);
        let sol = sys
            .solve_static(
                &loads,
                sys.default_q().as_slice(),
                &mut ws,
                &Default::default(),
            )
            .unwrap();
        assert!(sol.residual_norm < 1e-9);
        assert!(!ws.used_structured_tangent());
    }
}
