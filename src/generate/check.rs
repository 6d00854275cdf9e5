//! Step 6, the self-check of the generated model: wrap-sphere radii,
//! muscle paths cleared of the bones, and the base pipeline's checks.

use super::{clear, wraps};
use crate::error::Result;
use crate::landmarks::Level;
use crate::mesh::source::MeshSource;
use crate::mesh::MeshQuery;
use crate::osim::model::Model;
use crate::osim::Document;
use std::collections::BTreeMap;

/// Radius of every wrap sphere of the base model, by name.
pub(super) fn sphere_radii(model: &Model) -> BTreeMap<String, f64> {
    model
        .bodies
        .iter()
        .flat_map(|b| b.wrap_objects.iter())
        .filter_map(|w| match w.shape {
            crate::osim::model::WrapShape::Sphere { radius } => Some((w.name.clone(), radius)),
            _ => None,
        })
        .collect()
}

/// The vertebra meshes of `doc`'s bodies with their spatial queries, built
/// once for the path clearing and the self-check (neither changes a
/// body's geometry); `None` without meshes.
pub(super) fn vertebra_queries(
    doc: &Document,
    meshes: Option<&dyn MeshSource>,
) -> Result<Option<Vec<(String, MeshQuery)>>> {
    let Some(src) = meshes else {
        return Ok(None);
    };
    Ok(Some(crate::base::wrapped::vertebra_meshes(
        &doc.model()?,
        src,
    )?))
}

/// Step 5b: muscle paths cleared of the vertebra meshes ([`clear`]); no
/// edits without meshes.
pub(super) fn clear_muscle_paths(
    doc: &mut Document,
    vertebrae: Option<&[(String, MeshQuery)]>,
) -> Result<Vec<clear::PathEdit>> {
    let Some(owned) = vertebrae else {
        return Ok(Vec::new());
    };
    let refs: Vec<(String, &MeshQuery)> = owned.iter().map(|(n, q)| (n.clone(), q)).collect();
    clear::clear_paths(doc, &refs)
}

/// Step 6: the generated model's self-check (bushings at rest, muscle
/// paths against the vertebra meshes when there are any, equilibrium
/// under gravity), with the refitted wrap spheres.
pub(super) fn self_check(
    out_model: &Model,
    vertebrae: Option<&[(String, MeshQuery)]>,
    spheres: &[wraps::SphereOut],
) -> Result<crate::base::check::SelfCheck> {
    let refs: Vec<(String, &MeshQuery)> = vertebrae
        .unwrap_or_default()
        .iter()
        .map(|(n, q)| (n.clone(), q))
        .collect();
    let rows: Vec<crate::base::wrap::SphereRow> = spheres
        .iter()
        .map(|s| crate::base::wrap::SphereRow {
            level: Level::from_body_name(&s.body),
            body: s.body.clone(),
            name: s.name.clone(),
            centre: s.centre,
            radius_fit: s.radius_refit,
            radius_no_overlap: s.radius,
            radius: s.radius,
            rms_mm: 0.0,
            nodes: 0,
            centre_inside_mesh: true,
            source: "refitted from the base model".into(),
            body_mesh_registration_rms_mm: None,
            muscles: s.muscles.clone(),
            muscles_refused: s.muscles_refused.clone(),
        })
        .collect();
    crate::base::check::run_wrapped(out_model, &refs, &rows)
}
