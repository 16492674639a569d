//! `g1fw run --dds` against an independent peer: Debian's CycloneDDS 0.10.2 (the robot's version),
//! driven by `tests/dds_peer/g1_dds_peer.c` with its own IDL (compiled here by Debian's `idlc`) and
//! its own CRC. The peer relays between `g1-sim --dds` (the robot, domain 2) and `g1fw` (domain 1):
//! it republishes every LowState_ with a CRC it computes itself, checks every LowCmd_'s CRC, its
//! `mode_machine` echo and its gains against the spec's, and injects faults. Each scenario runs in
//! its own network namespace with multicast on `lo`, so nothing leaves this machine and parallel
//! tests do not hear each other.
#![allow(clippy::disallowed_methods)]
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::OnceLock;

use integration_tests::{
    built_bin, peer_spec_path, read_json, repo_root, scratch_dir, shared_dir, skip_loudly_or_fail, skip_or_fail, Netns,
    Reaped,
};

/// Loud skip outside CI, failure in CI (where install.sh put the tools and the tests run as root).
fn missing(what: &str) {
    skip_loudly_or_fail(&format!(
        "SKIP: the DDS peer test needs {what} (scripts/install.sh installs cyclonedds-dev and cyclonedds-tools)"
    ));
}

fn have(cmd: &str, arg: &str) -> bool {
    Command::new(cmd)
        .arg(arg)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

/// Builds the peer once per test binary: idlc → C, the short type renamed to LowState_'s wire
/// name (for the wrong-size injection), gcc against Debian's libddsc.
fn peer_binary() -> Option<&'static Path> {
    static PEER: OnceLock<Option<PathBuf>> = OnceLock::new();
    PEER.get_or_init(|| {
        if !have("idlc", "-v") || !Path::new("/usr/include/dds/dds.h").exists() {
            missing("Debian's CycloneDDS 0.10.2 (cyclonedds-dev, cyclonedds-tools: idlc)");
            return None;
        }
        let src = repo_root().join("tests/dds_peer");
        let out = built_bin("g1fw").parent().unwrap().join("dds_peer");
        std::fs::create_dir_all(&out).unwrap();
        for idl in ["unitree_hg.idl", "short_state.idl"] {
            let st = Command::new("idlc")
                .arg("-o")
                .arg(&out)
                .arg(src.join(idl))
                .status()
                .expect("idlc runs");
            assert!(st.success(), "idlc {idl} failed");
        }
        let short = out.join("short_state.c");
        let text = std::fs::read_to_string(&short).unwrap();
        assert!(text.contains("\"short_state::LowState_\""), "idlc output changed");
        std::fs::write(
            &short,
            text.replace("\"short_state::LowState_\"", "\"unitree_hg::msg::dds_::LowState_\""),
        )
        .unwrap();
        let bin = out.join("g1_dds_peer");
        let st = Command::new("gcc")
            .args(["-O2", "-Wall", "-Werror", "-I"])
            .arg(&out)
            .arg(src.join("g1_dds_peer.c"))
            .arg(out.join("unitree_hg.c"))
            .arg(&short)
            .args(["-lddsc", "-o"])
            .arg(&bin)
            .status()
            .expect("gcc runs");
        assert!(st.success(), "building the peer failed");
        Some(bin)
    })
    .as_deref()
}

struct Outcome {
    fw: serde_json::Value,
    fw_status: std::process::ExitStatus,
    fw_stderr: String,
    peer: serde_json::Value,
    sim: serde_json::Value,
    log: PathBuf,
    _dir: integration_tests::ScratchDir,
}

/// The spec's gains per enabled slot, as the peer reads them.
fn gains_file(dir: &Path) -> PathBuf {
    let spec = control::spec::DeploySpec::load(&peer_spec_path()).expect("spec");
    let controller = control::controller::Controller::new(spec).expect("controller");
    let mut text = String::new();
    for (slot, g) in controller.gain_table().iter().enumerate() {
        if let Some(g) = g {
            text += &format!(
                "{slot} {:.9e} {:.9e} {:.9e} {:.9e} {:.9e}\n",
                g.startup.0, g.startup.1, g.policy.0, g.policy.1, g.damping_kd
            );
        }
    }
    let p = dir.join("gains.txt");
    std::fs::write(&p, text).unwrap();
    p
}

/// Every test here runs programs in wall-clock time: one at a time on a small machine.
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// One scenario: g1-sim (robot, domain 2) ⇄ peer ⇄ g1fw (domain 1), for `duration` seconds, g1fw
/// ticking with `--tick-on pace`.
fn scenario(tag: &str, faults: &[&str], duration: f64, expect_run: bool, pace: &str) -> Option<Outcome> {
    // Three programs per scenario run in wall-clock time on two cores: one scenario at a time, or
    // the peer's reader falls behind and misses commands (477 of 500 damping commands seen once).
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    if shared_dir().is_none() {
        skip_or_fail("the DDS peer test (the peer policy and the 12-dof model)");
        return None;
    }
    let peer = peer_binary()?;
    let Some(ns) = Netns::new(&format!("g1dds-{tag}")) else {
        missing("a network namespace (`ip netns add`, as root) for a private multicast lo");
        return None;
    };
    let dir = scratch_dir(&format!("dds-{tag}"));
    let gains = gains_file(&dir);
    let sim = Reaped(Some(
        ns.command(&built_bin("g1-sim"))
            .args([
                "--dds",
                "lo,2",
                "--model",
                "g1-12dof",
                "--quiet",
                "--dds-idle-exit",
                "1",
            ])
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("g1-sim"),
    ));
    let mut pc = ns.command(peer);
    pc.args([
        "--robot-domain",
        "2",
        "--controller-domain",
        "1",
        "--idle-exit",
        "1",
        "--gains",
    ])
    .arg(&gains);
    for f in faults {
        pc.args(["--fault", f]);
    }
    let peer_child = Reaped(Some(
        pc.stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().expect("peer"),
    ));
    let report = dir.join("report.json");
    let log = dir.join("run.mcap");
    let duration = duration.to_string();
    let mut args = vec![
        "--tick-on",
        pace,
        "--cmd",
        "0.5,0,0",
        "--duration",
        &duration,
        // A silent link ticks every 4 ms: the supervisor's 20 ms state timeout still sees it.
        "--dds-tick-timeout-ms",
        "4",
    ];
    if pace == "clock" {
        // On the clock, three 500 Hz programs share two cores, and two DDS hops lie between the
        // simulator and g1fw: a scheduling stall of 20 ms happened on an idle 2-core VM (fresh check
        // 34: no state from tick 4411 to 4421, damping, a fall). The robot's default timeout is
        // not what this walk tests (`stale_states_latch_damping` does, at 20 ms, ticking on the
        // states), so it gets the tolerance `g1fw run --set` documents for a busy host.
        args.extend(["--set", "safety.state_timeout_s=0.1"]);
    }
    let fw = ns.g1fw_run_dds(&peer_spec_path(), &args, &report, &log);
    let fw_stderr = String::from_utf8_lossy(&fw.stderr).to_string();
    let fw_json = if report.exists() {
        read_json(&report)
    } else {
        serde_json::Value::Null
    };
    // A run that never started leaves the peer and the simulator waiting: they are killed.
    let (peer_json, sim_json) = if expect_run {
        (peer_child.wait_json("the peer"), sim.wait_json("g1-sim --dds"))
    } else {
        (serde_json::Value::Null, serde_json::Value::Null)
    };
    Some(Outcome {
        fw: fw_json,
        fw_status: fw.status,
        fw_stderr,
        peer: peer_json,
        sim: sim_json,
        log,
        _dir: dir,
    })
}

fn u(v: &serde_json::Value) -> u64 {
    v.as_u64().unwrap_or_else(|| panic!("not a count: {v}"))
}

#[test]
fn g1fw_walks_over_dds_through_an_independent_cyclonedds_peer() {
    // On the clock, as on the robot: the walk and the second of damping after it in real time (ticking
    // on the states, the walk outran real time and the peer missed up to 64 of the 500 damping
    // commands, 2 runs in 7).
    let Some(o) = scenario("walk", &[], 10.0, true, "clock") else {
        return;
    };
    let (fw, peer, sim) = (&o.fw, &o.peer, &o.sim);
    eprintln!("g1fw: {fw}\npeer: {peer}\nsim: {sim}");
    assert!(o.fw_status.success(), "g1fw failed: {}", o.fw_stderr);
    assert_eq!(fw["end"], "completed");
    assert!(fw["trip"].is_null(), "trip over DDS: {}", fw["trip"]);
    assert_eq!(u(&fw["ticks"]), 5000);
    assert!(u(&fw["policy_steps"]) >= 450, "{}", fw["policy_steps"]);
    assert_eq!(u(&fw["dds"]["rejected"]), 0);
    // The host's tolerance (see `scenario`) is on the record, as every `--set` is.
    assert!(
        fw["warnings"].as_array().is_some_and(|w| w
            .iter()
            .any(|n| n.as_str().is_some_and(|n| n.contains("safety.state_timeout_s=0.1")))),
        "{}",
        fw["warnings"]
    );
    // The peer: every command's CRC is right, echoes mode_machine, and carries the spec's gains.
    // g1fw handed 5000 commands over; the transport writes the newest when two come before it
    // wakes (a silent tick's command and the next), and the peer's BEST_EFFORT KEEP_LAST 1 reader
    // may miss one when two arrive between its takes (each seen once in CI: 4999).
    let d = &fw["dds"];
    // Then the damping command every period for 1 s after the end (--end-damping's default).
    let end_sent = u(&fw["end_damping"]["sent"]);
    assert_eq!(
        (end_sent, u(&fw["end_damping"]["failed"])),
        (500, 0),
        "{}",
        fw["end_damping"]
    );
    assert_eq!(u(&d["samples_out"]) + u(&d["coalesced"]), 5000 + end_sent, "{d}");
    assert!(u(&d["samples_out"]) >= 4990, "{d}");
    let cmds = u(&peer["cmds"]);
    assert!(cmds >= 4990, "the peer saw {cmds} of 5000 commands");
    assert_eq!(u(&peer["cmd_crc_bad"]), 0);
    assert_eq!(u(&peer["cmd_crc_ok"]), cmds);
    assert_eq!(u(&peer["mode_machine_mismatch"]), 0);
    assert_eq!(u(&peer["frames"]["mismatch"]), 0, "{}", peer["first_mismatch"]);
    assert!(u(&peer["frames"]["startup"]) >= 250, "{}", peer["frames"]);
    // The same KEEP_LAST 1 reader: 4463 of 4500 once, with a training run on both cores beside
    // the test (g1fw's own counts above were exact).
    assert!(u(&peer["frames"]["policy"]) >= 4450, "{}", peer["frames"]);
    // The peer counts the damping after the normal end. Its reader keeps the last sample only, so
    // under load it misses a few (488 of 500 once, with clippy running beside the tests); what
    // g1fw sent is asserted exactly above.
    let damping = u(&peer["frames"]["damping"]);
    assert!(
        (475..=500).contains(&damping),
        "the peer saw {damping} damping commands after the end"
    );
    // Our g1-sim's LowState_ CRC, checked by the peer's own implementation.
    assert_eq!(u(&peer["state_crc_bad_from_robot"]), 0);
    assert!(u(&peer["states_out"]) >= 4990);
    // It walked: 0.5 m/s for ~9.4 s under the policy, no fall.
    // No fall while the policy ran (10 s); the end's damping may let it sink afterwards.
    assert!(sim["fell_at_s"].as_f64().is_none_or(|t| t >= 10.0), "{sim}");
    let x = sim["base_travel_m"][0].as_f64().unwrap();
    assert!(x >= 3.5, "walked only {x:.2} m in 10 s at 0.5 m/s: {sim}");
    // The log replays bit-exact from the CDR samples it recorded.
    let out = integration_tests::g1fw(&["replay", o.log.to_str().unwrap()]);
    assert!(
        out.status.success(),
        "replay of the DDS log: {}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// A fault injected by the peer at 2.5 s (policy running): damping latches for `reason`, and the
/// peer sees the damping commands (except when it is the one that died).
fn fault_latches(tag: &str, fault: &str, reason: &str) {
    fault_latches_within(tag, fault, reason, 0.5, 4.0)
}

/// As [`fault_latches`], the trip expected within `within` s of the fault at 2.5 s.
fn fault_latches_within(tag: &str, fault: &str, reason: &str, within: f64, duration: f64) {
    // g1-sim --dds and the peer step when a command comes (lock-step): tick on their states, so a
    // loaded machine's late answers do not read as the fault under test.
    let Some(o) = scenario(tag, &[fault], duration, true, "state") else {
        return;
    };
    let (fw, peer) = (&o.fw, &o.peer);
    eprintln!("g1fw: {fw}\npeer: {peer}\nsim: {}", o.sim);
    assert_eq!(o.fw_status.code(), Some(3), "exit 3 = a trip latched: {}", o.fw_stderr);
    let trip = &fw["trip"];
    assert_eq!(trip["reason"], reason, "{trip}");
    let at = trip["time_s"].as_f64().unwrap();
    assert!(
        (2.4..2.5 + within).contains(&at),
        "tripped at {at} s, the fault began at 2.5 s"
    );
    assert!(
        fw["final_mode"].as_str().unwrap().starts_with("Damping"),
        "{}",
        fw["final_mode"]
    );
    assert!(
        !peer["faults_fired"].as_array().unwrap().is_empty(),
        "the fault never fired: {peer}"
    );
    assert_eq!(u(&peer["cmd_crc_bad"]), 0);
    assert_eq!(u(&peer["frames"]["mismatch"]), 0, "{}", peer["first_mismatch"]);
    if peer["end"] != "died" {
        assert!(
            u(&peer["frames"]["damping"]) > 0,
            "the peer saw no damping command: {peer}"
        );
    }
    // Replay reproduces the run, fault included.
    let out = integration_tests::g1fw(&["replay", o.log.to_str().unwrap()]);
    assert!(
        out.status.success(),
        "replay: {}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// The robot reports a variant without the legs the spec drives: the run stops before the policy
/// moves anything, damps, and exits non-zero (it used to exit 0 with `trip: null`), its report
/// saying why.
#[test]
fn a_variant_without_the_driven_legs_stops_damped_and_exits_non_zero() {
    let Some(o) = scenario("variant", &["variant@2.5+10"], 4.0, true, "state") else {
        return;
    };
    let fw = &o.fw;
    eprintln!("g1fw: {fw}\npeer: {}", o.peer);
    assert_eq!(o.fw_status.code(), Some(3), "{}", o.fw_stderr);
    assert_eq!(fw["normal_end"], false, "{fw}");
    let end = fw["end"].as_str().unwrap();
    assert!(end.contains("mode_machine 9") && end.contains("damping"), "{end}");
    assert!(fw["time_s"].as_f64().unwrap() < 3.0, "ran on past the variant: {fw}");
}

#[test]
fn stale_states_latch_damping() {
    fault_latches("stale", "stale@2.5+1", "state_timeout");
}

#[test]
fn a_bad_crc_latches_damping() {
    fault_latches("crc", "crc@2.5+1", "crc_streak");
}

#[test]
fn a_wrong_size_sample_latches_damping() {
    fault_latches("size", "size@2.5+1", "malformed_frame");
}

#[test]
fn a_second_lowcmd_publisher_latches_damping() {
    // Seen through discovery (the new writer's announcement, then a 200 ms check): measured
    // 0.3–1 s here, allowed 3 s on a loaded machine.
    fault_latches_within("writer", "writer@2.5", "hal_fault", 3.0, 6.0);
}

#[test]
fn a_peer_that_dies_latches_damping() {
    fault_latches("die", "die@2.5", "state_timeout");
}

#[test]
fn g1fw_refuses_to_start_while_another_program_publishes_lowcmd() {
    let Some(o) = scenario("refuse", &["writer@0"], 2.0, false, "state") else {
        return;
    };
    assert_eq!(o.fw_status.code(), Some(2), "g1fw should refuse: {}", o.fw_stderr);
    assert!(
        o.fw_stderr.contains("another program publishes rt/lowcmd"),
        "{}",
        o.fw_stderr
    );
    assert!(o.fw.is_null(), "no report for a run that never started");
}

/// The whole robot path without CycloneDDS: `g1-sim --dds` playing the G1 on a staircase and its
/// MID-360 over UDP, `g1fw run --dds --lidar-udp` with the stair policy and perception on its
/// thread. Frames reach perception over UDP, its results come back on their tick, the policy walks.
#[test]
fn the_stair_policy_runs_over_dds_with_the_mid360_over_udp() {
    // The heaviest run here (lidar rendering and the CNN): beside a scenario it starved the peer,
    // whose late states read as a dead link (a state_timeout 0.17 s into a run, fault due at 2.5 s).
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    if shared_dir().is_none() {
        return skip_or_fail("the DDS stair run (the 12-dof model)");
    }
    let Some(ns) = Netns::new("g1dds-stairs") else {
        return missing("a network namespace (`ip netns add`, as root) for a private multicast lo");
    };
    let dir = scratch_dir("dds-stairs");
    let sim = Reaped(Some(
        ns.command(&built_bin("g1-sim"))
            .args([
                "--dds",
                "lo,1",
                "--model",
                "g1-12dof",
                "--quiet",
                "--dds-idle-exit",
                "1",
            ])
            .args([
                "--world",
                "specs/worlds/stairs_up_low.toml",
                "--lidar-udp-to",
                "127.0.0.1:56301",
            ])
            .current_dir(repo_root())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("g1-sim"),
    ));
    let report = dir.join("report.json");
    let log = dir.join("run.mcap");
    let args = [
        "--tick-on",
        "state",
        "--lidar-udp",
        "127.0.0.1:56301",
        "--lidar-from",
        "any",
        // The speed the stair policy is judged at (docs/results.md): at 0.4 m/s the
        // committed actor stalls at the first 5 cm riser and trips on knee speed after 4.3 s,
        // with or without DDS (`g1fw sim` does the same).
        "--cmd",
        "0.5,0,0",
        "--duration",
        "6",
    ];
    let spec = repo_root().join("specs/stairs/g1_stairs_lstm.toml");
    let fw = ns.g1fw_run_dds(&spec, &args, &report, &log);
    assert!(fw.status.success(), "g1fw: {}", String::from_utf8_lossy(&fw.stderr));
    let r = read_json(&report);
    let sim = sim.wait_json("g1-sim --dds");
    eprintln!("g1fw: {r}\nsim: {sim}");
    assert!(r["trip"].is_null(), "{}", r["trip"]);
    assert_eq!(r["perception"]["exec"], "threaded:10");
    let lidar = &r["lidar"];
    assert!(u(&lidar["frames_used"]) >= 50, "{lidar}");
    assert_eq!(u(&lidar["malformed"]), 0, "{lidar}");
    assert!(u(&sim["lidar_datagrams_sent"]) > 10_000, "{sim}");
    // No fall while the policy ran (6 s); the end's damping may let it sink afterwards.
    assert!(sim["fell_at_s"].as_f64().is_none_or(|t| t >= 6.0), "{sim}");
    assert!(sim["base_travel_m"][0].as_f64().unwrap() > 1.0, "{sim}");
    let out = integration_tests::g1fw(&["replay", log.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "replay: {text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // Perception was fed and compared, step for step, from the recorded frames.
    let rep: serde_json::Value = serde_json::from_str(&text).expect("replay prints JSON");
    assert!(u(&rep["compared_perception_steps"]) >= 50, "{rep}");
}
