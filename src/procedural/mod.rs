//! The procedural default spine: a generic thoracolumbar model (T1-L5,
//! sacrum, pelvis) built from published anatomy, in the conventions of the
//! real generic model (`cyclistFullBodyMuscle.osim`), ready for the `base`
//! pipeline.
//!
//! | submodule | what lives there |
//! |---|---|
//! | [`tables`] | the embedded templates (`templates/*.toml`) with citations per value |
//! | [`shapes`] | closed-surface primitives (ring tubes, elliptic sweeps) |
//! | [`vertebra`] | one parametric vertebra (body, pedicles, lamina, processes, facets) and its landmarks |
//! | [`pelvis`] | sacrum and pelvis shapes and landmarks |
//! | [`skeleton`] | stature scaling, sagittal alignment, joint frames, default-pose transforms |
//! | [`segments`] | masses, centres of mass, inertias (de Leva 1996 trunk segments) |
//! | [`muscles`] | the rule-generated reduced muscle set |
//!
//! Conventions (as the cyclist model): bodies `thoracic1..12`, `lumbar1..5`,
//! `sacrum`, `pelvis`; `ground_pelvis` CustomJoint (pelvis_tilt/list/
//! rotation/tx/ty/tz); `sacral` WeldJoint pelvis -> sacrum; IVD joints
//! `<UP>_<LOW>_IVDjnt` (parent = lower body) with coordinates `<UP>_<LOW>_FE`
//! (Z), `_LB` (X), `_AR` (Y). Vertebra body frame: origin at the centre of
//! the disc below, X anterior, Y cranial, Z right. Meshes `proc_<LEVEL>.vtp`,
//! `proc_sacrum.vtp`, `proc_pelvis.vtp`.

pub mod muscles;
pub mod pelvis;
pub mod segments;
pub mod shapes;
pub mod skeleton;
pub mod tables;
pub mod vertebra;

use crate::error::{Error, Result};
use crate::landmarks::Level;
use crate::mesh::TriMesh;
use crate::osim::builders;
use crate::osim::xml::{Element, Node};
use crate::osim::Document;
use crate::util::fmt_f64;
use nalgebra::Vector3;
use std::collections::BTreeMap;
use std::fmt;
use std::path::Path;
use std::str::FromStr;

pub use muscles::MuscleSpec;
pub use segments::MassProps;
pub use skeleton::{JointSpec, Skeleton};
pub use tables::Templates;

/// Sex of the generated model (selects default stature, pelvis width and
/// trunk mass fractions).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
pub enum Sex {
    /// Female tables: default stature, pelvis width, trunk mass fractions.
    Female,
    /// Male tables (the default).
    #[default]
    Male,
}

impl FromStr for Sex {
    type Err = Error;
    fn from_str(s: &str) -> Result<Sex> {
        match s.trim().to_ascii_lowercase().as_str() {
            "female" | "f" => Ok(Sex::Female),
            "male" | "m" => Ok(Sex::Male),
            other => Err(Error::invalid(
                "--sex",
                format!("'{other}' is not a sex: expected 'female' or 'male'"),
            )),
        }
    }
}

impl fmt::Display for Sex {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Sex::Female => "female",
            Sex::Male => "male",
        })
    }
}

/// Options of the procedural generator.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ProceduralOptions {
    /// Stature (m); `None` = the default of the sex.
    pub stature: Option<f64>,
    /// Selects the default stature, pelvis width and trunk mass fractions.
    pub sex: Sex,
}

/// The generated generic model: the document and its meshes (by
/// `mesh_file`), plus the skeleton, mass properties and muscle figures
/// the generator used (for reports and tests).
#[derive(Debug, Clone)]
pub struct GenericModel {
    /// The OpenSim model document.
    pub doc: Document,
    /// The bodies' meshes by the `mesh_file` the document names.
    pub meshes: BTreeMap<String, TriMesh>,
    /// The skeleton the document was built from.
    pub skeleton: Skeleton,
    /// Mass properties per body.
    pub masses: Vec<MassProps>,
    /// The generated muscle fascicles.
    pub muscles: Vec<MuscleSpec>,
    /// Total body mass the segment fractions were taken of (kg).
    pub body_mass: f64,
}

/// Range of every rotational coordinate (rad), as the cyclist model's.
const ROT_RANGE: [f64; 2] = [-std::f64::consts::FRAC_PI_2, std::f64::consts::FRAC_PI_2];

/// Mesh file name of a body's procedural mesh.
pub fn mesh_file(body: &str) -> String {
    match Level::from_body_name(body) {
        Some(l) if !l.is_sacrum() => format!("proc_{l}.vtp"),
        _ => format!("proc_{body}.vtp"),
    }
}

fn v3(a: [f64; 3]) -> Vector3<f64> {
    Vector3::new(a[0], a[1], a[2])
}

fn with_mesh(mut body: Element, name: &str) -> Element {
    let m = builders::mesh(
        &format!("{name}_geom"),
        &mesh_file(name),
        &Vector3::repeat(1.0),
    );
    if let Some(g) = body.child_mut("attached_geometry") {
        g.children.push(Node::Element(m));
    }
    body
}

fn muscle_element(m: &MuscleSpec, class: &str) -> Element {
    let mut objects = Element::new("objects");
    for (i, p) in m.points.iter().enumerate() {
        objects = objects.with_child(
            Element::new("PathPoint")
                .with_attr("name", format!("{}-P{}", m.name, i + 1))
                .with_prop("socket_parent_frame", format!("/bodyset/{}", p.body))
                .with_prop("location", crate::osim::props::fmt_numbers(&p.location)),
        );
    }
    let path = Element::new("GeometryPath")
        .with_attr("name", "path")
        .with_child(
            Element::new("PathPointSet")
                .with_child(objects)
                .with_child(Element::new("groups")),
        )
        .with_child(
            Element::new("PathWrapSet")
                .with_child(Element::new("objects"))
                .with_child(Element::new("groups")),
        )
        .with_child(Element::new("Appearance").with_prop("color", "0.8 0.1 0.1"));
    let muscle = Element::new(class)
        .with_attr("name", m.name.clone())
        .with_child(path)
        .with_prop("max_isometric_force", fmt_f64(m.max_isometric_force))
        .with_prop("optimal_fiber_length", fmt_f64(m.optimal_fiber_length))
        .with_prop("tendon_slack_length", fmt_f64(m.tendon_slack_length))
        .with_prop("pennation_angle_at_optimal", "0")
        .with_prop("ignore_tendon_compliance", "true");
    if class != "Millard2012EquilibriumMuscle" {
        return muscle;
    }
    // Millard's damped fibre model (the default fiber_damping 0.1) needs an
    // active-force-length curve that reaches 0; OpenSim 4.6 lowers the
    // default 0.1 on every load and logs it, so the file states it.
    muscle.with_child(
        Element::new("ActiveForceLengthCurve")
            .with_attr("name", "ActiveForceLengthCurve")
            .with_prop("minimum_value", "0"),
    )
}

/// Build the generic document from the skeleton, masses and muscles.
fn build_document(
    sk: &Skeleton,
    masses: &[MassProps],
    muscles: &[MuscleSpec],
    t: &Templates,
) -> Result<Document> {
    let mut doc = Document::new_model("osim_spine_procedural");
    doc.set_model_property(
        "credits",
        "osim-spine procedural default spine (templates/: Panjabi 1991/1992, Gilad & Nissan 1986, \
         Vialle 2005, de Leva 1996, Bogduk 1992, Christophy 2012; see the templates for citations)",
    );
    doc.set_model_property("length_units", "meters");
    doc.set_model_property("force_units", "N");
    let mass_of = |name: &str| {
        masses
            .iter()
            .find(|m| m.body == name)
            .ok_or_else(|| Error::invalid("procedural model", format!("no mass for {name}")))
    };
    let mut order = vec!["pelvis".to_string(), "sacrum".to_string()];
    for l in Level::ALL[..17].iter().rev() {
        order.push(l.body_name());
    }
    for name in &order {
        let mp = mass_of(name)?;
        let b = builders::body(name, mp.mass, &v3(mp.mass_center), &mp.inertia);
        doc.insert_component("BodySet", with_mesh(b, name))?;
    }
    // ground -> pelvis
    let z = Vector3::zeros();
    let gp = {
        let pf = builders::offset_frame("ground_offset", "/ground", &z, &z);
        let cf = builders::offset_frame("pelvis_offset", "/bodyset/pelvis", &z, &z);
        let names = [
            "pelvis_tilt",
            "pelvis_list",
            "pelvis_rotation",
            "pelvis_tx",
            "pelvis_ty",
            "pelvis_tz",
        ];
        let axes_v = [
            Vector3::z(),
            Vector3::x(),
            Vector3::y(),
            Vector3::x(),
            Vector3::y(),
            Vector3::z(),
        ];
        let coords = names
            .iter()
            .enumerate()
            .map(|(i, n)| {
                let r = if i < 3 { ROT_RANGE } else { [-5.0, 5.0] };
                builders::coordinate(n, 0.0, r)
            })
            .collect();
        let axes = builders::transform_axes(&axes_v, names.map(Some));
        builders::custom_joint("ground_pelvis", pf, cf, coords, axes)
    };
    doc.insert_component("JointSet", gp)?;
    let so = sk.pelvis.sacrum_origin.coords;
    let weld = builders::weld_joint(
        "sacral",
        builders::offset_frame("pelvis_offset", "/bodyset/pelvis", &so, &z),
        builders::offset_frame("sacrum_offset", "/bodyset/sacrum", &z, &z),
    );
    doc.insert_component("JointSet", weld)?;
    for j in sk.joints.iter().rev() {
        let upper = j.upper.body_name();
        let pf = builders::offset_frame(
            &format!("{}_offset", j.parent_body),
            &format!("/bodyset/{}", j.parent_body),
            &j.translation,
            &Vector3::new(0.0, 0.0, j.angle),
        );
        let cf = builders::offset_frame(
            &format!("{upper}_offset"),
            &format!("/bodyset/{upper}"),
            &z,
            &z,
        );
        let cn = ["FE", "LB", "AR"].map(|s| format!("{}_{s}", j.prefix));
        let coords = cn
            .iter()
            .map(|n| builders::coordinate(n, 0.0, ROT_RANGE))
            .collect();
        let rot = [Vector3::z(), Vector3::x(), Vector3::y()];
        let dirs = [
            rot[0],
            rot[1],
            rot[2],
            Vector3::x(),
            Vector3::y(),
            Vector3::z(),
        ];
        let axes = builders::transform_axes(
            &dirs,
            [Some(&cn[0]), Some(&cn[1]), Some(&cn[2]), None, None, None]
                .map(|c| c.map(String::as_str)),
        );
        doc.insert_component(
            "JointSet",
            builders::custom_joint(&j.name, pf, cf, coords, axes),
        )?;
    }
    for m in muscles {
        doc.insert_component("ForceSet", muscle_element(m, &t.muscles.class))?;
    }
    // the hip joint centres as femoral head markers (the base keeps them)
    for (side, name) in [("r", "FH_R"), ("l", "FH_L")] {
        let h = sk
            .pelvis
            .pelvis_landmarks
            .get(&format!("hip_{side}"))
            .ok_or_else(|| {
                Error::invalid(
                    "procedural model",
                    format!("no hip joint centre on side {side}"),
                )
            })?;
        doc.set_objects_mut("MarkerSet")
            .children
            .push(Node::Element(builders::marker(
                name,
                "/bodyset/pelvis",
                &h.coords,
                true,
            )));
    }
    Ok(doc)
}

/// Generate the generic procedural model.
pub fn generate_generic(opts: &ProceduralOptions) -> Result<GenericModel> {
    let t = Templates::embedded()?;
    let sk = skeleton::build(opts, &t)?;
    let masses = segments::mass_properties(&sk, &t)?;
    let muscles = muscles::generate(&sk, &t)?;
    let doc = build_document(&sk, &masses, &muscles, &t)?;
    let mut meshes = BTreeMap::new();
    for v in &sk.vertebrae {
        meshes.insert(mesh_file(&v.level.body_name()), v.mesh()?);
    }
    meshes.insert(mesh_file("sacrum"), sk.pelvis.sacrum.clone());
    meshes.insert(mesh_file("pelvis"), sk.pelvis.pelvis.clone());
    let body_mass = segments::body_mass(&sk, &t);
    Ok(GenericModel {
        doc,
        meshes,
        skeleton: sk,
        masses,
        muscles,
        body_mass,
    })
}

/// What the generator did, for the JSON report of `base --procedural`.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ProceduralSummary {
    /// The sex whose tables were used.
    pub sex: Sex,
    /// Stature of the model (m).
    pub stature_m: f64,
    /// Total body mass (kg).
    pub body_mass_kg: f64,
    /// Stature / reference stature of the dimension table.
    pub scale: f64,
    /// Per IVD joint: (name, segment angle deg, disc wedge deg, disc height m).
    pub segments: Vec<(String, f64, f64, f64)>,
    /// Mass properties per body.
    pub masses: Vec<MassProps>,
    /// The generated muscle fascicles.
    pub muscles: Vec<MuscleSpec>,
}

impl GenericModel {
    /// Summary for reports (muscle fibre lengths at the default pose etc.).
    pub fn summary(&self) -> ProceduralSummary {
        let sk = &self.skeleton;
        ProceduralSummary {
            sex: sk.sex,
            stature_m: sk.stature,
            body_mass_kg: self.body_mass,
            scale: sk.scale,
            segments: sk
                .joints
                .iter()
                .map(|j| {
                    (
                        j.name.clone(),
                        j.segment_angle.to_degrees(),
                        j.disc_wedge.to_degrees(),
                        j.disc_height,
                    )
                })
                .collect(),
            masses: self.masses.clone(),
            muscles: self.muscles.clone(),
        }
    }

    /// The vertebral-body shells alone, per level (name, mesh in the body
    /// frame), e.g. for the base pipeline's sphere fits.
    pub fn body_meshes(&self) -> BTreeMap<Level, (String, TriMesh)> {
        self.skeleton
            .vertebrae
            .iter()
            .map(|v| {
                (
                    v.level,
                    (format!("procedural {} body", v.level), v.body.clone()),
                )
            })
            .collect()
    }

    /// Serialised outputs: (relative path, bytes): `<stem>.osim` and
    /// `Geometry/<mesh_file>` (ASCII VTP: OpenSim 4.6 reads only ASCII
    /// VTP; coordinates are whole micrometres). Deterministic.
    pub fn files(&self, stem: &str) -> Vec<(String, Vec<u8>)> {
        let mut out = vec![(
            format!("{stem}.osim"),
            self.doc.to_xml_string().into_bytes(),
        )];
        for (name, mesh) in &self.meshes {
            out.push((
                format!("Geometry/{name}"),
                crate::mesh::vtp::to_ascii(mesh).into_bytes(),
            ));
        }
        out
    }

    /// Write the model and its meshes into `dir` (everything is serialised
    /// first, then written all or nothing).
    pub fn write(&self, dir: &Path, stem: &str) -> Result<()> {
        let files: Vec<(std::path::PathBuf, Vec<u8>)> = self
            .files(stem)
            .into_iter()
            .map(|(rel, bytes)| (dir.join(rel), bytes))
            .collect();
        crate::util::write_all_or_nothing(&files)
    }
}
