//! The G1 control firmware as a library: `g1fw` is a thin CLI over it, and tests drive it directly.
//! The control core (spec, observations, network, controller, supervisor, envelope, perception, the
//! tick) is the `control` crate and the run's record (`log`, `replay`) the `runlog` crate; users
//! name them directly. This crate adds:
//!
//! - [`robot_run`]: `g1fw run`, the loop on the real G1 (DDS) or a CAN bench, damping at every end.
//! - [`sim_run`]: `g1fw sim`, the loop against the MuJoCo simulator over the lock-stepped bridge.
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
