//! From user choices to a [`Problem`]: parsing of `--params`, `--dofs`,
//! `--weights`, the levels of the experiment and the stiffness family.

use super::experiment::{dof_index, Experiment, DOF_NAMES};
use super::family::{find_levels, read_ratio_table, Parameterisation, StiffnessFamily};
use super::forms::{reference_rotations, CurveForm};
use super::measure::Convention;
use super::problem::{Problem, ProblemOptions};
use crate::error::{Error, Result};
use crate::solver::System;
use std::path::Path;
use std::sync::Arc;

/// What to calibrate and against what.
#[derive(Debug, Clone)]
pub struct Setup {
    /// The stiffness parameterisation fitted (`--params`).
    pub params: Parameterisation,
    /// DoFs in the cost; `None` = every measured rotational DoF (plus the
    /// measured translations with `translations`).
    pub dofs: Option<Vec<usize>>,
    /// Also fit translational stiffness (and put measured translations in the cost).
    pub translations: bool,
    /// Per-DoF weights (`--weights`, order rx ry rz tx ty tz); `None` = from
    /// the stated SD, else 1 / (RMS of the measured motion)^2.
    pub weights: [Option<f64>; 6],
    /// How measured increments are formed from the two bodies' motions.
    pub convention: Convention,
}

impl Default for Setup {
    fn default() -> Self {
        Setup {
            params: Parameterisation::Uniform,
            dofs: None,
            translations: false,
            weights: [None; 6],
            convention: Convention::Composed,
        }
    }
}

/// The accepted `--params` values, for messages.
const PARAMS_HELP: &str = "uniform, per-level, ratio:TABLE, nonlinear:sinh, nonlinear:cubic, nonlinear:sinh:per-level, nonlinear:cubic:per-level or coupled";

/// Parse `uniform`, `per-level`, `ratio:FILE` (FILE relative to the
/// working directory), `nonlinear:sinh|cubic[:per-level]` or `coupled`.
pub fn parse_params(s: &str) -> Result<Parameterisation> {
    let nonlinear = |curve, per_level| Ok(Parameterisation::Nonlinear { curve, per_level });
    match s {
        "uniform" => Ok(Parameterisation::Uniform),
        "per-level" => Ok(Parameterisation::PerLevel),
        "nonlinear:sinh" => nonlinear(CurveForm::Sinh, false),
        "nonlinear:cubic" => nonlinear(CurveForm::Cubic, false),
        "nonlinear:sinh:per-level" => nonlinear(CurveForm::Sinh, true),
        "nonlinear:cubic:per-level" => nonlinear(CurveForm::Cubic, true),
        "coupled" => Ok(Parameterisation::Coupled),
        _ => match s.strip_prefix("ratio:") {
            Some(f) if !f.is_empty() => {
                Ok(Parameterisation::Ratio(read_ratio_table(Path::new(f))?))
            }
            _ => Err(Error::invalid(
                "--params",
                format!("expected {PARAMS_HELP}, got '{s}'"),
            )),
        },
    }
}

/// Parse a comma-separated DoF list (`rx,ry,rz`).
pub fn parse_dofs(s: &str) -> Result<Vec<usize>> {
    let mut out = Vec::new();
    for t in s.split(',').map(str::trim).filter(|t| !t.is_empty()) {
        let Some(d) = dof_index(t) else {
            return Err(Error::invalid(
                "--dofs",
                format!("unknown DoF '{t}' (use rx,ry,rz,tx,ty,tz)"),
            ));
        };
        if !out.contains(&d) {
            out.push(d);
        }
    }
    if out.is_empty() {
        return Err(Error::invalid("--dofs", "no DoF given"));
    }
    out.sort_unstable();
    Ok(out)
}

/// Parse `rx=1,ry=2.5` into per-DoF weights.
pub fn parse_weights(s: &str) -> Result<[Option<f64>; 6]> {
    let mut w = [None; 6];
    for t in s.split(',').map(str::trim).filter(|t| !t.is_empty()) {
        let Some((k, v)) = t.split_once('=') else {
            return Err(Error::invalid(
                "--weights",
                format!("expected DOF=VALUE, got '{t}'"),
            ));
        };
        let Some(d) = dof_index(k.trim()) else {
            return Err(Error::invalid("--weights", format!("unknown DoF '{k}'")));
        };
        let x: f64 = v
            .trim()
            .parse()
            .map_err(|_| Error::invalid("--weights", format!("'{v}' is not a number")))?;
        if !(x.is_finite() && x >= 0.0) {
            return Err(Error::invalid(
                "--weights",
                format!("weight of {k} must be >= 0, got {x}"),
            ));
        }
        w[d] = Some(x);
    }
    Ok(w)
}

/// Build the stiffness family and the problem for an experiment, using
/// `sys` (the experiment's system, possibly with perturbed joint frames).
pub fn build_problem_with(
    exp: Arc<Experiment>,
    setup: &Setup,
    sys: System,
) -> Result<(Problem, Arc<StiffnessFamily>)> {
    let measured = exp.measured_dofs();
    if measured.is_empty() {
        return Err(Error::invalid(
            format!("experiment {}", exp.dir.display()),
            "kinematics.csv has no measured value: every rx .. tz cell is empty (nothing to calibrate against)",
        ));
    }
    let dofs = match &setup.dofs {
        Some(d) => d.clone(),
        None => {
            let mut d: Vec<usize> = measured.iter().copied().filter(|&d| d < 3).collect();
            if setup.translations {
                d.extend(measured.iter().copied().filter(|&d| d >= 3));
            }
            d
        }
    };
    let mut param_dofs: Vec<usize> = dofs.iter().copied().filter(|&d| d < 3).collect();
    if setup.translations {
        param_dofs.extend(3..6);
    }
    if param_dofs.is_empty() {
        return Err(Error::invalid(
            "calibration",
            format!(
                "no stiffness parameter: the cost DoFs ({}) contain no rotation and --translations is off",
                dofs.iter().map(|&d| DOF_NAMES[d]).collect::<Vec<_>>().join(",")
            ),
        ));
    }
    let fixed = sys.body_index(&exp.fixed_body).ok_or_else(|| {
        Error::invalid(
            "calibration",
            format!("fixed body '{}' not in the system", exp.fixed_body),
        )
    })?;
    let mut loaded = Vec::new();
    for c in &exp.cases {
        loaded.push(sys.body_index(&c.body).ok_or_else(|| {
            Error::invalid(
                format!("case '{}'", c.id),
                format!("body '{}' not in the system", c.body),
            )
        })?);
    }
    let levels = find_levels(&sys, fixed, &loaded);
    let mut fam = StiffnessFamily::new(&sys, levels, &param_dofs, &setup.params)?;
    // stiffening parameters are defined at the largest measured rotation
    fam.set_reference_rotations(reference_rotations(exp.rows.iter().flat_map(|r| {
        r.values
            .iter()
            .enumerate()
            .filter_map(|(d, v)| v.map(|v| (d, v)))
    })));
    let fam = Arc::new(fam);
    let opts = ProblemOptions {
        dofs,
        weights: setup.weights,
        convention: setup.convention,
    };
    let pb = Problem::with_system(exp, fam.clone(), opts, sys)?;
    Ok((pb, fam))
}

/// [`build_problem_with`] on the experiment's own system.
pub fn build_problem(
    exp: Arc<Experiment>,
    setup: &Setup,
) -> Result<(Problem, Arc<StiffnessFamily>)> {
    let sys = System::new(&exp.spec)?;
    build_problem_with(exp, setup, sys)
}
