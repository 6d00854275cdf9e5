//! Compiles the default base model into the binary: writes
//! `$OUT_DIR/embedded_files.rs` with one `include_bytes!` per file of the
//! model, `base_model/base.osim` and the mesh files it names
//! (`<mesh_file>`), so a stray file left in the folder (an `opensim.log`,
//! an editor's backup) never reaches the binary; a mesh the model names but
//! the folder lacks fails the build. (The templates the code reads are
//! embedded where they are read, with `include_str!`.)

#[path = "build/model_files.rs"]
mod model_files;

use std::fmt::Write as _;
use std::path::Path;

fn main() {
    let root = std::env::var("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR");
    let out_dir = std::env::var("OUT_DIR").expect("cargo sets OUT_DIR");
    println!("cargo:rerun-if-changed=build.rs");
    let base = Path::new(&root).join("base_model");
    println!("cargo:rerun-if-changed=build/model_files.rs");
    println!(
        "cargo:rerun-if-changed={}",
        base.join(model_files::MODEL_FILE).display()
    );
    let names = model_files::model_files(&base).unwrap_or_else(|e| panic!("{e}"));
    let mut code = String::new();
    table(&mut code, "BASE_MODEL", &base, &names);
    std::fs::write(Path::new(&out_dir).join("embedded_files.rs"), code)
        .expect("write embedded_files.rs");
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
