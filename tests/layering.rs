//! The modules of `src/` depend on each other in one direction only: the
//! order written at the top of ARCHITECTURE.md (`a -> b`: `b` may use `a`,
//! never the reverse). Every `crate::` path in the code of `src/` (comments
//! and string literals aside) is checked against it, as is the list of
//! top-level modules in `src/lib.rs`.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Names at the crate root that are not modules, and the module that owns
/// them (`lib.rs` re-exports, `#[macro_export]` macros).
const ROOT_ITEMS: &[(&str, &str)] = &[
    ("Error", "error"),
    ("Result", "error"),
    ("out", "util"),
    ("outln", "util"),
    ("errln", "util"),
];

/// The module order of ARCHITECTURE.md: the first line that is a single
/// code span of module names joined by `->` (names of one stage separated
/// by commas share a rank). Module -> rank.
fn module_order(architecture: &str) -> BTreeMap<String, usize> {
    let line = architecture
        .lines()
        .map(str::trim)
        .find(|l| l.starts_with('`') && l.ends_with('`') && l.contains("->"))
        .expect("ARCHITECTURE.md has no module order line (`a -> b -> ...`)");
    let mut rank = BTreeMap::new();
    for (r, stage) in line.trim_matches('`').split("->").enumerate() {
        for m in stage.split(',') {
            let m = m.trim();
            assert!(
                !m.is_empty() && m.chars().all(|c| c.is_ascii_lowercase() || c == '_'),
                "module order: '{m}' is not a module name"
            );
            assert!(
                rank.insert(m.to_string(), r).is_none(),
                "module order names '{m}' twice"
            );
        }
    }
    rank
}

/// `src` with comments, string and character literals blanked (newlines
/// kept, so line numbers stay).
fn code_only(src: &str) -> String {
    let b = src.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let blank = |out: &mut Vec<u8>, s: &[u8]| {
        out.extend(s.iter().map(|&c| if c == b'\n' { b'\n' } else { b' ' }));
    };
    let mut i = 0;
    while i < b.len() {
        let rest = &b[i..];
        let prev_ident = i > 0 && (b[i - 1].is_ascii_alphanumeric() || b[i - 1] == b'_');
        let end = if rest.starts_with(b"//") {
            i + rest.iter().position(|&c| c == b'\n').unwrap_or(rest.len())
        } else if rest.starts_with(b"/*") {
            let (mut depth, mut j) = (0usize, i);
            loop {
                if j >= b.len() {
                    break j;
                }
                if b[j..].starts_with(b"/*") {
                    depth += 1;
                    j += 2;
                } else if b[j..].starts_with(b"*/") {
                    depth -= 1;
                    j += 2;
                    if depth == 0 {
                        break j;
                    }
                } else {
                    j += 1;
                }
            }
        } else if !prev_ident
            && (rest.starts_with(b"r\"")
                || rest.starts_with(b"r#")
                || rest.starts_with(b"br\"")
                || rest.starts_with(b"br#"))
        {
            // raw string: r#*" ... "#*
            let start = i + rest.iter().position(|&c| c == b'r').unwrap_or(0) + 1;
            let hashes = b[start..].iter().take_while(|&&c| c == b'#').count();
            if b.get(start + hashes) != Some(&b'"') {
                out.push(b[i]);
                i += 1;
                continue;
            }
            let close: Vec<u8> = std::iter::once(b'"')
                .chain(std::iter::repeat_n(b'#', hashes))
                .collect();
            let body = start + hashes + 1;
            body + b[body..]
                .windows(close.len())
                .position(|w| w == close.as_slice())
                .map_or(b.len() - body, |p| p + close.len())
        } else if rest[0] == b'"' {
            let mut j = i + 1;
            while j < b.len() && b[j] != b'"' {
                j += if b[j] == b'\\' { 2 } else { 1 };
            }
            (j + 1).min(b.len())
        } else if rest[0] == b'\'' && !prev_ident {
            // a character literal ('x', '\n', '\u{..}'), not a lifetime ('a)
            if rest.get(1) == Some(&b'\\') {
                i + 2
                    + rest[2..]
                        .iter()
                        .position(|&c| c == b'\'')
                        .map_or(0, |p| p + 1)
            } else {
                let ch = std::str::from_utf8(&rest[1..])
                    .ok()
                    .and_then(|s| s.chars().next());
                match ch {
                    Some(c) if rest.get(1 + c.len_utf8()) == Some(&b'\'') => i + 2 + c.len_utf8(),
                    _ => {
                        out.push(b[i]);
                        i += 1;
                        continue;
                    }
                }
            }
        } else {
            out.push(b[i]);
            i += 1;
            continue;
        };
        blank(&mut out, &b[i..end]);
        i = end;
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// The crate-root names that `crate::` paths in `code` start with, with
/// their 1-based lines (`crate::{a, b::c}` gives `a` and `b`).
fn crate_paths(code: &str) -> Vec<(usize, String)> {
    let ident = |s: &str| -> String {
        s.trim_start()
            .chars()
            .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
            .collect()
    };
    let mut out = Vec::new();
    for (k, _) in code.match_indices("crate::") {
        let before = code[..k].chars().next_back();
        if before.is_some_and(|c| c.is_ascii_alphanumeric() || c == '_' || c == '$') {
            continue;
        }
        let line = code[..k].matches('\n').count() + 1;
        let rest = code[k + "crate::".len()..].trim_start();
        if let Some(group) = rest.strip_prefix('{') {
            let (mut depth, mut item_start) = (0usize, true);
            for (j, c) in group.char_indices() {
                match c {
                    '{' => depth += 1,
                    '}' if depth == 0 => break,
                    '}' => depth -= 1,
                    ',' if depth == 0 => item_start = true,
                    c if item_start && !c.is_whitespace() => {
                        item_start = false;
                        let name = ident(&group[j..]);
                        if !name.is_empty() && name != "self" {
                            out.push((line, name));
                        }
                    }
                    _ => {}
                }
            }
        } else {
            let name = ident(rest);
            if !name.is_empty() {
                out.push((line, name));
            }
        }
    }
    out
}

/// Every `crate::` reference of `code` (the source of a file of module
/// `module`) to a module later in `rank`, as `line: crate::name`.
fn violations(code: &str, module: &str, rank: &BTreeMap<String, usize>) -> Vec<String> {
    let own = rank[module];
    let mut bad = Vec::new();
    for (line, name) in crate_paths(&code_only(code)) {
        let target = ROOT_ITEMS
            .iter()
            .find(|(n, _)| *n == name)
            .map_or(name.as_str(), |(_, m)| m);
        match rank.get(target) {
            Some(&r) if r > own => bad.push(format!(
                "line {line}: crate::{name} ({target} comes after {module})"
            )),
            Some(_) => {}
            None => bad.push(format!(
                "line {line}: crate::{name} is neither a module in the order nor a known root item"
            )),
        }
    }
    bad
}

/// The `.rs` files of a directory, recursively.
fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

#[test]
fn modules_depend_only_on_earlier_modules() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let rank = module_order(&std::fs::read_to_string(root.join("ARCHITECTURE.md")).unwrap());
    // The order names exactly the top-level modules of lib.rs.
    let lib = std::fs::read_to_string(root.join("src/lib.rs")).unwrap();
    let modules: Vec<String> = code_only(&lib)
        .lines()
        .filter_map(|l| {
            l.trim()
                .strip_prefix("pub mod ")?
                .strip_suffix(';')
                .map(String::from)
        })
        .collect();
    assert!(!modules.is_empty(), "no `pub mod` in src/lib.rs");
    for m in &modules {
        assert!(
            rank.contains_key(m),
            "module `{m}` of src/lib.rs is not in the ARCHITECTURE.md order"
        );
    }
    for m in rank.keys() {
        assert!(
            modules.contains(m),
            "ARCHITECTURE.md orders `{m}`, which src/lib.rs does not declare"
        );
    }
    // Every `crate::` path of each module's files points to an earlier module.
    let mut bad = Vec::new();
    for m in &modules {
        let mut files = Vec::new();
        let file = root.join(format!("src/{m}.rs"));
        if file.exists() {
            files.push(file);
        }
        let dir = root.join(format!("src/{m}"));
        if dir.is_dir() {
            rust_files(&dir, &mut files);
        }
        assert!(!files.is_empty(), "module `{m}` has no source file");
        files.sort();
        for f in files {
            let src = std::fs::read_to_string(&f).unwrap();
            for v in violations(&src, m, &rank) {
                bad.push(format!("{}: {v}", f.strip_prefix(root).unwrap().display()));
            }
        }
    }
    assert!(
        bad.is_empty(),
        "imports against the module order of ARCHITECTURE.md:\n  {}",
        bad.join("\n  ")
    );
}

#[test]
fn the_checker_finds_a_later_module_and_ignores_comments_and_strings() {
    let rank = module_order("# A\n\n`error, util -> osim -> mesh`\n");
    assert_eq!(rank["error"], rank["util"]);
    assert!(rank["osim"] < rank["mesh"]);
    let ok = "//! see [`crate::mesh`]\n/* crate::mesh */\nuse crate::{util::x, Error};\n\
              const S: &str = \"crate::mesh\"; const R: &str = r#\"crate::mesh\"#;\n\
              fn f<'a>(c: char) -> bool { c == '\"' && crate::util::g() }\n";
    assert_eq!(violations(ok, "osim", &rank), Vec::<String>::new());
    let bad = "use crate::{\n    util,\n    mesh::TriMesh,\n};\nfn g() { crate::mesh::read(); }\n";
    assert_eq!(
        violations(bad, "osim", &rank),
        vec![
            "line 1: crate::mesh (mesh comes after osim)".to_string(),
            "line 5: crate::mesh (mesh comes after osim)".to_string(),
        ]
    );
    assert_eq!(
        violations("fn h() { crate::nowhere::f() }", "osim", &rank).len(),
        1
    );
}
