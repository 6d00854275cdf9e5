//! Closed-surface primitives for the procedural anatomy: a "tube" built from
//! rings of points (every ring has the same number of points, in the same
//! angular order) with flat fan caps at both ends, and a sweep of an
//! elliptical cross-section along a polyline. Every primitive is a closed,
//! watertight, consistently wound surface with outward normals (the winding
//! is chosen from the sign of the enclosed volume).

use crate::error::{Error, Result};
use crate::mesh::TriMesh;
use nalgebra::{Point3, Vector3};

/// Round a point to whole micrometres (compact, exact ASCII output; far
/// below any modelled dimension).
fn round_um(p: &Point3<f64>) -> Point3<f64> {
    p.map(|c| (c * 1e6).round() / 1e6)
}

/// A closed tube through `rings` (at least two rings of at least three points
/// each, all the same length) with flat caps at the first and last ring (a
/// fan around the ring's mean point). Outward normals.
pub fn tube(rings: &[Vec<Point3<f64>>], what: &str) -> Result<TriMesh> {
    let n = rings.first().map(|r| r.len()).unwrap_or(0);
    if rings.len() < 2 || n < 3 || rings.iter().any(|r| r.len() != n) {
        return Err(Error::invalid(
            what,
            "internal: a tube needs at least two rings of the same size (>= 3 points)",
        ));
    }
    let mut vertices: Vec<Point3<f64>> = rings.iter().flatten().map(round_um).collect();
    let centre = |r: &Vec<Point3<f64>>| {
        Point3::from(r.iter().map(|p| p.coords).sum::<Vector3<f64>>() / r.len() as f64)
    };
    let cs = vertices.len() as u32;
    vertices.push(round_um(&centre(&rings[0])));
    let ce = vertices.len() as u32;
    vertices.push(round_um(&centre(&rings[rings.len() - 1])));
    let n32 = n as u32;
    let mut triangles = Vec::with_capacity(2 * n * rings.len());
    for r in 0..(rings.len() as u32 - 1) {
        for k in 0..n32 {
            let a = r * n32 + k;
            let b = r * n32 + (k + 1) % n32;
            let c = (r + 1) * n32 + k;
            let d = (r + 1) * n32 + (k + 1) % n32;
            triangles.push([a, b, d]);
            triangles.push([a, d, c]);
        }
    }
    let last = (rings.len() as u32 - 1) * n32;
    for k in 0..n32 {
        triangles.push([cs, (k + 1) % n32, k]);
        triangles.push([ce, last + k, last + (k + 1) % n32]);
    }
    let mut mesh = TriMesh::new(vertices, triangles)?;
    if mesh.signed_volume() < 0.0 {
        for t in &mut mesh.triangles {
            t.swap(1, 2);
        }
    }
    Ok(mesh)
}

/// One station of a sweep: centre, the "height" direction of the section
/// (projected perpendicular to the path tangent), and the half-sizes of the
/// elliptical section across (`half_w`, along `tangent x height`) and along
/// the height direction (`half_h`).
#[derive(Debug, Clone, Copy)]
pub struct Station {
    /// Centre of the section.
    pub centre: Point3<f64>,
    /// The section's height direction (unit vector).
    pub up: Vector3<f64>,
    /// Half-size across, along `tangent x up`.
    pub half_w: f64,
    /// Half-size along `up`.
    pub half_h: f64,
    /// Path tangent here; `None` = from the neighbouring stations.
    pub tangent: Option<Vector3<f64>>,
}

/// Sweep an ellipse through the stations (at least two) with `around`
/// points per ring; flat caps at both ends. Fails if a station's `up` is
/// parallel to the path there.
pub fn sweep(stations: &[Station], around: usize, what: &str) -> Result<TriMesh> {
    let m = stations.len();
    if m < 2 {
        return Err(Error::invalid(what, "internal: a sweep needs two stations"));
    }
    let mut rings = Vec::with_capacity(m);
    for i in 0..m {
        let prev = stations[i.saturating_sub(1)].centre;
        let next = stations[(i + 1).min(m - 1)].centre;
        let s = &stations[i];
        let t = s
            .tangent
            .unwrap_or(next - prev)
            .try_normalize(1e-15)
            .ok_or_else(|| Error::invalid(what, "internal: repeated sweep station"))?;
        let up = (s.up - t * s.up.dot(&t))
            .try_normalize(1e-9)
            .ok_or_else(|| Error::invalid(what, "internal: section direction along the path"))?;
        let side = t.cross(&up);
        let ring: Vec<Point3<f64>> = (0..around)
            .map(|k| {
                let phi = std::f64::consts::TAU * k as f64 / around as f64;
                s.centre + side * (s.half_w * phi.cos()) + up * (s.half_h * phi.sin())
            })
            .collect();
        rings.push(ring);
    }
    tube(&rings, what)
}

/// Stations along a straight segment `a`-`b` (`n` >= 2 stations), with the
/// half-sizes interpolated linearly from `(w0, h0)` to `(w1, h1)`.
pub fn straight(
    a: Point3<f64>,
    b: Point3<f64>,
    up: Vector3<f64>,
    (w0, h0): (f64, f64),
    (w1, h1): (f64, f64),
    n: usize,
) -> Vec<Station> {
    let n = n.max(2);
    (0..n)
        .map(|i| {
            let s = i as f64 / (n - 1) as f64;
            Station {
                centre: a + (b - a) * s,
                up,
                half_w: w0 + (w1 - w0) * s,
                half_h: h0 + (h1 - h0) * s,
                tangent: None,
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sweep_is_closed_outward_and_has_the_cylinder_volume() {
        let st = straight(
            Point3::origin(),
            Point3::new(0.0, 0.0, 0.1),
            Vector3::y(),
            (0.02, 0.01),
            (0.02, 0.01),
            3,
        );
        let m = sweep(&st, 64, "test").unwrap();
        assert!(m.edge_report().is_watertight());
        assert!(m.edge_report().inconsistent_edges.is_empty());
        // Analytic volume of an elliptic cylinder (inscribed polygon: area
        // (vertices are rounded to whole micrometres, hence the 0.1% tolerance)
        // n/2 sin(2pi/n) a b).
        let n = 64.0;
        let area = 0.5 * n * (std::f64::consts::TAU / n).sin() * 0.02 * 0.01;
        let v = m.signed_volume();
        assert!(
            (v - area * 0.1).abs() < 1e-3 * area * 0.1,
            "{v} vs {}",
            area * 0.1
        );
    }
}
