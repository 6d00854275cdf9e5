//! `osim-spine diagnose` acceptance tests on the labelled development
//! experiments of `../shared/diagnose-dev/` (truth made by a richer model
//! solved in OpenSim 4.6): verdicts against the withheld labels, the held-out
//! shrink, `unidentifiable` when the separating load cases are removed, the
//! improved .osim reproducing the fitted predictions, and bad experiments.
//! The full 28-experiment benchmark is `examples/diagnose_dev.rs`.

mod common;

use osim_spine::calibrate::experiment::Experiment;
use osim_spine::diagnose::select::{diagnose, Options};
use osim_spine::diagnose::sim::Sim;
use std::path::{Path, PathBuf};

fn quiet() -> Options {
    Options {
        progress: false,
        ..Options::default()
    }
}

fn truth(dir: &Path) -> String {
    let t = std::fs::read_to_string(dir.join("truth.toml")).unwrap();
    let v: toml::Value = toml::from_str(&t).unwrap();
    v["effect"].as_str().unwrap().to_string()
}

fn dev(name: &str) -> Option<PathBuf> {
    let d = common::shared(&format!("diagnose-dev/{name}"));
    if d.is_none() {
        println!("skipped: ../shared/diagnose-dev/{name} is absent");
    }
    d
}

/// Copy an experiment keeping only the cases `keep` accepts.
fn reduced(src: &Path, dst: &Path, keep: impl Fn(&str) -> bool) {
    std::fs::create_dir_all(dst).unwrap();
    std::fs::copy(src.join("specimen.osim"), dst.join("specimen.osim")).unwrap();
    let t = std::fs::read_to_string(src.join("experiment.toml")).unwrap();
    let mut parts = t.split("[[case]]");
    let mut out = parts.next().unwrap().to_string();
    let mut ids = Vec::new();
    for c in parts {
        let id = c
            .split("id = \"")
            .nth(1)
            .unwrap()
            .split('"')
            .next()
            .unwrap()
            .to_string();
        if keep(&id) {
            out.push_str("[[case]]");
            out.push_str(c);
            ids.push(id);
        }
    }
    std::fs::write(dst.join("experiment.toml"), out).unwrap();
    let k = std::fs::read_to_string(src.join("kinematics.csv")).unwrap();
    let mut lines = k.lines();
    let mut csv = format!("{}\n", lines.next().unwrap());
    for l in lines {
        if ids.iter().any(|i| l.split(',').next() == Some(i.as_str())) {
            csv.push_str(l);
            csv.push('\n');
        }
    }
    std::fs::write(dst.join("kinematics.csv"), csv).unwrap();
}

/// The effect vocabulary of `../shared/formats/experiment.md`.
const EFFECTS: [&str; 7] = [
    "none",
    "level_dependent_stiffness",
    "nonlinear_stiffness",
    "asymmetric_stiffness",
    "coupled_stiffness",
    "joint_pose_error",
    "preload_stiffening",
];

/// Every required key of diagnosis.json, with the type and values the
/// format gives it (`experiment.md`, "diagnosis.json").
fn assert_diagnosis_schema(d: &serde_json::Value, exp: &Experiment, name: &str) {
    let v = &d["verdict"];
    let effect = v["effect"].as_str().expect("verdict.effect is a string");
    assert!(
        EFFECTS.contains(&effect) || effect == "unidentifiable",
        "{name}: verdict.effect {effect}"
    );
    let conf = v["confidence"]
        .as_f64()
        .expect("verdict.confidence is a number");
    assert!((0.0..=1.0).contains(&conf), "{name}: confidence {conf}");
    let ranked = v["ranked"].as_array().expect("verdict.ranked is a list");
    assert!(!ranked.is_empty(), "{name}: ranked is empty");
    for r in ranked {
        let e = r["effect"].as_str().expect("ranked[].effect is a string");
        assert!(EFFECTS.contains(&e), "{name}: ranked effect {e}");
        assert!(r["score"].as_f64().is_some(), "{name}: ranked score {r}");
    }
    let ids: Vec<&str> = exp.cases.iter().map(|c| c.id.as_str()).collect();
    let where_ = d["where"].as_array().expect("where is a list");
    assert!(!where_.is_empty(), "{name}: where is empty");
    for w in where_ {
        let case = w["case"].as_str().expect("where[].case is a string");
        if effect == "unidentifiable" {
            continue; // names the experiment that would separate the candidates
        }
        assert!(ids.contains(&case), "{name}: where case {case}");
        let upper = w["upper"].as_str().expect("where[].upper is a string");
        let lower = w["lower"].as_str().expect("where[].lower is a string");
        assert!(
            exp.rows
                .iter()
                .any(|r| r.upper == upper && r.lower == lower),
            "{name}: where pair {upper}/{lower} is not a measured pair"
        );
        let dof = w["dof"].as_str().expect("where[].dof is a string");
        assert!(
            osim_spine::calibrate::experiment::DOF_NAMES.contains(&dof),
            "{name}: dof {dof}"
        );
        let share = w["share"].as_f64().expect("where[].share is a number");
        assert!((0.0..=1.0).contains(&share), "{name}: share {share}");
    }
    let h = &d["heldout"];
    for c in h["cases"].as_array().expect("heldout.cases is a list") {
        let c = c.as_str().expect("heldout.cases[] are strings");
        assert!(ids.contains(&c), "{name}: held-out case {c}");
    }
    let b = h["baseline_rmse"].as_f64().expect("heldout.baseline_rmse");
    let a = h["augmented_rmse"]
        .as_f64()
        .expect("heldout.augmented_rmse");
    let shrink = h["shrink"].as_f64().expect("heldout.shrink");
    assert!(b >= 0.0 && a >= 0.0, "{name}: rmse {b} {a}");
    if b > 0.0 {
        // 1 - augmented / baseline, up to the 4-decimal rounding of the report
        assert!(
            (shrink - (1.0 - a / b)).abs() < 2e-3 * (1.0 + a / b),
            "{name}: shrink {shrink}"
        );
    }
}

#[test]
fn verdicts_match_the_withheld_labels_and_the_gap_shrinks() {
    // one `none`, one stiffness-form and one geometric effect (CI time)
    for name in ["dev-09", "dev-15", "dev-13"] {
        let Some(dir) = dev(name) else { return };
        let exp = Experiment::read(&dir).unwrap();
        let o = diagnose(&exp, &quiet()).unwrap();
        let want = truth(&dir);
        let (b, a) = o.heldout_rmse();
        println!(
            "{name}: truth {want}, verdict {} ({:.2}), held-out RMSE {b:.4} -> {a:.4} deg",
            o.verdict, o.confidence
        );
        assert_eq!(o.verdict, want, "{name}");
        let json = osim_spine::diagnose::report::diagnosis_json(&o, &exp, None);
        assert_diagnosis_schema(&json, &exp, name);
        // held-out cases never enter a fit
        for &h in &o.design.heldout {
            assert!(!o.design.train.contains(&h));
        }
        if want == "none" {
            assert_eq!(a, b, "{name}: nothing added for none");
        } else {
            assert!(1.0 - a / b > 0.5, "{name}: shrink {}", 1.0 - a / b);
            assert!(o.confidence > 0.9);
        }
    }
}

#[test]
fn single_magnitude_makes_nonlinear_truth_unidentifiable_and_names_the_cases() {
    let Some(dir) = dev("dev-16") else { return };
    assert_eq!(truth(&dir), "nonlinear_stiffness");
    let tmp = tempfile::tempdir().unwrap();
    let red = tmp.path().join("one-magnitude");
    reduced(&dir, &red, |id| {
        id.split('_').nth(2) == Some("5") && !id.contains("FL")
    });
    let out = tmp.path().join("out");
    osim_spine::diagnose::run(&red, &out, &quiet()).unwrap();
    let d: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("diagnosis.json")).unwrap())
            .unwrap();
    assert_eq!(d["verdict"]["effect"], "unidentifiable", "{}", d["verdict"]);
    assert_diagnosis_schema(&d, &Experiment::read(&red).unwrap(), "dev-16 one magnitude");
    let named: Vec<String> = d["where"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|w| w["effect"] == "nonlinear_stiffness")
        .map(|w| w["case"].as_str().unwrap().to_string())
        .collect();
    println!("named: {named:?}");
    // other magnitudes of every axis, in the experiment's id style
    for ax in ["FE", "LB", "AR"] {
        assert!(
            named
                .iter()
                .any(|c| c.starts_with(&format!("{ax}_")) && !c.ends_with("_5")),
            "{ax}: {named:?}"
        );
    }
    for f in [
        "report.md",
        "residual_map.svg",
        "curves.svg",
        "improved.osim",
    ] {
        assert!(out.join(f).exists(), "{f}");
    }
}

#[test]
fn improved_model_reproduces_the_fitted_predictions() {
    // joint pose error: the written model has moved joint frames
    let Some(dir) = dev("dev-13") else { return };
    let exp = Experiment::read(&dir).unwrap();
    let o = diagnose(&exp, &quiet()).unwrap();
    assert_eq!(o.verdict, "joint_pose_error");
    let files = osim_spine::diagnose::outputs(&exp, &o).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let copy = tmp.path().join("improved");
    reduced(&dir, &copy, |_| true);
    let model = files.iter().find(|(n, _)| n == "improved.osim").unwrap();
    std::fs::write(copy.join("specimen.osim"), &model.1).unwrap();
    let exp2 = Experiment::read(&copy).unwrap();
    let sys2 = osim_spine::solver::System::new(&exp2.spec).unwrap();
    let sim = Sim::new(&exp).unwrap();
    let all: Vec<usize> = (0..exp.cases.len()).collect();
    let pred = sim.predict(&sys2, &all, &mut sim.warm()).unwrap();
    let fitted = &o.augmented().pred;
    let mut worst: f64 = 0.0;
    for (p, q) in pred.iter().zip(fitted) {
        for d in 0..6 {
            worst = worst.max((p[d] - q[d]).abs());
        }
    }
    println!("largest difference written vs fitted: {worst:.2e} (deg or mm)");
    assert!(worst < 1e-6, "{worst}");
}

#[test]
fn bad_experiments_are_clear_errors_and_write_nothing() {
    let Some(dir) = dev("dev-09") else { return };
    let tmp = tempfile::tempdir().unwrap();
    // a kinematics row naming a pair that is not a level
    let bad = tmp.path().join("bad-pair");
    reduced(&dir, &bad, |_| true);
    let k = std::fs::read_to_string(bad.join("kinematics.csv")).unwrap();
    std::fs::write(
        bad.join("kinematics.csv"),
        k.replacen("lumbar4,lumbar5", "lumbar2,lumbar5", 1),
    )
    .unwrap();
    let out = tmp.path().join("out");
    let e = osim_spine::diagnose::run(&bad, &out, &quiet())
        .unwrap_err()
        .to_string();
    println!("{e}");
    assert!(
        e.contains("kinematics.csv") && e.contains("lumbar2") && e.contains("line 3"),
        "{e}"
    );
    assert!(!out.join("diagnosis.json").exists());
    // a case on a body the model lacks
    let bad2 = tmp.path().join("bad-body");
    reduced(&dir, &bad2, |_| true);
    let t = std::fs::read_to_string(bad2.join("experiment.toml")).unwrap();
    std::fs::write(
        bad2.join("experiment.toml"),
        t.replacen("body = \"lumbar1\"", "body = \"lumbar9\"", 1),
    )
    .unwrap();
    let e = osim_spine::diagnose::run(&bad2, &out, &quiet())
        .unwrap_err()
        .to_string();
    println!("{e}");
    assert!(e.contains("lumbar9"), "{e}");
    assert!(!out.join("diagnosis.json").exists());
    // the CLI exits non-zero
    let st = std::process::Command::new(env!("CARGO_BIN_EXE_osim-spine"))
        .args([
            "diagnose",
            bad2.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--quiet",
        ])
        .output()
        .unwrap();
    assert!(!st.status.success());
    assert!(!out.join("diagnosis.json").exists());
}
