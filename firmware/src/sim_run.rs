//! `g1fw sim`: start the simulator, run the firmware loop against it over the bridge, and evaluate
//! the run from the simulator's privileged ground truth (which never reaches the controller).
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{bail, Context as _, Result};
use serde::Serialize;
use sha2::{Digest, Sha256};
use sim_hal::bridge::{BridgeHal, SimLaunch, SimProcess, StairProgress, Truth, Wants};

pub use crate::run_report::{spec_meta, SafetyReport, TripReport};
use control::controller::{Controller, Mode};
use control::operator::{CommandSchedule, HeadingSource, OperatorInput, OperatorSource, ScheduleSource};
use control::perception::TerrainSource;
use control::runtime::{run_loop, LatencySummary, LoopEnd, Runtime, TickView};
use control::spec::DeploySpec;
use runlog::log::{LogOptions, LogStats, Logger, RunMeta};
use runlog::replay::key;

/// Everything `g1fw sim` needs besides the spec.
#[derive(Clone, Debug)]
pub struct SimOptions {
    /// `g1-29dof`, `g1-12dof` or a path to an MJCF file (passed to the simulator).
    pub model: String,
    /// Operator commands over time (a constant command is a one-line schedule).
    pub schedule: CommandSchedule,
    pub duration_s: f64,
    pub seed: u64,
    pub physics_dt: f64,
    /// Overrides the spec's start-up ramp and hold (seconds).
    pub ramp_override: Option<(f64, f64)>,
    /// The simulator binary; found beside this executable when `None`.
    pub sim_bin: Option<PathBuf>,
    /// Connect to an already running simulator at this Unix socket instead of starting one.
    pub connect: Option<PathBuf>,
    /// Stop at the first fall (base z < 0.5 m or tilt > 60°).
    pub stop_on_fall: bool,
    /// Do not load the policy; ramp to the default pose and hold.
    pub hold_only: bool,
    /// The operator steps the run through its states (passive at start; the schedule's requests).
    pub operated: bool,
    pub progress: bool,
    /// Faults for the simulator to inject (`g1-sim --fault` grammar).
    pub faults: Vec<String>,
    /// IMU error model for the simulator (`g1-sim --imu-noise` grammar, e.g. `realistic`).
    pub imu_noise: Option<String>,
    /// The simulator's integrator (`g1-sim --integrator`): `None` its default (implicitfast, the
    /// PD's damping implicit), `euler` to reproduce an explicit-PD reference loop.
    pub integrator: Option<String>,
    /// The simulator's physics profile (`g1-sim --physics`): `None` its default (deploy), or
    /// `training` (the trainer's lean contacts and solver).
    pub physics: Option<String>,
    /// Terrain world for the simulator (`g1-sim --world`: preset, scenario file or random:SEED).
    /// With a world the simulator also streams its MID-360 and the perception group runs.
    pub world: Option<String>,
    /// Record an MCAP log here.
    pub log: Option<PathBuf>,
    pub log_options: LogOptions,
    /// Real-time set-up of the control thread.
    pub rt: control::rt::RtOptions,
    /// Where the policy's terrain token comes from (`None`: the spec's estimator).
    pub terrain_source: Option<TerrainSource>,
    /// Perception inline (default) or on a worker thread (waited for when late: simulation time
    /// does not run on while it computes, so the run stays deterministic).
    pub perception: control::perception_worker::PerceptionExec,
    /// Heading correction: the schedule's vx with [`control::operator::heading_command`] towards
    /// this target every tick (`None`: the schedule's commands as they are).
    pub heading: Option<Heading>,
    /// With a heading: also steer back to the line through the start along it, from the
    /// estimator's position ([`control::operator::line_heading`]).
    pub hold_line: bool,
    /// Stop once the base has stood on the staircase's end landing this long (s), with no fall
    /// and no safety trip: the run has succeeded (saves time in evaluations).
    pub stop_after_landing_s: Option<f64>,
    /// Stop when this becomes true (SIGINT/SIGTERM handlers set it): the log is closed, the
    /// simulator stopped and reaped, and the report says `interrupted`.
    pub stop: Arc<AtomicBool>,
}

/// The target of the heading correction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Heading {
    /// Target yaw in the world frame (= relative to the start heading: the robot starts at yaw 0), rad.
    Fixed(f32),
    /// The staircase's axis direction (the scenario's `yaw_deg`), as an operator pointing the robot
    /// at the stairs would; read once from the world's layout before the first tick (0 on flat
    /// ground). The world's geometry, never the robot's state.
    StairAxis,
}

/// The run's operator: the schedule, with or without heading correction.
enum SimOperator<'a> {
    Plain(ScheduleSource<'a>),
    Heading(HeadingSource<ScheduleSource<'a>>),
}

impl OperatorSource for SimOperator<'_> {
    fn at(&mut self, tick: hal::TickTime) -> OperatorInput {
        match self {
            SimOperator::Plain(s) => s.at(tick),
            SimOperator::Heading(h) => h.at(tick),
        }
    }
    fn at_state(&mut self, tick: hal::TickTime, state: &hal::LowState) -> OperatorInput {
        match self {
            SimOperator::Plain(s) => s.at_state(tick, state),
            SimOperator::Heading(h) => h.at_state(tick, state),
        }
    }
    fn at_estimate(
        &mut self,
        tick: hal::TickTime,
        state: &hal::LowState,
        estimate: &estimator::BaseEstimate,
    ) -> OperatorInput {
        match self {
            SimOperator::Plain(s) => s.at_estimate(tick, state, estimate),
            SimOperator::Heading(h) => h.at_estimate(tick, state, estimate),
        }
    }
}

impl Default for SimOptions {
    fn default() -> Self {
        Self {
            model: "g1-29dof".into(),
            schedule: CommandSchedule::constant([0.0; 3]),
            duration_s: 10.0,
            seed: 0,
            physics_dt: 0.002,
            ramp_override: None,
            sim_bin: None,
            connect: None,
            stop_on_fall: true,
            hold_only: false,
            operated: false,
            progress: false,
            faults: Vec::new(),
            imu_noise: None,
            world: None,
            integrator: None,
            physics: None,
            log: None,
            log_options: LogOptions::default(),
            rt: control::rt::RtOptions::default(),
            terrain_source: None,
            perception: control::perception_worker::PerceptionExec::Inline,
            heading: None,
            hold_line: false,
            stop: Arc::new(AtomicBool::new(false)),
            stop_after_landing_s: None,
        }
    }
}

/// The JSON report of a run. Fields under `timing` depend on the machine; everything else is a
/// deterministic function of the inputs (same seed and spec → bit-identical).
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    pub fell: bool,
    pub fell_at_s: Option<f64>,
    pub time_s: f64,
    pub distance_x_m: f64,
    pub distance_y_m: f64,
    pub heading_change_rad: f64,
    pub mean_body_vx_second_half: f64,
    pub mean_body_vy_second_half: f64,
    pub mean_body_wz_second_half: f64,
    pub base_z_min: f64,
    pub base_z_max: f64,
    pub tilt_max_deg: f64,
    pub ticks: u64,
    pub policy_steps: u64,
    /// Every change of state (startup, policy, damping; an operated run's passive, stand and
    /// sit_down), its source and time.
    pub transitions: Vec<crate::run_report::ModeChange>,
    pub final_mode: String,
    pub repeated_commands: u64,
    /// sha256 over every LowState and LowCmd frame of the run, in order.
    pub state_trace_sha256: String,
    pub model: String,
    pub spec: String,
    pub weights_sha256: String,
    /// The command of the first schedule step (the whole run's, for a constant command), as given.
    pub command: [f32; 3],
    /// The same as the policy received it: clamped to the spec's `[commands]` limits. Tracking is
    /// scored against this.
    pub command_received: [f32; 3],
    /// Set when any command was clamped: the first one, and the limits (reported once).
    pub command_clamped: Option<CommandClamp>,
    pub seed: u64,
    /// Velocity tracking against the operator's commands (body frame, from ground truth).
    pub tracking: Tracking,
    /// The first latched damping: tick, time and reason.
    pub trip: Option<TripReport>,
    pub safety: SafetyReport,
    /// How the run ended: `completed`, `fell`, `interrupted ...`, or the HAL failure.
    pub end: String,
    /// Stopped early by SIGINT/SIGTERM: the figures cover the run up to then.
    pub interrupted: bool,
    pub log: Option<LogStats>,
    /// State estimator against ground truth, beside the naive baseline (`null` without leg
    /// kinematics in the spec).
    #[serde(flatten)]
    pub estimator: EstimatorReport,
    /// Perception against the world's ground truth (`null` without `--world`).
    pub terrain: Option<TerrainReport>,
    /// Where the policy's terrain token came from: `cnn`, `geometric`, `truth` (evaluation
    /// ablation: the simulator's ground truth) or `none` (flat).
    pub terrain_source: String,
    /// Target of the heading correction, degrees in the world frame (`null`: none).
    pub heading_target_deg: Option<f64>,
    /// Seconds under policy control (after the start-up ramp and hold).
    pub policy_time_s: f64,
    /// Progress over the world's staircase (`null` without one).
    pub stairs: Option<StairsReport>,
    #[serde(flatten)]
    pub timing: Timing,
    /// Why the log could not be written (the run stopped there), if it could not.
    pub log_error: Option<String>,
}

/// Progress over a staircase, from the simulator's ground truth ([`StairProgress`]).
///
/// **Reached the end landing**: the base (pelvis) is at least
/// [`sim_hal::bridge::END_LANDING_MARGIN_M`] (0.25 m) past the last riser's edge along the
/// staircase axis, not beyond the landing's far end, and within the stair width. **Success**: it
/// did so within the run, and the run had no fall (base < 0.5 m or tilt > 60°) and no safety trip.
#[derive(Clone, Debug, Default, Serialize)]
pub struct StairsReport {
    /// `up` or `down` (the sign of the end landing's level minus the start landing's).
    pub kind: String,
    pub risers: u16,
    /// Mean riser height (total rise / risers), m.
    pub mean_step_height_m: f64,
    /// Most risers behind the base at any tick.
    pub risers_passed: u16,
    /// Farthest base position along the axis, from the first riser, m.
    pub max_axis_s_m: f64,
    pub reached_end_landing: bool,
    pub reached_end_landing_at_s: Option<f64>,
    pub success: bool,
}

#[derive(Default)]
struct StairsEval {
    seen: Option<StairProgress>,
    passed: u16,
    max_s: f64,
    reached_at: Option<f64>,
    on_landing: LandingHold,
}

/// How long the base has stood on the end landing without a break: what `--stop-after-landing`
/// waits for, and the trainer's success (one definition for both).
#[derive(Clone, Copy, Debug, Default)]
pub struct LandingHold {
    since_s: Option<f64>,
}

impl LandingHold {
    /// Records whether the base is on the end landing at `time_s`.
    pub fn observe(&mut self, on_end_landing: bool, time_s: f64) {
        if on_end_landing {
            self.since_s.get_or_insert(time_s);
        } else {
            self.since_s = None;
        }
    }

    /// Whether, at `time_s`, the base has stood on the landing at least `hold_s` without a break.
    pub fn held(&self, hold_s: f64, time_s: f64) -> bool {
        self.since_s.is_some_and(|since| time_s - since >= hold_s)
    }
}

impl StairsEval {
    fn add(&mut self, p: &StairProgress, time_s: f64) {
        if self.seen.is_none() {
            self.max_s = p.axis_s;
        }
        self.seen = Some(*p);
        self.passed = self.passed.max(p.risers_passed);
        self.max_s = self.max_s.max(p.axis_s);
        if p.on_end_landing {
            self.reached_at.get_or_insert(time_s);
        }
        self.on_landing.observe(p.on_end_landing, time_s);
    }

    fn report(&self, clean: bool) -> Option<StairsReport> {
        let p = self.seen?;
        Some(StairsReport {
            kind: if p.rise_m >= 0.0 { "up" } else { "down" }.into(),
            risers: p.risers,
            mean_step_height_m: (p.rise_m.abs() as f64) / (p.risers.max(1) as f64),
            risers_passed: self.passed,
            max_axis_s_m: self.max_s,
            reached_end_landing: self.reached_at.is_some(),
            reached_end_landing_at_s: self.reached_at,
            success: self.reached_at.is_some() && clean,
        })
    }
}

/// The terrain token of every fresh lidar frame against the ground truth at that tick. MAE(h),
/// MAE(d) over all frames (flat: 0), MAE(yaw) over frames whose truth is stairs.
#[derive(Clone, Debug, Default, Serialize)]
pub struct TerrainReport {
    pub world: String,
    pub frames: u64,
    pub class_acc: Option<f64>,
    pub mae_h_cm: Option<f64>,
    pub mae_d_cm: Option<f64>,
    pub mae_yaw_deg: Option<f64>,
    /// Frames whose geometric estimate was implausible (token held).
    pub held_frames: u64,
    /// Mean points per frame after decoding.
    pub mean_points: Option<f64>,
    pub lidar_malformed_packets: u64,
    pub lidar_lost_packets: u64,
    /// Truth class counts (flat, up, down) over the frames.
    pub truth_classes: [u64; 3],
}

#[derive(Default)]
struct TerrainEval {
    frames: u64,
    correct: u64,
    err_h: f64,
    err_d: f64,
    err_yaw: f64,
    stairs: u64,
    held: u64,
    points: u64,
    classes: [u64; 3],
}

impl TerrainEval {
    fn add(&mut self, t: &Truth, v: &TickView) {
        let (Some(p), Some(z)) = (v.summary.perception, t.terrain) else {
            return;
        };
        if !p.fresh {
            return;
        }
        let e = p.estimate;
        self.frames += 1;
        self.points += p.points as u64;
        self.held += p.held as u64;
        self.classes[z.class.index()] += 1;
        self.correct += (e.class == z.class) as u64;
        self.err_h += (e.step_height_m - z.step_height_m).abs() as f64;
        self.err_d += (e.step_depth_m - z.step_depth_m).abs() as f64;
        if z.class != hal::TerrainClass::Flat {
            self.stairs += 1;
            self.err_yaw += hal::wrap_angle((e.yaw_rad - z.yaw_rad) as f64).abs();
        }
    }

    fn report(&self, world: &str, lidar: Option<sim_hal::bridge::LidarCounters>) -> TerrainReport {
        let n = self.frames as f64;
        let per = |v: f64, k: u64, scale: f64| (k > 0).then(|| v / k as f64 * scale);
        TerrainReport {
            world: world.to_string(),
            frames: self.frames,
            class_acc: per(self.correct as f64, self.frames, 1.0),
            mae_h_cm: per(self.err_h, self.frames, 100.0),
            mae_d_cm: per(self.err_d, self.frames, 100.0),
            mae_yaw_deg: per(self.err_yaw, self.stairs, 180.0 / std::f64::consts::PI),
            held_frames: self.held,
            mean_points: (self.frames > 0).then(|| self.points as f64 / n),
            lidar_malformed_packets: lidar.map_or(0, |c| c.decoder.malformed.total() + c.framing_errors),
            lidar_lost_packets: lidar.map_or(0, |c| c.decoder.lost_packets),
            truth_classes: self.classes,
        }
    }
}

/// Estimator errors over every fast tick from the first valid estimate on (body-frame velocity,
/// base height, both feet's contact state agreeing with the simulator's).
#[derive(Clone, Debug, Default, Serialize)]
pub struct EstimatorReport {
    pub est_ticks: u64,
    pub est_vel_rmse_x: Option<f64>,
    pub est_vel_rmse_y: Option<f64>,
    pub est_vel_rmse_z: Option<f64>,
    pub est_height_rmse_m: Option<f64>,
    /// Fraction of (tick, foot) pairs on which the estimated contact matches the simulator's.
    pub est_contact_agreement: Option<f64>,
    /// The same per foot (left, right).
    pub est_contact_agreement_feet: Option<[f64; 2]>,
    /// Fraction of ticks on which both feet match at once (the strictest reading).
    pub est_contact_agreement_both_feet: Option<f64>,
    /// Integrated accelerometer from rest and the "lower foot is down" rule.
    pub baseline_vel_rmse_x: Option<f64>,
    pub baseline_vel_rmse_y: Option<f64>,
    pub baseline_height_rmse_m: Option<f64>,
    pub baseline_contact_agreement: Option<f64>,
    pub baseline_contact_agreement_both_feet: Option<f64>,
}

/// A command the spec's `[commands]` limits changed before the policy saw it.
#[derive(Clone, Debug, Serialize)]
pub struct CommandClamp {
    pub at_s: f64,
    pub given: [f32; 3],
    pub received: [f32; 3],
    pub min: Option<[f32; 3]>,
    pub max: Option<[f32; 3]>,
}

/// Tracking error of one command segment, measured after `settle_s` (the robot needs time to reach
/// a new command) while the policy is in control.
#[derive(Clone, Debug, Serialize)]
pub struct SegmentTracking {
    pub start_s: f64,
    pub end_s: f64,
    pub command: [f32; 3],
    /// As the policy received it (clamped), what `rmse` is scored against.
    pub command_received: [f32; 3],
    pub samples: u64,
    pub mean_measured: [f64; 3],
    pub rmse: [f64; 3],
}

#[derive(Clone, Debug, Serialize)]
pub struct Tracking {
    pub settle_s: f64,
    pub segments: Vec<SegmentTracking>,
    /// Over all segments' settled samples: vx, vy (m/s), wz (rad/s).
    pub rmse: [f64; 3],
}

/// Wall-clock figures: measured, never used by control, not part of determinism.
#[derive(Clone, Debug, Serialize)]
pub struct Timing {
    pub sim_seconds_per_wall_second: f64,
    /// Fast-group compute per tick (read, estimate, safety, command).
    pub fast_group_us: LatencySummary,
    /// Whole-tick compute (fast plus whichever groups ran).
    pub tick_compute_us: LatencySummary,
}

fn yaw(q: [f64; 4]) -> f64 {
    let [w, x, y, z] = q;
    libm::atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
}

/// Runs the firmware against the simulator. `observe` sees every tick (evaluation only).
/// Longest run `g1fw sim` accepts: a day of simulated time (its report keeps a sample per tick).
pub const MAX_DURATION_S: f64 = 86_400.0;

pub fn run_sim(mut spec: DeploySpec, opts: &SimOptions, mut observe: impl FnMut(&TickView)) -> Result<Report> {
    if !(opts.duration_s.is_finite() && opts.duration_s > 0.0 && opts.duration_s <= MAX_DURATION_S) {
        bail!(
            "--duration {} s: give a positive number of seconds, at most {MAX_DURATION_S} (a day)",
            opts.duration_s
        );
    }
    if let Some((ramp, hold)) = opts.ramp_override {
        spec.startup.ramp_s = ramp;
        spec.startup.hold_s = hold;
    }
    if let Some(k) = opts.terrain_source.and_then(TerrainSource::estimator) {
        spec.perception.terrain_estimator = k;
    }
    let terrain_source = opts
        .terrain_source
        .unwrap_or_else(|| TerrainSource::of_spec(&spec.perception));
    let spec_name = spec.path.display().to_string();
    let control_dt = spec.control_dt();
    let mut meta = run_meta(&spec, opts);
    meta.set(key::TERRAIN_SOURCE, terrain_source.as_str());
    let mut controller = if opts.hold_only {
        Controller::hold_only(spec)
    } else {
        Controller::new(spec)?
    };
    if opts.operated {
        controller.operate();
    }
    let (obs_dim, act_dim) = (controller.spec().observation_dim(), controller.spec().num_joints());
    let weights_sha256 = controller.weights_sha256();
    meta.set(key::WEIGHTS_SHA256, &weights_sha256);

    let (mut hal, mut child) = start_simulator(opts, control_dt, &controller)?;
    let welcome = *hal.welcome();
    let heading_target = opts.heading.map(|h| match h {
        Heading::Fixed(y) => y,
        Heading::StairAxis => hal.truth().stairs.map_or(0.0, |p| p.axis_yaw_rad),
    });
    if let Some(y) = heading_target {
        meta.set("heading_target_rad", y);
    }
    let mut logger = match &opts.log {
        Some(path) => Some(Logger::create(path, &meta, obs_dim, act_dim, opts.log_options.clone())?),
        None => None,
    };
    control::rt::apply(&opts.rt)?;

    let total_ticks = (opts.duration_s / control_dt).round() as u64;
    let progress = opts.progress.then(|| progress_bar(opts.duration_s));
    let mut ev = Evaluation {
        hasher: Sha256::new(),
        agg: Aggregate::new(&opts.schedule, total_ticks as usize),
        est: EstimatorEval::new(controller.spec().kinematics.clone(), control_dt),
        terrain: TerrainEval::default(),
        stairs: StairsEval::default(),
        policy_ticks: 0,
    };
    let mut runtime = Runtime::new(controller);
    runtime.set_terrain_source(terrain_source);
    runtime
        .set_perception_exec(opts.perception)
        .context("starting the perception thread")?;
    let mut operator = match heading_target {
        None => SimOperator::Plain(opts.schedule.source(welcome.control_dt_ns)),
        Some(target_yaw) => SimOperator::Heading(HeadingSource {
            inner: opts.schedule.source(welcome.control_dt_ns),
            target_yaw,
            hold_line: opts.hold_line,
        }),
    };
    let (mut landed, mut interrupted, mut log_failed) = (false, false, false);
    let wall = Instant::now();
    let mut ticks = 0u64;

    let mut mode_changes = crate::run_report::ModeChanges::starting(runtime.controller().mode());
    let end = run_loop(&mut hal, &mut runtime, &mut operator, total_ticks, |v| {
        mode_changes.observe(v.summary, control_dt, "schedule");
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

        // Everything below is evaluation: it runs while the simulator steps.
        ev.add(v, control_dt, opts.duration_s);
        let k = v.summary.tick.index;
        ticks = k;
        let agg = &ev.agg;
        if let Some(hold) = opts.stop_after_landing_s {
            landed |= ev.stairs.on_landing.held(hold, k as f64 * control_dt)
                && agg.fell_at.is_none()
                && v.runtime.trip().is_none();
        }
        observe(v);
        if let Some(pb) = &progress {
            if k % 50 == 0 {
                pb.set_position((k as f64 * control_dt * 1000.0) as u64);
                pb.set_message(format!(
                    "x {:+.2} m  z {:.2} m  {:?}",
                    agg.last[0] - agg.start[0],
                    agg.last[2],
                    v.summary.mode
                ));
            }
        }
        interrupted = opts.stop.load(Ordering::Relaxed);
        !(landed || interrupted || opts.stop_on_fall && agg.fell_at.is_some())
    });
    if let Some(pb) = progress {
        pb.finish_and_clear();
    }
    let wall_s = wall.elapsed().as_secs_f64();
    let repeated = hal.repeated_commands();
    let lidar_counters = hal.lidar_counters();
    hal.close();
    let gone = simulator_gone(&mut child);
    drop(child);
    // The log is closed on every path, so a failed run keeps everything it recorded.
    let (log_stats, log_error) = match logger.map(|l| l.finish()) {
        Some(Ok(s)) => (Some(s), None),
        Some(Err(e)) => (None, Some(control::nn::with_causes(&e))),
        None => (None, None),
    };
    let end_text = describe_end(&end, opts, interrupted, landed, &gone)?;

    let time_s = ticks as f64 * control_dt;
    let trip = TripReport::of(&runtime, control_dt);
    let Evaluation {
        hasher,
        agg,
        est: est_eval,
        terrain: terrain_eval,
        stairs: stairs_eval,
        policy_ticks,
    } = ev;
    let clean = agg.fell_at.is_none() && trip.is_none() && !matches!(end, LoopEnd::HalError { .. });
    Ok(Report {
        log_error,
        fell: agg.fell_at.is_some(),
        fell_at_s: agg.fell_at,
        time_s,
        distance_x_m: agg.last[0] - agg.start[0],
        distance_y_m: agg.last[1] - agg.start[1],
        heading_change_rad: agg.heading_change,
        mean_body_vx_second_half: agg.mean(0),
        mean_body_vy_second_half: agg.mean(1),
        mean_body_wz_second_half: agg.mean(2),
        base_z_min: agg.z_min,
        base_z_max: agg.z_max,
        tilt_max_deg: agg.tilt_max,
        ticks,
        policy_steps: runtime.controller().policy_steps(),
        transitions: mode_changes.changes,
        final_mode: format!("{:?}", runtime.mode()),
        repeated_commands: repeated,
        state_trace_sha256: format!("{:x}", hasher.finalize()),
        model: opts.model.clone(),
        spec: spec_name,
        weights_sha256,
        command: opts.schedule.velocity_at(0.0),
        command_received: runtime.controller().clamp_command(opts.schedule.velocity_at(0.0)),
        command_clamped: agg.first_clamp.clone(),
        seed: opts.seed,
        tracking: agg.tracking(&opts.schedule, opts.duration_s),
        trip,
        safety: SafetyReport::of(&runtime),
        end: end_text,
        interrupted,
        log: log_stats,
        estimator: est_eval.report(),
        terrain: opts.world.as_ref().map(|w| terrain_eval.report(w, lidar_counters)),
        terrain_source: terrain_source.as_str().into(),
        heading_target_deg: heading_target.map(|y| (y as f64).to_degrees()),
        policy_time_s: policy_ticks as f64 * control_dt,
        stairs: stairs_eval.report(clean),
        timing: Timing {
            sim_seconds_per_wall_second: time_s / wall_s.max(1e-9),
            fast_group_us: runtime.timing_stats().fast(),
            tick_compute_us: runtime.timing_stats().tick(),
        },
    })
}

/// What `g1fw sim` measures while the simulator steps: a hash of the state and command trace, and
/// the ground-truth evaluations of the report.
struct Evaluation {
    hasher: Sha256,
    agg: Aggregate,
    est: EstimatorEval,
    terrain: TerrainEval,
    stairs: StairsEval,
    policy_ticks: u64,
}

impl Evaluation {
    fn add(&mut self, v: &TickView, control_dt: f64, duration_s: f64) {
        if let Some(raw) = v.raw_state {
            self.hasher.update(raw);
        }
        if v.command_sent {
            let mut b = [0u8; sensor_io::unitree_hg::LOW_CMD_LEN];
            sensor_io::unitree_hg::encode_low_cmd(v.command, &mut b);
            self.hasher.update(b);
        }
        let t = v.summary.tick.index as f64 * control_dt;
        if let Some(truth) = v.truth {
            self.agg.add(truth, t, duration_s, v);
            self.est.add(truth, v);
            self.terrain.add(truth, v);
            if let Some(p) = &truth.stairs {
                self.stairs.add(p, t);
            }
        }
        self.policy_ticks += (v.summary.mode == Mode::Policy) as u64;
    }
}

/// Starts `g1-sim` (or connects to a running one) and checks that it ticks at the spec's rate and
/// has every joint the policy drives.
fn start_simulator(
    opts: &SimOptions,
    control_dt: f64,
    controller: &Controller,
) -> Result<(BridgeHal, Option<SimProcess>)> {
    let mut child = None;
    let want = Wants {
        truth: true,
        lidar: opts.world.is_some(),
    };
    let hal = match &opts.connect {
        Some(path) => BridgeHal::connect_unix(path, want, Duration::from_secs(10), || Ok(()))?,
        None => {
            let launch = SimLaunch {
                bin: opts.sim_bin.clone(),
                seed: opts.seed,
                physics_dt: opts.physics_dt,
                faults: opts.faults.clone(),
                imu_noise: opts.imu_noise.clone(),
                world: opts.world.clone(),
                integrator: opts.integrator.clone(),
                physics: opts.physics.clone(),
                ..SimLaunch::new(&opts.model, control_dt)
            };
            let (c, hal) = launch.start("g1fw", want, Duration::from_secs(30))?;
            child = Some(c);
            hal
        }
    };
    let welcome = *hal.welcome();
    if (welcome.control_dt_ns as f64 * 1e-9 - control_dt).abs() > 1e-9 {
        bail!(
            "the simulator ticks every {} ns but the deploy spec asks for control_hz {}",
            welcome.control_dt_ns,
            1.0 / control_dt
        );
    }
    let missing: Vec<&str> = controller
        .spec()
        .policy
        .joint_ids_map
        .iter()
        .filter(|&&s| welcome.motor_slots_present & (1 << s) == 0)
        .map(|&s| hal::G1_MOTOR_NAMES[s])
        .collect();
    if !missing.is_empty() {
        bail!(
            "the model '{}' lacks joints the policy drives: {}",
            opts.model,
            missing.join(", ")
        );
    }
    Ok((hal, child))
}

/// What ended the run, in words; an internal error or an unexpected HAL failure is an error.
fn describe_end(end: &LoopEnd, opts: &SimOptions, interrupted: bool, landed: bool, gone: &str) -> Result<String> {
    Ok(match end {
        LoopEnd::Completed { .. } => "completed".to_string(),
        LoopEnd::Stopped { ticks } if interrupted => {
            format!("interrupted by a signal at tick {ticks}; the log is closed and the simulator stopped")
        }
        LoopEnd::Stopped { .. } if landed => format!(
            "stopped: on the end landing for {:.1} s (success)",
            opts.stop_after_landing_s.unwrap_or(0.0)
        ),
        LoopEnd::Stopped { .. } => "fell".to_string(),
        LoopEnd::Panicked {
            tick,
            message,
            damping_sent,
        } => bail!(
            "internal error: the control loop panicked at tick {tick} ({message}); damping {}{}",
            if *damping_sent { "sent" } else { "could not be sent" },
            log_note(&opts.log)
        ),
        LoopEnd::HalError { tick, kind, message } => {
            let what = match kind {
                hal::ErrorKind::Disconnected => {
                    format!("{gone} at tick {tick}: {message}; motors commanded to damping")
                }
                _ => format!("HAL failure at tick {tick} ({kind:?}): {message}; motors commanded to damping"),
            };
            if !opts.faults.is_empty() {
                // An injected disconnect ends the run by design; report it rather than fail.
                what
            } else {
                bail!("{what}{}", log_note(&opts.log));
            }
        }
    })
}

fn log_note(log: &Option<PathBuf>) -> String {
    match log {
        Some(p) => format!(" (the log {} holds everything up to the failure)", p.display()),
        None => String::new(),
    }
}

fn run_meta(spec: &DeploySpec, opts: &SimOptions) -> RunMeta {
    let mut m = spec_meta(spec, opts.hold_only);
    m.set(key::OPERATED, opts.operated);
    if opts.operated {
        m.set(key::OPERATOR, "schedule");
    }
    if opts.perception != control::perception_worker::PerceptionExec::Inline {
        m.set(key::PERCEPTION_EXEC, opts.perception.label());
    }
    m.set("model", &opts.model)
        .set("seed", opts.seed)
        .set("physics_dt", opts.physics_dt)
        .set("duration_s", opts.duration_s)
        .set("faults", opts.faults.join(" "))
        .set("imu_noise", opts.imu_noise.as_deref().unwrap_or("none"))
        .set(
            "command_schedule",
            opts.schedule
                .source
                .as_ref()
                .map_or("constant".to_string(), |p| p.display().to_string()),
        );
    m
}
fn simulator_gone(child: &mut Option<SimProcess>) -> String {
    match child.as_mut().map(|c| c.alive()) {
        Some(Err(why)) => format!("lost the simulator mid-run: {why}"),
        _ => "lost the simulator bridge mid-run".into(),
    }
}

fn progress_bar(duration_s: f64) -> indicatif::ProgressBar {
    let pb = indicatif::ProgressBar::new((duration_s * 1000.0) as u64);
    pb.set_style(
        indicatif::ProgressStyle::with_template("{spinner} sim {pos:>6}/{len} ms [{bar:30}] {msg}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    pb
}

/// Running evaluation figures from ground truth.
struct Aggregate {
    started: bool,
    start: [f64; 3],
    last: [f64; 3],
    start_yaw: f64,
    heading_change: f64,
    prev_yaw: f64,
    z_min: f64,
    z_max: f64,
    tilt_max: f64,
    fell_at: Option<f64>,
    sum_second_half: [f64; 3],
    n_second_half: u64,
    /// (time, command as received, measured body velocity) of ticks under policy control.
    samples: Vec<(f64, [f32; 3], [f64; 3])>,
    /// The first command the spec's limits changed.
    first_clamp: Option<CommandClamp>,
}

/// Seconds after a command change that tracking errors ignore.
const SETTLE_S: f64 = 1.0;

impl Aggregate {
    fn new(_schedule: &CommandSchedule, ticks: usize) -> Self {
        Self {
            started: false,
            start: [0.0; 3],
            last: [0.0; 3],
            start_yaw: 0.0,
            heading_change: 0.0,
            prev_yaw: 0.0,
            z_min: f64::INFINITY,
            z_max: f64::NEG_INFINITY,
            tilt_max: 0.0,
            fell_at: None,
            sum_second_half: [0.0; 3],
            n_second_half: 0,
            samples: Vec::with_capacity(ticks + 1),
            first_clamp: None,
        }
    }

    fn add(&mut self, t: &Truth, time_s: f64, duration_s: f64, v: &TickView) {
        let y = yaw(t.base_quat);
        if !self.started {
            self.started = true;
            self.start = t.base_pos;
            self.start_yaw = y;
            self.prev_yaw = y;
        }
        // Unwrap yaw so turning in place accumulates past ±π.
        let mut dy = y - self.prev_yaw;
        dy -= (dy / std::f64::consts::TAU).round() * std::f64::consts::TAU;
        self.heading_change += dy;
        self.prev_yaw = y;
        self.last = t.base_pos;
        let z = t.base_pos[2];
        self.z_min = self.z_min.min(z);
        self.z_max = self.z_max.max(z);
        self.tilt_max = self.tilt_max.max(t.tilt_deg());
        if self.fell_at.is_none() && t.fallen() {
            self.fell_at = Some(time_s);
        }
        let meas = [t.base_lin_vel_body[0], t.base_lin_vel_body[1], t.base_ang_vel_body[2]];
        if time_s >= duration_s / 2.0 {
            (0..3).for_each(|i| self.sum_second_half[i] += meas[i]);
            self.n_second_half += 1;
        }
        let given = v.summary.operator.velocity;
        if self.first_clamp.is_none() && v.summary.command_received != given {
            let c = &v.runtime.controller().spec().commands;
            self.first_clamp = Some(CommandClamp {
                at_s: time_s,
                given,
                received: v.summary.command_received,
                min: c.min,
                max: c.max,
            });
        }
        if v.summary.mode == Mode::Policy {
            // Scored against the command the policy received (clamped to `[commands]`).
            self.samples.push((time_s, v.summary.command_received, meas));
        }
    }

    fn mean(&self, i: usize) -> f64 {
        self.sum_second_half[i] / self.n_second_half.max(1) as f64
    }

    fn tracking(&self, schedule: &CommandSchedule, duration_s: f64) -> Tracking {
        let segs = schedule.velocity_segments();
        let mut out = Vec::new();
        let (mut all_sq, mut all_n) = ([0.0f64; 3], 0u64);
        for (i, &(start, cmd)) in segs.iter().enumerate() {
            let end = segs.get(i + 1).map_or(duration_s, |s| s.0);
            let (mut sum, mut sq, mut n) = ([0.0f64; 3], [0.0f64; 3], 0u64);
            // Errors against the command sent on that tick: with the heading correction its wz
            // is the correction's, not the schedule's.
            for &(t, c, m) in &self.samples {
                if t >= start + SETTLE_S && t < end {
                    for a in 0..3 {
                        sum[a] += m[a];
                        sq[a] += (m[a] - c[a] as f64).powi(2);
                    }
                    n += 1;
                }
            }
            (0..3).for_each(|a| all_sq[a] += sq[a]);
            all_n += n;
            let nf = n.max(1) as f64;
            out.push(SegmentTracking {
                start_s: start,
                end_s: end,
                command: cmd,
                command_received: self
                    .samples
                    .iter()
                    .find(|&&(t, _, _)| t >= start && t < end)
                    .map_or(cmd, |s| s.1),
                samples: n,
                mean_measured: sum.map(|x| x / nf),
                rmse: sq.map(|x| (x / nf).sqrt()),
            });
        }
        Tracking {
            settle_s: SETTLE_S,
            segments: out,
            rmse: all_sq.map(|x| (x / all_n.max(1) as f64).sqrt()),
        }
    }
}

/// Running estimator errors, and the naive baseline run beside the firmware (evaluation only).
struct EstimatorEval {
    kinematics: Option<estimator::LegKinematics>,
    dt: f64,
    baseline: Option<estimator::baseline::DeadReckoning>,
    last_tick: Option<u64>,
    n: u64,
    est_sq: [f64; 4],
    base_sq: [f64; 3],
    est_agree: [u64; 3],
    base_agree: [u64; 2],
}

impl EstimatorEval {
    fn new(kinematics: Option<estimator::LegKinematics>, dt: f64) -> Self {
        Self {
            kinematics,
            dt,
            baseline: None,
            last_tick: None,
            n: 0,
            est_sq: [0.0; 4],
            base_sq: [0.0; 3],
            est_agree: [0; 3],
            base_agree: [0; 2],
        }
    }

    fn add(&mut self, t: &Truth, v: &TickView) {
        use estimator::baseline::{lower_foot_contact, DeadReckoning};
        use nalgebra::{Quaternion, UnitQuaternion, Vector3};
        let e = &v.summary.estimate;
        let Some(kin) = &self.kinematics else { return };
        if !e.valid {
            return;
        }
        let k = v.summary.tick.index;
        let imu = &v.state.imu;
        let q = imu.quaternion.map(|x| x as f64);
        let rot = UnitQuaternion::from_quaternion(Quaternion::new(q[0], q[1], q[2], q[3]));
        let acc = Vector3::from(imu.accelerometer.map(|x| x as f64));
        // The baseline starts where the estimator starts (same initial height), then integrates.
        let b = self
            .baseline
            .get_or_insert_with(|| DeadReckoning::new(Vector3::from(e.position.map(|x| x as f64))));
        if v.summary.frame == control::supervisor::FrameStatus::Fresh {
            let steps = self.last_tick.map_or(1, |l| k.saturating_sub(l).max(1));
            if self.last_tick != Some(k) {
                b.step(steps as f64 * self.dt, &rot, &acc);
            }
            self.last_tick = Some(k);
        }
        let bv = b.body_velocity(&rot);
        let tv = t.base_lin_vel_body;
        let tz = t.base_pos[2];
        self.n += 1;
        for (sq, (ev, tv)) in self.est_sq.iter_mut().zip(e.lin_vel_body.iter().zip(tv)) {
            *sq += (*ev as f64 - tv).powi(2);
        }
        self.est_sq[3] += (e.position[2] as f64 - tz).powi(2);
        self.base_sq[0] += (bv.x - tv[0]).powi(2);
        self.base_sq[1] += (bv.y - tv[1]).powi(2);
        self.base_sq[2] += (b.position.z - tz).powi(2);
        for i in 0..2 {
            self.est_agree[i] += (e.contact[i] == t.foot_contact[i]) as u64;
        }
        self.est_agree[2] += (e.contact == t.foot_contact) as u64;
        // Naive contact: the lower foot (gravity-aligned) is down.
        let foot_z = [0, 1].map(|i| {
            let (q, _, _) = estimator::state::leg_joints(v.state, i);
            (rot * kin.leg(estimator::kinematics::LEGS[i]).foot_position(&q)).z
        });
        let naive = lower_foot_contact(foot_z, 0.01);
        self.base_agree[0] += (naive[0] == t.foot_contact[0]) as u64 + (naive[1] == t.foot_contact[1]) as u64;
        self.base_agree[1] += (naive == t.foot_contact) as u64;
    }

    fn report(&self) -> EstimatorReport {
        if self.n == 0 {
            return EstimatorReport::default();
        }
        let n = self.n as f64;
        let rms = |s: f64| Some((s / n).sqrt());
        EstimatorReport {
            est_ticks: self.n,
            est_vel_rmse_x: rms(self.est_sq[0]),
            est_vel_rmse_y: rms(self.est_sq[1]),
            est_vel_rmse_z: rms(self.est_sq[2]),
            est_height_rmse_m: rms(self.est_sq[3]),
            est_contact_agreement: Some((self.est_agree[0] + self.est_agree[1]) as f64 / (2.0 * n)),
            est_contact_agreement_feet: Some([self.est_agree[0] as f64 / n, self.est_agree[1] as f64 / n]),
            est_contact_agreement_both_feet: Some(self.est_agree[2] as f64 / n),
            baseline_vel_rmse_x: rms(self.base_sq[0]),
            baseline_vel_rmse_y: rms(self.base_sq[1]),
            baseline_height_rmse_m: rms(self.base_sq[2]),
            baseline_contact_agreement: Some(self.base_agree[0] as f64 / (2.0 * n)),
            baseline_contact_agreement_both_feet: Some(self.base_agree[1] as f64 / n),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::LandingHold;

    #[test]
    fn landing_hold_needs_an_unbroken_stay() {
        let mut h = LandingHold::default();
        assert!(!h.held(0.0, 0.0), "never on the landing: not held");
        h.observe(true, 1.0);
        h.observe(true, 1.5);
        assert!(!h.held(1.0, 1.5));
        h.observe(false, 1.6);
        h.observe(true, 1.7);
        assert!(!h.held(1.0, 2.6), "a step off the landing restarts the clock");
        assert!(h.held(1.0, 2.7));
    }
}
