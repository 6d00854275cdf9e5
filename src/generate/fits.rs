//! Step 2, the per-vertebra fits: landmark coverage, reduced fits with
//! borrowed scales, the protocol check and its compensation, and the
//! spinal-continuity smoothing of the fitted orientations.

use super::joints::{best_joint_model, chain_joints};
use super::pose::Method;
use super::pose::Points;
use super::smooth::Smooth;
use super::{chain, pose, residuals, smooth, JointScaling};
use super::{
    GenerateOptions, JointCentres, JointGeometry, ReducedFit, SmoothingLevel, SmoothingReport,
};
use crate::base::centres::{model_centres, CentreDef};
use crate::error::{Error, Result};
use crate::landmarks::{Code, LandmarkSet, Level};
use crate::osim::model::Model;
use nalgebra::{Isometry3, Point3, Vector3};
use std::collections::BTreeMap;

/// Levels of the set, ending at S1 (the check module reports the details;
/// this is the generator's own guard). Levels missing between measured
/// ones are filled from their neighbours ([`fill`](super::fill)).
pub(super) fn set_levels(set: &LandmarkSet, file: &str) -> Result<Vec<Level>> {
    let levels = set.levels();
    if levels.last() != Some(&Level::S1) {
        return Err(Error::invalid(
            file,
            "the landmark set has no S1 landmarks: the levels must end at the sacrum",
        ));
    }
    Ok(levels)
}

/// Fewest landmarks a vertebra is fitted on (of 14): the lsq fit of a
/// pose and three scale factors, with one landmark left out in turn.
pub const MIN_VERTEBRA_LANDMARKS: usize = 8;

/// Fewest sacral landmarks for the registration (a rigid fit needs 3).
pub const MIN_SACRUM_LANDMARKS: usize = 3;

/// Check that the base model has every marker of each landmarked level,
/// and list the levels whose landmarks are incomplete: fitted on what is
/// there (a reduced fit) when at least [`MIN_VERTEBRA_LANDMARKS`]
/// ([`MIN_SACRUM_LANDMARKS`] for S1) remain, refused otherwise.
pub(super) fn landmark_coverage(
    levels: &[Level],
    patient: &BTreeMap<Level, Points>,
    markers: &BTreeMap<Level, (String, Points)>,
    set_name: &str,
    bfile: &str,
) -> Result<Vec<ReducedFit>> {
    let mut reduced = Vec::new();
    for l in levels {
        let (_, mpts) = markers.get(l).ok_or_else(|| {
            Error::invalid(
                bfile,
                format!(
                    "the landmarks cover {l} but the base model has no {l} markers (body '{}')",
                    l.body_name()
                ),
            )
        })?;
        let absent = |have: &Points| -> Vec<String> {
            l.required_codes()
                .iter()
                .filter(|c| !have.contains_key(c))
                .map(|c| format!("{l}_{c}"))
                .collect()
        };
        let mmissing = absent(mpts);
        if !mmissing.is_empty() {
            return Err(Error::invalid(
                bfile,
                format!("the base model lacks the marker(s) {}", mmissing.join(", ")),
            ));
        }
        let have = patient.get(l).cloned().unwrap_or_default();
        let missing = absent(&have);
        if missing.is_empty() {
            continue;
        }
        let need = if l.is_sacrum() {
            MIN_SACRUM_LANDMARKS
        } else {
            MIN_VERTEBRA_LANDMARKS
        };
        let used = l.required_codes().len() - missing.len();
        if used < need {
            return Err(Error::invalid(
                set_name,
                format!(
                    "{l}: only {used} landmark(s) (missing {}); a fit needs at least {need}",
                    missing.join(", ")
                ),
            ));
        }
        reduced.push(ReducedFit {
            level: *l,
            missing,
            used,
            borrowed_scale: Vec::new(),
        });
    }
    Ok(reduced)
}

/// What every fit of step 2 shares: the levels, the base's markers and
/// joint centres, the options.
pub(super) struct FitInput<'a> {
    pub(super) vert_levels: &'a [Level],
    pub(super) markers: &'a BTreeMap<Level, (String, Points)>,
    /// Base joint centres between consecutive vertebrae, in each body (the
    /// chain smoothing's prior).
    pub(super) joint_centres: JointCentres,
    /// Each vertebra's centre in its body frame (the chain's joint model).
    pub(super) body_centres: BTreeMap<Level, Point3<f64>>,
    /// Scale factors borrowed from the neighbours where a vertebra's
    /// landmarks cannot measure a dimension.
    pub(super) borrowed: BTreeMap<Level, pose::Borrowed>,
    pub(super) opts: &'a GenerateOptions,
}

/// The scale factors each vertebra borrows from its neighbours
/// ([`pose::borrowed_scales`]), noted on its reduced fit.
pub(super) fn borrowed_scales(
    vert_levels: &[Level],
    patient: &BTreeMap<Level, Points>,
    markers: &BTreeMap<Level, (String, Points)>,
    reduced: &mut [ReducedFit],
) -> BTreeMap<Level, pose::Borrowed> {
    let model: BTreeMap<Level, Points> =
        markers.iter().map(|(l, (_, p))| (*l, p.clone())).collect();
    let all = pose::borrowed_scales(vert_levels, patient, &model);
    for r in reduced.iter_mut() {
        let Some((b, from)) = all.get(&r.level) else {
            continue;
        };
        let from: Vec<String> = from.iter().map(Level::to_string).collect();
        r.borrowed_scale = (0..3)
            .filter_map(|k| {
                Some(format!(
                    "{} {:.3} from {}",
                    pose::DIMENSIONS[k],
                    b[k]?,
                    from.join(", ")
                ))
            })
            .collect();
    }
    all.into_iter().map(|(l, (b, _))| (l, b)).collect()
}

/// Each vertebra's centre in its (unscaled) body frame: the vertebral
/// centre of [`model_centres`] (its vertebral-body wrap sphere, else the
/// midpoint of its SEC and IEC markers) with every body at the identity.
pub(super) fn base_body_centres(model: &Model) -> Result<BTreeMap<Level, Point3<f64>>> {
    let identity: BTreeMap<String, Isometry3<f64>> = model
        .bodies
        .iter()
        .map(|b| (b.name.clone(), Isometry3::identity()))
        .collect();
    model_centres(model, &identity, CentreDef::Sphere)
}

/// The fits of step 2: poses, the set's palpation noise (lsq), smoothing.
pub(super) struct LevelFits {
    pub(super) fits: BTreeMap<Level, pose::VertebraFit>,
    pub(super) noise: Option<f64>,
    pub(super) smoothing: SmoothingReport,
}

/// Step 2: fit every vertebra to `patient` (lsq: with the palpation noise
/// estimated over the whole set for the outlier test), then smooth the
/// orientations along the chain with the base joint centres as prior.
pub(super) fn fit_levels(
    input: &FitInput,
    markers: &BTreeMap<Level, (String, Points)>,
    patient: &BTreeMap<Level, Points>,
) -> Result<LevelFits> {
    let (vert_levels, opts) = (input.vert_levels, input.opts);
    // The leave-one-out statistics of every vertebra: the set-wide noise
    // estimate, then each vertebra's outlier test.
    let loo: Vec<pose::VertebraLoo> = match opts.method {
        Method::Lsq => vert_levels
            .iter()
            .map(|l| pose::vertebra_loo(*l, &patient[l], &markers[l].1))
            .collect(),
        Method::Thesis => Vec::new(),
    };
    let noise = match opts.method {
        Method::Lsq => pose::set_noise_sd(&loo),
        Method::Thesis => None,
    };
    let mut fits: BTreeMap<Level, pose::VertebraFit> = BTreeMap::new();
    for (k, l) in vert_levels.iter().enumerate() {
        let borrowed = input.borrowed.get(l).unwrap_or(&[None; 3]);
        let (points, model) = (&patient[l], &markers[l].1);
        // Lsq fits with the statistics above; the thesis method has none.
        let f = match loo.get(k) {
            Some(v) => pose::fit_lsq(
                *l,
                points,
                model,
                &v.full,
                opts.outlier_sigmas,
                noise,
                borrowed,
            )?,
            None => pose::fit_vertebra_with(
                *l,
                points,
                model,
                opts.method,
                opts.outlier_sigmas,
                noise,
                borrowed,
            )?,
        };
        fits.insert(*l, f);
    }
    let smoothing = smooth_fits(
        &mut fits,
        vert_levels,
        patient,
        markers,
        &JointGeometry {
            joint_centres: &input.joint_centres,
            centres: &input.body_centres,
        },
        opts,
        noise,
    )?;
    Ok(LevelFits {
        fits,
        noise,
        smoothing,
    })
}

/// Step 2 with the protocol check: fit, list the per-landmark residuals,
/// and when one code is off the same way at several levels (a set
/// palpated by another protocol than the base's markers), say so and
/// compensate it: that code's base marker is moved by its offset at every
/// level and the vertebrae are refitted with every landmark (lsq; at most
/// [`MAX_COMPENSATED_CODES`] codes, so that the others anchor the poses).
pub(super) fn fit_with_protocol_check(
    input: &FitInput,
    patient: &BTreeMap<Level, Points>,
) -> Result<(
    LevelFits,
    Vec<residuals::LandmarkResidual>,
    Vec<residuals::ProtocolMismatch>,
)> {
    let first = fit_levels(input, input.markers, patient)?;
    let res = residuals::landmark_residuals(&first.fits, patient, input.markers);
    let mut mismatches = residuals::protocol_mismatches(&res, first.noise.unwrap_or(PALPATION_SD));
    if mismatches.is_empty()
        || mismatches.len() > MAX_COMPENSATED_CODES
        || input.opts.method != Method::Lsq
    {
        return Ok((first, res, mismatches));
    }
    let codes: Vec<Code> = mismatches.iter().map(|m| m.code).collect();
    let (fit, res, offsets) = compensate(input, patient, first, res, &codes)?;
    for m in &mut mismatches {
        m.compensated = true;
        let d = offsets[&m.code] * 1e3;
        m.mean_offset_mm = [d.x, d.y, d.z];
    }
    Ok((fit, res, mismatches))
}

/// Most codes compensated in one set: the other landmarks (at least 8 of
/// 14) anchor the poses, so an offset is not mistaken for a translation or
/// rotation of every vertebra.
pub const MAX_COMPENSATED_CODES: usize = 6;

/// Refits of [`compensate`]: each one removes most of what is left of the
/// offsets (the part the fit absorbed, about the code's leverage, 1/5).
pub(super) const COMPENSATION_ROUNDS: usize = 8;

/// Offsets of the mismatched `codes` (vertebra frame, m) found by
/// refitting with their markers moved by the offsets so far, until the
/// median residual of each code is under 0.01 mm; the last fit, its
/// residuals (against the moved markers) and the offsets.
#[allow(clippy::type_complexity)]
pub(super) fn compensate(
    input: &FitInput,
    patient: &BTreeMap<Level, Points>,
    mut fit: LevelFits,
    mut res: Vec<residuals::LandmarkResidual>,
    codes: &[Code],
) -> Result<(
    LevelFits,
    Vec<residuals::LandmarkResidual>,
    BTreeMap<Code, Vector3<f64>>,
)> {
    let mut offsets: BTreeMap<Code, Vector3<f64>> =
        codes.iter().map(|c| (*c, Vector3::zeros())).collect();
    for _ in 0..COMPENSATION_ROUNDS {
        // What is left of each code's offset: its median residual.
        let step = residuals::median_offsets(&res, codes);
        for (c, d) in &step {
            *offsets.entry(*c).or_default() += d;
        }
        // Refit with the moved markers.
        let moved = moved_markers(input.markers, &fit.fits, &offsets);
        fit = fit_levels(input, &moved, patient)?;
        res = residuals::landmark_residuals(&fit.fits, patient, &moved);
        if step.values().all(|d| d.norm() < 1e-5) {
            break;
        }
    }
    Ok((fit, res, offsets))
}

/// The base markers with each code of `offsets` moved by its offset (given
/// in the fitted, scaled vertebra's frame, so divided by that level's
/// scale factors); levels without a fit keep theirs.
pub(super) fn moved_markers(
    markers: &BTreeMap<Level, (String, Points)>,
    fits: &BTreeMap<Level, pose::VertebraFit>,
    offsets: &BTreeMap<Code, Vector3<f64>>,
) -> BTreeMap<Level, (String, Points)> {
    let mut out = markers.clone();
    for (l, (_, pts)) in out.iter_mut() {
        let Some(f) = fits.get(l) else { continue };
        for (c, d) in offsets {
            if let Some(p) = pts.get_mut(c) {
                *p += d.component_div(&f.scale);
            }
        }
    }
    out
}

/// Palpation noise assumed where the set's own cannot be estimated (m per
/// axis; the thesis's sensitivity studies use 2.9 mm 3-D).
pub(super) const PALPATION_SD: f64 = 0.002;

/// Replace the fitted orientations by their spinal-continuity posterior
/// ([`smooth::smooth_orientations`]) when `opts.smooth` asks for it: each
/// vertebra turns about the centroid of its used landmarks' markers (its
/// least-squares position is kept) and its residuals are recomputed.
pub(super) fn smooth_fits(
    fits: &mut BTreeMap<Level, pose::VertebraFit>,
    chain: &[Level],
    patient: &BTreeMap<Level, Points>,
    markers: &BTreeMap<Level, (String, Points)>,
    geometry: &JointGeometry,
    opts: &GenerateOptions,
    noise: Option<f64>,
) -> Result<SmoothingReport> {
    let mut rep = SmoothingReport {
        mode: opts.smooth,
        applied: false,
        note: String::new(),
        tau_deg: None,
        effective_dof: None,
        parameters: 3 * chain.len(),
        joint_sd_mm: None,
        joint_scaling: None,
        levels: Vec::new(),
    };
    if opts.smooth == Smooth::Off {
        rep.note = "off".into();
        return Ok(rep);
    }
    if opts.method != Method::Lsq {
        rep.note = "not applied: smoothing needs the lsq fit's covariance (--method lsq)".into();
        return Ok(rep);
    }
    // Scaled markers of the used landmarks (body frame) per chain vertebra.
    let mut used: Vec<Vec<(Code, Point3<f64>)>> = Vec::new();
    let mut rots = Vec::new();
    let mut info = Vec::new();
    for l in chain {
        let (Some(f), Some((_, m))) = (fits.get(l), markers.get(l)) else {
            return Err(Error::invalid(
                format!("vertebra {l}"),
                "no fit or base-model markers to smooth",
            ));
        };
        let pts: Vec<(Code, Point3<f64>)> = f
            .residuals
            .keys()
            .filter_map(|c| Some((*c, pose::scale_point(m.get(c)?, &f.scale))))
            .collect();
        let posed: Vec<Point3<f64>> = pts.iter().map(|(_, p)| f.pose * p).collect();
        info.push(smooth::rotation_information(&posed));
        rots.push(f.pose.rotation);
        used.push(pts);
    }
    let sigma = noise.unwrap_or(0.0);
    if opts.smooth == Smooth::Chain {
        return chain_fits(fits, chain, patient, &used, geometry, sigma, rep);
    }
    let Some(s) = smooth::smooth_orientations(&rots, &info, sigma)? else {
        rep.note = if chain.len() < smooth::MIN_LEVELS {
            format!(
                "not applied: {} vertebrae (at least {} needed)",
                chain.len(),
                smooth::MIN_LEVELS
            )
        } else {
            "not applied: no landmark noise (the fits are exact)".into()
        };
        return Ok(rep);
    };
    for (k, l) in chain.iter().enumerate() {
        let (Some(f), Some(pts), Some(q), Some(pl)) = (
            fits.get_mut(l),
            used.get(k),
            s.rotations.get(k),
            patient.get(l),
        ) else {
            continue;
        };
        let n = pts.len().max(1) as f64;
        let mbar = Point3::from(pts.iter().fold(Vector3::zeros(), |a, (_, p)| a + p.coords) / n);
        let c = f.pose * mbar;
        let t = c.coords - q * mbar.coords;
        let pose = Isometry3::from_parts(t.into(), *q);
        rep.levels.push(apply_posterior(
            *l,
            f,
            pose,
            pts,
            pl,
            s.raw_sd[k],
            s.posterior_sd[k],
        ));
    }
    rep.applied = true;
    rep.tau_deg = Some(std::array::from_fn(|a| s.tau[a].to_degrees()));
    rep.effective_dof = Some(s.effective_dof);
    rep.note = format!(
        "posterior orientations (tau {:.2} / {:.2} / {:.2} deg per level^2 about X / Y / Z, {:.1} of {} orientation parameters kept)",
        s.tau.x.to_degrees(),
        s.tau.y.to_degrees(),
        s.tau.z.to_degrees(),
        s.effective_dof,
        3 * chain.len()
    );
    Ok(rep)
}

/// Replace a fit's pose by its posterior `pose`, recompute the residuals of
/// its used landmarks `pts` (scaled markers, body frame) against the
/// patient's `landmarks`, and give the report row (SDs in rad).
pub(super) fn apply_posterior(
    level: Level,
    f: &mut pose::VertebraFit,
    pose: Isometry3<f64>,
    pts: &[(Code, Point3<f64>)],
    landmarks: &Points,
    raw_sd: [f64; 3],
    posterior_sd: [f64; 3],
) -> SmoothingLevel {
    let before = f.pose.rotation;
    f.pose = pose;
    f.residuals = pts
        .iter()
        .filter_map(|(code, p)| Some((*code, (landmarks.get(code)? - pose * p).norm())))
        .collect();
    SmoothingLevel {
        level,
        fit_sd_deg: raw_sd.map(f64::to_degrees),
        posterior_sd_deg: posterior_sd.map(f64::to_degrees),
        correction_deg: before.angle_to(&pose.rotation).to_degrees(),
    }
}

/// [`chain::smooth_chain`] on the lsq fits: neighbours meet at the base
/// model's joint centres (scaled with each body).
pub(super) fn chain_fits(
    fits: &mut BTreeMap<Level, pose::VertebraFit>,
    chain: &[Level],
    patient: &BTreeMap<Level, Points>,
    used: &[Vec<(Code, Point3<f64>)>],
    geometry: &JointGeometry,
    sigma: f64,
    mut rep: SmoothingReport,
) -> Result<SmoothingReport> {
    rep.parameters = 6 * chain.len();
    let mut verts = Vec::with_capacity(chain.len());
    for (l, pts) in chain.iter().zip(used) {
        let Some(f) = fits.get(l) else {
            return Err(Error::invalid(format!("vertebra {l}"), "no fit to smooth"));
        };
        let posed: Vec<Point3<f64>> = pts.iter().map(|(_, p)| f.pose * p).collect();
        let n = posed.len().max(1);
        let c = posed.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / n as f64;
        verts.push(chain::ChainVertebra {
            pose: f.pose,
            centroid: c.into(),
            info_rot: smooth::rotation_information(&posed),
            n,
        });
    }
    let Some((s, scaling)) = best_joint_model(&verts, fits, chain, geometry, sigma)? else {
        rep.note = if chain_joints(fits, chain, geometry, JointScaling::WithBody).is_empty() {
            "not applied: no joint between two landmarked vertebrae".into()
        } else {
            "not applied: no landmark noise (the fits are exact)".into()
        };
        return Ok(rep);
    };
    for (k, l) in chain.iter().enumerate() {
        let (Some(f), Some(pts), Some(x), Some(pl)) =
            (fits.get_mut(l), used.get(k), s.poses.get(k), patient.get(l))
        else {
            continue;
        };
        rep.levels.push(apply_posterior(
            *l,
            f,
            *x,
            pts,
            pl,
            s.raw_sd[k],
            s.posterior_sd[k],
        ));
    }
    rep.applied = true;
    rep.effective_dof = Some(s.effective_dof);
    rep.joint_sd_mm = Some(std::array::from_fn(|a| s.s[a] * 1e3));
    rep.joint_scaling = Some(scaling);
    rep.note = format!(
        "posterior poses of the kinematic chain, {} (joint mismatch SD {:.2} / {:.2} / {:.2} mm along the lower body's X / Y / Z, common offset {:.2} / {:.2} / {:.2} mm; {:.1} of {} pose parameters kept)",
        scaling.describe(),
        s.s.x * 1e3,
        s.s.y * 1e3,
        s.s.z * 1e3,
        s.mu.x * 1e3,
        s.mu.y * 1e3,
        s.mu.z * 1e3,
        s.effective_dof,
        6 * chain.len()
    );
    Ok(rep)
}
