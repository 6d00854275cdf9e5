//! Geometric helpers of the base builder (also used by `generate` and
//! `evaluate`): body poses in ground for coordinate values given by name,
//! computed by the solver's forward kinematics
//! ([`crate::solver::System::body_transforms`], the one FK of the crate),
//! and muscle path points at a pose.

use crate::error::{Error, Result};
use crate::osim::model::{Muscle, PathPointKind};
use crate::osim::Model;
use crate::solver::{DofIndex, System, SystemSpec};
use nalgebra::{Isometry3, Point3};
use std::collections::BTreeMap;

/// Coordinate values by name (rad or m).
pub type Values = BTreeMap<String, f64>;

/// Forward kinematics of a typed [`Model`]: the solver's [`System`] built
/// from the model's bodies, joints and coordinates (no forces), with every
/// coordinate free so that any coordinate value given is honoured (locked
/// ones included).
pub struct Kinematics<'a> {
    model: &'a Model,
    sys: System,
}

impl<'a> Kinematics<'a> {
    /// Build the kinematic system of `model`.
    pub fn new(model: &'a Model) -> Result<Kinematics<'a>> {
        let mut spec = SystemSpec::kinematics_from_model(model)?;
        for c in spec.coordinates.iter_mut() {
            c.locked = false;
        }
        let sys = System::new(&spec).map_err(|e| {
            Error::invalid(
                model.file.display().to_string(),
                format!("forward kinematics: {e}"),
            )
        })?;
        Ok(Kinematics { model, sys })
    }

    /// The model.
    pub fn model(&self) -> &Model {
        self.model
    }

    /// Every coordinate at its default value.
    pub fn default_values(&self) -> Values {
        self.model
            .coordinates()
            .map(|c| (c.name.clone(), c.default_value))
            .collect()
    }

    /// The solver's free-dof vector for coordinate values by name; every
    /// coordinate a joint uses needs a value.
    fn dofs(&self, q: &Values) -> Result<Vec<f64>> {
        (0..self.sys.n_dofs())
            .map(|i| {
                let name = self.sys.dof_name(DofIndex(i));
                q.get(name).copied().ok_or_else(|| {
                    Error::invalid(
                        self.model.file.display().to_string(),
                        format!("no value for coordinate '{name}'"),
                    )
                })
            })
            .collect()
    }

    /// Pose of every body (and "ground") in ground.
    pub fn body_poses(&self, q: &Values) -> Result<BTreeMap<String, Isometry3<f64>>> {
        let mut out: BTreeMap<String, Isometry3<f64>> = self
            .sys
            .body_transforms(&self.dofs(q)?)?
            .into_iter()
            .collect();
        out.insert("ground".to_string(), Isometry3::identity());
        Ok(out)
    }

    /// Transform across the joint named `joint`, from its parent frame F to
    /// its child frame M, at `q`.
    pub fn joint_transform(&self, joint: &str, q: &Values) -> Result<Isometry3<f64>> {
        self.sys.joint_transform(joint, &self.dofs(q)?)
    }
}

/// A muscle path point resolved at a pose.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct PathPointAt {
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
pub(crate) fn muscle_path(
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
