//! `g1-train` and `g1-dataset`: learning for "Explicit Stair Geometry Conditioning".
//!
//! - [`cnn`]: the terrain CNN — datasets rendered from `g1_sim` worlds, trained with candle on the
//!   CPU, exported (BatchNorm folded) as a safetensors file plus a `control::nn::NetworkDesc`, which
//!   the firmware's executor runs in its 10 Hz perception group, and evaluated on held-out worlds
//!   against the geometric baseline.
//! - [`ppo`]: the stair policy, PPO on in-process MuJoCo environments.
//! - [`plot`]: the learning curves of both.
//! - [`tensor_file`]: the one writer of the safetensors files the trainer exports.
//!
//! Nothing here re-implements the robot side: grids come from `sensor_io::bev` (through the
//! dataset renderer), outputs are decoded by `estimator::terrain_cnn`, and evaluation runs the
//! exported network in `control::nn`, the code the robot runs.
// The trainer never runs on the robot: std's math is fine here (see clippy.toml).
#![allow(clippy::disallowed_methods)]
pub mod cnn;
pub mod plot;
pub mod ppo;
pub mod tensor_file;

pub use tensor_file::read_safetensors;

/// The most a JSON, TOML or text file the trainer reads may hold (`input_file` refuses more, and
/// anything that is not a regular file, before reading).
pub const MAX_TEXT_BYTES: u64 = 256 << 20;
/// The most a dataset shard may hold.
pub const MAX_DATA_BYTES: u64 = 2 << 30;
