//! MCAP run logs: what the HAL delivered and what the firmware decided, tick by tick.
//!
//! - [`channels`]: topics, schemas (ros2msg for raw frames, JSON Schema for derived products);
//! - [`writer`]: the fixed-pool logger and its writer thread;
//! - [`reader`]: reading logs back, including crash-truncated ones.
pub mod channels;
pub mod reader;
pub mod writer;

pub use reader::LogFile;
pub use writer::{mode_name, split_key, split_path, LogOptions, LogStats, Logger, RunMeta, SPLIT_METADATA};
