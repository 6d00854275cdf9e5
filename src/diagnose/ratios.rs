//! The fitted stiffness ratios of a model with their uncertainty: the
//! trend along the spine (the level next to the fixed body against the
//! farthest one), the direction asymmetry (one side against the other),
//! level factors; each with a 95% interval from the fit's parameter
//! standard errors (Gauss-Newton, in log space), inflated by the training
//! misfit when the model fits worse than the noise.

use super::family::trend_span;
use super::fit::Fitted;
use super::sim::Sim;
use serde::Serialize;

/// One fitted ratio.
#[derive(Debug, Clone, Serialize)]
pub struct Ratio {
    /// What it compares (`L5_S1/L1_L2 rz`, `rz neg/pos`).
    pub quantity: String,
    /// The fitted ratio.
    pub ratio: f64,
    /// 95% interval.
    pub ci95: [f64; 2],
    /// In words: "L5_S1 flexion/extension stiffness 0.56 x L1_L2 [0.42, 0.75]".
    pub text: String,
}

const DOF3: [&str; 3] = ["rx", "ry", "rz"];
/// Names of the rotational DoFs.
const DOF_WORDS: [&str; 3] = ["lateral bending", "axial rotation", "flexion/extension"];
/// The negative and positive direction of each rotational DoF (format
/// axes: X anterior, Y cranial, Z right; a negative moment about Z is
/// flexion, a positive one about X right lateral bending, a positive one
/// about Y left axial rotation).
const SIDES: [[&str; 2]; 3] = [
    ["left lateral bending", "right lateral bending"],
    ["right axial rotation", "left axial rotation"],
    ["flexion", "extension"],
];

/// z of the 95% interval.
const Z95: f64 = 1.959964;

/// A ratio `exp(scale * v)` of a log-parameter `v` with standard error `se`.
fn ratio(
    quantity: String,
    v: f64,
    se: f64,
    scale: f64,
    words: &dyn Fn(f64, [f64; 2]) -> String,
) -> Ratio {
    let r = (scale * v).exp();
    let h = (Z95 * se * scale.abs()).abs();
    let ci95 = if h.is_finite() {
        [(scale * v - h).exp(), (scale * v + h).exp()]
    } else {
        [f64::NAN, f64::NAN]
    };
    Ratio {
        quantity,
        ratio: r,
        text: words(r, ci95),
        ci95,
    }
}

/// `[lo, hi]`, or "interval not determined".
fn interval(ci: [f64; 2]) -> String {
    if ci.iter().all(|v| v.is_finite()) {
        format!("[{:.2}, {:.2}]", ci[0], ci[1])
    } else {
        "[interval not determined]".to_string()
    }
}

/// The ratios of the fit `f` (trend, asymmetry and level-factor
/// parameters), the standard errors multiplied by `inflate` (at least 1:
/// the square root of the training reduced chi-square when above 1).
pub fn of_fit(sim: &Sim, f: &Fitted, inflate: f64) -> Vec<Ratio> {
    let mut out = Vec::new();
    let inflate = inflate.max(1.0);
    for (i, name) in f.family.names.iter().enumerate() {
        let (Some(&v), se) = (
            f.x.get(i),
            f.se.get(i).copied().unwrap_or(f64::NAN) * inflate,
        ) else {
            continue;
        };
        let (lvl, key) = match name.split_once('.') {
            Some((l, k)) => (Some(l), k),
            None => (None, name.as_str()),
        };
        let trend = key
            .strip_prefix("trend_log_k_")
            .and_then(|k| k.strip_suffix("_per_level"));
        let dof = DOF3
            .iter()
            .position(|d| key.ends_with(d) || trend == Some(d));
        if let (Some(d), true) = (dof, trend.is_some()) {
            // the level next to the fixed body against the farthest one
            let Some((near, far)) = trend_span(sim) else {
                continue;
            };
            let span = sim.position[far] - sim.position[near];
            let (n, fa) = (&sim.levels[near].level.name, &sim.levels[far].level.name);
            let words = |r: f64, ci: [f64; 2]| {
                format!(
                    "{n} {} stiffness {r:.2} x {fa} {}",
                    DOF_WORDS[d],
                    interval(ci)
                )
            };
            out.push(ratio(format!("{n}/{fa} {}", DOF3[d]), v, se, -span, &words));
        } else if let (Some(d), true) = (dof, key.starts_with("log_kpos_over_kneg_")) {
            // k(negative side) / k(positive side) = exp(-v)
            let at = lvl.map(|l| format!("{l} ")).unwrap_or_default();
            let [neg, pos] = SIDES[d];
            let words = |r: f64, ci: [f64; 2]| {
                format!("{at}{neg} stiffness {r:.2} x {pos} {}", interval(ci))
            };
            out.push(ratio(
                format!("{at}{} neg/pos", DOF3[d]),
                v,
                se,
                -1.0,
                &words,
            ));
        } else if key == "log_m" {
            let (l, first) = (lvl.unwrap_or(""), &sim.levels[0].level.name);
            let words =
                |r: f64, ci: [f64; 2]| format!("{l} stiffness {r:.2} x {first} {}", interval(ci));
            out.push(ratio(format!("{l}/{first}"), v, se, 1.0, &words));
        }
    }
    out
}
