//! Ray casting per simulated MID-360 frame (20 000 rays) on the `stairs-up` world with the 29-dof
//! G1, and the cost of one dataset sample.
//!
//! - batched: `LidarSim::scan` over the whole 0.1 s frame in one call (one `mj_multiRay`);
//! - sliced: 50 calls of 400 rays (one per 2 ms control tick, as `g1-sim` does);
//! - per ray: the alternative, one `mj_ray` per ray (`MjData::ray`), same origin and directions;
//! - dataset sample: `WorldRenderer::render_index` (pose, scan, Livox packets and reassembly, BEV),
//!   standing (one scan call) and walking (50 slices with `mj_forward` between them); and the
//!   model build per world (`WorldRenderer::new`).
//!
//! Run: `cargo bench -p train --bench raycast` (figures on stdout; `G1_BENCH_FRAMES` sets the
//! frames per measurement, default 20).
use std::hint::black_box;
use std::time::Instant;

use g1_sim::lidar::{rpy_matrix, LidarConfig, LidarSim, Return};
use g1_sim::model::deps_dir;
use g1_sim::world::World;
use g1_sim::{ModelChoice, SimConfig, Simulator};
use mujoco_rs::prelude::*;
use train::cnn::dataset::{DatasetConfig, ModeChoice, WorldRenderer};

const FRAME_NS: u64 = 100_000_000;

fn mat_vec(a: &[f64; 9], v: [f64; 3]) -> [f64; 3] {
    [
        a[0] * v[0] + a[1] * v[1] + a[2] * v[2],
        a[3] * v[0] + a[4] * v[1] + a[5] * v[2],
        a[6] * v[0] + a[7] * v[1] + a[8] * v[2],
    ]
}

fn mat_mul(a: &[f64; 9], b: &[f64; 9]) -> [f64; 9] {
    let mut r = [0.0; 9];
    for i in 0..3 {
        for j in 0..3 {
            r[3 * i + j] = (0..3).map(|k| a[3 * i + k] * b[3 * k + j]).sum();
        }
    }
    r
}

/// Median of `v`.
fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Mean ms per call of `f` over `n` calls (after one warm-up call).
fn time_ms(n: usize, mut f: impl FnMut(usize)) -> f64 {
    f(0);
    let t = Instant::now();
    for i in 1..=n {
        f(i);
    }
    t.elapsed().as_secs_f64() * 1e3 / n as f64
}

fn main() {
    if !deps_dir().join("g1_29dof/g1.xml").exists() {
        eprintln!("raycast bench: the 29-dof model is missing; run scripts/install.sh first");
        std::process::exit(1);
    }
    let frames: usize = std::env::var("G1_BENCH_FRAMES")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(20);
    let world = World::preset("stairs-up").expect("preset");
    let mut sim = Simulator::load_in(ModelChoice::G1_29Dof, SimConfig::default(), Some(&world)).expect("model loads");
    let cfg = LidarConfig::default();
    let n = cfg.points_per_frame();
    let mut lidar = LidarSim::new(sim.data().model(), cfg, n).expect("lidar");
    let mut out: Vec<Return> = Vec::with_capacity(n);
    println!("ray casting on `stairs-up`, 29-dof G1, {n} rays per frame, {frames} frames per figure");

    // The three methods take turns frame by frame (the median of each is reported), so that load
    // from other processes hits them alike.
    let model = sim.data().model();
    let body = model
        .name_to_id(MjtObjBase::mjOBJ_BODY, "torso_link")
        .expect("torso_link");
    let (xpos, xmat) = (sim.data().xpos()[body], sim.data().xmat()[body]);
    let rot = mat_mul(&xmat, &rpy_matrix(cfg.mount_rpy));
    let o = mat_vec(&xmat, cfg.mount_xyz);
    let origin = [xpos[0] + o[0], xpos[1] + o[1], xpos[2] + o[2]];
    let mut lidar_sliced = LidarSim::new(sim.data().model(), cfg, n).expect("lidar");
    let (mut t_batched, mut t_sliced, mut t_per_ray) = (Vec::new(), Vec::new(), Vec::new());
    let (mut hits_batched, mut hits_per_ray) = (0, 0);
    for i in 0..=frames {
        let t0 = i as u64 * FRAME_NS;
        out.clear();
        let t = Instant::now();
        lidar.scan(sim.data_mut(), t0, t0 + FRAME_NS, &mut out);
        t_batched.push(t.elapsed().as_secs_f64() * 1e3);
        hits_batched = out.iter().filter(|r| r.geom >= 0).count();
        black_box(&out);

        out.clear();
        let t = Instant::now();
        for k in 0..50 {
            let a = t0 + k * FRAME_NS / 50;
            lidar_sliced.scan(sim.data_mut(), a, a + FRAME_NS / 50, &mut out);
        }
        t_sliced.push(t.elapsed().as_secs_f64() * 1e3);
        // Slice boundaries are rounded in f64 (ceil(t·rate)), so a frame may gain or lose a ray.
        assert!(out.len().abs_diff(n) <= 1, "50 slices: {} rays", out.len());
        black_box(&out);

        // One mj_ray per ray, from the same sensor pose, same directions.
        let first = (t0 as f64 * 1e-9 * cfg.points_per_second).ceil() as u64;
        let data = sim.data_mut();
        let t = Instant::now();
        hits_per_ray = 0;
        for k in 0..n as u64 {
            let d = mat_vec(&rot, lidar.direction(first + k));
            let (g, dist) = data.ray(&origin, &d, None, true, Some(body), None);
            if g.is_some() && dist <= cfg.max_range {
                hits_per_ray += 1;
            }
        }
        t_per_ray.push(t.elapsed().as_secs_f64() * 1e3);
        black_box(hits_per_ray);
    }
    let (batched, sliced, per_ray) = (
        median(&mut t_batched[1..]),
        median(&mut t_sliced[1..]),
        median(&mut t_per_ray[1..]),
    );
    println!("  batched  (1 x mj_multiRay of {n}):   {batched:8.2} ms/frame  ({hits_batched} hits, 1 % dropout)");
    println!(
        "  sliced   (50 x mj_multiRay of {}):  {sliced:8.2} ms/frame  ({:.2} x batched)",
        n / 50,
        sliced / batched
    );
    println!(
        "  per ray  ({n} x mj_ray):           {per_ray:8.2} ms/frame  ({hits_per_ray} hits; {:.1} x batched, {:.1} x sliced)",
        per_ray / batched,
        per_ray / sliced
    );

    // The dataset path.
    let t = Instant::now();
    let builds = 5;
    for i in 0..builds {
        black_box(WorldRenderer::new(world.clone(), i, DatasetConfig::default()).expect("renderer"));
    }
    let build_ms = t.elapsed().as_secs_f64() * 1e3 / builds as f64;
    println!("dataset (scan + Livox packets + reassembly + BEV):");
    println!("  model build per world:   {build_ms:8.2} ms");
    for mode in [ModeChoice::Standing, ModeChoice::Walking] {
        let cfg = DatasetConfig {
            mode,
            ..DatasetConfig::default()
        };
        let mut r = WorldRenderer::new(world.clone(), 7, cfg).expect("renderer");
        let ms = time_ms(frames, |i| {
            black_box(r.render_index(i as u64));
        });
        println!(
            "  {:<9} sample:         {ms:8.2} ms  ({:.0} samples/s on one core, model build excluded)",
            format!("{mode:?}"),
            1e3 / ms
        );
    }
}
