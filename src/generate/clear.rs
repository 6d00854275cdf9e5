//! Muscle paths clear of the vertebrae in the generated pose.
//!
//! The scoliotic curve moves vertebrae into the paths of muscles that span
//! them (psoas fascicles beside the lumbar bodies on the concave side,
//! multifidus and longissimus fascicles over rotated laminae). The path
//! tested is the one OpenSim computes ([`crate::base::wrapped`]:
//! own points, sphere wraps and their arcs) at the default pose, against
//! the vertebra meshes.
//!
//! The construct is a via point (a fixed `PathPoint`) on the crossed
//! vertebra, as lumbar spine models route the psoas and erector fascicles
//! (via points on the vertebrae they pass), not a PathWrap over the
//! vertebral-body sphere: that sphere is fitted to the anterior wall only
//! and is shrunk below the body's size by the no-overlap and inside-point
//! rules ([`super::wraps`]), so an arc over it runs inside the bone, and it
//! cannot route a path around the posterior elements at all. The via point
//! goes on the side the path already passes: among directions
//! perpendicular to the segment, the smallest detour from the middle of the
//! chord inside the bone that leaves both new segments outside every
//! vertebra they are not attached to, the point itself [`CLEARANCE`]
//! outside the bone and outside the muscle's wrap spheres. When the bone
//! crossing is the arc of the muscle's own PathWrap over that vertebra's
//! sphere, that PathWrap is removed first (the arc is in the bone).
//! Rounds repeat until no crossing is left or [`MAX_ROUNDS`] is reached;
//! what is left is reported by the self-check.

use crate::base::kin::Kinematics;
use crate::base::wrapped::{self, PathVertex};
use crate::error::Result;
use crate::mesh::MeshQuery;
use crate::osim::xml::{Element, Node};
use crate::osim::Document;
use nalgebra::{Point3, Vector3};
use std::collections::BTreeSet;

/// Distance kept between a via point and the bone surface (m).
pub const CLEARANCE: f64 = 0.002;
/// Offset step of the detour search (m).
const OFFSET_STEP: f64 = 0.001;
/// Offset steps searched: detours up to 50 mm from the chord.
const OFFSET_STEPS: usize = 50;
/// Rounds of the crossing fix.
pub(crate) const MAX_ROUNDS: usize = 12;
/// Length (m) a new segment may run inside another vertebra's mesh (a
/// graze of the coarse mesh's surface), well under the self-check's
/// [`wrapped::DEPTH_TOLERANCE`].
pub(crate) const GRAZE: f64 = 0.0001;

/// A via point that clears no crossing completely may still leave its
/// segments this share of the self-check's tolerance inside other
/// vertebrae (a graze of a coarse mesh's surface).
pub(crate) const FALLBACK_INSIDE: f64 = 0.8;

/// One edit made to clear a path.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct PathEdit {
    /// Muscle name.
    pub muscle: String,
    /// Body name of the vertebra its path passed through.
    pub vertebra: String,
    /// "via point `<name>`" or "removed PathWrap over `<sphere>`".
    pub action: String,
    /// Depth of the crossing it removed (mm).
    pub depth_mm: f64,
}

/// Clear the muscle paths of `doc` from the vertebrae `vertebrae` (body,
/// mesh query in the body frame) at the default pose. Edits `doc`.
pub fn clear_paths(
    doc: &mut Document,
    vertebrae: &[(String, &MeshQuery)],
) -> Result<Vec<PathEdit>> {
    let mut edits = Vec::new();
    // Edits only touch path points and PathWraps: the pose and the wrap
    // spheres are the same in every round, and a muscle needs looking at
    // again only after it was edited.
    let model = doc.model()?;
    let kin = Kinematics::new(&model)?;
    let q = kin.default_values();
    let poses = kin.body_poses(&q)?;
    let spheres = wrapped::spheres_at(&model, &poses);
    let bones: Vec<Bone> = vertebrae
        .iter()
        .filter_map(|(name, query)| {
            let pose = *poses.get(name)?;
            Some(Bone {
                name,
                query,
                pose,
                to_local: pose.inverse(),
            })
        })
        .collect();
    let mut pending: Option<BTreeSet<String>> = None;
    for _ in 0..MAX_ROUNDS {
        let model = doc.model()?;
        let mut edited = BTreeSet::new();
        for m in model
            .muscles()
            .filter(|m| pending.as_ref().is_none_or(|p| p.contains(&m.name)))
        {
            let path = wrapped::wrapped_path(&model, m, &poses, &q, &spheres)?;
            let mut cs = wrapped::through_vertebrae(&m.name, &path.polyline, vertebrae, &poses);
            cs.sort_by(|a, b| b.depth_mm.total_cmp(&a.depth_mm));
            let Some(c) = cs.first() else { continue };
            // A PathWrap over the crossed vertebra's sphere: its arc is in
            // the bone; remove it.
            let own_wrap = m.wraps.iter().find(|w| {
                spheres
                    .get(&w.wrap_object)
                    .map(|s| s.body == c.vertebra)
                    .unwrap_or(false)
            });
            if let Some(w) = own_wrap {
                if path.wrapped_over.contains(&w.wrap_object) {
                    remove_path_wrap(doc, &m.name, &w.wrap_object);
                    edits.push(PathEdit {
                        muscle: m.name.clone(),
                        vertebra: c.vertebra.clone(),
                        action: format!("removed PathWrap over {}", w.wrap_object),
                        depth_mm: c.depth_mm,
                    });
                    edited.insert(m.name.clone());
                    continue;
                }
            }
            let (Some(x), Some((_, mq))) = (
                poses.get(&c.vertebra),
                vertebrae.iter().find(|(b, _)| *b == c.vertebra),
            ) else {
                continue;
            };
            // The own points around the deepest crossing segment.
            let own: Vec<(usize, &PathVertex)> = path
                .polyline
                .iter()
                .enumerate()
                .filter(|(_, v)| v.body.is_some())
                .collect();
            let inv = x.inverse();
            let mut best_seg: Option<(f64, usize)> = None; // (depth, index in own)
            for (k, w) in own.windows(2).enumerate() {
                if w.iter()
                    .any(|v| v.1.body.as_deref() == Some(c.vertebra.as_str()))
                {
                    continue;
                }
                // Length of the polyline between these own points inside
                // the bone (summed like `through_vertebrae` sums it: a
                // crossing split over two arc samples is still one).
                let d: f64 = path.polyline[w[0].0..=w[1].0]
                    .windows(2)
                    .map(|s| mq.segment_length_inside(&(inv * s[0].ground), &(inv * s[1].ground)))
                    .sum();
                if d > 0.0 && best_seg.map(|(bd, _)| d > bd).unwrap_or(true) {
                    best_seg = Some((d, k));
                }
            }
            let Some((_, k)) = best_seg else { continue };
            let (Some(pa), Some(pb)) = (own.get(k), own.get(k + 1)) else {
                continue;
            };
            let (a, b) = (pa.1.ground, pb.1.ground);
            // Other vertebrae the new segments must miss (not the ones the
            // end points are on).
            let Some(via) = place_via(
                &a,
                &b,
                &c.vertebra,
                &bones,
                |p| {
                    m.wraps.iter().all(|w| {
                        spheres
                            .get(&w.wrap_object)
                            .map(|s| {
                                (p - Point3::from(s.frame.translation.vector)).norm()
                                    > s.radius + 0.0005
                            })
                            .unwrap_or(true)
                    })
                },
                &[pa.1.body.clone(), pb.1.body.clone()],
            ) else {
                continue;
            };
            // Insert after the PathPointSet entry of the first own point.
            let prev_idx = path.polyline[..=pa.0]
                .iter()
                .filter(|v| v.body.is_some())
                .count();
            let active = crate::base::kin::muscle_path(&model, m, &poses, &q)?;
            let Some(prev_name) = active
                .get(prev_idx.saturating_sub(1))
                .map(|p| p.name.clone())
            else {
                continue;
            };
            let name = format!("{}-clear-{}", m.name, c.vertebra);
            let local = inv * via;
            insert_via(doc, &m.name, &prev_name, &name, &c.vertebra, &local.coords);
            edits.push(PathEdit {
                muscle: m.name.clone(),
                vertebra: c.vertebra.clone(),
                action: format!("via point {name}"),
                depth_mm: c.depth_mm,
            });
            edited.insert(m.name.clone());
        }
        if edited.is_empty() {
            break;
        }
        pending = Some(edited);
    }
    Ok(edits)
}

/// The via point (ground) on `vertebra` for the segment `a`-`b`.
fn place_via(
    a: &Point3<f64>,
    b: &Point3<f64>,
    vertebra: &str,
    bones: &[Bone],
    outside_wraps: impl Fn(&Point3<f64>) -> bool,
    end_bodies: &[Option<String>],
) -> Option<Point3<f64>> {
    let bone = bones.iter().find(|b| b.name == vertebra)?;
    let (mq, x, inv) = (bone.query, &bone.pose, bone.to_local);
    let (la, lb) = (inv * a, inv * b);
    // Points along the chord inside the bone (vertebra frame): its middle
    // first, then its quarters (a detour from the middle may be blocked by
    // a neighbouring vertebra where one from a quarter is not).
    let hits = mq.segment_hits(&la, &lb);
    let (c0, c1) = if hits.len() >= 2 {
        (hits.first()?.point, hits.last()?.point)
    } else {
        (la, lb)
    };
    let starts = [0.5, 0.25, 0.75].map(|f| c0 + (c1 - c0) * f);
    let axis = (lb - la).try_normalize(1e-12)?;
    let u = axis
        .cross(&Vector3::x())
        .try_normalize(1e-6)
        .unwrap_or_else(|| axis.cross(&Vector3::y()).normalize());
    let v = axis.cross(&u);
    // A detour that clears everything from any start point, else the best
    // graze.
    let mut found: Vec<Detour> = Vec::new();
    for mid in starts {
        // The first start with a clearing detour decides: the later starts
        // are only searched when none has cleared yet.
        if found.iter().any(|d| d.clear.is_some()) {
            break;
        }
        found.push(detour_from(
            &mid,
            &u,
            &v,
            x,
            |p, g, wanted| {
                // The cheap tests first: outside the muscle's wrap spheres,
                // then clear of the crossed bone (distance, then inside).
                if !outside_wraps(g) || !clear_of_bone(mq, p) {
                    return None;
                }
                // Each new segment's run inside each other vertebra, once,
                // stopping as soon as the point cannot be wanted.
                let first = runs_inside(a, g, bones, end_bodies.get(..1));
                let second = runs_inside(g, b, bones, end_bodies.get(1..2));
                let mut inside = [0.0, 0.0];
                let mut deep = false;
                for (k, run) in first.map(|r| (0, r)).chain(second.map(|r| (1, r))) {
                    deep |= run > GRAZE;
                    inside[k] += run;
                    if deep && wanted.past(inside[0] + inside[1]) {
                        return None;
                    }
                }
                Some(if deep {
                    Fit::Graze(inside[0] + inside[1])
                } else {
                    Fit::Clear
                })
            },
            a,
            b,
        ));
    }
    let clear = found.iter().find_map(|d| d.clear);
    let least = |pick: fn(&Detour) -> Option<Candidate>| {
        found.iter().filter_map(pick).min_by(|p, q| {
            (p.0, p.1)
                .partial_cmp(&(q.0, q.1))
                .unwrap_or(std::cmp::Ordering::Equal)
        })
    };
    let graze = least(|d| d.graze);
    // Neither: the detour that runs least through other vertebrae than the
    // path's end bodies, if that is shorter than the direct segment's run;
    // the next round clears what its new segments still cross, and the
    // self-check reports what is left.
    let direct: f64 = runs_inside(a, b, bones, Some(end_bodies)).sum();
    let progress = least(|d| d.least).filter(|(inside, _, _)| *inside < direct);
    clear
        .map(|(_, p)| p)
        .or(graze.map(|(_, _, p)| p))
        .or(progress.map(|(_, _, p)| p))
}

/// How a trial via point's two segments pass the other vertebrae.
enum Fit {
    /// Clear of every vertebra.
    Clear,
    /// Running this length (m) inside them.
    Graze(f64),
}

/// Which trial points a detour search can still use.
#[derive(Clone, Copy)]
enum Wanted {
    /// Any point: nothing found yet.
    Any,
    /// A clearing point, or a graze running less than this (m) inside
    /// other vertebrae (the least found so far; the fallback graze is then
    /// that one or none).
    Below(f64),
}

impl Wanted {
    /// Is a point that does not clear, and runs at least `inside` (m)
    /// inside other vertebrae, past use?
    fn past(self, inside: f64) -> bool {
        match self {
            Wanted::Any => false,
            Wanted::Below(least) => inside > least,
        }
    }
}

/// A non-clearing detour: (length inside other vertebrae, detour length,
/// point), all m.
type Candidate = (f64, f64, Point3<f64>);

/// The detours found from one start. The grazes are searched to the end
/// only when no detour clears (a clearing one makes them unused).
struct Detour {
    /// The shortest clearing one (offset steps, point).
    clear: Option<(usize, Point3<f64>)>,
    /// The least-inside graze under [`FALLBACK_INSIDE`] (inside, detour,
    /// point).
    graze: Option<Candidate>,
    /// The least-inside one of any depth (inside, detour, point).
    least: Option<Candidate>,
}

/// The detour point from `mid` (vertebra frame) over 36 directions in the
/// plane of `u`, `v`: the shortest detour whose segments `score` clears
/// (score 0), the one running least inside other vertebrae under
/// [`FALLBACK_INSIDE`] of the self-check's tolerance, and the one running
/// least inside them at any depth. `score` takes a trial point in the
/// vertebra frame and in ground, and refuses (`None`) one too close to
/// the bone or inside a wrap sphere, or one that cannot be `wanted` any
/// more. Ground coordinates.
fn detour_from(
    mid: &Point3<f64>,
    u: &Vector3<f64>,
    v: &Vector3<f64>,
    x: &nalgebra::Isometry3<f64>,
    score: impl Fn(&Point3<f64>, &Point3<f64>, Wanted) -> Option<Fit>,
    a: &Point3<f64>,
    b: &Point3<f64>,
) -> Detour {
    let mut fallback: Option<Candidate> = None;
    let mut least: Option<Candidate> = None;
    let directions: Vec<Vector3<f64>> = (0..36)
        .map(|i| {
            let th = (i as f64) * std::f64::consts::TAU / 36.0;
            u * th.cos() + v * th.sin()
        })
        .collect();
    // Offsets outward, every direction at each: the first clearing point
    // is at the shortest clearing offset, and of the directions there the
    // first keeps the place. The detour depends on the offset alone (every
    // direction is perpendicular to the chord through `mid`), so offsets
    // are compared as whole steps, not through the round-off of the
    // lengths. The grazes are used only when no detour clears.
    for step in 1..=OFFSET_STEPS {
        let t = step as f64 * OFFSET_STEP;
        for d in &directions {
            let p = mid + d * t;
            let g = x * p;
            let wanted = match least {
                Some((inside, _, _)) => Wanted::Below(inside),
                None => Wanted::Any,
            };
            match score(&p, &g, wanted) {
                Some(Fit::Clear) => {
                    return Detour {
                        clear: Some((step, g)),
                        graze: fallback,
                        least,
                    };
                }
                Some(Fit::Graze(inside)) => {
                    let detour = (g - a).norm() + (b - g).norm();
                    let better = |f: Option<Candidate>| {
                        f.is_none_or(|(fi, fd, _)| (inside, detour) < (fi, fd))
                    };
                    if better(least) {
                        least = Some((inside, detour, g));
                    }
                    if inside < FALLBACK_INSIDE * wrapped::DEPTH_TOLERANCE && better(fallback) {
                        fallback = Some((inside, detour, g));
                    }
                }
                None => {}
            }
        }
    }
    Detour {
        clear: None,
        graze: fallback,
        least,
    }
}

/// A vertebra the paths are cleared from: its body, its mesh query (body
/// frame) and its pose (body frame to ground) with the inverse.
struct Bone<'a> {
    name: &'a str,
    query: &'a MeshQuery,
    pose: nalgebra::Isometry3<f64>,
    to_local: nalgebra::Isometry3<f64>,
}

/// Length (m) of the segment `a`-`b` (ground) inside each vertebra but
/// those named in `skip`, in the order of `bones`, computed as the
/// iterator is consumed.
fn runs_inside<'a>(
    a: &'a Point3<f64>,
    b: &'a Point3<f64>,
    bones: &'a [Bone],
    skip: Option<&'a [Option<String>]>,
) -> impl Iterator<Item = f64> + 'a {
    let skip = skip.unwrap_or(&[]);
    bones
        .iter()
        .filter(move |bone| !skip.iter().flatten().any(|s| s == bone.name))
        .map(move |bone| {
            let inv = &bone.to_local;
            bone.query.segment_length_inside(&(inv * a), &(inv * b))
        })
}

/// Is `p` (vertebra frame) outside the bone by more than [`CLEARANCE`]?
/// The distance first: the inside test casts rays.
fn clear_of_bone(mq: &MeshQuery, p: &Point3<f64>) -> bool {
    mq.farther_than(p, CLEARANCE) && !mq.contains(p)
}

/// The `objects` of a muscle's PathPointSet.
pub(super) fn path_points<'a>(doc: &'a mut Document, muscle: &str) -> Option<&'a mut Element> {
    doc.component_mut("ForceSet", muscle)?
        .elements_mut()
        .find(|e| e.name == "GeometryPath")?
        .child_mut("PathPointSet")?
        .child_mut("objects")
}

/// Insert a fixed PathPoint `name` on `body` after the point `after`;
/// explicit PathWrap ranges past it are shifted.
fn insert_via(
    doc: &mut Document,
    muscle: &str,
    after: &str,
    name: &str,
    body: &str,
    loc: &Vector3<f64>,
) {
    let el = Element::new("PathPoint")
        .with_attr("name", name)
        .with_prop("socket_parent_frame", format!("/bodyset/{body}"))
        .with_prop(
            "location",
            format!(
                "{} {} {}",
                crate::util::fmt_f64(loc.x),
                crate::util::fmt_f64(loc.y),
                crate::util::fmt_f64(loc.z)
            ),
        );
    let mut pos_1based = None;
    if let Some(objs) = path_points(doc, muscle) {
        let mut k = 0;
        let mut at = None;
        for (i, n) in objs.children.iter().enumerate() {
            if let Node::Element(e) = n {
                k += 1;
                if e.name_attr() == after {
                    at = Some((i, k));
                }
            }
        }
        if let Some((i, k)) = at {
            objs.children.insert(i + 1, Node::Element(el));
            pos_1based = Some(k as i64 + 1);
        }
    }
    let Some(p) = pos_1based else { return };
    if let Some(ws) = doc
        .component_mut("ForceSet", muscle)
        .and_then(|e| e.elements_mut().find(|e| e.name == "GeometryPath"))
        .and_then(|g| g.child_mut("PathWrapSet"))
        .and_then(|w| w.child_mut("objects"))
    {
        for w in ws.elements_mut() {
            let Some(r) = w.child_text("range") else {
                continue;
            };
            let v: Vec<i64> = r
                .split_whitespace()
                .filter_map(|s| s.parse().ok())
                .collect();
            if let [lo, hi] = v[..] {
                let sh = |x: i64| if x >= p { x + 1 } else { x };
                w.set_child_text("range", format!("{} {}", sh(lo), sh(hi)));
            }
        }
    }
}

fn remove_path_wrap(doc: &mut Document, muscle: &str, sphere: &str) {
    if let Some(ws) = doc
        .component_mut("ForceSet", muscle)
        .and_then(|e| e.elements_mut().find(|e| e.name == "GeometryPath"))
        .and_then(|g| g.child_mut("PathWrapSet"))
        .and_then(|w| w.child_mut("objects"))
    {
        ws.children.retain(|n| match n {
            Node::Element(e) => e.child_text("wrap_object").as_deref() != Some(sphere),
            _ => true,
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A point clears once it is 3 mm from the chord, whatever the
    /// direction: every direction ties at the third step, and the first
    /// one (`u`) keeps the place, as the search's steps are compared
    /// exactly, not through the round-off of the detour lengths.
    #[test]
    fn equal_offsets_keep_the_first_direction() {
        let (a, b) = (Point3::new(0.0, -0.1, 0.0), Point3::new(0.0, 0.2, 0.0));
        let mid = Point3::new(0.0, 0.05, 0.0);
        let (u, v) = (Vector3::z(), Vector3::x());
        let x = nalgebra::Isometry3::translation(0.01, -0.02, 0.03);
        let score = |p: &Point3<f64>, _: &Point3<f64>, _: Wanted| {
            ((p - mid).norm() > 0.0025).then_some(Fit::Clear)
        };
        let found = detour_from(&mid, &u, &v, &x, score, &(x * a), &(x * b));
        let (steps, g) = found.clear.expect("a clearing detour");
        assert_eq!(steps, 3);
        assert!((g - x * (mid + u * 0.003)).norm() < 1e-15, "{g}");
    }

    /// A shorter clearing offset in a later direction wins over a longer
    /// one in an earlier direction.
    #[test]
    fn the_shortest_clearing_offset_wins_whatever_the_direction() {
        let (a, b) = (Point3::new(0.0, -0.1, 0.0), Point3::new(0.0, 0.2, 0.0));
        let mid = Point3::new(0.0, 0.05, 0.0);
        let (u, v) = (Vector3::z(), Vector3::x());
        let x = nalgebra::Isometry3::identity();
        // Along u (the first direction) clear from 20 mm; along v (the
        // tenth, at 90 degrees) from 4 mm; nowhere else.
        let score = |p: &Point3<f64>, _: &Point3<f64>, _: Wanted| {
            let d = p - mid;
            let along = |w: &Vector3<f64>| (d.normalize() - w).norm() < 1e-9;
            let clear = (along(&u) && d.norm() > 0.0195) || (along(&v) && d.norm() > 0.0035);
            clear.then_some(Fit::Clear)
        };
        let found = detour_from(&mid, &u, &v, &x, score, &a, &b);
        let (steps, g) = found.clear.expect("a clearing detour");
        assert_eq!(steps, 4);
        assert!((g - (mid + v * 0.004)).norm() < 1e-12, "{g}");
    }

    /// Offsets up to 50 mm are searched, the last one included.
    #[test]
    fn the_largest_offset_is_searched() {
        let (a, b) = (Point3::new(0.0, -0.1, 0.0), Point3::new(0.0, 0.2, 0.0));
        let mid = Point3::new(0.0, 0.05, 0.0);
        let x = nalgebra::Isometry3::identity();
        let score = |p: &Point3<f64>, _: &Point3<f64>, _: Wanted| {
            ((p - mid).norm() > 0.0495).then_some(Fit::Clear)
        };
        let found = detour_from(&mid, &Vector3::z(), &Vector3::x(), &x, score, &a, &b);
        assert_eq!(found.clear.map(|c| c.0), Some(50));
    }
}
