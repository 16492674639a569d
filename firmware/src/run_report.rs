//! What every run reports and records, in simulation and on the robot: the first latched trip, the
//! safety counters, and the metadata that pins a log to its spec (replay checks it).
use serde::Serialize;

use control::runtime::{Overruns, Runtime};
use control::spec::DeploySpec;
use runlog::log::RunMeta;
use runlog::replay::key;

#[derive(Clone, Debug, Serialize)]
pub struct TripReport {
    pub tick: u64,
    pub time_s: f64,
    pub reason: String,
}

impl TripReport {
    /// The run's first latched damping, if any.
    pub fn of(runtime: &Runtime, control_dt: f64) -> Option<Self> {
        runtime.trip().map(|(tick, reason)| TripReport {
            tick,
            time_s: tick as f64 * control_dt,
            reason: reason.to_string(),
        })
    }
}

/// One change of the run's state, what caused it and when.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct ModeChange {
    pub tick: u64,
    pub time_s: f64,
    pub from: &'static str,
    pub to: &'static str,
    /// `remote`, `keyboard`, `schedule` (the operator's request), `safety` (a trip), `reset`, or `ramp` (a
    /// ramp that ended by itself).
    pub source: &'static str,
}

/// The run's changes of state, tick by tick (kept off the tick: the observer calls it after).
#[derive(Clone, Debug, Default)]
pub struct ModeChanges {
    last: Option<control::controller::Mode>,
    pub changes: Vec<ModeChange>,
}

/// The most changes a report lists (the count goes on in `dropped`).
const MAX_MODE_CHANGES: usize = 1000;

impl ModeChanges {
    /// Changes from `mode`, the run's state before its first tick.
    pub fn starting(mode: control::controller::Mode) -> Self {
        Self {
            last: Some(mode),
            changes: Vec::new(),
        }
    }

    /// Notes tick `s`'s mode; `operator` names where its requests come from. Returns the change,
    /// if the mode changed on this tick (the operator's terminal shows it).
    pub fn observe(
        &mut self,
        s: &control::runtime::TickSummary,
        control_dt: f64,
        operator: &'static str,
    ) -> Option<ModeChange> {
        let prev = self.last.replace(s.mode);
        let prev = prev.filter(|p| *p != s.mode)?;
        let source = if s.tripped.is_some() {
            "safety"
        } else if s.reset {
            "reset"
        } else if s.operator.request.is_some() {
            operator
        } else {
            "ramp"
        };
        let change = ModeChange {
            tick: s.tick.index,
            time_s: s.tick.index as f64 * control_dt,
            from: runlog::log::mode_name(prev),
            to: runlog::log::mode_name(s.mode),
            source,
        };
        if self.changes.len() < MAX_MODE_CHANGES {
            self.changes.push(change.clone());
        }
        Some(change)
    }
}

#[derive(Clone, Debug, Serialize)]
pub struct SafetyReport {
    pub crc_failures: u64,
    pub missing_frames: u64,
    pub stale_frames: u64,
    pub malformed_frames: u64,
    pub clamped_targets: u64,
    /// Targets the command envelope clamped into the joint range (not a fault).
    pub envelope_range_clamps: u64,
    /// Command fields outside the envelope (each latches damping).
    pub envelope_violations: u64,
    /// The newest of them, in words.
    pub envelope_last_violation: Option<String>,
    pub overruns: Overruns,
}

impl SafetyReport {
    pub fn of(runtime: &Runtime) -> Self {
        let c = runtime.counters();
        SafetyReport {
            crc_failures: c.crc_failures,
            missing_frames: c.missing_frames,
            stale_frames: c.stale_frames,
            malformed_frames: c.malformed_frames,
            clamped_targets: runtime.controller().clamped_targets(),
            envelope_range_clamps: runtime.controller().envelope_counts().range_clamps,
            envelope_violations: runtime.controller().envelope_counts().violations,
            envelope_last_violation: runtime.controller().envelope_counts().last.map(|v| v.to_string()),
            overruns: runtime.overruns(),
        }
    }
}

/// What pins any run to its spec in the log (replay checks these): the firmware version, the spec
/// (path, text, sha256) and the start-up it ran with.
pub fn spec_meta(spec: &DeploySpec, hold_only: bool) -> RunMeta {
    let mut m = RunMeta::default();
    m.set("firmware_version", env!("CARGO_PKG_VERSION"))
        .set(key::SPEC_PATH, spec.path.display())
        .set(key::SPEC_SHA256, control::nn::sha256_hex(spec.source_text.as_bytes()))
        .set(key::SPEC_TOML, &spec.source_text)
        .set(key::HOLD_ONLY, hold_only)
        .set(key::RAMP_S, spec.startup.ramp_s)
        .set(key::HOLD_S, spec.startup.hold_s)
        .set("control_hz", spec.rates.control_hz);
    m
}
