//! Kinematic-chain smoothing of the vertebral poses (empirical Bayes), an
//! option of `generate` (`--smooth chain`).
//!
//! The per-vertebra fits ([`super::pose`]) treat every vertebra as a free
//! rigid body, but a spine is a chain: neighbouring vertebrae meet at their
//! intervertebral joint. The base model says where that joint is in each
//! of the two bodies (the joint centre at the base model's default pose,
//! scaled with each body), and a vertebra that turns moves its joint point
//! by the turn times the lever arm from its landmarks' centroid. So the
//! positions of the neighbours, which the landmarks give very precisely
//! (their centroid has 1/sqrt(14) of the landmark noise), inform each
//! vertebra's orientation.
//!
//! Model, for `n` vertebrae and the joints between consecutive ones:
//! * **Data**: vertebra `i`'s fit is `(R_i, t_i)`; the truth is the fit
//!   turned by `exp(w_i)` about the centroid `c_i` of its posed markers and
//!   moved by `v_i`, with `(w_i, v_i) ~ N(0, sigma^2 (J^T J)^-1)`: about
//!   the centroid the rigid fit's information is block diagonal,
//!   [`super::smooth::rotation_information`] for `w_i` and `n_i I` for
//!   `v_i` (`n_i` landmarks, `sigma` the set-wide per-axis noise SD).
//! * **Prior**: at joint `k` (upper vertebra `u`, lower `l`), the mismatch
//!   `e_k = R_l^T (P_u - P_l) - mu` of the joint point placed by the upper
//!   body (`P_u`) and by the lower one (`P_l`), in the lower body's axes,
//!   is `N(0, diag(s^2))`: disc shear and compression that the base
//!   model's disc geometry does not carry. `mu` (a common offset, e.g.
//!   discs uniformly taller than the base model's) has a flat prior.
//! * **s** (one SD per axis of the lower body: anterior, cranial, right)
//!   maximises the restricted marginal likelihood (Laplace on the model
//!   linearised at the fits, `l(s) = -F/2 - m ln|s| - ln det(H)/2`, `m`
//!   joints); a spine whose joints do shear gets a large `s` and keeps its
//!   fits. The posterior mode is then refined by the crate's least-squares
//!   optimiser on the exact (non-linear) mismatch.
//!
//! Unlike a smoothness prior on the orientations, this one does not
//! flatten a curve: a spine posed by rotations about its joints has zero
//! mismatch whatever its curvature, so the estimate is unbiased for it.

use super::smooth::{maximise, posterior_mode, rows_scaled, Posterior};
use crate::error::{Error, Result};
use nalgebra::{DMatrix, DVector, Isometry3, Matrix3, Point3, UnitQuaternion, Vector3};

/// Search range of the joint mismatch SD `s` (m): 1 um to 50 mm.
pub(crate) const S_RANGE: [f64; 2] = [1e-6, 0.05];

/// One vertebra of the chain (ground frame, metres).
#[derive(Debug, Clone)]
pub struct ChainVertebra {
    /// Fitted pose (body to ground).
    pub pose: Isometry3<f64>,
    /// Centroid of the posed markers of the landmarks used.
    pub centroid: Point3<f64>,
    /// Rotation information `sum (|x|^2 I - x x^T)` of those markers (m^2).
    pub info_rot: Matrix3<f64>,
    /// Number of landmarks used.
    pub n: usize,
}

/// A joint between vertebrae `upper` and `lower` (indices into the chain):
/// its centre in each body's frame (scaled with that body).
#[derive(Debug, Clone)]
pub struct ChainJoint {
    /// Index of the upper vertebra in the chain.
    pub upper: usize,
    /// Index of the lower vertebra in the chain.
    pub lower: usize,
    /// The joint centre in the upper body's frame (m).
    pub in_upper: Point3<f64>,
    /// The joint centre in the lower body's frame (m).
    pub in_lower: Point3<f64>,
}

/// Result of [`smooth_chain`].
#[derive(Debug, Clone)]
pub struct ChainSmoothed {
    /// Posterior poses (body to ground), in the input order.
    pub poses: Vec<Isometry3<f64>>,
    /// REML estimate of the joint mismatch SD (m) along the lower body's
    /// X, Y, Z axes.
    pub s: Vector3<f64>,
    /// Estimated common mismatch `mu` (m, lower body's axes).
    pub mu: Vector3<f64>,
    /// Effective number of pose parameters kept, `tr(H^-1 W)` (of `6 n`).
    pub effective_dof: f64,
    /// Per-vertebra SD (rad) of the fitted orientation about ground X, Y, Z.
    pub raw_sd: Vec<[f64; 3]>,
    /// Per-vertebra posterior SD (rad) of the orientation.
    pub posterior_sd: Vec<[f64; 3]>,
    /// The maximised restricted log marginal likelihood `l(s)` (up to a
    /// constant common to every joint model of the same fits): compares
    /// joint models of one chain.
    pub log_ml: f64,
}

/// Pose of vertebra `v` moved by the increment `x[6i..6i+6]` = `(w, v)`.
fn moved(v: &ChainVertebra, x: &[f64]) -> Isometry3<f64> {
    let q = UnitQuaternion::from_scaled_axis(Vector3::new(x[0], x[1], x[2]));
    let dv = Vector3::new(x[3], x[4], x[5]);
    let c = v.centroid.coords;
    let t = q * (v.pose.translation.vector - c) + c + dv;
    Isometry3::from_parts(t.into(), q * v.pose.rotation)
}

/// The mismatch of joint `j` at parameters `x` (`6 n` increments, then
/// `mu`): the joint point placed by the upper body minus the one placed by
/// the lower body, in the lower body's axes, minus `mu`.
fn joint_mismatch(v: &[ChainVertebra], j: &ChainJoint, x: &[f64]) -> Vector3<f64> {
    let n = v.len();
    let xu = moved(&v[j.upper], &x[6 * j.upper..6 * j.upper + 6]);
    let xl = moved(&v[j.lower], &x[6 * j.lower..6 * j.lower + 6]);
    let mu = Vector3::new(x[6 * n], x[6 * n + 1], x[6 * n + 2]);
    xl.rotation.inverse() * (xu * j.in_upper - xl * j.in_lower) - mu
}

/// The stacked joint mismatches at parameters `x`.
fn mismatch(v: &[ChainVertebra], joints: &[ChainJoint], x: &DVector<f64>) -> DVector<f64> {
    let mut e = DVector::zeros(3 * joints.len());
    for (k, j) in joints.iter().enumerate() {
        e.fixed_rows_mut::<3>(3 * k)
            .copy_from(&joint_mismatch(v, j, x.as_slice()));
    }
    e
}

/// Jacobian of [`mismatch`] by central differences (each joint depends on
/// its two vertebrae and `mu` only).
fn jacobian(v: &[ChainVertebra], joints: &[ChainJoint], x: &DVector<f64>) -> DMatrix<f64> {
    const H: f64 = 1e-7;
    let n = v.len();
    let mut jac = DMatrix::zeros(3 * joints.len(), 6 * n + 3);
    let mut xx = x.as_slice().to_vec();
    for (k, j) in joints.iter().enumerate() {
        let cols = (6 * j.upper..6 * j.upper + 6)
            .chain(6 * j.lower..6 * j.lower + 6)
            .chain(6 * n..6 * n + 3);
        for c in cols {
            let x0 = xx[c];
            xx[c] = x0 + H;
            let up = joint_mismatch(v, j, &xx);
            xx[c] = x0 - H;
            let dn = joint_mismatch(v, j, &xx);
            xx[c] = x0;
            jac.fixed_view_mut::<3, 1>(3 * k, c)
                .copy_from(&((up - dn) / (2.0 * H)));
        }
    }
    jac
}

fn not_pd() -> Error {
    Error::numerical("chain smoothing", "posterior precision not positive")
}

/// Linear-Gaussian pieces at one `s`: mode `x`, objective `F` and
/// `ln det H`.
struct LinearMode {
    x: DVector<f64>,
    objective: f64,
    logdet: f64,
}

fn linear_mode(
    w: &DMatrix<f64>,
    jac: &DMatrix<f64>,
    e0: &DVector<f64>,
    s: &Vector3<f64>,
) -> Result<LinearMode> {
    let lam = DVector::from_fn(e0.len(), |k, _| 1.0 / (s[k % 3] * s[k % 3]));
    let lj = rows_scaled(jac.clone(), &lam);
    let hessian = w + jac.transpose() * &lj;
    let ch = hessian.cholesky().ok_or_else(not_pd)?;
    let x = ch.solve(&(-(lj.transpose() * e0)));
    let e = e0 + jac * &x;
    let objective = x.dot(&(w * &x)) + e.component_mul(&e).dot(&lam);
    let logdet = ch.l().diagonal().iter().map(|d| 2.0 * d.ln()).sum();
    Ok(LinearMode {
        x,
        objective,
        logdet,
    })
}

/// Smooth the chain `v` (any order) joined by `joints`, with per-axis
/// landmark noise SD `sigma` (m). `None` when there is nothing to do: no
/// joint, or `sigma` 0 (exact data: the posterior is the data).
pub fn smooth_chain(
    v: &[ChainVertebra],
    joints: &[ChainJoint],
    sigma: f64,
) -> Result<Option<ChainSmoothed>> {
    let n = v.len();
    if joints.is_empty() || !sigma.is_finite() || sigma <= 0.0 {
        return Ok(None);
    }
    if let Some(j) = joints.iter().find(|j| j.upper >= n || j.lower >= n) {
        return Err(Error::invalid(
            "chain smoothing",
            format!(
                "joint between vertebrae {} and {} of a chain of {n}",
                j.upper, j.lower
            ),
        ));
    }
    let dim = 6 * n + 3;
    let mut w = DMatrix::zeros(dim, dim);
    let mut raw_sd = Vec::with_capacity(n);
    for (i, vi) in v.iter().enumerate() {
        let prec = vi.info_rot / (sigma * sigma);
        let cov = prec.try_inverse().ok_or_else(|| {
            Error::numerical(
                "chain smoothing",
                format!(
                    "vertebra {} of the chain: its landmarks do not determine a rotation",
                    i + 1
                ),
            )
        })?;
        raw_sd.push(std::array::from_fn(|a| cov[(a, a)].max(0.0).sqrt()));
        w.view_mut((6 * i, 6 * i), (3, 3)).copy_from(&prec);
        w.view_mut((6 * i + 3, 6 * i + 3), (3, 3))
            .copy_from(&(Matrix3::identity() * (vi.n.max(1) as f64 / (sigma * sigma))));
    }
    let zero = DVector::zeros(dim);
    let e0 = mismatch(v, joints, &zero);
    let jac = jacobian(v, joints, &zero);
    let m = joints.len() as f64;
    let log_ml = |s: &Vector3<f64>| -> Result<f64> {
        let lm = linear_mode(&w, &jac, &e0, s)?;
        Ok(-0.5 * lm.objective - m * s.iter().map(|x| x.ln()).sum::<f64>() - 0.5 * lm.logdet)
    };
    let (lo, hi) = (S_RANGE[0].ln(), S_RANGE[1].ln());
    let common = maximise(|ls| log_ml(&Vector3::repeat(ls.exp())), lo, hi, 24)?;
    let mut log_s = Vector3::repeat(common);
    for _ in 0..2 {
        for a in 0..3 {
            log_s[a] = maximise(
                |ls| {
                    let mut t = log_s;
                    t[a] = ls;
                    log_ml(&t.map(f64::exp))
                },
                lo,
                hi,
                12,
            )?;
        }
    }
    let s = log_s.map(f64::exp);
    let log_ml_at_s = log_ml(&s)?;
    // Posterior mode on the exact mismatch, from the linear solution.
    let lam_sqrt = DVector::from_fn(e0.len(), |k, _| 1.0 / s[k % 3]);
    let start = linear_mode(&w, &jac, &e0, &s)?.x;
    let Posterior { x, hessian, .. } = posterior_mode(
        "chain smoothing",
        &w,
        &lam_sqrt,
        &start,
        |x| mismatch(v, joints, x),
        |x| jacobian(v, joints, x),
    )?;
    let cov = hessian.cholesky().ok_or_else(not_pd)?.inverse();
    let effective_dof = (0..6 * n)
        .map(|r| (0..6 * n).map(|c| cov[(r, c)] * w[(c, r)]).sum::<f64>())
        .sum();
    let poses = (0..n)
        .map(|i| moved(&v[i], &x.as_slice()[6 * i..6 * i + 6]))
        .collect();
    let posterior_sd = (0..n)
        .map(|i| std::array::from_fn(|a| cov[(6 * i + a, 6 * i + a)].max(0.0).sqrt()))
        .collect();
    Ok(Some(ChainSmoothed {
        poses,
        s,
        mu: Vector3::new(x[6 * n], x[6 * n + 1], x[6 * n + 2]),
        effective_dof,
        raw_sd,
        posterior_sd,
        log_ml: log_ml_at_s,
    }))
}

#[cfg(test)]
mod tests {
    use super::super::smooth::tests::lumbar_template;
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// Joint centre 16 mm below a body's origin (disc midpoint) and 16 mm
    /// above the next one's: a chain of `n` vertebrae posed by rotations
    /// `g(k)` (rad, rotation vector in the lower body) about its joints,
    /// plus a joint translation `shear(k)` (m, lower body). Returns the
    /// poses, cranial to caudal, and the joints.
    fn chain_truth(
        n: usize,
        g: impl Fn(usize) -> Vector3<f64>,
        shear: impl Fn(usize) -> Vector3<f64>,
    ) -> (Vec<Isometry3<f64>>, Vec<ChainJoint>) {
        let in_upper = Point3::new(0.0, -0.016, 0.0);
        let in_lower = Point3::new(0.0, 0.016, 0.0);
        // Build caudal to cranial from the lowest vertebra at the origin.
        let mut poses = vec![Isometry3::identity()];
        for k in 0..n - 1 {
            let lower = poses[k];
            let rot = lower.rotation * UnitQuaternion::from_scaled_axis(g(k));
            let joint = lower * in_lower + lower.rotation * shear(k);
            let t = joint.coords - rot * in_upper.coords;
            poses.push(Isometry3::from_parts(t.into(), rot));
        }
        poses.reverse();
        let joints = (0..n - 1)
            .map(|k| ChainJoint {
                upper: k,
                lower: k + 1,
                in_upper,
                in_lower,
            })
            .collect();
        (poses, joints)
    }

    /// Rigid least-squares fits of the template posed by `truth` with
    /// per-axis landmark noise `sigma` (Kabsch about the centroid).
    fn noisy_fits(
        truth: &[Isometry3<f64>],
        sigma: f64,
        rng: &mut rand_chacha::ChaCha8Rng,
    ) -> Vec<ChainVertebra> {
        let tpl = lumbar_template();
        let z = Normal::new(0.0, sigma).unwrap();
        truth
            .iter()
            .map(|x| {
                let obs: Vec<Point3<f64>> = tpl
                    .iter()
                    .map(|p| x * p + Vector3::from_fn(|_, _| z.sample(rng)))
                    .collect();
                let n = tpl.len() as f64;
                let cm = tpl.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / n;
                let co = obs.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / n;
                let mut h = Matrix3::zeros();
                for (p, o) in tpl.iter().zip(&obs) {
                    h += (o.coords - co) * (p.coords - cm).transpose();
                }
                let svd = h.svd(true, true);
                let (u, vt) = (svd.u.unwrap(), svd.v_t.unwrap());
                let mut d = Matrix3::identity();
                d[(2, 2)] = (u * vt).determinant().signum();
                let r = nalgebra::Rotation3::from_matrix_unchecked(u * d * vt);
                let q = UnitQuaternion::from_rotation_matrix(&r);
                let pose = Isometry3::from_parts((co - q * cm).into(), q);
                let posed: Vec<Point3<f64>> = tpl.iter().map(|p| pose * p).collect();
                ChainVertebra {
                    pose,
                    centroid: co.into(),
                    info_rot: super::super::smooth::rotation_information(&posed),
                    n: tpl.len(),
                }
            })
            .collect()
    }

    /// A scoliotic chain: lateral bending that changes sign sharply, some
    /// axial rotation and flexion.
    fn scoliotic(k: usize) -> Vector3<f64> {
        let lb = if (4..10).contains(&k) { -0.21 } else { 0.13 };
        Vector3::new(0.03, 0.05 * (k as f64 * 0.7).sin(), lb)
    }

    #[test]
    fn exact_data_are_kept() {
        let (truth, joints) = chain_truth(8, scoliotic, |_| Vector3::zeros());
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let v = noisy_fits(&truth, 0.0, &mut rng);
        assert!(smooth_chain(&v, &joints, 0.0).unwrap().is_none());
        let s = smooth_chain(&v, &joints, 1e-12).unwrap().unwrap();
        for (a, b) in s.poses.iter().zip(&truth) {
            assert!(a.rotation.angle_to(&b.rotation) < 1e-9);
            assert!((a.translation.vector - b.translation.vector).norm() < 1e-9);
        }
        assert!(smooth_chain(&v, &[], 0.002).unwrap().is_none());
        let bad = [ChainJoint {
            upper: 0,
            lower: 8,
            in_upper: Point3::origin(),
            in_lower: Point3::origin(),
        }];
        assert!(smooth_chain(&v, &bad, 0.002).is_err());
    }

    /// Frontal tilt error (rad, about the ground Z axis here: the chain
    /// bends about Z) of each vertebra.
    fn tilt_errors(est: &[Isometry3<f64>], truth: &[Isometry3<f64>]) -> Vec<f64> {
        est.iter()
            .zip(truth)
            .map(|(e, t)| (e.rotation * t.rotation.inverse()).scaled_axis().z)
            .collect()
    }

    #[test]
    fn a_chain_posed_by_joint_rotations_is_recovered_unbiased_with_less_noise() {
        let (truth, joints) = chain_truth(12, scoliotic, |_| Vector3::zeros());
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let sigma = 0.002;
        let (mut raw_sq, mut post_sq, mut cobb_raw, mut cobb_post) =
            (0.0, 0.0, Vec::new(), Vec::new());
        let mut s_mm = Vec::new();
        for _ in 0..40 {
            let v = noisy_fits(&truth, sigma, &mut rng);
            let raw: Vec<Isometry3<f64>> = v.iter().map(|x| x.pose).collect();
            let s = smooth_chain(&v, &joints, sigma).unwrap().unwrap();
            let er = tilt_errors(&raw, &truth);
            let ep = tilt_errors(&s.poses, &truth);
            raw_sq += er.iter().map(|e| e * e).sum::<f64>();
            post_sq += ep.iter().map(|e| e * e).sum::<f64>();
            // "Cobb" error between vertebrae 3 and 9.
            cobb_raw.push(er[3] - er[9]);
            cobb_post.push(ep[3] - ep[9]);
            s_mm.push(s.s.norm() * 1e3);
            assert!(s.effective_dof > 0.0 && s.effective_dof < 72.0);
            for (p, q) in s.posterior_sd.iter().zip(&s.raw_sd) {
                for a in 0..3 {
                    assert!(p[a] <= q[a] * (1.0 + 1e-9));
                }
            }
        }
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
        let sd = |v: &[f64]| {
            let m = mean(v);
            (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64).sqrt()
        };
        // Less tilt noise than the independent fits, about the same
        // (zero) mean: the prior holds exactly for this chain.
        assert!(post_sq < 0.75 * raw_sq, "{post_sq} vs {raw_sq}");
        assert!(sd(&cobb_post) < 0.8 * sd(&cobb_raw));
        assert!(
            mean(&cobb_post).abs() < 3.0 * sd(&cobb_post) / 40f64.sqrt(),
            "bias {} deg",
            mean(&cobb_post).to_degrees()
        );
        // The joints do not shear: the estimated mismatch SD is small
        // against the landmark noise.
        let med = {
            let mut m = s_mm.clone();
            m.sort_by(|a, b| a.total_cmp(b));
            m[m.len() / 2]
        };
        assert!(med < 1.0, "median joint mismatch SD {med} mm");
    }

    #[test]
    fn shearing_joints_are_left_to_the_data() {
        // Joints that translate by several mm at random: the REML mismatch
        // SD grows to match and the posterior stays close to the fits.
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let z = Normal::new(0.0, 0.006).unwrap();
        let shears: Vec<Vector3<f64>> = (0..11)
            .map(|_| Vector3::from_fn(|_, _| z.sample(&mut rng)))
            .collect();
        let (truth, joints) = chain_truth(12, scoliotic, |k| shears[k]);
        let sigma = 0.002;
        let (mut raw_sq, mut post_sq) = (0.0, 0.0);
        for _ in 0..20 {
            let v = noisy_fits(&truth, sigma, &mut rng);
            let raw: Vec<Isometry3<f64>> = v.iter().map(|x| x.pose).collect();
            let s = smooth_chain(&v, &joints, sigma).unwrap().unwrap();
            assert!(s.s.norm() > 0.003, "mismatch SD {} mm", s.s.norm() * 1e3);
            let er = tilt_errors(&raw, &truth);
            let ep = tilt_errors(&s.poses, &truth);
            raw_sq += er.iter().map(|e| e * e).sum::<f64>();
            post_sq += ep.iter().map(|e| e * e).sum::<f64>();
        }
        // Never much worse than the independent fits.
        assert!(post_sq < 1.2 * raw_sq, "{post_sq} vs {raw_sq}");
    }
}
