//! The calibration cases the derivative checks share (included with
//! `#[path]` by `calibrate_jacobian.rs` and `calibrate_dtau_dp.rs`): the
//! dev-07 T12-S1 specimen, every parameterisation the calibration offers,
//! a test point away from the nominal values, and the error bound of a
//! central difference.

use nalgebra::DMatrix;
use osim_spine::calibrate::experiment::Experiment;
use osim_spine::calibrate::family::{read_ratio_table, Parameterisation, Scale, StiffnessFamily};
use osim_spine::calibrate::forms::CurveForm;
use osim_spine::calibrate::measure::Convention;
use osim_spine::calibrate::problem::Problem;
use osim_spine::calibrate::setup::{build_problem, Setup};
use std::sync::Arc;

/// The dev-07 experiment (T12-S1, 24 load cases), or `None` with a printed
/// reason (a failure under CI).
pub fn experiment() -> Option<Experiment> {
    let dir = super::common::shared("diagnose-dev/dev-07")?;
    Some(Experiment::read(&dir).expect("dev-07 reads"))
}

/// Every parameterisation the calibration offers, with a label.
pub fn parameterisations() -> Vec<(&'static str, Parameterisation)> {
    let ratios = super::common::repo_root().join("templates/level_ratios_zhang.toml");
    let nonlinear = |curve, per_level| Parameterisation::Nonlinear { curve, per_level };
    vec![
        ("uniform", Parameterisation::Uniform),
        (
            "ratio",
            Parameterisation::Ratio(read_ratio_table(&ratios).expect("ratio table reads")),
        ),
        ("per-level", Parameterisation::PerLevel),
        ("nonlinear:sinh", nonlinear(CurveForm::Sinh, false)),
        ("nonlinear:cubic", nonlinear(CurveForm::Cubic, false)),
        ("nonlinear:sinh:per-level", nonlinear(CurveForm::Sinh, true)),
        (
            "nonlinear:cubic:per-level",
            nonlinear(CurveForm::Cubic, true),
        ),
        ("coupled", Parameterisation::Coupled),
    ]
}

/// The problem set-ups of each parameterisation: rotations with the
/// composed increments (the default), and rotations plus translations
/// (translational stiffness fitted too) with the difference increments,
/// where the parameterisation has translations (a ratio table may give
/// rotations only).
pub fn setups() -> Vec<(String, Setup)> {
    let mut out = Vec::new();
    for (label, params) in parameterisations() {
        out.push((
            label.to_string(),
            Setup {
                params: params.clone(),
                ..Setup::default()
            },
        ));
        if let Parameterisation::Ratio(table) = &params {
            if table.values().any(|v| v[3..].iter().any(Option::is_none)) {
                continue;
            }
        }
        out.push((
            format!("{label} +translations, difference"),
            Setup {
                params,
                translations: true,
                convention: Convention::Difference,
                ..Setup::default()
            },
        ));
    }
    out
}

/// The problem and family of `setup` on `exp`.
pub fn problem(exp: &Experiment, setup: &Setup) -> (Problem, Arc<StiffnessFamily>) {
    build_problem(Arc::new(exp.clone()), setup).expect("problem builds")
}

/// A point away from the nominal values (each fitting coordinate moved by a
/// different amount, inside the bounds), so no derivative vanishes by
/// symmetry.
pub fn test_point(fam: &StiffnessFamily) -> Vec<f64> {
    fam.params_info()
        .iter()
        .enumerate()
        .map(|(j, info)| {
            let shift = 0.15 * ((j as f64 * 1.7).sin() + 0.5);
            let x = match info.scale {
                Scale::Log => info.to_fit(info.nominal) + shift,
                Scale::Log1p => (0.3 + 0.2 * shift.abs()).ln_1p(),
                Scale::Linear => 0.2 * shift,
            };
            let (lo, hi) = info.fit_bounds();
            x.clamp(lo + 1e-3 * (hi - lo), hi - 1e-3 * (hi - lo))
        })
        .collect()
}

/// Largest entry of `|a - b|` against the largest entry of `|b|` (the
/// scale on which the rounding of a central difference is bounded: a
/// column that barely moves the output carries the rounding of the whole
/// residual, not of its own size).
pub fn relative_gap(a: &DMatrix<f64>, b: &DMatrix<f64>) -> f64 {
    let scale = b.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    (a - b).iter().fold(0.0f64, |m, v| m.max(v.abs())) / scale
}

/// Bound on the relative error of a central difference with relative step
/// `h` of a smooth function evaluated to machine precision: truncation
/// `h^2 / 6 |f'''| / |f'|` plus rounding `eps |f| / (h |f'|)`. Both ratios
/// of derivatives are of order one on the fitting scale (log-stiffness,
/// shape parameters of order one); `SAFETY` = 1000 covers them and the
/// conditioning of the equilibrium solves (for `h` = 1e-6 the bound is
/// 2.2e-7, where a wrong or missing term of the derivative shows as a gap
/// of its own relative size).
pub fn central_difference_tolerance(h: f64) -> f64 {
    const SAFETY: f64 = 1000.0;
    SAFETY * (h * h / 6.0 + f64::EPSILON / h)
}
