//! The mid-sagittal plane of a vertebra mesh: its plane of left-right
//! symmetry, found by mirroring surface samples through a trial plane and
//! minimising their mean distance to the surface (pattern search over the
//! plane's two tilt angles and its offset), started from the hint's right
//! axis and from every principal axis within 50 deg of it.

use crate::mesh::{sample_surface, MeshQuery, TriMesh};
use nalgebra::{Point3, Rotation3, Unit, Vector3};

/// A fitted symmetry plane `{p : normal . p = offset}`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct SymmetryPlane {
    /// Unit normal, pointing to the vertebra's right (same side as the hint).
    pub normal: Vector3<f64>,
    pub offset: f64,
    /// Mean mirrored-sample distance divided by the mesh's size.
    pub relative_cost: f64,
}

/// Number of surface samples mirrored per trial plane.
const SAMPLES: usize = 300;

/// Mean distance of the mirrored samples to the surface, each capped, or
/// `None` as soon as it is known to be at least `worse_than` (the distances
/// are not negative, so a partial sum that reaches it settles the
/// comparison). `hints` holds, per sample, the triangle nearest its last
/// mirror image (it only speeds the search up; the cost is exact).
fn mirror_cost(
    q: &MeshQuery,
    pts: &[Point3<f64>],
    hints: &mut [u32],
    plane: (&Vector3<f64>, f64),
    cap: f64,
    worse_than: f64,
) -> Option<f64> {
    let (n, d) = plane;
    let limit = worse_than * pts.len() as f64;
    let mut sum = 0.0;
    for (p, hint) in pts.iter().zip(hints.iter_mut()) {
        let m = p - n * (2.0 * (n.dot(&p.coords) - d));
        sum += q.distance_near(&m, hint, cap);
        if sum.is_nan() || sum >= limit {
            return None;
        }
    }
    Some(sum / pts.len() as f64)
}

/// Most trial planes one pattern search evaluates: bounds its time on any
/// input (a search that keeps improving by a step would otherwise run up
/// to 300 rounds of 6 trials). On the dev meshes and label maps a search
/// evaluates 40-125 planes, so the bound does not cut them short.
const MAX_EVALS: usize = 150;

/// The normal obtained by tilting `n0` by `a` about `u` and `b` about `v`.
fn tilted(n0: &Vector3<f64>, u: &Vector3<f64>, v: &Vector3<f64>, a: f64, b: f64) -> Vector3<f64> {
    let ra = Rotation3::from_axis_angle(&Unit::new_normalize(*u), a);
    let rb = Rotation3::from_axis_angle(&Unit::new_normalize(*v), b);
    (rb * ra * n0).normalize()
}

/// Pattern search from one starting normal, with angular steps from
/// `steps_deg.0` down to `steps_deg.1`; returns (normal, offset, cost).
fn refine(
    q: &MeshQuery,
    pts: &[Point3<f64>],
    n0: Vector3<f64>,
    size: f64,
    steps_deg: (f64, f64),
) -> (Vector3<f64>, f64, f64) {
    let u = n0
        .cross(&Vector3::x())
        .try_normalize(1e-6)
        .unwrap_or_else(|| n0.cross(&Vector3::y()).normalize());
    let v = n0.cross(&u);
    // The plane turns about the samples' centroid: x[2] is its offset from
    // the centroid, so a tilt does not sweep it across a vertebra that lies
    // far from the coordinate origin.
    let mean = pts.iter().fold(Vector3::zeros(), |s, p| s + p.coords) / pts.len() as f64;
    let cap = 0.1 * size;
    let mut x = [0.0, 0.0, 0.0];
    let mut hints = vec![0u32; pts.len()];
    let plane = |x: &[f64; 3]| {
        let n = tilted(&n0, &u, &v, x[0], x[1]);
        (n, x[2] + n.dot(&mean))
    };
    let mut evals = 1;
    let (n, d) = plane(&x);
    let Some(mut f) = mirror_cost(q, pts, &mut hints, (&n, d), cap, f64::INFINITY) else {
        return (n, d, f64::INFINITY);
    };
    let a0 = steps_deg.0.to_radians();
    let mut step = [a0, a0, 0.04 * size * steps_deg.0 / 8.0];
    // Points already evaluated: all but the current one were worse than
    // the cost at the time, so worse than it now (a search that steps back
    // to where it came from need not evaluate it again).
    let mut seen: Vec<[f64; 3]> = vec![x];
    'search: for _ in 0..300 {
        let mut improved = false;
        for k in 0..3 {
            for s in [1.0, -1.0] {
                let mut y = x;
                y[k] += s * step[k];
                let same = |p: &[f64; 3]| (0..3).all(|j| (p[j] - y[j]).abs() <= 1e-3 * step[j]);
                if seen.iter().any(same) {
                    continue;
                }
                if evals >= MAX_EVALS {
                    break 'search;
                }
                evals += 1;
                seen.push(y);
                let (n, d) = plane(&y);
                if let Some(fy) = mirror_cost(q, pts, &mut hints, (&n, d), cap, f) {
                    (x, f, improved) = (y, fy, true);
                    break;
                }
            }
        }
        if !improved {
            step.iter_mut().for_each(|s| *s *= 0.5);
            if step[0] < steps_deg.1.to_radians() {
                break;
            }
        }
    }
    let (n, d) = plane(&x);
    (n, d, f)
}

/// Turns of the hint's right axis about the cranial and anterior axes
/// tried as starting normals (deg): the hint may be off by about 45 deg.
const START_TURNS_DEG: [f64; 4] = [-30.0, -15.0, 15.0, 30.0];

/// The symmetry plane nearest the hint's right direction.
pub(crate) fn symmetry_plane(
    mesh: &TriMesh,
    q: &MeshQuery,
    right_hint: &Vector3<f64>,
    cranial_hint: &Vector3<f64>,
) -> Option<SymmetryPlane> {
    let (lo, hi) = mesh.bounds()?;
    let size = (hi - lo).norm();
    let pts: Vec<Point3<f64>> = sample_surface(mesh, SAMPLES, 7)
        .into_iter()
        .map(|(p, _)| p)
        .collect();
    if pts.len() < 10 {
        return None;
    }
    let hint = right_hint.try_normalize(1e-12)?;
    // Starting normals: the hint, the hint turned about its cranial and
    // anterior axes, and the principal axes within 50 deg of it.
    let mut starts = vec![hint];
    let cranial = (cranial_hint - hint * hint.dot(cranial_hint)).try_normalize(1e-12);
    if let Some(up) = cranial {
        let front = up.cross(&hint);
        for axis in [up, front] {
            for deg in START_TURNS_DEG {
                let r = Rotation3::from_axis_angle(&Unit::new_normalize(axis), deg.to_radians());
                starts.push(r * hint);
            }
        }
    }
    if let Some(axes) = crate::mesh::geom::point_principal_axes(&pts) {
        for c in 0..3 {
            let a: Vector3<f64> = axes.axes.column(c).into_owned();
            if a.dot(&hint).abs() >= 50f64.to_radians().cos() {
                starts.push(a * a.dot(&hint).signum());
            }
        }
    }
    // Every start searched coarsely (to 1 deg), the best two to 0.1 deg.
    // (the coarse search on every third sample: a third of the cost)
    let few: Vec<Point3<f64>> = pts.iter().step_by(3).copied().collect();
    let mut coarse: Vec<(Vector3<f64>, f64, f64)> = starts
        .into_iter()
        .map(|n0| refine(q, &few, n0, size, (8.0, 1.0)))
        .collect();
    coarse.sort_by(|a, b| a.2.total_cmp(&b.2));
    let best = coarse
        .into_iter()
        .take(2)
        .map(|(n0, _, _)| refine(q, &pts, n0, size, (1.0, 0.1)))
        .min_by(|a, b| a.2.total_cmp(&b.2))?;
    let (mut n, mut d) = (best.0, best.1);
    if n.dot(&hint) < 0.0 {
        (n, d) = (-n, -d);
    }
    Some(SymmetryPlane {
        normal: n,
        offset: d,
        relative_cost: best.2 / size,
    })
}
