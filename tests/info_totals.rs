//! `info` gives the total mass and every coordinate's range as OpenSim 4.6
//! does, and lists only the first missing meshes.

mod common;

use std::process::Command;

#[test]
fn total_mass_and_coordinate_ranges_agree_with_opensim() {
    let Some(model) = common::shared("data/models/cyclistFullBodyMuscle.osim") else {
        return;
    };
    let o = Command::new(common::bin())
        .args(["info", "--json", model.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    // The text summary names five missing meshes and counts the rest.
    let t = Command::new(common::bin())
        .args(["info", model.to_str().unwrap()])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&t.stdout);
    assert_eq!(text.matches("  not found: ").count(), 5, "{text}");
    assert!(text.contains("more not found"), "{text}");
    assert!(text.contains("total mass"), "{text}");
    let Some(py) = common::opensim_python() else {
        return;
    };
    let want = common::run_py(&py, "model_totals.py", &[model.to_str().unwrap()]);
    let (mass, want_mass) = (
        s["total_mass"].as_f64().unwrap(),
        want["total_mass"].as_f64().unwrap(),
    );
    println!("total mass {mass} kg (OpenSim {want_mass} kg)");
    assert!((mass - want_mass).abs() < 1e-9 * want_mass.max(1.0));
    let mut n = 0;
    for j in s["joints"].as_array().unwrap() {
        for c in j["coordinates"].as_array().unwrap() {
            let w = &want["coordinates"][c["name"].as_str().unwrap()];
            for k in 0..2 {
                let (a, b) = (
                    c["range"][k].as_f64().unwrap(),
                    w["range"][k].as_f64().unwrap(),
                );
                assert!((a - b).abs() < 1e-12, "{}: range {a} vs {b}", c["name"]);
            }
            assert_eq!(c["locked"], w["locked"], "{}", c["name"]);
            n += 1;
        }
    }
    assert_eq!(n, want["coordinates"].as_object().unwrap().len());
}
