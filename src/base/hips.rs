//! Step 8b of the base builder: the femoral head centres kept as pelvis
//! markers `FH_R` / `FH_L`. The base drops the legs, but a frontal
//! radiograph is placed on the pelvis by the sacrum and the femoral heads
//! (`../shared/formats/radiograph.md`), so the patient model needs them.
//!
//! Where they come from, first found wins:
//! 1. markers of the generic model named `FH_R` / `FH_L` (any body; moved
//!    into the pelvis frame at the generic default pose);
//! 2. the hip joints: the two joints whose parent is the pelvis and whose
//!    child is a body the base does not keep; the joint centre is the
//!    parent frame's origin, the side is its Z (right positive).
//!
//! A generic model with neither keeps no femoral heads (reported; nothing
//! else needs them).

use super::topology::Topology;
use crate::error::{Error, Result};
use crate::osim::builders;
use crate::osim::model::Model;
use crate::osim::xml::Node;
use crate::osim::Document;
use nalgebra::{Point3, Vector3};

/// Names of the femoral head markers (right, left).
pub(crate) const FEMORAL_HEADS: [&str; 2] = ["FH_R", "FH_L"];

/// A femoral head centre kept in the base.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct HipCentre {
    /// `FH_R` or `FH_L`.
    pub name: String,
    /// In the pelvis frame (m).
    pub location: [f64; 3],
    /// Where it came from (`marker FH_R`, `joint hip_r`).
    pub source: String,
}

/// The femoral head centres of the generic model in the pelvis frame
/// (right, left), or none when the model has neither markers nor hip joints.
pub(crate) fn hip_centres(model: &Model, topo: &Topology, gfile: &str) -> Result<Vec<HipCentre>> {
    // 1. Markers named FH_R / FH_L, moved into the pelvis frame.
    let pelvis = topo.pose_of("pelvis", gfile)?;
    let mut from_markers = Vec::new();
    for name in FEMORAL_HEADS {
        let Some(mk) = model.markers.iter().find(|m| m.name == name) else {
            break;
        };
        let (body, x) = model.marker_frame(mk)?;
        let pose = topo.pose_of(&body, gfile)?;
        let p = pelvis.inverse() * pose * x * Point3::from(mk.location);
        from_markers.push(HipCentre {
            name: name.into(),
            location: [p.x, p.y, p.z],
            source: format!("marker {name}"),
        });
    }
    if from_markers.len() == 2 {
        return Ok(from_markers);
    }
    // 2. The pelvis' joints to bodies the base drops: exactly one per side.
    let legs: Vec<(&str, Vector3<f64>)> = topo
        .frames
        .iter()
        .filter(|f| f.parent_body == "pelvis" && !topo.kept_set.contains(&f.child_body))
        .map(|f| (f.joint.as_str(), f.parent_in_body.translation.vector))
        .collect();
    let right: Vec<_> = legs.iter().filter(|(_, v)| v.z > 0.0).collect();
    let left: Vec<_> = legs.iter().filter(|(_, v)| v.z < 0.0).collect();
    match (right.as_slice(), left.as_slice()) {
        ([(jr, r)], [(jl, l)]) => Ok(vec![
            HipCentre {
                name: FEMORAL_HEADS[0].into(),
                location: [r.x, r.y, r.z],
                source: format!("joint {jr}"),
            },
            HipCentre {
                name: FEMORAL_HEADS[1].into(),
                location: [l.x, l.y, l.z],
                source: format!("joint {jl}"),
            },
        ]),
        ([], []) => Ok(Vec::new()),
        _ => Err(Error::invalid(
            gfile,
            format!(
                "cannot tell the hip joints apart: the pelvis has {} child joint(s) to dropped bodies on the right and {} on the left (expected one each; or name the femoral head centres with markers FH_R and FH_L)",
                right.len(),
                left.len()
            ),
        )),
    }
}

/// Add the femoral head markers to the pelvis of `doc`.
pub(crate) fn add_hip_markers(doc: &mut Document, hips: &[HipCentre]) {
    let els = hips.iter().map(|h| {
        Node::Element(builders::marker(
            &h.name,
            "/bodyset/pelvis",
            &Vector3::from(h.location),
            true,
        ))
    });
    doc.set_objects_mut("MarkerSet").children.extend(els);
}
