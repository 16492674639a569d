//! The README's commands work (issue 32): every `target/release/...` line of its shell blocks
//! parses against the binary's own command line (`G1_CHECK_ARGS=1`), and the ones that run here in
//! seconds (simulate, replay, log-info, the three-world evaluation) run for real, in the README's
//! order, from the repository root, as a user would type them. The rest need what CI does not have
//! (a robot on `eth0`, Unitree's simulator, the user's own policy files, hours of training), so
//! only their arguments are checked; `scripts/demo.sh` is the README's first set-up command.
#![allow(clippy::disallowed_methods)]
use std::process::Command;

use integration_tests::{built_bin, repo_root, shared_dir, skip_or_fail};

/// The README's commands, comments stripped, split into words.
fn readme_commands() -> Vec<Vec<String>> {
    let text = std::fs::read_to_string(repo_root().join("README.md")).expect("README.md");
    let mut in_sh = false;
    let mut out = Vec::new();
    for line in text.lines() {
        if line.starts_with("```") {
            in_sh = line == "```sh";
            continue;
        }
        let line = line.split(" # ").next().unwrap_or("").trim();
        if in_sh && line.starts_with("target/release/") {
            assert!(
                !line.contains(['"', '\'', '$', '|', '&', ';']),
                "README command with shell syntax this test does not split: {line}"
            );
            out.push(line.split_whitespace().map(String::from).collect());
        }
    }
    out
}

/// Quick enough to run for real here (seconds each).
fn runs_here(words: &[String]) -> bool {
    let w: Vec<&str> = words.iter().map(String::as_str).collect();
    match w.as_slice() {
        [bin, "sim" | "replay" | "log-info", ..] if bin.ends_with("/g1fw") => true,
        [bin, "eval", rest @ ..] if bin.ends_with("/g1fw") => rest.contains(&"--worlds"),
        _ => false,
    }
}

fn run(words: &[String], check_only: bool) -> std::process::Output {
    let bin = built_bin(words[0].trim_start_matches("target/release/"));
    let mut c = Command::new(&bin);
    c.args(&words[1..]).current_dir(repo_root());
    if check_only {
        c.env("G1_CHECK_ARGS", "1");
    }
    c.output().unwrap_or_else(|e| panic!("{}: {e}", bin.display()))
}

#[test]
fn every_readme_command_parses_and_the_quick_ones_run() {
    if shared_dir().is_none() {
        return skip_or_fail("the README's commands (the 12-dof model and the peer policy)");
    }
    let commands = readme_commands();
    assert!(commands.len() >= 10, "found only {} README commands", commands.len());
    std::fs::create_dir_all(repo_root().join("out")).unwrap();
    let mut ran = 0;
    for words in &commands {
        let line = words.join(" ");
        let parsed = run(words, true);
        assert!(
            parsed.status.success(),
            "README command does not parse: {line}\n{}",
            String::from_utf8_lossy(&parsed.stderr)
        );
        if runs_here(words) {
            let out = run(words, false);
            assert!(
                out.status.success(),
                "README command failed: {line}\nstdout: {}\nstderr: {}",
                String::from_utf8_lossy(&out.stdout),
                String::from_utf8_lossy(&out.stderr)
            );
            ran += 1;
        }
    }
    assert!(ran >= 5, "ran {ran} README commands for real");
}

/// The check itself fails on a flag that does not exist.
#[test]
fn a_misspelt_flag_fails_the_check() {
    let out = run(
        &["target/release/g1fw".into(), "sim".into(), "--no-such-flag".into()],
        true,
    );
    assert!(!out.status.success());
}
