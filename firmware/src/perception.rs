//! The perception group (10 Hz): the newest lidar frame → gravity-aligned robot frame (estimator
//! attitude and height, spec mount) → the paper's 6×60×60 BEV grid → terrain token.
//!
//! Today the token comes from the geometric estimator (`estimator::terrain`); it is checked for
//! plausibility and otherwise replaced by the last plausible one (or flat). Everything is
//! allocated in [`Perception::new`]; a step does not allocate.
use estimator::terrain::{plausible, GeometricTerrainConfig, GeometricTerrainEstimator, TerrainEstimate};
use hal::{PointFrame, TerrainToken};
use sensor_io::bev::{BevBuilder, BevGrid, BevStats, MountPose, RobotFrame, SelfFilter};
use sim_hal::bridge::LIDAR_FRAME_CAP;

use crate::runtime::Estimate;
use crate::spec::PerceptionSpec;

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
    pub bev: BevStats,
    /// Inputs of the robot frame.
    pub roll: f32,
    pub pitch: f32,
    pub base_height: f32,
    /// The geometric estimate of this frame.
    pub geometric: TerrainEstimate,
    /// The token the robot acts on (plausible, or held from before).
    pub token: TerrainToken,
    /// The geometric estimate was implausible and the token was held.
    pub held: bool,
    /// Frames seen so far.
    pub frames: u64,
}

pub struct Perception {
    mount: MountPose,
    filter: SelfFilter,
    fallback_height: f32,
    builder: Box<BevBuilder>,
    grid: Box<BevGrid>,
    frame: Box<LidarFrame>,
    robot_frame: RobotFrame,
    geometric: GeometricTerrainEstimator,
    last: PerceptionSummary,
}

/// A zeroed frame built on the heap (~800 KB).
pub fn boxed_lidar_frame() -> Box<LidarFrame> {
    let b = Box::<LidarFrame>::new_zeroed();
    // SAFETY: PointFrame holds only integers and f32s (and arrays of them), for which all-zero
    // bytes are valid values.
    unsafe { b.assume_init() }
}

impl Perception {
    /// Spec validation has already refused a bad self-filter; should one get here anyway, the
    /// default G1 filter is used.
    pub fn new(spec: &PerceptionSpec) -> Self {
        let mount = spec.mount();
        Self {
            mount,
            filter: spec.self_filter().unwrap_or(SelfFilter::G1_DEFAULT),
            fallback_height: spec.fallback_base_height_m,
            builder: BevBuilder::new_boxed(),
            grid: Box::new(BevGrid::zeroed()),
            frame: boxed_lidar_frame(),
            robot_frame: RobotFrame::new(&mount, 0.0, 0.0, spec.fallback_base_height_m),
            geometric: GeometricTerrainEstimator::new(GeometricTerrainConfig::default()),
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

    pub fn frame(&self) -> &LidarFrame {
        &self.frame
    }

    pub fn grid(&self) -> &BevGrid {
        &self.grid
    }

    pub fn robot_frame(&self) -> &RobotFrame {
        &self.robot_frame
    }

    pub fn last(&self) -> &PerceptionSummary {
        &self.last
    }

    /// One perception step. `fresh`: the HAL put a new frame into [`Perception::frame_mut`].
    pub fn step(&mut self, fresh: bool, est: &Estimate) -> PerceptionSummary {
        if !fresh {
            self.last.fresh = false;
            return self.last;
        }
        let (roll, pitch, height) = robot_frame_inputs(est, self.fallback_height);
        self.robot_frame = RobotFrame::new(&self.mount, roll, pitch, height);
        let bev = self
            .builder
            .build(self.frame.as_slice(), &self.robot_frame, &self.filter, &mut self.grid);
        let geometric = self.geometric.estimate(&self.grid);
        let ok = plausible(&geometric.token);
        self.last = PerceptionSummary {
            fresh: true,
            frame_timestamp_ns: self.frame.timestamp_ns,
            points: self.frame.len as u32,
            bev,
            roll,
            pitch,
            base_height: height,
            geometric,
            token: if ok { geometric.token } else { self.last.token },
            held: !ok,
            frames: self.last.frames + 1,
        };
        self.last
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
    (roll, pitch, if h.is_finite() && h > 0.2 && h < 1.5 { h } else { fallback_height })
}
