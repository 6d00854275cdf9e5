//! Fuzz the NIfTI-1 header geometry (`segmentation::nifti::geometry`):
//! any 348 header bytes (the magic forced to `n+1`) must give Ok or a clean
//! Err; an accepted transform must be finite and non-singular, equal the
//! sform rows when the sform is used, and, when the qform is used with
//! positive voxel sizes, equal an independent transcription of
//! `nifti_quatern_to_mat44` (nifti1_io.c); its handedness is qfac's, never
//! a voxel size's sign. Run:
//! `cargo +nightly fuzz run nifti_geometry -- -max_total_time=300`.
#![no_main]

use libfuzzer_sys::fuzz_target;
use osim_spine::segmentation::nifti as labelmaps;
use osim_spine::segmentation::nifti::NiftiHeader;
use std::path::Path;

/// `nifti_quatern_to_mat44`, transcribed: rows of the 3 x 4 transform.
fn reference(h: &NiftiHeader) -> [[f64; 4]; 3] {
    let (mut b, mut c, mut d) = (h.quatern_b as f64, h.quatern_c as f64, h.quatern_d as f64);
    let mut a = 1.0 - (b * b + c * c + d * d);
    if a < 1e-7 {
        a = 1.0 / (b * b + c * c + d * d).sqrt();
        b *= a;
        c *= a;
        d *= a;
        a = 0.0;
    } else {
        a = a.sqrt();
    }
    let pos = |x: f32| if x > 0.0 { x as f64 } else { 1.0 };
    let (xd, yd) = (pos(h.pixdim[1]), pos(h.pixdim[2]));
    let zd = if h.pixdim[0] < 0.0 {
        -pos(h.pixdim[3])
    } else {
        pos(h.pixdim[3])
    };
    [
        [
            (a * a + b * b - c * c - d * d) * xd,
            2.0 * (b * c - a * d) * yd,
            2.0 * (b * d + a * c) * zd,
            h.quatern_x as f64,
        ],
        [
            2.0 * (b * c + a * d) * xd,
            (a * a + c * c - b * b - d * d) * yd,
            2.0 * (c * d - a * b) * zd,
            h.quatern_y as f64,
        ],
        [
            2.0 * (b * d - a * c) * xd,
            2.0 * (c * d + a * b) * yd,
            (a * a + d * d - c * c - b * b) * zd,
            h.quatern_z as f64,
        ],
    ]
}

/// Millimetres per unit of the header's spatial units (mm when undeclared).
fn unit_mm(h: &NiftiHeader) -> f64 {
    match h.xyzt_units & 7 {
        1 => 1000.0,
        3 => 1e-3,
        _ => 1.0,
    }
}

fuzz_target!(|data: &[u8]| {
    let mut bytes = data.to_vec();
    bytes.resize(348, 0);
    bytes[344..348].copy_from_slice(b"n+1\0");
    let Ok(h) = NiftiHeader::from_reader(&bytes[..]) else {
        return;
    };
    let Ok(g) = labelmaps::geometry(&h, Path::new("fuzz.nii")) else {
        return;
    };
    let a = g.affine;
    assert!(a.iter().all(|x| x.is_finite()));
    let m = a.fixed_view::<3, 3>(0, 0);
    assert!(m.determinant() != 0.0);
    let s = unit_mm(&h);
    let want: [[f64; 4]; 3] = if g.transform == "sform" {
        let r = [h.srow_x, h.srow_y, h.srow_z];
        r.map(|row| row.map(|x| x as f64))
    } else {
        // The handedness is qfac's alone.
        let q = if h.pixdim[0] < 0.0 { -1.0 } else { 1.0 };
        assert!(m.determinant() * q > 0.0, "mirrored by a voxel size: {a}");
        if h.pixdim[1..4].iter().any(|&x| x <= 0.0) {
            return;
        }
        reference(&h)
    };
    for r in 0..3 {
        for c in 0..4 {
            let w = want[r][c] * s;
            let tol = 1e-9 * (1.0 + w.abs());
            assert!(
                (a[(r, c)] - w).abs() <= tol,
                "({r}, {c}): {} vs {w}",
                a[(r, c)]
            );
        }
    }
});
