//! Hardware abstraction for the Unitree G1 low level.
//!
//! Plain `Copy` data types mirroring what the robot's motor drivers, IMU and lidar deliver, and three
//! small traits in the spirit of `embedded-hal`: [`LowLevel`] (motor commands and states, IMU),
//! [`Lidar`] (point frames into a fixed-capacity buffer) and [`TimeBase`] (the control tick). Every
//! trait carries its own associated error type whose [`Error::kind`] lets generic code decide between
//! "retry", "fault" and "stop" without knowing the transport. `no_std`, no heap, no I/O.
#![no_std]

mod lidar;
mod rng;
mod terrain;
mod truth;
mod types;

pub use lidar::{LidarPoint, PointFrame};
pub use rng::XorShift64;
pub use terrain::{wrap_angle, TerrainClass, TerrainToken};
pub use truth::{GroundTruth, StairProgress};
pub use types::*;

/// Number of motor slots in the unitree_hg messages (29 used on the 29-dof G1).
pub const NUM_MOTORS: usize = 35;

/// Position of the G1's main IMU (in the pelvis) relative to the pelvis origin, m (Unitree's
/// hardware data; the 29-dof MJCF's `imu_in_pelvis` site sits at the same place).
pub const G1_PELVIS_IMU_POS: [f64; 3] = [0.04525, 0.0, -0.08339];

/// What went wrong, independent of the transport (socket, CAN, DDS).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ErrorKind {
    /// The peer went away (socket closed, bus down, simulator exited).
    Disconnected,
    /// Nothing arrived within the allowed time.
    Timeout,
    /// A frame arrived but could not be decoded (short, wrong type).
    Malformed,
    /// A frame arrived with a checksum that does not match its contents.
    Checksum,
    /// A frame arrived intact but carries NaN or infinite values (a sensor fault).
    NonFinite,
    /// Anything else (I/O error, misconfiguration).
    Other,
}

/// Error trait every HAL error type implements.
pub trait Error: core::fmt::Debug + core::fmt::Display {
    fn kind(&self) -> ErrorKind;
}

/// The control tick. In simulation this is simulation time advanced by the lock-stepped bridge; on
/// hardware it is a monotonic clock. Control decisions read time only from here.
pub trait TimeBase {
    type Error: Error;
    /// Blocks until the next control tick is due and returns its time.
    fn wait_tick(&mut self) -> Result<TickTime, Self::Error>;
    /// Control period in nanoseconds.
    fn period_ns(&self) -> u64;
}

/// Motors and the pelvis IMU, as carried by unitree_hg `LowCmd_` / `LowState_`.
pub trait LowLevel {
    type Error: Error;
    /// Copies the newest low-level state into `out`. Returns `Ok(false)` when nothing new arrived
    /// since the last call (the caller decides when staleness becomes a fault).
    fn read_state(&mut self, out: &mut LowState) -> Result<bool, Self::Error>;
    /// Sends one command for all 35 motor slots.
    fn write_command(&mut self, cmd: &LowCommand) -> Result<(), Self::Error>;
}

/// Points a lidar frame holds on the firmware side (the MID-360 sends ~20,000 per 10 Hz frame): the
/// `CAP` of every [`Lidar`] the firmware reads.
pub const LIDAR_FRAME_CAP: usize = 32_768;

/// A lidar delivering whole frames into a caller-owned fixed-capacity buffer.
pub trait Lidar<const CAP: usize> {
    type Error: Error;
    /// Fills `out` with the newest complete frame. `Ok(false)`: no new frame since the last call.
    fn read_frame(&mut self, out: &mut PointFrame<CAP>) -> Result<bool, Self::Error>;

    /// Takes in what has arrived without handing a frame over. A loop that reads frames less often
    /// than packets arrive calls it every tick, for transports whose buffers overflow when left
    /// alone (a UDP socket); the default does nothing.
    fn receive(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

/// Time of a control tick.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord)]
pub struct TickTime {
    /// Tick counter since start (0 = first tick).
    pub index: u64,
    /// Nanoseconds since start on the HAL's time base.
    pub time_ns: u64,
}

impl TickTime {
    pub fn seconds(&self) -> f64 {
        self.time_ns as f64 * 1e-9
    }
}

/// What a HAL offers besides the traits, for logging and evaluation: the frame as it arrived, an
/// observer's ground truth, the newest lidar frame.
pub trait FrameSource {
    /// Wire bytes of the LowState frame that arrived on the newest tick (valid or not), if any.
    fn received_frame(&self) -> Option<&[u8]>;
    /// Simulator ground truth of the newest tick (evaluation only, never control).
    fn truth(&self) -> Option<&GroundTruth> {
        None
    }
    /// Puts the newest complete lidar frame into `out`; false when there is none new (or no lidar).
    /// Asked only on perception ticks (the runtime's `load_lidar`); a frame it delivers is what that
    /// tick's perception step consumes, and what the log records as `/lidar/frame` for replay.
    fn read_lidar(&mut self, _out: &mut PointFrame<LIDAR_FRAME_CAP>) -> bool {
        false
    }
}
