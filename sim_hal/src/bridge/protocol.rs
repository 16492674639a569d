//! Wire protocol between the firmware (client) and the simulator (server).
//!
//! Every message is an 8-byte header — magic `b"G1"`, kind (u8), flags (u8), payload length (u32 LE)
//! — followed by the payload. Sequence:
//! 1. client → `Hello` (payload: protocol version u32, want_truth u8, want_lidar u8, 2 zero bytes)
//! 2. server → `Welcome` ([`Welcome`]), then `LowState` (initial state), if asked `LidarPackets`,
//!    and if asked `Truth`
//! 3. per tick: client → `LowCmd` (1004 B unitree_hg frame); server steps one control tick →
//!    `LowState` (2092 B), if asked `LidarPackets` (the Livox UDP datagrams the simulated MID-360
//!    sent during the tick, each prefixed by its u16 LE length; possibly none), and if asked
//!    `Truth` ([`Truth`], with the terrain label when the simulator runs a world)
//! 4. client → `Bye`; or server → `Error` (UTF-8 text) before closing.
//!
//! Flags (header byte 3): [`FLAG_NO_FRAME`] on a `LowState` means "this tick produced no frame"
//! (the simulator's fault injection dropped it); its payload is then empty, and the lock-step still
//! advanced one tick (the `Truth` of that tick follows if asked). All other bits, and any flag on
//! other kinds, are reserved and sent as zero. Version 2 introduced the flag, version 3 the lidar and
//! the terrain label, version 4 the ground height under the base and the stair progress in `Truth`
//! ([`StairProgress`], for `g1fw eval`); other versions are refused at `Hello`.
use std::io::{self, Read, Write};

pub const MAGIC: [u8; 2] = *b"G1";
pub const PROTOCOL_VERSION: u32 = 4;
pub const HEADER_LEN: usize = 8;
/// `LowState` flag: no frame this tick (dropped); the payload is empty.
pub const FLAG_NO_FRAME: u8 = 1 << 0;
/// Largest payload either side accepts (guards against a corrupted length field).
pub const MAX_PAYLOAD: usize = 1 << 20;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum Kind {
    Hello = 1,
    Welcome = 2,
    LowCmd = 3,
    LowState = 4,
    Truth = 5,
    Bye = 6,
    Error = 7,
    LidarPackets = 8,
}

impl Kind {
    pub fn from_u8(v: u8) -> Option<Kind> {
        Some(match v {
            1 => Kind::Hello,
            2 => Kind::Welcome,
            3 => Kind::LowCmd,
            4 => Kind::LowState,
            5 => Kind::Truth,
            6 => Kind::Bye,
            7 => Kind::Error,
            8 => Kind::LidarPackets,
            _ => return None,
        })
    }
}

#[derive(Debug, thiserror::Error)]
pub enum ProtocolError {
    #[error("connection closed by peer")]
    Closed,
    #[error("i/o: {0}")]
    Io(io::Error),
    #[error("bad magic {0:?} (not a G1 bridge peer, or the stream lost sync)")]
    BadMagic([u8; 2]),
    #[error("unknown message kind {0}")]
    UnknownKind(u8),
    #[error("payload of {0} bytes exceeds the {MAX_PAYLOAD}-byte limit")]
    TooLong(usize),
    #[error("expected {expected:?}, got {got:?}")]
    Unexpected { expected: Kind, got: Kind },
    #[error("{kind:?} payload is {got} bytes, expected {expected}")]
    BadLength { kind: Kind, expected: usize, got: usize },
    #[error("{kind:?} message has flags {flags:#04x}, which this protocol version does not define")]
    BadFlags { kind: Kind, flags: u8 },
    #[error("simulator reported: {0}")]
    Remote(String),
}

// Display carries the inner error's text; no `source` link, so `{:#}` chains print it once.
impl From<io::Error> for ProtocolError {
    fn from(e: io::Error) -> Self {
        ProtocolError::Io(e)
    }
}

/// Writes one message. `scratch` avoids an allocation per message: header and payload go out in one
/// write so a message is never split across two syscalls on the lock-stepped path.
pub fn write_msg<W: Write>(w: &mut W, kind: Kind, payload: &[u8], scratch: &mut Vec<u8>) -> Result<(), ProtocolError> {
    write_msg_flags(w, kind, 0, payload, scratch)
}

/// [`write_msg`] with header flags (e.g. [`FLAG_NO_FRAME`]).
pub fn write_msg_flags<W: Write>(
    w: &mut W,
    kind: Kind,
    flags: u8,
    payload: &[u8],
    scratch: &mut Vec<u8>,
) -> Result<(), ProtocolError> {
    scratch.clear();
    append_msg_flags(scratch, kind, flags, payload);
    w.write_all(scratch)?;
    Ok(())
}

/// Appends one framed message to `buf`, so several can leave in one write (one wake-up of the peer).
pub fn append_msg(buf: &mut Vec<u8>, kind: Kind, payload: &[u8]) {
    append_msg_flags(buf, kind, 0, payload);
}

/// [`append_msg`] with header flags (e.g. [`FLAG_NO_FRAME`]).
pub fn append_msg_flags(buf: &mut Vec<u8>, kind: Kind, flags: u8, payload: &[u8]) {
    buf.extend_from_slice(&MAGIC);
    buf.push(kind as u8);
    buf.push(flags);
    buf.extend_from_slice(&(payload.len() as u32).to_le_bytes());
    buf.extend_from_slice(payload);
}

/// Reads one message into `payload` (resized, capacity reused). Returns its kind; flags are
/// ignored (see [`read_msg_flags`]).
pub fn read_msg<R: Read>(r: &mut R, payload: &mut Vec<u8>) -> Result<Kind, ProtocolError> {
    read_msg_flags(r, payload).map(|(kind, _)| kind)
}

/// Reads one message into `payload` (resized, capacity reused). Returns its kind and header flags.
pub fn read_msg_flags<R: Read>(r: &mut R, payload: &mut Vec<u8>) -> Result<(Kind, u8), ProtocolError> {
    let mut h = [0u8; HEADER_LEN];
    if let Err(e) = r.read_exact(&mut h) {
        return Err(if e.kind() == io::ErrorKind::UnexpectedEof {
            ProtocolError::Closed
        } else {
            e.into()
        });
    }
    if h[0..2] != MAGIC {
        return Err(ProtocolError::BadMagic([h[0], h[1]]));
    }
    let kind = Kind::from_u8(h[2]).ok_or(ProtocolError::UnknownKind(h[2]))?;
    let len = u32::from_le_bytes([h[4], h[5], h[6], h[7]]) as usize;
    if len > MAX_PAYLOAD {
        return Err(ProtocolError::TooLong(len));
    }
    payload.resize(len, 0);
    if let Err(e) = r.read_exact(payload) {
        return Err(if e.kind() == io::ErrorKind::UnexpectedEof {
            ProtocolError::Closed
        } else {
            e.into()
        });
    }
    if kind == Kind::Error {
        return Err(ProtocolError::Remote(String::from_utf8_lossy(payload).into_owned()));
    }
    Ok((kind, h[3]))
}

/// Reads one message that must be of kind `expected` (payload into `payload`); flags ignored.
pub fn read_expect<R: Read>(r: &mut R, payload: &mut Vec<u8>, expected: Kind) -> Result<(), ProtocolError> {
    read_expect_flags(r, payload, expected).map(|_| ())
}

/// Reads one message that must be of kind `expected` (payload into `payload`); returns its flags.
pub fn read_expect_flags<R: Read>(r: &mut R, payload: &mut Vec<u8>, expected: Kind) -> Result<u8, ProtocolError> {
    match read_msg_flags(r, payload)? {
        (got, flags) if got == expected => Ok(flags),
        (got, _) => Err(ProtocolError::Unexpected { expected, got }),
    }
}

/// Appends one datagram to a `LidarPackets` payload (u16 LE length, then the bytes).
pub fn append_datagram(buf: &mut Vec<u8>, datagram: &[u8]) {
    buf.extend_from_slice(&(datagram.len() as u16).to_le_bytes());
    buf.extend_from_slice(datagram);
}

/// Splits a `LidarPackets` payload into its datagrams. A length that overruns the payload ends the
/// iteration with `Err(bytes left)`: the rest cannot be framed.
pub fn datagrams(payload: &[u8]) -> impl Iterator<Item = Result<&[u8], usize>> {
    let mut rest = payload;
    let mut failed = false;
    std::iter::from_fn(move || {
        if failed || rest.is_empty() {
            return None;
        }
        let n = if rest.len() >= 2 {
            u16::from_le_bytes([rest[0], rest[1]]) as usize
        } else {
            usize::MAX
        };
        if n == usize::MAX || rest.len() < 2 + n {
            failed = true;
            return Some(Err(rest.len()));
        }
        let d = &rest[2..2 + n];
        rest = &rest[2 + n..];
        Some(Ok(d))
    })
}

/// What the simulator tells the client once, after `Hello`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Welcome {
    pub protocol_version: u32,
    /// Bit i set: motor slot i maps to a joint of the loaded model.
    pub motor_slots_present: u64,
    /// `mode_machine` the simulated robot reports.
    pub mode_machine: u8,
    pub physics_dt_ns: u64,
    pub control_dt_ns: u64,
}

impl Welcome {
    pub const LEN: usize = 4 + 8 + 1 + 8 + 8;
    pub fn encode(&self) -> [u8; Self::LEN] {
        let mut b = [0u8; Self::LEN];
        b[0..4].copy_from_slice(&self.protocol_version.to_le_bytes());
        b[4..12].copy_from_slice(&self.motor_slots_present.to_le_bytes());
        b[12] = self.mode_machine;
        b[13..21].copy_from_slice(&self.physics_dt_ns.to_le_bytes());
        b[21..29].copy_from_slice(&self.control_dt_ns.to_le_bytes());
        b
    }
    pub fn decode(b: &[u8]) -> Result<Self, ProtocolError> {
        if b.len() != Self::LEN {
            return Err(ProtocolError::BadLength {
                kind: Kind::Welcome,
                expected: Self::LEN,
                got: b.len(),
            });
        }
        let u64_at = |i: usize| u64::from_le_bytes(b[i..i + 8].try_into().expect("8 bytes"));
        Ok(Self {
            protocol_version: u32::from_le_bytes(b[0..4].try_into().expect("4 bytes")),
            motor_slots_present: u64_at(4),
            mode_machine: b[12],
            physics_dt_ns: u64_at(13),
            control_dt_ns: u64_at(21),
        })
    }
}

/// The `Truth` message carries `hal`'s ground truth (an observer's payload, never on the control
/// path); the bridge only encodes it.
pub use hal::{GroundTruth as Truth, StairProgress};

/// How far past the last riser's edge the base (pelvis) must be to count as on the end landing, m:
/// with the G1's ~0.2 m feet under the pelvis, both feet are then past the edge.
pub const END_LANDING_MARGIN_M: f64 = 0.25;

const STAIRS_LEN: usize = 1 + 8 + 8 + 4 + 4 + 2 + 2 + 1;

fn encode_stairs(this: &StairProgress, b: &mut [u8]) {
    b[0] = 1;
    b[1..9].copy_from_slice(&this.axis_s.to_le_bytes());
    b[9..17].copy_from_slice(&this.axis_t.to_le_bytes());
    b[17..21].copy_from_slice(&this.axis_yaw_rad.to_le_bytes());
    b[21..25].copy_from_slice(&this.rise_m.to_le_bytes());
    b[25..27].copy_from_slice(&this.risers.to_le_bytes());
    b[27..29].copy_from_slice(&this.risers_passed.to_le_bytes());
    b[29] = this.on_end_landing as u8;
}

fn decode_stairs(b: &[u8]) -> Option<StairProgress> {
    let f32_at = |i: usize| f32::from_le_bytes(b[i..i + 4].try_into().expect("4 bytes"));
    (b[0] != 0).then(|| StairProgress {
        axis_s: f64::from_le_bytes(b[1..9].try_into().expect("8 bytes")),
        axis_t: f64::from_le_bytes(b[9..17].try_into().expect("8 bytes")),
        axis_yaw_rad: f32_at(17),
        rise_m: f32_at(21),
        risers: u16::from_le_bytes([b[25], b[26]]),
        risers_passed: u16::from_le_bytes([b[27], b[28]]),
        on_end_landing: b[29] != 0,
    })
}

/// Bytes of an encoded [`Truth`].
pub const TRUTH_LEN: usize = TRUTH_STAIRS_AT + STAIRS_LEN;
const TRUTH_TERRAIN_AT: usize = 8 * (1 + 3 + 4 + 3 + 3 + 3) + 2;
const TRUTH_GROUND_AT: usize = TRUTH_TERRAIN_AT + 1 + 12;
const TRUTH_STAIRS_AT: usize = TRUTH_GROUND_AT + 8;

/// The `Truth` message's payload.
pub fn encode_truth(this: &Truth) -> [u8; TRUTH_LEN] {
    let mut b = [0u8; TRUTH_LEN];
    // No intermediate Vec: this runs every tick when truth is requested.
    let time = [this.sim_time_s];
    let vals = time
        .iter()
        .chain(&this.base_pos)
        .chain(&this.base_quat)
        .chain(&this.base_lin_vel_world)
        .chain(&this.base_lin_vel_body)
        .chain(&this.base_ang_vel_body)
        .copied()
        .enumerate();
    for (i, v) in vals {
        b[8 * i..8 * i + 8].copy_from_slice(&v.to_le_bytes());
    }
    let t = TRUTH_TERRAIN_AT;
    b[t - 2] = this.foot_contact[0] as u8;
    b[t - 1] = this.foot_contact[1] as u8;
    // Class byte 0xFF: no terrain world.
    match this.terrain {
        None => b[t] = 0xFF,
        Some(z) => {
            b[t] = z.class as u8;
            b[t + 1..t + 5].copy_from_slice(&z.step_height_m.to_le_bytes());
            b[t + 5..t + 9].copy_from_slice(&z.step_depth_m.to_le_bytes());
            b[t + 9..t + 13].copy_from_slice(&z.yaw_rad.to_le_bytes());
        }
    }
    b[TRUTH_GROUND_AT..TRUTH_STAIRS_AT].copy_from_slice(&this.ground_height_m.to_le_bytes());
    // First byte 0: no staircase.
    if let Some(p) = &this.stairs {
        encode_stairs(p, &mut b[TRUTH_STAIRS_AT..]);
    }
    b
}

/// Reads a `Truth` message's payload.
pub fn decode_truth(b: &[u8]) -> Result<Truth, ProtocolError> {
    if b.len() != TRUTH_LEN {
        return Err(ProtocolError::BadLength {
            kind: Kind::Truth,
            expected: TRUTH_LEN,
            got: b.len(),
        });
    }
    let f = |i: usize| f64::from_le_bytes(b[8 * i..8 * i + 8].try_into().expect("8 bytes"));
    let f32_at = |i: usize| f32::from_le_bytes(b[i..i + 4].try_into().expect("4 bytes"));
    let t = TRUTH_TERRAIN_AT;
    let a3 = |i: usize| [f(i), f(i + 1), f(i + 2)];
    Ok(Truth {
        sim_time_s: f(0),
        base_pos: a3(1),
        base_quat: [f(4), f(5), f(6), f(7)],
        base_lin_vel_world: a3(8),
        base_lin_vel_body: a3(11),
        base_ang_vel_body: a3(14),
        foot_contact: [b[t - 2] != 0, b[t - 1] != 0],
        terrain: hal::TerrainClass::from_index(b[t] as usize).map(|class| hal::TerrainToken {
            class,
            step_height_m: f32_at(t + 1),
            step_depth_m: f32_at(t + 5),
            yaw_rad: f32_at(t + 9),
        }),
        ground_height_m: f64::from_le_bytes(b[TRUTH_GROUND_AT..TRUTH_STAIRS_AT].try_into().expect("8 bytes")),
        stairs: decode_stairs(&b[TRUTH_STAIRS_AT..]),
    })
}

/// Fuzz harness (the `bridge_protocol` cargo-fuzz target and the stable `fuzz_smoke` test): reads
/// `data` as the byte stream of a connection, message by message until it fails, and decodes every
/// payload as its kind says. A message that reads frames back to the same bytes; a decoded
/// `Welcome` or `Truth` encodes to what decodes to itself.
#[doc(hidden)]
pub fn fuzz_bridge(data: &[u8]) {
    let mut r = data;
    let mut payload = Vec::new();
    let mut framed = Vec::new();
    // Bounded: every message consumes at least its 8-byte header.
    loop {
        let before = r;
        let (kind, flags) = match read_msg_flags(&mut r, &mut payload) {
            Ok(m) => m,
            Err(ProtocolError::TooLong(n)) => {
                assert!(n > MAX_PAYLOAD);
                return;
            }
            Err(_) => return,
        };
        assert!(payload.len() <= MAX_PAYLOAD);
        framed.clear();
        append_msg_flags(&mut framed, kind, flags, &payload);
        assert_eq!(framed[..], before[..before.len() - r.len()]);
        match kind {
            Kind::Welcome => {
                if let Ok(w) = Welcome::decode(&payload) {
                    assert_eq!(w.encode()[..], payload[..]);
                }
            }
            Kind::Truth => {
                if let Ok(t) = decode_truth(&payload) {
                    let once = encode_truth(&t);
                    let twice = encode_truth(&decode_truth(&once).expect("own encoding decodes"));
                    assert_eq!(once, twice);
                }
            }
            Kind::LowState => {
                let _ = sensor_io::unitree_hg::decode_low_state(&payload, &mut hal::LowState::default());
            }
            Kind::LowCmd => {
                let _ = sensor_io::unitree_hg::decode_low_cmd(&payload, &mut hal::LowCommand::default());
            }
            Kind::LidarPackets => {
                let mut total = 0;
                for d in datagrams(&payload) {
                    match d {
                        Ok(d) => {
                            total += 2 + d.len();
                            let _ = sensor_io::livox::decode_packet(d);
                        }
                        Err(left) => total += left,
                    }
                }
                assert_eq!(total, payload.len());
            }
            Kind::Hello | Kind::Bye | Kind::Error => {}
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn message_round_trip_and_bad_input() {
        let mut wire = Vec::new();
        let mut scratch = Vec::new();
        write_msg(&mut wire, Kind::Bye, &[1, 2, 3], &mut scratch).unwrap();
        let mut p = Vec::new();
        assert_eq!(read_msg(&mut wire.as_slice(), &mut p).unwrap(), Kind::Bye);
        assert_eq!(p, [1, 2, 3]);
        // Truncated payload → Closed, not a panic.
        assert!(matches!(read_msg(&mut &wire[..9], &mut p), Err(ProtocolError::Closed)));
        let mut bad = wire.clone();
        bad[0] = b'X';
        assert!(matches!(
            read_msg(&mut bad.as_slice(), &mut p),
            Err(ProtocolError::BadMagic(_))
        ));
        let mut bad = wire.clone();
        bad[2] = 99;
        assert!(matches!(
            read_msg(&mut bad.as_slice(), &mut p),
            Err(ProtocolError::UnknownKind(99))
        ));
        let mut bad = wire.clone();
        bad[4..8].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(matches!(
            read_msg(&mut bad.as_slice(), &mut p),
            Err(ProtocolError::TooLong(_))
        ));
        let mut err = Vec::new();
        write_msg(&mut err, Kind::Error, b"model not found", &mut scratch).unwrap();
        assert!(
            matches!(read_msg(&mut err.as_slice(), &mut p), Err(ProtocolError::Remote(m)) if m == "model not found")
        );
    }

    #[test]
    fn flags_round_trip_and_plain_readers_ignore_them() {
        let (mut wire, mut scratch, mut p) = (Vec::new(), Vec::new(), vec![9u8; 4]);
        write_msg_flags(&mut wire, Kind::LowState, FLAG_NO_FRAME, &[], &mut scratch).unwrap();
        append_msg_flags(&mut wire, Kind::Truth, 0, &[7]);
        assert_eq!(wire[3], FLAG_NO_FRAME);
        let mut r = wire.as_slice();
        assert_eq!(read_msg_flags(&mut r, &mut p).unwrap(), (Kind::LowState, FLAG_NO_FRAME));
        assert!(p.is_empty());
        assert_eq!(read_expect_flags(&mut r, &mut p, Kind::Truth).unwrap(), 0);
        assert_eq!(p, [7]);
        assert_eq!(read_msg(&mut wire.as_slice(), &mut p).unwrap(), Kind::LowState);
        read_expect(&mut wire.as_slice(), &mut p, Kind::LowState).unwrap();
        // The unflagged writers still write a zero flags byte.
        let mut plain = Vec::new();
        append_msg(&mut plain, Kind::Bye, &[]);
        assert_eq!(plain, [b'G', b'1', Kind::Bye as u8, 0, 0, 0, 0, 0]);
    }

    #[test]
    fn datagrams_frame_and_stop_at_a_bad_length() {
        let mut p = Vec::new();
        append_datagram(&mut p, &[1, 2, 3]);
        append_datagram(&mut p, &[]);
        append_datagram(&mut p, &[9]);
        let got: Vec<_> = datagrams(&p).collect();
        assert_eq!(got, vec![Ok(&[1u8, 2, 3][..]), Ok(&[][..]), Ok(&[9u8][..])]);
        let mut bad = p.clone();
        bad[0] = 200;
        let got: Vec<_> = datagrams(&bad).collect();
        assert_eq!(got, vec![Err(bad.len())]);
        assert_eq!(datagrams(&[7]).collect::<Vec<_>>(), vec![Err(1)]);
    }

    #[test]
    fn welcome_and_truth_round_trip() {
        let w = Welcome {
            protocol_version: 1,
            motor_slots_present: 0xFFF,
            mode_machine: 5,
            physics_dt_ns: 2_000_000,
            control_dt_ns: 2_000_000,
        };
        assert_eq!(Welcome::decode(&w.encode()).unwrap(), w);
        let t = Truth {
            sim_time_s: 1.5,
            base_pos: [1.0, 2.0, 0.78],
            base_quat: [1.0, 0.0, 0.0, 0.0],
            base_lin_vel_world: [0.5, 0.0, 0.0],
            base_lin_vel_body: [0.4, 0.1, 0.0],
            base_ang_vel_body: [0.0, 0.0, 0.2],
            foot_contact: [true, false],
            terrain: None,
            ground_height_m: 0.0,
            stairs: None,
        };
        assert_eq!(decode_truth(&encode_truth(&t)).unwrap(), t);
        let t = Truth {
            terrain: Some(hal::TerrainToken {
                class: hal::TerrainClass::StairsDown,
                step_height_m: 0.15,
                step_depth_m: 0.3,
                yaw_rad: -0.2,
            }),
            ground_height_m: 0.45,
            stairs: Some(StairProgress {
                axis_s: 1.37,
                axis_t: -0.2,
                axis_yaw_rad: 0.3,
                rise_m: -0.9,
                risers: 6,
                risers_passed: 4,
                on_end_landing: false,
            }),
            ..t
        };
        assert_eq!(decode_truth(&encode_truth(&t)).unwrap(), t);
        let t = Truth {
            stairs: Some(StairProgress {
                on_end_landing: true,
                ..t.stairs.unwrap()
            }),
            ..t
        };
        assert_eq!(decode_truth(&encode_truth(&t)).unwrap(), t);
        assert!(decode_truth(&[0u8; 3]).is_err());
    }
}
