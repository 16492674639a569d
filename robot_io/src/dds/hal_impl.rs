//! The firmware's HAL over DDS, in one of two pacings ([`Pace`]):
//! - **clock** (the default of `g1fw run`, as Unitree's deploy loops): after the first state, ticks
//!   start on a monotonic clock at absolute deadlines (`first + k · period`, so lateness does not
//!   accumulate) and take the newest `rt/lowstate`; a tick with no newer sample runs without a frame
//!   (counted `stale_ticks`; the supervisor's state timeout still trips). How late each tick woke
//!   is kept in a fixed histogram ([`PeriodJitter`]: p50, p99, max).
//! - **state** (lock-step with `g1-sim --dds`): each new sample starts a tick; when none comes
//!   within `tick_timeout` the tick runs anyway without a frame.
//!
//! Either way ticks are counted and time is `index × period`: control never reads the wall clock;
//! which sample each tick took is in the log, which replay follows.
use std::time::{Duration, Instant};

use hal::{LowCommand, LowLevel, LowState, TickTime, TimeBase};
use sensor_io::unitree_hg::cdr::{low_cmd_to_cdr, low_state_from_cdr, CdrError, LOW_CMD_CDR_LEN, LOW_STATE_CDR_LEN};
use sensor_io::unitree_hg::{decode_low_state, encode_low_cmd, Stamp, UnsealedStamper, LOW_CMD_LEN, LOW_STATE_LEN};

use super::{DdsError, DdsLink, Endpoint, LinkCounters, CONTROLLER, LOW_STATE_TOPIC, SAMPLE_CAP};

/// What starts a tick.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Pace {
    /// A monotonic clock at the control period, reading the newest state.
    #[default]
    Clock,
    /// Each new state (lock-step with a simulator that waits for the command).
    State,
}

impl std::str::FromStr for Pace {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "clock" => Ok(Pace::Clock),
            "state" => Ok(Pace::State),
            _ => Err(format!(
                "'{s}': the tick pace is clock (the robot's) or state (lock-step)"
            )),
        }
    }
}

/// How late clock-paced ticks woke after their deadline: 1 µs buckets up to 20 ms, the rest in the
/// last. Fixed size, allocated at open; nothing allocates per tick.
#[derive(Clone)]
pub struct PeriodJitter {
    buckets: Vec<u32>,
    max_ns: u64,
    n: u64,
}

/// Percentiles of [`PeriodJitter`], µs.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct JitterSummary {
    pub ticks: u64,
    pub p50_us: f64,
    pub p99_us: f64,
    pub max_us: f64,
}

impl PeriodJitter {
    const BUCKETS: usize = 20_001;

    pub fn new() -> Self {
        Self {
            buckets: vec![0; Self::BUCKETS],
            max_ns: 0,
            n: 0,
        }
    }

    pub fn record(&mut self, late: Duration) {
        let ns = late.as_nanos().min(u64::MAX as u128) as u64;
        let us = ((ns / 1000) as usize).min(Self::BUCKETS - 1);
        self.buckets[us] = self.buckets[us].saturating_add(1);
        self.max_ns = self.max_ns.max(ns);
        self.n += 1;
    }

    pub fn summary(&self) -> JitterSummary {
        let quantile = |q: f64| {
            let want = ((q * self.n as f64).ceil() as u64).max(1);
            let mut seen = 0u64;
            for (us, &c) in self.buckets.iter().enumerate() {
                seen += c as u64;
                if seen >= want {
                    return us as f64;
                }
            }
            (Self::BUCKETS - 1) as f64
        };
        if self.n == 0 {
            return JitterSummary::default();
        }
        JitterSummary {
            ticks: self.n,
            p50_us: quantile(0.5),
            p99_us: quantile(0.99),
            max_us: self.max_ns as f64 / 1000.0,
        }
    }
}

impl Default for PeriodJitter {
    fn default() -> Self {
        Self::new()
    }
}

#[derive(Clone, Debug)]
pub struct DdsHalConfig {
    pub endpoint: Endpoint,
    /// Nominal control period (the robot publishes `rt/lowstate` at 500 Hz).
    pub period_ns: u64,
    /// How long to listen for peers before the first tick (and for another `rt/lowcmd` writer).
    pub discovery: Duration,
    /// How long the first `rt/lowstate` may take.
    pub startup_timeout: Duration,
    /// Set by a signal: the wait for the first state ends at once (a stop always stops, a robot
    /// that never answers included).
    pub stop: Option<std::sync::Arc<std::sync::atomic::AtomicBool>>,
    /// A tick without a new sample runs after this long (`Pace::State`).
    pub tick_timeout: Duration,
    pub pace: Pace,
    /// unitree_mujoco's Python bridge only (`g1fw run --unitree-mujoco`): accept states whose CRC
    /// and tick were never filled in, stamped by arrival (`sensor_io::unitree_hg::UnsealedStamper`).
    pub unitree_mujoco: bool,
}

impl DdsHalConfig {
    pub fn new(endpoint: Endpoint, period_ns: u64) -> Self {
        Self {
            endpoint,
            period_ns,
            discovery: Duration::from_millis(1500),
            startup_timeout: Duration::from_secs(10),
            stop: None,
            // Ten periods: late enough that a loaded host's scheduling hiccup is not a missing
            // frame, early enough that damping follows a dead link within the state timeout.
            tick_timeout: Duration::from_nanos(period_ns * 10),
            pace: Pace::Clock,
            unitree_mujoco: false,
        }
    }
}

/// What the HAL saw, beside the link's own counters.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct DdsHalCounters {
    #[serde(flatten)]
    pub link: LinkCounters,
    /// Samples replaced by a newer one before a tick took them.
    pub skipped: u64,
    /// Ticks that ran without a new sample (`Pace::State`: after `tick_timeout`).
    pub silent_ticks: u64,
    /// Clock-paced ticks that found no sample newer than the last one.
    pub stale_ticks: u64,
    /// Samples rejected: wrong size or encoding, CRC, non-finite.
    pub rejected: u64,
    /// Decoded samples whose `tick` equals the previous sample's (a frozen state, or a sender that
    /// never fills it in, as unitree_mujoco's Python bridge).
    pub tick_unchanged: u64,
    /// Samples stamped with the next tick (`--unitree-mujoco`), repeats included.
    pub stamped: u64,
    /// Of those, samples whose contents repeated the last one's (the simulator published before
    /// its physics stepped, or a robot at rest in a noise-free simulator).
    pub repeated: u64,
    /// Longest run of such repeats in a row.
    pub longest_repeat: u64,
    /// Samples whose CRC field was 0 (never computed: unitree_mujoco's Python bridge), unstamped.
    pub crc_zero: u64,
}

pub struct DdsHal {
    link: DdsLink,
    cfg: DdsHalConfig,
    next_tick: u64,
    last_seq: u64,
    raw: Vec<u8>,
    raw_len: usize,
    /// This tick brought a sample (for the log), and `read_state` has not judged it yet.
    arrived: bool,
    unread: bool,
    other_writer_present: bool,
    c_state: [u8; LOW_STATE_LEN],
    state: LowState,
    cmd_c: [u8; LOW_CMD_LEN],
    cmd_cdr: [u8; LOW_CMD_CDR_LEN],
    counters: DdsHalCounters,
    decoded_any: bool,
    /// `tick` of the last sample as sent (before any stamping).
    sent_tick: u32,
    /// `--unitree-mujoco`'s stamping.
    stamper: UnsealedStamper,
    repeat_run: u64,
    /// Clock pacing: when the first tick started, and how late ticks woke.
    first_tick_at: Option<Instant>,
    jitter: PeriodJitter,
}

impl DdsHal {
    /// Joins the domain, listens `discovery` long, and refuses to start when another program
    /// already publishes `rt/lowcmd` (as unitree_rl_lab does).
    pub fn open(cfg: DdsHalConfig) -> Result<Self, DdsError> {
        let link = DdsLink::open(&cfg.endpoint, CONTROLLER, cfg.discovery, true)?;
        Ok(Self {
            link,
            cfg,
            next_tick: 0,
            last_seq: 0,
            raw: vec![0; SAMPLE_CAP],
            raw_len: 0,
            arrived: false,
            unread: false,
            other_writer_present: false,
            c_state: [0; LOW_STATE_LEN],
            state: LowState::default(),
            cmd_c: [0; LOW_CMD_LEN],
            cmd_cdr: [0; LOW_CMD_CDR_LEN],
            counters: DdsHalCounters::default(),
            decoded_any: false,
            sent_tick: 0,
            stamper: UnsealedStamper::default(),
            repeat_run: 0,
            first_tick_at: None,
            jitter: PeriodJitter::new(),
        })
    }

    pub fn endpoint(&self) -> &Endpoint {
        self.link.endpoint()
    }

    /// How late clock-paced ticks woke after their deadlines (empty under `Pace::State`).
    pub fn jitter(&self) -> JitterSummary {
        self.jitter.summary()
    }

    pub fn counters(&self) -> DdsHalCounters {
        DdsHalCounters {
            link: self.link.counters(),
            ..self.counters
        }
    }

    /// The sample this tick brought, exactly as it was on the wire (header included), if any.
    pub fn received_sample(&self) -> Option<&[u8]> {
        self.arrived.then(|| &self.raw[..self.raw_len.min(self.raw.len())])
    }

    fn judge(&mut self) -> Result<(), DdsError> {
        if self.raw_len > self.raw.len() {
            return Err(CdrError::Length {
                message: "LowState_",
                expected: LOW_STATE_CDR_LEN,
                got: self.raw_len,
            }
            .into());
        }
        low_state_from_cdr(&self.raw[..self.raw_len], &mut self.c_state)?;
        let sent_tick = u32::from_le_bytes([self.c_state[12], self.c_state[13], self.c_state[14], self.c_state[15]]);
        if sent_tick == self.sent_tick && self.decoded_any {
            self.counters.tick_unchanged += 1;
        }
        self.sent_tick = sent_tick;
        self.decoded_any = true;
        if self.cfg.unitree_mujoco {
            // Every sample judged goes through the stamper, as replay's logged samples do.
            match self.stamper.stamp(&mut self.c_state) {
                Stamp::Fresh => {
                    self.counters.stamped += 1;
                    self.repeat_run = 0;
                }
                Stamp::Repeat => {
                    self.counters.stamped += 1;
                    self.counters.repeated += 1;
                    self.repeat_run += 1;
                    self.counters.longest_repeat = self.counters.longest_repeat.max(self.repeat_run);
                }
                Stamp::Corrupt => {}
            }
        } else if self.c_state[LOW_STATE_LEN - 4..] == [0; 4] {
            self.counters.crc_zero += 1;
        }
        let mut s = LowState::default();
        decode_low_state(&self.c_state, &mut s)?;
        self.state = s;
        Ok(())
    }
}

impl TimeBase for DdsHal {
    type Error = DdsError;

    fn wait_tick(&mut self) -> Result<TickTime, DdsError> {
        let first = self.next_tick == 0;
        let index = self.next_tick;
        let newer = if first {
            // In slices, so that a signal ends the wait within 50 ms.
            let deadline = Instant::now() + self.cfg.startup_timeout;
            let got = loop {
                let left = deadline.saturating_duration_since(Instant::now());
                let got = self
                    .link
                    .wait_newer(self.last_seq, left.min(Duration::from_millis(50)), &mut self.raw)?;
                if got.is_some() || left.is_zero() {
                    break got;
                }
                if self
                    .cfg
                    .stop
                    .as_ref()
                    .is_some_and(|s| s.load(std::sync::atomic::Ordering::Relaxed))
                {
                    return Err(DdsError::Stopped { topic: LOW_STATE_TOPIC });
                }
            };
            self.first_tick_at = Some(Instant::now());
            if got.is_none() {
                return Err(DdsError::Timeout {
                    topic: LOW_STATE_TOPIC,
                    waited_ms: self.cfg.startup_timeout.as_millis() as u64,
                    endpoint: self.cfg.endpoint.clone(),
                    hint: "is the robot (or g1-sim --dds / unitree_mujoco) running on this interface and domain? \
                           On the robot the domain is 0 and the interface the one in 192.168.123.0/24",
                });
            }
            got
        } else {
            match self.cfg.pace {
                Pace::State => self
                    .link
                    .wait_newer(self.last_seq, self.cfg.tick_timeout, &mut self.raw)?,
                Pace::Clock => {
                    let start = self.first_tick_at.unwrap_or_else(Instant::now);
                    let deadline = start + Duration::from_nanos(index.saturating_mul(self.cfg.period_ns));
                    let now = Instant::now();
                    if let Some(wait) = deadline.checked_duration_since(now) {
                        std::thread::sleep(wait);
                    }
                    self.jitter.record(Instant::now().saturating_duration_since(deadline));
                    self.link.wait_newer(self.last_seq, Duration::ZERO, &mut self.raw)?
                }
            }
        };
        match newer {
            Some((seq, len)) => {
                if !first {
                    self.counters.skipped += seq - self.last_seq - 1;
                }
                self.last_seq = seq;
                self.raw_len = len;
                self.arrived = true;
                self.unread = true;
            }
            None => {
                self.arrived = false;
                self.unread = false;
                match self.cfg.pace {
                    Pace::State => self.counters.silent_ticks += 1,
                    Pace::Clock => self.counters.stale_ticks += 1,
                }
            }
        }
        self.next_tick += 1;
        Ok(TickTime {
            index,
            time_ns: index * self.cfg.period_ns,
        })
    }

    fn period_ns(&self) -> u64 {
        self.cfg.period_ns
    }
}

impl LowLevel for DdsHal {
    type Error = DdsError;

    fn read_state(&mut self, out: &mut LowState) -> Result<bool, DdsError> {
        *out = self.state;
        // A second commander appearing mid-run is a fault of its own, reported once per appearance.
        let present = self.link.other_writers_now() > 0;
        if present != self.other_writer_present {
            self.other_writer_present = present;
            if present {
                // This tick's sample is not judged: the link itself is in question.
                self.unread = false;
                return Err(DdsError::OtherWriter {
                    topic: CONTROLLER.write_topic,
                    endpoint: self.cfg.endpoint.clone(),
                    writer: self.link.other_writer().unwrap_or_default(),
                });
            }
        }
        if !std::mem::take(&mut self.unread) {
            return Ok(false);
        }
        match self.judge() {
            Ok(()) => {
                *out = self.state;
                Ok(true)
            }
            Err(e) => {
                self.counters.rejected += 1;
                Err(e)
            }
        }
    }

    fn write_command(&mut self, cmd: &LowCommand) -> Result<(), DdsError> {
        encode_low_cmd(cmd, &mut self.cmd_c);
        low_cmd_to_cdr(&self.cmd_c, &mut self.cmd_cdr);
        self.link.send(&self.cmd_cdr)
    }
}

impl hal::FrameSource for DdsHal {
    /// The `LowState_` sample as it was on the wire (CDR); the log's metadata says so
    /// (`frame_encoding = cdr`) and replay decodes it with the same codec.
    fn received_frame(&self) -> Option<&[u8]> {
        self.received_sample()
    }
}
