//! The deploy spec: everything about one policy in one TOML file, validated at load.
//!
//! It expresses Unitree's unitree_rl_gym G1 policy (12 legs, single frame, phase clock, LSTM) and
//! unitree_rl_lab-style policies (29 joints through a `joint_ids_map`, per-term history laid out
//! term by term, command clamps). Paths inside the spec are relative to the spec file. Every
//! validation error names the offending field.
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::nn::NetworkDesc;

/// Every safety and rate setting's bounds (a spec may tighten a guard, never switch it off).
pub mod limits;
/// The left–right mirror of a spec's observation and action, built from its layout.
pub mod mirror;

#[derive(Debug, thiserror::Error)]
pub enum SpecError {
    #[error("cannot read deploy spec {path}")]
    Read { path: PathBuf, source: std::io::Error },
    #[error("deploy spec {path} is not valid TOML for a deploy spec: {message}")]
    Parse { path: PathBuf, message: String },
    #[error("deploy spec {path}: `{field}`: {message}")]
    Invalid {
        path: PathBuf,
        field: String,
        message: String,
    },
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DeploySpec {
    pub meta: Meta,
    pub rates: Rates,
    #[serde(default)]
    pub startup: Startup,
    pub policy: Policy,
    #[serde(default)]
    pub held: Vec<HeldGroup>,
    #[serde(default)]
    pub commands: Commands,
    #[serde(default)]
    pub phase: Option<Phase>,
    #[serde(default)]
    pub safety: Safety,
    #[serde(default)]
    pub estimator: EstimatorSpec,
    #[serde(default)]
    pub perception: PerceptionSpec,
    /// How the operator's wireless remote drives an operated run.
    #[serde(default)]
    pub operator: OperatorSpec,
    pub observation: Observation,
    /// Directory of the spec file; relative paths resolve against it.
    #[serde(skip)]
    pub base_dir: PathBuf,
    /// Where the spec was loaded from (for messages and logs).
    #[serde(skip)]
    pub path: PathBuf,
    /// The TOML text it was parsed from (pinned in run logs).
    #[serde(skip)]
    pub source_text: String,
    /// Leg kinematics read from `estimator.model` at load time (`None` without one).
    #[serde(skip)]
    pub kinematics: Option<estimator::LegKinematics>,
}

/// `[perception]`: the lidar's mount and the BEV self-filter. Defaults: the G1's MID-360 (latest
/// unitree_ros URDF, upside down on the torso; the waist is taken at zero) and one box around the
/// robot's body. Perception runs whenever the HAL delivers lidar frames.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PerceptionSpec {
    /// Sensor position in the pelvis frame, m.
    pub mount_xyz: [f32; 3],
    /// Sensor roll, pitch, yaw in the pelvis frame, rad (R = Rz·Ry·Rx).
    pub mount_rpy: [f32; 3],
    /// The sensor sits on the torso (the G1's MID-360): the mount above holds with the waist at
    /// zero, and each point is placed through the waist joints as measured
    /// (`sensor_io::bev::WaistChain::G1`). `false`: the sensor is fixed to the pelvis. On a robot
    /// without waist joints (the 12-dof G1) both read the same.
    pub mount_on_torso: bool,
    /// Robot-body boxes in the gravity-aligned robot frame, `[xmin, ymin, zmin, xmax, ymax, zmax]`
    /// (m, z from the ground under the robot); points inside are self-hits. At most 8.
    pub self_filter: Vec<[f32; 6]>,
    /// Base height used for the BEV when the estimator has no leg kinematics, m.
    pub fallback_base_height_m: f32,
    /// What makes the terrain token: `cnn` (the trained terrain CNN, default) or `geometric`
    /// (`estimator::terrain`, plane fits; no learned weights).
    pub terrain_estimator: TerrainEstimatorKind,
    /// The terrain CNN's description (TOML, as `g1-train` writes it) and weights (safetensors),
    /// relative to the spec; give both or neither. Default: the network built into the firmware.
    pub terrain_network: Option<PathBuf>,
    pub terrain_weights: Option<PathBuf>,
    /// Remembered lidar keyframes merged into the BEV grid (`sensor_io::bev_memory`; 0: single-frame
    /// grids). Default: what the built-in network was trained with
    /// (`sensor_io::bev_memory::BUILTIN_NETWORK_KEYFRAMES`); a network of your own needs the
    /// setting it was trained with (`g1-dataset export --memory-keyframes`).
    pub bev_memory_keyframes: usize,
}

/// `[perception] terrain_estimator`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TerrainEstimatorKind {
    #[default]
    Cnn,
    Geometric,
}

impl Default for PerceptionSpec {
    fn default() -> Self {
        let m = sensor_io::bev::MountPose::G1_MID360_DEFAULT;
        Self {
            mount_xyz: m.xyz,
            mount_rpy: m.rpy,
            mount_on_torso: true,
            self_filter: sensor_io::bev::SelfFilter::G1_DEFAULT
                .boxes()
                .iter()
                .map(|b| [b.min[0], b.min[1], b.min[2], b.max[0], b.max[1], b.max[2]])
                .collect(),
            fallback_base_height_m: 0.76,
            terrain_estimator: TerrainEstimatorKind::Cnn,
            terrain_network: None,
            terrain_weights: None,
            bev_memory_keyframes: sensor_io::bev_memory::BUILTIN_NETWORK_KEYFRAMES,
        }
    }
}

impl PerceptionSpec {
    pub fn mount(&self) -> sensor_io::bev::MountPose {
        sensor_io::bev::MountPose {
            xyz: self.mount_xyz,
            rpy: self.mount_rpy,
        }
    }

    pub fn self_filter(&self) -> Result<sensor_io::bev::SelfFilter, sensor_io::bev::BevError> {
        let boxes: Vec<_> = self
            .self_filter
            .iter()
            .map(|b| sensor_io::bev::Aabb {
                min: [b[0], b[1], b[2]],
                max: [b[3], b[4], b[5]],
            })
            .collect();
        sensor_io::bev::SelfFilter::new(&boxes)
    }

    pub fn bev_memory(&self) -> sensor_io::bev_memory::MemoryConfig {
        sensor_io::bev_memory::MemoryConfig::with_keyframes(self.bev_memory_keyframes)
    }
}

/// `[estimator]`: where the leg kinematics come from and the estimator's tuning. Without `model`
/// the estimator runs attitude only (no base velocity, height or contacts).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EstimatorSpec {
    /// The robot's MJCF (relative to the spec), the single source of the leg kinematics.
    pub model: Option<PathBuf>,
    /// Contact on/off thresholds on the vertical foot force from joint torques, N.
    pub contact_on_force_n: f64,
    pub contact_off_force_n: f64,
    /// On flat ground: a foot enters contact only with its sole below this height, and stays in
    /// contact while below the stance height however light, m.
    pub contact_touchdown_height_m: f64,
    pub contact_stance_height_m: f64,
    /// Standard deviation of the flat-ground prior on stance feet, m; 0 turns it off (stairs).
    pub ground_height_noise_m: f64,
    /// Stance-leg odometry noise, m/s.
    pub leg_velocity_noise_m_s: f64,
    /// Sole (and ground) compliance: sink per newton of load, m/N.
    pub sole_compliance_m_per_n: f64,
    /// Process noise on the base acceleration, m/s² per √Hz.
    pub accel_noise: f64,
}

impl Default for EstimatorSpec {
    fn default() -> Self {
        let c = estimator::EstimatorConfig::default();
        Self {
            model: None,
            contact_on_force_n: c.contact.on_force_n,
            contact_off_force_n: c.contact.off_force_n,
            contact_touchdown_height_m: c.contact.touchdown_height_m,
            contact_stance_height_m: c.contact.stance_height_m,
            ground_height_noise_m: c.filter.ground_height_noise.unwrap_or(0.0),
            leg_velocity_noise_m_s: c.filter.leg_velocity_noise,
            sole_compliance_m_per_n: c.filter.sole_compliance_m_per_n,
            accel_noise: c.filter.accel_noise,
        }
    }
}

impl EstimatorSpec {
    /// The estimator's configuration from these settings.
    pub fn config(&self) -> estimator::EstimatorConfig {
        let mut c = estimator::EstimatorConfig::default();
        c.contact.on_force_n = self.contact_on_force_n;
        c.contact.off_force_n = self.contact_off_force_n;
        c.contact.touchdown_height_m = self.contact_touchdown_height_m;
        c.contact.stance_height_m = self.contact_stance_height_m;
        c.filter.ground_height_noise = (self.ground_height_noise_m > 0.0).then_some(self.ground_height_noise_m);
        c.filter.leg_velocity_noise = self.leg_velocity_noise_m_s;
        c.filter.sole_compliance_m_per_n = self.sole_compliance_m_per_n;
        c.filter.accel_noise = self.accel_noise;
        c
    }
}

/// The wireless remote of an operated run: a button combination ("L2+up": every named button
/// pressed, names as on Unitree's remote) per request, and the sticks' command. The defaults are
/// unitree_rl_lab's G1 deploy (L2+up stand, R1+X walk, L2+B passive) plus L2+down to sit down.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OperatorSpec {
    pub stand_up: String,
    pub walk: String,
    pub sit_down: String,
    pub passive: String,
    /// Stick deflection read as centred, [0, 0.5).
    pub dead_zone: f32,
    /// Largest change of vx, vy (m/s per s) and wz (rad/s per s) the sticks command.
    pub rate_per_s: [f32; 3],
}

impl Default for OperatorSpec {
    fn default() -> Self {
        Self {
            stand_up: "L2+up".into(),
            walk: "R1+X".into(),
            sit_down: "L2+down".into(),
            passive: "L2+B".into(),
            dead_zone: 0.1,
            rate_per_s: [1.0, 1.0, 2.0],
        }
    }
}

impl OperatorSpec {
    /// The buttons of a combination ("L2+up") as a bit mask of `sensor_io`'s remote buttons.
    pub fn combo(text: &str) -> Result<u16, String> {
        use sensor_io::unitree_hg::remote::Button;
        let mut mask = 0u16;
        for name in text.split('+').map(str::trim) {
            let b = Button::from_name(name).ok_or_else(|| {
                let names: Vec<&str> = Button::ALL.iter().map(|b| b.name()).collect();
                format!("'{name}' is not a button of the remote ({})", names.join(", "))
            })?;
            mask |= b as u16;
        }
        Ok(mask)
    }

    /// `(request, mask)` of every combination, in a fixed order.
    pub fn combos(&self) -> Result<[(crate::operator::Request, u16); 4], String> {
        use crate::operator::Request;
        Ok([
            (Request::Passive, Self::combo(&self.passive)?),
            (Request::StandUp, Self::combo(&self.stand_up)?),
            (Request::Walk, Self::combo(&self.walk)?),
            (Request::SitDown, Self::combo(&self.sit_down)?),
        ])
    }
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Meta {
    pub name: String,
    #[serde(default)]
    pub description: String,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Rates {
    /// Fast control tick (state in, command out), Hz.
    pub control_hz: u32,
    /// Policy rate, Hz; must divide `control_hz`.
    pub policy_hz: u32,
    /// Perception rate, Hz; must divide `control_hz`.
    #[serde(default = "Rates::default_perception_hz")]
    pub perception_hz: u32,
    /// Compute budget per rate group, µs. Overruns are counted and logged, never acted on (acting
    /// on wall-clock time would break determinism).
    #[serde(default)]
    pub budget_us: Budgets,
}

impl Rates {
    fn default_perception_hz() -> u32 {
        10
    }
}

#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Budgets {
    pub fast: u32,
    pub policy: u32,
    pub perception: u32,
}

impl Default for Budgets {
    fn default() -> Self {
        // Of a 2000 µs tick: the fast group must leave room for policy and perception ticks.
        Self {
            fast: 200,
            policy: 1000,
            perception: 1000,
        }
    }
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Startup {
    /// Linear ramp from the measured pose to the default pose, seconds (0 = targets are the default
    /// pose from the first tick).
    #[serde(default = "Startup::default_ramp")]
    pub ramp_s: f64,
    /// Hold the default pose this long after the ramp, seconds. The policy's first step comes one
    /// policy period after ramp + hold (as in Unitree's reference loop).
    #[serde(default)]
    pub hold_s: f64,
    /// Gains for the policy joints during ramp and hold (and in hold-only mode), one per policy
    /// joint; default: the policy's `kp`/`kd`. A policy's walking gains are often too soft to stand
    /// without the policy (e.g. ankle kp 40), and a simulated robot has no gantry to hang from.
    #[serde(default)]
    pub kp: Option<Vec<f32>>,
    #[serde(default)]
    pub kd: Option<Vec<f32>>,
}

impl Startup {
    fn default_ramp() -> f64 {
        1.0
    }
}

impl Default for Startup {
    fn default() -> Self {
        Self {
            ramp_s: Self::default_ramp(),
            hold_s: 0.0,
            kp: None,
            kd: None,
        }
    }
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Policy {
    /// safetensors file, relative to the spec file.
    pub weights: PathBuf,
    pub network: NetworkDesc,
    /// Policy output index → motor slot (SDK order). Its length is the number of driven joints.
    pub joint_ids_map: Vec<usize>,
    /// Optional joint names per policy index, checked against the slot names (catches a wrong map).
    #[serde(default)]
    pub joint_names: Vec<String>,
    /// Per policy joint, rad.
    pub default_pose: Vec<f32>,
    /// `q_target = default_pose + action_scale * action` (scalar or per joint).
    pub action_scale: Scale,
    /// Clip raw actions to ±this before scaling (none if absent).
    #[serde(default)]
    pub action_clip: Option<f32>,
    /// `average`: also run the network, with its own recurrent state, on the left–right mirror image
    /// of every observation, and act on the mean of its action and the mirrored one: a policy with
    /// no left–right bias by construction ([`crate::spec::mirror`]). Absent or `none`: the network alone.
    #[serde(default)]
    pub mirror: MirrorMode,
    /// PD gains of the driven joints, in policy order (`kp[i]` drives slot `joint_ids_map[i]`);
    /// unitree_rl_lab's deploy.yaml lists them in SDK motor order instead (`g1-import` converts).
    pub kp: Vec<f32>,
    pub kd: Vec<f32>,
}

/// How the policy network's output becomes the action (see [`Policy::mirror`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MirrorMode {
    #[default]
    None,
    Average,
}

/// Motors the policy does not drive, held at a fixed pose.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HeldGroup {
    /// Motor slot names (see `hal::G1_MOTOR_NAMES`, with or without `_joint`).
    pub joints: Vec<String>,
    pub q: Scale,
    pub kp: Scale,
    pub kd: Scale,
}

#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Commands {
    /// Velocity command clamps (vx, vy, wz), applied before the observation scale.
    #[serde(default)]
    pub min: Option<[f32; 3]>,
    #[serde(default)]
    pub max: Option<[f32; 3]>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Phase {
    /// Gait period, seconds.
    pub period_s: f64,
    /// Phase-clock time at the policy's first step; it advances by one policy period per step.
    /// unitree_rl_gym's MuJoCo and real deploy scripts both give 0.02 s.
    pub first_step_time_s: f64,
    /// A clock the policy sets: the network has one output more than joints, and the clock runs at
    /// `1 + that output` times its nominal rate, clamped to `[min, max]`, from the next policy step
    /// on (so a network whose extra output is 0 keeps the fixed clock). The output never reaches
    /// a motor. Unset (the default): a fixed clock.
    #[serde(default)]
    pub rate: Option<PhaseRate>,
}

/// The range of a policy-set gait clock's rate (`[phase] rate = { min = 0.5, max = 1.5 }`).
#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PhaseRate {
    pub min: f64,
    pub max: f64,
}

/// Safety supervisor limits. Defaults follow Unitree's own runtime guards (../shared/facts/g1_low_level.md)
/// except where a 500 Hz loop can afford to be stricter (state timeout).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Safety {
    /// Damping applied to every enabled motor in the safe state (kp = 0).
    pub damping_kd: f32,
    /// Tilt from upright beyond which the robot is considered fallen, rad.
    pub tilt_limit_rad: f32,
    /// A joint-speed limit for every supervised joint, rad/s. Unset (the default), each joint is
    /// limited by its motor's own velocity limit (`hal::g1_motor_velocity_limit`: 20–37 rad/s); set,
    /// it may only be stricter. (Unitree's 10 rad/s `joint_vel_out_of_limit` is an optional "soft"
    /// helper that none of their deploy loops calls.)
    pub joint_speed_limit_rad_s: Option<f32>,
    /// Stricter limits for single joints, rad/s, by slot name (`left_knee = 15.0`).
    pub joint_speed_limits_rad_s: BTreeMap<String, f32>,
    /// Base angular speed limit, rad/s, on each gyro axis (as Unitree's `ang_vel_out_of_limit`: 6).
    pub base_ang_speed_limit_rad_s: f32,
    /// Motor winding / casing temperature limits, °C (Unitree: 120 / 85).
    pub motor_winding_limit_c: i16,
    pub motor_casing_limit_c: i16,
    /// No valid, newer LowState for this long trips, s.
    pub state_timeout_s: f64,
    /// This many consecutive frames failing their CRC trip (single failures are counted, not fatal).
    pub crc_failure_streak: u32,
    /// A policy joint whose reported state (q, dq, tau_est) stays bit-identical for this many fresh
    /// frames is frozen (stuck encoder or a motor that stopped answering). Real encoders and current
    /// sensors are never that still, and neither is a simulated joint under load.
    pub frozen_state_frames: u32,
    /// Policy targets are clamped to the joint range shrunk by this margin, rad.
    pub joint_range_margin_rad: f32,
}

impl Default for Safety {
    fn default() -> Self {
        Self {
            damping_kd: 5.0,
            tilt_limit_rad: 1.0,
            joint_speed_limit_rad_s: None,
            joint_speed_limits_rad_s: BTreeMap::new(),
            base_ang_speed_limit_rad_s: 6.0,
            motor_winding_limit_c: 120,
            motor_casing_limit_c: 85,
            state_timeout_s: 0.02,
            crc_failure_streak: 3,
            frozen_state_frames: 10,
            joint_range_margin_rad: 0.0,
        }
    }
}

/// How multi-frame history is laid out in the observation vector.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum HistoryLayout {
    /// Each term's frames (oldest first) back to back, term after term (IsaacLab / unitree_rl_lab).
    #[default]
    TermMajor,
    /// Whole frames (all terms), oldest frame first.
    FrameMajor,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Observation {
    #[serde(default)]
    pub history_layout: HistoryLayout,
    pub terms: Vec<ObsTerm>,
}

/// Largest PD gains a spec may command (N·m/rad, N·m·s/rad): above the G1's own (kp ≤ 300, kd ≤ 20
/// in Unitree's examples) with room, far below values that only a typo makes.
pub const MAX_KP: f32 = 1000.0;
pub const MAX_KD: f32 = 100.0;
/// Largest |action_scale| (rad of target per unit of action).
pub const MAX_ACTION_SCALE: f32 = 10.0;
/// Most frames of history one observation term may keep (IsaacLab exports use up to a few tens;
/// a value past this is a typo, and unbounded ones overflowed the observation size).
pub const MAX_OBS_HISTORY: usize = 1000;
/// Most values an observation vector may have (the policies here take 45 to 480).
pub const MAX_OBSERVATION_DIM: usize = 1 << 16;
/// Longest start-up ramp or hold, s (an hour; the tick counts derived from them must not overflow).
pub const MAX_STARTUP_S: f64 = 3600.0;
/// Largest deploy spec file read (the ones here are a few KB).
pub const MAX_SPEC_BYTES: usize = 1 << 20;
/// Largest operator command a spec may allow, m/s or rad/s (a G1 walks below 2 m/s).
pub const MAX_COMMAND: f32 = 10.0;
/// Largest magnitude of an observation term's scale (IsaacLab's are 0.05–5).
pub const MAX_OBS_SCALE: f32 = 1000.0;
/// Largest observation or action clip (IsaacLab clips at 100).
pub const MAX_CLIP: f32 = 10_000.0;
/// Largest ELU alpha (exporters write 1.0).
pub const MAX_ELU_ALPHA: f32 = 10.0;
/// Longest gait period, s.
pub const MAX_PHASE_PERIOD_S: f64 = 100.0;
/// Largest rate a policy-set gait clock may run at, in multiples of its nominal rate.
pub const MAX_PHASE_RATE: f64 = 4.0;

/// The signals an observation term can read.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ObsKind {
    /// IMU gyroscope, body frame (3).
    BaseAngVel,
    /// Gravity direction in the body frame from the IMU quaternion (3).
    ProjectedGravity,
    /// Operator velocity command vx, vy, wz after clamping (3).
    VelocityCommand,
    /// Joint position minus default pose, policy order (n).
    JointPosRel,
    /// Joint velocity, policy order (n).
    JointVel,
    /// Previous raw policy output (n).
    LastAction,
    /// sin(2π·phase), cos(2π·phase) (2).
    GaitPhase,
    /// The paper's terrain token z = (class index 0 flat / 1 up / 2 down, step height m, step
    /// depth m, yaw rad) from the perception group (4); flat until the first lidar frame.
    TerrainToken,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObsTerm {
    pub kind: ObsKind,
    #[serde(default = "Scale::one")]
    pub scale: Scale,
    /// Clip to ±clip after scaling (this project's convention; rsl_rl's `clip_obs` is the same).
    #[serde(default)]
    pub clip: Option<f32>,
    /// IsaacLab's `clip = (low, high)`: the raw value is clamped to `[low, high]` before scaling.
    /// Both may be given; this one applies first.
    #[serde(default)]
    pub clip_before_scale: Option<[f32; 2]>,
    /// Frames of history (1 = current only).
    #[serde(default = "one_usize")]
    pub history: usize,
}

fn one_usize() -> usize {
    1
}

/// A scalar or one value per element.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(untagged)]
pub enum Scale {
    Scalar(f32),
    PerElement(Vec<f32>),
}

impl Scale {
    fn one() -> Self {
        Scale::Scalar(1.0)
    }
    /// Expands to `n` values; `None` if a per-element list has the wrong length.
    pub fn expand(&self, n: usize) -> Option<Vec<f32>> {
        match self {
            Scale::Scalar(s) => Some(vec![*s; n]),
            Scale::PerElement(v) if v.len() == n => Some(v.clone()),
            Scale::PerElement(_) => None,
        }
    }
}

impl ObsKind {
    /// Elements per frame for a policy with `n` driven joints.
    pub fn dim(self, n: usize) -> usize {
        match self {
            ObsKind::BaseAngVel | ObsKind::ProjectedGravity | ObsKind::VelocityCommand => 3,
            ObsKind::JointPosRel | ObsKind::JointVel | ObsKind::LastAction => n,
            ObsKind::GaitPhase => 2,
            ObsKind::TerrainToken => 4,
        }
    }
}

/// What the spec commands on each of the 35 motor slots in policy mode: driven (policy joints) or
/// held (`[[held]]`), the target pose those slots rest at, and their PD gains. The controller and the
/// PPO trainer both build their commands from it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MotorTable {
    pub enabled: [bool; hal::NUM_MOTORS],
    pub default_q: [f32; hal::NUM_MOTORS],
    pub kp: [f32; hal::NUM_MOTORS],
    pub kd: [f32; hal::NUM_MOTORS],
}

impl DeploySpec {
    /// Gains that a PD law computed explicitly once per control period would not hold stable:
    /// the damping term diverges once `kd · dt / I > 2`, with `I` the joint's inertia. Judged on the
    /// distal joints (ankles, elbows, wrists), whose inertia is mostly the reflected rotor inertia
    /// used here; a proximal joint carries a heavy link (the waist, the torso) and is far from the
    /// limit at the same kd. The robot's motor drivers and `g1-sim`'s implicit actuators are not affected; a
    /// simulator that steps PD explicitly (Unitree's reference loop, `g1-sim --integrator euler`,
    /// IsaacGym-style explicit actuators) is. One line per joint.
    pub fn explicit_pd_warnings(&self) -> Vec<String> {
        let dt = self.control_dt();
        let t = self.motor_table();
        (0..hal::NUM_MOTORS)
            .filter(|&s| t.enabled[s] && t.kd[s] > 0.0)
            .filter_map(|s| {
                let name = hal::G1_MOTOR_NAMES[s];
                if !["ankle", "elbow", "wrist"].iter().any(|d| name.contains(d)) {
                    return None;
                }
                let inertia = hal::g1_rotor_inertia(name)?;
                let ratio = t.kd[s] as f64 * dt / inertia;
                (ratio > 2.0).then(|| {
                    format!(
                        "{name}: kd {} × dt {dt} s / I {inertia} kg·m² = {ratio:.1} > 2: explicit PD at this rate diverges \
                         (fine on the robot and in g1-sim's implicit actuators; not in a simulator that steps PD explicitly)",
                        t.kd[s]
                    )
                })
            })
            .collect()
    }

    /// The per-slot table of driven and held motors (policy joints first, then `[[held]]` groups).
    pub fn motor_table(&self) -> MotorTable {
        const N: usize = hal::NUM_MOTORS;
        let mut t = MotorTable {
            enabled: [false; N],
            default_q: [0.0; N],
            kp: [0.0; N],
            kd: [0.0; N],
        };
        let p = &self.policy;
        for (i, &slot) in p.joint_ids_map.iter().enumerate() {
            t.enabled[slot] = true;
            t.default_q[slot] = p.default_pose[i];
            t.kp[slot] = p.kp[i];
            t.kd[slot] = p.kd[i];
        }
        for g in &self.held {
            let k = g.joints.len();
            let (q, gp, gd) = (g.q.expand(k).unwrap(), g.kp.expand(k).unwrap(), g.kd.expand(k).unwrap());
            for (j, name) in g.joints.iter().enumerate() {
                let slot = hal::g1_motor_slot(name).expect("validated by DeploySpec");
                t.enabled[slot] = true;
                t.default_q[slot] = q[j];
                t.kp[slot] = gp[j];
                t.kd[slot] = gd[j];
            }
        }
        t
    }

    pub fn load(path: &Path) -> Result<Self, SpecError> {
        Self::from_toml(&Self::read_text(path)?, path)
    }

    /// The spec file's text: size-capped, UTF-8.
    fn read_text(path: &Path) -> Result<String, SpecError> {
        let read = |source| SpecError::Read {
            path: path.into(),
            source,
        };
        let bytes = crate::read_capped(path, MAX_SPEC_BYTES as u64).map_err(read)?;
        String::from_utf8(bytes).map_err(|e| read(std::io::Error::new(std::io::ErrorKind::InvalidData, e)))
    }

    /// As [`DeploySpec::load`], with `KEY=VALUE` overrides (`g1fw run --set`) applied first: a dotted
    /// key of the spec's TOML (`safety.state_timeout_s`) and a TOML value. The spec's text then is the
    /// overridden TOML, which the log keeps, so replay runs what ran.
    pub fn load_with_overrides(path: &Path, sets: &[String]) -> Result<Self, SpecError> {
        if sets.is_empty() {
            return Self::load(path);
        }
        let text = Self::read_text(path)?;
        let bad = |message: String| SpecError::Parse {
            path: path.into(),
            message,
        };
        let mut table: toml::Table = toml::from_str(&text).map_err(|e| bad(e.to_string()))?;
        for set in sets {
            let (key, value) = set
                .split_once('=')
                .ok_or_else(|| bad(format!("--set {set}: write KEY=VALUE, e.g. safety.state_timeout_s=0.1")))?;
            let value: toml::Value = match toml::from_str::<toml::Table>(&format!("v = {value}")) {
                Ok(mut t) => t.remove("v").expect("parsed one key"),
                Err(_) => toml::Value::String(value.to_string()),
            };
            let mut parts: Vec<&str> = key.trim().split('.').collect();
            let leaf = parts
                .pop()
                .filter(|l| !l.is_empty())
                .ok_or_else(|| bad(format!("--set {set}: no key")))?;
            let mut at = &mut table;
            for part in parts {
                at = at
                    .entry(part)
                    .or_insert_with(|| toml::Value::Table(toml::Table::new()))
                    .as_table_mut()
                    .ok_or_else(|| bad(format!("--set {set}: `{part}` is a value, not a table")))?;
            }
            at.insert(leaf.to_string(), value);
        }
        let text = format!(
            "# {} with g1fw run --set {}\n{}",
            path.display(),
            sets.join(" --set "),
            toml::to_string(&table).map_err(|e| bad(e.to_string()))?
        );
        Self::from_toml(&text, path)
    }

    /// Parses and validates; `path` locates relative files and names the spec in errors.
    pub fn from_toml(text: &str, path: &Path) -> Result<Self, SpecError> {
        let mut spec = Self::parse_unvalidated(text, path)?;
        spec.validate()?;
        if let Some(model) = &spec.estimator.model {
            let file = spec.base_dir.join(model);
            spec.kinematics = Some(estimator::LegKinematics::from_mjcf_file(&file).map_err(|e| {
                spec.invalid(
                    "estimator.model",
                    format!(
                        "{e} (reading {}; fix the path, or remove `model` to run attitude only)",
                        file.display()
                    ),
                )
            })?);
        }
        Ok(spec)
    }

    /// The TOML alone, not validated (the fuzz harness, `controller::fuzz_deploy_spec`, starts here).
    #[doc(hidden)]
    pub fn parse_unvalidated(text: &str, path: &Path) -> Result<Self, SpecError> {
        if text.len() > MAX_SPEC_BYTES {
            return Err(SpecError::Parse {
                path: path.into(),
                message: format!(
                    "{} bytes is more than the {MAX_SPEC_BYTES} a deploy spec may have",
                    text.len()
                ),
            });
        }
        let mut spec: DeploySpec = toml::from_str(text).map_err(|e| SpecError::Parse {
            path: path.into(),
            message: crate::text::for_terminal(&e.to_string(), crate::text::MAX_QUOTED_LINE, true),
        })?;
        spec.path = path.to_path_buf();
        spec.source_text = text.to_string();
        spec.base_dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
        Ok(spec)
    }

    fn validate_safety(&self) -> Result<(), SpecError> {
        let s = &self.safety;
        let positive = [
            ("safety.damping_kd", s.damping_kd as f64),
            ("safety.tilt_limit_rad", s.tilt_limit_rad as f64),
            ("safety.base_ang_speed_limit_rad_s", s.base_ang_speed_limit_rad_s as f64),
            ("safety.state_timeout_s", s.state_timeout_s),
        ];
        self.require_positive(&positive)?;
        if s.tilt_limit_rad > std::f32::consts::PI {
            return Err(self.invalid(
                "safety.tilt_limit_rad",
                format!("{}: a tilt from upright is at most π rad", s.tilt_limit_rad),
            ));
        }
        // The damping command is what goes out when something is already wrong: the same cap as
        // every other kd.
        if s.damping_kd > MAX_KD {
            return Err(self.invalid(
                "safety.damping_kd",
                format!("{} is above the largest kd a spec may command ({MAX_KD})", s.damping_kd),
            ));
        }
        // Joint speed: a spec may tighten the motors' own limits, never loosen them.
        if let Some(v) = s.joint_speed_limit_rad_s {
            self.require_positive(&[("safety.joint_speed_limit_rad_s", v as f64)])?;
        }
        for (name, &v) in &s.joint_speed_limits_rad_s {
            let field = format!("safety.joint_speed_limits_rad_s.{name}");
            self.require_positive(&[(&field, v as f64)])?;
            let Some(motor) =
                hal::g1_motor_slot(name).and_then(|slot| hal::g1_motor_velocity_limit(hal::G1_MOTOR_NAMES[slot]))
            else {
                return Err(self.invalid(
                    &field,
                    "is not a G1 joint (slot names as in hal::G1_MOTOR_NAMES, e.g. left_knee)",
                ));
            };
            if v > motor {
                return Err(self.invalid(
                    &field,
                    format!("{v} rad/s is above the motor's own limit of {motor} rad/s; a spec may only be stricter"),
                ));
            }
        }
        if s.crc_failure_streak == 0 || s.frozen_state_frames < 2 {
            return Err(self.invalid("safety", "crc_failure_streak must be >= 1 and frozen_state_frames >= 2"));
        }
        if !(s.joint_range_margin_rad.is_finite() && s.joint_range_margin_rad >= 0.0) {
            return Err(self.invalid("safety.joint_range_margin_rad", "must be >= 0"));
        }
        Ok(())
    }

    fn validate_operator(&self) -> Result<(), SpecError> {
        let o = &self.operator;
        let combos = o.combos().map_err(|e| self.invalid("operator", e))?;
        for (i, (r, m)) in combos.iter().enumerate() {
            if let Some((other, _)) = combos[..i].iter().find(|(_, n)| n == m) {
                return Err(self.invalid(
                    "operator",
                    format!("{} and {} are the same buttons", r.name(), other.name()),
                ));
            }
        }
        if !(0.0..0.5).contains(&o.dead_zone) {
            return Err(self.invalid("operator.dead_zone", "must be in [0, 0.5)"));
        }
        if !o.rate_per_s.iter().all(|r| r.is_finite() && *r > 0.0 && *r <= 10.0) {
            return Err(self.invalid("operator.rate_per_s", "each must be in (0, 10]"));
        }
        Ok(())
    }

    /// Every `(field, value)` is a finite number > 0.
    fn require_positive(&self, fields: &[(&str, f64)]) -> Result<(), SpecError> {
        for &(field, v) in fields {
            if !(v.is_finite() && v > 0.0) {
                return Err(self.invalid(field, format!("must be a positive number, got {v}")));
            }
        }
        Ok(())
    }

    fn invalid(&self, field: &str, message: impl Into<String>) -> SpecError {
        SpecError::Invalid {
            path: self.path.clone(),
            field: field.into(),
            message: message.into(),
        }
    }

    pub fn weights_path(&self) -> PathBuf {
        self.base_dir.join(&self.policy.weights)
    }

    /// Every file this spec makes a run read, each with the field naming it (outputs must never
    /// be any of them).
    pub fn files_read(&self) -> Vec<(&'static str, PathBuf)> {
        let mut v = vec![("the spec's policy.weights", self.weights_path())];
        if let Some(m) = &self.estimator.model {
            v.push(("the spec's estimator.model", self.base_dir.join(m)));
        }
        if let Some(d) = &self.perception.terrain_network {
            v.push(("the spec's perception.terrain_network", self.base_dir.join(d)));
        }
        if let Some(w) = &self.perception.terrain_weights {
            v.push(("the spec's perception.terrain_weights", self.base_dir.join(w)));
        }
        v
    }

    /// The same spec with another weights file (a training checkpoint's actor, say); the file is
    /// checked when the controller loads it, as the spec's own would be.
    pub fn with_weights(mut self, weights: &Path) -> Result<Self, SpecError> {
        self.policy.weights = std::path::absolute(weights)
            .map_err(|e| self.invalid("policy.weights", format!("cannot resolve {}: {e}", weights.display())))?;
        Ok(self)
    }

    /// Number of joints the policy drives.
    pub fn num_joints(&self) -> usize {
        self.policy.joint_ids_map.len()
    }

    /// Length of the network's output: one per joint, plus the gait clock's rate when the policy
    /// sets it (`[phase] rate`).
    pub fn action_dim(&self) -> usize {
        self.num_joints() + self.phase.as_ref().is_some_and(|ph| ph.rate.is_some()) as usize
    }

    /// Control ticks per perception step.
    pub fn perception_decimation(&self) -> u32 {
        self.rates.control_hz / self.rates.perception_hz
    }

    /// Control ticks per policy step.
    pub fn decimation(&self) -> u32 {
        self.rates.control_hz / self.rates.policy_hz
    }

    pub fn control_dt(&self) -> f64 {
        1.0 / self.rates.control_hz as f64
    }

    /// Length of the observation vector the spec builds (validated: at most
    /// [`MAX_OBSERVATION_DIM`]; saturates rather than overflow on an unvalidated spec).
    pub fn observation_dim(&self) -> usize {
        self.checked_observation_dim().unwrap_or(usize::MAX)
    }

    fn checked_observation_dim(&self) -> Option<usize> {
        let n = self.num_joints();
        self.observation
            .terms
            .iter()
            .try_fold(0usize, |sum, t| sum.checked_add(t.kind.dim(n).checked_mul(t.history)?))
    }

    /// Checks every field (what `load` and `parse` do after reading): the spec may be changed in code
    /// and checked again.
    pub fn validate(&self) -> Result<(), SpecError> {
        self.validate_safety()?;
        self.validate_estimator()?;
        self.validate_perception()?;
        self.validate_rates_and_startup()?;
        if let Some((field, message)) = limits::first_violation(self) {
            return Err(self.invalid(field, message));
        }
        let used = self.validate_policy()?;
        self.validate_held(used)?;
        self.validate_commands_and_phase()?;
        self.validate_observation()?;
        self.validate_operator()?;
        if let Err(e) = mirror::PolicyMirror::averaged_with(self) {
            return Err(self.invalid("policy.mirror", format!("\"average\" needs a mirrored policy: {e}")));
        }
        Ok(())
    }

    /// The estimator's contact thresholds and noise figures.
    fn validate_estimator(&self) -> Result<(), SpecError> {
        let e = &self.estimator;
        let positive = [
            ("estimator.contact_on_force_n", e.contact_on_force_n),
            ("estimator.leg_velocity_noise_m_s", e.leg_velocity_noise_m_s),
            ("estimator.accel_noise", e.accel_noise),
        ];
        self.require_positive(&positive)?;
        if !(e.contact_off_force_n.is_finite() && e.contact_off_force_n <= e.contact_on_force_n) {
            return Err(self.invalid(
                "estimator.contact_off_force_n",
                "must be a number <= contact_on_force_n (hysteresis)",
            ));
        }
        if !(e.sole_compliance_m_per_n.is_finite() && e.sole_compliance_m_per_n >= 0.0) {
            return Err(self.invalid("estimator.sole_compliance_m_per_n", "must be >= 0"));
        }
        if !(e.ground_height_noise_m.is_finite() && e.ground_height_noise_m >= 0.0) {
            return Err(self.invalid(
                "estimator.ground_height_noise_m",
                "must be >= 0 (0 turns the prior off)",
            ));
        }
        Ok(())
    }

    /// The lidar mount, self-filter, BEV memory and terrain network.
    fn validate_perception(&self) -> Result<(), SpecError> {
        let pc = &self.perception;
        if let Err(e) = pc.self_filter() {
            return Err(self.invalid("perception.self_filter", e.to_string()));
        }
        if pc.bev_memory_keyframes > sensor_io::bev_memory::MAX_KEYFRAMES {
            return Err(self.invalid(
                "perception.bev_memory_keyframes",
                format!(
                    "must be 0 to {} (each keyframe holds 8192 points and is merged every frame)",
                    sensor_io::bev_memory::MAX_KEYFRAMES
                ),
            ));
        }
        match (&pc.terrain_network, &pc.terrain_weights) {
            (None, None) => {}
            (Some(d), Some(w)) => {
                let (d, w) = (self.base_dir.join(d), self.base_dir.join(w));
                if let Err(e) = crate::terrain_net::TerrainNet::load(&d, &w) {
                    return Err(self.invalid(
                        "perception.terrain_network / terrain_weights",
                        format!("{e} (or remove both to use the network built into the firmware)"),
                    ));
                }
            }
            _ => {
                return Err(self.invalid(
                    "perception.terrain_network / terrain_weights",
                    "give both the description and the weights, or neither (the built-in network)",
                ))
            }
        }
        if !pc.mount_xyz.iter().chain(&pc.mount_rpy).all(|v| v.is_finite()) {
            return Err(self.invalid("perception.mount_xyz / mount_rpy", "must be finite numbers"));
        }
        if !(pc.fallback_base_height_m.is_finite() && pc.fallback_base_height_m > 0.0) {
            return Err(self.invalid("perception.fallback_base_height_m", "must be > 0"));
        }
        Ok(())
    }

    /// Control, policy and perception rates; the start-up ramp and hold.
    fn validate_rates_and_startup(&self) -> Result<(), SpecError> {
        let r = &self.rates;
        if r.perception_hz == 0 || !r.control_hz.is_multiple_of(r.perception_hz) {
            return Err(self.invalid(
                "rates.perception_hz",
                format!(
                    "must be positive and divide control_hz ({}), got {}",
                    r.control_hz, r.perception_hz
                ),
            ));
        }
        if r.control_hz == 0 || r.policy_hz == 0 || !r.control_hz.is_multiple_of(r.policy_hz) {
            return Err(self.invalid(
                "rates",
                format!(
                    "policy_hz ({}) must be positive and divide control_hz ({})",
                    r.policy_hz, r.control_hz
                ),
            ));
        }
        let s = &self.startup;
        if !((0.0..=MAX_STARTUP_S).contains(&s.ramp_s) && (0.0..=MAX_STARTUP_S).contains(&s.hold_s)) {
            return Err(self.invalid(
                "startup",
                format!(
                    "ramp_s and hold_s must be 0 to {MAX_STARTUP_S} s, got {} and {}",
                    s.ramp_s, s.hold_s
                ),
            ));
        }
        Ok(())
    }

    /// The joint map, gains, action scale and clip, network and default pose. Returns the motor
    /// slots the policy drives (held groups may not drive them too).
    fn validate_policy(&self) -> Result<[bool; hal::NUM_MOTORS], SpecError> {
        let p = &self.policy;
        let n = p.joint_ids_map.len();
        if n == 0 {
            return Err(self.invalid("policy.joint_ids_map", "is empty"));
        }
        let mut used = [false; hal::NUM_MOTORS];
        for (i, &slot) in p.joint_ids_map.iter().enumerate() {
            if slot >= hal::NUM_MOTORS {
                return Err(self.invalid(
                    &format!("policy.joint_ids_map[{i}]"),
                    format!("slot {slot} out of range 0..{}", hal::NUM_MOTORS),
                ));
            }
            if used[slot] {
                return Err(self.invalid(
                    &format!("policy.joint_ids_map[{i}]"),
                    format!("slot {slot} appears twice"),
                ));
            }
            used[slot] = true;
        }
        if !p.joint_names.is_empty() {
            if p.joint_names.len() != n {
                return Err(self.invalid(
                    "policy.joint_names",
                    format!(
                        "{} entries, expected {n} (one per joint_ids_map entry)",
                        p.joint_names.len()
                    ),
                ));
            }
            for (i, name) in p.joint_names.iter().enumerate() {
                if hal::g1_motor_slot(name) != Some(p.joint_ids_map[i]) {
                    return Err(self.invalid(
                        &format!("policy.joint_names[{i}]"),
                        format!(
                            "'{name}' is not motor slot {} ('{}'): joint_ids_map and joint_names disagree",
                            p.joint_ids_map[i],
                            hal::G1_MOTOR_NAMES[p.joint_ids_map[i]]
                        ),
                    ));
                }
            }
        }
        for (field, v) in [
            ("policy.default_pose", &p.default_pose),
            ("policy.kp", &p.kp),
            ("policy.kd", &p.kd),
        ] {
            if v.len() != n {
                return Err(self.invalid(
                    field,
                    format!("{} entries, expected {n} (one per policy joint)", v.len()),
                ));
            }
            if v.iter().any(|x| !x.is_finite()) {
                return Err(self.invalid(field, "contains a non-finite value"));
            }
        }
        for (field, v) in [("startup.kp", &self.startup.kp), ("startup.kd", &self.startup.kd)] {
            if let Some(v) = v {
                if v.len() != n || v.iter().any(|x| !x.is_finite() || *x < 0.0) {
                    return Err(self.invalid(
                        field,
                        format!("needs {n} finite non-negative entries (one per policy joint)"),
                    ));
                }
            }
        }
        if p.action_scale.expand(n).is_none() {
            return Err(self.invalid("policy.action_scale", format!("per-joint list must have {n} entries")));
        }
        // Physical ranges (docs: "Deploy spec limits"): the runtime can then meet no value it
        // cannot handle.
        let gains = [
            ("policy.kp", Some(&p.kp), MAX_KP),
            ("policy.kd", Some(&p.kd), MAX_KD),
            ("startup.kp", self.startup.kp.as_ref(), MAX_KP),
            ("startup.kd", self.startup.kd.as_ref(), MAX_KD),
        ];
        for (field, v, max) in gains {
            if let Some((i, x)) = v.and_then(|v| v.iter().enumerate().find(|(_, x)| !(0.0..=max).contains(*x))) {
                return Err(self.invalid(&format!("{field}[{i}]"), format!("{x} is outside 0..={max}")));
            }
        }
        for (i, &x) in p.action_scale.expand(n).unwrap_or_default().iter().enumerate() {
            if !(x.is_finite() && x.abs() <= MAX_ACTION_SCALE) {
                return Err(self.invalid(
                    &format!("policy.action_scale[{i}]"),
                    format!("{x} is not a finite number within ±{MAX_ACTION_SCALE} rad per unit of action"),
                ));
            }
        }
        if let Some(c) = p.action_clip {
            if !(c > 0.0 && c <= MAX_CLIP) {
                return Err(self.invalid(
                    "policy.action_clip",
                    format!("{c}: must be a number in (0, {MAX_CLIP}]"),
                ));
            }
        }
        for (i, l) in p.network.layers.iter().enumerate() {
            if let crate::nn::LayerDesc::Elu { alpha } = l {
                if !(0.0..=MAX_ELU_ALPHA).contains(alpha) {
                    return Err(self.invalid(
                        &format!("policy.network.layers[{i}].alpha"),
                        format!("{alpha}: an ELU's alpha must be in 0..={MAX_ELU_ALPHA}"),
                    ));
                }
            }
        }
        let margin = self.safety.joint_range_margin_rad;
        for (i, (&slot, &q)) in p.joint_ids_map.iter().zip(&p.default_pose).enumerate() {
            if let Some((lo, hi)) = crate::robot::G1_JOINT_RANGE[slot] {
                if 2.0 * margin >= hi - lo {
                    return Err(self.invalid(
                        "safety.joint_range_margin_rad",
                        format!(
                            "{margin} leaves no range for {} ([{lo}, {hi}] rad)",
                            hal::G1_MOTOR_NAMES[slot]
                        ),
                    ));
                }
                if !(lo..=hi).contains(&q) {
                    return Err(self.invalid(
                        &format!("policy.default_pose[{i}]"),
                        format!("{q} rad is outside {}'s range [{lo}, {hi}]", hal::G1_MOTOR_NAMES[slot]),
                    ));
                }
            }
        }
        Ok(used)
    }

    /// Joints held at a pose outside the policy (the arms, the waist).
    fn validate_held(&self, mut used: [bool; hal::NUM_MOTORS]) -> Result<(), SpecError> {
        let margin = self.safety.joint_range_margin_rad;
        for (g, group) in self.held.iter().enumerate() {
            let k = group.joints.len();
            for (j, name) in group.joints.iter().enumerate() {
                let field = format!("held[{g}].joints[{j}]");
                let slot =
                    hal::g1_motor_slot(name).ok_or_else(|| self.invalid(&field, format!("unknown motor '{name}'")))?;
                if used[slot] {
                    return Err(self.invalid(&field, format!("'{name}' is already driven or held")));
                }
                used[slot] = true;
            }
            for (f, sc, lo, hi) in [
                ("q", &group.q, -std::f32::consts::TAU, std::f32::consts::TAU),
                ("kp", &group.kp, 0.0, MAX_KP),
                ("kd", &group.kd, 0.0, MAX_KD),
            ] {
                // (`contains` is false for NaN, so a NaN is refused here too.)
                let Some(v) = sc.expand(k) else {
                    return Err(self.invalid(
                        &format!("held[{g}].{f}"),
                        format!("per-joint list must have {k} entries"),
                    ));
                };
                if let Some((j, x)) = v.iter().enumerate().find(|(_, x)| !(lo..=hi).contains(*x)) {
                    return Err(self.invalid(&format!("held[{g}].{f}[{j}]"), format!("{x} is outside {lo}..={hi}")));
                }
            }
            // A held target is a joint position like any other: inside the joint's range, less the
            // margin the controller clamps policy targets to.
            let q = group.q.expand(k).unwrap_or_default();
            for (j, name) in group.joints.iter().enumerate() {
                let Some(slot) = hal::g1_motor_slot(name) else { continue };
                if let Some((lo, hi)) = crate::robot::G1_JOINT_RANGE[slot] {
                    let (lo, hi) = (lo + margin, hi - margin);
                    if !(lo..=hi).contains(&q[j]) {
                        return Err(self.invalid(
                            &format!("held[{g}].q[{j}]"),
                            format!(
                                "{} rad is outside {name}'s range less safety.joint_range_margin_rad, [{lo}, {hi}] rad",
                                q[j]
                            ),
                        ));
                    }
                }
            }
        }
        Ok(())
    }

    /// The operator's command limits and the gait phase clock.
    fn validate_commands_and_phase(&self) -> Result<(), SpecError> {
        for (field, v) in [("commands.min", self.commands.min), ("commands.max", self.commands.max)] {
            let bad = |x: &f32| !(-MAX_COMMAND..=MAX_COMMAND).contains(x);
            if let Some((i, x)) = v.and_then(|v| v.into_iter().enumerate().find(|(_, x)| bad(x))) {
                return Err(self.invalid(
                    &format!("{field}[{i}]"),
                    format!("{x}: must be a velocity within ±{MAX_COMMAND} (m/s, rad/s)"),
                ));
            }
        }
        if let (Some(lo), Some(hi)) = (self.commands.min, self.commands.max) {
            if (0..3).any(|i| lo[i] > hi[i]) {
                return Err(self.invalid("commands", "min must be <= max for vx, vy, wz"));
            }
        }
        if let Some(ph) = &self.phase {
            if !(ph.period_s > 0.0 && ph.period_s <= MAX_PHASE_PERIOD_S) {
                return Err(self.invalid(
                    "phase.period_s",
                    format!("{}: a gait period must be in (0, {MAX_PHASE_PERIOD_S}] s", ph.period_s),
                ));
            }
            // The clock starts here and advances one policy period per step: any finite start
            // within a period or so is meaningful; NaN or ±1e300 only poison the observation.
            if !(ph.first_step_time_s.is_finite() && ph.first_step_time_s.abs() <= 1e3) {
                return Err(self.invalid(
                    "phase.first_step_time_s",
                    format!("{}: must be a finite time within ±1000 s", ph.first_step_time_s),
                ));
            }
            if let Some(r) = ph.rate {
                if !(r.min > 0.0 && r.min <= 1.0 && r.max >= 1.0 && r.max <= MAX_PHASE_RATE) {
                    return Err(self.invalid(
                        "phase.rate",
                        format!(
                            "min {} and max {}: need 0 < min <= 1 <= max <= {MAX_PHASE_RATE} (1 is the nominal clock)",
                            r.min, r.max
                        ),
                    ));
                }
            }
        }
        Ok(())
    }

    /// The observation terms, their scales and history, and the network's input size.
    fn validate_observation(&self) -> Result<(), SpecError> {
        let n = self.num_joints();
        for (i, t) in self.observation.terms.iter().enumerate() {
            let field = format!("observation.terms[{i}]");
            if !(1..=MAX_OBS_HISTORY).contains(&t.history) {
                return Err(self.invalid(
                    &format!("{field}.history"),
                    format!("{} frames: must be 1 to {MAX_OBS_HISTORY}", t.history),
                ));
            }
            match t.scale.expand(t.kind.dim(n)) {
                None => {
                    return Err(self.invalid(
                        &format!("{field}.scale"),
                        format!("per-element list must have {} entries for {:?}", t.kind.dim(n), t.kind),
                    ))
                }
                Some(v) if v.iter().any(|x| !(-MAX_OBS_SCALE..=MAX_OBS_SCALE).contains(x)) => {
                    return Err(self.invalid(
                        &format!("{field}.scale"),
                        format!("every scale must be a number within ±{MAX_OBS_SCALE}"),
                    ))
                }
                Some(_) => {}
            }
            if t.kind == ObsKind::GaitPhase && self.phase.is_none() {
                return Err(self.invalid(&field, "gait_phase needs a [phase] section"));
            }
            if let Some(c) = t.clip {
                if !(c > 0.0 && c <= MAX_CLIP) {
                    return Err(self.invalid(&format!("{field}.clip"), format!("{c}: must be in (0, {MAX_CLIP}]")));
                }
            }
            if let Some([lo, hi]) = t.clip_before_scale {
                if lo.is_nan() || hi.is_nan() || lo > hi {
                    return Err(self.invalid(
                        &format!("{field}.clip_before_scale"),
                        format!("[low, high] with low <= high, got [{lo}, {hi}]"),
                    ));
                }
            }
        }
        if self.observation.history_layout == HistoryLayout::FrameMajor {
            let h0 = self.observation.terms.first().map_or(1, |t| t.history);
            if self.observation.terms.iter().any(|t| t.history != h0) {
                return Err(self.invalid(
                    "observation.history_layout",
                    "frame_major needs the same history length for every term",
                ));
            }
        }

        let obs_dim = match self.checked_observation_dim() {
            Some(d) if d <= MAX_OBSERVATION_DIM => d,
            _ => {
                return Err(self.invalid(
                    "observation",
                    format!("terms add up to more than {MAX_OBSERVATION_DIM} values"),
                ))
            }
        };
        if obs_dim != self.policy.network.input {
            return Err(self.invalid(
                "observation",
                format!(
                    "terms add up to {obs_dim} values but policy.network.input is {}",
                    self.policy.network.input
                ),
            ));
        }
        Ok(())
    }
}
