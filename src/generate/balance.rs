//! Levels above the landmarks' field of view (`--above-fov balance|keep`).
//!
//! A CT that stops at, say, T9 leaves T8-T1 at the base model's joint
//! angles, so they inherit the tilt of the top measured vertebra and T1
//! can end far to one side. `balance` (the default) bends the unmeasured
//! joints in the frontal plane (about the ground's anterior axis, through
//! each joint centre) by a compensatory curve, linear along the levels
//! (`theta_k = a + b s_k`, `s_k` from 0 at the lowest joint to 1 at T1),
//! with the least compensation that makes T1's cranial axis level (no
//! coronal tilt) and brings its centre within [`CORONAL_BALANCE_MM`] of
//! the vertical through S1_SEC (the SRS threshold of coronal balance):
//! first an even bend (`b = 0`, the arc with the smallest bend per joint)
//! that levels T1; only if that leaves T1 further off, `a`, `b` solved so
//! that T1 ends at that distance on its side. Balancing T1 exactly over
//! the sacrum would add a curve the patient need not have (scoliotic
//! patients stand with T1 up to 20-25 mm off). With one unmeasured joint
//! the two goals are met in the least-squares sense.
//! No joint bends more than [`MAX_BEND_DEG`] (a severe scoliotic curve's
//! angulation per level): with few unmeasured levels the goals are
//! then met only as far as that allows, and the report says so.
//! `keep` leaves the base joints as they are. Both report the unmeasured
//! levels and where T1 ends.

use super::pose::Points;
use crate::base::kin::Kinematics;
use crate::landmarks::{Code, Level};
use crate::osim::model::{JointFrames, Model};
use crate::osim::Document;
use crate::util::lm::{self, LmOptions};
use crate::{Error, Result};
use nalgebra::{
    DMatrix, DVector, Isometry3, Point3, Translation3, UnitQuaternion, Vector2, Vector3,
};
use std::collections::BTreeMap;

/// Largest frontal bend added at one unmeasured joint (deg): the steepest
/// per-level angulation of a severe scoliotic curve (a 90 deg Cobb angle
/// over six levels), so a compensatory curve is never sharper than a
/// scoliotic one.
pub const MAX_BEND_DEG: f64 = 15.0;

/// Weight of T1's lateral offset against its tilt in the balance.
const POSITION_WEIGHT: f64 = 10.0;

/// Largest lateral offset of T1's centre from the vertical through S1_SEC
/// that counts as balanced (mm): the Scoliosis Research Society's 2 cm
/// threshold of coronal imbalance (C7 plumb line to the central sacral
/// vertical line).
pub const CORONAL_BALANCE_MM: f64 = 20.0;

/// How levels above the field of view are placed.
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    Default,
    serde::Serialize,
    serde::Deserialize,
    clap::ValueEnum,
)]
#[serde(rename_all = "lowercase")]
pub enum AboveFov {
    /// Compensatory frontal curve: T1 level and within
    /// [`CORONAL_BALANCE_MM`] of the vertical through S1_SEC.
    #[default]
    Balance,
    /// The base model's joint angles above the top measured level.
    Keep,
}

impl std::str::FromStr for AboveFov {
    type Err = Error;
    fn from_str(s: &str) -> Result<AboveFov> {
        match s.trim().to_ascii_lowercase().as_str() {
            "balance" => Ok(AboveFov::Balance),
            "keep" => Ok(AboveFov::Keep),
            o => Err(Error::invalid(
                "--above-fov",
                format!("'{o}' is not a mode: expected 'balance' or 'keep'"),
            )),
        }
    }
}

/// What was done above the field of view, and where T1 ended.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct AboveFovReport {
    /// What was done above the field of view.
    pub mode: AboveFov,
    /// Levels above the field of view (not measured), caudal to cranial.
    pub unmeasured: Vec<Level>,
    /// Levels whose joint to the level below was bent (balance), caudal to cranial.
    pub balanced: Vec<Level>,
    /// Frontal bend added at each balanced joint (deg, + about anterior).
    pub bend_deg: Vec<f64>,
    /// T1 centre minus the vertical through S1_SEC, along the right axis (mm).
    pub t1_lateral_offset_mm: f64,
    /// T1 centre minus S1_SEC along the anterior axis (mm).
    pub t1_anterior_offset_mm: f64,
    /// Coronal tilt of T1's cranial axis from vertical (deg, + toward the right).
    pub t1_coronal_tilt_deg: f64,
    /// Whether a bend reached [`MAX_BEND_DEG`] (balance only as far as
    /// the joints allow).
    pub bend_limited: bool,
}

/// One unmeasured joint: its child level, its frames and the child's pose
/// relative to the parent at default coordinates.
struct Link<'a> {
    level: Level,
    jf: &'a JointFrames,
    parent_to_child: Isometry3<f64>,
}

/// The base model's T1 markers needed for its centre and cranial axis.
struct T1Markers {
    sec: Point3<f64>,
    iec: Point3<f64>,
}

/// Place the levels above `top` (the most cranial measured vertebra) in
/// `doc` as `mode` asks; `None` when nothing lies above the field of view.
/// `s1_sec` is the patient's S1_SEC in ground (after registration).
pub fn place_above_fov(
    doc: &mut Document,
    base_model: &Model,
    top: Level,
    s1_sec: Point3<f64>,
    t1_markers: Option<&Points>,
    mode: AboveFov,
) -> Result<Option<AboveFovReport>> {
    let Some(t1) = t1_markers.and_then(|m| {
        Some(T1Markers {
            sec: *m.get(&Code::SEC)?,
            iec: *m.get(&Code::IEC)?,
        })
    }) else {
        return Ok(None);
    };
    // Current poses and the chain of unmeasured joints above `top`.
    let model = doc.model()?;
    let kin = Kinematics::new(&model)?;
    let poses = kin.body_poses(&kin.default_values())?;
    let frames = model.joint_frames()?;
    let links = unmeasured_links(top, &frames, &poses);
    if links.is_empty() {
        return Ok(None);
    }
    let x_top = poses[&top.body_name()];
    // Solve the curve (balance) or keep zeros.
    let (thetas, bend_limited) = match mode {
        AboveFov::Balance => solve_curve(&links, &x_top, &t1, s1_sec)?,
        AboveFov::Keep => (vec![0.0; links.len()], false),
    };
    if mode == AboveFov::Balance {
        write_bends(doc, base_model, &links, &x_top, &thetas)?;
    }
    let (centre, axis) = t1_state(&links, &x_top, &thetas, &t1);
    Ok(Some(AboveFovReport {
        mode,
        unmeasured: links.iter().map(|l| l.level).collect(),
        balanced: match mode {
            AboveFov::Balance => links.iter().map(|l| l.level).collect(),
            AboveFov::Keep => Vec::new(),
        },
        bend_deg: match mode {
            AboveFov::Balance => thetas.iter().map(|t| t.to_degrees()).collect(),
            AboveFov::Keep => Vec::new(),
        },
        t1_lateral_offset_mm: (centre.z - s1_sec.z) * 1e3,
        t1_anterior_offset_mm: (centre.x - s1_sec.x) * 1e3,
        t1_coronal_tilt_deg: axis.z.atan2(axis.y).to_degrees(),
        bend_limited,
    }))
}

/// The joints from `top` up to T1 (child level above its parent level),
/// caudal to cranial; stops at the first level without a joint.
fn unmeasured_links<'a>(
    top: Level,
    frames: &'a [JointFrames],
    poses: &BTreeMap<String, Isometry3<f64>>,
) -> Vec<Link<'a>> {
    let mut out = Vec::new();
    let mut lower = top;
    while let Some(up) = lower.cranial() {
        let jf = frames
            .iter()
            .find(|f| f.child_body == up.body_name() && f.parent_body == lower.body_name());
        let (Some(jf), Some(xp), Some(xc)) = (
            jf,
            poses.get(&lower.body_name()),
            poses.get(&up.body_name()),
        ) else {
            break;
        };
        out.push(Link {
            level: up,
            jf,
            parent_to_child: xp.inverse() * xc,
        });
        lower = up;
    }
    out
}

/// Rotation by `theta` about ground's anterior axis through the joint
/// centre, expressed in the parent body (posed at `x_parent`).
fn bend_in_parent(x_parent: &Isometry3<f64>, jf: &JointFrames, theta: f64) -> Isometry3<f64> {
    let axis = x_parent.rotation.inverse() * Vector3::x_axis();
    let r = UnitQuaternion::from_axis_angle(&axis, theta);
    let j = jf.parent_in_body.translation.vector;
    Translation3::from(j)
        * Isometry3::from_parts(Translation3::identity(), r)
        * Translation3::from(-j)
}

/// Poses of the unmeasured bodies for bends `thetas`, caudal to cranial.
fn chain_poses(links: &[Link], x_top: &Isometry3<f64>, thetas: &[f64]) -> Vec<Isometry3<f64>> {
    let mut x = *x_top;
    let mut out = Vec::with_capacity(links.len());
    for (l, th) in links.iter().zip(thetas) {
        x = x * bend_in_parent(&x, l.jf, *th) * l.parent_to_child;
        out.push(x);
    }
    out
}

/// T1 centre (midpoint of its endplate centres) and cranial axis in ground.
fn t1_state(
    links: &[Link],
    x_top: &Isometry3<f64>,
    thetas: &[f64],
    t1: &T1Markers,
) -> (Point3<f64>, Vector3<f64>) {
    let x = *chain_poses(links, x_top, thetas)
        .last()
        .expect("links not empty");
    let centre = x * nalgebra::center(&t1.sec, &t1.iec);
    let axis = (x.rotation * (t1.sec - t1.iec)).normalize();
    (centre, axis)
}

/// Bends along the chain for the curve parameters `q` = (bend of the
/// lowest joint, bend of the highest), linear in between.
fn curve(q: &Vector2<f64>, n: usize) -> Vec<f64> {
    (0..n)
        .map(|k| {
            let s = if n > 1 {
                k as f64 / (n - 1) as f64
            } else {
                0.0
            };
            q.x + (q.y - q.x) * s
        })
        .collect()
}

/// The bends above the field of view: an even bend that levels T1 if it
/// leaves T1 within [`CORONAL_BALANCE_MM`] of the vertical through
/// `s1_sec`; otherwise the linear curve that levels T1 at that distance.
/// Returns the bends and whether a bound was reached.
fn solve_curve(
    links: &[Link],
    x_top: &Isometry3<f64>,
    t1: &T1Markers,
    s1_sec: Point3<f64>,
) -> Result<(Vec<f64>, bool)> {
    let n = links.len();
    // Level T1 with an even bend (position ignored).
    let (q, limited) = fit_curve(links, x_top, t1, s1_sec, None)?;
    let even = curve(&q, n);
    let (c, _) = t1_state(links, x_top, &even, t1);
    let off = c.z - s1_sec.z;
    let tol = CORONAL_BALANCE_MM * 1e-3;
    if off.abs() <= tol {
        return Ok((even, limited));
    }
    // Too far off: bring T1 to the edge of the balanced range.
    let (q, limited) = fit_curve(links, x_top, t1, s1_sec, Some(tol.copysign(off)))?;
    Ok((curve(&q, n), limited))
}

/// Solve `q` by the one least-squares optimiser (finite-difference
/// Jacobian, both ends kept within [`MAX_BEND_DEG`]) so that T1 is level
/// and, with `target` (m), its centre lies `target` to the right of the
/// vertical through `s1_sec`; without it the bend is even (`q.x = q.y`,
/// one unknown) and only the tilt counts. Returns `q` and whether a bound
/// was reached.
fn fit_curve(
    links: &[Link],
    x_top: &Isometry3<f64>,
    t1: &T1Markers,
    s1_sec: Point3<f64>,
    target: Option<f64>,
) -> Result<(Vector2<f64>, bool)> {
    let n = links.len();
    let cap = MAX_BEND_DEG.to_radians();
    // Lateral offset over the chain length: both residuals in radians.
    let (c0, _) = t1_state(links, x_top, &vec![0.0; n], t1);
    let len = (c0 - x_top.translation.vector).coords.norm().max(1e-3);
    // Both ends move together for an even bend or a single joint.
    let even = target.is_none() || n == 1;
    let ends = |x: &[f64]| {
        if even {
            Vector2::new(x[0], x[0])
        } else {
            Vector2::new(x[0], x[1])
        }
    };
    // T1 at its place first: when the bends are limited, a T1 that leans
    // is better than one that stands off to the side.
    let resid = |x: &[f64]| {
        let (c, a) = t1_state(links, x_top, &curve(&ends(x), n), t1);
        let pos = target.map_or(0.0, |t| POSITION_WEIGHT * (c.z - s1_sec.z - t) / len);
        DVector::from_vec(vec![pos, a.z.atan2(a.y)])
    };
    let unknowns = if even { 1 } else { 2 };
    let residuals =
        |x: &[f64], want_jacobian: bool| -> Result<(DVector<f64>, Option<DMatrix<f64>>)> {
            let r = resid(x);
            let jac = want_jacobian.then(|| {
                let h = 1e-7;
                let columns: Vec<DVector<f64>> = (0..unknowns)
                    .map(|k| {
                        let mut xh = x.to_vec();
                        xh[k] += h;
                        (resid(&xh) - &r) / h
                    })
                    .collect();
                DMatrix::from_columns(&columns)
            });
            Ok((r, jac))
        };
    let fit = lm::minimize(
        residuals,
        &vec![0.0; unknowns],
        &vec![-cap; unknowns],
        &vec![cap; unknowns],
        // The residuals reach zero unless a bend is limited: iterate to
        // round-off, not to a relative gradient.
        &LmOptions {
            gtol: 0.0,
            xtol: 1e-14,
            ..LmOptions::default()
        },
    )?;
    let q = ends(&fit.x);
    let limited = q.iter().any(|v| v.abs() >= cap * (1.0 - 1e-9));
    Ok((q, limited))
}

/// Write the bent joint frames: each parent frame turned about the joint
/// centre, each child frame so that the child sits at its new pose with
/// the coordinates at zero (bushings stay undeflected: see `write_joint`).
fn write_bends(
    doc: &mut Document,
    base_model: &Model,
    links: &[Link],
    x_top: &Isometry3<f64>,
    thetas: &[f64],
) -> Result<()> {
    let poses = chain_poses(links, x_top, thetas);
    let mut x_parent = *x_top;
    for ((l, th), x_child) in links.iter().zip(thetas).zip(&poses) {
        let p = bend_in_parent(&x_parent, l.jf, *th) * l.jf.parent_in_body;
        let c = x_child.inverse() * x_parent * p;
        super::write_joint(
            doc,
            base_model,
            &l.jf.joint,
            &l.jf.parent_body,
            &l.jf.child_body,
            &p,
            &c,
        )?;
        x_parent = *x_child;
    }
    Ok(())
}
