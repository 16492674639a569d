//! `g1-sim --dds IFACE[,DOMAIN]`: the simulator as the robot on DDS, as unitree_mujoco plays it:
//! publishes `rt/lowstate`, subscribes `rt/lowcmd`. The same `g1fw run --dds` binary that runs on
//! the G1 then runs against it.
//!
//! Lock-stepped: one `rt/lowcmd` sample in → one control tick → one `rt/lowstate` out. Until the
//! first command, and whenever none follows a state within `resend_after`, the current state is
//! sent again (discovery may swallow the first samples; a BEST_EFFORT reader may drop one). What
//! changes in determinism against the socket bridge: the simulation itself is the same, but which
//! command meets which tick now depends on delivery — a lost or late sample, or a controller tick
//! that ran on its own timeout, shifts the pairing. Without loss the run repeats; with it, the
//! firmware's log still records exactly what it saw, and replay reproduces that bit for bit.
//! unitree_mujoco instead steps in wall-clock time and never waits for the controller.
//!
//! Free-running (`--dds-free-run`), as unitree_mujoco and the robot: held (not stepped) until the
//! first command, the state published every control period meanwhile (a robot on its gantry); then
//! one control tick per period on a monotonic clock at absolute deadlines, with the newest command
//! (the last one again when none came), and the state published after each. Ticks whose step ended
//! past the next deadline are counted (`late_ticks`), as are ticks without a new command.
//!
//! Faults (`--fault`, [`crate::faults`]) act on the state of control tick k as on the bridge: a
//! `drop` publishes nothing (the controller sees silence, as on a lossy link), `disconnect` stops
//! publishing for good and ends the run (the robot's DDS went away).
use std::time::{Duration, Instant};

use hal::{LowCommand, LowState};
use robot_io::dds::{DdsLink, Endpoint, ROBOT, SAMPLE_CAP};
use sensor_io::unitree_hg::cdr::{low_cmd_from_cdr, low_state_to_cdr, LOW_STATE_CDR_LEN};
use sensor_io::unitree_hg::{decode_low_cmd, encode_low_state, LOW_CMD_LEN, LOW_STATE_LEN};

use crate::faults::{FaultInjector, FaultPlan, Wire};
use crate::Simulator;

/// Base height under which a DDS run counts the robot as fallen.
pub const FELL_BELOW_M: f64 = 0.45;

#[derive(Clone, Debug)]
pub struct DdsServeOptions {
    pub endpoint: Endpoint,
    /// Send the state again when no command follows it within this long.
    pub resend_after: Duration,
    /// End when no command came for this long after the first one (`None`: run until killed).
    pub idle_exit: Option<Duration>,
    /// End after this much simulated time (`None`: no limit).
    pub max_sim_s: Option<f64>,
    /// Send the simulated MID-360's Livox datagrams here over UDP every tick, as the G1's lidar
    /// sends them to port 56301 (needs a world, so the simulator has a lidar).
    pub lidar_to: Option<std::net::SocketAddr>,
    /// Step on the wall clock at the control period instead of once per command.
    pub free_run: bool,
    pub quiet: bool,
    /// Faults to inject on the published states (empty: none).
    pub faults: FaultPlan,
}

/// What a DDS run did (`g1-sim --dds` prints it as one JSON line).
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct DdsSummary {
    pub ticks: u64,
    pub sim_time_s: f64,
    /// Commands that failed to decode (wrong size or encoding, CRC, non-finite): not applied.
    pub rejected_commands: u64,
    /// States sent again for lack of a command.
    pub resent_states: u64,
    /// Livox datagrams sent (`lidar_to`), and sends that failed (nobody listening yet).
    pub lidar_datagrams_sent: u64,
    pub lidar_send_errors: u64,
    /// Ground truth for the operator (never sent to the controller): base travel from the start
    /// (x, y, m), the lowest base height, and whether the robot fell (base below 0.45 m; the
    /// G1's pelvis stands at ~0.75 m).
    pub base_travel_m: [f64; 2],
    pub base_z_min_m: f64,
    pub fell: bool,
    /// Simulated time of the fall, s (a controller that damps at its end lets the robot sink
    /// after its last policy command: this says whether the fall came before or after).
    pub fell_at_s: Option<f64>,
    /// Free-running: ticks whose step ended past the next deadline, and ticks that found no new
    /// command (the last one held).
    pub late_ticks: u64,
    pub ticks_without_command: u64,
    /// States a `drop` fault kept off the wire.
    pub dropped_states: u64,
    /// A `disconnect` fault ended the run (`g1-sim` exits with status 4).
    pub fault_disconnect: bool,
}

/// Serves until idle, the time limit, or a DDS failure.
pub fn serve_dds(sim: &mut Simulator, opts: &DdsServeOptions, ready: impl FnOnce()) -> anyhow::Result<DdsSummary> {
    // Another robot on the same domain would interleave its states with ours: refuse.
    let lidar = match opts.lidar_to {
        Some(to) => {
            anyhow::ensure!(
                sim.has_lidar(),
                "--lidar-udp-to needs a simulated lidar: give g1-sim a --world"
            );
            let bind = if to.is_ipv4() { "0.0.0.0:0" } else { "[::]:0" };
            let sock = std::net::UdpSocket::bind(bind)?;
            sock.connect(to)?;
            Some(sock)
        }
        None => None,
    };
    let link = DdsLink::open(&opts.endpoint, ROBOT, Duration::from_millis(500), true)?;
    ready();
    let mut state = LowState::default();
    let mut c_state = [0u8; LOW_STATE_LEN];
    let mut cdr_state = [0u8; LOW_STATE_CDR_LEN];
    let mut raw = vec![0u8; SAMPLE_CAP];
    let mut c_cmd = [0u8; LOW_CMD_LEN];
    let mut cmd = LowCommand::default();
    let mut summary = DdsSummary::default();
    let mut faults = FaultInjector::new(&opts.faults, sim.config().control_dt, sim.motor_slots_present())?;
    // The state of the tick stepped last, through the faults; `false` once a `disconnect` fault
    // says the robot is gone (nothing sent).
    let mut publish = |sim: &mut Simulator, link: &DdsLink, summary: &mut DdsSummary| -> anyhow::Result<bool> {
        sim.low_state(&mut state);
        let wire = match faults.as_mut() {
            None => {
                encode_low_state(&state, &mut c_state);
                Wire::Frame
            }
            Some(f) => f.apply(summary.ticks, sim, &mut state, &mut c_state),
        };
        match wire {
            Wire::Frame => {
                low_state_to_cdr(&c_state, &mut cdr_state);
                link.send(&cdr_state)?;
            }
            Wire::NoFrame => summary.dropped_states += 1,
            Wire::Disconnect => {
                summary.fault_disconnect = true;
                return Ok(false);
            }
        }
        Ok(true)
    };
    publish(sim, &link, &mut summary)?;
    let start = sim.truth().base_pos;
    summary.base_z_min_m = start[2];
    let mut seen = 0u64;
    let mut last_command: Option<Instant> = None;
    let period = Duration::from_secs_f64(sim.config().control_dt);
    let mut free_start: Option<Instant> = None;
    let mut free_tick = 0u32;
    while !summary.fault_disconnect {
        if opts.free_run {
            // Held until the first command; then one tick per period whatever arrives.
            let wait = if free_start.is_some() { Duration::ZERO } else { period };
            let got = link.wait_newer(seen, wait, &mut raw)?;
            if let Some((seq, len)) = got {
                seen = seq;
                last_command = Some(Instant::now());
                if decode_command(
                    &raw[..len.min(raw.len())],
                    &mut c_cmd,
                    &mut cmd,
                    &mut summary,
                    opts.quiet,
                ) {
                    sim.apply_command(&cmd)?;
                }
                free_start.get_or_insert_with(Instant::now);
            } else if free_start.is_some() {
                summary.ticks_without_command += 1;
            }
            let Some(t0) = free_start else {
                summary.resent_states += 1;
                if !publish(sim, &link, &mut summary)? {
                    break;
                }
                continue;
            };
            control_tick(sim, lidar.as_ref(), &mut summary);
            if !publish(sim, &link, &mut summary)? {
                break;
            }
            free_tick += 1;
            let deadline = t0 + period * free_tick;
            match deadline.checked_duration_since(Instant::now()) {
                Some(wait) => std::thread::sleep(wait),
                None => summary.late_ticks += 1,
            }
            if let (Some(t), Some(idle)) = (last_command, opts.idle_exit) {
                if t.elapsed() >= idle {
                    break;
                }
            }
            if opts.max_sim_s.is_some_and(|m| sim.time() >= m) {
                break;
            }
            continue;
        }
        match link.wait_newer(seen, opts.resend_after, &mut raw)? {
            Some((seq, len)) => {
                seen = seq;
                last_command = Some(Instant::now());
                if !decode_command(
                    &raw[..len.min(raw.len())],
                    &mut c_cmd,
                    &mut cmd,
                    &mut summary,
                    opts.quiet,
                ) {
                    // A robot ignores a command it cannot read; the controller's next one counts.
                    summary.resent_states += 1;
                    if !publish(sim, &link, &mut summary)? {
                        break;
                    }
                    continue;
                }
                sim.apply_command(&cmd)?;
                control_tick(sim, lidar.as_ref(), &mut summary);
                if !publish(sim, &link, &mut summary)? {
                    break;
                }
            }
            None => {
                if let (Some(t), Some(idle)) = (last_command, opts.idle_exit) {
                    if t.elapsed() >= idle {
                        break;
                    }
                }
                summary.resent_states += 1;
                if !publish(sim, &link, &mut summary)? {
                    break;
                }
            }
        }
        if opts.max_sim_s.is_some_and(|m| sim.time() >= m) {
            break;
        }
    }
    summary.sim_time_s = sim.time();
    let end = sim.truth().base_pos;
    summary.base_travel_m = [end[0] - start[0], end[1] - start[1]];
    summary.fell = summary.base_z_min_m < FELL_BELOW_M;
    Ok(summary)
}

/// Decodes an `rt/lowcmd` sample into `cmd`. A sample that does not decode (size, encoding, CRC,
/// non-finite values) is counted and, the first time, named; the robot ignores it.
fn decode_command(
    raw: &[u8],
    c_cmd: &mut [u8; LOW_CMD_LEN],
    cmd: &mut LowCommand,
    summary: &mut DdsSummary,
    quiet: bool,
) -> bool {
    let decoded = low_cmd_from_cdr(raw, c_cmd)
        .map_err(|e| e.to_string())
        .and_then(|()| decode_low_cmd(c_cmd, cmd).map_err(|e| e.to_string()));
    if let Err(e) = decoded {
        if summary.rejected_commands == 0 && !quiet {
            eprintln!("g1-sim: rejected rt/lowcmd sample: {e}");
        }
        summary.rejected_commands += 1;
        return false;
    }
    true
}

/// One control tick of the robot: physics, the lidar's datagrams, the fall check.
fn control_tick(sim: &mut Simulator, lidar: Option<&std::net::UdpSocket>, summary: &mut DdsSummary) {
    sim.step_control_tick();
    summary.ticks += 1;
    send_lidar(sim, lidar, summary);
    let z = sim.truth().base_pos[2];
    summary.base_z_min_m = summary.base_z_min_m.min(z);
    if z < FELL_BELOW_M && summary.fell_at_s.is_none() {
        summary.fell_at_s = Some(sim.time());
    }
}

/// The tick's Livox datagrams to `--lidar-udp-to`, if set.
fn send_lidar(sim: &Simulator, lidar: Option<&std::net::UdpSocket>, summary: &mut DdsSummary) {
    let Some(sock) = lidar else { return };
    for d in sim_hal::bridge::datagrams(sim.lidar_datagrams()) {
        let Ok(d) = d else { break };
        match sock.send(d) {
            Ok(_) => summary.lidar_datagrams_sent += 1,
            Err(_) => summary.lidar_send_errors += 1,
        }
    }
}
