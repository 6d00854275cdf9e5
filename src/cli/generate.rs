//! `osim-spine generate [--base DIR] --landmarks FILE --out MODEL.osim`:
//! a patient-specific scoliotic model from a landmark set (see
//! [`crate::build::generate`]). The landmark file is checked first
//! ([`crate::landmarks::check`]): any error finding refuses the file.
//! Everything is computed in memory; then `MODEL.osim`, its meshes in
//! `Geometry/` beside it, `<stem>_report.json` and the SVG views
//! `<stem>_frontal.svg` / `<stem>_sagittal.svg` are written, each
//! atomically. Nothing is written on error.

use crate::build::base::DirMeshSource;
use crate::build::generate::{generate, GenerateOptions, Method};
use crate::error::Error;
use crate::landmarks::check::{check_raw, Severity};
use crate::osim::geometry::{check_relative, resolve, MeshLookup};
use crate::osim::model::Geometry;
use crate::osim::Document;
use std::path::{Path, PathBuf};

pub use crate::landmarks::check::GENERATE_BLOCKING as BLOCKING;

/// Arguments of `generate`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Base model: a folder holding one .osim (and its meshes), or an .osim file.
    #[arg(long, value_name = "DIR", default_value = "base_model")]
    pub base: PathBuf,
    /// Patient landmark set (.csv, .trc, .json; see ../shared/formats/landmarks.md).
    #[arg(long, value_name = "FILE")]
    pub landmarks: PathBuf,
    /// Output model (.osim); meshes go to Geometry/ beside it.
    #[arg(long, value_name = "MODEL.osim")]
    pub out: PathBuf,
    /// Vertebra pose fit: lsq (all 14 landmarks, one-outlier rejection) or
    /// thesis (ISB frames from the 6 joint landmarks).
    #[arg(long, default_value = "lsq")]
    pub method: String,
    /// How the per-vertebra fits are combined along the spine (lsq only):
    /// chain (neighbours meet at their joints, disc mismatch estimated from
    /// the data; unbiased), curvature (smoothness prior on the
    /// orientations; flattens sharp curves; `auto` is an alias) or off
    /// (independent fits).
    #[arg(long, default_value = "chain")]
    pub smooth: String,
    /// Skip the self-check (bushings, muscles through bone, equilibrium).
    #[arg(long)]
    pub no_self_check: bool,
    /// Allow --out to overwrite an input or to go into the base model's folder.
    #[arg(long)]
    pub force: bool,
}

/// `--out` may not be an input (after symlinks) nor go into the base
/// model's folder (its Geometry/ would be overwritten), unless `--force`.
fn refuse_overwriting_inputs(args: &Args) -> crate::Result<()> {
    let base = base_file(&args.base)?;
    let folder = match base.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let protected = crate::util::guard::Protected::default()
        .file(&base)
        .file(&args.landmarks)
        .folder(&folder);
    crate::util::guard::check_outputs(&[&args.out], &protected, args.force)
}

/// The base model file of `--base`.
pub fn base_file(base: &Path) -> crate::Result<PathBuf> {
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
        _ => {
            let pick = base.join("base.osim");
            if pick.is_file() {
                Ok(pick)
            } else {
                Err(Error::invalid(
                    base.display().to_string(),
                    format!(
                        "{} .osim files and no base.osim: give the file",
                        osims.len()
                    ),
                ))
            }
        }
    }
}

/// Run `generate`; returns the exit code.
pub fn run(args: Args) -> anyhow::Result<i32> {
    let method: Method = args.method.parse()?;
    let smooth: crate::build::generate::Smooth = args.smooth.parse()?;
    if args.out.extension().map(|e| e != "osim").unwrap_or(true) {
        return Err(Error::invalid("--out", "the output model must be a .osim file").into());
    }
    refuse_overwriting_inputs(&args)?;
    // Landmarks: check, then load strictly.
    let raw = crate::landmarks::read_path(&args.landmarks)?;
    let rep = check_raw(&raw);
    let blocking = |f: &crate::landmarks::check::Finding| {
        f.severity == Severity::Error && BLOCKING.contains(&f.code.as_str())
    };
    let errors: Vec<String> = rep
        .findings
        .iter()
        .filter(|f| blocking(f))
        .map(|f| {
            let at = f.line.map(|l| format!(" (line {l})")).unwrap_or_default();
            format!("{} {}{at}", f.code, f.message)
        })
        .collect();
    if !errors.is_empty() {
        return Err(Error::invalid(
            args.landmarks.display().to_string(),
            format!(
                "the landmark set fails its checks (see `osim-spine check`):\n  {}",
                errors.join("\n  ")
            ),
        )
        .into());
    }
    for f in rep
        .findings
        .iter()
        .filter(|f| f.severity != Severity::Info && !blocking(f))
    {
        crate::errln!("warning: {} {}", f.code, f.message);
    }
    let set = raw.to_set()?;
    for n in &raw.notes {
        crate::outln!("landmarks: {n}");
    }
    if let Some(d) = &set.detection {
        crate::outln!("landmarks: {}", d.summary());
    }
    let base_path = base_file(&args.base)?;
    let base = Document::read(&base_path)?;
    let source = DirMeshSource {
        model_path: base_path.clone(),
        extra: vec![],
    };
    let opts = GenerateOptions {
        method,
        smooth,
        self_check: !args.no_self_check,
        views: true,
        ..GenerateOptions::default()
    };
    let g = generate(
        &base,
        &set,
        &args.landmarks.display().to_string(),
        &opts,
        Some(&source),
    )?;
    // Everything computed: gather the bytes, then write.
    let dir = match args.out.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let stem = args
        .out
        .file_stem()
        .map(|s| s.to_string_lossy().to_string())
        .unwrap_or_else(|| "model".into());
    let mut files = model_files(&base_path, &g.doc, &args.out)?;
    files.push((
        dir.join(format!("{stem}_report.json")),
        serde_json::to_string_pretty(&g.report)?.into_bytes(),
    ));
    for (suffix, svg) in &g.views {
        files.push((
            dir.join(format!("{stem}_{suffix}.svg")),
            svg.clone().into_bytes(),
        ));
    }
    for (p, bytes) in &files {
        crate::util::write_atomic(p, bytes)?;
    }
    let r = &g.report;
    crate::outln!(
        "generated {} ({} method): {} vertebrae from landmarks ({}), {} kept from the base model",
        args.out.display(),
        r.method,
        r.levels_from_landmarks.len(),
        r.levels_from_landmarks.join(" "),
        r.levels_from_base.len()
    );
    crate::outln!(
        "sacral registration: {} landmarks, RMS {:.2} mm; landmark-to-model RMS {:.2} mm",
        r.registration.landmarks.len(),
        r.registration.rms_mm,
        r.landmark_rms_mm
    );
    if r.outliers.is_empty() {
        crate::outln!("outlier landmarks: none");
    } else {
        crate::outln!("outlier landmarks (rejected): {}", r.outliers.join(", "));
    }
    crate::outln!("orientation smoothing: {}", r.smoothing.note);
    if let Some(sc) = &r.self_check {
        crate::outln!(
            "self-check: bushing deflection at default {:.1e} rad / {:.1e} m; {} muscle segments through vertebrae; equilibrium under gravity (muscles off): largest displacement {:.1} mm ({}){}",
            sc.bushing_max_rotation,
            sc.bushing_max_translation,
            sc.muscle_segments_through_vertebrae.len(),
            sc.equilibrium.max_displacement * 1e3,
            sc.equilibrium.max_displacement_body,
            match sc.equilibrium.stable {
                Some(true) => ", stable",
                Some(false) => ", unstable (a ligamentous spine without muscles buckles under body weight)",
                None => "",
            }
        );
    }
    crate::outln!("wrote {} files to {}", files.len(), dir.display());
    Ok(0)
}

/// The bytes of a generated model written to `out` (.osim): the model,
/// then each mesh it references (read beside the base model at
/// `base_path`) under `Geometry/` beside `out`.
pub fn model_files(
    base_path: &Path,
    doc: &Document,
    out: &Path,
) -> crate::Result<Vec<(PathBuf, Vec<u8>)>> {
    let dir = match out.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let mut files: Vec<(PathBuf, Vec<u8>)> =
        vec![(out.to_path_buf(), doc.to_xml_string().into_bytes())];
    let model = doc.model()?;
    let mut seen = std::collections::BTreeSet::new();
    for b in &model.bodies {
        for geo in &b.geometry {
            let Geometry::Mesh { mesh_file, .. } = geo else {
                continue;
            };
            if mesh_file.is_empty() || !seen.insert(mesh_file.clone()) {
                continue;
            }
            let rel = check_relative(mesh_file).map_err(|why| {
                Error::invalid(
                    base_path.display().to_string(),
                    format!("mesh_file '{mesh_file}' {why}"),
                )
            })?;
            match resolve(base_path, mesh_file, &[]) {
                MeshLookup::Found(p) => {
                    let bytes = crate::mesh::read_file_bytes(&p)?;
                    files.push((dir.join("Geometry").join(rel), bytes));
                }
                MeshLookup::Missing => {
                    return Err(Error::invalid(
                        base_path.display().to_string(),
                        format!(
                            "mesh file '{mesh_file}' of body {} not found beside the base model",
                            b.name
                        ),
                    ))
                }
                MeshLookup::Escapes(why) => {
                    return Err(Error::invalid(base_path.display().to_string(), why))
                }
            }
        }
    }
    Ok(files)
}
