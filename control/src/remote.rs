//! The wireless remote's sticks as a velocity command, as Unitree's deploy loops read them
//! (unitree_rl_gym's `deploy_real.py`: vx from the left stick's y, vy from minus its x, wz from
//! minus the right stick's x): a dead zone, scaled to the spec's command limits, rate-limited. A
//! reading that cannot come from a working remote ([`RemoteFault`]) commands zero at once, never
//! motion, and is counted. Everything here is a function of the logged state's bytes and the tick,
//! so replay reproduces it.
use hal::{LowState, TickTime};
use sensor_io::unitree_hg::remote::{Remote, RemoteFault};

use crate::operator::{OperatorInput, OperatorSource, Request};
use crate::spec::DeploySpec;

/// How the sticks become a command.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StickMapping {
    /// Deflection below this reads as centred; above it the range is rescaled to start at 0.
    pub dead_zone: f32,
    /// Largest change of each command component per second (m/s², m/s², rad/s²).
    pub rate_per_s: [f32; 3],
}

impl Default for StickMapping {
    fn default() -> Self {
        Self {
            dead_zone: 0.1,
            rate_per_s: [1.0, 1.0, 2.0],
        }
    }
}

/// The command the sticks ask for, tick by tick.
#[derive(Clone, Debug, Default)]
pub struct StickCommand {
    mapping: StickMapping,
    /// The spec's command limits (vx, vy, wz): full deflection is the limit on its side.
    min: [f32; 3],
    max: [f32; 3],
    last: [f32; 3],
    /// Readings refused so far, and the last reason.
    pub faults: u64,
    pub last_fault: Option<RemoteFault>,
}

/// A stick value past the dead zone, rescaled so that the command starts at 0 there.
fn past_dead_zone(v: f32, dead: f32) -> f32 {
    let m = v.abs().min(1.0);
    if m <= dead {
        0.0
    } else {
        v.signum() * (m - dead) / (1.0 - dead)
    }
}

impl StickCommand {
    pub fn new(mapping: StickMapping, min: [f32; 3], max: [f32; 3]) -> Self {
        Self {
            mapping,
            min,
            max,
            ..Default::default()
        }
    }

    /// The command for this tick (`dt` seconds after the last), from the remote's reading.
    pub fn update(&mut self, remote: &Remote, dt: f32) -> [f32; 3] {
        self.update_checked(remote, remote.check(), dt)
    }

    /// [`StickCommand::update`] with the reading's [`Remote::check`] already made (once per tick).
    pub fn update_checked(&mut self, remote: &Remote, check: Result<(), RemoteFault>, dt: f32) -> [f32; 3] {
        if let Err(fault) = check {
            self.faults += 1;
            self.last_fault = Some(fault);
            self.last = [0.0; 3];
            return self.last;
        }
        let dead = self.mapping.dead_zone;
        let sticks = [remote.ly, -remote.lx, -remote.rx];
        for (i, &stick) in sticks.iter().enumerate() {
            let s = past_dead_zone(stick, dead);
            let want = if s >= 0.0 {
                s * self.max[i].max(0.0)
            } else {
                -s * self.min[i].min(0.0)
            };
            let step = self.mapping.rate_per_s[i] * dt;
            self.last[i] += (want - self.last[i]).clamp(-step, step);
        }
        self.last
    }
}

/// The operator's remote as the run's operator: the buttons' combinations (the spec's
/// `[operator]`) become requests on the tick they are completed (a combination held is one request),
/// the sticks the velocity command. A reading with a fault requests nothing and commands zero.
pub struct RemoteOperator {
    combos: [(Request, u16); 4],
    sticks: StickCommand,
    dt: f32,
    held: u16,
}

impl RemoteOperator {
    pub fn new(spec: &DeploySpec) -> Result<Self, String> {
        let o = &spec.operator;
        let limit = |v: Option<[f32; 3]>, d: f32| v.unwrap_or([d; 3]);
        Ok(Self {
            combos: o.combos()?,
            sticks: StickCommand::new(
                StickMapping {
                    dead_zone: o.dead_zone,
                    rate_per_s: o.rate_per_s,
                },
                limit(spec.commands.min, 0.0),
                limit(spec.commands.max, 0.0),
            ),
            dt: spec.control_dt() as f32,
            held: 0,
        })
    }

    /// Readings refused so far, and the last reason.
    pub fn faults(&self) -> (u64, Option<RemoteFault>) {
        (self.sticks.faults, self.sticks.last_fault)
    }

    /// This tick's input from the remote's bytes.
    pub fn input(&mut self, bytes: &[u8; sensor_io::unitree_hg::remote::REMOTE_LEN]) -> OperatorInput {
        let remote = Remote::decode(bytes);
        let check = remote.check();
        let velocity = self.sticks.update_checked(&remote, check, self.dt);
        let ok = check.is_ok();
        let pressed = if ok { remote.buttons } else { 0 };
        // The first combination (in the spec's order, passive first) completed this tick.
        let request = self
            .combos
            .iter()
            .find(|(_, m)| pressed & m == *m && self.held & m != *m)
            .map(|(r, _)| *r);
        self.held = pressed;
        OperatorInput {
            velocity,
            request,
            ..Default::default()
        }
    }
}

impl OperatorSource for RemoteOperator {
    fn at(&mut self, _tick: TickTime) -> OperatorInput {
        // Without a state there is no reading: nothing pressed, sticks centred.
        self.input(&[0; sensor_io::unitree_hg::remote::REMOTE_LEN])
    }

    fn at_state(&mut self, _tick: TickTime, state: &LowState) -> OperatorInput {
        self.input(&state.wireless_remote)
    }
}

/// A run's operator: the command schedule (scripted runs, tests), the robot's remote, or a
/// terminal's keyboard.
pub enum RunOperator<'a> {
    Schedule(crate::operator::ScheduleSource<'a>),
    Remote(RemoteOperator),
    Keyboard(crate::keyboard::KeyboardOperator),
}

impl RunOperator<'_> {
    /// Where this operator's requests come from, as the report names it.
    pub fn name(&self) -> &'static str {
        match self {
            RunOperator::Schedule(_) => "schedule",
            RunOperator::Remote(_) => "remote",
            RunOperator::Keyboard(_) => "keyboard",
        }
    }
}

impl OperatorSource for RunOperator<'_> {
    fn at(&mut self, tick: TickTime) -> OperatorInput {
        match self {
            RunOperator::Schedule(s) => s.at(tick),
            RunOperator::Remote(r) => r.at(tick),
            RunOperator::Keyboard(k) => k.at(tick),
        }
    }

    fn at_state(&mut self, tick: TickTime, state: &LowState) -> OperatorInput {
        match self {
            RunOperator::Schedule(s) => s.at_state(tick, state),
            RunOperator::Remote(r) => r.at_state(tick, state),
            RunOperator::Keyboard(k) => k.at_state(tick, state),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use sensor_io::unitree_hg::remote::Button;

    fn limits() -> StickCommand {
        StickCommand::new(StickMapping::default(), [-0.5, -0.3, -1.0], [0.8, 0.3, 1.0])
    }

    #[test]
    fn full_forward_ramps_to_the_spec_limit_and_centred_is_zero() {
        let mut c = limits();
        let fwd = Remote {
            ly: 1.0,
            ..Default::default()
        };
        let first = c.update(&fwd, 0.002);
        assert!((first[0] - 0.002).abs() < 1e-6, "rate-limited: {first:?}");
        let mut v = first;
        for _ in 0..1000 {
            v = c.update(&fwd, 0.002);
        }
        assert_eq!(v, [0.8, 0.0, 0.0]);
        // Left stick left → +vy, right stick left → +wz (counter-clockwise), back → the min.
        let mut c = limits();
        let r = Remote {
            lx: -1.0,
            rx: -1.0,
            ly: -1.0,
            ..Default::default()
        };
        for _ in 0..2000 {
            v = c.update(&r, 0.002);
        }
        assert_eq!(v, [-0.5, 0.3, 1.0]);
        // Inside the dead zone: nothing.
        let mut c = limits();
        let drift = Remote {
            lx: 0.05,
            ly: -0.09,
            rx: 0.1,
            ..Default::default()
        };
        for _ in 0..100 {
            v = c.update(&drift, 0.002);
        }
        assert_eq!(v, [0.0; 3]);
    }

    #[test]
    fn garbage_commands_zero_at_once_and_is_counted() {
        let mut c = limits();
        let fwd = Remote {
            ly: 1.0,
            ..Default::default()
        };
        for _ in 0..500 {
            c.update(&fwd, 0.002);
        }
        for (bad, fault) in [
            (Remote { ly: f32::NAN, ..fwd }, RemoteFault::NonFinite),
            (Remote { ly: 3.0, ..fwd }, RemoteFault::OutOfRange),
            (
                Remote {
                    buttons: Button::Left as u16 | Button::Right as u16,
                    ..fwd
                },
                RemoteFault::ImpossibleButtons,
            ),
        ] {
            assert_eq!(c.update(&bad, 0.002), [0.0; 3]);
            assert_eq!(c.last_fault, Some(fault));
        }
        assert_eq!(c.faults, 3);
        // Random bytes never command more than a good reading's ramp allows from zero.
        let mut x = 0x9e37_79b9_7f4a_7c15u64;
        for _ in 0..10_000 {
            let mut bytes = [0u8; 40];
            for b in bytes.iter_mut() {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                *b = x as u8;
            }
            let mut c = limits();
            let v = c.update(&Remote::decode(&bytes), 0.002);
            assert!(v.iter().all(|x| x.is_finite() && x.abs() <= 0.004 + 1e-6), "{v:?}");
        }
    }
}
