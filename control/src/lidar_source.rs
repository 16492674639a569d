//! A robot HAL plus a separate lidar: on the robot the motors and IMU come over one transport (CAN,
//! DDS) and the MID-360 over its own (UDP). [`WithLidar`] presents both to `run_loop` as one HAL:
//! the tick, state and commands are the inner HAL's; perception ticks take the lidar's newest frame.
//!
//! The lidar takes in what has arrived on every tick ([`Lidar::receive`]), not only on perception
//! ticks: the MID-360 sends ~2080 packets a second, and a UDP socket left alone for a 100 ms
//! perception period overflows its default receive buffer (measured: 1634 of 3134 datagrams lost
//! when it was read at 10 Hz). The completed frame stays in the lidar's assembler until a
//! perception tick copies it out.
use hal::{Lidar, LowCommand, LowLevel, LowState, TickTime, TimeBase};

use crate::perception::LidarFrame;
use crate::runtime::FrameSource;

/// Frames handed to perception, and lidar failures (a lidar that fails leaves perception holding
/// its last token; the motors do not depend on it).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct LidarReadCounters {
    pub used: u64,
    pub errors: u64,
}

pub struct WithLidar<H, L> {
    pub hal: H,
    /// `None`: no lidar (perception, if the spec has it, never gets a frame).
    pub lidar: Option<L>,
    pub counters: LidarReadCounters,
}

impl<H, L: Lidar<{ hal::LIDAR_FRAME_CAP }>> WithLidar<H, L> {
    pub fn new(hal: H, lidar: Option<L>) -> Self {
        Self {
            hal,
            lidar,
            counters: LidarReadCounters::default(),
        }
    }

    /// Counts a failure (and says so) instead of ending the run.
    fn count<T: Default>(&mut self, r: Result<T, L::Error>) -> T {
        r.unwrap_or_else(|e| {
            self.counters.errors += 1;
            tracing::warn!(error = %e, "lidar read failed; perception holds its token");
            T::default()
        })
    }
}

impl<H: TimeBase, L: Lidar<{ hal::LIDAR_FRAME_CAP }>> TimeBase for WithLidar<H, L> {
    type Error = H::Error;
    fn wait_tick(&mut self) -> Result<TickTime, H::Error> {
        let t = self.hal.wait_tick()?;
        if let Some(r) = self.lidar.as_mut().map(|l| l.receive()) {
            self.count(r);
        }
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

impl<H: FrameSource, L: Lidar<{ hal::LIDAR_FRAME_CAP }>> FrameSource for WithLidar<H, L> {
    fn received_frame(&self) -> Option<&[u8]> {
        self.hal.received_frame()
    }
    fn truth(&self) -> Option<&hal::GroundTruth> {
        self.hal.truth()
    }
    fn read_lidar(&mut self, out: &mut LidarFrame) -> bool {
        let Some(r) = self.lidar.as_mut().map(|l| l.read_frame(out)) else {
            return false;
        };
        let fresh = self.count(r);
        self.counters.used += fresh as u64;
        fresh
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

    /// `receive` call k: a frame stamped k completes on odd k, fails every third call.
    #[derive(Default)]
    struct FakeLidar {
        calls: u64,
        completed: Option<u64>,
    }
    impl Lidar<{ hal::LIDAR_FRAME_CAP }> for FakeLidar {
        type Error = E;
        fn read_frame(&mut self, out: &mut LidarFrame) -> Result<bool, E> {
            let Some(t) = self.completed.take() else {
                return Ok(false);
            };
            out.clear(t);
            out.push(LidarPoint::default());
            Ok(true)
        }
        fn receive(&mut self) -> Result<(), E> {
            self.calls += 1;
            if self.calls.is_multiple_of(3) {
                return Err(E);
            }
            if self.calls % 2 == 1 {
                self.completed = Some(self.calls);
            }
            Ok(())
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
    fn every_tick_takes_in_lidar_data_and_perception_takes_the_newest_frame() {
        let mut h = WithLidar::new(Ticks(0), Some(FakeLidar::default()));
        let mut out = sensor_io::livox::boxed_point_frame();
        assert!(!h.read_lidar(&mut out), "nothing before a tick");
        // receive calls 1..6 on ticks 1..6: frame, none, error, none, frame, error.
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
        assert_eq!(h.counters, LidarReadCounters { used: 2, errors: 2 });
        assert_eq!(h.received_frame(), Some(&b"state"[..]));
        let mut none = WithLidar::<Ticks, FakeLidar>::new(Ticks(0), None);
        none.wait_tick().unwrap();
        assert!(!none.read_lidar(&mut out));
    }
}
