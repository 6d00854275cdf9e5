//! Least-squares sphere fitting and the node-selection rule for the
//! anterior surface of a vertebral body.
//!
//! [`fit_sphere`] first solves the algebraic (linear) fit
//! `|p|^2 = 2 c.p + (r^2 - |c|^2)` and then refines the geometric residuals
//! `|p - c| - r` with the crate's Levenberg-Marquardt ([`crate::util::lm`]).
//! Points are centred and scaled internally for conditioning.
//!
//! [`anterior_body_nodes`] picks the vertices of a vertebral-body surface
//! that lie on the anterior wall, given the body's anatomical axes.

use super::TriMesh;
use crate::error::{Error, Result};
use crate::util::lm::{self, LmOptions};
use crate::util::quantiles::quantile;
use nalgebra::{DMatrix, DVector, Matrix4, Point3, Unit, Vector3, Vector4};

/// A fitted sphere.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sphere {
    /// Centre (m).
    pub centre: Point3<f64>,
    /// Radius (m).
    pub radius: f64,
    /// Root-mean-square of the geometric residuals `|p - c| - r` (m).
    pub rms: f64,
}

/// Fit a sphere to at least four points that are not coplanar.
pub fn fit_sphere(points: &[Point3<f64>]) -> Result<Sphere> {
    let ctx = "sphere fit";
    if points.len() < 4 {
        return Err(Error::invalid(
            ctx,
            format!("{} points given, at least 4 are needed", points.len()),
        ));
    }
    if points
        .iter()
        .any(|p| !p.coords.iter().all(|c| c.is_finite()))
    {
        return Err(Error::invalid(ctx, "a point has a non-finite coordinate"));
    }
    let n = points.len() as f64;
    let mean = points.iter().fold(Vector3::zeros(), |s, p| s + p.coords) / n;
    let spread = (points
        .iter()
        .map(|p| (p.coords - mean).norm_squared())
        .sum::<f64>()
        / n)
        .sqrt();
    if spread <= 0.0 {
        return Err(Error::invalid(ctx, "all points coincide"));
    }
    let q: Vec<Vector3<f64>> = points.iter().map(|p| (p.coords - mean) / spread).collect();
    // Degeneracy: the points must span 3-D (not collinear or coplanar).
    let cov = q
        .iter()
        .fold(nalgebra::Matrix3::zeros(), |s, v| s + v * v.transpose())
        / n;
    let eig = cov.symmetric_eigenvalues();
    let (mn, mx) = (eig.min(), eig.max());
    if mn <= 1e-10 * mx {
        return Err(Error::invalid(
            ctx,
            "the points are coplanar or collinear: no unique sphere",
        ));
    }
    // Algebraic fit via normal equations on centred, scaled data.
    let mut ata = Matrix4::zeros();
    let mut atb = Vector4::zeros();
    for v in &q {
        let row = Vector4::new(2.0 * v.x, 2.0 * v.y, 2.0 * v.z, 1.0);
        ata += row * row.transpose();
        atb += row * v.norm_squared();
    }
    let sol = ata
        .lu()
        .solve(&atb)
        .ok_or_else(|| Error::numerical(ctx, "singular algebraic system"))?;
    let c = Vector3::new(sol[0], sol[1], sol[2]);
    let r2 = sol[3] + c.norm_squared();
    let r = if r2 > 0.0 { r2.sqrt() } else { 1.0 };
    // Geometric refinement: the residuals |q - c| - r by the one
    // least-squares optimiser, unbounded.
    let residuals = |x: &[f64], want_jacobian: bool| {
        let c = Vector3::new(x[0], x[1], x[2]);
        let r = DVector::from_iterator(q.len(), q.iter().map(|v| (v - c).norm() - x[3]));
        let jac = want_jacobian.then(|| {
            let mut j = DMatrix::zeros(q.len(), 4);
            for (i, v) in q.iter().enumerate() {
                let d = v - c;
                let dist = d.norm();
                let u = if dist > 0.0 { d / dist } else { d };
                j.row_mut(i).copy_from_slice(&[-u.x, -u.y, -u.z, -1.0]);
            }
            j
        });
        Ok((r, jac))
    };
    let fit = lm::minimize(
        residuals,
        &[c.x, c.y, c.z, r],
        &[f64::NEG_INFINITY; 4],
        &[f64::INFINITY; 4],
        &LmOptions::default(),
    )?;
    let (c, r, f) = (
        Vector3::new(fit.x[0], fit.x[1], fit.x[2]),
        fit.x[3],
        fit.r.norm_squared(),
    );
    if !r.is_finite() || r <= 0.0 || r > 1e6 {
        return Err(Error::numerical(
            ctx,
            "the fit diverged (points nearly planar?)",
        ));
    }
    Ok(Sphere {
        centre: Point3::from(mean + c * spread),
        radius: r.abs() * spread,
        rms: (f / n).sqrt() * spread,
    })
}

/// Anatomical axes of a vertebra, expressed in the mesh's coordinates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AnatomicalFrame {
    /// Unit vector pointing anteriorly (from the canal to the body).
    pub anterior: Unit<Vector3<f64>>,
    /// Unit vector pointing cranially (endplate to endplate, upwards).
    pub cranial: Unit<Vector3<f64>>,
    /// Unit vector pointing to the subject's right
    /// (`anterior x cranial`, OpenSim's X, Y, Z convention).
    pub right: Unit<Vector3<f64>>,
}

impl AnatomicalFrame {
    /// A right-handed frame from an anterior and a cranial direction
    /// (the cranial one is orthogonalised against the anterior one).
    pub fn new(anterior: Vector3<f64>, cranial: Vector3<f64>) -> Result<AnatomicalFrame> {
        let ctx = "anatomical frame";
        let a = Unit::try_new(anterior, 1e-12)
            .ok_or_else(|| Error::invalid(ctx, "anterior direction is zero"))?;
        let c = cranial - a.into_inner() * a.dot(&cranial);
        let c = Unit::try_new(c, 1e-9 * cranial.norm().max(1e-300))
            .ok_or_else(|| Error::invalid(ctx, "anterior and cranial directions are parallel"))?;
        let r = Unit::new_normalize(a.cross(&c));
        Ok(AnatomicalFrame {
            anterior: a,
            cranial: c,
            right: r,
        })
    }

    /// OpenSim body frame: X anterior, Y cranial, Z right.
    pub fn opensim_body() -> AnatomicalFrame {
        AnatomicalFrame {
            anterior: Vector3::x_axis(),
            cranial: Vector3::y_axis(),
            right: Vector3::z_axis(),
        }
    }
}

/// Vertices on the anterior wall of a vertebral-body surface.
///
/// Rule (all in the given anatomical frame):
/// 1. outward vertex normals are computed on a consistently oriented copy
///    of the mesh (flipped triangles in the file do not matter);
/// 2. the body's height is the 2nd-98th percentile range (type 7,
///    [`quantile`]) of the vertices along `cranial`; only vertices in the
///    central 50 % of that height are kept (away from the endplates and
///    their rims);
/// 3. the vertex must lie anterior of the surface's area centroid;
/// 4. its normal must point anteriorly, within 60 degrees of `anterior`
///    (`n . anterior >= 0.5`), and be mostly horizontal
///    (`|n . cranial| <= 0.5`), i.e. on the wall, not an endplate.
///
/// Returns the vertex indices in increasing order. Fails for an empty mesh
/// or when no vertex qualifies (a wrong frame, for instance).
pub fn anterior_body_nodes(mesh: &TriMesh, frame: &AnatomicalFrame) -> Result<Vec<usize>> {
    let ctx = "anterior body nodes";
    let mut oriented = mesh.clone();
    oriented.orient_consistently();
    let normals = oriented.vertex_normals();
    let centre = mesh
        .area_centroid()
        .ok_or_else(|| Error::invalid(ctx, "the mesh has no area"))?;
    let h: Vec<f64> = mesh
        .vertices
        .iter()
        .map(|p| (p - centre).dot(&frame.cranial))
        .collect();
    let pct = |p: f64| {
        quantile(&h, p).ok_or_else(|| Error::invalid(ctx, "a vertex or the frame is not finite"))
    };
    let (lo, hi) = (pct(0.02)?, pct(0.98)?);
    let (band_lo, band_hi) = (lo + 0.25 * (hi - lo), hi - 0.25 * (hi - lo));
    let nodes: Vec<usize> = mesh
        .vertices
        .iter()
        .zip(&normals)
        .enumerate()
        .filter(|(_, (p, n))| {
            let d = *p - centre;
            let z = d.dot(&frame.cranial);
            z >= band_lo
                && z <= band_hi
                && d.dot(&frame.anterior) > 0.0
                && n.dot(&frame.anterior) >= 0.5
                && n.dot(&frame.cranial).abs() <= 0.5
        })
        .map(|(i, _)| i)
        .collect();
    if nodes.is_empty() {
        return Err(Error::invalid(
            ctx,
            "no vertex lies on the anterior wall: check the anatomical frame",
        ));
    }
    Ok(nodes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exact_sphere_is_recovered() {
        let c = Point3::new(0.1, -0.2, 0.05);
        let r = 0.02;
        let pts: Vec<Point3<f64>> = (0..50)
            .map(|i| {
                let th = 0.1 + 0.02 * i as f64;
                let ph = 0.7 * i as f64;
                c + r * Vector3::new(th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos())
            })
            .collect();
        let s = fit_sphere(&pts).unwrap();
        assert!((s.centre - c).norm() < 1e-12);
        assert!((s.radius - r).abs() < 1e-12);
        assert!(s.rms < 1e-12);
    }

    #[test]
    fn degenerate_inputs_are_errors() {
        let plane: Vec<Point3<f64>> = (0..20)
            .map(|i| Point3::new((i % 5) as f64, (i / 5) as f64, 0.0))
            .collect();
        let e = fit_sphere(&plane).unwrap_err().to_string();
        assert!(e.contains("coplanar"), "{e}");
        assert!(fit_sphere(&plane[..3]).is_err());
        assert!(fit_sphere(&[Point3::origin(); 10]).is_err());
    }

    #[test]
    fn frame_is_right_handed() {
        let f = AnatomicalFrame::new(Vector3::x(), Vector3::new(0.1, 0.0, 1.0)).unwrap();
        assert!((f.right.into_inner() - (-Vector3::y())).norm() < 1e-12);
        assert!(f.anterior.dot(&f.cranial).abs() < 1e-15);
        assert!(AnatomicalFrame::new(Vector3::x(), Vector3::x()).is_err());
    }
}
