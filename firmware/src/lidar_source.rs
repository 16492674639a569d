//! A robot HAL plus a separate lidar: on the robot the motors and IMU come over one transport (CAN,
//! DDS) and the MID-360 over its own (UDP). [`WithLidar`] presents both to `run_loop` as one HAL:
//! the tick, state and commands are the inner HAL's; perception ticks take the lidar's newest frame.
//!
//! The lidar is read on every tick, not only on perception ticks: the MID-360 sends ~2080 packets
//! a second, and a UDP socket left alone for a 100 ms perception period overflows its default
//! receive buffer (measured: 1634 of 3134 datagrams lost when it was read at 10 Hz). Each tick takes
//! what has arrived (a few datagrams); a completed frame waits in a staging buffer for the next
//! perception tick.
use hal::{Lidar, LowCommand, LowLevel, LowState, TickTime, TimeBase};

use crate::perception::LidarFrame;
use crate::runtime::FrameSource;

/// Lidar read failures, counted (a lidar that fails leaves perception holding its last token; the
/// motors do not depend on it).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct LidarReadCounters {
    /// Frames the lidar completed, and those a perception tick took (the rest were replaced by a
    /// newer frame before one came).
    pub frames: u64,
    pub used: u64,
    pub errors: u64,
}

pub struct WithLidar<H, L> {
    pub hal: H,
    /// `None`: no lidar (perception, if the spec has it, never gets a frame).
    pub lidar: Option<L>,
    pub counters: LidarReadCounters,
    staged: Box<LidarFrame>,
    staged_fresh: bool,
}

impl<H, L: Lidar<{ sim_hal::bridge::LIDAR_FRAME_CAP }>> WithLidar<H, L> {
    /// Allocates the staging frame (before the loop, as every buffer the tick uses).
    pub fn new(hal: H, lidar: Option<L>) -> Self {
        Self {
            hal,
            lidar,
            counters: LidarReadCounters::default(),
            staged: sensor_io::livox::boxed_point_frame(),
            staged_fresh: false,
        }
    }

    fn pull_lidar(&mut self) {
        let Some(lidar) = self.lidar.as_mut() else {
            return;
        };
        match lidar.read_frame(&mut self.staged) {
            Ok(true) => {
                self.counters.frames += 1;
                self.staged_fresh = true;
            }
            Ok(false) => {}
            Err(e) => {
                self.counters.errors += 1;
                tracing::warn!(error = %e, "lidar read failed; perception holds its token");
            }
        }
    }
}

impl<H: TimeBase, L: Lidar<{ sim_hal::bridge::LIDAR_FRAME_CAP }>> TimeBase for WithLidar<H, L> {
    type Error = H::Error;
    fn wait_tick(&mut self) -> Result<TickTime, H::Error> {
        let t = self.hal.wait_tick()?;
        self.pull_lidar();
        Ok(t)
    }
    fn period_ns(&self) -> u64 {
        self.hal.period_ns()
    }
}

impl<H: LowLevel, L> LowLevel for WithLidar<H, L> {
    type Error = H::Error;
    fn read_state(&mut self, out: &mut LowState) -> Result<bool, H::Error> {
        self.hal.read_state(out)
    }
    fn write_command(&mut self, cmd: &LowCommand) -> Result<(), H::Error> {
        self.hal.write_command(cmd)
    }
}

impl<H: FrameSource, L: Lidar<{ sim_hal::bridge::LIDAR_FRAME_CAP }>> FrameSource for WithLidar<H, L> {
    fn received_frame(&self) -> Option<&[u8]> {
        self.hal.received_frame()
    }
    fn truth(&self) -> Option<&sim_hal::bridge::Truth> {
        self.hal.truth()
    }
    fn read_lidar(&mut self, out: &mut LidarFrame) -> bool {
        if !std::mem::take(&mut self.staged_fresh) {
            return false;
        }
        out.copy_from(&self.staged);
        self.counters.used += 1;
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use hal::{ErrorKind, LidarPoint};

    #[derive(Debug)]
    struct E;
    impl core::fmt::Display for E {
        fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
            f.write_str("no frame")
        }
    }
    impl hal::Error for E {
        fn kind(&self) -> ErrorKind {
            ErrorKind::Other
        }
    }

    /// Frames on odd calls, an error every third call.
    struct FakeLidar(u32);
    impl Lidar<{ sim_hal::bridge::LIDAR_FRAME_CAP }> for FakeLidar {
        type Error = E;
        fn read_frame(&mut self, out: &mut LidarFrame) -> Result<bool, E> {
            self.0 += 1;
            if self.0.is_multiple_of(3) {
                return Err(E);
            }
            if self.0 % 2 == 1 {
                out.clear(u64::from(self.0));
                out.push(LidarPoint::default());
                return Ok(true);
            }
            Ok(false)
        }
    }

    struct Ticks(u64);
    impl TimeBase for Ticks {
        type Error = E;
        fn wait_tick(&mut self) -> Result<TickTime, E> {
            self.0 += 1;
            Ok(TickTime {
                index: self.0,
                time_ns: self.0 * 2_000_000,
            })
        }
        fn period_ns(&self) -> u64 {
            2_000_000
        }
    }
    impl FrameSource for Ticks {
        fn received_frame(&self) -> Option<&[u8]> {
            Some(b"state")
        }
    }

    #[test]
    fn every_tick_reads_the_lidar_and_perception_takes_the_newest_frame() {
        let mut h = WithLidar::new(Ticks(0), Some(FakeLidar(0)));
        let mut out = sensor_io::livox::boxed_point_frame();
        assert!(!h.read_lidar(&mut out), "nothing before a tick");
        // Lidar calls 1..6 on ticks 1..6: frame, none, error, none, frame, error.
        for _ in 0..3 {
            h.wait_tick().unwrap();
        }
        assert!(h.read_lidar(&mut out));
        assert_eq!(out.timestamp_ns, 1);
        assert!(!h.read_lidar(&mut out), "a frame is handed over once");
        for _ in 0..3 {
            h.wait_tick().unwrap();
        }
        assert!(h.read_lidar(&mut out));
        assert_eq!(out.timestamp_ns, 5);
        assert_eq!(
            h.counters,
            LidarReadCounters {
                frames: 2,
                used: 2,
                errors: 2
            }
        );
        assert_eq!(h.received_frame(), Some(&b"state"[..]));
        let mut none = WithLidar::<Ticks, FakeLidar>::new(Ticks(0), None);
        none.wait_tick().unwrap();
        assert!(!none.read_lidar(&mut out));
    }
}
