//! Transports of the real G1, as opposed to `sim_hal`'s simulated ones. Today: the MID-360's point
//! packets over UDP ([`udp_lidar`]). The robot's DDS topics (`rt/lowstate`, `rt/lowcmd`) are next.
pub mod udp_lidar;

pub use udp_lidar::{UdpLidar, UdpLidarConfig, UdpLidarCounters, UdpLidarError};
