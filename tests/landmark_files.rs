//! Landmark file reading: bad files give clear errors (file, line, what was
//! expected) and never a panic; units and frame are detected from the
//! anatomy; the three formats carry the same content; the CLI's exit codes.

mod common;

use nalgebra::Vector3;
use osim_spine::landmarks::io::{csv_string, load, read_palpations, read_path};
use osim_spine::landmarks::synth::{generate, SpineShape, SynthOptions};
use osim_spine::landmarks::{Frame, LandmarkSet, Level, Units};
use std::path::{Path, PathBuf};
use std::process::Command;

fn clean() -> LandmarkSet {
    generate(&SynthOptions {
        top: Level::T9,
        shape: SpineShape::lumbar_scoliosis(75.0),
        noise_sd: 0.0005,
        seed: 9,
    })
    .unwrap()
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

fn err_of(path: &Path) -> String {
    match read_path(path).and_then(|r| r.to_set()) {
        Ok(_) => panic!("{} was accepted", path.display()),
        Err(e) => e.to_string(),
    }
}

fn max_dist(a: &LandmarkSet, b: &LandmarkSet) -> f64 {
    assert_eq!(a.points.len(), b.points.len());
    a.points
        .iter()
        .map(|(k, p)| (p - b.points[k]).norm())
        .fold(0.0, f64::max)
}

#[test]
fn bad_files_give_clear_errors() {
    let d = tempfile::tempdir().unwrap();
    let cases: Vec<(&str, String, &str)> = vec![
        ("empty.csv", String::new(), "empty"),
        ("comments_only.csv", "# units: mm\n".into(), "empty"),
        (
            "wrong_columns.csv",
            "label,a,b\nL3_SEC,1,2\n".into(),
            "expected the header `name,x,y,z`",
        ),
        (
            "too_few_fields.csv",
            "name,x,y,z\nL3_SEC,1,2\n".into(),
            "line 2: expected 4 comma-separated fields, found 3",
        ),
        (
            "non_numeric.csv",
            "name,x,y,z\nL3_SEC,1,abc,3\n".into(),
            "line 2: column `y`: expected a number, found `abc`",
        ),
        (
            "nan.csv",
            "name,x,y,z\nL3_SEC,NaN,2,3\n".into(),
            "line 2: column `x`: expected a finite number",
        ),
        (
            "inf.csv",
            "name,x,y,z\nL3_SEC,1,inf,3\n".into(),
            "expected a finite number",
        ),
        (
            "bad_units.csv",
            "# units: cm\nname,x,y,z\nL3_SEC,1,2,3\n".into(),
            "line 1: `# units: cm`: expected `mm` or `m`",
        ),
        (
            "bad_frame.csv",
            "# frame: LAS\nname,x,y,z\nL3_SEC,1,2,3\n".into(),
            "expected `LPS`, `RAS` or `opensim`",
        ),
        ("no_rows.csv", "name,x,y,z\n".into(), "no landmark rows"),
        (
            "unknown_name.csv",
            "name,x,y,z\nL3_SEC,1,2,3\nL3_FOO,1,2,3\n".into(),
            "line 3: unknown landmark name `L3_FOO`",
        ),
        (
            "sacral_iec.csv",
            "name,x,y,z\nS1_IEC,1,2,3\n".into(),
            "not a sacral landmark",
        ),
        (
            "dup.csv",
            "name,x,y,z\nL3_SEC,1,2,3\nL3_SEC,1,2,3\n".into(),
            "line 3: duplicate landmark `L3_SEC` (first at line 2)",
        ),
        (
            "binary.csv",
            String::from_utf8_lossy(&[0xff, 0xfe, 0x00, 0x41]).into_owned(),
            "line 1: file holds a NUL byte: not UTF-8 or UTF-16 text",
        ),
        (
            "bad.json",
            "{\"landmarks\": {\"L3_SEC\": [1, 2]}}".into(),
            "landmarks.L3_SEC: expected [x, y, z]",
        ),
        (
            "bad2.json",
            "{\"units\": \"mm\", \"landmark\": {}}".into(),
            "missing field `landmarks`",
        ),
        (
            "trunc.json",
            "{\"units\": \"mm\", \"landmarks\": {\"L3_SEC\": [1, 2, 3]".into(),
            "line 1 column",
        ),
        ("empty.json", "  ".into(), "empty"),
        (
            "short.trc",
            "PathFileType\t4\t(X/Y/Z)\tx.trc\n".into(),
            "TRC header ends early",
        ),
        (
            "nounits.trc",
            "PathFileType\t4\nDataRate\tNumFrames\n100\t1\nFrame#\tTime\tL3_SEC\n\t\tX1\tY1\tZ1\n"
                .into(),
            "no `Units` column",
        ),
        ("data.xyz", "name,x,y,z\n".into(), "unknown extension"),
    ];
    for (name, text, expect) in &cases {
        let p = write(d.path(), name, text);
        let e = err_of(&p);
        assert!(
            e.contains(name),
            "{name}: error does not name the file: {e}"
        );
        assert!(e.contains(expect), "{name}: expected `{expect}` in: {e}");
    }
    // Missing file: an I/O error naming the path.
    let e = err_of(&d.path().join("absent.csv"));
    assert!(e.contains("absent.csv"), "{e}");
}

#[test]
fn huge_files_are_refused_before_reading() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("huge.csv");
    let f = std::fs::File::create(&p).unwrap();
    // Sparse file: no disk used, metadata says 64 MiB.
    f.set_len(64 * 1024 * 1024).unwrap();
    let e = err_of(&p);
    assert!(e.contains("limited to"), "{e}");
}

#[test]
fn random_bytes_never_panic() {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    let d = tempfile::tempdir().unwrap();
    let base = csv_string(&clean(), Units::Millimetre, Frame::Lps).into_bytes();
    for i in 0..300 {
        let mut b = base.clone();
        for _ in 0..rng.random_range(1..20) {
            let k = rng.random_range(0..b.len());
            b[k] = rng.random();
        }
        if i % 3 == 0 {
            b.truncate(rng.random_range(0..b.len()));
        }
        for ext in ["csv", "json", "trc"] {
            let p = d.path().join(format!("f{i}.{ext}"));
            std::fs::write(&p, &b).unwrap();
            let _ = read_path(&p).and_then(|r| r.to_set());
            let _ = osim_spine::landmarks::check::check_file(&p);
        }
    }
}

#[test]
fn units_and_frame_are_detected_without_header() {
    let d = tempfile::tempdir().unwrap();
    let truth = clean();
    for frame in Frame::ALL {
        for units in [Units::Millimetre, Units::Metre] {
            let text = csv_string(&truth, units, frame);
            let headerless: String = text.lines().skip(2).map(|l| format!("{l}\n")).collect();
            let p = write(d.path(), &format!("h_{frame}_{units}.csv"), &headerless);
            let set = load(&p).unwrap();
            let det = set.detection.clone().unwrap();
            assert_eq!(det.detected_units, Some(units), "{}", det.summary());
            assert_eq!(det.detected_frame, Some(frame), "{}", det.summary());
            assert!(max_dist(&set, &truth) < 1e-9);
        }
    }
}

#[test]
fn header_contradicting_the_anatomy_is_an_error() {
    let d = tempfile::tempdir().unwrap();
    let truth = clean();
    // Metres declared as mm.
    let text = csv_string(&truth, Units::Metre, Frame::Lps).replace("# units: m", "# units: mm");
    let e = err_of(&write(d.path(), "m_as_mm.csv", &text));
    assert!(
        e.contains("declared units `mm`") && e.contains("metres"),
        "{e}"
    );
    // RAS data declared LPS.
    let text =
        csv_string(&truth, Units::Millimetre, Frame::Ras).replace("# frame: RAS", "# frame: LPS");
    let e = err_of(&write(d.path(), "ras_as_lps.csv", &text));
    assert!(
        e.contains("declared frame `LPS`") && e.contains("RAS"),
        "{e}"
    );
    // Centimetres without header: refused as undetectable.
    let cm: String = csv_string(&truth, Units::Millimetre, Frame::Lps)
        .lines()
        .skip(2)
        .enumerate()
        .map(|(i, l)| {
            if i == 0 {
                format!("{l}\n")
            } else {
                let f: Vec<&str> = l.split(',').collect();
                let v: Vec<String> = f[1..]
                    .iter()
                    .map(|x| (x.parse::<f64>().unwrap() / 10.0).to_string())
                    .collect();
                format!("{},{}\n", f[0], v.join(","))
            }
        })
        .collect();
    let e = err_of(&write(d.path(), "cm.csv", &cm));
    assert!(e.contains("units not declared and not detectable"), "{e}");
}

#[test]
fn csv_trc_json_round_trip_to_the_same_set() {
    let d = tempfile::tempdir().unwrap();
    let truth = clean();
    // CSV (writer) round trip.
    let p = d.path().join("a.csv");
    osim_spine::landmarks::io::write_csv(&truth, &p, Units::Millimetre, Frame::Ras).unwrap();
    assert!(max_dist(&load(&p).unwrap(), &truth) < 1e-12);
    // JSON in LPS metres.
    let back = Frame::Lps.to_opensim().transpose();
    let entries: Vec<String> = truth
        .points
        .iter()
        .map(|(k, v)| {
            let f = back * v.coords;
            format!("\"{k}\": [{}, {}, {}]", f.x, f.y, f.z)
        })
        .collect();
    let json = format!(
        "{{\"units\": \"m\", \"frame\": \"LPS\", \"landmarks\": {{{}}}}}",
        entries.join(",\n")
    );
    let pj = write(d.path(), "a.json", &json);
    assert!(max_dist(&load(&pj).unwrap(), &truth) < 1e-12);
    // TRC, mm, OpenSim frame, two frames 0.4 mm apart: mean is used.
    let names: Vec<String> = truth.points.keys().map(|k| k.to_string()).collect();
    let make_trc = |offsets: &[f64]| {
        let mut trc = format!(
        "PathFileType\t4\t(X/Y/Z)\ta.trc\nDataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames\n100\t100\t2\t{n}\tmm\t100\t1\t2\nFrame#\tTime\t{}\n\t\t{}\n\n",
        names.join("\t\t\t"),
        (1..=names.len()).map(|i| format!("X{i}\tY{i}\tZ{i}")).collect::<Vec<_>>().join("\t"),
        n = names.len()
    );
        for (fi, off) in offsets.iter().enumerate() {
            let fi = fi + 1;
            let vals: Vec<String> = truth
                .points
                .values()
                .map(|p| {
                    let q = p.coords * 1e3 + Vector3::repeat(*off);
                    format!("{}\t{}\t{}", q.x, q.y, q.z)
                })
                .collect();
            trc.push_str(&format!(
                "{fi}\t{}\t{}\n",
                (fi - 1) as f64 * 0.01,
                vals.join("\t")
            ));
        }
        trc
    };
    let trc = make_trc(&[-0.2, 0.2]);
    let pt = write(d.path(), "a.trc", &trc);
    let set = load(&pt).unwrap();
    assert!(max_dist(&set, &truth) < 1e-9, "{}", max_dist(&set, &truth));
    assert_eq!(set.detection.unwrap().detected_frame, Some(Frame::OpenSim));
    // A moving TRC is refused.
    let moving = make_trc(&[0.0, 10.0]);
    let e = err_of(&write(d.path(), "moving.trc", &moving));
    assert!(e.contains("must be static"), "{e}");
}

#[test]
fn repeated_palpation_csv_is_split_by_operator_and_repetition() {
    let d = tempfile::tempdir().unwrap();
    let truth = clean();
    let body: Vec<String> = csv_string(&truth, Units::Millimetre, Frame::Lps)
        .lines()
        .skip(3)
        .map(String::from)
        .collect();
    let mut text = String::from("# units: mm\n# frame: LPS\noperator,repetition,name,x,y,z\n");
    for (op, rep) in [("A", 1), ("A", 2), ("B", 1)] {
        for r in &body {
            text.push_str(&format!("{op},{rep},{r}\n"));
        }
    }
    let p = write(d.path(), "long.csv", &text);
    let pals = read_palpations(&p).unwrap();
    assert_eq!(pals.len(), 3);
    assert_eq!((pals[2].operator.as_str(), pals[2].repetition), ("B", 1));
    // read_path refuses a multi-palpation file.
    assert!(read_path(&p)
        .unwrap_err()
        .to_string()
        .contains("3 palpations"));
    let bad = text.replacen("A,2,", "A,two,", 1);
    let e = read_palpations(&write(d.path(), "badrep.csv", &bad))
        .unwrap_err()
        .to_string();
    assert!(e.contains("column `repetition`"), "{e}");
}

#[test]
fn quoted_commas_bom_and_crlf_in_a_palpation_study() {
    // Operators named "Last, First" (a quoted cell holding a comma), a
    // byte-order mark, CRLF line ends and comment/blank lines between rows.
    let d = tempfile::tempdir().unwrap();
    let truth = clean();
    let rows = lps_mm_rows(&truth);
    let mut text = String::from(
        "\u{feff}# units: mm\r\n# frame: LPS\r\n\r\noperator,repetition,name,x,y,z\r\n",
    );
    for op in ["Smith, J", "Doe, A"] {
        text.push_str("# next operator\r\n");
        for (n, [x, y, z]) in &rows {
            text.push_str(&format!("\"{op}\",1,{n},{x},{y},{z}\r\n"));
        }
    }
    let pals = read_palpations(&write(d.path(), "study.csv", &text)).unwrap();
    let ops: Vec<&str> = pals.iter().map(|p| p.operator.as_str()).collect();
    assert_eq!(ops, ["Smith, J", "Doe, A"]);
    for p in &pals {
        let set = p.raw.to_set().unwrap();
        assert!(max_dist(&set, &truth) < 1e-12, "{}", max_dist(&set, &truth));
    }
    // A bad cell on the second operator's third row: the file's own line
    // (BOM, 2 header comments, a blank line, the header, a comment, the
    // first operator's rows, a comment, 3 rows), and the quoted `1,5` is one
    // cell, not a sixth field.
    let (n, [_, y, z]) = &rows[2];
    let bad_row = format!("\"Doe, A\",1,{n},\"1,5\",{y},{z}\r\n");
    let good_row = format!("\"Doe, A\",1,{n},{},{y},{z}\r\n", rows[2].1[0]);
    let bad = text.replacen(&good_row, &bad_row, 1);
    assert_ne!(bad, text);
    let line = 4 + 1 + rows.len() + 1 + 3;
    let e = read_palpations(&write(d.path(), "bad.csv", &bad))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains(&format!(
            "bad.csv: line {line}: column `x`: expected a number, found `1,5`"
        )),
        "{e}"
    );
}

#[test]
fn cli_check_exit_codes_and_github_format() {
    let d = tempfile::tempdir().unwrap();
    let truth = clean();
    let good = write(
        d.path(),
        "good.csv",
        &csv_string(&truth, Units::Millimetre, Frame::Lps),
    );
    let run = |args: &[&str]| {
        let o = Command::new(common::bin()).args(args).output().unwrap();
        (
            o.status.code().unwrap(),
            String::from_utf8_lossy(&o.stdout).into_owned(),
        )
    };
    let (code, _) = run(&["check", good.to_str().unwrap()]);
    assert_eq!(code, 0);
    // Warning only: a non-canonical name (`l3_sec`).
    let text = csv_string(&truth, Units::Millimetre, Frame::Lps).replace("L3_SEC,", "l3_sec,");
    let warn = write(d.path(), "warn.csv", &text);
    let (code, out) = run(&["check", warn.to_str().unwrap()]);
    assert_eq!(code, 2, "{out}");
    let (code, _) = run(&["check", "--strict", warn.to_str().unwrap()]);
    assert_eq!(code, 1);
    // Error: a missing landmark, reported as a GitHub annotation.
    let text: String = csv_string(&truth, Units::Millimetre, Frame::Lps)
        .lines()
        .filter(|l| !l.starts_with("L2_IEC"))
        .map(|l| format!("{l}\n"))
        .collect();
    let bad = write(d.path(), "bad.csv", &text);
    let (code, out) = run(&[
        "check",
        "--format",
        "github",
        bad.to_str().unwrap(),
        good.to_str().unwrap(),
    ]);
    assert_eq!(code, 1);
    assert!(
        out.lines().any(|l| l.starts_with("::error file=")
            && l.contains("title=LM020::")
            && l.contains("L2_IEC")),
        "{out}"
    );
    let (code, out) = run(&["check", "--format", "json", bad.to_str().unwrap()]);
    assert_eq!(code, 1);
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(
        v[0]["findings"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|f| f["code"] == "LM020")
            .count(),
        1
    );
    // Unreadable file: LM001, exit 1, no panic.
    let (code, out) = run(&["check", d.path().join("nope.csv").to_str().unwrap()]);
    assert_eq!(code, 1);
    assert!(out.contains("LM001"), "{out}");
}

/// The CSV of `set` in mm, LPS, header comments included, with the rows
/// turned into `(name, [x, y, z])` so the variants below can respell them.
fn lps_mm_rows(set: &LandmarkSet) -> Vec<(String, [String; 3])> {
    csv_string(set, Units::Millimetre, Frame::Lps)
        .lines()
        .skip(3)
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (
                f[0].to_string(),
                [f[1].to_string(), f[2].to_string(), f[3].to_string()],
            )
        })
        .collect()
}

#[test]
fn csv_spreadsheet_variants_read_as_the_same_set() {
    // BOM, CRLF, upper-case quoted header, quoted cells, trailing commas,
    // lower-case names, comment lines between rows, blank lines: all carry
    // the same landmarks (format: "name,x,y,z", `# units:` / `# frame:`).
    let d = tempfile::tempdir().unwrap();
    let truth = clean();
    let rows = lps_mm_rows(&truth);
    let mut text =
        String::from("\u{feff}# units: mm\r\n#frame:lps\r\n\"NAME\",\"X\",\"Y\",\"Z\",,\r\n");
    for (i, (n, [x, y, z])) in rows.iter().enumerate() {
        let n = if i % 2 == 0 {
            n.to_lowercase()
        } else {
            n.clone()
        };
        text.push_str(&format!("\"{n}\", \"{x}\" ,{y},{z},,\r\n"));
        if i == 3 {
            text.push_str("# a comment between rows\r\n\r\n");
        }
    }
    let set = load(&write(d.path(), "excel.csv", &text)).unwrap();
    assert!(max_dist(&set, &truth) < 1e-12, "{}", max_dist(&set, &truth));
    let det = set.detection.unwrap();
    assert_eq!(det.declared_units, Some(Units::Millimetre));
    assert_eq!(det.declared_frame, Some(Frame::Lps));
    // A trailing cell that is not empty is still an error naming the line.
    let mut bad = String::from("name,x,y,z\n");
    for (i, (n, [x, y, z])) in rows.iter().enumerate() {
        let extra = if i == 2 { ",7" } else { "" };
        bad.push_str(&format!("{n},{x},{y},{z}{extra}\n"));
    }
    let e = err_of(&write(d.path(), "extra.csv", &bad));
    assert!(
        e.contains("line 4: expected 4 comma-separated fields, found 5"),
        "{e}"
    );
}

#[test]
fn a_set_of_some_levels_ending_at_s1_is_read() {
    // "A set may cover any contiguous run of levels ending at S1".
    let d = tempfile::tempdir().unwrap();
    let truth = clean();
    let keep = |n: &str| {
        ["L3_", "L4_", "L5_", "S1_"]
            .iter()
            .any(|p| n.starts_with(p))
    };
    let mut text = String::from("# units: mm\n# frame: LPS\nname,x,y,z\n");
    for (n, [x, y, z]) in lps_mm_rows(&truth).iter().filter(|(n, _)| keep(n)) {
        text.push_str(&format!("{n},{x},{y},{z}\n"));
    }
    let set = load(&write(d.path(), "l3_s1.csv", &text)).unwrap();
    let levels: std::collections::BTreeSet<Level> = set.points.keys().map(|k| k.level).collect();
    assert_eq!(
        levels.into_iter().collect::<Vec<_>>(),
        vec![Level::L3, Level::L4, Level::L5, Level::S1]
    );
    let n = truth.points.keys().filter(|k| keep(&k.to_string())).count();
    assert_eq!(set.points.len(), n);
    for (k, p) in &set.points {
        assert!((p - truth.points[k]).norm() < 1e-12);
    }
    // ... and the checker finds no error in it (only info/warnings).
    let r = osim_spine::landmarks::check::check_file(&d.path().join("l3_s1.csv"));
    assert_eq!(
        r.count(osim_spine::landmarks::check::Severity::Error),
        0,
        "{:?}",
        r.findings
    );
}

/// A TRC in OpenSim's layout (mm, OpenSim frame) of `set`, marker names
/// `names` (extra non-landmark names get a fixed point), `frames` frames.
fn trc_text(set: &LandmarkSet, extra: &[&str], padded_names: bool, eol: &str) -> String {
    let mut names: Vec<String> = extra.iter().map(|s| s.to_string()).collect();
    names.extend(set.points.keys().map(|k| k.to_string()));
    let sep = if padded_names { "\t\t\t" } else { "\t" };
    let mut t = format!(
        "PathFileType\t4\t(X/Y/Z)\tp.trc{eol}DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames{eol}60.00\t60.00\t2\t{n}\tmm\t60.00\t1\t2{eol}Frame#\tTime\t{}{eol}\t\t{}{eol}{eol}",
        names.join(sep),
        (1..=names.len())
            .map(|i| format!("X{i}\tY{i}\tZ{i}"))
            .collect::<Vec<_>>()
            .join("\t"),
        n = names.len()
    );
    for f in 1..=2 {
        let mut vals: Vec<String> = extra.iter().map(|_| "1.0\t2.0\t3.0".to_string()).collect();
        vals.extend(set.points.values().map(|p| {
            let q = p.coords * 1e3;
            format!("{}\t{}\t{}", q.x, q.y, q.z)
        }));
        t.push_str(&format!(
            "{f}\t{:.4}\t{}{eol}",
            (f - 1) as f64 / 60.0,
            vals.join("\t")
        ));
    }
    t
}

#[test]
fn trc_variants_read_as_the_same_set() {
    let d = tempfile::tempdir().unwrap();
    let truth = clean();
    // OpenSim's layout with extra skin markers before the landmarks, CRLF and a BOM.
    let text = format!(
        "\u{feff}{}",
        trc_text(&truth, &["C7", "R.ASIS"], true, "\r\n")
    );
    let p = write(d.path(), "skin.trc", &text);
    let raw = read_path(&p).unwrap();
    assert!(
        raw.notes.iter().any(|n| n.contains("C7, R.ASIS")),
        "{:?}",
        raw.notes
    );
    let set = raw.to_set().unwrap();
    assert!(max_dist(&set, &truth) < 1e-9, "{}", max_dist(&set, &truth));
    // The checker says what it skipped (LM008) and finds no error.
    let r = osim_spine::landmarks::check::check_file(&p);
    assert!(r.has("LM008"), "{:?}", r.findings);
    // Marker names not padded with two empty cells: OpenSim still maps the
    // i-th name to columns 2+3i.
    let text = trc_text(&truth, &[], false, "\n");
    let set = load(&write(d.path(), "tight.trc", &text)).unwrap();
    assert!(max_dist(&set, &truth) < 1e-9, "{}", max_dist(&set, &truth));
    // Header keys and values separated by spaces, not tabs.
    let text = trc_text(&truth, &[], true, "\n")
        .replacen(
            "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames",
            "DataRate CameraRate NumFrames NumMarkers Units OrigDataRate OrigDataStartFrame OrigNumFrames",
            1,
        )
        .replacen("60.00\t60.00\t2\t", "60.00 60.00 2 ", 1);
    let text = {
        // the rest of line 3 too
        let mut lines: Vec<String> = text.lines().map(String::from).collect();
        lines[2] = lines[2].replace('\t', " ");
        lines.join("\n") + "\n"
    };
    let set = load(&write(d.path(), "spaces.trc", &text)).unwrap();
    assert!(max_dist(&set, &truth) < 1e-9);
    // Metres in the Units column.
    let text = trc_text(&truth, &[], true, "\n");
    let m: String = text
        .lines()
        .enumerate()
        .map(|(i, l)| match i {
            2 => l.replace("\tmm\t", "\tm\t") + "\n",
            i if i >= 6 && !l.is_empty() => {
                let f: Vec<String> = l
                    .split('\t')
                    .enumerate()
                    .map(|(k, c)| {
                        if k < 2 {
                            c.to_string()
                        } else {
                            (c.parse::<f64>().unwrap() / 1e3).to_string()
                        }
                    })
                    .collect();
                f.join("\t") + "\n"
            }
            _ => format!("{l}\n"),
        })
        .collect();
    let set = load(&write(d.path(), "metres.trc", &m)).unwrap();
    assert!(max_dist(&set, &truth) < 1e-9);
    assert_eq!(set.detection.unwrap().declared_units, Some(Units::Metre));
    // A misspelt landmark (a level prefix, a bad code) is not skipped.
    let text = trc_text(&truth, &["L3_SECC"], true, "\n");
    let e = err_of(&write(d.path(), "typo.trc", &text));
    assert!(e.contains("unknown landmark name `L3_SECC`"), "{e}");
}

#[test]
fn json_variants_read_as_the_same_set() {
    let d = tempfile::tempdir().unwrap();
    let truth = clean();
    let entries: Vec<String> = lps_mm_rows(&truth)
        .iter()
        .map(|(n, [x, y, z])| format!("\"{n}\": [{x}, {y}, {z}]"))
        .collect();
    // Both `units` and `frame` optional (detected), metadata keys ignored
    // with a note, BOM and CRLF accepted.
    let json = format!(
        "\u{feff}{{\"subject\": \"P01\", \"landmarks\": {{{}}}}}",
        entries.join(",\r\n")
    );
    let p = write(d.path(), "bare.json", &json);
    let raw = read_path(&p).unwrap();
    assert!(
        raw.notes.iter().any(|n| n.contains("subject")),
        "{:?}",
        raw.notes
    );
    let set = raw.to_set().unwrap();
    assert!(max_dist(&set, &truth) < 1e-12);
    let det = set.detection.unwrap();
    assert_eq!(det.detected_units, Some(Units::Millimetre));
    assert_eq!(det.detected_frame, Some(Frame::Lps));
    // "a tool that guesses must say what it guessed": the checker reports
    // both guesses (LM004 units, LM005 frame) and the ignored key (LM008).
    let r = osim_spine::landmarks::check::check_file(&p);
    for code in ["LM004", "LM005", "LM008"] {
        assert!(r.has(code), "{code}: {:?}", r.findings);
    }
    // A name given twice is refused, not merged.
    let dup = format!(
        "{{\"units\": \"mm\", \"frame\": \"LPS\", \"landmarks\": {{{}, {}}}}}",
        entries.join(","),
        entries[0]
    );
    let e = err_of(&write(d.path(), "dup.json", &dup));
    assert!(e.contains("duplicate landmark"), "{e}");
    // Without the `landmarks` object: a clear error.
    let e = err_of(&write(d.path(), "nolm.json", "{\"units\": \"mm\"}"));
    assert!(e.contains("missing field `landmarks`"), "{e}");
}
