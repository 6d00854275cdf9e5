//! A vertebra mesh prepared for palpation: welded, consistently wound,
//! and expressed in a trial vertebra frame (X anterior, Y cranial, Z
//! right), with per-face normals, areas and centroids, plus plane cuts.

use crate::error::{Error, Result};
use crate::mesh::TriMesh;
use nalgebra::{Isometry3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use std::collections::BTreeMap;

/// The mesh in a trial frame.
pub(crate) struct LocalMesh {
    /// Local -> mesh coordinates.
    pub to_mesh: Isometry3<f64>,
    /// Vertices in local coordinates.
    pub verts: Vec<Point3<f64>>,
    /// Triangles (welded, consistently wound).
    pub tris: Vec<[u32; 3]>,
    /// Outward unit normal, area and centroid of each triangle (local).
    pub normals: Vec<Vector3<f64>>,
    pub areas: Vec<f64>,
    pub centroids: Vec<Point3<f64>>,
}

/// Most points spread over one surface (`LocalMesh::area_samples`).
pub(crate) const MAX_SURFACE_SAMPLES: usize = 4_000_000;

/// Surface area per point of the evenly spread samples (m^2): 1 mm^2.
pub(crate) const SAMPLE_AREA: f64 = 1.0e-6;

/// Weld and orient a mesh once (shared by every trial frame).
pub(crate) fn prepare(mesh: &TriMesh, ctx: &str) -> Result<TriMesh> {
    mesh.validate()?;
    let (lo, hi) = mesh
        .bounds()
        .ok_or_else(|| Error::invalid(ctx, "the mesh has no vertices"))?;
    let size = (hi - lo).norm();
    if size.is_nan() || size <= 0.0 || mesh.triangles.len() < 4 {
        return Err(Error::invalid(ctx, "the mesh is empty or degenerate"));
    }
    // The surface must fit the sample cap (bounded time and memory).
    let area = mesh.area();
    if area.is_nan() || area / SAMPLE_AREA > MAX_SURFACE_SAMPLES as f64 {
        return Err(Error::invalid(
            ctx,
            format!(
                "the surface is {area:.3e} m^2: it would need more than the cap of {} million surface samples of 1 mm^2 each (a lumbar vertebra is about 0.01 m^2): are the coordinates in the declared units?",
                MAX_SURFACE_SAMPLES / 1_000_000
            ),
        ));
    }
    let (mut welded, _) = mesh.welded(1e-7 * size);
    welded.orient_consistently();
    Ok(welded)
}

/// A right-handed rotation whose columns are (anterior, cranial, right),
/// from an anterior direction and a normal of the mid-sagittal plane.
pub(crate) fn frame_rotation(anterior: &Vector3<f64>, right: &Vector3<f64>) -> Rotation3<f64> {
    let z = right.normalize();
    let x = (anterior - z * z.dot(anterior)).normalize();
    let y = z.cross(&x);
    Rotation3::from_basis_unchecked(&[x, y, z])
}

impl LocalMesh {
    /// Express `mesh` (prepared) in the frame `to_mesh` (local -> mesh).
    pub(crate) fn new(mesh: &TriMesh, rot: Rotation3<f64>, origin: Point3<f64>) -> LocalMesh {
        let to_mesh = Isometry3::from_parts(
            Translation3::from(origin.coords),
            UnitQuaternion::from_rotation_matrix(&rot),
        );
        let inv = to_mesh.inverse();
        let verts: Vec<Point3<f64>> = mesh.vertices.iter().map(|p| inv * p).collect();
        let mut normals = Vec::with_capacity(mesh.triangles.len());
        let mut areas = Vec::with_capacity(mesh.triangles.len());
        let mut centroids = Vec::with_capacity(mesh.triangles.len());
        for t in &mesh.triangles {
            let [a, b, c] = t.map(|k| verts[k as usize]);
            let w = (b - a).cross(&(c - a));
            let area = 0.5 * w.norm();
            normals.push(w.try_normalize(0.0).unwrap_or_else(Vector3::zeros));
            areas.push(area);
            centroids.push(Point3::from((a.coords + b.coords + c.coords) / 3.0));
        }
        LocalMesh {
            to_mesh,
            verts,
            tris: mesh.triangles.clone(),
            normals,
            areas,
            centroids,
        }
    }

    /// Map a local point to mesh coordinates.
    pub(crate) fn to_mesh_point(&self, p: &Point3<f64>) -> Point3<f64> {
        self.to_mesh * p
    }

    /// The sub-mesh of the given triangles (local coordinates).
    pub(crate) fn submesh(&self, faces: &[usize]) -> TriMesh {
        let mut map: BTreeMap<u32, u32> = BTreeMap::new();
        let mut vertices = Vec::new();
        let mut triangles = Vec::new();
        for &f in faces {
            let t = self.tris[f].map(|k| {
                *map.entry(k).or_insert_with(|| {
                    vertices.push(self.verts[k as usize]);
                    (vertices.len() - 1) as u32
                })
            });
            triangles.push(t);
        }
        TriMesh {
            vertices,
            triangles,
        }
    }

    /// Points spread evenly over the surface, about one per `area_each`
    /// (m^2) whatever the mesh's resolution: each face gets its share of
    /// points (the fractional remainder carried to the next face), spread
    /// over it by the R2 low-discrepancy sequence. Deterministic. At most
    /// `MAX_SURFACE_SAMPLES` points (sparser on a larger surface).
    pub(crate) fn area_samples(&self, area_each: f64) -> Vec<Point3<f64>> {
        // R2 sequence steps (the plastic number's inverse powers).
        const A1: f64 = 0.754_877_666_246_692_7;
        const A2: f64 = 0.569_840_290_998_053_3;
        let total: f64 = self.areas.iter().sum();
        let area_each = area_each.max(total / MAX_SURFACE_SAMPLES as f64);
        let mut out = Vec::new();
        let mut carry = 0.5;
        for (t, area) in self.tris.iter().zip(&self.areas) {
            let [a, b, c] = t.map(|k| self.verts[k as usize]);
            carry += area / area_each;
            let n = carry.floor();
            carry -= n;
            for i in 0..n as usize {
                let (mut u, mut v) = ((0.5 + A1 * i as f64) % 1.0, (0.5 + A2 * i as f64) % 1.0);
                // Fold the unit square onto the triangle.
                if u + v > 1.0 {
                    (u, v) = (1.0 - u, 1.0 - v);
                }
                out.push(a + (b - a) * u + (c - a) * v);
            }
        }
        out
    }

    /// Points where the edges of the given faces cross the plane
    /// `p[axis] = value` (exactly on the plane, on the surface).
    pub(crate) fn cut(
        &self,
        faces: impl Iterator<Item = usize>,
        axis: usize,
        value: f64,
    ) -> Vec<Point3<f64>> {
        self.cut_segments(faces, axis, value)
            .into_iter()
            .flatten()
            .collect()
    }

    /// The section of the given faces by the plane `p[axis] = value`: one
    /// segment per face that crosses it (end points on its edges).
    pub(crate) fn cut_segments(
        &self,
        faces: impl Iterator<Item = usize>,
        axis: usize,
        value: f64,
    ) -> Vec<[Point3<f64>; 2]> {
        faces
            .filter_map(|f| {
                let tri = self.tris[f].map(|k| self.verts[k as usize]);
                match polygon_section(&tri, axis, value)[..] {
                    [a, b] => Some([a, b]),
                    _ => None,
                }
            })
            .collect()
    }
}

/// The point of segment `ab` closest to `p`.
pub(crate) fn closest_on_segment(p: &Point3<f64>, a: &Point3<f64>, b: &Point3<f64>) -> Point3<f64> {
    let ab = b - a;
    let l2 = ab.norm_squared();
    if l2 <= 0.0 {
        return *a;
    }
    a + ab * ((p - a).dot(&ab) / l2).clamp(0.0, 1.0)
}

/// The part of the convex polygon `poly` with `n . p <= d` (one step of
/// Sutherland-Hodgman clipping); empty when none of it is.
pub(crate) fn clip_polygon(poly: &[Point3<f64>], n: &Vector3<f64>, d: f64) -> Vec<Point3<f64>> {
    let mut out = Vec::with_capacity(poly.len() + 1);
    for (k, a) in poly.iter().enumerate() {
        let b = &poly[(k + 1) % poly.len()];
        let (da, db) = (n.dot(&a.coords) - d, n.dot(&b.coords) - d);
        if da <= 0.0 {
            out.push(*a);
        }
        // The edge crosses the plane: keep the crossing point.
        if (da <= 0.0) != (db <= 0.0) {
            out.push(a + (b - a) * (da / (da - db)));
        }
    }
    out
}

/// Where the polygon's edges cross the plane `p[axis] = value` (points
/// exactly on the plane; a vertex on the plane counts as on its positive
/// side, so a convex polygon crossing it gives two points).
pub(crate) fn polygon_section(poly: &[Point3<f64>], axis: usize, value: f64) -> Vec<Point3<f64>> {
    let mut out = Vec::with_capacity(2);
    for (k, a) in poly.iter().enumerate() {
        let b = &poly[(k + 1) % poly.len()];
        let (da, db) = (a[axis] - value, b[axis] - value);
        if (da < 0.0) != (db < 0.0) && da != db {
            let mut p = a + (b - a) * (da / (da - db));
            p[axis] = value;
            out.push(p);
        }
    }
    out
}
