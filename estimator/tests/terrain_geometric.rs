//! The geometric terrain estimator on synthetic BEV grids: an analytic staircase heightfield seen by
//! a synthetic head lidar (upside down, 1.25 m up, elevations −52° … +7°, 1° × 1° rings, 2 cm range
//! noise, 2 % dropouts, a few residual self-hits), gridded into the paper's BEV grid by
//! `sensor_io::bev::BevBuilder::build_robot_points`.
//! `cargo test -p estimator --release --test terrain_geometric -- --nocapture` prints the sweep.
// Test inputs come from std's math on the host; this never runs on the robot.
#![allow(clippy::disallowed_methods)]
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::f32::consts::PI;

use estimator::terrain::{plausible, GeometricTerrainConfig, GeometricTerrainEstimator, TerrainEstimate};
use hal::{TerrainClass, TerrainToken};
use sensor_io::bev::{BevBuilder, BevGrid};

// ---------------------------------------------------------------------------------------------
// Allocation counter (per thread, only while armed).

struct Counting;

thread_local! {
    static ARMED: Cell<bool> = const { Cell::new(false) };
    static ALLOCS: Cell<u64> = const { Cell::new(0) };
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let _ = ARMED.try_with(|a| {
            if a.get() {
                let _ = ALLOCS.try_with(|c| c.set(c.get() + 1));
            }
        });
        // SAFETY: forwarded unchanged to the system allocator.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: forwarded unchanged to the system allocator.
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

// ---------------------------------------------------------------------------------------------
// Deterministic PRNG.

struct Rng(u64);

impl Rng {
    fn next_u64(&mut self) -> u64 {
        // splitmix64
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    fn uniform(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }
    fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.uniform()
    }
    fn gauss(&mut self) -> f32 {
        let u1 = self.uniform().max(1e-7);
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (2.0 * PI * u2).cos()
    }
}

// ---------------------------------------------------------------------------------------------
// Staircase world, in the robot frame (z = 0 on the ground under the robot).

#[derive(Clone, Debug)]
struct Stairs {
    /// Direction of travel (uphill for up, downhill for down) in the robot frame, rad (= −θ).
    dir: f32,
    up: bool,
    /// Riser positions along the travel direction, increasing, m.
    risers: Vec<f32>,
    /// Height of each riser, m.
    heights: Vec<f32>,
    /// Slope of the tread after each riser (dz per m along the travel direction, signed).
    slopes: Vec<f32>,
    /// Nosing radius, m (0: sharp).
    nosing: f32,
    /// Finite width: (centre across the travel direction, half width); outside, the lowest level.
    width: Option<(f32, f32)>,
    /// Height offset so that z(0, 0) = 0.
    offset: f32,
}

impl Stairs {
    #[allow(clippy::too_many_arguments)]
    fn new(
        dir_deg: f32,
        up: bool,
        first_riser: f32,
        n: usize,
        h: &[f32],
        d: &[f32],
        slopes: &[f32],
        nosing: f32,
    ) -> Self {
        let mut risers = Vec::with_capacity(n);
        let mut s = first_riser;
        for i in 0..n {
            risers.push(s);
            s += d[i % d.len()];
        }
        let heights = (0..n).map(|i| h[i % h.len()]).collect();
        let slopes = (0..n).map(|i| slopes[i % slopes.len()]).collect();
        let mut st = Stairs {
            dir: dir_deg.to_radians(),
            up,
            risers,
            heights,
            slopes,
            nosing,
            width: None,
            offset: 0.0,
        };
        st.offset = st.raw(0.0, 0.0);
        st
    }

    /// Uniform staircase: `n` steps of (h, d), first riser at `first_riser` along the travel direction.
    fn uniform(dir_deg: f32, up: bool, first_riser: f32, n: usize, h: f32, d: f32) -> Self {
        Self::new(dir_deg, up, first_riser, n, &[h], &[d], &[0.0], 0.0)
    }

    fn raw(&self, x: f32, y: f32) -> f32 {
        let (c, s) = (self.dir.cos(), self.dir.sin());
        let u = x * c + y * s;
        if let Some((tc, hw)) = self.width {
            let t = -x * s + y * c;
            if (t - tc).abs() > hw {
                return 0.0;
            }
        }
        // Height along the travel direction: climbs for up, falls for down.
        let sign = if self.up { 1.0 } else { -1.0 };
        let mut z = 0.0;
        let mut k = usize::MAX;
        for (i, &r) in self.risers.iter().enumerate() {
            if u >= r {
                z += sign * self.heights[i];
                k = i;
            }
        }
        if k != usize::MAX {
            z += self.slopes[k] * (u - self.risers[k]);
        }
        if self.nosing > 0.0 {
            let r = self.nosing;
            if self.up {
                // Nosing at the start of the upper tread.
                if k != usize::MAX && u - self.risers[k] < r {
                    let q = r - (u - self.risers[k]);
                    z -= r - (r * r - q * q).max(0.0).sqrt();
                }
            } else {
                // Nosing at the end of the upper tread (just before the next riser down).
                let next = if k == usize::MAX { 0 } else { k + 1 };
                if next < self.risers.len() && self.risers[next] - u < r {
                    let q = r - (self.risers[next] - u);
                    z -= r - (r * r - q * q).max(0.0).sqrt();
                }
            }
        }
        z
    }

    fn height(&self, x: f32, y: f32) -> f32 {
        self.raw(x, y) - self.offset
    }

    /// Whether a riser crosses the look-ahead box grown by `margin` along the travel direction.
    fn riser_in_box(&self, margin: f32) -> bool {
        let (c, s) = (self.dir.cos(), self.dir.sin());
        let corners = [(-0.5f32, -0.75f32), (-0.5, 0.75), (1.5, -0.75), (1.5, 0.75)];
        let lo = corners
            .iter()
            .map(|&(x, y)| x * c + y * s)
            .fold(f32::INFINITY, f32::min);
        let hi = corners
            .iter()
            .map(|&(x, y)| x * c + y * s)
            .fold(f32::NEG_INFINITY, f32::max);
        self.risers.iter().any(|&r| r >= lo - margin && r <= hi + margin)
    }

    /// The class is ambiguous: a riser lies within 0.1 m of the look-ahead box's boundary.
    fn ambiguous(&self) -> bool {
        self.riser_in_box(0.1) != self.riser_in_box(-0.1)
    }

    /// Ground-truth token (see `hal::TerrainToken`): stairs when a riser crosses the look-ahead box.
    fn truth(&self) -> TerrainToken {
        if !self.riser_in_box(0.0) {
            return TerrainToken::FLAT;
        }
        // The step about to be taken: the first riser ahead, else the last one.
        let k = self
            .risers
            .iter()
            .position(|&r| r > 0.0)
            .unwrap_or(self.risers.len() - 1);
        let d = if k + 1 < self.risers.len() {
            self.risers[k + 1] - self.risers[k]
        } else if k > 0 {
            self.risers[k] - self.risers[k - 1]
        } else {
            0.3
        };
        TerrainToken {
            class: if self.up {
                TerrainClass::StairsUp
            } else {
                TerrainClass::StairsDown
            },
            step_height_m: self.heights[k],
            step_depth_m: d,
            yaw_rad: -self.dir,
        }
    }

    fn z_max(&self) -> f32 {
        // Upper bound of the heightfield (plus nosing/slope slack).
        let mut z: f32 = 0.0;
        let mut acc = 0.0;
        let sign = if self.up { 1.0 } else { -1.0 };
        for (i, h) in self.heights.iter().enumerate() {
            acc += sign * h;
            let tread = if i + 1 < self.risers.len() {
                self.risers[i + 1] - self.risers[i]
            } else {
                3.0
            };
            z = z.max(acc + self.slopes[i].abs() * tread);
        }
        z - self.offset + 0.05
    }
}

// ---------------------------------------------------------------------------------------------
// Synthetic lidar and gridding.

const SENSOR_Z: f32 = 1.25;

/// Points of one lidar frame in the robot frame.
fn scan(world: &Stairs, rng: &mut Rng) -> Vec<[f32; 3]> {
    let zmax = world.z_max().max(0.05);
    let mut pts = Vec::with_capacity(8000);
    let max_horiz = 2.2f32;
    for ie in 0..60 {
        let el = (-52.0 + ie as f32 + 0.37).to_radians();
        let (ce, se) = (el.cos(), el.sin());
        for ia in 0..360 {
            let az = (ia as f32 + 0.5 * (ie % 2) as f32).to_radians();
            let dir = [ce * az.cos(), ce * az.sin(), se];
            // Start where the ray is just above the highest terrain.
            let mut t0 = 0.0f32;
            if se < 0.0 && SENSOR_Z > zmax {
                t0 = (SENSOR_Z - zmax) / -se;
            }
            let t_end = max_horiz / ce;
            if t0 >= t_end {
                continue;
            }
            let above = |t: f32| SENSOR_Z + t * dir[2] - world.height(t * dir[0], t * dir[1]);
            let step = 0.01;
            let mut t = t0;
            let mut hit = None;
            while t < t_end {
                let tn = t + step;
                if above(tn) <= 0.0 {
                    let (mut a, mut b) = (t, tn);
                    for _ in 0..12 {
                        let m = 0.5 * (a + b);
                        if above(m) > 0.0 {
                            a = m;
                        } else {
                            b = m;
                        }
                    }
                    hit = Some(0.5 * (a + b));
                    break;
                }
                t = tn;
            }
            let Some(th) = hit else { continue };
            if rng.uniform() < 0.02 {
                continue;
            }
            let r = th + 0.02 * rng.gauss();
            pts.push([r * dir[0], r * dir[1], SENSOR_Z + r * dir[2]]);
        }
    }
    // Residual self-hits on the legs that survived the builder's self filter.
    for _ in 0..25 {
        pts.push([rng.range(-0.15, 0.15), rng.range(-0.2, 0.2), rng.range(0.05, 0.8)]);
    }
    pts
}

fn grid_of(world: &Stairs, seed: u64) -> Box<BevGrid> {
    let mut rng = Rng(seed);
    let pts = scan(world, &mut rng);
    let mut g = Box::new(BevGrid::zeroed());
    let stats = BevBuilder::new_boxed().build_robot_points(&pts, &mut g);
    assert_eq!(
        stats.input,
        stats.used + stats.outside + stats.non_finite + stats.self_hits
    );
    g
}

fn flat_world() -> Stairs {
    // No riser anywhere near.
    Stairs::uniform(0.0, true, 50.0, 1, 0.1, 0.3)
}

fn estimate(world: &Stairs, seed: u64) -> TerrainEstimate {
    let g = grid_of(world, seed);
    let mut est = GeometricTerrainEstimator::new(GeometricTerrainConfig::default());
    est.estimate(&g)
}

fn deg(r: f32) -> f32 {
    r.to_degrees()
}

/// Asserts class, h within `eh`, d within `ed`, yaw within `eyaw_deg`.
fn check(name: &str, world: &Stairs, seed: u64, eh: f32, ed: f32, eyaw_deg: f32) {
    let truth = world.truth();
    let e = estimate(world, seed);
    let t = e.token;
    println!(
        "{name}: truth {:?} h {:.3} d {:.3} yaw {:.1}° | est {:?} h {:.3} d {:.3} yaw {:.1}° conf {:.2} cells {} levels {} risers {} res {:.3}",
        truth.class,
        truth.step_height_m,
        truth.step_depth_m,
        deg(truth.yaw_rad),
        t.class,
        t.step_height_m,
        t.step_depth_m,
        deg(t.yaw_rad),
        e.confidence,
        e.cells_used,
        e.levels,
        e.risers,
        e.fit_residual_m
    );
    assert_eq!(t.class, truth.class, "{name}: class");
    assert!(plausible(&t), "{name}: implausible {t:?}");
    if truth.class != TerrainClass::Flat {
        assert!((t.step_height_m - truth.step_height_m).abs() <= eh, "{name}: h");
        assert!((t.step_depth_m - truth.step_depth_m).abs() <= ed, "{name}: d");
        assert!(deg(t.yaw_rad - truth.yaw_rad).abs() <= eyaw_deg, "{name}: yaw");
    }
}

// ---------------------------------------------------------------------------------------------
// Cases.

#[test]
fn flat_ground_is_flat() {
    for seed in 0..3 {
        let e = estimate(&flat_world(), seed);
        assert_eq!(e.token, TerrainToken::FLAT, "{e:?}");
        assert!(e.cells_used > 500, "{e:?}");
    }
}

#[test]
fn stairs_up_ahead() {
    for (i, &(yaw, h, d)) in [
        (0.0, 0.15, 0.30),
        (0.0, 0.05, 0.20),
        (0.0, 0.25, 0.45),
        (30.0, 0.12, 0.28),
        (-30.0, 0.18, 0.35),
        (30.0, 0.22, 0.40),
        (-30.0, 0.08, 0.25),
    ]
    .iter()
    .enumerate()
    {
        let w = Stairs::uniform(-yaw, true, 0.6, 12, h, d);
        // With d = 0.45 only two risers are in the window: one spacing, quantized by the 5 cm cells.
        let ed = if d > 0.42 { 0.07 } else { 0.04 };
        check(&format!("up yaw {yaw} h {h} d {d}"), &w, 10 + i as u64, 0.015, ed, 5.0);
    }
}

#[test]
fn stairs_down_ahead() {
    for (i, &(yaw, h, d)) in [
        (0.0, 0.15, 0.30),
        (0.0, 0.06, 0.22),
        (30.0, 0.20, 0.40),
        (-30.0, 0.12, 0.30),
        (-20.0, 0.25, 0.45),
    ]
    .iter()
    .enumerate()
    {
        let w = Stairs::uniform(-yaw, false, 0.5, 12, h, d);
        check(
            &format!("down yaw {yaw} h {h} d {d}"),
            &w,
            20 + i as u64,
            0.015,
            0.04,
            5.0,
        );
    }
}

#[test]
fn mid_staircase() {
    // Robot on a tread with steps behind and ahead.
    for (i, &(up, yaw, h, d)) in [
        (true, 0.0, 0.15, 0.30),
        (true, 20.0, 0.12, 0.35),
        (false, 0.0, 0.15, 0.30),
        (false, -25.0, 0.18, 0.28),
    ]
    .iter()
    .enumerate()
    {
        let w = Stairs::uniform(-yaw, up, -4.0 * d + 0.4 * d, 12, h, d);
        check(
            &format!("mid up {up} yaw {yaw} h {h} d {d}"),
            &w,
            30 + i as u64,
            0.015,
            0.04,
            5.0,
        );
    }
}

#[test]
fn outdoor_jitter() {
    let mut rng = Rng(77);
    for i in 0..6 {
        let up = i % 2 == 0;
        let (h0, d0) = (rng.range(0.08, 0.2), rng.range(0.25, 0.4));
        let h: Vec<f32> = (0..12).map(|_| h0 * rng.range(0.9, 1.1)).collect();
        let d: Vec<f32> = (0..12).map(|_| d0 * rng.range(0.9, 1.1)).collect();
        let sl: Vec<f32> = (0..12).map(|_| rng.range(-3.0, 3.0).to_radians().tan()).collect();
        let yaw = rng.range(-30.0, 30.0);
        let w = Stairs::new(-yaw, up, 0.5, 12, &h, &d, &sl, 0.02);
        // Per-step jitter is ±10 %: the estimate is a median over the visible steps.
        check(
            &format!("outdoor {i} up {up} yaw {yaw:.1}"),
            &w,
            40 + i,
            0.03,
            0.07,
            5.0,
        );
    }
}

#[test]
fn garbage_grids_do_not_panic() {
    let mut est = GeometricTerrainEstimator::new(GeometricTerrainConfig::default());
    let mut g = Box::new(BevGrid::zeroed());
    let e = est.estimate(&g);
    assert_eq!(e.token, TerrainToken::FLAT);
    assert_eq!(e.confidence, 0.0);
    for v in g.data.iter_mut() {
        *v = f32::NAN;
    }
    let e = est.estimate(&g);
    assert_eq!(e.token, TerrainToken::FLAT);
    assert_eq!(e.confidence, 0.0);
    let mut rng = Rng(5);
    for kind in 0..4 {
        for v in g.data.iter_mut() {
            *v = match kind {
                0 => rng.range(-1e30, 1e30),
                1 => [f32::INFINITY, f32::NEG_INFINITY, f32::NAN, 1.0][(rng.next_u64() % 4) as usize],
                2 => rng.range(-3.0, 3.0),
                _ => rng.range(0.0, 1.0),
            };
        }
        let e = est.estimate(&g);
        assert!(e.token.is_finite(), "{e:?}");
        if e.token.class == TerrainClass::Flat {
            assert_eq!(e.token, TerrainToken::FLAT);
        }
        assert!((0.0..=1.0).contains(&e.confidence), "{e:?}");
    }
}

#[test]
fn plausibility() {
    assert!(plausible(&TerrainToken::FLAT));
    let s = TerrainToken {
        class: TerrainClass::StairsUp,
        step_height_m: 0.15,
        step_depth_m: 0.3,
        yaw_rad: 0.3,
    };
    assert!(plausible(&s));
    assert!(!plausible(&TerrainToken {
        step_height_m: 0.5,
        ..s
    }));
    assert!(!plausible(&TerrainToken {
        step_depth_m: 0.05,
        ..s
    }));
    assert!(!plausible(&TerrainToken { yaw_rad: 2.0, ..s }));
    assert!(!plausible(&TerrainToken {
        step_height_m: f32::NAN,
        ..s
    }));
    assert!(!plausible(&TerrainToken {
        step_height_m: 0.1,
        ..TerrainToken::FLAT
    }));
}

#[test]
fn estimate_does_not_allocate() {
    let grids = [
        grid_of(&flat_world(), 1),
        grid_of(&Stairs::uniform(20.0, true, 0.6, 10, 0.15, 0.3), 2),
    ];
    let mut est = GeometricTerrainEstimator::new(GeometricTerrainConfig::default());
    ALLOCS.with(|c| c.set(0));
    ARMED.with(|a| a.set(true));
    let mut classes = [TerrainClass::Flat; 2];
    for (i, g) in grids.iter().enumerate() {
        classes[i] = est.estimate(g).token.class;
    }
    ARMED.with(|a| a.set(false));
    assert_eq!(ALLOCS.with(|c| c.get()), 0);
    assert_eq!(classes, [TerrainClass::Flat, TerrainClass::StairsUp]);
}

#[test]
fn deterministic() {
    let g = grid_of(&Stairs::uniform(-15.0, false, 0.7, 10, 0.13, 0.32), 9);
    let mut a = GeometricTerrainEstimator::new(GeometricTerrainConfig::default());
    let mut b = GeometricTerrainEstimator::new(GeometricTerrainConfig::default());
    let ea = a.estimate(&g);
    let _ = a.estimate(&grid_of(&flat_world(), 3));
    assert_eq!(ea, a.estimate(&g));
    assert_eq!(ea, b.estimate(&g));
}

// ---------------------------------------------------------------------------------------------
// Randomized sweep.

fn random_scene(rng: &mut Rng) -> Stairs {
    let kind = rng.uniform();
    if kind < 0.12 {
        return flat_world();
    }
    let up = rng.uniform() < 0.5;
    let yaw = rng.range(-45.0, 45.0);
    let h0 = rng.range(0.05, 0.25);
    let d0 = rng.range(0.20, 0.45);
    let outdoor = rng.uniform() < 0.3;
    let n = 4 + (rng.next_u64() % 9) as usize;
    let (h, d, sl, nosing): (Vec<f32>, Vec<f32>, Vec<f32>, f32) = if outdoor {
        (
            (0..n).map(|_| h0 * rng.range(0.9, 1.1)).collect(),
            (0..n).map(|_| d0 * rng.range(0.9, 1.1)).collect(),
            (0..n).map(|_| rng.range(-3.0, 3.0).to_radians().tan()).collect(),
            0.02,
        )
    } else {
        (vec![h0], vec![d0], vec![0.0], 0.0)
    };
    let total: f32 = (0..n).map(|i| d[i % d.len()]).sum();
    // Where the robot stands: before the first step, on the staircase, or past its end.
    let place = rng.uniform();
    let first = if place < 0.45 {
        rng.range(0.3, 1.7)
    } else if place < 0.8 {
        let k = (rng.next_u64() % n as u64) as usize;
        let before: f32 = (0..k).map(|i| d[i % d.len()]).sum();
        -(before + rng.range(0.25, 0.75) * d[k % d.len()])
    } else {
        -(total + rng.range(0.1, 1.0))
    };
    Stairs::new(-yaw, up, first, n, &h, &d, &sl, nosing)
}

#[test]
fn debug_one() {
    let Ok(k) = std::env::var("TERRAIN_SCENE") else { return };
    let k: usize = k.parse().unwrap();
    let mut rng = Rng(2024);
    let worlds: Vec<Stairs> = (0..=k).map(|_| random_scene(&mut rng)).collect();
    let w = &worlds[k];
    println!("{w:?}");
    check("debug", w, 1000 + k as u64, 0.015, 0.04, 5.0);
}

#[test]
fn randomized_sweep() {
    let scenes = if cfg!(debug_assertions) { 30 } else { 300 };
    let mut rng = Rng(2024);
    let worlds: Vec<(Stairs, u64)> = (0..scenes).map(|i| (random_scene(&mut rng), 1000 + i as u64)).collect();
    // Two threads (the lidar simulation dominates).
    let results: Vec<(TerrainToken, TerrainEstimate)> = std::thread::scope(|s| {
        let half = worlds.len() / 2;
        let (a, b) = worlds.split_at(half);
        let run = |part: &[(Stairs, u64)]| -> Vec<(TerrainToken, TerrainEstimate)> {
            let mut est = GeometricTerrainEstimator::new(GeometricTerrainConfig::default());
            part.iter()
                .map(|(w, seed)| {
                    let g = grid_of(w, *seed);
                    (w.truth(), est.estimate(&g))
                })
                .collect()
        };
        let ha = s.spawn(move || run(a));
        let rb = run(b);
        let mut ra = ha.join().unwrap();
        ra.extend(rb);
        ra
    });
    let mut correct = 0;
    let (mut clear, mut clear_correct) = (0, 0);
    let mut confusion = [[0u32; 3]; 3];
    let (mut eh, mut ed, mut ey, mut ns) = (0.0f64, 0.0f64, 0.0f64, 0);
    let mut implausible = 0;
    for (i, (truth, e)) in results.iter().enumerate() {
        let t = e.token;
        confusion[truth.class.index()][t.class.index()] += 1;
        if !plausible(&t) {
            implausible += 1;
        }
        if !worlds[i].0.ambiguous() {
            clear += 1;
            clear_correct += (t.class == truth.class) as usize;
        }
        if t.class == truth.class {
            correct += 1;
            if truth.class != TerrainClass::Flat {
                eh += (t.step_height_m - truth.step_height_m).abs() as f64;
                ed += (t.step_depth_m - truth.step_depth_m).abs() as f64;
                ey += deg(t.yaw_rad - truth.yaw_rad).abs() as f64;
                ns += 1;
            }
        } else if std::env::var_os("TERRAIN_VERBOSE").is_some() {
            let w = &worlds[i].0;
            println!(
                "miss {i}: truth {truth:?} est {t:?} levels {} risers {} cells {}; world dir {:.1} up {} risers {:?}",
                e.levels,
                e.risers,
                e.cells_used,
                deg(w.dir),
                w.up,
                w.risers
            );
        }
    }
    let acc = correct as f64 / results.len() as f64;
    let clear_acc = clear_correct as f64 / clear.max(1) as f64;
    let (mh, md, my) = (eh / ns.max(1) as f64, ed / ns.max(1) as f64, ey / ns.max(1) as f64);
    println!(
        "sweep: {} scenes, class acc {:.1} %, over {} correctly classified stair scenes MAE(h) {:.2} cm, MAE(d) {:.2} cm, MAE(yaw) {:.2} deg; implausible {}",
        results.len(),
        100.0 * acc,
        ns,
        100.0 * mh,
        100.0 * md,
        my,
        implausible
    );
    println!(
        "class acc {:.1} % over the {clear} scenes without a riser within 0.1 m of the look-ahead box's edge",
        100.0 * clear_acc
    );
    println!("confusion (rows truth flat/up/down, cols estimate): {confusion:?}");
    assert_eq!(implausible, 0);
    assert!(acc >= 0.9, "class accuracy {acc}");
    assert!(clear_acc >= 0.97, "class accuracy {clear_acc} without boundary cases");
    assert!(mh <= 0.015 && md <= 0.05 && my <= 4.0, "MAE h {mh} d {md} yaw {my}");
}

/// Development harness: figures on grids exported by `g1-dataset export` (converted to raw little
/// endian f32: `$TERRAIN_DS/bev.bin` [n, 6, 60, 60], `$TERRAIN_DS/lab.bin` [n, 5] = class, h, d,
/// yaw, mode). Skipped unless TERRAIN_DS is set.
#[test]
fn dataset_figures() {
    let Some(dir) = std::env::var_os("TERRAIN_DS") else {
        return;
    };
    let dir = std::path::PathBuf::from(dir);
    let rd = |name: &str| -> Vec<f32> {
        std::fs::read(dir.join(name))
            .unwrap()
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect()
    };
    let bev = rd("bev.bin");
    let lab = rd("lab.bin");
    let n = lab.len() / 5;
    let len = sensor_io::bev::BEV_LEN;
    let mut est = GeometricTerrainEstimator::new(GeometricTerrainConfig::default());
    let mut g = Box::new(BevGrid::zeroed());
    let mut conf = [[0u32; 3]; 3];
    let (mut eh, mut ed, mut ey, mut ns, mut implausible) = (0.0f64, 0.0f64, 0.0f64, 0usize, 0usize);
    let verbose = std::env::var_os("TERRAIN_VERBOSE").is_some();
    let t0 = std::time::Instant::now();
    for i in 0..n {
        g.data.copy_from_slice(&bev[i * len..(i + 1) * len]);
        let e = est.estimate(&g);
        let l = &lab[i * 5..i * 5 + 5];
        let class = [TerrainClass::Flat, TerrainClass::StairsUp, TerrainClass::StairsDown][l[0] as usize];
        let t = e.token;
        conf[class.index()][t.class.index()] += 1;
        eh += (l[1] - t.step_height_m).abs() as f64;
        ed += (l[2] - t.step_depth_m).abs() as f64;
        if class != TerrainClass::Flat {
            ey += hal::wrap_angle(l[3] as f64 - t.yaw_rad as f64).abs().to_degrees();
            ns += 1;
        }
        implausible += !plausible(&t) as usize;
        let bad = class != t.class
            || (class != TerrainClass::Flat
                && ((l[1] - t.step_height_m).abs() > 0.04 || deg(l[3] - t.yaw_rad).abs() > 10.0));
        if verbose && bad {
            println!(
                "{i}: truth {:?} h {:.3} d {:.3} yaw {:.1} | est {:?} h {:.3} d {:.3} yaw {:.1} lev {} ris {} res {:.3}",
                class,
                l[1],
                l[2],
                deg(l[3]),
                t.class,
                t.step_height_m,
                t.step_depth_m,
                deg(t.yaw_rad),
                e.levels,
                e.risers,
                e.fit_residual_m
            );
        }
    }
    let correct: u32 = (0..3).map(|i| conf[i][i]).sum();
    println!(
        "dataset {n}: acc {:.1} % MAE h {:.2} cm d {:.2} cm yaw {:.2} deg implausible {implausible} conf {conf:?} ({:.2} ms/grid)",
        100.0 * correct as f64 / n as f64,
        100.0 * eh / n as f64,
        100.0 * ed / n as f64,
        ey / ns.max(1) as f64,
        t0.elapsed().as_secs_f64() * 1e3 / n as f64
    );
}
