//! `g1-train ppo` on the command line: a new run writes its recipe.toml; `--resume DIR` continues
//! it with nothing else; a recipe edited since the checkpoint is refused, naming the setting, and
//! accepted with `--accept-recipe-change`, which the run's table of chunks records.
mod common;
use common::have_12dof_model;
use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/.."))
}

fn g1_train(args: &[&str], out: &Path) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_g1-train"))
        .current_dir(root())
        .args(args)
        .arg(out)
        .output()
        .expect("g1-train runs")
}

fn iteration(dir: &Path) -> u64 {
    let state: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("state.json")).unwrap()).unwrap();
    state["iteration"].as_u64().unwrap()
}

#[test]
fn a_run_resumes_from_its_directory_alone_and_a_changed_recipe_only_on_purpose() {
    if !have_12dof_model() {
        return;
    }
    let dir = std::env::temp_dir().join(format!("g1_ppo_cli_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let new = [
        "ppo",
        "--spec",
        "specs/stairs/g1_stairs_mlp.toml",
        "--actor-hidden",
        "16,16,16",
        "--symmetry",
        "--envs",
        "4",
        "--steps",
        "4",
        "--epochs",
        "1",
        "--minibatches",
        "1",
        "--episode-s",
        "1",
        "--iterations",
        "2",
        "--checkpoint-every",
        "1",
        "--judge-every",
        "0",
        "--threads",
        "1",
        "--quiet",
        "--out",
    ];
    let o = g1_train(&new, &dir);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let recipe = std::fs::read_to_string(dir.join("recipe.toml")).unwrap();
    assert!(
        recipe.contains("envs = 4") && recipe.contains("symmetry = true"),
        "{recipe}"
    );
    assert!(!recipe.contains("threads") && !recipe.contains("quiet"), "{recipe}");
    assert_eq!(iteration(&dir), 2);

    let o = g1_train(
        &["ppo", "--iterations", "3", "--threads", "1", "--quiet", "--resume"],
        &dir,
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(iteration(&dir), 3, "resumed from the directory alone");

    // An edited recipe: refused, naming the setting, until accepted on purpose.
    std::fs::write(
        dir.join("recipe.toml"),
        recipe.replace("entropy-coef = 0.005", "entropy-coef = 0.01"),
    )
    .unwrap();
    let more = ["ppo", "--iterations", "4", "--threads", "1", "--quiet", "--resume"];
    let o = g1_train(&more, &dir);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("entropy_coef: 0.01"), "{err}");
    let accept = [
        "ppo",
        "--iterations",
        "4",
        "--threads",
        "1",
        "--quiet",
        "--accept-recipe-change",
        "--resume",
    ];
    let o = g1_train(&accept, &dir);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(iteration(&dir), 4);
    let chunks = std::fs::read_to_string(dir.join("chunks.md")).unwrap();
    assert_eq!(chunks.lines().count(), 2 + 3, "{chunks}");
    assert!(chunks.contains("new run") && chunks.contains("| resumed |"), "{chunks}");
    assert!(
        chunks.contains("changed recipe") && chunks.contains("entropy_coef: 0.01"),
        "{chunks}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
