//! The sacrum of a palpated segmentation registered to a base model's
//! sacrum by its surface (`generate --segmentation`): the patient's sacrum
//! surface is moved onto the base's sacrum mesh by trimmed ICP (a
//! similarity: sacra differ in size), and the base's S1 markers carried
//! back onto the patient's sacrum replace the palpated S1 landmarks. The
//! model is then registered to the patient through the whole sacral
//! surface instead of five plateau points, and its S1 markers and the
//! patient's are placed by the same rule whatever the plateau's mesh
//! (a coarse plateau's landmarks copy L5's layout, which follows the
//! patient's L5, not the sacrum). Refused (the palpated landmarks kept,
//! with a warning) when the surfaces do not match.

use super::{Finding, Palpated, Severity};
use crate::landmarks::{Code, Level};
use crate::mesh::{icp, IcpOptions, MeshQuery, Similarity, TriMesh};
use crate::palpation::PalpatedLandmark;
use nalgebra::Point3;
use std::collections::BTreeMap;

/// Largest RMS surface distance (m) of a registration accepted: sacra of
/// different patients differ by a few millimetres after a similarity.
const MAX_RMS: f64 = 0.004;
/// Scale factors a registration may find (a patient's sacrum against the
/// base's).
const SCALE_RANGE: (f64, f64) = (0.7, 1.4);
/// Vertices of the patient's sacrum used (evenly taken).
const MAX_POINTS: usize = 4000;

/// What the registration found.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct SacrumRegistration {
    /// RMS distance of the patient's sacrum to the base's after it (mm).
    pub rms_mm: f64,
    /// Uniform scale of the base's sacrum onto the patient's.
    pub scale: f64,
    /// Largest distance between a carried marker and the palpated
    /// landmark of the same code (mm).
    pub largest_change_mm: f64,
}

/// Replace `p`'s S1 landmarks by `base_s1` (the base's S1 markers, in the
/// frame of `base_sacrum`, metres) carried onto the patient's sacrum.
/// Returns what was done, or `None` (a warning added) when the patient has
/// no sacrum surface or the registration does not match.
pub fn carry_base_markers(
    p: &mut Palpated,
    base_sacrum: &TriMesh,
    base_s1: &BTreeMap<Code, Point3<f64>>,
) -> Option<SacrumRegistration> {
    let k = p.levels.iter().position(|l| l.level == Level::S1)?;
    let r = register(
        &p.levels[k].mesh,
        base_sacrum,
        &p.levels[k].palpation,
        base_s1,
    );
    let Some(x) = r else {
        p.findings.push(Finding::new(
            Some(Level::S1),
            Severity::Warning,
            "the sacrum's surface does not match the base model's (registration RMS over 4 mm or a scale outside 0.7-1.4): the palpated S1 landmarks are kept",
        ));
        return None;
    };
    let (sim, rms) = x;
    let back = sim.inverse();
    let to_os = p.world.to_opensim();
    let level = &mut p.levels[k];
    let mut largest: f64 = 0.0;
    for (code, m) in base_s1 {
        if !Code::SACRUM_REQUIRED.contains(code) {
            continue;
        }
        let q = back.apply(m);
        if let Some(old) = level.palpation.landmarks.get(code) {
            largest = largest.max((old.point - q).norm());
        }
        level.palpation.landmarks.insert(
            *code,
            PalpatedLandmark {
                point: q,
                confidence: 1.0,
                note: Some("the base model's marker carried onto the sacrum's surface".into()),
                spread: 0.0,
            },
        );
        p.set.insert(Level::S1, *code, (to_os * q.coords).into());
    }
    let out = SacrumRegistration {
        rms_mm: rms * 1e3,
        scale: 1.0 / sim.scale,
        largest_change_mm: largest * 1e3,
    };
    p.findings.push(Finding::new(
        Some(Level::S1),
        Severity::Info,
        format!(
            "S1 landmarks: the base model's S1 markers carried onto the patient's sacrum by registering the two sacral surfaces (RMS {:.2} mm, scale {:.3}); up to {:.1} mm from the palpated plateau landmarks",
            out.rms_mm, out.scale, out.largest_change_mm
        ),
    ));
    Some(out)
}

/// The similarity taking the patient's sacrum (`patient`, segmentation
/// axes) onto the base's (`base`, its body frame) and its RMS (m), started
/// from the S1 landmarks and from the surfaces' principal axes (the better
/// kept); `None` when neither matches.
fn register(
    patient: &TriMesh,
    base: &TriMesh,
    palpated: &crate::palpation::VertebraPalpation,
    base_s1: &BTreeMap<Code, Point3<f64>>,
) -> Option<(Similarity, f64)> {
    let target = MeshQuery::new(base).ok()?;
    let step = patient.vertices.len().div_ceil(MAX_POINTS).max(1);
    let pts: Vec<Point3<f64>> = patient.vertices.iter().step_by(step).copied().collect();
    let (src, dst): (Vec<Point3<f64>>, Vec<Point3<f64>>) = Code::SACRUM_REQUIRED
        .iter()
        .filter_map(|c| Some((palpated.landmarks.get(c)?.point, *base_s1.get(c)?)))
        .unzip();
    let from_landmarks = crate::mesh::kabsch(&src, &dst).ok();
    let opts = |initial: Option<Similarity>| IcpOptions {
        allow_scale: true,
        keep_fraction: 0.85,
        initial,
        ..IcpOptions::default()
    };
    let runs = [from_landmarks, None]
        .into_iter()
        .filter_map(|init| icp(&pts, &target, &opts(init)).ok());
    let best = runs.min_by(|a, b| a.trimmed_rms.total_cmp(&b.trimmed_rms))?;
    let ok = best.trimmed_rms <= MAX_RMS
        && (SCALE_RANGE.0..=SCALE_RANGE.1).contains(&(1.0 / best.transform.scale));
    ok.then_some((best.transform, best.trimmed_rms))
}
