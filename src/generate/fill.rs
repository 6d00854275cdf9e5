//! Levels missing between measured ones (a gap in the landmark set: a
//! vertebra the segmentation could not give, a level an operator skipped)
//! are placed from their neighbours, so that a gap never drops the levels
//! above it:
//! - **scale**: interpolated along the gap between the nearest measured
//!   levels' factors (the one above alone when the gap reaches the
//!   sacrum, which is not scaled);
//! - **orientation**: the base model's relative rotations carried up the
//!   gap from the measured level below, with the mismatch to the measured
//!   level above shared out along the gap (a fraction `p / (k + 1)` of the
//!   correction at the gap's `p`-th joint of `k + 1`);
//! - **position**: each body placed so that its joint with the body below
//!   meets (the base model's joint centres, scaled with each body), the
//!   mismatch at the measured level above shared out the same way.
//!
//! Only levels between the top measured vertebra and the sacrum are
//! filled; the levels above the top one are above the field of view
//! ([`super::balance`]).

use super::pose::{scale_point, VertebraFit};
use super::JointCentres;
use crate::landmarks::Level;
use nalgebra::{Isometry3, UnitQuaternion, Vector3};
use std::collections::BTreeMap;

/// A level placed from its neighbours.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct FilledLevel {
    /// The level that was missing.
    pub level: Level,
    /// The measured levels (or the sacrum) it was placed between.
    pub between: [Level; 2],
    /// Its scale factors X (depth), Y (height), Z (width).
    pub scale: [f64; 3],
}

/// The levels missing between the first of `measured` (cranial to
/// caudal, T1..L5) and the sacrum.
pub fn gaps(measured: &[Level]) -> Vec<Level> {
    let Some(top) = measured.first() else {
        return Vec::new();
    };
    Level::ALL
        .into_iter()
        .filter(|l| !l.is_sacrum() && l > top && !measured.contains(l))
        .collect()
}

/// Place every gap level (`fits` gains their fits). `sacrum` is the
/// sacrum's pose in ground; `poses0` the base's body poses at its default
/// pose; `joints` the base's joint centres (unscaled, in each body).
pub fn fill_gaps(
    fits: &mut BTreeMap<Level, VertebraFit>,
    sacrum: &Isometry3<f64>,
    poses0: &BTreeMap<String, Isometry3<f64>>,
    joints: &JointCentres,
) -> Vec<FilledLevel> {
    let measured: Vec<Level> = fits.keys().copied().collect();
    let missing = gaps(&measured);
    let mut out = Vec::new();
    // Each run of consecutive missing levels, cranial to caudal.
    let mut runs: Vec<Vec<Level>> = Vec::new();
    for l in missing {
        match runs.last_mut() {
            Some(r) if r.last().and_then(|x| x.caudal()) == Some(l) => r.push(l),
            _ => runs.push(vec![l]),
        }
    }
    for run in runs {
        let (Some(up), Some(down)) = (
            run.first().and_then(|l| l.cranial()),
            run.last().and_then(|l| l.caudal()),
        ) else {
            continue;
        };
        let placed = fill_run(&run, up, down, fits, sacrum, poses0, joints);
        for (l, f) in run.iter().zip(placed) {
            out.push(FilledLevel {
                level: *l,
                between: [up, down],
                scale: [f.scale.x, f.scale.y, f.scale.z],
            });
            fits.insert(*l, f);
        }
    }
    out
}

/// The fits of one run of missing levels between the measured `up` and
/// `down` (the sacrum when the run reaches it).
fn fill_run(
    run: &[Level],
    up: Level,
    down: Level,
    fits: &BTreeMap<Level, VertebraFit>,
    sacrum: &Isometry3<f64>,
    poses0: &BTreeMap<String, Isometry3<f64>>,
    joints: &JointCentres,
) -> Vec<VertebraFit> {
    let k = run.len();
    let n = (k + 1) as f64;
    let fit_up = &fits[&up];
    let (pose_down, scale_down) = match fits.get(&down) {
        Some(f) => (f.pose, f.scale),
        None => (*sacrum, fit_up.scale),
    };
    // Scale factors along the gap (p = 1 next to `up`).
    let scales: Vec<Vector3<f64>> = (1..=k)
        .map(|p| fit_up.scale + (scale_down - fit_up.scale) * (p as f64 / n))
        .collect();
    // The chain from `down` upwards by the base's relative poses: body
    // j's pose from body j-1's (below it) through their joint.
    let chain: Vec<Level> = std::iter::once(down)
        .chain(run.iter().rev().copied())
        .chain(std::iter::once(up))
        .collect();
    let scale_of = |l: Level| -> Vector3<f64> {
        if l == up {
            fit_up.scale
        } else if l == down {
            scale_down
        } else {
            run.iter()
                .position(|x| *x == l)
                .map(|p| scales[p])
                .unwrap_or(fit_up.scale)
        }
    };
    let base_rel = |lower: Level, upper: Level| -> UnitQuaternion<f64> {
        match (
            poses0.get(&lower.body_name()),
            poses0.get(&upper.body_name()),
        ) {
            (Some(a), Some(b)) => a.rotation.inverse() * b.rotation,
            _ => UnitQuaternion::identity(),
        }
    };
    // Body `upper` on body `lower` (pose `below`) with rotation `rot`: its
    // joint centre meets the lower body's.
    let on = |below: &Isometry3<f64>, lower: Level, upper: Level, rot: UnitQuaternion<f64>| {
        let t = match joints.get(&upper) {
            Some((in_upper, in_lower)) => {
                let centre = below * scale_point(in_lower, &scale_of(lower));
                centre.coords - rot * scale_point(in_upper, &scale_of(upper)).coords
            }
            None => below.translation.vector,
        };
        Isometry3::from_parts(t.into(), rot)
    };
    // The base's rotations carried up from `down`; the mismatch of the
    // rotation at `up` shared out along the chain.
    let mut carried = vec![pose_down.rotation];
    for w in chain.windows(2) {
        let below = *carried.last().expect("started with down");
        carried.push(below * base_rel(w[0], w[1]));
    }
    let turn = carried[k + 1].inverse() * fit_up.pose.rotation;
    let mut corrected = vec![pose_down];
    for (j, w) in chain.windows(2).enumerate() {
        let f = (j + 1) as f64 / n;
        let rot = carried[j + 1] * UnitQuaternion::identity().slerp(&turn, f);
        let next = on(&corrected[j], w[0], w[1], rot);
        corrected.push(next);
    }
    // The positions' mismatch at `up`, shared out the same way.
    let residual = fit_up.pose.translation.vector - corrected[k + 1].translation.vector;
    // corrected[1..=k] are the run from the bottom (next to `down`) up.
    (1..=k)
        .map(|j| {
            let f = j as f64 / n;
            let x = corrected[j];
            let level = chain[j];
            VertebraFit {
                scale: scale_of(level),
                pose: Isometry3::from_parts(
                    (x.translation.vector + residual * f).into(),
                    x.rotation,
                ),
                residuals: BTreeMap::new(),
                outlier: None,
                loo_max: None,
            }
        })
        .rev()
        .collect()
}
