//! A folder of per-level surface meshes: one file per level named by the
//! level (`T1.stl` .. `L5.stl`, `S1.*` or `sacrum.*`; also the names
//! TotalSegmentator writes, `vertebrae_L3.*`, `sacrum.*`), in `.stl`,
//! `.obj`, `.vtp` or `.ply`, all in the same length units. Two files for
//! one level are refused, except TotalSegmentator's `sacrum` plus
//! `vertebrae_S1`, which together are the sacrum (merged). Other files are
//! named in the notes and ignored. Each mesh must be non-empty and closed
//! (after welding coincident vertices). A folder of per-structure NIfTI
//! masks named by level (TotalSegmentator's default output) is refused with
//! what to give instead.

use super::labels::{class_of_name, LabelClass};
use crate::error::{Error, Result};
use crate::landmarks::Level;
use crate::mesh::{self, TriMesh};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Mesh file extensions read.
const EXTENSIONS: [&str; 4] = ["stl", "obj", "vtp", "ply"];

use crate::mesh::MAX_MESH_BYTES;

/// The mesh files of a folder named by a level, and what was left out.
#[derive(Debug, Clone, PartialEq)]
pub struct LevelFiles {
    /// The files of each level (one or, for TotalSegmentator's sacrum, two).
    pub by_level: BTreeMap<Level, Vec<PathBuf>>,
    /// Notes on the files ignored.
    pub notes: Vec<String>,
}

/// The level files of a folder (see [`LevelFiles`]).
pub fn level_files(dir: &Path) -> Result<LevelFiles> {
    let rd = std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))?;
    let mut paths: Vec<PathBuf> = rd.filter_map(|e| e.ok().map(|e| e.path())).collect();
    paths.sort();
    let mut by_level: BTreeMap<Level, Vec<PathBuf>> = BTreeMap::new();
    let mut notes = Vec::new();
    let mut masks = Vec::new();
    let mut others = Vec::new();
    for p in paths {
        if let Some(stem) = super::nifti_stem(&p).filter(|_| p.is_file()) {
            if matches!(class_of_name(&stem), LabelClass::Level(_)) {
                masks.push(p.display().to_string());
            }
            continue;
        }
        let Some(stem) = mesh_stem(&p) else { continue };
        match class_of_name(&stem) {
            LabelClass::Level(l) if !p.is_file() => notes.push(format!(
                "{}: named as {l}'s mesh but {}: not read",
                p.display(),
                not_a_file(&p)
            )),
            LabelClass::Level(l) => by_level.entry(l).or_default().push(p),
            _ => others.push(p.display().to_string()),
        }
    }
    if !others.is_empty() {
        notes.push(format!(
            "not a T1..L5 vertebra or the sacrum, ignored: {}",
            crate::util::messages::bounded_list(&others, 5)
        ));
    }
    for (level, files) in &by_level {
        if files.len() > 1 && !is_ts_sacrum_pair(*level, files) {
            let names: Vec<String> = files.iter().map(|f| f.display().to_string()).collect();
            return Err(Error::invalid(
                dir.display().to_string(),
                format!("two meshes for {level}: {} (keep one)", names.join(" and ")),
            ));
        }
    }
    // Per-structure binary masks (TotalSegmentator's default output): not
    // a folder of meshes, and not one label map.
    if !masks.is_empty() {
        if by_level.is_empty() {
            return Err(Error::invalid(
                dir.display().to_string(),
                format!(
                    "a folder of per-structure NIfTI masks ({} ...), not of meshes: give one label map instead (TotalSegmentator: run it with --ml, or combine the masks), or export the masks as closed surfaces",
                    masks[0]
                ),
            ));
        }
        notes.push(format!(
            "{} NIfTI mask(s) named by a level ignored (only the meshes are read): {}",
            masks.len(),
            masks.join(", ")
        ));
    }
    Ok(LevelFiles { by_level, notes })
}

/// The stem of a mesh file name (`vertebrae_L3` of `vertebrae_L3.stl`),
/// `None` for other names.
fn mesh_stem(p: &Path) -> Option<String> {
    let ext = p.extension()?.to_str()?.to_ascii_lowercase();
    if !EXTENSIONS.contains(&ext.as_str()) {
        return None;
    }
    Some(p.file_stem()?.to_str()?.to_string())
}

/// What a path that is not a regular file is (a folder, a device, a FIFO,
/// a broken link), in words.
fn not_a_file(p: &Path) -> &'static str {
    use std::os::unix::fs::FileTypeExt;
    match std::fs::metadata(p) {
        Err(_) => "a broken link (or unreadable)",
        Ok(m) if m.is_dir() => "a folder",
        Ok(m) if m.file_type().is_block_device() || m.file_type().is_char_device() => "a device",
        Ok(m) if m.file_type().is_fifo() => "a FIFO",
        Ok(_) => "not a regular file",
    }
}

/// TotalSegmentator's `sacrum.*` + `vertebrae_S1.*`.
fn is_ts_sacrum_pair(level: Level, files: &[PathBuf]) -> bool {
    let stems: Vec<String> = files
        .iter()
        .filter_map(|f| mesh_stem(f).map(|s| s.to_ascii_lowercase()))
        .collect();
    level == Level::S1
        && files.len() == 2
        && stems.contains(&"sacrum".to_string())
        && stems.contains(&"vertebrae_s1".to_string())
}

/// Read one level's mesh (file units times `to_metres` -> metres),
/// merging TotalSegmentator's sacrum pair; refuses empty and open meshes.
/// Also returns the number of triangles whose winding was turned to make
/// the surface consistent and outward.
pub fn read_level(files: &[PathBuf], to_metres: f64) -> Result<(TriMesh, usize)> {
    let mut parts = Vec::new();
    let mut flipped = 0;
    for f in files {
        let len = std::fs::metadata(f).map_err(|e| Error::io(f, e))?.len();
        if len > MAX_MESH_BYTES {
            return Err(Error::invalid(
                f.display().to_string(),
                format!("{len} bytes: mesh files are limited to {MAX_MESH_BYTES}"),
            ));
        }
        let m = mesh::read(f)?;
        let m = m.scaled(&nalgebra::Vector3::repeat(to_metres));
        let (m, k) = closed(m, f)?;
        flipped += k;
        parts.push(m);
    }
    let refs: Vec<&TriMesh> = parts.iter().collect();
    Ok((TriMesh::merge(&refs)?, flipped))
}

/// The mesh welded (coincident vertices of STL-like files joined) and
/// checked: triangles present, no boundary edge; its winding made
/// consistent and outward before any volume is taken (mixed windings are
/// common in exported surfaces). Also returns the triangles turned.
pub fn closed(m: TriMesh, f: &Path) -> Result<(TriMesh, usize)> {
    let what = f.display().to_string();
    if m.triangles.is_empty() || m.vertices.is_empty() {
        return Err(Error::invalid(what, "the mesh is empty (no triangles)"));
    }
    let diag = m.bounds().map(|(lo, hi)| (hi - lo).norm()).unwrap_or(0.0);
    let (w, _) = m.welded(diag * 1e-7);
    let rep = w.edge_report();
    if !rep.boundary_edges.is_empty() {
        return Err(Error::invalid(
            what,
            format!(
                "the mesh is not closed: {} boundary edge(s); a vertebra surface must be closed (export the segmentation as a closed surface)",
                rep.boundary_edges.len()
            ),
        ));
    }
    let mut w = w;
    let flipped = w.orient_consistently();
    Ok((w, flipped))
}
