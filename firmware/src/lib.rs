//! The G1 control firmware as a library: `g1fw` is a thin CLI over it, and tests drive it directly.
//!
//! - [`spec`]: the deploy spec (one TOML per policy), validated at load.
//! - [`obs`]: observation builder (terms, scales, clips, history layouts).
//! - [`nn`]: fixed-buffer network executor (Linear, ELU/ReLU/Tanh, stateful LSTM) over safetensors.
//! - [`controller`]: start-up ramp, policy at its rate, PD targets, latched damping.
//! - [`sim_run`]: `g1fw sim`, the loop against the MuJoCo simulator over the lock-stepped bridge.
pub mod controller;
pub mod nn;
pub mod obs;
pub mod sim_run;
pub mod spec;
pub mod plot;
