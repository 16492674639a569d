//! The firmware's side of the bridge: a HAL whose time base is the simulator's lock-stepped tick.
//!
//! Per tick, [`TimeBase::wait_tick`] receives whatever the simulator sent for that tick and fails
//! only when the link itself is broken (closed socket, lost sync, wrong message kind). What the
//! tick brought is reported once by [`LowLevel::read_state`]:
//!
//! | this tick                                       | `read_state`               | `out`           |
//! |-------------------------------------------------|----------------------------|-----------------|
//! | a frame that decodes                            | `Ok(true)`                 | that frame      |
//! | no frame (`FLAG_NO_FRAME`), or already read     | `Ok(false)`                | last good state |
//! | a frame that fails to decode (CRC, length, NaN) | `Err(BridgeError::Decode)` | last good state |
//!
//! A bad frame is a sensor-side fault the controller decides about (like a stale one), not a dead
//! link, so it no longer ends `wait_tick`. Decoding is exactly
//! [`sensor_io::unitree_hg::decode_low_state`] on the received bytes, so a replay that re-decodes
//! the logged [`BridgeHal::state_frame`] reproduces every result; it decodes into a scratch state so
//! a half-written bad frame never leaks out. "Last good state" before any good frame is
//! `LowState::default()`.
use std::io::{BufReader, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::os::unix::net::UnixStream;
use std::path::Path;
use std::time::{Duration, Instant};

use hal::{ErrorKind, LowCommand, LowLevel, LowState, PointFrame, TickTime, TimeBase};
use sensor_io::livox::{AssemblerStats, FrameAssembler};
use sensor_io::unitree_hg::{decode_low_state, encode_low_cmd, DecodeError, LOW_CMD_LEN, LOW_STATE_LEN};

use super::protocol::{
    datagrams, decode_truth, read_expect, read_expect_flags, write_msg, Kind, ProtocolError, Truth, Welcome,
    FLAG_NO_FRAME, PROTOCOL_VERSION,
};
use super::spin::SpinStream;

#[derive(Debug, thiserror::Error)]
pub enum BridgeError {
    #[error("bridge: {0}")]
    Protocol(ProtocolError),
    #[error("bridge: bad LowState frame from the simulator: {0}")]
    Decode(DecodeError),
    #[error("bridge: could not connect to the simulator at {target} within {waited:?}: {last}")]
    Connect {
        target: String,
        waited: Duration,
        last: String,
    },
    #[error("bridge: {0} is not a loopback address; the bridge only talks to this machine")]
    NotLoopback(SocketAddr),
    #[error("bridge: simulator speaks protocol {got}, this firmware speaks {PROTOCOL_VERSION}")]
    Version { got: u32 },
    #[error(
        "bridge: the simulator at {target} accepted the connection but sent no Welcome within \
         {waited:?}; g1-sim serves one client at a time: is another g1fw connected to it?"
    )]
    NoWelcome { target: String, waited: Duration },
}

// Display carries the inner error's text; no `source` link, so `{:#}` chains print it once.
impl From<DecodeError> for BridgeError {
    fn from(e: DecodeError) -> Self {
        BridgeError::Decode(e)
    }
}

// Display carries the inner error's text; no `source` link, so `{:#}` chains print it once.
impl From<ProtocolError> for BridgeError {
    fn from(e: ProtocolError) -> Self {
        BridgeError::Protocol(e)
    }
}

impl hal::Error for BridgeError {
    fn kind(&self) -> ErrorKind {
        match self {
            BridgeError::Protocol(ProtocolError::Closed) => ErrorKind::Disconnected,
            BridgeError::Protocol(ProtocolError::Io(_)) => ErrorKind::Disconnected,
            BridgeError::Protocol(_) => ErrorKind::Malformed,
            // The same classification as every other unitree_hg decoder (replay included).
            BridgeError::Decode(e) => hal::Error::kind(e),
            BridgeError::Connect { .. } | BridgeError::NoWelcome { .. } => ErrorKind::Timeout,
            BridgeError::NotLoopback(_) | BridgeError::Version { .. } => ErrorKind::Other,
        }
    }
}

enum Stream {
    Unix(SpinStream<UnixStream>),
    Tcp(SpinStream<TcpStream>),
}

/// How long the firmware spins waiting for the simulator's answer before blocking: about one
/// control tick of physics on this class of machine.
pub const CLIENT_SPIN: Duration = Duration::from_micros(300);

impl Stream {
    fn set_read_timeout(&self, t: Option<Duration>) -> std::io::Result<()> {
        match self {
            Stream::Unix(s) => s.get_ref().set_read_timeout(t),
            Stream::Tcp(s) => s.get_ref().set_read_timeout(t),
        }
    }
}

/// How long a connected simulator may take to answer the Hello (it sends Welcome at once, unless
/// it is busy with another client).
pub const WELCOME_TIMEOUT: Duration = Duration::from_secs(10);

impl Read for Stream {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        match self {
            Stream::Unix(s) => s.read(buf),
            Stream::Tcp(s) => s.read(buf),
        }
    }
}

impl Write for Stream {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        match self {
            Stream::Unix(s) => s.write(buf),
            Stream::Tcp(s) => s.write(buf),
        }
    }
    fn flush(&mut self) -> std::io::Result<()> {
        match self {
            Stream::Unix(s) => s.flush(),
            Stream::Tcp(s) => s.flush(),
        }
    }
}

pub use hal::LIDAR_FRAME_CAP;

/// What the client asks the simulator for besides the robot's state.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Wants {
    /// Privileged ground truth every tick (evaluation only).
    pub truth: bool,
    /// The simulated MID-360's Livox datagrams every tick.
    pub lidar: bool,
}

impl From<bool> for Wants {
    /// `true`: truth, no lidar (what callers before the lidar asked for).
    fn from(truth: bool) -> Self {
        Wants { truth, lidar: false }
    }
}

/// The lidar side of the bridge: datagrams → Livox decoder → frames.
struct LidarIn {
    /// Its last completed frame stays put until the next completes: that is the frame handed over.
    assembler: FrameAssembler<LIDAR_FRAME_CAP>,
    /// A frame completed since the last hand-over.
    fresh: bool,
    /// Bridge payloads whose datagram framing was inconsistent (rest of the payload dropped).
    framing_errors: u64,
    payload: Vec<u8>,
}

/// Lidar counters, for logs and reports.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LidarCounters {
    pub decoder: AssemblerStats,
    pub framing_errors: u64,
}

/// Lock-stepped simulator HAL. `wait_tick` receives the state the simulator produced for the
/// command of the previous tick (the first call returns the initial state).
pub struct BridgeHal {
    /// Buffered so one `recv` usually brings a whole LowState + Truth pair.
    stream: BufReader<Stream>,
    welcome: Welcome,
    want_truth: bool,
    lidar: Option<Box<LidarIn>>,
    /// Last frame that decoded.
    state: LowState,
    /// Decode target, copied to `state` only on success.
    decoded: LowState,
    /// Newest received frame, exactly as received (any length); swapped with `payload`, not copied.
    frame: Vec<u8>,
    /// `frame` padded with zeros / cut to the unitree_hg length, for fixed-size logs.
    state_bytes: [u8; LOW_STATE_LEN],
    /// A frame (good or bad) arrived on the newest tick.
    frame_received: bool,
    /// This tick's `read_state` result, until it is read: `Some(Ok)` fresh, `Some(Err)` bad frame.
    pending: Option<Result<(), DecodeError>>,
    truth: Truth,
    cmd_bytes: [u8; LOW_CMD_LEN],
    /// A command was written since the last tick (so the simulator is stepping).
    command_sent: bool,
    /// Ticks on which the firmware wrote no command and the previous one was repeated.
    repeated_commands: u64,
    have_initial: bool,
    tick: TickTime,
    payload: Vec<u8>,
    scratch: Vec<u8>,
}

impl BridgeHal {
    /// Connects over a Unix-domain socket, retrying until `timeout` (the simulator may still be
    /// starting). `alive` is polled between retries so a simulator that died is reported at once.
    pub fn connect_unix(
        path: &Path,
        want: impl Into<Wants>,
        timeout: Duration,
        mut alive: impl FnMut() -> Result<(), String>,
    ) -> Result<Self, BridgeError> {
        let start = Instant::now();
        loop {
            match UnixStream::connect(path) {
                Ok(s) => {
                    let s = SpinStream::new(s, CLIENT_SPIN).map_err(ProtocolError::from)?;
                    return Self::handshake(Stream::Unix(s), want.into(), &path.display().to_string());
                }
                Err(e) => {
                    let last = match alive() {
                        Ok(()) => e.to_string(),
                        Err(why) => why,
                    };
                    if start.elapsed() >= timeout || last != e.to_string() {
                        return Err(BridgeError::Connect {
                            target: path.display().to_string(),
                            waited: start.elapsed(),
                            last,
                        });
                    }
                    std::thread::sleep(Duration::from_millis(5));
                }
            }
        }
    }

    /// Connects over loopback TCP (any other address is refused).
    pub fn connect_tcp(addr: SocketAddr, want: impl Into<Wants>) -> Result<Self, BridgeError> {
        if !addr.ip().is_loopback() {
            return Err(BridgeError::NotLoopback(addr));
        }
        let s = TcpStream::connect(addr).map_err(|e| BridgeError::Connect {
            target: addr.to_string(),
            waited: Duration::ZERO,
            last: e.to_string(),
        })?;
        s.set_nodelay(true).map_err(ProtocolError::from)?;
        let s = SpinStream::new(s, CLIENT_SPIN).map_err(ProtocolError::from)?;
        Self::handshake(Stream::Tcp(s), want.into(), &addr.to_string())
    }

    fn handshake(stream: Stream, want: Wants, target: &str) -> Result<Self, BridgeError> {
        let want_truth = want.truth;
        let mut stream = BufReader::with_capacity(16 * 1024, stream);
        let mut scratch = Vec::with_capacity(4096);
        let mut payload = Vec::with_capacity(4096);
        let mut hello = [0u8; 8];
        hello[..4].copy_from_slice(&PROTOCOL_VERSION.to_le_bytes());
        hello[4] = want_truth as u8;
        hello[5] = want.lidar as u8;
        write_msg(stream.get_mut(), Kind::Hello, &hello, &mut scratch)?;
        stream
            .get_ref()
            .set_read_timeout(Some(WELCOME_TIMEOUT))
            .map_err(ProtocolError::from)?;
        match read_expect(&mut stream, &mut payload, Kind::Welcome) {
            Err(ProtocolError::Io(e))
                if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) =>
            {
                return Err(BridgeError::NoWelcome {
                    target: target.to_string(),
                    waited: WELCOME_TIMEOUT,
                })
            }
            r => r?,
        }
        stream.get_ref().set_read_timeout(None).map_err(ProtocolError::from)?;
        let welcome = Welcome::decode(&payload)?;
        if welcome.protocol_version != PROTOCOL_VERSION {
            return Err(BridgeError::Version {
                got: welcome.protocol_version,
            });
        }
        let mut hal = Self {
            stream,
            welcome,
            want_truth,
            lidar: want.lidar.then(|| {
                Box::new(LidarIn {
                    assembler: FrameAssembler::new_boxed(),
                    fresh: false,
                    framing_errors: 0,
                    payload: Vec::with_capacity(64 * 1024),
                })
            }),
            state: LowState::default(),
            decoded: LowState::default(),
            frame: Vec::with_capacity(LOW_STATE_LEN),
            state_bytes: [0; LOW_STATE_LEN],
            frame_received: false,
            pending: None,
            truth: Truth::default(),
            cmd_bytes: [0; LOW_CMD_LEN],
            command_sent: false,
            repeated_commands: 0,
            have_initial: true,
            tick: TickTime::default(),
            payload,
            scratch,
        };
        hal.receive_state()?;
        Ok(hal)
    }

    /// Receives one tick's `LowState` (and `Truth`). Fails only on transport / protocol errors; a
    /// frame that does not decode is kept in `pending` for `read_state`.
    fn receive_state(&mut self) -> Result<(), BridgeError> {
        let flags = read_expect_flags(&mut self.stream, &mut self.payload, Kind::LowState)?;
        match flags {
            0 => {
                // Keep the raw bytes (for logs) even when they fail to decode. Swapping keeps both
                // buffers' capacity, so no allocation per tick.
                std::mem::swap(&mut self.frame, &mut self.payload);
                let n = self.frame.len().min(LOW_STATE_LEN);
                self.state_bytes[..n].copy_from_slice(&self.frame[..n]);
                self.state_bytes[n..].fill(0);
                self.frame_received = true;
                let decoded = decode_low_state(&self.frame, &mut self.decoded);
                if decoded.is_ok() {
                    self.state = self.decoded;
                }
                self.pending = Some(decoded);
            }
            FLAG_NO_FRAME if self.payload.is_empty() => {
                self.frame_received = false;
                self.pending = None;
            }
            FLAG_NO_FRAME => {
                return Err(ProtocolError::BadLength {
                    kind: Kind::LowState,
                    expected: 0,
                    got: self.payload.len(),
                }
                .into())
            }
            flags => {
                return Err(ProtocolError::BadFlags {
                    kind: Kind::LowState,
                    flags,
                }
                .into())
            }
        }
        if let Some(l) = self.lidar.as_deref_mut() {
            read_expect(&mut self.stream, &mut l.payload, Kind::LidarPackets)?;
            for d in datagrams(&l.payload) {
                let Ok(d) = d else {
                    l.framing_errors += 1;
                    break;
                };
                // Malformed packets are counted by the assembler and skipped.
                if let Ok(Some(_)) = l.assembler.push(d) {
                    l.fresh = true;
                }
            }
        }
        if self.want_truth {
            read_expect(&mut self.stream, &mut self.payload, Kind::Truth)?;
            self.truth = decode_truth(&self.payload)?;
        }
        Ok(())
    }

    /// The last tick's Livox datagrams as the simulator sent them (length-prefixed, see
    /// [`datagrams`]); empty without lidar. What a UDP transport would have carried this tick.
    pub fn lidar_datagrams(&self) -> &[u8] {
        self.lidar.as_deref().map_or(&[], |l| &l.payload)
    }

    /// Decoder and framing counters of the lidar stream (None without lidar).
    pub fn lidar_counters(&self) -> Option<LidarCounters> {
        self.lidar.as_ref().map(|l| LidarCounters {
            decoder: *l.assembler.stats(),
            framing_errors: l.framing_errors,
        })
    }

    pub fn welcome(&self) -> &Welcome {
        &self.welcome
    }

    /// Privileged ground truth of the newest tick. Evaluation only: never feed it to control.
    pub fn truth(&self) -> &Truth {
        &self.truth
    }

    /// Raw bytes of the newest received LowState frame, good or bad (for logging); unchanged on a
    /// tick without a frame. A frame of the wrong length is cut or zero-padded to fit, so only
    /// [`Self::state_frame`] reproduces a length error on replay; all other results re-decode
    /// identically from these bytes.
    pub fn state_bytes(&self) -> &[u8; LOW_STATE_LEN] {
        &self.state_bytes
    }

    /// The newest received LowState frame exactly as it arrived (any length; empty before the first).
    pub fn state_frame(&self) -> &[u8] {
        &self.frame
    }

    /// A LowState frame (good or bad) arrived on the newest tick; `false` when the simulator sent
    /// `FLAG_NO_FRAME` (the frame was dropped).
    pub fn frame_received(&self) -> bool {
        self.frame_received
    }

    /// Raw bytes of the newest LowCmd frame sent.
    pub fn command_bytes(&self) -> &[u8; LOW_CMD_LEN] {
        &self.cmd_bytes
    }

    pub fn repeated_commands(&self) -> u64 {
        self.repeated_commands
    }

    /// Tells the simulator to stop; errors are ignored (it may already be gone).
    pub fn close(mut self) {
        let _ = write_msg(self.stream.get_mut(), Kind::Bye, &[], &mut self.scratch);
    }
}

impl TimeBase for BridgeHal {
    type Error = BridgeError;

    fn wait_tick(&mut self) -> Result<TickTime, BridgeError> {
        if self.have_initial {
            self.have_initial = false;
            return Ok(self.tick);
        }
        if !self.command_sent {
            // Lock-step needs a command per tick: repeat the last one, as a motor driver would keep
            // its last setpoint, and count it so the omission is visible.
            self.repeated_commands += 1;
            write_msg(self.stream.get_mut(), Kind::LowCmd, &self.cmd_bytes, &mut self.scratch)?;
        }
        self.command_sent = false;
        self.receive_state()?;
        self.tick.index += 1;
        self.tick.time_ns = self.tick.index * self.welcome.control_dt_ns;
        Ok(self.tick)
    }

    fn period_ns(&self) -> u64 {
        self.welcome.control_dt_ns
    }
}

impl LowLevel for BridgeHal {
    type Error = BridgeError;

    /// See the module doc: `Ok(true)` fresh frame, `Ok(false)` none (dropped or already read),
    /// `Err(Decode)` bad frame; `out` is the newest frame that decoded in every case.
    fn read_state(&mut self, out: &mut LowState) -> Result<bool, BridgeError> {
        *out = self.state;
        match self.pending.take() {
            Some(Ok(())) => Ok(true),
            Some(Err(e)) => Err(BridgeError::Decode(e)),
            None => Ok(false),
        }
    }

    fn write_command(&mut self, cmd: &LowCommand) -> Result<(), BridgeError> {
        encode_low_cmd(cmd, &mut self.cmd_bytes);
        write_msg(self.stream.get_mut(), Kind::LowCmd, &self.cmd_bytes, &mut self.scratch)?;
        self.command_sent = true;
        Ok(())
    }
}

impl hal::Lidar<LIDAR_FRAME_CAP> for BridgeHal {
    type Error = BridgeError;

    /// The newest frame the simulated MID-360 completed; `Ok(false)` when none is new (or the
    /// bridge was opened without lidar).
    fn read_frame(&mut self, out: &mut PointFrame<LIDAR_FRAME_CAP>) -> Result<bool, BridgeError> {
        match self.lidar.as_deref_mut() {
            Some(l) if l.fresh => {
                out.copy_from(l.assembler.last_frame());
                l.fresh = false;
                Ok(true)
            }
            _ => Ok(false),
        }
    }
}

impl hal::FrameSource for BridgeHal {
    fn received_frame(&self) -> Option<&[u8]> {
        self.frame_received().then(|| self.state_frame())
    }
    fn truth(&self) -> Option<&hal::GroundTruth> {
        Some(BridgeHal::truth(self))
    }
    fn read_lidar(&mut self, out: &mut PointFrame<LIDAR_FRAME_CAP>) -> bool {
        hal::Lidar::read_frame(self, out).unwrap_or(false)
    }
}
