//! The patient's own vertebrae in the model (`generate --segmentation SEG
//! --geometry patient`).
//!
//! [`PatientGeometry::from_palpated`] takes each palpated level's surface
//! (the segmentation's axes) into the landmark set's frame (OpenSim axes,
//! metres), as the landmarks were: a mesh folder's mesh as given
//! (decimated only above [`MAX_TRIANGLES`]); a label map's surface, whose
//! voxel staircase is smoothed away by [`SMOOTH_PASSES`] passes of Taubin's
//! lambda|mu filter ([`crate::mesh::smooth`]) and then decimated to at most
//! [`MAX_TRIANGLES`] by meshoptimizer ([`crate::mesh::decimate`]). Every
//! mesh must be closed and consistently oriented (outward); a level whose
//! mesh is not keeps the scaled base mesh, and the report says why.
//!
//! [`apply`] then builds the model around them, after the generic steps
//! (fit, scaling, joints) have placed every body:
//! 1. each patient level's body wears its mesh, expressed in the body's
//!    frame through the sacral registration and the body's default pose
//!    (scale factors 1), and its markers are the palpated landmarks;
//! 2. the vertebral-body wrap sphere's centre is the base's vertebral
//!    centre carried onto the patient's bone by an affine surface fit of
//!    the scaled base mesh ([`crate::mesh::register::affine_icp`]: the
//!    bone's proportions as well as its place, so the centre keeps its
//!    anatomical place inside a body that is deeper, taller or wider than
//!    the landmarks measured), or the palpation engine's centre (the
//!    protocol's least-squares sphere through the patient's anterior body
//!    surface) where the fit moves it more than [`SURFACE_FIT_LIMIT`] or
//!    the base mesh is missing; its radius is the engine's, before the
//!    wrap rules shrink it;
//! 3. each intervertebral joint between two patient levels is at the
//!    patient's disc: the base's joint centre carried into the patient by
//!    each of its two vertebrae (the landmark fit, as the chain fit places
//!    joints, refined by a rigid ICP of the scaled base mesh onto the
//!    patient's surface, [`SURFACE_FIT_LIMIT`]), midway between the two, so
//!    that the disc keeps the base's joint relative to the bone (a patient
//!    whose vertebrae are the base's, posed, gets the base's joints back);
//!    oriented half-way between the two vertebrae's ISB frames from the
//!    patient's landmarks ([`super::disc_frame`]);
//! 4. mass and inertia scaled from the (scaled) base by the ratio of the
//!    patient's bone volume to the scaled base mesh's: mass by the ratio,
//!    inertia by its 5/3 power (a body grown uniformly to that volume);
//!    centre of mass kept;
//! 5. muscle attachments, carried from the base by each vertebra's
//!    landmark transform (the generic scaling), that fall inside a patient
//!    bone at the default pose are moved out along the surface normal to
//!    [`ATTACHMENT_CLEARANCE`] outside it, and listed.
//!
//! The caller then refits the wrap spheres and clears the muscle paths
//! against the patient's meshes ([`Overlay`]), and the self-check tests
//! them.

use crate::base::kin::Kinematics;
use crate::error::{Error, Result};
use crate::landmarks::Level;
use crate::mesh::source::{body_mesh, MeshSource};
use crate::mesh::{MeshQuery, TriMesh};
use crate::osim::model::{Model, PathPointKind, WrapShape};
use crate::osim::props::{set_f64, set_numbers, set_vec3};
use crate::osim::Document;
use crate::segmentation::{Kind, Palpated};
use nalgebra::{Isometry3, Point3, Vector3};
use std::collections::BTreeMap;

/// Which vertebra meshes a generated model wears.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum GeometryChoice {
    /// The base model's meshes, scaled by each vertebra's landmarks.
    #[default]
    Base,
    /// The patient's own meshes from the segmentation (`--segmentation`).
    Patient,
}

impl std::fmt::Display for GeometryChoice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            GeometryChoice::Base => "base",
            GeometryChoice::Patient => "patient",
        })
    }
}

/// Most triangles of a mesh written into a model.
pub const MAX_TRIANGLES: usize = 5000;
/// Taubin lambda|mu passes on a label map's surface: enough to take out a
/// voxel staircase (period two voxels), few enough to keep the anatomy.
pub const SMOOTH_PASSES: usize = 10;
/// How far outside the bone a moved attachment is put (m).
pub const ATTACHMENT_CLEARANCE: f64 = 0.0005;
/// Largest move of a joint centre by the surface refinement (m): beyond
/// it the patient's bone is too unlike the base's for the rigid ICP to be
/// trusted, and the landmark fit alone places the joint.
pub const SURFACE_FIT_LIMIT: f64 = 0.003;

/// One level of the patient's segmentation, ready for the model.
#[derive(Debug, Clone)]
pub struct PatientLevel {
    /// The vertebra.
    pub level: Level,
    /// File or label it came from.
    pub origin: String,
    /// Closed, outward surface in the landmark set's frame (OpenSim axes, m).
    pub mesh: TriMesh,
    /// Vertebral centre (palpation engine) in the same frame, and the
    /// radius of its sphere (m).
    pub centre: Point3<f64>,
    /// Radius of the centre's sphere (m).
    pub radius: f64,
    /// Triangles of the surface as read.
    pub source_triangles: usize,
    /// What was done to it (`as given`, `smoothed ... and decimated ...`).
    pub prepared: String,
}

/// The patient's vertebrae for [`apply`].
#[derive(Debug, Clone)]
pub struct PatientGeometry {
    /// The segmentation's name.
    pub source: String,
    /// What kind of segmentation it was read from.
    pub kind: Kind,
    /// The usable levels.
    pub levels: BTreeMap<Level, PatientLevel>,
    /// Levels whose surface cannot be worn (not closed), with why.
    pub refused: Vec<String>,
    /// The meshes' file names are `<prefix>_<LEVEL>.vtp`.
    pub prefix: String,
}

impl PatientGeometry {
    /// The palpated levels' surfaces, prepared (module documentation);
    /// `prefix` names the mesh files.
    pub fn from_palpated(p: &Palpated, prefix: &str) -> PatientGeometry {
        use rayon::prelude::*;
        let to_os = p.world.to_opensim();
        // Each level on its own (in parallel, in order).
        let prepared: Vec<_> = p
            .levels
            .par_iter()
            .map(|r| {
                let world = TriMesh {
                    vertices: r
                        .mesh
                        .vertices
                        .iter()
                        .map(|v| Point3::from(to_os * v.coords))
                        .collect(),
                    triangles: r.mesh.triangles.clone(),
                };
                (r, prepare(world, p.kind))
            })
            .collect();
        let mut levels = BTreeMap::new();
        let mut refused = Vec::new();
        for (r, result) in prepared {
            match result {
                Ok((mesh, prepared)) => {
                    levels.insert(
                        r.level,
                        PatientLevel {
                            level: r.level,
                            origin: r.origin.clone(),
                            mesh,
                            centre: Point3::from(to_os * r.palpation.centre.coords),
                            radius: r.palpation.centre_radius,
                            source_triangles: r.mesh.triangles.len(),
                            prepared,
                        },
                    );
                }
                Err(why) => refused.push(format!("{} ({}): {why}", r.level, r.origin)),
            }
        }
        PatientGeometry {
            source: p.source.clone(),
            kind: p.kind,
            levels,
            refused,
            prefix: prefix.to_string(),
        }
    }

    /// The mesh file name of `level`.
    pub fn mesh_file(&self, level: Level) -> String {
        format!("{}_{level}.vtp", self.prefix)
    }
}

/// Why a level's surface cannot be the model's geometry.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum UnusableSurface {
    /// Decimation left more than [`MAX_TRIANGLES`] triangles.
    #[error("{0} triangles after decimation (at most {MAX_TRIANGLES})")]
    TooManyTriangles(usize),
    /// The surface has boundary or non-manifold edges.
    #[error("the surface is not closed ({boundary} boundary, {non_manifold} non-manifold edges)")]
    NotClosed {
        /// Edges with one triangle.
        boundary: usize,
        /// Edges with more than two triangles.
        non_manifold: usize,
    },
    /// No consistent outward orientation exists.
    #[error("the surface cannot be oriented consistently outward")]
    NotOrientable,
}

/// A level's surface made fit for the model: smoothed (label maps),
/// decimated to [`MAX_TRIANGLES`], checked closed and turned outward;
/// with a description of what was done, or why it cannot be used.
pub fn prepare(
    mesh: TriMesh,
    kind: Kind,
) -> std::result::Result<(TriMesh, String), UnusableSurface> {
    let n0 = mesh.triangles.len();
    // Voxel surfaces pinch where two voxels touch along an edge.
    let (mesh, split) = crate::mesh::manifold::split_non_manifold_edges(&mesh);
    let (smoothed, mut what) = match kind {
        Kind::LabelMap => (
            crate::mesh::smooth::taubin(&mesh, SMOOTH_PASSES),
            format!("smoothed ({SMOOTH_PASSES} Taubin lambda|mu passes)"),
        ),
        Kind::MeshFolder => (mesh, "as given".to_string()),
    };
    if split > 0 {
        what = format!("{what}, {split} pinched edge(s) split");
    }
    let mut out = crate::mesh::decimate::decimate(&smoothed, MAX_TRIANGLES);
    if out.triangles.len() < n0 {
        what = format!(
            "{what}, decimated from {n0} to {} triangles",
            out.triangles.len()
        );
    }
    if out.triangles.len() > MAX_TRIANGLES {
        return Err(UnusableSurface::TooManyTriangles(out.triangles.len()));
    }
    let rep = out.edge_report();
    if !rep.boundary_edges.is_empty() || !rep.non_manifold_edges.is_empty() {
        return Err(UnusableSurface::NotClosed {
            boundary: rep.boundary_edges.len(),
            non_manifold: rep.non_manifold_edges.len(),
        });
    }
    out.orient_consistently();
    if !out.edge_report().inconsistent_edges.is_empty() || out.signed_volume() <= 0.0 {
        return Err(UnusableSurface::NotOrientable);
    }
    Ok((out, what))
}

/// Meshes by file name first, then the base model's.
pub struct Overlay<'a> {
    /// The model's own meshes, by file name, looked up first.
    pub own: &'a BTreeMap<String, TriMesh>,
    /// The base model's meshes, looked up next.
    pub base: Option<&'a dyn MeshSource>,
}

impl MeshSource for Overlay<'_> {
    fn load(&self, mesh_file: &str) -> Result<Option<TriMesh>> {
        if let Some(m) = self.own.get(mesh_file) {
            return Ok(Some(m.clone()));
        }
        match self.base {
            Some(b) => b.load(mesh_file),
            None => Ok(None),
        }
    }
    fn describe(&self) -> String {
        let base = self.base.map(|b| b.describe()).unwrap_or_default();
        format!("{} patient meshes, then {base}", self.own.len())
    }
}

/// One patient mesh in the model.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct MeshRow {
    /// The vertebra (or the sacrum).
    pub level: Level,
    /// The body wearing the mesh.
    pub body: String,
    /// The mesh's file name as written in the model.
    pub mesh_file: String,
    /// File or label of the segmentation.
    pub origin: String,
    /// What was done to the surface before use.
    pub prepared: String,
    /// Triangles of the mesh written.
    pub triangles: usize,
    /// Bone volume of the patient mesh and of the scaled base mesh (cm^3).
    pub volume_cm3: f64,
    /// Bone volume of the scaled base mesh (cm^3); `None` when it is missing.
    pub base_volume_cm3: Option<f64>,
    /// Mass written (kg) and the scaled base's (kg).
    pub mass_kg: f64,
    /// Mass of the scaled base body (kg).
    pub base_mass_kg: f64,
    /// Vertebral-body sphere from the patient's body: centre in the body
    /// frame (m) and radius before the wrap rules (m); none for the sacrum.
    pub sphere_centre: Option<[f64; 3]>,
    /// Radius of that sphere before the wrap rules (m).
    pub sphere_radius: Option<f64>,
    /// Where the sphere's centre comes from.
    pub sphere_centre_rule: Option<CentreRule>,
    /// The scaled base mesh registered onto the patient's (rigid ICP from
    /// the landmark fit): how far it moved (mm at the mesh's extent) and
    /// its trimmed RMS (mm); `None` when the base mesh is missing.
    pub surface_fit_mm: Option<f64>,
    /// Trimmed RMS distance of that registration (mm).
    pub surface_rms_mm: Option<f64>,
}

/// Where a patient vertebra's sphere centre comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum CentreRule {
    /// The base's vertebral centre carried by an affine fit of the scaled
    /// base mesh onto the patient's bone.
    CarriedFromBase,
    /// The palpation engine's sphere through the patient's anterior body
    /// surface (the base mesh is missing or does not fit).
    Palpated,
}

/// A muscle attachment moved out of a patient bone.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct MovedPoint {
    /// The muscle's name.
    pub muscle: String,
    /// The path point's name.
    pub point: String,
    /// Body the point is fixed to, and the bone it was inside.
    pub body: String,
    /// The bone it was inside (its body's name).
    pub bone: String,
    /// How deep inside it was, and how far it moved (mm).
    pub depth_mm: f64,
    /// How far it moved (mm).
    pub moved_mm: f64,
}

/// What [`apply`] did (the report's `geometry`).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct GeometryReport {
    /// The geometry asked for.
    pub geometry: GeometryChoice,
    /// The segmentation's name.
    pub segmentation: String,
    /// Levels wearing the patient's mesh, cranial to caudal.
    pub patient_levels: Vec<Level>,
    /// Vertebrae and sacrum still wearing the scaled base mesh, and why.
    pub base_levels: Vec<String>,
    /// One row per patient mesh in the model.
    pub meshes: Vec<MeshRow>,
    /// Joints placed at the patient's disc centres.
    pub joints_at_patient_discs: Vec<String>,
    /// Muscle attachments moved out of patient bones.
    pub moved_attachments: Vec<MovedPoint>,
    /// How mass and inertia were set.
    pub mass_rule: String,
}

/// What [`apply`] hands back to the generator.
pub struct Applied {
    /// What was done.
    pub report: GeometryReport,
    /// Patient meshes by file name, in their bodies' frames (m).
    pub meshes: BTreeMap<String, TriMesh>,
    /// Radius of each patient wrap sphere (by name), before the wrap rules.
    pub sphere_radii: BTreeMap<String, f64>,
    /// Bodies wearing a patient mesh.
    pub bodies: Vec<String>,
    /// Per body, the rigid correction (ground) taking the landmark-fitted
    /// scaled base mesh onto the patient's surface.
    pub surface_fits: BTreeMap<String, Isometry3<f64>>,
}

/// What [`apply`] needs from the generator.
pub struct Placement<'a> {
    /// Landmark set frame -> model ground.
    pub registration: Isometry3<f64>,
    /// The patient's landmarks in ground (registered), by level.
    pub landmarks: &'a BTreeMap<Level, super::pose::Points>,
    /// Levels placed from landmarks (vertebrae) and S1.
    pub placed: Vec<Level>,
    /// The base's joint centres carried into the patient by the fits of
    /// the two vertebrae of each joint, in their (scaled) body frames,
    /// keyed by the upper level ([`super::carried_joints`]).
    pub joints: super::JointCentres,
    /// The base model's meshes (for the scaled base volumes).
    pub base_meshes: Option<&'a dyn MeshSource>,
}

/// Build the model around the patient's meshes (module documentation,
/// steps 1-5). `doc` has been scaled and its joints placed.
pub fn apply(doc: &mut Document, pg: &PatientGeometry, at: &Placement) -> Result<Applied> {
    let model = doc.model()?;
    let kin = Kinematics::new(&model)?;
    let poses = kin.body_poses(&kin.default_values())?;
    let mut out = Applied {
        report: GeometryReport {
            geometry: GeometryChoice::Patient,
            segmentation: pg.source.clone(),
            patient_levels: Vec::new(),
            base_levels: Vec::new(),
            meshes: Vec::new(),
            joints_at_patient_discs: Vec::new(),
            moved_attachments: Vec::new(),
            mass_rule: "mass = scaled base mass x patient bone volume / scaled base mesh volume; \
                        inertia x (that ratio)^(5/3); centre of mass of the scaled base"
                .into(),
        },
        meshes: BTreeMap::new(),
        sphere_radii: BTreeMap::new(),
        bodies: Vec::new(),
        surface_fits: BTreeMap::new(),
    };
    // Steps 1, 2, 4: each patient level's body.
    for l in Level::ALL {
        let body = l.body_name();
        let (Some(x), Some(pl), true) =
            (poses.get(&body), pg.levels.get(&l), at.placed.contains(&l))
        else {
            if model.body(&body).is_some() {
                out.report.base_levels.push(base_reason(l, pg, at));
            }
            continue;
        };
        let row = wear(doc, &model, pg, pl, x, at, &mut out)?;
        out.report.meshes.push(row);
        out.report.patient_levels.push(l);
        out.bodies.push(body);
    }
    // Step 3: joints at the patient's disc centres.
    out.report.joints_at_patient_discs =
        patient_joints(doc, &model, &poses, at, &out.surface_fits)?;
    // Step 5: attachments out of the patient's bones.
    let bones: Vec<(String, MeshQuery)> = out
        .bodies
        .iter()
        .zip(&out.report.meshes)
        .map(|(b, r)| {
            let q = MeshQuery::new(&out.meshes[&r.mesh_file])
                .map_err(|e| Error::invalid(format!("patient mesh of {b}"), e.to_string()))?;
            Ok((b.clone(), q))
        })
        .collect::<Result<_>>()?;
    out.report.moved_attachments = attachments_out_of_bone(doc, &bones, &poses)?;
    Ok(out)
}

/// Why level `l` keeps the scaled base mesh.
fn base_reason(l: Level, pg: &PatientGeometry, at: &Placement) -> String {
    if let Some(r) = pg.refused.iter().find(|r| r.starts_with(&format!("{l} "))) {
        return r.clone();
    }
    if !pg.levels.contains_key(&l) {
        return format!("{l}: not in the segmentation's palpated levels");
    }
    if !at.placed.contains(&l) {
        return format!("{l}: not placed from landmarks");
    }
    format!("{l}: no such body")
}

/// Dress one body in its patient mesh: geometry, mass and inertia,
/// markers, wrap sphere (steps 1, 2, 4).
fn wear(
    doc: &mut Document,
    model: &Model,
    pg: &PatientGeometry,
    pl: &PatientLevel,
    x: &Isometry3<f64>,
    at: &Placement,
    out: &mut Applied,
) -> Result<MeshRow> {
    let l = pl.level;
    let to_body = x.inverse() * at.registration;
    let body = l.body_name();
    let file = model.file.display().to_string();
    let b = model
        .body(&body)
        .ok_or_else(|| Error::invalid(&file, format!("no body '{body}'")))?;
    let mesh = pl.mesh.transformed(&to_body);
    let volume = mesh.signed_volume();
    let base_mesh = scaled_base_mesh(b, at.base_meshes)?;
    let base_volume = base_mesh
        .as_ref()
        .filter(|m| m.edge_report().is_watertight())
        .map(TriMesh::signed_volume)
        .filter(|v| *v > 0.0);
    let surface = match &base_mesh {
        Some(m) => Some(surface_fit(m, &mesh)?),
        None => None,
    };
    if let Some((t, _, _)) = &surface {
        out.surface_fits.insert(body.clone(), x * t * x.inverse());
    }
    let mesh_file = pg.mesh_file(l);
    let el = doc
        .component_mut("BodySet", &body)
        .ok_or_else(|| Error::invalid(&file, format!("body element '{body}' not found")))?;
    dress(el, &body, &mesh_file);
    let ratio = base_volume.map(|v| volume / v);
    if let Some(k) = ratio {
        set_f64(el, "mass", b.mass * k);
        let i: Vec<f64> = b.inertia.iter().map(|v| v * k.powf(5.0 / 3.0)).collect();
        set_numbers(el, "inertia", &i);
    }
    let mut sphere = None;
    let mut centre_rule = None;
    if let Some(w) = b
        .wrap_objects
        .iter()
        .find(|w| matches!(w.shape, WrapShape::Sphere { .. }) && !l.is_sacrum())
    {
        let (c, rule) = sphere_centre(&w.translation, base_mesh.as_ref(), &mesh, &to_body, pl);
        set_sphere_centre(el, &w.name, &c);
        centre_rule = Some(rule);
        out.sphere_radii.insert(w.name.clone(), pl.radius);
        sphere = Some(c);
    }
    set_markers(doc, model, l, &body, x, at)?;
    out.meshes.insert(mesh_file.clone(), mesh);
    Ok(MeshRow {
        level: l,
        body,
        mesh_file,
        origin: pl.origin.clone(),
        prepared: pl.prepared.clone(),
        triangles: pl.mesh.triangles.len(),
        volume_cm3: volume * 1e6,
        base_volume_cm3: base_volume.map(|v| v * 1e6),
        mass_kg: ratio.map(|k| b.mass * k).unwrap_or(b.mass),
        base_mass_kg: b.mass,
        sphere_centre: sphere.map(|c| [c.x, c.y, c.z]),
        sphere_radius: sphere.map(|_| pl.radius),
        sphere_centre_rule: centre_rule,
        surface_fit_mm: surface.as_ref().map(|(_, d, _)| d * 1e3),
        surface_rms_mm: surface.as_ref().map(|(_, _, r)| r * 1e3),
    })
}

/// The vertebral centre in the body frame: the (scaled) base's centre
/// carried onto the patient's bone by an affine surface fit of the scaled
/// base mesh (its proportions as well as its place), when the fit is
/// sound and moves it less than [`SURFACE_FIT_LIMIT`]; else the palpation
/// engine's centre of the patient's own body. Also says which.
fn sphere_centre(
    base_centre: &Vector3<f64>,
    base_mesh: Option<&TriMesh>,
    patient: &TriMesh,
    to_body: &Isometry3<f64>,
    pl: &PatientLevel,
) -> (Point3<f64>, CentreRule) {
    let c0 = Point3::from(*base_centre);
    let carried = base_mesh.and_then(|m| {
        let q = MeshQuery::new(patient).ok()?;
        let fit = crate::mesh::register::affine_icp(&m.vertices, &q, 0.9, 50).ok()?;
        Some(fit.apply(&c0))
    });
    match carried {
        Some(c) if (c - c0).norm() <= SURFACE_FIT_LIMIT => (c, CentreRule::CarriedFromBase),
        _ => (to_body * pl.centre, CentreRule::Palpated),
    }
}

/// The rigid motion (body frame) taking the scaled base mesh onto the
/// patient's mesh `patient` (ICP from where the landmark fit put it), how
/// far it moves the base mesh's vertices at most (m) and the trimmed RMS
/// (m).
fn surface_fit(base: &TriMesh, patient: &TriMesh) -> Result<(Isometry3<f64>, f64, f64)> {
    let q = MeshQuery::new(patient).map_err(|e| Error::invalid("patient mesh", e.to_string()))?;
    let opts = crate::mesh::IcpOptions {
        initial: Some(crate::mesh::Similarity::identity()),
        max_iterations: 100,
        ..crate::mesh::IcpOptions::default()
    };
    let r = crate::mesh::icp(&base.vertices, &q, &opts)?;
    let t = Isometry3::from_parts(r.transform.translation.into(), r.transform.rotation);
    let moved = base
        .vertices
        .iter()
        .map(|p| (t * p - p).norm())
        .fold(0.0f64, f64::max);
    Ok((t, moved, r.trimmed_rms))
}

/// A body's (scaled) base meshes merged, in its frame; `None` when it has
/// none or one is missing.
fn scaled_base_mesh(
    b: &crate::osim::model::Body,
    source: Option<&dyn MeshSource>,
) -> Result<Option<TriMesh>> {
    let Some(src) = source else { return Ok(None) };
    let loaded = body_mesh(b, src)?;
    Ok(loaded.mesh.filter(|_| loaded.missing.is_empty()))
}

/// The body's mesh geometry replaced by one visible Mesh of `mesh_file`
/// at scale 1 (the first Mesh element kept for its name and appearance).
fn dress(el: &mut crate::osim::xml::Element, body: &str, mesh_file: &str) {
    let ag = el.child_or_insert("attached_geometry");
    let mut first = true;
    ag.children.retain(|n| match n {
        crate::osim::xml::Node::Element(e) if e.name == "Mesh" => std::mem::take(&mut first),
        _ => true,
    });
    let has_mesh = ag.elements().any(|e| e.name == "Mesh");
    if !has_mesh {
        ag.children.push(crate::osim::xml::Node::Element(
            crate::osim::builders::mesh(
                &format!("{body}_geom_1"),
                mesh_file,
                &Vector3::repeat(1.0),
            ),
        ));
    }
    if let Some(m) = ag.elements_mut().find(|e| e.name == "Mesh") {
        m.set_child_text("mesh_file", mesh_file);
        set_vec3(m, "scale_factors", &Vector3::repeat(1.0));
        if let Some(a) = m.child_mut("Appearance") {
            a.set_child_text("visible", "true");
        }
    }
}

/// Write the translation of the body's wrap sphere `name`.
fn set_sphere_centre(el: &mut crate::osim::xml::Element, name: &str, c: &Point3<f64>) {
    if let Some(w) = el
        .child_mut("WrapObjectSet")
        .and_then(|w| w.child_mut("objects"))
        .and_then(|o| o.elements_mut().find(|e| e.name_attr() == name))
    {
        set_vec3(w, "translation", &c.coords);
    }
}

/// The level's markers on `body` (pose `x` in ground) moved to the
/// patient's landmarks.
fn set_markers(
    doc: &mut Document,
    model: &Model,
    l: Level,
    body: &str,
    x: &Isometry3<f64>,
    at: &Placement,
) -> Result<()> {
    let Some(pts) = at.landmarks.get(&l) else {
        return Ok(());
    };
    for mk in &model.markers {
        let Some((id, _)) = crate::landmarks::LandmarkId::parse_name(&mk.name) else {
            continue;
        };
        let Some(p) = pts.get(&id.code).filter(|_| id.level == l) else {
            continue;
        };
        let (b, x_bf) = model.marker_frame(mk)?;
        if b != body {
            continue;
        }
        let local = x_bf.inverse() * (x.inverse() * p);
        if let Some(e) = doc.component_mut("MarkerSet", &mk.name) {
            set_vec3(e, "location", &local.coords);
        }
    }
    Ok(())
}

/// Step 3: every intervertebral joint between two placed levels at the
/// patient's disc: midway between the base's joint centre carried by the
/// upper vertebra's fit and by the lower one's (they agree to the chain's
/// joint mismatch), oriented half-way between the two vertebrae's ISB
/// frames from the patient's landmarks; returns the joints written.
fn patient_joints(
    doc: &mut Document,
    model: &Model,
    poses: &BTreeMap<String, Isometry3<f64>>,
    at: &Placement,
    surface_fits: &BTreeMap<String, Isometry3<f64>>,
) -> Result<Vec<String>> {
    // A joint centre carried by a body's landmark fit, then its surface fit
    // when that moves it less than the limit.
    let carry = |body: &str, x: &Isometry3<f64>, p: &Point3<f64>| {
        let g = x * p;
        match surface_fits.get(body).map(|t| t * g) {
            Some(h) if (h - g).norm() <= SURFACE_FIT_LIMIT => h,
            _ => g,
        }
    };
    let mut done = Vec::new();
    for jf in model.joint_frames()? {
        let (Some(lu), Some(ll)) = (
            Level::from_body_name(&jf.child_body),
            Level::from_body_name(&jf.parent_body),
        ) else {
            continue;
        };
        if lu.caudal() != Some(ll) || !at.placed.contains(&lu) || !at.placed.contains(&ll) {
            continue;
        }
        let (Some(pu), Some(pl), Some((ju, jl))) = (
            at.landmarks.get(&lu),
            at.landmarks.get(&ll),
            at.joints.get(&lu),
        ) else {
            continue;
        };
        let ru = super::isb_rotation(pu);
        let rl = if ll.is_sacrum() {
            super::sacral_rotation(pl)
        } else {
            super::isb_rotation(pl)
        };
        let (Some(ru), Some(rl), Some(xu), Some(xl)) = (
            ru,
            rl,
            poses.get(&jf.child_body),
            poses.get(&jf.parent_body),
        ) else {
            continue;
        };
        let j = super::disc_frame(
            &carry(&jf.child_body, xu, ju),
            &carry(&jf.parent_body, xl, jl),
            &nalgebra::UnitQuaternion::from_rotation_matrix(&ru),
            &nalgebra::UnitQuaternion::from_rotation_matrix(&rl),
        );
        super::write_joint(
            doc,
            model,
            &jf.joint,
            &jf.parent_body,
            &jf.child_body,
            &(xl.inverse() * j),
            &(xu.inverse() * j),
        )?;
        done.push(jf.joint.clone());
    }
    Ok(done)
}

/// Step 5: every muscle path point (fixed or conditional) inside a
/// patient bone at the default pose moved out along the bone's surface
/// normal to [`ATTACHMENT_CLEARANCE`] outside it; listed.
fn attachments_out_of_bone(
    doc: &mut Document,
    bones: &[(String, MeshQuery)],
    poses: &BTreeMap<String, Isometry3<f64>>,
) -> Result<Vec<MovedPoint>> {
    let model = doc.model()?;
    let boxes: Vec<Option<(Point3<f64>, Point3<f64>)>> =
        bones.iter().map(|(_, q)| q.mesh().bounds()).collect();
    let mut moved = Vec::new();
    for m in model.muscles() {
        for p in &m.points {
            if matches!(p.kind, PathPointKind::Moving { .. }) {
                continue;
            }
            let owner = format!("/forceset/{}/path/{}", m.name, p.name);
            let (body, x_bf) = model.resolve_frame(&owner, &p.socket_parent_frame)?;
            let Some(xb) = poses.get(&body) else { continue };
            let g0 = xb * (x_bf * Point3::from(p.location));
            let mut g = g0;
            let mut first: Option<(String, f64)> = None;
            // A point pushed out of one bone may land in its neighbour.
            for _ in 0..4 {
                let Some((bone, depth, out)) = push_out(&g, bones, &boxes, poses) else {
                    break;
                };
                first.get_or_insert((bone, depth));
                g = out;
            }
            let Some((bone, depth)) = first else { continue };
            let local = x_bf.inverse() * (xb.inverse() * g);
            set_path_point(doc, &m.name, &p.name, &local.coords);
            moved.push(MovedPoint {
                muscle: m.name.clone(),
                point: p.name.clone(),
                body,
                bone,
                depth_mm: depth * 1e3,
                moved_mm: (g - g0).norm() * 1e3,
            });
        }
    }
    Ok(moved)
}

/// The first bone `g` (ground) is inside: its name, the depth and the
/// point moved out along the surface normal (ground).
fn push_out(
    g: &Point3<f64>,
    bones: &[(String, MeshQuery)],
    boxes: &[Option<(Point3<f64>, Point3<f64>)>],
    poses: &BTreeMap<String, Isometry3<f64>>,
) -> Option<(String, f64, Point3<f64>)> {
    for ((name, q), bx) in bones.iter().zip(boxes) {
        let (Some(x), Some((lo, hi))) = (poses.get(name), bx) else {
            continue;
        };
        let l = x.inverse() * g;
        if (0..3).any(|k| l[k] < lo[k] || l[k] > hi[k]) || !q.contains(&l) {
            continue;
        }
        let hit = q.closest_point(&l);
        let mut n = q.mesh().triangle_normal(hit.triangle);
        if (hit.point - l).dot(&n) < 0.0 && hit.t > 0.0 {
            n = -n;
        }
        let out = hit.point + n * ATTACHMENT_CLEARANCE;
        return Some((name.clone(), hit.t, x * out));
    }
    None
}

/// Write a path point's location (in its socket frame).
fn set_path_point(doc: &mut Document, muscle: &str, point: &str, loc: &Vector3<f64>) {
    if let Some(e) = super::clear::path_points(doc, muscle)
        .and_then(|o| o.elements_mut().find(|e| e.name_attr() == point))
    {
        set_vec3(e, "location", loc);
    }
}
