//! Meshes to a label map and a label map to NIfTI-1 bytes: the inverse of
//! [`super::labelmap`], for tests, benchmarks and synthetic data. A voxel
//! takes a mesh's label when its centre is inside the (closed) mesh, by
//! scan lines along k: each triangle's crossings of the voxel-centre lines
//! are collected per (i, j) column and the voxels between pairs of
//! crossings filled (even-odd rule).

use super::nifti::LabelMap;
use crate::mesh::TriMesh;
use nalgebra::{Matrix4, Point3};
use std::collections::HashMap;

/// A label map of `dims` voxels with voxel-to-world `affine` (mm), each
/// mesh (world mm) filled with its label; later meshes win on overlap.
pub fn voxelise(meshes: &[(u16, &TriMesh)], dims: [usize; 3], affine: Matrix4<f64>) -> LabelMap {
    let inv = affine.try_inverse().unwrap_or_else(Matrix4::identity);
    let mut labels = vec![0u16; dims[0] * dims[1] * dims[2]];
    for (label, mesh) in meshes {
        let ijk: Vec<Point3<f64>> = mesh
            .vertices
            .iter()
            .map(|v| Point3::from_homogeneous(inv * v.to_homogeneous()).unwrap_or(*v))
            .collect();
        for ((i, j), mut ks) in crossings(&ijk, &mesh.triangles, dims) {
            ks.sort_by(f64::total_cmp);
            for pair in ks.chunks_exact(2) {
                let k0 = pair[0].ceil().max(0.0) as usize;
                let k1 = (pair[1].floor() as i64).min(dims[2] as i64 - 1);
                for k in k0 as i64..=k1 {
                    labels[i + dims[0] * (j + dims[1] * k as usize)] = *label;
                }
            }
        }
    }
    LabelMap {
        dims,
        labels,
        affine,
        transform: "sform",
        notes: vec![],
    }
}

/// For each voxel-centre column (i, j) inside the grid, the k of every
/// triangle crossing it.
fn crossings(
    p: &[Point3<f64>],
    tris: &[[u32; 3]],
    dims: [usize; 3],
) -> HashMap<(usize, usize), Vec<f64>> {
    let mut out: HashMap<(usize, usize), Vec<f64>> = HashMap::new();
    for t in tris {
        let [a, b, c] = t.map(|k| p[k as usize]);
        let lo = |f: fn(&Point3<f64>) -> f64| f(&a).min(f(&b)).min(f(&c));
        let hi = |f: fn(&Point3<f64>) -> f64| f(&a).max(f(&b)).max(f(&c));
        let i0 = lo(|q| q.x).ceil().max(0.0) as usize;
        let i1 = (hi(|q| q.x).floor() as i64).min(dims[0] as i64 - 1);
        let j0 = lo(|q| q.y).ceil().max(0.0) as usize;
        let j1 = (hi(|q| q.y).floor() as i64).min(dims[1] as i64 - 1);
        for i in i0 as i64..=i1 {
            for j in j0 as i64..=j1 {
                if let Some(k) = column_hit(&a, &b, &c, i as f64, j as f64) {
                    out.entry((i as usize, j as usize)).or_default().push(k);
                }
            }
        }
    }
    out
}

/// The k where the line (x, y) = (i, j) crosses triangle abc. The line
/// is moved by a tiny irrational offset so that it never passes exactly
/// through an edge or a vertex (each crossing counted once).
fn column_hit(a: &Point3<f64>, b: &Point3<f64>, c: &Point3<f64>, i: f64, j: f64) -> Option<f64> {
    let (i, j) = (i + 1.234_567_1e-7, j + 2.718_281_8e-7);
    let e = |p: &Point3<f64>, q: &Point3<f64>| (q.x - p.x) * (j - p.y) - (q.y - p.y) * (i - p.x);
    let (w0, w1, w2) = (e(b, c), e(c, a), e(a, b));
    let inside = (w0 > 0.0 && w1 > 0.0 && w2 > 0.0) || (w0 < 0.0 && w1 < 0.0 && w2 < 0.0);
    inside.then(|| (w0 * a.z + w1 * b.z + w2 * c.z) / (w0 + w1 + w2))
}

/// Which header transform [`nifti_bytes`] writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HeaderTransform {
    /// `srow_*` rows, `sform_code` 1, `qform_code` 0.
    Sform,
    /// Quaternion, `pixdim` and offsets, `qform_code` 1, `sform_code` 0
    /// (the affine must be a rotation times voxel sizes, k possibly flipped).
    Qform,
}

/// NIfTI-1 single-file bytes (`.nii`) of a label map: uint16 labels, the
/// affine as sform or qform (code 1, scanner anatomical); units mm.
pub fn nifti_bytes(map: &LabelMap, how: HeaderTransform) -> Vec<u8> {
    let mut h = vec![0u8; 352];
    let put_i16 =
        |h: &mut Vec<u8>, at: usize, v: i16| h[at..at + 2].copy_from_slice(&v.to_le_bytes());
    let put_f32 =
        |h: &mut Vec<u8>, at: usize, v: f32| h[at..at + 4].copy_from_slice(&v.to_le_bytes());
    h[0..4].copy_from_slice(&348i32.to_le_bytes());
    put_i16(&mut h, 40, 3);
    for k in 0..3 {
        put_i16(&mut h, 42 + 2 * k, map.dims[k] as i16);
    }
    for k in 3..7 {
        put_i16(&mut h, 42 + 2 * k, 1);
    }
    put_i16(&mut h, 70, 512); // uint16
    put_i16(&mut h, 72, 16);
    let sp = map.spacing();
    put_f32(&mut h, 76, 1.0);
    for k in 0..3 {
        put_f32(&mut h, 80 + 4 * k, sp[k] as f32);
    }
    put_f32(&mut h, 108, 352.0);
    put_f32(&mut h, 112, 1.0);
    h[123] = 2; // mm
    match how {
        HeaderTransform::Sform => {
            put_i16(&mut h, 254, 1); // sform_code: scanner anatomical
            for r in 0..3 {
                for c in 0..4 {
                    put_f32(&mut h, 280 + 16 * r + 4 * c, map.affine[(r, c)] as f32);
                }
            }
        }
        HeaderTransform::Qform => {
            put_i16(&mut h, 252, 1); // qform_code
            let (qfac, [b, c, d]) = quaternion(map);
            put_f32(&mut h, 76, qfac);
            for (k, v) in [b, c, d].into_iter().enumerate() {
                put_f32(&mut h, 256 + 4 * k, v as f32);
            }
            for k in 0..3 {
                put_f32(&mut h, 268 + 4 * k, map.affine[(k, 3)] as f32);
            }
        }
    }
    h[344..348].copy_from_slice(b"n+1\0");
    h.reserve(map.labels.len() * 2);
    for l in &map.labels {
        h.extend_from_slice(&l.to_le_bytes());
    }
    h
}

/// `qfac` and the quaternion (b, c, d) of the affine's rotation (a >= 0).
fn quaternion(map: &LabelMap) -> (f32, [f64; 3]) {
    let sp = map.spacing();
    let mut r = map.affine.fixed_view::<3, 3>(0, 0).into_owned();
    for k in 0..3 {
        r.set_column(k, &(r.column(k) / sp[k]));
    }
    let qfac = if r.determinant() < 0.0 { -1.0 } else { 1.0 };
    r.set_column(2, &(r.column(2) * qfac));
    let q = nalgebra::UnitQuaternion::from_matrix(&r);
    let s = if q.w < 0.0 { -1.0 } else { 1.0 };
    (qfac as f32, [s * q.i, s * q.j, s * q.k])
}
