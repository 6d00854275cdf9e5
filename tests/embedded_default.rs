//! The default base model is compiled into the binary: `generate` and
//! `variability` work from a folder outside the repository with no
//! `--base` (the binary reads nothing from the source tree), and `--base`
//! still overrides it.

mod common;

use std::path::Path;
use std::process::Command;

fn run_in(dir: &Path, args: &[&str]) -> std::process::Output {
    Command::new(common::bin())
        .current_dir(dir)
        .args(args)
        .output()
        .unwrap()
}

fn example() -> String {
    common::repo_root()
        .join("fixtures/example-scoliosis.csv")
        .display()
        .to_string()
}

#[test]
fn generate_runs_outside_the_repository_without_base() {
    let d = tempfile::tempdir().unwrap();
    let o = run_in(
        d.path(),
        &[
            "generate",
            "--landmarks",
            &example(),
            "--out",
            "x/patient.osim",
        ],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let out = d.path().join("x");
    assert!(out.join("patient.osim").is_file());
    // Every mesh of the default base travels with the model.
    let n_meshes = std::fs::read_dir(out.join("Geometry")).unwrap().count();
    let n_base = osim_spine::embedded::files::BASE_MODEL
        .iter()
        .filter(|(n, _)| n.ends_with(".vtp"))
        .count();
    assert_eq!(n_meshes, n_base);
    // The model is named after the patient's landmark file; the console
    // states the self-check and the levels above the field of view.
    let osim = std::fs::read_to_string(out.join("patient.osim")).unwrap();
    assert!(osim.contains("<Model name=\"example-scoliosis\""));
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        stdout.contains("self-check: bushing deflection"),
        "{stdout}"
    );
    assert!(
        stdout.contains("T8 T7 T6 T5 T4 T3 T2 T1 not measured"),
        "{stdout}"
    );
    // The report names the embedded base.
    let rep = std::fs::read_to_string(out.join("patient_report.json")).unwrap();
    assert!(
        rep.contains(osim_spine::embedded::EMBEDDED_BASE_LABEL),
        "{rep}"
    );
}

#[test]
fn base_overrides_the_embedded_default() {
    let d = tempfile::tempdir().unwrap();
    let base = common::repo_root().join("base_model");
    let o = run_in(
        d.path(),
        &[
            "generate",
            "--base",
            base.to_str().unwrap(),
            "--landmarks",
            &example(),
            "--out",
            "p.osim",
            "--no-self-check",
        ],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let rep = std::fs::read_to_string(d.path().join("p_report.json")).unwrap();
    // the report names the base file (by name only: determinism), not the embedded one
    assert!(rep.contains("\"base_model\": \"base.osim\""), "{rep}");
    assert!(
        !rep.contains(osim_spine::embedded::EMBEDDED_BASE_LABEL),
        "{rep}"
    );
    // A --base that does not exist is an error naming it, not a fallback.
    let o = run_in(
        d.path(),
        &[
            "generate",
            "--base",
            "nowhere",
            "--landmarks",
            &example(),
            "--out",
            "q.osim",
        ],
    );
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("nowhere"));
}

#[test]
fn variability_runs_outside_the_repository_without_base() {
    let d = tempfile::tempdir().unwrap();
    // Three palpations of the example differing in one coordinate (the
    // same file twice is refused).
    let text = std::fs::read_to_string(example()).unwrap();
    let sets: Vec<String> = (1..=3)
        .map(|k| {
            let p = d.path().join(format!("p{k}.csv"));
            std::fs::write(
                &p,
                text.replacen("T9_SEC,-11.90", &format!("T9_SEC,-11.9{k}"), 1),
            )
            .unwrap();
            p.display().to_string()
        })
        .collect();
    let o = run_in(
        d.path(),
        &[
            "variability",
            &sets[0],
            &sets[1],
            &sets[2],
            "--out",
            "var",
            "--jobs",
            "1",
        ],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(d.path().join("var/variability.json").is_file());
}
