//! `osim-spine flexibility` on films made by bending the project's base
//! model (`base_model/base.osim`) with known per-joint multipliers: what the
//! films can and cannot tell.
//!
//! - the neutral film alone bends nothing: no stiffness, said so, nothing
//!   written;
//! - one bending film gives wider 95% intervals than a left and a right one
//!   (information adds);
//! - `stiffness --table DIR/stiffness.toml` writes a model that OpenSim 4.6
//!   loads, whose bushings are the estimated ones (OpenSim's own reading of
//!   the file against `flexibility.json`).
//!
//! The films: the base model's frontal projection, bent by a lateral force
//! and a frontal moment on T1 with the truth multipliers (the tool's solver),
//! turned and shifted on the film, with a fixed pseudo-random digitising
//! noise of 0.5 mm SD per coordinate.

mod common;

use nalgebra::Vector2;
use osim_spine::flexibility::bend::BendModel;
use osim_spine::flexibility::place::Placement;
use osim_spine::flexibility::{self, FlexibilityOptions};
use osim_spine::landmarks::radiograph::{self, FilmPoint, Projection, Side};
use osim_spine::landmarks::{Code, LandmarkId, Level};
use osim_spine::osim::Document;
use osim_spine::solver::Workspace;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

/// Digitising noise of the synthetic films (m).
const NOISE: f64 = 0.5e-3;

fn base_path() -> PathBuf {
    common::repo_root().join("base_model/base.osim")
}

/// The truth multipliers: stiffer in the mid-thorax, softer below
/// (geometric mean not 1: only ratios are identifiable).
fn truth(n: usize) -> Vec<f64> {
    (0..n)
        .map(|j| (0.5 * (j as f64 * 0.45).cos()).exp())
        .collect()
}

/// Every point a film shows of T1..L5, the sacrum and the femoral heads.
fn film_points() -> Vec<FilmPoint> {
    let mut points = Vec::new();
    for l in &Level::ALL[..17] {
        for c in [Code::SR, Code::SL, Code::IR, Code::IL, Code::SEC, Code::IEC] {
            points.push(FilmPoint::Landmark(LandmarkId::new(*l, c)));
        }
    }
    for c in [Code::SR, Code::SL, Code::SEC] {
        points.push(FilmPoint::Landmark(LandmarkId::new(Level::S1, c)));
    }
    points.push(FilmPoint::FemoralHead(Side::Right));
    points.push(FilmPoint::FemoralHead(Side::Left));
    points
}

/// A deterministic N(0, 1) sequence (Box-Muller on a linear congruential
/// generator): the same films on every machine.
struct Noise(u64);

impl Noise {
    fn uniform(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((self.0 >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }
    fn normal(&mut self) -> f64 {
        let (a, b) = (self.uniform(), self.uniform());
        (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
    }
}

/// Write the film of the base model bent by `loads` on T1 to `path`.
fn write_film(bm: &BendModel, loads: [f64; 3], seed: u64, film: &str, path: &Path) {
    let sys = bm.with_multipliers(&truth(bm.joints.len())).unwrap();
    let mut ws = Workspace::new(&sys);
    let q = bm
        .solve(&sys, Level::T1, loads, bm.rest.as_slice(), &mut ws)
        .unwrap();
    let points = film_points();
    let (proj, _) = bm.project(&points, q.as_slice(), None).unwrap();
    let place = Placement {
        phi: 0.03,
        t: Vector2::new(0.21, 0.93),
    };
    let mut noise = Noise(seed);
    let pts: BTreeMap<FilmPoint, Vector2<f64>> = points
        .into_iter()
        .zip(proj)
        .map(|(p, m)| {
            let e = Vector2::new(noise.normal(), noise.normal()) * NOISE;
            (p, place.apply(&m) + e)
        })
        .collect();
    std::fs::write(
        path,
        radiograph::write_csv(&pts, Projection::Orthographic, film, &[]),
    )
    .unwrap();
}

/// The neutral, left and right films in `dir`.
fn films(dir: &Path) -> [PathBuf; 3] {
    let doc = Document::read(base_path()).unwrap();
    let bm = BendModel::new(&doc.model().unwrap()).unwrap();
    let paths = [
        dir.join("film_neutral.csv"),
        dir.join("film_left.csv"),
        dir.join("film_right.csv"),
    ];
    // left bending: T1 towards the patient's left (ground -Z), tilted so
    write_film(&bm, [0.0; 3], 11, "neutral", &paths[0]);
    write_film(&bm, [-7.0, -1.0, 0.0], 12, "left bending", &paths[1]);
    write_film(&bm, [7.0, 1.0, 0.0], 13, "right bending", &paths[2]);
    paths
}

fn options() -> FlexibilityOptions {
    FlexibilityOptions {
        noise: NOISE,
        ..FlexibilityOptions::default()
    }
}

#[test]
fn the_neutral_film_alone_gives_no_stiffness_and_says_so() {
    let tmp = tempfile::tempdir().unwrap();
    let [neutral, _, _] = films(tmp.path());
    let out = tmp.path().join("out");
    let o = Command::new(common::bin())
        .arg("flexibility")
        .arg("--model")
        .arg(base_path())
        .arg("--film")
        .arg(&neutral)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "neutral alone succeeded: {err}");
    assert!(err.contains("no stiffness can be estimated"), "{err}");
    assert!(err.contains("no film bends the spine"), "{err}");
    assert!(!out.join("flexibility.json").exists());
    assert!(!out.join("stiffness.toml").exists());
    // the same film with the model's own stiffness is a valid (uniform) run
    let r = flexibility::flexibility(
        &Document::read(base_path()).unwrap().model().unwrap(),
        &[radiograph::read(&neutral).unwrap()],
        &[],
        &FlexibilityOptions {
            uniform: true,
            ..options()
        },
    )
    .unwrap();
    assert!(r.stiffness_toml.is_none() && r.report.joints.is_empty());
}

#[test]
fn one_bending_film_gives_wider_intervals_than_two() {
    let tmp = tempfile::tempdir().unwrap();
    let [neutral, left, right] = films(tmp.path());
    let model = Document::read(base_path()).unwrap().model().unwrap();
    let read = |p: &PathBuf| radiograph::read(p).unwrap();
    let widths = |films: &[PathBuf]| -> BTreeMap<String, f64> {
        let films: Vec<_> = films.iter().map(read).collect();
        let r = flexibility::flexibility(&model, &films, &[], &options()).unwrap();
        r.report
            .joints
            .iter()
            .map(|j| (j.joint.clone(), (j.ci95[1] / j.ci95[0]).ln()))
            .collect()
    };
    let one = widths(&[neutral.clone(), left.clone()]);
    let two = widths(&[neutral, left, right]);
    assert_eq!(one.len(), 17);
    assert_eq!(
        one.keys().collect::<Vec<_>>(),
        two.keys().collect::<Vec<_>>()
    );
    let mut narrower = 0;
    for (j, w1) in &one {
        let w2 = two[j];
        println!("{j}: 95% interval log-width {w1:.3} (one film), {w2:.3} (two)");
        narrower += usize::from(w2 < *w1);
    }
    let mean = |w: &BTreeMap<String, f64>| w.values().sum::<f64>() / w.len() as f64;
    let (m1, m2) = (mean(&one), mean(&two));
    println!("mean log-width {m1:.3} (one film), {m2:.3} (two); {narrower} of 17 joints narrower");
    // information adds: narrower on the whole, and for most joints (a
    // joint the prior already bounds may stay as wide)
    assert!(
        m2 < 0.85 * m1,
        "mean log-width {m2:.3} (two) vs {m1:.3} (one)"
    );
    assert!(
        narrower >= 12,
        "{narrower} of 17 joints narrower with two films"
    );
}

#[test]
fn stiffness_table_writes_the_estimated_bushings_opensim_loads() {
    let tmp = tempfile::tempdir().unwrap();
    let [neutral, left, right] = films(tmp.path());
    let out = tmp.path().join("out");
    common::run_ok(&[
        "flexibility".as_ref(),
        "--model".as_ref(),
        base_path().as_os_str(),
        "--film".as_ref(),
        neutral.as_os_str(),
        "--film".as_ref(),
        left.as_os_str(),
        "--film".as_ref(),
        right.as_os_str(),
        "--noise-mm".as_ref(),
        "0.5".as_ref(),
        "--out".as_ref(),
        out.as_os_str(),
    ]);
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("flexibility.json")).unwrap())
            .unwrap();
    let joints = report["joints"].as_array().unwrap();
    assert_eq!(joints.len(), 17);
    let personalised = tmp.path().join("personalised.osim");
    common::run_ok(&[
        "stiffness".as_ref(),
        base_path().as_os_str(),
        "--table".as_ref(),
        out.join("stiffness.toml").as_os_str(),
        "--out".as_ref(),
        personalised.as_os_str(),
    ]);
    let Some(py) = common::opensim_python() else {
        return;
    };
    // OpenSim's reading of the personalised and the base model's bushings
    let k = common::run_py(
        &py,
        "bushing_stiffness.py",
        &[personalised.to_str().unwrap()],
    );
    let k0 = common::run_py(
        &py,
        "bushing_stiffness.py",
        &[base_path().to_str().unwrap()],
    );
    let get = |v: &serde_json::Value, j: &str, d: usize| -> f64 {
        v[format!("{j}_bushing")][d].as_f64().unwrap()
    };
    let names: Vec<&str> = joints
        .iter()
        .map(|j| j["joint"].as_str().unwrap())
        .collect();
    // relative stiffness: lateral bending stiffness over its geometric mean
    let log_mean = names.iter().map(|j| get(&k, j, 0).ln()).sum::<f64>() / names.len() as f64;
    for (j, name) in joints.iter().zip(&names) {
        let rel = j["relative_stiffness"].as_f64().unwrap();
        let opensim_rel = (get(&k, name, 0).ln() - log_mean).exp();
        assert!(
            (opensim_rel / rel - 1.0).abs() < 1e-6,
            "{name}: OpenSim's relative stiffness {opensim_rel} vs flexibility.json {rel}"
        );
        // one multiplier on the three rotations; translations the model's
        let m = get(&k, name, 0) / get(&k0, name, 0);
        for d in 1..3 {
            let md = get(&k, name, d) / get(&k0, name, d);
            assert!((md / m - 1.0).abs() < 1e-6, "{name} dof {d}: {md} vs {m}");
        }
        for d in 3..6 {
            assert!((get(&k, name, d) / get(&k0, name, d) - 1.0).abs() < 1e-9);
        }
    }
    // and the estimate is near the truth's ratios (0.5 mm noise, two films)
    let t = truth(17);
    let tmean = t.iter().map(|x| x.ln()).sum::<f64>() / 17.0;
    let inside = joints
        .iter()
        .enumerate()
        .filter(|(i, j)| {
            let ci = j["ci95"].as_array().unwrap();
            let k0j = get(&k0, names[*i], 0);
            let k0_mean = names.iter().map(|n| get(&k0, n, 0).ln()).sum::<f64>() / 17.0;
            let truth_rel = ((t[*i].ln() - tmean) + (k0j.ln() - k0_mean)).exp();
            ci[0].as_f64().unwrap() <= truth_rel && truth_rel <= ci[1].as_f64().unwrap()
        })
        .count();
    println!("truth inside the 95% interval for {inside} of 17 joints");
    assert!(
        inside >= 13,
        "truth inside the 95% interval for {inside} of 17 joints"
    );
}

/// A film rewritten point by point: `edit` returns the new name and
/// position, or None to drop the point.
fn rewrite(
    src: &Path,
    dst: &Path,
    edit: impl Fn(FilmPoint, Vector2<f64>) -> Option<(FilmPoint, Vector2<f64>)>,
) {
    let r = radiograph::read(src).unwrap();
    let pts: BTreeMap<FilmPoint, Vector2<f64>> = r
        .points
        .iter()
        .filter_map(|(p, (x, _))| edit(*p, *x))
        .collect();
    std::fs::write(
        dst,
        radiograph::write_csv(&pts, Projection::Orthographic, "edited", &[]),
    )
    .unwrap();
}

#[test]
fn films_that_cannot_be_placed_or_contradict_the_model_are_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let [neutral, left, _] = films(tmp.path());
    let model = Document::read(base_path()).unwrap().model().unwrap();
    let run = |bad: &Path| -> String {
        let films = [
            radiograph::read(&neutral).unwrap(),
            radiograph::read(bad).unwrap(),
        ];
        match flexibility::flexibility(&model, &films, &[], &options()) {
            Ok(_) => panic!("{} accepted", bad.display()),
            Err(e) => e.to_string(),
        }
    };
    // no pelvic landmarks: nothing to place the film on
    let p = tmp.path().join("no_pelvis.csv");
    rewrite(&left, &p, |q, x| (!q.is_pelvic()).then_some((q, x)));
    let e = run(&p);
    assert!(e.contains("cannot place the film on the pelvis"), "{e}");
    assert!(e.contains("no_pelvis.csv"), "{e}");
    // left and right swapped (u mirrored)
    let p = tmp.path().join("mirrored.csv");
    rewrite(&left, &p, |q, x| Some((q, Vector2::new(-x.x, x.y))));
    let e = run(&p);
    assert!(e.contains("left and right are swapped"), "{e}");
    // two vertebrae's labels exchanged: the spine contradicts the model
    let p = tmp.path().join("swapped_levels.csv");
    let swap = |l: Level| match l {
        Level::T4 => Level::T10,
        Level::T10 => Level::T4,
        other => other,
    };
    rewrite(&left, &p, |q, x| match q {
        FilmPoint::Landmark(id) => Some((
            FilmPoint::Landmark(LandmarkId::new(swap(id.level), id.code)),
            x,
        )),
        other => Some((other, x)),
    });
    let e = run(&p);
    assert!(e.contains("contradicts the model"), "{e}");
    assert!(e.contains("swapped_levels.csv"), "{e}");
}
