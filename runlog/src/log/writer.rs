//! The MCAP logger: the control tick copies a fixed-size record into a preallocated pool; a writer
//! thread encodes, compresses and writes chunks.
//!
//! Crash safety: the run metadata is written before the first message, and the writer closes a
//! chunk and hands it to the OS every `flush_every_ticks` ticks, so after `kill -9` every chunk
//! written before the kill reads back (only the summary at the end is missing).
//!
//! Split files ([`LogOptions::split_bytes`], as rosbag2's `--max-bag-size`): once a file has
//! reached the size, the control thread writes the runtime's state after the next tick that can
//! be cut ([`control::runtime::Runtime::save_snapshot`]: no perception step out, no fresh frame on
//! the tick) and the writer goes on in `NAME_1.mcap`, `NAME_2.mcap`, … Each file starts with the
//! run metadata and that state ([`SPLIT_METADATA`]), so each replays on its own.
use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use crossbeam_queue::ArrayQueue;
use hal::GroundTruth;
use hal::{LowCommand, LowState};
use serde::Serialize;

use super::channels::{self as ch, encode_lidar_frame, encode_low_cmd_frame, encode_low_state_frame};
use control::controller::Mode;
use control::perception::{LidarFrame, PerceptionSummary};
use control::runtime::{HalFailure, TickSummary, TickView};
use sensor_io::bev::{BevGrid, BEV_CELLS, BEV_CELL_M, BEV_CHANNELS, BEV_HALF_EXTENT_M, CHANNEL_NAMES};

/// Name of the metadata record a split file starts with, after the run's (see the module doc).
pub const SPLIT_METADATA: &str = "g1fw.split";

/// Keys of [`SPLIT_METADATA`].
pub mod split_key {
    /// 1 for the second file, 2 for the third, …
    pub const PART: &str = "part";
    /// The first tick this file holds.
    pub const FIRST_TICK: &str = "first_tick";
    /// The runtime's state before that tick (`Runtime::save_snapshot`), hex, and its sha256.
    pub const SNAPSHOT_HEX: &str = "snapshot_hex";
    pub const SNAPSHOT_SHA256: &str = "snapshot_sha256";
    /// The last LowState the loop held (what a tick without a frame reuses), unitree_hg C layout, hex.
    pub const LAST_STATE_HEX: &str = "last_state_hex";
    /// The file before this one.
    pub const PREVIOUS: &str = "previous";
}

/// The `part`-th file of a log split from `base` (`run.mcap` → `run_1.mcap`; part 0 is `base`).
pub fn split_path(base: &Path, part: u64) -> PathBuf {
    if part == 0 {
        return base.to_path_buf();
    }
    let stem = base
        .file_stem()
        .map_or_else(String::new, |s| s.to_string_lossy().into_owned());
    let name = match base.extension() {
        Some(ext) => format!("{stem}_{part}.{}", ext.to_string_lossy()),
        None => format!("{stem}_{part}"),
    };
    base.with_file_name(name)
}

/// Where the control thread cut the run: the state the next file starts from.
struct SplitPoint {
    snapshot: Vec<u8>,
    last_state: LowState,
    first_tick: u64,
}

/// Largest observation / action the log record holds.
pub const MAX_OBS: usize = 1024;
pub const MAX_ACT: usize = 64;
const FRAME_CAP: usize = sensor_io::unitree_hg::LOW_STATE_LEN;

#[derive(Debug, thiserror::Error)]
pub enum LogError {
    #[error("cannot create log {path}")]
    Create { path: PathBuf, source: std::io::Error },
    #[error("writing log {path}")]
    Mcap { path: PathBuf, source: mcap::McapError },
    #[error("writing log {path}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("the log holds observations up to {MAX_OBS} values and actions up to {MAX_ACT}; this policy has {obs} and {act}")]
    TooLarge { obs: usize, act: usize },
    #[error("the log writer thread panicked")]
    WriterPanicked,
    #[error("{} is there from an earlier split log: move or remove it (and the parts after it), or log to another name", path.display())]
    StalePart { path: PathBuf },
}

/// One tick, as copied by the control thread. Fixed size: no allocation on the tick path.
#[derive(Clone)]
pub struct Record {
    pub summary: TickSummary,
    pub frame_len: usize,
    pub frame_received: bool,
    pub frame: [u8; FRAME_CAP],
    pub command: LowCommand,
    pub command_sent: bool,
    pub obs_len: usize,
    pub obs: [f32; MAX_OBS],
    pub act_len: usize,
    pub action: [f32; MAX_ACT],
    pub target_q: [f32; hal::NUM_MOTORS],
    pub truth: Option<GroundTruth>,
    pub hal_error: Option<HalFailure>,
    /// Records dropped (pool full) since the previous record.
    pub dropped_before: u64,
    /// The log goes on in a new file after this record.
    pub split_after: bool,
}

impl Record {
    fn boxed() -> Box<Record> {
        Box::new(Record {
            summary: TickSummary::empty(),
            frame_len: 0,
            frame_received: false,
            frame: [0; FRAME_CAP],
            command: LowCommand::default(),
            command_sent: false,
            obs_len: 0,
            obs: [0.0; MAX_OBS],
            act_len: 0,
            action: [0.0; MAX_ACT],
            target_q: [0.0; hal::NUM_MOTORS],
            truth: None,
            hal_error: None,
            dropped_before: 0,
            split_after: false,
        })
    }

    fn fill(&mut self, v: &TickView, dropped_before: u64) {
        self.summary = *v.summary;
        self.frame_received = v.raw_state.is_some();
        let raw = v.raw_state.unwrap_or(&[]);
        self.frame_len = raw.len().min(FRAME_CAP);
        self.frame[..self.frame_len].copy_from_slice(&raw[..self.frame_len]);
        self.command = *v.command;
        self.command_sent = v.command_sent;
        if v.summary.policy_step {
            let c = v.runtime.controller();
            let (o, a) = (c.observation(), c.last_action());
            self.obs_len = o.len();
            self.obs[..o.len()].copy_from_slice(o);
            self.act_len = a.len();
            self.action[..a.len()].copy_from_slice(a);
            self.target_q = *c.target_q();
        } else {
            self.obs_len = 0;
            self.act_len = 0;
        }
        self.truth = v.truth.copied();
        self.hal_error = v.hal_error;
        self.dropped_before = dropped_before;
        self.split_after = false;
    }
}

/// One perception step with a fresh lidar frame: the raw frame it consumed (for replay), the cloud in
/// the robot frame, the BEV grid and the token. Large (~1.4 MB), so a small separate pool.
pub struct PerceptionRecord {
    pub tick: u64,
    /// The tick the step's result came back (threaded perception; `tick` when inline).
    pub back_tick: u64,
    pub time_ns: u64,
    pub summary: PerceptionSummary,
    pub truth: Option<hal::TerrainToken>,
    pub n: usize,
    /// x, y, z (robot frame, m, motion-compensated, self-hits removed) and intensity (0: the
    /// simulated sensor reports none worth drawing).
    pub points: Box<[[f32; 4]]>,
    pub grid: Box<BevGrid>,
    /// The sensor-frame lidar frame the step consumed, as the HAL delivered it (`/lidar/frame`).
    pub frame: Box<LidarFrame>,
}

impl PerceptionRecord {
    fn boxed() -> Box<PerceptionRecord> {
        Box::new(PerceptionRecord {
            tick: 0,
            back_tick: 0,
            time_ns: 0,
            summary: PerceptionSummary::default(),
            truth: None,
            n: 0,
            points: vec![[0.0; 4]; hal::LIDAR_FRAME_CAP].into_boxed_slice(),
            grid: Box::new(BevGrid::zeroed()),
            frame: sensor_io::livox::boxed_point_frame(),
        })
    }

    /// `false` when perception is away (cannot happen for a summary that just came home).
    fn fill(&mut self, v: &TickView, p: &PerceptionSummary) -> bool {
        let Some(per) = v.runtime.perception() else {
            return false;
        };
        let pts = per.robot_points();
        // Keyed by the step's tick: replay feeds `/lidar/frame` back on that tick.
        self.tick = p.step_tick;
        self.back_tick = v.summary.tick.index;
        let back = self.back_tick.saturating_sub(p.step_tick);
        self.time_ns = v.summary.tick.time_ns.saturating_sub(back * v.runtime.period_ns());
        self.summary = *p;
        self.truth = v.truth.and_then(|t| t.terrain);
        self.n = pts.len().min(self.points.len());
        for (dst, q) in self.points.iter_mut().zip(pts) {
            *dst = [q[0], q[1], q[2], 0.0];
        }
        self.grid.data.copy_from_slice(&per.grid().data);
        // The used points only (a copy of the whole buffer would be ~800 KB per frame).
        let src = per.frame();
        self.frame.points[..src.len].copy_from_slice(src.as_slice());
        self.frame.len = src.len;
        self.frame.timestamp_ns = src.timestamp_ns;
        self.frame.overflow = src.overflow;
        true
    }
}

/// Perception records in the pool (frames arrive at 10 Hz; the writer keeps up easily).
const PERCEPTION_POOL: usize = 4;

/// What pins a run: everything replay needs besides the recorded inputs.
#[derive(Clone, Debug, Default)]
pub struct RunMeta {
    pub entries: BTreeMap<String, String>,
}

impl RunMeta {
    pub fn set(&mut self, key: &str, value: impl ToString) -> &mut Self {
        self.entries.insert(key.into(), value.to_string());
        self
    }

    /// Adds `other`'s entries (replacing equal keys).
    pub fn extend(&mut self, other: RunMeta) -> &mut Self {
        self.entries.extend(other.entries);
        self
    }
}

#[derive(Clone, Debug)]
pub struct LogOptions {
    /// Close a chunk at least this often (ticks), bounding what a crash can lose.
    pub flush_every_ticks: u64,
    /// Records in the pool between the control thread and the writer.
    pub pool: usize,
    /// When the pool is full: wait for the writer (simulation and replay, where time is virtual) or
    /// drop the record and count it (hardware, where the tick must not wait).
    pub block_when_full: bool,
    /// Go on in a new file once one has this many bytes (see the module doc); `None`: one file.
    pub split_bytes: Option<u64>,
}

impl Default for LogOptions {
    fn default() -> Self {
        Self {
            flush_every_ticks: 250,
            pool: 512,
            block_when_full: true,
            split_bytes: None,
        }
    }
}

/// Totals after the log is closed.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct LogStats {
    pub records: u64,
    pub messages: u64,
    pub dropped_records: u64,
    pub chunks_flushed: u64,
    /// All files together.
    pub bytes: u64,
    /// Files written (1 unless the log was split).
    pub files: u64,
}

pub struct Logger {
    free: Arc<ArrayQueue<Box<Record>>>,
    full: Arc<ArrayQueue<Box<Record>>>,
    pfree: Arc<ArrayQueue<Box<PerceptionRecord>>>,
    pfull: Arc<ArrayQueue<Box<PerceptionRecord>>>,
    stop: Arc<AtomicBool>,
    flushed_ticks: Arc<AtomicU64>,
    thread: Option<JoinHandle<Result<LogStats, LogError>>>,
    block_when_full: bool,
    dropped: u64,
    dropped_total: u64,
    path: PathBuf,
    /// Set by the writer when the current file has reached [`LogOptions::split_bytes`].
    split_wanted: Arc<AtomicBool>,
    split: Arc<Mutex<Option<SplitPoint>>>,
}

impl Logger {
    /// Creates the file, writes the run metadata and starts the writer thread. Allocates the pool.
    pub fn create(
        path: &Path,
        meta: &RunMeta,
        obs_dim: usize,
        act_dim: usize,
        opts: LogOptions,
    ) -> Result<Self, LogError> {
        if obs_dim > MAX_OBS || act_dim > MAX_ACT {
            return Err(LogError::TooLarge {
                obs: obs_dim,
                act: act_dim,
            });
        }
        // A part left by an earlier split log would read as this run's.
        let part = split_path(path, 1);
        if opts.split_bytes.is_some() && part.exists() {
            return Err(LogError::StalePart { path: part });
        }
        let file = File::create(path).map_err(|source| LogError::Create {
            path: path.into(),
            source,
        })?;
        let w = McapSink::new(BufWriter::with_capacity(1 << 20, file), path, meta)?;
        let free = Arc::new(ArrayQueue::new(opts.pool));
        for _ in 0..opts.pool {
            let _ = free.push(Record::boxed());
        }
        let full = Arc::new(ArrayQueue::new(opts.pool));
        let pfree = Arc::new(ArrayQueue::new(PERCEPTION_POOL));
        for _ in 0..PERCEPTION_POOL {
            let _ = pfree.push(PerceptionRecord::boxed());
        }
        let pfull = Arc::new(ArrayQueue::new(PERCEPTION_POOL));
        let stop = Arc::new(AtomicBool::new(false));
        let flushed_ticks = Arc::new(AtomicU64::new(0));
        let split_wanted = Arc::new(AtomicBool::new(false));
        let split = Arc::new(Mutex::new(None));
        let thread = {
            let (free, full, stop, flushed) = (free.clone(), full.clone(), stop.clone(), flushed_ticks.clone());
            let (pfree, pfull) = (pfree.clone(), pfull.clone());
            let splits = Splits {
                bytes: opts.split_bytes,
                wanted: split_wanted.clone(),
                point: split.clone(),
                base: path.to_path_buf(),
                meta: meta.clone(),
            };
            let every = opts.flush_every_ticks.max(1);
            std::thread::Builder::new()
                .name("g1fw-log".into())
                .spawn(move || writer_loop(w, (&free, &full), (&pfree, &pfull), &stop, &flushed, every, splits))
                .map_err(|source| LogError::Io {
                    path: path.into(),
                    source,
                })?
        };
        Ok(Self {
            free,
            full,
            pfree,
            pfull,
            stop,
            flushed_ticks,
            thread: Some(thread),
            block_when_full: opts.block_when_full,
            dropped: 0,
            dropped_total: 0,
            path: path.into(),
            split_wanted,
            split,
        })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Ticks whose messages are in closed chunks on disk (crash-safe).
    pub fn flushed_ticks(&self) -> u64 {
        self.flushed_ticks.load(Ordering::Acquire)
    }

    /// Copies one tick into the pool. Never allocates. Returns false if the record was dropped.
    pub fn push(&mut self, view: &TickView) -> bool {
        let mut rec = loop {
            match self.free.pop() {
                Some(r) => break r,
                None if self.block_when_full && !self.writer_gone() => std::thread::yield_now(),
                None => {
                    self.dropped += 1;
                    self.dropped_total += 1;
                    return false;
                }
            }
        };
        rec.fill(view, self.dropped);
        self.dropped = 0;
        if self.split_wanted.load(Ordering::Acquire) {
            rec.split_after = self.cut_after(view);
        }
        // Cannot fail: the pool and the queue have the same capacity.
        let _ = self.full.push(rec);
        if let Some(p) = view.summary.perception.filter(|p| p.fresh) {
            let prec = loop {
                match self.pfree.pop() {
                    Some(r) => break Some(r),
                    None if self.block_when_full && !self.writer_gone() => std::thread::yield_now(),
                    None => break None,
                }
            };
            match prec {
                Some(mut r) => {
                    if r.fill(view, &p) {
                        let _ = self.pfull.push(r);
                    } else {
                        let _ = self.pfree.push(r);
                    }
                }
                None => self.dropped_total += 1,
            }
        }
        true
    }

    /// The writer asked for a new file: cut after `view`'s tick if it can be cut there (no
    /// perception step out, no fresh perception record to follow, the HAL fine). Allocates the
    /// snapshot (a few tens of kB), once per file.
    fn cut_after(&mut self, view: &TickView) -> bool {
        if view.summary.perception.is_some_and(|p| p.fresh) || view.hal_error.is_some() {
            return false;
        }
        let mut snapshot = Vec::new();
        if !view.runtime.save_snapshot(&mut snapshot) {
            return false;
        }
        let Ok(mut slot) = self.split.lock() else {
            return false;
        };
        if slot.is_some() {
            return false;
        }
        *slot = Some(SplitPoint {
            snapshot,
            last_state: *view.state,
            first_tick: view.summary.tick.index + 1,
        });
        self.split_wanted.store(false, Ordering::Release);
        true
    }

    fn writer_gone(&self) -> bool {
        self.thread.as_ref().is_none_or(|t| t.is_finished())
    }

    /// The writer stopped before it was asked to: a write failed (a full disk, say). Nothing
    /// more reaches the file; [`Logger::finish`] returns the error.
    pub fn writer_failed(&self) -> bool {
        !self.stop.load(Ordering::Acquire) && self.thread.as_ref().is_some_and(|t| t.is_finished())
    }

    /// Drains the pool, writes the summary and closes the file.
    pub fn finish(mut self) -> Result<LogStats, LogError> {
        self.stop.store(true, Ordering::Release);
        let t = self.thread.take().expect("finish runs once");
        let mut stats = t.join().map_err(|_| LogError::WriterPanicked)??;
        stats.dropped_records = self.dropped_total;
        Ok(stats)
    }
}

impl Drop for Logger {
    fn drop(&mut self) {
        // An error path that did not call finish still closes the log properly.
        self.stop.store(true, Ordering::Release);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

type Pool<T> = ArrayQueue<Box<T>>;

/// The writer's side of splitting.
struct Splits {
    bytes: Option<u64>,
    wanted: Arc<AtomicBool>,
    point: Arc<Mutex<Option<SplitPoint>>>,
    base: PathBuf,
    meta: RunMeta,
}

impl Splits {
    /// The next file, opened with the run metadata and the state at the cut.
    fn open(&self, part: u64, point: &SplitPoint) -> Result<McapSink, LogError> {
        let path = split_path(&self.base, part);
        let mut last_state = [0u8; FRAME_CAP];
        sensor_io::unitree_hg::encode_low_state(&point.last_state, &mut last_state);
        let previous = split_path(&self.base, part - 1);
        let entries = BTreeMap::from([
            (split_key::PART.to_string(), part.to_string()),
            (split_key::FIRST_TICK.to_string(), point.first_tick.to_string()),
            (split_key::SNAPSHOT_HEX.to_string(), hex(&point.snapshot)),
            (
                split_key::SNAPSHOT_SHA256.to_string(),
                control::nn::sha256_hex(&point.snapshot),
            ),
            (split_key::LAST_STATE_HEX.to_string(), hex(&last_state)),
            (
                split_key::PREVIOUS.to_string(),
                previous
                    .file_name()
                    .map_or_else(String::new, |n| n.to_string_lossy().into_owned()),
            ),
        ]);
        let file = File::create(&path).map_err(|source| LogError::Create {
            path: path.clone(),
            source,
        })?;
        McapSink::with_split(
            BufWriter::with_capacity(1 << 20, file),
            &path,
            &self.meta,
            Some(entries),
        )
    }
}

/// Lower-case hex of `bytes`.
fn hex(bytes: &[u8]) -> String {
    const DIGITS: &[u8; 16] = b"0123456789abcdef";
    let mut s = String::with_capacity(2 * bytes.len());
    for b in bytes {
        s.push(DIGITS[(b >> 4) as usize] as char);
        s.push(DIGITS[(b & 15) as usize] as char);
    }
    s
}

fn writer_loop(
    mut w: McapSink,
    (free, full): (&Pool<Record>, &Pool<Record>),
    (pfree, pfull): (&Pool<PerceptionRecord>, &Pool<PerceptionRecord>),
    stop: &AtomicBool,
    flushed: &AtomicU64,
    every: u64,
    splits: Splits,
) -> Result<LogStats, LogError> {
    let mut since_flush = 0u64;
    // The files already closed, and how many.
    let mut done = LogStats::default();
    let result = loop {
        // Perception records are pushed right after their tick's record.
        if let Some(p) = pfull.pop() {
            let r = w.perception(&p);
            let _ = pfree.push(p);
            if let Err(e) = r {
                break Err(e);
            }
        }
        match full.pop() {
            Some(rec) => {
                let r = w.record(&rec);
                let last_tick = rec.summary.tick.index;
                let split_after = rec.split_after;
                let _ = free.push(rec);
                if let Err(e) = r {
                    break Err(e);
                }
                since_flush += 1;
                let point = if split_after {
                    splits.point.lock().ok().and_then(|mut p| p.take())
                } else {
                    None
                };
                if let Some(point) = point {
                    // A new file that cannot be opened (a full disk) stops the log; the one open
                    // is finished below with everything up to here.
                    let next = match splits.open(done.files + 1, &point) {
                        Ok(n) => n,
                        Err(e) => break Err(e),
                    };
                    match std::mem::replace(&mut w, next).finish() {
                        Ok(s) => done.add(&s),
                        Err(e) => break Err(e),
                    }
                    since_flush = 0;
                    flushed.store(last_tick + 1, Ordering::Release);
                } else if since_flush >= every {
                    since_flush = 0;
                    if let Err(e) = w.flush() {
                        break Err(e);
                    }
                    flushed.store(last_tick + 1, Ordering::Release);
                    if splits.bytes.is_some_and(|b| w.bytes_on_disk() >= b) {
                        splits.wanted.store(true, Ordering::Release);
                    }
                }
            }
            None if stop.load(Ordering::Acquire) => {
                // The control thread pushes before it sets `stop`, so the queue is drained.
                if full.is_empty() && pfull.is_empty() {
                    break Ok(());
                }
            }
            None => std::thread::sleep(Duration::from_micros(200)),
        }
    };
    // The first error is the one that says why (ENOSPC); finishing a writer that already failed
    // only adds "attempted another write after a write method failed".
    let finished = w.finish().map(|last| {
        done.add(&last);
        done
    });
    match result {
        Err(e) => Err(e),
        Ok(()) => finished,
    }
}

impl LogStats {
    /// Adds another file's totals.
    fn add(&mut self, other: &LogStats) {
        self.records += other.records;
        self.messages += other.messages;
        self.dropped_records += other.dropped_records;
        self.chunks_flushed += other.chunks_flushed;
        self.bytes += other.bytes;
        self.files += 1;
    }
}

/// The MCAP file with its channels.
struct McapSink {
    w: mcap::Writer<BufWriter<File>>,
    path: PathBuf,
    low_state: u16,
    low_cmd: u16,
    lidar_frame: u16,
    json: BTreeMap<&'static str, u16>,
    seq: u32,
    buf: Vec<u8>,
    cmd_bytes: [u8; sensor_io::unitree_hg::LOW_CMD_LEN],
    last_operator: Option<control::operator::OperatorInput>,
    last_mode: Option<Mode>,
    stats: LogStats,
}

impl McapSink {
    fn new(out: BufWriter<File>, path: &Path, meta: &RunMeta) -> Result<Self, LogError> {
        Self::with_split(out, path, meta, None)
    }

    /// A file that continues a split log starts with `split` ([`SPLIT_METADATA`]) after the run's metadata.
    fn with_split(
        out: BufWriter<File>,
        path: &Path,
        meta: &RunMeta,
        split: Option<BTreeMap<String, String>>,
    ) -> Result<Self, LogError> {
        let mk = |source| LogError::Mcap {
            path: path.into(),
            source,
        };
        let opts = mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Lz4))
            .chunk_size(Some(4 << 20))
            // Readers (Foxglove included) decompress whole chunks anyway; per-channel indexes cost ~10 %.
            .emit_message_indexes(false)
            .profile("")
            .library(format!("g1fw {}", env!("CARGO_PKG_VERSION")));
        let mut w = opts.create(out).map_err(mk)?;
        // Metadata first, outside any chunk: a reader finds it even in a crash-truncated file.
        w.write_metadata(&mcap::records::Metadata {
            name: ch::RUN_METADATA.into(),
            metadata: meta.entries.clone(),
        })
        .map_err(mk)?;
        if let Some(entries) = split {
            w.write_metadata(&mcap::records::Metadata {
                name: SPLIT_METADATA.into(),
                metadata: entries,
            })
            .map_err(mk)?;
        }
        let none = BTreeMap::new();
        let s = w
            .add_schema("g1fw/msg/LowStateFrame", "ros2msg", ch::LOW_STATE_MSG.as_bytes())
            .map_err(mk)?;
        let low_state = w.add_channel(s, ch::LOW_STATE, "cdr", &none).map_err(mk)?;
        let s = w
            .add_schema("g1fw/msg/LowCmdFrame", "ros2msg", ch::LOW_CMD_MSG.as_bytes())
            .map_err(mk)?;
        let low_cmd = w.add_channel(s, ch::LOW_CMD, "cdr", &none).map_err(mk)?;
        let s = w
            .add_schema(ch::LIDAR_FRAME_SCHEMA, "ros2msg", ch::LIDAR_FRAME_MSG.as_bytes())
            .map_err(mk)?;
        let lidar_frame = w.add_channel(s, ch::LIDAR_FRAME, "cdr", &none).map_err(mk)?;
        let mut json = BTreeMap::new();
        for &(topic, name, schema) in ch::JSON_CHANNELS {
            let s = w.add_schema(name, "jsonschema", schema.as_bytes()).map_err(mk)?;
            json.insert(topic, w.add_channel(s, topic, "json", &none).map_err(mk)?);
        }
        // Foxglove's own schemas by name, so its 3D panel draws the cloud and the grid.
        for (topic, name, schema) in [
            (ch::LIDAR_POINTS, "foxglove.PointCloud", ch::point_cloud_schema()),
            (ch::PERCEPTION_BEV, "foxglove.Grid", ch::grid_schema()),
        ] {
            let s = w.add_schema(name, "jsonschema", schema.as_bytes()).map_err(mk)?;
            json.insert(topic, w.add_channel(s, topic, "json", &none).map_err(mk)?);
        }
        Ok(Self {
            w,
            path: path.into(),
            low_state,
            low_cmd,
            lidar_frame,
            json,
            seq: 0,
            buf: Vec::with_capacity(8192),
            cmd_bytes: [0; sensor_io::unitree_hg::LOW_CMD_LEN],
            last_operator: None,
            last_mode: None,
            stats: LogStats::default(),
        })
    }

    fn err(&self, source: mcap::McapError) -> LogError {
        LogError::Mcap {
            path: self.path.clone(),
            source,
        }
    }

    fn put(&mut self, channel: u16, time_ns: u64) -> Result<(), LogError> {
        self.seq = self.seq.wrapping_add(1);
        let header = mcap::records::MessageHeader {
            channel_id: channel,
            sequence: self.seq,
            log_time: time_ns,
            publish_time: time_ns,
        };
        self.stats.messages += 1;
        let r = self.w.write_to_known_channel(&header, &self.buf);
        r.map_err(|e| self.err(e))
    }

    fn put_json(&mut self, topic: &'static str, time_ns: u64, value: &impl Serialize) -> Result<(), LogError> {
        self.buf.clear();
        serde_json::to_writer(&mut self.buf, value).expect("serializing to memory cannot fail");
        let id = self.json[topic];
        self.put(id, time_ns)
    }

    fn record(&mut self, r: &Record) -> Result<(), LogError> {
        let s = &r.summary;
        let (k, t) = (s.tick.index, s.tick.time_ns);
        self.stats.records += 1;

        encode_low_state_frame(
            &mut self.buf,
            k,
            t,
            s.frame.code(),
            r.frame_received,
            &r.frame[..r.frame_len],
        );
        self.put(self.low_state, t)?;
        sensor_io::unitree_hg::encode_low_cmd(&r.command, &mut self.cmd_bytes);
        let cmd = self.cmd_bytes;
        encode_low_cmd_frame(&mut self.buf, k, t, r.command_sent, &cmd);
        self.put(self.low_cmd, t)?;

        if let Some(f) = r.hal_error {
            self.put_json(
                ch::HAL_EVENT,
                t,
                &HalEventMsg {
                    tick: k,
                    kind: format!("{:?}", f.kind),
                    phase: if f.in_write { "write" } else { "wait" },
                },
            )?;
        }
        if self.last_operator != Some(s.operator) {
            self.last_operator = Some(s.operator);
            let o = s.operator;
            let rx = s.command_received;
            self.put_json(
                ch::OPERATOR,
                t,
                &OperatorMsg {
                    tick: k,
                    vx: o.velocity[0],
                    vy: o.velocity[1],
                    wz: o.velocity[2],
                    received: rx,
                    estop: o.estop,
                    reset: o.reset,
                    request: o.request.map(|r| r.name()),
                },
            )?;
        }
        if s.policy_step {
            self.put_json(
                ch::OBSERVATION,
                t,
                &ValuesMsg {
                    tick: k,
                    values: &r.obs[..r.obs_len],
                    target_q: None,
                },
            )?;
            self.put_json(
                ch::ACTION,
                t,
                &ValuesMsg {
                    tick: k,
                    values: &r.action[..r.act_len],
                    target_q: Some(&r.target_q[..]),
                },
            )?;
        }
        let e = s.estimate;
        self.put_json(
            ch::ESTIMATOR,
            t,
            &EstimatorMsg {
                tick: k,
                valid: e.valid,
                attitude_source: match e.attitude_source {
                    estimator::AttitudeSource::None => "none",
                    estimator::AttitudeSource::Imu => "imu",
                    estimator::AttitudeSource::Filter => "filter",
                },
                projected_gravity: Xyz::from(e.projected_gravity),
                rpy: Rpy {
                    roll: e.rpy[0],
                    pitch: e.rpy[1],
                    yaw: e.rpy[2],
                },
                lin_vel_body: Xyz::from(e.lin_vel_body),
                lin_vel_world: Xyz::from(e.lin_vel_world),
                ang_vel_body: Xyz::from(e.ang_vel_body),
                lin_vel_std: Xyz::from(e.lin_vel_std),
                position: Xyz::from(e.position),
                height: e.position[2],
                height_std: e.height_std,
                foot_left: Xyz::from(e.foot_pos[0]),
                foot_right: Xyz::from(e.foot_pos[1]),
                contact: e.contact,
                contact_force_n: e.contact_force,
                sole_height: e.sole_height,
            },
        )?;
        self.record_safety(r)?;
        let tm = s.timing;
        self.put_json(
            ch::TIMING,
            t,
            &TimingMsg {
                tick: k,
                fast_ns: tm.fast_ns,
                perception_ns: tm.perception_ns,
                policy_ns: tm.policy_ns,
                overruns: s.overruns,
            },
        )?;
        if let Some(tr) = &r.truth {
            self.record_truth(tr, k, t)?;
        }
        Ok(())
    }

    /// `/safety/state` at 50 Hz and on every change of mode; `/safety/event` on trips and resets.
    fn record_safety(&mut self, r: &Record) -> Result<(), LogError> {
        let s = &r.summary;
        let (k, t) = (s.tick.index, s.tick.time_ns);
        if k.is_multiple_of(10) || self.last_mode != Some(s.mode) || r.dropped_before > 0 {
            self.last_mode = Some(s.mode);
            let c = s.counters;
            self.put_json(
                ch::SAFETY_STATE,
                t,
                &SafetyMsg {
                    tick: k,
                    mode: mode_name(s.mode),
                    reason: match s.mode {
                        Mode::Damping(r) => r.to_string(),
                        _ => String::new(),
                    },
                    frame: s.frame.code(),
                    crc_failures: c.crc_failures,
                    crc_streak: c.crc_streak,
                    missing_frames: c.missing_frames,
                    stale_frames: c.stale_frames,
                    state_age_ticks: c.state_age_ticks,
                    clamped_targets: s.clamped_targets,
                    envelope_range_clamps: s.envelope.range_clamps,
                    envelope_violations: s.envelope.violations,
                    dropped_log_records: r.dropped_before,
                },
            )?;
        }
        if let Some(reason) = s.tripped {
            tracing::warn!(tick = k, reason = %reason, "safety: damping latched");
            self.put_json(
                ch::SAFETY_EVENT,
                t,
                &SafetyEventMsg {
                    tick: k,
                    time_s: t as f64 * 1e-9,
                    event: "trip",
                    reason: reason.name(),
                    joint: reason.slot().map_or("", |s| hal::G1_MOTOR_NAMES[s as usize]),
                    detail: s.envelope_violation.map(|v| v.to_string()).unwrap_or_default(),
                },
            )?;
        }
        if s.reset {
            self.put_json(
                ch::SAFETY_EVENT,
                t,
                &SafetyEventMsg {
                    tick: k,
                    time_s: t as f64 * 1e-9,
                    event: "reset",
                    reason: "operator",
                    joint: "",
                    detail: String::new(),
                },
            )?;
        }
        Ok(())
    }

    /// The simulator's ground truth of the tick (`/sim/truth`).
    fn record_truth(&mut self, tr: &GroundTruth, k: u64, t: u64) -> Result<(), LogError> {
        self.put_json(
            ch::TRUTH,
            t,
            &TruthMsg {
                tick: k,
                base_pos: Xyz64::from(tr.base_pos),
                base_quat: Quat {
                    w: tr.base_quat[0],
                    x: tr.base_quat[1],
                    y: tr.base_quat[2],
                    z: tr.base_quat[3],
                },
                lin_vel_body: Xyz64::from(tr.base_lin_vel_body),
                ang_vel_body: Xyz64::from(tr.base_ang_vel_body),
                foot_contact: tr.foot_contact,
                stairs: tr.stairs.map(|p| StairsMsg {
                    axis_s: p.axis_s,
                    risers: p.risers,
                    risers_passed: p.risers_passed,
                    on_end_landing: p.on_end_landing,
                }),
            },
        )?;
        Ok(())
    }

    /// `/lidar/frame`, `/lidar/points`, `/perception/bev`, `/perception/terrain`.
    fn perception(&mut self, p: &PerceptionRecord) -> Result<(), LogError> {
        use base64::Engine as _;
        let (k, t) = (p.tick, p.time_ns);
        encode_lidar_frame(&mut self.buf, k, &p.frame);
        self.put(self.lidar_frame, t)?;
        let stamp = Stamp {
            sec: (t / 1_000_000_000) as u32,
            nsec: (t % 1_000_000_000) as u32,
        };
        let mut bytes = Vec::with_capacity(p.n * 16);
        for q in &p.points[..p.n] {
            for v in q {
                bytes.extend_from_slice(&v.to_le_bytes());
            }
        }
        let f32_field = |name: &'static str, offset: u32| Field {
            name,
            offset,
            r#type: 7,
        };
        self.put_json(
            ch::LIDAR_POINTS,
            t,
            &PointCloudMsg {
                timestamp: stamp,
                frame_id: ch::ROBOT_FRAME_ID,
                pose: Pose::IDENTITY,
                point_stride: 16,
                fields: [
                    f32_field("x", 0),
                    f32_field("y", 4),
                    f32_field("z", 8),
                    f32_field("intensity", 12),
                ],
                data: base64::engine::general_purpose::STANDARD.encode(&bytes),
            },
        )?;
        // foxglove.Grid: column = ix (x), row = iy (y), six float32 fields per cell.
        bytes.clear();
        for iy in 0..BEV_CELLS {
            for ix in 0..BEV_CELLS {
                for c in 0..BEV_CHANNELS {
                    bytes.extend_from_slice(&p.grid.get(c, ix, iy).to_le_bytes());
                }
            }
        }
        let mut fields = [f32_field("", 0); BEV_CHANNELS];
        for (c, f) in fields.iter_mut().enumerate() {
            *f = f32_field(CHANNEL_NAMES[c], 4 * c as u32);
        }
        self.put_json(
            ch::PERCEPTION_BEV,
            t,
            &GridMsg {
                timestamp: stamp,
                frame_id: ch::ROBOT_FRAME_ID,
                pose: Pose {
                    position: Xyz64 {
                        x: -BEV_HALF_EXTENT_M as f64,
                        y: -BEV_HALF_EXTENT_M as f64,
                        z: 0.0,
                    },
                    ..Pose::IDENTITY
                },
                column_count: BEV_CELLS as u32,
                cell_size: CellSize {
                    x: BEV_CELL_M as f64,
                    y: BEV_CELL_M as f64,
                },
                row_stride: (BEV_CELLS * BEV_CHANNELS * 4) as u32,
                cell_stride: (BEV_CHANNELS * 4) as u32,
                fields,
                data: base64::engine::general_purpose::STANDARD.encode(&bytes),
            },
        )?;
        let s = &p.summary;
        self.put_json(
            ch::PERCEPTION_TERRAIN,
            t,
            &TerrainMsg {
                tick: k,
                back_tick: p.back_tick,
                class: s.token.class.name(),
                step_height_m: s.token.step_height_m,
                step_depth_m: s.token.step_depth_m,
                yaw_deg: s.token.yaw_rad.to_degrees(),
                source: match s.source {
                    control::spec::TerrainEstimatorKind::Cnn => "cnn",
                    control::spec::TerrainEstimatorKind::Geometric => "geometric",
                },
                held: s.held,
                late: s.late,
                estimate: TokenMsg {
                    class: s.estimate.class.name(),
                    step_height_m: s.estimate.step_height_m,
                    step_depth_m: s.estimate.step_depth_m,
                    yaw_deg: s.estimate.yaw_rad.to_degrees(),
                    confidence: s.confidence,
                },
                geometric: GeometricMsg {
                    class: s.geometric.token.class.name(),
                    step_height_m: s.geometric.token.step_height_m,
                    step_depth_m: s.geometric.token.step_depth_m,
                    yaw_deg: s.geometric.token.yaw_rad.to_degrees(),
                    confidence: s.geometric.confidence,
                    cells_used: s.geometric.cells_used,
                    levels: s.geometric.levels,
                    risers: s.geometric.risers,
                },
                points: s.points,
                frame_timestamp_ns: s.frame_timestamp_ns,
                bev: BevStatsMsg {
                    input: s.bev.input,
                    used: s.bev.used,
                    self_hits: s.bev.self_hits,
                    outside: s.bev.outside,
                    non_finite: s.bev.non_finite,
                },
                memory_keyframes: s.memory_keyframes,
                memory_points: s.memory_points,
                base_height_m: s.base_height,
                roll: s.roll,
                pitch: s.pitch,
            },
        )?;
        if let Some(z) = p.truth {
            self.put_json(
                ch::TRUTH_TERRAIN,
                t,
                &TruthTerrainMsg {
                    tick: k,
                    class: z.class.name(),
                    step_height_m: z.step_height_m,
                    step_depth_m: z.step_depth_m,
                    yaw_deg: z.yaw_rad.to_degrees(),
                },
            )?;
        }
        Ok(())
    }

    fn flush(&mut self) -> Result<(), LogError> {
        self.w.flush().map_err(|e| self.err(e))?;
        self.stats.chunks_flushed += 1;
        Ok(())
    }

    /// The file's size as the OS has it (after a flush: every closed chunk).
    fn bytes_on_disk(&self) -> u64 {
        std::fs::metadata(&self.path).map_or(0, |m| m.len())
    }

    fn finish(mut self) -> Result<LogStats, LogError> {
        self.w.finish().map_err(|e| self.err(e))?;
        let mut out = self.w.into_inner();
        out.flush().map_err(|source| LogError::Io {
            path: self.path.clone(),
            source,
        })?;
        self.stats.bytes = out.get_ref().metadata().map(|m| m.len()).unwrap_or(0);
        Ok(self.stats)
    }
}

pub fn mode_name(m: Mode) -> &'static str {
    match m {
        Mode::Passive => "passive",
        Mode::Startup => "startup",
        Mode::Stand => "stand",
        Mode::Policy => "policy",
        Mode::SitDown => "sit_down",
        Mode::Damping(_) => "damping",
    }
}

#[derive(Serialize, Clone, Copy)]
struct Stamp {
    sec: u32,
    nsec: u32,
}

#[derive(Serialize, Clone, Copy)]
struct Orientation {
    x: f64,
    y: f64,
    z: f64,
    w: f64,
}

#[derive(Serialize, Clone, Copy)]
struct Pose {
    position: Xyz64,
    orientation: Orientation,
}

impl Pose {
    const IDENTITY: Pose = Pose {
        position: Xyz64 { x: 0.0, y: 0.0, z: 0.0 },
        orientation: Orientation {
            x: 0.0,
            y: 0.0,
            z: 0.0,
            w: 1.0,
        },
    };
}

#[derive(Serialize, Clone, Copy)]
struct Field {
    name: &'static str,
    offset: u32,
    /// foxglove.PackedElementField numeric type (7 = FLOAT32).
    r#type: u8,
}

#[derive(Serialize)]
struct PointCloudMsg {
    timestamp: Stamp,
    frame_id: &'static str,
    pose: Pose,
    point_stride: u32,
    fields: [Field; 4],
    data: String,
}

#[derive(Serialize, Clone, Copy)]
struct CellSize {
    x: f64,
    y: f64,
}

#[derive(Serialize)]
struct GridMsg {
    timestamp: Stamp,
    frame_id: &'static str,
    pose: Pose,
    column_count: u32,
    cell_size: CellSize,
    row_stride: u32,
    cell_stride: u32,
    fields: [Field; BEV_CHANNELS],
    data: String,
}

#[derive(Serialize)]
struct GeometricMsg {
    class: &'static str,
    step_height_m: f32,
    step_depth_m: f32,
    yaw_deg: f32,
    confidence: f32,
    cells_used: u32,
    levels: u32,
    risers: u32,
}

#[derive(Serialize)]
struct TerrainMsg {
    tick: u64,
    /// The tick the result came back: replay of a late threaded step keeps perception away until
    /// then, as it was live.
    back_tick: u64,
    class: &'static str,
    step_height_m: f32,
    step_depth_m: f32,
    yaw_deg: f32,
    source: &'static str,
    held: bool,
    /// Threaded perception: ready after its due tick, so the policy did not get this token.
    late: bool,
    /// This frame's estimate by `source` (the token above is it, unless held).
    estimate: TokenMsg,
    /// Details of the geometric estimator (zeros when the CNN is the source).
    geometric: GeometricMsg,
    points: u32,
    frame_timestamp_ns: u64,
    bev: BevStatsMsg,
    /// BEV memory: keyframes held and remembered points in the grid.
    memory_keyframes: u32,
    memory_points: u32,
    base_height_m: f32,
    roll: f32,
    pitch: f32,
}

#[derive(Serialize)]
struct TokenMsg {
    class: &'static str,
    step_height_m: f32,
    step_depth_m: f32,
    yaw_deg: f32,
    confidence: f32,
}

#[derive(Serialize)]
struct BevStatsMsg {
    input: usize,
    used: usize,
    self_hits: usize,
    outside: usize,
    non_finite: usize,
}

#[derive(Serialize)]
struct TruthTerrainMsg {
    tick: u64,
    class: &'static str,
    step_height_m: f32,
    step_depth_m: f32,
    yaw_deg: f32,
}

#[derive(Serialize)]
struct HalEventMsg {
    tick: u64,
    kind: String,
    phase: &'static str,
}

#[derive(Serialize)]
struct OperatorMsg {
    tick: u64,
    vx: f32,
    vy: f32,
    wz: f32,
    /// vx, vy, wz as the policy receives them (clamped to the spec's `[commands]`).
    received: [f32; 3],
    estop: bool,
    reset: bool,
    /// An operated run's request this tick.
    #[serde(skip_serializing_if = "Option::is_none")]
    request: Option<&'static str>,
}

#[derive(Serialize)]
struct ValuesMsg<'a> {
    tick: u64,
    values: &'a [f32],
    #[serde(skip_serializing_if = "Option::is_none")]
    target_q: Option<&'a [f32]>,
}

#[derive(Serialize)]
struct Xyz {
    x: f32,
    y: f32,
    z: f32,
}

impl From<[f32; 3]> for Xyz {
    fn from(v: [f32; 3]) -> Self {
        Self {
            x: v[0],
            y: v[1],
            z: v[2],
        }
    }
}

#[derive(Serialize, Clone, Copy)]
struct Xyz64 {
    x: f64,
    y: f64,
    z: f64,
}

impl From<[f64; 3]> for Xyz64 {
    fn from(v: [f64; 3]) -> Self {
        Self {
            x: v[0],
            y: v[1],
            z: v[2],
        }
    }
}

#[derive(Serialize)]
struct Quat {
    w: f64,
    x: f64,
    y: f64,
    z: f64,
}

#[derive(Serialize)]
struct Rpy {
    roll: f32,
    pitch: f32,
    yaw: f32,
}

#[derive(Serialize)]
struct EstimatorMsg {
    tick: u64,
    valid: bool,
    attitude_source: &'static str,
    projected_gravity: Xyz,
    rpy: Rpy,
    lin_vel_body: Xyz,
    lin_vel_world: Xyz,
    ang_vel_body: Xyz,
    lin_vel_std: Xyz,
    position: Xyz,
    height: f32,
    height_std: f32,
    foot_left: Xyz,
    foot_right: Xyz,
    contact: [bool; 2],
    contact_force_n: [f32; 2],
    sole_height: [f32; 2],
}

#[derive(Serialize)]
struct SafetyMsg {
    tick: u64,
    mode: &'static str,
    reason: String,
    frame: u8,
    crc_failures: u64,
    crc_streak: u32,
    missing_frames: u64,
    stale_frames: u64,
    state_age_ticks: u64,
    clamped_targets: u64,
    envelope_range_clamps: u64,
    envelope_violations: u64,
    dropped_log_records: u64,
}

#[derive(Serialize)]
struct SafetyEventMsg {
    tick: u64,
    time_s: f64,
    event: &'static str,
    reason: &'static str,
    joint: &'static str,
    /// What broke the command envelope, for its trips.
    detail: String,
}

#[derive(Serialize)]
struct TimingMsg {
    tick: u64,
    fast_ns: u32,
    perception_ns: u32,
    policy_ns: u32,
    overruns: u8,
}

#[derive(Serialize)]
struct TruthMsg {
    tick: u64,
    base_pos: Xyz64,
    base_quat: Quat,
    lin_vel_body: Xyz64,
    ang_vel_body: Xyz64,
    foot_contact: [bool; 2],
    /// The base's progress on the world's staircase (absent on flat ground).
    #[serde(skip_serializing_if = "Option::is_none")]
    stairs: Option<StairsMsg>,
}

#[derive(Serialize)]
struct StairsMsg {
    axis_s: f64,
    risers: u16,
    risers_passed: u16,
    on_end_landing: bool,
}
