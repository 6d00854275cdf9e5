//! `osim-spine variability` model propagation (thesis Tables 5.6-5.8):
//! one generated model per palpation, evaluated against a truth or the
//! consensus model. Palpations are simulated from a known spine: the
//! default base model posed by forward kinematics into the README's
//! example scoliosis ([`posed_example`]), its markers palpated with
//! Gaussian noise; the truth centres and landmarks are the posed model's.

mod common;

use nalgebra::{Point3, Vector3};
use osim_spine::evaluate::propagation::{propagate, Propagated, PropagationOptions};
use osim_spine::evaluate::variability::PalpationSet;
use osim_spine::evaluate::{metrics, Truth};
use osim_spine::generate::example::posed_example;
use osim_spine::landmarks::{Code, LandmarkSet, Level};
use osim_spine::osim::Document;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use std::collections::BTreeMap;
use std::path::PathBuf;

fn base() -> Document {
    Document::read(common::repo_root().join("base_model/base.osim")).unwrap()
}

/// The posed spine: landmarks T9..S1 and centres T9..L5 (m, base model ground).
fn posed(base: &Document) -> (LandmarkSet, BTreeMap<Level, Point3<f64>>) {
    let (set, centres) = posed_example(base).unwrap();
    let mut s = LandmarkSet::new();
    for (id, p) in &set.points {
        if id.level >= Level::T9 {
            s.points.insert(*id, *p);
        }
    }
    let c = centres
        .into_iter()
        .filter(|(l, _)| *l >= Level::T9)
        .collect();
    (s, c)
}

/// `set` with N(0, sd) noise (m) on every coordinate.
fn noisy(set: &LandmarkSet, sd: f64, seed: u64) -> LandmarkSet {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let n = Normal::new(0.0, sd).unwrap();
    let mut out = set.clone();
    for p in out.points.values_mut() {
        *p += Vector3::new(n.sample(&mut rng), n.sample(&mut rng), n.sample(&mut rng));
    }
    out
}

fn pal(op: &str, rep: u32, set: LandmarkSet) -> PalpationSet {
    PalpationSet {
        operator: op.into(),
        repetition: rep,
        source: PathBuf::from(format!("sim-{op}-{rep}")),
        set,
    }
}

/// Operators A and B, repetitions 1..=reps, each palpation from `f`.
fn design(reps: u32, f: &mut dyn FnMut(u64) -> LandmarkSet) -> Vec<PalpationSet> {
    let mut out = Vec::new();
    let mut k = 0;
    for op in ["A", "B"] {
        for rep in 1..=reps {
            k += 1;
            out.push(pal(op, rep, f(k)));
        }
    }
    out
}

fn groups(p: &Propagated) -> Vec<String> {
    p.report
        .groups
        .iter()
        .map(|g| format!("{} {}", g.kind, g.within))
        .collect()
}

#[test]
fn identical_palpations_give_identical_models_equal_to_the_consensus() {
    let base = base();
    let (set, _) = posed(&base);
    let one = noisy(&set, 0.001, 7);
    let pals = design(3, &mut |_| one.clone());
    let p = propagate(&pals, &base, &PropagationOptions::default()).unwrap();
    let r = &p.report;
    assert_eq!(r.reference.kind, "consensus");
    assert_eq!((r.models, r.failed), (6, 0));
    // Thesis grouping: overall, intra per operator, inter per repetition.
    assert_eq!(
        groups(&p),
        [
            "overall all",
            "intra operator A",
            "intra operator B",
            "inter repetition 1",
            "inter repetition 2",
            "inter repetition 3"
        ]
    );
    let rc = r.reference.cobb.as_ref().unwrap();
    for g in &r.groups {
        let c = g.centre_rmse_mm.as_ref().unwrap();
        assert!(c.median < 1e-6 && c.iqr == 0.0, "{g:?}");
        for m in [
            &g.sagittal_curve_rmse_mm,
            &g.frontal_curve_rmse_mm,
            &g.sagittal_r2,
            &g.frontal_r2,
            &g.cobb_deg,
            &g.lordosis_deg,
        ] {
            assert_eq!(m.as_ref().unwrap().iqr, 0.0, "{g:?}");
        }
        assert!((g.sagittal_r2.as_ref().unwrap().median - 1.0).abs() < 1e-9);
        // The consensus model is the same model: same Cobb angle.
        let gc = g.cobb_deg.as_ref().unwrap().median;
        assert!(
            (gc - rc.angle_deg).abs() < 1e-6,
            "{} {}: models {gc} deg, consensus {rc:?}",
            g.kind,
            g.within
        );
        // identical values: the SD is zero up to the rounding of their mean
        assert!(g.cobb_mean_sd_deg.as_ref().unwrap().sd < 1e-9, "{g:?}");
    }
}

#[test]
fn centre_error_grows_with_palpation_noise_and_cobb_stays_near_the_truth() {
    let base = base();
    let (set, centres) = posed(&base);
    let truth = Truth {
        source: "posed base model".into(),
        centres,
        landmarks: Some(set.clone()),
    };
    // The truth's own Cobb angle, automatic end vertebrae (independent of
    // the generator: the posed model's markers).
    let tc = metrics::cobb(&set, None).unwrap();
    assert!(tc.angle_deg.abs() > 40.0, "{tc:?}");
    let opts = PropagationOptions {
        truth: Some(truth),
        ..PropagationOptions::default()
    };
    let mut medians = Vec::new();
    for (i, sd_mm) in [0.0, 0.5, 1.0, 2.0].into_iter().enumerate() {
        let pals = design(4, &mut |k| noisy(&set, sd_mm * 1e-3, 1000 * i as u64 + k));
        let p = propagate(&pals, &base, &opts).unwrap();
        let r = &p.report;
        assert_eq!(r.reference.kind, "truth");
        assert_eq!(r.models, 8, "{:?}", r.rows);
        assert_eq!(
            r.cobb_ends,
            format!("{}-{} (truth landmarks)", tc.upper, tc.lower)
        );
        let all = &r.groups[0];
        let rmse = all.centre_rmse_mm.as_ref().unwrap().median;
        let cobb = all.cobb_deg.as_ref().unwrap().median;
        eprintln!(
            "noise {sd_mm} mm: median centre RMSE {rmse:.3} mm (IQR {:.3}), Cobb {cobb:.2} deg (truth {:.2}), sagittal R2 {:.4}",
            all.centre_rmse_mm.as_ref().unwrap().iqr,
            tc.angle_deg,
            all.sagittal_r2.as_ref().unwrap().median
        );
        assert!(
            (cobb - tc.angle_deg).abs() < 2.5,
            "noise {sd_mm} mm: Cobb {cobb} vs truth {}",
            tc.angle_deg
        );
        medians.push(rmse);
    }
    // Noise-free palpations rebuild the posed spine.
    assert!(medians[0] < 0.1, "{medians:?}");
    for w in medians.windows(2) {
        assert!(w[0] < w[1], "not monotone in the noise: {medians:?}");
    }
    // A linear error propagation: twice the noise, about twice the error.
    let ratio = medians[3] / medians[2];
    assert!((1.4..2.8).contains(&ratio), "{medians:?}");
}

#[test]
fn failing_palpations_are_listed_and_the_others_evaluated() {
    let base = base();
    let (set, _) = posed(&base);
    let mut pals = design(2, &mut |k| noisy(&set, 0.001, 50 + k));
    // A palpation missing a required landmark ...
    let mut missing = noisy(&set, 0.001, 90);
    missing
        .points
        .remove(&osim_spine::landmarks::LandmarkId::new(
            Level::L2,
            Code::SEC,
        ));
    pals.push(pal("C", 1, missing));
    // ... and one whose L1 landmarks all sit on one point.
    let mut collapsed = noisy(&set, 0.001, 91);
    let c = collapsed.get(Level::L1, Code::SEC).unwrap();
    for (id, p) in collapsed.points.iter_mut() {
        if id.level == Level::L1 {
            *p = c;
        }
    }
    pals.push(pal("C", 2, collapsed));
    let p = propagate(&pals, &base, &PropagationOptions::default()).unwrap();
    let r = &p.report;
    assert_eq!((r.palpations, r.models, r.failed), (6, 4, 2));
    assert!(r.rows[..4].iter().all(|x| x.ok && x.metrics.is_some()));
    let e4 = r.rows[4].error.as_deref().unwrap();
    assert!(!r.rows[4].ok && e4.contains("L2_SEC"), "{e4}");
    assert!(!r.rows[5].ok && r.rows[5].metrics.is_none());
    assert!(!r.rows[5].error.as_deref().unwrap().is_empty());
    // The consensus (median) still has every landmark: 6 palpations hold
    // L2_SEC five times.
    assert!(r.consensus.generated && r.consensus.left_out.is_empty());
    let all = &r.groups[0];
    assert_eq!((all.palpations, all.models), (6, 4));
    // Operator C's two failed palpations still form a group with no models.
    let c = r.groups.iter().find(|g| g.within == "operator C").unwrap();
    assert_eq!(c.models, 0);
    assert!(c.centre_rmse_mm.is_none());
    // Nothing usable at all: an error naming the palpations.
    let bad: Vec<PalpationSet> = pals[4..].to_vec();
    let e = propagate(&bad, &base, &PropagationOptions::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("L2_SEC") || e.contains("consensus"), "{e}");
}

/// The example patient's landmark file with extra noise, as a palpation
/// file of `op`/`rep` (LPS, mm, as a CT viewer writes it).
fn example_palpation(op: &str, rep: u32, sd_mm: f64, seed: u64, drop: Option<&str>) -> String {
    let text = std::fs::read_to_string(common::repo_root().join("fixtures/example-scoliosis.csv"))
        .unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let n = Normal::new(0.0, sd_mm).unwrap();
    let mut out = format!("# operator: {op}\n# repetition: {rep}\n");
    for line in text.lines() {
        let f: Vec<&str> = line.split(',').collect();
        let num: Option<Vec<f64>> = (f.len() == 4)
            .then(|| f[1..].iter().map(|v| v.parse().ok()).collect())
            .flatten();
        match num {
            Some(v) => {
                if Some(f[0]) == drop {
                    continue;
                }
                out.push_str(&format!(
                    "{},{:.3},{:.3},{:.3}\n",
                    f[0],
                    v[0] + n.sample(&mut rng),
                    v[1] + n.sample(&mut rng),
                    v[2] + n.sample(&mut rng)
                ));
            }
            None => {
                out.push_str(line);
                out.push('\n');
            }
        }
    }
    out
}

#[test]
fn cli_with_truth_is_deterministic_and_reports_failures() {
    let d = tempfile::tempdir().unwrap();
    let mut files = Vec::new();
    let mut seed = 0;
    for op in ["A", "B"] {
        for rep in 1..=2 {
            seed += 1;
            let f = d.path().join(format!("{op}{rep}.csv"));
            std::fs::write(&f, example_palpation(op, rep, 0.5, seed, None)).unwrap();
            files.push(f.display().to_string());
        }
    }
    let f = d.path().join("C1.csv");
    std::fs::write(&f, example_palpation("C", 1, 0.5, 9, Some("L2_SEC"))).unwrap();
    files.push(f.display().to_string());
    let root = common::repo_root();
    let run = |out: &str, jobs: &str, extra: &[&str]| {
        let mut args: Vec<String> = vec!["variability".into()];
        args.extend(files.iter().cloned());
        for a in [
            "--base",
            &root.join("base_model").display().to_string(),
            "--truth",
            &root
                .join("fixtures/example-scoliosis-centres.csv")
                .display()
                .to_string(),
            "--jobs",
            jobs,
            "--out",
            &d.path().join(out).display().to_string(),
        ] {
            args.push(a.to_string());
        }
        args.extend(extra.iter().map(|s| s.to_string()));
        let o = std::process::Command::new(common::bin())
            .args(&args)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        String::from_utf8_lossy(&o.stdout).to_string()
    };
    let stdout = run("o1", "1", &["--write-models"]);
    run("o2", "2", &[]);
    assert!(
        stdout.contains("no model for ") && stdout.contains("operator C repetition 1"),
        "{stdout}"
    );
    for name in [
        "variability.json",
        "iqr_boxplot.svg",
        "model_errors_boxplot.svg",
        "model_r2_boxplot.svg",
        "model_angles_boxplot.svg",
        "model_centre_rmse_groups.svg",
    ] {
        let a = std::fs::read(d.path().join("o1").join(name)).unwrap();
        let b = std::fs::read(d.path().join("o2").join(name)).unwrap();
        assert!(a == b, "{name} differs between --jobs 1 and --jobs 2");
    }
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.path().join("o1/variability.json")).unwrap())
            .unwrap();
    let p = &json["model_propagation"];
    assert_eq!(p["reference"]["kind"], "truth");
    assert_eq!(p["models"], 4);
    assert_eq!(p["failed"], 1);
    assert!(p["rows"][4]["error"].as_str().unwrap().contains("L2_SEC"));
    // The example's single model is within ~0.6 mm of its truth; 0.5 mm
    // more palpation noise keeps the median well under 2 mm.
    let rmse = p["groups"][0]["centre_rmse_mm"]["median"].as_f64().unwrap();
    assert!(rmse > 0.0 && rmse < 2.0, "{rmse}");
    let names: Vec<String> = p["groups"]
        .as_array()
        .unwrap()
        .iter()
        .map(|g| {
            format!(
                "{} {}",
                g["kind"].as_str().unwrap(),
                g["within"].as_str().unwrap()
            )
        })
        .collect();
    assert!(
        names.contains(&"inter repetition 1".to_string()),
        "{names:?}"
    );
    assert!(names.contains(&"intra operator B".to_string()), "{names:?}");
    let models = d.path().join("o1/models");
    assert!(models.join("opA_rep1.osim").is_file());
    assert!(models.join("opB_rep2_report.json").is_file());
    assert!(!models.join("opC_rep1.osim").exists());
    let generated = Document::read(models.join("opA_rep1.osim")).unwrap();
    assert!(generated.model().unwrap().bodies.len() > 10);
    assert!(!d.path().join("o2/models").exists());
}
