//! Geometry sanity: every vertebra mesh must sit on its body's joint chain
//! before spheres are fitted or landmarks palpated on it.
//!
//! For a vertebra with inferior joint centre `a` and superior joint centre
//! `b` (both in its body frame; `b` is the parent frame origin of the joint
//! to the next cranial vertebra, or, for the top vertebra of the model,
//! `a` plus the segment length of the vertebra below along the body's Y
//! axis), with `h = |b - a|` and `u = (b - a)/h`, the mesh passes when
//! 1. the points at 30 %, 50 % and 70 % of the segment are inside the
//!    (closed) mesh or within `max(2 mm, 0.1 h)` of its surface: the
//!    vertebral body lies between the two joint centres;
//! 2. from the midpoint, the first surface hit along `+u` and along `-u`
//!    (the endplates) lies between `0.15 h` and `0.85 h` away: the body's
//!    axis runs along the segment, with disc space at both ends;
//! 3. the mesh's vertex centroid lies posterior (-X) of the segment: the
//!    posterior elements are behind the body (not a mesh flipped
//!    front-to-back).
//!
//! The shared `geometry/` meshes of the cyclist model fail rule 1 by
//! centimetres; `geometry-bodyframe/` passes.

use crate::anatomy::Level;
use crate::mesh::MeshQuery;
use nalgebra::{Point3, Vector3};

/// The joint-chain segment of a vertebra in its body frame.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Segment {
    /// Inferior joint centre (m).
    pub inferior: Point3<f64>,
    /// Superior joint centre (m).
    pub superior: Point3<f64>,
    /// `false` when the superior centre was extrapolated (top vertebra).
    pub superior_from_joint: bool,
}

impl Segment {
    /// Joint-to-joint height (m).
    pub fn height(&self) -> f64 {
        (self.superior - self.inferior).norm()
    }
    /// Unit direction inferior -> superior.
    pub fn axis(&self) -> Vector3<f64> {
        (self.superior - self.inferior)
            .try_normalize(1e-12)
            .unwrap_or_else(Vector3::y)
    }
    /// Point at fraction `t` from inferior to superior.
    pub fn at(&self, t: f64) -> Point3<f64> {
        self.inferior + (self.superior - self.inferior) * t
    }
}

/// Result of the sanity check of one vertebra mesh.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct SanityRow {
    /// Level name (T1..L5).
    pub level: Level,
    /// Body name.
    pub body: String,
    /// Mesh file as referenced by the model.
    pub mesh_file: String,
    /// Joint-to-joint height (m).
    pub segment_height: f64,
    /// Signed distances (m, negative inside) of the 30/50/70 % points.
    pub signed_distances: [f64; 3],
    /// Distance from the midpoint to the first hit along +u (m);
    /// `None` when the ray leaves without a hit.
    pub endplate_up: Option<f64>,
    /// Distance from the midpoint to the first hit along -u (m); `None` without a hit.
    pub endplate_down: Option<f64>,
    /// X of the vertex centroid relative to the segment midpoint (m).
    pub centroid_x_offset: f64,
    /// Passed every rule.
    pub ok: bool,
    /// What failed, for the error message.
    pub problems: Vec<String>,
}

/// Check one mesh (in its body frame) against its segment.
pub fn check_vertebra(
    level: Level,
    body: &str,
    mesh_file: &str,
    q: &MeshQuery,
    seg: &Segment,
) -> SanityRow {
    let h = seg.height();
    let tol = (0.1 * h).max(0.002);
    let signed = [0.3, 0.5, 0.7].map(|t| q.signed_distance(&seg.at(t)));
    let mut problems = Vec::new();
    for (t, d) in [0.3, 0.5, 0.7].iter().zip(signed) {
        if d > tol {
            problems.push(format!(
                "the point at {:.0} % of the joint-to-joint segment is {:.1} mm outside the mesh",
                t * 100.0,
                d * 1e3
            ));
        }
    }
    let m = seg.at(0.5);
    let u = seg.axis();
    let first = |dir: Vector3<f64>| -> Option<f64> {
        q.ray_hits(&m, &dir, f64::MAX)
            .into_iter()
            .map(|hit| hit.t)
            .find(|t| *t > 1e-9)
    };
    let up = first(u);
    let down = first(-u);
    for (name, d) in [("superior", up), ("inferior", down)] {
        match d {
            Some(d) if (0.15 * h..=0.85 * h).contains(&d) => {}
            Some(d) => problems.push(format!(
                "the {name} endplate is {:.1} mm from the segment midpoint, expected {:.1}..{:.1} mm \
                 (body axis not along the joint chain)",
                d * 1e3,
                0.15 * h * 1e3,
                0.85 * h * 1e3
            )),
            None => problems.push(format!("no {name} endplate found along the joint chain")),
        }
    }
    let verts = &q.mesh().vertices;
    let cx = if verts.is_empty() {
        0.0
    } else {
        verts.iter().map(|p| p.x).sum::<f64>() / verts.len() as f64 - m.x
    };
    if cx >= 0.0 {
        problems.push(format!(
            "the mesh centroid is {:.1} mm anterior of the joint chain (posterior elements should be behind it)",
            cx * 1e3
        ));
    }
    SanityRow {
        level,
        body: body.to_string(),
        mesh_file: mesh_file.to_string(),
        segment_height: h,
        signed_distances: signed,
        endplate_up: up,
        endplate_down: down,
        centroid_x_offset: cx,
        ok: problems.is_empty(),
        problems,
    }
}
