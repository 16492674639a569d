//! `g1fw run --dds` against Unitree's own simulator: unitree_mujoco's `simulate_python` with
//! Unitree's `UnitreeSdk2Bridge` unmodified, over unitree_sdk2py and CycloneDDS 0.10.2 in Python
//! (both read in place from ../shared/peers; `.venv-unitree`, made by scripts/install.sh).
//! `tests/python/unitree_mujoco_harness.py` replaces only the viewer: it sets `config.py` as a user
//! does (the G1 29-dof scene, domain 1, `lo`, a 2 ms step, the elastic band) and lets go of the
//! band once the start-up ramp has run. The walk lock-steps the simulator to the commands
//! (`--lockstep`, g1fw `--tick-on state`), so it passes on any CPU. Each scenario runs in its own
//! network namespace.
#![allow(clippy::disallowed_methods)]
use std::path::PathBuf;
use std::process::Stdio;

use integration_tests::{peer_spec_path, read_json, repo_root, scratch_dir, shared_dir, skip_loudly_or_fail};
use integration_tests::{Netns, Reaped};

/// The Python with unitree_sdk2py's CycloneDDS 0.10.2, MuJoCo and pygame (scripts/install.sh).
fn unitree_python() -> Option<PathBuf> {
    let p = repo_root().join(".venv-unitree/bin/python");
    if p.is_file() {
        return Some(p);
    }
    skip_loudly_or_fail(
        "SKIP: the unitree_mujoco test needs .venv-unitree (CycloneDDS 0.10.2 for Python, MuJoCo, pygame); \
         run scripts/install.sh",
    );
    None
}

struct Outcome {
    report: serde_json::Value,
    status: std::process::ExitStatus,
    stderr: String,
    sim: serde_json::Value,
    log: PathBuf,
    _dir: integration_tests::ScratchDir,
}

/// Unitree's simulator steps in wall-clock time: one scenario at a time, so they do not slow each other.
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// How the simulator's physics is paced.
#[derive(Clone, Copy, PartialEq)]
enum SimPace {
    /// Unitree's own loop: a 2 ms `mj_step` in wall-clock time, states on the bridge's 2 ms timer.
    WallClock,
    /// One physics step per command, then the state (`--lockstep`); g1fw ticks on the states.
    LockStep,
}

/// Metres walked forward while upright (the pelvis above 0.6 m) from where the band let go, and
/// how many 10 Hz trajectory samples that upright stretch has.
fn walked_upright(sim: &serde_json::Value) -> (f64, usize) {
    let upright: Vec<(f64, f64)> = sim["trajectory"]
        .as_array()
        .expect("trajectory")
        .iter()
        .map(|p| (p[1].as_f64().unwrap(), p[3].as_f64().unwrap()))
        .take_while(|&(_, z)| z > 0.6)
        .collect();
    let walked = upright.last().map_or(0.0, |&(x, _)| x) - upright.first().map_or(0.0, |&(x, _)| x);
    (walked, upright.len())
}

/// Unitree's simulator and `g1fw run --dds lo,1 EXTRA… --duration S` in one namespace.
fn run(tag: &str, extra: &[&str], duration: f64, pace: SimPace) -> Option<Outcome> {
    run_with(tag, extra, &[], duration, pace)
}

/// [`run`] with `sim_extra` for the harness too.
fn run_with(tag: &str, extra: &[&str], sim_extra: &[&str], duration: f64, pace: SimPace) -> Option<Outcome> {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let shared = shared_dir().or_else(|| {
        skip_loudly_or_fail("SKIP: the unitree_mujoco test needs ../shared (peers/unitree_mujoco)");
        None
    })?;
    let py = unitree_python()?;
    let Some(ns) = Netns::new(&format!("g1um-{tag}")) else {
        skip_loudly_or_fail("SKIP: the unitree_mujoco test needs a network namespace (`ip netns add`, as root)");
        return None;
    };
    let dir = scratch_dir(&format!("unitree-mujoco-{tag}"));
    let mut harness = ns.command(&py);
    harness
        .arg(repo_root().join("tests/python/unitree_mujoco_harness.py"))
        .args(["--domain", "1", "--interface", "lo", "--duration", "180"]);
    if pace == SimPace::LockStep {
        harness.arg("--lockstep");
    }
    harness.args(sim_extra);
    let sim = Reaped(Some(
        harness
            .env("G1_SHARED", &shared)
            .env("PYTHONUNBUFFERED", "1")
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("python runs the harness"),
    ));
    let report = dir.join("report.json");
    let log = dir.join("run.mcap");
    let duration = duration.to_string();
    // An operated run takes its command from the remote; the others walk at a constant command.
    let mut args = if extra.contains(&"--operated") {
        vec!["--duration", &duration]
    } else {
        vec!["--cmd", "0.8,0,0", "--duration", &duration]
    };
    if pace == SimPace::LockStep {
        // A tick waits up to 100 ms for its state before it runs without one: a slow or loaded CPU
        // delays the state (Python steps and publishes it), it does not lose it.
        args.extend(["--tick-on", "state", "--dds-tick-timeout-ms", "100"]);
    }
    args.extend_from_slice(extra);
    let out = ns.g1fw_run_dds(&peer_spec_path(), &args, &report, &log);
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(report.exists(), "g1fw wrote no report: {stderr}");
    Some(Outcome {
        report: read_json(&report),
        status: out.status,
        stderr,
        sim: sim.wait_json("the unitree_mujoco harness"),
        log,
        _dir: dir,
    })
}

/// The peer walker walks in Unitree's simulator with `--unitree-mujoco`, damps at the end, and the
/// log replays bit-exact (replay stamps the logged samples as the run did). The simulator is
/// lock-stepped to the commands and g1fw ticks on its states, so the walk does not depend on the
/// CPU's speed: in wall-clock time, Python fell to 0.42-0.56 x real time on a slow CPU (CI and fresh
/// checks, 2026-12-01) and the walker tripped in the slowed world (docs/robot.md).
#[test]
fn the_peer_walker_walks_in_unitree_mujoco_and_damps_at_the_end() {
    let Some(o) = run("walk", &["--unitree-mujoco"], 10.0, SimPace::LockStep) else {
        return;
    };
    let r = &o.report;
    let rtf = o.sim["real_time_factor"].as_f64().unwrap_or(0.0);
    eprintln!(
        "unitree_mujoco lock-stepped at {rtf:.2} x real time; {} of {} states repeated the last one",
        r["dds"]["repeated"], r["dds"]["stamped"]
    );
    let ctx = format!("report {r}\nsimulator {}\nstderr {}", o.sim, o.stderr);
    assert_eq!(o.sim["lockstep"], true, "{ctx}");
    assert!(r["trip"].is_null(), "no trip expected: {ctx}");
    assert_eq!(r["end"], "completed", "{ctx}");
    assert_eq!(r["unitree_mujoco"], true, "{ctx}");
    assert_eq!(r["pace"], "state", "{ctx}");
    // Every tick but a few ran on a new state: a silent tick is one whose state came more than
    // 100 ms late.
    let (stamped, silent) = (
        r["dds"]["stamped"].as_u64().unwrap(),
        r["dds"]["silent_ticks"].as_u64().unwrap(),
    );
    assert!(stamped >= 4950 && silent <= 10, "{ctx}");
    // One physics step per command: the world ran at least the 10 s of g1fw's ticks (5000 steps of
    // 2 ms, less a few commands lost in discovery), and no step without a command. The end's
    // damping goes out in wall-clock time, faster than Python steps, so some of it is dropped.
    let (steps, sent) = (
        o.sim["physics_steps"].as_u64().unwrap(),
        r["dds"]["samples_out"].as_u64().unwrap(),
    );
    assert!(
        (4900..=sent).contains(&steps),
        "{steps} steps for {sent} commands: {ctx}"
    );
    assert!(
        r["end_damping"]["sent"].as_u64().unwrap() >= 100,
        "damping after the end: {ctx}"
    );
    assert!(o.status.success(), "{ctx}");
    // Distance walked while upright (the pelvis above 0.6 m), from where the band let go.
    let (walked, _) = walked_upright(&o.sim);
    assert!(
        walked >= 4.0,
        "walked {walked:.2} m forward upright (≥ 4 m expected): {ctx}"
    );
    // The robot went down after the damping (nobody holds it): the end was reached.
    integration_tests::assert_replays_identical(&o.log);
}

/// Without the flag, Unitree's simulator's states (CRC 0) are refused at once, and the run's end
/// names the simulator and the flag.
#[test]
fn unitree_mujoco_states_without_the_flag_are_refused_with_a_message_naming_it() {
    let Some(o) = run("refuse", &[], 2.0, SimPace::WallClock) else {
        return;
    };
    let r = &o.report;
    assert_eq!(r["trip"]["reason"], "crc_streak", "{r}");
    assert!(r["trip"]["tick"].as_u64().unwrap() < 10, "{r}");
    let end = r["end"].as_str().unwrap();
    assert!(end.contains("--unitree-mujoco") && end.contains("CRC of 0"), "{end}");
    assert!(r["dds"]["crc_zero"].as_u64().unwrap() > 0, "{r}");
    assert_eq!(o.status.code(), Some(3), "a latched trip exits 3: {}", o.stderr);
    assert!(r["end_damping"]["sent"].as_u64().unwrap() > 0, "{r}");
}

/// The operator's remote as Unitree's bridge writes it: a scripted gamepad read by the bridge's own
/// joystick code (`--pad`), whose `wireless_remote` bytes g1fw decodes. With the spec's default
/// combinations (unitree_rl_lab's): L2+up stands the robot up from damping, R1+X walks, the left
/// stick walks it 3 m, L2+up stands it still, L2+B damps it. The report names every change and its
/// source, and the log replays bit-exact.
#[test]
fn the_remote_as_unitrees_bridge_writes_it_stands_walks_stands_and_damps_the_robot() {
    let script_dir = scratch_dir("unitree-mujoco-pad");
    let script = script_dir.join("pad.json");
    // Simulated seconds (lock-stepped: one 2 ms step per tick). The band holds the robot until
    // 1.2 s, past the stand-up ramp; the stick is pushed to 0.8 of full (≈ 0.62 m/s).
    std::fs::write(
        &script,
        r#"[
            [0.0, {}],
            [0.3, {"hold": ["LT", "up"]}],
            [0.4, {}],
            [1.25, {"hold": ["RB", "X"]}],
            [1.35, {}],
            [1.4, {"LY": -0.8}],
            [8.4, {}],
            [9.4, {"hold": ["LT", "up"]}],
            [9.5, {}],
            [10.2, {"hold": ["LT", "B"]}],
            [10.3, {}]
        ]"#,
    )
    .unwrap();
    let script_arg = script.to_str().unwrap();
    let Some(o) = run_with(
        "remote",
        &["--unitree-mujoco", "--operated"],
        &["--pad", script_arg, "--release-after", "1.2"],
        11.5,
        SimPace::LockStep,
    ) else {
        return;
    };
    let r = &o.report;
    let ctx = format!("report {r}\nsimulator {}\nstderr {}", o.sim, o.stderr);
    assert!(r["trip"].is_null(), "no trip expected: {ctx}");
    assert_eq!(r["final_mode"], "Passive", "{ctx}");
    let changes = integration_tests::transitions(r);
    let want = [
        ("startup", "remote", 0.3),
        ("stand", "ramp", 0.9),
        ("policy", "remote", 1.25),
        ("startup", "remote", 9.4),
        ("stand", "ramp", 10.0),
        ("passive", "remote", 10.2),
    ];
    let got: Vec<(&str, &str)> = changes.iter().map(|(a, b, _)| (a.as_str(), b.as_str())).collect();
    let wanted: Vec<(&str, &str)> = want.iter().map(|(a, b, _)| (*a, *b)).collect();
    assert_eq!(got, wanted, "{ctx}");
    // On the script's times, counted from the first press: g1fw's clock runs ahead of the
    // simulator's by the ticks it ran on states sent again while discovery swallowed its commands.
    for ((_, _, t), (_, _, wt)) in changes.iter().zip(want) {
        assert!(
            ((t - changes[0].2) - (wt - want[0].2)).abs() < 0.1,
            "{changes:?}: {ctx}"
        );
    }
    // 3 m with the left stick, upright (the pelvis above 0.6 m) from where the band let go to the end
    // of the run: standing still again, the robot did not fall.
    let (walked, samples) = walked_upright(&o.sim);
    assert!(
        walked >= 3.0,
        "walked {walked:.2} m forward upright (≥ 3 m expected): {ctx}"
    );
    let stood_until = samples as f64 * 0.1 + 1.2;
    assert!(
        stood_until >= 10.0,
        "upright until {stood_until:.1} s (simulated): {ctx}"
    );
    integration_tests::assert_replays_identical(&o.log);
}
