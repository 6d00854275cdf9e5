//! Wrap spheres after anisotropic scaling.
//!
//! A sphere scaled by `S = diag(sx, sy, sz)` becomes an ellipsoid
//! (OpenSim's own scaling averages the three factors and users report
//! broken wrapping after non-uniform scaling). The sphere is refitted:
//! * centre: `S c`, the ellipsoid's centre (the affine image of the
//!   vertebral-body centre, which keeps the vertebral-centre definition of
//!   [`crate::evaluate`] consistent);
//! * radius: least-squares radius about that centre of the scaled image of
//!   the base sphere's anterior wall (the region the base pipeline fitted
//!   it to: points within 60 degrees of anterior in the transverse plane
//!   and within 25 degrees of it in elevation);
//! * then the base pipeline's consistency rules are enforced at the default
//!   pose and the base test poses ([`crate::build::base::wrap::test_poses`]):
//!   spheres do not overlap (pairs shrunk to 98 % of their closest centre
//!   distance) and no path point of a muscle wrapping over a sphere lies
//!   within the radius + 0.5 mm; a muscle that would force the radius
//!   below half the refitted one loses that PathWrap (reported).

use crate::build::base::kin::{muscle_path, Kinematics};
use crate::build::base::wrap::{test_poses, CLEARANCE};
use crate::error::{Error, Result};
use crate::osim::document::set_f64;
use crate::osim::model::WrapShape;
use crate::osim::xml::Node;
use crate::osim::Document;
use nalgebra::{Point3, Vector3};
use std::collections::BTreeMap;

/// Least-squares radius about the scaled centre of the scaled anterior wall
/// of a sphere of radius `r` scaled by `s`.
pub fn refit_radius(r: f64, s: &Vector3<f64>) -> f64 {
    let mut sum = 0.0;
    let mut n = 0.0;
    for i in -6..=6 {
        let az = (i as f64) * 10f64.to_radians(); // -60..60 deg from anterior
        for j in -5..=5 {
            let el = (j as f64) * 5f64.to_radians(); // -25..25 deg
            let p = Vector3::new(el.cos() * az.cos(), el.sin(), el.cos() * az.sin()) * r;
            sum += p.component_mul(s).norm();
            n += 1.0;
        }
    }
    sum / n
}

/// One sphere of the generated model.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct SphereOut {
    pub name: String,
    pub body: String,
    /// Centre in the body frame (m).
    pub centre: [f64; 3],
    /// Radius in the base model (m).
    pub radius_base: f64,
    /// Radius refitted after scaling (m).
    pub radius_refit: f64,
    /// Radius written (m).
    pub radius: f64,
    /// What limited the radius below the refit ("" when nothing did).
    pub limited_by: String,
    /// Muscles wrapping over it.
    pub muscles: Vec<String>,
    /// Muscles whose PathWrap over it was removed (a path point too deep).
    pub pathwraps_removed: Vec<String>,
}

/// Refit and constrain every WrapSphere of `doc` (already scaled, joints
/// rewritten); `scales` gives each scaled body's factors, `base_radii` the
/// base model's radius of each sphere by name. Edits `doc`.
pub fn refit_spheres(
    doc: &mut Document,
    scales: &BTreeMap<String, Vector3<f64>>,
    base_radii: &BTreeMap<String, f64>,
    ivd_prefixes: &[String],
) -> Result<Vec<SphereOut>> {
    let model = doc.model()?;
    let kin = Kinematics::new(&model)?;
    let q0 = kin.default_values();
    let poses: Vec<_> = test_poses(&q0, ivd_prefixes);
    let mut body_poses = Vec::new();
    for (_, q) in &poses {
        body_poses.push(kin.body_poses(q)?);
    }
    // Spheres.
    let mut out = Vec::new();
    for b in &model.bodies {
        for w in &b.wrap_objects {
            if let WrapShape::Sphere { .. } = w.shape {
                let rb = base_radii.get(&w.name).copied().unwrap_or(match w.shape {
                    WrapShape::Sphere { radius } => radius,
                    _ => 0.0,
                });
                let rf = match scales.get(&b.name) {
                    Some(s) => refit_radius(rb, s),
                    None => rb,
                };
                out.push(SphereOut {
                    name: w.name.clone(),
                    body: b.name.clone(),
                    centre: [w.translation.x, w.translation.y, w.translation.z],
                    radius_base: rb,
                    radius_refit: rf,
                    radius: rf,
                    limited_by: String::new(),
                    muscles: vec![],
                    pathwraps_removed: vec![],
                });
            }
        }
    }
    let centres = |s: &SphereOut| -> Vec<Point3<f64>> {
        let c = Point3::from(s.centre);
        body_poses
            .iter()
            .map(|bp| bp.get(&s.body).map(|x| x * c).unwrap_or(c))
            .collect()
    };
    let all_c: Vec<Vec<Point3<f64>>> = out.iter().map(centres).collect();
    // No overlap.
    for i in 0..out.len() {
        for j in (i + 1)..out.len() {
            let d = all_c[i]
                .iter()
                .zip(&all_c[j])
                .map(|(a, b)| (a - b).norm())
                .fold(f64::MAX, f64::min);
            let sum = out[i].radius + out[j].radius;
            if sum > 0.98 * d {
                let f = 0.98 * d / sum;
                out[i].radius *= f;
                out[j].radius *= f;
                let (ni, nj) = (out[i].name.clone(), out[j].name.clone());
                out[i].limited_by = format!("no overlap with {nj}");
                out[j].limited_by = format!("no overlap with {ni}");
            }
        }
    }
    // Path points of the muscles wrapping over each sphere.
    let mut removals: Vec<(String, String)> = Vec::new(); // (muscle, sphere)
    for (k, s) in out.iter_mut().enumerate() {
        let mut limits: Vec<(f64, String)> = Vec::new();
        for m in model.muscles() {
            if !m.wraps.iter().any(|w| w.wrap_object == s.name) {
                continue;
            }
            s.muscles.push(m.name.clone());
            let mut dpose = f64::MAX;
            for (pi, ((_, q), bp)) in poses.iter().zip(&body_poses).enumerate() {
                for p in muscle_path(&model, m, bp, q)? {
                    dpose = dpose.min((p.ground - all_c[k][pi]).norm());
                }
            }
            limits.push((dpose - CLEARANCE, m.name.clone()));
        }
        limits.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        for (lim, name) in limits {
            if lim >= s.radius {
                continue;
            }
            if lim < 0.5 * s.radius_refit {
                s.pathwraps_removed.push(name.clone());
                s.muscles.retain(|x| *x != name);
                removals.push((name, s.name.clone()));
            } else {
                s.radius = lim;
                s.limited_by = format!("path point of {name}");
            }
        }
    }
    // Write radii and remove PathWraps.
    for s in &out {
        let el = doc
            .component_mut("BodySet", &s.body)
            .and_then(|b| b.child_mut("WrapObjectSet"))
            .and_then(|w| w.child_mut("objects"))
            .and_then(|o| o.elements_mut().find(|e| e.name_attr() == s.name))
            .ok_or_else(|| {
                Error::invalid(
                    doc_name(&model.file),
                    format!("wrap sphere '{}' vanished", s.name),
                )
            })?;
        set_f64(el, "radius", s.radius);
    }
    for (muscle, sphere) in &removals {
        if let Some(objs) = doc
            .component_mut("ForceSet", muscle)
            .and_then(|m| m.elements_mut().find(|e| e.name == "GeometryPath"))
            .and_then(|g| g.child_mut("PathWrapSet"))
            .and_then(|w| w.child_mut("objects"))
        {
            objs.children.retain(|n| match n {
                Node::Element(e) => e.child_text("wrap_object").as_deref() != Some(sphere),
                _ => true,
            });
        }
    }
    Ok(out)
}

fn doc_name(p: &std::path::Path) -> String {
    p.display().to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn refit_radius_is_exact_for_uniform_scaling_and_between_factors_otherwise() {
        assert!((refit_radius(0.015, &Vector3::repeat(1.0)) - 0.015).abs() < 1e-15);
        assert!((refit_radius(0.015, &Vector3::repeat(1.3)) - 0.0195).abs() < 1e-15);
        let r = refit_radius(0.01, &Vector3::new(1.2, 1.0, 0.9));
        assert!(r > 0.009 && r < 0.012, "{r}");
    }
}
