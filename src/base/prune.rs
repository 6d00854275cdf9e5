//! What the base model keeps of the generic model, and why the rest goes.
//!
//! A muscle is kept exactly when every path point (fixed, conditional,
//! moving) is on a kept body, every coordinate its points depend on is a
//! coordinate of the base model, and every wrap object it uses is on a kept
//! body. Every other force (actuators, existing bushings, ...) is dropped:
//! the base model's forces are the kept muscles and the new IVD bushings.
//! Markers, constraints, contact geometry, controllers, probes and extra
//! components are dropped.

use crate::error::Result;
use crate::osim::model::{Constraint, Force, Model, PathPointKind};
use crate::osim::xml::Element;
use std::collections::{BTreeMap, BTreeSet};

/// A dropped component and the reason.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Dropped {
    /// Component name.
    pub name: String,
    /// Its OpenSim class (e.g. `Thelen2003Muscle`).
    pub class: String,
    /// Why it was dropped.
    pub reason: String,
}

/// Keep/drop decisions.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct PruneReport {
    /// Bodies kept.
    pub bodies_kept: Vec<String>,
    /// Bodies dropped.
    pub bodies_dropped: Vec<String>,
    /// Joints dropped (with their child bodies).
    pub joints_dropped: Vec<String>,
    /// Muscles kept.
    pub muscles_kept: Vec<String>,
    /// Muscles dropped and why.
    pub muscles_dropped: Vec<Dropped>,
    /// Other forces dropped and why.
    pub other_forces_dropped: Vec<Dropped>,
    /// Number of markers dropped.
    pub markers_dropped: usize,
    /// Constraints dropped.
    pub constraints_dropped: Vec<String>,
    /// Wrap objects on kept bodies that no kept muscle uses (dropped).
    pub wrap_objects_dropped: Vec<String>,
    /// Wrap objects kept (used by kept muscles).
    pub used_wrap_objects: BTreeSet<String>,
}

/// Decide what to keep. `renames` maps old coordinate names to (joint,
/// new name); `kept_coords` are the base model's coordinate names.
pub fn decide(
    model: &Model,
    kept_bodies: &BTreeSet<String>,
    kept_coords: &BTreeSet<String>,
    renames: &BTreeMap<String, (String, String)>,
) -> Result<PruneReport> {
    let wrap_body: BTreeMap<&str, &str> = model
        .bodies
        .iter()
        .flat_map(|b| {
            b.wrap_objects
                .iter()
                .map(move |w| (w.name.as_str(), b.name.as_str()))
        })
        .chain(
            model
                .ground
                .wrap_objects
                .iter()
                .map(|w| (w.name.as_str(), "ground")),
        )
        .collect();
    let coord_ok = |c: &str| -> bool {
        let name = c.rsplit('/').next().unwrap_or(c);
        let name = renames.get(name).map(|(_, n)| n.as_str()).unwrap_or(name);
        kept_coords.contains(name)
    };
    let mut muscles_kept = Vec::new();
    let mut muscles_dropped = Vec::new();
    let mut other = Vec::new();
    let mut used = BTreeSet::new();
    for f in &model.forces {
        let Force::Muscle(m) = f else {
            other.push(Dropped {
                name: f.name().to_string(),
                class: f.class().to_string(),
                reason: "not a muscle: the base model's forces are the kept muscles and the IVD bushings"
                    .into(),
            });
            continue;
        };
        let mut reason = None;
        for p in &m.points {
            let owner = format!("/forceset/{}/path/{}", m.name, p.name);
            let body = model.resolve_frame(&owner, &p.socket_parent_frame)?.0;
            if !kept_bodies.contains(&body) {
                reason = Some(format!(
                    "path point '{}' is on dropped body '{body}'",
                    p.name
                ));
                break;
            }
            let coords: Vec<&String> = match &p.kind {
                PathPointKind::Fixed => vec![],
                PathPointKind::Conditional { coordinate, .. } => vec![coordinate],
                PathPointKind::Moving { x, y, z } => [x, y, z]
                    .iter()
                    .filter_map(|o| o.as_ref().map(|fc| &fc.1))
                    .collect(),
            };
            if let Some(c) = coords.into_iter().find(|c| !coord_ok(c)) {
                reason = Some(format!(
                    "path point '{}' depends on coordinate '{c}', which the base model does not have",
                    p.name
                ));
                break;
            }
        }
        if reason.is_none() {
            for w in &m.wraps {
                match wrap_body.get(w.wrap_object.as_str()) {
                    Some(b) if kept_bodies.contains(*b) => {}
                    Some(b) => {
                        reason = Some(format!(
                            "wraps over '{}' on dropped body '{b}'",
                            w.wrap_object
                        ));
                        break;
                    }
                    None => {
                        reason = Some(format!("wraps over unknown object '{}'", w.wrap_object));
                        break;
                    }
                }
            }
        }
        match reason {
            Some(r) => muscles_dropped.push(Dropped {
                name: m.name.clone(),
                class: m.class.clone(),
                reason: r,
            }),
            None => {
                for w in &m.wraps {
                    used.insert(w.wrap_object.clone());
                }
                muscles_kept.push(m.name.clone());
            }
        }
    }
    let wrap_objects_dropped = model
        .bodies
        .iter()
        .filter(|b| kept_bodies.contains(&b.name))
        .flat_map(|b| b.wrap_objects.iter())
        .filter(|w| !used.contains(&w.name))
        .map(|w| w.name.clone())
        .collect();
    let frames = model.joint_frames()?;
    Ok(PruneReport {
        bodies_kept: model
            .bodies
            .iter()
            .filter(|b| kept_bodies.contains(&b.name))
            .map(|b| b.name.clone())
            .collect(),
        bodies_dropped: model
            .bodies
            .iter()
            .filter(|b| !kept_bodies.contains(&b.name))
            .map(|b| b.name.clone())
            .collect(),
        joints_dropped: frames
            .iter()
            .filter(|f| {
                !(kept_bodies.contains(&f.child_body) && (kept_bodies.contains(&f.parent_body)))
            })
            .map(|f| f.joint.clone())
            .collect(),
        muscles_kept,
        muscles_dropped,
        other_forces_dropped: other,
        markers_dropped: model.markers.len(),
        constraints_dropped: model
            .constraints
            .iter()
            .map(|c| match c {
                Constraint::CoordinateCoupler { name, .. } => name.clone(),
                Constraint::Other { name, .. } => name.clone(),
            })
            .collect(),
        wrap_objects_dropped,
        used_wrap_objects: used,
    })
}

/// Rewrite `socket_*coordinate` properties of a muscle element that name a
/// renamed coordinate (`/jointset/<joint>/<new>`).
pub fn rename_coordinate_sockets(el: &mut Element, renames: &BTreeMap<String, (String, String)>) {
    if renames.is_empty() {
        return;
    }
    if el.name.starts_with("socket_") && el.name.ends_with("coordinate") {
        let t = el.text();
        let name = t.trim().rsplit('/').next().unwrap_or("").to_string();
        if let Some((joint, new)) = renames.get(&name) {
            el.set_text(format!("/jointset/{joint}/{new}"));
        }
        return;
    }
    for c in el.elements_mut() {
        rename_coordinate_sockets(c, renames);
    }
}
