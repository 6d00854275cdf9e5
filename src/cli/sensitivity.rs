//! `osim-spine sensitivity EXPERIMENT [--params ...] [--samples 500]
//! [--landmark-sd MM] [--seed S] [--jobs N] --out DIR`: the joint-pose
//! sensitivity study of [`crate::calibrate::sensitivity`]: landmark noise
//! propagated to joint frames (Latin hypercube), every sample re-calibrated,
//! spread of stiffness and error, two-factor (pose x stiffness) analysis.
//! Writes `sensitivity.json` and `spread.svg`.

use crate::calibrate::experiment::Experiment;
use crate::calibrate::measure::Convention;
use crate::calibrate::sensitivity::{self, SensitivityOptions};
use crate::calibrate::setup::{self, Setup};
use crate::util::write_all_or_nothing;
use clap::Args as ClapArgs;
use std::path::PathBuf;
use std::sync::Arc;

/// Default landmark SD per coordinate (mm): the source thesis's value.
pub const THESIS_LANDMARK_SD_MM: f64 = 2.9;

/// Arguments of `sensitivity`.
#[derive(Debug, ClapArgs)]
pub struct Args {
    /// Experiment folder.
    pub experiment: PathBuf,
    /// Parameterisation (uniform, ratio:TABLE, per-level).
    #[arg(long, default_value = "uniform", value_name = "KIND")]
    pub params: String,
    /// DoFs in the cost (default: the measured rotations).
    #[arg(long, value_name = "rx,ry,rz,...")]
    pub dofs: Option<String>,
    /// Weights per DoF.
    #[arg(long, value_name = "rx=1,...")]
    pub weights: Option<String>,
    /// Number of landmark sets (joint-pose samples).
    #[arg(long, default_value_t = 500)]
    pub samples: usize,
    /// Landmark SD per coordinate, millimetres (default 2.9 mm, the
    /// palpation SD the source thesis used).
    #[arg(long, default_value_t = THESIS_LANDMARK_SD_MM, value_name = "MM")]
    pub landmark_sd: f64,
    /// Seed of the Latin hypercube.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub jobs: Option<usize>,
    /// Output folder.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Allow the output to go where an input is (it may be replaced).
    #[arg(long)]
    pub force: bool,
}

/// Run `sensitivity`.
pub fn run(a: Args) -> anyhow::Result<i32> {
    // Never write into a folder that holds an input.
    let protected = crate::util::guard::Protected::default().inputs([&a.experiment]);
    crate::util::guard::check_output_dir(&a.out, &protected, a.force)?;
    super::with_jobs(a.jobs, || run_inner(&a))
}

fn run_inner(a: &Args) -> anyhow::Result<i32> {
    if !(a.landmark_sd.is_finite() && a.landmark_sd >= 0.0) {
        anyhow::bail!("--landmark-sd must be a finite number of millimetres >= 0");
    }
    let setup = Setup {
        params: setup::parse_params(&a.params)?,
        dofs: a.dofs.as_deref().map(setup::parse_dofs).transpose()?,
        translations: false,
        weights: match &a.weights {
            Some(w) => setup::parse_weights(w)?,
            None => [None; 6],
        },
        convention: Convention::Composed,
    };
    let exp = Arc::new(Experiment::read(&a.experiment)?);
    let sd_note = if a.landmark_sd == THESIS_LANDMARK_SD_MM {
        " (default: the source thesis's palpation SD; --landmark-sd sets it)"
    } else {
        ""
    };
    crate::errln!(
        "sensitivity: {} samples, landmark SD {} mm{sd_note}, {}",
        a.samples,
        a.landmark_sd,
        a.params
    );
    let rep = sensitivity::run(
        exp.clone(),
        &setup,
        &SensitivityOptions {
            samples: a.samples,
            landmark_sd: a.landmark_sd * 1e-3,
            seed: a.seed,
            progress: true,
            ..SensitivityOptions::default()
        },
    )?;
    let json = serde_json::to_string_pretty(&rep)? + "\n";
    let svg = sensitivity::spread_svg(
        &rep,
        &format!(
            "{}: joint-pose sensitivity ({} mm)",
            exp.name, a.landmark_sd
        ),
    );
    write_all_or_nothing(&[
        (a.out.join("sensitivity.json"), json.into_bytes()),
        (a.out.join("spread.svg"), svg.into_bytes()),
    ])?;
    crate::errln!(
        "sensitivity: {} of {} samples in the reduced dataset; rotation RMSE median {:.4} (reference {:.4})",
        rep.reduced, rep.samples, rep.rmse.median, rep.reference_rmse
    );
    for s in &rep.params {
        crate::errln!(
            "  {:<14} reference {:>10.3}  median {:>10.3}  95% range [{:.3}, {:.3}]",
            s.name,
            s.reference,
            s.median,
            s.p2_5,
            s.p97_5
        );
    }
    if let Some(t) = &rep.two_factor {
        crate::errln!(
            "  two-factor (RMSE): pose {:.1}%, stiffness {:.1}%, interaction {:.1}%",
            100.0 * t.share_pose,
            100.0 * t.share_stiffness,
            100.0 * t.share_interaction
        );
    }
    crate::errln!("sensitivity: written to {}", a.out.display());
    Ok(0)
}
