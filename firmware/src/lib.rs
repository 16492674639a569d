//! The G1 control firmware as a library: `g1fw` is a thin CLI over it, and tests drive it directly.
pub mod nn;
