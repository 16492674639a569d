//! `g1fw`: the G1 control firmware.
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{bail, Context, Result};
use clap::{Parser, Subcommand};
use control::operator::CommandSchedule;
use control::spec::DeploySpec;
#[cfg(feature = "lab")]
use firmware::sim_run::{run_sim, SimOptions};
use runlog::replay::{replay, ReplayOptions};

#[derive(Parser)]
#[command(
    name = "g1fw",
    version,
    about = "Unitree G1 control firmware: deploy-spec driven policy, PD targets, safety, simulation bridge"
)]
struct Cli {
    #[command(subcommand)]
    command: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Start the MuJoCo simulator (g1-sim) and run the firmware against it, lock-stepped over the
    /// bridge, then print (and optionally write) a JSON report evaluated from ground truth. Exit 0
    /// when no safety trip latched, 3 when one did (the report names it), 2 on errors, 130 when
    /// interrupted.
    #[cfg(feature = "lab")]
    Sim(Box<SimArgs>),
    /// Evaluate a (stair) policy through the real firmware loop: N episodes, each exactly a
    /// `g1fw sim` run (500 Hz, lock-stepped with its own g1-sim, perception on) walking forward at
    /// --vx with the heading correction pointed along the staircase axis. Success on stairs: the
    /// base reached the end landing (0.25 m past the last riser, within the stair width) within
    /// --time-limit with no fall and no safety trip; on flat: no fall, no trip and at least
    /// 0.8·vx·(time under policy) walked. Prints successes, failure causes (fell, safety trip and
    /// its reason, stalled, timeout, short) and a table per step height and kind; writes a JSON
    /// report with every episode.
    #[cfg(feature = "lab")]
    Eval(Box<EvalArgs>),
    /// Run the firmware on a robot: `--dds IFACE[,DOMAIN]` speaks the G1's own DDS topics
    /// (rt/lowstate, rt/lowcmd; the real robot on domain 0, unitree_mujoco or `g1-sim --dds` on
    /// `lo,1`); `--can-config` drives motors on CAN buses (docs/can.md; the vcan bench against
    /// `g1-can-emu`). Runs until --duration or SIGINT/SIGTERM. Every end damps: the duration ran out,
    /// a signal, a safety trip (damping from that tick on), a lost link or a crash of the loop, the
    /// damping command then goes out every control period for --end-damping seconds (default 1)
    /// before the program exits (docs/robot.md, "How a run ends"). Hold the robot (gantry, or the
    /// simulator's elastic band) until the start-up ramp has run. Prints a JSON report; exit 0 when
    /// no safety trip latched, 3 when one did, 2 on errors.
    Run(Box<RunArgs>),
    /// Load and validate a deploy spec and its weights, print a summary, exit non-zero on any error.
    CheckSpec {
        /// Deploy spec (TOML).
        #[arg(long)]
        spec: PathBuf,
    },
    /// Feed a recorded log's inputs through the same firmware code and compare every output bit for
    /// bit. Exit 0: identical; 1: diverged (the first divergent tick, channel and field are printed);
    /// 2: could not replay (missing or mismatched spec/weights, unreadable log) or the log is damaged
    /// (the ticks before the damage are replayed; the damaged chunk is named). A later file of a
    /// split log (--log-split-mb) replays on its own, from the run's state at its first tick.
    Replay(ReplayArgs),
    /// Render commanded vs measured base velocity of a logged simulation run to a PNG.
    #[cfg(feature = "lab")]
    Plot {
        /// A log written by `g1fw sim --log`.
        log: PathBuf,
        /// Output PNG.
        #[arg(long, short)]
        out: PathBuf,
    },
    /// Render one perception frame of a `g1fw sim --world` log to PNG: the six BEV channels
    /// (max z, min z, mean z, max−min, std, density; forward is up), the robot-centred cloud from
    /// above and from the side, and the terrain estimate against ground truth.
    #[cfg(feature = "lab")]
    Bev {
        /// A log written by `g1fw sim --world ... --log`.
        log: PathBuf,
        /// Log time of the frame, s (the nearest frame; default: the last).
        #[arg(long, value_parser = parse_at_s)]
        at: Option<f64>,
        /// Output PNG.
        #[arg(long, short)]
        out: PathBuf,
    },
    /// Summarise a log: run metadata, messages per channel, safety events, whether it was cut short.
    LogInfo { log: PathBuf },
}

#[derive(clap::Args)]
struct ReplayArgs {
    /// The MCAP log to replay.
    log: PathBuf,
    /// Spec file to use instead of the one the log names (must match the pinned hash unless
    /// --allow-mismatch).
    #[arg(long)]
    spec: Option<PathBuf>,
    /// Weights file to use instead of the spec's (must match the pinned hash unless --allow-mismatch).
    #[arg(long)]
    weights: Option<PathBuf>,
    /// Replay even if the spec or weights differ from the log's pinned hashes, to see where the
    /// outputs diverge.
    #[arg(long)]
    allow_mismatch: bool,
    /// Write the JSON replay report here.
    #[arg(long)]
    report: Option<PathBuf>,
}

#[cfg(feature = "lab")]
#[derive(clap::Args)]
struct SimArgs {
    /// Deploy spec (TOML): observation layout, joint map, gains, rates, weights file.
    #[arg(long, default_value = "specs/peer/unitree_g1_lstm.toml")]
    spec: PathBuf,
    /// Policy weights (safetensors) instead of the file the spec names, e.g. a training run's
    /// `g1_stairs_lstm.safetensors` or one of its `actors/` snapshots.
    #[arg(long, value_name = "FILE")]
    weights: Option<PathBuf>,
    /// Robot model: `g1-29dof` (mjlab's 29-dof G1, installed by scripts/install.sh), `g1-12dof`
    /// (../shared/assets/unitree_g1_12dof) or a path to an MJCF file.
    #[arg(long, default_value = "g1-29dof")]
    model: String,
    /// Velocity command vx,vy,wz (m/s, m/s, rad/s), held for the whole run.
    #[arg(long, default_value = "0.5,0,0", value_parser = parse_cmd, allow_hyphen_values = true, conflicts_with = "cmd_schedule")]
    cmd: [f32; 3],
    /// Piecewise-constant operator commands over time: lines `T VX VY WZ`, `T estop`, `T reset`
    /// (see specs/schedules/velocity_steps.txt).
    #[arg(long)]
    cmd_schedule: Option<PathBuf>,
    /// Record every HAL input and output and the firmware's derived products to this MCAP file
    /// (opens in Foxglove; replay with `g1fw replay`).
    #[arg(long)]
    log: Option<PathBuf>,
    /// Go on in a new log file once one has this many megabytes (as rosbag2's --max-bag-size):
    /// RUN.mcap, then RUN_1.mcap, RUN_2.mcap, … Each file starts with the run's state at its first
    /// tick, so each replays on its own (`g1fw replay RUN_2.mcap`).
    #[arg(long, value_name = "MB", value_parser = parse_log_split_mb, requires = "log")]
    log_split_mb: Option<f64>,
    /// Render commanded vs measured velocity to this PNG after the run.
    #[arg(long)]
    plot: Option<PathBuf>,
    /// Inject a fault in the simulator (repeatable): KIND@START_S[+DURATION_S][:ARG], KIND one of
    /// drop, delay:N, corrupt, imu-nan, freeze-joint:SLOT, motor-dead:SLOT, overheat:SLOT, disconnect.
    #[arg(long = "fault")]
    faults: Vec<String>,
    /// IMU errors in the simulator: `realistic` (MEMS-grade white noise, biases, roll/pitch error
    /// and yaw drift), or numbers as `g1-sim --imu-noise` takes them. Off by default.
    #[arg(long, value_name = "realistic|STD[,...]")]
    imu_noise: Option<String>,
    /// The simulator's integrator (`g1-sim --integrator`): implicitfast (its default) or euler
    /// (the explicit PD of Unitree's Python reference loop).
    #[arg(long, value_name = "implicitfast|euler")]
    sim_integrator: Option<String>,
    /// The simulator's physics profile (`g1-sim --physics`): deploy (its default: the model's
    /// contacts and solver) or training (the trainer's lean profile).
    #[arg(long, value_name = "deploy|training", value_parser = ["deploy", "training"])]
    sim_physics: Option<String>,
    /// Terrain world: a preset (flat, stairs-up, stairs-down, outdoor), a scenario file
    /// (SCENARIO.toml) or random:SEED. The simulator then streams its MID-360 (Livox packets), the
    /// perception group builds the BEV grid and a terrain token every frame, and the report gains
    /// `terrain` (token vs ground truth). The log carries /lidar/points, /perception/bev,
    /// /perception/terrain and /truth/terrain.
    #[arg(long, value_name = "PRESET|SCENARIO.toml")]
    world: Option<String>,
    #[command(flatten)]
    rt: RtArgs,
    /// Simulated seconds to run.
    #[arg(long, default_value_t = 20.0, value_parser = parse_run_s)]
    duration: f64,
    /// Seed for the simulator (same seed, spec and command: bit-identical run).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Write the JSON report here (it is always printed to stdout too).
    #[arg(long)]
    report: Option<PathBuf>,
    /// Physics time step of the simulator, seconds.
    #[arg(long, default_value_t = 0.002, value_parser = parse_physics_dt)]
    physics_dt: f64,
    /// Skip the start-up ramp: targets are the default pose from the first tick and the policy
    /// first runs one policy period later (as Unitree's reference loop).
    #[arg(long, conflicts_with = "ramp")]
    no_ramp: bool,
    /// Start-up ramp duration in seconds (overrides the spec's `startup.ramp_s`).
    #[arg(long, value_parser = parse_ramp_s)]
    ramp: Option<f64>,
    /// Do not load or run the policy: ramp to the spec's default pose and hold it.
    #[arg(long)]
    hold: bool,
    /// An operated run, as on the robot with its remote: passive (damping) at start, and every
    /// change of state asked for by the operator (here the --cmd-schedule's `stand_up`, `walk`,
    /// `stand`, `sit_down` and `passive` lines): stand-up ramp, standing, walking (the policy),
    /// sit-down ramp, passive. Without it the policy engages by itself after the start-up.
    #[arg(long, conflicts_with = "hold")]
    operated: bool,
    /// Keep running after a fall instead of stopping at it.
    #[arg(long)]
    keep_going: bool,
    /// Path of the g1-sim binary (default: beside g1fw, or $G1_SIM_BIN).
    #[arg(long)]
    sim_bin: Option<PathBuf>,
    /// Connect to an already running g1-sim at this Unix socket instead of starting one.
    #[arg(long)]
    connect: Option<PathBuf>,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
    /// Where the policy's terrain token comes from: cnn | geometric (the perception estimator;
    /// default: the spec's `[perception] terrain_estimator`), truth (an evaluation ablation: the
    /// simulator's privileged ground-truth token of each tick; such a log does not replay) or
    /// none (the token stays flat: class flat, h = d = 0, yaw 0; the policy runs blind).
    /// Recorded in the log and the report.
    #[arg(long, value_parser = parse_terrain_source, value_name = "cnn|geometric|truth|none")]
    terrain_source: Option<control::perception::TerrainSource>,
    /// Where the perception step runs: `inline` (in the tick, after the command) or
    /// `threaded[:TICKS]` (on its own thread, its result used TICKS ticks after the frame, default
    /// 10; in simulation a late result is waited for, so runs stay deterministic). `g1fw run`
    /// defaults to threaded.
    #[arg(long, default_value = "inline", value_parser = parse_perception_sim, value_name = "inline|threaded[:TICKS]")]
    perception: control::perception_worker::PerceptionExec,
    /// Heading correction: keep this heading (degrees, world frame = relative to the start
    /// heading) by replacing the command's wz every tick with 0.5·wrap(target − IMU yaw), clamped
    /// to ±0.5 rad/s (`control::operator::heading_command`); vx comes from --cmd VX,0,0 or from
    /// --cmd-schedule (whose vy and wz it then ignores).
    #[arg(long, value_name = "DEG", allow_hyphen_values = true, value_parser = parse_heading_deg)]
    heading: Option<f64>,
    /// With --heading: also steer back to the line through the start along that heading, from
    /// the estimator's position: the target heading turns toward the line by 1 rad per metre
    /// across it, at most 0.5 rad (`control::operator::line_heading`). Heading hold alone lets a
    /// sideways drift grow until the robot leaves a staircase's side.
    #[arg(long, requires = "heading")]
    hold_line: bool,
    /// Draw base height and the ground under the base against distance along the staircase axis
    /// (along x on flat ground) to this PNG.
    #[arg(long, value_name = "FILE.png")]
    profile_plot: Option<PathBuf>,
    /// Stop once the base has stood on the staircase's end landing this long (s) with no fall and
    /// no trip (the run has succeeded; `stairs` in the report).
    #[arg(long, value_name = "S", value_parser = parse_wait_s)]
    stop_after_landing: Option<f64>,
}

/// Parses `--terrain-source`.
#[cfg(feature = "lab")]
fn parse_perception_sim(s: &str) -> Result<control::perception_worker::PerceptionExec, String> {
    control::perception_worker::PerceptionExec::parse(s, true)
}

fn parse_perception_robot(s: &str) -> Result<control::perception_worker::PerceptionExec, String> {
    control::perception_worker::PerceptionExec::parse(s, false)
}

#[cfg(feature = "lab")]
fn parse_terrain_source(s: &str) -> Result<control::perception::TerrainSource, String> {
    s.parse()
}

#[cfg(feature = "lab")]
#[derive(clap::Args)]
struct EvalArgs {
    /// Deploy spec (TOML) of the policy under test.
    #[arg(long, default_value = "specs/peer/unitree_g1_lstm.toml")]
    spec: PathBuf,
    /// Policy weights (safetensors) instead of the file the spec names, e.g. a training run's
    /// `g1_stairs_lstm.safetensors` or one of its `actors/` snapshots.
    #[arg(long, value_name = "FILE")]
    weights: Option<PathBuf>,
    /// Robot model: g1-12dof, g1-29dof or an MJCF path (as `g1fw sim --model`).
    #[arg(long, default_value = "g1-29dof")]
    model: String,
    /// Where the policy's terrain token comes from: cnn | geometric (the perception estimator;
    /// default: the spec's `[perception] terrain_estimator`), truth (evaluation ablation: the
    /// simulator's ground-truth token) or none (flat token: the policy runs blind).
    #[arg(long, value_parser = parse_terrain_source, value_name = "cnn|geometric|truth|none")]
    terrain_source: Option<control::perception::TerrainSource>,
    /// Forward velocity command, m/s (vy = 0; wz from the heading correction).
    #[arg(long, default_value_t = 0.5, allow_hyphen_values = true, value_parser = parse_vx)]
    vx: f32,
    /// Simulated seconds per episode.
    #[arg(long, default_value_t = 20.0, value_name = "S", value_parser = parse_run_s)]
    time_limit: f64,
    /// Episodes run at once, each with its own g1-sim (results do not depend on it).
    #[arg(long, default_value_t = 1, value_name = "N")]
    jobs: usize,
    /// Base seed: episode i runs its simulator with seed + i; the random sweep draws from it.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Worlds, comma-separated, one episode each: presets (flat, stairs-up, stairs-down, outdoor),
    /// scenario files (specs/worlds/*.toml) or random:SEED.
    #[arg(long, value_delimiter = ',', value_name = "LIST", conflicts_with = "heights")]
    worlds: Vec<String>,
    /// Random sweep: riser heights (m), comma-separated; each episode draws depth 0.22-0.40 m,
    /// yaw ±30°, start distance 0.6-2.0 m, 3-8 steps and width 1.2-2.0 m from --seed and writes
    /// a scenario file into a scratch directory removed afterwards.
    #[arg(long, value_delimiter = ',', value_name = "H,...", value_parser = parse_riser_m)]
    heights: Vec<f64>,
    /// Random sweep: staircase kinds, comma-separated: up, down.
    #[arg(long, value_delimiter = ',', default_value = "up,down", value_name = "up,down")]
    kinds: Vec<String>,
    /// Random sweep: episodes per (kind, height).
    #[arg(long, default_value_t = 10, value_name = "N")]
    episodes_per_height: usize,
    /// End an episode once the base has stood on the end landing this long (s); 0 runs every
    /// episode to --time-limit.
    #[arg(long, default_value_t = firmware::eval::LANDING_HOLD_S, value_name = "S", value_parser = parse_wait_s)]
    stop_after_landing: f64,
    /// Write the JSON report here.
    #[arg(long)]
    report: Option<PathBuf>,
    /// Path of the g1-sim binary (default: beside g1fw, or $G1_SIM_BIN).
    #[arg(long)]
    sim_bin: Option<PathBuf>,
    /// The simulator's physics profile: deploy (the default: the model's contacts and solver) or
    /// training (the trainer's lean profile: feet and shins against the world only, 10 solver
    /// iterations, no joint friction), to measure how much of a policy's result is the physics.
    #[arg(long, value_name = "deploy|training", value_parser = ["deploy", "training"])]
    sim_physics: Option<String>,
    /// The operator also steers back to the staircase's centre line (the line through the start
    /// along the axis), from the estimator's position, as `g1fw sim --hold-line`.
    #[arg(long)]
    hold_line: bool,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
}

#[derive(clap::Args)]
struct RunArgs {
    /// Deploy spec (TOML).
    #[arg(long, default_value = "specs/peer/unitree_g1_lstm.toml")]
    spec: PathBuf,
    /// The G1's DDS interface: the network interface the robot is on and the domain, e.g.
    /// `eth0` (domain 0, the robot's) or `lo,1` (unitree_mujoco's default, and `g1-sim --dds lo,1`).
    /// Refuses to start while another program publishes rt/lowcmd.
    #[arg(
        long,
        value_name = "IFACE[,DOMAIN]",
        required_unless_present = "can_config",
        conflicts_with = "can_config"
    )]
    dds: Option<robot_io::dds::Endpoint>,
    /// Overrides one value of the spec for this run, as `KEY=VALUE` with a dotted key and a TOML value,
    /// e.g. `safety.state_timeout_s=0.1` for a simulator on a busy desktop (repeatable). The run warns,
    /// the report lists it under `warnings`, and the log keeps the spec as run, so replay repeats it.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    sets: Vec<String>,
    /// With --dds --tick-on state: a tick without a new rt/lowstate runs after this long (default 10 periods),
    /// so the safety supervisor sees the silence and damping keeps going out.
    #[arg(long, value_name = "MS", requires = "dds")]
    dds_tick_timeout_ms: Option<u32>,
    /// With --dds, for Unitree's Python simulator (unitree_mujoco's simulate_python) only: accept
    /// rt/lowstate samples whose CRC and tick were never filled in (its bridge leaves both at 0),
    /// judging freshness by arrival order instead. A CRC that is set but wrong is still refused.
    /// The report and the log say it was on. Never use it on the robot, which fills in both.
    #[arg(long, requires = "dds")]
    unitree_mujoco: bool,
    /// With --dds, what starts a control tick: `clock` (the robot's way, as Unitree's deploy loops:
    /// a monotonic clock at the control period, reading the newest rt/lowstate; a tick without a
    /// newer one counts as stale) or `state` (each new rt/lowstate; lock-step with `g1-sim --dds`).
    /// The report gives the clock's lateness (p50, p99, max).
    #[arg(long, value_name = "clock|state", default_value = "clock", requires = "dds")]
    tick_on: robot_io::dds::Pace,
    /// Bus layout for motors on CAN (the vcan bench): motor slots, node ids and ranges, the IMU's
    /// bus, timeouts (specs/can/*.toml).
    #[arg(long, value_name = "FILE")]
    can_config: Option<PathBuf>,
    /// Interface names, comma-separated, in the layout's bus order (default: the layout's own).
    #[arg(long, value_name = "IF[,IF…]", value_delimiter = ',', requires = "can_config")]
    can: Vec<String>,
    /// Seconds of control ticks to run (default: until SIGINT/SIGTERM).
    #[arg(long, value_parser = parse_run_s)]
    duration: Option<f64>,
    /// After every end (the duration ran out, a signal, a safety trip, a lost link, a crash of the
    /// loop): send the damping command (kp 0, the spec's damping kd) every control period for this
    /// many seconds, then exit. At least one is sent.
    #[arg(long, value_name = "SECONDS", default_value_t = 1.0, value_parser = parse_end_damping_s)]
    end_damping: f64,
    /// Velocity command vx,vy,wz (m/s, m/s, rad/s), held for the whole run.
    #[arg(long, default_value = "0,0,0", value_parser = parse_cmd, allow_hyphen_values = true, conflicts_with = "cmd_schedule")]
    cmd: [f32; 3],
    /// Piecewise-constant operator commands over time (as `g1fw sim --cmd-schedule`).
    #[arg(long)]
    cmd_schedule: Option<PathBuf>,
    /// Record an MCAP log (replay with `g1fw replay`).
    #[arg(long)]
    log: Option<PathBuf>,
    /// Go on in a new log file once one has this many megabytes (as rosbag2's --max-bag-size):
    /// RUN.mcap, then RUN_1.mcap, RUN_2.mcap, … Each file starts with the run's state at its first
    /// tick, so each replays on its own (`g1fw replay RUN_2.mcap`).
    #[arg(long, value_name = "MB", value_parser = parse_log_split_mb, requires = "log")]
    log_split_mb: Option<f64>,
    /// Write the JSON report here too.
    #[arg(long)]
    report: Option<PathBuf>,
    /// Start-up ramp duration in seconds (overrides the spec's `startup.ramp_s`).
    #[arg(long, value_parser = parse_ramp_s)]
    ramp: Option<f64>,
    /// Do not load or run the policy: ramp to the default pose and hold it.
    #[arg(long)]
    hold: bool,
    /// An operated run, as on the robot with its remote: passive (damping) at start, and every
    /// change of state asked for by the operator (here the --cmd-schedule's `stand_up`, `walk`,
    /// `stand`, `sit_down` and `passive` lines): stand-up ramp, standing, walking (the policy),
    /// sit-down ramp, passive. Without it the policy engages by itself after the start-up.
    #[arg(long, conflicts_with = "hold")]
    operated: bool,
    /// The operated run's operator is this terminal's keyboard instead of the robot's remote (for
    /// `g1-sim --dds` or unitree_mujoco without a gamepad; rl_sar's keys): 0 stand up, 1 walk,
    /// 2 stand, 9 sit down, p passive (damping from any state), w/s vx ±0.1 m/s, a/d vy ±0.1 m/s,
    /// q/e wz ±0.2 rad/s, space zero velocity, Ctrl-C stop. The keys reach the controller only as
    /// the logged operator input, so replay needs no keyboard.
    #[arg(long, requires = "operated", conflicts_with = "cmd_schedule")]
    keyboard: bool,
    /// Seconds to wait at start-up for every motor to answer and the first IMU sample.
    #[arg(long, default_value_t = 10.0, value_parser = parse_wait_s)]
    startup_timeout: f64,
    /// Override the layout's `tick_timeout_ms` (no IMU sample for this long ends the run with
    /// damping); e.g. for emulated buses on a loaded machine.
    #[arg(long, value_name = "MS", requires = "can_config")]
    tick_timeout_ms: Option<u32>,
    /// Receive the MID-360's point packets (Livox SDK2 over UDP) on this local address, e.g.
    /// 0.0.0.0:56301 (the G1's host port); the spec's perception then runs on them as under
    /// `g1fw sim --world`. The report gains `lidar` (datagrams, frames, drops).
    #[arg(long, value_name = "ADDR:PORT")]
    lidar_udp: Option<std::net::SocketAddr>,
    /// With --lidar-udp: accept packets only from this address (`any`: from anyone, e.g. a replay
    /// on loopback).
    #[arg(
        long,
        default_value = "192.168.123.120",
        value_name = "IP|any",
        requires = "lidar_udp"
    )]
    lidar_from: String,
    /// Where the perception step runs: `threaded[:TICKS]` (default: its own thread; the result is
    /// used TICKS = 10 ticks after the frame, or counted late and not used) or `inline` (in the
    /// tick, after the command).
    #[arg(long, default_value = "threaded", value_parser = parse_perception_robot, value_name = "threaded[:TICKS]|inline")]
    perception: control::perception_worker::PerceptionExec,
    #[command(flatten)]
    rt: RtArgs,
}

/// Real-time set-up of the control thread (`g1fw sim` and `g1fw run`).
#[derive(clap::Args)]
struct RtArgs {
    /// Run the control thread with SCHED_FIFO at this priority (1-99; needs CAP_SYS_NICE).
    #[arg(long)]
    rt_priority: Option<i32>,
    /// Pin the control thread to this CPU.
    #[arg(long)]
    cpu: Option<usize>,
    /// Lock all memory (mlockall) so the control loop never page-faults.
    #[arg(long)]
    mlockall: bool,
}

impl RtArgs {
    fn options(&self) -> control::rt::RtOptions {
        control::rt::RtOptions {
            fifo_priority: self.rt_priority,
            cpu: self.cpu,
            mlockall: self.mlockall,
        }
    }
}

/// A finite number within `lo..=hi` (clap's f64 parser takes NaN, ∞ and 1e30).
fn finite_in(s: &str, lo: f64, hi: f64, unit: &str) -> Result<f64, String> {
    let v: f64 = s.trim().parse().map_err(|e| format!("'{s}': {e}"))?;
    if v.is_finite() && (lo..=hi).contains(&v) {
        Ok(v)
    } else {
        Err(format!("{v} is outside {lo} to {hi} {unit}"))
    }
}

/// A run's length, s: up to a week.
fn parse_run_s(s: &str) -> Result<f64, String> {
    finite_in(s, 1e-3, 7.0 * 86400.0, "s")
}

/// A start-up ramp, s, within what a spec may hold (`startup.ramp_s`).
/// A log file's size before the next one, MB (0.1 MB to 1 TB).
fn parse_log_split_mb(s: &str) -> Result<f64, String> {
    finite_in(s, 0.1, 1e6, "MB")
}

/// The logger's options for `--log-split-mb`.
fn log_options(split_mb: Option<f64>) -> runlog::log::LogOptions {
    runlog::log::LogOptions {
        split_bytes: split_mb.map(|mb| (mb * 1e6) as u64),
        ..Default::default()
    }
}

fn parse_ramp_s(s: &str) -> Result<f64, String> {
    finite_in(s, 0.0, control::spec::MAX_STARTUP_S, "s")
}

/// The damping after a run, s: a stop must stop.
fn parse_end_damping_s(s: &str) -> Result<f64, String> {
    finite_in(s, 0.0, 10.0, "s")
}

/// A wait or a hold, s.
fn parse_wait_s(s: &str) -> Result<f64, String> {
    finite_in(s, 0.0, 600.0, "s")
}

#[cfg(feature = "lab")]
/// A time into a log, s.
fn parse_at_s(s: &str) -> Result<f64, String> {
    finite_in(s, 0.0, 1e9, "s")
}

#[cfg(feature = "lab")]
/// The simulator's physics step, s.
fn parse_physics_dt(s: &str) -> Result<f64, String> {
    finite_in(s, 1e-4, 0.01, "s")
}

#[cfg(feature = "lab")]
/// A heading, degrees.
fn parse_heading_deg(s: &str) -> Result<f64, String> {
    finite_in(s, -360.0, 360.0, "degrees")
}

#[cfg(feature = "lab")]
/// A riser height, m.
fn parse_riser_m(s: &str) -> Result<f64, String> {
    finite_in(s, 0.0, 0.5, "m")
}

#[cfg(feature = "lab")]
/// A forward speed, m/s, within any spec's command limits.
fn parse_vx(s: &str) -> Result<f32, String> {
    finite_in(
        s,
        -(control::spec::MAX_COMMAND as f64),
        control::spec::MAX_COMMAND as f64,
        "m/s",
    )
    .map(|v| v as f32)
}

fn parse_cmd(s: &str) -> Result<[f32; 3], String> {
    let v: Vec<f32> = s
        .split(',')
        .map(|x| x.trim().parse::<f32>().map_err(|e| format!("'{x}': {e}")))
        .collect::<Result<_, _>>()?;
    match v.as_slice() {
        [a, b, c] if v.iter().all(|x| x.is_finite()) => Ok([*a, *b, *c]),
        _ => Err(format!("expected three finite numbers VX,VY,WZ, got '{s}'")),
    }
}

/// What `RUST_LOG` asks for (`level` and `target=level`, comma-separated), or by default info, with
/// rustdds at warnings: it narrates discovery and shutdown at info level.
fn log_filter() -> tracing_subscriber::filter::Targets {
    use tracing_subscriber::filter::{LevelFilter, Targets};
    let default = Targets::new()
        .with_default(LevelFilter::INFO)
        .with_target("rustdds", LevelFilter::WARN);
    match std::env::var("RUST_LOG") {
        Ok(s) if !s.trim().is_empty() => s.parse().unwrap_or_else(|e| {
            eprintln!("g1fw: RUST_LOG={s:?} is not `level,target=level,...` ({e}); logging at the default (info)");
            default
        }),
        _ => default,
    }
}

fn main() -> ExitCode {
    let default_hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        default_hook(info);
        eprintln!(
            "g1fw: this is a bug, please report it with the run's log. A panic inside the control loop \
             is caught by its guard, which commands damping on every enabled motor and closes the log."
        );
    }));
    use tracing_subscriber::layer::SubscriberExt as _;
    use tracing_subscriber::util::SubscriberInitExt as _;
    tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .finish()
        .with(log_filter())
        .init();
    let cli = Cli::parse();
    // The README's commands are checked against the parser in CI (tests/tests/readme.rs).
    if std::env::var_os("G1_CHECK_ARGS").is_some() {
        eprintln!("G1_CHECK_ARGS is set: the arguments parse; nothing was run");
        return ExitCode::SUCCESS;
    }
    match run(cli) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(2)
        }
    }
}

fn run(cli: Cli) -> Result<ExitCode> {
    match cli.command {
        Cmd::CheckSpec { spec } => {
            let spec = DeploySpec::load(&spec)?;
            let c = control::controller::Controller::new(spec)?;
            let s = c.spec();
            println!(
                "ok: {} — {} joints{}, observation {} values, {} Hz control / {} Hz policy, weights sha256 {}",
                input_file::text::for_terminal(&s.meta.name, input_file::text::MAX_QUOTED_LINE, false),
                s.num_joints(),
                if s.action_dim() > s.num_joints() {
                    " and the gait clock's rate"
                } else {
                    ""
                },
                s.observation_dim(),
                s.rates.control_hz,
                s.rates.policy_hz,
                c.weights_sha256()
            );
            for w in s.explicit_pd_warnings() {
                println!("warning: {w}");
            }
            Ok(ExitCode::SUCCESS)
        }
        #[cfg(feature = "lab")]
        Cmd::Sim(a) => sim(*a),
        #[cfg(feature = "lab")]
        Cmd::Eval(a) => eval(*a),
        Cmd::Run(a) => run_robot(*a),
        Cmd::Replay(a) => {
            distinct_files(
                &[("--report", a.report.as_deref())],
                &[
                    ("the log", Some(a.log.as_path())),
                    ("--spec", a.spec.as_deref()),
                    ("--weights", a.weights.as_deref()),
                ],
            )?;
            let report = replay(
                &a.log,
                &ReplayOptions {
                    spec: a.spec,
                    weights: a.weights,
                    allow_mismatch: a.allow_mismatch,
                },
            )?;
            let json = serde_json::to_string_pretty(&report)?;
            if let Some(path) = &a.report {
                write_report(path, &json)?;
            }
            for n in &report.notes {
                eprintln!("note: {n}");
            }
            if let Some(d) = &report.damaged {
                println!("{json}");
                eprintln!(
                    "LOG DAMAGED: {d}; replay stopped there ({} ticks before it {})",
                    report.ticks,
                    match &report.divergence {
                        Some(_) => "diverged",
                        None => "matched",
                    }
                );
                return Ok(ExitCode::from(2));
            }
            if let Some(t) = &report.truncated {
                eprintln!(
                    "note: the log ends early ({t}); replayed its {} complete ticks",
                    report.ticks
                );
            }
            match &report.divergence {
                Some(d) => {
                    println!("{json}");
                    eprintln!("REPLAY DIVERGED: {d}");
                    Ok(ExitCode::from(1))
                }
                None => {
                    println!("{json}");
                    eprintln!(
                        "replay identical: {} ticks, {} commands and {} policy steps bit-exact, {:.0}x real time",
                        report.ticks,
                        report.compared_commands,
                        report.compared_policy_steps,
                        report.sim_seconds_per_wall_second
                    );
                    Ok(ExitCode::SUCCESS)
                }
            }
        }
        #[cfg(feature = "lab")]
        Cmd::Plot { log, out } => {
            distinct_files(&[("--out", Some(&out))], &[("the log", Some(&log))])?;
            firmware::log_tools::plot_log(&log, &out)?;
            eprintln!("wrote {}", out.display());
            Ok(ExitCode::SUCCESS)
        }
        #[cfg(feature = "lab")]
        Cmd::Bev { log, at, out } => {
            distinct_files(&[("--out", Some(&out))], &[("the log", Some(&log))])?;
            let info = firmware::bev_render::render_bev_png(&log, at, &out)?;
            println!("{}", serde_json::to_string_pretty(&info)?);
            eprintln!("wrote {}", out.display());
            Ok(ExitCode::SUCCESS)
        }
        Cmd::LogInfo { log } => {
            let info = firmware::log_tools::log_info(&log)?;
            println!("{}", serde_json::to_string_pretty(&info)?);
            if let Some(d) = &info.damaged {
                eprintln!("error: log {} is damaged: {d}", log.display());
                return Ok(ExitCode::from(2));
            }
            Ok(ExitCode::SUCCESS)
        }
    }
}

#[cfg(feature = "lab")]
fn sim(a: SimArgs) -> Result<ExitCode> {
    if !(a.duration > 0.0 && a.duration.is_finite()) {
        bail!("--duration must be a positive number of seconds");
    }
    if a.ramp.is_some_and(|r| !(r >= 0.0 && r.is_finite())) {
        bail!("--ramp must be a non-negative number of seconds");
    }
    distinct_files(
        &[
            ("--log", a.log.as_deref()),
            ("--report", a.report.as_deref()),
            ("--plot", a.plot.as_deref()),
            ("--profile-plot", a.profile_plot.as_deref()),
        ],
        &[
            ("--spec", Some(a.spec.as_path())),
            ("--weights", a.weights.as_deref()),
            ("--cmd-schedule", a.cmd_schedule.as_deref()),
        ],
    )?;
    let mut spec = DeploySpec::load(&a.spec)?;
    if let Some(w) = &a.weights {
        spec = spec.with_weights(w)?;
    }
    spec_outputs_distinct(
        &spec,
        &[
            ("--log", a.log.as_deref()),
            ("--report", a.report.as_deref()),
            ("--plot", a.plot.as_deref()),
            ("--profile-plot", a.profile_plot.as_deref()),
        ],
    )?;
    let schedule = match &a.cmd_schedule {
        Some(p) => CommandSchedule::load(p)?,
        None => CommandSchedule::constant(a.cmd),
    };
    schedule.check_within(a.duration).map_err(anyhow::Error::msg)?;
    for f in &a.faults {
        // `KIND@START_S[+DURATION_S][:ARG]` (g1-sim parses the rest and names any error).
        let start = f
            .split_once('@')
            .and_then(|(_, rest)| rest.split(['+', ':']).next())
            .and_then(|t| t.trim().parse::<f64>().ok());
        if let Some(t) = start.filter(|t| *t >= a.duration) {
            bail!(
                "--fault {f} starts at {t} s, at or after the run's end (--duration {}): it would never happen",
                a.duration
            );
        }
    }
    if let Some(h) = a.heading {
        if !h.is_finite() {
            bail!("--heading must be a finite number of degrees");
        }
        if a.cmd_schedule.is_none() && (a.cmd[1] != 0.0 || a.cmd[2] != 0.0) {
            bail!("--heading sets wz itself and keeps vy 0: give --cmd VX,0,0");
        }
    }
    if a.stop_after_landing.is_some_and(|s| !(s >= 0.0 && s.is_finite())) {
        bail!("--stop-after-landing must be a non-negative number of seconds");
    }
    let opts = SimOptions {
        model: a.model,
        schedule,
        duration_s: a.duration,
        seed: a.seed,
        physics_dt: a.physics_dt,
        ramp_override: if a.no_ramp {
            Some((0.0, 0.0))
        } else {
            a.ramp.map(|r| (r, spec.startup.hold_s))
        },
        sim_bin: a.sim_bin,
        connect: a.connect,
        stop_on_fall: !a.keep_going,
        hold_only: a.hold,
        operated: a.operated,
        progress: !a.quiet && std::io::IsTerminal::is_terminal(&std::io::stderr()),
        faults: a.faults,
        imu_noise: a.imu_noise,
        integrator: a.sim_integrator,
        physics: a.sim_physics,
        world: a.world.clone(),
        log: a.log.clone(),
        log_options: log_options(a.log_split_mb),
        rt: a.rt.options(),
        terrain_source: a.terrain_source,
        perception: a.perception,
        heading: a
            .heading
            .map(|d| firmware::sim_run::Heading::Fixed(d.to_radians() as f32)),
        hold_line: a.hold_line,
        stop_after_landing_s: a.stop_after_landing,
        stop: stop_on_signals()?,
    };
    let mut profile = Vec::new();
    let mut on_stairs = false;
    let report = run_sim(spec, &opts, |v| {
        if a.profile_plot.is_none() || v.summary.tick.index % 10 != 0 {
            return;
        }
        if let Some(t) = v.truth {
            on_stairs |= t.stairs.is_some();
            profile.push(firmware::profile_plot::ProfileSample {
                s: t.stairs.map_or(t.base_pos[0], |p| p.axis_s),
                base_z: t.base_pos[2],
                ground_z: t.ground_height_m,
            });
        }
    })?;
    let json = serde_json::to_string_pretty(&report)?;
    println!("{json}");
    if let Some(path) = a.report {
        write_report(&path, &json)?;
    }
    if let Some(e) = &report.log_error {
        bail!("the log could not be written ({e}); the run stopped there, and its report is above");
    }
    if let Some(png) = &a.plot {
        let Some(log) = &a.log else {
            bail!("--plot draws from the run's log: add --log FILE.mcap");
        };
        firmware::log_tools::plot_log(log, png)?;
        tracing::info!(plot = %png.display(), "velocity plot written");
    }
    if let Some(png) = &a.profile_plot {
        let at_s = |t: Option<f64>| t.and_then(|t| profile.get((t / 0.02) as usize).map(|p| p.s));
        let event = match (&report.trip, report.fell_at_s) {
            (Some(t), _) => at_s(Some(t.time_s)).map(|s| (s, format!("trip: {}", t.reason))),
            (None, Some(f)) => at_s(Some(f)).map(|s| (s, "fell".to_string())),
            _ => None,
        };
        let stairs = report.stairs.as_ref();
        let p = firmware::profile_plot::Profile {
            title: format!(
                "{} on {}: {}, terrain source {}",
                report.spec,
                a.world.as_deref().unwrap_or("flat ground"),
                match stairs {
                    Some(s) if s.success => format!("success, {} of {} risers", s.risers_passed, s.risers),
                    Some(s) => format!("no success, {} of {} risers", s.risers_passed, s.risers),
                    None => format!("{:.2} m in {:.1} s", report.distance_x_m, report.time_s),
                },
                report.terrain_source
            ),
            axis_label: if on_stairs {
                "along the staircase axis from its first riser".into()
            } else {
                "along world x".into()
            },
            landing_at: stairs.and_then(|s| at_s(s.reached_end_landing_at_s)),
            event,
            samples: profile,
        };
        firmware::profile_plot::profile_png(png, &p)?;
        tracing::info!(plot = %png.display(), "profile plot written");
    }
    tracing::info!(
        fell = report.fell,
        distance_x_m = format!("{:.2}", report.distance_x_m),
        rt = format!("{:.1}x", report.timing.sim_seconds_per_wall_second),
        end = report.end,
        "run finished"
    );
    // 128 + SIGINT, as shells report an interrupted command; 3 for a latched trip, as `g1fw run`.
    Ok(if report.interrupted {
        ExitCode::from(130)
    } else if report.trip.is_some() {
        ExitCode::from(3)
    } else {
        ExitCode::SUCCESS
    })
}

/// A flag SIGINT and SIGTERM set instead of killing the process: the run stops at the next tick,
/// damps (robot) or stops the simulator, closes its log and writes its report.
fn stop_on_signals() -> Result<std::sync::Arc<std::sync::atomic::AtomicBool>> {
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(sig, stop.clone()).context("installing the signal handler")?;
    }
    Ok(stop)
}

/// Refuses a run whose outputs (files) would overwrite one another or one of its inputs
/// (`output_file`'s rule, shared by every binary).
fn distinct_files(outputs: &[(&'static str, Option<&Path>)], inputs: &[(&'static str, Option<&Path>)]) -> Result<()> {
    let outs: Vec<_> = outputs.iter().map(|(f, p)| (*f, *p, output_file::Kind::File)).collect();
    output_file::check_given(&outs, inputs)?;
    Ok(())
}

/// Writes a report through a temporary file and a rename (a full disk leaves no empty or
/// half-written report); the report is on stdout already, which the error says.
fn write_report(path: &Path, json: &str) -> Result<()> {
    output_file::write_atomically(path, format!("{json}\n").as_bytes()).with_context(|| {
        format!(
            "writing the report {} (nothing was left there; the report is printed on stdout above)",
            path.display()
        )
    })
}

/// No output may be a file the spec makes the run read (weights, estimator model, terrain network).
fn spec_outputs_distinct(spec: &DeploySpec, outputs: &[(&'static str, Option<&Path>)]) -> Result<()> {
    let read = spec.files_read();
    let inputs: Vec<(&'static str, Option<&Path>)> = read.iter().map(|(f, p)| (*f, Some(p.as_path()))).collect();
    distinct_files(outputs, &inputs)
}

#[cfg(feature = "lab")]
fn eval(a: EvalArgs) -> Result<ExitCode> {
    use firmware::eval::{random_sweep, run_eval, EpisodeWorld, EvalOptions};
    if !(a.time_limit > 0.0 && a.time_limit.is_finite()) {
        bail!("--time-limit must be a positive number of seconds");
    }
    if !a.vx.is_finite() {
        bail!("--vx must be a finite number (m/s)");
    }
    if a.jobs == 0 || a.jobs > 64 {
        bail!(
            "--jobs must be 1 to 64 (each job is its own g1-sim process; got {})",
            a.jobs
        );
    }
    let (episodes, _scratch) = if !a.heights.is_empty() {
        let mut kinds = Vec::new();
        for k in &a.kinds {
            kinds.push(match k.as_str() {
                "up" => true,
                "down" => false,
                _ => bail!("--kinds: '{k}' is neither up nor down"),
            });
        }
        if a.episodes_per_height == 0 || a.episodes_per_height > 100_000 {
            bail!(
                "--episodes-per-height must be 1 to 100000 (got {})",
                a.episodes_per_height
            );
        }
        let (w, g) = random_sweep(&a.heights, &kinds, a.episodes_per_height, a.seed, &std::env::temp_dir())?;
        (w, Some(g))
    } else if !a.worlds.is_empty() {
        let w = a
            .worlds
            .iter()
            .map(|w| EpisodeWorld {
                world: w.trim().to_string(),
                drawn: None,
            })
            .collect();
        (w, None)
    } else {
        bail!("say which worlds: --worlds LIST (e.g. flat,stairs-up,specs/worlds/stairs_down_steep.toml) or a random sweep --heights 0.12,0.16 [--kinds up,down --episodes-per-height N]");
    };
    // The report may not land on the spec, the files it names, or a world file.
    let spec = DeploySpec::load(&a.spec)?;
    let mut inputs: Vec<(&'static str, Option<&Path>)> =
        vec![("--spec", Some(a.spec.as_path())), ("--weights", a.weights.as_deref())];
    let read = spec.files_read();
    inputs.extend(read.iter().map(|(f, p)| (*f, Some(p.as_path()))));
    inputs.extend(episodes.iter().map(|e| ("a --worlds file", Some(Path::new(&e.world)))));
    distinct_files(&[("--report", a.report.as_deref())], &inputs)?;
    let opts = EvalOptions {
        spec: a.spec,
        weights: a.weights,
        model: a.model,
        terrain_source: a.terrain_source,
        vx: a.vx,
        time_limit_s: a.time_limit,
        jobs: a.jobs,
        seed: a.seed,
        episodes,
        stop_after_landing_s: (a.stop_after_landing > 0.0).then_some(a.stop_after_landing),
        sim_bin: a.sim_bin,
        physics: a.sim_physics,
        hold_line: a.hold_line,
        progress: !a.quiet && std::io::IsTerminal::is_terminal(&std::io::stderr()),
        stop: stop_on_signals()?,
    };
    let report = run_eval(&opts)?;
    print!("{}", report.text());
    if let Some(path) = &a.report {
        let json = serde_json::to_string_pretty(&report)?;
        write_report(path, &json)?;
        eprintln!("wrote {}", path.display());
    }
    if report.interrupted {
        eprintln!(
            "interrupted: {} of {} episodes finished and scored",
            report.episodes, report.episodes_planned
        );
        return Ok(ExitCode::from(130));
    }
    Ok(ExitCode::SUCCESS)
}

fn run_robot(a: RunArgs) -> Result<ExitCode> {
    if a.duration.is_some_and(|d| !(d > 0.0 && d.is_finite())) {
        bail!("--duration must be a positive number of seconds");
    }
    if !(a.startup_timeout > 0.0 && a.startup_timeout.is_finite()) {
        bail!("--startup-timeout must be a positive number of seconds");
    }
    if !(0.0..=60.0).contains(&a.end_damping) {
        bail!("--end-damping must be 0 to 60 seconds (got {})", a.end_damping);
    }
    if a.dds_tick_timeout_ms == Some(0) {
        bail!("--dds-tick-timeout-ms must be at least 1");
    }
    let spec = DeploySpec::load_with_overrides(&a.spec, &a.sets)?;
    let overridden: Vec<String> = a
        .sets
        .iter()
        .map(|set| format!("the spec was overridden for this run: --set {set}"))
        .collect();
    for note in &overridden {
        tracing::warn!("{note}");
    }
    spec_outputs_distinct(&spec, &[("--log", a.log.as_deref()), ("--report", a.report.as_deref())])?;
    let layout = match &a.can_config {
        Some(path) => {
            let mut layout = sensor_io::can::BusLayout::load(path)?;
            if !a.can.is_empty() {
                layout.rename_interfaces(&a.can)?;
            }
            if let Some(ms) = a.tick_timeout_ms {
                if ms == 0 {
                    bail!("--tick-timeout-ms must be at least 1");
                }
                layout.tick_timeout_ms = ms;
            }
            Some(layout)
        }
        None => None,
    };
    distinct_files(
        &[("--log", a.log.as_deref()), ("--report", a.report.as_deref())],
        &[
            ("--spec", Some(a.spec.as_path())),
            ("--can-config", a.can_config.as_deref()),
            ("--cmd-schedule", a.cmd_schedule.as_deref()),
        ],
    )?;
    let stop = stop_on_signals()?;
    let schedule = match &a.cmd_schedule {
        Some(p) => CommandSchedule::load(p)?,
        None => CommandSchedule::constant(a.cmd),
    };
    if let Some(d) = a.duration {
        schedule.check_within(d).map_err(anyhow::Error::msg)?;
    }
    let opts = firmware::robot_run::RunOptions {
        schedule,
        duration_s: a.duration,
        ramp_override: a.ramp.map(|r| (r, spec.startup.hold_s)),
        hold_only: a.hold,
        operated: a.operated,
        keyboard: a.keyboard,
        startup_timeout: std::time::Duration::from_secs_f64(a.startup_timeout),
        log: a.log.clone(),
        log_options: log_options(a.log_split_mb),
        rt: a.rt.options(),
        stop,
        perception: a.perception,
        inject_panic_at_tick: None,
        end_damping: std::time::Duration::from_secs_f64(a.end_damping),
        lidar: match a.lidar_udp {
            None => None,
            Some(bind) => Some(robot_io::UdpLidarConfig {
                bind,
                lidar: match a.lidar_from.as_str() {
                    "any" => None,
                    ip => Some(ip.parse().with_context(|| {
                        format!("--lidar-from {ip}: give the lidar's IP address (e.g. 192.168.123.120) or `any`")
                    })?),
                },
                ..Default::default()
            }),
        },
    };
    let mut report = match (layout, a.dds) {
        (Some(layout), _) => {
            tracing::info!(
                interfaces = layout.interfaces.join(","),
                motors = layout.motors.len(),
                "starting on CAN"
            );
            firmware::robot_run::run_can(spec, layout, &opts)?
        }
        (None, Some(endpoint)) => {
            tracing::info!(%endpoint, "starting on DDS (listening for peers first)");
            let tick_timeout = a
                .dds_tick_timeout_ms
                .map(|ms| std::time::Duration::from_millis(ms as u64));
            if a.unitree_mujoco && a.log_split_mb.is_some() {
                bail!(
                    "--log-split-mb does not go with --unitree-mujoco: the states that simulator sends \
                     unsealed are stamped by their count since the start, which a later file cannot know"
                );
            }
            if a.unitree_mujoco {
                tracing::warn!(
                    "--unitree-mujoco: states without a CRC or an advancing tick are accepted (Unitree's Python \
                     simulator only; never on the robot)"
                );
            }
            firmware::robot_run::run_dds(spec, endpoint, &opts, tick_timeout, a.tick_on, a.unitree_mujoco)?
        }
        (None, None) => {
            bail!("name the robot's transport: --dds IFACE[,DOMAIN] (the G1) or --can-config FILE (a CAN bench)")
        }
    };
    report.warnings.splice(0..0, overridden);
    let json = serde_json::to_string_pretty(&report)?;
    println!("{json}");
    if let Some(path) = a.report {
        write_report(&path, &json)?;
    }
    if let Some(e) = &report.log_error {
        bail!("the log could not be written ({e}); the run stopped and damped there, and its report is above");
    }
    tracing::info!(
        ticks = report.ticks,
        mode = report.final_mode,
        trip = report.trip.as_ref().map_or("none".to_string(), |t| t.reason.clone()),
        end = report.end,
        "run finished"
    );
    // 3: the robot was damped for a reason (a trip, a HAL failure, a variant it cannot drive, a
    // panic); the report's `end` and `trip` say which.
    Ok(if report.normal_end {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(3)
    })
}
