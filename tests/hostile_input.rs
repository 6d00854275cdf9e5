//! Hostile and everyday inputs, by category. Each asserts a clean refusal
//! (non-zero exit, the file named, no panic text, nothing written) or the
//! correct result. Inputs are generated in a temporary folder: devices
//! through symlinks, FIFOs through `mkfifo`, large models by string
//! building. The later rounds live in `hostile_input/`, one file per topic.

mod common;

#[path = "hostile_input/everyday.rs"]
mod everyday;
#[path = "hostile_input/nifti.rs"]
mod label_maps;
#[path = "hostile_input/model_files.rs"]
mod model_files;
#[path = "hostile_input/outputs.rs"]
mod outputs;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn run(args: &[&str]) -> Output {
    Command::new(common::bin()).args(args).output().unwrap()
}

fn text(o: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

/// Non-zero exit, `named` in the message, no panic text.
fn assert_refused(o: &Output, named: &str, fragment: &str) {
    let t = text(o);
    assert_ne!(o.status.code(), Some(0), "accepted:\n{t}");
    assert!(!t.contains("panicked"), "panic:\n{t}");
    assert!(t.contains(named), "does not name '{named}':\n{t}");
    assert!(t.contains(fragment), "lacks '{fragment}':\n{t}");
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn symlink(target: &str, link: &Path) {
    std::os::unix::fs::symlink(target, link).unwrap();
}

fn mkfifo(p: &Path) {
    let ok = Command::new("mkfifo").arg(p).status().unwrap().success();
    assert!(ok, "mkfifo failed");
}

/// The files left in `dir` besides `keep`.
fn written(dir: &Path, keep: &[&str]) -> Vec<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| !keep.contains(&n.as_str()))
        .collect()
}

/// The checked-in valid corpus model (sacrum + L5, one bushing).
fn corpus_model() -> String {
    std::fs::read_to_string(common::repo_root().join("tests/corpus/osim/valid_base.osim")).unwrap()
}

fn load_file(dir: &Path) -> PathBuf {
    let p = dir.join("load.toml");
    std::fs::write(&p, "[[case]]\nid = \"rest\"\nbody = \"L5\"\n").unwrap();
    p
}

// ---------------------------------------------------------------------------
// Out of memory (10): devices and symlinks to them are not regular files.

#[test]
fn devices_are_refused_by_every_reader() {
    let d = tempfile::tempdir().unwrap();
    let model = d.path().join("m.osim");
    std::fs::write(&model, corpus_model()).unwrap();
    let (zero_csv, rand_trc, zero_vtp, zero_stl) = (
        d.path().join("zero.csv"),
        d.path().join("rand.trc"),
        d.path().join("zero.vtp"),
        d.path().join("zero.stl"),
    );
    symlink("/dev/zero", &zero_csv);
    symlink("/dev/urandom", &rand_trc);
    symlink("/dev/zero", &zero_vtp);
    symlink("/dev/urandom", &zero_stl);
    // landmark files (check, generate)
    assert_refused(&run(&["check", s(&zero_csv)]), "zero.csv", "device");
    assert_refused(&run(&["check", s(&rand_trc)]), "rand.trc", "device");
    assert_refused(&run(&["check", "/dev/zero"]), "/dev/zero", "");
    // meshes
    let out = d.path().join("o.obj");
    assert_refused(
        &run(&["convert", s(&zero_vtp), s(&out)]),
        "zero.vtp",
        "device",
    );
    assert_refused(
        &run(&["convert", s(&zero_stl), s(&out)]),
        "zero.stl",
        "device",
    );
    // load file
    let zero_toml = d.path().join("zero.toml");
    symlink("/dev/zero", &zero_toml);
    let o = run(&[
        "simulate",
        s(&model),
        "--load",
        s(&zero_toml),
        "--out",
        s(&d.path().join("sim")),
    ]);
    assert_refused(&o, "zero.toml", "device");
    // stiffness table
    let o = run(&[
        "stiffness",
        s(&model),
        "--table",
        s(&zero_toml),
        "--out",
        s(&d.path().join("n.osim")),
    ]);
    assert_refused(&o, "zero.toml", "device");
    assert_eq!(
        written(
            d.path(),
            &[
                "m.osim",
                "zero.csv",
                "rand.trc",
                "zero.vtp",
                "zero.stl",
                "zero.toml"
            ]
        ),
        Vec::<String>::new()
    );
}

#[test]
fn experiment_files_and_ratio_tables_that_are_devices_are_refused() {
    let Some(dev) = common::shared("diagnose-dev/dev-01") else {
        return;
    };
    let d = tempfile::tempdir().unwrap();
    for (bad, target) in [
        ("experiment.toml", "/dev/zero"),
        ("kinematics.csv", "/dev/urandom"),
    ] {
        let exp = d.path().join(format!("exp-{bad}"));
        std::fs::create_dir(&exp).unwrap();
        for f in ["experiment.toml", "kinematics.csv", "specimen.osim"] {
            if f == bad {
                symlink(target, &exp.join(f));
            } else {
                std::fs::copy(dev.join(f), exp.join(f)).unwrap();
            }
        }
        let out = d.path().join(format!("out-{bad}"));
        let o = run(&["calibrate", s(&exp), "--starts", "1", "--out", s(&out)]);
        assert_refused(&o, bad, "device");
        assert!(!out.exists(), "calibrate wrote {out:?}");
    }
    // --params ratio:TABLE
    let ratio = d.path().join("ratio.toml");
    symlink("/dev/zero", &ratio);
    let out = d.path().join("out-ratio");
    let arg = format!("ratio:{}", s(&ratio));
    let o = run(&[
        "calibrate",
        s(&dev),
        "--params",
        &arg,
        "--starts",
        "1",
        "--out",
        s(&out),
    ]);
    assert_refused(&o, "ratio.toml", "device");
    assert!(!out.exists());
}

#[test]
fn evaluate_truth_mesh_that_is_a_device_is_refused() {
    let d = tempfile::tempdir().unwrap();
    let truth = d.path().join("truth");
    std::fs::create_dir(&truth).unwrap();
    symlink("/dev/zero", &truth.join("L1.vtp"));
    let model = common::repo_root().join("base_model/base.osim");
    let o = run(&[
        "evaluate",
        "--model",
        s(&model),
        "--truth",
        s(&truth),
        "--truth-units",
        "mm",
        "--truth-frame",
        "LPS",
        "--out",
        s(&d.path().join("ev")),
    ]);
    assert_refused(&o, "L1.vtp", "device");
    assert!(!d.path().join("ev").exists());
}

// ---------------------------------------------------------------------------
// Hangs (6).

#[test]
fn fifo_landmark_file_is_refused_without_blocking() {
    let d = tempfile::tempdir().unwrap();
    let fifo = d.path().join("pipe.csv");
    mkfifo(&fifo);
    assert_refused(&run(&["check", s(&fifo)]), "pipe.csv", "FIFO");
    let out = d.path().join("p.osim");
    let base = common::repo_root().join("base_model");
    let o = run(&[
        "generate",
        "--base",
        s(&base),
        "--landmarks",
        s(&fifo),
        "--out",
        s(&out),
    ]);
    assert_refused(&o, "pipe.csv", "FIFO");
    assert!(!out.exists());
}

/// A chain of `n` bodies on pin joints, as OpenSim writes one.
fn chain(n: usize) -> String {
    let mut b = String::new();
    let mut j = String::new();
    for i in 0..n {
        b += &format!("<Body name=\"b{i}\"><mass>1</mass><mass_center>0 0 0</mass_center><inertia>0.01 0.01 0.01 0 0 0</inertia></Body>\n");
        let parent = if i == 0 {
            "/ground".to_string()
        } else {
            format!("/bodyset/b{}", i - 1)
        };
        j += &format!("<PinJoint name=\"j{i}\"><socket_parent_frame>p</socket_parent_frame><socket_child_frame>c</socket_child_frame><coordinates><Coordinate name=\"q{i}\"><default_value>0</default_value><range>-1 1</range></Coordinate></coordinates><frames><PhysicalOffsetFrame name=\"p\"><socket_parent>{parent}</socket_parent><translation>0 0.01 0</translation><orientation>0 0 0</orientation></PhysicalOffsetFrame><PhysicalOffsetFrame name=\"c\"><socket_parent>/bodyset/b{i}</socket_parent><translation>0 0 0</translation><orientation>0 0 0</orientation></PhysicalOffsetFrame></frames></PinJoint>\n");
    }
    format!("<?xml version=\"1.0\" encoding=\"UTF-8\" ?>\n<OpenSimDocument Version=\"40600\"><Model name=\"chain\"><Ground name=\"ground\" /><gravity>0 -9.80665 0</gravity>\n<BodySet name=\"bodyset\"><objects>{b}</objects></BodySet>\n<JointSet name=\"jointset\"><objects>{j}</objects></JointSet></Model></OpenSimDocument>\n")
}

#[test]
fn long_chain_is_read_and_converted() {
    // 20,000 bodies: linear cost (timings in BENCHMARKS.md, not here).
    let d = tempfile::tempdir().unwrap();
    let m = d.path().join("chain.osim");
    std::fs::write(&m, chain(20_000)).unwrap();
    let o = run(&["info", s(&m)]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("20000"), "{}", text(&o));
    let out = d.path().join("out.osim");
    let o = run(&["convert", s(&m), s(&out)]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(out.exists());
}

#[test]
fn many_attributes_on_one_element_are_read() {
    let d = tempfile::tempdir().unwrap();
    let attrs: String = (0..200_000).map(|i| format!(" a{i}=\"{i}\"")).collect();
    let m = d.path().join("attrs.osim");
    std::fs::write(
        &m,
        corpus_model().replacen(
            "<Body name=\"L5\">",
            &format!("<Body name=\"L5\"{attrs}>"),
            1,
        ),
    )
    .unwrap();
    let o = run(&["info", s(&m)]);
    assert!(o.status.success(), "{}", text(&o));
    // a duplicate among them is still found
    let dup = corpus_model().replacen(
        "<Body name=\"L5\">",
        &format!("<Body name=\"L5\"{attrs} a7=\"x\">"),
        1,
    );
    std::fs::write(&m, dup).unwrap();
    assert_refused(
        &run(&["info", s(&m)]),
        "attrs.osim",
        "duplicate attribute 'a7'",
    );
}

#[test]
fn dynamic_run_beyond_the_step_cap_is_refused() {
    let d = tempfile::tempdir().unwrap();
    let m = d.path().join("m.osim");
    std::fs::write(&m, corpus_model()).unwrap();
    let load = load_file(d.path());
    let out = d.path().join("sim");
    let o = run(&[
        "simulate",
        s(&m),
        "--load",
        s(&load),
        "--dynamic",
        "1e9",
        "--dt",
        "1e-9",
        "--out",
        s(&out),
    ]);
    assert_refused(&o, "--dynamic", "more than the cap");
    assert!(!out.exists());
}

// ---------------------------------------------------------------------------
// Silently wrong or accepted (20).

fn vtp(points: &str, extra_prolog: &str) -> String {
    format!("<?xml version=\"1.0\"?>{extra_prolog}<VTKFile type=\"PolyData\" version=\"0.1\"><PolyData><Piece NumberOfPoints=\"3\" NumberOfPolys=\"1\"><Points><DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"ascii\">{points}</DataArray></Points><Polys><DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">0 1 2</DataArray><DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">3</DataArray></Polys></Piece></PolyData></VTKFile>")
}

#[test]
fn vtp_shares_the_osim_xml_rules() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("o.obj");
    let cases = [
        (
            "doctype.vtp",
            vtp("0 0 0 1 0 0 0 1 0", "<!DOCTYPE v>"),
            "DOCTYPE",
        ),
        (
            "entity.vtp",
            vtp(
                "5&x;0.01 0 0 1 0 0 0 1 0",
                "<!DOCTYPE v [<!ENTITY x \"\">]>",
            ),
            "DOCTYPE",
        ),
        (
            "undefined.vtp",
            vtp("5&x;0.01 0 0 1 0 0 0 1 0", ""),
            "undefined entity '&x;'",
        ),
        (
            "laughs.vtp",
            vtp(
                "&b;",
                "<!DOCTYPE v [<!ENTITY a \"0 0 0 \"><!ENTITY b \"&a;&a;&a;\">]>",
            ),
            "DOCTYPE",
        ),
        (
            "xxe.vtp",
            vtp(
                "&e;",
                "<!DOCTYPE v [<!ENTITY e SYSTEM \"file:///etc/passwd\">]>",
            ),
            "DOCTYPE",
        ),
    ];
    for (name, body, fragment) in cases {
        let p = d.path().join(name);
        std::fs::write(&p, body).unwrap();
        assert_refused(&run(&["convert", s(&p), s(&out)]), name, fragment);
        assert!(!out.exists());
    }
    // The predefined entities and numeric references still read.
    let p = d.path().join("ok.vtp");
    std::fs::write(&p, vtp("&#48; 0 0 1 0 0 0 1 0", "")).unwrap();
    let o = run(&["convert", s(&p), s(&out)]);
    assert!(o.status.success(), "{}", text(&o));
}

fn with_l5(model: &str, from: &str, to: &str) -> String {
    assert!(model.contains(from), "{from}");
    model.replacen(from, to, 1)
}

#[test]
fn inertia_must_be_physical() {
    let d = tempfile::tempdir().unwrap();
    let base = corpus_model();
    let l5 = "<inertia>0.00067 0.00098 0.00045 0 0 0</inertia>";
    for (name, inertia) in [
        (
            "indefinite.osim",
            "<inertia>0.001 0.001 0.001 0.002 0 0</inertia>",
        ),
        (
            "negative.osim",
            "<inertia>-0.001 0.001 0.001 0 0 0</inertia>",
        ),
    ] {
        let p = d.path().join(name);
        std::fs::write(&p, with_l5(&base, l5, inertia)).unwrap();
        assert_refused(&run(&["info", s(&p)]), name, "not positive definite");
    }
    // 1 + 2 < 4: a warning in info, refused by forward dynamics.
    let p = d.path().join("triangle.osim");
    std::fs::write(
        &p,
        with_l5(&base, l5, "<inertia>0.001 0.002 0.004 0 0 0</inertia>"),
    )
    .unwrap();
    let o = run(&["info", s(&p)]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("triangle inequality"), "{}", text(&o));
    let load = load_file(d.path());
    let out = d.path().join("sim");
    let o = run(&[
        "simulate",
        s(&p),
        "--load",
        s(&load),
        "--dynamic",
        "0.01",
        "--out",
        s(&out),
    ]);
    assert_refused(&o, "triangle.osim", "triangle inequality");
    assert!(!out.exists());
}

#[test]
fn coordinate_defaults_and_stiffness_are_bounded() {
    let d = tempfile::tempdir().unwrap();
    let base = corpus_model();
    let p = d.path().join("default.osim");
    std::fs::write(
        &p,
        with_l5(
            &base,
            "<default_value>0</default_value>",
            "<default_value>1e308</default_value>",
        ),
    )
    .unwrap();
    assert_refused(
        &run(&["info", s(&p)]),
        "default.osim",
        "default_value 1e308",
    );
    // outside the range: a warning
    std::fs::write(
        &p,
        with_l5(
            &base,
            "<default_value>0</default_value>",
            "<default_value>0.7</default_value>",
        ),
    )
    .unwrap();
    let o = run(&["info", s(&p)]);
    assert!(
        o.status.success() && text(&o).contains("outside its range"),
        "{}",
        text(&o)
    );
    // 1e308 stiffness in the model and in a table
    let k = "<rotational_stiffness>68.8 291 51</rotational_stiffness>";
    let p = d.path().join("stiff.osim");
    std::fs::write(
        &p,
        with_l5(
            &base,
            k,
            "<rotational_stiffness>1e308 291 51</rotational_stiffness>",
        ),
    )
    .unwrap();
    assert_refused(&run(&["info", s(&p)]), "stiff.osim", "rotational_stiffness");
    let m = d.path().join("m.osim");
    std::fs::write(&m, &base).unwrap();
    let t = d.path().join("t.toml");
    std::fs::write(&t, "format = \"osim-spine stiffness table 1\"\n[units]\nrotational = \"N*m/rad\"\ntranslational = \"N/m\"\nrot_damping = \"N*m*s/rad\"\ntrans_damping = \"N*s/m\"\n[all]\nform = \"linear\"\nstiffness = { rx = 1e308 }\n").unwrap();
    let out = d.path().join("n.osim");
    let o = run(&["stiffness", s(&m), "--table", s(&t), "--out", s(&out)]);
    assert_refused(&o, "t.toml", "1e308");
    assert!(!out.exists());
}

#[test]
fn negative_bushing_stiffness_is_named() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("neg.osim");
    let k = "<rotational_stiffness>68.8 291 51</rotational_stiffness>";
    std::fs::write(
        &p,
        with_l5(
            &corpus_model(),
            k,
            "<rotational_stiffness>-68.8 291 51</rotational_stiffness>",
        ),
    )
    .unwrap();
    let load = load_file(d.path());
    let o = run(&[
        "simulate",
        s(&p),
        "--load",
        s(&load),
        "--out",
        s(&d.path().join("sim")),
    ]);
    let t = text(&o);
    assert!(
        t.contains("bushing_sacrum_L5") && t.contains("may be unstable"),
        "{t}"
    );
}

#[test]
fn huge_mesh_coordinates_and_empty_stl_are_refused() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("o.obj");
    let stl_big = "solid x\nfacet normal 0 0 1\nouter loop\nvertex 1e308 0 0\nvertex 0 1 0\nvertex 0 0 1\nendloop\nendfacet\nendsolid x\n";
    let cases = [
        ("big.vtp", vtp("1e308 0 0 0 1 0 0 0 1", ""), "beyond"),
        ("big.stl", stl_big.to_string(), "beyond"),
        ("only.stl", "solid x\n".to_string(), "no facets"),
        (
            "junk.stl",
            "solid\nnot a facet\n".to_string(),
            "unexpected `not`",
        ),
    ];
    for (name, body, fragment) in cases {
        let p = d.path().join(name);
        std::fs::write(&p, body).unwrap();
        assert_refused(&run(&["convert", s(&p), s(&out)]), name, fragment);
        assert!(!out.exists());
    }
}

#[test]
fn trc_header_counts_are_bounded() {
    let d = tempfile::tempdir().unwrap();
    for (name, counts) in [
        ("markers.trc", "2\t1000000000"),
        ("frames.trc", "1000000000\t1"),
    ] {
        let t = format!("PathFileType\t4\t(X/Y/Z)\tx.trc\nDataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\n100\t100\t{counts}\tmm\nFrame#\tTime\tL1_SECC\n\t\tX1\tY1\tZ1\n1\t0\t0\t0\t0\n");
        let p = d.path().join(name);
        std::fs::write(&p, t).unwrap();
        assert_refused(&run(&["check", s(&p)]), name, "1000000000");
    }
}

#[test]
fn cobb_ends_must_be_two_vertebrae() {
    let model = common::repo_root().join("base_model/base.osim");
    let d = tempfile::tempdir().unwrap();
    let truth = d.path().join("c.csv");
    std::fs::write(
        &truth,
        "# units: m\n# frame: opensim\nlevel,x,y,z\nL1,0,0,0\n",
    )
    .unwrap();
    let o = run(&[
        "evaluate",
        "--model",
        s(&model),
        "--truth",
        s(&truth),
        "--cobb-ends",
        "L1,L1",
        "--out",
        s(&d.path().join("ev")),
    ]);
    assert_refused(&o, "--cobb-ends", "UPPER must be a vertebra above LOWER");
}

// ---------------------------------------------------------------------------
// Inputs overwritten (2).

#[test]
fn generate_does_not_overwrite_the_base_model() {
    let d = tempfile::tempdir().unwrap();
    let b = d.path().join("b");
    std::fs::create_dir(&b).unwrap();
    let base = b.join("base.osim");
    std::fs::copy(common::repo_root().join("base_model/base.osim"), &base).unwrap();
    let before = std::fs::read(&base).unwrap();
    let lm = d.path().join("lm.csv");
    std::fs::write(&lm, "x").unwrap();
    let o = run(&[
        "generate",
        "--base",
        s(&b),
        "--landmarks",
        s(&lm),
        "--out",
        s(&base),
    ]);
    assert_refused(&o, "base.osim", "--force");
    // a symlink elsewhere that points at the base
    let link = d.path().join("link.osim");
    symlink(s(&base), &link);
    let o = run(&[
        "generate",
        "--base",
        s(&b),
        "--landmarks",
        s(&lm),
        "--out",
        s(&link),
    ]);
    assert_refused(&o, "link.osim", "overwrite the input");
    assert_eq!(std::fs::read(&base).unwrap(), before);
}

#[test]
fn stiffness_list_does_not_overwrite_the_model() {
    let d = tempfile::tempdir().unwrap();
    let m = d.path().join("m.osim");
    std::fs::write(&m, corpus_model()).unwrap();
    let o = run(&["stiffness", s(&m), "--list", "--out", s(&m)]);
    assert_refused(&o, "m.osim", "overwrite the input");
    assert_eq!(std::fs::read_to_string(&m).unwrap(), corpus_model());
    // --list --out checks the extension
    let o = run(&[
        "stiffness",
        s(&m),
        "--list",
        "--out",
        s(&d.path().join("t.osim")),
    ]);
    assert_refused(&o, "t.osim", ".toml or .csv");
    let o = run(&[
        "stiffness",
        s(&m),
        "--list",
        "--out",
        s(&d.path().join("t.toml")),
    ]);
    assert!(o.status.success(), "{}", text(&o));
}

// ---------------------------------------------------------------------------
// Panics (2): a closed stdout ends the command quietly.

/// Run `args` with stdout closed by the reader before anything is read.
fn run_with_closed_stdout(args: &[&str]) -> Output {
    let mut child = Command::new(common::bin())
        .args(args)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    child.wait_with_output().unwrap()
}

#[test]
fn closed_stdout_is_not_a_panic() {
    let d = tempfile::tempdir().unwrap();
    let bad = d.path().join("bad.csv");
    std::fs::write(&bad, "x\n").unwrap();
    // check: > 64 KB of findings
    let many: Vec<&str> = std::iter::once("check")
        .chain(std::iter::repeat_n(s(&bad), 2000))
        .collect();
    let o = run_with_closed_stdout(&many);
    assert!(!text(&o).contains("panicked"), "{}", text(&o));
    assert_ne!(o.status.code(), Some(101), "{}", text(&o));
    // info --json of a 2,000-body chain (> 64 KB)
    let m = d.path().join("chain.osim");
    std::fs::write(&m, chain(2_000)).unwrap();
    let o = run_with_closed_stdout(&["info", "--json", s(&m)]);
    assert!(!text(&o).contains("panicked"), "{}", text(&o));
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
}

#[test]
fn no_command_writes_where_an_input_is() {
    let d = tempfile::tempdir().unwrap();
    let m = d.path().join("m.osim");
    std::fs::write(&m, corpus_model()).unwrap();
    let load = load_file(d.path());
    let exp = d.path().join("exp");
    std::fs::create_dir(&exp).unwrap();
    std::fs::write(exp.join("experiment.toml"), "x").unwrap();
    let seg = d.path().join("seg");
    std::fs::create_dir(&seg).unwrap();
    let mesh = d.path().join("a.stl");
    std::fs::write(&mesh, "solid a\nendsolid a\n").unwrap();
    let lm = d.path().join("lm.csv");
    std::fs::write(&lm, "x").unwrap();
    let snapshot = |p: &Path| std::fs::read(p).unwrap();
    let before = (snapshot(&m), snapshot(&exp.join("experiment.toml")));
    let (dir, e) = (s(d.path()), s(&exp));
    let refusals: Vec<(Vec<&str>, &str)> = vec![
        (vec!["convert", s(&m), s(&m)], "overwrite the input"),
        (
            vec!["simulate", s(&m), "--load", s(&load), "--out", dir],
            "holds the input",
        ),
        (vec!["calibrate", e, "--out", e], "holds the input"),
        (vec!["diagnose", e, "--out", e], "holds the input"),
        (vec!["sensitivity", e, "--out", e], "holds the input"),
        (
            vec![
                "evaluate",
                "--model",
                s(&m),
                "--truth",
                s(&lm),
                "--out",
                dir,
            ],
            "holds the input",
        ),
        (
            vec!["base", "--generic", s(&m), "--out", dir],
            "holds the input",
        ),
        (
            vec!["variability", s(&lm), s(&lm), "--out", dir],
            "holds the input",
        ),
        (
            vec!["mean-shape", s(&mesh), s(&mesh), "--out", s(&mesh)],
            "overwrite the input",
        ),
    ];
    for (args, fragment) in &refusals {
        let o = run(args);
        assert_refused(&o, "--force", fragment);
    }
    let into_seg = seg.join("lm.csv");
    let o = run(&["palpate", s(&seg), "--out", s(&into_seg)]);
    assert_refused(&o, "seg", "input folder");
    assert!(!into_seg.exists());
    assert_eq!(
        before,
        (snapshot(&m), snapshot(&exp.join("experiment.toml")))
    );
}
