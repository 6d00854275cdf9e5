//! `osim-spine calibrate EXPERIMENT [--params uniform|ratio:TABLE|per-level|
//! nonlinear:sinh|nonlinear:cubic[:per-level]|coupled]
//! [--dofs rx,ry,rz,...] [--translations] [--weights rx=1,...] [--starts N]
//! [--seed S] [--jobs N] [--loco] [--loso EXP...] --out DIR`: stiffness
//! calibration from measured kinematics. Writes `calibrated.osim`,
//! `report.json`, `fit.svg` and `params.svg`, all computed before anything is
//! written.

use crate::calibrate::experiment::{Experiment, DOF_NAMES};
use crate::calibrate::fit::{self, error_table, Calibration, FitOptions};
use crate::calibrate::measure::Convention;
use crate::calibrate::problem::Problem;
use crate::calibrate::report::{self, FitSummary};
use crate::calibrate::setup::{self, Setup};
use crate::calibrate::validate;
use crate::solver::{BushingModel, Curve};
use crate::util::write_all_or_nothing;
use anyhow::Context;
use clap::Args as ClapArgs;
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Arc;

/// Arguments of `calibrate`.
#[derive(Debug, ClapArgs)]
pub struct Args {
    /// Experiment folder (experiment.toml, kinematics.csv, model).
    pub experiment: PathBuf,
    /// Parameterisation: uniform (one value per DoF for all levels),
    /// ratio:TABLE (a base value per DoF times fixed level ratios, TOML or
    /// CSV level,rx,ry,rz; e.g. templates/level_ratios_zhang.toml),
    /// per-level (independent values), nonlinear:sinh or nonlinear:cubic
    /// (uniform slope k_d plus one stiffening s_d per rotational DoF:
    /// tangent stiffness at the largest measured rotation = (1 + s_d) k_d;
    /// append :per-level for per-level slopes; written as
    /// ExpressionBasedBushingForce / FunctionBasedBushingForce) or coupled
    /// (uniform k_d plus correlations rho_rx_ry, rho_rx_rz and partial
    /// rho_ry_rz|rx of the rotational stiffness, positive definite by
    /// construction; written as ExpressionBasedBushingForce).
    #[arg(long, default_value = "uniform", value_name = "KIND")]
    pub params: String,
    /// DoFs in the cost (default: the measured rotations, plus the measured
    /// translations with --translations). Rotational ones get a stiffness parameter.
    #[arg(long, value_name = "rx,ry,rz,...")]
    pub dofs: Option<String>,
    /// Also calibrate translational stiffness.
    #[arg(long)]
    pub translations: bool,
    /// Weights per DoF (default 1 / RMS of the measured motion in the DoF, squared).
    #[arg(long, value_name = "rx=1,...")]
    pub weights: Option<String>,
    /// Number of starts (the nominal model plus a Latin hypercube over the bounds).
    #[arg(long, default_value_t = 16)]
    pub starts: usize,
    /// Seed of the Latin hypercube.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub jobs: Option<usize>,
    /// How measured increments are formed: composed (the format's
    /// definition) or difference (upper's rotation vector minus lower's).
    #[arg(long, default_value = "composed")]
    pub convention: Convention,
    /// Leave-one-case-out validation.
    #[arg(long)]
    pub loco: bool,
    /// Other experiments for leave-one-specimen-out validation (each is
    /// calibrated with the same options; predicted with the median of the others).
    #[arg(long, num_args = 1.., value_name = "EXPERIMENT")]
    pub loso: Vec<PathBuf>,
    /// Output folder.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Allow the output to go where an input is (it may be replaced).
    #[arg(long)]
    pub force: bool,
}

#[derive(Debug, Serialize)]
struct ExperimentInfo {
    name: String,
    dir: String,
    model: String,
    fixed_body: String,
    gravity: bool,
    units: crate::calibrate::experiment::Units,
    cases: usize,
    rows: usize,
    warnings: Vec<String>,
}

#[derive(Debug, Serialize)]
struct OptionsInfo {
    params: String,
    cost_dofs: Vec<&'static str>,
    weights: BTreeMap<&'static str, f64>,
    convention: Convention,
    starts: usize,
    seed: u64,
}

#[derive(Debug, Serialize)]
struct LosoSpecimen {
    experiment: String,
    calibrated: Vec<f64>,
}

#[derive(Debug, Serialize)]
struct Validation {
    #[serde(skip_serializing_if = "Option::is_none")]
    leave_one_case_out: Option<validate::LeaveOneCaseOut>,
    #[serde(skip_serializing_if = "Option::is_none")]
    leave_one_specimen_out: Option<Vec<validate::HeldOutSpecimen>>,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    specimens: Vec<LosoSpecimen>,
}

#[derive(Debug, Serialize)]
struct Report<'a> {
    tool: &'static str,
    experiment: ExperimentInfo,
    options: OptionsInfo,
    levels: Vec<crate::calibrate::family::SystemLevel>,
    calibration: &'a Calibration,
    fit: FitSummary,
    nominal_fit: FitSummary,
    /// Linear part (slope at zero / diagonal) of every calibrated level.
    stiffness: BTreeMap<String, [f64; 6]>,
    /// The calibrated law of every level (non-linear and coupled forms).
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    laws: BTreeMap<String, serde_json::Value>,
    validation: Validation,
    rows: Vec<report::RowOut>,
}

fn summary(pb: &Problem, pred: &[[f64; 6]]) -> FitSummary {
    let t = error_table(pb, pred, |_| true);
    let tr = t.pooled(false);
    FitSummary {
        rotation_rmse: t.pooled(true),
        translation_rmse: tr.is_finite().then_some(tr),
        per_case: report::case_errors(pb, pred),
        per_level_dof: t,
    }
}

/// A JSON description of a calibrated law (curves per DoF or the 6x6 matrix).
fn law_json(m: &BushingModel) -> serde_json::Value {
    use serde_json::json;
    match m {
        BushingModel::PerDof { curves, .. } => {
            let c: BTreeMap<&str, serde_json::Value> = curves
                .iter()
                .zip(DOF_NAMES)
                .map(|(c, d)| {
                    let v = match c {
                        Curve::Linear { k } => json!({"kind": "linear", "k": k}),
                        Curve::Cubic { k, c } => json!({"kind": "cubic", "k": k, "c": c}),
                        Curve::Sinh { k, a } => json!({"kind": "sinh", "k": k, "a": a}),
                        Curve::Bilinear { k_neg, k_pos } => {
                            json!({"kind": "bilinear", "k_neg": k_neg, "k_pos": k_pos})
                        }
                        Curve::Function(_) => json!({"kind": "function"}),
                    };
                    (d, v)
                })
                .collect();
            json!({"form": "nonlinear", "curves": c})
        }
        BushingModel::Coupled { stiffness, .. } => {
            let rows: Vec<Vec<f64>> = (0..6)
                .map(|i| (0..6).map(|j| stiffness[(i, j)]).collect())
                .collect();
            json!({"form": "coupled", "matrix": rows})
        }
        _ => json!({"form": "linear", "stiffness": m.stiffness_params()}),
    }
}

fn setup_from(a: &Args) -> anyhow::Result<Setup> {
    Ok(Setup {
        params: setup::parse_params(&a.params)?,
        dofs: a.dofs.as_deref().map(setup::parse_dofs).transpose()?,
        translations: a.translations,
        weights: match &a.weights {
            Some(w) => setup::parse_weights(w)?,
            None => [None; 6],
        },
        convention: a.convention,
    })
}

/// Run `calibrate`.
pub fn run(a: Args) -> anyhow::Result<i32> {
    // Never write into a folder that holds an input.
    let protected = crate::util::guard::Protected::default()
        .inputs(std::iter::once(&a.experiment).chain(&a.loso));
    crate::util::guard::check_output_dir(&a.out, &protected, a.force)?;
    super::with_jobs(a.jobs, || run_inner(&a))
}

fn run_inner(a: &Args) -> anyhow::Result<i32> {
    let setup = setup_from(a)?;
    let exp = Arc::new(Experiment::read(&a.experiment)?);
    for w in &exp.warnings {
        crate::errln!("warning: {w}");
    }
    let (pb, fam) = setup::build_problem(exp.clone(), &setup)?;
    let fopts = FitOptions {
        starts: a.starts,
        seed: a.seed,
        progress: true,
        ..FitOptions::default()
    };
    crate::errln!(
        "calibrate: {} ({} cases, {} residuals), {} parameters ({}), {} starts",
        exp.name,
        exp.cases.len(),
        pb.cells.len(),
        pb.n_params(),
        fam.label_str(),
        a.starts
    );
    let cal = fit::calibrate(&pb, &fopts)?;
    let mut ev = pb.evaluator();
    let nominal: Vec<f64> = fam.params_nominal();
    let nominal_pred = ev
        .predict(&pb, &nominal)
        .context("solving the nominal model")?;
    let loco = if a.loco {
        crate::errln!("calibrate: leave-one-case-out ...");
        Some(validate::leave_one_case_out(&pb, &cal.best, &fopts)?)
    } else {
        None
    };
    let (loso, specimens) = leave_one_specimen_out(a, &setup, &pb, &cal, &fopts)?;
    // calibrated model
    let stiff = fam.bushing_stiffness(&cal.best);
    let names: Vec<String> = pb.system().bushing_names().map(String::from).collect();
    let level_values: Vec<(String, [f64; 6])> = fam
        .levels
        .iter()
        .filter_map(|l| Some((names.get(l.bushing.0)?.clone(), *stiff.get(l.bushing.0)?)))
        .collect();
    let doc = report::calibrated_document(&exp, &fam, pb.system(), &cal.best)?;
    let laws: BTreeMap<String, serde_json::Value> = fam
        .level_models(&cal.best)
        .iter()
        .filter_map(|(b, m)| Some((names.get(b.0)?.clone(), law_json(m))))
        .collect();
    let rep = Report {
        tool: concat!("osim-spine ", env!("CARGO_PKG_VERSION")),
        experiment: experiment_info(&exp),
        options: OptionsInfo {
            params: a.params.clone(),
            cost_dofs: pb.opts.dofs.iter().map(|&d| DOF_NAMES[d]).collect(),
            weights: pb
                .opts
                .dofs
                .iter()
                .map(|&d| (DOF_NAMES[d], pb.weights[d]))
                .collect(),
            convention: a.convention,
            starts: a.starts,
            seed: a.seed,
        },
        levels: fam.levels.clone(),
        calibration: &cal,
        fit: summary(&pb, &cal.predictions),
        nominal_fit: summary(&pb, &nominal_pred),
        stiffness: level_values.iter().cloned().collect(),
        laws: if fam.is_linear() {
            BTreeMap::new()
        } else {
            laws
        },
        validation: Validation {
            leave_one_case_out: loco,
            leave_one_specimen_out: loso,
            specimens,
        },
        rows: report::rows_out(&pb, &cal.predictions),
    };
    let json = serde_json::to_string_pretty(&rep)? + "\n";
    let fit_svg = report::fit_svg(
        &pb,
        &cal.predictions,
        &format!("{}: calibrated ({})", exp.name, a.params),
    );
    let params_svg = report::params_svg(&cal, &format!("{}: parameters ({})", exp.name, a.params));
    let model_out = a.out.join("calibrated.osim");
    let (mut files, missing) = doc.files_for(&model_out, &[], false)?;
    files.extend([
        (a.out.join("report.json"), json.into_bytes()),
        (a.out.join("fit.svg"), fit_svg.into_bytes()),
        (a.out.join("params.svg"), params_svg.into_bytes()),
    ]);
    write_all_or_nothing(&files)?;
    super::warn_missing_meshes(&model_out, &missing, false);
    print_summary(&rep, &cal, a.starts, exp.units.angle);
    crate::errln!("calibrate: written to {}", a.out.display());
    Ok(0)
}

/// `--loso`: calibrate each other experiment alone, then predict each
/// specimen with the median of the others' parameters.
#[allow(clippy::type_complexity)]
fn leave_one_specimen_out(
    a: &Args,
    setup: &Setup,
    pb: &Problem,
    cal: &Calibration,
    fopts: &FitOptions,
) -> anyhow::Result<(Option<Vec<validate::HeldOutSpecimen>>, Vec<LosoSpecimen>)> {
    let mut specimens = Vec::new();
    let loso = if a.loso.is_empty() {
        None
    } else {
        let mut items: Vec<(Problem, Vec<f64>)> = vec![(pb.clone(), cal.best.clone())];
        for dir in &a.loso {
            crate::errln!(
                "calibrate: leave-one-specimen-out: calibrating {} ...",
                dir.display()
            );
            let e = Arc::new(Experiment::read(dir)?);
            let (p2, _) = setup::build_problem(e, setup)?;
            let c2 = fit::calibrate(
                &p2,
                &FitOptions {
                    progress: false,
                    ..fopts.clone()
                },
            )
            .with_context(|| format!("calibrating {}", dir.display()))?;
            specimens.push(LosoSpecimen {
                experiment: p2.exp.name.clone(),
                calibrated: c2.best.clone(),
            });
            items.push((p2, c2.best));
        }
        Some(validate::leave_one_specimen_out(&items)?)
    };
    Ok((loso, specimens))
}

/// The experiment as the report describes it (file names only: the report
/// is the same wherever the experiment lies).
fn experiment_info(exp: &Experiment) -> ExperimentInfo {
    ExperimentInfo {
        name: exp.name.clone(),
        // Names only: the report is the same wherever the experiment lies.
        dir: file_name_of(&exp.dir),
        model: file_name_of(&exp.model_path),
        fixed_body: exp.fixed_body.clone(),
        gravity: exp.gravity,
        units: exp.units,
        cases: exp.cases.len(),
        rows: exp.rows.len(),
        warnings: exp.warnings.clone(),
    }
}

/// The console summary: fit, estimates with their 95% CIs, held-out
/// errors, and every parameter the data cannot determine.
fn print_summary(rep: &Report, cal: &Calibration, starts: usize, unit: &str) {
    crate::errln!(
        "calibrate: rotation RMSE {:.4} {unit} (nominal model {:.4} {unit}); {} local minim{} from {} starts{}; condition number {:.3e}",
        rep.fit.rotation_rmse,
        rep.nominal_fit.rotation_rmse,
        cal.minima.len(),
        if cal.minima.len() == 1 { "um" } else { "a" },
        starts,
        match cal.starts.iter().filter(|s| !s.converged).count() {
            0 => String::new(),
            k => format!(" ({k} start(s) did not converge: see report.json)"),
        },
        cal.identifiability.condition_number
    );
    for e in &cal.estimates {
        crate::errln!(
            "  {:<14} {:>12.4} {}  95% CI [{:.4}, {:.4}]{}",
            e.name,
            e.value,
            e.unit,
            e.ci95[0],
            e.ci95[1],
            if e.at_bound { "  (at bound)" } else { "" }
        );
    }
    print_validation(&rep.validation, unit);
    for p in &cal.identifiability.poorly_determined {
        crate::errln!(
            "warning: parameter {} is poorly determined: {}",
            p.name,
            p.reason
        );
    }
}

/// The held-out errors of `--loco` and `--loso`: pooled rotation RMSE and
/// the worst level/DoF, per held-out specimen for `--loso`.
fn print_validation(v: &Validation, unit: &str) {
    let line = |label: String, t: &crate::calibrate::fit::ErrorTable| {
        let worst = t
            .entries
            .iter()
            .max_by(|a, b| a.rmse_in_unit.total_cmp(&b.rmse_in_unit));
        let worst = worst
            .map(|e| {
                format!(
                    "; worst {} {} {:.4} {}",
                    e.pair, e.dof, e.rmse_in_unit, e.unit
                )
            })
            .unwrap_or_default();
        crate::errln!(
            "{label}: held-out rotation RMSE {:.4} {unit}{worst}",
            t.pooled(true)
        );
    };
    if let Some(l) = &v.leave_one_case_out {
        line(
            format!(
                "leave-one-case-out ({} cases held out in turn)",
                l.cases.len()
            ),
            &l.errors,
        );
    }
    for h in v.leave_one_specimen_out.iter().flatten() {
        line(
            format!("leave-one-specimen-out: {}", h.experiment),
            &h.errors,
        );
    }
}

/// The last component of `p` (the whole path when it has none).
fn file_name_of(p: &std::path::Path) -> String {
    p.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| p.display().to_string())
}
