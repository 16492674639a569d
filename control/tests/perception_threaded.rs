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
use control::runtime::{run_loop, FrameSource, LateStep, LoopEnd, Runtime};
use control::spec::DeploySpec;
use hal::{LidarPoint, LowCommand, LowLevel, LowState, TickTime, TimeBase};

/// A standing robot and, on every perception tick, a lidar frame of ground with a step ahead.
struct StandingWithLidar {
    k: u64,
    /// Wall time per tick, µs (the step's ~1 ms spans more ticks the shorter they are).
    tick_us: u64,
    /// As a log replays: frames only on these ticks (the steps whose result came back), or on
    /// every perception tick (`None`).
    frames_at: Option<Vec<u64>>,
    started: bool,
    /// The last command written.
    last: LowCommand,
}

impl StandingWithLidar {
    fn new(tick_us: u64, frames_at: Option<Vec<u64>>) -> Self {
        Self {
            k: 0,
            tick_us,
            frames_at,
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
        if self.tick_us > 0 {
            std::thread::sleep(std::time::Duration::from_micros(self.tick_us));
        }
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
        if self
            .frames_at
            .as_ref()
            .is_some_and(|f| f.binary_search(&self.k).is_err())
        {
            return false;
        }
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
    /// Late steps, and perception ticks skipped while a late step still had perception, as of the
    /// last result (a step still in flight when the run ends is in no log).
    late_skipped: (u64, u64),
}

enum Mode {
    Live(PerceptionExec),
    /// Consume after, the late steps, and the ticks with a frame (`None`: every perception tick).
    Replay(u32, Vec<LateStep>, Option<Vec<u64>>),
}

fn stair_spec() -> DeploySpec {
    DeploySpec::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("../specs/stairs/g1_stairs_lstm.toml"))
        .expect("stair spec")
}

/// A live run's ticks: a few tens of µs, so a step (~1 ms) is late at 1 tick yet usually home
/// before the next perception tick.
const TICK_US: u64 = 40;

fn run(mode: Mode) -> Trace {
    run_ticks(mode, TICK_US)
}

fn run_ticks(mode: Mode, tick_us: u64) -> Trace {
    let spec = stair_spec();
    let mut rt = Runtime::new(Controller::new(spec).expect("controller"));
    let frames_at = match mode {
        Mode::Live(exec) => {
            rt.set_perception_exec(exec).unwrap();
            None
        }
        Mode::Replay(l, late, frames_at) => {
            rt.set_perception_replay(l, late);
            frames_at
        }
    };
    let mut hal = StandingWithLidar::new(tick_us, frames_at);
    let schedule = CommandSchedule::constant([0.3, 0.0, 0.0]);
    let mut op = schedule.source(2_000_000);
    let mut t = Trace {
        commands: Vec::new(),
        results: Vec::new(),
        late_skipped: (0, 0),
    };
    let end = run_loop(&mut hal, &mut rt, &mut op, 1500, |v| {
        t.commands.push(*v.command);
        if let Some(p) = v.summary.perception.filter(|p| p.fresh) {
            t.late_skipped = v.runtime.perception_late();
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
    let late = late_steps(&live);
    assert!(live.results.len() >= 10, "{} results", live.results.len());
    assert!(!late.is_empty(), "no result was late: {:?}", live.results);
    // The step ticks advance by the perception period unless a late step made a tick skip.
    for w in live.results.windows(2) {
        assert!(w[1].1 > w[0].1 && (w[1].1 - w[0].1) % 50 == 0, "{w:?}");
    }
    let replay = run(replay_of(&live, 1));
    // Late results come back on the tick they came back live, whenever the worker finished.
    assert_same(&live, &replay);
}

/// Ticks with no sleep: a step spans the next perception tick, which the live run skips (no frame
/// taken, no step). The replay skips the same ticks from the recorded returns alone.
#[test]
fn a_live_run_whose_steps_span_perception_ticks_replays_bit_exact() {
    let live = run_ticks(
        Mode::Live(PerceptionExec::Threaded {
            consume_after: 1,
            wait: false,
        }),
        0,
    );
    assert!(
        live.late_skipped.1 > 0,
        "no perception tick was skipped (late, skipped: {:?}); the steps were faster than 50 ticks",
        live.late_skipped
    );
    let replay = run_ticks(replay_of(&live, 1), 0);
    assert_same(&live, &replay);
}

/// Replay equals live: the perception results (with the tick each came back), the late and skipped
/// counts, and every command (the first differing tick named, not thousands of commands printed).
fn assert_same(live: &Trace, replay: &Trace) {
    assert_eq!(live.results, replay.results, "perception results");
    assert_eq!(live.late_skipped, replay.late_skipped, "late steps and skipped ticks");
    assert_eq!(live.commands.len(), replay.commands.len());
    if let Some(k) = (0..live.commands.len()).find(|&k| live.commands[k] != replay.commands[k]) {
        panic!("the commands differ from tick {k} on");
    }
}

/// The replay of `live` as its log gives it: the late steps with the ticks they came back, and
/// frames only where a step's result came back (`/lidar/frame` is written with it).
fn replay_of(live: &Trace, consume_after: u32) -> Mode {
    let frames: Vec<u64> = live.results.iter().map(|r| r.1).collect();
    Mode::Replay(consume_after, late_steps(live), Some(frames))
}

/// The log's late steps: their step tick and the tick they came back.
fn late_steps(t: &Trace) -> Vec<LateStep> {
    t.results
        .iter()
        .filter(|r| r.2)
        .map(|r| LateStep {
            step_tick: r.1,
            back_tick: Some(r.0),
        })
        .collect()
}

/// A late step still away at the next perception tick (a loaded machine, a slow step) makes the
/// live run skip that tick: no frame is taken and no step runs. Replay keeps perception away until
/// the recorded return, so it skips the same ticks and computes the same steps. Here one step is
/// made away for 120 ticks (past two perception ticks) by replaying it so.
#[test]
fn a_replayed_late_step_keeps_perception_away_until_it_came_back() {
    let waited = run(Mode::Live(PerceptionExec::Threaded {
        consume_after: 1,
        wait: true,
    }));
    let first = waited.results[2].1;
    let away = [LateStep {
        step_tick: first,
        back_tick: Some(first + 120),
    }];
    let replay = run(Mode::Replay(1, away.to_vec(), None));
    let ticks: Vec<(u64, u64, bool)> = replay.results.iter().map(|r| (r.0, r.1, r.2)).collect();
    // The late result comes back at its recorded tick; the two perception ticks it spans are
    // skipped, so the next step is the third period's.
    let i = ticks.iter().position(|r| r.1 == first).expect("the late step's result");
    assert_eq!(ticks[i], (first + 120, first, true), "{ticks:?}");
    assert_eq!(ticks[i + 1].1, first + 150, "{ticks:?}");
    assert_eq!(replay.late_skipped, (1, 2));
    assert!(ticks[..i].iter().all(|r| !r.2 && r.0 == r.1 + 1), "{ticks:?}");
    // Everything before the late step is the waiting run's, tick for tick.
    assert_eq!(waited.results[..i], replay.results[..i]);
    // Replaying that replay's own late steps gives it again, bit for bit.
    assert_eq!(run(replay_of(&replay, 1)), replay);
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
    let replay = run(replay_of(&waited, 3));
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
        let mut hal = StandingWithLidar::new(TICK_US, None);
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
