//! Determinism of the main jobs: `generate`,
//! `diagnose` and `calibrate` give byte-identical output folders when rerun
//! from another working directory, with the input folder at another path,
//! and (diagnose, calibrate) with another `--jobs`. Every file of the output folder is
//! compared, byte for byte, and the two folders hold the same file names.
//! Inputs are copied under the same folder name, so the experiment name is
//! the same in both runs (the issue allows only that name to differ).

mod common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

/// Every file under `dir`, by path relative to it, with its bytes.
fn tree(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                let rel = p.strip_prefix(dir).unwrap().to_path_buf();
                out.insert(rel, std::fs::read(&p).unwrap());
            }
        }
    }
    out
}

/// Copy the files of `from` (one level) into a new folder `to`.
fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let p = e.unwrap().path();
        if p.is_file() {
            std::fs::copy(&p, to.join(p.file_name().unwrap())).unwrap();
        }
    }
}

/// Run the tool in `cwd` with `args`; panics with its stderr on failure.
fn run(cwd: &Path, args: &[&str]) {
    let o = Command::new(common::bin())
        .current_dir(cwd)
        .args(args)
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "{args:?} in {}: {}",
        cwd.display(),
        String::from_utf8_lossy(&o.stderr)
    );
}

/// The two output folders hold the same files with the same bytes.
fn assert_same_tree(a: &Path, b: &Path, what: &str) {
    let (ta, tb) = (tree(a), tree(b));
    assert!(!ta.is_empty(), "{what}: no output in {}", a.display());
    let names = |t: &BTreeMap<PathBuf, Vec<u8>>| t.keys().cloned().collect::<Vec<_>>();
    assert_eq!(names(&ta), names(&tb), "{what}: different file names");
    for (rel, bytes) in &ta {
        assert!(
            *bytes == tb[rel],
            "{what}: {} differs between the two runs",
            rel.display()
        );
    }
    println!("{what}: {} files byte-identical", ta.len());
}

/// Two work places: (root, first cwd, second cwd), the cwds unrelated to
/// the inputs' folders.
fn places() -> (tempfile::TempDir, PathBuf, PathBuf) {
    let tmp = tempfile::tempdir().unwrap();
    let (c1, c2) = (tmp.path().join("cwd1"), tmp.path().join("x/y/cwd2"));
    std::fs::create_dir_all(&c1).unwrap();
    std::fs::create_dir_all(&c2).unwrap();
    (tmp, c1, c2)
}

#[test]
fn generate_is_byte_identical_from_another_folder_and_path() {
    let (tmp, c1, c2) = places();
    let src = common::repo_root().join("fixtures/example-scoliosis.csv");
    let (in1, in2) = (tmp.path().join("in1"), tmp.path().join("deep/in2"));
    for d in [&in1, &in2] {
        std::fs::create_dir_all(d).unwrap();
        std::fs::copy(&src, d.join("example-scoliosis.csv")).unwrap();
    }
    let (o1, o2) = (tmp.path().join("out1"), tmp.path().join("o/out2"));
    for (cwd, input, out) in [(&c1, &in1, &o1), (&c2, &in2, &o2)] {
        let lm = input.join("example-scoliosis.csv");
        let model = out.join("patient.osim");
        run(
            cwd,
            &[
                "generate",
                "--landmarks",
                lm.to_str().unwrap(),
                "--out",
                model.to_str().unwrap(),
            ],
        );
    }
    assert_same_tree(&o1, &o2, "generate");
}

#[test]
fn diagnose_is_byte_identical_across_jobs_folders_and_paths() {
    let Some(dev) = common::shared("diagnose-dev/dev-09") else {
        return;
    };
    let (tmp, c1, c2) = places();
    let (e1, e2) = (tmp.path().join("a/dev-09"), tmp.path().join("b/c/dev-09"));
    copy_dir(&dev, &e1);
    copy_dir(&dev, &e2);
    let (o1, o2) = (tmp.path().join("out1"), tmp.path().join("o/out2"));
    for (cwd, exp, out, jobs) in [(&c1, &e1, &o1, "1"), (&c2, &e2, &o2, "2")] {
        let args = [
            "diagnose",
            exp.to_str().unwrap(),
            "--quiet",
            "--jobs",
            jobs,
            "--out",
            out.to_str().unwrap(),
        ];
        run(cwd, &args);
    }
    assert_same_tree(&o1, &o2, "diagnose");
}

#[test]
fn calibrate_is_byte_identical_across_jobs_folders_and_paths() {
    let Some(dev) = common::shared("diagnose-dev/dev-09") else {
        return;
    };
    let (tmp, c1, c2) = places();
    let (e1, e2) = (tmp.path().join("a/dev-09"), tmp.path().join("b/c/dev-09"));
    copy_dir(&dev, &e1);
    copy_dir(&dev, &e2);
    let (o1, o2) = (tmp.path().join("out1"), tmp.path().join("o/out2"));
    for (cwd, exp, out, jobs) in [(&c1, &e1, &o1, "1"), (&c2, &e2, &o2, "2")] {
        let args = [
            "calibrate",
            exp.to_str().unwrap(),
            "--starts",
            "2",
            "--jobs",
            jobs,
            "--out",
            out.to_str().unwrap(),
        ];
        run(cwd, &args);
    }
    assert_same_tree(&o1, &o2, "calibrate");
}
