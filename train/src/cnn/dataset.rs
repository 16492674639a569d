//! Labelled BEV samples for the terrain estimator: robot poses on and around a world's staircase,
//! the simulated MID-360 frame from each pose, the robot's BEV grid and the world's ground-truth
//! terrain token ([`World::truth`]).
//!
//! **Poses are scripted kinematic poses, not physics.** The sampler puts the pelvis at a position
//! and heading, sets the joints (the home pose, or a scripted gait) and calls `mj_forward`; nothing
//! is simulated, so feet may float above or sink into a step (the pelvis keeps the nominal height
//! above the ground under it) and a "walking" robot is not balanced. What matters for the lidar is
//! where the head is and which of the robot's own links are in the beams, and both are realistic.
//!
//! Pose distribution ([`sample_pose`]), per sample:
//! - stair worlds: along the stair axis from 2.5 m before the first riser to 1.5 m past the last
//!   one (clipped to 0.3 m inside the landings, so the robot never stands at the edge of a landing's
//!   box), across it within ± (width / 2 − 0.25 m); heading = the stair direction or its opposite
//!   (probability ½ each, so going up and going down both appear) plus uniform ±45°;
//! - flat worlds: x, y uniform within ±1 m of the origin, heading uniform;
//! - base height = ground height under the pelvis + the model's nominal pelvis height (initial
//!   `qpos` z minus the ground at the start);
//! - [`Mode::Standing`]: home joint pose, level pelvis, still during the frame;
//! - [`Mode::Walking`]: a scripted gait with a random phase and frequency (1.0–1.6 Hz): hip pitch
//!   ±0.3 rad, knee flexion up to 0.6 rad in swing, ankle pitch, arm swing; pelvis roll up to ±3°
//!   (sway with the gait), pitch a random lean within ±4° plus ±1° at twice the gait frequency
//!   (within ±5°), height bob ±2 cm; forward speed 0–0.8 m/s. The robot moves during the frame: the
//!   frame is cast in 50 slices of 2 ms (one per control tick, as `g1-sim` does), each from the pose
//!   at that time, and the sampled pose (the label's) is the one at the end of the frame, when the
//!   firmware would build the grid.
//! - [`Posture`] (off by default; `g1-dataset export --roll-lean-deg --pitch-lean-deg --crouch-m`):
//!   walking poses add a constant roll lean, a further pitch lean and a lowered pelvis, each
//!   uniform in its range. Why: trained policies do not walk like the scripted gait. The committed
//!   stair policy walks flat ground with the pelvis rolled 7–11° and 7–12 cm low, and the network
//!   trained without these poses read that ground as stairs down in 44 % of frames (the peer
//!   walker, upright: 3.5 %). Drawn after every other draw, so a dataset without them is unchanged.
//!
//! Rendering ([`WorldRenderer::render`]): one full 0.1 s frame (20 000 rays) through
//! [`LidarSim`]; the returns are packetised with [`PacketWriter`] and reassembled with
//! [`FrameAssembler`] exactly as the robot's driver receives them (quantisation to mm, the 0.1 m
//! minimum range and the zero "no return" points dropped); the grid is built with the pelvis's true
//! roll and pitch and base height = pelvis z − ground height under the pelvis, each with optional
//! Gaussian noise (0.01 rad, 0.01 m; on by default) that mimics the state estimator's error.
//!
//! Memory ([`sensor_io::bev_memory`], as the firmware grids; when [`DatasetConfig::memory`] has
//! keyframes, e.g. `g1-dataset export --memory-keyframes 4`): before the labelled frame, the
//! keyframes the firmware's memory would hold are rendered along the robot's approach: a straight
//! path into the pose, heading ± 23° off its heading, keyframes every `spacing_m` (0.3 m) back from
//! a random offset in [0, 0.3) m, each a walking frame (speed 0.2–0.8 m/s, heading ± 6°). Their
//! odometry poses carry leg-odometry drift growing with the distance walked since: σ = 3 mm + 2 %
//! (x, y), 3 mm + 1 % (z), 0.1° + 0.5°/m (yaw). 15 % of samples hold 0 to 3 keyframes (start-up,
//! odometry reset), the rest all 4. The grid is the current frame's points plus, in cells it
//! misses, the newest keyframe's that hit them.
//!
//! Every sample is a pure function of (world, world seed, pose index, [`DatasetConfig`]): the lidar
//! noise, the scan pattern's start (a random frame index) and the pose come from seeds derived from
//! the world seed and the pose index, so the output does not depend on threads or order.
//!
//! Seeds: [`export`] draws world `i` as `World::random(seed + i)` (default `seed` 0);
//! [`evaluate_geometric`] draws world `i` as `World::random(EVAL_SEED_BASE + seed + i)` with
//! `EVAL_SEED_BASE` = 1 000 000, so held-out worlds never overlap an export of fewer than a million
//! worlds from seed 0.
use std::collections::BTreeMap;
use std::f64::consts::PI;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::mpsc;

use estimator::terrain::{plausible, GeometricTerrainConfig, GeometricTerrainEstimator};
use hal::{wrap_angle, LidarPoint, PointFrame, TerrainClass, TerrainToken};
use mujoco_rs::prelude::*;
use sensor_io::bev::{
    BevBuilder, BevGrid, BevStats, MountPose, PointClass, RobotFrame, SelfFilter, BEV_CELLS, BEV_CHANNELS,
};
pub use sensor_io::bev_memory::MemoryConfig;
use sensor_io::bev_memory::{BevMemory, MemoryStats, OdomPose};
use sensor_io::livox::{FrameAssembler, PacketWriter};
use serde::Serialize;

use g1_sim::lidar::{LidarConfig, LidarSim, Return};
use g1_sim::world::{LabelledRiser, RandomRanges, World};
use g1_sim::{ModelChoice, SimConfig, SimError, Simulator};
use labkit::rng::Rng;

/// Evaluation worlds are `World::random(EVAL_SEED_BASE + seed + i)`.
pub const EVAL_SEED_BASE: u64 = 1_000_000;
/// Capacity of the reassembled frame (a full frame is 20 000 points).
pub const FRAME_CAP: usize = 24_000;
/// Lidar frame length, ns.
const FRAME_NS: u64 = 100_000_000;

/// Standing or walking (see the module documentation).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    Standing = 0,
    Walking = 1,
}

/// Which modes a dataset draws.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum ModeChoice {
    Standing,
    Walking,
    /// Each pose draws standing or walking with probability ½.
    Mixed,
}

impl std::str::FromStr for ModeChoice {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "standing" => Ok(Self::Standing),
            "walking" => Ok(Self::Walking),
            "mixed" => Ok(Self::Mixed),
            _ => Err(format!("mode `{s}`: expected standing, walking or mixed")),
        }
    }
}

/// Rendering settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DatasetConfig {
    pub mode: ModeChoice,
    /// The simulated sensor (its `seed` is replaced per sample).
    pub lidar: LidarConfig,
    /// Gaussian noise on the roll and pitch the grid is levelled with, rad (1 σ; 0: off).
    pub attitude_noise_rad: f64,
    /// Gaussian noise on the base height the grid is built with, m (1 σ; 0: off).
    pub height_noise_m: f64,
    /// The firmware's BEV memory (default [`MemoryConfig::BUILTIN`], as the firmware's default;
    /// [`MemoryConfig::OFF`]: single-frame grids).
    pub memory: MemoryConfig,
    /// Share of samples whose memory is partly filled (0 to keyframes − 1 keyframes: just
    /// started, or odometry was reset); the rest hold all keyframes.
    pub memory_cold_fraction: f64,
    /// Scale of the keyframes' odometry drift (1: the module documentation's model; 0: perfect
    /// odometry, the upper bound of what the memory can give).
    pub odometry_drift: f64,
    /// Extra walking posture (none by default).
    pub posture: Posture,
}

impl Default for DatasetConfig {
    fn default() -> Self {
        Self {
            mode: ModeChoice::Mixed,
            lidar: LidarConfig::default(),
            attitude_noise_rad: 0.01,
            height_noise_m: 0.01,
            memory: MemoryConfig::BUILTIN,
            memory_cold_fraction: 0.15,
            odometry_drift: 1.0,
            posture: Posture::default(),
        }
    }
}

/// A sampled pose (the labelled one: at the end of the lidar frame) and its gait parameters.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct PoseSample {
    pub mode: Mode,
    /// Pelvis position on the ground plane, m, and heading, rad (world frame).
    pub x: f64,
    pub y: f64,
    pub yaw: f64,
    /// Gait phase at the end of the frame, rad, and frequency, Hz (walking).
    pub phase: f64,
    pub gait_hz: f64,
    /// Forward speed, m/s (walking; 0 standing).
    pub speed: f64,
    /// Constant forward lean, rad, and roll sway amplitude, rad (walking).
    pub lean: f64,
    pub sway: f64,
    /// Extra posture (walking, [`Posture`]): constant roll, rad, further pitch, rad, and how far
    /// the pelvis sits below its nominal height, m.
    pub roll_lean: f64,
    pub pitch_lean: f64,
    pub crouch: f64,
}

/// `--roll-lean-deg`, `--pitch-lean-deg`, `--crouch-m`: the [`Posture`] ranges, for every
/// command that renders samples (`g1-dataset export`, `g1-train eval-terrain`).
#[derive(clap::Args, Clone, Copy, Debug, Default, PartialEq)]
pub struct PostureArgs {
    /// Walking poses lean sideways by a constant roll, uniform in ±this, degrees (0: none). The
    /// committed stair policy walks with 7–11°.
    #[arg(long, default_value_t = 0.0, value_name = "DEG", value_parser = parse_posture_deg)]
    pub roll_lean_deg: f64,
    /// Walking poses add a pitch lean, uniform in ±this, degrees, to the gait's own ±5° (0: none).
    #[arg(long, default_value_t = 0.0, value_name = "DEG", value_parser = parse_posture_deg)]
    pub pitch_lean_deg: f64,
    /// Walking poses lower the pelvis by a uniform 0…this, m (0: none). The committed stair
    /// policy walks 7–12 cm below the nominal height.
    #[arg(long, default_value_t = 0.0, value_name = "M", value_parser = parse_crouch_m)]
    pub crouch_m: f64,
}

impl PostureArgs {
    pub fn posture(&self) -> Posture {
        Posture {
            roll_lean_rad: self.roll_lean_deg.to_radians(),
            pitch_lean_rad: self.pitch_lean_deg.to_radians(),
            crouch_m: self.crouch_m,
        }
    }
}

fn parse_posture_deg(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if (0.0..=30.0).contains(&v) => Ok(v),
        _ => Err(format!("`{s}`: give a lean range in [0, 30] degrees, e.g. 12")),
    }
}

fn parse_crouch_m(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if (0.0..=0.3).contains(&v) => Ok(v),
        _ => Err(format!(
            "`{s}`: give how far the pelvis may sit low in [0, 0.3] m, e.g. 0.14"
        )),
    }
}

/// Ranges of the extra walking posture (see the module documentation); zero: none drawn.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Posture {
    /// Constant roll lean, uniform in ±this, rad.
    pub roll_lean_rad: f64,
    /// Pitch lean added to the gait's, uniform in ±this, rad.
    pub pitch_lean_rad: f64,
    /// Pelvis lowered by a uniform 0…this, m.
    pub crouch_m: f64,
}

/// Kinematic state at one instant.
#[derive(Clone, Copy, Debug, PartialEq)]
struct BodyPose {
    pos: [f64; 3],
    rpy: [f64; 3],
    /// Offsets from the home pose: hip pitch, knee, ankle pitch, shoulder pitch; left, right.
    legs: [[f64; 4]; 2],
}

fn mix(a: u64, b: u64) -> u64 {
    Rng(a ^ b.wrapping_mul(0xD1B5_4A32_D192_ED03) ^ 0x0DA7_A5E7).next_u64()
}

/// Draws the pose of sample `pose_index` of a world (deterministic in `world_seed`, `pose_index`).
pub fn sample_pose(world: &World, world_seed: u64, pose_index: u64, mode: ModeChoice, posture: &Posture) -> PoseSample {
    let mut rng = Rng(mix(world_seed, pose_index));
    let (x, y, yaw) = match &world.stairs {
        Some(st) => {
            let last_s = st.risers.last().map_or(0.0, |r| r.s);
            let s_lo = (-2.5f64).max(-st.landing_before + 0.3);
            let s_hi = (last_s + 1.5).min(st.end_s - 0.3);
            let s = rng.range(s_lo, s_hi.max(s_lo));
            let half = (0.5 * st.width - 0.25).max(0.0);
            let t = rng.range(-half, half);
            let (c, sn) = (st.yaw.cos(), st.yaw.sin());
            let x = st.origin[0] + c * s - sn * t;
            let y = st.origin[1] + sn * s + c * t;
            let back = rng.chance(0.5);
            let yaw = st.yaw + if back { PI } else { 0.0 } + rng.range(-PI / 4.0, PI / 4.0);
            (x, y, wrap_angle(yaw))
        }
        None => (rng.range(-1.0, 1.0), rng.range(-1.0, 1.0), rng.range(-PI, PI)),
    };
    let walking = match mode {
        ModeChoice::Standing => false,
        ModeChoice::Walking => true,
        ModeChoice::Mixed => rng.chance(0.5),
    };
    let mut p = PoseSample {
        mode: Mode::Standing,
        x,
        y,
        yaw,
        phase: 0.0,
        gait_hz: 0.0,
        speed: 0.0,
        lean: 0.0,
        sway: 0.0,
        roll_lean: 0.0,
        pitch_lean: 0.0,
        crouch: 0.0,
    };
    if walking {
        p.mode = Mode::Walking;
        p.phase = rng.range(0.0, 2.0 * PI);
        p.gait_hz = rng.range(1.0, 1.6);
        p.speed = rng.range(0.0, 0.8);
        p.lean = rng.range(-4.0, 4.0).to_radians();
        p.sway = rng.range(-3.0, 3.0).to_radians();
        // After every other draw: without a posture range the stream is what it always was.
        if posture.roll_lean_rad > 0.0 {
            p.roll_lean = rng.range(-posture.roll_lean_rad, posture.roll_lean_rad);
        }
        if posture.pitch_lean_rad > 0.0 {
            p.pitch_lean = rng.range(-posture.pitch_lean_rad, posture.pitch_lean_rad);
        }
        if posture.crouch_m > 0.0 {
            p.crouch = rng.range(0.0, posture.crouch_m);
        }
    }
    p
}

impl PoseSample {
    /// Pelvis position and attitude and the gait's joint offsets `dt` seconds after the labelled
    /// instant (dt ≤ 0 within a frame).
    fn at(&self, world: &World, nominal_height: f64, dt: f64) -> BodyPose {
        let (c, s) = (self.yaw.cos(), self.yaw.sin());
        let (x, y) = (self.x + c * self.speed * dt, self.y + s * self.speed * dt);
        let ground = world.ground_height(x, y);
        if self.mode == Mode::Standing {
            return BodyPose {
                pos: [x, y, ground + nominal_height],
                rpy: [0.0, 0.0, self.yaw],
                legs: [[0.0; 4]; 2],
            };
        }
        let ph = self.phase + 2.0 * PI * self.gait_hz * dt;
        let leg = |ph: f64| {
            let swing = ph.cos().max(0.0);
            // Hip forward (negative pitch) while cos > 0 (swing), knee flexed mid-swing, ankle
            // dorsiflexed in swing and following the hip in stance; the arm swings against the leg.
            [
                -0.3 * ph.sin(),
                0.6 * swing,
                -0.25 * swing + 0.1 * ph.sin(),
                0.25 * ph.sin(),
            ]
        };
        BodyPose {
            pos: [x, y, ground + nominal_height - self.crouch + 0.02 * (2.0 * ph).cos()],
            rpy: [
                self.roll_lean + self.sway * ph.sin(),
                self.lean + self.pitch_lean + 1f64.to_radians() * (2.0 * ph).sin(),
                self.yaw,
            ],
            legs: [leg(ph), leg(ph + PI)],
        }
    }
}

/// What [`WorldRenderer::render`] records besides the grid.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct SampleMeta {
    pub pose: PoseSample,
    /// Pelvis position (m) and roll, pitch, yaw (rad) at the labelled instant.
    pub pelvis: [f64; 3],
    pub rpy: [f64; 3],
    /// Roll, pitch and base height the grid was built with (noise included).
    pub bev_roll: f64,
    pub bev_pitch: f64,
    pub bev_height: f64,
    /// Ground height under the pelvis, m.
    pub ground: f64,
    /// Points in the reassembled frame, and those in the grid (remembered ones included).
    pub frame_points: usize,
    pub bev_points: usize,
    /// Keyframes in the memory, and the remembered points that went into the grid.
    pub keyframes: usize,
    pub memory_points: usize,
    /// The riser the truth describes (none on flat labels).
    pub riser: Option<LabelledRiser>,
    /// The world is the outdoor variant (per-step jitter, sloped treads, rounded nosings).
    pub outdoor: bool,
}

/// One labelled sample.
#[derive(Clone, Debug)]
pub struct Sample {
    pub bev: Box<BevGrid>,
    pub truth: TerrainToken,
    pub meta: SampleMeta,
}

/// Qpos addresses of the joints the gait moves (left, right).
#[derive(Clone, Copy, Debug)]
struct GaitJoints {
    adr: [[usize; 4]; 2],
}

/// One world's simulator and the buffers to render samples from it (the model compile is the
/// expensive part; render many poses per world).
pub struct WorldRenderer {
    pub world: World,
    pub world_seed: u64,
    cfg: DatasetConfig,
    sim: Simulator,
    root: usize,
    joints: GaitJoints,
    home: Vec<f64>,
    nominal_height: f64,
    mount: MountPose,
    returns: Vec<Return>,
    points: Vec<LidarPoint>,
    packet: Vec<u8>,
    assembler: FrameAssembler<FRAME_CAP>,
    bev: Box<BevBuilder>,
    memory: BevMemory,
    /// Robot-frame points of the last rendered frame.
    robot: Vec<[f32; 3]>,
}

impl WorldRenderer {
    /// Builds the 29-dof G1 in `world`.
    pub fn new(world: World, world_seed: u64, cfg: DatasetConfig) -> Result<Self, SimError> {
        cfg.lidar.validate()?;
        let sim = Simulator::load_in(ModelChoice::G1_29Dof, SimConfig::default(), Some(&world))?;
        let model = sim.data().model();
        let joint_adr = |name: &str| -> Result<usize, SimError> {
            let j = model
                .name_to_id(MjtObjBase::mjOBJ_JOINT, name)
                .ok_or_else(|| SimError::Model(format!("dataset: joint {name} missing")))?;
            Ok(model.jnt_qposadr()[j] as usize)
        };
        let root = (0..model.ffi().njnt as usize)
            .find(|&j| model.jnt_type()[j] == MjtJoint::mjJNT_FREE)
            .map(|j| model.jnt_qposadr()[j] as usize)
            .ok_or_else(|| SimError::Model("dataset: the model has no free root joint".into()))?;
        let mut adr = [[0; 4]; 2];
        for (side, name) in ["left", "right"].iter().enumerate() {
            for (k, j) in ["hip_pitch", "knee", "ankle_pitch", "shoulder_pitch"]
                .iter()
                .enumerate()
            {
                adr[side][k] = joint_adr(&format!("{name}_{j}_joint"))?;
            }
        }
        let home = sim.initial_qpos().to_vec();
        let nominal_height = home[root + 2] - world.start()[2];
        let (xyz, rpy) = cfg.lidar.mount_in_pelvis();
        let mount = MountPose {
            xyz: xyz.map(|v| v as f32),
            rpy: rpy.map(|v| v as f32),
        };
        let writer = PacketWriter::new();
        Ok(Self {
            world,
            world_seed,
            cfg,
            sim,
            root,
            joints: GaitJoints { adr },
            home,
            nominal_height,
            mount,
            returns: Vec::with_capacity(cfg.lidar.points_per_frame()),
            points: Vec::with_capacity(cfg.lidar.points_per_frame()),
            packet: vec![0; writer.max_packet_len()],
            assembler: FrameAssembler::new_boxed(),
            bev: BevBuilder::new_boxed(),
            memory: BevMemory::new(cfg.memory, FRAME_CAP),
            robot: Vec::with_capacity(FRAME_CAP),
        })
    }

    /// Nominal pelvis height above the ground, m.
    pub fn nominal_height(&self) -> f64 {
        self.nominal_height
    }

    pub fn config(&self) -> &DatasetConfig {
        &self.cfg
    }

    /// Pose `pose_index` of this world (see [`sample_pose`]).
    pub fn pose(&self, pose_index: u64) -> PoseSample {
        sample_pose(
            &self.world,
            self.world_seed,
            pose_index,
            self.cfg.mode,
            &self.cfg.posture,
        )
    }

    /// Samples pose `pose_index` and renders it.
    pub fn render_index(&mut self, pose_index: u64) -> Sample {
        let pose = self.pose(pose_index);
        self.render(&pose, mix(self.world_seed ^ 0x5A3B_1E00, pose_index))
    }

    fn set_pose(&mut self, b: &BodyPose) {
        let q = rpy_quat(b.rpy);
        let (root, home, adr) = (self.root, &self.home, self.joints.adr);
        let qpos = self.sim.data_mut().qpos_mut();
        qpos.copy_from_slice(home);
        qpos[root..root + 3].copy_from_slice(&b.pos);
        qpos[root + 3..root + 7].copy_from_slice(&q);
        for side in 0..2 {
            for k in 0..4 {
                qpos[adr[side][k]] += b.legs[side][k];
            }
        }
        self.sim.data_mut().forward();
    }

    /// One lidar frame of `pose` (see the module documentation) into `self.robot`: robot-frame
    /// points, self-hits and non-finite points dropped, levelled with the (noisy) attitude and
    /// height the estimator would give. `rng` drives the lidar noise, the scan pattern's start and
    /// the attitude / height noise. The robot is left at the labelled pose.
    fn render_frame(&mut self, pose: &PoseSample, rng: &mut Rng) -> FrameInfo {
        let lidar_cfg = LidarConfig {
            seed: rng.next_u64(),
            ..self.cfg.lidar
        };
        let n = lidar_cfg.points_per_frame();
        let mut lidar = LidarSim::new(self.sim.data().model(), lidar_cfg, n).expect("validated in new");
        let frame_idx = rng.int(0, 100_000);
        let t0 = frame_idx * FRAME_NS;
        self.returns.clear();
        // Walking: one slice per 2 ms control tick, each from the pose at its time; standing: the
        // pose does not change, so one call.
        let slices: u64 = if pose.mode == Mode::Walking { 50 } else { 1 };
        for k in 0..slices {
            let (a, b) = (t0 + k * FRAME_NS / slices, t0 + (k + 1) * FRAME_NS / slices);
            let dt = (a as f64 - (t0 + FRAME_NS) as f64) * 1e-9;
            let body = pose.at(&self.world, self.nominal_height, if slices == 1 { 0.0 } else { dt });
            self.set_pose(&body);
            lidar.scan(self.sim.data_mut(), a, b, &mut self.returns);
        }
        // The labelled pose: the end of the frame.
        let body = pose.at(&self.world, self.nominal_height, 0.0);
        self.set_pose(&body);

        self.points.clear();
        self.points.extend(self.returns.iter().map(|r| r.point(t0)));
        let mut writer = PacketWriter::new();
        let asm = &mut self.assembler;
        writer
            .write_frame(&self.points, t0, &mut self.packet, |pkt| {
                asm.push(pkt).expect("own packets decode");
            })
            .expect("packet buffer sized by the writer");
        let empty = PointFrame::<0>::new();
        let frame_points: &[LidarPoint] = match self.assembler.flush() {
            Some(f) => &f.points[..f.len],
            None => &empty.points[..],
        };

        let q = {
            let qpos = self.sim.data().qpos();
            [
                qpos[self.root + 3],
                qpos[self.root + 4],
                qpos[self.root + 5],
                qpos[self.root + 6],
            ]
        };
        let rpy = g1_sim::quat_to_rpy(q);
        let ground = self.world.ground_height(body.pos[0], body.pos[1]);
        let (an, hn) = (self.cfg.attitude_noise_rad, self.cfg.height_noise_m);
        let bev_roll = rpy[0] + an * rng.gaussian();
        let bev_pitch = rpy[1] + an * rng.gaussian();
        let bev_height = body.pos[2] - ground + hn * rng.gaussian();
        let frame = RobotFrame::new(&self.mount, bev_roll as f32, bev_pitch as f32, bev_height as f32);
        // The firmware's rule for which points are terrain (it grids them via `BevMemory`).
        self.robot.clear();
        self.robot.extend(
            frame_points
                .iter()
                .map(|p| frame.apply(p.xyz))
                .filter(|&q| SelfFilter::G1_DEFAULT.classify(q) == PointClass::Terrain),
        );
        FrameInfo {
            body,
            rpy,
            ground,
            bev_roll,
            bev_pitch,
            bev_height,
            frame_points: frame_points.len(),
        }
    }

    /// The keyframes the firmware's memory would hold when it reaches `pose` (see the module
    /// documentation), oldest first, each with the odometry error of its pose.
    fn approach(&self, pose: &PoseSample, rng: &mut Rng) -> Vec<(PoseSample, [f64; 4])> {
        let mem = self.cfg.memory;
        let k_max = mem.keyframes;
        if k_max == 0 {
            return Vec::new();
        }
        let count = if rng.chance(self.cfg.memory_cold_fraction) {
            rng.int(0, k_max as u64) as usize
        } else {
            k_max
        };
        let travel = pose.yaw + rng.range(-0.4, 0.4);
        let (c, s) = (travel.cos(), travel.sin());
        let spacing = f64::from(mem.spacing_m);
        let s0 = rng.range(0.0, spacing);
        let gait_hz = if pose.mode == Mode::Walking {
            pose.gait_hz
        } else {
            rng.range(1.0, 1.6)
        };
        let mut out: Vec<(PoseSample, [f64; 4])> = (0..count)
            .map(|k| {
                let back = s0 + spacing * k as f64;
                let kf = PoseSample {
                    mode: Mode::Walking,
                    x: pose.x - c * back,
                    y: pose.y - s * back,
                    yaw: wrap_angle(pose.yaw + rng.range(-0.1, 0.1)),
                    phase: rng.range(0.0, 2.0 * PI),
                    gait_hz,
                    speed: rng.range(0.2, 0.8),
                    lean: rng.range(-4.0, 4.0).to_radians(),
                    sway: rng.range(-3.0, 3.0).to_radians(),
                    // The robot walked to this pose in its own posture.
                    roll_lean: pose.roll_lean,
                    pitch_lean: pose.pitch_lean,
                    crouch: pose.crouch,
                };
                // Leg odometry drifts with the distance walked since.
                let noise = [
                    (0.003 + 0.02 * back) * rng.gaussian(),
                    (0.003 + 0.02 * back) * rng.gaussian(),
                    (0.003 + 0.01 * back) * rng.gaussian(),
                    (0.1 + 0.5 * back).to_radians() * rng.gaussian(),
                ]
                .map(|v| v * self.cfg.odometry_drift);
                (kf, noise)
            })
            .collect();
        out.reverse();
        out
    }

    /// Renders `pose` (see the module documentation): its approach's keyframes into the memory,
    /// then the frame itself, gridded with the memory as the firmware does. `seed` drives
    /// everything random (lidar noise, scan pattern start, estimator error, the approach).
    pub fn render(&mut self, pose: &PoseSample, seed: u64) -> Sample {
        let mut rng = Rng(seed);
        let info = self.render_frame(pose, &mut rng);
        let current = std::mem::take(&mut self.robot);
        let now = OdomPose {
            pos: info.body.pos.map(|v| v as f32),
            yaw: pose.yaw as f32,
            height: info.bev_height as f32,
        };
        self.memory.clear();
        let mut mem_rng = Rng(mix(seed, 0x3E30_4B1D));
        for (kf, noise) in self.approach(pose, &mut mem_rng) {
            let mut frame_rng = Rng(mem_rng.next_u64());
            let ki = self.render_frame(&kf, &mut frame_rng);
            let at = OdomPose {
                pos: [
                    (ki.body.pos[0] + noise[0]) as f32,
                    (ki.body.pos[1] + noise[1]) as f32,
                    (ki.body.pos[2] + noise[2]) as f32,
                ],
                yaw: wrap_angle(kf.yaw + noise[3]) as f32,
                height: ki.bev_height as f32,
            };
            self.memory.remember(&self.robot, &at);
        }
        // The keyframes moved the robot: back to the labelled pose (its state is observable).
        self.set_pose(&info.body);
        let mut grid = Box::new(BevGrid::zeroed());
        let (stats, mem): (BevStats, MemoryStats) = self.memory.build(&current, &now, &mut self.bev, &mut grid);
        self.robot = current;
        let (truth, riser) = self.world.labelled_truth(info.body.pos[0], info.body.pos[1], pose.yaw);
        Sample {
            bev: grid,
            truth,
            meta: SampleMeta {
                pose: *pose,
                pelvis: info.body.pos,
                rpy: info.rpy,
                bev_roll: info.bev_roll,
                bev_pitch: info.bev_pitch,
                bev_height: info.bev_height,
                ground: info.ground,
                frame_points: info.frame_points,
                bev_points: stats.used,
                keyframes: mem.keyframes,
                memory_points: mem.points_used,
                riser,
                outdoor: self.world.spec.outdoor.is_some(),
            },
        }
    }
}

/// What [`WorldRenderer::render_frame`] reports besides the points.
struct FrameInfo {
    body: BodyPose,
    rpy: [f64; 3],
    ground: f64,
    bev_roll: f64,
    bev_pitch: f64,
    bev_height: f64,
    frame_points: usize,
}

/// Quaternion (w, x, y, z) of Rz(yaw)·Ry(pitch)·Rx(roll).
fn rpy_quat(rpy: [f64; 3]) -> [f64; 4] {
    let (sr, cr) = (0.5 * rpy[0]).sin_cos();
    let (sp, cp) = (0.5 * rpy[1]).sin_cos();
    let (sy, cy) = (0.5 * rpy[2]).sin_cos();
    [
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    ]
}

// ---------------------------------------------------------------------------------------------
// Running many worlds

/// Which worlds a run renders.
#[derive(Clone, Debug, PartialEq)]
pub enum WorldSet {
    /// `World::random(first_seed + i)`, i < count; the world seed is `first_seed + i`.
    Random { first_seed: u64, count: usize },
    /// Named worlds (presets, scenario files, `random:SEED`); world `i` gets seed `seed + i` for
    /// its poses.
    Named { args: Vec<String>, seed: u64 },
}

impl WorldSet {
    pub fn len(&self) -> usize {
        match self {
            WorldSet::Random { count, .. } => *count,
            WorldSet::Named { args, .. } => args.len(),
        }
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Held-out evaluation worlds: `World::random(EVAL_SEED_BASE + seed + i)`, i < count.
    pub fn held_out(seed: u64, count: usize) -> anyhow::Result<Self> {
        let first_seed = EVAL_SEED_BASE.checked_add(seed).ok_or_else(|| {
            anyhow::anyhow!("--seed {seed}: held-out seeds start at {EVAL_SEED_BASE} + SEED, past u64")
        })?;
        let set = WorldSet::Random { first_seed, count };
        set.check()?;
        Ok(set)
    }

    /// Refuses an empty set, and seeds that would wrap around u64 into another seed range (held-out
    /// worlds must never become training worlds).
    pub fn check(&self) -> anyhow::Result<()> {
        let (first, n) = match self {
            WorldSet::Random { first_seed, count } => (*first_seed, *count),
            WorldSet::Named { args, seed } => (*seed, args.len()),
        };
        anyhow::ensure!(n > 0, "no worlds to render: give at least one");
        anyhow::ensure!(
            first.checked_add(n as u64).is_some(),
            "world seeds {first}.. (+{n}) run past u64::MAX and would wrap around to seed 0: choose a smaller --seed"
        );
        Ok(())
    }

    /// World `i` and its seed.
    pub fn get(&self, i: usize) -> Result<(World, u64), SimError> {
        match self {
            WorldSet::Random { first_seed, count } => {
                assert!(i < *count);
                let seed = first_seed + i as u64;
                Ok((World::random(seed, &RandomRanges::default()), seed))
            }
            WorldSet::Named { args, seed } => {
                let w = World::resolve(&args[i]).map_err(|e| SimError::Config(e.to_string()))?;
                Ok((w, seed + i as u64))
            }
        }
    }
}

/// Renders `poses_per_world` samples of every world of `set`, on `jobs` threads (one world at a
/// time per thread), and hands them to `sink` in world order, then pose order (the output does not
/// depend on `jobs`). `sink` returns false to stop.
pub fn render_worlds(
    set: &WorldSet,
    poses_per_world: usize,
    cfg: DatasetConfig,
    jobs: usize,
    mut sink: impl FnMut(usize, u64, Sample) -> anyhow::Result<()>,
) -> anyhow::Result<()> {
    set.check()?;
    anyhow::ensure!(
        poses_per_world > 0,
        "--poses-per-world 0 renders nothing: give at least 1"
    );
    anyhow::ensure!(jobs > 0, "--jobs 0: give at least 1 worker");
    let n = set.len();
    let jobs = jobs.clamp(1, n.max(1));
    let next = AtomicUsize::new(0);
    let stop = std::sync::atomic::AtomicBool::new(false);
    type Msg = (usize, Result<(u64, Vec<Sample>), SimError>);
    let (tx, rx) = mpsc::sync_channel::<Msg>(2 * jobs);
    std::thread::scope(|scope| -> anyhow::Result<()> {
        for _ in 0..jobs {
            let (tx, next, stop) = (tx.clone(), &next, &stop);
            scope.spawn(move || loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                if i >= n || stop.load(Ordering::Relaxed) {
                    break;
                }
                let r = set.get(i).and_then(|(world, seed)| {
                    let mut r = WorldRenderer::new(world, seed, cfg)?;
                    Ok((seed, (0..poses_per_world as u64).map(|k| r.render_index(k)).collect()))
                });
                if tx.send((i, r)).is_err() {
                    break;
                }
            });
        }
        drop(tx);
        let mut pending: BTreeMap<usize, (u64, Vec<Sample>)> = BTreeMap::new();
        let mut want = 0;
        let result = (|| -> anyhow::Result<()> {
            for (i, r) in rx.iter() {
                pending.insert(i, r.map_err(|e| anyhow::anyhow!("world {i}: {e}"))?);
                while let Some((seed, samples)) = pending.remove(&want) {
                    for s in samples {
                        sink(want, seed, s)?;
                    }
                    want += 1;
                }
            }
            Ok(())
        })();
        if result.is_err() {
            stop.store(true, Ordering::Relaxed);
            // Drain so that blocked senders finish.
            for _ in rx.iter() {}
        }
        result
    })
}

// ---------------------------------------------------------------------------------------------
// Export

/// Settings of [`export`].
#[derive(Clone, Debug)]
pub struct ExportConfig {
    pub worlds: WorldSet,
    pub poses_per_world: usize,
    pub shard_size: usize,
    pub out: PathBuf,
    /// Write into an `out` that exists and is not empty (its shards are replaced).
    pub force: bool,
    pub jobs: usize,
    pub dataset: DatasetConfig,
}

/// What `manifest.json` holds.
#[derive(Clone, Debug, Serialize)]
pub struct Manifest {
    pub format: &'static str,
    pub samples: usize,
    pub worlds: usize,
    pub poses_per_world: usize,
    pub world_seeds: Vec<u64>,
    pub world_names: Vec<String>,
    pub shards: Vec<ShardInfo>,
    pub mode: ModeChoice,
    pub attitude_noise_rad: f64,
    pub height_noise_m: f64,
    pub lidar_points_per_frame: usize,
    /// Samples per true class: flat, stairs-up, stairs-down.
    pub class_histogram: [usize; 3],
    pub mode_histogram: [usize; 2],
    pub tensors: BTreeMap<&'static str, &'static str>,
}

#[derive(Clone, Debug, Serialize)]
pub struct ShardInfo {
    pub file: String,
    pub samples: usize,
}

/// Tensor names and layouts.
pub const TENSOR_DOC: [(&str, &str); 8] = [
    (
        "bev",
        "f32 [n, 6, 60, 60]: sensor_io::bev grid (channels max_z, min_z, mean_z, range_z, std_z, density; \
         row = x from -1.5 m, column = y from -1.5 m; 0.05 m cells; empty cells 0)",
    ),
    ("class", "u8 [n]: true class 0 flat, 1 stairs-up, 2 stairs-down"),
    ("step_height", "f32 [n]: true step height h, m (0 for flat)"),
    ("step_depth", "f32 [n]: true step depth d, m (0 for flat)"),
    (
        "yaw",
        "f32 [n]: true token yaw theta, rad (stairs: heading - direction of travel; flat: heading)",
    ),
    ("world_seed", "i64 [n]: seed of the sample's world (split by it)"),
    (
        "pose",
        "f32 [n, 4]: pelvis x, y, z (world, m) and heading (rad) at the labelled instant",
    ),
    ("mode", "u8 [n]: 0 standing, 1 walking"),
];

fn shard_name(k: usize) -> String {
    format!("shard-{k:05}.safetensors")
}

#[derive(Default)]
struct ShardBuf {
    bev: Vec<u8>,
    class: Vec<u8>,
    h: Vec<u8>,
    d: Vec<u8>,
    yaw: Vec<u8>,
    seed: Vec<u8>,
    pose: Vec<u8>,
    mode: Vec<u8>,
    n: usize,
}

impl ShardBuf {
    fn push(&mut self, world_seed: u64, s: &Sample) {
        for v in s.bev.data.iter() {
            self.bev.extend_from_slice(&v.to_le_bytes());
        }
        self.class.push(s.truth.class.index() as u8);
        self.h.extend_from_slice(&s.truth.step_height_m.to_le_bytes());
        self.d.extend_from_slice(&s.truth.step_depth_m.to_le_bytes());
        self.yaw.extend_from_slice(&s.truth.yaw_rad.to_le_bytes());
        self.seed.extend_from_slice(&(world_seed as i64).to_le_bytes());
        let m = &s.meta;
        for v in [m.pelvis[0], m.pelvis[1], m.pelvis[2], m.pose.yaw] {
            self.pose.extend_from_slice(&(v as f32).to_le_bytes());
        }
        self.mode.push(m.pose.mode as u8);
        self.n += 1;
    }

    fn write(&mut self, path: &Path) -> anyhow::Result<()> {
        use safetensors::tensor::{Dtype, TensorView};
        let n = self.n;
        fn t(dtype: Dtype, shape: Vec<usize>, data: &[u8]) -> Result<TensorView<'_>, safetensors::SafeTensorError> {
            TensorView::new(dtype, shape, data)
        }
        let tensors = vec![
            (
                "bev",
                t(Dtype::F32, vec![n, BEV_CHANNELS, BEV_CELLS, BEV_CELLS], &self.bev)?,
            ),
            ("class", t(Dtype::U8, vec![n], &self.class)?),
            ("step_height", t(Dtype::F32, vec![n], &self.h)?),
            ("step_depth", t(Dtype::F32, vec![n], &self.d)?),
            ("yaw", t(Dtype::F32, vec![n], &self.yaw)?),
            ("world_seed", t(Dtype::I64, vec![n], &self.seed)?),
            ("pose", t(Dtype::F32, vec![n, 4], &self.pose)?),
            ("mode", t(Dtype::U8, vec![n], &self.mode)?),
        ];
        let meta = Some(std::collections::HashMap::from([(
            "format".to_string(),
            "g1-dataset terrain BEV v1 (see manifest.json)".to_string(),
        )]));
        safetensors::serialize_to_file(tensors, &meta, path)
            .map_err(|e| anyhow::anyhow!("writing {}: {e:?}", path.display()))?;
        *self = ShardBuf::default();
        Ok(())
    }
}

/// Renders the dataset into `cfg.out` (`shard-NNNNN.safetensors` of at most `shard_size` samples,
/// tensors as in [`TENSOR_DOC`], and `manifest.json`). `progress` is called once per sample.
pub fn export(cfg: &ExportConfig, progress: &dyn Fn()) -> anyhow::Result<Manifest> {
    anyhow::ensure!(cfg.shard_size > 0, "shard size must be at least 1");
    anyhow::ensure!(!cfg.worlds.is_empty(), "no worlds to render");
    let occupied = std::fs::read_dir(&cfg.out).is_ok_and(|mut d| d.next().is_some());
    anyhow::ensure!(
        !occupied || cfg.force,
        "{} exists and is not empty: export into a new directory, or pass --force to replace its dataset",
        cfg.out.display()
    );
    std::fs::create_dir_all(&cfg.out).map_err(|e| anyhow::anyhow!("creating {}: {e}", cfg.out.display()))?;
    let mut shards = Vec::new();
    let mut buf = ShardBuf::default();
    let (mut class_histogram, mut mode_histogram) = ([0usize; 3], [0usize; 2]);
    let (mut world_seeds, mut world_names) = (Vec::new(), Vec::new());
    let mut samples = 0;
    render_worlds(
        &cfg.worlds,
        cfg.poses_per_world,
        cfg.dataset,
        cfg.jobs,
        |wi, seed, s| {
            if world_seeds.len() == wi {
                world_seeds.push(seed);
                world_names.push(match &cfg.worlds {
                    WorldSet::Named { args, .. } => args[wi].clone(),
                    WorldSet::Random { .. } => format!("random:{seed}"),
                });
            }
            class_histogram[s.truth.class.index()] += 1;
            mode_histogram[s.meta.pose.mode as usize] += 1;
            buf.push(seed, &s);
            samples += 1;
            if buf.n == cfg.shard_size {
                let file = shard_name(shards.len());
                shards.push(ShardInfo {
                    file: file.clone(),
                    samples: buf.n,
                });
                buf.write(&cfg.out.join(file))?;
            }
            progress();
            Ok(())
        },
    )?;
    if buf.n > 0 {
        let file = shard_name(shards.len());
        shards.push(ShardInfo {
            file: file.clone(),
            samples: buf.n,
        });
        buf.write(&cfg.out.join(file))?;
    }
    let d = &cfg.dataset;
    let manifest = Manifest {
        format: "g1-dataset terrain BEV v1",
        samples,
        worlds: world_seeds.len(),
        poses_per_world: cfg.poses_per_world,
        world_seeds,
        world_names,
        shards,
        mode: d.mode,
        attitude_noise_rad: d.attitude_noise_rad,
        height_noise_m: d.height_noise_m,
        lidar_points_per_frame: d.lidar.points_per_frame(),
        class_histogram,
        mode_histogram,
        tensors: TENSOR_DOC.iter().copied().collect(),
    };
    let path = cfg.out.join("manifest.json");
    std::fs::write(&path, serde_json::to_string_pretty(&manifest)? + "\n")
        .map_err(|e| anyhow::anyhow!("writing {}: {e}", path.display()))?;
    Ok(manifest)
}

// ---------------------------------------------------------------------------------------------
// Evaluation of the geometric estimator

/// Errors of one group of samples.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct EvalStats {
    pub samples: usize,
    /// Over all samples (flat counts with h = d = 0), cm.
    pub mae_h_cm: f64,
    pub mae_d_cm: f64,
    /// h and d over samples whose true class is stairs only, cm (the stricter reading).
    pub mae_h_cm_stairs: f64,
    pub mae_d_cm_stairs: f64,
    /// Over samples whose true class is stairs, degrees (wrapped difference).
    pub mae_yaw_deg: f64,
    pub stairs_samples: usize,
    /// Over samples where both the truth and the estimate are stairs, degrees.
    pub mae_yaw_deg_both_stairs: f64,
    pub both_stairs_samples: usize,
    pub class_accuracy: f64,
    /// `confusion[true][predicted]`, classes flat, stairs-up, stairs-down.
    pub confusion: [[usize; 3]; 3],
    /// Estimates that `estimator::terrain::plausible` rejects (the firmware would not use them;
    /// they are counted in the errors above all the same).
    pub implausible: usize,
    /// h, d, yaw (stairs), yaw (both stairs), h (stairs), d (stairs): sums of absolute errors.
    #[serde(skip)]
    sums: [f64; 6],
}

impl EvalStats {
    pub fn add(&mut self, truth: &TerrainToken, est: &TerrainToken) {
        self.samples += 1;
        self.sums[0] += (truth.step_height_m - est.step_height_m).abs() as f64;
        self.sums[1] += (truth.step_depth_m - est.step_depth_m).abs() as f64;
        let stairs = |c: TerrainClass| c != TerrainClass::Flat;
        if stairs(truth.class) {
            let e = wrap_angle(truth.yaw_rad as f64 - est.yaw_rad as f64).abs();
            self.stairs_samples += 1;
            self.sums[2] += e;
            self.sums[4] += (truth.step_height_m - est.step_height_m).abs() as f64;
            self.sums[5] += (truth.step_depth_m - est.step_depth_m).abs() as f64;
            if stairs(est.class) {
                self.both_stairs_samples += 1;
                self.sums[3] += e;
            }
        }
        self.confusion[truth.class.index()][est.class.index()] += 1;
        if !plausible(est) {
            self.implausible += 1;
        }
        self.finish();
    }

    fn finish(&mut self) {
        let n = self.samples.max(1) as f64;
        self.mae_h_cm = 100.0 * self.sums[0] / n;
        self.mae_d_cm = 100.0 * self.sums[1] / n;
        let n_stairs = self.stairs_samples.max(1) as f64;
        self.mae_h_cm_stairs = 100.0 * self.sums[4] / n_stairs;
        self.mae_d_cm_stairs = 100.0 * self.sums[5] / n_stairs;
        self.mae_yaw_deg = self.sums[2].to_degrees() / n_stairs;
        self.mae_yaw_deg_both_stairs = self.sums[3].to_degrees() / self.both_stairs_samples.max(1) as f64;
        let correct: usize = (0..3).map(|i| self.confusion[i][i]).sum();
        self.class_accuracy = correct as f64 / n;
    }
}

impl std::fmt::Display for EvalStats {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "{} samples: MAE(h) {:.2} cm, MAE(d) {:.2} cm, MAE(yaw) {:.2} deg over {} stairs samples \
             ({:.2} deg over {} where both are stairs), class accuracy {:.1} %, {} implausible estimates",
            self.samples,
            self.mae_h_cm,
            self.mae_d_cm,
            self.mae_yaw_deg,
            self.stairs_samples,
            self.mae_yaw_deg_both_stairs,
            self.both_stairs_samples,
            100.0 * self.class_accuracy,
            self.implausible
        )?;
        writeln!(f, "  confusion (rows true, columns predicted): flat / up / down")?;
        for (name, row) in ["flat", "up", "down"].iter().zip(&self.confusion) {
            writeln!(f, "  {name:>5} {:>6} {:>6} {:>6}", row[0], row[1], row[2])?;
        }
        Ok(())
    }
}

/// One evaluated sample (for the report and for determinism checks).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct EvalRecord {
    pub world_seed: u64,
    pub mode: Mode,
    pub truth: [f32; 4],
    pub estimate: [f32; 4],
    pub confidence: f32,
    pub bev_points: usize,
}

/// A token as `[class index, h, d, yaw]` (how reports store tokens).
pub fn token_array(t: &TerrainToken) -> [f32; 4] {
    [t.class.index() as f32, t.step_height_m, t.step_depth_m, t.yaw_rad]
}

/// The geometric estimator's errors over a set of worlds.
#[derive(Clone, Debug, Serialize)]
pub struct EvalReport {
    pub worlds: usize,
    pub poses_per_world: usize,
    pub first_world_seed: Option<u64>,
    pub all: EvalStats,
    pub standing: EvalStats,
    pub walking: EvalStats,
    pub records: Vec<EvalRecord>,
}

/// Renders `set` and runs the geometric estimator (default configuration) on every grid.
pub fn evaluate_geometric(
    set: &WorldSet,
    poses_per_world: usize,
    cfg: DatasetConfig,
    jobs: usize,
    progress: &dyn Fn(),
) -> anyhow::Result<EvalReport> {
    let mut est = GeometricTerrainEstimator::new(GeometricTerrainConfig::default());
    let (mut all, mut standing, mut walking) = (EvalStats::default(), EvalStats::default(), EvalStats::default());
    let mut records = Vec::new();
    let mut seeds = Vec::new();
    render_worlds(set, poses_per_world, cfg, jobs, |wi, seed, s| {
        if seeds.len() == wi {
            seeds.push(seed);
        }
        let e = est.estimate(&s.bev);
        all.add(&s.truth, &e.token);
        match s.meta.pose.mode {
            Mode::Standing => standing.add(&s.truth, &e.token),
            Mode::Walking => walking.add(&s.truth, &e.token),
        }
        records.push(EvalRecord {
            world_seed: seed,
            mode: s.meta.pose.mode,
            truth: token_array(&s.truth),
            estimate: token_array(&e.token),
            confidence: e.confidence,
            bev_points: s.meta.bev_points,
        });
        progress();
        Ok(())
    })?;
    Ok(EvalReport {
        worlds: seeds.len(),
        poses_per_world,
        first_world_seed: seeds.first().copied(),
        all,
        standing,
        walking,
        records,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn token(class: TerrainClass, h: f32, d: f32, yaw_deg: f32) -> TerrainToken {
        TerrainToken {
            class,
            step_height_m: h,
            step_depth_m: d,
            yaw_rad: yaw_deg.to_radians(),
        }
    }

    #[test]
    fn posture_ranges_add_lean_and_crouch_and_leave_every_other_draw_unchanged() {
        let world = World::preset("stairs-up").expect("preset");
        let posture = Posture {
            roll_lean_rad: 12f64.to_radians(),
            pitch_lean_rad: 4f64.to_radians(),
            crouch_m: 0.14,
        };
        let (mut walking, mut rolled_far) = (0, 0);
        for i in 0..200 {
            let plain = sample_pose(&world, 7, i, ModeChoice::Mixed, &Posture::default());
            let p = sample_pose(&world, 7, i, ModeChoice::Mixed, &posture);
            assert_eq!((plain.roll_lean, plain.pitch_lean, plain.crouch), (0.0, 0.0, 0.0));
            // The new draws come last: everything else is the pose drawn without them.
            let bare = PoseSample {
                roll_lean: 0.0,
                pitch_lean: 0.0,
                crouch: 0.0,
                ..p
            };
            assert_eq!(bare, plain, "pose {i}");
            if p.mode == Mode::Standing {
                assert_eq!(
                    (p.roll_lean, p.crouch),
                    (0.0, 0.0),
                    "standing poses keep the home posture"
                );
                continue;
            }
            walking += 1;
            assert!(p.roll_lean.abs() <= posture.roll_lean_rad && p.pitch_lean.abs() <= posture.pitch_lean_rad);
            assert!((0.0..=posture.crouch_m).contains(&p.crouch));
            rolled_far += usize::from(p.roll_lean.abs() > 6f64.to_radians());
            // The body carries them: lower by the crouch, rolled and pitched by the leans.
            let (a, b) = (plain.at(&world, 0.79, 0.0), p.at(&world, 0.79, 0.0));
            assert!((a.pos[2] - p.crouch - b.pos[2]).abs() < 1e-12);
            assert!((b.rpy[0] - a.rpy[0] - p.roll_lean).abs() < 1e-12);
            assert!((b.rpy[1] - a.rpy[1] - p.pitch_lean).abs() < 1e-12);
        }
        assert!(
            walking > 60 && rolled_far > walking / 4,
            "{walking} walking, {rolled_far} beyond 6°"
        );
    }

    #[test]
    fn eval_stats_average_each_error_over_its_own_samples() {
        let mut s = EvalStats::default();
        // Stairs, estimated as stairs: 1 cm h, 2 cm d, 3° yaw off.
        s.add(
            &token(TerrainClass::StairsUp, 0.15, 0.30, 10.0),
            &token(TerrainClass::StairsUp, 0.16, 0.28, 13.0),
        );
        // Stairs, estimated flat: 15 cm h, 30 cm d off; yaw 20° off (counted in mae_yaw_deg only).
        s.add(
            &token(TerrainClass::StairsDown, 0.15, 0.30, 0.0),
            &token(TerrainClass::Flat, 0.0, 0.0, 20.0),
        );
        // Flat, estimated flat: no error.
        s.add(&TerrainToken::FLAT, &TerrainToken::FLAT);
        let close = |a: f64, b: f64| (a - b).abs() < 1e-4;
        assert_eq!((s.samples, s.stairs_samples, s.both_stairs_samples), (3, 2, 1));
        assert!(close(s.mae_h_cm, 16.0 / 3.0), "{s:?}");
        assert!(close(s.mae_d_cm, 32.0 / 3.0), "{s:?}");
        assert!(close(s.mae_h_cm_stairs, 8.0) && close(s.mae_d_cm_stairs, 16.0), "{s:?}");
        assert!(
            close(s.mae_yaw_deg, 11.5) && close(s.mae_yaw_deg_both_stairs, 3.0),
            "{s:?}"
        );
        assert!(close(s.class_accuracy, 2.0 / 3.0));
        assert_eq!(s.confusion[2][0], 1);
    }
}
