//! What runs on the robot, every tick: the deploy spec, observations, the network executor, the
//! controller, the safety supervisor, the command envelope, perception with the terrain CNN, and the
//! tick itself. No logging, no transports, no lab tools: `firmware` (`g1fw`) puts this on a robot,
//! a simulator or a log, and the trainer builds its observations with it.
//!
//! - [`spec`]: the deploy spec (one TOML per policy), validated at load.
//! - [`obs`]: observation builder (terms, scales, clips, history layouts).
//! - [`nn`]: fixed-buffer network executor (Linear, ELU/ReLU/Tanh, stateful LSTM, Conv2d) over safetensors.
//! - [`policy_io`]: state → observation and action → PD targets, shared by the controller and the trainer.
//! - [`controller`]: start-up ramp, policy at its rate, PD targets, latched damping.
//! - [`supervisor`]: safety checks on every frame; the reasons for latched damping.
//! - [`envelope`]: the last check of every command before it reaches a motor.
//! - [`perception`], [`perception_worker`], [`terrain_net`]: lidar frame → BEV → terrain token, on the
//!   tick or on its own thread.
//! - [`runtime`]: the tick with its rate groups in a fixed order, and the loop over any HAL;
//!   [`lidar_source`] puts a lidar beside a HAL.
//! - [`operator`]: velocity commands, e-stop and reset (constant or from a schedule file).
//! - [`rt`]: real-time process set-up (SCHED_FIFO, CPU pinning, mlockall).
//! - [`robot`]: the G1's joint ranges.
//! - [`mirror`]: the left–right mirror of a spec's observation and action; [`actor`]: the policy
//!   network as the spec runs it (alone, or averaged with its mirror image).
//! - [`alloc_probe`]: a counting global allocator that tests install to prove the tick allocates nothing.
pub mod actor;
pub mod alloc_probe;
pub mod controller;
pub mod envelope;
pub mod keyboard;
pub mod lidar_source;
pub mod nn;
pub mod obs;
pub mod operator;
pub mod perception;
pub mod perception_worker;
pub mod policy_io;
pub mod remote;
pub mod robot;
pub mod rt;
pub mod runtime;
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
