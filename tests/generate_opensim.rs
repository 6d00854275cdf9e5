//! Acceptance tests of `osim-spine generate` and `evaluate` against ground
//! truth made with the real OpenSim 4.6:
//!
//! 1. the base model (built from the cyclist model) is posed in OpenSim
//!    into scoliotic shapes; the posed markers (the patient's landmarks)
//!    and the posed vertebral-body sphere centres (the truth centres) are
//!    moved into LPS millimetres by a random rigid transform; `generate`
//!    then `evaluate` must recover the centres (RMSE < 0.5 mm, in the
//!    sacral frame without any superimposition) and the Cobb angle (within
//!    0.5 deg of the truth's, which is computed from the posed landmarks);
//! 2. the noise study (2 mm SD on every landmark, 50 draws per shape, both
//!    methods), printed as a table, with the targets asserted for the
//!    default method and the lsq outlier rejection checked;
//! 3. the generated models in OpenSim: zero bushing force at the default
//!    pose and the base issue's wrap checks;
//! 4. bad inputs: clear errors, non-zero exit, nothing written.

mod common;

use nalgebra::{Matrix3, Point3, Rotation3, Vector3};
use osim_spine::evaluate::{evaluate_model, Align, CentreDef, ModelShape, Truth};
use osim_spine::generate::{generate, GenerateOptions, Method, Smooth};
use osim_spine::landmarks::{Frame, LandmarkId, LandmarkSet, Level, Units};
use osim_spine::osim::Document;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal, UnitSphere};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

/// The cyclist base model, built once per test binary.
fn base_dir() -> Option<PathBuf> {
    static DIR: OnceLock<Option<PathBuf>> = OnceLock::new();
    DIR.get_or_init(|| {
        let model = common::shared("data/models/cyclistFullBodyMuscle.osim")?;
        let geom = common::shared("data/geometry-bodyframe")?;
        let sacrum = common::shared("data/geometry/sacrumv.vtp")?;
        let dir = tempfile::tempdir().unwrap().keep().join("base");
        let o = Command::new(common::bin())
            .args(["base", "--generic"])
            .arg(&model)
            .arg("--geometry")
            .arg(&geom)
            .arg("--sacrum")
            .arg(&sacrum)
            .arg("--out")
            .arg(&dir)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        Some(dir)
    })
    .clone()
}

/// A scoliotic shape: coordinate offsets (deg) per joint prefix.
struct Shape {
    name: &'static str,
    /// Designed Cobb angle of the main curve (deg, magnitude).
    cobb: f64,
    lb: Vec<(&'static str, f64)>,
    ar: Vec<(&'static str, f64)>,
    fe: Vec<(&'static str, f64)>,
}

fn shapes() -> Vec<Shape> {
    vec![
        Shape {
            name: "lumbar 60 deg with axial rotation",
            cobb: 60.0,
            lb: vec![
                ("L5_S1", -15.0),
                ("L4_L5", -15.0),
                ("L3_L4", 12.0),
                ("L2_L3", 12.0),
                ("L1_L2", 12.0),
                ("T12_L1", 12.0),
                ("T11_T12", 12.0),
                ("T10_T11", -7.5),
                ("T9_T10", -7.5),
                ("T8_T9", -7.5),
                ("T7_T8", -7.5),
            ],
            ar: vec![
                ("L3_L4", 4.0),
                ("L2_L3", 4.0),
                ("L1_L2", 4.0),
                ("T12_L1", 4.0),
            ],
            fe: vec![("L2_L3", 3.0), ("T12_L1", -3.0)],
        },
        Shape {
            name: "double curve",
            cobb: 54.0,
            lb: vec![
                ("L5_S1", -10.0),
                ("L4_L5", -10.0),
                ("L3_L4", 11.0),
                ("L2_L3", 11.0),
                ("L1_L2", 11.0),
                ("T12_L1", 11.0),
                ("T11_T12", -9.0),
                ("T10_T11", -9.0),
                ("T9_T10", -9.0),
                ("T8_T9", -9.0),
                ("T7_T8", -9.0),
                ("T6_T7", -9.0),
                ("T5_T6", 6.0),
                ("T4_T5", 6.0),
                ("T3_T4", 6.0),
            ],
            ar: vec![
                ("L2_L3", 3.0),
                ("L1_L2", 3.0),
                ("T9_T10", -3.0),
                ("T8_T9", -3.0),
            ],
            fe: vec![],
        },
        Shape {
            name: "severe 90 deg",
            cobb: 90.0,
            lb: vec![
                ("L5_S1", -20.0),
                ("L4_L5", -25.0),
                ("L3_L4", 18.0),
                ("L2_L3", 18.0),
                ("L1_L2", 18.0),
                ("T12_L1", 18.0),
                ("T11_T12", 18.0),
                ("T10_T11", -9.0),
                ("T9_T10", -9.0),
                ("T8_T9", -9.0),
                ("T7_T8", -9.0),
                ("T6_T7", -9.0),
            ],
            ar: vec![
                ("L3_L4", 5.0),
                ("L2_L3", 5.0),
                ("L1_L2", 5.0),
                ("T12_L1", 5.0),
            ],
            fe: vec![("L1_L2", 4.0)],
        },
        // Curvature that changes smoothly from level to level (no sharp
        // turn at the end vertebrae): relative lateral bending
        // 9 sin(pi (j + 1/2) / 8) deg and axial rotation a third of it
        // at joint j = 0 (T1_T2) .. 16 (L5_S1): a thoracic and a lumbar
        // curve of 46 deg of lateral bending each; with the axial
        // rotation in the kyphotic thorax the frontal Cobb angle of the
        // thoracic curve reads about 60 deg.
        Shape {
            name: "smooth double curve",
            cobb: 55.0,
            lb: smooth_wave(9.0),
            ar: smooth_wave(3.0),
            fe: vec![],
        },
    ]
}

/// `amp sin(pi (j + 1/2) / 8)` (deg) at the 17 joints T1_T2 .. L5_S1.
fn smooth_wave(amp: f64) -> Vec<(&'static str, f64)> {
    const JOINTS: [&str; 17] = [
        "T1_T2", "T2_T3", "T3_T4", "T4_T5", "T5_T6", "T6_T7", "T7_T8", "T8_T9", "T9_T10",
        "T10_T11", "T11_T12", "T12_L1", "L1_L2", "L2_L3", "L3_L4", "L4_L5", "L5_S1",
    ];
    JOINTS
        .iter()
        .enumerate()
        .map(|(j, n)| {
            (
                *n,
                amp * (std::f64::consts::PI * (j as f64 + 0.5) / 8.0).sin(),
            )
        })
        .collect()
}

/// OpenSim's posed markers and vertebral-body sphere centres (ground, m).
struct Posed {
    markers: BTreeMap<String, Point3<f64>>,
    spheres: BTreeMap<Level, Point3<f64>>,
}

impl Posed {
    /// Vertebral centres by the default definition: midpoints of the posed
    /// SEC and IEC markers.
    fn centres(&self) -> BTreeMap<Level, Point3<f64>> {
        Level::ALL
            .iter()
            .filter(|l| !l.is_sacrum())
            .filter_map(|l| {
                let a = self.markers.get(&format!("{l}_SEC"))?;
                let b = self.markers.get(&format!("{l}_IEC"))?;
                Some((*l, nalgebra::center(a, b)))
            })
            .collect()
    }
}

fn pose_in_opensim(py: &Path, model: &Path, shape: &Shape) -> Posed {
    let mut m = serde_json::Map::new();
    for (list, suffix) in [(&shape.lb, "LB"), (&shape.ar, "AR"), (&shape.fe, "FE")] {
        for (j, deg) in list {
            m.insert(format!("{j}_{suffix}"), serde_json::json!(deg.to_radians()));
        }
    }
    let f = tempfile::NamedTempFile::new().unwrap();
    std::fs::write(f.path(), serde_json::Value::Object(m).to_string()).unwrap();
    let r = common::run_py(
        py,
        "pose_spine.py",
        &[model.to_str().unwrap(), f.path().to_str().unwrap()],
    );
    let p = |v: &serde_json::Value| {
        Point3::new(
            v[0].as_f64().unwrap(),
            v[1].as_f64().unwrap(),
            v[2].as_f64().unwrap(),
        )
    };
    Posed {
        markers: r["markers"]
            .as_object()
            .unwrap()
            .iter()
            .map(|(k, v)| (k.clone(), p(v)))
            .collect(),
        spheres: r["centres"]
            .as_object()
            .unwrap()
            .iter()
            .map(|(k, v)| (k.parse::<Level>().unwrap(), p(v)))
            .collect(),
    }
}

/// A random rigid transform of OpenSim-axes metres into LPS millimetres: a
/// rotation of up to 30 degrees about a random axis (patient positioning in
/// the scanner: the file still declares LPS, which the anatomy must
/// confirm within 60 degrees) and a translation of up to 500 mm per axis.
struct ToLps {
    r: Rotation3<f64>,
    t: Vector3<f64>,
}

impl ToLps {
    fn random(rng: &mut ChaCha8Rng) -> ToLps {
        let axis: [f64; 3] = UnitSphere.sample(rng);
        let angle = rng.random_range(-30f64..30.0).to_radians();
        ToLps {
            r: Rotation3::from_axis_angle(
                &nalgebra::Unit::new_normalize(Vector3::from(axis)),
                angle,
            ),
            t: Vector3::new(
                rng.random_range(-500.0..500.0),
                rng.random_range(-500.0..500.0),
                rng.random_range(-500.0..500.0),
            ),
        }
    }
    /// OpenSim-axes point (m) -> LPS (mm).
    fn apply(&self, p: &Point3<f64>) -> Vector3<f64> {
        let lps: Matrix3<f64> = Frame::Lps.to_opensim().transpose();
        self.r * (lps * p.coords * 1e3) + self.t
    }
}

fn landmarks_csv(
    markers: &BTreeMap<String, Point3<f64>>,
    x: &ToLps,
    keep: &dyn Fn(Level) -> bool,
) -> String {
    let mut s = String::from("# units: mm\n# frame: LPS\nname,x,y,z\n");
    for (n, p) in markers {
        let Some((id, _)) = LandmarkId::parse_name(n) else {
            continue;
        };
        if !keep(id.level) {
            continue;
        }
        let v = x.apply(p);
        s.push_str(&format!("{n},{},{},{}\n", v.x, v.y, v.z));
    }
    s
}

fn centres_csv(centres: &BTreeMap<Level, Point3<f64>>, x: &ToLps) -> String {
    let mut s = String::from("# units: mm\n# frame: LPS\nlevel,x,y,z\n");
    for (l, p) in centres {
        let v = x.apply(p);
        s.push_str(&format!("{l},{},{},{}\n", v.x, v.y, v.z));
    }
    s
}

fn run(args: &[&str]) -> std::process::Output {
    Command::new(common::bin()).args(args).output().unwrap()
}

/// Acceptance 1 and 3: noise-free shapes posed in OpenSim, both methods.
#[test]
fn noise_free_shapes_are_reproduced_and_load_in_opensim() {
    let Some(base) = base_dir() else { return };
    let Some(py) = common::opensim_python() else {
        return;
    };
    let base_osim = base.join("base.osim");
    let tmp = tempfile::tempdir().unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(2024);
    for (k, shape) in shapes().iter().enumerate() {
        let posed = pose_in_opensim(&py, &base_osim, shape);
        assert_eq!(posed.spheres.len(), 17);
        assert_eq!(posed.centres().len(), 17);
        let x = ToLps::random(&mut rng);
        let lm = tmp.path().join(format!("shape{k}.csv"));
        let ct = tmp.path().join(format!("shape{k}_centres.csv"));
        let cs = tmp.path().join(format!("shape{k}_spheres.csv"));
        std::fs::write(&lm, landmarks_csv(&posed.markers, &x, &|_| true)).unwrap();
        std::fs::write(&ct, centres_csv(&posed.centres(), &x)).unwrap();
        std::fs::write(&cs, centres_csv(&posed.spheres, &x)).unwrap();
        // Smoothing must keep the noise-free acceptance (exact data: the
        // posterior is the data).
        for (fit, smooth) in [
            ("lsq", "chain"),
            ("lsq", "off"),
            ("lsq", "curvature"),
            ("thesis", "off"),
        ] {
            let method = format!("{fit}+{smooth}");
            let out = tmp
                .path()
                .join(format!("gen{k}_{fit}_{smooth}/patient.osim"));
            let o = run(&[
                "generate",
                "--base",
                base.to_str().unwrap(),
                "--landmarks",
                lm.to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
                "--method",
                fit,
                "--smooth",
                smooth,
            ]);
            assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
            let ev = tmp.path().join(format!("ev{k}_{fit}_{smooth}"));
            let o = run(&[
                "evaluate",
                "--model",
                out.to_str().unwrap(),
                "--truth",
                ct.to_str().unwrap(),
                "--truth-landmarks",
                lm.to_str().unwrap(),
                "--align",
                "sacrum",
                "--out",
                ev.to_str().unwrap(),
            ]);
            assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
            let r: serde_json::Value =
                serde_json::from_slice(&std::fs::read(ev.join("evaluation.json")).unwrap())
                    .unwrap();
            let m = &r["models"][0];
            let rmse = m["centre_rmse_mm"].as_f64().unwrap();
            let cobb = m["cobb"]["angle_deg"].as_f64().unwrap();
            let tcobb = m["truth_cobb"]["angle_deg"].as_f64().unwrap();
            println!(
                "{} ({method}): centre RMSE {rmse:.2e} mm in the sacral frame, Cobb {cobb:.2} deg vs truth {tcobb:.2} deg ({}-{}), designed {}",
                shape.name, m["cobb"]["upper"], m["cobb"]["lower"], shape.cobb
            );
            assert!(rmse < 0.5, "{}: RMSE {rmse} mm", shape.name);
            assert!(
                (cobb - tcobb).abs() < 0.5,
                "{}: Cobb {cobb} vs {tcobb}",
                shape.name
            );
            // The truth's Cobb angle measures the designed curve (independent
            // of the generator: OpenSim's posed landmarks).
            assert!(
                (tcobb.abs() - shape.cobb).abs() < 10.0,
                "{}: truth Cobb {tcobb}",
                shape.name
            );
            assert_eq!(m["apex"], m["truth_apex"]);
            // The thesis's definition (wrap-sphere centres) agrees too.
            let ev2 = tmp.path().join(format!("ev{k}_{fit}_{smooth}_sphere"));
            let o = run(&[
                "evaluate",
                "--model",
                out.to_str().unwrap(),
                "--truth",
                cs.to_str().unwrap(),
                "--centre",
                "sphere",
                "--align",
                "sacrum",
                "--out",
                ev2.to_str().unwrap(),
            ]);
            assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
            let r2: serde_json::Value =
                serde_json::from_slice(&std::fs::read(ev2.join("evaluation.json")).unwrap())
                    .unwrap();
            let rmse2 = r2["models"][0]["centre_rmse_mm"].as_f64().unwrap();
            assert!(rmse2 < 0.5, "{}: sphere-centre RMSE {rmse2} mm", shape.name);
            // Acceptance 3 in OpenSim (once per shape, default method).
            if method == "lsq+chain" {
                check_in_opensim(&py, &out);
            }
        }
    }
}

/// OpenSim loads the model, reports zero bushing force at the default pose,
/// the base issue's wrap checks hold in a scoliotic test pose, and
/// OpenSim's wrapped muscle paths pass through no vertebra.
fn check_in_opensim(py: &Path, model: &Path) {
    let r = common::run_py(py, "base_check.py", &[model.to_str().unwrap(), "10", "5"]);
    assert_eq!(r["bushings"], 17);
    let bmax = r["bushing_max_record_at_default"].as_f64().unwrap();
    assert!(
        bmax < 1e-6,
        "bushing force/torque at the default pose {bmax}"
    );
    let rows = r["scoliotic"].as_array().unwrap();
    let crossing = common::assert_wrap_rows(rows);
    println!(
        "  OpenSim: bushing records at default <= {bmax:.1e}; {} muscles with PathWraps, {crossing} crossing and wrapping",
        rows.len()
    );
    // OpenSim's wrapped paths at the default pose cross no vertebra, and
    // the tool's wrapped path lengths are OpenSim's.
    let (crossings, dlen) = common::opensim_path_crossings(py, model);
    println!(
        "  OpenSim: wrapped paths through vertebrae {}; tool vs OpenSim length {dlen:.1e} m",
        crossings.len()
    );
    assert!(crossings.is_empty(), "{crossings:?}");
    assert!(dlen < 1e-9, "path lengths differ by {dlen} m");
}

/// Levels without landmarks keep the base model's shape and alignment:
/// a T9-S1 set of a spine bent only below T9 reproduces all 17 centres.
#[test]
fn partial_set_keeps_the_base_alignment_above() {
    let Some(base) = base_dir() else { return };
    let Some(py) = common::opensim_python() else {
        return;
    };
    let shape = Shape {
        name: "lumbar only",
        cobb: 60.0,
        lb: vec![
            ("L5_S1", -12.0),
            ("L4_L5", -12.0),
            ("L3_L4", 10.0),
            ("L2_L3", 10.0),
            ("L1_L2", 10.0),
            ("T12_L1", 10.0),
            ("T11_T12", 10.0),
            ("T10_T11", 10.0),
        ],
        ar: vec![("L1_L2", 5.0)],
        fe: vec![("L3_L4", 5.0)],
    };
    let posed = pose_in_opensim(&py, &base.join("base.osim"), &shape);
    let x = ToLps::random(&mut ChaCha8Rng::seed_from_u64(5));
    let tmp = tempfile::tempdir().unwrap();
    let lm = tmp.path().join("t9.csv");
    let ct = tmp.path().join("centres.csv");
    std::fs::write(&lm, landmarks_csv(&posed.markers, &x, &|l| l >= Level::T9)).unwrap();
    std::fs::write(&ct, centres_csv(&posed.centres(), &x)).unwrap();
    let out = tmp.path().join("g/p.osim");
    let o = run(&[
        "generate",
        "--base",
        base.to_str().unwrap(),
        "--landmarks",
        lm.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        // the levels above the field of view keep the base alignment (the
        // default, balance, bends them over the sacrum instead)
        "--above-fov",
        "keep",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let rep: serde_json::Value =
        serde_json::from_slice(&std::fs::read(tmp.path().join("g/p_report.json")).unwrap())
            .unwrap();
    assert_eq!(rep["levels_from_base"].as_array().unwrap().len(), 8);
    let ev = tmp.path().join("ev");
    let o = run(&[
        "evaluate",
        "--model",
        out.to_str().unwrap(),
        "--truth",
        ct.to_str().unwrap(),
        "--align",
        "sacrum",
        "--out",
        ev.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let r: serde_json::Value =
        serde_json::from_slice(&std::fs::read(ev.join("evaluation.json")).unwrap()).unwrap();
    let m = &r["models"][0];
    assert_eq!(m["levels"].as_array().unwrap().len(), 17);
    let rmse = m["centre_rmse_mm"].as_f64().unwrap();
    println!("T9-S1 set, 17 centres: RMSE {rmse:.2e} mm");
    assert!(rmse < 0.5);
}

// ---------------------------------------------------------------- noise study

fn set_from_csv(text: &str) -> LandmarkSet {
    let p = osim_spine::landmarks::io::parse_csv(text, Path::new("noisy.csv")).unwrap();
    p[0].raw.to_set().unwrap()
}

#[derive(Default)]
struct Stats {
    rmse: Vec<f64>,
    rmse_sacral: Vec<f64>,
    cobb: Vec<f64>,
    cobb_fixed: Vec<f64>,
    flagged: usize,
    flagged_right: usize,
    displaced: usize,
    clean_flags: usize,
    clean_vertebrae: usize,
}

fn median(v: &[f64]) -> f64 {
    osim_spine::landmarks::stats::median(v).unwrap()
}

fn sd(v: &[f64]) -> f64 {
    let m = v.iter().sum::<f64>() / v.len() as f64;
    (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64).sqrt()
}

/// One generate + evaluate in memory (no files).
fn one_run(
    base: &Document,
    lm_text: &str,
    truth: &Truth,
    method: Method,
    smooth: Smooth,
    ends: (Level, Level),
) -> (f64, f64, f64, Vec<String>, f64) {
    let debug = std::env::var("OSIM_SPINE_STUDY_DEBUG").is_ok();
    let set = set_from_csv(lm_text);
    let opts = GenerateOptions {
        method,
        smooth,
        self_check: false,
        views: false,
        outlier_sigmas: std::env::var("OSIM_SPINE_STUDY_SIGMAS")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(osim_spine::generate::pose::OUTLIER_SIGMAS),
        ..GenerateOptions::default()
    };
    let g = generate(base, &set, "noisy.csv", &opts, None).unwrap();
    let shape = ModelShape::from_document(
        &g.doc,
        Some(g.report.registration.clone()),
        CentreDef::Endplates,
    )
    .unwrap();
    let m = evaluate_model(&shape, truth, Align::Rigid, None).unwrap();
    if debug {
        eprintln!("cobb {:?}", m.cobb);
        for v in &g.report.vertebrae {
            eprintln!(
                "  {} loo {:?} thr {:?} outlier {:?}",
                v.level, v.loo_max_mm, v.loo_threshold_mm, v.outlier
            );
        }
    }
    let cobb = m.cobb.map(|c| c.angle_deg).unwrap_or(f64::NAN);
    let fixed = osim_spine::evaluate::metrics::cobb(&shape.landmarks, Some(ends))
        .map(|c| c.angle_deg)
        .unwrap_or(f64::NAN);
    (
        m.centre_rmse_mm,
        m.centre_rmse_sacral_frame_mm.unwrap_or(f64::NAN),
        cobb,
        g.report.outliers.clone(),
        fixed,
    )
}

/// Acceptance 2: 2 mm SD noise, 50 draws per shape, both methods; one
/// landmark per vertebra displaced by 12 mm for the outlier check.
#[test]
fn noise_study_table() {
    let Some(base) = base_dir() else { return };
    let Some(py) = common::opensim_python() else {
        return;
    };
    let draws: usize = std::env::var("OSIM_SPINE_STUDY_DRAWS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(50);
    let base_doc = Document::read(base.join("base.osim")).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(77);
    println!("| noise | shape | method | median centre RMSE (mm) | median RMSE, sacral frame (mm) | Cobb SD, automatic ends (deg) | Cobb SD, truth's ends (deg) | mean Cobb error, automatic / truth's ends (deg) | truth Cobb (deg) |");
    println!("|---|---|---|---|---|---|---|---|---|");
    // Per (noise level, shape): the default method's figures and the
    // comparisons the assertions need.
    let mut rows: Vec<StudyRow> = Vec::new();
    let mut outlier_rows: Vec<OutlierRow> = Vec::new();
    let levels = [
        (2.0, "2 mm SD per axis"),
        (2.0 / 3f64.sqrt(), "2 mm SD 3-D (1.15 per axis)"),
    ];
    for (level_i, (noise_sd, noise_label)) in levels.into_iter().enumerate() {
        let noise = Normal::new(0.0, noise_sd).unwrap();
        let with_outliers = level_i == 0;
        for shape in shapes() {
            // The shape posed in OpenSim, seen in a random LPS frame.
            let st = ShapeTruth::new(&py, &base, &shape, &mut rng);
            // Every method on noisy draws (and displaced landmarks).
            let (stats, displaced_rmse_diff) =
                run_draws(&base_doc, &st, &noise, draws, with_outliers, &mut rng);
            // The table rows, and the default method's figures.
            for (method, _, _) in METHODS {
                print_row(noise_label, shape.name, method, &stats[method], &st);
            }
            let (def, off, th) = (&stats[DEFAULT], &stats["lsq"], &stats["thesis"]);
            rows.push(StudyRow {
                noise: noise_label,
                per_axis: with_outliers,
                shape: shape.name,
                rmse: median(&def.rmse),
                cobb_sd: sd(&def.cobb_fixed),
                bias: st.bias(&def.cobb_fixed),
                beats_independent_rmse: median(&def.rmse) < median(&off.rmse),
                // Cobb spread with the truth's end vertebrae: with automatic
                // ends a shape whose two curves are nearly equal (lumbar 60:
                // -57.7 against 55.5) flips between them for every method.
                beats_thesis: median(&def.rmse) < median(&th.rmse)
                    && sd(&def.cobb_fixed) < sd(&th.cobb_fixed),
            });
            if with_outliers {
                outlier_rows.push((
                    shape.name,
                    def.displaced,
                    def.flagged_right,
                    def.flagged,
                    median(&displaced_rmse_diff),
                    def.clean_flags,
                    def.clean_vertebrae,
                ));
            }
        }
    }
    print_summary(&rows, &outlier_rows);
    assert_study_targets(&rows, &outlier_rows);
}

/// Outlier check of one shape: (shape, displaced landmarks, flagged
/// correctly, flagged in all, median RMSE change mm, flags on clean sets,
/// clean vertebrae).
type OutlierRow = (&'static str, usize, usize, usize, f64, usize, usize);

/// A shape posed in OpenSim and seen in a random LPS frame: the truth
/// centres, the clean landmarks and the truth's Cobb angle.
struct ShapeTruth {
    truth: Truth,
    clean: BTreeMap<String, Vector3<f64>>,
    /// The truth's Cobb angle and end vertebrae (in the model's ground).
    tc: osim_spine::evaluate::metrics::Cobb,
    ends: (Level, Level),
    /// The largest curve of the other sign, described.
    other: String,
}

impl ShapeTruth {
    fn new(py: &Path, base: &Path, shape: &Shape, rng: &mut ChaCha8Rng) -> Self {
        let posed = pose_in_opensim(py, &base.join("base.osim"), shape);
        let x = ToLps::random(rng);
        let truth_lps: BTreeMap<Level, Vector3<f64>> = posed
            .centres()
            .iter()
            .map(|(l, p)| (*l, x.apply(p)))
            .collect();
        let truth = Truth {
            source: shape.name.into(),
            centres: truth_lps
                .iter()
                .map(|(l, v)| {
                    (
                        *l,
                        Point3::from(Frame::Lps.to_opensim() * v * Units::Millimetre.to_metres()),
                    )
                })
                .collect(),
            landmarks: None,
        };
        let clean: BTreeMap<String, Vector3<f64>> = posed
            .markers
            .iter()
            // Landmarks only: the base's other markers (FH_R / FH_L) are
            // not in the palpation protocol.
            .filter(|(n, _)| LandmarkId::parse_name(n).is_some())
            .map(|(n, p)| (n.clone(), x.apply(p)))
            .collect();
        // Truth's Cobb angle in the model's ground (OpenSim's posed markers).
        let mut ground = LandmarkSet::new();
        for (n, p) in &posed.markers {
            if let Some((id, _)) = LandmarkId::parse_name(n) {
                ground.points.insert(id, *p);
            }
        }
        let tc = osim_spine::evaluate::metrics::cobb(&ground, None).unwrap();
        let other = other_curve(&ground, tc.angle_deg)
            .map(|o| format!("; other curve {:.1} ({}-{})", o.angle_deg, o.upper, o.lower))
            .unwrap_or_default();
        let ends: (Level, Level) = (tc.upper, tc.lower);
        ShapeTruth {
            truth,
            clean,
            tc,
            ends,
            other,
        }
    }

    /// Mean error of Cobb angles `v` against the truth's.
    fn bias(&self, v: &[f64]) -> f64 {
        v.iter().map(|c| c - self.tc.angle_deg).sum::<f64>() / v.len() as f64
    }
}

/// The largest curve of the sign opposite to `truth_cobb` (the automatic
/// end vertebrae may jump to it when the two are close).
fn other_curve(
    ground: &LandmarkSet,
    truth_cobb: f64,
) -> Option<osim_spine::evaluate::metrics::Cobb> {
    let lv: Vec<Level> = Level::ALL
        .iter()
        .copied()
        .filter(|l| !l.is_sacrum())
        .collect();
    let mut other: Option<osim_spine::evaluate::metrics::Cobb> = None;
    for (i, u) in lv.iter().enumerate() {
        for w in &lv[i..] {
            if let Some(c) = osim_spine::evaluate::metrics::cobb(ground, Some((*u, *w))) {
                if c.angle_deg * truth_cobb < 0.0
                    && other
                        .as_ref()
                        .is_none_or(|o| c.angle_deg.abs() > o.angle_deg.abs())
                {
                    other = Some(c);
                }
            }
        }
    }
    other
}

/// Every method on `draws` noisy copies of the shape's landmarks; with
/// outliers, the default method also on copies with one landmark per
/// vertebra displaced by 12 mm (the first 20 draws). Returns the figures
/// per method and the RMSE changes the displaced landmarks caused.
fn run_draws(
    base_doc: &Document,
    st: &ShapeTruth,
    noise: &Normal<f64>,
    draws: usize,
    with_outliers: bool,
    rng: &mut ChaCha8Rng,
) -> (BTreeMap<&'static str, Stats>, Vec<f64>) {
    let mut stats: BTreeMap<&str, Stats> = BTreeMap::new();
    let mut displaced_rmse_diff = Vec::new();
    for d in 0..draws {
        let mut noisy = st.clean.clone();
        for v in noisy.values_mut() {
            *v += Vector3::new(noise.sample(rng), noise.sample(rng), noise.sample(rng));
        }
        // One landmark per vertebra displaced by 12 mm (outlier check).
        let (bad, which) = displace_one_per_vertebra(&noisy, rng);
        for (name, method, smooth) in METHODS {
            let (rmse, rs, cobb, fl, fixed) = one_run(
                base_doc,
                &to_text(&noisy),
                &st.truth,
                method,
                smooth,
                st.ends,
            );
            let s = stats.entry(name).or_default();
            if name == DEFAULT {
                s.clean_flags += fl.len();
                s.clean_vertebrae += 17;
            }
            s.rmse.push(rmse);
            s.rmse_sacral.push(rs);
            s.cobb.push(cobb);
            s.cobb_fixed.push(fixed);
            if with_outliers && name == DEFAULT && d < draws.min(20) {
                let (rmse_bad, _, _, flagged, _) =
                    one_run(base_doc, &to_text(&bad), &st.truth, method, smooth, st.ends);
                displaced_rmse_diff.push(rmse_bad - rmse);
                s.displaced += which.len();
                s.flagged += flagged.len();
                s.flagged_right += flagged
                    .iter()
                    .filter(|f| which.contains_key(f.split(' ').next().unwrap_or("")))
                    .count();
            }
        }
    }
    (stats, displaced_rmse_diff)
}

/// A copy of `noisy` with one random landmark of every vertebra moved
/// 12 mm in a random direction, and the names of the moved ones.
fn displace_one_per_vertebra(
    noisy: &BTreeMap<String, Vector3<f64>>,
    rng: &mut ChaCha8Rng,
) -> (BTreeMap<String, Vector3<f64>>, BTreeMap<String, ()>) {
    let mut bad = noisy.clone();
    let mut which = BTreeMap::new();
    for l in Level::ALL.iter().filter(|l| !l.is_sacrum()) {
        let codes = osim_spine::landmarks::Code::ALL;
        let c = codes[rng.random_range(0..codes.len())];
        let dir: [f64; 3] = UnitSphere.sample(rng);
        let name = format!("{l}_{c}");
        if let Some(v) = bad.get_mut(&name) {
            *v += Vector3::from(dir) * 12.0;
            which.insert(name, ());
        }
    }
    (bad, which)
}

/// One row of the study table.
fn print_row(noise_label: &str, shape: &str, method: &str, s: &Stats, st: &ShapeTruth) {
    let (mr, cs, cf) = (median(&s.rmse), sd(&s.cobb), sd(&s.cobb_fixed));
    println!(
        "| {noise_label} | {shape} | {method} | {mr:.2} | {:.2} | {cs:.2} | {cf:.2} | {:+.2} / {:+.2} | {:.1} ({}-{}){} |",
        median(&s.rmse_sacral),
        st.bias(&s.cobb),
        st.bias(&s.cobb_fixed),
        st.tc.angle_deg,
        st.tc.upper,
        st.tc.lower,
        st.other
    );
}

/// The default method against the targets, and the outlier table.
fn print_summary(rows: &[StudyRow], outlier_rows: &[OutlierRow]) {
    for r in rows {
        println!(
            "{DEFAULT}, {}, {}: median RMSE {:.2} mm, Cobb SD {:.2} deg, bias {:+.2} deg (targets 2.5 mm, 3 deg: {})",
            r.noise,
            r.shape,
            r.rmse,
            r.cobb_sd,
            r.bias,
            if r.rmse <= 2.5 && r.cobb_sd <= 3.0 { "met" } else { "missed" }
        );
    }
    println!();
    println!("| shape | displaced landmarks | flagged correctly | flagged in all | median RMSE change (mm) | flags on clean sets (vertebrae) |");
    println!("|---|---|---|---|---|---|");
    for (name, n, right, all, diff, cf, cv) in outlier_rows {
        println!("| {name} | {n} | {right} | {all} | {diff:+.2} | {cf} ({cv}) |");
    }
}

/// The default method against the targets (acceptance 2: median RMSE
/// <= 2.5 mm and Cobb SD <= 3 deg at 2 mm per axis), unbiased (the chain
/// prior holds exactly for a spine posed by joint rotations; the mean of 50
/// draws has a standard error of about 0.4 deg), better than the
/// independent fits on RMSE and than the thesis method; outliers found.
fn assert_study_targets(rows: &[StudyRow], outlier_rows: &[OutlierRow]) {
    for r in rows {
        let what = format!("{} ({})", r.shape, r.noise);
        assert!(r.rmse <= 2.5, "{what}: median centre RMSE {} mm", r.rmse);
        let sd_max = if r.per_axis { 3.0 } else { 2.0 };
        assert!(r.cobb_sd <= sd_max, "{what}: Cobb SD {} deg", r.cobb_sd);
        assert!(
            r.bias.abs() <= 1.0,
            "{what}: mean Cobb error {} deg",
            r.bias
        );
        assert!(
            r.beats_independent_rmse,
            "{what}: chain RMSE not below lsq's"
        );
        assert!(r.beats_thesis, "{what}: not better than the thesis method");
    }
    for (name, n, right, _, diff, cf, cv) in outlier_rows {
        assert!(
            *right as f64 >= 0.85 * *n as f64,
            "{name}: {right} of {n} displaced landmarks flagged"
        );
        assert!(
            diff.abs() <= 1.0,
            "{name}: RMSE changes by {diff} mm with outliers"
        );
        // Chi-square test at 4.7e-3 per landmark: about 6 % of clean
        // vertebrae (14 landmarks) get a false flag.
        assert!(
            (*cf as f64) <= 0.10 * *cv as f64,
            "{name}: {cf} false flags in {cv} vertebrae"
        );
    }
}

/// The default of `generate` and the methods the study compares it with.
const DEFAULT: &str = "lsq+chain";
const METHODS: [(&str, Method, Smooth); 4] = [
    ("lsq+chain", Method::Lsq, Smooth::Chain),
    ("lsq", Method::Lsq, Smooth::Off),
    ("lsq+curvature", Method::Lsq, Smooth::Curvature),
    ("thesis", Method::Thesis, Smooth::Off),
];

/// The default method's figures for one noise level and shape.
struct StudyRow {
    noise: &'static str,
    per_axis: bool,
    shape: &'static str,
    rmse: f64,
    cobb_sd: f64,
    bias: f64,
    beats_independent_rmse: bool,
    beats_thesis: bool,
}

fn to_text(pts: &BTreeMap<String, Vector3<f64>>) -> String {
    let mut s = String::from("# units: mm\n# frame: LPS\nname,x,y,z\n");
    for (n, v) in pts {
        s.push_str(&format!("{n},{},{},{}\n", v.x, v.y, v.z));
    }
    s
}
