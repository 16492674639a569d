//! SocketCAN: one raw CAN socket per bus (`vcan0`, `can0`, …), read without blocking and waited on
//! together with one epoll set (no allocation per wait).
use std::time::Duration;

use nix::sys::epoll::{Epoll, EpollCreateFlags, EpollEvent, EpollFlags, EpollTimeout};
use socketcan::{CanSocket, EmbeddedFrame, Id, Socket, StandardId};

use super::{BusError, CanBuses, CanFrame, FOREIGN_ID};

/// Receive buffer asked for per socket: vcan has no flow control, so a reader that falls behind
/// loses frames once its buffer is full (the kernel caps it at net.core.rmem_max).
const RECV_BUFFER: usize = 4 << 20;

pub struct SocketCanBuses {
    names: Vec<String>,
    sockets: Vec<CanSocket>,
    epoll: Epoll,
    /// Round-robin start, so one flooded bus cannot starve the others.
    next: usize,
}

impl SocketCanBuses {
    /// Opens one socket per interface name, in order (bus 0 = `names[0]`).
    pub fn open(names: &[String]) -> Result<Self, BusError> {
        let mut sockets = Vec::with_capacity(names.len());
        let epoll = Epoll::new(EpollCreateFlags::EPOLL_CLOEXEC).map_err(|e| BusError {
            bus: 0,
            name: names.first().cloned().unwrap_or_default(),
            io: e.into(),
        })?;
        for (bus, name) in names.iter().enumerate() {
            let err = |e: std::io::Error| {
                // EAFNOSUPPORT, or no /proc/net/can: the kernel itself has no CAN.
                let hint = if e.raw_os_error() == Some(97) || !std::path::Path::new("/proc/net/can").exists() {
                    "this kernel has no CAN support (CONFIG_CAN); `cargo xtask hil` runs the CAN suite in a VM \
                     that has it"
                        .to_string()
                } else {
                    format!(
                        "is the interface up? on a bench: `ip link set {name} up type can bitrate 1000000`; \
                         for a virtual bus: `ip link add dev {name} type vcan && ip link set {name} up`"
                    )
                };
                BusError {
                    bus,
                    name: name.clone(),
                    io: std::io::Error::new(e.kind(), format!("{e} ({hint})")),
                }
            };
            let s = CanSocket::open(name).map_err(err)?;
            s.set_nonblocking(true).map_err(err)?;
            // Best effort: an unprivileged process keeps the default size.
            let _ = s.as_raw_socket().set_recv_buffer_size(RECV_BUFFER);
            epoll
                .add(&s, EpollEvent::new(EpollFlags::EPOLLIN, bus as u64))
                .map_err(|e| err(e.into()))?;
            sockets.push(s);
        }
        Ok(Self {
            names: names.to_vec(),
            sockets,
            epoll,
            next: 0,
        })
    }

    fn err(&self, bus: usize, io: std::io::Error) -> BusError {
        BusError {
            bus,
            name: self.names[bus].clone(),
            io,
        }
    }

    fn try_read(&mut self) -> Result<Option<(usize, CanFrame)>, BusError> {
        let n = self.sockets.len();
        for k in 0..n {
            let bus = (self.next + k) % n;
            match self.sockets[bus].read_frame() {
                Ok(f) => {
                    self.next = (bus + 1) % n;
                    return Ok(Some((bus, convert(&f))));
                }
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {}
                Err(e) => return Err(self.err(bus, e)),
            }
        }
        Ok(None)
    }
}

fn convert(f: &socketcan::CanFrame) -> CanFrame {
    match (f, f.id()) {
        (socketcan::CanFrame::Data(_), Id::Standard(id)) => CanFrame::new(id.as_raw(), f.data()),
        _ => CanFrame {
            id: FOREIGN_ID,
            len: 0,
            data: [0; 8],
        },
    }
}

impl CanBuses for SocketCanBuses {
    fn count(&self) -> usize {
        self.sockets.len()
    }

    fn send(&mut self, bus: usize, frame: &CanFrame) -> Result<bool, BusError> {
        let id = StandardId::new(frame.id).unwrap_or(StandardId::ZERO);
        let Some(f) = socketcan::CanFrame::new(id, frame.payload()) else {
            return Ok(false);
        };
        match self.sockets[bus].write_frame(&f) {
            Ok(()) => Ok(true),
            // ENOBUFS / EAGAIN: the transmit queue is full (a flooded or disconnected wire).
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock || e.raw_os_error() == Some(105) => Ok(false),
            Err(e) => Err(self.err(bus, e)),
        }
    }

    fn recv(&mut self, timeout: Duration) -> Result<Option<(usize, CanFrame)>, BusError> {
        if let Some(f) = self.try_read()? {
            return Ok(Some(f));
        }
        if timeout.is_zero() {
            return Ok(None);
        }
        let mut events = [EpollEvent::empty(); 1];
        let ms =
            EpollTimeout::try_from(timeout.as_millis().clamp(1, i32::MAX as u128) as i32).unwrap_or(EpollTimeout::MAX);
        match self.epoll.wait(&mut events, ms) {
            Ok(0) => Ok(None),
            Ok(_) => self.try_read(),
            Err(nix::errno::Errno::EINTR) => Ok(None),
            Err(e) => Err(self.err(0, std::io::Error::from(e))),
        }
    }
}
