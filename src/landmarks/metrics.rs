//! Spine-shape metrics (pure functions, ground frame of the model: X
//! anterior, Y superior, Z right; frontal plane Y-Z, sagittal plane X-Y).
//!
//! * Endplate lines as a radiograph shows them. Each endplate is the
//!   least-squares plane through its rim landmarks and centre (superior:
//!   `SA`, `SP`, `SR`, `SL`, `SEC`; inferior: `IA`, `IP`, `IR`, `IL`,
//!   `IEC`), normal `n` oriented cranially (along `SEC - IEC`; for S1
//!   along ground's Y). A frontal
//!   radiograph sees the endplate (a thin disc nearly edge-on to the beam)
//!   as a line along the intersection of its plane with the frontal plane,
//!   direction `e_x x n`; the lateral view likewise along `n x e_z`. These
//!   lines do not depend on the vertebra's axial rotation, unlike the
//!   projected lateral diameter `SR - SL`, whose frontal projection shortens
//!   by the cosine of the axial rotation and so exaggerates the tilt (by
//!   14 deg of Cobb angle on a 84 deg curve whose apical vertebrae are
//!   rotated 40-50 deg) and picks up the sagittal rotation noise of a fit
//!   in proportion to the rotation. The lines are undefined only when the
//!   endplate faces the beam (`n` within [`EDGE_ON_MIN`] of the view axis,
//!   an endplate inclined by more than about 84 deg): then no tilt.
//! * Frontal tilt of an endplate: `atan2(n.z, n.y)` (positive when the
//!   right end is lower, i.e. the endplate faces to the right). **Cobb
//!   angle** of the main curve:
//!   `tilt(inferior endplate of the lower end vertebra) - tilt(superior
//!   endplate of the upper end vertebra)`; the end vertebrae, when not
//!   given, are the pair (upper at or above lower) with the largest
//!   absolute difference. Positive: the curve is convex to the right.
//!   The **secondary** curve is the largest of the opposite sign. A frontal
//!   radiograph gives the same tilts from its endplate lines (`SR`-`SL`,
//!   `IR`-`IL` on the film, [`frontal_tilt_of_line`]), so the films' Cobb
//!   angles come from the same [`cobb_of_tilts`].
//! * Sagittal tilt: `atan2(n.x, n.y)` (positive when the anterior end is
//!   lower, i.e. the endplate faces anteriorly). **Lumbar lordosis** =
//!   `tilt(L1 superior) - tilt(S1 superior)` (the sacral slope enters
//!   through S1), negative for a lordotic spine as in the thesis (Table
//!   5.2: -34 deg supine).
//! * **Apex** of the main curve: the vertebra between the end vertebrae
//!   whose centre lies farthest, in the frontal plane, from the straight
//!   line through the end vertebrae's centres.
//! * **Curves**: 4th-order polynomials `v(h)` (v = X sagittal or Z
//!   frontal, h = Y) fitted by least squares to the truth centres and to
//!   the model centres; curve RMSE = RMS of `p_model(h) - p_truth(h)` over
//!   the truth heights, `R2 = 1 - sum (p_model - p_truth)^2 / sum (v_truth
//!   - mean)^2`. Identical spines give 0 and 1. The order drops to
//!   `n - 2` when fewer than 6 centres are available (reported).

use crate::landmarks::{Code, LandmarkSet, Level};
use nalgebra::{DMatrix, DVector, Point3, Vector3};
use std::collections::BTreeMap;

/// Smallest length of the endplate normal's projection on a view plane
/// (sine of the angle between the normal and the view axis) for which the
/// endplate's line in that view is defined.
pub(crate) const EDGE_ON_MIN: f64 = 0.1;

/// Frontal and sagittal tilts (rad) of an endplate of unit normal `n`
/// (oriented cranially): the angles of the lines where the endplate plane
/// meets the frontal and the sagittal plane. `None` for a view in which the
/// endplate faces the beam.
pub fn tilts(n: &Vector3<f64>) -> (Option<f64>, Option<f64>) {
    let frontal = (n.y.hypot(n.z) >= EDGE_ON_MIN).then(|| n.z.atan2(n.y));
    let sagittal = (n.y.hypot(n.x) >= EDGE_ON_MIN).then(|| n.x.atan2(n.y));
    (frontal, sagittal)
}

/// Unit normal of the least-squares plane through `pts`, oriented along
/// `up`; `None` when the points do not span a plane (collinear or
/// coincident within 1e-9 m) or `up` lies in it.
pub(crate) fn plane_normal(pts: &[Point3<f64>], up: &Vector3<f64>) -> Option<Vector3<f64>> {
    if pts.len() < 3 {
        return None;
    }
    let c = pts.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / pts.len() as f64;
    let mut cov = nalgebra::Matrix3::zeros();
    for p in pts {
        let d = p.coords - c;
        cov += d * d.transpose();
    }
    let e = cov.symmetric_eigen();
    let mut order = [0usize, 1, 2];
    order.sort_by(|a, b| e.eigenvalues[*a].total_cmp(&e.eigenvalues[*b]));
    // The two in-plane spreads must be real (a plane, not a line).
    if e.eigenvalues[order[1]].max(0.0).sqrt() < 1e-9 {
        return None;
    }
    let n: Vector3<f64> = e.eigenvectors.column(order[0]).into();
    let d = n.dot(up);
    if !d.is_finite() || d.abs() < 1e-12 {
        return None;
    }
    Some(if d < 0.0 { -n } else { n })
}

/// Frontal and sagittal tilt of one endplate (rad); `None` for a view in
/// which it faces the beam.
pub(crate) type Tilts = (Option<f64>, Option<f64>);

/// Frontal and sagittal tilts (rad) of the superior and inferior endplates
/// of a level (`None` when landmarks are missing or the endplate is
/// degenerate).
pub(crate) fn endplate_tilts(set: &LandmarkSet, level: Level) -> (Option<Tilts>, Option<Tilts>) {
    let g = |c| set.get(level, c);
    // Cranial direction of the vertebra; S1 has no inferior endplate
    // landmarks: ground's superior axis.
    let up = match (g(Code::SEC), g(Code::IEC)) {
        (Some(s), Some(i)) => Some(s - i),
        _ if level.is_sacrum() => Some(Vector3::y()),
        _ => None,
    };
    let t = |codes: [Code; 5]| -> Option<Tilts> {
        let pts: Option<Vec<Point3<f64>>> = codes.iter().map(|c| g(*c)).collect();
        let n = plane_normal(&pts?, &up?)?;
        Some(tilts(&n))
    };
    (
        t([Code::SA, Code::SP, Code::SR, Code::SL, Code::SEC]),
        t([Code::IA, Code::IP, Code::IR, Code::IL, Code::IEC]),
    )
}

/// Cobb angle of the main curve.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Cobb {
    /// Signed angle (deg), positive convex to the right.
    pub angle_deg: f64,
    /// Upper end vertebra (e.g. `T11`).
    pub upper: Level,
    /// Lower end vertebra (e.g. `L4`).
    pub lower: Level,
    /// Whether the end vertebrae were found automatically.
    pub automatic: bool,
}

/// Frontal tilts (rad) of each level's superior and inferior endplate.
pub type FrontalTilts = BTreeMap<Level, (Option<f64>, Option<f64>)>;

/// Frontal tilt (rad) of an endplate line as a frontal radiograph shows it,
/// from its right and left ends in film coordinates `(u, v)` (`u` towards
/// the patient's left, `v` cranial): the tilt of [`tilts`] of the endplate
/// whose trace is that line, `atan2(v_L - v_R, u_L - u_R)` (with `u = -z`,
/// the normal of a line from R to L is `(n_z, n_y) = (dy, -dz)`), positive
/// when the right end is lower.
pub fn frontal_tilt_of_line(right: (f64, f64), left: (f64, f64)) -> Option<f64> {
    let (du, dv) = (left.0 - right.0, left.1 - right.1);
    (du.hypot(dv) > 1e-12 && du > 0.0).then(|| dv.atan2(du))
}

/// Frontal tilts of every vertebra of `set` (S1 excluded).
pub(crate) fn frontal_tilts(set: &LandmarkSet) -> FrontalTilts {
    set.levels()
        .into_iter()
        .filter(|l| !l.is_sacrum())
        .map(|l| {
            let (s, i) = endplate_tilts(set, l);
            (l, (s.and_then(|t| t.0), i.and_then(|t| t.0)))
        })
        .collect()
}

/// Cobb angle from the endplates of the vertebrae in `set` (S1 excluded);
/// `ends` fixes the end vertebrae (upper, lower).
pub fn cobb(set: &LandmarkSet, ends: Option<(Level, Level)>) -> Option<Cobb> {
    cobb_of_tilts(&frontal_tilts(set), ends)
}

/// The curve between `u` (superior endplate) and `w` (inferior endplate),
/// rad.
fn curve_angle(frontal: &FrontalTilts, u: Level, w: Level) -> Option<f64> {
    Some(frontal.get(&w)?.1? - frontal.get(&u)?.0?)
}

/// Cobb angle from per-level frontal endplate tilts (a landmark set's, or
/// a radiograph's endplate lines); `ends` fixes the end vertebrae (upper,
/// lower), else the pair with the largest absolute angle.
pub fn cobb_of_tilts(frontal: &FrontalTilts, ends: Option<(Level, Level)>) -> Option<Cobb> {
    let (u, w, a, auto) = match ends {
        Some((u, w)) => (u, w, curve_angle(frontal, u, w)?, false),
        None => {
            let (u, w, a) = largest_curve(frontal, |_| true)?;
            (u, w, a, true)
        }
    };
    Some(Cobb {
        angle_deg: a.to_degrees(),
        upper: u,
        lower: w,
        automatic: auto,
    })
}

/// The curve of largest magnitude among those whose angle passes `keep`:
/// (upper, lower, angle rad).
fn largest_curve(
    frontal: &FrontalTilts,
    keep: impl Fn(f64) -> bool,
) -> Option<(Level, Level, f64)> {
    let levels: Vec<Level> = frontal.keys().copied().collect();
    let mut best: Option<(Level, Level, f64)> = None;
    for (i, u) in levels.iter().enumerate() {
        for w in &levels[i..] {
            if let Some(a) = curve_angle(frontal, *u, *w).filter(|a| keep(*a)) {
                if best.map(|b| a.abs() > b.2.abs()).unwrap_or(true) {
                    best = Some((*u, *w, a));
                }
            }
        }
    }
    best
}

/// The secondary curve: the largest curve of the opposite sign to the main
/// curve `main` (end vertebrae found the same way); `None` without one.
pub fn secondary_of_tilts(frontal: &FrontalTilts, main: &Cobb) -> Option<Cobb> {
    let sign = main.angle_deg.signum();
    let (u, w, a) = largest_curve(frontal, |a| a * sign < 0.0)?;
    Some(Cobb {
        angle_deg: a.to_degrees(),
        upper: u,
        lower: w,
        automatic: true,
    })
}

/// Lumbar lordosis (deg): sagittal tilt of L1's superior endplate minus
/// that of S1 (negative for lordosis).
pub fn lordosis(set: &LandmarkSet) -> Option<f64> {
    let l1 = endplate_tilts(set, Level::L1).0?.1?;
    let s1 = endplate_tilts(set, Level::S1).0?.1?;
    Some((l1 - s1).to_degrees())
}

/// Thoracic kyphosis T4-T12 (deg): sagittal tilt of T12's inferior
/// endplate minus that of T4's superior endplate (positive kyphotic).
pub fn kyphosis(set: &LandmarkSet) -> Option<f64> {
    let t4 = endplate_tilts(set, Level::T4).0?.1?;
    let t12 = endplate_tilts(set, Level::T12).1?.1?;
    Some((t4 - t12).to_degrees())
}

/// The shape of a spine in one table (ground frame).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Shape {
    /// Main curve (end vertebrae found automatically), positive convex to
    /// the right.
    pub cobb: Option<Cobb>,
    /// Apex of the main curve (farthest from the line through its ends).
    pub apex: Option<Level>,
    /// Lumbar lordosis L1-S1, negative lordotic.
    pub lumbar_lordosis_deg: Option<f64>,
    /// Thoracic kyphosis T4-T12, positive kyphotic.
    pub kyphosis_t4_t12_deg: Option<f64>,
    /// Sacral slope (deg): the S1 endplate's angle to the horizontal.
    pub sacral_slope_deg: Option<f64>,
    /// The conventions of the numbers above.
    pub conventions: &'static str,
}

/// Cobb angle, apex, lordosis, kyphosis and sacral slope of a set whose
/// vertebral centres are `centres`.
pub fn shape(set: &LandmarkSet, centres: &BTreeMap<Level, Point3<f64>>) -> Shape {
    let cobb = cobb(set, None);
    let apex = cobb.as_ref().and_then(|c| apex(centres, c.upper, c.lower));
    Shape {
        cobb,
        apex,
        lumbar_lordosis_deg: lordosis(set),
        kyphosis_t4_t12_deg: kyphosis(set),
        sacral_slope_deg: sacral_slope(set),
        conventions: "ground frame (X anterior, Y up, Z right); endplate lines are the traces of each endplate's least-squares plane in the frontal and sagittal planes; Cobb = tilt(lower end's inferior endplate) - tilt(upper end's superior endplate), positive convex to the right, ends with the largest magnitude; lordosis = sagittal tilt(L1 superior) - tilt(S1 superior), negative lordotic; kyphosis = tilt(T4 superior) - tilt(T12 inferior), positive kyphotic",
    }
}

/// Sacral slope (deg): sagittal tilt of the S1 endplate.
pub fn sacral_slope(set: &LandmarkSet) -> Option<f64> {
    Some(endplate_tilts(set, Level::S1).0?.1?.to_degrees())
}

/// Apex: the level in `upper..=lower` farthest (frontal plane) from the
/// line through the end levels' centres.
pub fn apex(centres: &BTreeMap<Level, Point3<f64>>, upper: Level, lower: Level) -> Option<Level> {
    let (a, b) = (centres.get(&upper)?, centres.get(&lower)?);
    let (a2, b2) = ((a.y, a.z), (b.y, b.z));
    let d = (b2.0 - a2.0, b2.1 - a2.1);
    let len = (d.0 * d.0 + d.1 * d.1).sqrt();
    let mut best: Option<(Level, f64)> = None;
    for (l, p) in centres.range(upper..=lower) {
        let dist = if len > 1e-12 {
            ((p.y - a2.0) * d.1 - (p.z - a2.1) * d.0).abs() / len
        } else {
            ((p.y - a2.0).powi(2) + (p.z - a2.1).powi(2)).sqrt()
        };
        if best.map(|x| dist > x.1).unwrap_or(true) {
            best = Some((*l, dist));
        }
    }
    best.map(|b| b.0)
}

/// Least-squares polynomial (coefficients in powers of `(x - x0) / xs`,
/// returned with `x0`, `xs`).
#[derive(Debug, Clone, PartialEq)]
pub struct Poly {
    /// Coefficients, constant first.
    pub coef: Vec<f64>,
    /// Centre of the x values.
    pub x0: f64,
    /// Half-range of the x values about `x0`.
    pub xs: f64,
}

impl Poly {
    /// The polynomial's value at `x`.
    pub fn eval(&self, x: f64) -> f64 {
        let t = (x - self.x0) / self.xs;
        self.coef.iter().rev().fold(0.0, |a, c| a * t + c)
    }
}

/// Fit a polynomial of `order` to (x, y) (needs more than `order` points
/// with distinct x).
pub fn polyfit(x: &[f64], y: &[f64], order: usize) -> Option<Poly> {
    let n = x.len();
    if n != y.len() || n <= order {
        return None;
    }
    let x0 = x.iter().sum::<f64>() / n as f64;
    let xs = x.iter().map(|v| (v - x0).abs()).fold(0.0, f64::max);
    if xs <= 0.0 || !xs.is_finite() {
        return None;
    }
    let a = DMatrix::from_fn(n, order + 1, |i, j| ((x[i] - x0) / xs).powi(j as i32));
    let b = DVector::from_column_slice(y);
    let svd = a.svd(true, true);
    let sol = svd.solve(&b, 1e-12).ok()?;
    Some(Poly {
        coef: sol.iter().copied().collect(),
        x0,
        xs,
    })
}

/// Comparison of the model's curve with the truth's in one plane.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct CurveFit {
    /// Polynomial order used.
    pub order: usize,
    /// RMS difference of the two polynomials at the truth's heights (mm).
    pub rmse_mm: f64,
    /// `1 - SS_res / SS_tot`: the two polynomials' squared differences over the truth's variance.
    pub r2: f64,
    /// RMS residual of each polynomial fit to its own centres (mm).
    pub truth_fit_rms_mm: f64,
    /// RMS residual of the model's polynomial to its own centres (mm).
    pub model_fit_rms_mm: f64,
}

/// Curve comparison (module rule) of truth and model samples `(h, v)`.
pub fn curve_compare(truth: &[(f64, f64)], model: &[(f64, f64)]) -> Option<CurveFit> {
    let n = truth.len().min(model.len());
    let order = 4.min(n.checked_sub(2)?);
    if order == 0 {
        return None;
    }
    let split = |s: &[(f64, f64)]| -> (Vec<f64>, Vec<f64>) { s.iter().copied().unzip() };
    let (ht, vt) = split(truth);
    let (hm, vm) = split(model);
    let pt = polyfit(&ht, &vt, order)?;
    let pm = polyfit(&hm, &vm, order)?;
    let own = |p: &Poly, h: &[f64], v: &[f64]| {
        (h.iter()
            .zip(v)
            .map(|(a, b)| (p.eval(*a) - b).powi(2))
            .sum::<f64>()
            / h.len() as f64)
            .sqrt()
    };
    let mean = vt.iter().sum::<f64>() / vt.len() as f64;
    let ss_tot: f64 = vt.iter().map(|v| (v - mean).powi(2)).sum();
    let ss_res: f64 = ht.iter().map(|h| (pm.eval(*h) - pt.eval(*h)).powi(2)).sum();
    Some(CurveFit {
        order,
        rmse_mm: (ss_res / ht.len() as f64).sqrt() * 1e3,
        r2: if ss_tot > 0.0 {
            1.0 - ss_res / ss_tot
        } else {
            f64::NAN
        },
        truth_fit_rms_mm: own(&pt, &ht, &vt) * 1e3,
        model_fit_rms_mm: own(&pm, &hm, &vm) * 1e3,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An endplate disc whose plane contains the frontal line of tilt
    /// `alpha` and the sagittal line of tilt `beta`, its rim landmarks on
    /// diameters turned by `theta` about the normal (axial rotation).
    fn endplate(alpha: f64, beta: f64, theta: f64) -> LandmarkSet {
        let df = Vector3::new(0.0, -alpha.sin(), alpha.cos());
        let ds = Vector3::new(beta.cos(), -beta.sin(), 0.0);
        let n = df.cross(&ds).normalize();
        let n = if n.y < 0.0 { -n } else { n };
        // Orthonormal in-plane basis, then turned by theta.
        let e1 = ds.normalize();
        let e2 = n.cross(&e1);
        let (a, r) = (
            e1 * theta.cos() + e2 * theta.sin(),
            -e1 * theta.sin() + e2 * theta.cos(),
        );
        let c = Point3::new(0.01, 0.3, -0.02);
        let mut set = LandmarkSet::new();
        let mut put = |code, p: Point3<f64>| {
            set.points.insert(
                crate::landmarks::LandmarkId {
                    level: Level::L2,
                    code,
                },
                p,
            );
        };
        put(Code::SEC, c);
        put(Code::SA, c + a * 0.017);
        put(Code::SP, c - a * 0.015);
        put(Code::SR, c + r * 0.022);
        put(Code::SL, c - r * 0.020);
        put(Code::IEC, c - n * 0.025);
        set
    }

    #[test]
    fn endplate_tilts_are_the_radiographic_lines_whatever_the_axial_rotation() {
        for (alpha, beta) in [(0.0, 0.0), (30.0, -10.0), (-45.0, 25.0), (10.0, 40.0)] {
            let (alpha, beta) = (f64::to_radians(alpha), f64::to_radians(beta));
            for theta in [-50.0, -20.0, 0.0, 15.0, 45.0] {
                let set = endplate(alpha, beta, f64::to_radians(theta));
                let (sup, _) = endplate_tilts(&set, Level::L2);
                let (f, s) = sup.unwrap();
                // tan(frontal) = tan(alpha) and tan(sagittal) = tan(beta):
                // the lines in the two views are the plane's traces.
                assert!((f.unwrap() - alpha).abs() < 1e-9, "{f:?} vs {alpha}");
                assert!((s.unwrap() - beta).abs() < 1e-9, "{s:?} vs {beta}");
            }
        }
    }

    #[test]
    fn endplate_facing_the_beam_has_no_tilt_and_degenerate_plane_none() {
        // Normal along X (endplate facing the frontal beam): no frontal line.
        let (f, s) = tilts(&Vector3::new(1.0, 0.05, 0.0).normalize());
        assert!(f.is_none());
        assert!((s.unwrap() - (1.0f64).atan2(0.05)).abs() < 1e-12);
        let line = [
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(0.0, 0.0, 0.01),
            Point3::new(0.0, 0.0, 0.02),
        ];
        assert!(plane_normal(&line, &Vector3::y()).is_none());
    }

    #[test]
    fn polyfit_recovers_a_quartic() {
        let f = |x: f64| 0.3 - 2.0 * x + 0.5 * x * x - 0.1 * x.powi(3) + 0.02 * x.powi(4);
        let x: Vec<f64> = (0..9).map(|i| i as f64 * 0.37 - 1.0).collect();
        let y: Vec<f64> = x.iter().map(|v| f(*v)).collect();
        let p = polyfit(&x, &y, 4).unwrap();
        for v in [-1.0, 0.0, 0.7, 2.0] {
            assert!((p.eval(v) - f(v)).abs() < 1e-9);
        }
    }

    #[test]
    fn identical_curves_compare_perfectly() {
        let s: Vec<(f64, f64)> = (0..8)
            .map(|i| (i as f64 * 0.03, (i as f64).sin() * 0.01))
            .collect();
        let c = curve_compare(&s, &s).unwrap();
        assert_eq!(c.order, 4);
        assert!(c.rmse_mm < 1e-9 && (c.r2 - 1.0).abs() < 1e-12);
    }
}
