//! The calibration Jacobian (`calibrate/problem.rs`): the derivative of the
//! weighted residuals with respect to the fitting coordinates, by implicit
//! differentiation through the equilibria (`dq/dp = -T^{-1} d tau/d p`) and
//! dual numbers through the kinematics, for every parameterisation
//! (uniform, ratio, per-level, non-linear sinh and cubic, uniform and per
//! level, coupled), with rotations only and with translations and the
//! difference increments, on the dev-07 T12-S1 specimen and its 24 load
//! cases:
//! 1. equals central differences of the residuals, to the error bound of a
//!    central difference of the step;
//! 2. is the first-order term of the residuals' Taylor expansion: the
//!    remainder `|r(x + h v) - r(x) - h J v|` falls four-fold when `h`
//!    halves (second order), where a wrong Jacobian leaves a first-order
//!    part in the remainder and the ratio falls toward two.

#[path = "common/calibration.rs"]
mod calibration;
mod common;

use calibration::{
    central_difference_tolerance, experiment, problem, relative_gap, setups, test_point,
};
use nalgebra::{DMatrix, DVector};
use osim_spine::calibrate::problem::{Evaluator, Problem};

/// Weighted residuals at `x`.
fn residuals(ev: &mut Evaluator, pb: &Problem, x: &[f64]) -> DVector<f64> {
    ev.residuals(pb, x, false).expect("residuals").0
}

/// Central differences of the residuals, one column per fitting coordinate.
fn central_differences(ev: &mut Evaluator, pb: &Problem, x: &[f64], h: f64) -> DMatrix<f64> {
    let m = pb.cells.len();
    let mut fd = DMatrix::zeros(m, x.len());
    let mut xp = x.to_vec();
    for k in 0..x.len() {
        xp[k] = x[k] + h;
        let rp = residuals(ev, pb, &xp);
        xp[k] = x[k] - h;
        let rm = residuals(ev, pb, &xp);
        xp[k] = x[k];
        fd.set_column(k, &((rp - rm) / (2.0 * h)));
    }
    fd
}

#[test]
fn the_calibration_jacobian_equals_central_differences_for_every_parameterisation() {
    let Some(exp) = experiment() else { return };
    // Fitting coordinates are of order one (log-stiffness, shape
    // parameters), so an absolute step is a relative one.
    let h = 1e-6;
    let tol = central_difference_tolerance(h);
    for (label, setup) in setups() {
        let (pb, fam) = problem(&exp, &setup);
        let x = test_point(&fam);
        let mut ev = pb.evaluator();
        let (_, jac) = ev.residuals(&pb, &x, true).expect("residuals");
        let jac = jac.expect("a Jacobian was asked for");
        let fd = central_differences(&mut ev, &pb, &x, h);
        let gap = relative_gap(&jac, &fd);
        println!(
            "{label}: {} x {} Jacobian, relative gap {gap:.2e} (bound {tol:.1e})",
            jac.nrows(),
            jac.ncols()
        );
        assert!(
            gap < tol,
            "{label}: Jacobian differs from central differences by {gap:.2e} (bound {tol:.1e})"
        );
    }
}

/// A direction in fitting coordinates with every component non-zero and of
/// unit length.
fn direction(n: usize) -> DVector<f64> {
    let v = DVector::from_fn(n, |j, _| {
        (j as f64 * 2.9 + 0.4).sin() + 0.1 * (j % 3) as f64 + 0.2
    });
    v.normalize()
}

#[test]
fn the_taylor_remainder_of_the_residuals_is_second_order() {
    let Some(exp) = experiment() else { return };
    for (label, setup) in setups() {
        let (pb, fam) = problem(&exp, &setup);
        let x = DVector::from_vec(test_point(&fam));
        let mut ev = pb.evaluator();
        let (r0, jac) = ev.residuals(&pb, x.as_slice(), true).expect("residuals");
        let jv = jac.expect("a Jacobian was asked for") * direction(x.len());
        let v = direction(x.len());
        // The first-order remainder at h = 0.04, 0.02, 0.01: far above
        // rounding (of order h^2 |r''|, |r''| of order |r|).
        let remainders: Vec<f64> = [0.04, 0.02, 0.01]
            .iter()
            .map(|&h| {
                let xh = &x + &v * h;
                (residuals(&mut ev, &pb, xh.as_slice()) - &r0 - &jv * h).norm()
            })
            .collect();
        let ratios: Vec<f64> = remainders.windows(2).map(|w| w[0] / w[1]).collect();
        println!("{label}: remainders {remainders:.3?}, ratios {ratios:.2?}");
        for q in &ratios {
            assert!(
                (3.5..4.5).contains(q),
                "{label}: Taylor remainder falls by {q:.2} when the step halves \
                 (expected 4: second order; a wrong Jacobian tends to 2)"
            );
        }
    }
}
