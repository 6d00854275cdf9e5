//! Joint-pose sensitivity study (thesis Chapter 3, "Sensitivity to joint
//! pose" and "Two-factor analysis"), done on the joint frames directly:
//!
//! 1. Landmark noise -> joint-frame perturbations, through the landmark frame
//!    construction of [`crate::landmarks::frames::vertebra_frame`]: a clean
//!    synthetic landmark set ([`crate::landmarks::synth`], normal spine) is
//!    perturbed with Gaussian noise of the given SD on every coordinate of
//!    every landmark (a stratified normal sample: Latin hypercube through
//!    the inverse normal CDF); each vertebra's frame is rebuilt and its change
//!    expressed in its own axes (origin offset, rotation vector). A joint's
//!    perturbation is the mean of its two vertebrae's (the sacrum, whose
//!    frame needs landmarks the protocol does not palpate on S1, contributes
//!    none).
//! 2. Each sample moves every level's joint frame (parent frame F and child
//!    frame M together, and the bushing frames with them, so the default
//!    pose of the bodies is unchanged) and the model is re-calibrated (LM
//!    from the unperturbed optimum). The measured increments are body-based,
//!    so the data are unchanged.
//! 3. Reduced dataset: samples whose fit failed (error, LM stalled or out of
//!    iterations) or gave a stiffness an order of magnitude above nominal
//!    are set aside.
//! 4. Two-factor analysis: the joint poses of the first `two_factor_poses`
//!    reduced samples crossed with the stiffness of the `two_factor_best`
//!    best-fitting ones (no re-optimisation); the rotation RMSE table is
//!    decomposed (two-way ANOVA without replication) into pose, stiffness
//!    and interaction (residual) sums of squares.

use super::fit::{self, error_table, FitOptions};
use super::lhs;
use super::problem::Problem;
use super::setup::{build_problem_with, Setup};
use crate::calibrate::experiment::Experiment;
use crate::error::{Error, Result};
use crate::landmarks::frames::vertebra_frame;
use crate::landmarks::synth::{generate, SynthOptions};
use crate::landmarks::{Code, Level};
use crate::solver::{System, SystemSpec};
use crate::util::lm::LmStop;
use nalgebra::{Isometry3, Rotation3, Translation3, UnitQuaternion, Vector3};
use rayon::prelude::*;
use serde::Serialize;
use std::sync::Arc;

/// Options of the study.
#[derive(Debug, Clone)]
pub struct SensitivityOptions {
    /// Number of landmark sets (joint-pose samples).
    pub samples: usize,
    /// Landmark SD per coordinate (m).
    pub landmark_sd: f64,
    /// Seed of the landmark noise sample.
    pub seed: u64,
    /// Number of reduced samples whose poses enter the two-factor analysis.
    pub two_factor_poses: usize,
    /// Number of best-fitting stiffness sets of the two-factor analysis.
    pub two_factor_best: usize,
    /// Show a progress bar on stderr.
    pub progress: bool,
}

impl Default for SensitivityOptions {
    fn default() -> Self {
        SensitivityOptions {
            samples: 500,
            landmark_sd: 0.001,
            seed: 1,
            two_factor_poses: 50,
            two_factor_best: 10,
            progress: false,
        }
    }
}

/// A joint frame perturbation in the joint frame's own axes.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct FramePerturbation {
    /// Origin offset (m).
    pub offset: [f64; 3],
    /// Rotation vector (rad).
    pub rotation: [f64; 3],
}

/// One sample of the study.
#[derive(Debug, Clone, Serialize)]
pub struct Sample {
    /// Position in the sample list.
    pub index: usize,
    /// Per level (family order).
    pub perturbations: Vec<FramePerturbation>,
    /// Mean over levels of |offset| (m) and |rotation| (rad).
    pub mean_offset: f64,
    /// Mean over levels of |rotation| (rad).
    pub mean_rotation: f64,
    /// Re-calibrated parameters (natural units); empty when the fit failed.
    pub params: Vec<f64>,
    /// Cost `sum r^2` at those parameters (NaN when the fit failed).
    pub cost: f64,
    /// Pooled rotation RMSE (experiment units).
    pub rotation_rmse: f64,
    /// In the reduced dataset.
    pub ok: bool,
    /// Why the sample was set aside, when it was.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
}

/// Distribution summary.
#[derive(Debug, Clone, Serialize)]
pub struct Spread {
    /// The quantity (a parameter name or `rotation_rmse`).
    pub name: String,
    /// Its value in the reference (unperturbed) calibration.
    pub reference: f64,
    /// Median over the reduced dataset.
    pub median: f64,
    /// 2.5th percentile.
    pub p2_5: f64,
    /// 25th percentile.
    pub p25: f64,
    /// 75th percentile.
    pub p75: f64,
    /// 97.5th percentile.
    pub p97_5: f64,
    /// Smallest value.
    pub min: f64,
    /// Largest value.
    pub max: f64,
    /// Pearson correlation with the mean joint offset.
    pub corr_offset: f64,
    /// Pearson correlation with the mean joint rotation.
    pub corr_rotation: f64,
}

/// Two-way ANOVA (no replication) of the rotation RMSE over pose x stiffness.
#[derive(Debug, Clone, Serialize)]
pub struct TwoFactor {
    /// Sample indices whose joint poses are the rows.
    pub poses: Vec<usize>,
    /// Sample indices whose stiffness parameters are the columns.
    pub stiffness_sets: Vec<usize>,
    /// `rmse[pose][stiffness]` (experiment units).
    pub rmse: Vec<Vec<f64>>,
    /// Sum of squares of the pose factor.
    pub ss_pose: f64,
    /// Sum of squares of the stiffness factor.
    pub ss_stiffness: f64,
    /// Interaction (residual) sum of squares.
    pub ss_interaction: f64,
    /// `ss_pose` over the total sum of squares.
    pub share_pose: f64,
    /// `ss_stiffness` over the total sum of squares.
    pub share_stiffness: f64,
    /// `ss_interaction` over the total sum of squares.
    pub share_interaction: f64,
}

/// Empirical SD of the frame perturbation per level (from the samples).
#[derive(Debug, Clone, Serialize)]
pub struct LevelFrameSd {
    /// Body pair, `upper/lower`.
    pub level: String,
    /// RMS of the offset components (m).
    pub offset_sd: f64,
    /// RMS of the rotation components (rad).
    pub rotation_sd: f64,
}

/// Result of the study.
#[derive(Debug, Clone, Serialize)]
pub struct SensitivityReport {
    /// Landmark SD per coordinate (m).
    pub landmark_sd: f64,
    /// Number of samples.
    pub samples: usize,
    /// Number of samples in the reduced dataset.
    pub reduced: usize,
    /// Parameter names, in the order of every parameter vector.
    pub param_names: Vec<String>,
    /// Calibration with the unperturbed joint poses.
    pub reference_params: Vec<f64>,
    /// Pooled rotation RMSE of that calibration (experiment units).
    pub reference_rmse: f64,
    /// Empirical frame perturbation SD per level.
    pub frame_sd: Vec<LevelFrameSd>,
    /// Spread of each parameter over the reduced dataset.
    pub params: Vec<Spread>,
    /// Spread of the pooled rotation RMSE over the reduced dataset.
    pub rmse: Spread,
    /// The two-factor analysis; `None` with fewer than two reduced samples.
    pub two_factor: Option<TwoFactor>,
    /// Every sample.
    pub sample_list: Vec<Sample>,
}

fn pose_delta(
    a: &crate::landmarks::frames::VertebraFrame,
    b: &crate::landmarks::frames::VertebraFrame,
) -> FramePerturbation {
    let ra = a.rotation;
    let off = ra.inverse() * (b.origin - a.origin);
    let rel = ra.inverse() * b.rotation;
    let rv = rel.scaled_axis();
    FramePerturbation {
        offset: [off.x, off.y, off.z],
        rotation: [rv.x, rv.y, rv.z],
    }
}

/// Joint-frame perturbations of `n` landmark-noise samples for the joints
/// between the given (upper, lower) vertebra levels.
fn frame_perturbations(
    joints: &[(Level, Level)],
    n: usize,
    sd: f64,
    seed: u64,
) -> Result<Vec<Vec<FramePerturbation>>> {
    let top = joints
        .iter()
        .flat_map(|(u, l)| [*u, *l])
        .min_by_key(|l| l.index())
        .ok_or_else(|| Error::invalid("sensitivity", "no joint"))?;
    let clean = generate(&SynthOptions {
        top,
        ..SynthOptions::default()
    })?;
    let mut vertebrae: Vec<Level> = joints.iter().flat_map(|(u, l)| [*u, *l]).collect();
    vertebrae.sort_by_key(|l| l.index());
    vertebrae.dedup();
    // landmark coordinates that are perturbed: every present landmark of every vertebra
    let mut slots: Vec<(Level, Code)> = Vec::new();
    for &v in &vertebrae {
        for c in Code::ALL {
            if clean.get(v, c).is_some() {
                slots.push((v, c));
            }
        }
    }
    let z = lhs::normal(n, 3 * slots.len(), seed);
    let base: Vec<Option<crate::landmarks::frames::VertebraFrame>> = vertebrae
        .iter()
        .map(|&v| vertebra_frame(&clean, v))
        .collect();
    let mut out = Vec::with_capacity(n);
    for zi in &z {
        let mut set = clean.clone();
        for (k, &(v, c)) in slots.iter().enumerate() {
            if let Some(p) = clean.get(v, c) {
                let d = Vector3::new(zi[3 * k], zi[3 * k + 1], zi[3 * k + 2]) * sd;
                set.insert(v, c, p + d);
            }
        }
        let deltas: Vec<Option<FramePerturbation>> = vertebrae
            .iter()
            .zip(&base)
            .map(|(&v, b)| Some(pose_delta(b.as_ref()?, &vertebra_frame(&set, v)?)))
            .collect();
        let get = |l: Level| {
            vertebrae
                .iter()
                .position(|&v| v == l)
                .and_then(|i| deltas[i])
        };
        out.push(
            joints
                .iter()
                .map(|&(u, l)| {
                    let parts: Vec<FramePerturbation> =
                        [get(u), get(l)].into_iter().flatten().collect();
                    let k = parts.len().max(1) as f64;
                    FramePerturbation {
                        offset: std::array::from_fn(|d| {
                            parts.iter().map(|p| p.offset[d]).sum::<f64>() / k
                        }),
                        rotation: std::array::from_fn(|d| {
                            parts.iter().map(|p| p.rotation[d]).sum::<f64>() / k
                        }),
                    }
                })
                .collect(),
        );
    }
    Ok(out)
}

/// Apply perturbations (per level of `pb`'s family, by joint child body) to
/// a copy of the experiment's spec: joint frames F and M and the bushing's
/// frames all right-multiplied by the same small transform.
fn perturbed_spec(
    spec: &SystemSpec,
    joints: &[(String, String)],
    bushings: &[String],
    pert: &[FramePerturbation],
) -> Result<SystemSpec> {
    let mut s = spec.clone();
    for (k, ((upper, _lower), p)) in joints.iter().zip(pert).enumerate() {
        let delta = Isometry3::from_parts(
            Translation3::from(Vector3::from(p.offset)),
            UnitQuaternion::from_rotation_matrix(&Rotation3::new(Vector3::from(p.rotation))),
        );
        let bi = s
            .bodies
            .iter()
            .position(|b| &b.name == upper)
            .ok_or_else(|| Error::invalid("sensitivity", format!("no body '{upper}'")))?;
        let j = s
            .joints
            .iter_mut()
            .find(|j| j.child == bi)
            .ok_or_else(|| Error::invalid("sensitivity", format!("no joint for '{upper}'")))?;
        let (old_pf, old_bm) = (j.x_pf, j.x_bm);
        j.x_pf = old_pf * delta;
        j.x_bm = old_bm * delta;
        let (new_pf, new_bm) = (j.x_pf, j.x_bm);
        if let Some(b) = s
            .bushings
            .iter_mut()
            .find(|b| Some(&b.name) == bushings.get(k))
        {
            b.frame1.transform = if b.frame1.transform == old_pf {
                new_pf
            } else {
                b.frame1.transform * delta
            };
            b.frame2.transform = if b.frame2.transform == old_bm {
                new_bm
            } else {
                b.frame2.transform * delta
            };
        }
    }
    Ok(s)
}

/// Quantile `q` of `v` (type 7), NaN when empty.
fn quantile(v: &[f64], q: f64) -> f64 {
    crate::util::quantile(v, q).unwrap_or(f64::NAN)
}

fn pearson(x: &[f64], y: &[f64]) -> f64 {
    let n = x.len().min(y.len()) as f64;
    if n < 2.0 {
        return f64::NAN;
    }
    let mx = x.iter().sum::<f64>() / n;
    let my = y.iter().sum::<f64>() / n;
    let (mut sxy, mut sxx, mut syy) = (0.0, 0.0, 0.0);
    for (a, b) in x.iter().zip(y) {
        sxy += (a - mx) * (b - my);
        sxx += (a - mx).powi(2);
        syy += (b - my).powi(2);
    }
    sxy / (sxx * syy).sqrt()
}

fn spread(name: &str, reference: f64, v: &[f64], off: &[f64], rot: &[f64]) -> Spread {
    let mut s = v.to_vec();
    s.sort_by(|a, b| a.total_cmp(b));
    Spread {
        name: name.to_string(),
        reference,
        median: quantile(&s, 0.5),
        p2_5: quantile(&s, 0.025),
        p25: quantile(&s, 0.25),
        p75: quantile(&s, 0.75),
        p97_5: quantile(&s, 0.975),
        min: s.first().copied().unwrap_or(f64::NAN),
        max: s.last().copied().unwrap_or(f64::NAN),
        corr_offset: pearson(off, v),
        corr_rotation: pearson(rot, v),
    }
}

/// Two-way ANOVA without replication of `y[i][j]`: (SS rows, SS cols, SS residual).
fn two_way_anova(y: &[Vec<f64>]) -> (f64, f64, f64) {
    let r = y.len();
    let c = y.first().map(|v| v.len()).unwrap_or(0);
    if r == 0 || c == 0 {
        return (f64::NAN, f64::NAN, f64::NAN);
    }
    let grand = y.iter().flatten().sum::<f64>() / (r * c) as f64;
    let rm: Vec<f64> = y.iter().map(|v| v.iter().sum::<f64>() / c as f64).collect();
    let cm: Vec<f64> = (0..c)
        .map(|j| y.iter().map(|v| v[j]).sum::<f64>() / r as f64)
        .collect();
    let ss_r = c as f64 * rm.iter().map(|m| (m - grand).powi(2)).sum::<f64>();
    let ss_c = r as f64 * cm.iter().map(|m| (m - grand).powi(2)).sum::<f64>();
    let mut ss_e = 0.0;
    for i in 0..r {
        for j in 0..c {
            ss_e += (y[i][j] - rm[i] - cm[j] + grand).powi(2);
        }
    }
    (ss_r, ss_c, ss_e)
}

/// Pooled rotation RMSE of predictions `pred` against the measurements.
fn rotation_rmse(pb: &Problem, pred: &[[f64; 6]]) -> f64 {
    error_table(pb, pred, |_| true).pooled(true)
}

/// What every sample of a study shares: the experiment, the reference
/// calibration, and the levels whose joint frames are perturbed.
struct Study<'a> {
    exp: Arc<Experiment>,
    setup: &'a Setup,
    /// (upper body, lower body) of each calibrated level.
    joints: Vec<(String, String)>,
    /// The bushing of each level.
    bushings: Vec<String>,
    /// The unperturbed optimum (natural units), each re-calibration's start.
    reference_best: Vec<f64>,
    /// Nominal parameters (a stiffness 10x above is an outlier).
    nominal: Vec<f64>,
}

impl Study<'_> {
    /// The problem of the model with the joint frames perturbed by `p`.
    fn problem(&self, p: &[FramePerturbation]) -> Result<Problem> {
        let spec = perturbed_spec(&self.exp.spec, &self.joints, &self.bushings, p)?;
        let (pb, _) = build_problem_with(self.exp.clone(), self.setup, System::new(&spec)?)?;
        Ok(pb)
    }

    /// Sample `i`: the model with the joint frames perturbed by `p`,
    /// re-calibrated from the reference optimum, and whether it counts.
    fn sample(&self, i: usize, p: &[FramePerturbation]) -> Sample {
        let mean_norm = |f: fn(&FramePerturbation) -> [f64; 3]| {
            p.iter().map(|x| Vector3::from(f(x)).norm()).sum::<f64>() / p.len().max(1) as f64
        };
        let mut s = Sample {
            index: i,
            perturbations: p.to_vec(),
            mean_offset: mean_norm(|x| x.offset),
            mean_rotation: mean_norm(|x| x.rotation),
            params: Vec::new(),
            cost: f64::NAN,
            rotation_rmse: f64::NAN,
            ok: false,
            note: None,
        };
        let res = (|| -> Result<(Vec<f64>, f64, f64, LmStop)> {
            let pb = self.problem(p)?;
            let mut ev = pb.evaluator();
            let r = fit::fit_from(
                &pb,
                &mut ev,
                &self.reference_best,
                &FitOptions::default().lm,
            )?;
            let params = pb.values_of(&r.x);
            let pred = ev.predict(&pb, &params)?;
            Ok((
                params.clone(),
                2.0 * r.cost,
                rotation_rmse(&pb, &pred),
                r.stop,
            ))
        })();
        match res {
            Ok((params, cost, rmse, stop)) => {
                let outlier = params.iter().zip(&self.nominal).any(|(v, n)| *v > 10.0 * n);
                s.ok = !outlier && matches!(stop, LmStop::Gradient | LmStop::Step | LmStop::Cost);
                if outlier {
                    s.note = Some("stiffness more than 10x nominal".into());
                } else if !s.ok {
                    s.note = Some(format!("optimiser stopped: {stop:?}"));
                }
                s.params = params;
                s.cost = cost;
                s.rotation_rmse = rmse;
            }
            Err(e) => s.note = Some(e.to_string()),
        }
        s
    }

    /// Two-factor analysis: the poses of the first reduced samples crossed
    /// with the stiffness of the best-fitting ones (no re-optimisation);
    /// `None` with fewer than two reduced samples or an empty design.
    fn two_factor(
        &self,
        samples: &[Sample],
        ok: &[&Sample],
        opts: &SensitivityOptions,
    ) -> Result<Option<TwoFactor>> {
        if !(ok.len() >= 2 && opts.two_factor_poses > 0 && opts.two_factor_best > 0) {
            return Ok(None);
        }
        let poses: Vec<usize> = ok
            .iter()
            .take(opts.two_factor_poses)
            .map(|s| s.index)
            .collect();
        let mut by_cost: Vec<&Sample> = ok.to_vec();
        by_cost.sort_by(|a, b| a.cost.total_cmp(&b.cost).then(a.index.cmp(&b.index)));
        let best: Vec<usize> = by_cost
            .iter()
            .take(opts.two_factor_best)
            .map(|s| s.index)
            .collect();
        let table: Vec<Result<Vec<f64>>> = poses
            .par_iter()
            .map(|&pi| {
                let pb = self.problem(&samples[pi].perturbations)?;
                let mut ev = pb.evaluator();
                best.iter()
                    .map(|&bi| Ok(rotation_rmse(&pb, &ev.predict(&pb, &samples[bi].params)?)))
                    .collect()
            })
            .collect();
        let rmse: Vec<Vec<f64>> = table.into_iter().collect::<Result<_>>()?;
        let (sp, ss, si) = two_way_anova(&rmse);
        let tot = sp + ss + si;
        Ok(Some(TwoFactor {
            poses,
            stiffness_sets: best,
            rmse,
            ss_pose: sp,
            ss_stiffness: ss,
            ss_interaction: si,
            share_pose: sp / tot,
            share_stiffness: ss / tot,
            share_interaction: si / tot,
        }))
    }

    /// RMS offset and rotation per axis of each level's frame over the samples.
    fn frame_sd(&self, samples: &[Sample]) -> Vec<LevelFrameSd> {
        self.joints
            .iter()
            .enumerate()
            .map(|(k, (u, l))| {
                let n = samples.len().max(1) as f64;
                let o = samples
                    .iter()
                    .map(|s| Vector3::from(s.perturbations[k].offset).norm_squared())
                    .sum::<f64>();
                let r = samples
                    .iter()
                    .map(|s| Vector3::from(s.perturbations[k].rotation).norm_squared())
                    .sum::<f64>();
                LevelFrameSd {
                    level: format!("{u}/{l}"),
                    offset_sd: (o / (3.0 * n)).sqrt(),
                    rotation_sd: (r / (3.0 * n)).sqrt(),
                }
            })
            .collect()
    }
}

/// The vertebral levels of each (upper, lower) body pair.
fn vertebra_levels(joints: &[(String, String)]) -> Result<Vec<(Level, Level)>> {
    let mut lv = Vec::new();
    for (u, l) in joints {
        let (Some(a), Some(b)) = (Level::from_body_name(u), Level::from_body_name(l)) else {
            return Err(Error::invalid(
                "sensitivity",
                format!("level {u}/{l}: body names must be vertebra names (thoracic1..12, lumbar1..5, sacrum) to place landmarks"),
            ));
        };
        lv.push((a, b));
    }
    Ok(lv)
}

/// Run the study on an experiment with a parameterisation.
pub fn run(
    exp: Arc<Experiment>,
    setup: &Setup,
    opts: &SensitivityOptions,
) -> Result<SensitivityReport> {
    if !(opts.landmark_sd.is_finite() && opts.landmark_sd >= 0.0) {
        return Err(Error::invalid("--landmark-sd", "must be finite and >= 0"));
    }
    if opts.samples == 0 {
        return Err(Error::invalid("--samples", "must be at least 1"));
    }
    // The reference calibration of the unperturbed model.
    let sys0 = System::new(&exp.spec)?;
    let (pb0, fam0) = build_problem_with(exp.clone(), setup, sys0)?;
    let reference = fit::calibrate(
        &pb0,
        &FitOptions {
            starts: 4,
            progress: false,
            ..FitOptions::default()
        },
    )?;
    let reference_rmse = rotation_rmse(&pb0, &reference.predictions);
    // The calibrated levels: their bodies and bushings.
    let names: Vec<String> = pb0.system().bushing_names().map(String::from).collect();
    let study = Study {
        exp: exp.clone(),
        setup,
        joints: fam0
            .levels
            .iter()
            .map(|l| (l.level.upper_body.clone(), l.level.lower_body.clone()))
            .collect(),
        bushings: fam0
            .levels
            .iter()
            .map(|l| names.get(l.bushing.0).cloned().unwrap_or_default())
            .collect(),
        reference_best: reference.best.clone(),
        nominal: fam0.params_nominal(),
    };
    // Joint-frame perturbations from landmark noise, one set per sample.
    let lv = vertebra_levels(&study.joints)?;
    let perts = frame_perturbations(&lv, opts.samples, opts.landmark_sd, opts.seed)?;
    // Every sample re-calibrated (in parallel).
    let bar =
        crate::util::progress::bar("sensitivity", opts.samples as u64, "samples", opts.progress);
    let samples: Vec<Sample> = perts
        .par_iter()
        .enumerate()
        .map(|(i, p)| {
            let s = study.sample(i, p);
            bar.inc(1);
            s
        })
        .collect();
    bar.finish_and_clear();
    // Spread of each parameter and of the RMSE over the reduced dataset.
    let ok: Vec<&Sample> = samples.iter().filter(|s| s.ok).collect();
    let off: Vec<f64> = ok.iter().map(|s| s.mean_offset).collect();
    let rot: Vec<f64> = ok.iter().map(|s| s.mean_rotation).collect();
    let info = fam0.params_info();
    let params = info
        .iter()
        .enumerate()
        .map(|(k, pi)| {
            let v: Vec<f64> = ok.iter().map(|s| s.params[k]).collect();
            spread(&pi.name, reference.best[k], &v, &off, &rot)
        })
        .collect();
    let rm: Vec<f64> = ok.iter().map(|s| s.rotation_rmse).collect();
    let rmse = spread("rotation_rmse", reference_rmse, &rm, &off, &rot);
    // Two-factor analysis (pose x stiffness) and the frame spread per level.
    let two_factor = study.two_factor(&samples, &ok, opts)?;
    let frame_sd = study.frame_sd(&samples);
    Ok(SensitivityReport {
        landmark_sd: opts.landmark_sd,
        samples: samples.len(),
        reduced: ok.len(),
        param_names: info.iter().map(|p| p.name.clone()).collect(),
        reference_params: reference.best.clone(),
        reference_rmse,
        frame_sd,
        params,
        rmse,
        two_factor,
        sample_list: samples,
    })
}

/// Box plot of each parameter over the reduced dataset, as value /
/// reference calibration on a log axis: box 25-75%, whiskers 2.5-97.5%,
/// red median, dots at the minimum and maximum (`spread.svg`).
pub fn spread_svg(rep: &SensitivityReport, title: &str) -> String {
    use crate::util::charts::{self, Category, CategoryChart, Mark, ValueAxis};
    use plotters::style::BLACK;
    let ratios: Vec<f64> = rep
        .params
        .iter()
        .flat_map(|s| [s.min / s.reference, s.max / s.reference])
        .filter(|v| v.is_finite() && *v > 0.0)
        .collect();
    // 3% of room beyond the extremes so the end dots stay inside
    let lo = ratios.iter().fold(0.9f64, |m, v| m.min(*v)) / 1.03;
    let hi = ratios.iter().fold(1.1f64, |m, v| m.max(*v)) * 1.03;
    let span = |lo: f64, hi: f64, width: u32| Mark::Span {
        lo,
        hi,
        dx: 0,
        colour: BLACK,
        width,
    };
    let dot = |at: f64| Mark::Dot {
        at,
        dx: 0,
        radius: 2,
        colour: BLACK,
        filled: true,
    };
    let categories = rep
        .params
        .iter()
        .map(|p| {
            let r = p.reference;
            Category {
                label: p.name.clone(),
                marks: vec![
                    span(p.p2_5 / r, p.p97_5 / r, 1),
                    Mark::Box {
                        lo: p.p25 / r,
                        hi: p.p75 / r,
                        half: 8,
                        fill: charts::BOX_FILL,
                    },
                    Mark::Tick {
                        at: p.median / r,
                        half: 8,
                        colour: charts::HIGHLIGHT,
                        width: 2,
                    },
                    dot(p.min / r),
                    dot(p.max / r),
                ],
            }
        })
        .collect();
    let n = rep.params.len().max(1) as f64;
    charts::category_svg(&CategoryChart {
        title: title.to_string(),
        subtitle: format!(
            "box 25-75%, whiskers 2.5-97.5%, red: median, dots: min/max ({} of {} samples)",
            rep.reduced, rep.samples
        ),
        axis: ValueAxis {
            label: "stiffness / reference calibration (log)".into(),
            range: (lo, hi),
            ticks: vec![lo, 0.5 * (lo + 1.0), 1.0, 0.5 * (1.0 + hi), hi],
            format: |v| format!("{v:.3}"),
            log: true,
            grid: true,
            reference: Some(1.0),
        },
        categories,
        slot: (500.0 / n).clamp(50.0, 90.0) as u32,
        min_width: 360,
        plot_h: 260,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn anova_separates_additive_effects() {
        // y = row effect + column effect: no interaction
        let y: Vec<Vec<f64>> = (0..4)
            .map(|i| (0..3).map(|j| i as f64 * 2.0 + j as f64).collect())
            .collect();
        let (r, c, e) = two_way_anova(&y);
        assert!(
            (r - 3.0 * 4.0 * 5.0).abs() < 1e-12 && (c - 4.0 * 2.0).abs() < 1e-12 && e.abs() < 1e-12,
            "{r} {c} {e}"
        );
    }

    #[test]
    fn frame_noise_scales_with_landmark_sd_and_vanishes_without_it() {
        let joints = [(Level::L4, Level::L5), (Level::L5, Level::S1)];
        let zero = frame_perturbations(&joints, 5, 0.0, 1).unwrap();
        assert!(zero.iter().flatten().all(|p| p
            .offset
            .iter()
            .chain(&p.rotation)
            .all(|v| v.abs() < 1e-12)));
        let a = frame_perturbations(&joints, 400, 0.001, 1).unwrap();
        let b = frame_perturbations(&joints, 400, 0.002, 1).unwrap();
        let rms = |s: &Vec<Vec<FramePerturbation>>| {
            (s.iter().map(|v| v[0].offset[0].powi(2)).sum::<f64>() / s.len() as f64).sqrt()
        };
        // origin = mean of SEC and IEC, averaged over two vertebrae: SD / 2 per axis
        assert!((rms(&a) / 0.0005 - 1.0).abs() < 0.1, "{}", rms(&a));
        assert!((rms(&b) / rms(&a) - 2.0).abs() < 1e-9);
    }
}
