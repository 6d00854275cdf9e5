//! The model's landmarks calibrated on the unbent (neutral) film.
//!
//! A generated model carries its base's markers, fitted to the patient's
//! landmarks: they miss the patient's own by a millimetre or two (palpation
//! differences, the fit). The unbent film shows where the patient's
//! landmarks are when the spine is at rest, so each landmark the film shows
//! is moved, in the model's frontal plane at rest, towards the film:
//! 1. the film placed on the model at rest (every point, in-plane rigid);
//! 2. per vertebra (and the pelvis as one body) the in-plane rigid motion of
//!    its model landmarks onto the film's, and per landmark code (`SR`,
//!    `IEC`, ...) the mean offset left over the vertebrae (a protocol's
//!    systematic difference), alternated twice;
//! 3. what remains per landmark is partly digitising noise: it is added
//!    with the weight `w = 1 - sigma^2 c / v` (empirical Bayes: `v` the
//!    remainder's variance per coordinate, `c` the fraction of coordinates
//!    not used by step 2's parameters), 0 when the remainder is noise alone.
//!
//! The bodies, joints and bushings are unchanged: only where each marker
//! sits on its vertebra (its depth kept).

use super::bend::BendModel;
use super::fit::FilmData;
use super::place::{procrustes, Placement};
use crate::error::{Error, Result};
use crate::landmarks::radiograph::FilmPoint;
use nalgebra::Vector2;
use serde::Serialize;
use std::collections::BTreeMap;

/// A vertebra (or the pelvis) moved by the calibration.
#[derive(Debug, Clone, Serialize)]
pub struct GroupShift {
    /// `T7`, or `pelvis`.
    pub body: String,
    /// Mean displacement of its landmarks (mm, film axes u, v).
    pub shift_mm: [f64; 2],
    /// In-plane rotation (deg).
    pub rotation_deg: f64,
}

/// What the calibration did.
#[derive(Debug, Clone, Serialize)]
pub struct NeutralCalibration {
    /// The unbent film's file.
    pub film: String,
    /// RMS distance model-at-rest to film, best in-plane placement (mm).
    pub rms_before_mm: f64,
    /// After the per-body motions and code offsets, before the remainder (mm).
    pub rms_rigid_mm: f64,
    /// Weight given to each landmark's remainder.
    pub remainder_weight: f64,
    /// Mean offset per landmark code (mm, film axes).
    pub code_offsets_mm: BTreeMap<String, [f64; 2]>,
    /// The rigid motion per vertebra and the pelvis.
    pub bodies: Vec<GroupShift>,
}

/// The group a film point belongs to: its vertebra, or the pelvis.
fn group(p: &FilmPoint) -> String {
    match p.vertebra() {
        Some(l) => l.to_string(),
        None => "pelvis".into(),
    }
}

/// The code of a vertebral landmark (None for the pelvis).
fn code(p: &FilmPoint) -> Option<String> {
    match p {
        FilmPoint::Landmark(id) if !id.level.is_sacrum() => Some(id.code.to_string()),
        _ => None,
    }
}

/// Calibrate `bm`'s landmarks on the unbent `film` (noise SD `sigma`, m).
pub fn calibrate(
    bm: &BendModel,
    film: &FilmData,
    sigma: f64,
) -> Result<(BendModel, NeutralCalibration)> {
    // 1. The film on the model at rest, in the model's frontal plane.
    let (m, _) = bm.project(&film.points, bm.rest.as_slice(), None)?;
    let (place, rms_before) = procrustes(&m, &film.measured).ok_or_else(|| {
        Error::invalid(
            film.file.clone(),
            "its points coincide: cannot place it on the model",
        )
    })?;
    let f: Vec<Vector2<f64>> = film
        .measured
        .iter()
        .map(|x| place.inverse_apply(x))
        .collect();
    let groups: BTreeMap<String, Vec<usize>> =
        film.points
            .iter()
            .enumerate()
            .fold(BTreeMap::new(), |mut g, (i, p)| {
                g.entry(group(p)).or_default().push(i);
                g
            });
    // 2. Per-body rigid motions and per-code offsets, alternated.
    let mut offsets: BTreeMap<String, Vector2<f64>> = BTreeMap::new();
    let mut a = m.clone();
    let mut motions: BTreeMap<String, Placement> = BTreeMap::new();
    for _ in 0..2 {
        let shifted: Vec<Vector2<f64>> = film
            .points
            .iter()
            .zip(&m)
            .map(|(p, mi)| {
                mi + code(p)
                    .and_then(|c| offsets.get(&c).copied())
                    .unwrap_or_default()
            })
            .collect();
        for (g, idx) in &groups {
            let src: Vec<Vector2<f64>> = idx.iter().map(|&i| shifted[i]).collect();
            let dst: Vec<Vector2<f64>> = idx.iter().map(|&i| f[i]).collect();
            let motion = body_motion(&src, &dst);
            for &i in idx {
                a[i] = motion.apply(&shifted[i]);
            }
            motions.insert(g.clone(), motion);
        }
        let mut sums: BTreeMap<String, (Vector2<f64>, usize)> = BTreeMap::new();
        for (i, p) in film.points.iter().enumerate() {
            if let Some(c) = code(p) {
                let e = sums.entry(c).or_insert((Vector2::zeros(), 0));
                e.0 += f[i] - a[i];
                e.1 += 1;
            }
        }
        for (c, (s, n)) in sums {
            *offsets.entry(c).or_default() += s / n as f64;
        }
    }
    // 3. The remainder, weighted by how much of it is more than noise.
    let n = film.points.len();
    let ss: f64 = f
        .iter()
        .zip(&a)
        .map(|(fi, ai)| (fi - ai).norm_squared())
        .sum();
    let v = ss / (2 * n) as f64;
    let params = 3 * groups.len() + 2 * offsets.len();
    let c = (2 * n).saturating_sub(params) as f64 / (2 * n) as f64;
    let w = if v > 0.0 {
        (1.0 - sigma * sigma * c / v).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let corrected: BTreeMap<FilmPoint, Vector2<f64>> = film
        .points
        .iter()
        .enumerate()
        .filter(|(_, p)| !p.is_pelvic())
        .map(|(i, p)| (*p, a[i] + (f[i] - a[i]) * w))
        .collect();
    let bodies = groups
        .iter()
        .map(|(g, idx)| {
            let d = idx.iter().map(|&i| a[i] - m[i]).sum::<Vector2<f64>>() / idx.len() as f64;
            GroupShift {
                body: g.clone(),
                shift_mm: [d.x * 1e3, d.y * 1e3],
                rotation_deg: motions.get(g).map_or(0.0, |p| p.phi.to_degrees()),
            }
        })
        .collect();
    let cal = NeutralCalibration {
        film: film.file.clone(),
        rms_before_mm: rms_before * 1e3,
        rms_rigid_mm: (ss / n as f64).sqrt() * 1e3,
        remainder_weight: w,
        code_offsets_mm: offsets
            .iter()
            .map(|(c, o)| (c.clone(), [o.x * 1e3, o.y * 1e3]))
            .collect(),
        bodies,
    };
    Ok((bm.with_frontal_positions(&corrected), cal))
}

/// The in-plane rigid motion of a body's points onto the film's: Procrustes
/// with two points or more, a translation with one.
fn body_motion(src: &[Vector2<f64>], dst: &[Vector2<f64>]) -> Placement {
    if let Some((p, _)) = procrustes(src, dst) {
        return p;
    }
    let t = dst
        .iter()
        .zip(src)
        .map(|(d, s)| d - s)
        .sum::<Vector2<f64>>()
        / src.len().max(1) as f64;
    Placement { phi: 0.0, t }
}
