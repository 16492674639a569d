//! The G1 control firmware as a library: `g1fw` is a thin CLI over it, and tests drive it directly.
//! The control core (spec, observations, network, controller, supervisor, envelope, perception, the
//! tick) is the `control` crate and the run's record (`log`, `replay`) the `runlog` crate, both
//! re-exported here under the same module names; this crate adds:
//!
//! - [`robot_run`]: `g1fw run`, the loop on the real G1 (DDS) or a CAN bench, damping at every end.
//! - [`sim_run`]: `g1fw sim`, the loop against the MuJoCo simulator over the lock-stepped bridge.
// The control core (what runs every tick) is its own crate; its modules keep their paths here.
pub use control::{
    actor, alloc_probe, controller, envelope, lidar_source, mirror, nn, obs, operator, perception, perception_worker,
    policy_io, robot, rt, runtime, spec, supervisor, terrain_net,
};
// So is the run's record (MCAP logs, their reader, bit-exact replay).
pub use runlog::{log, replay};
#[cfg(feature = "lab")]
pub mod bev_render;
#[cfg(feature = "lab")]
pub mod eval;
pub mod log_tools;
#[cfg(feature = "lab")]
pub mod plot;
#[cfg(feature = "lab")]
pub mod profile_plot;
pub mod robot_run;
pub mod run_report;
#[cfg(feature = "lab")]
pub mod sim_run;
pub mod terminal_keys;
/// Input text on its way to a terminal (escaped control characters, long lines cut).
pub use input_file::text;

/// Every input file is read through these: regular files only (a FIFO, device or directory is
/// refused without blocking), size-capped before allocating (the `input_file` crate).
pub use input_file::{read_capped, read_text_capped};

pub use control::panic_message;
