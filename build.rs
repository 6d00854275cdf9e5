//! Compiles the default base model into the binary: writes
//! `$OUT_DIR/embedded_files.rs` with one `include_bytes!` per file of the
//! model, `base_model/base.osim` and the mesh files it names
//! (`<mesh_file>`), so a stray file left in the folder (an `opensim.log`,
//! an editor's backup) never reaches the binary; a mesh the model names but
//! the folder lacks fails the build. (The templates the code reads are
//! embedded where they are read, with `include_str!`.)

use std::fmt::Write as _;
use std::path::Path;

fn main() {
    let root = std::env::var("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR");
    let out_dir = std::env::var("OUT_DIR").expect("cargo sets OUT_DIR");
    println!("cargo:rerun-if-changed=build.rs");
    let base = Path::new(&root).join("base_model");
    let mut code = String::new();
    table(&mut code, "BASE_MODEL", &base, &model_files(&base));
    std::fs::write(Path::new(&out_dir).join("embedded_files.rs"), code)
        .expect("write embedded_files.rs");
}

/// `base.osim` and the mesh files it names, sorted (the same table on every machine).
fn model_files(dir: &Path) -> Vec<String> {
    let model = dir.join("base.osim");
    println!("cargo:rerun-if-changed={}", model.display());
    let text = std::fs::read_to_string(&model).expect("base_model/base.osim is readable UTF-8");
    let mut names: Vec<String> = text
        .split("<mesh_file>")
        .skip(1)
        .filter_map(|rest| rest.split("</mesh_file>").next())
        .map(|n| n.trim().to_string())
        .collect();
    names.push("base.osim".to_string());
    names.sort();
    names.dedup();
    for n in &names {
        assert!(
            !n.contains(['/', '\\']) && dir.join(n).is_file(),
            "base_model/base.osim names `{n}`, which is not a file of base_model/"
        );
    }
    names
}

/// One `pub static KONST: &[(&str, &[u8])]` of the files `names` of `dir`.
fn table(code: &mut String, konst: &str, dir: &Path, names: &[String]) {
    let folder = dir.file_name().and_then(|n| n.to_str()).unwrap_or("");
    writeln!(
        code,
        "/// Embedded files of `{folder}/` (name, bytes), sorted by name."
    )
    .unwrap();
    writeln!(code, "pub static {konst}: &[(&str, &[u8])] = &[").unwrap();
    for n in names {
        let abs = dir.join(n);
        println!("cargo:rerun-if-changed={}", abs.display());
        writeln!(
            code,
            "    ({n:?}, include_bytes!({:?})),",
            abs.display().to_string()
        )
        .unwrap();
    }
    writeln!(code, "];").unwrap();
}
