//! `generate` and `evaluate` on the embedded default base model
//! (`base_model/`): the README's example patient (fixtures regenerated
//! byte for byte, the main job end to end, the model in OpenSim), bad
//! inputs (acceptance 4: clear errors, non-zero exit, nothing written) and
//! `evaluate` on analytic spines.

mod common;

use nalgebra::{Point3, Rotation3, Vector3};
use osim_spine::evaluate::{evaluate_model, metrics, Align, ModelShape, Truth};
use osim_spine::generate::example::example_scoliosis;
use osim_spine::landmarks::{Code, LandmarkSet, Level};
use osim_spine::osim::Document;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    common::repo_root()
}

fn run(args: &[&str]) -> std::process::Output {
    Command::new(common::bin())
        .current_dir(root())
        .args(args)
        .output()
        .unwrap()
}

#[test]
fn example_fixtures_are_regenerated_byte_for_byte() {
    let base = Document::read(root().join("base_model/base.osim")).unwrap();
    let ex = example_scoliosis(&base).unwrap();
    let lm = std::fs::read_to_string(root().join("fixtures/example-scoliosis.csv")).unwrap();
    let ct =
        std::fs::read_to_string(root().join("fixtures/example-scoliosis-centres.csv")).unwrap();
    assert!(
        ex.landmarks_csv == lm,
        "fixtures/example-scoliosis.csv is stale: cargo run --example example_scoliosis"
    );
    assert!(
        ex.centres_csv == ct,
        "fixtures/example-scoliosis-centres.csv is stale"
    );
}

/// The README's main job: generate (default base, default method) then
/// evaluate against the truth centres; the planted outlier is flagged;
/// the model passes OpenSim's checks.
#[test]
fn example_patient_main_job() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out/patient.osim");
    let o = run(&[
        "generate",
        "--landmarks",
        "fixtures/example-scoliosis.csv",
        "--out",
        out.to_str().unwrap(),
    ]);
    let stdout = String::from_utf8_lossy(&o.stdout).to_string();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    println!("{stdout}");
    assert!(
        stdout.contains("L3_PTL"),
        "the planted outlier is not reported:\n{stdout}"
    );
    assert!(stdout.contains("detected mm") && stdout.contains("detected LPS"));
    for f in [
        "patient_report.json",
        "patient_frontal.svg",
        "patient_sagittal.svg",
        "Geometry/proc_L3.vtp",
    ] {
        assert!(tmp.path().join("out").join(f).is_file(), "{f} not written");
    }
    // The base's femoral head markers ride on the (welded) pelvis into the
    // patient model unchanged: bending films are placed on them.
    let marker = |doc: &Document, name: &str| {
        let m = doc.model().unwrap();
        let mk = m.markers.iter().find(|mk| mk.name == name).cloned();
        mk.map(|mk| (m.marker_frame(&mk).unwrap().0, mk.location))
    };
    let base = Document::read(root().join("base_model/base.osim")).unwrap();
    let patient = Document::read(&out).unwrap();
    for name in ["FH_R", "FH_L"] {
        let b = marker(&base, name).unwrap_or_else(|| panic!("base lacks {name}"));
        assert_eq!(b.0, "pelvis");
        assert_eq!(marker(&patient, name), Some(b), "{name}");
    }
    let ev = tmp.path().join("eval");
    let o = run(&[
        "evaluate",
        "--model",
        out.to_str().unwrap(),
        "--truth",
        "fixtures/example-scoliosis-centres.csv",
        "--truth-landmarks",
        "fixtures/example-scoliosis.csv",
        "--out",
        ev.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    println!("{}", String::from_utf8_lossy(&o.stdout));
    let r: serde_json::Value =
        serde_json::from_slice(&std::fs::read(ev.join("evaluation.json")).unwrap()).unwrap();
    let m = &r["models"][0];
    let rmse = m["centre_rmse_mm"].as_f64().unwrap();
    assert!(
        rmse < 1.5,
        "centre RMSE {rmse} mm with 1 mm palpation noise"
    );
    let cobb_err = m["cobb_error_deg"].as_f64().unwrap();
    assert!(cobb_err.abs() < 5.0, "Cobb error {cobb_err}");
    assert_eq!(m["levels"].as_array().unwrap().len(), 9);
    for f in [
        "centres_frontal.svg",
        "centres_sagittal.svg",
        "curves_frontal.svg",
        "curves_sagittal.svg",
    ] {
        let svg = std::fs::read_to_string(ev.join(f)).unwrap();
        assert!(svg.contains("<svg") && svg.contains("circle"), "{f}");
    }
    // Same inputs, byte-identical outputs.
    let out2 = tmp.path().join("out2/patient.osim");
    let o = run(&[
        "generate",
        "--landmarks",
        "fixtures/example-scoliosis.csv",
        "--out",
        out2.to_str().unwrap(),
    ]);
    assert!(o.status.success());
    for f in ["patient.osim", "patient_report.json", "patient_frontal.svg"] {
        let a = std::fs::read(tmp.path().join("out").join(f)).unwrap();
        let b = std::fs::read(tmp.path().join("out2").join(f)).unwrap();
        if f == "patient_report.json" {
            // The report names the output's folder only through the landmarks path; compare as text.
            assert_eq!(String::from_utf8_lossy(&a), String::from_utf8_lossy(&b));
        } else {
            assert_eq!(a, b, "{f} differs between two runs");
        }
    }
    // OpenSim: loads, zero bushing force at the default pose, wrap checks.
    let Some(py) = common::opensim_python() else {
        return;
    };
    let r = common::run_py(&py, "base_check.py", &[out.to_str().unwrap(), "10", "5"]);
    assert_eq!(r["bushings"], 17);
    let bmax = r["bushing_max_record_at_default"].as_f64().unwrap();
    assert!(bmax < 1e-6, "bushing record at the default pose {bmax}");
    for row in r["scoliotic"].as_array().unwrap() {
        let name = row["muscle"].as_str().unwrap();
        let (len, straight) = (
            row["length"].as_f64().unwrap(),
            row["straight"].as_f64().unwrap(),
        );
        assert!(
            len >= straight - 1e-9,
            "{name}: path {len} shorter than straight {straight}"
        );
        assert!(
            row["min_clearance"].as_f64().unwrap() > 0.0,
            "{name}: path point inside its sphere"
        );
        if row["crosses_wrapped_sphere"].as_bool().unwrap() {
            assert!(
                row["wrap_points"].as_u64().unwrap() > 0,
                "{name}: crosses but does not wrap"
            );
        }
    }
    println!("OpenSim: bushing records at the default pose <= {bmax:.1e}");
}

// ------------------------------------------------------------ bad inputs

fn example_lines() -> Vec<String> {
    std::fs::read_to_string(root().join("fixtures/example-scoliosis.csv"))
        .unwrap()
        .lines()
        .map(String::from)
        .collect()
}

/// `generate` on the landmark file `name`, written from `text` into
/// `dir`, to `out`.
fn generate_file(dir: &Path, name: &str, text: &str, out: &Path) -> std::process::Output {
    let lm = dir.join(name);
    std::fs::write(&lm, text).unwrap();
    run(&[
        "generate",
        "--landmarks",
        lm.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ])
}

fn refused(name: &str, text: &str, needles: &[&str]) {
    let tmp = tempfile::tempdir().unwrap();
    let out_dir = tmp.path().join("out");
    let o = generate_file(tmp.path(), name, text, &out_dir.join("p.osim"));
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    assert!(!o.status.success(), "{name}: accepted");
    assert_eq!(o.status.code(), Some(1), "{name}: exit code");
    for n in needles {
        assert!(
            err.contains(n),
            "{name}: the error does not say `{n}`:\n{err}"
        );
    }
    assert!(!err.contains("panicked"), "{name}: panic\n{err}");
    assert!(
        !out_dir.exists(),
        "{name}: output written despite the error"
    );
}

fn without(lines: &[String], pred: &dyn Fn(&str) -> bool) -> String {
    lines
        .iter()
        .filter(|l| !pred(l))
        .cloned()
        .collect::<Vec<_>>()
        .join("\n")
        + "\n"
}

type Rename<'a> = dyn Fn(&str, [f64; 3]) -> (String, [f64; 3]) + 'a;

fn map_points(lines: &[String], f: &Rename<'_>) -> String {
    let mut s = String::new();
    for l in lines {
        let parts: Vec<&str> = l.split(',').collect();
        if l.starts_with('#') || l.starts_with("name") || parts.len() != 4 {
            s.push_str(l);
        } else {
            let v = [
                parts[1].parse().unwrap(),
                parts[2].parse().unwrap(),
                parts[3].parse().unwrap(),
            ];
            let (n, w) = f(parts[0], v);
            s.push_str(&format!("{n},{},{},{}", w[0], w[1], w[2]));
        }
        s.push('\n');
    }
    s
}

#[test]
fn bad_landmark_sets_are_refused_without_output() {
    let lines = example_lines();
    // Too few landmarks at a level to fit it: named.
    refused(
        "sparse.csv",
        &without(&lines, &|l| {
            [
                "L2_IEC,", "L2_SEC,", "L2_SA,", "L2_SP,", "L2_IA,", "L2_IP,", "L2_SR,",
            ]
            .iter()
            .any(|p| l.starts_with(p))
        }),
        &["L2", "a fit needs at least 8"],
    );
    // Duplicate names.
    let dup = lines
        .iter()
        .find(|l| l.starts_with("L4_SA,"))
        .unwrap()
        .clone();
    let mut d = lines.clone();
    d.push(dup);
    refused(
        "duplicate.csv",
        &(d.join("\n") + "\n"),
        &["duplicate", "L4_SA"],
    );
    // Left and right swapped (every R/L pair renamed), detected from the anatomy.
    let swapped = map_points(&lines, &|n, v| {
        let m = if let Some(x) = n.strip_suffix('R') {
            format!("{x}L")
        } else if let Some(x) = n.strip_suffix('L') {
            format!("{x}R")
        } else {
            n.to_string()
        };
        (m, v)
    });
    refused("swapped.csv", &swapped, &["LM0"]);
    // A set in metres declared as millimetres.
    let metres = map_points(&lines, &|n, v| {
        (n.to_string(), [v[0] / 1000.0, v[1] / 1000.0, v[2] / 1000.0])
    });
    refused("metres.csv", &metres, &["LM002", "declared units `mm`"]);
    // NaN.
    let nan = lines
        .iter()
        .map(|l| {
            if l.starts_with("L1_SA,") {
                "L1_SA,NaN,1,2".to_string()
            } else {
                l.clone()
            }
        })
        .collect::<Vec<_>>()
        .join("\n")
        + "\n";
    refused("nan.csv", &nan, &["line", "finite number"]);
    // Coincident landmarks: every L1 landmark at one point.
    let c = map_points(&lines, &|n, v| {
        if n.starts_with("L1_") {
            (n.to_string(), [10.0, 250.0, -760.0])
        } else {
            (n.to_string(), v)
        }
    });
    refused("coincident.csv", &c, &["L1"]);
    // Collinear landmarks: the L1 landmarks on one line.
    let k = std::cell::Cell::new(0.0);
    let col = map_points(&lines, &|n, v| {
        if n.starts_with("L1_") {
            k.set(k.get() + 1.0);
            (n.to_string(), [10.0, 250.0, -770.0 + 2.0 * k.get()])
        } else {
            (n.to_string(), v)
        }
    });
    refused("collinear.csv", &col, &["L1"]);
}

/// The generator's own guards, below the checker: collinear and
/// coincident landmarks of one vertebra (checked in the library).
#[test]
fn generator_refuses_degenerate_vertebrae_itself() {
    let base = Document::read(root().join("base_model/base.osim")).unwrap();
    let set =
        osim_spine::landmarks::io::load(&root().join("fixtures/example-scoliosis.csv")).unwrap();
    let opts = osim_spine::generate::GenerateOptions::default();
    let mut line = set.clone();
    for (i, c) in Code::ALL.iter().enumerate() {
        line.insert(Level::L2, *c, Point3::new(0.0, 0.1 + 0.002 * i as f64, 0.0));
    }
    let e = osim_spine::generate::generate(&base, &line, "t.csv", &opts, None).unwrap_err();
    assert!(
        e.to_string().contains("L2") && e.to_string().contains("collinear"),
        "{e}"
    );
    let mut same = set.clone();
    for c in Code::ALL {
        same.insert(Level::L2, c, Point3::new(0.0, 0.1, 0.0));
    }
    let e = osim_spine::generate::generate(&base, &same, "t.csv", &opts, None).unwrap_err();
    assert!(e.to_string().contains("L2"), "{e}");
}

#[test]
fn evaluate_refuses_bad_truth() {
    let tmp = tempfile::tempdir().unwrap();
    let t = tmp.path().join("c.csv");
    std::fs::write(&t, "level,x,y,z\nL1,1,2,3\n").unwrap();
    let out = tmp.path().join("ev");
    let o = run(&[
        "evaluate",
        "--model",
        "base_model/base.osim",
        "--truth",
        t.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("units"));
    assert!(!out.exists());
    std::fs::write(&t, "# units: mm\n# frame: LPS\nlevel,x,y,z\nL1,1,NaN,3\n").unwrap();
    let o = run(&[
        "evaluate",
        "--model",
        "base_model/base.osim",
        "--truth",
        t.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("line 4"));
    assert!(!out.exists());
}

// ------------------------------------------------------- analytic spines

/// Landmarks of a box vertebra (depth 34, height 24, width 44 mm) with its
/// centre at `c` and orientation `r`.
fn put_vertebra(set: &mut LandmarkSet, level: Level, c: Point3<f64>, r: &Rotation3<f64>) {
    let local = [
        (Code::SEC, [0.0, 12.0, 0.0]),
        (Code::IEC, [0.0, -12.0, 0.0]),
        (Code::PTR, [-20.0, 8.0, 12.0]),
        (Code::PBR, [-20.0, -4.0, 12.0]),
        (Code::PTL, [-20.0, 8.0, -12.0]),
        (Code::PBL, [-20.0, -4.0, -12.0]),
        (Code::SA, [17.0, 12.0, 0.0]),
        (Code::SP, [-17.0, 12.0, 0.0]),
        (Code::SR, [0.0, 12.0, 22.0]),
        (Code::SL, [0.0, 12.0, -22.0]),
        (Code::IA, [17.0, -12.0, 0.0]),
        (Code::IP, [-17.0, -12.0, 0.0]),
        (Code::IR, [0.0, -12.0, 22.0]),
        (Code::IL, [0.0, -12.0, -22.0]),
    ];
    for (code, p) in local {
        if level.is_sacrum() && !Code::SACRUM_REQUIRED.contains(&code) {
            continue;
        }
        set.insert(level, code, c + r * (Vector3::from(p) * 1e-3));
    }
}

fn centres_of(set: &LandmarkSet) -> BTreeMap<Level, Point3<f64>> {
    set.levels()
        .into_iter()
        .filter(|l| !l.is_sacrum())
        .map(|l| {
            (
                l,
                nalgebra::center(
                    &set.get(l, Code::SEC).unwrap(),
                    &set.get(l, Code::IEC).unwrap(),
                ),
            )
        })
        .collect()
}

/// A planar arc in the frontal plane: T11..L4 on a circle, each vertebra
/// perpendicular to the arc; straight spine above and below. The Cobb
/// angle is the arc's angle, the apex its middle vertebra.
#[test]
fn planar_arc_has_its_cobb_angle_and_apex() {
    let arc_deg = 48.0;
    let levels: Vec<Level> = Level::ALL[Level::T11.index()..=Level::L4.index()].to_vec(); // 6 vertebrae
    let n = levels.len();
    let radius = 0.2;
    let mut set = LandmarkSet::new();
    for (i, l) in levels.iter().enumerate() {
        // Angle along the arc: +arc/2 at T11 (top) to -arc/2 at L4 (bottom).
        let phi = (arc_deg * ((n - 1 - i) as f64 / (n - 1) as f64 - 0.5)).to_radians();
        // Circle centred at +Z: the tangent (cos phi, sin phi) in (Y, Z) is
        // the vertebra's axis; the spine bulges to -Z (left) at the apex.
        let c = Point3::new(0.0, radius * phi.sin(), radius * (1.0 - phi.cos()));
        let r = Rotation3::from_axis_angle(&Vector3::x_axis(), phi);
        put_vertebra(&mut set, *l, c, &r);
    }
    let cobb = metrics::cobb(&set, None).unwrap();
    assert!((cobb.angle_deg.abs() - arc_deg).abs() < 1e-9, "{cobb:?}");
    assert_eq!((cobb.upper, cobb.lower), (Level::T11, Level::L4));
    // Convex to the left: negative by the documented sign.
    assert!(cobb.angle_deg < 0.0);
    let apex = metrics::apex(&centres_of(&set), Level::T11, Level::L4).unwrap();
    assert!(apex == Level::L1 || apex == Level::L2, "{apex}");
    // Given end vertebrae inside the arc: the arc between them.
    let part = metrics::cobb(&set, Some((Level::T12, Level::L3))).unwrap();
    assert!(
        (part.angle_deg.abs() - arc_deg * 3.0 / 5.0).abs() < 1e-9,
        "{part:?}"
    );
}

/// A straight spine with a known lordosis: S1 endplate at a 40 deg sacral
/// slope, L1 tilted back by 12 deg: lordosis -52 deg (thesis sign).
#[test]
fn straight_spine_has_its_lordosis() {
    let mut set = LandmarkSet::new();
    for (i, l) in Level::ALL[Level::L1.index()..=Level::L5.index()]
        .iter()
        .enumerate()
    {
        // Rotation about Z (right): positive turns +X (anterior) to +Y, so
        // L1's endplate faces 12 deg posteriorly.
        let tilt = if *l == Level::L1 { 12f64 } else { 0.0 };
        let r = Rotation3::from_axis_angle(&Vector3::z_axis(), tilt.to_radians());
        put_vertebra(
            &mut set,
            *l,
            Point3::new(0.0, 0.2 - 0.035 * i as f64, 0.0),
            &r,
        );
    }
    // S1: endplate facing anteriorly by 40 deg (anterior edge lower).
    let r = Rotation3::from_axis_angle(&Vector3::z_axis(), (-40f64).to_radians());
    put_vertebra(&mut set, Level::S1, Point3::new(0.0, 0.0, 0.0), &r);
    let ll = metrics::lordosis(&set).unwrap();
    assert!((ll - (-52.0)).abs() < 1e-9, "{ll}");
    assert!((metrics::sacral_slope(&set).unwrap() - 40.0).abs() < 1e-9);
    // Straight in the frontal plane: Cobb 0.
    assert!(metrics::cobb(&set, None).unwrap().angle_deg.abs() < 1e-9);
}

/// Centre errors: a model shifted by 3 mm anteriorly has 3 mm RMSE in the
/// sacral frame and none after rigid superimposition; identical curves fit
/// perfectly.
#[test]
fn evaluate_measures_a_known_offset() {
    let mut truth_set = LandmarkSet::new();
    for (i, l) in Level::ALL[Level::T9.index()..=Level::L5.index()]
        .iter()
        .enumerate()
    {
        let r = Rotation3::from_axis_angle(&Vector3::x_axis(), (0.1 * (i as f64)).sin() * 0.3);
        put_vertebra(
            &mut truth_set,
            *l,
            Point3::new(
                0.01 * (i as f64 * 0.7).sin(),
                0.4 - 0.03 * i as f64,
                0.02 * (i as f64 * 0.5).sin(),
            ),
            &r,
        );
    }
    let truth = Truth {
        source: "analytic".into(),
        centres: centres_of(&truth_set),
        landmarks: Some(truth_set.clone()),
    };
    let shift = Vector3::new(0.003, 0.0, 0.0);
    let model_set = truth_set.transformed(&nalgebra::Matrix3::identity(), &shift);
    let m = ModelShape {
        name: "shifted".into(),
        centres: centres_of(&model_set),
        landmarks: model_set,
        registration: None,
    };
    let s = evaluate_model(&m, &truth, Align::Sacrum, None).unwrap();
    assert!(
        (s.centre_rmse_mm - 3.0).abs() < 1e-9,
        "{}",
        s.centre_rmse_mm
    );
    for e in &s.levels {
        assert!((e.ap_mm - 3.0).abs() < 1e-9 && e.is_mm.abs() < 1e-9 && e.rl_mm.abs() < 1e-9);
    }
    let frontal = s.frontal.unwrap();
    assert!(frontal.rmse_mm < 1e-9 && (frontal.r2 - 1.0).abs() < 1e-12);
    assert!((s.sagittal.unwrap().rmse_mm - 3.0).abs() < 1e-6);
    assert!(s.cobb_error_deg.unwrap().abs() < 1e-9);
    let r = evaluate_model(&m, &truth, Align::Rigid, None).unwrap();
    assert!(r.centre_rmse_mm < 1e-9);
    let l5 = evaluate_model(&m, &truth, Align::L5, None).unwrap();
    assert!(l5.centre_rmse_mm < 1e-9);
    let _ = Path::new(".");
}

/// The default combination of the fits (`--smooth chain`) on the README
/// example: applied, the joint mismatch SD per axis and the per-level
/// posterior SDs (no larger than the fits') are reported, 6 pose
/// parameters per vertebra, deterministic output.
#[test]
fn chain_smoothing_is_the_default_and_reported() {
    let tmp = tempfile::tempdir().unwrap();
    let mut reports = Vec::new();
    for k in 0..2 {
        let out = tmp.path().join(format!("c{k}/patient.osim"));
        let o = run(&[
            "generate",
            "--landmarks",
            "fixtures/example-scoliosis.csv",
            "--out",
            out.to_str().unwrap(),
            "--no-self-check",
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let stdout = String::from_utf8_lossy(&o.stdout).to_string();
        assert!(
            stdout.contains("orientation smoothing: posterior poses of the kinematic chain"),
            "{stdout}"
        );
        reports.push(std::fs::read(tmp.path().join(format!("c{k}/patient_report.json"))).unwrap());
        let osim = std::fs::read(&out).unwrap();
        if k == 1 {
            let first = std::fs::read(tmp.path().join("c0/patient.osim")).unwrap();
            assert_eq!(first, osim, "model not deterministic");
        }
    }
    assert_eq!(reports[0], reports[1], "report not deterministic");
    let r: serde_json::Value = serde_json::from_slice(&reports[0]).unwrap();
    let s = &r["smoothing"];
    assert_eq!(s["mode"], "chain");
    assert_eq!(s["applied"], true);
    let n = r["levels_from_landmarks"].as_array().unwrap().len();
    assert_eq!(s["parameters"].as_u64().unwrap() as usize, 6 * n);
    let sd = s["joint_sd_mm"].as_array().unwrap();
    assert_eq!(sd.len(), 3);
    assert!(sd.iter().all(|t| t.as_f64().unwrap() > 0.0));
    let levels = s["levels"].as_array().unwrap();
    assert_eq!(levels.len(), n);
    for l in levels {
        for a in 0..3 {
            let (fit, post) = (
                l["fit_sd_deg"][a].as_f64().unwrap(),
                l["posterior_sd_deg"][a].as_f64().unwrap(),
            );
            assert!(post > 0.0 && post <= fit * (1.0 + 1e-9), "{l}");
        }
    }
}

/// `--smooth auto` on the README example (noisy landmarks, one planted
/// outlier): the report states tau per axis, the effective smoothing and
/// per-level posterior SDs no larger than the fits' SDs; the output is
/// deterministic; a bad mode is refused without output.
#[test]
fn smoothing_is_reported_and_deterministic() {
    let tmp = tempfile::tempdir().unwrap();
    let mut reports = Vec::new();
    for k in 0..2 {
        let out = tmp.path().join(format!("s{k}/patient.osim"));
        let o = run(&[
            "generate",
            "--landmarks",
            "fixtures/example-scoliosis.csv",
            "--out",
            out.to_str().unwrap(),
            "--smooth",
            "auto",
            "--no-self-check",
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let stdout = String::from_utf8_lossy(&o.stdout).to_string();
        assert!(
            stdout.contains("orientation smoothing: posterior"),
            "{stdout}"
        );
        reports.push(std::fs::read(tmp.path().join(format!("s{k}/patient_report.json"))).unwrap());
    }
    assert_eq!(reports[0], reports[1], "report not deterministic");
    let r: serde_json::Value = serde_json::from_slice(&reports[0]).unwrap();
    let s = &r["smoothing"];
    assert_eq!(s["applied"], true);
    let levels = s["levels"].as_array().unwrap();
    let n = r["levels_from_landmarks"].as_array().unwrap().len();
    assert_eq!(levels.len(), n);
    assert_eq!(s["parameters"].as_u64().unwrap() as usize, 3 * n);
    let tau = s["tau_deg"].as_array().unwrap();
    assert_eq!(tau.len(), 3);
    assert!(tau.iter().all(|t| t.as_f64().unwrap() > 0.0));
    let edf = s["effective_dof"].as_f64().unwrap();
    assert!(edf > 0.0 && edf < 3.0 * n as f64, "{edf}");
    for l in levels {
        for a in 0..3 {
            let (fit, post) = (
                l["fit_sd_deg"][a].as_f64().unwrap(),
                l["posterior_sd_deg"][a].as_f64().unwrap(),
            );
            assert!(post > 0.0 && post <= fit * (1.0 + 1e-9), "{l}");
        }
    }
    // Bad mode: clear error, nothing written.
    let out = tmp.path().join("bad/patient.osim");
    let o = run(&[
        "generate",
        "--landmarks",
        "fixtures/example-scoliosis.csv",
        "--out",
        out.to_str().unwrap(),
        "--smooth",
        "maybe",
    ]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("--smooth"));
    assert!(!tmp.path().join("bad").exists());
}

/// `generate` on the landmark file `name` (written from `text` into
/// `dir`); its stderr and report. Panics if it fails.
fn generate_report(dir: &Path, name: &str, text: &str) -> (String, serde_json::Value) {
    let out = dir.join(name.replace(".csv", "")).join("p.osim");
    let o = generate_file(dir, name, text, &out);
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    assert!(o.status.success(), "{name}: {err}");
    let rep = serde_json::from_slice(&std::fs::read(out.with_file_name("p_report.json")).unwrap())
        .unwrap();
    (err, rep)
}

/// One missing landmark does not refuse the set; the
/// level is fitted on the 13 others, flagged on the console and in the
/// report, and lands where the complete set puts it.
#[test]
fn a_missing_landmark_gives_a_reduced_fit() {
    let tmp = tempfile::tempdir().unwrap();
    let lines = example_lines();
    let mut centres = Vec::new();
    for (name, text) in [
        ("full.csv", lines.join("\n") + "\n"),
        (
            "missing.csv",
            without(&lines, &|l| l.starts_with("L2_IEC,")),
        ),
    ] {
        let (err, rep) = generate_report(tmp.path(), name, &text);
        let reduced = rep["reduced_fits"].as_array().unwrap();
        if name == "missing.csv" {
            assert_eq!(reduced.len(), 1, "{reduced:?}");
            assert_eq!(reduced[0]["level"], "L2");
            assert_eq!(reduced[0]["missing"][0], "L2_IEC");
            assert_eq!(reduced[0]["used"], 13);
            assert!(err.contains("L2 fitted on 13 of 14 landmarks"), "{err}");
        } else {
            assert!(reduced.is_empty());
        }
        let c = &rep["centres"]["L2"];
        centres.push([0, 1, 2].map(|k| c[k].as_f64().unwrap()));
    }
    let d = (0..3)
        .map(|k| (centres[0][k] - centres[1][k]).powi(2))
        .sum::<f64>()
        .sqrt();
    println!("L2 centre moved {:.2} mm by the reduced fit", d * 1e3);
    assert!(d < 2e-3, "L2 centre moved {:.2} mm", d * 1e3);
}

/// A level missing between landmarked ones (a gap) is filled from its
/// neighbours, said on the console and in the report (`filled_levels`),
/// and lands near where the complete set puts it; the other measured
/// levels' centres move by less than 0.3 mm.
#[test]
fn a_missing_level_is_filled_from_its_neighbours() {
    let tmp = tempfile::tempdir().unwrap();
    let lines = example_lines();
    let (_, full) = generate_report(tmp.path(), "full.csv", &(lines.join("\n") + "\n"));
    let (err, gap) = generate_report(
        tmp.path(),
        "gap.csv",
        &without(&lines, &|l| l.starts_with("L2_")),
    );
    assert_eq!(gap["filled_levels"], serde_json::json!(["L2"]), "{err}");
    assert!(full["filled_levels"].as_array().unwrap().is_empty());
    assert!(err.contains("L2 has no landmarks"), "{err}");
    assert!(err.contains("LM021"), "{err}");
    // Only the levels above the top measured one are above the field of view.
    assert_eq!(
        gap["above_fov"]["unmeasured"],
        full["above_fov"]["unmeasured"]
    );
    let centre = |r: &serde_json::Value, l: &str| {
        let c = &r["centres"][l];
        nalgebra::Vector3::from_fn(|k, _| c[k].as_f64().unwrap())
    };
    // The measured levels (those above them are balanced, 400 mm of lever).
    for level in full["levels_from_landmarks"].as_array().unwrap() {
        let level = level.as_str().unwrap();
        let d = (centre(&full, level) - centre(&gap, level)).norm() * 1e3;
        println!("{level}: {d:.2} mm");
        let limit = if level == "L2" { 2.0 } else { 0.3 };
        assert!(d < limit, "{level} moved {d:.2} mm");
    }
}

/// A level without either lateral pair (SR, SL, IR, IL) cannot measure
/// its width: it borrows the mean width factor of the levels on either
/// side, says so on the console and in the report, and lands where the
/// complete set puts it (before, `generate` refused the set).
#[test]
fn a_level_without_lateral_landmarks_borrows_its_width_scale() {
    let tmp = tempfile::tempdir().unwrap();
    let lines = example_lines();
    let lateral = |l: &str| {
        ["L2_SR,", "L2_SL,", "L2_IR,", "L2_IL,"]
            .iter()
            .any(|p| l.starts_with(p))
    };
    let mut reports = Vec::new();
    for (name, text) in [
        ("full.csv", lines.join("\n") + "\n"),
        ("nolateral.csv", without(&lines, &lateral)),
    ] {
        let (err, rep) = generate_report(tmp.path(), name, &text);
        if name == "nolateral.csv" {
            assert!(err.contains("L2 fitted on 10 of 14 landmarks"), "{err}");
            assert!(err.contains("width"), "{err}");
        }
        reports.push(rep);
    }
    let (full, part) = (&reports[0], &reports[1]);
    let borrowed = part["reduced_fits"][0]["borrowed_scale"]
        .as_array()
        .unwrap();
    assert_eq!(borrowed.len(), 1, "{borrowed:?}");
    assert!(
        borrowed[0].as_str().unwrap().contains("from L1, L3"),
        "{borrowed:?}"
    );
    // The width factor is the mean of L1's and L3's in the complete set's fit.
    let scale = |r: &serde_json::Value, level: &str| -> f64 {
        let v = r["vertebrae"].as_array().unwrap();
        let e = v.iter().find(|e| e["level"] == level).unwrap();
        e["scale"][2].as_f64().unwrap()
    };
    let want = 0.5 * (scale(part, "L1") + scale(part, "L3"));
    assert!(
        (scale(part, "L2") - want).abs() < 1e-9,
        "{} vs {want}",
        scale(part, "L2")
    );
    let c = |r: &serde_json::Value| [0, 1, 2].map(|k| r["centres"]["L2"][k].as_f64().unwrap());
    let (a, b) = (c(full), c(part));
    let d = (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>().sqrt();
    println!("L2 centre moved {:.2} mm by the borrowed width", d * 1e3);
    assert!(d < 1e-3, "L2 centre moved {:.2} mm", d * 1e3);
}
