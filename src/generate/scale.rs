//! Anisotropic scaling of one body in an .osim document, in the body frame
//! about the body origin (as OpenSim's ScaleTool does), applied
//! consistently to everything fixed to the body: mesh `scale_factors`,
//! mass (times `sx sy sz`), centre of mass, inertia (the second moments of
//! the mass distribution scale as `S Sigma S`), wrap-object translations,
//! markers, muscle path points (fixed and conditional; a MovingPathPoint is
//! a function of coordinates and is reported, not scaled) and every
//! PhysicalOffsetFrame whose parent is the body (joint and bushing frames).
//! Wrap-sphere radii are refitted by the caller ([`super::wraps`]).

use crate::error::{Error, Result};
use crate::osim::props::{parse_numbers, set_numbers, set_vec3};
use crate::osim::xml::Element;
use crate::osim::Document;
use nalgebra::{Matrix3, Vector3};

fn walk_mut(e: &mut Element, f: &mut dyn FnMut(&mut Element)) {
    f(e);
    for c in e.elements_mut() {
        walk_mut(c, f);
    }
}

/// Is `text` the socket path of `body` (`/bodyset/<body>` or
/// `bodyset/<body>`, surrounding whitespace ignored)?
fn is_body_socket(text: &str, body: &str) -> bool {
    let t = text.trim();
    t.strip_prefix('/').unwrap_or(t).strip_prefix("bodyset/") == Some(body)
}

/// Does the socket `prop` of `e` name `body`?
fn on_body(e: &Element, prop: &str, body: &str) -> bool {
    e.child(prop)
        .is_some_and(|c| is_body_socket(&c.text(), body))
}

fn scale_prop(e: &mut Element, prop: &str, s: &Vector3<f64>, file: &std::path::Path) -> Result<()> {
    let Some(c) = e.child(prop) else {
        return Ok(());
    };
    let v = parse_numbers(&c.text(), c, file)?;
    if v.len() != 3 {
        return Err(Error::invalid(
            file.display().to_string(),
            format!(
                "<{}> of {}: expected 3 numbers",
                prop,
                crate::osim::props::loc(e)
            ),
        ));
    }
    set_vec3(e, prop, &Vector3::new(v[0] * s.x, v[1] * s.y, v[2] * s.z));
    Ok(())
}

/// Inertia `[Ixx Iyy Izz Ixy Ixz Iyz]` about the centre of mass of a body
/// of mass `m` scaled by `s` (new mass `m sx sy sz`).
pub(crate) fn scaled_inertia(i: &[f64; 6], s: &Vector3<f64>) -> [f64; 6] {
    let it = Matrix3::new(i[0], i[3], i[4], i[3], i[1], i[5], i[4], i[5], i[2]);
    let sigma = Matrix3::identity() * (0.5 * it.trace()) - it;
    let k = s.x * s.y * s.z;
    let sm = Matrix3::from_diagonal(s);
    let sig2 = sm * sigma * sm * k;
    let i2 = Matrix3::identity() * sig2.trace() - sig2;
    [
        i2[(0, 0)],
        i2[(1, 1)],
        i2[(2, 2)],
        i2[(0, 1)],
        i2[(0, 2)],
        i2[(1, 2)],
    ]
}

/// What scaling a body touched.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct ScaleCount {
    /// Meshes scaled.
    pub meshes: usize,
    /// Markers moved.
    pub markers: usize,
    /// Path points moved.
    pub path_points: usize,
    /// Offset frames moved.
    pub offset_frames: usize,
    /// Wrap objects moved (their translation scaled).
    pub wrap_objects: usize,
    /// MovingPathPoints on the body (not scaled: functions of coordinates).
    pub moving_points_not_scaled: Vec<String>,
}

/// Scale body `body` of `doc` by `s` (see the module documentation).
pub fn scale_body(doc: &mut Document, body: &str, s: &Vector3<f64>) -> Result<ScaleCount> {
    let file = doc.path().to_path_buf();
    let mut count = ScaleCount::default();
    {
        let el = doc.component_mut("BodySet", body).ok_or_else(|| {
            Error::invalid(file.display().to_string(), format!("no body '{body}'"))
        })?;
        let mass = crate::osim::props::f64_or(el, "mass", 0.0, &file)?;
        crate::osim::props::set_f64(el, "mass", mass * s.x * s.y * s.z);
        scale_prop(el, "mass_center", s, &file)?;
        if let Some(c) = el.child("inertia") {
            let v = parse_numbers(&c.text(), c, &file)?;
            if v.len() == 6 {
                let i = [v[0], v[1], v[2], v[3], v[4], v[5]];
                set_numbers(el, "inertia", &scaled_inertia(&i, s));
            }
        }
        if let Some(ag) = el.child_mut("attached_geometry") {
            for g in ag.elements_mut().filter(|g| g.name == "Mesh") {
                let old = match g.child("scale_factors") {
                    Some(c) => parse_numbers(&c.text(), c, &file)?,
                    None => vec![1.0, 1.0, 1.0],
                };
                if old.len() != 3 {
                    return Err(Error::invalid(
                        file.display().to_string(),
                        format!("scale_factors of a mesh of body '{body}': expected 3 numbers"),
                    ));
                }
                set_vec3(
                    g,
                    "scale_factors",
                    &Vector3::new(old[0] * s.x, old[1] * s.y, old[2] * s.z),
                );
                count.meshes += 1;
            }
        }
        if let Some(objs) = el
            .child_mut("WrapObjectSet")
            .and_then(|w| w.child_mut("objects"))
        {
            for w in objs.elements_mut() {
                scale_prop(w, "translation", s, &file)?;
                count.wrap_objects += 1;
            }
        }
    }
    let mut err = None;
    walk_mut(doc.model_element_mut(), &mut |e: &mut Element| {
        if err.is_some() {
            return;
        }
        let r = match e.name.as_str() {
            "PhysicalOffsetFrame" => {
                if on_body(e, "socket_parent", body) {
                    count.offset_frames += 1;
                    scale_prop(e, "translation", s, &file)
                } else {
                    Ok(())
                }
            }
            "Marker" | "PathPoint" | "ConditionalPathPoint" => {
                if on_body(e, "socket_parent_frame", body) {
                    if e.name == "Marker" {
                        count.markers += 1;
                    } else {
                        count.path_points += 1;
                    }
                    scale_prop(e, "location", s, &file)
                } else {
                    Ok(())
                }
            }
            "MovingPathPoint" => {
                if on_body(e, "socket_parent_frame", body) {
                    count
                        .moving_points_not_scaled
                        .push(e.name_attr().to_string());
                }
                Ok(())
            }
            _ => Ok(()),
        };
        if let Err(x) = r {
            err = Some(x);
        }
    });
    if let Some(e) = err {
        return Err(e);
    }
    Ok(count)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn body_sockets_are_matched_whole() {
        for t in [
            "/bodyset/lumbar1",
            "bodyset/lumbar1",
            "  /bodyset/lumbar1\n",
        ] {
            assert!(is_body_socket(t, "lumbar1"), "{t:?}");
        }
        for t in [
            "/bodyset/lumbar10",
            "/bodyset/lumbar",
            "//bodyset/lumbar1",
            "/jointset/lumbar1",
            "lumbar1",
            "/bodyset/lumbar1/frame",
        ] {
            assert!(!is_body_socket(t, "lumbar1"), "{t:?}");
        }
    }

    /// Inertia of a solid box of mass m, sides a b c about its centre.
    fn box_inertia(m: f64, a: f64, b: f64, c: f64) -> [f64; 6] {
        [
            m * (b * b + c * c) / 12.0,
            m * (a * a + c * c) / 12.0,
            m * (a * a + b * b) / 12.0,
            0.0,
            0.0,
            0.0,
        ]
    }

    #[test]
    fn scaled_box_inertia_is_the_inertia_of_the_scaled_box() {
        let (m, a, b, c) = (1.3, 0.04, 0.025, 0.05);
        let s = Vector3::new(1.2, 0.8, 1.1);
        let got = scaled_inertia(&box_inertia(m, a, b, c), &s);
        let want = box_inertia(m * s.x * s.y * s.z, a * s.x, b * s.y, c * s.z);
        for k in 0..6 {
            assert!((got[k] - want[k]).abs() < 1e-15, "{k}: {got:?} vs {want:?}");
        }
    }
}
