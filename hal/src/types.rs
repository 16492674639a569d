//! Plain data mirroring unitree_hg `LowCmd_` / `LowState_` field for field (see
//! `../shared/facts/g1_low_level.md`); the byte layout lives in `sensor_io`.
use crate::NUM_MOTORS;

/// `MotorCmd_.mode`: 0 disables the motor (the SDK default, a known trap), 1 enables it.
pub const MOTOR_MODE_DISABLED: u8 = 0;
pub const MOTOR_MODE_ENABLED: u8 = 1;

/// `MotorState::motor_state` bit a HAL sets while a motor has not answered for longer than its
/// timeout (the motor's other fields are then its last answer). The safety supervisor damps on it.
pub const MOTOR_STATE_NO_REPLY: u32 = 1 << 31;

/// One motor slot of `LowCmd_`. The motor driver applies
/// `tau_out = tau + kp (q − q_meas) + kd (dq − dq_meas)`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MotorCommand {
    pub mode: u8,
    pub q: f32,
    pub dq: f32,
    pub tau: f32,
    pub kp: f32,
    pub kd: f32,
    pub reserve: u32,
}

impl MotorCommand {
    /// Passive damping: no stiffness, only velocity damping (Unitree's recommended safe state).
    pub const fn damping(kd: f32) -> Self {
        Self {
            mode: MOTOR_MODE_ENABLED,
            q: 0.0,
            dq: 0.0,
            tau: 0.0,
            kp: 0.0,
            kd,
            reserve: 0,
        }
    }
}

/// `LowCmd_`: one command for all 35 slots.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LowCommand {
    /// 0 = PR (serial pitch/roll ankle), 1 = AB (parallel).
    pub mode_pr: u8,
    /// Must echo `LowState::mode_machine`.
    pub mode_machine: u8,
    pub motors: [MotorCommand; NUM_MOTORS],
    pub reserve: [u32; 4],
}

impl Default for LowCommand {
    fn default() -> Self {
        Self {
            mode_pr: 0,
            mode_machine: 0,
            motors: [MotorCommand::default(); NUM_MOTORS],
            reserve: [0; 4],
        }
    }
}

/// `IMUState_` of the pelvis IMU.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImuState {
    /// Orientation, w x y z.
    pub quaternion: [f32; 4],
    /// Body-frame angular velocity, rad/s.
    pub gyroscope: [f32; 3],
    /// Body-frame specific force, m/s².
    pub accelerometer: [f32; 3],
    /// Roll, pitch, yaw, rad.
    pub rpy: [f32; 3],
    pub temperature: i16,
}

impl Default for ImuState {
    fn default() -> Self {
        Self {
            quaternion: [1.0, 0.0, 0.0, 0.0],
            gyroscope: [0.0; 3],
            accelerometer: [0.0; 3],
            rpy: [0.0; 3],
            temperature: 0,
        }
    }
}

/// `MotorState_` of one slot.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MotorState {
    pub mode: u8,
    pub q: f32,
    pub dq: f32,
    pub ddq: f32,
    pub tau_est: f32,
    /// Casing and winding temperature, °C.
    pub temperature: [i16; 2],
    pub voltage: f32,
    pub sensor: [u32; 2],
    /// Error code reported by the driver (0 = ok).
    pub motor_state: u32,
    pub reserve: [u32; 4],
}

/// `LowState_`: everything the low level reports in one frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LowState {
    pub version: [u32; 2],
    pub mode_pr: u8,
    pub mode_machine: u8,
    /// The robot's own millisecond-ish counter (the simulator's step counter in simulation).
    pub tick: u32,
    pub imu: ImuState,
    pub motors: [MotorState; NUM_MOTORS],
    pub wireless_remote: [u8; 40],
    pub reserve: [u32; 4],
}

impl Default for LowState {
    fn default() -> Self {
        Self {
            version: [0; 2],
            mode_pr: 0,
            mode_machine: 0,
            tick: 0,
            imu: ImuState::default(),
            motors: [MotorState::default(); NUM_MOTORS],
            wireless_remote: [0; 40],
            reserve: [0; 4],
        }
    }
}

/// `mode_machine` values reported by the robot.
pub mod mode_machine {
    pub const G1_23DOF: u8 = 1;
    pub const G1_29DOF: u8 = 2;
    pub const LOCK_WAIST: u8 = 3;
    pub const G1_23DOF_REV_1_0: u8 = 4;
    pub const G1_29DOF_REV_1_0: u8 = 5;
    pub const LOCK_WAIST_REV_1_0: u8 = 6;
    pub const DUAL_ARM: u8 = 9;
}

/// The G1's motor slots in SDK order (index = slot in `LowCmd_`/`LowState_`); the MJCF joint of a
/// slot is this name plus `_joint`. Slots 29–34 are unused on the 29-dof G1.
pub const G1_MOTOR_NAMES: [&str; crate::NUM_MOTORS] = [
    "left_hip_pitch",
    "left_hip_roll",
    "left_hip_yaw",
    "left_knee",
    "left_ankle_pitch",
    "left_ankle_roll",
    "right_hip_pitch",
    "right_hip_roll",
    "right_hip_yaw",
    "right_knee",
    "right_ankle_pitch",
    "right_ankle_roll",
    "waist_yaw",
    "waist_roll",
    "waist_pitch",
    "left_shoulder_pitch",
    "left_shoulder_roll",
    "left_shoulder_yaw",
    "left_elbow",
    "left_wrist_roll",
    "left_wrist_pitch",
    "left_wrist_yaw",
    "right_shoulder_pitch",
    "right_shoulder_roll",
    "right_shoulder_yaw",
    "right_elbow",
    "right_wrist_roll",
    "right_wrist_pitch",
    "right_wrist_yaw",
    "unused_29",
    "unused_30",
    "unused_31",
    "unused_32",
    "unused_33",
    "unused_34",
];

/// Index of the slot whose joint is `name` (with or without the `_joint` suffix).
pub fn g1_motor_slot(name: &str) -> Option<usize> {
    slot_of(name.strip_suffix("_joint").unwrap_or(name))
}

/// [`g1_motor_slot`] for constant slot tables, evaluated at compile time: a name that is not in
/// [`G1_MOTOR_NAMES`] (no `_joint` suffix here) fails the build instead of naming a wrong slot.
pub const fn g1_motor_slot_const(name: &str) -> usize {
    match slot_of(name) {
        Some(slot) => slot,
        None => panic!("not a G1 motor name (hal::G1_MOTOR_NAMES)"),
    }
}

/// The one search of [`G1_MOTOR_NAMES`], usable at compile time and at run time.
const fn slot_of(base: &str) -> Option<usize> {
    let mut slot = 0;
    while slot < G1_MOTOR_NAMES.len() {
        if const_str_eq(G1_MOTOR_NAMES[slot], base) {
            return Some(slot);
        }
        slot += 1;
    }
    None
}

/// `a == b` in a const context (`str`'s `PartialEq` is not const).
const fn const_str_eq(a: &str, b: &str) -> bool {
    let (a, b) = (a.as_bytes(), b.as_bytes());
    if a.len() != b.len() {
        return false;
    }
    let mut i = 0;
    while i < a.len() {
        if a[i] != b[i] {
            return false;
        }
        i += 1;
    }
    true
}

/// Velocity limit of a G1 joint's motor, rad/s (`<limit velocity>` in Unitree's
/// g1_29dof_rev_1_0.urdf), by slot name with or without its side. This is the physical bound the
/// supervisor and the trainer use by default; a deploy spec may only be stricter
/// (`[safety] joint_speed_limit_rad_s`, `joint_speed_limits_rad_s`).
pub fn g1_motor_velocity_limit(slot_name: &str) -> Option<f32> {
    let n = slot_name.trim_start_matches("left_").trim_start_matches("right_");
    Some(match n {
        "hip_pitch" | "hip_yaw" | "waist_yaw" => 32.0,
        "hip_roll" | "knee" => 20.0,
        "ankle_pitch" | "ankle_roll" | "waist_roll" | "waist_pitch" => 37.0,
        "shoulder_pitch" | "shoulder_roll" | "shoulder_yaw" | "elbow" | "wrist_roll" => 37.0,
        "wrist_pitch" | "wrist_yaw" => 22.0,
        _ => return None,
    })
}

/// A G1 variant as LowState's `mode_machine` names it (unitree_sdk2; `../shared/facts/g1_low_level.md`),
/// and the motor slots it does not have (a spec that drives one of them is refused on that robot).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct G1Variant {
    pub mode_machine: u8,
    pub name: &'static str,
    pub missing: &'static [usize],
}

/// Waist roll and pitch (locked or absent), and the wrists' pitch and yaw (23-dof arms).
const NO_WAIST_ROLL_PITCH: [usize; 2] = [13, 14];
const DOF23_MISSING: [usize; 6] = [13, 14, 20, 21, 27, 28];
/// The dual-arm G1 is an upper body: no legs.
const NO_LEGS: [usize; 12] = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11];

pub const G1_VARIANTS: [G1Variant; 7] = [
    G1Variant {
        mode_machine: 1,
        name: "g1_23dof",
        missing: &DOF23_MISSING,
    },
    G1Variant {
        mode_machine: 2,
        name: "g1_29dof",
        missing: &[],
    },
    G1Variant {
        mode_machine: 3,
        name: "g1_lock_waist",
        missing: &NO_WAIST_ROLL_PITCH,
    },
    G1Variant {
        mode_machine: 4,
        name: "g1_23dof_rev_1_0",
        missing: &DOF23_MISSING,
    },
    G1Variant {
        mode_machine: 5,
        name: "g1_29dof_rev_1_0",
        missing: &[],
    },
    G1Variant {
        mode_machine: 6,
        name: "g1_lock_waist_rev_1_0",
        missing: &NO_WAIST_ROLL_PITCH,
    },
    G1Variant {
        mode_machine: 9,
        name: "g1_dual_arm",
        missing: &NO_LEGS,
    },
];

/// The variant a LowState's `mode_machine` names; `None` for 0 (not set: simulators) or a value
/// this table does not know.
pub fn g1_variant(mode_machine: u8) -> Option<&'static G1Variant> {
    G1_VARIANTS.iter().find(|v| v.mode_machine == mode_machine)
}

/// Effort limit of a G1 joint's motor, N·m (`actuatorfrcrange` of Unitree's MJCF, `effort` of
/// g1_29dof_rev_1_0.urdf), by slot name with or without its side. The
/// command envelope bounds each motor's feed-forward torque by it.
pub fn g1_motor_effort_limit(slot_name: &str) -> Option<f32> {
    let n = slot_name.trim_start_matches("left_").trim_start_matches("right_");
    Some(match n {
        "hip_pitch" | "hip_yaw" | "waist_yaw" => 88.0,
        "hip_roll" | "knee" => 139.0,
        "ankle_pitch" | "ankle_roll" | "waist_roll" | "waist_pitch" => 50.0,
        "shoulder_pitch" | "shoulder_roll" | "shoulder_yaw" | "elbow" | "wrist_roll" => 25.0,
        "wrist_pitch" | "wrist_yaw" => 5.0,
        _ => return None,
    })
}

/// Reflected rotor inertia (MuJoCo `armature`) of a G1 joint, kg·m², by slot name with or without
/// its side (mjlab's `g1_constants.py`): the simulator adds it to the 29-dof MJCF, and `check-spec`
/// judges gains against it. A joint's inertia is at least this.
pub fn g1_rotor_inertia(slot_name: &str) -> Option<f64> {
    let n = slot_name.trim_start_matches("left_").trim_start_matches("right_");
    Some(match n {
        "hip_pitch" | "hip_yaw" | "waist_yaw" => 0.01018,
        "hip_roll" | "knee" => 0.02510,
        "waist_roll" | "waist_pitch" | "ankle_pitch" | "ankle_roll" => 0.00722,
        "shoulder_pitch" | "shoulder_roll" | "shoulder_yaw" | "elbow" | "wrist_roll" => 0.00361,
        "wrist_pitch" | "wrist_yaw" => 0.00425,
        _ => return None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_const_slot_lookup_agrees_with_the_runtime_one() {
        for (slot, name) in G1_MOTOR_NAMES.iter().enumerate() {
            assert_eq!(g1_motor_slot_const(name), slot, "{name}");
            assert_eq!(g1_motor_slot(name), Some(slot), "{name}");
        }
        const WAIST_PITCH: usize = g1_motor_slot_const("waist_pitch");
        assert_eq!(WAIST_PITCH, 14);
        assert!(!const_str_eq("waist_pitch", "waist_pitc"));
        assert!(!const_str_eq("waist_roll", "waist_yawl"));
    }
}
