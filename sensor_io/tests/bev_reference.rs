//! `BevBuilder` against a plain, obviously correct BEV (per-cell lists of heights, two-pass mean
//! and std), plus analytic cases: flat floor, a step edge, frame transforms and the self filter.
// Test inputs come from std's math on the host; this never runs on the robot.
#![allow(clippy::disallowed_methods)]
use hal::{LidarPoint, XorShift64 as Rng};
use sensor_io::bev::*;

/// The reference: collect every point's height per cell, then compute each channel directly.
fn reference_bev(points_robot: &[[f32; 3]]) -> Vec<f32> {
    let mut cells: Vec<Vec<f64>> = vec![Vec::new(); BEV_CELLS * BEV_CELLS];
    for p in points_robot {
        if !p.iter().all(|v| v.is_finite()) {
            continue;
        }
        // The layout's formula, spelled out (independently of `BevGrid::cell_of`).
        let ix = ((p[0] + 1.5) / 0.05).floor();
        let iy = ((p[1] + 1.5) / 0.05).floor();
        if (0.0..60.0).contains(&ix) && (0.0..60.0).contains(&iy) {
            cells[ix as usize * BEV_CELLS + iy as usize].push(p[2] as f64);
        }
    }
    let fullest = cells.iter().map(|c| c.len()).max().unwrap_or(0);
    let mut out = vec![0.0f32; BEV_LEN];
    for ix in 0..BEV_CELLS {
        for iy in 0..BEV_CELLS {
            let zs = &cells[ix * BEV_CELLS + iy];
            if zs.is_empty() {
                continue;
            }
            let n = zs.len() as f64;
            let max = zs.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
            let min = zs.iter().cloned().fold(f64::INFINITY, f64::min);
            let mean = zs.iter().sum::<f64>() / n;
            let var = zs.iter().map(|z| (z - mean) * (z - mean)).sum::<f64>() / n;
            let vals = [max, min, mean, max - min, var.sqrt(), n / fullest as f64];
            for (ch, v) in vals.iter().enumerate() {
                out[BevGrid::index(ch, ix, iy)] = *v as f32;
            }
        }
    }
    out
}

fn grid() -> Box<BevGrid> {
    Box::new(BevGrid::zeroed())
}

fn assert_close(got: &[f32], want: &[f32], tol: f32) {
    assert_eq!(got.len(), want.len());
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        let (ch, cell) = (i / (BEV_CELLS * BEV_CELLS), i % (BEV_CELLS * BEV_CELLS));
        assert!(
            (g - w).abs() <= tol,
            "{} at cell ({}, {}): builder {g}, reference {w}",
            CHANNEL_NAMES[ch],
            cell / BEV_CELLS,
            cell % BEV_CELLS
        );
    }
}

fn random_cloud(rng: &mut Rng, n: usize) -> Vec<[f32; 3]> {
    let mut pts = Vec::with_capacity(n);
    for i in 0..n {
        let p = match i % 10 {
            // Exactly on cell borders (as the grid computes them) and on the window's edges.
            0 => {
                let kx = (self_u(rng) % 61) as f32;
                let ky = (self_u(rng) % 61) as f32;
                [
                    kx * BEV_CELL_M - BEV_HALF_EXTENT_M,
                    ky * BEV_CELL_M - BEV_HALF_EXTENT_M,
                    rng.range(-0.3, 1.0),
                ]
            }
            // Outside the window.
            1 => [rng.range(1.5, 4.0), rng.range(-4.0, 4.0), rng.range(-1.0, 1.0)],
            2 if i % 40 == 2 => [f32::NAN, 0.2, 0.1],
            3 if i % 40 == 3 => [0.2, 0.3, f32::INFINITY],
            // Clustered so some cells hold many points.
            4 => [rng.range(0.5, 0.6), rng.range(-0.1, 0.0), rng.range(0.0, 0.3)],
            _ => [rng.range(-1.6, 1.6), rng.range(-1.6, 1.6), rng.range(-0.5, 1.5)],
        };
        pts.push(p);
    }
    pts
}

fn self_u(rng: &mut Rng) -> u64 {
    rng.next_u64() >> 32
}

#[test]
fn random_clouds_match_the_reference() {
    let mut rng = Rng(0xBEEF_0000_0000_0001);
    let mut b = BevBuilder::new_boxed();
    let mut out = grid();
    for (round, n) in [0usize, 1, 10, 500, 5_000, 20_000].into_iter().enumerate() {
        let pts = random_cloud(&mut rng, n);
        let stats = b.build_robot_points(&pts, &mut out);
        let want = reference_bev(&pts);
        assert_close(&out.data, &want, 1e-5);
        let non_finite = pts.iter().filter(|p| !p.iter().all(|v| v.is_finite())).count();
        let used = pts
            .iter()
            .filter(|p| p.iter().all(|v| v.is_finite()) && BevGrid::cell_of(p[0], p[1]).is_some())
            .count();
        assert_eq!(
            stats,
            BevStats {
                input: n,
                used,
                self_hits: 0,
                outside: n - used - non_finite,
                non_finite
            },
            "round {round}"
        );
        if used > 0 {
            let dmax = out.data[CH_DENSITY * 3600..].iter().cloned().fold(0.0, f32::max);
            assert_eq!(dmax, 1.0);
        }
    }
}

#[test]
fn sensor_frame_build_matches_reference_on_transformed_points() {
    let mut rng = Rng(42);
    let frame = RobotFrame::new(&MountPose::G1_MID360_DEFAULT, 0.05, -0.08, 0.78);
    let filter = SelfFilter::G1_DEFAULT;
    let points: Vec<LidarPoint> = (0..20_000)
        .map(|i| LidarPoint {
            xyz: if i % 997 == 0 {
                [f32::NAN, 0.0, 0.0]
            } else {
                [rng.range(-2.5, 2.5), rng.range(-2.5, 2.5), rng.range(0.0, 1.5)]
            },
            ..LidarPoint::default()
        })
        .collect();
    let mut b = BevBuilder::new_boxed();
    let mut out = grid();
    let stats = b.build(&points, &frame, &filter, &mut out);
    let robot: Vec<[f32; 3]> = points.iter().map(|p| frame.apply(p.xyz)).collect();
    let kept: Vec<[f32; 3]> = robot.iter().copied().filter(|q| !filter.contains(*q)).collect();
    assert_close(&out.data, &reference_bev(&kept), 1e-5);
    let non_finite = robot.iter().filter(|q| !q.iter().all(|v| v.is_finite())).count();
    assert_eq!(non_finite, 21);
    assert_eq!(stats.input, 20_000);
    assert_eq!(stats.non_finite, non_finite);
    assert!(stats.self_hits > 0 && stats.outside > 0 && stats.used > 0);
    assert_eq!(
        stats.used + stats.self_hits + stats.outside + stats.non_finite,
        stats.input
    );
}

#[test]
fn empty_cloud_and_empty_cells_are_exactly_zero() {
    let mut b = BevBuilder::new_boxed();
    let mut out = grid();
    out.data.fill(7.0);
    let s = b.build_robot_points(&[], &mut out);
    assert_eq!(s, BevStats::default());
    assert!(out.data.iter().all(|&v| v == 0.0));
    // One point: one cell set, every other value exactly 0 (also after a fuller build).
    b.build_robot_points(&random_cloud(&mut Rng(5), 1000), &mut out);
    b.build_robot_points(&[[0.01, 0.01, -0.2]], &mut out);
    let (ix, iy) = BevGrid::cell_of(0.01, 0.01).unwrap();
    assert_eq!((ix, iy), (30, 30));
    for (ch, name) in CHANNEL_NAMES.iter().enumerate() {
        for x in 0..BEV_CELLS {
            for y in 0..BEV_CELLS {
                let v = out.get(ch, x, y);
                if (x, y) != (ix, iy) {
                    assert_eq!(v.to_bits(), 0, "{name} ({x}, {y})");
                }
            }
        }
    }
    let got: Vec<f32> = (0..BEV_CHANNELS).map(|ch| out.get(ch, ix, iy)).collect();
    assert_eq!(got, [-0.2, -0.2, -0.2, 0.0, 0.0, 1.0]);
}

fn lattice(step: f32, z: impl Fn(f32, f32) -> f32) -> Vec<[f32; 3]> {
    let n = (3.0 / step) as i32;
    let mut pts = Vec::new();
    for i in 0..n {
        for j in 0..n {
            let x = (-1.5 + (i as f64 + 0.5) * step as f64) as f32;
            let y = (-1.5 + (j as f64 + 0.5) * step as f64) as f32;
            pts.push([x, y, z(x, y)]);
        }
    }
    pts
}

#[test]
fn flat_floor_is_flat() {
    let pts = lattice(0.01, |_, _| 0.0);
    let mut b = BevBuilder::new_boxed();
    let mut out = grid();
    let s = b.build_robot_points(&pts, &mut out);
    assert_eq!(s.used, pts.len());
    for ix in 0..BEV_CELLS {
        for iy in 0..BEV_CELLS {
            assert!(out.occupied(ix, iy));
            for ch in [CH_MAX, CH_MIN, CH_MEAN, CH_RANGE, CH_STD] {
                assert_eq!(out.get(ch, ix, iy), 0.0);
            }
        }
    }
}

/// Step from z = 0 to z = 0.15 at x = `edge`; returns the rows straddling the edge.
fn check_step(edge: f32) -> Vec<usize> {
    let pts = lattice(0.005, |x, _| if x < edge { 0.0 } else { 0.15 });
    let mut b = BevBuilder::new_boxed();
    let mut out = grid();
    b.build_robot_points(&pts, &mut out);
    let mut straddling = Vec::new();
    for ix in 0..BEV_CELLS {
        let (cx, _) = BevGrid::cell_center(ix, 0);
        let row: Vec<[f32; 6]> = (0..BEV_CELLS)
            .map(|iy| core::array::from_fn(|ch| out.get(ch, ix, iy)))
            .collect();
        assert!(row.iter().all(|c| *c == row[0]), "row {ix} not uniform across y");
        let [max, min, mean, range, std, _] = row[0];
        if min == 0.0 && max == 0.15 {
            assert_eq!(range, 0.15);
            assert!(mean > 0.0 && mean < 0.15 && std > 0.0);
            straddling.push(ix);
        } else {
            let want = if cx < edge { 0.0 } else { 0.15 };
            assert_eq!((max, min, mean, range), (want, want, want, 0.0), "row {ix} centre {cx}");
            assert!(std < 1e-6);
        }
    }
    assert!(straddling.len() <= 1);
    straddling
}

#[test]
fn step_edge_lands_in_the_expected_rows() {
    // On a cell border (row 42 starts at x = 0.6): no row straddles it.
    assert_eq!(check_step(0.6), Vec::<usize>::new());
    // Through the middle of row 42 ([0.6, 0.65)): that row has both heights.
    assert_eq!(check_step(0.625), vec![42]);
}

fn close3(a: [f32; 3], b: [f32; 3], tol: f32) -> bool {
    (0..3).all(|k| (a[k] - b[k]).abs() <= tol)
}

#[test]
fn robot_frame_rotates_and_translates() {
    let id = MountPose::IDENTITY;
    let f = RobotFrame::new(&id, 0.0, 0.0, 0.0);
    assert_eq!(f.apply([1.0, 2.0, 3.0]), [1.0, 2.0, 3.0]);
    // Roll about x: y tips towards z.
    let f = RobotFrame::new(&id, 0.3, 0.0, 0.5);
    assert!(close3(
        f.apply([0.0, 1.0, 0.0]),
        [0.0, 0.3f32.cos(), 0.3f32.sin() + 0.5],
        1e-6
    ));
    // Pitch about y: nose-down pitch (positive) sends x downwards.
    let f = RobotFrame::new(&id, 0.0, 0.2, 0.0);
    assert!(close3(
        f.apply([1.0, 0.0, 0.0]),
        [0.2f32.cos(), 0.0, -(0.2f32.sin())],
        1e-6
    ));
    // Roll then pitch: Ry(p)·Rx(r).
    let f = RobotFrame::new(&id, 0.3, 0.2, 0.0);
    let (sr, cr, sp, cp) = (0.3f32.sin(), 0.3f32.cos(), 0.2f32.sin(), 0.2f32.cos());
    assert!(close3(f.apply([0.0, 1.0, 0.0]), [sp * sr, cr, cp * sr], 1e-6));
    // The mount's translation is rotated with the base, then lifted by the base height.
    let m = MountPose {
        xyz: [0.1, 0.0, 0.4],
        rpy: [0.0; 3],
    };
    let f = RobotFrame::new(&m, 0.0, 0.0, 0.7);
    assert!(close3(f.apply([0.0; 3]), [0.1, 0.0, 1.1], 1e-6));
    let f = RobotFrame::new(&m, 0.0, 0.1, 0.0);
    let want = [
        0.1 * 0.1f32.cos() + 0.4 * 0.1f32.sin(),
        0.0,
        -0.1 * 0.1f32.sin() + 0.4 * 0.1f32.cos(),
    ];
    assert!(close3(f.apply([0.0; 3]), want, 1e-6));
    // Mount yaw turns sensor x into robot y.
    let m = MountPose {
        xyz: [0.0; 3],
        rpy: [0.0, 0.0, core::f32::consts::FRAC_PI_2],
    };
    assert!(close3(
        RobotFrame::new(&m, 0.0, 0.0, 0.0).apply([1.0, 0.0, 0.0]),
        [0.0, 1.0, 0.0],
        1e-6
    ));
}

#[test]
fn g1_mid360_looks_down_when_mounted_upside_down() {
    let f = RobotFrame::new(&MountPose::G1_MID360_DEFAULT, 0.0, 0.0, 0.75);
    let origin = f.apply([0.0; 3]);
    assert!(close3(origin, [-0.00368, 0.00003, 0.75 + 0.472434], 1e-6));
    // Sensor +z (its "up", upside down) points down in the robot frame, tilted by the 0.0511 pitch.
    let d = f.apply([0.0, 0.0, 1.0]);
    let dir = [d[0] - origin[0], d[1] - origin[1], d[2] - origin[2]];
    assert!(dir[2] < -0.99, "{dir:?}");
    assert!(close3(dir, [-(0.0511f32.sin()), 0.0, -(0.0511f32.cos())], 1e-5));
    // Sensor +y flips to robot −y (roll π), sensor +x stays forward.
    let y = f.apply([0.0, 1.0, 0.0]);
    assert!(y[1] - origin[1] < -0.99);
    let x = f.apply([1.0, 0.0, 0.0]);
    assert!(x[0] - origin[0] > 0.99);
    // A floor point 2 m ahead and 1 m below the sensor, seen upside down, lands at z ≈ 0.
    let seen = [2.0, 0.0, 1.0 + 0.472434 + 0.75 - 1.0]; // sensor +z is down
    let floor_z = f.apply(seen)[2];
    assert!(floor_z.abs() < 0.15, "{floor_z}");
}

#[test]
fn self_filter_drops_the_robots_body() {
    let filter = SelfFilter::G1_DEFAULT;
    assert_eq!(filter.boxes().len(), 1);
    assert!(filter.contains([0.0, 0.0, 0.5]));
    assert!(filter.contains([0.35, -0.40, 2.5]));
    assert!(!filter.contains([0.36, 0.0, 0.5]));
    assert!(!filter.contains([f32::NAN, 0.0, 0.0]));
    assert_eq!(filter.classify([0.0, 0.0, 0.5]), PointClass::SelfHit);
    assert_eq!(filter.classify([0.5, 0.0, 0.1]), PointClass::Terrain);
    assert_eq!(filter.classify([0.0, f32::INFINITY, 0.1]), PointClass::NonFinite);
    // A NaN inside the body box is non-finite first, as `BevStats` counts it.
    assert_eq!(filter.classify([0.0, 0.0, f32::NAN]), PointClass::NonFinite);
    assert_eq!(SelfFilter::NONE.classify([0.0, 0.0, 0.5]), PointClass::Terrain);
    let frame = RobotFrame::new(&MountPose::IDENTITY, 0.0, 0.0, 0.0);
    let pts: Vec<LidarPoint> = [
        [0.1, 0.1, 0.3],
        [-0.3, 0.39, 1.0],
        [0.5, 0.0, 0.1],
        [0.0, 0.6, 0.0],
        [9.0, 0.0, 0.0],
    ]
    .iter()
    .map(|&xyz| LidarPoint {
        xyz,
        ..LidarPoint::default()
    })
    .collect();
    let mut b = BevBuilder::new_boxed();
    let mut out = grid();
    let s = b.build(&pts, &frame, &filter, &mut out);
    assert_eq!(
        s,
        BevStats {
            input: 5,
            used: 2,
            self_hits: 2,
            outside: 1,
            non_finite: 0
        }
    );
    let (ix, iy) = BevGrid::cell_of(0.1, 0.1).unwrap();
    assert!(!out.occupied(ix, iy));
    let (ix, iy) = BevGrid::cell_of(0.5, 0.0).unwrap();
    assert!(out.occupied(ix, iy));
    assert_eq!(out.get(CH_MAX, ix, iy), 0.1);
    // With no filter the body points count.
    let s = b.build(&pts, &frame, &SelfFilter::NONE, &mut out);
    assert_eq!((s.used, s.self_hits), (4, 0));

    // Construction checks.
    let ok = Aabb {
        min: [0.0; 3],
        max: [1.0; 3],
    };
    assert_eq!(SelfFilter::new(&[ok; 8]).unwrap().boxes().len(), 8);
    assert_eq!(
        SelfFilter::new(&[ok; 9]).unwrap_err(),
        BevError::TooManyBoxes { count: 9 }
    );
    let inverted = Aabb {
        min: [0.0, 1.0, 0.0],
        max: [1.0, 0.5, 1.0],
    };
    assert_eq!(
        SelfFilter::new(&[ok, inverted]).unwrap_err(),
        BevError::InvalidBox { index: 1 }
    );
    let nan = Aabb {
        min: [f32::NAN, 0.0, 0.0],
        max: [1.0; 3],
    };
    assert_eq!(SelfFilter::new(&[nan]).unwrap_err(), BevError::InvalidBox { index: 0 });
    let two = SelfFilter::new(&[
        ok,
        Aabb {
            min: [-2.0; 3],
            max: [-1.0; 3],
        },
    ])
    .unwrap();
    assert!(two.contains([-1.5; 3]) && two.contains([0.5; 3]) && !two.contains([-0.5; 3]));
}

/// With the waist at zero the torso chain is the fixed mount, bit for bit (logs recorded before
/// the chain replay unchanged); a waist angle moves the points.
#[test]
fn waist_at_zero_is_the_fixed_mount_bit_for_bit() {
    use sensor_io::bev::WaistChain;
    let m = MountPose::G1_MID360_DEFAULT;
    let p = [1.3, -0.4, 0.2];
    let fixed = RobotFrame::new(&m, 0.04, -0.07, 0.75);
    let chained = RobotFrame::on_waist(&m, &WaistChain::G1, [0.0; 3], 0.04, -0.07, 0.75);
    assert_eq!(fixed, chained);
    let rolled = RobotFrame::on_waist(&m, &WaistChain::G1, [0.0, 0.03, 0.0], 0.04, -0.07, 0.75);
    let (a, b) = (fixed.apply(p), rolled.apply(p));
    assert!((a[2] - b[2]).abs() > 0.005, "{a:?} {b:?}");
}
