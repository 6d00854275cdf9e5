//! Is a naming of a segmentation's structures anatomically right? The same
//! test decides a label map's table (each built-in table is a naming of
//! its labels) and checks a mesh folder's file names. A naming is read as
//! a spine: the structures named C1..C7, T1..L5 and the sacrum, in their
//! order along the spine, and every other structure. It is contradicted by:
//! - **order**: two named vertebrae out of order along the spine (two
//!   files or labels swapped: the pair is named when one swap explains it);
//! - **spacing**: consecutive named levels much nearer or further apart
//!   than their distance in levels says (a misnumbered level, a label
//!   holding two vertebrae), against the published vertebral heights and
//!   discs ([`crate::anatomy`]) scaled to the patient;
//! - **the sacrum**: a structure named sacrum the size and height of the
//!   vertebra above it is a lumbar vertebra;
//! - **named vertebrae that are not vertebrae**: several times the volume
//!   of their named neighbours, or off the spine's line;
//! - **unnamed vertebrae**: a structure the naming calls an organ (or does
//!   not know) that is placed and shaped like a vertebra: on the spine's
//!   line or its continuation, of a vertebra's volume, height and width
//!   (the cord, the canal, the aorta are thin; discs are flat).
//!
//! Structures cut by the field of view are judged by their place only.
//! The spacing scale (measured over expected centre distances) also
//! measures how well a consistent naming fits: two consistent namings of
//! the same map are told apart by it, or not at all.

use crate::anatomy::DimensionTable;
use crate::landmarks::Level;
use nalgebra::{Matrix3, Point3, Vector3};

/// One structure of a segmentation (metres, the segmentation's axes).
#[derive(Debug, Clone, PartialEq)]
pub struct Structure {
    /// Where it comes from (`label 27`, `L3.stl`).
    pub origin: String,
    /// Centroid of its volume (m).
    pub centroid: Point3<f64>,
    /// Enclosed volume (m^3).
    pub volume: f64,
    /// Covariance of its volume (m^2).
    pub covariance: Matrix3<f64>,
    /// Cut by the field of view (size is not evidence).
    pub truncated: bool,
}

impl Structure {
    /// The structure of a closed mesh (its enclosed solid).
    pub fn of_mesh(mesh: &crate::mesh::TriMesh, origin: String, truncated: bool) -> Structure {
        let volume = mesh.signed_volume().abs();
        let centroid = super::hints::centroid(mesh);
        // Second moment from the inertia tensor: C = tr(I)/2 - I.
        let covariance = mesh
            .solid_inertia()
            .filter(|_| volume > 0.0)
            .map(|i| (Matrix3::identity() * (0.5 * i.trace()) - i) / volume)
            .unwrap_or_else(Matrix3::zeros);
        Structure {
            origin,
            centroid,
            volume,
            covariance,
            truncated,
        }
    }

    /// Length along `u` (m): the length of a uniform bar with the same
    /// variance along `u`.
    pub fn extent(&self, u: &Vector3<f64>) -> f64 {
        (12.0 * u.dot(&(self.covariance * u)).max(0.0)).sqrt()
    }

    /// Largest length across `u` (m), as [`Structure::extent`]: the cord,
    /// a vessel or a muscle is thin, a vertebra wide.
    pub fn width(&self, u: &Vector3<f64>) -> f64 {
        let p = Matrix3::identity() - u * u.transpose();
        let c = p * self.covariance * p;
        let eig = c.symmetric_eigenvalues();
        (12.0 * eig.max().max(0.0)).sqrt()
    }
}

/// A place in the spine named by a reading: cervical C1..C7, T1..L5 or
/// the sacrum.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Place {
    /// A cervical vertebra, C1..C7 (1..7).
    Cervical(u8),
    /// A thoracolumbar level or the sacrum.
    Level(Level),
}

impl Place {
    /// 0 = C1 .. 6 = C7, 7 = T1 .. 23 = L5, 24 = sacrum.
    fn index(self) -> usize {
        match self {
            Place::Cervical(c) => c.saturating_sub(1) as usize,
            Place::Level(l) => 7 + l.index(),
        }
    }
    fn is_sacrum(self) -> bool {
        matches!(self, Place::Level(l) if l.is_sacrum())
    }
}

impl std::fmt::Display for Place {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Place::Cervical(c) => write!(f, "C{c}"),
            Place::Level(l) if l.is_sacrum() => write!(f, "sacrum"),
            Place::Level(l) => write!(f, "{l}"),
        }
    }
}

/// A naming of the structures: each named place, and the others (with
/// what the naming calls them).
#[derive(Debug, Clone, Default)]
pub struct Reading<'a> {
    /// Structures the reading names, with their places.
    pub named: Vec<(Place, &'a Structure)>,
    /// Structures it does not place, with what it calls them.
    pub others: Vec<(String, &'a Structure)>,
}

/// What the anatomy says of a reading.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Assessment {
    /// Clear contradictions: the naming is wrong.
    pub problems: Vec<String>,
    /// Doubts that do not contradict it (size dips, odd spacings).
    pub doubts: Vec<String>,
    /// Measured over expected centre distances of consecutive named T1..L5
    /// levels (median; `None` with fewer than two such levels).
    pub scale: Option<f64>,
}

impl Assessment {
    /// True when nothing contradicts the reading (doubts allowed).
    pub fn consistent(&self) -> bool {
        self.problems.is_empty()
    }
}

/// Ratio of a pair's distance to its expected distance (both scaled) below
/// or above which the naming is contradicted (a level skipped or doubled).
const SPACING_CLEAR: (f64, f64) = (0.55, 1.7);
/// Same, for a doubt.
const SPACING_DOUBT: (f64, f64) = (0.75, 1.35);
/// Volume of a named vertebra over the mean of its named neighbours' out
/// of which it is no vertebra (adjacent vertebrae differ by up to about
/// 2.5 times: 15 % per axis either way).
const VOLUME_CLEAR: (f64, f64) = (0.25, 4.0);
/// A sacrum is at least this much larger (volume) or taller than L5.
const SACRUM_OVER_L5: f64 = 1.3;

/// Assess a reading. `up` is the patient's cranial direction when the
/// axes are known (a NIfTI world), else the spine's main axis is used.
pub fn assess(reading: &Reading, up: Option<Vector3<f64>>, dims: &DimensionTable) -> Assessment {
    let mut a = Assessment::default();
    let mut named = reading.named.clone();
    named.sort_by_key(|(p, _)| p.index());
    if named.is_empty() {
        return a;
    }
    let u = up.or_else(|| spine_axis(&named)).unwrap_or(Vector3::z());
    check_order(&named, &u, &mut a);
    a.scale = spacing_scale(&named, dims);
    if let Some(s) = a.scale {
        check_spacing(&named, s, dims, &mut a);
    }
    check_sacrum(&named, &u, &mut a);
    check_named_sizes(&named, &mut a);
    check_unnamed(&named, &reading.others, &u, &mut a);
    a
}

/// The main axis of the named centroids, oriented cranially (the first
/// named place above the last).
fn spine_axis(named: &[(Place, &Structure)]) -> Option<Vector3<f64>> {
    let pts: Vec<Point3<f64>> = named
        .iter()
        .filter(|(p, _)| !p.is_sacrum())
        .map(|(_, s)| s.centroid)
        .collect();
    if pts.len() < 2 {
        return None;
    }
    let axes = crate::mesh::geom::point_principal_axes(&pts)?;
    let v: Vector3<f64> = axes.axes.column(0).into_owned();
    let along = pts[0] - pts[pts.len() - 1];
    Some(if v.dot(&along) < 0.0 { -v } else { v })
}

/// Consecutive named places must descend along `u`; a single swap that
/// puts every one in order is named.
fn check_order(named: &[(Place, &Structure)], u: &Vector3<f64>, a: &mut Assessment) {
    let h: Vec<f64> = named
        .iter()
        .map(|(_, s)| s.centroid.coords.dot(u))
        .collect();
    let bad: Vec<usize> = (1..named.len()).filter(|&i| h[i] >= h[i - 1]).collect();
    if bad.is_empty() {
        return;
    }
    let sorted = |h: &[f64]| h.windows(2).all(|w| w[1] < w[0]);
    for i in 0..named.len() {
        for j in i + 1..named.len() {
            let mut hh = h.clone();
            hh.swap(i, j);
            if sorted(&hh) {
                a.problems.push(format!(
                    "{} ({}) and {} ({}) are in each other's places along the spine (swapped?)",
                    named[i].0, named[i].1.origin, named[j].0, named[j].1.origin
                ));
                return;
            }
        }
    }
    let pairs: Vec<String> = bad
        .iter()
        .map(|&i| {
            format!(
                "{} ({}) is not above {} ({})",
                named[i - 1].0,
                named[i - 1].1.origin,
                named[i].0,
                named[i].1.origin
            )
        })
        .collect();
    a.problems.push(format!(
        "named levels out of order along the spine: {}",
        pairs.join("; ")
    ));
}

/// Expected distance (m) between the centres of two T1..L5 levels.
fn expected_distance(a: Level, b: Level, dims: &DimensionTable) -> f64 {
    let (lo, hi) = (a.index().min(b.index()), a.index().max(b.index()));
    (lo..hi)
        .filter_map(|i| Some((Level::from_index(i)?, Level::from_index(i + 1)?)))
        .map(|(u, l)| {
            let (du, dl) = (dims.level(u), dims.level(l));
            0.5 * du.body_height().mean + du.disc_height.mean + 0.5 * dl.body_height().mean
        })
        .sum()
}

/// Consecutive named T1..L5 vertebrae (sacrum and cervical excluded).
fn vertebra_pairs<'a>(
    named: &'a [(Place, &'a Structure)],
) -> impl Iterator<Item = (Level, &'a Structure, Level, &'a Structure)> + 'a {
    named.windows(2).filter_map(|w| match (w[0].0, w[1].0) {
        (Place::Level(a), Place::Level(b)) if !b.is_sacrum() => Some((a, w[0].1, b, w[1].1)),
        _ => None,
    })
}

/// Median of measured over expected distances of adjacent named levels
/// (of every consecutive pair when no two are adjacent).
fn spacing_scale(named: &[(Place, &Structure)], dims: &DimensionTable) -> Option<f64> {
    let ratio = |a: Level, sa: &Structure, b: Level, sb: &Structure| {
        (sa.centroid - sb.centroid).norm() / expected_distance(a, b, dims)
    };
    let adjacent: Vec<f64> = vertebra_pairs(named)
        .filter(|(a, _, b, _)| a.caudal() == Some(*b))
        .map(|(a, sa, b, sb)| ratio(a, sa, b, sb))
        .collect();
    let all: Vec<f64> = vertebra_pairs(named)
        .map(|(a, sa, b, sb)| ratio(a, sa, b, sb))
        .collect();
    crate::util::median(if adjacent.is_empty() { &all } else { &adjacent })
}

/// Consecutive named levels against their expected distance x `scale`.
fn check_spacing(
    named: &[(Place, &Structure)],
    scale: f64,
    dims: &DimensionTable,
    a: &mut Assessment,
) {
    for (la, sa, lb, sb) in vertebra_pairs(named) {
        let d = (sa.centroid - sb.centroid).norm();
        let e = expected_distance(la, lb, dims) * scale;
        let r = d / e;
        let what = format!(
            "{la} ({}) and {lb} ({}) are {:.0} mm apart, {} level(s) at this spine's size would be {:.0} mm",
            sa.origin,
            sb.origin,
            d * 1e3,
            lb.index() - la.index(),
            e * 1e3
        );
        if !(SPACING_CLEAR.0..=SPACING_CLEAR.1).contains(&r) {
            a.problems
                .push(format!("{what}: a level misnumbered, missing or doubled"));
        } else if !(SPACING_DOUBT.0..=SPACING_DOUBT.1).contains(&r) {
            a.doubts.push(what);
        }
    }
}

/// The sacrum is larger or taller than the lumbar vertebra named above it.
fn check_sacrum(named: &[(Place, &Structure)], u: &Vector3<f64>, a: &mut Assessment) {
    let Some(k) = named.iter().position(|(p, _)| p.is_sacrum()) else {
        return;
    };
    let (_, s) = named[k];
    let Some((pl, l)) = k.checked_sub(1).map(|j| named[j]) else {
        return;
    };
    if s.truncated || l.truncated || !matches!(pl, Place::Level(x) if x >= Level::L1) {
        return;
    }
    let v = s.volume / l.volume.max(1e-12);
    let h = s.extent(u) / l.extent(u).max(1e-9);
    if v < SACRUM_OVER_L5 && h < SACRUM_OVER_L5 {
        a.problems.push(format!(
            "the sacrum ({}) has {v:.1} times the volume and {h:.1} times the height of {pl} ({}): a lumbar vertebra, not a sacrum",
            s.origin, l.origin
        ));
    }
}

/// Named vertebrae of several times (or a fraction of) their named
/// neighbours' volume are no vertebrae (an organ, two vertebrae, a piece).
fn check_named_sizes(named: &[(Place, &Structure)], a: &mut Assessment) {
    let verts: Vec<&(Place, &Structure)> = named.iter().filter(|(p, _)| !p.is_sacrum()).collect();
    for (i, (p, s)) in verts.iter().enumerate() {
        if s.truncated {
            continue;
        }
        let nb: Vec<f64> = [i.checked_sub(1), (i + 1 < verts.len()).then_some(i + 1)]
            .into_iter()
            .flatten()
            .map(|j| verts[j])
            .filter(|(q, t)| !t.truncated && q.index().abs_diff(p.index()) <= 3)
            .map(|(_, t)| t.volume)
            .collect();
        if nb.is_empty() {
            continue;
        }
        let r = s.volume / (nb.iter().sum::<f64>() / nb.len() as f64);
        if !(VOLUME_CLEAR.0..=VOLUME_CLEAR.1).contains(&r) {
            a.problems.push(format!(
                "{p} ({}) has {r:.2} times the volume of its named neighbours: not one vertebra",
                s.origin
            ));
        }
    }
}

/// Structures the reading does not call vertebrae that lie on the spine's
/// line (or its continuation by two levels past either end) with a
/// vertebra's volume and height.
fn check_unnamed(
    named: &[(Place, &Structure)],
    others: &[(String, &Structure)],
    u: &Vector3<f64>,
    a: &mut Assessment,
) {
    let chain: Vec<&Structure> = named
        .iter()
        .filter(|(p, s)| !p.is_sacrum() && !s.truncated)
        .map(|(_, s)| *s)
        .collect();
    let all: Vec<&Structure> = named.iter().map(|(_, s)| *s).collect();
    if all.is_empty() {
        return;
    }
    let spacing = crate::util::median(
        &all.windows(2)
            .map(|w| (w[0].centroid - w[1].centroid).norm())
            .collect::<Vec<f64>>(),
    )
    .unwrap_or(0.03);
    let line = extended_line(&all, u, 2.5 * spacing);
    let mut found = Vec::new();
    for (what, o) in others {
        let Some((d, nearest)) = nearest_on_line(&line, &all, &o.centroid) else {
            continue;
        };
        if d > 0.6 * spacing {
            continue;
        }
        // Compared with the nearest whole named vertebra (or any named one).
        let refs = if chain.is_empty() { &all } else { &chain };
        let r = refs
            .iter()
            .min_by(|x, y| {
                (x.centroid - nearest)
                    .norm()
                    .total_cmp(&(y.centroid - nearest).norm())
            })
            .copied()
            .unwrap_or(all[0]);
        let v = o.volume / r.volume.max(1e-12);
        let h = o.extent(u) / r.extent(u).max(1e-9);
        let w = o.width(u) / r.width(u).max(1e-9);
        // A structure cut by the field of view can be smaller and shorter.
        let (v_lo, h_lo) = if o.truncated { (0.05, 0.0) } else { (0.3, 0.5) };
        let vertebra_like = (v_lo..=3.5).contains(&v) && (h_lo..=2.0).contains(&h) && w >= 0.4;
        if vertebra_like {
            found.push(format!("{} ({what})", o.origin));
        }
    }
    if !found.is_empty() {
        a.problems.push(format!(
            "{} placed and shaped like vertebrae on the spine's line but not named vertebrae: {}",
            found.len(),
            found.join(", ")
        ));
    }
}

/// The polyline through the named centroids, extended by `reach` past
/// either end along the chain's own direction there (over its last two
/// segments: a curved spine's continuation, which may lean 30 deg or more
/// from the superior axis); along `u` when a single structure is named.
fn extended_line(all: &[&Structure], u: &Vector3<f64>, reach: f64) -> Vec<Point3<f64>> {
    let mut line: Vec<Point3<f64>> = all.iter().map(|s| s.centroid).collect();
    let n = line.len();
    if n == 0 {
        return line;
    }
    let k = 2.min(n - 1);
    let towards = |from: Point3<f64>, to: Point3<f64>, fallback: Vector3<f64>| {
        (to - from).try_normalize(1e-9).unwrap_or(fallback)
    };
    let up = towards(line[k], line[0], *u);
    let down = towards(line[n - 1 - k], line[n - 1], -u);
    let (first, last) = (line[0], line[n - 1]);
    line.insert(0, first + up * reach);
    line.push(last + down * reach);
    line
}

/// Distance from `p` to the polyline and the nearest point on it.
fn nearest_on_line(
    line: &[Point3<f64>],
    _all: &[&Structure],
    p: &Point3<f64>,
) -> Option<(f64, Point3<f64>)> {
    line.windows(2)
        .map(|w| {
            let (a, b) = (w[0], w[1]);
            let ab = b - a;
            let t = ((p - a).dot(&ab) / ab.norm_squared().max(1e-18)).clamp(0.0, 1.0);
            let q = a + ab * t;
            ((p - q).norm(), q)
        })
        .min_by(|x, y| x.0.total_cmp(&y.0))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A straight spine along +z: T1..L5 at the template's spacing and a
    /// sacrum, the vertebrae's volume growing caudally.
    fn spine() -> Vec<(Place, Structure)> {
        let dims = DimensionTable::embedded().unwrap();
        let mut z = 0.0;
        let mut out = Vec::new();
        for (i, l) in Level::ALL.iter().enumerate() {
            if i > 0 {
                z -= expected_distance(Level::ALL[i - 1], *l, &dims);
            }
            let (vol, h) = if l.is_sacrum() {
                (2.0e-4, 0.09)
            } else {
                (1.5e-5 * (1.0 + 0.12 * i as f64), 0.035)
            };
            let w: f64 = 0.05;
            let cov = Matrix3::from_diagonal(&(Vector3::new(w * w, w * w, h * h) / 12.0));
            out.push((
                Place::Level(*l),
                Structure {
                    origin: format!("{l}.stl"),
                    centroid: Point3::new(0.0, 0.0, z - if l.is_sacrum() { 0.03 } else { 0.0 }),
                    volume: vol,
                    covariance: cov,
                    truncated: false,
                },
            ));
        }
        out
    }

    fn reading(s: &[(Place, Structure)]) -> Reading<'_> {
        Reading {
            named: s.iter().map(|(p, x)| (*p, x)).collect(),
            others: vec![],
        }
    }

    #[test]
    fn a_right_spine_is_consistent_and_a_swap_is_named() {
        let dims = DimensionTable::embedded().unwrap();
        let s = spine();
        let a = assess(&reading(&s), Some(Vector3::z()), &dims);
        assert!(a.consistent(), "{a:?}");
        assert!((a.scale.unwrap() - 1.0).abs() < 1e-9);
        // The same without an up axis (folders): the main axis.
        assert!(assess(&reading(&s), None, &dims).consistent());
        // L1 and L4 swapped.
        let mut w = spine();
        let (i, j) = (12, 15);
        let ci = w[i].1.centroid;
        w[i].1.centroid = w[j].1.centroid;
        w[j].1.centroid = ci;
        let a = assess(&reading(&w), None, &dims);
        assert!(
            a.problems
                .iter()
                .any(|p| p.contains("L1 (L1.stl) and L4 (L4.stl)")),
            "{a:?}"
        );
    }

    #[test]
    fn a_gap_is_fine_but_a_renumbering_is_not() {
        let dims = DimensionTable::embedded().unwrap();
        let mut s = spine();
        s.remove(13); // L2 missing
        assert!(assess(&reading(&s), Some(Vector3::z()), &dims).consistent());
        // L3..L5 named L2..L4 with L2 removed: L1-"L2" is one level apart.
        let mut r = spine();
        r.remove(13);
        for (p, _) in r.iter_mut().skip(13).take(3) {
            if let Place::Level(l) = p {
                *p = Place::Level(l.cranial().unwrap());
            }
        }
        let a = assess(&reading(&r), Some(Vector3::z()), &dims);
        assert!(!a.consistent(), "{a:?}");
    }

    #[test]
    fn a_lumbar_sacrum_and_an_unnamed_vertebra_are_found() {
        let dims = DimensionTable::embedded().unwrap();
        let mut s = spine();
        // The sacrum is an L5-like vertebra.
        let l5 = s[16].1.clone();
        s[17].1.volume = l5.volume * 1.05;
        s[17].1.covariance = l5.covariance;
        let a = assess(&reading(&s), Some(Vector3::z()), &dims);
        assert!(
            a.problems.iter().any(|p| p.contains("not a sacrum")),
            "{a:?}"
        );
        // L3 called an organ.
        let s = spine();
        let mut r = reading(&s);
        let (_, l3) = r.named.remove(14);
        r.others.push(("colon".into(), l3));
        let a = assess(&r, Some(Vector3::z()), &dims);
        assert!(
            a.problems.iter().any(|p| p.contains("L3.stl (colon)")),
            "{a:?}"
        );
    }
}
