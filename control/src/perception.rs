//! The perception group (10 Hz): the newest lidar frame → gravity-aligned robot frame (estimator
//! attitude and height, spec mount) → the paper's 6×60×60 BEV grid → terrain token.
//!
//! Motion during a frame (100 ms) is compensated: every fast tick records the estimator's pose
//! (attitude, position, height) in a ring, and each point is mapped through the pose of the tick it
//! was fired in, into the gravity-aligned robot frame of the perception tick. Without that, a
//! walking robot's sway (a few degrees over a frame) tilts the ground by centimetres at 1.5 m.
//!
//! The lidar sees nothing within ~0.8 m of the robot, where the nearest riser usually is, so the
//! grid also holds a few remembered keyframes taken while the robot walked there
//! ([`sensor_io::bev_memory`]: placed through the estimator's odometry, filling only cells the
//! current frame misses; `[perception] bev_memory_keyframes`, default: what the built-in network
//! was trained with). Losing the estimate clears it.
//!
//! The token comes from the terrain CNN ([`crate::terrain_net`], trained by `g1-train`; the
//! default) or the geometric estimator (`estimator::terrain`), as `[perception] terrain_estimator`
//! says; it is checked for plausibility and otherwise replaced by the last plausible one (or flat).
//! Everything is allocated in [`Perception::new`]; a step does not allocate.
use estimator::terrain::{plausible, GeometricTerrainConfig, GeometricTerrainEstimator, TerrainEstimate};
use hal::LIDAR_FRAME_CAP;
use hal::{PointFrame, TerrainToken};
use sensor_io::bev::{
    rpy_rotation, BevBuilder, BevGrid, BevStats, MountPose, PointClass, RobotFrame, SelfFilter, WaistChain,
};
use sensor_io::bev_memory::{BevMemory, MemoryStats, OdomPose};

/// The state estimate of one tick (attitude, base velocity and height, foot contacts).
pub type Estimate = estimator::BaseEstimate;
use crate::spec::{PerceptionSpec, TerrainEstimatorKind};
use crate::terrain_net::TerrainNet;

/// Where the policy's terrain token comes from (`g1fw sim|eval --terrain-source`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TerrainSource {
    /// The perception group's token from the terrain CNN.
    Cnn,
    /// The perception group's token from the geometric estimator.
    Geometric,
    /// **Evaluation ablation**: the simulator's privileged ground-truth token (`Truth.terrain`) of
    /// each tick goes to the policy. Simulation only, logged as such; replay refuses such logs.
    Truth,
    /// The policy runs blind: the token stays flat (class flat, h = d = 0, yaw 0). Perception still
    /// runs and is logged and reported.
    None,
}

impl TerrainSource {
    pub const NAMES: [&'static str; 4] = ["cnn", "geometric", "truth", "none"];

    pub fn as_str(self) -> &'static str {
        match self {
            TerrainSource::Cnn => "cnn",
            TerrainSource::Geometric => "geometric",
            TerrainSource::Truth => "truth",
            TerrainSource::None => "none",
        }
    }

    /// The perception estimator this source selects (`None` keeps the spec's).
    pub fn estimator(self) -> Option<TerrainEstimatorKind> {
        match self {
            TerrainSource::Cnn => Some(TerrainEstimatorKind::Cnn),
            TerrainSource::Geometric => Some(TerrainEstimatorKind::Geometric),
            _ => None,
        }
    }

    /// The source a spec selects by itself (its `[perception] terrain_estimator`).
    pub fn of_spec(spec: &PerceptionSpec) -> Self {
        match spec.terrain_estimator {
            TerrainEstimatorKind::Cnn => TerrainSource::Cnn,
            TerrainEstimatorKind::Geometric => TerrainSource::Geometric,
        }
    }
}

impl std::str::FromStr for TerrainSource {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Ok(match s {
            "cnn" => TerrainSource::Cnn,
            "geometric" => TerrainSource::Geometric,
            "truth" => TerrainSource::Truth,
            "none" => TerrainSource::None,
            _ => {
                return Err(format!(
                    "unknown terrain source '{s}': expected one of {}",
                    Self::NAMES.join(", ")
                ))
            }
        })
    }
}

impl std::fmt::Display for TerrainSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// The lidar frame buffer the HAL fills.
pub type LidarFrame = PointFrame<LIDAR_FRAME_CAP>;

/// What one perception step produced (small and `Copy`: it rides in the tick summary).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PerceptionSummary {
    /// The step had a new lidar frame (otherwise the token is the previous one).
    pub fresh: bool,
    /// Start of the frame used, on the HAL's time base, ns.
    pub frame_timestamp_ns: u64,
    pub points: u32,
    /// The current frame's points (remembered ones are counted in `memory_points`).
    pub bev: BevStats,
    /// Keyframes in the BEV memory, and the remembered points that went into the grid.
    pub memory_keyframes: u32,
    pub memory_points: u32,
    /// Inputs of the robot frame.
    pub roll: f32,
    pub pitch: f32,
    pub base_height: f32,
    /// Which estimator made `estimate`.
    pub source: TerrainEstimatorKind,
    /// This frame's estimate (before the plausibility check).
    pub estimate: TerrainToken,
    /// The CNN's softmax probability of its class, or the geometric estimator's confidence.
    pub confidence: f32,
    /// The geometric estimate of this frame (only when it is the source; default otherwise).
    pub geometric: TerrainEstimate,
    /// The token the robot acts on (plausible, or held from before).
    pub token: TerrainToken,
    /// This frame's estimate was implausible (or not finite) and the token was held.
    pub held: bool,
    /// Frames seen so far.
    pub frames: u64,
    /// The tick whose frame this step used (threaded perception hands its result back later).
    pub step_tick: u64,
    /// Threaded: the result was not ready when due, and its token was not used.
    pub late: bool,
}

/// Ticks of pose history (512 ms at 500 Hz: a frame plus the wait for the next perception tick).
const HISTORY: usize = 256;

#[derive(Clone, Copy, Debug, Default)]
struct PoseSample {
    time_ns: u64,
    /// Base to heading frame (rows), including yaw.
    rot: [[f32; 3]; 3],
    pos: [f32; 3],
    height: f32,
    /// The waist joints (yaw, roll, pitch) the torso-mounted sensor sat on.
    waist: [f32; 3],
}

pub struct Perception {
    mount: MountPose,
    /// `Some` when the sensor rides on the torso (`[perception] mount_on_torso`).
    waist_chain: Option<WaistChain>,
    history: Box<[PoseSample; HISTORY]>,
    history_len: usize,
    history_next: usize,
    /// Points mapped into the robot frame, before gridding.
    scratch: Box<[[f32; 3]]>,
    filter: SelfFilter,
    fallback_height: f32,
    builder: Box<BevBuilder>,
    memory: BevMemory,
    grid: Box<BevGrid>,
    frame: Box<LidarFrame>,
    geometric: GeometricTerrainEstimator,
    /// `Some` when the CNN makes the token.
    cnn: Option<Box<TerrainNet>>,
    last: PerceptionSummary,
}

impl Perception {
    /// Spec validation has already refused a bad self-filter or terrain network; should one get
    /// here anyway, the default G1 filter and the built-in network are used (and said so).
    /// `base_dir` resolves the spec's relative paths.
    pub fn new(spec: &PerceptionSpec, base_dir: &std::path::Path) -> Self {
        let mount = spec.mount();
        let cnn = match spec.terrain_estimator {
            TerrainEstimatorKind::Geometric => None,
            TerrainEstimatorKind::Cnn => {
                let loaded = match (&spec.terrain_network, &spec.terrain_weights) {
                    (Some(d), Some(w)) => TerrainNet::load(&base_dir.join(d), &base_dir.join(w)),
                    _ => TerrainNet::embedded(),
                };
                match loaded.or_else(|e| {
                    tracing::error!("terrain network: {e}; using the built-in one");
                    TerrainNet::embedded()
                }) {
                    Ok(net) => Some(Box::new(net)),
                    Err(e) => {
                        tracing::error!("built-in terrain network: {e}; using the geometric estimator");
                        None
                    }
                }
            }
        };
        Self {
            mount,
            waist_chain: spec.mount_on_torso.then_some(WaistChain::G1),
            history: Box::new([PoseSample::default(); HISTORY]),
            history_len: 0,
            history_next: 0,
            scratch: vec![[0.0; 3]; LIDAR_FRAME_CAP].into_boxed_slice(),
            filter: spec.self_filter().unwrap_or(SelfFilter::G1_DEFAULT),
            fallback_height: spec.fallback_base_height_m,
            builder: BevBuilder::new_boxed(),
            memory: BevMemory::new(spec.bev_memory(), LIDAR_FRAME_CAP),
            grid: Box::new(BevGrid::zeroed()),
            frame: sensor_io::livox::boxed_point_frame(),
            geometric: GeometricTerrainEstimator::new(GeometricTerrainConfig::default()),
            cnn,
            last: PerceptionSummary {
                token: TerrainToken::FLAT,
                ..Default::default()
            },
        }
    }

    /// The buffer the HAL writes the newest lidar frame into.
    pub fn frame_mut(&mut self) -> &mut LidarFrame {
        &mut self.frame
    }

    /// The lidar frame in the buffer: after a step with a fresh frame (until the HAL is next asked
    /// for one, before the next perception step), exactly the frame that step consumed; for logs.
    pub fn frame(&self) -> &LidarFrame {
        &self.frame
    }

    pub fn grid(&self) -> &BevGrid {
        &self.grid
    }

    pub fn last(&self) -> &PerceptionSummary {
        &self.last
    }

    /// Records the estimate of a fast tick (every tick, so points can be mapped through the pose
    /// of the tick they were fired in).
    pub fn record_pose(&mut self, time_ns: u64, est: &Estimate) {
        let (roll, pitch, height) = robot_frame_inputs(est, self.fallback_height);
        let yaw = if est.rpy[2].is_finite() { est.rpy[2] } else { 0.0 };
        let pos = if est.valid && est.position.iter().all(|v| v.is_finite()) {
            est.position
        } else {
            [0.0; 3]
        };
        self.history[self.history_next] = PoseSample {
            time_ns,
            rot: rpy_rows(roll, pitch, yaw),
            pos,
            height,
            waist: est.waist,
        };
        self.history_next = (self.history_next + 1) % HISTORY;
        self.history_len = (self.history_len + 1).min(HISTORY);
    }

    /// The newest recorded pose at or before `t_ns` (the oldest one if all are later).
    fn pose_at(&self, t_ns: u64) -> Option<&PoseSample> {
        let mut best: Option<&PoseSample> = None;
        for i in 0..self.history_len {
            let p = &self.history[(self.history_next + HISTORY - 1 - i) % HISTORY];
            best = Some(p);
            if p.time_ns <= t_ns {
                break;
            }
        }
        best
    }

    /// One perception step at `now_ns`. `fresh`: the HAL put a new frame into
    /// [`Perception::frame_mut`].
    pub fn step(&mut self, now_ns: u64, fresh: bool, est: &Estimate) -> PerceptionSummary {
        if !fresh {
            self.last.fresh = false;
            return self.last;
        }
        let (roll, pitch, height) = robot_frame_inputs(est, self.fallback_height);
        if !est.valid {
            // No odometry: remembered frames cannot be placed.
            self.memory.clear();
        }
        let current = self.sensor_frame(est.waist, roll, pitch, height);
        let (bev, memory) = self.grid_frame(now_ns, &current);
        let heading = if est.rpy[2].is_finite() { est.rpy[2] } else { 0.0 };
        let (source, estimate, confidence, geometric) = match self.cnn.as_deref_mut() {
            Some(net) => {
                let e = net.estimate(&self.grid, heading);
                let conf = estimator::terrain_cnn::class_confidence(net.outputs());
                // A non-finite output is never plausible: mark it so with a NaN height.
                let e = e.unwrap_or(TerrainToken {
                    step_height_m: f32::NAN,
                    ..TerrainToken::FLAT
                });
                (TerrainEstimatorKind::Cnn, e, conf, TerrainEstimate::default())
            }
            None => {
                let g = self.geometric.estimate(&self.grid);
                (TerrainEstimatorKind::Geometric, g.token, g.confidence, g)
            }
        };
        let ok = plausible(&estimate);
        self.last = PerceptionSummary {
            fresh: true,
            frame_timestamp_ns: self.frame.timestamp_ns,
            points: self.frame.len as u32,
            bev,
            memory_keyframes: memory.keyframes as u32,
            memory_points: memory.points_used as u32,
            roll,
            pitch,
            base_height: height,
            source,
            estimate,
            confidence,
            geometric,
            token: if ok { estimate } else { self.last.token },
            held: !ok,
            frames: self.last.frames + 1,
            step_tick: 0,
            late: false,
        };
        self.last
    }
}

fn rpy_rows(roll: f32, pitch: f32, yaw: f32) -> [[f32; 3]; 3] {
    rpy_rotation([roll, pitch, yaw].map(f64::from)).map(|r| r.map(|v| v as f32))
}

fn mat_vec(m: &[[f32; 3]; 3], v: [f32; 3]) -> [f32; 3] {
    [0, 1, 2].map(|i| m[i][0] * v[0] + m[i][1] * v[1] + m[i][2] * v[2])
}

impl Perception {
    /// Maps the frame's points through the pose of the tick each was fired in into the robot frame
    /// at `now_ns` (yaw and translation since then included), drops self-hits, and grids them
    /// together with the BEV memory's keyframes. Without pose history (first tick) every point
    /// goes through `current` and the memory is left out.
    fn grid_frame(&mut self, now_ns: u64, current: &RobotFrame) -> (BevStats, MemoryStats) {
        let Some(now) = self.pose_at(now_ns).copied() else {
            let stats = self
                .builder
                .build(self.frame.as_slice(), current, &self.filter, &mut self.grid);
            return (stats, MemoryStats::default());
        };
        // Heading frame → robot frame at `now`: undo yaw only (roll and pitch stay gravity-aligned).
        let yaw_now = libm::atan2f(now.rot[1][0], now.rot[0][0]);
        let (s, c) = libm::sincosf(yaw_now);
        let unyaw = [[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]];
        let (mut n, mut self_hits, mut non_finite) = (0usize, 0usize, 0usize);
        let mut cached: Option<(u64, PoseSample, RobotFrame)> = None;
        for p in self.frame.as_slice() {
            let t = self.frame.timestamp_ns.saturating_add(p.offset_ns as u64);
            // Points come in firing order: one pose lookup per tick, not per point.
            let (pose, mount) = match cached {
                Some((tick_t, pose, mount)) if t >= tick_t && t < tick_t + 2_000_000 => (pose, mount),
                _ => {
                    let pose = self.pose_at(t).copied().unwrap_or(now);
                    // Sensor → base at that tick: the torso's pose on the pelvis then.
                    let mount = self.sensor_frame(pose.waist, 0.0, 0.0, 0.0);
                    cached = Some((pose.time_ns, pose, mount));
                    (pose, mount)
                }
            };
            let base = mount.apply(p.xyz);
            let w = mat_vec(&pose.rot, base);
            let d = [
                w[0] + pose.pos[0] - now.pos[0],
                w[1] + pose.pos[1] - now.pos[1],
                w[2] + pose.pos[2] - now.pos[2],
            ];
            let r = mat_vec(&unyaw, d);
            let q = [r[0], r[1], r[2] + now.height];
            match self.filter.classify(q) {
                PointClass::NonFinite => non_finite += 1,
                PointClass::SelfHit => self_hits += 1,
                PointClass::Terrain => {
                    self.scratch[n] = q;
                    n += 1;
                }
            }
        }
        let odom = OdomPose {
            pos: now.pos,
            yaw: yaw_now,
            height: now.height,
        };
        let (mut stats, memory) = self
            .memory
            .build(&self.scratch[..n], &odom, &mut self.builder, &mut self.grid);
        // Describe the current frame only: remembered points all landed in cells.
        stats.used -= memory.points_used;
        stats.input = self.frame.len;
        stats.self_hits = self_hits;
        stats.non_finite += non_finite;
        (stats, memory)
    }

    /// Sensor → robot frame with the waist at `waist` (when the sensor rides on the torso).
    fn sensor_frame(&self, waist: [f32; 3], roll: f32, pitch: f32, height: f32) -> RobotFrame {
        match &self.waist_chain {
            Some(chain) => RobotFrame::on_waist(&self.mount, chain, waist, roll, pitch, height),
            None => RobotFrame::new(&self.mount, roll, pitch, height),
        }
    }

    /// The frame's points in the robot frame of the last step (self-hits removed), for logs.
    pub fn robot_points(&self) -> &[[f32; 3]] {
        let n = self.last.bev.input - self.last.bev.self_hits - self.last.bev.non_finite;
        &self.scratch[..n.min(self.scratch.len())]
    }
}

/// Roll, pitch and the base's height above the ground under the robot, from the estimate: the
/// height is over the lowest foot in contact (else the lowest foot), which is the tread the robot
/// stands on; without leg kinematics the spec's fallback height.
pub fn robot_frame_inputs(est: &Estimate, fallback_height: f32) -> (f32, f32, f32) {
    let (roll, pitch) = (est.rpy[0], est.rpy[1]);
    let (roll, pitch) = if roll.is_finite() && pitch.is_finite() {
        (roll, pitch)
    } else {
        (0.0, 0.0)
    };
    if !est.valid {
        return (roll, pitch, fallback_height);
    }
    let feet = est.foot_pos;
    let any_contact = est.contact[0] || est.contact[1];
    let mut ground = f32::INFINITY;
    for (i, f) in feet.iter().enumerate() {
        if !any_contact || est.contact[i] {
            ground = ground.min(f[2]);
        }
    }
    let h = est.position[2] - ground;
    (
        roll,
        pitch,
        if h.is_finite() && h > 0.2 && h < 1.5 {
            h
        } else {
            fallback_height
        },
    )
}

impl snapshot::Snapshot for TerrainEstimatorKind {
    fn save(&self, out: &mut Vec<u8>) {
        out.push(match self {
            TerrainEstimatorKind::Cnn => 0,
            TerrainEstimatorKind::Geometric => 1,
        });
    }

    fn restore(&mut self, input: &mut &[u8]) -> Result<(), snapshot::SnapshotError> {
        *self = match snapshot::take::<1>(input, "terrain estimator")?[0] {
            0 => TerrainEstimatorKind::Cnn,
            1 => TerrainEstimatorKind::Geometric,
            v => {
                return Err(snapshot::SnapshotError::Invalid {
                    what: "terrain estimator",
                    value: v as u64,
                })
            }
        };
        Ok(())
    }
}

snapshot::snapshot_fields!(PerceptionSummary {
    fresh,
    frame_timestamp_ns,
    points,
    bev,
    memory_keyframes,
    memory_points,
    roll,
    pitch,
    base_height,
    source,
    estimate,
    confidence,
    geometric,
    token,
    held,
    frames,
    step_tick,
    late,
});

snapshot::snapshot_fields!(PoseSample {
    time_ns,
    rot,
    pos,
    height,
    waist
});

// The pose history, the BEV memory's keyframes and the last summary (the token held when a
// frame is implausible, the step without a frame). Not the frame buffer: the HAL fills it before
// every step that reads it.
snapshot::snapshot_fields!(Perception {
    history,
    history_len,
    history_next,
    memory,
    last
});

#[cfg(test)]
mod tests {
    use super::*;

    /// Identity mount, no self filter, geometric estimator: robot-frame point = sensor point + base
    /// height.
    fn perception() -> Perception {
        let spec = PerceptionSpec {
            mount_xyz: [0.0; 3],
            mount_rpy: [0.0; 3],
            self_filter: Vec::new(),
            terrain_estimator: TerrainEstimatorKind::Geometric,
            bev_memory_keyframes: 4,
            ..PerceptionSpec::default()
        };
        Perception::new(&spec, std::path::Path::new("."))
    }

    fn estimate(x: f32, valid: bool) -> Estimate {
        Estimate {
            valid,
            position: [x, 0.0, 0.8],
            foot_pos: [[x, 0.1, 0.0], [x, -0.1, 0.0]],
            contact: [true, true],
            ..Estimate::default()
        }
    }

    /// One step at `t` s with a frame holding a 20 cm tread patch at robot-frame x ∈ [x0, x0+0.2].
    fn step(p: &mut Perception, t: f64, x: f32, valid: bool, x0: f32) -> PerceptionSummary {
        let now = (t * 1e9) as u64;
        let est = estimate(x, valid);
        p.record_pose(now, &est);
        let f = p.frame_mut();
        f.timestamp_ns = now;
        f.len = 0;
        for i in 0..10 {
            for j in 0..10 {
                f.points[f.len] = hal::LidarPoint {
                    xyz: [x0 + 0.02 * i as f32, -0.1 + 0.02 * j as f32, 0.1 - 0.8],
                    ..Default::default()
                };
                f.len += 1;
            }
        }
        p.step(now, true, &est)
    }

    fn occupied_between(g: &BevGrid, lo: f32, hi: f32) -> usize {
        (0..sensor_io::bev::BEV_CELLS)
            .flat_map(|ix| (0..sensor_io::bev::BEV_CELLS).map(move |iy| (ix, iy)))
            .filter(|&(ix, iy)| {
                let x = BevGrid::cell_center(ix, iy).0;
                g.occupied(ix, iy) && x > lo && x < hi
            })
            .count()
    }

    #[test]
    fn the_memory_keeps_a_tread_in_view_after_the_robot_walks_onto_it_and_forgets_without_odometry() {
        let mut p = perception();
        let s = step(&mut p, 0.1, 0.0, true, 1.0);
        assert_eq!((s.memory_keyframes, s.memory_points), (0, 0));
        // 0.6 m further on, the frame shows only a patch 1.2 m ahead; the tread is now 0.4–0.6 m
        // ahead, in the lidar's blind disc, and comes from the memory.
        let s = step(&mut p, 0.2, 0.6, true, 1.2);
        assert_eq!(s.memory_keyframes, 1);
        assert_eq!(s.memory_points, 100);
        assert_eq!(s.bev.used, 100, "the current frame's own points");
        assert!(occupied_between(p.grid(), 0.38, 0.62) >= 16);
        // The estimate is lost: the memory cannot be placed and is dropped.
        let s = step(&mut p, 0.3, 0.6, false, 1.2);
        assert_eq!((s.memory_keyframes, s.memory_points), (0, 0));
        assert_eq!(occupied_between(p.grid(), 0.38, 0.62), 0);
    }

    #[test]
    fn no_memory_keyframes_gives_single_frame_grids() {
        let spec = PerceptionSpec {
            bev_memory_keyframes: 0,
            terrain_estimator: TerrainEstimatorKind::Geometric,
            ..PerceptionSpec::default()
        };
        let mut p = Perception::new(&spec, std::path::Path::new("."));
        step(&mut p, 0.1, 0.0, true, 1.0);
        let s = step(&mut p, 0.2, 0.6, true, 1.2);
        assert_eq!((s.memory_keyframes, s.memory_points), (0, 0));
    }
}
