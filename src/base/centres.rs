//! The vertebral centres and landmarks of a model at a pose, read from the
//! base model's conventions: the `<LEVEL>_SEC`/`<LEVEL>_IEC` markers and the
//! `<LEVEL>_body_sphere` wrap (`../shared/formats/landmarks.md`, "vertebral
//! centre"). The generator reports them and `evaluate` scores them.

use crate::error::Result;
use crate::landmarks::{Code, LandmarkId, LandmarkSet, Level};
use crate::osim::model::{Model, WrapShape};
use nalgebra::{Isometry3, Point3};
use std::collections::BTreeMap;

/// Definition of the vertebral centre.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum CentreDef {
    /// Midpoint of the `SEC` and `IEC` markers (centre of the vertebral
    /// body on its endplate axis); for truth meshes, the volume centroid of
    /// the vertebral-body mesh.
    #[default]
    Endplates,
    /// Centre of the vertebral-body wrap sphere (thesis); for truth meshes,
    /// a sphere fit to the anterior wall.
    Sphere,
}

/// Vertebral centres of a model in ground at `poses` (see [`CentreDef`];
/// a vertebra lacking what the definition needs falls back to the other).
pub fn model_centres(
    model: &Model,
    poses: &BTreeMap<String, Isometry3<f64>>,
    def: CentreDef,
) -> Result<BTreeMap<Level, Point3<f64>>> {
    let mut out = BTreeMap::new();
    let markers = model_landmarks(model, poses)?;
    for b in &model.bodies {
        let Some(l) = Level::from_body_name(&b.name) else {
            continue;
        };
        if l.is_sacrum() {
            continue;
        }
        let Some(x) = poses.get(&b.name) else {
            continue;
        };
        let want = format!("{l}_body_sphere");
        let sphere = b
            .wrap_objects
            .iter()
            .filter(|w| matches!(w.shape, WrapShape::Sphere { .. }))
            .find(|w| w.name == want)
            .or_else(|| {
                b.wrap_objects
                    .iter()
                    .find(|w| matches!(w.shape, WrapShape::Sphere { .. }))
            })
            .map(|w| x * Point3::from(w.translation));
        let mid = match (markers.get(l, Code::SEC), markers.get(l, Code::IEC)) {
            (Some(a), Some(b)) => Some(nalgebra::center(&a, &b)),
            _ => None,
        };
        let c = match def {
            CentreDef::Endplates => mid.or(sphere),
            CentreDef::Sphere => sphere.or(mid),
        };
        if let Some(c) = c {
            out.insert(l, c);
        }
    }
    Ok(out)
}

/// The model's `<LEVEL>_<CODE>` markers in ground at `poses`, as a set.
pub fn model_landmarks(
    model: &Model,
    poses: &BTreeMap<String, Isometry3<f64>>,
) -> Result<LandmarkSet> {
    let mut set = LandmarkSet::new();
    for mk in &model.markers {
        let Some((id, _)) = LandmarkId::parse_name(&mk.name) else {
            continue;
        };
        let (body, x) = model.marker_frame(mk)?;
        if let Some(pb) = poses.get(&body) {
            set.points.insert(id, pb * x * Point3::from(mk.location));
        }
    }
    Ok(set)
}
