//! `osim-spine variability FILES... --out DIR`: repeated-palpation
//! statistics and their propagation to the model (thesis chapter 5,
//! Tables 5.5-5.8). Writes `variability.json`, `iqr_boxplot.svg` and, with
//! the models (default; `--no-models` skips them), the model box plots
//! `model_errors_boxplot.svg`, `model_r2_boxplot.svg`,
//! `model_angles_boxplot.svg`, `model_centre_rmse_groups.svg`; with
//! `--write-models` also `models/<operator>_<repetition>.osim` (+ reports and
//! `models/Geometry/`). Everything is computed first, then written
//! atomically.

use crate::evaluate::propagation::PropagationOptions;
use crate::evaluate::variability;
use crate::generate::Method;
use anyhow::Context;
use std::collections::BTreeMap;
use std::path::PathBuf;

/// Arguments of `variability`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Palpation files: one set per file (operator/repetition from
    /// `# operator:` / `# repetition:` comments, else repetitions of one
    /// operator in the order given) or CSVs with `operator,repetition` columns.
    #[arg(required = true)]
    pub files: Vec<PathBuf>,
    /// Output folder.
    #[arg(long)]
    pub out: PathBuf,
    /// Allow the output to go where an input is (it may be replaced).
    #[arg(long)]
    pub force: bool,
    /// Landmark statistics only: no model per palpation.
    #[arg(long)]
    pub no_models: bool,
    /// Base model for the models: a folder holding one .osim (and its
    /// meshes), or an .osim file (default: the base model compiled into
    /// the binary).
    #[arg(long, value_name = "DIR")]
    pub base: Option<PathBuf>,
    /// Vertebra pose fit of the generator: lsq or thesis.
    #[arg(long, value_enum, ignore_case = true, default_value_t = Method::Lsq)]
    pub method: Method,
    /// Reference of the model metrics: truth centres CSV (`level,x,y,z`,
    /// `# units:`, `# frame:`) or a folder of vertebral-body meshes. Without
    /// it: the consensus model of the per-landmark median landmark set.
    #[arg(
        long,
        value_name = "CENTRES.csv|MESH_DIR",
        conflicts_with = "no_models"
    )]
    pub truth: Option<PathBuf>,
    #[command(flatten)]
    /// Metric options (clap ignores this comment on a flattened field).
    pub metrics: super::evaluate::MetricArgs,
    /// Worker threads for the models (default: all cores).
    #[arg(long, value_name = "N")]
    pub jobs: Option<usize>,
    /// Also write every palpation's model into `DIR/models/`.
    #[arg(long, conflicts_with = "no_models")]
    pub write_models: bool,
}

/// A file-name-safe stem for a palpation's model.
fn model_stem(label: &str) -> String {
    let s: String = label
        .trim_start_matches("operator ")
        .replace(" repetition ", "_rep")
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '_' || c == '-' {
                c
            } else {
                '_'
            }
        })
        .collect();
    format!("op{s}")
}

/// Run; returns the exit code.
pub fn run(args: &Args) -> anyhow::Result<i32> {
    // Never write into a folder that holds an input.
    let protected = crate::util::guard::Protected::default()
        .inputs(args.files.iter().chain(&args.base).chain(&args.truth));
    crate::util::guard::check_output_dir(&args.out, &protected, args.force)?;
    super::with_jobs(args.jobs, || run_inner(args))
}

fn run_inner(args: &Args) -> anyhow::Result<i32> {
    let mut base_path = None;
    let models =
        if args.no_models {
            None
        } else {
            let method = args.method;
            let truth = match &args.truth {
                Some(t) => Some(args.metrics.load_truth(t)?),
                None => None,
            };
            let cobb_ends = args.metrics.cobb_ends()?;
            let bp =
                crate::embedded::BaseModel::locate(args.base.as_deref()).with_context(|| {
                    format!(
                "base model for the per-palpation models (--base {}; --no-models skips them)",
                args.base.as_deref().unwrap_or(std::path::Path::new("")).display()
            )
                })?;
            let base = bp.read()?;
            base_path = Some(bp);
            Some((
                base,
                PropagationOptions {
                    method,
                    truth,
                    align: args.metrics.align,
                    centre: args.metrics.centre,
                    cobb_ends,
                    progress: true,
                    keep_models: args.write_models,
                },
            ))
        };
    let c = variability::compute(&args.files, models.as_ref().map(|(b, o)| (b, o)))?;
    // Everything computed: gather the bytes, then write.
    let mut files: BTreeMap<PathBuf, Vec<u8>> = BTreeMap::new();
    for (p, b) in variability::output_files(&c)? {
        files.insert(args.out.join(p), b);
    }
    if let Some(bp) = &base_path {
        let mdir = args.out.join("models");
        for (label, g) in &c.models {
            let stem = model_stem(label);
            for (p, b) in super::generate::model_files(bp, g, &mdir.join(format!("{stem}.osim")))? {
                files.insert(p, b);
            }
            files.insert(
                mdir.join(format!("{stem}_report.json")),
                serde_json::to_string_pretty(&g.report)?.into_bytes(),
            );
        }
    }
    let files: Vec<(PathBuf, Vec<u8>)> = files.into_iter().collect();
    crate::util::write_all_or_nothing(&files)?;
    let r = &c.report;
    for w in &r.warnings {
        crate::errln!("warning: {w}");
    }
    if r.operators.len() == 1 && args.files.len() > 1 {
        crate::outln!(
            "note: one operator: without `# operator:` comments or an operator column the {} files are \
             treated as repetitions of one operator (no inter-operator statistics)",
            args.files.len()
        );
    }
    crate::outln!(
        "{} palpations, {} operators, {} landmarks; wrote {} files to {}",
        r.palpations,
        r.operators.len(),
        r.landmarks.len(),
        files.len(),
        args.out.display()
    );
    for s in r.summary.iter().filter(|s| s.group == "all") {
        crate::outln!(
            "  IQR {:<9} median {:.2} mm, IQR of IQRs {:.2} mm, max {:.2} mm",
            s.axis,
            s.median_mm,
            s.iqr_mm,
            s.max_mm
        );
    }
    if let Some(p) = &r.model_propagation {
        crate::outln!(
            "  models: {} of {} palpations ({} method), reference: {} ({}); Cobb ends {}",
            p.models,
            p.palpations,
            p.method,
            p.reference.kind,
            p.reference.source,
            p.cobb_ends
        );
        let mi = |m: &Option<crate::evaluate::MedIqr>| {
            m.as_ref()
                .map(|m| format!("{:.2} ({:.2})", m.median, m.iqr))
                .unwrap_or_else(|| "-".into())
        };
        crate::outln!(
            "  {:<22} {:>14} {:>14} {:>14} {:>14} {:>14} {:>14} {:>14}",
            "group (median (IQR))",
            "centre RMSE mm",
            "sag. curve mm",
            "front. curve mm",
            "sag. R2",
            "front. R2",
            "Cobb deg",
            "lordosis deg"
        );
        for g in &p.groups {
            crate::outln!(
                "  {:<22} {:>14} {:>14} {:>14} {:>14} {:>14} {:>14} {:>14}",
                format!("{} {}", g.kind, g.within),
                mi(&g.centre_rmse_mm),
                mi(&g.sagittal_curve_rmse_mm),
                mi(&g.frontal_curve_rmse_mm),
                mi(&g.sagittal_r2),
                mi(&g.frontal_r2),
                mi(&g.cobb_deg),
                mi(&g.lordosis_deg),
            );
        }
        for row in p.rows.iter().filter(|r| !r.ok) {
            crate::outln!(
                "  no model for {}: {}",
                row.source,
                row.error.as_deref().unwrap_or("")
            );
        }
    }
    for n in &r.notes {
        crate::outln!("  note: {n}");
    }
    Ok(0)
}
