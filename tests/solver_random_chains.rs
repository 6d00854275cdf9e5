//! Acceptance 2: OpenSim 4.6 builds random chains (3-20 joints, random axis
//! orders and frame orientations, random stiffness and damping, random
//! gravity; `tests/py/random_chains.py`); the solver reads the same .osim
//! files and must reproduce OpenSim's generalised accelerations at random
//! states within 1e-8 (relative to the largest |udot|) and its static
//! equilibria under random loads within 1e-8.

mod common;

use nalgebra::Vector3;
use osim_spine::solver::{
    DofIndex, Load, LoadFrame, LoadSet, StaticOptions, System, SystemSpec, Workspace,
};
use serde_json::Value;

fn vec3(v: &Value) -> Vector3<f64> {
    let a: Vec<f64> = v
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    Vector3::new(a[0], a[1], a[2])
}

fn by_name(sys: &System, map: &Value) -> Vec<f64> {
    (0..sys.n_dofs())
        .map(|i| {
            map[sys.dof_name(DofIndex(i))]
                .as_f64()
                .unwrap_or_else(|| panic!("{} missing", sys.dof_name(DofIndex(i))))
        })
        .collect()
}

#[test]
fn random_chains_match_opensim() {
    let Some(py) = common::opensim_python() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().to_str().unwrap();
    let out = common::run_py(&py, "random_chains.py", &[d, "20250101", "8"]);
    let (mut worst_a, mut worst_q) = (0.0f64, 0.0f64);
    let mut n_states = 0;
    for m in out["models"].as_array().unwrap() {
        let file = std::path::PathBuf::from(m["file"].as_str().unwrap());
        let sys = System::new(&SystemSpec::read_osim(&file).unwrap()).unwrap();
        let mut ws = Workspace::new(&sys);
        let n = sys.n_dofs();
        assert_eq!(n, 6 * m["joints"].as_u64().unwrap() as usize);
        for st in m["states"].as_array().unwrap() {
            let q = by_name(&sys, &st["q"]);
            let u = by_name(&sys, &st["u"]);
            let want = by_name(&sys, &st["udot"]);
            let mut a = vec![0.0; n];
            sys.accelerations(&q, &u, &LoadSet::empty(), &mut ws, &mut a)
                .unwrap();
            let scale = want.iter().fold(0.0f64, |s, v| s.max(v.abs()));
            for i in 0..n {
                let rel = (a[i] - want[i]).abs() / scale;
                worst_a = worst_a.max(rel);
                assert!(
                    rel < 1e-8,
                    "{}: udot {} = {} vs OpenSim {} (rel {rel:e})",
                    file.display(),
                    sys.dof_name(DofIndex(i)),
                    a[i],
                    want[i]
                );
            }
            n_states += 1;
        }
        for sc in m["statics"].as_array().unwrap() {
            assert!(
                sc["residual"].as_f64().unwrap() < 1e-9,
                "OpenSim's Newton did not converge"
            );
            let loads: Vec<Load> = sc["loads"]
                .as_array()
                .unwrap()
                .iter()
                .map(|l| {
                    let frame = if l["frame"] == "ground" {
                        LoadFrame::Ground
                    } else {
                        LoadFrame::Body
                    };
                    let body = l["body"].as_str().unwrap().to_string();
                    if l["kind"] == "moment" {
                        Load::Moment {
                            body,
                            vec: vec3(&l["vec"]),
                            frame,
                        }
                    } else {
                        Load::Force {
                            body,
                            point_in_body: vec3(&l["point"]),
                            vec: vec3(&l["vec"]),
                            frame,
                        }
                    }
                })
                .collect();
            let ls = sys.prepare_loads(&loads).unwrap();
            let sol = sys
                .solve_static(
                    &ls,
                    sys.default_q().as_slice(),
                    &mut ws,
                    &StaticOptions::default(),
                )
                .unwrap();
            let want = by_name(&sys, &sc["q"]);
            for i in 0..n {
                let dq = (sol.q[i] - want[i]).abs();
                worst_q = worst_q.max(dq);
                assert!(
                    dq < 1e-8,
                    "{}: equilibrium {} = {} vs OpenSim {}",
                    file.display(),
                    sys.dof_name(DofIndex(i)),
                    sol.q[i],
                    want[i]
                );
            }
        }
    }
    eprintln!("random chains: {n_states} states, max rel udot diff {worst_a:.2e}; max equilibrium diff {worst_q:.2e}");
}
