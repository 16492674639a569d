//! The firmware on CAN on a machine whose kernel has no CAN: firmware (`g1fw run`'s code) ⇄ an
//! in-process bus ⇄ the motor emulator (`g1-can-emu`'s code) ⇄ bridge ⇄ g1-sim (MuJoCo), with a
//! third node on the bus that sniffs and injects. The same checks run over vcan in the HIL VM
//! (`cargo xtask hil`, with python-can as the independent peer).
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use control::operator::CommandSchedule;
use control::spec::DeploySpec;
use firmware::robot_run::{run_on, RunOptions, RunReport};
use integration_tests::*;
use sensor_io::can::{decode_motor_rx, BusLayout, CanFrame, MotorRx, IMU_ACCEL_ID};
use sim_hal::bridge::{SimLaunch, Wants};
use sim_hal::can::{mem_buses, serve, CanBuses, EmuReport, MemBuses, MotorEmulator, ServeOptions};

/// The robot's layout, with a longer IMU timeout: these runs are lock-stepped on a shared machine
/// where a process can stall for longer than the robot's 250 ms.
fn layout() -> BusLayout {
    let mut l = BusLayout::load(&repo_root().join("specs/can/g1_12dof.toml")).expect("bus layout");
    l.tick_timeout_ms = 10_000;
    l
}

/// g1-sim with the 12-dof model, and the emulator serving it on `bus` in a thread, with `sc`'s
/// length and emulator-side faults.
/// `emu_tick` follows the emulator's tick, so the injecting node can say when its frames reached
/// the bus (on a loaded machine that thread lags the lock-stepped pair by many ticks).
fn start_emulator(name: &str, mut bus: MemBuses, sc: &Scenario, emu_tick: Arc<AtomicU64>) -> JoinHandle<EmuReport> {
    let launch = SimLaunch {
        bin: Some(built_bin("g1-sim")),
        world: sc.lidar_port.map(|_| "stairs-up".to_string()),
        ..SimLaunch::new("g1-12dof", 0.002)
    };
    let opts = ServeOptions {
        // The firmware commands ticks 0..N-1 of an N-tick run: then the emulator is done.
        max_ticks: Some((sc.duration_s / 0.002).round() as u64),
        startup_timeout: Duration::from_secs(60),
        // Without an IMU the firmware stops early: do not wait long for it after that.
        idle_timeout: Duration::from_secs(if sc.imu_off.is_some() { 2 } else { 10 }),
        control_dt: 0.002,
        power_off: sc.power_off.clone(),
        imu_off: sc.imu_off,
        lidar_to: sc.lidar_port.map(|p| std::net::SocketAddr::from(([127, 0, 0, 1], p))),
    };
    let tag = format!("can_bus_{name}");
    let lidar_to_set = sc.lidar_port.is_some();
    std::thread::spawn(move || {
        let wants = Wants {
            truth: true,
            lidar: lidar_to_set,
        };
        let (sim, mut bridge) = launch
            .start(&tag, wants, Duration::from_secs(60))
            .expect("start g1-sim and connect");
        let mut emu = MotorEmulator::new(layout());
        let r = serve(&mut bus, &mut emu, &mut bridge, &opts, |tick, _| {
            emu_tick.store(tick, Ordering::Relaxed)
        })
        .expect("emulator serves");
        bridge.close();
        drop(sim);
        r
    })
}

/// What the third node saw: every frame in order, the IMU samples counted.
#[derive(Default)]
struct Sniffed {
    frames: Vec<(usize, CanFrame, u64)>,
    /// The emulator's tick just after the first injected frame was sent.
    injected_at_tick: Option<u64>,
}

/// A node that records everything and, after `at_sample` IMU samples, sends `inject` once.
fn start_peer(
    mut bus: MemBuses,
    at_sample: u64,
    inject: Vec<(usize, CanFrame)>,
    done: Arc<AtomicBool>,
    emu_tick: Arc<AtomicU64>,
) -> (JoinHandle<()>, Arc<Mutex<Sniffed>>) {
    let seen = Arc::new(Mutex::new(Sniffed::default()));
    let out = seen.clone();
    let h = std::thread::spawn(move || {
        let mut samples = 0u64;
        let mut injected = inject.is_empty();
        while !done.load(Ordering::Relaxed) {
            let Ok(Some((b, f))) = bus.recv(Duration::from_millis(20)) else {
                continue;
            };
            if f.id == IMU_ACCEL_ID {
                samples += 1;
            }
            seen.lock().unwrap().frames.push((b, f, samples));
            if !injected && samples >= at_sample {
                for (i, (b, f)) in inject.iter().enumerate() {
                    bus.send(*b, f).unwrap();
                    if i == 0 {
                        seen.lock().unwrap().injected_at_tick = Some(emu_tick.load(Ordering::Relaxed));
                    }
                }
                injected = true;
            }
        }
    });
    (h, out)
}

struct Run {
    fw: RunReport,
    emu: EmuReport,
    sniffed: Vec<(usize, CanFrame, u64)>,
    injected_at_tick: Option<u64>,
}

/// One firmware ⇄ emulator run and what goes wrong in it.
struct Scenario {
    cmd: [f32; 3],
    duration_s: f64,
    /// The third node sends `inject` once after this many IMU samples.
    at_sample: u64,
    inject: Vec<(usize, CanFrame)>,
    /// Motors that lose power: (slot, tick).
    power_off: Vec<(usize, u64)>,
    /// The IMU loses power after this tick.
    imu_off: Option<u64>,
    /// The firmware's IMU timeout instead of `layout()`'s.
    tick_timeout_ms: Option<u32>,
    /// MCAP log of the firmware.
    log: Option<std::path::PathBuf>,
    /// The emulator plays the MID-360 too (g1-sim on `stairs-up`), sending its packets over UDP to
    /// the firmware on this loopback port, and the firmware runs the stair spec (with perception).
    lidar_port: Option<u16>,
    /// The firmware's control loop panics on this tick (`RunOptions::inject_panic_at_tick`).
    panic_at: Option<u64>,
    /// An operated run (`--operated`) stepped by this schedule instead of walking at `cmd`.
    operated: Option<&'static str>,
}

impl Scenario {
    /// A 2 s walk at 0.3 m/s with nothing wrong.
    fn walk() -> Self {
        Self {
            cmd: [0.3, 0.0, 0.0],
            duration_s: 2.0,
            at_sample: 0,
            inject: vec![],
            power_off: vec![],
            imu_off: None,
            tick_timeout_ms: None,
            log: None,
            lidar_port: None,
            panic_at: None,
            operated: None,
        }
    }
}

fn run(name: &str, cmd: [f32; 3], duration_s: f64, at_sample: u64, inject: Vec<(usize, CanFrame)>) -> Run {
    run_scenario(
        name,
        Scenario {
            cmd,
            duration_s,
            at_sample,
            inject,
            ..Scenario::walk()
        },
    )
}

fn run_scenario(name: &str, sc: Scenario) -> Run {
    let mut eps = mem_buses(2, 3).into_iter();
    let (fw_bus, emu_bus, peer_bus) = (eps.next().unwrap(), eps.next().unwrap(), eps.next().unwrap());
    let done = Arc::new(AtomicBool::new(false));
    let emu_tick = Arc::new(AtomicU64::new(0));
    let (peer, sniffed) = start_peer(
        peer_bus,
        sc.at_sample,
        sc.inject.clone(),
        done.clone(),
        emu_tick.clone(),
    );
    let emu = start_emulator(name, emu_bus, &sc, emu_tick);
    let spec = match sc.lidar_port {
        None => DeploySpec::load(&peer_spec_path()).expect("peer spec"),
        Some(_) => DeploySpec::load(&repo_root().join("specs/stairs/g1_stairs_lstm.toml")).expect("stair spec"),
    };
    let opts = RunOptions {
        schedule: match sc.operated {
            Some(text) => CommandSchedule::parse(text, std::path::Path::new("inline")).expect("schedule"),
            None => CommandSchedule::constant(sc.cmd),
        },
        operated: sc.operated.is_some(),
        duration_s: Some(sc.duration_s),
        startup_timeout: Duration::from_secs(60),
        log: sc.log,
        lidar: sc.lidar_port.map(|p| robot_io::UdpLidarConfig {
            bind: std::net::SocketAddr::from(([127, 0, 0, 1], p)),
            lidar: Some([127, 0, 0, 1].into()),
            ..Default::default()
        }),
        inject_panic_at_tick: sc.panic_at,
        ..RunOptions::default()
    };
    let mut fw_layout = layout();
    if let Some(ms) = sc.tick_timeout_ms {
        fw_layout.tick_timeout_ms = ms;
    }
    let fw = run_on(spec, fw_layout, fw_bus, &opts).expect("firmware runs on CAN");
    let emu = emu.join().expect("emulator thread");
    done.store(true, Ordering::Relaxed);
    peer.join().unwrap();
    let (sniffed, injected_at_tick) = {
        let mut s = sniffed.lock().unwrap();
        (std::mem::take(&mut s.frames), s.injected_at_tick)
    };
    eprintln!(
        "{name}: fw {} ticks, mode {}, trip {:?}, can {:?}; emulator {} ticks, fell {}, z_min {:.3}, x {:.2} m, {:.1} s wall",
        fw.ticks, fw.final_mode, fw.trip, fw.can.expect("CAN counters"), emu.ticks, emu.fell, emu.base_z_min, emu.distance_x_m, emu.wall_s
    );
    Run {
        fw,
        emu,
        sniffed,
        injected_at_tick,
    }
}

/// Decoded firmware commands on the bus, in order: (IMU samples seen before it, slot, kp, kd).
fn commands(r: &Run) -> Vec<(u64, usize, f32, f32)> {
    let l = layout();
    r.sniffed
        .iter()
        .filter_map(|(b, f, s)| {
            let i = l.motor_index(*b, f.id.try_into().ok()?)?;
            match decode_motor_rx(f, &l.motors[i].ranges) {
                Ok(MotorRx::Command(c)) => Some((*s, l.motors[i].slot, c.kp, c.kd)),
                _ => None,
            }
        })
        .collect()
}

/// A decoded firmware command on the bus: (IMU samples seen before it, slot, kp, kd).
type BusCommand = (u64, usize, f32, f32);

/// The commands on the bus split before the trailing run of damping commands (kp 0 and the peer
/// spec's damping kd, which travels as a 12-bit fixed-point value), checked to be whole rounds of
/// one per motor.
fn split_trailing_damping(r: &Run) -> (Vec<BusCommand>, Vec<BusCommand>) {
    let kd = DeploySpec::load(&peer_spec_path()).unwrap().safety.damping_kd;
    let mut cmds = commands(r);
    let n = cmds
        .iter()
        .rev()
        .take_while(|&&(_, _, kp, d)| kp == 0.0 && (d - kd).abs() < 0.01)
        .count();
    let damping = cmds.split_off(cmds.len() - n);
    assert_eq!(damping.len() % 12, 0, "damping in whole rounds of the 12 motors");
    for round in damping.chunks(12) {
        let mut slots: Vec<usize> = round.iter().map(|c| c.1).collect();
        slots.sort();
        assert_eq!(slots, layout().motors.iter().map(|m| m.slot).collect::<Vec<_>>());
    }
    (cmds, damping)
}

/// Decoded firmware commands after IMU sample `from`: (slot, kp, kd).
fn commands_after(r: &Run, from: u64) -> Vec<(usize, f32, f32)> {
    commands(r)
        .into_iter()
        .filter(|c| c.0 > from)
        .map(|(_, slot, kp, kd)| (slot, kp, kd))
        .collect()
}

#[test]
fn walks_ten_seconds_over_can() {
    if shared_dir().is_none() {
        return skip_or_fail("walking over CAN");
    }
    // 0.6 s of start-up ramp and hold, then at least 10 s under the policy.
    let r = run("walk", [0.5, 0.0, 0.0], 11.0, 0, vec![]);
    assert!(!r.emu.fell, "fell over CAN: {:?}", r.emu);
    assert!(r.fw.trip.is_none(), "false trip over CAN: {:?}", r.fw.trip);
    assert_eq!(r.fw.final_mode, "Policy");
    assert!(r.fw.policy_steps >= 500, "{}", r.fw.policy_steps);
    assert!(r.emu.distance_x_m > 2.0, "walked {:.2} m", r.emu.distance_x_m);
    // A normal end damps too: the damping command every period for 1 s (--end-damping's default).
    let (walk, damping) = split_trailing_damping(&r);
    let end = r.fw.end_damping;
    assert_eq!((end.sent, end.failed), (500, 0), "{end:?}");
    assert!(end.seconds >= 0.99, "{end:?}");
    assert_eq!(
        damping.len() as u64,
        12 * end.sent,
        "damping commands on the bus after the end"
    );
    assert!(walk.iter().all(|&(_, _, kp, _)| kp > 0.0), "no damping before the end");
    let c = r.fw.can.expect("CAN counters");
    assert_eq!(
        (c.malformed, c.foreign, c.missing_replies, c.imu_gaps),
        (0, 0, 0, 0),
        "{c:?}"
    );
    // One command per motor per IMU sample, one reply per command.
    let e = r.emu.counters;
    assert_eq!(e.commands, 12 * r.fw.ticks, "{e:?}");
    // Start-up repeats *enter motor mode* until the emulator listens; each one is answered too.
    assert_eq!(c.replies, e.commands + e.specials, "{c:?} {e:?}");
    // Ids and layout on the wire: commands on ids 1..=6 of both buses.
    let mut ids: Vec<(usize, u16)> = r
        .sniffed
        .iter()
        .filter(|(_, f, _)| f.id < 0x80)
        .map(|(b, f, _)| (*b, f.id))
        .collect();
    ids.sort();
    ids.dedup();
    assert_eq!(
        ids,
        (0..2).flat_map(|b| (1..=6).map(move |i| (b, i))).collect::<Vec<_>>()
    );
}

/// The operated state machine runs unchanged over CAN: passive (damping on the bus) until the
/// operator's stand-up, the ramp, standing, walking, standing again, sitting down to passive.
#[test]
fn the_operator_steps_the_robot_through_its_states_over_can() {
    if shared_dir().is_none() {
        return skip_or_fail("an operated run over CAN");
    }
    let r = run_scenario(
        "operated",
        Scenario {
            duration_s: 6.0,
            operated: Some("0.5 stand_up\n1.2 walk\n1.22 0.4 0 0\n4.0 0 0 0\n4.8 stand\n5.45 sit_down\n"),
            ..Scenario::walk()
        },
    );
    assert!(r.fw.trip.is_none(), "{:?}", r.fw.trip);
    assert!(!r.emu.fell, "{:?}", r.emu);
    assert_eq!(r.fw.final_mode, "Passive");
    let changes: Vec<(&str, &str, f64)> = r.fw.transitions.iter().map(|c| (c.to, c.source, c.time_s)).collect();
    let want = [
        ("startup", "schedule", 0.5),
        ("stand", "ramp", 1.1),
        ("policy", "schedule", 1.2),
        ("startup", "schedule", 4.8),
        ("stand", "ramp", 5.4),
        ("sit_down", "schedule", 5.45),
        ("passive", "ramp", 5.95),
    ];
    assert_eq!(changes.len(), want.len(), "{changes:?}");
    for ((to, source, t), (wto, wsource, wt)) in changes.iter().zip(want) {
        assert_eq!((*to, *source), (wto, wsource), "{changes:?}");
        assert!((t - wt).abs() < 0.01, "{changes:?}");
    }
    assert!(r.emu.distance_x_m > 0.6, "walked {:.2} m", r.emu.distance_x_m);
    // Passive before the stand-up: only damping went out on the bus (kp 0).
    let cmds = commands(&r);
    let first_drive = cmds.iter().find(|c| c.2 > 0.0).expect("the motors were driven").0;
    assert!(
        (240..=260).contains(&first_drive),
        "the first command with kp > 0 after {first_drive} IMU samples (stand-up at 0.5 s = 250)"
    );
}

#[test]
fn same_inputs_give_the_same_commands_on_the_bus() {
    if shared_dir().is_none() {
        return skip_or_fail("CAN determinism");
    }
    let dir = scratch_dir("can_bus_log");
    let log = dir.join("det_a.mcap");
    let a = run_scenario(
        "det_a",
        Scenario {
            log: Some(log.clone()),
            ..Scenario::walk()
        },
    );
    let b = run("det_b", [0.3, 0.0, 0.0], 2.0, 0, vec![]);
    let cmds = |r: &Run| -> Vec<(usize, CanFrame)> {
        r.sniffed
            .iter()
            .filter(|(_, f, _)| f.id < 0x80 && f.data[..7] != [0xFF; 7])
            .map(|(b, f, _)| (*b, *f))
            .collect()
    };
    let (ca, cb) = (cmds(&a), cmds(&b));
    assert!(ca.len() > 12 * 900, "{}", ca.len());
    assert!(ca == cb, "the command frames differ between two identical runs");
    // And the log of a CAN run replays bit-exact through the same firmware code.
    let rep = runlog::replay::replay(&log, &runlog::replay::ReplayOptions::default()).expect("replay");
    assert!(rep.divergence.is_none(), "{}", rep.divergence.unwrap());
    assert!(
        rep.compared_commands >= 999 && rep.compared_policy_steps >= 60,
        "{rep:?}"
    );
}

/// Each injected fault ends in damping with the expected reason, and the bus shows it: every
/// command after the trip has kp = 0 and kd > 0.
#[test]
fn every_injected_fault_ends_in_damping() {
    if shared_dir().is_none() {
        return skip_or_fail("CAN fault injection");
    }
    let flood: Vec<(usize, CanFrame)> = (0..2000)
        .map(|i| (i % 2, CanFrame::new(0x7FF, &[i as u8; 8])))
        .collect();
    type Injection = Vec<(usize, CanFrame)>;
    let cases: Vec<(&str, Injection, &str)> = vec![
        (
            "short_reply",
            vec![(0, CanFrame::new(0x101, &[1, 2, 3]))],
            "malformed_frame",
        ),
        (
            "reply_names_wrong_motor",
            vec![(0, CanFrame::new(0x101, &[2, 0x80, 0, 0x80, 0x08, 0]))],
            "malformed_frame",
        ),
        (
            "unknown_node",
            vec![(1, CanFrame::new(0x142, &[0x42, 0, 0, 0, 0, 0]))],
            "malformed_frame",
        ),
        (
            "second_master",
            vec![(0, CanFrame::new(0x003, &[0x80, 0, 0x80, 0, 0, 0, 0x08, 0]))],
            "malformed_frame",
        ),
        ("flood", flood, "malformed_frame"),
        (
            "imu_short_frame",
            vec![(0, CanFrame::new(0x082, &[0, 0, 0, 0]))],
            "malformed_frame",
        ),
        // A gyroscope frame whose sequence the accelerometer frame will not match.
        (
            "imu_sequence_mismatch",
            vec![(0, CanFrame::new(0x082, &[0, 0, 0, 0, 0, 0, 0xFF, 0xFF]))],
            "malformed_frame",
        ),
        // Somebody else's *exit motor mode* on the bus is a second master too.
        (
            "exit_motor_mode_from_elsewhere",
            vec![(1, CanFrame::new(4, &[0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFD]))],
            "malformed_frame",
        ),
    ];
    let inject_at = 700; // after the 0.6 s start-up, in the policy
    for (name, frames, reason) in cases {
        let r = run(name, [0.3, 0.0, 0.0], 2.0, inject_at, frames);
        let trip =
            r.fw.trip
                .as_ref()
                .unwrap_or_else(|| panic!("{name}: no trip: {:?}", r.fw));
        assert_eq!(trip.reason, reason, "{name}");
        // Judged from when the frames reached the bus: the injecting thread may lag the pair.
        let on_bus = r.injected_at_tick.expect("the peer injected");
        let delay = trip.tick.saturating_sub(on_bus);
        assert!(
            trip.tick >= inject_at - 1 && delay <= 15,
            "{name}: tripped at tick {}, the frames reached the bus at tick {on_bus}",
            trip.tick
        );
        assert!(r.fw.final_mode.starts_with("Damping"), "{name}: {}", r.fw.final_mode);
        let after = commands_after(&r, trip.tick + 2);
        assert!(
            after.len() >= 12 * 100,
            "{name}: {} commands after the trip",
            after.len()
        );
        assert!(
            after.iter().all(|&(_, kp, kd)| kp == 0.0 && kd > 0.0),
            "{name}: a command after the trip is not damping"
        );
        eprintln!("{name}: {reason} {delay} ticks after the injection");
    }
}

/// A motor that loses power goes silent: after `motor_timeout_ticks` the supervisor damps, naming it.
#[test]
fn a_motor_that_stops_answering_ends_in_damping() {
    if shared_dir().is_none() {
        return skip_or_fail("CAN silent motor");
    }
    let knee = 9; // right_knee
    let r = run_scenario(
        "power_off",
        Scenario {
            power_off: vec![(knee, 700)],
            ..Scenario::walk()
        },
    );
    let trip = r.fw.trip.as_ref().expect("a trip");
    assert_eq!(trip.reason, "motor_silent (right_knee)");
    let timeout = layout().motor_timeout_ticks as u64;
    assert!(
        (700..=700 + timeout + 1).contains(&trip.tick),
        "tripped at {}",
        trip.tick
    );
    let can = r.fw.can.expect("CAN counters");
    assert!(can.missing_replies >= 1000 - 701, "{can:?}");
    let after = commands_after(&r, trip.tick + 2);
    assert!(!after.is_empty() && after.iter().all(|&(_, kp, kd)| kp == 0.0 && kd > 0.0));
    assert_eq!(r.emu.motors_at_rest, ["right_knee"]);
}

/// An IMU that stops (the tick never comes again): after `tick_timeout_ms` the firmware damps
/// every motor, ends with a HAL failure that says what to check, and its log keeps every tick it
/// ran and replays bit-exact.
#[test]
fn an_imu_that_stops_ends_the_run_in_damping() {
    if shared_dir().is_none() {
        return skip_or_fail("CAN silent IMU");
    }
    let dir = scratch_dir("can_bus_imu_off");
    let log = dir.join("imu_off.mcap");
    let r = run_scenario(
        "imu_off",
        Scenario {
            imu_off: Some(700),
            // Long enough not to fire on a stall of this shared machine, short enough to wait for.
            tick_timeout_ms: Some(1000),
            log: Some(log.clone()),
            ..Scenario::walk()
        },
    );
    // Sample 700 was the IMU's last: tick 701 never came, and that is where the run ends.
    assert_eq!(r.fw.ticks, 701);
    assert!(
        r.fw.end.contains("HAL failure") && r.fw.end.contains("the IMU stopped"),
        "{}",
        r.fw.end
    );
    let trip = r.fw.trip.as_ref().expect("a trip");
    assert_eq!((trip.reason.as_str(), trip.tick), ("hal_fault", 701));
    assert!(r.fw.final_mode.starts_with("Damping"), "{}", r.fw.final_mode);
    // On the bus: the walk's commands up to the last sample, then one damping command per motor
    // at once, and the end's damping for 1 s.
    let (walk, damping) = split_trailing_damping(&r);
    assert_eq!(
        damping.len() as u64,
        12 * (1 + r.fw.end_damping.sent),
        "{:?}",
        r.fw.end_damping
    );
    assert!(r.fw.end_damping.sent >= 500);
    assert!(walk.iter().filter(|c| c.0 > 600).all(|&(_, _, kp, _)| kp > 0.0));
    // (The emulator, stepping on commands, serves the end's damping rounds too: it no longer goes
    // quiet after the IMU's last sample.)
    // Nothing already logged is lost: the log closes and replays to its last tick.
    let rep = runlog::replay::replay(&log, &runlog::replay::ReplayOptions::default()).expect("replay");
    assert!(rep.divergence.is_none(), "{}", rep.divergence.unwrap());
    assert!(rep.compared_commands >= 700, "{rep:?}");
}

/// A panic in the control loop (a bug, forced here) is caught by the loop's guard: one damping
/// command per enabled motor goes out on the bus, the run reports it, and the log keeps every tick
/// before the panic and replays bit-exact.
#[test]
fn a_panic_in_the_control_loop_damps_every_motor() {
    if shared_dir().is_none() {
        return skip_or_fail("CAN panic guard");
    }
    let dir = scratch_dir("can_bus_panic");
    let log = dir.join("panic.mcap");
    let r = run_scenario(
        "panic",
        Scenario {
            panic_at: Some(600),
            log: Some(log.clone()),
            ..Scenario::walk()
        },
    );
    assert_eq!(r.fw.ticks, 600);
    assert!(
        r.fw.panicked && r.fw.end.contains("injected at tick 600") && r.fw.end.contains("damping sent"),
        "{}",
        r.fw.end
    );
    // The guard's damping command per motor, then the end's damping for 1 s.
    let (walk, damping) = split_trailing_damping(&r);
    assert_eq!(
        damping.len() as u64,
        12 * (1 + r.fw.end_damping.sent),
        "{:?}",
        r.fw.end_damping
    );
    assert!(r.fw.end_damping.sent >= 500);
    assert!(walk.iter().filter(|c| c.0 > 500).all(|&(_, _, kp, _)| kp > 0.0));
    let rep = runlog::replay::replay(&log, &runlog::replay::ReplayOptions::default()).expect("replay");
    assert!(rep.divergence.is_none() && rep.damaged.is_none(), "{rep:?}");
    assert!(rep.compared_commands >= 600, "{rep:?}");
}

/// The robot's full sensor set: motors and IMU on CAN, the MID-360 over UDP. The emulator sends the
/// simulated lidar's packets to `g1fw run --lidar-udp`'s socket; the stair spec's perception turns
/// them into frames and tokens while the robot walks.
#[test]
fn the_mid360_over_udp_feeds_perception_on_can() {
    if shared_dir().is_none() {
        return skip_or_fail("UDP lidar over CAN");
    }
    // A free loopback port (released again just before the firmware binds it).
    let port = std::net::UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let r = run_scenario(
        "udp_lidar",
        Scenario {
            cmd: [0.0, 0.0, 0.0],
            duration_s: 1.5,
            lidar_port: Some(port),
            ..Scenario::walk()
        },
    );
    let lidar = r.fw.lidar.expect("the report has the lidar's counters");
    eprintln!(
        "lidar {lidar:?}; emulator sent {} ({} failed)",
        r.emu.lidar_datagrams_sent, r.emu.lidar_send_errors
    );
    assert_eq!(r.fw.end, "completed", "{:?}", r.fw.trip);
    assert!(r.fw.trip.is_none(), "{:?}", r.fw.trip);
    assert!(r.emu.lidar_datagrams_sent > 1000, "{}", r.emu.lidar_datagrams_sent);
    // Loopback loses nothing the socket's buffer holds; the last tick's packets may still be in flight.
    assert!(lidar.datagrams + 100 >= r.emu.lidar_datagrams_sent, "{lidar:?}");
    assert_eq!(
        (lidar.foreign, lidar.malformed, lidar.read_errors),
        (0, 0, 0),
        "{lidar:?}"
    );
    // 1.5 s at 10 Hz, the first frame completing when the second starts.
    assert!(lidar.frames >= 12, "{lidar:?}");
    assert!(lidar.frames_used >= 10, "{lidar:?}");
}

/// A stop always stops (issue 73): SIGINT/SIGTERM's flag, set while `g1fw run --can-config` waits
/// for motors and an IMU that never answer, ends the run at once (it waited out the start-up
/// timeout), damped and reported as a stop.
#[test]
fn a_stop_while_waiting_for_the_motors_ends_the_run_at_once() {
    let mut ends = mem_buses(layout().interfaces.len(), 2).into_iter();
    let (ours, _silent) = (ends.next().unwrap(), ends.next().unwrap());
    let stop = Arc::new(AtomicBool::new(false));
    let opts = RunOptions {
        schedule: CommandSchedule::constant([0.0; 3]),
        startup_timeout: Duration::from_secs(60),
        stop: stop.clone(),
        end_damping: Duration::from_millis(100),
        ..Default::default()
    };
    let setter = std::thread::spawn(move || {
        std::thread::sleep(Duration::from_millis(300));
        stop.store(true, Ordering::Relaxed);
    });
    let start = std::time::Instant::now();
    let spec = DeploySpec::load(&peer_spec_path()).expect("peer spec");
    let report = run_on(spec, layout(), ours, &opts).expect("a stopped run still reports");
    setter.join().unwrap();
    assert!(start.elapsed() < Duration::from_secs(3), "took {:?}", start.elapsed());
    assert_eq!(report.end, "stopped by signal", "{report:?}");
    assert!(report.normal_end && report.trip.is_none(), "{report:?}");
}
