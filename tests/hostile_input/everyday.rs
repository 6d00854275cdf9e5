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
