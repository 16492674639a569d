//! The deterministic runtime: one control tick, its rate groups in a fixed order, and the loop that
//! drives it from a HAL.
//!
//! Order inside a tick (fixed; the same on hardware, in simulation and in replay):
//! 1. **fast** — read: the HAL's newest state and its frame status (in [`run_loop`]);
//! 2. **fast** — estimate: attitude, base velocity, height and foot contacts from a fresh state;
//! 3. **fast** — safety: the supervisor judges the frame; operator e-stop / reset;
//! 4. **policy** (every `control_hz / policy_hz` ticks after the policy engaged): observation
//!    (with the newest terrain token), network, targets (clamped to joint ranges); NaN/Inf latches
//!    damping;
//! 5. **fast** — command: PD targets or damping, handed to the HAL (`send`);
//! 6. **perception** (every `control_hz / perception_hz` ticks, phase 0), after the command is
//!    out: budgeted and timed; the terrain pipeline lands here, and its token reaches the next
//!    policy step. Its millisecond of work thus never delays a motor command (it used to run
//!    before the policy, holding the command of every perception tick back by its whole duration).
//!
//! The policy's terrain token is the perception group's newest, unless the run selected another
//! [`TerrainSource`] (`none`: flat; `truth`: the simulator's ground truth of the tick, an evaluation
//! ablation and the only place ground truth reaches control).
//!
//! Time comes only from the HAL's tick index. Group compute times are measured with a monotonic
//! clock for the log and the benchmarks, and never feed back into control.
use std::time::Instant;

use hal::{ErrorKind, LowCommand, LowLevel, LowState, TickTime, TimeBase};

use crate::controller::{Controller, Mode};
use crate::operator::{OperatorInput, OperatorSource, Request};
use crate::perception::{Perception, PerceptionSummary, TerrainSource};
use crate::perception_worker::{PerceptionExec, PerceptionWorker};
use crate::supervisor::{DampingReason, FrameStatus, SafetyCounters, Supervisor};
use estimator::StateEstimator;

pub use crate::perception::Estimate;

/// Compute time of each group this tick, ns (0 when the group did not run).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TickTiming {
    pub fast_ns: u32,
    pub perception_ns: u32,
    pub policy_ns: u32,
}

impl TickTiming {
    pub fn total_ns(&self) -> u32 {
        self.fast_ns + self.perception_ns + self.policy_ns
    }
}

/// What happened in one tick.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TickSummary {
    pub tick: TickTime,
    pub frame: FrameStatus,
    pub operator: OperatorInput,
    /// The velocity command as the policy receives it: the operator's, clamped to the spec's
    /// `[commands]` limits.
    pub command_received: [f32; 3],
    pub policy_step: bool,
    pub perception_step: bool,
    pub mode: Mode,
    /// Set on the tick the supervisor (or operator) latched damping.
    pub tripped: Option<DampingReason>,
    /// Set on the tick an operator reset left damping.
    pub reset: bool,
    pub counters: SafetyCounters,
    pub clamped_targets: u64,
    /// What the command envelope found since start-up.
    pub envelope: crate::controller::EnvelopeCounts,
    /// Set on the tick a command broke the envelope and latched damping: what broke it.
    pub envelope_violation: Option<crate::envelope::Violation>,
    pub estimate: Estimate,
    /// Set on perception steps.
    pub perception: Option<PerceptionSummary>,
    pub timing: TickTiming,
    /// Groups over budget this tick: bit 0 fast, 1 perception, 2 policy.
    pub overruns: u8,
}

impl TickSummary {
    /// A summary of nothing (tick 0, no frame), for preallocated buffers.
    pub fn empty() -> Self {
        Self {
            tick: TickTime::default(),
            frame: FrameStatus::NoFrame,
            operator: OperatorInput::default(),
            command_received: [0.0; 3],
            policy_step: false,
            perception_step: false,
            mode: Mode::Startup,
            tripped: None,
            reset: false,
            counters: SafetyCounters::default(),
            clamped_targets: 0,
            envelope: Default::default(),
            envelope_violation: None,
            estimate: Estimate::default(),
            perception: None,
            timing: TickTiming::default(),
            overruns: 0,
        }
    }
}

/// Overrun counts per group since start.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct Overruns {
    pub fast: u64,
    pub perception: u64,
    pub policy: u64,
}

/// Poses kept while perception is with the worker (a late step can be away past one period).
const AWAY_POSES: usize = 256;

/// A threaded perception step a log marks late (its result was not ready when due).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LateStep {
    pub step_tick: u64,
    /// The tick its result came back, in logs that record it. Until then perception was away with
    /// the worker: later perception ticks took no frame and were skipped, and replay does the same.
    pub back_tick: Option<u64>,
}

#[derive(Clone, Copy, Debug)]
struct PendingStep {
    step_tick: u64,
    consume_tick: u64,
    /// Not ready at `consume_tick` (live): its token will not be used.
    late: bool,
    /// Replay: the result computed at `step_tick`.
    ready: Option<PerceptionSummary>,
    /// Replay: the log's entry when it marks this step late (looked up once, at the step).
    logged_late: Option<LateStep>,
}

impl PendingStep {
    fn new(step_tick: u64, consume_tick: u64, ready: Option<PerceptionSummary>) -> Self {
        Self {
            step_tick,
            consume_tick,
            late: false,
            ready,
            logged_late: None,
        }
    }
}

pub struct Runtime {
    controller: Controller,
    supervisor: Supervisor,
    perception_decimation: u64,
    budget_ns: [u32; 3],
    overruns: Overruns,
    trip: Option<(u64, DampingReason)>,
    estimator: StateEstimator,
    /// `None` while the worker thread has it (threaded perception).
    perception: Option<Box<Perception>>,
    exec: PerceptionExec,
    worker: Option<PerceptionWorker>,
    /// Replay of a threaded run: steps are computed at once, and consumed or not as the log says
    /// (sorted by step tick).
    replayed_late_steps: Option<Vec<LateStep>>,
    /// Replay: perception held back until a late step's recorded return ([`LateStep::back_tick`]).
    replay_away: Option<Box<Perception>>,
    /// The step handed over (or, in replay, computed ahead) and not yet consumed.
    pending: Option<PendingStep>,
    /// Poses recorded while perception was away, added to its history when it comes home: a ring
    /// of the newest `AWAY_POSES` (oldest at `away_start`), O(1) per tick however long it is away.
    away_poses: Box<[(u64, Estimate); AWAY_POSES]>,
    away_start: usize,
    away_len: usize,
    /// The token the policy reads (perception's newest consumed one).
    policy_token: hal::TerrainToken,
    perception_late: u64,
    perception_skipped: u64,
    /// A new lidar frame is in `perception`'s buffer for this tick's perception step.
    lidar_fresh: bool,
    stats: TimingStats,
    /// Where the policy's token comes from (perception unless an evaluation says otherwise).
    terrain_source: TerrainSource,
    /// The ground-truth token of this tick under [`TerrainSource::Truth`].
    truth_token: hal::TerrainToken,
}

/// The layout of [`Runtime::save_snapshot`]: a change to what it writes changes this number.
pub const SNAPSHOT_FORMAT: u32 = 1;

impl Runtime {
    pub fn new(controller: Controller) -> Self {
        let spec = controller.spec();
        let b = spec.rates.budget_us;
        Self {
            supervisor: Supervisor::new(spec, controller.enabled_slots()),
            perception_decimation: spec.perception_decimation() as u64,
            budget_ns: [b.fast * 1000, b.perception * 1000, b.policy * 1000],
            overruns: Overruns::default(),
            trip: None,
            estimator: StateEstimator::new(spec.kinematics.clone(), spec.estimator.config(), spec.control_dt()),
            perception: Some(Box::new(Perception::new(&spec.perception, &spec.base_dir))),
            exec: PerceptionExec::Inline,
            worker: None,
            replayed_late_steps: None,
            replay_away: None,
            pending: None,
            away_poses: Box::new([(0, Estimate::default()); AWAY_POSES]),
            away_start: 0,
            away_len: 0,
            policy_token: hal::TerrainToken::FLAT,
            perception_late: 0,
            perception_skipped: 0,
            lidar_fresh: false,
            stats: TimingStats::new(),
            terrain_source: TerrainSource::of_spec(&spec.perception),
            truth_token: hal::TerrainToken::FLAT,
            controller,
        }
    }

    /// Selects where the policy's token comes from. `Cnn`/`Geometric` only label the perception
    /// token (the estimator itself is the spec's, chosen before [`Runtime::new`]); `Truth` is the
    /// evaluation ablation fed by [`run_loop`] from the HAL's ground truth; `None` keeps it flat.
    pub fn set_terrain_source(&mut self, source: TerrainSource) {
        self.terrain_source = source;
    }
    pub fn terrain_source(&self) -> TerrainSource {
        self.terrain_source
    }
    /// Under [`TerrainSource::Truth`] (evaluation ablation only): this tick's ground-truth token
    /// (flat when the simulator has no world).
    pub fn set_truth_token(&mut self, token: Option<hal::TerrainToken>) {
        self.truth_token = token.unwrap_or(hal::TerrainToken::FLAT);
    }

    pub fn controller(&self) -> &Controller {
        &self.controller
    }
    /// The control period the spec asks for, ns.
    pub fn period_ns(&self) -> u64 {
        (self.controller.spec().control_dt() * 1e9).round() as u64
    }
    pub fn mode(&self) -> Mode {
        self.controller.mode()
    }
    /// The first latched trip: tick and reason.
    pub fn trip(&self) -> Option<(u64, DampingReason)> {
        self.trip
    }
    pub fn overruns(&self) -> Overruns {
        self.overruns
    }
    pub fn timing_stats(&self) -> &TimingStats {
        &self.stats
    }
    /// See [`Supervisor::disable_frozen_check`]; recorded in the log's metadata so replay does the same.
    pub fn disable_frozen_check(&mut self) {
        self.supervisor.disable_frozen_check();
    }
    pub fn counters(&self) -> SafetyCounters {
        self.supervisor.counters()
    }
    /// The newest state estimate.
    pub fn estimate(&self) -> &Estimate {
        self.estimator.estimate()
    }
    pub fn estimator(&self) -> &StateEstimator {
        &self.estimator
    }
    /// Perception, unless the worker thread has it right now (threaded, between a perception
    /// tick and its result).
    pub fn perception(&self) -> Option<&Perception> {
        self.perception.as_deref()
    }

    /// Runs the perception step inline (default) or on a worker thread, consumed a fixed number
    /// of ticks after the frame (see [`crate::perception_worker`]). Call before the first tick.
    pub fn set_perception_exec(&mut self, exec: PerceptionExec) -> std::io::Result<()> {
        if let PerceptionExec::Threaded { consume_after, .. } = exec {
            if consume_after as u64 >= self.perception_decimation {
                return Err(std::io::Error::new(
                    std::io::ErrorKind::InvalidInput,
                    format!(
                        "threaded perception must consume its result before the next perception tick: \
                         {consume_after} ticks is not less than the perception period of {} ticks",
                        self.perception_decimation
                    ),
                ));
            }
            self.worker = Some(PerceptionWorker::start()?);
        }
        self.exec = exec;
        Ok(())
    }

    /// Tests only: the threaded perception worker panics on its next step.
    #[doc(hidden)]
    pub fn inject_perception_panic(&self) {
        if let Some(w) = &self.worker {
            w.inject_panic();
        }
    }

    pub fn perception_exec(&self) -> PerceptionExec {
        self.exec
    }

    /// Replays a threaded run: each step is computed at its tick and consumed `consume_after`
    /// ticks later unless the log marks it late; a late one keeps perception away until the tick it
    /// came back, where the log records it.
    pub fn set_perception_replay(&mut self, consume_after: u32, mut late_steps: Vec<LateStep>) {
        self.exec = PerceptionExec::Threaded {
            consume_after,
            wait: true,
        };
        self.worker = None;
        late_steps.sort_by_key(|l| l.step_tick);
        self.replayed_late_steps = Some(late_steps);
    }

    /// Appends the state this runtime carries into its next tick to `out` (see the `snapshot`
    /// crate): what a log file split after this tick starts from. `false` (nothing written) while
    /// a threaded perception step is out; it comes home within a perception period.
    pub fn save_snapshot(&self, out: &mut Vec<u8>) -> bool {
        use snapshot::Snapshot;
        let Some(p) = self.perception.as_deref() else {
            return false;
        };
        if self.pending.is_some() || self.replay_away.is_some() || self.away_len > 0 {
            return false;
        }
        SNAPSHOT_FORMAT.save(out);
        self.controller.save(out);
        self.supervisor.save(out);
        self.estimator.save(out);
        p.save(out);
        self.policy_token.save(out);
        self.trip.is_some().save(out);
        if let Some((k, r)) = self.trip {
            k.save(out);
            r.save(out);
        }
        self.perception_late.save(out);
        self.perception_skipped.save(out);
        true
    }

    /// Restores what [`Runtime::save_snapshot`] wrote, into a runtime built from the same spec
    /// and set up the same way (perception execution, frozen check), before its first tick.
    pub fn restore_snapshot(&mut self, bytes: &[u8]) -> Result<(), snapshot::SnapshotError> {
        use snapshot::Snapshot;
        let mut input = bytes;
        let mut format = 0u32;
        format.restore(&mut input)?;
        if format != SNAPSHOT_FORMAT {
            return Err(snapshot::SnapshotError::Version {
                expected: SNAPSHOT_FORMAT,
                found: format,
            });
        }
        self.controller.restore(&mut input)?;
        self.supervisor.restore(&mut input)?;
        self.estimator.restore(&mut input)?;
        let Some(p) = self.perception.as_deref_mut() else {
            return Err(snapshot::SnapshotError::Invalid {
                what: "perception at home",
                value: 0,
            });
        };
        p.restore(&mut input)?;
        self.policy_token.restore(&mut input)?;
        let mut tripped = false;
        tripped.restore(&mut input)?;
        self.trip = None;
        if tripped {
            let (mut k, mut r) = (0u64, DampingReason::Tilt);
            k.restore(&mut input)?;
            r.restore(&mut input)?;
            self.trip = Some((k, r));
        }
        self.perception_late.restore(&mut input)?;
        self.perception_skipped.restore(&mut input)?;
        if input.is_empty() {
            Ok(())
        } else {
            Err(snapshot::SnapshotError::Trailing(input.len()))
        }
    }

    /// Threaded steps whose result was not ready when due (their token was not used), and
    /// perception ticks skipped because a late step still had perception.
    pub fn perception_late(&self) -> (u64, u64) {
        (self.perception_late, self.perception_skipped)
    }

    fn record_pose(&mut self, time_ns: u64) {
        let est = *self.estimator.estimate();
        match self.perception.as_deref_mut() {
            Some(p) => p.record_pose(time_ns, &est),
            None => {
                // The history holds only the last HISTORY poses anyway: keep the newest.
                if self.away_len == AWAY_POSES {
                    self.away_poses[self.away_start] = (time_ns, est);
                    self.away_start = (self.away_start + 1) % AWAY_POSES;
                } else {
                    self.away_poses[(self.away_start + self.away_len) % AWAY_POSES] = (time_ns, est);
                    self.away_len += 1;
                }
            }
        }
    }

    fn come_home(&mut self, mut p: Box<Perception>) {
        for i in 0..self.away_len {
            let (t, est) = &self.away_poses[(self.away_start + i) % AWAY_POSES];
            p.record_pose(*t, est);
        }
        (self.away_start, self.away_len) = (0, 0);
        self.perception = Some(p);
    }

    /// Threaded: takes the pending step's result back at its tick (before the policy group), or
    /// a late one whenever it comes.
    fn collect(&mut self, k: u64, s: &mut TickSummary) {
        let Some(mut pend) = self.pending else { return };
        let PerceptionExec::Threaded { wait, .. } = self.exec else {
            return;
        };
        if !pend.late && k < pend.consume_tick {
            return;
        }
        let (result, late) = if self.replayed_late_steps.is_some() {
            // Computed at its tick; the log says whether it was on time, and when it came back.
            if let Some(back) = pend.logged_late.and_then(|l| l.back_tick) {
                if k < back {
                    return;
                }
                if let Some(p) = self.replay_away.take() {
                    self.come_home(p);
                }
            }
            (pend.ready.take(), pend.logged_late.is_some())
        } else {
            let Some(w) = self.worker.as_ref() else { return };
            let got = if wait && !pend.late {
                Some(w.take())
            } else {
                w.try_take()
            };
            match got {
                Some((p, sum)) => {
                    self.come_home(p);
                    (Some(sum), pend.late)
                }
                None => {
                    if !pend.late {
                        pend.late = true;
                        self.perception_late += 1;
                    }
                    self.pending = Some(pend);
                    return;
                }
            }
        };
        self.pending = None;
        let Some(mut sum) = result else { return };
        sum.step_tick = pend.step_tick;
        sum.late = late;
        if late {
            if self.replayed_late_steps.is_some() {
                self.perception_late += 1;
            }
        } else {
            self.policy_token = sum.token;
        }
        s.perception = Some(sum);
    }
    /// Tick `k` runs the perception group.
    pub fn perception_due(&self, k: u64) -> bool {
        k.is_multiple_of(self.perception_decimation)
    }
    /// On a perception tick, lets `source` put its newest lidar frame into the perception buffer
    /// (before [`Runtime::tick`]).
    /// While a late threaded step still has perception, no frame is taken (it stays in the HAL).
    pub fn load_lidar<S: FrameSource + ?Sized>(&mut self, k: u64, source: &mut S) {
        self.lidar_fresh = self.perception_due(k)
            && match self.perception.as_deref_mut() {
                Some(p) => source.read_lidar(p.frame_mut()),
                None => false,
            };
    }

    /// The perception group of tick `k`: inline, the step itself; threaded, the hand-over.
    fn perception_step(&mut self, k: u64, now_ns: u64, fresh: bool, s: &mut TickSummary) {
        let est = *self.estimator.estimate();
        let Some(mut p) = self.perception.take() else {
            // A late step still runs: this tick's frame was left in the HAL.
            self.perception_skipped += 1;
            return;
        };
        match self.exec {
            PerceptionExec::Threaded { consume_after, .. } if fresh => {
                let consume_tick = k + consume_after as u64;
                if let Some(late_steps) = &self.replayed_late_steps {
                    let sum = p.step(now_ns, true, &est);
                    let mut pend = PendingStep::new(k, consume_tick, Some(sum));
                    pend.logged_late = late_steps
                        .binary_search_by_key(&k, |l| l.step_tick)
                        .ok()
                        .map(|i| late_steps[i]);
                    if pend.logged_late.is_some_and(|l| l.back_tick.is_some()) {
                        self.replay_away = Some(p);
                    } else {
                        self.perception = Some(p);
                    }
                    self.pending = Some(pend);
                } else if let Some(w) = self.worker.as_ref() {
                    w.submit(p, now_ns, est);
                    self.pending = Some(PendingStep::new(k, consume_tick, None));
                } else {
                    self.perception = Some(p);
                }
            }
            _ => {
                // Inline, or no new frame (nothing to compute: the last summary, marked not fresh).
                let mut sum = p.step(now_ns, fresh, &est);
                self.perception = Some(p);
                sum.step_tick = k;
                if s.perception.is_none() {
                    if self.exec == PerceptionExec::Inline {
                        self.policy_token = sum.token;
                    }
                    s.perception = Some(sum);
                }
            }
        }
    }

    fn latch(&mut self, k: u64, reason: DampingReason, summary: &mut TickSummary) {
        if !matches!(self.controller.mode(), Mode::Damping(_)) {
            self.controller.enter_damping(reason);
            summary.tripped = Some(reason);
            if self.trip.is_none() {
                self.trip = Some((k, reason));
            }
        }
    }

    /// Latches damping from outside the tick (HAL failure), and writes the damping command.
    pub fn fail_safe(&mut self, k: u64, reason: DampingReason, state: &LowState, out: &mut LowCommand) -> bool {
        let was = matches!(self.controller.mode(), Mode::Damping(_));
        self.controller.enter_damping(reason);
        if !was && self.trip.is_none() {
            self.trip = Some((k, reason));
        }
        self.controller.write_command(state, out);
        !was
    }

    /// After `write_command`: a violation of the command envelope latched damping; record the trip.
    fn note_envelope(&mut self, k: u64, summary: &mut TickSummary) {
        if let Some(v) = self.controller.take_envelope_trip() {
            let reason = DampingReason::CommandEnvelope { slot: v.slot };
            summary.tripped = Some(reason);
            summary.envelope_violation = Some(v);
            if self.trip.is_none() {
                self.trip = Some((k, reason));
            }
        }
        summary.envelope = self.controller.envelope_counts();
    }

    /// One control tick (steps 2–6 of the module doc; the caller did the read): the command is
    /// computed into `out` and handed to `send` before the perception group runs. When `send`
    /// fails, perception is skipped (the caller is about to fail safe) and its error returned.
    pub fn tick<E>(
        &mut self,
        tick: TickTime,
        frame: FrameStatus,
        state: &LowState,
        operator: OperatorInput,
        out: &mut LowCommand,
        send: impl FnOnce(&LowCommand) -> Result<(), E>,
    ) -> (TickSummary, Result<(), E>) {
        let k = tick.index;
        let t0 = Instant::now();
        let mut s = TickSummary {
            tick,
            frame,
            operator,
            command_received: self.controller.clamp_command(operator.velocity),
            policy_step: false,
            perception_step: false,
            mode: self.controller.mode(),
            tripped: None,
            reset: false,
            counters: SafetyCounters::default(),
            clamped_targets: 0,
            envelope: Default::default(),
            envelope_violation: None,
            estimate: *self.estimator.estimate(),
            perception: None,
            timing: TickTiming::default(),
            overruns: 0,
        };

        // 2. estimate (from fresh frames only: a repeated state carries no new information)
        if frame == FrameStatus::Fresh {
            self.estimator.update(k, state);
        }
        self.record_pose(tick.time_ns);

        // 3. safety and operator
        self.supervisor
            .set_motion_checks(self.controller.mode() != Mode::Passive);
        if let Some(reason) = self.supervisor.check_frame(k, frame, state) {
            self.latch(k, reason, &mut s);
        }
        if !operator.velocity.iter().all(|v| v.is_finite()) {
            self.latch(k, DampingReason::NonFiniteInput, &mut s);
        }
        if operator.estop {
            self.latch(k, DampingReason::EStop, &mut s);
        } else if operator.reset && matches!(self.controller.mode(), Mode::Damping(_)) {
            if self.controller.operated() {
                // An operated run comes back passive: the operator stands it up again.
                self.controller.request(k, state, Request::Passive);
            } else {
                self.controller.restart(k, state);
            }
            self.supervisor.reset(k);
            s.reset = true;
        } else if let Some(request) = operator.request {
            let tripped = matches!(self.controller.mode(), Mode::Damping(_));
            if self.controller.request(k, state, request).is_some() && tripped {
                // Acknowledging a trip clears the supervisor's streaks, as a reset does.
                self.supervisor.reset(k);
                s.reset = true;
            }
        }
        self.controller.advance(k, state);
        let t1 = Instant::now();

        // Threaded perception: a step's result comes back at its fixed tick, before the policy.
        self.collect(k, &mut s);
        let t1c = Instant::now();

        // 4. policy group (the token of the newest perception step before this tick's)
        let mut t2 = t1c;
        if self.controller.policy_due(k) {
            s.policy_step = true;
            let terrain = match self.terrain_source {
                TerrainSource::Cnn | TerrainSource::Geometric => self.policy_token,
                TerrainSource::Truth => self.truth_token,
                TerrainSource::None => hal::TerrainToken::FLAT,
            };
            if let Err(reason) = self.controller.policy_step(state, operator.velocity, terrain) {
                self.latch(k, reason, &mut s);
            }
            t2 = Instant::now();
        }

        // 5. command, out before perception (through the command envelope, last)
        self.controller.write_command(state, out);
        self.note_envelope(k, &mut s);
        let t3 = Instant::now();
        let sent = send(out);
        let t4 = Instant::now();

        // 6. perception group
        let lidar_fresh = std::mem::take(&mut self.lidar_fresh);
        if sent.is_ok() && k.is_multiple_of(self.perception_decimation) {
            s.perception_step = true;
            self.perception_step(k, tick.time_ns, lidar_fresh, &mut s);
        }
        let t5 = Instant::now();

        s.mode = self.controller.mode();
        s.counters = self.supervisor.counters();
        s.clamped_targets = self.controller.clamped_targets();
        s.estimate = *self.estimator.estimate();
        // The HAL's own write time (t3..t4) belongs to no group.
        s.timing = TickTiming {
            fast_ns: ns(t1 - t0) + ns(t3 - t2),
            perception_ns: if s.perception_step || s.perception.is_some() {
                ns(t5 - t4) + ns(t1c - t1)
            } else {
                0
            },
            policy_ns: if s.policy_step { ns(t2 - t1c) } else { 0 },
        };
        let times = [s.timing.fast_ns, s.timing.perception_ns, s.timing.policy_ns];
        let counts = [
            &mut self.overruns.fast,
            &mut self.overruns.perception,
            &mut self.overruns.policy,
        ];
        for (g, count) in counts.into_iter().enumerate() {
            if times[g] > self.budget_ns[g] {
                *count += 1;
                s.overruns |= 1 << g;
            }
        }
        self.stats.add(&s.timing);
        (s, sent)
    }
}

fn ns(d: std::time::Duration) -> u32 {
    d.as_nanos().min(u32::MAX as u128) as u32
}

/// Fixed-size latency histograms (fast group and whole tick), 25 ns buckets up to 250 µs; slower
/// ticks land in the last bucket and still count towards the exact maximum.
pub struct TimingStats {
    fast: Histogram,
    total: Histogram,
}

const BUCKET_NS: u32 = 25;
const BUCKETS: usize = 10_000;

struct Histogram {
    counts: Box<[u32; BUCKETS]>,
    n: u64,
    max_ns: u32,
}

impl Histogram {
    fn new() -> Self {
        Self {
            counts: Box::new([0; BUCKETS]),
            n: 0,
            max_ns: 0,
        }
    }
    fn add(&mut self, v: u32) {
        self.counts[((v / BUCKET_NS) as usize).min(BUCKETS - 1)] += 1;
        self.n += 1;
        self.max_ns = self.max_ns.max(v);
    }
    /// Upper edge of the bucket holding quantile `p` (0..1), µs.
    fn quantile_us(&self, p: f64) -> f64 {
        let target = ((self.n as f64) * p).ceil().max(1.0) as u64;
        let mut acc = 0u64;
        for (i, &c) in self.counts.iter().enumerate() {
            acc += c as u64;
            if acc >= target {
                return ((i as u32 + 1) * BUCKET_NS).min(self.max_ns) as f64 / 1000.0;
            }
        }
        self.max_ns as f64 / 1000.0
    }
    fn summary(&self) -> LatencySummary {
        LatencySummary {
            ticks: self.n,
            p50_us: self.quantile_us(0.5),
            p99_us: self.quantile_us(0.99),
            p999_us: self.quantile_us(0.999),
            max_us: self.max_ns as f64 / 1000.0,
        }
    }
}

/// Latency percentiles, µs.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct LatencySummary {
    pub ticks: u64,
    pub p50_us: f64,
    pub p99_us: f64,
    pub p999_us: f64,
    pub max_us: f64,
}

impl TimingStats {
    fn new() -> Self {
        Self {
            fast: Histogram::new(),
            total: Histogram::new(),
        }
    }
    fn add(&mut self, t: &TickTiming) {
        self.fast.add(t.fast_ns);
        self.total.add(t.total_ns());
    }
    /// Fast group alone.
    pub fn fast(&self) -> LatencySummary {
        self.fast.summary()
    }
    /// Whole tick (fast + whichever groups ran).
    pub fn tick(&self) -> LatencySummary {
        self.total.summary()
    }
}

pub use hal::FrameSource;

/// Everything about one tick, for loggers, evaluators and the replay comparator.
pub struct TickView<'a> {
    pub summary: &'a TickSummary,
    pub raw_state: Option<&'a [u8]>,
    pub state: &'a LowState,
    pub command: &'a LowCommand,
    /// The command went to the HAL (false on the final tick and when the HAL failed first).
    pub command_sent: bool,
    pub runtime: &'a Runtime,
    pub truth: Option<&'a hal::GroundTruth>,
    /// The HAL failed on this tick (the loop ends after it).
    pub hal_error: Option<HalFailure>,
}

/// A HAL failure and where it happened.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct HalFailure {
    pub kind: ErrorKind,
    /// In `write_command` (this tick ran), rather than in `wait_tick` (the tick never came).
    pub in_write: bool,
}

/// How a loop ended.
#[derive(Debug)]
pub enum LoopEnd {
    /// Ran to the last tick.
    Completed { ticks: u64 },
    /// The observer asked to stop.
    Stopped { ticks: u64 },
    /// The HAL failed; damping was commanded best-effort.
    HalError {
        tick: u64,
        kind: ErrorKind,
        message: String,
    },
    /// Code on the tick panicked (a bug): the guard sent the damping command (kp 0, the spec's
    /// damping kd on every enabled motor) before returning.
    Panicked {
        tick: u64,
        message: String,
        damping_sent: bool,
    },
}

// `run_loop`'s guard catches a panic to damp the motors; with `panic = "abort"` it could not.
#[cfg(panic = "abort")]
compile_error!("g1fw's control-loop panic guard needs panic = \"unwind\" (the default); do not set abort");

pub use crate::panic_message;

/// Drives `runtime` from `hal` until tick `last_tick` (inclusive; no command is written on it, so a
/// lock-stepped simulator stops there), the observer returns `false`, or the HAL fails.
/// `observe` sees every tick, including the failing one. Allocation-free per tick when the HAL,
/// operator source and observer are.
///
/// A panic anywhere in the tick (runtime, HAL, observer) is caught here: the damping command, built
/// before the first tick so that it depends on nothing the panic may have left half-updated, goes
/// to the HAL, and the loop ends with [`LoopEnd::Panicked`]. The caller then finishes its log and
/// report as after a HAL failure.
pub fn run_loop<H, O>(
    hal: &mut H,
    rt: &mut Runtime,
    operator: &mut O,
    last_tick: u64,
    mut observe: impl FnMut(&TickView) -> bool,
) -> LoopEnd
where
    H: TimeBase + LowLevel + FrameSource,
    O: OperatorSource,
{
    let mut damping = LowCommand::default();
    rt.controller().damping_command(&LowState::default(), &mut damping);
    let mut at = (0u64, 0u8); // (tick, the robot's mode_machine, echoed in every command)
    let run = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        ticks(hal, rt, operator, last_tick, &mut observe, &mut at)
    }));
    match run {
        Ok(end) => end,
        Err(payload) => {
            damping.mode_machine = at.1;
            let damping_sent =
                std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| hal.write_command(&damping).is_ok()))
                    .unwrap_or(false);
            let message = panic_message(payload.as_ref());
            tracing::error!(
                tick = at.0,
                damping_sent,
                "the control loop panicked ({message}); damping commanded on every enabled motor"
            );
            LoopEnd::Panicked {
                tick: at.0,
                message,
                damping_sent,
            }
        }
    }
}

fn ticks<H, O>(
    hal: &mut H,
    rt: &mut Runtime,
    operator: &mut O,
    last_tick: u64,
    mut observe: impl FnMut(&TickView) -> bool,
    at: &mut (u64, u8),
) -> LoopEnd
where
    H: TimeBase + LowLevel + FrameSource,
    O: OperatorSource,
{
    let mut state = LowState::default();
    let mut cmd = LowCommand::default();
    let mut k = 0u64;
    let mut bad_frames = 0u64;
    loop {
        let tick = match hal.wait_tick() {
            Ok(t) => t,
            Err(e) => {
                let kind = hal::Error::kind(&e);
                return fail(
                    hal,
                    rt,
                    &mut state,
                    &mut cmd,
                    k,
                    kind,
                    e.to_string(),
                    None,
                    &mut observe,
                );
            }
        };
        k = tick.index;
        let frame = match hal.read_state(&mut state) {
            Ok(true) => FrameStatus::Fresh,
            Ok(false) => FrameStatus::NoFrame,
            Err(e) => {
                // Say why, but not 500 times a second: the first bad frame and every 500th.
                if bad_frames.is_multiple_of(500) {
                    tracing::warn!(tick = k, bad_frames = bad_frames + 1, "rejected LowState frame: {e}");
                }
                bad_frames += 1;
                FrameStatus::Bad(hal::Error::kind(&e))
            }
        };
        *at = (k, state.mode_machine);
        let op = operator.at_estimate(tick, &state, rt.estimate());
        if rt.terrain_source() == TerrainSource::Truth {
            // The documented evaluation ablation: ground truth into the policy's token.
            rt.set_truth_token(hal.truth().and_then(|t| t.terrain));
        }
        rt.load_lidar(k, hal);
        let last = k >= last_tick;
        // The final tick computes its command but does not send it (a lock-stepped simulator
        // would step once more).
        let (summary, sent) = rt.tick(tick, frame, &state, op, &mut cmd, |c| {
            if last {
                Ok(())
            } else {
                hal.write_command(c)
            }
        });
        if !last {
            if let Err(e) = sent {
                let kind = hal::Error::kind(&e);
                return fail(
                    hal,
                    rt,
                    &mut state,
                    &mut cmd,
                    k,
                    kind,
                    e.to_string(),
                    Some(summary),
                    &mut observe,
                );
            }
        }
        let go_on = observe(&TickView {
            summary: &summary,
            raw_state: hal.received_frame(),
            state: &state,
            command: &cmd,
            command_sent: !last,
            runtime: rt,
            truth: hal.truth(),
            hal_error: None,
        });
        if last {
            return LoopEnd::Completed { ticks: k };
        }
        if !go_on {
            return LoopEnd::Stopped { ticks: k };
        }
    }
}

/// HAL failure: latch damping, try once to send it, and let the observer record the tick.
#[allow(clippy::too_many_arguments)]
fn fail<H, F>(
    hal: &mut H,
    rt: &mut Runtime,
    state: &mut LowState,
    cmd: &mut LowCommand,
    last_k: u64,
    kind: ErrorKind,
    message: String,
    summary: Option<TickSummary>,
    observe: &mut F,
) -> LoopEnd
where
    H: TimeBase + LowLevel + FrameSource,
    F: FnMut(&TickView) -> bool,
{
    // A failed wait means the tick after the last one never came; a failed write fails this tick.
    let k = if summary.is_some() { last_k } else { last_k + 1 };
    let tripped = rt.fail_safe(k, DampingReason::HalFault, state, cmd);
    let sent = hal.write_command(cmd).is_ok();
    let mut s = summary.unwrap_or_else(|| TickSummary {
        tick: TickTime {
            index: k,
            time_ns: k * hal.period_ns(),
        },
        frame: FrameStatus::Bad(kind),
        counters: rt.counters(),
        clamped_targets: rt.controller().clamped_targets(),
        envelope: rt.controller().envelope_counts(),
        ..TickSummary::empty()
    });
    s.mode = rt.mode();
    if tripped {
        s.tripped = Some(DampingReason::HalFault);
    }
    observe(&TickView {
        summary: &s,
        raw_state: None,
        state,
        command: cmd,
        command_sent: sent,
        runtime: rt,
        truth: None,
        hal_error: Some(HalFailure {
            kind,
            in_write: summary.is_some(),
        }),
    });
    LoopEnd::HalError { tick: k, kind, message }
}
