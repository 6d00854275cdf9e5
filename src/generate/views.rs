//! The generator's frontal and sagittal views (drawn by the shared
//! [`crate::util::svg`]): vertebral centres with their level names, the
//! registered landmarks and the model's markers; the patient's own
//! vertebrae as grey silhouettes when the model wears them. Lengths in mm.

use crate::landmarks::Level;
use crate::mesh::TriMesh;
use crate::osim::model::{Geometry, Model};
use crate::util::svg::{Figure, Series, Silhouette};
use nalgebra::Isometry3;
use nalgebra::Point3;
use plotters::style::{RGBColor, BLACK};
use std::collections::BTreeMap;

/// The generator's views: vertebral centres (joined), registered
/// landmarks and the model's markers.
pub fn generate_views(
    centres: &BTreeMap<Level, Point3<f64>>,
    landmarks: &[(String, Point3<f64>)],
    markers: &[Point3<f64>],
    bones: &[[Point3<f64>; 3]],
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
    if !bones.is_empty() {
        f.silhouettes.push(Silhouette {
            label: "patient's vertebrae (segmentation)".into(),
            colour: RGBColor(190, 190, 190),
            triangles: bones.to_vec(),
        });
    }
    f.labels = centres.iter().map(|(l, p)| (*p, l.to_string())).collect();
    f.draw_both()
}

/// The triangles (ground, default pose `poses`) of every mesh of `own`
/// that a body of `model` wears.
pub fn posed_triangles(
    own: &BTreeMap<String, TriMesh>,
    model: &Model,
    poses: &BTreeMap<String, Isometry3<f64>>,
) -> Vec<[Point3<f64>; 3]> {
    let mut out = Vec::new();
    for b in &model.bodies {
        let Some(x) = poses.get(&b.name) else {
            continue;
        };
        for g in &b.geometry {
            let Geometry::Mesh { mesh_file, .. } = g else {
                continue;
            };
            let Some(m) = own.get(mesh_file) else {
                continue;
            };
            out.extend(m.triangle_corners().map(|c| c.map(|p| x * p)));
        }
    }
    out
}
