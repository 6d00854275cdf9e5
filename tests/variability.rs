//! `osim-spine variability` on simulated repeated palpations with known
//! noise and a planted operator bias.

mod common;

use nalgebra::Vector3;
use osim_spine::evaluate::variability::{analyse, PalpationSet};
use osim_spine::landmarks::io::csv_string;
use osim_spine::landmarks::synth::{generate, SpineShape, SynthOptions};
use osim_spine::landmarks::{Code, Frame, Level, Units};
use std::path::PathBuf;

/// The thesis design: 2 operators x 10 repetitions + 3 operators x 3
/// (29 palpations), T9..S1, palpation noise SD `sd` m per coordinate.
/// Operator `C` places every SEC `bias` m too high (Y).
fn study(sd: f64, bias: f64) -> Vec<PalpationSet> {
    let mut out = Vec::new();
    let mut seed = 100;
    for (op, reps) in [("A", 10), ("B", 10), ("C", 3), ("D", 3), ("E", 3)] {
        for rep in 1..=reps {
            seed += 1;
            let mut set = generate(&SynthOptions {
                top: Level::T9,
                shape: SpineShape::lumbar_scoliosis(75.0),
                noise_sd: sd,
                seed,
            })
            .unwrap();
            if op == "C" {
                for (id, p) in set.points.iter_mut() {
                    if id.code == Code::SEC {
                        *p += Vector3::new(0.0, bias, 0.0);
                    }
                }
            }
            out.push(PalpationSet {
                operator: op.into(),
                repetition: rep,
                source: PathBuf::from("sim"),
                set,
            });
        }
    }
    out
}

#[test]
fn iqr_summary_matches_the_noise_that_was_put_in() {
    let r = analyse(&study(0.001, 0.0)).unwrap();
    assert_eq!(r.palpations, 29);
    // The population IQR of N(0, 1 mm) is 1.349 mm, but the sample IQR
    // (type 7) of 29 values is biased low: its median is 1.269 mm and its
    // quartiles 1.086 / 1.466 mm (Monte Carlo, 200000 samples of 29 standard
    // normals, numpy `quantile`). The median over 119 landmarks has a
    // standard error of ~0.035 mm.
    for axis in ["X", "Y", "Z"] {
        let s = r
            .summary
            .iter()
            .find(|s| s.group == "all" && s.axis == axis)
            .unwrap();
        assert!(
            (s.median_mm - 1.269).abs() < 0.12,
            "{axis}: {}",
            s.median_mm
        );
    }
    // Landmarks are far apart relative to 1 mm: ICC(2,1) near 1 everywhere.
    assert!(!r.icc.is_empty());
    for e in &r.icc {
        assert!(e.icc2_1 > 0.99, "{e:?}");
    }
    // Inter-operator for repetitions 1..3 (5 operators), 4..10 (2), intra for 5 operators.
    assert!(r
        .icc
        .iter()
        .any(|e| e.kind == "inter" && e.within == "repetition 3" && e.raters == 5));
    assert!(r
        .icc
        .iter()
        .any(|e| e.kind == "intra" && e.within == "operator A" && e.raters == 10));
    // Gaussian noise: Shapiro-Wilk rejects about 5% of the tests.
    let rate = r.normality_rejected_at_5pct as f64 / r.normality.len() as f64;
    assert!(rate < 0.12, "normality rejection rate {rate}");
    assert!(r.model_propagation.is_none());
}

#[test]
fn friedman_and_nemenyi_find_a_planted_operator_bias() {
    let r = analyse(&study(0.001, 0.004)).unwrap();
    // Inter-operator, repetition 1: SEC in Y differs for operator C.
    let t = r
        .friedman
        .iter()
        .find(|f| {
            f.kind == "inter"
                && f.within == "repetition 1"
                && f.marker == Code::SEC
                && f.axis == "Y"
        })
        .unwrap();
    assert!(t.p < 0.01, "{t:?}");
    assert_eq!(t.groups[0], "operator A");
    let c = t.posthoc.iter().find(|p| p.versus == "operator C").unwrap();
    assert!(c.z > 0.0 && c.p < 0.05, "{c:?}");
    // The unbiased coordinate of the same marker is not flagged as often:
    // across X and Z, most inter-operator SEC tests have p >= 0.05.
    let others: Vec<_> = r
        .friedman
        .iter()
        .filter(|f| f.kind == "inter" && f.marker == Code::SEC && (f.axis == "X" || f.axis == "Z"))
        .collect();
    let sig = others.iter().filter(|f| f.p < 0.05).count();
    assert!(sig * 3 <= others.len(), "{sig} of {}", others.len());
}

#[test]
fn cli_writes_json_and_svg_and_refuses_bad_input() {
    let d = tempfile::tempdir().unwrap();
    let mut files = Vec::new();
    for (i, p) in study(0.001, 0.0).iter().take(6).enumerate() {
        let mut text = csv_string(&p.set, Units::Millimetre, Frame::Lps);
        text = format!(
            "# operator: {}\n# repetition: {}\n{text}",
            p.operator, p.repetition
        );
        let f = d.path().join(format!("p{i}.csv"));
        std::fs::write(&f, text).unwrap();
        files.push(f);
    }
    let out = d.path().join("out");
    let mut args: Vec<String> = vec!["variability".into()];
    args.extend(files.iter().map(|f| f.display().to_string()));
    // Landmark statistics only (the models: tests/variability_models.rs).
    args.extend([
        "--no-models".into(),
        "--out".into(),
        out.display().to_string(),
    ]);
    let o = std::process::Command::new(common::bin())
        .args(&args)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("variability.json")).unwrap()).unwrap();
    assert_eq!(json["palpations"], 6);
    assert!(json["model_propagation"].is_null());
    assert!(!out.join("model_errors_boxplot.svg").exists());
    let svg = std::fs::read_to_string(out.join("iqr_boxplot.svg")).unwrap();
    assert!(svg.starts_with("<svg") && svg.contains("Euclidean"));
    // Byte-identical on a second run.
    let first = std::fs::read(out.join("variability.json")).unwrap();
    let o = std::process::Command::new(common::bin())
        .args(&args)
        .output()
        .unwrap();
    assert!(o.status.success());
    assert_eq!(first, std::fs::read(out.join("variability.json")).unwrap());
    // Same operator/repetition twice (in two files: the same file twice
    // is refused by its content): refused, nothing written.
    let out2 = d.path().join("out2");
    let again = d.path().join("again.csv");
    let copy = std::fs::read_to_string(&files[0]).unwrap() + "# a copy\n";
    std::fs::write(&again, copy).unwrap();
    let o = std::process::Command::new(common::bin())
        .args([
            "variability",
            &files[0].display().to_string(),
            &again.display().to_string(),
            "--out",
            &out2.display().to_string(),
        ])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("appears twice"));
    assert!(!out2.exists());
}
