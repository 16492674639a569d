//! Reading g1fw logs back: a bounded, checking MCAP reader of our own.
//!
//! Two ways a log can be incomplete, told apart:
//! - **truncated**: the writer was killed (`kill -9`, power loss). The file has no `DataEnd` and no
//!   footer; every complete chunk reads back, and the scan says where it stopped.
//! - **damaged**: bytes changed after they were written. Every check MCAP offers is verified: each
//!   chunk's CRC of its records, the LZ4 frame (and its content checksum), the data-section CRC, the
//!   summary CRC, the footer and the closing magic. The first failure is named (chunk number and byte
//!   offset) and the scan stops there.
//!
//! Every size read from the file is checked against what is left of the file, or against
//! [`MAX_CHUNK_BYTES`], before anything is allocated for it: a flipped length field is an error,
//! never an allocation of exabytes.
use std::collections::BTreeMap;
use std::fmt;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use super::channels::RUN_METADATA;

/// Largest log file the tools read (it is read into memory whole). An hour at 500 Hz with lidar is
/// ~2 GB.
pub const MAX_LOG_BYTES: u64 = 8 << 30;
/// Largest uncompressed chunk accepted. g1fw writes 4 MiB chunks; one lidar frame message is ~0.3 MB.
pub const MAX_CHUNK_BYTES: u64 = 64 << 20;

const MAGIC: &[u8; 8] = b"\x89MCAP0\r\n";
const FOOTER_LEN: usize = 1 + 8 + 8 + 8 + 4;

mod op {
    pub const HEADER: u8 = 0x01;
    pub const FOOTER: u8 = 0x02;
    pub const SCHEMA: u8 = 0x03;
    pub const CHANNEL: u8 = 0x04;
    pub const MESSAGE: u8 = 0x05;
    pub const CHUNK: u8 = 0x06;
    pub const METADATA: u8 = 0x0C;
    pub const DATA_END: u8 = 0x0F;
}

#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    #[error("cannot read log {path}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path} is not an MCAP log (or its first bytes are damaged): {message}")]
    NotMcap { path: PathBuf, message: String },
    #[error("log {path} is {bytes} bytes, more than this reader's limit of {limit} bytes")]
    TooLarge { path: PathBuf, bytes: u64, limit: u64 },
    #[error("log {path} is damaged: {damage}")]
    Damaged { path: PathBuf, damage: Damage },
    #[error("log {path} has no '{RUN_METADATA}' metadata record; was it written by g1fw?")]
    NoMetadata { path: PathBuf },
}

/// Where and how a log is damaged.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Damage {
    /// Byte offset of the record that fails its check.
    pub offset: u64,
    /// 0-based index of the chunk, when the damage is in (or is) a chunk.
    pub chunk: Option<u64>,
    pub what: String,
}

impl fmt::Display for Damage {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.chunk {
            Some(c) => write!(f, "chunk {c} (at byte {}): {}", self.offset, self.what),
            None => write!(f, "record at byte {}: {}", self.offset, self.what),
        }
    }
}

/// A log file in memory.
pub struct LogFile {
    pub path: PathBuf,
    pub bytes: Vec<u8>,
}

/// How a scan ended.
#[derive(Clone, Debug, Default)]
pub struct ScanEnd {
    pub messages: u64,
    /// `Some(why)` when the file ends without its summary (the writer was killed): everything up to
    /// the last complete chunk was read.
    pub truncated: Option<String>,
    /// `Some` when a check failed; messages after the damage were not delivered.
    pub damaged: Option<Damage>,
}

impl LogFile {
    pub fn open(path: &Path) -> Result<Self, ReadError> {
        let io = |source| ReadError::Io {
            path: path.into(),
            source,
        };
        let bytes = std::fs::metadata(path).map_err(io)?.len();
        if bytes > MAX_LOG_BYTES {
            return Err(ReadError::TooLarge {
                path: path.into(),
                bytes,
                limit: MAX_LOG_BYTES,
            });
        }
        Self::from_bytes(path, control::read_capped(path, MAX_LOG_BYTES).map_err(io)?)
    }

    /// A log already in memory (`path` names it in messages).
    pub fn from_bytes(path: &Path, bytes: Vec<u8>) -> Result<Self, ReadError> {
        if !bytes.starts_with(MAGIC) {
            return Err(ReadError::NotMcap {
                path: path.into(),
                message: "missing the MCAP magic at the start".into(),
            });
        }
        Ok(Self {
            path: path.into(),
            bytes,
        })
    }

    /// The run metadata (written first, before any chunk, so it survives a crash).
    pub fn run_metadata(&self) -> Result<BTreeMap<String, String>, ReadError> {
        let mut found = None;
        let end = Scanner::new(&self.bytes).run(&mut |_, _, _| {}, &mut |name, map| {
            if name == RUN_METADATA {
                found = Some(map);
                return false;
            }
            true
        });
        match (found, end.damaged) {
            (Some(m), _) => Ok(m),
            (None, Some(damage)) => Err(ReadError::Damaged {
                path: self.path.clone(),
                damage,
            }),
            (None, None) => Err(ReadError::NoMetadata {
                path: self.path.clone(),
            }),
        }
    }

    /// The metadata record `name` (before any chunk), if the file has one.
    pub fn metadata(&self, name: &str) -> Option<BTreeMap<String, String>> {
        let mut found = None;
        Scanner::new(&self.bytes).run(&mut |_, _, _| {}, &mut |n, map| {
            if n == name {
                found = Some(map);
                return false;
            }
            true
        });
        found
    }

    /// Calls `f(topic, log_time_ns, data)` for every message in file order, up to the end of the
    /// last complete chunk or up to the first damage.
    pub fn scan(&self, mut f: impl FnMut(&str, u64, &[u8])) -> ScanEnd {
        Scanner::new(&self.bytes).run(&mut f, &mut |_, _| true)
    }

    /// Verifies every check in the file without delivering messages.
    pub fn verify(&self) -> Result<ScanEnd, ReadError> {
        self.undamaged(self.scan(|_, _, _| {}))
    }

    /// A scan's end as a result: damage is an error naming this log.
    pub fn undamaged(&self, end: ScanEnd) -> Result<ScanEnd, ReadError> {
        match end.damaged {
            Some(damage) => Err(ReadError::Damaged {
                path: self.path.clone(),
                damage,
            }),
            None => Ok(end),
        }
    }
}

/// Fuzz harness (cargo-fuzz target `mcap_log` and the stable smoke test): reads arbitrary bytes the
/// way replay does. Must never panic or allocate beyond the stated limits.
#[doc(hidden)]
pub fn fuzz_log(data: &[u8]) {
    let Ok(log) = LogFile::from_bytes(Path::new("fuzz.mcap"), data.to_vec()) else {
        return;
    };
    let _ = log.run_metadata();
    let mut bytes = 0usize;
    let end = log.scan(|topic, _, d| bytes += topic.len() + d.len());
    assert!(end.damaged.is_none() || end.truncated.is_none());
}

/// A failure while walking records: damage, or (in a file that never got its summary) the end of
/// what was written.
enum Stop {
    Damaged(Damage),
    EndOfWritten(String),
}

struct Cursor<'a> {
    buf: &'a [u8],
    pos: usize,
}

type Field<T> = Result<T, String>;

impl<'a> Cursor<'a> {
    fn new(buf: &'a [u8]) -> Self {
        Self { buf, pos: 0 }
    }
    fn left(&self) -> usize {
        self.buf.len() - self.pos
    }
    fn take(&mut self, n: u64, what: &str) -> Field<&'a [u8]> {
        if n > self.left() as u64 {
            return Err(format!(
                "{what} claims {n} bytes but only {} remain in its record",
                self.left()
            ));
        }
        let s = &self.buf[self.pos..self.pos + n as usize];
        self.pos += n as usize;
        Ok(s)
    }
    fn u16(&mut self, what: &str) -> Field<u16> {
        Ok(u16::from_le_bytes(self.take(2, what)?.try_into().unwrap_or_default()))
    }
    fn u32(&mut self, what: &str) -> Field<u32> {
        Ok(u32::from_le_bytes(self.take(4, what)?.try_into().unwrap_or_default()))
    }
    fn u64(&mut self, what: &str) -> Field<u64> {
        Ok(u64::from_le_bytes(self.take(8, what)?.try_into().unwrap_or_default()))
    }
    fn string(&mut self, what: &str) -> Field<&'a str> {
        let n = self.u32(what)?;
        std::str::from_utf8(self.take(n as u64, what)?).map_err(|_| format!("{what} is not UTF-8"))
    }
    fn string_map(&mut self, what: &str) -> Field<BTreeMap<String, String>> {
        let n = self.u32(what)?;
        let mut inner = Cursor::new(self.take(n as u64, what)?);
        let mut map = BTreeMap::new();
        while inner.left() > 0 {
            let k = inner.string(what)?;
            let v = inner.string(what)?;
            map.insert(k.to_string(), v.to_string());
        }
        Ok(map)
    }
}

struct Scanner<'a> {
    bytes: &'a [u8],
    /// Topic per channel id (ids are u16, so this is bounded).
    topics: Vec<Option<Arc<str>>>,
    messages: u64,
}

type OnMessage<'f> = dyn FnMut(&str, u64, &[u8]) + 'f;
/// Return `false` to stop the scan.
type OnMetadata<'f> = dyn FnMut(&str, BTreeMap<String, String>) -> bool + 'f;

impl<'a> Scanner<'a> {
    fn new(bytes: &'a [u8]) -> Self {
        Self {
            bytes,
            topics: Vec::new(),
            messages: 0,
        }
    }

    /// True when the file ends the way a finished MCAP does: a footer record and the magic.
    fn ends_like_a_finished_log(&self) -> bool {
        let b = self.bytes;
        b.len() >= MAGIC.len() * 2 + FOOTER_LEN && b.ends_with(MAGIC) && {
            let f = b.len() - MAGIC.len() - FOOTER_LEN;
            b[f] == op::FOOTER && b[f + 1..f + 9] == 20u64.to_le_bytes()
        }
    }

    fn run(mut self, on_message: &mut OnMessage<'_>, on_metadata: &mut OnMetadata<'_>) -> ScanEnd {
        let result = self.walk(on_message, on_metadata);
        let mut end = ScanEnd {
            messages: self.messages,
            ..ScanEnd::default()
        };
        match result {
            Ok(()) => {}
            Err(Stop::Damaged(d)) => end.damaged = Some(d),
            Err(Stop::EndOfWritten(why)) => end.truncated = Some(why),
        }
        end
    }

    fn walk(&mut self, on_message: &mut OnMessage<'_>, on_metadata: &mut OnMetadata<'_>) -> Result<(), Stop> {
        let b = self.bytes;
        // A file that was finished (footer and magic at its end, or a DataEnd record reached) has no
        // excuse for ending early: anything wrong is damage, not a crash-truncated tail.
        let mut finished = self.ends_like_a_finished_log();
        let mut pos = MAGIC.len();
        let mut chunk_index = 0u64;
        let mut summary_start = None;
        loop {
            let at = pos as u64;
            let damaged = |what: String| {
                Stop::Damaged(Damage {
                    offset: at,
                    chunk: None,
                    what,
                })
            };
            if pos == b.len() {
                return Err(if finished {
                    damaged("the file ends before its footer".into())
                } else {
                    Stop::EndOfWritten(format!(
                        "the log ends at byte {pos} without its summary (the writer did not close it)"
                    ))
                });
            }
            let left = (b.len() - pos) as u64;
            if left < 9 {
                return Err(if finished {
                    damaged(format!("{left} stray bytes where a record should start"))
                } else {
                    Stop::EndOfWritten(format!("the log ends inside the record at byte {pos}"))
                });
            }
            let opcode = b[pos];
            let len = u64::from_le_bytes(b[pos + 1..pos + 9].try_into().unwrap_or_default());
            if len > left - 9 {
                return Err(if finished {
                    damaged(format!(
                        "record (opcode {opcode:#04x}) claims {len} bytes, past the end of the file"
                    ))
                } else {
                    Stop::EndOfWritten(format!(
                        "the log ends inside the record at byte {pos} (the writer did not finish it)"
                    ))
                });
            }
            let body = &b[pos + 9..pos + 9 + len as usize];
            let next = pos + 9 + len as usize;
            if pos == MAGIC.len() && opcode != op::HEADER {
                return Err(damaged(format!(
                    "the first record is opcode {opcode:#04x}, not a header"
                )));
            }
            if summary_start.is_some() && matches!(opcode, op::CHUNK | op::MESSAGE | op::METADATA) {
                return Err(damaged(format!("a data record (opcode {opcode:#04x}) after DataEnd")));
            }
            match opcode {
                op::CHUNK => {
                    self.chunk(body, on_message).map_err(|what| {
                        Stop::Damaged(Damage {
                            offset: at,
                            chunk: Some(chunk_index),
                            what,
                        })
                    })?;
                    chunk_index += 1;
                }
                op::SCHEMA | op::CHANNEL | op::MESSAGE => {
                    self.record(opcode, body, on_message).map_err(damaged)?;
                }
                op::METADATA => {
                    let mut c = Cursor::new(body);
                    let name = c.string("metadata name").map_err(damaged)?;
                    let map = c.string_map("metadata").map_err(damaged)?;
                    if !on_metadata(name, map) {
                        return Ok(());
                    }
                }
                op::DATA_END => {
                    let stored = Cursor::new(body).u32("data section CRC").map_err(damaged)?;
                    let computed = crc32fast::hash(&b[..pos]);
                    if stored != 0 && stored != computed {
                        return Err(damaged(format!(
                            "data section CRC mismatch (stored {stored:#010x}, computed {computed:#010x}): \
                             bytes before DataEnd changed after they were written"
                        )));
                    }
                    finished = true;
                    summary_start = Some(next);
                }
                op::FOOTER => return self.footer(at, body, next, summary_start),
                _ => {} // indexes, statistics, attachments: not needed to read messages
            }
            pos = next;
        }
    }

    fn footer(&self, at: u64, body: &[u8], next: usize, summary_start: Option<usize>) -> Result<(), Stop> {
        let damaged = |what: String| {
            Stop::Damaged(Damage {
                offset: at,
                chunk: None,
                what,
            })
        };
        let Some(data_end) = summary_start else {
            return Err(damaged("a footer without a DataEnd record before it".into()));
        };
        let mut c = Cursor::new(body);
        let stored_start = c.u64("footer").map_err(damaged)?;
        c.u64("footer").map_err(damaged)?;
        let stored_crc = c.u32("footer").map_err(damaged)?;
        if body.len() != 20 {
            return Err(damaged(format!("footer of {} bytes (20 expected)", body.len())));
        }
        if stored_start != 0 && stored_start != data_end as u64 {
            return Err(damaged(format!(
                "footer says the summary starts at byte {stored_start}, but DataEnd ends at byte {data_end}"
            )));
        }
        // The summary CRC covers the summary records and the footer up to the CRC itself.
        let computed = crc32fast::hash(&self.bytes[data_end..next - 4]);
        if stored_crc != 0 && stored_crc != computed {
            return Err(damaged(format!(
                "summary CRC mismatch (stored {stored_crc:#010x}, computed {computed:#010x})"
            )));
        }
        if self.bytes.len() != next + MAGIC.len() || &self.bytes[next..] != MAGIC {
            return Err(damaged(
                "the file does not end with the MCAP magic right after its footer".into(),
            ));
        }
        Ok(())
    }

    fn chunk(&mut self, body: &[u8], on_message: &mut OnMessage<'_>) -> Field<()> {
        let mut c = Cursor::new(body);
        c.u64("chunk start time")?;
        c.u64("chunk end time")?;
        let size = c.u64("chunk size")?;
        let crc = c.u32("chunk CRC")?;
        let compression = c.string("chunk compression")?;
        let compressed_len = c.u64("chunk records")?;
        let compressed = c.take(compressed_len, "chunk records")?;
        if c.left() != 0 {
            return Err(format!("{} stray bytes after the chunk's records", c.left()));
        }
        if size > MAX_CHUNK_BYTES {
            return Err(format!(
                "chunk claims {size} uncompressed bytes, more than the limit of {MAX_CHUNK_BYTES}"
            ));
        }
        let owned;
        let records: &[u8] = match compression {
            "" => compressed,
            "lz4" => {
                owned = lz4_decompress(compressed, size)?;
                &owned
            }
            other => {
                return Err(format!(
                    "chunk compression '{other}' is not supported (g1fw writes lz4)"
                ))
            }
        };
        if records.len() as u64 != size {
            return Err(format!(
                "chunk holds {} bytes of records, its header says {size}",
                records.len()
            ));
        }
        let computed = crc32fast::hash(records);
        if crc != 0 && crc != computed {
            return Err(format!(
                "CRC of its records mismatch (stored {crc:#010x}, computed {computed:#010x})"
            ));
        }
        // Check the whole chunk before delivering any of it: damage stops the scan at a chunk boundary.
        let mut inner = Cursor::new(records);
        while inner.left() > 0 {
            inner.take(1, "record opcode")?;
            let len = inner.u64("record length")?;
            inner.take(len, "record")?;
        }
        let mut inner = Cursor::new(records);
        while inner.left() > 0 {
            let opcode = inner.take(1, "record opcode")?[0];
            let len = inner.u64("record length")?;
            let body = inner.take(len, "record")?;
            self.record(opcode, body, on_message)
                .map_err(|e| format!("record at byte {} of its records: {e}", inner.pos - body.len() - 9))?;
        }
        Ok(())
    }

    fn record(&mut self, opcode: u8, body: &[u8], on_message: &mut OnMessage<'_>) -> Field<()> {
        let mut c = Cursor::new(body);
        match opcode {
            op::CHANNEL => {
                let id = c.u16("channel id")? as usize;
                c.u16("channel schema id")?;
                let topic = c.string("channel topic")?;
                if self.topics.len() <= id {
                    self.topics.resize(id + 1, None);
                }
                self.topics[id] = Some(topic.into());
            }
            op::MESSAGE => {
                let id = c.u16("message channel id")?;
                c.u32("message sequence")?;
                let log_time = c.u64("message log time")?;
                c.u64("message publish time")?;
                let Some(Some(topic)) = self.topics.get(id as usize) else {
                    return Err(format!("a message on channel {id}, which was never declared"));
                };
                on_message(topic, log_time, &body[c.pos..]);
                self.messages += 1;
            }
            _ => {} // schemas are for other tools; g1fw knows its own
        }
        Ok(())
    }
}

/// LZ4 frame → exactly `size` bytes (≤ [`MAX_CHUNK_BYTES`]), reading the frame to its end so that
/// its content checksum is verified.
fn lz4_decompress(compressed: &[u8], size: u64) -> Field<Vec<u8>> {
    let lz4 = |e: std::io::Error| format!("its LZ4 frame does not decompress: {e}");
    let decoder = lz4::Decoder::new(compressed).map_err(lz4)?;
    let mut out = Vec::with_capacity(size as usize);
    let mut limited = decoder.take(size + 1);
    limited.read_to_end(&mut out).map_err(lz4)?;
    if out.len() as u64 > size {
        return Err(format!(
            "its LZ4 frame holds more than the {size} bytes its header says"
        ));
    }
    let (_, finished) = limited.into_inner().finish();
    finished.map_err(|_| "its LZ4 frame ends early".to_string())?;
    Ok(out)
}
