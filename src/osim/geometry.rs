//! Mesh file resolution like OpenSim: the model's folder, its `Geometry/`
//! subfolder, then any extra folders given (`--geometry DIR`). A
//! `mesh_file` that is absolute or contains `..` is never followed: it is
//! reported as escaping its folder. Nor is a file found there that
//! resolves (through a symbolic link, of the file or of a folder on its
//! way) outside the model's folder tree or the `--geometry` folder it was
//! found in: a model folder from someone else cannot make the tool read,
//! or copy into an output, a file from elsewhere.

use super::xml::Element;
use crate::error::Result;
use std::path::{Component, Path, PathBuf};

/// Largest mesh file read (bytes): far above any vertebra or pelvis mesh.
pub const MAX_MESH_BYTES: u64 = 512 * 1024 * 1024;

/// Outcome of looking up one mesh file.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum MeshLookup {
    /// Found at this path.
    Found(PathBuf),
    /// Not in any of the searched folders.
    Missing,
    /// Absolute, climbing out with `..`, or a symbolic link leading out of
    /// the folders searched: not followed.
    Escapes(String),
}

/// Folders searched for meshes of a model at `model_path`, in order.
pub fn search_dirs(model_path: &Path, extra: &[PathBuf]) -> Vec<PathBuf> {
    search_roots(model_path, extra)
        .into_iter()
        .map(|(d, _, _)| d)
        .collect()
}

/// The folders searched, each with the tree a file found in it must stay
/// inside (and that tree's name): the model's folder for the folder and
/// its `Geometry/`, each `--geometry` folder for itself.
fn search_roots(model_path: &Path, extra: &[PathBuf]) -> Vec<(PathBuf, PathBuf, &'static str)> {
    let dir = match model_path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let model = "the model's folder";
    let mut out = vec![
        (dir.clone(), dir.clone(), model),
        (dir.join("Geometry"), dir, model),
    ];
    out.extend(extra.iter().map(|d| {
        (
            d.clone(),
            d.clone(),
            "the --geometry folder it was found in",
        )
    }));
    out
}

/// Why a `mesh_file` text may not be followed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum UnsafeMeshPath {
    /// The text holds a NUL character.
    #[error("contains a NUL character")]
    Nul,
    /// A `..` component would leave the geometry folders.
    #[error("contains '..' (escapes the geometry folders)")]
    ParentDir,
    /// The path is absolute.
    #[error("is an absolute path (must be relative to the geometry folders)")]
    Absolute,
}

/// Check a `mesh_file` text: the relative path to follow, or why not.
pub fn check_relative(mesh_file: &str) -> Result<&Path, UnsafeMeshPath> {
    let p = Path::new(mesh_file);
    if mesh_file.contains('\0') {
        return Err(UnsafeMeshPath::Nul);
    }
    for c in p.components() {
        match c {
            Component::ParentDir => return Err(UnsafeMeshPath::ParentDir),
            Component::RootDir | Component::Prefix(_) => return Err(UnsafeMeshPath::Absolute),
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
    for (d, root, tree) in search_roots(model_path, extra) {
        let p = d.join(rel);
        if p.is_file() {
            if !inside(&p, &root) {
                return MeshLookup::Escapes(format!(
                    "mesh_file '{mesh_file}' is a symbolic link (or lies in a linked folder) leading outside {tree}; not followed"
                ));
            }
            return MeshLookup::Found(p);
        }
    }
    MeshLookup::Missing
}

/// `true` when `p` resolves (symbolic links followed) to a file inside
/// the folder `root` (resolved likewise).
fn inside(p: &Path, root: &Path) -> bool {
    match (std::fs::canonicalize(p), std::fs::canonicalize(root)) {
        (Ok(f), Ok(r)) => f.starts_with(r),
        _ => false,
    }
}

/// Every `mesh_file` of a model element tree (bodies, ground, offset
/// frames), in document order, each once, empty ones skipped.
pub fn mesh_files(root: &Element) -> Vec<String> {
    let mut out: Vec<String> = Vec::new();
    let mut stack = vec![root];
    while let Some(e) = stack.pop() {
        if e.name == "mesh_file" {
            let f = e.text().trim().to_string();
            if !f.is_empty() && !out.contains(&f) {
                out.push(f);
            }
            continue;
        }
        // Children pushed in reverse: popped in document order.
        stack.extend(e.elements().collect::<Vec<_>>().into_iter().rev());
    }
    out
}

/// Remove every `Mesh` geometry whose `mesh_file` is one of `files` (in
/// any frame of the tree); returns how many were removed.
pub fn drop_meshes(root: &mut Element, files: &[String]) -> usize {
    let before = root.children.len();
    root.children.retain(|n| match n {
        super::xml::Node::Element(e) if e.name == "Mesh" => e
            .child_text("mesh_file")
            .is_none_or(|f| !files.contains(&f)),
        _ => true,
    });
    let mut removed = before - root.children.len();
    for e in root.elements_mut() {
        removed += drop_meshes(e, files);
    }
    removed
}

/// The meshes an output model needs beside it.
#[derive(Debug, Default)]
pub struct MeshCopies {
    /// (destination path, bytes): meshes to write into the output's
    /// `Geometry/` folder.
    pub files: Vec<(PathBuf, Vec<u8>)>,
    /// Meshes found neither beside the output nor where the source model
    /// looks: OpenSim will not find them either.
    pub missing: Vec<String>,
}

/// What makes every mesh of a model read from `source` resolvable by
/// OpenSim from an output model at `out`: meshes the output's folder
/// already resolves (e.g. the same folder) need nothing; the others are
/// read where the source model finds them (its folder, `Geometry/`,
/// `extra`) and copied into `out`'s `Geometry/`. Escaping names are not
/// followed and count as missing.
pub fn mesh_copies(
    files: &[String],
    source: &Path,
    out: &Path,
    extra: &[PathBuf],
) -> Result<MeshCopies> {
    let mut copies = MeshCopies::default();
    let geometry = search_dirs(out, &[])[1].clone();
    for f in files {
        if matches!(resolve(out, f, &[]), MeshLookup::Found(_)) {
            continue;
        }
        match resolve(source, f, extra) {
            MeshLookup::Found(p) => {
                let bytes = crate::util::read_bytes_capped(&p, MAX_MESH_BYTES, "mesh files")?;
                copies.files.push((geometry.join(f), bytes));
            }
            MeshLookup::Missing | MeshLookup::Escapes(_) => copies.missing.push(f.clone()),
        }
    }
    Ok(copies)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unsafe_mesh_paths_are_typed() {
        assert!(check_relative("Geometry/l1.vtp").is_ok());
        assert_eq!(check_relative("../x.vtp"), Err(UnsafeMeshPath::ParentDir));
        assert_eq!(check_relative("/etc/passwd"), Err(UnsafeMeshPath::Absolute));
        assert_eq!(check_relative("a\0b"), Err(UnsafeMeshPath::Nul));
    }

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

    #[test]
    fn meshes_follow_a_model_written_elsewhere() {
        let src = tempfile::tempdir().unwrap();
        let model = src.path().join("m.osim");
        std::fs::create_dir(src.path().join("Geometry")).unwrap();
        std::fs::write(src.path().join("Geometry/a.vtp"), "A").unwrap();
        std::fs::write(src.path().join("b.stl"), "B").unwrap();
        let files: Vec<String> = ["a.vtp", "b.stl", "gone.obj", "../x.vtp"]
            .map(String::from)
            .into();
        // Another folder: the found meshes go to its Geometry/.
        let out = tempfile::tempdir().unwrap();
        let o = out.path().join("sub/n.osim");
        let c = mesh_copies(&files, &model, &o, &[]).unwrap();
        let dests: Vec<&PathBuf> = c.files.iter().map(|(p, _)| p).collect();
        let g = out.path().join("sub/Geometry");
        assert_eq!(dests, [&g.join("a.vtp"), &g.join("b.stl")]);
        assert_eq!(c.files[0].1, b"A");
        assert_eq!(c.missing, ["gone.obj", "../x.vtp"]);
        // The same folder: nothing to copy.
        let same = mesh_copies(&files, &model, &src.path().join("n.osim"), &[]).unwrap();
        assert!(same.files.is_empty());
    }

    #[test]
    fn mesh_files_are_listed_once_in_order() {
        let root = Element::new("Model")
            .with_child(
                Element::new("Body")
                    .with_child(Element::new("Mesh").with_prop("mesh_file", "b.vtp")),
            )
            .with_child(Element::new("Mesh").with_prop("mesh_file", "a.vtp"))
            .with_child(Element::new("Mesh").with_prop("mesh_file", "b.vtp"))
            .with_child(Element::new("Mesh").with_prop("mesh_file", " "));
        assert_eq!(mesh_files(&root), ["b.vtp", "a.vtp"]);
        let mut root = root;
        assert_eq!(drop_meshes(&mut root, &["b.vtp".to_string()]), 2);
        assert_eq!(mesh_files(&root), ["a.vtp"]);
    }
}
