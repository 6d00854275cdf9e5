//! Step 2 of the base builder: the kept bodies' meshes, and every vertebra
//! mesh checked to sit on its body's joint chain ([`super::sanity`]).

use super::sanity::{self, SanityRow, Segment};
use super::topology::Topology;
use crate::error::{Error, Result};
use crate::landmarks::Level;
use crate::mesh::source::{body_mesh, MeshSource};
use crate::mesh::{MeshQuery, TriMesh};
use crate::osim::model::Model;
use nalgebra::{Point3, Vector3};
use std::collections::BTreeMap;

/// One kept vertebra with its mesh (body frame).
pub(crate) struct Vert {
    pub level: Level,
    pub body: String,
    pub mesh_file: String,
    pub mesh: TriMesh,
    pub query: MeshQuery,
    pub seg: Segment,
}

impl Vert {
    /// How the vertebra is named in messages.
    pub(super) fn context(&self) -> String {
        format!(
            "vertebra {} ({}, mesh {})",
            self.level, self.body, self.mesh_file
        )
    }
}

/// The kept meshes by body, the vertebrae, and the geometry check rows.
pub(crate) struct Vertebrae {
    pub body_meshes: BTreeMap<String, (String, TriMesh)>,
    pub verts: Vec<Vert>,
    pub sanity: Vec<SanityRow>,
}

/// The merged mesh of a body (its mesh geometries, scaled), if any.
pub(crate) fn mesh_of(
    model: &Model,
    body: &str,
    source: &dyn MeshSource,
    missing: &mut Vec<String>,
) -> Result<Option<(String, TriMesh)>> {
    let b = model.body(body).ok_or_else(|| {
        Error::invalid(
            model.file.display().to_string(),
            format!("no body '{body}'"),
        )
    })?;
    let loaded = body_mesh(b, source)?;
    missing.extend(
        loaded
            .missing
            .iter()
            .map(|f| format!("'{f}' (body {body})")),
    );
    Ok(loaded.mesh.map(|m| (loaded.found.join("+"), m)))
}

/// Load every kept body's mesh and check each vertebra's geometry.
pub(crate) fn load_vertebrae(
    model: &Model,
    topo: &Topology,
    source: &dyn MeshSource,
    gfile: &str,
) -> Result<Vertebrae> {
    // Every kept body's mesh (all must be found).
    let mut missing_meshes = Vec::new();
    let mut body_meshes: BTreeMap<String, (String, TriMesh)> = BTreeMap::new();
    for b in &topo.kept {
        if let Some(m) = mesh_of(model, b, source, &mut missing_meshes)? {
            body_meshes.insert(b.clone(), m);
        }
    }
    if !missing_meshes.is_empty() {
        return Err(Error::invalid(
            gfile,
            format!(
                "mesh files not found: {} (searched {})",
                missing_meshes.join(", "),
                source.describe()
            ),
        ));
    }
    // Each vertebra with its joint segment, then the geometry check.
    let verts = vertebra_segments(topo, &body_meshes, gfile)?;
    let sanity = check_geometry(&verts, gfile)?;
    Ok(Vertebrae {
        body_meshes,
        verts,
        sanity,
    })
}

/// Each vertebra's mesh with the segment between its joint centres (the
/// top vertebra's superior centre extrapolated from the one below).
fn vertebra_segments(
    topo: &Topology,
    body_meshes: &BTreeMap<String, (String, TriMesh)>,
    gfile: &str,
) -> Result<Vec<Vert>> {
    let frames = &topo.frames;
    let mut no_mesh = Vec::new();
    let mut vs = Vec::new();
    let mut below_len = 0.025;
    for &(up, _, i) in &topo.ivd {
        let body = up.body_name();
        let Some((file, mesh)) = body_meshes.get(&body) else {
            no_mesh.push(body.clone());
            continue;
        };
        let ctx = format!("mesh {file} of body {body}");
        mesh.require_watertight(&ctx)?;
        let query = MeshQuery::new(mesh).map_err(|e| Error::invalid(&ctx, e.to_string()))?;
        let inferior = Point3::from(frames[i].child_in_body.translation.vector);
        let superior_joint = up
            .cranial()
            .and_then(|c| {
                frames
                    .iter()
                    .find(|f| f.parent_body == body && f.child_body == c.body_name())
            })
            .map(|f| Point3::from(f.parent_in_body.translation.vector));
        let (superior, from_joint) = match superior_joint {
            Some(s) => (s, true),
            None => (inferior + Vector3::y() * below_len, false),
        };
        let seg = Segment {
            inferior,
            superior,
            superior_from_joint: from_joint,
        };
        below_len = seg.height().max(1e-4);
        vs.push(Vert {
            level: up,
            body,
            mesh_file: file.clone(),
            mesh: mesh.clone(),
            query,
            seg,
        });
    }
    if !no_mesh.is_empty() {
        return Err(Error::invalid(
            gfile,
            format!("vertebra bodies without a mesh: {}", no_mesh.join(", ")),
        ));
    }
    Ok(vs)
}

/// Every vertebra mesh must sit on its body's joint chain.
fn check_geometry(vs: &[Vert], gfile: &str) -> Result<Vec<SanityRow>> {
    let sanity: Vec<SanityRow> = vs
        .iter()
        .map(|v| sanity::check_vertebra(v.level, &v.body, &v.mesh_file, &v.query, &v.seg))
        .collect();
    let bad: Vec<String> = sanity
        .iter()
        .filter(|r| !r.ok)
        .map(|r| format!("{} ({}): {}", r.mesh_file, r.body, r.problems.join("; ")))
        .collect();
    if !bad.is_empty() {
        return Err(Error::invalid(
            gfile,
            format!(
                "{} vertebra mesh(es) do not sit on their body's joint chain (misplaced meshes; use \
                 meshes placed in the body frames, e.g. ../shared/data/geometry-bodyframe/):\n  {}",
                bad.len(),
                bad.join("\n  ")
            ),
        ));
    }
    Ok(sanity)
}
