//! Muscle paths as OpenSim 4.6 computes them, wrapping over spheres
//! included, and their test against the vertebra meshes.
//!
//! OpenSim's rules (GeometryPath and WrapSphere; re-derived here, the
//! geometry is the classic tangent construction):
//! * a PathWrap considers the segments of the current path between the
//!   active points its range selects (1-based, -1 = first/last point), and
//!   not a segment between two tangent points of the same object;
//! * a segment wraps over a sphere only when the straight segment enters it
//!   (both intersections of the line with the sphere strictly between the
//!   two points); when either point is inside the sphere the wrap is
//!   skipped;
//! * the tangent points lie in the plane of the two points and the centre;
//!   without a quadrant the pair with the shortest arc is taken; with a
//!   quadrant (`+x`, `-y`, ... in the sphere frame), a segment with a point
//!   on the constrained side is a mandatory wrap (the first such segment is
//!   taken), the tangent points are turned towards the quadrant and the
//!   wrap may go over the far side;
//! * among unconstrained wrapping segments the one with the smallest
//!   length change is kept; the two tangent points are inserted after the
//!   segment's first point; with several PathWraps the pass is repeated
//!   (up to 8 times) until the length changes less than 0.5 mm (OpenSim's
//!   swap of the first two objects when the second has a point inside is
//!   not reproduced: the generated models have one PathWrap per muscle);
//! * the length adds the arc (radius times the angle between the tangent
//!   points; OpenSim 4.6 subtracts the far-side arc, the `length` of [`SphereWrap::Wrapped`]
//!   keeps its sign so that lengths agree with OpenSim's).
//!
//! [`wrapped_path`] gives that path as a polyline with the arcs sampled
//! every millimetre, [`through_vertebrae`] the length of it inside each
//! vertebra mesh.

use super::kin::{muscle_path, Values};
use super::MeshSource;
use crate::error::{Error, Result};
use crate::mesh::source::body_mesh;
use crate::mesh::MeshQuery;
use crate::osim::model::{body_fixed_xyz, Model, Muscle, WrapShape};
use nalgebra::{Isometry3, Point3, Vector3};
use std::collections::BTreeMap;

/// Arc sampling step of [`wrapped_path`] (m).
pub(crate) const ARC_STEP: f64 = 0.001;
/// Smallest length inside a vertebra that counts as a crossing (m).
pub const DEPTH_TOLERANCE: f64 = 0.0005;

/// A WrapSphere placed in ground.
#[derive(Debug, Clone, PartialEq)]
pub struct SphereAt {
    /// WrapSphere name.
    pub name: String,
    /// Body the sphere is fixed to.
    pub body: String,
    /// Sphere frame in ground (origin at the centre).
    pub frame: Isometry3<f64>,
    /// Radius (m).
    pub radius: f64,
    /// Quadrant constraint: axis (0..3 of the sphere frame) and sign.
    pub quadrant: Option<(usize, f64)>,
}

/// Parse an OpenSim quadrant (`all`, `+x`, `-y`, `x`, ...): `None` for
/// an unconstrained one.
pub(crate) fn parse_quadrant(q: &str) -> Option<(usize, f64)> {
    let q = q.trim().to_ascii_lowercase();
    let (sign, axis) = match q.strip_prefix('-') {
        Some(a) => (-1.0, a),
        None => (1.0, q.strip_prefix('+').unwrap_or(&q)),
    };
    match axis {
        "x" => Some((0, sign)),
        "y" => Some((1, sign)),
        "z" => Some((2, sign)),
        _ => None,
    }
}

/// Outcome of one segment against one sphere.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum SphereWrap {
    /// The straight segment does not enter the sphere.
    NoWrap,
    /// A point is inside the sphere: OpenSim skips the wrap.
    Inside,
    /// The segment wraps: tangent points (ground), the signed arc length
    /// OpenSim adds, and whether the wrap was mandatory (quadrant).
    Wrapped {
        /// First tangent point (ground, m).
        r1: Point3<f64>,
        /// Second tangent point (ground, m).
        r2: Point3<f64>,
        /// Signed arc length OpenSim adds (m).
        length: f64,
        /// Whether the quadrant made the wrap mandatory.
        mandatory: bool,
        /// Whether the quadrant forced the long way round (a negative arc angle).
        far_side: bool,
    },
}

fn sgn(x: f64) -> f64 {
    if x >= 0.0 {
        1.0
    } else {
        -1.0
    }
}

/// Wrap the segment `a`-`b` (ground) over `s`.
pub(crate) fn wrap_segment(a: &Point3<f64>, b: &Point3<f64>, s: &SphereAt) -> SphereWrap {
    let inv = s.frame.inverse();
    let (p1, p2) = ((inv * a).coords, (inv * b).coords);
    let r = s.radius;
    let (d1, d2) = (p1.norm(), p2.norm());
    if d1 < r || d2 < r {
        return SphereWrap::Inside;
    }
    let d = p2 - p1;
    let qa = d.norm_squared();
    let qb = 2.0 * p1.dot(&d);
    let qc = p1.norm_squared() - r * r;
    let disc = qb * qb - 4.0 * qa * qc;
    if qa <= 0.0 || disc < 0.0 {
        return SphereWrap::NoWrap;
    }
    let (t1, t2) = (
        (-qb - disc.sqrt()) / (2.0 * qa),
        (-qb + disc.sqrt()) / (2.0 * qa),
    );
    if !(t1 > 0.0 && t1 < 1.0 && t2 > 0.0 && t2 < 1.0) {
        return SphereWrap::NoWrap;
    }
    let Some(n) = p1.cross(&p2).try_normalize(1e-12) else {
        // The line passes through the centre: no plane to wrap in.
        return SphereWrap::NoWrap;
    };
    // Tangent points from a point p at distance D: at angle acos(r/D) from
    // p's direction, on either side, in the plane with normal n.
    let tangents = |p: &Vector3<f64>, dist: f64| -> [Vector3<f64>; 2] {
        let u = p / dist;
        let v = n.cross(&u);
        let al = (r / dist).clamp(-1.0, 1.0).acos();
        [
            (u * al.cos() + v * al.sin()) * r,
            (u * al.cos() - v * al.sin()) * r,
        ]
    };
    let c1 = tangents(&p1, d1);
    let c2 = tangents(&p2, d2);
    // Shortest arc among the four pairs.
    let mut best = (f64::NEG_INFINITY, 0, 0);
    for (i, x) in c1.iter().enumerate() {
        for (j, y) in c2.iter().enumerate() {
            let dot = x.dot(y) / (r * r);
            if dot > best.0 {
                best = (dot, i, j);
            }
        }
    }
    let (mut i1, mut i2) = (best.1, best.2);
    let mut mandatory = false;
    let mut far_side = false;
    if let Some((axis, sign)) = s.quadrant {
        let on1 = sgn(p1[axis]) == sign;
        let on2 = sgn(p2[axis]) == sign;
        if on1 || on2 {
            // The segment enters the sphere (checked above): mandatory.
            mandatory = true;
        }
        if !(on1 && on2) {
            let towards = -(p1 + p2);
            let towards = towards.try_normalize(1e-15).unwrap_or(towards);
            i1 = if c1[0].dot(&towards) > c1[1].dot(&towards) {
                0
            } else {
                1
            };
            i2 = if c2[0].dot(&towards) > c2[1].dot(&towards) {
                0
            } else {
                1
            };
            let mut axis_v = Vector3::zeros();
            axis_v[axis] = sign;
            let pull = (c1[i1] - p1) + (c2[i2] - p2);
            if pull.dot(&axis_v) < 0.0 {
                i1 = 1 - i1;
                i2 = 1 - i2;
            }
            let pull = (c1[i1] - p1) + (c2[i2] - p2);
            let sum_r = c1[i1] + c2[i2];
            far_side = sum_r.dot(&pull) < 0.0;
        }
    }
    let (r1, r2) = (c1[i1], c2[i2]);
    let mut angle = (r1.dot(&r2) / (r * r)).clamp(-1.0, 1.0).acos();
    if far_side {
        angle = -(2.0 * std::f64::consts::PI - angle);
    }
    SphereWrap::Wrapped {
        r1: s.frame * Point3::from(r1),
        r2: s.frame * Point3::from(r2),
        length: r * angle,
        mandatory,
        far_side,
    }
}

/// One vertex of a wrapped path.
#[derive(Debug, Clone, PartialEq)]
pub struct PathVertex {
    /// The vertex in ground (m).
    pub ground: Point3<f64>,
    /// The body of a muscle's own path point; `None` for tangent points
    /// and arc samples.
    pub body: Option<String>,
}

/// A muscle's path at a pose, OpenSim's way.
#[derive(Debug, Clone, PartialEq)]
pub struct WrappedPath {
    /// Own points, tangent points and arc samples, in order.
    pub polyline: Vec<PathVertex>,
    /// The path length as OpenSim computes it (m).
    pub length: f64,
    /// Length of the straight polyline through the own points (m).
    pub straight: f64,
    /// Spheres the path wraps over.
    pub wrapped_over: Vec<String>,
}

/// Every WrapSphere of `model` placed at the body poses `poses`, by name.
pub fn spheres_at(
    model: &Model,
    poses: &BTreeMap<String, Isometry3<f64>>,
) -> BTreeMap<String, SphereAt> {
    let mut out = BTreeMap::new();
    for (body, wraps) in model
        .bodies
        .iter()
        .map(|b| (b.name.as_str(), &b.wrap_objects))
        .chain(std::iter::once(("ground", &model.ground.wrap_objects)))
    {
        let Some(x) = poses.get(body) else { continue };
        for w in wraps {
            let WrapShape::Sphere { radius } = w.shape else {
                continue;
            };
            if !w.active {
                continue;
            }
            let local = Isometry3::from_parts(
                w.translation.into(),
                nalgebra::UnitQuaternion::from_rotation_matrix(&body_fixed_xyz(
                    &w.xyz_body_rotation,
                )),
            );
            out.insert(
                w.name.clone(),
                SphereAt {
                    name: w.name.clone(),
                    body: body.to_string(),
                    frame: x * local,
                    radius,
                    quadrant: parse_quadrant(&w.quadrant),
                },
            );
        }
    }
    out
}

/// One entry of the current path while wrapping: an own point (index in
/// the PathPointSet) or a tangent point of a PathWrap.
#[derive(Debug, Clone)]
enum Entry {
    Own(usize, Point3<f64>, String),
    Tangent(usize, Point3<f64>),
}

impl Entry {
    fn at(&self) -> Point3<f64> {
        match self {
            Entry::Own(_, p, _) | Entry::Tangent(_, p) => *p,
        }
    }
}

/// A PathWrap over a sphere: its index among the muscle's PathWraps, the
/// sphere, and its range of path points (1-based, -1 = first/last).
type PathWrap<'a> = (usize, &'a SphereAt, [i64; 2]);

/// The path of `muscle` at coordinate values `q` (body poses `poses`) as
/// OpenSim computes it, over the spheres `spheres` (from [`spheres_at`]);
/// PathWraps over other objects (cylinders, ellipsoids) are ignored.
pub fn wrapped_path(
    model: &Model,
    muscle: &Muscle,
    poses: &BTreeMap<String, Isometry3<f64>>,
    q: &Values,
    spheres: &BTreeMap<String, SphereAt>,
) -> Result<WrappedPath> {
    // The active path points in ground, and the straight path's length.
    let active = muscle_path(model, muscle, poses, q)?;
    let index: BTreeMap<&str, usize> = muscle
        .points
        .iter()
        .enumerate()
        .map(|(i, p)| (p.name.as_str(), i))
        .collect();
    let mut path: Vec<Entry> = Vec::new();
    for p in &active {
        let i = index.get(p.name.as_str()).copied().ok_or_else(|| {
            Error::invalid(
                format!("muscle {}", muscle.name),
                format!("path point '{}' not in its PathPointSet", p.name),
            )
        })?;
        path.push(Entry::Own(i, p.ground, p.body.clone()));
    }
    let straight: f64 = active
        .windows(2)
        .map(|w| (w[1].ground - w[0].ground).norm())
        .sum();
    // The sphere PathWraps, applied in turn; with several, repeated until
    // the length settles (0.5 mm, at most 8 passes).
    let wraps: Vec<PathWrap> = muscle
        .wraps
        .iter()
        .enumerate()
        .filter_map(|(k, w)| Some((k, spheres.get(&w.wrap_object)?, w.range)))
        .collect();
    // Arc length of each applied wrap, by PathWrap index.
    let mut arcs: BTreeMap<usize, f64> = BTreeMap::new();
    let iterations = if wraps.len() < 2 { 1 } else { 8 };
    let mut last = f64::INFINITY;
    for _ in 0..iterations {
        for &wrap in &wraps {
            apply_wrap(&mut path, &mut arcs, wrap, &wraps, muscle.points.len());
        }
        let length = path_length(&path, &arcs);
        if (length - last).abs() < 0.0005 {
            break;
        }
        last = length;
    }
    let length = path_length(&path, &arcs);
    // The polyline with the arcs sampled.
    let (polyline, wrapped_over) = polyline(&path, &wraps, &arcs);
    Ok(WrappedPath {
        polyline,
        length,
        straight,
        wrapped_over,
    })
}

/// Apply one PathWrap to `path`: its previous tangent points removed, then
/// the segment of its range it wraps (the first mandatory one, else the
/// smallest length change) gets its two tangent points and its arc.
fn apply_wrap(
    path: &mut Vec<Entry>,
    arcs: &mut BTreeMap<usize, f64>,
    (k, sphere, range): PathWrap,
    wraps: &[PathWrap],
    n_points: usize,
) {
    path.retain(|e| !matches!(e, Entry::Tangent(j, _) if *j == k));
    arcs.remove(&k);
    let lo = if range[0] < 1 {
        0
    } else {
        range[0] as usize - 1
    };
    let hi = if range[1] < 1 {
        n_points.saturating_sub(1)
    } else {
        range[1] as usize - 1
    };
    let own_pos = |want_first: bool| -> Option<usize> {
        let mut it = path.iter().enumerate().filter_map(|(pos, e)| match e {
            Entry::Own(i, _, _) if *i >= lo && *i <= hi => Some(pos),
            _ => None,
        });
        if want_first {
            it.next()
        } else {
            it.next_back()
        }
    };
    let (Some(start), Some(end)) = (own_pos(true), own_pos(false)) else {
        return;
    };
    if let Some((pt1, SphereWrap::Wrapped { r1, r2, length, .. })) =
        best_segment(path, start, end, sphere, wraps)
    {
        path.insert(pt1 + 1, Entry::Tangent(k, r1));
        path.insert(pt1 + 2, Entry::Tangent(k, r2));
        arcs.insert(k, length);
    }
}

/// The segment of `path[start..=end]` that wraps over `sphere` (not one
/// between two tangent points of the same object): the first mandatory
/// wrap, else the one with the smallest length change.
fn best_segment(
    path: &[Entry],
    start: usize,
    end: usize,
    sphere: &SphereAt,
    wraps: &[PathWrap],
) -> Option<(usize, SphereWrap)> {
    let mut best: Option<(usize, SphereWrap)> = None;
    let mut min_change = f64::INFINITY;
    for pt1 in start..end {
        let (Some(e1), Some(e2)) = (path.get(pt1), path.get(pt1 + 1)) else {
            continue;
        };
        if let (Entry::Tangent(j1, _), Entry::Tangent(j2, _)) = (e1, e2) {
            let same_object = wraps
                .iter()
                .find(|w| w.0 == *j1)
                .zip(wraps.iter().find(|w| w.0 == *j2))
                .map(|(a, b)| a.1.name == b.1.name)
                .unwrap_or(false);
            if same_object {
                continue;
            }
        }
        let (a, b) = (e1.at(), e2.at());
        let w = wrap_segment(&a, &b, sphere);
        if let SphereWrap::Wrapped {
            r1,
            r2,
            length,
            mandatory,
            ..
        } = &w
        {
            if *mandatory {
                return Some((pt1, w.clone()));
            }
            let change = (r1 - a).norm() + length + (b - r2).norm() - (b - a).norm();
            if change < min_change {
                min_change = change;
                best = Some((pt1, w.clone()));
            }
        }
    }
    best
}

/// The path as a polyline (arcs between the tangent points of one wrap
/// sampled every [`ARC_STEP`]), and the spheres it wraps over.
fn polyline(
    path: &[Entry],
    wraps: &[PathWrap],
    arcs: &BTreeMap<usize, f64>,
) -> (Vec<PathVertex>, Vec<String>) {
    let mut polyline = Vec::new();
    let mut wrapped_over = Vec::new();
    let mut prev_tangent: Option<(usize, Point3<f64>)> = None;
    for e in path {
        match e {
            Entry::Own(_, p, body) => {
                prev_tangent = None;
                polyline.push(PathVertex {
                    ground: *p,
                    body: Some(body.clone()),
                });
            }
            Entry::Tangent(k, p) => {
                if let (Some((k0, p0)), Some(w)) = (prev_tangent, wraps.iter().find(|w| w.0 == *k))
                {
                    if k0 == *k {
                        let arc = arcs.get(k).copied().unwrap_or(0.0);
                        for s in sample_arc(w.1, &p0, p, arc) {
                            polyline.push(PathVertex {
                                ground: s,
                                body: None,
                            });
                        }
                        wrapped_over.push(w.1.name.clone());
                    }
                }
                prev_tangent = Some((*k, *p));
                polyline.push(PathVertex {
                    ground: *p,
                    body: None,
                });
            }
        }
    }
    (polyline, wrapped_over)
}

fn path_length(path: &[Entry], arcs: &BTreeMap<usize, f64>) -> f64 {
    path.windows(2)
        .map(|w| match (&w[0], &w[1]) {
            (Entry::Tangent(a, _), Entry::Tangent(b, _)) if a == b => {
                arcs.get(a).copied().unwrap_or(0.0)
            }
            (a, b) => (b.at() - a.at()).norm(),
        })
        .sum()
}

/// Interior samples (every [`ARC_STEP`]) of the great-circle arc from
/// tangent point `a` to `b` on sphere `s`: the short arc, or the long way
/// round for a far-side wrap (negative `arc`, OpenSim's sign).
pub(crate) fn sample_arc(
    s: &SphereAt,
    a: &Point3<f64>,
    b: &Point3<f64>,
    arc: f64,
) -> Vec<Point3<f64>> {
    let c = Point3::from(s.frame.translation.vector);
    let (ua, ub) = ((a - c) / s.radius, (b - c) / s.radius);
    let Some(n) = ua.cross(&ub).try_normalize(1e-12) else {
        return Vec::new();
    };
    let short = ua.dot(&ub).clamp(-1.0, 1.0).acos();
    let total = if arc < 0.0 {
        -(2.0 * std::f64::consts::PI - short)
    } else {
        short
    };
    let len = total.abs() * s.radius;
    let steps = ((len / ARC_STEP).ceil() as usize).max(1);
    let w = n.cross(&ua);
    (1..steps)
        .map(|k| {
            let t = total * k as f64 / steps as f64;
            c + (ua * t.cos() + w * t.sin()) * s.radius
        })
        .collect()
}

/// A muscle path crossing a vertebra.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Crossing {
    /// Muscle name.
    pub muscle: String,
    /// Body name of the vertebra it crosses.
    pub vertebra: String,
    /// Length of the path inside the vertebra mesh (mm).
    pub depth_mm: f64,
}

/// The vertebra meshes: (body, closed-mesh query in the body frame).
pub type Vertebrae<'a> = [(String, &'a MeshQuery)];

/// Length of `polyline` inside each vertebra mesh (placed by `poses`),
/// per vertebra, where it exceeds [`DEPTH_TOLERANCE`]. A segment is not
/// tested against a vertebra one of its own points is fixed to (it starts
/// at the bone surface).
pub fn through_vertebrae(
    muscle: &str,
    polyline: &[PathVertex],
    vertebrae: &Vertebrae,
    poses: &BTreeMap<String, Isometry3<f64>>,
) -> Vec<Crossing> {
    let mut out = Vec::new();
    for (body, mq) in vertebrae {
        let Some(x) = poses.get(body) else { continue };
        let (lo, hi) = mq.bounds();
        let (c, rad) = (nalgebra::center(&lo, &hi), 0.5 * (hi - lo).norm());
        let inv = x.inverse();
        let mut depth = 0.0;
        for w in polyline.windows(2) {
            if w.iter().any(|v| v.body.as_deref() == Some(body.as_str())) {
                continue;
            }
            let (a, b) = (inv * w[0].ground, inv * w[1].ground);
            if super::kin::point_segment_distance(&c, &a, &b) > rad {
                continue;
            }
            depth += mq.segment_length_inside(&a, &b);
        }
        if depth > DEPTH_TOLERANCE {
            out.push(Crossing {
                muscle: muscle.to_string(),
                vertebra: body.clone(),
                depth_mm: depth * 1e3,
            });
        }
    }
    out
}

/// Closed-mesh queries of the vertebrae of `model` (bodies named after a
/// thoracic or lumbar level), their meshes scaled as the model says.
pub fn vertebra_meshes(model: &Model, source: &dyn MeshSource) -> Result<Vec<(String, MeshQuery)>> {
    let mut out = Vec::new();
    for b in &model.bodies {
        let is_vertebra = crate::landmarks::Level::from_body_name(&b.name)
            .map(|l| !l.is_sacrum())
            .unwrap_or(false);
        if !is_vertebra {
            continue;
        }
        // The meshes found (a missing one is the model check's to report).
        let Some(m) = body_mesh(b, source)?.mesh else {
            continue;
        };
        let q = MeshQuery::new(&m)
            .map_err(|e| Error::invalid(format!("mesh of {}", b.name), e.to_string()))?;
        out.push((b.name.clone(), q));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sphere(r: f64, quadrant: Option<(usize, f64)>) -> SphereAt {
        SphereAt {
            name: "s".into(),
            body: "b".into(),
            frame: Isometry3::identity(),
            radius: r,
            quadrant,
        }
    }

    /// A segment passing through a unit sphere at height h wraps over the
    /// cap: tangent points at distance 1 from the centre, tangent segments
    /// perpendicular to the radius, arc = the angle between the tangent
    /// points (analytic: from (-2, h) the tangent angle is acos(1/2)).
    #[test]
    fn sphere_wrap_matches_the_tangent_construction() {
        let s = sphere(1.0, None);
        let a = Point3::new(-2.0, 0.1, 0.0);
        let b = Point3::new(2.0, 0.1, 0.0);
        let SphereWrap::Wrapped { r1, r2, length, .. } = wrap_segment(&a, &b, &s) else {
            panic!("no wrap");
        };
        for (p, t) in [(a, r1), (b, r2)] {
            assert!((t.coords.norm() - 1.0).abs() < 1e-12);
            assert!((p - t).dot(&t.coords).abs() < 1e-12, "not tangent");
        }
        // Wraps over the top (the side the segment passes).
        assert!(r1.y > 0.0 && r2.y > 0.0);
        // |p| = 2.0025; tangent angle acos(1/|p|) from each point's direction.
        let d = (4.0f64 + 0.01).sqrt();
        let dir = 0.1f64.atan2(2.0);
        let half = std::f64::consts::FRAC_PI_2 - (1.0 / d).acos() - dir;
        assert!((length - 2.0 * half).abs() < 1e-12, "{length}");
        // Misses and inside points.
        assert_eq!(
            wrap_segment(
                &Point3::new(-2.0, 1.5, 0.0),
                &Point3::new(2.0, 1.5, 0.0),
                &s
            ),
            SphereWrap::NoWrap
        );
        assert_eq!(
            wrap_segment(&Point3::new(-0.5, 0.0, 0.0), &b, &s),
            SphereWrap::Inside
        );
        // A segment ending before the sphere does not wrap.
        assert_eq!(
            wrap_segment(&a, &Point3::new(-1.5, 0.1, 0.0), &s),
            SphereWrap::NoWrap
        );
    }

    /// A +y quadrant forces the wrap over the +y side even when the
    /// segment passes below the centre.
    #[test]
    fn quadrant_chooses_the_side() {
        let s = sphere(1.0, Some((1, 1.0)));
        let a = Point3::new(-2.0, -0.1, 0.0);
        let b = Point3::new(2.0, -0.1, 0.0);
        let SphereWrap::Wrapped {
            r1, r2, mandatory, ..
        } = wrap_segment(&a, &b, &s)
        else {
            panic!("no wrap");
        };
        assert!(r1.y > 0.0 && r2.y > 0.0, "{r1} {r2}");
        assert!(!mandatory);
        let free = wrap_segment(&a, &b, &sphere(1.0, None));
        let SphereWrap::Wrapped { r1, .. } = free else {
            panic!()
        };
        assert!(r1.y < 0.0);
        assert_eq!(parse_quadrant("-X"), Some((0, -1.0)));
        assert_eq!(parse_quadrant("all"), None);
        assert_eq!(parse_quadrant("+z"), Some((2, 1.0)));
    }

    #[test]
    fn arc_samples_lie_on_the_great_circle_between_the_tangent_points() {
        let s = sphere(0.02, None);
        let a = Point3::new(0.02, 0.0, 0.0);
        let b = Point3::new(0.0, 0.02, 0.0);
        let pts = sample_arc(&s, &a, &b, 0.02 * std::f64::consts::FRAC_PI_2);
        assert!(pts.len() >= 30);
        let mut prev = a;
        let mut len = 0.0;
        for p in pts.iter().chain(std::iter::once(&b)) {
            assert!((p.coords.norm() - 0.02).abs() < 1e-12);
            assert!(p.z.abs() < 1e-15 && p.x >= -1e-15 && p.y >= -1e-15);
            len += (p - prev).norm();
            prev = *p;
        }
        let arc = 0.02 * std::f64::consts::FRAC_PI_2;
        assert!(len < arc && len > arc * 0.999, "{len} vs {arc}");
    }
}
