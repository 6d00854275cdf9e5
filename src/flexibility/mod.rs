//! The patient's own intervertebral flexibility from frontal bending films
//! (`osim-spine flexibility`).
//!
//! A scoliosis clinic takes a neutral and a left and right side-bending
//! film of every surgical candidate. Each bending film shows how the spine
//! shares one bend between its joints: a stiff joint turns little, a soft
//! one much. The patient model is bent into each film with the tool's own
//! solver ([`bend`]): pelvis and sacrum held, the film's most cranial
//! vertebra (T1) pulled sideways and tilted by a lateral force and a
//! frontal moment (the patient's effort), every level between in
//! equilibrium of the bushings alone (no gravity, no muscles). Each
//! joint's rotational stiffness is the model's times a multiplier;
//! multipliers, loads and the films' placements are fitted to every film
//! point by least squares ([`fit`]).
//!
//! Only stiffness ratios are identifiable: scaling every stiffness and the
//! loads together bends the spine identically, so the multipliers are
//! normalised to geometric mean 1 over the estimated joints, and the
//! absolute scale is the model's own (stated in the report). Intervals come
//! from the fit's covariance with the residual variance (never below the
//! stated digitising noise), optionally with a Gaussian prior on each log
//! multiplier; joints whose 95% interval spans more than a factor
//! [`report::RESOLVED_SPAN`] are listed as not resolved.
//!
//! Stages ([`flexibility`]): films read and placed on the pelvis
//! ([`place`]); every film fitted with the model's own stiffness (the
//! uniform baseline, which also says which films bend the spine); the
//! multipliers estimated from the bending films; the prediction films (a
//! few levels given, e.g. T1 and the pelvis) fitted with the personalised
//! and the uniform stiffness and every other level predicted; the curves'
//! flexibility (bending Cobb / unbent Cobb) measured and reproduced
//! ([`report`]); one figure per film ([`views`]).

pub mod bend;
pub mod fit;
pub mod neutral;
pub mod place;
pub mod report;
pub mod views;

use crate::error::{Error, Result};
use crate::landmarks::metrics::FrontalTilts;
use crate::landmarks::radiograph::{self, FilmPoint, Radiograph};
use crate::landmarks::{Code, LandmarkId, Level};
use crate::osim::model::Model;
use crate::personalise::table::{write_toml_ratios, LevelLaw};
use crate::util::lm::LmResult;
use bend::BendModel;
use fit::{fit_films, sum_zero_basis, Estimated, FilmData, FilmState, Problem};
use nalgebra::{DMatrix, Vector2};
use report::{FilmFit, JointEstimate, Loads, RegionEstimate};
use serde::Serialize;
use std::collections::BTreeMap;

/// Options of [`flexibility`].
#[derive(Debug, Clone)]
pub struct FlexibilityOptions {
    /// Digitising noise per film coordinate (m).
    pub noise: f64,
    /// SD of a Gaussian prior on each joint's log multiplier (None: none).
    pub prior_sd: Option<f64>,
    /// SD of a Gaussian prior on neighbouring joints' log multiplier
    /// difference (None: none).
    pub step_sd: Option<f64>,
    /// Predict with the model's own stiffness only (no estimate).
    pub uniform: bool,
    /// Write the results even when a film contradicts the model.
    pub allow_mismatch: bool,
    /// Show a progress bar.
    pub progress: bool,
}

impl Default for FlexibilityOptions {
    fn default() -> Self {
        FlexibilityOptions {
            noise: 1e-3,
            prior_sd: Some(DEFAULT_PRIOR_SD),
            step_sd: None,
            uniform: false,
            allow_mismatch: false,
            progress: false,
        }
    }
}

/// Default prior SD of a log multiplier: 95% of joints within a factor
/// e^(1.96) = 7 of the spine's mean stiffness.
pub const DEFAULT_PRIOR_SD: f64 = 1.0;
/// A film bends the spine when its loaded level moved more than this (m) ...
const BENT_LATERAL: f64 = 0.010;
/// ... or turned more than this (rad) from the unbent model.
const BENT_TILT: f64 = 0.087;
/// A film whose RMS residual exceeds this many noise SDs contradicts the
/// model (another patient, swapped levels).
const CONTRADICTION_SIGMAS: f64 = 4.0;
/// A film turned more than this on its pelvis (rad) is refused.
const MAX_FILM_ROTATION: f64 = 0.35;

/// What a film is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Role {
    /// A full film that bends the spine: stiffness information.
    Bending,
    /// A full film of the unbent spine (neutral): the reference shape.
    Unbent,
    /// A partial film whose other levels are predicted (`--predict`).
    Predict,
}

/// One film in the report.
#[derive(Debug, Clone, Serialize)]
pub struct FilmReport {
    /// The film's file, as given.
    pub file: String,
    /// The film's `# film:` text, if any.
    pub film: Option<String>,
    /// What the film is for.
    pub role: Role,
    /// The level the bending load acts on (e.g. `T1`).
    pub loaded_level: Level,
    /// The film's projection, as its header states it.
    pub projection: String,
    /// Image size over patient size at the patient's plane (1 for orthographic).
    pub magnification: f64,
    /// Number of digitised points.
    pub points: usize,
    /// RMS of the pelvic placement before the fit (mm).
    pub pelvic_placement_rms_mm: f64,
    /// Fitted with the model's own stiffness.
    pub uniform: FilmFit,
    /// Fitted with the personalised stiffness.
    pub personalised: Option<FilmFit>,
    /// The predicted film written (predict films).
    pub output: Option<String>,
    /// The reader's notes.
    pub notes: Vec<String>,
}

/// The estimate's summary.
#[derive(Debug, Clone, Serialize)]
pub struct EstimateSummary {
    /// The films the estimate used.
    pub films: Vec<String>,
    /// Number of joints whose stiffness was estimated.
    pub joints_estimated: usize,
    /// Number of data residuals (2 per film point).
    pub residuals: usize,
    /// Number of fitted parameters.
    pub parameters: usize,
    /// RMS residual in noise SDs (the covariance uses max(1, its square)).
    pub residual_sd_in_noise: f64,
    /// SD of the prior on a log multiplier (`None`: no prior).
    pub prior_sd: Option<f64>,
    /// Least-squares iterations run.
    pub iterations: usize,
    /// Why the least-squares optimiser stopped.
    pub stop: crate::util::lm::LmStop,
    /// Whether it converged.
    pub converged: bool,
}

/// `flexibility.json`.
#[derive(Debug, Clone, Serialize)]
pub struct FlexibilityReport {
    /// The model file, as given.
    pub model: String,
    /// `personalised` or `uniform`.
    pub mode: String,
    /// Digitising noise SD assumed (mm).
    pub noise_mm: f64,
    /// What the films can and cannot determine.
    pub identifiability: String,
    /// How the overall stiffness scale is fixed.
    pub absolute_scale: String,
    /// The modelling assumptions of the estimate, for a reader.
    pub assumptions: Vec<String>,
    /// The estimate's summary (`None` in `--uniform` mode or with no bending film).
    pub estimate: Option<EstimateSummary>,
    /// Relative stiffness per estimated joint with its 95% interval.
    pub joints: Vec<JointEstimate>,
    /// Joints whose 95% interval is too wide to say anything.
    pub unresolved_joints: Vec<String>,
    /// Relative stiffness per spinal region.
    pub regions: Vec<RegionEstimate>,
    /// The unbent model's curves and their flexibility on each film.
    pub curves: Vec<report::Curve>,
    /// The model's landmarks calibrated on the unbent film (None without one).
    pub neutral_calibration: Option<neutral::NeutralCalibration>,
    /// Every film read and how it was fitted.
    pub films: Vec<FilmReport>,
    /// What a reader should know about the result.
    pub findings: Vec<String>,
}

/// Everything `flexibility` writes, in memory.
#[derive(Debug, Clone)]
pub struct Flexibility {
    /// The report (`flexibility.json`).
    pub report: FlexibilityReport,
    /// `stiffness.toml` (None when nothing was estimated).
    pub stiffness_toml: Option<String>,
    /// (file name, text) of each predicted film.
    pub predicted: Vec<(String, String)>,
    /// (file name, SVG) per film.
    pub figures: Vec<(String, String)>,
}

/// A film read and prepared, with its fits.
struct Film<'a> {
    raw: &'a Radiograph,
    data: FilmData,
    role: Role,
    pelvic_rms: f64,
    uniform: FilmState,
    personalised: Option<FilmState>,
}

/// Run the whole analysis (nothing written).
pub fn flexibility(
    model: &Model,
    films: &[Radiograph],
    predict: &[Radiograph],
    opts: &FlexibilityOptions,
) -> Result<Flexibility> {
    let bm0 = BendModel::new(model)?;
    let bar = crate::util::progress::bar(
        "flexibility",
        (2 * films.len() + 3 * predict.len() + 1) as u64,
        "fits",
        opts.progress,
    );
    // 1. Films checked against the model and placed on its pelvis.
    let mut all: Vec<Film> = Vec::new();
    for (r, role) in films
        .iter()
        .map(|r| (r, Role::Unbent))
        .chain(predict.iter().map(|r| (r, Role::Predict)))
    {
        let data = prepare(&bm0, r)?;
        let pelvic_rms = check_placement(&bm0, &data, opts.noise)?;
        all.push(Film {
            raw: r,
            data,
            role,
            pelvic_rms,
            uniform: FilmState {
                loads: [0.0; 3],
                place: place::Placement {
                    phi: 0.0,
                    t: Vector2::zeros(),
                },
                q: bm0.rest.clone(),
            },
            personalised: None,
        });
    }
    // 2. Every film with the model's own stiffness: which ones bend.
    uniform_fits(&bm0, &mut all, opts, &bar)?;
    for f in all.iter_mut().filter(|f| f.role != Role::Predict) {
        if bends(&bm0, &f.data, &f.uniform)? {
            f.role = Role::Bending;
        }
    }
    // 3. The model's landmarks calibrated on the unbent film, films refitted.
    let mut findings = Vec::new();
    let (bm, calibration) = match all.iter().find(|f| f.role == Role::Unbent) {
        Some(f) => {
            let (bm, cal) = neutral::calibrate(&bm0, &f.data, opts.noise)?;
            uniform_fits(&bm, &mut all, opts, &bar)?;
            calibration_findings(&cal, &mut findings);
            (bm, Some(cal))
        }
        None => {
            findings.push("no unbent (neutral) film: the model's own landmarks are compared with the films as they are (typically 1-2 mm off the patient's)".into());
            (bm0, None)
        }
    };
    // 4. The multipliers from the bending films.
    let est = if opts.uniform {
        None
    } else {
        let e = estimate(&bm, &all, opts)?;
        for (f, st) in all
            .iter_mut()
            .filter(|f| f.role == Role::Bending)
            .zip(&e.states)
        {
            f.personalised = Some(st.clone());
        }
        bar.inc(1);
        Some(e)
    };
    // 5. The other films with the personalised stiffness (predictions).
    if let Some(e) = &est {
        for f in all.iter_mut().filter(|f| f.role != Role::Bending) {
            let (st, _) = fit_films(&bm, &[&f.data], &e.multipliers, opts.noise)?.remove(0);
            f.personalised = Some(st);
            bar.inc(1);
        }
    }
    bar.finish_and_clear();
    // 6. Report, predicted films, figures, stiffness table.
    let fits = film_reports(&bm, &all, &mut findings, opts)?;
    contradictions(&all, &fits, opts, &mut findings)?;
    let mut out = assemble(model, &bm, &all, fits, est.as_ref(), findings, opts)?;
    out.report.neutral_calibration = calibration;
    Ok(out)
}

/// Fit every film with the model's own stiffness.
fn uniform_fits(
    bm: &BendModel,
    all: &mut [Film],
    opts: &FlexibilityOptions,
    bar: &crate::util::progress::Bar,
) -> Result<()> {
    let ones = vec![1.0; bm.joints.len()];
    for f in all.iter_mut() {
        let (st, _) = fit_films(bm, &[&f.data], &ones, opts.noise)?.remove(0);
        f.uniform = st;
        bar.inc(1);
    }
    Ok(())
}

/// Vertebrae the calibration moved far: the unbent film and the model's
/// rest shape differ by more than landmark errors.
fn calibration_findings(cal: &neutral::NeutralCalibration, findings: &mut Vec<String>) {
    let far: Vec<String> = cal
        .bodies
        .iter()
        .filter(|b| b.shift_mm[0].hypot(b.shift_mm[1]) > 5.0 || b.rotation_deg.abs() > 5.0)
        .map(|b| {
            format!(
                "{} {:.1} mm, {:.1} deg",
                b.body,
                b.shift_mm[0].hypot(b.shift_mm[1]),
                b.rotation_deg
            )
        })
        .collect();
    findings.push(format!(
        "the model's landmarks were calibrated on the unbent film {}: RMS {:.2} mm to the film before, {:.2} mm after moving each vertebra in the frontal plane (remainder weight {:.2})",
        cal.film, cal.rms_before_mm, cal.rms_rigid_mm, cal.remainder_weight
    ));
    if !far.is_empty() {
        findings.push(format!(
            "the unbent film differs from the model's rest shape by more than landmark errors at {} (a standing film against a supine model, or another patient?): the model's rest pose is kept",
            far.join("; ")
        ));
    }
}

/// The film's points checked against the model, its loaded level, its
/// coordinates at the patient's scale.
fn prepare(bm: &BendModel, r: &Radiograph) -> Result<FilmData> {
    let file = r.path.display().to_string();
    // Every point must be one the model has.
    let missing: Vec<String> = r
        .points
        .iter()
        .filter(|(p, _)| !bm.has(**p))
        .map(|(p, (_, line))| format!("{p} (line {line})"))
        .collect();
    if !missing.is_empty() {
        let levels = bm.levels();
        let hint = if missing.iter().any(|m| m.starts_with("FH_")) {
            "; the model has no femoral head markers FH_R/FH_L: regenerate it from a base built by this version of `osim-spine base`"
        } else {
            ""
        };
        return Err(Error::invalid(
            file,
            format!(
                "the film names landmarks the model lacks: {} (the model's vertebrae: {}..{}){hint}",
                missing.join(", "),
                levels.first().map(|l| l.to_string()).unwrap_or_default(),
                levels.last().map(|l| l.to_string()).unwrap_or_default(),
            ),
        ));
    }
    // At least two pelvic points place the film.
    let pelvic = r.points.keys().filter(|p| p.is_pelvic()).count();
    if pelvic < 2 {
        return Err(Error::invalid(
            file,
            format!(
                "cannot place the film on the pelvis: it gives {pelvic} of S1_SR, S1_SL, S1_SEC, FH_R, FH_L (at least two are needed, all five are best)"
            ),
        ));
    }
    // The most cranial vertebra with two points is loaded.
    let level = r
        .vertebrae()
        .into_iter()
        .find(|l| r.points.keys().filter(|p| p.vertebra() == Some(*l)).count() >= 2)
        .ok_or_else(|| {
            Error::invalid(
                file.clone(),
                "no vertebra with at least two points: nothing to bend the model to",
            )
        })?;
    let mag = r.projection.magnification();
    let (points, measured) = r.points.iter().map(|(p, (x, _))| (*p, x / mag)).unzip();
    Ok(FilmData {
        stem: r.stem(),
        file,
        level,
        points,
        measured,
    })
}

/// The film's pelvic placement: refused when turned more than
/// [`MAX_FILM_ROTATION`], mirrored, or far off the model's pelvis. Returns
/// its RMS (m).
fn check_placement(bm: &BendModel, film: &FilmData, noise: f64) -> Result<f64> {
    let (p, rms) = fit::initial_placement(bm, film)?;
    let mirrored = FilmData {
        measured: film
            .measured
            .iter()
            .map(|m| Vector2::new(-m.x, m.y))
            .collect(),
        ..film.clone()
    };
    let (_, rms_m) = fit::initial_placement(bm, &mirrored)?;
    let limit = 2.0 * CONTRADICTION_SIGMAS * noise;
    if rms > limit && rms_m < 0.5 * rms {
        return Err(Error::invalid(
            film.file.clone(),
            format!(
                "the film's left and right are swapped: its pelvic landmarks fit the model's pelvis mirrored (RMS {:.1} mm) and not as given ({:.1} mm); u must grow towards the patient's left (or say `# axes: u towards the patient's right`)",
                rms_m * 1e3,
                rms * 1e3
            ),
        ));
    }
    if rms > limit {
        return Err(Error::invalid(
            film.file.clone(),
            format!(
                "the film's pelvic landmarks do not fit the model's pelvis: RMS {:.1} mm after the best in-plane placement, against {:.1} mm digitising noise (another patient, or misnamed pelvic landmarks?)",
                rms * 1e3,
                noise * 1e3
            ),
        ));
    }
    if p.phi.abs() > MAX_FILM_ROTATION {
        return Err(Error::invalid(
            film.file.clone(),
            format!(
                "the film is turned {:.0} deg on the model's pelvis: a frontal film is placed within a few degrees (v must point cranially)",
                p.phi.to_degrees()
            ),
        ));
    }
    Ok(rms)
}

/// Whether a film's fitted loaded level moved away from the unbent model.
fn bends(bm: &BendModel, film: &FilmData, st: &FilmState) -> Result<bool> {
    let (t0, z0) = bm.level_pose(film.level, bm.rest.as_slice())?;
    let (t1, z1) = bm.level_pose(film.level, st.q.as_slice())?;
    Ok((z1 - z0).abs() > BENT_LATERAL || (t1 - t0).abs() > BENT_TILT)
}

/// The estimated multipliers and their covariance.
struct Estimate {
    /// Indices of the estimated joints.
    joints: Vec<usize>,
    /// Every joint's multiplier.
    multipliers: Vec<f64>,
    /// Log multipliers of the estimated joints and their covariance.
    log_m: Vec<f64>,
    cov: DMatrix<f64>,
    /// Bending films' states at the estimate (in film order).
    states: Vec<FilmState>,
    summary: EstimateSummary,
}

/// Estimate the multipliers from the bending films.
fn estimate(bm: &BendModel, all: &[Film], opts: &FlexibilityOptions) -> Result<Estimate> {
    let bending: Vec<&Film> = all.iter().filter(|f| f.role == Role::Bending).collect();
    if bending.is_empty() {
        let unbent: Vec<String> = all
            .iter()
            .filter(|f| f.role == Role::Unbent)
            .map(|f| f.data.file.clone())
            .collect();
        return Err(Error::invalid(
            "flexibility",
            format!(
                "no stiffness can be estimated: no film bends the spine ({} show the loaded level within {:.0} mm and {:.0} deg of the unbent model). Stiffness shows only in how a bend is shared between the joints: give a left and a right bending film (or use --uniform to predict with the model's own stiffness)",
                if unbent.is_empty() { "none given".to_string() } else { unbent.join(", ") },
                BENT_LATERAL * 1e3,
                BENT_TILT.to_degrees()
            ),
        ));
    }
    // Joints that carry the bending films' loads: below the highest loaded level.
    let top = bending
        .iter()
        .map(|f| f.data.level)
        .min()
        .unwrap_or(Level::T1);
    let joints: Vec<usize> = (0..bm.joints.len())
        .filter(|&j| bm.joints[j].upper >= top)
        .collect();
    let basis = sum_zero_basis(joints.len());
    let est = Estimated {
        joints: joints.clone(),
        basis: basis.clone(),
        prior: fit::prior_rows(joints.len(), opts.prior_sd, opts.step_sd),
    };
    let datas: Vec<&FilmData> = bending.iter().map(|f| &f.data).collect();
    let mut pb = Problem::new(bm, datas, vec![1.0; bm.joints.len()], Some(est), opts.noise);
    pb.set_warm(bending.iter().map(|f| f.uniform.q.clone()).collect());
    let states0: Vec<FilmState> = bending.iter().map(|f| f.uniform.clone()).collect();
    let x0 = vec![0.0; basis.ncols()];
    let p0 = pb.pack(&x0, &states0);
    let res = pb.minimise(&p0)?;
    pb.eval(&res.x, false)?;
    let ns = basis.ncols();
    let multipliers = pb.multipliers(&res.x[..ns]);
    let states = pb.states(&res.x);
    let (cov_x, s2) = covariance(&res, pb.n_data(), ns);
    let cov = &basis * cov_x * basis.transpose();
    let log_m: Vec<f64> = joints.iter().map(|&j| multipliers[j].ln()).collect();
    let summary = EstimateSummary {
        films: bending.iter().map(|f| f.data.file.clone()).collect(),
        joints_estimated: joints.len(),
        residuals: pb.n_data(),
        parameters: res.x.len(),
        residual_sd_in_noise: s2.sqrt(),
        prior_sd: opts.prior_sd,
        iterations: res.iterations,
        stop: res.stop,
        converged: res.converged(),
    };
    Ok(Estimate {
        joints,
        multipliers,
        log_m,
        cov,
        states,
        summary,
    })
}

/// Covariance of the first `ns` parameters: the data rows' information
/// scaled by `1 / s2` (`s2` = residual variance in noise units, at least
/// 1), plus the prior rows'; and `s2` unfloored.
fn covariance(res: &LmResult, n_data: usize, ns: usize) -> (DMatrix<f64>, f64) {
    let p = res.x.len();
    let jd = res.jac.rows(0, n_data);
    let rd = res.r.rows(0, n_data);
    let s2 = rd.norm_squared() / (n_data.saturating_sub(p)).max(1) as f64;
    let mut info = jd.transpose() * jd / s2.max(1.0);
    let n_prior = res.r.len() - n_data;
    if n_prior > 0 {
        let jp = res.jac.rows(n_data, n_prior);
        info += jp.transpose() * jp;
    }
    let cov = info
        .clone()
        .pseudo_inverse(1e-12 * info.norm())
        .unwrap_or_else(|_| DMatrix::from_element(p, p, f64::NAN));
    (cov.view((0, 0), (ns, ns)).into_owned(), s2)
}

/// The fit of every film: uniform and personalised.
fn film_reports(
    bm: &BendModel,
    all: &[Film],
    findings: &mut Vec<String>,
    opts: &FlexibilityOptions,
) -> Result<Vec<(FilmFit, Option<FilmFit>)>> {
    let mut out = Vec::new();
    for f in all {
        let u = film_fit(bm, &f.data, &f.uniform)?;
        let p = match &f.personalised {
            Some(st) => Some(film_fit(bm, &f.data, st)?),
            None => None,
        };
        if f.role == Role::Unbent && !opts.uniform {
            findings.push(format!(
                "{}: the spine is not bent on this film (loaded level {} moved {:.1} mm, {:.1} deg): no stiffness information, used as the unbent reference",
                f.data.file, f.data.level, u.loaded_level_lateral_mm, u.loaded_level_tilt_deg
            ));
        }
        out.push((u, p));
    }
    Ok(out)
}

/// A film's fit statistics at state `st`.
fn film_fit(bm: &BendModel, film: &FilmData, st: &FilmState) -> Result<FilmFit> {
    let (proj, _) = bm.project(&film.points, st.q.as_slice(), None)?;
    let d: Vec<Vector2<f64>> = proj
        .iter()
        .zip(&film.measured)
        .map(|(m, f)| st.place.apply(m) - f)
        .collect();
    let (rms, per_level) = report::rms_per_level(&film.points, &d);
    let (t0, z0) = bm.level_pose(film.level, bm.rest.as_slice())?;
    let (t1, z1) = bm.level_pose(film.level, st.q.as_slice())?;
    Ok(FilmFit {
        rms_mm: rms,
        rms_per_level_mm: per_level,
        loads: Loads {
            force_n: st.loads[0],
            moment_n_m: st.loads[1],
            vertical_force_n: st.loads[2],
        },
        // u = -z on the film
        loaded_level_lateral_mm: -(z1 - z0) * 1e3,
        loaded_level_tilt_deg: (t1 - t0).to_degrees(),
        placement_rotation_deg: st.place.phi.to_degrees(),
        placement_offset_mm: [st.place.t.x * 1e3, st.place.t.y * 1e3],
    })
}

/// Films whose best fit is far above the digitising noise contradict the
/// model: a finding, and an error unless `allow_mismatch`.
fn contradictions(
    all: &[Film],
    fits: &[(FilmFit, Option<FilmFit>)],
    opts: &FlexibilityOptions,
    findings: &mut Vec<String>,
) -> Result<()> {
    let limit = CONTRADICTION_SIGMAS * opts.noise * 1e3;
    let mut bad = Vec::new();
    for (f, (u, p)) in all.iter().zip(fits) {
        let best = p.as_ref().map_or(u.rms_mm, |p| p.rms_mm.min(u.rms_mm));
        if best > limit {
            let worst = p
                .as_ref()
                .unwrap_or(u)
                .rms_per_level_mm
                .iter()
                .max_by(|a, b| a.1.total_cmp(b.1))
                .map(|(l, v)| format!("{l} {v:.1} mm"))
                .unwrap_or_default();
            bad.push(format!(
                "{}: the model reproduces the film to RMS {best:.1} mm only, against {:.1} mm digitising noise (worst level {worst}): the film contradicts the model (another patient, swapped sides or misnamed levels?)",
                f.data.file,
                opts.noise * 1e3
            ));
        }
    }
    if !bad.is_empty() && !opts.allow_mismatch {
        return Err(Error::invalid(
            "flexibility",
            format!(
                "{} (--allow-mismatch writes the results anyway)",
                bad.join("; ")
            ),
        ));
    }
    findings.extend(bad);
    Ok(())
}

/// Every frontal point the model has: per vertebra the endplate ends and
/// centres, the sacrum's, the femoral heads.
fn frontal_points(bm: &BendModel) -> Vec<FilmPoint> {
    let mut out = Vec::new();
    for level in &Level::ALL[..17] {
        for c in [Code::SR, Code::SL, Code::IR, Code::IL, Code::SEC, Code::IEC] {
            out.push(FilmPoint::Landmark(LandmarkId::new(*level, c)));
        }
    }
    for c in [Code::SR, Code::SL, Code::SEC] {
        out.push(FilmPoint::Landmark(LandmarkId::new(Level::S1, c)));
    }
    out.extend(FilmPoint::PELVIC[3..].iter().copied());
    out.retain(|p| bm.has(*p));
    out
}

/// The model's frontal points at `st` in the model's frontal plane (m).
fn model_points(bm: &BendModel, st: &FilmState) -> Result<BTreeMap<FilmPoint, Vector2<f64>>> {
    let pts = frontal_points(bm);
    let (proj, _) = bm.project(&pts, st.q.as_slice(), None)?;
    Ok(pts.into_iter().zip(proj).collect())
}

/// Report, predicted films, figures and stiffness table.
fn assemble(
    model: &Model,
    bm: &BendModel,
    all: &[Film],
    fits: Vec<(FilmFit, Option<FilmFit>)>,
    est: Option<&Estimate>,
    mut findings: Vec<String>,
    opts: &FlexibilityOptions,
) -> Result<Flexibility> {
    // Joints and regions.
    let (joints, regions) = match est {
        Some(e) => joint_estimates(bm, e, all)?,
        None => (Vec::new(), Vec::new()),
    };
    let unresolved: Vec<String> = joints
        .iter()
        .filter(|j| !j.resolved)
        .map(|j| j.joint.clone())
        .collect();
    if !unresolved.is_empty() {
        findings.push(format!(
            "the films do not resolve {} of {} joints (95% interval wider than a factor {}): {}",
            unresolved.len(),
            joints.len(),
            report::RESOLVED_SPAN,
            unresolved.join(", ")
        ));
    }
    // Curves, predicted films, figures.
    let curves = curves(bm, all, est.is_some())?;
    let mut predicted = Vec::new();
    let mut figures = Vec::new();
    let mut film_reports = Vec::new();
    for (f, (u, p)) in all.iter().zip(fits) {
        let output = if f.role == Role::Predict {
            let (name, text) = predicted_film(bm, f, opts.uniform)?;
            predicted.push((name.clone(), text));
            Some(name)
        } else {
            None
        };
        figures.push(figure(bm, f, &curves)?);
        film_reports.push(FilmReport {
            file: f.data.file.clone(),
            film: f.raw.film.clone(),
            role: f.role,
            loaded_level: f.data.level,
            projection: f.raw.projection.header(),
            magnification: f.raw.projection.magnification(),
            points: f.data.points.len(),
            pelvic_placement_rms_mm: f.pelvic_rms * 1e3,
            uniform: u,
            personalised: p,
            output,
            notes: f.raw.notes.clone(),
        });
    }
    if all
        .iter()
        .any(|f| matches!(f.raw.projection, radiograph::Projection::Perspective { .. }))
    {
        findings.push("perspective films are scaled by source_to_image / source_to_patient as a whole: the magnification's change with depth inside the patient (a few percent) is not modelled".into());
    }
    let stiffness_toml = match est {
        Some(e) => Some(stiffness_table(model, bm, e)?),
        None => None,
    };
    let report = FlexibilityReport {
        model: model.file.display().to_string(),
        mode: if opts.uniform { "uniform" } else { "personalised" }.into(),
        noise_mm: opts.noise * 1e3,
        identifiability: "a film bent by a prescribed level fixes only stiffness ratios: scaling every joint's stiffness and the loads on the level together bends the spine identically".into(),
        absolute_scale: "left at the model's own: the estimated joints' multipliers (relative to the model's stiffness) have geometric mean 1, so stiffness.toml keeps the model's mean stiffness and changes its distribution".into(),
        assumptions: vec![
            "each joint's lateral bending, axial rotation and flexion-extension stiffness scale together by one multiplier; translational stiffness is the model's".into(),
            "the bushings are at rest in the model's default pose (the unbent shape); no gravity, no muscles: the loaded level's lateral force and frontal moment carry the patient's effort".into(),
            format!("film points are independent with {:.1} mm SD per coordinate; intervals use the fit's residual variance when larger", opts.noise * 1e3),
            match opts.prior_sd {
                Some(s) => format!("prior: each log multiplier ~ N(0, {s}^2) (95% within a factor {:.1} of the spine's mean)", (1.96 * s).exp()),
                None => "no prior".into(),
            },
        ],
        estimate: est.map(|e| e.summary.clone()),
        joints,
        unresolved_joints: unresolved,
        regions,
        curves,
        neutral_calibration: None,
        films: film_reports,
        findings,
    };
    Ok(Flexibility {
        report,
        stiffness_toml,
        predicted,
        figures,
    })
}

/// Per-joint and per-region estimates.
fn joint_estimates(
    bm: &BendModel,
    e: &Estimate,
    all: &[Film],
) -> Result<(Vec<JointEstimate>, Vec<RegionEstimate>)> {
    let n = e.joints.len();
    // relative stiffness: the lateral-bending stiffness over its geometric mean
    let log_k: Vec<f64> = e.joints.iter().map(|&j| bm.joints[j].k[0].ln()).collect();
    let mean_k = log_k.iter().sum::<f64>() / n as f64;
    let joints = (0..n)
        .map(|i| {
            let mut a = vec![0.0; n];
            a[i] = 1.0;
            let (v, ci, sd) = report::combination(&a, &e.log_m, &e.cov);
            let shift = (log_k[i] - mean_k).exp();
            let ci = [ci[0] * shift, ci[1] * shift];
            JointEstimate {
                joint: bm.joints[e.joints[i]].name.clone(),
                relative_stiffness: v * shift,
                ci95: ci,
                log_sd: sd,
                resolved: report::resolved(ci),
            }
        })
        .collect();
    // Regions: thoracic, lumbar, the main curve and the rest, and their ratio.
    let name = |i: usize| bm.joints[e.joints[i]].name.clone();
    let upper = |i: usize| bm.joints[e.joints[i]].upper;
    let mut groups: Vec<(String, Vec<usize>)> = vec![
        (
            "thoracic".into(),
            (0..n).filter(|&i| upper(i) < Level::T12).collect(),
        ),
        (
            "thoracolumbar and lumbar".into(),
            (0..n).filter(|&i| upper(i) >= Level::T12).collect(),
        ),
    ];
    if let Some((u, w)) = main_curve_ends(bm, all)? {
        let inside: Vec<usize> = (0..n).filter(|&i| upper(i) >= u && upper(i) < w).collect();
        let outside: Vec<usize> = (0..n).filter(|i| !inside.contains(i)).collect();
        groups.push((format!("main curve {u}-{w}"), inside));
        groups.push(("outside the main curve".into(), outside));
    }
    let mut regions = Vec::new();
    for (label, idx) in &groups {
        if idx.is_empty() {
            continue;
        }
        let mut a = vec![0.0; n];
        for &i in idx {
            a[i] = 1.0 / idx.len() as f64;
        }
        let shift: f64 = idx
            .iter()
            .map(|&i| (log_k[i] - mean_k) / idx.len() as f64)
            .sum();
        let (v, ci, _) = report::combination(&a, &e.log_m, &e.cov);
        let ci = [ci[0] * shift.exp(), ci[1] * shift.exp()];
        regions.push(RegionEstimate {
            region: label.clone(),
            joints: idx.iter().map(|&i| name(i)).collect(),
            relative_stiffness: v * shift.exp(),
            ci95: ci,
            resolved: report::resolved(ci),
        });
    }
    if let [.., (li, inside), (_, outside)] = groups.as_slice() {
        if li.starts_with("main curve") && !inside.is_empty() && !outside.is_empty() {
            let mut a = vec![0.0; n];
            for &i in inside {
                a[i] += 1.0 / inside.len() as f64;
            }
            for &i in outside {
                a[i] -= 1.0 / outside.len() as f64;
            }
            let shift: f64 = (0..n).map(|i| a[i] * (log_k[i] - mean_k)).sum();
            let (v, ci, _) = report::combination(&a, &e.log_m, &e.cov);
            let ci = [ci[0] * shift.exp(), ci[1] * shift.exp()];
            regions.push(RegionEstimate {
                region: format!("{li} / outside (ratio of geometric means)"),
                joints: inside.iter().map(|&i| name(i)).collect(),
                relative_stiffness: v * shift.exp(),
                ci95: ci,
                resolved: report::resolved(ci),
            });
        }
    }
    Ok((joints, regions))
}

/// The unbent shape's frontal tilts and where they come from: the first
/// unbent film (in the model's frontal plane), else the model at rest.
fn unbent_tilts(bm: &BendModel, all: &[Film]) -> Result<(String, FrontalTilts)> {
    if let Some(f) = all.iter().find(|f| f.role == Role::Unbent) {
        return Ok((
            f.data.file.clone(),
            report::film_tilts(&report::film_in_model(&f.data, &f.uniform.place)),
        ));
    }
    let rest = FilmState {
        loads: [0.0; 3],
        place: place::Placement {
            phi: 0.0,
            t: Vector2::zeros(),
        },
        q: bm.rest.clone(),
    };
    Ok((
        "model".into(),
        report::film_tilts(&model_points(bm, &rest)?),
    ))
}

/// The main curve's end vertebrae of the unbent shape.
fn main_curve_ends(bm: &BendModel, all: &[Film]) -> Result<Option<(Level, Level)>> {
    let (_, tilts) = unbent_tilts(bm, all)?;
    Ok(report::curves_of(&tilts)
        .first()
        .map(|(_, c)| (c.upper, c.lower)))
}

/// The curves of the unbent shape and their angles on every film.
fn curves(bm: &BendModel, all: &[Film], personalised: bool) -> Result<Vec<report::Curve>> {
    let (source, tilts) = unbent_tilts(bm, all)?;
    let mut out = Vec::new();
    for (name, c) in report::curves_of(&tilts) {
        let unbent = c.angle_deg;
        let flex = |x: Option<f64>| x.map(|v| v / unbent);
        let mut films = Vec::new();
        for f in all {
            let measured = report::cobb_between(
                &report::film_tilts(&report::film_in_model(&f.data, &f.uniform.place)),
                &c,
            );
            let uniform =
                report::cobb_between(&report::film_tilts(&model_points(bm, &f.uniform)?), &c);
            let pers = match (&f.personalised, personalised) {
                (Some(st), true) => {
                    report::cobb_between(&report::film_tilts(&model_points(bm, st)?), &c)
                }
                _ => None,
            };
            films.push(report::CurveOnFilm {
                film: f.data.file.clone(),
                measured_cobb_deg: measured,
                measured_flexibility: flex(measured),
                personalised_cobb_deg: pers,
                personalised_flexibility: flex(pers),
                uniform_cobb_deg: uniform,
                uniform_flexibility: flex(uniform),
            });
        }
        out.push(report::Curve {
            curve: name,
            upper: c.upper,
            lower: c.lower,
            defined_on: source.clone(),
            unbent_cobb_deg: unbent,
            films,
        });
    }
    Ok(out)
}

/// `predicted_<stem>.csv`: every frontal point of the model bent to the
/// film, placed on it, at the film's scale.
fn predicted_film(bm: &BendModel, f: &Film, uniform: bool) -> Result<(String, String)> {
    let st = if uniform {
        &f.uniform
    } else {
        f.personalised.as_ref().unwrap_or(&f.uniform)
    };
    let mag = f.raw.projection.magnification();
    let pts: BTreeMap<FilmPoint, Vector2<f64>> = model_points(bm, st)?
        .into_iter()
        .map(|(p, m)| (p, st.place.apply(&m) * mag))
        .collect();
    let which = if uniform {
        "uniform (the model's own)"
    } else {
        "personalised"
    };
    let film = format!(
        "predicted from {} ({}) with the {which} stiffness",
        f.data.file,
        f.raw.film.as_deref().unwrap_or("no film text")
    );
    let comments = vec![format!(
        "osim-spine flexibility: the model bent to the given levels ({} given points), every other level predicted",
        f.data.points.len()
    )];
    Ok((
        format!("predicted_{}.csv", f.data.stem),
        radiograph::write_csv(&pts, f.raw.projection, &film, &comments),
    ))
}

/// The figure of one film.
fn figure(bm: &BendModel, f: &Film, curves: &[report::Curve]) -> Result<(String, String)> {
    let cobb_text = |pts: &BTreeMap<FilmPoint, Vector2<f64>>| -> String {
        let t = report::film_tilts(pts);
        let parts: Vec<String> = curves
            .iter()
            .filter_map(|c| {
                let ends = crate::landmarks::metrics::Cobb {
                    angle_deg: 0.0,
                    upper: c.upper,
                    lower: c.lower,
                    automatic: false,
                };
                report::cobb_between(&t, &ends)
                    .map(|a| format!("{}-{} {a:.1} deg", c.upper, c.lower))
            })
            .collect();
        if parts.is_empty() {
            String::new()
        } else {
            format!(" (Cobb {})", parts.join(", "))
        }
    };
    let measured = report::film_in_model(&f.data, &f.uniform.place);
    let mut layers = vec![views::Layer {
        label: format!("film{}", cobb_text(&measured)),
        colour: views::MEASURED,
        points: measured,
    }];
    if let Some(st) = &f.personalised {
        let pts = model_points(bm, st)?;
        layers.push(views::Layer {
            label: format!("personalised model{}", cobb_text(&pts)),
            colour: views::PERSONALISED,
            points: pts,
        });
    }
    let pts = model_points(bm, &f.uniform)?;
    layers.push(views::Layer {
        label: format!("uniform model{}", cobb_text(&pts)),
        colour: views::UNIFORM,
        points: pts,
    });
    let title = format!(
        "{} ({}), placed on the model's pelvis",
        f.data.stem,
        f.raw.film.as_deref().unwrap_or("film")
    );
    Ok((
        format!("{}.svg", f.data.stem),
        views::film_figure(&title, &layers),
    ))
}

/// `stiffness.toml`: every estimated joint's law as the model's stiffness
/// times its multiplier (rotational DoFs).
fn stiffness_table(model: &Model, bm: &BendModel, e: &Estimate) -> Result<String> {
    let mut rows = Vec::new();
    for &j in &e.joints {
        let joint = &bm.joints[j];
        let law = bm
            .sys
            .bushing_model(joint.bushing)
            .ok_or_else(|| Error::invalid("flexibility", "bushing index out of range"))?;
        let law: LevelLaw = crate::personalise::law_of_model(law, None)?;
        let m = e.multipliers[j];
        rows.push((joint.name.clone(), law, [m, m, m, 1.0, 1.0, 1.0]));
    }
    let comments = vec![
        format!(
            "Personalised intervertebral stiffness from bending films by osim-spine flexibility, for {}",
            model.file.file_name().map(|n| n.to_string_lossy().to_string()).unwrap_or_default()
        ),
        "stiffness = the model's own; ratio = the estimated multiplier of each joint's rotational stiffness (geometric mean 1 over the estimated joints: the films fix only ratios)".into(),
        "apply with: osim-spine stiffness MODEL.osim --table stiffness.toml --out PERSONALISED.osim".into(),
    ];
    Ok(write_toml_ratios(&comments, &rows))
}
