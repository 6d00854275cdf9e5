//! A small bound-constrained Levenberg-Marquardt for `min 1/2 ||r(x)||^2`
//! with `lo <= x <= hi` (calibration works on log-parameters, so the box is
//! the literature range). Marquardt scaling `diag(J^T J)`, Nielsen's damping
//! update, projection onto the box, and variables at a bound whose gradient
//! points outward are held (an active set), so a solution on a bound is a
//! proper KKT point. A failed evaluation at a trial point (e.g. no
//! equilibrium for extreme parameters) counts as a rejected step.

use crate::error::Result;
use nalgebra::{DMatrix, DVector};

/// Options.
#[derive(Debug, Clone, Copy)]
pub struct LmOptions {
    /// Maximum accepted + rejected iterations.
    pub max_iterations: usize,
    /// Stop when the projected gradient's inf-norm is below `gtol * (1 + cost)`.
    pub gtol: f64,
    /// Stop when the step's inf-norm is below `xtol` ...
    pub xtol: f64,
    /// ... or the relative cost decrease is below `ftol`.
    pub ftol: f64,
}

impl Default for LmOptions {
    fn default() -> Self {
        LmOptions {
            max_iterations: 200,
            gtol: 1e-12,
            xtol: 1e-11,
            ftol: 1e-15,
        }
    }
}

/// Why the iteration stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum LmStop {
    Gradient,
    Step,
    Cost,
    MaxIterations,
    /// Damping grew without bound: no descent possible (round-off floor).
    Stalled,
}

/// Result.
#[derive(Debug, Clone)]
pub struct LmResult {
    pub x: Vec<f64>,
    /// `1/2 ||r||^2`.
    pub cost: f64,
    pub r: DVector<f64>,
    pub jac: DMatrix<f64>,
    pub iterations: usize,
    pub stop: LmStop,
    /// Variables on a bound at the end.
    pub at_bound: Vec<bool>,
    /// Inf-norm of the projected gradient at the end (0 for variables held
    /// on a bound with the gradient pointing outward).
    pub grad_inf: f64,
}

impl LmResult {
    /// A first-order (KKT) point: the projected gradient is small.
    pub fn converged(&self) -> bool {
        self.grad_inf <= 1e-6 * (1.0 + self.cost)
    }
}

fn project(x: &mut [f64], lo: &[f64], hi: &[f64]) {
    for i in 0..x.len() {
        x[i] = x[i].clamp(lo[i], hi[i]);
    }
}

/// Minimise from `x0` (projected into the box). `f(x, want_jacobian)`
/// returns the residuals and, when asked, the Jacobian.
pub fn minimize<F>(
    mut f: F,
    x0: &[f64],
    lo: &[f64],
    hi: &[f64],
    opts: &LmOptions,
) -> Result<LmResult>
where
    F: FnMut(&[f64], bool) -> Result<(DVector<f64>, Option<DMatrix<f64>>)>,
{
    let n = x0.len();
    let mut x = x0.to_vec();
    project(&mut x, lo, hi);
    let (mut r, j) = f(&x, true)?;
    let mut jac = j.unwrap_or_else(|| DMatrix::zeros(r.len(), n));
    let mut cost = 0.5 * r.norm_squared();
    let mut lambda = -1.0;
    let mut nu = 2.0;
    let mut it = 0;
    let bound_tol = 1e-12;
    let stop;
    loop {
        let g = jac.transpose() * &r;
        let jtj = jac.transpose() * &jac;
        // active set: on a bound with the gradient pushing outward
        let free: Vec<usize> = (0..n)
            .filter(|&i| {
                let at_lo = x[i] <= lo[i] + bound_tol && g[i] > 0.0;
                let at_hi = x[i] >= hi[i] - bound_tol && g[i] < 0.0;
                !(at_lo || at_hi)
            })
            .collect();
        let gfree = free.iter().fold(0.0f64, |m, &i| m.max(g[i].abs()));
        if gfree <= opts.gtol * (1.0 + cost) || free.is_empty() {
            stop = LmStop::Gradient;
            break;
        }
        if it >= opts.max_iterations {
            stop = LmStop::MaxIterations;
            break;
        }
        let nf = free.len();
        let mut a = DMatrix::zeros(nf, nf);
        let mut b = DVector::zeros(nf);
        let mut diag = vec![0.0; nf];
        let dmax = free.iter().fold(0.0f64, |m, &i| m.max(jtj[(i, i)]));
        for (ai, &i) in free.iter().enumerate() {
            b[ai] = -g[i];
            diag[ai] = jtj[(i, i)].max(1e-12 * dmax.max(1e-300));
            for (bi, &k) in free.iter().enumerate() {
                a[(ai, bi)] = jtj[(i, k)];
            }
        }
        if lambda < 0.0 {
            lambda = 1e-3;
        }
        let mut accepted = false;
        let mut small_step = false;
        while !accepted {
            it += 1;
            let mut m = a.clone();
            for k in 0..nf {
                m[(k, k)] += lambda * diag[k];
            }
            let step = match m.clone().cholesky() {
                Some(c) => c.solve(&b),
                None => match m.lu().solve(&b) {
                    Some(s) => s,
                    None => {
                        lambda *= nu;
                        nu *= 2.0;
                        if lambda > 1e16 {
                            break;
                        }
                        continue;
                    }
                },
            };
            let mut xt = x.clone();
            for (ai, &i) in free.iter().enumerate() {
                xt[i] += step[ai];
            }
            project(&mut xt, lo, hi);
            let dx: Vec<f64> = (0..n).map(|i| xt[i] - x[i]).collect();
            let step_inf = dx.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            if step_inf <= opts.xtol {
                small_step = true;
                break;
            }
            // predicted decrease with the projected step
            let dxv = DVector::from_vec(dx.clone());
            let jd = &jac * &dxv;
            let pred = -(g.dot(&dxv) + 0.5 * jd.norm_squared());
            // evaluate the trial with its Jacobian: most steps are accepted,
            // and the Jacobian costs less than a second equilibrium solve
            let trial = f(&xt, true);
            let (rt, ct) = match trial {
                Ok((rt, jt)) => {
                    let ct = 0.5 * rt.norm_squared();
                    (Some((rt, jt)), ct)
                }
                Err(_) => (None, f64::INFINITY),
            };
            let rho = if pred > 0.0 { (cost - ct) / pred } else { -1.0 };
            if ct.is_finite() && rho > 1e-4 && ct < cost {
                let rel = (cost - ct) / cost.max(1e-300);
                x = xt;
                let (rn, jn) = match rt {
                    Some(v) => v,
                    None => f(&x, true)?,
                };
                r = rn;
                jac = jn.unwrap_or_else(|| DMatrix::zeros(r.len(), n));
                cost = 0.5 * r.norm_squared();
                lambda *= (1.0f64 / 3.0).max(1.0 - (2.0 * rho - 1.0).powi(3));
                nu = 2.0;
                accepted = true;
                if rel <= opts.ftol {
                    small_step = true;
                }
            } else {
                lambda *= nu;
                nu *= 2.0;
                if lambda > 1e16 || it >= opts.max_iterations {
                    break;
                }
            }
        }
        if small_step {
            stop = if accepted { LmStop::Cost } else { LmStop::Step };
            break;
        }
        if !accepted {
            stop = if it >= opts.max_iterations {
                LmStop::MaxIterations
            } else {
                LmStop::Stalled
            };
            break;
        }
    }
    let at_bound = (0..n)
        .map(|i| x[i] <= lo[i] + 1e-9 || x[i] >= hi[i] - 1e-9)
        .collect();
    let g = jac.transpose() * &r;
    let grad_inf = (0..n)
        .filter(|&i| {
            let out_lo = x[i] <= lo[i] + bound_tol && g[i] > 0.0;
            let out_hi = x[i] >= hi[i] - bound_tol && g[i] < 0.0;
            !(out_lo || out_hi)
        })
        .fold(0.0f64, |m, i| m.max(g[i].abs()));
    Ok(LmResult {
        x,
        cost,
        r,
        jac,
        iterations: it,
        stop,
        at_bound,
        grad_inf,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rosenbrock(x: &[f64], j: bool) -> Result<(DVector<f64>, Option<DMatrix<f64>>)> {
        let r = DVector::from_vec(vec![10.0 * (x[1] - x[0] * x[0]), 1.0 - x[0]]);
        let jm = j.then(|| DMatrix::from_row_slice(2, 2, &[-20.0 * x[0], 10.0, -1.0, 0.0]));
        Ok((r, jm))
    }

    #[test]
    fn solves_rosenbrock() {
        let res = minimize(
            rosenbrock,
            &[-1.2, 1.0],
            &[-5.0, -5.0],
            &[5.0, 5.0],
            &LmOptions::default(),
        )
        .unwrap();
        assert!(
            (res.x[0] - 1.0).abs() < 1e-9 && (res.x[1] - 1.0).abs() < 1e-9,
            "{:?}",
            res
        );
    }

    #[test]
    fn stops_on_an_active_bound_at_the_constrained_minimum() {
        // min (x0-3)^2 + (x1+1)^2 on [0,2]x[0,2] -> (2, 0)
        let f = |x: &[f64], j: bool| -> Result<(DVector<f64>, Option<DMatrix<f64>>)> {
            Ok((
                DVector::from_vec(vec![x[0] - 3.0, x[1] + 1.0]),
                j.then(|| DMatrix::identity(2, 2)),
            ))
        };
        let res = minimize(
            f,
            &[1.0, 1.0],
            &[0.0, 0.0],
            &[2.0, 2.0],
            &LmOptions::default(),
        )
        .unwrap();
        assert_eq!(res.x, vec![2.0, 0.0]);
        assert_eq!(res.at_bound, vec![true, true]);
        assert_eq!(res.stop, LmStop::Gradient);
    }

    #[test]
    fn linear_least_squares_in_one_step_region() {
        // exponential fit y = a exp(b t), noise-free
        let t: Vec<f64> = (0..20).map(|i| i as f64 * 0.1).collect();
        let y: Vec<f64> = t.iter().map(|t| 2.5 * (-1.3 * t).exp()).collect();
        let f = |x: &[f64], j: bool| -> Result<(DVector<f64>, Option<DMatrix<f64>>)> {
            let r = DVector::from_iterator(
                20,
                t.iter().zip(&y).map(|(t, y)| x[0] * (x[1] * t).exp() - y),
            );
            let jm = j.then(|| {
                DMatrix::from_fn(20, 2, |i, k| {
                    if k == 0 {
                        (x[1] * t[i]).exp()
                    } else {
                        x[0] * t[i] * (x[1] * t[i]).exp()
                    }
                })
            });
            Ok((r, jm))
        };
        let res = minimize(
            f,
            &[1.0, 0.0],
            &[0.0, -10.0],
            &[10.0, 10.0],
            &LmOptions::default(),
        )
        .unwrap();
        assert!((res.x[0] - 2.5).abs() < 1e-10 && (res.x[1] + 1.3).abs() < 1e-10);
    }
}
