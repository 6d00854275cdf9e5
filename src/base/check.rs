//! Self-check of the built base model before anything is written:
//! * every bushing is undeflected at the default pose (its two frames
//!   coincide in ground, computed by forward kinematics);
//! * no muscle path segment passes through a vertebra at the default pose
//!   (segments are tested against the closed vertebra meshes with parry;
//!   a vertebra is skipped for a segment attached to it; depth > 0.5 mm
//!   counts); [`run`] tests the straight segments between path points (the
//!   base model), [`run_wrapped`] the path OpenSim computes, wrap arcs
//!   included (generated models);
//! * every WrapSphere is reachable by its muscles (at least one muscle
//!   wraps over it; by the crossing rule each of them passes within the
//!   radius + 5 mm in a test pose); spheres without muscles are listed;
//! * the model settles under gravity: static equilibrium with the tool's
//!   solver ([`crate::solver`]; muscles apply no force there, as in a
//!   passive model) from the default pose, reporting the largest
//!   displacement of a vertebral body origin.

use super::kin::{muscle_path, Kinematics};
use super::wrap::SphereRow;
use crate::error::Result;
use crate::mesh::MeshQuery;
use crate::osim::model::Model;

/// A muscle segment found inside a vertebra.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ThroughBone {
    /// Muscle name.
    pub muscle: String,
    /// Body name of the vertebra it passes through.
    pub vertebra: String,
    /// Length of the segment inside the mesh (mm).
    pub depth_mm: f64,
}

/// Self-check figures.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct SelfCheck {
    /// Largest bushing rotational deflection at the default pose (rad).
    pub bushing_max_rotation: f64,
    /// Largest bushing translational deflection at the default pose (m).
    pub bushing_max_translation: f64,
    /// Muscle segments passing through a vertebra at the default pose.
    pub muscle_segments_through_vertebrae: Vec<ThroughBone>,
    /// Spheres no muscle wraps over.
    pub spheres_without_muscles: Vec<String>,
    /// Number of spheres with at least one wrapping muscle.
    pub spheres_reachable: usize,
    /// Static equilibrium under gravity with the tool's solver.
    pub equilibrium: Equilibrium,
}

/// Static equilibrium under gravity.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Equilibrium {
    /// Newton iterations to converge.
    pub iterations: usize,
    /// Largest generalised force residual (N or N m).
    pub residual_norm: f64,
    /// Largest displacement of a body origin from the default pose (m).
    pub max_displacement: f64,
    /// The body that moved most.
    pub max_displacement_body: String,
    /// Energy stability of this equilibrium (positive-definite tangent
    /// stiffness), when the solver can tell. A ligamentous spine without
    /// muscles carries far less than body weight before it buckles, so an
    /// unstable equilibrium under gravity is expected physics, not a
    /// defect of the model: this check is about the model's assembly.
    pub stable: Option<bool>,
    /// Every coordinate at equilibrium.
    pub coordinates: std::collections::BTreeMap<String, f64>,
}

/// Above this displacement (m) under gravity a "stable" equilibrium is
/// not the model's posture but where the spine sagged to.
pub(crate) const SAGGED_M: f64 = 0.02;

impl Equilibrium {
    /// The stability verdict in words, the one wording every command prints.
    pub fn verdict(&self) -> &'static str {
        match self.stable {
            Some(true) if self.max_displacement > SAGGED_M => "stable only after the spine sagged this far from its default posture (a ligamentous spine without muscles does not hold its posture under body weight)",
            Some(true) => "stable",
            Some(false) => "unstable (a ligamentous spine without muscles buckles under body weight)",
            None => "stability not assessed",
        }
    }
}

impl SelfCheck {
    /// The warnings of the self-check (muscles through bone), one line each.
    pub fn warnings(&self) -> Vec<String> {
        let through = &self.muscle_segments_through_vertebrae;
        if through.is_empty() {
            return Vec::new();
        }
        let deepest = through.iter().fold(0.0f64, |m, t| m.max(t.depth_mm));
        let first: Vec<String> = through
            .iter()
            .take(5)
            .map(|t| format!("{} in {} ({:.1} mm)", t.muscle, t.vertebra, t.depth_mm))
            .collect();
        vec![format!(
            "{} muscle segment(s) pass through a vertebra, up to {deepest:.1} mm deep: {}{}",
            through.len(),
            first.join(", "),
            if through.len() > 5 { ", ..." } else { "" }
        )]
    }
}

/// Every result of the self-check, as the console prints it.
impl std::fmt::Display for SelfCheck {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let eq = &self.equilibrium;
        write!(
            f,
            "self-check: bushing deflection at default {:.1e} rad / {:.1e} m; {} muscle segments through vertebrae; equilibrium under gravity (muscles off): largest displacement {:.1} mm ({}), {}",
            self.bushing_max_rotation,
            self.bushing_max_translation,
            self.muscle_segments_through_vertebrae.len(),
            eq.max_displacement * 1e3,
            eq.max_displacement_body,
            eq.verdict()
        )?;
        if !self.spheres_without_muscles.is_empty() {
            write!(
                f,
                "\nself-check: {} wrap sphere(s) with no muscle over them",
                self.spheres_without_muscles.len()
            )?;
        }
        Ok(())
    }
}

/// Static equilibrium of `model` under gravity from its default pose.
pub fn equilibrium(model: &Model) -> Result<Equilibrium> {
    use crate::solver::{StaticOptions, System, SystemSpec, Workspace};
    let spec = SystemSpec::from_model(model)?;
    let sys = System::new(&spec)?;
    let mut ws = Workspace::new(&sys);
    let q0 = sys.default_q();
    let loads = sys.prepare_loads(&[])?;
    let sol = sys.solve_static(&loads, q0.as_slice(), &mut ws, &StaticOptions::default())?;
    let p0 = sys.body_poses(q0.as_slice(), &mut ws)?;
    let p1 = sys.body_poses(sol.q.as_slice(), &mut ws)?;
    let mut best = (0.0, String::new());
    for (name, a) in &p0 {
        if let Some(b) = p1.get(name) {
            let d = (0..3)
                .map(|k| (a.origin_in_ground[k] - b.origin_in_ground[k]).powi(2))
                .sum::<f64>()
                .sqrt();
            if d > best.0 {
                best = (d, name.clone());
            }
        }
    }
    let full = sys.full_coordinates(sol.q.as_slice());
    let coordinates = sys
        .coordinates()
        .iter()
        .map(|c| c.name.clone())
        .zip(full)
        .collect();
    Ok(Equilibrium {
        iterations: sol.iterations,
        residual_norm: sol.residual_norm,
        max_displacement: best.0,
        max_displacement_body: best.1,
        stable: sol.stable,
        coordinates,
    })
}

/// Run the self-check on the base model; `vertebrae` are (body, mesh
/// query in the body frame). Muscle paths are the straight segments between
/// their points (the base model's own test).
pub fn run(
    model: &Model,
    vertebrae: &[(String, &MeshQuery)],
    spheres: &[SphereRow],
) -> Result<SelfCheck> {
    run_with(model, vertebrae, spheres, false)
}

/// The self-check with muscle paths as OpenSim computes them, sphere
/// wraps and their arcs included ([`super::wrapped`]); the crossing depth
/// is the path's total length inside each vertebra (used by `generate`).
pub fn run_wrapped(
    model: &Model,
    vertebrae: &[(String, &MeshQuery)],
    spheres: &[SphereRow],
) -> Result<SelfCheck> {
    run_with(model, vertebrae, spheres, true)
}

fn run_with(
    model: &Model,
    vertebrae: &[(String, &MeshQuery)],
    spheres: &[SphereRow],
    wrapped: bool,
) -> Result<SelfCheck> {
    let kin = Kinematics::new(model)?;
    let q = kin.default_values();
    let poses = kin.body_poses(&q)?;
    let mut max_rot: f64 = 0.0;
    let mut max_tr: f64 = 0.0;
    for b in model.bushings() {
        let owner = format!("/forceset/{}", b.name);
        let (b1, x1) = model.resolve_frame(&owner, &b.socket_frame1)?;
        let (b2, x2) = model.resolve_frame(&owner, &b.socket_frame2)?;
        let (Some(p1), Some(p2)) = (poses.get(&b1), poses.get(&b2)) else {
            continue;
        };
        let d = (p1 * x1).inverse() * (p2 * x2);
        max_rot = max_rot.max(d.rotation.angle());
        max_tr = max_tr.max(d.translation.vector.norm());
    }
    let mut through = Vec::new();
    let bounds: Vec<(nalgebra::Point3<f64>, f64)> = vertebrae
        .iter()
        .map(|(_, q)| match q.mesh().bounds() {
            Some((lo, hi)) => (nalgebra::center(&lo, &hi), 0.5 * (hi - lo).norm()),
            None => (nalgebra::Point3::origin(), 0.0),
        })
        .collect();
    let placed = super::wrapped::spheres_at(model, &poses);
    for m in model.muscles() {
        if wrapped {
            let p = super::wrapped::wrapped_path(model, m, &poses, &q, &placed)?;
            for c in super::wrapped::through_vertebrae(&m.name, &p.polyline, vertebrae, &poses) {
                through.push(ThroughBone {
                    muscle: c.muscle,
                    vertebra: c.vertebra,
                    depth_mm: c.depth_mm,
                });
            }
            continue;
        }
        let path = muscle_path(model, m, &poses, &q)?;
        for w in path.windows(2) {
            for ((body, mq), (c, r)) in vertebrae.iter().zip(&bounds) {
                if w[0].body == *body || w[1].body == *body {
                    continue;
                }
                let Some(x) = poses.get(body) else { continue };
                let inv = x.inverse();
                let (a, b) = (inv * w[0].ground, inv * w[1].ground);
                if super::kin::point_segment_distance(c, &a, &b) > *r {
                    continue;
                }
                let depth = mq.segment_length_inside(&a, &b);
                if depth > 0.0005 {
                    through.push(ThroughBone {
                        muscle: m.name.clone(),
                        vertebra: body.clone(),
                        depth_mm: depth * 1e3,
                    });
                }
            }
        }
    }
    Ok(SelfCheck {
        bushing_max_rotation: max_rot,
        bushing_max_translation: max_tr,
        muscle_segments_through_vertebrae: through,
        spheres_without_muscles: spheres
            .iter()
            .filter(|s| s.muscles.is_empty())
            .map(|s| s.name.clone())
            .collect(),
        spheres_reachable: spheres.iter().filter(|s| !s.muscles.is_empty()).count(),
        equilibrium: equilibrium(model)?,
    })
}
