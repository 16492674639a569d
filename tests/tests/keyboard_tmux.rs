//! The keyboard operator as a user drives it: `g1fw run --dds --operated --keyboard` in a tmux
//! pane against `g1-sim --dds --dds-free-run` (both in wall-clock time, as with unitree_mujoco),
//! keys sent with `tmux send-keys`: stand up, walk with `w` pressed five times, stop with space,
//! stand, sit down, Ctrl-C.
//! The report names each change and its source, the robot walked, and the log replays bit for bit.
#![allow(clippy::disallowed_methods)]
use std::process::Command;
use std::time::{Duration, Instant};

use integration_tests::{
    assert_replays_identical, built_bin, g1_sim_dds, peer_spec_path, read_json, repo_root, scratch_dir, shared_dir,
    skip_loudly_or_fail, skip_or_fail, transitions, Netns,
};

fn tmux(args: &[&str]) -> std::process::Output {
    Command::new("tmux").args(args).output().expect("tmux runs")
}

/// A detached tmux pane, named; killed on drop (a failing test leaves no pane behind).
/// tmux commands by their aliases: `new` starts one, `kill-ses` ends it.
struct Pane(String);

impl Drop for Pane {
    fn drop(&mut self) {
        let _ = tmux(&["kill-ses", "-t", &self.0]);
    }
}

impl Pane {
    fn screen(&self) -> String {
        String::from_utf8_lossy(&tmux(&["capture-pane", "-p", "-t", &self.0]).stdout).to_string()
    }

    fn keys(&self, keys: &str) {
        for k in keys.chars() {
            let key = if k == ' ' { "Space".to_string() } else { k.to_string() };
            assert!(tmux(&["send-keys", "-t", &self.0, &key]).status.success());
        }
    }
}

#[test]
fn keys_in_a_tmux_pane_stand_walk_stand_and_sit_the_robot() {
    if shared_dir().is_none() {
        skip_or_fail("the keyboard test (the peer policy and the 12-dof model)");
        return;
    }
    if Command::new("tmux").arg("-V").output().is_err() {
        skip_loudly_or_fail("SKIP: the keyboard test needs tmux (scripts/install.sh installs it)");
        return;
    }
    let Some(ns) = Netns::new("g1kbd") else {
        skip_loudly_or_fail("SKIP: the keyboard test needs a network namespace (`ip netns add`, as root)");
        return;
    };
    let dir = scratch_dir("keyboard-tmux");
    let sim = g1_sim_dds(&ns, &["--dds-free-run"]);
    let (report, log) = (dir.join("report.json"), dir.join("run.mcap"));
    // As a user types it in a terminal (the pane), inside the test's network namespace. The state
    // timeout is widened as in the other wall-clock tests (a shared 2-core VM wakes up late).
    let run = format!(
        "cd {root} && ip netns exec {ns} {g1fw} run --dds lo,1 --spec {spec} --operated --keyboard \
         --set safety.state_timeout_s=0.1 --duration 60 --report {report} --log {log} \
         2> {stderr}; echo exited $?; sleep 60",
        root = repo_root().display(),
        ns = ns.name(),
        g1fw = built_bin("g1fw").display(),
        spec = peer_spec_path().display(),
        report = report.display(),
        log = log.display(),
        stderr = dir.join("stderr.txt").display(),
    );
    let tmux_pane = Pane(format!("g1kbd-{}", std::process::id()));
    let started = tmux(&["new", "-d", "-s", &tmux_pane.0, "-x", "160", "-y", "48", &run]);
    assert!(started.status.success(), "{}", String::from_utf8_lossy(&started.stderr));
    // The card of keys goes to stderr (a file here) once the first state has come.
    let stderr_path = dir.join("stderr.txt");
    let t0 = Instant::now();
    while !std::fs::read_to_string(&stderr_path).is_ok_and(|s| s.contains("keyboard operator:")) {
        assert!(
            t0.elapsed() < Duration::from_secs(30) && !tmux_pane.screen().contains("exited"),
            "g1fw never printed its keys: {:?}\npane:\n{}",
            std::fs::read_to_string(&stderr_path),
            tmux_pane.screen()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    // Each key once the robot is where the operator would press it: g1fw prints every change of
    // state as it happens (on a loaded machine the wall clock alone would not tell).
    let seen = |text: &str, times: usize| {
        let t0 = Instant::now();
        loop {
            let err = std::fs::read_to_string(&stderr_path).unwrap_or_default();
            if err.matches(text).count() >= times {
                return;
            }
            assert!(
                t0.elapsed() < Duration::from_secs(20) && !tmux_pane.screen().contains("exited"),
                "waited for `{text}` ({times}×):\n{err}\npane:\n{}",
                tmux_pane.screen()
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    };
    tmux_pane.keys("0"); // stand up: the ramp to the default pose, then standing
    seen("→ stand (ramp)", 1);
    tmux_pane.keys("1wwwww"); // walk, at 0.5 m/s
    seen("→ policy (keyboard)", 1);
    std::thread::sleep(Duration::from_secs(5));
    tmux_pane.keys(" "); // stop walking, as an operator does before standing the robot still
    std::thread::sleep(Duration::from_secs(1));
    tmux_pane.keys("2"); // stand
    seen("→ stand (ramp)", 2);
    tmux_pane.keys("9"); // sit down, then passive by itself
    seen("→ passive (ramp)", 1);
    assert!(
        tmux(&["send-keys", "-t", &tmux_pane.0, "C-c"]).status.success(),
        "Ctrl-C ends the run"
    );
    let t0 = Instant::now();
    while !tmux_pane.screen().contains("exited") {
        assert!(
            t0.elapsed() < Duration::from_secs(30),
            "g1fw did not end:\n{}",
            tmux_pane.screen()
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    let pane = tmux_pane.screen();
    let stderr = std::fs::read_to_string(&stderr_path).unwrap_or_default();
    let r = read_json(&report);
    let sim = sim.wait_json("g1-sim --dds --dds-free-run");
    let ctx = format!("report {r}\nsim {sim}\npane {pane}\nstderr {stderr}");
    assert!(pane.contains("exited 0"), "{ctx}");
    assert_eq!(r["final_mode"], "Passive", "{ctx}");
    assert!(r["trip"].is_null(), "{ctx}");
    let changes = transitions(&r);
    let want = [
        ("startup", "keyboard"),
        ("stand", "ramp"),
        ("policy", "keyboard"),
        ("startup", "keyboard"),
        ("stand", "ramp"),
        ("sit_down", "keyboard"),
        ("passive", "ramp"),
    ];
    let got: Vec<(&str, &str)> = changes.iter().map(|(a, b, _)| (a.as_str(), b.as_str())).collect();
    assert_eq!(got, want, "{ctx}");
    assert_eq!(r["end"].as_str().map(|e| e.starts_with("stopped")), Some(true), "{ctx}");
    // Walked about 5 s at up to 0.5 m/s.
    let x = sim["base_travel_m"][0].as_f64().unwrap();
    assert!(x > 1.5, "walked {x} m: {ctx}");
    // The log names where the requests came from.
    let meta = runlog::log::LogFile::open(&log).unwrap().run_metadata().unwrap();
    assert_eq!(meta.get("operator").map(String::as_str), Some("keyboard"), "{meta:?}");
    assert_replays_identical(&log);
}
