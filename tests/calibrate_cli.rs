//! `osim-spine calibrate` end to end, and acceptance 4 of the calibration
//! issue: bad experiments (unknown bodies, inconsistent units, parameters
//! that affect no measured DoF, a case that cannot reach equilibrium, ...)
//! are reported clearly, with a non-zero exit and no output; poorly
//! determined parameters are named.

mod common;

use osim_spine::calibrate::experiment::Experiment;
use osim_spine::calibrate::fit::{self, FitOptions};
use osim_spine::calibrate::setup::{build_problem, Setup};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::Arc;

fn calibrate(exp: &Path, out: &Path, extra: &[&str]) -> Output {
    Command::new(common::bin())
        .arg("calibrate")
        .arg(exp)
        .arg("--out")
        .arg(out)
        .args(extra)
        .output()
        .unwrap()
}

/// A writable copy of a dev experiment (rotations only, 5 levels).
fn copy_dev(name: &str) -> Option<(tempfile::TempDir, PathBuf)> {
    let src = common::shared(&format!("diagnose-dev/{name}"))?;
    let tmp = tempfile::tempdir().unwrap();
    let dst = tmp.path().join(name);
    std::fs::create_dir_all(&dst).unwrap();
    for f in ["experiment.toml", "kinematics.csv", "specimen.osim"] {
        std::fs::copy(src.join(f), dst.join(f)).unwrap();
    }
    Some((tmp, dst))
}

fn edit(path: &Path, from: &str, to: &str, count: usize) {
    let s = std::fs::read_to_string(path).unwrap();
    assert!(s.contains(from), "{from} not in {}", path.display());
    std::fs::write(path, s.replacen(from, to, count)).unwrap();
}

fn assert_fails(o: &Output, out: &Path, needles: &[&str]) {
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "expected failure, stderr:\n{err}");
    for n in needles {
        assert!(err.contains(n), "stderr lacks '{n}':\n{err}");
    }
    assert!(!out.exists(), "output written despite the error");
}

#[test]
fn calibrates_writes_outputs_and_is_deterministic() {
    let Some(dir) = common::shared("diagnose-dev/dev-09") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = (tmp.path().join("a"), tmp.path().join("b"));
    let o = calibrate(&dir, &a, &["--starts", "3", "--loco", "--jobs", "1"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    // --loco prints its held-out errors
    assert!(
        err.contains("leave-one-case-out (24 cases held out in turn): held-out rotation RMSE"),
        "{err}"
    );
    let o2 = calibrate(&dir, &b, &["--starts", "3", "--loco", "--jobs", "2"]);
    assert!(o2.status.success());
    for f in ["report.json", "calibrated.osim", "fit.svg", "params.svg"] {
        let x = std::fs::read(a.join(f)).unwrap();
        assert_eq!(
            x,
            std::fs::read(b.join(f)).unwrap(),
            "{f} differs between runs"
        );
    }
    let r: serde_json::Value =
        serde_json::from_slice(&std::fs::read(a.join("report.json")).unwrap()).unwrap();
    let rmse = r["fit"]["rotation_rmse"].as_f64().unwrap();
    let nominal = r["nominal_fit"]["rotation_rmse"].as_f64().unwrap();
    println!("rotation RMSE {rmse:.4} deg (nominal model {nominal:.4} deg)");
    assert!(rmse < 0.12 && nominal > 5.0 * rmse);
    let loco = &r["validation"]["leave_one_case_out"];
    assert_eq!(loco["cases"].as_array().unwrap().len(), 24);
    for e in loco["errors"]["entries"].as_array().unwrap() {
        // held-out predictions of a `none` case stay near the noise level
        assert!(e["rmse_in_unit"].as_f64().unwrap() < 0.15, "{e}");
    }
    assert_eq!(r["calibration"]["estimates"].as_array().unwrap().len(), 3);
    assert!(std::fs::read_to_string(a.join("fit.svg"))
        .unwrap()
        .contains("lumbar4/lumbar5 rz"));
    // the calibrated model is valid for OpenSim and carries the values
    if let Some(py) = common::opensim_python() {
        let model = a.join("calibrated.osim");
        let k = common::run_py(&py, "bushing_stiffness.py", &[model.to_str().unwrap()]);
        let best: Vec<f64> = r["calibration"]["best"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        for (name, vals) in k.as_object().unwrap() {
            for d in 0..3 {
                let v = vals[d].as_f64().unwrap();
                assert!(
                    (v / best[d] - 1.0).abs() < 1e-12,
                    "{name}: {v} vs {}",
                    best[d]
                );
            }
        }
    }
}

#[test]
fn bad_experiments_are_reported_without_output() {
    let Some((tmp, dir)) = copy_dev("dev-09") else {
        return;
    };
    let out = tmp.path().join("out");
    let toml = dir.join("experiment.toml");
    let csv = dir.join("kinematics.csv");
    let original_toml = std::fs::read_to_string(&toml).unwrap();
    let original_csv = std::fs::read_to_string(&csv).unwrap();
    let reset = || {
        std::fs::write(&toml, &original_toml).unwrap();
        std::fs::write(&csv, &original_csv).unwrap();
    };

    edit(&toml, "body = \"lumbar1\"", "body = \"lumbar9\"", 1);
    assert_fails(
        &calibrate(&dir, &out, &[]),
        &out,
        &["experiment.toml", "[[case]] #1", "unknown body 'lumbar9'"],
    );
    reset();

    edit(
        &csv,
        "FE_neg_1,lumbar5,sacrum",
        "FE_neg_1,lumbar5x,sacrum",
        1,
    );
    assert_fails(
        &calibrate(&dir, &out, &[]),
        &out,
        &["kinematics.csv", "line 2", "unknown body 'lumbar5x'"],
    );
    reset();

    edit(
        &csv,
        "FE_neg_1,lumbar4,lumbar5",
        "FE_neg_1,lumbar4,sacrum",
        1,
    );
    assert_fails(
        &calibrate(&dir, &out, &[]),
        &out,
        &["kinematics.csv", "not an adjacent pair"],
    );
    reset();

    edit(&toml, "angle = \"deg\"", "angle = \"rad\"", 1);
    assert_fails(
        &calibrate(&dir, &out, &[]),
        &out,
        &["kinematics.csv", "inconsistent units", "look like deg"],
    );
    reset();

    edit(&toml, "angle = \"deg\"", "angle = \"degrees\"", 1);
    assert_fails(
        &calibrate(&dir, &out, &[]),
        &out,
        &["[units] angle", "\"deg\" or \"rad\""],
    );
    reset();

    edit(&csv, "FE_neg_1,lumbar5", "nope,lumbar5", 1);
    assert_fails(
        &calibrate(&dir, &out, &[]),
        &out,
        &["line 2", "case 'nope' is not a [[case]]"],
    );
    reset();

    // dev-09 measured rotations only: translational stiffness moves nothing measured
    assert_fails(
        &calibrate(&dir, &out, &["--translations"]),
        &out,
        &["parameter(s) tx, ty, tz affect no measured DoF"],
    );
    assert_fails(
        &calibrate(&dir, &out, &["--dofs", "rx,tx"]),
        &out,
        &["DoF tx is selected", "no measured value"],
    );

    // a level without measurements: its per-level parameters are named
    let kept: String = original_csv
        .lines()
        .filter(|l| !l.contains(",lumbar1,lumbar2,"))
        .map(|l| format!("{l}\n"))
        .collect();
    std::fs::write(&csv, kept).unwrap();
    assert_fails(
        &calibrate(&dir, &out, &["--params", "per-level"]),
        &out,
        &["L1_L2.rx, L1_L2.ry, L1_L2.rz affect no measured DoF"],
    );
    reset();

    // a case that cannot reach equilibrium
    edit(
        &toml,
        "moment = [0.0, 0.0, -7.5]",
        "moment = [0.0, 0.0, -7500.0]",
        1,
    );
    assert_fails(
        &calibrate(&dir, &out, &[]),
        &out,
        &["case 'FE_neg_7.5'", "cannot be solved"],
    );
    reset();

    assert_fails(
        &calibrate(&dir, &out, &["--params", "ratio:/no/such.toml"]),
        &out,
        &["/no/such.toml"],
    );
    assert_fails(
        &calibrate(&dir, &out, &["--weights", "rx=-1"]),
        &out,
        &["--weights"],
    );
    assert_fails(
        &calibrate(&dir, &out, &["--dofs", "rq"]),
        &out,
        &["unknown DoF 'rq'"],
    );
    // sanity: the restored copy calibrates
    let o = calibrate(&dir, &out, &["--starts", "1"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

#[test]
fn parameters_the_data_cannot_determine_are_named() {
    let Some(dir) = common::shared("diagnose-dev/dev-09") else {
        return;
    };
    // flexion-extension cases only: lateral bending and axial rotation
    // stiffness move nothing measured -> an error naming them
    let exp = Experiment::read(&dir).unwrap();
    let fe = exp.subset(|i| exp.cases[i].id.starts_with("FE"));
    let e = build_problem(Arc::new(fe), &Setup::default())
        .and_then(|(pb, _)| fit::calibrate(&pb, &FitOptions::default()))
        .unwrap_err()
        .to_string();
    assert!(e.contains("rx, ry affect no measured DoF"), "{e}");
    // plus one lateral-bending and one axial-rotation case at 2% of 1 N*m
    // (measurements scaled alike): rx and ry are barely constrained
    let keep = |i: usize| {
        let id = &exp.cases[i].id;
        id.starts_with("FE") || id == "LB_pos_1" || id == "AR_pos_1"
    };
    let mut weak = exp.subset(keep);
    let small: Vec<usize> = (0..weak.cases.len())
        .filter(|&i| !weak.cases[i].id.starts_with("FE"))
        .collect();
    for &i in &small {
        for m in weak.cases[i].moment.iter_mut() {
            *m *= 0.02;
        }
    }
    for r in weak.rows.iter_mut().filter(|r| small.contains(&r.case)) {
        for v in r.values.iter_mut().flatten() {
            *v *= 0.02;
        }
    }
    let (pb, _) = build_problem(Arc::new(weak), &Setup::default()).unwrap();
    let cal = fit::calibrate(
        &pb,
        &FitOptions {
            starts: 2,
            ..FitOptions::default()
        },
    )
    .unwrap();
    let named: Vec<&str> = cal
        .identifiability
        .poorly_determined
        .iter()
        .map(|p| p.name.as_str())
        .collect();
    println!(
        "weak LB/AR: poorly determined {named:?}; rel SD {:?}; condition number {:.1}",
        cal.estimates.iter().map(|e| e.rel_sd).collect::<Vec<_>>(),
        cal.identifiability.condition_number
    );
    assert!(named.contains(&"rx") && named.contains(&"ry"), "{named:?}");
    assert!(!named.contains(&"rz"), "{named:?}");
}

#[test]
fn leave_one_specimen_out_over_two_none_specimens() {
    let (Some(a), Some(b)) = (
        common::shared("diagnose-dev/dev-09"),
        common::shared("diagnose-dev/dev-25"),
    ) else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("o");
    let o = calibrate(&a, &out, &["--starts", "2", "--loso", b.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let r: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    let loso = r["validation"]["leave_one_specimen_out"]
        .as_array()
        .unwrap();
    assert_eq!(loso.len(), 2);
    // with two specimens the "median of the others" is the other one's calibration
    let own: Vec<f64> = r["calibration"]["best"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    let other: Vec<f64> = r["validation"]["specimens"][0]["calibrated"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert_eq!(
        loso[0]["params"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect::<Vec<_>>(),
        other
    );
    assert_eq!(
        loso[1]["params"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect::<Vec<_>>(),
        own
    );
    // dev-09 and dev-25 differ (FE x0.57 vs x0.56, LB x1.17 vs x0.65): the
    // other specimen's stiffness predicts lateral bending clearly worse
    let rx_err = |k: usize| -> f64 {
        loso[k]["errors"]["entries"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|e| e["dof"] == "rx")
            .map(|e| e["rmse_in_unit"].as_f64().unwrap())
            .fold(0.0, f64::max)
    };
    println!(
        "held-out rx RMSE (deg): dev-09 {:.3}, dev-25 {:.3}",
        rx_err(0),
        rx_err(1)
    );
    assert!(rx_err(0) > 0.3 && rx_err(1) > 0.3);
}

#[test]
fn sensitivity_cli_reports_spread_and_two_factor_shares() {
    let Some(dir) = common::shared("diagnose-dev/dev-09") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("s");
    let run = |sd: &str, out: &Path| {
        Command::new(common::bin())
            .args([
                "sensitivity",
                dir.to_str().unwrap(),
                "--samples",
                "12",
                "--landmark-sd",
                sd,
                "--out",
            ])
            .arg(out)
            .output()
            .unwrap()
    };
    let o = run("1.0", &out);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let r: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("sensitivity.json")).unwrap()).unwrap();
    assert_eq!(r["samples"], 12);
    let t = &r["two_factor"];
    let shares: f64 = ["share_pose", "share_stiffness", "share_interaction"]
        .iter()
        .map(|k| t[k].as_f64().unwrap())
        .sum();
    assert!((shares - 1.0).abs() < 1e-9);
    for p in r["params"].as_array().unwrap() {
        assert!(p["p2_5"].as_f64().unwrap() <= p["median"].as_f64().unwrap());
        assert!(p["median"].as_f64().unwrap() <= p["p97_5"].as_f64().unwrap());
    }
    // no landmark noise: every sample is the reference model
    let out0 = tmp.path().join("s0");
    assert!(run("0", &out0).status.success());
    let r0: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out0.join("sensitivity.json")).unwrap()).unwrap();
    for p in r0["params"].as_array().unwrap() {
        let (lo, hi, reference) = (
            p["min"].as_f64().unwrap(),
            p["max"].as_f64().unwrap(),
            p["reference"].as_f64().unwrap(),
        );
        assert!(
            (lo / reference - 1.0).abs() < 1e-6 && (hi / reference - 1.0).abs() < 1e-6,
            "{p}"
        );
    }
    let bad = run("-1", &tmp.path().join("bad"));
    assert!(!bad.status.success() && !tmp.path().join("bad").exists());
}
