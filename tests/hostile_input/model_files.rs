//! Files a model references resolve inside its folder tree (or a
//! `--geometry` folder named): a symbolic link leading out is refused by
//! name and never copied into an output.

use super::*;

/// A model folder holding the corpus model with L5 showing
/// `Geometry/lumbar5.vtp`, and a file outside it with `secret` content.
fn model_with_mesh(d: &Path) -> (PathBuf, PathBuf) {
    let dir = d.join("model");
    std::fs::create_dir_all(dir.join("Geometry")).unwrap();
    let model = corpus_model().replacen(
        "<Body name=\"L5\">",
        "<Body name=\"L5\"><attached_geometry><Mesh name=\"L5_geom\"><mesh_file>lumbar5.vtp</mesh_file></Mesh></attached_geometry>",
        1,
    );
    assert!(model.contains("lumbar5.vtp"));
    let m = dir.join("m.osim");
    std::fs::write(&m, model).unwrap();
    let outside = d.join("elsewhere");
    std::fs::create_dir(&outside).unwrap();
    let secret = outside.join("secret.vtp");
    std::fs::write(&secret, vtp("0 0 0 1 0 0 0 1 0", "")).unwrap();
    (m, secret)
}

/// No file under `dir` holds `needle`.
fn nothing_holds(dir: &Path, needle: &[u8]) {
    if !dir.exists() {
        return;
    }
    for e in std::fs::read_dir(dir).unwrap().flatten() {
        let p = e.path();
        if p.is_dir() {
            nothing_holds(&p, needle);
        } else {
            let b = std::fs::read(&p).unwrap();
            assert!(
                !b.windows(needle.len()).any(|w| w == needle),
                "{p:?} copied"
            );
        }
    }
}

#[test]
fn convert_refuses_a_mesh_linked_from_outside_the_model() {
    let d = tempfile::tempdir().unwrap();
    let (m, secret) = model_with_mesh(d.path());
    let geo = m.parent().unwrap().join("Geometry");
    symlink(s(&secret), &geo.join("lumbar5.vtp"));
    let out = d.path().join("out");
    let o = run(&["convert", s(&m), s(&out.join("c.osim"))]);
    assert_refused(&o, "lumbar5.vtp", "symbolic link");
    assert!(!out.exists(), "convert wrote {out:?}");
    // A system file, as the round found it.
    std::fs::remove_file(geo.join("lumbar5.vtp")).unwrap();
    symlink("/etc/passwd", &geo.join("lumbar5.vtp"));
    let o = run(&["convert", s(&m), s(&out.join("c.osim"))]);
    assert_refused(&o, "lumbar5.vtp", "outside the model's folder");
    assert!(!out.exists());
    // `info` refuses it too.
    assert_refused(&run(&["info", s(&m)]), "lumbar5.vtp", "symbolic link");
}

#[test]
fn convert_refuses_a_linked_geometry_folder_and_dotdot() {
    let d = tempfile::tempdir().unwrap();
    let (m, secret) = model_with_mesh(d.path());
    let dir = m.parent().unwrap();
    // Geometry/ itself a link to the folder outside.
    std::fs::remove_dir(dir.join("Geometry")).unwrap();
    std::fs::rename(&secret, secret.with_file_name("lumbar5.vtp")).unwrap();
    symlink(s(secret.parent().unwrap()), &dir.join("Geometry"));
    let out = d.path().join("out");
    let o = run(&["convert", s(&m), s(&out.join("c.osim"))]);
    assert_refused(&o, "lumbar5.vtp", "linked folder");
    assert!(!out.exists());
    // `..` in the name.
    let text = std::fs::read_to_string(&m)
        .unwrap()
        .replace("lumbar5.vtp", "../elsewhere/lumbar5.vtp");
    std::fs::write(&m, text).unwrap();
    let o = run(&["convert", s(&m), s(&out.join("c.osim"))]);
    assert_refused(&o, "../elsewhere/lumbar5.vtp", "'..'");
    assert!(!out.exists());
}

#[test]
fn links_inside_the_model_folder_and_named_geometry_folders_are_followed() {
    let d = tempfile::tempdir().unwrap();
    let (m, secret) = model_with_mesh(d.path());
    let dir = m.parent().unwrap();
    // A link inside the tree (Geometry/lumbar5.vtp -> ../shared.vtp) is fine.
    std::fs::copy(&secret, dir.join("shared.vtp")).unwrap();
    symlink("../shared.vtp", &dir.join("Geometry/lumbar5.vtp"));
    let out = d.path().join("out");
    let o = run(&["convert", s(&m), s(&out.join("c.osim"))]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(out.join("Geometry/lumbar5.vtp").is_file());
    // The outside folder, named with --geometry, is the user's choice.
    std::fs::remove_file(dir.join("Geometry/lumbar5.vtp")).unwrap();
    std::fs::rename(&secret, secret.with_file_name("lumbar5.vtp")).unwrap();
    let out2 = d.path().join("out2");
    let o = run(&[
        "convert",
        s(&m),
        s(&out2.join("c.osim")),
        "--geometry",
        s(secret.parent().unwrap()),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(out2.join("Geometry/lumbar5.vtp").is_file());
}

#[test]
fn generate_never_copies_a_file_from_outside_the_base() {
    let d = tempfile::tempdir().unwrap();
    // A base model folder whose L5 mesh is a link to a file elsewhere.
    let base = d.path().join("base");
    std::fs::create_dir(&base).unwrap();
    let root = common::repo_root().join("base_model");
    for e in std::fs::read_dir(&root).unwrap().flatten() {
        std::fs::copy(e.path(), base.join(e.file_name())).unwrap();
    }
    let outside = d.path().join("elsewhere.vtp");
    let marker = b"<!-- not a mesh of the model -->";
    let mut bytes = std::fs::read(root.join("proc_L5.vtp")).unwrap();
    bytes.extend_from_slice(marker);
    std::fs::write(&outside, &bytes).unwrap();
    std::fs::remove_file(base.join("proc_L5.vtp")).unwrap();
    symlink(s(&outside), &base.join("proc_L5.vtp"));
    let out = d.path().join("g");
    let o = run(&[
        "generate",
        "--base",
        s(&base),
        "--landmarks",
        s(&common::repo_root().join("fixtures/example-scoliosis.csv")),
        "--out",
        s(&out.join("p.osim")),
    ]);
    let t = text(&o);
    assert!(!t.contains("panicked"), "{t}");
    assert!(t.contains("proc_L5.vtp"), "the link is not named:\n{t}");
    nothing_holds(&out, marker);
}
