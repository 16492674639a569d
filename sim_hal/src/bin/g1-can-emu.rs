//! `g1-can-emu`: the G1's motors and IMU emulated on CAN buses (the vcan bench), backed by the MuJoCo
//! simulator. (The real G1 is reached over DDS: `g1fw run --dds`, `g1-sim --dds`.)
//!
//! firmware ⇄ CAN (vcan0, vcan1, …) ⇄ g1-can-emu ⇄ bridge ⇄ g1-sim (MuJoCo). It speaks docs/can.md
//! as the motors would, lock-stepped: once every motor has a command, the simulator advances one
//! control period and the motors answer. It never links MuJoCo: it starts `g1-sim` (or connects to
//! a running one) and talks to it over the bridge, exactly like `g1fw sim` does.
use std::path::PathBuf;
use std::time::Duration;

use anyhow::{bail, Context, Result};
use clap::Parser;
use sensor_io::can::BusLayout;
use sim_hal::bridge::{BridgeHal, SimLaunch, Wants};
use sim_hal::can::{serve, MotorEmulator, ServeOptions, SocketCanBuses};

#[derive(Parser)]
#[command(version, about, long_about = None)]
struct Args {
    /// Bus layout (motor slots, node ids, ranges, IMU bus): e.g. specs/can/g1_12dof.toml.
    #[arg(long, value_name = "FILE")]
    can_config: PathBuf,
    /// Interface names, comma-separated, in the layout's bus order (default: the layout's names).
    #[arg(long, value_name = "IF[,IF…]", value_delimiter = ',')]
    can: Vec<String>,
    /// Robot model for g1-sim: g1-12dof, g1-29dof or an MJCF path.
    #[arg(long, default_value = "g1-12dof")]
    model: String,
    /// Control rate the motors are stepped at (must match the firmware's spec).
    #[arg(long, default_value_t = 500)]
    control_hz: u32,
    #[arg(long, default_value_t = 0.002)]
    physics_dt: f64,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Passed to g1-sim (its `--fault` grammar), repeatable.
    #[arg(long = "fault", value_name = "SPEC")]
    faults: Vec<String>,
    /// Passed to g1-sim (`--imu-noise`).
    #[arg(long)]
    imu_noise: Option<String>,
    /// Terrain world for g1-sim (`--world`: preset, scenario file or random:SEED); mounts the
    /// simulated MID-360.
    #[arg(long)]
    world: Option<String>,
    /// Play the MID-360 as well: send its Livox point packets over UDP to this address (the
    /// firmware's `g1fw run --lidar-udp`), e.g. 127.0.0.1:56301. Needs --world (or a --connect'ed
    /// simulator started with --lidar).
    #[arg(long, value_name = "ADDR:PORT")]
    lidar_udp_to: Option<std::net::SocketAddr>,
    /// Connect to a running g1-sim at this Unix socket instead of starting one.
    #[arg(long, value_name = "SOCKET")]
    connect: Option<PathBuf>,
    /// The g1-sim binary (default: beside this one, or $G1_SIM_BIN).
    #[arg(long)]
    sim_bin: Option<PathBuf>,
    /// Fault: this joint's motor loses power at this time (it goes limp and stops answering),
    /// e.g. `right_knee@3.0`. Repeatable.
    #[arg(long, value_name = "JOINT@SECONDS")]
    power_off: Vec<String>,
    /// Fault: the IMU loses power at this time (the motors keep answering, but no sample closes a
    /// tick any more), e.g. `3.0`.
    #[arg(long, value_name = "SECONDS")]
    imu_off: Option<f64>,
    /// Stop after this many control ticks.
    #[arg(long)]
    max_ticks: Option<u64>,
    /// Seconds to wait for the firmware to enter motor mode on every motor.
    #[arg(long, default_value_t = 120.0)]
    startup_timeout_s: f64,
    /// Seconds of bus silence after start-up after which the firmware counts as gone.
    #[arg(long, default_value_t = 5.0)]
    idle_timeout_s: f64,
    /// Write the ground-truth report (fell, base height, distance, counters) here as JSON.
    #[arg(long, value_name = "FILE")]
    report: Option<PathBuf>,
    /// Write one line "ready" here once the buses are open and the simulator is connected (so a
    /// test can start the firmware only then).
    #[arg(long, value_name = "FILE")]
    ready_file: Option<PathBuf>,
    #[arg(long)]
    quiet: bool,
}

fn main() -> std::process::ExitCode {
    match run(Args::parse()) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("g1-can-emu: error: {e:#}");
            std::process::ExitCode::from(2)
        }
    }
}

/// The control tick at `secs` seconds; `flag` names the argument in the error.
fn tick_at(flag: &str, secs: f64, control_dt: f64) -> Result<u64> {
    if !(secs >= 0.0 && secs.is_finite()) {
        bail!("{flag}: the time must be a non-negative number of seconds");
    }
    Ok((secs / control_dt).round() as u64)
}

/// `--power-off JOINT@S` as (slot, tick).
fn power_off_ticks(args: &Args, layout: &BusLayout, control_dt: f64) -> Result<Vec<(usize, u64)>> {
    let mut power_off = Vec::new();
    for p in &args.power_off {
        let (joint, at) = p
            .split_once('@')
            .with_context(|| format!("--power-off {p}: expected JOINT@SECONDS, e.g. right_knee@3.0"))?;
        let slot = hal::G1_MOTOR_NAMES
            .iter()
            .position(|n| *n == joint)
            .filter(|&s| layout.motors.iter().any(|m| m.slot == s))
            .with_context(|| format!("--power-off {p}: '{joint}' is not a motor of the bus layout"))?;
        let secs: f64 = at
            .parse()
            .with_context(|| format!("--power-off {p}: '{at}' is not a time in seconds"))?;
        power_off.push((slot, tick_at(&format!("--power-off {p}"), secs, control_dt)?));
    }
    Ok(power_off)
}

fn run(args: Args) -> Result<()> {
    output_file::check_given(
        &[
            ("--report", args.report.as_deref(), output_file::Kind::File),
            ("--ready-file", args.ready_file.as_deref(), output_file::Kind::File),
        ],
        &[("--can-config", Some(&args.can_config))],
    )?;
    let mut layout = BusLayout::load(&args.can_config)?;
    if !args.can.is_empty() {
        layout.rename_interfaces(&args.can)?;
    }
    let control_dt = 1.0 / args.control_hz as f64;
    // Faults are checked before any bus or simulator is opened: a typo fails at once.
    let power_off = power_off_ticks(&args, &layout, control_dt)?;
    let imu_off = args
        .imu_off
        .map(|secs| tick_at(&format!("--imu-off {secs}"), secs, control_dt))
        .transpose()?;
    if args.lidar_udp_to.is_some() && args.world.is_none() && args.connect.is_none() {
        bail!("--lidar-udp-to needs --world: the simulated MID-360 only scans a terrain world");
    }
    let mut buses = SocketCanBuses::open(&layout.interfaces)?;
    let wants = Wants {
        truth: true,
        lidar: args.lidar_udp_to.is_some(),
    };
    let mut _child = None;
    let mut bridge = match &args.connect {
        Some(p) => BridgeHal::connect_unix(p, wants, Duration::from_secs(30), || Ok(()))?,
        None => {
            let launch = SimLaunch {
                bin: args.sim_bin.clone(),
                seed: args.seed,
                physics_dt: args.physics_dt,
                faults: args.faults.clone(),
                imu_noise: args.imu_noise.clone(),
                world: args.world.clone(),
                ..SimLaunch::new(&args.model, control_dt)
            };
            let (child, hal) = launch.start("g1-can-emu", wants, Duration::from_secs(120))?;
            _child = Some(child);
            hal
        }
    };
    let present = bridge.welcome().motor_slots_present;
    let missing: Vec<&str> = layout
        .motors
        .iter()
        .filter(|m| present & (1 << m.slot) == 0)
        .map(|m| hal::G1_MOTOR_NAMES[m.slot])
        .collect();
    if !missing.is_empty() {
        bail!(
            "the model '{}' has no joints for these motors of the bus layout: {}",
            args.model,
            missing.join(", ")
        );
    }
    if let Some(p) = &args.ready_file {
        output_file::write_atomically(p, b"ready\n").with_context(|| format!("writing {}", p.display()))?;
    }
    if !args.quiet {
        eprintln!(
            "g1-can-emu: {} motors on {} (IMU on {}), model {}, waiting for the firmware",
            layout.motors.len(),
            layout.interfaces.join(","),
            layout.interfaces[layout.imu_bus],
            args.model
        );
    }
    let mut emu = MotorEmulator::new(layout);
    let opts = ServeOptions {
        max_ticks: args.max_ticks,
        startup_timeout: Duration::from_secs_f64(args.startup_timeout_s),
        idle_timeout: Duration::from_secs_f64(args.idle_timeout_s),
        control_dt,
        power_off,
        imu_off,
        lidar_to: args.lidar_udp_to,
    };
    let report = serve(&mut buses, &mut emu, &mut bridge, &opts, |_, _| {})?;
    bridge.close();
    let json = serde_json::to_string_pretty(&report)? + "\n";
    match &args.report {
        Some(p) => {
            output_file::write_atomically(p, json.as_bytes()).with_context(|| format!("writing {}", p.display()))?
        }
        None => print!("{json}"),
    }
    if !args.quiet {
        eprintln!(
            "g1-can-emu: {} ticks ({:.2} s simulated in {:.1} s), fell: {}, ended: {}",
            report.ticks, report.time_s, report.wall_s, report.fell, report.end
        );
    }
    Ok(())
}
