//! `osim-spine palpate SEGMENTATION --out LANDMARKS.csv [--units mm|m]
//! [--frame LPS|RAS|opensim] [--levels T1..S1] [--labels FILE]
//! [--laterals furthest|rim-middle]`: patient
//! landmarks from vertebra segmentations (see [`crate::segmentation`]).
//! Writes the landmark CSV, `<stem>_report.json` and the figures
//! `<stem>_frontal.svg` / `<stem>_sagittal.svg`, each atomically, and
//! only once everything is computed: nothing is written on error.

use crate::error::Error;
use crate::landmarks::{Frame, Level, Units};
use crate::segmentation::{self, report, Laterals, Options, Palpated, Severity};
use std::path::{Path, PathBuf};

/// Arguments of `palpate`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// A folder of per-level meshes (T1.stl .. L5.stl, S1/sacrum; .stl .obj
    /// .vtp .ply; TotalSegmentator names) or a NIfTI label map (.nii, .nii.gz).
    pub segmentation: PathBuf,
    /// Landmark set to write (.csv).
    #[arg(long, value_name = "LANDMARKS.csv")]
    pub out: PathBuf,
    /// Allow the output to go where an input is (it may be replaced).
    #[arg(long)]
    pub force: bool,
    /// Where SR, SL, IR, IL are taken: the endplate regions' furthest points
    /// (the protocol's words, as an operator places them) or the middles of
    /// their lateral rims (the rule of a base model's markers, which
    /// `generate --segmentation` uses).
    #[arg(long, value_enum, default_value = "furthest")]
    pub laterals: LateralsArg,
    #[command(flatten)]
    /// Segmentation options (clap ignores this comment on a flattened field).
    pub seg: SegArgs,
}

/// `--laterals`.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
#[allow(missing_docs)] // clap prints variant doc comments in --help; the names say it
pub enum LateralsArg {
    Furthest,
    RimMiddle,
}

/// The segmentation options shared by `palpate` and `generate --segmentation`.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct SegArgs {
    /// Units of a mesh folder's files (default mm); of the landmarks written
    /// for a label map (default mm).
    #[arg(long, value_name = "mm|m")]
    pub units: Option<String>,
    /// Frame of a mesh folder's files (default: detected from the anatomy);
    /// of the landmarks written for a label map (default RAS, its world).
    #[arg(long, value_name = "LPS|RAS|opensim")]
    pub frame: Option<String>,
    /// Levels to palpate, e.g. T9..S1 (default all present).
    #[arg(long, value_name = "T1..S1")]
    pub levels: Option<String>,
    /// Label table of a label map: lines `LABEL NAME` (default: the built-in
    /// TotalSegmentator and TotalSpineSeg tables).
    #[arg(long, value_name = "FILE")]
    pub labels: Option<PathBuf>,
}

impl SegArgs {
    /// The library options (progress bar on).
    pub fn options(&self) -> crate::Result<Options> {
        let units = match &self.units {
            Some(u) => Some(
                Units::parse_label(u)
                    .ok_or_else(|| Error::invalid("--units", format!("'{u}': expected mm or m")))?,
            ),
            None => None,
        };
        let frame = match &self.frame {
            Some(f) => Some(Frame::parse_label(f).ok_or_else(|| {
                Error::invalid("--frame", format!("'{f}': expected LPS, RAS or opensim"))
            })?),
            None => None,
        };
        let levels = match &self.levels {
            Some(s) => Some(parse_levels(s)?),
            None => None,
        };
        Ok(Options {
            units,
            frame,
            levels,
            labels: self.labels.clone(),
            progress: true,
            laterals: Laterals::RimMiddle,
        })
    }
}

/// `T9..S1`, `T9-S1` or one level `L3`.
pub fn parse_levels(s: &str) -> crate::Result<(Level, Level)> {
    let bad = || {
        Error::invalid(
            "--levels",
            format!("'{s}': expected a range such as T9..S1"),
        )
    };
    let (a, b) = s
        .split_once("..")
        .or_else(|| s.split_once('-'))
        .unwrap_or((s, s));
    let a: Level = a.parse().map_err(|_| bad())?;
    let b: Level = b.parse().map_err(|_| bad())?;
    Ok((a.min(b), a.max(b)))
}

/// Print the findings (warnings and errors to stderr) and a summary.
pub fn print_summary(p: &Palpated) {
    for f in &p.findings {
        let at = f.level.map(|l| format!("{l}: ")).unwrap_or_default();
        match f.severity {
            Severity::Info => crate::outln!("palpate: {at}{}", f.message),
            Severity::Warning => crate::errln!("warning: {at}{}", f.message),
            Severity::Error => crate::errln!("error: {at}{}", f.message),
        }
    }
    let levels: Vec<String> = p.levels.iter().map(|l| l.level.to_string()).collect();
    let uncertain = p
        .findings
        .iter()
        .filter(|f| f.code.is_some() && f.severity == Severity::Warning)
        .count();
    crate::outln!(
        "palpated {} levels ({}) of {}: {} landmarks, {} uncertain; SR/SL/IR/IL at the {}; segmentation frame {}, landmarks written in {} {}",
        levels.len(),
        levels.join(" "),
        p.source,
        p.set.len(),
        uncertain,
        match p.laterals {
            Laterals::Furthest => "endplates' furthest points",
            Laterals::RimMiddle => "middles of the endplates' lateral rims",
        },
        p.world,
        p.units,
        p.frame
    );
}

/// The files of a palpation written as `out` (.csv): CSV, report, figures.
pub fn output_files(p: &Palpated, out: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let dir = match out.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let stem = out
        .file_stem()
        .map(|s| s.to_string_lossy().to_string())
        .unwrap_or_else(|| "landmarks".into());
    let mut files = vec![
        (out.to_path_buf(), report::csv_text(p).into_bytes()),
        (
            dir.join(format!("{stem}_report.json")),
            report::json_text(p).into_bytes(),
        ),
    ];
    for (view, svg) in report::figure(p) {
        files.push((dir.join(format!("{stem}_{view}.svg")), svg.into_bytes()));
    }
    files
}

/// Run `palpate`; returns the exit code.
pub fn run(args: Args) -> anyhow::Result<i32> {
    // Never overwrite an input.
    let protected = crate::util::guard::Protected::default()
        .inputs(std::iter::once(&args.segmentation).chain(&args.seg.labels));
    crate::util::guard::check_outputs(&[&args.out], &protected, args.force)?;
    if args
        .out
        .extension()
        .map(|e| !e.eq_ignore_ascii_case("csv"))
        .unwrap_or(true)
    {
        return Err(Error::invalid("--out", "the landmark set is written as .csv").into());
    }
    let opts = Options {
        laterals: match args.laterals {
            LateralsArg::Furthest => Laterals::Furthest,
            LateralsArg::RimMiddle => Laterals::RimMiddle,
        },
        ..args.seg.options()?
    };
    let p = segmentation::palpate(&args.segmentation, &opts)?;
    let files = output_files(&p, &args.out);
    if files.iter().any(|(f, _)| same_file(f, &args.segmentation)) {
        return Err(Error::invalid("--out", "would overwrite the segmentation").into());
    }
    print_summary(&p);
    crate::util::write_all_or_nothing(&files)?;
    crate::outln!("wrote {} files: {}", files.len(), args.out.display());
    Ok(0)
}

/// `true` when both paths name the same existing file.
fn same_file(a: &Path, b: &Path) -> bool {
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(x), Ok(y)) => x == y,
        _ => false,
    }
}
