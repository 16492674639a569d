//! `g1_sim`: the MuJoCo side of the lock-stepped firmware bridge.
//!
//! - [`model`] loads a G1 MJCF (the 29-dof mjlab model by default, the 12-dof unitree_rl_gym model,
//!   or any file) and makes it drivable: floor, armature, one torque motor per unitree_hg slot,
//!   pelvis IMU.
//! - [`Simulator`] runs the robot's motor drivers. **Actuator model**: each slot is one MuJoCo
//!   general actuator (gear 1, gain 1, affine bias, `forcerange` = the effort limit) with
//!   `ctrl = tau_ff + kp·q_des + kd·dq_des` and `biasprm = [0, −kp, −kd]`, written into the model
//!   whenever the command (or a fault, or a randomisation hook) changes, so MuJoCo computes
//!   `tau = tau_ff + kp (q_des − q) + kd (dq_des − dq)` at every physics step and clamps it. With
//!   the `implicitfast` integrator the `−kd` term enters the step's mass matrix: the PD's damping
//!   is integrated implicitly. Computing the torque explicitly diverges once `kd·dt / I > 2`
//!   (unitree_rl_lab's kd 10 on a ~0.004 kg·m² wrist at dt 0.002: the wrists chatter bang-bang
//!   between ±5 N·m). MuJoCo drops the `−kd` derivative of an actuator saturated at its
//!   forcerange (its force is then constant), so the clamp stays exact. A stuck encoder (the driver
//!   sees a fake q, dq) stays explicit: a constant torque in `ctrl`, no bias; a dead or disabled
//!   motor gets zero. `tau_est` is MuJoCo's `actuator_force`, the clamped force applied. It fills
//!   unitree_hg [`LowState`]s and privileged [`Truth`].
//! - [`model::PhysicsProfile`] (`SimConfig::physics`): `Deploy` keeps the model's contacts and
//!   solver; `Training` is lean (10 solver iterations, no joint friction loss, only feet and shins
//!   colliding, only with the world) for RL rollouts.
//! - Terrain pool ([`Simulator::load_with_terrain_capacity`], [`Simulator::set_world`]): static
//!   boxes and cylinders preallocated as mocap bodies, so a trainer moves a robot onto a new stair
//!   world per episode without recompiling (pose in `mjData`, size in `mjModel`).
//! - Domain randomisation hooks for episode resets ([`Simulator::set_friction`] and friends).
//! - [`faults`] parses `--fault` specs into a tick-indexed [`faults::FaultPlan`] (dropped, delayed,
//!   corrupted frames, sensor and motor faults, disconnects) that the server injects.
//! - [`server`] serves one bridge client over a Unix or loopback TCP socket with the protocol in
//!   `sim_hal::bridge::protocol`; the `g1-sim` binary wraps it.
//!
//! The per-tick path (`apply_command` → `step_control_tick` → `low_state`, and the server's
//! message loop) does not allocate. Runs are deterministic: same model, config and commands give
//! bit-identical states (optional IMU noise comes from a seeded PRNG).
// The simulator never runs on the robot: std's math is fine here (see clippy.toml).
#![allow(clippy::disallowed_methods)]
pub mod dds_serve;
pub mod faults;
pub mod lidar;
pub mod model;
pub mod model_cache;
pub mod server;
pub mod slots;
pub mod world;

use std::path::PathBuf;

use hal::{ImuState, LowCommand, LowState, MotorState, MOTOR_MODE_ENABLED, NUM_MOTORS};
use labkit::rng::Rng;
pub use model::{ModelChoice, PhysicsProfile};
use model::{PoolGeom, SlotMap};
use mujoco_rs::prelude::*;
pub use sim_hal::bridge::Truth;

/// The floating base's pose and velocities ([`Simulator::base_kinematics`]), as in [`Truth`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BaseKinematics {
    /// Position in the world, m.
    pub pos: [f64; 3],
    /// Orientation, w x y z.
    pub quat: [f64; 4],
    /// Linear velocity, world frame, m/s.
    pub lin_vel_world: [f64; 3],
    /// Linear velocity, body frame, m/s.
    pub lin_vel_body: [f64; 3],
    /// Angular velocity, body frame, rad/s.
    pub ang_vel_body: [f64; 3],
}

/// Keeps MuJoCo from writing `MUJOCO_LOG.TXT` into the working directory: its warnings still go to
/// the console. Call first thing in `main`, before any thread or MuJoCo object exists.
pub fn no_mujoco_log_file() {
    use mujoco_rs::wrappers::mj_logging::{log_config, set_log_config};
    // SAFETY: called at the start of main, when no other thread uses MuJoCo's global configuration.
    unsafe { set_log_config(log_config().with_logto_file(false)) };
}

/// Errors of the simulator library.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    #[error("model file {path} not found: {hint}")]
    ModelMissing { path: PathBuf, hint: &'static str },
    #[error("model: {0}")]
    Model(String),
    #[error("config: {0}")]
    Config(String),
    #[error("command: non-finite {field} in motor slot {slot}")]
    NonFinite { field: &'static str, slot: usize },
    #[error(
        "terrain pool too small: the world needs {need_boxes} boxes and {need_cylinders} cylinders, \
         the pool has {have_boxes} and {have_cylinders}; load with a larger \
         Simulator::load_with_terrain_capacity"
    )]
    PoolTooSmall {
        need_boxes: usize,
        need_cylinders: usize,
        have_boxes: usize,
        have_cylinders: usize,
    },
    #[error("{what} = {value} is out of range: {hint}")]
    BadParameter {
        what: &'static str,
        value: f64,
        hint: &'static str,
    },
}

/// Timing and noise settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SimConfig {
    /// MuJoCo timestep, s.
    pub physics_dt: f64,
    /// Control tick, s; an integer multiple of `physics_dt`.
    pub control_dt: f64,
    /// Seeds the IMU noise generator (the only randomness).
    pub seed: u64,
    /// IMU errors (white noise, biases, attitude error). `None` (the default) keeps the output
    /// exactly the model's.
    pub imu_noise: Option<ImuNoise>,
    /// Solver and collision settings (default: the deploy-side model as shipped).
    pub physics: PhysicsProfile,
    /// MuJoCo integrator (default implicitfast: the PD's damping implicit).
    pub integrator: Integrator,
}

/// MuJoCo integrator. The PD actuator is the same under both; only its damping's integration
/// differs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Integrator {
    /// `implicitfast`: −kd (and joint damping) enter each step's mass matrix; stable at any kd.
    #[default]
    ImplicitFast,
    /// Semi-implicit Euler: the actuator force is evaluated from the state at the start of the
    /// step, exactly the explicit motor law of Unitree's reference loop (for parity checks).
    Euler,
}

impl std::str::FromStr for Integrator {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "implicitfast" => Ok(Self::ImplicitFast),
            "euler" => Ok(Self::Euler),
            _ => Err(format!("integrator '{s}': expected implicitfast or euler")),
        }
    }
}

/// Error model of the pelvis IMU, drawn from the seeded generator. Standard deviations.
///
/// - gyroscope: white noise per sample plus a constant bias per axis (drawn once per run);
/// - accelerometer: white noise per sample plus a constant bias per axis;
/// - attitude quaternion (the IMU's own filter): constant roll and pitch errors, and a yaw that
///   drifts at the gyro's z bias (no magnetometer), so the heading error grows over the run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImuNoise {
    pub gyro_std: f64,
    pub acc_std: f64,
    pub gyro_bias_std: f64,
    pub acc_bias_std: f64,
    pub attitude_std: f64,
}

impl ImuNoise {
    /// White noise only (the attitude quaternion stays exact).
    pub fn white(gyro_std: f64, acc_std: f64) -> Self {
        Self {
            gyro_std,
            acc_std,
            gyro_bias_std: 0.0,
            acc_bias_std: 0.0,
            attitude_std: 0.0,
        }
    }

    /// A consumer MEMS IMU on a walking robot, sampled at 500 Hz (`--imu-noise realistic`):
    /// - gyro white 0.01 rad/s per sample (≈0.036 °/s/√Hz, ~2.5× a BMI088's datasheet density,
    ///   for vibration), bias 0.005 rad/s (0.3 °/s, after start-up calibration);
    /// - accelerometer white 0.05 m/s² per sample (≈320 µg/√Hz, ~2× BMI088), bias 0.1 m/s²
    ///   (10 mg);
    /// - attitude: roll / pitch off by 0.01 rad (what a 10 mg accelerometer bias does to a
    ///   gravity-referenced filter), yaw drifting at the gyro z bias (0.1 rad per 20 s at 1σ).
    pub const REALISTIC: Self = Self {
        gyro_std: 0.01,
        acc_std: 0.05,
        gyro_bias_std: 0.005,
        acc_bias_std: 0.1,
        attitude_std: 0.01,
    };

    fn is_valid(&self) -> bool {
        [
            self.gyro_std,
            self.acc_std,
            self.gyro_bias_std,
            self.acc_bias_std,
            self.attitude_std,
        ]
        .iter()
        .all(|v| v.is_finite() && *v >= 0.0)
    }
}

impl std::str::FromStr for ImuNoise {
    type Err = String;
    /// `realistic`, `STD` (gyro and accelerometer), `GYRO_STD,ACC_STD`, or
    /// `GYRO_STD,ACC_STD,GYRO_BIAS,ACC_BIAS,ATTITUDE`.
    fn from_str(s: &str) -> Result<Self, String> {
        if s == "realistic" {
            return Ok(Self::REALISTIC);
        }
        let v: Vec<f64> = s
            .split(',')
            .map(|p| p.trim().parse::<f64>())
            .collect::<Result<_, _>>()
            .map_err(|e| format!("IMU noise '{s}': {e}; expected realistic, STD, G,A or G,A,GB,AB,ATT"))?;
        let n = match v.as_slice() {
            [x] => Self::white(*x, *x),
            [g, a] => Self::white(*g, *a),
            [g, a, gb, ab, att] => Self {
                gyro_std: *g,
                acc_std: *a,
                gyro_bias_std: *gb,
                acc_bias_std: *ab,
                attitude_std: *att,
            },
            _ => return Err(format!("IMU noise '{s}': give 1, 2 or 5 numbers, or `realistic`")),
        };
        if !n.is_valid() {
            return Err(format!("IMU noise '{s}': every value must be finite and >= 0"));
        }
        Ok(n)
    }
}

impl Default for SimConfig {
    fn default() -> Self {
        Self {
            physics_dt: 0.002,
            control_dt: 0.002,
            seed: 0,
            imu_noise: None,
            physics: PhysicsProfile::Deploy,
            integrator: Integrator::ImplicitFast,
        }
    }
}

impl SimConfig {
    /// Physics steps per control tick.
    pub fn substeps(&self) -> Result<u32, SimError> {
        if !(self.physics_dt.is_finite() && self.physics_dt > 0.0) {
            return Err(SimError::Config(format!("physics dt {} must be > 0", self.physics_dt)));
        }
        let r = self.control_dt / self.physics_dt;
        let n = r.round();
        if !(n >= 1.0 && (r - n).abs() < 1e-6 && n < 1e6) {
            return Err(SimError::Config(format!(
                "control dt {} must be a whole multiple (>= 1) of physics dt {}",
                self.control_dt, self.physics_dt
            )));
        }
        Ok(n as u32)
    }
}

/// One motor slot's command, widened to f64 once per control tick.
#[derive(Clone, Copy, Debug, Default)]
struct SlotCmd {
    enabled: bool,
    q: f64,
    dq: f64,
    tau: f64,
    kp: f64,
    kd: f64,
}

/// A simulated motor-driver fault (see [`Simulator::set_motor_fault`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum MotorFault {
    /// The driver runs its PD law on the joint's real state.
    #[default]
    Healthy,
    /// Stuck encoder: the driver's PD law sees this position (rad) and velocity (rad/s) instead of
    /// the joint's; the joint itself still moves under the resulting torque.
    StuckEncoder { q: f64, dq: f64 },
    /// The driver produces no torque at all.
    Dead,
}

/// The simulated G1 with its motor drivers.
pub struct Simulator {
    data: MjData<Box<MjModel>>,
    slots: Vec<SlotMap>,
    present: u64,
    cmd: [SlotCmd; NUM_MOTORS],
    motor_fault: [MotorFault; NUM_MOTORS],
    /// Some slot is not `Healthy`: the physics step only looks at `motor_fault` when set, so the
    /// fault-free path stays as it was.
    any_motor_fault: bool,
    /// Torque applied at the last physics step, per slot.
    tau_applied: [f64; NUM_MOTORS],
    initial_qpos: Vec<f64>,
    config: SimConfig,
    substeps: u32,
    steps: u64,
    mode_machine: u8,
    pelvis_body: usize,
    root_qpos_adr: Option<usize>,
    root_dof_adr: Option<usize>,
    gyro_adr: usize,
    acc_adr: usize,
    foot_side: Vec<u8>,
    robot_root: i32,
    rng: Rng,
    /// Noise sample for the current tick: gyro xyz, accelerometer xyz.
    imu_noise_now: [f64; 6],
    /// Per-run biases: gyro xyz, accelerometer xyz; then roll and pitch error of the attitude.
    imu_bias: [f64; 6],
    attitude_offset: [f64; 2],
    world: Option<world::World>,
    lidar: Option<Box<LidarRig>>,
    /// Terrain pool (empty unless loaded with a capacity) and the pose each pooled geom takes
    /// after a reset (mocap poses live in `mjData`, which a reset rewinds).
    pool_boxes: Vec<PoolGeom>,
    pool_cylinders: Vec<PoolGeom>,
    pool_pose: Vec<([f64; 3], [f64; 4])>,
    /// Domain randomisation (1, 1, 0 = off): torque output and limit scale, commanded-kp scale.
    motor_strength: f64,
    kp_scale: f64,
    /// Geom friction and body mass as compiled, so the hooks scale from them, not compound.
    friction0: Vec<[f64; 3]>,
    pelvis_mass0: f64,
    pelvis_inertia0: [f64; 3],
    /// Added to the initial root x, y and yaw at every reset (`set_initial_xy_yaw`).
    start_offset: [f64; 3],
    /// The initial `qpos` on flat ground at the origin, before any world's start pose.
    base_qpos: Vec<f64>,
    /// What the model cache did at load (`$G1_SIM_MODEL_CACHE`), if one is configured.
    model_cache_note: Option<String>,
    /// The test gantry's rope ([`Simulator::hang_on_gantry`]) and where it is tied, if hung.
    gantry: Option<(Gantry, [f64; 3])>,
}

/// A rope from a point above the robot's start pose to its pelvis, as on a test gantry (or
/// unitree_mujoco's elastic band): slack while the robot stands, it catches a fall. Long runs
/// with faults (each trip damps the motors, and a damped robot sinks) then go on standing after
/// each operator reset instead of lying on the floor.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Gantry {
    /// Rope length minus the tie point's height above the pelvis at the start pose, m: how far
    /// the pelvis may sink (or, further, sway) before the rope pulls.
    pub slack_m: f64,
    /// Height of the tie point above the start pelvis, m.
    pub height_m: f64,
    /// Rope stiffness (N/m) and damping (N·s/m) while taut.
    pub stiffness: f64,
    pub damping: f64,
}

impl Default for Gantry {
    fn default() -> Self {
        // Taut 5 cm below the standing pelvis or 0.32 m to either side of the tie point; the
        // 35 kg robot hangs on it ~4 cm further down (a damped robot's knees barely bend, so a
        // start-up from there is a start-up from standing), close to critically damped.
        Self {
            slack_m: 0.05,
            height_m: 1.0,
            stiffness: 8000.0,
            damping: 1000.0,
        }
    }
}

impl Gantry {
    /// The rope's pull on a pelvis at `pos` moving at `vel` (world frame), tied at `anchor`: along
    /// the rope, never pushing.
    pub fn force(&self, anchor: [f64; 3], pos: [f64; 3], vel: [f64; 3]) -> [f64; 3] {
        let d = [anchor[0] - pos[0], anchor[1] - pos[1], anchor[2] - pos[2]];
        let dist = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        let stretch = dist - (self.height_m + self.slack_m);
        if stretch <= 0.0 || dist == 0.0 {
            return [0.0; 3];
        }
        let u = [d[0] / dist, d[1] / dist, d[2] / dist];
        // The stretch grows as the pelvis moves away from the tie point.
        let stretch_rate = -(vel[0] * u[0] + vel[1] * u[1] + vel[2] * u[2]);
        let tension = (self.stiffness * stretch + self.damping * stretch_rate).max(0.0);
        [tension * u[0], tension * u[1], tension * u[2]]
    }
}

/// The simulated MID-360 and its packet stream, with per-tick buffers sized at attach time.
struct LidarRig {
    sensor: lidar::LidarSim,
    stream: lidar::LivoxStream,
    returns: Vec<lidar::Return>,
    datagrams: Vec<u8>,
}

impl Simulator {
    /// Loads and prepares `choice` and puts it in its initial state.
    pub fn load(choice: ModelChoice, config: SimConfig) -> Result<Self, SimError> {
        Self::load_in(choice, config, None)
    }

    /// [`Simulator::load`] in a terrain world (stairs); the robot starts on the world's start pose.
    pub fn load_in(choice: ModelChoice, config: SimConfig, world: Option<&world::World>) -> Result<Self, SimError> {
        let cache = model_cache::dir_from_env();
        Self::load_full(choice, config, world, model::TerrainPool::default(), cache.as_deref())
    }

    /// [`Simulator::load_in`] with an explicit model cache directory (`None`: always compile),
    /// instead of `$G1_SIM_MODEL_CACHE`. See [`model_cache`].
    pub fn load_with_model_cache(
        choice: ModelChoice,
        config: SimConfig,
        world: Option<&world::World>,
        cache_dir: Option<&std::path::Path>,
    ) -> Result<Self, SimError> {
        Self::load_full(choice, config, world, model::TerrainPool::default(), cache_dir)
    }

    /// [`Simulator::load`] with a pool of `n_boxes` static boxes and `n_cylinders` cylinders that
    /// [`Simulator::set_world`] fills with a terrain world per episode, without recompiling. The
    /// robot starts on flat ground until a world is set.
    pub fn load_with_terrain_capacity(
        choice: ModelChoice,
        config: SimConfig,
        n_boxes: usize,
        n_cylinders: usize,
    ) -> Result<Self, SimError> {
        let pool = model::TerrainPool {
            boxes: n_boxes,
            cylinders: n_cylinders,
        };
        let cache = model_cache::dir_from_env();
        Self::load_full(choice, config, None, pool, cache.as_deref())
    }

    fn load_full(
        choice: ModelChoice,
        config: SimConfig,
        world: Option<&world::World>,
        pool: model::TerrainPool,
        cache_dir: Option<&std::path::Path>,
    ) -> Result<Self, SimError> {
        let substeps = config.substeps()?;
        if let Some(n) = config.imu_noise {
            if !n.is_valid() {
                return Err(SimError::Config(format!(
                    "IMU noise {n:?}: every value must be finite and >= 0"
                )));
            }
        }
        let l = model::load(&choice, &config, world, pool, cache_dir)?;
        let robot_root = l.model.body_rootid()[l.pelvis_body];
        let friction0 = l.model.geom_friction().to_vec();
        let pelvis_mass0 = l.model.body_mass()[l.pelvis_body];
        let pelvis_inertia0 = l.model.body_inertia()[l.pelvis_body];
        let pool_pose =
            vec![([0.0, 0.0, model::POOL_PARK_Z], [1.0, 0.0, 0.0, 0.0]); l.pool_boxes.len() + l.pool_cylinders.len()];
        let data = MjData::new(Box::new(l.model));
        let mut sim = Self {
            data,
            slots: l.slots,
            present: l.present,
            cmd: [SlotCmd::default(); NUM_MOTORS],
            motor_fault: [MotorFault::Healthy; NUM_MOTORS],
            any_motor_fault: false,
            tau_applied: [0.0; NUM_MOTORS],
            initial_qpos: l.initial_qpos,
            config,
            substeps,
            steps: 0,
            mode_machine: l.mode_machine,
            pelvis_body: l.pelvis_body,
            root_qpos_adr: l.root_qpos_adr,
            root_dof_adr: l.root_dof_adr,
            gyro_adr: l.gyro_adr,
            acc_adr: l.acc_adr,
            foot_side: l.foot_side,
            robot_root,
            rng: Rng(config.seed),
            imu_noise_now: [0.0; 6],
            imu_bias: [0.0; 6],
            attitude_offset: [0.0; 2],
            world: world.cloned(),
            lidar: None,
            pool_boxes: l.pool_boxes,
            pool_cylinders: l.pool_cylinders,
            pool_pose,
            motor_strength: 1.0,
            kp_scale: 1.0,
            friction0,
            pelvis_mass0,
            pelvis_inertia0,
            start_offset: [0.0; 3],
            gantry: None,
            base_qpos: l.base_qpos,
            model_cache_note: l.cache_note,
        };
        sim.reset();
        Ok(sim)
    }

    /// What the model cache (`$G1_SIM_MODEL_CACHE`, [`model_cache`]) did at load: loaded, compiled
    /// and stored, or why it could not be used. `None` without a cache.
    pub fn model_cache_note(&self) -> Option<&str> {
        self.model_cache_note.as_deref()
    }

    /// Back to the initial state: all motors disabled and healthy, step counter 0, noise generator
    /// reseeded, the robot on the world's start pose (plus [`Simulator::set_initial_xy_yaw`]).
    /// Domain randomisation settings stay until changed.
    pub fn reset(&mut self) {
        self.reset_state();
        self.finish_reset();
    }

    /// [`Simulator::reset`], then the initial state offset: `joint_offsets[slot]` (rad) added to each
    /// present slot's joint angle, `base_vel` (world linear xyz, body angular xyz) given to the free
    /// joint. Rejects non-finite values (the state is then reset without offsets).
    pub fn reset_with(&mut self, joint_offsets: &[f64; NUM_MOTORS], base_vel: [f64; 6]) -> Result<(), SimError> {
        self.reset_state();
        let bad = joint_offsets.iter().chain(&base_vel).position(|v| !v.is_finite());
        if let Some(i) = bad {
            self.finish_reset();
            return Err(SimError::BadParameter {
                what: if i < NUM_MOTORS {
                    "reset_with joint offset"
                } else {
                    "reset_with base velocity"
                },
                value: f64::NAN,
                hint: "give finite offsets and velocities",
            });
        }
        {
            let q = self.data.qpos_mut();
            for s in &self.slots {
                q[s.qpos_adr] += joint_offsets[s.slot];
            }
        }
        if let Some(da) = self.root_dof_adr {
            self.data.qvel_mut()[da..da + 6].copy_from_slice(&base_vel);
        }
        self.finish_reset();
        Ok(())
    }

    fn reset_state(&mut self) {
        self.motor_fault = [MotorFault::Healthy; NUM_MOTORS];
        self.any_motor_fault = false;
        self.data.reset();
        self.data.qpos_mut().copy_from_slice(&self.initial_qpos);
        if let Some(qa) = self.root_qpos_adr {
            let [dx, dy, dyaw] = self.start_offset;
            // Yaw about the start pose's own position, then the xy shift.
            let q = self.data.qpos_mut();
            let r = [(0.5 * dyaw).cos(), 0.0, 0.0, (0.5 * dyaw).sin()];
            let o = [q[qa + 3], q[qa + 4], q[qa + 5], q[qa + 6]];
            q[qa + 3..qa + 7].copy_from_slice(&quat_mul(r, o));
            q[qa] += dx;
            q[qa + 1] += dy;
        }
        self.write_pool_poses();
        self.cmd = [SlotCmd::default(); NUM_MOTORS];
        self.tau_applied = [0.0; NUM_MOTORS];
        self.steps = 0;
    }

    fn finish_reset(&mut self) {
        self.sync_actuators();
        // Positions, velocities and sensors of the initial state, so the first LowState is real.
        self.data.forward();
        self.rng = Rng(self.config.seed);
        // Biases first, so the same seed gives the same biases whatever the run length.
        if let Some(n) = self.config.imu_noise {
            for (i, b) in self.imu_bias.iter_mut().enumerate() {
                *b = self.rng.gaussian() * if i < 3 { n.gyro_bias_std } else { n.acc_bias_std };
            }
            for o in &mut self.attitude_offset {
                *o = self.rng.gaussian() * n.attitude_std;
            }
        }
        self.draw_noise();
    }

    /// Latches a command; it acts at every physics step until the next one. Rejects non-finite
    /// fields (the decoder already does for wire frames) so NaN never reaches the physics.
    pub fn apply_command(&mut self, cmd: &LowCommand) -> Result<(), SimError> {
        for (slot, m) in cmd.motors.iter().enumerate() {
            for (field, v) in [("q", m.q), ("dq", m.dq), ("tau", m.tau), ("kp", m.kp), ("kd", m.kd)] {
                if !v.is_finite() {
                    return Err(SimError::NonFinite { field, slot });
                }
            }
        }
        for (c, m) in self.cmd.iter_mut().zip(&cmd.motors) {
            *c = SlotCmd {
                enabled: m.mode == MOTOR_MODE_ENABLED,
                q: m.q as f64,
                dq: m.dq as f64,
                tau: m.tau as f64,
                kp: m.kp as f64,
                kd: m.kd as f64,
            };
        }
        self.sync_actuators();
        Ok(())
    }

    /// Injects (or clears, with `Healthy`) a driver fault on motor slot `slot`; it acts from the
    /// next physics step until changed. Slots the model does not drive are ignored (they have no
    /// driver), as are slots past the 35 of unitree_hg.
    pub fn set_motor_fault(&mut self, slot: usize, fault: MotorFault) {
        if let Some(f) = self.motor_fault.get_mut(slot) {
            *f = fault;
        }
        self.any_motor_fault = self.motor_fault.iter().any(|f| *f != MotorFault::Healthy);
        self.sync_actuators();
    }

    /// The driver fault currently injected on `slot`.
    pub fn motor_fault(&self, slot: usize) -> MotorFault {
        self.motor_fault.get(slot).copied().unwrap_or_default()
    }

    /// Writes the latched command, faults and randomisation into each slot's PD actuator:
    /// `ctrl = tau_ff + kp·q_des + kd·dq_des`, `biasprm = [0, −kp, −kd]` (both times the motor
    /// strength, as is the force range), so MuJoCo's force is the motor law of every physics step.
    /// A stuck encoder's law is a constant torque (its q, dq are fixed), written to `ctrl` with no
    /// bias; a disabled or dead motor gets nothing.
    fn sync_actuators(&mut self) {
        let (strength, kp_scale) = (self.motor_strength, self.kp_scale);
        let mut ctrl_of = [0.0f64; NUM_MOTORS];
        // SAFETY: only the values of existing per-actuator parameters change (gain, bias, force
        // range); no size, count, index or address of the model, so `data` stays consistent.
        let m = unsafe { self.data.model_mut() };
        for s in &self.slots {
            let c = &self.cmd[s.slot];
            let (kp, kd) = (c.kp * kp_scale, c.kd);
            let fault = if self.any_motor_fault {
                self.motor_fault[s.slot]
            } else {
                MotorFault::Healthy
            };
            let (ctrl, bkp, bkd) = match (c.enabled, fault) {
                (false, _) | (_, MotorFault::Dead) => (0.0, 0.0, 0.0),
                (true, MotorFault::StuckEncoder { q, dq }) => {
                    let raw = c.tau + kp * (c.q - q) + kd * (c.dq - dq);
                    (raw.clamp(s.tau_lo, s.tau_hi), 0.0, 0.0)
                }
                (true, MotorFault::Healthy) => (c.tau + kp * c.q + kd * c.dq, kp, kd),
            };
            ctrl_of[s.slot] = ctrl;
            let a = s.actuator;
            // SAFETY: gainprm[0] of a fixed-gain actuator is a plain gain, never read as an index.
            let gain = unsafe { m.actuator_gainprm_mut() };
            gain[a][0] = strength;
            let b = &mut m.actuator_biasprm_mut()[a];
            b[0] = 0.0;
            b[1] = -bkp * strength;
            b[2] = -bkd * strength;
            m.actuator_forcerange_mut()[a] = [s.tau_lo * strength, s.tau_hi * strength];
        }
        let ctrl = self.data.ctrl_mut();
        for s in &self.slots {
            ctrl[s.actuator] = ctrl_of[s.slot];
        }
    }

    /// One physics step; the applied torque is the (clamped) force MuJoCo computed for it.
    fn physics_step(&mut self) {
        if let Some((rope, anchor)) = self.gantry {
            let b = self.base_kinematics();
            let f = rope.force(anchor, b.pos, b.lin_vel_world);
            let x = &mut self.data.xfrc_applied_mut()[self.pelvis_body];
            x[..3].copy_from_slice(&f);
        }
        self.data.step();
        let f = self.data.actuator_force();
        for s in &self.slots {
            self.tau_applied[s.slot] = f[s.actuator];
        }
        self.steps += 1;
    }

    /// Fills the terrain pool with `world`'s geoms (pose into `mjData`'s mocap slots, size and
    /// bounds into the model) and parks the unused ones; the next [`Simulator::reset`] puts the
    /// robot on the world's start pose. [`Simulator::world`] and [`Simulator::truth`] use it at
    /// once. Errors (changing nothing) if the pool is too small.
    pub fn set_world(&mut self, world: &world::World) -> Result<(), SimError> {
        let prims = world.primitives();
        let need_boxes = prims
            .iter()
            .filter(|p| matches!(p, world::Primitive::Box { .. }))
            .count();
        let need_cylinders = prims.len() - need_boxes;
        if need_boxes > self.pool_boxes.len() || need_cylinders > self.pool_cylinders.len() {
            return Err(SimError::PoolTooSmall {
                need_boxes,
                need_cylinders,
                have_boxes: self.pool_boxes.len(),
                have_cylinders: self.pool_cylinders.len(),
            });
        }
        let park = ([0.0, 0.0, model::POOL_PARK_Z], [1.0, 0.0, 0.0, 0.0]);
        self.pool_pose.iter_mut().for_each(|p| *p = park);
        let nb = self.pool_boxes.len();
        let (mut ib, mut ic) = (0, 0);
        // SAFETY: only geom sizes, bounding radii and boxes and the bodies' BVH boxes change, not
        // any size, count, index or address of the model.
        let m = unsafe { self.data.model_mut() };
        for p in &prims {
            let (g, slot, pose, half) = match *p {
                world::Primitive::Box { pos, quat, half } => {
                    ib += 1;
                    (self.pool_boxes[ib - 1], ib - 1, (pos, quat), half)
                }
                world::Primitive::Cylinder {
                    pos,
                    quat,
                    radius,
                    half_len,
                } => {
                    ic += 1;
                    (
                        self.pool_cylinders[ic - 1],
                        nb + ic - 1,
                        (pos, quat),
                        [radius, radius, half_len],
                    )
                }
            };
            let size = if slot < nb { half } else { [half[0], half[2], 0.0] };
            m.geom_size_mut()[g.geom] = size;
            // Geom and body frames coincide (one geom per pool body at its origin), so the local
            // bounding box is centred with the half extents, for the geom and the body's BVH root.
            let aabb = [0.0, 0.0, 0.0, half[0], half[1], half[2]];
            m.geom_aabb_mut()[g.geom] = aabb;
            m.geom_rbound_mut()[g.geom] = if slot < nb {
                (half[0] * half[0] + half[1] * half[1] + half[2] * half[2]).sqrt()
            } else {
                (half[0] * half[0] + half[2] * half[2]).sqrt()
            };
            let bvh = m.body_bvhadr()[g.body];
            if bvh >= 0 {
                m.bvh_aabb_mut()[bvh as usize] = aabb;
            }
            self.pool_pose[slot] = pose;
        }
        self.world = Some(world.clone());
        self.initial_qpos.copy_from_slice(&self.base_qpos);
        if let Some(qa) = self.root_qpos_adr {
            model::place_on_start(&mut self.initial_qpos, qa, world.start());
        }
        self.write_pool_poses();
        self.data.forward();
        Ok(())
    }

    /// Writes each pool geom's pose into its mocap slot.
    fn write_pool_poses(&mut self) {
        let all = self.pool_boxes.iter().chain(&self.pool_cylinders);
        for (g, (pos, quat)) in all.zip(&self.pool_pose) {
            self.data.mocap_pos_mut()[g.mocap] = *pos;
            self.data.mocap_quat_mut()[g.mocap] = *quat;
        }
    }

    /// Number of pooled terrain boxes and cylinders (0, 0 without a pool).
    pub fn terrain_capacity(&self) -> (usize, usize) {
        (self.pool_boxes.len(), self.pool_cylinders.len())
    }

    /// Domain randomisation: every geom's friction becomes `scale` × its compiled value (feet,
    /// shins and terrain alike; MuJoCo takes the larger of a pair's, so scaling all keeps the
    /// contact's friction scaled by `scale`). Acts until changed; `scale` must be finite and > 0.
    pub fn set_friction(&mut self, scale: f64) -> Result<(), SimError> {
        check_positive("friction scale", scale)?;
        // SAFETY: only friction values change, no size, count, index or address of the model.
        let m = unsafe { self.data.model_mut() };
        for (f, f0) in m.geom_friction_mut().iter_mut().zip(&self.friction0) {
            *f = f0.map(|v| v * scale);
        }
        Ok(())
    }

    /// Domain randomisation: adds `kg` (may be negative, down to −half the pelvis mass) to the
    /// pelvis, scaling its inertia with it. Acts from the next step (a reset re-derives the
    /// composite inertias); replaces any earlier added mass.
    pub fn set_added_base_mass(&mut self, kg: f64) -> Result<(), SimError> {
        if !(kg.is_finite() && kg > -0.5 * self.pelvis_mass0) {
            return Err(SimError::BadParameter {
                what: "added base mass (kg)",
                value: kg,
                hint: "must be finite and above minus half the pelvis mass",
            });
        }
        let (b, ratio) = (self.pelvis_body, (self.pelvis_mass0 + kg) / self.pelvis_mass0);
        // SAFETY: only the pelvis's mass and inertia values change, no size, count, index or
        // address of the model.
        let m = unsafe { self.data.model_mut() };
        m.body_mass_mut()[b] = self.pelvis_mass0 + kg;
        m.body_inertia_mut()[b] = self.pelvis_inertia0.map(|v| v * ratio);
        Ok(())
    }

    /// Domain randomisation: every motor's output and torque limit × `scale` (a weaker or stronger
    /// drive). Acts from the next physics step; `scale` must be finite and > 0.
    pub fn set_motor_strength(&mut self, scale: f64) -> Result<(), SimError> {
        check_positive("motor strength", scale)?;
        self.motor_strength = scale;
        self.sync_actuators();
        Ok(())
    }

    /// Domain randomisation: the commanded kp of every motor × `scale` (the drive's gain error).
    /// Acts from the next physics step; `scale` must be finite and >= 0.
    pub fn set_kp_scale(&mut self, scale: f64) -> Result<(), SimError> {
        if !(scale.is_finite() && scale >= 0.0) {
            return Err(SimError::BadParameter {
                what: "kp scale",
                value: scale,
                hint: "must be finite and >= 0",
            });
        }
        self.kp_scale = scale;
        self.sync_actuators();
        Ok(())
    }

    /// Domain randomisation: adds `(dvx, dvy)` m/s (world frame) to the free joint's velocity now.
    pub fn push_base(&mut self, dvx: f64, dvy: f64) -> Result<(), SimError> {
        if !(dvx.is_finite() && dvy.is_finite()) {
            return Err(SimError::BadParameter {
                what: "push velocity",
                value: if dvx.is_finite() { dvy } else { dvx },
                hint: "give finite velocities",
            });
        }
        if let Some(da) = self.root_dof_adr {
            let v = self.data.qvel_mut();
            v[da] += dvx;
            v[da + 1] += dvy;
        }
        Ok(())
    }

    /// Training aid: a force and a torque (world frame, N and N·m) on the base body at its centre
    /// of mass, held until changed; a reset clears it. The robot has no such thing: only
    /// `g1-train`'s assisted episodes use it (a helping hand that explores climbs the policy cannot
    /// yet do alone, decayed to nothing). Rejects non-finite values.
    pub fn set_base_wrench(&mut self, force: [f64; 3], torque: [f64; 3]) -> Result<(), SimError> {
        if let Some(bad) = force.iter().chain(&torque).find(|v| !v.is_finite()) {
            return Err(SimError::BadParameter {
                what: "base wrench",
                value: *bad,
                hint: "give finite forces and torques",
            });
        }
        let b = self.pelvis_body;
        self.data.xfrc_applied_mut()[b] = [force[0], force[1], force[2], torque[0], torque[1], torque[2]];
        Ok(())
    }

    /// Hangs the robot on a test gantry's rope ([`Gantry`]), tied above the pelvis as it is now
    /// (call after a reset: the start pose) and kept there across resets; `None` takes it down.
    /// The rope's force replaces a base wrench's force ([`Simulator::set_base_wrench`]): the two
    /// are for different tools and do not combine.
    pub fn hang_on_gantry(&mut self, gantry: Option<Gantry>) -> Result<(), SimError> {
        let Some(g) = gantry else {
            self.gantry = None;
            self.data.xfrc_applied_mut()[self.pelvis_body][..3].fill(0.0);
            return Ok(());
        };
        for (what, v) in [
            ("gantry slack", g.slack_m),
            ("gantry height", g.height_m),
            ("gantry stiffness", g.stiffness),
            ("gantry damping", g.damping),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(SimError::BadParameter {
                    what,
                    value: v,
                    hint: "give a finite value >= 0",
                });
            }
        }
        let p = self.base_kinematics().pos;
        self.gantry = Some((g, [p[0], p[1], p[2] + g.height_m]));
        Ok(())
    }

    /// The robot's mass, kg (every body under the base, as compiled; added base mass not included).
    pub fn robot_mass(&self) -> f64 {
        self.data.model().body_subtreemass()[self.pelvis_body]
    }

    /// From the next reset on, the robot starts moved by `(x, y)` m and turned by `yaw` rad (about
    /// its start position) from the world's start pose.
    pub fn set_initial_xy_yaw(&mut self, x: f64, y: f64, yaw: f64) -> Result<(), SimError> {
        if !(x.is_finite() && y.is_finite() && yaw.is_finite()) {
            return Err(SimError::BadParameter {
                what: "initial x, y, yaw",
                value: f64::NAN,
                hint: "give finite values",
            });
        }
        self.start_offset = [x, y, yaw];
        Ok(())
    }

    /// Advances one control tick (`control_dt / physics_dt` physics steps); an attached lidar
    /// fires the points due during the tick from the pose at its end.
    pub fn step_control_tick(&mut self) {
        let t0_ns = self.time_ns();
        for _ in 0..self.substeps {
            self.physics_step();
        }
        self.draw_noise();
        if let Some(rig) = self.lidar.as_deref_mut() {
            let t1_ns = (self.data.time() * 1e9).round() as u64;
            rig.returns.clear();
            rig.datagrams.clear();
            rig.sensor.scan(&mut self.data, t0_ns, t1_ns, &mut rig.returns);
            rig.stream.push(&rig.returns, &mut rig.datagrams);
        }
    }

    fn time_ns(&self) -> u64 {
        (self.data.time() * 1e9).round() as u64
    }

    /// Mounts a simulated MID-360 (see [`lidar`]). From then on every control tick produces Livox
    /// datagrams ([`Simulator::lidar_datagrams`]).
    pub fn attach_lidar(&mut self, cfg: lidar::LidarConfig) -> Result<(), SimError> {
        let per_tick = (cfg.points_per_second * self.config.control_dt).ceil() as usize + 8;
        let sensor = lidar::LidarSim::new(self.data.model(), cfg, per_tick)?;
        let packets = per_tick / sensor_io::livox::MID360_POINTS_PER_PACKET + 2;
        self.lidar = Some(Box::new(LidarRig {
            sensor,
            stream: lidar::LivoxStream::new(cfg.frame_hz),
            returns: Vec::with_capacity(per_tick),
            datagrams: Vec::with_capacity(packets * (2 + sensor_io::livox::cartesian_high_len(96))),
        }));
        Ok(())
    }

    /// The Livox datagrams of the last control tick, length-prefixed (empty without a lidar).
    pub fn lidar_datagrams(&self) -> &[u8] {
        self.lidar.as_ref().map_or(&[], |r| &r.datagrams)
    }

    pub fn has_lidar(&self) -> bool {
        self.lidar.is_some()
    }

    /// The terrain world, if any.
    pub fn world(&self) -> Option<&world::World> {
        self.world.as_ref()
    }

    fn draw_noise(&mut self) {
        if let Some(noise) = self.config.imu_noise {
            for (i, n) in self.imu_noise_now.iter_mut().enumerate() {
                let white = self.rng.gaussian() * if i < 3 { noise.gyro_std } else { noise.acc_std };
                *n = white + self.imu_bias[i];
            }
        }
    }

    /// Pelvis orientation (w, x, y, z): the free joint's quaternion, or the body's world
    /// orientation for a model without one.
    fn base_quat(&self) -> [f64; 4] {
        match self.root_qpos_adr {
            Some(a) => {
                let q = &self.data.qpos()[a + 3..a + 7];
                [q[0], q[1], q[2], q[3]]
            }
            None => self.data.xquat()[self.pelvis_body],
        }
    }

    /// Fills `out` with what the robot would report now. Absent slots read as all zeros.
    ///
    /// The gyroscope is the pelvis's body-frame angular velocity of the current state (models with
    /// a free root); the accelerometer comes from MuJoCo's sensor on `imu_in_pelvis`, which
    /// `mj_step` evaluates before integrating, so it is one physics step older than `q` / `dq`.
    /// `ddq` is the joint acceleration of that last step.
    pub fn low_state(&self, out: &mut LowState) {
        out.version = [1, 0];
        out.mode_pr = 0;
        out.mode_machine = self.mode_machine;
        out.tick = self.steps as u32; // wraps like the robot's counter
        let quat = self.base_quat();
        let sd = self.data.sensordata();
        let n = &self.imu_noise_now;
        // The gyro sensor is evaluated inside `mj_step` before integration, one physics step older
        // than qpos/qvel. A real IMU samples rate and attitude together, and Unitree's reference
        // loop reads the free joint's body-frame angular velocity, so use that when the model has
        // a free root (the IMU site is axis-aligned with the pelvis in both G1 models).
        let w = match self.root_dof_adr {
            Some(da) => {
                let v = self.data.qvel();
                [v[da + 3], v[da + 4], v[da + 5]]
            }
            None => [sd[self.gyro_adr], sd[self.gyro_adr + 1], sd[self.gyro_adr + 2]],
        };
        let gyro = [w[0] + n[0], w[1] + n[1], w[2] + n[2]];
        let acc = [
            sd[self.acc_adr] + n[3],
            sd[self.acc_adr + 1] + n[4],
            sd[self.acc_adr + 2] + n[5],
        ];
        // The IMU's own attitude filter: off in roll and pitch, drifting in yaw.
        let quat = if self.config.imu_noise.is_some() {
            let yaw_drift = self.imu_bias[2] * self.data.time();
            let err = quat_mul(
                axis_angle_quat(2, yaw_drift),
                quat_mul(
                    axis_angle_quat(0, self.attitude_offset[0]),
                    axis_angle_quat(1, self.attitude_offset[1]),
                ),
            );
            quat_mul(err, quat)
        } else {
            quat
        };
        let rpy = quat_to_rpy(quat);
        out.imu = ImuState {
            quaternion: quat.map(|v| v as f32),
            gyroscope: gyro.map(|v| v as f32),
            accelerometer: acc.map(|v| v as f32),
            rpy: rpy.map(|v| v as f32),
            temperature: 40,
        };
        out.motors = [MotorState::default(); NUM_MOTORS];
        let (qpos, qvel, qacc) = (self.data.qpos(), self.data.qvel(), self.data.qacc());
        for s in &self.slots {
            out.motors[s.slot] = MotorState {
                mode: MOTOR_MODE_ENABLED,
                q: qpos[s.qpos_adr] as f32,
                dq: qvel[s.dof_adr] as f32,
                ddq: qacc[s.dof_adr] as f32,
                tau_est: self.tau_applied[s.slot] as f32,
                temperature: [35, 40],
                voltage: 48.0,
                ..MotorState::default()
            };
        }
        out.wireless_remote = [0; 40];
        out.reserve = [0; 4];
    }

    /// The floating base's pose and velocities now: the part of [`Simulator::truth`] that needs
    /// no contact scan and no terrain query, for code that reads the base at every physics step
    /// (the trainer's supervisor walls and its assistant).
    pub fn base_kinematics(&self) -> BaseKinematics {
        let d = &self.data;
        let quat = self.base_quat();
        let (pos, lin_vel_world, ang_vel_body) = match (self.root_qpos_adr, self.root_dof_adr) {
            (Some(qa), Some(da)) => {
                let (q, v) = (d.qpos(), d.qvel());
                // Free joint: qvel[0..3] is the world-frame linear velocity, qvel[3..6] the
                // body-frame angular velocity.
                (
                    [q[qa], q[qa + 1], q[qa + 2]],
                    [v[da], v[da + 1], v[da + 2]],
                    [v[da + 3], v[da + 4], v[da + 5]],
                )
            }
            _ => {
                // cvel is [angular, linear] at the subtree com, world-oriented: good enough for a
                // base that has no free joint (normally fixed, so zero).
                let c = d.cvel()[self.pelvis_body];
                let r = d.xmat()[self.pelvis_body];
                let w_world = [c[0], c[1], c[2]];
                (d.xpos()[self.pelvis_body], [c[3], c[4], c[5]], mat_t_vec(&r, &w_world))
            }
        };
        BaseKinematics {
            pos,
            quat,
            lin_vel_world,
            lin_vel_body: mat_t_vec(&quat_to_mat(quat), &lin_vel_world),
            ang_vel_body,
        }
    }

    /// Privileged ground truth of the current state.
    pub fn truth(&self) -> Truth {
        let d = &self.data;
        let m = d.model();
        let base = self.base_kinematics();
        let (pos, quat) = (base.pos, base.quat);

        let mut foot_contact = [false; 2];
        let (gb, rootid) = (m.geom_bodyid(), m.body_rootid());
        for c in d.contact() {
            let (g1, g2) = (c.geom[0], c.geom[1]);
            // Skip flex contacts (no geom) and candidates still separated (inside the margin).
            if g1 < 0 || g2 < 0 || c.dist > 0.0 {
                continue;
            }
            let (b1, b2) = (gb[g1 as usize] as usize, gb[g2 as usize] as usize);
            for (foot, other) in [(b1, b2), (b2, b1)] {
                let side = self.foot_side[foot];
                if side != 0 && rootid[other] != self.robot_root {
                    foot_contact[side as usize - 1] = true;
                }
            }
        }
        let terrain = self
            .world
            .as_ref()
            .map(|w| w.truth(pos[0], pos[1], quat_to_rpy(quat)[2]));
        Truth {
            sim_time_s: d.time(),
            base_pos: pos,
            base_quat: quat,
            base_lin_vel_world: base.lin_vel_world,
            base_lin_vel_body: base.lin_vel_body,
            base_ang_vel_body: base.ang_vel_body,
            foot_contact,
            terrain,
            ground_height_m: self.world.as_ref().map_or(0.0, |w| w.ground_height(pos[0], pos[1])),
            stairs: self.world.as_ref().and_then(|w| w.stair_progress(pos[0], pos[1])),
        }
    }

    /// Bit `i` set: slot `i` drives a joint of this model.
    pub fn motor_slots_present(&self) -> u64 {
        self.present
    }
    /// `mode_machine` this robot reports (5 for the 29-dof, 4 for the 12-dof).
    pub fn mode_machine(&self) -> u8 {
        self.mode_machine
    }
    pub fn config(&self) -> &SimConfig {
        &self.config
    }
    /// Per-run IMU biases drawn from the seed: gyro xyz (rad/s), accelerometer xyz (m/s²); zeros
    /// without IMU noise.
    pub fn imu_bias(&self) -> [f64; 6] {
        self.imu_bias
    }
    /// Physics steps per control tick.
    pub fn substeps(&self) -> u32 {
        self.substeps
    }
    /// Physics steps taken since load / reset.
    pub fn steps(&self) -> u64 {
        self.steps
    }
    /// Simulated time, s.
    pub fn time(&self) -> f64 {
        self.data.time()
    }
    /// The initial `qpos` (home pose for the 29-dof, `qpos0` for the 12-dof).
    pub fn initial_qpos(&self) -> &[f64] {
        &self.initial_qpos
    }
    /// Torque applied to slot `i` at the last physics step, N·m.
    pub fn applied_torque(&self, slot: usize) -> f64 {
        self.tau_applied[slot]
    }
    /// `(lo, hi)` torque clamp of slot `i`, if present.
    pub fn effort_limit(&self, slot: usize) -> Option<(f64, f64)> {
        self.slots.iter().find(|s| s.slot == slot).map(|s| (s.tau_lo, s.tau_hi))
    }
    /// The underlying MuJoCo data (and, through it, the model), for inspection.
    pub fn data(&self) -> &MjData<Box<MjModel>> {
        &self.data
    }

    /// Mutable MuJoCo state, for sensors that need it (ray casting); not for stepping.
    pub fn data_mut(&mut self) -> &mut MjData<Box<MjModel>> {
        &mut self.data
    }

    /// A command holding the initial pose with [`slots::hold_gains`] on every present slot.
    pub fn hold_initial_pose_command(&self) -> LowCommand {
        let mut cmd = LowCommand {
            mode_machine: self.mode_machine,
            ..LowCommand::default()
        };
        for s in &self.slots {
            let (kp, kd) = slots::hold_gains(s.slot);
            let m = &mut cmd.motors[s.slot];
            m.mode = MOTOR_MODE_ENABLED;
            m.q = self.initial_qpos[s.qpos_adr] as f32;
            m.kp = kp;
            m.kd = kd;
        }
        cmd
    }
}

fn check_positive(what: &'static str, v: f64) -> Result<(), SimError> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(SimError::BadParameter {
            what,
            value: v,
            hint: "must be finite and > 0",
        })
    }
}

/// Roll, pitch, yaw (ZYX) of a unit quaternion (w, x, y, z).
pub fn quat_to_rpy(q: [f64; 4]) -> [f64; 3] {
    let [w, x, y, z] = q;
    let roll = (2.0 * (w * x + y * z)).atan2(1.0 - 2.0 * (x * x + y * y));
    let pitch = (2.0 * (w * y - z * x)).clamp(-1.0, 1.0).asin();
    let yaw = (2.0 * (w * z + x * y)).atan2(1.0 - 2.0 * (y * y + z * z));
    [roll, pitch, yaw]
}

/// Hamilton product `a ⊗ b` of quaternions (w, x, y, z).
pub(crate) fn quat_mul(a: [f64; 4], b: [f64; 4]) -> [f64; 4] {
    [
        a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
        a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
        a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
        a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0],
    ]
}

/// Rotation by `angle` about world axis `axis` (0 x, 1 y, 2 z).
fn axis_angle_quat(axis: usize, angle: f64) -> [f64; 4] {
    let (s, c) = (0.5 * angle).sin_cos();
    let mut q = [c, 0.0, 0.0, 0.0];
    q[axis + 1] = s;
    q
}

/// Row-major rotation matrix of a unit quaternion (w, x, y, z).
pub fn quat_to_mat(q: [f64; 4]) -> [f64; 9] {
    let [w, x, y, z] = q;
    [
        1.0 - 2.0 * (y * y + z * z),
        2.0 * (x * y - w * z),
        2.0 * (x * z + w * y),
        2.0 * (x * y + w * z),
        1.0 - 2.0 * (x * x + z * z),
        2.0 * (y * z - w * x),
        2.0 * (x * z - w * y),
        2.0 * (y * z + w * x),
        1.0 - 2.0 * (x * x + y * y),
    ]
}

/// `Rᵀ v` for a row-major 3×3 `R`: world vector into the body frame.
fn mat_t_vec(r: &[f64; 9], v: &[f64; 3]) -> [f64; 3] {
    [
        r[0] * v[0] + r[3] * v[1] + r[6] * v[2],
        r[1] * v[0] + r[4] * v[1] + r[7] * v[2],
        r[2] * v[0] + r[5] * v[1] + r[8] * v[2],
    ]
}
