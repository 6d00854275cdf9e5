//! The family's exact `d tau / d p` (`StiffnessFamily::dtau_dp`: the
//! stiffness sensitivities of the solver for the linear families, dual
//! numbers through the laws for the non-linear and coupled ones,
//! `dtau_dp_forms`) equals central differences of the static residual of
//! the family's systems, for every parameterisation, with rotations only
//! and with translational stiffness, at a deflected state of the dev-07
//! T12-S1 specimen.

#[path = "common/calibration.rs"]
mod calibration;
mod common;

use calibration::{
    central_difference_tolerance, experiment, problem, relative_gap, setups, test_point,
};
use nalgebra::DMatrix;
use osim_spine::calibrate::family::{ModelFamily, StiffnessFamily};
use osim_spine::solver::{LoadSet, System, Workspace};

/// The static residual of the family's system of `p` at `q`.
fn residual(
    fam: &StiffnessFamily,
    p: &[f64],
    sys: &System,
    q: &[f64],
    loads: &LoadSet,
    ws: &mut Workspace,
) -> Vec<f64> {
    let s = fam.system(p, sys).expect("system of p");
    s.static_residual(q, loads, ws).expect("residual").to_vec()
}

#[test]
fn the_exact_dtau_dp_equals_central_differences_for_every_parameterisation() {
    let Some(exp) = experiment() else { return };
    // Each parameter stepped by `H` of its value (shape parameters near zero
    // by `H` of 1e-3): a relative step.
    const H: f64 = 1e-6;
    let tol = central_difference_tolerance(H);
    for (label, setup) in setups() {
        let (pb, fam) = problem(&exp, &setup);
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
            let h = H * p[j].abs().max(1e-3);
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
            "{label}: dtau/dp {} x {}, relative gap {gap:.2e} (bound {tol:.1e})",
            fd.nrows(),
            fd.ncols()
        );
        assert!(
            gap < tol,
            "{label}: d tau / d p differs from central differences by {gap:.2e} (bound {tol:.1e})"
        );
    }
}
