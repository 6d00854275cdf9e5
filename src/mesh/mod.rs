//! Triangle meshes and their file formats.
//!
//! [`TriMesh`] is the one in-memory mesh type shared by all geometry work
//! (registration, sphere fitting, palpation, collision checks). Coordinates
//! are in metres once read; readers for files in other units say so.

use nalgebra::{Point3, Vector3};

/// An indexed triangle mesh: vertices in metres and counter-clockwise
/// triangles (outward normals where the source file is consistent).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TriMesh {
    /// Vertex positions (m).
    pub vertices: Vec<Point3<f64>>,
    /// Triangles as indices into `vertices`.
    pub triangles: Vec<[u32; 3]>,
}

impl TriMesh {
    /// A mesh from vertices and triangles; indices are checked.
    pub fn new(vertices: Vec<Point3<f64>>, triangles: Vec<[u32; 3]>) -> crate::Result<Self> {
        let n = vertices.len();
        if let Some((i, t)) = triangles
            .iter()
            .enumerate()
            .find(|(_, t)| t.iter().any(|&k| k as usize >= n))
        {
            return Err(crate::Error::invalid(
                "mesh",
                format!("triangle {i} {t:?} indexes past the {n} vertices"),
            ));
        }
        if let Some(i) = vertices
            .iter()
            .position(|v| !v.coords.iter().all(|c| c.is_finite()))
        {
            return Err(crate::Error::invalid(
                "mesh",
                format!("vertex {i} has a non-finite coordinate"),
            ));
        }
        Ok(TriMesh {
            vertices,
            triangles,
        })
    }

    /// Axis-aligned bounding box (min, max); `None` for an empty mesh.
    pub fn bounds(&self) -> Option<(Point3<f64>, Point3<f64>)> {
        let first = self.vertices.first()?;
        let (mut lo, mut hi) = (*first, *first);
        for v in &self.vertices {
            for k in 0..3 {
                lo[k] = lo[k].min(v[k]);
                hi[k] = hi[k].max(v[k]);
            }
        }
        Some((lo, hi))
    }

    /// Area-weighted unit normal of triangle `i` (zero for a degenerate one).
    pub fn triangle_normal(&self, i: usize) -> Vector3<f64> {
        let [a, b, c] = self.triangles[i].map(|k| self.vertices[k as usize]);
        (b - a)
            .cross(&(c - a))
            .try_normalize(0.0)
            .unwrap_or_else(Vector3::zeros)
    }
}
