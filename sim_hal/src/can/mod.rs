//! The motor side of the CAN bench (docs/can.md): the emulator logic ([`MotorEmulator`]), served by
//! the `g1-can-emu` binary over the MuJoCo bridge. The firmware's side and the buses are the real
//! robot's transports: `robot_io::can`, re-exported here for the emulator's callers.
mod emulator;
mod serve;

pub use emulator::{EmuCounters, EmuEvent, MotorEmulator};
pub use robot_io::can::{mem_buses, BusError, CanBuses, CanFrame, MemBuses, SocketCanBuses, FOREIGN_ID};
pub use serve::{serve, EmuReport, ServeError, ServeOptions};
