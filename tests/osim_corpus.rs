//! Acceptance: malformed and hostile inputs (the checked-in corpus
//! `tests/corpus/osim/`, index `INDEX.tsv`, plus a generated 300 MB file)
//! each give a clear error naming the file and the element or line, a
//! non-zero exit from `osim-spine info` and `convert`, and no output file.

mod common;

use std::path::Path;
use std::process::Command;

fn run(args: &[&str]) -> (i32, String) {
    let o = Command::new(common::bin()).args(args).output().unwrap();
    (
        o.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

/// `info` and `convert` both fail on `file` with `fragment` in the message,
/// naming the file, and `convert` leaves nothing in its output folder.
fn assert_refused(file: &Path, fragment: &str, whole_file: bool) {
    let f = file.to_str().unwrap();
    let name = file.file_name().unwrap().to_str().unwrap();
    let (code, err) = run(&["info", f]);
    assert_ne!(code, 0, "{name}: info succeeded");
    assert!(
        err.contains(fragment),
        "{name}: info error lacks '{fragment}':\n{err}"
    );
    assert!(
        err.contains(name),
        "{name}: error does not name the file:\n{err}"
    );
    assert!(
        whole_file || err.contains("line ") || err.contains('<'),
        "{name}: error names neither element nor line:\n{err}"
    );
    let out = tempfile::tempdir().unwrap();
    let target = out.path().join("out.osim");
    let (code, err) = run(&["convert", f, target.to_str().unwrap()]);
    assert_ne!(code, 0, "{name}: convert succeeded");
    assert!(
        err.contains(fragment),
        "{name}: convert error lacks '{fragment}':\n{err}"
    );
    let left: Vec<_> = std::fs::read_dir(out.path()).unwrap().collect();
    assert!(
        left.is_empty(),
        "{name}: convert left files behind: {left:?}"
    );
}

#[test]
fn corpus_inputs_are_refused_clearly() {
    let dir = common::repo_root().join("tests/corpus/osim");
    // The base the corpus is mutated from is valid: each case has one fault.
    let (code, err) = run(&["info", dir.join("valid_base.osim").to_str().unwrap()]);
    assert_eq!(code, 0, "valid_base.osim refused: {err}");
    let index = std::fs::read_to_string(dir.join("INDEX.tsv")).unwrap();
    let mut n = 0;
    for line in index
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
    {
        let (file, fragment) = line.split_once('\t').expect("INDEX.tsv: file<TAB>fragment");
        assert_refused(&dir.join(file), fragment, false);
        n += 1;
    }
    assert!(n >= 25, "corpus has only {n} cases");
    // Every corpus file is listed in the index.
    let listed: std::collections::BTreeSet<&str> =
        index.lines().filter_map(|l| l.split('\t').next()).collect();
    for e in std::fs::read_dir(&dir).unwrap() {
        let p = e.unwrap().path();
        let fname = p.file_name().unwrap().to_str().unwrap().to_string();
        if fname.ends_with(".osim") && fname != "valid_base.osim" {
            assert!(listed.contains(fname.as_str()), "{fname} not in INDEX.tsv");
        }
    }
}

#[test]
fn oversized_file_refused_before_reading() {
    let dir = tempfile::tempdir().unwrap();
    let big = dir.path().join("huge.osim");
    {
        use std::io::Write;
        let mut f = std::fs::File::create(&big).unwrap();
        f.write_all(
            b"<?xml version=\"1.0\"?>\n<OpenSimDocument Version=\"40600\"><Model name=\"big\">",
        )
        .unwrap();
        // 300 MB (sparse: the size check must come before any reading).
        f.set_len(300 * 1024 * 1024).unwrap();
    }
    assert_refused(&big, "larger than the 256 MB limit", true);
}
