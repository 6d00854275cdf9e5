//! Automatic virtual palpation of the landmark set of
//! `../shared/formats/landmarks.md` on a model's own meshes, so that patient
//! landmark sets can be matched by name.
//!
//! Vertebrae (mesh in its body frame: X anterior, Y cranial, Z right; `m`
//! the midpoint of the joint-chain [`Segment`], which the sanity check has
//! put inside the vertebral body):
//! 1. walls by ray casting from `m`: anterior wall (first hit along +X),
//!    posterior wall `x_pw` (first hit along -X) and the front of the
//!    neural arch `x_arch` (second hit along -X; several heights are tried;
//!    if the canal is never closed the arch is put 0.6 body depths behind
//!    the wall); right/left walls (first hits along +Z/-Z);
//! 2. the vertebral body is the set of vertices with `x >= x_pw - 1 mm`
//!    between the lateral walls (+-1 mm); its height range `[y_bot, y_top]`;
//! 3. superior endplate band: body vertices with `y >= y_top - 0.2 (y_top -
//!    y_bot)`; SA/SP/SR/SL are its extreme vertices along +X/-X/+Z/-Z;
//!    inferior band and IA/IP/IR/IL likewise at the bottom;
//! 4. SEC/IEC: the centre of the band's outline (mid SA-SP in X, mid SR-SL
//!    in Z) projected onto the endplate by a ray along +Y/-Y from the body's
//!    mid-height (closest surface point if the ray misses);
//! 5. pedicles: the canal's lateral borders are the first hits along +-Z
//!    from the canal centre (`(x_pw + x_arch)/2`, several heights, nearest
//!    hit kept); a pedicle is the set of vertices beside the canal
//!    (`|z|` from 0.8 to 1 canal half-width plus 0.6 body half-width) in
//!    the anterior 70 % of the canal depth; PT = its most cranial vertex,
//!    PB = its most caudal vertex.
//!
//! Sacrum (mesh in the sacrum body frame; the L5-S1 joint's parent frame
//! gives the disc centre `c` and the S1 endplate axes: normal `n` = frame
//! Y, anterior = frame X, right = frame Z):
//! S1_SEC = first hit of the ray from `c` along `-n` (re-centred once on
//! the endplate outline); the endplate is the set of vertices within 2.5 mm
//! of the plane through S1_SEC normal to `n` and within 28 mm of S1_SEC;
//! S1_SA/SP/SR/SL are its extremes along the frame's +X/-X/+Z/-Z.
//!
//! Every landmark is a mesh vertex or a ray hit on the surface, so it lies
//! on the surface up to rounding.

use super::sanity::Segment;
use crate::error::{Error, Result};
use crate::landmarks::Code;
use crate::mesh::{MeshQuery, TriMesh};
use nalgebra::{Isometry3, Point3, Vector3};
use std::collections::BTreeMap;

/// Landmarks of one vertebra (or the sacrum), in its body frame.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Palpation {
    /// Landmark positions by code (m).
    pub points: BTreeMap<Code, Point3<f64>>,
    /// Ordering checks that failed (empty when all hold).
    pub ordering_failures: Vec<String>,
}

fn first_hit(q: &MeshQuery, o: &Point3<f64>, d: &Vector3<f64>) -> Option<f64> {
    q.ray_hits(o, d, f64::MAX)
        .into_iter()
        .map(|h| h.t)
        .find(|t| *t > 1e-9)
}

fn argmax<'a>(
    pts: &[&'a Point3<f64>],
    key: impl Fn(&Point3<f64>) -> f64,
) -> Option<&'a Point3<f64>> {
    pts.iter().copied().max_by(|a, b| key(a).total_cmp(&key(b)))
}

/// The vertebral body located in a vertebra mesh (steps 1-2 of the
/// module rule), in the body frame.
#[derive(Debug, Clone, PartialEq)]
pub struct BodyRegion {
    /// Anterior and posterior wall X at the segment midpoint (m).
    pub x_anterior: f64,
    pub x_posterior: f64,
    /// X of the front of the neural arch (canal's posterior border).
    pub x_arch: f64,
    /// Right and left wall Z (m).
    pub z_right: f64,
    pub z_left: f64,
    /// Indices of the mesh vertices on the vertebral body.
    pub vertices: Vec<usize>,
}

impl BodyRegion {
    /// The sub-mesh of triangles whose three corners are on the body.
    pub fn submesh(&self, mesh: &TriMesh) -> TriMesh {
        let mut map = vec![u32::MAX; mesh.vertices.len()];
        let mut vertices = Vec::new();
        for &i in &self.vertices {
            if let Some(slot) = map.get_mut(i) {
                *slot = vertices.len() as u32;
                vertices.push(mesh.vertices[i]);
            }
        }
        let triangles = mesh
            .triangles
            .iter()
            .filter_map(|t| {
                let m = t.map(|k| map.get(k as usize).copied().unwrap_or(u32::MAX));
                m.iter().all(|&k| k != u32::MAX).then_some(m)
            })
            .collect();
        TriMesh {
            vertices,
            triangles,
        }
    }
}

/// Locate the vertebral body (walls, canal front, body vertices).
pub fn body_region(ctx: &str, q: &MeshQuery, seg: &Segment) -> Result<BodyRegion> {
    let err = |m: String| Error::invalid(ctx.to_string(), format!("virtual palpation: {m}"));
    let m = seg.at(0.5);
    let h = seg.height();
    let (ex, ez) = (Vector3::x(), Vector3::z());
    let x_aw = m.x
        + first_hit(q, &m, &ex)
            .ok_or_else(|| err("no anterior wall of the vertebral body".into()))?;
    // Posterior wall and arch, at a few heights.
    let mut x_pw = None;
    let mut x_arch = None;
    for dy in [0.0, 0.15, -0.15, 0.3, -0.3] {
        let o = m + Vector3::y() * (dy * h);
        if q.signed_distance(&o) > 0.0 {
            continue;
        }
        let hits: Vec<f64> = q
            .ray_hits(&o, &(-ex), f64::MAX)
            .into_iter()
            .map(|hit| hit.t)
            .filter(|t| *t > 1e-9)
            .collect();
        if x_pw.is_none() {
            x_pw = hits.first().map(|t| o.x - t);
        }
        if let (Some(t0), Some(t1)) = (hits.first(), hits.get(1)) {
            x_pw = Some(o.x - t0);
            x_arch = Some(o.x - t1);
            break;
        }
    }
    let x_pw = x_pw.ok_or_else(|| err("no posterior wall of the vertebral body".into()))?;
    let depth = x_aw - x_pw;
    if depth <= 0.0 {
        return Err(err("the vertebral body has no depth along X".into()));
    }
    let x_arch = x_arch.unwrap_or(x_pw - 0.6 * depth);
    let z_r = m.z + first_hit(q, &m, &ez).ok_or_else(|| err("no right wall".into()))?;
    let z_l = m.z - first_hit(q, &m, &(-ez)).ok_or_else(|| err("no left wall".into()))?;
    let vertices: Vec<usize> = q
        .mesh()
        .vertices
        .iter()
        .enumerate()
        .filter(|(_, p)| {
            p.x >= x_pw - 0.001
                && p.z <= z_r + 0.001
                && p.z >= z_l - 0.001
                && p.y >= seg.inferior.y - 0.3 * h
                && p.y <= seg.superior.y + 0.3 * h
        })
        .map(|(i, _)| i)
        .collect();
    if vertices.len() < 8 {
        return Err(err(format!(
            "only {} vertices on the vertebral body",
            vertices.len()
        )));
    }
    Ok(BodyRegion {
        x_anterior: x_aw,
        x_posterior: x_pw,
        x_arch,
        z_right: z_r,
        z_left: z_l,
        vertices,
    })
}

/// Palpate a vertebra mesh `q` (in its body frame) around its segment.
pub fn palpate_vertebra(ctx: &str, q: &MeshQuery, seg: &Segment) -> Result<Palpation> {
    let err = |m: String| Error::invalid(ctx.to_string(), format!("virtual palpation: {m}"));
    let m = seg.at(0.5);
    let h = seg.height();
    let ez = Vector3::z();
    let region = body_region(ctx, q, seg)?;
    let (x_pw, x_arch, z_r, z_l) = (
        region.x_posterior,
        region.x_arch,
        region.z_right,
        region.z_left,
    );
    let verts = &q.mesh().vertices;
    let body: Vec<&Point3<f64>> = region.vertices.iter().map(|&i| &verts[i]).collect();
    let y_top = body.iter().map(|p| p.y).fold(f64::MIN, f64::max);
    let y_bot = body.iter().map(|p| p.y).fold(f64::MAX, f64::min);
    let band = 0.2 * (y_top - y_bot);
    let sup: Vec<&Point3<f64>> = body
        .iter()
        .copied()
        .filter(|p| p.y >= y_top - band)
        .collect();
    let inf: Vec<&Point3<f64>> = body
        .iter()
        .copied()
        .filter(|p| p.y <= y_bot + band)
        .collect();
    let mut out = Palpation::default();
    let y_mid = 0.5 * (y_top + y_bot);
    for (pts, codes, dir) in [
        (
            &sup,
            [Code::SA, Code::SP, Code::SR, Code::SL, Code::SEC],
            1.0,
        ),
        (
            &inf,
            [Code::IA, Code::IP, Code::IR, Code::IL, Code::IEC],
            -1.0,
        ),
    ] {
        let a = argmax(pts, |p| p.x).ok_or_else(|| err("empty endplate band".into()))?;
        let p = argmax(pts, |p| -p.x).ok_or_else(|| err("empty endplate band".into()))?;
        let r = argmax(pts, |p| p.z).ok_or_else(|| err("empty endplate band".into()))?;
        let l = argmax(pts, |p| -p.z).ok_or_else(|| err("empty endplate band".into()))?;
        out.points.insert(codes[0], *a);
        out.points.insert(codes[1], *p);
        out.points.insert(codes[2], *r);
        out.points.insert(codes[3], *l);
        let o = Point3::new(0.5 * (a.x + p.x), y_mid, 0.5 * (r.z + l.z));
        let d = Vector3::y() * dir;
        let c = match first_hit(q, &o, &d) {
            Some(t) if q.signed_distance(&o) <= 0.0 => o + d * t,
            _ => {
                let y_end = if dir > 0.0 { y_top } else { y_bot };
                q.closest_point(&Point3::new(o.x, y_end, o.z)).point
            }
        };
        out.points.insert(codes[4], c);
    }
    // Canal borders.
    let x_cc = 0.5 * (x_pw + x_arch);
    let mut w_r = f64::MAX;
    let mut w_l = f64::MAX;
    for k in 0..9 {
        let y = y_bot + (y_top - y_bot) * (0.1 + 0.1 * k as f64);
        let o = Point3::new(x_cc, y, m.z);
        if q.signed_distance(&o) < 0.0 {
            continue; // inside bone, not in the canal
        }
        if let Some(t) = first_hit(q, &o, &ez) {
            w_r = w_r.min(t);
        }
        if let Some(t) = first_hit(q, &o, &(-ez)) {
            w_l = w_l.min(t);
        }
    }
    let half_body = 0.5 * (z_r - z_l);
    if w_r == f64::MAX {
        w_r = 0.3 * half_body;
    }
    if w_l == f64::MAX {
        w_l = 0.3 * half_body;
    }
    let canal_depth = (x_pw - x_arch).max(1e-4);
    for (side, w, codes) in [
        (1.0, w_r, [Code::PTR, Code::PBR]),
        (-1.0, w_l, [Code::PTL, Code::PBL]),
    ] {
        let mut found = None;
        for frac in [0.7, 1.0, 1.3] {
            let region: Vec<&Point3<f64>> = verts
                .iter()
                .filter(|p| {
                    let zz = side * (p.z - m.z);
                    p.x <= x_pw + 0.0005
                        && p.x >= x_pw - frac * canal_depth
                        && zz >= 0.8 * w
                        && zz <= w + 0.6 * half_body
                        && p.y >= y_bot - 0.2 * h
                        && p.y <= y_top + 0.2 * h
                })
                .collect();
            let top = argmax(&region, |p| p.y);
            let bot = argmax(&region, |p| -p.y);
            if let (Some(t), Some(b)) = (top, bot) {
                if t.y > b.y {
                    found = Some((*t, *b));
                    break;
                }
            }
        }
        let (t, b) = found.ok_or_else(|| {
            err(format!(
                "no {} pedicle found beside the canal",
                if side > 0.0 { "right" } else { "left" }
            ))
        })?;
        out.points.insert(codes[0], t);
        out.points.insert(codes[1], b);
    }
    out.ordering_failures = vertebra_orderings(&out.points);
    Ok(out)
}

/// The left/right, superior/inferior and anterior/posterior orderings a
/// vertebra's 14 landmarks must satisfy (body frame); returns the failures.
pub fn vertebra_orderings(p: &BTreeMap<Code, Point3<f64>>) -> Vec<String> {
    use Code::*;
    let mut fails = Vec::new();
    let mut check = |a: Code, b: Code, axis: usize, what: &str| {
        if let (Some(pa), Some(pb)) = (p.get(&a), p.get(&b)) {
            if pa[axis] <= pb[axis] {
                fails.push(format!("{a} is not {what} of {b}"));
            }
        } else {
            fails.push(format!("{a} or {b} missing"));
        }
    };
    for (a, b) in [(SR, SL), (IR, IL), (PTR, PTL), (PBR, PBL)] {
        check(a, b, 2, "right");
    }
    for (a, b) in [
        (SEC, IEC),
        (SA, IA),
        (SP, IP),
        (SR, IR),
        (SL, IL),
        (PTR, PBR),
        (PTL, PBL),
    ] {
        check(a, b, 1, "superior");
    }
    for (a, b) in [
        (SA, SP),
        (IA, IP),
        (SEC, PTR),
        (SEC, PTL),
        (IEC, PBR),
        (IEC, PBL),
    ] {
        check(a, b, 0, "anterior");
    }
    fails
}

/// Palpate the S1 superior endplate on a sacrum mesh `q` (sacrum body
/// frame); `joint` is the L5-S1 joint's parent frame in the sacrum.
pub fn palpate_sacrum(ctx: &str, q: &MeshQuery, joint: &Isometry3<f64>) -> Result<Palpation> {
    let err = |m: String| Error::invalid(ctx.to_string(), format!("virtual palpation: {m}"));
    let c = Point3::from(joint.translation.vector);
    let rot = joint.rotation;
    let (xa, n, zr) = (rot * Vector3::x(), rot * Vector3::y(), rot * Vector3::z());
    let hit = |o: &Point3<f64>| first_hit(q, o, &(-n)).map(|t| o - n * t);
    let mut sec = hit(&c).ok_or_else(|| {
        err("no S1 endplate below the L5-S1 joint centre (is the sacrum mesh registered?)".into())
    })?;
    let mut pts = BTreeMap::new();
    for pass in 0..2 {
        let region: Vec<&Point3<f64>> = q
            .mesh()
            .vertices
            .iter()
            .filter(|p| {
                let d = *p - sec;
                let dn = d.dot(&n);
                dn.abs() <= 0.0025 && (d - n * dn).norm() <= 0.028
            })
            .collect();
        if region.len() < 4 {
            return Err(err(format!(
                "only {} vertices on the S1 endplate",
                region.len()
            )));
        }
        let a = argmax(&region, |p| (p - sec).dot(&xa)).copied();
        let pp = argmax(&region, |p| -(p - sec).dot(&xa)).copied();
        let r = argmax(&region, |p| (p - sec).dot(&zr)).copied();
        let l = argmax(&region, |p| -(p - sec).dot(&zr)).copied();
        let (Some(a), Some(pp), Some(r), Some(l)) = (a, pp, r, l) else {
            return Err(err("empty S1 endplate".into()));
        };
        pts.insert(Code::SA, a);
        pts.insert(Code::SP, pp);
        pts.insert(Code::SR, r);
        pts.insert(Code::SL, l);
        if pass == 0 {
            // Re-centre on the outline and project again.
            let centre = sec
                + xa * (0.5 * ((a - sec).dot(&xa) + (pp - sec).dot(&xa)))
                + zr * (0.5 * ((r - sec).dot(&zr) + (l - sec).dot(&zr)));
            if let Some(s) = hit(&(centre + n * 0.01)) {
                sec = s;
            }
        }
    }
    pts.insert(Code::SEC, sec);
    let mut fails = Vec::new();
    let along = |c: Code, v: &Vector3<f64>| pts.get(&c).map(|p| (p - sec).dot(v)).unwrap_or(0.0);
    if along(Code::SR, &zr) <= along(Code::SL, &zr) {
        fails.push("S1_SR is not right of S1_SL".to_string());
    }
    if along(Code::SA, &xa) <= along(Code::SP, &xa) {
        fails.push("S1_SA is not anterior of S1_SP".to_string());
    }
    Ok(Palpation {
        points: pts,
        ordering_failures: fails,
    })
}
