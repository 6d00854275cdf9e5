//! The typed reader against OpenSim 4.6: socket path resolution (each
//! joint's parent/child base body and frame transforms, each marker's frame)
//! on real models, and function values and derivatives (SimmSpline,
//! PiecewiseLinearFunction, PolynomialFunction, LinearFunction; a
//! MultiplierFunction built in OpenSim's Python bindings crashes them, so it
//! is checked as scale * an OpenSim-checked spline) at knots, between knots and outside the knot range.

mod common;

use nalgebra::Isometry3;
use osim_spine::osim::function::{CubicSpline, Function};
use osim_spine::osim::Document;
use serde_json::Value;

fn flat(x: &Isometry3<f64>) -> Vec<f64> {
    let p = x.translation.vector;
    let r = x.rotation.to_rotation_matrix();
    let mut v = vec![p.x, p.y, p.z];
    for i in 0..3 {
        for j in 0..3 {
            v.push(r[(i, j)]);
        }
    }
    v
}

fn close(a: &[f64], b: &Value, tol: f64) -> bool {
    let b: Vec<f64> = b
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    a.len() == b.len() && a.iter().zip(&b).all(|(x, y)| (x - y).abs() <= tol)
}

fn check_model(rel: &str) {
    let Some(path) = common::shared(rel) else {
        return;
    };
    let Some(py) = common::opensim_python() else {
        return;
    };
    let facts = common::run_py(&py, "osim_facts.py", &[path.to_str().unwrap()]);
    let model = Document::read(&path).unwrap().model().unwrap();
    let frames = model.joint_frames().unwrap();
    assert_eq!(frames.len(), facts["joints"].as_object().unwrap().len());
    for jf in &frames {
        let o = &facts["joints"][&jf.joint];
        assert_eq!(
            o["parent_body"],
            jf.parent_body.as_str(),
            "{rel} {}",
            jf.joint
        );
        assert_eq!(
            o["child_body"],
            jf.child_body.as_str(),
            "{rel} {}",
            jf.joint
        );
        assert!(
            close(&flat(&jf.parent_in_body), &o["parent_in_body"], 1e-12),
            "{rel} {} parent frame",
            jf.joint
        );
        assert!(
            close(&flat(&jf.child_in_body), &o["child_in_body"], 1e-12),
            "{rel} {} child frame",
            jf.joint
        );
    }
    for mk in &model.markers {
        let o = &facts["markers"][&mk.name];
        let (body, x) = model.marker_frame(mk).unwrap();
        assert_eq!(o["body"], body.as_str(), "{rel} marker {}", mk.name);
        assert!(
            close(&flat(&x), &o["frame_in_body"], 1e-12),
            "{rel} marker {}",
            mk.name
        );
    }
    eprintln!(
        "{rel}: {} joints, {} markers agree with OpenSim",
        frames.len(),
        model.markers.len()
    );
}

#[test]
fn socket_resolution_matches_opensim_chain() {
    check_model("oracle/chain.osim");
    check_model("oracle/chain_bushing_ownframes.osim");
}

#[test]
fn socket_resolution_matches_opensim_cyclist() {
    check_model("data/models/cyclistFullBodyMuscle.osim");
}

#[test]
fn functions_match_opensim() {
    let Some(py) = common::opensim_python() else {
        return;
    };
    let Some(path) = common::shared("oracle/chain.osim") else {
        return;
    };
    let facts = common::run_py(&py, "osim_facts.py", &[path.to_str().unwrap()]);
    let xs: Vec<f64> = facts["xs"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    let nums = |v: &Value| -> Vec<f64> {
        v.as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect()
    };
    let mut checked = 0;
    for (name, f) in facts["functions"].as_object().unwrap() {
        let ours = if name.starts_with("SimmSpline") {
            Function::Spline {
                class: "SimmSpline".into(),
                spline: CubicSpline::new(nums(&f["x"]), nums(&f["y"])),
            }
        } else if name.starts_with("PiecewiseLinear") {
            Function::PiecewiseLinear {
                x: nums(&f["x"]),
                y: nums(&f["y"]),
            }
        } else if name == "Polynomial" {
            Function::Polynomial(nums(&f["coefficients"]))
        } else if name == "Linear" {
            let c = nums(&f["coefficients"]);
            Function::Linear {
                slope: c[0],
                intercept: c[1],
            }
        } else {
            panic!("unexpected function {name}");
        };
        let scaled = Function::Multiplier {
            scale: -1.75,
            inner: Box::new(ours.clone()),
        };
        for (x, want) in xs.iter().zip(f["values"].as_array().unwrap()) {
            let want = nums(want);
            for (order, w) in want.iter().enumerate() {
                let got = ours.derivative(*x, order);
                assert!(
                    (got - w).abs() <= 1e-12 * (1.0 + w.abs()),
                    "{name} order {order} at x={x}: ours {got}, OpenSim {w}"
                );
                let s = scaled.derivative(*x, order);
                assert!(
                    (s + 1.75 * w).abs() <= 2e-12 * (1.0 + w.abs()),
                    "multiplier {name}: {s}"
                );
                checked += 1;
            }
        }
    }
    assert!(checked >= 300, "only {checked} values checked");
}
