//! Rough anatomical directions of each vertebra in the segmentation's
//! world ([`FrameHint`] for the palpation engine), from the anatomy, not
//! from the image axes:
//! - cranial: along the chain of vertebral centroids, from the caudal
//!   neighbour to the cranial one (one-sided at the ends);
//! - anterior: the vertebral body is a compact mass in front of the
//!   neural arch, whose spinous process is a long posterior tail. In the
//!   plane across the cranial axis the third moment of the vertebra's
//!   volume about its centroid is largest towards the tail: anterior is
//!   the opposite direction. The sacrum, whose shape says little, takes
//!   L5's anterior; a level that disagrees with both neighbours by more
//!   than 60 deg takes theirs. When the patient frame is known (a NIfTI
//!   affine, a declared `--frame`) an anatomical anterior more than 90 deg
//!   from the frame's is replaced by the frame's, with a warning.

use crate::landmarks::{Frame, Level};
use crate::mesh::TriMesh;
use crate::palpation::FrameHint;
use nalgebra::{Point3, Vector3};

/// The hint of each level (same order as `levels`) and remarks.
pub fn frame_hints(
    levels: &[(Level, &TriMesh)],
    patient: Option<Frame>,
) -> (Vec<FrameHint>, Vec<String>) {
    let mut notes = Vec::new();
    let centroids: Vec<Point3<f64>> = levels.iter().map(|(_, m)| centroid(m)).collect();
    let cranial = cranial_axes(&centroids, patient);
    let mut anterior: Vec<Vector3<f64>> = levels
        .iter()
        .zip(&cranial)
        .map(|((_, m), c)| tail_anterior(m, c))
        .collect();
    fix_outliers(levels, &cranial, &mut anterior, &mut notes);
    if let Some(f) = patient {
        check_against_frame(levels, &cranial, &mut anterior, f, &mut notes);
    }
    let hints = cranial
        .into_iter()
        .zip(anterior)
        .map(|(c, a)| FrameHint {
            anterior: a,
            cranial: c,
        })
        .collect();
    (hints, notes)
}

/// Volume centroid (area centroid for an open or flat mesh).
pub fn centroid(m: &TriMesh) -> Point3<f64> {
    m.volume_centroid()
        .filter(|_| m.signed_volume().abs() > 0.0)
        .or_else(|| m.area_centroid())
        .unwrap_or_else(Point3::origin)
}

/// The patient frame's anterior and cranial in its own coordinates.
pub fn frame_axes(f: Frame) -> (Vector3<f64>, Vector3<f64>) {
    let back = f.to_opensim().transpose();
    (back * Vector3::x(), back * Vector3::y())
}

/// Cranial axis of each level from its neighbours' centroids (levels are
/// cranial to caudal); a lone level takes the patient frame's (or +z).
fn cranial_axes(c: &[Point3<f64>], patient: Option<Frame>) -> Vec<Vector3<f64>> {
    let fallback = patient.map(|f| frame_axes(f).1).unwrap_or(Vector3::z());
    (0..c.len())
        .map(|i| {
            let up = if i > 0 { c[i - 1] } else { c[i] };
            let down = if i + 1 < c.len() { c[i + 1] } else { c[i] };
            (up - down).try_normalize(1e-12).unwrap_or(fallback)
        })
        .collect()
}

/// Anterior of one vertebra: opposite to the direction, across `cranial`,
/// in which the third moment of its volume is largest.
fn tail_anterior(m: &TriMesh, cranial: &Vector3<f64>) -> Vector3<f64> {
    let c = centroid(m);
    let e1 = cranial
        .cross(&Vector3::x())
        .try_normalize(1e-6)
        .unwrap_or_else(|| cranial.cross(&Vector3::y()).normalize());
    let e2 = cranial.cross(&e1);
    // Third-moment coefficients of (a cos t + b sin t)^3 over the volume
    // (each tetrahedron from the centroid as a point mass at its centroid).
    let mut k = [0.0f64; 4];
    for [p0, p1, p2] in m.triangle_corners() {
        let w = (p0 - c).dot(&(p1 - c).cross(&(p2 - c))) / 6.0;
        let d = ((p0 - c) + (p1 - c) + (p2 - c)) / 4.0;
        let (a, b) = (d.dot(&e1), d.dot(&e2));
        k[0] += w * a * a * a;
        k[1] += w * a * a * b;
        k[2] += w * a * b * b;
        k[3] += w * b * b * b;
    }
    let m3 = |t: f64| {
        let (s, co) = t.sin_cos();
        k[0] * co.powi(3) + 3.0 * k[1] * co * co * s + 3.0 * k[2] * co * s * s + k[3] * s.powi(3)
    };
    let best = (0..720)
        .map(|i| i as f64 * std::f64::consts::PI / 360.0)
        .max_by(|a, b| m3(*a).total_cmp(&m3(*b)))
        .unwrap_or(0.0);
    -(best.cos() * e1 + best.sin() * e2)
}

/// Degrees between two directions.
fn angle_deg(a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    a.angle(b).to_degrees()
}

/// `v` made perpendicular to `axis` and unit (unchanged if degenerate).
fn across(v: &Vector3<f64>, axis: &Vector3<f64>) -> Vector3<f64> {
    (v - axis * v.dot(axis)).try_normalize(1e-9).unwrap_or(*v)
}

/// The sacrum takes L5's anterior; a level more than 60 deg from both its
/// neighbours (which agree) takes their mean.
fn fix_outliers(
    levels: &[(Level, &TriMesh)],
    cranial: &[Vector3<f64>],
    anterior: &mut [Vector3<f64>],
    notes: &mut Vec<String>,
) {
    let n = levels.len();
    for i in 0..n {
        let nb: Vec<Vector3<f64>> = [i.checked_sub(1), (i + 1 < n).then_some(i + 1)]
            .into_iter()
            .flatten()
            .filter(|&j| !levels[j].0.is_sacrum())
            .map(|j| anterior[j])
            .collect();
        let agree = nb.len() == 2 && angle_deg(&nb[0], &nb[1]) < 45.0 || nb.len() == 1;
        let mean = nb.iter().sum::<Vector3<f64>>();
        if levels[i].0.is_sacrum() && !nb.is_empty() {
            anterior[i] = across(&mean, &cranial[i]);
        } else if agree && nb.iter().all(|v| angle_deg(v, &anterior[i]) > 60.0) && n > 2 {
            notes.push(format!(
                "{}: anterior direction from the shape disagrees with the neighbours; theirs used",
                levels[i].0
            ));
            anterior[i] = across(&mean, &cranial[i]);
        }
    }
}

/// Against a known patient frame: an anatomical anterior more than 90 deg
/// from the frame's is replaced by the frame's (warning).
fn check_against_frame(
    levels: &[(Level, &TriMesh)],
    cranial: &[Vector3<f64>],
    anterior: &mut [Vector3<f64>],
    f: Frame,
    notes: &mut Vec<String>,
) {
    let (fa, _) = frame_axes(f);
    for i in 0..levels.len() {
        let want = across(&fa, &cranial[i]);
        if angle_deg(&anterior[i], &want) > 90.0 {
            notes.push(format!(
                "{}: anterior direction from the shape is {:.0} deg from the {f} frame's anterior; the frame's used",
                levels[i].0,
                angle_deg(&anterior[i], &want)
            ));
            anterior[i] = want;
        }
    }
}
