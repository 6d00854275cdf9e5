//! The procedural templates (`templates/alignment.toml`, `segments.toml`,
//! `muscles.toml`, `procedural_shape.toml`), embedded at compile time and
//! parsed into typed tables. Each file carries its citations per value;
//! values here are exactly as written there (degrees, metres, cm^2).

use crate::error::{Error, Result};
use serde::Deserialize;
use std::path::Path;

/// Embedded template texts (name, text).
const ALIGNMENT_TOML: &str = include_str!("../../templates/alignment.toml");
const SEGMENTS_TOML: &str = include_str!("../../templates/segments.toml");
const MUSCLES_TOML: &str = include_str!("../../templates/muscles.toml");
const SHAPE_TOML: &str = include_str!("../../templates/procedural_shape.toml");

/// `alignment.toml`.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Alignment {
    pub pelvis: PelvisAlignment,
    pub lumbar: LumbarAlignment,
    pub thoracic: ThoracicAlignment,
}

#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PelvisAlignment {
    pub sacral_slope_deg: f64,
    pub pelvic_tilt_deg: f64,
    pub pelvic_radius_m: f64,
}

#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct LumbarAlignment {
    pub lordosis_l1_s1_deg: f64,
    pub segment_weights: [f64; 5],
}

#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ThoracicAlignment {
    pub kyphosis_t4_t12_deg: f64,
    pub upper_fraction_of_mean: f64,
    pub thoracolumbar_deg: f64,
}

/// `segments.toml`.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Segments {
    pub male: SexSegments,
    pub female: SexSegments,
    pub torso: Torso,
}

#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SexSegments {
    pub bmi_ref: f64,
    pub upt_mass_frac: f64,
    pub mpt_mass_frac: f64,
    pub lpt_mass_frac: f64,
    pub lpt_length_m: f64,
    pub ref_stature_m: f64,
}

#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Torso {
    pub thoracic_breadth_m: f64,
    pub thoracic_depth_m: f64,
    pub lumbar_breadth_m: f64,
    pub lumbar_depth_m: f64,
    pub pelvis_breadth_m: f64,
    pub pelvis_depth_m: f64,
    pub thoracic_com_anterior_m: f64,
    pub lumbar_com_anterior_m: f64,
    pub pelvis_com_anterior_m: f64,
    pub pelvis_com_below_m: f64,
    pub sacrum_nominal_mass_kg: f64,
}

/// `muscles.toml`.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Muscles {
    pub specific_tension_n_per_cm2: f64,
    pub norm_fiber_length_default: f64,
    pub class: String,
    pub family: Vec<Family>,
}

/// One muscle family's fascicle rule (see the file's header).
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Family {
    pub name: String,
    pub prefix: String,
    pub pcsa_cm2: f64,
    pub tendon_fraction: f64,
    pub origins: Vec<String>,
    pub origin: String,
    #[serde(default)]
    pub spans: Vec<usize>,
    #[serde(default)]
    pub insertion: Option<String>,
    #[serde(default)]
    pub sacral_insertion: Option<String>,
    #[serde(default)]
    pub sacral_target: Option<String>,
    #[serde(default)]
    pub pelvis_insertion: Option<String>,
    #[serde(default)]
    pub pelvis_via: Option<String>,
    #[serde(default)]
    pub via: Option<String>,
    #[serde(default)]
    pub via_stride: Option<usize>,
}

/// `procedural_shape.toml`.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Shape {
    pub reference_stature_m: f64,
    pub default_stature_male_m: f64,
    pub default_stature_female_m: f64,
    pub min_stature_m: f64,
    pub max_stature_m: f64,
    pub body: BodyShape,
    pub posterior: PosteriorShape,
    pub sacrum: SacrumShape,
    pub pelvis: PelvisShape,
}

#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct BodyShape {
    pub around: usize,
    pub rings: usize,
    pub waist: f64,
    pub posterior_exponent: f64,
}

#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PosteriorShape {
    pub gap_m: f64,
    pub around: usize,
    pub pedicle_length_frac_canal_depth: f64,
    pub pedicle_centre_frac_body: f64,
    pub lamina_thickness_frac_canal_depth: f64,
    pub lamina_height_frac_body: f64,
    pub lamina_centre_frac_body: f64,
    pub spinous_thickness_frac_canal_depth: f64,
    pub spinous_root_height_frac_body: f64,
    pub spinous_tip_height_frac_body: f64,
    pub transverse_height_frac_pedicle: f64,
    pub transverse_depth_frac_pedicle: f64,
    pub facet_height_frac_body: f64,
    pub facet_size_frac_canal_depth: f64,
    pub facet_thickness_frac_canal_depth: f64,
    pub spinous_inclination_deg: [f64; 17],
    pub transverse_dorsal_deg: [f64; 17],
    pub transverse_cranial_deg: [f64; 17],
}

#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SacrumShape {
    pub length_m: f64,
    pub alar_width_m: f64,
    pub thickness_m: f64,
    pub tip_width_m: f64,
    pub tip_thickness_m: f64,
    pub curvature_deg: f64,
    pub around: usize,
    pub rings: usize,
}

#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PelvisShape {
    pub inter_asis_male_m: f64,
    pub inter_asis_female_m: f64,
    pub hjc_posterior: f64,
    pub hjc_inferior: f64,
    pub hjc_lateral: f64,
    pub psis: [f64; 3],
    pub iliac_crest_posterior: [f64; 3],
    pub iliac_crest_mid: [f64; 3],
    pub iliac_crest_anterior: [f64; 3],
    pub pelvic_brim: [f64; 3],
    pub lesser_trochanter_proxy: [f64; 3],
    pub pubic_symphysis: [f64; 3],
    pub ilium_blade_height: f64,
    pub ilium_thickness_m: f64,
    pub ramus_diameter_m: f64,
    pub around: usize,
}

/// All procedural templates.
#[derive(Debug, Clone, PartialEq)]
pub struct Templates {
    pub alignment: Alignment,
    pub segments: Segments,
    pub muscles: Muscles,
    pub shape: Shape,
}

fn parse<T: serde::de::DeserializeOwned>(text: &str, name: &str) -> Result<T> {
    toml::from_str(text).map_err(|e| {
        let loc = e
            .span()
            .map(|s| {
                format!(
                    "line {}",
                    text[..s.start.min(text.len())].lines().count().max(1)
                )
            })
            .unwrap_or_else(|| "document".into());
        Error::parse(Path::new(name), loc, e.message().to_string())
    })
}

impl Templates {
    /// The templates shipped with the crate (a unit test parses them).
    pub fn embedded() -> Result<Templates> {
        let t = Templates {
            alignment: parse(ALIGNMENT_TOML, "templates/alignment.toml")?,
            segments: parse(SEGMENTS_TOML, "templates/segments.toml")?,
            muscles: parse(MUSCLES_TOML, "templates/muscles.toml")?,
            shape: parse(SHAPE_TOML, "templates/procedural_shape.toml")?,
        };
        t.validate()?;
        Ok(t)
    }

    /// Range checks that the generator relies on.
    fn validate(&self) -> Result<()> {
        let bad = |file: &str, what: &str| {
            Err(Error::parse(
                Path::new(file),
                what.to_string(),
                "value out of its plausible range",
            ))
        };
        let s = &self.shape;
        if !(s.reference_stature_m > 1.0 && s.min_stature_m < s.max_stature_m) {
            return bad("templates/procedural_shape.toml", "reference_stature_m");
        }
        if s.body.around < 8 || s.body.rings < 3 || s.posterior.around < 6 {
            return bad("templates/procedural_shape.toml", "around/rings");
        }
        let a = &self.alignment;
        if a.lumbar.segment_weights.iter().any(|w| *w <= 0.0) {
            return bad("templates/alignment.toml", "lumbar.segment_weights");
        }
        for f in &self.muscles.family {
            if !(f.pcsa_cm2 > 0.0 && (0.0..0.9).contains(&f.tendon_fraction)) {
                return bad("templates/muscles.toml", &format!("family {}", f.prefix));
            }
        }
        if !(self.muscles.norm_fiber_length_default > 0.5
            && self.muscles.norm_fiber_length_default < 1.5)
        {
            return bad("templates/muscles.toml", "norm_fiber_length_default");
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn embedded_templates_parse() {
        let t = Templates::embedded().unwrap();
        assert!(t.muscles.family.len() >= 5);
        assert!((t.alignment.pelvis.sacral_slope_deg - 41.2).abs() < 1e-12);
    }

    #[test]
    fn malformed_template_names_file_and_line() {
        let text = ALIGNMENT_TOML.replace("sacral_slope_deg = 41.2", "sacral_slope_deg = \"x\"");
        let e = parse::<Alignment>(&text, "templates/alignment.toml").unwrap_err();
        let s = e.to_string();
        assert!(s.contains("alignment.toml") && s.contains("line"), "{s}");
    }
}
