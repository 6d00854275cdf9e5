//! JSON reports at a stated precision. Reports are for people and for
//! byte-identical regeneration: full-precision solver figures (equilibrium
//! coordinates, residuals at round-off level) would change in their last
//! bits with any harmless change of the solver's arithmetic. Model files
//! (.osim) keep full precision; only reports go through here.
//!
//! Rules, by the name of the number's nearest object key (array elements
//! take their array's key):
//! * a key containing `residual` (a solver residual, N or N m): 3
//!   significant digits, and anything below [`RESIDUAL_FLOOR`] reads 0;
//! * a key ending in `_mm` (millimetres): 0.001 mm;
//! * anything else (SI: m, rad, N, and dimensionless factors): 1e-6;
//!   magnitudes of 1e9 and above (stiffnesses) are kept as they are.
//!
//! Integers are never touched and `-0` is written as `0`. The rounding
//! works on serde_json's own text, so key order and layout stay those of
//! the serialised struct.

use serde::Serialize;

/// Residuals below this (N or N m) are reported as 0: they are round-off.
const RESIDUAL_FLOOR: f64 = 1e-9;

/// Round `x` to `decimals` decimal places (the f64 nearest to that decimal);
/// values too large for that grid are returned as they are.
fn round_decimals(x: f64, decimals: i32) -> f64 {
    let p = 10f64.powi(decimals);
    let scaled = x * p;
    if !scaled.is_finite() || scaled.abs() >= 2f64.powi(52) {
        return x;
    }
    scaled.round() / p
}

/// Round to `digits` significant digits (through decimal formatting, so the
/// result is the f64 nearest to that decimal).
fn round_sig(x: f64, digits: usize) -> f64 {
    if x == 0.0 || !x.is_finite() {
        return x;
    }
    format!("{:.*e}", digits.saturating_sub(1), x)
        .parse()
        .unwrap_or(x)
}

/// The reported value of a number found under key `key`.
fn round_number(key: &str, x: f64) -> f64 {
    let r = if key.contains("residual") {
        if x.abs() < RESIDUAL_FLOOR {
            0.0
        } else {
            round_sig(x, 3)
        }
    } else if key.ends_with("_mm") {
        round_decimals(x, 3)
    } else if x.abs() >= 1e9 {
        x
    } else {
        round_decimals(x, 6)
    };
    // -0 -> 0
    r + 0.0
}

/// Round every float (a number token with a fraction or exponent) of the
/// JSON text `json` by the rules of the module; everything else is copied
/// unchanged.
fn round_json_text(json: &str) -> String {
    let b = json.as_bytes();
    let mut out = String::with_capacity(json.len());
    let mut stack: Vec<String> = Vec::new();
    let mut key = String::new();
    let mut last_string = String::new();
    let mut i = 0;
    while i < b.len() {
        match b[i] {
            b'"' => {
                let mut j = i + 1;
                while j < b.len() && b[j] != b'"' {
                    j += if b[j] == b'\\' { 2 } else { 1 };
                }
                let end = (j + 1).min(b.len());
                let lit = json.get(i..end).unwrap_or("");
                out.push_str(lit);
                last_string = serde_json::from_str::<String>(lit).unwrap_or_default();
                i = end;
            }
            b':' => {
                key = last_string.clone();
                out.push(':');
                i += 1;
            }
            c @ (b'{' | b'[') => {
                stack.push(key.clone());
                out.push(c as char);
                i += 1;
            }
            c @ (b'}' | b']') => {
                key = stack.pop().unwrap_or_default();
                out.push(c as char);
                i += 1;
            }
            b'-' | b'0'..=b'9' => {
                let mut j = i;
                while j < b.len() && matches!(b[j], b'0'..=b'9' | b'-' | b'+' | b'.' | b'e' | b'E')
                {
                    j += 1;
                }
                let tok = json.get(i..j).unwrap_or("");
                let is_float = tok.bytes().any(|c| matches!(c, b'.' | b'e' | b'E'));
                match tok.parse::<f64>() {
                    Ok(x) if is_float => {
                        let r = round_number(&key, x);
                        out.push_str(&serde_json::to_string(&r).unwrap_or_else(|_| tok.into()));
                    }
                    _ => out.push_str(tok),
                }
                i = j;
            }
            _ => {
                // Outside strings serde_json writes ASCII only.
                let next = json[i..].chars().next().map(char::len_utf8).unwrap_or(1);
                out.push_str(json.get(i..i + next).unwrap_or(""));
                i += next;
            }
        }
    }
    out
}

/// Serialise `x` as pretty JSON with every float rounded by the rules of
/// the module (field order as in the struct).
pub fn to_json_pretty<T: Serialize>(x: &T) -> serde_json::Result<String> {
    Ok(round_json_text(&serde_json::to_string_pretty(x)?))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Serialize)]
    struct Eq {
        iterations: usize,
        residual_norm: f64,
        max_displacement: f64,
        note: String,
        coordinates: std::collections::BTreeMap<String, f64>,
        depth_mm: Vec<f64>,
        stiffness: f64,
    }

    #[test]
    fn rules_by_key() {
        // residuals: 3 significant digits, round-off reads 0
        assert_eq!(round_number("residual_norm", 7.105427357601002e-14), 0.0);
        assert_eq!(round_number("residual_norm", 1.23456e-3), 1.23e-3);
        // millimetres to 1 um, SI to 1e-6
        assert_eq!(round_number("rms_mm", 0.123456789), 0.123);
        assert_eq!(
            round_number("max_displacement", 0.11017486136016777),
            0.110175
        );
        assert_eq!(round_number("x", -6.39263375474011e-05), -6.4e-5);
        assert_eq!(round_number("x", -1e-9).to_bits(), 0f64.to_bits());
        // large values are not put on a grid they cannot hold
        assert_eq!(round_number("k", 1.2345678912345e12), 1.2345678912345e12);
        // the error is at most half a step
        for k in 0..1000 {
            let x = (k as f64 * 0.7316).sin() * 0.3;
            assert!((round_number("q", x) - x).abs() <= 0.5e-6 + 1e-15);
        }
    }

    #[test]
    fn text_keeps_layout_order_integers_and_strings() {
        let e = Eq {
            iterations: 7,
            residual_norm: 2.0e-14,
            max_displacement: 0.11017486136016777,
            note: "keep 0.123456789 and \"1.5e-3\": as is".into(),
            coordinates: [("b".to_string(), -0.0514424112679), ("a".to_string(), 3.0)]
                .into_iter()
                .collect(),
            depth_mm: vec![1.23456, -0.0001],
            stiffness: 1.5e6,
        };
        let full = serde_json::to_string_pretty(&e).unwrap();
        let r = to_json_pretty(&e).unwrap();
        // same layout line by line, only numbers differ
        assert_eq!(full.lines().count(), r.lines().count());
        let v: serde_json::Value = serde_json::from_str(&r).unwrap();
        assert_eq!(v["iterations"], 7);
        assert_eq!(v["residual_norm"], 0.0);
        assert_eq!(v["max_displacement"], 0.110175);
        assert_eq!(v["note"], "keep 0.123456789 and \"1.5e-3\": as is");
        assert_eq!(v["coordinates"]["b"], -0.051442);
        assert_eq!(v["coordinates"]["a"], 3.0);
        assert_eq!(v["depth_mm"][0], 1.235);
        assert_eq!(v["depth_mm"][1], 0.0);
        assert_eq!(v["stiffness"], 1.5e6);
        let keys: Vec<&str> = r
            .lines()
            .filter_map(|l| l.trim().strip_prefix('"')?.split('"').next())
            .collect();
        assert_eq!(
            &keys[..5],
            [
                "iterations",
                "residual_norm",
                "max_displacement",
                "note",
                "coordinates"
            ]
        );
        assert!(!r.contains("-0.0,") && !r.contains("-0.0\n"));
        // idempotent
        assert_eq!(round_json_text(&r), r);
    }
}
