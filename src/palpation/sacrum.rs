//! The S1 superior endplate (sacral plateau): `S1_SEC`, `S1_SA`, `S1_SP`,
//! `S1_SR`, `S1_SL` by the endplate rules, on the plateau found as the
//! largest flat cranial patch on the midline (or the one facing L5's
//! inferior endplate when that is given). Where the plateau is too coarse
//! (fewer than 4 faces, no mid-sagittal section, or shallower than half
//! the L5 inferior endplate), the points keep the layout of the L5
//! inferior endplate about `S1_SEC` (the protocol's coarse fallback).

use super::body::{endplate_points, Endplate, EndplatePoints};
use super::local::{frame_rotation, prepare, LocalMesh};
use super::{
    frame, landmark, protocol_findings, Finding, FrameHint, PalpatedLandmark, Severity,
    VertebraPalpation,
};
use crate::error::{Error, Result};
use crate::landmarks::{Code, Level};
use crate::mesh::{MeshQuery, TriMesh};
use nalgebra::{Isometry3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use std::collections::BTreeMap;

/// Connected groups of the given faces (sharing an edge).
fn components(lm: &LocalMesh, faces: &[usize]) -> Vec<Vec<usize>> {
    let mut parent: Vec<usize> = (0..faces.len()).collect();
    fn root(p: &mut [usize], i: usize) -> usize {
        let mut r = i;
        while p[r] != r {
            r = p[r];
        }
        p[i] = r;
        r
    }
    let mut edge_owner: BTreeMap<[u32; 2], usize> = BTreeMap::new();
    for (i, &f) in faces.iter().enumerate() {
        let t = lm.tris[f];
        for j in 0..3 {
            let e = [t[j].min(t[(j + 1) % 3]), t[j].max(t[(j + 1) % 3])];
            if let Some(&k) = edge_owner.get(&e) {
                let (a, b) = (root(&mut parent, i), root(&mut parent, k));
                parent[a] = b;
            } else {
                edge_owner.insert(e, i);
            }
        }
    }
    let mut groups: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
    for (i, &f) in faces.iter().enumerate() {
        let r = root(&mut parent, i);
        groups.entry(r).or_default().push(f);
    }
    groups.into_values().collect()
}

/// The plateau patch: cranial-facing midline faces, grouped; the largest,
/// or the one nearest L5's inferior endplate centre (local coordinates).
fn plateau_patch(lm: &LocalMesh, l5_iec: Option<Point3<f64>>) -> Option<Vec<usize>> {
    let zs = lm.verts.iter().map(|p| p.z.abs()).fold(0.0, f64::max);
    let cos50 = 50f64.to_radians().cos();
    let cand: Vec<usize> = (0..lm.tris.len())
        .filter(|&f| lm.normals[f].y >= cos50 && lm.centroids[f].z.abs() < 0.3 * zs)
        .collect();
    let groups = components(lm, &cand);
    let area = |g: &Vec<usize>| g.iter().map(|&f| lm.areas[f]).sum::<f64>();
    let max_area = groups.iter().map(area).fold(0.0, f64::max);
    let centroid = |g: &Vec<usize>| {
        Point3::from(
            g.iter().fold(Vector3::zeros(), |s, &f| {
                s + lm.centroids[f].coords * lm.areas[f]
            }) / area(g),
        )
    };
    match l5_iec {
        Some(t) => groups
            .into_iter()
            .filter(|g| area(g) >= 0.1 * max_area)
            .min_by(|a, b| {
                (centroid(a) - t)
                    .norm()
                    .total_cmp(&(centroid(b) - t).norm())
            }),
        None => groups
            .into_iter()
            .max_by(|a, b| area(a).total_cmp(&area(b))),
    }
}

/// The plateau region by the endplate rule around the patch.
fn plateau_region(lm: &LocalMesh, patch: &[usize]) -> Option<Endplate> {
    let a: f64 = patch.iter().map(|&f| lm.areas[f]).sum();
    let n = patch
        .iter()
        .fold(Vector3::zeros(), |s, &f| s + lm.normals[f] * lm.areas[f])
        .try_normalize(1e-12)?;
    let mut hs: Vec<f64> = patch
        .iter()
        .map(|&f| n.dot(&lm.centroids[f].coords))
        .collect();
    hs.sort_by(f64::total_cmp);
    let d = hs[hs.len() / 2];
    let (mut lo, mut hi) = (
        Point3::new(f64::MAX, 0.0, f64::MAX),
        Point3::new(f64::MIN, 0.0, f64::MIN),
    );
    for &f in patch {
        let c = lm.centroids[f];
        (lo.x, lo.z, hi.x, hi.z) = (lo.x.min(c.x), lo.z.min(c.z), hi.x.max(c.x), hi.z.max(c.z));
    }
    let (m, tol, cos40) = (0.003, 0.003, 40f64.to_radians().cos());
    let faces: Vec<usize> = (0..lm.tris.len())
        .filter(|&f| {
            let c = lm.centroids[f];
            lm.normals[f].dot(&n) >= cos40
                && (n.dot(&c.coords) - d).abs() <= tol
                && c.x >= lo.x - m
                && c.x <= hi.x + m
                && c.z >= lo.z - m
                && c.z <= hi.z + m
        })
        .collect();
    let area = faces.iter().map(|&f| lm.areas[f]).sum();
    (a > 0.0 && !faces.is_empty()).then_some(Endplate {
        faces,
        normal: n,
        offset: d,
        area,
    })
}

/// The plateau frame (X anterior in the plateau, Y its normal, Z right), local.
fn plateau_rotation(n: &Vector3<f64>) -> Rotation3<f64> {
    let x = (Vector3::x() - n * n.x).normalize();
    let z = x.cross(n);
    Rotation3::from_basis_unchecked(&[x, *n, z])
}

/// Palpate the sacrum's S1 plateau; `facing_l5` (same coordinates as the
/// mesh) selects the plateau and gives the coarse-mesh layout.
pub fn palpate_sacrum(
    mesh: &TriMesh,
    hint: &FrameHint,
    facing_l5: Option<&VertebraPalpation>,
) -> Result<VertebraPalpation> {
    let ctx = "palpation of S1";
    let prepared = prepare(mesh, ctx)?;
    let q = MeshQuery::new(&prepared)?;
    let plane = frame::symmetry_plane(&prepared, &q, &hint.right())
        .ok_or_else(|| Error::invalid(ctx, "cannot estimate the mid-sagittal plane"))?;
    let n = plane.normal;
    let c = prepared.area_centroid().unwrap_or(prepared.vertices[0]);
    let origin = c - n * (n.dot(&c.coords) - plane.offset);
    let lm = LocalMesh::new(&prepared, frame_rotation(&hint.anterior, &n), origin);
    let l5_iec = facing_l5
        .and_then(|l5| l5.landmarks.get(&Code::IEC))
        .map(|l| lm.to_mesh.inverse() * l.point);
    let patch = plateau_patch(&lm, l5_iec).ok_or_else(|| {
        Error::invalid(ctx, "SEC: no cranial-facing patch on the sacrum's midline")
    })?;
    let ep = plateau_region(&lm, &patch)
        .ok_or_else(|| Error::invalid(ctx, "SEC: the sacral plateau region is empty"))?;
    let pts = endplate_points(&lm, &ep)
        .ok_or_else(|| Error::invalid(ctx, "SEC: the sacral plateau region is degenerate"))?;
    let rot = plateau_rotation(&ep.normal);
    let mut findings = Vec::new();
    let mut landmarks = plateau_landmarks(&lm, &ep, &pts, &rot, facing_l5, &mut findings)?;
    for l in landmarks.values_mut() {
        l.point = lm.to_mesh_point(&l.point);
    }
    let depth = (pts.front - pts.back).norm();
    let centre_local = pts.centre - ep.normal * (0.3 * depth);
    let frame_rot = lm.to_mesh.rotation * UnitQuaternion::from_rotation_matrix(&rot);
    let sec = landmarks[&Code::SEC].point;
    let mut out = VertebraPalpation {
        level: Level::S1,
        frame: Isometry3::from_parts(Translation3::from(sec.coords), frame_rot),
        landmarks,
        centre: lm.to_mesh_point(&centre_local),
        centre_radius: 0.25 * (pts.right - pts.left).norm(),
        findings,
    };
    out.findings.extend(protocol_findings(&out));
    Ok(out)
}

/// S1_SEC..S1_SL by the endplate rules, or the L5 layout on a coarse plateau.
fn plateau_landmarks(
    lm: &LocalMesh,
    ep: &Endplate,
    pts: &EndplatePoints,
    rot: &Rotation3<f64>,
    facing_l5: Option<&VertebraPalpation>,
    findings: &mut Vec<Finding>,
) -> Result<BTreeMap<Code, PalpatedLandmark>> {
    use Code::*;
    let mut out = BTreeMap::new();
    out.insert(SEC, landmark(pts.centre, 1.0, None));
    let depth = (pts.front - pts.back).norm();
    let l5_depth = facing_l5.and_then(|l5| Some((l5.local(IA)? - l5.local(IP)?).norm()));
    let coarse =
        ep.faces.len() < 4 || !pts.midline_section || l5_depth.is_some_and(|d| depth < 0.5 * d);
    let layout = facing_l5.filter(|_| coarse);
    let Some(l5) = layout else {
        for (c, p) in [
            (SA, pts.front),
            (SP, pts.back),
            (SR, pts.right),
            (SL, pts.left),
        ] {
            let conf = if coarse { 0.5 } else { 1.0 };
            let note = coarse
                .then(|| "coarse sacral plateau and no L5 to copy the layout from".to_string());
            out.insert(c, landmark(p, conf, note));
        }
        return Ok(out);
    };
    findings.push(Finding {
        level: Level::S1,
        code: Some(SA),
        severity: Severity::Warning,
        message: format!(
            "the sacral plateau is too coarse ({} faces, {:.1} mm deep): SA, SP, SR, SL keep the layout of the L5 inferior endplate",
            ep.faces.len(),
            depth * 1e3
        ),
    });
    let q = lm.query()?;
    let iec = l5
        .local(IEC)
        .ok_or_else(|| Error::invalid("palpation of S1", "L5 has no IEC"))?;
    for (c, from) in [(SA, IA), (SP, IP), (SR, IR), (SL, IL)] {
        let Some(p) = l5.local(from) else { continue };
        let mut v = p - iec;
        v.y = 0.0;
        let target = pts.centre + rot * v;
        let on = q.closest_point(&target).point;
        out.insert(
            c,
            landmark(
                on,
                0.5,
                Some(format!("layout of L5_{from} on a coarse plateau")),
            ),
        );
    }
    Ok(out)
}
