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
    #[arg(
        long,
        value_name = "FILE",
        required_unless_present = "segmentation",
        conflicts_with = "segmentation"
    )]
    pub landmarks: Option<PathBuf>,
    /// Palpate these vertebra segmentations first (see `osim-spine palpate`):
    /// the landmarks are written beside the model as `<stem>_landmarks.csv`.
    #[arg(long, value_name = "SEGMENTATION")]
    pub segmentation: Option<PathBuf>,
    #[command(flatten)]
    pub seg: super::palpate::SegArgs,
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
    // Landmarks (read, or palpated on the segmentation): check, then load strictly.
    let (raw, landmarks_name, mut palpated) = landmark_source(&args)?;
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
            landmarks_name.clone(),
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
        eprintln!("warning: {} {}", f.code, f.message);
    }
    let set = raw.to_set()?;
    for n in &raw.notes {
        println!("landmarks: {n}");
    }
    if let Some(d) = &set.detection {
        println!("landmarks: {}", d.summary());
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
    let g = generate(&base, &set, &landmarks_name, &opts, Some(&source))?;
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
    files.append(&mut palpated);
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
    println!(
        "generated {} ({} method): {} vertebrae from landmarks ({}), {} kept from the base model",
        args.out.display(),
        r.method,
        r.levels_from_landmarks.len(),
        r.levels_from_landmarks.join(" "),
        r.levels_from_base.len()
    );
    println!(
        "sacral registration: {} landmarks, RMS {:.2} mm; landmark-to-model RMS {:.2} mm",
        r.registration.landmarks.len(),
        r.registration.rms_mm,
        r.landmark_rms_mm
    );
    if r.outliers.is_empty() {
        println!("outlier landmarks: none");
    } else {
        println!("outlier landmarks (rejected): {}", r.outliers.join(", "));
    }
    println!("orientation smoothing: {}", r.smoothing.note);
    if let Some(sc) = &r.self_check {
        println!(
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
    println!("wrote {} files to {}", files.len(), dir.display());
    Ok(0)
}

/// The raw landmarks, their name for messages and reports, and the files
/// of a palpation to write beside the model (`--segmentation`).
#[allow(clippy::type_complexity)]
fn landmark_source(
    args: &Args,
) -> anyhow::Result<(
    crate::landmarks::RawLandmarks,
    String,
    Vec<(PathBuf, Vec<u8>)>,
)> {
    if let Some(path) = &args.landmarks {
        return Ok((
            crate::landmarks::read_path(path)?,
            path.display().to_string(),
            vec![],
        ));
    }
    let seg = args
        .segmentation
        .as_ref()
        .ok_or_else(|| Error::invalid("generate", "give --landmarks or --segmentation"))?;
    let p = crate::segmentation::palpate(seg, &args.seg.options()?)?;
    super::palpate::print_summary(&p);
    let stem = args
        .out
        .file_stem()
        .map(|s| s.to_string_lossy().to_string())
        .unwrap_or_else(|| "model".into());
    let csv_path = args.out.with_file_name(format!("{stem}_landmarks.csv"));
    let files = super::palpate::output_files(&p, &csv_path);
    let text = String::from_utf8_lossy(&files[0].1).to_string();
    let raw = crate::landmarks::io::parse_csv(&text, &csv_path)?
        .into_iter()
        .next()
        .ok_or_else(|| Error::invalid(seg.display().to_string(), "no landmark palpated"))?
        .raw;
    Ok((
        raw,
        format!("{} (palpated)", crate::segmentation::source_name(seg)),
        files,
    ))
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
                    let bytes = std::fs::read(&p).map_err(|e| Error::io(&p, e))?;
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
