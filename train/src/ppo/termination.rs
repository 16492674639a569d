//! When an episode ends early: the supervisor's own walls (tilt, a joint past its motor's limit,
//! base angular speed per axis), from the spec's `[safety]` through `MotionLimits`, and a base too
//! low (the field's termination; the robot has no such guard); optionally a robot stalled on a
//! staircase (`EnvConfig::end_stalled`).
use control::supervisor::MotionLimits;

use super::reward::MIN_BASE_HEIGHT;

/// Why an episode ended early, in the order [`EpisodeEnd::cause`] indexes.
pub const FALL_CAUSES: [&str; 5] = ["tilt", "joint_speed", "base_height", "base_angular_speed", "stalled"];

/// [`FALL_CAUSES`] index of a robot that stopped making progress on a staircase.
pub const STALLED: usize = 4;

/// The first cause that ends the episode, as an index into [`FALL_CAUSES`]: `up_z` is gravity's
/// projection on the body's up axis, `base_height` the base above the ground under it.
pub fn cause(
    limits: &MotionLimits,
    up_z: f32,
    joint_too_fast: bool,
    base_height: f64,
    ang_vel: [f32; 3],
) -> Option<usize> {
    [
        limits.tilted(up_z),
        joint_too_fast,
        base_height < MIN_BASE_HEIGHT,
        limits.base_spinning(ang_vel),
    ]
    .iter()
    .position(|&c| c)
}
