//! Pedicle sections and the vertebral centre, in the local frame.
//!
//! Pedicles: the frontal plane a fifth of the body's depth behind the
//! posterior wall cuts the pedicles; on each side of the mid-sagittal
//! plane the highest and lowest cut points along Y are the top and base of
//! the pedicle arch.
//!
//! Vertebral centre (thesis rule): the least-squares sphere through the
//! body's anterior-surface nodes: vertices between the walls, in front of
//! the body's centre, between the two endplate planes, at least 60 % of the
//! endplate rim radius away from the body's axis.

use super::body::{Endplate, Walls};
use super::local::LocalMesh;
use crate::mesh::{fit_sphere, Sphere};
use nalgebra::Point3;

/// Top and base of one pedicle arch (local).
pub(crate) struct Pedicle {
    pub top: Point3<f64>,
    pub base: Point3<f64>,
    /// Number of cut points the pedicle section had.
    pub points: usize,
}

/// The pedicle section on one side (`side` +1 right, -1 left).
pub(crate) fn pedicle_section(lm: &LocalMesh, w: &Walls, side: f64) -> Option<Pedicle> {
    let x_cut = w.x_post - 0.2 * w.depth();
    let hw = w.half_width();
    let h = w.height();
    let pts: Vec<Point3<f64>> = lm
        .cut(0..lm.tris.len(), 0, x_cut)
        .into_iter()
        .filter(|p| {
            let zz = side * p.z;
            zz > 0.1 * hw && zz < 1.5 * hw && p.y > w.y_lo - 0.15 * h && p.y < w.y_hi + 0.15 * h
        })
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

/// The anterior-surface nodes of the body and their least-squares sphere.
pub(crate) fn vertebral_centre(
    lm: &LocalMesh,
    w: &Walls,
    sup: &Endplate,
    inf: &Endplate,
    sec: &Point3<f64>,
    iec: &Point3<f64>,
    rim_radius: f64,
) -> Option<(Sphere, usize)> {
    let axis = (sec - iec).try_normalize(1e-12)?;
    let mid = Point3::from((sec.coords + iec.coords) * 0.5);
    let x_c = 0.5 * (w.x_ant + w.x_post);
    let margin = 0.04 * w.depth();
    let nodes = |frac: f64| -> Vec<Point3<f64>> {
        lm.verts
            .iter()
            .copied()
            .filter(|p| {
                let d = p - mid;
                let radial = (d - axis * d.dot(&axis)).norm();
                p.x > x_c
                    && p.x <= w.x_ant + margin
                    && p.z <= w.z_right + margin
                    && p.z >= w.z_left - margin
                    && sup.normal.dot(&p.coords) < sup.offset
                    && inf.normal.dot(&p.coords) < inf.offset
                    && radial >= frac * rim_radius
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
