//! unitree_hg `LowCmd_` (1004 bytes) and `LowState_` (2092 bytes): little-endian, packed with explicit
//! zero padding, CRC32 in the last word. Encoders always zero the padding (dirty padding changes the
//! CRC and makes the robot drop commands silently). Decoders check length, then CRC, then that every
//! float is finite, and report the first problem by field name.
pub mod cdr;
mod crc;
pub mod remote;

pub use crc::crc32_words;
use hal::{ImuState, LowCommand, LowState, MotorCommand, MotorState, NUM_MOTORS};

pub const LOW_CMD_LEN: usize = 1004;
pub const LOW_STATE_LEN: usize = 2092;
const MOTOR_CMD_LEN: usize = 28;
const MOTOR_STATE_LEN: usize = 56;
const LOW_CMD_MOTORS_AT: usize = 4;
const LOW_STATE_IMU_AT: usize = 16;
const LOW_STATE_MOTORS_AT: usize = 72;
const LOW_STATE_REMOTE_AT: usize = LOW_STATE_MOTORS_AT + NUM_MOTORS * MOTOR_STATE_LEN;

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DecodeError {
    #[error("{message}: frame is {got} bytes, expected {expected}")]
    Length {
        message: &'static str,
        expected: usize,
        got: usize,
    },
    #[error("{message}: CRC mismatch (frame says {stored:#010x}, contents give {computed:#010x}){}", crc_hint(*stored))]
    Crc {
        message: &'static str,
        stored: u32,
        computed: u32,
    },
    #[error("{message}: non-finite value in {field}[{index}]")]
    NonFinite {
        message: &'static str,
        field: &'static str,
        index: usize,
    },
}

/// A CRC of 0 was never computed: say who sends such frames.
fn crc_hint(stored: u32) -> &'static str {
    if stored == 0 {
        "; a CRC of 0 is one never computed: Unitree's Python simulator (unitree_mujoco's \
         simulate_python, through unitree_sdk2py) publishes LowState without one. The robot always \
         sends it, and g1fw refuses such states unless run with --unitree-mujoco (docs/robot.md, \
         \"Run in Unitree's simulator\")"
    } else {
        ""
    }
}

/// Every HAL that decodes unitree_hg frames (bridge, replay, DDS) classifies failures the same way,
/// so the safety supervisor reacts the same to the same bytes.
impl hal::Error for DecodeError {
    fn kind(&self) -> hal::ErrorKind {
        match self {
            DecodeError::Length { .. } => hal::ErrorKind::Malformed,
            DecodeError::Crc { .. } => hal::ErrorKind::Checksum,
            DecodeError::NonFinite { .. } => hal::ErrorKind::NonFinite,
        }
    }
}

struct Writer<'a> {
    buf: &'a mut [u8],
}

impl Writer<'_> {
    fn u8(&mut self, at: usize, v: u8) {
        self.buf[at] = v;
    }
    fn u32(&mut self, at: usize, v: u32) {
        self.buf[at..at + 4].copy_from_slice(&v.to_le_bytes());
    }
    fn i16(&mut self, at: usize, v: i16) {
        self.buf[at..at + 2].copy_from_slice(&v.to_le_bytes());
    }
    fn f32(&mut self, at: usize, v: f32) {
        self.buf[at..at + 4].copy_from_slice(&v.to_le_bytes());
    }
    fn f32s(&mut self, at: usize, v: &[f32]) {
        for (i, x) in v.iter().enumerate() {
            self.f32(at + 4 * i, *x);
        }
    }
}

fn rd_u32(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}
fn rd_i16(b: &[u8], at: usize) -> i16 {
    i16::from_le_bytes([b[at], b[at + 1]])
}
fn rd_f32(b: &[u8], at: usize) -> f32 {
    f32::from_bits(rd_u32(b, at))
}
fn rd_f32s<const N: usize>(b: &[u8], at: usize) -> [f32; N] {
    core::array::from_fn(|i| rd_f32(b, at + 4 * i))
}

fn seal(buf: &mut [u8]) {
    let n = buf.len();
    let crc = crc32_words(&buf[..n - 4]);
    buf[n - 4..].copy_from_slice(&crc.to_le_bytes());
}

fn check(message: &'static str, buf: &[u8], expected: usize) -> Result<(), DecodeError> {
    if buf.len() != expected {
        return Err(DecodeError::Length {
            message,
            expected,
            got: buf.len(),
        });
    }
    let stored = rd_u32(buf, expected - 4);
    let computed = crc32_words(&buf[..expected - 4]);
    if stored != computed {
        return Err(DecodeError::Crc {
            message,
            stored,
            computed,
        });
    }
    Ok(())
}

fn finite(message: &'static str, field: &'static str, values: &[f32]) -> Result<(), DecodeError> {
    match values.iter().position(|v| !v.is_finite()) {
        Some(index) => Err(DecodeError::NonFinite { message, field, index }),
        None => Ok(()),
    }
}

/// Encodes `cmd` into `out` with zeroed padding and a fresh CRC.
pub fn encode_low_cmd(cmd: &LowCommand, out: &mut [u8; LOW_CMD_LEN]) {
    encode_low_cmd_body(cmd, out);
    seal(out);
}

/// Everything [`encode_low_cmd`] writes except the CRC word (left zero). The CRC is a function of
/// these bytes, so comparing bodies compares frames (replay uses this to skip a CRC per tick).
pub fn encode_low_cmd_body(cmd: &LowCommand, out: &mut [u8; LOW_CMD_LEN]) {
    out.fill(0);
    let mut w = Writer { buf: out };
    w.u8(0, cmd.mode_pr);
    w.u8(1, cmd.mode_machine);
    for (i, m) in cmd.motors.iter().enumerate() {
        let at = LOW_CMD_MOTORS_AT + i * MOTOR_CMD_LEN;
        w.u8(at, m.mode);
        w.f32s(at + 4, &[m.q, m.dq, m.tau, m.kp, m.kd]);
        w.u32(at + 24, m.reserve);
    }
    for (i, r) in cmd.reserve.iter().enumerate() {
        w.u32(LOW_CMD_MOTORS_AT + NUM_MOTORS * MOTOR_CMD_LEN + 4 * i, *r);
    }
}

/// Decodes and validates a `LowCmd_` frame (the simulator's and the CAN emulator's side).
pub fn decode_low_cmd(buf: &[u8], out: &mut LowCommand) -> Result<(), DecodeError> {
    const M: &str = "LowCmd_";
    check(M, buf, LOW_CMD_LEN)?;
    let mut cmd = LowCommand {
        mode_pr: buf[0],
        mode_machine: buf[1],
        ..LowCommand::default()
    };
    for (i, m) in cmd.motors.iter_mut().enumerate() {
        let at = LOW_CMD_MOTORS_AT + i * MOTOR_CMD_LEN;
        let [q, dq, tau, kp, kd] = rd_f32s::<5>(buf, at + 4);
        finite(M, "motor_cmd", &[q, dq, tau, kp, kd]).map_err(|_| DecodeError::NonFinite {
            message: M,
            field: "motor_cmd",
            index: i,
        })?;
        *m = MotorCommand {
            mode: buf[at],
            q,
            dq,
            tau,
            kp,
            kd,
            reserve: rd_u32(buf, at + 24),
        };
    }
    for (i, r) in cmd.reserve.iter_mut().enumerate() {
        *r = rd_u32(buf, LOW_CMD_MOTORS_AT + NUM_MOTORS * MOTOR_CMD_LEN + 4 * i);
    }
    *out = cmd;
    Ok(())
}

/// Encodes `state` into `out` with zeroed padding and a fresh CRC (the simulator's side).
pub fn encode_low_state(state: &LowState, out: &mut [u8; LOW_STATE_LEN]) {
    out.fill(0);
    let mut w = Writer { buf: out };
    w.u32(0, state.version[0]);
    w.u32(4, state.version[1]);
    w.u8(8, state.mode_pr);
    w.u8(9, state.mode_machine);
    w.u32(12, state.tick);
    let imu = &state.imu;
    let at = LOW_STATE_IMU_AT;
    w.f32s(at, &imu.quaternion);
    w.f32s(at + 16, &imu.gyroscope);
    w.f32s(at + 28, &imu.accelerometer);
    w.f32s(at + 40, &imu.rpy);
    w.i16(at + 52, imu.temperature);
    for (i, m) in state.motors.iter().enumerate() {
        let at = LOW_STATE_MOTORS_AT + i * MOTOR_STATE_LEN;
        w.u8(at, m.mode);
        w.f32s(at + 4, &[m.q, m.dq, m.ddq, m.tau_est]);
        w.i16(at + 20, m.temperature[0]);
        w.i16(at + 22, m.temperature[1]);
        w.f32(at + 24, m.voltage);
        w.u32(at + 28, m.sensor[0]);
        w.u32(at + 32, m.sensor[1]);
        w.u32(at + 36, m.motor_state);
        for (k, r) in m.reserve.iter().enumerate() {
            w.u32(at + 40 + 4 * k, *r);
        }
    }
    w.buf[LOW_STATE_REMOTE_AT..LOW_STATE_REMOTE_AT + 40].copy_from_slice(&state.wireless_remote);
    for (i, r) in state.reserve.iter().enumerate() {
        w.u32(LOW_STATE_REMOTE_AT + 40 + 4 * i, *r);
    }
    seal(out);
}

/// unitree_mujoco's Python bridge (through unitree_sdk2py) leaves `crc` and `tick` of `LowState_` at
/// 0. For that simulator only (`g1fw run --unitree-mujoco`), frames are stamped before decoding:
/// each gets the next `tick` (freshness comes from arrival order) and is sealed with its CRC. A frame
/// whose CRC is set but wrong is left alone, so corruption is still refused. Frames whose contents
/// repeat the last one's are told apart (the bridge publishes on its own timer whether or not the
/// physics stepped, and a robot at rest in a noise-free simulator repeats its f32 state exactly).
/// Replay stamps the logged wire samples with a stamper of its own, the same way.
#[derive(Clone)]
pub struct UnsealedStamper {
    tick: u32,
    last: [u8; LOW_STATE_LEN],
}

/// What [`UnsealedStamper::stamp`] did to a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stamp {
    /// New contents.
    Fresh,
    /// The same contents as the last frame (but for tick and CRC).
    Repeat,
    /// A CRC set but wrong: left as it came.
    Corrupt,
}

impl Default for UnsealedStamper {
    fn default() -> Self {
        Self {
            tick: 0,
            last: [0; LOW_STATE_LEN],
        }
    }
}

impl UnsealedStamper {
    pub fn stamp(&mut self, buf: &mut [u8; LOW_STATE_LEN]) -> Stamp {
        let stored = rd_u32(buf, LOW_STATE_LEN - 4);
        if stored != 0 && stored != crc32_words(&buf[..LOW_STATE_LEN - 4]) {
            return Stamp::Corrupt;
        }
        // Compared without tick and CRC, which the sender may or may not fill in.
        let same = self.tick > 0
            && buf[..12] == self.last[..12]
            && buf[16..LOW_STATE_LEN - 4] == self.last[16..LOW_STATE_LEN - 4];
        let verdict = if same { Stamp::Repeat } else { Stamp::Fresh };
        self.tick = self.tick.wrapping_add(1).max(1);
        self.last.copy_from_slice(buf);
        buf[12..16].copy_from_slice(&self.tick.to_le_bytes());
        seal(buf);
        verdict
    }
}

/// Decodes and validates a `LowState_` frame (the firmware's side).
pub fn decode_low_state(buf: &[u8], out: &mut LowState) -> Result<(), DecodeError> {
    const M: &str = "LowState_";
    check(M, buf, LOW_STATE_LEN)?;
    let at = LOW_STATE_IMU_AT;
    let imu = ImuState {
        quaternion: rd_f32s(buf, at),
        gyroscope: rd_f32s(buf, at + 16),
        accelerometer: rd_f32s(buf, at + 28),
        rpy: rd_f32s(buf, at + 40),
        temperature: rd_i16(buf, at + 52),
    };
    finite(M, "imu_state.quaternion", &imu.quaternion)?;
    finite(M, "imu_state.gyroscope", &imu.gyroscope)?;
    finite(M, "imu_state.accelerometer", &imu.accelerometer)?;
    finite(M, "imu_state.rpy", &imu.rpy)?;
    let mut motors = [MotorState::default(); NUM_MOTORS];
    for (i, m) in motors.iter_mut().enumerate() {
        let at = LOW_STATE_MOTORS_AT + i * MOTOR_STATE_LEN;
        let [q, dq, ddq, tau_est] = rd_f32s::<4>(buf, at + 4);
        let voltage = rd_f32(buf, at + 24);
        if !(q.is_finite() && dq.is_finite() && ddq.is_finite() && tau_est.is_finite() && voltage.is_finite()) {
            return Err(DecodeError::NonFinite {
                message: M,
                field: "motor_state",
                index: i,
            });
        }
        *m = MotorState {
            mode: buf[at],
            q,
            dq,
            ddq,
            tau_est,
            temperature: [rd_i16(buf, at + 20), rd_i16(buf, at + 22)],
            voltage,
            sensor: [rd_u32(buf, at + 28), rd_u32(buf, at + 32)],
            motor_state: rd_u32(buf, at + 36),
            reserve: core::array::from_fn(|k| rd_u32(buf, at + 40 + 4 * k)),
        };
    }
    out.version = [rd_u32(buf, 0), rd_u32(buf, 4)];
    out.mode_pr = buf[8];
    out.mode_machine = buf[9];
    out.tick = rd_u32(buf, 12);
    out.imu = imu;
    out.motors = motors;
    out.wireless_remote
        .copy_from_slice(&buf[LOW_STATE_REMOTE_AT..LOW_STATE_REMOTE_AT + 40]);
    out.reserve = core::array::from_fn(|k| rd_u32(buf, LOW_STATE_REMOTE_AT + 40 + 4 * k));
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// Fuzzing entry points (the `unitree_hg_low_state` / `unitree_hg_low_cmd` cargo-fuzz targets and the
// stable `fuzz_smoke` test). The first byte picks a path, so one corpus covers all three:
// 0: the bytes as a C-layout frame; 1: the bytes zero-padded/cut to a frame and resealed with a
// fresh CRC (reaches the checks behind the CRC); 2: the bytes as a DDS CDR sample.

/// Bytes of the C layout that carry a field (not padding, not the CRC word).
fn field_mask<const N: usize>(fields: &[cdr::Field]) -> [bool; N] {
    let mut m = [false; N];
    for f in fields {
        m[f.c_offset..f.c_offset + f.size * f.count].fill(true);
    }
    m[N - 4..].fill(false);
    m
}

/// `data` zero-padded or cut to `N` bytes, with a fresh CRC.
fn resealed<const N: usize>(data: &[u8]) -> [u8; N] {
    let mut b = [0u8; N];
    let n = data.len().min(N);
    b[..n].copy_from_slice(&data[..n]);
    seal(&mut b);
    b
}

#[doc(hidden)]
pub fn fuzz_low_state(data: &[u8]) {
    let Some((&mode, rest)) = data.split_first() else {
        return;
    };
    let mut c = [0u8; LOW_STATE_LEN];
    match mode % 3 {
        0 => check_low_state(rest, decode_low_state(rest, &mut LowState::default())),
        1 => {
            let b: [u8; LOW_STATE_LEN] = resealed(rest);
            let r = decode_low_state(&b, &mut LowState::default());
            assert!(
                !matches!(r, Err(DecodeError::Length { .. } | DecodeError::Crc { .. })),
                "{r:?}"
            );
            check_low_state(&b, r);
        }
        _ => {
            if cdr::low_state_from_cdr(rest, &mut c).is_ok() {
                // Either byte order: the C frame survives its own little-endian CDR (the sample's
                // alignment padding is not kept, as in CDR itself).
                let mut again = [0u8; cdr::LOW_STATE_CDR_LEN];
                cdr::low_state_to_cdr(&c, &mut again);
                let mut back = [0u8; LOW_STATE_LEN];
                cdr::low_state_from_cdr(&again, &mut back).expect("own CDR decodes");
                assert!(back == c, "C frame changed through its own CDR");
                check_low_state(&c, decode_low_state(&c, &mut LowState::default()));
                let b: [u8; LOW_STATE_LEN] = resealed(&c[..LOW_STATE_LEN - 4]);
                check_low_state(&b, decode_low_state(&b, &mut LowState::default()));
            }
        }
    }
}

/// A frame that decoded encodes back to the same bytes, padding aside.
fn check_low_state(buf: &[u8], r: Result<(), DecodeError>) {
    if r.is_err() {
        return;
    }
    let mut s = LowState::default();
    decode_low_state(buf, &mut s).expect("decodes twice");
    let mut out = [0u8; LOW_STATE_LEN];
    encode_low_state(&s, &mut out);
    let mask: [bool; LOW_STATE_LEN] = field_mask(&cdr::LOW_STATE_FIELDS);
    for (i, m) in mask.iter().enumerate() {
        assert!(!m || out[i] == buf[i], "LowState_ byte {i} changed in a round trip");
    }
}

#[doc(hidden)]
pub fn fuzz_low_cmd(data: &[u8]) {
    let Some((&mode, rest)) = data.split_first() else {
        return;
    };
    match mode % 3 {
        0 => check_low_cmd(rest, decode_low_cmd(rest, &mut LowCommand::default())),
        1 => {
            let b: [u8; LOW_CMD_LEN] = resealed(rest);
            let r = decode_low_cmd(&b, &mut LowCommand::default());
            assert!(
                !matches!(r, Err(DecodeError::Length { .. } | DecodeError::Crc { .. })),
                "{r:?}"
            );
            check_low_cmd(&b, r);
        }
        _ => {
            let mut c = [0u8; LOW_CMD_LEN];
            if cdr::low_cmd_from_cdr(rest, &mut c).is_ok() {
                let mut again = [0u8; cdr::LOW_CMD_CDR_LEN];
                cdr::low_cmd_to_cdr(&c, &mut again);
                let mut back = [0u8; LOW_CMD_LEN];
                cdr::low_cmd_from_cdr(&again, &mut back).expect("own CDR decodes");
                assert!(back == c, "C frame changed through its own CDR");
                check_low_cmd(&c, decode_low_cmd(&c, &mut LowCommand::default()));
                let b: [u8; LOW_CMD_LEN] = resealed(&c[..LOW_CMD_LEN - 4]);
                check_low_cmd(&b, decode_low_cmd(&b, &mut LowCommand::default()));
            }
        }
    }
}

fn check_low_cmd(buf: &[u8], r: Result<(), DecodeError>) {
    if r.is_err() {
        return;
    }
    let mut c = LowCommand::default();
    decode_low_cmd(buf, &mut c).expect("decodes twice");
    let mut out = [0u8; LOW_CMD_LEN];
    encode_low_cmd(&c, &mut out);
    let mask: [bool; LOW_CMD_LEN] = field_mask(&cdr::LOW_CMD_FIELDS);
    for (i, m) in mask.iter().enumerate() {
        assert!(!m || out[i] == buf[i], "LowCmd_ byte {i} changed in a round trip");
    }
}

#[cfg(test)]
mod tests;

#[cfg(test)]
mod crc_zero {
    use super::*;

    /// As unitree_mujoco's Python bridge sends it: tick and CRC left at 0.
    fn unsealed(q0: f32) -> [u8; LOW_STATE_LEN] {
        let mut st = LowState::default();
        st.imu.quaternion = [1.0, 0.0, 0.0, 0.0];
        st.motors[0].q = q0;
        let mut buf = [0u8; LOW_STATE_LEN];
        encode_low_state(&st, &mut buf);
        buf[LOW_STATE_LEN - 4..].fill(0);
        buf
    }

    #[test]
    fn unsealed_states_are_stamped_by_arrival_repeats_keep_their_tick_and_corrupt_ones_stay_corrupt() {
        let mut stamper = UnsealedStamper::default();
        let mut out = LowState::default();
        let mut buf = unsealed(0.1);
        assert!(decode_low_state(&buf, &mut out).is_err());
        assert_eq!(stamper.stamp(&mut buf), Stamp::Fresh);
        decode_low_state(&buf, &mut out).unwrap();
        assert_eq!(out.tick, 1);
        // The same contents again (published before the physics stepped): told apart, still the
        // next tick (freshness is arrival order).
        let mut again = unsealed(0.1);
        assert_eq!(stamper.stamp(&mut again), Stamp::Repeat);
        decode_low_state(&again, &mut out).unwrap();
        assert_eq!(out.tick, 2);
        // New contents: the next tick; a sealed frame (a frozen tick, valid CRC) is stamped too.
        let mut st = LowState::default();
        st.motors[0].q = 0.2;
        let mut sealed = [0u8; LOW_STATE_LEN];
        encode_low_state(&st, &mut sealed);
        assert_eq!(stamper.stamp(&mut sealed), Stamp::Fresh);
        decode_low_state(&sealed, &mut out).unwrap();
        assert_eq!(out.tick, 3);
        // A CRC that is set and wrong stays wrong.
        sealed[100] ^= 1;
        assert_eq!(stamper.stamp(&mut sealed), Stamp::Corrupt);
        assert!(matches!(
            decode_low_state(&sealed, &mut out),
            Err(DecodeError::Crc { .. })
        ));
    }

    #[test]
    fn a_crc_of_zero_names_the_simulator_that_sends_it() {
        let zero = super::DecodeError::Crc {
            message: "LowState_",
            stored: 0,
            computed: 0x1234,
        };
        assert!(zero.to_string().contains("unitree_mujoco"), "{zero}");
        let other = super::DecodeError::Crc {
            message: "LowState_",
            stored: 7,
            computed: 0x1234,
        };
        assert!(!other.to_string().contains("unitree_mujoco"), "{other}");
    }
}
