//! The procedural skeleton: stature scaling, per-level geometry, the
//! neutral sagittal alignment (joint frames) and the default-pose body
//! transforms.
//!
//! Alignment rule (`templates/alignment.toml`): segment angles (superior
//! endplate of the upper vertebra to superior endplate of the lower one,
//! positive = lordotic = +Z rotation) are set from the Cobb targets; each
//! IVD joint's parent frame sits in the disc centre and is rotated about Z
//! by `theta = w_lower + seg - w_upper` (w = body wedge), so that at default
//! coordinates (all zero) the Cobb angles are exactly the targets. The
//! disc between two bodies takes the wedge `seg - w_upper`.

use super::pelvis::{self, PelvisGeometry, PelvisInputs};
use super::tables::Templates;
use super::vertebra::{self, LevelShape, VertebraGeometry};
use super::{ProceduralOptions, Sex};
use crate::anatomy::DimensionTable;
use crate::error::{Error, Result};
use crate::landmarks::Level;
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use std::collections::BTreeMap;

/// One intervertebral joint of the chain (`<UP>_<LOW>_IVDjnt`).
#[derive(Debug, Clone, PartialEq)]
pub struct JointSpec {
    /// e.g. `L5_S1_IVDjnt`.
    pub name: String,
    /// e.g. `L5_S1` (coordinates `<prefix>_FE`, `_LB`, `_AR`).
    pub prefix: String,
    /// The upper (child) level.
    pub upper: Level,
    /// Parent body name (the lower vertebra, or `sacrum`).
    pub parent_body: String,
    /// Origin of the parent frame in the parent body (m).
    pub translation: Vector3<f64>,
    /// Rotation of the parent frame about the parent body's Z axis (rad).
    pub angle: f64,
    /// Segment angle (rad; + lordotic).
    pub segment_angle: f64,
    /// Disc wedge angle (rad).
    pub disc_wedge: f64,
    /// Mean disc height (m).
    pub disc_height: f64,
}

/// The generated skeleton (no muscles, no document yet).
#[derive(Debug, Clone)]
pub struct Skeleton {
    /// The sex whose tables were used.
    pub sex: Sex,
    /// Stature (m).
    pub stature: f64,
    /// Stature / reference stature of the dimension table.
    pub scale: f64,
    /// Scaled dimensions T1..L5.
    pub levels: Vec<LevelShape>,
    /// Vertebrae T1..L5 in their body frames.
    pub vertebrae: Vec<VertebraGeometry>,
    /// Sacrum and pelvis meshes and landmarks.
    pub pelvis: PelvisGeometry,
    /// IVD joints, cranial to caudal (T1_T2 .. L5_S1).
    pub joints: Vec<JointSpec>,
    /// Body -> ground transform at the default pose (all coordinates 0).
    pub poses: BTreeMap<String, Isometry3<f64>>,
    /// Inter-ASIS distance (m).
    pub inter_asis: f64,
}

fn rz(a: f64) -> UnitQuaternion<f64> {
    UnitQuaternion::from_axis_angle(&Vector3::z_axis(), a)
}

impl Skeleton {
    /// Vertebra of `level` (T1..L5).
    pub fn vertebra(&self, level: Level) -> Option<&VertebraGeometry> {
        self.vertebrae.iter().find(|v| v.level == level)
    }
    /// Default-pose transform of body `name`.
    pub fn pose(&self, name: &str) -> Result<&Isometry3<f64>> {
        self.poses
            .get(name)
            .ok_or_else(|| Error::invalid("procedural skeleton", format!("no body '{name}'")))
    }
    /// A landmark in its body frame: `(body name, point)`. `owner` is a
    /// level (`T1`..`L5`), `sacrum` or `pelvis`; sided landmarks are looked
    /// up as `<name>_<side>` first.
    pub fn landmark(&self, owner: &str, name: &str, side: &str) -> Result<(String, Point3<f64>)> {
        let (body, map) = match owner {
            "sacrum" => ("sacrum".to_string(), &self.pelvis.sacrum_landmarks),
            "pelvis" => ("pelvis".to_string(), &self.pelvis.pelvis_landmarks),
            lv => {
                let level: Level = lv.parse().map_err(|_| {
                    Error::invalid("procedural landmarks", format!("unknown level '{lv}'"))
                })?;
                let v = self.vertebra(level).ok_or_else(|| {
                    Error::invalid("procedural landmarks", format!("no vertebra {level}"))
                })?;
                (level.body_name(), &v.landmarks)
            }
        };
        let p = map
            .get(&format!("{name}_{side}"))
            .or_else(|| map.get(name))
            .ok_or_else(|| {
                Error::invalid(
                    "procedural landmarks",
                    format!("{owner} has no landmark '{name}' (side {side})"),
                )
            })?;
        Ok((body, *p))
    }
}

/// Distribute `total` over weights.
fn distribute(total: f64, weights: &[f64]) -> Vec<f64> {
    let s: f64 = weights.iter().sum();
    weights.iter().map(|w| total * w / s).collect()
}

/// Segment angles (rad, + lordotic) of the 17 joints T1-T2 .. L5-S1 from
/// the alignment targets; `w` are the body wedges T1..L5.
fn segment_angles(t: &Templates, w: &[f64]) -> Vec<f64> {
    let a = &t.alignment;
    let mut seg = vec![0.0; 17];
    // lumbar: L1-L2 .. L5-S1 (joints 12..16)
    let ll = a.lumbar.lordosis_l1_s1_deg.to_radians();
    for (i, v) in distribute(ll, &a.lumbar.segment_weights)
        .into_iter()
        .enumerate()
    {
        seg[12 + i] = v;
    }
    seg[11] = a.thoracic.thoracolumbar_deg.to_radians();
    // thoracic T4-T5 .. T11-T12 (joints 3..10): sum = -TK - w_T12
    let tk = a.thoracic.kyphosis_t4_t12_deg.to_radians();
    let w_t12 = w.get(11).copied().unwrap_or(0.0);
    let weights: Vec<f64> = (0..8)
        .map(|k| (std::f64::consts::PI * (k as f64 + 0.5) / 8.0).sin())
        .collect();
    let th = distribute(-tk - w_t12, &weights);
    for (i, v) in th.iter().enumerate() {
        seg[3 + i] = *v;
    }
    let mean = th.iter().sum::<f64>() / 8.0;
    for s in seg.iter_mut().take(3) {
        *s = a.thoracic.upper_fraction_of_mean * mean;
    }
    seg
}

/// Build the skeleton for `opts`.
pub fn build(opts: &ProceduralOptions, t: &Templates) -> Result<Skeleton> {
    let sh = &t.shape;
    let stature = match opts.stature {
        Some(s) => s,
        None => match opts.sex {
            Sex::Male => sh.default_stature_male_m,
            Sex::Female => sh.default_stature_female_m,
        },
    };
    if !stature.is_finite() || stature < sh.min_stature_m || stature > sh.max_stature_m {
        return Err(Error::invalid(
            "--stature",
            format!(
                "{stature} m is outside {}..{} m (give the stature in metres, e.g. 1.72)",
                sh.min_stature_m, sh.max_stature_m
            ),
        ));
    }
    let k = stature / sh.reference_stature_m;
    let table = DimensionTable::embedded()?;
    let levels: Vec<LevelShape> = Level::ALL[..17]
        .iter()
        .map(|l| LevelShape::from_table(table.level(*l), k))
        .collect();
    let s1 = table.level(Level::S1);
    let vertebrae: Vec<VertebraGeometry> = levels
        .iter()
        .map(|s| vertebra::generate(s, &sh.body, &sh.posterior))
        .collect::<Result<_>>()?;
    let inter_asis = k * match opts.sex {
        Sex::Male => sh.pelvis.inter_asis_male_m,
        Sex::Female => sh.pelvis.inter_asis_female_m,
    };
    let al = &t.alignment;
    let pel = pelvis::generate(
        &sh.sacrum,
        &sh.pelvis,
        &PelvisInputs {
            k,
            w: inter_asis,
            s1_width: k * s1.sup_ep_width.mean,
            s1_depth: k * s1.sup_ep_depth.mean,
            sacral_slope: al.pelvis.sacral_slope_deg.to_radians(),
            pelvic_tilt: al.pelvis.pelvic_tilt_deg.to_radians(),
            pelvic_radius: k * al.pelvis.pelvic_radius_m,
        },
    )?;

    let wedges: Vec<f64> = levels.iter().map(|s| s.wedge()).collect();
    let seg = segment_angles(t, &wedges);
    let ss = al.pelvis.sacral_slope_deg.to_radians();
    let mut joints = Vec::with_capacity(17);
    for j in 0..17 {
        let upper = Level::ALL[j];
        let lower = Level::ALL[j + 1];
        let w_u = wedges[j];
        let d = levels[j].disc_below;
        let delta = seg[j] - w_u;
        // lower body: base orientation of its superior endplate and centre
        let (base, w_l, c_sup) = if lower == Level::S1 {
            (-ss, 0.0, Point3::origin())
        } else {
            let v = &vertebrae[j + 1];
            (0.0, wedges[j + 1], v.superior_centre)
        };
        let dir = rz(base + w_l + 0.5 * delta) * Vector3::y();
        let translation = c_sup.coords + dir * (0.5 * d);
        let angle = base + w_l + seg[j] - w_u;
        joints.push(JointSpec {
            name: format!("{upper}_{lower}_IVDjnt"),
            prefix: format!("{upper}_{lower}"),
            upper,
            parent_body: lower.body_name(),
            translation,
            angle,
            segment_angle: seg[j],
            disc_wedge: delta,
            disc_height: d,
        });
    }

    let mut poses = BTreeMap::new();
    poses.insert("pelvis".to_string(), Isometry3::identity());
    let sac = Isometry3::from_parts(
        Translation3::from(pel.sacrum_origin.coords),
        UnitQuaternion::identity(),
    );
    poses.insert("sacrum".to_string(), sac);
    for jt in joints.iter().rev() {
        let parent = poses
            .get(&jt.parent_body)
            .copied()
            .ok_or_else(|| Error::invalid("procedural skeleton", "internal: joint order"))?;
        let local = Isometry3::from_parts(Translation3::from(jt.translation), rz(jt.angle));
        poses.insert(jt.upper.body_name(), parent * local);
    }
    Ok(Skeleton {
        sex: opts.sex,
        stature,
        scale: k,
        levels,
        vertebrae,
        pelvis: pel,
        joints,
        poses,
        inter_asis,
    })
}
