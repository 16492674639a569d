//! `g1fw sim`: start the simulator, run the firmware loop against it over the bridge, and evaluate
//! the run from the simulator's privileged ground truth (which never reaches the controller).
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use hal::{LowCommand, LowLevel, LowState, TimeBase};
use serde::Serialize;
use sha2::{Digest, Sha256};
use sim_hal::bridge::{BridgeHal, Truth};

use crate::controller::{Controller, DampingReason};
use crate::spec::DeploySpec;

/// Everything `g1fw sim` needs besides the spec.
#[derive(Clone, Debug)]
pub struct SimOptions {
    /// `g1-29dof`, `g1-12dof` or a path to an MJCF file (passed to the simulator).
    pub model: String,
    pub command: [f32; 3],
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
    pub progress: bool,
}

impl Default for SimOptions {
    fn default() -> Self {
        Self {
            model: "g1-29dof".into(),
            command: [0.0; 3],
            duration_s: 10.0,
            seed: 0,
            physics_dt: 0.002,
            ramp_override: None,
            sim_bin: None,
            connect: None,
            stop_on_fall: true,
            hold_only: false,
            progress: false,
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
    pub final_mode: String,
    pub repeated_commands: u64,
    /// sha256 over every LowState and LowCmd frame of the run, in order.
    pub state_trace_sha256: String,
    pub model: String,
    pub spec: String,
    pub weights_sha256: String,
    pub command: [f32; 3],
    pub seed: u64,
    #[serde(flatten)]
    pub timing: Timing,
}

/// Wall-clock figures: measured, never used by control, not part of determinism.
#[derive(Clone, Debug, Serialize)]
pub struct Timing {
    pub sim_seconds_per_wall_second: f64,
    pub max_tick_compute_us: f64,
    pub mean_tick_compute_us: f64,
}

/// Per-tick record handed to an observer (tests and tools).
pub struct TickRecord<'a> {
    pub index: u64,
    pub state: &'a LowState,
    pub command: &'a LowCommand,
    pub truth: &'a Truth,
    pub controller: &'a Controller,
    pub policy_step: bool,
}

/// A running simulator child process; killed if dropped before `finish`.
struct SimChild {
    child: Child,
    socket: PathBuf,
}

impl SimChild {
    fn status_line(&mut self) -> Result<(), String> {
        match self.child.try_wait() {
            Ok(Some(status)) => Err(format!(
                "the simulator exited during start-up ({status}); see its message above"
            )),
            Ok(None) => Ok(()),
            Err(e) => Err(format!("cannot poll the simulator process: {e}")),
        }
    }
}

impl Drop for SimChild {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            // Give it a moment to exit after Bye, then make sure it is gone.
            for _ in 0..100 {
                if let Ok(Some(_)) = self.child.try_wait() {
                    break;
                }
                std::thread::sleep(Duration::from_millis(5));
            }
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
        let _ = std::fs::remove_file(&self.socket);
    }
}

/// Locates the `g1-sim` binary: explicit path, `$G1_SIM_BIN`, or beside this executable (also one
/// level up, for test binaries in `target/*/deps`).
pub fn find_sim_bin(explicit: Option<&Path>) -> Result<PathBuf> {
    if let Some(p) = explicit {
        return Ok(p.to_path_buf());
    }
    if let Some(p) = std::env::var_os("G1_SIM_BIN") {
        return Ok(PathBuf::from(p));
    }
    let exe = std::env::current_exe().context("locating this executable")?;
    let dir = exe.parent().context("executable has no directory")?;
    for d in [Some(dir), dir.parent()].into_iter().flatten() {
        let c = d.join("g1-sim");
        if c.is_file() {
            return Ok(c);
        }
    }
    bail!(
        "cannot find the simulator binary g1-sim next to {}; build it with `cargo build --release -p g1_sim` \
         or pass --sim-bin PATH (or set G1_SIM_BIN)",
        exe.display()
    )
}

fn spawn_sim(opts: &SimOptions, control_dt: f64) -> Result<SimChild> {
    let bin = find_sim_bin(opts.sim_bin.as_deref())?;
    let socket = std::env::temp_dir().join(format!("g1fw-{}-{}.sock", std::process::id(), unique()));
    let _ = std::fs::remove_file(&socket);
    let child = Command::new(&bin)
        .arg("--socket")
        .arg(&socket)
        .args(["--model", &opts.model])
        .args(["--seed", &opts.seed.to_string()])
        .args(["--physics-dt", &opts.physics_dt.to_string()])
        .args(["--control-dt", &control_dt.to_string()])
        .arg("--quiet")
        .stdin(Stdio::null())
        .spawn()
        .with_context(|| format!("starting the simulator {}", bin.display()))?;
    Ok(SimChild { child, socket })
}

fn unique() -> u64 {
    use std::sync::atomic::{AtomicU64, Ordering};
    static N: AtomicU64 = AtomicU64::new(0);
    N.fetch_add(1, Ordering::Relaxed)
}

fn tilt_deg(q: [f64; 4]) -> f64 {
    let [_, x, y, _] = q;
    // Body z axis in world: its z component is 1 - 2(x² + y²).
    (1.0 - 2.0 * (x * x + y * y)).clamp(-1.0, 1.0).acos().to_degrees()
}

fn yaw(q: [f64; 4]) -> f64 {
    let [w, x, y, z] = q;
    (2.0 * (w * z + x * y)).atan2(1.0 - 2.0 * (y * y + z * z))
}

/// Runs the firmware against the simulator. `observe` sees every tick (evaluation only).
pub fn run_sim(mut spec: DeploySpec, opts: &SimOptions, mut observe: impl FnMut(&TickRecord)) -> Result<Report> {
    if let Some((ramp, hold)) = opts.ramp_override {
        spec.startup.ramp_s = ramp;
        spec.startup.hold_s = hold;
    }
    let spec_name = spec.path.display().to_string();
    let control_dt = spec.control_dt();
    let mut controller = if opts.hold_only {
        Controller::hold_only(spec)
    } else {
        Controller::new(spec)?
    };

    let mut child = None;
    let mut hal = match &opts.connect {
        Some(path) => BridgeHal::connect_unix(path, true, Duration::from_secs(10), || Ok(()))?,
        None => {
            let mut c = spawn_sim(opts, control_dt)?;
            let socket = c.socket.clone();
            let hal = BridgeHal::connect_unix(&socket, true, Duration::from_secs(30), || c.status_line())?;
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

    let total_ticks = (opts.duration_s / control_dt).round() as u64;
    let progress = opts.progress.then(|| progress_bar(opts.duration_s));
    let mut state = LowState::default();
    let mut cmd = LowCommand::default();
    let mut hasher = Sha256::new();
    let mut agg = Aggregate::default();
    let wall = Instant::now();
    let (mut max_compute, mut sum_compute) = (Duration::ZERO, Duration::ZERO);
    let mut ticks = 0u64;

    let result: Result<()> = (|| {
        loop {
            let tick = match hal.wait_tick() {
                Ok(t) => t,
                Err(e) => {
                    // Best effort: command damping before giving up (the link may still carry it).
                    controller.enter_damping(DampingReason::HalFault);
                    controller.damping_command(&state, &mut cmd);
                    let _ = hal.write_command(&cmd);
                    let at = format!("at tick {}", ticks + 1);
                    return Err(match hal::Error::kind(&e) {
                        hal::ErrorKind::Disconnected => {
                            anyhow::Error::new(e).context(format!("{} {at}", simulator_gone(&mut child)))
                        }
                        _ => anyhow::Error::new(e)
                            .context(format!("bad data from the simulator {at}; motors commanded to damping")),
                    });
                }
            };
            let t0 = Instant::now();
            hal.read_state(&mut state)?;
            let info = controller.tick(&state, tick, opts.command, &mut cmd);
            let last = tick.index >= total_ticks;
            if !last {
                hal.write_command(&cmd).with_context(|| simulator_gone(&mut child))?;
            }
            let compute = t0.elapsed();
            max_compute = max_compute.max(compute);
            sum_compute += compute;

            // Everything below is evaluation: it runs while the simulator steps.
            hasher.update(hal.state_bytes());
            if !last {
                hasher.update(hal.command_bytes());
            }
            let truth = *hal.truth();
            agg.add(&truth, tick.index as f64 * control_dt, opts.duration_s);
            observe(&TickRecord {
                index: tick.index,
                state: &state,
                command: &cmd,
                truth: &truth,
                controller: &controller,
                policy_step: info.policy_step,
            });
            ticks = tick.index;
            if let Some(pb) = &progress {
                if tick.index % 50 == 0 {
                    pb.set_position((tick.index as f64 * control_dt * 1000.0) as u64);
                    pb.set_message(format!(
                        "x {:+.2} m  z {:.2} m  {:?}",
                        truth.base_pos[0] - agg.start[0],
                        truth.base_pos[2],
                        controller.mode()
                    ));
                }
            }
            if last || (opts.stop_on_fall && agg.fell_at.is_some()) {
                break;
            }
        }
        Ok(())
    })();
    if let Some(pb) = progress {
        pb.finish_and_clear();
    }
    let repeated = hal.repeated_commands();
    hal.close();
    drop(child);
    result?;

    let wall_s = wall.elapsed().as_secs_f64();
    let time_s = ticks as f64 * control_dt;
    Ok(Report {
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
        policy_steps: controller.policy_steps(),
        final_mode: format!("{:?}", controller.mode()),
        repeated_commands: repeated,
        state_trace_sha256: format!("{:x}", hasher.finalize()),
        model: opts.model.clone(),
        spec: spec_name,
        weights_sha256: controller.weights_sha256(),
        command: opts.command,
        seed: opts.seed,
        timing: Timing {
            sim_seconds_per_wall_second: time_s / wall_s.max(1e-9),
            max_tick_compute_us: max_compute.as_secs_f64() * 1e6,
            mean_tick_compute_us: sum_compute.as_secs_f64() * 1e6 / (ticks.max(1) as f64),
        },
    })
}

fn simulator_gone(child: &mut Option<SimChild>) -> String {
    match child.as_mut().map(|c| c.child.try_wait()) {
        Some(Ok(Some(status))) => format!("the simulator exited mid-run ({status})"),
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
#[derive(Default)]
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
}

impl Aggregate {
    fn add(&mut self, t: &Truth, time_s: f64, duration_s: f64) {
        let y = yaw(t.base_quat);
        if !self.started {
            self.started = true;
            self.start = t.base_pos;
            self.start_yaw = y;
            self.prev_yaw = y;
            self.z_min = f64::INFINITY;
            self.z_max = f64::NEG_INFINITY;
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
        let tilt = tilt_deg(t.base_quat);
        self.tilt_max = self.tilt_max.max(tilt);
        if self.fell_at.is_none() && (z < 0.5 || tilt > 60.0) {
            self.fell_at = Some(time_s);
        }
        if time_s >= duration_s / 2.0 {
            self.sum_second_half[0] += t.base_lin_vel_body[0];
            self.sum_second_half[1] += t.base_lin_vel_body[1];
            self.sum_second_half[2] += t.base_ang_vel_body[2];
            self.n_second_half += 1;
        }
    }
    fn mean(&self, i: usize) -> f64 {
        self.sum_second_half[i] / self.n_second_half.max(1) as f64
    }
}
