//! Sim-to-real gap diagnosis (`osim-spine diagnose EXPERIMENT --out DIR`):
//! where a re-fitted nominal model still disagrees with measured
//! kinematics, which unmodelled effect causes it, and how far the gap
//! shrinks on held-out load cases once that effect is added.
//!
//! | file | what lives there |
//! |---|---|
//! | `sim` | [`sim::Sim`]: the experiment as simulated (levels, prepared loads, measured cells), predictions of a model variant |
//! | `family` | [`family::Family`]: baseline and candidate effects as parametric extensions (laws, joint frames) |
//! | `law` | [`law::LawParts`]: one level's law from what the effects contribute (native law for one, an expression law for several) |
//! | `fit` | weighted least squares of a family on the training cells (LM, finite-difference Jacobian) |
//! | `design` | [`design::Design`]: case structure, held-out split, effects the design cannot test |
//! | `stages` | the fits of a diagnosis: candidates on the training cells, per fold of a K-fold design (out-of-fold predictions), mixed-effect pairs |
//! | `gap` | the held-out gap: held-out cells, RMSE, where the baseline's gap sits |
//! | `mixed` | two effects fitted together, kept when they explain significantly more of the held-out gap; the share of each (`verdict.effects`) |
//! | `other` | what the augmented model leaves of the held-out gap and its structure (by level, DoF, load, protocol order): the `other` verdict |
//! | `ratios` | the fitted stiffness ratios (trend along the spine, direction asymmetry, level factors) with 95% intervals |
//! | `select` | [`select::diagnose`]: the procedure, noise estimate, criterion, verdict, gap decomposition |
//! | `synth` | synthetic labelled experiments (truth = nominal + one random effect, solved by the crate's solver, plus noise) for testing generality |
//! | `report` | `diagnosis.json`, Markdown, SVG figures, the improved `.osim` |

pub mod criteria;
pub mod design;
pub mod family;
pub mod fit;
pub mod gap;
pub mod law;
pub mod mixed;
pub mod noise;
pub mod other;
pub mod outcome;
pub mod ratios;
pub mod report;
pub mod select;
pub mod sim;
pub mod stages;
pub mod synth;

use crate::calibrate::experiment::Experiment;
use crate::error::Result;
use std::path::{Path, PathBuf};

/// Everything a diagnosis writes into `out`, computed in memory (paths,
/// bytes), and the specimen's meshes found nowhere (dropped from the
/// improved model).
#[allow(clippy::type_complexity)]
pub fn outputs(
    exp: &Experiment,
    o: &select::Outcome,
    out: &Path,
) -> Result<(Vec<(PathBuf, Vec<u8>)>, Vec<String>)> {
    let aug = o.augmented();
    let variant = aug.family.variant(&o.sim, &aug.x)?;
    let doc = report::improved_model(&o.sim, exp, &variant)?;
    let model_name = "improved.osim";
    let json = report::diagnosis_json(o, exp, Some(model_name));
    let md = report::markdown(o, exp, &json);
    let mut text = serde_json::to_string_pretty(&json)
        .map_err(|e| crate::Error::invalid("diagnosis.json", e.to_string()))?;
    text.push('\n');
    let mut files: Vec<(PathBuf, Vec<u8>)> = vec![
        (out.join("diagnosis.json"), text.into_bytes()),
        (out.join("report.md"), md.into_bytes()),
        (
            out.join("residual_map.svg"),
            report::residual_map_svg(o, exp).into_bytes(),
        ),
        (
            out.join("curves.svg"),
            report::curves_svg(o, exp).into_bytes(),
        ),
    ];
    // The improved model with the specimen's meshes (copied or dropped).
    let (model_files, missing) = doc.files_for(&out.join(model_name), &[], false)?;
    files.extend(model_files);
    Ok((files, missing))
}

/// Read, diagnose and write `out/` (all outputs computed before any is
/// written); returns the outcome and the specimen's meshes found nowhere.
pub fn run(
    experiment: &Path,
    out: &Path,
    opts: &select::Options,
) -> Result<(select::Outcome, Vec<String>)> {
    let exp = Experiment::read(experiment)?;
    let o = select::diagnose(&exp, opts)?;
    let (files, missing) = outputs(&exp, &o, out)?;
    crate::util::write_all_or_nothing(&files)?;
    Ok((o, missing))
}
