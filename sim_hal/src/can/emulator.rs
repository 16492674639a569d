//! The motors' and the IMU's side of the bus, as logic without I/O: frames in, frames out, and
//! "step the plant now" (docs/can.md, "Motor behaviour" and "One control tick"). `g1-can-emu`
//! drives it with the MuJoCo simulator over the bridge; tests drive it in-process.
use hal::{LowCommand, LowState, MotorCommand, MOTOR_MODE_ENABLED, NUM_MOTORS};
use sensor_io::can::{decode_motor_rx, encode_imu, encode_reply, BusLayout, MitCommand, MotorRx, Special};

use super::CanFrame;

/// What a received frame means for the plant.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EmuEvent {
    Nothing,
    /// Every motor entered motor mode for the first time: IMU sample 0 went out (tick 0).
    Started,
    /// Every motor has a command since the last step: apply [`MotorEmulator::low_command`], step
    /// one control period, then [`MotorEmulator::publish`] the new state.
    Step,
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct EmuCounters {
    pub frames_rx: u64,
    pub commands: u64,
    pub specials: u64,
    /// Frames on a motor's id that no motor would accept (wrong length).
    pub malformed: u64,
    /// Frames for ids no emulated node owns (replies, other nodes, floods): ignored, like a real motor.
    pub foreign: u64,
    pub steps: u64,
    /// Commands that reached a motor at rest (ignored by it).
    pub ignored_at_rest: u64,
}

pub struct MotorEmulator {
    layout: BusLayout,
    in_mode: [bool; NUM_MOTORS],
    /// A motor without power (an injected fault) hears nothing and says nothing.
    powered: [bool; NUM_MOTORS],
    commanded: [bool; NUM_MOTORS],
    last: [MitCommand; NUM_MOTORS],
    /// False once the IMU lost power (an injected fault): no more samples, so no more ticks.
    imu_powered: bool,
    started: bool,
    seq: u16,
    counters: EmuCounters,
}

impl MotorEmulator {
    pub fn new(layout: BusLayout) -> Self {
        Self {
            layout,
            in_mode: [false; NUM_MOTORS],
            powered: [true; NUM_MOTORS],
            commanded: [false; NUM_MOTORS],
            last: [MitCommand::default(); NUM_MOTORS],
            imu_powered: true,
            started: false,
            seq: 0,
            counters: EmuCounters::default(),
        }
    }

    pub fn counters(&self) -> EmuCounters {
        self.counters
    }
    pub fn started(&self) -> bool {
        self.started
    }
    /// Cuts the power of the motor in `slot` (a fault to inject): it goes limp and silent for good,
    /// but still counts as commanded so the plant keeps stepping.
    pub fn power_off(&mut self, slot: usize) {
        self.powered[slot] = false;
        self.in_mode[slot] = false;
        self.last[slot] = MitCommand::default();
    }

    /// Cuts the IMU's power (a fault to inject): the motors still answer, but no sample closes a
    /// tick any more, so the firmware's next tick never comes.
    pub fn imu_off(&mut self) {
        self.imu_powered = false;
    }

    /// Names of the configured joints whose motor is at rest.
    pub fn resting_joints(&self) -> Vec<String> {
        self.layout
            .motors
            .iter()
            .filter(|m| !self.in_mode[m.slot])
            .map(|m| hal::G1_MOTOR_NAMES[m.slot].to_string())
            .collect()
    }

    /// Whether the motor in `slot` is in motor mode (answering, obeying commands).
    pub fn in_motor_mode(&self, slot: usize) -> bool {
        self.in_mode[slot]
    }

    fn reply(&self, i: usize, state: &LowState, send: &mut dyn FnMut(usize, CanFrame)) {
        let m = &self.layout.motors[i];
        let s = &state.motors[m.slot];
        send(m.bus, encode_reply(m.id, s.q, s.dq, s.tau_est, &m.ranges));
    }

    /// One received frame. `state` is the plant's current state (for immediate replies).
    pub fn on_frame(
        &mut self,
        bus: usize,
        f: &CanFrame,
        state: &LowState,
        send: &mut dyn FnMut(usize, CanFrame),
    ) -> EmuEvent {
        self.counters.frames_rx += 1;
        let owner = (f.id <= u8::MAX as u16)
            .then(|| self.layout.motor_index(bus, f.id as u8))
            .flatten();
        let Some(i) = owner else {
            self.counters.foreign += 1;
            return EmuEvent::Nothing;
        };
        let slot = self.layout.motors[i].slot;
        if !self.powered[slot] {
            // Still counts toward the step: the firmware did send it.
            self.commanded[slot] = true;
            return self.step_if_ready();
        }
        match decode_motor_rx(f, &self.layout.motors[i].ranges) {
            Err(_) => {
                self.counters.malformed += 1;
                EmuEvent::Nothing
            }
            Ok(MotorRx::Special(s)) => {
                self.counters.specials += 1;
                match s {
                    Special::EnterMotorMode => {
                        self.in_mode[slot] = true;
                        self.reply(i, state, send);
                        if !self.started && self.layout.motors.iter().all(|m| self.in_mode[m.slot]) {
                            self.started = true;
                            self.send_imu(state, send);
                            return EmuEvent::Started;
                        }
                    }
                    Special::ExitMotorMode => {
                        self.in_mode[slot] = false;
                        self.last[slot] = MitCommand::default();
                    }
                    Special::SetZero => {
                        if self.in_mode[slot] {
                            self.reply(i, state, send);
                        }
                    }
                }
                EmuEvent::Nothing
            }
            Ok(MotorRx::Command(c)) => {
                self.counters.commands += 1;
                if self.in_mode[slot] {
                    self.last[slot] = c;
                } else {
                    self.counters.ignored_at_rest += 1;
                }
                self.commanded[slot] = true;
                self.step_if_ready()
            }
        }
    }

    fn step_if_ready(&self) -> EmuEvent {
        if self.started && self.layout.motors.iter().all(|m| self.commanded[m.slot]) {
            EmuEvent::Step
        } else {
            EmuEvent::Nothing
        }
    }

    /// The motors' commands as the plant applies them; a motor at rest is limp.
    pub fn low_command(&self) -> LowCommand {
        let mut cmd = LowCommand::default();
        for m in &self.layout.motors {
            let s = m.slot;
            if self.in_mode[s] {
                let c = self.last[s];
                cmd.motors[s] = MotorCommand {
                    mode: MOTOR_MODE_ENABLED,
                    q: c.q,
                    dq: c.dq,
                    tau: c.tau,
                    kp: c.kp,
                    kd: c.kd,
                    reserve: 0,
                };
            }
        }
        cmd
    }

    /// After a step: every motor in motor mode answers (the highest bus first, ids ascending), then
    /// the IMU sample closes the tick.
    pub fn publish(&mut self, state: &LowState, send: &mut dyn FnMut(usize, CanFrame)) {
        self.counters.steps += 1;
        self.commanded = [false; NUM_MOTORS];
        let n = self.layout.motors.len();
        for bus in (0..self.layout.interfaces.len()).rev() {
            for i in 0..n {
                let m = &self.layout.motors[i];
                if m.bus == bus && self.in_mode[m.slot] {
                    self.reply(i, state, send);
                }
            }
        }
        if self.imu_powered {
            self.send_imu(state, send);
        }
    }

    fn send_imu(&mut self, state: &LowState, send: &mut dyn FnMut(usize, CanFrame)) {
        for f in encode_imu(&state.imu, self.seq) {
            send(self.layout.imu_bus, f);
        }
        self.seq = self.seq.wrapping_add(1);
    }
}
