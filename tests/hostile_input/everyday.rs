//! Everyday files as spreadsheets, CAD exporters and segmentation tools
//! write them (read, or refused by name), floods of findings kept to a few
//! lines, names shown as they could be typed back, and budgets checked
//! before the work.

use super::*;
use osim_spine::landmarks::{Frame, Level};
use osim_spine::mesh;
use osim_spine::segmentation::{self, Options};

/// The README's example landmark file (UTF-8, LF line ends).
fn example() -> String {
    std::fs::read_to_string(common::repo_root().join("fixtures/example-scoliosis.csv")).unwrap()
}

/// `osim-spine check` of `bytes` written to `dir/name`.
fn check(dir: &Path, name: &str, bytes: &[u8]) -> (Output, String) {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    let o = run(&["check", s(&p)]);
    // The report with the file's path replaced, to compare files.
    let t = text(&o).replace(s(&p), "FILE");
    (o, t)
}

#[test]
fn spreadsheet_encodings_are_read_as_the_utf8_file() {
    let d = tempfile::tempdir().unwrap();
    let text = example();
    let (want, want_text) = check(d.path(), "utf8.csv", text.as_bytes());
    let utf16 = |big: bool, bom: bool| -> Vec<u8> {
        let units = bom.then_some(0xFEFF).into_iter().chain(text.encode_utf16());
        units
            .flat_map(|u| {
                if big {
                    u.to_be_bytes()
                } else {
                    u.to_le_bytes()
                }
            })
            .collect()
    };
    let cases: Vec<(&str, Vec<u8>)> = vec![
        // Excel's "CSV (Macintosh)": CR line ends only.
        ("mac.csv", text.replace('\n', "\r").into_bytes()),
        // "Unicode text": UTF-16 little-endian with a byte-order mark.
        ("utf16le_bom.csv", utf16(false, true)),
        ("utf16be_bom.csv", utf16(true, true)),
        ("utf16le.csv", utf16(false, false)),
        ("utf16be.csv", utf16(true, false)),
    ];
    for (name, bytes) in cases {
        let (o, t) = check(d.path(), name, &bytes);
        assert!(!t.contains('\0'), "{name}: NUL echoed:\n{t}");
        assert_eq!(o.status.code(), want.status.code(), "{name}:\n{t}");
        assert_eq!(t, want_text, "{name}");
    }
    // Bytes that are no text: refused by line, no NUL echoed.
    let (o, t) = check(d.path(), "nul.csv", b"name,x,y,z\nL3_SEC,1,2,3\0\n");
    assert_refused(&o, "nul.csv", "line 2: file holds a NUL byte");
    assert!(!t.contains('\0'), "{t}");
}

#[test]
fn invisible_characters_are_escaped_and_long_fields_cut() {
    let d = tempfile::tempdir().unwrap();
    let zw = example().replacen("L3_SEC", "L3_\u{200B}SEC", 1);
    let (_, t) = check(d.path(), "zw.csv", zw.as_bytes());
    assert!(t.contains("L3_\\u{200B}SEC"), "{t}");
    assert!(!t.contains('\u{200B}'), "{t}");
    // One 10 MB name: cut in the message and in the landmark list.
    let big = format!("{}X{},1,2,3\n", example(), "y".repeat(10 << 20));
    let (_, t) = check(d.path(), "big.csv", big.as_bytes());
    assert!(t.len() < 20_000, "{} bytes of report", t.len());
    assert!(t.contains("(10485761 characters)"), "{t}");
}

#[test]
fn a_flood_of_findings_is_kept_to_a_few_lines() {
    let d = tempfile::tempdir().unwrap();
    let mut flood = example();
    for i in 0..100_000 {
        flood += &format!("junk{i},1,2,3\n");
    }
    let (_, t) = check(d.path(), "flood.csv", flood.as_bytes());
    assert!(t.lines().count() < 200, "{} lines", t.lines().count());
    assert!(
        t.contains("... and 99980 more LM010 like this"),
        "{}",
        &t[t.len().saturating_sub(2000)..]
    );
}

/// A binary STL of `n` triangles whose 80-byte header is `header`.
fn binary_stl(header: &[u8], tris: &[[[f32; 3]; 3]]) -> Vec<u8> {
    let mut b = header.to_vec();
    b.resize(80, b' ');
    b.extend((tris.len() as u32).to_le_bytes());
    for t in tris {
        b.extend([0u8; 12]);
        for p in t {
            for x in p {
                b.extend(x.to_le_bytes());
            }
        }
        b.extend([0u8; 2]);
    }
    b
}

#[test]
fn a_binary_stl_whose_header_says_solid_is_read_as_binary() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("cad.stl");
    let tri = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    std::fs::write(&p, binary_stl(b"solid part exported by CAD", &[tri, tri])).unwrap();
    let m = mesh::read(&p).unwrap();
    assert_eq!((m.triangles.len(), m.vertices.len()), (2, 3));
}

#[test]
fn a_mesh_over_the_triangle_cap_is_refused_before_it_is_parsed() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("huge.stl");
    let n = mesh::MAX_MESH_TRIANGLES as u64 + 1;
    let mut head = binary_stl(b"binary", &[]);
    head[80..84].copy_from_slice(&(n as u32).to_le_bytes());
    std::fs::write(&p, &head).unwrap();
    // A sparse file of the declared size (100 MB, no disk used).
    std::fs::OpenOptions::new()
        .write(true)
        .open(&p)
        .unwrap()
        .set_len(84 + 50 * n)
        .unwrap();
    let e = mesh::read(&p).unwrap_err().to_string();
    assert!(
        e.contains("huge.stl") && e.contains("limited to 2000000") && e.contains("decimate"),
        "{e}"
    );
    // Ten million triangles (a 500 MB file, sparse): refused by `palpate`
    // within 5 s and 1 GB of address space.
    let dir = d.path().join("meshes");
    std::fs::create_dir(&dir).unwrap();
    let big = dir.join("L3.stl");
    let n: u64 = 10_000_000;
    head[80..84].copy_from_slice(&(n as u32).to_le_bytes());
    std::fs::write(&big, &head).unwrap();
    std::fs::OpenOptions::new()
        .write(true)
        .open(&big)
        .unwrap()
        .set_len(84 + 50 * n)
        .unwrap();
    let out = d.path().join("lm.csv");
    let t = std::time::Instant::now();
    let o = super::label_maps::run_within(1024, &["palpate", s(&dir), "--out", s(&out)]);
    let secs = t.elapsed().as_secs_f64();
    assert_refused(&o, "L3.stl", "limited to 2000000");
    assert!(secs < 5.0, "refused in {secs:.1} s");
    assert!(!out.exists());
}

#[test]
fn mesh_folders_as_exporters_leave_them() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path().join("meshes");
    std::fs::create_dir(&dir).unwrap();
    for (l, mut m) in super::label_maps::lumbosacral() {
        // Every other triangle of L4 wound the other way (as some
        // exporters and the OpenSim geometry have it).
        if l == Level::L4 {
            for t in m.triangles.iter_mut().step_by(2) {
                t.swap(1, 2);
            }
        }
        mesh::write(&dir.join(format!("{l}.obj")), &m).unwrap();
    }
    // A folder and a device under level names, and 5,000 unrelated files.
    std::fs::create_dir(dir.join("L3.stl")).unwrap();
    symlink("/dev/null", &dir.join("L2.stl"));
    for i in 0..5000 {
        std::fs::write(dir.join(format!("scan_{i}.obj")), "").unwrap();
    }
    let opts = Options {
        frame: Some(Frame::OpenSim),
        ..Options::default()
    };
    let got = segmentation::palpate(&dir, &opts).unwrap();
    assert_eq!(got.levels.len(), 3, "{:?}", got.findings);
    let said = |a: &str, b: &str| {
        got.findings
            .iter()
            .any(|f| f.message.contains(a) && f.message.contains(b))
    };
    assert!(said("L3.stl", "a folder"), "{:?}", got.findings);
    assert!(said("L2.stl", "a device"), "{:?}", got.findings);
    assert!(said("winding was mixed", "turned"), "{:?}", got.findings);
    let unrelated: Vec<&str> = got
        .findings
        .iter()
        .map(|f| f.message.as_str())
        .filter(|m| m.contains("scan_"))
        .collect();
    assert_eq!(unrelated.len(), 1, "{unrelated:?}");
    assert!(unrelated[0].contains("... and 4995 more like this") && unrelated[0].len() < 1000);
}

#[test]
fn jobs_beyond_the_cores_are_capped() {
    let Some(dev) = common::shared("diagnose-dev/dev-01") else {
        return;
    };
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("dg");
    let o = run(&[
        "diagnose",
        s(&dev),
        "--quiet",
        "--jobs",
        "100000",
        "--out",
        s(&out),
    ]);
    let t = text(&o);
    assert_eq!(o.status.code(), Some(0), "{t}");
    assert!(t.contains("--jobs 100000 is more than the"), "{t}");
}

#[test]
fn variability_refuses_the_same_palpation_twice() {
    let d = tempfile::tempdir().unwrap();
    let a = d.path().join("a.csv");
    let b = d.path().join("b.csv");
    std::fs::write(&a, example()).unwrap();
    std::fs::write(&b, example()).unwrap();
    let out = d.path().join("var");
    let o = run(&["variability", s(&a), s(&b), "--no-models", "--out", s(&out)]);
    assert_refused(&o, "b.csv", "the same content as");
    assert!(text(&o).contains("a.csv"), "{}", text(&o));
    assert!(!out.exists());
}

#[test]
fn loads_beyond_a_spine_are_refused_naming_the_magnitude() {
    let d = tempfile::tempdir().unwrap();
    let m = d.path().join("m.osim");
    std::fs::write(&m, corpus_model()).unwrap();
    for (name, case, fragment) in [
        (
            "moment",
            "moment = [0.0, 0.0, 1e9]\nmoment_frame = \"ground\"",
            "moment of magnitude 1.0000e9 N*m",
        ),
        (
            "force",
            "force = [3e5, 4e5, 0.0]",
            "force of magnitude 5.0000e5 N",
        ),
        (
            "follower",
            "follower_load = 2e5",
            "follower_load of magnitude 2.0000e5 N",
        ),
    ] {
        let load = d.path().join(format!("{name}.toml"));
        std::fs::write(
            &load,
            format!("[[case]]\nid = \"big\"\nbody = \"L5\"\n{case}\n"),
        )
        .unwrap();
        let out = d.path().join(format!("sim_{name}"));
        let o = run(&["simulate", s(&m), "--load", s(&load), "--out", s(&out)]);
        assert_refused(&o, &format!("{name}.toml"), fragment);
        assert!(!text(&o).contains("no stiffness"), "{}", text(&o));
        assert!(!out.exists());
    }
    // A moment a spine bears is solved.
    let load = d.path().join("small.toml");
    std::fs::write(
        &load,
        "[[case]]\nid = \"small\"\nbody = \"L5\"\nmoment = [0.0, 0.0, 5.0]\nmoment_frame = \"ground\"\n",
    )
    .unwrap();
    let out = d.path().join("sim_small");
    let o = run(&["simulate", s(&m), "--load", s(&load), "--out", s(&out)]);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
}

#[test]
fn variability_warns_on_identical_sets_in_different_files() {
    let d = tempfile::tempdir().unwrap();
    let text = example();
    // b: the same landmarks with other comments (different bytes); c:
    // one coordinate moved by 0.1 mm.
    let a = d.path().join("a.csv");
    let b = d.path().join("b.csv");
    let c = d.path().join("c.csv");
    std::fs::write(&a, &text).unwrap();
    std::fs::write(&b, format!("# palpated again on Tuesday\n{text}")).unwrap();
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    let row = lines.iter().position(|l| l.starts_with("L3_")).unwrap();
    let mut cells: Vec<String> = lines[row].split(',').map(String::from).collect();
    cells[1] = format!("{}", cells[1].parse::<f64>().unwrap() + 0.1);
    lines[row] = cells.join(",");
    std::fs::write(&c, lines.join("\n") + "\n").unwrap();
    let out = d.path().join("var");
    let o = run(&[
        "variability",
        s(&a),
        s(&b),
        s(&c),
        "--no-models",
        "--out",
        s(&out),
    ]);
    let t = super::text(&o);
    assert_eq!(o.status.code(), Some(0), "{t}");
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("variability.json")).unwrap()).unwrap();
    let w = json["warnings"].as_array().unwrap();
    assert_eq!(w.len(), 1, "{w:?}");
    let w = w[0].as_str().unwrap();
    assert!(
        w.contains("identical landmark sets") && w.contains("a.csv") && w.contains("b.csv"),
        "{w}"
    );
    assert!(!w.contains("c.csv"), "{w}");
    assert!(t.contains("warning: identical landmark sets"), "{t}");
    // Different sets: no warning.
    let out2 = d.path().join("var2");
    let o = run(&[
        "variability",
        s(&a),
        s(&c),
        "--no-models",
        "--out",
        s(&out2),
    ]);
    assert_eq!(o.status.code(), Some(0), "{}", super::text(&o));
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out2.join("variability.json")).unwrap()).unwrap();
    assert_eq!(json["warnings"].as_array().unwrap().len(), 0);
}

#[test]
fn an_experiment_of_20000_cases_loads_in_linear_time() {
    let src = common::repo_root().join("tests/data/published");
    let d = tempfile::tempdir().unwrap();
    std::fs::copy(src.join("specimen.osim"), d.path().join("specimen.osim")).unwrap();
    let case = d.path().join("case");
    std::fs::create_dir(&case).unwrap();
    let toml = std::fs::read_to_string(src.join("yamamoto1989/experiment.toml")).unwrap();
    let head = &toml[..toml.find("[[case]]").unwrap()];
    // n cases of 1..9 N*m, each with one measured rotation.
    let write = |n: usize| {
        let mut t = head.to_string();
        let mut k = String::from("case,upper,lower,rx,ry,rz,tx,ty,tz\n");
        for i in 0..n {
            let m = 1.0 + (i % 9) as f64;
            t.push_str(&format!(
                "[[case]]\nid = \"c{i}\"\nbody = \"lumbar1\"\nmoment = [0.0, 0.0, {m}]\nmoment_frame = \"ground\"\n\n"
            ));
            k.push_str(&format!("c{i},lumbar1,lumbar2,,,{:.2},,,\n", 0.6 * m));
        }
        std::fs::write(case.join("experiment.toml"), t).unwrap();
        std::fs::write(case.join("kinematics.csv"), k).unwrap();
        let t = std::time::Instant::now();
        let e = osim_spine::calibrate::experiment::Experiment::read(&case)
            .unwrap_or_else(|e| panic!("{n} cases: {e}"));
        assert_eq!(e.cases.len(), n);
        t.elapsed().as_secs_f64()
    };
    let small = write(2_000);
    let big = write(20_000);
    println!("experiment load: 2,000 cases {small:.3} s, 20,000 cases {big:.3} s");
    assert!(big < 2.0, "20,000 cases loaded in {big:.2} s");
    // Linear: ten times the cases, not a hundred times the time.
    assert!(big < 30.0 * small.max(0.01), "{small:.3} s -> {big:.3} s");
}
