//! Acceptance: each legacy (1.9/2.x/3.x) model in ../shared/data/models/legacy,
//! converted by `osim-spine convert`, loads in OpenSim 4.6 and gives the same
//! body transforms, marker positions, muscle path lengths and bushing forces
//! as OpenSim's own reading of the legacy file, in the default state and 20
//! random states, within 1e-9.

mod common;

use std::process::Command;

const TOL: f64 = 1e-9;

#[test]
fn legacy_models_convert_like_opensim() {
    let Some(dir) = common::shared("data/models/legacy") else {
        return;
    };
    let py = common::opensim_python();
    let out_dir = tempfile::tempdir().unwrap();
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "osim"))
        .collect();
    files.sort();
    assert!(
        files.len() >= 4,
        "expected the 4 legacy models, found {}",
        files.len()
    );
    for f in files {
        let out = out_dir.path().join(f.file_name().unwrap());
        let st = Command::new(common::bin())
            .args(["convert", f.to_str().unwrap(), out.to_str().unwrap()])
            .output()
            .unwrap();
        assert!(
            st.status.success(),
            "{}: {}",
            f.display(),
            String::from_utf8_lossy(&st.stderr)
        );
        let text = std::fs::read_to_string(&out).unwrap();
        assert!(
            text.contains("<OpenSimDocument Version=\"40600\">"),
            "{}",
            f.display()
        );
        assert!(!text.contains("<parent_body>") && !text.contains("location_in_parent"));
        // Our own typed reading of the converted file agrees with the original's.
        let a = osim_spine::osim::Document::read(&f)
            .unwrap()
            .model()
            .unwrap();
        let b = osim_spine::osim::Document::read(&out)
            .unwrap()
            .model()
            .unwrap();
        assert_eq!(a.bodies.len(), b.bodies.len());
        assert_eq!(a.joint_frames().unwrap(), b.joint_frames().unwrap());

        let Some(py) = &py else { continue };
        let r = common::run_py(
            py,
            "compare_models.py",
            &[f.to_str().unwrap(), out.to_str().unwrap(), "20", "11"],
        );
        eprintln!("{}: {r}", f.display());
        assert_eq!(r["states"], 21);
        assert_eq!(r["name_mismatch"].as_array().unwrap().len(), 0, "{r}");
        assert_eq!(r["bodies"].as_u64().unwrap() as usize, a.bodies.len());
        assert_eq!(r["markers"].as_u64().unwrap() as usize, a.markers.len());
        for k in ["max_body", "max_marker", "max_length"] {
            let v = r[k].as_f64().unwrap();
            assert!(v <= TOL, "{}: {k} = {v}", f.display());
        }
    }
}
