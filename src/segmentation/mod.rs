//! Patient landmarks from vertebra segmentations, with no operator
//! (`osim-spine palpate`): per-level surfaces from a folder of meshes
//! ([`folder`]) or a NIfTI label map ([`nifti`], [`labels`],
//! [`surface`]), screened ([`checks`]), given rough anatomical directions
//! ([`hints`]) and palpated by the crate's palpation engine
//! ([`crate::palpation`], the same that places the base model's markers),
//! all in [`palpate_levels`]. [`palpate`] runs the whole chain and gives a
//! [`LandmarkSet`], a per-landmark report and findings; [`report`] renders
//! the CSV, JSON and SVG.
//!
//! Units and frames: meshes are read in metres in the segmentation's own
//! axes (mesh folders: `--units`, default mm; NIfTI: the header's spatial
//! units, world RAS+ by the NIfTI standard). A folder's axes are LPS, RAS
//! or OpenSim as declared by `--frame`, or detected from the anatomy
//! (anterior and cranial directions of the palpated vertebrae); a folder
//! whose anatomy fits none of them (permuted axes) is refused.

pub mod assemble;
pub mod checks;
pub mod choose;
pub mod evidence;
pub mod folder;
pub mod hints;
pub mod labelmap;
pub mod labels;
pub mod nifti;
mod pedicle_voxels;
pub mod report;
pub mod sacrum;
pub mod surface;
pub mod voxelise;

use crate::error::{Error, Result};
use crate::landmarks::{Code, Frame, LandmarkSet, Level, Units};
use crate::mesh::TriMesh;
use crate::palpation::{self, FrameHint, VertebraPalpation};
use std::path::{Path, PathBuf};

/// How serious a finding is: the landmark checker's scale (info, warning, error).
pub use crate::landmarks::check::Severity;

/// A remark on the segmentation or a landmark.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Finding {
    /// The level concerned (`None`: the segmentation as a whole).
    pub level: Option<Level>,
    /// The landmark concerned, if one.
    pub code: Option<Code>,
    /// How serious it is.
    pub severity: Severity,
    /// What was noticed, for a reader.
    pub message: String,
}

impl Finding {
    fn new(level: Option<Level>, severity: Severity, message: impl Into<String>) -> Finding {
        Finding {
            level,
            code: None,
            severity,
            message: message.into(),
        }
    }
}

/// What the segmentation is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum Kind {
    /// A folder of per-level mesh files.
    #[serde(rename = "mesh folder")]
    MeshFolder,
    /// A NIfTI-1 label map.
    #[serde(rename = "NIfTI label map")]
    LabelMap,
}

/// Options of [`palpate`].
#[derive(Debug, Clone, Default)]
pub struct Options {
    /// Mesh folders: units of the files (default mm). Label maps: units of
    /// the landmarks written (default mm).
    pub units: Option<Units>,
    /// Mesh folders: frame of the files (default: detected). Label maps:
    /// frame of the landmarks written (default RAS, the NIfTI world).
    pub frame: Option<Frame>,
    /// Levels to palpate (inclusive range, cranial first); default all.
    pub levels: Option<(Level, Level)>,
    /// Label table file for label maps (default: the built-in tables).
    pub labels: Option<PathBuf>,
    /// Show a progress bar on label maps.
    pub progress: bool,
    /// Where `SR`, `SL`, `IR`, `IL` are taken on the endplate regions.
    pub laterals: Laterals,
}

/// Where the lateral endplate landmarks (`SR`, `SL`, `IR`, `IL`) are taken.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Laterals {
    /// The middles of the lateral rims, the rule a base model's markers
    /// follow (see [`crate::palpation`]): the same point along a flat rim on
    /// a mesh, its decimation and its label map. `generate --segmentation`
    /// fits the base's markers to these, the same rule on both sides.
    #[default]
    RimMiddle,
    /// The literal furthest points of the endplate regions, as
    /// `landmarks.md` words the protocol and an operator palpating the CT
    /// places them: as far out and as high as the operator's, but anywhere
    /// along a flat rim (its anterior-posterior position follows a voxel
    /// step or a mesh vertex). What `osim-spine palpate` writes by default.
    Furthest,
}

/// One level's surface, metres, in the segmentation's axes.
#[derive(Debug, Clone)]
pub struct LevelInput {
    /// The level the surface is of.
    pub level: Level,
    /// The surface (m, the segmentation's axes).
    pub mesh: TriMesh,
    /// File or label it came from.
    pub origin: String,
    /// A label map's boundary voxels of the level (m, the segmentation's
    /// axes); `None` for a mesh.
    pub voxels: Option<surface::BoundaryVoxels>,
}

/// A segmentation read: its level surfaces and what was noticed.
#[derive(Debug, Clone)]
pub struct Loaded {
    /// Mesh folder or label map.
    pub kind: Kind,
    /// The segmentation's file or folder name.
    pub source: String,
    /// Axes of the coordinates, when known before looking at the anatomy.
    pub frame: Option<Frame>,
    /// Length units the coordinates were given in.
    pub units: Units,
    /// Label table used (label maps).
    pub label_table: Option<String>,
    /// The levels' surfaces, cranial to caudal.
    pub levels: Vec<LevelInput>,
    /// What was noticed while reading.
    pub findings: Vec<Finding>,
    /// Levels left out because the field of view cuts them (label maps).
    pub cut_by_fov: Vec<Level>,
    /// The voxel size (label maps).
    pub resolution: Option<labelmap::Resolution>,
}

/// One palpated level.
#[derive(Debug, Clone)]
pub struct LevelResult {
    /// The level palpated.
    pub level: Level,
    /// File or label the surface came from.
    pub origin: String,
    /// The surface palpated (metres, the segmentation's axes).
    pub mesh: TriMesh,
    /// The palpation engine's landmarks, centre and findings (mesh coordinates).
    pub palpation: VertebraPalpation,
    /// Distance of each landmark to the level's surface (m).
    pub distance: std::collections::BTreeMap<Code, f64>,
}

/// The outcome of [`palpate`].
#[derive(Debug, Clone)]
pub struct Palpated {
    /// Mesh folder or label map.
    pub kind: Kind,
    /// The segmentation's file or folder name.
    pub source: String,
    /// Label table used (label maps).
    pub label_table: Option<String>,
    /// The landmarks (metres, OpenSim frame); levels may have gaps.
    pub set: LandmarkSet,
    /// Axes of the segmentation (declared, the NIfTI world or detected).
    pub world: Frame,
    /// Units and frame to write the landmarks in.
    pub units: Units,
    /// Frame to write the landmarks in.
    pub frame: Frame,
    /// Every palpated level.
    pub levels: Vec<LevelResult>,
    /// What was noticed while reading and palpating.
    pub findings: Vec<Finding>,
    /// The voxel size (label maps).
    pub resolution: Option<labelmap::Resolution>,
    /// Where `SR`, `SL`, `IR`, `IL` were taken.
    pub laterals: Laterals,
}

/// Read a segmentation: a folder of meshes or a NIfTI label map.
pub fn load(path: &Path, opts: &Options) -> Result<Loaded> {
    if path.is_dir() {
        load_folder(path, opts)
    } else if is_nifti(path) {
        labelmap::load(path, opts)
    } else if !path.exists() {
        Err(Error::invalid(
            path.display().to_string(),
            "no such file or folder",
        ))
    } else {
        Err(Error::invalid(
            path.display().to_string(),
            "expected a folder of per-level meshes or a NIfTI label map (.nii, .nii.gz)",
        ))
    }
}

/// `.nii` or `.nii.gz`.
pub(crate) fn is_nifti(path: &Path) -> bool {
    nifti_stem(path).is_some()
}

/// The name of a `.nii` or `.nii.gz` file without that suffix
/// (`vertebrae_L3` of `vertebrae_L3.nii.gz`); `None` for other names.
pub fn nifti_stem(path: &Path) -> Option<String> {
    let name = path.file_name()?.to_string_lossy().to_string();
    let lower = name.to_ascii_lowercase();
    let cut = [".nii.gz", ".nii"].iter().find(|e| lower.ends_with(*e))?;
    Some(name[..name.len() - cut.len()].to_string())
}

/// The name of a path for reports (its last component: the same whatever
/// the working directory).
pub fn source_name(path: &Path) -> String {
    path.file_name()
        .map(|n| n.to_string_lossy().to_string())
        .unwrap_or_else(|| path.display().to_string())
}

/// A folder of per-level meshes.
fn load_folder(dir: &Path, opts: &Options) -> Result<Loaded> {
    let folder::LevelFiles {
        by_level: files,
        notes,
    } = folder::level_files(dir)?;
    if files.is_empty() {
        return Err(Error::invalid(
            dir.display().to_string(),
            "no mesh named by a level (T1..L5, S1/sacrum, vertebrae_L3, ...; .stl .obj .vtp .ply)",
        ));
    }
    let units = opts.units.unwrap_or(Units::Millimetre);
    let mut findings: Vec<Finding> = notes
        .into_iter()
        .map(|n| Finding::new(None, Severity::Info, n))
        .collect();
    let mut levels = Vec::new();
    for (level, paths) in files {
        let (mesh, flipped) = folder::read_level(&paths, units.to_metres())?;
        // A whole-mesh turn (an inward surface) is routine; a mixed winding
        // is worth a word.
        if flipped > 0 && flipped < mesh.triangles.len() {
            findings.push(Finding::new(
                Some(level),
                Severity::Info,
                format!(
                    "the mesh's triangle winding was mixed: {flipped} of {} triangles turned to make it consistent and outward",
                    mesh.triangles.len()
                ),
            ));
        }
        if paths.len() > 1 {
            findings.push(Finding::new(
                Some(level),
                Severity::Info,
                "sacrum.* and vertebrae_S1.* merged into the sacrum",
            ));
        }
        let origin = paths
            .iter()
            .map(|p| source_name(p))
            .collect::<Vec<_>>()
            .join("+");
        levels.push(LevelInput {
            level,
            mesh,
            origin,
            voxels: None,
        });
    }
    Ok(Loaded {
        kind: Kind::MeshFolder,
        source: source_name(dir),
        frame: opts.frame,
        units,
        label_table: None,
        levels,
        findings,
        cut_by_fov: Vec::new(),
        resolution: None,
    })
}

/// Palpate every level: the vertebrae (in parallel) with
/// [`palpation::palpate_vertebra`], the sacrum with
/// [`palpation::palpate_sacrum`] facing the palpated L5. The one place the
/// engine is called. A level whose palpation reports errors is palpated
/// once more with the vertebra frame the engine found as the hint (the
/// hints from the anatomy are rough; the engine's frame is closer), and
/// the better of the two kept.
pub(crate) fn palpate_levels(
    levels: &[LevelInput],
    hints: &[FrameHint],
) -> Vec<(Level, Result<VertebraPalpation>)> {
    use rayon::prelude::*;
    // A vertebra's second chance: its own anterior with the cranial
    // neighbour's cranial axis (L5's own axis leans towards the sacrum's
    // centroid, which lies far behind the chain).
    let neighbour = |i: usize| {
        (i > 0).then(|| FrameHint {
            anterior: hints[i].anterior,
            cranial: hints[i - 1].cranial,
        })
    };
    // The vertebrae, each on its own (in parallel, in order).
    let mut out: Vec<Option<Result<VertebraPalpation>>> = levels
        .par_iter()
        .zip(hints)
        .enumerate()
        .map(|(i, (input, hint))| {
            (!input.level.is_sacrum()).then(|| palpate_level(input, hint, neighbour(i), None))
        })
        .collect();
    // The sacrum last: its fallback uses L5's palpation.
    let l5 = levels
        .iter()
        .zip(&out)
        .find(|(i, _)| i.level == Level::L5)
        .and_then(|(_, r)| r.as_ref().and_then(|r| r.as_ref().ok()))
        .cloned();
    for ((input, hint), r) in levels.iter().zip(hints).zip(out.iter_mut()) {
        if r.is_none() {
            *r = Some(palpate_level(input, hint, None, l5.as_ref()));
        }
    }
    levels
        .iter()
        .zip(out)
        .filter_map(|(input, r)| r.map(|r| (input.level, r)))
        .collect()
}

/// One level palpated from `hint`; when the engine reports an error, once
/// more from the frame it found and then from `second` (when given), the
/// first with fewer errors and warnings kept.
fn palpate_level(
    input: &LevelInput,
    hint: &FrameHint,
    second: Option<FrameHint>,
    l5: Option<&VertebraPalpation>,
) -> Result<VertebraPalpation> {
    let run = |h: &FrameHint| {
        if input.level.is_sacrum() {
            palpation::palpate_sacrum(&input.mesh, h, l5)
        } else {
            palpation::palpate_vertebra(&input.mesh, input.level, h)
        }
    };
    let r = run(hint);
    if let Ok(p) = &r {
        // The sacrum's warnings mean its coarse fallback was taken, which
        // a better frame may avoid.
        let (errors, warnings) = counts(p);
        if errors > 0 || (input.level.is_sacrum() && warnings > 0) {
            let again = FrameHint {
                anterior: p.frame.rotation * nalgebra::Vector3::x(),
                cranial: p.frame.rotation * nalgebra::Vector3::y(),
            };
            for h in std::iter::once(again).chain(second) {
                let r2 = run(&h);
                if r2.as_ref().is_ok_and(|p2| counts(p2) < (errors, warnings)) {
                    return r2;
                }
            }
        }
    }
    r
}

/// Number of error and warning findings the engine reported.
fn counts(p: &VertebraPalpation) -> (usize, usize) {
    let n = |s: palpation::Severity| p.findings.iter().filter(|f| f.severity == s).count();
    (
        n(palpation::Severity::Error),
        n(palpation::Severity::Warning),
    )
}

/// Read, screen, palpate and assemble (see the module documentation).
pub fn palpate(path: &Path, opts: &Options) -> Result<Palpated> {
    let mut loaded = load(path, opts)?;
    // Palpated about a local origin, moved back before assembling.
    let local = local_origin(&loaded.levels);
    for l in loaded.levels.iter_mut() {
        shift_level(l, -local);
    }
    assemble::select_levels(&mut loaded, opts.levels)?;
    assemble::screen(&mut loaded);
    assemble::check_naming(&mut loaded)?;
    let pairs: Vec<(Level, &TriMesh)> = loaded.levels.iter().map(|l| (l.level, &l.mesh)).collect();
    let (hints, notes) = hints::frame_hints(&pairs, loaded.frame);
    for n in notes {
        loaded
            .findings
            .push(Finding::new(None, Severity::Warning, n));
    }
    let world = assemble::world_frame(&mut loaded, &hints)?;
    let mut results = palpate_levels(&loaded.levels, &hints);
    // A label map's pedicle bases from its voxels.
    for (level, r) in results.iter_mut() {
        let voxels = loaded.levels.iter().find(|l| l.level == *level);
        if let (Some(v), Ok(p)) = (voxels.and_then(|l| l.voxels.as_ref()), r.as_mut()) {
            pedicle_voxels::refine_pedicle_bases(p, v);
        }
    }
    // SR/SL/IR/IL at the literal furthest points when asked.
    if opts.laterals == Laterals::Furthest {
        for p in results.iter_mut().filter_map(|(_, r)| r.as_mut().ok()) {
            *p = p.with_furthest_laterals();
        }
    }
    for l in loaded.levels.iter_mut() {
        shift_level(l, local);
    }
    for p in results.iter_mut().filter_map(|(_, r)| r.as_mut().ok()) {
        shift_palpation(p, local);
    }
    assemble::assemble(loaded, world, results, opts)
}

/// The point the levels are palpated about: the centre of their bounding
/// box in whole metres. Far from the coordinates' origin (a scanner's world
/// metres or kilometres away) volumes and inside tests lose precision, and
/// the palpation of voxel surfaces breaks near-ties by the rounding; about
/// a whole-metre local origin the same anatomy gives the same local
/// coordinates wherever its world is (and a world within half a metre of
/// the origin is palpated as it is).
fn local_origin(levels: &[LevelInput]) -> nalgebra::Vector3<f64> {
    use nalgebra::Vector3;
    let mut lo = Vector3::repeat(f64::INFINITY);
    let mut hi = Vector3::repeat(f64::NEG_INFINITY);
    for v in levels.iter().flat_map(|l| &l.mesh.vertices) {
        lo = lo.inf(&v.coords);
        hi = hi.sup(&v.coords);
    }
    if lo.x > hi.x {
        return Vector3::zeros();
    }
    ((lo + hi) * 0.5).map(f64::round)
}

/// Move a level's surface and voxels by `by` (metres).
fn shift_level(l: &mut LevelInput, by: nalgebra::Vector3<f64>) {
    shift_mesh(&mut l.mesh, by);
    if let Some(v) = l.voxels.as_mut() {
        for c in v.centres.iter_mut() {
            *c += by;
        }
    }
}

/// Move a mesh by `by` (metres).
fn shift_mesh(m: &mut TriMesh, by: nalgebra::Vector3<f64>) {
    for v in m.vertices.iter_mut() {
        *v += by;
    }
}

/// Move a level's palpation (every point it holds) by `by` (metres).
fn shift_palpation(p: &mut VertebraPalpation, by: nalgebra::Vector3<f64>) {
    p.frame.translation.vector += by;
    for lm in p.landmarks.values_mut() {
        lm.point += by;
    }
    p.centre += by;
    for q in p.furthest.values_mut() {
        *q += by;
    }
}
