//! What `generate` returns and reports: options, the sacral registration,
//! per-vertebra rows, the smoothing summary and the whole report.

use super::balance::{AboveFov, AboveFovReport};
use super::pose::Method;
use super::smooth::Smooth;

use super::{clear, fill, geometry, pose, residuals, scale, wraps};
use crate::landmarks::Level;
use crate::osim::Document;
use nalgebra::{Isometry3, Rotation3, UnitQuaternion, Vector3};
use std::collections::BTreeMap;

/// Options of [`generate`](super::generate()).
#[derive(Debug, Clone)]
pub struct GenerateOptions {
    /// How each vertebra's pose and scale are fitted to its landmarks.
    pub method: Method,
    /// Run the self-check (needs the meshes for the through-bone test).
    pub self_check: bool,
    /// Draw the SVG views.
    pub views: bool,
    /// Outlier threshold of the lsq method in noise SDs
    /// ([`pose::OUTLIER_SIGMAS`] by default).
    pub outlier_sigmas: f64,
    /// How the per-vertebra fits are combined along the spine (lsq only):
    /// [`Smooth::Chain`] by default ([`chain`](super::chain)), [`smooth`](super::smooth), or off.
    pub smooth: Smooth,
    /// Levels above the field of view: balanced (default) or kept ([`balance`](super::balance)).
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
    pub(super) fn from_iso(x: &Isometry3<f64>, landmarks: Vec<String>, rms: f64) -> Registration {
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
    /// The vertebra.
    pub level: Level,
    /// Its body's name in the model.
    pub body: String,
    /// Scale factors X (depth), Y (height), Z (width).
    pub scale: [f64; 3],
    /// Body origin in ground (m).
    pub origin: [f64; 3],
    /// Body orientation in ground, body-fixed XYZ angles (deg).
    pub orientation_deg: [f64; 3],
    /// RMS and largest landmark-to-marker residual (mm) of the used landmarks.
    pub rms_mm: f64,
    /// Largest landmark-to-marker residual (mm) of the used landmarks.
    pub max_residual_mm: f64,
    /// Rejected outlier landmark (lsq).
    pub outlier: Option<String>,
    /// Its leave-one-out prediction error (mm).
    pub outlier_error_mm: Option<f64>,
    /// Leave-one-out candidate's prediction error and threshold (mm) (lsq).
    pub loo_max_mm: Option<f64>,
    /// Outlier threshold on that error (mm) (lsq).
    pub loo_threshold_mm: Option<f64>,
    /// Placed from its neighbours (no landmarks: a gap in the set).
    pub filled: bool,
}

/// Everything [`generate`](super::generate()) did and measured (the JSON report).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct GenerateReport {
    /// File name of the base model.
    pub base_model: String,
    /// File name of the landmark set.
    pub landmarks: String,
    /// Units/frame: declared, detected and used.
    pub detection: Option<String>,
    /// The fitting method used.
    pub method: Method,
    /// Vertebrae placed from landmarks, cranial to caudal.
    pub levels_from_landmarks: Vec<Level>,
    /// Vertebrae of the base model kept with the base shape and alignment.
    pub levels_from_base: Vec<Level>,
    /// Landmark frame to ground, from the sacral landmarks.
    pub registration: Registration,
    /// One row per vertebra placed from landmarks, cranial to caudal.
    pub vertebrae: Vec<VertebraRow>,
    /// Per-axis palpation noise SD (mm) estimated over the whole set from
    /// the leave-one-out prediction errors (lsq; [`pose::noise_sd`]).
    pub noise_sd_mm: Option<f64>,
    /// Outliers flagged (`<LEVEL>_<CODE> (error mm)`).
    pub outliers: Vec<String>,
    /// Landmark codes off the same way at several levels: the set follows
    /// another palpation protocol than the base's markers ([`residuals`]).
    pub protocol_mismatches: Vec<residuals::ProtocolMismatch>,
    /// Spinal-continuity smoothing of the orientations ([`smooth`](super::smooth)).
    pub smoothing: SmoothingReport,
    /// RMS of all landmark-to-marker residuals (mm), outliers excluded.
    pub landmark_rms_mm: f64,
    /// Names of the intervertebral joints whose frames were rewritten.
    pub joints_rewritten: Vec<String>,
    /// What scaling touched, by body name.
    pub scaling: BTreeMap<String, scale::ScaleCount>,
    /// The refitted wrap spheres.
    pub spheres: Vec<wraps::SphereOut>,
    /// Edits that cleared muscle paths from the vertebrae ([`clear`]).
    pub path_edits: Vec<clear::PathEdit>,
    /// Vertebral centres ([`crate::evaluate::CentreDef::Endplates`]) in
    /// ground at the default pose (m).
    #[serde(serialize_with = "crate::anatomy::serialize_by_name")]
    pub centres: BTreeMap<Level, [f64; 3]>,
    /// The generated model's self-check (`None` when not run).
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
    pub filled_levels: Vec<Level>,
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

/// What the orientation smoothing did ([`smooth`](super::smooth)).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct SmoothingReport {
    /// The smoothing asked for.
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
    /// Number of orientation parameters (3 per vertebra).
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
    /// The vertebra.
    pub level: Level,
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
    /// The generated model.
    pub doc: Document,
    /// What was done and measured.
    pub report: GenerateReport,
    /// (suffix, SVG text): `frontal`, `sagittal`.
    pub views: Vec<(String, String)>,
    /// Meshes of the model that are not the base model's (the patient's,
    /// [`geometry`]), by `mesh_file`, in their bodies' frames (m).
    pub meshes: BTreeMap<String, crate::mesh::TriMesh>,
}

/// A level fitted on fewer landmarks than the protocol's.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ReducedFit {
    /// The vertebra.
    pub level: Level,
    /// The protocol's landmarks missing from the set.
    pub missing: Vec<String>,
    /// Landmarks the fit used (before outlier rejection).
    pub used: usize,
    /// Dimensions its landmarks cannot measure, scaled by the neighbours'
    /// factors instead (`width 1.03 from T4, T6`); empty when none.
    pub borrowed_scale: Vec<String>,
}

pub(super) fn xyz_deg(r: &UnitQuaternion<f64>) -> [f64; 3] {
    let a = crate::osim::model::xyz_angles(&r.to_rotation_matrix());
    [a.x.to_degrees(), a.y.to_degrees(), a.z.to_degrees()]
}

/// The report's row per fitted vertebra, the outliers rejected and the
/// RMS of all residuals (m).
pub(super) fn vertebra_rows(
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
            level: *l,
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
            filled: filled.iter().any(|x| x.level == *l),
        });
    }
    let landmark_rms =
        (all_res.iter().map(|r| r * r).sum::<f64>() / all_res.len().max(1) as f64).sqrt();
    (rows, outliers, landmark_rms)
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
    pub(super) fn describe(self) -> &'static str {
        match self {
            JointScaling::WithBody => "joint centres scaled with each vertebra",
            JointScaling::AboutCentre => {
                "joint centres kept at their offsets from each vertebral centre (the data's choice)"
            }
        }
    }
}
