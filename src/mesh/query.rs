//! Spatial queries on a mesh: closest point, point-inside test, and
//! ray/segment intersection, with parry's BVH built once in [`MeshQuery`].
//!
//! Degenerate triangles (zero area, repeated indices) are left out of the
//! acceleration structure; duplicate vertices are harmless because no
//! topology is needed. The inside test is orientation-free: it counts
//! crossings along three fixed, non-axis-aligned rays and takes the
//! majority, so meshes with flipped triangles (as in the shared VTP files)
//! give the same answer as consistently wound ones. It assumes a closed
//! surface (weld duplicated seam vertices first if needed: the crossings do
//! not depend on connectivity, only on the surface having no holes).

use super::TriMesh;
use crate::error::{Error, Result};
use nalgebra::{Point3, Vector3};
use parry3d_f64::query::PointQuery;
use parry3d_f64::shape::TriMesh as ParryMesh;

/// A point on the mesh surface.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceHit {
    /// The point (m).
    pub point: Point3<f64>,
    /// Distance from the query point (closest point), or the ray parameter
    /// (`origin + t * dir`; for segments, the fraction 0..1 along it).
    pub t: f64,
    /// Index of the triangle in the original [`TriMesh`].
    pub triangle: usize,
}

/// A mesh with its bounding-volume hierarchy, for repeated queries.
pub struct MeshQuery {
    mesh: TriMesh,
    shape: ParryMesh,
    /// parry triangle index -> original triangle index.
    tri_map: Vec<usize>,
    /// Length scale for tolerances (bounding-box diagonal).
    scale: f64,
    /// Bounding box of the vertices: a point outside is outside the surface.
    bounds: (Point3<f64>, Point3<f64>),
}

/// Fixed ray directions for the parity test (irrational-ish, not aligned
/// with axes or typical mesh edges).
const RAYS: [[f64; 3]; 3] = [
    [0.5773, 0.6022, 0.5518],
    [-0.7045, 0.3203, -0.6333],
    [0.2672, -0.8881, 0.3741],
];

impl MeshQuery {
    /// Build the acceleration structure. Fails for a mesh without any
    /// non-degenerate triangle or with invalid indices/coordinates.
    pub fn new(mesh: &TriMesh) -> Result<MeshQuery> {
        mesh.validate()?;
        let (lo, hi) = mesh
            .bounds()
            .ok_or_else(|| Error::invalid("mesh query", "the mesh has no vertices"))?;
        let scale = (hi - lo).norm().max(f64::MIN_POSITIVE);
        let min_area2 = (scale * 1e-12).powi(4);
        let mut tris = Vec::new();
        let mut tri_map = Vec::new();
        for (i, [a, b, c]) in mesh.triangle_corners().enumerate() {
            let t = mesh.triangles[i];
            if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] {
                continue;
            }
            if (b - a).cross(&(c - a)).norm_squared() <= min_area2 {
                continue;
            }
            tris.push(t);
            tri_map.push(i);
        }
        if tris.is_empty() {
            return Err(Error::invalid(
                "mesh query",
                "the mesh has no non-degenerate triangle",
            ));
        }
        let shape = ParryMesh::new(mesh.vertices.clone(), tris)
            .map_err(|e| Error::invalid("mesh query", format!("cannot build the BVH: {e:?}")))?;
        Ok(MeshQuery {
            mesh: mesh.clone(),
            shape,
            tri_map,
            scale,
            bounds: (lo, hi),
        })
    }

    /// The mesh being queried.
    pub fn mesh(&self) -> &TriMesh {
        &self.mesh
    }

    /// Closest point of the surface to `p` (`t` is the distance).
    pub fn closest_point(&self, p: &Point3<f64>) -> SurfaceHit {
        let (proj, feature) = self.shape.project_local_point_and_get_feature(p);
        let k = match feature {
            parry3d_f64::shape::FeatureId::Face(k) => k as usize,
            _ => 0,
        };
        // parry may report back faces as k + n.
        let k = k % self.tri_map.len();
        SurfaceHit {
            point: proj.point,
            t: (proj.point - p).norm(),
            triangle: self.tri_map[k],
        }
    }

    /// Distance from `p` to the surface (m).
    pub fn distance(&self, p: &Point3<f64>) -> f64 {
        self.closest_point(p).t
    }

    /// Distance from `p` to the surface, capped at `cap` (m): equal to
    /// `distance(p).min(cap)`, but faster for a stream of nearby points.
    /// `hint` is the parry triangle that was closest to the previous point
    /// of the stream (any valid index to start, updated here): its
    /// distance bounds the search, so the bounding-volume traversal visits
    /// only the nodes that could hold a closer triangle.
    pub fn distance_near(&self, p: &Point3<f64>, hint: &mut u32, cap: f64) -> f64 {
        use parry3d_f64::query::PointQueryWithLocation;
        let first = (*hint as usize) < self.tri_map.len();
        let bound = if first {
            let t = self.shape.triangle(*hint);
            (t.project_local_point(p, false).point - p).norm()
        } else {
            f64::MAX
        };
        // A hair above the bound so that the hinted triangle itself passes.
        let bound = bound.min(cap) * (1.0 + 1e-9) + 1e-15;
        match self
            .shape
            .project_local_point_and_get_location_with_max_dist(p, false, bound)
        {
            Some((proj, (tri, _))) => {
                *hint = tri;
                (proj.point - p).norm().min(cap)
            }
            None => cap,
        }
    }

    /// Is `p` farther than `r` from the surface? Equal to
    /// `distance(p) > r`, but the search stops at the triangles within
    /// about `2 r` of `p`.
    pub fn farther_than(&self, p: &Point3<f64>, r: f64) -> bool {
        if r.is_nan() || r <= 0.0 {
            return self.distance(p) > r;
        }
        // The capped distance is exact below the cap, and the cap is past r.
        let mut hint = u32::MAX;
        self.distance_near(p, &mut hint, 2.0 * r) > r
    }

    /// Every crossing of the ray `origin + t dir`, `0 <= t <= max_t`, with
    /// the surface, sorted by `t`; crossings at the same `t` (a ray through
    /// an edge or a vertex) are reported once.
    pub fn ray_hits(
        &self,
        origin: &Point3<f64>,
        dir: &Vector3<f64>,
        max_t: f64,
    ) -> Vec<SurfaceHit> {
        let ray = SlabRay::new(origin, dir, max_t);
        let mut hits: Vec<SurfaceHit> = Vec::new();
        let bvh = self.shape.bvh();
        for leaf in bvh.leaves(|node| ray.hits_box(&node.mins(), &node.maxs())) {
            let k = leaf as usize;
            let Some(&orig) = self.tri_map.get(k) else {
                continue;
            };
            let [a, b, c] = self.mesh.corners(orig);
            if let Some(t) = ray_triangle(origin, dir, &a, &b, &c) {
                if (0.0..=max_t).contains(&t) {
                    hits.push(SurfaceHit {
                        point: origin + dir * t,
                        t,
                        triangle: orig,
                    });
                }
            }
        }
        hits.sort_by(|x, y| x.t.total_cmp(&y.t).then(x.triangle.cmp(&y.triangle)));
        let eps = 1e-12 * self.scale / dir.norm().max(f64::MIN_POSITIVE);
        hits.dedup_by(|later, earlier| (later.t - earlier.t).abs() <= eps);
        hits
    }

    /// Crossings of the segment `a`-`b` with the surface (`t` in 0..1).
    pub fn segment_hits(&self, a: &Point3<f64>, b: &Point3<f64>) -> Vec<SurfaceHit> {
        self.ray_hits(a, &(b - a), 1.0)
    }

    /// Does the segment `a`-`b` cross or touch the surface?
    pub fn segment_intersects(&self, a: &Point3<f64>, b: &Point3<f64>) -> bool {
        !self.segment_hits(a, b).is_empty() || self.contains(a)
    }

    /// Length of the part of segment `a`-`b` inside the closed surface (m):
    /// how deep a muscle path segment passes through a bone.
    pub fn segment_length_inside(&self, a: &Point3<f64>, b: &Point3<f64>) -> f64 {
        // A segment clear of the bounding box (by a margin far above
        // rounding) neither crosses the surface nor has a piece inside.
        if self.segment_misses_bounds(a, b) {
            return 0.0;
        }
        let len = (b - a).norm();
        let hits = self.segment_hits(a, b);
        // No crossing lies inside a piece, so the piece from an end outside
        // the bounding box to its first crossing is outside with that end:
        // only the other pieces cast rays.
        let (lo, hi) = &self.bounds;
        let outside_box = |p: &Point3<f64>| (0..3).any(|k| p[k] < lo[k] || p[k] > hi[k]);
        let (a_out, b_out) = (outside_box(a), outside_box(b));
        let last = hits.len();
        // The pieces between consecutive crossings (and the ends).
        let mut inside = 0.0;
        let mut from = 0.0;
        for (piece, to) in hits.iter().map(|h| h.t).chain([1.0]).enumerate() {
            let by_its_end = (piece == 0 && a_out) || (piece == last && b_out);
            if to > from && !by_its_end {
                let mid = a + (b - a) * (0.5 * (from + to));
                if self.contains(&mid) {
                    inside += (to - from) * len;
                }
            }
            from = to;
        }
        inside
    }

    /// Is the box of segment `a`-`b` apart from the mesh's bounding box by
    /// more than a millionth of the mesh's size along some axis?
    fn segment_misses_bounds(&self, a: &Point3<f64>, b: &Point3<f64>) -> bool {
        let (lo, hi) = &self.bounds;
        let margin = 1e-6 * self.scale;
        (0..3).any(|k| a[k].max(b[k]) < lo[k] - margin || a[k].min(b[k]) > hi[k] + margin)
    }

    /// Bounding box of the mesh's vertices (the mesh's own
    /// [`TriMesh::bounds`], computed once).
    pub fn bounds(&self) -> (Point3<f64>, Point3<f64>) {
        self.bounds
    }

    /// Is `p` inside the closed surface? Majority vote of crossing parity
    /// along three rays (independent of triangle winding).
    pub fn contains(&self, p: &Point3<f64>) -> bool {
        // Outside the bounding box: outside, without casting a ray.
        let (lo, hi) = &self.bounds;
        if (0..3).any(|k| p[k] < lo[k] || p[k] > hi[k]) {
            return false;
        }
        let odd = |d: &[f64; 3]| {
            let dir = Vector3::new(d[0], d[1], d[2]);
            self.ray_hits(p, &dir, f64::MAX).len() % 2 == 1
        };
        // Two rays that agree decide the majority; the third breaks a tie.
        match (odd(&RAYS[0]), odd(&RAYS[1])) {
            (first, second) if first == second => first,
            _ => odd(&RAYS[2]),
        }
    }

    /// Distance to the surface, negative inside (m).
    pub fn signed_distance(&self, p: &Point3<f64>) -> f64 {
        let d = self.distance(p);
        if self.contains(p) {
            -d
        } else {
            d
        }
    }
}

/// A ray `origin + t dir`, `0 <= t <= max_t`, with its reciprocal
/// direction computed once for the bounding-box tests of a traversal.
struct SlabRay {
    origin: Point3<f64>,
    /// `1 / dir[k]`, `None` where `dir[k]` is zero.
    inv_dir: [Option<f64>; 3],
    max_t: f64,
}

impl SlabRay {
    fn new(origin: &Point3<f64>, dir: &Vector3<f64>, max_t: f64) -> SlabRay {
        SlabRay {
            origin: *origin,
            inv_dir: [0, 1, 2].map(|k| (dir[k] != 0.0).then(|| 1.0 / dir[k])),
            max_t,
        }
    }

    /// Does the ray meet the box `mins`-`maxs`? The slab test of parry's
    /// solid `Aabb` ray cast, with the reciprocal direction computed once
    /// per ray instead of a division per box.
    fn hits_box(&self, mins: &Point3<f64>, maxs: &Point3<f64>) -> bool {
        let (mut tmin, mut tmax) = (0.0_f64, self.max_t);
        for k in 0..3 {
            let o = self.origin[k];
            let Some(inv) = self.inv_dir[k] else {
                if o < mins[k] || o > maxs[k] {
                    return false;
                }
                continue;
            };
            let (mut near, mut far) = ((mins[k] - o) * inv, (maxs[k] - o) * inv);
            if near > far {
                std::mem::swap(&mut near, &mut far);
            }
            // Plain comparisons: no NaN arises (finite bounds and
            // reciprocals), and the sign of a zero bound compares equal.
            if near > tmin {
                tmin = near;
            }
            if far < tmax {
                tmax = far;
            }
            if tmin > tmax {
                return false;
            }
        }
        tmin < f64::MAX
    }
}

/// Ray-triangle intersection parameter (two-sided), `None` if parallel or
/// missed. Barycentric bounds include the edges.
fn ray_triangle(
    o: &Point3<f64>,
    d: &Vector3<f64>,
    a: &Point3<f64>,
    b: &Point3<f64>,
    c: &Point3<f64>,
) -> Option<f64> {
    let e1 = b - a;
    let e2 = c - a;
    let p = d.cross(&e2);
    let det = e1.dot(&p);
    let scale = e1.norm() * e2.norm() * d.norm();
    if det.abs() <= 1e-14 * scale {
        return None;
    }
    let inv = 1.0 / det;
    let s = o - a;
    let u = s.dot(&p) * inv;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s.cross(&e1);
    let v = d.dot(&q) * inv;
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    Some(e2.dot(&q) * inv)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit_box() -> TriMesh {
        let v: Vec<Point3<f64>> = (0..8)
            .map(|i| Point3::new((i & 1) as f64, ((i >> 1) & 1) as f64, ((i >> 2) & 1) as f64))
            .collect();
        let quads = [
            [0, 2, 3, 1],
            [4, 5, 7, 6],
            [0, 1, 5, 4],
            [2, 6, 7, 3],
            [0, 4, 6, 2],
            [1, 3, 7, 5],
        ];
        let mut t = Vec::new();
        for q in quads {
            t.push([q[0], q[1], q[2]]);
            t.push([q[0], q[2], q[3]]);
        }
        TriMesh::new(v, t).unwrap()
    }

    #[test]
    fn hinted_distance_is_the_capped_distance() {
        // A stream of points around and inside the box, with stale and
        // out-of-range hints: always distance(p).min(cap).
        let q = MeshQuery::new(&unit_box()).unwrap();
        let mut hint = u32::MAX;
        for i in 0..400 {
            let t = i as f64 * 0.37;
            let p = Point3::new(
                0.5 + 1.3 * t.sin(),
                0.5 + 0.9 * (1.7 * t).cos(),
                (0.3 * t).sin(),
            );
            for cap in [0.05, 0.4, 10.0] {
                let want = q.distance(&p).min(cap);
                let got = q.distance_near(&p, &mut hint, cap);
                assert!(
                    (got - want).abs() < 1e-12,
                    "{p:?} cap {cap}: {got} vs {want}"
                );
            }
        }
    }

    #[test]
    fn farther_than_is_the_distance_compared() {
        // Points around and inside the box, radii below, at and above
        // their distances.
        let q = MeshQuery::new(&unit_box()).unwrap();
        for i in 0..300 {
            let t = i as f64 * 0.41;
            let p = Point3::new(
                0.5 + 0.9 * t.sin(),
                0.5 + 0.7 * (1.3 * t).cos(),
                0.2 * t.cos(),
            );
            let d = q.distance(&p);
            for r in [0.0, 0.5 * d, d, d * (1.0 + 1e-15), 1.5 * d, 0.01, 0.3, 2.0] {
                assert_eq!(q.farther_than(&p, r), d > r, "{p:?} r {r} d {d}");
            }
        }
    }

    #[test]
    fn box_queries() {
        let mut m = unit_box();
        // Flip some triangles and add a degenerate one: answers must not change.
        m.triangles[3].swap(1, 2);
        m.triangles[8].swap(0, 1);
        m.triangles.push([0, 0, 1]);
        let q = MeshQuery::new(&m).unwrap();
        assert!(q.contains(&Point3::new(0.5, 0.5, 0.5)));
        assert!(q.contains(&Point3::new(0.01, 0.99, 0.5)));
        assert!(!q.contains(&Point3::new(1.5, 0.5, 0.5)));
        assert!(!q.contains(&Point3::new(-0.01, 0.5, 0.5)));
        let h = q.closest_point(&Point3::new(2.0, 0.5, 0.25));
        assert!((h.point - Point3::new(1.0, 0.5, 0.25)).norm() < 1e-12);
        assert!((h.t - 1.0).abs() < 1e-12);
        // The hit triangle lies on the x = 1 face.
        let [a, b, c] = m.corners(h.triangle);
        assert!(a.x == 1.0 && b.x == 1.0 && c.x == 1.0);
        assert!((q.signed_distance(&Point3::new(0.5, 0.5, 0.2)) + 0.2).abs() < 1e-12);
        // Segment through the box: two crossings, 1 m inside.
        let (a, b) = (Point3::new(-1.0, 0.3, 0.6), Point3::new(2.0, 0.3, 0.6));
        let hits = q.segment_hits(&a, &b);
        assert_eq!(hits.len(), 2);
        assert!((hits[0].t - 1.0 / 3.0).abs() < 1e-12);
        assert!((q.segment_length_inside(&a, &b) - 1.0).abs() < 1e-12);
        // One end inside (one crossing), both inside (none), both outside
        // and missing the box.
        let inside =
            |a: [f64; 3], b: [f64; 3]| q.segment_length_inside(&Point3::from(a), &Point3::from(b));
        assert!((inside([0.5, 0.5, 0.5], [3.0, 0.5, 0.5]) - 0.5).abs() < 1e-12);
        assert!((inside([3.0, 0.4, 0.5], [0.25, 0.4, 0.5]) - 0.75).abs() < 1e-12);
        assert!((inside([0.2, 0.5, 0.5], [0.8, 0.5, 0.5]) - 0.6).abs() < 1e-12);
        assert_eq!(inside([-1.0, 2.0, 0.5], [2.0, 2.0, 0.5]), 0.0);
        assert!(!q.segment_intersects(&Point3::new(-1.0, 2.0, 0.0), &Point3::new(2.0, 2.0, 0.0)));
        // Through an edge (two triangles share it): counted once.
        let hits = q.ray_hits(
            &Point3::new(0.5, -1.0, -1.0),
            &Vector3::new(0.0, 1.0, 1.0),
            10.0,
        );
        assert_eq!(hits.len(), 2, "{hits:?}");
    }
}
