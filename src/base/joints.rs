//! Rebuilding the intervertebral joints as 6-DoF CustomJoints with a
//! coincident BushingForce, and grounding the model.
//!
//! Convention (documented for users of the base model):
//! * coordinates `<JOINT>_LB`, `<JOINT>_AR`, `<JOINT>_FE` (rotations about
//!   the joint frame's X, Y, Z: lateral bending, axial rotation,
//!   flexion-extension) and `<JOINT>_AP`, `<JOINT>_SI`, `<JOINT>_ML`
//!   (translations along X, Y, Z), where JOINT is `<UPPER>_<LOWER>` in level
//!   names, e.g. `L5_S1`, `T12_L1`;
//! * SpatialTransform rotation1..3 = X, Y, Z (body-fixed X-Y-Z), the order
//!   in which OpenSim's BushingForce measures its rotational deflection:
//!   with the bushing on the joint's own two frames the bushing acts on the
//!   joint's coordinates exactly as `-K q - C q'` (see
//!   `../shared/oracle/README.md`), so the stiffness of each axis is the
//!   stiffness of the coordinate of the same name;
//! * the joint keeps the generic joint's own parent and child offset frames
//!   (cloned verbatim) and the generic default pose: the new coordinates'
//!   default values are the X-Y-Z angles and the translation of the generic
//!   joint's transform at its default coordinate values;
//! * the bushing (`<JOINT>_bushing`) connects the joint's two frames when
//!   they coincide at the default pose (all defaults zero, the usual case);
//!   otherwise it owns two frames that coincide at the default pose, so it
//!   is undeflected there either way.

use super::template::IvdParams;
use crate::error::{Error, Result};
use crate::landmarks::Level;
use crate::osim::builders;
use crate::osim::model::{xyz_angles, Joint, JointFrames, JointKind};
use crate::osim::xml::Element;
use nalgebra::{Isometry3, Vector3};

/// Suffixes of the six coordinates, in SpatialTransform order.
pub const COORD_SUFFIXES: [&str; 6] = ["LB", "AR", "FE", "AP", "SI", "ML"];

/// Joint prefix `<UPPER>_<LOWER>` (e.g. `L5_S1`).
pub fn joint_prefix(upper: Level, lower: Level) -> String {
    format!("{upper}_{lower}")
}

/// What rebuilding one IVD joint produced.
#[derive(Debug, Clone)]
pub struct RebuiltJoint {
    /// The new CustomJoint element.
    pub joint: Element,
    /// The new BushingForce element.
    pub bushing: Element,
    /// Coordinate renames (old name, new name) for sockets that used them.
    pub renames: Vec<(String, String)>,
    /// Generic coordinates that have no counterpart (non-axis-aligned).
    pub lost: Vec<String>,
    /// Default values of the new coordinates, in [`COORD_SUFFIXES`] order.
    pub defaults: [f64; 6],
    /// `true` when the bushing owns frames (non-zero default pose).
    pub bushing_owns_frames: bool,
}

fn offset_frame_from(name: &str, body: &str, x: &Isometry3<f64>) -> Element {
    builders::offset_frame(
        name,
        &format!("/bodyset/{body}"),
        &x.translation.vector,
        &xyz_angles(&x.rotation.to_rotation_matrix()),
    )
}

/// Rebuild the IVD joint `joint` (element `el`, resolved frames `jf`)
/// between `upper` (child) and `lower` (parent) with the parameters `p`.
/// `x0` is the generic joint's transform (parent frame F to child frame M)
/// at the generic model's default coordinate values.
pub fn rebuild_ivd_joint(
    el: &Element,
    joint: &Joint,
    jf: &JointFrames,
    upper: Level,
    lower: Level,
    p: &IvdParams,
    x0: &Isometry3<f64>,
) -> Result<RebuiltJoint> {
    let ctx = format!("joint {}", joint.name);
    let prefix = joint_prefix(upper, lower);
    let cname = |s: &str| format!("{prefix}_{s}");
    // Generic default pose across the joint.
    let ang = xyz_angles(&x0.rotation.to_rotation_matrix());
    let t = x0.translation.vector;
    let defaults = [ang.x, ang.y, ang.z, t.x, t.y, t.z];
    // Coordinate renames by axis.
    let mut renames = Vec::new();
    let mut lost = Vec::new();
    if let JointKind::Custom { axes } = &joint.kind {
        for (i, ax) in axes.iter().enumerate() {
            let Some(old) = ax.coordinates.first() else {
                continue;
            };
            let dir = ax.axis.normalize();
            let k = (0..3).find(|&k| dir[k].abs() > 1.0 - 1e-9);
            match k {
                Some(k) => {
                    let new = cname(COORD_SUFFIXES[if i < 3 { k } else { 3 + k }]);
                    if *old != new {
                        renames.push((old.clone(), new));
                    }
                }
                None => lost.push(old.clone()),
            }
        }
    } else {
        for c in &joint.coordinates {
            lost.push(c.name.clone());
        }
    }
    // Frames: the generic joint's own, verbatim when it owns both.
    let frames_el = el.child("frames");
    let own = |socket: &str| -> Option<Element> {
        let bare = socket.trim();
        frames_el?
            .elements()
            .find(|f| f.name == "PhysicalOffsetFrame" && f.name_attr() == bare)
            .cloned()
    };
    let (parent_frame, child_frame) = match (
        own(&joint.socket_parent_frame),
        own(&joint.socket_child_frame),
    ) {
        (Some(a), Some(b)) => (a, b),
        _ => (
            offset_frame_from(
                &format!("{}_offset", jf.parent_body),
                &jf.parent_body,
                &jf.parent_in_body,
            ),
            offset_frame_from(
                &format!("{}_offset", jf.child_body),
                &jf.child_body,
                &jf.child_in_body,
            ),
        ),
    };
    let pf_name = parent_frame.name_attr().to_string();
    let cf_name = child_frame.name_attr().to_string();
    if pf_name == cf_name {
        return Err(Error::invalid(
            ctx,
            format!("parent and child frames share the name '{pf_name}'"),
        ));
    }
    let axes_dirs = [Vector3::x(), Vector3::y(), Vector3::z()];
    let coords: Vec<Element> = COORD_SUFFIXES
        .iter()
        .enumerate()
        .map(|(i, s)| {
            let range = if i < 3 {
                p.rotation_range
            } else {
                p.translation_range
            };
            let d = defaults[i];
            let range = [range[0].min(d), range[1].max(d)];
            builders::coordinate(&cname(s), d, range)
        })
        .collect();
    let cn = COORD_SUFFIXES.map(cname);
    let axes = builders::transform_axes(
        &std::array::from_fn(|i| axes_dirs[i % 3]),
        std::array::from_fn(|i| Some(cn[i].as_str())),
    );
    let new_joint = builders::custom_joint(
        &joint.name,
        parent_frame.clone(),
        child_frame.clone(),
        coords,
        axes,
    );
    // Bushing: on the joint's frames when they coincide at the default pose.
    let identity_default = defaults.iter().all(|v| v.abs() <= 1e-12);
    let bname = format!("{prefix}_bushing");
    let bushing = if identity_default {
        builders::bushing_force(
            &bname,
            &format!("/jointset/{}/{pf_name}", joint.name),
            &format!("/jointset/{}/{cf_name}", joint.name),
            &p.rotational_stiffness,
            &p.translational_stiffness,
            &p.rotational_damping,
            &p.translational_damping,
        )
    } else {
        // Frame 2 on the child body, where the parent frame is at the default pose.
        let f1 = offset_frame_from(
            &format!("{prefix}_bushing_frame1"),
            &jf.parent_body,
            &jf.parent_in_body,
        );
        let f2 = offset_frame_from(
            &format!("{prefix}_bushing_frame2"),
            &jf.child_body,
            &(jf.child_in_body * x0.inverse()),
        );
        builders::bushing_force(
            &bname,
            &format!("{prefix}_bushing_frame1"),
            &format!("{prefix}_bushing_frame2"),
            &p.rotational_stiffness,
            &p.translational_stiffness,
            &p.rotational_damping,
            &p.translational_damping,
        )
        .with_child(Element::new("frames").with_child(f1).with_child(f2))
    };
    Ok(RebuiltJoint {
        joint: new_joint,
        bushing,
        renames,
        lost,
        defaults,
        bushing_owns_frames: !identity_default,
    })
}

/// A WeldJoint `name` fixing `child` to `parent` at `x_parent_child`
/// (child body pose in the parent body).
pub fn weld_joint(name: &str, parent: &str, child: &str, x: &Isometry3<f64>) -> Element {
    let parent_path = if parent == "ground" {
        "/ground".to_string()
    } else {
        format!("/bodyset/{parent}")
    };
    let pf = builders::offset_frame(
        &format!("{parent}_offset"),
        &parent_path,
        &x.translation.vector,
        &xyz_angles(&x.rotation.to_rotation_matrix()),
    );
    let cf = builders::offset_frame(
        &format!("{child}_offset"),
        &format!("/bodyset/{child}"),
        &Vector3::zeros(),
        &Vector3::zeros(),
    );
    builders::weld_joint(name, pf, cf)
}
