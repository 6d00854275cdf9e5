//! Per-vertebra scaling and pose from the 14 landmarks of one vertebra.
//!
//! * Scale factors (body axes X depth, Y height, Z width) are ratios of the
//!   patient's dimensions to the base model's, both measured with the same
//!   rule on the 8 scaling landmarks / markers: depth = mean of `|SA-SP|`,
//!   `|IA-IP|`; width = mean of `|SR-SL|`, `|IR-IL|`; height = mean of
//!   `|SA-IA|`, `|SP-IP|`, `|SR-IR|`, `|SL-IL|`. A landmark excluded as an
//!   outlier is left out of both sides.
//! * [`Method::Thesis`] (chapter 5 of the source thesis): orientation from
//!   the ISB frames ([`crate::landmarks::frames`]) of the 6 joint landmarks
//!   and of the scaled model markers; position from the "vertebral body
//!   alignment": the centroid of the 8 scaled scaling markers is put on the
//!   centroid of the 8 scaling landmarks.
//! * [`Method::Lsq`]: rigid least-squares (Kabsch) fit of the 14 scaled
//!   model markers onto the 14 landmarks. One outlier per vertebra is
//!   rejected by a leave-one-out test: each landmark is predicted from a
//!   fit (and scaling) without it; its threshold is the larger of
//!   [`OUTLIER_MIN_MM`] and [`OUTLIER_SIGMAS`] times the per-axis noise
//!   estimated from the other 13 residuals of that fit (`3 n - 9` degrees
//!   of freedom: 6 pose and 3 scale parameters); the landmark with
//!   the largest error-to-threshold ratio is rejected when the ratio
//!   exceeds 1.

use crate::error::{Error, Result};
use crate::landmarks::{Code, Level};
use crate::mesh::umeyama;
use nalgebra::{Isometry3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use std::collections::BTreeMap;

/// Smallest prediction error (mm) that can flag a landmark as an outlier.
pub const OUTLIER_MIN_MM: f64 = 6.0;
/// Prediction error over the per-axis noise estimate that flags an outlier.
pub const OUTLIER_SIGMAS: f64 = 4.0;
/// Accepted range of a scale factor (beyond it the landmarks are wrong).
pub const SCALE_RANGE: [f64; 2] = [0.5, 2.0];

/// Pose-fit method.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// ISB joint frames from the 6 joint landmarks + body realignment (thesis).
    Thesis,
    /// Least-squares fit of all 14 landmarks with one-outlier rejection.
    Lsq,
}

impl std::str::FromStr for Method {
    type Err = Error;
    fn from_str(s: &str) -> Result<Method> {
        match s.trim().to_ascii_lowercase().as_str() {
            "thesis" => Ok(Method::Thesis),
            "lsq" => Ok(Method::Lsq),
            o => Err(Error::invalid(
                "--method",
                format!("'{o}' is not a method: expected 'thesis' or 'lsq'"),
            )),
        }
    }
}

impl std::fmt::Display for Method {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Method::Thesis => "thesis",
            Method::Lsq => "lsq",
        })
    }
}

/// Points of one vertebra by code.
pub type Points = BTreeMap<Code, Point3<f64>>;

/// Depth, height, width of a vertebra (m) by the module rule, leaving out
/// `exclude`.
pub fn dimensions(p: &Points, exclude: Option<Code>) -> [Option<f64>; 3] {
    let d = |a: Code, b: Code| -> Option<f64> {
        if exclude == Some(a) || exclude == Some(b) {
            return None;
        }
        Some((p.get(&a)? - p.get(&b)?).norm())
    };
    let mean = |v: &[Option<f64>]| -> Option<f64> {
        let x: Vec<f64> = v.iter().flatten().copied().collect();
        (!x.is_empty()).then(|| x.iter().sum::<f64>() / x.len() as f64)
    };
    [
        mean(&[d(Code::SA, Code::SP), d(Code::IA, Code::IP)]),
        mean(&[
            d(Code::SA, Code::IA),
            d(Code::SP, Code::IP),
            d(Code::SR, Code::IR),
            d(Code::SL, Code::IL),
        ]),
        mean(&[d(Code::SR, Code::SL), d(Code::IR, Code::IL)]),
    ]
}

/// Scale factors (X depth, Y height, Z width) patient / model.
pub fn scale_factors(
    level: Level,
    patient: &Points,
    model: &Points,
    exclude: Option<Code>,
) -> Result<Vector3<f64>> {
    let dp = dimensions(patient, exclude);
    let dm = dimensions(model, exclude);
    let names = ["depth", "height", "width"];
    let mut s = Vector3::zeros();
    for k in 0..3 {
        let (Some(a), Some(b)) = (dp[k], dm[k]) else {
            return Err(Error::invalid(
                format!("vertebra {level}"),
                format!(
                    "cannot measure the {} (scaling landmarks missing)",
                    names[k]
                ),
            ));
        };
        if b <= 1e-6 {
            return Err(Error::invalid(
                format!("base model vertebra {level}"),
                format!("its markers give a {} of {:.3} mm", names[k], b * 1e3),
            ));
        }
        let f = a / b;
        if !(SCALE_RANGE[0]..=SCALE_RANGE[1]).contains(&f) {
            return Err(Error::invalid(
                format!("landmarks of {level}"),
                format!(
                    "the vertebra's {} is {:.1} mm against {:.1} mm in the base model (scale {f:.2}, \
                     accepted {}..{}): coincident, misplaced or mislabelled landmarks",
                    names[k],
                    a * 1e3,
                    b * 1e3,
                    SCALE_RANGE[0],
                    SCALE_RANGE[1]
                ),
            ));
        }
        s[k] = f;
    }
    Ok(s)
}

/// Scale a body-frame point about the body origin.
pub fn scale_point(p: &Point3<f64>, s: &Vector3<f64>) -> Point3<f64> {
    Point3::from(p.coords.component_mul(s))
}

/// The result of one vertebra's fit.
#[derive(Debug, Clone, PartialEq)]
pub struct VertebraFit {
    /// Scale factors (X, Y, Z) applied in the body frame.
    pub scale: Vector3<f64>,
    /// Body pose in ground (after registration).
    pub pose: Isometry3<f64>,
    /// Residual of every landmark used (m): landmark - posed scaled marker.
    pub residuals: BTreeMap<Code, f64>,
    /// Rejected outlier: code and its leave-one-out prediction error (m).
    pub outlier: Option<(Code, f64)>,
    /// The leave-one-out candidate: code, prediction error and threshold
    /// (m), for the report (lsq only).
    pub loo_max: Option<(Code, f64, f64)>,
}

fn isometry(r: &Rotation3<f64>, t: &Vector3<f64>) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::from(*t),
        UnitQuaternion::from_rotation_matrix(r),
    )
}

/// ISB rotation (columns anterior, cranial, right) from SEC, IEC and the
/// pedicle landmarks.
fn isb_rotation(level: Level, p: &Points, what: &str) -> Result<Rotation3<f64>> {
    let g = |c: Code| {
        p.get(&c).copied().ok_or_else(|| {
            Error::invalid(
                format!("{what} of {level}"),
                format!("{level}_{c} is missing"),
            )
        })
    };
    let (sec, iec) = (g(Code::SEC)?, g(Code::IEC)?);
    let right = nalgebra::center(&g(Code::PTR)?, &g(Code::PBR)?);
    let left = nalgebra::center(&g(Code::PTL)?, &g(Code::PBL)?);
    crate::landmarks::frames::frame_from_axes(sec - iec, right - left).ok_or_else(|| {
        Error::invalid(
            format!("{what} of {level}"),
            "SEC/IEC coincide or the pedicle line is parallel to the SEC-IEC axis: no joint frame",
        )
    })
}

fn centroid(pts: &[Point3<f64>]) -> Point3<f64> {
    let n = pts.len().max(1) as f64;
    Point3::from(pts.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / n)
}

/// Refuse landmark sets that cannot determine a rotation: all points of the
/// vertebra within 1 mm of a line.
fn require_spread(level: Level, p: &[Point3<f64>]) -> Result<()> {
    let c = centroid(p);
    let mut cov = nalgebra::Matrix3::zeros();
    for q in p {
        let d = q - c;
        cov += d * d.transpose();
    }
    cov /= p.len().max(1) as f64;
    let mut ev: Vec<f64> = cov.symmetric_eigenvalues().iter().copied().collect();
    ev.sort_by(|a, b| b.total_cmp(a));
    let second = ev.get(1).copied().unwrap_or(0.0).max(0.0).sqrt();
    if second < 1e-3 {
        return Err(Error::invalid(
            format!("landmarks of {level}"),
            format!(
                "the landmarks are collinear or coincident (spread across their main line {:.2} mm): \
                 the vertebra's orientation is not determined",
                second * 1e3
            ),
        ));
    }
    Ok(())
}

fn residuals(
    pose: &Isometry3<f64>,
    patient: &Points,
    scaled: &Points,
    skip: Option<Code>,
) -> BTreeMap<Code, f64> {
    patient
        .iter()
        .filter(|(c, _)| Some(**c) != skip)
        .filter_map(|(c, p)| Some((*c, (p - pose * scaled.get(c)?).norm())))
        .collect()
}

fn scaled_points(model: &Points, s: &Vector3<f64>) -> Points {
    model.iter().map(|(c, p)| (*c, scale_point(p, s))).collect()
}

/// Rigid fit of the scaled model markers onto the landmarks (codes present
/// in both, minus `skip`).
fn kabsch(
    level: Level,
    patient: &Points,
    scaled: &Points,
    skip: Option<Code>,
) -> Result<Isometry3<f64>> {
    let mut src = Vec::new();
    let mut dst = Vec::new();
    for (c, p) in patient {
        if Some(*c) == skip {
            continue;
        }
        if let Some(m) = scaled.get(c) {
            src.push(*m);
            dst.push(*p);
        }
    }
    let s = umeyama(&src, &dst, false)
        .map_err(|e| Error::invalid(format!("landmarks of {level}"), e.to_string()))?;
    Ok(Isometry3::from_parts(
        Translation3::from(s.translation),
        s.rotation,
    ))
}

/// Fit one vertebra: `patient` landmarks (ground, after registration) and
/// `model` markers (body frame of the base model).
pub fn fit_vertebra(
    level: Level,
    patient: &Points,
    model: &Points,
    method: Method,
) -> Result<VertebraFit> {
    fit_vertebra_with(level, patient, model, method, OUTLIER_SIGMAS)
}

/// [`fit_vertebra`] with an explicit outlier threshold in noise SDs.
pub fn fit_vertebra_with(
    level: Level,
    patient: &Points,
    model: &Points,
    method: Method,
    outlier_sigmas: f64,
) -> Result<VertebraFit> {
    let pts: Vec<Point3<f64>> = patient.values().copied().collect();
    require_spread(level, &pts)?;
    match method {
        Method::Thesis => {
            let scale = scale_factors(level, patient, model, None)?;
            let scaled = scaled_points(model, &scale);
            let rp = isb_rotation(level, patient, "landmarks")?;
            let rm = isb_rotation(level, &scaled, "base model markers")?;
            let r = rp * rm.inverse();
            let scaling_codes = Code::ALL.iter().filter(|c| !c.is_joint_marker());
            let (mut a, mut b) = (Vec::new(), Vec::new());
            for c in scaling_codes {
                if let (Some(p), Some(m)) = (patient.get(c), scaled.get(c)) {
                    a.push(*p);
                    b.push(*m);
                }
            }
            if a.is_empty() {
                return Err(Error::invalid(
                    format!("landmarks of {level}"),
                    "no scaling landmarks",
                ));
            }
            let t = centroid(&a).coords - r * centroid(&b).coords;
            let pose = isometry(&r, &t);
            Ok(VertebraFit {
                scale,
                residuals: residuals(&pose, patient, &scaled, None),
                pose,
                outlier: None,
                loo_max: None,
            })
        }
        Method::Lsq => {
            // Leave-one-out prediction errors; the candidate is the
            // landmark whose error is largest relative to its threshold
            // (a displaced landmark inflates the noise estimate of every
            // other candidate's fit, not its own).
            let threshold = |sigma: f64| (OUTLIER_MIN_MM * 1e-3).max(outlier_sigmas * sigma);
            let mut worst: Option<(Code, f64, f64)> = None; // (code, error, threshold)
            if patient.len() >= 6 {
                for c in patient.keys() {
                    let s = match scale_factors(level, patient, model, Some(*c)) {
                        Ok(s) => s,
                        Err(_) => continue,
                    };
                    let scaled = scaled_points(model, &s);
                    let Ok(pose) = kabsch(level, patient, &scaled, Some(*c)) else {
                        continue;
                    };
                    let (Some(p), Some(m)) = (patient.get(c), scaled.get(c)) else {
                        continue;
                    };
                    let e = (p - pose * m).norm();
                    let others = residuals(&pose, patient, &scaled, Some(*c));
                    let n = others.len() as f64;
                    let ss: f64 = others.values().map(|r| r * r).sum();
                    let dof = (3.0 * n - 9.0).max(1.0);
                    let t = threshold((ss / dof).sqrt());
                    if worst.map(|w| e / t > w.1 / w.2).unwrap_or(true) {
                        worst = Some((*c, e, t));
                    }
                }
            }
            let outlier = worst.filter(|(_, e, t)| e > t).map(|(c, e, _)| (c, e));
            let skip = outlier.map(|o| o.0);
            let scale = scale_factors(level, patient, model, skip)?;
            let scaled = scaled_points(model, &scale);
            let pose = kabsch(level, patient, &scaled, skip)?;
            Ok(VertebraFit {
                scale,
                residuals: residuals(&pose, patient, &scaled, skip),
                pose,
                outlier,
                loo_max: worst,
            })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A box vertebra whose dimension pairs are axis-aligned (so that
    /// distance ratios are exactly the scale factors).
    fn box_vertebra() -> Points {
        let pts = [
            (Code::SEC, [0.0, 0.012, 0.0]),
            (Code::IEC, [0.0, -0.012, 0.0]),
            (Code::PTR, [-0.02, 0.008, 0.012]),
            (Code::PBR, [-0.02, -0.004, 0.012]),
            (Code::PTL, [-0.02, 0.008, -0.012]),
            (Code::PBL, [-0.02, -0.004, -0.012]),
            (Code::SA, [0.017, 0.012, 0.0]),
            (Code::SP, [-0.017, 0.012, 0.0]),
            (Code::SR, [0.0, 0.012, 0.021]),
            (Code::SL, [0.0, 0.012, -0.021]),
            (Code::IA, [0.017, -0.012, 0.0]),
            (Code::IP, [-0.017, -0.012, 0.0]),
            (Code::IR, [0.0, -0.012, 0.021]),
            (Code::IL, [0.0, -0.012, -0.021]),
        ];
        pts.iter()
            .map(|(c, p)| (*c, Point3::new(p[0], p[1] + 0.02, p[2])))
            .collect()
    }

    fn transform(p: &Points, s: &Vector3<f64>, x: &Isometry3<f64>) -> Points {
        p.iter().map(|(c, q)| (*c, x * scale_point(q, s))).collect()
    }

    #[test]
    fn both_methods_recover_a_scaled_and_moved_vertebra_exactly() {
        let model = box_vertebra();
        let s = Vector3::new(1.1, 0.9, 1.2);
        let x = Isometry3::new(Vector3::new(0.1, 0.4, -0.03), Vector3::new(0.2, -0.5, 0.3));
        let patient = transform(&model, &s, &x);
        for m in [Method::Thesis, Method::Lsq] {
            let f = fit_vertebra(Level::L2, &patient, &model, m).unwrap();
            assert!((f.scale - s).norm() < 1e-12, "{m}: {}", f.scale);
            let d = f.pose.inverse() * x;
            assert!(d.translation.vector.norm() < 1e-12 && d.rotation.angle() < 1e-12);
            assert!(f.outlier.is_none());
        }
    }

    #[test]
    fn lsq_flags_one_displaced_landmark_and_ignores_it() {
        let model = box_vertebra();
        let x = Isometry3::new(Vector3::new(0.0, 0.3, 0.0), Vector3::new(0.0, 0.0, 0.4));
        let mut patient = transform(&model, &Vector3::repeat(1.0), &x);
        for code in [Code::SA, Code::PTL, Code::IR] {
            let mut p = patient.clone();
            if let Some(q) = p.get_mut(&code) {
                *q += Vector3::new(0.008, -0.006, 0.0064); // 11.9 mm
            }
            let f = fit_vertebra(Level::L2, &p, &model, Method::Lsq).unwrap();
            assert_eq!(f.outlier.map(|o| o.0), Some(code));
            let d = f.pose.inverse() * x;
            assert!(d.translation.vector.norm() < 1e-9 && d.rotation.angle() < 1e-9);
        }
        // Clean: nothing flagged.
        patient.insert(Code::SA, patient[&Code::SA]);
        let f = fit_vertebra(Level::L2, &patient, &model, Method::Lsq).unwrap();
        assert!(f.outlier.is_none());
    }

    #[test]
    fn collinear_and_coincident_landmarks_are_refused() {
        let model = box_vertebra();
        let line: Points = model
            .keys()
            .enumerate()
            .map(|(i, c)| (*c, Point3::new(0.0, 0.003 * i as f64, 0.0)))
            .collect();
        let e = fit_vertebra(Level::L1, &line, &model, Method::Lsq).unwrap_err();
        assert!(e.to_string().contains("collinear"), "{e}");
        let same: Points = model
            .keys()
            .map(|c| (*c, Point3::new(0.1, 0.2, 0.3)))
            .collect();
        let e = fit_vertebra(Level::L1, &same, &model, Method::Thesis).unwrap_err();
        assert!(e.to_string().contains("coincident"), "{e}");
    }
}
