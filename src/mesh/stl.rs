//! STL (stereolithography) reading and writing, ASCII and binary.
//!
//! STL stores a triangle soup; on read, corners with bit-identical
//! coordinates are welded into shared vertices (numbered in order of first
//! appearance), so the triangle list and every corner position are kept
//! exactly. Precision: binary STL is float32 (about 1e-7 relative, i.e.
//! ~1e-8 m on a vertebra), ASCII STL written by [`to_ascii`] uses the
//! shortest round-trip representation of each f64, so it is lossless.
//!
//! Detection: a file whose length is exactly `84 + 50 n` for the triangle
//! count `n` in its header is binary (even if its header starts with
//! `solid`); otherwise a file starting with `solid` is ASCII; anything else
//! is an error that says which of the two it failed to be.

use super::TriMesh;
use crate::error::{Error, Result};
use nalgebra::Point3;
use std::collections::BTreeMap;
use std::path::Path;

/// Read an STL file (ASCII or binary).
pub fn read(path: &Path) -> Result<TriMesh> {
    let bytes = super::read_file_bytes(path)?;
    read_bytes(&bytes, path)
}

/// Parse STL bytes; `name` is used in error messages.
pub fn read_bytes(bytes: &[u8], name: &Path) -> Result<TriMesh> {
    if bytes.len() >= 84 {
        let n = u32::from_le_bytes([bytes[80], bytes[81], bytes[82], bytes[83]]) as u64;
        let need = 84 + 50 * n;
        if need == bytes.len() as u64 {
            if n > super::MAX_MESH_TRIANGLES as u64 {
                return Err(super::too_many_triangles(name, n));
            }
            return read_binary(bytes, name);
        }
        if !starts_with_solid(bytes) {
            return Err(Error::parse(
                name,
                "header",
                format!(
                    "not ASCII STL (does not start with `solid`) and not binary STL: the header \
                     declares {n} triangles, which needs {need} bytes, but the file has {} bytes{}",
                    bytes.len(),
                    if (bytes.len() as u64) < need {
                        " (truncated?)"
                    } else {
                        ""
                    }
                ),
            ));
        }
    } else if !starts_with_solid(bytes) {
        return Err(Error::parse(
            name,
            "header",
            format!(
                "not an STL file: {} bytes is too short for binary STL (84-byte header) and it \
                 does not start with `solid`",
                bytes.len()
            ),
        ));
    }
    read_ascii(bytes, name)
}

fn starts_with_solid(bytes: &[u8]) -> bool {
    let start = bytes
        .iter()
        .position(|b| !b.is_ascii_whitespace())
        .unwrap_or(bytes.len());
    bytes[start..]
        .get(..5)
        .is_some_and(|s| s.eq_ignore_ascii_case(b"solid"))
}

/// Welds bit-identical corners into shared vertices.
struct Welder {
    index: BTreeMap<[u64; 3], u32>,
    vertices: Vec<Point3<f64>>,
    triangles: Vec<[u32; 3]>,
}

impl Welder {
    fn new() -> Self {
        Welder {
            index: BTreeMap::new(),
            vertices: Vec::new(),
            triangles: Vec::new(),
        }
    }
    fn vertex(&mut self, p: Point3<f64>) -> u32 {
        // -0.0 and 0.0 are the same point.
        let key = [p.x, p.y, p.z].map(|c| (c + 0.0).to_bits());
        let next = self.vertices.len() as u32;
        let k = *self.index.entry(key).or_insert(next);
        if k == next {
            self.vertices.push(p);
        }
        k
    }
    fn triangle(&mut self, c: [Point3<f64>; 3]) {
        let t = c.map(|p| self.vertex(p));
        self.triangles.push(t);
    }
    fn finish(self) -> TriMesh {
        TriMesh {
            vertices: self.vertices,
            triangles: self.triangles,
        }
    }
}

fn read_binary(bytes: &[u8], name: &Path) -> Result<TriMesh> {
    let mut w = Welder::new();
    for (k, rec) in bytes[84..].chunks_exact(50).enumerate() {
        let f = |o: usize| f32::from_le_bytes([rec[o], rec[o + 1], rec[o + 2], rec[o + 3]]) as f64;
        let mut c = [Point3::origin(); 3];
        for (j, p) in c.iter_mut().enumerate() {
            let o = 12 + 12 * j;
            *p = Point3::new(f(o), f(o + 4), f(o + 8));
            if !p.coords.iter().all(|x| x.is_finite()) {
                return Err(Error::parse(
                    name,
                    format!("triangle {k}"),
                    format!("corner {j} has a non-finite coordinate {p:?}"),
                ));
            }
        }
        w.triangle(c);
    }
    Ok(w.finish())
}

fn read_ascii(bytes: &[u8], name: &Path) -> Result<TriMesh> {
    let text = std::str::from_utf8(bytes).map_err(|e| {
        let line = super::line_of(bytes, e.valid_up_to());
        Error::parse(
            name,
            format!("line {line}"),
            "ASCII STL contains bytes that are not UTF-8 text",
        )
    })?;
    let mut w = Welder::new();
    let mut corners: Vec<Point3<f64>> = Vec::with_capacity(3);
    let mut in_facet = false;
    let mut facet_line = 0;
    let mut seen_solid = false;
    for (i, line) in text.lines().enumerate() {
        let ln = i + 1;
        let loc = || format!("line {ln}");
        let mut tok = line.split_whitespace();
        let Some(key) = tok.next() else { continue };
        match key.to_ascii_lowercase().as_str() {
            "solid" => seen_solid = true,
            "endsolid" => {}
            "facet" => {
                if in_facet {
                    return Err(Error::parse(
                        name,
                        loc(),
                        format!("`facet` inside the facet opened on line {facet_line}"),
                    ));
                }
                in_facet = true;
                facet_line = ln;
                corners.clear();
            }
            "outer" | "endloop" => {
                if !in_facet {
                    return Err(Error::parse(
                        name,
                        loc(),
                        format!("`{key}` outside a facet"),
                    ));
                }
            }
            "vertex" => {
                if !in_facet {
                    return Err(Error::parse(name, loc(), "`vertex` outside a facet"));
                }
                let mut xyz = [0.0; 3];
                for (k, c) in xyz.iter_mut().enumerate() {
                    let t = tok.next().ok_or_else(|| {
                        Error::parse(name, loc(), "`vertex` needs three coordinates")
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
                if corners.len() == 3 {
                    return Err(Error::parse(
                        name,
                        loc(),
                        "more than three vertices in one facet (only triangles are valid STL)",
                    ));
                }
                corners.push(Point3::from(xyz));
            }
            "endfacet" => {
                if !in_facet {
                    return Err(Error::parse(name, loc(), "`endfacet` without `facet`"));
                }
                let c: [Point3<f64>; 3] = corners.as_slice().try_into().map_err(|_| {
                    Error::parse(
                        name,
                        format!("line {facet_line}"),
                        format!("facet has {} vertices, expected 3", corners.len()),
                    )
                })?;
                w.triangle(c);
                in_facet = false;
            }
            other => {
                return Err(Error::parse(
                    name,
                    loc(),
                    format!("unexpected `{other}` in ASCII STL"),
                ))
            }
        }
    }
    if !seen_solid {
        return Err(Error::parse(
            name,
            "line 1",
            "ASCII STL must start with `solid`",
        ));
    }
    if in_facet {
        return Err(Error::parse(
            name,
            format!("line {facet_line}"),
            "facet is not closed by `endfacet` (truncated file?)",
        ));
    }
    let mesh = w.finish();
    if mesh.triangles.is_empty() {
        return Err(Error::parse(
            name,
            "end of file",
            "ASCII STL has no facets (empty mesh)",
        ));
    }
    Ok(mesh)
}

/// ASCII STL with shortest round-trip coordinates (lossless for f64).
/// `solid_name` is written after `solid`/`endsolid` (spaces replaced by `_`).
pub fn to_ascii(mesh: &TriMesh, solid_name: &str) -> String {
    use crate::util::fmt_f64;
    let name: String = solid_name
        .chars()
        .map(|c| if c.is_whitespace() { '_' } else { c })
        .collect();
    let mut s = format!("solid {name}\n");
    for (i, c) in mesh.triangle_corners().enumerate() {
        let n = mesh.triangle_normal(i);
        s.push_str(&format!(
            "facet normal {} {} {}\n  outer loop\n",
            fmt_f64(n.x),
            fmt_f64(n.y),
            fmt_f64(n.z)
        ));
        for p in c {
            s.push_str(&format!(
                "    vertex {} {} {}\n",
                fmt_f64(p.x),
                fmt_f64(p.y),
                fmt_f64(p.z)
            ));
        }
        s.push_str("  endloop\nendfacet\n");
    }
    s.push_str(&format!("endsolid {name}\n"));
    s
}

/// Binary STL bytes (float32: coordinates are rounded to single precision).
/// Fails if the mesh has more than `u32::MAX` triangles.
pub fn to_binary(mesh: &TriMesh) -> Result<Vec<u8>> {
    let n = u32::try_from(mesh.triangles.len()).map_err(|_| {
        Error::invalid(
            "binary STL",
            "more than 4294967295 triangles cannot be stored",
        )
    })?;
    let mut out = Vec::with_capacity(84 + 50 * mesh.triangles.len());
    let mut header = [b' '; 80];
    let tag = b"binary STL written by osim-spine (metres)";
    header[..tag.len()].copy_from_slice(tag);
    out.extend_from_slice(&header);
    out.extend_from_slice(&n.to_le_bytes());
    for (i, c) in mesh.triangle_corners().enumerate() {
        let nrm = mesh.triangle_normal(i);
        for x in nrm.iter().chain(c.iter().flat_map(|p| p.coords.iter())) {
            out.extend_from_slice(&(*x as f32).to_le_bytes());
        }
        out.extend_from_slice(&0u16.to_le_bytes());
    }
    Ok(out)
}

/// Write binary STL (float32) atomically.
pub fn write_binary(path: &Path, mesh: &TriMesh) -> Result<()> {
    crate::util::write_atomic(path, &to_binary(mesh)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tet() -> TriMesh {
        TriMesh::new(
            vec![
                Point3::new(0.0, 0.0, 0.0),
                Point3::new(0.1, 0.0, 0.0),
                Point3::new(0.0, 0.1, 0.0),
                Point3::new(0.0, 0.0, 0.1 / 3.0),
            ],
            vec![[0, 2, 1], [0, 1, 3], [1, 2, 3], [2, 0, 3]],
        )
        .unwrap()
    }

    #[test]
    fn ascii_round_trip_is_exact() {
        let m = tet();
        let s = to_ascii(&m, "tet");
        let r = read_bytes(s.as_bytes(), Path::new("t.stl")).unwrap();
        // Vertices are renumbered by first appearance; corners are exact.
        assert_eq!(r.max_corner_distance(&m), Some(0.0));
        assert_eq!(r.vertices.len(), 4);
    }

    #[test]
    fn binary_round_trip_is_float32() {
        let m = tet();
        let b = to_binary(&m).unwrap();
        assert_eq!(b.len(), 84 + 50 * 4);
        let r = read_bytes(&b, Path::new("t.stl")).unwrap();
        for (a, b) in r.triangle_corners().zip(m.triangle_corners()) {
            for j in 0..3 {
                for k in 0..3 {
                    assert_eq!(a[j][k], b[j][k] as f32 as f64);
                }
            }
        }
    }

    #[test]
    fn binary_with_solid_header_is_binary() {
        let mut b = to_binary(&tet()).unwrap();
        b[..5].copy_from_slice(b"solid");
        assert_eq!(
            read_bytes(&b, Path::new("t.stl")).unwrap().triangles.len(),
            4
        );
    }

    #[test]
    fn truncated_binary_is_an_error() {
        let b = to_binary(&tet()).unwrap();
        let e = read_bytes(&b[..150], Path::new("t.stl"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("t.stl") && e.contains("truncated"), "{e}");
    }

    #[test]
    fn ascii_errors_name_the_line() {
        let s = "solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 nan 0\n";
        let e = read_bytes(s.as_bytes(), Path::new("a.stl"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("a.stl: line 5"), "{e}");
        let s = "solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nendloop\nendfacet\n";
        let e = read_bytes(s.as_bytes(), Path::new("a.stl"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 2") && e.contains("1 vertices"), "{e}");
    }
}
