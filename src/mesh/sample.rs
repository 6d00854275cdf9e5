//! Seeded uniform sampling of points on a mesh surface (area-weighted
//! triangle choice, uniform within each triangle). Same mesh, count and
//! seed give the same points on every platform (ChaCha8).

use super::TriMesh;
use nalgebra::Point3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// `n` points uniformly distributed over the surface, each with the index
/// of its triangle. Empty if the mesh has no area.
pub fn sample_surface(mesh: &TriMesh, n: usize, seed: u64) -> Vec<(Point3<f64>, usize)> {
    let mut cum = Vec::with_capacity(mesh.triangles.len());
    let mut total = 0.0;
    for [a, b, c] in mesh.triangle_corners() {
        total += 0.5 * (b - a).cross(&(c - a)).norm();
        cum.push(total);
    }
    if total.is_nan() || total <= 0.0 {
        return Vec::new();
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            let u: f64 = rng.random::<f64>() * total;
            let k = cum.partition_point(|&c| c <= u).min(cum.len() - 1);
            let [a, b, c] = mesh.corners(k);
            let (r1, r2): (f64, f64) = (rng.random(), rng.random());
            let s = r1.sqrt();
            let p = a.coords * (1.0 - s) + b.coords * (s * (1.0 - r2)) + c.coords * (s * r2);
            (Point3::from(p), k)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn samples_follow_area_and_are_deterministic() {
        // Two triangles, areas 1 and 3 (in units of 0.5).
        let m = TriMesh::new(
            vec![
                Point3::new(0.0, 0.0, 0.0),
                Point3::new(1.0, 0.0, 0.0),
                Point3::new(0.0, 1.0, 0.0),
                Point3::new(0.0, 0.0, 1.0),
                Point3::new(3.0, 0.0, 1.0),
                Point3::new(0.0, 1.0, 1.0),
            ],
            vec![[0, 1, 2], [3, 4, 5]],
        )
        .unwrap();
        let s = sample_surface(&m, 20000, 7);
        assert_eq!(s, sample_surface(&m, 20000, 7));
        let frac = s.iter().filter(|(_, k)| *k == 1).count() as f64 / s.len() as f64;
        assert!((frac - 0.75).abs() < 0.015, "{frac}");
        // Uniform within the triangle: mean is the centroid.
        let c = s
            .iter()
            .filter(|(_, k)| *k == 0)
            .fold(nalgebra::Vector3::zeros(), |a, (p, _)| a + p.coords);
        let n0 = s.iter().filter(|(_, k)| *k == 0).count() as f64;
        assert!((c / n0 - nalgebra::Vector3::new(1.0 / 3.0, 1.0 / 3.0, 0.0)).norm() < 0.01);
        for (p, k) in &s {
            let z = if *k == 0 { 0.0 } else { 1.0 };
            assert!((p.z - z).abs() < 1e-12);
        }
    }
}
