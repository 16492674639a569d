//! A socket wrapper whose reads spin briefly on the non-blocking socket before blocking.
//!
//! On the lock-stepped bridge each side waits for the other every tick; a blocking read costs a
//! scheduler wake-up (tens of µs in a VM) per message, more than a whole physics step. Spinning for
//! about as long as the peer usually takes removes that; past the budget we block, so an idle peer
//! costs no CPU. The spin budget is measured with a monotonic clock, which decides only *how* we
//! wait, never *what* is computed.
use std::io::{self, Read, Write};
use std::net::TcpStream;
use std::os::unix::net::UnixStream;
use std::time::{Duration, Instant};

/// Sockets whose blocking mode can be switched.
pub trait Blocking {
    fn set_nonblocking(&self, nonblocking: bool) -> io::Result<()>;
}

impl Blocking for UnixStream {
    fn set_nonblocking(&self, nb: bool) -> io::Result<()> {
        UnixStream::set_nonblocking(self, nb)
    }
}

impl Blocking for TcpStream {
    fn set_nonblocking(&self, nb: bool) -> io::Result<()> {
        TcpStream::set_nonblocking(self, nb)
    }
}

/// Reads spin on the non-blocking socket for up to `spin`, then fall back to one blocking read.
/// The socket stays non-blocking between calls, so the fast path costs one `read` syscall.
pub struct SpinStream<S: Read + Write + Blocking> {
    inner: S,
    spin: Duration,
}

impl<S: Read + Write + Blocking> SpinStream<S> {
    /// Wraps `inner`; `spin == 0` keeps it an ordinary blocking socket.
    pub fn new(inner: S, spin: Duration) -> io::Result<Self> {
        inner.set_nonblocking(spin > Duration::ZERO)?;
        Ok(Self { inner, spin })
    }

    pub fn get_ref(&self) -> &S {
        &self.inner
    }

    fn blocking<T>(&mut self, f: impl FnOnce(&mut S) -> io::Result<T>) -> io::Result<T> {
        self.inner.set_nonblocking(false)?;
        let r = f(&mut self.inner);
        self.inner.set_nonblocking(true)?;
        r
    }
}

impl<S: Read + Write + Blocking> Read for SpinStream<S> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let mut start: Option<Instant> = None;
        loop {
            match self.inner.read(buf) {
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => {
                    let t0 = *start.get_or_insert_with(Instant::now);
                    if t0.elapsed() >= self.spin {
                        return self.blocking(|s| s.read(buf));
                    }
                    std::hint::spin_loop();
                }
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                r => return r,
            }
        }
    }
}

impl<S: Read + Write + Blocking> Write for SpinStream<S> {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        match self.inner.write(buf) {
            // Socket buffer full: the peer is slow to read; wait for it.
            Err(e) if e.kind() == io::ErrorKind::WouldBlock => self.blocking(|s| s.write(buf)),
            r => r,
        }
    }
    fn flush(&mut self) -> io::Result<()> {
        self.inner.flush()
    }
}
