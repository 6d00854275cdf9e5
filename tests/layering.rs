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

/// The sibling names of `dir_module` (`osim`, `diagnose::synth`) that
/// `code` (a file of that directory, comments and strings blanked, test
/// module cut) refers to: `super::NAME` and `crate::<dir_module>::NAME`.
fn sibling_refs(code: &str, dir_module: &str, siblings: &[String]) -> Vec<String> {
    let code = code.split("#[cfg(test)]").next().unwrap_or("");
    let ident = |s: &str| -> String {
        s.chars()
            .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
            .collect()
    };
    let mut out = Vec::new();
    let full = format!("crate::{dir_module}::");
    for prefix in ["super::", full.as_str()] {
        for (k, _) in code.match_indices(prefix) {
            let before = code[..k].chars().next_back();
            if before.is_some_and(|c| c.is_ascii_alphanumeric() || c == '_' || c == ':') {
                continue;
            }
            let rest = &code[k + prefix.len()..];
            let names: Vec<String> = match rest.strip_prefix('{') {
                Some(group) => group
                    .split('}')
                    .next()
                    .unwrap_or("")
                    .split(',')
                    .map(|s| ident(s.trim()))
                    .collect(),
                None => vec![ident(rest)],
            };
            out.extend(names.into_iter().filter(|n| siblings.contains(n)));
        }
    }
    out.sort();
    out.dedup();
    out
}

/// A cycle in `edges` (node -> nodes it uses), as the list of its nodes.
fn find_cycle(edges: &BTreeMap<String, Vec<String>>) -> Option<Vec<String>> {
    fn visit(
        n: &str,
        edges: &BTreeMap<String, Vec<String>>,
        state: &mut BTreeMap<String, u8>,
        stack: &mut Vec<String>,
    ) -> Option<Vec<String>> {
        state.insert(n.to_string(), 1);
        stack.push(n.to_string());
        for m in edges.get(n).into_iter().flatten() {
            match state.get(m.as_str()) {
                Some(1) => {
                    let at = stack.iter().position(|s| s == m).unwrap_or(0);
                    return Some(stack[at..].to_vec());
                }
                Some(_) => {}
                None => {
                    if let Some(c) = visit(m, edges, state, stack) {
                        return Some(c);
                    }
                }
            }
        }
        stack.pop();
        state.insert(n.to_string(), 2);
        None
    }
    let mut state = BTreeMap::new();
    for n in edges.keys() {
        if !state.contains_key(n.as_str()) {
            if let Some(c) = visit(n, edges, &mut state, &mut Vec::new()) {
                return Some(c);
            }
        }
    }
    None
}

/// The sibling files (and sub-folders) of every module folder, as a graph.
fn sibling_cycles(dir: &Path, module: &str, out: &mut Vec<String>) {
    let mut nodes: BTreeMap<String, Vec<PathBuf>> = BTreeMap::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        let name = p.file_stem().unwrap().to_string_lossy().to_string();
        if p.is_dir() {
            sibling_cycles(&p, &format!("{module}::{name}"), out);
            let mut files = Vec::new();
            rust_files(&p, &mut files);
            nodes.entry(name).or_default().extend(files);
        } else if p.extension().is_some_and(|x| x == "rs") && name != "mod" {
            nodes.entry(name).or_default().push(p);
        }
    }
    let names: Vec<String> = nodes.keys().cloned().collect();
    let mut edges = BTreeMap::new();
    for (n, files) in &nodes {
        let mut used = Vec::new();
        for f in files {
            // Files of a sub-folder reach this folder's siblings by the
            // full path only (their `super::` is the sub-folder).
            let direct = f.parent() == Some(dir);
            let code = code_only(&std::fs::read_to_string(f).unwrap());
            let refs = if direct {
                sibling_refs(&code, module, &names)
            } else {
                sibling_refs(&code.replace("super::", "_uper::"), module, &names)
            };
            used.extend(refs.into_iter().filter(|r| r != n));
        }
        used.sort();
        used.dedup();
        edges.insert(n.clone(), used);
    }
    if let Some(c) = find_cycle(&edges) {
        out.push(format!(
            "src/{}: {}",
            module.replace("::", "/"),
            c.join(" -> ")
        ));
    }
}

#[test]
fn no_cycle_between_sibling_files() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut bad = Vec::new();
    for e in std::fs::read_dir(&root).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            let m = p.file_name().unwrap().to_string_lossy().to_string();
            sibling_cycles(&p, &m, &mut bad);
        }
    }
    assert!(
        bad.is_empty(),
        "files of one module that use each other (move the shared types to a file both use):\n  {}",
        bad.join("\n  ")
    );
}

#[test]
fn the_sibling_checker_sees_super_and_full_paths() {
    let names = vec!["a".to_string(), "b".to_string(), "c".to_string()];
    let code = "use super::{a::X, c};\nfn f() { crate::m::b::g(); crate::other::a::h(); }\n";
    assert_eq!(sibling_refs(code, "m", &names), vec!["a", "b", "c"]);
    let mut edges = BTreeMap::new();
    edges.insert("a".to_string(), vec!["b".to_string()]);
    edges.insert("b".to_string(), vec!["c".to_string()]);
    edges.insert("c".to_string(), vec![]);
    assert_eq!(find_cycle(&edges), None);
    edges.insert("c".to_string(), vec!["a".to_string()]);
    assert_eq!(find_cycle(&edges).map(|c| c.len()), Some(3));
}
