//! Mesh file resolution like OpenSim: the model's folder, its `Geometry/`
//! subfolder, then any extra folders given (`--geometry DIR`). A
//! `mesh_file` that is absolute or contains `..` is never followed: it is
//! reported as escaping its folder.

use std::path::{Component, Path, PathBuf};

/// Outcome of looking up one mesh file.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum MeshLookup {
    /// Found at this path.
    Found(PathBuf),
    /// Not in any of the searched folders.
    Missing,
    /// Absolute, or climbing out with `..`: not followed.
    Escapes(String),
}

/// Folders searched for meshes of a model at `model_path`, in order.
pub fn search_dirs(model_path: &Path, extra: &[PathBuf]) -> Vec<PathBuf> {
    let dir = match model_path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let mut out = vec![dir.clone(), dir.join("Geometry")];
    out.extend(extra.iter().cloned());
    out
}

/// Check a `mesh_file` text: `Err(reason)` when it may not be followed.
pub fn check_relative(mesh_file: &str) -> Result<&Path, String> {
    let p = Path::new(mesh_file);
    if mesh_file.contains('\0') {
        return Err("contains a NUL character".into());
    }
    for c in p.components() {
        match c {
            Component::ParentDir => {
                return Err("contains '..' (escapes the geometry folders)".into())
            }
            Component::RootDir | Component::Prefix(_) => {
                return Err("is an absolute path (must be relative to the geometry folders)".into())
            }
            _ => {}
        }
    }
    Ok(p)
}

/// Find `mesh_file` in the folders of [`search_dirs`].
pub fn resolve(model_path: &Path, mesh_file: &str, extra: &[PathBuf]) -> MeshLookup {
    let rel = match check_relative(mesh_file) {
        Ok(r) => r,
        Err(why) => return MeshLookup::Escapes(format!("mesh_file '{mesh_file}' {why}")),
    };
    for d in search_dirs(model_path, extra) {
        let p = d.join(rel);
        if p.is_file() {
            return MeshLookup::Found(p);
        }
    }
    MeshLookup::Missing
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lookup_order_and_escapes() {
        let dir = tempfile::tempdir().unwrap();
        let model = dir.path().join("m.osim");
        std::fs::create_dir(dir.path().join("Geometry")).unwrap();
        std::fs::write(dir.path().join("Geometry/a.vtp"), "x").unwrap();
        let extra = tempfile::tempdir().unwrap();
        std::fs::write(extra.path().join("b.vtp"), "x").unwrap();
        let ex = vec![extra.path().to_path_buf()];
        assert_eq!(
            resolve(&model, "a.vtp", &ex),
            MeshLookup::Found(dir.path().join("Geometry/a.vtp"))
        );
        assert_eq!(
            resolve(&model, "b.vtp", &ex),
            MeshLookup::Found(extra.path().join("b.vtp"))
        );
        assert_eq!(resolve(&model, "c.vtp", &ex), MeshLookup::Missing);
        assert!(matches!(
            resolve(&model, "../Geometry/a.vtp", &ex),
            MeshLookup::Escapes(_)
        ));
        assert!(matches!(
            resolve(&model, "/etc/passwd", &ex),
            MeshLookup::Escapes(_)
        ));
    }
}
