//! The last line before the motors: every outgoing `LowCmd` passes [`CommandEnvelope::enforce`],
//! whatever produced it (start-up ramp, policy, held joints, damping, an imported spec).
//!
//! Validation of each spec field is a list, and a list can miss a field. This check cannot: it looks
//! only at the command. Per enabled motor:
//! - `q` inside the joint range less the spec's margin (only where `kp > 0`: with no stiffness the
//!   target does nothing). Outside, it is clamped and counted as a *range clamp*: the start-up ramp
//!   from a joint resting at its stop does this legitimately, so it does not latch anything.
//! - `kp` in `0..=KP_MAX`, `kd` in `0..=KD_MAX`, `|tau|` ≤ the motor's effort limit, `|dq|` ≤ its
//!   velocity limit, and every field finite. Anything else is a *violation*: clamped here (a
//!   non-finite value becomes 0, and a non-finite `q` also takes the position gain to 0), counted,
//!   and the controller latches damping (`DampingReason::CommandEnvelope`) and sends that instead.
//!
//! Disabled motors (mode 0) must carry an all-zero command; anything else there is a violation and
//! is zeroed.
use hal::{LowCommand, MotorCommand, NUM_MOTORS};

use crate::spec::DeploySpec;

/// Highest position gain any command may carry, N·m/rad (the G1's stiffest policies use ≤ 200).
pub const KP_MAX: f32 = 1000.0;
/// Highest velocity gain any command may carry, N·m·s/rad (the spec's own bound for every gain).
pub const KD_MAX: f32 = 100.0;

pub use hal::g1_motor_effort_limit;

/// What produced a command (logged with each violation).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CommandSource {
    /// The start-up ramp and hold.
    Startup,
    /// A policy joint while the policy runs.
    Policy,
    /// A joint the spec holds (`[[held]]`) while the policy runs.
    Held,
    /// The latched damping command.
    Damping,
}

impl CommandSource {
    pub fn name(&self) -> &'static str {
        match self {
            CommandSource::Startup => "startup",
            CommandSource::Policy => "policy",
            CommandSource::Held => "held",
            CommandSource::Damping => "damping",
        }
    }
}

/// Which field of a motor command broke the envelope.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CommandField {
    Q,
    Dq,
    Tau,
    Kp,
    Kd,
    /// A disabled motor with a non-zero command.
    Disabled,
}

impl CommandField {
    pub fn name(&self) -> &'static str {
        match self {
            CommandField::Q => "q",
            CommandField::Dq => "dq",
            CommandField::Tau => "tau",
            CommandField::Kp => "kp",
            CommandField::Kd => "kd",
            CommandField::Disabled => "disabled_motor",
        }
    }
}

/// One violation: the slot, the field, the value as produced, and who produced it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Violation {
    pub slot: u8,
    pub field: CommandField,
    pub value: f32,
    pub source: CommandSource,
}

impl std::fmt::Display for Violation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} {} = {} from the {} command",
            hal::G1_MOTOR_NAMES[self.slot as usize],
            self.field.name(),
            self.value,
            self.source.name()
        )
    }
}

/// What one [`CommandEnvelope::enforce`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct EnvelopeVerdict {
    /// Targets clamped into the joint range (not a fault).
    pub range_clamps: u32,
    /// Fields that broke the envelope (clamped; the controller latches damping).
    pub violations: u32,
    /// The first violation (by slot).
    pub first: Option<Violation>,
}

/// The limits every command is held to.
#[derive(Clone, Debug)]
pub struct CommandEnvelope {
    q_min: [f32; NUM_MOTORS],
    q_max: [f32; NUM_MOTORS],
    tau_max: [f32; NUM_MOTORS],
    dq_max: [f32; NUM_MOTORS],
}

impl CommandEnvelope {
    /// The G1's joint ranges less `spec.safety.joint_range_margin_rad`, its motors' effort and
    /// velocity limits.
    pub fn from_spec(spec: &DeploySpec) -> Self {
        Self::g1(spec.safety.joint_range_margin_rad)
    }

    /// The G1's envelope with the joint ranges shrunk by `margin`.
    pub fn g1(margin: f32) -> Self {
        let (q_min, q_max) = target_limits(margin);
        let limit = |f: fn(&str) -> Option<f32>| -> [f32; NUM_MOTORS] {
            std::array::from_fn(|s| f(hal::G1_MOTOR_NAMES[s]).unwrap_or(0.0))
        };
        Self {
            q_min,
            q_max,
            tau_max: limit(g1_motor_effort_limit),
            dq_max: limit(hal::g1_motor_velocity_limit),
        }
    }

    /// Holds `cmd` to the envelope in place. `source` says what produced slot `s`'s command.
    pub fn enforce(&self, cmd: &mut LowCommand, source: impl Fn(usize) -> CommandSource) -> EnvelopeVerdict {
        let mut v = EnvelopeVerdict::default();
        for s in 0..NUM_MOTORS {
            let m = &mut cmd.motors[s];
            let mut flag = |field: CommandField, value: f32| {
                v.violations += 1;
                if v.first.is_none() {
                    v.first = Some(Violation {
                        slot: s as u8,
                        field,
                        value,
                        source: source(s),
                    });
                }
            };
            if m.mode != hal::MOTOR_MODE_ENABLED {
                if *m != MotorCommand::default() {
                    flag(CommandField::Disabled, m.mode as f32);
                    *m = MotorCommand::default();
                }
                continue;
            }
            // Slots with no G1 motor behind them have effort and velocity limits of 0.
            bound(&mut m.kp, 0.0, KP_MAX, CommandField::Kp, &mut flag);
            bound(&mut m.kd, 0.0, KD_MAX, CommandField::Kd, &mut flag);
            bound(
                &mut m.tau,
                -self.tau_max[s],
                self.tau_max[s],
                CommandField::Tau,
                &mut flag,
            );
            bound(&mut m.dq, -self.dq_max[s], self.dq_max[s], CommandField::Dq, &mut flag);
            if !m.q.is_finite() {
                flag(CommandField::Q, m.q);
                m.q = 0.0;
                m.kp = 0.0;
            } else if m.kp > 0.0 && (m.q < self.q_min[s] || m.q > self.q_max[s]) {
                m.q = m.q.clamp(self.q_min[s], self.q_max[s]);
                v.range_clamps += 1;
            }
        }
        v
    }
}

/// cargo-fuzz harness (`fuzz/fuzz_targets/command_envelope.rs`, and the stable smoke test): any
/// bytes as a margin and a LowCmd (35 motors of mode + five `f32`), through the envelope. Afterwards
/// every enabled motor's fields are finite and inside the limits, disabled motors are all zero, and
/// a second pass finds nothing to do.
pub fn fuzz_command_envelope(data: &[u8]) {
    let Some((&m, rest)) = data.split_first() else { return };
    let margin = m as f32 * 1e-3;
    let env = CommandEnvelope::g1(margin);
    let mut cmd = LowCommand::default();
    let f = |i: usize| -> f32 {
        rest.get(i..i + 4)
            .map_or(0.0, |b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    };
    for (s, motor) in cmd.motors.iter_mut().enumerate() {
        let o = s * 21;
        let Some(&mode) = rest.get(o) else { break };
        *motor = MotorCommand {
            mode: if mode & 0x80 == 0 {
                hal::MOTOR_MODE_ENABLED
            } else {
                mode
            },
            q: f(o + 1),
            dq: f(o + 5),
            tau: f(o + 9),
            kp: f(o + 13),
            kd: f(o + 17),
            reserve: 0,
        };
    }
    let sources = [
        CommandSource::Startup,
        CommandSource::Policy,
        CommandSource::Held,
        CommandSource::Damping,
    ];
    let first = env.enforce(&mut cmd, |s| sources[s % 4]);
    if let Some(v) = first.first {
        assert!(v.to_string().contains(v.field.name()));
    }
    for (s, m) in cmd.motors.iter().enumerate() {
        if m.mode != hal::MOTOR_MODE_ENABLED {
            assert_eq!(*m, MotorCommand::default());
            continue;
        }
        assert!([m.q, m.dq, m.tau, m.kp, m.kd].iter().all(|v| v.is_finite()), "{m:?}");
        assert!(
            (0.0..=KP_MAX).contains(&m.kp) && (0.0..=KD_MAX).contains(&m.kd),
            "{m:?}"
        );
        assert!(m.tau.abs() <= env.tau_max[s] && m.dq.abs() <= env.dq_max[s], "{m:?}");
        assert!(m.kp == 0.0 || (env.q_min[s]..=env.q_max[s]).contains(&m.q), "{m:?}");
    }
    let again = env.enforce(&mut cmd, |s| sources[s % 4]);
    assert_eq!(again, EnvelopeVerdict::default(), "a second pass changed the command");
}

/// Clamps `x` into `lo..=hi` (a non-finite value becomes 0, or the nearest bound if 0 is outside),
/// flagging any change.
fn bound(x: &mut f32, lo: f32, hi: f32, field: CommandField, flag: &mut impl FnMut(CommandField, f32)) {
    if x.is_finite() && *x >= lo && *x <= hi {
        return;
    }
    flag(field, *x);
    *x = if x.is_finite() {
        x.clamp(lo, hi)
    } else {
        0.0f32.clamp(lo, hi)
    };
}

/// Position-target limits per slot: the G1's joint range shrunk by `margin` (unbounded for slots
/// with no joint). The policy's action rule and the envelope use this one definition.
pub fn target_limits(margin: f32) -> ([f32; NUM_MOTORS], [f32; NUM_MOTORS]) {
    let (mut q_min, mut q_max) = ([f32::NEG_INFINITY; NUM_MOTORS], [f32::INFINITY; NUM_MOTORS]);
    for s in 0..NUM_MOTORS {
        if let Some((lo, hi)) = crate::robot::G1_JOINT_RANGE[s] {
            (q_min[s], q_max[s]) = (lo + margin, hi - margin);
        }
    }
    (q_min, q_max)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn envelope() -> CommandEnvelope {
        let (q_min, q_max) = target_limits(0.02);
        CommandEnvelope {
            q_min,
            q_max,
            tau_max: std::array::from_fn(|s| g1_motor_effort_limit(hal::G1_MOTOR_NAMES[s]).unwrap_or(0.0)),
            dq_max: std::array::from_fn(|s| hal::g1_motor_velocity_limit(hal::G1_MOTOR_NAMES[s]).unwrap_or(0.0)),
        }
    }

    fn enabled(q: f32, kp: f32, kd: f32) -> MotorCommand {
        MotorCommand {
            mode: hal::MOTOR_MODE_ENABLED,
            q,
            dq: 0.0,
            tau: 0.0,
            kp,
            kd,
            reserve: 0,
        }
    }

    #[test]
    fn a_command_inside_passes_unchanged() {
        let mut cmd = LowCommand::default();
        cmd.motors[3] = enabled(0.3, 150.0, 4.0); // left knee
        let before = cmd;
        let v = envelope().enforce(&mut cmd, |_| CommandSource::Policy);
        assert_eq!(v, EnvelopeVerdict::default());
        assert_eq!(cmd, before);
    }

    #[test]
    fn a_target_past_the_stop_is_clamped_and_counted_but_is_no_violation() {
        let mut cmd = LowCommand::default();
        cmd.motors[3] = enabled(5.0, 150.0, 4.0);
        let v = envelope().enforce(&mut cmd, |_| CommandSource::Startup);
        assert_eq!((v.range_clamps, v.violations), (1, 0));
        assert!((cmd.motors[3].q - (2.8798 - 0.02)).abs() < 1e-6);
        // With kp = 0 (damping) the target does nothing and is left alone.
        cmd.motors[3] = enabled(5.0, 0.0, 4.0);
        assert_eq!(envelope().enforce(&mut cmd, |_| CommandSource::Damping).range_clamps, 0);
    }

    #[test]
    fn gains_torque_and_nan_beyond_the_envelope_are_violations_named_with_their_source() {
        let mut cmd = LowCommand::default();
        cmd.motors[0] = enabled(0.0, 150.0, 1e6);
        cmd.motors[1] = enabled(f32::NAN, 150.0, 2.0);
        cmd.motors[2] = MotorCommand {
            tau: 500.0,
            ..enabled(0.0, f32::INFINITY, 2.0)
        };
        cmd.motors[30] = MotorCommand {
            kp: 5.0,
            ..MotorCommand::default()
        };
        let v = envelope().enforce(&mut cmd, |s| {
            if s == 0 {
                CommandSource::Damping
            } else {
                CommandSource::Held
            }
        });
        assert_eq!(v.violations, 5);
        let first = v.first.unwrap();
        assert_eq!(
            (first.slot, first.field, first.source),
            (0, CommandField::Kd, CommandSource::Damping)
        );
        assert_eq!(
            first.to_string(),
            "left_hip_pitch kd = 1000000 from the damping command"
        );
        assert_eq!(cmd.motors[0].kd, KD_MAX);
        assert_eq!((cmd.motors[1].q, cmd.motors[1].kp), (0.0, 0.0));
        assert_eq!((cmd.motors[2].kp, cmd.motors[2].tau), (0.0, 88.0));
        assert_eq!(cmd.motors[30], MotorCommand::default());
    }
}
