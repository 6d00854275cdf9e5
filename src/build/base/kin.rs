//! Forward kinematics on a typed [`Model`] snapshot, enough for the base
//! builder's geometric work (default poses, test poses, muscle paths): body
//! poses in ground for given coordinate values, for Weld, Pin, Free and
//! Custom joints, computed as OpenSim does
//! (`X_GB = X_GP X_PF X_FM(q) inv(X_BM)`, CustomJoint rotations as
//! successive body-fixed rotations about the TransformAxis axes, the
//! translation along the parent joint frame's axes).

use crate::error::{Error, Result};
use crate::osim::model::{Joint, JointFrames, JointKind, Muscle, PathPointKind};
use crate::osim::Model;
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use std::collections::BTreeMap;

/// Coordinate values by name (rad or m).
pub type Values = BTreeMap<String, f64>;

/// Joint frames resolved once, joints in an order where every parent body
/// is placed before its child.
pub struct Kinematics<'a> {
    model: &'a Model,
    frames: Vec<JointFrames>,
    order: Vec<usize>,
}

/// Transform across a joint, from its parent frame F to its child frame M.
pub fn joint_transform(joint: &Joint, q: &Values) -> Result<Isometry3<f64>> {
    let val = |c: &str| -> Result<f64> {
        q.get(c).copied().ok_or_else(|| {
            Error::invalid(
                format!("joint {}", joint.name),
                format!("no value for coordinate '{c}'"),
            )
        })
    };
    let coord = |i: usize| -> Result<f64> {
        let c = joint.coordinates.get(i).ok_or_else(|| {
            Error::invalid(
                format!("joint {}", joint.name),
                format!("{} needs coordinate {}", joint.class, i + 1),
            )
        })?;
        val(&c.name)
    };
    match &joint.kind {
        JointKind::Weld => Ok(Isometry3::identity()),
        JointKind::Pin => Ok(Isometry3::rotation(Vector3::z() * coord(0)?)),
        JointKind::Free => {
            let r =
                crate::osim::model::body_fixed_xyz(&Vector3::new(coord(0)?, coord(1)?, coord(2)?));
            Ok(Isometry3::from_parts(
                Translation3::new(coord(3)?, coord(4)?, coord(5)?),
                UnitQuaternion::from_rotation_matrix(&r),
            ))
        }
        JointKind::Custom { axes } => {
            let mut rot = UnitQuaternion::identity();
            let mut p = Vector3::zeros();
            for (i, ax) in axes.iter().enumerate() {
                let x = match ax.coordinates.first() {
                    Some(c) => val(c)?,
                    None => 0.0,
                };
                let f = ax.function.eval(x);
                let Some(dir) = ax.axis.try_normalize(1e-12) else {
                    return Err(Error::invalid(
                        format!("joint {}", joint.name),
                        format!("{} has a zero axis", ax.name),
                    ));
                };
                if i < 3 {
                    rot *= UnitQuaternion::from_scaled_axis(dir * f);
                } else {
                    p += dir * f;
                }
            }
            Ok(Isometry3::from_parts(Translation3::from(p), rot))
        }
        JointKind::Other => Err(Error::invalid(
            format!("joint {}", joint.name),
            format!("joint class {} is not supported here", joint.class),
        )),
    }
}

impl<'a> Kinematics<'a> {
    /// Resolve the joint frames and a parent-before-child order.
    pub fn new(model: &'a Model) -> Result<Kinematics<'a>> {
        let frames = model.joint_frames()?;
        let mut placed: Vec<&str> = vec!["ground"];
        let mut order = Vec::new();
        let mut left: Vec<usize> = (0..frames.len()).collect();
        while !left.is_empty() {
            let before = left.len();
            left.retain(|&i| {
                if placed.contains(&frames[i].parent_body.as_str()) {
                    order.push(i);
                    placed.push(frames[i].child_body.as_str());
                    false
                } else {
                    true
                }
            });
            if left.len() == before {
                return Err(Error::invalid(
                    model.file.display().to_string(),
                    "joint graph is not a tree rooted at ground",
                ));
            }
        }
        Ok(Kinematics {
            model,
            frames,
            order,
        })
    }

    /// The model.
    pub fn model(&self) -> &Model {
        self.model
    }

    /// Resolved joint frames, in model joint order.
    pub fn frames(&self) -> &[JointFrames] {
        &self.frames
    }

    /// Every coordinate at its default value.
    pub fn default_values(&self) -> Values {
        self.model
            .coordinates()
            .map(|c| (c.name.clone(), c.default_value))
            .collect()
    }

    /// Pose of every body (and "ground") in ground.
    pub fn body_poses(&self, q: &Values) -> Result<BTreeMap<String, Isometry3<f64>>> {
        let mut out = BTreeMap::new();
        out.insert("ground".to_string(), Isometry3::identity());
        for &i in &self.order {
            let jf = &self.frames[i];
            let j = &self.model.joints[i];
            let x_gp = out.get(&jf.parent_body).copied().ok_or_else(|| {
                Error::invalid(
                    format!("joint {}", j.name),
                    format!("parent body '{}' not placed", jf.parent_body),
                )
            })?;
            let x_fm = joint_transform(j, q)?;
            let x_gb = x_gp * jf.parent_in_body * x_fm * jf.child_in_body.inverse();
            out.insert(jf.child_body.clone(), x_gb);
        }
        Ok(out)
    }
}

/// A muscle path point resolved at a pose.
#[derive(Debug, Clone, PartialEq)]
pub struct PathPointAt {
    /// Point name.
    pub name: String,
    /// Body it is fixed to.
    pub body: String,
    /// Location in that body (m).
    pub local: Point3<f64>,
    /// Location in ground (m).
    pub ground: Point3<f64>,
}

/// The active path points of `muscle` at coordinate values `q` (conditional
/// points outside their range are left out, moving points evaluated).
pub fn muscle_path(
    model: &Model,
    muscle: &Muscle,
    poses: &BTreeMap<String, Isometry3<f64>>,
    q: &Values,
) -> Result<Vec<PathPointAt>> {
    let mut out = Vec::new();
    for p in &muscle.points {
        let owner = format!("/forceset/{}/path/{}", muscle.name, p.name);
        let (body, x_bf) = model.resolve_frame(&owner, &p.socket_parent_frame)?;
        let coord_val = |c: &str| -> Result<f64> {
            let name = c.rsplit('/').next().unwrap_or(c);
            q.get(name).copied().ok_or_else(|| {
                Error::invalid(
                    format!("muscle {}", muscle.name),
                    format!(
                        "path point '{}' uses coordinate '{c}' with no value",
                        p.name
                    ),
                )
            })
        };
        let mut loc = p.location;
        match &p.kind {
            PathPointKind::Fixed => {}
            PathPointKind::Conditional { coordinate, range } => {
                let v = coord_val(coordinate)?;
                if v < range[0] || v > range[1] {
                    continue;
                }
            }
            PathPointKind::Moving { x, y, z } => {
                for (k, f) in [x, y, z].into_iter().enumerate() {
                    if let Some(fc) = f {
                        let (func, c) = fc.as_ref();
                        loc[k] = func.eval(coord_val(c)?);
                    }
                }
            }
        }
        let local = x_bf * Point3::from(loc);
        let x_gb = poses.get(&body).ok_or_else(|| {
            Error::invalid(
                format!("muscle {}", muscle.name),
                format!("body '{body}' has no pose"),
            )
        })?;
        out.push(PathPointAt {
            name: p.name.clone(),
            body,
            local,
            ground: x_gb * local,
        });
    }
    Ok(out)
}

/// Distance from `c` to the segment `a`-`b`.
pub fn point_segment_distance(c: &Point3<f64>, a: &Point3<f64>, b: &Point3<f64>) -> f64 {
    let ab = b - a;
    let l2 = ab.norm_squared();
    let t = if l2 > 0.0 {
        ((c - a).dot(&ab) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (a + ab * t - c).norm()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn segment_distance_is_euclidean() {
        let a = Point3::new(0.0, 0.0, 0.0);
        let b = Point3::new(1.0, 0.0, 0.0);
        assert!((point_segment_distance(&Point3::new(0.5, 2.0, 0.0), &a, &b) - 2.0).abs() < 1e-15);
        assert!((point_segment_distance(&Point3::new(-3.0, 4.0, 0.0), &a, &b) - 5.0).abs() < 1e-15);
    }
}
