//! Symmetric surface distance between two surfaces (the segmentation
//! literature's ASSD family): points spread evenly over each surface
//! ([`super::sample_surface`]), each one's distance to the other surface.

use super::{sample_surface, MeshQuery, TriMesh};
use crate::error::Result;

/// Distances (m) from `n` points spread evenly over `a` to `b`, followed by
/// those from `n` points over `b` to `a` (seeded: the same every run).
/// Their median and 95th percentile are the symmetric surface distance's.
pub fn symmetric_surface_distances(a: &TriMesh, b: &TriMesh, n: usize) -> Result<Vec<f64>> {
    let (qa, qb) = (MeshQuery::new(a)?, MeshQuery::new(b)?);
    let one_way = |from: &TriMesh, to: &MeshQuery| -> Vec<f64> {
        sample_surface(from, n, 0x5eed)
            .iter()
            .map(|(p, _)| to.distance(p))
            .collect()
    };
    let mut d = one_way(a, &qb);
    d.extend(one_way(b, &qa));
    Ok(d)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;

    /// A closed box of half-sides `h` (12 triangles).
    fn cube(h: f64) -> TriMesh {
        let v: Vec<Point3<f64>> = (0..8)
            .map(|i| {
                Point3::new(
                    if i & 1 == 0 { -h } else { h },
                    if i & 2 == 0 { -h } else { h },
                    if i & 4 == 0 { -h } else { h },
                )
            })
            .collect();
        let t = vec![
            [0, 2, 3],
            [0, 3, 1],
            [4, 5, 7],
            [4, 7, 6],
            [0, 1, 5],
            [0, 5, 4],
            [2, 6, 7],
            [2, 7, 3],
            [0, 4, 6],
            [0, 6, 2],
            [1, 3, 7],
            [1, 7, 5],
        ];
        TriMesh::new(v, t).unwrap()
    }

    /// Two cubes 1 mm apart in size: every point of each is 1 mm (outer
    /// faces) from the other, except near the edges and corners of the
    /// outer one, which are further (up to sqrt(3) mm).
    #[test]
    fn nested_cubes_are_their_gap_apart() {
        let (a, b) = (cube(0.010), cube(0.011));
        let d = symmetric_surface_distances(&a, &b, 2000).unwrap();
        assert_eq!(d.len(), 4000);
        let med = crate::util::median(&d).unwrap();
        assert!((med - 0.001).abs() < 1e-9, "{med}");
        let worst = d.iter().fold(0.0f64, |m, x| m.max(*x));
        assert!(worst <= 3f64.sqrt() * 0.001 + 1e-12 && worst > 0.0012);
        // a surface is 0 from itself
        assert!(symmetric_surface_distances(&a, &a, 500)
            .unwrap()
            .iter()
            .all(|x| *x < 1e-12));
    }
}
