//! The implicit PD actuator at real gains, the training profile, the terrain pool and the domain
//! randomisation hooks.
// The simulator never runs on the robot: std's math is fine here (see clippy.toml).
#![allow(clippy::disallowed_methods)]
mod common;

use common::{have_12dof, require_deps};
use g1_sim::world::World;
use g1_sim::{ModelChoice, PhysicsProfile, SimConfig, SimError, Simulator};
use hal::{LowCommand, MOTOR_MODE_ENABLED, NUM_MOTORS};
use mujoco_rs::prelude::*;

/// Wrist roll, pitch, yaw of both arms (unitree_hg slots).
const WRISTS: [usize; 6] = [19, 20, 21, 26, 27, 28];
/// A chattering speed: no held wrist moves this fast on purpose, rad/s.
const SPEED_GUARD: f64 = 10.0;

/// The home pose with unitree_rl_lab's arm gains: kp 40, kd 10 on shoulders, elbows and wrists
/// (legs and waist as `hold_gains`).
fn rl_lab_arm_hold(sim: &Simulator) -> LowCommand {
    let mut cmd = sim.hold_initial_pose_command();
    for m in &mut cmd.motors[15..29] {
        m.kp = 40.0;
        m.kd = 10.0;
    }
    cmd
}

/// Largest |dq| over the wrist joints.
fn wrist_speed(sim: &Simulator) -> f64 {
    let v = sim.data().qvel();
    WRISTS.iter().map(|&s| v[6 + s].abs()).fold(0.0, f64::max)
}

/// Holds the pose for `seconds` with MuJoCo's implicit PD; returns the peak wrist speed after the
/// first 0.2 s and the lowest pelvis height.
fn hold_implicit(config: SimConfig, seconds: f64) -> (f64, f64) {
    let mut sim = Simulator::load(ModelChoice::G1_29Dof, config).unwrap();
    let cmd = rl_lab_arm_hold(&sim);
    sim.apply_command(&cmd).unwrap();
    let (mut peak, mut min_z) = (0.0f64, f64::INFINITY);
    while sim.time() < seconds {
        sim.step_control_tick();
        if sim.time() > 0.2 {
            peak = peak.max(wrist_speed(&sim));
        }
        min_z = min_z.min(sim.truth().base_pos[2]);
    }
    (peak, min_z)
}

#[test]
fn wrists_hold_still_at_rl_lab_gains_dt_0_002() {
    require_deps();
    let (peak, min_z) = hold_implicit(SimConfig::default(), 4.0);
    eprintln!("implicit PD, dt 0.002: peak wrist speed {peak:.4} rad/s, min pelvis z {min_z:.3}");
    assert!(peak < 1.0, "wrist speed {peak} rad/s");
    assert!(min_z > 0.6, "pelvis dropped to {min_z}");
}

#[test]
fn wrists_hold_still_at_rl_lab_gains_dt_0_005_decimation_4() {
    require_deps();
    let config = SimConfig {
        physics_dt: 0.005,
        control_dt: 0.02,
        ..SimConfig::default()
    };
    for physics in [PhysicsProfile::Deploy, PhysicsProfile::Training] {
        let (peak, min_z) = hold_implicit(SimConfig { physics, ..config }, 4.0);
        eprintln!("implicit PD, dt 0.005 x 4, {physics:?}: peak wrist speed {peak:.4} rad/s, min pelvis z {min_z:.3}");
        assert!(peak < 1.0, "{physics:?}: wrist speed {peak} rad/s");
        assert!(min_z > 0.6, "{physics:?}: pelvis dropped to {min_z}");
    }
}

/// Both models drive every slot through exactly one PD actuator: the 12-dof model's own gear-1
/// motors are converted in place (not duplicated), and the joint-level force clamp moved onto the
/// actuator, which MuJoCo's implicit derivative respects.
#[test]
fn every_slot_has_one_force_limited_affine_pd_actuator() {
    require_deps();
    let mut models = vec![(ModelChoice::G1_29Dof, 29)];
    if have_12dof("every_slot_has_one_force_limited_affine_pd_actuator") {
        models.push((ModelChoice::G1_12Dof, 12));
    }
    for (choice, n) in models {
        let sim = Simulator::load(choice.clone(), SimConfig::default()).unwrap();
        let m = sim.data().model();
        assert_eq!(m.nu() as usize, n, "{choice}");
        assert_eq!(m.opt().integrator, MjtIntegrator::mjINT_IMPLICITFAST as i32, "{choice}");
        for a in 0..n {
            assert_eq!(m.actuator_biastype()[a], MjtBias::mjBIAS_AFFINE, "{choice} {a}");
            assert!(m.actuator_forcelimited()[a], "{choice} {a}");
            assert!(!m.actuator_ctrllimited()[a], "{choice} {a}");
        }
        assert!(
            m.jnt_actfrclimited().iter().all(|l| !l),
            "{choice}: a joint-level clamp is left"
        );
        let (lo, hi) = sim.effort_limit(3).unwrap();
        assert_eq!(m.actuator_forcerange()[3], [lo, hi], "{choice}");
    }
}

/// The old motor law on the same setup: the torque computed from the state at the start of every
/// physics step and applied as a feed-forward torque (kp = kd = 0 on the actuator, so MuJoCo sees
/// a constant force, exactly what the explicit law wrote into `ctrl`). It trips the firmware's
/// joint-speed guard: kd·dt / I = 10 · 0.002 / ~0.005 ≈ 4 > 2 on the wrists.
/// Runs the old explicit law for 4 s: peak wrist speed after 0.2 s, and how many physics steps a
/// wrist motor sat at its torque limit.
fn hold_explicit(physics_dt: f64) -> (f64, usize) {
    let config = SimConfig {
        physics_dt,
        control_dt: physics_dt,
        ..SimConfig::default()
    };
    let mut sim = Simulator::load(ModelChoice::G1_29Dof, config).unwrap();
    let gains = rl_lab_arm_hold(&sim);
    let (mut peak, mut saturated) = (0.0f64, 0);
    while sim.time() < 4.0 {
        let mut cmd = gains;
        let (q, v) = (sim.data().qpos(), sim.data().qvel());
        for (slot, m) in cmd.motors.iter_mut().enumerate().take(29) {
            let (lo, hi) = sim.effort_limit(slot).unwrap();
            let tau = m.kp as f64 * (m.q as f64 - q[7 + slot]) - m.kd as f64 * v[6 + slot];
            m.tau = tau.clamp(lo, hi) as f32;
            m.kp = 0.0;
            m.kd = 0.0;
        }
        sim.apply_command(&cmd).unwrap();
        sim.step_control_tick();
        if sim.time() > 0.2 {
            peak = peak.max(wrist_speed(&sim));
        }
        saturated += WRISTS
            .iter()
            .filter(|&&w| sim.applied_torque(w).abs() >= sim.effort_limit(w).unwrap().1 * 0.999)
            .count();
    }
    (peak, saturated)
}

/// The old motor law on the same setup: the torque computed from the state at the start of every
/// physics step and applied as a feed-forward torque (kp = kd = 0 on the actuator, so MuJoCo sees
/// a constant force, exactly what the explicit law wrote into `ctrl`). kd·dt / I ≈ 10 · 0.002 /
/// 0.005 = 4 > 2 on the wrists: the damping overshoots every step and the wrists chatter
/// bang-bang between their ±5 N·m limits (measured: 8.9 rad/s peak at dt 0.002, against < 0.01 with
/// the implicit actuator); at the training's dt 0.005 they pass 10 rad/s.
#[test]
fn the_old_explicit_law_chatters_on_the_same_setup() {
    require_deps();
    let (peak2, sat2) = hold_explicit(0.002);
    let (peak5, sat5) = hold_explicit(0.005);
    let (implicit, _) = hold_implicit(SimConfig::default(), 4.0);
    eprintln!(
        "explicit PD: dt 0.002 peak wrist speed {peak2:.2} rad/s ({sat2} saturated wrist-steps), \
         dt 0.005 {peak5:.2} rad/s ({sat5}); implicit dt 0.002 {implicit:.4} rad/s"
    );
    assert!(
        peak2 > 5.0 && peak2 > 100.0 * implicit,
        "explicit dt 0.002: {peak2} rad/s"
    );
    assert!(sat2 > 1000, "explicit dt 0.002: only {sat2} saturated wrist-steps");
    assert!(peak5 > SPEED_GUARD, "explicit dt 0.005 stayed at {peak5} rad/s");
}

#[test]
fn applied_torque_is_the_clamped_actuator_force_and_faults_still_act() {
    require_deps();
    let mut sim = Simulator::load(ModelChoice::G1_29Dof, SimConfig::default()).unwrap();
    let mut cmd = rl_lab_arm_hold(&sim);
    // Wrist yaw far off target: saturates at its 5 N·m limit.
    cmd.motors[21].q += 1.0;
    sim.apply_command(&cmd).unwrap();
    sim.step_control_tick();
    assert_eq!(sim.applied_torque(21), 5.0);
    assert_eq!(sim.data().actuator_force()[21], 5.0);
    // Damping mode (kp 0, kd > 0): a torque opposing the motion only.
    sim.reset();
    sim.apply_command(&cmd).unwrap();
    for _ in 0..5 {
        sim.step_control_tick();
    }
    let mut damp = LowCommand::default();
    for m in &mut damp.motors[..29] {
        m.mode = MOTOR_MODE_ENABLED;
        m.kd = 0.1;
    }
    sim.apply_command(&damp).unwrap();
    let v_before = sim.data().qvel()[6 + 21];
    sim.step_control_tick();
    let tau = sim.applied_torque(21);
    assert!(v_before > 0.0 && tau < 0.0, "v {v_before}, tau {tau}");
    // The force is the law of the state at the start of the step, as MuJoCo evaluates it.
    let kd = 0.1f32 as f64;
    assert!(
        (tau + kd * v_before).abs() < 1e-9,
        "tau {tau} vs -kd·v {}",
        -kd * v_before
    );
    // Dead motor: zero; stuck encoder: the law of the fake reading, constant.
    sim.set_motor_fault(21, g1_sim::MotorFault::Dead);
    sim.step_control_tick();
    assert_eq!(sim.applied_torque(21), 0.0);
    sim.set_motor_fault(21, g1_sim::MotorFault::StuckEncoder { q: 0.1, dq: 0.0 });
    sim.apply_command(&cmd).unwrap();
    sim.step_control_tick();
    let expect = (40.0 * (cmd.motors[21].q as f64 - 0.1)).clamp(-5.0, 5.0);
    assert!((sim.applied_torque(21) - expect).abs() < 1e-12);
}

/// Robot geoms that can collide, by body name.
fn colliding_robot_bodies(sim: &Simulator) -> Vec<String> {
    let m = sim.data().model();
    let mut v: Vec<String> = (0..m.ngeom() as usize)
        .filter(|&g| m.body_weldid()[m.geom_bodyid()[g] as usize] != 0)
        .filter(|&g| m.geom_contype()[g] != 0 || m.geom_conaffinity()[g] != 0)
        .map(|g| {
            m.id_to_name(MjtObjBase::mjOBJ_BODY, m.geom_bodyid()[g] as usize)
                .unwrap_or_default()
                .to_string()
        })
        .collect();
    v.dedup();
    v
}

fn training() -> SimConfig {
    SimConfig {
        physics: PhysicsProfile::Training,
        physics_dt: 0.005,
        control_dt: 0.02,
        ..SimConfig::default()
    }
}

#[test]
fn training_profile_collides_feet_and_shins_with_the_world_and_the_legs_with_each_other_and_stands() {
    require_deps();
    assert_eq!("training".parse::<PhysicsProfile>(), Ok(PhysicsProfile::Training));
    assert_eq!("deploy".parse::<PhysicsProfile>(), Ok(PhysicsProfile::Deploy));
    assert!("fast"
        .parse::<PhysicsProfile>()
        .unwrap_err()
        .contains("deploy or training"));
    assert_eq!("euler".parse::<g1_sim::Integrator>(), Ok(g1_sim::Integrator::Euler));
    assert!("rk4".parse::<g1_sim::Integrator>().is_err());
    let mut models = vec![ModelChoice::G1_29Dof];
    if have_12dof("training_profile_collides_feet_and_shins_with_the_world_and_the_legs_with_each_other_and_stands") {
        models.push(ModelChoice::G1_12Dof);
    }
    for choice in models {
        let mut sim = Simulator::load(choice.clone(), training()).unwrap();
        // No meshes (training renders nothing and collides primitives), and the same bodies: the
        // masses and inertias are the deploy profile's, bit for bit.
        let deploy = Simulator::load(choice.clone(), SimConfig::default()).unwrap();
        let (m, d) = (sim.data().model(), deploy.data().model());
        assert_eq!(m.ffi().nmesh, 0, "{choice}");
        assert!(d.ffi().nmesh > 0, "{choice}");
        assert!(
            (m.ffi().nbuffer as f64) < 0.2 * d.ffi().nbuffer as f64,
            "{choice}: model {} bytes against the deploy profile's {}",
            m.ffi().nbuffer,
            d.ffi().nbuffer
        );
        assert_eq!(m.body_mass(), d.body_mass(), "{choice}");
        assert_eq!(m.body_inertia(), d.body_inertia(), "{choice}");
        assert_eq!(m.body_ipos(), d.body_ipos(), "{choice}");
        drop(deploy);
        let m = sim.data().model();
        assert_eq!(m.opt().iterations, 10);
        assert!(m.dof_frictionloss().iter().all(|&f| f == 0.0));
        let bodies = colliding_robot_bodies(&sim);
        assert_eq!(
            bodies,
            [
                "left_hip_yaw_link",
                "left_knee_link",
                "left_ankle_roll_link",
                "right_hip_yaw_link",
                "right_knee_link",
                "right_ankle_roll_link"
            ],
            "{choice}"
        );
        let m = sim.data().model();
        for g in 0..m.ngeom() as usize {
            if m.geom_type()[g] == MjtGeomBase::mjGEOM_MESH {
                assert_eq!(
                    (m.geom_contype()[g], m.geom_conaffinity()[g]),
                    (0, 0),
                    "{choice}: mesh {g}"
                );
            }
        }
        sim.apply_command(&sim.hold_initial_pose_command()).unwrap();
        let mut max_contacts = 0;
        for _ in 0..100 {
            sim.step_control_tick();
            max_contacts = max_contacts.max(sim.data().contact().len());
        }
        let t = sim.truth();
        eprintln!(
            "{choice} training: z {:.3}, up to {max_contacts} contacts",
            t.base_pos[2]
        );
        assert!(t.base_pos[2] > 0.6, "{choice}: {t:?}");
        assert_eq!(t.foot_contact, [true, true], "{choice}");
        // Standing apart, no contact that is not robot-vs-world.
        let m = sim.data().model();
        for c in sim.data().contact() {
            let w = |g: i32| m.body_weldid()[m.geom_bodyid()[g as usize] as usize] == 0;
            assert!(w(c.geom[0]) != w(c.geom[1]), "{choice}: contact {:?}", c.geom);
        }
        // The legs meet each other (a policy trained without it learns a gait whose legs touch,
        // which the deployed model does not let pass), and nothing else of the robot does.
        let names = |g: usize| {
            let b = m.geom_bodyid()[g] as usize;
            m.id_to_name(MjtObjBase::mjOBJ_BODY, b).unwrap_or_default().to_string()
        };
        let pairs = |a: &str, b: &str| {
            let (ga, gb): (Vec<usize>, Vec<usize>) = (
                (0..m.ngeom() as usize).filter(|&g| names(g) == a).collect(),
                (0..m.ngeom() as usize).filter(|&g| names(g) == b).collect(),
            );
            ga.iter().any(|&x| {
                gb.iter().any(|&y| {
                    m.geom_contype()[x] & m.geom_conaffinity()[y] != 0
                        || m.geom_contype()[y] & m.geom_conaffinity()[x] != 0
                })
            })
        };
        for (a, b) in [
            ("left_hip_yaw_link", "right_hip_yaw_link"),
            ("left_knee_link", "right_ankle_roll_link"),
            ("left_hip_yaw_link", "right_knee_link"),
            ("left_ankle_roll_link", "right_ankle_roll_link"),
        ] {
            assert!(pairs(a, b), "{choice}: {a} and {b} must collide");
        }
        for (a, b) in [
            ("left_knee_link", "left_ankle_roll_link"),
            ("left_hip_yaw_link", "left_knee_link"),
            ("right_knee_link", "right_ankle_roll_link"),
        ] {
            assert!(!pairs(a, b), "{choice}: {a} and {b} (one leg) must not collide");
        }
    }
}

/// Holds the initial pose 1.5 s; the pelvis height.
fn settle(sim: &mut Simulator) -> f64 {
    sim.apply_command(&sim.hold_initial_pose_command()).unwrap();
    for _ in 0..750 {
        sim.step_control_tick();
    }
    sim.truth().base_pos[2]
}

#[test]
fn swapped_terrain_matches_a_compiled_world() {
    require_deps();
    // The training profile too (its lean collision filter once left the pool's mocap geoms
    // colliding with nothing: the robot fell through every pooled step).
    let training = SimConfig {
        physics: g1_sim::PhysicsProfile::Training,
        ..SimConfig::default()
    };
    let mut pooled = Simulator::load_with_terrain_capacity(ModelChoice::G1_29Dof, training, 24, 0).unwrap();
    let flat_z = settle(&mut pooled);
    pooled.set_world(&World::preset("stairs-down").unwrap()).unwrap();
    pooled.reset();
    let z = settle(&mut pooled);
    assert!(
        z > flat_z + 0.1,
        "training profile: stands at {z} on the raised landing? flat {flat_z}"
    );

    let mut pooled = Simulator::load_with_terrain_capacity(ModelChoice::G1_29Dof, SimConfig::default(), 24, 0).unwrap();
    assert_eq!(pooled.terrain_capacity(), (24, 0));
    let flat_z = settle(&mut pooled);
    for name in ["stairs-down", "stairs-up"] {
        let world = World::preset(name).unwrap();
        pooled.set_world(&world).unwrap();
        pooled.reset();
        assert_eq!(pooled.world().map(|w| w.name.as_str()), Some(name));
        let mut compiled = Simulator::load_in(ModelChoice::G1_29Dof, SimConfig::default(), Some(&world)).unwrap();
        assert_eq!(pooled.initial_qpos(), compiled.initial_qpos(), "{name}: start pose");
        assert_eq!(pooled.truth().terrain, compiled.truth().terrain, "{name}");
        let (zp, zc) = (settle(&mut pooled), settle(&mut compiled));
        eprintln!("{name}: pooled z {zp:.5}, compiled z {zc:.5}, flat {flat_z:.5}");
        assert!((zp - zc).abs() < 1e-3, "{name}: pooled {zp} vs compiled {zc}");
        if name == "stairs-down" {
            // Starts on the raised landing, and stands on it.
            assert!(zp > flat_z + 0.1, "{name}: {zp} vs flat {flat_z}");
        }
    }
    // A world needing more than the pool is refused, naming the fix.
    let mut small = Simulator::load_with_terrain_capacity(ModelChoice::G1_29Dof, SimConfig::default(), 2, 0).unwrap();
    let err = small.set_world(&World::preset("stairs-up").unwrap()).unwrap_err();
    assert!(matches!(err, SimError::PoolTooSmall { have_boxes: 2, .. }), "{err}");
    assert!(err.to_string().contains("load_with_terrain_capacity"), "{err}");
    assert!(small.world().is_none());
}

#[test]
fn randomisation_hooks_change_what_they_should() {
    require_deps();
    let mut sim = Simulator::load(ModelChoice::G1_29Dof, SimConfig::default()).unwrap();
    let (floor_mu, pelvis) = {
        let m = sim.data().model();
        let floor = m.name_to_id(MjtObjBase::mjOBJ_GEOM, "floor").unwrap();
        let pelvis = m.name_to_id(MjtObjBase::mjOBJ_BODY, "pelvis").unwrap();
        (m.geom_friction()[floor][0], pelvis)
    };
    sim.set_friction(0.5).unwrap();
    sim.set_friction(0.5).unwrap(); // scales the compiled value, never compounds
    let floor = sim.data().model().name_to_id(MjtObjBase::mjOBJ_GEOM, "floor").unwrap();
    assert_eq!(sim.data().model().geom_friction()[floor][0], 0.5 * floor_mu);
    assert!(sim.set_friction(f64::NAN).is_err() && sim.set_friction(0.0).is_err());

    let m0 = sim.data().model().body_mass()[pelvis];
    sim.set_added_base_mass(3.0).unwrap();
    assert_eq!(sim.data().model().body_mass()[pelvis], m0 + 3.0);
    assert!(sim.set_added_base_mass(-1e3).is_err());
    sim.set_added_base_mass(0.0).unwrap();

    // Motor strength scales output and limit; kp scale the commanded kp.
    let mut cmd = LowCommand::default();
    cmd.motors[3].mode = MOTOR_MODE_ENABLED;
    cmd.motors[3].q = sim.initial_qpos()[7 + 3] as f32 + 0.1;
    cmd.motors[3].kp = 100.0;
    let torque_with = |sim: &mut Simulator, cmd: &LowCommand| {
        sim.reset();
        sim.apply_command(cmd).unwrap();
        sim.step_control_tick();
        sim.applied_torque(3)
    };
    let torque = |sim: &mut Simulator| torque_with(sim, &cmd);
    let base = torque(&mut sim);
    sim.set_motor_strength(0.5).unwrap();
    assert!((torque(&mut sim) - 0.5 * base).abs() < 1e-9);
    sim.set_motor_strength(1.0).unwrap();
    sim.set_kp_scale(2.0).unwrap();
    assert!(
        (torque(&mut sim) - 2.0 * base).abs() < 1e-6,
        "{} vs {}",
        torque(&mut sim),
        base
    );
    sim.set_kp_scale(1.0).unwrap();
    let mut far = cmd;
    far.motors[3].q += 10.0; // saturates: the limit scales with the strength
    sim.set_motor_strength(0.5).unwrap();
    assert_eq!(torque_with(&mut sim, &far), 0.5 * 139.0);
    sim.set_motor_strength(1.0).unwrap();

    // Push: adds to the free joint's velocity.
    sim.reset();
    sim.push_base(0.3, -0.2).unwrap();
    assert_eq!(&sim.data().qvel()[..2], &[0.3, -0.2]);
    assert!(sim.push_base(f64::INFINITY, 0.0).is_err());

    // Initial pose: x, y, yaw offsets and joint offsets.
    sim.set_initial_xy_yaw(1.0, -2.0, 0.5).unwrap();
    let mut off = [0.0; NUM_MOTORS];
    off[3] = 0.05;
    sim.reset_with(&off, [0.1, 0.0, 0.0, 0.0, 0.0, 0.2]).unwrap();
    let t = sim.truth();
    assert!((t.base_pos[0] - 1.0).abs() < 1e-12 && (t.base_pos[1] + 2.0).abs() < 1e-12);
    assert!((g1_sim::quat_to_rpy(t.base_quat)[2] - 0.5).abs() < 1e-9);
    assert_eq!(sim.data().qpos()[7 + 3], sim.initial_qpos()[7 + 3] + 0.05);
    assert_eq!(sim.data().qvel()[0], 0.1);
    assert_eq!(sim.data().qvel()[5], 0.2);
    off[0] = f64::NAN;
    assert!(sim.reset_with(&off, [0.0; 6]).is_err());
}

/// The training aid's wrench (`g1-train ppo --assist-share`): twice the robot's weight, upward on
/// the base, lifts it off the ground where without it the limp robot sinks; a reset clears it.
#[test]
fn a_base_wrench_of_twice_the_robots_weight_lifts_it_and_a_reset_clears_it() {
    require_deps();
    let mut sim = Simulator::load(ModelChoice::G1_29Dof, SimConfig::default()).unwrap();
    let mass = sim.robot_mass();
    let total: f64 = sim.data().model().body_mass()[1..].iter().sum();
    assert!(
        (mass - total).abs() < 1e-9 && mass > 20.0,
        "robot mass {mass} kg, bodies {total} kg"
    );
    // Motors off for 0.4 s; the base's rise (negative: it sank).
    let rise = |sim: &mut Simulator, lift: f64| {
        sim.reset();
        sim.set_base_wrench([0.0, 0.0, lift], [0.0; 3]).unwrap();
        let z0 = sim.truth().base_pos[2];
        for _ in 0..200 {
            sim.step_control_tick();
        }
        sim.truth().base_pos[2] - z0
    };
    let (free, lifted) = (rise(&mut sim, 0.0), rise(&mut sim, 2.0 * mass * 9.81));
    assert!(free < -0.01, "rises {free} m without the wrench");
    assert!(lifted > 0.2, "rises {lifted} m at twice its weight (without: {free} m)");
    sim.reset();
    assert_eq!(
        sim.data()
            .xfrc_applied()
            .iter()
            .flatten()
            .filter(|v| **v != 0.0)
            .count(),
        0
    );
    assert!(sim.set_base_wrench([f64::NAN, 0.0, 0.0], [0.0; 3]).is_err());
    assert!(sim.set_base_wrench([0.0; 3], [0.0, f64::INFINITY, 0.0]).is_err());
}

/// `base_kinematics` (read by the trainer at every physics step) is exactly the base part of
/// `truth`, on a robot that falls and spins, so every component is exercised.
#[test]
fn base_kinematics_is_the_base_part_of_truth() {
    require_deps();
    let mut sim = Simulator::load(ModelChoice::G1_12Dof, training()).unwrap();
    sim.set_base_wrench([30.0, -20.0, 0.0], [5.0, 8.0, 12.0]).unwrap();
    let mut moved = 0.0f64;
    for _ in 0..150 {
        sim.step_control_tick();
        let (b, t) = (sim.base_kinematics(), sim.truth());
        assert_eq!(b.pos, t.base_pos);
        assert_eq!(b.quat, t.base_quat);
        assert_eq!(b.lin_vel_world, t.base_lin_vel_world);
        assert_eq!(b.lin_vel_body, t.base_lin_vel_body);
        assert_eq!(b.ang_vel_body, t.base_ang_vel_body);
        moved = moved.max(b.ang_vel_body.iter().fold(0.0, |m, w| m.max(w.abs())));
    }
    assert!(
        moved > 0.5,
        "the base never spun ({moved} rad/s): the check has no teeth"
    );
}

/// Episode resets with a swapped world and randomisation replay bit for bit.
#[test]
fn swaps_and_randomisation_are_deterministic() {
    require_deps();
    let run = || {
        let mut sim = Simulator::load_with_terrain_capacity(ModelChoice::G1_29Dof, training(), 24, 0).unwrap();
        let mut out = Vec::new();
        for (i, name) in ["stairs-up", "stairs-down"].into_iter().enumerate() {
            sim.set_world(&World::preset(name).unwrap()).unwrap();
            sim.set_friction(0.8 + 0.1 * i as f64).unwrap();
            sim.set_added_base_mass(1.5).unwrap();
            sim.set_kp_scale(0.9).unwrap();
            sim.set_motor_strength(1.1).unwrap();
            sim.set_initial_xy_yaw(0.1, 0.0, 0.2).unwrap();
            sim.reset();
            sim.apply_command(&sim.hold_initial_pose_command()).unwrap();
            for t in 0..100 {
                if t == 50 {
                    sim.push_base(0.3, 0.1).unwrap();
                }
                sim.step_control_tick();
            }
            out.extend_from_slice(sim.data().qpos());
        }
        out
    };
    let (a, b) = (run(), run());
    assert!(a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()));
}
