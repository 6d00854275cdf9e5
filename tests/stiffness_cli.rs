//! `osim-spine stiffness` from the command line: acceptance 2 (`--list`
//! then `--table` of its own output reproduces the model byte for byte, for
//! OpenSim-written models and for models holding every form) and acceptance
//! 3 (bad tables are rejected naming the offending row, nothing written),
//! each checked by one function per acceptance on the dev specimen and on
//! the project's base model `base_model/base.osim`.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const UNITS: &str = "[units]\nrotational = \"N*m/rad\"\ntranslational = \"N/m\"\nrot_damping = \"N*m*s/rad\"\ntrans_damping = \"N*s/m\"\n";

fn run(args: &[&str]) -> Output {
    Command::new(common::bin()).args(args).output().unwrap()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Apply `table` (TOML text) to `model`; returns (output path, process output).
fn apply(model: &Path, table: &str, dir: &Path, tag: &str, ext: &str) -> (PathBuf, Output) {
    let t = dir.join(format!("{tag}.{ext}"));
    std::fs::write(&t, table).unwrap();
    let out = dir.join(format!("{tag}.osim"));
    let o = run(&["stiffness", s(model), "--table", s(&t), "--out", s(&out)]);
    (out, o)
}

fn list(model: &Path, format: &str) -> String {
    let o = run(&["stiffness", s(model), "--list", "--format", format]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8(o.stdout).unwrap()
}

/// list -> table -> identical bytes, in TOML (and CSV when `csv`).
fn assert_round_trip(model: &Path, dir: &Path, tag: &str, csv: bool) {
    let formats: &[&str] = if csv { &["toml", "csv"] } else { &["toml"] };
    for f in formats {
        let text = list(model, f);
        let (out, o) = apply(model, &text, dir, &format!("{tag}_rt_{f}"), f);
        assert!(
            o.status.success(),
            "{tag} {f}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        // The model as written: its own bytes for a 4.6 file, the upgraded
        // document for an older one (a 4.0 file is written as 4.6).
        let doc = osim_spine::osim::Document::read(model).unwrap();
        let want = if doc.original_version() == doc.version() {
            std::fs::read(model).unwrap()
        } else {
            doc.to_xml_string().into_bytes()
        };
        assert_eq!(
            want,
            std::fs::read(&out).unwrap(),
            "{tag}: --list ({f}) then --table changed the model"
        );
        // listing is deterministic
        assert_eq!(text, list(model, f));
    }
}

fn forms_tables() -> Vec<(&'static str, String)> {
    vec![
        (
            "nonlinear",
            format!("{UNITS}[all]\nform = \"nonlinear\"\nstiffness = {{ rx = 68.8, ry = 291, tx = 149000, ty = 1890000, tz = 135000 }}\ndamping = {{ rx = 2.3, ry = 2.3, rz = 2.3, tx = 1000, ty = 1000, tz = 1000 }}\n[[all.curve]]\ndof = \"rz\"\nkind = \"points\"\ninterp = \"spline\"\nx = [-0.3, 0.0, 0.1, 0.3]\ny = [-20.0, 0.0, 5.0, 19.0]\n[[all.curve]]\ndof = \"rx\"\nkind = \"polynomial\"\ncoefficients = [5.0, 0.0, 70.0, 0.1]\n"),
        ),
        (
            "sinh",
            format!("{UNITS}[all]\nform = \"nonlinear\"\nstiffness = {{ tx = 149000, ty = 1890000, tz = 135000 }}\ndamping = {{ rx = 2.3, ry = 2.3, rz = 2.3, tx = 1000, ty = 1000, tz = 1000 }}\n[[all.curve]]\ndof = \"rx\"\nkind = \"sinh\"\nk = 68.8\na = 0.05\n[[all.curve]]\ndof = \"ry\"\nkind = \"bilinear\"\nk_neg = 250.0\nk_pos = 300.0\n[[all.curve]]\ndof = \"rz\"\nkind = \"cubic\"\nk = 51.0\nc = 0.7\n"),
        ),
        (
            "coupled",
            format!("{UNITS}[all]\nform = \"coupled\"\ndamping = {{ rx = 2.3, ry = 2.3, rz = 2.3, tx = 1000, ty = 1000, tz = 1000 }}\nmatrix = [[68.8, 0, 8, 0, 0, 0], [0, 291, 0, 0, 0, 0], [8, 0, 51, 0, 0, -150.5], [0, 0, 0, 149000, 0, 0], [0, 0, 0, 0, 1890000, 0], [0, 0, -150.5, 0, 0, 135000]]\n"),
        ),
        (
            "expression",
            format!("{UNITS}[[level]]\nname = \"L5_S1\"\nform = \"expression\"\ndamping = {{ rx = 2.3, ry = 2.3, rz = 2.3, tx = 1000, ty = 1000, tz = 1000 }}\nexpressions = {{ rx = \"68.8*theta_x*(1+max(0,-delta_y)*100)\", ry = \"291*theta_y\", rz = \"51*theta_z+0.5*theta_x\", tx = \"149000*delta_x\", ty = \"1890000*delta_y\", tz = \"135000*delta_z\" }}\n"),
        ),
    ]
}

/// Acceptance 2 on one model: `--list` then `--table` reproduces it (TOML
/// and CSV), and so does every model the tool writes from it, one per form.
fn assert_model_round_trips(model: &Path, dir: &Path, label: &str) {
    assert_round_trip(model, dir, label, true);
    for (tag, table) in forms_tables() {
        let tag_full = format!("{label}_{tag}");
        let (out, o) = apply(model, &table, dir, &tag_full, "toml");
        assert!(
            o.status.success(),
            "{tag_full}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        assert_round_trip(&out, dir, &tag_full, false);
        let text = list(&out, "toml");
        assert!(
            text.contains(&format!(
                "form = \"{}\"",
                if tag == "sinh" { "nonlinear" } else { tag }
            )),
            "{tag_full}:\n{text}"
        );
    }
}

#[test]
fn list_then_table_reproduces_models_byte_for_byte() {
    let (Some(chain), Some(spec)) = (
        common::shared("oracle/chain17.osim"),
        common::shared("diagnose-dev/dev-01/specimen.osim"),
    ) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    // OpenSim-written models (numbers as OpenSim prints them: 68.799999999999997)
    assert_round_trip(&chain, dir.path(), "chain17", true);
    // the specimen and the models written from it, one per form
    assert_model_round_trips(&spec, dir.path(), "specimen");
}

#[test]
fn base_model_list_then_table_reproduces_it_byte_for_byte() {
    let dir = tempfile::tempdir().unwrap();
    let base = common::repo_root().join("base_model/base.osim");
    assert_model_round_trips(&base, dir.path(), "base_model");
}

#[test]
fn applied_values_are_listed_back() {
    let Some(spec) = common::shared("diagnose-dev/dev-01/specimen.osim") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    // base x ratio in non-SI units, uniform damping, per-level override by alias
    let table = "[units]\nrotational = \"N*m/deg\"\ntranslational = \"N/mm\"\nrot_damping = \"N*m*s/rad\"\ntrans_damping = \"N*s/m\"\n[all]\nstiffness = { rx = 1.0, ry = 5.0, rz = 1.0, tx = 149, ty = 1890, tz = 135 }\ndamping = { rx = 2.0, ry = 2.0, rz = 2.0, tx = 900, ty = 900, tz = 900 }\n[[level]]\nname = \"L2_L3\"\nratio = { rx = 0.5, tz = 2.0 }\n";
    let (out, o) = apply(&spec, table, dir.path(), "units", "toml");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let csv = list(&out, "csv");
    let deg = 180.0 / std::f64::consts::PI;
    let rows: Vec<Vec<String>> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').map(String::from).collect())
        .collect();
    assert_eq!(rows.len(), 5);
    for r in &rows {
        let v: Vec<f64> = r[1..].iter().map(|x| x.parse().unwrap()).collect();
        let (rx, tz) = if r[0] == "L2_L3" {
            (0.5 * deg, 270000.0)
        } else {
            (deg, 135000.0)
        };
        assert!((v[0] - rx).abs() < 1e-12 * rx, "{r:?}");
        assert!((v[1] - 5.0 * deg).abs() < 1e-12 * deg * 5.0);
        assert!((v[5] - tz).abs() < 1e-9, "{r:?}");
        assert_eq!(v[6..9], [2.0, 2.0, 2.0]);
        assert_eq!(v[9..12], [900.0, 900.0, 900.0]);
    }
    // the CSV form of the same table gives the same model
    let csv_table = "level,rx [N*m/deg],ry [N*m/deg],rz [N*m/deg],tx [N/mm],ty [N/mm],tz [N/mm],c_rx [N*m*s/rad],c_ry [N*m*s/rad],c_rz [N*m*s/rad],c_tx [N*s/m],c_ty [N*s/m],c_tz [N*s/m],ratio_rx [1],ratio_tz [1]\n*,1.0,5.0,1.0,149,1890,135,2,2,2,900,900,900,,\nL2_L3,,,,,,,,,,,,,0.5,2.0\n";
    let (out_csv, o) = apply(&spec, csv_table, dir.path(), "units_csv", "csv");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(
        std::fs::read(&out).unwrap(),
        std::fs::read(&out_csv).unwrap()
    );
}

/// Acceptance 3 on one model (which must have the levels L1_L2 to L5_S1):
/// each bad table is rejected naming the offending row, nothing is written;
/// a softening curve is accepted with `--allow-softening`.
fn assert_bad_tables_rejected(spec: &Path, label: &str) {
    let dir = tempfile::tempdir().unwrap();
    let lin = "stiffness = { rx = 68.8, ry = 291, rz = 51.0, tx = 149000, ty = 1890000, tz = 135000 }\ndamping = { rx = 2.3, ry = 2.3, rz = 2.3, tx = 1000, ty = 1000, tz = 1000 }\n";
    let cases: Vec<(&str, String, &str, &[&str])> = vec![
        ("unknown_level", format!("{UNITS}[[level]]\nname = \"L9_L10\"\n{lin}"), "toml", &["[[level]] #1 'L9_L10'", "unknown level"]),
        ("negative_stiffness", format!("{UNITS}[all]\n{lin}[[level]]\nname = \"L3_L4\"\nstiffness = {{ ry = -5.0 }}\n"), "toml", &["'L3_L4'", "stiffness ry must be positive"]),
        ("indefinite", format!("{UNITS}[[level]]\nname = \"L4_L5\"\nform = \"coupled\"\nmatrix = [[68.8, 100, 0, 0, 0, 0], [100, 51, 0, 0, 0, 0], [0, 0, 51, 0, 0, 0], [0, 0, 0, 149000, 0, 0], [0, 0, 0, 0, 1890000, 0], [0, 0, 0, 0, 0, 135000]]\n"), "toml", &["'L4_L5'", "not positive definite"]),
        ("asymmetric", format!("{UNITS}[[level]]\nname = \"L4_L5\"\nform = \"coupled\"\nmatrix = [[68.8, 1, 0, 0, 0, 0], [0, 51, 0, 0, 0, 0], [0, 0, 51, 0, 0, 0], [0, 0, 0, 149000, 0, 0], [0, 0, 0, 0, 1890000, 0], [0, 0, 0, 0, 0, 135000]]\n"), "toml", &["'L4_L5'", "not symmetric"]),
        ("missing_units", format!("[[level]]\nname = \"L4_L5\"\n{lin}"), "toml", &["[units]", "missing"]),
        ("missing_one_unit", format!("[units]\nrotational = \"N*m/rad\"\ntranslational = \"N/m\"\nrot_damping = \"N*m*s/rad\"\n[[level]]\nname = \"L4_L5\"\n{lin}"), "toml", &["trans_damping"]),
        ("unknown_dof", format!("{UNITS}[[level]]\nname = \"L1_L2\"\nstiffness = {{ rq = 5.0 }}\n"), "toml", &["[[level]] #1 'L1_L2'", "unknown DoF 'rq'"]),
        ("softening", format!("{UNITS}[[level]]\nname = \"L1_L2\"\nform = \"nonlinear\"\n{lin}[[level.curve]]\ndof = \"rx\"\nkind = \"points\"\nx = [-0.1, 0.0, 0.1, 0.2]\ny = [-5.0, 0.0, 5.0, 4.0]\n"), "toml", &["'L1_L2'", "curve rx", "--allow-softening"]),
        ("duplicate", format!("{UNITS}[[level]]\nname = \"L5_S1\"\n{lin}[[level]]\nname = \"L5_S1\"\n{lin}"), "toml", &["[[level]] #2 'L5_S1'", "already set"]),
        ("csv_unknown_level", "level,rx [N*m/rad]\nL5_S1,60\nT13_L1,70\n".to_string(), "csv", &["line 3 'T13_L1'", "unknown level"]),
        ("csv_negative", "level,rx [N*m/rad],ry [N*m/rad],rz [N*m/rad],tx [N/m],ty [N/m],tz [N/m]\nL5_S1,60,1,1,1,1,1\nL4_L5,60,-1,1,1,1,1\n".to_string(), "csv", &["line 3 'L4_L5'", "stiffness ry must be positive"]),
        ("csv_missing_unit", "level,rx\nL5_S1,60\n".to_string(), "csv", &["column 2", "no unit"]),
        ("bad_expression", format!("{UNITS}[[level]]\nname = \"L5_S1\"\nform = \"expression\"\nexpressions = {{ rx = \"68.8*theta_q\", ry = \"1\", rz = \"1\", tx = \"1\", ty = \"1\", tz = \"1\" }}\n"), "toml", &["'L5_S1'", "theta_q"]),
    ];
    for (tag, table, ext, needles) in cases {
        let (out, o) = apply(spec, &table, dir.path(), tag, ext);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{label} {tag}: accepted");
        for n in needles {
            assert!(err.contains(n), "{label} {tag}: message lacks '{n}': {err}");
        }
        assert!(
            !out.exists(),
            "{label} {tag}: output written despite the error"
        );
    }
    // the softening curve is accepted when asked for
    let table = format!("{UNITS}[[level]]\nname = \"L1_L2\"\nform = \"nonlinear\"\n{lin}[[level.curve]]\ndof = \"rx\"\nkind = \"points\"\nx = [-0.1, 0.0, 0.1, 0.2]\ny = [-5.0, 0.0, 5.0, 4.0]\n");
    let t = dir.path().join("soft.toml");
    std::fs::write(&t, table).unwrap();
    let out = dir.path().join("soft.osim");
    let o = run(&[
        "stiffness",
        s(spec),
        "--table",
        s(&t),
        "--out",
        s(&out),
        "--allow-softening",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(out.exists());
}

#[test]
fn bad_tables_are_rejected_naming_the_row_and_nothing_is_written() {
    let Some(spec) = common::shared("diagnose-dev/dev-01/specimen.osim") else {
        return;
    };
    assert_bad_tables_rejected(&spec, "specimen");
}

#[test]
fn base_model_bad_tables_are_rejected_naming_the_row_and_nothing_is_written() {
    let base = common::repo_root().join("base_model/base.osim");
    assert_bad_tables_rejected(&base, "base_model");
}

#[test]
fn templates_apply_and_give_the_thesis_numbers() {
    let Some(chain) = common::shared("oracle/chain17.osim") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let t = common::repo_root().join("templates");
    // Table 4.3 (base x ratio): the chain's sacrum_L5 is L5_S1, L1_T12 is T12_L1
    let out = dir.path().join("t43.osim");
    let o = run(&[
        "stiffness",
        s(&chain),
        "--table",
        s(&t.join("stiffness-table4.3-ratios.toml")),
        "--out",
        s(&out),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let csv = list(&out, "csv");
    let row = |name: &str| -> Vec<f64> {
        let l = csv
            .lines()
            .find(|l| l.starts_with(&format!("{name},")))
            .unwrap();
        l.split(',').skip(1).map(|x| x.parse().unwrap()).collect()
    };
    for (name, want) in [
        ("sacrum_L5", [68.8, 183.4, 51.0]),
        ("L1_T12", [36.4, 136.8, 16.3]),
        ("L4_L3", [12.4, 291.1, 49.5]),
    ] {
        let v = row(name);
        for k in 0..3 {
            assert!((v[k] - want[k]).abs() < 1e-9, "{name}: {v:?}");
        }
        assert_eq!(v[3..6], [149000.0, 1890000.0, 135000.0]);
    }
    // levels above T12 keep Table 5.1 values
    assert_eq!(row("T5_T4")[..3], [68.8, 291.0, 51.0]);
    // Table 5.1 in TOML and CSV give the same model; forms example applies
    let a = dir.path().join("a.osim");
    let b = dir.path().join("b.osim");
    for (tpl, out) in [
        ("stiffness-table5.1-uniform.toml", &a),
        ("stiffness-table5.1-uniform.csv", &b),
    ] {
        let o = run(&[
            "stiffness",
            s(&chain),
            "--table",
            s(&t.join(tpl)),
            "--out",
            s(out),
        ]);
        assert!(
            o.status.success(),
            "{tpl}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
    }
    assert_eq!(std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
    let Some(spec) = common::shared("diagnose-dev/dev-01/specimen.osim") else {
        return;
    };
    let c = dir.path().join("c.osim");
    let o = run(&[
        "stiffness",
        s(&spec),
        "--table",
        s(&t.join("stiffness-forms-example.toml")),
        "--out",
        s(&c),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}
