//! Pedicle sections and the vertebral centre, in the local frame.
//!
//! Pedicles: the frontal plane a fifth of the body's depth behind the
//! posterior wall cuts the vertebra; on each side of the mid-sagittal plane
//! the highest and lowest cut points along Y are the top and base of the
//! pedicle arch. The walls and the depth are those of the endplate
//! landmarks: posterior wall = mean X of SP and IP, anterior wall = mean X
//! of SA and IA.
//!
//! Vertebral centre (thesis rule): the least-squares sphere through the
//! body's anterior-surface nodes: vertices in front of the body's centre
//! (the SEC-IEC midpoint), between the two endplate planes (through SEC and
//! IEC, tilted as the rim landmarks of each endplate), at least 60 % of the
//! endplate rim radius (mean distance of the eight rim landmarks from
//! their endplate centre, across the axis) away from the body's axis.

use super::body::EndplatePoints;
use super::local::{LocalMesh, SAMPLE_AREA};
use crate::mesh::{fit_sphere, Sphere};
use nalgebra::{Point3, Vector3};

/// Top and base of one pedicle arch (local).
pub(crate) struct Pedicle {
    pub top: Point3<f64>,
    pub base: Point3<f64>,
    /// Number of cut points the pedicle section had.
    pub points: usize,
}

/// X of the frontal cut: a fifth of the body depth behind the posterior
/// wall (walls from the endplates' mid-sagittal ends).
pub(crate) fn pedicle_cut_x(sup: &EndplatePoints, inf: &EndplatePoints) -> f64 {
    cut_x([sup.front.x, sup.back.x, inf.front.x, inf.back.x])
}

/// X of the frontal cut from the local X of `SA`, `SP`, `IA`, `IP`.
pub(crate) fn cut_x([sa, sp, ia, ip]: [f64; 4]) -> f64 {
    let x_post = 0.5 * (sp + ip);
    let x_ant = 0.5 * (sa + ia);
    x_post - 0.2 * (x_ant - x_post)
}

/// The pedicle section on one side (`side` +1 right, -1 left).
pub(crate) fn pedicle_section(lm: &LocalMesh, x_cut: f64, side: f64) -> Option<Pedicle> {
    let pts: Vec<Point3<f64>> = lm
        .cut(0..lm.tris.len(), 0, x_cut)
        .into_iter()
        .filter(|p| side * p.z > 0.0)
        .collect();
    if pts.len() < 2 {
        return None;
    }
    let top = pts.iter().copied().max_by(|a, b| a.y.total_cmp(&b.y))?;
    let base = pts.iter().copied().min_by(|a, b| a.y.total_cmp(&b.y))?;
    Some(Pedicle {
        top,
        base,
        points: pts.len(),
    })
}

/// Unit normal (towards +Y) of the least-squares plane through the rim
/// landmarks of one endplate.
fn rim_normal(e: &EndplatePoints) -> Option<Vector3<f64>> {
    let pts = [e.front, e.back, e.right, e.left];
    let c = pts.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / 4.0;
    let cov = pts.iter().fold(nalgebra::Matrix3::zeros(), |a, p| {
        let d = p.coords - c;
        a + d * d.transpose()
    });
    let eig = cov.symmetric_eigen();
    let k = eig.eigenvalues.imin();
    let n = eig.eigenvectors.column(k).into_owned();
    let n = n.try_normalize(1e-12)?;
    Some(if n.y < 0.0 { -n } else { n })
}

/// Mean distance of the rim landmarks from their endplate centre, across
/// the body's axis (Y).
pub(crate) fn rim_radius(sup: &EndplatePoints, inf: &EndplatePoints) -> f64 {
    let across = |p: &Point3<f64>, c: &Point3<f64>| (p.x - c.x).hypot(p.z - c.z);
    let mut s = 0.0;
    for e in [sup, inf] {
        for p in [e.front, e.back, e.right, e.left] {
            s += across(&p, &e.centre);
        }
    }
    s / 8.0
}

/// The anterior-surface nodes of the body (points spread evenly over it)
/// and their least-squares sphere.
pub(crate) fn vertebral_centre(
    lm: &LocalMesh,
    sup: &EndplatePoints,
    inf: &EndplatePoints,
) -> Option<(Sphere, usize)> {
    let (ns, ni) = (rim_normal(sup)?, rim_normal(inf)?);
    let mid = Point3::from((sup.centre.coords + inf.centre.coords) * 0.5);
    let rim = rim_radius(sup, inf);
    // Surface points at an even density, so that the fit does not depend
    // on where a coarse or decimated mesh happens to keep its vertices.
    let samples = lm.area_samples(SAMPLE_AREA);
    let nodes = |frac: f64| -> Vec<Point3<f64>> {
        samples
            .iter()
            .copied()
            .filter(|p| {
                p.x > mid.x
                    && (p - sup.centre).dot(&ns) < 0.0
                    && (p - inf.centre).dot(&ni) > 0.0
                    && (p.x - mid.x).hypot(p.z - mid.z) >= frac * rim
            })
            .collect()
    };
    let mut pts = nodes(0.6);
    if pts.len() < 8 {
        pts = nodes(0.4);
    }
    let s = fit_sphere(&pts).ok()?;
    Some((s, pts.len()))
}
