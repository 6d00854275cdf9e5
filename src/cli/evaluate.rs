//! `osim-spine evaluate --model MODEL.osim... --truth CENTRES.csv|MESH_DIR
//! --out DIR`: model accuracy metrics of the source thesis (see
//! [`crate::evaluate`]). Writes `DIR/evaluation.json` and the figures
//! `DIR/centres_{frontal,sagittal}.svg` (Fig. 5.6) and
//! `DIR/curves_{frontal,sagittal}.svg` (Fig. 5.7), atomically, after
//! everything is computed.

use crate::evaluate::{evaluate, load_model, load_truth, parse_cobb_ends, Align, CentreDef, Truth};
use crate::landmarks::Level;
use std::path::PathBuf;

/// Arguments of `evaluate`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Model(s) to evaluate (several: one per palpation -> median and IQR).
    #[arg(long, value_name = "MODEL.osim", required = true, num_args = 1..)]
    pub model: Vec<PathBuf>,
    /// Truth: a centres CSV (`level,x,y,z`, `# units:`, `# frame:`) or a
    /// folder of vertebral-body meshes `<LEVEL>*.stl|obj|vtp|ply`.
    #[arg(long, value_name = "CENTRES.csv|MESH_DIR")]
    pub truth: PathBuf,
    #[command(flatten)]
    /// Metric options (clap ignores this comment on a flattened field).
    pub metrics: MetricArgs,
    /// Output folder.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Allow the output to go where an input is (it may be replaced).
    #[arg(long)]
    pub force: bool,
}

/// How models are compared with a reference (shared by `evaluate` and
/// `variability`).
#[derive(Debug, clap::Args)]
pub struct MetricArgs {
    /// Truth landmark set, for the truth's Cobb angle, apex and lordosis
    /// (and, in `variability`, the Cobb end vertebrae of every model).
    #[arg(long, value_name = "FILE")]
    pub truth_landmarks: Option<PathBuf>,
    /// Units of truth meshes (mm or m).
    #[arg(long, value_name = "mm|m")]
    pub truth_units: Option<String>,
    /// Frame of truth meshes (LPS, RAS, opensim).
    #[arg(long, value_name = "FRAME")]
    pub truth_frame: Option<String>,
    /// Superimposition of the reference on each model after the sacral
    /// registration: rigid (shape error), l5 (thesis), sacrum (none).
    #[arg(long, value_enum, default_value = "rigid")]
    pub align: Align,
    /// Vertebral centre: endplates (midpoint of SEC/IEC; meshes: volume
    /// centroid) or sphere (vertebral-body wrap sphere; meshes: anterior-wall
    /// sphere fit, the thesis's definition).
    #[arg(long, value_enum, default_value = "endplates")]
    pub centre: CentreDef,
    /// End vertebrae of the main curve, `UPPER,LOWER` (default: automatic;
    /// `variability`: the reference's automatic ends, for every model).
    #[arg(long, value_name = "UPPER,LOWER")]
    pub cobb_ends: Option<String>,
}

impl MetricArgs {
    /// The truth at `path` read with these options.
    pub fn load_truth(&self, path: &std::path::Path) -> crate::error::Result<Truth> {
        load_truth(
            path,
            self.truth_units.as_deref(),
            self.truth_frame.as_deref(),
            self.truth_landmarks.as_deref(),
            self.centre,
        )
    }

    /// `--cobb-ends`, parsed.
    pub fn cobb_ends(&self) -> crate::error::Result<Option<(Level, Level)>> {
        self.cobb_ends.as_deref().map(parse_cobb_ends).transpose()
    }
}

/// Run `evaluate`; returns the exit code.
pub fn run(args: Args) -> anyhow::Result<i32> {
    // Never write into a folder that holds an input.
    let protected =
        crate::util::guard::Protected::default().inputs(args.model.iter().chain([&args.truth]));
    crate::util::guard::check_output_dir(&args.out, &protected, args.force)?;
    let opts = &args.metrics;
    let ends = opts.cobb_ends()?;
    let truth = opts.load_truth(&args.truth)?;
    let mut models = Vec::new();
    for m in &args.model {
        models.push(load_model(m, opts.centre)?);
    }
    let (report, figures) = evaluate(&models, &truth, opts.align, ends, opts.centre)?;
    let mut files: Vec<(PathBuf, Vec<u8>)> = vec![(
        args.out.join("evaluation.json"),
        serde_json::to_string_pretty(&report)?.into_bytes(),
    )];
    for (name, svg) in figures {
        files.push((args.out.join(name), svg.into_bytes()));
    }
    crate::util::write_all_or_nothing(&files)?;
    for m in &report.models {
        let cobb = m
            .cobb
            .as_ref()
            .map(|c| format!("{:.1} deg ({}-{})", c.angle_deg, c.upper, c.lower))
            .unwrap_or_else(|| "-".into());
        let tcobb = m
            .truth_cobb
            .as_ref()
            .map(|c| format!(" (truth {:.1} deg, {}-{})", c.angle_deg, c.upper, c.lower))
            .unwrap_or_default();
        crate::outln!(
            "{}: centre RMSE {:.2} mm ({} align{}); Cobb {cobb}{tcobb}; apex {}; lordosis {}",
            m.model,
            m.centre_rmse_mm,
            serde_json::to_value(m.align)?.as_str().unwrap_or(""),
            m.centre_rmse_sacral_frame_mm
                .map(|v| format!(", {v:.2} mm in the sacral frame"))
                .unwrap_or_default(),
            m.apex.map_or("-".into(), |l| l.to_string()),
            m.lordosis_deg
                .map(|v| format!("{v:.1} deg"))
                .unwrap_or_else(|| "-".into()),
        );
    }
    if report.models.len() > 1 {
        let s = &report.summary;
        if let Some(r) = &s.centre_rmse_mm {
            crate::outln!(
                "{} models: median centre RMSE {:.2} mm (IQR {:.2})",
                s.models,
                r.median,
                r.iqr
            );
        }
        if let Some(c) = &s.cobb_deg {
            crate::outln!(
                "Cobb angle mean {:.1} deg (SD {:.1}, min {:.1}, max {:.1})",
                c.mean,
                c.sd,
                c.min,
                c.max
            );
        }
    }
    crate::outln!("wrote {} files to {}", files.len(), args.out.display());
    Ok(0)
}
