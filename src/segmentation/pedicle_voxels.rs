//! Pedicle bases of a label map from its voxels. The protocol's base is the
//! lowest point of the frontal cut through the pedicle, and on many
//! vertebrae that point is a downward spike of the cut thinner than a
//! voxel: the smoothed voxel surface rounds it off, and its lowest point
//! sits 2-3 mm high. A voxel is labelled when its centre is inside the
//! vertebra, so the labelled voxels reach further down the spike: the base
//! is taken at the bottom of the lowest boundary voxel the cut passes
//! through, where that is below the surface's.

use super::surface::BoundaryVoxels;
use crate::landmarks::Code;
use crate::palpation::{self, VertebraPalpation};
use nalgebra::{Point3, Vector3};

/// Move `PBR`/`PBL` down to the voxels' lowest point of the pedicle cut
/// where it is below the surface's (`p` and `v` in the same coordinates).
/// Returns the codes moved.
pub(crate) fn refine_pedicle_bases(p: &mut VertebraPalpation, v: &BoundaryVoxels) -> Vec<Code> {
    // The cut, as the engine placed it: local X from SA, SP, IA, IP.
    let xs = [Code::SA, Code::SP, Code::IA, Code::IP].map(|c| p.local(c).map(|q| q.x));
    let [Some(sa), Some(sp), Some(ia), Some(ip)] = xs else {
        return Vec::new();
    };
    let x_cut = palpation::pedicle_cut_x([sa, sp, ia, ip]);
    // Half a voxel's extent along the vertebra's X and Y.
    let axis = |a: Vector3<f64>| p.frame.rotation * a;
    let half = |a: Vector3<f64>| 0.5 * v.edges.iter().map(|e| e.dot(&a).abs()).sum::<f64>();
    let (hx, hy) = (half(axis(Vector3::x())), half(axis(Vector3::y())));
    // The boundary voxels the cut passes through, in the vertebra's frame.
    let to_local = p.frame.inverse();
    let in_cut: Vec<Point3<f64>> = v
        .centres
        .iter()
        .map(|c| to_local * c)
        .filter(|q| (q.x - x_cut).abs() <= hx)
        .collect();
    let mut moved = Vec::new();
    for (code, side) in [(Code::PBR, 1.0), (Code::PBL, -1.0)] {
        let (Some(now), Some(low)) = (
            p.local(code),
            in_cut
                .iter()
                .filter(|q| side * q.z > 0.0)
                .min_by(|a, b| a.y.total_cmp(&b.y)),
        ) else {
            continue;
        };
        // The bottom of the lowest voxel, on the cut.
        let base = Point3::new(x_cut, low.y - hy, low.z);
        if base.y < now.y {
            if let Some(l) = p.landmarks.get_mut(&code) {
                l.point = p.frame * base;
                l.note = Some(
                    "the bottom of the lowest labelled voxel of the pedicle cut (the voxel surface rounds off a base thinner than a voxel)"
                        .into(),
                );
            }
            moved.push(code);
        }
    }
    moved
}
