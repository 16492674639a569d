//! `g1fw run`: the firmware on a robot's own transport. `--dds`: the G1's DDS topics `rt/lowstate` /
//! `rt/lowcmd` (the real robot, unitree_mujoco, or `g1-sim --dds`); `--can-config`: the motors on
//! CAN buses (docs/can.md), the vcan hardware-in-the-loop bench against `g1-can-emu`. The same
//! `run_loop`, controller and logger as `g1fw sim`; only the HAL differs. There is no ground truth
//! here: the report says what the firmware saw and did.
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use robot_io::can::{CanBuses, CanCounters, CanHal, SocketCanBuses};
use robot_io::{DdsHal, DdsHalConfig, DdsHalCounters};
use serde::Serialize;

use hal::LIDAR_FRAME_CAP;
use robot_io::UdpLidar;

use crate::run_report::{SafetyReport, TripReport};
use control::controller::Controller;
use control::lidar_source::WithLidar;
use control::operator::CommandSchedule;
use control::perception_worker::{PerceptionExec, DEFAULT_CONSUME_AFTER};
use control::runtime::{run_loop, FrameSource, LoopEnd, Runtime};
use control::spec::DeploySpec;
use hal::{LowLevel, TimeBase};
use runlog::log::RunMeta;
use runlog::log::{LogOptions, LogStats, Logger};
use runlog::replay::key;

#[derive(Clone, Debug)]
pub struct RunOptions {
    pub schedule: CommandSchedule,
    /// Stop after this many seconds of control ticks; `None`: until SIGINT/SIGTERM.
    pub duration_s: Option<f64>,
    pub ramp_override: Option<(f64, f64)>,
    pub hold_only: bool,
    /// The operator steps the run through its states (passive at start; the schedule's requests).
    pub operated: bool,
    /// An operated run's operator is the terminal's keyboard ([`control::keyboard::KEYS`]) instead
    /// of the robot's remote.
    pub keyboard: bool,
    /// How long start-up waits for the first state (CAN: every motor's answer and the IMU's first
    /// sample; DDS: the first `rt/lowstate`).
    pub startup_timeout: Duration,
    pub log: Option<PathBuf>,
    pub log_options: LogOptions,
    pub rt: control::rt::RtOptions,
    /// Stop when this becomes true (signal handlers set it); the motors are then damped.
    pub stop: Arc<AtomicBool>,
    /// The MID-360 over UDP (`None`: no lidar; perception, if the spec has it, sees no frames).
    pub lidar: Option<robot_io::UdpLidarConfig>,
    /// Perception off the tick thread by default: its result is used a fixed number of ticks after
    /// the frame, or counted late and not used (never waited for on a robot).
    pub perception: PerceptionExec,
    /// Tests only (no command-line flag sets it): panic inside the control loop on this tick, to
    /// show that the guard damps the motors and the log and report survive.
    pub inject_panic_at_tick: Option<u64>,
    /// After the loop ends, for whatever reason (duration, signal, HAL failure, panic), the damping
    /// command is sent every control period for this long before the program exits.
    pub end_damping: Duration,
}

impl Default for RunOptions {
    fn default() -> Self {
        Self {
            schedule: CommandSchedule::constant([0.0; 3]),
            duration_s: None,
            ramp_override: None,
            hold_only: false,
            operated: false,
            keyboard: false,
            startup_timeout: Duration::from_secs(10),
            log: None,
            log_options: LogOptions::default(),
            rt: control::rt::RtOptions::default(),
            stop: Arc::new(AtomicBool::new(false)),
            lidar: None,
            perception: PerceptionExec::Threaded {
                consume_after: DEFAULT_CONSUME_AFTER,
                wait: false,
            },
            inject_panic_at_tick: None,
            end_damping: Duration::from_secs(1),
        }
    }
}

#[derive(Clone, Debug, Serialize)]
pub struct RunReport {
    /// `dds IFACE,DOMAIN` or `can IF,IF…`.
    pub transport: String,
    pub ticks: u64,
    pub time_s: f64,
    pub policy_steps: u64,
    pub final_mode: String,
    pub trip: Option<TripReport>,
    /// Every change of state: passive, startup, stand, policy, sit_down, damping; its source and time.
    pub transitions: Vec<crate::run_report::ModeChange>,
    /// `completed`, `stopped` (signal) or the HAL failure.
    pub end: String,
    /// The run ended as asked: its duration ran out or the operator stopped it (a signal). Any
    /// other end (a trip, a HAL failure, a variant without the driven joints, a log that could not
    /// be written, a panic) left the robot damped for a reason, and `g1fw run` exits non-zero.
    pub normal_end: bool,
    /// Why the log could not be written (the run stopped and damped there), if it could not.
    pub log_error: Option<String>,
    /// The control loop panicked (a bug); the guard sent damping (see `end`).
    pub panicked: bool,
    /// The damping command sent after the end, whatever ended the run.
    pub end_damping: EndDamping,
    pub safety: SafetyReport,
    /// The CAN HAL's counters (CAN runs only).
    pub can: Option<CanCounters>,
    /// The DDS HAL's counters (DDS runs only).
    pub dds: Option<DdsHalCounters>,
    /// `--unitree-mujoco` was on: states without a CRC or tick were accepted, stamped by arrival.
    pub unitree_mujoco: bool,
    /// What started a tick (DDS runs): `clock` or `state`.
    pub pace: Option<robot_io::dds::Pace>,
    /// Clock pacing: how late ticks woke after their deadlines (p50, p99, max, µs).
    pub period_jitter: Option<robot_io::dds::JitterSummary>,
    /// Things the operator should know that did not stop the run.
    pub warnings: Vec<String>,
    /// The UDP lidar's counters (absent without `--lidar-udp`).
    pub lidar: Option<LidarReport>,
    pub perception: PerceptionReport,
    pub spec: String,
    pub weights_sha256: String,
    pub log: Option<LogStats>,
    pub wall_s: f64,
}

/// How perception ran: `inline` or `threaded:L`; threaded steps whose result was late (token not
/// used), and perception ticks skipped because a late step still had perception.
#[derive(Clone, Debug, Serialize)]
pub struct PerceptionReport {
    pub exec: String,
    pub late_steps: u64,
    pub skipped_ticks: u64,
}

/// What the lidar delivered over the run.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct LidarReport {
    pub datagrams: u64,
    /// From an address other than the configured lidar (dropped).
    pub foreign: u64,
    pub malformed: u64,
    pub lost_packets: u64,
    /// Frames assembled, and frames the perception step took.
    pub frames: u64,
    pub frames_used: u64,
    pub read_errors: u64,
}

/// Opens the layout's interfaces and runs.
pub fn run_can(spec: DeploySpec, layout: sensor_io::can::BusLayout, opts: &RunOptions) -> Result<RunReport> {
    let buses = SocketCanBuses::open(&layout.interfaces)?;
    run_on(spec, layout, buses, opts)
}

/// Runs over any CAN buses (SocketCAN, or the in-process bus in tests).
pub fn run_on<B: CanBuses>(
    spec: DeploySpec,
    layout: sensor_io::can::BusLayout,
    buses: B,
    opts: &RunOptions,
) -> Result<RunReport> {
    let on_bus = layout.slot_mask();
    let missing: Vec<&str> = spec
        .policy
        .joint_ids_map
        .iter()
        .filter(|&&s| on_bus & (1 << s) == 0)
        .map(|&s| hal::G1_MOTOR_NAMES[s])
        .collect();
    if !missing.is_empty() {
        bail!(
            "the bus layout has no motors for joints the policy drives: {}",
            missing.join(", ")
        );
    }
    let mut meta = RunMeta::default();
    meta.set("hal", "can")
        // Quantized readings repeat exactly while a joint rests; a dead motor is a missing reply.
        .set(key::FROZEN_CHECK, false)
        .set("can_interfaces", layout.interfaces.join(","));
    let transport = format!("can {}", layout.interfaces.join(","));
    let startup = opts.startup_timeout;
    let stop = opts.stop.clone();
    let (mut report, hal) = run_hal(spec, opts, meta, false, transport, |period_ns| {
        Ok(CanHal::open(buses, layout, period_ns, startup)?.with_stop(stop))
    })?;
    report.can = Some(hal.counters());
    Ok(report)
}

/// What was sent after the loop ended.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct EndDamping {
    /// Damping commands handed to the transport.
    pub sent: u64,
    /// Those the transport refused (a lost link).
    pub failed: u64,
    pub seconds: f64,
}

/// Sends the damping command (kp 0, the spec's damping kd, through the command envelope) every
/// control period for `duration`, on a monotonic clock with absolute deadlines: the robot's state
/// may have stopped (a lost link, a finished simulator), so nothing here waits for it.
fn damp_after_end<H: LowLevel>(
    hal: &mut H,
    runtime: &Runtime,
    mode_machine: u8,
    period_ns: u64,
    duration: Duration,
) -> EndDamping {
    let mut cmd = hal::LowCommand::default();
    let state = hal::LowState {
        mode_machine,
        ..Default::default()
    };
    runtime.controller().damping_command(&state, &mut cmd);
    let period = Duration::from_nanos(period_ns.max(1));
    let n = (duration.as_nanos() / period.as_nanos()).max(1) as u64;
    let start = Instant::now();
    let mut out = EndDamping::default();
    for i in 0..n {
        if hal.write_command(&cmd).is_ok() {
            out.sent += 1;
        } else {
            out.failed += 1;
        }
        let deadline = start + period * (i as u32 + 1);
        if let Some(wait) = deadline.checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
    }
    out.seconds = start.elapsed().as_secs_f64();
    tracing::info!(
        sent = out.sent,
        failed = out.failed,
        "run ended: damping sent for {:.2} s",
        out.seconds
    );
    out
}

/// Joins the DDS domain on `cfg`'s interface and runs, ticking on `rt/lowstate`.
pub fn run_dds(
    spec: DeploySpec,
    endpoint: robot_io::dds::Endpoint,
    opts: &RunOptions,
    tick_timeout: Option<Duration>,
    pace: robot_io::dds::Pace,
    unitree_mujoco: bool,
) -> Result<RunReport> {
    let mut meta = RunMeta::default();
    meta.set("hal", "dds")
        .set(key::FRAME_ENCODING, key::FRAME_ENCODING_CDR)
        .set("dds_endpoint", &endpoint);
    if unitree_mujoco {
        meta.set(key::UNITREE_MUJOCO, "true").set(key::FROZEN_CHECK, false);
    }
    let transport = format!("dds {endpoint}");
    let startup = opts.startup_timeout;
    let stop = opts.stop.clone();
    // A robot at rest in a noise-free simulator repeats its f32 state exactly, which the frozen-joint
    // check would take for a dead encoder: off for unitree_mujoco (the log says so; replay follows).
    let frozen_check = !unitree_mujoco;
    let (mut report, hal) = run_hal(spec, opts, meta, frozen_check, transport, |period_ns| {
        let mut cfg = DdsHalConfig::new(endpoint, period_ns);
        cfg.startup_timeout = startup;
        cfg.stop = Some(stop.clone());
        if let Some(t) = tick_timeout {
            cfg.tick_timeout = t;
        }
        cfg.unitree_mujoco = unitree_mujoco;
        cfg.pace = pace;
        Ok(DdsHal::open(cfg)?)
    })?;
    let counters = hal.counters();
    // unitree_mujoco's bridge leaves the tick (and CRC) unset on every sample; a few repeats (a
    // simulator resending a state while it waits for a command) are not that simulator.
    let most = |n: u64| n > 0 && 2 * n > counters.link.samples_in;
    if !unitree_mujoco
        && most(counters.tick_unchanged)
        && report.trip.as_ref().is_some_and(|t| t.reason == "state_timeout")
    {
        report.end = format!(
            "{}; rt/lowstate kept arriving but its tick did not advance in {} of {} samples: unitree_mujoco's \
             Python bridge leaves LowState.tick at 0, and g1fw judges freshness by it (the robot's tick advances \
             every 2 ms). For that simulator only, run with --unitree-mujoco (docs/robot.md, \"Run in Unitree's \
             simulator\")",
            report.end, counters.tick_unchanged, counters.link.samples_in
        );
    }
    if most(counters.crc_zero) && report.trip.as_ref().is_some_and(|t| t.reason == "crc_streak") {
        report.end = format!(
            "{}; {} of {} rt/lowstate samples had a CRC of 0, one never computed: Unitree's Python simulator \
             (unitree_mujoco's simulate_python) sends LowState without it. The robot always fills it in. For that \
             simulator only, run with --unitree-mujoco (docs/robot.md, \"Run in Unitree's simulator\")",
            report.end, counters.crc_zero, counters.link.samples_in
        );
    }
    // States arriving far from the control rate (unitree_mujoco at its default 5 ms step): each
    // command is then held longer than the policy was trained for, or states are dropped unseen.
    let ratio = counters.link.samples_in as f64 / report.ticks.max(1) as f64;
    if report.ticks >= 100 && !(0.8..=1.25).contains(&ratio) {
        let note = format!(
            "rt/lowstate arrived {:.2} times per control tick ({} samples in {} ticks of {:.1} ms): the robot \
             publishes at the control rate; a simulator should step at the spec's control period (unitree_mujoco: \
             SIMULATE_DT = {:.3})",
            ratio,
            counters.link.samples_in,
            report.ticks,
            1e3 * report.time_s / report.ticks.max(1) as f64,
            report.time_s / report.ticks.max(1) as f64
        );
        tracing::warn!("{note}");
        report.warnings.push(note);
    }
    report.dds = Some(counters);
    report.pace = Some(pace);
    report.period_jitter = (pace == robot_io::dds::Pace::Clock).then(|| hal.jitter());
    report.unitree_mujoco = unitree_mujoco;
    Ok(report)
}

/// Why a spec cannot run on the G1 variant `mode_machine` names: its policy drives a motor that
/// variant does not have. `None` when it can, or when the value is not one we know.
pub fn variant_mismatch(mode_machine: u8, driven: &[bool; hal::NUM_MOTORS]) -> Option<String> {
    let variant = hal::g1_variant(mode_machine)?;
    let lacking: Vec<&str> = variant
        .missing
        .iter()
        .filter(|&&slot| driven[slot])
        .map(|&slot| hal::G1_MOTOR_NAMES[slot])
        .collect();
    (!lacking.is_empty()).then(|| {
        format!(
            "the robot reports mode_machine {mode_machine} ({}), which has no {} motor{}, but the spec's \
             policy drives {}; use a spec for this variant",
            variant.name,
            lacking.join(", "),
            if lacking.len() == 1 { "" } else { "s" },
            if lacking.len() == 1 { "it" } else { "them" }
        )
    })
}

/// The loop shared by every robot transport: log, lidar, real-time set-up, the HAL (opened last,
/// right before the first tick), signals, the report.
fn run_hal<H: TimeBase + LowLevel + FrameSource>(
    mut spec: DeploySpec,
    opts: &RunOptions,
    hal_meta: RunMeta,
    frozen_check: bool,
    transport: String,
    open: impl FnOnce(u64) -> Result<H>,
) -> Result<(RunReport, H)> {
    if let Some((ramp, hold)) = opts.ramp_override {
        spec.startup.ramp_s = ramp;
        spec.startup.hold_s = hold;
    }
    let spec_name = spec.path.display().to_string();
    let control_dt = spec.control_dt();
    let mut meta = crate::run_report::spec_meta(&spec, opts.hold_only);
    meta.set(key::OPERATED, opts.operated);
    if opts.operated {
        let source = match (opts.keyboard, opts.schedule.source.is_none()) {
            (true, _) => "keyboard",
            (false, true) => "remote",
            (false, false) => "schedule",
        };
        meta.set(key::OPERATOR, source);
    }
    meta.extend(hal_meta);
    meta.set(key::PERCEPTION_EXEC, opts.perception.label());
    // The policy's joints: a held joint the variant lacks is only a slot nobody reads (a portable
    // spec holds waist and arms that a 23-dof G1 does not have).
    let mut driven = [false; hal::NUM_MOTORS];
    for &slot in &spec.policy.joint_ids_map {
        driven[slot] = true;
    }
    let mut controller = if opts.hold_only {
        Controller::hold_only(spec)
    } else {
        Controller::new(spec)?
    };
    if opts.operated {
        controller.operate();
    }
    let weights_sha256 = controller.weights_sha256();
    meta.set(key::WEIGHTS_SHA256, &weights_sha256);
    let (obs_dim, act_dim) = (controller.spec().observation_dim(), controller.spec().num_joints());
    let period_ns = (control_dt * 1e9).round() as u64;
    // Everything that allocates or locks memory happens before the HAL opens: once CAN motors are
    // in motor mode (or the robot's state flows), the first command must follow at once (under the
    // HIL VM, building these after the handshake held it back ~0.8 s).
    let mut logger = match &opts.log {
        Some(path) => Some(Logger::create(path, &meta, obs_dim, act_dim, opts.log_options.clone())?),
        None => None,
    };
    let lidar = match &opts.lidar {
        Some(cfg) => Some(UdpLidar::<LIDAR_FRAME_CAP>::open(cfg.clone())?),
        None => None,
    };
    control::rt::apply(&opts.rt)?;
    let last_tick = opts.duration_s.map_or(u64::MAX, |d| (d / control_dt).round() as u64);
    let mut runtime = Runtime::new(controller);
    if !frozen_check {
        runtime.disable_frozen_check();
    }
    runtime
        .set_perception_exec(opts.perception)
        .context("starting the perception thread")?;
    let mut hal = WithLidar::new(open(period_ns)?, lidar);
    // An operated run without a schedule takes its operator from the robot's remote, or from the
    // terminal's keyboard when asked (the guard puts the terminal back however the run ends).
    let mut keys_guard = None;
    let mut operator = if opts.operated && opts.keyboard {
        let (keys, guard) = crate::terminal_keys::start().context("reading keys from the terminal (--keyboard)")?;
        keys_guard = Some(guard);
        eprintln!("{}", control::keyboard::card());
        control::remote::RunOperator::Keyboard(control::keyboard::KeyboardOperator::new(
            runtime.controller().spec(),
            keys,
        ))
    } else if opts.operated && opts.schedule.source.is_none() {
        let remote = control::remote::RemoteOperator::new(runtime.controller().spec()).map_err(anyhow::Error::msg)?;
        control::remote::RunOperator::Remote(remote)
    } else {
        control::remote::RunOperator::Schedule(opts.schedule.source(period_ns))
    };
    let wall = Instant::now();
    let mut ticks = 0u64;
    let mut mode_machine = 0u8;
    let mut log_failed = false;
    let mut variant_refusal: Option<String> = None;
    let operator_name = operator.name();
    let mut mode_changes = crate::run_report::ModeChanges::starting(runtime.controller().mode());
    let end = run_loop(&mut hal, &mut runtime, &mut operator, last_tick, |v| {
        if let Some(c) = mode_changes.observe(v.summary, control_dt, operator_name) {
            // A few lines a run, for whoever holds the remote or the keyboard.
            tracing::info!("{:.2} s: {} → {} ({})", c.time_s, c.from, c.to, c.source);
        }
        // A log that cannot be written (a full disk) stops the log, never the control: what
        // reached the disk stays readable, and the report names the error.
        if let Some(l) = logger.as_mut().filter(|_| !log_failed) {
            l.push(v);
            if l.writer_failed() {
                log_failed = true;
                tracing::error!(
                    tick = v.summary.tick.index,
                    "the log could not be written: logging stopped, control goes on"
                );
            }
        }
        ticks = v.summary.tick.index;
        // The robot names its variant in every state (0: not set, as simulators send): a spec that
        // drives a motor this variant lacks stops at its first state, before the ramp moves anything.
        if v.state.mode_machine != mode_machine && v.state.mode_machine != 0 {
            if let Some(refusal) = variant_mismatch(v.state.mode_machine, &driven) {
                variant_refusal = Some(refusal);
                return false;
            }
        }
        mode_machine = v.state.mode_machine;
        if opts.inject_panic_at_tick == Some(ticks) {
            panic!("injected at tick {ticks} by RunOptions::inject_panic_at_tick");
        }
        !opts.stop.load(Ordering::Relaxed)
    });
    let mut warnings = Vec::new();
    if let control::remote::RunOperator::Remote(r) = &operator {
        if let (n @ 1.., Some(last)) = r.faults() {
            warnings.push(format!(
                "the remote read garbage on {n} ticks (last: {}); each commanded zero velocity and no transition",
                last.name()
            ));
        }
    }
    if let control::remote::RunOperator::Keyboard(k) = &operator {
        if k.keys_ignored > 0 {
            warnings.push(format!(
                "{} of {} keys pressed do nothing (the keys: g1fw run --help, --keyboard)",
                k.keys_ignored, k.keys_read
            ));
        }
        if k.input_closed {
            warnings.push("the keyboard's input ended during the run: the command went to zero".into());
        }
    }
    drop(keys_guard);
    // A signal that ended a wait inside the HAL (the first state that never came) is a stop.
    let stopped_in_hal = matches!(end, LoopEnd::HalError { .. }) && opts.stop.load(Ordering::Relaxed);
    let end = match end {
        LoopEnd::HalError { tick, .. } if stopped_in_hal => LoopEnd::Stopped { ticks: tick },
        end => end,
    };
    // Every end leaves the robot damped, not holding the last targets with the policy's gains.
    let end_damping = damp_after_end(&mut hal, &runtime, mode_machine, period_ns, opts.end_damping);
    let (log, log_error) = match logger.map(|l| l.finish()) {
        Some(Ok(s)) => (Some(s), None),
        Some(Err(e)) => (None, Some(control::nn::with_causes(&e))),
        None => (None, None),
    };
    let end_text = describe_end(&end, variant_refusal.as_deref());

    let lidar = hal.lidar.as_ref().map(|l| {
        let (c, s) = (l.counters(), l.assembler_stats());
        LidarReport {
            datagrams: c.datagrams,
            foreign: c.foreign,
            malformed: c.malformed,
            lost_packets: s.lost_packets,
            frames: c.frames,
            frames_used: hal.counters.used,
            read_errors: hal.counters.errors,
        }
    });
    let (late_steps, skipped_ticks) = runtime.perception_late();
    let report = RunReport {
        perception: PerceptionReport {
            exec: opts.perception.label(),
            late_steps,
            skipped_ticks,
        },
        transport,
        ticks,
        time_s: ticks as f64 * control_dt,
        policy_steps: runtime.controller().policy_steps(),
        final_mode: format!("{:?}", runtime.mode()),
        // The HAL's error that a signal caused latched damping: a stop, not a trip.
        trip: TripReport::of(&runtime, control_dt).filter(|_| !stopped_in_hal),
        transitions: mode_changes.changes,
        end: end_text,
        normal_end: (runtime.trip().is_none() || stopped_in_hal)
            && match end {
                LoopEnd::Completed { .. } => true,
                LoopEnd::Stopped { .. } => variant_refusal.is_none(),
                LoopEnd::HalError { .. } | LoopEnd::Panicked { .. } => false,
            },
        log_error,
        panicked: matches!(end, LoopEnd::Panicked { .. }),
        end_damping,
        safety: SafetyReport::of(&runtime),
        can: None,
        dds: None,
        unitree_mujoco: false,
        pace: None,
        period_jitter: None,
        warnings,
        lidar,
        spec: spec_name,
        weights_sha256,
        log,
        wall_s: wall.elapsed().as_secs_f64(),
    };
    Ok((report, hal.hal))
}

/// How the run ended, in words for the report (the motors are damped after every end).
fn describe_end(end: &LoopEnd, variant_refusal: Option<&str>) -> String {
    match end {
        LoopEnd::Completed { .. } => "completed".to_string(),
        LoopEnd::Stopped { ticks } if variant_refusal.is_some() => format!(
            "stopped at tick {ticks}: {}; motors commanded to damping",
            variant_refusal.unwrap_or_default()
        ),
        LoopEnd::Stopped { .. } => "stopped by signal".to_string(),
        LoopEnd::HalError { tick, kind, message } => {
            format!("HAL failure at tick {tick} ({kind:?}): {message}; motors commanded to damping")
        }
        LoopEnd::Panicked {
            tick,
            message,
            damping_sent,
        } => format!(
            "panicked at tick {tick} (a bug: {message}); damping {} on every enabled motor",
            if *damping_sent { "sent" } else { "could not be sent" }
        ),
    }
}

#[cfg(test)]
mod variant_tests {
    use super::variant_mismatch;

    #[test]
    fn a_spec_that_drives_a_motor_the_variant_lacks_is_refused_by_name() {
        let mut driven = [false; hal::NUM_MOTORS];
        driven[..12].fill(true); // legs
        for mm in [0, 1, 2, 3, 4, 5, 6, 77] {
            assert_eq!(variant_mismatch(mm, &driven), None, "legs run on variant {mm}");
        }
        let m = variant_mismatch(9, &driven).expect("the dual-arm G1 has no legs");
        assert!(
            m.contains("g1_dual_arm") && m.contains("left_hip_pitch") && m.contains("motors"),
            "{m}"
        );
        driven[13] = true; // waist roll
        assert_eq!(variant_mismatch(2, &driven), None);
        let m = variant_mismatch(3, &driven).expect("the locked waist has no roll motor");
        assert!(m.contains("g1_lock_waist") && m.contains("no waist_roll motor,"), "{m}");
        assert!(variant_mismatch(4, &driven).is_some());
    }
}
