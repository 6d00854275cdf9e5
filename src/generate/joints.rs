//! Step 4, the joint frames: disc centres and frames from the fitted
//! vertebrae, joint centres carried along the chain, and the writing of each
//! joint's parent and child offset frames.

use super::pose::Points;
use super::{chain, pose};
use super::{isb_rotation, sacral_rotation, JointScaling};
use crate::error::{Error, Result};
use crate::landmarks::{Code, Level};
use crate::osim::model::Model;
use crate::osim::props::{set_f64, set_vec3};
use crate::osim::Document;
use nalgebra::{Isometry3, Point3, UnitQuaternion, Vector3};
use std::collections::BTreeMap;

/// Base joint centres between consecutive vertebrae, keyed by the upper
/// level: the centre in the upper body and in the lower body.
pub type JointCentres = BTreeMap<Level, (Point3<f64>, Point3<f64>)>;

/// The base joint centres between consecutive vertebrae, each in the
/// upper and in the lower body.
pub(super) fn base_joint_centres(
    model: &Model,
    poses0: &BTreeMap<String, Isometry3<f64>>,
) -> Result<JointCentres> {
    let mut joint_centres = BTreeMap::new();
    for jf in model.joint_frames()? {
        let (Some(lu), Some(ll)) = (
            Level::from_body_name(&jf.child_body),
            Level::from_body_name(&jf.parent_body),
        ) else {
            continue;
        };
        let (Some(xu), Some(xl)) = (poses0.get(&jf.child_body), poses0.get(&jf.parent_body)) else {
            continue;
        };
        if lu.caudal() == Some(ll) {
            let in_lower = Point3::from(jf.parent_in_body.translation.vector);
            let in_upper = xu.inverse() * (xl * in_lower);
            joint_centres.insert(lu, (in_upper, in_lower));
        }
    }
    Ok(joint_centres)
}

/// Step 4: each IVD joint between a fitted vertebra and the one below at
/// the mid-point of IEC above and SEC below, oriented half-way between the
/// two ISB frames, written with undeflected bushings. Returns the joints
/// rewritten and the prefixes (`L4_L5`) of every IVD joint.
pub(super) fn rewrite_joint_frames(
    doc: &mut Document,
    model: &Model,
    fits: &BTreeMap<Level, pose::VertebraFit>,
    markers: &BTreeMap<Level, (String, Points)>,
    x_sacrum: &Isometry3<f64>,
    bfile: &str,
) -> Result<(Vec<String>, Vec<String>)> {
    let jframes = model.joint_frames()?;
    let pose_of = |l: Level| -> Isometry3<f64> {
        match fits.get(&l) {
            Some(f) => f.pose,
            None => *x_sacrum,
        }
    };
    let scaled_markers = |l: Level| -> Points {
        let (_, m) = &markers[&l];
        match fits.get(&l) {
            Some(f) => m
                .iter()
                .map(|(c, p)| (*c, pose::scale_point(p, &f.scale)))
                .collect(),
            None => m.clone(),
        }
    };
    let mut rewritten = Vec::new();
    let mut prefixes = Vec::new();
    for jf in &jframes {
        let (Some(lu), Some(ll)) = (
            Level::from_body_name(&jf.child_body),
            Level::from_body_name(&jf.parent_body),
        ) else {
            continue;
        };
        if lu.caudal() != Some(ll) {
            continue;
        }
        prefixes.push(format!("{lu}_{ll}"));
        if !fits.contains_key(&lu) {
            continue;
        }
        let (xu, xl) = (pose_of(lu), pose_of(ll));
        let (mu, ml) = (scaled_markers(lu), scaled_markers(ll));
        let iec = xu * mu[&Code::IEC];
        let sec = xl * ml[&Code::SEC];
        let ru = isb_rotation(&mu)
            .ok_or_else(|| Error::invalid(bfile, format!("the {lu} markers give no ISB frame")))?;
        let rl = if ll.is_sacrum() {
            sacral_rotation(&ml)
        } else {
            isb_rotation(&ml)
        }
        .ok_or_else(|| Error::invalid(bfile, format!("the {ll} markers give no frame")))?;
        let qu = xu.rotation * UnitQuaternion::from_rotation_matrix(&ru);
        let ql = xl.rotation * UnitQuaternion::from_rotation_matrix(&rl);
        let j = disc_frame(&iec, &sec, &qu, &ql);
        let p_in_l = xl.inverse() * j;
        let c_in_u = xu.inverse() * j;
        write_joint(
            doc,
            model,
            &jf.joint,
            &jf.parent_body,
            &jf.child_body,
            &p_in_l,
            &c_in_u,
        )?;
        rewritten.push(jf.joint.clone());
    }
    let prefixes: Vec<String> = prefixes;
    Ok((rewritten, prefixes))
}

/// An intervertebral joint's frame in ground: origin midway between a
/// point of the upper vertebra and one of the lower (the generic route:
/// the upper IEC and the lower SEC, the disc centre), orientation half-way
/// (quaternion midpoint) between the two vertebrae's frames `qu`, `ql`.
pub(super) fn disc_frame(
    iec: &Point3<f64>,
    sec: &Point3<f64>,
    qu: &UnitQuaternion<f64>,
    ql: &UnitQuaternion<f64>,
) -> Isometry3<f64> {
    Isometry3::from_parts(nalgebra::center(iec, sec).coords.into(), ql.slerp(qu, 0.5))
}

/// Where the chain's joints sit in the base model: the joint centre in
/// each of the two bodies, and each body's centre ([`base_body_centres`](super::fits::base_body_centres)),
/// all in the unscaled body frames.
pub(super) struct JointGeometry<'a> {
    pub(super) joint_centres: &'a JointCentres,
    pub(super) centres: &'a BTreeMap<Level, Point3<f64>>,
}

impl JointGeometry<'_> {
    /// A joint centre `p` of level `l`'s unscaled body frame, placed in its
    /// body scaled by `scale` under the joint model `scaling`.
    pub(super) fn place(
        &self,
        p: &Point3<f64>,
        l: Level,
        scale: &Vector3<f64>,
        scaling: JointScaling,
    ) -> Point3<f64> {
        match scaling {
            JointScaling::WithBody => pose::scale_point(p, scale),
            JointScaling::AboutCentre => {
                let c = self.centres.get(&l).copied().unwrap_or(Point3::origin());
                p + (pose::scale_point(&c, scale) - c)
            }
        }
    }
}

/// The chain's joints, each body's joint centre placed by `scaling`.
pub(super) fn chain_joints(
    fits: &BTreeMap<Level, pose::VertebraFit>,
    chain: &[Level],
    geometry: &JointGeometry,
    scaling: JointScaling,
) -> Vec<chain::ChainJoint> {
    let mut joints = Vec::new();
    for (k, w) in chain.windows(2).enumerate() {
        // A joint only between adjacent levels (a gap breaks the chain).
        if w[0].caudal() != Some(w[1]) {
            continue;
        }
        let (Some((qu, pl)), Some(fu), Some(fl)) = (
            geometry.joint_centres.get(&w[0]),
            fits.get(&w[0]),
            fits.get(&w[1]),
        ) else {
            continue;
        };
        joints.push(chain::ChainJoint {
            upper: k,
            lower: k + 1,
            in_upper: geometry.place(qu, w[0], &fu.scale, scaling),
            in_lower: geometry.place(pl, w[1], &fl.scale, scaling),
        });
    }
    joints
}

/// Every base joint centre between a fitted vertebra and the fitted
/// vertebra or sacrum below, carried into both bodies (scaled frames) by
/// their fits under `scaling`, keyed by the upper level.
pub(super) fn carried_joints(
    fits: &BTreeMap<Level, pose::VertebraFit>,
    geometry: &JointGeometry,
    scaling: JointScaling,
) -> JointCentres {
    let one = Vector3::repeat(1.0);
    let mut out = JointCentres::new();
    for (lu, (qu, pl)) in geometry.joint_centres {
        let (Some(fu), Some(ll)) = (fits.get(lu), lu.caudal()) else {
            continue;
        };
        let sl = match fits.get(&ll) {
            Some(f) => f.scale,
            None if ll.is_sacrum() => one,
            None => continue,
        };
        out.insert(
            *lu,
            (
                geometry.place(qu, *lu, &fu.scale, scaling),
                geometry.place(pl, ll, &sl, scaling),
            ),
        );
    }
    out
}

/// The chain smoothed under the joint model the landmarks support best
/// (higher restricted marginal likelihood; both models have the same
/// hyperparameters, and a tie keeps [`JointScaling::WithBody`]).
pub(super) fn best_joint_model(
    verts: &[chain::ChainVertebra],
    fits: &BTreeMap<Level, pose::VertebraFit>,
    chain: &[Level],
    geometry: &JointGeometry,
    sigma: f64,
) -> Result<Option<(chain::ChainSmoothed, JointScaling)>> {
    let mut best: Option<(chain::ChainSmoothed, JointScaling)> = None;
    for scaling in [JointScaling::WithBody, JointScaling::AboutCentre] {
        let joints = chain_joints(fits, chain, geometry, scaling);
        let Some(s) = chain::smooth_chain(verts, &joints, sigma)? else {
            continue;
        };
        if best.as_ref().is_none_or(|(b, _)| s.log_ml > b.log_ml) {
            best = Some((s, scaling));
        }
    }
    Ok(best)
}

/// Write a joint's two offset frames (in the parent and child bodies) and
/// zero its coordinates' defaults; bushings that own frames on the same two
/// bodies get the same frames.
pub(super) fn write_joint(
    doc: &mut Document,
    model: &Model,
    joint: &str,
    parent_body: &str,
    child_body: &str,
    p_in_parent: &Isometry3<f64>,
    c_in_child: &Isometry3<f64>,
) -> Result<()> {
    let file = model.file.display().to_string();
    let j = model
        .joint(joint)
        .ok_or_else(|| Error::invalid(&file, format!("no joint '{joint}'")))?;
    let owned = |socket: &str| -> Option<String> {
        let bare = socket.trim();
        j.frames
            .iter()
            .find(|f| f.name == bare || f.path.ends_with(&format!("/{bare}")))
            .map(|f| f.name.clone())
    };
    let (Some(pf), Some(cf)) = (owned(&j.socket_parent_frame), owned(&j.socket_child_frame)) else {
        return Err(Error::invalid(
            &file,
            format!(
                "joint '{joint}' does not own both of its offset frames (a base model from \
                 `osim-spine base` does): cannot place it"
            ),
        ));
    };
    let set_frame = |e: &mut crate::osim::xml::Element, body: &str, x: &Isometry3<f64>| {
        e.set_child_text("socket_parent", format!("/bodyset/{body}"));
        set_vec3(e, "translation", &x.translation.vector);
        set_vec3(
            e,
            "orientation",
            &crate::osim::model::xyz_angles(&x.rotation.to_rotation_matrix()),
        );
    };
    let el = doc
        .component_mut("JointSet", joint)
        .ok_or_else(|| Error::invalid(&file, format!("joint element '{joint}' not found")))?;
    if let Some(frames) = el.child_mut("frames") {
        for f in frames.elements_mut() {
            if f.name_attr() == pf {
                set_frame(f, parent_body, p_in_parent);
            } else if f.name_attr() == cf {
                set_frame(f, child_body, c_in_child);
            }
        }
    }
    if let Some(cs) = el.child_mut("coordinates") {
        for c in cs.elements_mut() {
            set_f64(c, "default_value", 0.0);
        }
    }
    // Bushings owning frames on these two bodies.
    for b in model.bushings() {
        if b.frames.len() != 2 {
            continue;
        }
        let owner = format!("/forceset/{}", b.name);
        let (Ok((b1, _)), Ok((b2, _))) = (
            model.resolve_frame(&owner, &b.socket_frame1),
            model.resolve_frame(&owner, &b.socket_frame2),
        ) else {
            continue;
        };
        if !(b1 == parent_body && b2 == child_body) {
            continue;
        }
        let n1 = b
            .socket_frame1
            .trim()
            .rsplit('/')
            .next()
            .unwrap_or("")
            .to_string();
        let n2 = b
            .socket_frame2
            .trim()
            .rsplit('/')
            .next()
            .unwrap_or("")
            .to_string();
        if let Some(frames) = doc
            .component_mut("ForceSet", &b.name)
            .and_then(|e| e.child_mut("frames"))
        {
            for f in frames.elements_mut() {
                if f.name_attr() == n1 {
                    set_frame(f, parent_body, p_in_parent);
                } else if f.name_attr() == n2 {
                    set_frame(f, child_body, c_in_child);
                }
            }
        }
    }
    Ok(())
}
