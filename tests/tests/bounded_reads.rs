//! Every file the project reads goes through the one bounded reader (`input_file`): FIFOs, devices
//! and directories refused without blocking, sizes capped before allocating. This walks the
//! sources of every crate (not their tests) so that a new reader cannot bypass it.
use std::path::{Path, PathBuf};

/// Calls that read a whole file by themselves.
const UNBOUNDED: &[&str] = &[
    "fs::read(",
    "fs::read_to_string(",
    "safetensors::load(",
    "MmapedSafetensors",
    "VarMap::load",
    "vars.load(",
    "vm.load(",
    "varmap.load(",
];

/// Files the project does not take from its user: the kernel's own.
const ALLOWED: &[&str] = &["\"/proc/"];

fn sources(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            sources(&p, out);
        } else if p.extension().is_some_and(|e| e == "rs") {
            out.push(p);
        }
    }
}

#[test]
fn every_reader_goes_through_the_bounded_reader() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let mut files = Vec::new();
    for krate in std::fs::read_dir(&root).unwrap() {
        let src = krate.unwrap().path().join("src");
        if src.is_dir() && !src.starts_with(root.join("input_file")) && !src.starts_with(root.join("xtask")) {
            sources(&src, &mut files);
        }
    }
    assert!(files.len() > 100, "found only {} source files", files.len());
    let mut found = Vec::new();
    for f in &files {
        let text = std::fs::read_to_string(f).unwrap();
        // Unit tests read their fixtures as they like.
        let code = text.split("#[cfg(test)]").next().unwrap();
        for (i, line) in code.lines().enumerate() {
            let l = line.trim_start();
            if l.starts_with("//") || ALLOWED.iter().any(|a| l.contains(a)) {
                continue;
            }
            if UNBOUNDED.iter().any(|u| l.contains(u)) {
                found.push(format!("{}:{}: {}", f.strip_prefix(&root).unwrap().display(), i + 1, l));
            }
        }
    }
    assert!(
        found.is_empty(),
        "read these through input_file::read_capped / read_text_capped:\n{}",
        found.join("\n")
    );
}
