//! `check --strict` on the shipped example and the noise-aware severity of
//! LM033 (an endplate centre outside its four extreme points).

mod common;

use osim_spine::landmarks::check::{check_raw, CheckReport, Severity};
use osim_spine::landmarks::io::parse_csv;
use std::path::Path;
use std::process::Command;

fn example_text() -> String {
    std::fs::read_to_string(common::repo_root().join("fixtures/example-scoliosis.csv")).unwrap()
}

fn check_text(text: &str) -> CheckReport {
    let pal = parse_csv(text, Path::new("example.csv")).unwrap();
    check_raw(&pal[0].raw)
}

/// The example with S1_SEC moved `dy` mm along the file's y axis (posterior in LPS).
fn with_s1_sec_moved(dy: f64) -> String {
    example_text()
        .lines()
        .map(|l| match l.strip_prefix("S1_SEC,") {
            Some(rest) => {
                let v: Vec<f64> = rest.split(',').map(|x| x.parse().unwrap()).collect();
                format!("S1_SEC,{},{},{}\n", v[0], v[1] + dy, v[2])
            }
            None => format!("{l}\n"),
        })
        .collect()
}

fn lm033(r: &CheckReport) -> Option<Severity> {
    r.findings
        .iter()
        .find(|f| f.code == "LM033")
        .map(|f| f.severity)
}

#[test]
fn strict_check_of_the_shipped_example_exits_2_for_its_planted_outlier_only() {
    let ex = common::repo_root().join("fixtures/example-scoliosis.csv");
    let o = Command::new(common::bin())
        .args(["check", "--strict", ex.to_str().unwrap()])
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    assert_eq!(o.status.code(), Some(2), "{out}");
    assert!(!out.contains(" error "), "{out}");
    assert!(out.contains("LM050 [L3_PTL]"), "{out}");
}

#[test]
fn lm033_severity_follows_palpation_noise() {
    // The shipped example has no endplate centre beyond noise.
    let shipped = lm033(&check_text(&example_text()));
    assert!(
        matches!(shipped, None | Some(Severity::Info)),
        "{shipped:?}"
    );
    // Move S1_SEC posteriorly until it first leaves its quadrilateral...
    let edge = (0..400)
        .map(|i| f64::from(i) * 0.1)
        .find(|d| lm033(&check_text(&with_s1_sec_moved(*d))).is_some())
        .expect("S1_SEC leaves its quadrilateral within 40 mm");
    // ...then 1.3 mm beyond it (within 2 mm noise) is information only...
    let near = check_text(&with_s1_sec_moved(edge + 1.3));
    assert_eq!(lm033(&near), Some(Severity::Info));
    // ...and 15 mm beyond it is far outside 3 SD of palpation noise.
    let far = check_text(&with_s1_sec_moved(edge + 15.0));
    assert_eq!(lm033(&far), Some(Severity::Error));
}
