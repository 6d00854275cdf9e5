//! The generator's frontal and sagittal views (drawn by the shared
//! [`crate::util::svg`]): vertebral centres with their level names, the
//! registered landmarks and the model's markers. Lengths in mm.

use crate::landmarks::Level;
use crate::util::svg::{Figure, Series};
use nalgebra::Point3;
use plotters::style::{RGBColor, BLACK};
use std::collections::BTreeMap;

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
    let mut f = Figure::new("generated model");
    f.series = series.to_vec();
    f.labels = centres.iter().map(|(l, p)| (*p, l.to_string())).collect();
    f.draw_both()
}
