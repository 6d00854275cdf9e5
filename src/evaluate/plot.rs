//! SVG figures (plotters, SVG backend only): the generator's frontal and
//! sagittal views of vertebral centres and landmarks, and the evaluation
//! figures in the style of the thesis's Figures 5.6 (centres of the models
//! and the truth, sagittal and frontal) and 5.7 (centres with their
//! 4th-order polynomial fits). Frontal views are seen from anterior (the
//! subject's right on the viewer's left); sagittal views from the right
//! (anterior to the right). Lengths in mm.

use crate::landmarks::Level;
use nalgebra::Point3;
use plotters::prelude::*;
use std::collections::BTreeMap;

/// One series of a figure.
pub struct Series {
    pub label: String,
    pub colour: RGBColor,
    /// Points in ground (m).
    pub points: Vec<Point3<f64>>,
    /// Marker radius (px); 0 draws no markers.
    pub radius: i32,
    /// Join the points by a line (in the given order).
    pub line: bool,
}

/// Horizontal coordinate of a view (mm).
type Horizontal = fn(&Point3<f64>) -> f64;

fn frontal(p: &Point3<f64>) -> f64 {
    -p.z * 1e3
}
fn sagittal(p: &Point3<f64>) -> f64 {
    p.x * 1e3
}

/// Draw one view of `series` with equal axis scales.
pub fn view(title: &str, h: Horizontal, series: &[Series]) -> String {
    let (mut h0, mut h1, mut v0, mut v1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for s in series {
        for p in &s.points {
            if !(p.x.is_finite() && p.y.is_finite() && p.z.is_finite()) {
                continue;
            }
            h0 = h0.min(h(p));
            h1 = h1.max(h(p));
            v0 = v0.min(p.y * 1e3);
            v1 = v1.max(p.y * 1e3);
        }
    }
    if h0 > h1 {
        (h0, h1, v0, v1) = (-100.0, 100.0, 0.0, 500.0);
    }
    let span = (h1 - h0).max(v1 - v0) * 1.1 + 1.0;
    let (hc, vc) = (0.5 * (h0 + h1), 0.5 * (v0 + v1));
    let (w, ht) = (600u32, 800u32);
    let hspan = span * w as f64 / ht as f64;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (w, ht)).into_drawing_area();
        let _ = root.fill(&WHITE);
        let chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 15))
            .margin(10)
            .x_label_area_size(30)
            .y_label_area_size(50)
            .build_cartesian_2d(
                (hc - 0.5 * hspan)..(hc + 0.5 * hspan),
                (vc - 0.5 * span)..(vc + 0.5 * span),
            );
        let Ok(mut chart) = chart else {
            return format!(
                "<svg xmlns=\"http://www.w3.org/2000/svg\"><text x=\"10\" y=\"20\">{title}</text></svg>"
            );
        };
        let _ = chart
            .configure_mesh()
            .x_desc("mm")
            .y_desc("superior (mm)")
            .draw();
        for s in series {
            let pts: Vec<(f64, f64)> = s.points.iter().map(|p| (h(p), p.y * 1e3)).collect();
            let col = s.colour;
            if s.line && pts.len() > 1 {
                let r = chart.draw_series(LineSeries::new(pts.clone(), col.stroke_width(2)));
                if let Ok(a) = r {
                    a.label(s.label.clone()).legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 16, y)], col.stroke_width(2))
                    });
                }
            }
            if s.radius > 0 {
                let r = chart.draw_series(
                    pts.iter()
                        .map(|(x, y)| Circle::new((*x, *y), s.radius, col.filled())),
                );
                if let (Ok(a), false) = (r, s.line) {
                    a.label(s.label.clone())
                        .legend(move |(x, y)| Circle::new((x + 8, y), 4, col.filled()));
                }
            }
        }
        let _ = chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .position(SeriesLabelPosition::UpperLeft)
            .draw();
        let _ = root.present();
    }
    svg
}

/// The two views: `[(suffix, svg)]` with suffixes `frontal`, `sagittal`.
pub fn views(title: &str, series: &[Series]) -> Vec<(String, String)> {
    vec![
        (
            "frontal".to_string(),
            view(
                &format!("{title}: frontal (from anterior; right on the left)"),
                frontal,
                series,
            ),
        ),
        (
            "sagittal".to_string(),
            view(
                &format!("{title}: sagittal (from the right; anterior to the right)"),
                sagittal,
                series,
            ),
        ),
    ]
}

/// The generator's views: vertebral centres (joined), registered
/// landmarks and the model's markers.
pub fn generate_views(
    centres: &BTreeMap<Level, Point3<f64>>,
    landmarks: &[(String, Point3<f64>)],
    markers: &[Point3<f64>],
) -> Vec<(String, String)> {
    let series = [
        Series {
            label: "model markers".into(),
            colour: RGBColor(90, 120, 230),
            points: markers.to_vec(),
            radius: 2,
            line: false,
        },
        Series {
            label: "landmarks (registered)".into(),
            colour: RGBColor(220, 40, 40),
            points: landmarks.iter().map(|(_, p)| *p).collect(),
            radius: 2,
            line: false,
        },
        Series {
            label: "model vertebral centres".into(),
            colour: BLACK,
            points: centres.values().copied().collect(),
            radius: 4,
            line: true,
        },
    ];
    views("generated model", &series)
}
