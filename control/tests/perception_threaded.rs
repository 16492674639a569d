//! Threaded perception is deterministic given what the log records. A live run with the worker
//! (results late or on time as thread timing has it) and a replay of its recorded late steps give
//! the same commands and the same perception results, tick for tick; a run that waits for late
//! results equals a replay with none late.
// Test inputs come from std's math on the host; this never runs on the robot.
#![allow(clippy::disallowed_methods)]
use std::path::Path;

use control::controller::Controller;
use control::operator::CommandSchedule;
use control::perception::LidarFrame;
use control::perception_worker::PerceptionExec;
use control::runtime::{run_loop, FrameSource, LoopEnd, Runtime};
use control::spec::DeploySpec;
use hal::{LidarPoint, LowCommand, LowLevel, LowState, TickTime, TimeBase};

/// A standing robot and, on every perception tick, a lidar frame of ground with a step ahead.
struct StandingWithLidar {
    k: u64,
    started: bool,
    /// The last command written.
    last: LowCommand,
}

impl StandingWithLidar {
    fn new() -> Self {
        Self {
            k: 0,
            started: false,
            last: LowCommand::default(),
        }
    }
}

impl TimeBase for StandingWithLidar {
    type Error = Never;
    fn wait_tick(&mut self) -> Result<TickTime, Self::Error> {
        if self.started {
            self.k += 1;
        }
        self.started = true;
        // A few tens of µs per tick: a step (~1 ms) is late at 1 tick, yet home again well before
        // the next perception tick, so both paths run.
        std::thread::sleep(std::time::Duration::from_micros(40));
        Ok(TickTime {
            index: self.k,
            time_ns: self.k * 2_000_000,
        })
    }
    fn period_ns(&self) -> u64 {
        2_000_000
    }
}

/// The HAL never fails.
#[derive(Debug)]
struct Never;
impl std::fmt::Display for Never {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("never")
    }
}
impl hal::Error for Never {
    fn kind(&self) -> hal::ErrorKind {
        hal::ErrorKind::Other
    }
}

impl LowLevel for StandingWithLidar {
    type Error = Never;
    fn read_state(&mut self, out: &mut LowState) -> Result<bool, Self::Error> {
        let k = self.k as f32;
        *out = LowState {
            tick: self.k as u32,
            ..Default::default()
        };
        out.imu.quaternion = [1.0, 0.0, 0.0, 0.0];
        out.imu.accelerometer = [0.0, 0.0, 9.81];
        for (i, m) in out.motors.iter_mut().enumerate() {
            m.q = (k * 0.01 + i as f32).sin() * 0.05;
            m.temperature = [40, 40];
        }
        Ok(true)
    }
    fn write_command(&mut self, cmd: &LowCommand) -> Result<(), Self::Error> {
        self.last = *cmd;
        Ok(())
    }
}

impl FrameSource for StandingWithLidar {
    fn received_frame(&self) -> Option<&[u8]> {
        None
    }
    fn read_lidar(&mut self, out: &mut LidarFrame) -> bool {
        out.clear(self.k * 2_000_000);
        let shift = (self.k / 50) as f32 * 0.01;
        for i in 0..60 {
            for j in 0..40 {
                let x = 0.4 + i as f32 * 0.04 - shift;
                let y = -0.8 + j as f32 * 0.04;
                let z = if x > 1.2 { -1.05 } else { -1.2 };
                out.push(LidarPoint {
                    xyz: [x, y, z],
                    reflectivity: 10,
                    tag: 0,
                    offset_ns: (i * 40 + j) as u32 * 1000,
                });
            }
        }
        true
    }
}

#[derive(Debug, PartialEq)]
struct Trace {
    commands: Vec<LowCommand>,
    /// (tick it came back, step tick, late, token class, h, d, yaw bits)
    results: Vec<(u64, u64, bool, u8, u32, u32, u32)>,
}

enum Mode {
    Live(PerceptionExec),
    Replay(u32, Vec<u64>),
}

fn stair_spec() -> DeploySpec {
    DeploySpec::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("../specs/stairs/g1_stairs_lstm.toml"))
        .expect("stair spec")
}

fn run(mode: Mode) -> Trace {
    let spec = stair_spec();
    let mut rt = Runtime::new(Controller::new(spec).expect("controller"));
    match mode {
        Mode::Live(exec) => rt.set_perception_exec(exec).unwrap(),
        Mode::Replay(l, late) => rt.set_perception_replay(l, late),
    }
    let mut hal = StandingWithLidar::new();
    let schedule = CommandSchedule::constant([0.3, 0.0, 0.0]);
    let mut op = schedule.source(2_000_000);
    let mut t = Trace {
        commands: Vec::new(),
        results: Vec::new(),
    };
    let end = run_loop(&mut hal, &mut rt, &mut op, 1500, |v| {
        t.commands.push(*v.command);
        if let Some(p) = v.summary.perception.filter(|p| p.fresh) {
            let z = p.token;
            t.results.push((
                v.summary.tick.index,
                p.step_tick,
                p.late,
                z.class as u8,
                z.step_height_m.to_bits(),
                z.step_depth_m.to_bits(),
                z.yaw_rad.to_bits(),
            ));
        }
        true
    });
    assert!(matches!(end, LoopEnd::Completed { .. }), "{end:?}");
    t
}

#[test]
fn a_live_threaded_run_replays_bit_exact_from_its_late_steps() {
    // One tick to finish a ~1 ms step while these ticks take microseconds: most results are late.
    let live = run(Mode::Live(PerceptionExec::Threaded {
        consume_after: 1,
        wait: false,
    }));
    let late: Vec<u64> = live.results.iter().filter(|r| r.2).map(|r| r.1).collect();
    assert!(live.results.len() >= 10, "{} results", live.results.len());
    assert!(!late.is_empty(), "no result was late: {:?}", live.results);
    // The step ticks advance by the perception period unless a late step made a tick skip.
    for w in live.results.windows(2) {
        assert!(w[1].1 > w[0].1 && (w[1].1 - w[0].1) % 50 == 0, "{w:?}");
    }
    let replay = run(Mode::Replay(1, late));
    // Results come back on the step's due tick in replay, whenever the worker finished live.
    let key = |t: &Trace| {
        t.results
            .iter()
            .map(|r| (r.1, r.2, r.3, r.4, r.5, r.6))
            .collect::<Vec<_>>()
    };
    assert_eq!(key(&live), key(&replay));
    assert_eq!(
        live.commands, replay.commands,
        "commands differ between the live run and its replay"
    );
}

#[test]
fn a_waiting_threaded_run_uses_every_result_on_its_tick() {
    let waited = run(Mode::Live(PerceptionExec::Threaded {
        consume_after: 3,
        wait: true,
    }));
    assert!(
        waited.results.iter().all(|r| !r.2 && r.0 == r.1 + 3),
        "{:?}",
        waited.results
    );
    let replay = run(Mode::Replay(3, Vec::new()));
    assert_eq!(waited, replay);
}

/// A panic on the perception worker (a bug) must not leave the policy an old token, nor a waiting
/// tick blocked forever: it reaches the control thread at the step's due tick, where the loop's
/// guard sends damping on every enabled motor.
#[test]
fn a_panic_on_the_perception_worker_damps_through_the_loop_guard() {
    for wait in [false, true] {
        let mut rt = Runtime::new(Controller::new(stair_spec()).expect("controller"));
        rt.set_perception_exec(PerceptionExec::Threaded { consume_after: 5, wait })
            .unwrap();
        rt.inject_perception_panic();
        let mut damping = LowCommand::default();
        rt.controller().damping_command(&LowState::default(), &mut damping);
        let mut hal = StandingWithLidar::new();
        let schedule = CommandSchedule::constant([0.3, 0.0, 0.0]);
        let mut op = schedule.source(2_000_000);
        // Without waiting, the panic surfaces whenever the worker thread gets to run: on a loaded
        // machine that may be many (fast, synthetic) ticks after the step was due.
        let ticks = if wait { 1500 } else { 200_000 };
        let end = run_loop(&mut hal, &mut rt, &mut op, ticks, |_| true);
        match end {
            LoopEnd::Panicked {
                tick,
                message,
                damping_sent,
            } => {
                assert!(
                    message.contains("perception worker panicked") && message.contains("injected"),
                    "{message}"
                );
                // The first perception step comes once start-up (ramp and hold) is over.
                assert!(damping_sent, "wait {wait}: no damping sent");
                if wait {
                    assert!(tick < 1000, "wait {wait}: tick {tick}");
                }
            }
            other => panic!("wait {wait}: {other:?}"),
        }
        assert_eq!(hal.last, damping, "wait {wait}: the last command is not damping");
        assert!(damping.motors.iter().any(|m| m.kd > 0.0 && m.kp == 0.0));
    }
}
