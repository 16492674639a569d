//! Fault injection end to end: the simulator injects each fault (g1-sim --fault), and the firmware
//! must latch damping within 2 fast ticks of the fault becoming detectable, never panic, and log
//! the trip with its reason. Every fault starts at t = 1.5 s (tick 750), with the policy walking.
use std::path::Path;

use control::operator::CommandSchedule;
use control::spec::DeploySpec;
use firmware::sim_run::{run_sim, Report, SimOptions};
use integration_tests::*;
use runlog::log::channels as ch;
use runlog::log::LogFile;

const FAULT_TICK: u64 = 750;

struct Outcome {
    report: Report,
    /// (tick, reason, joint) of every trip event in the log.
    trips: Vec<(u64, String, String)>,
    resets: Vec<u64>,
    hal_events: usize,
    last_logged_tick: u64,
}

fn run(name: &str, faults: &[&str], schedule: Option<&str>) -> Option<Outcome> {
    let Some(_) = shared_dir() else {
        skip_or_fail("fault injection tests");
        return None;
    };
    let dir = scratch_dir(&format!("fault-{name}"));
    let log = dir.join("run.mcap");
    let spec = DeploySpec::load(&peer_spec_path()).unwrap();
    let opts = SimOptions {
        model: "g1-12dof".into(),
        schedule: match schedule {
            Some(text) => CommandSchedule::parse(text, Path::new("inline")).unwrap(),
            None => CommandSchedule::constant([0.5, 0.0, 0.0]),
        },
        duration_s: 2.5,
        sim_bin: Some(built_bin("g1-sim")),
        stop_on_fall: false,
        faults: faults.iter().map(|s| s.to_string()).collect(),
        log: Some(log.clone()),
        ..Default::default()
    };
    let report = run_sim(spec, &opts, |_| {}).unwrap_or_else(|e| panic!("{name}: run failed: {e:#}"));
    let file = LogFile::open(&log).unwrap();
    let (mut trips, mut resets, mut hal_events, mut last) = (Vec::new(), Vec::new(), 0, 0);
    let end = file.scan(|topic, _, data| match topic {
        ch::SAFETY_EVENT => {
            let v: serde_json::Value = serde_json::from_slice(data).unwrap();
            let tick = v["tick"].as_u64().unwrap();
            if v["event"] == "trip" {
                trips.push((
                    tick,
                    v["reason"].as_str().unwrap().to_string(),
                    v["joint"].as_str().unwrap().to_string(),
                ));
            } else {
                resets.push(tick);
            }
        }
        ch::HAL_EVENT => hal_events += 1,
        ch::LOW_STATE => last = ch::decode_low_state_frame(data).unwrap().tick,
        _ => {}
    });
    assert!(
        end.truncated.is_none(),
        "{name}: log closed properly: {:?}",
        end.truncated
    );
    Some(Outcome {
        report,
        trips,
        resets,
        hal_events,
        last_logged_tick: last,
    })
}

/// Asserts one trip, for `reason`, within 2 ticks after `detectable`.
fn assert_trip(o: &Outcome, reason: &str, detectable: u64) {
    assert_eq!(o.trips.len(), 1, "exactly one latched trip: {:?}", o.trips);
    let (tick, r, _) = &o.trips[0];
    assert_eq!(r, reason, "trip reason; report: {:?}", o.report.trip);
    assert!(
        *tick >= detectable.saturating_sub(2) && *tick <= detectable + 2,
        "{reason}: tripped at tick {tick}, detectable at {detectable}"
    );
    assert!(
        o.report.final_mode.starts_with(&format!("Damping({}", camel(reason))),
        "{}",
        o.report.final_mode
    );
    let t = o.report.trip.as_ref().expect("report names the trip");
    assert_eq!(t.tick, *tick);
}

fn camel(reason: &str) -> String {
    reason
        .split('_')
        .map(|w| w[..1].to_uppercase() + &w[1..])
        .collect::<String>()
}

#[test]
fn no_fault_no_trip() {
    let Some(o) = run("none", &[], None) else { return };
    assert!(o.trips.is_empty(), "{:?}", o.trips);
    assert_eq!(o.report.final_mode, "Policy");
    assert_eq!(o.report.safety.crc_failures + o.report.safety.missing_frames, 0);
}

#[test]
fn dropped_frames_trip_the_state_timeout() {
    // 10-tick timeout (state_timeout_s 0.02): the last frame is tick 749, so tick 760 is too old.
    let Some(o) = run("drop", &["drop@1.5+0.1"], None) else {
        return;
    };
    assert_trip(&o, "state_timeout", FAULT_TICK + 10);
    assert!(o.report.safety.missing_frames >= 10);
}

#[test]
fn delayed_frames_trip_the_state_timeout() {
    // Frames 20 ticks late: their counter goes back, nothing newer arrives for 20 ticks.
    let Some(o) = run("delay", &["delay@1.5+0.2:20"], None) else {
        return;
    };
    assert_trip(&o, "state_timeout", FAULT_TICK + 10);
    assert!(o.report.safety.stale_frames >= 10);
}

#[test]
fn a_crc_streak_trips_but_a_single_bad_frame_does_not() {
    let Some(o) = run("corrupt", &["corrupt@1.5+0.1"], None) else {
        return;
    };
    assert_trip(&o, "crc_streak", FAULT_TICK + 2); // third bad frame in a row
    let Some(o) = run("corrupt1", &["corrupt@1.5+0.002"], None) else {
        return;
    };
    assert!(o.trips.is_empty(), "one bad frame is counted, not fatal: {:?}", o.trips);
    assert_eq!(o.report.safety.crc_failures, 1);
}

#[test]
fn nan_in_the_imu_trips_at_once() {
    let Some(o) = run("imu-nan", &["imu-nan@1.5+0.01"], None) else {
        return;
    };
    assert_trip(&o, "non_finite_input", FAULT_TICK);
}

#[test]
fn a_frozen_encoder_trips_after_the_frozen_window() {
    // Detectable once 10 identical frames (safety.frozen_state_frames) have arrived.
    let Some(o) = run("freeze", &["freeze-joint@1.5:3"], None) else {
        return;
    };
    assert_trip(&o, "frozen_joint", FAULT_TICK + 9);
    assert_eq!(o.trips[0].2, "left_knee");
}

#[test]
fn a_motor_that_stops_answering_trips() {
    let Some(o) = run("dead", &["motor-dead@1.5:9"], None) else {
        return;
    };
    assert_trip(&o, "frozen_joint", FAULT_TICK + 9);
    assert_eq!(o.trips[0].2, "right_knee");
}

#[test]
fn an_overheating_motor_trips_at_once() {
    let Some(o) = run("overheat", &["overheat@1.5:4"], None) else {
        return;
    };
    assert_trip(&o, "motor_temperature", FAULT_TICK);
    assert_eq!(o.trips[0].2, "left_ankle_pitch");
}

#[test]
fn a_bridge_disconnect_damps_and_keeps_the_log() {
    let Some(o) = run("disconnect", &["disconnect@1.5"], None) else {
        return;
    };
    assert_trip(&o, "hal_fault", FAULT_TICK);
    assert_eq!(o.hal_events, 1);
    assert!(o.report.end.contains("at tick 750"), "{}", o.report.end);
    assert_eq!(o.last_logged_tick, FAULT_TICK, "every tick up to the failure is logged");
}

#[test]
fn operator_estop_latches_and_reset_restarts() {
    let Some(o) = run("estop", &[], Some("0 0.5 0 0\n1.5 estop\n1.52 reset\n")) else {
        return;
    };
    assert_eq!(o.trips.len(), 1, "{:?}", o.trips);
    assert_eq!((o.trips[0].0, o.trips[0].1.as_str()), (FAULT_TICK, "estop"));
    assert_eq!(o.resets, vec![760], "reset at 1.52 s");
    // Ramp 0.5 s + hold 0.1 s after the reset: policy again from tick 1060.
    assert_eq!(o.report.final_mode, "Policy");
}
