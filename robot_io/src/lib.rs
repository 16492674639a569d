//! Transports of the real G1, as opposed to `sim_hal`'s simulated ones: the robot's DDS topics
//! `rt/lowstate` / `rt/lowcmd` ([`dds`]), the MID-360's point packets over UDP ([`udp_lidar`]), and
//! motors on CAN for a bench ([`can`], SocketCAN).
pub mod can;
pub mod dds;
pub mod udp_lidar;

pub use dds::{DdsError, DdsHal, DdsHalConfig, DdsHalCounters};
pub use udp_lidar::{UdpLidar, UdpLidarConfig, UdpLidarCounters, UdpLidarError};
