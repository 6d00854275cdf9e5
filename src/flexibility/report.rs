//! What `flexibility` reports (`flexibility.json`): per joint the relative
//! stiffness with its 95% interval and whether the films resolve it, per
//! region and across the main curve, each film's fit (loads, placement,
//! residuals per level), each curve's flexibility measured and reproduced,
//! the predictions, and every finding.

use super::fit::FilmData;
use super::place::Placement;
use crate::landmarks::metrics::{
    cobb_of_tilts, frontal_tilt_of_line, secondary_of_tilts, Cobb, FrontalTilts,
};
use crate::landmarks::radiograph::FilmPoint;
use crate::landmarks::{Code, LandmarkId, Level};
use nalgebra::{DMatrix, Vector2};
use serde::Serialize;
use std::collections::BTreeMap;

/// Span (hi / lo) of a 95% interval below which the films resolve a stiffness.
pub const RESOLVED_SPAN: f64 = 4.0;

/// One joint's estimate.
#[derive(Debug, Clone, Serialize)]
pub struct JointEstimate {
    /// `L1_L2`.
    pub joint: String,
    /// Stiffness relative to the other estimated joints (geometric mean 1).
    pub relative_stiffness: f64,
    /// 95% interval of the relative stiffness.
    pub ci95: [f64; 2],
    /// SD of its natural log.
    pub log_sd: f64,
    /// Whether the films resolve it (interval narrower than a factor
    /// [`RESOLVED_SPAN`]).
    pub resolved: bool,
}

/// A group of joints: geometric mean of their relative stiffness.
#[derive(Debug, Clone, Serialize)]
pub struct RegionEstimate {
    /// Region label.
    pub region: String,
    /// The joints of the region.
    pub joints: Vec<String>,
    /// Geometric mean of the joints' relative stiffness.
    pub relative_stiffness: f64,
    /// Its 95% interval.
    pub ci95: [f64; 2],
    /// Whether the interval is narrow enough to call the region resolved.
    pub resolved: bool,
}

/// The estimate of a log-linear combination `a . log m` with covariance `c`:
/// (value, 95% interval, SD of the log).
pub fn combination(a: &[f64], log_m: &[f64], c: &DMatrix<f64>) -> (f64, [f64; 2], f64) {
    let v: f64 = a.iter().zip(log_m).map(|(a, l)| a * l).sum();
    let mut var = 0.0;
    for i in 0..a.len() {
        for j in 0..a.len() {
            var += a[i] * c[(i, j)] * a[j];
        }
    }
    let sd = var.max(0.0).sqrt();
    (v.exp(), [(v - 1.96 * sd).exp(), (v + 1.96 * sd).exp()], sd)
}

/// Whether an interval is narrow enough to call the stiffness resolved.
pub fn resolved(ci: [f64; 2]) -> bool {
    ci[1] / ci[0] < RESOLVED_SPAN
}

/// The lateral force and frontal moment of a fit.
#[derive(Debug, Clone, Serialize)]
pub struct Loads {
    /// Lateral force (ground Z, towards the patient's right positive).
    pub force_n: f64,
    /// Frontal moment (about ground X).
    pub moment_n_m: f64,
    /// Vertical force (ground Y, cranial positive).
    pub vertical_force_n: f64,
}

/// How well a model reproduces a film.
#[derive(Debug, Clone, Serialize)]
pub struct FilmFit {
    /// RMS distance of the film's points to the model's (mm, 2-D).
    pub rms_mm: f64,
    /// Per level (T1..L5, S1, pelvis for the femoral heads), RMS mm.
    pub rms_per_level_mm: BTreeMap<String, f64>,
    /// The fitted loads on the loaded level.
    pub loads: Loads,
    /// The loaded level's lateral displacement (mm, towards the patient's
    /// left positive, as the film's u) and frontal tilt change (deg,
    /// positive right end lower) from the unbent model.
    pub loaded_level_lateral_mm: f64,
    /// The loaded level's frontal tilt change (deg, positive right end lower).
    pub loaded_level_tilt_deg: f64,
    /// The film's placement on the model: rotation (deg) and offset (mm).
    pub placement_rotation_deg: f64,
    /// The film's placement offset (mm).
    pub placement_offset_mm: [f64; 2],
}

/// RMS per level of 2-D residuals `d` at `points` (mm).
pub fn rms_per_level(points: &[FilmPoint], d: &[Vector2<f64>]) -> (f64, BTreeMap<String, f64>) {
    let mut acc: BTreeMap<String, (f64, usize)> = BTreeMap::new();
    let mut all = 0.0;
    for (p, e) in points.iter().zip(d) {
        let key = match p {
            FilmPoint::Landmark(id) => id.level.to_string(),
            FilmPoint::FemoralHead(_) => "FH".to_string(),
        };
        let a = acc.entry(key).or_insert((0.0, 0));
        a.0 += e.norm_squared();
        a.1 += 1;
        all += e.norm_squared();
    }
    let n = points.len().max(1) as f64;
    (
        (all / n).sqrt() * 1e3,
        acc.into_iter()
            .map(|(k, (s, c))| (k, (s / c as f64).sqrt() * 1e3))
            .collect(),
    )
}

/// Frontal tilts of the endplate lines (`SR`-`SL`, `IR`-`IL`) of a set of
/// 2-D points.
pub fn film_tilts(points: &BTreeMap<FilmPoint, Vector2<f64>>) -> FrontalTilts {
    let get = |l: Level, c: Code| points.get(&FilmPoint::Landmark(LandmarkId::new(l, c)));
    let line = |l: Level, r: Code, s: Code| {
        let (a, b) = (get(l, r)?, get(l, s)?);
        frontal_tilt_of_line((a.x, a.y), (b.x, b.y))
    };
    Level::ALL[..17]
        .iter()
        .filter_map(|&l| {
            let t = (line(l, Code::SR, Code::SL), line(l, Code::IR, Code::IL));
            (t.0.is_some() || t.1.is_some()).then_some((l, t))
        })
        .collect()
}

/// A curve of the spine: its end vertebrae from the unbent film (or the
/// model at rest), its Cobb angle there, and per film the Cobb angle
/// between the same ends and the flexibility (bending Cobb / unbent Cobb).
#[derive(Debug, Clone, Serialize)]
pub struct Curve {
    /// `main` or `secondary`.
    pub curve: String,
    /// The curve's upper end vertebra.
    pub upper: Level,
    /// The curve's lower end vertebra.
    pub lower: Level,
    /// Where the ends and the unbent angle come from (a film, or `model`).
    pub defined_on: String,
    /// Cobb angle of the unbent curve (deg).
    pub unbent_cobb_deg: f64,
    /// The curve on each bending film.
    pub films: Vec<CurveOnFilm>,
}

/// One curve on one film.
#[derive(Debug, Clone, Serialize)]
pub struct CurveOnFilm {
    /// The film's file.
    pub film: String,
    /// Measured on the film (None: its endplates are not on the film).
    pub measured_cobb_deg: Option<f64>,
    /// Measured bending Cobb / unbent Cobb.
    pub measured_flexibility: Option<f64>,
    /// Reproduced by the personalised model (None in `--uniform` mode).
    pub personalised_cobb_deg: Option<f64>,
    /// Personalised-model bending Cobb / unbent Cobb.
    pub personalised_flexibility: Option<f64>,
    /// Reproduced by the model's own (unpersonalised) stiffness.
    pub uniform_cobb_deg: Option<f64>,
    /// Uniform-model bending Cobb / unbent Cobb.
    pub uniform_flexibility: Option<f64>,
}

/// The main and secondary curves of the unbent shape (`tilts`).
pub fn curves_of(tilts: &FrontalTilts) -> Vec<(String, Cobb)> {
    let Some(main) = cobb_of_tilts(tilts, None) else {
        return Vec::new();
    };
    let second = secondary_of_tilts(tilts, &main);
    let mut out = vec![("main".to_string(), main)];
    if let Some(s) = second {
        out.push(("secondary".into(), s));
    }
    out
}

/// The Cobb angle (deg) between the ends of `c` on `tilts`.
pub fn cobb_between(tilts: &FrontalTilts, c: &Cobb) -> Option<f64> {
    cobb_of_tilts(tilts, Some((c.upper, c.lower))).map(|x| x.angle_deg)
}

/// The film points of `film` moved into the model's frontal plane by the
/// inverse of its placement.
pub fn film_in_model(film: &FilmData, place: &Placement) -> BTreeMap<FilmPoint, Vector2<f64>> {
    film.points
        .iter()
        .zip(&film.measured)
        .map(|(p, f)| (*p, place.inverse_apply(f)))
        .collect()
}
