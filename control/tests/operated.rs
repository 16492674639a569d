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
