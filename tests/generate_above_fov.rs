//! Levels above the landmarks' field of view (`--above-fov`): on the
//! README example (T9-S1), `balance` levels T1 and brings its centre
//! within 20 mm of the vertical through S1_SEC (acceptance: 30 mm);
//! `keep` leaves T1 where the base joints put it (far to the right).

use osim_spine::embedded::BaseModel;
use osim_spine::generate::{generate, AboveFov, GenerateOptions};
use osim_spine::landmarks::{Code, Level};

/// (T1 centre minus the vertical through S1_SEC along the right axis in mm,
/// the report) for one mode; the centre comes from the written model.
fn t1_lateral_mm(mode: AboveFov) -> (f64, osim_spine::generate::GenerateReport) {
    let file = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/fixtures/example-scoliosis.csv"
    );
    let set = osim_spine::landmarks::read_path(std::path::Path::new(file))
        .unwrap()
        .to_set()
        .unwrap();
    let base = BaseModel::Embedded.read().unwrap();
    let opts = GenerateOptions {
        self_check: false,
        views: false,
        above_fov: mode,
        ..GenerateOptions::default()
    };
    let g = generate(&base, &set, file, &opts, None).unwrap();
    // S1_SEC in the model's ground through the sacral registration.
    let s1 = g.report.registration.isometry() * set.get(Level::S1, Code::SEC).unwrap();
    // T1's centre recomputed from the generated model itself.
    let model = g.doc.model().unwrap();
    let kin = osim_spine::base::kin::Kinematics::new(&model).unwrap();
    let poses = kin.body_poses(&kin.default_values()).unwrap();
    let centres = osim_spine::evaluate::model_centres(&model, &poses, Default::default()).unwrap();
    let t1 = centres[&Level::T1];
    ((t1.z - s1.z) * 1e3, g.report)
}

#[test]
fn balance_puts_t1_over_the_sacrum_and_keep_does_not() {
    let (bal, rep) = t1_lateral_mm(AboveFov::Balance);
    assert!(
        bal.abs() < 30.0,
        "balanced T1 is {bal:.1} mm lateral of S1_SEC"
    );
    let a = rep.above_fov.expect("T8-T1 are above the field of view");
    let expect = [
        Level::T8,
        Level::T7,
        Level::T6,
        Level::T5,
        Level::T4,
        Level::T3,
        Level::T2,
        Level::T1,
    ];
    assert_eq!(a.unmeasured, expect);
    assert_eq!(a.balanced, expect);
    // No joint bends past the limit; T1 is level unless the limit was hit.
    let cap = osim_spine::generate::balance::MAX_BEND_DEG;
    assert!(a.bend_deg.iter().all(|b| b.abs() <= cap + 1e-9), "{a:?}");
    assert!(a.bend_limited || a.t1_coronal_tilt_deg.abs() < 0.5, "{a:?}");
    // The least compensation: an even bend when that leaves T1 within the
    // coronal-balance range, otherwise T1 at the edge of that range.
    let tol = osim_spine::generate::balance::CORONAL_BALANCE_MM;
    let even = a.bend_deg.iter().all(|b| (b - a.bend_deg[0]).abs() < 1e-9);
    assert!(
        a.bend_limited || (even && bal.abs() <= tol + 0.5) || (bal.abs() - tol).abs() < 0.5,
        "T1 {bal:.1} mm lateral, bends {:?}",
        a.bend_deg
    );
    let (keep, rep) = t1_lateral_mm(AboveFov::Keep);
    assert!(keep.abs() > 60.0, "kept T1 is {keep:.1} mm lateral");
    let a = rep.above_fov.unwrap();
    assert!(a.balanced.is_empty());
    assert!(
        (a.t1_lateral_offset_mm - keep).abs() < 5.0,
        "{a:?} vs {keep}"
    );
}

/// `evaluate --model A B` (one flag, two models): the truth's Cobb angle
/// and lordosis come from the truth alone (identical for both models), the
/// models' over the truth's levels (T9-S1: the balanced curve above is not
/// compared), and the JSON states its conventions.
#[test]
fn evaluate_truth_metrics_come_from_the_truth_alone() {
    let root = env!("CARGO_MANIFEST_DIR");
    let bin = env!("CARGO_BIN_EXE_osim-spine");
    let d = tempfile::tempdir().unwrap();
    let run = |args: &[&str]| {
        let o = std::process::Command::new(bin)
            .current_dir(root)
            .args(args)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    };
    let (a, b) = (d.path().join("a/p.osim"), d.path().join("b/p.osim"));
    for (m, mode) in [(&a, "balance"), (&b, "keep")] {
        let out = m.to_str().unwrap();
        let lm = "fixtures/example-scoliosis.csv";
        run(&[
            "generate",
            "--landmarks",
            lm,
            "--out",
            out,
            "--above-fov",
            mode,
            "--no-self-check",
        ]);
    }
    let ev = d.path().join("ev");
    run(&[
        "evaluate",
        "--model",
        a.to_str().unwrap(),
        b.to_str().unwrap(),
        "--truth",
        "fixtures/example-scoliosis-centres.csv",
        "--truth-landmarks",
        "fixtures/example-scoliosis.csv",
        "--out",
        ev.to_str().unwrap(),
    ]);
    let r: serde_json::Value =
        serde_json::from_slice(&std::fs::read(ev.join("evaluation.json")).unwrap()).unwrap();
    let ms = r["models"].as_array().unwrap();
    assert_eq!(ms.len(), 2);
    assert_eq!(ms[0]["truth_cobb"], ms[1]["truth_cobb"]);
    assert_eq!(ms[0]["truth_lordosis_deg"], ms[1]["truth_lordosis_deg"]);
    for m in ms {
        let err = m["cobb_error_deg"].as_f64().unwrap();
        assert!(err.abs() < 5.0, "Cobb error {err} deg");
    }
    assert!(r["conventions"]["lordosis"]
        .as_str()
        .unwrap()
        .contains("L1"));
    assert!(r["conventions"]["cobb"]
        .as_str()
        .unwrap()
        .contains("positive"));
}
