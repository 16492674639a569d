//! Transports of the real G1, as opposed to `sim_hal`'s simulated ones: the robot's DDS topics
//! `rt/lowstate` / `rt/lowcmd` ([`dds`]) and the MID-360's point packets over UDP ([`udp_lidar`]).
pub mod dds;
pub mod udp_lidar;

pub use dds::{DdsError, DdsHal, DdsHalConfig, DdsHalCounters};
pub use udp_lidar::{UdpLidar, UdpLidarConfig, UdpLidarCounters, UdpLidarError};
