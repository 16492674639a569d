//! Fault injection end to end: an in-process server on the 12-dof model with a fault plan, driven
//! by `BridgeHal` holding a standing command; each kind must show on exactly its planned ticks.
mod common;

use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::Duration;

use common::{have_12dof, require_deps};
use g1_sim::faults::{FaultPlan, OVERHEAT_TEMPERATURE};
use g1_sim::server::{serve_unix, ServeOptions, SessionEnd, SessionSummary};
use g1_sim::{ModelChoice, SimConfig, Simulator};
use hal::{Error as _, ErrorKind, LowLevel, LowState, MotorState, TimeBase};
use sensor_io::unitree_hg::{decode_low_state, DecodeError};
use sim_hal::bridge::{BridgeError, BridgeHal};

// Every run here uses the default 2 ms control tick = physics step, so a frame's `tick` field is k.

/// The fault window used below: ticks [FROM, TO).
const FROM: u64 = 10;
const TO: u64 = 30;
/// `FROM..TO` as a spec suffix.
const WINDOW: &str = "0.02+0.04";
/// Left knee: present on the 12-dof model and loaded while standing.
const SLOT: usize = 3;

/// What the HAL showed on one tick.
struct Obs {
    read: Result<bool, BridgeError>,
    frame_received: bool,
    state: LowState,
}

fn sock_path(tag: &str) -> PathBuf {
    std::env::temp_dir().join(format!("g1-sim-faults-{tag}-{}.sock", std::process::id()))
}

fn sim12() -> Option<Simulator> {
    require_deps();
    if !have_12dof("faults") {
        return None;
    }
    Some(Simulator::load(ModelChoice::G1_12Dof, SimConfig::default()).expect("12-dof model loads"))
}

/// Serves `sim` with `faults` in a thread and drives it for LowState ticks 0..=`last` with the
/// standing command. Stops early if `wait_tick` fails; returns the observations, that error (if
/// any) and the server's result.
fn run_with(
    tag: &str,
    mut sim: Simulator,
    faults: &[&str],
    last: u64,
) -> (Vec<Obs>, Option<BridgeError>, SessionSummary) {
    let hold = sim.hold_initial_pose_command();
    let opts = ServeOptions {
        quiet: true,
        faults: FaultPlan::parse(faults).expect("test plan parses"),
        ..ServeOptions::default()
    };
    let path = sock_path(tag);
    let p2 = path.clone();
    let server = std::thread::spawn(move || serve_unix(&p2, &mut sim, &opts, || {}));
    let mut hal = BridgeHal::connect_unix(&path, true, Duration::from_secs(20), || Ok(())).expect("connects");
    let (mut obs, mut failure) = (Vec::new(), None);
    for k in 0..=last {
        let t = match hal.wait_tick() {
            Ok(t) => t,
            Err(e) => {
                failure = Some(e);
                break;
            }
        };
        assert_eq!(t.index, k);
        let mut state = LowState::default();
        let read = hal.read_state(&mut state);
        // The logged bytes re-decode to the same verdict (what a replay HAL relies on).
        if hal.frame_received() {
            let mut replay = LowState::default();
            match (&read, decode_low_state(hal.state_bytes(), &mut replay)) {
                (Ok(true), Ok(())) => assert_eq!(replay.tick, state.tick),
                (Err(BridgeError::Decode(a)), Err(b)) => assert_eq!(*a, b),
                (a, b) => panic!("tick {k}: HAL said {a:?}, replay decode says {b:?}"),
            }
        }
        obs.push(Obs {
            read,
            frame_received: hal.frame_received(),
            state,
        });
        if k < last {
            hal.write_command(&hold).expect("command sent");
        }
    }
    if failure.is_none() {
        hal.close();
    }
    let summary = server.join().expect("server thread").expect("connection ends cleanly");
    (obs, failure, summary)
}

fn run(tag: &str, faults: &[&str], last: u64) -> Option<Vec<Obs>> {
    let (obs, failure, summary) = run_with(tag, sim12()?, faults, last);
    assert!(failure.is_none(), "{tag}: wait_tick failed: {failure:?}");
    assert_eq!(summary.end, SessionEnd::Bye);
    assert_eq!(obs.len() as u64, last + 1);
    Some(obs)
}

fn in_window(k: u64) -> bool {
    (FROM..TO).contains(&k)
}

fn fresh(o: &Obs) -> bool {
    matches!(o.read, Ok(true)) && o.frame_received
}

fn motor_bits(m: &MotorState) -> [u32; 4] {
    [m.q.to_bits(), m.dq.to_bits(), m.ddq.to_bits(), m.tau_est.to_bits()]
}

#[test]
fn no_faults_every_tick_is_fresh_and_read_once() {
    let Some(sim) = sim12() else { return };
    let hold = sim.hold_initial_pose_command();
    let path = sock_path("none");
    let p2 = path.clone();
    let mut sim = sim;
    let server = std::thread::spawn(move || serve_unix(&p2, &mut sim, &ServeOptions::default(), || {}));
    let mut hal = BridgeHal::connect_unix(&path, false, Duration::from_secs(20), || Ok(())).unwrap();
    let mut st = LowState::default();
    for k in 0..=40u64 {
        assert_eq!(hal.wait_tick().unwrap().index, k);
        assert!(matches!(hal.read_state(&mut st), Ok(true)), "tick {k}");
        assert!(hal.frame_received());
        assert_eq!(st.tick as u64, k);
        assert_eq!(hal.state_frame(), hal.state_bytes());
        // Each tick's result is handed out once.
        let mut again = LowState::default();
        assert!(matches!(hal.read_state(&mut again), Ok(false)), "tick {k}");
        assert_eq!(again.tick, st.tick);
        // None after the last tick: the server would answer into a closed socket.
        if k < 40 {
            hal.write_command(&hold).unwrap();
        }
    }
    hal.close();
    assert_eq!(server.join().unwrap().unwrap().end, SessionEnd::Bye);
}

#[test]
fn drop_sends_no_frame_and_keeps_the_last_good_state() {
    let Some(obs) = run("drop", &[&format!("drop@{WINDOW}")], TO + 5) else {
        return;
    };
    for (k, o) in obs.iter().enumerate() {
        let k = k as u64;
        if in_window(k) {
            assert!(matches!(o.read, Ok(false)) && !o.frame_received, "tick {k}");
            assert_eq!(o.state.tick as u64, FROM - 1, "tick {k}: last good state");
        } else {
            assert!(fresh(o), "tick {k}");
            assert_eq!(o.state.tick as u64, k);
        }
    }
}

#[test]
fn delay_sends_old_frames() {
    const N: u64 = 4;
    let Some(obs) = run("delay", &[&format!("delay@{WINDOW}:{N}")], TO + 5) else {
        return;
    };
    for (k, o) in obs.iter().enumerate() {
        let k = k as u64;
        assert!(fresh(o), "tick {k}: delayed frames are valid");
        let want = if in_window(k) { k - N } else { k };
        assert_eq!(o.state.tick as u64, want, "tick {k}");
    }
}

#[test]
fn corrupt_fails_the_crc_and_keeps_the_last_good_state() {
    let Some(obs) = run("corrupt", &[&format!("corrupt@{WINDOW}")], TO + 5) else {
        return;
    };
    for (k, o) in obs.iter().enumerate() {
        let k = k as u64;
        if in_window(k) {
            assert!(o.frame_received, "tick {k}");
            assert!(
                matches!(&o.read, Err(e @ BridgeError::Decode(DecodeError::Crc { .. })) if e.kind() == ErrorKind::Checksum),
                "tick {k}: {:?}",
                o.read
            );
            assert_eq!(o.state.tick as u64, FROM - 1, "tick {k}: last good state");
        } else {
            assert!(fresh(o), "tick {k}");
            assert_eq!(o.state.tick as u64, k);
        }
    }
}

#[test]
fn imu_nan_is_a_non_finite_decode_error() {
    let Some(obs) = run("nan", &[&format!("imu-nan@{WINDOW}")], TO + 5) else {
        return;
    };
    for (k, o) in obs.iter().enumerate() {
        let k = k as u64;
        if in_window(k) {
            assert!(o.frame_received, "tick {k}");
            assert!(
                matches!(
                    &o.read,
                    Err(BridgeError::Decode(DecodeError::NonFinite {
                        field: "imu_state.gyroscope",
                        index: 0,
                        ..
                    }))
                ),
                "tick {k}: {:?}",
                o.read
            );
            assert!(o.state.imu.gyroscope[0].is_finite(), "the bad frame never leaks out");
        } else {
            assert!(fresh(o), "tick {k}");
        }
    }
}

/// Checks a frozen slot: its reported state is bit-identical over the window while other joints
/// move, and it tracks the joint again afterwards.
fn assert_frozen(obs: &[Obs], whole_state: bool) {
    let frozen = obs[FROM as usize].state.motors[SLOT];
    let mut others_moved = false;
    for k in FROM..TO {
        let o = &obs[k as usize];
        assert!(fresh(o), "tick {k}");
        let m = &o.state.motors[SLOT];
        assert_eq!(motor_bits(m), motor_bits(&frozen), "tick {k}: slot {SLOT} frozen");
        if whole_state {
            assert_eq!(*m, frozen, "tick {k}");
        }
        let first = &obs[FROM as usize].state.motors;
        others_moved |= (0..12).any(|j| j != SLOT && o.state.motors[j].q != first[j].q);
    }
    assert!(others_moved, "the other joints kept moving");
    let after = &obs[TO as usize].state.motors[SLOT];
    assert_ne!(
        after.q, frozen.q,
        "slot {SLOT} reports the real joint again after the window"
    );
    assert!(obs[TO as usize..].iter().all(fresh));
}

#[test]
fn freeze_joint_holds_the_reported_state() {
    let Some(obs) = run("freeze", &[&format!("freeze-joint@{WINDOW}:{SLOT}")], TO + 5) else {
        return;
    };
    assert_frozen(&obs, false);
}

#[test]
fn motor_dead_freezes_the_slot_and_drops_its_torque() {
    let Some(obs) = run("dead", &[&format!("motor-dead@{WINDOW}:{SLOT}")], TO + 5) else {
        return;
    };
    assert_frozen(&obs, true);
}

#[test]
fn stuck_encoder_and_dead_driver_change_the_torque() {
    let Some(mut sim) = sim12() else { return };
    let hold = sim.hold_initial_pose_command();
    sim.apply_command(&hold).unwrap();
    for _ in 0..20 {
        sim.step_control_tick();
    }
    // Stuck encoder 0.2 rad short of the target: the driver pushes kp·0.2 (clamped) whatever the
    // joint does.
    let (target, (kp, _)) = (hold.motors[SLOT].q as f64, g1_sim::slots::hold_gains(SLOT));
    sim.set_motor_fault(
        SLOT,
        g1_sim::MotorFault::StuckEncoder {
            q: target - 0.2,
            dq: 0.0,
        },
    );
    let (lo, hi) = sim.effort_limit(SLOT).unwrap();
    for _ in 0..5 {
        sim.step_control_tick();
        assert_eq!(sim.applied_torque(SLOT), (kp as f64 * 0.2).clamp(lo, hi));
    }
    sim.set_motor_fault(SLOT, g1_sim::MotorFault::Dead);
    sim.step_control_tick();
    assert_eq!(sim.applied_torque(SLOT), 0.0);
    sim.set_motor_fault(SLOT, g1_sim::MotorFault::Healthy);
    sim.step_control_tick();
    assert_ne!(sim.applied_torque(SLOT), 0.0);
}

#[test]
fn overheat_reports_hot_windings() {
    let Some(obs) = run("hot", &[&format!("overheat@{WINDOW}:{SLOT}")], TO + 5) else {
        return;
    };
    for (k, o) in obs.iter().enumerate() {
        let k = k as u64;
        assert!(fresh(o), "tick {k}");
        let t = o.state.motors[SLOT].temperature;
        if in_window(k) {
            assert_eq!(t, OVERHEAT_TEMPERATURE, "tick {k}");
            assert_eq!((t[0], t[1]), (90, 130));
        } else {
            assert_eq!(t, [35, 40], "tick {k}");
        }
        assert_eq!(o.state.motors[SLOT + 1].temperature, [35, 40]);
    }
}

#[test]
fn disconnect_closes_at_its_tick() {
    let Some(sim) = sim12() else { return };
    let (obs, failure, summary) = run_with("disc", sim, &["disconnect@0.02"], TO);
    assert_eq!(obs.len() as u64, FROM, "ticks 0..{FROM} arrived");
    assert!(obs.iter().all(fresh));
    let e = failure.expect("wait_tick fails at the disconnect tick");
    assert_eq!(e.kind(), ErrorKind::Disconnected, "{e}");
    assert_eq!(summary.end, SessionEnd::FaultDisconnect);
    assert_eq!(summary.ticks, FROM);
}

#[test]
fn same_plan_same_bytes() {
    let plan = [
        "drop@0.01+0.004",
        "delay@0.02+0.01:3",
        "corrupt@0.03+0.004",
        "imu-nan@0.035+0.002",
        "freeze-joint@0.01+0.03:3",
        "motor-dead@0.02:7",
        "overheat@0:1",
    ];
    let config = SimConfig {
        seed: 7,
        imu_noise: Some(g1_sim::ImuNoise::white(0.01, 0.05)),
        ..SimConfig::default()
    };
    let trace = |tag: &str| -> Option<Vec<(bool, Vec<u8>)>> {
        require_deps();
        if !have_12dof("same_plan_same_bytes") {
            return None;
        }
        let mut sim = Simulator::load(ModelChoice::G1_12Dof, config).unwrap();
        let hold = sim.hold_initial_pose_command();
        let opts = ServeOptions {
            quiet: true,
            faults: FaultPlan::parse(plan).unwrap(),
            ..ServeOptions::default()
        };
        let path = sock_path(tag);
        let p2 = path.clone();
        let server = std::thread::spawn(move || serve_unix(&p2, &mut sim, &opts, || {}));
        let mut hal = BridgeHal::connect_unix(&path, false, Duration::from_secs(20), || Ok(())).unwrap();
        let mut out = Vec::new();
        for k in 0..=50 {
            hal.wait_tick().unwrap();
            out.push((hal.frame_received(), hal.state_frame().to_vec()));
            if k < 50 {
                hal.write_command(&hold).unwrap();
            }
        }
        hal.close();
        server.join().unwrap().unwrap();
        Some(out)
    };
    let Some(a) = trace("det-a") else { return };
    let b = trace("det-b").unwrap();
    assert!(a == b, "same plan and seed must give the same frames");
    assert!(a.iter().any(|(r, _)| !r), "the plan did drop frames");
}

fn g1_sim() -> Command {
    Command::new(env!("CARGO_BIN_EXE_g1-sim"))
}

#[test]
fn binary_prints_faults_and_exits_4_on_disconnect() {
    require_deps();
    if !have_12dof("binary_prints_faults_and_exits_4_on_disconnect") {
        return;
    }
    let path = sock_path("bin");
    let child = g1_sim()
        .args([
            "--model",
            "g1-12dof",
            "--fault",
            "drop@0.004+0.002",
            "--fault",
            "disconnect@0.01",
            "--socket",
        ])
        .arg(&path)
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut hal = BridgeHal::connect_unix(&path, false, Duration::from_secs(20), || Ok(())).unwrap();
    let mut st = LowState::default();
    let e = loop {
        match hal.wait_tick() {
            Ok(t) => {
                let fresh = hal.read_state(&mut st).unwrap();
                assert_eq!(fresh, !(2..3).contains(&t.index), "tick {}", t.index);
                // Motors off: this test only needs the lock-step to advance.
                hal.write_command(&hal::LowCommand::default()).unwrap();
            }
            Err(e) => break e,
        }
    };
    assert_eq!(e.kind(), ErrorKind::Disconnected);
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(4), "{err}");
    assert!(
        err.contains("g1-sim: fault 'drop@0.004+0.002': drop on LowState ticks 2..3"),
        "{err}"
    );
    assert!(
        err.contains("g1-sim: fault 'disconnect@0.01': disconnect at LowState tick 5"),
        "{err}"
    );
    assert!(
        err.contains("disconnect fault closed the connection after 5 ticks"),
        "{err}"
    );
    assert!(!path.exists(), "socket file removed on exit");
}

#[test]
fn binary_rejects_bad_fault_specs() {
    require_deps();
    let out = g1_sim().args(["--quiet", "--fault", "foo@1"]).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("--fault 'foo@1': unknown kind 'foo'; known: drop, delay, corrupt"),
        "{err}"
    );
    // Slot checks need the model: the default 29-dof has no slot 30.
    let out = g1_sim().args(["--quiet", "--fault", "overheat@0:30"]).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("--fault 'overheat@0:30': the model has no motor in slot 30"),
        "{err}"
    );
}
