//! The S1 superior endplate (sacral plateau): `S1_SEC`, `S1_SA`, `S1_SP`,
//! `S1_SR`, `S1_SL` by the endplate rules, on the plateau found as the
//! largest flat cranial patch that crosses the midline (of those facing
//! L5's inferior endplate when that is given). Flatness is judged on face
//! normals averaged over 3 mm, so that a voxel surface's staircase does
//! not break the plateau up. The lateral extremes lie in front of the
//! plateau's posterior end (behind it, a real sacrum's plateau runs on into
//! the bases of the superior articular processes and the alae). Where the
//! plateau is too coarse (fewer than 4 faces, no mid-sagittal section, or
//! shallower than half the L5 inferior endplate), the points keep the
//! layout of the L5 inferior endplate (the protocol's coarse fallback),
//! dropped onto the plateau plane and, for `SEC`/`SA`/`SP`, onto the
//! sacrum's own mid-sagittal plane.

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

/// Edge-adjacent faces of every face.
fn neighbours(lm: &LocalMesh) -> Vec<Vec<usize>> {
    let mut edge_faces: BTreeMap<[u32; 2], Vec<usize>> = BTreeMap::new();
    for (f, t) in lm.tris.iter().enumerate() {
        for j in 0..3 {
            let e = [t[j].min(t[(j + 1) % 3]), t[j].max(t[(j + 1) % 3])];
            edge_faces.entry(e).or_default().push(f);
        }
    }
    let mut out = vec![Vec::new(); lm.tris.len()];
    for fs in edge_faces.values() {
        for &a in fs {
            out[a].extend(fs.iter().copied().filter(|&b| b != a));
        }
    }
    out
}

/// Radius (m) over which face normals are averaged before the flatness
/// tests: a voxel surface's staircase (faces along the voxel axes, up to
/// 45 deg off the plateau) averages out over a few voxels, while the faces
/// of a coarse mesh are larger than this and keep their own normal.
const NORMAL_RADIUS: f64 = 0.003;

/// Area-weighted mean normal of the faces connected to each face whose
/// centroids lie within `r` of its centroid (the face itself included).
fn smoothed_normals(lm: &LocalMesh, nb: &[Vec<usize>], r: f64) -> Vec<Vector3<f64>> {
    let mut mark = vec![usize::MAX; lm.tris.len()];
    (0..lm.tris.len())
        .map(|f| {
            let c = lm.centroids[f];
            let (mut stack, mut sum) = (vec![f], Vector3::zeros());
            mark[f] = f;
            while let Some(g) = stack.pop() {
                sum += lm.normals[g] * lm.areas[g];
                for &h in &nb[g] {
                    if mark[h] != f && (lm.centroids[h] - c).norm() <= r {
                        mark[h] = f;
                        stack.push(h);
                    }
                }
            }
            sum.try_normalize(1e-300).unwrap_or(lm.normals[f])
        })
        .collect()
}

/// Largest angle between a face of a flat patch and the patch's seed.
const FLAT_DEG: f64 = 12.0;

/// Flat cranial patches: faces facing within 50 deg of cranial, grown from
/// the largest remaining face over edge neighbours whose normals stay
/// within [`FLAT_DEG`] of the seed's.
fn flat_patches(lm: &LocalMesh, nb: &[Vec<usize>], normals: &[Vector3<f64>]) -> Vec<Vec<usize>> {
    let cos50 = 50f64.to_radians().cos();
    let cos_flat = FLAT_DEG.to_radians().cos();
    let mut cand: Vec<usize> = (0..lm.tris.len())
        .filter(|&f| normals[f].y >= cos50)
        .collect();
    // Seeds by decreasing area (ties by index): deterministic.
    cand.sort_by(|&a, &b| lm.areas[b].total_cmp(&lm.areas[a]).then(a.cmp(&b)));
    let mut taken = vec![false; lm.tris.len()];
    let mut patches = Vec::new();
    for &seed in &cand {
        if taken[seed] {
            continue;
        }
        let n0 = normals[seed];
        let mut patch = vec![seed];
        taken[seed] = true;
        let mut i = 0;
        while i < patch.len() {
            for &g in &nb[patch[i]] {
                if !taken[g] && normals[g].y >= cos50 && normals[g].dot(&n0) >= cos_flat {
                    taken[g] = true;
                    patch.push(g);
                }
            }
            i += 1;
        }
        patch.sort_unstable();
        patches.push(patch);
    }
    patches
}

/// The plateau patch: the largest flat cranial patch; with L5 given, the
/// largest whose centre lies within `reach` of L5's inferior endplate
/// centre (local coordinates).
fn plateau_patch(
    lm: &LocalMesh,
    nb: &[Vec<usize>],
    normals: &[Vector3<f64>],
    l5: Option<(Point3<f64>, f64)>,
) -> Option<Vec<usize>> {
    let area = |g: &Vec<usize>| g.iter().map(|&f| lm.areas[f]).sum::<f64>();
    let centroid = |g: &Vec<usize>| {
        Point3::from(
            g.iter().fold(Vector3::zeros(), |s, &f| {
                s + lm.centroids[f].coords * lm.areas[f]
            }) / area(g),
        )
    };
    // The plateau is on the midline: a patch must reach across the
    // mid-sagittal plane (on a voxel surface the staircase breaks the
    // plateau into small patches, and a flat ala may be the largest one).
    let crosses = |g: &Vec<usize>| {
        let t = &lm.tris;
        let z = g.iter().flat_map(|&f| t[f].map(|k| lm.verts[k as usize].z));
        let (lo, hi) = z.fold((f64::MAX, f64::MIN), |(lo, hi), z| (lo.min(z), hi.max(z)));
        lo <= 0.0 && hi >= 0.0
    };
    let patches = flat_patches(lm, nb, normals);
    let faces_l5 =
        |g: &&Vec<usize>| l5.is_none_or(|(iec, reach)| (centroid(g) - iec).norm() <= reach);
    let near: Vec<&Vec<usize>> = patches.iter().filter(faces_l5).collect();
    let midline: Vec<&Vec<usize>> = near.iter().copied().filter(|g| crosses(g)).collect();
    // The first non-empty of: midline patches facing L5, patches facing
    // L5, every patch.
    let pool = [midline, near]
        .into_iter()
        .find(|g| !g.is_empty())
        .unwrap_or_else(|| patches.iter().collect());
    pool.into_iter()
        .max_by(|a, b| area(a).total_cmp(&area(b)))
        .cloned()
}

/// The plateau plane (area-weighted least-squares plane through the
/// patch's face centroids, normal cranial) and the region by the endplate
/// rule around the patch.
fn plateau_region(
    lm: &LocalMesh,
    nb: &[Vec<usize>],
    normals: &[Vector3<f64>],
    patch: &[usize],
) -> Option<Endplate> {
    let a: f64 = patch.iter().map(|&f| lm.areas[f]).sum();
    if a.is_nan() || a <= 0.0 {
        return None;
    }
    let c = patch.iter().fold(Vector3::zeros(), |s, &f| {
        s + lm.centroids[f].coords * lm.areas[f]
    }) / a;
    let cov = patch.iter().fold(nalgebra::Matrix3::zeros(), |m, &f| {
        let d = lm.centroids[f].coords - c;
        m + d * d.transpose() * lm.areas[f]
    });
    let mean_n = patch
        .iter()
        .fold(Vector3::zeros(), |s, &f| s + lm.normals[f] * lm.areas[f]);
    // A single face (or a strip) does not span a plane: its mean normal.
    let eig = cov.symmetric_eigen();
    let mut ev: Vec<usize> = vec![0, 1, 2];
    ev.sort_by(|&i, &j| eig.eigenvalues[i].total_cmp(&eig.eigenvalues[j]));
    let n = if eig.eigenvalues[ev[1]] > 1e-3 * eig.eigenvalues[ev[2]] {
        let n: Vector3<f64> = eig.eigenvectors.column(ev[0]).into_owned();
        if n.dot(&mean_n) < 0.0 {
            -n
        } else {
            n
        }
    } else {
        mean_n.try_normalize(1e-12)?
    };
    let d = n.dot(&c);
    let (mut lo, mut hi) = (
        Point3::new(f64::MAX, 0.0, f64::MAX),
        Point3::new(f64::MIN, 0.0, f64::MIN),
    );
    for &f in patch {
        let c = lm.centroids[f];
        (lo.x, lo.z, hi.x, hi.z) = (lo.x.min(c.x), lo.z.min(c.z), hi.x.max(c.x), hi.z.max(c.z));
    }
    let (m, tol, cos40) = (0.003, 0.003, 40f64.to_radians().cos());
    let on_plateau =
        |f: usize| normals[f].dot(&n) >= cos40 && (n.dot(&lm.centroids[f].coords) - d).abs() <= tol;
    let in_box =
        |c: &Point3<f64>| c.x >= lo.x - m && c.x <= hi.x + m && c.z >= lo.z - m && c.z <= hi.z + m;
    let mut faces: Vec<usize> = (0..lm.tris.len())
        .filter(|&f| on_plateau(f) && in_box(&lm.centroids[f]))
        .collect();
    faces.extend(connected_beyond(nb, &faces, on_plateau));
    faces.sort_unstable();
    let area = faces.iter().map(|&f| lm.areas[f]).sum();
    (!faces.is_empty()).then_some(Endplate {
        faces,
        normal: n,
        offset: d,
        area,
        tol,
    })
}

/// Faces reachable from `seed` over edge neighbours (`nb`, [`neighbours`])
/// that satisfy `keep`, not already in `seed`: the rest of a plateau whose
/// flat patch was cut short (the normals of a voxel surface's staircase
/// break a patch up).
fn connected_beyond(nb: &[Vec<usize>], seed: &[usize], keep: impl Fn(usize) -> bool) -> Vec<usize> {
    let mut taken = vec![false; nb.len()];
    seed.iter().for_each(|&f| taken[f] = true);
    let mut queue: Vec<usize> = seed.to_vec();
    let mut extra = Vec::new();
    while let Some(f) = queue.pop() {
        for &g in &nb[f] {
            if !taken[g] && keep(g) {
                taken[g] = true;
                queue.push(g);
                extra.push(g);
            }
        }
    }
    extra
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
    let plane = frame::symmetry_plane(&prepared, &q, &hint.right(), &hint.cranial)
        .ok_or_else(|| Error::invalid(ctx, "cannot estimate the mid-sagittal plane"))?;
    let n = plane.normal;
    let c = prepared.area_centroid().unwrap_or(prepared.vertices[0]);
    let origin = c - n * (n.dot(&c.coords) - plane.offset);
    let lm = LocalMesh::new(&prepared, frame_rotation(&hint.anterior, &n), origin);
    // L5's inferior endplate centre and its reach (1.5 x its depth).
    let l5 = facing_l5.and_then(|l5| {
        let iec = l5.landmarks.get(&Code::IEC)?.point;
        let depth =
            (l5.landmarks.get(&Code::IA)?.point - l5.landmarks.get(&Code::IP)?.point).norm();
        Some((lm.to_mesh.inverse() * iec, 1.5 * depth))
    });
    let nb = neighbours(&lm);
    let normals = smoothed_normals(&lm, &nb, NORMAL_RADIUS);
    let patch = plateau_patch(&lm, &nb, &normals, l5).ok_or_else(|| {
        Error::invalid(ctx, "SEC: no cranial-facing patch on the sacrum's midline")
    })?;
    let ep = plateau_region(&lm, &nb, &normals, &patch)
        .ok_or_else(|| Error::invalid(ctx, "SEC: the sacral plateau region is empty"))?;
    // No walls to bound the plateau's X, but its lateral extremes lie in
    // front of its posterior end, as on a vertebra.
    let pts = endplate_points(&lm, &ep, Some((f64::MIN, f64::MAX)))
        .ok_or_else(|| Error::invalid(ctx, "SEC: the sacral plateau region is degenerate"))?;
    let rot = plateau_rotation(&ep.normal);
    let mut findings = Vec::new();
    let mut landmarks = plateau_landmarks(&lm, &ep, &pts, facing_l5, &mut findings)?;
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
        centre_fit: super::CentreFit::default(),
        centre_confidence: 1.0,
        furthest: BTreeMap::new(),
    };
    out.findings.extend(protocol_findings(&out));
    Ok(out)
}

/// A plateau wider than this times L5's inferior endplate runs onto the
/// alae (a real S1 plateau is 0.8-1.4 times as wide as L5's inferior
/// endplate): its lateral extremes are not the plateau's.
const MAX_WIDTH_OF_L5: f64 = 1.5;

/// S1_SEC..S1_SL by the endplate rules, or the L5 layout on a coarse plateau.
fn plateau_landmarks(
    lm: &LocalMesh,
    ep: &Endplate,
    pts: &EndplatePoints,
    facing_l5: Option<&VertebraPalpation>,
    findings: &mut Vec<Finding>,
) -> Result<BTreeMap<Code, PalpatedLandmark>> {
    use Code::*;
    let mut out = BTreeMap::new();
    out.insert(SEC, landmark(pts.centre, 1.0, None));
    let depth = (pts.front - pts.back).norm();
    let width = (pts.right - pts.left).norm();
    let l5_size = facing_l5.and_then(|l5| {
        let d = (l5.local(IA)? - l5.local(IP)?).norm();
        let w = (l5.local(IR)? - l5.local(IL)?).norm();
        Some((d, w))
    });
    let coarse = ep.faces.len() < 4
        || !pts.midline_section
        || l5_size.is_some_and(|(d, w)| depth < 0.5 * d || width > MAX_WIDTH_OF_L5 * w);
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
            "the sacral plateau is too coarse or runs onto the alae ({} faces, {:.1} mm deep, {:.1} mm wide): SEC, SA, SP, SR, SL keep the layout of L5's inferior endplate, on the plateau plane and about the sacrum's own mid-sagittal plane",
            ep.faces.len(),
            depth * 1e3,
            width * 1e3
        ),
    });
    for (c, p) in l5_layout(lm, ep, l5) {
        out.insert(
            c,
            landmark(
                p,
                0.5,
                Some("L5's inferior endplate layout on a coarse plateau".into()),
            ),
        );
    }
    Ok(out)
}

/// The protocol's coarse fallback (local coordinates): L5's inferior
/// landmarks dropped onto the plateau plane, the layout turned about the
/// plateau's normal so that L5's anterior axis is the sacrum's own, and
/// centred on the sacrum's mid-sagittal plane (`SEC`, `SA`, `SP` on it):
/// L5's pose on the sacrum (a scoliotic L5 is rotated and shifted on S1)
/// does not move the sacrum's landmarks, only L5's size and the height of
/// its endplate centre do.
fn l5_layout(lm: &LocalMesh, ep: &Endplate, l5: &VertebraPalpation) -> Vec<(Code, Point3<f64>)> {
    use Code::*;
    let to_local = lm.to_mesh.inverse();
    let n = ep.normal;
    let drop = |p: Point3<f64>| p - n * (n.dot(&p.coords) - ep.offset);
    let Some(iec) = l5.landmarks.get(&IEC).map(|l| drop(to_local * l.point)) else {
        return Vec::new();
    };
    // L5's anterior axis and the sacrum's, in the plateau plane.
    let in_plane = |v: Vector3<f64>| (v - n * n.dot(&v)).try_normalize(1e-9);
    let l5_x = in_plane(to_local.rotation * (l5.frame.rotation * Vector3::x()));
    let own_x = in_plane(Vector3::x());
    let turn = match (l5_x, own_x) {
        (Some(a), Some(b)) => {
            UnitQuaternion::rotation_between(&a, &b).unwrap_or_else(UnitQuaternion::identity)
        }
        _ => UnitQuaternion::identity(),
    };
    // The centre on the sacrum's mid-sagittal plane (z = 0), on the plateau.
    let mut sec = iec;
    sec.z = 0.0;
    let sec = drop(sec);
    let mut out = vec![(SEC, sec)];
    for (c, from) in [(SA, IA), (SP, IP), (SR, IR), (SL, IL)] {
        let Some(l) = l5.landmarks.get(&from).map(|l| l.point) else {
            continue;
        };
        let mut p = sec + turn * (drop(to_local * l) - iec);
        if matches!(c, SA | SP) {
            p.z = 0.0;
        }
        out.push((c, drop(p)));
    }
    out
}
