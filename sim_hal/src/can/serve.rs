//! The emulator's loop: CAN frames in, the simulator stepped over the bridge, CAN frames out, and
//! a report judged from the simulator's ground truth (which never crosses the bus).
use std::net::{SocketAddr, UdpSocket};
use std::time::{Duration, Instant};

use hal::{LowLevel, LowState, TimeBase};

use super::{BusError, CanBuses, EmuCounters, EmuEvent, MotorEmulator};
use crate::bridge::{BridgeError, BridgeHal};

#[derive(Clone, Debug)]
pub struct ServeOptions {
    /// Stop after this many steps.
    pub max_ticks: Option<u64>,
    /// How long to wait for the firmware to put every motor into motor mode.
    pub startup_timeout: Duration,
    /// After start-up: how long the bus may stay silent before the firmware counts as gone.
    pub idle_timeout: Duration,
    /// Control period, s (for times in the report).
    pub control_dt: f64,
    /// Faults: (slot, tick) — that motor loses power after that many steps.
    pub power_off: Vec<(usize, u64)>,
    /// Fault: the IMU loses power after this many steps (its last sample is that step's).
    pub imu_off: Option<u64>,
    /// Play the MID-360 too: send each step's Livox datagrams (the simulator must have a world,
    /// and the bridge lidar) over UDP to this address, as the lidar sends them to the robot's computer.
    pub lidar_to: Option<SocketAddr>,
}

/// Judged from ground truth: did the robot stay up?
#[derive(Clone, Debug, serde::Serialize)]
pub struct EmuReport {
    /// Simulator steps (control ticks) served.
    pub ticks: u64,
    pub time_s: f64,
    /// Base below 0.5 m or tilted over 60° at any tick.
    pub fell: bool,
    pub fell_at_s: Option<f64>,
    pub base_z_min: f64,
    pub base_z_max: f64,
    pub tilt_max_deg: f64,
    pub distance_x_m: f64,
    pub distance_y_m: f64,
    /// Why serving ended.
    pub end: String,
    /// Joints whose motor was at rest (not in motor mode) when serving ended.
    pub motors_at_rest: Vec<String>,
    /// Livox datagrams sent over UDP (`lidar_to`), and sends that failed (nobody listening yet).
    pub lidar_datagrams_sent: u64,
    pub lidar_send_errors: u64,
    pub counters: EmuCounters,
    pub wall_s: f64,
}

#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    #[error(transparent)]
    Bus(#[from] BusError),
    #[error(transparent)]
    Bridge(#[from] BridgeError),
    // The cause is in the message, not a `source` link: `{:#}` chains print it once.
    #[error("lidar UDP socket towards {to}: {cause}")]
    LidarSocket { to: SocketAddr, cause: std::io::Error },
}

/// Serves the motors of `emu` on `buses` from the simulator behind `bridge` until the firmware goes
/// quiet, `max_ticks` steps were served, or the simulator ends.
pub fn serve<B: CanBuses>(
    buses: &mut B,
    emu: &mut MotorEmulator,
    bridge: &mut BridgeHal,
    opts: &ServeOptions,
    mut on_step: impl FnMut(u64, &LowState),
) -> Result<EmuReport, ServeError> {
    let wall = Instant::now();
    let mut state = LowState::default();
    bridge.wait_tick()?;
    let _ = bridge.read_state(&mut state);
    let t0 = *bridge.truth();
    let mut rep = EmuReport {
        ticks: 0,
        time_s: 0.0,
        fell: false,
        fell_at_s: None,
        base_z_min: t0.base_pos[2],
        base_z_max: t0.base_pos[2],
        tilt_max_deg: t0.tilt_deg(),
        distance_x_m: 0.0,
        distance_y_m: 0.0,
        end: String::new(),
        motors_at_rest: Vec::new(),
        lidar_datagrams_sent: 0,
        lidar_send_errors: 0,
        counters: EmuCounters::default(),
        wall_s: 0.0,
    };
    let lidar = match opts.lidar_to {
        Some(to) => {
            let err = |cause| ServeError::LidarSocket { to, cause };
            let bind: SocketAddr = if to.is_ipv4() { "0.0.0.0:0" } else { "[::]:0" }
                .parse()
                .expect("literal");
            let sock = UdpSocket::bind(bind).map_err(err)?;
            sock.connect(to).map_err(err)?;
            Some(sock)
        }
        None => None,
    };
    let mut last_heard = Instant::now();
    let mut send_error: Option<BusError> = None;
    loop {
        let limit = if emu.started() {
            opts.idle_timeout
        } else {
            opts.startup_timeout
        };
        let Some((bus, frame)) = buses.recv(Duration::from_millis(50))? else {
            if last_heard.elapsed() >= limit {
                rep.end = if emu.started() {
                    format!("the firmware went quiet for {:.1} s", limit.as_secs_f64())
                } else {
                    format!(
                        "no firmware put every motor into motor mode within {:.1} s",
                        limit.as_secs_f64()
                    )
                };
                break;
            }
            continue;
        };
        last_heard = Instant::now();
        let mut send = |b: usize, f: super::CanFrame| {
            if let Err(e) = buses.send(b, &f) {
                send_error.get_or_insert(e);
            }
        };
        if emu.on_frame(bus, &frame, &state, &mut send) != EmuEvent::Step {
            if let Some(e) = send_error.take() {
                return Err(e.into());
            }
            continue;
        }
        bridge.write_command(&emu.low_command())?;
        match bridge.wait_tick() {
            Ok(_) => {}
            Err(e) if hal::Error::kind(&e) == hal::ErrorKind::Disconnected => {
                rep.end = format!("the simulator ended: {e}");
                break;
            }
            Err(e) => return Err(e.into()),
        }
        // A bad or missing frame from the simulator (an injected fault) keeps the last state.
        let _ = bridge.read_state(&mut state);
        if let Some(sock) = &lidar {
            for d in crate::bridge::datagrams(bridge.lidar_datagrams()) {
                let Ok(d) = d else { break };
                match sock.send(d) {
                    Ok(_) => rep.lidar_datagrams_sent += 1,
                    Err(_) => rep.lidar_send_errors += 1,
                }
            }
        }
        rep.ticks += 1;
        let t = bridge.truth();
        let time = rep.ticks as f64 * opts.control_dt;
        rep.base_z_min = rep.base_z_min.min(t.base_pos[2]);
        rep.base_z_max = rep.base_z_max.max(t.base_pos[2]);
        rep.tilt_max_deg = rep.tilt_max_deg.max(t.tilt_deg());
        rep.distance_x_m = t.base_pos[0] - t0.base_pos[0];
        rep.distance_y_m = t.base_pos[1] - t0.base_pos[1];
        if !rep.fell && t.fallen() {
            rep.fell = true;
            rep.fell_at_s = Some(time);
        }
        emu.publish(&state, &mut send);
        if let Some(e) = send_error.take() {
            return Err(e.into());
        }
        for &(slot, at) in &opts.power_off {
            if rep.ticks == at {
                emu.power_off(slot);
            }
        }
        if opts.imu_off == Some(rep.ticks) {
            emu.imu_off();
        }
        on_step(rep.ticks, &state);
        if opts.max_ticks.is_some_and(|m| rep.ticks >= m) {
            rep.end = format!("served {} ticks", rep.ticks);
            break;
        }
    }
    rep.time_s = rep.ticks as f64 * opts.control_dt;
    rep.counters = emu.counters();
    rep.motors_at_rest = emu.resting_joints();
    rep.wall_s = wall.elapsed().as_secs_f64();
    Ok(rep)
}
