//! Swapping in a mean sacrum: the given mesh is cleaned (exact duplicate
//! triangles removed; remaining non-manifold edges are counted and
//! reported: registration and ray casting do not need a manifold), registered onto
//! the generic sacrum surface by ICP (rigid, or similarity with
//! `allow_scale`; initial alignment from the 24 signed permutations of the
//! principal axes, see [`crate::mesh::register`]), and its residual
//! surface distance is reported both ways (registered mesh to generic, and
//! generic to registered). A registration whose RMS distance exceeds the
//! limit is refused: the mesh is not a sacrum like the generic one.

use crate::error::{Error, Result};
use crate::mesh::{icp_mesh, IcpOptions, MeshQuery, Residuals, TriMesh};
use std::collections::BTreeSet;

/// Residual statistics in the report (mm).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ResidualMm {
    /// Number of distances.
    pub n: usize,
    /// Root mean square distance (mm).
    pub rms_mm: f64,
    /// Mean distance (mm).
    pub mean_mm: f64,
    /// 95th percentile distance (mm).
    pub p95_mm: f64,
    /// Largest distance (mm).
    pub max_mm: f64,
}

impl From<Residuals> for ResidualMm {
    fn from(r: Residuals) -> Self {
        ResidualMm {
            n: r.n,
            rms_mm: r.rms * 1e3,
            mean_mm: r.mean * 1e3,
            p95_mm: r.p95 * 1e3,
            max_mm: r.max * 1e3,
        }
    }
}

/// What the sacrum swap did.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct SacrumReport {
    /// Where the mesh came from.
    pub source: String,
    /// Generic sacrum mesh file it replaced.
    pub replaced: String,
    /// New mesh file name written next to the model.
    pub mesh_file: String,
    /// Vertex count of the swapped-in mesh.
    pub vertices: usize,
    /// Triangle count of the swapped-in mesh.
    pub triangles: usize,
    /// Exact duplicate triangles removed before registration.
    pub duplicate_triangles_removed: usize,
    /// Edges shared by more than two triangles after that (the sacrum is
    /// only registered and ray-cast, which tolerates them; reported).
    pub non_manifold_edges: usize,
    /// Whether a similarity (scaled) registration was allowed.
    pub allow_scale: bool,
    /// Registration: 4x4 matrix (row-major) from the source mesh to the
    /// sacrum body frame, and its scale.
    pub transform: [[f64; 4]; 4],
    /// Scale factor of the registration (1 when rigid).
    pub scale: f64,
    /// Distances of the registered mesh's vertices to the generic sacrum.
    pub residual_to_generic: ResidualMm,
    /// Distances of the generic sacrum's vertices to the registered mesh.
    pub residual_from_generic: ResidualMm,
    /// ICP iterations run.
    pub icp_iterations: usize,
}

/// Remove exact duplicate triangles (same three vertices, any order or
/// winding); returns the number removed.
pub(crate) fn remove_duplicate_triangles(mesh: &mut TriMesh) -> usize {
    let mut seen = BTreeSet::new();
    let before = mesh.triangles.len();
    mesh.triangles.retain(|t| {
        let mut k = *t;
        k.sort_unstable();
        seen.insert(k)
    });
    before - mesh.triangles.len()
}

/// Register `source` onto `generic` (both meshes; the result is in the
/// generic's frame). `max_rms` (m) bounds the accepted RMS residual.
pub fn register_sacrum(
    source: &TriMesh,
    source_name: &str,
    generic: &TriMesh,
    generic_name: &str,
    new_name: &str,
    allow_scale: bool,
    max_rms: f64,
) -> Result<(TriMesh, SacrumReport)> {
    let ctx = format!("sacrum mesh {source_name}");
    let mut src = source.clone();
    let dups = remove_duplicate_triangles(&mut src);
    let non_manifold_edges = src.edge_report().non_manifold_edges.len();
    if src.vertices.len() < 10 || src.triangles.is_empty() {
        return Err(Error::invalid(
            &ctx,
            "the mesh has too few vertices/triangles to register",
        ));
    }
    let target = MeshQuery::new(generic).map_err(|e| {
        Error::invalid(format!("generic sacrum mesh {generic_name}"), e.to_string())
    })?;
    let opts = IcpOptions {
        allow_scale,
        ..IcpOptions::default()
    };
    let r = icp_mesh(&src, &target, &opts).map_err(|e| Error::invalid(&ctx, e.to_string()))?;
    let moved = r.transform.apply_mesh(&src);
    let back = MeshQuery::new(&moved).map_err(|e| Error::invalid(&ctx, e.to_string()))?;
    let from_generic = Residuals::to_surface(&generic.vertices, &back);
    let to_generic = r.residuals;
    if !(to_generic.rms <= max_rms && from_generic.rms <= max_rms) {
        return Err(Error::invalid(
            &ctx,
            format!(
                "cannot be registered onto the generic sacrum {generic_name}: RMS surface distance \
                 {:.2} mm (mesh to generic) / {:.2} mm (generic to mesh) after ICP, limit {:.2} mm \
                 (is it a sacrum, in metres?{})",
                to_generic.rms * 1e3,
                from_generic.rms * 1e3,
                max_rms * 1e3,
                if allow_scale { "" } else { " try --allow-scale" }
            ),
        ));
    }
    let m = r.transform.to_matrix();
    let transform = std::array::from_fn(|i| std::array::from_fn(|j| m[(i, j)]));
    let report = SacrumReport {
        source: source_name.to_string(),
        replaced: generic_name.to_string(),
        mesh_file: new_name.to_string(),
        vertices: moved.vertices.len(),
        triangles: moved.triangles.len(),
        duplicate_triangles_removed: dups,
        non_manifold_edges,
        allow_scale,
        transform,
        scale: r.transform.scale,
        residual_to_generic: to_generic.into(),
        residual_from_generic: from_generic.into(),
        icp_iterations: r.iterations,
    };
    Ok((moved, report))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;

    #[test]
    fn duplicates_are_removed_whatever_the_winding() {
        let mut m = TriMesh {
            vertices: vec![
                Point3::origin(),
                Point3::new(1.0, 0.0, 0.0),
                Point3::new(0.0, 1.0, 0.0),
            ],
            triangles: vec![[0, 1, 2], [2, 1, 0], [1, 2, 0]],
        };
        assert_eq!(remove_duplicate_triangles(&mut m), 2);
        assert_eq!(m.triangles, vec![[0, 1, 2]]);
    }
}
