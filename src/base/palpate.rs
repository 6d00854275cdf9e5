//! Steps 6 and 8 of the base builder: every vertebra palpated by the
//! palpation engine ([`crate::palpation`]; a modeller's own palpation,
//! [`super::overrides`], replaces what it names), the guards on the result,
//! the vertebral-body spheres at the vertebral centres, and the markers.

use super::overrides::{Overrides, Placed};
use super::topology::Topology;
use super::vertebrae::Vert;
use super::{guards, wrap, MarkerRow};
use crate::error::{Error, Result};
use crate::landmarks::{Code, Level};
use crate::mesh::{MeshQuery, TriMesh};
use crate::osim::builders;
use crate::osim::xml::Node;
use crate::osim::Document;
use crate::palpation::{self, FrameHint, PalpatedLandmark, VertebraPalpation};
use nalgebra::{Isometry3, Vector3};
use std::collections::BTreeMap;

/// The palpation of the vertebrae and what the guards found.
pub(crate) struct Palpated {
    pub palps: Vec<VertebraPalpation>,
    pub guard_failures: Vec<guards::GuardFailure>,
    /// Landmarks and centres taken from the modeller's files.
    pub overridden: Vec<String>,
}

/// Palpate every vertebra, apply the modeller's palpation, run the guards.
pub(crate) fn palpate(
    vs: &[Vert],
    topo: &Topology,
    overrides: &Overrides,
    allow_implausible: bool,
) -> Result<Palpated> {
    // The engine on every vertebra mesh (each in its body frame).
    let mut palps = vs
        .iter()
        .map(|v| {
            palpation::palpate_vertebra(&v.mesh, v.level, &FrameHint::body_frame())
                .map_err(|e| Error::invalid(v.context(), e.to_string()))
        })
        .collect::<Result<Vec<_>>>()?;
    // The modeller's landmarks and centres replace the engine's.
    let overridden = apply_overrides(&mut palps, vs, topo, overrides)?;
    // Guards: refuse an implausible base unless allowed.
    let guard_failures: Vec<guards::GuardFailure> =
        palps.iter().flat_map(guards::check_vertebra).collect();
    refuse_implausible(&guard_failures, allow_implausible)?;
    Ok(Palpated {
        palps,
        guard_failures,
        overridden,
    })
}

/// Replace the engine's landmarks and centres by the modeller's (vertebrae
/// only; S1 is done with the sacrum); returns what was replaced.
fn apply_overrides(
    palps: &mut [VertebraPalpation],
    vs: &[Vert],
    topo: &Topology,
    ov: &Overrides,
) -> Result<Vec<String>> {
    let src = ov.sources.join(", ");
    let ctx = format!("base --palpation/--centres ({src})");
    // Every named vertebra must be kept.
    let named = ov
        .landmarks
        .keys()
        .map(|(l, _)| *l)
        .chain(ov.centres.keys().copied());
    for l in named.filter(|l| !l.is_sacrum()) {
        if !vs.iter().any(|v| v.level == l) {
            return Err(Error::invalid(
                &ctx,
                format!("{l} is not a kept level of the base"),
            ));
        }
    }
    let mut done = Vec::new();
    for (v, p) in vs.iter().zip(palps.iter_mut()) {
        for ((l, c), placed) in ov.landmarks.iter().filter(|((l, _), _)| *l == v.level) {
            let point = placed.in_body(&v.body, &topo.poses, &ctx)?;
            p.landmarks.insert(*c, given(point, &src));
            done.push(format!("{l}_{c}"));
        }
        if let Some(placed) = ov.centres.get(&v.level) {
            p.centre = placed.in_body(&v.body, &topo.poses, &ctx)?;
            done.push(format!("{}_centre", v.level));
        }
    }
    Ok(done)
}

/// A landmark taken from a modeller's file.
fn given(point: nalgebra::Point3<f64>, src: &str) -> PalpatedLandmark {
    PalpatedLandmark {
        point,
        confidence: 1.0,
        note: Some(format!("given in {src}")),
        spread: 0.0,
    }
}

/// Refuse a base whose landmarks break the protocol (unless allowed).
fn refuse_implausible(failures: &[guards::GuardFailure], allow: bool) -> Result<()> {
    if failures.is_empty() || allow {
        return Ok(());
    }
    let list: Vec<String> = failures.iter().map(|f| f.to_string()).collect();
    Err(Error::invalid(
        "base",
        format!(
            "refusing to write a base model whose landmarks break the palpation protocol ({} guard failures; --allow-implausible writes it with these as warnings):\n  {}",
            failures.len(),
            list.join("\n  ")
        ),
    ))
}

/// The vertebral-body wrapping sphere: centred on the vertebral centre,
/// with the radius of its least-squares sphere (shrunk later if needed).
pub(crate) fn body_sphere(
    v: &Vert,
    p: &VertebraPalpation,
    body_mesh_given: bool,
) -> wrap::SphereRow {
    let mut source = format!(
        "vertebral centre by the palpation engine (thesis sphere rule) on {}",
        v.mesh_file
    );
    if body_mesh_given {
        source.push_str("; the body-only mesh given is not used for the centre");
    }
    wrap::SphereRow {
        level: Some(v.level),
        body: v.body.clone(),
        name: format!("{}_body_sphere", v.level),
        centre: [p.centre.x, p.centre.y, p.centre.z],
        radius_fit: p.centre_radius,
        radius_no_overlap: p.centre_radius,
        radius: p.centre_radius,
        rms_mm: p.centre_fit.rms * 1e3,
        nodes: p.centre_fit.nodes,
        centre_inside_mesh: v.query.contains(&p.centre),
        source,
        body_mesh_registration_rms_mm: None,
        muscles: vec![],
        muscles_refused: vec![],
    }
}

/// The markers of the base: every vertebra's landmarks, then the S1
/// plateau's.
pub(crate) struct Markers {
    pub rows: Vec<MarkerRow>,
    /// Every finding of the palpation engine (warnings and errors).
    pub findings: Vec<String>,
}

/// Step 8: the markers on the vertebrae and the sacrum, added to `doc`.
pub(crate) fn add_markers(
    doc: &mut Document,
    vs: &[Vert],
    pal: &mut Palpated,
    sacrum: (&TriMesh, &str),
    topo: &Topology,
    overrides: &Overrides,
) -> Result<Markers> {
    let (sacrum_mesh, sacrum_file) = sacrum;
    let mut findings = Vec::new();
    let mut markers = Vec::new();
    for (v, p) in vs.iter().zip(&pal.palps) {
        findings.extend(p.findings.iter().map(|f| f.to_string()));
        for (code, l) in &p.landmarks {
            markers.push((v.level, *code, v.body.clone(), l.point, &v.query));
        }
    }
    // The S1 plateau, facing L5 at the default pose.
    let sacrum_query = MeshQuery::new(sacrum_mesh)
        .map_err(|e| Error::invalid(format!("sacrum mesh {sacrum_file}"), e.to_string()))?;
    let mut s1 = palpate_sacrum_of(doc, sacrum_mesh, vs, &pal.palps, topo)
        .map_err(|e| Error::invalid(format!("sacrum mesh {sacrum_file}"), e.to_string()))?;
    pal.overridden
        .extend(sacrum_overrides(&mut s1, topo, overrides)?);
    findings.extend(s1.findings.iter().map(|f| f.to_string()));
    for code in Code::SACRUM_REQUIRED {
        if let Some(l) = s1.landmarks.get(&code) {
            markers.push((Level::S1, code, "sacrum".into(), l.point, &sacrum_query));
        }
    }
    // Marker elements and report rows.
    let mut rows = Vec::new();
    let mut els = Vec::new();
    for (level, code, body, pt, q) in &markers {
        let name = format!("{level}_{code}");
        rows.push(MarkerRow {
            name: name.clone(),
            body: body.clone(),
            location: [pt.x, pt.y, pt.z],
            surface_distance_mm: q.distance(pt) * 1e3,
        });
        els.push(builders::marker(
            &name,
            &format!("/bodyset/{body}"),
            &pt.coords,
            true,
        ));
    }
    doc.set_objects_mut("MarkerSet")
        .children
        .extend(els.into_iter().map(Node::Element));
    Ok(Markers { rows, findings })
}

/// The S1 plateau on the sacrum mesh (sacrum body frame): the hint is the
/// L5-S1 joint's parent frame; L5's palpation, carried into the sacrum's
/// frame at the default pose, selects the plateau and gives the coarse
/// layout, with L5's lateral landmarks by the protocol's literal rule
/// (the furthest points, as operators and the scoliosis-dev maker copy
/// them onto a coarse plateau; at the default pose of a base they are
/// well defined, and a patient's sacrum is registered to the base's by
/// its surface, [`crate::segmentation`]).
fn palpate_sacrum_of(
    doc: &Document,
    mesh: &TriMesh,
    vs: &[Vert],
    palps: &[VertebraPalpation],
    topo: &Topology,
) -> Result<VertebraPalpation> {
    let i = topo
        .ivd
        .iter()
        .find(|(u, _, _)| *u == Level::L5)
        .map(|(_, _, i)| *i)
        .ok_or_else(|| Error::invalid(doc.path().display().to_string(), "no L5-S1 joint"))?;
    let joint: &Isometry3<f64> = &topo.frames[i].parent_in_body;
    let model = doc.model()?;
    let kin = super::kin::Kinematics::new(&model)?;
    let pose = kin.body_poses(&kin.default_values())?;
    let hint = FrameHint {
        anterior: joint.rotation * Vector3::x(),
        cranial: joint.rotation * Vector3::y(),
    };
    let l5 = vs.iter().zip(palps).find(|(v, _)| v.level == Level::L5);
    let facing = l5.and_then(|(v, p)| {
        let to_sacrum = pose.get("sacrum")?.inverse() * pose.get(&v.body)?;
        Some(p.with_furthest_laterals().transformed(&to_sacrum))
    });
    palpation::palpate_sacrum(mesh, &hint, facing.as_ref())
}

/// The modeller's S1 landmarks replace the engine's.
fn sacrum_overrides(
    s1: &mut VertebraPalpation,
    topo: &Topology,
    ov: &Overrides,
) -> Result<Vec<String>> {
    let src = ov.sources.join(", ");
    let ctx = format!("base --palpation ({src})");
    let mut done = Vec::new();
    let given_s1: BTreeMap<Code, &Placed> = ov
        .landmarks
        .iter()
        .filter(|((l, _), _)| l.is_sacrum())
        .map(|((_, c), p)| (*c, p))
        .collect();
    for (c, placed) in given_s1 {
        let point = placed.in_body("sacrum", &topo.poses, &ctx)?;
        s1.landmarks.insert(c, given(point, &src));
        done.push(format!("S1_{c}"));
    }
    Ok(done)
}
