//! Non-manifold edges split, so that a closed surface is a 2-manifold.
//!
//! Surfaces extracted from voxels (surface nets, marching cubes) have an
//! edge shared by four triangles where two voxels of a label touch only
//! along that edge (the ambiguous saddle). Here the triangles around such
//! an edge are ordered by their angle about it and paired with a
//! neighbour of the opposite winding (so each pair joins consistently
//! across the edge), and every vertex whose triangles then fall into
//! several fans is duplicated, one copy per fan. The surface keeps its
//! shape and orientation; where two pieces touched along the edge, they
//! now touch at coincident vertices, each closed on its own side.

use super::TriMesh;
use nalgebra::Vector3;
use std::collections::BTreeMap;

/// Pairs of triangles joined across an edge.
type Pairing = Vec<(usize, usize)>;

/// Triangles around each edge `[lo, hi]`, with whether they run lo -> hi.
fn edge_map(mesh: &TriMesh) -> BTreeMap<[u32; 2], Vec<(usize, bool)>> {
    let mut edges: BTreeMap<[u32; 2], Vec<(usize, bool)>> = BTreeMap::new();
    for (i, t) in mesh.triangles.iter().enumerate() {
        for j in 0..3 {
            let (a, b) = (t[j], t[(j + 1) % 3]);
            if a != b {
                edges
                    .entry([a.min(b), a.max(b)])
                    .or_default()
                    .push((i, a < b));
            }
        }
    }
    edges
}

/// The ways to pair the triangles of a non-manifold edge across it, best
/// first: ordered by the angle of their third vertex about the edge, each
/// paired with the next one when the sector between them is inside the
/// solid (its outward normal points away from the sector), so that each
/// piece closes on its own side; then, where the normals are unclear (a
/// fold of coincident triangles), the two pairings of neighbours of
/// opposite winding. Every pair has opposite windings.
fn pairings(mesh: &TriMesh, e: [u32; 2], tris: &[(usize, bool)]) -> Vec<Pairing> {
    let (pa, pb) = (mesh.vertices[e[0] as usize], mesh.vertices[e[1] as usize]);
    let Some(axis) = (pb - pa).try_normalize(0.0) else {
        return Vec::new();
    };
    if tris.len() % 2 != 0 {
        return Vec::new();
    }
    let u = axis
        .cross(&Vector3::x())
        .try_normalize(1e-6)
        .unwrap_or_else(|| axis.cross(&Vector3::y()).normalize());
    let v = axis.cross(&u);
    // (angle, triangle, winding lo -> hi, solid towards increasing angle)
    let mut around: Vec<(f64, usize, bool, bool)> = tris
        .iter()
        .map(|&(i, fwd)| {
            let c = mesh.triangles[i]
                .iter()
                .find(|&&k| k != e[0] && k != e[1])
                .copied()
                .unwrap_or(e[0]);
            let w = mesh.vertices[c as usize] - pa;
            let (x, y) = (w.dot(&u), w.dot(&v));
            let increasing = axis.cross(&(u * x + v * y));
            let solid_ahead = mesh.triangle_normal(i).dot(&increasing) < 0.0;
            (y.atan2(x), i, fwd, solid_ahead)
        })
        .collect();
    around.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    let n = around.len();
    let preferred = usize::from(!around[0].3);
    let mut out: Vec<Pairing> = Vec::new();
    for (shift, strict) in [
        (preferred, true),
        (preferred, false),
        (1 - preferred, false),
    ] {
        let pairs: Vec<(usize, usize)> = (0..n / 2)
            .map(|k| (around[(2 * k + shift) % n], around[(2 * k + 1 + shift) % n]))
            .filter(|(a, b)| a.2 != b.2 && (!strict || (a.3 && !b.3)))
            .map(|(a, b)| (a.1, b.1))
            .collect();
        if pairs.len() == n / 2 && !out.contains(&pairs) {
            out.push(pairs);
        }
    }
    out
}

/// Union-find root.
fn root(parent: &mut [usize], mut x: usize) -> usize {
    while parent[x] != x {
        parent[x] = parent[parent[x]];
        x = parent[x];
    }
    x
}

/// `mesh` with every non-manifold edge split (module documentation), and
/// how many edges were split. A pairing that leaves its edge shared by
/// more than two triangles (the pieces meet elsewhere around a vertex) is
/// replaced by the next one; edges with no pairing that works are left as
/// they are (the caller's edge check reports them).
pub fn split_non_manifold_edges(mesh: &TriMesh) -> (TriMesh, usize) {
    let edges = edge_map(mesh);
    let candidates: BTreeMap<[u32; 2], Vec<Pairing>> = edges
        .iter()
        .filter(|(_, t)| t.len() > 2)
        .map(|(e, t)| (*e, pairings(mesh, *e, t)))
        .filter(|(_, p)| !p.is_empty())
        .collect();
    if candidates.is_empty() {
        return (mesh.clone(), 0);
    }
    let mut choice: BTreeMap<[u32; 2], usize> = candidates.keys().map(|e| (*e, 0)).collect();
    let mut best = (mesh.clone(), usize::MAX);
    for _ in 0..3 {
        let out = split_with(mesh, &edges, &candidates, &choice);
        let left: Vec<[u32; 2]> = candidates
            .keys()
            .filter(|e| still_shared(&out, mesh, e))
            .copied()
            .collect();
        if left.len() < best.1 {
            best = (out, left.len());
        }
        if left.is_empty() {
            break;
        }
        for e in left {
            if let Some(c) = choice.get_mut(&e) {
                *c = (*c + 1) % candidates[&e].len();
            }
        }
    }
    let split = candidates.len() - best.1;
    (best.0, split)
}

/// Whether the original edge `e` of `mesh` is still shared by more than
/// two triangles in `out` (under any copy of its vertices).
fn still_shared(out: &TriMesh, mesh: &TriMesh, e: &[u32; 2]) -> bool {
    let (pa, pb) = (mesh.vertices[e[0] as usize], mesh.vertices[e[1] as usize]);
    let mut uses: BTreeMap<[u32; 2], usize> = BTreeMap::new();
    for t in &out.triangles {
        for j in 0..3 {
            let (a, b) = (t[j], t[(j + 1) % 3]);
            let (qa, qb) = (out.vertices[a as usize], out.vertices[b as usize]);
            if (qa == pa && qb == pb) || (qa == pb && qb == pa) {
                *uses.entry([a.min(b), a.max(b)]).or_default() += 1;
            }
        }
    }
    uses.values().any(|&n| n > 2)
}

/// The split for one choice of pairing per non-manifold edge.
fn split_with(
    mesh: &TriMesh,
    edges: &BTreeMap<[u32; 2], Vec<(usize, bool)>>,
    candidates: &BTreeMap<[u32; 2], Vec<Pairing>>,
    choice: &BTreeMap<[u32; 2], usize>,
) -> TriMesh {
    // Which triangles join across each edge: both of a manifold edge's,
    // the chosen pairs of a non-manifold one.
    let mut joins: Vec<([u32; 2], usize, usize)> = Vec::new();
    for (e, tris) in edges {
        if let [a, b] = tris[..] {
            joins.push((*e, a.0, b.0));
        } else if let (Some(c), Some(k)) = (candidates.get(e), choice.get(e)) {
            joins.extend(c[*k].iter().map(|(a, b)| (*e, *a, *b)));
        }
    }
    // Per vertex, its corners (triangle, slot) grouped into fans: two
    // corners are in one fan when their triangles join across an edge of
    // that vertex.
    let corner = |t: usize, k: u32| -> Option<usize> {
        mesh.triangles[t]
            .iter()
            .position(|&x| x == k)
            .map(|s| 3 * t + s)
    };
    let mut parent: Vec<usize> = (0..3 * mesh.triangles.len()).collect();
    for (e, a, b) in &joins {
        for &k in e {
            if let (Some(ca), Some(cb)) = (corner(*a, k), corner(*b, k)) {
                let (ra, rb) = (root(&mut parent, ca), root(&mut parent, cb));
                parent[ra] = rb;
            }
        }
    }
    // One vertex per (vertex, fan): the first fan keeps the index.
    let mut out = mesh.clone();
    let mut fan_vertex: BTreeMap<(u32, usize), u32> = BTreeMap::new();
    let mut first_fan: BTreeMap<u32, usize> = BTreeMap::new();
    for t in 0..mesh.triangles.len() {
        for s in 0..3 {
            let k = mesh.triangles[t][s];
            let fan = root(&mut parent, 3 * t + s);
            let f0 = *first_fan.entry(k).or_insert(fan);
            let id = if fan == f0 {
                k
            } else {
                *fan_vertex.entry((k, fan)).or_insert_with(|| {
                    out.vertices.push(mesh.vertices[k as usize]);
                    (out.vertices.len() - 1) as u32
                })
            };
            out.triangles[t][s] = id;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;

    /// The outward surface of a set of unit voxels (shared corner
    /// vertices), as surface extraction gives it.
    fn voxels(cells: &[[i32; 3]]) -> TriMesh {
        let filled = |c: [i32; 3]| cells.contains(&c);
        let mut ids: BTreeMap<[i32; 3], u32> = BTreeMap::new();
        let mut v = Vec::new();
        let mut t = Vec::new();
        let mut vid = |p: [i32; 3], v: &mut Vec<Point3<f64>>| {
            *ids.entry(p).or_insert_with(|| {
                v.push(Point3::new(p[0] as f64, p[1] as f64, p[2] as f64));
                (v.len() - 1) as u32
            })
        };
        for c in cells {
            for axis in 0..3 {
                for s in [0, 1] {
                    let mut n = *c;
                    n[axis] += if s == 1 { 1 } else { -1 };
                    if filled(n) {
                        continue;
                    }
                    let (u, w) = ((axis + 1) % 3, (axis + 2) % 3);
                    let q: Vec<u32> = [(0, 0), (1, 0), (1, 1), (0, 1)]
                        .iter()
                        .map(|&(du, dw)| {
                            let mut p = *c;
                            p[axis] += s;
                            p[u] += du;
                            p[w] += dw;
                            vid(p, &mut v)
                        })
                        .collect();
                    if s == 1 {
                        t.push([q[0], q[1], q[2]]);
                        t.push([q[0], q[2], q[3]]);
                    } else {
                        t.push([q[0], q[2], q[1]]);
                        t.push([q[0], q[3], q[2]]);
                    }
                }
            }
        }
        TriMesh {
            vertices: v,
            triangles: t,
        }
    }

    #[test]
    fn two_voxels_touching_along_an_edge_become_two_closed_pieces() {
        let m = voxels(&[[0, 0, 0], [1, 1, 0]]);
        let rep = m.edge_report();
        assert_eq!(rep.non_manifold_edges.len(), 1, "{rep:?}");
        assert!((m.signed_volume() - 2.0).abs() < 1e-12);
        let (s, n) = split_non_manifold_edges(&m);
        assert_eq!(n, 1);
        let rep = s.edge_report();
        assert!(rep.is_watertight(), "{rep:?}");
        assert!(rep.inconsistent_edges.is_empty());
        // two vertices duplicated, the shape and volume unchanged
        assert_eq!(s.vertices.len(), m.vertices.len() + 2);
        assert!((s.signed_volume() - 2.0).abs() < 1e-12);
        // a manifold mesh comes back as it is
        let one = voxels(&[[0, 0, 0], [1, 0, 0]]);
        assert_eq!(split_non_manifold_edges(&one), (one.clone(), 0));
    }
}
