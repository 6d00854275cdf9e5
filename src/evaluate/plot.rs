//! SVG figures, drawn by the shared [`crate::util::svg`]: the generator's frontal and
//! sagittal views of vertebral centres and landmarks, and the evaluation
//! figures in the style of the thesis's Figures 5.6 (centres of the models
//! and the truth, sagittal and frontal) and 5.7 (centres with their
//! 4th-order polynomial fits). Frontal views are seen from anterior (the
//! subject's right on the viewer's left); sagittal views from the right
//! (anterior to the right). Lengths in mm.

use crate::landmarks::Level;
use crate::util::svg::Figure;
use nalgebra::Point3;
use plotters::style::{RGBColor, BLACK};
use std::collections::BTreeMap;

/// One series of a figure (the shared drawing's series).
pub use crate::util::svg::Series;

/// The two views of `series`: `[(suffix, svg)]` with suffixes `frontal`,
/// `sagittal`.
pub fn views(title: &str, series: &[Series]) -> Vec<(String, String)> {
    labelled_views(title, series, &BTreeMap::new())
}

/// [`views`] with each level's name written beside its point.
pub fn labelled_views(
    title: &str,
    series: &[Series],
    labels: &BTreeMap<Level, Point3<f64>>,
) -> Vec<(String, String)> {
    let mut f = Figure::new(title);
    f.series = series.to_vec();
    f.labels = labels.iter().map(|(l, p)| (*p, l.to_string())).collect();
    f.draw_both()
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
    labelled_views("generated model", &series, centres)
}
