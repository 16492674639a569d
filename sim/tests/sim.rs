//! Simulator library: model loading, the motor law, determinism, standing, IMU.
// The simulator never runs on the robot: std's math is fine here (see clippy.toml).
#![allow(clippy::disallowed_methods)]
mod common;

use common::{have_12dof, load, load29, require_deps};
use g1_sim::{ModelChoice, SimConfig, Simulator};
use hal::{LowCommand, LowState, MOTOR_MODE_DISABLED, MOTOR_MODE_ENABLED};
use mujoco_rs::prelude::*;
use sensor_io::unitree_hg::{encode_low_state, LOW_STATE_LEN};

const LEFT_KNEE: usize = 3;
const LEFT_WRIST_YAW: usize = 21;

#[test]
fn g1_29dof_loads_with_29_slots_in_home_pose() {
    let sim = load29();
    assert_eq!(sim.motor_slots_present(), (1u64 << 29) - 1);
    assert_eq!(sim.mode_machine(), hal::mode_machine::G1_29DOF_REV_1_0);
    let q = sim.initial_qpos();
    assert_eq!(q[2], 0.7837);
    // Slot order = joint order in this MJCF: qpos[7 + slot].
    assert_eq!(q[7 + LEFT_KNEE], 0.3);
    assert_eq!(q[7 + 16], 0.2); // left shoulder roll
    assert_eq!(q[7 + 23], -0.2); // right shoulder roll
    assert_eq!(q[7 + 25], 1.28); // right elbow
    assert_eq!(sim.effort_limit(LEFT_KNEE), Some((-139.0, 139.0)));
    assert_eq!(sim.effort_limit(LEFT_WRIST_YAW), Some((-5.0, 5.0)));
    assert_eq!(sim.effort_limit(29), None);
    // Armature was added (the shipped MJCF has none).
    let m = sim.data().model();
    let knee = m.name_to_id(MjtObjBase::mjOBJ_JOINT, "left_knee_joint").unwrap();
    assert_eq!(m.dof_armature()[m.jnt_dofadr()[knee] as usize], 0.02510);
    let mut st = LowState::default();
    sim.low_state(&mut st);
    assert_eq!(st.motors[LEFT_KNEE].q, 0.3);
    assert_eq!(st.motors[LEFT_KNEE].mode, MOTOR_MODE_ENABLED);
    assert_eq!(st.motors[30].mode, 0);
    assert_eq!(st.mode_machine, 5);
    assert_eq!(st.version, [1, 0]);
}

#[test]
fn g1_12dof_loads_with_12_slots_at_qpos0() {
    require_deps();
    if !have_12dof("g1_12dof_loads_with_12_slots_at_qpos0") {
        return;
    }
    let sim = load(ModelChoice::G1_12Dof);
    assert_eq!(sim.motor_slots_present(), 0xFFF);
    assert_eq!(sim.mode_machine(), hal::mode_machine::G1_23DOF_REV_1_0);
    let plain = MjModel::from_xml(ModelChoice::G1_12Dof.path()).unwrap();
    assert_eq!(
        sim.initial_qpos(),
        plain.qpos0(),
        "initial state must be the model's qpos0"
    );
    assert_eq!(sim.data().qpos(), plain.qpos0());
    // Its own actuatorfrcrange sets the clamp.
    assert_eq!(sim.effort_limit(LEFT_KNEE), Some((-139.0, 139.0)));
    let mut st = LowState::default();
    sim.low_state(&mut st);
    let q = sim.data().qpos();
    assert_eq!(st.imu.quaternion, [q[3] as f32, q[4] as f32, q[5] as f32, q[6] as f32]);
    assert_eq!(st.mode_machine, 4);
    assert_eq!(st.motors[12].mode, 0, "no waist on the 12-dof model");
}

fn one_slot(slot: usize, mode: u8, q: f32, kp: f32) -> LowCommand {
    let mut cmd = LowCommand::default();
    let m = &mut cmd.motors[slot];
    m.mode = mode;
    m.q = q;
    m.kp = kp;
    cmd
}

#[test]
fn pd_torque_is_clamped_to_effort_limit() {
    let mut sim = load29();
    for (slot, limit) in [(LEFT_KNEE, 139.0), (LEFT_WRIST_YAW, 5.0)] {
        sim.reset();
        sim.apply_command(&one_slot(slot, MOTOR_MODE_ENABLED, 2.0, 1.0e4))
            .unwrap();
        sim.step_control_tick();
        assert_eq!(sim.applied_torque(slot), limit);
        let mut st = LowState::default();
        sim.low_state(&mut st);
        assert_eq!(st.motors[slot].tau_est, limit as f32);
        sim.apply_command(&one_slot(slot, MOTOR_MODE_ENABLED, -2.0, 1.0e4))
            .unwrap();
        sim.step_control_tick();
        assert_eq!(sim.applied_torque(slot), -limit);
    }
    // Unclamped: exactly the motor law from the state at that step.
    sim.reset();
    let q0 = sim.data().qpos()[7 + LEFT_KNEE];
    let mut cmd = one_slot(LEFT_KNEE, MOTOR_MODE_ENABLED, 0.35, 100.0);
    cmd.motors[LEFT_KNEE].tau = 1.5;
    cmd.motors[LEFT_KNEE].kd = 2.0;
    sim.apply_command(&cmd).unwrap();
    sim.step_control_tick();
    let expect = 1.5 + 100.0 * (0.35f32 as f64 - q0) + 2.0 * (0.0 - 0.0);
    assert!((sim.applied_torque(LEFT_KNEE) - expect).abs() < 1e-12);
    assert_eq!(sim.data().actuator_force()[LEFT_KNEE], sim.applied_torque(LEFT_KNEE));
}

#[test]
fn disabled_motor_gets_no_torque() {
    let mut sim = load29();
    let mut cmd = one_slot(LEFT_KNEE, MOTOR_MODE_DISABLED, 2.0, 1.0e4);
    cmd.motors[LEFT_KNEE].tau = 50.0;
    sim.apply_command(&cmd).unwrap();
    for _ in 0..5 {
        sim.step_control_tick();
        assert_eq!(sim.applied_torque(LEFT_KNEE), 0.0);
        assert_eq!(sim.data().ctrl()[LEFT_KNEE], 0.0);
        assert!(sim.data().ctrl().iter().all(|&c| c == 0.0));
    }
}

#[test]
fn non_finite_command_is_rejected() {
    let mut sim = load29();
    let mut cmd = LowCommand::default();
    cmd.motors[7].kd = f32::NAN;
    assert!(matches!(
        sim.apply_command(&cmd),
        Err(g1_sim::SimError::NonFinite { field: "kd", slot: 7 })
    ));
}

/// 500 ticks of a time-varying command; returns every encoded LowState.
fn run_500(config: SimConfig) -> Vec<[u8; LOW_STATE_LEN]> {
    let mut sim = Simulator::load(ModelChoice::G1_29Dof, config).unwrap();
    let base = sim.hold_initial_pose_command();
    let (mut st, mut bytes, mut out) = (LowState::default(), [0u8; LOW_STATE_LEN], Vec::new());
    for t in 0..500 {
        let mut cmd = base;
        for (i, m) in cmd.motors.iter_mut().enumerate() {
            m.q += 0.1 * ((t as f32) * 0.05 + i as f32).sin();
        }
        sim.apply_command(&cmd).unwrap();
        sim.step_control_tick();
        sim.low_state(&mut st);
        encode_low_state(&st, &mut bytes);
        out.push(bytes);
    }
    out
}

#[test]
fn same_commands_give_bit_identical_states() {
    require_deps();
    let a = run_500(SimConfig::default());
    let b = run_500(SimConfig::default());
    assert!(a == b, "two identical runs diverged");
    // Noise is seeded: same seed → same bytes, different seed → different bytes.
    let noisy = SimConfig {
        seed: 7,
        imu_noise: Some(g1_sim::ImuNoise::REALISTIC),
        ..SimConfig::default()
    };
    let n1 = run_500(noisy);
    assert!(n1 == run_500(noisy));
    assert!(n1 != run_500(SimConfig { seed: 8, ..noisy }));
    assert!(n1 != a);
}

#[test]
fn realistic_imu_noise_has_biases_and_a_drifting_yaw() {
    let config = SimConfig {
        seed: 3,
        imu_noise: Some("realistic".parse().unwrap()),
        ..SimConfig::default()
    };
    require_deps();
    let mut sim = Simulator::load(ModelChoice::G1_29Dof, config).unwrap();
    sim.apply_command(&sim.hold_initial_pose_command()).unwrap();
    let bias = sim.imu_bias();
    assert!(bias.iter().all(|b| *b != 0.0), "{bias:?}");
    let mut st = LowState::default();
    let (mut gyro_sum, mut n) = ([0.0f64; 3], 0.0);
    let mut yaw_err = Vec::new();
    for tick in 1..=1000 {
        sim.step_control_tick();
        sim.low_state(&mut st);
        let t = sim.truth();
        if tick > 500 {
            // Standing still: the mean gyro reading is the bias.
            for (sum, (g, w)) in gyro_sum
                .iter_mut()
                .zip(st.imu.gyroscope.iter().zip(t.base_ang_vel_body))
            {
                *sum += *g as f64 - w;
            }
            n += 1.0;
        }
        if tick % 500 == 0 {
            let truth_yaw = g1_sim::quat_to_rpy(t.base_quat)[2];
            yaw_err.push(st.imu.rpy[2] as f64 - truth_yaw);
        }
    }
    for a in 0..3 {
        let mean = gyro_sum[a] / n;
        // White noise 0.01 over 500 samples leaves ~0.0005 of scatter on the mean.
        assert!(
            (mean - bias[a]).abs() < 0.002,
            "axis {a}: mean {mean} vs bias {}",
            bias[a]
        );
    }
    // Yaw drifts at the z bias: twice the error after twice the time.
    assert!((yaw_err[0] - bias[2] * 1.0).abs() < 1e-3, "{yaw_err:?} {}", bias[2]);
    assert!((yaw_err[1] - bias[2] * 2.0).abs() < 1e-3, "{yaw_err:?} {}", bias[2]);
    assert!("1,2,3".parse::<g1_sim::ImuNoise>().is_err());
    assert!("0.1,-1".parse::<g1_sim::ImuNoise>().is_err());
}

#[test]
fn g1_29dof_stands_for_2s_holding_home_pose() {
    let mut sim = load29();
    sim.apply_command(&sim.hold_initial_pose_command()).unwrap();
    let mut st = LowState::default();
    let mut min_z = f64::INFINITY;
    for tick in 0..1000 {
        sim.step_control_tick();
        let t = sim.truth();
        min_z = min_z.min(t.base_pos[2]);
        if tick >= 500 {
            // Standing still: the accelerometer reads +g along the pelvis z axis.
            sim.low_state(&mut st);
            let a = st.imu.accelerometer;
            assert!((a[2] - 9.81).abs() < 0.5, "tick {tick}: accelerometer {a:?}");
            assert!(a[0].abs() < 1.0 && a[1].abs() < 1.0, "tick {tick}: accelerometer {a:?}");
        }
    }
    let t = sim.truth();
    assert!(min_z > 0.6, "pelvis dropped to {min_z}");
    assert!((t.sim_time_s - 2.0).abs() < 1e-9);
    assert_eq!(t.foot_contact, [true, true], "both feet on the floor");
    assert!(t.base_lin_vel_world.iter().all(|v| v.abs() < 0.05), "{t:?}");
    sim.low_state(&mut st);
    assert_eq!(st.tick, 1000);
    // IMU rpy agrees with the quaternion; near upright.
    assert!(st.imu.rpy[0].abs() < 0.1 && st.imu.rpy[1].abs() < 0.1);
}

#[test]
fn g1_12dof_stands_and_reads_gravity() {
    require_deps();
    if !have_12dof("g1_12dof_stands_and_reads_gravity") {
        return;
    }
    let mut sim = load(ModelChoice::G1_12Dof);
    sim.apply_command(&sim.hold_initial_pose_command()).unwrap();
    for _ in 0..1000 {
        sim.step_control_tick();
    }
    let t = sim.truth();
    assert!(t.base_pos[2] > 0.6, "{t:?}");
    let mut st = LowState::default();
    sim.low_state(&mut st);
    assert!((st.imu.accelerometer[2] - 9.81).abs() < 0.5, "{:?}", st.imu);
}

#[test]
fn control_tick_runs_whole_physics_steps() {
    require_deps();
    let cfg = SimConfig {
        physics_dt: 0.001,
        control_dt: 0.005,
        ..SimConfig::default()
    };
    let mut sim = Simulator::load(ModelChoice::G1_29Dof, cfg).unwrap();
    assert_eq!(sim.substeps(), 5);
    sim.step_control_tick();
    assert_eq!(sim.steps(), 5);
    assert!((sim.time() - 0.005).abs() < 1e-12);
    let bad = SimConfig {
        physics_dt: 0.002,
        control_dt: 0.003,
        ..SimConfig::default()
    };
    assert!(Simulator::load(ModelChoice::G1_29Dof, bad).is_err());
}

#[test]
fn missing_model_names_the_fix() {
    let err = Simulator::load(ModelChoice::Path("/nonexistent/g1.xml".into()), SimConfig::default())
        .err()
        .unwrap();
    assert!(err.to_string().contains("/nonexistent/g1.xml"), "{err}");
}

/// The test gantry's rope: slack while standing, pulling along itself when stretched, never pushing.
#[test]
fn the_gantry_rope_is_slack_near_the_start_and_only_pulls() {
    let g = g1_sim::Gantry::default();
    let anchor = [0.0, 0.0, 1.8];
    let standing = [0.0, 0.0, 0.8];
    assert_eq!(g.force(anchor, standing, [0.0; 3]), [0.0; 3]);
    // 10 cm down: 5 cm stretched, pulled up by k · 0.05 (plus damping while sinking).
    let f = g.force(anchor, [0.0, 0.0, 0.7], [0.0; 3]);
    assert!((f[2] - g.stiffness * 0.05).abs() < 1e-9 && f[0] == 0.0, "{f:?}");
    assert!(g.force(anchor, [0.0, 0.0, 0.7], [0.0, 0.0, -0.5])[2] > f[2]);
    // Rising fast on a stretched rope: the damping may cancel the pull, never reverse it.
    assert_eq!(g.force(anchor, [0.0, 0.0, 0.7], [0.0, 0.0, 5.0]), [0.0; 3]);
    // Off to the side: pulled back toward the tie point.
    let f = g.force(anchor, [0.6, 0.0, 0.8], [0.0; 3]);
    assert!(f[0] < 0.0 && f[2] > 0.0, "{f:?}");
}

/// With every motor damped (a tripped controller), the 12-dof G1 falls; on the gantry it hangs
/// a few centimetres below its start height.
#[test]
fn a_damped_robot_on_the_gantry_hangs_instead_of_falling() {
    if !have_12dof("a_damped_robot_on_the_gantry_hangs_instead_of_falling") {
        return;
    }
    let mut damping = LowCommand::default();
    for m in damping.motors.iter_mut() {
        m.mode = MOTOR_MODE_ENABLED;
        m.kd = 5.0;
    }
    let lowest = |gantry: bool| {
        let mut sim = load(ModelChoice::G1_12Dof);
        let z0 = sim.truth().base_pos[2];
        if gantry {
            sim.hang_on_gantry(Some(g1_sim::Gantry::default())).unwrap();
        }
        sim.apply_command(&damping).unwrap();
        let mut low = z0;
        for _ in 0..1500 {
            sim.step_control_tick();
            low = low.min(sim.truth().base_pos[2]);
        }
        (z0, low)
    };
    let (z0, fell) = lowest(false);
    assert!(
        fell < z0 - 0.3,
        "without the gantry the damped robot falls: {z0} → {fell}"
    );
    let (z0, hung) = lowest(true);
    assert!(hung > z0 - 0.15, "on the gantry it hangs: {z0} → {hung}");
}
