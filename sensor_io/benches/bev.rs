//! Per-frame perception cost: BEV grid from a 20,000-point lidar frame (target ≤ 200 µs) against
//! the straightforward alternatives (per-cell `Vec`s as in the reference test, a `HashMap` of
//! cells), and decoding one frame of MID-360 packets (20,000 points, 96 per packet).
// Benchmark inputs come from std's math on the host; this never runs on the robot.
#![allow(clippy::disallowed_methods)]
use std::collections::HashMap;
use std::time::{Duration, Instant};

use criterion::{black_box, criterion_group, criterion_main, Criterion};
use hal::{LidarPoint, XorShift64 as Rng};
use sensor_io::bev::*;
use sensor_io::livox::*;

const N: usize = 20_000;

/// Stairs ahead: 0.15 m risers every 0.3 m from x = 0.5 m, eight steps, flat floor elsewhere.
fn stairs(x: f32) -> f32 {
    if x < 0.5 {
        0.0
    } else {
        0.15 * ((x - 0.5) / 0.3 + 1.0).floor().min(8.0)
    }
}

fn frame() -> RobotFrame {
    RobotFrame::new(&MountPose::G1_MID360_DEFAULT, 0.02, -0.03, 0.75)
}

/// A lidar-like frame in the sensor frame: rings of returns around the robot on the staircase
/// heightfield (denser near the robot), a few off the robot's own legs, a few far walls.
fn cloud() -> Vec<LidarPoint> {
    let f = frame();
    let mut rng = Rng(0x1DA1_25EE);
    (0..N)
        .map(|i| {
            let theta = rng.unit() * std::f32::consts::TAU;
            let robot = match i % 20 {
                0 => [0.1 * theta.cos(), 0.15 * theta.sin(), 0.3 * rng.unit()], // own legs
                1 => [4.0 * theta.cos(), 4.0 * theta.sin(), 2.0 * rng.unit()],  // walls
                _ => {
                    let ring = (i % 16) as f32;
                    let r = 0.35 + 0.14 * ring + 0.05 * rng.unit();
                    let (x, y) = (r * theta.cos(), r * theta.sin());
                    [x, y, stairs(x) + 0.01 * (rng.unit() - 0.5)]
                }
            };
            // Back into the sensor frame: p_s = Rᵀ (p − t).
            let d = [robot[0] - f.trans[0], robot[1] - f.trans[1], robot[2] - f.trans[2]];
            let xyz = core::array::from_fn(|k| f.rot[0][k] * d[0] + f.rot[1][k] * d[1] + f.rot[2][k] * d[2]);
            LidarPoint {
                xyz,
                reflectivity: 20,
                tag: 0,
                offset_ns: i as u32 * 5_000,
            }
        })
        .collect()
}

/// The reference test's implementation: per-cell `Vec<f64>`, two-pass mean and std.
fn reference_bev(points: &[LidarPoint], f: &RobotFrame, filter: &SelfFilter) -> Vec<f32> {
    let mut cells: Vec<Vec<f64>> = vec![Vec::new(); BEV_CELLS * BEV_CELLS];
    for p in points {
        let q = f.apply(p.xyz);
        if !q.iter().all(|v| v.is_finite()) || filter.contains(q) {
            continue;
        }
        if let Some((ix, iy)) = BevGrid::cell_of(q[0], q[1]) {
            cells[ix * BEV_CELLS + iy].push(q[2] as f64);
        }
    }
    let fullest = cells.iter().map(|c| c.len()).max().unwrap_or(0);
    let mut out = vec![0.0f32; BEV_LEN];
    for (c, zs) in cells.iter().enumerate() {
        if zs.is_empty() {
            continue;
        }
        let n = zs.len() as f64;
        let max = zs.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
        let min = zs.iter().cloned().fold(f64::INFINITY, f64::min);
        let mean = zs.iter().sum::<f64>() / n;
        let var = zs.iter().map(|z| (z - mean) * (z - mean)).sum::<f64>() / n;
        for (ch, v) in [max, min, mean, max - min, var.sqrt(), n / fullest as f64]
            .iter()
            .enumerate()
        {
            out[ch * BEV_CELLS * BEV_CELLS + c] = *v as f32;
        }
    }
    out
}

/// The other obvious way: a hash map from cell to its heights.
fn hashmap_bev(points: &[LidarPoint], f: &RobotFrame, filter: &SelfFilter) -> Vec<f32> {
    let mut cells: HashMap<(usize, usize), Vec<f32>> = HashMap::new();
    for p in points {
        let q = f.apply(p.xyz);
        if !q.iter().all(|v| v.is_finite()) || filter.contains(q) {
            continue;
        }
        if let Some(cell) = BevGrid::cell_of(q[0], q[1]) {
            cells.entry(cell).or_default().push(q[2]);
        }
    }
    let fullest = cells.values().map(|c| c.len()).max().unwrap_or(0);
    let mut out = vec![0.0f32; BEV_LEN];
    for (&(ix, iy), zs) in &cells {
        let n = zs.len() as f64;
        let max = zs.iter().cloned().fold(f32::NEG_INFINITY, f32::max);
        let min = zs.iter().cloned().fold(f32::INFINITY, f32::min);
        let mean = zs.iter().map(|&z| z as f64).sum::<f64>() / n;
        let var = zs.iter().map(|&z| (z as f64 - mean).powi(2)).sum::<f64>() / n;
        let vals = [
            max,
            min,
            mean as f32,
            max - min,
            var.sqrt() as f32,
            (n / fullest as f64) as f32,
        ];
        for (ch, v) in vals.iter().enumerate() {
            out[BevGrid::index(ch, ix, iy)] = *v;
        }
    }
    out
}

/// Fastest and median time per call over `reps` calls (on a busy machine the fastest is the better
/// estimate of the uncontended cost).
fn timings(reps: usize, mut f: impl FnMut()) -> (Duration, Duration) {
    let mut t: Vec<Duration> = (0..reps)
        .map(|_| {
            let s = Instant::now();
            f();
            s.elapsed()
        })
        .collect();
    t.sort();
    (t[0], t[reps / 2])
}

fn us(d: Duration) -> f64 {
    d.as_secs_f64() * 1e6
}

fn bench(c: &mut Criterion) {
    let points = cloud();
    let f = frame();
    let filter = SelfFilter::G1_DEFAULT;
    let mut builder = BevBuilder::new_boxed();
    let mut grid = Box::new(BevGrid::zeroed());

    let stats = builder.build(&points, &f, &filter, &mut grid);
    let want = reference_bev(&points, &f, &filter);
    let worst = grid
        .data
        .iter()
        .zip(&want)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f32::max);
    assert!(worst <= 1e-5, "builder and reference differ by {worst}");
    let inside = stats.used + stats.self_hits;
    println!(
        "cloud: {N} points, {:.0} % inside the window ({} used, {} self hits, {} outside), {} cells occupied",
        100.0 * inside as f64 / N as f64,
        stats.used,
        stats.self_hits,
        stats.outside,
        (0..BEV_CELLS * BEV_CELLS)
            .filter(|&i| grid.data[CH_DENSITY * BEV_CELLS * BEV_CELLS + i] > 0.0)
            .count()
    );

    c.bench_function("bev_build_20k", |b| {
        b.iter(|| builder.build(black_box(&points), &f, &filter, &mut grid))
    });
    c.bench_function("bev_reference_vecs_20k", |b| {
        b.iter(|| reference_bev(black_box(&points), &f, &filter))
    });
    c.bench_function("bev_hashmap_20k", |b| {
        b.iter(|| hashmap_bev(black_box(&points), &f, &filter))
    });

    let ours = timings(300, || {
        builder.build(black_box(&points), &f, &filter, &mut grid);
    });
    let vecs = timings(100, || {
        black_box(reference_bev(black_box(&points), &f, &filter));
    });
    let hash = timings(100, || {
        black_box(hashmap_bev(black_box(&points), &f, &filter));
    });
    println!(
        "BEV per frame, fastest / median: builder {:.1} / {:.1} µs; per-cell Vecs {:.1} / {:.1} µs ({:.1}x \
         by fastest); HashMap {:.1} / {:.1} µs ({:.1}x)",
        us(ours.0),
        us(ours.1),
        us(vecs.0),
        us(vecs.1),
        us(vecs.0) / us(ours.0),
        us(hash.0),
        us(hash.1),
        us(hash.0) / us(ours.0)
    );

    // The BEV memory: the same frame gridded with 4 keyframes of it taken 0.3 m apart on the
    // approach (the firmware's default), against the single-frame build from robot points.
    let robot: Vec<[f32; 3]> = points
        .iter()
        .map(|p| f.apply(p.xyz))
        .filter(|q| !filter.contains(*q))
        .collect();
    let mut memory = sensor_io::bev_memory::BevMemory::new(sensor_io::bev_memory::MemoryConfig::DEFAULT, N);
    let at = |x: f32| sensor_io::bev_memory::OdomPose {
        pos: [x, 0.0, 0.75],
        yaw: 0.0,
        height: 0.75,
    };
    for k in 0..4 {
        memory.remember(&robot, &at(-1.2 + 0.3 * k as f32));
    }
    let (_, m) = memory.build(&robot, &at(0.0), &mut builder, &mut grid);
    let single = timings(300, || {
        builder.build_robot_points(black_box(&robot), &mut grid);
    });
    let merged = timings(300, || {
        memory.build(black_box(&robot), &at(0.0), &mut builder, &mut grid);
    });
    println!(
        "BEV with memory ({} keyframes, {} remembered points used), fastest / median: {:.1} / {:.1} µs vs \
         single frame {:.1} / {:.1} µs ({:.2}x by fastest)",
        m.keyframes,
        m.points_used,
        us(merged.0),
        us(merged.1),
        us(single.0),
        us(single.1),
        us(merged.0) / us(single.0)
    );

    // One frame of packets as the sensor sends it.
    let mut writer = PacketWriter::new();
    let mut buf = vec![0u8; writer.max_packet_len()];
    let mut packets: Vec<Vec<u8>> = Vec::new();
    writer
        .write_frame(&points, 1_000_000_000, &mut buf, |p| packets.push(p.to_vec()))
        .unwrap();
    // The next frame's first packet closes this one, as in a stream.
    let mut next: Vec<Vec<u8>> = Vec::new();
    writer
        .write_frame(&points[..96], 1_100_000_000, &mut buf, |p| next.push(p.to_vec()))
        .unwrap();
    let bytes: usize = packets.iter().map(|p| p.len()).sum();
    println!("frame: {} packets, {bytes} bytes", packets.len());
    let mut asm = FrameAssembler::<32_768>::new_boxed();
    c.bench_function("livox_assemble_frame_20k", |b| {
        b.iter(|| {
            for p in &packets {
                let _ = asm.push(black_box(p));
            }
            asm.flush().map(|f| f.len)
        })
    });
    c.bench_function("livox_decode_packets_20k", |b| {
        b.iter(|| {
            let mut s = 0.0f32;
            for p in &packets {
                for q in decode_packet(black_box(p)).unwrap().points() {
                    s += q.xyz[2];
                }
            }
            s
        })
    });
    c.bench_function("livox_crc_frame_20k", |b| {
        b.iter(|| packets.iter().fold(0u32, |a, p| a ^ crc32(black_box(&p[28..]))))
    });
    c.bench_function("livox_crc_frame_20k_table", |b| {
        b.iter(|| packets.iter().fold(0u32, |a, p| a ^ crc32_table(black_box(&p[28..]))))
    });
    let assemble = timings(300, || {
        for p in &packets {
            let _ = asm.push(black_box(p));
        }
        black_box(asm.flush().map(|f| f.len));
    });
    let decode = timings(300, || {
        let mut s = 0.0f32;
        for p in &packets {
            for q in decode_packet(black_box(p)).unwrap().points() {
                s += q.xyz[2];
            }
        }
        black_box(s);
    });
    let crc_fast = timings(300, || {
        black_box(packets.iter().fold(0u32, |a, p| a ^ crc32(black_box(&p[28..]))));
    });
    let crc_table = timings(300, || {
        black_box(packets.iter().fold(0u32, |a, p| a ^ crc32_table(black_box(&p[28..]))));
    });
    println!(
        "one 20k-point frame ({} packets), fastest / median: assemble {:.1} / {:.1} µs, decode {:.1} / {:.1} µs",
        packets.len(),
        us(assemble.0),
        us(assemble.1),
        us(decode.0),
        us(decode.1)
    );
    println!(
        "CRC-32 of the frame's packets, median: crc32fast {:.1} µs vs slicing-by-16 table {:.1} µs = {:.1}x",
        us(crc_fast.1),
        us(crc_table.1),
        crc_table.1.as_secs_f64() / crc_fast.1.as_secs_f64()
    );
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(30).measurement_time(Duration::from_secs(3));
    targets = bench
}
criterion_main!(benches);
