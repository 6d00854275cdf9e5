//! SVG figures, drawn by the shared [`crate::util::svg`]: the evaluation
//! figures in the style of the thesis's Figures 5.6 (centres of the models
//! and the truth, sagittal and frontal) and 5.7 (centres with their
//! 4th-order polynomial fits). Frontal views are seen from anterior (the
//! subject's right on the viewer's left); sagittal views from the right
//! (anterior to the right). Lengths in mm.

use crate::landmarks::Level;
use crate::util::svg::Figure;
use nalgebra::Point3;
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
