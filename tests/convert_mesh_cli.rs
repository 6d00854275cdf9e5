//! `osim-spine convert` on meshes: VTP -> STL -> OBJ -> VTP through the CLI keeps
//! every triangle corner, and a mesh cannot be "converted" into a model.
mod common;

use std::process::Command;

#[test]
fn convert_mesh_chain_keeps_vertices_and_triangles() {
    let Some(src) = common::shared("data/geometry-bodyframe/lumbar3.vtp") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let chain = ["a.stl", "b.obj", "c.vtp"];
    let mut prev = src.clone();
    for name in chain {
        let out = dir.path().join(name);
        let st = Command::new(common::bin())
            .args(["convert"])
            .arg(&prev)
            .arg(&out)
            .status()
            .unwrap();
        assert!(st.success(), "convert {} -> {name} failed", prev.display());
        prev = out;
    }
    let a = osim_spine::mesh::read(&src).unwrap();
    let b = osim_spine::mesh::read(&prev).unwrap();
    assert_eq!(a.triangles.len(), b.triangles.len());
    let d = a.max_corner_distance(&b).unwrap();
    assert!(d <= 1e-9, "corners moved by {d} m");
}

#[test]
fn convert_refuses_mesh_to_model() {
    let Some(src) = common::shared("data/geometry-bodyframe/lumbar3.vtp") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("x.osim");
    let o = Command::new(common::bin())
        .args(["convert"])
        .arg(&src)
        .arg(&out)
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("mesh converts only to a mesh"));
    assert!(!out.exists());
}
