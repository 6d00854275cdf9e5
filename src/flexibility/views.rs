//! One frontal figure per film (drawn by the shared [`crate::util::svg`]):
//! the film's points placed on the model, the personalised model's and the
//! uniform model's, each with its endplate lines (what a Cobb angle is
//! measured on) and, in the legend, the curves' Cobb angles.

use crate::landmarks::radiograph::FilmPoint;
use crate::landmarks::{Code, LandmarkId, Level};
use crate::util::svg::{Figure, Series, View};
use nalgebra::{Point3, Vector2};
use plotters::style::RGBColor;
use std::collections::BTreeMap;

/// One set of points to draw: label (with its Cobb angles), colour, points
/// in the model's frontal plane (m).
pub(crate) struct Layer {
    pub(crate) label: String,
    pub(crate) colour: RGBColor,
    pub(crate) points: BTreeMap<FilmPoint, Vector2<f64>>,
}

/// The measured film, the personalised and the uniform model's colours.
pub(crate) const MEASURED: RGBColor = RGBColor(220, 40, 40);
pub(crate) const PERSONALISED: RGBColor = RGBColor(40, 90, 220);
pub(crate) const UNIFORM: RGBColor = RGBColor(120, 120, 120);

/// A frontal-plane point (u, v) in ground (x = 0, y = v, z = -u).
fn ground(p: &Vector2<f64>) -> Point3<f64> {
    Point3::new(0.0, p.y, -p.x)
}

/// The figure of one film.
pub(crate) fn film_figure(title: &str, layers: &[Layer]) -> String {
    let mut f = Figure::new(title);
    for layer in layers {
        f.series.push(Series {
            label: layer.label.clone(),
            colour: layer.colour,
            points: layer.points.values().map(ground).collect(),
            radius: 2,
            line: false,
        });
        // the endplate lines, unlabelled
        for level in &Level::ALL[..17] {
            for (r, l) in [(Code::SR, Code::SL), (Code::IR, Code::IL)] {
                let get = |c| {
                    layer
                        .points
                        .get(&FilmPoint::Landmark(LandmarkId::new(*level, c)))
                };
                if let (Some(a), Some(b)) = (get(r), get(l)) {
                    f.series.push(Series {
                        label: String::new(),
                        colour: layer.colour,
                        points: vec![ground(a), ground(b)],
                        radius: 0,
                        line: true,
                    });
                }
            }
        }
    }
    // level names beside the measured (else first) layer's superior ends
    if let Some(layer) = layers.first() {
        for level in &Level::ALL[..17] {
            if let Some(p) = layer
                .points
                .get(&FilmPoint::Landmark(LandmarkId::new(*level, Code::SL)))
            {
                f.labels.push((ground(p), level.to_string()));
            }
        }
    }
    f.draw(View::Frontal)
}
