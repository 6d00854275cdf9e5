//! Muscle paths of generated scoliotic models against the vertebrae, with
//! the real OpenSim 4.6: the README's example patient (embedded default
//! base). OpenSim's wrapped path (own points, wrap tangent points and arcs,
//! `tests/py/wrapped_paths.py`) must pass through no vertebra mesh (more
//! than 0.5 mm inside), the tool's wrapped path length must equal
//! OpenSim's, the generate self-check must agree, the base issue's wrap
//! checks must hold and OpenSim must report zero bushing force at the
//! default pose. (The OpenSim-posed shapes of `tests/generate_opensim.rs`
//! get the same checks there.)

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    common::repo_root()
}

/// Generate the README example into `dir`; returns the model and report.
fn generate_example(dir: &Path) -> (PathBuf, serde_json::Value) {
    let out = dir.join("patient.osim");
    let o = Command::new(common::bin())
        .current_dir(root())
        .args([
            "generate",
            "--landmarks",
            "fixtures/example-scoliosis.csv",
            "--out",
            out.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let rep: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("patient_report.json")).unwrap()).unwrap();
    (out, rep)
}

#[test]
fn readme_example_paths_clear_the_vertebrae_in_opensim() {
    let Some(py) = common::opensim_python() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let (model, rep) = generate_example(tmp.path());
    let (crossings, dlen) = common::opensim_path_crossings(&py, &model);
    let selfc = rep["self_check"]["muscle_segments_through_vertebrae"]
        .as_array()
        .unwrap();
    println!(
        "README example: OpenSim's wrapped paths cross {} vertebrae; self-check lists {}; \
         tool vs OpenSim path length max |diff| {dlen:.2e} m",
        crossings.len(),
        selfc.len()
    );
    for c in &crossings {
        println!(
            "  {} through {} ({:.2} mm)",
            c.muscle, c.vertebra, c.depth_mm
        );
    }
    for c in selfc {
        println!("  self-check: {c}");
    }
    let edits = rep["path_edits"].as_array().unwrap();
    for e in edits {
        println!(
            "  edit: {} {} ({})",
            e["muscle"], e["action"], e["vertebra"]
        );
    }
    assert!(crossings.is_empty(), "OpenSim's paths cross vertebrae");
    assert!(selfc.is_empty(), "the self-check lists crossings");
    assert!(
        dlen < 1e-9,
        "tool and OpenSim path lengths differ by {dlen} m"
    );
    common::check_generated_in_opensim(&py, &model);
}
