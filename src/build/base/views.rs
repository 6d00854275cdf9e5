//! SVG views of the base model at its default pose (ground frame): frontal
//! (seen from the front: horizontal axis = ground Z, the subject's right, on
//! the viewer's left) and sagittal (horizontal axis = ground X, anterior to
//! the right). Mesh vertices are grey dots, wrap spheres blue outlines,
//! palpated markers red (right side / midline) and green (left side) dots.

use super::wrap::SphereRow;
use super::MarkerRow;
use crate::mesh::TriMesh;
use nalgebra::{Isometry3, Point3};
use plotters::prelude::*;
use std::collections::BTreeMap;

/// (file name, title, horizontal coordinate of a point).
type View = (&'static str, &'static str, fn(&Point3<f64>) -> f64);

/// Render the two views: `[(file name, svg)]`.
pub fn render(
    poses: &BTreeMap<String, Isometry3<f64>>,
    meshes: &[(String, &TriMesh)],
    markers: &[MarkerRow],
    spheres: &[SphereRow],
) -> Vec<(String, String)> {
    let mut pts: Vec<Point3<f64>> = Vec::new();
    for (body, m) in meshes {
        if let Some(x) = poses.get(body) {
            pts.extend(m.vertices.iter().map(|p| x * p));
        }
    }
    let mk: Vec<(Point3<f64>, bool)> = markers
        .iter()
        .filter_map(|r| {
            let x = poses.get(&r.body)?;
            let left = r.name.ends_with('L');
            Some((
                x * Point3::new(r.location[0], r.location[1], r.location[2]),
                left,
            ))
        })
        .collect();
    let sp: Vec<(Point3<f64>, f64)> = spheres
        .iter()
        .filter_map(|s| {
            let x = poses.get(&s.body)?;
            Some((
                x * Point3::new(s.centre[0], s.centre[1], s.centre[2]),
                s.radius,
            ))
        })
        .collect();
    let views: [View; 2] = [
        (
            "view_frontal.svg",
            "frontal (from anterior; subject's right on the left)",
            |p| -p.z,
        ),
        (
            "view_sagittal.svg",
            "sagittal (from the right; anterior to the right)",
            |p| p.x,
        ),
    ];
    views
        .iter()
        .map(|(file, title, h)| (file.to_string(), draw(title, *h, &pts, &mk, &sp)))
        .collect()
}

fn draw(
    title: &str,
    h: fn(&Point3<f64>) -> f64,
    pts: &[Point3<f64>],
    mk: &[(Point3<f64>, bool)],
    sp: &[(Point3<f64>, f64)],
) -> String {
    let all = pts.iter().chain(mk.iter().map(|(p, _)| p));
    let (mut h0, mut h1, mut v0, mut v1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for p in all {
        h0 = h0.min(h(p));
        h1 = h1.max(h(p));
        v0 = v0.min(p.y);
        v1 = v1.max(p.y);
    }
    if h0 > h1 {
        (h0, h1, v0, v1) = (-0.1, 0.1, 0.0, 0.5);
    }
    // Equal scales on both axes.
    let span = (h1 - h0).max(v1 - v0) * 1.05 + 1e-3;
    let (hc, vc) = (0.5 * (h0 + h1), 0.5 * (v0 + v1));
    let (w, ht) = (700u32, 900u32);
    let hspan = span * w as f64 / ht as f64;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (w, ht)).into_drawing_area();
        let _ = root.fill(&WHITE);
        let chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 16))
            .margin(10)
            .x_label_area_size(30)
            .y_label_area_size(50)
            .build_cartesian_2d(
                (hc - 0.5 * hspan)..(hc + 0.5 * hspan),
                (vc - 0.5 * span)..(vc + 0.5 * span),
            );
        let Ok(mut chart) = chart else {
            return svg_fallback(title);
        };
        let _ = chart.configure_mesh().x_desc("m").y_desc("Y (m)").draw();
        let _ = chart.draw_series(
            pts.iter()
                .map(|p| Circle::new((h(p), p.y), 1, RGBColor(150, 150, 150).filled())),
        );
        let px_per_m = ht as f64 / span;
        let _ = chart.draw_series(sp.iter().map(|(c, r)| {
            Circle::new(
                (h(c), c.y),
                (r * px_per_m * 0.9).max(1.0) as i32,
                BLUE.stroke_width(1),
            )
        }));
        let _ = chart.draw_series(mk.iter().map(|(p, left)| {
            let col = if *left { GREEN } else { RED };
            Circle::new((h(p), p.y), 3, col.filled())
        }));
        let _ = root.present();
    }
    svg
}

fn svg_fallback(title: &str) -> String {
    format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\"><text x=\"10\" y=\"20\">{title}</text></svg>"
    )
}
