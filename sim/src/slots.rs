//! The 35 unitree_hg motor slots and the per-joint constants the G1 models need but do not all
//! ship (see `../shared/facts/g1_low_level.md` and `g1_sim_models.md`).

/// SDK name of slot `i` (`"left_knee"`), from `hal::G1_MOTOR_NAMES`; `None` for the unused
/// slots 29..35. Slot `i` drives the MJCF joint `<name>_joint`.
pub fn slot_name(slot: usize) -> Option<&'static str> {
    hal::G1_MOTOR_NAMES
        .get(slot)
        .copied()
        .filter(|n| !n.starts_with("unused"))
}

/// MJCF joint name of slot `i`, if the slot is used.
pub fn joint_name(slot: usize) -> Option<String> {
    slot_name(slot).map(|n| format!("{n}_joint"))
}

/// Actuator group of a G1 joint; effort limit and armature follow from it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Group {
    /// Hip pitch / yaw, waist yaw: 88 N·m.
    N88,
    /// Hip roll, knee: 139 N·m.
    N139,
    /// Ankles, waist roll / pitch: 50 N·m.
    N50,
    /// Shoulders, elbow, wrist roll: 25 N·m.
    N25,
    /// Wrist pitch / yaw: 5 N·m.
    N5,
}

fn group(slot_name: &str) -> Option<Group> {
    // Strip the side so "left_knee" and "right_knee" share an entry.
    let n = slot_name.trim_start_matches("left_").trim_start_matches("right_");
    Some(match n {
        "hip_pitch" | "hip_yaw" | "waist_yaw" => Group::N88,
        "hip_roll" | "knee" => Group::N139,
        "ankle_pitch" | "ankle_roll" | "waist_roll" | "waist_pitch" => Group::N50,
        "shoulder_pitch" | "shoulder_roll" | "shoulder_yaw" | "elbow" | "wrist_roll" => Group::N25,
        "wrist_pitch" | "wrist_yaw" => Group::N5,
        _ => return None,
    })
}

/// Effort (torque) limit in N·m from the G1 URDF, by slot name (`"left_knee"`).
pub fn effort_limit(slot_name: &str) -> Option<f64> {
    group(slot_name).map(|g| match g {
        Group::N88 => 88.0,
        Group::N139 => 139.0,
        Group::N50 => 50.0,
        Group::N25 => 25.0,
        Group::N5 => 5.0,
    })
}

/// Reflected rotor inertia (kg·m²) mjlab adds to the 29-dof model, by slot name. The armature
/// groups do not coincide with the torque groups (hip roll and knee share 0.02510, ankles share
/// with waist roll/pitch, wrist pitch/yaw have their own).
pub fn armature(slot_name: &str) -> Option<f64> {
    hal::g1_rotor_inertia(slot_name)
}

/// Home pose used by mjlab for the 29-dof model: joint angles by slot name (others 0) and the
/// root height.
pub const HOME_ROOT_Z: f64 = 0.7837;
pub fn home_angle(slot_name: &str) -> f64 {
    match slot_name {
        "left_hip_pitch" | "right_hip_pitch" => -0.1,
        "left_knee" | "right_knee" => 0.3,
        "left_ankle_pitch" | "right_ankle_pitch" => -0.2,
        "left_shoulder_pitch" | "right_shoulder_pitch" => 0.2,
        "left_shoulder_roll" => 0.2,
        "right_shoulder_roll" => -0.2,
        "left_elbow" | "right_elbow" => 1.28,
        _ => 0.0,
    }
}

/// PD gains `(kp, kd)` with which a pure posture-holding PD keeps the simulated G1 standing
/// (used by `Simulator::hold_initial_pose_command`, the bare-stepping benchmark and the tests).
///
/// Unitree's walking-policy leg gains (kp 100/100/100/150/40/40, kd 2/2/2/4/2/2) with waist
/// 300/20, except for measured deviations:
/// - ankle pitch kp 250 instead of 40: the body is an inverted pendulum on the two (co-axial)
///   ankle-pitch joints, and without a balancing policy their stiffness must exceed
///   m·g·h ≈ 33 kg · 9.81 · 0.62 m ≈ 200 N·m/rad in total; at 40 the 29-dof robot pitches forward
///   and falls in about 1.2 s;
/// - hip pitch kp 200 and knee kp 300: the 12-dof model starts with straight legs (`qpos0`), where
///   the weaker gains let the knees creep to their hyper-extension limit and the robot folds
///   forward after about 1.3 s;
/// - arm kd 2 instead of 5: chosen when the motor law was explicit (unstable once kd·dt / I > 2:
///   the elbow / wrist links, I ≈ 0.004–0.01 kg·m² with armature, chattered at their limits with
///   kd 5). The implicit PD actuator is stable at kd 10 there (`tests/actuator.rs`); kd 2 is
///   kept so standing and the tests calibrated on it stay as they were.
pub fn hold_gains(slot: usize) -> (f32, f32) {
    const LEG_KP: [f32; 6] = [200.0, 100.0, 100.0, 300.0, 250.0, 40.0];
    const LEG_KD: [f32; 6] = [2.0, 2.0, 2.0, 4.0, 2.0, 2.0];
    match slot {
        0..=11 => (LEG_KP[slot % 6], LEG_KD[slot % 6]),
        12..=14 => (300.0, 20.0),
        15..=28 => (100.0, 2.0),
        _ => (0.0, 0.0),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_used_slot_has_constants() {
        for i in 0..hal::NUM_MOTORS {
            match slot_name(i) {
                Some(n) => {
                    assert!(effort_limit(n).is_some(), "{n}");
                    assert!(armature(n).is_some(), "{n}");
                    assert!(i < 29);
                }
                None => assert!(i >= 29),
            }
        }
        assert_eq!(joint_name(3).as_deref(), Some("left_knee_joint"));
        assert_eq!(effort_limit("right_knee"), Some(139.0));
        assert_eq!(effort_limit("left_wrist_yaw"), Some(5.0));
        assert_eq!(armature("right_ankle_roll"), Some(0.00722));
    }
}
