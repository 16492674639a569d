//! Motors on CAN (a CAN bench or the HIL VM; the G1 itself is reached over DDS, [`crate::dds`]): the
//! firmware-side HAL ([`CanHal`]) and the buses it talks over — SocketCAN ([`SocketCanBuses`]), or an
//! in-process bus ([`mem_buses`]) so the same code is tested on a host whose kernel has no CAN. The
//! motor side (the emulator behind `g1-can-emu`) is a simulation HAL: `sim_hal::can`.
mod hal_impl;
mod mem;
mod socket;

use std::time::Duration;

pub use hal_impl::{CanCounters, CanError, CanHal, MOTOR_STATE_NO_REPLY};
pub use mem::{mem_buses, MemBuses};
pub use sensor_io::can::CanFrame;
pub use socket::SocketCanBuses;

/// Identifier given to frames that are not classic data frames with a standard id (extended ids,
/// remote and error frames): no node of ours uses them, so they are foreign.
pub const FOREIGN_ID: u16 = 0xFFFF;

/// A transport failure on one bus.
#[derive(Debug, thiserror::Error)]
#[error("CAN bus {bus} ({name}): {io}")]
pub struct BusError {
    pub bus: usize,
    pub name: String,
    pub io: std::io::Error,
}

impl BusError {
    pub fn kind(&self) -> hal::ErrorKind {
        use std::io::ErrorKind as K;
        match self.io.kind() {
            K::NotConnected | K::BrokenPipe | K::ConnectionReset | K::NotFound | K::UnexpectedEof => {
                hal::ErrorKind::Disconnected
            }
            K::TimedOut => hal::ErrorKind::Timeout,
            _ if self.io.raw_os_error() == Some(NETDOWN) => hal::ErrorKind::Disconnected,
            _ => hal::ErrorKind::Other,
        }
    }
}

/// ENETDOWN on Linux: the interface went down under us.
const NETDOWN: i32 = 100;

/// One or more CAN buses, seen from one node.
pub trait CanBuses {
    fn count(&self) -> usize;
    /// Queues `frame` on `bus`. `Ok(false)`: the transmit queue is full and the frame was dropped
    /// (a congested bus, not a dead one; the caller counts it).
    fn send(&mut self, bus: usize, frame: &CanFrame) -> Result<bool, BusError>;
    /// The next frame received on any bus, waiting at most `timeout` (zero: do not wait).
    fn recv(&mut self, timeout: Duration) -> Result<Option<(usize, CanFrame)>, BusError>;
}
