//! Reading g1fw logs back, including logs cut short by a crash (`kill -9`): every complete chunk
//! reads back, and the reader says where and why it stopped.
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use super::channels::RUN_METADATA;

#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    #[error("cannot read log {path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path} is not an MCAP log: {message}")]
    NotMcap { path: PathBuf, message: String },
    #[error("log {path} has no '{RUN_METADATA}' metadata record; was it written by g1fw?")]
    NoMetadata { path: PathBuf },
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
    /// `Some(why)` when the file ends without a proper footer (the writer was killed) or is damaged
    /// after the last complete chunk.
    pub truncated: Option<String>,
}

impl LogFile {
    pub fn open(path: &Path) -> Result<Self, ReadError> {
        let bytes = std::fs::read(path).map_err(|source| ReadError::Io {
            path: path.into(),
            source,
        })?;
        if !bytes.starts_with(mcap::MAGIC) {
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

    /// The run metadata (written first, so it survives a crash).
    pub fn run_metadata(&self) -> Result<BTreeMap<String, String>, ReadError> {
        let reader =
            mcap::read::LinearReader::new_with_options(&self.bytes, mcap::read::Options::IgnoreEndMagic.into())
                .map_err(|e| ReadError::NotMcap {
                    path: self.path.clone(),
                    message: e.to_string(),
                })?;
        for rec in reader {
            match rec {
                Ok(mcap::records::Record::Metadata(m)) if m.name == RUN_METADATA => return Ok(m.metadata),
                Ok(mcap::records::Record::Chunk { .. }) | Err(_) => break,
                Ok(_) => {}
            }
        }
        Err(ReadError::NoMetadata {
            path: self.path.clone(),
        })
    }

    /// Calls `f(topic, log_time_ns, data)` for every message in file order, up to the end of the
    /// last complete chunk.
    pub fn scan(&self, mut f: impl FnMut(&str, u64, &[u8])) -> ScanEnd {
        let mut end = ScanEnd::default();
        let stream = match mcap::read::RawMessageStream::new(&self.bytes) {
            Ok(s) => s,
            Err(e) => {
                end.truncated = Some(e.to_string());
                return end;
            }
        };
        // Topic per channel id, looked up once per channel rather than once per message.
        let mut topics: Vec<Option<std::sync::Arc<str>>> = Vec::new();
        let mut stream = stream;
        loop {
            match stream.next() {
                None => break,
                Some(Err(e)) => {
                    end.truncated = Some(e.to_string());
                    break;
                }
                Some(Ok(m)) => {
                    let id = m.header.channel_id as usize;
                    if topics.len() <= id {
                        topics.resize(id + 1, None);
                    }
                    if topics[id].is_none() {
                        topics[id] = stream.get_channel(m.header.channel_id).map(|c| c.topic.as_str().into());
                    }
                    if let Some(t) = &topics[id] {
                        f(t, m.header.log_time, &m.data);
                        end.messages += 1;
                    }
                }
            }
        }
        end
    }
}
