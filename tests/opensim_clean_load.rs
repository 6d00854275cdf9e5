//! Every model the tool writes loads in the real OpenSim 4.6 with no
//! warning, no error, no update notice and no parameter update: `convert` of the four legacy models and of the cyclist
//! model, `base` (procedural and cyclist), `generate`, `stiffness`,
//! `calibrate` and `diagnose`, each written to a folder other than its
//! input's. The legacy models' meshes exist nowhere here: `convert` keeps
//! such references by default (as OpenSim's upgrade does) and drops them
//! with `--drop-missing-meshes`, used here. OpenSim's log is captured model by model
//! (`tests/py/load_log.py`); the only line allowed is "Loaded model ...".

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

/// Run the tool; panics with its stderr on failure.
fn run(args: &[&str]) {
    let o = Command::new(common::bin()).args(args).output().unwrap();
    assert!(
        o.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// OpenSim's log lines for each model, by path.
fn opensim_logs(python: &Path, models: &[PathBuf], result: &Path) -> serde_json::Value {
    let script = common::repo_root().join("tests/py/load_log.py");
    let mut cmd = Command::new(python);
    cmd.arg(&script).arg(result).args(models);
    let o = cmd.output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_slice(&std::fs::read(result).unwrap()).unwrap()
}

/// The legacy and cyclist conversions, into `dir` (another folder).
fn converted(shared: &Path, dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let legacy = shared.join("data/models/legacy");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&legacy)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "osim"))
        .collect();
    files.sort();
    assert_eq!(files.len(), 4, "the four legacy models of ../shared/data");
    for f in files {
        let o = dir.join(f.file_name().unwrap());
        run(&["convert", s(&f), s(&o), "--drop-missing-meshes"]);
        out.push(o);
    }
    let cyclist = shared.join("data/models/cyclistFullBodyMuscle.osim");
    let geometry = shared.join("data/geometry-bodyframe");
    let o = dir.join("cyclist.osim");
    let g = s(&geometry);
    run(&[
        "convert",
        s(&cyclist),
        s(&o),
        "--geometry",
        g,
        "--drop-missing-meshes",
    ]);
    out.push(o);
    out
}

#[test]
fn every_written_model_loads_in_opensim_without_warnings() {
    let Some(shared) = common::shared_dir() else {
        return;
    };
    let Some(py) = common::opensim_python() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let t = |rel: &str| tmp.path().join(rel);
    let mut models = converted(&shared, &t("convert"));
    // base: procedural and from the cyclist model.
    run(&["base", "--procedural", "--out", s(&t("base-procedural"))]);
    let cyclist = shared.join("data/models/cyclistFullBodyMuscle.osim");
    let geometry = shared.join("data/geometry-bodyframe");
    let base_args = ["base", "--generic", s(&cyclist), "--geometry", s(&geometry)];
    run(&[&base_args[..], &["--out", s(&t("base-cyclist"))]].concat());
    models.extend([t("base-procedural/base.osim"), t("base-cyclist/base.osim")]);
    // generate, then stiffness into another folder.
    let lm = common::repo_root().join("fixtures/example-scoliosis.csv");
    let patient = t("gen/patient.osim");
    run(&["generate", "--landmarks", s(&lm), "--out", s(&patient)]);
    let table = common::repo_root().join("templates/stiffness-table4.3-ratios.toml");
    let stiff = t("elsewhere/stiff/stiff.osim");
    run(&[
        "stiffness",
        s(&patient),
        "--table",
        s(&table),
        "--out",
        s(&stiff),
    ]);
    models.extend([patient, stiff]);
    // calibrate and diagnose a dev experiment.
    let exp = shared.join("diagnose-dev/dev-09");
    run(&["calibrate", s(&exp), "--starts", "1", "--out", s(&t("cal"))]);
    run(&["diagnose", s(&exp), "--quiet", "--out", s(&t("diag"))]);
    models.extend([t("cal/calibrated.osim"), t("diag/improved.osim")]);
    // Every log line but "Loaded model" is a finding.
    let logs = opensim_logs(&py, &models, &t("logs.json"));
    let mut findings = Vec::new();
    for m in &models {
        let lines = logs[s(m)].as_array().unwrap();
        assert!(!lines.is_empty(), "{}: no log captured", m.display());
        for l in lines.iter().map(|l| l.as_str().unwrap()) {
            if !l.starts_with("[info] Loaded model") {
                findings.push(format!("{}: {l}", m.display()));
            }
        }
    }
    println!("{} models loaded in OpenSim 4.6", models.len());
    assert!(
        findings.is_empty(),
        "OpenSim said:\n{}",
        findings.join("\n")
    );
}
