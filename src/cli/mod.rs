//! The command-line interface: a thin clap shell over the library. Each
//! subcommand lives in its own file with an `Args` struct and a `run`.

use clap::{Parser, Subcommand};

pub mod base;
pub mod calibrate;
pub mod check;
pub mod convert;
pub mod diagnose;
pub mod evaluate;
pub mod flexibility;
pub mod generate;
pub mod info;
pub mod mean_shape;
pub mod palpate;
pub mod sensitivity;
pub mod simulate;
pub mod stiffness;
pub mod variability;

/// osim-spine: patient-specific scoliotic OpenSim spine models.
#[derive(Debug, Parser)]
#[command(name = "osim-spine", version, about, long_about = None)]
pub struct Cli {
    #[command(subcommand)]
    /// The subcommand to run (clap ignores this comment on a subcommand field).
    pub command: Command,
}

/// Subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Calibrate intervertebral stiffness from measured kinematics
    /// (experiment folder): multi-start Levenberg-Marquardt, covariance,
    /// identifiability, validation; calibrated .osim, JSON and SVG.
    Calibrate(calibrate::Args),
    /// Diagnose the sim-to-real gap of an experiment: baseline re-fit,
    /// held-out design, candidate effects, verdict, held-out shrink;
    /// diagnosis.json, report.md, SVG figures, improved .osim.
    Diagnose(diagnose::Args),
    /// Joint-pose sensitivity of a calibration: landmark noise propagated
    /// to the joint frames (Latin hypercube), every sample re-calibrated;
    /// spread of stiffness and error, two-factor (pose x stiffness) analysis.
    Sensitivity(sensitivity::Args),
    /// Summarise a model: bodies, joints, coordinates, forces, muscles, markers, meshes.
    Info(info::Args),
    /// Convert a model (any version -> canonical 4.x) or a mesh file.
    Convert(convert::Args),
    /// Build the base model (T1-L5, sacrum, pelvis; 6-DoF IVD joints with bushings,
    /// wrap spheres, palpated markers) from a generic model.
    Base(base::Args),
    /// Mean of meshes in vertex correspondence (generalised Procrustes analysis).
    MeanShape(mean_shape::Args),
    /// Static equilibrium (or forward dynamics) of a model under load cases.
    Simulate(simulate::Args),
    /// Validate landmark sets: protocol completeness, names, units and
    /// frame, per-vertebra geometry, inter-vertebral plausibility, outliers.
    /// Exit 0 clean, 1 errors, 2 warnings only (1 with --strict).
    Check(check::Args),
    /// Repeated-palpation statistics: IQRs, ICC(2,1), Shapiro-Wilk,
    /// Friedman/Skillings-Mack with Nemenyi post hoc; one model per
    /// palpation with median/IQR of centre RMSE, curve fits, Cobb angle and
    /// lordosis (overall, intra- and inter-operator); JSON + SVG.
    Variability(variability::Args),
    /// Generate a patient-specific scoliotic model from a landmark set
    /// (sacral registration, per-vertebra anisotropic scaling and pose,
    /// joints placed so that every bushing is undeflected at the default pose).
    Generate(generate::Args),
    /// Landmarks palpated with no operator on vertebra segmentations (a
    /// folder of per-level meshes or a NIfTI label map): landmark CSV,
    /// JSON report per landmark, SVG of the palpated levels.
    Palpate(palpate::Args),
    /// Accuracy of model(s) against truth vertebral centres: centre RMSE,
    /// per-axis errors, curve fits, Cobb angle, apex, lordosis; JSON + SVG.
    Evaluate(evaluate::Args),
    /// The patient's relative intervertebral stiffness from frontal bending
    /// films (neutral, left, right): the model bent into each film, stiffness
    /// ratios with 95% intervals, curves' flexibility, predicted films;
    /// flexibility.json, stiffness.toml, SVG per film.
    Flexibility(flexibility::Args),
    /// Assign intervertebral stiffness from a table (uniform, per level,
    /// base x ratio; linear, non-linear per DoF, coupled 6x6), or --list the
    /// current stiffness in the same format.
    Stiffness(stiffness::Args),
}

/// Parse the command line and run; returns the process exit code.
/// Warn about the meshes of a written model found nowhere beside its
/// input: dropped from it, or (`kept`) left for OpenSim to warn about.
pub fn warn_missing_meshes(out: &std::path::Path, missing: &[String], kept: bool) {
    if missing.is_empty() {
        return;
    }
    let shown: Vec<&str> = missing.iter().take(5).map(String::as_str).collect();
    crate::errln!(
        "warning: {}: {} mesh file(s) of the input model found nowhere ({}{}): {}",
        out.display(),
        missing.len(),
        shown.join(", "),
        if missing.len() > shown.len() {
            ", ..."
        } else {
            ""
        },
        if kept {
            "kept as references; OpenSim will warn that it cannot find them"
        } else {
            "their references are removed from the output (display only)"
        }
    );
}

/// The self-check of a written model (its `Display`: every result and
/// the equilibrium verdict) on stdout; muscles through bone warned on stderr.
pub fn print_self_check(sc: &crate::base::check::SelfCheck) {
    crate::outln!("{sc}");
    for w in sc.warnings() {
        crate::errln!("warning: {w}");
    }
}

/// The worker threads for `--jobs requested` on a machine of `cores`
/// cores: at most the cores (more threads only add memory and switching),
/// at least one; `None` (all cores) without `--jobs` or with `--jobs 0`.
pub fn worker_threads(requested: Option<usize>, cores: usize) -> Option<usize> {
    match requested {
        None | Some(0) => None,
        Some(j) => Some(j.min(cores.max(1))),
    }
}

/// Run `f` on a pool of `jobs` worker threads (`None`: one per core; more
/// than the cores: the cores, with a note on stderr). Results do not
/// depend on the count: parallel work is collected in input order.
pub fn with_jobs<T>(
    jobs: Option<usize>,
    f: impl FnOnce() -> anyhow::Result<T> + Send,
) -> anyhow::Result<T>
where
    T: Send,
{
    use anyhow::Context;
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    if let Some(n) = jobs.filter(|&n| n > cores) {
        eprintln!("note: --jobs {n} is more than the {cores} cores: {cores} used");
    }
    let jobs = worker_threads(jobs, cores);
    rayon::ThreadPoolBuilder::new()
        .num_threads(jobs.unwrap_or(0))
        .build()
        .context("starting the worker threads")?
        .install(f)
}

/// Parses the command line, runs the subcommand and returns the process exit code.
pub fn main() -> i32 {
    let cli = Cli::parse();
    let result: anyhow::Result<i32> = match cli.command {
        Command::Calibrate(a) => calibrate::run(a),
        Command::Diagnose(a) => diagnose::run(a),
        Command::Sensitivity(a) => sensitivity::run(a),
        Command::Info(a) => info::run(a),
        Command::Convert(a) => convert::run(a),
        Command::Base(a) => base::run(a),
        Command::MeanShape(a) => mean_shape::run(a),
        Command::Simulate(a) => simulate::run(a),
        Command::Check(a) => check::run(&a),
        Command::Variability(a) => variability::run(&a),
        Command::Generate(a) => generate::run(a),
        Command::Evaluate(a) => evaluate::run(a),
        Command::Palpate(a) => palpate::run(a),
        Command::Stiffness(a) => stiffness::run(a),
        Command::Flexibility(a) => flexibility::run(a),
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            crate::errln!("error: {e:#}");
            1
        }
    }
}
