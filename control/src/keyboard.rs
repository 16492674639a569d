//! A terminal's keyboard as the run's operator, for runs without a gamepad (`g1fw run --operated
//! --keyboard` against `g1-sim --dds` or unitree_mujoco), with rl_sar's keys: digits step the state
//! machine, letters step the velocity command by a fixed amount. The keys arrive from a reader
//! thread over a bounded channel and are taken once per tick; what they ask for reaches the
//! controller only as the tick's [`OperatorInput`], which the log records, so replay needs no
//! keyboard.
use std::sync::mpsc::{Receiver, TryRecvError};

use hal::TickTime;

use crate::operator::{OperatorInput, OperatorSource, Request};
use crate::spec::DeploySpec;

/// Change of (vx, vy, wz) per key press (m/s, m/s, rad/s).
pub const VELOCITY_STEP: [f32; 3] = [0.1, 0.1, 0.2];

/// What a key does.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum KeyAction {
    Request(Request),
    /// Add this to the velocity command (clamped to the spec's command limits).
    Step([f32; 3]),
    /// Velocity command to zero.
    Zero,
}

/// The keys, as rl_sar has them (`0` get up, `1` the policy, `9` get down, `p` passive), with
/// `2` for standing from walking; upper case reads as lower case.
pub const KEYS: [(u8, KeyAction, &str); 12] = [
    (
        b'0',
        KeyAction::Request(Request::StandUp),
        "stand up (passive → default pose)",
    ),
    (
        b'1',
        KeyAction::Request(Request::Walk),
        "walk (the policy; from standing)",
    ),
    (
        b'2',
        KeyAction::Request(Request::Stand),
        "stand (walking → default pose, hold)",
    ),
    (b'9', KeyAction::Request(Request::SitDown), "sit down, then passive"),
    (
        b'p',
        KeyAction::Request(Request::Passive),
        "passive: damping from any state (e-stop)",
    ),
    (b'w', KeyAction::Step([VELOCITY_STEP[0], 0.0, 0.0]), "vx +0.1 m/s"),
    (b's', KeyAction::Step([-VELOCITY_STEP[0], 0.0, 0.0]), "vx -0.1 m/s"),
    (
        b'a',
        KeyAction::Step([0.0, VELOCITY_STEP[1], 0.0]),
        "vy +0.1 m/s (left)",
    ),
    (
        b'd',
        KeyAction::Step([0.0, -VELOCITY_STEP[1], 0.0]),
        "vy -0.1 m/s (right)",
    ),
    (
        b'q',
        KeyAction::Step([0.0, 0.0, VELOCITY_STEP[2]]),
        "wz +0.2 rad/s (turn left)",
    ),
    (
        b'e',
        KeyAction::Step([0.0, 0.0, -VELOCITY_STEP[2]]),
        "wz -0.2 rad/s (turn right)",
    ),
    (b' ', KeyAction::Zero, "velocity to zero"),
];

/// What `key` does, if anything.
pub fn action(key: u8) -> Option<KeyAction> {
    let key = key.to_ascii_lowercase();
    KEYS.iter().find(|(k, _, _)| *k == key).map(|(_, a, _)| *a)
}

/// The keys as a short card (what `g1fw run --keyboard` prints at start).
pub fn card() -> String {
    let mut s = String::from("keyboard operator:");
    for (k, _, what) in KEYS {
        let name = if k == b' ' {
            "space".to_string()
        } else {
            (k as char).to_string()
        };
        s.push_str(&format!("\n  {name:<5} {what}"));
    }
    s.push_str("\n  Ctrl-C  stop the run (end damping, report, log)");
    s
}

/// Requests taken in one tick beyond the first wait for the next ticks, up to this many.
const QUEUED_REQUESTS: usize = 8;

/// The keyboard as the run's operator: one request per tick at most (in key order), and the
/// velocity command the keys stepped to, reached at the spec's `[operator] rate_per_s`.
pub struct KeyboardOperator {
    keys: Receiver<u8>,
    min: [f32; 3],
    max: [f32; 3],
    rate_per_s: [f32; 3],
    dt: f32,
    /// Where the keys have stepped the command to, and the rate-limited command.
    target: [f32; 3],
    command: [f32; 3],
    queued: [Option<Request>; QUEUED_REQUESTS],
    /// Keys read in all, and those that do nothing.
    pub keys_read: u64,
    pub keys_ignored: u64,
    /// The reader thread is gone (end of input): the command went to zero.
    pub input_closed: bool,
}

impl KeyboardOperator {
    pub fn new(spec: &DeploySpec, keys: Receiver<u8>) -> Self {
        let limit = |v: Option<[f32; 3]>| v.unwrap_or([0.0; 3]);
        Self {
            keys,
            min: limit(spec.commands.min),
            max: limit(spec.commands.max),
            rate_per_s: spec.operator.rate_per_s,
            dt: spec.control_dt() as f32,
            target: [0.0; 3],
            command: [0.0; 3],
            queued: [None; QUEUED_REQUESTS],
            keys_read: 0,
            keys_ignored: 0,
            input_closed: false,
        }
    }

    /// Applies one key.
    fn press(&mut self, key: u8) {
        self.keys_read += 1;
        match action(key) {
            Some(KeyAction::Request(r)) => {
                if r == Request::Passive {
                    // The e-stop goes first, whatever waits, and stops the command.
                    self.queued = [None; QUEUED_REQUESTS];
                    self.target = [0.0; 3];
                }
                if let Some(slot) = self.queued.iter_mut().find(|q| q.is_none()) {
                    *slot = Some(r);
                }
            }
            Some(KeyAction::Step(d)) => {
                for (i, (t, step)) in self.target.iter_mut().zip(d).enumerate() {
                    // Rounded to the step's grid, so ten presses are exactly 1.0, not 0.99999994.
                    let v = ((*t + step) * 100.0).round() / 100.0;
                    *t = v.clamp(self.min[i].min(0.0), self.max[i].max(0.0));
                }
            }
            Some(KeyAction::Zero) => self.target = [0.0; 3],
            None => self.keys_ignored += 1,
        }
    }

    /// This tick's input: the keys that came since the last tick applied in order.
    pub fn input(&mut self) -> OperatorInput {
        loop {
            match self.keys.try_recv() {
                Ok(k) => self.press(k),
                Err(TryRecvError::Empty) => break,
                Err(TryRecvError::Disconnected) => {
                    // No more keys can come: nothing may keep commanding motion.
                    self.input_closed = true;
                    self.target = [0.0; 3];
                    break;
                }
            }
        }
        for i in 0..3 {
            let step = self.rate_per_s[i] * self.dt;
            self.command[i] += (self.target[i] - self.command[i]).clamp(-step, step);
        }
        let request = self.queued[0];
        self.queued.rotate_left(1);
        self.queued[QUEUED_REQUESTS - 1] = None;
        OperatorInput {
            velocity: self.command,
            request,
            ..Default::default()
        }
    }
}

impl OperatorSource for KeyboardOperator {
    fn at(&mut self, _tick: TickTime) -> OperatorInput {
        self.input()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::mpsc::sync_channel;

    fn operator() -> (std::sync::mpsc::SyncSender<u8>, KeyboardOperator) {
        let spec =
            DeploySpec::load(&std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../specs/test/rl_lab_style.toml"))
                .expect("the test spec loads");
        let (tx, rx) = sync_channel(64);
        (tx, KeyboardOperator::new(&spec, rx))
    }

    fn settle(op: &mut KeyboardOperator) -> OperatorInput {
        let mut last = op.input();
        for _ in 0..2000 {
            last = op.input();
        }
        last
    }

    #[test]
    fn keys_step_the_command_within_the_spec_limits_at_the_operators_rate() {
        let (tx, mut op) = operator();
        for k in b"wwwww" {
            tx.send(*k).unwrap();
        }
        let first = op.input();
        assert!(
            first.velocity[0] > 0.0 && first.velocity[0] < 0.01,
            "rate-limited: {first:?}"
        );
        assert_eq!(settle(&mut op).velocity, [0.5, 0.0, 0.0]);
        // Far past the limit: held at it.
        for _ in 0..40 {
            tx.send(b'W').unwrap();
        }
        let max = op.max;
        assert_eq!(settle(&mut op).velocity[0], max[0]);
        for k in b" qa" {
            tx.send(*k).unwrap();
        }
        assert_eq!(settle(&mut op).velocity, [0.0, 0.1, 0.2]);
        // A key that means nothing is counted and changes nothing.
        tx.send(b'z').unwrap();
        assert_eq!(settle(&mut op).velocity, [0.0, 0.1, 0.2]);
        assert_eq!(op.keys_ignored, 1);
    }

    #[test]
    fn requests_come_one_per_tick_in_order_and_passive_clears_what_waits() {
        let (tx, mut op) = operator();
        for k in b"01" {
            tx.send(*k).unwrap();
        }
        assert_eq!(op.input().request, Some(Request::StandUp));
        assert_eq!(op.input().request, Some(Request::Walk));
        assert_eq!(op.input().request, None);
        for k in b"www9p" {
            tx.send(*k).unwrap();
        }
        let i = op.input();
        assert_eq!(
            i.request,
            Some(Request::Passive),
            "the e-stop drops the sit-down that waited"
        );
        assert_eq!(op.input().request, None);
        assert_eq!(settle(&mut op).velocity, [0.0; 3], "and the command");
    }

    #[test]
    fn a_closed_keyboard_commands_zero() {
        let (tx, mut op) = operator();
        for k in b"www" {
            tx.send(*k).unwrap();
        }
        assert!((settle(&mut op).velocity[0] - 0.3).abs() < 1e-6);
        drop(tx);
        assert_eq!(settle(&mut op).velocity, [0.0; 3]);
        assert!(op.input_closed);
    }

    #[test]
    fn every_key_on_the_card_is_distinct_and_acts() {
        let mut seen: Vec<u8> = KEYS.iter().map(|(k, _, _)| *k).collect();
        seen.sort_unstable();
        seen.dedup();
        assert_eq!(seen.len(), KEYS.len());
        for (k, a, _) in KEYS {
            assert_eq!(action(k), Some(a));
        }
        assert!(card().contains("passive"));
        for r in Request::ALL {
            assert!(
                KEYS.iter().any(|(_, a, _)| *a == KeyAction::Request(r)),
                "{r:?} has a key"
            );
        }
    }
}
