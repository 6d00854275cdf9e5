//! Step 7 of the base builder: the vertebral-body spheres placed on their
//! bodies and the muscles that wrap over them (rules in [`super::wrap`]):
//! muscle paths over the test poses, spheres kept apart, each sphere's
//! muscles assigned, one PathWrap per muscle.

use super::body_level_index;
use super::kin::{self, Kinematics};
use super::wrap::{self, muscle_geometry, MuscleGeom, SphereRow};
use crate::error::{Error, Result};
use crate::osim::builders;
use crate::osim::xml::Node;
use crate::osim::Document;
use nalgebra::{Isometry3, Point3, Vector3};
use std::collections::BTreeMap;

/// What the wrapping step did.
pub(crate) struct Wrapping {
    /// Labels of the test poses.
    pub test_poses: Vec<String>,
    pub path_wraps_added: usize,
    pub muscles_with_wraps: usize,
}

/// Add the spheres and PathWraps to `doc` (edits `spheres`' radii and
/// muscle lists).
pub(crate) fn add_wraps(
    doc: &mut Document,
    spheres: &mut [SphereRow],
    prefixes: &[String],
    gfile: &str,
) -> Result<Wrapping> {
    // Body poses and straight muscle paths over the test poses.
    let base0 = doc.model()?;
    let kin0 = Kinematics::new(&base0)?;
    let poses = wrap::test_poses(&kin0.default_values(), prefixes);
    let mut pose_bodies = Vec::new();
    for (_, q) in &poses {
        pose_bodies.push(kin0.body_poses(q)?);
    }
    let mgeo = muscle_geometry(&base0, &poses, &pose_bodies)?;
    // Spheres apart in every pose, then each one's muscles.
    separate_spheres(spheres, &pose_bodies);
    let mut wraps_for: BTreeMap<usize, Vec<(f64, String)>> = BTreeMap::new();
    for s in spheres.iter_mut() {
        assign_sphere(doc, s, &mgeo, &pose_bodies, &mut wraps_for, gfile)?;
    }
    // One PathWrap per muscle: the sphere its straight path penetrates
    // deepest (OpenSim 4.6 gives paths shorter than the straight line when
    // a path wraps over several spheres in sequence).
    for list in wraps_for.values_mut() {
        list.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        list.truncate(1);
    }
    for s in spheres.iter_mut() {
        s.muscles.retain(|m| {
            mgeo.iter()
                .position(|g| g.name == *m)
                .and_then(|k| wraps_for.get(&k))
                .map(|l| l.iter().any(|(_, n)| *n == s.name))
                .unwrap_or(false)
        });
    }
    let path_wraps_added = add_path_wraps(doc, &wraps_for, &mgeo, gfile)?;
    Ok(Wrapping {
        test_poses: poses.iter().map(|(l, _)| l.clone()).collect(),
        path_wraps_added,
        muscles_with_wraps: wraps_for.len(),
    })
}

/// A sphere's centre in ground in every test pose.
fn centres_in_poses(
    s: &SphereRow,
    pose_bodies: &[BTreeMap<String, Isometry3<f64>>],
) -> Vec<Point3<f64>> {
    let c = Point3::new(s.centre[0], s.centre[1], s.centre[2]);
    pose_bodies
        .iter()
        .map(|pb| pb.get(&s.body).map(|x| x * c).unwrap_or(c))
        .collect()
}

/// Spheres must not overlap one another in any test pose: OpenSim wraps
/// sequentially, and a tangent point inside the next sphere gives wrong
/// (even shorter than straight) paths. Overlapping pairs are shrunk in
/// proportion to 98 % of their closest centre distance.
fn separate_spheres(spheres: &mut [SphereRow], pose_bodies: &[BTreeMap<String, Isometry3<f64>>]) {
    let all_centres: Vec<Vec<Point3<f64>>> = spheres
        .iter()
        .map(|s| centres_in_poses(s, pose_bodies))
        .collect();
    for i in 0..spheres.len() {
        for j in (i + 1)..spheres.len() {
            let d = all_centres[i]
                .iter()
                .zip(&all_centres[j])
                .map(|(a, b)| (a - b).norm())
                .fold(f64::MAX, f64::min);
            let sum = spheres[i].radius + spheres[j].radius;
            if sum > 0.98 * d {
                let f = 0.98 * d / sum;
                spheres[i].radius *= f;
                spheres[j].radius *= f;
            }
        }
    }
    for s in spheres.iter_mut() {
        s.radius_no_overlap = s.radius;
    }
}

/// The muscles over one sphere (with each one's clearance), and the
/// WrapSphere written on its body.
fn assign_sphere(
    doc: &mut Document,
    s: &mut SphereRow,
    mgeo: &[MuscleGeom],
    pose_bodies: &[BTreeMap<String, Isometry3<f64>>],
    wraps_for: &mut BTreeMap<usize, Vec<(f64, String)>>,
    gfile: &str,
) -> Result<()> {
    let g = wrap::SphereGeom {
        level_index: body_level_index(&s.body).unwrap_or(0),
        body: s.body.clone(),
        radius_fit: s.radius,
        centres: centres_in_poses(s, pose_bodies),
    };
    let a = wrap::assign(&g, mgeo);
    s.radius = a.radius;
    s.muscles = a.muscles.iter().map(|&k| mgeo[k].name.clone()).collect();
    s.muscles_refused = a.refused.iter().map(|&k| mgeo[k].name.clone()).collect();
    for &k in &a.muscles {
        // Clearance of the straight path to this sphere over the test poses.
        let clear = mgeo[k]
            .paths
            .iter()
            .zip(&g.centres)
            .flat_map(|(p, c)| {
                p.windows(2)
                    .map(move |w| kin::point_segment_distance(c, &w[0], &w[1]))
            })
            .fold(f64::MAX, f64::min)
            - a.radius;
        wraps_for
            .entry(k)
            .or_default()
            .push((clear, s.name.clone()));
    }
    // WrapSphere on the body.
    let el = doc
        .component_mut("BodySet", &s.body)
        .ok_or_else(|| Error::invalid(gfile, format!("body '{}' vanished", s.body)))?;
    let ws = el.child_or_insert("WrapObjectSet");
    if ws.attr("name").is_none() {
        ws.set_attr("name", "wrapobjectset");
    }
    ws.child_or_insert("objects")
        .children
        .push(Node::Element(builders::wrap_sphere(
            &s.name,
            &Vector3::new(s.centre[0], s.centre[1], s.centre[2]),
            &Vector3::zeros(),
            s.radius,
            "all",
        )));
    Ok(())
}

/// The PathWraps of every muscle that wraps; returns how many were added.
fn add_path_wraps(
    doc: &mut Document,
    wraps_for: &BTreeMap<usize, Vec<(f64, String)>>,
    mgeo: &[MuscleGeom],
    gfile: &str,
) -> Result<usize> {
    let mut added = 0;
    for (k, list) in wraps_for {
        let name = &mgeo[*k].name;
        let el = doc
            .component_mut("ForceSet", name)
            .ok_or_else(|| Error::invalid(gfile, format!("muscle '{name}' vanished")))?;
        let gp = el
            .elements_mut()
            .find(|e| e.name == "GeometryPath")
            .ok_or_else(|| Error::invalid(gfile, format!("muscle '{name}' has no GeometryPath")))?;
        let objs = gp.child_or_insert("PathWrapSet").child_or_insert("objects");
        for (_, sname) in list {
            objs.children.push(Node::Element(builders::path_wrap(
                &format!("pathwrap_{sname}"),
                sname,
                "hybrid",
                [-1, -1],
            )));
            added += 1;
        }
    }
    Ok(added)
}
