//! Compiles the default base model (`base_model/`, every file in it) and
//! the templates (`templates/`) into the binary: writes
//! `$OUT_DIR/embedded_files.rs` with one `include_bytes!` per file, so
//! the file set follows whatever the folders hold when built.

use std::fmt::Write as _;
use std::path::Path;

/// The embedded folders and the constant naming each in the generated file.
const FOLDERS: [(&str, &str); 2] = [("BASE_MODEL", "base_model"), ("TEMPLATES", "templates")];

fn main() {
    let root = std::env::var("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR");
    let out_dir = std::env::var("OUT_DIR").expect("cargo sets OUT_DIR");
    println!("cargo:rerun-if-changed=build.rs");
    let mut code = String::new();
    for (konst, folder) in FOLDERS {
        let dir = Path::new(&root).join(folder);
        println!("cargo:rerun-if-changed={}", dir.display());
        // Sorted file names: the same table on every machine.
        let mut names: Vec<String> = std::fs::read_dir(&dir)
            .map(|rd| {
                rd.filter_map(|e| e.ok())
                    .filter(|e| e.path().is_file())
                    .filter_map(|e| e.file_name().into_string().ok())
                    .collect()
            })
            .unwrap_or_default();
        names.sort();
        writeln!(
            code,
            "/// The files of `{folder}/` (name, bytes), sorted by name."
        )
        .unwrap();
        writeln!(code, "pub static {konst}: &[(&str, &[u8])] = &[").unwrap();
        for n in &names {
            let abs = dir.join(n).display().to_string();
            writeln!(code, "    ({n:?}, include_bytes!({abs:?})),").unwrap();
        }
        writeln!(code, "];").unwrap();
    }
    std::fs::write(Path::new(&out_dir).join("embedded_files.rs"), code)
        .expect("write embedded_files.rs");
}
