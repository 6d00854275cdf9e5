//! Placing a film on the model: the in-plane rigid motion (rotation `phi`,
//! translation `t`) that takes the model's frontal projection `m` to the
//! film, `f = R(phi) m + t`, first from the pelvic points alone (2-D
//! Procrustes, no reflection: a film whose sides are swapped does not fit),
//! then refined with every point in the fit.

use nalgebra::{Matrix2, Vector2};

/// An in-plane rigid motion: model frontal plane -> film (m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Placement {
    /// Rotation (rad), counter-clockwise on the film.
    pub phi: f64,
    /// Translation (m).
    pub t: Vector2<f64>,
}

impl Placement {
    /// The rotation matrix.
    pub fn rotation(&self) -> Matrix2<f64> {
        let (s, c) = self.phi.sin_cos();
        Matrix2::new(c, -s, s, c)
    }

    /// `R m + t`.
    pub fn apply(&self, m: &Vector2<f64>) -> Vector2<f64> {
        self.rotation() * m + self.t
    }

    /// `R^T (f - t)`: a film point in the model's frontal plane.
    pub fn inverse_apply(&self, f: &Vector2<f64>) -> Vector2<f64> {
        self.rotation().transpose() * (f - self.t)
    }

    /// Derivative of `R m + t` with respect to `phi` (the columns for `t`
    /// are the identity).
    pub fn d_phi(&self, m: &Vector2<f64>) -> Vector2<f64> {
        let (s, c) = self.phi.sin_cos();
        Matrix2::new(-s, -c, c, -s) * m
    }
}

/// The least-squares rigid motion taking `model[i]` to `film[i]` (2-D
/// Procrustes without reflection) and its RMS residual (m). At least two
/// distinct points.
pub fn procrustes(model: &[Vector2<f64>], film: &[Vector2<f64>]) -> Option<(Placement, f64)> {
    let n = model.len();
    if n < 2 || film.len() != n {
        return None;
    }
    let cm = model.iter().sum::<Vector2<f64>>() / n as f64;
    let cf = film.iter().sum::<Vector2<f64>>() / n as f64;
    let (mut dot, mut cross) = (0.0, 0.0);
    for (m, f) in model.iter().zip(film) {
        let (a, b) = (m - cm, f - cf);
        dot += a.dot(&b);
        cross += a.x * b.y - a.y * b.x;
    }
    if dot.hypot(cross) < 1e-12 {
        return None;
    }
    let mut p = Placement {
        phi: cross.atan2(dot),
        t: Vector2::zeros(),
    };
    p.t = cf - p.rotation() * cm;
    let ss: f64 = model
        .iter()
        .zip(film)
        .map(|(m, f)| (p.apply(m) - f).norm_squared())
        .sum();
    Some((p, (ss / n as f64).sqrt()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_a_motion_and_refuses_a_mirror() {
        let m = [
            Vector2::new(0.0, 0.0),
            Vector2::new(0.15, 0.0),
            Vector2::new(0.07, 0.15),
        ];
        let truth = Placement {
            phi: 0.05,
            t: Vector2::new(0.2, 1.3),
        };
        let f: Vec<_> = m.iter().map(|x| truth.apply(x)).collect();
        let (p, rms) = procrustes(&m, &f).unwrap();
        assert!((p.phi - 0.05).abs() < 1e-12 && (p.t - truth.t).norm() < 1e-12 && rms < 1e-12);
        // the mirror image cannot be reached by a rotation
        let mirrored: Vec<_> = f.iter().map(|x| Vector2::new(-x.x, x.y)).collect();
        assert!(procrustes(&m, &mirrored).unwrap().1 > 0.02);
        // d_phi by finite differences
        let x = Vector2::new(0.3, -0.2);
        let h = 1e-7;
        let q = Placement {
            phi: p.phi + h,
            ..p
        };
        let fd = (q.apply(&x) - p.apply(&x)) / h;
        assert!((fd - p.d_phi(&x)).norm() < 1e-6);
    }
}
