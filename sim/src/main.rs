//! `g1-sim`: MuJoCo G1 simulator serving one lock-stepped bridge client (see `g1_sim`).
// The simulator never runs on the robot: std's math is fine here (see clippy.toml).
#![allow(clippy::disallowed_methods)]
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use clap::Parser;
use g1_sim::faults::FaultPlan;
use g1_sim::server::{self, ServeOptions, SessionEnd};
use g1_sim::{ModelChoice, SimConfig, Simulator};
use hal::LowState;

/// MuJoCo simulator of the Unitree G1 for the lock-stepped firmware bridge.
///
/// Serves exactly one client (Hello → Welcome; per LowCmd one control tick → LowState), then
/// exits 0 on Bye or disconnect. Exit status 3: the client sent a malformed LowCmd (bad CRC,
/// length or non-finite value); 2: another protocol error; 1: setup failure (including a bad
/// --fault); 4: a `disconnect` fault closed the connection as planned. An Error message with the
/// reason is sent to the client before exiting on an error.
///
/// $G1_SIM_MODEL_CACHE: a directory where compiled models are kept (MuJoCo's MJB, keyed by the
/// model files, this executable and the options), so later starts skip the compile; the CAN HIL
/// uses it, where a compile under QEMU takes 80-90 s.
#[derive(Parser, Debug)]
#[command(name = "g1-sim", version)]
struct Cli {
    /// Unix-domain socket to listen on (the default transport). A stale socket file is replaced;
    /// the file is removed on exit.
    #[arg(
        long,
        value_name = "PATH",
        default_value = "/tmp/g1-sim.sock",
        conflicts_with = "tcp"
    )]
    socket: PathBuf,

    /// Listen on TCP instead, e.g. 127.0.0.1:7000 (port 0 picks a free one). Loopback only:
    /// any other address is refused, since the bridge is unauthenticated.
    #[arg(long, value_name = "ADDR")]
    tcp: Option<String>,

    /// Play the robot on DDS instead of serving the bridge, as unitree_mujoco does: publish
    /// rt/lowstate and take rt/lowcmd (unitree_hg, XCDR1) on this interface and domain, e.g.
    /// `lo,1`; then `g1fw run --dds lo,1` drives it. Lock-stepped: one command, one tick.
    #[arg(long, value_name = "IFACE[,DOMAIN]", conflicts_with_all = ["tcp", "bench_bare"])]
    dds: Option<robot_io::dds::Endpoint>,

    /// With --dds: step in wall-clock time at the control period, as unitree_mujoco and the robot
    /// do, taking the newest command each tick, instead of lock-stepping one tick per command. The
    /// robot is held until the first command arrives.
    #[arg(long, requires = "dds")]
    dds_free_run: bool,

    /// With --dds: exit when no command came for this many seconds after the first.
    #[arg(long, value_name = "S", default_value_t = 2.0, requires = "dds")]
    dds_idle_exit: f64,

    /// With --dds: stop after this many simulated seconds.
    #[arg(long, value_name = "S", requires = "dds")]
    dds_max_time: Option<f64>,

    /// With --dds and --world: send the simulated MID-360's Livox packets to this UDP address
    /// every tick, as the G1's lidar does (`g1fw run --lidar-udp ADDR --lidar-from any`).
    #[arg(long, value_name = "ADDR:PORT", requires_all = ["dds", "world"])]
    lidar_udp_to: Option<std::net::SocketAddr>,

    /// Model: `g1-29dof` (mjlab 29-dof G1 from .deps, home pose; $G1_DEPS_DIR overrides .deps),
    /// `g1-12dof` (unitree_rl_gym legs-only G1 from ../shared, at qpos0; $G1_SHARED_DIR
    /// overrides ../shared), or a path to any MJCF with G1 joint names.
    #[arg(long, value_name = "M", default_value = "g1-29dof")]
    model: ModelChoice,

    /// MuJoCo timestep in seconds. The motor PD law runs at every physics step.
    #[arg(long, value_name = "S", default_value_t = 0.002)]
    physics_dt: f64,

    /// Control tick in seconds (one LowCmd / LowState exchange); a whole multiple of
    /// --physics-dt. Default: equal to --physics-dt.
    #[arg(long, value_name = "S")]
    control_dt: Option<f64>,

    /// Seed of the IMU noise generator. Same seed and same commands give bit-identical states.
    #[arg(long, value_name = "N", default_value_t = 0)]
    seed: u64,

    /// IMU errors: `realistic` (white noise, biases, attitude error of a MEMS IMU; see
    /// `ImuNoise::REALISTIC`), white noise only as `STD` or `GYRO_STD,ACC_STD` (rad/s, m/s²), or
    /// `GYRO_STD,ACC_STD,GYRO_BIAS,ACC_BIAS,ATTITUDE_STD`. Off by default (exactly the model's).
    #[arg(long, value_name = "realistic|STD[,...]")]
    imu_noise: Option<g1_sim::ImuNoise>,

    /// MuJoCo integrator: `implicitfast` (the PD actuators' damping integrated implicitly, stable at
    /// real gains) or `euler` (the PD force from the state at the start of each step, explicit,
    /// as in Unitree's Python reference loop; unstable once kd·dt/I > 2).
    #[arg(long, value_name = "implicitfast|euler", default_value = "implicitfast")]
    integrator: g1_sim::Integrator,

    /// Physics profile: `deploy` (the model's contacts and solver) or `training` (the lean RL
    /// profile: feet and shins against the world only, 10 solver iterations, no joint friction).
    #[arg(long, value_name = "deploy|training", default_value = "deploy")]
    physics: g1_sim::PhysicsProfile,

    /// Microseconds a socket read spins before blocking (lower latency when the client answers
    /// quickly; 0 = always block).
    #[arg(long, value_name = "US", default_value_t = 20)]
    spin_us: u64,

    /// Do not print progress (or the active faults) to stderr.
    #[arg(long)]
    quiet: bool,

    /// Inject a fault, repeatable: KIND@START_S[+DURATION_S][:ARG], active on LowState ticks k
    /// with round(START/control_dt) <= k < round((START+DURATION)/control_dt); no duration = until
    /// the end. Kinds: drop, delay:N (send tick k-N's frame), corrupt (CRC fails), imu-nan,
    /// freeze-joint:SLOT (stuck encoder), motor-dead:SLOT, overheat:SLOT, disconnect (close the
    /// connection, exit 4). Deterministic. With --dds they act on the published rt/lowstate of
    /// control tick k: `drop` publishes nothing, `disconnect` stops publishing and exits 4.
    /// E.g. --fault drop@1+0.02 --fault motor-dead@2:3
    #[arg(long = "fault", value_name = "SPEC")]
    faults: Vec<String>,

    /// Terrain world: a preset (flat, stairs-up, stairs-down, outdoor), a scenario file (.toml, see
    /// sim/src/world.rs) or random:SEED. The robot starts at the origin facing +x; ground
    /// truth (terrain class, step height and depth, yaw to the stairs) goes out with `Truth`.
    #[arg(long, value_name = "PRESET|FILE.toml|random:SEED")]
    world: Option<String>,

    /// Mount the simulated Livox MID-360 (200k points/s, 10 Hz frames, range noise, dropouts) and
    /// stream its point packets to clients that ask for them.
    #[arg(long)]
    lidar: bool,

    /// Range noise of the lidar, m (1 σ).
    #[arg(long, value_name = "M", default_value_t = 0.02)]
    lidar_noise: f64,

    /// Hang the robot on a test gantry: a rope tied 1 m above the start pelvis, slack while the
    /// robot stands (5 cm), that catches a fall, as a robot on its gantry or unitree_mujoco's
    /// elastic band. For long runs with faults, where each trip damps the motors: after the
    /// operator's reset the robot stands up from the rope instead of the floor.
    #[arg(long)]
    gantry: bool,

    /// Benchmark instead of serving: simulate SECONDS of simulated time with the same model and
    /// PD law holding the initial pose, no sockets or codecs, and print one JSON line
    /// {"sim_seconds_per_wall_second": X, "steps": N}.
    #[arg(long, value_name = "SECONDS")]
    bench_bare: Option<f64>,
}

/// Exit status after a `disconnect` fault ended the connection as planned.
const FAULT_DISCONNECT_EXIT: u8 = 4;

fn bench_bare(sim: &mut Simulator, seconds: f64) -> Result<()> {
    if !(seconds.is_finite() && seconds > 0.0) {
        bail!("--bench-bare needs a positive number of seconds, got {seconds}");
    }
    let ticks = (seconds / sim.config().control_dt).round().max(1.0) as u64;
    let cmd = sim.hold_initial_pose_command();
    sim.apply_command(&cmd)?;
    // Read the state every tick like a controller would; only sockets and codecs are left out.
    let mut state = LowState::default();
    let t0 = Instant::now();
    for _ in 0..ticks {
        sim.step_control_tick();
        sim.low_state(&mut state);
    }
    let wall = t0.elapsed().as_secs_f64();
    std::hint::black_box(&state);
    println!(
        "{{\"sim_seconds_per_wall_second\": {:.3}, \"steps\": {}}}",
        sim.time() / wall,
        sim.steps()
    );
    Ok(())
}

fn run(cli: Cli) -> Result<ExitCode> {
    let config = SimConfig {
        physics_dt: cli.physics_dt,
        control_dt: cli.control_dt.unwrap_or(cli.physics_dt),
        seed: cli.seed,
        imu_noise: cli.imu_noise,
        integrator: cli.integrator,
        physics: cli.physics,
    };
    let model_name = cli.model.to_string();
    // Syntax errors before the (slow) model load; slot checks need the model.
    let faults = FaultPlan::parse(&cli.faults)?;
    let world = cli
        .world
        .as_deref()
        .map(g1_sim::world::World::resolve)
        .transpose()
        .context("--world")?;
    let mut sim =
        Simulator::load_in(cli.model, config, world.as_ref()).with_context(|| format!("loading model {model_name}"))?;
    if let (Some(note), false) = (sim.model_cache_note(), cli.quiet) {
        eprintln!("g1-sim: {note}");
    }
    if cli.lidar || cli.lidar_udp_to.is_some() {
        let lidar = g1_sim::lidar::LidarConfig {
            range_noise_std: cli.lidar_noise,
            seed: cli.seed,
            ..Default::default()
        };
        sim.attach_lidar(lidar).context("--lidar")?;
    }
    if cli.gantry {
        sim.hang_on_gantry(Some(g1_sim::Gantry::default()))
            .context("--gantry")?;
    }
    if let Some(seconds) = cli.bench_bare {
        if !faults.is_empty() {
            bail!("--fault has no effect with --bench-bare (no bridge to inject into)");
        }
        bench_bare(&mut sim, seconds)?;
        return Ok(ExitCode::SUCCESS);
    }
    let schedule = faults.schedule(config.control_dt, sim.motor_slots_present())?;
    let quiet = cli.quiet;
    if !quiet {
        for (spec, f) in faults.faults.iter().zip(&schedule) {
            eprintln!("g1-sim: fault '{}': {f}", spec.text);
        }
    }
    let opts = ServeOptions {
        spin: Duration::from_micros(cli.spin_us),
        quiet: cli.quiet,
        faults,
    };
    let info = format!(
        "model {model_name}, {} motor slots, physics dt {} s, {} step(s) per tick",
        sim.motor_slots_present().count_ones(),
        config.physics_dt,
        sim.substeps()
    );
    if let Some(endpoint) = cli.dds.clone() {
        if !(cli.dds_idle_exit.is_finite() && cli.dds_idle_exit > 0.0) {
            bail!("--dds-idle-exit must be a positive number of seconds");
        }
        let opts = g1_sim::dds_serve::DdsServeOptions {
            endpoint: endpoint.clone(),
            resend_after: Duration::from_millis(20),
            idle_exit: Some(Duration::from_secs_f64(cli.dds_idle_exit)),
            max_sim_s: cli.dds_max_time,
            lidar_to: cli.lidar_udp_to,
            free_run: cli.dds_free_run,
            quiet,
            faults: opts.faults.clone(),
        };
        let s = g1_sim::dds_serve::serve_dds(&mut sim, &opts, || {
            if !quiet {
                eprintln!("g1-sim: {info}; the robot on DDS {endpoint} (rt/lowstate out, rt/lowcmd in)");
            }
        })?;
        if !quiet {
            eprintln!(
                "g1-sim: DDS run ended after {} ticks ({:.3} s simulated; {} commands rejected, {} states resent)",
                s.ticks, s.sim_time_s, s.rejected_commands, s.resent_states
            );
        }
        // One JSON line on stdout: what a harness scores the run by.
        println!("{}", serde_json::to_string(&s)?);
        if s.fault_disconnect {
            return Ok(ExitCode::from(FAULT_DISCONNECT_EXIT));
        }
        return Ok(ExitCode::SUCCESS);
    }
    let result = match &cli.tcp {
        Some(addr) => server::serve_tcp(addr, &mut sim, &opts, |a| {
            if !quiet {
                eprintln!("g1-sim: {info}; listening on tcp {a}");
            }
        }),
        None => server::serve_unix(&cli.socket, &mut sim, &opts, || {
            if !quiet {
                eprintln!("g1-sim: {info}; listening on {}", cli.socket.display());
            }
        }),
    };
    match result {
        Ok(s) => {
            if !quiet {
                let how = match s.end {
                    SessionEnd::Bye => "client said Bye",
                    SessionEnd::Disconnected => "client disconnected",
                    SessionEnd::FaultDisconnect => "disconnect fault closed the connection",
                };
                eprintln!(
                    "g1-sim: {how} after {} ticks ({:.3} s simulated)",
                    s.ticks, s.sim_time_s
                );
            }
            Ok(match s.end {
                // Distinct from a normal end so a harness can tell the planned cut from a crash
                // or a clean end.
                SessionEnd::FaultDisconnect => ExitCode::from(FAULT_DISCONNECT_EXIT),
                SessionEnd::Bye | SessionEnd::Disconnected => ExitCode::SUCCESS,
            })
        }
        Err(e) => {
            eprintln!("g1-sim: error: {e}");
            Ok(ExitCode::from(e.exit_code()))
        }
    }
}

fn main() -> ExitCode {
    g1_sim::no_mujoco_log_file();
    match run(Cli::parse()) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("g1-sim: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
