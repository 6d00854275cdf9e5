//! `osim-spine base`: build the base model from a generic model (see
//! [`crate::base`]). Everything is computed in memory first; then
//! `OUT/base.osim`, its meshes, `OUT/base_report.json` and the SVG views
//! are written, each atomically. Nothing is written on error.
//!
//! `--procedural [--stature M] [--sex female|male]` replaces the generic
//! model by the procedural spine of [`crate::procedural`] (also
//! writing `OUT/procedural_report.json`); `base_model/` in the repository
//! is `osim-spine base --procedural --out base_model`.

use crate::base::{build_base, BaseOptions, DirMeshSource, FixedBody, IvdParams};
use crate::error::Error;
use crate::landmarks::Level;
use crate::osim::Document;
use crate::procedural::{generate_generic, ProceduralOptions, Sex};
use clap::Args as ClapArgs;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Arguments of `base`.
#[derive(Debug, ClapArgs)]
pub struct Args {
    /// The generic model (.osim) with an articulated thoracolumbar spine.
    #[arg(
        long,
        value_name = "MODEL.osim",
        required_unless_present = "procedural",
        conflicts_with = "procedural"
    )]
    pub generic: Option<PathBuf>,
    /// Use the procedural generic spine built from published anatomy
    /// (templates/) instead of a generic model file; nothing to download.
    #[arg(long)]
    pub procedural: bool,
    /// Stature of the procedural spine in metres (default: 1.75 male,
    /// 1.62 female).
    #[arg(long, value_name = "M", requires = "procedural")]
    pub stature: Option<f64>,
    /// Sex of the procedural spine (default stature, pelvis width, trunk
    /// mass fractions).
    #[arg(long, value_enum, default_value = "male", requires = "procedural")]
    pub sex: SexArg,
    /// Folder(s) to search for the model's mesh files (after the model's
    /// own folder and its Geometry/).
    #[arg(long, value_name = "DIR")]
    pub geometry: Vec<PathBuf>,
    /// Mean sacrum mesh to register onto the generic sacrum and swap in.
    #[arg(long, value_name = "MESH")]
    pub sacrum: Option<PathBuf>,
    /// Allow a uniform scale in the sacrum registration (similarity).
    #[arg(long)]
    pub allow_scale: bool,
    /// Kept vertebrae, `TOP..L5` (default T1..L5).
    #[arg(long, value_name = "T1..L5", default_value = "T1..L5")]
    pub keep: String,
    /// Body welded to ground.
    #[arg(long, value_enum, default_value = "pelvis")]
    pub fixed: Fixed,
    /// Folder with body-only meshes `<LEVEL>_body.{obj,vtp,stl,ply}` for
    /// the sphere fits (e.g. ../shared/data/vertebra-meshes).
    #[arg(long, value_name = "DIR")]
    pub body_meshes: Option<PathBuf>,
    /// IVD parameter template (default: the embedded templates/ivd_defaults.toml).
    #[arg(long, value_name = "TOML")]
    pub ivd: Option<PathBuf>,
    /// Write the model even when a landmark or sphere guard fails (the
    /// failures are printed as warnings).
    #[arg(long)]
    pub allow_implausible: bool,
    /// Your own palpation of the generic model (landmark format: names
    /// `<LEVEL>_<CODE>`, `# units:`, and `# frame:` for coordinates in its
    /// ground at the default pose, or a `body` column `name,body,x,y,z` for
    /// coordinates in that body's frame): replaces the engine's markers for
    /// the landmarks it names.
    #[arg(long, value_name = "FILE")]
    pub palpation: Option<PathBuf>,
    /// Your own vertebral centres of the generic model (names
    /// `<LEVEL>_centre`, same format as --palpation): replace the engine's
    /// vertebral-body sphere centres for the levels named.
    #[arg(long, value_name = "FILE")]
    pub centres: Option<PathBuf>,
    /// Output folder.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Allow the output to go where an input is (it may be replaced).
    #[arg(long)]
    pub force: bool,
}

/// `--fixed` values.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
#[allow(missing_docs)] // clap prints variant doc comments in --help; the names say it
pub enum Fixed {
    Pelvis,
    Sacrum,
}

/// `--sex` values.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
#[allow(missing_docs)] // clap prints variant doc comments in --help; the names say it
pub enum SexArg {
    Female,
    Male,
}

/// Parse `--keep TOP..L5`.
pub fn parse_keep(s: &str) -> crate::Result<Level> {
    let bad = || {
        Error::invalid(
            "--keep",
            format!("'{s}' is not a level range TOP..L5 (e.g. T1..L5, T6..L5)"),
        )
    };
    let (a, b) = s.split_once("..").ok_or_else(bad)?;
    let top: Level = a.parse().map_err(|_| bad())?;
    let bottom: Level = b.parse().map_err(|_| bad())?;
    if bottom != Level::L5 {
        return Err(Error::invalid(
            "--keep",
            format!("the kept run must end at L5 (the sacrum and pelvis are kept), got '{s}'"),
        ));
    }
    if top > Level::L5 {
        return Err(bad());
    }
    Ok(top)
}

fn body_meshes(
    dir: &Path,
    top: Level,
) -> crate::Result<BTreeMap<Level, (String, crate::mesh::TriMesh)>> {
    if !dir.is_dir() {
        return Err(Error::invalid(
            "--body-meshes",
            format!("{} is not a folder", dir.display()),
        ));
    }
    let mut out = BTreeMap::new();
    for l in &Level::ALL[top.index()..=Level::L5.index()] {
        for ext in ["obj", "vtp", "stl", "ply"] {
            let p = dir.join(format!("{l}_body.{ext}"));
            if p.is_file() {
                out.insert(*l, (p.display().to_string(), crate::mesh::read(&p)?));
                break;
            }
        }
    }
    Ok(out)
}

/// Run `base`; returns the exit code.
pub fn run(args: Args) -> anyhow::Result<i32> {
    // Never write into a folder that holds an input.
    let protected = crate::util::guard::Protected::default().inputs(
        args.generic
            .iter()
            .chain(&args.geometry)
            .chain(&args.sacrum)
            .chain(&args.body_meshes)
            .chain(&args.ivd)
            .chain(&args.palpation)
            .chain(&args.centres),
    );
    crate::util::guard::check_output_dir(&args.out, &protected, args.force)?;
    let top = parse_keep(&args.keep)?;
    let mut opts = BaseOptions {
        top,
        fixed: match args.fixed {
            Fixed::Pelvis => FixedBody::Pelvis,
            Fixed::Sacrum => FixedBody::Sacrum,
        },
        allow_scale: args.allow_scale,
        allow_implausible: args.allow_implausible,
        ..BaseOptions::default()
    };
    if let Some(p) = &args.ivd {
        opts.ivd = IvdParams::read(p)?;
    }
    if let Some(p) = &args.sacrum {
        opts.sacrum = Some((p.display().to_string(), crate::mesh::read(p)?));
    }
    if let Some(d) = &args.body_meshes {
        opts.body_meshes = body_meshes(d, top)?;
    }
    opts.overrides =
        crate::base::Overrides::read(args.palpation.as_deref(), args.centres.as_deref())?;
    let mut files: Vec<(PathBuf, Vec<u8>)> = Vec::new();
    let built = if args.procedural {
        let popts = ProceduralOptions {
            stature: args.stature,
            sex: match args.sex {
                SexArg::Female => Sex::Female,
                SexArg::Male => Sex::Male,
            },
        };
        let generic = generate_generic(&popts)?;
        if args.body_meshes.is_none() {
            // the generated vertebral bodies, for the sphere fits
            opts.body_meshes = generic.body_meshes();
        }
        let summary = serde_json::to_string_pretty(&generic.summary())?;
        files.push((
            args.out.join("procedural_report.json"),
            summary.into_bytes(),
        ));
        build_base(&generic.doc, &opts, &generic.meshes)?
    } else {
        let path = args
            .generic
            .clone()
            .ok_or_else(|| Error::invalid("base", "give --generic MODEL.osim or --procedural"))?;
        let generic = Document::read(&path)?;
        let source = DirMeshSource {
            model_path: path,
            extra: args.geometry.clone(),
        };
        build_base(&generic, &opts, &source)?
    };
    // Everything computed: serialise, then write.
    files.push((
        args.out.join("base.osim"),
        built.doc.to_xml_string().into_bytes(),
    ));
    for (name, mesh) in &built.meshes {
        let path = args.out.join(name);
        let fmt = crate::mesh::Format::from_path(&path)?;
        files.push((path, crate::mesh::to_bytes(fmt, mesh)));
    }
    // Reported figures at a stated precision (the .osim keeps full precision).
    let json = crate::util::report::to_json_pretty(&built.report)?;
    files.push((args.out.join("base_report.json"), json.into_bytes()));
    for (name, svg) in &built.views {
        files.push((args.out.join(name), svg.clone().into_bytes()));
    }
    crate::util::write_all_or_nothing(&files)?;
    let r = &built.report;
    crate::outln!(
        "base model: {} bodies, {} joints ({} rebuilt 6-DoF), {} muscles kept ({} dropped), {} bushings",
        r.prune.bodies_kept.len(),
        r.joints.len(),
        r.joints.iter().filter(|j| j.bushing.is_some()).count(),
        r.prune.muscles_kept.len(),
        r.prune.muscles_dropped.len(),
        r.joints.iter().filter(|j| j.bushing.is_some()).count(),
    );
    if let Some(s) = &r.sacrum {
        crate::outln!(
            "sacrum: {} registered, RMS surface distance {:.2} mm (max {:.2} mm)",
            s.source,
            s.residual_to_generic.rms_mm,
            s.residual_to_generic.max_mm
        );
    }
    crate::outln!(
        "wrap spheres: {}, path wraps: {} on {} muscles; markers: {}",
        r.spheres.len(),
        r.path_wraps_added,
        r.muscles_with_wraps,
        r.markers.len()
    );
    super::print_self_check(&r.self_check);
    print_guards(r);
    crate::outln!("wrote {} files to {}", files.len(), args.out.display());
    Ok(0)
}

/// Every guard result and the palpation's findings, as the report has them.
fn print_guards(r: &crate::base::BaseReport) {
    for g in &r.guards_checked {
        let fails: Vec<_> = r.guard_failures.iter().filter(|f| f.guard == *g).collect();
        let verdict = if fails.is_empty() {
            "pass".to_string()
        } else {
            format!("{} FAILED", fails.len())
        };
        crate::outln!("guard {}: {verdict}", g.describe());
        for f in fails {
            crate::outln!("  warning (--allow-implausible): {f}");
        }
    }
    for f in &r.palpation_ordering_failures {
        crate::outln!("palpation: {f}");
    }
    if !r.palpation_given.is_empty() {
        crate::outln!(
            "palpation: {} landmark(s)/centre(s) from your files instead of the engine: {}",
            r.palpation_given.len(),
            r.palpation_given.join(" ")
        );
    }
}
