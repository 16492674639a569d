//! `cargo build` and `cargo test` compile one set of dependencies. With resolver 2 a
//! dev-dependency's features reach shared dependencies only in builds with test targets, and then
//! everything above such a dependency is compiled twice (it cost a fresh `scripts/test.sh` about
//! 4 minutes). `workspace_hack/Cargo.toml` turns those features on in every build; this test fails
//! when a dependency change brings the two feature sets apart again.
use std::collections::BTreeSet;
use std::path::Path;
use std::process::Command;

/// Every `package version [features]` that `cargo tree` resolves over the workspace along `edges`.
fn resolved_features(edges: &str) -> BTreeSet<String> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let out = Command::new(cargo)
        .current_dir(root)
        .args([
            "tree",
            "--workspace",
            "--offline",
            "-e",
            edges,
            "-f",
            "{p} [{f}]",
            "--prefix",
            "none",
        ])
        .output()
        .expect("cargo runs");
    assert!(
        out.status.success(),
        "cargo tree -e {edges} failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout)
        .expect("cargo tree prints UTF-8")
        .lines()
        .map(|l| l.trim_end_matches(" (*)").to_string())
        .filter(|l| !l.is_empty())
        .collect()
}

#[test]
fn normal_and_test_builds_resolve_the_same_dependency_features() {
    let normal = resolved_features("no-dev");
    let with_dev = resolved_features("normal,build,dev");
    assert!(normal.len() > 100, "cargo tree listed only {} packages", normal.len());
    let differ: Vec<&String> = normal.difference(&with_dev).collect();
    assert!(
        differ.is_empty(),
        "these get other features in test builds, so `cargo build` and `cargo test` would compile them \
         and everything above them twice; add the test build's features (`cargo tree --workspace -e \
         normal,build,dev -f '{{p}} [{{f}}]' -i NAME`) to workspace_hack/Cargo.toml:\n{differ:#?}"
    );
}
