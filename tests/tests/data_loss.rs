//! Nothing written is lost (issue 22): SIGINT/SIGTERM during `g1fw sim --log` close the log, write
//! the report marked interrupted and reap the simulator; outputs never overwrite inputs or each
//! other; a simulator that accepts but never answers is a clear error, not a hang.
use std::os::unix::net::UnixListener;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use integration_tests::*;
use runlog::log::LogFile;

/// Children of `pid` (from /proc).
fn children(pid: u32) -> Vec<u32> {
    std::fs::read_dir("/proc")
        .unwrap()
        .filter_map(|e| e.ok()?.file_name().to_str()?.parse::<u32>().ok())
        .filter(|p| {
            std::fs::read_to_string(format!("/proc/{p}/stat")).is_ok_and(|s| {
                // pid (comm) state ppid ...: comm may hold spaces, so split after the last ')'.
                s.rsplit_once(')')
                    .and_then(|(_, rest)| rest.split_whitespace().nth(1)?.parse::<u32>().ok())
                    == Some(pid)
            })
        })
        .collect()
}

/// Starts the built `g1fw` from the repository root, stderr captured.
fn spawn_g1fw(args: &[&str]) -> std::process::Child {
    Command::new(built_bin("g1fw"))
        .args(args)
        .current_dir(repo_root())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("g1fw starts")
}

fn interrupt_a_logged_run(signal: &str, name: &str) {
    let dir = scratch_dir(name);
    let (log, report) = (dir.join("run.mcap"), dir.join("report.json"));
    let child = spawn_g1fw(&[
        "sim",
        "--quiet",
        "--keep-going",
        "--duration",
        "600",
        "--cmd",
        "0.3,0,0",
        "--spec",
        "specs/test/rl_lab_style.toml",
        "--log",
        log.to_str().unwrap(),
        "--report",
        report.to_str().unwrap(),
    ]);
    // Wait until the run is well under way: the simulator is up and the log has its first chunk.
    let start = Instant::now();
    let sim = loop {
        let kids = children(child.id());
        if !kids.is_empty() && std::fs::metadata(&log).is_ok_and(|m| m.len() > 200_000) {
            break kids[0];
        }
        assert!(start.elapsed() < Duration::from_secs(60), "the run did not get going");
        std::thread::sleep(Duration::from_millis(50));
    };
    let kill = Command::new("kill")
        .args([signal, &child.id().to_string()])
        .status()
        .expect("kill runs");
    assert!(kill.success());
    let out = child.wait_with_output().expect("g1fw exits");
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(130), "{err}");
    // The report is written and says so.
    let r = read_json(&report);
    assert_eq!(r["interrupted"], true, "{r}");
    assert!(r["end"].as_str().unwrap().contains("interrupted"), "{r}");
    assert!(r["time_s"].as_f64().unwrap() > 0.1, "{r}");
    // The log is finished (footer, summary, every CRC right), not crash-truncated.
    let end = LogFile::open(&log).unwrap().verify().expect("an intact log");
    assert!(end.truncated.is_none() && end.messages > 1000, "{end:?}");
    // The simulator was stopped and reaped: its process is gone.
    assert!(
        !Path::new(&format!("/proc/{sim}")).exists(),
        "g1-sim (pid {sim}) outlived g1fw"
    );
}

#[test]
fn sigterm_closes_the_log_writes_the_report_and_reaps_the_simulator() {
    interrupt_a_logged_run("-TERM", "sigterm");
}

#[test]
fn sigint_closes_the_log_writes_the_report_and_reaps_the_simulator() {
    interrupt_a_logged_run("-INT", "sigint");
}

#[test]
fn an_output_that_is_another_output_or_an_input_is_refused() {
    let dir = scratch_dir("same-output");
    let same = dir.join("x.mcap");
    std::fs::write(&same, b"keep me").unwrap();
    let s = same.to_str().unwrap();
    for args in [
        vec![
            "sim",
            "--spec",
            "specs/test/rl_lab_style.toml",
            "--log",
            s,
            "--report",
            s,
        ],
        vec![
            "sim",
            "--spec",
            "specs/test/rl_lab_style.toml",
            "--report",
            "specs/test/rl_lab_style.toml",
        ],
        vec![
            "run",
            "--dds",
            "lo",
            "--spec",
            "specs/test/rl_lab_style.toml",
            "--log",
            s,
            "--report",
            s,
        ],
    ] {
        let out = g1fw(&args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        assert!(err.contains("would overwrite"), "{args:?}: {err}");
    }
    assert_eq!(std::fs::read(&same).unwrap(), b"keep me");
}

#[test]
fn a_simulator_that_never_answers_is_a_clear_error() {
    let dir = scratch_dir("silent-sim");
    let sock = dir.join("silent.sock");
    // Accepts, then says nothing (as g1-sim does to a second client while it serves the first).
    let listener = UnixListener::bind(&sock).unwrap();
    let held = std::thread::spawn(move || listener.accept().map(|(s, _)| s));
    let start = Instant::now();
    let out = g1fw(&[
        "sim",
        "--quiet",
        "--spec",
        "specs/test/rl_lab_style.toml",
        "--connect",
        sock.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("sent no Welcome") && err.contains("another g1fw"), "{err}");
    assert!(start.elapsed() < Duration::from_secs(30));
    drop(held.join());
}

/// `kill -9` of g1fw (no handler can run) still ends its simulator: g1-sim dies with its parent
/// instead of waiting on its socket forever. Killed as soon as the simulator runs (before it has a
/// client: without `PR_SET_PDEATHSIG` it would wait in accept() forever), and mid-run.
#[test]
fn the_simulator_dies_with_a_killed_g1fw() {
    for mid_run in [false, true] {
        let mut child = spawn_g1fw(&[
            "sim",
            "--quiet",
            "--keep-going",
            "--duration",
            "600",
            "--spec",
            "specs/test/rl_lab_style.toml",
        ]);
        let start = Instant::now();
        let sim = loop {
            let running =
                |p: &u32| std::fs::read_to_string(format!("/proc/{p}/comm")).is_ok_and(|c| c.trim() == "g1-sim");
            if let Some(&s) = children(child.id()).iter().find(|p| running(p)) {
                break s;
            }
            assert!(start.elapsed() < Duration::from_secs(60), "no simulator started");
            std::thread::sleep(Duration::from_millis(5));
        };
        if mid_run {
            std::thread::sleep(Duration::from_millis(1500));
        }
        child.kill().unwrap();
        child.wait().unwrap();
        let gone = Instant::now();
        // Gone, or a zombie waiting for init to reap it.
        while std::fs::read_to_string(format!("/proc/{sim}/stat")).is_ok_and(|s| !s.contains(") Z ")) {
            assert!(
                gone.elapsed() < Duration::from_secs(5),
                "g1-sim (pid {sim}) outlived a killed g1fw (mid-run: {mid_run})"
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

/// SIGTERM during `g1fw eval`: running episodes stop (their simulators reaped), no new one
/// starts, and the report of the finished ones is written, marked interrupted, exit 130.
#[test]
fn an_interrupted_eval_reports_what_finished() {
    let dir = scratch_dir("eval-sigterm");
    let report = dir.join("eval.json");
    let child = spawn_g1fw(&[
        "eval",
        "--model",
        "g1-12dof",
        "--spec",
        "specs/stairs/g1_stairs_lstm.toml",
        "--worlds",
        "flat,flat,flat,flat,flat,flat",
        "--time-limit",
        "2",
        "--jobs",
        "1",
        "--quiet",
        "--report",
        report.to_str().unwrap(),
    ]);
    // Wait for the second episode's simulator (the first has finished by then).
    let start = Instant::now();
    let mut seen = Vec::new();
    while seen.len() < 2 {
        for c in children(child.id()) {
            if !seen.contains(&c) {
                seen.push(c);
            }
        }
        assert!(start.elapsed() < Duration::from_secs(120), "the eval did not get going");
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_millis(300));
    assert!(Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap()
        .success());
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(130), "{err}");
    let r = read_json(&report);
    assert_eq!(r["interrupted"], true, "{r}");
    assert_eq!(r["episodes_planned"], 6, "{r}");
    let done = r["episodes"].as_u64().unwrap();
    assert!((1..6).contains(&done), "{r}");
    for sim in seen {
        assert!(
            !Path::new(&format!("/proc/{sim}")).exists(),
            "g1-sim {sim} outlived the eval"
        );
    }
}

/// A full disk stops the log, never the control (issue 73; issue 30 stopped the run): the log's
/// first write error (ENOSPC) is named, the run goes on to its end, the report is written (on
/// another disk, and on stdout) and says so, the exit status is not 0, and what reached the disk
/// stays readable. A 1 MiB tmpfs fills up mid-run.
#[test]
fn a_full_disk_stops_the_log_not_the_run_and_keeps_the_report_and_the_log_so_far() {
    let dir = scratch_dir("full_disk");
    let small = dir.join("small");
    std::fs::create_dir_all(&small).unwrap();
    let mounted = std::process::Command::new("mount")
        .args(["-t", "tmpfs", "-o", "size=1m", "tmpfs"])
        .arg(&small)
        .status()
        .is_ok_and(|s| s.success());
    if !mounted {
        return skip_loudly_or_fail(
            "SKIP: the full-disk test mounts a 1 MiB tmpfs (needs root, as the DDS tests' netns)",
        );
    }
    struct Unmount(std::path::PathBuf);
    impl Drop for Unmount {
        fn drop(&mut self) {
            let _ = std::process::Command::new("umount").arg(&self.0).status();
        }
    }
    let _unmount = Unmount(small.clone());
    let log = small.join("run.mcap");
    let report = dir.join("report.json");
    let out = g1fw(&[
        "sim",
        "--duration",
        "5",
        "--quiet",
        "--log",
        log.to_str().unwrap(),
        "--report",
        report.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("No space left on device"), "{err}");
    assert!(!err.contains("attempted another write"), "{err}");
    let r = read_json(&report);
    assert!(
        r["log_error"].as_str().unwrap().contains("No space left on device"),
        "{r}"
    );
    assert_eq!(r["end"], "completed", "the control stopped with the log");
    assert!(
        r["ticks"].as_u64().unwrap() >= 2499,
        "the run stopped at the error: {}",
        r["ticks"]
    );
    // The report is on stdout as well.
    assert!(String::from_utf8_lossy(&out.stdout).contains("\"log_error\""));
    let info = g1fw(&["log-info", log.to_str().unwrap()]);
    let info: serde_json::Value = serde_json::from_slice(&info.stdout).expect("log-info prints JSON");
    let messages = info["messages"].as_object().map_or(0, |m| m.len());
    assert!(messages > 0, "nothing readable in the log: {info}");
}

/// A stop always stops (issue 73): SIGTERM while `g1fw run` waits for a robot that never answers
/// ends it at once (it used to wait out the whole start-up timeout), damped, its report written and
/// its log closed, as a stop and not a fault.
#[test]
fn a_signal_while_waiting_for_the_robot_stops_the_run_at_once() {
    let dir = scratch_dir("stop_at_startup");
    let (log, report) = (dir.join("run.mcap"), dir.join("report.json"));
    // A domain of its own on loopback: nothing answers there.
    let domain = format!("lo,{}", 150 + std::process::id() % 80);
    let child = spawn_g1fw(&[
        "run",
        "--spec",
        "specs/stairs/g1_stairs_lstm.toml",
        "--dds",
        &domain,
        "--startup-timeout",
        "120",
        "--log",
        log.to_str().unwrap(),
        "--report",
        report.to_str().unwrap(),
    ]);
    std::thread::sleep(Duration::from_secs(3));
    let sent = Instant::now();
    assert!(Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap()
        .success());
    let out = child.wait_with_output().expect("g1fw exits");
    let took = sent.elapsed();
    let err = String::from_utf8_lossy(&out.stderr);
    // The end damping (1 s by default) is part of every end.
    assert!(took < Duration::from_secs(5), "took {took:?} after SIGTERM: {err}");
    assert_eq!(out.status.code(), Some(0), "{err}");
    let r = read_json(&report);
    assert_eq!(r["end"], "stopped by signal", "{r}");
    assert_eq!(r["normal_end"], true, "{r}");
    assert!(r["trip"].is_null(), "{r}");
    assert!(r["end_damping"]["sent"].as_u64().unwrap() > 0, "{r}");
    let end = LogFile::open(&log).unwrap().verify().expect("an intact log");
    assert!(end.truncated.is_none(), "{end:?}");
}
