//! A log split into files at a size (`--log-split-mb`, as rosbag2 splits bags): every file replays
//! bit-exact on its own, from the runtime's state at its first tick (the LSTM's memory, the
//! estimator's filter, perception's pose history and token, the supervisor's streaks), the files
//! hold every tick once, and a damaged state is refused by name.
#![allow(clippy::disallowed_methods)]
use std::path::{Path, PathBuf};

use integration_tests::*;

/// `g1fw replay FILE --json`-style summary: (identical, compared perception steps, stderr+stdout).
fn replay(path: &Path) -> (bool, u64, String) {
    let (identical, text) = replays_identical(path);
    let steps = text
        .lines()
        .find_map(|l| l.trim().strip_prefix("\"compared_perception_steps\": "))
        .and_then(|v| v.trim_end_matches(',').parse().ok())
        .unwrap_or(0);
    (identical, steps, text)
}

#[test]
fn a_stair_climb_split_into_files_replays_file_by_file_and_a_damaged_state_is_refused() {
    if shared_dir().is_none() {
        skip_or_fail("the split-log test (the stair policy runs on the 12-dof model)");
        return;
    }
    let dir = scratch_dir("log-split");
    let log = dir.join("climb.mcap");
    let report = dir.join("report.json");
    let args = [
        "sim",
        "--spec",
        "specs/stairs/g1_stairs_lstm.toml",
        "--model",
        "g1-12dof",
        "--world",
        "stairs-up",
        "--duration",
        "6",
        "--cmd",
        "0.5,0,0",
        "--quiet",
        "--log",
        log.to_str().unwrap(),
        "--log-split-mb",
        "2",
        "--report",
        report.to_str().unwrap(),
    ];
    let out = g1fw(&args);
    assert!(ran(&out), "{}", String::from_utf8_lossy(&out.stderr));
    let r = read_json(&report);
    let files = r["log"]["files"].as_u64().expect("log.files");
    assert!(
        files >= 3,
        "a 6 s climb with its lidar frames is more than 3 × 2 MB: {r}"
    );
    let paths: Vec<PathBuf> = (0..files).map(|n| runlog::log::split_path(&log, n)).collect();
    assert!(!runlog::log::split_path(&log, files).exists());
    // Every tick once, in order, across the files.
    let all: Vec<u64> = paths.iter().flat_map(|p| logged_ticks(p).0).collect();
    assert_eq!(all, (0..all.len() as u64).collect::<Vec<_>>());
    assert_eq!(all.len() as u64, r["log"]["records"].as_u64().unwrap());
    // Each file alone, bit for bit, perception included.
    for p in &paths {
        let (identical, perception_steps, text) = replay(p);
        assert!(identical, "{}: {text}", p.display());
        assert!(perception_steps > 0, "{}: perception compared: {text}", p.display());
    }
    // The same run again onto the same name would leave the old parts mixed with the new: refused.
    let out = g1fw(&args);
    let text = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && text.contains("climb_1.mcap") && text.contains("earlier split log"),
        "{text}"
    );
    // A later file whose starting state was altered (one hex digit of it) is refused, by name.
    let second = &paths[1];
    let mut bytes = std::fs::read(second).unwrap();
    let key = b"snapshot_hex";
    let at = bytes
        .windows(key.len())
        .position(|w| w == key)
        .expect("the split record names its state");
    // The value follows its key and a 4-byte length; change its 100th digit.
    let digit = at + key.len() + 4 + 100;
    bytes[digit] = if bytes[digit] == b'0' { b'1' } else { b'0' };
    let damaged = dir.join("damaged_1.mcap");
    std::fs::write(&damaged, &bytes).unwrap();
    let out = g1fw(&["replay", damaged.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&out.stderr).to_string();
    assert_eq!(out.status.code(), Some(2), "{text}");
    assert!(
        text.contains("damaged_1.mcap") && (text.contains("sha256") || text.contains("damaged")),
        "{text}"
    );
}
