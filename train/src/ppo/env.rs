//! One training environment: the G1 in MuJoCo (`g1_sim::Simulator`, in process) on a stair world,
//! observed and commanded through the firmware's own `PolicyIo` built from the deploy spec, with the
//! actor run by the firmware's own executor (`control::nn::Network`).
//!
//! Per policy step (50 Hz): the simulator's `LowState` (plus observation noise) → `PolicyIo::observe`
//! with the operator command (`control::operator`-style heading hold) and the privileged terrain
//! token (`World::truth`, paper stage 1, refreshed at the perception rate of 10 Hz with noise shaped
//! like the CNN's errors) → actor → `PolicyIo::apply_action` (clip, scale, joint-range clamp) → PD
//! targets with the spec's gains → physics steps of 5 ms up to the spec's policy period (4 at
//! 50 Hz), the new command arriving after a random latency of 0–4 of them. Rewards are in
//! [`super::reward`]; the episode ends on the same walls the firmware's supervisor trips on
//! (`control::supervisor::MotionLimits`, from the spec's `[safety]`), or a base too low.
//!
//! Determinism: an environment draws everything from its own seeded generator, so a rollout is the
//! same for the same seed whatever the thread count.
use std::sync::Arc;

use control::actor::Actor;
use control::nn::Network;
use control::policy_io::PolicyIo;
use control::spec::{DeploySpec, ObsKind};
use control::supervisor::MotionLimits;
use firmware::sim_run::LandingHold;
use g1_sim::world::{Outdoor, TerrainKind, TerrainSpec, World};
use g1_sim::{ModelChoice, SimConfig, Simulator};
use hal::{LowCommand, LowState, TerrainClass, TerrainToken, MOTOR_MODE_ENABLED, NUM_MOTORS};
use labkit::rng::Rng;
use mujoco_rs::mujoco_c::_mjtObjBase;

use super::curriculum;
pub use super::curriculum::Column;
pub use super::curriculum::{level_height, LEVELS, MAX_STEPS};
use super::reward::{self, Terms, Weights, WEIGHTS};
use super::stair_turn::StairTurn;
use super::termination;
pub use super::termination::FALL_CAUSES;

/// Physics step of training (the field's 5 ms with implicit integration).
pub const PHYSICS_DT: f64 = 0.005;

/// The rates of training, from the spec's `[rates]`: what g1fw runs is what was trained.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Timing {
    /// Physics steps per policy step (4 at 50 Hz).
    pub decimation: usize,
    /// Policy period, s.
    pub policy_dt: f64,
    /// Policy steps between terrain-token refreshes (the perception rate; 5 at 10 Hz).
    pub token_period: u32,
}

impl Timing {
    pub fn from_spec(spec: &DeploySpec) -> anyhow::Result<Self> {
        let r = &spec.rates;
        let per_policy = 1.0 / (r.policy_hz as f64 * PHYSICS_DT);
        let decimation = per_policy.round() as usize;
        anyhow::ensure!(
            decimation >= 1 && (per_policy - decimation as f64).abs() < 1e-9,
            "rates.policy_hz = {} is not a whole number of {PHYSICS_DT} s physics steps; \
             the trainer needs policy_hz to divide {}",
            r.policy_hz,
            (1.0 / PHYSICS_DT).round()
        );
        anyhow::ensure!(
            r.perception_hz >= 1 && r.policy_hz.is_multiple_of(r.perception_hz),
            "rates.perception_hz = {} must divide rates.policy_hz = {} for training",
            r.perception_hz,
            r.policy_hz
        );
        Ok(Self {
            decimation,
            policy_dt: decimation as f64 * PHYSICS_DT,
            token_period: r.policy_hz / r.perception_hz,
        })
    }
}

/// Where the soft joint-speed penalty starts, as a share of each joint's limit (legged_gym's
/// `soft_dof_vel_limit`).
pub const SOFT_JOINT_SPEED: f32 = 0.9;
/// Privileged critic inputs beyond the actor's observation: body velocity (3), base height above
/// the ground (1), true token (4), foot contacts (2), terrain heights along the heading (11), foot
/// clearances (2).
pub const CRITIC_EXTRA: usize = 23;
/// Terrain samples for the critic: along the heading from −0.3 m to 1.2 m.
const HEIGHT_SAMPLES: usize = 11;

/// The simulator settings of training: 5 ms physics steps, one per `step_control_tick` (the
/// environment applies the command per physics step to model the action latency).
pub fn sim_config(seed: u64) -> SimConfig {
    SimConfig {
        physics_dt: PHYSICS_DT,
        control_dt: PHYSICS_DT,
        seed,
        imu_noise: None,
        physics: g1_sim::PhysicsProfile::Training,
        ..SimConfig::default()
    }
}

/// Terrain pool every environment's model carries: enough boxes and cylinders for the largest
/// world the curriculum draws (8 outdoor steps with nosings), found by building it.
pub fn terrain_capacity() -> (usize, usize) {
    let spec = TerrainSpec {
        kind: TerrainKind::StairsUp,
        step_height: 0.2,
        step_depth: 0.3,
        steps: MAX_STEPS,
        width: 2.0,
        yaw_deg: 0.0,
        start_distance: 1.0,
        lateral_offset: 0.0,
        landing_before: 2.0,
        landing_after: 2.0,
        outdoor: Some(Outdoor {
            height_jitter: 0.1,
            depth_jitter: 0.1,
            tread_slope_deg: 2.0,
            nosing_radius: 0.02,
            seed: 1,
        }),
    };
    let prims = World::build("capacity", spec).expect("valid").primitives();
    let boxes = prims
        .iter()
        .filter(|p| matches!(p, g1_sim::world::Primitive::Box { .. }))
        .count();
    (boxes, prims.len() - boxes)
}

/// What an environment randomises (all on by default; tests turn them off).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Randomization {
    /// Uniform observation noise: gyro (rad/s), joint position (rad), joint velocity (rad/s).
    pub obs_noise: [f32; 3],
    /// Token noise like the CNN's measured errors: h σ (m), d σ (m), yaw σ (rad), class flips
    /// when the labelled riser sits near the look-ahead box's far edge (probability).
    pub token_noise: [f64; 4],
    /// Action latency drawn per episode, physics steps (0 … this).
    pub max_latency_steps: usize,
    /// Random pushes: velocity change (m/s) every 4–8 s.
    pub push_mps: f64,
    /// Per episode: friction ×0.5–1.25, base mass −1…+3 kg, motor strength and kp ×0.9–1.1.
    pub dynamics: bool,
}

impl Randomization {
    pub const DEFAULT: Self = Self {
        obs_noise: [0.2, 0.01, 1.5],
        token_noise: [0.01, 0.02, 0.045, 0.3],
        max_latency_steps: 4, // 20 ms: one policy period at 50 Hz
        push_mps: 0.5,
        dynamics: true,
    };
    pub const NONE: Self = Self {
        obs_noise: [0.0; 3],
        token_noise: [0.0; 4],
        max_latency_steps: 0,
        push_mps: 0.0,
        dynamics: false,
    };
}

#[derive(Clone, Debug)]
pub struct EnvConfig {
    pub model: ModelChoice,
    pub spec: Arc<DeploySpec>,
    pub settings: EnvSettings,
}

/// How environments are drawn, commanded and rewarded: what `g1-train ppo`'s options set, held
/// once so that the run's config, each environment's and the tests' share one list of them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EnvSettings {
    /// Episode length, s.
    pub episode_s: f64,
    pub random: Randomization,
    /// Commanded forward speed range, m/s.
    pub vx: (f64, f64),
    /// Highest curriculum level a new environment starts at.
    pub max_init_level: usize,
    /// Train on this terrain column only (default: the curriculum's mix).
    pub only: Option<Column>,
    /// Share of flat-column episodes commanded as a joystick does: a constant (vx, vy, wz) from
    /// [`JOYSTICK_VY`] and [`JOYSTICK_WZ`], without heading hold, so the policy learns to hold a
    /// zero turn rate itself (`g1fw sim` without `--heading`). 0: every episode holds a heading.
    pub joystick_share: f64,
    /// Where the soft joint-speed penalty starts, as a share of each joint's limit from the spec
    /// ([`SOFT_JOINT_SPEED`] by default). Below 0.9 it leaves a margin for the deploy physics
    /// (2 ms steps and mesh contacts), whose peaks run higher than training's 5 ms steps.
    pub soft_joint_speed: f32,
    /// End a staircase episode as a failure (the termination penalty, demotion) once the base has
    /// gained less than [`firmware::eval::STALL_PROGRESS_M`] along the staircase in the last
    /// [`firmware::eval::STALL_WINDOW_S`]: `g1fw eval`'s `stalled`. Without it a policy can learn
    /// to stand at the first riser, which a noisy rollout hides and the mean action shows (run 19:
    /// up 11 cm 8/16 in `g1-train ppo-eval` at 20.2 M env steps, 0/16, all time-outs, at 22.6 M).
    pub end_stalled: bool,
    /// How environments split between the columns: flat ground's share
    /// ([`curriculum::FLAT_SHARE`] by default) and the climbing share of the stair columns
    /// ([`curriculum::UP_SHARE`]).
    pub mix: curriculum::ColumnMix,
    /// Standard deviation of the two tracking kernels, m/s and rad/s ([`reward::TRACKING_STD`]
    /// by default). A tighter kernel pays more for walking at the commanded speed rather than
    /// near it (run 20 walked 0.59 m/s for 0.5 and 0.47 for 0.3 on flat ground).
    pub tracking_std: f64,
    /// Forward speed range of joystick episodes, m/s (`None`: [`EnvSettings::vx`]). Including 0 and
    /// negative speeds teaches the policy to stop and back up when a joystick asks (run 21's actor,
    /// trained on 0.4–0.8 and a 5 % stand, walked 0.27 m/s when asked for 0).
    pub joystick_vx: Option<(f64, f64)>,
    /// Share of episodes commanded to stand (vx 0), on every column (IsaacLab's
    /// `rel_standing_envs`; [`STAND_SHARE`] by default).
    pub stand_share: f64,
    /// The lowest curriculum level of the climbing columns (up and outdoor up): they start there
    /// at least and are never demoted below it, so the climbs train at the heights that fail
    /// (the committed actor's climbing environments sat near level 3.8, 13 cm, while `g1fw`
    /// scores 12–22 cm). 0 (default): no floor.
    pub up_level_floor: usize,
    /// Share of staircase episodes that review: drawn at a level uniformly from the column's
    /// floor to its curriculum level, and moving no level ([`curriculum::episode_level`]).
    /// 0 (default): every episode trains at the frontier.
    pub review_share: f64,
    /// Weight of the `flat_orientation` penalty ‖g_xy‖² (IsaacLab's G1 −1 by default, mjlab's
    /// G1 −5). The committed actor walks flat ground leaning 11° sideways at −1.
    pub flat_orientation_weight: f64,
    /// Weight of the `drift` penalty (m across the target heading's line; `reward::drift`).
    /// 0 (default): off.
    pub drift_weight: f64,
    /// Heading-hold episodes also steer back to the line through the start along the target
    /// heading, by `g1fw sim|eval --hold-line`'s rule (`control::operator::line_heading`), from
    /// the simulator's base position (the firmware reads its estimator's). false (default): off.
    pub hold_line: bool,
    /// Share of heading-hold staircase episodes whose target heading leaves the axis once and
    /// comes back ([`StairTurn`]), so the policy is asked to turn while it climbs.
    /// 0 (default): every staircase episode holds the axis.
    pub stair_turn_share: f64,
    /// Weight of the `yaw_rate_error` penalty (the squared turn-rate error, `reward`).
    /// 0 (default): off.
    pub yaw_error_weight: f64,
    /// How far ahead of the swing foot, along its travel, the terrain counts for the
    /// `foot_clearance` term, m ([`reward::CLEARANCE_LOOKAHEAD`], the toe, by default). Longer,
    /// the term asks for the lift before the toe reaches a riser, not as it meets it.
    pub clearance_lookahead: f64,
    /// Weight of the `riser_clearance` penalty (the sole below the next higher tread's top plus
    /// [`reward::RISER_MARGIN`], `reward`). 0 (default): off.
    pub riser_clearance_weight: f64,
    /// Weight of the `foothold_edge` penalty (a foot in contact across a tread's edge,
    /// `reward`). 0 (default): off.
    pub foothold_edge_weight: f64,
    /// Weight of the `token_clearance` penalty (a swing below the observed token's step height
    /// plus a margin, on up flights, `reward`). 0 (default): off.
    pub token_clearance_weight: f64,
    /// Weight of the `swing_apex` penalty (a swing whose apex stayed below the observed token's
    /// step height plus a margin, charged once at touchdown on up flights, `reward`). 0
    /// (default): off.
    pub swing_apex_weight: f64,
    /// Weight of the `swing_advance` penalty (a swing on an up flight that carried the foot less
    /// than a tread forward; `reward::swing_advance_target`). 0 (default): off.
    pub swing_advance_weight: f64,
    /// Weight of the `swing_overshoot` penalty (a swing on an up flight whose apex rose more than
    /// `reward::SWING_OVERSHOOT_MARGIN_M` above what `swing_apex` asks). 0 (default): off.
    pub swing_overshoot_weight: f64,
    /// Weight of the `base_height` penalty (the base lower than `reward::BASE_HEIGHT_TARGET_M`
    /// over the feet's ground while the token reads up). 0 (default): off.
    pub base_height_weight: f64,
    /// Weight of the `up_lean` penalty (the base pitched less than `reward::UP_LEAN_TARGET_RAD`
    /// forward while the token reads up). 0 (default): off.
    pub up_lean_weight: f64,
    /// Weight of the `stance_lead` penalty (a lone stance foot more than
    /// `reward::STANCE_LEAD_MAX_M` ahead of the base while the token reads up). 0 (default): off.
    pub stance_lead_weight: f64,
    /// Assisted climbs ([`super::assist`]): a share of the climbing columns' episodes at hard
    /// levels with a decaying helping hand on the base. Off by default.
    pub assist: super::assist::Assist,
}

/// The default share of episodes commanded to stand.
pub const STAND_SHARE: f64 = 0.05;

impl EnvSettings {
    /// `g1-train ppo`'s defaults.
    pub const DEFAULT: Self = Self {
        episode_s: 20.0,
        random: Randomization::DEFAULT,
        vx: (0.3, 0.8),
        max_init_level: 2,
        only: None,
        joystick_share: 0.0,
        soft_joint_speed: SOFT_JOINT_SPEED,
        end_stalled: false,
        mix: curriculum::ColumnMix {
            flat: curriculum::FLAT_SHARE,
            up: curriculum::UP_SHARE,
        },
        tracking_std: reward::TRACKING_STD,
        joystick_vx: None,
        stand_share: STAND_SHARE,
        up_level_floor: 0,
        review_share: 0.0,
        flat_orientation_weight: reward::WEIGHTS.flat_orientation,
        drift_weight: reward::WEIGHTS.drift,
        hold_line: false,
        stair_turn_share: 0.0,
        yaw_error_weight: reward::WEIGHTS.yaw_rate_error,
        clearance_lookahead: reward::CLEARANCE_LOOKAHEAD,
        riser_clearance_weight: reward::WEIGHTS.riser_clearance,
        foothold_edge_weight: reward::WEIGHTS.foothold_edge,
        token_clearance_weight: reward::WEIGHTS.token_clearance,
        swing_apex_weight: reward::WEIGHTS.swing_apex,
        swing_advance_weight: reward::WEIGHTS.swing_advance,
        swing_overshoot_weight: reward::WEIGHTS.swing_overshoot,
        base_height_weight: reward::WEIGHTS.base_height,
        up_lean_weight: reward::WEIGHTS.up_lean,
        stance_lead_weight: reward::WEIGHTS.stance_lead,
        assist: super::assist::Assist::OFF,
    };
}

impl Default for EnvSettings {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Lateral speed commands of joystick episodes, m/s (symmetric).
pub const JOYSTICK_VY: f64 = 0.2;
/// Turn-rate commands of joystick episodes, rad/s (symmetric; a third of them exactly 0).
pub const JOYSTICK_WZ: f64 = 0.5;

/// Result of one step.
#[derive(Clone, Copy, Debug, Default)]
pub struct StepOut {
    pub reward: f32,
    /// The episode ended by a fall or trip (no bootstrap).
    pub terminated: bool,
    /// The episode ended by time-out or success (bootstrap from the value of the final state).
    pub truncated: bool,
}

/// Statistics of a finished episode.
#[derive(Clone, Copy, Debug, Default)]
pub struct EpisodeEnd {
    pub column: Option<Column>,
    /// The episode commanded a stand ([`StairEnv::standing`]): no success to score.
    pub standing: bool,
    /// Why it fell: an index into [`FALL_CAUSES`] (meaningful when `fell`).
    pub cause: usize,
    /// The level this episode's staircase was drawn at.
    pub level: usize,
    /// A review episode ([`EnvSettings::review_share`]): below the frontier, moving no level.
    pub review: bool,
    /// An assisted episode ([`EnvSettings::assist`]): moves no level, has its own success rate.
    pub assisted: bool,
    pub success: bool,
    pub fell: bool,
    pub ret: f64,
    /// The return split by reward term, in [`super::reward::Terms::named`]'s order (before the
    /// per-step bound, which clips only extreme steps).
    pub ret_by_term: [f64; super::reward::TERM_COUNT],
    pub steps: usize,
    /// Farthest the base got along the staircase axis, and where success starts, m.
    pub progress_m: f64,
    pub goal_m: f64,
    /// Where the base started along the staircase axis, m.
    pub start_m: f64,
}

pub struct StairEnv {
    cfg: EnvConfig,
    timing: Timing,
    limits: MotionLimits,
    /// The spec's scale of the terrain token term (class, h, d, yaw), for the critic's true token.
    token_scale: [f32; 4],
    sim: Simulator,
    io: PolicyIo,
    /// The actor as the spec runs it (the firmware's [`control::actor::Actor`]: the network, and
    /// its mirrored twin with `[policy] mirror = "average"`).
    pub net: Actor,
    rng: Rng,
    world: World,
    pub column: Column,
    /// The curriculum level: where this environment's column trains.
    pub level: usize,
    /// The level the current episode's staircase was drawn at ([`curriculum::episode_level`]).
    episode_level: usize,
    /// The current episode reviews a level below the frontier and moves no level.
    review: bool,
    /// The current episode's assistant strength (0: none; [`super::assist`]), and whether the
    /// episode is an assisted one (it stays one once the strength has decayed to 0).
    assist_strength: f64,
    assisted: bool,
    /// The strength the next assisted episode gets (the runner decays it with the env steps).
    assist_now: f64,
    robot_mass: f64,
    vx_cmd: f32,
    heading: f64,
    /// A joystick episode's constant command (vx, vy, wz), in place of heading hold.
    joystick: Option<[f32; 3]>,
    /// This episode's commanded turn off the staircase's axis (none: `StairTurn::default()`).
    turn: StairTurn,
    token: TerrainToken,
    token_phase: u32,
    latency: usize,
    kp: [f32; NUM_MOTORS],
    kd: [f32; NUM_MOTORS],
    enabled: [bool; NUM_MOTORS],
    default_q: [f32; NUM_MOTORS],
    target_q: [f32; NUM_MOTORS],
    cmd_now: LowCommand,
    cmd_prev: LowCommand,
    state: LowState,
    slots: Vec<usize>,
    prev_action: Vec<f32>,
    prev_dq: Vec<f32>,
    /// Fastest |dq| of each motor over the physics steps of the current policy step.
    peak_dq: [f32; NUM_MOTORS],
    /// The first supervisor wall (tilt, joint speed, base angular speed; a [`FALL_CAUSES`] index)
    /// hit at any physics step of the current policy step.
    physics_step_trip: Option<usize>,
    air_time: [f64; 2],
    /// The highest sole clearance over the ground under the foot in the current swing, m.
    swing_peak: [f64; 2],
    /// Where each foot lifted off (x, y), m: the start of its current swing.
    swing_start: [[f64; 2]; 2],
    contact_time: [f64; 2],
    prev_foot: [[f64; 3]; 2],
    foot_body: [usize; 2],
    sole_offset: f64,
    step: usize,
    max_steps: usize,
    next_push: usize,
    progress: f64,
    /// Progress along the staircase for `--end-stalled` (`g1fw eval`'s own stall rule).
    stall: firmware::eval::StallWatch,
    /// How long the base has stood on the end landing (`g1fw eval`'s success).
    landing: LandingHold,
    fell: bool,
    cause: usize,
    ret: f64,
    /// The current episode's return by reward term ([`EpisodeEnd::ret_by_term`]).
    ret_by_term: [f64; super::reward::TERM_COUNT],
    /// Keep this curriculum level on every reset (in-environment evaluation).
    held_level: Option<usize>,
    /// Command this forward speed in every episode (in-environment evaluation).
    held_vx: Option<f32>,
    /// Assist every episode at this strength (in-environment evaluation; 0: none).
    held_assist: f64,
    start_s: f64,
    pub last_end: Option<EpisodeEnd>,
}

fn yaw_of(q: [f64; 4]) -> f64 {
    let [w, x, y, z] = q;
    (2.0 * (w * z + x * y)).atan2(1.0 - 2.0 * (y * y + z * z))
}

impl StairEnv {
    /// An environment running the actor `weights` (safetensors in the spec's network layout).
    pub fn new(cfg: EnvConfig, seed: u64, weights: &[u8]) -> anyhow::Result<Self> {
        let mut rng = Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ 0x5747_5254);
        let world = World::preset("flat").expect("preset");
        let sim = Self::load_sim(&cfg, seed)?;
        let spec = &cfg.spec;
        let timing = Timing::from_spec(spec)?;
        let limits = MotionLimits::from_spec(spec);
        let token_scale = spec
            .observation
            .terms
            .iter()
            .find(|t| t.kind == ObsKind::TerrainToken)
            .and_then(|t| t.scale.expand(4))
            .map_or([1.0; 4], |v| [v[0], v[1], v[2], v[3]]);
        let io = PolicyIo::new(spec);
        let net = Actor::new(spec, Network::from_safetensors_bytes(&spec.policy.network, weights)?)?;
        // Driven and held motors exactly as the firmware commands them; slots the model lacks off.
        let control::spec::MotorTable {
            mut enabled,
            default_q,
            kp,
            kd,
        } = spec.motor_table();
        let present = sim.motor_slots_present();
        for (s, e) in enabled.iter_mut().enumerate() {
            *e &= present & (1 << s) != 0;
        }
        let m = sim.data().model();
        let body = |n: &str| {
            m.name_to_id(_mjtObjBase::mjOBJ_BODY, n)
                .ok_or_else(|| anyhow::anyhow!("model has no body {n}"))
        };
        let foot_body = [body("left_ankle_roll_link")?, body("right_ankle_roll_link")?];
        let n = spec.num_joints();
        let level = rng.int(0, cfg.settings.max_init_level as u64) as usize;
        let mut env = Self {
            max_steps: (cfg.settings.episode_s / timing.policy_dt).round() as usize,
            timing,
            limits,
            token_scale,
            io,
            net,
            world,
            column: Column::draw(&mut rng, cfg.settings.only, cfg.settings.mix),
            level,
            episode_level: level,
            review: false,
            assist_strength: 0.0,
            assisted: false,
            assist_now: cfg.settings.assist.strength(0),
            robot_mass: sim.robot_mass(),
            vx_cmd: 0.0,
            heading: 0.0,
            joystick: None,
            turn: StairTurn::default(),
            token: TerrainToken::FLAT,
            token_phase: 0,
            latency: 0,
            kp,
            kd,
            enabled,
            default_q,
            target_q: default_q,
            cmd_now: LowCommand::default(),
            cmd_prev: LowCommand::default(),
            state: LowState::default(),
            slots: spec.policy.joint_ids_map.clone(),
            prev_action: vec![0.0; n],
            prev_dq: vec![0.0; n],
            peak_dq: [0.0; NUM_MOTORS],
            physics_step_trip: None,
            air_time: [0.0; 2],
            swing_peak: [0.0; 2],
            swing_start: [[0.0; 2]; 2],
            contact_time: [0.0; 2],
            prev_foot: [[0.0; 3]; 2],
            foot_body,
            sole_offset: 0.0,
            step: 0,
            next_push: 0,
            progress: f64::NEG_INFINITY,
            stall: firmware::eval::StallWatch::default(),
            landing: LandingHold::default(),
            fell: false,
            cause: 0,
            ret: 0.0,
            ret_by_term: [0.0; super::reward::TERM_COUNT],
            held_level: None,
            held_vx: None,
            held_assist: 0.0,
            start_s: 0.0,
            last_end: None,
            rng,
            sim,
            cfg,
        };
        env.reset()?;
        Ok(env)
    }

    fn load_sim(cfg: &EnvConfig, seed: u64) -> anyhow::Result<Simulator> {
        let (boxes, cylinders) = terrain_capacity();
        Ok(Simulator::load_with_terrain_capacity(
            cfg.model.clone(),
            sim_config(seed),
            boxes,
            cylinders,
        )?)
    }

    /// The lowest level this environment's column trains at ([`EnvSettings::up_level_floor`]).
    fn level_floor(&self) -> usize {
        if self.column.climbs() {
            self.cfg.settings.up_level_floor
        } else {
            0
        }
    }

    /// Puts the environment in curriculum `column` at `level` (the runner's assignment, or where a
    /// resumed run left it) and starts its first episode there.
    pub fn place(&mut self, column: Column, level: usize) -> anyhow::Result<()> {
        self.column = column;
        self.level = level.max(self.level_floor()).min(LEVELS - 1);
        self.step = 0;
        self.reset()
    }

    /// Drops the episode in progress without scoring it, takes a new random stream from `seed`,
    /// and starts afresh in `column` at `level`: what a freshly made environment does after
    /// `place`, whatever this one ran before (a checkpoint restarts every environment this way,
    /// in the run that goes on and in the one that resumes it).
    pub fn restart(&mut self, seed: u64, column: Column, level: usize) -> anyhow::Result<()> {
        self.rng = Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ 0x5747_5254);
        self.last_end = None;
        self.place(column, level)
    }

    /// Holds the curriculum at `level` and the forward command at `vx` from now on, and starts a
    /// new episode there (in-environment evaluation).
    pub fn hold(&mut self, level: usize, vx: f32) -> anyhow::Result<()> {
        let level = level.min(LEVELS - 1);
        self.held_level = Some(level);
        self.held_vx = Some(vx);
        self.level = level;
        self.step = 0;
        self.reset()
    }

    /// Ends the current episode's bookkeeping (curriculum) and starts a new one.
    pub fn reset(&mut self) -> anyhow::Result<()> {
        if self.step > 0 {
            let success = self.succeeded();
            self.last_end = Some(EpisodeEnd {
                column: Some(self.column),
                standing: self.standing(),
                level: self.episode_level,
                review: self.review,
                assisted: self.assisted,
                success,
                fell: self.fell,
                cause: self.cause,
                ret: self.ret,
                ret_by_term: self.ret_by_term,
                steps: self.step,
                progress_m: self.progress,
                goal_m: self.last_riser_s() + sim_hal::bridge::END_LANDING_MARGIN_M,
                start_m: self.start_s,
            });
            if let Some(l) = self.held_level {
                self.level = l;
            } else if self.column != Column::Flat && !self.standing() && !self.review && !self.assisted {
                let walked_half = self.progress >= 0.5 * self.last_riser_s();
                let floor = self.level_floor();
                self.level = curriculum::next_level(self.level, success, walked_half, floor, &mut self.rng);
            }
            // The column stays: the level is this column's (see `Column::for_env`).
        }
        // Drawn only when enabled, so runs without reviews keep their random streams.
        self.review = self.held_level.is_none()
            && self.column != Column::Flat
            && self.cfg.settings.review_share > 0.0
            && self.rng.chance(self.cfg.settings.review_share);
        // Drawn only when enabled, so runs without assisted climbs keep their random streams.
        let assist = self.cfg.settings.assist;
        self.assisted =
            self.held_level.is_none() && self.column.climbs() && assist.share > 0.0 && self.rng.chance(assist.share);
        self.assist_strength = if self.assisted { self.assist_now } else { 0.0 };
        self.episode_level = if self.assisted {
            self.review = false;
            self.rng.int(assist.levels.0 as u64, assist.levels.1 as u64) as usize
        } else {
            curriculum::episode_level(self.level, self.level_floor(), self.review, &mut self.rng)
        };
        if self.held_level.is_some() && self.held_assist > 0.0 {
            self.assisted = true;
            self.assist_strength = self.held_assist;
        }
        self.world = curriculum::draw_world(self.column, self.episode_level, &mut self.rng);
        self.sim.set_world(&self.world)?;
        let r = self.cfg.settings.random;
        if r.dynamics {
            self.sim.set_friction(self.rng.range(0.5, 1.25))?;
            self.sim.set_added_base_mass(self.rng.range(-1.0, 3.0))?;
            self.sim.set_motor_strength(self.rng.range(0.9, 1.1))?;
            self.sim.set_kp_scale(self.rng.range(0.9, 1.1))?;
        }
        self.sim.reset();
        self.io.reset();
        self.net.reset();
        self.latency = self.rng.int(0, r.max_latency_steps as u64) as usize;
        self.token_phase = self.rng.int(0, self.timing.token_period as u64 - 1) as u32;
        self.vx_cmd = if let Some(vx) = self.held_vx {
            vx
        } else if !self.assisted && self.rng.chance(self.cfg.settings.stand_share) {
            0.0
        } else {
            self.rng.range(self.cfg.settings.vx.0, self.cfg.settings.vx.1) as f32
        };
        self.heading = self.world.stairs.as_ref().map_or(0.0, |s| s.yaw) + 0.05 * self.rng.gaussian();
        self.joystick = None;
        // Drawn only when enabled, so runs without joystick episodes keep their random streams.
        if self.column == Column::Flat
            && self.held_vx.is_none()
            && self.cfg.settings.joystick_share > 0.0
            && self.rng.chance(self.cfg.settings.joystick_share)
        {
            let vy = self.rng.range(-JOYSTICK_VY, JOYSTICK_VY);
            let wz = if self.rng.chance(1.0 / 3.0) {
                0.0
            } else {
                self.rng.range(-JOYSTICK_WZ, JOYSTICK_WZ)
            };
            if let Some((lo, hi)) = self.cfg.settings.joystick_vx {
                self.vx_cmd = self.rng.range(lo, hi) as f32;
            }
            self.joystick = Some([self.vx_cmd, vy as f32, wz as f32]);
        }
        self.turn = StairTurn::default();
        // Drawn only when enabled, so runs without turns keep their random streams.
        if self.column != Column::Flat
            && self.held_vx.is_none()
            && self.cfg.settings.stair_turn_share > 0.0
            && self.rng.chance(self.cfg.settings.stair_turn_share)
        {
            self.turn = StairTurn::draw(&mut self.rng);
        }
        self.step = 0;
        self.fell = false;
        self.ret = 0.0;
        self.ret_by_term = [0.0; super::reward::TERM_COUNT];
        self.progress = f64::NEG_INFINITY;
        self.stall = firmware::eval::StallWatch::default();
        self.landing = LandingHold::default();
        self.next_push = self.push_interval();
        self.prev_action.iter_mut().for_each(|a| *a = 0.0);
        self.air_time = [0.0; 2];
        self.swing_peak = [0.0; 2];
        self.swing_start = [[0.0; 2]; 2];
        self.contact_time = [0.0; 2];
        // Stand in the default pose (what g1fw's start-up ramp ends in), then let it settle.
        let qpos_adr = self.slot_qpos_adr();
        {
            let d = self.sim.data_mut();
            let qpos = d.qpos_mut();
            for (slot, adr) in qpos_adr {
                qpos[adr] = self.default_q[slot] as f64 + 0.02 * (self.rng.uniform() - 0.5);
            }
            d.forward();
        }
        self.target_q = self.default_q;
        self.cmd_now = self.command(&self.target_q.clone());
        self.cmd_prev = self.cmd_now;
        for _ in 0..10 * self.timing.decimation {
            self.sim.apply_command(&self.cmd_now)?;
            self.sim.step_control_tick();
        }
        self.sim.low_state(&mut self.state);
        for (i, &slot) in self.slots.iter().enumerate() {
            self.prev_dq[i] = self.state.motors[slot].dq as f64 as f32;
        }
        let feet = self.feet();
        self.prev_foot = feet;
        self.sole_offset = 0.5
            * (0..2)
                .map(|f| feet[f][2] - self.ground(feet[f][0], feet[f][1]))
                .sum::<f64>();
        self.refresh_token(true);
        let b = self.sim.base_kinematics();
        self.start_s = self.axis_s(b.pos[0], b.pos[1]);
        Ok(())
    }

    fn push_interval(&mut self) -> usize {
        (self.rng.range(4.0, 8.0) / self.timing.policy_dt) as usize
    }

    fn slot_qpos_adr(&self) -> Vec<(usize, usize)> {
        let m = self.sim.data().model();
        (0..NUM_MOTORS)
            .filter(|&s| self.enabled[s])
            .filter_map(|s| {
                let name = format!("{}_joint", hal::G1_MOTOR_NAMES[s]);
                m.name_to_id(_mjtObjBase::mjOBJ_JOINT, &name)
                    .map(|j| (s, m.jnt_qposadr()[j] as usize))
            })
            .collect()
    }

    fn command(&self, target: &[f32; NUM_MOTORS]) -> LowCommand {
        let mut cmd = LowCommand {
            mode_machine: self.sim.mode_machine(),
            ..LowCommand::default()
        };
        for (s, m) in cmd.motors.iter_mut().enumerate() {
            if self.enabled[s] {
                m.mode = MOTOR_MODE_ENABLED;
                m.q = target[s];
                m.kp = self.kp[s];
                m.kd = self.kd[s];
            }
        }
        cmd
    }

    fn feet(&self) -> [[f64; 3]; 2] {
        let x = self.sim.data().xpos();
        [x[self.foot_body[0]], x[self.foot_body[1]]]
    }

    fn ground(&self, x: f64, y: f64) -> f64 {
        self.world.ground_height(x, y)
    }

    fn last_riser_s(&self) -> f64 {
        self.world
            .stairs
            .as_ref()
            .and_then(|s| s.risers.last().map(|r| r.s))
            .unwrap_or(0.0)
    }

    fn axis_s(&self, x: f64, y: f64) -> f64 {
        self.world.stairs.as_ref().map_or(x, |s| s.to_axis(x, y).0)
    }

    /// `g1fw eval`'s success: on the end landing ([`World::stair_progress`]) for
    /// [`firmware::eval::LANDING_HOLD_S`] without a break and without a fall. Ending the episode at
    /// the landing's edge instead taught a dive across the line: 10 of 16 climbs of 12 cm that
    /// passed every riser through `g1fw` tripped on tilt within 0.4 s of reaching the landing.
    /// Time since the episode started, s.
    fn time_s(&self) -> f64 {
        self.step as f64 * self.timing.policy_dt
    }

    /// The episode commands the robot to stand (vx 0 with heading hold, or a joystick at rest):
    /// on a staircase it is neither a stall nor a success, and it moves no curriculum level.
    /// Until run 21 a stand on stairs (5 % of episodes) ended as a stall and paid the success
    /// bonus for crossing, which taught the policy to walk when told to stop (0.27 m/s for 0).
    pub fn standing(&self) -> bool {
        match self.joystick {
            Some(c) => c == [0.0; 3],
            None => self.vx_cmd == 0.0,
        }
    }

    /// Stood on the end landing long enough, alive, and not told to stand (a stand that
    /// started on the landing crosses nothing).
    fn succeeded(&self) -> bool {
        !self.fell && !self.standing() && self.landing.held(firmware::eval::LANDING_HOLD_S, self.time_s())
    }

    fn refresh_token(&mut self, force: bool) {
        if !force && !(self.step as u32 + self.token_phase).is_multiple_of(self.timing.token_period) {
            return;
        }
        let b = self.sim.base_kinematics();
        let yaw = yaw_of(b.quat);
        let (mut z, riser) = self.world.labelled_truth(b.pos[0], b.pos[1], yaw);
        let n = self.cfg.settings.random.token_noise;
        if z.class != TerrainClass::Flat {
            z.step_height_m += (n[0] * self.rng.gaussian()) as f32;
            z.step_depth_m += (n[1] * self.rng.gaussian()) as f32;
            z.yaw_rad += (n[2] * self.rng.gaussian()) as f32;
            // The CNN's class errors sit at the far edge of the look-ahead box.
            let near_edge = riser.is_some_and(|r| r.mid_x_m > world_edge() - 0.25);
            if near_edge && self.rng.chance(n[3]) {
                z = TerrainToken {
                    class: TerrainClass::Flat,
                    step_height_m: 0.0,
                    step_depth_m: 0.0,
                    ..z
                };
            }
        }
        self.token = z;
    }

    fn noisy_state(&mut self) -> LowState {
        let mut s = self.state;
        let [g, q, dq] = self.cfg.settings.random.obs_noise;
        if g > 0.0 {
            for v in &mut s.imu.gyroscope {
                *v += g * (2.0 * self.rng.uniform() as f32 - 1.0);
            }
            for &slot in &self.slots {
                s.motors[slot].q += q * (2.0 * self.rng.uniform() as f32 - 1.0);
                s.motors[slot].dq += dq * (2.0 * self.rng.uniform() as f32 - 1.0);
            }
        }
        s
    }

    /// The operator's command now: forward speed with heading hold toward the staircase axis,
    /// by the same rule and from the same IMU yaw as `g1fw sim --heading` / `g1fw eval` (with
    /// `hold_line`, as `--hold-line`; off the axis during a commanded turn, `stair_turn_share`),
    /// or a joystick episode's constant command.
    pub fn operator_command(&self) -> [f32; 3] {
        if let Some(cmd) = self.joystick {
            return cmd;
        }
        let axis = if self.cfg.settings.hold_line {
            let [x, y, _] = self.base_position();
            control::operator::line_heading(self.heading as f32, x as f32, y as f32)
        } else {
            self.heading as f32
        };
        let target = axis + self.turn.offset_at(self.time_s()) as f32;
        control::operator::heading_command(self.vx_cmd, target, control::operator::imu_yaw(&self.state))
    }

    /// The base's position in the world (the simulator's; the robot starts at the origin), m.
    pub fn base_position(&self) -> [f64; 3] {
        self.sim.base_kinematics().pos
    }

    /// The target heading of a heading-hold episode (the staircase axis, or 0 on flat ground, with
    /// a little noise), rad in the world frame.
    pub fn target_heading(&self) -> f64 {
        self.heading
    }

    /// The actor's observation of the current state, built by the firmware's `PolicyIo`.
    pub fn observe(&mut self) -> &[f32] {
        let s = self.noisy_state();
        let cmd = self.operator_command();
        self.io.observe(&s, cmd, self.token)
    }

    /// Builds the observation and runs the actor's mean on it (the firmware's executor).
    pub fn observe_and_act(&mut self, mean: &mut [f32]) -> anyhow::Result<&[f32]> {
        let s = self.noisy_state();
        let cmd = self.operator_command();
        let obs = self.io.observe(&s, cmd, self.token);
        self.net.step(obs, mean)?;
        Ok(obs)
    }

    /// The newest observation without building a new one (the critic's bootstrap input after an
    /// episode's last step; one policy step old, which the critic tolerates).
    pub fn observe_peek(&self) -> Vec<f32> {
        self.io.observation().to_vec()
    }

    /// The actor's layers, as the spec lists them.
    pub fn network_desc(&self) -> &control::nn::NetworkDesc {
        &self.cfg.spec.policy.network
    }

    /// A new actor (loaded once by the caller, cloned here); the LSTM state carries over.
    pub fn set_actor(&mut self, net: &Network) {
        self.net.set_weights(net);
    }

    /// The mirror image (left ↔ right, y → −y; see [`super::symmetry`]) of [`StairEnv::critic_extra`]'s
    /// layout: body velocity (vx, −vy, vz), base height, token (yaw negated), foot contacts
    /// swapped, terrain heights along the heading (on the mirror line: unchanged), foot heights
    /// swapped.
    pub fn critic_extra_mirror() -> super::symmetry::SignedPermutation {
        let mut source: Vec<usize> = (0..CRITIC_EXTRA).collect();
        let mut factor = vec![1.0f32; CRITIC_EXTRA];
        factor[1] = -1.0; // vy
        factor[7] = -1.0; // token yaw
        source.swap(8, 9); // foot contacts
        source.swap(8 + 2 + HEIGHT_SAMPLES, 9 + 2 + HEIGHT_SAMPLES); // foot heights
        super::symmetry::SignedPermutation { source, factor }
    }

    /// Privileged critic inputs (appended after the actor's observation).
    pub fn critic_extra(&self, out: &mut [f32]) {
        let t = self.sim.truth();
        let yaw = yaw_of(t.base_quat);
        let ground = self.ground(t.base_pos[0], t.base_pos[1]);
        let z = self.world.truth(t.base_pos[0], t.base_pos[1], yaw);
        let mut k = 0;
        let mut put = |v: f64| {
            out[k] = v as f32;
            k += 1;
        };
        for v in t.base_lin_vel_body {
            put(2.0 * v);
        }
        put(t.base_pos[2] - ground - 0.75);
        let ts = self.token_scale.map(f64::from);
        put(ts[0] * z.class.index() as f64);
        put(ts[1] * z.step_height_m as f64);
        put(ts[2] * z.step_depth_m as f64);
        put(ts[3] * z.yaw_rad as f64);
        put(t.foot_contact[0] as u8 as f64);
        put(t.foot_contact[1] as u8 as f64);
        let (c, s) = (yaw.cos(), yaw.sin());
        for i in 0..HEIGHT_SAMPLES {
            let d = -0.3 + 0.15 * i as f64;
            put(5.0 * (self.ground(t.base_pos[0] + c * d, t.base_pos[1] + s * d) - ground));
        }
        let feet = self.feet();
        for f in feet {
            put(5.0 * (f[2] - self.sole_offset - self.ground(f[0], f[1])));
        }
        debug_assert_eq!(k, CRITIC_EXTRA);
    }

    /// Applies `action` (raw network output) and advances one policy step.
    pub fn step(&mut self, action: &[f32]) -> anyhow::Result<StepOut> {
        // Before the step's time advances: `succeeded` compares the landing's hold with the
        // current time, so asked after `self.step += 1` it already read true on the step that
        // completes the hold, and the bonus below was never paid.
        let was_success = self.succeeded();
        self.io.apply_action(action, &mut self.target_q);
        self.cmd_prev = self.cmd_now;
        self.cmd_now = self.command(&self.target_q.clone());
        self.peak_dq = [0.0; NUM_MOTORS];
        self.physics_step_trip = None;
        for k in 0..self.timing.decimation {
            let c = if k < self.latency { self.cmd_prev } else { self.cmd_now };
            self.sim.apply_command(&c)?;
            if self.assist_strength > 0.0 {
                self.apply_assist()?;
            }
            self.sim.step_control_tick();
            self.sim.low_state(&mut self.state);
            self.watch_physics_step();
        }
        self.step += 1;
        if self.cfg.settings.random.push_mps > 0.0 && self.step == self.next_push {
            let p = self.cfg.settings.random.push_mps;
            let (dx, dy) = (self.rng.range(-p, p), self.rng.range(-p, p));
            self.sim.push_base(dx, dy)?;
            self.next_push += self.push_interval();
        }
        let (mut terms, terminated) = self.rewards(action);
        // The bonus comes once the base has stood on the landing (no bonus, no promotion for a
        // fall that carries it there).
        // A stand command never succeeds, so it earns nothing for crossing the staircase.
        if !was_success && !terminated && self.succeeded() {
            terms.success = 1.0 / self.timing.policy_dt;
        }
        let weights = Weights {
            flat_orientation: self.cfg.settings.flat_orientation_weight,
            drift: self.cfg.settings.drift_weight,
            yaw_rate_error: self.cfg.settings.yaw_error_weight,
            riser_clearance: self.cfg.settings.riser_clearance_weight,
            foothold_edge: self.cfg.settings.foothold_edge_weight,
            token_clearance: self.cfg.settings.token_clearance_weight,
            swing_apex: self.cfg.settings.swing_apex_weight,
            swing_advance: self.cfg.settings.swing_advance_weight,
            swing_overshoot: self.cfg.settings.swing_overshoot_weight,
            base_height: self.cfg.settings.base_height_weight,
            up_lean: self.cfg.settings.up_lean_weight,
            stance_lead: self.cfg.settings.stance_lead_weight,
            ..WEIGHTS
        };
        let reward = super::reward::bounded(terms.total(&weights, self.timing.policy_dt));
        self.ret += reward;
        terms.accumulate(&weights, self.timing.policy_dt, &mut self.ret_by_term);
        let n = self.prev_action.len();
        self.prev_action.copy_from_slice(&action[..n]);
        self.refresh_token(false);
        let truncated = !terminated && (self.step >= self.max_steps || self.succeeded());
        self.fell |= terminated;
        Ok(StepOut {
            reward: reward as f32,
            terminated,
            truncated,
        })
    }

    /// The assistant's wrench on the base for the coming physics step ([`super::assist`]).
    fn apply_assist(&mut self) -> anyhow::Result<()> {
        let b = self.sim.base_kinematics();
        let base = super::assist::BaseState {
            quat: b.quat,
            ang_vel_body: b.ang_vel_body,
            lin_vel_world: b.lin_vel_world,
            height: b.pos[2] - self.ground(b.pos[0], b.pos[1]),
        };
        let (force, torque) = super::assist::wrench(
            self.assist_strength,
            self.robot_mass,
            &base,
            self.target_heading(),
            self.vx_cmd as f64,
        );
        self.sim.set_base_wrench(force, torque)?;
        Ok(())
    }

    /// Assists every episode from the next reset on at `strength` (in-environment evaluation,
    /// with [`StairEnv::hold`]; 0: none).
    pub fn hold_assist(&mut self, strength: f64) {
        self.held_assist = strength;
    }

    /// Sets the strength of the assisted episodes that start from now on ([`super::assist`]; the
    /// runner decays it with the run's env steps).
    pub fn set_assist_strength(&mut self, strength: f64) {
        self.assist_now = strength;
    }

    /// The current episode is an assisted one, and its assistant's strength.
    pub fn assist(&self) -> (bool, f64) {
        (self.assisted, self.assist_strength)
    }

    /// The supervisor's walls at one physics step. `g1fw`'s supervisor checks every 2 ms tick, so
    /// a knee-speed spike at a foot strike trips the robot even when it is over before the policy
    /// step ends; checked only at policy steps (every 20 ms), training never saw most of them.
    fn watch_physics_step(&mut self) {
        let mut too_fast = false;
        for &slot in &self.slots {
            let dq = self.state.motors[slot].dq;
            self.peak_dq[slot] = self.peak_dq[slot].max(dq.abs());
            too_fast |= self.limits.joint_too_fast(slot, dq);
        }
        if self.physics_step_trip.is_none() {
            let b = self.sim.base_kinematics();
            let g = estimator::projected_gravity(b.quat.map(|x| x as f32));
            let w = b.ang_vel_body.map(|x| x as f32);
            // The base height is the field's termination, not the supervisor's: judged per policy step.
            self.physics_step_trip = termination::cause(&self.limits, -g[2], too_fast, f64::INFINITY, w);
        }
    }

    /// Fastest |dq| of motor `slot` over the physics steps of the last policy step, rad/s.
    pub fn peak_joint_speed(&self, slot: usize) -> f32 {
        self.peak_dq[slot]
    }

    fn rewards(&mut self, action: &[f32]) -> (Terms, bool) {
        let t = self.sim.truth();
        let yaw = yaw_of(t.base_quat);
        let (c, s) = (yaw.cos(), yaw.sin());
        let v = t.base_lin_vel_world;
        let (vx, vy) = (c * v[0] + s * v[1], -s * v[0] + c * v[1]);
        let cmd = self.operator_command().map(|x| x as f64);
        let w = t.base_ang_vel_body;
        let g = estimator::projected_gravity(t.base_quat.map(|x| x as f32));
        let yaw_rate_error = (cmd[2] - w[2]).powi(2);
        let mut r = Terms {
            track_lin_vel_xy: (-((cmd[0] - vx).powi(2) + (cmd[1] - vy).powi(2))
                / self.cfg.settings.tracking_std.powi(2))
            .exp(),
            track_ang_vel_z: (-yaw_rate_error / self.cfg.settings.tracking_std.powi(2)).exp(),
            yaw_rate_error,
            flat_orientation: (g[0] as f64).powi(2) + (g[1] as f64).powi(2),
            ang_vel_xy: w[0] * w[0] + w[1] * w[1],
            // Speed along the target heading, up to the commanded speed: standing at a riser earns
            // none of it, and going faster than asked earns nothing more.
            // (A joystick episode has no target heading: its forward speed counts.)
            progress: {
                let along = if self.joystick.is_some() {
                    vx
                } else {
                    let (hc, hs) = (self.heading.cos(), self.heading.sin());
                    hc * v[0] + hs * v[1]
                };
                along.clamp(0.0, (cmd[0]).max(0.0))
            },
            drift: if self.joystick.is_some() {
                0.0
            } else {
                reward::drift(self.heading, t.base_pos[0], t.base_pos[1])
            },
            ..Terms::default()
        };
        let policy_dt = self.timing.policy_dt;
        for (i, &slot) in self.slots.iter().enumerate() {
            let m = &self.state.motors[slot];
            let dq = m.dq as f64;
            let soft = (self.cfg.settings.soft_joint_speed * self.limits.joint_speed_rad_s[slot]) as f64;
            r.joint_speed += (self.peak_dq[slot] as f64 - soft).max(0.0).powi(2);
            r.action_rate += ((action[i] - self.prev_action[i]) as f64).powi(2);
            r.torques += self.sim.applied_torque(slot).powi(2);
            r.joint_acc += ((dq - self.prev_dq[i] as f64) / policy_dt).powi(2);
            self.prev_dq[i] = m.dq;
            let name = hal::G1_MOTOR_NAMES[slot];
            let dev = (m.q - self.default_q[slot]).abs() as f64;
            if name.ends_with("hip_yaw") || name.ends_with("hip_roll") {
                r.joint_deviation += dev;
            }
            if name.contains("ankle") {
                if let Some((lo, hi)) = control::robot::G1_JOINT_RANGE[slot] {
                    let (mid, half) = (0.5 * (lo + hi) as f64, 0.45 * (hi - lo) as f64);
                    r.ankle_limits += ((m.q as f64 - mid).abs() - half).max(0.0);
                }
            }
        }
        // Feet.
        let feet = self.feet();
        let mut single = 0;
        let mut in_mode = [0.0; 2];
        for f in 0..2 {
            let vel = [
                (feet[f][0] - self.prev_foot[f][0]) / policy_dt,
                (feet[f][1] - self.prev_foot[f][1]) / policy_dt,
            ];
            let speed = vel[0].hypot(vel[1]);
            if t.foot_contact[f] {
                r.feet_slide += speed;
                self.contact_time[f] += policy_dt;
                if self.air_time[f] > 0.0 {
                    // Touchdown: the swing that ended is charged once for its apex.
                    if let Some(target) = reward::token_clearance_target(&self.token) {
                        r.swing_apex += (target - self.swing_peak[f]).max(0.0) / policy_dt;
                    }
                    if let Some(over) = reward::swing_overshoot(&self.token, self.swing_peak[f]) {
                        r.swing_overshoot += over / policy_dt;
                    }
                    self.swing_peak[f] = 0.0;
                    if let Some(target) = reward::swing_advance_target(&self.token).filter(|_| !self.standing()) {
                        let [x0, y0] = self.swing_start[f];
                        let advance = (feet[f][0] - x0) * c + (feet[f][1] - y0) * s;
                        r.swing_advance += (target - advance).max(0.0) / policy_dt;
                    }
                }
                self.air_time[f] = 0.0;
                single += 1;
                in_mode[f] = self.contact_time[f];
                if reward::straddles_edge(|x, y| self.ground(x, y), (feet[f][0], feet[f][1]), (c, s)) {
                    r.foothold_edge += 1.0;
                }
            } else {
                if self.air_time[f] == 0.0 {
                    // Liftoff: the swing starts where the foot last stood.
                    self.swing_start[f] = [self.prev_foot[f][0], self.prev_foot[f][1]];
                }
                self.air_time[f] += policy_dt;
                self.contact_time[f] = 0.0;
                in_mode[f] = self.air_time[f];
                let (ux, uy) = if speed > 1e-3 {
                    (vel[0] / speed, vel[1] / speed)
                } else {
                    (c, s)
                };
                let terrain = reward::clearance_terrain(
                    |x, y| self.ground(x, y),
                    (feet[f][0], feet[f][1]),
                    (ux, uy),
                    self.cfg.settings.clearance_lookahead,
                );
                let sole = feet[f][2] - self.sole_offset;
                r.foot_clearance += (reward::CLEARANCE_TARGET - (sole - terrain)).max(0.0) * speed.min(1.0);
                let over = sole - self.ground(feet[f][0], feet[f][1]);
                self.swing_peak[f] = self.swing_peak[f].max(over);
                if let Some(target) = reward::token_clearance_target(&self.token) {
                    r.token_clearance += (target - over).max(0.0) * speed.min(1.0);
                }
                if let Some(top) = reward::next_tread_top(
                    |x, y| self.ground(x, y),
                    (feet[f][0], feet[f][1]),
                    (ux, uy),
                    reward::RISER_LOOKAHEAD,
                ) {
                    r.riser_clearance += (top + reward::RISER_MARGIN - sole).max(0.0) * speed.min(1.0);
                }
            }
        }
        let feet_ground = 0.5 * (self.ground(feet[0][0], feet[0][1]) + self.ground(feet[1][0], feet[1][1]));
        if let Some(deficit) = reward::base_height_deficit(&self.token, t.base_pos[2] - feet_ground) {
            r.base_height = deficit;
        }
        if let Some(deficit) = reward::up_lean_deficit(&self.token, g[0] as f64) {
            r.up_lean = deficit;
        }
        if single == 1 {
            let f = if t.foot_contact[0] { 0 } else { 1 };
            let lead = (feet[f][0] - t.base_pos[0]) * c + (feet[f][1] - t.base_pos[1]) * s;
            if let Some(excess) = reward::stance_lead_excess(&self.token, lead) {
                r.stance_lead = excess;
            }
            if cmd[0].hypot(cmd[1]) > 0.1 {
                r.feet_air_time = in_mode[f].min(reward::AIR_TIME_THRESHOLD);
            }
        }
        self.prev_foot = feet;
        // Contacts against the terrain: risers under the feet, anything else.
        let d = self.sim.data();
        let m = d.model();
        let (gb, root) = (m.geom_bodyid(), m.body_rootid());
        for con in d.contact() {
            let (g1, g2) = (con.geom[0], con.geom[1]);
            if g1 < 0 || g2 < 0 || con.dist > 0.0 {
                continue;
            }
            // Robot bodies share the pelvis's root; terrain is the world body or a pool body.
            let robot_root = root[self.foot_body[0]];
            let (b1, b2) = (gb[g1 as usize] as usize, gb[g2 as usize] as usize);
            let (robot, other) = if root[b1] == robot_root { (b1, b2) } else { (b2, b1) };
            if root[robot] != robot_root {
                continue;
            }
            if root[other] == robot_root {
                // Leg against leg (the training profile lets only the legs meet each other).
                r.body_contact += 1.0;
                continue;
            }
            if self.foot_body.contains(&robot) {
                if con.frame[2].abs() < 0.5 {
                    r.stumble += 1.0;
                }
            } else {
                r.body_contact += 1.0;
            }
        }
        // Progress along the staircase, for success and the curriculum.
        let s = self.axis_s(t.base_pos[0], t.base_pos[1]);
        self.progress = self.progress.max(s);
        let on_landing = self
            .world
            .stair_progress(t.base_pos[0], t.base_pos[1])
            .is_some_and(|p| p.on_end_landing);
        self.landing.observe(on_landing, self.time_s());
        if on_landing {
            self.stall.excuse(s, self.time_s());
        } else {
            self.stall.observe(s, self.time_s());
        }
        // Standing still is what a stand command asks for, not a stall.
        let stalled =
            self.cfg.settings.end_stalled && self.world.stairs.is_some() && !self.standing() && self.stall.stalled();
        // The supervisor's own checks (tilt, joint speed, base angular speed per axis) on the true
        // state, and a base too low (the field's termination; the robot has no such guard).
        let height = t.base_pos[2] - self.ground(t.base_pos[0], t.base_pos[1]);
        let cause = self
            .physics_step_trip
            .or(termination::cause(
                &self.limits,
                -g[2],
                false,
                height,
                w.map(|x| x as f32),
            ))
            .or(stalled.then_some(termination::STALLED));
        if let Some(c) = cause {
            r.termination = 1.0;
            self.cause = c;
        }
        (r, cause.is_some())
    }

    /// Whether the episode's world is a staircase and the robot, not told to stand, has reached
    /// and held its end landing.
    pub fn success(&self) -> bool {
        self.succeeded()
    }

    pub fn world(&self) -> &World {
        &self.world
    }

    /// The rates this environment trains at (from the spec's `[rates]`).
    pub fn timing(&self) -> Timing {
        self.timing
    }

    /// The walls an episode ends on (from the spec's `[safety]`, as the supervisor's).
    pub fn limits(&self) -> &MotionLimits {
        &self.limits
    }

    /// The current (noise-free) LowState, for parity tests.
    pub fn low_state(&self) -> &LowState {
        &self.state
    }

    /// Farthest the base got along the staircase axis (along x on flat ground) this episode, m.
    pub fn progress(&self) -> f64 {
        self.progress
    }

    /// Base pose and world, for test messages.
    pub fn debug_summary(&self) -> String {
        let t = self.sim.truth();
        format!(
            "world {:?} column {:?} level {} base {:?} progress {:.2} fell {} last speeds {:?}",
            self.world.spec.kind,
            self.column,
            self.level,
            t.base_pos,
            self.progress,
            self.fell,
            self.slots.iter().map(|&s| self.state.motors[s].dq).collect::<Vec<_>>()
        )
    }

    pub fn token(&self) -> TerrainToken {
        self.token
    }
}

fn world_edge() -> f64 {
    g1_sim::world::LOOKAHEAD_X.1
}
