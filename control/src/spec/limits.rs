//! The bounds every safety and rate setting of a deploy spec must stay within, from the robot's
//! facts. A spec (or `--set`) may tighten a guard, never switch it off: each bound's loose side is
//! where the guard would stop guarding (a timeout of 1e9 s, a tilt limit past lying flat), its tight
//! side where the setting stops making sense (no damping at all, a rate no HAL runs).
//!
//! `docs/spec_limits.md` prints this table (a test keeps the two equal).
use super::{DeploySpec, MAX_KD};

/// One numeric setting's bounds, inclusive.
pub struct Bound {
    /// The spec's TOML key.
    pub field: &'static str,
    pub lo: f64,
    pub hi: f64,
    pub unit: &'static str,
    /// Why these numbers (the facts behind them).
    pub why: &'static str,
    /// The setting's value in a parsed spec (`None` when unset: the default applies).
    pub value: fn(&DeploySpec) -> Option<f64>,
}

impl Bound {
    /// Within the bounds, as the setting's own type holds them (an `f32` field's 1.57 is
    /// 1.5700000524 in `f64`).
    pub fn contains(&self, v: f64) -> bool {
        let slack = |b: f64| b.abs() * 1e-7;
        v.is_finite() && v >= self.lo - slack(self.lo) && v <= self.hi + slack(self.hi)
    }
}

/// The G1 sends a `LowState` every 2 ms (Unitree's examples write commands at 500 Hz).
const G1_STATE_PERIOD_S: f64 = 0.002;

pub const BOUNDS: &[Bound] = &[
    Bound {
        field: "safety.damping_kd",
        lo: 1.0,
        hi: MAX_KD as f64,
        unit: "N·m·s/rad",
        why: "deploy stacks damp with kp 0 and kd 3–8; below 1 a trip barely damps, above the cap of every kd it is a command of its own",
        value: |s| Some(s.safety.damping_kd as f64),
    },
    Bound {
        field: "safety.tilt_limit_rad",
        lo: 0.1,
        hi: 1.57,
        unit: "rad",
        why: "Unitree's `bad_orientation` trips at 1.0 rad, unitree_rl_gym at about 90°; past 90° the robot lies on the ground",
        value: |s| Some(s.safety.tilt_limit_rad as f64),
    },
    Bound {
        field: "safety.base_ang_speed_limit_rad_s",
        lo: 0.5,
        hi: 12.0,
        unit: "rad/s",
        why: "Unitree's `ang_vel_out_of_limit` trips at 6 rad/s per gyro axis; twice that is a fall in progress",
        value: |s| Some(s.safety.base_ang_speed_limit_rad_s as f64),
    },
    Bound {
        field: "safety.joint_speed_limit_rad_s",
        lo: 1.0,
        hi: 37.0,
        unit: "rad/s",
        why: "the motors' own limits are 20–37 rad/s (a spec may only be stricter, per joint too); below 1 rad/s a joint cannot move",
        value: |s| s.safety.joint_speed_limit_rad_s.map(f64::from),
    },
    Bound {
        field: "safety.motor_winding_limit_c",
        lo: 40.0,
        hi: 120.0,
        unit: "°C",
        why: "Unitree's limit for the winding is 120 °C; below 40 °C a motor trips at room temperature under load",
        value: |s| Some(s.safety.motor_winding_limit_c as f64),
    },
    Bound {
        field: "safety.motor_casing_limit_c",
        lo: 40.0,
        hi: 85.0,
        unit: "°C",
        why: "Unitree's limit for the casing is 85 °C",
        value: |s| Some(s.safety.motor_casing_limit_c as f64),
    },
    Bound {
        field: "safety.state_timeout_s",
        lo: G1_STATE_PERIOD_S,
        hi: 0.1,
        unit: "s",
        why: "the G1 reports every 2 ms; a walking robot without feedback for 0.1 s (50 states) is falling (a loose cable sends a step to the motors)",
        value: |s| Some(s.safety.state_timeout_s),
    },
    Bound {
        field: "safety.crc_failure_streak",
        lo: 1.0,
        hi: 25.0,
        unit: "frames",
        why: "25 damaged states in a row are 50 ms without a usable one",
        value: |s| Some(s.safety.crc_failure_streak as f64),
    },
    Bound {
        field: "safety.frozen_state_frames",
        lo: 2.0,
        hi: 50.0,
        unit: "frames",
        why: "real encoders and current sensors never repeat a reading bit for bit for 50 fresh states (0.1 s)",
        value: |s| Some(s.safety.frozen_state_frames as f64),
    },
    Bound {
        field: "safety.joint_range_margin_rad",
        lo: 0.0,
        hi: 0.2,
        unit: "rad",
        why: "the ankle roll's whole range is ±0.26 rad: a wider margin leaves it no range",
        value: |s| Some(s.safety.joint_range_margin_rad as f64),
    },
    Bound {
        field: "rates.control_hz",
        lo: 50.0,
        hi: 1000.0,
        unit: "Hz",
        why: "the G1 runs at 500 Hz (its DDS and the CAN HIL up to 1 kHz); faster floods `rt/lowcmd`, slower cannot hold a PD loop",
        value: |s| Some(s.rates.control_hz as f64),
    },
    Bound {
        field: "rates.policy_hz",
        lo: 10.0,
        hi: 200.0,
        unit: "Hz",
        why: "walking policies run at 50 Hz (IsaacLab, unitree_rl_lab, mjlab); the network's budget stops at 200 Hz",
        value: |s| Some(s.rates.policy_hz as f64),
    },
    Bound {
        field: "rates.perception_hz",
        lo: 1.0,
        hi: 50.0,
        unit: "Hz",
        why: "the MID-360 sends frames at 5–50 Hz (10 by default)",
        value: |s| Some(s.rates.perception_hz as f64),
    },
];

/// The first setting of `spec` outside its bounds: `(field, message)`.
pub fn first_violation(spec: &DeploySpec) -> Option<(&'static str, String)> {
    BOUNDS.iter().find_map(|b| {
        let v = (b.value)(spec)?;
        (!b.contains(v)).then(|| {
            (
                b.field,
                format!(
                    "{v} {} is outside {} to {} {}: {} (a spec may tighten a guard, never switch it off; docs/spec_limits.md)",
                    b.unit, b.lo, b.hi, b.unit, b.why
                ),
            )
        })
    })
}

/// The bounds as the Markdown table `docs/spec_limits.md` holds.
pub fn markdown_table() -> String {
    let mut s = String::from("| setting | lowest | highest | unit | why |\n|---|---|---|---|---|\n");
    for b in BOUNDS {
        s += &format!("| `{}` | {} | {} | {} | {} |\n", b.field, b.lo, b.hi, b.unit, b.why);
    }
    s
}
