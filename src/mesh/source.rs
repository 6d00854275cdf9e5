//! Where the meshes a model references come from: folders searched as
//! OpenSim searches them, or meshes held in memory.

use super::TriMesh;
use crate::error::{Error, Result};
use std::collections::BTreeMap;
use std::path::PathBuf;

/// Where meshes referenced by a model come from.
pub trait MeshSource {
    /// The mesh for `mesh_file` as written in the model; `Ok(None)` when
    /// it is not there.
    fn load(&self, mesh_file: &str) -> Result<Option<TriMesh>>;
    /// Where it looked, for error messages.
    fn describe(&self) -> String;
}

/// A body's mesh geometries loaded from a [`MeshSource`], each checked,
/// scaled by its `scale_factors` and merged in the body's frame
/// ([`body_mesh`]).
#[derive(Debug, Clone)]
pub struct BodyMesh {
    /// The merged mesh; `None` when none of its meshes was found (or the
    /// body has none).
    pub mesh: Option<TriMesh>,
    /// The `mesh_file`s found, in the model's order.
    pub found: Vec<String>,
    /// The `mesh_file`s the source does not have.
    pub missing: Vec<String>,
}

/// Load `body`'s Mesh geometries (an empty `mesh_file` names nothing and
/// is skipped) from `source`: each checked ([`TriMesh::validate`]), scaled
/// as the model says and merged in the body's frame.
pub fn body_mesh(body: &crate::osim::model::Body, source: &dyn MeshSource) -> Result<BodyMesh> {
    let mut parts = Vec::new();
    let (mut found, mut missing) = (Vec::new(), Vec::new());
    for g in &body.geometry {
        let crate::osim::model::Geometry::Mesh {
            mesh_file,
            scale_factors,
            ..
        } = g
        else {
            continue;
        };
        if mesh_file.is_empty() {
            continue;
        }
        match source.load(mesh_file)? {
            Some(m) => {
                m.validate().map_err(|e| {
                    Error::invalid(
                        format!("mesh {mesh_file} of body {}", body.name),
                        e.to_string(),
                    )
                })?;
                parts.push(m.scaled(scale_factors));
                found.push(mesh_file.clone());
            }
            None => missing.push(mesh_file.clone()),
        }
    }
    let mesh = if parts.is_empty() {
        None
    } else {
        Some(TriMesh::merge(&parts.iter().collect::<Vec<_>>())?)
    };
    Ok(BodyMesh {
        mesh,
        found,
        missing,
    })
}

/// Meshes looked up like OpenSim does: the model's folder, its
/// `Geometry/`, then the extra folders in order.
pub struct DirMeshSource {
    /// The model file; its folder and its `Geometry/` are searched first.
    pub model_path: PathBuf,
    /// Further folders searched in order after the model's own.
    pub extra: Vec<PathBuf>,
}

impl MeshSource for DirMeshSource {
    fn load(&self, mesh_file: &str) -> Result<Option<TriMesh>> {
        use crate::osim::geometry::{resolve, MeshLookup};
        match resolve(&self.model_path, mesh_file, &self.extra) {
            MeshLookup::Found(p) => super::read(&p).map(Some),
            MeshLookup::Missing => Ok(None),
            MeshLookup::Escapes(why) => {
                Err(Error::invalid(self.model_path.display().to_string(), why))
            }
        }
    }
    fn describe(&self) -> String {
        let dirs = crate::osim::geometry::search_dirs(&self.model_path, &self.extra);
        dirs.iter()
            .map(|d| d.display().to_string())
            .collect::<Vec<_>>()
            .join(", ")
    }
}

/// In-memory meshes by file name (for generated models).
impl MeshSource for BTreeMap<String, TriMesh> {
    fn load(&self, mesh_file: &str) -> Result<Option<TriMesh>> {
        Ok(self.get(mesh_file).cloned())
    }
    fn describe(&self) -> String {
        format!("the {} in-memory meshes", self.len())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::osim::model::{Body, Geometry};
    use nalgebra::{Point3, Vector3};

    fn triangle(x: f64) -> TriMesh {
        let v = vec![
            Point3::new(x, 0.0, 0.0),
            Point3::new(x + 1.0, 0.0, 0.0),
            Point3::new(x, 1.0, 0.0),
        ];
        TriMesh::new(v, vec![[0, 1, 2]]).unwrap()
    }

    fn mesh(file: &str, scale: f64) -> Geometry {
        Geometry::Mesh {
            name: file.into(),
            mesh_file: file.into(),
            scale_factors: Vector3::repeat(scale),
        }
    }

    /// Found meshes are scaled by their own factors and merged in the
    /// model's order; a missing file is listed, an empty name skipped.
    #[test]
    fn body_meshes_are_scaled_merged_and_missing_ones_listed() {
        let source: BTreeMap<String, TriMesh> = [
            ("a.vtp".to_string(), triangle(0.0)),
            ("b.vtp".to_string(), triangle(10.0)),
        ]
        .into();
        let body = Body {
            name: "lumbar1".into(),
            mass: 1.0,
            mass_center: Vector3::zeros(),
            inertia: [1.0, 1.0, 1.0, 0.0, 0.0, 0.0],
            geometry: vec![
                mesh("a.vtp", 2.0),
                mesh("", 1.0),
                mesh("c.vtp", 1.0),
                mesh("b.vtp", 0.5),
            ],
            wrap_objects: Vec::new(),
            line: 1,
        };
        let loaded = body_mesh(&body, &source).unwrap();
        assert_eq!(loaded.found, ["a.vtp", "b.vtp"]);
        assert_eq!(loaded.missing, ["c.vtp"]);
        let m = loaded.mesh.unwrap();
        assert_eq!(m.triangles.len(), 2);
        assert_eq!(m.vertices[1], Point3::new(2.0, 0.0, 0.0));
        assert_eq!(m.vertices[3], Point3::new(5.0, 0.0, 0.0));
        // Nothing found: no mesh.
        let none = Body {
            geometry: vec![mesh("c.vtp", 1.0)],
            ..body
        };
        assert!(body_mesh(&none, &source).unwrap().mesh.is_none());
    }
}
