//! A run's record: MCAP logging through a fixed pool and a writer thread ([`log`]: channels, writer,
//! reader), and bit-exact replay ([`replay`]: the recorded inputs through the same `control` runtime,
//! outputs compared bit for bit). Logs open in Foxglove.
pub mod log;
pub mod replay;
