//! Server side of the bridge protocol (`sim_hal::bridge::protocol`): one client, lock-stepped.
//!
//! `Hello` → `Welcome`, initial `LowState` (+ `Truth` if asked); then per `LowCmd` one control
//! tick → `LowState` (+ `Truth`); `Bye` or a clean disconnect ends the connection. Any protocol
//! violation is answered with an `Error` message naming it (best effort) before the connection ends;
//! [`ServeError::exit_code`] maps it to the process exit status (3 for a malformed `LowCmd`).
//!
//! [`ServeOptions::faults`] injects the faults of a [`FaultPlan`] on their ticks (see
//! [`crate::faults`]); a `disconnect` fault ends the connection with [`SessionEnd::FaultDisconnect`].
use std::io::{self, BufReader, Read, Write};
use std::net::{TcpListener, ToSocketAddrs};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::time::Duration;

use hal::{LowCommand, LowState};
use sensor_io::unitree_hg::{decode_low_cmd, encode_low_state, DecodeError, LOW_STATE_LEN};
pub use sim_hal::bridge::Blocking;
use sim_hal::bridge::{
    append_msg, append_msg_flags, read_msg, write_msg, Kind, ProtocolError, SpinStream, Welcome, FLAG_NO_FRAME,
    PROTOCOL_VERSION,
};

use crate::faults::{FaultInjector, FaultPlan, Wire};
use crate::Simulator;

/// Settings of the served connection.
#[derive(Clone, Debug)]
pub struct ServeOptions {
    /// How long a read spins on a non-blocking socket before blocking. Saves the wake-up latency
    /// of a blocking read when the client answers within a few µs; 0 disables spinning.
    pub spin: Duration,
    /// No progress messages on stderr.
    pub quiet: bool,
    /// Faults to inject (empty: none).
    pub faults: FaultPlan,
}

impl Default for ServeOptions {
    fn default() -> Self {
        Self {
            spin: Duration::from_micros(20),
            quiet: false,
            faults: FaultPlan::default(),
        }
    }
}

/// How a connection ended normally.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SessionEnd {
    /// The client said `Bye`.
    Bye,
    /// The client closed the connection.
    Disconnected,
    /// A `disconnect` fault closed the connection (`g1-sim` exits with status 4).
    FaultDisconnect,
}

/// Summary of a finished connection.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SessionSummary {
    pub end: SessionEnd,
    pub ticks: u64,
    pub sim_time_s: f64,
}

/// Why a connection failed.
#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    #[error("malformed LowCmd: {0}")]
    MalformedCmd(DecodeError),
    #[error("bad Hello: {0}")]
    BadHello(String),
    #[error("unexpected {got:?} message (expected {expected})")]
    Unexpected { got: Kind, expected: &'static str },
    #[error("protocol: {0}")]
    Protocol(ProtocolError),
    #[error("socket: {0}")]
    Io(io::Error),
    #[error("{0}")]
    Setup(String),
}

// Display carries the inner error's text; no `source` link, so `{:#}` chains print it once.
impl From<io::Error> for ServeError {
    fn from(e: io::Error) -> Self {
        ServeError::Io(e)
    }
}

// Display carries the inner error's text; no `source` link, so `{:#}` chains print it once.
impl From<ProtocolError> for ServeError {
    fn from(e: ProtocolError) -> Self {
        ServeError::Protocol(e)
    }
}

// Display carries the inner error's text; no `source` link, so `{:#}` chains print it once.
impl From<DecodeError> for ServeError {
    fn from(e: DecodeError) -> Self {
        ServeError::MalformedCmd(e)
    }
}

impl ServeError {
    /// Process exit status for this failure: 3 malformed `LowCmd`, 2 other protocol errors,
    /// 1 socket setup / I/O.
    pub fn exit_code(&self) -> u8 {
        match self {
            ServeError::MalformedCmd(_) => 3,
            ServeError::BadHello(_) | ServeError::Unexpected { .. } | ServeError::Protocol(_) => 2,
            ServeError::Io(_) | ServeError::Setup(_) => 1,
        }
    }
}

/// A stream that can switch between blocking and non-blocking mode.
/// Reads through a buffer (a frame usually arrives in one `recv`), writes straight through.
struct Buffered<T: Read + Write>(BufReader<T>);

impl<T: Read + Write> Read for Buffered<T> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        self.0.read(buf)
    }
}

impl<T: Read + Write> Write for Buffered<T> {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        self.0.get_mut().write(buf)
    }
    fn flush(&mut self) -> io::Result<()> {
        self.0.get_mut().flush()
    }
}

/// Buffers reused for every message of a connection.
struct Bufs {
    payload: Vec<u8>,
    scratch: Vec<u8>,
    state: LowState,
    state_bytes: [u8; LOW_STATE_LEN],
    cmd: LowCommand,
}

/// Sends LowState tick `k` (+ `Truth`), through the fault injector if there is one. Returns
/// `false` when a `disconnect` fault says to close instead (nothing was sent).
fn send_state<W: Write>(
    w: &mut W,
    sim: &mut Simulator,
    (truth, lidar): (bool, bool),
    b: &mut Bufs,
    faults: Option<&mut FaultInjector>,
    k: u64,
) -> Result<bool, ServeError> {
    sim.low_state(&mut b.state);
    let wire = match faults {
        None => {
            encode_low_state(&b.state, &mut b.state_bytes);
            Wire::Frame
        }
        Some(f) => f.apply(k, sim, &mut b.state, &mut b.state_bytes),
    };
    b.scratch.clear();
    match wire {
        Wire::Frame => append_msg(&mut b.scratch, Kind::LowState, &b.state_bytes),
        Wire::NoFrame => append_msg_flags(&mut b.scratch, Kind::LowState, FLAG_NO_FRAME, &[]),
        Wire::Disconnect => return Ok(false),
    }
    if lidar {
        append_msg(&mut b.scratch, Kind::LidarPackets, sim.lidar_datagrams());
    }
    if truth {
        append_msg(
            &mut b.scratch,
            Kind::Truth,
            &sim_hal::bridge::encode_truth(&sim.truth()),
        );
    }
    // One write for both messages: one wake-up of the client per tick.
    w.write_all(&b.scratch)?;
    Ok(true)
}

/// Serves one client on an accepted stream until `Bye`, disconnect or error. On error an
/// `Error` message with the reason is sent if the socket is still up.
pub fn serve_stream<S: Read + Write + Blocking>(
    stream: S,
    sim: &mut Simulator,
    opts: &ServeOptions,
) -> Result<SessionSummary, ServeError> {
    let mut s = Buffered(BufReader::with_capacity(16 * 1024, SpinStream::new(stream, opts.spin)?));
    let mut b = Bufs {
        payload: Vec::with_capacity(4096),
        scratch: Vec::with_capacity(32 * 1024),
        state: LowState::default(),
        state_bytes: [0; LOW_STATE_LEN],
        cmd: LowCommand::default(),
    };
    let r = lockstep(&mut s, sim, &mut b, &opts.faults);
    if let Err(e) = &r {
        // The peer may be gone already (that is often why we failed); ignore send errors.
        if !matches!(
            e,
            ServeError::Protocol(ProtocolError::Closed | ProtocolError::Remote(_))
        ) {
            let _ = write_msg(&mut s, Kind::Error, e.to_string().as_bytes(), &mut b.scratch);
        }
    }
    r
}

fn lockstep<S: Read + Write>(
    s: &mut S,
    sim: &mut Simulator,
    b: &mut Bufs,
    plan: &FaultPlan,
) -> Result<SessionSummary, ServeError> {
    let mut faults = FaultInjector::new(plan, sim.config().control_dt, sim.motor_slots_present())
        .map_err(|e| ServeError::Setup(e.to_string()))?;
    // Hello: version u32 LE, want_truth u8, 3 zero bytes.
    let (want_truth, want_lidar) = match read_msg(s, &mut b.payload)? {
        Kind::Hello => {
            let p = &b.payload;
            if p.len() != 8 {
                return Err(ServeError::BadHello(format!(
                    "payload is {} bytes, expected 8",
                    p.len()
                )));
            }
            let v = u32::from_le_bytes([p[0], p[1], p[2], p[3]]);
            if v != PROTOCOL_VERSION {
                return Err(ServeError::BadHello(format!(
                    "client speaks protocol version {v}, this simulator speaks {PROTOCOL_VERSION}"
                )));
            }
            if p[5] != 0 && !sim.has_lidar() {
                return Err(ServeError::BadHello(
                    "the client wants lidar packets but this simulator has no lidar (start g1-sim with --lidar)".into(),
                ));
            }
            (p[4] != 0, p[5] != 0)
        }
        got => return Err(ServeError::Unexpected { got, expected: "Hello" }),
    };
    let cfg = sim.config();
    let welcome = Welcome {
        protocol_version: PROTOCOL_VERSION,
        motor_slots_present: sim.motor_slots_present(),
        mode_machine: sim.mode_machine(),
        physics_dt_ns: (cfg.physics_dt * 1e9).round() as u64,
        control_dt_ns: (cfg.physics_dt * 1e9).round() as u64 * sim.substeps() as u64,
    };
    write_msg(s, Kind::Welcome, &welcome.encode(), &mut b.scratch)?;
    let fault_disconnect = |ticks, sim: &Simulator| SessionSummary {
        end: SessionEnd::FaultDisconnect,
        ticks,
        sim_time_s: sim.time(),
    };
    if !send_state(s, sim, (want_truth, want_lidar), b, faults.as_mut(), 0)? {
        return Ok(fault_disconnect(0, sim));
    }

    let mut ticks = 0u64;
    loop {
        let kind = match read_msg(s, &mut b.payload) {
            Ok(k) => k,
            Err(ProtocolError::Closed) => {
                return Ok(SessionSummary {
                    end: SessionEnd::Disconnected,
                    ticks,
                    sim_time_s: sim.time(),
                })
            }
            Err(e) => return Err(e.into()),
        };
        match kind {
            Kind::LowCmd => {
                decode_low_cmd(&b.payload, &mut b.cmd)?;
                sim.apply_command(&b.cmd).expect("decoder rejects non-finite fields");
                sim.step_control_tick();
                ticks += 1;
                match send_state(s, sim, (want_truth, want_lidar), b, faults.as_mut(), ticks) {
                    Ok(true) => {}
                    Ok(false) => return Ok(fault_disconnect(ticks, sim)),
                    // A client that sent its last command and left without reading the reply (a run
                    // ended by a trip or a fall) is a disconnect, not a failure of the simulator.
                    Err(ServeError::Io(e))
                        if matches!(e.kind(), io::ErrorKind::BrokenPipe | io::ErrorKind::ConnectionReset) =>
                    {
                        return Ok(SessionSummary {
                            end: SessionEnd::Disconnected,
                            ticks,
                            sim_time_s: sim.time(),
                        })
                    }
                    Err(e) => return Err(e),
                }
            }
            Kind::Bye => {
                return Ok(SessionSummary {
                    end: SessionEnd::Bye,
                    ticks,
                    sim_time_s: sim.time(),
                })
            }
            got => {
                return Err(ServeError::Unexpected {
                    got,
                    expected: "LowCmd or Bye",
                })
            }
        }
    }
}

/// Removes the socket file when dropped (normal exit, error, panic unwinding).
struct SocketFile(PathBuf);
impl Drop for SocketFile {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

/// Binds a Unix socket at `path` (replacing a stale socket file nobody listens on), calls
/// `ready` once listening, serves one client, and removes the file.
pub fn serve_unix(
    path: &Path,
    sim: &mut Simulator,
    opts: &ServeOptions,
    ready: impl FnOnce(),
) -> Result<SessionSummary, ServeError> {
    if let Ok(meta) = std::fs::symlink_metadata(path) {
        // Only a socket is ours to replace: anything else at PATH is someone's file.
        if !std::os::unix::fs::FileTypeExt::is_socket(&meta.file_type()) {
            return Err(ServeError::Setup(format!(
                "{} exists and is not a socket; refusing to replace it (choose another --socket path)",
                path.display()
            )));
        }
        if UnixStream::connect(path).is_ok() {
            return Err(ServeError::Setup(format!(
                "{} is in use by another server",
                path.display()
            )));
        }
        std::fs::remove_file(path)
            .map_err(|e| ServeError::Setup(format!("removing stale socket {}: {e}", path.display())))?;
    }
    let listener =
        UnixListener::bind(path).map_err(|e| ServeError::Setup(format!("binding {}: {e}", path.display())))?;
    let _guard = SocketFile(path.to_owned());
    ready();
    let (stream, _) = listener.accept()?;
    drop(listener);
    serve_stream(stream, sim, opts)
}

/// Resolves `addr` and refuses anything that is not loopback: the bridge has no authentication
/// and commands a robot's motors.
pub fn loopback_addr(addr: &str) -> Result<std::net::SocketAddr, ServeError> {
    let addrs: Vec<_> = addr
        .to_socket_addrs()
        .map_err(|e| ServeError::Setup(format!("cannot resolve --tcp {addr:?}: {e}")))?
        .collect();
    match addrs.first() {
        Some(a) if addrs.iter().all(|a| a.ip().is_loopback()) => Ok(*a),
        Some(_) => Err(ServeError::Setup(format!(
            "--tcp {addr:?} is not a loopback address; the bridge is unauthenticated and only \
             listens on 127.0.0.1 / ::1 (use e.g. --tcp 127.0.0.1:7000)"
        ))),
        None => Err(ServeError::Setup(format!("--tcp {addr:?} resolves to nothing"))),
    }
}

/// Listens on loopback TCP `addr`, calls `ready` with the bound address, serves one client.
pub fn serve_tcp(
    addr: &str,
    sim: &mut Simulator,
    opts: &ServeOptions,
    ready: impl FnOnce(std::net::SocketAddr),
) -> Result<SessionSummary, ServeError> {
    let a = loopback_addr(addr)?;
    let listener = TcpListener::bind(a).map_err(|e| ServeError::Setup(format!("binding {a}: {e}")))?;
    ready(listener.local_addr()?);
    let (stream, _) = listener.accept()?;
    drop(listener);
    // Lock-step messages are small: never let Nagle hold one back.
    stream.set_nodelay(true)?;
    serve_stream(stream, sim, opts)
}
