//! `g1fw run --dds` paced by its own clock (the default, as on the robot) against `g1-sim --dds
//! --dds-free-run`, which steps in wall-clock time as the robot and unitree_mujoco do. Each scenario
//! runs in its own network namespace.
#![allow(clippy::disallowed_methods)]

use integration_tests::{
    g1_sim_dds, peer_spec_path, read_json, scratch_dir, shared_dir, skip_loudly_or_fail, skip_or_fail, Netns,
};

/// Both run in wall-clock time: one scenario at a time.
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

struct Outcome {
    report: serde_json::Value,
    sim: serde_json::Value,
    log: std::path::PathBuf,
    stderr: String,
    _dir: integration_tests::ScratchDir,
}

fn run(tag: &str, sim_args: &[&str], duration: f64) -> Option<Outcome> {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    if shared_dir().is_none() {
        skip_or_fail("the clock-paced DDS test (the peer policy and the 12-dof model)");
        return None;
    }
    let Some(ns) = Netns::new(&format!("g1clk-{tag}")) else {
        skip_loudly_or_fail("SKIP: the clock-paced DDS test needs a network namespace (`ip netns add`, as root)");
        return None;
    };
    let dir = scratch_dir(&format!("dds-clock-{tag}"));
    let mut sim_extra = vec!["--dds-free-run"];
    sim_extra.extend_from_slice(sim_args);
    let sim = g1_sim_dds(&ns, &sim_extra);
    let report = dir.join("report.json");
    let log = dir.join("run.mcap");
    // Both programs pace themselves by the wall clock on a shared 2-core VM, where even a lone
    // SCHED_FIFO loop sleeping 2 ms periods wakes up to 8-17 ms late (docs/robot.md, "Clock
    // timing"): the 20 ms state timeout would then trip on the VM's stalls, not on the code.
    let duration = duration.to_string();
    let args = [
        "--set",
        "safety.state_timeout_s=0.1",
        "--cmd",
        "0.5,0,0",
        "--duration",
        &duration,
    ];
    let out = ns.g1fw_run_dds(&peer_spec_path(), &args, &report, &log);
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(report.exists(), "no report: {stderr}");
    Some(Outcome {
        report: read_json(&report),
        sim: sim.wait_json("g1-sim --dds --dds-free-run"),
        log,
        stderr,
        _dir: dir,
    })
}

/// The robot's way: a free-running robot, a clock-paced controller. It walks, the clock's lateness
/// is reported, and the log replays bit-exact although nothing was lock-stepped.
#[test]
fn a_clock_paced_run_against_a_free_running_robot_walks_reports_its_jitter_and_replays() {
    let Some(o) = run("walk", &[], 10.0) else { return };
    let r = &o.report;
    let ctx = format!("report {r}\nsim {}\nstderr {}", o.sim, o.stderr);
    assert_eq!(r["pace"], "clock", "{ctx}");
    assert!(r["trip"].is_null(), "{ctx}");
    assert_eq!(r["end"], "completed", "{ctx}");
    let j = &r["period_jitter"];
    assert_eq!(
        j["ticks"], r["ticks"],
        "every tick after the first is clock-paced: {ctx}"
    );
    let (p50, p99, max) = (
        j["p50_us"].as_f64().unwrap(),
        j["p99_us"].as_f64().unwrap(),
        j["max_us"].as_f64().unwrap(),
    );
    eprintln!("clock pacing: late by p50 {p50} µs, p99 {p99} µs, max {max} µs");
    assert!(p50 <= p99 && p99 <= max.ceil(), "{ctx}");
    // The override is said, and nothing else is: the state rate matched the control rate.
    let warnings = r["warnings"].as_array().unwrap();
    assert_eq!(warnings.len(), 1, "{ctx}");
    assert!(
        warnings[0]
            .as_str()
            .unwrap()
            .contains("--set safety.state_timeout_s=0.1"),
        "{ctx}"
    );
    // Walked while the policy ran (the end's damping may let it sink afterwards).
    assert!(o.sim["fell_at_s"].as_f64().is_none_or(|t| t >= 10.0), "{ctx}");
    let x = o.sim["base_travel_m"][0].as_f64().unwrap();
    assert!(x >= 3.5, "walked {x:.2} m: {ctx}");
    assert!(r["end_damping"]["sent"].as_u64().unwrap() >= 100, "{ctx}");
    let out = integration_tests::g1fw(&["replay", o.log.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success() && text.contains("replay identical"), "{text}");
}

/// A robot stepping at 5 ms (unitree_mujoco's default) under a 2 ms control loop: the run says so.
#[test]
fn a_state_rate_far_from_the_control_rate_gets_a_warning() {
    let Some(o) = run("slow", &["--physics-dt", "0.005"], 2.0) else {
        return;
    };
    let w = o.report["warnings"].as_array().unwrap();
    assert!(
        w.iter().any(|n| n.as_str().unwrap().contains("SIMULATE_DT")),
        "report {}\nstderr {}",
        o.report,
        o.stderr
    );
    assert!(o.report["dds"]["stale_ticks"].as_u64().unwrap() > 300, "{}", o.report);
}
