//! The command envelope (`control::envelope`) through the runtime: whatever the spec, the states
//! and the faults, every outgoing LowCmd is inside it; a command that is not (a field whose own
//! validation was forgotten) latches damping and names the field and its source.
// Test inputs come from std's math on the host; this never runs on the robot.
#![allow(clippy::disallowed_methods)]
mod common;
use common::{healthy, tick};
use std::path::Path;

use control::controller::{Controller, DampingReason, Mode};
use control::envelope::{g1_motor_effort_limit, CommandField, CommandSource, KD_MAX, KP_MAX};
use control::operator::OperatorInput;
use control::robot::G1_JOINT_RANGE;
use control::runtime::Runtime;
use control::spec::{DeploySpec, Scale};
use control::supervisor::FrameStatus;
use hal::{ErrorKind, LowCommand, LowState, XorShift64, MOTOR_MODE_ENABLED, NUM_MOTORS};
use proptest::prelude::*;

fn spec() -> DeploySpec {
    DeploySpec::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("../specs/test/rl_lab_style.toml")).unwrap()
}

/// The envelope, written out independently of `control::envelope`: `Err` names the first breach.
fn inside(cmd: &LowCommand, margin: f32) -> Result<(), String> {
    for (s, m) in cmd.motors.iter().enumerate() {
        let name = hal::G1_MOTOR_NAMES[s];
        if m.mode != MOTOR_MODE_ENABLED {
            if *m != hal::MotorCommand::default() {
                return Err(format!("{name}: disabled but commanded {m:?}"));
            }
            continue;
        }
        let fields = [m.q, m.dq, m.tau, m.kp, m.kd];
        if fields.iter().any(|v| !v.is_finite()) {
            return Err(format!("{name}: non-finite {m:?}"));
        }
        if !(0.0..=KP_MAX).contains(&m.kp) || !(0.0..=KD_MAX).contains(&m.kd) {
            return Err(format!("{name}: gains kp {} kd {}", m.kp, m.kd));
        }
        let effort = g1_motor_effort_limit(name).unwrap_or(0.0);
        let speed = hal::g1_motor_velocity_limit(name).unwrap_or(0.0);
        if m.tau.abs() > effort || m.dq.abs() > speed {
            return Err(format!("{name}: tau {} dq {}", m.tau, m.dq));
        }
        if let (true, Some((lo, hi))) = (m.kp > 0.0, G1_JOINT_RANGE[s]) {
            if m.q < lo + margin - 1e-6 || m.q > hi - margin + 1e-6 {
                return Err(format!("{name}: q {} outside [{}, {}]", m.q, lo + margin, hi - margin));
            }
        }
    }
    Ok(())
}

/// A state for tick `k`, upright and slowly moving, with the fault `fault` (0: none) applied.
fn state(k: u64, fault: u8, rng: &mut XorShift64) -> (FrameStatus, LowState, OperatorInput) {
    let mut s = healthy(k);
    let mut op = OperatorInput {
        velocity: [0.4, 0.0, 0.1],
        ..Default::default()
    };
    let mut frame = FrameStatus::Fresh;
    let slot = rng.below(NUM_MOTORS);
    match fault {
        1 => s.motors[slot].q = f32::NAN,
        2 => s.motors[slot].q = 1e30,
        3 => s.motors[slot].dq = -1e6,
        4 => s.imu.quaternion = [0.0, 1.0, 0.0, 0.0],
        5 => s.imu.gyroscope = [f32::INFINITY, 0.0, 0.0],
        6 => frame = FrameStatus::NoFrame,
        7 => frame = FrameStatus::Bad(ErrorKind::Checksum),
        8 => op.velocity = [1e30, -1e30, f32::NAN],
        9 => op.estop = true,
        10 => op.reset = true,
        11 => s.motors[slot].q = G1_JOINT_RANGE[slot].map_or(9.0, |(_, hi)| hi + 0.5),
        _ => {}
    }
    (frame, s, op)
}

/// Runs `ticks` ticks of faults drawn from `seed`; checks every command against [`inside`].
fn run(spec: DeploySpec, seed: u64, ticks: u64, fault_rate: f32) -> Runtime {
    let margin = spec.safety.joint_range_margin_rad;
    let mut rt = Runtime::new(Controller::new(spec).unwrap());
    let mut rng = XorShift64(seed | 1);
    let mut cmd = LowCommand::default();
    for k in 0..ticks {
        let fault = if rng.unit() < fault_rate {
            1 + rng.below(11) as u8
        } else {
            0
        };
        let (f, st, op) = state(k, fault, &mut rng);
        rt.tick(tick(k), f, &st, op, &mut cmd, |c| {
            inside(c, margin).map_err(|e| format!("tick {k} (fault {fault}): {e}"))
        })
        .1
        .unwrap();
    }
    rt
}

#[test]
fn damping_kd_forgotten_by_validation_is_clamped_counted_and_named() {
    // The reproduction, with the field's own check bypassed: damping kd 1e6 after an
    // IMU NaN. The damping command goes out with kd 100, and every clamp is counted.
    let mut s = spec();
    s.safety.damping_kd = 1e6;
    let mut rt = Runtime::new(Controller::new(s).unwrap());
    let mut rng = XorShift64(1 | 1);
    let mut cmd = LowCommand::default();
    for k in 0..50 {
        let (f, mut st, op) = state(k, 0, &mut rng);
        if k >= 20 {
            st.imu.gyroscope[0] = f32::NAN;
        }
        rt.tick(tick(k), f, &st, op, &mut cmd, |c| inside(c, 0.0)).1.unwrap();
    }
    assert_eq!(rt.mode(), Mode::Damping(DampingReason::NonFiniteInput));
    let enabled = cmd.motors.iter().filter(|m| m.mode == MOTOR_MODE_ENABLED).count();
    assert!(enabled > 0);
    assert!(cmd
        .motors
        .iter()
        .filter(|m| m.mode == MOTOR_MODE_ENABLED)
        .all(|m| m.kd == KD_MAX && m.kp == 0.0));
    let counts = rt.controller().envelope_counts();
    assert_eq!(
        counts.violations,
        30 * enabled as u64,
        "every damping tick's kd on every motor"
    );
    let last = counts.last.unwrap();
    assert_eq!(
        (last.field, last.source, last.value),
        (CommandField::Kd, CommandSource::Damping, 1e6)
    );
}

#[test]
fn a_policy_gain_past_the_envelope_latches_damping_on_the_first_command() {
    let mut s = spec();
    s.policy.kp[0] = 5000.0;
    let slot = s.policy.joint_ids_map[0];
    let mut rt = Runtime::new(Controller::new(s).unwrap());
    let mut rng = XorShift64(2 | 1);
    let mut cmd = LowCommand::default();
    let (f, st, op) = state(0, 0, &mut rng);
    let (summary, sent) = rt.tick(tick(0), f, &st, op, &mut cmd, |c| inside(c, 0.0));
    sent.unwrap();
    let reason = DampingReason::CommandEnvelope { slot: slot as u8 };
    assert_eq!(summary.tripped, Some(reason));
    assert_eq!(rt.trip(), Some((0, reason)));
    let v = summary.envelope_violation.unwrap();
    // The ramp uses the startup gains, which are the policy's when the spec sets none.
    assert_eq!(
        (v.field, v.source, v.value),
        (CommandField::Kp, CommandSource::Startup, 5000.0)
    );
    assert!(
        cmd.motors[slot].kp == 0.0,
        "this tick's command is already the damping command"
    );
    assert_eq!(
        reason.to_string(),
        format!("command_envelope ({})", hal::G1_MOTOR_NAMES[slot])
    );
}

#[test]
fn a_held_target_outside_the_joint_range_is_clamped_without_a_trip() {
    // 29-dof spec with its waist held at q = 6.0 (the reproduction; check-spec now refuses
    // it, the envelope clamps it regardless).
    let mut s = spec();
    if s.held.is_empty() {
        s.held.push(control::spec::HeldGroup {
            joints: vec!["waist_roll".into()],
            q: Scale::Scalar(6.0),
            kp: Scale::Scalar(200.0),
            kd: Scale::Scalar(5.0),
        });
    } else {
        s.held[0].q = Scale::Scalar(6.0);
    }
    let rt = run(s, 3, 600, 0.0);
    assert_eq!(rt.trip(), None);
    assert!(rt.controller().envelope_counts().range_clamps > 0);
    assert_eq!(rt.controller().envelope_counts().violations, 0);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    /// Specs that `validate` accepts (gains, damping, margins, poses, scales drawn at random), a
    /// few hundred ticks with faults: every LowCmd is inside the envelope.
    #[test]
    fn every_command_of_every_valid_spec_is_inside_the_envelope(
        kp_scale in 0.0f32..1.5,
        kd_scale in 0.0f32..3.0,
        damping_kd in 0.0f32..105.0,
        margin in 0.0f32..0.12,
        pose_offset in -0.4f32..0.4,
        action_scale in 0.0f32..5.0,
        ramp_s in 0.0f64..0.2,
        seed in any::<u64>(),
        fault_rate in 0.0f32..0.2,
    ) {
        let mut s = spec();
        s.policy.kp.iter_mut().for_each(|k| *k *= kp_scale);
        s.policy.kd.iter_mut().for_each(|k| *k *= kd_scale);
        s.policy.default_pose.iter_mut().step_by(3).for_each(|q| *q += pose_offset);
        s.policy.action_scale = Scale::Scalar(action_scale);
        s.safety.damping_kd = damping_kd;
        s.safety.joint_range_margin_rad = margin;
        s.startup.ramp_s = ramp_s;
        s.startup.hold_s = ramp_s;
        prop_assume!(s.validate().is_ok());
        run(s, seed, 400, fault_rate);
    }

    /// The same with the spec's validation skipped altogether (a field whose check was forgotten):
    /// still every LowCmd is inside.
    #[test]
    fn every_command_is_inside_even_when_validation_is_skipped(
        kp in prop_oneof![Just(f32::NAN), Just(f32::INFINITY), -1e6f32..1e6],
        kd in prop_oneof![Just(f32::NAN), -1e3f32..1e3],
        damping_kd in prop_oneof![Just(f32::NAN), -1e3f32..1e6],
        pose in prop_oneof![Just(f32::NAN), -50.0f32..50.0],
        seed in any::<u64>(),
    ) {
        let mut s = spec();
        s.policy.kp[1] = kp;
        s.policy.kd[2] = kd;
        s.policy.default_pose[4] = pose;
        s.safety.damping_kd = damping_kd;
        s.startup.ramp_s = 0.05;
        s.startup.hold_s = 0.05;
        run(s, seed, 200, 0.05);
    }
}
