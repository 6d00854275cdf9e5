//! `osim-spine flexibility --model PATIENT.osim --film NEUTRAL.csv --film
//! LEFT.csv --film RIGHT.csv [--predict PARTIAL.csv ...] [--uniform] --out
//! DIR`: the patient's relative intervertebral stiffness from frontal
//! bending films. Writes `flexibility.json`, `stiffness.toml` (when
//! estimated), `predicted_<stem>.csv` per `--predict` film and `<stem>.svg`
//! per film, all computed before anything is written and written all or
//! none.

use crate::flexibility::{self, Flexibility, FlexibilityOptions, FlexibilityReport, Role};
use crate::landmarks::radiograph;
use crate::osim::Document;
use crate::util::guard::{check_output_dir, Protected};
use clap::Args as ClapArgs;
use std::collections::BTreeSet;
use std::path::PathBuf;

/// Arguments of `flexibility`.
#[derive(Debug, ClapArgs)]
pub struct Args {
    /// The patient model (.osim; from `generate`, with the femoral head
    /// markers FH_R / FH_L of its base).
    #[arg(long)]
    pub model: PathBuf,
    /// A full frontal film (radiograph format): the neutral one and the
    /// bending ones (repeat).
    #[arg(long = "film", value_name = "FILM.csv")]
    pub films: Vec<PathBuf>,
    /// A film of which only some levels are given (e.g. T1, S1 and the
    /// femoral heads): every other level is predicted (repeat).
    #[arg(long, value_name = "FILM.csv")]
    pub predict: Vec<PathBuf>,
    /// Predict with the model's own stiffness (the unpersonalised baseline);
    /// nothing is estimated.
    #[arg(long)]
    pub uniform: bool,
    /// Digitising noise per film coordinate (mm).
    #[arg(long, default_value_t = 1.0, value_name = "MM")]
    pub noise_mm: f64,
    /// SD of the Gaussian prior on each joint's natural-log stiffness
    /// multiplier (0: no prior).
    #[arg(long, default_value_t = flexibility::DEFAULT_PRIOR_SD, value_name = "SD")]
    pub prior_sd: f64,
    /// SD of the Gaussian prior on the difference of neighbouring joints'
    /// log multipliers (0: none).
    #[arg(long, default_value_t = 0.0, value_name = "SD")]
    pub step_sd: f64,
    /// Write the results even when a film contradicts the model.
    #[arg(long)]
    pub allow_mismatch: bool,
    /// Output folder.
    #[arg(long)]
    pub out: PathBuf,
    /// Allow the output folder to hold an input.
    #[arg(long)]
    pub force: bool,
}

/// Run `flexibility`; returns the exit code.
pub fn run(args: Args) -> anyhow::Result<i32> {
    // Inputs checked before anything is computed.
    if args.films.is_empty() && args.predict.is_empty() {
        anyhow::bail!(
            "give the films with --film (a neutral and the bending films) and/or --predict"
        );
    }
    if !(args.noise_mm.is_finite() && args.noise_mm > 0.0) {
        anyhow::bail!(
            "--noise-mm must be a positive number of mm, got {}",
            args.noise_mm
        );
    }
    if !(args.prior_sd.is_finite() && args.prior_sd >= 0.0) {
        anyhow::bail!(
            "--prior-sd must be >= 0 (0: no prior), got {}",
            args.prior_sd
        );
    }
    let inputs: Vec<PathBuf> = std::iter::once(args.model.clone())
        .chain(args.films.iter().cloned())
        .chain(args.predict.iter().cloned())
        .collect();
    check_output_dir(&args.out, &Protected::default().inputs(&inputs), args.force)?;
    let doc = Document::read(&args.model)?;
    let model = doc.model()?;
    let films = args
        .films
        .iter()
        .map(|p| radiograph::read(p))
        .collect::<crate::Result<Vec<_>>>()?;
    let predict = args
        .predict
        .iter()
        .map(|p| radiograph::read(p))
        .collect::<crate::Result<Vec<_>>>()?;
    let opts = FlexibilityOptions {
        noise: args.noise_mm * 1e-3,
        prior_sd: (args.prior_sd > 0.0).then_some(args.prior_sd),
        step_sd: (args.step_sd > 0.0).then_some(args.step_sd),
        uniform: args.uniform,
        allow_mismatch: args.allow_mismatch,
        progress: true,
    };
    let t0 = std::time::Instant::now();
    let flex = flexibility::flexibility(&model, &films, &predict, &opts)?;
    let files = outputs(&args, &flex)?;
    crate::util::write_all_or_nothing(&files)?;
    print_summary(&flex.report);
    crate::outln!(
        "wrote {} files to {} in {:.2} s",
        files.len(),
        args.out.display(),
        t0.elapsed().as_secs_f64()
    );
    Ok(0)
}

/// Every output file (path, bytes); distinct names.
fn outputs(args: &Args, flex: &Flexibility) -> anyhow::Result<Vec<(PathBuf, Vec<u8>)>> {
    let mut files = vec![(
        args.out.join("flexibility.json"),
        crate::util::report::to_json_pretty(&flex.report)?.into_bytes(),
    )];
    if let Some(t) = &flex.stiffness_toml {
        files.push((args.out.join("stiffness.toml"), t.clone().into_bytes()));
    }
    for (name, text) in flex.predicted.iter().chain(&flex.figures) {
        files.push((args.out.join(name), text.clone().into_bytes()));
    }
    let mut seen = BTreeSet::new();
    for (p, _) in &files {
        if !seen.insert(p.clone()) {
            anyhow::bail!(
                "two outputs would be written to {}: give the films distinct file names",
                p.display()
            );
        }
    }
    Ok(files)
}

/// The console summary: films, joints, regions, curves, findings.
fn print_summary(r: &FlexibilityReport) {
    crate::outln!("flexibility of {} ({} mode)", r.model, r.mode);
    for f in &r.films {
        let pers = f
            .personalised
            .as_ref()
            .map(|p| format!(", personalised {:.2} mm", p.rms_mm))
            .unwrap_or_default();
        crate::outln!(
            "film {} [{}]: {} points, loaded level {} moved {:.1} mm / {:.1} deg; RMS uniform {:.2} mm{pers}{}",
            f.file,
            match f.role {
                Role::Bending => "bending",
                Role::Unbent => "unbent",
                Role::Predict => "predict",
            },
            f.points,
            f.loaded_level,
            f.uniform.loaded_level_lateral_mm,
            f.uniform.loaded_level_tilt_deg,
            f.uniform.rms_mm,
            f.output
                .as_ref()
                .map(|o| format!(" -> {o}"))
                .unwrap_or_default()
        );
        for n in &f.notes {
            crate::outln!("  note: {n}");
        }
    }
    if let Some(e) = &r.estimate {
        crate::outln!(
            "estimate: {} joints from {} bending film(s), {} residuals, residual SD {:.2} x noise, {} LM iterations{}",
            e.joints_estimated,
            e.films.len(),
            e.residuals,
            e.residual_sd_in_noise,
            e.iterations,
            if e.converged { "" } else { " (NOT converged)" }
        );
        crate::outln!("{}", r.identifiability);
        crate::outln!("absolute scale: {}", r.absolute_scale);
    }
    for j in &r.joints {
        crate::outln!(
            "  {:8} relative stiffness {:6.2}  95% [{:5.2}, {:6.2}]{}",
            j.joint,
            j.relative_stiffness,
            j.ci95[0],
            j.ci95[1],
            if j.resolved { "" } else { "  (not resolved)" }
        );
    }
    for g in &r.regions {
        crate::outln!(
            "  region {}: {:.2} 95% [{:.2}, {:.2}]{}",
            g.region,
            g.relative_stiffness,
            g.ci95[0],
            g.ci95[1],
            if g.resolved { "" } else { " (not resolved)" }
        );
    }
    for c in &r.curves {
        crate::outln!(
            "curve {} {}-{} (on {}): {:.1} deg unbent",
            c.curve,
            c.upper,
            c.lower,
            c.defined_on,
            c.unbent_cobb_deg
        );
        for f in &c.films {
            let show = |x: Option<f64>| x.map(|v| format!("{v:.1}")).unwrap_or_else(|| "-".into());
            crate::outln!(
                "  {}: Cobb measured {} / personalised {} / uniform {} deg",
                f.film,
                show(f.measured_cobb_deg),
                show(f.personalised_cobb_deg),
                show(f.uniform_cobb_deg)
            );
        }
    }
    for f in &r.findings {
        crate::outln!("finding: {f}");
    }
}
