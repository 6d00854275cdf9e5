//! Multi-file outputs are all or nothing: a command whose writes fail
//! part-way (here a file-size limit, `ulimit -f`, so that the small files
//! of the set fit and a larger one fails with EFBIG: the error a full disk
//! gives late in a set) exits non-zero and leaves no file of the set.

use super::*;

/// Run `osim-spine args` with files limited to `kb` KiB (SIGXFSZ ignored,
/// so the write fails with an error instead of killing the process).
fn run_limited(kb: u64, args: &[&str]) -> Output {
    Command::new("sh")
        .arg("-c")
        .arg("trap '' XFSZ; ulimit -f \"$1\"; shift; exec \"$@\"")
        .arg("sh")
        .arg((kb * 2).to_string()) // 512-byte blocks (POSIX)
        .arg(common::bin())
        .args(args)
        .output()
        .unwrap()
}

/// Every file under `dir` (relative paths), recursively.
fn files_under(dir: &Path) -> Vec<String> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        let Ok(rd) = std::fs::read_dir(&d) else {
            continue;
        };
        for e in rd.flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.push(p.strip_prefix(dir).unwrap().display().to_string());
            }
        }
    }
    out.sort();
    out
}

/// The write failed (named), and nothing of the set is left in `out`.
fn assert_nothing_left(o: &Output, out: &Path) {
    let t = text(o);
    assert_ne!(o.status.code(), Some(0), "accepted:\n{t}");
    assert!(!t.contains("panicked"), "panic:\n{t}");
    assert!(t.contains("File too large"), "not the write error:\n{t}");
    assert_eq!(files_under(out), Vec::<String>::new(), "left behind:\n{t}");
}

#[test]
fn palpate_writes_all_or_nothing() {
    let Some(meshes) = common::shared("scoliosis-dev/D01_thoracic45/segmentation/meshes") else {
        return;
    };
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("out");
    // CSV (2 KB) and report (10 KB) fit, the figures (50 KB) do not.
    let lm = out.join("lm.csv");
    let o = run_limited(
        24,
        &["palpate", s(&meshes), "--levels", "L4..S1", "--out", s(&lm)],
    );
    assert_nothing_left(&o, &out);
    assert!(!out.exists(), "the folder it created is left");
}

#[test]
fn generate_writes_all_or_nothing() {
    let d = tempfile::tempdir().unwrap();
    let root = common::repo_root();
    let out = d.path().join("g");
    std::fs::create_dir(&out).unwrap();
    // The meshes (65 KB) fit, the model (270 KB) does not.
    let o = run_limited(
        128,
        &[
            "generate",
            "--base",
            s(&root.join("base_model")),
            "--landmarks",
            s(&root.join("fixtures/example-scoliosis.csv")),
            "--out",
            s(&out.join("p.osim")),
        ],
    );
    assert_nothing_left(&o, &out);
}

#[test]
fn diagnose_writes_all_or_nothing() {
    let Some(dev) = common::shared("diagnose-dev/dev-01") else {
        return;
    };
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("dg");
    // diagnosis.json (40 KB) and report.md fit, the residual map (110 KB) does not.
    let o = run_limited(64, &["diagnose", s(&dev), "--quiet", "--out", s(&out)]);
    assert_nothing_left(&o, &out);
    assert!(!out.exists(), "the folder it created is left");
}

#[test]
fn convert_writes_all_or_nothing() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("cv");
    // The meshes copied into Geometry/ (65 KB) fit, the model (260 KB) does not.
    let model = common::repo_root().join("base_model/base.osim");
    let o = run_limited(128, &["convert", s(&model), s(&out.join("m.osim"))]);
    assert_nothing_left(&o, &out);
    assert!(!out.exists(), "the folders it created are left");
}

#[test]
fn simulate_writes_all_or_nothing() {
    let d = tempfile::tempdir().unwrap();
    let m = d.path().join("m.osim");
    std::fs::write(&m, corpus_model()).unwrap();
    // Many small static cases, then one long dynamic run whose .sto is
    // larger than the limit.
    let mut load = String::new();
    for i in 0..12 {
        load += &format!("[[case]]\nid = \"c{i}\"\nbody = \"L5\"\nforce = [0, -{i}, 0]\n");
    }
    let load_path = d.path().join("load.toml");
    std::fs::write(&load_path, load).unwrap();
    let out = d.path().join("sim");
    let o = run_limited(
        1,
        &["simulate", s(&m), "--load", s(&load_path), "--out", s(&out)],
    );
    assert_nothing_left(&o, &out);
    assert!(!out.exists(), "the folder it created is left");
}
