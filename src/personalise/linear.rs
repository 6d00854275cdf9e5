//! Writing linear (OpenSim `BushingForce`) stiffness values into a model
//! document: the minimal writer calibration needs until the general
//! stiffness-form writer of `osim-spine stiffness` covers it.

use crate::error::{Error, Result};
use crate::osim::document::set_vec3;
use crate::osim::Document;
use nalgebra::Vector3;

/// Set `rotational_stiffness` (N*m/rad about X, Y, Z) and
/// `translational_stiffness` (N/m along X, Y, Z) of the named
/// `BushingForce`s of `doc`'s ForceSet. Every name must be a BushingForce
/// and every value finite and >= 0; on error `doc` is unchanged.
pub fn set_linear_bushing_stiffness(
    doc: &mut Document,
    values: &[(String, [f64; 6])],
) -> Result<()> {
    for (name, k) in values {
        let ctx = || format!("{}: BushingForce '{name}'", doc.path().display());
        match doc.component("ForceSet", name) {
            Some(e) if e.name == "BushingForce" => {}
            Some(e) => {
                return Err(Error::invalid(
                    ctx(),
                    format!("is a {}, not a linear BushingForce", e.name),
                ))
            }
            None => return Err(Error::invalid(ctx(), "no such force in the ForceSet")),
        }
        if !k.iter().all(|v| v.is_finite() && *v >= 0.0) {
            return Err(Error::invalid(
                ctx(),
                format!("stiffness must be finite and >= 0, got {k:?}"),
            ));
        }
    }
    for (name, k) in values {
        if let Some(e) = doc.component_mut("ForceSet", name) {
            set_vec3(e, "rotational_stiffness", &Vector3::new(k[0], k[1], k[2]));
            set_vec3(
                e,
                "translational_stiffness",
                &Vector3::new(k[3], k[4], k[5]),
            );
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_and_reads_back_through_the_model_reader() {
        let Some(p) = ["../shared/diagnose-dev/dev-07/specimen.osim"]
            .iter()
            .map(std::path::Path::new)
            .find(|p| p.exists())
        else {
            eprintln!("SKIP: ../shared/diagnose-dev not found");
            return;
        };
        let mut doc = Document::read(p).unwrap();
        let k = [11.5, 222.25, 33.0, 1.0e5, 2.0e6, 3.5e5];
        set_linear_bushing_stiffness(&mut doc, &[("L4_L5_bushing".into(), k)]).unwrap();
        let back = Document::parse(&doc.to_xml_string(), p)
            .unwrap()
            .model()
            .unwrap();
        let b = back.bushings().find(|b| b.name == "L4_L5_bushing").unwrap();
        assert_eq!(b.rotational_stiffness, Vector3::new(k[0], k[1], k[2]));
        assert_eq!(b.translational_stiffness, Vector3::new(k[3], k[4], k[5]));
        let other = back.bushings().find(|b| b.name == "L5_S1_bushing").unwrap();
        assert_eq!(other.rotational_stiffness, Vector3::new(68.8, 291.0, 51.0));
        let before = doc.to_xml_string();
        let e = set_linear_bushing_stiffness(
            &mut doc,
            &[
                ("L4_L5_bushing".into(), [1.0; 6]),
                ("nope".into(), [1.0; 6]),
            ],
        )
        .unwrap_err();
        assert!(e.to_string().contains("nope"), "{e}");
        assert_eq!(before, doc.to_xml_string(), "document changed on error");
    }
}
