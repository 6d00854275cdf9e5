//! Small shared helpers: the input gate every reader goes through
//! ([`input`]), atomic output, deterministic number formatting,
//! reports at a stated precision ([`report`]), the one quantile helper
//! ([`quantiles`]), the one progress bar ([`progress`]), the one CSV layer
//! ([`table`]), the one least-squares optimiser ([`lm`]) and the shared SVG
//! figures ([`svg`]).

pub mod charts;
pub mod guard;
pub mod input;
pub mod lm;
pub mod messages;
pub mod output;
pub mod progress;
pub mod quantiles;
pub mod report;
pub mod scalar;
pub mod svg;
pub mod table;

pub use input::{read_bytes_capped, read_text_capped};
pub use quantiles::{iqr, median, quantile};

use crate::error::{Error, Result};
use std::io::Write;
use std::path::Path;

/// Write `bytes` to `path` atomically: a temporary file in the same folder,
/// flushed and then renamed over `path`. Readers never see a half-written
/// file, and on error nothing is left behind.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let dir = parent_or_dot(path);
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let tmp = temp_with(dir, path, bytes)?;
    tmp.persist(path).map_err(|e| Error::io(path, e.error))?;
    Ok(())
}

/// Write a set of output files all or nothing: every file is first
/// written in full to a temporary file beside its target (folders that do
/// not exist yet are created), and only when all of them are written are
/// they moved onto their targets. On any error (a full disk, a read-only
/// folder) the temporary files, any file already moved in and the folders
/// created are removed: no file of the set is left behind.
pub fn write_all_or_nothing(files: &[(std::path::PathBuf, Vec<u8>)]) -> Result<()> {
    let mut created: Vec<std::path::PathBuf> = Vec::new();
    let staged = stage_all(files, &mut created);
    let result = staged.and_then(|temps| commit_all(files, temps));
    if result.is_err() {
        // Deepest first: a folder is removed only once it is empty.
        for d in created.iter().rev() {
            let _ = std::fs::remove_dir(d);
        }
    }
    result
}

/// Each file written to a temporary file beside its target (the folders
/// created on the way recorded in `created`, outermost first).
fn stage_all(
    files: &[(std::path::PathBuf, Vec<u8>)],
    created: &mut Vec<std::path::PathBuf>,
) -> Result<Vec<tempfile::TempPath>> {
    let mut temps = Vec::with_capacity(files.len());
    for (path, bytes) in files {
        let dir = parent_or_dot(path);
        create_dirs(dir, created)?;
        // Closed once written (the path kept): a set of many files does
        // not hold a descriptor each.
        temps.push(temp_with(dir, path, bytes)?.into_temp_path());
    }
    Ok(temps)
}

/// Move every staged file onto its target; on a failure the files already
/// moved in are removed again (the remaining temporary files go with
/// their handles).
fn commit_all(
    files: &[(std::path::PathBuf, Vec<u8>)],
    temps: Vec<tempfile::TempPath>,
) -> Result<()> {
    let mut done: Vec<&Path> = Vec::new();
    for ((path, _), tmp) in files.iter().zip(temps) {
        if let Err(e) = tmp.persist(path) {
            for p in done {
                let _ = std::fs::remove_file(p);
            }
            return Err(Error::io(path, e.error));
        }
        done.push(path);
    }
    Ok(())
}

/// The folder of `path` (`.` for a bare file name).
fn parent_or_dot(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// Create `dir` and its missing ancestors, recording each one created.
fn create_dirs(dir: &Path, created: &mut Vec<std::path::PathBuf>) -> Result<()> {
    if dir.is_dir() {
        return Ok(());
    }
    if let Some(up) = dir.parent().filter(|p| !p.as_os_str().is_empty()) {
        create_dirs(up, created)?;
    }
    match std::fs::create_dir(dir) {
        Ok(()) => {
            created.push(dir.to_path_buf());
            Ok(())
        }
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists && dir.is_dir() => Ok(()),
        Err(e) => Err(Error::io(dir, e)),
    }
}

/// `bytes` in a new temporary file in `dir` (flushed to disk, mode 0644),
/// bound for `target` (named in errors).
fn temp_with(dir: &Path, target: &Path, bytes: &[u8]) -> Result<tempfile::NamedTempFile> {
    let mut tmp = tempfile::Builder::new()
        .prefix(".osim-spine-")
        .suffix(".tmp")
        .tempfile_in(dir)
        .map_err(|e| Error::io(dir, e))?;
    // Through the file itself: the wrapper's errors repeat the temporary path.
    tmp.as_file_mut()
        .write_all(bytes)
        .map_err(|e| Error::io(target, e))?;
    tmp.as_file().sync_all().map_err(|e| Error::io(target, e))?;
    // tempfile creates its files 0600; an output is an ordinary file (0644).
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(tmp.path(), std::fs::Permissions::from_mode(0o644))
            .map_err(|e| Error::io(target, e))?;
    }
    Ok(tmp)
}

/// Format a float the way the project writes numbers into text files: the
/// shortest representation that reads back to the same f64 (Rust's `{}`),
/// with `-0` normalised to `0` so outputs are byte-stable.
pub fn fmt_f64(x: f64) -> String {
    if x == 0.0 {
        "0".to_string()
    } else {
        format!("{x}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn atomic_write_replaces_and_leaves_no_temp() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("out.txt");
        write_atomic(&p, b"one").unwrap();
        write_atomic(&p, b"two").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"two");
        let n = std::fs::read_dir(dir.path()).unwrap().count();
        assert_eq!(n, 1, "temporary file left behind");
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let mode = std::fs::metadata(&p).unwrap().permissions().mode() & 0o777;
            assert_eq!(
                mode, 0o644,
                "outputs must be world-readable like any written file"
            );
        }
    }

    #[test]
    fn float_format_round_trips() {
        for x in [0.1, 1e-300, -2.5, 149000.0, std::f64::consts::PI] {
            assert_eq!(fmt_f64(x).parse::<f64>().unwrap(), x);
        }
        assert_eq!(fmt_f64(-0.0), "0");
    }
}
