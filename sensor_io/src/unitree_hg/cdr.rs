//! The same messages as DDS carries them: XCDR1 (plain CDR) of unitree_hg's IDL, as CycloneDDS
//! 0.10.2 sends `rt/lowcmd` / `rt/lowstate` (payload 1000 / 2088 bytes after a 4-byte
//! encapsulation header). CDR aligns each primitive to its own size from the payload start and has
//! no padding between or after structs; the C layout this module's parent encodes (and over which
//! Unitree's CRC is computed) pads every struct to 4 bytes. So a message crosses DDS as: encode
//! (C layout, CRC) → [`c_to_cdr`]; and back: [`cdr_to_c`] → decode (checks the CRC).
//!
//! Both layouts are walked from one field list per message ([`LOW_CMD_FIELDS`],
//! [`LOW_STATE_FIELDS`]): C offset, primitive size and count, in IDL order.
use super::{LOW_CMD_LEN, LOW_STATE_LEN};
use hal::NUM_MOTORS;

/// Encapsulation header: CDR little-endian (what CycloneDDS sends) and big-endian.
pub const CDR_LE: [u8; 2] = [0x00, 0x01];
pub const CDR_BE: [u8; 2] = [0x00, 0x00];
const HEADER_LEN: usize = 4;
/// CDR payload sizes (without the header).
pub const LOW_CMD_CDR_PAYLOAD: usize = 1000;
pub const LOW_STATE_CDR_PAYLOAD: usize = 2088;
/// Serialized sizes, header included.
pub const LOW_CMD_CDR_LEN: usize = HEADER_LEN + LOW_CMD_CDR_PAYLOAD;
pub const LOW_STATE_CDR_LEN: usize = HEADER_LEN + LOW_STATE_CDR_PAYLOAD;

/// One run of primitives: offset in the C layout, size of one primitive (1, 2 or 4), count.
#[derive(Clone, Copy, Debug)]
pub struct Field {
    pub c_offset: usize,
    pub size: usize,
    pub count: usize,
}

const fn f(c_offset: usize, size: usize, count: usize) -> Field {
    Field { c_offset, size, count }
}

/// `LowCmd_`: mode_pr, mode_machine, motor_cmd[35] {mode, q, dq, tau, kp, kd, reserve}, reserve[4], crc.
pub const LOW_CMD_FIELDS: [Field; 2 + 2 * NUM_MOTORS + 2] = {
    let mut v = [f(0, 1, 1); 2 + 2 * NUM_MOTORS + 2];
    v[1] = f(1, 1, 1);
    let mut i = 0;
    while i < NUM_MOTORS {
        let base = 4 + 28 * i;
        v[2 + 2 * i] = f(base, 1, 1); // mode
        v[3 + 2 * i] = f(base + 4, 4, 6); // q, dq, tau, kp, kd, reserve
        i += 1;
    }
    v[2 + 2 * NUM_MOTORS] = f(984, 4, 4); // reserve[4]
    v[3 + 2 * NUM_MOTORS] = f(1000, 4, 1); // crc
    v
};

/// `LowState_`: version[2], mode_pr, mode_machine, tick, imu_state {quaternion[4], gyroscope[3],
/// accelerometer[3], rpy[3], temperature (i16)}, motor_state[35] {mode, q, dq, ddq, tau_est,
/// temperature[2] (i16), vol, sensor[2], motorstate, reserve[4]}, wireless_remote[40], reserve[4], crc.
pub const LOW_STATE_FIELDS: [Field; 6 + 6 * NUM_MOTORS + 3] = {
    let mut v = [f(0, 4, 2); 6 + 6 * NUM_MOTORS + 3];
    v[1] = f(8, 1, 1);
    v[2] = f(9, 1, 1);
    v[3] = f(12, 4, 1);
    v[4] = f(16, 4, 13);
    v[5] = f(68, 2, 1);
    let mut i = 0;
    while i < NUM_MOTORS {
        let b = 72 + 56 * i;
        v[6 + 6 * i] = f(b, 1, 1); // mode
        v[7 + 6 * i] = f(b + 4, 4, 4); // q, dq, ddq, tau_est
        v[8 + 6 * i] = f(b + 20, 2, 2); // temperature[2]
        v[9 + 6 * i] = f(b + 24, 4, 1); // vol
        v[10 + 6 * i] = f(b + 28, 4, 2); // sensor[2]
        v[11 + 6 * i] = f(b + 36, 4, 5); // motorstate, reserve[4]
        i += 1;
    }
    v[6 + 6 * NUM_MOTORS] = f(2032, 1, 40); // wireless_remote
    v[7 + 6 * NUM_MOTORS] = f(2072, 4, 4); // reserve[4]
    v[8 + 6 * NUM_MOTORS] = f(2088, 4, 1); // crc
    v
};

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CdrError {
    #[error("{message}: CDR sample is {got} bytes, expected {expected} (4-byte header + payload)")]
    Length {
        message: &'static str,
        expected: usize,
        got: usize,
    },
    #[error("{message}: encapsulation {0:02x}{1:02x} is not plain CDR (00 00 / 00 01); XCDR2 senders must offer XCDR1", header[0], header[1])]
    Encapsulation { message: &'static str, header: [u8; 2] },
}

impl hal::Error for CdrError {
    fn kind(&self) -> hal::ErrorKind {
        hal::ErrorKind::Malformed
    }
}

/// Walks `fields`, calling `copy(c_offset, cdr_offset, size, count)` with CDR offsets from the
/// payload start; returns the payload length.
fn walk(fields: &[Field], mut copy: impl FnMut(usize, usize, usize, usize)) -> usize {
    let mut at = 0usize;
    for fd in fields {
        at = at.next_multiple_of(fd.size);
        copy(fd.c_offset, at, fd.size, fd.count);
        at += fd.size * fd.count;
    }
    at
}

/// C layout → CDR little-endian with its header.
pub fn c_to_cdr(fields: &[Field], c: &[u8], out: &mut [u8]) -> usize {
    out[..HEADER_LEN].copy_from_slice(&[CDR_LE[0], CDR_LE[1], 0, 0]);
    let payload = &mut out[HEADER_LEN..];
    let n = walk(fields, |co, po, size, count| {
        payload[po..po + size * count].copy_from_slice(&c[co..co + size * count]);
    });
    HEADER_LEN + n
}

/// CDR (either byte order) → C layout little-endian with zeroed padding.
pub fn cdr_to_c(
    message: &'static str,
    fields: &[Field],
    cdr: &[u8],
    expected_len: usize,
    out: &mut [u8],
) -> Result<(), CdrError> {
    if cdr.len() != expected_len {
        return Err(CdrError::Length {
            message,
            expected: expected_len,
            got: cdr.len(),
        });
    }
    let header = [cdr[0], cdr[1]];
    let big_endian = match header {
        CDR_LE => false,
        CDR_BE => true,
        _ => return Err(CdrError::Encapsulation { message, header }),
    };
    out.fill(0);
    let payload = &cdr[HEADER_LEN..];
    walk(fields, |co, po, size, count| {
        for k in 0..count {
            let (c, p) = (co + k * size, po + k * size);
            out[c..c + size].copy_from_slice(&payload[p..p + size]);
            if big_endian {
                out[c..c + size].reverse();
            }
        }
    });
    Ok(())
}

/// A C-layout `LowCmd_` (as [`super::encode_low_cmd`] makes it) as the CDR sample DDS sends.
pub fn low_cmd_to_cdr(c: &[u8; LOW_CMD_LEN], out: &mut [u8; LOW_CMD_CDR_LEN]) {
    c_to_cdr(&LOW_CMD_FIELDS, c, out);
}

/// A received `rt/lowcmd` CDR sample in the C layout (decode it with [`super::decode_low_cmd`]).
pub fn low_cmd_from_cdr(cdr: &[u8], out: &mut [u8; LOW_CMD_LEN]) -> Result<(), CdrError> {
    cdr_to_c("LowCmd_", &LOW_CMD_FIELDS, cdr, LOW_CMD_CDR_LEN, out)
}

/// A C-layout `LowState_` as the CDR sample DDS sends.
pub fn low_state_to_cdr(c: &[u8; LOW_STATE_LEN], out: &mut [u8; LOW_STATE_CDR_LEN]) {
    c_to_cdr(&LOW_STATE_FIELDS, c, out);
}

/// A received `rt/lowstate` CDR sample in the C layout (decode it with [`super::decode_low_state`],
/// which checks Unitree's CRC over this layout).
pub fn low_state_from_cdr(cdr: &[u8], out: &mut [u8; LOW_STATE_LEN]) -> Result<(), CdrError> {
    cdr_to_c("LowState_", &LOW_STATE_FIELDS, cdr, LOW_STATE_CDR_LEN, out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn field_lists_cover_both_layouts_exactly() {
        for (fields, c_len, cdr_len) in [
            (&LOW_CMD_FIELDS[..], LOW_CMD_LEN, LOW_CMD_CDR_PAYLOAD),
            (&LOW_STATE_FIELDS[..], LOW_STATE_LEN, LOW_STATE_CDR_PAYLOAD),
        ] {
            let mut covered = vec![0u8; c_len];
            let n = walk(fields, |co, _, size, count| {
                for b in &mut covered[co..co + size * count] {
                    *b += 1;
                }
            });
            assert_eq!(n, cdr_len);
            // Every C byte at most once (the uncovered ones are the C padding).
            assert!(covered.iter().all(|&c| c <= 1));
            // C offsets increase and are aligned to their size.
            assert!(fields.windows(2).all(|w| w[0].c_offset < w[1].c_offset));
            assert!(fields.iter().all(|f| f.c_offset % f.size == 0));
        }
        // The facts: LowCmd_'s motor_cmd[i].q at payload offset 4 + 28 i.
        let mut q = Vec::new();
        walk(&LOW_CMD_FIELDS, |co, po, _, _| {
            if (4..984).contains(&co) && (co - 4) % 28 == 4 {
                q.push(po);
            }
        });
        assert_eq!(q, (0..NUM_MOTORS).map(|i| 4 + 28 * i).collect::<Vec<_>>());
    }

    #[test]
    fn round_trips_and_rejects_bad_samples() {
        let mut c = [0u8; LOW_STATE_LEN];
        let mut x = hal::XorShift64(3);
        for b in c.iter_mut() {
            *b = x.next_u64() as u8;
        }
        // Padding is zero in a well-formed C frame.
        let mut covered = [false; LOW_STATE_LEN];
        walk(&LOW_STATE_FIELDS, |co, _, s, n| covered[co..co + s * n].fill(true));
        for (b, cov) in c.iter_mut().zip(covered) {
            if !cov {
                *b = 0;
            }
        }
        let mut cdr = [0u8; LOW_STATE_CDR_LEN];
        low_state_to_cdr(&c, &mut cdr);
        let mut back = [0u8; LOW_STATE_LEN];
        low_state_from_cdr(&cdr, &mut back).unwrap();
        assert_eq!(back, c);
        assert!(matches!(
            low_state_from_cdr(&cdr[..100], &mut back),
            Err(CdrError::Length { got: 100, .. })
        ));
        let mut xcdr2 = cdr;
        xcdr2[1] = 0x07;
        assert!(matches!(
            low_state_from_cdr(&xcdr2, &mut back),
            Err(CdrError::Encapsulation { .. })
        ));
    }
}
