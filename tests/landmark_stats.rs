//! The statistics of `osim-spine variability` against published worked
//! examples, published tables, R outputs (with the R call that produced
//! them) and analytic identities.

use osim_spine::landmarks::stats::*;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// Shrout & Fleiss (1979), Psychol. Bull. 86(2):420-428, Table 2: 6 targets
/// rated by 4 judges. Table 4 of the paper gives ICC(1,1) = .17,
/// ICC(2,1) = .29, ICC(3,1) = .71; Table 3's mean squares BMS = 11.24,
/// WMS = 6.26, JMS = 32.49, EMS = 1.02.
#[test]
fn icc_reproduces_shrout_fleiss_1979() {
    let data = vec![
        vec![9.0, 2.0, 5.0, 8.0],
        vec![6.0, 1.0, 3.0, 2.0],
        vec![8.0, 4.0, 6.0, 8.0],
        vec![7.0, 1.0, 2.0, 6.0],
        vec![10.0, 5.0, 6.0, 9.0],
        vec![6.0, 2.0, 4.0, 7.0],
    ];
    let r = icc(&data).unwrap();
    assert!((r.bms - 11.24).abs() < 0.005, "BMS {}", r.bms);
    assert!((r.wms - 6.26).abs() < 0.005, "WMS {}", r.wms);
    assert!((r.jms - 32.49).abs() < 0.005, "JMS {}", r.jms);
    assert!((r.ems - 1.02).abs() < 0.005, "EMS {}", r.ems);
    assert!((r.icc1_1 - 0.17).abs() < 0.005, "ICC(1,1) {}", r.icc1_1);
    assert!((r.icc2_1 - 0.29).abs() < 0.005, "ICC(2,1) {}", r.icc2_1);
    assert!((r.icc3_1 - 0.71).abs() < 0.005, "ICC(3,1) {}", r.icc3_1);
}

#[test]
fn icc_is_one_for_perfect_agreement_and_rejects_ragged_tables() {
    let data: Vec<Vec<f64>> = (0..5).map(|i| vec![i as f64; 3]).collect();
    assert!((icc(&data).unwrap().icc2_1 - 1.0).abs() < 1e-12);
    assert!(icc(&[vec![1.0, 2.0], vec![1.0]]).is_err());
    assert!(icc(&[vec![1.0, 2.0]]).is_err());
}

/// Shapiro & Wilk (1965), Biometrika 52:591-611, section 7 example: weights
/// of 11 men (lb); the paper gives W = 0.79, below the 1% point (0.792) of
/// its Table 6, so p < 0.01. (R 4.x: `shapiro.test(c(148,154,158,160,161,
/// 162,166,170,182,195,236))` uses the same Royston algorithm.)
#[test]
fn shapiro_wilk_reproduces_the_1965_example() {
    let x = [
        148.0, 154.0, 158.0, 160.0, 161.0, 162.0, 166.0, 170.0, 182.0, 195.0, 236.0,
    ];
    let r = shapiro_wilk(&x).unwrap();
    assert!((r.w - 0.79).abs() < 0.005, "W = {}", r.w);
    assert!(r.p < 0.01 && r.p > 0.001, "p = {}", r.p);
}

/// Percentage points of W from Shapiro & Wilk (1965) Table 6: the p-value
/// of W equal to the tabulated alpha-point must be close to alpha (Royston's
/// approximation agrees with the table to a few per cent of alpha).
#[test]
fn shapiro_wilk_p_matches_published_percentage_points() {
    // (n, alpha, W_alpha): Shapiro & Wilk 1965, Table 6.
    let table = [
        (11, 0.01, 0.792),
        (11, 0.05, 0.850),
        (11, 0.10, 0.876),
        (20, 0.01, 0.868),
        (20, 0.05, 0.905),
        (30, 0.01, 0.900),
        (30, 0.05, 0.927),
    ];
    for (n, alpha, w) in table {
        let p = p_of_w(n, w);
        assert!(
            (p - alpha).abs() < 0.3 * alpha,
            "n={n} W={w}: p={p}, table alpha={alpha}"
        );
    }
}

/// p-value for a given W and n through the library: a sample of size n
/// whose W is exactly `w` is built by blending a normal-scores sample with
/// an outlier and bisecting on the blend.
fn p_of_w(n: usize, w: f64) -> f64 {
    let base: Vec<f64> = (1..=n)
        .map(|i| {
            let p = (i as f64 - 0.375) / (n as f64 + 0.25);
            statrs::distribution::ContinuousCDF::inverse_cdf(
                &statrs::distribution::Normal::standard(),
                p,
            )
        })
        .collect();
    let sample = |t: f64| -> Vec<f64> {
        let mut v = base.clone();
        let last = v.len() - 1;
        v[last] += t;
        v
    };
    let (mut lo, mut hi) = (0.0, 50.0);
    for _ in 0..100 {
        let mid = 0.5 * (lo + hi);
        if shapiro_wilk(&sample(mid)).unwrap().w > w {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let r = shapiro_wilk(&sample(0.5 * (lo + hi))).unwrap();
    assert!((r.w - w).abs() < 1e-6);
    r.p
}

#[test]
fn shapiro_wilk_has_nominal_size_under_normality() {
    let mut rng = ChaCha8Rng::seed_from_u64(42);
    let nd = Normal::new(10.0, 2.0).unwrap();
    for n in [8usize, 29, 100] {
        let reps = 3000;
        let mut rejections = 0;
        for _ in 0..reps {
            let x: Vec<f64> = (0..n).map(|_| nd.sample(&mut rng)).collect();
            if shapiro_wilk(&x).unwrap().p < 0.05 {
                rejections += 1;
            }
        }
        let rate = rejections as f64 / reps as f64;
        // Binomial SD at 3000 reps is 0.004: allow +-0.015.
        assert!((rate - 0.05).abs() < 0.015, "n={n}: rejection rate {rate}");
    }
    assert!(shapiro_wilk(&[1.0, 2.0]).is_err());
    assert!(shapiro_wilk(&[1.0, 1.0, 1.0]).is_err());
}

/// R 4.x, `example(friedman.test)`: Hollander & Wolfe (1973) p. 140,
/// rounding first base. `friedman.test(RoundingTimes)` prints
/// "Friedman chi-squared = 11.143, df = 2, p-value = 0.003805".
#[test]
fn friedman_reproduces_r_rounding_times() {
    #[rustfmt::skip]
    let rt = [
        5.40, 5.50, 5.55, 5.85, 5.70, 5.75, 5.20, 5.60, 5.50, 5.55, 5.50, 5.40,
        5.90, 5.85, 5.70, 5.45, 5.55, 5.60, 5.40, 5.40, 5.35, 5.45, 5.50, 5.35,
        5.25, 5.15, 5.00, 5.85, 5.80, 5.70, 5.25, 5.20, 5.10, 5.65, 5.55, 5.45,
        5.60, 5.35, 5.45, 5.05, 5.00, 4.95, 5.50, 5.50, 5.40, 5.45, 5.55, 5.50,
        5.55, 5.55, 5.35, 5.45, 5.50, 5.55, 5.50, 5.45, 5.25, 5.65, 5.60, 5.40,
        5.70, 5.65, 5.55, 6.30, 6.30, 6.25,
    ];
    let y: Vec<Vec<f64>> = rt.chunks(3).map(|c| c.to_vec()).collect();
    assert_eq!(y.len(), 22);
    let r = friedman(&y).unwrap();
    assert!((r.statistic - 11.143).abs() < 0.0005, "{}", r.statistic);
    assert_eq!(r.df, 2);
    assert!((r.p - 0.003805).abs() < 0.000005, "{}", r.p);
}

/// R 4.x, `example(friedman.test)`, formula interface:
/// `wb <- aggregate(warpbreaks$breaks, by = list(w = warpbreaks$wool,
/// t = warpbreaks$tension), FUN = mean); friedman.test(x ~ w | t, data = wb)`
/// prints "Friedman chi-squared = 0.33333, df = 1, p-value = 0.5637".
#[test]
fn friedman_reproduces_r_warpbreaks() {
    // blocks = tension L, M, H; groups = wool A, B (mean breaks).
    let y = vec![
        vec![44.55556, 28.22222],
        vec![24.00000, 28.77778],
        vec![24.55556, 18.77778],
    ];
    let r = friedman(&y).unwrap();
    assert!((r.statistic - 1.0 / 3.0).abs() < 1e-9);
    assert!((r.p - 0.5637).abs() < 0.00005, "{}", r.p);
}

#[test]
fn skillings_mack_equals_friedman_on_complete_untied_blocks() {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let nd = Normal::new(0.0, 1.0).unwrap();
    for k in [3usize, 5, 10] {
        let y: Vec<Vec<f64>> = (0..8)
            .map(|_| {
                (0..k)
                    .map(|j| nd.sample(&mut rng) + 0.2 * j as f64)
                    .collect()
            })
            .collect();
        let f = friedman(&y).unwrap();
        let yo: Vec<Vec<Option<f64>>> = y
            .iter()
            .map(|r| r.iter().map(|v| Some(*v)).collect())
            .collect();
        let sm = skillings_mack(&yo).unwrap();
        assert!(
            (f.statistic - sm.statistic).abs() < 1e-9,
            "k={k}: {} vs {}",
            f.statistic,
            sm.statistic
        );
        assert_eq!(friedman_blocked(&yo).unwrap().method, "friedman");
    }
}

#[test]
fn skillings_mack_has_nominal_size_with_missing_cells() {
    // 8 blocks (levels) x 5 groups (operators), 15% of cells missing,
    // no group effect: the rejection rate at 5% must be near 5%.
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let nd = Normal::new(0.0, 1.0).unwrap();
    let u = rand_distr::Uniform::new(0.0, 1.0).unwrap();
    let reps = 2000;
    let mut rej = 0;
    for _ in 0..reps {
        let y: Vec<Vec<Option<f64>>> = (0..8)
            .map(|b| {
                (0..5)
                    .map(|_| {
                        let v = nd.sample(&mut rng) + b as f64;
                        if u.sample(&mut rng) < 0.15 {
                            None
                        } else {
                            Some(v)
                        }
                    })
                    .collect()
            })
            .collect();
        let r = friedman_blocked(&y).unwrap();
        if r.p < 0.05 {
            rej += 1;
        }
    }
    let rate = rej as f64 / reps as f64;
    assert!((rate - 0.05).abs() < 0.02, "rejection rate {rate}");
}

#[test]
fn skillings_mack_detects_a_real_group_effect() {
    let y: Vec<Vec<Option<f64>>> = (0..10)
        .map(|b| {
            (0..4)
                .map(|j| {
                    if (b + j) % 5 == 0 {
                        None
                    } else {
                        Some(j as f64 + 0.01 * b as f64)
                    }
                })
                .collect()
        })
        .collect();
    let r = skillings_mack(&y).unwrap();
    assert_eq!(r.method, "skillings-mack");
    assert!(r.p < 1e-3, "p = {}", r.p);
}

/// Dunnett (1964), Biometrics 20:482-491, two-sided table, infinite df,
/// alpha = 0.05: 1.96 (1 comparison), 2.21, 2.35, 2.44, 2.51, 2.57, 2.61,
/// 2.65, 2.69 (9 comparisons). These are the single-step critical values of
/// the many-to-one Nemenyi test (correlation 0.5 between comparisons).
#[test]
fn many_one_critical_values_match_dunnett_table() {
    let table = [1.96, 2.21, 2.35, 2.44, 2.51, 2.57, 2.61, 2.65, 2.69];
    for (i, &c) in table.iter().enumerate() {
        let got = many_one_critical(0.05, i + 1);
        assert!((got - c).abs() < 0.006, "m={}: {got} vs {c}", i + 1);
    }
    // One comparison is the plain two-sided normal test.
    let p = many_one_p(1.959964, 1);
    assert!((p - 0.05).abs() < 1e-6, "{p}");
}

/// Studentized range, infinite df, upper 5% points (Harter 1960 / standard
/// tables): k=2 2.772, 3 3.314, 5 3.858, 10 4.474. The thesis's critical z
/// values 2.728 (5 operators) and 3.164 (10 repetitions) are these / sqrt 2.
#[test]
fn studentized_range_and_thesis_critical_values() {
    for (k, q) in [(2usize, 2.772), (3, 3.314), (5, 3.858), (10, 4.474)] {
        let got = studentized_range_quantile_inf(0.05, k);
        assert!((got - q).abs() < 0.002, "k={k}: {got} vs {q}");
    }
    assert!((nemenyi_critical_z(0.05, 5) - 2.728).abs() < 0.002);
    assert!((nemenyi_critical_z(0.05, 10) - 3.164).abs() < 0.002);
    // k = 2: range of two normals is sqrt2 |Z|, so q = 1.95996 sqrt 2.
    let q2 = studentized_range_quantile_inf(0.05, 2);
    assert!((q2 - 1.959964 * 2f64.sqrt()).abs() < 1e-4);
}

/// Thesis Table 5.4 (R, `PMCMRplus::frdManyOneNemenyiTest`, 4 comparisons
/// with operator 1): z = -2.8 -> p = 0.02, z = 3.3 -> p = 0.004 (values as
/// printed, rounded).
#[test]
fn many_one_p_matches_thesis_table_5_4() {
    assert!((many_one_p(-2.8, 4) - 0.02).abs() < 0.005);
    assert!((many_one_p(3.3, 4) - 0.004).abs() < 0.0005);
}

#[test]
fn nemenyi_many_one_statistic_is_the_rank_sum_difference() {
    // 4 blocks, 3 groups, group 2 always largest, group 0 always smallest:
    // rank sums 4, 8, 12; se = sqrt(4*3*4/6) = sqrt 8.
    let y: Vec<Vec<Option<f64>>> = (0..4)
        .map(|b| vec![Some(b as f64), Some(b as f64 + 1.0), Some(b as f64 + 2.0)])
        .collect();
    let r = nemenyi_many_one(&y).unwrap();
    assert_eq!(r.len(), 2);
    assert!((r[0].z - 4.0 / 8f64.sqrt()).abs() < 1e-12);
    assert!((r[1].z - 8.0 / 8f64.sqrt()).abs() < 1e-12);
    assert!(r[1].p < r[0].p);
}
