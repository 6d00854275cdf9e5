//! Per-vertebra local frames and dimensions from landmarks.
//!
//! ISB-style frame (Wu et al. 2002), built from the joint markers:
//! - origin: mid-point of `SEC` and `IEC`;
//! - cranial axis `y`: `IEC -> SEC`;
//! - right axis `z`: from the left pedicle landmarks to the right ones
//!   (mean of `PTL`/`PBL` to mean of `PTR`/`PBR`), made orthogonal to `y`;
//! - anterior axis `x = y x z` (right-handed: x anterior, y superior, z right,
//!   the OpenSim convention).
//!
//! Dimensions from the 8 scaling markers: depth (`SA-SP`, `IA-IP`), width
//! (`SR-SL`, `IR-IL`) and height (mean of `SA-IA`, `SP-IP`, `SR-IR`,
//! `SL-IL`). The patient model generator uses both.

use super::{Code, LandmarkSet, Level};
use nalgebra::{Matrix3, Point3, Rotation3, Vector3};

/// A vertebra's landmark-based local frame (OpenSim/ground coordinates).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VertebraFrame {
    /// The vertebral level.
    pub level: Level,
    /// Mid-point of SEC and IEC (m).
    pub origin: Point3<f64>,
    /// Columns: anterior (x), cranial (y), right (z) unit axes.
    pub rotation: Rotation3<f64>,
}

impl VertebraFrame {
    /// Anterior unit axis (x) in ground.
    pub fn anterior(&self) -> Vector3<f64> {
        self.rotation.matrix().column(0).into()
    }
    /// Cranial unit axis (y) in ground.
    pub fn cranial(&self) -> Vector3<f64> {
        self.rotation.matrix().column(1).into()
    }
    /// Right unit axis (z) in ground.
    pub fn right(&self) -> Vector3<f64> {
        self.rotation.matrix().column(2).into()
    }
    /// Express a ground point in this frame.
    pub fn to_local(&self, p: &Point3<f64>) -> Vector3<f64> {
        self.rotation.inverse() * (p - self.origin)
    }
}

/// A right-handed frame from a cranial direction and an approximate right
/// direction (`None` when degenerate: zero or parallel vectors).
pub fn frame_from_axes(
    cranial: Vector3<f64>,
    right_approx: Vector3<f64>,
) -> Option<Rotation3<f64>> {
    let y = cranial.try_normalize(1e-12)?;
    let z = (right_approx - y * y.dot(&right_approx)).try_normalize(1e-9)?;
    let x = y.cross(&z);
    Some(Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[
        x, y, z,
    ])))
}

/// ISB-style frame of `level`, or `None` when SEC, IEC or the pedicles are
/// missing or degenerate.
pub fn vertebra_frame(set: &LandmarkSet, level: Level) -> Option<VertebraFrame> {
    let g = |c| set.get(level, c);
    let sec = g(Code::SEC)?;
    let iec = g(Code::IEC)?;
    let right = mean_of(&[g(Code::PTR), g(Code::PBR)])?;
    let left = mean_of(&[g(Code::PTL), g(Code::PBL)])?;
    let rotation = frame_from_axes(sec - iec, right - left)?;
    Some(VertebraFrame {
        level,
        origin: nalgebra::center(&sec, &iec),
        rotation,
    })
}

/// Mean of the present points (`None` if none present).
pub fn mean_of(points: &[Option<Point3<f64>>]) -> Option<Point3<f64>> {
    let v: Vec<Point3<f64>> = points.iter().flatten().copied().collect();
    if v.is_empty() {
        return None;
    }
    let s = v.iter().fold(Vector3::zeros(), |a, p| a + p.coords);
    Some(Point3::from(s / v.len() as f64))
}

/// Vertebral dimensions from the scaling markers (m). A field is `None`
/// when its landmarks are missing.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize)]
pub struct VertebraDimensions {
    /// Superior endplate depth, anterior-posterior (m).
    pub sup_depth: Option<f64>,
    /// Inferior endplate depth, anterior-posterior (m).
    pub inf_depth: Option<f64>,
    /// Superior endplate width, left-right (m).
    pub sup_width: Option<f64>,
    /// Inferior endplate width, left-right (m).
    pub inf_width: Option<f64>,
    /// Mean of the four superior-inferior distances that are present.
    pub height: Option<f64>,
}

impl VertebraDimensions {
    /// Mean depth (superior and inferior endplates).
    pub fn depth(&self) -> Option<f64> {
        mean_opt(&[self.sup_depth, self.inf_depth])
    }
    /// Mean width (superior and inferior endplates).
    pub fn width(&self) -> Option<f64> {
        mean_opt(&[self.sup_width, self.inf_width])
    }
}

fn mean_opt(v: &[Option<f64>]) -> Option<f64> {
    let p: Vec<f64> = v.iter().flatten().copied().collect();
    if p.is_empty() {
        None
    } else {
        Some(p.iter().sum::<f64>() / p.len() as f64)
    }
}

/// Dimensions of `level` from its scaling markers.
pub fn vertebra_dimensions(set: &LandmarkSet, level: Level) -> VertebraDimensions {
    let d = |a, b| Some((set.get(level, a)? - set.get(level, b)?).norm());
    VertebraDimensions {
        sup_depth: d(Code::SA, Code::SP),
        inf_depth: d(Code::IA, Code::IP),
        sup_width: d(Code::SR, Code::SL),
        inf_width: d(Code::IR, Code::IL),
        height: mean_opt(&[
            d(Code::SA, Code::IA),
            d(Code::SP, Code::IP),
            d(Code::SR, Code::IR),
            d(Code::SL, Code::IL),
        ]),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_of_a_rotated_box_vertebra_recovers_the_rotation() {
        // Landmarks of an axis-aligned vertebra, then rotate and translate.
        let mut s = LandmarkSet::new();
        let l = Level::L2;
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
            (Code::IA, [0.018, -0.012, 0.0]),
            (Code::IP, [-0.018, -0.012, 0.0]),
            (Code::IR, [0.0, -0.012, 0.022]),
            (Code::IL, [0.0, -0.012, -0.022]),
        ];
        for (c, p) in pts {
            s.insert(l, c, Point3::from(p));
        }
        let r = Rotation3::from_euler_angles(0.3, -0.2, 0.5);
        let t = Vector3::new(0.1, 0.5, -0.02);
        let moved = s.transformed(r.matrix(), &t);
        let f = vertebra_frame(&moved, l).unwrap();
        assert!((f.rotation.matrix() - r.matrix()).norm() < 1e-12);
        assert!((f.origin.coords - t).norm() < 1e-12);
        let d = vertebra_dimensions(&moved, l);
        assert!((d.sup_depth.unwrap() - 0.034).abs() < 1e-12);
        assert!((d.inf_width.unwrap() - 0.044).abs() < 1e-12);
        // Inferior endplate 1 mm wider/deeper: the four heights are sqrt(24^2 + 1^2) mm.
        assert!((d.height.unwrap() - (0.024f64.powi(2) + 0.001f64.powi(2)).sqrt()).abs() < 1e-12);
    }
}
