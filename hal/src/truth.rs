//! What an outside observer knows of the robot: ground truth for logs, evaluations and reports.
//! The control path never reads it.
use crate::TerrainToken;

/// Privileged ground truth of one tick, from a simulator or a motion-capture rig: an observer's
/// payload for logs, evaluations and reports, never on the control path.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GroundTruth {
    pub sim_time_s: f64,
    /// Base (pelvis) position in the world, m.
    pub base_pos: [f64; 3],
    /// Base orientation, w x y z.
    pub base_quat: [f64; 4],
    /// Base linear velocity, world frame, m/s.
    pub base_lin_vel_world: [f64; 3],
    /// Base linear velocity, body frame, m/s.
    pub base_lin_vel_body: [f64; 3],
    /// Base angular velocity, body frame, rad/s.
    pub base_ang_vel_body: [f64; 3],
    /// Left and right foot touching anything other than the robot.
    pub foot_contact: [bool; 2],
    /// Ground-truth terrain token at the base's pose, when the simulator runs a terrain world.
    pub terrain: Option<TerrainToken>,
    /// Height of the walking surface under the base (x, y), m (0 on flat ground and without a
    /// world).
    pub ground_height_m: f64,
    /// Where the base is on the world's staircase (`None` without one).
    pub stairs: Option<StairProgress>,
}

/// The base's progress over a staircase (ground truth, evaluation only). Axis coordinates as in
/// the simulator's worlds: `s` along the staircase axis from the first riser, `t` to its left.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StairProgress {
    /// Base position along the staircase axis, from the first riser, m.
    pub axis_s: f64,
    /// Base position across the axis (left positive), m.
    pub axis_t: f64,
    /// The staircase axis (direction of +s, from its first riser to its last), rad from world +x
    /// (a fixed property of the world: where an operator would point the robot).
    pub axis_yaw_rad: f32,
    /// End landing level minus start landing level, m (> 0: the stairs go up along +s).
    pub rise_m: f32,
    /// Risers in the staircase.
    pub risers: u16,
    /// Risers whose edge lies behind the base (`riser.s < axis_s`) while the base is within the
    /// stair width (`|axis_t| ≤ width/2`); 0 beside the staircase.
    pub risers_passed: u16,
    /// The base is on the end landing: `axis_s ≥ last riser + margin` (the bridge's
    /// `END_LANDING_MARGIN_M`), at most
    /// the landing's far end, and within the stair width.
    pub on_end_landing: bool,
}

impl GroundTruth {
    /// Angle between the base's z axis and the world's vertical, degrees.
    pub fn tilt_deg(&self) -> f64 {
        let [_, x, y, _] = self.base_quat;
        // Body z axis in world: its z component is 1 - 2(x² + y²).
        libm::acos((1.0 - 2.0 * (x * x + y * y)).clamp(-1.0, 1.0)).to_degrees()
    }

    /// The evaluations' fall: base below 0.5 m or tilted more than 60°.
    pub fn fallen(&self) -> bool {
        self.base_pos[2] < 0.5 || self.tilt_deg() > 60.0
    }
}
