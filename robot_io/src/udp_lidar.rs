//! The MID-360 over UDP: Livox SDK2 point packets (Cartesian high, 96 per packet, 10 Hz frames)
//! arrive from the lidar (factory address 192.168.123.120) on the host's point-data port 56301.
//! [`UdpLidar`] drains its non-blocking socket whenever the control loop asks for a frame and feeds
//! every datagram to the same [`FrameAssembler`] the simulator bridge uses, so a frame is assembled
//! the same way whichever transport carried its packets.
//!
//! Nothing here allocates after [`UdpLidar::open`]: one receive buffer and the assembler's two
//! frames are allocated once.
//!
//! Time: the packets carry the lidar's own timestamps (`timestamp_ns`, `time_type` 0 = since power-on
//! unless PTP/gPTP or GPS synchronises it). The assembler only uses differences inside a frame, so
//! the BEV's motion compensation does not need the lidar's clock to match the robot's; matching a
//! frame to the robot's pose history across frames does (docs: synchronise the MID-360 by PTP to the
//! onboard computer when frames must be placed in the robot's time).
use std::io::ErrorKind as IoErrorKind;
use std::net::{IpAddr, Ipv4Addr, SocketAddr, UdpSocket};

use hal::PointFrame;
use sensor_io::livox::FrameAssembler;

/// The G1's defaults: the MID-360's factory address and the host's Livox SDK2 point-data port.
pub const DEFAULT_LIDAR_ADDR: IpAddr = IpAddr::V4(Ipv4Addr::new(192, 168, 123, 120));
pub const DEFAULT_POINT_PORT: u16 = 56301;
/// Larger than any Livox SDK2 datagram (Cartesian high: 36 + 96 × 14 = 1380 bytes); a longer
/// datagram is cut to this and then rejected by the decoder as malformed.
const RECV_BUF_LEN: usize = 2048;

/// Where the packets arrive and whom they are accepted from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct UdpLidarConfig {
    /// Local address to bind (the host's point-data port).
    pub bind: SocketAddr,
    /// Accept datagrams only from this address (`None`: from anyone, e.g. a replay on loopback).
    pub lidar: Option<IpAddr>,
    /// Largest number of datagrams taken in one call (bounds the time a call can take when the
    /// socket is flooded; the rest wait for the next call).
    pub max_datagrams_per_poll: usize,
}

impl Default for UdpLidarConfig {
    fn default() -> Self {
        Self {
            bind: SocketAddr::new(IpAddr::V4(Ipv4Addr::UNSPECIFIED), DEFAULT_POINT_PORT),
            lidar: Some(DEFAULT_LIDAR_ADDR),
            // A 10 Hz frame of 20k points is ~209 packets; a 500 Hz loop sees ~21 per tick.
            max_datagrams_per_poll: 512,
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum UdpLidarError {
    #[error("cannot bind the lidar's UDP port {addr} (is another program, e.g. Livox Viewer or a second g1fw, bound to it? is {addr} an address of this machine?)")]
    Bind { addr: SocketAddr, source: std::io::Error },
    #[error("lidar UDP socket {addr}")]
    Socket { addr: SocketAddr, source: std::io::Error },
}

impl hal::Error for UdpLidarError {
    fn kind(&self) -> hal::ErrorKind {
        hal::ErrorKind::Other
    }
}

/// What the socket has seen (the assembler's own counters are in [`UdpLidar::assembler_stats`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct UdpLidarCounters {
    pub datagrams: u64,
    /// Datagrams from an address other than the configured lidar (dropped).
    pub foreign: u64,
    /// Datagrams the assembler rejected (malformed, bad CRC, ...).
    pub malformed: u64,
    /// Completed frames.
    pub frames: u64,
}

/// A [`hal::Lidar`] over UDP. `CAP`: the most points a frame holds (the rest are counted as
/// overflow by the assembler).
pub struct UdpLidar<const CAP: usize> {
    socket: UdpSocket,
    cfg: UdpLidarConfig,
    local: SocketAddr,
    buf: Box<[u8; RECV_BUF_LEN]>,
    /// Its last completed frame stays put until the next completes: that is the frame handed over.
    assembler: FrameAssembler<CAP>,
    /// A frame completed since the last hand-over.
    fresh: bool,
    counters: UdpLidarCounters,
}

impl<const CAP: usize> UdpLidar<CAP> {
    /// Binds the socket (non-blocking) and allocates every buffer.
    pub fn open(cfg: UdpLidarConfig) -> Result<Self, UdpLidarError> {
        let socket = UdpSocket::bind(cfg.bind).map_err(|source| UdpLidarError::Bind { addr: cfg.bind, source })?;
        let local = socket
            .local_addr()
            .map_err(|source| UdpLidarError::Socket { addr: cfg.bind, source })?;
        socket
            .set_nonblocking(true)
            .map_err(|source| UdpLidarError::Socket { addr: local, source })?;
        Ok(Self {
            socket,
            cfg,
            local,
            buf: Box::new([0; RECV_BUF_LEN]),
            assembler: FrameAssembler::new_boxed(),
            fresh: false,
            counters: UdpLidarCounters::default(),
        })
    }

    /// The bound address (with the port the OS chose when `bind` asked for port 0).
    pub fn local_addr(&self) -> SocketAddr {
        self.local
    }

    pub fn counters(&self) -> UdpLidarCounters {
        self.counters
    }

    pub fn assembler_stats(&self) -> &sensor_io::livox::AssemblerStats {
        self.assembler.stats()
    }

    /// Takes in every datagram waiting on the socket (up to the configured bound). Returns how many
    /// were taken. A frame completes when the first packet of the next one arrives, as on the bridge.
    pub fn poll(&mut self) -> Result<usize, UdpLidarError> {
        let mut taken = 0;
        while taken < self.cfg.max_datagrams_per_poll {
            let (n, from) = match self.socket.recv_from(&mut self.buf[..]) {
                Ok(r) => r,
                Err(e) if e.kind() == IoErrorKind::WouldBlock => break,
                Err(e) if e.kind() == IoErrorKind::Interrupted => continue,
                // An ICMP port-unreachable from an earlier send, or similar: not fatal for a receiver.
                Err(e) if e.kind() == IoErrorKind::ConnectionRefused => continue,
                Err(source) => {
                    return Err(UdpLidarError::Socket {
                        addr: self.local,
                        source,
                    })
                }
            };
            taken += 1;
            self.counters.datagrams += 1;
            if self.cfg.lidar.is_some_and(|ip| ip != from.ip()) {
                self.counters.foreign += 1;
                continue;
            }
            match self.assembler.push(&self.buf[..n]) {
                Ok(Some(_)) => {
                    self.fresh = true;
                    self.counters.frames += 1;
                }
                Ok(None) => {}
                Err(_) => self.counters.malformed += 1,
            }
        }
        Ok(taken)
    }
}

impl<const CAP: usize> hal::Lidar<CAP> for UdpLidar<CAP> {
    type Error = UdpLidarError;

    /// Drains the socket, then hands over the newest completed frame; `Ok(false)` when none is new.
    fn read_frame(&mut self, out: &mut PointFrame<CAP>) -> Result<bool, UdpLidarError> {
        self.poll()?;
        if !self.fresh {
            return Ok(false);
        }
        out.copy_from(self.assembler.last_frame());
        self.fresh = false;
        Ok(true)
    }

    /// Drains the socket into the assembler (`g1fw run` calls it every tick).
    fn receive(&mut self) -> Result<(), UdpLidarError> {
        self.poll().map(|_| ())
    }
}
