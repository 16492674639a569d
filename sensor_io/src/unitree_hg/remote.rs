//! The wireless remote in every `rt/lowstate`: 40 bytes, laid out as unitree_sdk2's
//! `xRockerBtnDataStruct` (`head[2]`, two button bytes, `lx`, `rx`, `ry`, `L2` analog, `ly` as
//! little-endian f32, 16 idle bytes). unitree_sdk2py's `utils/joystick.py` reads and writes the
//! same layout, and unitree_mujoco's bridge fills it from a gamepad.
//!
//! [`Remote::check`] says when the bytes cannot come from a working remote (a stick that is not a
//! number or beyond full deflection, opposite D-pad directions at once): such a reading must never
//! command motion.

/// Bytes of the remote in `LowState_::wireless_remote`.
pub const REMOTE_LEN: usize = 40;

/// One button's bit in [`Remote::buttons`]: byte 2 is the low byte, byte 3 the high byte.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u16)]
pub enum Button {
    R1 = 1 << 0,
    L1 = 1 << 1,
    Start = 1 << 2,
    Select = 1 << 3,
    R2 = 1 << 4,
    L2 = 1 << 5,
    F1 = 1 << 6,
    F2 = 1 << 7,
    A = 1 << 8,
    B = 1 << 9,
    X = 1 << 10,
    Y = 1 << 11,
    Up = 1 << 12,
    Right = 1 << 13,
    Down = 1 << 14,
    Left = 1 << 15,
}

impl Button {
    pub const ALL: [Button; 16] = [
        Button::R1,
        Button::L1,
        Button::Start,
        Button::Select,
        Button::R2,
        Button::L2,
        Button::F1,
        Button::F2,
        Button::A,
        Button::B,
        Button::X,
        Button::Y,
        Button::Up,
        Button::Right,
        Button::Down,
        Button::Left,
    ];

    /// The name Unitree's remote prints on the button.
    pub fn name(self) -> &'static str {
        match self {
            Button::R1 => "R1",
            Button::L1 => "L1",
            Button::Start => "start",
            Button::Select => "select",
            Button::R2 => "R2",
            Button::L2 => "L2",
            Button::F1 => "F1",
            Button::F2 => "F2",
            Button::A => "A",
            Button::B => "B",
            Button::X => "X",
            Button::Y => "Y",
            Button::Up => "up",
            Button::Right => "right",
            Button::Down => "down",
            Button::Left => "left",
        }
    }

    pub fn from_name(name: &str) -> Option<Button> {
        Button::ALL.into_iter().find(|b| b.name().eq_ignore_ascii_case(name))
    }
}

/// One reading of the remote.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Remote {
    /// Pressed buttons, a bit each ([`Button`]).
    pub buttons: u16,
    /// Left stick, right positive / up positive; right stick likewise; each in [-1, 1].
    pub lx: f32,
    pub ly: f32,
    pub rx: f32,
    pub ry: f32,
    /// The L2 trigger's analog travel, [0, 1].
    pub l2: f32,
}

/// Why a reading cannot come from a working remote.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RemoteFault {
    /// A stick or the trigger is NaN or infinite.
    NonFinite,
    /// A stick beyond full deflection (|v| > 1), or the trigger outside [0, 1].
    OutOfRange,
    /// Opposite directions of the D-pad at once, which its rocker cannot press.
    ImpossibleButtons,
}

impl RemoteFault {
    pub fn name(self) -> &'static str {
        match self {
            RemoteFault::NonFinite => "non_finite_stick",
            RemoteFault::OutOfRange => "stick_out_of_range",
            RemoteFault::ImpossibleButtons => "impossible_buttons",
        }
    }
}

/// Full deflection reads a hair over 1 on some remotes.
const STICK_SLACK: f32 = 1.0 + 1e-3;

impl Remote {
    pub fn decode(bytes: &[u8; REMOTE_LEN]) -> Remote {
        let f = |at: usize| f32::from_le_bytes([bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]]);
        Remote {
            buttons: u16::from_le_bytes([bytes[2], bytes[3]]),
            lx: f(4),
            rx: f(8),
            ry: f(12),
            l2: f(16),
            ly: f(20),
        }
    }

    pub fn encode(&self) -> [u8; REMOTE_LEN] {
        let mut b = [0u8; REMOTE_LEN];
        b[2..4].copy_from_slice(&self.buttons.to_le_bytes());
        for (at, v) in [(4, self.lx), (8, self.rx), (12, self.ry), (16, self.l2), (20, self.ly)] {
            b[at..at + 4].copy_from_slice(&v.to_le_bytes());
        }
        b
    }

    pub fn pressed(&self, b: Button) -> bool {
        self.buttons & b as u16 != 0
    }

    pub fn check(&self) -> Result<(), RemoteFault> {
        let sticks = [self.lx, self.ly, self.rx, self.ry];
        if !sticks.iter().chain([&self.l2]).all(|v| v.is_finite()) {
            return Err(RemoteFault::NonFinite);
        }
        if sticks.iter().any(|v| v.abs() > STICK_SLACK) || !(-1e-3..=STICK_SLACK).contains(&self.l2) {
            return Err(RemoteFault::OutOfRange);
        }
        let both = |a: Button, b: Button| self.pressed(a) && self.pressed(b);
        if both(Button::Up, Button::Down) || both(Button::Left, Button::Right) {
            return Err(RemoteFault::ImpossibleButtons);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_reading_round_trips_and_names_its_buttons() {
        let r = Remote {
            buttons: Button::A as u16 | Button::L2 as u16,
            lx: 0.25,
            ly: -1.0,
            rx: 0.5,
            ry: 0.0,
            l2: 1.0,
        };
        let back = Remote::decode(&r.encode());
        assert_eq!(back, r);
        assert!(back.pressed(Button::A) && back.pressed(Button::L2) && !back.pressed(Button::B));
        assert_eq!(back.check(), Ok(()));
        for b in Button::ALL {
            assert_eq!(Button::from_name(b.name()), Some(b));
        }
    }

    #[test]
    fn garbage_is_named() {
        let ok = Remote::default();
        assert_eq!(Remote { lx: f32::NAN, ..ok }.check(), Err(RemoteFault::NonFinite));
        assert_eq!(Remote { ly: 1.5, ..ok }.check(), Err(RemoteFault::OutOfRange));
        assert_eq!(Remote { l2: -0.5, ..ok }.check(), Err(RemoteFault::OutOfRange));
        let updown = Button::Up as u16 | Button::Down as u16;
        assert_eq!(
            Remote { buttons: updown, ..ok }.check(),
            Err(RemoteFault::ImpossibleButtons)
        );
    }
}
