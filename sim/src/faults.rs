//! Fault injection for the bridge server (`g1-sim --fault SPEC`, repeatable).
//!
//! Firmware fault handling (stale frames, bad CRCs, NaN sensors, dead motors, a vanished simulator)
//! can only be tested reproducibly if the faults happen on known ticks. So faults are scheduled on
//! LowState tick indices, never on wall-clock time, and involve no randomness: the same plan, model,
//! seed and commands give the same bytes on the wire.
//!
//! # Grammar
//!
//! `KIND@START_S[+DURATION_S][:ARG]`, e.g. `drop@1.5+0.02`, `delay@2+1:5`, `freeze-joint@3:4`.
//! Times are seconds of simulated time; without a duration the fault lasts until the end. A fault
//! is active on LowState tick indices `k` (k = 0 is the initial state, k = n the state after n
//! control ticks) with `round(START / control_dt) <= k < round((START + DURATION) / control_dt)`.
//!
//! | kind | ARG | effect on tick k |
//! |---|---|---|
//! | `drop` | – | no frame: `LowState` with `FLAG_NO_FRAME` (`Truth` still follows if asked) |
//! | `delay` | N ticks, 1..=10000 | the frame of tick k − N (of tick 0 while k < N) is sent instead |
//! | `corrupt` | – | one byte in the middle of the encoded frame flipped (its CRC fails) |
//! | `imu-nan` | – | gyroscope x = NaN, re-encoded with a valid CRC (a sensor fault) |
//! | `freeze-joint` | slot | stuck encoder: reported q, dq, ddq, tau_est stay at their tick-START values and the driver's PD law uses that q / dq; physics goes on |
//! | `motor-dead` | slot | the driver gives zero torque; the slot's whole reported state stays at its tick-START value |
//! | `overheat` | slot | temperature = [90, 130] °C (casing, winding) |
//! | `disconnect` | – | the server closes the connection instead of sending tick k (no `Error` message; no duration) |
//!
//! Slots are unitree_hg motor slots (SDK order, 0..=34); a slot the model has no motor for is
//! refused. Faults compose in a fixed order per tick: disconnect; then freeze-joint / motor-dead
//! (plan order); overheat and imu-nan; encode; delay (the largest active N); corrupt; drop.
use std::fmt;

use hal::{LowState, MotorState, NUM_MOTORS};
use sensor_io::unitree_hg::{encode_low_state, LOW_STATE_LEN};

use crate::{MotorFault, Simulator};

/// Every kind `--fault` accepts, for error messages.
pub const KNOWN_KINDS: &str = "drop, delay, corrupt, imu-nan, freeze-joint, motor-dead, overheat, disconnect";

/// Longest `delay` accepted: the server keeps N + 1 frames (2 KiB each) in memory.
pub const MAX_DELAY_TICKS: u32 = 10_000;

/// Casing and winding temperatures (°C) an `overheat` fault reports, in unitree_hg order.
pub const OVERHEAT_TEMPERATURE: [i16; 2] = [90, 130];

/// What a fault does (see the module doc).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FaultKind {
    Drop,
    Delay { ticks: u32 },
    Corrupt,
    ImuNan,
    FreezeJoint { slot: usize },
    MotorDead { slot: usize },
    Overheat { slot: usize },
    Disconnect,
}

impl FaultKind {
    fn slot(&self) -> Option<usize> {
        match *self {
            FaultKind::FreezeJoint { slot } | FaultKind::MotorDead { slot } | FaultKind::Overheat { slot } => {
                Some(slot)
            }
            _ => None,
        }
    }
}

/// A `--fault` spec that does not parse or does not fit the model; the message names the spec.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("--fault '{spec}': {reason}")]
pub struct FaultError {
    pub spec: String,
    pub reason: String,
}

/// One parsed `--fault` spec, times still in seconds.
#[derive(Clone, Debug, PartialEq)]
pub struct FaultSpec {
    pub kind: FaultKind,
    pub start_s: f64,
    /// `None`: until the end of the run.
    pub duration_s: Option<f64>,
    /// The spec as given, for messages.
    pub text: String,
}

impl FaultSpec {
    /// Parses `KIND@START_S[+DURATION_S][:ARG]`.
    pub fn parse(text: &str) -> Result<Self, FaultError> {
        let err = |reason: String| FaultError {
            spec: text.to_owned(),
            reason,
        };
        let (kind, rest) = text
            .split_once('@')
            .ok_or_else(|| err("expected KIND@START_S[+DURATION_S][:ARG], e.g. drop@1.5+0.02".into()))?;
        let (times, arg) = match rest.split_once(':') {
            Some((t, a)) => (t, Some(a)),
            None => (rest, None),
        };
        // A '+' right after an exponent marker belongs to the number (1e+2), not to a duration.
        let plus = times
            .char_indices()
            .find(|&(i, c)| c == '+' && i > 0 && !matches!(times.as_bytes()[i - 1], b'e' | b'E'))
            .map(|(i, _)| i);
        let (start, duration) = match plus {
            Some(i) => (&times[..i], Some(&times[i + 1..])),
            None => (times, None),
        };
        let seconds = |what: &str, v: &str| -> Result<f64, FaultError> {
            v.trim()
                .parse::<f64>()
                .ok()
                .filter(|s| s.is_finite())
                .ok_or_else(|| err(format!("{what} {v:?} is not a number of seconds")))
        };
        let start_s = seconds("start", start)?;
        if start_s < 0.0 {
            return Err(err(format!("start {start_s} s is before the run starts (>= 0)")));
        }
        let duration_s = duration.map(|d| seconds("duration", d)).transpose()?;
        if let Some(d) = duration_s {
            if d <= 0.0 {
                return Err(err(format!("duration {d} s must be > 0")));
            }
        }
        let no_arg = |k: FaultKind| match arg {
            None => Ok(k),
            Some(a) => Err(err(format!("'{kind}' takes no argument, got ':{a}'"))),
        };
        let slot = || -> Result<usize, FaultError> {
            let a = arg.ok_or_else(|| err(format!("'{kind}' needs a motor slot, e.g. {kind}@{rest}:3")))?;
            match a.trim().parse::<usize>() {
                Ok(s) if s < NUM_MOTORS => Ok(s),
                _ => Err(err(format!(
                    "motor slot {a:?} is not one of the unitree_hg slots 0..={}",
                    NUM_MOTORS - 1
                ))),
            }
        };
        let kind = match kind {
            "drop" => no_arg(FaultKind::Drop)?,
            "corrupt" => no_arg(FaultKind::Corrupt)?,
            "imu-nan" => no_arg(FaultKind::ImuNan)?,
            "disconnect" => no_arg(FaultKind::Disconnect)?,
            "delay" => {
                let a = arg.ok_or_else(|| err(format!("'delay' needs a number of ticks, e.g. delay@{rest}:5")))?;
                match a.trim().parse::<u32>() {
                    Ok(n) if (1..=MAX_DELAY_TICKS).contains(&n) => FaultKind::Delay { ticks: n },
                    _ => {
                        return Err(err(format!(
                            "delay {a:?} is not a number of ticks in 1..={MAX_DELAY_TICKS}"
                        )))
                    }
                }
            }
            "freeze-joint" => FaultKind::FreezeJoint { slot: slot()? },
            "motor-dead" => FaultKind::MotorDead { slot: slot()? },
            "overheat" => FaultKind::Overheat { slot: slot()? },
            other => {
                return Err(err(format!(
                    "unknown kind '{other}'; known: {KNOWN_KINDS} (the form is KIND@START_S[+DURATION_S][:ARG], e.g. delay@1:5)"
                )))
            }
        };
        if kind == FaultKind::Disconnect && duration_s.is_some() {
            return Err(err(
                "'disconnect' takes no duration (the connection stays closed)".into()
            ));
        }
        Ok(Self {
            kind,
            start_s,
            duration_s,
            text: text.to_owned(),
        })
    }
}

/// All `--fault` specs of a run. Empty (the default) means no fault injection at all.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FaultPlan {
    pub faults: Vec<FaultSpec>,
}

impl FaultPlan {
    /// Parses every spec; the first bad one is the error.
    pub fn parse<I, S>(specs: I) -> Result<Self, FaultError>
    where
        I: IntoIterator<Item = S>,
        S: AsRef<str>,
    {
        let faults = specs
            .into_iter()
            .map(|s| FaultSpec::parse(s.as_ref()))
            .collect::<Result<_, _>>()?;
        Ok(Self { faults })
    }

    pub fn is_empty(&self) -> bool {
        self.faults.is_empty()
    }

    /// Turns times into LowState tick windows for `control_dt` and checks the slots against the
    /// model (`present`: bit i set = slot i has a motor). Same order as the plan.
    pub fn schedule(&self, control_dt: f64, present: u64) -> Result<Vec<ScheduledFault>, FaultError> {
        self.faults.iter().map(|f| f.schedule(control_dt, present)).collect()
    }
}

impl FaultSpec {
    fn schedule(&self, control_dt: f64, present: u64) -> Result<ScheduledFault, FaultError> {
        let err = |reason: String| FaultError {
            spec: self.text.clone(),
            reason,
        };
        if let Some(slot) = self.kind.slot() {
            if present & (1u64 << slot) == 0 {
                return Err(err(format!("the model has no motor in slot {slot}")));
            }
        }
        // `as u64` saturates, so an absurd time gives a window that never comes, not a panic.
        let tick = |s: f64| (s / control_dt).round() as u64;
        let start_tick = tick(self.start_s);
        let end_tick = self.duration_s.map(|d| tick(self.start_s + d));
        if end_tick.is_some_and(|e| e <= start_tick) {
            return Err(err(format!(
                "covers no control tick (the duration is under half a tick of {control_dt} s)"
            )));
        }
        Ok(ScheduledFault {
            kind: self.kind,
            start_tick,
            end_tick,
        })
    }
}

/// A fault with its window of LowState tick indices.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ScheduledFault {
    pub kind: FaultKind,
    pub start_tick: u64,
    /// Exclusive; `None`: until the end.
    pub end_tick: Option<u64>,
}

impl ScheduledFault {
    pub fn active(&self, k: u64) -> bool {
        k >= self.start_tick && self.end_tick.is_none_or(|e| k < e)
    }
}

impl fmt::Display for ScheduledFault {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.kind {
            FaultKind::Drop => write!(f, "drop")?,
            FaultKind::Delay { ticks } => write!(f, "delay by {ticks} tick(s)")?,
            FaultKind::Corrupt => write!(f, "corrupt")?,
            FaultKind::ImuNan => write!(f, "imu-nan")?,
            FaultKind::FreezeJoint { slot } => write!(f, "freeze-joint slot {slot}")?,
            FaultKind::MotorDead { slot } => write!(f, "motor-dead slot {slot}")?,
            FaultKind::Overheat { slot } => write!(f, "overheat slot {slot}")?,
            FaultKind::Disconnect => return write!(f, "disconnect at LowState tick {}", self.start_tick),
        }
        match self.end_tick {
            Some(e) => write!(f, " on LowState ticks {}..{e}", self.start_tick),
            None => write!(f, " from LowState tick {} on", self.start_tick),
        }
    }
}

/// What goes on the wire for one tick.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Wire {
    /// The (possibly faulty) frame now in the caller's buffer.
    Frame,
    /// `LowState` with `FLAG_NO_FRAME`.
    NoFrame,
    /// Close the connection instead.
    Disconnect,
}

struct Active {
    f: ScheduledFault,
    /// Reported motor state at the fault's first tick (freeze-joint, motor-dead).
    frozen: Option<MotorState>,
}

/// Applies a plan tick by tick. Built once per run; nothing allocates per tick.
pub struct FaultInjector {
    faults: Vec<Active>,
    /// Slots some motor fault touches; their driver state is recomputed every tick.
    motor_slots: u64,
    /// Frame of tick k at `ring[k % ring.len()]`; empty without a `delay` fault.
    ring: Vec<[u8; LOW_STATE_LEN]>,
}

impl FaultInjector {
    /// `None` for an empty plan, so the fault-free path costs one `Option` check per tick.
    pub fn new(plan: &FaultPlan, control_dt: f64, present: u64) -> Result<Option<Self>, FaultError> {
        if plan.is_empty() {
            return Ok(None);
        }
        let scheduled = plan.schedule(control_dt, present)?;
        let mut motor_slots = 0u64;
        let mut max_delay = 0u32;
        for f in &scheduled {
            match f.kind {
                FaultKind::FreezeJoint { slot } | FaultKind::MotorDead { slot } => motor_slots |= 1 << slot,
                FaultKind::Delay { ticks } => max_delay = max_delay.max(ticks),
                _ => {}
            }
        }
        let ring_len = if max_delay > 0 { max_delay as usize + 1 } else { 0 };
        Ok(Some(Self {
            faults: scheduled.into_iter().map(|f| Active { f, frozen: None }).collect(),
            motor_slots,
            ring: vec![[0; LOW_STATE_LEN]; ring_len],
        }))
    }

    /// Tick `k`: `state` is the simulator's true state of that tick. Applies the sensor faults to
    /// `state`, sets the simulator's motor-driver faults for the physics of the next tick, and
    /// leaves in `bytes` the frame to send (when the answer is [`Wire::Frame`]).
    pub fn apply(
        &mut self,
        k: u64,
        sim: &mut Simulator,
        state: &mut LowState,
        bytes: &mut [u8; LOW_STATE_LEN],
    ) -> Wire {
        let on = |f: &ScheduledFault| f.active(k);
        if self
            .faults
            .iter()
            .any(|a| a.f.kind == FaultKind::Disconnect && on(&a.f))
        {
            return Wire::Disconnect;
        }
        let mut driver = [MotorFault::Healthy; NUM_MOTORS];
        // Motor faults first: a frozen state is what the motor reports, and later sensor faults
        // (overheat) act on top of it.
        for a in self.faults.iter_mut().filter(|a| on(&a.f)) {
            let (slot, dead) = match a.f.kind {
                FaultKind::FreezeJoint { slot } => (slot, false),
                FaultKind::MotorDead { slot } => (slot, true),
                _ => continue,
            };
            let frozen = *a.frozen.get_or_insert(state.motors[slot]);
            let m = &mut state.motors[slot];
            if dead {
                *m = frozen;
                driver[slot] = MotorFault::Dead;
            } else {
                (m.q, m.dq, m.ddq, m.tau_est) = (frozen.q, frozen.dq, frozen.ddq, frozen.tau_est);
                if driver[slot] != MotorFault::Dead {
                    driver[slot] = MotorFault::StuckEncoder {
                        q: frozen.q as f64,
                        dq: frozen.dq as f64,
                    };
                }
            }
        }
        if self.motor_slots != 0 {
            for (slot, d) in driver.iter().enumerate() {
                if self.motor_slots & (1 << slot) != 0 && sim.motor_fault(slot) != *d {
                    sim.set_motor_fault(slot, *d);
                }
            }
        }
        let (mut delay, mut corrupt, mut drop) = (0u32, false, false);
        for a in self.faults.iter().filter(|a| on(&a.f)) {
            match a.f.kind {
                FaultKind::Overheat { slot } => state.motors[slot].temperature = OVERHEAT_TEMPERATURE,
                FaultKind::ImuNan => state.imu.gyroscope[0] = f32::NAN,
                FaultKind::Delay { ticks } => delay = delay.max(ticks),
                FaultKind::Corrupt => corrupt = true,
                FaultKind::Drop => drop = true,
                _ => {}
            }
        }
        encode_low_state(state, bytes);
        if !self.ring.is_empty() {
            let n = self.ring.len() as u64;
            self.ring[(k % n) as usize] = *bytes;
            if delay > 0 {
                // While k < N the oldest frame there is, tick 0's, stands in for the missing ones.
                *bytes = self.ring[(k.saturating_sub(delay as u64) % n) as usize];
            }
        }
        if corrupt {
            bytes[LOW_STATE_LEN / 2] ^= 0xFF;
        }
        if drop {
            Wire::NoFrame
        } else {
            Wire::Frame
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(s: &str) -> Result<FaultSpec, String> {
        FaultSpec::parse(s).map_err(|e| e.to_string())
    }

    #[test]
    fn parses_every_kind() {
        let p = parse("drop@1.5+0.02").unwrap();
        assert_eq!((p.kind, p.start_s, p.duration_s), (FaultKind::Drop, 1.5, Some(0.02)));
        assert_eq!(parse("delay@2+1:5").unwrap().kind, FaultKind::Delay { ticks: 5 });
        assert_eq!(parse("corrupt@0").unwrap().duration_s, None);
        assert_eq!(parse("imu-nan@1e+0+2").unwrap().start_s, 1.0);
        assert_eq!(parse("imu-nan@1e+0+2").unwrap().duration_s, Some(2.0));
        assert_eq!(
            parse("freeze-joint@3:4").unwrap().kind,
            FaultKind::FreezeJoint { slot: 4 }
        );
        assert_eq!(
            parse("motor-dead@3+1:34").unwrap().kind,
            FaultKind::MotorDead { slot: 34 }
        );
        assert_eq!(parse("overheat@0.5:0").unwrap().kind, FaultKind::Overheat { slot: 0 });
        assert_eq!(parse("disconnect@1").unwrap().kind, FaultKind::Disconnect);
    }

    #[test]
    fn bad_specs_name_the_spec_and_the_problem() {
        assert_eq!(
            parse("foo@1").unwrap_err(),
            format!(
                "--fault 'foo@1': unknown kind 'foo'; known: {KNOWN_KINDS} (the form is KIND@START_S[+DURATION_S][:ARG], e.g. delay@1:5)"
            )
        );
        for (spec, why) in [
            ("drop", "expected KIND@START_S"),
            ("drop@x", "start \"x\" is not a number"),
            ("drop@-1", "before the run starts"),
            ("drop@1+0", "must be > 0"),
            ("drop@1+nan", "duration \"nan\" is not a number"),
            ("drop@1:3", "'drop' takes no argument"),
            ("delay@1", "'delay' needs a number of ticks"),
            ("delay@1:0", "not a number of ticks in 1..=10000"),
            ("delay@1:10001", "not a number of ticks"),
            ("freeze-joint@1", "needs a motor slot"),
            ("overheat@1:35", "not one of the unitree_hg slots 0..=34"),
            ("motor-dead@1:-1", "not one of the unitree_hg slots"),
            ("disconnect@1+1", "takes no duration"),
        ] {
            let e = parse(spec).unwrap_err();
            assert!(e.starts_with(&format!("--fault '{spec}': ")), "{e}");
            assert!(e.contains(why), "{spec}: {e}");
        }
    }

    #[test]
    fn schedule_rounds_to_ticks_and_checks_slots() {
        let plan = FaultPlan::parse(["drop@0.02+0.01", "overheat@0.0031:3", "disconnect@1"]).unwrap();
        let s = plan.schedule(0.002, 0xFFF).unwrap();
        assert_eq!((s[0].start_tick, s[0].end_tick), (10, Some(15)));
        assert!(!s[0].active(9) && s[0].active(10) && s[0].active(14) && !s[0].active(15));
        assert_eq!((s[1].start_tick, s[1].end_tick), (2, None));
        assert!(s[1].active(u64::MAX));
        assert_eq!(s[2].to_string(), "disconnect at LowState tick 500");
        assert_eq!(s[0].to_string(), "drop on LowState ticks 10..15");
        let e = FaultPlan::parse(["overheat@0:20"])
            .unwrap()
            .schedule(0.002, 0xFFF)
            .unwrap_err();
        assert_eq!(
            e.to_string(),
            "--fault 'overheat@0:20': the model has no motor in slot 20"
        );
        let e = FaultPlan::parse(["drop@1+0.0009"])
            .unwrap()
            .schedule(0.002, 0xFFF)
            .unwrap_err();
        assert!(e.to_string().contains("covers no control tick"), "{e}");
        assert!(FaultPlan::parse(["drop@1", "bad"]).is_err());
        assert!(FaultPlan::default().is_empty());
    }
}
