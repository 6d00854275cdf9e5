//! What the binary embeds of `base_model/`: exactly the model file and the
//! meshes it names (read back with the tool's own XML reader, independent
//! of the build script's text rule), byte for byte as on disk and tracked
//! by git; a stray file in the folder (OpenSim's `opensim.log`, an
//! editor's backup) is not in the list the build script embeds.

mod common;

#[path = "../build/model_files.rs"]
mod model_files;

use model_files::{model_files, ModelFilesError, MODEL_FILE};
use osim_spine::embedded::files::BASE_MODEL;
use osim_spine::osim::geometry::mesh_files;
use osim_spine::osim::Document;
use std::collections::BTreeSet;
use std::path::Path;

/// `base.osim` of `dir` and the meshes its XML names (the tool's reader).
fn model_and_meshes(dir: &Path) -> BTreeSet<String> {
    let doc = Document::read(dir.join(MODEL_FILE)).expect("base.osim reads");
    let mut set: BTreeSet<String> = mesh_files(doc.model_element()).into_iter().collect();
    set.insert(MODEL_FILE.to_string());
    set
}

#[test]
fn the_binary_embeds_exactly_the_model_and_its_meshes() {
    let dir = common::repo_root().join("base_model");
    let embedded: BTreeSet<String> = BASE_MODEL.iter().map(|(n, _)| n.to_string()).collect();
    assert_eq!(embedded.len(), BASE_MODEL.len(), "a file embedded twice");
    let truth = model_and_meshes(&dir);
    assert!(truth.len() > 1, "the base model names no mesh");
    assert_eq!(embedded, truth);
    // Byte for byte the files on disk.
    for (name, bytes) in BASE_MODEL {
        let disk = std::fs::read(dir.join(name)).expect("embedded file on disk");
        assert!(
            disk == *bytes,
            "embedded {name} differs from base_model/{name}"
        );
    }
    // Every embedded file is tracked (none is a local leftover).
    match common::git_tracked(&dir) {
        Some(t) => {
            let untracked: Vec<_> = embedded.difference(&t).collect();
            assert!(
                untracked.is_empty(),
                "embedded but not tracked: {untracked:?}"
            );
        }
        None => common::skip("base_model/ is not in a git checkout: tracking not checked"),
    }
}

/// A copy of `base_model/`'s model and meshes in a fresh folder.
fn copy_of_the_model() -> tempfile::TempDir {
    let src = common::repo_root().join("base_model");
    let d = tempfile::tempdir().unwrap();
    for name in model_and_meshes(&src) {
        std::fs::copy(src.join(&name), d.path().join(&name)).unwrap();
    }
    d
}

#[test]
fn stray_files_in_the_folder_are_not_embedded() {
    let d = copy_of_the_model();
    let clean = model_files(d.path()).expect("rule on the clean copy");
    // What OpenSim and editors leave behind, and another model.
    for stray in [
        "opensim.log",
        "base.osim~",
        "notes.txt",
        "other.osim",
        "unused.vtp",
    ] {
        std::fs::write(d.path().join(stray), b"stray").unwrap();
    }
    let with_strays = model_files(d.path()).expect("rule with stray files");
    assert_eq!(with_strays, clean);
    let expected: Vec<String> = model_and_meshes(d.path()).into_iter().collect();
    assert_eq!(with_strays, expected);
}

#[test]
fn a_mesh_the_model_names_but_the_folder_lacks_is_refused() {
    let d = copy_of_the_model();
    let mesh = model_and_meshes(d.path())
        .into_iter()
        .find(|n| n != MODEL_FILE)
        .expect("a mesh");
    std::fs::remove_file(d.path().join(&mesh)).unwrap();
    match model_files(d.path()) {
        Err(e @ ModelFilesError::MissingMesh { .. }) => {
            let msg = e.to_string();
            assert!(msg.contains(&mesh) && msg.contains(MODEL_FILE), "{msg}");
        }
        other => panic!("expected MissingMesh naming {mesh}, got {other:?}"),
    }
}

#[test]
fn a_folder_without_a_model_is_refused() {
    let d = tempfile::tempdir().unwrap();
    std::fs::write(d.path().join("opensim.log"), b"stray").unwrap();
    let e = model_files(d.path()).expect_err("no base.osim");
    assert!(matches!(e, ModelFilesError::Unreadable(..)), "{e:?}");
    assert!(e.to_string().contains(MODEL_FILE), "{e}");
}
