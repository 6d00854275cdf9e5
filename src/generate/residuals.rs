//! Per-landmark residuals of the vertebra fits (as OpenSim's Scale tool
//! lists per-marker errors), and protocol mismatches: one landmark code
//! off the same way in the vertebra frames at several levels is not a set
//! of independent outliers but a palpation that followed another protocol
//! than the base model's markers (`../shared/formats/landmarks.md`, "How
//! each landmark is placed").

use super::pose::{scale_point, Points, VertebraFit};
use crate::landmarks::{Code, Level};
use crate::util::quantiles::median;
use nalgebra::Vector3;
use std::collections::BTreeMap;

/// Fewest levels at which one code must be off the same way.
pub(crate) const MISMATCH_MIN_LEVELS: usize = 3;
/// Smallest mean offset of a mismatched code (m).
pub(crate) const MISMATCH_MIN_OFFSET: f64 = 0.002;
/// The mean offset must exceed this many standard errors of a mean of
/// palpation noise.
pub(crate) const MISMATCH_MIN_T: f64 = 5.0;
/// Share of the levels whose residual points along the mean offset.
pub(crate) const MISMATCH_MIN_AGREEMENT: f64 = 0.75;
/// More codes off than this is not a palpation protocol but vertebrae of
/// another shape than the base's (reported as such; still compensated up
/// to `generate::MAX_COMPENSATED_CODES`).
pub(crate) const MAX_PROTOCOL_CODES: usize = 3;

/// What a consistent offset of a code means.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum MismatchKind {
    /// One or a few codes: palpated by another protocol than the base's.
    Protocol,
    /// Many codes: the base's vertebrae differ in shape from the patient's.
    Shape,
}

/// One landmark's residual after its vertebra's fit.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct LandmarkResidual {
    /// `L3_SP`.
    pub landmark: String,
    /// The landmark's level.
    #[serde(skip)]
    pub level: Level,
    /// The landmark's code.
    #[serde(skip)]
    pub code: Code,
    /// Landmark minus the fitted model marker, in the vertebra's frame
    /// (x anterior, y cranial, z right), mm.
    pub residual_mm: [f64; 3],
    /// Its length, mm.
    pub distance_mm: f64,
    /// Whether the fit used it (not an outlier, not a mismatched code).
    pub used: bool,
}

/// A code palpated by another protocol than the base's markers.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ProtocolMismatch {
    /// The mismatched code.
    pub code: Code,
    /// Protocol or shape mismatch.
    pub kind: MismatchKind,
    /// Levels where its residual points along the mean offset.
    pub levels: Vec<Level>,
    /// The code's offset from the base's marker, vertebra frame (x
    /// anterior, y cranial, z right), mm: its mean residual over the
    /// levels, or, when compensated, the offset the refit settled on.
    pub mean_offset_mm: [f64; 3],
    /// Whether the vertebrae were refitted with this code's marker moved
    /// by the offset at every level.
    pub compensated: bool,
}

impl std::fmt::Display for ProtocolMismatch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let [x, y, z] = self.mean_offset_mm;
        let n = (x * x + y * y + z * z).sqrt();
        write!(
            f,
            "every {} sits {n:.1} mm from where the base model's markers put it ({} levels: mean offset {x:+.1} mm anterior, {y:+.1} mm cranial, {z:+.1} mm right, vertebra frames): ",
            self.code,
            self.levels.len(),
        )?;
        match self.kind {
            MismatchKind::Protocol => write!(f, "the set follows another palpation protocol for {}", self.code),
            MismatchKind::Shape => write!(f, "with this many codes off, the base's vertebrae differ in shape from the patient's (a base from meshes like the patient's, or base --palpation, fits better)"),
        }
    }
}

/// Residual of every landmark of every fitted vertebra.
pub fn landmark_residuals(
    fits: &BTreeMap<Level, VertebraFit>,
    patient: &BTreeMap<Level, Points>,
    markers: &BTreeMap<Level, (String, Points)>,
) -> Vec<LandmarkResidual> {
    let mut out = Vec::new();
    for (l, f) in fits {
        let (Some(pts), Some((_, m))) = (patient.get(l), markers.get(l)) else {
            continue;
        };
        for (c, p) in pts {
            let Some(mk) = m.get(c) else { continue };
            // Landmark minus the scaled, posed marker, in the vertebra frame.
            let r = f.pose.rotation.inverse() * (p - f.pose * scale_point(mk, &f.scale));
            out.push(LandmarkResidual {
                landmark: format!("{l}_{c}"),
                level: *l,
                code: *c,
                residual_mm: [r.x * 1e3, r.y * 1e3, r.z * 1e3],
                distance_mm: r.norm() * 1e3,
                used: f.residuals.contains_key(c),
            });
        }
    }
    out
}

/// Codes whose residuals point the same way at [`MISMATCH_MIN_LEVELS`] or
/// more levels, by more than palpation noise (`noise_sd`, m per axis).
pub fn protocol_mismatches(res: &[LandmarkResidual], noise_sd: f64) -> Vec<ProtocolMismatch> {
    let mut by_code: BTreeMap<Code, Vec<&LandmarkResidual>> = BTreeMap::new();
    for r in res.iter().filter(|r| !r.level.is_sacrum()) {
        by_code.entry(r.code).or_default().push(r);
    }
    let mut out = Vec::new();
    for (code, rs) in by_code {
        let n = rs.len();
        if n < MISMATCH_MIN_LEVELS {
            continue;
        }
        // Mean offset, and its size against the noise of a mean.
        let v = |r: &LandmarkResidual| Vector3::from(r.residual_mm) * 1e-3;
        let mean = rs.iter().fold(Vector3::zeros(), |a, r| a + v(r)) / n as f64;
        let se = noise_sd / (n as f64).sqrt();
        if mean.norm() < MISMATCH_MIN_OFFSET || mean.norm() < MISMATCH_MIN_T * se {
            continue;
        }
        // Levels whose residual points along it (at least half its size).
        let dir = mean.normalize();
        let agree: Vec<Level> = rs
            .iter()
            .filter(|r| v(r).dot(&dir) >= 0.5 * mean.norm())
            .map(|r| r.level)
            .collect();
        if agree.len() < MISMATCH_MIN_LEVELS
            || (agree.len() as f64) < MISMATCH_MIN_AGREEMENT * n as f64
        {
            continue;
        }
        out.push(ProtocolMismatch {
            code,
            kind: MismatchKind::Protocol,
            levels: agree,
            mean_offset_mm: [mean.x * 1e3, mean.y * 1e3, mean.z * 1e3],
            compensated: false,
        });
    }
    if out.len() > MAX_PROTOCOL_CODES {
        out.iter_mut().for_each(|m| m.kind = MismatchKind::Shape);
    }
    out
}

/// Per-axis median residual (vertebra frame, m) of each of `codes` over
/// the vertebrae (the sacrum has its own layout): a robust mean, so that
/// one outlier does not move a code's offset.
pub fn median_offsets(res: &[LandmarkResidual], codes: &[Code]) -> BTreeMap<Code, Vector3<f64>> {
    codes
        .iter()
        .filter_map(|c| {
            let rs: Vec<&LandmarkResidual> = res
                .iter()
                .filter(|r| r.code == *c && !r.level.is_sacrum())
                .collect();
            let axis = |k: usize| {
                let v: Vec<f64> = rs.iter().map(|r| r.residual_mm[k] * 1e-3).collect();
                median(&v)
            };
            Some((*c, Vector3::new(axis(0)?, axis(1)?, axis(2)?)))
        })
        .collect()
}
