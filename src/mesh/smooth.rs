//! Taubin's lambda|mu smoothing (Taubin 1995, "A signal processing approach
//! to fair surface design"): each pass moves every vertex by `lambda` times
//! the umbrella Laplacian (towards the mean of its neighbours), then by `mu`
//! (negative, slightly larger) times it, away again. The pair is a low-pass
//! filter: a voxel staircase (high frequency) goes, the shape (low
//! frequency) stays, and, unlike plain Laplacian smoothing, the surface
//! does not shrink. The connectivity is kept, so a closed, consistently
//! oriented mesh stays one.

use super::TriMesh;
use nalgebra::{Point3, Vector3};

/// Taubin's smoothing factor (the shrinking step).
const LAMBDA: f64 = 0.5;
/// Taubin's inflating factor, `1/lambda + 1/mu = 0.1` (pass-band edge k = 0.1).
const MU: f64 = -0.526_315_789_473_684_2;

/// Each vertex's neighbours (vertices sharing an edge), sorted, unique.
fn neighbours(mesh: &TriMesh) -> Vec<Vec<u32>> {
    let mut nb: Vec<Vec<u32>> = vec![Vec::new(); mesh.vertices.len()];
    for t in &mesh.triangles {
        for j in 0..3 {
            let (a, b) = (t[j], t[(j + 1) % 3]);
            nb[a as usize].push(b);
            nb[b as usize].push(a);
        }
    }
    for v in nb.iter_mut() {
        v.sort_unstable();
        v.dedup();
    }
    nb
}

/// One umbrella step: every vertex moved by `f` times the mean of its
/// neighbours minus itself (vertices with no neighbour stay).
fn umbrella_step(points: &[Point3<f64>], nb: &[Vec<u32>], f: f64) -> Vec<Point3<f64>> {
    points
        .iter()
        .zip(nb)
        .map(|(p, n)| {
            if n.is_empty() {
                return *p;
            }
            let mean = n
                .iter()
                .fold(Vector3::zeros(), |a, &k| a + points[k as usize].coords)
                / n.len() as f64;
            p + (mean - p.coords) * f
        })
        .collect()
}

/// `passes` lambda|mu passes of Taubin smoothing ([`LAMBDA`], [`MU`]);
/// the triangles are unchanged.
pub fn taubin(mesh: &TriMesh, passes: usize) -> TriMesh {
    let nb = neighbours(mesh);
    let mut v = mesh.vertices.clone();
    for _ in 0..passes {
        v = umbrella_step(&v, &nb, LAMBDA);
        v = umbrella_step(&v, &nb, MU);
    }
    TriMesh {
        vertices: v,
        triangles: mesh.triangles.clone(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An octahedron refined `n` times, projected on the unit sphere.
    fn sphere(n: usize) -> TriMesh {
        let mut v = vec![
            Point3::new(1.0, 0.0, 0.0),
            Point3::new(-1.0, 0.0, 0.0),
            Point3::new(0.0, 1.0, 0.0),
            Point3::new(0.0, -1.0, 0.0),
            Point3::new(0.0, 0.0, 1.0),
            Point3::new(0.0, 0.0, -1.0),
        ];
        let mut t: Vec<[u32; 3]> = vec![
            [0, 2, 4],
            [2, 1, 4],
            [1, 3, 4],
            [3, 0, 4],
            [2, 0, 5],
            [1, 2, 5],
            [3, 1, 5],
            [0, 3, 5],
        ];
        for _ in 0..n {
            let mut mid = std::collections::BTreeMap::new();
            let mut next = Vec::new();
            for tri in &t {
                let m: Vec<u32> = (0..3)
                    .map(|j| {
                        let (a, b) = (tri[j].min(tri[(j + 1) % 3]), tri[j].max(tri[(j + 1) % 3]));
                        *mid.entry((a, b)).or_insert_with(|| {
                            let p = nalgebra::center(&v[a as usize], &v[b as usize]);
                            v.push(Point3::from(p.coords.normalize()));
                            (v.len() - 1) as u32
                        })
                    })
                    .collect();
                next.push([tri[0], m[0], m[2]]);
                next.push([tri[1], m[1], m[0]]);
                next.push([tri[2], m[2], m[1]]);
                next.push([m[0], m[1], m[2]]);
            }
            t = next;
        }
        TriMesh {
            vertices: v,
            triangles: t,
        }
    }

    /// A noisy sphere comes back near the unit sphere, with its volume
    /// kept (plain Laplacian smoothing, lambda alone, shrinks it).
    #[test]
    fn taubin_removes_noise_without_shrinking() {
        let clean = sphere(4);
        let mut noisy = clean.clone();
        for (i, p) in noisy.vertices.iter_mut().enumerate() {
            // deterministic +-3 % radial noise
            let e = 0.03 * (((i * 7919) % 13) as f64 / 6.0 - 1.0);
            *p = Point3::from(p.coords * (1.0 + e));
        }
        let rms = |m: &TriMesh| {
            (m.vertices
                .iter()
                .map(|p| (p.coords.norm() - 1.0).powi(2))
                .sum::<f64>()
                / m.vertices.len() as f64)
                .sqrt()
        };
        let smooth = taubin(&noisy, 10);
        assert!(
            rms(&smooth) < 0.5 * rms(&noisy),
            "{} vs {}",
            rms(&smooth),
            rms(&noisy)
        );
        let v0 = clean.signed_volume();
        assert!((smooth.signed_volume() / v0 - 1.0).abs() < 0.02);
        assert_eq!(smooth.triangles, noisy.triangles);
        // lambda alone shrinks: the reason for mu
        let nb = neighbours(&noisy);
        let mut v = noisy.vertices.clone();
        for _ in 0..20 {
            v = umbrella_step(&v, &nb, LAMBDA);
        }
        let shrunk = TriMesh {
            vertices: v,
            triangles: noisy.triangles.clone(),
        };
        assert!(shrunk.signed_volume() / v0 < 0.97);
    }
}
