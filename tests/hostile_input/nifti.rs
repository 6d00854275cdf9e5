//! Label maps: budgets checked before anything is decompressed or
//! allocated, gzip streams bounded by the header, and landmarks that do not
//! depend on where the scanner put its origin.

use super::*;
use nalgebra::{Matrix4, Vector3};
use osim_spine::base::kin::Kinematics;
use osim_spine::landmarks::Level;
use osim_spine::mesh::{self, TriMesh};
use osim_spine::osim::Document;
use osim_spine::segmentation::{self, nifti, voxelise, Options};
use std::io::Write;

/// A gzip-compressed NIfTI-1 of `n`^3 uint8 zeros (a 500 KB file for
/// n = 800: 512 MB of voxels).
fn zero_bomb(path: &Path, n: usize) {
    let mut h = vec![0u8; 352];
    h[0..4].copy_from_slice(&348i32.to_le_bytes());
    for (k, d) in [3i16, n as i16, n as i16, n as i16, 1, 1, 1, 1]
        .iter()
        .enumerate()
    {
        h[40 + 2 * k..42 + 2 * k].copy_from_slice(&d.to_le_bytes());
    }
    h[70..72].copy_from_slice(&2i16.to_le_bytes());
    h[72..74].copy_from_slice(&8i16.to_le_bytes());
    for k in 0..4 {
        h[76 + 4 * k..80 + 4 * k].copy_from_slice(&1f32.to_le_bytes());
    }
    h[108..112].copy_from_slice(&352f32.to_le_bytes());
    h[123] = 2;
    h[254..256].copy_from_slice(&1i16.to_le_bytes());
    for (r, row) in [[1f32, 0., 0., 0.], [0., 1., 0., 0.], [0., 0., 1., 0.]]
        .iter()
        .enumerate()
    {
        for (c, x) in row.iter().enumerate() {
            let at = 280 + 16 * r + 4 * c;
            h[at..at + 4].copy_from_slice(&x.to_le_bytes());
        }
    }
    h[344..348].copy_from_slice(b"n+1\0");
    let f = std::fs::File::create(path).unwrap();
    let mut e = flate2::write::GzEncoder::new(f, flate2::Compression::best());
    e.write_all(&h).unwrap();
    let slab = vec![0u8; n * n];
    for _ in 0..n {
        e.write_all(&slab).unwrap();
    }
    e.finish().unwrap();
}

/// Run `osim-spine args` with its address space limited to `mb` MB.
pub fn run_within(mb: u64, args: &[&str]) -> Output {
    Command::new("sh")
        .arg("-c")
        .arg("ulimit -v \"$1\"; shift; exec \"$@\"")
        .arg("sh")
        .arg((mb * 1024).to_string())
        .arg(common::bin())
        .args(args)
        .output()
        .unwrap()
}

#[test]
fn a_gzip_bomb_is_read_within_a_small_memory() {
    let d = tempfile::tempdir().unwrap();
    let bomb = d.path().join("bomb.nii.gz");
    zero_bomb(&bomb, 800);
    assert!(std::fs::metadata(&bomb).unwrap().len() < 1 << 20);
    // 512 MB of voxels (and a 1 GB 16-bit copy before): none of it is
    // held, so the empty map is named within 200 MB of address space.
    let out = d.path().join("lm.csv");
    let o = run_within(200, &["palpate", s(&bomb), "--out", s(&out)]);
    assert_refused(&o, "bomb.nii.gz", "the map is empty");
    assert!(!text(&o).contains("memory"), "{}", text(&o));
    assert!(!out.exists());
}

#[test]
fn declared_sizes_are_checked_before_decompressing() {
    let d = tempfile::tempdir().unwrap();
    // 800^3 declared uint8 in a few bytes: the stream ends early
    // (truncated), found by streaming, nothing allocated.
    let p = d.path().join("short.nii.gz");
    let mut h = Vec::new();
    zero_bomb(&p, 4);
    let mut raw = Vec::new();
    std::io::Read::read_to_end(
        &mut flate2::read::GzDecoder::new(std::fs::File::open(&p).unwrap()),
        &mut raw,
    )
    .unwrap();
    h.extend_from_slice(&raw[..352]);
    for k in 1..4 {
        h[40 + 2 * k..42 + 2 * k].copy_from_slice(&800i16.to_le_bytes());
    }
    let gz = |b: &[u8], name: &str| {
        let p = d.path().join(name);
        let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        e.write_all(b).unwrap();
        std::fs::write(&p, e.finish().unwrap()).unwrap();
        p
    };
    let out = d.path().join("lm.csv");
    let o = run_within(
        200,
        &["palpate", s(&gz(&h, "big.nii.gz")), "--out", s(&out)],
    );
    assert_refused(&o, "big.nii.gz", "truncated");
    // Over the grid cap: refused from the header alone.
    let mut huge = h.clone();
    for k in 1..4 {
        huge[40 + 2 * k..42 + 2 * k].copy_from_slice(&30000i16.to_le_bytes());
    }
    let o = run(&["palpate", s(&gz(&huge, "huge.nii.gz")), "--out", s(&out)]);
    assert_refused(&o, "huge.nii.gz", "label maps are limited");
    // A stream that outgrows its header: refused, not expanded.
    let mut long = raw.clone();
    long.extend(std::iter::repeat_n(0u8, 1 << 20));
    let o = run(&["palpate", s(&gz(&long, "long.nii.gz")), "--out", s(&out)]);
    assert_refused(&o, "long.nii.gz", "more than the");
    assert!(!out.exists());
}

/// L4, L5 and the sacrum of the default base at its default pose, in
/// millimetres (ground axes).
pub fn lumbosacral() -> Vec<(Level, TriMesh)> {
    let root = common::repo_root().join("base_model");
    let doc = Document::read(root.join("base.osim")).unwrap();
    let model = doc.model().unwrap();
    let kin = Kinematics::new(&model).unwrap();
    let poses = kin.body_poses(&kin.default_values()).unwrap();
    model
        .mesh_files()
        .into_iter()
        .filter_map(|(body, file)| {
            let level = Level::from_body_name(&body)?;
            if !matches!(level, Level::L4 | Level::L5 | Level::S1) {
                return None;
            }
            let m = mesh::read(&root.join(file)).unwrap();
            Some((
                level,
                m.transformed(&poses[&body]).scaled(&Vector3::repeat(1e3)),
            ))
        })
        .collect()
}

/// Palpated landmarks by name (mm, the output frame).
fn landmarks(p: &segmentation::Palpated) -> Vec<(String, Vector3<f64>)> {
    p.set
        .points
        .iter()
        .map(|(id, q)| (id.to_string(), q.coords * 1e3))
        .collect()
}

/// Largest distance between two sets' landmarks after moving `b` back by
/// `shift` (OpenSim frame, mm); both must hold the same landmarks.
fn worst_after(
    a: &[(String, Vector3<f64>)],
    b: &[(String, Vector3<f64>)],
    shift: Vector3<f64>,
) -> f64 {
    assert_eq!(
        a.iter().map(|x| &x.0).collect::<Vec<_>>(),
        b.iter().map(|x| &x.0).collect::<Vec<_>>()
    );
    a.iter()
        .zip(b)
        .map(|((_, p), (_, q))| (q - shift - p).norm())
        .fold(0.0, f64::max)
}

#[test]
fn an_origin_far_away_changes_no_landmark() {
    // The same label map (1 mm voxels, LPS grid, TotalSegmentator labels)
    // with its world shifted by 2 m, 100 m and 1 km.
    let levels = lumbosacral();
    // ground (X anterior, Y up, Z right) -> RAS
    let to_ras = |v: &Vector3<f64>| Vector3::new(v.z, v.x, v.y);
    let meshes: Vec<(u16, TriMesh)> = levels
        .iter()
        .map(|(l, m)| {
            let mut m = m.clone();
            for v in m.vertices.iter_mut() {
                v.coords = to_ras(&v.coords);
            }
            (
                if l.is_sacrum() {
                    25
                } else {
                    43 - l.index() as u16
                },
                m,
            )
        })
        .collect();
    let refs: Vec<(u16, &TriMesh)> = meshes.iter().map(|(l, m)| (*l, m)).collect();
    let (lo, hi) = meshes.iter().flat_map(|(_, m)| &m.vertices).fold(
        (Vector3::repeat(f64::MAX), Vector3::repeat(f64::MIN)),
        |(a, b), v| (a.inf(&v.coords), b.sup(&v.coords)),
    );
    // -x, -y voxel axes (an LPS grid); integer offsets (exact in the header's floats).
    let lps = Matrix4::from_diagonal(&nalgebra::Vector4::new(-1.0, -1.0, 1.0, 1.0));
    let corner = Vector3::new(hi.x + 5.0, hi.y + 5.0, lo.z - 5.0).map(f64::round);
    let dims = [0, 1, 2].map(|k| (hi[k] - lo[k]).ceil() as usize + 11);
    let d = tempfile::tempdir().unwrap();
    let mut sets = Vec::new();
    for (name, shift_mm) in [
        ("at_0", 0.0),
        ("at_2m", 2e3),
        ("at_100m", 1e5),
        ("at_1km", 1e6),
    ] {
        let shift = Vector3::new(shift_mm, -shift_mm, shift_mm);
        let mut a = lps;
        a.fixed_view_mut::<3, 1>(0, 3).copy_from(&corner);
        let mut map = voxelise::voxelise(&refs, dims, a);
        let world = corner + shift;
        map.affine.fixed_view_mut::<3, 1>(0, 3).copy_from(&world);
        let p = d.path().join(format!("{name}.nii"));
        let bytes = voxelise::nifti_bytes(&map, voxelise::HeaderTransform::Sform);
        std::fs::write(&p, &bytes).unwrap();
        let header = nifti::NiftiHeader::from_reader(&bytes[..]).unwrap();
        let back = nifti::geometry(&header, &p).unwrap();
        assert_eq!(
            back.affine.fixed_view::<3, 1>(0, 3).into_owned(),
            world,
            "{name}: the header holds the shift exactly"
        );
        let got = segmentation::palpate(&p, &Options::default()).unwrap();
        assert_eq!(got.levels.len(), 3, "{name}: {:?}", got.findings);
        // RAS shift -> OpenSim frame (X = anterior = +y, Y = up = +z, Z = right = +x).
        let os = Vector3::new(shift.y, shift.z, shift.x);
        sets.push((name, os, landmarks(&got)));
    }
    // The levels are palpated about a whole-metre local origin: no
    // landmark moves.
    let (_, _, at0) = &sets[0];
    for (name, os, set) in &sets[1..] {
        let w = worst_after(at0, set, *os);
        println!("{name}: largest landmark change {w:.2e} mm");
        assert!(w < 0.01, "{name}: a landmark moved {w} mm");
    }
}

#[test]
fn a_mesh_folder_far_away_gives_the_same_landmarks() {
    let d = tempfile::tempdir().unwrap();
    let mut sets = Vec::new();
    // Turned a little and roughened by 0.05 mm, as a CT would give them
    // (the procedural meshes are exactly symmetric: ties that rounding
    // breaks one way or the other).
    let turn = nalgebra::Rotation3::from_axis_angle(
        &nalgebra::Unit::new_normalize(Vector3::new(0.3, -0.5, 0.8)),
        7f64.to_radians(),
    );
    for (name, shift_mm) in [
        ("at_0", 0.0),
        ("at_2m", 2e3),
        ("at_100m", 1e5),
        ("at_1km", 1e6),
    ] {
        let dir = d.path().join(name);
        std::fs::create_dir(&dir).unwrap();
        let shift = Vector3::new(shift_mm, shift_mm, -shift_mm);
        for (l, m) in lumbosacral() {
            let mut m = m;
            for (i, v) in m.vertices.iter_mut().enumerate() {
                let t = i as f64;
                let jitter =
                    Vector3::new((t * 12.9898).sin(), (t * 78.233).sin(), (t * 37.719).sin());
                v.coords = turn * (v.coords + 0.05 * jitter) + shift;
            }
            mesh::write(&dir.join(format!("{l}.obj")), &m).unwrap();
        }
        let opts = Options {
            frame: Some(osim_spine::landmarks::Frame::OpenSim),
            ..Options::default()
        };
        let got = segmentation::palpate(&dir, &opts).unwrap();
        assert_eq!(got.levels.len(), 3, "{name}: {:?}", got.findings);
        sets.push((shift, landmarks(&got)));
    }
    for (shift, set) in &sets[1..] {
        let w = worst_after(&sets[0].1, set, *shift);
        println!("mesh folder shifted by {shift:?} mm: largest landmark change {w:.2e} mm");
        assert!(w < 0.01, "shifted by {shift:?} mm: a landmark moved {w} mm");
    }
}

#[test]
fn a_surface_beyond_the_sample_cap_is_refused_naming_the_cap() {
    use osim_spine::palpation::{palpate_vertebra, FrameHint};
    let (_, l4) = lumbosacral()
        .into_iter()
        .find(|(l, _)| *l == Level::L4)
        .unwrap();
    // Back to metres: a real L4 palpates; the same shape 30 times larger
    // (900 times the area) is over the cap of 1 mm^2 samples.
    let real = l4.scaled(&Vector3::repeat(1e-3));
    let area = real.area();
    assert!(area < 0.05, "L4 surface {area} m^2");
    palpate_vertebra(&real, Level::L4, &FrameHint::body_frame()).unwrap();
    let huge = real.scaled(&Vector3::repeat(30.0));
    assert!(huge.area() * 1e6 > 4e6, "{} m^2", huge.area());
    let t = std::time::Instant::now();
    let e = palpate_vertebra(&huge, Level::L4, &FrameHint::body_frame())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("4 million surface samples") && e.contains("L4"),
        "{e}"
    );
    assert!(t.elapsed().as_secs_f64() < 2.0, "{:?}", t.elapsed());
}

/// The lumbosacral meshes voxelised on a RAS grid of `voxel` mm edges
/// (TotalSegmentator labels), as a NIfTI file in `dir`.
fn thick_map(dir: &Path, name: &str, voxel: [f64; 3]) -> std::path::PathBuf {
    let to_ras = |v: &Vector3<f64>| Vector3::new(v.z, v.x, v.y);
    let meshes: Vec<(u16, TriMesh)> = lumbosacral()
        .into_iter()
        .map(|(l, mut m)| {
            for v in m.vertices.iter_mut() {
                v.coords = to_ras(&v.coords);
            }
            let label = if l.is_sacrum() {
                25
            } else {
                43 - l.index() as u16
            };
            (label, m)
        })
        .collect();
    let refs: Vec<(u16, &TriMesh)> = meshes.iter().map(|(l, m)| (*l, m)).collect();
    let (lo, hi) = meshes.iter().flat_map(|(_, m)| &m.vertices).fold(
        (Vector3::repeat(f64::MAX), Vector3::repeat(f64::MIN)),
        |(a, b), v| (a.inf(&v.coords), b.sup(&v.coords)),
    );
    let mut a = Matrix4::from_diagonal(&nalgebra::Vector4::new(voxel[0], voxel[1], voxel[2], 1.0));
    let corner = lo - Vector3::from(voxel) * 2.0;
    a.fixed_view_mut::<3, 1>(0, 3).copy_from(&corner);
    let dims = [0, 1, 2].map(|k| ((hi[k] - lo[k]) / voxel[k]).ceil() as usize + 5);
    let map = voxelise::voxelise(&refs, dims, a);
    let p = dir.join(format!("{name}.nii"));
    std::fs::write(
        &p,
        voxelise::nifti_bytes(&map, voxelise::HeaderTransform::Sform),
    )
    .unwrap();
    p
}

#[test]
fn thick_slices_are_named_and_widen_every_landmark() {
    let d = tempfile::tempdir().unwrap();
    for (name, voxel, axis, direction) in [
        ("fine", [1.0, 1.0, 1.0], None, ""),
        ("thick_k", [0.5, 0.5, 6.0], Some("k"), "superior-inferior"),
        ("thick_i", [6.0, 0.5, 0.5], Some("i"), "left-right"),
    ] {
        let p = thick_map(d.path(), name, voxel);
        let largest = voxel.iter().copied().fold(0.0, f64::max);
        let got = match segmentation::palpate(&p, &Options::default()) {
            Ok(got) => got,
            Err(e) => panic!("{name}: {e}"),
        };
        let coarse: Vec<&str> = got
            .findings
            .iter()
            .map(|f| f.message.as_str())
            .filter(|m| m.contains("too coarse for the protocol"))
            .collect();
        match axis {
            None => assert!(coarse.is_empty(), "{name}: {coarse:?}"),
            Some(a) => {
                assert_eq!(coarse.len(), 1, "{name}: {coarse:?}");
                let m = coarse[0];
                assert!(
                    m.contains(&format!("along {a}"))
                        && m.contains("6.00 mm")
                        && m.contains(direction),
                    "{name}: {m}"
                );
            }
        }
        let report = segmentation::report::report(&got);
        let cap = (3.0 / largest).min(1.0);
        let entries: Vec<_> = report.levels.iter().flat_map(|l| &l.landmarks).collect();
        assert!(!entries.is_empty(), "{name}: no landmark");
        for e in entries {
            // Output in mm: half the largest voxel edge and the landmark's
            // region spread, in quadrature (each rounded to 1e-4 mm).
            let u = e
                .uncertainty
                .unwrap_or_else(|| panic!("{name} {}: no uncertainty", e.name));
            assert!(
                u >= 0.5 * largest - 1e-4
                    && (u - (0.5 * largest).hypot(e.region_spread)).abs() < 2e-4,
                "{name} {}: uncertainty {u}, spread {}",
                e.name,
                e.region_spread
            );
            assert!(
                e.confidence <= cap + 1e-9,
                "{name} {}: confidence {}",
                e.name,
                e.confidence
            );
        }
    }
}
