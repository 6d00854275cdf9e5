//! Layout of every figure the tool writes: each
//! SVG is laid out by usvg (resvg's parser) with the machine's fonts, and
//! every text box must lie inside the canvas, and no two text boxes may
//! overlap (titles, axis labels, tick labels and legends alike). The
//! figures come from real runs: `generate`, `base --procedural`,
//! `evaluate`, `variability` (with models), `calibrate`, `diagnose` and
//! `sensitivity`.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

/// Run the tool; panics with its stderr on failure.
fn run(args: &[&str]) {
    let o = Command::new(common::bin()).args(args).output().unwrap();
    assert!(
        o.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Every `.svg` below `dir`, sorted.
fn svgs(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else if p.extension().is_some_and(|e| e == "svg") {
                out.push(p);
            }
        }
    }
    out.sort();
    out
}

/// One laid-out text: its string and box (left, top, right, bottom) in
/// canvas pixels.
struct TextBox {
    text: String,
    b: [f32; 4],
}

/// The text boxes of a usvg group, recursively.
fn texts(g: &usvg::Group, out: &mut Vec<TextBox>) {
    for n in g.children() {
        match n {
            usvg::Node::Group(g) => texts(g, out),
            usvg::Node::Text(t) => {
                let r = t.abs_bounding_box();
                let text = t.chunks().iter().map(|c| c.text()).collect::<String>();
                out.push(TextBox {
                    text,
                    b: [r.left(), r.top(), r.right(), r.bottom()],
                });
            }
            _ => {}
        }
    }
}

/// Overlap area of two boxes (px²).
fn overlap(a: &[f32; 4], b: &[f32; 4]) -> f32 {
    let w = (a[2].min(b[2]) - a[0].max(b[0])).max(0.0);
    let h = (a[3].min(b[3]) - a[1].max(b[1])).max(0.0);
    w * h
}

/// The layout findings of one SVG file.
fn layout_findings(path: &Path, opt: &usvg::Options) -> Vec<String> {
    let text = std::fs::read_to_string(path).unwrap();
    let tree = usvg::Tree::from_str(&text, opt)
        .unwrap_or_else(|e| panic!("{}: not a valid SVG ({e})", path.display()));
    let (w, h) = (tree.size().width(), tree.size().height());
    let mut boxes = Vec::new();
    texts(tree.root(), &mut boxes);
    let name = path.file_name().unwrap().to_string_lossy();
    let mut out = Vec::new();
    if boxes.is_empty() {
        out.push(format!(
            "{name}: no text laid out (no title, axes or legend?)"
        ));
    }
    // Half a pixel of slack for anti-aliasing rounding.
    for t in &boxes {
        let [l, tp, r, b] = t.b;
        if l < -0.5 || tp < -0.5 || r > w + 0.5 || b > h + 0.5 {
            out.push(format!(
                "{name}: '{}' at [{l:.0}, {tp:.0}, {r:.0}, {b:.0}] leaves the {w:.0} x {h:.0} canvas",
                t.text
            ));
        }
    }
    for (i, a) in boxes.iter().enumerate() {
        for b in &boxes[i + 1..] {
            if overlap(&a.b, &b.b) > 2.0 {
                out.push(format!("{name}: '{}' overlaps '{}'", a.text, b.text));
            }
        }
    }
    out
}

/// Produce every kind of figure into `root`.
fn make_figures(shared: &Path, root: &Path) {
    let repo = common::repo_root();
    let lm = repo.join("fixtures/example-scoliosis.csv");
    let truth = repo.join("fixtures/example-scoliosis-centres.csv");
    let patient = root.join("generate/patient.osim");
    run(&["generate", "--landmarks", s(&lm), "--out", s(&patient)]);
    run(&["base", "--procedural", "--out", s(&root.join("base"))]);
    let ev = root.join("evaluate");
    let ev_args = ["evaluate", "--model", s(&patient), "--truth", s(&truth)];
    run(&[
        &ev_args[..],
        &["--truth-landmarks", s(&lm), "--out", s(&ev)],
    ]
    .concat());
    let d01 = shared.join("scoliosis-dev/D01_thoracic45");
    let sets: Vec<PathBuf> = (1..=3)
        .map(|k| d01.join(format!("landmarks_noise2mm_{k}.csv")))
        .collect();
    let mut var: Vec<&str> = vec!["variability"];
    var.extend(sets.iter().map(|p| s(p)));
    let var_out = root.join("variability");
    var.extend(["--out", s(&var_out)]);
    run(&var);
    let exp = shared.join("diagnose-dev/dev-09");
    run(&[
        "calibrate",
        s(&exp),
        "--starts",
        "1",
        "--out",
        s(&root.join("cal")),
    ]);
    run(&[
        "diagnose",
        s(&exp),
        "--quiet",
        "--out",
        s(&root.join("diag")),
    ]);
    let sens = ["sensitivity", s(&exp), "--samples", "4"];
    run(&[&sens[..], &["--out", s(&root.join("sens"))]].concat());
}

/// DejaVu Sans when present, else the first family of the database.
fn sans_family(db: &usvg::fontdb::Database) -> Option<String> {
    let families: Vec<String> = db
        .faces()
        .filter_map(|f| f.families.first().map(|(n, _)| n.clone()))
        .collect();
    families
        .iter()
        .find(|f| f.as_str() == "DejaVu Sans")
        .or(families.first())
        .cloned()
}

#[test]
fn every_figure_keeps_its_text_inside_and_apart() {
    let Some(shared) = common::shared_dir() else {
        return;
    };
    let mut opt = usvg::Options::default();
    opt.fontdb_mut().load_system_fonts();
    // The generic "sans-serif" of the figures maps to a font the machine
    // has (fontdb's default, Arial, may be absent).
    let Some(family) = sans_family(&opt.fontdb) else {
        common::skip("no system fonts: text cannot be laid out");
        return;
    };
    opt.fontdb_mut().set_sans_serif_family(family.clone());
    opt.font_family = family;
    let tmp = tempfile::tempdir().unwrap();
    make_figures(&shared, tmp.path());
    let files = svgs(tmp.path());
    // generate 2, base 2, evaluate, variability, calibrate 2, diagnose 2, sensitivity 1
    assert!(files.len() >= 12, "only {} figures: {files:?}", files.len());
    let mut findings = Vec::new();
    for f in &files {
        findings.extend(layout_findings(f, &opt));
    }
    println!("{} figures laid out", files.len());
    assert!(
        findings.is_empty(),
        "{} layout finding(s):\n{}",
        findings.len(),
        findings.join("\n")
    );
}
