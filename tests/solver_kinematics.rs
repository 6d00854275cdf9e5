//! Acceptance 2 (kinematics): forward kinematics of the full-body cyclist
//! model (CustomJoints with splines, multipliers, constants; PinJoints,
//! UniversalJoints, WeldJoints) matches OpenSim 4.6 for 100 random states
//! within 1e-10 in every body transform.

mod common;

use nalgebra::{Matrix3, Vector3};
use osim_spine::solver::{System, SystemSpec, Workspace};

#[test]
fn cyclist_forward_kinematics_matches_opensim() {
    let Some(model) = common::shared("data/models/cyclistFullBodyMuscle.osim") else {
        return;
    };
    let Some(py) = common::opensim_python() else {
        return;
    };
    let out = common::run_py(
        &py,
        "body_poses.py",
        &[model.to_str().unwrap(), "100", "4242"],
    );
    let mut spec = SystemSpec::read_osim(&model).unwrap();
    // every coordinate free: pure X_GB(q)
    for c in spec.coordinates.iter_mut() {
        c.locked = false;
    }
    let sys = System::new(&spec).unwrap();
    let mut ws = Workspace::new(&sys);
    let states = out["states"].as_array().unwrap();
    assert_eq!(states.len(), 100);
    let mut worst = 0.0f64;
    for st in states {
        let full: Vec<f64> = sys
            .coordinates()
            .iter()
            .map(|c| {
                st["q"][&c.name]
                    .as_f64()
                    .unwrap_or_else(|| panic!("{} missing", c.name))
            })
            .collect();
        let q = sys.dofs_from_full(&full);
        let poses = sys.body_poses(q.as_slice(), &mut ws).unwrap();
        for (name, want) in st["bodies"].as_object().unwrap() {
            let got = poses
                .get(name)
                .unwrap_or_else(|| panic!("body {name} missing"));
            let p: Vec<f64> = want["p"]
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_f64().unwrap())
                .collect();
            let dp = (Vector3::from(got.origin_in_ground) - Vector3::new(p[0], p[1], p[2])).amax();
            let r = Matrix3::from_fn(|i, j| want["R"][i][j].as_f64().unwrap());
            let gr = Matrix3::from_fn(|i, j| got.r_ground_body_rowmajor[i][j]);
            let dr = (gr - r).amax();
            worst = worst.max(dp).max(dr);
            assert!(
                dp < 1e-10 && dr < 1e-10,
                "body {name}: |dp| {dp:e}, |dR| {dr:e}"
            );
        }
    }
    eprintln!(
        "cyclist FK: 100 states x {} bodies, max difference {worst:.2e}",
        sys.n_bodies()
    );
}
