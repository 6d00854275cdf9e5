//! Triangle meshes and their file formats.
//!
//! [`TriMesh`] is the one in-memory mesh type shared by all geometry work
//! (registration, sphere fitting, palpation, collision checks). Coordinates
//! are in metres once read; readers for files in other units say so.
//!
//! | submodule | what lives there |
//! |---|---|
//! | [`vtp`], [`stl`], [`obj`], [`ply`] | one reader/writer per file format, each usable on in-memory bytes |
//! | [`geom`] | transforms, merge, area/volume/centroids, principal axes, normals, topology checks, orientation, welding |
//! | [`query`] | [`MeshQuery`]: closest point, inside test, segment/ray intersection (parry BVH built once) |
//! | [`sphere`] | least-squares sphere fit and the anterior vertebral-body node rule |
//! | [`register`] | Kabsch/Umeyama, ICP with PCA initialisation, residual statistics, generalised Procrustes |
//! | [`sample`] | seeded uniform surface sampling |
//! | [`distance`] | symmetric surface distance between two surfaces |
//! | [`manifold`] | non-manifold edges of voxel surfaces split |
//! | [`smooth`], [`decimate`] | Taubin's lambda/mu smoothing; quadric-error decimation (meshoptimizer) |
//!
//! [`read`] and [`write()`] dispatch on the file extension.

pub mod decimate;
pub mod distance;
pub mod geom;
pub mod manifold;
pub mod obj;
pub mod ply;
pub mod query;
pub mod register;
pub mod sample;
pub mod smooth;
pub mod source;
pub mod sphere;
pub mod stl;
pub mod vtp;

pub use geom::{EdgeReport, PrincipalAxes};
pub use query::{MeshQuery, SurfaceHit};
pub use register::{
    gpa, gpa_meshes, icp, icp_mesh, kabsch, umeyama, GpaResult, IcpOptions, IcpResult, Residuals,
    Similarity,
};
pub use sample::sample_surface;
pub use sphere::{anterior_body_nodes, fit_sphere, AnatomicalFrame, Sphere};

use crate::error::{Error, Result};
use nalgebra::{Point3, Vector3};
use std::path::Path;

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
    ///
    /// Panics if `i` or the triangle's indices are out of range: meshes
    /// built by [`TriMesh::new`] and the readers are always in range.
    pub fn triangle_normal(&self, i: usize) -> Vector3<f64> {
        let [a, b, c] = self.corners(i);
        (b - a)
            .cross(&(c - a))
            .try_normalize(0.0)
            .unwrap_or_else(Vector3::zeros)
    }

    /// The three corner positions of triangle `i` (same range contract as
    /// [`TriMesh::triangle_normal`]).
    pub fn corners(&self, i: usize) -> [Point3<f64>; 3] {
        self.triangles[i].map(|k| self.vertices[k as usize])
    }

    /// Iterator over the corner positions of every triangle.
    pub fn triangle_corners(&self) -> impl Iterator<Item = [Point3<f64>; 3]> + '_ {
        (0..self.triangles.len()).map(|i| self.corners(i))
    }

    /// Largest distance between corresponding triangle corners of two
    /// meshes (triangle `i` corner `j` against the same in `other`),
    /// whatever the vertex numbering; `None` if the triangle counts differ.
    /// Used to compare meshes across formats that renumber vertices (STL).
    pub fn max_corner_distance(&self, other: &TriMesh) -> Option<f64> {
        if self.triangles.len() != other.triangles.len() {
            return None;
        }
        let mut d: f64 = 0.0;
        for (a, b) in self.triangle_corners().zip(other.triangle_corners()) {
            for j in 0..3 {
                d = d.max((a[j] - b[j]).norm());
            }
        }
        Some(d)
    }

    /// Check the invariants of [`TriMesh::new`] on an existing value (for
    /// meshes assembled by hand through the public fields).
    pub fn validate(&self) -> Result<()> {
        let n = self.vertices.len();
        for (i, t) in self.triangles.iter().enumerate() {
            if t.iter().any(|&k| k as usize >= n) {
                return Err(Error::invalid(
                    "mesh",
                    format!("triangle {i} {t:?} indexes past the {n} vertices"),
                ));
            }
        }
        if let Some(i) = self
            .vertices
            .iter()
            .position(|v| !v.coords.iter().all(|c| c.is_finite()))
        {
            return Err(Error::invalid(
                "mesh",
                format!("vertex {i} has a non-finite coordinate"),
            ));
        }
        Ok(())
    }
}

/// Mesh file formats known to [`read`] and [`write()`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// VTK XML PolyData (`.vtp`).
    Vtp,
    /// Stereolithography (`.stl`), ASCII or binary.
    Stl,
    /// Wavefront OBJ (`.obj`).
    Obj,
    /// Stanford PLY (`.ply`), ASCII or binary.
    Ply,
}

impl Format {
    /// The format named by a path's extension (case-insensitive).
    pub fn from_path(path: &Path) -> Result<Format> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(|e| e.to_ascii_lowercase());
        match ext.as_deref() {
            Some("vtp") => Ok(Format::Vtp),
            Some("stl") => Ok(Format::Stl),
            Some("obj") => Ok(Format::Obj),
            Some("ply") => Ok(Format::Ply),
            _ => Err(Error::invalid(
                path.display().to_string(),
                "unknown mesh format: expected a .vtp, .stl, .obj or .ply file",
            )),
        }
    }
}

/// Read a mesh file, choosing the reader from the extension
/// (`.vtp`, `.stl`, `.obj`, `.ply`). Coordinates are taken as metres.
pub fn read(path: &Path) -> Result<TriMesh> {
    let format = Format::from_path(path)?;
    let bytes = read_file_bytes(path)?;
    read_bytes(format, &bytes, path)
}

pub use crate::osim::geometry::MAX_MESH_BYTES;

/// The bytes of a mesh file, through the crate's input gate (regular files
/// only, at most [`MAX_MESH_BYTES`]).
pub fn read_file_bytes(path: &Path) -> Result<Vec<u8>> {
    crate::util::read_bytes_capped(path, MAX_MESH_BYTES, "mesh files")
}

/// Most triangles a mesh may have: a vertebra's surface needs tens of
/// thousands; a binary STL declaring more is refused before it is read.
pub const MAX_MESH_TRIANGLES: usize = 2_000_000;

/// The refusal of a mesh of `n` triangles (over [`MAX_MESH_TRIANGLES`]).
pub fn too_many_triangles(name: &Path, n: u64) -> Error {
    Error::parse(
        name,
        "triangles",
        format!(
            "{n} triangles: meshes are limited to {MAX_MESH_TRIANGLES}; decimate it first (e.g. MeshLab's Quadric Edge Collapse Decimation to 100,000 faces)"
        ),
    )
}

/// Parse in-memory bytes in `format`; `name` is used in error messages.
pub fn read_bytes(format: Format, bytes: &[u8], name: &Path) -> Result<TriMesh> {
    let mesh = match format {
        Format::Vtp => vtp::read_bytes(bytes, name),
        Format::Stl => stl::read_bytes(bytes, name),
        Format::Obj => obj::read_bytes(bytes, name),
        Format::Ply => ply::read_bytes(bytes, name),
    }?;
    if mesh.triangles.len() > MAX_MESH_TRIANGLES {
        return Err(too_many_triangles(name, mesh.triangles.len() as u64));
    }
    check_coordinates(&mesh, name)?;
    Ok(mesh)
}

/// Largest |coordinate| a mesh may have (in its file's unit, metres or
/// millimetres): far beyond any anatomy, small enough that areas, normals
/// and volumes stay finite in f64.
pub const MAX_COORDINATE: f64 = 1e9;

/// Refuse a mesh with a coordinate that is not finite or beyond
/// [`MAX_COORDINATE`], naming the vertex.
pub fn check_coordinates(mesh: &TriMesh, name: &Path) -> Result<()> {
    let bad = mesh.vertices.iter().position(|p| {
        p.coords
            .iter()
            .any(|x| !x.is_finite() || x.abs() > MAX_COORDINATE)
    });
    match bad {
        None => Ok(()),
        Some(i) => Err(Error::parse(
            name,
            format!("vertex {i}"),
            format!(
                "coordinates {:?} are not finite or beyond +-{MAX_COORDINATE:e}",
                mesh.vertices[i].coords.as_slice()
            ),
        )),
    }
}

/// Write a mesh, choosing the writer from the extension. Every format is
/// written losslessly for f64 coordinates: VTP as ASCII Float64, STL as
/// ASCII with shortest round-trip numbers, OBJ likewise, PLY as ASCII.
/// (Use [`stl::write_binary`] for compact float32 STL and
/// [`vtp::write_binary`] for base64/zlib VTP.) The file is written
/// atomically.
pub fn write(path: &Path, mesh: &TriMesh) -> Result<()> {
    let bytes = to_bytes(Format::from_path(path)?, mesh);
    crate::util::write_atomic(path, &bytes)
}

/// Serialise a mesh in `format` with the defaults of [`write()`].
pub fn to_bytes(format: Format, mesh: &TriMesh) -> Vec<u8> {
    match format {
        Format::Vtp => vtp::to_ascii(mesh).into_bytes(),
        Format::Stl => stl::to_ascii(mesh, "osim-spine").into_bytes(),
        Format::Obj => obj::to_string(mesh).into_bytes(),
        Format::Ply => ply::to_ascii(mesh).into_bytes(),
    }
}

/// 1-based line number of byte offset `pos` in `bytes` (for error messages).
pub(crate) fn line_of(bytes: &[u8], pos: usize) -> usize {
    let end = pos.min(bytes.len());
    bytes[..end].iter().filter(|&&b| b == b'\n').count() + 1
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn format_from_extension() {
        assert_eq!(
            Format::from_path(Path::new("a/B.VTP")).unwrap(),
            Format::Vtp
        );
        assert_eq!(Format::from_path(Path::new("x.ply")).unwrap(), Format::Ply);
        let e = Format::from_path(Path::new("x.off"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("x.off"), "{e}");
    }

    #[test]
    fn new_rejects_bad_indices_and_nan() {
        let v = vec![Point3::origin(); 3];
        assert!(TriMesh::new(v.clone(), vec![[0, 1, 3]]).is_err());
        let mut w = v.clone();
        w[1].y = f64::NAN;
        assert!(TriMesh::new(w, vec![[0, 1, 2]]).is_err());
        assert!(TriMesh::new(v, vec![[0, 1, 2]]).is_ok());
    }

    #[test]
    fn line_numbers() {
        let b = b"a\nb\nc";
        assert_eq!(line_of(b, 0), 1);
        assert_eq!(line_of(b, 2), 2);
        assert_eq!(line_of(b, 100), 3);
    }
}
