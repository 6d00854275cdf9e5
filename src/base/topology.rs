//! Step 1 of the base builder: which levels are kept, the IVD joint of each
//! (lower vertebra as parent), the pelvis-sacrum joint, and the generic
//! model's default poses.

use super::kin::{Kinematics, Values};
use super::BaseOptions;
use crate::error::{Error, Result};
use crate::landmarks::Level;
use crate::osim::model::{JointFrames, Model};
use nalgebra::Isometry3;
use std::collections::{BTreeMap, BTreeSet};

/// The kept spine of the generic model.
pub(crate) struct Topology {
    /// Kept vertebrae, cranial to caudal (`top..=L5`).
    pub levels: Vec<Level>,
    /// Kept bodies: the vertebrae, then `sacrum` and `pelvis`.
    pub kept: Vec<String>,
    pub kept_set: BTreeSet<String>,
    /// Frames of every joint of the generic model.
    pub frames: Vec<JointFrames>,
    /// IVD joints, caudal to cranial: (upper, lower, joint index).
    pub ivd: Vec<(Level, Level, usize)>,
    /// Index of the pelvis-sacrum joint.
    pub sacral: usize,
    /// Generic default coordinate values and body poses.
    pub defaults: Values,
    pub poses: BTreeMap<String, Isometry3<f64>>,
}

impl Topology {
    /// Default pose of a generic body.
    pub(crate) fn pose_of(&self, body: &str, gfile: &str) -> Result<Isometry3<f64>> {
        self.poses
            .get(body)
            .copied()
            .ok_or_else(|| Error::invalid(gfile, format!("body '{body}' has no pose")))
    }
}

/// Select the kept levels and find their joints.
pub(crate) fn select_levels(model: &Model, opts: &BaseOptions, gfile: &str) -> Result<Topology> {
    // Kept levels and bodies; all must be in the generic model.
    if opts.top > Level::L5 {
        return Err(Error::invalid(
            "--keep",
            "the top kept level must be T1..L5",
        ));
    }
    let levels: Vec<Level> = Level::ALL[opts.top.index()..=Level::L5.index()].to_vec();
    let mut kept: Vec<String> = levels.iter().map(|l| l.body_name()).collect();
    kept.push("sacrum".into());
    kept.push("pelvis".into());
    let missing: Vec<&String> = kept.iter().filter(|b| model.body(b).is_none()).collect();
    if !missing.is_empty() {
        return Err(Error::invalid(
            gfile,
            format!(
                "the generic model lacks the bodies {} (a base model needs thoracic1..12, lumbar1..5, \
                 sacrum and pelvis for the kept levels {}..L5)",
                missing.iter().map(|s| format!("'{s}'")).collect::<Vec<_>>().join(", "),
                opts.top
            ),
        ));
    }
    // Joints: one IVD joint per kept vertebra, and the sacral joint.
    let frames = model.joint_frames()?;
    let ivd = ivd_joints(&levels, &frames, gfile)?;
    let sacral = frames
        .iter()
        .position(|f| {
            (f.parent_body == "pelvis" && f.child_body == "sacrum")
                || (f.parent_body == "sacrum" && f.child_body == "pelvis")
        })
        .ok_or_else(|| Error::invalid(gfile, "no joint between 'pelvis' and 'sacrum'"))?;
    // Generic default poses.
    let defaults: Values = model
        .coordinates()
        .map(|c| (c.name.clone(), c.default_value))
        .collect();
    let poses = Kinematics::new(model)?.body_poses(&defaults)?;
    Ok(Topology {
        kept_set: kept.iter().cloned().collect(),
        levels,
        kept,
        frames,
        ivd,
        sacral,
        defaults,
        poses,
    })
}

/// The IVD joint of every kept vertebra (the vertebra below as parent),
/// caudal to cranial.
fn ivd_joints(
    levels: &[Level],
    frames: &[JointFrames],
    gfile: &str,
) -> Result<Vec<(Level, Level, usize)>> {
    let mut ivd = Vec::new();
    for &up in levels.iter().rev() {
        let low = up.caudal().unwrap_or(Level::S1);
        let (ub, lb) = (up.body_name(), low.body_name());
        let found = frames
            .iter()
            .position(|f| f.parent_body == lb && f.child_body == ub);
        let Some(i) = found else {
            let reversed = frames
                .iter()
                .find(|f| f.parent_body == ub && f.child_body == lb);
            return Err(Error::invalid(
                gfile,
                match reversed {
                    Some(f) => format!(
                        "joint '{}' has '{ub}' as parent of '{lb}': the base builder needs the lower \
                         vertebra as parent",
                        f.joint
                    ),
                    None => format!("no joint between '{lb}' (parent) and '{ub}' (child)"),
                },
            ));
        };
        ivd.push((up, low, i));
    }
    Ok(ivd)
}
