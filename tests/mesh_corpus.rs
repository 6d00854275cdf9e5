//! Malformed mesh inputs: every file in `tests/corpus/mesh/` is refused with
//! an error that names the file, and random or mutated bytes never make a
//! reader panic.

use osim_spine::mesh::{self, Format, TriMesh};
use proptest::prelude::*;
use std::path::{Path, PathBuf};

fn corpus() -> Vec<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/corpus/mesh");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| Format::from_path(p).is_ok())
        .collect();
    files.sort();
    files
}

#[test]
fn every_malformed_file_is_a_clear_error() {
    let files = corpus();
    assert!(files.len() >= 40, "corpus has only {} files", files.len());
    for f in &files {
        let name = f.file_name().unwrap().to_str().unwrap();
        match mesh::read(f) {
            Ok(m) => panic!(
                "{name}: accepted ({} vertices, {} triangles) but should be refused",
                m.vertices.len(),
                m.triangles.len()
            ),
            Err(e) => {
                let msg = e.to_string();
                assert!(
                    msg.contains(name),
                    "{name}: error does not name the file: {msg}"
                );
                // A location or a reason beyond the file name.
                assert!(
                    msg.len() > f.to_str().unwrap().len() + 10,
                    "{name}: terse error {msg}"
                );
                println!("{name}: {msg}");
            }
        }
    }
}

/// Small valid files of every format, to mutate.
fn seeds() -> Vec<(Format, Vec<u8>)> {
    let m = TriMesh::new(
        vec![
            [0.0, 0.0, 0.0].into(),
            [0.01, 0.0, 0.0].into(),
            [0.0, 0.01, 0.0].into(),
            [0.0, 0.0, 0.01].into(),
        ],
        vec![[0, 2, 1], [0, 1, 3], [1, 2, 3], [2, 0, 3]],
    )
    .unwrap();
    vec![
        (Format::Vtp, mesh::vtp::to_ascii(&m).into_bytes()),
        (Format::Vtp, mesh::vtp::to_binary(&m, false).into_bytes()),
        (Format::Vtp, mesh::vtp::to_binary(&m, true).into_bytes()),
        (Format::Stl, mesh::stl::to_ascii(&m, "s").into_bytes()),
        (Format::Stl, mesh::stl::to_binary(&m).unwrap()),
        (Format::Obj, mesh::obj::to_string(&m).into_bytes()),
        (Format::Ply, mesh::ply::to_ascii(&m).into_bytes()),
    ]
}

const FORMATS: [Format; 4] = [Format::Vtp, Format::Stl, Format::Obj, Format::Ply];

fn check(format: Format, bytes: &[u8]) {
    // Must return (Ok or Err), never panic; a returned mesh is valid.
    if let Ok(m) = mesh::read_bytes(format, bytes, Path::new("fuzz.bin")) {
        m.validate().unwrap();
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(400))]

    #[test]
    fn random_bytes_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..600)) {
        for f in FORMATS {
            check(f, &bytes);
        }
    }

    #[test]
    fn mutated_valid_files_never_panic(
        seed in 0usize..7,
        edits in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..8),
        cut in any::<prop::sample::Index>(),
        truncate in any::<bool>(),
    ) {
        let (format, mut bytes) = seeds().swap_remove(seed);
        for (i, b) in edits {
            let k = i.index(bytes.len());
            bytes[k] = b;
        }
        if truncate {
            let k = cut.index(bytes.len());
            bytes.truncate(k);
        }
        check(format, &bytes);
    }
}

#[test]
fn unmutated_seeds_read() {
    for (f, b) in seeds() {
        let m = mesh::read_bytes(f, &b, Path::new("seed")).unwrap();
        assert_eq!(m.triangles.len(), 4);
    }
}
