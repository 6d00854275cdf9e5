//! Statistics for repeated-palpation studies (thesis chapter 5).
//!
//! - [`icc`]: intraclass correlations of Shrout & Fleiss (1979) from the
//!   two-way ANOVA mean squares; the study uses ICC(2,1) (two-way random,
//!   absolute agreement, single measure).
//! - [`shapiro_wilk`]: W and p by Royston's (1995) algorithm AS R94
//!   (3 <= n <= 5000), the algorithm behind R's `shapiro.test`.
//! - [`friedman`]: Friedman rank test for an unreplicated complete block
//!   design with R's tie correction (`friedman.test`), chi-square
//!   approximation with k-1 df.
//! - [`skillings_mack`]: the Skillings & Mack (1981) generalisation for
//!   incomplete blocks ("unbalanced Friedman"): within-block ranks over the
//!   available observations, missing cells at the block's mean rank, ranks
//!   scaled by sqrt(12/(k_i+1)); statistic `A' S^-1 A` on k-1 treatments with
//!   the exact permutation covariance, chi-square k-1 df. Midranks for ties,
//!   no tie correction. On complete blocks without ties it equals Friedman's
//!   statistic. [`friedman_blocked`] picks Friedman when every block is
//!   complete and Skillings-Mack otherwise.
//! - [`nemenyi_many_one`]: Nemenyi-Wilcoxon-Wilcox-Miller many-to-one test
//!   (as `PMCMRplus::frdManyOneNemenyiTest`): `z_j = (R_j - R_1) /
//!   sqrt(n k (k+1) / 6)` on rank sums, two-sided p-values single-step
//!   adjusted from the equicorrelated (rho = 0.5) multivariate normal
//!   (Dunnett-type, infinite df). Incomplete blocks are dropped.
//!   The conservative critical value used in the thesis,
//!   `q_{alpha}(k, inf) / sqrt 2` from the studentized range, is
//!   [`nemenyi_critical_z`].
//! - Descriptives: [`quantile`] (R type 7), [`median`], [`iqr`].

use crate::error::{Error, Result};
use nalgebra::{DMatrix, DVector};
use statrs::distribution::{ChiSquared, ContinuousCDF, Normal};

fn std_normal() -> Normal {
    // Parameters are constants: cannot fail.
    Normal::standard()
}

fn phi_cdf(x: f64) -> f64 {
    std_normal().cdf(x)
}

fn phi_pdf(x: f64) -> f64 {
    (-0.5 * x * x).exp() / (2.0 * std::f64::consts::PI).sqrt()
}

fn qnorm(p: f64) -> f64 {
    std_normal().inverse_cdf(p.clamp(0.0, 1.0))
}

pub use crate::util::quantiles::{iqr, median, quantile};

/// Composite Simpson integral of `f` on `[a, b]` with `n` (even) intervals.
fn simpson(f: impl Fn(f64) -> f64, a: f64, b: f64, n: usize) -> f64 {
    let n = n + n % 2;
    let h = (b - a) / n as f64;
    let mut s = f(a) + f(b);
    for i in 1..n {
        let w = if i % 2 == 1 { 4.0 } else { 2.0 };
        s += w * f(a + i as f64 * h);
    }
    s * h / 3.0
}

// ------------------------------------------------------------------ ICC

/// Shrout & Fleiss (1979) intraclass correlations and the two-way ANOVA
/// mean squares they are built from.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Icc {
    /// Targets (rows).
    pub n: usize,
    /// Raters / repetitions (columns).
    pub k: usize,
    /// Between-targets mean square.
    pub bms: f64,
    /// Within-target mean square (one-way).
    pub wms: f64,
    /// Between-raters mean square.
    pub jms: f64,
    /// Residual mean square.
    pub ems: f64,
    /// ICC(1,1): one-way random, single measure.
    pub icc1_1: f64,
    /// ICC(2,1): two-way random, absolute agreement, single measure.
    pub icc2_1: f64,
    /// ICC(3,1): two-way mixed, consistency, single measure.
    pub icc3_1: f64,
}

/// ICCs of a complete `n x k` table (`rows[i][j]`: target i, rater j).
pub fn icc(rows: &[Vec<f64>]) -> Result<Icc> {
    let n = rows.len();
    let k = rows.first().map(|r| r.len()).unwrap_or(0);
    if n < 2 || k < 2 {
        return Err(Error::invalid(
            "ICC",
            format!("need at least 2 targets and 2 raters, got {n} x {k}"),
        ));
    }
    if rows
        .iter()
        .any(|r| r.len() != k || r.iter().any(|v| !v.is_finite()))
    {
        return Err(Error::invalid(
            "ICC",
            "every target needs one finite value per rater",
        ));
    }
    let (nf, kf) = (n as f64, k as f64);
    let grand = rows.iter().flatten().sum::<f64>() / (nf * kf);
    let row_means: Vec<f64> = rows.iter().map(|r| r.iter().sum::<f64>() / kf).collect();
    let col_means: Vec<f64> = (0..k)
        .map(|j| rows.iter().map(|r| r[j]).sum::<f64>() / nf)
        .collect();
    let ss_total: f64 = rows.iter().flatten().map(|v| (v - grand).powi(2)).sum();
    let ss_rows: f64 = kf * row_means.iter().map(|m| (m - grand).powi(2)).sum::<f64>();
    let ss_cols: f64 = nf * col_means.iter().map(|m| (m - grand).powi(2)).sum::<f64>();
    let ss_err = (ss_total - ss_rows - ss_cols).max(0.0);
    let bms = ss_rows / (nf - 1.0);
    let jms = ss_cols / (kf - 1.0);
    let ems = ss_err / ((nf - 1.0) * (kf - 1.0));
    let wms = (ss_cols + ss_err) / (nf * (kf - 1.0));
    let icc1_1 = (bms - wms) / (bms + (kf - 1.0) * wms);
    let icc2_1 = (bms - ems) / (bms + (kf - 1.0) * ems + kf * (jms - ems) / nf);
    let icc3_1 = (bms - ems) / (bms + (kf - 1.0) * ems);
    Ok(Icc {
        n,
        k,
        bms,
        wms,
        jms,
        ems,
        icc1_1,
        icc2_1,
        icc3_1,
    })
}

// ------------------------------------------------------------------ Shapiro-Wilk

/// Shapiro-Wilk result.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct ShapiroWilk {
    /// Sample size.
    pub n: usize,
    /// The W statistic.
    pub w: f64,
    /// p-value of normality.
    pub p: f64,
}

fn poly(c: &[f64], x: f64) -> f64 {
    c.iter().rev().fold(0.0, |acc, &ci| acc * x + ci)
}

/// Shapiro-Wilk W test (Royston 1995, AS R94), 3 <= n <= 5000.
pub fn shapiro_wilk(x: &[f64]) -> Result<ShapiroWilk> {
    let n = x.len();
    if !(3..=5000).contains(&n) {
        return Err(Error::invalid(
            "Shapiro-Wilk",
            format!("sample size must be between 3 and 5000, got {n}"),
        ));
    }
    if x.iter().any(|v| !v.is_finite()) {
        return Err(Error::invalid("Shapiro-Wilk", "non-finite value"));
    }
    let mut v = x.to_vec();
    v.sort_by(f64::total_cmp);
    let range = v[n - 1] - v[0];
    if range < 1e-10 * v[n - 1].abs().max(1e-300) || range == 0.0 {
        return Err(Error::invalid(
            "Shapiro-Wilk",
            "all values (nearly) identical",
        ));
    }
    let nn2 = n / 2;
    let an = n as f64;
    // Coefficients a[0..nn2] for the smallest..middle order statistics (positive).
    let mut a = vec![0.0; nn2];
    if n == 3 {
        a[0] = std::f64::consts::FRAC_1_SQRT_2;
    } else {
        const C1: [f64; 6] = [0.0, 0.221157, -0.147981, -2.071190, 4.434685, -2.706056];
        const C2: [f64; 6] = [0.0, 0.042981, -0.293762, -1.752461, 5.682633, -3.582633];
        let m: Vec<f64> = (1..=nn2)
            .map(|i| qnorm((i as f64 - 0.375) / (an + 0.25)))
            .collect();
        let summ2 = 2.0 * m.iter().map(|t| t * t).sum::<f64>();
        let ssumm2 = summ2.sqrt();
        let rsn = 1.0 / an.sqrt();
        let a1 = poly(&C1, rsn) - m[0] / ssumm2;
        let (i1, fac) = if n > 5 {
            let a2 = -m[1] / ssumm2 + poly(&C2, rsn);
            let fac = ((summ2 - 2.0 * m[0] * m[0] - 2.0 * m[1] * m[1])
                / (1.0 - 2.0 * a1 * a1 - 2.0 * a2 * a2))
                .sqrt();
            a[1] = a2;
            (2, fac)
        } else {
            let fac = ((summ2 - 2.0 * m[0] * m[0]) / (1.0 - 2.0 * a1 * a1)).sqrt();
            (1, fac)
        };
        a[0] = a1;
        for i in i1..nn2 {
            a[i] = -m[i] / fac;
        }
    }
    let mean = v.iter().sum::<f64>() / an;
    let ssq: f64 = v.iter().map(|t| (t - mean).powi(2)).sum();
    let num: f64 = (0..nn2).map(|i| a[i] * (v[n - 1 - i] - v[i])).sum();
    let w = (num * num / ssq).min(1.0);
    if n == 3 {
        let pi6 = 6.0 / std::f64::consts::PI;
        let stqr = (0.75f64).sqrt().asin();
        let p = (pi6 * (w.sqrt().asin() - stqr)).max(0.0);
        return Ok(ShapiroWilk { n, w, p });
    }
    let w1 = (1.0 - w).ln();
    let (m, s, y) = if n <= 11 {
        let gamma = poly(&[-2.273, 0.459], an);
        if w1 >= gamma {
            return Ok(ShapiroWilk { n, w, p: 1e-99 });
        }
        let y = -(gamma - w1).ln();
        let m = poly(&[0.544, -0.39978, 0.025054, -6.714e-4], an);
        let s = poly(&[1.3822, -0.77857, 0.062767, -0.0020322], an).exp();
        (m, s, y)
    } else {
        let xx = an.ln();
        let m = poly(&[-1.5861, -0.31082, -0.083751, 0.0038915], xx);
        let s = poly(&[-0.4803, -0.082676, 0.0030302], xx).exp();
        (m, s, w1)
    };
    let p = 1.0 - phi_cdf((y - m) / s);
    Ok(ShapiroWilk { n, w, p })
}

// ------------------------------------------------------------------ Friedman

/// Result of a Friedman-type rank test.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct RankTest {
    /// `"friedman"` or `"skillings-mack"`.
    pub method: String,
    /// The test statistic (chi-squared under the null).
    pub statistic: f64,
    /// Degrees of freedom.
    pub df: usize,
    /// p-value.
    pub p: f64,
    /// Blocks used.
    pub blocks: usize,
    /// Groups (treatments).
    pub groups: usize,
}

/// Midranks of `x` (1-based) and the sizes of tie groups.
fn midranks(x: &[f64]) -> (Vec<f64>, Vec<usize>) {
    let mut idx: Vec<usize> = (0..x.len()).collect();
    idx.sort_by(|&a, &b| x[a].total_cmp(&x[b]));
    let mut r = vec![0.0; x.len()];
    let mut ties = Vec::new();
    let mut i = 0;
    while i < idx.len() {
        let mut j = i;
        while j + 1 < idx.len() && x[idx[j + 1]] == x[idx[i]] {
            j += 1;
        }
        let rank = (i + j) as f64 / 2.0 + 1.0;
        for &t in &idx[i..=j] {
            r[t] = rank;
        }
        ties.push(j - i + 1);
        i = j + 1;
    }
    (r, ties)
}

fn chisq_sf(x: f64, df: usize) -> Result<f64> {
    let d =
        ChiSquared::new(df as f64).map_err(|e| Error::numerical("chi-squared", e.to_string()))?;
    Ok(d.sf(x.max(0.0)))
}

fn check_table(y: &[Vec<Option<f64>>], what: &str) -> Result<usize> {
    let k = y.first().map(|r| r.len()).unwrap_or(0);
    if k < 2 {
        return Err(Error::invalid(what, "need at least 2 groups"));
    }
    if y.iter().any(|r| r.len() != k) {
        return Err(Error::invalid(what, "every block needs one cell per group"));
    }
    if y.iter().flatten().flatten().any(|v| !v.is_finite()) {
        return Err(Error::invalid(what, "non-finite value"));
    }
    Ok(k)
}

/// Friedman test on complete blocks (`y[block][group]`), tie-corrected as
/// R's `friedman.test`.
pub fn friedman(y: &[Vec<f64>]) -> Result<RankTest> {
    let opt: Vec<Vec<Option<f64>>> = y
        .iter()
        .map(|r| r.iter().map(|v| Some(*v)).collect())
        .collect();
    let k = check_table(&opt, "Friedman")?;
    let n = y.len();
    if n < 2 {
        return Err(Error::invalid("Friedman", "need at least 2 blocks"));
    }
    let mut rsum = vec![0.0; k];
    let mut tie_sum = 0.0;
    for row in y {
        let (r, ties) = midranks(row);
        for (s, v) in rsum.iter_mut().zip(r) {
            *s += v;
        }
        tie_sum += ties.iter().map(|&t| (t * t * t - t) as f64).sum::<f64>();
    }
    let (nf, kf) = (n as f64, k as f64);
    let num = 12.0
        * rsum
            .iter()
            .map(|s| (s - nf * (kf + 1.0) / 2.0).powi(2))
            .sum::<f64>();
    let den = nf * kf * (kf + 1.0) - tie_sum / (kf - 1.0);
    if den <= 0.0 {
        return Err(Error::invalid("Friedman", "every block is entirely tied"));
    }
    let statistic = num / den;
    Ok(RankTest {
        method: "friedman".into(),
        statistic,
        df: k - 1,
        p: chisq_sf(statistic, k - 1)?,
        blocks: n,
        groups: k,
    })
}

/// Skillings-Mack test for incomplete blocks (`None` = missing cell).
/// Blocks with fewer than 2 observations are ignored.
pub fn skillings_mack(y: &[Vec<Option<f64>>]) -> Result<RankTest> {
    let k = check_table(y, "Skillings-Mack")?;
    let mut a = DVector::<f64>::zeros(k);
    let mut cov = DMatrix::<f64>::zeros(k, k);
    let mut used = 0;
    for row in y {
        let obs: Vec<(usize, f64)> = row
            .iter()
            .enumerate()
            .filter_map(|(j, v)| v.map(|v| (j, v)))
            .collect();
        let ki = obs.len();
        if ki < 2 {
            continue;
        }
        used += 1;
        let vals: Vec<f64> = obs.iter().map(|o| o.1).collect();
        let (r, _) = midranks(&vals);
        let kf = ki as f64;
        let scale = (12.0 / (kf + 1.0)).sqrt();
        for ((j, _), rj) in obs.iter().zip(&r) {
            a[*j] += scale * (rj - (kf + 1.0) / 2.0);
        }
        for (p, (j, _)) in obs.iter().enumerate() {
            for (q, (t, _)) in obs.iter().enumerate() {
                if p != q {
                    cov[(*j, *t)] -= 1.0;
                    cov[(*j, *j)] += 1.0;
                }
            }
        }
    }
    if used < 2 {
        return Err(Error::invalid(
            "Skillings-Mack",
            "need at least 2 blocks with 2 or more observations",
        ));
    }
    // Drop the last group: the covariance of the first k-1 is regular when
    // the design is connected.
    let sub = cov.view((0, 0), (k - 1, k - 1)).into_owned();
    let inv = sub.try_inverse().ok_or_else(|| {
        Error::numerical(
            "Skillings-Mack",
            "groups are not connected through common blocks (singular covariance)",
        )
    })?;
    let av = a.rows(0, k - 1).into_owned();
    let statistic = (av.transpose() * inv * &av)[(0, 0)];
    Ok(RankTest {
        method: "skillings-mack".into(),
        statistic,
        df: k - 1,
        p: chisq_sf(statistic, k - 1)?,
        blocks: used,
        groups: k,
    })
}

/// Friedman when every block is complete, Skillings-Mack otherwise.
pub fn friedman_blocked(y: &[Vec<Option<f64>>]) -> Result<RankTest> {
    check_table(y, "Friedman")?;
    if y.iter().all(|r| r.iter().all(Option::is_some)) {
        let full: Vec<Vec<f64>> = y
            .iter()
            .map(|r| r.iter().flatten().copied().collect())
            .collect();
        friedman(&full)
    } else {
        skillings_mack(y)
    }
}

// ------------------------------------------------------------------ multiple comparisons

/// `P(max_i |X_i| <= c)` for `m` standard normals with common correlation
/// `rho` in [0, 1): one-dimensional integral over the shared factor.
pub(crate) fn equicorrelated_normal_box(c: f64, m: usize, rho: f64) -> f64 {
    if m == 0 {
        return 1.0;
    }
    let (sr, s1) = (rho.sqrt(), (1.0 - rho).sqrt());
    let f = |t: f64| {
        let inner = phi_cdf((c - sr * t) / s1) - phi_cdf((-c - sr * t) / s1);
        phi_pdf(t) * inner.max(0.0).powi(m as i32)
    };
    simpson(f, -9.0, 9.0, 3000).clamp(0.0, 1.0)
}

/// Two-sided single-step p-value of a many-to-one z statistic among `m`
/// comparisons with correlation 0.5 (Dunnett, infinite df).
pub fn many_one_p(z: f64, m: usize) -> f64 {
    (1.0 - equicorrelated_normal_box(z.abs(), m, 0.5)).clamp(0.0, 1.0)
}

/// Two-sided critical value of the many-to-one comparison (Dunnett's table,
/// infinite df) at level `alpha` for `m` comparisons.
pub fn many_one_critical(alpha: f64, m: usize) -> f64 {
    bisect(|c| many_one_p(c, m) - alpha, 0.0, 10.0)
}

/// CDF of the studentized range of `k` normals with infinite df.
pub(crate) fn studentized_range_cdf_inf(q: f64, k: usize) -> f64 {
    if q <= 0.0 || k < 2 {
        return 0.0;
    }
    let f = |t: f64| phi_pdf(t) * (phi_cdf(t + q) - phi_cdf(t)).max(0.0).powi(k as i32 - 1);
    (k as f64 * simpson(f, -9.0, 9.0, 3000)).clamp(0.0, 1.0)
}

/// Upper-`alpha` quantile of the studentized range (infinite df).
pub fn studentized_range_quantile_inf(alpha: f64, k: usize) -> f64 {
    bisect(
        |q| (1.0 - studentized_range_cdf_inf(q, k)) - alpha,
        0.0,
        12.0,
    )
}

/// Nemenyi critical |z| for `k` groups: `q_alpha(k, inf) / sqrt 2` (the
/// thesis's 2.728 for 5 operators and 3.164 for 10 repetitions).
pub fn nemenyi_critical_z(alpha: f64, k: usize) -> f64 {
    studentized_range_quantile_inf(alpha, k) / std::f64::consts::SQRT_2
}

/// Root of a decreasing function on [lo, hi] by bisection.
fn bisect(f: impl Fn(f64) -> f64, mut lo: f64, mut hi: f64) -> f64 {
    for _ in 0..100 {
        let mid = 0.5 * (lo + hi);
        if f(mid) > 0.0 {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// One comparison of a many-to-one test.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ManyOne {
    /// Index of the group compared with group 0.
    pub group: usize,
    /// The z statistic of the comparison with group 0.
    pub z: f64,
    /// Single-step adjusted two-sided p-value.
    pub p: f64,
}

/// Nemenyi many-to-one test against group 0 (see the module docs). Blocks
/// with a missing cell are dropped.
pub fn nemenyi_many_one(y: &[Vec<Option<f64>>]) -> Result<Vec<ManyOne>> {
    let k = check_table(y, "Nemenyi")?;
    let full: Vec<Vec<f64>> = y
        .iter()
        .filter(|r| r.iter().all(Option::is_some))
        .map(|r| r.iter().flatten().copied().collect())
        .collect();
    let n = full.len();
    if n < 2 {
        return Err(Error::invalid("Nemenyi", "need at least 2 complete blocks"));
    }
    let mut rsum = vec![0.0; k];
    for row in &full {
        let (r, _) = midranks(row);
        for (s, v) in rsum.iter_mut().zip(r) {
            *s += v;
        }
    }
    let (nf, kf) = (n as f64, k as f64);
    let se = (nf * kf * (kf + 1.0) / 6.0).sqrt();
    Ok((1..k)
        .map(|j| {
            let z = (rsum[j] - rsum[0]) / se;
            ManyOne {
                group: j,
                z,
                p: many_one_p(z, k - 1),
            }
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn midranks_handle_ties() {
        let (r, t) = midranks(&[3.0, 1.0, 3.0, 2.0]);
        assert_eq!(r, vec![3.5, 1.0, 3.5, 2.0]);
        assert_eq!(t, vec![1, 1, 2]);
    }
}
