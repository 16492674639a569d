//! MCAP logs: crash safety under `kill -9`, an independent reader (Python `mcap`), and replay of a
//! freshly recorded run. These runs use the 29-dof model installed by scripts/install.sh and the
//! committed rl_lab-style spec, so they need nothing from ../shared.
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use integration_tests::*;
use runlog::log::LogFile;

/// Ticks per chunk the logger flushes (LogOptions::default).
const FLUSH_EVERY: u64 = 250;

fn python_read(py: &Path, log: &Path) -> serde_json::Value {
    python_json(py, "read_log.py", &[log])
}

fn contiguous_from_zero(t: &[u64]) -> bool {
    t.iter().enumerate().all(|(i, &k)| k == i as u64)
}

#[test]
fn kill_9_mid_run_keeps_every_flushed_chunk() {
    let dir = scratch_dir("kill9");
    let log = dir.join("run.mcap");
    let mut child = Command::new(built_bin("g1fw"))
        .args([
            "sim",
            "--model",
            "g1-29dof",
            "--spec",
            "specs/test/rl_lab_style.toml",
            "--hold",
            "--ramp",
            "2",
        ])
        .args(["--duration", "600", "--keep-going", "--quiet", "--log"])
        .arg(&log)
        .current_dir(repo_root())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("g1fw starts");
    // Wait for a few chunks on disk, then snapshot the file and kill without warning.
    let t0 = Instant::now();
    while std::fs::metadata(&log).map_or(0, |m| m.len()) < 600_000 {
        assert!(t0.elapsed() < Duration::from_secs(60), "log did not grow");
        assert!(child.try_wait().unwrap().is_none(), "g1fw exited early");
        std::thread::sleep(Duration::from_millis(20));
    }
    let snapshot_bytes = std::fs::read(&log).unwrap();
    Command::new("kill")
        .arg("-9")
        .arg(child.id().to_string())
        .status()
        .unwrap();
    let status = child.wait().unwrap();
    assert!(!status.success(), "killed process cannot succeed");
    let snapshot = dir.join("snapshot.mcap");
    std::fs::write(&snapshot, &snapshot_bytes).unwrap();

    // The prefix that existed before the kill: every chunk in it reads back, ticks 0.. contiguous,
    // ending on a chunk boundary.
    let (ticks, truncated) = logged_ticks(&snapshot);
    assert!(truncated.is_some(), "a prefix has no footer");
    assert!(ticks.len() as u64 >= FLUSH_EVERY, "{} ticks", ticks.len());
    assert!(contiguous_from_zero(&ticks));
    assert_eq!(ticks.len() as u64 % FLUSH_EVERY, 0, "reads end on a chunk boundary");

    // The file after the kill holds at least as much, and the same ticks first.
    let (after, truncated_after) = logged_ticks(&log);
    assert!(truncated_after.is_some(), "no footer after kill -9");
    assert!(after.len() >= ticks.len() && after[..ticks.len()] == ticks[..]);

    // The run metadata survives (written first), so the crash log still replays bit-exact.
    let out = g1fw(&["replay", log.to_str().unwrap()]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "replay of the crash log: {stderr}");
    assert!(stderr.contains("ends early"), "{stderr}");

    // An independent reader agrees.
    if let Some(py) = venv_python("kill_9 python check") {
        let v = python_read(&py, &snapshot);
        assert_eq!(v["ticks"].as_u64().unwrap(), ticks.len() as u64, "{v}");
        assert_eq!(v["contiguous"], true);
        assert!(v["metadata"]["g1fw.run"].as_array().unwrap().len() > 5, "{v}");
    }
}

#[test]
fn python_mcap_reads_a_complete_log_like_we_do() {
    let Some(py) = venv_python("python reader test") else {
        return;
    };
    let dir = scratch_dir("pyread");
    let log = dir.join("run.mcap");
    let out = g1fw(&[
        "sim",
        "--model",
        "g1-29dof",
        "--spec",
        "specs/test/rl_lab_style.toml",
        "--duration",
        "2",
        "--quiet",
        "--keep-going",
        "--log",
        log.to_str().unwrap(),
    ]);
    assert!(ran(&out), "{}", String::from_utf8_lossy(&out.stderr));
    let v = python_read(&py, &log);
    assert!(v["truncated"].is_null(), "{v}");
    assert_eq!(v["json_ok"], true);
    assert_eq!(v["contiguous"], true);
    assert_eq!(v["low_state_sample"]["len"], 2092);
    assert_eq!(v["low_cmd_sample"]["len"], 1004);
    // Same message counts per topic as our own reader.
    let mut ours = std::collections::BTreeMap::<String, u64>::new();
    LogFile::open(&log)
        .unwrap()
        .scan(|t, _, _| *ours.entry(t.to_string()).or_default() += 1);
    let theirs: std::collections::BTreeMap<String, u64> = serde_json::from_value(v["topics"].clone()).unwrap();
    assert_eq!(ours, theirs);
    for t in [
        "/hal/low_state",
        "/hal/low_cmd",
        "/policy/action",
        "/policy/observation",
        "/estimator/state",
        "/safety/state",
        "/timing/tick",
        "/sim/truth",
        "/operator/command",
    ] {
        assert!(theirs.get(t).copied().unwrap_or(0) > 0, "{t} missing: {theirs:?}");
    }
    // The same log renders to a velocity-tracking PNG.
    let png = dir.join("v.png");
    let out = g1fw(&["plot", log.to_str().unwrap(), "--out", png.to_str().unwrap()]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(std::fs::read(&png).unwrap().starts_with(b"\x89PNG"));
}

#[test]
fn a_fresh_log_replays_bit_exact_and_perturbed_weights_diverge() {
    let dir = scratch_dir("replay");
    let log = dir.join("run.mcap");
    // The seeded test MLP does not walk; that is fine: what matters is the same outputs again.
    let out = g1fw(&[
        "sim",
        "--model",
        "g1-29dof",
        "--spec",
        "specs/test/rl_lab_style.toml",
        "--duration",
        "3",
        "--quiet",
        "--keep-going",
        "--cmd",
        "0.3,0,0.2",
        "--log",
        log.to_str().unwrap(),
    ]);
    assert!(ran(&out), "{}", String::from_utf8_lossy(&out.stderr));
    let report = dir.join("replay.json");
    let out = g1fw(&["replay", log.to_str().unwrap(), "--report", report.to_str().unwrap()]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
    assert_eq!(r["ticks"], 1501);
    // It falls and the supervisor latches damping after a few dozen steps.
    assert!(r["compared_policy_steps"].as_u64().unwrap() > 20, "{r}");

    // One weight changed by one part in a thousand.
    let weights = repo_root().join("specs/test/mlp_480_29.safetensors");
    let bytes = std::fs::read(&weights).unwrap();
    let perturbed = dir.join("perturbed.safetensors");
    std::fs::write(&perturbed, perturb_first_weight(&bytes)).unwrap();
    let out = g1fw(&[
        "replay",
        log.to_str().unwrap(),
        "--weights",
        perturbed.to_str().unwrap(),
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "pinned hash refuses: {stderr}");
    assert!(
        stderr.contains("sha256") && stderr.contains("--allow-mismatch"),
        "{stderr}"
    );
    let out = g1fw(&[
        "replay",
        log.to_str().unwrap(),
        "--weights",
        perturbed.to_str().unwrap(),
        "--allow-mismatch",
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "divergence exits 1: {stderr}");
    assert!(stderr.contains("REPLAY DIVERGED: first divergence at tick"), "{stderr}");
    assert!(
        stderr.contains("/policy/") && stderr.contains("values["),
        "names channel and field: {stderr}"
    );
}
