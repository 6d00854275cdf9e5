//! Basic mesh geometry: transforms, merging, area, enclosed volume,
//! centroids, principal axes, vertex normals, topology (edge-manifold and
//! watertight checks), consistent orientation and vertex welding.
//!
//! Everything here is plain computation on [`TriMesh`]; methods are added
//! to `TriMesh` itself. Meshes read from files may have flipped triangles:
//! the mass properties use the winding as it is (call
//! [`TriMesh::orient_consistently`] first when outward normals matter).

use super::TriMesh;
use crate::error::{Error, Result};
use nalgebra::{Affine3, Isometry3, Matrix3, Point3, SymmetricEigen, Vector3};
use std::collections::{BTreeMap, HashMap};

/// Principal axes of a mesh surface or a point set.
#[derive(Debug, Clone, PartialEq)]
pub struct PrincipalAxes {
    /// Centre (area centroid for a surface, mean for points) (m).
    pub centre: Point3<f64>,
    /// Unit axes as columns, sorted by decreasing variance, right-handed.
    pub axes: Matrix3<f64>,
    /// Variances along the axes (m^2), decreasing.
    pub variances: Vector3<f64>,
}

/// Edge topology of a mesh, from [`TriMesh::edge_report`]. Edges are
/// vertex-index pairs `[lo, hi]`, sorted.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct EdgeReport {
    /// Number of distinct edges.
    pub edges: usize,
    /// Edges used by exactly one triangle (holes).
    pub boundary_edges: Vec<[u32; 2]>,
    /// Edges used by three or more triangles, with their use count.
    pub non_manifold_edges: Vec<([u32; 2], usize)>,
    /// Manifold edges whose two triangles traverse them in the same
    /// direction (inconsistent winding across the edge).
    pub inconsistent_edges: Vec<[u32; 2]>,
    /// Triangles with a repeated vertex index.
    pub degenerate_triangles: Vec<usize>,
}

impl EdgeReport {
    /// Every edge has exactly two triangles (and no degenerate triangles).
    pub fn is_watertight(&self) -> bool {
        self.boundary_edges.is_empty()
            && self.non_manifold_edges.is_empty()
            && self.degenerate_triangles.is_empty()
    }
}

/// Principal axes of a point set (covariance of the points).
pub fn point_principal_axes(points: &[Point3<f64>]) -> Option<PrincipalAxes> {
    if points.is_empty() {
        return None;
    }
    let n = points.len() as f64;
    let c = points.iter().fold(Vector3::zeros(), |s, p| s + p.coords) / n;
    let mut cov = Matrix3::zeros();
    for p in points {
        let d = p.coords - c;
        cov += d * d.transpose();
    }
    Some(axes_from_cov(Point3::from(c), cov / n))
}

fn axes_from_cov(centre: Point3<f64>, cov: Matrix3<f64>) -> PrincipalAxes {
    let eig = SymmetricEigen::new(cov);
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    let mut axes = Matrix3::zeros();
    let mut var = Vector3::zeros();
    for (k, &i) in order.iter().enumerate() {
        let mut v: Vector3<f64> = eig.eigenvectors.column(i).into_owned();
        // Deterministic sign: largest-magnitude component positive.
        let imax = v.iamax();
        if v[imax] < 0.0 {
            v = -v;
        }
        axes.set_column(k, &v);
        var[k] = eig.eigenvalues[i].max(0.0);
    }
    if axes.determinant() < 0.0 {
        let c2: Vector3<f64> = -axes.column(2).into_owned();
        axes.set_column(2, &c2);
    }
    PrincipalAxes {
        centre,
        axes,
        variances: var,
    }
}

impl TriMesh {
    /// The mesh moved by a rigid transform.
    pub fn transformed(&self, iso: &Isometry3<f64>) -> TriMesh {
        TriMesh {
            vertices: self.vertices.iter().map(|p| iso * p).collect(),
            triangles: self.triangles.clone(),
        }
    }

    /// The mesh under a general affine map. If the map mirrors
    /// (negative determinant) the triangles are re-wound so that outward
    /// normals stay outward.
    pub fn affine(&self, a: &Affine3<f64>) -> TriMesh {
        let m = a.matrix().fixed_view::<3, 3>(0, 0).into_owned();
        let flip = m.determinant() < 0.0;
        TriMesh {
            vertices: self.vertices.iter().map(|p| a * p).collect(),
            triangles: self
                .triangles
                .iter()
                .map(|t| if flip { [t[0], t[2], t[1]] } else { *t })
                .collect(),
        }
    }

    /// The mesh scaled per axis about the origin (OpenSim `scale_factors`).
    pub fn scaled(&self, s: &Vector3<f64>) -> TriMesh {
        let flip = s.x * s.y * s.z < 0.0;
        TriMesh {
            vertices: self
                .vertices
                .iter()
                .map(|p| Point3::from(p.coords.component_mul(s)))
                .collect(),
            triangles: self
                .triangles
                .iter()
                .map(|t| if flip { [t[0], t[2], t[1]] } else { *t })
                .collect(),
        }
    }

    /// All meshes in one (vertices concatenated, indices offset).
    pub fn merge(meshes: &[&TriMesh]) -> Result<TriMesh> {
        let mut out = TriMesh::default();
        for m in meshes {
            let base = u32::try_from(out.vertices.len())
                .ok()
                .filter(|b| b.checked_add(m.vertices.len() as u32).is_some())
                .ok_or_else(|| Error::invalid("mesh merge", "more than 2^32 vertices"))?;
            out.vertices.extend_from_slice(&m.vertices);
            out.triangles
                .extend(m.triangles.iter().map(|t| t.map(|k| k + base)));
        }
        Ok(out)
    }

    /// Total surface area (m^2).
    pub fn area(&self) -> f64 {
        self.triangle_corners()
            .map(|[a, b, c]| 0.5 * (b - a).cross(&(c - a)).norm())
            .sum()
    }

    /// Signed enclosed volume (m^3) by the divergence theorem: positive for
    /// a closed mesh with outward normals, negative if wound inward;
    /// meaningless for an open mesh.
    pub fn signed_volume(&self) -> f64 {
        self.triangle_corners()
            .map(|[a, b, c]| a.coords.dot(&b.coords.cross(&c.coords)) / 6.0)
            .sum()
    }

    /// Area-weighted centroid of the surface; `None` if the area is zero.
    pub fn area_centroid(&self) -> Option<Point3<f64>> {
        let mut s = Vector3::zeros();
        let mut total = 0.0;
        for [a, b, c] in self.triangle_corners() {
            let w = 0.5 * (b - a).cross(&(c - a)).norm();
            s += w * (a.coords + b.coords + c.coords) / 3.0;
            total += w;
        }
        (total > 0.0).then(|| Point3::from(s / total))
    }

    /// Centroid of the enclosed solid (closed, consistently wound mesh);
    /// `None` if the enclosed volume is zero.
    pub fn volume_centroid(&self) -> Option<Point3<f64>> {
        let mut s = Vector3::zeros();
        let mut total = 0.0;
        for [a, b, c] in self.triangle_corners() {
            let v = a.coords.dot(&b.coords.cross(&c.coords)) / 6.0;
            s += v * (a.coords + b.coords + c.coords) / 4.0;
            total += v;
        }
        (total.abs() > 0.0).then(|| Point3::from(s / total))
    }

    /// Principal axes of the surface (area-weighted covariance of a uniform
    /// density on the triangles, independent of the tessellation density).
    pub fn principal_axes(&self) -> Option<PrincipalAxes> {
        let c = self.area_centroid()?;
        let mut m = Matrix3::zeros();
        let mut total = 0.0;
        for [a, b, cc] in self.triangle_corners() {
            let area = 0.5 * (b - a).cross(&(cc - a)).norm();
            let (a, b, cc) = (a - c, b - c, cc - c);
            let s = a + b + cc;
            m += area / 12.0
                * (a * a.transpose() + b * b.transpose() + cc * cc.transpose() + s * s.transpose());
            total += area;
        }
        Some(axes_from_cov(c, m / total))
    }

    /// Inertia tensor of the enclosed solid about its volume centroid for a
    /// unit density (kg m^2 per kg/m^3), by signed tetrahedra. Needs a
    /// closed, outward-wound mesh.
    pub fn solid_inertia(&self) -> Option<Matrix3<f64>> {
        let c = self.volume_centroid()?;
        let mut cov = Matrix3::zeros();
        for [a, b, d] in self.triangle_corners() {
            let (a, b, d) = (a - c, b - c, d - c);
            let v = a.dot(&b.cross(&d)) / 6.0;
            // Second moment of the tetrahedron (0, a, b, d).
            let s = a + b + d;
            cov += v / 20.0
                * (a * a.transpose() + b * b.transpose() + d * d.transpose() + s * s.transpose());
        }
        Some(Matrix3::identity() * cov.trace() - cov)
    }

    /// Unit vertex normals: area-weighted average of the adjacent triangle
    /// normals (zero for unreferenced vertices).
    pub fn vertex_normals(&self) -> Vec<Vector3<f64>> {
        let mut n = vec![Vector3::zeros(); self.vertices.len()];
        for (t, [a, b, c]) in self.triangles.iter().zip(self.triangle_corners()) {
            let w = (b - a).cross(&(c - a));
            for &k in t {
                n[k as usize] += w;
            }
        }
        n.into_iter()
            .map(|v| v.try_normalize(0.0).unwrap_or_else(Vector3::zeros))
            .collect()
    }

    /// Edge topology: boundary, non-manifold and inconsistently wound edges.
    pub fn edge_report(&self) -> EdgeReport {
        // (lo, hi) -> (uses, uses in lo->hi direction)
        let mut edges: BTreeMap<[u32; 2], (usize, usize)> = BTreeMap::new();
        let mut rep = EdgeReport::default();
        for (i, t) in self.triangles.iter().enumerate() {
            if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] {
                rep.degenerate_triangles.push(i);
                continue;
            }
            for j in 0..3 {
                let (a, b) = (t[j], t[(j + 1) % 3]);
                let e = edges.entry([a.min(b), a.max(b)]).or_default();
                e.0 += 1;
                if a < b {
                    e.1 += 1;
                }
            }
        }
        rep.edges = edges.len();
        for (e, (uses, fwd)) in edges {
            match uses {
                1 => rep.boundary_edges.push(e),
                2 if fwd != 1 => rep.inconsistent_edges.push(e),
                2 => {}
                _ => rep.non_manifold_edges.push((e, uses)),
            }
        }
        rep
    }

    /// Refuse a mesh with edges shared by more than two triangles, with an
    /// error naming `context` and the first offending edges.
    fn require_edge_manifold(&self, context: &str) -> Result<()> {
        let rep = self.edge_report();
        if rep.non_manifold_edges.is_empty() {
            return Ok(());
        }
        let shown: Vec<String> = rep
            .non_manifold_edges
            .iter()
            .take(5)
            .map(|(e, n)| format!("{}-{} ({n} triangles)", e[0], e[1]))
            .collect();
        Err(Error::invalid(
            context,
            format!(
                "non-manifold mesh: {} edge(s) shared by more than two triangles, e.g. vertices {}",
                rep.non_manifold_edges.len(),
                shown.join(", ")
            ),
        ))
    }

    /// Refuse a mesh that is not closed (boundary or non-manifold edges).
    pub fn require_watertight(&self, context: &str) -> Result<()> {
        self.require_edge_manifold(context)?;
        let rep = self.edge_report();
        if !rep.boundary_edges.is_empty() {
            let e = rep.boundary_edges[0];
            return Err(Error::invalid(
                context,
                format!(
                    "mesh is not closed: {} boundary edge(s), e.g. vertices {}-{} (try welding \
                     duplicate vertices first)",
                    rep.boundary_edges.len(),
                    e[0],
                    e[1]
                ),
            ));
        }
        Ok(())
    }

    /// Merge vertices closer than `tol` (m), keeping the first of each
    /// cluster (in index order); triangles that collapse are dropped and
    /// unreferenced vertices removed. Returns the new mesh and, for each
    /// old vertex, its new index (`u32::MAX` if it was dropped).
    pub fn welded(&self, tol: f64) -> (TriMesh, Vec<u32>) {
        let tol = tol.max(0.0);
        let cell = if tol > 0.0 { tol } else { 1.0 };
        let key = |p: &Point3<f64>| -> [i64; 3] {
            if tol > 0.0 {
                [p.x, p.y, p.z].map(|c| (c / cell).floor() as i64)
            } else {
                [p.x, p.y, p.z].map(|c| (c + 0.0).to_bits() as i64)
            }
        };
        // Looked up only (never iterated): the order of a hash map is moot.
        let mut grid: HashMap<[i64; 3], Vec<u32>> = HashMap::with_capacity(self.vertices.len());
        let mut rep = vec![0u32; self.vertices.len()];
        for (i, p) in self.vertices.iter().enumerate() {
            let k = key(p);
            let mut found = None;
            if tol > 0.0 {
                for dx in -1..=1 {
                    for dy in -1..=1 {
                        for dz in -1..=1 {
                            let Some(list) = grid.get(&[k[0] + dx, k[1] + dy, k[2] + dz]) else {
                                continue;
                            };
                            for &j in list {
                                if (self.vertices[j as usize] - p).norm() <= tol
                                    && found.is_none_or(|f| j < f)
                                {
                                    found = Some(j);
                                }
                            }
                        }
                    }
                }
            } else if let Some(list) = grid.get(&k) {
                found = list.first().copied();
            }
            match found {
                Some(j) => rep[i] = j,
                None => {
                    rep[i] = i as u32;
                    grid.entry(k).or_default().push(i as u32);
                }
            }
        }
        let tris: Vec<[u32; 3]> = self
            .triangles
            .iter()
            .map(|t| t.map(|k| rep[k as usize]))
            .filter(|t| t[0] != t[1] && t[1] != t[2] && t[0] != t[2])
            .collect();
        let mut used = vec![false; self.vertices.len()];
        for t in &tris {
            for &k in t {
                used[k as usize] = true;
            }
        }
        let mut new_index = vec![u32::MAX; self.vertices.len()];
        let mut vertices = Vec::new();
        for (i, p) in self.vertices.iter().enumerate() {
            if used[i] {
                new_index[i] = vertices.len() as u32;
                vertices.push(*p);
            }
        }
        let map: Vec<u32> = rep.iter().map(|&r| new_index[r as usize]).collect();
        let triangles = tris
            .into_iter()
            .map(|t| t.map(|k| new_index[k as usize]))
            .collect();
        (
            TriMesh {
                vertices,
                triangles,
            },
            map,
        )
    }

    /// Make the winding consistent across every manifold edge and outward:
    /// triangles are flipped so that neighbours traverse shared edges in
    /// opposite directions (vertices at identical positions count as
    /// shared, so seams of duplicated vertices do not split a surface);
    /// then each connected piece is turned so that its signed volume is
    /// positive (closed pieces) or its normals point away from its centroid
    /// on average (open pieces). Non-manifold edges are not crossed.
    /// Returns the number of triangles flipped.
    pub fn orient_consistently(&mut self) -> usize {
        let (_, map) = self.welded(0.0);
        let canon = |k: u32| map[k as usize];
        let nt = self.triangles.len();
        // Edge -> triangles using it (iterated only to set flags: the
        // order of a hash map is moot).
        let mut edge_tris: HashMap<[u32; 2], Vec<usize>> = HashMap::with_capacity(3 * nt / 2);
        for (i, t) in self.triangles.iter().enumerate() {
            let c = t.map(canon);
            if c[0] == c[1] || c[1] == c[2] || c[0] == c[2] {
                continue;
            }
            for j in 0..3 {
                let (a, b) = (c[j], c[(j + 1) % 3]);
                edge_tris.entry([a.min(b), a.max(b)]).or_default().push(i);
            }
        }
        let dir = |t: &[u32; 3], a: u32, b: u32| -> bool {
            // true if t traverses a->b
            let c = t.map(canon);
            (0..3).any(|j| c[j] == a && c[(j + 1) % 3] == b)
        };
        let mut flipped = vec![false; nt];
        let mut comp = vec![usize::MAX; nt];
        let mut n_comp = 0;
        for seed in 0..nt {
            if comp[seed] != usize::MAX {
                continue;
            }
            let mut stack = vec![seed];
            comp[seed] = n_comp;
            while let Some(i) = stack.pop() {
                let t = self.triangles[i];
                let tc = t.map(canon);
                for j in 0..3 {
                    let (mut a, mut b) = (tc[j], tc[(j + 1) % 3]);
                    if flipped[i] {
                        std::mem::swap(&mut a, &mut b);
                    }
                    let Some(list) = edge_tris.get(&[a.min(b), a.max(b)]) else {
                        continue;
                    };
                    if list.len() != 2 {
                        continue;
                    }
                    for &o in list {
                        if o == i || comp[o] != usize::MAX {
                            continue;
                        }
                        // Neighbour must traverse b->a.
                        let same = dir(&self.triangles[o], a, b);
                        flipped[o] = same;
                        comp[o] = n_comp;
                        stack.push(o);
                    }
                }
            }
            n_comp += 1;
        }
        for (i, f) in flipped.iter().enumerate() {
            if *f {
                let t = &mut self.triangles[i];
                t.swap(1, 2);
            }
        }
        // Outward per component.
        let mut boundary = vec![false; n_comp];
        for list in edge_tris.values() {
            if list.len() == 1 {
                boundary[comp[list[0]]] = true;
            }
        }
        // Volumes about a vertex of the mesh: about the coordinates' origin
        // a mesh far from it (a scanner's world) loses the sign to rounding.
        let o = self
            .vertices
            .first()
            .copied()
            .unwrap_or_else(Point3::origin);
        let mut vol = vec![0.0; n_comp];
        let mut area_c = vec![(Vector3::zeros(), 0.0); n_comp];
        for (i, [a, b, c]) in self.triangle_corners().enumerate() {
            vol[comp[i]] += (a - o).dot(&(b - o).cross(&(c - o)));
            let w = 0.5 * (b - a).cross(&(c - a)).norm();
            area_c[comp[i]].0 += w * (a.coords + b.coords + c.coords) / 3.0;
            area_c[comp[i]].1 += w;
        }
        let mut outward = vec![0.0; n_comp];
        for (i, [a, b, c]) in self.triangle_corners().enumerate() {
            let k = comp[i];
            let (s, w) = area_c[k];
            if w <= 0.0 {
                continue;
            }
            let centre = s / w;
            let n = 0.5 * (b - a).cross(&(c - a));
            outward[k] += n.dot(&((a.coords + b.coords + c.coords) / 3.0 - centre));
        }
        let turn: Vec<bool> = (0..n_comp)
            .map(|k| {
                if boundary[k] {
                    outward[k] < 0.0
                } else {
                    vol[k] < 0.0
                }
            })
            .collect();
        let mut count = 0;
        for i in 0..nt {
            if comp[i] != usize::MAX && turn[comp[i]] {
                self.triangles[i].swap(1, 2);
                flipped[i] = !flipped[i];
            }
            if flipped[i] {
                count += 1;
            }
        }
        count
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    /// Axis-aligned box [0,a]x[0,b]x[0,c], outward winding.
    pub(crate) fn cuboid(a: f64, b: f64, c: f64) -> TriMesh {
        let v: Vec<Point3<f64>> = (0..8)
            .map(|i| {
                Point3::new(
                    if i & 1 != 0 { a } else { 0.0 },
                    if i & 2 != 0 { b } else { 0.0 },
                    if i & 4 != 0 { c } else { 0.0 },
                )
            })
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
    fn box_mass_properties_are_analytic() {
        let m = cuboid(1.0, 2.0, 3.0);
        assert!((m.area() - 22.0).abs() < 1e-12);
        assert!((m.signed_volume() - 6.0).abs() < 1e-12);
        let c = m.volume_centroid().unwrap();
        assert!((c - Point3::new(0.5, 1.0, 1.5)).norm() < 1e-12);
        let ac = m.area_centroid().unwrap();
        assert!((ac - Point3::new(0.5, 1.0, 1.5)).norm() < 1e-12);
        // Solid box inertia per unit density: V/12 (b^2+c^2) etc.
        let i = m.solid_inertia().unwrap();
        let v = 6.0;
        assert!((i[(0, 0)] - v / 12.0 * (4.0 + 9.0)).abs() < 1e-9);
        assert!((i[(1, 1)] - v / 12.0 * (1.0 + 9.0)).abs() < 1e-9);
        assert!((i[(2, 2)] - v / 12.0 * (1.0 + 4.0)).abs() < 1e-9);
        assert!(i[(0, 1)].abs() < 1e-12);
        let ax = m.principal_axes().unwrap();
        assert!(ax.axes.column(0).z.abs() > 1.0 - 1e-9, "longest axis is z");
        assert!(ax.axes.column(2).x.abs() > 1.0 - 1e-9, "shortest axis is x");
        assert!(ax.axes.determinant() > 0.0);
    }

    #[test]
    fn rigid_transform_keeps_volume_and_mirror_keeps_sign() {
        let m = cuboid(1.0, 2.0, 3.0);
        let iso = Isometry3::from_parts(
            Translation3::new(0.3, -2.0, 5.0),
            UnitQuaternion::from_euler_angles(0.3, -1.1, 2.0),
        );
        assert!((m.transformed(&iso).signed_volume() - 6.0).abs() < 1e-9);
        let mirrored = m.scaled(&Vector3::new(-1.0, 2.0, 1.0));
        assert!((mirrored.signed_volume() - 12.0).abs() < 1e-9);
        let aff = Affine3::from_matrix_unchecked(nalgebra::Matrix4::new_nonuniform_scaling(
            &Vector3::new(1.0, 1.0, -0.5),
        ));
        assert!((m.affine(&aff).signed_volume() - 3.0).abs() < 1e-9);
    }

    #[test]
    fn topology_report() {
        let m = cuboid(1.0, 1.0, 1.0);
        assert!(m.edge_report().is_watertight());
        let mut open = m.clone();
        open.triangles.pop();
        let r = open.edge_report();
        assert_eq!(r.boundary_edges.len(), 3);
        assert!(open.require_watertight("box").is_err());
        let mut fin = m.clone();
        // Two fins on the existing edge 0-2: four triangles share it.
        fin.triangles.push([0, 2, 7]);
        fin.triangles.push([0, 2, 5]);
        let e = fin
            .require_edge_manifold("fin.vtp")
            .unwrap_err()
            .to_string();
        assert!(e.contains("fin.vtp") && e.contains("non-manifold"), "{e}");
    }

    #[test]
    fn orientation_is_repaired() {
        let good = cuboid(1.0, 2.0, 3.0);
        let mut bad = good.clone();
        for k in [0, 3, 7] {
            bad.triangles[k].swap(0, 1);
        }
        assert!(!bad.edge_report().inconsistent_edges.is_empty());
        let n = bad.orient_consistently();
        assert_eq!(n, 3);
        assert!(bad.edge_report().inconsistent_edges.is_empty());
        assert!((bad.signed_volume() - 6.0).abs() < 1e-12);
        // All inward: every triangle flipped back.
        let mut inward = good.clone();
        for t in &mut inward.triangles {
            t.swap(1, 2);
        }
        assert_eq!(inward.orient_consistently(), 12);
        assert_eq!(inward, good);
    }

    #[test]
    fn welding_merges_close_vertices() {
        let m = cuboid(1.0, 1.0, 1.0);
        // Split into triangle soup with tiny jitter.
        let mut v = Vec::new();
        let mut t = Vec::new();
        for (i, c) in m.triangle_corners().enumerate() {
            for (j, p) in c.iter().enumerate() {
                v.push(p + Vector3::new(1e-9 * j as f64, 0.0, 0.0));
            }
            t.push([3 * i as u32, 3 * i as u32 + 1, 3 * i as u32 + 2]);
        }
        let soup = TriMesh::new(v, t).unwrap();
        assert_eq!(soup.edge_report().boundary_edges.len(), 36);
        let (w, map) = soup.welded(1e-6);
        assert_eq!(w.vertices.len(), 8);
        assert_eq!(map.len(), 36);
        assert!(w.edge_report().is_watertight());
    }
}
