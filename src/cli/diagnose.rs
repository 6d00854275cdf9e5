//! `osim-spine diagnose EXPERIMENT --out DIR [--quiet] [--jobs N]`: sim-to-real gap
//! diagnosis. Writes `diagnosis.json` (format in
//! `../shared/formats/experiment.md`), `report.md`, `residual_map.svg`,
//! `curves.svg` and `improved.osim` (the chosen effect added).

use crate::diagnose::{self, select::Options};
use clap::Args as ClapArgs;
use std::path::PathBuf;

/// Arguments of `diagnose`.
#[derive(Debug, ClapArgs)]
pub struct Args {
    /// Experiment folder (experiment.toml, kinematics.csv, model).
    pub experiment: PathBuf,
    /// Output folder.
    #[arg(long)]
    pub out: PathBuf,
    /// Allow the output to go where an input is (it may be replaced).
    #[arg(long)]
    pub force: bool,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
    /// Worker threads (default and at most: the machine's cores); the
    /// results do not depend on it.
    #[arg(long)]
    pub jobs: Option<usize>,
}

/// Run.
pub fn run(a: Args) -> anyhow::Result<i32> {
    // Never write into a folder that holds an input.
    let protected = crate::util::guard::Protected::default().inputs([&a.experiment]);
    crate::util::guard::check_output_dir(&a.out, &protected, a.force)?;
    super::with_jobs(a.jobs, || run_inner(&a))
}

fn run_inner(a: &Args) -> anyhow::Result<i32> {
    let opts = Options {
        progress: !a.quiet,
        ..Options::default()
    };
    let (o, missing) = diagnose::run(&a.experiment, &a.out, &opts)?;
    super::warn_missing_meshes(&a.out.join("improved.osim"), &missing, false);
    let (b, au) = o.heldout_rmse();
    let effects: Vec<&str> = o.effects.iter().map(|e| e.effect.name()).collect();
    let both = if effects.len() > 1 {
        format!(" [effects: {}]", effects.join(" + "))
    } else {
        String::new()
    };
    let rests = if o.assumptions.is_empty() {
        ""
    } else {
        ", resting on an assumed noise"
    };
    crate::errln!(
        "verdict: {}{both} (confidence {:.2}{rests}); held-out rotation RMSE {:.4} -> {:.4} deg; wrote {}",
        o.verdict,
        o.confidence,
        b,
        au,
        a.out.join("diagnosis.json").display()
    );
    for x in &o.assumptions {
        crate::errln!("ASSUMED: {x}");
    }
    if let Some(line) = diagnose::report::ratios_line(&o) {
        crate::errln!("{line}");
    }
    crate::errln!("{}", diagnose::report::noise_line(&o));
    crate::errln!("{}", diagnose::report::params_line(&o));
    crate::errln!("{}", diagnose::report::separable_line(&o));
    Ok(0)
}
