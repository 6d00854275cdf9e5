//! SVG views of the base model at its default pose (ground frame), drawn by
//! the shared [`crate::util::svg`]: frontal (seen from the front, the
//! subject's right on the viewer's left) and sagittal (anterior to the
//! right), in mm. Vertebra and sacrum meshes are grey silhouettes, wrap
//! spheres blue outlines at their radius, palpated markers red (right side
//! / midline) and green (left side) dots.

use super::wrap::SphereRow;
use super::MarkerRow;
use crate::mesh::TriMesh;
use crate::util::svg::{Circles, Figure, Series, Silhouette, View};
use nalgebra::{Isometry3, Point3};
use plotters::style::{RGBColor, BLUE, GREEN, RED};
use std::collections::BTreeMap;

/// Render the two views: `[(file name, svg)]` (`view_frontal.svg`,
/// `view_sagittal.svg`).
pub fn render(
    poses: &BTreeMap<String, Isometry3<f64>>,
    meshes: &[(String, &TriMesh)],
    markers: &[MarkerRow],
    spheres: &[SphereRow],
) -> Vec<(String, String)> {
    let mut triangles = Vec::new();
    for (body, m) in meshes {
        let Some(x) = poses.get(body) else { continue };
        let world: Vec<Point3<f64>> = m.vertices.iter().map(|p| x * p).collect();
        triangles.extend(m.triangles.iter().filter_map(|t| {
            Some([
                *world.get(t[0] as usize)?,
                *world.get(t[1] as usize)?,
                *world.get(t[2] as usize)?,
            ])
        }));
    }
    let marker = |left: bool| -> Vec<Point3<f64>> {
        markers
            .iter()
            .filter(|r| r.name.ends_with('L') == left)
            .filter_map(|r| {
                let x = poses.get(&r.body)?;
                Some(x * Point3::new(r.location[0], r.location[1], r.location[2]))
            })
            .collect()
    };
    let circles = spheres
        .iter()
        .filter_map(|s| {
            let x = poses.get(&s.body)?;
            Some((
                x * Point3::new(s.centre[0], s.centre[1], s.centre[2]),
                s.radius,
            ))
        })
        .collect();
    let mut f = Figure::new("base model");
    f.size = (700, 900);
    f.silhouettes.push(Silhouette {
        label: "vertebra and sacrum meshes".into(),
        colour: RGBColor(190, 190, 190),
        triangles,
    });
    f.circles.push(Circles {
        label: "wrap spheres".into(),
        colour: BLUE,
        circles,
    });
    for (left, colour, label) in [
        (false, RED, "markers (right, midline)"),
        (true, GREEN, "markers (left)"),
    ] {
        f.series.push(Series {
            label: label.into(),
            colour,
            points: marker(left),
            radius: 3,
            line: false,
        });
    }
    View::BOTH
        .iter()
        .map(|v| (format!("view_{}.svg", v.name()), f.draw(*v)))
        .collect()
}
