//! `g1-train`: the terrain CNN of "Explicit Stair Geometry Conditioning" — trained with candle on
//! the CPU from `g1-dataset` exports, exported (BatchNorm folded) as a safetensors file plus a
//! `firmware::nn::NetworkDesc`, which the firmware's executor runs in its 10 Hz perception group,
//! and evaluated on held-out worlds against the geometric baseline.
//!
//! Nothing here re-implements the robot side: grids come from `sensor_io::bev` (through the
//! dataset renderer), outputs are decoded by `estimator::terrain_cnn`, and evaluation runs the
//! exported network in `firmware::nn`, the code the robot runs.
// The trainer never runs on the robot: std's math is fine here (see clippy.toml).
#![allow(clippy::disallowed_methods)]
pub mod data;
pub mod dataset;
pub mod eval;
pub mod export;
pub mod fit;
pub mod model;
pub mod plot;
pub mod ppo;
