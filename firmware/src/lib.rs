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
pub mod bev_render;
pub mod controller;
pub mod envelope;
pub mod eval;
pub mod lidar_source;
pub mod log;
pub mod log_tools;
pub mod nn;
pub mod obs;
pub mod operator;
pub mod perception;
pub mod perception_worker;
pub mod plot;
pub mod policy_io;
pub mod profile_plot;
pub mod replay;
pub mod robot;
pub mod robot_run;
pub mod rt;
pub mod runtime;
pub mod sim_run;
pub mod spec;
pub mod supervisor;
pub mod terrain_net;

/// Reads a whole file of at most `max` bytes, refusing a larger one before allocating for it (also
/// a pipe or device that never ends, which `metadata` cannot size): the error says how large.
pub fn read_capped(path: &std::path::Path, max: u64) -> std::io::Result<Vec<u8>> {
    use std::io::Read;
    let too_large = |n: u64| {
        std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!("{n} bytes or more is over the {max}-byte limit for this file"),
        )
    };
    let file = std::fs::File::open(path)?;
    let len = file.metadata()?.len();
    if len > max {
        return Err(too_large(len));
    }
    let mut bytes = Vec::with_capacity(len as usize);
    file.take(max + 1).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > max {
        return Err(too_large(bytes.len() as u64));
    }
    Ok(bytes)
}
