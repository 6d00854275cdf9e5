//! Patient-specific scoliotic model generation (`osim-spine generate`):
//! a base model (from `osim-spine base` or the embedded default) and a
//! patient's palpated landmark set give a model whose default pose
//! reproduces the patient's spine with every bushing undeflected.
//!
//! Pipeline ([`generate`]; everything in memory, nothing written), one
//! file per step: `register.rs`, `fits.rs` (with [`pose`] and [`residuals`]),
//! [`scale`], `joints.rs` (with [`chain`] and [`fill`]), [`wraps`], `check.rs`
//! (with [`clear`]); `report.rs` holds what the stage returns.
//! 1. **Common reference** (thesis): the landmark set is registered to the
//!    model through the sacrum: a rigid least-squares fit of the S1
//!    landmarks (`S1_SEC`, `S1_SA`, `S1_SP`, `S1_SR`, `S1_SL`, and the
//!    pedicle tops when both sides have them) onto the base model's sacral
//!    markers at the default pose. This aligns the S1 endplate centre and
//!    the endplate plane (sacral slope) of patient and model. The
//!    transform is reported ([`Registration`]) so that [`crate::evaluate`]
//!    can bring truth data into the model's frame.
//! 2. **Per-vertebra scaling and pose** ([`pose`]): anisotropic scale
//!    factors from the 8 scaling landmarks; pose by the thesis rule (ISB
//!    frames from the 6 joint landmarks, realigned on the scaling
//!    landmarks) or by a least-squares fit of all 14 with one-outlier
//!    rejection ([`Method`]). A code whose residuals point the same way at
//!    several levels (a set palpated by another protocol than the base's
//!    markers) is reported and, for lsq, compensated: its marker is moved
//!    by that offset and every vertebra refitted ([`residuals`]).
//! 3. **Scaling** of each landmarked vertebra ([`scale`]): meshes, mass and
//!    inertia, markers, muscle points, wrap objects, joint frames.
//! 4. **Joint frames**: for each intervertebral joint between two placed
//!    bodies (upper vertebra U, lower vertebra or sacrum L) the joint frame
//!    in ground has its origin midway between U's inferior endplate centre
//!    (`IEC` marker) and L's superior endplate centre (`SEC`), and the mean
//!    orientation (quaternion midpoint) of the two bodies' ISB frames (for
//!    the sacrum: Y normal to the S1 endplate, Z right). The joint's parent
//!    offset frame (in L) and child offset frame (in U) are both written
//!    from it and its six coordinates default to 0, so the joint transform
//!    is the identity and every bushing is undeflected at the default
//!    pose. Levels without landmarks keep the base model's shape and
//!    alignment relative to the nearest landmarked vertebra below.
//! 5. **Wrap spheres** refitted ([`wraps`]).
//! 6. **Self-check** with the base pipeline's checks
//!    ([`crate::base::check`]: bushing deflection, muscle segments
//!    through vertebrae, reachability, equilibrium with the solver), and
//!    frontal/sagittal SVG views of the vertebral centres and landmarks.
//!
//! Body origins keep the base model's convention (origin at the centre of
//! the disc below, X anterior, Y cranial, Z right; see
//! [`crate::base`]); only the poses change.

pub mod balance;
pub mod chain;
mod check;
pub mod clear;
pub mod example;
pub mod fill;
mod fits;
pub mod geometry;
mod joints;
pub mod pose;
mod register;
mod report;
pub mod residuals;
pub mod scale;
pub mod smooth;
pub mod views;
pub mod wraps;

use crate::base::centres::{model_centres, CentreDef};
use crate::base::kin::Kinematics;
use crate::error::{Error, Result};
use crate::landmarks::{Code, LandmarkSet, Level};
use crate::mesh::source::MeshSource;
use crate::osim::model::Model;
use crate::osim::Document;
pub use balance::{AboveFov, AboveFovReport};
use check::{clear_muscle_paths, self_check, sphere_radii, vertebra_queries};
use fits::{
    base_body_centres, borrowed_scales, fit_with_protocol_check, landmark_coverage, set_levels,
    FitInput, LevelFits,
};
pub use fits::{MAX_COMPENSATED_CODES, MIN_SACRUM_LANDMARKS, MIN_VERTEBRA_LANDMARKS};
pub use geometry::{GeometryChoice, PatientGeometry};
pub use joints::JointCentres;
use joints::{
    base_joint_centres, carried_joints, disc_frame, rewrite_joint_frames, write_joint,
    JointGeometry,
};
use nalgebra::{Isometry3, Point3, Vector3};
pub use pose::Method;
use pose::Points;
pub use register::{base_markers, base_sacrum};
use register::{isb_rotation, landmarks_per_level, register_sacrum, sacral_rotation};
use report::vertebra_rows;
pub use report::{
    GenerateOptions, GenerateReport, Generated, JointScaling, ReducedFit, Registration,
    SmoothingLevel, SmoothingReport, VertebraRow,
};
pub use smooth::Smooth;
use std::collections::BTreeMap;

/// Generate the patient model from `base` and `set` (see the module docs).
/// `meshes` serve the self-check's through-bone test (skipped without).
pub fn generate(
    base: &Document,
    set: &LandmarkSet,
    set_name: &str,
    opts: &GenerateOptions,
    meshes: Option<&dyn MeshSource>,
) -> Result<Generated> {
    generate_with_geometry(base, set, set_name, opts, meshes, None)
}

/// [`generate`], the vertebrae wearing the patient's own meshes where
/// `patient` has them ([`geometry`]); `set` must be the landmarks palpated
/// on those meshes.
pub fn generate_with_geometry(
    base: &Document,
    set: &LandmarkSet,
    set_name: &str,
    opts: &GenerateOptions,
    meshes: Option<&dyn MeshSource>,
    patient_geometry: Option<&PatientGeometry>,
) -> Result<Generated> {
    // ---- 0. the base model at its default pose; what the set measures
    let b = BaseState::read(base)?;
    let mut m = Measured::read(set, set_name, &b)?;

    // ---- 1. registration through the sacrum
    let x_sacrum = b.sacrum_pose()?;
    let registration = register_sacrum(&mut m.patient, &b.markers, &x_sacrum, set_name)?;

    // ---- 2. per-vertebra fits, protocol mismatches compensated; 2b. gaps filled
    let input = FitInput {
        vert_levels: &m.vert_levels,
        markers: &b.markers,
        joint_centres: base_joint_centres(&b.model, &b.poses)?,
        body_centres: base_body_centres(&b.model)?,
        borrowed: std::mem::take(&mut m.borrowed),
        opts,
    };
    let fitted = fit_and_fill(&input, &m.patient, &b, &x_sacrum)?;

    // ---- 3-4b. scaling, joint frames, levels above the field of view
    let mut doc = base.clone();
    let mut placed = place_bodies(&mut doc, &b, &m, &fitted.fits, &x_sacrum, opts)?;

    // ---- 4c. the patient's own vertebrae ([`geometry`])
    let mut radii = sphere_radii(&b.model);
    let placement = PatientPlacement {
        fits: &fitted.fits,
        input: &input,
        smoothing: &fitted.smoothing,
        registration: registration.isometry(),
        patient: &m.patient,
    };
    let applied = match patient_geometry {
        Some(pg) => Some(wear_patient_geometry(&mut doc, pg, &placement, meshes)?),
        None => None,
    };
    if let Some(a) = &applied {
        radii.extend(a.sphere_radii.iter().map(|(n, r)| (n.clone(), *r)));
        for body in &a.bodies {
            placed.scales.remove(body);
        }
    }
    // the self-check's bones: the patient's own where it has them
    let own_meshes = applied
        .as_ref()
        .map(|a| a.meshes.clone())
        .unwrap_or_default();
    let overlay = geometry::Overlay {
        own: &own_meshes,
        base: meshes,
    };
    let meshes: Option<&dyn MeshSource> = match (&applied, meshes) {
        (Some(_), _) => Some(&overlay),
        (None, m) => m,
    };

    // ---- 5. wrap spheres; 5b. muscle paths clear of the vertebrae ([`clear`])
    let spheres = wraps::refit_spheres(&mut doc, &placed.scales, &radii, &placed.prefixes)?;
    let vertebrae = vertebra_queries(&doc, meshes)?;
    let path_edits = clear_muscle_paths(&mut doc, vertebrae.as_deref())?;

    // ---- 6. report, views, self-check
    let steps = Steps {
        measured: m,
        registration,
        fitted,
        placed,
        spheres,
        vertebrae,
        path_edits,
        geometry: applied.map(|a| a.report),
        own_meshes,
    };
    finish(doc, &b, set, set_name, opts, steps)
}

/// The base model at its default pose: what the steps read from it.
struct BaseState {
    /// The base model's file (or label).
    file: String,
    model: Model,
    /// Body poses in ground at the default pose.
    poses: BTreeMap<String, Isometry3<f64>>,
    markers: BTreeMap<Level, (String, Points)>,
}

impl BaseState {
    fn read(base: &Document) -> Result<BaseState> {
        let model = base.model()?;
        let kin = Kinematics::new(&model)?;
        let poses = kin.body_poses(&kin.default_values())?;
        let markers = base_markers(&model)?;
        Ok(BaseState {
            file: base.path().display().to_string(),
            model,
            poses,
            markers,
        })
    }

    /// The sacrum's pose in ground (the registration's target).
    fn sacrum_pose(&self) -> Result<Isometry3<f64>> {
        self.poses
            .get("sacrum")
            .copied()
            .ok_or_else(|| Error::invalid(&self.file, "the base model has no body 'sacrum'"))
    }
}

/// What the landmark set measures: its vertebrae, landmarks by level, the
/// vertebrae fitted on fewer landmarks than the protocol's and the scale
/// factors they borrow from their neighbours.
struct Measured {
    vert_levels: Vec<Level>,
    patient: BTreeMap<Level, Points>,
    reduced_fits: Vec<ReducedFit>,
    borrowed: BTreeMap<Level, pose::Borrowed>,
}

impl Measured {
    fn read(set: &LandmarkSet, set_name: &str, b: &BaseState) -> Result<Measured> {
        let levels = set_levels(set, set_name)?;
        let vert_levels: Vec<Level> = levels.iter().copied().filter(|l| !l.is_sacrum()).collect();
        let patient = landmarks_per_level(set);
        let mut reduced_fits = landmark_coverage(&levels, &patient, &b.markers, set_name, &b.file)?;
        let borrowed = borrowed_scales(&vert_levels, &patient, &b.markers, &mut reduced_fits);
        Ok(Measured {
            vert_levels,
            patient,
            reduced_fits,
            borrowed,
        })
    }
}

/// Steps 2 and 2b: the vertebrae's fits and what they found.
struct Fitted {
    fits: BTreeMap<Level, pose::VertebraFit>,
    noise: Option<f64>,
    smoothing: SmoothingReport,
    landmark_residuals: Vec<residuals::LandmarkResidual>,
    protocol_mismatches: Vec<residuals::ProtocolMismatch>,
    filled: Vec<fill::FilledLevel>,
}

/// Steps 2 and 2b: fit every vertebra (lsq: palpation noise estimated over
/// the whole set for the outlier test; a code off the same way at several
/// levels is a protocol mismatch, compensated: [`fit_with_protocol_check`]),
/// then the levels missing between measured ones from their neighbours.
fn fit_and_fill(
    input: &FitInput,
    patient: &BTreeMap<Level, Points>,
    b: &BaseState,
    x_sacrum: &Isometry3<f64>,
) -> Result<Fitted> {
    let (
        LevelFits {
            mut fits,
            noise,
            smoothing,
        },
        landmark_residuals,
        protocol_mismatches,
    ) = fit_with_protocol_check(input, patient)?;
    let filled = fill::fill_gaps(&mut fits, x_sacrum, &b.poses, &input.joint_centres);
    Ok(Fitted {
        fits,
        noise,
        smoothing,
        landmark_residuals,
        protocol_mismatches,
        filled,
    })
}

/// Steps 3 to 4b: what placing the bodies did.
struct Placed {
    /// Scale factors by body name.
    scales: BTreeMap<String, Vector3<f64>>,
    scaling: BTreeMap<String, scale::ScaleCount>,
    /// The joints whose frames were rewritten.
    rewritten: Vec<String>,
    /// The prefixes (`L4_L5`) of every IVD joint.
    prefixes: Vec<String>,
    above_fov: Option<AboveFovReport>,
}

/// Steps 3 to 4b: scale the fitted bodies, rewrite the joint frames, place
/// the levels above the field of view ([`balance`]).
fn place_bodies(
    doc: &mut Document,
    b: &BaseState,
    m: &Measured,
    fits: &BTreeMap<Level, pose::VertebraFit>,
    x_sacrum: &Isometry3<f64>,
    opts: &GenerateOptions,
) -> Result<Placed> {
    let (scales, scaling) = scale_bodies(doc, fits)?;
    let (rewritten, prefixes) =
        rewrite_joint_frames(doc, &b.model, fits, &b.markers, x_sacrum, &b.file)?;
    let above_fov = match m.vert_levels.first() {
        Some(top) => balance::place_above_fov(
            doc,
            &b.model,
            *top,
            m.patient[&Level::S1][&Code::SEC],
            b.markers.get(&Level::T1).map(|(_, mk)| mk),
            opts.above_fov,
        )?,
        None => None,
    };
    Ok(Placed {
        scales,
        scaling,
        rewritten,
        prefixes,
        above_fov,
    })
}

/// What steps 0 to 5 hand to step 6.
struct Steps {
    measured: Measured,
    registration: Registration,
    fitted: Fitted,
    placed: Placed,
    spheres: Vec<wraps::SphereOut>,
    /// The vertebrae's bones, for the self-check's through-bone test.
    vertebrae: Option<Vec<(String, crate::mesh::MeshQuery)>>,
    path_edits: Vec<clear::PathEdit>,
    geometry: Option<geometry::GeometryReport>,
    /// The patient's meshes by file name.
    own_meshes: BTreeMap<String, crate::mesh::TriMesh>,
}

/// Step 6: the generated model `doc` with its report, self-check and views.
fn finish(
    doc: Document,
    b: &BaseState,
    set: &LandmarkSet,
    set_name: &str,
    opts: &GenerateOptions,
    steps: Steps,
) -> Result<Generated> {
    let Steps {
        measured: m,
        fitted,
        placed,
        ..
    } = steps;
    let out_model = doc.model()?;
    let kin = Kinematics::new(&out_model)?;
    let poses = kin.body_poses(&kin.default_values())?;
    let centres = model_centres(&out_model, &poses, CentreDef::default())?;
    let (rows, outliers, landmark_rms) = vertebra_rows(&fitted.fits, &poses, &fitted.filled);
    let levels_from_base: Vec<Level> = b
        .markers
        .keys()
        .filter(|l| !l.is_sacrum() && !fitted.fits.contains_key(l))
        .copied()
        .collect();
    let self_check = if opts.self_check {
        Some(self_check(
            &out_model,
            steps.vertebrae.as_deref(),
            &steps.spheres,
        )?)
    } else {
        None
    };
    // the model's shape and the frontal/sagittal views
    let (shape, views) = shape_and_views(
        &out_model,
        &poses,
        &centres,
        &m.patient,
        &steps.own_meshes,
        opts.views,
    )?;
    let report = GenerateReport {
        // File names only: the report is the same wherever the inputs lie
        // and whatever the working directory (determinism).
        base_model: file_name_of(&b.file),
        landmarks: file_name_of(set_name),
        detection: set.detection.as_ref().map(|d| d.summary()),
        method: opts.method,
        levels_from_landmarks: m.vert_levels,
        levels_from_base,
        registration: steps.registration,
        vertebrae: rows,
        noise_sd_mm: fitted.noise.map(|n| n * 1e3),
        outliers,
        protocol_mismatches: fitted.protocol_mismatches,
        smoothing: fitted.smoothing,
        landmark_rms_mm: landmark_rms * 1e3,
        joints_rewritten: placed.rewritten,
        scaling: placed.scaling,
        spheres: steps.spheres,
        path_edits: steps.path_edits,
        centres: centres.iter().map(|(l, p)| (*l, [p.x, p.y, p.z])).collect(),
        self_check,
        above_fov: placed.above_fov,
        reduced_fits: m.reduced_fits,
        filled_levels: fitted.filled.iter().map(|f| f.level).collect(),
        filled: fitted.filled,
        shape,
        landmark_residuals: fitted.landmark_residuals,
        geometry: steps.geometry,
    };
    Ok(Generated {
        doc,
        report,
        views,
        meshes: steps.own_meshes,
    })
}

/// Step 6: the shape of the model (Cobb, lordosis, kyphosis from its
/// markers and centres) and, when asked, the frontal and sagittal views
/// (centres, registered landmarks, markers, the patient's bones).
fn shape_and_views(
    model: &Model,
    poses: &BTreeMap<String, Isometry3<f64>>,
    centres: &BTreeMap<Level, Point3<f64>>,
    patient: &BTreeMap<Level, Points>,
    own_meshes: &BTreeMap<String, crate::mesh::TriMesh>,
    with_views: bool,
) -> Result<(crate::landmarks::metrics::Shape, Vec<(String, String)>)> {
    let model_set = crate::base::centres::model_landmarks(model, poses)?;
    let shape = crate::landmarks::metrics::shape(&model_set, centres);
    if !with_views {
        return Ok((shape, Vec::new()));
    }
    let registered: Vec<(String, Point3<f64>)> = patient
        .iter()
        .flat_map(|(l, pts)| pts.iter().map(move |(c, p)| (format!("{l}_{c}"), *p)))
        .collect();
    let model_markers: Vec<Point3<f64>> = model_set.points.values().copied().collect();
    let bones = views::posed_triangles(own_meshes, model, poses);
    let views = views::generate_views(centres, &registered, &model_markers, &bones);
    Ok((shape, views))
}

/// What step 4c needs from the generic steps.
struct PatientPlacement<'a> {
    fits: &'a BTreeMap<Level, pose::VertebraFit>,
    input: &'a FitInput<'a>,
    smoothing: &'a SmoothingReport,
    registration: Isometry3<f64>,
    patient: &'a BTreeMap<Level, Points>,
}

/// Step 4c: the patient's own vertebrae ([`geometry::apply`]), with the
/// base's joint centres carried by the fits as the chain places them.
fn wear_patient_geometry(
    doc: &mut Document,
    pg: &PatientGeometry,
    p: &PatientPlacement,
    meshes: Option<&dyn MeshSource>,
) -> Result<geometry::Applied> {
    let placed: Vec<Level> = p.fits.keys().copied().chain([Level::S1]).collect();
    let joint_geometry = JointGeometry {
        joint_centres: &p.input.joint_centres,
        centres: &p.input.body_centres,
    };
    let scaling = p.smoothing.joint_scaling.unwrap_or(JointScaling::WithBody);
    let at = geometry::Placement {
        registration: p.registration,
        landmarks: p.patient,
        placed,
        joints: carried_joints(p.fits, &joint_geometry, scaling),
        base_meshes: meshes,
    };
    geometry::apply(doc, pg, &at)
}

/// Step 3: scale each fitted vertebra's body (meshes, markers, frames).
#[allow(clippy::type_complexity)]
fn scale_bodies(
    doc: &mut Document,
    fits: &BTreeMap<Level, pose::VertebraFit>,
) -> Result<(
    BTreeMap<String, Vector3<f64>>,
    BTreeMap<String, scale::ScaleCount>,
)> {
    let mut scales: BTreeMap<String, Vector3<f64>> = BTreeMap::new();
    let mut scaling = BTreeMap::new();
    for (l, f) in fits {
        let body = l.body_name();
        let c = scale::scale_body(doc, &body, &f.scale)?;
        scaling.insert(l.to_string(), c);
        scales.insert(body, f.scale);
    }
    Ok((scales, scaling))
}

/// The file name of `path` (the whole string when it has none).
fn file_name_of(path: &str) -> String {
    // the embedded base is named by its label, not a path
    if path == crate::embedded::EMBEDDED_BASE_LABEL {
        return path.to_string();
    }
    std::path::Path::new(path)
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| path.to_string())
}
