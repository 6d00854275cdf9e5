//! Spinal-continuity smoothing of the vertebral orientations (empirical
//! Bayes), an option of `generate` (`--smooth curvature`; the default is
//! the kinematic chain of [`super::chain`]).
//!
//! Model, for `n` vertebrae ordered cranial to caudal (the sacrum, the
//! registration frame, is not part of the chain):
//! * **Data**: the least-squares fit of vertebra `i` gives the rotation
//!   `R_i` (body to ground). The true rotation is `exp(theta_i) R_i`
//!   (`theta_i` a rotation vector in ground, a small increment around the
//!   estimate, so the linearisation is local to each vertebra and valid for
//!   any curve size), and `theta_i ~ N(0, Sigma_i)` with
//!   `Sigma_i = sigma^2 (J^T J)^-1`: for a rigid fit of points `x_k`
//!   (posed markers relative to their centroid) the rotation block of
//!   `J^T J` is `sum_k (|x_k|^2 I - x_k x_k^T)` ([`rotation_information`]);
//!   `sigma` is the set-wide per-axis noise estimate of the lsq method.
//! * **Prior**: the relative rotation of neighbours in the lower body's
//!   frame, `g_i = log(R_i^T R_(i+1))`, changes slowly along the spine:
//!   its first differences (the second differences of the orientation
//!   sequence) are `N(0, tau^2 I)`. A constant `g` (a uniformly curved
//!   spine, whatever its curvature) costs nothing; the prior does not depend
//!   on the frame of the landmarks.
//! * **tau** maximises the restricted (type-II) marginal likelihood of the
//!   data, Laplace-approximated at the posterior mode:
//!   `l(tau) = -F/2 - r ln tau - ln det(H)/2`, with `F` the minimum of
//!   `theta^T W theta + |d(theta)|^2 / tau^2` (`W = blockdiag Sigma_i^-1`,
//!   `d` the stacked second differences), `H = W + D^T D / tau^2` at the
//!   mode (`D` the Jacobian of `d`) and `r = 3 (n - 2)` the rank of the
//!   prior (the improper directions, constant and uniformly changing
//!   rotations, are integrated out). Grid over `log tau` then golden
//!   section.
//! * **Posterior**: mode by the crate's least-squares optimiser
//!   ([`crate::util::lm`]) on `theta` (exact on the
//!   manifold: `d` is evaluated from the rotations `exp(theta_i) R_i`),
//!   covariance `H^-1`. The posterior rotations replace the fitted ones;
//!   each vertebra is turned about the centroid of its landmarks, so the
//!   least-squares position is kept.
//!
//! When `sigma` is 0 the data are exact and the posterior is the data; runs
//! of fewer than [`MIN_LEVELS`] vertebrae are not smoothed.

use crate::error::{Error, Result};
use crate::util::lm::{self, LmOptions};
use nalgebra::{DMatrix, DVector, Matrix3, Point3, UnitQuaternion, Vector3};

/// Fewest vertebrae in the chain for smoothing (a second difference needs
/// three, its variance estimate a few of them).
pub const MIN_LEVELS: usize = 4;
/// Search range of tau (rad): 0.0006 to 57 deg of change of the relative
/// rotation per level.
pub(crate) const TAU_RANGE: [f64; 2] = [1e-5, 1.0];

/// `--smooth`: how the per-vertebra fits are combined along the spine
/// (lsq method only).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Smooth {
    /// Kinematic chain (the default): neighbouring vertebrae meet at the
    /// base model's joint centres, up to a disc mismatch whose size the
    /// data estimate ([`super::chain`]). Unbiased for any curvature.
    Chain,
    /// Spinal-continuity prior on the orientations (this module): lower
    /// variance, but it flattens the curve where it turns (1.5-2.5 deg of
    /// Cobb angle on sharp curves). Also accepted as `auto`.
    #[value(alias = "auto")]
    Curvature,
    /// Per-vertebra fits as they are.
    Off,
}

impl std::str::FromStr for Smooth {
    type Err = Error;
    fn from_str(s: &str) -> Result<Smooth> {
        match s.trim().to_ascii_lowercase().as_str() {
            "chain" => Ok(Smooth::Chain),
            "curvature" | "auto" => Ok(Smooth::Curvature),
            "off" => Ok(Smooth::Off),
            o => Err(Error::invalid(
                "--smooth",
                format!("'{o}' is not a smoothing mode: expected 'chain', 'curvature' or 'off'"),
            )),
        }
    }
}

impl std::fmt::Display for Smooth {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Smooth::Chain => "chain",
            Smooth::Curvature => "curvature",
            Smooth::Off => "off",
        })
    }
}

/// Rotation block of `J^T J` (m^2) of a rigid least-squares fit of the
/// posed points `pts` (ground): `sum_k (|x_k|^2 I - x_k x_k^T)`, `x_k`
/// relative to the centroid.
pub fn rotation_information(pts: &[Point3<f64>]) -> Matrix3<f64> {
    let n = pts.len().max(1) as f64;
    let c = pts.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / n;
    let mut m = Matrix3::zeros();
    for p in pts {
        let x = p.coords - c;
        m += Matrix3::identity() * x.norm_squared() - x * x.transpose();
    }
    m
}

/// Result of [`smooth_orientations`].
#[derive(Debug, Clone, PartialEq)]
pub struct Smoothed {
    /// Posterior rotations (body to ground), in the input order.
    pub rotations: Vec<UnitQuaternion<f64>>,
    /// Posterior increments `theta_i` (rad, ground).
    pub theta: Vec<Vector3<f64>>,
    /// REML estimate of tau (rad per level^2) for the axes X, Y, Z of
    /// the relative rotations (the lower vertebra's frame: lateral bending,
    /// axial rotation, flexion-extension).
    pub tau: Vector3<f64>,
    /// Effective number of orientation parameters, `tr(H^-1 W)` (out of
    /// `3 n`): how much of the data the posterior keeps.
    pub effective_dof: f64,
    /// Per-vertebra SD (rad) of the fit, `sqrt(diag Sigma_i)` (ground X, Y, Z).
    pub raw_sd: Vec<[f64; 3]>,
    /// Per-vertebra posterior SD (rad), `sqrt(diag H^-1)`.
    pub posterior_sd: Vec<[f64; 3]>,
}

/// The stacked second differences of the orientation sequence
/// `exp(theta_i) R_i`.
fn second_differences(r: &[UnitQuaternion<f64>], theta: &DVector<f64>) -> DVector<f64> {
    let n = r.len();
    let rot: Vec<UnitQuaternion<f64>> = (0..n)
        .map(|i| {
            UnitQuaternion::from_scaled_axis(Vector3::new(
                theta[3 * i],
                theta[3 * i + 1],
                theta[3 * i + 2],
            )) * r[i]
        })
        .collect();
    let g: Vec<Vector3<f64>> = rot
        .windows(2)
        .map(|w| (w[0].inverse() * w[1]).scaled_axis())
        .collect();
    let mut d = DVector::zeros(3 * n.saturating_sub(2));
    for (i, w) in g.windows(2).enumerate() {
        let v = w[1] - w[0];
        d.fixed_rows_mut::<3>(3 * i).copy_from(&v);
    }
    d
}

/// Jacobian of [`second_differences`] by central differences; `theta_j`
/// enters only the second differences `j - 2 ..= j`, so each column is
/// computed from the three relative rotations around vertebra `j`.
fn jacobian(r: &[UnitQuaternion<f64>], theta: &DVector<f64>) -> DMatrix<f64> {
    const H: f64 = 1e-6;
    let n = r.len();
    let m = 3 * n.saturating_sub(2);
    let mut jac = DMatrix::zeros(m, theta.len());
    let rot: Vec<UnitQuaternion<f64>> = (0..n)
        .map(|i| UnitQuaternion::from_scaled_axis(theta.fixed_rows::<3>(3 * i).into_owned()) * r[i])
        .collect();
    let rel = |a: &UnitQuaternion<f64>, b: &UnitQuaternion<f64>| (a.inverse() * b).scaled_axis();
    // Relative rotations g_(j-2) .. g_(j+1) with vertebra j turned by
    // `exp(e) rot_j`; rows of d_(j-2) ..= d_j.
    let local = |j: usize, e: Vector3<f64>| -> Vec<(usize, Vector3<f64>)> {
        let q = |i: usize| {
            if i == j {
                UnitQuaternion::from_scaled_axis(e) * rot[j]
            } else {
                rot[i]
            }
        };
        let g = |i: usize| rel(&q(i), &q(i + 1));
        let mut out = Vec::new();
        for k in j.saturating_sub(2)..=j {
            if k + 2 < n {
                out.push((k, g(k + 1) - g(k)));
            }
        }
        out
    };
    for j in 0..n {
        for a in 0..3 {
            // Perturb theta_j[a]: exp(theta + h e_a) = exp(delta) exp(theta)
            // to first order only for small theta, so turn the local
            // rotation by the exact increment instead.
            let mut tp = theta.fixed_rows::<3>(3 * j).into_owned();
            let mut tm = tp;
            tp[a] += H;
            tm[a] -= H;
            let base = UnitQuaternion::from_scaled_axis(theta.fixed_rows::<3>(3 * j).into_owned());
            let ep = (UnitQuaternion::from_scaled_axis(tp) * base.inverse()).scaled_axis();
            let em = (UnitQuaternion::from_scaled_axis(tm) * base.inverse()).scaled_axis();
            for ((k, up), (_, dn)) in local(j, ep).into_iter().zip(local(j, em)) {
                let col = (up - dn) / (2.0 * H);
                jac.fixed_view_mut::<3, 1>(3 * k, 3 * j + a).copy_from(&col);
            }
        }
    }
    jac
}

/// Prior precision weights `1 / tau_a^2` for every row of the stacked
/// second differences.
fn weights(rows: usize, tau: &Vector3<f64>) -> DVector<f64> {
    DVector::from_fn(rows, |k, _| 1.0 / (tau[k % 3] * tau[k % 3]))
}

/// Posterior mode of the orientations `theta` for one tau.
fn mode(
    r: &[UnitQuaternion<f64>],
    w: &DMatrix<f64>,
    tau: &Vector3<f64>,
    start: &DVector<f64>,
) -> Result<Posterior> {
    let lam_sqrt = weights(3 * r.len().saturating_sub(2), tau).map(f64::sqrt);
    posterior_mode(
        "orientation smoothing",
        w,
        &lam_sqrt,
        start,
        |theta| second_differences(r, theta),
        |theta| jacobian(r, theta),
    )
}

/// The mode of a Gaussian posterior with data precision `w` (3x3 blocks
/// down its diagonal; trailing unknowns without data have zero rows) and
/// prior residuals `e(x)` of precision `lam_sqrt^2`: the one least-squares
/// optimiser on `[L_b^T x_b; lam_sqrt e(x)]` (`W_b = L_b L_b^T`), whose
/// squares sum to `x^T W x + e^T Lam e`, from `start`.
pub(super) fn posterior_mode(
    ctx: &'static str,
    w: &DMatrix<f64>,
    lam_sqrt: &DVector<f64>,
    start: &DVector<f64>,
    prior: impl Fn(&DVector<f64>) -> DVector<f64>,
    prior_jacobian: impl Fn(&DVector<f64>) -> DMatrix<f64>,
) -> Result<Posterior> {
    let dim = start.len();
    let not_pd = || Error::numerical(ctx, "posterior precision not positive");
    // Square roots of the data blocks, up to the last non-zero one (a zero
    // block before it is not positive definite: an error).
    let block = |b: usize| w.fixed_view::<3, 3>(3 * b, 3 * b).into_owned();
    let with_data = (0..dim / 3)
        .rposition(|b| block(b).iter().any(|v| *v != 0.0))
        .map_or(0, |last| last + 1);
    let blocks = (0..with_data)
        .map(|b| Ok(block(b).cholesky().ok_or_else(not_pd)?.l().transpose()))
        .collect::<Result<Vec<Matrix3<f64>>>>()?;
    let data_rows = 3 * blocks.len();
    let prior_rows = lam_sqrt.len();
    let residuals = |x: &[f64], want_jacobian: bool| {
        let x = DVector::from_column_slice(x);
        let mut r = DVector::zeros(data_rows + prior_rows);
        for (b, root) in blocks.iter().enumerate() {
            r.fixed_rows_mut::<3>(3 * b)
                .copy_from(&(root * x.fixed_rows::<3>(3 * b)));
        }
        r.rows_mut(data_rows, prior_rows)
            .copy_from(&prior(&x).component_mul(lam_sqrt));
        let jac = want_jacobian.then(|| {
            let mut j = DMatrix::zeros(data_rows + prior_rows, dim);
            for (b, root) in blocks.iter().enumerate() {
                j.fixed_view_mut::<3, 3>(3 * b, 3 * b).copy_from(root);
            }
            let jp = rows_scaled(prior_jacobian(&x), lam_sqrt);
            j.rows_mut(data_rows, prior_rows).copy_from(&jp);
            j
        });
        Ok((r, jac))
    };
    let fit = lm::minimize(
        residuals,
        start.as_slice(),
        &vec![f64::NEG_INFINITY; dim],
        &vec![f64::INFINITY; dim],
        // Started at or near the linearised mode: Gauss-Newton steps
        // first (a tight prior makes the valley narrow and curved, where
        // damped steps crawl).
        &LmOptions {
            xtol: 1e-12,
            initial_damping: 1e-12,
            ..LmOptions::default()
        },
    )?;
    // The Gauss-Newton Hessian W + J^T Lam J at the mode.
    Ok(Posterior {
        hessian: fit.jac.transpose() * &fit.jac,
        objective: 2.0 * fit.cost,
        x: DVector::from_vec(fit.x),
    })
}

/// `diag(d) * m`, each row of `m` times its entry of `d` (the same numbers
/// as the dense product, without it).
pub(super) fn rows_scaled(mut m: DMatrix<f64>, d: &DVector<f64>) -> DMatrix<f64> {
    for (mut row, x) in m.row_iter_mut().zip(d.iter()) {
        row *= *x;
    }
    m
}

/// A posterior mode ([`posterior_mode`]).
pub(super) struct Posterior {
    /// The mode.
    pub(super) x: DVector<f64>,
    /// `x^T W x + e^T Lam e` there.
    pub(super) objective: f64,
    /// The Gauss-Newton Hessian there (the inverse covariance).
    pub(super) hessian: DMatrix<f64>,
}

/// Log restricted marginal likelihood of tau (up to a constant) and the mode.
fn log_marginal(
    r: &[UnitQuaternion<f64>],
    w: &DMatrix<f64>,
    tau: &Vector3<f64>,
    start: &DVector<f64>,
) -> Result<(f64, Posterior)> {
    let m = mode(r, w, tau, start)?;
    let per_axis = r.len() as f64 - 2.0;
    let ch = m.hessian.clone().cholesky().ok_or_else(|| {
        Error::numerical("orientation smoothing", "posterior precision not positive")
    })?;
    let logdet: f64 = ch.l().diagonal().iter().map(|x| 2.0 * x.ln()).sum();
    let log_tau: f64 = tau.iter().map(|t| t.ln()).sum();
    Ok((-0.5 * m.objective - per_axis * log_tau - 0.5 * logdet, m))
}

/// Maximise `f` over `[lo, hi]`: grid of `steps + 1` points, then golden
/// section in the best grid point's neighbourhood (to 1e-3).
pub(super) fn maximise(
    mut f: impl FnMut(f64) -> Result<f64>,
    lo: f64,
    hi: f64,
    steps: usize,
) -> Result<f64> {
    let at = |k: usize| lo + (hi - lo) * k as f64 / steps as f64;
    let mut best: Option<(usize, f64)> = None;
    for k in 0..=steps {
        let l = f(at(k))?;
        if l.is_finite() && best.is_none_or(|(_, b)| l > b) {
            best = Some((k, l));
        }
    }
    let (kb, _) = best.ok_or_else(|| {
        Error::numerical("smoothing (REML search)", "no finite marginal likelihood")
    })?;
    let (mut a, mut b) = (at(kb.saturating_sub(1)), at((kb + 1).min(steps)));
    let gr = (5f64.sqrt() - 1.0) / 2.0;
    let (mut c, mut d) = (b - gr * (b - a), a + gr * (b - a));
    let (mut fc, mut fd) = (f(c)?, f(d)?);
    for _ in 0..40 {
        if (b - a).abs() < 1e-3 {
            break;
        }
        if fc > fd {
            b = d;
            d = c;
            fd = fc;
            c = b - gr * (b - a);
            fc = f(c)?;
        } else {
            a = c;
            c = d;
            fc = fd;
            d = a + gr * (b - a);
            fd = f(d)?;
        }
    }
    Ok(0.5 * (a + b))
}

/// Smooth the orientation sequence `r` (cranial to caudal) whose fits have
/// rotation information `info` (m^2, [`rotation_information`]) and per-axis
/// landmark noise SD `sigma` (m). `None` when there is nothing to smooth:
/// fewer than [`MIN_LEVELS`] vertebrae or `sigma` 0 (exact data: the
/// posterior is the data).
pub fn smooth_orientations(
    r: &[UnitQuaternion<f64>],
    info: &[Matrix3<f64>],
    sigma: f64,
) -> Result<Option<Smoothed>> {
    let n = r.len();
    if info.len() != n {
        return Err(Error::invalid(
            "orientation smoothing",
            format!("{n} rotations but {} information matrices", info.len()),
        ));
    }
    if n < MIN_LEVELS || !sigma.is_finite() || sigma <= 0.0 {
        return Ok(None);
    }
    let mut w = DMatrix::zeros(3 * n, 3 * n);
    let mut raw_sd = Vec::with_capacity(n);
    for (i, m) in info.iter().enumerate() {
        let prec = m / (sigma * sigma);
        let cov = prec.try_inverse().ok_or_else(|| {
            Error::numerical(
                "orientation smoothing",
                format!(
                    "vertebra {} of the chain: its landmarks do not determine a rotation",
                    i + 1
                ),
            )
        })?;
        raw_sd.push(std::array::from_fn(|a| cov[(a, a)].max(0.0).sqrt()));
        w.view_mut((3 * i, 3 * i), (3, 3)).copy_from(&prec);
    }
    // Type-II ML over log tau: a common tau first, then each axis in turn
    // (two rounds of coordinate ascent).
    let zero = DVector::zeros(3 * n);
    let (lo, hi) = (TAU_RANGE[0].ln(), TAU_RANGE[1].ln());
    let common = maximise(
        |lt| Ok(log_marginal(r, &w, &Vector3::repeat(lt.exp()), &zero)?.0),
        lo,
        hi,
        24,
    )?;
    let mut log_tau = Vector3::repeat(common);
    for _ in 0..2 {
        for a in 0..3 {
            log_tau[a] = maximise(
                |lt| {
                    let mut t = log_tau;
                    t[a] = lt;
                    Ok(log_marginal(r, &w, &t.map(f64::exp), &zero)?.0)
                },
                lo,
                hi,
                12,
            )?;
        }
    }
    let tau = log_tau.map(f64::exp);
    let (_, m) = log_marginal(r, &w, &tau, &zero)?;
    let cov = m
        .hessian
        .clone()
        .cholesky()
        .map(|c| c.inverse())
        .ok_or_else(|| {
            Error::numerical("orientation smoothing", "posterior precision not positive")
        })?;
    let effective_dof = (&cov * &w).trace();
    let theta: Vec<Vector3<f64>> = (0..n)
        .map(|i| Vector3::new(m.x[3 * i], m.x[3 * i + 1], m.x[3 * i + 2]))
        .collect();
    let rotations = theta
        .iter()
        .zip(r)
        .map(|(t, q)| UnitQuaternion::from_scaled_axis(*t) * q)
        .collect();
    let posterior_sd = (0..n)
        .map(|i| std::array::from_fn(|a| cov[(3 * i + a, 3 * i + a)].max(0.0).sqrt()))
        .collect();
    Ok(Some(Smoothed {
        rotations,
        theta,
        tau,
        effective_dof,
        raw_sd,
        posterior_sd,
    }))
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// Scaling the rows gives the dense product `diag(d) * m` exactly.
    #[test]
    fn scaled_rows_are_the_diagonal_product() {
        let m = DMatrix::from_fn(7, 5, |r, c| ((r * 5 + c) as f64 * 0.731).sin() * 1e3);
        let d = DVector::from_fn(7, |r, _| 1.0 / (0.3 + r as f64).powi(2));
        assert_eq!(rows_scaled(m.clone(), &d), DMatrix::from_diagonal(&d) * &m);
    }

    /// 14 landmark-like points of a lumbar-sized vertebra (body frame, m,
    /// X anterior, Y cranial, Z right), origin at the body centre.
    pub(in crate::generate) fn lumbar_template() -> Vec<Point3<f64>> {
        [
            [0.0, 0.012, 0.0],
            [0.0, -0.012, 0.0],
            [-0.02, 0.008, 0.012],
            [-0.02, -0.004, 0.012],
            [-0.02, 0.008, -0.012],
            [-0.02, -0.004, -0.012],
            [0.017, 0.012, 0.0],
            [-0.017, 0.012, 0.0],
            [0.0, 0.012, 0.021],
            [0.0, 0.012, -0.021],
            [0.017, -0.012, 0.0],
            [-0.017, -0.012, 0.0],
            [0.0, -0.012, 0.021],
            [0.0, -0.012, -0.021],
        ]
        .iter()
        .map(|p| Point3::new(p[0], p[1], p[2]))
        .collect()
    }

    /// Information of a 14-point vertebra of about the lumbar size.
    fn vertebra_info() -> Matrix3<f64> {
        rotation_information(&lumbar_template())
    }

    /// A curved sequence of `n` rotations whose relative rotation
    /// `g_i` follows `g(i)`.
    fn sequence(n: usize, g: impl Fn(usize) -> Vector3<f64>) -> Vec<UnitQuaternion<f64>> {
        let mut r = vec![UnitQuaternion::from_scaled_axis(Vector3::new(
            0.3, -0.2, 0.5,
        ))];
        for i in 0..n - 1 {
            let last = r[i];
            r.push(last * UnitQuaternion::from_scaled_axis(g(i)));
        }
        r
    }

    /// Noisy copies `exp(e_i) R_i`, `e_i ~ N(0, sigma^2 info^-1)`.
    fn noisy(
        r: &[UnitQuaternion<f64>],
        info: &Matrix3<f64>,
        sigma: f64,
        rng: &mut rand_chacha::ChaCha8Rng,
    ) -> Vec<UnitQuaternion<f64>> {
        let cov = info.try_inverse().unwrap() * sigma * sigma;
        let l = cov.cholesky().unwrap().l();
        let z = Normal::new(0.0, 1.0).unwrap();
        r.iter()
            .map(|q| {
                let e = l * Vector3::from_fn(|_, _| z.sample(rng));
                UnitQuaternion::from_scaled_axis(e) * q
            })
            .collect()
    }

    fn rms_angle(a: &[UnitQuaternion<f64>], b: &[UnitQuaternion<f64>]) -> f64 {
        (a.iter()
            .zip(b)
            .map(|(x, y)| x.angle_to(y).powi(2))
            .sum::<f64>()
            / a.len() as f64)
            .sqrt()
    }

    #[test]
    fn exact_data_are_kept() {
        let r = sequence(17, |i| {
            Vector3::new(0.15 * (i as f64 * 0.4).sin(), 0.05, 0.02)
        });
        let info = vec![vertebra_info(); 17];
        assert!(smooth_orientations(&r, &info, 0.0).unwrap().is_none());
        // A noise estimate of a noise-free set (round-off): posterior = data.
        let s = smooth_orientations(&r, &info, 1e-13).unwrap().unwrap();
        for (a, b) in s.rotations.iter().zip(&r) {
            assert!(a.angle_to(b) < 1e-9, "{}", a.angle_to(b));
        }
        // Short runs are left alone.
        assert!(smooth_orientations(&r[..3], &info[..3], 0.002)
            .unwrap()
            .is_none());
    }

    #[test]
    fn reml_tau_is_in_range_and_the_posterior_beats_the_raw_fits() {
        // Large curve (relative rotations up to 10 deg per level, 60+ deg
        // over the curve) whose second differences are random with SD tau.
        let info = vertebra_info();
        let sigma = 0.002;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let z = Normal::new(0.0, 1.0).unwrap();
        let n = 17;
        let (mut ratios, mut raw_err, mut post_err) = (Vec::new(), 0.0, 0.0);
        for &tau_true in &[0.01, 0.03] {
            for _ in 0..10 {
                let mut g = vec![Vector3::new(0.17, -0.05, 0.08)];
                for i in 1..n - 1 {
                    let prev = g[i - 1];
                    g.push(prev + Vector3::from_fn(|_, _| tau_true * z.sample(&mut rng)));
                }
                let truth = sequence(n, |i| g[i]);
                let data = noisy(&truth, &info, sigma, &mut rng);
                let s = smooth_orientations(&data, &vec![info; n], sigma)
                    .unwrap()
                    .unwrap();
                ratios.push(s.tau.mean() / tau_true);
                raw_err += rms_angle(&data, &truth);
                post_err += rms_angle(&s.rotations, &truth);
                assert!(s.effective_dof > 6.0 && s.effective_dof < 3.0 * n as f64);
                for (p, q) in s.posterior_sd.iter().zip(&s.raw_sd) {
                    for a in 0..3 {
                        assert!(p[a] <= q[a] * (1.0 + 1e-9));
                    }
                }
            }
        }
        ratios.sort_by(|a, b| a.total_cmp(b));
        let med = 0.5 * (ratios[9] + ratios[10]);
        assert!(
            (0.5..2.0).contains(&med),
            "median tau/tau_true {med}: {ratios:?}"
        );
        assert!(
            post_err < 0.8 * raw_err,
            "posterior error {post_err} vs raw {raw_err}"
        );
    }

    #[test]
    fn a_sharp_kink_survives_small_noise() {
        // Uniform curve, then the relative rotation turns by 15 deg at one
        // level (apex of a short curve); landmarks with 0.1 mm noise.
        let kink = 15f64.to_radians();
        let g = |i: usize| {
            if i < 8 {
                Vector3::new(0.1, 0.0, 0.0)
            } else {
                Vector3::new(0.1 - kink, 0.0, 0.0)
            }
        };
        let n = 17;
        let truth = sequence(n, g);
        let info = vertebra_info();
        let sigma = 0.0001;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let data = noisy(&truth, &info, sigma, &mut rng);
        let s = smooth_orientations(&data, &vec![info; n], sigma)
            .unwrap()
            .unwrap();
        // The posterior's change of relative rotation at the kink.
        let rel = |r: &[UnitQuaternion<f64>], i: usize| (r[i].inverse() * r[i + 1]).scaled_axis();
        let dk = rel(&s.rotations, 8) - rel(&s.rotations, 7);
        assert!(
            (dk.x + kink).abs() < 0.5f64.to_radians(),
            "kink {} deg of -15",
            dk.x.to_degrees()
        );
        assert!(rms_angle(&s.rotations, &truth) <= 1.2 * rms_angle(&data, &truth));
    }
}
