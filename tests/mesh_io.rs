//! Mesh file formats on the real meshes in `../shared/data/`: every file
//! reads and agrees with an independent reader, and format chains keep the
//! geometry to the precision each format stores.

mod common;

use osim_spine::mesh::{self, Format, TriMesh};
use std::path::{Path, PathBuf};

fn shared_meshes() -> Option<Vec<PathBuf>> {
    let mut out = Vec::new();
    for dir in [
        "data/geometry",
        "data/geometry-bodyframe",
        "data/vertebra-meshes",
    ] {
        let d = common::shared(dir)?;
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if Format::from_path(&p).is_ok() {
                out.push(p);
            }
        }
    }
    out.sort();
    Some(out)
}

/// Independent reading of an ASCII VTP: plain string slicing of the three
/// arrays (no XML parser), polygons fanned.
fn naive_vtp(path: &Path) -> TriMesh {
    let s = std::fs::read_to_string(path).unwrap();
    let array = |key: &str| -> Vec<&str> {
        let start = s.find(key).unwrap();
        // From the key to the end of its DataArray start tag.
        let tag = if key.starts_with('<') {
            start + s[start..].find("<DataArray").unwrap()
        } else {
            start
        };
        let body = &s[tag..];
        let open = body.find('>').unwrap() + 1;
        let close = body.find("</DataArray>").unwrap();
        body[open..close].split_whitespace().collect()
    };
    let pts: Vec<f64> = array("<Points>")
        .iter()
        .map(|t| t.parse().unwrap())
        .collect();
    let conn: Vec<u32> = array("Name=\"connectivity\"")
        .iter()
        .map(|t| t.parse().unwrap())
        .collect();
    let offs: Vec<usize> = array("Name=\"offsets\"")
        .iter()
        .map(|t| t.parse().unwrap())
        .collect();
    let mut tris = Vec::new();
    let mut start = 0;
    for o in offs {
        let c = &conn[start..o];
        for j in 1..c.len() - 1 {
            tris.push([c[0], c[j], c[j + 1]]);
        }
        start = o;
    }
    TriMesh {
        vertices: pts.chunks(3).map(|c| [c[0], c[1], c[2]].into()).collect(),
        triangles: tris,
    }
}

/// Independent reading of an OBJ with `tobj` (float32 positions).
fn tobj_obj(path: &Path) -> TriMesh {
    let opts = tobj::LoadOptions {
        triangulate: true,
        single_index: true,
        ..Default::default()
    };
    let (models, _materials) = tobj::load_obj(path, &opts).unwrap();
    let mut out = TriMesh::default();
    for m in models {
        let base = out.vertices.len() as u32;
        out.vertices.extend(
            m.mesh
                .positions
                .chunks(3)
                .map(|c| nalgebra::Point3::new(c[0] as f64, c[1] as f64, c[2] as f64)),
        );
        out.triangles.extend(
            m.mesh
                .indices
                .chunks(3)
                .map(|c| [c[0] + base, c[1] + base, c[2] + base]),
        );
    }
    out
}

#[test]
fn every_shared_mesh_reads_and_matches_an_independent_reader() {
    let Some(files) = shared_meshes() else { return };
    assert!(files.len() >= 50, "only {} meshes found", files.len());
    for f in &files {
        let m = mesh::read(f).unwrap_or_else(|e| panic!("{e}"));
        assert!(!m.triangles.is_empty(), "{}", f.display());
        let (lo, hi) = m.bounds().unwrap();
        let size = (hi - lo).norm();
        // Metres: a vertebra or a pelvis half is centimetres to decimetres.
        assert!(size > 0.02 && size < 0.5, "{}: size {size} m", f.display());
        let other = if f.extension().unwrap() == "vtp" {
            naive_vtp(f)
        } else {
            tobj_obj(f)
        };
        let d = m.max_corner_distance(&other).unwrap_or_else(|| {
            panic!(
                "{}: {} triangles vs {} from the independent reader",
                f.display(),
                m.triangles.len(),
                other.triangles.len()
            )
        });
        // VTP: same decimal text parsed -> identical; OBJ: tobj is float32.
        let tol = if f.extension().unwrap() == "vtp" {
            0.0
        } else {
            1e-7 * size
        };
        assert!(d <= tol, "{}: corners differ by {d} m", f.display());
    }
}

#[test]
fn vtp_stl_obj_vtp_chain_is_lossless() {
    let Some(files) = shared_meshes() else { return };
    let dir = tempfile::tempdir().unwrap();
    let mut n = 0;
    for f in files.iter().filter(|f| f.extension().unwrap() == "vtp") {
        let m0 = mesh::read(f).unwrap();
        let stem = f.file_stem().unwrap().to_str().unwrap();
        let mut m = m0.clone();
        for ext in ["stl", "obj", "ply", "vtp"] {
            let p = dir.path().join(format!("{stem}.{ext}"));
            mesh::write(&p, &m).unwrap();
            m = mesh::read(&p).unwrap();
            let d = m.max_corner_distance(&m0).expect("triangle count changed");
            assert!(d <= 1e-9, "{stem} after .{ext}: {d} m");
            // Exactly, in fact: every writer prints round-trip numbers.
            assert_eq!(d, 0.0, "{stem} after .{ext}");
        }
        n += 1;
    }
    assert!(n >= 40);
}

#[test]
fn binary_stl_keeps_float32_precision() {
    let Some(files) = shared_meshes() else { return };
    for f in &files {
        let m0 = mesh::read(f).unwrap();
        let b = mesh::stl::to_binary(&m0).unwrap();
        let m = mesh::read_bytes(Format::Stl, &b, f).unwrap();
        let (lo, hi) = m0.bounds().unwrap();
        let scale = lo.coords.abs().max().max(hi.coords.abs().max());
        let d = m.max_corner_distance(&m0).unwrap();
        // Float32 rounding: half an ulp, 2^-24 relative.
        assert!(
            d <= scale * 2f64.powi(-24) * 3f64.sqrt(),
            "{}: {d}",
            f.display()
        );
    }
}

#[test]
fn binary_and_compressed_vtp_read_back_bit_exact() {
    let Some(files) = shared_meshes() else { return };
    let dir = tempfile::tempdir().unwrap();
    for f in &files {
        let m0 = mesh::read(f).unwrap();
        for compress in [false, true] {
            let p = dir.path().join("b.vtp");
            mesh::vtp::write_binary(&p, &m0, compress).unwrap();
            let m = mesh::read(&p).unwrap();
            assert_eq!(m, m0, "{} (compress {compress})", f.display());
        }
    }
}
