//! Safety supervisor: decides, from what the HAL delivered this tick, whether the robot must go to
//! the latched damping state, and why.
//!
//! It sees every frame status (fresh, none, bad), so transport faults (drops, delays, CRC streaks,
//! timeouts) and sensor faults (NaN, frozen joints, over-speed, over-temperature, tilt) are judged in
//! one place, in a fixed order, from tick indices only (never wall-clock time). Checks of values run
//! on accepted frames; the staleness check runs every tick. Fixed size, no allocation.
use hal::{ErrorKind, LowState, NUM_MOTORS};

use crate::spec::DeploySpec;

/// Why the robot is in damping. `slot` fields name the motor (SDK order).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DampingReason {
    /// Tilt from upright over the limit (fallen or falling).
    Tilt,
    JointSpeed {
        slot: u8,
    },
    BaseAngularSpeed,
    MotorTemperature {
        slot: u8,
    },
    /// No valid, newer LowState for longer than `safety.state_timeout_s`.
    StateTimeout,
    /// `safety.crc_failure_streak` consecutive frames failed their CRC.
    CrcStreak,
    /// A frame that is not a LowState (wrong length or type).
    MalformedFrame,
    /// NaN/Inf in a sensor value or operator command.
    NonFiniteInput,
    NonFiniteObservation,
    NonFiniteAction,
    /// A policy joint's state stopped changing (stuck encoder or motor not answering).
    FrozenJoint {
        slot: u8,
    },
    /// The HAL's link failed (disconnect, I/O error).
    HalFault,
    /// A motor stopped answering (the HAL flags it with `hal::MOTOR_STATE_NO_REPLY`).
    MotorSilent {
        slot: u8,
    },
    /// Operator emergency stop.
    EStop,
    /// Requested by code (tests, shutdown).
    Requested,
    /// The IMU's quaternion is not a rotation (|q| far from 1; all zeros: the IMU has sent nothing
    /// yet, as a simulator's first frame may), so the tilt cannot be judged.
    InvalidImu,
    /// An outgoing command broke the command envelope (`crate::envelope`) in this motor's slot.
    CommandEnvelope {
        slot: u8,
    },
}

impl DampingReason {
    /// Stable short name for logs.
    pub fn name(&self) -> &'static str {
        match self {
            DampingReason::Tilt => "tilt",
            DampingReason::JointSpeed { .. } => "joint_speed",
            DampingReason::BaseAngularSpeed => "base_angular_speed",
            DampingReason::MotorTemperature { .. } => "motor_temperature",
            DampingReason::StateTimeout => "state_timeout",
            DampingReason::CrcStreak => "crc_streak",
            DampingReason::MalformedFrame => "malformed_frame",
            DampingReason::NonFiniteInput => "non_finite_input",
            DampingReason::NonFiniteObservation => "non_finite_observation",
            DampingReason::NonFiniteAction => "non_finite_action",
            DampingReason::FrozenJoint { .. } => "frozen_joint",
            DampingReason::HalFault => "hal_fault",
            DampingReason::MotorSilent { .. } => "motor_silent",
            DampingReason::EStop => "estop",
            DampingReason::Requested => "requested",
            DampingReason::CommandEnvelope { .. } => "command_envelope",
            DampingReason::InvalidImu => "invalid_imu",
        }
    }

    /// The motor slot the reason names, if any.
    pub fn slot(&self) -> Option<u8> {
        match *self {
            DampingReason::JointSpeed { slot }
            | DampingReason::MotorTemperature { slot }
            | DampingReason::FrozenJoint { slot }
            | DampingReason::MotorSilent { slot }
            | DampingReason::CommandEnvelope { slot } => Some(slot),
            _ => None,
        }
    }

    /// Stable numeric code for compact logs (0 = none).
    pub fn code(&self) -> u8 {
        match self {
            DampingReason::Tilt => 1,
            DampingReason::JointSpeed { .. } => 2,
            DampingReason::BaseAngularSpeed => 3,
            DampingReason::MotorTemperature { .. } => 4,
            DampingReason::StateTimeout => 5,
            DampingReason::CrcStreak => 6,
            DampingReason::MalformedFrame => 7,
            DampingReason::NonFiniteInput => 8,
            DampingReason::NonFiniteObservation => 9,
            DampingReason::NonFiniteAction => 10,
            DampingReason::FrozenJoint { .. } => 11,
            DampingReason::HalFault => 12,
            DampingReason::EStop => 13,
            DampingReason::Requested => 14,
            DampingReason::MotorSilent { .. } => 15,
            DampingReason::CommandEnvelope { .. } => 16,
            DampingReason::InvalidImu => 17,
        }
    }
}

impl std::fmt::Display for DampingReason {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.slot() {
            Some(s) => write!(f, "{} ({})", self.name(), hal::G1_MOTOR_NAMES[s as usize]),
            None => f.write_str(self.name()),
        }
    }
}

/// What the HAL delivered for the LowState on this tick.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrameStatus {
    /// A new frame decoded.
    Fresh,
    /// Nothing arrived this tick.
    NoFrame,
    /// A frame arrived but was rejected.
    Bad(ErrorKind),
}

impl FrameStatus {
    pub fn code(&self) -> u8 {
        match self {
            FrameStatus::Fresh => 0,
            FrameStatus::NoFrame => 1,
            FrameStatus::Bad(ErrorKind::Disconnected) => 2,
            FrameStatus::Bad(ErrorKind::Timeout) => 3,
            FrameStatus::Bad(ErrorKind::Malformed) => 4,
            FrameStatus::Bad(ErrorKind::Checksum) => 5,
            FrameStatus::Bad(ErrorKind::NonFinite) => 6,
            FrameStatus::Bad(ErrorKind::Other) => 7,
        }
    }
    pub fn from_code(c: u8) -> Option<Self> {
        Some(match c {
            0 => FrameStatus::Fresh,
            1 => FrameStatus::NoFrame,
            2 => FrameStatus::Bad(ErrorKind::Disconnected),
            3 => FrameStatus::Bad(ErrorKind::Timeout),
            4 => FrameStatus::Bad(ErrorKind::Malformed),
            5 => FrameStatus::Bad(ErrorKind::Checksum),
            6 => FrameStatus::Bad(ErrorKind::NonFinite),
            7 => FrameStatus::Bad(ErrorKind::Other),
            _ => return None,
        })
    }
}

/// The limits a policy's motion must stay inside, resolved once from a spec's `[safety]`: what the
/// supervisor trips on, and what the trainer (`g1-train ppo`) ends an episode on and penalises near.
/// One type for both, so a policy is trained against exactly the walls it is deployed with.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MotionLimits {
    /// Tilt from upright, rad.
    pub tilt_rad: f32,
    /// Per slot: the motor's velocity limit, or the spec's stricter one, rad/s (∞ for slots that
    /// name no motor).
    pub joint_speed_rad_s: [f32; NUM_MOTORS],
    /// Base angular speed on each gyro axis, rad/s.
    pub base_ang_speed_rad_s: f32,
}

impl MotionLimits {
    pub fn from_spec(spec: &DeploySpec) -> Self {
        let s = &spec.safety;
        let joint_speed_rad_s = std::array::from_fn(|slot| {
            let name = hal::G1_MOTOR_NAMES[slot];
            let mut v = hal::g1_motor_velocity_limit(name).unwrap_or(f32::INFINITY);
            if let Some(all) = s.joint_speed_limit_rad_s {
                v = v.min(all);
            }
            if let Some(&one) = s.joint_speed_limits_rad_s.get(name) {
                v = v.min(one);
            }
            v
        });
        Self {
            tilt_rad: s.tilt_limit_rad,
            joint_speed_rad_s,
            base_ang_speed_rad_s: s.base_ang_speed_limit_rad_s,
        }
    }

    /// Whether a base whose up axis has vertical component `up` (= −projected gravity z) is tilted
    /// past the limit.
    pub fn tilted(&self, up: f32) -> bool {
        up < libm::cosf(self.tilt_rad)
    }

    pub fn joint_too_fast(&self, slot: usize, dq: f32) -> bool {
        dq.abs() > self.joint_speed_rad_s[slot]
    }

    /// Any gyro axis over the limit (per axis, as Unitree's `ang_vel_out_of_limit`, not the norm).
    pub fn base_spinning(&self, gyro: [f32; 3]) -> bool {
        gyro.iter().any(|w| w.abs() > self.base_ang_speed_rad_s)
    }
}

/// Counters the supervisor keeps (logged every tick).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SafetyCounters {
    pub crc_failures: u64,
    pub crc_streak: u32,
    pub missing_frames: u64,
    /// Frames whose tick counter did not advance (duplicated or delayed).
    pub stale_frames: u64,
    pub malformed_frames: u64,
    /// Ticks since the newest accepted frame.
    pub state_age_ticks: u64,
}

pub struct Supervisor {
    /// Limits, resolved once.
    limits: MotionLimits,
    winding_limit: i16,
    casing_limit: i16,
    timeout_ticks: u64,
    crc_streak_limit: u32,
    frozen_frames: u32,
    /// Slots whose values are checked (driven or held) and slots checked for freezing (policy joints).
    supervised: [bool; NUM_MOTORS],
    frozen_watch: [bool; NUM_MOTORS],
    frozen_last: [[u32; 3]; NUM_MOTORS],
    frozen_count: [u32; NUM_MOTORS],
    last_accepted_tick: Option<u64>,
    last_frame_counter: Option<u32>,
    counters: SafetyCounters,
    /// Judge the robot's motion (tilt, base angular speed, joint speed, frozen joints); off while
    /// the operator keeps the robot passive ([`Supervisor::set_motion_checks`]).
    motion_checks: bool,
}

impl Supervisor {
    /// The motion limits it trips on (the trainer ends episodes on the same, from the same spec).
    pub fn limits(&self) -> &MotionLimits {
        &self.limits
    }

    pub fn new(spec: &DeploySpec, supervised: [bool; NUM_MOTORS]) -> Self {
        let s = &spec.safety;
        let mut frozen_watch = [false; NUM_MOTORS];
        for &slot in &spec.policy.joint_ids_map {
            frozen_watch[slot] = true;
        }
        Self {
            limits: MotionLimits::from_spec(spec),
            winding_limit: s.motor_winding_limit_c,
            casing_limit: s.motor_casing_limit_c,
            timeout_ticks: ((s.state_timeout_s * spec.rates.control_hz as f64).round() as u64).max(1),
            crc_streak_limit: s.crc_failure_streak,
            frozen_frames: s.frozen_state_frames,
            supervised,
            frozen_watch,
            frozen_last: [[0; 3]; NUM_MOTORS],
            frozen_count: [0; NUM_MOTORS],
            last_accepted_tick: None,
            last_frame_counter: None,
            counters: SafetyCounters::default(),
            motion_checks: true,
        }
    }

    /// Whether this tick judges the robot's motion. Off in an operated run's `passive` state: the
    /// motors are damped by the operator's choice, so a robot that is lowered, lies on the floor,
    /// rests still or is moved by hand there has no fault to latch. Sensor, link and motor faults
    /// (timeouts, CRC, NaN, silent or hot motors) are judged in every state.
    pub fn set_motion_checks(&mut self, on: bool) {
        if !on {
            self.frozen_count = [0; NUM_MOTORS];
        }
        self.motion_checks = on;
    }

    pub fn counters(&self) -> SafetyCounters {
        self.counters
    }

    /// Stops judging joints as frozen. For HALs whose readings are quantized (CAN's 16- and 12-bit
    /// fields repeat exactly while a joint rests), where a dead motor shows as a missing reply
    /// (`MotorSilent`) instead.
    pub fn disable_frozen_check(&mut self) {
        self.frozen_watch = [false; NUM_MOTORS];
    }

    /// Clears streaks and histories after an operator reset (the latch itself lives in the controller).
    pub fn reset(&mut self, tick: u64) {
        self.frozen_count = [0; NUM_MOTORS];
        self.counters.crc_streak = 0;
        self.last_accepted_tick = Some(tick);
    }

    /// Judges this tick's frame. `state` is the newest accepted state (the new one when `Fresh`).
    /// Returns the first reason found, in a fixed order.
    pub fn check_frame(&mut self, tick: u64, status: FrameStatus, state: &LowState) -> Option<DampingReason> {
        let mut trip = None;
        match status {
            FrameStatus::Fresh => {
                // The robot's counter must advance: an old frame (delayed or repeated) is not news.
                let advanced = self
                    .last_frame_counter
                    .is_none_or(|prev| matches!(state.tick.wrapping_sub(prev), 1..0x8000_0000));
                if advanced {
                    self.last_frame_counter = Some(state.tick);
                    self.last_accepted_tick = Some(tick);
                    self.counters.crc_streak = 0;
                    trip = self.check_values(state);
                } else {
                    self.counters.stale_frames += 1;
                }
            }
            FrameStatus::NoFrame => self.counters.missing_frames += 1,
            FrameStatus::Bad(ErrorKind::Checksum) => {
                self.counters.crc_failures += 1;
                self.counters.crc_streak += 1;
                if self.counters.crc_streak >= self.crc_streak_limit {
                    trip = Some(DampingReason::CrcStreak);
                }
            }
            FrameStatus::Bad(ErrorKind::NonFinite) => trip = Some(DampingReason::NonFiniteInput),
            FrameStatus::Bad(ErrorKind::Malformed) => {
                self.counters.malformed_frames += 1;
                trip = Some(DampingReason::MalformedFrame);
            }
            FrameStatus::Bad(_) => trip = Some(DampingReason::HalFault),
        }
        // Age counts from tick 0 when nothing was ever accepted.
        let since = self.last_accepted_tick.map_or(tick + 1, |t| tick - t);
        self.counters.state_age_ticks = since;
        if trip.is_none() && since > self.timeout_ticks {
            trip = Some(DampingReason::StateTimeout);
        }
        trip
    }

    fn check_values(&mut self, st: &LowState) -> Option<DampingReason> {
        // Belt and braces: codecs reject non-finite frames, but a HAL may not decode at all.
        let imu = &st.imu;
        if imu.quaternion.iter().chain(&imu.gyroscope).any(|v| !v.is_finite()) {
            return Some(DampingReason::NonFiniteInput);
        }
        let norm2: f32 = imu.quaternion.iter().map(|q| q * q).sum();
        if !(0.81..=1.21).contains(&norm2) {
            return Some(DampingReason::InvalidImu);
        }
        let up = -estimator::projected_gravity(imu.quaternion)[2];
        if self.motion_checks && self.limits.tilted(up) {
            return Some(DampingReason::Tilt);
        }
        if self.motion_checks && self.limits.base_spinning(imu.gyroscope) {
            return Some(DampingReason::BaseAngularSpeed);
        }
        let mut trip = None;
        for (s, m) in st.motors.iter().enumerate() {
            if !self.supervised[s] {
                continue;
            }
            let slot = s as u8;
            // Its other fields are stale: judge the silence, not them.
            if m.motor_state & hal::MOTOR_STATE_NO_REPLY != 0 {
                return Some(DampingReason::MotorSilent { slot });
            }
            if !(m.q.is_finite() && m.dq.is_finite()) {
                return Some(DampingReason::NonFiniteInput);
            }
            if trip.is_none() && self.motion_checks && self.limits.joint_too_fast(s, m.dq) {
                trip = Some(DampingReason::JointSpeed { slot });
            }
            if trip.is_none() && (m.temperature[0] > self.casing_limit || m.temperature[1] > self.winding_limit) {
                trip = Some(DampingReason::MotorTemperature { slot });
            }
            if self.frozen_watch[s] && self.motion_checks {
                let now = [m.q.to_bits(), m.dq.to_bits(), m.tau_est.to_bits()];
                if now == self.frozen_last[s] {
                    self.frozen_count[s] += 1;
                } else {
                    self.frozen_count[s] = 1;
                    self.frozen_last[s] = now;
                }
                if trip.is_none() && self.frozen_count[s] >= self.frozen_frames {
                    trip = Some(DampingReason::FrozenJoint { slot });
                }
            }
        }
        trip
    }
}

/// A reason as (code, slot): the code numbers the variants in their order of declaration.
impl snapshot::Snapshot for DampingReason {
    fn save(&self, out: &mut Vec<u8>) {
        use DampingReason as R;
        let code = match self {
            R::Tilt => 0,
            R::JointSpeed { .. } => 1,
            R::BaseAngularSpeed => 2,
            R::MotorTemperature { .. } => 3,
            R::StateTimeout => 4,
            R::CrcStreak => 5,
            R::MalformedFrame => 6,
            R::NonFiniteInput => 7,
            R::NonFiniteObservation => 8,
            R::NonFiniteAction => 9,
            R::FrozenJoint { .. } => 10,
            R::HalFault => 11,
            R::MotorSilent { .. } => 12,
            R::EStop => 13,
            R::Requested => 14,
            R::InvalidImu => 15,
            R::CommandEnvelope { .. } => 16,
        };
        out.extend_from_slice(&[code, self.slot().unwrap_or(0)]);
    }

    fn restore(&mut self, input: &mut &[u8]) -> Result<(), snapshot::SnapshotError> {
        use DampingReason as R;
        let [code, slot] = snapshot::take::<2>(input, "damping reason")?;
        *self = match code {
            0 => R::Tilt,
            1 => R::JointSpeed { slot },
            2 => R::BaseAngularSpeed,
            3 => R::MotorTemperature { slot },
            4 => R::StateTimeout,
            5 => R::CrcStreak,
            6 => R::MalformedFrame,
            7 => R::NonFiniteInput,
            8 => R::NonFiniteObservation,
            9 => R::NonFiniteAction,
            10 => R::FrozenJoint { slot },
            11 => R::HalFault,
            12 => R::MotorSilent { slot },
            13 => R::EStop,
            14 => R::Requested,
            15 => R::InvalidImu,
            16 => R::CommandEnvelope { slot },
            _ => {
                return Err(snapshot::SnapshotError::Invalid {
                    what: "damping reason",
                    value: code as u64,
                })
            }
        };
        Ok(())
    }
}

snapshot::snapshot_fields!(SafetyCounters {
    crc_failures,
    crc_streak,
    missing_frames,
    stale_frames,
    malformed_frames,
    state_age_ticks,
});

snapshot::snapshot_fields!(Supervisor {
    frozen_watch,
    frozen_last,
    frozen_count,
    last_accepted_tick,
    last_frame_counter,
    counters,
    motion_checks,
});
