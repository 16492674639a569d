//! Shared helpers of the lab tools (`g1-sim`, `g1-dataset`, `g1-train`): [`rng`], the seeded
//! random numbers of worlds, datasets and training, and [`progress`], the terminal's progress bars.
//! The robot's firmware never links this crate.
// Lab code, never on the robot: std's math is fine here (see clippy.toml); the worlds and datasets
// it seeds were made with it, so it stays.
#![allow(clippy::disallowed_methods)]
pub mod progress;
pub mod rng;
