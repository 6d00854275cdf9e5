//! Finite-difference checks of the calibration's derivatives, for every
//! parameterisation (uniform, ratio, per-level, non-linear sinh and cubic,
//! uniform and per level, coupled) on the dev-07 T12-S1 specimen and its 24
//! load cases:
//! 1. the Jacobian of the weighted residuals with respect to the fitting
//!    coordinates (implicit differentiation through the equilibria,
//!    `calibrate/problem.rs`) equals central differences of the residuals;
//! 2. the family's exact `d tau / d p` (dual numbers through the laws,
//!    `StiffnessFamily::dtau_dp`, the forms' path for the non-linear and
//!    coupled families) equals central differences of the static residual
//!    of the family's systems.

mod common;

use nalgebra::DMatrix;
use osim_spine::calibrate::experiment::Experiment;
use osim_spine::calibrate::family::{
    read_ratio_table, ModelFamily, Parameterisation, Scale, StiffnessFamily,
};
use osim_spine::calibrate::forms::CurveForm;
use osim_spine::calibrate::problem::Problem;
use osim_spine::calibrate::setup::{build_problem, Setup};
use osim_spine::solver::Workspace;
use std::sync::Arc;

fn experiment() -> Option<Experiment> {
    let dir = common::shared("diagnose-dev/dev-07")?;
    Some(Experiment::read(&dir).expect("dev-07 reads"))
}

/// Every parameterisation the calibration offers, with a label.
fn parameterisations() -> Vec<(&'static str, Parameterisation)> {
    let ratios = common::repo_root().join("templates/level_ratios_zhang.toml");
    let nonlinear = |curve, per_level| Parameterisation::Nonlinear { curve, per_level };
    vec![
        ("uniform", Parameterisation::Uniform),
        (
            "ratio",
            Parameterisation::Ratio(read_ratio_table(&ratios).expect("ratio table reads")),
        ),
        ("per-level", Parameterisation::PerLevel),
        ("nonlinear:sinh", nonlinear(CurveForm::Sinh, false)),
        ("nonlinear:cubic", nonlinear(CurveForm::Cubic, false)),
        ("nonlinear:sinh:per-level", nonlinear(CurveForm::Sinh, true)),
        (
            "nonlinear:cubic:per-level",
            nonlinear(CurveForm::Cubic, true),
        ),
        ("coupled", Parameterisation::Coupled),
    ]
}

fn problem(exp: &Experiment, params: Parameterisation) -> (Problem, Arc<StiffnessFamily>) {
    let setup = Setup {
        params,
        ..Setup::default()
    };
    build_problem(Arc::new(exp.clone()), &setup).expect("problem builds")
}

/// A point away from the nominal values (each fitting coordinate moved by a
/// different amount, inside the bounds), so no derivative vanishes by
/// symmetry.
fn test_point(fam: &StiffnessFamily) -> Vec<f64> {
    fam.params_info()
        .iter()
        .enumerate()
        .map(|(j, info)| {
            let shift = 0.15 * ((j as f64 * 1.7).sin() + 0.5);
            let x = match info.scale {
                Scale::Log => info.to_fit(info.nominal) + shift,
                Scale::Log1p => (0.3 + 0.2 * shift.abs()).ln_1p(),
                Scale::Linear => 0.2 * shift,
            };
            let (lo, hi) = info.fit_bounds();
            x.clamp(lo + 1e-3 * (hi - lo), hi - 1e-3 * (hi - lo))
        })
        .collect()
}

/// Largest entry of `|a - b|` against the largest entry of `|b|`.
fn relative_gap(a: &DMatrix<f64>, b: &DMatrix<f64>) -> f64 {
    let scale = b.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    (a - b).iter().fold(0.0f64, |m, v| m.max(v.abs())) / scale
}

#[test]
fn the_calibration_jacobian_equals_central_differences_for_every_parameterisation() {
    let Some(exp) = experiment() else { return };
    for (label, params) in parameterisations() {
        let (pb, fam) = problem(&exp, params);
        let x = test_point(&fam);
        let mut ev = pb.evaluator();
        let (_, jac) = ev.residuals(&pb, &x, true).expect("residuals");
        let jac = jac.expect("a Jacobian was asked for");
        let mut fd = DMatrix::zeros(jac.nrows(), jac.ncols());
        for k in 0..x.len() {
            let h = 1e-6;
            let mut xp = x.clone();
            xp[k] += h;
            let (rp, _) = ev.residuals(&pb, &xp, false).expect("residuals +h");
            xp[k] -= 2.0 * h;
            let (rm, _) = ev.residuals(&pb, &xp, false).expect("residuals -h");
            fd.set_column(k, &((rp - rm) / (2.0 * h)));
        }
        let gap = relative_gap(&jac, &fd);
        println!(
            "{label}: {} x {} Jacobian, relative gap {gap:.2e}",
            jac.nrows(),
            jac.ncols()
        );
        assert!(
            gap < 1e-5,
            "{label}: Jacobian differs from central differences by {gap:.2e}"
        );
    }
}

#[test]
fn the_exact_dtau_dp_equals_central_differences_for_every_parameterisation() {
    let Some(exp) = experiment() else { return };
    for (label, params) in parameterisations() {
        let (pb, fam) = problem(&exp, params);
        let p = pb.values_of(&test_point(&fam));
        let sys = fam.system(&p, pb.system()).expect("system of p");
        let loads = sys.prepare_loads(&[]).expect("no loads");
        let mut ws = Workspace::new(&sys);
        // A deflected state: every free coordinate moved by a few degrees (or mm).
        let q: Vec<f64> = (0..sys.n_dofs())
            .map(|i| 0.05 * ((i as f64 * 2.3).cos() + 0.3))
            .collect();
        let mut exact = DMatrix::zeros(sys.n_dofs(), p.len());
        fam.dtau_dp(&p, &sys, &q, &loads, &mut ws, &mut exact)
            .expect("dtau_dp");
        let mut fd = DMatrix::zeros(sys.n_dofs(), p.len());
        let mut pp = p.clone();
        for j in 0..p.len() {
            let h = 1e-6 * p[j].abs().max(1e-3);
            pp[j] = p[j] + h;
            let plus = residual(&fam, &pp, &sys, &q, &loads, &mut ws);
            pp[j] = p[j] - h;
            let minus = residual(&fam, &pp, &sys, &q, &loads, &mut ws);
            pp[j] = p[j];
            for i in 0..sys.n_dofs() {
                fd[(i, j)] = (plus[i] - minus[i]) / (2.0 * h);
            }
        }
        let gap = relative_gap(&exact, &fd);
        println!(
            "{label}: dtau/dp {} x {}, relative gap {gap:.2e}",
            fd.nrows(),
            fd.ncols()
        );
        assert!(
            gap < 1e-6,
            "{label}: d tau / d p differs from central differences by {gap:.2e}"
        );
    }
}

/// The static residual of the family's system of `p` at `q`.
fn residual(
    fam: &StiffnessFamily,
    p: &[f64],
    sys: &osim_spine::solver::System,
    q: &[f64],
    loads: &osim_spine::solver::LoadSet,
    ws: &mut Workspace,
) -> Vec<f64> {
    let s = fam.system(p, sys).expect("system of p");
    s.static_residual(q, loads, ws).expect("residual").to_vec()
}
