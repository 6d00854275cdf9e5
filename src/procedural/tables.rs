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
    /// Sacral slope, pelvic tilt and pelvic radius.
    pub pelvis: PelvisAlignment,
    /// Lumbar lordosis and its split over the lumbar segments.
    pub lumbar: LumbarAlignment,
    /// Thoracic kyphosis and the upper-thoracic and thoracolumbar segment angles.
    pub thoracic: ThoracicAlignment,
}

/// `[pelvis]` of `alignment.toml`.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PelvisAlignment {
    /// Angle of the S1 superior endplate to the horizontal (deg).
    pub sacral_slope_deg: f64,
    /// Angle of the hip axis to S1 endplate centre line from the vertical (deg).
    pub pelvic_tilt_deg: f64,
    /// Hip axis to S1 endplate distance at the reference stature (m; scaled with stature).
    pub pelvic_radius_m: f64,
}

/// `[lumbar]` of `alignment.toml`.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct LumbarAlignment {
    /// Cobb angle from the L1 to the S1 superior endplate (deg).
    pub lordosis_l1_s1_deg: f64,
    /// Relative weights splitting the lordosis over L1-L2 .. L5-S1.
    pub segment_weights: [f64; 5],
}

/// `[thoracic]` of `alignment.toml`.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ThoracicAlignment {
    /// Cobb angle from the T4 superior to the T12 inferior endplate (deg).
    pub kyphosis_t4_t12_deg: f64,
    /// Segment angle of T1-T2 .. T3-T4 as a fraction of the mean T4-T12 segment angle.
    pub upper_fraction_of_mean: f64,
    /// Segment angle of T12-L1 (deg).
    pub thoracolumbar_deg: f64,
}

/// `segments.toml`.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub(crate) struct Segments {
    pub(crate) male: SexSegments,
    pub(crate) female: SexSegments,
    pub(crate) torso: Torso,
}

#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub(crate) struct SexSegments {
    pub(crate) bmi_ref: f64,
    pub(crate) upt_mass_frac: f64,
    pub(crate) mpt_mass_frac: f64,
    pub(crate) lpt_mass_frac: f64,
    pub(crate) lpt_length_m: f64,
    pub(crate) ref_stature_m: f64,
}

#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub(crate) struct Torso {
    pub(crate) thoracic_breadth_m: f64,
    pub(crate) thoracic_depth_m: f64,
    pub(crate) lumbar_breadth_m: f64,
    pub(crate) lumbar_depth_m: f64,
    pub(crate) pelvis_breadth_m: f64,
    pub(crate) pelvis_depth_m: f64,
    pub(crate) thoracic_com_anterior_m: f64,
    pub(crate) lumbar_com_anterior_m: f64,
    pub(crate) pelvis_com_anterior_m: f64,
    pub(crate) pelvis_com_below_m: f64,
    pub(crate) sacrum_nominal_mass_kg: f64,
}

/// `muscles.toml`.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub(crate) struct Muscles {
    pub(crate) specific_tension_n_per_cm2: f64,
    pub(crate) norm_fiber_length_default: f64,
    pub(crate) class: String,
    pub(crate) family: Vec<Family>,
}

/// One muscle family's fascicle rule (see the file's header).
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub(crate) struct Family {
    pub(crate) name: String,
    pub(crate) prefix: String,
    pub(crate) pcsa_cm2: f64,
    pub(crate) tendon_fraction: f64,
    pub(crate) origins: Vec<String>,
    pub(crate) origin: String,
    #[serde(default)]
    pub(crate) spans: Vec<usize>,
    #[serde(default)]
    pub(crate) insertion: Option<String>,
    #[serde(default)]
    pub(crate) sacral_insertion: Option<String>,
    #[serde(default)]
    pub(crate) sacral_target: Option<String>,
    #[serde(default)]
    pub(crate) pelvis_insertion: Option<String>,
    #[serde(default)]
    pub(crate) pelvis_via: Option<String>,
    #[serde(default)]
    pub(crate) via: Option<String>,
    #[serde(default)]
    pub(crate) via_stride: Option<usize>,
}

/// `procedural_shape.toml`.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub(crate) struct Shape {
    pub(crate) reference_stature_m: f64,
    pub(crate) default_stature_male_m: f64,
    pub(crate) default_stature_female_m: f64,
    pub(crate) min_stature_m: f64,
    pub(crate) max_stature_m: f64,
    pub(crate) body: BodyShape,
    pub(crate) posterior: PosteriorShape,
    pub(crate) sacrum: SacrumShape,
    pub(crate) pelvis: PelvisShape,
}

#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub(crate) struct BodyShape {
    pub(crate) around: usize,
    pub(crate) rings: usize,
    pub(crate) waist: f64,
    pub(crate) posterior_exponent: f64,
}

#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub(crate) struct PosteriorShape {
    pub(crate) gap_m: f64,
    pub(crate) around: usize,
    pub(crate) pedicle_length_frac_canal_depth: f64,
    pub(crate) pedicle_centre_frac_body: f64,
    pub(crate) lamina_thickness_frac_canal_depth: f64,
    pub(crate) lamina_height_frac_body: f64,
    pub(crate) lamina_centre_frac_body: f64,
    pub(crate) spinous_thickness_frac_canal_depth: f64,
    pub(crate) spinous_root_height_frac_body: f64,
    pub(crate) spinous_tip_height_frac_body: f64,
    pub(crate) transverse_height_frac_pedicle: f64,
    pub(crate) transverse_depth_frac_pedicle: f64,
    pub(crate) facet_height_frac_body: f64,
    pub(crate) facet_size_frac_canal_depth: f64,
    pub(crate) facet_thickness_frac_canal_depth: f64,
    pub(crate) spinous_inclination_deg: [f64; 17],
    pub(crate) transverse_dorsal_deg: [f64; 17],
    pub(crate) transverse_cranial_deg: [f64; 17],
}

#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub(crate) struct SacrumShape {
    pub(crate) length_m: f64,
    pub(crate) alar_width_m: f64,
    pub(crate) thickness_m: f64,
    pub(crate) tip_width_m: f64,
    pub(crate) tip_thickness_m: f64,
    pub(crate) curvature_deg: f64,
    pub(crate) around: usize,
    pub(crate) rings: usize,
}

#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub(crate) struct PelvisShape {
    pub(crate) inter_asis_male_m: f64,
    pub(crate) inter_asis_female_m: f64,
    pub(crate) hjc_posterior: f64,
    pub(crate) hjc_inferior: f64,
    pub(crate) hjc_lateral: f64,
    pub(crate) psis: [f64; 3],
    pub(crate) iliac_crest_posterior: [f64; 3],
    pub(crate) iliac_crest_mid: [f64; 3],
    pub(crate) iliac_crest_anterior: [f64; 3],
    pub(crate) pelvic_brim: [f64; 3],
    pub(crate) lesser_trochanter_proxy: [f64; 3],
    pub(crate) pubic_symphysis: [f64; 3],
    pub(crate) ilium_blade_height: f64,
    pub(crate) ilium_thickness_m: f64,
    pub(crate) ramus_diameter_m: f64,
    pub(crate) around: usize,
}

/// All procedural templates.
#[derive(Debug, Clone, PartialEq)]
pub struct Templates {
    /// `alignment.toml`: the sagittal alignment.
    pub alignment: Alignment,
    /// `segments.toml`: segment mass fractions and trunk dimensions.
    pub(crate) segments: Segments,
    /// `muscles.toml`: the muscle families.
    pub(crate) muscles: Muscles,
    /// `procedural_shape.toml`: vertebra, sacrum and pelvis shape parameters.
    pub(crate) shape: Shape,
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
