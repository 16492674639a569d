//! An operated run's state machine through the runtime: passive at start, the operator's requests
//! (stand up, walk, stand, sit down, passive) move it, nothing else does, a trip latches damping
//! until the operator acknowledges it, and requests that make no sense in a state are ignored.
// Test inputs come from std's math on the host; this never runs on the robot.
#![allow(clippy::disallowed_methods)]
mod common;
use common::{healthy, tick};
use std::path::Path;

use control::controller::{Controller, Mode};
use control::operator::{OperatorInput, Request};
use control::runtime::Runtime;
use control::supervisor::{DampingReason, FrameStatus};
use hal::LowCommand;

fn operated() -> Runtime {
    let spec =
        control::spec::DeploySpec::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("../specs/test/rl_lab_style.toml"))
            .unwrap();
    let mut c = Controller::new(spec).unwrap();
    c.operate();
    Runtime::new(c)
}

/// Runs ticks `from..to` with healthy states, `request` on tick `from` only; returns the last
/// command and how many policy steps ran.
fn run(rt: &mut Runtime, from: u64, to: u64, request: Option<Request>, estop: bool) -> (LowCommand, u64) {
    let mut cmd = LowCommand::default();
    let mut steps = 0;
    for k in from..to {
        let op = OperatorInput {
            velocity: [0.3, 0.0, 0.0],
            request: if k == from { request } else { None },
            estop: estop && k == from,
            ..Default::default()
        };
        let (s, _) = rt.tick(tick(k), FrameStatus::Fresh, &healthy(k), op, &mut cmd, |_| {
            Ok::<(), ()>(())
        });
        steps += s.policy_step as u64;
    }
    (cmd, steps)
}

fn damped(cmd: &LowCommand) -> bool {
    cmd.motors[..12].iter().all(|m| m.kp == 0.0 && m.kd > 0.0)
}

#[test]
fn the_operator_steps_the_robot_through_its_states() {
    let mut rt = operated();
    // Passive: damped, and it stays so without a request (no start-up of its own).
    let (cmd, steps) = run(&mut rt, 0, 2000, None, false);
    assert_eq!(rt.mode(), Mode::Passive);
    assert!(damped(&cmd) && steps == 0);
    // A request that makes no sense here is ignored.
    run(&mut rt, 2000, 2001, Some(Request::Walk), false);
    assert_eq!(rt.mode(), Mode::Passive);
    // Stand up: the ramp, then standing, never walking on its own.
    let (cmd, steps) = run(&mut rt, 2001, 5000, Some(Request::StandUp), false);
    assert_eq!(rt.mode(), Mode::Stand);
    assert!(!damped(&cmd) && steps == 0);
    let default_q = rt.controller().spec().motor_table().default_q;
    assert!(cmd.motors[..12].iter().zip(&default_q).all(|(m, q)| m.q == *q));
    // Walk: the policy runs, one step per policy period from one period after the request.
    let (_, steps) = run(&mut rt, 5000, 5500, Some(Request::Walk), false);
    assert_eq!(rt.mode(), Mode::Policy);
    assert_eq!(
        steps, 49,
        "policy steps in 500 ticks at decimation 10, the first one period in"
    );
    // Stand: back to the ramp and standing.
    let (_, steps) = run(&mut rt, 5500, 8000, Some(Request::Stand), false);
    assert_eq!((rt.mode(), steps), (Mode::Stand, 0));
    // Sit down: the ramp to the pose it stood up from, then passive.
    let (cmd, _) = run(&mut rt, 8000, 8001, Some(Request::SitDown), false);
    assert_eq!(rt.mode(), Mode::SitDown);
    assert!(!damped(&cmd));
    let (cmd, _) = run(&mut rt, 8001, 10_000, None, false);
    assert_eq!(rt.mode(), Mode::Passive);
    assert!(damped(&cmd));
}

#[test]
fn a_trip_latches_until_the_operator_acknowledges_it() {
    let mut rt = operated();
    run(&mut rt, 0, 10, Some(Request::StandUp), false);
    run(&mut rt, 10, 3000, None, false);
    assert_eq!(rt.mode(), Mode::Stand);
    run(&mut rt, 3000, 3500, Some(Request::Walk), false);
    let (cmd, _) = run(&mut rt, 3500, 3600, None, true);
    assert_eq!(rt.mode(), Mode::Damping(DampingReason::EStop));
    assert!(damped(&cmd));
    // Standing up or walking from a latched trip is refused.
    for r in [Request::StandUp, Request::Walk, Request::Stand, Request::SitDown] {
        run(&mut rt, 3600, 3601, Some(r), false);
        assert_eq!(rt.mode(), Mode::Damping(DampingReason::EStop), "{r:?}");
    }
    // Acknowledged: passive, then a fresh stand-up.
    run(&mut rt, 3601, 3602, Some(Request::Passive), false);
    assert_eq!(rt.mode(), Mode::Passive);
    run(&mut rt, 3602, 6000, Some(Request::StandUp), false);
    assert_eq!(rt.mode(), Mode::Stand);
    // Passive from anywhere.
    run(&mut rt, 6000, 6001, Some(Request::Passive), false);
    assert_eq!(rt.mode(), Mode::Passive);
}

/// The remote drives the same machine: combinations (the spec's defaults, unitree_rl_lab's) request
/// once per press, the left stick walks it, and garbage bytes neither move nor command motion.
#[test]
fn the_remote_drives_the_state_machine_and_garbage_never_moves_it() {
    use control::operator::OperatorSource;
    use control::remote::RemoteOperator;
    use sensor_io::unitree_hg::remote::{Button, Remote};
    let mut rt = operated();
    let mut remote = RemoteOperator::new(rt.controller().spec()).unwrap();
    let press = |buttons: &[Button], ly: f32| {
        Remote {
            buttons: buttons.iter().fold(0, |m, b| m | *b as u16),
            ly,
            ..Default::default()
        }
        .encode()
    };
    let mut cmd = LowCommand::default();
    let mut k = 0u64;
    let mut drive =
        |rt: &mut Runtime, remote: &mut RemoteOperator, bytes: [u8; 40], n: u64| -> control::runtime::TickSummary {
            let mut last = None;
            for _ in 0..n {
                let mut st = healthy(k);
                st.wireless_remote = bytes;
                let op = remote.at_state(tick(k), &st);
                let (s, _) = rt.tick(tick(k), FrameStatus::Fresh, &st, op, &mut cmd, |_| Ok::<(), ()>(()));
                last = Some(s);
                k += 1;
            }
            last.unwrap()
        };
    drive(&mut rt, &mut remote, press(&[], 0.0), 100);
    assert_eq!(rt.mode(), Mode::Passive);
    // L2+up held for a second: one stand-up, then standing.
    drive(&mut rt, &mut remote, press(&[Button::L2, Button::Up], 0.0), 500);
    drive(&mut rt, &mut remote, press(&[], 0.0), 100);
    assert_eq!(rt.mode(), Mode::Stand);
    // R1+X: walk; the left stick forward ramps the command to the spec's limit.
    drive(&mut rt, &mut remote, press(&[Button::R1, Button::X], 0.0), 10);
    assert_eq!(rt.mode(), Mode::Policy);
    let s = drive(&mut rt, &mut remote, press(&[], 1.0), 1000);
    let vmax = rt.controller().spec().commands.max.map_or(0.0, |m| m[0]);
    assert!(
        vmax > 0.0 && (s.operator.velocity[0] - vmax).abs() < 1e-6,
        "{:?}",
        s.operator.velocity
    );
    // Garbage while walking: zero at once, no transition.
    let mut nan = press(&[], 1.0);
    nan[20..24].copy_from_slice(&f32::NAN.to_le_bytes());
    let s = drive(&mut rt, &mut remote, nan, 1);
    assert_eq!((s.operator.velocity, s.operator.request), ([0.0; 3], None));
    assert_eq!(rt.mode(), Mode::Policy);
    assert_eq!(remote.faults().0, 1);
    // L2+B: passive from walking.
    drive(&mut rt, &mut remote, press(&[Button::L2, Button::B], 0.0), 10);
    assert_eq!(rt.mode(), Mode::Passive);
    // Random bytes from passive: never a command other than damping, never a stand-up by chance
    // unless the bytes are a well-formed L2+up press.
    let mut x = 0x2545_f491_4f6c_dd1du64;
    for _ in 0..2000 {
        let mut b = [0u8; 40];
        for v in b.iter_mut() {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            *v = x as u8;
        }
        let r = Remote::decode(&b);
        let s = drive(&mut rt, &mut remote, b, 1);
        if r.check().is_err() {
            assert_eq!(s.operator.velocity, [0.0; 3]);
            assert_eq!(s.operator.request, None);
        }
        if rt.mode() != Mode::Passive {
            // Only a valid reading may have asked; bring it back and go on.
            assert!(r.check().is_ok(), "garbage moved the robot: {r:?}");
            drive(&mut rt, &mut remote, press(&[Button::L2, Button::B], 0.0), 2);
            drive(&mut rt, &mut remote, press(&[], 0.0), 1);
        }
    }
}

#[test]
fn a_remote_mapping_with_unknown_or_shared_buttons_is_refused() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../specs/test/rl_lab_style.toml");
    let e = control::spec::DeploySpec::load_with_overrides(&path, &["operator.walk=\"R1+Q\"".into()]).unwrap_err();
    assert!(e.to_string().contains("'Q' is not a button"), "{e}");
    let e = control::spec::DeploySpec::load_with_overrides(&path, &["operator.walk=\"B+L2\"".into()]).unwrap_err();
    assert!(e.to_string().contains("walk and passive are the same buttons"), "{e}");
    let ok = control::spec::DeploySpec::load_with_overrides(&path, &["operator.walk=\"start\"".into()]).unwrap();
    assert_eq!(ok.operator.walk, "start");
}

/// Passive is damping by the operator's choice: a robot that falls over, lies still on the floor or
/// is swung by hand there latches nothing, while a sensor fault still does; once it stands up, the
/// motion checks are back.
#[test]
fn a_passive_robot_on_the_floor_trips_nothing_but_a_bad_sensor_still_latches() {
    let mut rt = operated();
    let mut cmd = LowCommand::default();
    // Lying on its side (90° roll), spinning, joints fast, then perfectly still (frozen-looking).
    let lying = |k: u64, still: bool| {
        let mut s = healthy(k);
        let h = std::f32::consts::FRAC_1_SQRT_2;
        s.imu.quaternion = [h, h, 0.0, 0.0];
        s.imu.gyroscope = if still { [0.0; 3] } else { [9.0, 0.0, 0.0] };
        for m in s.motors.iter_mut() {
            if still {
                (m.q, m.dq, m.tau_est) = (0.1, 0.0, 0.0);
            } else {
                m.dq = 40.0;
            }
        }
        s
    };
    for k in 0..3000 {
        let _ = rt.tick(
            tick(k),
            FrameStatus::Fresh,
            &lying(k, k >= 500),
            OperatorInput::default(),
            &mut cmd,
            |_| Ok::<(), ()>(()),
        );
        assert_eq!(rt.mode(), Mode::Passive, "tick {k}");
    }
    assert!(damped(&cmd));
    // A NaN from the IMU is a fault in any state.
    let mut bad = lying(3000, true);
    bad.imu.gyroscope[0] = f32::NAN;
    let _ = rt.tick(
        tick(3000),
        FrameStatus::Fresh,
        &bad,
        OperatorInput::default(),
        &mut cmd,
        |_| Ok::<(), ()>(()),
    );
    assert!(matches!(rt.mode(), Mode::Damping(_)), "{:?}", rt.mode());
    // Acknowledged, stood up while still lying on its side: the tilt check is back at once.
    let mut rt = operated();
    let stand_up = OperatorInput {
        request: Some(Request::StandUp),
        ..Default::default()
    };
    let _ = rt.tick(tick(0), FrameStatus::Fresh, &lying(0, true), stand_up, &mut cmd, |_| {
        Ok::<(), ()>(())
    });
    let _ = rt.tick(
        tick(1),
        FrameStatus::Fresh,
        &lying(1, true),
        OperatorInput::default(),
        &mut cmd,
        |_| Ok::<(), ()>(()),
    );
    assert_eq!(rt.mode(), Mode::Damping(DampingReason::Tilt));
}
