//! The safety supervisor through the runtime, one trigger at a time, from hand-made states: each
//! latches damping (kp = 0, damping kd on every enabled motor) on the tick it becomes detectable,
//! stays latched until an operator reset, and names its reason.
// Test inputs come from std's math on the host; this never runs on the robot.
#![allow(clippy::disallowed_methods)]
mod common;
use common::{healthy, tick};
use std::path::Path;

use control::controller::{Controller, DampingReason, Mode};
use control::operator::OperatorInput;
use control::runtime::{Runtime, TickSummary};
use control::spec::DeploySpec;
use control::supervisor::FrameStatus;
use hal::{ErrorKind, LowCommand, LowState};

fn spec() -> DeploySpec {
    DeploySpec::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("../specs/test/rl_lab_style.toml")).unwrap()
}

fn runtime() -> Runtime {
    Runtime::new(Controller::new(spec()).unwrap())
}

/// One tick; the command goes nowhere (these tests read it from `cmd`).
fn step(
    rt: &mut Runtime,
    k: u64,
    f: FrameStatus,
    st: &LowState,
    op: OperatorInput,
    cmd: &mut LowCommand,
) -> TickSummary {
    rt.tick(tick(k), f, st, op, cmd, |_| Ok::<(), ()>(())).0
}

/// Runs healthy ticks `0..until`, then `bad(k)` from `until` on for `n` ticks; returns the first
/// trip (tick, reason).
fn trip_after(
    mut rt: Runtime,
    until: u64,
    n: u64,
    bad: impl Fn(u64) -> (FrameStatus, LowState, OperatorInput),
) -> (Runtime, Option<(u64, DampingReason)>) {
    let mut cmd = LowCommand::default();
    let op = OperatorInput {
        velocity: [0.3, 0.0, 0.0],
        ..Default::default()
    };
    for k in 0..until {
        let s = step(&mut rt, k, FrameStatus::Fresh, &healthy(k), op, &mut cmd);
        assert!(s.tripped.is_none(), "healthy tick {k} tripped: {:?}", s.tripped);
    }
    for k in until..until + n {
        let (f, st, o) = bad(k);
        step(&mut rt, k, f, &st, o, &mut cmd);
    }
    let trip = rt.trip();
    if trip.is_some() {
        assert!(matches!(rt.mode(), Mode::Damping(_)));
        assert!(
            cmd.motors[..29].iter().all(|m| m.kp == 0.0 && m.kd == 5.0),
            "damping command"
        );
    }
    (rt, trip)
}

const OP: OperatorInput = OperatorInput {
    velocity: [0.3, 0.0, 0.0],
    estop: false,
    reset: false,
    request: None,
};

#[test]
fn tilt_over_one_radian_trips() {
    let (_, trip) = trip_after(runtime(), 100, 1, |k| {
        let mut s = healthy(k);
        let a: f32 = 1.05;
        s.imu.quaternion = [(a / 2.0).cos(), (a / 2.0).sin(), 0.0, 0.0];
        (FrameStatus::Fresh, s, OP)
    });
    assert_eq!(trip, Some((100, DampingReason::Tilt)));
    // 0.95 rad does not.
    let (_, trip) = trip_after(runtime(), 100, 5, |k| {
        let mut s = healthy(k);
        let a: f32 = 0.95;
        s.imu.quaternion = [(a / 2.0).cos(), (a / 2.0).sin(), 0.0, 0.0];
        (FrameStatus::Fresh, s, OP)
    });
    assert_eq!(trip, None);
}

#[test]
fn joint_speed_base_rate_and_temperature_limits_trip() {
    // Joint speed: each motor's own limit by default (knee 20 rad/s, hip pitch 32), not Unitree's
    // optional 10 rad/s helper.
    let fast = |slot: usize, dq: f32| {
        trip_after(runtime(), 50, 1, move |k| {
            let mut s = healthy(k);
            s.motors[slot].dq = dq;
            (FrameStatus::Fresh, s, OP)
        })
        .1
    };
    assert_eq!(fast(9, -15.0), None, "right knee at 15 rad/s is inside its motor's 20");
    assert_eq!(fast(9, -20.5), Some((50, DampingReason::JointSpeed { slot: 9 })));
    assert_eq!(
        fast(0, 25.0),
        None,
        "left hip pitch at 25 rad/s is inside its motor's 32"
    );
    assert_eq!(fast(0, 32.5), Some((50, DampingReason::JointSpeed { slot: 0 })));
    // Base angular speed, per axis: a norm of 6.18 with every axis under 6 is fine, one axis over trips.
    let spin = |w: [f32; 3]| {
        trip_after(runtime(), 50, 1, move |k| {
            let mut s = healthy(k);
            s.imu.gyroscope = w;
            (FrameStatus::Fresh, s, OP)
        })
        .1
    };
    assert_eq!(spin([4.0, 4.0, 2.5]), None);
    assert_eq!(spin([0.0, -6.1, 0.0]), Some((50, DampingReason::BaseAngularSpeed)));
    let (_, trip) = trip_after(runtime(), 50, 1, |k| {
        let mut s = healthy(k);
        s.motors[20].temperature = [40, 121];
        (FrameStatus::Fresh, s, OP)
    });
    assert_eq!(trip, Some((50, DampingReason::MotorTemperature { slot: 20 })));
}

/// The test spec with `safety` (TOML) appended; it has no `[safety]` table of its own.
fn spec_with_safety(safety: &str) -> Result<DeploySpec, control::spec::SpecError> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../specs/test/rl_lab_style.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    assert!(!text.contains("[safety]"));
    DeploySpec::from_toml(&format!("{text}\n{safety}"), &path)
}

#[test]
fn a_spec_may_tighten_joint_speed_limits_but_not_loosen_them() {
    let strict = spec_with_safety(
        "[safety]\njoint_speed_limit_rad_s = 12.0\n[safety.joint_speed_limits_rad_s]\nleft_knee = 8.0\n",
    )
    .unwrap();
    let lim = control::supervisor::MotionLimits::from_spec(&strict);
    assert_eq!(lim.joint_speed_rad_s[3], 8.0, "left knee: its own entry");
    assert_eq!(
        lim.joint_speed_rad_s[9], 12.0,
        "right knee: the spec's 12 under the motor's 20"
    );
    assert_eq!(lim.joint_speed_rad_s[4], 12.0, "left ankle: 12 under 37");
    let (_, trip) = trip_after(Runtime::new(Controller::new(strict).unwrap()), 50, 1, |k| {
        let mut s = healthy(k);
        s.motors[3].dq = 9.0;
        (FrameStatus::Fresh, s, OP)
    });
    assert_eq!(trip, Some((50, DampingReason::JointSpeed { slot: 3 })));

    // Looser than the motor, or a joint the G1 does not have: refused, naming the field.
    let err = spec_with_safety("[safety.joint_speed_limits_rad_s]\nleft_knee = 25.0\n")
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("safety.joint_speed_limits_rad_s.left_knee") && err.contains("20"),
        "{err}"
    );
    let err = spec_with_safety("[safety.joint_speed_limits_rad_s]\nleft_tail = 5.0\n")
        .unwrap_err()
        .to_string();
    assert!(err.contains("left_tail"), "{err}");
    let err = spec_with_safety("[safety]\njoint_speed_limit_rad_s = -1.0\n")
        .unwrap_err()
        .to_string();
    assert!(err.contains("safety.joint_speed_limit_rad_s"), "{err}");
}

#[test]
fn crc_failures_trip_only_as_a_streak_and_stale_state_times_out() {
    // Two bad frames, one good, two bad: never three in a row.
    let (rt, trip) = trip_after(runtime(), 50, 5, |k| {
        let f = if k == 52 {
            FrameStatus::Fresh
        } else {
            FrameStatus::Bad(ErrorKind::Checksum)
        };
        (f, healthy(k), OP)
    });
    assert_eq!(trip, None);
    assert_eq!(rt.counters().crc_failures, 4);
    let (_, trip) = trip_after(runtime(), 50, 3, |k| {
        (FrameStatus::Bad(ErrorKind::Checksum), healthy(k), OP)
    });
    assert_eq!(trip, Some((52, DampingReason::CrcStreak)));
    // No frame for 10 ticks is tolerated (state_timeout_s 0.02 s); the 11th trips.
    let (_, trip) = trip_after(runtime(), 50, 12, |_| (FrameStatus::NoFrame, healthy(49), OP));
    assert_eq!(trip, Some((60, DampingReason::StateTimeout)));
    // A frame whose counter does not advance is stale, not news.
    let (rt, trip) = trip_after(runtime(), 50, 12, |_| (FrameStatus::Fresh, healthy(49), OP));
    assert_eq!(trip, Some((60, DampingReason::StateTimeout)));
    assert!(rt.counters().stale_frames >= 10);
}

#[test]
fn non_finite_inputs_and_malformed_frames_trip_at_once() {
    let (_, trip) = trip_after(runtime(), 50, 1, |k| {
        (FrameStatus::Bad(ErrorKind::NonFinite), healthy(k), OP)
    });
    assert_eq!(trip, Some((50, DampingReason::NonFiniteInput)));
    let (_, trip) = trip_after(runtime(), 50, 1, |k| {
        (FrameStatus::Bad(ErrorKind::Malformed), healthy(k), OP)
    });
    assert_eq!(trip, Some((50, DampingReason::MalformedFrame)));
    let (_, trip) = trip_after(runtime(), 50, 1, |k| {
        let mut o = OP;
        o.velocity[1] = f32::NAN;
        (FrameStatus::Fresh, healthy(k), o)
    });
    assert_eq!(trip, Some((50, DampingReason::NonFiniteInput)));
}

/// Issue 31: an all-zero IMU frame (a simulator's first state before its IMU has data) is an
/// invalid IMU reading, named as such, not a tilt.
#[test]
fn an_all_zero_imu_quaternion_is_an_invalid_imu_not_a_tilt() {
    let (_, trip) = trip_after(runtime(), 50, 1, |k| {
        let mut s = healthy(k);
        s.imu.quaternion = [0.0; 4];
        (FrameStatus::Fresh, s, OP)
    });
    assert_eq!(trip, Some((50, DampingReason::InvalidImu)));
    assert_eq!(DampingReason::InvalidImu.to_string(), "invalid_imu");
}

#[test]
fn nan_policy_output_trips_and_targets_are_clamped_to_joint_ranges() {
    // The loader refuses NaN weights, but finite ones can still overflow: a first layer of 3e38
    // makes the hidden layer infinite and the action NaN.
    let mut s = spec();
    let bytes = std::fs::read(s.weights_path()).unwrap();
    let poisoned = overflow_first_tensor(&bytes);
    let dir = std::env::temp_dir().join(format!("g1fw-safety-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let w = dir.join("nan.safetensors");
    std::fs::write(&w, poisoned).unwrap();
    s.policy.weights = w;
    let rt = Runtime::new(Controller::new(s).unwrap());
    // The policy engages after the 0.5 s ramp (250 ticks) and first steps 10 ticks later.
    let (_, trip) = trip_after(rt, 250, 20, |k| (FrameStatus::Fresh, healthy(k), OP));
    assert_eq!(trip, Some((260, DampingReason::NonFiniteAction)));
    let _ = std::fs::remove_dir_all(&dir);

    // The seeded test MLP's targets exceed the ankle ranges at times: clamped and counted, no trip.
    let (rt, trip) = trip_after(runtime(), 500, 500, |k| (FrameStatus::Fresh, healthy(k), OP));
    assert_eq!(trip, None);
    let c = rt.controller();
    for (s, q) in c.target_q().iter().enumerate().take(29) {
        let (lo, hi) = control::robot::G1_JOINT_RANGE[s].unwrap();
        assert!(*q >= lo && *q <= hi, "slot {s}: {q} outside [{lo}, {hi}]");
    }
    eprintln!("clamped targets: {}", c.clamped_targets());
}

#[test]
fn estop_latches_until_an_explicit_reset() {
    let mut rt = runtime();
    let mut cmd = LowCommand::default();
    let estop = OperatorInput { estop: true, ..OP };
    let reset = OperatorInput { reset: true, ..OP };
    for k in 0..700 {
        let op = match k {
            600 => estop,
            650 => reset,
            _ => OP,
        };
        let s = step(&mut rt, k, FrameStatus::Fresh, &healthy(k), op, &mut cmd);
        match k {
            600 => assert_eq!(s.tripped, Some(DampingReason::EStop)),
            601..650 => assert!(matches!(s.mode, Mode::Damping(DampingReason::EStop)), "latched at {k}"),
            650 => assert!(s.reset && s.mode == Mode::Startup, "reset leaves damping"),
            _ => {}
        }
    }
    assert_eq!(rt.trip(), Some((600, DampingReason::EStop)));
}

/// Sets every value of the first F32 tensor (by offset) to 3e38.
fn overflow_first_tensor(bytes: &[u8]) -> Vec<u8> {
    let n = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let header: serde_json::Value = serde_json::from_slice(&bytes[8..8 + n]).unwrap();
    let (start, end) = header
        .as_object()
        .unwrap()
        .iter()
        .filter(|(k, v)| *k != "__metadata__" && v["dtype"] == "F32")
        .map(|(_, v)| {
            let o = &v["data_offsets"];
            (o[0].as_u64().unwrap() as usize, o[1].as_u64().unwrap() as usize)
        })
        .min()
        .unwrap();
    let mut out = bytes.to_vec();
    for at in (8 + n + start..8 + n + end).step_by(4) {
        out[at..at + 4].copy_from_slice(&3e38f32.to_le_bytes());
    }
    out
}

/// Issue 30's reproductions: values that reached the motors or the policy unchecked are refused,
/// naming the field.
#[test]
fn unsafe_damping_held_targets_commands_and_phase_are_refused() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../specs/stairs/g1_stairs_lstm.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    assert!(
        DeploySpec::from_toml(&text, &path).is_ok(),
        "the stair spec itself loads"
    );
    let refused = |from: &str, to: &str| -> String {
        assert!(text.contains(from), "the stair spec has no '{from}'");
        let t = text.replacen(from, to, 1);
        DeploySpec::from_toml(&t, &path)
            .map(|_| format!("accepted: {to}"))
            .unwrap_or_else(|e| e.to_string())
    };
    let e = refused("damping_kd = 5.0", "damping_kd = 1e6");
    assert!(e.contains("safety.damping_kd") && e.contains("100"), "{e}");
    // The waist held at 1 rad: waist roll's range is ±0.52 rad.
    let e = refused(
        "joints = [\"waist_yaw\", \"waist_roll\", \"waist_pitch\"]\nq = 0.0",
        "joints = [\"waist_yaw\", \"waist_roll\", \"waist_pitch\"]\nq = 1.0",
    );
    assert!(e.contains("held[0].q[1]") && e.contains("waist_roll"), "{e}");
    let e = refused("min = [-0.8, -0.5, -1.57]", "min = [-0.8, nan, -1.57]");
    assert!(e.contains("commands.min[1]"), "{e}");
    let e = refused("max = [0.8, 0.5, 1.57]", "max = [inf, 0.5, 1.57]");
    assert!(e.contains("commands.max[0]"), "{e}");
    for bad in ["nan", "-1e300", "inf"] {
        let e = refused("first_step_time_s = 0.02", &format!("first_step_time_s = {bad}"));
        assert!(e.contains("phase.first_step_time_s"), "{bad}: {e}");
    }
    let e = refused("period_s = 0.8", "period_s = inf");
    assert!(e.contains("phase.period_s"), "{e}");
}
