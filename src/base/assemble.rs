//! Steps 3-5 of the base builder: the mean sacrum swapped in, the IVD
//! joints rebuilt with their bushings and the muscles kept, and the base
//! document assembled from them (bodies, joints, forces; no wraps or
//! markers yet).

use super::kin::Kinematics;
use super::topology::Topology;
use super::{joints, prune, sacrum, BaseOptions, FixedBody, JointRow};
use crate::error::{Error, Result};
use crate::landmarks::Level;
use crate::mesh::TriMesh;
use crate::osim::model::Model;
use crate::osim::xml::{Element, Node};
use crate::osim::Document;
use std::collections::{BTreeMap, BTreeSet};

/// The sacrum the base uses.
pub(crate) struct Sacrum {
    pub mesh: TriMesh,
    pub file: String,
    pub report: Option<sacrum::SacrumReport>,
}

/// Step 3: the mean sacrum registered and swapped in, or the generic one.
pub(crate) fn swap_sacrum(
    body_meshes: &BTreeMap<String, (String, TriMesh)>,
    opts: &BaseOptions,
    gfile: &str,
) -> Result<Sacrum> {
    let (sac_file, sac_mesh) = body_meshes
        .get("sacrum")
        .cloned()
        .ok_or_else(|| Error::invalid(gfile, "the sacrum has no mesh"))?;
    Ok(match &opts.sacrum {
        Some((name, m)) => {
            let (moved, rep) = sacrum::register_sacrum(
                m,
                name,
                &sac_mesh,
                &sac_file,
                &opts.sacrum_file,
                opts.allow_scale,
                opts.max_sacrum_rms,
            )?;
            Sacrum {
                mesh: moved,
                file: opts.sacrum_file.clone(),
                report: Some(rep),
            }
        }
        None => Sacrum {
            mesh: sac_mesh,
            file: sac_file,
            report: None,
        },
    })
}

/// Step 4: every IVD joint rebuilt, and what the pruning keeps.
pub(crate) struct Rebuilt {
    /// (upper, lower, joint index, rebuilt joint), caudal to cranial.
    pub joints: Vec<(Level, Level, usize, joints::RebuiltJoint)>,
    /// Renamed coordinates: old -> (joint, new).
    pub renames: BTreeMap<String, (String, String)>,
    pub prune: prune::PruneReport,
}

impl Rebuilt {
    /// Coordinate prefixes (`L4_L5`) of the rebuilt joints.
    pub(super) fn prefixes(&self) -> Vec<String> {
        self.joints
            .iter()
            .map(|(u, l, _, _)| joints::joint_prefix(*u, *l))
            .collect()
    }
}

/// Rebuild the IVD joints as 6-DoF bushing joints and decide what to keep.
pub(crate) fn rebuild_joints(
    generic: &Document,
    model: &Model,
    topo: &Topology,
    opts: &BaseOptions,
    gfile: &str,
) -> Result<Rebuilt> {
    // Each IVD joint rebuilt at its generic default transform.
    let gkin = Kinematics::new(model)?;
    let mut renames: BTreeMap<String, (String, String)> = BTreeMap::new();
    let mut rebuilt = Vec::new();
    let joint_els = generic.components("JointSet");
    for &(up, low, i) in &topo.ivd {
        let j = &model.joints[i];
        let el = joint_els
            .iter()
            .find(|e| e.name_attr() == j.name)
            .ok_or_else(|| {
                Error::invalid(gfile, format!("joint element '{}' not found", j.name))
            })?;
        let x0 = gkin.joint_transform(&j.name, &topo.defaults)?;
        let r = joints::rebuild_ivd_joint(el, j, &topo.frames[i], up, low, &opts.ivd, &x0)?;
        for (old, new) in &r.renames {
            renames.insert(old.clone(), (j.name.clone(), new.clone()));
        }
        rebuilt.push((up, low, i, r));
    }
    // Kept coordinates: the rebuilt joints' and the sacral joint's.
    let mut kept_coords: BTreeSet<String> = BTreeSet::new();
    for (up, low, _, _) in &rebuilt {
        for s in joints::COORD_SUFFIXES {
            kept_coords.insert(format!("{}_{s}", joints::joint_prefix(*up, *low)));
        }
    }
    for c in &model.joints[topo.sacral].coordinates {
        kept_coords.insert(c.name.clone());
    }
    let pr = prune::decide(model, &topo.kept_set, &kept_coords, &renames)?;
    Ok(Rebuilt {
        joints: rebuilt,
        renames,
        prune: pr,
    })
}

/// Step 5: the base document (kept bodies, the new joints, kept muscles and
/// bushings; other sets emptied) and the joint rows of the report.
pub(crate) fn assemble_document(
    generic: &Document,
    model: &Model,
    topo: &Topology,
    rebuilt: &Rebuilt,
    sac: &Sacrum,
    opts: &BaseOptions,
    gfile: &str,
) -> Result<(Document, Vec<JointRow>)> {
    let mut doc = generic.clone();
    let mname = format!("{}_base", model.name);
    doc.model_element_mut().set_attr("name", mname);
    keep_bodies(&mut doc, topo, rebuilt, sac, opts);
    let (new_joints, joint_rows, bushings) =
        joints_of_base(generic, model, topo, rebuilt, opts, gfile)?;
    {
        let objs = doc.set_objects_mut("JointSet");
        objs.children.clear();
        objs.children
            .extend(new_joints.into_iter().map(Node::Element));
    }
    // Forces: kept muscles (renamed coordinate sockets), then bushings.
    let force_els = generic.components("ForceSet");
    let mut muscles_out = Vec::new();
    for name in &rebuilt.prune.muscles_kept {
        let el = force_els
            .iter()
            .find(|e| e.name_attr() == name)
            .ok_or_else(|| Error::invalid(gfile, format!("muscle element '{name}' not found")))?;
        let mut el = (*el).clone();
        prune::rename_coordinate_sockets(&mut el, &rebuilt.renames);
        muscles_out.push(el);
    }
    {
        let objs = doc.set_objects_mut("ForceSet");
        objs.children.clear();
        objs.children
            .extend(muscles_out.into_iter().chain(bushings).map(Node::Element));
    }
    // Sets the base does not carry.
    for set in [
        "MarkerSet",
        "ConstraintSet",
        "ContactGeometrySet",
        "ControllerSet",
        "ProbeSet",
        "ComponentSet",
    ] {
        if doc.model_element().child(set).is_some() {
            doc.set_objects_mut(set).children.clear();
        }
    }
    Ok((doc, joint_rows))
}

/// Keep the kept bodies, their used wrap objects, and the swapped sacrum mesh.
fn keep_bodies(
    doc: &mut Document,
    topo: &Topology,
    rebuilt: &Rebuilt,
    sac: &Sacrum,
    opts: &BaseOptions,
) {
    {
        let objs = doc.set_objects_mut("BodySet");
        objs.children.retain(|n| match n {
            Node::Element(e) => topo.kept_set.contains(e.name_attr()),
            _ => true,
        });
    }
    for b in &topo.kept {
        let Some(el) = doc.component_mut("BodySet", b) else {
            continue;
        };
        // Wrap objects not used by kept muscles are dropped.
        if let Some(ws) = el
            .child_mut("WrapObjectSet")
            .and_then(|w| w.child_mut("objects"))
        {
            ws.children.retain(|n| match n {
                Node::Element(e) => rebuilt.prune.used_wrap_objects.contains(e.name_attr()),
                _ => true,
            });
        }
        if b == "sacrum" && opts.sacrum.is_some() {
            if let Some(ag) = el.child_mut("attached_geometry") {
                let mut first = true;
                ag.children.retain(|n| match n {
                    Node::Element(e) if e.name == "Mesh" => std::mem::replace(&mut first, false),
                    _ => true,
                });
                if let Some(mesh) = ag.elements_mut().find(|e| e.name == "Mesh") {
                    mesh.set_child_text("mesh_file", sac.file.clone());
                    mesh.set_child_text("scale_factors", "1 1 1");
                }
            }
        }
    }
}

/// The base's joints (fixed weld, sacral joint, rebuilt IVD joints), their
/// report rows and the bushings.
#[allow(clippy::type_complexity)]
fn joints_of_base(
    generic: &Document,
    model: &Model,
    topo: &Topology,
    rebuilt: &Rebuilt,
    opts: &BaseOptions,
    gfile: &str,
) -> Result<(Vec<Element>, Vec<JointRow>, Vec<Element>)> {
    let mut joint_rows = Vec::new();
    let mut new_joints = Vec::new();
    // The fixed body welded to ground at its generic default pose.
    let (fixed, name) = match opts.fixed {
        FixedBody::Pelvis => ("pelvis", "ground_pelvis"),
        FixedBody::Sacrum => ("sacrum", "ground_sacrum"),
    };
    new_joints.push(joints::weld_joint(
        name,
        "ground",
        fixed,
        &topo.pose_of(fixed, gfile)?,
    ));
    joint_rows.push(JointRow {
        name: name.into(),
        action: format!("{fixed} welded to ground at its generic default pose"),
        parent: "ground".into(),
        child: fixed.into(),
        coordinates: vec![],
        default_values: vec![],
        bushing: None,
    });
    // The pelvis-sacrum joint, reversed (welds only) when needed.
    let (el, row) = sacral_joint(generic, model, topo, opts, gfile)?;
    new_joints.push(el);
    joint_rows.push(row);
    // The rebuilt IVD joints and their bushings.
    let mut bushings = Vec::new();
    for (up, low, i, r) in &rebuilt.joints {
        let prefix = joints::joint_prefix(*up, *low);
        joint_rows.push(JointRow {
            name: model.joints[*i].name.clone(),
            action: "rebuilt as 6-DoF CustomJoint (LB, AR, FE, AP, SI, ML)".into(),
            parent: topo.frames[*i].parent_body.clone(),
            child: topo.frames[*i].child_body.clone(),
            coordinates: joints::COORD_SUFFIXES
                .iter()
                .map(|s| format!("{prefix}_{s}"))
                .collect(),
            default_values: r.defaults.to_vec(),
            bushing: Some(r.bushing.name_attr().to_string()),
        });
        new_joints.push(r.joint.clone());
        bushings.push(r.bushing.clone());
    }
    Ok((new_joints, joint_rows, bushings))
}

/// The pelvis-sacrum joint, kept or (a weld) reversed so that its parent
/// is on the ground side.
fn sacral_joint(
    generic: &Document,
    model: &Model,
    topo: &Topology,
    opts: &BaseOptions,
    gfile: &str,
) -> Result<(Element, JointRow)> {
    let sacral_joint = &model.joints[topo.sacral];
    let jf = &topo.frames[topo.sacral];
    let mut el = generic
        .components("JointSet")
        .iter()
        .find(|e| e.name_attr() == sacral_joint.name)
        .map(|e| (*e).clone())
        .ok_or_else(|| Error::invalid(gfile, "sacral joint element not found"))?;
    let parent_is_ground_side = match opts.fixed {
        FixedBody::Pelvis => jf.parent_body == "pelvis",
        FixedBody::Sacrum => jf.parent_body == "sacrum",
    };
    let action = if parent_is_ground_side {
        "kept".to_string()
    } else {
        if el.name != "WeldJoint" {
            return Err(Error::invalid(
                gfile,
                format!(
                    "joint '{}' between pelvis and sacrum is a {}: only a WeldJoint can be \
                     reversed for the requested fixed body",
                    sacral_joint.name, el.name
                ),
            ));
        }
        let p = el.child_text("socket_parent_frame").unwrap_or_default();
        let c = el.child_text("socket_child_frame").unwrap_or_default();
        el.set_child_text("socket_parent_frame", c);
        el.set_child_text("socket_child_frame", p);
        "reversed (weld)".to_string()
    };
    let (parent, child) = if parent_is_ground_side {
        (jf.parent_body.clone(), jf.child_body.clone())
    } else {
        (jf.child_body.clone(), jf.parent_body.clone())
    };
    let row = JointRow {
        name: sacral_joint.name.clone(),
        action,
        parent,
        child,
        coordinates: sacral_joint
            .coordinates
            .iter()
            .map(|c| c.name.clone())
            .collect(),
        default_values: sacral_joint
            .coordinates
            .iter()
            .map(|c| c.default_value)
            .collect(),
        bushing: None,
    };
    Ok((el, row))
}
