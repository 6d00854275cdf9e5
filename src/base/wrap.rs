//! Wrapping spheres on the vertebral bodies and the muscles that wrap over
//! them.
//!
//! * Sphere: centred on the vertebral centre the palpation engine finds
//!   (the thesis's rule, [`crate::palpation`]: least-squares sphere through
//!   the anterior-surface nodes of the body), with that sphere's radius;
//!   a modeller's `--centres` file replaces the centre.
//! * Crossing rule: a muscle wraps over the sphere of vertebra V when its
//!   attachments span V strictly (a point on a level cranial of V and a
//!   point on a level caudal of V; sacrum and pelvis count as S1), it has
//!   no point on V itself, and in at least one test pose (the default pose,
//!   and every IVD joint at LB +-10 deg with AR +-5 deg, or FE +-10 deg) a
//!   segment of its straight path comes within the radius + 5 mm of the
//!   sphere's centre.
//! * Spheres may not overlap one another in any test pose (OpenSim wraps
//!   sequentially; a tangent point inside the next sphere gives wrong,
//!   even shorter than straight, paths): overlapping pairs are shrunk in
//!   proportion to 98 % of their closest centre distance.
//! * Path points inside a sphere (OpenSim then silently skips the wrap):
//!   over the test poses, the sphere is shrunk to 0.5 mm inside the nearest
//!   path point of its wrapping muscles; a muscle whose point would force
//!   the radius below half the fitted radius loses that PathWrap instead
//!   (reported).
//! * One PathWrap per muscle: among the spheres it crosses, the one its
//!   straight path penetrates deepest over the test poses (OpenSim 4.6
//!   computes path lengths shorter than the straight line when a path
//!   wraps over several spheres in sequence). PathWraps use the `hybrid`
//!   method (WrapSphere's analytic solution does not depend on it) over
//!   the whole path (range -1 -1).

use super::kin::{point_segment_distance, Values};
use crate::anatomy::Level;
use nalgebra::Point3;

/// Extra reach of the crossing rule beyond the radius (m).
pub(crate) const CROSS_MARGIN: f64 = 0.005;
/// Clearance kept between a shrunk sphere and the nearest path point (m).
pub const CLEARANCE: f64 = 0.0005;
/// Lateral bending test angle (rad).
pub(crate) const TEST_LB: f64 = 10.0 * std::f64::consts::PI / 180.0;
/// Axial rotation test angle (rad).
pub(crate) const TEST_AR: f64 = 5.0 * std::f64::consts::PI / 180.0;
/// Flexion test angle (rad).
pub(crate) const TEST_FE: f64 = 10.0 * std::f64::consts::PI / 180.0;

/// One fitted sphere, body frame.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct SphereRow {
    /// The vertebra (None: a sphere of a model on another body, refitted by `generate`).
    pub level: Option<Level>,
    /// Body the sphere is fixed to.
    pub body: String,
    /// WrapSphere name (`<LEVEL>_body_sphere`).
    pub name: String,
    /// Centre in the body frame (m).
    pub centre: [f64; 3],
    /// Radius of the least-squares fit (m).
    pub radius_fit: f64,
    /// Radius after the no-overlap rule between spheres (m).
    pub radius_no_overlap: f64,
    /// Radius written (after any shrinking for path points) (m).
    pub radius: f64,
    /// RMS distance of the selected nodes to the fitted sphere (mm).
    pub rms_mm: f64,
    /// Number of selected nodes.
    pub nodes: usize,
    /// Whether the centre lies inside the vertebra mesh.
    pub centre_inside_mesh: bool,
    /// Which mesh the nodes came from.
    pub source: String,
    /// Registration RMS of a body-only mesh (mm), when one was used.
    pub body_mesh_registration_rms_mm: Option<f64>,
    /// Muscles wrapping over it.
    pub muscles: Vec<String>,
    /// Muscles that would cross it but had a path point too deep inside.
    pub muscles_refused: Vec<String>,
}

/// The test poses: label and coordinate values, given the default values
/// and the IVD joint prefixes.
pub fn test_poses(defaults: &Values, prefixes: &[String]) -> Vec<(String, Values)> {
    let mut out = vec![("default".to_string(), defaults.clone())];
    let combos = [
        ("LB+10 AR+5", TEST_LB, TEST_AR, 0.0),
        ("LB-10 AR-5", -TEST_LB, -TEST_AR, 0.0),
        ("LB+10 AR-5", TEST_LB, -TEST_AR, 0.0),
        ("LB-10 AR+5", -TEST_LB, TEST_AR, 0.0),
        ("FE+10", 0.0, 0.0, TEST_FE),
        ("FE-10", 0.0, 0.0, -TEST_FE),
    ];
    for (label, lb, ar, fe) in combos {
        let mut q = defaults.clone();
        for p in prefixes {
            for (s, d) in [("LB", lb), ("AR", ar), ("FE", fe)] {
                if let Some(v) = q.get_mut(&format!("{p}_{s}")) {
                    *v += d;
                }
            }
        }
        out.push((label.to_string(), q));
    }
    out
}

/// A muscle as seen by the crossing rule.
pub struct MuscleGeom {
    /// Muscle name.
    pub name: String,
    /// Lowest and highest attachment level index (T1 = 0 .. S1 = 17).
    pub level_lo: usize,
    /// Highest attachment level index.
    pub level_hi: usize,
    /// Bodies carrying a path point.
    pub bodies: Vec<String>,
    /// Ground path per test pose.
    pub paths: Vec<Vec<Point3<f64>>>,
}

/// A sphere as seen by the crossing rule.
pub struct SphereGeom {
    /// Level index of the sphere's vertebra (T1 = 0 .. S1 = 17).
    pub level_index: usize,
    /// Body the sphere is fixed to.
    pub body: String,
    /// Radius before the inside-point fix (m).
    pub radius_fit: f64,
    /// Centre in ground per test pose.
    pub centres: Vec<Point3<f64>>,
}

/// Outcome for one sphere: final radius, wrapping muscles (indices), and
/// refused muscles (indices).
pub(crate) struct Assignment {
    /// Final sphere radius (m).
    pub radius: f64,
    /// Indices of the muscles that wrap over it.
    pub muscles: Vec<usize>,
    /// Indices of crossing muscles refused: a path point lies too deep inside the sphere.
    pub refused: Vec<usize>,
}

/// Apply the crossing rule and the inside-point fix to one sphere.
pub(crate) fn assign(sphere: &SphereGeom, muscles: &[MuscleGeom]) -> Assignment {
    let mut cands: Vec<(usize, f64, f64)> = Vec::new(); // (muscle, min seg dist, min point dist)
    for (k, m) in muscles.iter().enumerate() {
        if !(m.level_lo < sphere.level_index && sphere.level_index < m.level_hi) {
            continue;
        }
        if m.bodies.contains(&sphere.body) {
            continue;
        }
        let mut dseg = f64::MAX;
        let mut dpt = f64::MAX;
        for (path, c) in m.paths.iter().zip(&sphere.centres) {
            for w in path.windows(2) {
                dseg = dseg.min(point_segment_distance(c, &w[0], &w[1]));
            }
            for p in path {
                dpt = dpt.min((p - c).norm());
            }
        }
        if dseg < sphere.radius_fit + CROSS_MARGIN {
            cands.push((k, dseg, dpt));
        }
    }
    let floor = 0.5 * sphere.radius_fit;
    let mut refused = Vec::new();
    let mut radius = sphere.radius_fit;
    cands.retain(|&(k, _, dpt)| {
        if dpt - CLEARANCE < floor {
            refused.push(k);
            false
        } else {
            radius = radius.min(dpt - CLEARANCE);
            true
        }
    });
    let muscles = cands
        .iter()
        .filter(|&&(_, dseg, _)| dseg < radius + CROSS_MARGIN)
        .map(|&(k, _, _)| k)
        .collect();
    Assignment {
        radius,
        muscles,
        refused,
    }
}

/// Every muscle's straight path in every test pose (body poses
/// `pose_bodies`), the bodies it touches and the levels it spans (`base`
/// and `generate` both assign wraps from it).
pub fn muscle_geometry(
    model: &crate::osim::Model,
    poses: &[(String, Values)],
    pose_bodies: &[std::collections::BTreeMap<String, nalgebra::Isometry3<f64>>],
) -> crate::error::Result<Vec<MuscleGeom>> {
    let mut mgeo = Vec::new();
    for m in model.muscles() {
        let mut paths = Vec::new();
        let mut bodies = std::collections::BTreeSet::new();
        for ((_, q), pb) in poses.iter().zip(pose_bodies) {
            let path = super::kin::muscle_path(model, m, pb, q)?;
            for p in &path {
                bodies.insert(p.body.clone());
            }
            paths.push(path.iter().map(|p| p.ground).collect::<Vec<_>>());
        }
        let lv: Vec<usize> = bodies
            .iter()
            .filter_map(|b| super::body_level_index(b))
            .collect();
        mgeo.push(MuscleGeom {
            name: m.name.clone(),
            level_lo: lv.iter().copied().min().unwrap_or(0),
            level_hi: lv.iter().copied().max().unwrap_or(0),
            bodies: bodies.into_iter().collect(),
            paths,
        });
    }
    Ok(mgeo)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;
    use rand::{Rng, SeedableRng};
    use rand_distr::{Distribution, Normal};

    /// Synthetic spherical caps with 0.05 mm Gaussian noise: centre and
    /// radius are recovered within 0.1 mm (acceptance 2).
    #[test]
    fn noisy_sphere_patches_are_recovered() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let noise = Normal::new(0.0, 0.00005).unwrap();
        for case in 0..20 {
            let c = Point3::new(
                rng.random_range(-0.1..0.1),
                rng.random_range(-0.1..0.1),
                rng.random_range(-0.1..0.1),
            );
            let r = rng.random_range(0.01..0.03);
            // A cap of half-angle 50 degrees around a random axis, like the
            // anterior wall of a vertebral body.
            let axis = Vector3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            )
            .normalize();
            let u = axis
                .cross(&Vector3::x())
                .try_normalize(1e-6)
                .unwrap_or(Vector3::y());
            let v = axis.cross(&u);
            let pts: Vec<Point3<f64>> = (0..300)
                .map(|_| {
                    let th: f64 = rng.random_range(0.0..50f64.to_radians());
                    let ph: f64 = rng.random_range(0.0..std::f64::consts::TAU);
                    let d = axis * th.cos() + (u * ph.cos() + v * ph.sin()) * th.sin();
                    c + d * (r + noise.sample(&mut rng))
                })
                .collect();
            let s = crate::mesh::fit_sphere(&pts).unwrap();
            assert!(
                (s.centre - c).norm() < 1e-4,
                "case {case}: centre off by {}",
                (s.centre - c).norm()
            );
            assert!(
                (s.radius - r).abs() < 1e-4,
                "case {case}: radius off by {}",
                s.radius - r
            );
        }
    }

    fn line_muscle(name: &str, lo: usize, hi: usize, x: f64) -> MuscleGeom {
        MuscleGeom {
            name: name.into(),
            level_lo: lo,
            level_hi: hi,
            bodies: vec!["a".into(), "b".into()],
            paths: vec![vec![Point3::new(x, -0.1, 0.0), Point3::new(x, 0.1, 0.0)]],
        }
    }

    #[test]
    fn crossing_rule_and_inside_fix() {
        let s = SphereGeom {
            level_index: 5,
            body: "v".into(),
            radius_fit: 0.02,
            centres: vec![Point3::origin()],
        };
        let ms = vec![
            line_muscle("near", 3, 8, 0.022),       // within r + margin: wraps
            line_muscle("far", 3, 8, 0.05),         // too far
            line_muscle("not spanning", 5, 8, 0.0), // attaches at the level
            line_muscle("inside", 3, 8, 0.005),     // point-free segment through: wraps
        ];
        let a = assign(&s, &ms);
        assert_eq!(a.muscles, vec![0, 3]);
        assert!(a.refused.is_empty());
        assert_eq!(a.radius, 0.02);
        // A muscle with a path point inside the sphere shrinks it.
        let mut m = line_muscle("via", 3, 8, 0.0);
        m.paths[0].insert(1, Point3::new(0.015, 0.0, 0.0));
        let a = assign(&s, &[m]);
        assert_eq!(a.muscles, vec![0]);
        assert!((a.radius - (0.015 - CLEARANCE)).abs() < 1e-15);
        // One too deep inside is refused, the sphere keeps its size.
        let mut m = line_muscle("deep", 3, 8, 0.0);
        m.paths[0].insert(1, Point3::new(0.004, 0.0, 0.0));
        let a = assign(&s, &[m]);
        assert!(a.muscles.is_empty());
        assert_eq!(a.refused, vec![0]);
        assert_eq!(a.radius, 0.02);
    }
}
