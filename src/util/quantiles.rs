//! The crate's one quantile helper (R's default, type 7) and the median and
//! interquartile range built on it. Every median, quartile and percentile of
//! the reports goes through [`quantile`]; empty input or a NaN gives `None`.

/// Quantile of `x` at probability `p` (R's default, type 7: linear
/// interpolation between order statistics, `p` clamped to [0, 1]; `x` need
/// not be sorted). `None` when `x` is empty or holds a NaN.
pub fn quantile(x: &[f64], p: f64) -> Option<f64> {
    if x.is_empty() || x.iter().any(|v| v.is_nan()) {
        return None;
    }
    let mut v = x.to_vec();
    v.sort_by(f64::total_cmp);
    let h = (v.len() - 1) as f64 * p.clamp(0.0, 1.0);
    let lo = h.floor() as usize;
    let hi = h.ceil() as usize;
    Some(v[lo] + (h - lo as f64) * (v[hi] - v[lo]))
}

/// Median (type 7); `None` when empty or holding a NaN.
pub fn median(x: &[f64]) -> Option<f64> {
    quantile(x, 0.5)
}

/// Interquartile range (R's `IQR`, type 7); `None` when empty or holding a NaN.
pub fn iqr(x: &[f64]) -> Option<f64> {
    Some(quantile(x, 0.75)? - quantile(x, 0.25)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_match_r_type_7() {
        // R: quantile(c(1, 2, 4, 7, 11), c(.25, .5, .75)) -> 2 4 7; IQR = 5
        let x = [7.0, 1.0, 11.0, 2.0, 4.0];
        assert_eq!(quantile(&x, 0.25), Some(2.0));
        assert_eq!(median(&x), Some(4.0));
        assert_eq!(iqr(&x), Some(5.0));
        // Interpolated: quantile(1:4, .25) = 1.75; median of an even count
        // halfway between the middle values.
        assert_eq!(quantile(&[1.0, 2.0, 3.0, 4.0], 0.25), Some(1.75));
        assert_eq!(median(&[4.0, 1.0, 3.0, 2.0]), Some(2.5));
        // Ends: the minimum and maximum.
        assert_eq!(quantile(&x, 0.0), Some(1.0));
        assert_eq!(quantile(&x, 1.0), Some(11.0));
    }

    #[test]
    fn empty_or_nan_input_has_no_quantile() {
        assert_eq!(median(&[]), None);
        assert_eq!(iqr(&[]), None);
        assert_eq!(quantile(&[1.0, f64::NAN, 3.0], 0.5), None);
    }
}
