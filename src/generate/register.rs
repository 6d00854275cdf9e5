//! Step 1, the common reference: the base model's markers per level and the
//! rigid sacral registration of the patient's landmarks onto them.

use super::pose::Points;
use super::Registration;
use crate::error::{Error, Result};
use crate::landmarks::frames::frame_from_axes;
use crate::landmarks::{Code, LandmarkId, LandmarkSet, Level};
use crate::mesh::source::{body_mesh, MeshSource};
use crate::mesh::umeyama;
use crate::osim::model::Model;
use crate::osim::Document;
use nalgebra::{Isometry3, Point3, Rotation3};
use std::collections::BTreeMap;

/// Base-model markers `<LEVEL>_<CODE>` in their bodies' frames, and the
/// bodies they are on.
pub fn base_markers(model: &Model) -> Result<BTreeMap<Level, (String, Points)>> {
    let mut out: BTreeMap<Level, (String, Points)> = BTreeMap::new();
    for mk in &model.markers {
        let Some((id, _)) = LandmarkId::parse_name(&mk.name) else {
            continue;
        };
        let (body, x) = model.marker_frame(mk)?;
        if body != id.level.body_name() {
            return Err(Error::invalid(
                model.file.display().to_string(),
                format!(
                    "marker '{}' is on body '{body}', expected '{}'",
                    mk.name,
                    id.level.body_name()
                ),
            ));
        }
        out.entry(id.level)
            .or_insert_with(|| (body.clone(), Points::new()))
            .1
            .insert(id.code, x * Point3::from(mk.location));
    }
    Ok(out)
}

/// The base model's sacrum surface (its body frame, metres, meshes scaled
/// as the model scales them) and its S1 markers: what a patient's sacrum
/// is registered to when the patient comes as a segmentation
/// ([`crate::segmentation::sacrum`]). `None` when the base has no sacrum
/// mesh or no S1 markers.
pub fn base_sacrum(
    base: &Document,
    meshes: &dyn MeshSource,
) -> Result<Option<(crate::mesh::TriMesh, Points)>> {
    let model = base.model()?;
    let markers = base_markers(&model)?;
    let Some((body, s1)) = markers.get(&Level::S1) else {
        return Ok(None);
    };
    let Some(b) = model.bodies.iter().find(|b| &b.name == body) else {
        return Ok(None);
    };
    Ok(body_mesh(b, meshes)?.mesh.map(|m| (m, s1.clone())))
}

/// Sacral frame from S1 endplate points: Y normal to the endplate (from the
/// two diameters, `(SR - SL) x (SA - SP)`), Z right.
pub(super) fn sacral_rotation(p: &Points) -> Option<Rotation3<f64>> {
    let a = p.get(&Code::SA)? - p.get(&Code::SP)?;
    let r = p.get(&Code::SR)? - p.get(&Code::SL)?;
    frame_from_axes(r.cross(&a), r)
}

pub(super) fn isb_rotation(p: &Points) -> Option<Rotation3<f64>> {
    let right = nalgebra::center(p.get(&Code::PTR)?, p.get(&Code::PBR)?);
    let left = nalgebra::center(p.get(&Code::PTL)?, p.get(&Code::PBL)?);
    frame_from_axes(p.get(&Code::SEC)? - p.get(&Code::IEC)?, right - left)
}

/// Step 1: register the landmarks to the base model through the sacrum
/// (its required landmarks, plus PTR/PTL when both sides have them); every
/// landmark is moved into the model's frame.
pub(super) fn register_sacrum(
    patient: &mut BTreeMap<Level, Points>,
    markers: &BTreeMap<Level, (String, Points)>,
    x_sacrum: &Isometry3<f64>,
    set_name: &str,
) -> Result<Registration> {
    let (src, dst, used): (Vec<Point3<f64>>, Vec<Point3<f64>>, Vec<String>) = {
        let pp = &patient[&Level::S1];
        let mp = &markers[&Level::S1].1;
        let mut codes: Vec<Code> = Code::SACRUM_REQUIRED.to_vec();
        if [Code::PTR, Code::PTL]
            .iter()
            .all(|c| pp.contains_key(c) && mp.contains_key(c))
        {
            codes.extend([Code::PTR, Code::PTL]);
        }
        let mut s = Vec::new();
        let mut d = Vec::new();
        let mut u = Vec::new();
        for c in codes {
            if let (Some(p), Some(m)) = (pp.get(&c), mp.get(&c)) {
                s.push(*p);
                d.push(x_sacrum * m);
                u.push(format!("S1_{c}"));
            }
        }
        (s, d, u)
    };
    let reg = umeyama(&src, &dst, false).map_err(|e| {
        Error::invalid(
            set_name,
            format!("sacral landmarks cannot be registered to the model: {e}"),
        )
    })?;
    let x_reg = Isometry3::from_parts(reg.translation.into(), reg.rotation);
    let reg_rms = (src
        .iter()
        .zip(&dst)
        .map(|(s, d)| (x_reg * s - d).norm_squared())
        .sum::<f64>()
        / src.len() as f64)
        .sqrt();
    for pts in patient.values_mut() {
        for p in pts.values_mut() {
            *p = x_reg * *p;
        }
    }
    Ok(Registration::from_iso(&x_reg, used, reg_rms))
}

/// The set's landmarks grouped by level.
pub(super) fn landmarks_per_level(set: &LandmarkSet) -> BTreeMap<Level, Points> {
    let mut patient: BTreeMap<Level, Points> = BTreeMap::new();
    for (id, p) in &set.points {
        patient.entry(id.level).or_default().insert(id.code, *p);
    }
    patient
}
