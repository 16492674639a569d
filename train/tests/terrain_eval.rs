//! The geometric terrain estimator on held-out random worlds (sanity bars only: the issue sets no
//! accuracy target), and a dataset export read back with the `safetensors` crate.
mod common;

use std::path::PathBuf;
use std::time::Instant;

use g1_sim::world::{RandomRanges, World};
use safetensors::tensor::Dtype;
use safetensors::SafeTensors;
use sensor_io::bev::{BevGrid, BEV_CELLS, BEV_CHANNELS, BEV_LEN, CH_DENSITY};
use train::cnn::dataset::{
    evaluate_geometric, export, render_worlds, sample_pose, DatasetConfig, ExportConfig, ModeChoice, WorldRenderer,
    WorldSet, EVAL_SEED_BASE,
};

const EVAL_WORLDS: usize = 200;

fn jobs() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

#[test]
fn geometric_estimator_on_held_out_worlds() {
    common::require_deps();
    let set = WorldSet::Random {
        first_seed: EVAL_SEED_BASE,
        count: EVAL_WORLDS,
    };
    let cfg = DatasetConfig::default();
    let t = Instant::now();
    let r = evaluate_geometric(&set, 1, cfg, jobs(), &|| {}).expect("evaluation runs");
    let secs = t.elapsed().as_secs_f64();
    println!(
        "geometric estimator, {} held-out worlds (seeds {EVAL_SEED_BASE}..), 1 pose each, {secs:.1} s",
        r.worlds
    );
    print!("all: {}", r.all);
    print!("standing: {}", r.standing);
    print!("walking: {}", r.walking);

    assert_eq!(r.all.samples, EVAL_WORLDS);
    assert_eq!(r.standing.samples + r.walking.samples, EVAL_WORLDS);
    assert!(
        r.standing.samples > 50 && r.walking.samples > 50,
        "mixed mode draws both"
    );
    for s in [&r.all, &r.standing, &r.walking] {
        assert!(s.mae_h_cm.is_finite() && s.mae_d_cm.is_finite() && s.mae_yaw_deg.is_finite());
    }
    // Every class occurs in the truth.
    for (c, row) in r.all.confusion.iter().enumerate() {
        assert!(row.iter().sum::<usize>() >= 10, "class {c}: {row:?}");
    }
    assert!(
        r.all.class_accuracy > 1.0 / 3.0,
        "class accuracy {:.3} is no better than chance",
        r.all.class_accuracy
    );
    // Grids are not empty.
    assert!(
        r.records.iter().all(|x| x.bev_points > 100),
        "some grid is (nearly) empty"
    );

    // Deterministic: the first worlds again, on one thread, give identical records.
    let again = evaluate_geometric(
        &WorldSet::Random {
            first_seed: EVAL_SEED_BASE,
            count: 8,
        },
        1,
        cfg,
        1,
        &|| {},
    )
    .unwrap();
    assert_eq!(again.records[..], r.records[..8]);
}

/// A unique scratch directory (removed at the end).
fn scratch_dir() -> PathBuf {
    let d = std::env::temp_dir().join(format!("g1_dataset_test_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

fn f32s(data: &[u8]) -> Vec<f32> {
    data.chunks_exact(4)
        .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
        .collect()
}

#[test]
fn dataset_export_reads_back() {
    common::require_deps();
    let out = scratch_dir();
    let (first_seed, worlds, poses) = (42u64, 3usize, 3usize);
    let dataset = DatasetConfig::default();
    let cfg = ExportConfig {
        worlds: WorldSet::Random {
            first_seed,
            count: worlds,
        },
        poses_per_world: poses,
        shard_size: 4,
        out: out.clone(),
        force: false,
        jobs: 2,
        dataset,
    };
    let manifest = export(&cfg, &|| {}).expect("export");
    assert_eq!(manifest.samples, worlds * poses);
    assert_eq!(manifest.shards.len(), 3, "9 samples in shards of 4");
    assert_eq!(manifest.class_histogram.iter().sum::<usize>(), 9);
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("manifest.json")).unwrap()).unwrap();
    assert_eq!(json["samples"], 9);

    let mut k = 0usize; // global sample index
    let mut renderers: Vec<WorldRenderer> = (0..worlds as u64)
        .map(|i| {
            let w = World::random(first_seed + i, &RandomRanges::default());
            WorldRenderer::new(w, first_seed + i, dataset).unwrap()
        })
        .collect();
    for shard in &manifest.shards {
        let bytes = std::fs::read(out.join(&shard.file)).unwrap();
        let st = SafeTensors::deserialize(&bytes).unwrap();
        let n = shard.samples;
        let check = |name: &str, dtype: Dtype, shape: &[usize]| {
            let t = st
                .tensor(name)
                .unwrap_or_else(|e| panic!("{}: {name}: {e:?}", shard.file));
            assert_eq!(t.dtype(), dtype, "{name}");
            assert_eq!(t.shape(), shape, "{name}");
            t
        };
        let bev = f32s(check("bev", Dtype::F32, &[n, BEV_CHANNELS, BEV_CELLS, BEV_CELLS]).data());
        let class = check("class", Dtype::U8, &[n]).data().to_vec();
        let h = f32s(check("step_height", Dtype::F32, &[n]).data());
        let d = f32s(check("step_depth", Dtype::F32, &[n]).data());
        let yaw = f32s(check("yaw", Dtype::F32, &[n]).data());
        let mode = check("mode", Dtype::U8, &[n]).data().to_vec();
        let pose = f32s(check("pose", Dtype::F32, &[n, 4]).data());
        let seeds: Vec<i64> = check("world_seed", Dtype::I64, &[n])
            .data()
            .chunks_exact(8)
            .map(|c| i64::from_le_bytes(c.try_into().unwrap()))
            .collect();
        for i in 0..n {
            let (wi, pi) = (k / poses, (k % poses) as u64);
            let seed = first_seed + wi as u64;
            assert_eq!(seeds[i], seed as i64);
            let world = &renderers[wi].world;
            let p = sample_pose(world, seed, pi, ModeChoice::Mixed, &Default::default());
            assert_eq!(mode[i], p.mode as u8);
            // The recorded pose is the sampled one, and the label is the world's truth there.
            assert!((pose[4 * i] as f64 - p.x).abs() < 1e-5 && (pose[4 * i + 1] as f64 - p.y).abs() < 1e-5);
            assert!((pose[4 * i + 3] as f64 - p.yaw).abs() < 1e-5);
            let z_expected = world.ground_height(p.x, p.y) + renderers[wi].nominal_height();
            assert!((pose[4 * i + 2] as f64 - z_expected).abs() < 0.021, "pelvis height");
            let truth = world.truth(pose[4 * i] as f64, pose[4 * i + 1] as f64, pose[4 * i + 3] as f64);
            let exact = world.truth(p.x, p.y, p.yaw);
            assert_eq!(class[i], exact.class.index() as u8);
            assert_eq!(
                (h[i], d[i], yaw[i]),
                (exact.step_height_m, exact.step_depth_m, exact.yaw_rad)
            );
            assert_eq!(truth.class, exact.class, "f32 pose rounding changed the label");
            // The grid: finite, empty cells exactly 0 in every channel, some cells occupied, and
            // the same as a fresh render of the same sample.
            let g = &bev[i * BEV_LEN..(i + 1) * BEV_LEN];
            assert!(g.iter().all(|v| v.is_finite()));
            let cells = BEV_CELLS * BEV_CELLS;
            let mut occupied = 0;
            for c in 0..cells {
                if g[CH_DENSITY * cells + c] == 0.0 {
                    assert!(
                        (0..BEV_CHANNELS).all(|ch| g[ch * cells + c] == 0.0),
                        "empty cell {c} not 0"
                    );
                } else {
                    occupied += 1;
                }
            }
            assert!(occupied > 100, "sample {k}: {occupied} occupied cells");
            let again = renderers[wi].render_index(pi);
            let mut grid = BevGrid::zeroed();
            grid.data.copy_from_slice(g);
            assert!(*again.bev == grid, "sample {k} is not reproducible");
            assert_eq!(again.truth, exact);
            k += 1;
        }
    }
    assert_eq!(k, 9);
    // A second export into the same directory would replace this dataset: refused unless forced.
    let e = export(&cfg, &|| {}).unwrap_err().to_string();
    assert!(e.contains("not empty") && e.contains("--force"), "{e}");
    assert!(export(
        &ExportConfig {
            force: true,
            ..cfg.clone()
        },
        &|| {}
    )
    .is_ok());
    std::fs::remove_dir_all(&out).unwrap();
}

/// Requests that would render nothing, or whose world seeds would wrap around u64 (into the
/// training range, for held-out worlds), are errors rather than empty results.
#[test]
fn empty_or_wrapping_requests_are_errors() {
    let dataset = DatasetConfig::default();
    let one = WorldSet::Random {
        first_seed: 0,
        count: 1,
    };
    let e = render_worlds(&one, 0, dataset, 1, |_, _, _| Ok(()))
        .unwrap_err()
        .to_string();
    assert!(e.contains("--poses-per-world 0"), "{e}");
    let none = WorldSet::Random {
        first_seed: 0,
        count: 0,
    };
    assert!(render_worlds(&none, 1, dataset, 1, |_, _, _| Ok(())).is_err());
    let e = WorldSet::held_out(u64::MAX, 10).unwrap_err().to_string();
    assert!(e.contains("past u64"), "{e}");
    let e = WorldSet::held_out(u64::MAX - EVAL_SEED_BASE - 5, 10)
        .unwrap_err()
        .to_string();
    assert!(e.contains("wrap"), "{e}");
    assert!(WorldSet::held_out(7, 10).is_ok());
}

/// The memory's render path: a sample holds the keyframes its approach gave it, their points fill
/// cells the single frame leaves empty, the odometry drift moves them, and memory off reproduces
/// the single-frame grid exactly.
#[test]
fn memory_samples_fill_the_blind_disc_and_drift_moves_them() {
    common::require_deps();
    let seed = 7u64;
    let render = |memory: train::cnn::dataset::MemoryConfig, drift: f64, pose: u64| {
        let cfg = DatasetConfig {
            memory,
            odometry_drift: drift,
            ..DatasetConfig::default()
        };
        let w = World::random(seed, &RandomRanges::default());
        WorldRenderer::new(w, seed, cfg).unwrap().render_index(pose)
    };
    let occupied = |g: &BevGrid| {
        (0..BEV_CELLS * BEV_CELLS)
            .filter(|&i| g.data[CH_DENSITY * BEV_CELLS * BEV_CELLS + i] > 0.0)
            .count()
    };
    let on = train::cnn::dataset::MemoryConfig::DEFAULT;
    let off = train::cnn::dataset::MemoryConfig::OFF;
    // The first pose (of a few) whose approach holds keyframes.
    let pose = (0..8u64)
        .find(|&p| render(on, 1.0, p).meta.keyframes > 0)
        .expect("85 % of samples hold keyframes");
    let (with, perfect, single) = (render(on, 1.0, pose), render(on, 0.0, pose), render(off, 1.0, pose));
    assert_eq!(single.meta.keyframes, 0);
    assert!(with.meta.memory_points > 0);
    assert!(
        occupied(&with.bev) > occupied(&single.bev) + 50,
        "memory {} vs single {} occupied cells",
        occupied(&with.bev),
        occupied(&single.bev)
    );
    assert_eq!(with.truth, single.truth);
    assert!(with.bev.data != perfect.bev.data, "the drift moves remembered points");
    // Memory off is the single-frame grid, whatever the drift.
    assert!(render(off, 0.0, pose).bev.data == single.bev.data);
}
