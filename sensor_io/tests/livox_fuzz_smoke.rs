//! Deterministic mutation fuzzing of the Livox packet codec for CI (no cargo-fuzz, no nightly):
//! valid packets from the encoder, mutated by bit flips, byte sets, truncation, extension, length
//! and dot_num tampering and splicing, half of them re-sealed with a fresh CRC so that mutations
//! reach the checks behind it, all fed to `sensor_io::livox::fuzz_livox` (which asserts the
//! invariants). `LIVOX_FUZZ_INPUTS` overrides the input count (200,000 in release, 20,000 in debug).
use std::time::Instant;

use hal::{LidarPoint, XorShift64 as Rng};
use sensor_io::livox::*;

fn reseal(buf: &mut [u8]) {
    if buf.len() >= HEADER_LEN {
        let crc = crc32(&buf[28..]);
        buf[24..28].copy_from_slice(&crc.to_le_bytes());
    }
}

fn raw_packet(data_type: u8, dot_num: u16, payload: &[u8], udp_cnt: u16, frame_cnt: u8) -> Vec<u8> {
    let mut b = vec![0u8; HEADER_LEN];
    b[1..3].copy_from_slice(&((HEADER_LEN + payload.len()) as u16).to_le_bytes());
    b[3..5].copy_from_slice(&1000u16.to_le_bytes());
    b[5..7].copy_from_slice(&dot_num.to_le_bytes());
    b[7..9].copy_from_slice(&udp_cnt.to_le_bytes());
    b[9] = frame_cnt;
    b[10] = data_type;
    b[28..36].copy_from_slice(&123_456_789u64.to_le_bytes());
    b.extend_from_slice(payload);
    reseal(&mut b);
    b
}

fn seeds(rng: &mut Rng) -> Vec<Vec<u8>> {
    let mut out = Vec::new();
    for (k, n) in [0usize, 1, 2, 5, 17, 96].into_iter().enumerate() {
        let points: Vec<LidarPoint> = (0..n)
            .map(|i| LidarPoint {
                xyz: match i % 4 {
                    0 => [0.0; 3], // "no return"
                    1 => [0.05, 0.0, 0.0],
                    _ => [
                        (rng.below(20_000) as f32 - 10_000.0) / 1000.0,
                        (rng.below(20_000) as f32 - 10_000.0) / 1000.0,
                        (rng.below(4_000) as f32 - 2_000.0) / 1000.0,
                    ],
                },
                reflectivity: rng.next_u64() as u8,
                tag: rng.next_u64() as u8,
                offset_ns: 0,
            })
            .collect();
        let meta = PacketMeta {
            udp_cnt: k as u16,
            frame_cnt: (k / 3) as u8,
            timestamp_ns: 1_000_000 * k as u64,
            time_interval: 4800,
            time_type: 0,
        };
        let mut buf = vec![0u8; cartesian_high_len(n)];
        encode_cartesian_high(&meta, &points, &mut buf).unwrap();
        out.push(buf);
    }
    let low: Vec<u8> = (0..4u8).flat_map(|i| [i * 10, 1, 0xF0, 0xFF, 30, 0, 5, 0]).collect();
    out.push(raw_packet(DATA_TYPE_CARTESIAN_LOW, 4, &low, 9, 3));
    let imu: Vec<u8> = [0.01f32, -0.02, 0.0, 0.0, 0.0, -1.0]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    out.push(raw_packet(DATA_TYPE_IMU, 1, &imu, 10, 3));
    out
}

const INTERESTING: [u8; 8] = [0, 1, 0x7F, 0x80, 0xFF, 0xFE, 36, 14];

fn mutate(rng: &mut Rng, seeds: &[Vec<u8>], buf: &mut Vec<u8>) {
    buf.clear();
    buf.extend_from_slice(&seeds[rng.below(seeds.len())]);
    let rounds = 1 + rng.below(4);
    for _ in 0..rounds {
        match rng.below(9) {
            0 if !buf.is_empty() => {
                let i = rng.below(buf.len());
                buf[i] ^= 1 << rng.below(8);
            }
            1 if !buf.is_empty() => {
                let i = rng.below(buf.len());
                buf[i] = if rng.chance(50) {
                    INTERESTING[rng.below(8)]
                } else {
                    rng.next_u64() as u8
                };
            }
            2 => {
                let n = rng.below(buf.len() + 1);
                buf.truncate(n);
            }
            3 => {
                for _ in 0..1 + rng.below(40) {
                    buf.push(rng.next_u64() as u8);
                }
            }
            4 if buf.len() >= 3 => {
                // length field: random, off by a little, or the true length.
                let v = match rng.below(3) {
                    0 => rng.next_u64() as u16,
                    1 => (buf.len() as u16).wrapping_add(rng.below(5) as u16).wrapping_sub(2),
                    _ => buf.len() as u16,
                };
                buf[1..3].copy_from_slice(&v.to_le_bytes());
            }
            5 if buf.len() >= 7 => {
                let v = match rng.below(3) {
                    0 => rng.next_u64() as u16,
                    1 => u16::from_le_bytes([buf[5], buf[6]])
                        .wrapping_add(rng.below(3) as u16)
                        .wrapping_sub(1),
                    _ => 0,
                };
                buf[5..7].copy_from_slice(&v.to_le_bytes());
            }
            6 => {
                // splice: a prefix of this one and a suffix of another, or two packets back to back.
                let other = &seeds[rng.below(seeds.len())];
                if rng.chance(50) {
                    buf.extend_from_slice(other);
                } else {
                    let cut = rng.below(buf.len() + 1);
                    let from = rng.below(other.len() + 1);
                    buf.truncate(cut);
                    buf.extend_from_slice(&other[from..]);
                }
            }
            7 if buf.len() > 11 => {
                // data type / version / frame and udp counters.
                let field = [0usize, 7, 9, 10][rng.below(4)];
                buf[field] = if rng.chance(50) {
                    rng.below(4) as u8
                } else {
                    rng.next_u64() as u8
                };
            }
            _ => {
                // payload values, e.g. NaN in an IMU sample or huge coordinates.
                if buf.len() > HEADER_LEN + 4 {
                    let i = HEADER_LEN + rng.below(buf.len() - HEADER_LEN - 3);
                    let v = [
                        f32::NAN.to_bits(),
                        f32::INFINITY.to_bits(),
                        i32::MAX as u32,
                        i32::MIN as u32,
                        0,
                    ][rng.below(5)];
                    buf[i..i + 4].copy_from_slice(&v.to_le_bytes());
                }
            }
        }
    }
    if rng.chance(50) {
        // Keep the CRC right so the mutation gets past it to the payload checks.
        if buf.len() >= 3 && rng.chance(50) {
            let n = buf.len() as u16;
            buf[1..3].copy_from_slice(&n.to_le_bytes());
        }
        reseal(buf);
    }
}

#[derive(Default, Debug)]
struct Tally {
    accepted: u64,
    too_short: u64,
    length_mismatch: u64,
    version: u64,
    unknown_data_type: u64,
    dot_count: u64,
    crc: u64,
    non_finite: u64,
}

impl Tally {
    fn record(&mut self, r: &Result<Packet<'_>, LivoxError>) {
        let c = match r {
            Ok(_) => &mut self.accepted,
            Err(LivoxError::TooShort { .. }) => &mut self.too_short,
            Err(LivoxError::LengthMismatch { .. }) => &mut self.length_mismatch,
            Err(LivoxError::Version(_)) => &mut self.version,
            Err(LivoxError::UnknownDataType(_)) => &mut self.unknown_data_type,
            Err(LivoxError::DotCountMismatch { .. }) => &mut self.dot_count,
            Err(LivoxError::Crc { .. }) => &mut self.crc,
            Err(LivoxError::NonFinite { .. }) => &mut self.non_finite,
            Err(e) => panic!("decoder returned an encoder error: {e}"),
        };
        *c += 1;
    }
}

#[test]
fn mutation_fuzz_smoke() {
    let inputs: u64 = std::env::var("LIVOX_FUZZ_INPUTS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(if cfg!(debug_assertions) { 20_000 } else { 200_000 });
    let mut rng = Rng(0x5EED_1234_ABCD_0001);
    let seeds = seeds(&mut rng);
    for s in &seeds {
        decode_packet(s).expect("seed packet decodes");
        fuzz_livox(s);
    }
    fuzz_livox(&seeds.concat());

    let start = Instant::now();
    let mut tally = Tally::default();
    let mut buf = Vec::with_capacity(4096);
    for _ in 0..inputs {
        mutate(&mut rng, &seeds, &mut buf);
        tally.record(&decode_packet(&buf));
        fuzz_livox(&buf);
    }
    let secs = start.elapsed().as_secs_f64();
    println!(
        "livox fuzz smoke: {inputs} inputs in {secs:.2} s ({:.0}/s); {tally:?}",
        inputs as f64 / secs
    );

    // The unmutated packets still decode, to the same points.
    for s in &seeds {
        let p = decode_packet(s).expect("seed packet decodes after fuzzing");
        assert_eq!(
            p.points().len(),
            if p.is_points() { p.header.dot_num as usize } else { 0 }
        );
    }
    // The mutator reaches every check (at this input count), including those behind the CRC.
    if inputs >= 20_000 {
        let t = &tally;
        for (name, n) in [
            ("accepted", t.accepted),
            ("too_short", t.too_short),
            ("length_mismatch", t.length_mismatch),
            ("version", t.version),
            ("unknown_data_type", t.unknown_data_type),
            ("dot_count", t.dot_count),
            ("crc", t.crc),
            ("non_finite", t.non_finite),
        ] {
            assert!(n > 0, "no input ended as {name}: {tally:?}");
        }
        assert!(
            t.accepted * 20 > inputs,
            "too few valid inputs to exercise the assembler: {tally:?}"
        );
    }
    if !cfg!(debug_assertions) {
        assert!(secs < 30.0, "fuzz smoke took {secs:.1} s");
    }
}
