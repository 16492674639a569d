//! `g1-dataset`: labelled BEV datasets for the terrain estimator, and the geometric estimator's
//! errors on held-out worlds. See `train::cnn::dataset` for the pose distribution and the rendering.
// The simulator never runs on the robot: std's math is fine here (see clippy.toml).
#![allow(clippy::disallowed_methods)]
use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use clap::{Parser, Subcommand};
use labkit::progress::{bar, default_jobs};
use train::cnn::dataset::{
    evaluate_geometric, export, DatasetConfig, ExportConfig, ModeChoice, WorldSet, EVAL_SEED_BASE, TENSOR_DOC,
};

/// Terrain datasets from the simulated G1 (29-dof model, simulated MID-360, MuJoCo worlds).
///
/// Every sample is a scripted kinematic pose of the robot (no physics) on or around a world's
/// staircase, one simulated 0.1 s lidar frame (20 000 rays) sent through the Livox packet codec,
/// the robot's 6×60×60 BEV grid and the world's ground-truth terrain token (class, h, d, yaw).
/// Output is deterministic in the seeds and settings and does not depend on --jobs.
#[derive(Parser, Debug)]
#[command(name = "g1-dataset", version, about, long_about)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand, Debug)]
enum Cmd {
    /// Render samples into safetensors shards plus manifest.json.
    ///
    /// Tensors per shard (n samples): bev f32 [n,6,60,60], class u8 [n] (0 flat, 1 stairs-up,
    /// 2 stairs-down), step_height f32 [n] (m), step_depth f32 [n] (m), yaw f32 [n] (rad),
    /// world_seed i64 [n], pose f32 [n,4] (pelvis x, y, z, heading), mode u8 [n] (0 standing,
    /// 1 walking). Random worlds are World::random(SEED + i), i < --worlds; split train/validation
    /// by world_seed.
    Export {
        /// Random worlds to render (ignored when --world is given).
        #[arg(long, default_value_t = 100)]
        worlds: usize,
        /// Poses (samples) per world.
        #[arg(long, default_value_t = 16)]
        poses_per_world: usize,
        /// First world seed (random worlds SEED, SEED+1, ...; named worlds get these seeds for
        /// their poses). Evaluation uses seeds from 1 000 000 upwards.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Output directory (created; refused if it exists and is not empty, unless --force).
        #[arg(long)]
        out: PathBuf,
        /// Replace the dataset in an existing --out directory.
        #[arg(long)]
        force: bool,
        /// Samples per shard file.
        #[arg(long, default_value_t = 1024)]
        shard_size: usize,
        /// standing (home pose), walking (scripted gait) or mixed (each pose ½ / ½).
        #[arg(long, default_value = "mixed")]
        mode: ModeChoice,
        /// Render these worlds instead of random ones: a preset (flat, stairs-up, stairs-down,
        /// outdoor), a scenario .toml file or random:SEED; repeat the flag for several.
        #[arg(long = "world", value_name = "PRESET|FILE")]
        world: Vec<String>,
        #[command(flatten)]
        common: Common,
    },
    /// Evaluate the geometric terrain estimator on held-out random worlds.
    ///
    /// Worlds are World::random(1 000 000 + SEED + i), i < --worlds, disjoint from an export's
    /// default seeds. Prints MAE(h) and MAE(d) in cm over all samples (flat counts as h = d = 0),
    /// MAE(yaw) in degrees over samples whose true class is stairs, class accuracy and the
    /// confusion matrix, overall and split by standing / walking.
    EvalGeometric {
        #[arg(long, default_value_t = 200)]
        worlds: usize,
        #[arg(long, default_value_t = 0)]
        seed: u64,
        #[arg(long, default_value_t = 2)]
        poses_per_world: usize,
        #[arg(long, default_value = "mixed")]
        mode: ModeChoice,
        /// Write the figures (and every sample's truth and estimate) as JSON here.
        #[arg(long)]
        report: Option<PathBuf>,
        #[command(flatten)]
        common: Common,
    },
}

#[derive(clap::Args, Debug)]
struct Common {
    /// Worker threads (one world at a time each; the output order does not depend on it).
    #[arg(long, default_value_t = default_jobs())]
    jobs: usize,
    /// Build the grids with the true attitude and height (no simulated estimator error).
    #[arg(long)]
    no_pose_noise: bool,
    /// BEV memory keyframes (the firmware's `[perception] bev_memory_keyframes`; 0: single-frame
    /// grids). Default: what the firmware's built-in network was trained with.
    #[arg(long, value_parser = sensor_io::bev_memory::parse_keyframes, default_value_t = train::cnn::dataset::MemoryConfig::BUILTIN.keyframes)]
    memory_keyframes: usize,
    #[command(flatten)]
    posture: train::cnn::dataset::PostureArgs,
    /// Hide the progress bar.
    #[arg(long)]
    quiet: bool,
}

fn dataset_config(mode: ModeChoice, c: &Common) -> DatasetConfig {
    let mut d = DatasetConfig {
        mode,
        ..DatasetConfig::default()
    };
    d.memory = train::cnn::dataset::MemoryConfig::with_keyframes(c.memory_keyframes);
    d.posture = c.posture.posture();
    if c.no_pose_noise {
        d.attitude_noise_rad = 0.0;
        d.height_noise_m = 0.0;
    }
    d
}

fn main() -> anyhow::Result<()> {
    g1_sim::no_mujoco_log_file();
    let cli = Cli::parse();
    match cli.cmd {
        Cmd::Export {
            worlds,
            poses_per_world,
            seed,
            out,
            force,
            shard_size,
            mode,
            world,
            common,
        } => {
            // Bounded before anything is allocated: a shard holds shard_size BEV grids (86 KB each).
            let bounded = |flag: &str, v: usize, lo: usize, hi: usize| -> anyhow::Result<()> {
                anyhow::ensure!((lo..=hi).contains(&v), "{flag} must be {lo} to {hi} (got {v})");
                Ok(())
            };
            bounded("--worlds", worlds, 1, 10_000_000)?;
            bounded("--poses-per-world", poses_per_world, 1, 1000)?;
            bounded("--shard-size", shard_size, 1, 100_000)?;
            bounded("--jobs", common.jobs, 1, 256)?;
            // A scenario file inside --out would be overwritten by the shards' directory.
            let files: Vec<(&str, &std::path::Path)> = world
                .iter()
                .map(std::path::Path::new)
                .filter(|p| p.is_file())
                .map(|p| ("a --world file", p))
                .collect();
            output_file::check(&[("--out", &out, output_file::Kind::Dir)], &files)?;
            let set = if world.is_empty() {
                WorldSet::Random {
                    first_seed: seed,
                    count: worlds,
                }
            } else {
                WorldSet::Named { args: world, seed }
            };
            set.check()?;
            if let WorldSet::Random { first_seed, count } = &set {
                if first_seed + *count as u64 > EVAL_SEED_BASE {
                    eprintln!(
                        "warning: world seeds reach {EVAL_SEED_BASE}, where eval-geometric's held-out worlds start"
                    );
                }
            }
            let total = set.len() * poses_per_world;
            let cfg = ExportConfig {
                worlds: set,
                poses_per_world,
                shard_size,
                out: out.clone(),
                force,
                jobs: common.jobs,
                dataset: dataset_config(mode, &common),
            };
            let pb = bar(total, common.quiet, "samples");
            let t = Instant::now();
            let m = export(&cfg, &|| pb.inc(1)).with_context(|| format!("exporting to {}", out.display()))?;
            pb.finish_and_clear();
            let secs = t.elapsed().as_secs_f64();
            println!(
                "{} samples from {} worlds in {} shard(s) -> {} ({:.1} s, {:.1} samples/s)",
                m.samples,
                m.worlds,
                m.shards.len(),
                out.display(),
                secs,
                m.samples as f64 / secs
            );
            println!(
                "classes: flat {}, stairs-up {}, stairs-down {}; standing {}, walking {}",
                m.class_histogram[0],
                m.class_histogram[1],
                m.class_histogram[2],
                m.mode_histogram[0],
                m.mode_histogram[1]
            );
            for (name, doc) in TENSOR_DOC {
                println!("  {name}: {doc}");
            }
        }
        Cmd::EvalGeometric {
            worlds,
            seed,
            poses_per_world,
            mode,
            report,
            common,
        } => {
            let set = WorldSet::held_out(seed, worlds)?;
            let pb = bar(worlds * poses_per_world, common.quiet, "samples");
            let t = Instant::now();
            let r = evaluate_geometric(
                &set,
                poses_per_world,
                dataset_config(mode, &common),
                common.jobs,
                &|| pb.inc(1),
            )?;
            pb.finish_and_clear();
            println!(
                "geometric estimator, {} worlds (seeds {}..{}), {} poses each, {:.1} s",
                r.worlds,
                EVAL_SEED_BASE.saturating_add(seed),
                EVAL_SEED_BASE.saturating_add(seed).saturating_add(worlds as u64),
                poses_per_world,
                t.elapsed().as_secs_f64()
            );
            print!("all: {}", r.all);
            print!("standing: {}", r.standing);
            print!("walking: {}", r.walking);
            if let Some(path) = report {
                output_file::write_atomically(&path, (serde_json::to_string_pretty(&r)? + "\n").as_bytes())
                    .with_context(|| format!("writing {}", path.display()))?;
                println!("report: {}", path.display());
            }
        }
    }
    Ok(())
}
