//! The firmware's side: a HAL over the bus layout's motors and IMU.
//!
//! The IMU's sample is the tick (docs/can.md): `wait_tick` returns when an accelerometer frame closes
//! a sample, after draining what else is already queued (the replies sent before it). Everything
//! that tick brought is judged once by `read_state`:
//!
//! | this tick                                            | `read_state`                  |
//! |------------------------------------------------------|-------------------------------|
//! | all good                                             | `Ok(true)`, the new state     |
//! | a malformed frame or a frame with a foreign id        | `Err(CanError::Malformed)`    |
//! | a motor silent for `motor_timeout_ticks` ticks        | `Ok(true)`, that slot's `motor_state` has [`MOTOR_STATE_NO_REPLY`] |
//!
//! `wait_tick` fails only when no sample arrives within `tick_timeout_ms` (the bus or the IMU is
//! gone) or the transport fails. No allocation after [`CanHal::open`].
use std::time::{Duration, Instant};

use hal::{ErrorKind, ImuState, LowCommand, LowLevel, LowState, TickTime, TimeBase, MOTOR_MODE_ENABLED, NUM_MOTORS};
use sensor_io::can::{
    decode_reply, encode_command, encode_special, is_imu_id, BusLayout, CanDecodeError, ImuAssembler, MitCommand,
    Special, REPLY_BASE,
};
use sensor_io::unitree_hg::{encode_low_state, LOW_STATE_LEN};

use super::{BusError, CanBuses, CanFrame};

pub use hal::MOTOR_STATE_NO_REPLY;

/// How often start-up repeats *enter motor mode* to motors that have not answered yet (a motor
/// still booting, or an emulator not yet listening, loses the first one).
const ENTER_RETRY: Duration = Duration::from_millis(100);

#[derive(Debug, thiserror::Error)]
pub enum CanError {
    #[error(transparent)]
    Bus(#[from] BusError),
    #[error("CAN: no IMU sample for {waited_ms} ms (tick {tick}); {hint}")]
    Timeout {
        tick: u64,
        waited_ms: u64,
        hint: &'static str,
    },
    // The cause is in the message, not a `source` link: `{:#}` chains print it once.
    #[error("CAN: malformed frame on bus {bus}: {cause}")]
    Malformed { bus: usize, cause: CanDecodeError },
    #[error("CAN: unexpected frame id {id:#05x} (DLC {len}) on bus {bus}: no configured node sends it")]
    Foreign { bus: usize, id: u16, len: u8 },
    #[error("CAN: stopped by a signal while waiting for the motors and the IMU")]
    Stopped,
}

impl hal::Error for CanError {
    fn kind(&self) -> ErrorKind {
        match self {
            CanError::Bus(e) => e.kind(),
            CanError::Timeout { .. } => ErrorKind::Timeout,
            CanError::Malformed { .. } | CanError::Foreign { .. } => ErrorKind::Malformed,
            CanError::Stopped => ErrorKind::Other,
        }
    }
}

/// What crossed the bus (for reports and logs; never for control).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct CanCounters {
    pub frames_rx: u64,
    pub frames_tx: u64,
    /// Frames the transmit queue refused (congested bus).
    pub tx_dropped: u64,
    pub replies: u64,
    pub imu_samples: u64,
    /// IMU samples lost between two received ones (sequence gaps).
    pub imu_gaps: u64,
    pub malformed: u64,
    pub foreign: u64,
    /// (tick, motor) pairs without a reply.
    pub missing_replies: u64,
}

pub struct CanHal<B: CanBuses> {
    buses: B,
    layout: BusLayout,
    period_ns: u64,
    startup_timeout: Duration,
    state: LowState,
    imu: ImuAssembler,
    sample: ImuState,
    replied: [bool; NUM_MOTORS],
    silent_ticks: [u32; NUM_MOTORS],
    /// The first problem of the current tick, reported by `read_state`.
    fault: Option<CanError>,
    next_tick: u64,
    last_seq: Option<u16>,
    /// Sample counter (the unitree_hg `tick` field): sequence numbers unwrapped.
    sample_count: u32,
    fresh: bool,
    encoded: [u8; LOW_STATE_LEN],
    counters: CanCounters,
    stop: Option<std::sync::Arc<std::sync::atomic::AtomicBool>>,
}

impl<B: CanBuses> CanHal<B> {
    /// Puts every motor of `layout` into motor mode (repeated until it answers, within
    /// `startup_timeout`, by the first `wait_tick`). `period_ns` is the control period the IMU runs at.
    pub fn open(mut buses: B, layout: BusLayout, period_ns: u64, startup_timeout: Duration) -> Result<Self, CanError> {
        assert_eq!(buses.count(), layout.interfaces.len(), "one transport per interface");
        let state = LowState::default();
        let mut counters = CanCounters::default();
        for m in &layout.motors {
            buses.send(m.bus, &encode_special(m.id, Special::EnterMotorMode))?;
            counters.frames_tx += 1;
        }
        Ok(Self {
            buses,
            layout,
            period_ns,
            startup_timeout,
            state,
            imu: ImuAssembler::default(),
            sample: ImuState::default(),
            replied: [false; NUM_MOTORS],
            silent_ticks: [0; NUM_MOTORS],
            fault: None,
            next_tick: 0,
            last_seq: None,
            sample_count: 0,
            fresh: false,
            encoded: [0; LOW_STATE_LEN],
            counters,
            stop: None,
        })
    }

    /// Set by a signal: the start-up wait for the motors and the IMU ends at once.
    pub fn with_stop(mut self, stop: std::sync::Arc<std::sync::atomic::AtomicBool>) -> Self {
        self.stop = Some(stop);
        self
    }

    pub fn layout(&self) -> &BusLayout {
        &self.layout
    }
    pub fn counters(&self) -> CanCounters {
        self.counters
    }
    /// The newest state as unitree_hg `LowState_` bytes (what the log records and replay decodes).
    pub fn state_bytes(&self) -> &[u8; LOW_STATE_LEN] {
        &self.encoded
    }
    /// A state was read on this tick.
    pub fn fresh(&self) -> bool {
        self.fresh
    }
    pub fn into_buses(self) -> B {
        self.buses
    }

    fn note(&mut self, e: CanError) {
        match e {
            CanError::Foreign { .. } => self.counters.foreign += 1,
            _ => self.counters.malformed += 1,
        }
        if self.fault.is_none() {
            self.fault = Some(e);
        }
    }

    /// Classifies one received frame; true when it closed an IMU sample.
    fn handle(&mut self, bus: usize, f: &CanFrame) -> bool {
        self.counters.frames_rx += 1;
        if is_imu_id(f.id) && bus == self.layout.imu_bus {
            return match self.imu.push(f, &mut self.sample) {
                Ok(Some(seq)) => {
                    if let Some(prev) = self.last_seq {
                        let gap = seq.wrapping_sub(prev);
                        self.counters.imu_gaps += gap.saturating_sub(1) as u64;
                        self.sample_count = self.sample_count.wrapping_add(gap.max(1) as u32);
                    }
                    self.last_seq = Some(seq);
                    self.counters.imu_samples += 1;
                    self.state.imu.quaternion = self.sample.quaternion;
                    self.state.imu.gyroscope = self.sample.gyroscope;
                    self.state.imu.accelerometer = self.sample.accelerometer;
                    true
                }
                Ok(None) => false,
                Err(source) => {
                    self.note(CanError::Malformed { bus, cause: source });
                    false
                }
            };
        }
        let node = f.id.wrapping_sub(REPLY_BASE);
        if f.id > REPLY_BASE && node <= u8::MAX as u16 {
            if let Some(i) = self.layout.motor_index(bus, node as u8) {
                let m = &self.layout.motors[i];
                let (slot, id, ranges) = (m.slot, m.id, m.ranges);
                match decode_reply(f, id, &ranges) {
                    Ok(r) => {
                        let s = &mut self.state.motors[slot];
                        s.q = r.q;
                        s.dq = r.dq;
                        s.tau_est = r.tau;
                        s.mode = MOTOR_MODE_ENABLED;
                        self.replied[slot] = true;
                        self.counters.replies += 1;
                    }
                    Err(source) => self.note(CanError::Malformed { bus, cause: source }),
                }
                return false;
            }
        }
        self.note(CanError::Foreign {
            bus,
            id: f.id,
            len: f.len,
        });
        false
    }

    /// Repeats *enter motor mode* to motors that have not answered yet (start-up only).
    fn retry_enter(&mut self) -> Result<(), CanError> {
        for i in 0..self.layout.motors.len() {
            let m = &self.layout.motors[i];
            if !self.replied[m.slot] {
                let (bus, id) = (m.bus, m.id);
                self.send(bus, &encode_special(id, Special::EnterMotorMode))?;
            }
        }
        Ok(())
    }

    fn send(&mut self, bus: usize, f: &CanFrame) -> Result<(), CanError> {
        if self.buses.send(bus, f)? {
            self.counters.frames_tx += 1;
        } else {
            self.counters.tx_dropped += 1;
        }
        Ok(())
    }
}

impl<B: CanBuses> TimeBase for CanHal<B> {
    type Error = CanError;

    fn wait_tick(&mut self) -> Result<TickTime, CanError> {
        let first = self.next_tick == 0;
        let limit = if first {
            self.startup_timeout
        } else {
            Duration::from_millis(self.layout.tick_timeout_ms as u64)
        };
        let start = Instant::now();
        let mut retry_at = start + ENTER_RETRY;
        loop {
            let now = Instant::now();
            let left = limit.saturating_sub(now - start);
            if left.is_zero() {
                return Err(CanError::Timeout {
                    tick: self.next_tick,
                    waited_ms: limit.as_millis() as u64,
                    hint: if first {
                        "no IMU sample since start-up: are the motors and the IMU powered, on these interfaces, \
                         with the ids of the bus layout (or is g1-can-emu running)?"
                    } else {
                        "the IMU stopped: check the bus wiring and power"
                    },
                });
            }
            if first
                && self
                    .stop
                    .as_ref()
                    .is_some_and(|s| s.load(std::sync::atomic::Ordering::Relaxed))
            {
                return Err(CanError::Stopped);
            }
            let wait = if first {
                left.min(retry_at.saturating_duration_since(now))
                    .min(Duration::from_millis(50))
            } else {
                left
            };
            match self.buses.recv(wait)? {
                Some((bus, f)) if self.handle(bus, &f) => break,
                Some(_) => {}
                None if first && Instant::now() >= retry_at => {
                    self.retry_enter()?;
                    retry_at = Instant::now() + ENTER_RETRY;
                }
                None => {}
            }
        }
        // What is already queued was sent before the sample closed (or belongs to it).
        while let Some((bus, f)) = self.buses.recv(Duration::ZERO)? {
            self.handle(bus, &f);
        }
        let index = self.next_tick;
        self.next_tick += 1;
        self.fresh = false;
        Ok(TickTime {
            index,
            time_ns: index * self.period_ns,
        })
    }

    fn period_ns(&self) -> u64 {
        self.period_ns
    }
}

impl<B: CanBuses> LowLevel for CanHal<B> {
    type Error = CanError;

    fn read_state(&mut self, out: &mut LowState) -> Result<bool, CanError> {
        if self.fresh {
            *out = self.state;
            return Ok(false);
        }
        for m in &self.layout.motors {
            let s = m.slot;
            if self.replied[s] {
                self.silent_ticks[s] = 0;
            } else {
                self.silent_ticks[s] = self.silent_ticks[s].saturating_add(1);
                self.counters.missing_replies += 1;
            }
            self.replied[s] = false;
            let st = &mut self.state.motors[s].motor_state;
            if self.silent_ticks[s] >= self.layout.motor_timeout_ticks {
                *st |= MOTOR_STATE_NO_REPLY;
            } else {
                *st &= !MOTOR_STATE_NO_REPLY;
            }
        }
        self.state.tick = self.sample_count;
        self.fresh = true;
        encode_low_state(&self.state, &mut self.encoded);
        *out = self.state;
        match self.fault.take() {
            Some(e) => Err(e),
            None => Ok(true),
        }
    }

    fn write_command(&mut self, cmd: &LowCommand) -> Result<(), CanError> {
        for i in 0..self.layout.motors.len() {
            let m = &self.layout.motors[i];
            let c = &cmd.motors[m.slot];
            // A disabled slot gets a limp command: no gains, no torque.
            let mit = if c.mode == MOTOR_MODE_ENABLED {
                MitCommand {
                    q: c.q,
                    dq: c.dq,
                    kp: c.kp,
                    kd: c.kd,
                    tau: c.tau,
                }
            } else {
                MitCommand::default()
            };
            let (bus, frame) = (m.bus, encode_command(m.id, &mit, &m.ranges));
            self.send(bus, &frame)?;
        }
        Ok(())
    }
}

impl<B: CanBuses> hal::FrameSource for CanHal<B> {
    /// The assembled state as unitree_hg bytes: the log records them and replay decodes them with
    /// the same codec as a bridge run's.
    fn received_frame(&self) -> Option<&[u8]> {
        self.fresh().then(|| &self.state_bytes()[..])
    }
}
