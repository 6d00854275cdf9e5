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
    /// Damping of the first trial step, relative to `diag(J^T J)`: small
    /// for a nearly linear problem started near its solution (the first
    /// step is then Gauss-Newton's).
    pub initial_damping: f64,
}

impl Default for LmOptions {
    fn default() -> Self {
        LmOptions {
            max_iterations: 200,
            gtol: 1e-12,
            xtol: 1e-11,
            ftol: 1e-15,
            initial_damping: 1e-3,
        }
    }
}

/// Why the iteration stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum LmStop {
    /// The projected gradient is below `gtol * (1 + cost)` (or every variable is held).
    Gradient,
    /// The projected trial step's inf-norm is below `xtol`.
    Step,
    /// An accepted step lowered the cost by a relative amount below `ftol`.
    Cost,
    /// `max_iterations` reached.
    MaxIterations,
    /// Damping grew without bound: no descent possible (round-off floor).
    Stalled,
}

/// Result.
#[derive(Debug, Clone)]
pub struct LmResult {
    /// Solution.
    pub x: Vec<f64>,
    /// `1/2 ||r||^2`.
    pub cost: f64,
    /// Residuals at `x`.
    pub r: DVector<f64>,
    /// Jacobian of the residuals at `x`.
    pub jac: DMatrix<f64>,
    /// Iterations, accepted and rejected.
    pub iterations: usize,
    /// Why the iteration stopped.
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

/// Tolerance of "on a bound" for the active set.
const BOUND_TOL: f64 = 1e-12;

/// Whether variable `i` is held: on a bound with the gradient `g` pushing
/// outward.
fn held(i: usize, x: &[f64], g: &DVector<f64>, lo: &[f64], hi: &[f64]) -> bool {
    let at_lo = x[i] <= lo[i] + BOUND_TOL && g[i] > 0.0;
    let at_hi = x[i] >= hi[i] - BOUND_TOL && g[i] < 0.0;
    at_lo || at_hi
}

/// The iterate and the damping state of a minimisation.
struct Iterate {
    x: Vec<f64>,
    r: DVector<f64>,
    jac: DMatrix<f64>,
    /// `1/2 ||r||^2`.
    cost: f64,
    lambda: f64,
    nu: f64,
    /// Accepted + rejected iterations so far.
    it: usize,
}

/// The damped normal equations over the free variables: `(a + lambda
/// diag(d)) s = b`.
struct Reduced {
    free: Vec<usize>,
    a: DMatrix<f64>,
    b: DVector<f64>,
    diag: Vec<f64>,
}

impl Reduced {
    /// Normal equations of `jtj`, gradient `g` restricted to `free`, with
    /// Marquardt scaling (floored at 1e-12 of the largest diagonal entry).
    fn new(free: Vec<usize>, g: &DVector<f64>, jtj: &DMatrix<f64>) -> Self {
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
        Reduced { free, a, b, diag }
    }

    /// The step for damping `lambda` (Cholesky, LU as fallback; `None`
    /// when singular).
    fn solve(&self, lambda: f64) -> Option<DVector<f64>> {
        let mut m = self.a.clone();
        for k in 0..self.free.len() {
            m[(k, k)] += lambda * self.diag[k];
        }
        match m.clone().cholesky() {
            Some(c) => Some(c.solve(&self.b)),
            None => m.lu().solve(&self.b),
        }
    }
}

/// How a round of damped trial steps ended.
struct Round {
    accepted: bool,
    small_step: bool,
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
    // Start inside the box, with residuals and Jacobian there.
    let mut x = x0.to_vec();
    project(&mut x, lo, hi);
    let (r, j) = f(&x, true)?;
    let jac = j.unwrap_or_else(|| DMatrix::zeros(r.len(), n));
    let cost = 0.5 * r.norm_squared();
    let mut s = Iterate {
        x,
        r,
        jac,
        cost,
        lambda: opts.initial_damping,
        nu: 2.0,
        it: 0,
    };
    let stop = loop {
        // The gradient and Gauss-Newton matrix; variables held on a bound.
        let g = s.jac.transpose() * &s.r;
        let jtj = s.jac.transpose() * &s.jac;
        let free: Vec<usize> = (0..n).filter(|&i| !held(i, &s.x, &g, lo, hi)).collect();
        // First-order point, or out of iterations.
        let gfree = free.iter().fold(0.0f64, |m, &i| m.max(g[i].abs()));
        if gfree <= opts.gtol * (1.0 + s.cost) || free.is_empty() {
            break LmStop::Gradient;
        }
        if s.it >= opts.max_iterations {
            break LmStop::MaxIterations;
        }
        // Damped steps over the free variables until one lowers the cost.
        let sys = Reduced::new(free, &g, &jtj);
        let round = s.trial_steps(&mut f, &sys, &g, lo, hi, opts)?;
        if round.small_step {
            break if round.accepted {
                LmStop::Cost
            } else {
                LmStop::Step
            };
        }
        if !round.accepted {
            break if s.it >= opts.max_iterations {
                LmStop::MaxIterations
            } else {
                LmStop::Stalled
            };
        }
    };
    // Which variables end on a bound, and the projected gradient there.
    Ok(s.result(stop, lo, hi))
}

impl Iterate {
    /// Trial steps with growing damping until one is accepted (gain ratio
    /// above 1e-4 and a lower cost), the step or the relative decrease is
    /// below tolerance, or the damping / iteration limit is hit. A failed
    /// evaluation is a rejected step.
    fn trial_steps<F>(
        &mut self,
        f: &mut F,
        sys: &Reduced,
        g: &DVector<f64>,
        lo: &[f64],
        hi: &[f64],
        opts: &LmOptions,
    ) -> Result<Round>
    where
        F: FnMut(&[f64], bool) -> Result<(DVector<f64>, Option<DMatrix<f64>>)>,
    {
        let n = self.x.len();
        loop {
            self.it += 1;
            let Some(step) = sys.solve(self.lambda) else {
                self.lambda *= self.nu;
                self.nu *= 2.0;
                if self.lambda > 1e16 {
                    return Ok(Round {
                        accepted: false,
                        small_step: false,
                    });
                }
                continue;
            };
            let mut xt = self.x.clone();
            for (ai, &i) in sys.free.iter().enumerate() {
                xt[i] += step[ai];
            }
            project(&mut xt, lo, hi);
            let dx: Vec<f64> = (0..n).map(|i| xt[i] - self.x[i]).collect();
            let step_inf = dx.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            if step_inf <= opts.xtol {
                return Ok(Round {
                    accepted: false,
                    small_step: true,
                });
            }
            // predicted decrease with the projected step
            let dxv = DVector::from_vec(dx);
            let jd = &self.jac * &dxv;
            let pred = -(g.dot(&dxv) + 0.5 * jd.norm_squared());
            // evaluate the trial with its Jacobian: most steps are accepted,
            // and the Jacobian costs less than a second equilibrium solve
            let (rt, ct) = match f(&xt, true) {
                Ok((rt, jt)) => {
                    let ct = 0.5 * rt.norm_squared();
                    (Some((rt, jt)), ct)
                }
                Err(_) => (None, f64::INFINITY),
            };
            let rho = if pred > 0.0 {
                (self.cost - ct) / pred
            } else {
                -1.0
            };
            if ct.is_finite() && rho > 1e-4 && ct < self.cost {
                let rel = (self.cost - ct) / self.cost.max(1e-300);
                self.x = xt;
                let (rn, jn) = match rt {
                    Some(v) => v,
                    None => f(&self.x, true)?,
                };
                self.r = rn;
                self.jac = jn.unwrap_or_else(|| DMatrix::zeros(self.r.len(), n));
                self.cost = 0.5 * self.r.norm_squared();
                self.lambda *= (1.0f64 / 3.0).max(1.0 - (2.0 * rho - 1.0).powi(3));
                self.nu = 2.0;
                return Ok(Round {
                    accepted: true,
                    small_step: rel <= opts.ftol,
                });
            }
            self.lambda *= self.nu;
            self.nu *= 2.0;
            if self.lambda > 1e16 || self.it >= opts.max_iterations {
                return Ok(Round {
                    accepted: false,
                    small_step: false,
                });
            }
        }
    }

    /// The result at this iterate.
    fn result(self, stop: LmStop, lo: &[f64], hi: &[f64]) -> LmResult {
        let n = self.x.len();
        let x = self.x;
        let at_bound = (0..n)
            .map(|i| x[i] <= lo[i] + 1e-9 || x[i] >= hi[i] - 1e-9)
            .collect();
        let g = self.jac.transpose() * &self.r;
        let grad_inf = (0..n)
            .filter(|&i| !held(i, &x, &g, lo, hi))
            .fold(0.0f64, |m, i| m.max(g[i].abs()));
        LmResult {
            x,
            cost: self.cost,
            r: self.r,
            jac: self.jac,
            iterations: self.it,
            stop,
            at_bound,
            grad_inf,
        }
    }
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
