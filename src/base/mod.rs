//! The base-model builder (`osim-spine base`): from a generic full-body
//! model with an articulated thoracolumbar spine (the cyclist model's
//! conventions: bodies `thoracic1..12`, `lumbar1..5`, `sacrum`, `pelvis`;
//! IVD CustomJoints with the lower vertebra as parent; vertebra body origin
//! at the inferior joint centre, X anterior, Y cranial, Z right) to the
//! base model of the thesis (chapter 5.2):
//!
//! 1. keep the vertebrae (default T1-L5), the sacrum and the pelvis; drop
//!    every other body, joint, constraint, actuator, marker, contact
//!    element and component; keep exactly the muscles whose whole path lies
//!    on kept bodies and kept coordinates ([`prune`]); weld the pelvis (or
//!    the sacrum) to ground at its generic default pose;
//! 2. check that every vertebra mesh sits on its joint chain ([`sanity`]);
//! 3. swap in a mean sacrum ([`sacrum`]);
//! 4. rebuild every IVD joint as a 6-DoF CustomJoint with a coincident
//!    BushingForce ([`joints`], parameters from [`template`]);
//! 5. palpate every vertebra with the palpation engine
//!    ([`crate::palpation`]): its landmarks become the markers, its
//!    vertebral centre (thesis sphere rule) the centre of the vertebral-body
//!    wrapping sphere; add PathWraps ([`wrap`]);
//! 6. the S1 plateau markers by the engine's sacrum rule, and the femoral
//!    head centres as pelvis markers `FH_R` / `FH_L` ([`hips`]);
//! 7. self-check ([`check`]) and draw the report views ([`views`]).
//!
//! [`build_base`] computes everything in memory and writes nothing; meshes
//! come through a [`MeshSource`] (a folder search like OpenSim's, or an
//! in-memory map for generated models).

mod assemble;
pub mod centres;
pub mod check;
pub mod guards;
pub mod hips;
pub mod joints;
pub mod kin;
pub mod overrides;
mod palpate;
pub mod prune;
pub mod sacrum;
pub mod sanity;
pub mod template;
mod topology;
mod vertebrae;
pub mod views;
pub mod wrap;
pub mod wrapped;
mod wrapping;

use crate::error::Result;
use crate::landmarks::Level;
use crate::mesh::{MeshQuery, TriMesh};
use crate::osim::model::{Geometry, Model};
use crate::osim::Document;
use kin::Kinematics;
pub use overrides::Overrides;
use sanity::SanityRow;
use std::collections::BTreeMap;
pub use template::IvdParams;

pub use crate::mesh::source::{DirMeshSource, MeshSource};

/// Which body is welded to ground.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum FixedBody {
    /// The pelvis, through a weld joint at its generic default pose.
    Pelvis,
    /// The sacrum, through a weld joint at its generic default pose.
    Sacrum,
}

/// Options of [`build_base`].
#[derive(Debug, Clone)]
pub struct BaseOptions {
    /// Most cranial kept vertebra (T1 by default); the kept run always
    /// ends at L5 (the sacrum and pelvis are kept).
    pub top: Level,
    /// Body welded to ground.
    pub fixed: FixedBody,
    /// Mean sacrum to swap in: (name for messages, mesh in metres).
    pub sacrum: Option<(String, TriMesh)>,
    /// Similarity (not only rigid) registration of the sacrum.
    pub allow_scale: bool,
    /// Body-only meshes per level for the sphere fits: (name, mesh).
    pub body_meshes: BTreeMap<Level, (String, TriMesh)>,
    /// IVD bushing parameters and coordinate ranges.
    pub ivd: IvdParams,
    /// Largest accepted RMS residual of the sacrum registration (m).
    pub max_sacrum_rms: f64,
    /// File name given to the swapped-in sacrum mesh.
    pub sacrum_file: String,
    /// Write the model even when a guard fails (failures become warnings).
    pub allow_implausible: bool,
    /// A modeller's own palpation of the generic model (`--palpation`,
    /// `--centres`): replaces the engine's landmarks and centres it names.
    pub overrides: Overrides,
}

impl Default for BaseOptions {
    fn default() -> Self {
        BaseOptions {
            top: Level::T1,
            fixed: FixedBody::Pelvis,
            sacrum: None,
            allow_scale: false,
            body_meshes: BTreeMap::new(),
            ivd: IvdParams::defaults(),
            max_sacrum_rms: 0.012,
            sacrum_file: "sacrum_mean.vtp".into(),
            allow_implausible: false,
            overrides: Overrides::default(),
        }
    }
}

/// One joint of the base model.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct JointRow {
    /// Joint name.
    pub name: String,
    /// What the builder did with it (e.g. rebuilt as a 6-DoF CustomJoint).
    pub action: String,
    /// Parent body name.
    pub parent: String,
    /// Child body name.
    pub child: String,
    /// Its coordinates' names (empty for a weld).
    pub coordinates: Vec<String>,
    /// Default values of those coordinates (rad or m), in the same order.
    pub default_values: Vec<f64>,
    /// Name of the bushing acting across it, if any.
    pub bushing: Option<String>,
}

/// One palpated marker.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct MarkerRow {
    /// Marker name.
    pub name: String,
    /// Body the marker is fixed to.
    pub body: String,
    /// In the body frame (m).
    pub location: [f64; 3],
    /// Distance to the body's mesh surface (mm).
    pub surface_distance_mm: f64,
}

/// Everything the builder did and measured (serialised as the JSON report).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct BaseReport {
    /// The generic model file the base was built from.
    pub generic_model: String,
    /// Vertebral levels kept, cranial to caudal.
    pub kept_levels: Vec<String>,
    /// The body welded to ground.
    pub fixed_body: FixedBody,
    /// Bodies, joints, forces, markers and constraints kept or dropped.
    pub prune: prune::PruneReport,
    /// Every joint of the base model and what was done to it.
    pub joints: Vec<JointRow>,
    /// IVD bushing parameters and coordinate ranges used.
    pub ivd_parameters: IvdParams,
    /// Per-segment geometry checks of the kept vertebra meshes.
    pub geometry_sanity: Vec<SanityRow>,
    /// The sacrum swap, when a mean sacrum was given.
    pub sacrum: Option<sacrum::SacrumReport>,
    /// The fitted vertebral body wrap spheres.
    pub spheres: Vec<wrap::SphereRow>,
    /// Labels of the test poses the wrapping rules were checked at.
    pub test_poses: Vec<String>,
    /// Number of muscle path wraps added.
    pub path_wraps_added: usize,
    /// Number of muscles wrapping over at least one sphere.
    pub muscles_with_wraps: usize,
    /// The palpated markers written into the model.
    pub markers: Vec<MarkerRow>,
    /// The femoral head centres kept as pelvis markers (empty when the
    /// generic model has neither `FH_R`/`FH_L` markers nor hip joints).
    pub hip_centres: Vec<hips::HipCentre>,
    /// Every finding of the palpation engine (warnings and errors).
    pub palpation_ordering_failures: Vec<String>,
    /// Landmarks (`T3_SP`) and centres (`T3_centre`) taken from the
    /// modeller's `--palpation` / `--centres` files instead of the engine.
    pub palpation_given: Vec<String>,
    /// Guards checked per vertebra ([`guards::Guard::ALL`]) and their failures.
    pub guards_checked: Vec<guards::Guard>,
    /// Guards that failed, one row per vertebra and guard.
    pub guard_failures: Vec<guards::GuardFailure>,
    /// Whether failures were allowed (`--allow-implausible`).
    pub allow_implausible: bool,
    /// The built model's self-check (deflections, muscle paths, equilibrium).
    pub self_check: check::SelfCheck,
}

/// The built base model, not yet written.
#[derive(Debug, Clone)]
pub struct BaseModel {
    /// The base model document.
    pub doc: Document,
    /// Mesh files the model references, to write next to it.
    pub meshes: Vec<(String, TriMesh)>,
    /// What the builder did and measured.
    pub report: BaseReport,
    /// SVG views: (file name, SVG text).
    pub views: Vec<(String, String)>,
}

/// Level index for a kept body (vertebra index, S1 for sacrum and pelvis).
pub(crate) fn body_level_index(body: &str) -> Option<usize> {
    if body == "pelvis" {
        return Some(Level::S1.index());
    }
    Level::from_body_name(body).map(|l| l.index())
}

/// Build the base model from `generic` (see the module documentation).
pub fn build_base(
    generic: &Document,
    opts: &BaseOptions,
    source: &dyn MeshSource,
) -> Result<BaseModel> {
    let gfile = generic.path().display().to_string();
    let model = generic.model()?;
    // 1. Kept levels, their IVD joints, the generic default poses.
    let topo = topology::select_levels(&model, opts, &gfile)?;
    // 2. Every kept body's mesh; each vertebra on its joint chain.
    let vert = vertebrae::load_vertebrae(&model, &topo, source, &gfile)?;
    let vs = &vert.verts;
    // 3. The mean sacrum, if one is given.
    let sac = assemble::swap_sacrum(&vert.body_meshes, opts, &gfile)?;
    // 4. IVD joints rebuilt with bushings; the muscles kept.
    let rebuilt = assemble::rebuild_joints(generic, &model, &topo, opts, &gfile)?;
    // 5. The base document without wraps and markers.
    let (mut doc, joint_rows) =
        assemble::assemble_document(generic, &model, &topo, &rebuilt, &sac, opts, &gfile)?;
    // 6. Landmarks and vertebral centres (engine, then the modeller's); guards.
    let mut pal = palpate::palpate(vs, &topo, &opts.overrides, opts.allow_implausible)?;
    let mut spheres: Vec<wrap::SphereRow> = vs
        .iter()
        .zip(&pal.palps)
        .map(|(v, p)| palpate::body_sphere(v, p, opts.body_meshes.contains_key(&v.level)))
        .collect();
    // 7. Spheres on the bodies and the muscles that wrap over them.
    let wrapping = wrapping::add_wraps(&mut doc, &mut spheres, &rebuilt.prefixes(), &gfile)?;
    // 8. Markers on the vertebrae and the S1 plateau.
    let markers = palpate::add_markers(
        &mut doc,
        vs,
        &mut pal,
        (&sac.mesh, &sac.file),
        &topo,
        &opts.overrides,
    )?;
    let hip_centres = hips::hip_centres(&model, &topo, &gfile)?;
    hips::add_hip_markers(&mut doc, &hip_centres);
    // 9. The meshes written beside the model.
    let out_meshes = meshes_to_write(&model, &topo, &sac, opts, source)?;
    // 10. Self-check, views and the report.
    let base = doc.model()?;
    let vert_meshes: Vec<(String, &MeshQuery)> =
        vs.iter().map(|v| (v.body.clone(), &v.query)).collect();
    let self_check = check::run(&base, &vert_meshes, &spheres)?;
    let kinb = Kinematics::new(&base)?;
    let pb = kinb.body_poses(&kinb.default_values())?;
    let view_meshes: Vec<(String, &TriMesh)> = vs
        .iter()
        .map(|v| (v.body.clone(), &v.mesh))
        .chain(std::iter::once(("sacrum".to_string(), &sac.mesh)))
        .collect();
    let views = views::render(&pb, &view_meshes, &markers.rows, &spheres);
    let report = BaseReport {
        generic_model: gfile,
        kept_levels: topo.levels.iter().map(|l| l.to_string()).collect(),
        fixed_body: opts.fixed,
        prune: rebuilt.prune,
        joints: joint_rows,
        ivd_parameters: opts.ivd.clone(),
        geometry_sanity: vert.sanity,
        sacrum: sac.report,
        spheres,
        test_poses: wrapping.test_poses,
        path_wraps_added: wrapping.path_wraps_added,
        muscles_with_wraps: wrapping.muscles_with_wraps,
        markers: markers.rows,
        hip_centres,
        palpation_ordering_failures: markers.findings,
        palpation_given: pal.overridden,
        guards_checked: guards::Guard::ALL.to_vec(),
        guard_failures: pal.guard_failures,
        allow_implausible: opts.allow_implausible,
        self_check,
    };
    Ok(BaseModel {
        doc,
        meshes: out_meshes.into_iter().collect(),
        report,
        views,
    })
}

/// Step 9: the meshes of the kept bodies (the sacrum's, swapped or not).
fn meshes_to_write(
    model: &Model,
    topo: &topology::Topology,
    sac: &assemble::Sacrum,
    opts: &BaseOptions,
    source: &dyn MeshSource,
) -> Result<BTreeMap<String, TriMesh>> {
    let mut out: BTreeMap<String, TriMesh> = BTreeMap::new();
    let add_body = |out: &mut BTreeMap<String, TriMesh>, b: &str, skip_known: bool| -> Result<()> {
        if let Some(base) = model.body(b) {
            for g in &base.geometry {
                if let Geometry::Mesh { mesh_file, .. } = g {
                    if skip_known && (mesh_file.is_empty() || out.contains_key(mesh_file)) {
                        continue;
                    }
                    if let Some(m) = source.load(mesh_file)? {
                        out.insert(mesh_file.clone(), m);
                    }
                }
            }
        }
        Ok(())
    };
    for b in topo.kept.iter().filter(|b| *b != "sacrum") {
        add_body(&mut out, b, true)?;
    }
    if opts.sacrum.is_some() {
        out.insert(sac.file.clone(), sac.mesh.clone());
    } else {
        add_body(&mut out, "sacrum", false)?;
    }
    Ok(out)
}
