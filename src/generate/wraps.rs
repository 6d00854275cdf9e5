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
//! * then the base pipeline's wrapping rules ([`crate::base::wrap`])
//!   are re-applied on the generated pose (its default pose and the base
//!   test poses around it), since the scoliotic curve changes which
//!   muscles cross which vertebral body: spheres may not overlap (pairs
//!   shrunk to 98 % of their closest centre distance); the crossing rule
//!   and the inside-point fix decide which muscles wrap over each sphere
//!   and shrink it clear of their path points (a muscle that would force
//!   it below half its radius is refused, reported); each muscle gets one
//!   PathWrap, over the sphere its straight path penetrates deepest; the
//!   base model's PathWraps over vertebral-body spheres are replaced.

use crate::base::body_level_index;
use crate::base::kin::{point_segment_distance, Kinematics};
use crate::base::wrap::{assign, muscle_geometry, test_poses, MuscleGeom, SphereGeom};
use crate::error::{Error, Result};
use crate::osim::builders;
use crate::osim::model::{Model, WrapShape};
use crate::osim::props::set_f64;
use crate::osim::xml::Node;
use crate::osim::Document;
use nalgebra::{Point3, Vector3};
use std::collections::{BTreeMap, BTreeSet};

/// Least-squares radius about the scaled centre of the scaled anterior wall
/// of a sphere of radius `r` scaled by `s`.
pub(crate) fn refit_radius(r: f64, s: &Vector3<f64>) -> f64 {
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
    /// WrapSphere name.
    pub name: String,
    /// Body the sphere is fixed to.
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
    /// Muscles wrapping over it (PathWraps).
    pub muscles: Vec<String>,
    /// Muscles that cross it but have a path point too deep inside.
    pub muscles_refused: Vec<String>,
}

/// No two spheres overlap in any test pose: a pair closer than the sum of
/// their radii (with 2% margin) shrinks both in proportion. `centres[k]` is
/// sphere `k`'s centre in each test pose.
fn limit_overlaps(out: &mut [SphereOut], centres: &[Vec<Point3<f64>>]) {
    for i in 0..out.len() {
        for j in (i + 1)..out.len() {
            let d = centres[i]
                .iter()
                .zip(&centres[j])
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
    // The body poses of the default pose and the test poses around it.
    let kin = Kinematics::new(&model)?;
    let q0 = kin.default_values();
    let poses: Vec<_> = test_poses(&q0, ivd_prefixes);
    let mut body_poses = Vec::new();
    for (_, q) in &poses {
        body_poses.push(kin.body_poses(q)?);
    }
    // Each sphere's radius refitted to its body's scaling.
    let mut out = refitted_spheres(&model, scales, base_radii);
    // Spheres may not overlap at any test pose.
    let all_c: Vec<Vec<Point3<f64>>> = out
        .iter()
        .map(|s| {
            let c = Point3::from(s.centre);
            body_poses
                .iter()
                .map(|bp| bp.get(&s.body).map(|x| x * c).unwrap_or(c))
                .collect()
        })
        .collect();
    limit_overlaps(&mut out, &all_c);
    // Muscles over the test poses, and the base pipeline's crossing rule
    // and inside-point fix on the generated pose: one sphere per muscle.
    let mgeo = muscle_geometry(&model, &poses, &body_poses)?;
    let chosen = assign_muscles(&mut out, &all_c, &mgeo);
    // Write the radii and the PathWraps.
    write_radii(doc, &out, &model.file)?;
    write_path_wraps(doc, &model, &out, &chosen);
    Ok(out)
}

/// Every WrapSphere of the model with its base radius and the radius
/// refitted to its body's scaling.
fn refitted_spheres(
    model: &Model,
    scales: &BTreeMap<String, Vector3<f64>>,
    base_radii: &BTreeMap<String, f64>,
) -> Vec<SphereOut> {
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
                    muscles_refused: vec![],
                });
            }
        }
    }
    out
}

/// The crossing rule and inside-point fix of every sphere (centres
/// `all_c` at the test poses), shrinking it where needed; then one sphere
/// per muscle, the one its straight path penetrates deepest. Returns
/// muscle -> sphere.
fn assign_muscles(
    out: &mut [SphereOut],
    all_c: &[Vec<Point3<f64>>],
    mgeo: &[MuscleGeom],
) -> BTreeMap<String, String> {
    // Per muscle: (clearance, sphere index) of every sphere it crosses.
    let mut crossings: BTreeMap<usize, Vec<(f64, usize)>> = BTreeMap::new();
    for (k, s) in out.iter_mut().enumerate() {
        let g = SphereGeom {
            level_index: body_level_index(&s.body).unwrap_or(0),
            body: s.body.clone(),
            radius_fit: s.radius,
            centres: all_c[k].clone(),
        };
        let a = assign(&g, mgeo);
        if a.radius < s.radius {
            s.limited_by = "path points of its muscles (inside-point rule)".into();
        }
        s.radius = a.radius;
        s.muscles_refused = a.refused.iter().map(|&i| mgeo[i].name.clone()).collect();
        for &i in &a.muscles {
            let clear = mgeo[i]
                .paths
                .iter()
                .zip(&g.centres)
                .flat_map(|(p, c)| {
                    p.windows(2)
                        .map(move |w| point_segment_distance(c, &w[0], &w[1]))
                })
                .fold(f64::MAX, f64::min)
                - a.radius;
            crossings.entry(i).or_default().push((clear, k));
        }
    }
    // One PathWrap per muscle: the sphere its straight path penetrates deepest.
    let mut chosen: BTreeMap<String, String> = BTreeMap::new(); // muscle -> sphere
    for (i, list) in crossings.iter_mut() {
        list.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        if let Some((_, k)) = list.first() {
            out[*k].muscles.push(mgeo[*i].name.clone());
            chosen.insert(mgeo[*i].name.clone(), out[*k].name.clone());
        }
    }
    chosen
}

/// Write each sphere's radius into `doc` (the model of `file`).
fn write_radii(doc: &mut Document, out: &[SphereOut], file: &std::path::Path) -> Result<()> {
    for s in out {
        let el = doc
            .component_mut("BodySet", &s.body)
            .and_then(|b| b.child_mut("WrapObjectSet"))
            .and_then(|w| w.child_mut("objects"))
            .and_then(|o| o.elements_mut().find(|e| e.name_attr() == s.name))
            .ok_or_else(|| {
                Error::invalid(doc_name(file), format!("wrap sphere '{}' vanished", s.name))
            })?;
        set_f64(el, "radius", s.radius);
    }
    Ok(())
}

/// Replace each muscle's PathWraps over the spheres by one over its
/// `chosen` sphere (none when it has none).
fn write_path_wraps(
    doc: &mut Document,
    model: &Model,
    out: &[SphereOut],
    chosen: &BTreeMap<String, String>,
) {
    let sphere_names: BTreeSet<String> = out.iter().map(|s| s.name.clone()).collect();
    for m in model.muscles() {
        let Some(gp) = doc
            .component_mut("ForceSet", &m.name)
            .and_then(|e| e.elements_mut().find(|e| e.name == "GeometryPath"))
        else {
            continue;
        };
        let had = gp.child("PathWrapSet").is_some();
        let new = chosen.get(&m.name);
        if !had && new.is_none() {
            continue;
        }
        let objs = gp.child_or_insert("PathWrapSet").child_or_insert("objects");
        objs.children.retain(|n| match n {
            Node::Element(e) => e
                .child_text("wrap_object")
                .map(|w| !sphere_names.contains(&w))
                .unwrap_or(true),
            _ => true,
        });
        if let Some(sphere) = new {
            objs.children.push(Node::Element(builders::path_wrap(
                &format!("pathwrap_{sphere}"),
                sphere,
                "hybrid",
                [-1, -1],
            )));
        }
    }
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
