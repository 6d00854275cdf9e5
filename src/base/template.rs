//! The intervertebral-joint parameter template (`templates/ivd_defaults.toml`,
//! thesis Table 5.1): bushing stiffness and damping per axis and the
//! coordinate ranges of the rebuilt 6-DoF joints. The default file is
//! embedded at compile time; [`IvdParams::from_toml`] reads a user copy.

use crate::error::{Error, Result};
use nalgebra::Vector3;
use serde::Deserialize;
use std::path::Path;

/// The embedded default template.
pub(crate) const EMBEDDED_TOML: &str = include_str!("../../templates/ivd_defaults.toml");

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Trans {
    ap: f64,
    si: f64,
    ml: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Rot {
    lb: f64,
    ar: f64,
    fe: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Ranges {
    rotation_rad: [f64; 2],
    translation_m: [f64; 2],
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    translational_stiffness_n_per_m: Trans,
    rotational_stiffness_nm_per_rad: Rot,
    translational_damping_n_s_per_m: Trans,
    rotational_damping_nm_s_per_rad: Rot,
    ranges: Ranges,
}

/// Bushing parameters and coordinate ranges of every rebuilt IVD joint, on
/// the joint-frame axes X (AP / LB), Y (SI / AR), Z (ML / FE).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct IvdParams {
    /// N/m along X, Y, Z (AP, SI, ML).
    pub translational_stiffness: Vector3<f64>,
    /// Nm/rad about X, Y, Z (LB, AR, FE).
    pub rotational_stiffness: Vector3<f64>,
    /// N/(m/s) along X, Y, Z.
    pub translational_damping: Vector3<f64>,
    /// Nm/(rad/s) about X, Y, Z.
    pub rotational_damping: Vector3<f64>,
    /// Range of the rotational coordinates (rad).
    pub rotation_range: [f64; 2],
    /// Range of the translational coordinates (m).
    pub translation_range: [f64; 2],
}

impl IvdParams {
    /// The embedded defaults (thesis Table 5.1).
    pub fn defaults() -> IvdParams {
        // The embedded file is checked by a unit test; a parse failure here
        // is a build defect, not a user-input error.
        IvdParams::from_toml(EMBEDDED_TOML, Path::new("templates/ivd_defaults.toml"))
            .expect("embedded templates/ivd_defaults.toml is valid")
    }

    /// Read a template file.
    pub fn read(path: &Path) -> Result<IvdParams> {
        let text = crate::util::read_text_capped(
            path,
            crate::util::input::MAX_TABLE_BYTES,
            "template files",
        )?;
        IvdParams::from_toml(&text, path)
    }

    /// Parse template text; `path` names it in errors.
    pub(crate) fn from_toml(text: &str, path: &Path) -> Result<IvdParams> {
        let f: File = toml::from_str(text)
            .map_err(|e| Error::parse(path, "TOML", e.to_string().trim().to_string()))?;
        let t = |v: &Trans| Vector3::new(v.ap, v.si, v.ml);
        let r = |v: &Rot| Vector3::new(v.lb, v.ar, v.fe);
        let p = IvdParams {
            translational_stiffness: t(&f.translational_stiffness_n_per_m),
            rotational_stiffness: r(&f.rotational_stiffness_nm_per_rad),
            translational_damping: t(&f.translational_damping_n_s_per_m),
            rotational_damping: r(&f.rotational_damping_nm_s_per_rad),
            rotation_range: f.ranges.rotation_rad,
            translation_range: f.ranges.translation_m,
        };
        let groups = [
            ("translational_stiffness_n_per_m", p.translational_stiffness),
            ("rotational_stiffness_nm_per_rad", p.rotational_stiffness),
            ("translational_damping_n_s_per_m", p.translational_damping),
            ("rotational_damping_nm_s_per_rad", p.rotational_damping),
        ];
        for (name, v) in groups {
            if v.iter().any(|x| !x.is_finite() || *x < 0.0) {
                return Err(Error::parse(
                    path,
                    format!("[{name}]"),
                    "values must be finite and non-negative",
                ));
            }
        }
        if p.translational_stiffness.min() <= 0.0 || p.rotational_stiffness.min() <= 0.0 {
            return Err(Error::parse(
                path,
                "stiffness",
                "stiffness must be positive on every axis (a zero stiffness leaves the joint free)",
            ));
        }
        for (name, r) in [
            ("ranges.rotation_rad", p.rotation_range),
            ("ranges.translation_m", p.translation_range),
        ] {
            if !(r[0].is_finite() && r[1].is_finite() && r[0] < 0.0 && r[1] > 0.0) {
                return Err(Error::parse(
                    path,
                    name,
                    "range must be [min, max] with min < 0 < max",
                ));
            }
        }
        Ok(p)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn embedded_template_is_table_5_1() {
        let p = IvdParams::defaults();
        // Thesis Table 5.1 (AP, SI, ML translation; LB, AR, FE rotation).
        assert_eq!(
            p.translational_stiffness,
            Vector3::new(149_000.0, 1_890_000.0, 135_000.0)
        );
        assert_eq!(p.rotational_stiffness, Vector3::new(68.8, 291.0, 51.0));
        assert_eq!(p.translational_damping, Vector3::repeat(1000.0));
        assert_eq!(p.rotational_damping, Vector3::repeat(2.3));
    }

    #[test]
    fn bad_templates_are_refused() {
        let f = Path::new("t.toml");
        let bad_key = EMBEDDED_TOML.replace("ap = 149000.0", "apx = 149000.0");
        assert!(IvdParams::from_toml(&bad_key, f).is_err());
        let neg = EMBEDDED_TOML.replace("fe = 51.0", "fe = -51.0");
        let e = IvdParams::from_toml(&neg, f).unwrap_err().to_string();
        assert!(e.contains("non-negative"), "{e}");
        let zero = EMBEDDED_TOML.replace("fe = 51.0", "fe = 0.0");
        assert!(IvdParams::from_toml(&zero, f).is_err());
    }
}
