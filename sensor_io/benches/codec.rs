//! Codec cost per control tick: table CRC versus the SDK's bit-serial CRC, and full encode/decode.
use criterion::{black_box, criterion_group, criterion_main, Criterion};
use hal::{LowCommand, LowState};
use sensor_io::unitree_hg::*;

fn bitwise_crc(bytes: &[u8]) -> u32 {
    let mut crc = 0xFFFF_FFFFu32;
    for w in bytes.chunks_exact(4) {
        let data = u32::from_le_bytes([w[0], w[1], w[2], w[3]]);
        for bit in (0..32).rev() {
            let top = crc & 0x8000_0000 != 0;
            crc <<= 1;
            if top ^ (data >> bit & 1 != 0) {
                crc ^= 0x04C1_1DB7;
            }
        }
    }
    crc
}

fn bench(c: &mut Criterion) {
    let mut sb = [0u8; LOW_STATE_LEN];
    encode_low_state(&LowState::default(), &mut sb);
    c.bench_function("crc_table_lowstate", |b| {
        b.iter(|| crc32_words(black_box(&sb[..LOW_STATE_LEN - 4])))
    });
    c.bench_function("crc_bitwise_lowstate", |b| {
        b.iter(|| bitwise_crc(black_box(&sb[..LOW_STATE_LEN - 4])))
    });
    let mut out = LowState::default();
    c.bench_function("decode_low_state", |b| {
        b.iter(|| decode_low_state(black_box(&sb), &mut out))
    });
    let cmd = LowCommand::default();
    let mut cb = [0u8; LOW_CMD_LEN];
    c.bench_function("encode_low_cmd", |b| {
        b.iter(|| encode_low_cmd(black_box(&cmd), &mut cb))
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
