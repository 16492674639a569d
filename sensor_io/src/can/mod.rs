//! Motors on CAN, the vcan bench (docs/can.md; the G1 itself is reached over DDS): MIT-style motor frames (command, reply, enter/exit motor mode, set
//! zero), the IMU's three frames, and the bus layout (`specs/can/*.toml`). Pure functions on a plain
//! [`CanFrame`]; the SocketCAN transport lives in `sim_hal::can`.
mod config;

pub use config::{BusLayout, ConfigError, MotorConfig, MotorRanges, MAX_LAYOUT_BYTES, MAX_MIT_RANGE};

use hal::ImuState;

/// Reply identifiers are `REPLY_BASE + motor id` (docs/can.md: never two nodes on one identifier).
pub const REPLY_BASE: u16 = 0x100;
/// The IMU's frames: quaternion, gyroscope, accelerometer (which closes a sample).
pub const IMU_QUAT_ID: u16 = 0x081;
pub const IMU_GYRO_ID: u16 = 0x082;
pub const IMU_ACCEL_ID: u16 = 0x083;
/// Largest motor node id (the reply range 0x101..=0x17F must stay clear of other identifiers).
pub const MAX_MOTOR_ID: u8 = 0x7F;

const QUAT_LSB: f32 = 1.0 / 32767.0;
const GYRO_LSB: f32 = 0.001;
const ACCEL_LSB: f32 = 0.005;

/// A classic CAN data frame with a standard (11-bit) identifier.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CanFrame {
    pub id: u16,
    pub len: u8,
    pub data: [u8; 8],
}

impl CanFrame {
    /// A frame with `data` (at most 8 bytes; longer input is cut at 8).
    pub fn new(id: u16, data: &[u8]) -> Self {
        let len = data.len().min(8);
        let mut d = [0u8; 8];
        d[..len].copy_from_slice(&data[..len]);
        Self {
            id: id & 0x7FF,
            len: len as u8,
            data: d,
        }
    }
    pub fn payload(&self) -> &[u8] {
        &self.data[..(self.len as usize).min(8)]
    }
}

/// `round((clamp(x) − lo) · (2^bits − 1) / (hi − lo))`; NaN maps to the low end (and never reaches
/// the bus from the firmware, whose supervisor trips first).
pub fn to_uint(x: f32, lo: f32, hi: f32, bits: u32) -> u16 {
    let max = ((1u32 << bits) - 1) as f32;
    if x.is_nan() {
        return 0;
    }
    let c = x.clamp(lo, hi);
    let v = ((c - lo) * max / (hi - lo)).round();
    v.clamp(0.0, max) as u16
}

pub fn to_float(u: u16, lo: f32, hi: f32, bits: u32) -> f32 {
    let max = ((1u32 << bits) - 1) as f32;
    lo + u as f32 * (hi - lo) / max
}

/// One motor command (the MIT layout): target position, velocity, gains and feed-forward torque.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MitCommand {
    pub q: f32,
    pub dq: f32,
    pub kp: f32,
    pub kd: f32,
    pub tau: f32,
}

/// What a motor reports back.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MitReply {
    pub id: u8,
    pub q: f32,
    pub dq: f32,
    pub tau: f32,
}

/// The special frames a motor obeys besides commands.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Special {
    EnterMotorMode,
    ExitMotorMode,
    SetZero,
}

impl Special {
    fn last_byte(self) -> u8 {
        match self {
            Special::EnterMotorMode => 0xFC,
            Special::ExitMotorMode => 0xFD,
            Special::SetZero => 0xFE,
        }
    }
}

/// What arrived on a motor's command identifier.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum MotorRx {
    Command(MitCommand),
    Special(Special),
}

/// Why a frame could not be decoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum CanDecodeError {
    #[error("CAN id {id:#05x}: expected {expected} data bytes, got {got}")]
    Length { id: u16, expected: u8, got: u8 },
    #[error("motor reply on CAN id {id:#05x} names motor {named} in byte 0")]
    WrongMotorId { id: u16, named: u8 },
    #[error("IMU gyroscope sequence {gyro} and accelerometer sequence {accel} differ")]
    ImuSequence { gyro: u16, accel: u16 },
    #[error("IMU accelerometer frame without a quaternion and gyroscope before it")]
    ImuIncomplete,
    #[error("IMU frame {id:#05x} twice in one sample (a second sender, or a lost accelerometer frame)")]
    ImuDuplicate { id: u16 },
}

pub fn encode_special(id: u8, s: Special) -> CanFrame {
    let mut d = [0xFF; 8];
    d[7] = s.last_byte();
    CanFrame::new(id as u16, &d)
}

pub fn encode_command(id: u8, c: &MitCommand, r: &MotorRanges) -> CanFrame {
    let p = to_uint(c.q, -r.p_max, r.p_max, 16);
    let v = to_uint(c.dq, -r.v_max, r.v_max, 12);
    let kp = to_uint(c.kp, 0.0, r.kp_max, 12);
    let kd = to_uint(c.kd, 0.0, r.kd_max, 12);
    let t = to_uint(c.tau, -r.t_max, r.t_max, 12);
    let d = [
        (p >> 8) as u8,
        p as u8,
        (v >> 4) as u8,
        (((v & 0xF) << 4) | (kp >> 8)) as u8,
        kp as u8,
        (kd >> 4) as u8,
        (((kd & 0xF) << 4) | (t >> 8)) as u8,
        t as u8,
    ];
    CanFrame::new(id as u16, &d)
}

/// Decodes a frame on a motor's command identifier (the motor side).
pub fn decode_motor_rx(f: &CanFrame, r: &MotorRanges) -> Result<MotorRx, CanDecodeError> {
    if f.len != 8 {
        return Err(CanDecodeError::Length {
            id: f.id,
            expected: 8,
            got: f.len,
        });
    }
    let d = &f.data;
    if d[..7] == [0xFF; 7] {
        match d[7] {
            0xFC => return Ok(MotorRx::Special(Special::EnterMotorMode)),
            0xFD => return Ok(MotorRx::Special(Special::ExitMotorMode)),
            0xFE => return Ok(MotorRx::Special(Special::SetZero)),
            _ => {}
        }
    }
    let p = (d[0] as u16) << 8 | d[1] as u16;
    let v = (d[2] as u16) << 4 | (d[3] >> 4) as u16;
    let kp = ((d[3] & 0xF) as u16) << 8 | d[4] as u16;
    let kd = (d[5] as u16) << 4 | (d[6] >> 4) as u16;
    let t = ((d[6] & 0xF) as u16) << 8 | d[7] as u16;
    Ok(MotorRx::Command(MitCommand {
        q: to_float(p, -r.p_max, r.p_max, 16),
        dq: to_float(v, -r.v_max, r.v_max, 12),
        kp: to_float(kp, 0.0, r.kp_max, 12),
        kd: to_float(kd, 0.0, r.kd_max, 12),
        tau: to_float(t, -r.t_max, r.t_max, 12),
    }))
}

pub fn encode_reply(id: u8, q: f32, dq: f32, tau: f32, r: &MotorRanges) -> CanFrame {
    let p = to_uint(q, -r.p_max, r.p_max, 16);
    let v = to_uint(dq, -r.v_max, r.v_max, 12);
    let t = to_uint(tau, -r.t_max, r.t_max, 12);
    let d = [
        id,
        (p >> 8) as u8,
        p as u8,
        (v >> 4) as u8,
        (((v & 0xF) << 4) | (t >> 8)) as u8,
        t as u8,
    ];
    CanFrame::new(REPLY_BASE + id as u16, &d)
}

/// Decodes a reply of the motor with node id `id` (the frame's identifier is `REPLY_BASE + id`).
pub fn decode_reply(f: &CanFrame, id: u8, r: &MotorRanges) -> Result<MitReply, CanDecodeError> {
    if f.len != 6 {
        return Err(CanDecodeError::Length {
            id: f.id,
            expected: 6,
            got: f.len,
        });
    }
    let d = &f.data;
    if d[0] != id {
        return Err(CanDecodeError::WrongMotorId { id: f.id, named: d[0] });
    }
    let p = (d[1] as u16) << 8 | d[2] as u16;
    let v = (d[3] as u16) << 4 | (d[4] >> 4) as u16;
    let t = ((d[4] & 0xF) as u16) << 8 | d[5] as u16;
    Ok(MitReply {
        id,
        q: to_float(p, -r.p_max, r.p_max, 16),
        dq: to_float(v, -r.v_max, r.v_max, 12),
        tau: to_float(t, -r.t_max, r.t_max, 12),
    })
}

fn i16_of(x: f32, lsb: f32) -> i16 {
    if x.is_nan() {
        return 0;
    }
    (x / lsb).round().clamp(i16::MIN as f32, i16::MAX as f32) as i16
}

fn put3(vals: [f32; 3], lsb: f32, seq: u16) -> [u8; 8] {
    let mut d = [0u8; 8];
    for (i, v) in vals.iter().enumerate() {
        d[2 * i..2 * i + 2].copy_from_slice(&i16_of(*v, lsb).to_be_bytes());
    }
    d[6..8].copy_from_slice(&seq.to_be_bytes());
    d
}

/// The IMU sample as its three frames, in sending order (the accelerometer closes the sample).
pub fn encode_imu(imu: &ImuState, seq: u16) -> [CanFrame; 3] {
    let mut q = [0u8; 8];
    for (i, v) in imu.quaternion.iter().enumerate() {
        q[2 * i..2 * i + 2].copy_from_slice(&i16_of(*v, QUAT_LSB).to_be_bytes());
    }
    [
        CanFrame::new(IMU_QUAT_ID, &q),
        CanFrame::new(IMU_GYRO_ID, &put3(imu.gyroscope, GYRO_LSB, seq)),
        CanFrame::new(IMU_ACCEL_ID, &put3(imu.accelerometer, ACCEL_LSB, seq)),
    ]
}

fn get3(d: &[u8; 8], lsb: f32) -> ([f32; 3], u16) {
    let v = |i: usize| i16::from_be_bytes([d[2 * i], d[2 * i + 1]]) as f32 * lsb;
    ([v(0), v(1), v(2)], u16::from_be_bytes([d[6], d[7]]))
}

/// Assembles IMU samples from their frames. `push` returns the sample's sequence number when an
/// accelerometer frame closes a complete sample.
#[derive(Clone, Copy, Debug, Default)]
pub struct ImuAssembler {
    quat: Option<[f32; 4]>,
    gyro: Option<([f32; 3], u16)>,
}

impl ImuAssembler {
    /// Feeds one frame with an IMU identifier; fills `out` (quaternion, gyroscope, accelerometer;
    /// roll-pitch-yaw is left to the caller) when a sample completes.
    pub fn push(&mut self, f: &CanFrame, out: &mut ImuState) -> Result<Option<u16>, CanDecodeError> {
        if f.len != 8 {
            return Err(CanDecodeError::Length {
                id: f.id,
                expected: 8,
                got: f.len,
            });
        }
        match f.id {
            // A second copy within one sample is an error; the newest is kept to resynchronise.
            IMU_QUAT_ID => {
                let v = |i: usize| i16::from_be_bytes([f.data[2 * i], f.data[2 * i + 1]]) as f32 * QUAT_LSB;
                match self.quat.replace([v(0), v(1), v(2), v(3)]) {
                    Some(_) => Err(CanDecodeError::ImuDuplicate { id: f.id }),
                    None => Ok(None),
                }
            }
            IMU_GYRO_ID => match self.gyro.replace(get3(&f.data, GYRO_LSB)) {
                Some(_) => Err(CanDecodeError::ImuDuplicate { id: f.id }),
                None => Ok(None),
            },
            _ => {
                let (accel, seq) = get3(&f.data, ACCEL_LSB);
                let (Some(quat), Some((gyro, gseq))) = (self.quat.take(), self.gyro.take()) else {
                    return Err(CanDecodeError::ImuIncomplete);
                };
                if gseq != seq {
                    return Err(CanDecodeError::ImuSequence { gyro: gseq, accel: seq });
                }
                out.quaternion = quat;
                out.gyroscope = gyro;
                out.accelerometer = accel;
                Ok(Some(seq))
            }
        }
    }
}

pub fn is_imu_id(id: u16) -> bool {
    (IMU_QUAT_ID..=IMU_ACCEL_ID).contains(&id)
}

// ---------------------------------------------------------------------------------------------
// Fuzzing entry point (the `can_frame` cargo-fuzz target and the stable `fuzz_smoke` test).

/// The ranges of `specs/can/g1_12dof.toml`'s hip motors: frames are decoded with these unless the
/// input is a bus layout.
const FUZZ_RANGES: MotorRanges = MotorRanges {
    p_max: 12.5,
    v_max: 37.5,
    t_max: 88.0,
    kp_max: 500.0,
    kd_max: 5.0,
};

/// First byte even: the rest is a stream of 11-byte frames (id u16 LE, len, 8 data bytes) decoded
/// as motor commands, motor replies and IMU frames. Odd: the rest is a bus layout (TOML); if it
/// loads, every motor's ranges round-trip a command and a reply.
#[doc(hidden)]
pub fn fuzz_can(data: &[u8]) {
    let Some((&mode, rest)) = data.split_first() else {
        return;
    };
    if mode % 2 == 1 {
        let Ok(text) = core::str::from_utf8(rest) else {
            return;
        };
        if let Ok(layout) = BusLayout::from_toml(text) {
            for (k, m) in layout.motors.iter().enumerate() {
                let c = MitCommand {
                    q: k as f32 * 0.1,
                    dq: -0.5,
                    kp: 20.0,
                    kd: 0.5,
                    tau: 1.0,
                };
                check_rx(&encode_command(m.id, &c, &m.ranges), &m.ranges);
                check_reply(&encode_reply(m.id, 0.3, -1.0, 2.0, &m.ranges), m.id, &m.ranges);
            }
        }
        return;
    }
    let mut imu = ImuAssembler::default();
    let mut out = ImuState::default();
    for chunk in rest.chunks(11).filter(|c| c.len() == 11) {
        let f = CanFrame {
            id: u16::from_le_bytes([chunk[0], chunk[1]]) & 0x7FF,
            len: chunk[2],
            data: chunk[3..11].try_into().expect("8 bytes"),
        };
        assert!(f.payload().len() <= 8);
        check_rx(&f, &FUZZ_RANGES);
        check_reply(&f, f.id.wrapping_sub(REPLY_BASE) as u8, &FUZZ_RANGES);
        if is_imu_id(f.id) {
            if let Ok(Some(_)) = imu.push(&f, &mut out) {
                let v = out.quaternion.iter().chain(&out.gyroscope).chain(&out.accelerometer);
                assert!(v.clone().all(|x| x.is_finite()));
            }
        }
    }
}

/// A frame that decodes holds values inside its ranges and encodes back to itself.
fn check_rx(f: &CanFrame, r: &MotorRanges) {
    match decode_motor_rx(f, r) {
        Ok(MotorRx::Special(s)) => assert_eq!(encode_special(f.id as u8, s).data, f.data),
        Ok(MotorRx::Command(c)) => {
            for (v, lo, hi) in [
                (c.q, -r.p_max, r.p_max),
                (c.dq, -r.v_max, r.v_max),
                (c.kp, 0.0, r.kp_max),
                (c.kd, 0.0, r.kd_max),
                (c.tau, -r.t_max, r.t_max),
            ] {
                // Quantisation rounds within a part in 10⁶ of the span.
                let slack = (hi - lo) * 1e-6;
                assert!(
                    v.is_finite() && v >= lo - slack && v <= hi + slack,
                    "{v} outside [{lo}, {hi}]"
                );
            }
            assert_eq!(encode_command(f.id as u8, &c, r).data, f.data, "{c:?}");
        }
        Err(_) => {}
    }
}

fn check_reply(f: &CanFrame, id: u8, r: &MotorRanges) {
    if let Ok(m) = decode_reply(f, id, r) {
        assert!(m.q.is_finite() && m.dq.is_finite() && m.tau.is_finite(), "{m:?}");
        let again = encode_reply(id, m.q, m.dq, m.tau, r);
        assert_eq!(again.payload(), f.payload(), "{m:?}");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const R: MotorRanges = MotorRanges {
        p_max: 12.5,
        v_max: 37.5,
        t_max: 140.0,
        kp_max: 500.0,
        kd_max: 5.0,
    };

    #[test]
    fn command_layout_matches_the_mit_packing() {
        // Hand-packed: q = +p_max → 0xFFFF, dq = -v_max → 0x000, kp = kp_max → 0xFFF,
        // kd = 0 → 0x000, tau = +t_max → 0xFFF.
        let c = MitCommand {
            q: 12.5,
            dq: -37.5,
            kp: 500.0,
            kd: 0.0,
            tau: 140.0,
        };
        let f = encode_command(3, &c, &R);
        assert_eq!(f.id, 3);
        assert_eq!(f.payload(), &[0xFF, 0xFF, 0x00, 0x0F, 0xFF, 0x00, 0x0F, 0xFF]);
        let MotorRx::Command(back) = decode_motor_rx(&f, &R).unwrap() else {
            panic!("not a command")
        };
        assert_eq!(back, c);
    }

    #[test]
    fn quantisation_error_is_half_a_step() {
        for i in 0..1000 {
            let x = -12.5 + 25.0 * i as f32 / 999.0 * 0.999;
            let back = to_float(to_uint(x, -12.5, 12.5, 16), -12.5, 12.5, 16);
            assert!((back - x).abs() <= 0.5 * 25.0 / 65535.0 + 1e-6, "{x} -> {back}");
        }
        assert_eq!(to_uint(1e9, -1.0, 1.0, 12), 4095);
        assert_eq!(to_uint(f32::NAN, -1.0, 1.0, 12), 0);
    }

    #[test]
    fn specials_and_replies_round_trip() {
        let f = encode_special(5, Special::EnterMotorMode);
        assert_eq!(f.payload(), &[0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFC]);
        assert_eq!(
            decode_motor_rx(&f, &R).unwrap(),
            MotorRx::Special(Special::EnterMotorMode)
        );
        let r = encode_reply(5, 0.3, -1.0, 20.0, &R);
        assert_eq!((r.id, r.len, r.data[0]), (0x105, 6, 5));
        let back = decode_reply(&r, 5, &R).unwrap();
        assert!((back.q - 0.3).abs() < 2e-4 && (back.dq + 1.0).abs() < 0.01 && (back.tau - 20.0).abs() < 0.04);
        assert!(matches!(
            decode_reply(&r, 6, &R),
            Err(CanDecodeError::WrongMotorId { named: 5, .. })
        ));
        let short = CanFrame::new(0x105, &[5, 0, 0]);
        assert!(matches!(
            decode_reply(&short, 5, &R),
            Err(CanDecodeError::Length { got: 3, .. })
        ));
    }

    #[test]
    fn imu_sample_round_trips_and_checks_sequences() {
        let imu = ImuState {
            quaternion: [0.9, 0.1, -0.2, 0.3],
            gyroscope: [0.5, -1.25, 3.0],
            accelerometer: [0.1, -0.2, 9.81],
            ..ImuState::default()
        };
        let frames = encode_imu(&imu, 0xBEEF);
        let mut asm = ImuAssembler::default();
        let mut out = ImuState::default();
        assert_eq!(asm.push(&frames[0], &mut out), Ok(None));
        assert_eq!(asm.push(&frames[1], &mut out), Ok(None));
        assert_eq!(asm.push(&frames[2], &mut out), Ok(Some(0xBEEF)));
        assert!((out.accelerometer[2] - 9.81).abs() <= 0.0025);
        assert!((out.gyroscope[1] + 1.25).abs() <= 0.0005);
        assert!((out.quaternion[0] - 0.9).abs() <= 1.0 / 32767.0);
        // A frame twice in one sample, an accelerometer alone, and mismatched sequences are errors.
        asm.push(&frames[1], &mut out).unwrap();
        assert_eq!(
            asm.push(&frames[1], &mut out),
            Err(CanDecodeError::ImuDuplicate { id: IMU_GYRO_ID })
        );
        asm = ImuAssembler::default();
        assert_eq!(asm.push(&frames[2], &mut out), Err(CanDecodeError::ImuIncomplete));
        let other = encode_imu(&imu, 1);
        asm.push(&frames[0], &mut out).unwrap();
        asm.push(&frames[1], &mut out).unwrap();
        assert!(matches!(
            asm.push(&other[2], &mut out),
            Err(CanDecodeError::ImuSequence { .. })
        ));
    }
}
