//! `generate` on a set palpated by another protocol: every `SP` of the README example moved 5 mm posterior is reported
//! as a protocol mismatch of the code SP, with its offset, and compensated:
//! the vertebrae are refitted with every SP marker moved by that offset,
//! which leaves the SP residuals at the noise; the example as shipped has
//! none.

mod common;

use nalgebra::Vector3;
use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;

/// The README example with every vertebra's SP moved `mm` away from its SA.
fn shifted_sp(mm: f64) -> String {
    let text = std::fs::read_to_string(common::repo_root().join("fixtures/example-scoliosis.csv"))
        .unwrap();
    let mut pts: BTreeMap<String, Vector3<f64>> = BTreeMap::new();
    for l in text
        .lines()
        .filter(|l| !l.starts_with('#') && !l.starts_with("name"))
    {
        let f: Vec<&str> = l.split(',').collect();
        pts.insert(
            f[0].into(),
            Vector3::new(
                f[1].parse().unwrap(),
                f[2].parse().unwrap(),
                f[3].parse().unwrap(),
            ),
        );
    }
    let mut out = String::new();
    for l in text.lines() {
        let name = l.split(',').next().unwrap_or("");
        match name.strip_suffix("_SP").filter(|lv| *lv != "S1") {
            Some(lv) => {
                let d = (pts[name] - pts[&format!("{lv}_SA")]).normalize();
                let p = pts[name] + d * mm;
                out.push_str(&format!("{name},{},{},{}\n", p.x, p.y, p.z));
            }
            None => out.push_str(&format!("{l}\n")),
        }
    }
    out
}

fn generate(landmarks: &Path, out: &Path) -> (String, serde_json::Value) {
    let o = Command::new(common::bin())
        .args(["generate", "--landmarks"])
        .arg(landmarks)
        .arg("--out")
        .arg(out.join("patient.osim"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let rep = std::fs::read_to_string(out.join("patient_report.json")).unwrap();
    (
        String::from_utf8_lossy(&o.stderr).to_string(),
        serde_json::from_str(&rep).unwrap(),
    )
}

#[test]
fn a_shifted_code_is_reported_by_code_not_as_outliers() {
    let tmp = tempfile::tempdir().unwrap();
    let f = tmp.path().join("shifted.csv");
    std::fs::write(&f, shifted_sp(5.0)).unwrap();
    let (err, rep) = generate(&f, &tmp.path().join("a"));
    let m = rep["protocol_mismatches"].as_array().unwrap();
    assert_eq!(m.len(), 1, "{m:?}");
    assert_eq!(m[0]["code"], "SP");
    assert_eq!(m[0]["kind"], "protocol");
    assert_eq!(m[0]["compensated"], true);
    assert_eq!(m[0]["levels"].as_array().unwrap().len(), 9, "{m:?}");
    // Its offset, as the compensation settled it: about 5 mm posterior.
    let x = m[0]["mean_offset_mm"][0].as_f64().unwrap();
    assert!((-6.0..=-4.0).contains(&x), "offset {x} mm anterior");
    assert!(err.contains("protocol mismatch: every SP sits"), "{err}");
    // No SP is rejected as a separate outlier; compensated, every SP is
    // used and fitted as well as the example's landmarks (1 mm noise).
    assert!(
        !rep["outliers"].to_string().contains("_SP"),
        "{}",
        rep["outliers"]
    );
    let sp: Vec<&serde_json::Value> = rep["landmark_residuals"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|r| {
            r["landmark"].as_str().unwrap().ends_with("_SP")
                && !r["landmark"].as_str().unwrap().starts_with("S1")
        })
        .collect();
    assert_eq!(sp.len(), 9);
    assert!(sp.iter().all(|r| r["used"] == true), "{sp:?}");
    let worst = sp
        .iter()
        .map(|r| r["distance_mm"].as_f64().unwrap())
        .fold(0.0, f64::max);
    assert!(worst < 4.0, "SP residual {worst:.2} mm after compensation");
    // The example as shipped has no mismatch.
    let ex = common::repo_root().join("fixtures/example-scoliosis.csv");
    let (_, rep0) = generate(&ex, &tmp.path().join("b"));
    assert_eq!(rep0["protocol_mismatches"], serde_json::json!([]));
    assert!(rep0["shape"]["cobb"]["angle_deg"].is_number());
}

/// Vertebral centres of a generate report, by level (m).
fn centres(r: &serde_json::Value) -> BTreeMap<String, Vector3<f64>> {
    r["centres"]
        .as_object()
        .unwrap()
        .iter()
        .map(|(k, v)| {
            let c: Vec<f64> = v
                .as_array()
                .unwrap()
                .iter()
                .map(|x| x.as_f64().unwrap())
                .collect();
            (k.clone(), Vector3::new(c[0], c[1], c[2]))
        })
        .collect()
}

/// Compensated, the set with every SP 5 mm posterior places the vertebral
/// centres where the example does (left uncompensated, the shifted SPs pull
/// the fits and one is rejected as an outlier).
#[test]
fn a_compensated_code_leaves_the_vertebral_centres_in_place() {
    let tmp = tempfile::tempdir().unwrap();
    let f = tmp.path().join("shifted.csv");
    std::fs::write(&f, shifted_sp(5.0)).unwrap();
    let (_, rep) = generate(&f, &tmp.path().join("a"));
    let ex = common::repo_root().join("fixtures/example-scoliosis.csv");
    let (_, rep0) = generate(&ex, &tmp.path().join("b"));
    let (c1, c0) = (centres(&rep), centres(&rep0));
    let moved = c0
        .iter()
        .map(|(k, c)| (c1[k] - c).norm() * 1e3)
        .fold(0.0, f64::max);
    eprintln!("vertebral centres moved at most {moved:.2} mm");
    assert!(moved < 0.8, "a vertebral centre moved {moved:.2} mm");
}
