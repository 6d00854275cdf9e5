//! Wavefront OBJ reading and writing (geometry only).
//!
//! The reader keeps the vertex list in file order (so meshes exported from
//! one template stay in vertex correspondence), parses coordinates as f64,
//! triangulates polygons as fans, resolves negative (relative) indices, and
//! ignores texture coordinates, normals, groups and materials (a missing
//! `.mtl` file is therefore fine). Errors name the line.
//!
//! It is a small hand-written parser rather than `tobj` because `tobj`
//! (without its `use_f64` feature) reads positions as f32, renumbers vertices
//! per object and reports errors without a line; the tests cross-check this
//! reader against `tobj` on the real meshes.

use super::TriMesh;
use crate::error::{Error, Result};
use nalgebra::Point3;
use std::path::Path;

/// OBJ statements that carry no triangle geometry and are skipped.
const IGNORED: &[&str] = &[
    "vt",
    "vn",
    "vp",
    "l",
    "p",
    "o",
    "g",
    "s",
    "usemtl",
    "mtllib",
    "cstype",
    "deg",
    "bmat",
    "step",
    "curv",
    "curv2",
    "surf",
    "parm",
    "trim",
    "hole",
    "scrv",
    "sp",
    "end",
    "con",
    "mg",
    "lod",
    "bevel",
    "c_interp",
    "d_interp",
    "usemap",
    "maplib",
    "shadow_obj",
    "trace_obj",
    "ctech",
    "stech",
];

/// Read an OBJ file.
pub fn read(path: &Path) -> Result<TriMesh> {
    let bytes = super::read_file_bytes(path)?;
    read_bytes(&bytes, path)
}

/// Parse OBJ bytes; `name` is used in error messages.
pub fn read_bytes(bytes: &[u8], name: &Path) -> Result<TriMesh> {
    let text = std::str::from_utf8(bytes).map_err(|e| {
        let line = super::line_of(bytes, e.valid_up_to());
        Error::parse(
            name,
            format!("line {line}"),
            "OBJ contains bytes that are not UTF-8 text",
        )
    })?;
    let mut vertices: Vec<Point3<f64>> = Vec::new();
    // Triangles with the line they came from (bounds are checked at the end
    // because positive indices may in principle refer to later vertices).
    let mut triangles: Vec<([u32; 3], usize)> = Vec::new();
    let mut face: Vec<u32> = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let ln = i + 1;
        let loc = || format!("line {ln}");
        let line = raw.split('#').next().unwrap_or("");
        let mut tok = line.split_whitespace();
        let Some(key) = tok.next() else { continue };
        match key {
            "v" => {
                let mut xyz = [0.0; 3];
                for (k, c) in xyz.iter_mut().enumerate() {
                    let t = tok.next().ok_or_else(|| {
                        Error::parse(name, loc(), "vertex `v` needs three coordinates")
                    })?;
                    *c = t.parse::<f64>().map_err(|_| {
                        Error::parse(name, loc(), format!("coordinate {k} `{t}` is not a number"))
                    })?;
                    if !c.is_finite() {
                        return Err(Error::parse(
                            name,
                            loc(),
                            format!("coordinate {k} `{t}` is not finite"),
                        ));
                    }
                }
                if vertices.len() >= u32::MAX as usize {
                    return Err(Error::parse(name, loc(), "too many vertices"));
                }
                vertices.push(Point3::from(xyz));
            }
            "f" => {
                face.clear();
                for t in tok {
                    let first = t.split('/').next().unwrap_or("");
                    let k: i64 = first.parse().map_err(|_| {
                        Error::parse(
                            name,
                            loc(),
                            format!("face vertex `{t}` does not start with an integer index"),
                        )
                    })?;
                    let n = vertices.len() as i64;
                    let idx = if k > 0 {
                        k - 1
                    } else if k < 0 {
                        n + k
                    } else {
                        -1
                    };
                    if idx < 0 || idx >= u32::MAX as i64 {
                        return Err(Error::parse(
                            name,
                            loc(),
                            format!(
                                "face index {k} is invalid ({n} vertices defined so far; OBJ \
                                 indices start at 1, negative ones count back from the last)"
                            ),
                        ));
                    }
                    face.push(idx as u32);
                }
                if face.len() < 3 {
                    return Err(Error::parse(
                        name,
                        loc(),
                        format!("face has {} vertices, at least 3 expected", face.len()),
                    ));
                }
                for j in 1..face.len() - 1 {
                    triangles.push(([face[0], face[j], face[j + 1]], ln));
                }
            }
            k if IGNORED.contains(&k) => {}
            other => {
                let shown: String = other.chars().take(20).collect();
                return Err(Error::parse(
                    name,
                    loc(),
                    format!("unknown OBJ statement `{shown}`"),
                ));
            }
        }
    }
    let n = vertices.len();
    let mut tris = Vec::with_capacity(triangles.len());
    for (t, ln) in triangles {
        if let Some(&k) = t.iter().find(|&&k| k as usize >= n) {
            return Err(Error::parse(
                name,
                format!("line {ln}"),
                format!(
                    "face refers to vertex {} but the file defines only {n} vertices",
                    k as u64 + 1
                ),
            ));
        }
        tris.push(t);
    }
    if tris.is_empty() {
        return Err(Error::parse(
            name,
            "end of file",
            "no faces (`f` lines) found: not a triangle-mesh OBJ",
        ));
    }
    Ok(TriMesh {
        vertices,
        triangles: tris,
    })
}

/// OBJ text with shortest round-trip coordinates (lossless for f64).
pub fn to_string(mesh: &TriMesh) -> String {
    use crate::util::fmt_f64;
    let mut s = String::from("# written by osim-spine; units: metres\n");
    for p in &mesh.vertices {
        s.push_str(&format!(
            "v {} {} {}\n",
            fmt_f64(p.x),
            fmt_f64(p.y),
            fmt_f64(p.z)
        ));
    }
    for t in &mesh.triangles {
        s.push_str(&format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1));
    }
    s
}

/// Write an OBJ file atomically.
pub fn write(path: &Path, mesh: &TriMesh) -> Result<()> {
    crate::util::write_atomic(path, to_string(mesh).as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quads_fan_and_negative_indices() {
        let s = "mtllib missing.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvn 0 0 1\n\
                 f 1//1 2//1 3//1 4//1\nf -4 -2 -1\n";
        let m = read_bytes(s.as_bytes(), Path::new("q.obj")).unwrap();
        assert_eq!(m.triangles, vec![[0, 1, 2], [0, 2, 3], [0, 2, 3]]);
    }

    #[test]
    fn round_trip_is_exact() {
        let m = TriMesh::new(
            vec![
                Point3::new(0.1, -2e-7, 1.0 / 3.0),
                Point3::new(1.0, 0.0, 0.0),
                Point3::new(0.0, 1.0, 0.0),
            ],
            vec![[0, 1, 2]],
        )
        .unwrap();
        let r = read_bytes(to_string(&m).as_bytes(), Path::new("r.obj")).unwrap();
        assert_eq!(r, m);
    }

    #[test]
    fn errors_name_the_line() {
        let e = read_bytes(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n", Path::new("b.obj"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("b.obj: line 4") && e.contains("only 3 vertices"),
            "{e}"
        );
        let e = read_bytes(b"v 0 0 0\nv 1 inf 0\n", Path::new("b.obj"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 2"), "{e}");
        let e = read_bytes(b"v 0 0 0\nf 0 1 1\n", Path::new("b.obj"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 2") && e.contains("index 0"), "{e}");
    }
}
