//! Acceptance: the cyclist model round-trips through `osim-spine convert`
//! losslessly (but for OpenSim's own 4.0 -> 4.6 upgrade), loads in OpenSim 4.6, and gives the same body transforms,
//! marker positions and muscle path lengths as OpenSim's reading of the
//! original in 100 random admissible states (seeded), within 1e-9.

mod common;

use osim_spine::osim::xml;
use osim_spine::osim::Document;
use std::process::Command;

const TOL: f64 = 1e-9;

#[test]
fn cyclist_round_trip_matches_opensim() {
    let Some(src) = common::shared("data/models/cyclistFullBodyMuscle.osim") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("cyclist_rt.osim");
    let st = Command::new(common::bin())
        .args(["convert", src.to_str().unwrap(), out.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(
        st.status.success(),
        "{}",
        String::from_utf8_lossy(&st.stderr)
    );

    // Lossless: the written tree has every element, attribute, text and
    // comment of the original, with the one documented 4.0 -> 4.6 upgrade
    // (Version, path actuators' `geometrypath` -> `path`) applied.
    let mut a = xml::parse(&std::fs::read_to_string(&src).unwrap(), &src).unwrap();
    osim_spine::osim::legacy::upgrade_4x(&mut a);
    let b = xml::parse(&std::fs::read_to_string(&out).unwrap(), &out).unwrap();
    assert!(
        xml::same_content(&a.root, &b.root),
        "written tree differs from the original"
    );
    let count = |t: &xml::XmlTree| {
        let mut n = 0;
        t.root.walk(&mut |_| n += 1);
        n
    };
    assert_eq!(count(&a), count(&b));

    let Some(py) = common::opensim_python() else {
        return;
    };
    let r = common::run_py(
        &py,
        "compare_models.py",
        &[
            src.to_str().unwrap(),
            out.to_str().unwrap(),
            "100",
            "20240601",
        ],
    );
    eprintln!("cyclist round trip: {r}");
    assert_eq!(r["states"], 101);
    assert_eq!(r["bodies"], 80);
    assert_eq!(r["markers"], 57);
    assert_eq!(r["muscles"], 520);
    assert_eq!(r["name_mismatch"].as_array().unwrap().len(), 0);
    for k in ["max_body", "max_marker", "max_length"] {
        let v = r[k].as_f64().unwrap();
        assert!(v <= TOL, "{k} = {v}");
    }

    // Control: the comparison does see a 1 micrometre change of one marker
    // and of one joint frame (so the zero differences above mean something).
    let mut doc = Document::read(&out).unwrap();
    let mk = doc.component_mut("MarkerSet", "racr").unwrap();
    let loc =
        osim_spine::osim::props::vec3_prop(mk, "location", std::path::Path::new("x")).unwrap();
    osim_spine::osim::props::set_vec3(
        mk,
        "location",
        &(loc + nalgebra::Vector3::new(1e-6, 0.0, 0.0)),
    );
    let j = doc.component_mut("JointSet", "L5_S1_IVDjnt").unwrap();
    let frame = j
        .child_mut("frames")
        .unwrap()
        .elements_mut()
        .next()
        .unwrap();
    let t = osim_spine::osim::props::vec3_prop(frame, "translation", std::path::Path::new("x"))
        .unwrap();
    osim_spine::osim::props::set_vec3(
        frame,
        "translation",
        &(t + nalgebra::Vector3::new(0.0, 1e-6, 0.0)),
    );
    let bad = dir.path().join("perturbed.osim");
    doc.write(&bad).unwrap();
    let r = common::run_py(
        &py,
        "compare_models.py",
        &[src.to_str().unwrap(), bad.to_str().unwrap(), "3", "1"],
    );
    assert!(
        r["max_marker"].as_f64().unwrap() > 5e-7,
        "marker change not seen: {r}"
    );
    assert!(
        r["max_body"].as_f64().unwrap() > 5e-7,
        "frame change not seen: {r}"
    );
    assert!(
        r["max_length"].as_f64().unwrap() > 1e-9,
        "path change not seen: {r}"
    );
}
