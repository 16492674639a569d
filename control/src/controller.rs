//! The per-tick control law: start-up ramp, policy at its own rate, PD targets out, damping on fault.
//!
//! Fixed allocation: every buffer is sized in [`Controller::new`]; [`Controller::tick`] allocates
//! nothing. Time comes only from the tick index, so the same states give the same commands.
use hal::{LowCommand, LowState, MotorCommand, TickTime, MOTOR_MODE_ENABLED, NUM_MOTORS};

use crate::actor::Actor;
use crate::envelope::{CommandEnvelope, CommandSource, EnvelopeVerdict, Violation};
use crate::nn::{Network, NnError};
use crate::operator::Request;
use crate::policy_io::PolicyIo;
use crate::spec::mirror::MirrorError;
use crate::spec::DeploySpec;

#[derive(Debug, thiserror::Error)]
pub enum ControllerError {
    #[error("loading the policy's weights")]
    Weights {
        path: std::path::PathBuf,
        source: Box<NnError>,
    },
    #[error("deploy spec {spec}: policy network {what} is {got}, but the spec needs {expected}")]
    Dimension {
        spec: std::path::PathBuf,
        what: &'static str,
        got: usize,
        expected: usize,
    },
    #[error("deploy spec: [policy] mirror = \"average\"")]
    Mirror(#[from] MirrorError),
}

/// What the controller is doing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// An operated run's start and rest: damping (kp 0), no fault. The operator stands the robot up.
    Passive,
    /// Ramping to / holding the default pose before the policy engages.
    Startup,
    /// An operated run, standing: the default pose held after the ramp, until the operator says walk.
    Stand,
    /// Policy in control.
    Policy,
    /// An operated run, sitting down: ramping to the pose the robot stood up from, then passive.
    SitDown,
    /// Latched safe state: kp = 0, damping only. Left only by an explicit [`Controller::restart`]
    /// (operator reset) or a restart of the firmware.
    Damping(DampingReason),
}

pub use crate::supervisor::DampingReason;

/// What happened in one tick (for logging and evaluation).
/// What the command envelope ([`crate::envelope`]) found since start-up.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct EnvelopeCounts {
    /// Targets clamped into the joint range (not a fault).
    pub range_clamps: u64,
    /// Fields outside the envelope (each latched damping, or arrived while damping).
    pub violations: u64,
    /// The newest violation.
    pub last: Option<Violation>,
}

#[derive(Clone, Copy, Debug, Default)]
pub struct TickInfo {
    /// The policy ran this tick.
    pub policy_step: bool,
}

/// One slot's gains in each phase (kp, kd).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SlotGains {
    pub startup: (f32, f32),
    pub policy: (f32, f32),
    /// Damping is kp 0 with this kd.
    pub damping_kd: f32,
}

pub struct Controller {
    spec: DeploySpec,
    /// `None`: hold-only mode (no policy loaded; ramp to the default pose and stay there).
    net: Option<Actor>,
    /// Observation and action rules (shared with the trainer).
    io: PolicyIo,
    action: Vec<f32>,
    /// Per slot: driven or held, target pose, gains.
    enabled: [bool; NUM_MOTORS],
    default_q: [f32; NUM_MOTORS],
    kp: [f32; NUM_MOTORS],
    kd: [f32; NUM_MOTORS],
    /// Gains during ramp and hold.
    startup_kp: [f32; NUM_MOTORS],
    startup_kd: [f32; NUM_MOTORS],
    target_q: [f32; NUM_MOTORS],
    start_q: [f32; NUM_MOTORS],
    /// Policy targets clamped into range, total.
    clamped_targets: u64,
    /// The last check on every outgoing command, and what it found so far.
    envelope: CommandEnvelope,
    envelope_counts: EnvelopeCounts,
    /// A violation that latched damping and that the runtime has not reported yet.
    envelope_trip: Option<Violation>,
    /// Slots the policy drives (the others, when enabled, are held).
    policy_slot: [bool; NUM_MOTORS],
    /// Tick at which the current start-up began (0, or the tick of the last operator reset).
    start_tick: u64,
    ramp_ticks: u64,
    engage_tick: u64,
    decimation: u64,
    policy_steps: u64,
    mode: Mode,
    /// The operator steps the run through its states ([`Controller::operate`]); otherwise the
    /// policy engages by itself after the start-up.
    operated: bool,
    /// Tick the policy engaged at (its steps follow every `decimation` ticks from there).
    engaged_at: u64,
    /// The sit-down ramp: its first tick and the targets it starts from.
    sit_start: u64,
    sit_from: [f32; NUM_MOTORS],
}

impl Controller {
    pub fn new(spec: DeploySpec) -> Result<Self, ControllerError> {
        let path = spec.weights_path();
        let net = Network::load(&spec.policy.network, &path).map_err(|source| ControllerError::Weights {
            path,
            source: Box::new(source),
        })?;
        Self::build(spec, Some(net))
    }

    /// [`Controller::new`] with a network already loaded (embedded or fuzzed weights).
    pub fn with_network(spec: DeploySpec, net: Network) -> Result<Self, ControllerError> {
        Self::build(spec, Some(net))
    }

    /// A controller that never runs the policy: it ramps to the spec's default pose and holds it.
    pub fn hold_only(spec: DeploySpec) -> Self {
        Self::build(spec, None).expect("no network to mismatch")
    }

    fn build(spec: DeploySpec, net: Option<Network>) -> Result<Self, ControllerError> {
        let n = spec.action_dim();
        if let Some(net) = &net {
            Self::check_dims(&spec, net)?;
        }
        let crate::spec::MotorTable {
            enabled,
            default_q,
            kp,
            kd,
        } = spec.motor_table();
        let p = &spec.policy;
        let (mut startup_kp, mut startup_kd) = (kp, kd);
        for (i, &slot) in p.joint_ids_map.iter().enumerate() {
            if let Some(v) = &spec.startup.kp {
                startup_kp[slot] = v[i];
            }
            if let Some(v) = &spec.startup.kd {
                startup_kd[slot] = v[i];
            }
        }
        let net = net.map(|n| Actor::new(&spec, n)).transpose()?;
        let hz = spec.rates.control_hz as f64;
        let ramp_ticks = (spec.startup.ramp_s * hz).round() as u64;
        let engage_tick = ramp_ticks + (spec.startup.hold_s * hz).round() as u64;
        Ok(Self {
            io: PolicyIo::new(&spec),
            action: vec![0.0; n],
            decimation: spec.decimation() as u64,
            enabled,
            default_q,
            kp,
            kd,
            startup_kp,
            startup_kd,
            target_q: default_q,
            start_q: default_q,
            clamped_targets: 0,
            envelope: CommandEnvelope::from_spec(&spec),
            envelope_counts: EnvelopeCounts::default(),
            envelope_trip: None,
            policy_slot: std::array::from_fn(|s| p.joint_ids_map.contains(&s)),
            start_tick: 0,
            ramp_ticks,
            engage_tick,
            policy_steps: 0,
            mode: Mode::Startup,
            operated: false,
            engaged_at: engage_tick,
            sit_start: 0,
            sit_from: default_q,
            net,
            spec,
        })
    }

    fn check_dims(spec: &DeploySpec, net: &Network) -> Result<(), ControllerError> {
        let dim = |what, got, expected| ControllerError::Dimension {
            spec: spec.path.clone(),
            what,
            got,
            expected,
        };
        if net.output_dim() != spec.action_dim() {
            return Err(dim("output", net.output_dim(), spec.action_dim()));
        }
        if net.input_dim() != spec.observation_dim() {
            return Err(dim("input", net.input_dim(), spec.observation_dim()));
        }
        Ok(())
    }

    pub fn spec(&self) -> &DeploySpec {
        &self.spec
    }
    pub fn mode(&self) -> Mode {
        self.mode
    }
    pub fn policy_steps(&self) -> u64 {
        self.policy_steps
    }
    /// Slots the controller drives or holds (the supervisor watches these).
    pub fn enabled_slots(&self) -> [bool; NUM_MOTORS] {
        self.enabled
    }
    /// Policy targets clamped into the joint range so far.
    pub fn clamped_targets(&self) -> u64 {
        self.clamped_targets
    }
    /// What the command envelope found so far.
    pub fn envelope_counts(&self) -> EnvelopeCounts {
        self.envelope_counts
    }
    /// The violation that latched damping since the last call, if any (the runtime reports it).
    pub fn take_envelope_trip(&mut self) -> Option<Violation> {
        self.envelope_trip.take()
    }
    /// PD position targets of the newest command, per slot.
    pub fn target_q(&self) -> &[f32; NUM_MOTORS] {
        &self.target_q
    }
    /// The observation of the newest policy step.
    pub fn observation(&self) -> &[f32] {
        self.io.observation()
    }
    /// The raw policy output of the newest policy step.
    pub fn last_action(&self) -> &[f32] {
        self.io.last_action()
    }
    /// sha256 of the weights file, or "none" in hold-only mode.
    pub fn weights_sha256(&self) -> String {
        self.net
            .as_ref()
            .map_or_else(|| "none".into(), |n| n.network().weights_sha256().to_string())
    }

    /// Latches the damping state (the first reason is kept).
    pub fn enter_damping(&mut self, reason: DampingReason) {
        if !matches!(self.mode, Mode::Damping(_)) {
            self.mode = Mode::Damping(reason);
        }
    }

    /// Operator reset: leave damping (or restart) with a fresh start-up from the pose measured at
    /// tick `k`. Network memory, history and the last action start from zero again.
    pub fn restart(&mut self, k: u64, state: &LowState) {
        self.mode = Mode::Startup;
        self.start_tick = k;
        self.engaged_at = k + self.engage_tick;
        for s in 0..NUM_MOTORS {
            self.start_q[s] = state.motors[s].q;
        }
        self.target_q = self.start_q;
        self.io.reset();
        if let Some(net) = self.net.as_mut() {
            net.reset();
        }
    }

    /// Start-up bookkeeping for tick `k`: ramp, hold, and engaging the policy. Call once per tick
    /// before [`Self::policy_due`].
    pub fn advance(&mut self, k: u64, state: &LowState) {
        if k == 0 && self.start_tick == 0 {
            for s in 0..NUM_MOTORS {
                self.start_q[s] = state.motors[s].q;
            }
        }
        if self.mode == Mode::SitDown {
            let r = k - self.sit_start;
            if r >= self.ramp_ticks {
                self.mode = Mode::Passive;
            } else {
                let a = r as f32 / self.ramp_ticks.max(1) as f32;
                for s in 0..NUM_MOTORS {
                    self.target_q[s] = self.sit_from[s] + a * (self.start_q[s] - self.sit_from[s]);
                }
            }
            return;
        }
        if self.mode != Mode::Startup {
            return;
        }
        let r = k - self.start_tick;
        if r < self.ramp_ticks {
            let a = r as f32 / self.ramp_ticks as f32;
            for s in 0..NUM_MOTORS {
                self.target_q[s] = self.start_q[s] + a * (self.default_q[s] - self.start_q[s]);
            }
        } else {
            self.target_q = self.default_q;
            if r >= self.engage_tick && self.operated {
                self.mode = Mode::Stand;
            } else if r >= self.engage_tick && self.net.is_some() {
                // Policy gains from here; its first step comes one policy period later.
                self.mode = Mode::Policy;
            }
        }
    }

    /// Whether the policy group runs at tick `k`: in policy mode, every `decimation` ticks after
    /// engaging (so the policy's phase is fixed by the start-up, not by wall-clock time).
    pub fn policy_due(&self, k: u64) -> bool {
        let engaged_at = self.engaged_at;
        self.mode == Mode::Policy && k > engaged_at && (k - engaged_at).is_multiple_of(self.decimation)
    }

    /// Makes this an operated run: it starts passive (damping, no fault) and moves only when the
    /// operator asks ([`Controller::request`]). Call before the first tick.
    pub fn operate(&mut self) {
        self.operated = true;
        self.mode = Mode::Passive;
    }

    pub fn operated(&self) -> bool {
        self.operated
    }

    /// The operator's request at tick `k`: the new mode when it applies in the present one, `None`
    /// when it does not (a request that makes no sense in a state is ignored, as on Unitree's
    /// remote). A latched trip is left only through [`Request::Passive`].
    pub fn request(&mut self, k: u64, state: &LowState, request: Request) -> Option<Mode> {
        if !self.operated {
            return None;
        }
        match (request, self.mode) {
            (Request::Passive, Mode::Passive) => return None,
            (Request::Passive, _) => self.mode = Mode::Passive,
            // The remote's one "stand" combination stands a passive robot up and a walking one still.
            (Request::StandUp, Mode::Passive) | (Request::Stand | Request::StandUp, Mode::Policy) => {
                self.restart(k, state)
            }
            (Request::Walk, Mode::Stand) if self.net.is_some() => {
                self.io.reset();
                if let Some(net) = self.net.as_mut() {
                    net.reset();
                }
                self.engaged_at = k;
                self.mode = Mode::Policy;
            }
            (Request::SitDown, Mode::Startup | Mode::Stand | Mode::Policy) => {
                self.sit_start = k;
                self.sit_from = self.target_q;
                self.mode = Mode::SitDown;
            }
            _ => return None,
        }
        Some(self.mode)
    }

    /// One control tick in one call (start-up, policy when due, command): what the runtime does,
    /// minus supervision and perception (a terrain-token observation reads flat).
    /// `command` is the operator's (vx, vy, wz).
    pub fn tick(&mut self, state: &LowState, tick: TickTime, command: [f32; 3], out: &mut LowCommand) -> TickInfo {
        let mut info = TickInfo::default();
        self.advance(tick.index, state);
        if self.policy_due(tick.index) {
            if let Err(reason) = self.policy_step(state, command, hal::TerrainToken::FLAT) {
                self.enter_damping(reason);
            }
            info.policy_step = true;
        }
        self.write_command(state, out);
        info
    }

    /// Builds the observation, runs the network and sets PD targets. On NaN/Inf in the observation
    /// or action it returns the reason and leaves the targets unchanged (the caller latches damping).
    pub fn policy_step(
        &mut self,
        state: &LowState,
        command: [f32; 3],
        terrain: hal::TerrainToken,
    ) -> Result<(), DampingReason> {
        let obs = self.io.observe(state, command, terrain);
        self.policy_steps += 1;
        if obs.iter().any(|v| !v.is_finite()) {
            return Err(DampingReason::NonFiniteObservation);
        }
        let Some(net) = self.net.as_mut() else { return Ok(()) };
        if net.step(obs, &mut self.action).is_err() || self.action.iter().any(|a| !a.is_finite()) {
            return Err(DampingReason::NonFiniteAction);
        }
        self.clamped_targets += self.io.apply_action(&self.action, &mut self.target_q);
        Ok(())
    }

    /// The operator's velocity command as the policy receives it (clamped to `[commands]`).
    pub fn clamp_command(&self, command: [f32; 3]) -> [f32; 3] {
        self.io.clamp_command(command)
    }

    /// The gains each slot is commanded with, per phase: what a peer on the wire may check the
    /// commands against. `None` for slots the controller leaves disabled.
    pub fn gain_table(&self) -> [Option<SlotGains>; NUM_MOTORS] {
        std::array::from_fn(|s| {
            self.enabled[s].then(|| SlotGains {
                startup: (self.startup_kp[s], self.startup_kd[s]),
                policy: (self.kp[s], self.kd[s]),
                damping_kd: self.spec.safety.damping_kd,
            })
        })
    }

    /// Writes the damping command (kp = 0, configured kd on every enabled motor) into `out`, held
    /// to the command envelope like every other command.
    pub fn damping_command(&self, state: &LowState, out: &mut LowCommand) -> EnvelopeVerdict {
        self.raw_damping_command(state, out);
        self.envelope.enforce(out, |_| CommandSource::Damping)
    }

    fn raw_damping_command(&self, state: &LowState, out: &mut LowCommand) {
        out.mode_pr = 0;
        out.mode_machine = state.mode_machine;
        for s in 0..NUM_MOTORS {
            out.motors[s] = if self.enabled[s] {
                MotorCommand::damping(self.spec.safety.damping_kd)
            } else {
                MotorCommand::default()
            };
        }
    }

    /// Writes this tick's command: PD targets with the mode's gains, or damping. Whatever it is, it
    /// passes the command envelope last. A violation there latches damping at once, and this
    /// tick's command is the damping command.
    pub fn write_command(&mut self, state: &LowState, out: &mut LowCommand) {
        let verdict = match self.mode {
            Mode::Damping(_) | Mode::Passive => self.damping_command(state, out),
            mode => {
                self.raw_write_command(state, out);
                let policy_slot = self.policy_slot;
                self.envelope.enforce(out, |s| match mode {
                    Mode::Startup | Mode::Stand | Mode::SitDown => CommandSource::Startup,
                    _ if policy_slot[s] => CommandSource::Policy,
                    _ => CommandSource::Held,
                })
            }
        };
        self.envelope_counts.range_clamps += verdict.range_clamps as u64;
        self.envelope_counts.violations += verdict.violations as u64;
        if let Some(v) = verdict.first {
            self.envelope_counts.last = Some(v);
            if !matches!(self.mode, Mode::Damping(_)) {
                self.enter_damping(DampingReason::CommandEnvelope { slot: v.slot });
                self.envelope_trip = Some(v);
                let damping = self.damping_command(state, out);
                self.envelope_counts.violations += damping.violations as u64;
            }
        }
    }

    fn raw_write_command(&self, state: &LowState, out: &mut LowCommand) {
        out.mode_pr = 0;
        out.mode_machine = state.mode_machine;
        let (kp, kd) = if matches!(self.mode, Mode::Startup | Mode::Stand | Mode::SitDown) {
            (&self.startup_kp, &self.startup_kd)
        } else {
            (&self.kp, &self.kd)
        };
        for s in 0..NUM_MOTORS {
            out.motors[s] = if !self.enabled[s] {
                MotorCommand::default()
            } else {
                MotorCommand {
                    mode: MOTOR_MODE_ENABLED,
                    q: self.target_q[s],
                    dq: 0.0,
                    tau: 0.0,
                    kp: kp[s],
                    kd: kd[s],
                    reserve: 0,
                }
            };
        }
    }
}

/// Fuzz harness (the `deploy_spec` cargo-fuzz target and the stable `fuzz_smoke` test): the bytes
/// before the first NUL are a deploy spec, the bytes after it a weight file. A spec that validates
/// builds what `g1fw check-spec` builds (the controller, its observation, the warnings) and, if the
/// weights load against its network, the controller with them. Paths inside the spec are not
/// followed: the MJCF and terrain-network loaders have their own limits, and a fuzzer must not read
/// the disk.
#[doc(hidden)]
pub fn fuzz_deploy_spec(data: &[u8]) {
    let (text, weights) = match data.iter().position(|&b| b == 0) {
        Some(i) => (&data[..i], Some(&data[i + 1..])),
        None => (data, None),
    };
    let Ok(text) = std::str::from_utf8(text) else {
        return;
    };
    let Ok(mut spec) = DeploySpec::parse_unvalidated(text, std::path::Path::new("/nonexistent/g1fw-fuzz/spec.toml"))
    else {
        return;
    };
    spec.estimator.model = None;
    spec.perception.terrain_network = None;
    spec.perception.terrain_weights = None;
    if spec.validate().is_err() {
        return;
    }
    let dim = spec.observation_dim();
    assert!(dim <= crate::spec::MAX_OBSERVATION_DIM && dim == spec.policy.network.input);
    let _ = spec.explicit_pd_warnings();
    let _ = spec.estimator.config();
    let _ = spec.perception.self_filter().expect("validated");
    let c = Controller::hold_only(spec.clone());
    assert_eq!(c.observation().len(), dim);
    if let Some(w) = weights {
        if let Ok(net) = crate::nn::Network::from_safetensors_bytes(&spec.policy.network, w) {
            assert_eq!(net.input_dim(), dim);
            let _ = Controller::with_network(spec, net);
        }
    }
}

impl snapshot::Snapshot for Mode {
    fn save(&self, out: &mut Vec<u8>) {
        let code: u8 = match self {
            Mode::Passive => 0,
            Mode::Startup => 1,
            Mode::Stand => 2,
            Mode::Policy => 3,
            Mode::SitDown => 4,
            Mode::Damping(_) => 5,
        };
        out.push(code);
        if let Mode::Damping(r) = self {
            r.save(out);
        }
    }

    fn restore(&mut self, input: &mut &[u8]) -> Result<(), snapshot::SnapshotError> {
        let code = snapshot::take::<1>(input, "mode")?[0];
        *self = match code {
            0 => Mode::Passive,
            1 => Mode::Startup,
            2 => Mode::Stand,
            3 => Mode::Policy,
            4 => Mode::SitDown,
            5 => {
                let mut r = DampingReason::Tilt;
                r.restore(input)?;
                Mode::Damping(r)
            }
            _ => {
                return Err(snapshot::SnapshotError::Invalid {
                    what: "mode",
                    value: code as u64,
                })
            }
        };
        Ok(())
    }
}

/// What the controller carries between ticks. Not written: the spec, gains and limits (the
/// log pins the spec), and the envelope's last violation (a report's detail; a split file's
/// report starts without it). A violation is taken on its own tick, so none is pending here.
impl snapshot::Snapshot for Controller {
    fn save(&self, out: &mut Vec<u8>) {
        self.net.is_some().save(out);
        if let Some(n) = &self.net {
            n.save(out);
        }
        self.io.save(out);
        self.action.save(out);
        self.target_q.save(out);
        self.start_q.save(out);
        self.clamped_targets.save(out);
        self.envelope_counts.range_clamps.save(out);
        self.envelope_counts.violations.save(out);
        self.start_tick.save(out);
        self.ramp_ticks.save(out);
        self.engage_tick.save(out);
        self.policy_steps.save(out);
        self.mode.save(out);
        self.operated.save(out);
        self.engaged_at.save(out);
        self.sit_start.save(out);
        self.sit_from.save(out);
    }

    fn restore(&mut self, input: &mut &[u8]) -> Result<(), snapshot::SnapshotError> {
        let mut has_net = false;
        has_net.restore(input)?;
        match (&mut self.net, has_net) {
            (Some(n), true) => n.restore(input)?,
            (None, false) => {}
            _ => {
                return Err(snapshot::SnapshotError::Invalid {
                    what: "policy presence (hold-only run?)",
                    value: has_net as u64,
                })
            }
        }
        self.io.restore(input)?;
        self.action.restore(input)?;
        self.target_q.restore(input)?;
        self.start_q.restore(input)?;
        self.clamped_targets.restore(input)?;
        self.envelope_counts.range_clamps.restore(input)?;
        self.envelope_counts.violations.restore(input)?;
        self.envelope_counts.last = None;
        self.envelope_trip = None;
        self.start_tick.restore(input)?;
        self.ramp_ticks.restore(input)?;
        self.engage_tick.restore(input)?;
        self.policy_steps.restore(input)?;
        self.mode.restore(input)?;
        self.operated.restore(input)?;
        self.engaged_at.restore(input)?;
        self.sit_start.restore(input)?;
        self.sit_from.restore(input)
    }
}
