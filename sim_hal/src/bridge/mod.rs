//! Lock-stepped simulator bridge: the firmware sends one unitree_hg `LowCmd_` per control tick, the
//! simulator advances exactly one control tick and answers with a `LowState_`, so simulation time
//! is the firmware's time base. Privileged ground truth travels on its own message kind and is only
//! ever read by evaluation code.
pub mod client;
pub mod launch;
pub mod protocol;
pub mod spin;

pub use client::{BridgeError, BridgeHal, LidarCounters, Wants, LIDAR_FRAME_CAP};
pub use launch::{find_sim_bin, LaunchError, SimLaunch, SimProcess};
pub use protocol::*;
pub use spin::{Blocking, SpinStream};
