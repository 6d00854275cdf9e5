//! Patient-specific scoliotic model generation (`osim-spine generate`):
//! a base model (from `osim-spine base` or the embedded default) and a
//! patient's palpated landmark set give a model whose default pose
//! reproduces the patient's spine with every bushing undeflected.
//!
//! Pipeline ([`generate`]; everything in memory, nothing written):
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
pub mod clear;
pub mod example;
pub mod fill;
pub mod geometry;
pub mod pose;
pub mod residuals;
pub mod scale;
pub mod smooth;
pub mod views;
pub mod wraps;

use crate::base::centres::{model_centres, CentreDef};
use crate::base::kin::Kinematics;
use crate::error::{Error, Result};
use crate::landmarks::frames::frame_from_axes;
use crate::landmarks::{Code, LandmarkId, LandmarkSet, Level};
use crate::mesh::source::MeshSource;
use crate::mesh::{umeyama, MeshQuery};
use crate::osim::model::Model;
use crate::osim::props::{set_f64, set_vec3};
use crate::osim::Document;
pub use balance::{AboveFov, AboveFovReport};
pub use geometry::{GeometryChoice, PatientGeometry};
use nalgebra::{Isometry3, Point3, Rotation3, UnitQuaternion, Vector3};
pub use pose::Method;
use pose::Points;
pub use smooth::Smooth;
use std::collections::BTreeMap;

/// Options of [`generate`].
#[derive(Debug, Clone)]
pub struct GenerateOptions {
    pub method: Method,
    /// Run the self-check (needs the meshes for the through-bone test).
    pub self_check: bool,
    /// Draw the SVG views.
    pub views: bool,
    /// Outlier threshold of the lsq method in noise SDs
    /// ([`pose::OUTLIER_SIGMAS`] by default).
    pub outlier_sigmas: f64,
    /// How the per-vertebra fits are combined along the spine (lsq only):
    /// [`Smooth::Chain`] by default ([`chain`]), [`smooth`], or off.
    pub smooth: Smooth,
    /// Levels above the field of view: balanced (default) or kept ([`balance`]).
    pub above_fov: AboveFov,
}

impl Default for GenerateOptions {
    fn default() -> Self {
        GenerateOptions {
            method: Method::Lsq,
            self_check: true,
            views: true,
            outlier_sigmas: pose::OUTLIER_SIGMAS,
            smooth: Smooth::Chain,
            above_fov: AboveFov::Balance,
        }
    }
}

/// The rigid transform from the landmark set's frame (OpenSim axes, m,
/// after the file's units and frame were converted) to the model's ground.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Registration {
    /// Row-major rotation matrix.
    pub rotation: [[f64; 3]; 3],
    /// Translation (m).
    pub translation: [f64; 3],
    /// Sacral landmarks used.
    pub landmarks: Vec<String>,
    /// RMS residual of the sacral fit (mm).
    pub rms_mm: f64,
}

impl Registration {
    fn from_iso(x: &Isometry3<f64>, landmarks: Vec<String>, rms: f64) -> Registration {
        let r = x.rotation.to_rotation_matrix();
        let m = r.matrix();
        Registration {
            rotation: std::array::from_fn(|i| std::array::from_fn(|j| m[(i, j)])),
            translation: [
                x.translation.vector.x,
                x.translation.vector.y,
                x.translation.vector.z,
            ],
            landmarks,
            rms_mm: rms * 1e3,
        }
    }
    /// As an isometry.
    pub fn isometry(&self) -> Isometry3<f64> {
        let m = nalgebra::Matrix3::from_fn(|i, j| self.rotation[i][j]);
        let r = Rotation3::from_matrix(&m);
        Isometry3::from_parts(
            Vector3::from(self.translation).into(),
            UnitQuaternion::from_rotation_matrix(&r),
        )
    }
}

/// One fitted vertebra in the report.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct VertebraRow {
    pub level: String,
    pub body: String,
    /// Scale factors X (depth), Y (height), Z (width).
    pub scale: [f64; 3],
    /// Body origin in ground (m).
    pub origin: [f64; 3],
    /// Body orientation in ground, body-fixed XYZ angles (deg).
    pub orientation_deg: [f64; 3],
    /// RMS and largest landmark-to-marker residual (mm) of the used landmarks.
    pub rms_mm: f64,
    pub max_residual_mm: f64,
    /// Rejected outlier landmark (lsq).
    pub outlier: Option<String>,
    /// Its leave-one-out prediction error (mm).
    pub outlier_error_mm: Option<f64>,
    /// Leave-one-out candidate's prediction error and threshold (mm) (lsq).
    pub loo_max_mm: Option<f64>,
    pub loo_threshold_mm: Option<f64>,
    /// Placed from its neighbours (no landmarks: a gap in the set).
    pub filled: bool,
}

/// Everything [`generate`] did and measured (the JSON report).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct GenerateReport {
    pub base_model: String,
    pub landmarks: String,
    /// Units/frame: declared, detected and used.
    pub detection: Option<String>,
    pub method: Method,
    /// Vertebrae placed from landmarks, cranial to caudal.
    pub levels_from_landmarks: Vec<String>,
    /// Vertebrae of the base model kept with the base shape and alignment.
    pub levels_from_base: Vec<String>,
    pub registration: Registration,
    pub vertebrae: Vec<VertebraRow>,
    /// Per-axis palpation noise SD (mm) estimated over the whole set from
    /// the leave-one-out prediction errors (lsq; [`pose::noise_sd`]).
    pub noise_sd_mm: Option<f64>,
    /// Outliers flagged (`<LEVEL>_<CODE> (error mm)`).
    pub outliers: Vec<String>,
    /// Landmark codes off the same way at several levels: the set follows
    /// another palpation protocol than the base's markers ([`residuals`]).
    pub protocol_mismatches: Vec<residuals::ProtocolMismatch>,
    /// Spinal-continuity smoothing of the orientations ([`smooth`]).
    pub smoothing: SmoothingReport,
    /// RMS of all landmark-to-marker residuals (mm), outliers excluded.
    pub landmark_rms_mm: f64,
    pub joints_rewritten: Vec<String>,
    pub scaling: BTreeMap<String, scale::ScaleCount>,
    pub spheres: Vec<wraps::SphereOut>,
    /// Edits that cleared muscle paths from the vertebrae ([`clear`]).
    pub path_edits: Vec<clear::PathEdit>,
    /// Vertebral centres ([`crate::evaluate::CentreDef::Endplates`]) in
    /// ground at the default pose (m).
    pub centres: BTreeMap<String, [f64; 3]>,
    pub self_check: Option<crate::base::check::SelfCheck>,
    /// Levels above the landmarks' field of view and where T1 ended
    /// (`None` when the landmarks reach T1, or when they measure no
    /// vertebra at all: `levels_from_landmarks` is then empty).
    pub above_fov: Option<AboveFovReport>,
    /// Levels fitted on fewer landmarks than the protocol's (missing ones
    /// named); empty for a complete set.
    pub reduced_fits: Vec<ReducedFit>,
    /// Levels missing between measured ones, placed from their neighbours
    /// ([`fill`]), cranial to caudal; empty for a set without gaps.
    pub filled_levels: Vec<String>,
    /// How each of them was placed.
    pub filled: Vec<fill::FilledLevel>,
    /// The generated model's spine shape from its markers and centres at
    /// the default pose ([`crate::landmarks::metrics::shape`]).
    pub shape: crate::landmarks::metrics::Shape,
    /// Every landmark's residual after its vertebra's fit (as OpenSim's
    /// Scale tool lists marker errors), vertebra frames.
    pub landmark_residuals: Vec<residuals::LandmarkResidual>,
    /// The patient's own vertebrae (`--geometry patient`, [`geometry`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub geometry: Option<geometry::GeometryReport>,
}

/// What the orientation smoothing did ([`smooth`]).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct SmoothingReport {
    pub mode: Smooth,
    /// Whether the posterior orientations replaced the fitted ones.
    pub applied: bool,
    /// Why not, or what was done.
    pub note: String,
    /// REML estimates of the SD of the second differences of the
    /// orientation sequence (deg per level^2), about the X (lateral
    /// bending), Y (axial rotation) and Z (flexion) axes of the relative
    /// rotations.
    pub tau_deg: Option<[f64; 3]>,
    /// Effective number of orientation parameters kept (`tr(H^-1 W)`), and
    /// the number of parameters (3 per vertebra).
    pub effective_dof: Option<f64>,
    pub parameters: usize,
    /// `--smooth chain`: REML estimate of the SD of the joint mismatch
    /// (mm) along the lower body's X, Y, Z axes.
    pub joint_sd_mm: Option<[f64; 3]>,
    /// `--smooth chain`: how the joint centres follow each vertebra's
    /// size, as the landmarks chose (`with_body` or `about_centre`).
    pub joint_scaling: Option<JointScaling>,
    /// Per level, cranial to caudal.
    pub levels: Vec<SmoothingLevel>,
}

/// One vertebra of [`SmoothingReport`].
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct SmoothingLevel {
    pub level: String,
    /// SD of the fitted orientation (deg) about the ground X, Y, Z axes.
    pub fit_sd_deg: [f64; 3],
    /// Posterior SD (deg) about the ground X, Y, Z axes.
    pub posterior_sd_deg: [f64; 3],
    /// Angle between the fitted and the posterior orientation (deg).
    pub correction_deg: f64,
}

/// A generated model, not yet written.
#[derive(Debug, Clone)]
pub struct Generated {
    pub doc: Document,
    pub report: GenerateReport,
    /// (suffix, SVG text): `frontal`, `sagittal`.
    pub views: Vec<(String, String)>,
    /// Meshes of the model that are not the base model's (the patient's,
    /// [`geometry`]), by `mesh_file`, in their bodies' frames (m).
    pub meshes: BTreeMap<String, crate::mesh::TriMesh>,
}

/// Base-model markers `<LEVEL>_<CODE>` in their bodies' frames, and the
/// bodies they are on.
pub fn base_markers(model: &Model) -> Result<BTreeMap<Level, (String, Points)>> {
    let mut out: BTreeMap<Level, (String, Points)> = BTreeMap::new();
    for mk in &model.markers {
        let Some((id, _)) = LandmarkId::parse_name(&mk.name) else {
            continue;
        };
        let (body, x) = model.marker_frame(mk)?;
        if body != id.level.body_name() {
            return Err(Error::invalid(
                model.file.display().to_string(),
                format!(
                    "marker '{}' is on body '{body}', expected '{}'",
                    mk.name,
                    id.level.body_name()
                ),
            ));
        }
        out.entry(id.level)
            .or_insert_with(|| (body.clone(), Points::new()))
            .1
            .insert(id.code, x * Point3::from(mk.location));
    }
    Ok(out)
}

/// The base model's sacrum surface (its body frame, metres, meshes scaled
/// as the model scales them) and its S1 markers: what a patient's sacrum
/// is registered to when the patient comes as a segmentation
/// ([`crate::segmentation::sacrum`]). `None` when the base has no sacrum
/// mesh or no S1 markers.
pub fn base_sacrum(
    base: &Document,
    meshes: &dyn MeshSource,
) -> Result<Option<(crate::mesh::TriMesh, Points)>> {
    let model = base.model()?;
    let markers = base_markers(&model)?;
    let Some((body, s1)) = markers.get(&Level::S1) else {
        return Ok(None);
    };
    let Some(b) = model.bodies.iter().find(|b| &b.name == body) else {
        return Ok(None);
    };
    let mut missing = Vec::new();
    Ok(mesh_of(b, meshes, &mut missing)?.map(|m| (m, s1.clone())))
}

/// Sacral frame from S1 endplate points: Y normal to the endplate (from the
/// two diameters, `(SR - SL) x (SA - SP)`), Z right.
fn sacral_rotation(p: &Points) -> Option<Rotation3<f64>> {
    let a = p.get(&Code::SA)? - p.get(&Code::SP)?;
    let r = p.get(&Code::SR)? - p.get(&Code::SL)?;
    frame_from_axes(r.cross(&a), r)
}

fn isb_rotation(p: &Points) -> Option<Rotation3<f64>> {
    let right = nalgebra::center(p.get(&Code::PTR)?, p.get(&Code::PBR)?);
    let left = nalgebra::center(p.get(&Code::PTL)?, p.get(&Code::PBL)?);
    frame_from_axes(p.get(&Code::SEC)? - p.get(&Code::IEC)?, right - left)
}

fn xyz_deg(r: &UnitQuaternion<f64>) -> [f64; 3] {
    let a = crate::osim::model::xyz_angles(&r.to_rotation_matrix());
    [a.x.to_degrees(), a.y.to_degrees(), a.z.to_degrees()]
}

/// Levels of the set, ending at S1 (the check module reports the details;
/// this is the generator's own guard). Levels missing between measured
/// ones are filled from their neighbours ([`fill`]).
fn set_levels(set: &LandmarkSet, file: &str) -> Result<Vec<Level>> {
    let levels = set.levels();
    if levels.last() != Some(&Level::S1) {
        return Err(Error::invalid(
            file,
            "the landmark set has no S1 landmarks: the levels must end at the sacrum",
        ));
    }
    Ok(levels)
}

/// Fewest landmarks a vertebra is fitted on (of 14): the lsq fit of a
/// pose and three scale factors, with one landmark left out in turn.
pub const MIN_VERTEBRA_LANDMARKS: usize = 8;

/// Fewest sacral landmarks for the registration (a rigid fit needs 3).
pub const MIN_SACRUM_LANDMARKS: usize = 3;

/// A level fitted on fewer landmarks than the protocol's.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ReducedFit {
    pub level: String,
    /// The protocol's landmarks missing from the set.
    pub missing: Vec<String>,
    /// Landmarks the fit used (before outlier rejection).
    pub used: usize,
    /// Dimensions its landmarks cannot measure, scaled by the neighbours'
    /// factors instead (`width 1.03 from T4, T6`); empty when none.
    pub borrowed_scale: Vec<String>,
}

/// Check that the base model has every marker of each landmarked level,
/// and list the levels whose landmarks are incomplete: fitted on what is
/// there (a reduced fit) when at least [`MIN_VERTEBRA_LANDMARKS`]
/// ([`MIN_SACRUM_LANDMARKS`] for S1) remain, refused otherwise.
fn landmark_coverage(
    levels: &[Level],
    patient: &BTreeMap<Level, Points>,
    markers: &BTreeMap<Level, (String, Points)>,
    set_name: &str,
    bfile: &str,
) -> Result<Vec<ReducedFit>> {
    let mut reduced = Vec::new();
    for l in levels {
        let (_, mpts) = markers.get(l).ok_or_else(|| {
            Error::invalid(
                bfile,
                format!(
                    "the landmarks cover {l} but the base model has no {l} markers (body '{}')",
                    l.body_name()
                ),
            )
        })?;
        let absent = |have: &Points| -> Vec<String> {
            l.required_codes()
                .iter()
                .filter(|c| !have.contains_key(c))
                .map(|c| format!("{l}_{c}"))
                .collect()
        };
        let mmissing = absent(mpts);
        if !mmissing.is_empty() {
            return Err(Error::invalid(
                bfile,
                format!("the base model lacks the marker(s) {}", mmissing.join(", ")),
            ));
        }
        let have = patient.get(l).cloned().unwrap_or_default();
        let missing = absent(&have);
        if missing.is_empty() {
            continue;
        }
        let need = if l.is_sacrum() {
            MIN_SACRUM_LANDMARKS
        } else {
            MIN_VERTEBRA_LANDMARKS
        };
        let used = l.required_codes().len() - missing.len();
        if used < need {
            return Err(Error::invalid(
                set_name,
                format!(
                    "{l}: only {used} landmark(s) (missing {}); a fit needs at least {need}",
                    missing.join(", ")
                ),
            ));
        }
        reduced.push(ReducedFit {
            level: l.to_string(),
            missing,
            used,
            borrowed_scale: Vec::new(),
        });
    }
    Ok(reduced)
}

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
    let bfile = base.path().display().to_string();
    let model = base.model()?;
    let kin = Kinematics::new(&model)?;
    let q0 = kin.default_values();
    let poses0 = kin.body_poses(&q0)?;
    let markers = base_markers(&model)?;
    let levels = set_levels(set, set_name)?;
    let vert_levels: Vec<Level> = levels.iter().copied().filter(|l| !l.is_sacrum()).collect();

    let mut patient = landmarks_per_level(set);
    let mut reduced_fits = landmark_coverage(&levels, &patient, &markers, set_name, &bfile)?;
    let borrowed = borrowed_scales(&vert_levels, &patient, &markers, &mut reduced_fits);

    // ---- 1. registration through the sacrum
    let x_sacrum = poses0
        .get("sacrum")
        .copied()
        .ok_or_else(|| Error::invalid(&bfile, "the base model has no body 'sacrum'"))?;
    let registration = register_sacrum(&mut patient, &markers, &x_sacrum, set_name)?;

    // ---- 2. fits (lsq: palpation noise estimated over the whole set for
    // the outlier test); a code off the same way at several levels is a
    // protocol mismatch, compensated ([`fit_with_protocol_check`])
    let input = FitInput {
        vert_levels: &vert_levels,
        markers: &markers,
        joint_centres: base_joint_centres(&model, &poses0)?,
        body_centres: base_body_centres(&model)?,
        borrowed,
        opts,
    };
    let (
        LevelFits {
            fits,
            noise,
            smoothing,
        },
        landmark_residuals,
        protocol_mismatches,
    ) = fit_with_protocol_check(&input, &patient)?;
    let mut fits = fits;

    // ---- 2b. levels missing between measured ones, from their neighbours
    let filled = fill::fill_gaps(&mut fits, &x_sacrum, &poses0, &input.joint_centres);

    // ---- 3. scaling
    let mut doc = base.clone();
    let (mut scales, scaling) = scale_bodies(&mut doc, &fits)?;

    // ---- 4. joint frames
    let (rewritten, prefixes) =
        rewrite_joint_frames(&mut doc, &model, &fits, &markers, &x_sacrum, &bfile)?;

    // ---- 4b. levels above the field of view ([`balance`])
    let above_fov = match vert_levels.first() {
        Some(top) => balance::place_above_fov(
            &mut doc,
            &model,
            *top,
            patient[&Level::S1][&Code::SEC],
            markers.get(&Level::T1).map(|(_, m)| m),
            opts.above_fov,
        )?,
        None => None,
    };

    // ---- 4c. the patient's own vertebrae ([`geometry`]): meshes, markers,
    // sphere centres, joints at the discs, mass, attachments out of bone
    let mut radii = sphere_radii(&model);
    let applied = match patient_geometry {
        Some(pg) => {
            let placement = PatientPlacement {
                fits: &fits,
                input: &input,
                smoothing: &smoothing,
                registration: registration.isometry(),
                patient: &patient,
            };
            let a = wear_patient_geometry(&mut doc, pg, &placement, meshes)?;
            radii.extend(a.sphere_radii.iter().map(|(n, r)| (n.clone(), *r)));
            for b in &a.bodies {
                scales.remove(b);
            }
            Some(a)
        }
        None => None,
    };
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

    // ---- 5. wrap spheres
    let spheres = wraps::refit_spheres(&mut doc, &scales, &radii, &prefixes)?;

    // ---- 5b. muscle paths clear of the vertebrae ([`clear`])
    let path_edits = clear_muscle_paths(&mut doc, meshes)?;

    // ---- 6. report, views, self-check
    let out_model = doc.model()?;
    let kin2 = Kinematics::new(&out_model)?;
    let poses2 = kin2.body_poses(&kin2.default_values())?;
    let centres = model_centres(&out_model, &poses2, CentreDef::default())?;
    let (rows, outliers, landmark_rms) = vertebra_rows(&fits, &poses2, &filled);
    let levels_from_base: Vec<String> = markers
        .keys()
        .filter(|l| !l.is_sacrum() && !fits.contains_key(l))
        .map(|l| l.to_string())
        .collect();
    let self_check = if opts.self_check {
        Some(self_check(&out_model, meshes, &spheres)?)
    } else {
        None
    };
    // the model's shape and the frontal/sagittal views
    let (shape, views) = shape_and_views(
        &out_model,
        &poses2,
        &centres,
        &patient,
        &own_meshes,
        opts.views,
    )?;
    let report = GenerateReport {
        // File names only: the report is the same wherever the inputs lie
        // and whatever the working directory (determinism).
        base_model: file_name_of(&bfile),
        landmarks: file_name_of(set_name),
        detection: set.detection.as_ref().map(|d| d.summary()),
        method: opts.method,
        levels_from_landmarks: vert_levels.iter().map(|l| l.to_string()).collect(),
        levels_from_base,
        registration,
        vertebrae: rows,
        noise_sd_mm: noise.map(|n| n * 1e3),
        outliers,
        protocol_mismatches,
        smoothing,
        landmark_rms_mm: landmark_rms * 1e3,
        joints_rewritten: rewritten,
        scaling,
        spheres,
        path_edits,
        centres: centres
            .iter()
            .map(|(l, p)| (l.to_string(), [p.x, p.y, p.z]))
            .collect(),
        self_check,
        above_fov,
        reduced_fits,
        filled_levels: filled.iter().map(|f| f.level.clone()).collect(),
        filled,
        shape,
        landmark_residuals,
        geometry: applied.map(|a| a.report),
    };
    Ok(Generated {
        doc,
        report,
        views,
        meshes: own_meshes,
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

/// The set's landmarks grouped by level.
fn landmarks_per_level(set: &LandmarkSet) -> BTreeMap<Level, Points> {
    let mut patient: BTreeMap<Level, Points> = BTreeMap::new();
    for (id, p) in &set.points {
        patient.entry(id.level).or_default().insert(id.code, *p);
    }
    patient
}

/// Radius of every wrap sphere of the base model, by name.
fn sphere_radii(model: &Model) -> BTreeMap<String, f64> {
    model
        .bodies
        .iter()
        .flat_map(|b| b.wrap_objects.iter())
        .filter_map(|w| match w.shape {
            crate::osim::model::WrapShape::Sphere { radius } => Some((w.name.clone(), radius)),
            _ => None,
        })
        .collect()
}

/// Step 5b: muscle paths cleared of the vertebra meshes ([`clear`]); no
/// edits without meshes.
fn clear_muscle_paths(
    doc: &mut Document,
    meshes: Option<&dyn MeshSource>,
) -> Result<Vec<clear::PathEdit>> {
    let Some(src) = meshes else {
        return Ok(Vec::new());
    };
    let m = doc.model()?;
    let owned = crate::base::wrapped::vertebra_meshes(&m, src)?;
    let refs: Vec<(String, &MeshQuery)> = owned.iter().map(|(n, q)| (n.clone(), q)).collect();
    clear::clear_paths(doc, &refs)
}

/// Step 1: register the landmarks to the base model through the sacrum
/// (its required landmarks, plus PTR/PTL when both sides have them); every
/// landmark is moved into the model's frame.
fn register_sacrum(
    patient: &mut BTreeMap<Level, Points>,
    markers: &BTreeMap<Level, (String, Points)>,
    x_sacrum: &Isometry3<f64>,
    set_name: &str,
) -> Result<Registration> {
    let (src, dst, used): (Vec<Point3<f64>>, Vec<Point3<f64>>, Vec<String>) = {
        let pp = &patient[&Level::S1];
        let mp = &markers[&Level::S1].1;
        let mut codes: Vec<Code> = Code::SACRUM_REQUIRED.to_vec();
        if [Code::PTR, Code::PTL]
            .iter()
            .all(|c| pp.contains_key(c) && mp.contains_key(c))
        {
            codes.extend([Code::PTR, Code::PTL]);
        }
        let mut s = Vec::new();
        let mut d = Vec::new();
        let mut u = Vec::new();
        for c in codes {
            if let (Some(p), Some(m)) = (pp.get(&c), mp.get(&c)) {
                s.push(*p);
                d.push(x_sacrum * m);
                u.push(format!("S1_{c}"));
            }
        }
        (s, d, u)
    };
    let reg = umeyama(&src, &dst, false).map_err(|e| {
        Error::invalid(
            set_name,
            format!("sacral landmarks cannot be registered to the model: {e}"),
        )
    })?;
    let x_reg = Isometry3::from_parts(reg.translation.into(), reg.rotation);
    let reg_rms = (src
        .iter()
        .zip(&dst)
        .map(|(s, d)| (x_reg * s - d).norm_squared())
        .sum::<f64>()
        / src.len() as f64)
        .sqrt();
    for pts in patient.values_mut() {
        for p in pts.values_mut() {
            *p = x_reg * *p;
        }
    }
    Ok(Registration::from_iso(&x_reg, used, reg_rms))
}

/// Base joint centres between consecutive vertebrae, keyed by the upper
/// level: the centre in the upper body and in the lower body.
pub type JointCentres = BTreeMap<Level, (Point3<f64>, Point3<f64>)>;

/// What every fit of step 2 shares: the levels, the base's markers and
/// joint centres, the options.
struct FitInput<'a> {
    vert_levels: &'a [Level],
    markers: &'a BTreeMap<Level, (String, Points)>,
    /// Base joint centres between consecutive vertebrae, in each body (the
    /// chain smoothing's prior).
    joint_centres: JointCentres,
    /// Each vertebra's centre in its body frame (the chain's joint model).
    body_centres: BTreeMap<Level, Point3<f64>>,
    /// Scale factors borrowed from the neighbours where a vertebra's
    /// landmarks cannot measure a dimension.
    borrowed: BTreeMap<Level, pose::Borrowed>,
    opts: &'a GenerateOptions,
}

/// The scale factors each vertebra borrows from its neighbours
/// ([`pose::borrowed_scales`]), noted on its reduced fit.
fn borrowed_scales(
    vert_levels: &[Level],
    patient: &BTreeMap<Level, Points>,
    markers: &BTreeMap<Level, (String, Points)>,
    reduced: &mut [ReducedFit],
) -> BTreeMap<Level, pose::Borrowed> {
    let model: BTreeMap<Level, Points> =
        markers.iter().map(|(l, (_, p))| (*l, p.clone())).collect();
    let all = pose::borrowed_scales(vert_levels, patient, &model);
    for r in reduced.iter_mut() {
        let Some((b, from)) = r.level.parse::<Level>().ok().and_then(|l| all.get(&l)) else {
            continue;
        };
        let from: Vec<String> = from.iter().map(Level::to_string).collect();
        r.borrowed_scale = (0..3)
            .filter_map(|k| {
                Some(format!(
                    "{} {:.3} from {}",
                    pose::DIMENSIONS[k],
                    b[k]?,
                    from.join(", ")
                ))
            })
            .collect();
    }
    all.into_iter().map(|(l, (b, _))| (l, b)).collect()
}

/// Each vertebra's centre in its (unscaled) body frame: the vertebral
/// centre of [`model_centres`] (its vertebral-body wrap sphere, else the
/// midpoint of its SEC and IEC markers) with every body at the identity.
fn base_body_centres(model: &Model) -> Result<BTreeMap<Level, Point3<f64>>> {
    let identity: BTreeMap<String, Isometry3<f64>> = model
        .bodies
        .iter()
        .map(|b| (b.name.clone(), Isometry3::identity()))
        .collect();
    model_centres(model, &identity, CentreDef::Sphere)
}

/// The fits of step 2: poses, the set's palpation noise (lsq), smoothing.
struct LevelFits {
    fits: BTreeMap<Level, pose::VertebraFit>,
    noise: Option<f64>,
    smoothing: SmoothingReport,
}

/// The base joint centres between consecutive vertebrae, each in the
/// upper and in the lower body.
fn base_joint_centres(
    model: &Model,
    poses0: &BTreeMap<String, Isometry3<f64>>,
) -> Result<JointCentres> {
    let mut joint_centres = BTreeMap::new();
    for jf in model.joint_frames()? {
        let (Some(lu), Some(ll)) = (
            Level::from_body_name(&jf.child_body),
            Level::from_body_name(&jf.parent_body),
        ) else {
            continue;
        };
        let (Some(xu), Some(xl)) = (poses0.get(&jf.child_body), poses0.get(&jf.parent_body)) else {
            continue;
        };
        if lu.caudal() == Some(ll) {
            let in_lower = Point3::from(jf.parent_in_body.translation.vector);
            let in_upper = xu.inverse() * (xl * in_lower);
            joint_centres.insert(lu, (in_upper, in_lower));
        }
    }
    Ok(joint_centres)
}

/// Step 2: fit every vertebra to `patient` (lsq: with the palpation noise
/// estimated over the whole set for the outlier test), then smooth the
/// orientations along the chain with the base joint centres as prior.
fn fit_levels(
    input: &FitInput,
    markers: &BTreeMap<Level, (String, Points)>,
    patient: &BTreeMap<Level, Points>,
) -> Result<LevelFits> {
    let (vert_levels, opts) = (input.vert_levels, input.opts);
    let noise = match opts.method {
        Method::Lsq => {
            let loo: Vec<pose::VertebraLoo> = vert_levels
                .iter()
                .map(|l| pose::vertebra_loo(*l, &patient[l], &markers[l].1))
                .collect();
            pose::set_noise_sd(&loo)
        }
        Method::Thesis => None,
    };
    let mut fits: BTreeMap<Level, pose::VertebraFit> = BTreeMap::new();
    for l in vert_levels {
        let f = pose::fit_vertebra_with(
            *l,
            &patient[l],
            &markers[l].1,
            opts.method,
            opts.outlier_sigmas,
            noise,
            input.borrowed.get(l).unwrap_or(&[None; 3]),
        )?;
        fits.insert(*l, f);
    }
    let smoothing = smooth_fits(
        &mut fits,
        vert_levels,
        patient,
        markers,
        &JointGeometry {
            joint_centres: &input.joint_centres,
            centres: &input.body_centres,
        },
        opts,
        noise,
    )?;
    Ok(LevelFits {
        fits,
        noise,
        smoothing,
    })
}

/// Step 2 with the protocol check: fit, list the per-landmark residuals,
/// and when one code is off the same way at several levels (a set
/// palpated by another protocol than the base's markers), say so and
/// compensate it: that code's base marker is moved by its offset at every
/// level and the vertebrae are refitted with every landmark (lsq; at most
/// [`MAX_COMPENSATED_CODES`] codes, so that the others anchor the poses).
fn fit_with_protocol_check(
    input: &FitInput,
    patient: &BTreeMap<Level, Points>,
) -> Result<(
    LevelFits,
    Vec<residuals::LandmarkResidual>,
    Vec<residuals::ProtocolMismatch>,
)> {
    let first = fit_levels(input, input.markers, patient)?;
    let res = residuals::landmark_residuals(&first.fits, patient, input.markers);
    let mut mismatches = residuals::protocol_mismatches(&res, first.noise.unwrap_or(PALPATION_SD));
    if mismatches.is_empty()
        || mismatches.len() > MAX_COMPENSATED_CODES
        || input.opts.method != Method::Lsq
    {
        return Ok((first, res, mismatches));
    }
    let codes: Vec<Code> = mismatches.iter().map(|m| m.code).collect();
    let (fit, res, offsets) = compensate(input, patient, first, res, &codes)?;
    for m in &mut mismatches {
        m.compensated = true;
        let d = offsets[&m.code] * 1e3;
        m.mean_offset_mm = [d.x, d.y, d.z];
    }
    Ok((fit, res, mismatches))
}

/// Most codes compensated in one set: the other landmarks (at least 8 of
/// 14) anchor the poses, so an offset is not mistaken for a translation or
/// rotation of every vertebra.
pub const MAX_COMPENSATED_CODES: usize = 6;

/// Refits of [`compensate`]: each one removes most of what is left of the
/// offsets (the part the fit absorbed, about the code's leverage, 1/5).
const COMPENSATION_ROUNDS: usize = 8;

/// Offsets of the mismatched `codes` (vertebra frame, m) found by
/// refitting with their markers moved by the offsets so far, until the
/// median residual of each code is under 0.01 mm; the last fit, its
/// residuals (against the moved markers) and the offsets.
#[allow(clippy::type_complexity)]
fn compensate(
    input: &FitInput,
    patient: &BTreeMap<Level, Points>,
    mut fit: LevelFits,
    mut res: Vec<residuals::LandmarkResidual>,
    codes: &[Code],
) -> Result<(
    LevelFits,
    Vec<residuals::LandmarkResidual>,
    BTreeMap<Code, Vector3<f64>>,
)> {
    let mut offsets: BTreeMap<Code, Vector3<f64>> =
        codes.iter().map(|c| (*c, Vector3::zeros())).collect();
    for _ in 0..COMPENSATION_ROUNDS {
        // What is left of each code's offset: its median residual.
        let step = residuals::median_offsets(&res, codes);
        for (c, d) in &step {
            *offsets.entry(*c).or_default() += d;
        }
        // Refit with the moved markers.
        let moved = moved_markers(input.markers, &fit.fits, &offsets);
        fit = fit_levels(input, &moved, patient)?;
        res = residuals::landmark_residuals(&fit.fits, patient, &moved);
        if step.values().all(|d| d.norm() < 1e-5) {
            break;
        }
    }
    Ok((fit, res, offsets))
}

/// The base markers with each code of `offsets` moved by its offset (given
/// in the fitted, scaled vertebra's frame, so divided by that level's
/// scale factors); levels without a fit keep theirs.
fn moved_markers(
    markers: &BTreeMap<Level, (String, Points)>,
    fits: &BTreeMap<Level, pose::VertebraFit>,
    offsets: &BTreeMap<Code, Vector3<f64>>,
) -> BTreeMap<Level, (String, Points)> {
    let mut out = markers.clone();
    for (l, (_, pts)) in out.iter_mut() {
        let Some(f) = fits.get(l) else { continue };
        for (c, d) in offsets {
            if let Some(p) = pts.get_mut(c) {
                *p += d.component_div(&f.scale);
            }
        }
    }
    out
}

/// Palpation noise assumed where the set's own cannot be estimated (m per
/// axis; the thesis's sensitivity studies use 2.9 mm 3-D).
const PALPATION_SD: f64 = 0.002;

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

/// Step 4: each IVD joint between a fitted vertebra and the one below at
/// the mid-point of IEC above and SEC below, oriented half-way between the
/// two ISB frames, written with undeflected bushings. Returns the joints
/// rewritten and the prefixes (`L4_L5`) of every IVD joint.
fn rewrite_joint_frames(
    doc: &mut Document,
    model: &Model,
    fits: &BTreeMap<Level, pose::VertebraFit>,
    markers: &BTreeMap<Level, (String, Points)>,
    x_sacrum: &Isometry3<f64>,
    bfile: &str,
) -> Result<(Vec<String>, Vec<String>)> {
    let jframes = model.joint_frames()?;
    let pose_of = |l: Level| -> Isometry3<f64> {
        match fits.get(&l) {
            Some(f) => f.pose,
            None => *x_sacrum,
        }
    };
    let scaled_markers = |l: Level| -> Points {
        let (_, m) = &markers[&l];
        match fits.get(&l) {
            Some(f) => m
                .iter()
                .map(|(c, p)| (*c, pose::scale_point(p, &f.scale)))
                .collect(),
            None => m.clone(),
        }
    };
    let mut rewritten = Vec::new();
    let mut prefixes = Vec::new();
    for jf in &jframes {
        let (Some(lu), Some(ll)) = (
            Level::from_body_name(&jf.child_body),
            Level::from_body_name(&jf.parent_body),
        ) else {
            continue;
        };
        if lu.caudal() != Some(ll) {
            continue;
        }
        prefixes.push(format!("{lu}_{ll}"));
        if !fits.contains_key(&lu) {
            continue;
        }
        let (xu, xl) = (pose_of(lu), pose_of(ll));
        let (mu, ml) = (scaled_markers(lu), scaled_markers(ll));
        let iec = xu * mu[&Code::IEC];
        let sec = xl * ml[&Code::SEC];
        let ru = isb_rotation(&mu)
            .ok_or_else(|| Error::invalid(bfile, format!("the {lu} markers give no ISB frame")))?;
        let rl = if ll.is_sacrum() {
            sacral_rotation(&ml)
        } else {
            isb_rotation(&ml)
        }
        .ok_or_else(|| Error::invalid(bfile, format!("the {ll} markers give no frame")))?;
        let qu = xu.rotation * UnitQuaternion::from_rotation_matrix(&ru);
        let ql = xl.rotation * UnitQuaternion::from_rotation_matrix(&rl);
        let j = disc_frame(&iec, &sec, &qu, &ql);
        let p_in_l = xl.inverse() * j;
        let c_in_u = xu.inverse() * j;
        write_joint(
            doc,
            model,
            &jf.joint,
            &jf.parent_body,
            &jf.child_body,
            &p_in_l,
            &c_in_u,
        )?;
        rewritten.push(jf.joint.clone());
    }
    let prefixes: Vec<String> = prefixes;
    Ok((rewritten, prefixes))
}

/// An intervertebral joint's frame in ground: origin midway between a
/// point of the upper vertebra and one of the lower (the generic route:
/// the upper IEC and the lower SEC, the disc centre), orientation half-way
/// (quaternion midpoint) between the two vertebrae's frames `qu`, `ql`.
fn disc_frame(
    iec: &Point3<f64>,
    sec: &Point3<f64>,
    qu: &UnitQuaternion<f64>,
    ql: &UnitQuaternion<f64>,
) -> Isometry3<f64> {
    Isometry3::from_parts(nalgebra::center(iec, sec).coords.into(), ql.slerp(qu, 0.5))
}

/// The report's row per fitted vertebra, the outliers rejected and the
/// RMS of all residuals (m).
fn vertebra_rows(
    fits: &BTreeMap<Level, pose::VertebraFit>,
    poses2: &BTreeMap<String, Isometry3<f64>>,
    filled: &[fill::FilledLevel],
) -> (Vec<VertebraRow>, Vec<String>, f64) {
    let mut rows = Vec::new();
    let mut outliers = Vec::new();
    let mut all_res = Vec::new();
    for (l, f) in fits {
        let rms = (f.residuals.values().map(|r| r * r).sum::<f64>()
            / f.residuals.len().max(1) as f64)
            .sqrt();
        all_res.extend(f.residuals.values().copied());
        if let Some((c, e)) = f.outlier {
            outliers.push(format!("{l}_{c} ({:.1} mm)", e * 1e3));
        }
        let x = poses2.get(&l.body_name()).copied().unwrap_or(f.pose);
        rows.push(VertebraRow {
            level: l.to_string(),
            body: l.body_name(),
            scale: [f.scale.x, f.scale.y, f.scale.z],
            origin: [
                x.translation.vector.x,
                x.translation.vector.y,
                x.translation.vector.z,
            ],
            orientation_deg: xyz_deg(&x.rotation),
            rms_mm: rms * 1e3,
            max_residual_mm: f.residuals.values().fold(0.0f64, |a, b| a.max(*b)) * 1e3,
            outlier: f.outlier.map(|(c, _)| format!("{l}_{c}")),
            outlier_error_mm: f.outlier.map(|(_, e)| e * 1e3),
            loo_max_mm: f.loo_max.map(|(_, e, _)| e * 1e3),
            loo_threshold_mm: f.loo_max.map(|(_, _, t)| t * 1e3),
            filled: filled.iter().any(|x| x.level == l.to_string()),
        });
    }
    let landmark_rms =
        (all_res.iter().map(|r| r * r).sum::<f64>() / all_res.len().max(1) as f64).sqrt();
    (rows, outliers, landmark_rms)
}

/// Step 6: the generated model's self-check (bushings at rest, muscle
/// paths against the vertebra meshes when there are any, equilibrium
/// under gravity), with the refitted wrap spheres.
fn self_check(
    out_model: &Model,
    meshes: Option<&dyn MeshSource>,
    spheres: &[wraps::SphereOut],
) -> Result<crate::base::check::SelfCheck> {
    let mut owned = Vec::new();
    if let Some(src) = meshes {
        for b in &out_model.bodies {
            if Level::from_body_name(&b.name).map(|l| l.is_sacrum()) != Some(false) {
                continue;
            }
            let mut missing = Vec::new();
            if let Some(m) = mesh_of(b, src, &mut missing)? {
                let q = MeshQuery::new(&m)
                    .map_err(|e| Error::invalid(format!("mesh of {}", b.name), e.to_string()))?;
                owned.push((b.name.clone(), q));
            }
        }
    }
    let refs: Vec<(String, &MeshQuery)> = owned.iter().map(|(n, q)| (n.clone(), q)).collect();
    let rows: Vec<crate::base::wrap::SphereRow> = spheres
        .iter()
        .map(|s| crate::base::wrap::SphereRow {
            level: Level::from_body_name(&s.body)
                .map(|l| l.to_string())
                .unwrap_or_default(),
            body: s.body.clone(),
            name: s.name.clone(),
            centre: s.centre,
            radius_fit: s.radius_refit,
            radius_no_overlap: s.radius,
            radius: s.radius,
            rms_mm: 0.0,
            nodes: 0,
            centre_inside_mesh: true,
            source: "refitted from the base model".into(),
            body_mesh_registration_rms_mm: None,
            muscles: s.muscles.clone(),
            muscles_refused: s.muscles_refused.clone(),
        })
        .collect();
    crate::base::check::run_wrapped(out_model, &refs, &rows)
}

/// Replace the fitted orientations by their spinal-continuity posterior
/// ([`smooth::smooth_orientations`]) when `opts.smooth` asks for it: each
/// vertebra turns about the centroid of its used landmarks' markers (its
/// least-squares position is kept) and its residuals are recomputed.
fn smooth_fits(
    fits: &mut BTreeMap<Level, pose::VertebraFit>,
    chain: &[Level],
    patient: &BTreeMap<Level, Points>,
    markers: &BTreeMap<Level, (String, Points)>,
    geometry: &JointGeometry,
    opts: &GenerateOptions,
    noise: Option<f64>,
) -> Result<SmoothingReport> {
    let mut rep = SmoothingReport {
        mode: opts.smooth,
        applied: false,
        note: String::new(),
        tau_deg: None,
        effective_dof: None,
        parameters: 3 * chain.len(),
        joint_sd_mm: None,
        joint_scaling: None,
        levels: Vec::new(),
    };
    if opts.smooth == Smooth::Off {
        rep.note = "off".into();
        return Ok(rep);
    }
    if opts.method != Method::Lsq {
        rep.note = "not applied: smoothing needs the lsq fit's covariance (--method lsq)".into();
        return Ok(rep);
    }
    // Scaled markers of the used landmarks (body frame) per chain vertebra.
    let mut used: Vec<Vec<(Code, Point3<f64>)>> = Vec::new();
    let mut rots = Vec::new();
    let mut info = Vec::new();
    for l in chain {
        let (Some(f), Some((_, m))) = (fits.get(l), markers.get(l)) else {
            return Err(Error::invalid(
                format!("vertebra {l}"),
                "no fit or base-model markers to smooth",
            ));
        };
        let pts: Vec<(Code, Point3<f64>)> = f
            .residuals
            .keys()
            .filter_map(|c| Some((*c, pose::scale_point(m.get(c)?, &f.scale))))
            .collect();
        let posed: Vec<Point3<f64>> = pts.iter().map(|(_, p)| f.pose * p).collect();
        info.push(smooth::rotation_information(&posed));
        rots.push(f.pose.rotation);
        used.push(pts);
    }
    let sigma = noise.unwrap_or(0.0);
    if opts.smooth == Smooth::Chain {
        return chain_fits(fits, chain, patient, &used, geometry, sigma, rep);
    }
    let Some(s) = smooth::smooth_orientations(&rots, &info, sigma)? else {
        rep.note = if chain.len() < smooth::MIN_LEVELS {
            format!(
                "not applied: {} vertebrae (at least {} needed)",
                chain.len(),
                smooth::MIN_LEVELS
            )
        } else {
            "not applied: no landmark noise (the fits are exact)".into()
        };
        return Ok(rep);
    };
    for (k, l) in chain.iter().enumerate() {
        let (Some(f), Some(pts), Some(q), Some(pl)) = (
            fits.get_mut(l),
            used.get(k),
            s.rotations.get(k),
            patient.get(l),
        ) else {
            continue;
        };
        let n = pts.len().max(1) as f64;
        let mbar = Point3::from(pts.iter().fold(Vector3::zeros(), |a, (_, p)| a + p.coords) / n);
        let c = f.pose * mbar;
        let t = c.coords - q * mbar.coords;
        let pose = Isometry3::from_parts(t.into(), *q);
        rep.levels.push(apply_posterior(
            *l,
            f,
            pose,
            pts,
            pl,
            s.raw_sd[k],
            s.posterior_sd[k],
        ));
    }
    rep.applied = true;
    rep.tau_deg = Some(std::array::from_fn(|a| s.tau[a].to_degrees()));
    rep.effective_dof = Some(s.effective_dof);
    rep.note = format!(
        "posterior orientations (tau {:.2} / {:.2} / {:.2} deg per level^2 about X / Y / Z, {:.1} of {} orientation parameters kept)",
        s.tau.x.to_degrees(),
        s.tau.y.to_degrees(),
        s.tau.z.to_degrees(),
        s.effective_dof,
        3 * chain.len()
    );
    Ok(rep)
}

/// Replace a fit's pose by its posterior `pose`, recompute the residuals of
/// its used landmarks `pts` (scaled markers, body frame) against the
/// patient's `landmarks`, and give the report row (SDs in rad).
fn apply_posterior(
    level: Level,
    f: &mut pose::VertebraFit,
    pose: Isometry3<f64>,
    pts: &[(Code, Point3<f64>)],
    landmarks: &Points,
    raw_sd: [f64; 3],
    posterior_sd: [f64; 3],
) -> SmoothingLevel {
    let before = f.pose.rotation;
    f.pose = pose;
    f.residuals = pts
        .iter()
        .filter_map(|(code, p)| Some((*code, (landmarks.get(code)? - pose * p).norm())))
        .collect();
    SmoothingLevel {
        level: level.to_string(),
        fit_sd_deg: raw_sd.map(f64::to_degrees),
        posterior_sd_deg: posterior_sd.map(f64::to_degrees),
        correction_deg: before.angle_to(&pose.rotation).to_degrees(),
    }
}

/// Where the chain's joints sit in the base model: the joint centre in
/// each of the two bodies, and each body's centre ([`base_body_centres`]),
/// all in the unscaled body frames.
struct JointGeometry<'a> {
    joint_centres: &'a JointCentres,
    centres: &'a BTreeMap<Level, Point3<f64>>,
}

/// How a vertebra's size change moves its joint centres (the chain
/// smoothing's joint model).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum JointScaling {
    /// Scaled with the body (a larger vertebra carries its discs further
    /// out).
    WithBody,
    /// Kept at their offsets from the body's centre (the body grows about
    /// its centre; the discs take up the size change).
    AboutCentre,
}

impl JointScaling {
    fn describe(self) -> &'static str {
        match self {
            JointScaling::WithBody => "joint centres scaled with each vertebra",
            JointScaling::AboutCentre => {
                "joint centres kept at their offsets from each vertebral centre (the data's choice)"
            }
        }
    }
}

impl JointGeometry<'_> {
    /// A joint centre `p` of level `l`'s unscaled body frame, placed in its
    /// body scaled by `scale` under the joint model `scaling`.
    fn place(
        &self,
        p: &Point3<f64>,
        l: Level,
        scale: &Vector3<f64>,
        scaling: JointScaling,
    ) -> Point3<f64> {
        match scaling {
            JointScaling::WithBody => pose::scale_point(p, scale),
            JointScaling::AboutCentre => {
                let c = self.centres.get(&l).copied().unwrap_or(Point3::origin());
                p + (pose::scale_point(&c, scale) - c)
            }
        }
    }
}

/// The chain's joints, each body's joint centre placed by `scaling`.
fn chain_joints(
    fits: &BTreeMap<Level, pose::VertebraFit>,
    chain: &[Level],
    geometry: &JointGeometry,
    scaling: JointScaling,
) -> Vec<chain::ChainJoint> {
    let mut joints = Vec::new();
    for (k, w) in chain.windows(2).enumerate() {
        // A joint only between adjacent levels (a gap breaks the chain).
        if w[0].caudal() != Some(w[1]) {
            continue;
        }
        let (Some((qu, pl)), Some(fu), Some(fl)) = (
            geometry.joint_centres.get(&w[0]),
            fits.get(&w[0]),
            fits.get(&w[1]),
        ) else {
            continue;
        };
        joints.push(chain::ChainJoint {
            upper: k,
            lower: k + 1,
            in_upper: geometry.place(qu, w[0], &fu.scale, scaling),
            in_lower: geometry.place(pl, w[1], &fl.scale, scaling),
        });
    }
    joints
}

/// Every base joint centre between a fitted vertebra and the fitted
/// vertebra or sacrum below, carried into both bodies (scaled frames) by
/// their fits under `scaling`, keyed by the upper level.
fn carried_joints(
    fits: &BTreeMap<Level, pose::VertebraFit>,
    geometry: &JointGeometry,
    scaling: JointScaling,
) -> JointCentres {
    let one = Vector3::repeat(1.0);
    let mut out = JointCentres::new();
    for (lu, (qu, pl)) in geometry.joint_centres {
        let (Some(fu), Some(ll)) = (fits.get(lu), lu.caudal()) else {
            continue;
        };
        let sl = match fits.get(&ll) {
            Some(f) => f.scale,
            None if ll.is_sacrum() => one,
            None => continue,
        };
        out.insert(
            *lu,
            (
                geometry.place(qu, *lu, &fu.scale, scaling),
                geometry.place(pl, ll, &sl, scaling),
            ),
        );
    }
    out
}

/// The chain smoothed under the joint model the landmarks support best
/// (higher restricted marginal likelihood; both models have the same
/// hyperparameters, and a tie keeps [`JointScaling::WithBody`]).
fn best_joint_model(
    verts: &[chain::ChainVertebra],
    fits: &BTreeMap<Level, pose::VertebraFit>,
    chain: &[Level],
    geometry: &JointGeometry,
    sigma: f64,
) -> Result<Option<(chain::ChainSmoothed, JointScaling)>> {
    let mut best: Option<(chain::ChainSmoothed, JointScaling)> = None;
    for scaling in [JointScaling::WithBody, JointScaling::AboutCentre] {
        let joints = chain_joints(fits, chain, geometry, scaling);
        let Some(s) = chain::smooth_chain(verts, &joints, sigma)? else {
            continue;
        };
        if best.as_ref().is_none_or(|(b, _)| s.log_ml > b.log_ml) {
            best = Some((s, scaling));
        }
    }
    Ok(best)
}

/// [`chain::smooth_chain`] on the lsq fits: neighbours meet at the base
/// model's joint centres (scaled with each body).
fn chain_fits(
    fits: &mut BTreeMap<Level, pose::VertebraFit>,
    chain: &[Level],
    patient: &BTreeMap<Level, Points>,
    used: &[Vec<(Code, Point3<f64>)>],
    geometry: &JointGeometry,
    sigma: f64,
    mut rep: SmoothingReport,
) -> Result<SmoothingReport> {
    rep.parameters = 6 * chain.len();
    let mut verts = Vec::with_capacity(chain.len());
    for (l, pts) in chain.iter().zip(used) {
        let Some(f) = fits.get(l) else {
            return Err(Error::invalid(format!("vertebra {l}"), "no fit to smooth"));
        };
        let posed: Vec<Point3<f64>> = pts.iter().map(|(_, p)| f.pose * p).collect();
        let n = posed.len().max(1);
        let c = posed.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / n as f64;
        verts.push(chain::ChainVertebra {
            pose: f.pose,
            centroid: c.into(),
            info_rot: smooth::rotation_information(&posed),
            n,
        });
    }
    let Some((s, scaling)) = best_joint_model(&verts, fits, chain, geometry, sigma)? else {
        rep.note = if chain_joints(fits, chain, geometry, JointScaling::WithBody).is_empty() {
            "not applied: no joint between two landmarked vertebrae".into()
        } else {
            "not applied: no landmark noise (the fits are exact)".into()
        };
        return Ok(rep);
    };
    for (k, l) in chain.iter().enumerate() {
        let (Some(f), Some(pts), Some(x), Some(pl)) =
            (fits.get_mut(l), used.get(k), s.poses.get(k), patient.get(l))
        else {
            continue;
        };
        rep.levels.push(apply_posterior(
            *l,
            f,
            *x,
            pts,
            pl,
            s.raw_sd[k],
            s.posterior_sd[k],
        ));
    }
    rep.applied = true;
    rep.effective_dof = Some(s.effective_dof);
    rep.joint_sd_mm = Some(std::array::from_fn(|a| s.s[a] * 1e3));
    rep.joint_scaling = Some(scaling);
    rep.note = format!(
        "posterior poses of the kinematic chain, {} (joint mismatch SD {:.2} / {:.2} / {:.2} mm along the lower body's X / Y / Z, common offset {:.2} / {:.2} / {:.2} mm; {:.1} of {} pose parameters kept)",
        scaling.describe(),
        s.s.x * 1e3,
        s.s.y * 1e3,
        s.s.z * 1e3,
        s.mu.x * 1e3,
        s.mu.y * 1e3,
        s.mu.z * 1e3,
        s.effective_dof,
        6 * chain.len()
    );
    Ok(rep)
}

/// The merged, scaled meshes of a body (None when it has none).
fn mesh_of(
    b: &crate::osim::model::Body,
    source: &dyn MeshSource,
    missing: &mut Vec<String>,
) -> Result<Option<crate::mesh::TriMesh>> {
    let mut parts = Vec::new();
    for g in &b.geometry {
        if let crate::osim::model::Geometry::Mesh {
            mesh_file,
            scale_factors,
            ..
        } = g
        {
            match source.load(mesh_file)? {
                Some(m) => parts.push(m.scaled(scale_factors)),
                None => missing.push(mesh_file.clone()),
            }
        }
    }
    if parts.is_empty() {
        return Ok(None);
    }
    let refs: Vec<&crate::mesh::TriMesh> = parts.iter().collect();
    Ok(Some(crate::mesh::TriMesh::merge(&refs)?))
}

/// Write a joint's two offset frames (in the parent and child bodies) and
/// zero its coordinates' defaults; bushings that own frames on the same two
/// bodies get the same frames.
fn write_joint(
    doc: &mut Document,
    model: &Model,
    joint: &str,
    parent_body: &str,
    child_body: &str,
    p_in_parent: &Isometry3<f64>,
    c_in_child: &Isometry3<f64>,
) -> Result<()> {
    let file = model.file.display().to_string();
    let j = model
        .joint(joint)
        .ok_or_else(|| Error::invalid(&file, format!("no joint '{joint}'")))?;
    let owned = |socket: &str| -> Option<String> {
        let bare = socket.trim();
        j.frames
            .iter()
            .find(|f| f.name == bare || f.path.ends_with(&format!("/{bare}")))
            .map(|f| f.name.clone())
    };
    let (Some(pf), Some(cf)) = (owned(&j.socket_parent_frame), owned(&j.socket_child_frame)) else {
        return Err(Error::invalid(
            &file,
            format!(
                "joint '{joint}' does not own both of its offset frames (a base model from \
                 `osim-spine base` does): cannot place it"
            ),
        ));
    };
    let set_frame = |e: &mut crate::osim::xml::Element, body: &str, x: &Isometry3<f64>| {
        e.set_child_text("socket_parent", format!("/bodyset/{body}"));
        set_vec3(e, "translation", &x.translation.vector);
        set_vec3(
            e,
            "orientation",
            &crate::osim::model::xyz_angles(&x.rotation.to_rotation_matrix()),
        );
    };
    let el = doc
        .component_mut("JointSet", joint)
        .ok_or_else(|| Error::invalid(&file, format!("joint element '{joint}' not found")))?;
    if let Some(frames) = el.child_mut("frames") {
        for f in frames.elements_mut() {
            if f.name_attr() == pf {
                set_frame(f, parent_body, p_in_parent);
            } else if f.name_attr() == cf {
                set_frame(f, child_body, c_in_child);
            }
        }
    }
    if let Some(cs) = el.child_mut("coordinates") {
        for c in cs.elements_mut() {
            set_f64(c, "default_value", 0.0);
        }
    }
    // Bushings owning frames on these two bodies.
    for b in model.bushings() {
        if b.frames.len() != 2 {
            continue;
        }
        let owner = format!("/forceset/{}", b.name);
        let (Ok((b1, _)), Ok((b2, _))) = (
            model.resolve_frame(&owner, &b.socket_frame1),
            model.resolve_frame(&owner, &b.socket_frame2),
        ) else {
            continue;
        };
        if !(b1 == parent_body && b2 == child_body) {
            continue;
        }
        let n1 = b
            .socket_frame1
            .trim()
            .rsplit('/')
            .next()
            .unwrap_or("")
            .to_string();
        let n2 = b
            .socket_frame2
            .trim()
            .rsplit('/')
            .next()
            .unwrap_or("")
            .to_string();
        if let Some(frames) = doc
            .component_mut("ForceSet", &b.name)
            .and_then(|e| e.child_mut("frames"))
        {
            for f in frames.elements_mut() {
                if f.name_attr() == n1 {
                    set_frame(f, parent_body, p_in_parent);
                } else if f.name_attr() == n2 {
                    set_frame(f, child_body, c_in_child);
                }
            }
        }
    }
    Ok(())
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
