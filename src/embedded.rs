//! The default base model and the templates compiled into the binary
//! (`build.rs` embeds `base_model/base.osim` and the meshes it names), and
//! [`BaseModel`]: where a command's base model comes from, the embedded
//! default or a `--base` folder/file. Commands run from any directory and
//! after `cargo install` without the repository.

use crate::mesh::source::MeshSource;
use crate::mesh::TriMesh;
use crate::osim::geometry::{check_relative, resolve, MeshLookup};
use crate::osim::Document;
use crate::{Error, Result};
use std::path::{Path, PathBuf};

/// The generated file table (`BASE_MODEL`).
pub mod files {
    include!(concat!(env!("OUT_DIR"), "/embedded_files.rs"));
}

/// Name given to the embedded base model in reports and messages.
pub const EMBEDDED_BASE_LABEL: &str = "<embedded>/base_model/base.osim";

/// The bytes of `name` in an embedded table.
fn lookup(table: &'static [(&'static str, &'static [u8])], name: &str) -> Option<&'static [u8]> {
    table.iter().find(|(n, _)| *n == name).map(|(_, b)| *b)
}

/// An embedded file of `base_model/` by name (e.g. `base.osim`, `proc_L1.vtp`).
pub fn base_file_bytes(name: &str) -> Option<&'static [u8]> {
    lookup(files::BASE_MODEL, name)
}

/// Where a base model comes from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum BaseModel {
    /// An .osim file on disk; its meshes are looked up beside it like OpenSim does.
    File(PathBuf),
    /// The default base compiled into the binary.
    Embedded,
}

impl BaseModel {
    /// `--base DIR|FILE` when given, else the embedded default.
    pub fn locate(arg: Option<&Path>) -> Result<BaseModel> {
        match arg {
            Some(p) => base_file(p).map(BaseModel::File),
            None => Ok(BaseModel::Embedded),
        }
    }

    /// The path (or label) naming the base in messages and reports.
    pub fn label(&self) -> PathBuf {
        match self {
            BaseModel::File(p) => p.clone(),
            BaseModel::Embedded => PathBuf::from(EMBEDDED_BASE_LABEL),
        }
    }

    /// Read the base model document.
    pub fn read(&self) -> Result<Document> {
        match self {
            BaseModel::File(p) => Document::read(p),
            BaseModel::Embedded => {
                let bytes = base_file_bytes("base.osim").ok_or_else(|| {
                    Error::invalid(EMBEDDED_BASE_LABEL, "this build embeds no base.osim")
                })?;
                let text = std::str::from_utf8(bytes)
                    .map_err(|e| Error::invalid(EMBEDDED_BASE_LABEL, e.to_string()))?;
                Document::parse(text, EMBEDDED_BASE_LABEL)
            }
        }
    }

    /// The bytes of a mesh the base references (`Ok(None)` when absent).
    pub fn mesh_bytes(&self, mesh_file: &str) -> Result<Option<Vec<u8>>> {
        match self {
            BaseModel::File(p) => match resolve(p, mesh_file, &[]) {
                MeshLookup::Found(f) => crate::mesh::read_file_bytes(&f).map(Some),
                MeshLookup::Missing => Ok(None),
                MeshLookup::Escapes(why) => Err(Error::invalid(p.display().to_string(), why)),
            },
            BaseModel::Embedded => {
                check_relative(mesh_file)
                    .map_err(|why| Error::invalid(EMBEDDED_BASE_LABEL, why.to_string()))?;
                let name = mesh_file.rsplit(['/', '\\']).next().unwrap_or(mesh_file);
                Ok(base_file_bytes(name).map(|b| b.to_vec()))
            }
        }
    }
}

impl MeshSource for BaseModel {
    fn load(&self, mesh_file: &str) -> Result<Option<TriMesh>> {
        let Some(bytes) = self.mesh_bytes(mesh_file)? else {
            return Ok(None);
        };
        let name = Path::new(mesh_file);
        crate::mesh::read_bytes(crate::mesh::Format::from_path(name)?, &bytes, name).map(Some)
    }
    fn describe(&self) -> String {
        match self {
            BaseModel::File(p) => {
                let dirs = crate::osim::geometry::search_dirs(p, &[]);
                let d: Vec<String> = dirs.iter().map(|d| d.display().to_string()).collect();
                d.join(", ")
            }
            BaseModel::Embedded => "the embedded base_model/ meshes".into(),
        }
    }
}

/// The base model file of `--base`: the file itself, or the one .osim of
/// a folder (`base.osim` when it holds several).
pub fn base_file(base: &Path) -> Result<PathBuf> {
    if base.is_file() {
        return Ok(base.to_path_buf());
    }
    let rd = std::fs::read_dir(base).map_err(|e| Error::io(base, e))?;
    let mut osims: Vec<PathBuf> = rd
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().map(|e| e == "osim").unwrap_or(false))
        .collect();
    osims.sort();
    match osims.len() {
        1 => Ok(osims.remove(0)),
        0 => Err(Error::invalid(
            base.display().to_string(),
            "no .osim model in the base folder",
        )),
        n => {
            let pick = base.join("base.osim");
            if pick.is_file() {
                Ok(pick)
            } else {
                Err(Error::invalid(
                    base.display().to_string(),
                    format!("{n} .osim files and no base.osim: give the file"),
                ))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_embedded_base_is_the_model_and_its_meshes_byte_for_byte() {
        // Exactly base.osim and the meshes it names; a stray file of the
        // folder (not named by the model) is not embedded.
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("base_model");
        let doc = crate::osim::Document::read(dir.join("base.osim")).unwrap();
        let model = doc.model().unwrap();
        let mut want: Vec<String> = model.mesh_files().into_iter().map(|(_, f)| f).collect();
        want.push("base.osim".to_string());
        want.sort();
        want.dedup();
        let names: Vec<String> = files::BASE_MODEL
            .iter()
            .map(|(n, _)| n.to_string())
            .collect();
        assert_eq!(names, want);
        for (n, b) in files::BASE_MODEL {
            assert_eq!(*b, std::fs::read(dir.join(n)).unwrap().as_slice(), "{n}");
        }
    }

    #[test]
    fn embedded_base_reads_and_finds_its_meshes() {
        let base = BaseModel::Embedded;
        let doc = base.read().unwrap();
        let model = doc.model().unwrap();
        let mut meshes = 0;
        for b in &model.bodies {
            for g in &b.geometry {
                if let crate::osim::model::Geometry::Mesh { mesh_file, .. } = g {
                    assert!(base.load(mesh_file).unwrap().is_some(), "{mesh_file}");
                    meshes += 1;
                }
            }
        }
        assert!(meshes > 10, "the default base has its vertebra meshes");
    }
}
