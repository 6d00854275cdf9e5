//! `osim-spine generate [--base DIR] --landmarks FILE --out MODEL.osim`:
//! a patient-specific scoliotic model from a landmark set (see
//! [`crate::generate`]). The landmark file is checked first
//! ([`crate::landmarks::check`]): any error finding refuses the file.
//! Everything is computed in memory; then `MODEL.osim`, its meshes in
//! `Geometry/` beside it, `<stem>_report.json` and the SVG views
//! `<stem>_frontal.svg` / `<stem>_sagittal.svg` are written, each
//! atomically. Nothing is written on error.

pub use crate::embedded::base_file;
use crate::embedded::BaseModel;
use crate::error::Error;
use crate::generate::{
    generate_with_geometry, GenerateOptions, GenerateReport, Generated, GeometryChoice, Method,
    PatientGeometry,
};
use crate::landmarks::check::{check_raw, Severity};
use crate::landmarks::LandmarkSet;
use crate::osim::geometry::check_relative;
use crate::osim::model::Geometry;
use crate::osim::Document;
use crate::util::messages::joined;
use std::path::{Path, PathBuf};

pub use crate::landmarks::check::GENERATE_BLOCKING as BLOCKING;

/// Arguments of `generate`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Base model: a folder holding one .osim (and its meshes), or an .osim
    /// file (default: the base model compiled into the binary).
    #[arg(long, value_name = "DIR")]
    pub base: Option<PathBuf>,
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
    /// Segmentation options (clap ignores this comment on a flattened field).
    pub seg: super::palpate::SegArgs,
    /// Vertebra meshes the model wears: base (the base model's, scaled by
    /// each vertebra's landmarks) or patient (the segmentation's own, with
    /// --segmentation: wrap spheres, joints, markers and mass from the
    /// patient's bones; written to Geometry/ as `<stem>_<LEVEL>.vtp`).
    /// Default: patient with --segmentation, base with --landmarks.
    #[arg(long, value_enum, ignore_case = true)]
    pub geometry: Option<GeometryChoice>,
    /// Output model (.osim); meshes go to Geometry/ beside it.
    #[arg(long, value_name = "MODEL.osim")]
    pub out: PathBuf,
    /// Vertebra pose fit: lsq (all 14 landmarks, one-outlier rejection) or
    /// thesis (ISB frames from the 6 joint landmarks).
    #[arg(long, value_enum, ignore_case = true, default_value_t = Method::Lsq)]
    pub method: Method,
    /// How the per-vertebra fits are combined along the spine (lsq only):
    /// chain (neighbours meet at their joints, disc mismatch estimated from
    /// the data; unbiased), curvature (smoothness prior on the
    /// orientations; flattens sharp curves; `auto` is an alias) or off
    /// (independent fits).
    #[arg(long, value_enum, ignore_case = true, default_value_t = crate::generate::Smooth::Chain)]
    pub smooth: crate::generate::Smooth,
    /// Levels above the landmarks' field of view: balance (the least
    /// compensatory frontal curve that levels T1 within 20 mm of the
    /// vertical through S1_SEC) or keep (the base model's joint angles
    /// above the top measured vertebra).
    #[arg(long, value_enum, ignore_case = true, default_value_t = crate::generate::AboveFov::Balance)]
    pub above_fov: crate::generate::AboveFov,
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
    let mut protected = crate::util::guard::Protected::default();
    for input in args.landmarks.iter().chain(&args.segmentation) {
        protected = protected.file(input);
    }
    // an embedded base has no folder to protect
    if let Some(arg) = &args.base {
        let base = base_file(arg)?;
        let folder = match base.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        protected = protected.file(&base).folder(&folder);
    }
    crate::util::guard::check_outputs(&[&args.out], &protected, args.force)
}

/// The meshes the model wears: as asked, else the patient's own when a
/// segmentation gives them (they measure closer to the patient's bone and
/// centres than the scaled base meshes), else the base's.
fn geometry_choice(args: &Args) -> GeometryChoice {
    match (args.geometry, &args.segmentation) {
        (Some(g), _) => g,
        (None, Some(_)) => GeometryChoice::Patient,
        (None, None) => GeometryChoice::Base,
    }
}

/// Run `generate`; returns the exit code.
pub fn run(args: Args) -> anyhow::Result<i32> {
    if args.out.extension().map(|e| e != "osim").unwrap_or(true) {
        return Err(Error::invalid("--out", "the output model must be a .osim file").into());
    }
    if args.geometry == Some(GeometryChoice::Patient) && args.segmentation.is_none() {
        return Err(Error::invalid(
            "--geometry",
            "`--geometry patient` takes the patient's meshes from a segmentation: give --segmentation instead of --landmarks",
        )
        .into());
    }
    refuse_overwriting_inputs(&args)?;
    let base_model = BaseModel::locate(args.base.as_deref())?;
    let base = base_model.read()?;
    // Landmarks (read, or palpated on the segmentation), checked.
    let (set, landmarks_name, palpated, segmentation) =
        checked_landmarks(&args, &base, &base_model)?;
    // The patient's meshes (`--geometry patient`), named after the model.
    let stem = args
        .out
        .file_stem()
        .map(|s| patient_model_name(&s.to_string_lossy()))
        .unwrap_or_else(|| "patient".into());
    let patient_geometry = match (&segmentation, geometry_choice(&args)) {
        (Some(p), GeometryChoice::Patient) => Some(PatientGeometry::from_palpated(p, &stem)),
        _ => None,
    };
    // The model, generated in memory.
    let opts = GenerateOptions {
        method: args.method,
        smooth: args.smooth,
        self_check: !args.no_self_check,
        views: true,
        above_fov: args.above_fov,
        ..GenerateOptions::default()
    };
    let mut g = generate_with_geometry(
        &base,
        &set,
        &landmarks_name,
        &opts,
        Some(&base_model),
        patient_geometry.as_ref(),
    )?;
    // The model is named after the patient's landmark file (or segmentation).
    let patient = args
        .landmarks
        .as_ref()
        .or(args.segmentation.as_ref())
        .and_then(|p| p.file_stem())
        .map(|s| s.to_string_lossy().to_string())
        .unwrap_or_else(|| "patient".into());
    g.doc
        .model_element_mut()
        .set_attr("name", patient_model_name(&patient));
    // Everything computed: gather the bytes, then write.
    let (written, dir) = write_outputs(&args, &base_model, &g, palpated)?;
    print_summary(&g.report, &args.out);
    crate::outln!("wrote {written} files to {}", dir.display());
    Ok(0)
}

/// The landmark set (read, or palpated on the segmentation, with the
/// palpation's files to write), refused on a blocking check finding;
/// the other findings are printed as warnings.
#[allow(clippy::type_complexity)]
fn checked_landmarks(
    args: &Args,
    base: &Document,
    base_model: &BaseModel,
) -> anyhow::Result<(
    LandmarkSet,
    String,
    Vec<(PathBuf, Vec<u8>)>,
    Option<crate::segmentation::Palpated>,
)> {
    let (raw, landmarks_name, palpated, segmentation) = landmark_source(args, base, base_model)?;
    let rep = check_raw(&raw);
    // Missing landmarks (LM020) are not blocking here: the level is fitted
    // on those present (a reduced fit, reported) when enough remain.
    let blocking = |f: &crate::landmarks::check::Finding| {
        f.severity == Severity::Error && f.code != "LM020" && BLOCKING.contains(&f.code.as_str())
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
        crate::errln!("warning: {} {}", f.code, f.message);
    }
    let set = raw.to_set()?;
    for n in &raw.notes {
        crate::outln!("landmarks: {n}");
    }
    if let Some(d) = &set.detection {
        crate::outln!("landmarks: {}", d.summary());
    }
    Ok((set, landmarks_name, palpated, segmentation))
}

/// Write the model (with its meshes), the palpation's files, the report
/// and the views, each atomically; returns how many files and their folder.
fn write_outputs(
    args: &Args,
    base_model: &BaseModel,
    g: &Generated,
    mut palpated: Vec<(PathBuf, Vec<u8>)>,
) -> anyhow::Result<(usize, PathBuf)> {
    let dir = match args.out.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let stem = args
        .out
        .file_stem()
        .map(|s| s.to_string_lossy().to_string())
        .unwrap_or_else(|| "model".into());
    let mut files = model_files(base_model, g, &args.out)?;
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
    crate::util::write_all_or_nothing(&files)?;
    Ok((files.len(), dir))
}

/// The console summary of a generated model: what was fitted, outliers,
/// reduced fits, protocol mismatches, smoothing, levels above the field of
/// view, shape and self-check.
fn print_summary(r: &GenerateReport, out: &Path) {
    crate::outln!(
        "generated {} ({} method): {} vertebrae from landmarks ({}), {} filled from their neighbours{}, {} kept from the base model",
        out.display(),
        r.method,
        r.levels_from_landmarks.len(),
        joined(&r.levels_from_landmarks, " "),
        r.filled_levels.len(),
        if r.filled_levels.is_empty() {
            String::new()
        } else {
            format!(
                " ({})",
                r.filled_levels
                    .iter()
                    .map(|l| l.to_string())
                    .collect::<Vec<_>>()
                    .join(" ")
            )
        },
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
    print_fit_warnings(r);
    if let Some(g) = &r.geometry {
        print_geometry(g);
    }
    crate::outln!("orientation smoothing: {}", r.smoothing.note);
    print_above_fov(r.above_fov.as_ref(), r.levels_from_landmarks.is_empty());
    print_shape(&r.shape);
    match &r.self_check {
        Some(sc) => super::print_self_check(sc),
        None => crate::outln!("self-check: skipped (--no-self-check)"),
    }
}

/// Which vertebrae wear the patient's meshes, which keep the base's, and
/// the attachments moved out of the patient's bones.
fn print_geometry(g: &crate::generate::geometry::GeometryReport) {
    let most = g.meshes.iter().map(|m| m.triangles).max().unwrap_or(0);
    crate::outln!(
        "geometry: the patient's own meshes ({}) on {} levels: {} (at most {most} triangles each); wrap spheres at the patient's vertebral centres; {} joints at the patient's disc centres; {}",
        g.segmentation,
        g.patient_levels.len(),
        joined(&g.patient_levels, " "),
        g.joints_at_patient_discs.len(),
        g.mass_rule
    );
    if !g.base_levels.is_empty() {
        crate::outln!(
            "geometry: scaled base meshes kept for {}",
            g.base_levels.join("; ")
        );
    }
    if !g.moved_attachments.is_empty() {
        let deepest = g
            .moved_attachments
            .iter()
            .fold(0.0f64, |m, p| m.max(p.depth_mm));
        let shown: Vec<String> = g
            .moved_attachments
            .iter()
            .take(5)
            .map(|p| {
                format!(
                    "{} {} out of {} ({:.1} mm)",
                    p.muscle, p.point, p.bone, p.depth_mm
                )
            })
            .collect();
        crate::errln!(
            "warning: {} muscle attachment(s) were inside the patient's bone (up to {deepest:.1} mm) and moved out along its surface normal: {}{}",
            g.moved_attachments.len(),
            shown.join(", "),
            if g.moved_attachments.len() > 5 { ", ... (all in the report)" } else { "" }
        );
    }
}

/// Warnings of the fits: reduced fits (and borrowed scale factors) and
/// protocol mismatches (and their compensation).
fn print_fit_warnings(r: &GenerateReport) {
    for f in &r.filled {
        crate::errln!(
            "warning: {} has no landmarks (a gap in the set): placed between {} and {} from its neighbours (pose interpolated along the chain, scale factors {:.3} / {:.3} / {:.3} from theirs)",
            f.level,
            f.between[0],
            f.between[1],
            f.scale[0],
            f.scale[1],
            f.scale[2]
        );
    }
    for f in &r.reduced_fits {
        let borrowed = if f.borrowed_scale.is_empty() {
            String::new()
        } else {
            format!(
                "; scaled by its neighbours' factors where it cannot be measured: {}",
                f.borrowed_scale.join("; ")
            )
        };
        crate::errln!(
            "warning: {} fitted on {} of {} landmarks (missing {}): a reduced fit, its pose is less certain{borrowed}",
            f.level,
            f.used,
            f.used + f.missing.len(),
            f.missing.join(", "),
        );
    }
    for m in &r.protocol_mismatches {
        let compensated = if m.compensated {
            format!(
                "; compensated: the vertebrae were refitted with every {} marker moved by that offset",
                m.code
            )
        } else {
            String::new()
        };
        crate::errln!("warning: protocol mismatch: {m}{compensated}");
    }
}

/// The generated spine's shape (Cobb angle, apex, lordosis, kyphosis).
fn print_shape(s: &crate::landmarks::metrics::Shape) {
    let deg = |v: Option<f64>| {
        v.map(|d| format!("{d:+.1} deg"))
            .unwrap_or_else(|| "n/a".into())
    };
    let cobb = s
        .cobb
        .as_ref()
        .map(|c| format!("{:+.1} deg ({}-{})", c.angle_deg, c.upper, c.lower))
        .unwrap_or_else(|| "n/a".into());
    crate::outln!(
        "shape: Cobb {cobb} (+ convex right), apex {}, lumbar lordosis L1-S1 {}, kyphosis T4-T12 {}, sacral slope {}",
        s.apex.map_or("n/a".into(), |l| l.to_string()),
        deg(s.lumbar_lordosis_deg),
        deg(s.kyphosis_t4_t12_deg),
        deg(s.sacral_slope_deg)
    );
}

/// A model name from a file stem: letters, digits, `_` and `-` kept,
/// others `_` (OpenSim object names allow no spaces or slashes).
fn patient_model_name(stem: &str) -> String {
    stem.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' {
                c
            } else {
                '_'
            }
        })
        .collect()
}

/// Levels above the field of view: which were not measured, what was
/// done, where T1 ended.
fn print_above_fov(a: Option<&crate::generate::AboveFovReport>, no_vertebra: bool) {
    let Some(a) = a else {
        if no_vertebra {
            crate::outln!("above the field of view: every vertebra (no vertebra was measured; all kept as in the base model)");
        } else {
            crate::outln!("above the field of view: none (the landmarks reach T1)");
        }
        return;
    };
    let done = if a.balanced.is_empty() {
        "kept at the base model's joint angles (--above-fov keep)".to_string()
    } else {
        let max = a.bend_deg.iter().fold(0.0f64, |m, b| m.max(b.abs()));
        format!(
            "balanced {} by a compensatory frontal curve (largest bend {max:.1} deg per joint{})",
            joined(&a.balanced, " "),
            if a.bend_limited {
                format!(
                    ", the limit of {:.0} deg: too few unmeasured levels to bring T1 over the sacrum",
                    crate::generate::balance::MAX_BEND_DEG
                )
            } else {
                String::new()
            }
        )
    };
    crate::outln!(
        "above the field of view: {} not measured; {done}; T1 ends {:.1} mm {} of the vertical through S1_SEC, {:.1} mm anterior, coronal tilt {:.1} deg",
        joined(&a.unmeasured, " "),
        a.t1_lateral_offset_mm.abs(),
        if a.t1_lateral_offset_mm >= 0.0 { "right" } else { "left" },
        a.t1_anterior_offset_mm,
        a.t1_coronal_tilt_deg
    );
}

/// The raw landmarks, their name for messages and reports, the files of
/// a palpation to write beside the model and the palpation itself
/// (`--segmentation`: the patient's sacrum registered to the base's by its
/// surface, the base's S1 markers carried onto it).
#[allow(clippy::type_complexity)]
fn landmark_source(
    args: &Args,
    base: &Document,
    base_model: &BaseModel,
) -> anyhow::Result<(
    crate::landmarks::RawLandmarks,
    String,
    Vec<(PathBuf, Vec<u8>)>,
    Option<crate::segmentation::Palpated>,
)> {
    if let Some(path) = &args.landmarks {
        return Ok((
            crate::landmarks::read_path(path)?,
            path.display().to_string(),
            vec![],
            None,
        ));
    }
    let seg = args
        .segmentation
        .as_ref()
        .ok_or_else(|| Error::invalid("generate", "give --landmarks or --segmentation"))?;
    let mut p = crate::segmentation::palpate(seg, &args.seg.options()?)?;
    if let Some((mesh, s1)) = crate::generate::base_sacrum(base, base_model)? {
        crate::segmentation::sacrum::carry_base_markers(&mut p, &mesh, &s1);
    }
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
        Some(p),
    ))
}

/// The bytes of a generated model written to `out` (.osim): the model,
/// then each mesh it references (the generator's own, e.g. the patient's,
/// as ASCII VTP; else taken from the base model) under `Geometry/` beside
/// `out`.
pub fn model_files(
    base: &BaseModel,
    g: &Generated,
    out: &Path,
) -> crate::Result<Vec<(PathBuf, Vec<u8>)>> {
    let doc = &g.doc;
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
            let label = base.label().display().to_string();
            let rel = check_relative(mesh_file)
                .map_err(|why| Error::invalid(&label, format!("mesh_file '{mesh_file}' {why}")))?;
            if let Some(m) = g.meshes.get(mesh_file) {
                files.push((
                    dir.join("Geometry").join(rel),
                    crate::mesh::vtp::to_ascii(m).into_bytes(),
                ));
                continue;
            }
            let bytes = base.mesh_bytes(mesh_file)?.ok_or_else(|| {
                Error::invalid(
                    &label,
                    format!(
                        "mesh file '{mesh_file}' of body {} not found beside the base model",
                        b.name
                    ),
                )
            })?;
            files.push((dir.join("Geometry").join(rel), bytes));
        }
    }
    Ok(files)
}
