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
//! 6. the S1 plateau markers by the engine's sacrum rule;
//! 7. self-check ([`check`]) and draw the report views ([`views`]).
//!
//! [`build_base`] computes everything in memory and writes nothing; meshes
//! come through a [`MeshSource`] (a folder search like OpenSim's, or an
//! in-memory map for generated models).

pub mod centres;
pub mod check;
pub mod guards;
pub mod joints;
pub mod kin;
pub mod palpate;
pub mod prune;
pub mod sacrum;
pub mod sanity;
pub mod template;
pub mod views;
pub mod wrap;
pub mod wrapped;

use crate::error::{Error, Result};
use crate::landmarks::{Code, Level};
use crate::mesh::{MeshQuery, TriMesh};
use crate::osim::builders;
use crate::osim::model::{Geometry, Model};
use crate::osim::xml::Node;
use crate::osim::Document;
use crate::palpation::{self, FrameHint, VertebraPalpation};
use kin::{Kinematics, Values};
use nalgebra::{Isometry3, Point3, Vector3};
use sanity::{SanityRow, Segment};
use std::collections::{BTreeMap, BTreeSet};
pub use template::IvdParams;

pub use crate::mesh::source::{DirMeshSource, MeshSource};

/// Which body is welded to ground.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum FixedBody {
    Pelvis,
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
        }
    }
}

/// One joint of the base model.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct JointRow {
    pub name: String,
    pub action: String,
    pub parent: String,
    pub child: String,
    pub coordinates: Vec<String>,
    pub default_values: Vec<f64>,
    pub bushing: Option<String>,
}

/// One palpated marker.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct MarkerRow {
    pub name: String,
    pub body: String,
    /// In the body frame (m).
    pub location: [f64; 3],
    /// Distance to the body's mesh surface (mm).
    pub surface_distance_mm: f64,
}

/// Everything the builder did and measured (serialised as the JSON report).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct BaseReport {
    pub generic_model: String,
    pub kept_levels: Vec<String>,
    pub fixed_body: FixedBody,
    pub prune: prune::PruneReport,
    pub joints: Vec<JointRow>,
    pub ivd_parameters: IvdParams,
    pub geometry_sanity: Vec<SanityRow>,
    pub sacrum: Option<sacrum::SacrumReport>,
    pub spheres: Vec<wrap::SphereRow>,
    pub test_poses: Vec<String>,
    pub path_wraps_added: usize,
    pub muscles_with_wraps: usize,
    pub markers: Vec<MarkerRow>,
    /// Every finding of the palpation engine (warnings and errors).
    pub palpation_ordering_failures: Vec<String>,
    /// Guards checked per vertebra ([`guards::Guard::ALL`]) and their failures.
    pub guards_checked: Vec<guards::Guard>,
    pub guard_failures: Vec<guards::GuardFailure>,
    /// Whether failures were allowed (`--allow-implausible`).
    pub allow_implausible: bool,
    pub self_check: check::SelfCheck,
}

/// The built base model, not yet written.
#[derive(Debug, Clone)]
pub struct BaseModel {
    pub doc: Document,
    /// Mesh files the model references, to write next to it.
    pub meshes: Vec<(String, TriMesh)>,
    pub report: BaseReport,
    /// SVG views: (file name, SVG text).
    pub views: Vec<(String, String)>,
}

/// Per-vertebra data gathered on the way.
struct Vert {
    level: Level,
    body: String,
    mesh_file: String,
    mesh: TriMesh,
    query: MeshQuery,
    seg: Segment,
}

/// Level index for a kept body (vertebra index, S1 for sacrum and pelvis).
pub(crate) fn body_level_index(body: &str) -> Option<usize> {
    if body == "pelvis" {
        return Some(Level::S1.index());
    }
    Level::from_body_name(body).map(|l| l.index())
}

fn mesh_of(
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
    let mut parts = Vec::new();
    let mut names = Vec::new();
    for g in &b.geometry {
        if let Geometry::Mesh {
            mesh_file,
            scale_factors,
            ..
        } = g
        {
            if mesh_file.is_empty() {
                continue;
            }
            match source.load(mesh_file)? {
                Some(m) => {
                    m.validate().map_err(|e| {
                        Error::invalid(format!("mesh {mesh_file} of body {body}"), e.to_string())
                    })?;
                    parts.push(m.scaled(scale_factors));
                    names.push(mesh_file.clone());
                }
                None => missing.push(format!("'{mesh_file}' (body {body})")),
            }
        }
    }
    if parts.is_empty() {
        return Ok(None);
    }
    let refs: Vec<&TriMesh> = parts.iter().collect();
    let merged = TriMesh::merge(&refs)?;
    Ok(Some((names.join("+"), merged)))
}

/// Build the base model from `generic` (see the module documentation).
pub fn build_base(
    generic: &Document,
    opts: &BaseOptions,
    source: &dyn MeshSource,
) -> Result<BaseModel> {
    let gfile = generic.path().display().to_string();
    let model = generic.model()?;
    // ---- 1. kept bodies and topology
    if opts.top > Level::L5 {
        return Err(Error::invalid(
            "--keep",
            "the top kept level must be T1..L5",
        ));
    }
    let levels: Vec<Level> = Level::ALL[opts.top.index()..=Level::L5.index()].to_vec();
    let mut kept: Vec<String> = levels.iter().map(|l| l.body_name()).collect();
    kept.push("sacrum".into());
    kept.push("pelvis".into());
    let missing: Vec<&String> = kept.iter().filter(|b| model.body(b).is_none()).collect();
    if !missing.is_empty() {
        return Err(Error::invalid(
            &gfile,
            format!(
                "the generic model lacks the bodies {} (a base model needs thoracic1..12, lumbar1..5, \
                 sacrum and pelvis for the kept levels {}..L5)",
                missing.iter().map(|s| format!("'{s}'")).collect::<Vec<_>>().join(", "),
                opts.top
            ),
        ));
    }
    let kept_set: BTreeSet<String> = kept.iter().cloned().collect();
    let frames = model.joint_frames()?;
    let gdefaults: Values = model
        .coordinates()
        .map(|c| (c.name.clone(), c.default_value))
        .collect();
    // IVD joints, caudal to cranial.
    let mut ivd = Vec::new(); // (upper, lower, joint index)
    for &up in levels.iter().rev() {
        let low = up.caudal().unwrap_or(Level::S1);
        let (ub, lb) = (up.body_name(), low.body_name());
        let found = frames
            .iter()
            .position(|f| f.parent_body == lb && f.child_body == ub);
        let Some(i) = found else {
            let reversed = frames
                .iter()
                .find(|f| f.parent_body == ub && f.child_body == lb);
            return Err(Error::invalid(
                &gfile,
                match reversed {
                    Some(f) => format!(
                        "joint '{}' has '{ub}' as parent of '{lb}': the base builder needs the lower \
                         vertebra as parent",
                        f.joint
                    ),
                    None => format!("no joint between '{lb}' (parent) and '{ub}' (child)"),
                },
            ));
        };
        ivd.push((up, low, i));
    }
    let sacral = frames
        .iter()
        .position(|f| {
            (f.parent_body == "pelvis" && f.child_body == "sacrum")
                || (f.parent_body == "sacrum" && f.child_body == "pelvis")
        })
        .ok_or_else(|| Error::invalid(&gfile, "no joint between 'pelvis' and 'sacrum'"))?;
    // Generic default poses of the pelvis and sacrum.
    let gkin = Kinematics::new(&model)?;
    let gposes = gkin.body_poses(&gdefaults)?;
    let pose_of = |b: &str| {
        gposes
            .get(b)
            .copied()
            .ok_or_else(|| Error::invalid(&gfile, format!("body '{b}' has no pose")))
    };
    let x_pelvis = pose_of("pelvis")?;
    let x_sacrum = pose_of("sacrum")?;

    // ---- 2. meshes and sanity
    let mut missing_meshes = Vec::new();
    let mut body_meshes: BTreeMap<String, (String, TriMesh)> = BTreeMap::new();
    for b in &kept {
        if let Some(m) = mesh_of(&model, b, source, &mut missing_meshes)? {
            body_meshes.insert(b.clone(), m);
        }
    }
    if !missing_meshes.is_empty() {
        return Err(Error::invalid(
            &gfile,
            format!(
                "mesh files not found: {} (searched {})",
                missing_meshes.join(", "),
                source.describe()
            ),
        ));
    }
    let mut verts = Vec::new();
    let mut no_mesh = Vec::new();
    for &(up, _, i) in &ivd {
        let body = up.body_name();
        let Some((file, mesh)) = body_meshes.get(&body) else {
            no_mesh.push(body.clone());
            continue;
        };
        let ctx = format!("mesh {file} of body {body}");
        mesh.require_watertight(&ctx)?;
        let query = MeshQuery::new(mesh).map_err(|e| Error::invalid(&ctx, e.to_string()))?;
        let inferior = Point3::from(frames[i].child_in_body.translation.vector);
        let superior = up
            .cranial()
            .and_then(|c| {
                frames
                    .iter()
                    .find(|f| f.parent_body == body && f.child_body == c.body_name())
            })
            .map(|f| Point3::from(f.parent_in_body.translation.vector));
        verts.push((
            up,
            body,
            file.clone(),
            mesh.clone(),
            query,
            inferior,
            superior,
        ));
    }
    if !no_mesh.is_empty() {
        return Err(Error::invalid(
            &gfile,
            format!("vertebra bodies without a mesh: {}", no_mesh.join(", ")),
        ));
    }
    // Extrapolate missing superior centres (top vertebra) from the one below.
    let mut vs: Vec<Vert> = Vec::new();
    let mut below_len = 0.025;
    for (up, body, file, mesh, query, inferior, superior) in verts {
        let (superior, from_joint) = match superior {
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
            mesh_file: file,
            mesh,
            query,
            seg,
        });
    }
    let sanity: Vec<SanityRow> = vs
        .iter()
        .map(|v| {
            sanity::check_vertebra(
                &v.level.to_string(),
                &v.body,
                &v.mesh_file,
                &v.query,
                &v.seg,
            )
        })
        .collect();
    let bad: Vec<String> = sanity
        .iter()
        .filter(|r| !r.ok)
        .map(|r| format!("{} ({}): {}", r.mesh_file, r.body, r.problems.join("; ")))
        .collect();
    if !bad.is_empty() {
        return Err(Error::invalid(
            &gfile,
            format!(
                "{} vertebra mesh(es) do not sit on their body's joint chain (misplaced meshes; use \
                 meshes placed in the body frames, e.g. ../shared/data/geometry-bodyframe/):\n  {}",
                bad.len(),
                bad.join("\n  ")
            ),
        ));
    }

    // ---- 3. sacrum swap
    let mut out_meshes: BTreeMap<String, TriMesh> = BTreeMap::new();
    let (sac_file, sac_mesh) = body_meshes
        .get("sacrum")
        .cloned()
        .ok_or_else(|| Error::invalid(&gfile, "the sacrum has no mesh"))?;
    let (sacrum_mesh, sacrum_file, sacrum_report) = match &opts.sacrum {
        Some((name, m)) => {
            let (moved, rep) = sacrum::register_sacrum(
                m,
                name,
                &sac_mesh,
                &sac_file,
                &opts.sacrum_file,
                opts.allow_scale,
                opts.max_sacrum_rms,
            )?;
            (moved, opts.sacrum_file.clone(), Some(rep))
        }
        None => (sac_mesh.clone(), sac_file.clone(), None),
    };

    // ---- 4. prune (muscles etc.) and joint rebuild
    let mut renames: BTreeMap<String, (String, String)> = BTreeMap::new(); // old -> (joint, new)
    let mut rebuilt = Vec::new();
    let joint_els = generic.components("JointSet");
    for &(up, low, i) in &ivd {
        let j = &model.joints[i];
        let el = joint_els
            .iter()
            .find(|e| e.name_attr() == j.name)
            .ok_or_else(|| {
                Error::invalid(&gfile, format!("joint element '{}' not found", j.name))
            })?;
        let x0 = gkin.joint_transform(&j.name, &gdefaults)?;
        let r = joints::rebuild_ivd_joint(el, j, &frames[i], up, low, &opts.ivd, &x0)?;
        for (old, new) in &r.renames {
            renames.insert(old.clone(), (j.name.clone(), new.clone()));
        }
        rebuilt.push((up, low, i, r));
    }
    let mut kept_coords: BTreeSet<String> = BTreeSet::new();
    for (up, low, _, _) in &rebuilt {
        for s in joints::COORD_SUFFIXES {
            kept_coords.insert(format!("{}_{s}", joints::joint_prefix(*up, *low)));
        }
    }
    let sacral_joint = &model.joints[sacral];
    for c in &sacral_joint.coordinates {
        kept_coords.insert(c.name.clone());
    }
    let pr = prune::decide(&model, &kept_set, &kept_coords, &renames)?;

    // ---- 5. assemble the document (without wraps and markers)
    let mut doc = generic.clone();
    let mname = format!("{}_base", model.name);
    doc.model_element_mut().set_attr("name", mname);
    // Bodies.
    {
        let objs = doc.set_objects_mut("BodySet");
        objs.children.retain(|n| match n {
            Node::Element(e) => kept_set.contains(e.name_attr()),
            _ => true,
        });
    }
    for b in &kept {
        let Some(el) = doc.component_mut("BodySet", b) else {
            continue;
        };
        // Wrap objects not used by kept muscles are dropped.
        if let Some(ws) = el
            .child_mut("WrapObjectSet")
            .and_then(|w| w.child_mut("objects"))
        {
            ws.children.retain(|n| match n {
                Node::Element(e) => pr.used_wrap_objects.contains(e.name_attr()),
                _ => true,
            });
        }
        if b == "sacrum" && opts.sacrum.is_some() {
            if let Some(ag) = el.child_mut("attached_geometry") {
                let mut first = true;
                ag.children.retain(|n| match n {
                    Node::Element(e) if e.name == "Mesh" => std::mem::replace(&mut first, false),
                    _ => true,
                });
                if let Some(mesh) = ag.elements_mut().find(|e| e.name == "Mesh") {
                    mesh.set_child_text("mesh_file", sacrum_file.clone());
                    mesh.set_child_text("scale_factors", "1 1 1");
                }
            }
        }
    }
    // Joints.
    let mut joint_rows = Vec::new();
    let mut new_joints = Vec::new();
    match opts.fixed {
        FixedBody::Pelvis => {
            new_joints.push(joints::weld_joint(
                "ground_pelvis",
                "ground",
                "pelvis",
                &x_pelvis,
            ));
            joint_rows.push(JointRow {
                name: "ground_pelvis".into(),
                action: "pelvis welded to ground at its generic default pose".into(),
                parent: "ground".into(),
                child: "pelvis".into(),
                coordinates: vec![],
                default_values: vec![],
                bushing: None,
            });
        }
        FixedBody::Sacrum => {
            new_joints.push(joints::weld_joint(
                "ground_sacrum",
                "ground",
                "sacrum",
                &x_sacrum,
            ));
            joint_rows.push(JointRow {
                name: "ground_sacrum".into(),
                action: "sacrum welded to ground at its generic default pose".into(),
                parent: "ground".into(),
                child: "sacrum".into(),
                coordinates: vec![],
                default_values: vec![],
                bushing: None,
            });
        }
    }
    {
        let jf = &frames[sacral];
        let el = joint_els
            .iter()
            .find(|e| e.name_attr() == sacral_joint.name)
            .map(|e| (*e).clone())
            .ok_or_else(|| Error::invalid(&gfile, "sacral joint element not found"))?;
        let parent_is_ground_side = match opts.fixed {
            FixedBody::Pelvis => jf.parent_body == "pelvis",
            FixedBody::Sacrum => jf.parent_body == "sacrum",
        };
        let mut el = el;
        let action = if parent_is_ground_side {
            "kept".to_string()
        } else {
            if el.name != "WeldJoint" {
                return Err(Error::invalid(
                    &gfile,
                    format!(
                        "joint '{}' between pelvis and sacrum is a {}: only a WeldJoint can be \
                         reversed for the requested fixed body",
                        sacral_joint.name, el.name
                    ),
                ));
            }
            let p = el.child_text("socket_parent_frame").unwrap_or_default();
            let c = el.child_text("socket_child_frame").unwrap_or_default();
            el.set_child_text("socket_parent_frame", c);
            el.set_child_text("socket_child_frame", p);
            "reversed (weld)".to_string()
        };
        let (parent, child) = if parent_is_ground_side {
            (jf.parent_body.clone(), jf.child_body.clone())
        } else {
            (jf.child_body.clone(), jf.parent_body.clone())
        };
        joint_rows.push(JointRow {
            name: sacral_joint.name.clone(),
            action,
            parent,
            child,
            coordinates: sacral_joint
                .coordinates
                .iter()
                .map(|c| c.name.clone())
                .collect(),
            default_values: sacral_joint
                .coordinates
                .iter()
                .map(|c| c.default_value)
                .collect(),
            bushing: None,
        });
        new_joints.push(el);
    }
    let mut bushings = Vec::new();
    for (up, low, i, r) in &rebuilt {
        let prefix = joints::joint_prefix(*up, *low);
        joint_rows.push(JointRow {
            name: model.joints[*i].name.clone(),
            action: "rebuilt as 6-DoF CustomJoint (LB, AR, FE, AP, SI, ML)".into(),
            parent: frames[*i].parent_body.clone(),
            child: frames[*i].child_body.clone(),
            coordinates: joints::COORD_SUFFIXES
                .iter()
                .map(|s| format!("{prefix}_{s}"))
                .collect(),
            default_values: r.defaults.to_vec(),
            bushing: Some(r.bushing.name_attr().to_string()),
        });
        new_joints.push(r.joint.clone());
        bushings.push(r.bushing.clone());
    }
    {
        let objs = doc.set_objects_mut("JointSet");
        objs.children.clear();
        objs.children
            .extend(new_joints.into_iter().map(Node::Element));
    }
    // Forces: kept muscles (renamed coordinate sockets), then bushings.
    let force_els = generic.components("ForceSet");
    let mut muscles_out = Vec::new();
    for name in &pr.muscles_kept {
        let el = force_els
            .iter()
            .find(|e| e.name_attr() == name)
            .ok_or_else(|| Error::invalid(&gfile, format!("muscle element '{name}' not found")))?;
        let mut el = (*el).clone();
        prune::rename_coordinate_sockets(&mut el, &renames);
        muscles_out.push(el);
    }
    {
        let objs = doc.set_objects_mut("ForceSet");
        objs.children.clear();
        objs.children
            .extend(muscles_out.into_iter().chain(bushings).map(Node::Element));
    }
    for set in [
        "MarkerSet",
        "ConstraintSet",
        "ContactGeometrySet",
        "ControllerSet",
        "ProbeSet",
        "ComponentSet",
    ] {
        if doc.model_element().child(set).is_some() {
            doc.set_objects_mut(set).children.clear();
        }
    }

    // ---- 6. palpation engine: landmarks and vertebral-body spheres; guards
    let palps = palpate_vertebrae(&vs)?;
    let guard_failures: Vec<guards::GuardFailure> =
        palps.iter().flat_map(guards::check_vertebra).collect();
    refuse_implausible(&guard_failures, opts.allow_implausible)?;
    let mut spheres: Vec<wrap::SphereRow> = vs
        .iter()
        .zip(&palps)
        .map(|(v, p)| body_sphere(v, p, opts.body_meshes.contains_key(&v.level)))
        .collect();

    // ---- 7. wrapping assignment on the assembled model
    let prefixes: Vec<String> = rebuilt
        .iter()
        .map(|(u, l, _, _)| joints::joint_prefix(*u, *l))
        .collect();
    let base0 = doc.model()?;
    let kin0 = Kinematics::new(&base0)?;
    let defaults = kin0.default_values();
    let poses = wrap::test_poses(&defaults, &prefixes);
    let mut pose_bodies = Vec::new();
    for (_, q) in &poses {
        pose_bodies.push(kin0.body_poses(q)?);
    }
    let mut mgeo = Vec::new();
    for m in base0.muscles() {
        let mut paths = Vec::new();
        let mut bodies = BTreeSet::new();
        for ((_, q), pb) in poses.iter().zip(&pose_bodies) {
            let path = kin::muscle_path(&base0, m, pb, q)?;
            for p in &path {
                bodies.insert(p.body.clone());
            }
            paths.push(path.iter().map(|p| p.ground).collect::<Vec<_>>());
        }
        let lv: Vec<usize> = bodies.iter().filter_map(|b| body_level_index(b)).collect();
        mgeo.push(wrap::MuscleGeom {
            name: m.name.clone(),
            level_lo: lv.iter().copied().min().unwrap_or(0),
            level_hi: lv.iter().copied().max().unwrap_or(0),
            bodies: bodies.into_iter().collect(),
            paths,
        });
    }
    // Spheres must not overlap one another in any test pose: OpenSim wraps
    // sequentially, and a tangent point inside the next sphere gives wrong
    // (even shorter than straight) paths. Overlapping pairs are shrunk in
    // proportion to 98 % of their closest centre distance.
    let centres_of = |s: &wrap::SphereRow| -> Vec<Point3<f64>> {
        let c = Point3::new(s.centre[0], s.centre[1], s.centre[2]);
        pose_bodies
            .iter()
            .map(|pb| pb.get(&s.body).map(|x| x * c).unwrap_or(c))
            .collect()
    };
    let all_centres: Vec<Vec<Point3<f64>>> = spheres.iter().map(centres_of).collect();
    for i in 0..spheres.len() {
        for j in (i + 1)..spheres.len() {
            let d = all_centres[i]
                .iter()
                .zip(&all_centres[j])
                .map(|(a, b)| (a - b).norm())
                .fold(f64::MAX, f64::min);
            let sum = spheres[i].radius + spheres[j].radius;
            if sum > 0.98 * d {
                let f = 0.98 * d / sum;
                spheres[i].radius *= f;
                spheres[j].radius *= f;
            }
        }
    }
    for s in spheres.iter_mut() {
        s.radius_no_overlap = s.radius;
    }
    let mut wraps_for: BTreeMap<usize, Vec<(f64, String)>> = BTreeMap::new();
    for s in spheres.iter_mut() {
        let level_index = body_level_index(&s.body).unwrap_or(0);
        let c = Point3::new(s.centre[0], s.centre[1], s.centre[2]);
        let centres = pose_bodies
            .iter()
            .map(|pb| pb.get(&s.body).map(|x| x * c).unwrap_or(c))
            .collect();
        let g = wrap::SphereGeom {
            level_index,
            body: s.body.clone(),
            radius_fit: s.radius,
            centres,
        };
        let a = wrap::assign(&g, &mgeo);
        s.radius = a.radius;
        s.muscles = a.muscles.iter().map(|&k| mgeo[k].name.clone()).collect();
        s.muscles_refused = a.refused.iter().map(|&k| mgeo[k].name.clone()).collect();
        for &k in &a.muscles {
            // Clearance of the straight path to this sphere over the test poses.
            let clear = mgeo[k]
                .paths
                .iter()
                .zip(&g.centres)
                .flat_map(|(p, c)| {
                    p.windows(2)
                        .map(move |w| kin::point_segment_distance(c, &w[0], &w[1]))
                })
                .fold(f64::MAX, f64::min)
                - a.radius;
            wraps_for
                .entry(k)
                .or_default()
                .push((clear, s.name.clone()));
        }
        // WrapSphere on the body.
        let el = doc
            .component_mut("BodySet", &s.body)
            .ok_or_else(|| Error::invalid(&gfile, format!("body '{}' vanished", s.body)))?;
        let ws = el.child_or_insert("WrapObjectSet");
        if ws.attr("name").is_none() {
            ws.set_attr("name", "wrapobjectset");
        }
        ws.child_or_insert("objects")
            .children
            .push(Node::Element(builders::wrap_sphere(
                &s.name,
                &Vector3::new(s.centre[0], s.centre[1], s.centre[2]),
                &Vector3::zeros(),
                s.radius,
                "all",
            )));
    }
    let mut path_wraps_added = 0;
    // One PathWrap per muscle: the sphere its straight path penetrates
    // deepest (OpenSim 4.6 gives paths shorter than the straight line when
    // a path wraps over several spheres in sequence).
    for list in wraps_for.values_mut() {
        list.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        list.truncate(1);
    }
    for s in spheres.iter_mut() {
        s.muscles.retain(|m| {
            mgeo.iter()
                .position(|g| g.name == *m)
                .and_then(|k| wraps_for.get(&k))
                .map(|l| l.iter().any(|(_, n)| *n == s.name))
                .unwrap_or(false)
        });
    }
    for (k, list) in wraps_for.iter().map(|(k, l)| (*k, l.clone())) {
        let name = &mgeo[k].name;
        let el = doc
            .component_mut("ForceSet", name)
            .ok_or_else(|| Error::invalid(&gfile, format!("muscle '{name}' vanished")))?;
        let gp = el
            .elements_mut()
            .find(|e| e.name == "GeometryPath")
            .ok_or_else(|| {
                Error::invalid(&gfile, format!("muscle '{name}' has no GeometryPath"))
            })?;
        let objs = gp.child_or_insert("PathWrapSet").child_or_insert("objects");
        for (_, sname) in list {
            objs.children.push(Node::Element(builders::path_wrap(
                &format!("pathwrap_{sname}"),
                &sname,
                "hybrid",
                [-1, -1],
            )));
            path_wraps_added += 1;
        }
    }

    // ---- 8. palpation -> markers
    let mut ordering = Vec::new();
    let mut marker_els = Vec::new();
    let mut markers = Vec::new();
    for (v, p) in vs.iter().zip(&palps) {
        ordering.extend(p.findings.iter().map(|f| f.to_string()));
        for (code, l) in &p.landmarks {
            markers.push((v.level, *code, v.body.clone(), l.point, &v.query));
        }
    }
    let sacrum_query = MeshQuery::new(&sacrum_mesh)
        .map_err(|e| Error::invalid(format!("sacrum mesh {sacrum_file}"), e.to_string()))?;
    {
        let i = ivd
            .iter()
            .find(|(u, _, _)| *u == Level::L5)
            .map(|(_, _, i)| *i)
            .ok_or_else(|| Error::invalid(&gfile, "no L5-S1 joint"))?;
        let pose = kin0.body_poses(&defaults)?;
        let l5 = vs.iter().zip(&palps).find(|(v, _)| v.level == Level::L5);
        let p = palpate_sacrum_of(&sacrum_mesh, &frames[i].parent_in_body, l5, &pose)
            .map_err(|e| Error::invalid(format!("sacrum mesh {sacrum_file}"), e.to_string()))?;
        ordering.extend(p.findings.iter().map(|f| f.to_string()));
        for code in Code::SACRUM_REQUIRED {
            if let Some(l) = p.landmarks.get(&code) {
                markers.push((Level::S1, code, "sacrum".into(), l.point, &sacrum_query));
            }
        }
    }
    let mut marker_rows = Vec::new();
    for (level, code, body, pt, q) in &markers {
        let name = format!("{level}_{code}");
        marker_rows.push(MarkerRow {
            name: name.clone(),
            body: body.clone(),
            location: [pt.x, pt.y, pt.z],
            surface_distance_mm: q.distance(pt) * 1e3,
        });
        marker_els.push(builders::marker(
            &name,
            &format!("/bodyset/{body}"),
            &pt.coords,
            true,
        ));
    }
    {
        let objs = doc.set_objects_mut("MarkerSet");
        objs.children
            .extend(marker_els.into_iter().map(Node::Element));
    }

    // ---- 9. meshes to write
    for b in &kept {
        if b == "sacrum" {
            continue;
        }
        if let Some(base) = model.body(b) {
            for g in &base.geometry {
                if let Geometry::Mesh { mesh_file, .. } = g {
                    if mesh_file.is_empty() || out_meshes.contains_key(mesh_file) {
                        continue;
                    }
                    if let Some(m) = source.load(mesh_file)? {
                        out_meshes.insert(mesh_file.clone(), m);
                    }
                }
            }
        }
    }
    if opts.sacrum.is_some() {
        out_meshes.insert(sacrum_file.clone(), sacrum_mesh.clone());
    } else if let Some(base) = model.body("sacrum") {
        for g in &base.geometry {
            if let Geometry::Mesh { mesh_file, .. } = g {
                if let Some(m) = source.load(mesh_file)? {
                    out_meshes.insert(mesh_file.clone(), m);
                }
            }
        }
    }

    // ---- 10. self-check and views
    let base = doc.model()?;
    let vert_meshes: Vec<(String, &MeshQuery)> =
        vs.iter().map(|v| (v.body.clone(), &v.query)).collect();
    let self_check = check::run(&base, &vert_meshes, &spheres)?;
    let kinb = Kinematics::new(&base)?;
    let pb = kinb.body_poses(&kinb.default_values())?;
    let view_meshes: Vec<(String, &TriMesh)> = vs
        .iter()
        .map(|v| (v.body.clone(), &v.mesh))
        .chain(std::iter::once(("sacrum".to_string(), &sacrum_mesh)))
        .collect();
    let views = views::render(&pb, &view_meshes, &marker_rows, &spheres);
    let muscles_with_wraps = wraps_for.len();
    let report = BaseReport {
        generic_model: gfile,
        kept_levels: levels.iter().map(|l| l.to_string()).collect(),
        fixed_body: opts.fixed,
        prune: pr,
        joints: joint_rows,
        ivd_parameters: opts.ivd.clone(),
        geometry_sanity: sanity,
        sacrum: sacrum_report,
        spheres,
        test_poses: poses.iter().map(|(l, _)| l.clone()).collect(),
        path_wraps_added,
        muscles_with_wraps,
        markers: marker_rows,
        palpation_ordering_failures: ordering,
        guards_checked: guards::Guard::ALL.to_vec(),
        guard_failures,
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

/// The palpation engine on every vertebra mesh (each in its body frame).
fn palpate_vertebrae(vs: &[Vert]) -> Result<Vec<VertebraPalpation>> {
    vs.iter()
        .map(|v| {
            palpation::palpate_vertebra(&v.mesh, v.level, &FrameHint::body_frame()).map_err(|e| {
                Error::invalid(
                    format!("vertebra {} ({}, mesh {})", v.level, v.body, v.mesh_file),
                    e.to_string(),
                )
            })
        })
        .collect()
}

/// The vertebral-body wrapping sphere: centred on the vertebral centre,
/// with the radius of its least-squares sphere (shrunk later if needed).
fn body_sphere(v: &Vert, p: &VertebraPalpation, body_mesh_given: bool) -> wrap::SphereRow {
    let mut source = format!(
        "vertebral centre by the palpation engine (thesis sphere rule) on {}",
        v.mesh_file
    );
    if body_mesh_given {
        source.push_str("; the body-only mesh given is not used for the centre");
    }
    wrap::SphereRow {
        level: v.level.to_string(),
        body: v.body.clone(),
        name: format!("{}_body_sphere", v.level),
        centre: [p.centre.x, p.centre.y, p.centre.z],
        radius_fit: p.centre_radius,
        radius_no_overlap: p.centre_radius,
        radius: p.centre_radius,
        rms_mm: p.centre_fit.rms * 1e3,
        nodes: p.centre_fit.nodes,
        centre_inside_mesh: v.query.contains(&p.centre),
        source,
        body_mesh_registration_rms_mm: None,
        muscles: vec![],
        muscles_refused: vec![],
    }
}

/// The S1 plateau on the sacrum mesh (sacrum body frame): the hint is the
/// L5-S1 joint's parent frame; L5's palpation, carried into the sacrum's
/// frame at the default pose, selects the plateau and gives the coarse
/// layout.
fn palpate_sacrum_of(
    mesh: &TriMesh,
    joint: &Isometry3<f64>,
    l5: Option<(&Vert, &VertebraPalpation)>,
    pose: &BTreeMap<String, Isometry3<f64>>,
) -> Result<VertebraPalpation> {
    let hint = FrameHint {
        anterior: joint.rotation * Vector3::x(),
        cranial: joint.rotation * Vector3::y(),
    };
    let facing = l5.and_then(|(v, p)| {
        let to_sacrum = pose.get("sacrum")?.inverse() * pose.get(&v.body)?;
        Some(p.transformed(&to_sacrum))
    });
    palpation::palpate_sacrum(mesh, &hint, facing.as_ref())
}

/// Refuse a base whose landmarks break the protocol (unless allowed).
fn refuse_implausible(failures: &[guards::GuardFailure], allow: bool) -> Result<()> {
    if failures.is_empty() || allow {
        return Ok(());
    }
    let list: Vec<String> = failures.iter().map(|f| f.to_string()).collect();
    Err(Error::invalid(
        "base",
        format!(
            "refusing to write a base model whose landmarks break the palpation protocol ({} guard failures; --allow-implausible writes it with these as warnings):\n  {}",
            failures.len(),
            list.join("\n  ")
        ),
    ))
}
