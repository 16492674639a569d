//! Geometric terrain estimator cost per BEV grid.
//! `cargo bench -p estimator --bench terrain`; prints the median µs per grid for flat ground, stairs
//! up ahead and stairs at 30°.
// Benchmark inputs come from std's math on the host; this never runs on the robot.
#![allow(clippy::disallowed_methods)]
use std::hint::black_box;
use std::time::Instant;

use estimator::terrain::{GeometricTerrainConfig, GeometricTerrainEstimator};
use sensor_io::bev::{BevGrid, BEV_CELLS, CH_DENSITY, CH_MAX, CH_MEAN, CH_MIN, CH_RANGE, CH_STD};

/// A grid as the lidar sees a staircase (h, d, travel angle `dir` in the robot frame, first riser
/// `s0` ahead): the ring 0.9 m .. window edge occupied, cell means with ~1 cm noise.
fn stair_grid(h: f32, d: f32, dir: f32, s0: f32) -> Box<BevGrid> {
    let mut g = Box::new(BevGrid::zeroed());
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let (c, s) = (dir.cos(), dir.sin());
    for ix in 0..BEV_CELLS {
        for iy in 0..BEV_CELLS {
            let (x, y) = BevGrid::cell_center(ix, iy);
            if (x * x + y * y).sqrt() < 0.9 {
                continue;
            }
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let noise = ((state >> 40) as f32 / (1u64 << 24) as f32 - 0.5) * 0.035;
            let u = x * c + y * s;
            let z = if h > 0.0 && u >= s0 {
                h * (((u - s0) / d).floor() + 1.0)
            } else {
                0.0
            } + noise;
            g.data[BevGrid::index(CH_MAX, ix, iy)] = z + 0.01;
            g.data[BevGrid::index(CH_MIN, ix, iy)] = z - 0.01;
            g.data[BevGrid::index(CH_MEAN, ix, iy)] = z;
            g.data[BevGrid::index(CH_RANGE, ix, iy)] = 0.02;
            g.data[BevGrid::index(CH_STD, ix, iy)] = 0.01;
            g.data[BevGrid::index(CH_DENSITY, ix, iy)] = 0.5;
        }
    }
    g
}

fn main() {
    let mut est = GeometricTerrainEstimator::new(GeometricTerrainConfig::default());
    let cases = [
        ("flat", stair_grid(0.0, 0.3, 0.0, 0.0)),
        ("stairs up 0 deg", stair_grid(0.15, 0.3, 0.0, 0.5)),
        ("stairs up 30 deg", stair_grid(0.15, 0.3, 30f32.to_radians(), 0.5)),
    ];
    for (name, grid) in &cases {
        let reps = 31;
        let n = 20;
        let mut v: Vec<f64> = (0..reps)
            .map(|_| {
                let t = Instant::now();
                for _ in 0..n {
                    black_box(est.estimate(black_box(grid)));
                }
                t.elapsed().as_secs_f64() * 1e6 / n as f64
            })
            .collect();
        v.sort_by(f64::total_cmp);
        let e = est.estimate(grid);
        println!(
            "{name:>18}: {:8.1} µs/grid (median of {reps}×{n}); {} cells, token {:?}",
            v[reps / 2],
            e.cells_used,
            e.token
        );
    }
}
