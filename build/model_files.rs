//! The rule of what `build.rs` embeds of the default base model: the model
//! file `base.osim` and the mesh files it names (`<mesh_file>`), nothing
//! else of the folder (a stray `opensim.log` or an editor's backup never
//! reaches the binary). Shared by `build.rs` and `tests/embedded_files.rs`.

use std::fmt;
use std::path::{Path, PathBuf};

/// The model file of the base model folder.
pub const MODEL_FILE: &str = "base.osim";

/// Why the embedded file list cannot be made.
#[derive(Debug)]
pub enum ModelFilesError {
    /// The model file cannot be read as UTF-8 text.
    Unreadable(PathBuf, std::io::Error),
    /// The model names a mesh that is not a plain file of the folder.
    MissingMesh {
        /// The model file.
        model: PathBuf,
        /// The `<mesh_file>` text.
        mesh: String,
    },
}

impl fmt::Display for ModelFilesError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ModelFilesError::Unreadable(p, e) => {
                write!(f, "{}: cannot be read as UTF-8 text: {e}", p.display())
            }
            ModelFilesError::MissingMesh { model, mesh } => write!(
                f,
                "{} names the mesh `{mesh}`, which is not a file of its folder \
                 (expected a plain file name beside the model)",
                model.display()
            ),
        }
    }
}

/// `base.osim` of `dir` and the mesh files it names, sorted and without
/// repeats (the same table on every machine).
pub fn model_files(dir: &Path) -> Result<Vec<String>, ModelFilesError> {
    let model = dir.join(MODEL_FILE);
    let text = std::fs::read_to_string(&model)
        .map_err(|e| ModelFilesError::Unreadable(model.clone(), e))?;
    // The text of every non-empty `<mesh_file>` element.
    let mut names: Vec<String> = text
        .split("<mesh_file>")
        .skip(1)
        .filter_map(|rest| rest.split("</mesh_file>").next())
        .map(|n| n.trim().to_string())
        .filter(|n| !n.is_empty())
        .collect();
    names.push(MODEL_FILE.to_string());
    names.sort();
    names.dedup();
    // Each a plain file beside the model.
    for n in &names {
        if n.contains(['/', '\\']) || !dir.join(n).is_file() {
            return Err(ModelFilesError::MissingMesh {
                model,
                mesh: n.clone(),
            });
        }
    }
    Ok(names)
}
