//! Never overwrite an input: [`check_outputs`] refuses an output path that
//! resolves (after symlinks) to one of the command's inputs, or that lies in
//! a protected folder (the base model's own folder), unless `--force`.

use crate::error::{Error, Result};
use std::path::{Path, PathBuf};

/// Where outputs must not go.
#[derive(Debug, Default, Clone)]
pub struct Protected {
    /// Input files (never overwritten).
    pub files: Vec<PathBuf>,
    /// Folders no output may be written directly into (e.g. the base
    /// model's folder; outputs that write `Geometry/` beside themselves
    /// would then overwrite the folder's meshes too).
    pub folders: Vec<PathBuf>,
}

impl Protected {
    /// Protect the input `file`.
    pub fn file(mut self, file: &Path) -> Self {
        self.files.push(file.to_path_buf());
        self
    }

    /// Protect each input path: a folder as a folder, anything else as a file.
    pub fn inputs<'a>(mut self, paths: impl IntoIterator<Item = &'a PathBuf>) -> Self {
        for p in paths {
            self = if p.is_dir() {
                self.folder(p)
            } else {
                self.file(p)
            };
        }
        self
    }

    /// Protect everything in `folder`.
    pub fn folder(mut self, folder: &Path) -> Self {
        self.folders.push(folder.to_path_buf());
        self
    }
}

/// `path` with symlinks resolved: the whole path when it exists, else its
/// nearest existing ancestor resolved and the rest appended.
pub fn resolve(path: &Path) -> PathBuf {
    if let Ok(p) = std::fs::canonicalize(path) {
        return p;
    }
    let abs = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
    let comps: Vec<std::path::Component> = abs.components().collect();
    for k in (1..comps.len()).rev() {
        let head: PathBuf = comps[..k].iter().collect();
        if let Ok(base) = std::fs::canonicalize(&head) {
            // The missing part is created by the writer: `..` then steps up.
            return comps[k..].iter().fold(base, |mut acc, c| {
                match c {
                    std::path::Component::ParentDir => {
                        acc.pop();
                    }
                    std::path::Component::CurDir => {}
                    other => acc.push(other),
                }
                acc
            });
        }
    }
    abs
}

/// Refuse each of `outputs` that is (after symlinks) one of the protected
/// files or lies inside a protected folder, unless `force`.
pub fn check_outputs(outputs: &[&Path], protected: &Protected, force: bool) -> Result<()> {
    if force {
        return Ok(());
    }
    let files: Vec<PathBuf> = protected.files.iter().map(|p| resolve(p)).collect();
    let folders: Vec<PathBuf> = protected.folders.iter().map(|p| resolve(p)).collect();
    for out in outputs {
        let r = resolve(out);
        if let Some(i) = files.iter().position(|f| *f == r) {
            return Err(Error::invalid(
                out.display().to_string(),
                format!(
                    "output would overwrite the input {}; refused (pass --force to allow it)",
                    protected.files[i].display()
                ),
            ));
        }
        if let Some(i) = folders.iter().position(|d| r.parent() == Some(d.as_path())) {
            return Err(Error::invalid(
                out.display().to_string(),
                format!(
                    "output would be written into the input folder {} (it could replace an input there); refused (pass --force to allow it)",
                    protected.folders[i].display()
                ),
            ));
        }
    }
    Ok(())
}

/// Refuse an output folder that is (after symlinks) a protected folder, a
/// protected file, or the folder of a protected file (the command writes
/// fixed file names into it, which could replace an input), unless `force`.
pub fn check_output_dir(dir: &Path, protected: &Protected, force: bool) -> Result<()> {
    if force {
        return Ok(());
    }
    let r = resolve(dir);
    let folders = protected.folders.iter().map(|d| (d, resolve(d)));
    let holders = protected.files.iter().map(|f| {
        (
            f,
            resolve(f)
                .parent()
                .map(Path::to_path_buf)
                .unwrap_or_default(),
        )
    });
    for (input, held) in folders.chain(holders) {
        if held == r || resolve(input) == r {
            return Err(Error::invalid(
                dir.display().to_string(),
                format!(
                    "the output folder holds the input {}; writing there could replace it: choose another folder (or pass --force)",
                    input.display()
                ),
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inputs_and_folders_are_protected() {
        let dir = tempfile::tempdir().unwrap();
        let input = dir.path().join("m.osim");
        std::fs::write(&input, "x").unwrap();
        let p = Protected::default().file(&input);
        assert!(check_outputs(&[&input], &p, false).is_err());
        assert!(check_outputs(&[&input], &p, true).is_ok());
        // A symlink to the input, and a path through `..`.
        #[cfg(unix)]
        {
            let link = dir.path().join("link.osim");
            std::os::unix::fs::symlink(&input, &link).unwrap();
            assert!(check_outputs(&[&link], &p, false).is_err());
        }
        let sub = dir.path().join("sub");
        std::fs::create_dir(&sub).unwrap();
        let dotted = sub.join("..").join("m.osim");
        assert!(check_outputs(&[&dotted], &p, false).is_err());
        // Into a protected folder, even a file that does not exist yet.
        let p = Protected::default().folder(&sub);
        assert!(check_outputs(&[&sub.join("out.osim")], &p, false).is_err());
        assert!(check_outputs(&[&sub.join("x/../out.osim")], &p, false).is_err());
        assert!(check_outputs(&[&dir.path().join("out.osim")], &p, false).is_ok());
    }

    #[test]
    fn output_folders_holding_inputs_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let input = dir.path().join("m.osim");
        std::fs::write(&input, "x").unwrap();
        let exp = dir.path().join("exp");
        std::fs::create_dir(&exp).unwrap();
        let p = Protected::default().file(&input).folder(&exp);
        // The input's own folder, the input folder, through `..`: refused.
        assert!(check_output_dir(dir.path(), &p, false).is_err());
        assert!(check_output_dir(&exp, &p, false).is_err());
        assert!(check_output_dir(&exp.join("x/.."), &p, false).is_err());
        assert!(check_output_dir(&input, &p, false).is_err());
        // A new folder beside them is fine, and --force allows the rest.
        assert!(check_output_dir(&dir.path().join("out"), &p, false).is_ok());
        assert!(check_output_dir(&exp.join("out"), &p, false).is_ok());
        assert!(check_output_dir(&exp, &p, true).is_ok());
    }
}
