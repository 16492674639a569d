//! The G1 control firmware as a library: `g1fw` is a thin CLI over it, and tests drive it directly.
//!
//! - [`spec`]: the deploy spec (one TOML per policy), validated at load.
//! - [`obs`]: observation builder (terms, scales, clips, history layouts).
//! - [`nn`]: fixed-buffer network executor (Linear, ELU/ReLU/Tanh, stateful LSTM) over safetensors.
//! - [`policy_io`]: state → observation and action → PD targets, shared by the controller and the trainer.
//! - [`controller`]: start-up ramp, policy at its rate, PD targets, latched damping.
//! - [`supervisor`]: safety checks on every frame; the reasons for latched damping.
//! - [`runtime`]: the tick with its rate groups in a fixed order, and the loop over any HAL.
//! - [`operator`]: velocity commands, e-stop and reset (constant or from a schedule file).
//! - [`log`]: MCAP logging through a fixed pool and a writer thread; reading logs back.
//! - [`replay`]: `g1fw replay`, recorded inputs through the same runtime, outputs compared bit for bit.
//! - [`rt`]: real-time process set-up (SCHED_FIFO, CPU pinning, mlockall).
//! - [`robot`]: the G1's joint ranges.
//! - [`alloc_probe`]: a counting global allocator that tests install to prove the tick allocates nothing.
//! - [`sim_run`]: `g1fw sim`, the loop against the MuJoCo simulator over the lock-stepped bridge.
pub mod alloc_probe;
#[cfg(feature = "lab")]
pub mod bev_render;
pub mod controller;
pub mod envelope;
#[cfg(feature = "lab")]
pub mod eval;
pub mod lidar_source;
pub mod log;
pub mod log_tools;
pub mod nn;
pub mod obs;
pub mod operator;
pub mod perception;
pub mod perception_worker;
#[cfg(feature = "lab")]
pub mod plot;
pub mod policy_io;
#[cfg(feature = "lab")]
pub mod profile_plot;
pub mod replay;
pub mod robot;
pub mod robot_run;
pub mod rt;
pub mod run_report;
pub mod runtime;
#[cfg(feature = "lab")]
pub mod sim_run;
pub mod spec;
pub mod supervisor;
pub mod terrain_net;
/// Input text on its way to a terminal (escaped control characters, long lines cut).
pub use input_file::text;

/// Every input file is read through these: regular files only (a FIFO, device or directory is
/// refused without blocking), size-capped before allocating (the `input_file` crate).
pub use input_file::{read_capped, read_text_capped};

/// The text of a panic payload (`panic!` with a literal or a formatted message): what the control
/// loop's guard and the perception worker report.
pub fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "a panic with a non-text payload".into())
}
