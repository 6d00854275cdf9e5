//! `base --palpation FILE` and `--centres FILE`: a
//! modeller's own palpation of the generic model replaces exactly the
//! markers (and sphere centres) it names; everything else stays the
//! engine's. Files that do not say their units or frame are refused.

mod common;

use nalgebra::{Point3, Vector3};
use osim_spine::base::kin::Kinematics;
use osim_spine::generate::base_markers;
use osim_spine::landmarks::{Code, Level};
use osim_spine::osim::Document;
use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;

/// `base --procedural` into `out` with extra arguments; panics on failure.
fn base(out: &Path, extra: &[&str]) -> std::process::Output {
    Command::new(common::bin())
        .args(["base", "--procedural", "--out"])
        .arg(out)
        .args(extra)
        .output()
        .unwrap()
}

/// Every marker of a base (body frame, m) by name.
fn markers(dir: &Path) -> BTreeMap<String, Point3<f64>> {
    let doc = Document::read(dir.join("base.osim")).unwrap();
    let model = doc.model().unwrap();
    let mut out = BTreeMap::new();
    for (l, (_, pts)) in base_markers(&model).unwrap() {
        for (c, p) in pts {
            out.insert(format!("{l}_{c}"), p);
        }
    }
    out
}

/// The vertebral-body sphere centres of a base (body frame) by level.
fn sphere_centres(dir: &Path) -> BTreeMap<String, Point3<f64>> {
    let doc = Document::read(dir.join("base.osim")).unwrap();
    let model = doc.model().unwrap();
    let mut out = BTreeMap::new();
    for b in &model.bodies {
        for w in &b.wrap_objects {
            if let Some(l) = w.name.strip_suffix("_body_sphere") {
                out.insert(l.to_string(), Point3::from(w.translation));
            }
        }
    }
    out
}

#[test]
fn palpation_file_moves_exactly_the_codes_it_names() {
    let tmp = tempfile::tempdir().unwrap();
    let a = tmp.path().join("a");
    assert!(base(&a, &[]).status.success());
    let before = markers(&a);
    // Every SP 5 mm posterior, in each vertebra's body frame (mm).
    let mut csv = String::from("# units: mm\nname,body,x,y,z\n");
    for l in &Level::ALL[..17] {
        let p = before[&format!("{l}_SP")] * 1e3;
        csv.push_str(&format!(
            "{l}_SP,{},{},{},{}\n",
            l.body_name(),
            p.x - 5.0,
            p.y,
            p.z
        ));
    }
    let file = tmp.path().join("sp_posterior.csv");
    std::fs::write(&file, csv).unwrap();
    let b = tmp.path().join("b");
    let o = base(&b, &["--palpation", file.to_str().unwrap()]);
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(
        out.contains("17 landmark(s)/centre(s) from your files"),
        "{out}"
    );
    let after = markers(&b);
    assert_eq!(before.len(), after.len());
    for (name, p) in &before {
        let d = after[name] - p;
        if name.ends_with("_SP") && !name.starts_with("S1") {
            assert!(
                (d - Vector3::new(-0.005, 0.0, 0.0)).norm() < 1e-9,
                "{name}: {d:?}"
            );
        } else {
            assert!(d.norm() == 0.0, "{name} moved by {:?}", d);
        }
    }
}

#[test]
fn ground_coordinates_and_centres_are_read_in_the_generic_models_frames() {
    let tmp = tempfile::tempdir().unwrap();
    let a = tmp.path().join("a");
    assert!(base(&a, &[]).status.success());
    let before = markers(&a);
    let centres = sphere_centres(&a);
    // L3_SA 2 mm cranial, given in the model's ground at its default pose
    // (opensim frame, m), and the L3 centre 1 mm anterior in LPS mm.
    let doc = Document::read(a.join("base.osim")).unwrap();
    let model = doc.model().unwrap();
    let kin = Kinematics::new(&model).unwrap();
    let poses = kin.body_poses(&kin.default_values()).unwrap();
    let x = poses[&Level::L3.body_name()];
    let sa = x * before["L3_SA"] + x.rotation * Vector3::new(0.0, 0.002, 0.0);
    let pal = tmp.path().join("pal.csv");
    std::fs::write(
        &pal,
        format!(
            "# units: m\n# frame: opensim\nname,x,y,z\nL3_SA,{},{},{}\n",
            sa.x, sa.y, sa.z
        ),
    )
    .unwrap();
    // Ground, opensim -> LPS (mm): lps = (-z, -x, y) x 1000.
    let c = x * (centres["L3"] + Vector3::new(0.001, 0.0, 0.0));
    let cen = tmp.path().join("centres.csv");
    std::fs::write(
        &cen,
        format!(
            "# units: mm\n# frame: LPS\nname,x,y,z\nL3_centre,{},{},{}\n",
            -c.z * 1e3,
            -c.x * 1e3,
            c.y * 1e3
        ),
    )
    .unwrap();
    let b = tmp.path().join("b");
    let o = base(
        &b,
        &[
            "--palpation",
            pal.to_str().unwrap(),
            "--centres",
            cen.to_str().unwrap(),
        ],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let after = markers(&b);
    let d = after["L3_SA"] - before["L3_SA"];
    assert!(
        (d - Vector3::new(0.0, 0.002, 0.0)).norm() < 1e-9,
        "L3_SA moved by {d:?}"
    );
    let dc = sphere_centres(&b)["L3"] - centres["L3"];
    assert!(
        (dc - Vector3::new(0.001, 0.0, 0.0)).norm() < 1e-9,
        "L3 centre moved by {dc:?}"
    );
    assert_eq!(after["L4_SA"], before["L4_SA"]);
    let rep: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(b.join("base_report.json")).unwrap())
            .unwrap();
    assert_eq!(
        rep["palpation_given"],
        serde_json::json!(["L3_SA", "L3_centre"])
    );
    let _ = Code::SA;
}

#[test]
fn palpation_files_that_do_not_say_units_or_frame_are_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let cases = [
        (
            "no_units.csv",
            "# frame: opensim\nname,x,y,z\nL3_SA,0.1,0.2,0.3\n",
            "units",
        ),
        (
            "no_frame.csv",
            "# units: mm\nname,x,y,z\nL3_SA,1,2,3\n",
            "frame",
        ),
        (
            "lps_body.csv",
            "# units: mm\n# frame: LPS\nname,body,x,y,z\nL3_SA,lumbar3,1,2,3\n",
            "body",
        ),
        (
            "bad_name.csv",
            "# units: mm\n# frame: opensim\nname,x,y,z\nL3_XX,1,2,3\n",
            "L3_XX",
        ),
        (
            "bad_body.csv",
            "# units: mm\nname,body,x,y,z\nL3_SA,femur_r,1,2,3\n",
            "femur_r",
        ),
    ];
    for (name, text, needle) in cases {
        let f = tmp.path().join(name);
        std::fs::write(&f, text).unwrap();
        let out = tmp.path().join(format!("out_{name}"));
        let o = base(&out, &["--palpation", f.to_str().unwrap()]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{name}: {err}");
        assert!(err.contains(name) || err.contains(needle), "{name}: {err}");
        assert!(err.contains(needle), "{name}: {err}");
        assert!(!out.exists(), "{name}: output written");
    }
}
