//! NIfTI-1 voxel-to-world geometry (`segmentation::nifti::geometry`) on a
//! set of headers: against nibabel where nibabel reads the header (sform,
//! qform with rotations, qfac, zero and negative voxel sizes, a quaternion
//! on the unit sphere, units, both transforms, big-endian), and against an
//! independent transcription of `nifti_quatern_to_mat44` (nifti1_io.c)
//! where nibabel refuses it (a quaternion of norm above 1, which the
//! reference normalises). Headers the two readers would read differently
//! (a fractional qfac, a negative transform code) are refused.

mod common;

use nalgebra::{Matrix4, Vector3};
use osim_spine::segmentation::nifti;
use std::path::{Path, PathBuf};

/// The fields of a header the geometry depends on.
#[derive(Clone)]
struct Hdr {
    qform_code: i16,
    sform_code: i16,
    pixdim: [f32; 4],
    quatern: [f32; 3],
    qoffset: [f32; 3],
    srow: [[f32; 4]; 3],
    /// xyzt_units: 1 m, 2 mm, 3 um.
    units: u8,
    big_endian: bool,
}

impl Default for Hdr {
    fn default() -> Self {
        Hdr {
            qform_code: 0,
            sform_code: 0,
            pixdim: [1.0, 1.0, 1.0, 1.0],
            quatern: [0.0; 3],
            qoffset: [0.0; 3],
            srow: [
                [1.0, 0.0, 0.0, 0.0],
                [0.0, 1.0, 0.0, 0.0],
                [0.0, 0.0, 1.0, 0.0],
            ],
            units: 2,
            big_endian: false,
        }
    }
}

/// A single-file NIfTI-1 of 3 x 4 x 5 uint8 voxels (two corners labelled) with
/// the header `h`.
fn file_bytes(h: &Hdr) -> Vec<u8> {
    let mut b = vec![0u8; 352];
    let be = h.big_endian;
    let i32b = |v: i32| if be { v.to_be_bytes() } else { v.to_le_bytes() };
    let i16b = |v: i16| if be { v.to_be_bytes() } else { v.to_le_bytes() };
    let f32b = |v: f32| if be { v.to_be_bytes() } else { v.to_le_bytes() };
    b[0..4].copy_from_slice(&i32b(348));
    for (k, d) in [3i16, 3, 4, 5, 1, 1, 1, 1].iter().enumerate() {
        b[40 + 2 * k..42 + 2 * k].copy_from_slice(&i16b(*d));
    }
    b[70..72].copy_from_slice(&i16b(2)); // uint8
    b[72..74].copy_from_slice(&i16b(8));
    for (k, p) in h.pixdim.iter().enumerate() {
        b[76 + 4 * k..80 + 4 * k].copy_from_slice(&f32b(*p));
    }
    b[108..112].copy_from_slice(&f32b(352.0));
    b[123] = h.units;
    b[252..254].copy_from_slice(&i16b(h.qform_code));
    b[254..256].copy_from_slice(&i16b(h.sform_code));
    for (k, v) in h.quatern.iter().chain(&h.qoffset).enumerate() {
        b[256 + 4 * k..260 + 4 * k].copy_from_slice(&f32b(*v));
    }
    for r in 0..3 {
        for c in 0..4 {
            let at = 280 + 16 * r + 4 * c;
            b[at..at + 4].copy_from_slice(&f32b(h.srow[r][c]));
        }
    }
    b[344..348].copy_from_slice(b"n+1\0");
    // Labels in the first and last voxels: the map is kept whole (a
    // reader keeps only the box of labelled voxels).
    let mut vol = vec![0u8; 60];
    vol[0] = 5;
    vol[59] = 5;
    b.extend(vol);
    b
}

/// `nifti_quatern_to_mat44` of nifti1_io.c, transcribed (doubles, as the
/// C code computes before storing floats).
fn reference_qform(h: &Hdr) -> Matrix4<f64> {
    let (mut b, mut c, mut d) = (
        h.quatern[0] as f64,
        h.quatern[1] as f64,
        h.quatern[2] as f64,
    );
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
    let mut zd = pos(h.pixdim[3]);
    if h.pixdim[0] < 0.0 {
        zd = -zd;
    }
    #[rustfmt::skip]
    let m = Matrix4::new(
        (a * a + b * b - c * c - d * d) * xd, 2.0 * (b * c - a * d) * yd, 2.0 * (b * d + a * c) * zd, h.qoffset[0] as f64,
        2.0 * (b * c + a * d) * xd, (a * a + c * c - b * b - d * d) * yd, 2.0 * (c * d - a * b) * zd, h.qoffset[1] as f64,
        2.0 * (b * d - a * c) * xd, 2.0 * (c * d + a * b) * yd, (a * a + d * d - c * c - b * b) * zd, h.qoffset[2] as f64,
        0.0, 0.0, 0.0, 1.0,
    );
    m
}

/// A unit quaternion's (b, c, d) for a rotation of `deg` about `axis`
/// (a >= 0).
fn quat(axis: [f64; 3], deg: f64) -> [f32; 3] {
    let ax = Vector3::from(axis).normalize();
    let h = deg.to_radians() / 2.0;
    let v = ax * h.sin();
    [v.x as f32, v.y as f32, v.z as f32]
}

/// The cases nibabel reads, by name.
fn nibabel_cases() -> Vec<(&'static str, Hdr)> {
    let q = |pixdim: [f32; 4], quatern: [f32; 3]| Hdr {
        qform_code: 1,
        pixdim,
        quatern,
        qoffset: [-47.1, -569.1, 904.3],
        ..Hdr::default()
    };
    let oblique = quat([0.3, -0.5, 0.8], 23.0);
    vec![
        (
            "sform_oblique",
            Hdr {
                sform_code: 1,
                srow: [
                    [0.78, 0.1, -0.05, 120.5],
                    [-0.12, 0.77, 0.2, -80.25],
                    [0.03, -0.18, 1.48, 950.0],
                ],
                ..Hdr::default()
            },
        ),
        ("qform_identity", q([1.0, 0.8, 0.8, 1.5], [0.0; 3])),
        ("qform_oblique", q([1.0, 0.8, 0.8, 1.5], oblique)),
        ("qform_qfac_minus", q([-1.0, 0.8, 0.9, 2.5], oblique)),
        ("qform_qfac_zero", q([0.0, 0.8, 0.9, 2.5], oblique)),
        (
            "qform_lps_half_turn",
            q([1.0, 0.7, 0.7, 1.0], [0.0, 0.0, 1.0]),
        ),
        // Half turns about oblique axes: (b, c, d) of norm 1 but for float
        // rounding (1 - |(b, c, d)|^2 = 3.4e-8, 3.6e-8), so a = 0 exactly,
        // as nifti1_io decides below 1e-7 and nibabel below its threshold.
        (
            "qform_half_turn_diagonal",
            q([1.0, 0.7, 0.7, 1.0], [0.707_106_77, 0.707_106_77, 0.0]),
        ),
        (
            "qform_half_turn_oblique",
            q([-1.0, 0.7, 0.9, 2.0], [0.577_350_26; 3]),
        ),
        (
            "qform_norm_at_one",
            q([1.0, 0.7, 0.7, 1.0], [0.6, 0.8, 0.0]),
        ),
        ("qform_negative_pixdim", q([1.0, -0.8, 0.8, 1.5], oblique)),
        (
            "qform_negative_pixdims",
            q([-1.0, -2.0, 0.5, -3.0], oblique),
        ),
        ("qform_zero_pixdim", q([1.0, 0.8, 0.0, 1.5], oblique)),
        (
            "qform_metres",
            Hdr {
                units: 1,
                ..q([1.0, 0.0008, 0.0008, 0.0015], oblique)
            },
        ),
        (
            "both_sform_used",
            Hdr {
                sform_code: 2,
                srow: [
                    [-0.8, 0.0, 0.0, 10.0],
                    [0.0, -0.8, 0.0, 20.0],
                    [0.0, 0.0, 1.5, 30.0],
                ],
                ..q([1.0, 0.8, 0.8, 1.5], oblique)
            },
        ),
        (
            "qform_big_endian",
            Hdr {
                big_endian: true,
                ..q([-1.0, 0.8, 0.9, 2.5], oblique)
            },
        ),
    ]
}

fn write(dir: &Path, name: &str, h: &Hdr) -> PathBuf {
    let p = dir.join(format!("{name}.nii"));
    std::fs::write(&p, file_bytes(h)).unwrap();
    p
}

/// Largest difference between two affines.
fn gap(a: &Matrix4<f64>, b: &Matrix4<f64>) -> f64 {
    (a - b).abs().max()
}

#[test]
fn affines_agree_with_nibabel() {
    let Some(py) = common::nibabel_python() else {
        return;
    };
    let d = tempfile::tempdir().unwrap();
    let cases = nibabel_cases();
    let paths: Vec<PathBuf> = cases.iter().map(|(n, h)| write(d.path(), n, h)).collect();
    let mut args = vec![common::repo_root()
        .join("tests/py/nifti_affines.py")
        .display()
        .to_string()];
    args.extend(paths.iter().map(|p| p.display().to_string()));
    let out = std::process::Command::new(&py)
        .args(&args)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let nib: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    for ((name, h), p) in cases.iter().zip(&paths) {
        let want = &nib[p.display().to_string()];
        let rows = want["affine"]
            .as_array()
            .unwrap_or_else(|| panic!("{name}: nibabel refused it: {want}"));
        let mut w = Matrix4::zeros();
        for (r, row) in rows.iter().enumerate() {
            for (c, x) in row.as_array().unwrap().iter().enumerate() {
                w[(r, c)] = x.as_f64().unwrap();
            }
        }
        // nibabel's affine is in the file's units; ours in millimetres.
        let mm = match h.units {
            1 => 1000.0,
            3 => 1e-3,
            _ => 1.0,
        };
        w.fixed_view_mut::<3, 4>(0, 0).scale_mut(mm);
        let got = nifti::read(p).unwrap_or_else(|e| panic!("{name}: {e}"));
        let g = gap(&got.affine, &w);
        println!(
            "{name}: {} largest difference from nibabel {g:.2e} mm",
            got.transform
        );
        // Rounding only (a half turn's a = 0 exactly in both readers).
        assert!(
            g <= 1e-9 * (1.0 + w.abs().max()),
            "{name}: ours {}\nnibabel {}",
            got.affine,
            w
        );
    }
}

#[test]
fn qform_is_the_reference_transcription() {
    // Every qform case nibabel reads with positive voxel sizes, plus a
    // quaternion of norm above 1 (nibabel refuses it; nifti1_io normalises
    // it to a half turn). Negative and zero voxel sizes differ by design
    // (the magnitude, as nibabel; the reference takes 1) and are left out.
    let d = tempfile::tempdir().unwrap();
    let mut cases: Vec<(&str, Hdr)> = nibabel_cases()
        .into_iter()
        .filter(|(_, h)| h.sform_code == 0 && h.pixdim[1..].iter().all(|&x| x > 0.0))
        .collect();
    cases.push((
        "qform_norm_above_one",
        Hdr {
            qform_code: 1,
            pixdim: [1.0, 0.8, 0.8, 1.5],
            quatern: [1.2, 0.9, 0.3],
            qoffset: [10.0, -20.0, 30.0],
            ..Hdr::default()
        },
    ));
    for (name, h) in &cases {
        let got = nifti::read(&write(d.path(), name, h)).unwrap();
        let mut want = reference_qform(h);
        if h.units == 1 {
            want.fixed_view_mut::<3, 4>(0, 0).scale_mut(1000.0);
        }
        // The same arithmetic in doubles: equal to rounding (a half turn's
        // a is 0 exactly, not the 1.5e-8 a renormalised norm leaves).
        let tol = 1e-12 * (1.0 + want.abs().max());
        assert!(
            gap(&got.affine, &want) <= tol,
            "{name}: {} vs {want} (largest difference {:.2e})",
            got.affine,
            gap(&got.affine, &want)
        );
        // A rotation times voxel sizes: the scale is never the quaternion's.
        let sp = got.spacing();
        assert!((sp.x - h.pixdim[1] as f64 * if h.units == 1 { 1000.0 } else { 1.0 }).abs() < 1e-4);
    }
    // The norm-above-one header is read and its repair named.
    let got = nifti::read(&d.path().join("qform_norm_above_one.nii")).unwrap();
    assert!(
        got.notes.iter().any(|w| w.contains("normalised")),
        "{:?}",
        got.notes
    );
}

#[test]
fn a_negative_voxel_size_never_mirrors() {
    let d = tempfile::tempdir().unwrap();
    let base = Hdr {
        qform_code: 1,
        pixdim: [1.0, 0.8, 0.8, 1.5],
        quatern: quat([0.2, 1.0, 0.1], 40.0),
        qoffset: [5.0, 6.0, 7.0],
        ..Hdr::default()
    };
    let mut neg = base.clone();
    neg.pixdim[1] = -0.8;
    let a = nifti::read(&write(d.path(), "pos", &base)).unwrap();
    let b = nifti::read(&write(d.path(), "neg", &neg)).unwrap();
    assert!(
        gap(&a.affine, &b.affine) < 1e-9,
        "{} vs {}",
        a.affine,
        b.affine
    );
    let det = a.affine.fixed_view::<3, 3>(0, 0).determinant();
    assert!(det > 0.0, "right-handed voxel axes mirrored: {det}");
    assert!(
        b.notes.iter().any(|w| w.contains("pixdim[1]")),
        "{:?}",
        b.notes
    );
}

#[test]
fn headers_the_readers_disagree_on_are_refused() {
    let d = tempfile::tempdir().unwrap();
    let q = Hdr {
        qform_code: 1,
        pixdim: [-0.5, 1.0, 1.0, 1.0],
        ..Hdr::default()
    };
    let e = nifti::read(&write(d.path(), "qfac", &q))
        .unwrap_err()
        .to_string();
    assert!(e.contains("pixdim[0]") && e.contains("mirrored"), "{e}");
    let s = Hdr {
        sform_code: -1,
        qform_code: 1,
        ..Hdr::default()
    };
    let e = nifti::read(&write(d.path(), "code", &s))
        .unwrap_err()
        .to_string();
    assert!(e.contains("sform_code") && e.contains("-1"), "{e}");
}
