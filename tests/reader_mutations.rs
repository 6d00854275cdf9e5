//! A short, seeded, stable-toolchain fuzz pass over the same
//! corpora as the cargo-fuzz targets (`fuzz/`): every corpus and fixture
//! file is mutated (bit flips, byte inserts/deletes, duplicated and cut
//! chunks, hostile tokens spliced in) and fed to its reader in process.
//! Every reader must return Ok or Err, never panic. Deterministic (fixed
//! seed) and fast, so CI catches regressions without nightly.

mod common;

use osim_spine::{calibrate::experiment, landmarks::io, mesh, osim::Document, personalise::table};
use rand::{Rng, SeedableRng};
use std::path::{Path, PathBuf};

/// Mutations per seed file.
const ROUNDS: usize = 40;

const TOKENS: &[&[u8]] = &[
    b"<!DOCTYPE x [<!ENTITY a \"b\">]>",
    b"&x;",
    b"&#0;",
    b"1e308",
    b"nan",
    b"-1",
    b"\n",
    b",",
    b"\t",
    b"</",
    b"<a>",
    b"999999999999",
    b"\xff\xfe",
    b"\"",
];

/// One seeded mutation of `seed`.
fn mutate(seed: &[u8], rng: &mut rand_chacha::ChaCha8Rng) -> Vec<u8> {
    let mut b = seed.to_vec();
    for _ in 0..rng.random_range(1..4) {
        let n = b.len().max(1);
        let at = rng.random_range(0..n).min(b.len());
        match rng.random_range(0..5) {
            0 if !b.is_empty() => {
                let i = at.min(b.len() - 1);
                b[i] ^= 1 << rng.random_range(0..8);
            }
            1 => b.insert(at, rng.random()),
            2 if at < b.len() => {
                b.remove(at);
            }
            3 => {
                let end = (at + rng.random_range(1..64)).min(b.len());
                let chunk = b[at..end].to_vec();
                b.splice(at..at, chunk);
            }
            _ => {
                let t = TOKENS[rng.random_range(0..TOKENS.len())];
                b.splice(at..at, t.iter().copied());
            }
        }
    }
    b
}

/// Feed `bytes` to the reader of `ext`; a panic fails the test.
fn read(ext: &str, bytes: &[u8]) {
    let p = PathBuf::from(format!("mutant.{ext}"));
    let text = std::str::from_utf8(bytes).ok();
    match ext {
        "vtp" | "stl" | "obj" | "ply" => {
            let _ = mesh::read_bytes(mesh::Format::from_path(&p).unwrap(), bytes, &p);
        }
        "osim" => {
            if let Some(Ok(doc)) = text.map(|t| Document::parse(t, &p)) {
                let _ = doc.model();
            }
        }
        "csv" | "trc" | "json" => {
            if let Some(t) = text {
                let _ = io::parse_csv(t, &p);
                let _ = io::parse_trc(t, &p);
                let _ = io::parse_json(t, &p);
                let _ = table::parse_csv(t, &p);
            }
        }
        "toml" => {
            if let Some(t) = text {
                let _ = experiment::parse_experiment_toml(t, &p);
                let _ = experiment::parse_cases(t, &p);
                let _ = table::parse_toml(t, &p);
            }
        }
        _ => {}
    }
}

fn seeds() -> Vec<PathBuf> {
    let root = common::repo_root();
    let mut out = Vec::new();
    for dir in [
        "tests/corpus/osim",
        "tests/corpus/mesh",
        "tests/fixtures/mesh",
        "templates",
    ] {
        let Ok(rd) = std::fs::read_dir(root.join(dir)) else {
            continue;
        };
        out.extend(rd.filter_map(|e| e.ok().map(|e| e.path())));
    }
    // a few real landmark files and experiments when the shared data is there
    for rel in [
        "scoliosis-dev/D01_thoracic45/landmarks_clean.csv",
        "diagnose-dev/dev-01/experiment.toml",
    ] {
        out.extend(common::shared(rel));
    }
    out.retain(|p| small_known(p));
    out.sort();
    out
}

fn small_known(p: &Path) -> bool {
    let ext = p.extension().and_then(|e| e.to_str()).unwrap_or("");
    let known = [
        "vtp", "stl", "obj", "ply", "osim", "csv", "trc", "json", "toml",
    ];
    known.contains(&ext)
        && std::fs::metadata(p)
            .map(|m| m.len() < 200_000)
            .unwrap_or(false)
}

#[test]
fn mutated_corpora_never_panic_any_reader() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(19);
    let files = seeds();
    assert!(files.len() > 50, "corpora not found: {files:?}");
    let mut n = 0;
    for f in &files {
        let ext = f.extension().unwrap().to_str().unwrap().to_string();
        let seed = std::fs::read(f).unwrap();
        for _ in 0..ROUNDS {
            let m = mutate(&seed, &mut rng);
            let r = std::panic::catch_unwind(|| read(&ext, &m));
            assert!(
                r.is_ok(),
                "{} panicked on mutant:\n{}",
                f.display(),
                String::from_utf8_lossy(&m)
            );
            n += 1;
        }
    }
    eprintln!("{n} mutants of {} files", files.len());
}

#[test]
fn mutated_nifti_headers_never_panic_the_label_map_reader() {
    use nalgebra::Matrix4;
    use osim_spine::segmentation::{nifti, voxelise};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(19);
    // A small map, its header written as an oblique qform and as an sform.
    let turn = nalgebra::Rotation3::from_euler_angles(0.3, -0.2, 0.5).to_homogeneous();
    let map = nifti::LabelMap {
        dims: [4, 3, 2],
        labels: (0..24).map(|i| (i % 3) as u16 * 20).collect(),
        affine: turn * Matrix4::new_nonuniform_scaling(&nalgebra::Vector3::new(0.8, 0.8, 2.5)),
        transform: "sform",
        notes: Vec::new(),
    };
    let p = Path::new("mutant.nii");
    let mut n = 0;
    for how in [
        voxelise::HeaderTransform::Qform,
        voxelise::HeaderTransform::Sform,
    ] {
        let seed = voxelise::nifti_bytes(&map, how);
        assert!(nifti::parse(&seed, p).is_ok());
        for _ in 0..20 * ROUNDS {
            // Mutations of the header only (the volume stays as long).
            let mut m = mutate(&seed[..348], &mut rng);
            m.resize(348, 0);
            m.extend_from_slice(&seed[348..]);
            let r = std::panic::catch_unwind(|| nifti::parse(&m, p).map(|l| l.affine));
            assert!(r.is_ok(), "panicked on header {m:?}");
            n += 1;
        }
    }
    eprintln!("{n} mutated NIfTI headers");
}
