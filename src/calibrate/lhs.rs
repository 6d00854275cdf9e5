//! Seeded Latin hypercube sampling on boxes (multi-start points, joint-pose
//! perturbations). Deterministic for a given seed ([`rand_chacha::ChaCha8Rng`]).

use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// `n` points in `[0,1)^dim`: each coordinate has exactly one point in each
/// of the `n` equal strata, strata paired across coordinates at random.
#[allow(clippy::needless_range_loop)]
pub fn unit(n: usize, dim: usize, seed: u64) -> Vec<Vec<f64>> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut pts = vec![vec![0.0; dim]; n];
    let mut perm: Vec<usize> = (0..n).collect();
    for d in 0..dim {
        perm.shuffle(&mut rng);
        for (i, &s) in perm.iter().enumerate() {
            let u: f64 = rng.random();
            pts[i][d] = (s as f64 + u) / n as f64;
        }
    }
    pts
}

/// `n` points in the box `[lo, hi]` (per coordinate).
pub fn in_box(n: usize, lo: &[f64], hi: &[f64], seed: u64) -> Vec<Vec<f64>> {
    unit(n, lo.len().min(hi.len()), seed)
        .into_iter()
        .map(|u| {
            u.iter()
                .enumerate()
                .map(|(d, v)| lo[d] + v * (hi[d] - lo[d]))
                .collect()
        })
        .collect()
}

/// `n` standard-normal points in `dim` dimensions by inverting the normal
/// CDF at Latin-hypercube points (a stratified normal sample).
pub fn normal(n: usize, dim: usize, seed: u64) -> Vec<Vec<f64>> {
    use statrs::distribution::{ContinuousCDF, Normal};
    let Ok(nd) = Normal::new(0.0, 1.0) else {
        return vec![vec![0.0; dim]; n];
    };
    unit(n, dim, seed)
        .into_iter()
        .map(|u| {
            u.iter()
                .map(|v| nd.inverse_cdf(v.clamp(1e-12, 1.0 - 1e-12)))
                .collect()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_point_per_stratum_and_deterministic() {
        let n = 37;
        let pts = unit(n, 5, 42);
        for d in 0..5 {
            let mut strata: Vec<usize> = pts.iter().map(|p| (p[d] * n as f64) as usize).collect();
            strata.sort_unstable();
            assert_eq!(strata, (0..n).collect::<Vec<_>>());
        }
        assert_eq!(pts, unit(n, 5, 42));
        assert_ne!(pts, unit(n, 5, 43));
    }

    #[test]
    fn box_and_normal_samples() {
        let pts = in_box(10, &[-1.0, 2.0], &[1.0, 3.0], 1);
        assert!(pts
            .iter()
            .all(|p| (-1.0..1.0).contains(&p[0]) && (2.0..3.0).contains(&p[1])));
        let z = normal(2000, 1, 3);
        let mean = z.iter().map(|p| p[0]).sum::<f64>() / 2000.0;
        let var = z.iter().map(|p| (p[0] - mean).powi(2)).sum::<f64>() / 1999.0;
        assert!(
            mean.abs() < 0.01 && (var - 1.0).abs() < 0.02,
            "{mean} {var}"
        );
    }
}
