//! No file cycle in any crate: within a crate, the files' references (`crate::a::b`, `super::c`,
//! `self::d`, grouped `use crate::{…}` included) form a graph without cycles. A child's reference to
//! its own ancestors (a module file naming what its `mod.rs` or `lib.rs` defines) is not an edge: a
//! parent declares its children, and that is not a dependency. Two sibling files that name each
//! other are a cycle, and so is a longer loop.
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use integration_tests::repo_root;

/// Every `.rs` file under `dir`.
fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    for e in entries.flatten() {
        let p = e.path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// The module path of a file under `src/` (`a/b.rs` and `a/b/mod.rs` → ["a", "b"]; `lib.rs` → []).
fn module_of(src: &Path, file: &Path) -> Vec<String> {
    let rel = file.strip_prefix(src).unwrap();
    let mut parts: Vec<String> = rel.iter().map(|s| s.to_string_lossy().to_string()).collect();
    let last = parts.pop().unwrap();
    let stem = last.trim_end_matches(".rs");
    if stem != "mod" && stem != "lib" && stem != "main" {
        parts.push(stem.to_string());
    }
    parts
}

/// Paths a file names, as module paths from the crate root (`crate::`, `super::`, `self::`).
fn referenced_paths(text: &str, here: &[String]) -> Vec<Vec<String>> {
    let mut out = Vec::new();
    // Comments name paths too (doc links): only code counts.
    let code: String = text
        .lines()
        .map(|l| l.split("//").next().unwrap_or(""))
        .collect::<Vec<_>>()
        .join("\n");
    let bytes = code.as_bytes();
    let ident = |c: u8| c.is_ascii_alphanumeric() || c == b'_';
    for (start, anchor) in [("crate::", 0usize), ("super::", 1), ("self::", 2)] {
        let mut from = 0;
        while let Some(i) = code[from..].find(start) {
            let at = from + i;
            from = at + start.len();
            if at > 0 && (ident(bytes[at - 1]) || bytes[at - 1] == b':') && anchor != 0 {
                continue; // `super::super::…` is read from its first `super`; `x::self::` is not ours
            }
            if at > 0 && ident(bytes[at - 1]) {
                continue;
            }
            // The base module.
            let mut base: Vec<String> = match anchor {
                0 => Vec::new(),
                1 => here[..here.len().saturating_sub(1)].to_vec(),
                _ => here.to_vec(),
            };
            let mut rest = &code[at + start.len()..];
            while let Some(r) = rest.strip_prefix("super::") {
                base.pop();
                rest = r;
            }
            if let Some(group) = rest.strip_prefix('{') {
                // `use crate::{a::b, c}`: one path per top-level item of the group.
                let end = group.find('}').unwrap_or(group.len());
                for item in group[..end].split(',') {
                    let p: Vec<String> = item
                        .trim()
                        .split("::")
                        .map(|s| s.trim().to_string())
                        .take_while(|s| !s.is_empty() && s.bytes().all(ident))
                        .collect();
                    out.push(base.iter().cloned().chain(p).collect());
                }
                continue;
            }
            let p: Vec<String> = rest
                .split("::")
                .map(|s| {
                    s.chars()
                        .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                        .collect::<String>()
                })
                .take_while(|s| !s.is_empty())
                .collect();
            out.push(base.into_iter().chain(p).collect());
        }
    }
    out
}

/// The cycles (as lists of files) among one crate's files.
fn cycles_in(src: &Path) -> Vec<Vec<String>> {
    let mut files = Vec::new();
    rust_files(src, &mut files);
    // Binaries are crate roots of their own: left out (each is one file or a small tree).
    files.retain(|f| !f.strip_prefix(src).unwrap().starts_with("bin"));
    let modules: BTreeMap<Vec<String>, PathBuf> = files.iter().map(|f| (module_of(src, f), f.clone())).collect();
    let mut edges: BTreeMap<Vec<String>, BTreeSet<Vec<String>>> = BTreeMap::new();
    for (m, f) in &modules {
        let text = std::fs::read_to_string(f).unwrap();
        for p in referenced_paths(&text, m) {
            // The longest prefix that is a module file.
            let Some(target) = (0..=p.len())
                .rev()
                .map(|n| p[..n].to_vec())
                .find(|q| modules.contains_key(q))
            else {
                continue;
            };
            let ancestor = m.starts_with(&target);
            if target != *m && !ancestor {
                edges.entry(m.clone()).or_default().insert(target);
            }
        }
    }
    // Depth-first search for back edges.
    let mut cycles = Vec::new();
    let mut state: BTreeMap<Vec<String>, u8> = BTreeMap::new();
    fn visit(
        m: &Vec<String>,
        edges: &BTreeMap<Vec<String>, BTreeSet<Vec<String>>>,
        state: &mut BTreeMap<Vec<String>, u8>,
        stack: &mut Vec<Vec<String>>,
        cycles: &mut Vec<Vec<String>>,
    ) {
        state.insert(m.clone(), 1);
        stack.push(m.clone());
        for t in edges.get(m).into_iter().flatten() {
            match state.get(t).copied().unwrap_or(0) {
                0 => visit(t, edges, state, stack, cycles),
                1 => {
                    let from = stack.iter().position(|s| s == t).unwrap();
                    cycles.push(stack[from..].iter().map(|s| s.join("::")).collect());
                }
                _ => {}
            }
        }
        stack.pop();
        state.insert(m.clone(), 2);
    }
    for m in modules.keys() {
        if state.get(m).copied().unwrap_or(0) == 0 {
            visit(m, &edges, &mut state, &mut Vec::new(), &mut cycles);
        }
    }
    cycles
}

#[test]
fn no_crate_has_a_file_cycle() {
    let root = repo_root();
    let mut found = Vec::new();
    let mut crates = 0;
    for entry in std::fs::read_dir(&root).unwrap().flatten() {
        let src = entry.path().join("src");
        if !entry.path().join("Cargo.toml").is_file() || !src.is_dir() {
            continue;
        }
        crates += 1;
        for c in cycles_in(&src) {
            found.push(format!("{}: {}", entry.file_name().to_string_lossy(), c.join(" → ")));
        }
    }
    assert!(crates >= 15, "only {crates} crates found under {}", root.display());
    assert!(found.is_empty(), "file cycles:\n{}", found.join("\n"));
}

#[test]
fn the_checker_finds_a_sibling_cycle_and_ignores_a_child_naming_its_parent() {
    let dir = std::env::temp_dir().join(format!("g1-file-cycles-{}", std::process::id()));
    let src = dir.join("src");
    std::fs::create_dir_all(src.join("m")).unwrap();
    std::fs::write(
        src.join("lib.rs"),
        "pub mod a;\npub mod b;\npub mod m;\npub struct Root;\n",
    )
    .unwrap();
    std::fs::write(
        src.join("a.rs"),
        "use crate::b::B;\npub struct A;\nfn f(_: crate::Root) {}\n",
    )
    .unwrap();
    std::fs::write(src.join("b.rs"), "pub struct B(super::a::A);\n").unwrap();
    std::fs::write(src.join("m/mod.rs"), "pub mod x;\npub struct M;\n").unwrap();
    std::fs::write(
        src.join("m/x.rs"),
        "use super::M;\n// crate::a::A in a comment is no edge\n",
    )
    .unwrap();
    let cycles = cycles_in(&src);
    std::fs::remove_dir_all(&dir).unwrap();
    assert_eq!(cycles, vec![vec!["a".to_string(), "b".to_string()]]);
}
