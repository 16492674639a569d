//! `g1fw replay`: feed a log's recorded inputs through the same runtime and compare every output
//! bit for bit.
//!
//! The recorded LowState bytes go through the same decoder the live HAL used ([`ReplayHal`]), the
//! recorded operator input is replayed per tick, and the spec and weights are the ones the log pins
//! by content hash. Compared per tick: the LowCmd bytes (named down to the motor field), the policy
//! step schedule, observation and action values, and safety trips.
//!
//! Perception: the raw lidar frames the recorded run consumed (`/lidar/frame`) are handed back to
//! the runtime on the same ticks ([`FrameSource::read_lidar`]), so the perception group, and the
//! terrain token a policy may observe, are re-computed bit for bit; each re-computed step is
//! compared with the recorded `/perception/terrain`. Logs from before `/lidar/frame` existed still
//! replay (without frames, as then) unless the policy observes the terrain token, which such a log
//! cannot reproduce ([`check_lidar_coverage`]).
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use control::nn::sha256_hex;
use control::runtime::LateStep;
use hal::{ErrorKind, LowCommand, LowLevel, LowState, TickTime, TimeBase};
use sensor_io::unitree_hg::cdr::{low_state_from_cdr, CdrError};
use sensor_io::unitree_hg::{
    decode_low_cmd, decode_low_state, encode_low_cmd_body, DecodeError, UnsealedStamper, LOW_CMD_LEN, LOW_STATE_LEN,
};

use crate::log::channels as ch;
use crate::log::reader::{Damage, LogFile};
use control::controller::Controller;
use control::operator::{OperatorInput, OperatorSource, Request};
use control::perception::{LidarFrame, PerceptionSummary, TerrainSource};
use control::runtime::{run_loop, FrameSource, LoopEnd, Runtime, TickView};
use control::spec::{DeploySpec, ObsKind};
use control::supervisor::FrameStatus;

/// Metadata keys of the run record (see [`crate::log::writer::RunMeta`]).
pub mod key {
    pub const SPEC_PATH: &str = "spec_path";
    pub const SPEC_SHA256: &str = "spec_sha256";
    pub const SPEC_TOML: &str = "spec_toml";
    pub const WEIGHTS_SHA256: &str = "weights_sha256";
    pub const HOLD_ONLY: &str = "hold_only";
    /// "true" when the operator stepped the run through its states (`--operated`); absent in
    /// older logs.
    pub const OPERATED: &str = "operated";
    /// Where an operated run's requests came from: `remote`, `keyboard` or `schedule` (the source
    /// each change of state in `/safety/state` names in the report); absent in older logs.
    pub const OPERATOR: &str = "operator";
    pub const RAMP_S: &str = "ramp_s";
    pub const HOLD_S: &str = "hold_s";
    /// "false" when the run judged no joint as frozen (quantized HALs: CAN).
    pub const FROZEN_CHECK: &str = "frozen_check";
    /// `cnn`, `geometric`, `truth` or `none` (`g1fw sim --terrain-source`); absent in older logs.
    pub const TERRAIN_SOURCE: &str = "terrain_source";
    /// How `/hal/low_state` frames are encoded: absent = unitree_hg's C layout (bridge, CAN);
    /// `cdr` = the DDS sample as it was on the wire (`g1fw run --dds`), converted by
    /// `sensor_io::unitree_hg::cdr` before decoding.
    pub const FRAME_ENCODING: &str = "frame_encoding";
    pub const FRAME_ENCODING_CDR: &str = "cdr";
    /// "true" when `g1fw run --unitree-mujoco` stamped states without a CRC or tick with their
    /// arrival count; replay stamps the logged samples the same way.
    pub const UNITREE_MUJOCO: &str = "unitree_mujoco";
    /// `inline` or `threaded:L` (the perception step on a worker thread, its result consumed L
    /// ticks after the frame); absent in older logs (inline).
    pub const PERCEPTION_EXEC: &str = "perception_exec";
}

#[derive(Clone, Debug, Default)]
pub struct ReplayOptions {
    /// Use this spec file instead of the one the log names (its hash must still match unless
    /// `allow_mismatch`).
    pub spec: Option<PathBuf>,
    /// Use this weights file instead of the spec's.
    pub weights: Option<PathBuf>,
    /// Run even when the spec or weights differ from the pinned hashes (to see where outputs diverge).
    pub allow_mismatch: bool,
}

/// The first output that differs.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Divergence {
    pub tick: u64,
    pub time_s: f64,
    pub channel: String,
    pub field: String,
    pub recorded: String,
    pub replayed: String,
}

impl std::fmt::Display for Divergence {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "first divergence at tick {} (t = {:.3} s), channel {}, field {}: recorded {}, replayed {}",
            self.tick, self.time_s, self.channel, self.field, self.recorded, self.replayed
        )
    }
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct ReplayReport {
    pub log: String,
    pub ticks: u64,
    pub sim_seconds: f64,
    pub wall_seconds: f64,
    pub sim_seconds_per_wall_second: f64,
    /// Seconds spent reading and decompressing the log (included in `wall_seconds`).
    pub load_seconds: f64,
    pub compared_commands: u64,
    pub compared_policy_steps: u64,
    /// Recorded lidar frames (`/lidar/frame`) handed to the perception group.
    pub perception_frames_fed: u64,
    /// Perception steps whose re-computed terrain estimate matched the recorded one bit for bit.
    pub compared_perception_steps: u64,
    pub truncated: Option<String>,
    /// The log fails a check (CRC, LZ4 checksum, structure): only the ticks before the damage were
    /// replayed, and the replay is not a pass whatever it compared.
    pub damaged: Option<Damage>,
    pub divergence: Option<Divergence>,
    pub notes: Vec<String>,
    /// Ticks per wall-second of the re-execution alone (after the log is loaded), as sim-s/wall-s.
    pub run_sim_seconds_per_wall_second: f64,
    /// Fast group and whole-tick compute during the replay.
    pub fast_group_us: control::runtime::LatencySummary,
    pub tick_compute_us: control::runtime::LatencySummary,
}

/// One recorded tick.
#[derive(Clone, Debug, Default)]
struct RecTick {
    tick: TickTime,
    status: u8,
    received: bool,
    frame: std::ops::Range<usize>,
    /// Range of the recorded LowCmd bytes in `Recording::cmds`.
    cmd: Option<std::ops::Range<usize>>,
    cmd_sent: bool,
    hal_error: Option<(ErrorKind, bool)>,
    operator: OperatorInput,
    obs: Option<std::ops::Range<usize>>,
    action: Option<std::ops::Range<usize>>,
    trip: Option<String>,
}

struct Recording {
    ticks: Vec<RecTick>,
    frames: Vec<u8>,
    cmds: Vec<u8>,
    values: Vec<f32>,
    /// `/lidar/frame` messages by tick (sorted; ranges into `lidar_bytes`, validated at load).
    lidar: Vec<(u64, std::ops::Range<usize>)>,
    lidar_bytes: Vec<u8>,
    /// `/perception/terrain` by tick (sorted).
    terrain: Vec<(u64, RecTerrain)>,
    truncated: Option<String>,
    damaged: Option<Damage>,
    period_ns: u64,
}

/// A recorded token or estimate (`null`: not finite).
#[derive(Clone, Debug, serde::Deserialize)]
struct RecToken {
    class: String,
    step_height_m: Option<f32>,
    step_depth_m: Option<f32>,
    yaw_deg: Option<f32>,
}

/// The parts of a `/perception/terrain` message replay compares.
#[derive(Clone, Debug, serde::Deserialize)]
struct RecTerrain {
    tick: u64,
    /// Threaded perception: the result was not ready when due (its token was not used).
    #[serde(default)]
    late: bool,
    /// The tick the result came back (absent in logs written before it was recorded).
    #[serde(default)]
    back_tick: Option<u64>,
    #[serde(flatten)]
    token: RecToken,
    held: bool,
    estimate: RecEstimate,
    points: u32,
    frame_timestamp_ns: u64,
    base_height_m: Option<f32>,
    roll: Option<f32>,
    pitch: Option<f32>,
}

#[derive(Clone, Debug, serde::Deserialize)]
struct RecEstimate {
    #[serde(flatten)]
    token: RecToken,
    confidence: Option<f32>,
}

/// The threaded steps the log marks late, with the tick each came back where the log has it.
fn late_steps(terrain: &[(u64, RecTerrain)]) -> Vec<LateStep> {
    terrain
        .iter()
        .filter(|(_, r)| r.late)
        .map(|(t, r)| LateStep {
            step_tick: *t,
            back_tick: r.back_tick,
        })
        .collect()
}

/// What replay can do with a log's perception inputs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LidarCoverage {
    /// The recorded run consumed no lidar frame: nothing to feed.
    NoPerception,
    /// `/lidar/frame` is there: frames are fed and perception steps compared.
    Frames,
    /// The run consumed frames but the log lacks `/lidar/frame` (written before it existed); the
    /// policy does not observe the terrain token, so commands still replay (perception does not).
    MissingButUnobserved,
}

/// Decides whether a log whose run consumed `perception_steps` lidar frames (its
/// `/perception/terrain` messages) and holds `lidar_frames` `/lidar/frame` messages can be replayed
/// by a policy that does (`observes_terrain`) or does not observe the terrain token. An error names
/// the missing channel: without the frames the token, and so the commands, cannot be reproduced.
pub fn check_lidar_coverage(
    observes_terrain: bool,
    perception_steps: usize,
    lidar_frames: usize,
) -> std::result::Result<LidarCoverage, String> {
    match (perception_steps, lidar_frames) {
        (_, 1..) => Ok(LidarCoverage::Frames),
        (0, 0) => Ok(LidarCoverage::NoPerception),
        (n, 0) if observes_terrain => Err(format!(
            "cannot reproduce perception: the policy observes terrain_token and the recorded run consumed \
             {n} lidar frames, but the log has no '{}' channel (it was recorded before g1fw logged raw \
             lidar frames, or the channel was removed); its commands cannot be replayed bit-exact",
            ch::LIDAR_FRAME
        )),
        (_, 0) => Ok(LidarCoverage::MissingButUnobserved),
    }
}

fn parse_values(data: &[u8], out: &mut Vec<f32>) -> Option<std::ops::Range<usize>> {
    #[derive(serde::Deserialize)]
    struct V {
        values: Vec<Option<f32>>,
    }
    let v: V = serde_json::from_slice(data).ok()?;
    let start = out.len();
    out.extend(v.values.into_iter().map(|x| x.unwrap_or(f32::NAN)));
    Some(start..out.len())
}

fn load(log: &LogFile) -> Result<Recording> {
    // Sized from the file: roughly one tick per 900 compressed bytes, generously.
    let guess = log.bytes.len() / 300 + 16;
    let mut ticks: Vec<RecTick> = Vec::with_capacity(guess);
    let mut frames = Vec::with_capacity(guess * sensor_io::unitree_hg::LOW_STATE_LEN);
    let mut cmds = Vec::with_capacity(guess * LOW_CMD_LEN);
    let mut values = Vec::new();
    let mut lidar = Vec::new();
    let mut lidar_bytes = Vec::new();
    let mut terrain = Vec::new();
    let mut scratch: Box<LidarFrame> = sensor_io::livox::boxed_point_frame();
    let mut operator = OperatorInput::default();
    let mut bad: Option<String> = None;
    // Messages of one tick share its log time; the LowState message opens a tick.
    let end = log.scan(|topic, _t, data| {
        if bad.is_some() {
            return;
        }
        match topic {
            ch::LOW_STATE => match ch::decode_low_state_frame(data) {
                Some(f) => {
                    let start = frames.len();
                    frames.extend_from_slice(f.data);
                    ticks.push(RecTick {
                        tick: TickTime {
                            index: f.tick,
                            time_ns: f.time_ns,
                        },
                        status: f.status,
                        received: f.received,
                        frame: start..frames.len(),
                        operator,
                        ..Default::default()
                    });
                }
                None => bad = Some("a /hal/low_state message does not decode".into()),
            },
            // Perception messages are keyed by their tick: the writer may put them ahead of that
            // tick's LowState.
            ch::LIDAR_FRAME => match ch::decode_lidar_frame(data, &mut scratch) {
                Ok(h) => {
                    let start = lidar_bytes.len();
                    lidar_bytes.extend_from_slice(data);
                    lidar.push((h.tick, start..lidar_bytes.len()));
                }
                Err(e) => bad = Some(format!("a {} message does not decode: {e}", ch::LIDAR_FRAME)),
            },
            ch::PERCEPTION_TERRAIN => match serde_json::from_slice::<RecTerrain>(data) {
                Ok(t) => terrain.push((t.tick, t)),
                Err(e) => bad = Some(format!("a {} message does not parse: {e}", ch::PERCEPTION_TERRAIN)),
            },
            _ if ticks.is_empty() => {}
            ch::LOW_CMD => match ch::decode_low_cmd_frame(data) {
                Some(c) if c.data.len() == LOW_CMD_LEN => {
                    let t = ticks.last_mut().expect("checked");
                    let start = cmds.len();
                    cmds.extend_from_slice(c.data);
                    t.cmd = Some(start..cmds.len());
                    t.cmd_sent = c.sent;
                }
                _ => bad = Some("a /hal/low_cmd message does not decode".into()),
            },
            ch::OPERATOR => {
                #[derive(serde::Deserialize)]
                struct Op {
                    vx: f32,
                    vy: f32,
                    wz: f32,
                    estop: bool,
                    reset: bool,
                    #[serde(default)]
                    request: Option<String>,
                }
                match serde_json::from_slice::<Op>(data) {
                    Ok(o) => {
                        let request = match o.request.as_deref().map(Request::from_name) {
                            None => None,
                            Some(Some(r)) => Some(r),
                            Some(None) => {
                                bad = Some(format!("an operator message asks for {:?}", o.request));
                                None
                            }
                        };
                        operator = OperatorInput {
                            velocity: [o.vx, o.vy, o.wz],
                            estop: o.estop,
                            reset: o.reset,
                            request,
                        };
                        ticks.last_mut().expect("checked").operator = operator;
                    }
                    Err(e) => bad = Some(format!("an operator message does not parse: {e}")),
                }
            }
            ch::HAL_EVENT => {
                #[derive(serde::Deserialize)]
                struct Ev {
                    kind: String,
                    phase: String,
                }
                if let Ok(e) = serde_json::from_slice::<Ev>(data) {
                    let kind = match e.kind.as_str() {
                        "Disconnected" => ErrorKind::Disconnected,
                        "Timeout" => ErrorKind::Timeout,
                        "Malformed" => ErrorKind::Malformed,
                        "Checksum" => ErrorKind::Checksum,
                        "NonFinite" => ErrorKind::NonFinite,
                        _ => ErrorKind::Other,
                    };
                    ticks.last_mut().expect("checked").hal_error = Some((kind, e.phase == "write"));
                }
            }
            ch::OBSERVATION => ticks.last_mut().expect("checked").obs = parse_values(data, &mut values),
            ch::ACTION => ticks.last_mut().expect("checked").action = parse_values(data, &mut values),
            ch::SAFETY_EVENT => {
                #[derive(serde::Deserialize)]
                struct Ev {
                    event: String,
                    reason: String,
                }
                if let Ok(e) = serde_json::from_slice::<Ev>(data) {
                    if e.event == "trip" {
                        ticks.last_mut().expect("checked").trip = Some(e.reason);
                    }
                }
            }
            _ => {}
        }
    });
    if let Some(b) = bad {
        bail!("{}: {b}", log.path.display());
    }
    // A crash can cut the last tick in half: drop it.
    if ticks.last().is_some_and(|t| t.cmd.is_none()) {
        ticks.pop();
    }
    if ticks.is_empty() {
        match &end.damaged {
            Some(d) => bail!("{} is damaged before its first complete tick: {d}", log.path.display()),
            None => bail!("{} holds no complete control tick", log.path.display()),
        }
    }
    lidar.sort_by_key(|(k, _)| *k);
    terrain.sort_by_key(|(k, _)| *k);
    let period_ns = if ticks.len() > 1 {
        (ticks[1].tick.time_ns - ticks[0].tick.time_ns) / (ticks[1].tick.index - ticks[0].tick.index).max(1)
    } else {
        2_000_000
    };
    Ok(Recording {
        ticks,
        frames,
        cmds,
        values,
        lidar,
        lidar_bytes,
        terrain,
        truncated: end.truncated,
        damaged: end.damaged,
        period_ns,
    })
}

/// Errors a replay HAL reports: decode failures of recorded frames, and recorded link failures.
#[derive(Debug, thiserror::Error)]
pub enum ReplayHalError {
    #[error("recorded frame: {0}")]
    Decode(DecodeError),
    #[error("recorded frame: {0}")]
    Cdr(CdrError),
    #[error("recorded HAL failure ({0:?})")]
    Recorded(ErrorKind),
    #[error("end of the recording")]
    End,
}

// Display carries the inner error's text; no `source` link, so `{:#}` chains print it once.
impl From<CdrError> for ReplayHalError {
    fn from(e: CdrError) -> Self {
        ReplayHalError::Cdr(e)
    }
}

// Display carries the inner error's text; no `source` link, so `{:#}` chains print it once.
impl From<DecodeError> for ReplayHalError {
    fn from(e: DecodeError) -> Self {
        ReplayHalError::Decode(e)
    }
}

impl hal::Error for ReplayHalError {
    fn kind(&self) -> ErrorKind {
        match self {
            ReplayHalError::Decode(e) => hal::Error::kind(e),
            ReplayHalError::Cdr(e) => hal::Error::kind(e),
            ReplayHalError::Recorded(k) => *k,
            ReplayHalError::End => ErrorKind::Disconnected,
        }
    }
}

/// A HAL whose ticks, frames and link failures come from a recording.
struct ReplayHal<'a> {
    rec: &'a Recording,
    next: usize,
    cur: usize,
    state: LowState,
    scratch: LowState,
    unread: bool,
    /// Recorded lidar frames handed out.
    lidar_fed: u64,
    /// Frames are DDS samples (CDR), converted to the C layout before decoding.
    cdr_frames: bool,
    /// Stamp unsealed states with their arrival count, as the run did (`--unitree-mujoco`).
    stamp_unsealed: bool,
    stamper: UnsealedStamper,
    c_frame: [u8; LOW_STATE_LEN],
}

impl TimeBase for ReplayHal<'_> {
    type Error = ReplayHalError;
    fn wait_tick(&mut self) -> Result<TickTime, ReplayHalError> {
        let t = self.rec.ticks.get(self.next).ok_or(ReplayHalError::End)?;
        if let Some((kind, false)) = t.hal_error {
            return Err(ReplayHalError::Recorded(kind));
        }
        self.cur = self.next;
        self.next += 1;
        self.unread = true;
        Ok(t.tick)
    }
    fn period_ns(&self) -> u64 {
        self.rec.period_ns
    }
}

impl LowLevel for ReplayHal<'_> {
    type Error = ReplayHalError;
    fn read_state(&mut self, out: &mut LowState) -> Result<bool, ReplayHalError> {
        let t = &self.rec.ticks[self.cur];
        let unread = std::mem::take(&mut self.unread);
        // A link fault the HAL reported instead of a frame (a second `rt/lowcmd` writer): decoding
        // cannot give it back, the record can.
        if let Some(FrameStatus::Bad(kind)) = FrameStatus::from_code(t.status) {
            if unread && matches!(kind, ErrorKind::Other | ErrorKind::Timeout | ErrorKind::Disconnected) {
                *out = self.state;
                return Err(ReplayHalError::Recorded(kind));
            }
        }
        let fresh = unread && t.received;
        let result = if fresh {
            let frame = &self.rec.frames[t.frame.clone()];
            let decoded = if self.cdr_frames {
                low_state_from_cdr(frame, &mut self.c_frame)
                    .map_err(ReplayHalError::from)
                    .and_then(|()| {
                        if self.stamp_unsealed {
                            self.stamper.stamp(&mut self.c_frame);
                        }
                        Ok(decode_low_state(&self.c_frame, &mut self.scratch)?)
                    })
            } else {
                decode_low_state(frame, &mut self.scratch).map_err(ReplayHalError::from)
            };
            match decoded {
                Ok(()) => {
                    self.state = self.scratch;
                    Ok(true)
                }
                Err(e) => Err(e),
            }
        } else {
            Ok(false)
        };
        *out = self.state;
        result
    }
    fn write_command(&mut self, _cmd: &LowCommand) -> Result<(), ReplayHalError> {
        match self.rec.ticks[self.cur].hal_error {
            Some((kind, true)) => Err(ReplayHalError::Recorded(kind)),
            _ => Ok(()),
        }
    }
}

impl FrameSource for ReplayHal<'_> {
    fn received_frame(&self) -> Option<&[u8]> {
        let t = &self.rec.ticks[self.cur];
        t.received.then(|| &self.rec.frames[t.frame.clone()])
    }
    /// The frame the recorded run consumed on this tick, if it consumed one.
    fn read_lidar(&mut self, out: &mut LidarFrame) -> bool {
        let k = self.rec.ticks[self.cur].tick.index;
        let Ok(i) = self.rec.lidar.binary_search_by_key(&k, |(t, _)| *t) else {
            return false;
        };
        // Validated at load; cannot fail.
        let fed = ch::decode_lidar_frame(&self.rec.lidar_bytes[self.rec.lidar[i].1.clone()], out).is_ok();
        self.lidar_fed += fed as u64;
        fed
    }
}

struct RecordedOperator<'a> {
    rec: &'a Recording,
    i: usize,
}

impl OperatorSource for RecordedOperator<'_> {
    fn at(&mut self, tick: TickTime) -> OperatorInput {
        // Ticks are replayed in order; find this one's entry.
        while self.i + 1 < self.rec.ticks.len() && self.rec.ticks[self.i].tick.index < tick.index {
            self.i += 1;
        }
        self.rec.ticks[self.i].operator
    }
}

/// Finds the spec the log names: as recorded (absolute, or relative to the current directory), or
/// relative to any directory above the log (a corpus committed inside the repository).
fn locate_spec(recorded: &str, log_path: &Path) -> Option<PathBuf> {
    let p = PathBuf::from(recorded);
    if p.is_file() {
        return Some(p);
    }
    if p.is_relative() {
        let dir = std::fs::canonicalize(log_path).ok()?;
        for anc in dir.ancestors().skip(1) {
            let c = anc.join(&p);
            if c.is_file() {
                return Some(c);
            }
        }
    }
    None
}

fn meta_get<'a>(meta: &'a BTreeMap<String, String>, k: &str) -> Result<&'a str> {
    meta.get(k)
        .map(String::as_str)
        .with_context(|| format!("the log's run metadata lacks '{k}'"))
}

/// Replays `log_path`; returns the report (with `divergence` set on the first mismatch).
pub fn replay(log_path: &Path, opts: &ReplayOptions) -> Result<ReplayReport> {
    let wall = Instant::now();
    let log = LogFile::open(log_path)?;
    // A replay that ran reports damage from its own scan (`damaged`). One that failed first (a spec
    // mismatch, a bad metadata value) may have failed on damage that only the data-section CRC at
    // the end reveals: then every check is run, and the error says so.
    replay_log(wall, log_path, &log, opts).map_err(|e| match log.scan(|_, _, _| {}).damaged {
        Some(d) => e.context(format!("log {} is damaged: {d}", log_path.display())),
        None => e,
    })
}

/// The controller the log was recorded with: the spec pinned in the log (or `--spec`, which must hash
/// the same), the weights it names (or `--weights`), the start-up and terrain source of the run. A
/// mismatch allowed by `--allow-mismatch` becomes a note.
fn controller_from_log(
    meta: &std::collections::BTreeMap<String, String>,
    log_path: &Path,
    opts: &ReplayOptions,
    notes: &mut Vec<String>,
) -> Result<(Controller, Option<TerrainSource>)> {
    // The spec: the text pinned in the log, located where the log says (relative weights paths
    // resolve against it), or an explicit override that must hash the same.
    let pinned_spec_sha = meta_get(meta, key::SPEC_SHA256)?;
    let (spec_text, spec_path) = match &opts.spec {
        Some(p) => {
            let text = control::read_text_capped(p, control::spec::MAX_SPEC_BYTES as u64)
                .with_context(|| format!("reading spec {}", p.display()))?;
            (text, p.clone())
        }
        None => {
            let recorded = meta_get(meta, key::SPEC_PATH)?;
            let text = meta_get(meta, key::SPEC_TOML)?.to_string();
            let path = locate_spec(recorded, log_path).with_context(|| {
                format!(
                    "the log was recorded with spec '{recorded}', which is not found relative to the current \
                     directory or above the log; pass --spec PATH"
                )
            })?;
            (text, path)
        }
    };
    let spec_sha = sha256_hex(spec_text.as_bytes());
    if spec_sha != pinned_spec_sha {
        let msg = format!(
            "spec {} has sha256 {spec_sha}, but the log pins {pinned_spec_sha}",
            spec_path.display()
        );
        if !opts.allow_mismatch {
            bail!("{msg}; pass --allow-mismatch to replay anyway and see where outputs diverge");
        }
        notes.push(msg);
    }
    let mut spec = DeploySpec::from_toml(&spec_text, &spec_path)?;
    if let Some(w) = &opts.weights {
        spec.policy.weights = std::path::absolute(w).with_context(|| format!("resolving {}", w.display()))?;
    }
    if let (Some(r), Some(h)) = (meta.get(key::RAMP_S), meta.get(key::HOLD_S)) {
        spec.startup.ramp_s = r.parse().context("metadata ramp_s")?;
        spec.startup.hold_s = h.parse().context("metadata hold_s")?;
    }
    let terrain_source = match meta.get(key::TERRAIN_SOURCE) {
        None => None,
        Some(v) => Some(
            v.parse::<TerrainSource>()
                .map_err(|e| anyhow::anyhow!("the log's metadata terrain_source: {e}"))?,
        ),
    };
    if terrain_source == Some(TerrainSource::Truth) {
        bail!(
            "{} was recorded with --terrain-source truth (the evaluation ablation that feeds the \
             simulator's ground-truth token to the policy); replay has no simulator, so it cannot \
             re-run it. Record with --terrain-source cnn|geometric|none to get a replayable log",
            log_path.display()
        );
    }
    if let Some(k) = terrain_source.and_then(TerrainSource::estimator) {
        spec.perception.terrain_estimator = k;
    }
    let hold_only = meta.get(key::HOLD_ONLY).is_some_and(|v| v == "true");
    let mut controller = if hold_only {
        Controller::hold_only(spec)
    } else {
        Controller::new(spec)?
    };
    if meta.get(key::OPERATED).is_some_and(|v| v == "true") {
        controller.operate();
    }
    let pinned_w = meta_get(meta, key::WEIGHTS_SHA256)?;
    if controller.weights_sha256() != pinned_w {
        let msg = format!(
            "weights {} have sha256 {}, but the log pins {pinned_w}",
            controller.spec().weights_path().display(),
            controller.weights_sha256()
        );
        if !opts.allow_mismatch {
            bail!("{msg}; pass --allow-mismatch to replay anyway and see where outputs diverge");
        }
        notes.push(msg);
    }
    Ok((controller, terrain_source))
}

/// Restores the runtime's state from a split file's [`crate::log::writer::SPLIT_METADATA`]
/// (checked against its sha256, and against this runtime's spec by every length), and returns the
/// last LowState the recorded loop held.
fn restore_split(rt: &mut Runtime, split: &BTreeMap<String, String>, log_path: &Path) -> Result<LowState> {
    use crate::log::writer::split_key as k;
    let get = |key: &str| {
        split
            .get(key)
            .with_context(|| format!("{}: the split record lacks '{key}'", log_path.display()))
    };
    let snapshot =
        unhex(get(k::SNAPSHOT_HEX)?).with_context(|| format!("{}: {}", log_path.display(), k::SNAPSHOT_HEX))?;
    if sha256_hex(&snapshot) != *get(k::SNAPSHOT_SHA256)? {
        bail!(
            "{}: the runtime state it starts from does not match its sha256 (the file is damaged)",
            log_path.display()
        );
    }
    rt.restore_snapshot(&snapshot).map_err(|e| {
        anyhow::anyhow!(
            "{}: the runtime state it starts from does not fit this spec and g1fw: {e}",
            log_path.display()
        )
    })?;
    let bytes =
        unhex(get(k::LAST_STATE_HEX)?).with_context(|| format!("{}: {}", log_path.display(), k::LAST_STATE_HEX))?;
    let frame: [u8; LOW_STATE_LEN] = bytes.as_slice().try_into().map_err(|_| {
        anyhow::anyhow!(
            "{}: the last state is {} bytes, not {LOW_STATE_LEN}",
            log_path.display(),
            bytes.len()
        )
    })?;
    let mut state = LowState::default();
    decode_low_state(&frame, &mut state).with_context(|| format!("{}: the last state", log_path.display()))?;
    Ok(state)
}

/// Bytes from lower- or upper-case hex.
fn unhex(text: &str) -> Result<Vec<u8>> {
    let digit = |c: u8| match c {
        b'0'..=b'9' => Ok(c - b'0'),
        b'a'..=b'f' => Ok(c - b'a' + 10),
        b'A'..=b'F' => Ok(c - b'A' + 10),
        _ => Err(anyhow::anyhow!("'{}' is not a hex digit", c as char)),
    };
    let b = text.as_bytes();
    if !b.len().is_multiple_of(2) {
        bail!("an odd number of hex digits ({})", b.len());
    }
    b.chunks_exact(2)
        .map(|p| Ok(digit(p[0])? << 4 | digit(p[1])?))
        .collect()
}

fn replay_log(wall: Instant, log_path: &Path, log: &LogFile, opts: &ReplayOptions) -> Result<ReplayReport> {
    let meta = log.run_metadata()?;
    let mut notes = Vec::new();

    let (controller, terrain_source) = controller_from_log(&meta, log_path, opts, &mut notes)?;

    let rec = load(log)?;
    let observes_terrain = controller
        .spec()
        .observation
        .terms
        .iter()
        .any(|t| t.kind == ObsKind::TerrainToken);
    let coverage = check_lidar_coverage(observes_terrain, rec.terrain.len(), rec.lidar.len())
        .map_err(|e| anyhow::anyhow!("{}: {e}", log_path.display()))?;
    if coverage == LidarCoverage::MissingButUnobserved {
        notes.push(format!(
            "the log has no {} (recorded before g1fw logged raw lidar frames): the perception group ran \
             without frames and its {} recorded steps were not compared; the policy does not observe the \
             terrain token, so commands still compare",
            ch::LIDAR_FRAME,
            rec.terrain.len()
        ));
    }
    let load_seconds = wall.elapsed().as_secs_f64();
    let mut rt = Runtime::new(controller);
    if let Some(src) = terrain_source {
        rt.set_terrain_source(src);
    }
    if meta.get(key::FROZEN_CHECK).is_some_and(|v| v == "false") {
        rt.disable_frozen_check();
    }
    match meta.get(key::PERCEPTION_EXEC).map(String::as_str) {
        None | Some("inline") => {}
        Some(label) => match control::perception_worker::PerceptionExec::parse(label, true) {
            Ok(control::perception_worker::PerceptionExec::Threaded { consume_after, .. }) => {
                rt.set_perception_replay(consume_after, late_steps(&rec.terrain));
            }
            _ => bail!(
                "the log's {} '{label}' is not one this g1fw knows",
                key::PERCEPTION_EXEC
            ),
        },
    }
    // A file that continues a split log starts from the state the run had at the cut.
    let mut start_state = LowState::default();
    if let Some(split) = log.metadata(crate::log::writer::SPLIT_METADATA) {
        start_state = restore_split(&mut rt, &split, log_path)?;
        let first = split
            .get(crate::log::writer::split_key::FIRST_TICK)
            .cloned()
            .unwrap_or_default();
        notes.push(format!(
            "part {} of a split log: started from the state the run had before tick {first}",
            split
                .get(crate::log::writer::split_key::PART)
                .map_or("?", String::as_str)
        ));
    }
    let mut hal = ReplayHal {
        rec: &rec,
        next: 0,
        cur: 0,
        state: start_state,
        scratch: LowState::default(),
        unread: false,
        lidar_fed: 0,
        cdr_frames: meta
            .get(key::FRAME_ENCODING)
            .is_some_and(|v| v == key::FRAME_ENCODING_CDR),
        stamp_unsealed: meta.get(key::UNITREE_MUJOCO).is_some_and(|v| v == "true"),
        stamper: UnsealedStamper::default(),
        c_frame: [0; LOW_STATE_LEN],
    };
    let mut op = RecordedOperator { rec: &rec, i: 0 };
    let last = rec.ticks.last().expect("non-empty");
    // A run that ended normally did not send its final command; one that stopped early (a fall, a
    // crash cutting the log) did, so the loop must not treat that tick as final.
    let last_tick = last.tick.index + last.cmd_sent as u64;
    let mut cmp = Comparator {
        rec: &rec,
        i: 0,
        bytes: [0; LOW_CMD_LEN],
        divergence: None,
        commands: 0,
        policy_steps: 0,
        compare_perception: coverage == LidarCoverage::Frames,
        terrain_i: 0,
        perception_steps: 0,
    };
    let end = run_loop(&mut hal, &mut rt, &mut op, last_tick, |v| cmp.check(v));
    match &end {
        LoopEnd::HalError { tick, kind, .. } if cmp.divergence.is_none() => {
            let recorded = rec
                .ticks
                .iter()
                .find(|t| t.tick.index == *tick)
                .and_then(|t| t.hal_error);
            if recorded.map(|r| r.0) != Some(*kind) {
                cmp.divergence = Some(Divergence {
                    tick: *tick,
                    time_s: 0.0,
                    channel: ch::HAL_EVENT.into(),
                    field: "kind".into(),
                    recorded: format!("{recorded:?}"),
                    replayed: format!("{kind:?}"),
                });
            }
        }
        _ => {}
    }
    let ticks = rec.ticks.len() as u64;
    let sim_seconds = ticks as f64 * rec.period_ns as f64 * 1e-9;
    let wall_seconds = wall.elapsed().as_secs_f64();
    let run_seconds = (wall_seconds - load_seconds).max(1e-9);
    Ok(ReplayReport {
        log: log_path.display().to_string(),
        ticks,
        sim_seconds,
        wall_seconds,
        sim_seconds_per_wall_second: sim_seconds / wall_seconds.max(1e-9),
        load_seconds,
        compared_commands: cmp.commands,
        compared_policy_steps: cmp.policy_steps,
        perception_frames_fed: hal.lidar_fed,
        compared_perception_steps: cmp.perception_steps,
        truncated: rec.truncated.clone(),
        damaged: rec.damaged.clone(),
        divergence: cmp.divergence,
        notes,
        run_sim_seconds_per_wall_second: sim_seconds / run_seconds,
        fast_group_us: rt.timing_stats().fast(),
        tick_compute_us: rt.timing_stats().tick(),
    })
}

struct Comparator<'a> {
    rec: &'a Recording,
    i: usize,
    bytes: [u8; LOW_CMD_LEN],
    divergence: Option<Divergence>,
    commands: u64,
    policy_steps: u64,
    /// The log has `/lidar/frame`: every perception step is compared with `/perception/terrain`.
    compare_perception: bool,
    terrain_i: usize,
    perception_steps: u64,
}

/// `recorded` (JSON; `None` for a non-finite value) is `replayed`, bit for bit.
fn same_f32(recorded: Option<f32>, replayed: f32) -> bool {
    match recorded {
        Some(r) => r.to_bits() == replayed.to_bits(),
        None => !replayed.is_finite(),
    }
}

fn show_f32(v: Option<f32>) -> String {
    v.map_or("null".into(), |v| format!("{v:e}"))
}

/// The first field where a replayed perception step differs from the recorded one.
fn first_perception_difference(r: &RecTerrain, p: &PerceptionSummary) -> Option<(String, String, String)> {
    let tokens = [("", &r.token, &p.token), ("estimate.", &r.estimate.token, &p.estimate)];
    for (prefix, rt, t) in tokens {
        if rt.class != t.class.name() {
            return Some((format!("{prefix}class"), rt.class.clone(), t.class.name().into()));
        }
        for (name, rv, v) in [
            ("step_height_m", rt.step_height_m, t.step_height_m),
            ("step_depth_m", rt.step_depth_m, t.step_depth_m),
            ("yaw_deg", rt.yaw_deg, t.yaw_rad.to_degrees()),
        ] {
            if !same_f32(rv, v) {
                return Some((format!("{prefix}{name}"), show_f32(rv), format!("{v:e}")));
            }
        }
    }
    if r.held != p.held {
        return Some(("held".into(), r.held.to_string(), p.held.to_string()));
    }
    if r.points != p.points {
        return Some(("points".into(), r.points.to_string(), p.points.to_string()));
    }
    if r.frame_timestamp_ns != p.frame_timestamp_ns {
        return Some((
            "frame_timestamp_ns".into(),
            r.frame_timestamp_ns.to_string(),
            p.frame_timestamp_ns.to_string(),
        ));
    }
    for (name, rv, v) in [
        ("estimate.confidence", r.estimate.confidence, p.confidence),
        ("base_height_m", r.base_height_m, p.base_height),
        ("roll", r.roll, p.roll),
        ("pitch", r.pitch, p.pitch),
    ] {
        if !same_f32(rv, v) {
            return Some((name.into(), show_f32(rv), format!("{v:e}")));
        }
    }
    None
}

impl Comparator<'_> {
    fn diverge(&mut self, t: &RecTick, channel: &str, field: String, recorded: String, replayed: String) -> bool {
        self.divergence = Some(Divergence {
            tick: t.tick.index,
            time_s: t.tick.time_ns as f64 * 1e-9,
            channel: channel.into(),
            field,
            recorded,
            replayed,
        });
        false
    }

    /// Compares one replayed tick with the recording; false stops the replay.
    fn check(&mut self, v: &TickView) -> bool {
        let k = v.summary.tick.index;
        while self.i < self.rec.ticks.len() && self.rec.ticks[self.i].tick.index < k {
            self.i += 1;
        }
        let Some(t) = self.rec.ticks.get(self.i) else {
            let t = self.rec.ticks.last().expect("non-empty").clone();
            return self.diverge(&t, "tick", "index".into(), "end of log".into(), k.to_string());
        };
        if t.tick.index != k {
            return self.diverge(t, "tick", "index".into(), t.tick.index.to_string(), k.to_string());
        }
        if v.summary.frame.code() != t.status {
            let rec = FrameStatus::from_code(t.status).map_or(t.status.to_string(), |s| format!("{s:?}"));
            return self.diverge(t, ch::LOW_STATE, "status".into(), rec, format!("{:?}", v.summary.frame));
        }
        if let Some(p) = v.summary.perception.filter(|_| self.compare_perception) {
            // Keyed by the step's tick (a threaded step's result comes back later).
            let step = p.step_tick;
            let terrain = &self.rec.terrain;
            while self.terrain_i < terrain.len() && terrain[self.terrain_i].0 < step {
                self.terrain_i += 1;
            }
            let recorded = terrain
                .get(self.terrain_i)
                .filter(|(tk, _)| *tk == step)
                .map(|(_, r)| r);
            match recorded {
                Some(r) if p.fresh => {
                    if let Some((field, a, b)) = first_perception_difference(r, &p) {
                        return self.diverge(t, ch::PERCEPTION_TERRAIN, field, a, b);
                    }
                    self.perception_steps += 1;
                }
                None if !p.fresh => {}
                _ => {
                    return self.diverge(
                        t,
                        ch::PERCEPTION_TERRAIN,
                        "fresh frame".into(),
                        recorded.is_some().to_string(),
                        p.fresh.to_string(),
                    )
                }
            }
        }
        if v.summary.policy_step != t.action.is_some() {
            return self.diverge(
                t,
                ch::ACTION,
                "policy step".into(),
                t.action.is_some().to_string(),
                v.summary.policy_step.to_string(),
            );
        }
        if v.summary.policy_step {
            let c = v.runtime.controller();
            for (chan, recorded, replayed) in [
                (ch::OBSERVATION, &t.obs, c.observation()),
                (ch::ACTION, &t.action, c.last_action()),
            ] {
                let r = &self.rec.values[recorded.clone().expect("present")];
                if r.len() != replayed.len() {
                    return self.diverge(
                        t,
                        chan,
                        "values.len".into(),
                        r.len().to_string(),
                        replayed.len().to_string(),
                    );
                }
                if let Some(i) = (0..r.len()).find(|&i| r[i].to_bits() != replayed[i].to_bits()) {
                    return self.diverge(
                        t,
                        chan,
                        format!("values[{i}]"),
                        format!("{:e}", r[i]),
                        format!("{:e}", replayed[i]),
                    );
                }
            }
            self.policy_steps += 1;
        }
        // Bodies only: the CRC word is a function of them (and the recorded one was checked by
        // whoever wrote it), so this saves a CRC per tick.
        encode_low_cmd_body(v.command, &mut self.bytes);
        let recorded = &self.rec.cmds[t.cmd.clone().expect("complete ticks only")];
        let body = LOW_CMD_LEN - 4;
        if self.bytes[..body] != recorded[..body] {
            let recorded: &[u8; LOW_CMD_LEN] = recorded.try_into().expect("length checked at load");
            sensor_io::unitree_hg::encode_low_cmd(v.command, &mut self.bytes);
            let (field, a, b) = first_cmd_difference(recorded, &self.bytes);
            return self.diverge(t, ch::LOW_CMD, field, a, b);
        }
        if v.command_sent != t.cmd_sent {
            return self.diverge(
                t,
                ch::LOW_CMD,
                "sent".into(),
                t.cmd_sent.to_string(),
                v.command_sent.to_string(),
            );
        }
        self.commands += 1;
        let tripped = v.summary.tripped.map(|r| r.name().to_string());
        if tripped != t.trip {
            return self.diverge(
                t,
                ch::SAFETY_EVENT,
                "trip".into(),
                format!("{:?}", t.trip),
                format!("{tripped:?}"),
            );
        }
        // Stop after the last recorded tick.
        self.i + 1 < self.rec.ticks.len()
    }
}

/// Names the first differing field of two LowCmd frames.
fn first_cmd_difference(recorded: &[u8; LOW_CMD_LEN], replayed: &[u8; LOW_CMD_LEN]) -> (String, String, String) {
    let (mut a, mut b) = (LowCommand::default(), LowCommand::default());
    let ok = decode_low_cmd(recorded, &mut a).is_ok() && decode_low_cmd(replayed, &mut b).is_ok();
    if ok {
        if a.mode_pr != b.mode_pr {
            return ("mode_pr".into(), a.mode_pr.to_string(), b.mode_pr.to_string());
        }
        if a.mode_machine != b.mode_machine {
            return (
                "mode_machine".into(),
                a.mode_machine.to_string(),
                b.mode_machine.to_string(),
            );
        }
        for s in 0..hal::NUM_MOTORS {
            let (x, y) = (&a.motors[s], &b.motors[s]);
            let name = hal::G1_MOTOR_NAMES[s];
            let fields = [
                ("q", x.q, y.q),
                ("dq", x.dq, y.dq),
                ("tau", x.tau, y.tau),
                ("kp", x.kp, y.kp),
                ("kd", x.kd, y.kd),
            ];
            if x.mode != y.mode {
                return (
                    format!("motor_cmd[{s}] ({name}).mode"),
                    x.mode.to_string(),
                    y.mode.to_string(),
                );
            }
            for (f, p, q) in fields {
                if p.to_bits() != q.to_bits() {
                    return (
                        format!("motor_cmd[{s}] ({name}).{f}"),
                        format!("{p:e}"),
                        format!("{q:e}"),
                    );
                }
            }
        }
    }
    let i = recorded.iter().zip(replayed).position(|(x, y)| x != y).unwrap_or(0);
    (format!("byte {i}"), recorded[i].to_string(), replayed[i].to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lidar_coverage_refuses_a_terrain_policy_without_frames() {
        assert_eq!(check_lidar_coverage(true, 0, 0), Ok(LidarCoverage::NoPerception));
        assert_eq!(check_lidar_coverage(false, 0, 0), Ok(LidarCoverage::NoPerception));
        assert_eq!(check_lidar_coverage(true, 20, 20), Ok(LidarCoverage::Frames));
        assert_eq!(check_lidar_coverage(false, 20, 20), Ok(LidarCoverage::Frames));
        assert_eq!(
            check_lidar_coverage(false, 20, 0),
            Ok(LidarCoverage::MissingButUnobserved)
        );
        let e = check_lidar_coverage(true, 20, 0).unwrap_err();
        assert!(
            e.contains("'/lidar/frame'") && e.contains("terrain_token") && e.contains("20 lidar frames"),
            "{e}"
        );
    }

    #[test]
    fn late_steps_carry_the_tick_they_came_back_where_the_log_has_it() {
        let msg = |extra: &str| -> (u64, RecTerrain) {
            let json = format!(
                r#"{{"tick":50,{extra}"class":"flat","step_height_m":0.0,"step_depth_m":0.0,"yaw_deg":0.0,
                    "held":false,"estimate":{{"class":"flat","step_height_m":0.0,"step_depth_m":0.0,"yaw_deg":0.0}},
                    "points":1,"frame_timestamp_ns":1}}"#
            );
            (50, serde_json::from_str(&json).unwrap())
        };
        let terrain = [
            msg(r#""late":true,"back_tick":173,"#),
            msg(r#""late":false,"back_tick":60,"#),
            msg(r#""late":true,"#), // written before back_tick was logged
        ];
        assert_eq!(
            late_steps(&terrain),
            vec![
                LateStep {
                    step_tick: 50,
                    back_tick: Some(173)
                },
                LateStep {
                    step_tick: 50,
                    back_tick: None
                },
            ]
        );
    }

    #[test]
    fn perception_steps_compare_bit_for_bit() {
        let r: RecTerrain = serde_json::from_str(
            r#"{"tick":50,"class":"stairs-up","step_height_m":0.15,"step_depth_m":0.3,"yaw_deg":-0.0,"source":"cnn",
                "held":false,"estimate":{"class":"stairs-up","step_height_m":0.15,"step_depth_m":0.3,"yaw_deg":-0.0,
                "confidence":null},"geometric":{},"points":123,"frame_timestamp_ns":99,"bev":{},
                "base_height_m":0.75,"roll":0.01,"pitch":-0.02}"#,
        )
        .unwrap();
        let token = hal::TerrainToken {
            class: hal::TerrainClass::StairsUp,
            step_height_m: 0.15,
            step_depth_m: 0.3,
            yaw_rad: -0.0,
        };
        let mut p = PerceptionSummary {
            fresh: true,
            frame_timestamp_ns: 99,
            points: 123,
            base_height: 0.75,
            roll: 0.01,
            pitch: -0.02,
            estimate: token,
            confidence: f32::NAN,
            token,
            ..Default::default()
        };
        assert_eq!(first_perception_difference(&r, &p), None);
        p.token.yaw_rad = 0.0;
        assert_eq!(
            first_perception_difference(&r, &p).map(|d| d.0),
            Some("yaw_deg".into()),
            "-0 and +0 differ"
        );
        p.token.yaw_rad = -0.0;
        p.estimate.step_depth_m = f32::from_bits(0.3f32.to_bits() + 1);
        assert_eq!(
            first_perception_difference(&r, &p).map(|d| d.0),
            Some("estimate.step_depth_m".into()),
            "one ulp"
        );
        p.estimate.step_depth_m = 0.3;
        p.confidence = 0.5;
        assert_eq!(
            first_perception_difference(&r, &p).map(|d| d.0),
            Some("estimate.confidence".into()),
            "null is not finite"
        );
    }
}
