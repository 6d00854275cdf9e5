//! Static equilibria that plain damped Newton could not find (its line search
//! stalled or it ran out of iterations) and the load-continuation fallback
//! finds, checked by OpenSim 4.6: the base model (`base_model/base.osim`,
//! 17 six-DoF joints, muscles off) under gravity and large pure moments on
//! T1. OpenSim's own inverse-dynamics residual at the tool's answer must be
//! at round-off and its own Newton from there must stay put. The stability
//! flag of the gravity-only equilibrium is checked against the eigenvalues of
//! OpenSim's own (finite-difference) stiffness matrix.

mod common;

use nalgebra::Vector3;
use osim_spine::solver::{Load, LoadFrame, StaticOptions, System, SystemSpec, Workspace};
use serde_json::json;

#[test]
fn base_model_large_moments_match_opensim() {
    let path = common::repo_root().join("base_model/base.osim");
    let spec = SystemSpec::read_osim(&path).unwrap();
    let sys = System::new(&spec).unwrap();
    let mut ws = Workspace::new(&sys);
    let opts = StaticOptions::default();
    let names: Vec<String> = sys.coordinates().iter().map(|c| c.name.clone()).collect();
    // moments (N m, ground axes) on T1 with gravity on; the first two made
    // plain Newton's line search stall, the third its iteration limit
    // (200); the last is gravity alone (plain Newton converges, to an
    // unstable equilibrium: the straight-ish ligamentous spine is beyond its
    // buckling load); gravity alone again by continuation only
    // (`solve_static_continuation`: the loaded path, a stable equilibrium)
    let moments = [
        Vector3::new(0.0, 0.0, -30.0),
        Vector3::new(30.0, 0.0, 0.0),
        Vector3::new(0.0, 0.0, 30.0),
        Vector3::zeros(),
        Vector3::zeros(),
    ];
    let mut cases = Vec::new();
    let mut tool = Vec::new();
    let mut tool_min_eig: Vec<f64> = Vec::new();
    for (k, m) in moments.into_iter().enumerate() {
        let loads = if m == Vector3::zeros() {
            vec![]
        } else {
            vec![Load::Moment {
                body: "thoracic1".into(),
                vec: m,
                frame: LoadFrame::Ground,
            }]
        };
        let loads = sys.prepare_loads(&loads).unwrap();
        let q0 = sys.default_q();
        let sol = if k == 4 {
            sys.solve_static_continuation(&loads, q0.as_slice(), &mut ws, &opts)
        } else {
            sys.solve_static(&loads, q0.as_slice(), &mut ws, &opts)
        }
        .unwrap_or_else(|e| panic!("moment {m:?}: {e}"));
        assert!(
            sol.residual_norm <= opts.residual_tol,
            "{m:?}: {}",
            sol.residual_norm
        );
        // the tool's own dense stiffness -(T + T^T)/2: smallest eigenvalue
        let t = sys
            .static_tangent(sol.q.as_slice(), &loads, &mut ws)
            .unwrap();
        let e = (-(&t + t.transpose()) * 0.5).symmetric_eigenvalues();
        tool_min_eig.push(e.iter().copied().fold(f64::INFINITY, f64::min));
        if k == 4 {
            assert!(sol.continuation_steps > 0);
        } else if m != Vector3::zeros() {
            assert!(
                sol.continuation_steps > 0,
                "{m:?}: expected a case plain Newton cannot solve"
            );
            assert_eq!(sol.stable, None, "moments are not conservative");
        } else {
            assert_eq!(sol.continuation_steps, 0);
        }
        let full = sys.full_coordinates(sol.q.as_slice());
        let q: serde_json::Map<String, serde_json::Value> = names
            .iter()
            .zip(full.iter())
            .map(|(n, v)| (n.clone(), json!(v)))
            .collect();
        cases.push(json!({"moment": [m.x, m.y, m.z], "q": q}));
        tool.push(sol);
    }
    let Some(python) = common::opensim_python() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let cpath = dir.path().join("cases.json");
    std::fs::write(
        &cpath,
        serde_json::to_string(&json!({"body": "thoracic1", "cases": cases})).unwrap(),
    )
    .unwrap();
    let res = common::run_py(
        &python,
        "loaded_equilibrium.py",
        &[path.to_str().unwrap(), cpath.to_str().unwrap()],
    );
    let out = res["cases"].as_array().unwrap();
    assert_eq!(out.len(), moments.len());
    for ((c, m), sol) in out.iter().zip(moments).zip(&tool) {
        let r0 = c["residual_at_tool_q"].as_f64().unwrap();
        let dq = c["max_abs_dq"].as_f64().unwrap();
        let fin = c["final_residual"].as_f64().unwrap();
        let maxq = c["max_abs_q"].as_f64().unwrap();
        eprintln!(
            "moment {:?}: OpenSim residual at the tool's q {r0:.2e}, |dq| {dq:.2e}, final {fin:.2e}, \
             max |q| {maxq:.3}, min stiffness eigenvalue {}, tool stable {:?}, {} continuation steps",
            [m.x, m.y, m.z],
            c["min_stiffness_eigenvalue"],
            sol.stable,
            sol.continuation_steps
        );
        // relative to the moment (30 N m) or, under gravity alone, to the
        // gravity moments of the same order
        assert!(r0 < 1e-8 * 30.0, "{m:?}: OpenSim residual {r0:e}");
        assert!(
            fin < 1e-8,
            "{m:?}: OpenSim's Newton did not converge ({fin:e})"
        );
        assert!(
            dq < 1e-8,
            "{m:?}: OpenSim's Newton moved {dq:e} from the tool's q"
        );
        assert!(maxq > 0.1, "{m:?}: loads too small to test anything");
    }
    // stability: gravity alone is conservative; OpenSim's stiffness must be
    // symmetric, its smallest eigenvalue equal to the tool's and its sign
    // match the tool's flag: plain Newton's equilibrium is unstable, the
    // continuation's stable
    for k in [3, 4] {
        let g = &out[k];
        let asym = g["jacobian_asymmetry"].as_f64().unwrap();
        let min_eig = g["min_stiffness_eigenvalue"].as_f64().unwrap();
        assert!(
            asym < 1e-6,
            "gravity-only stiffness not symmetric: {asym:e}"
        );
        assert!(
            (min_eig - tool_min_eig[k]).abs() <= 1e-4 * min_eig.abs().max(1.0),
            "smallest stiffness eigenvalue: OpenSim {min_eig}, tool {}",
            tool_min_eig[k]
        );
        assert_eq!(
            tool[k].stable,
            Some(min_eig > 0.0),
            "tool's stability flag vs OpenSim's smallest stiffness eigenvalue {min_eig:e}"
        );
    }
    assert_eq!(tool[3].stable, Some(false));
    assert_eq!(tool[4].stable, Some(true));
}
