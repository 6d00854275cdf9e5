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
