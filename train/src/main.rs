//! `g1-train`: train, export and evaluate the terrain CNN. See the crate docs and `--help`.
// The trainer never runs on the robot: std's math is fine here (see clippy.toml).
#![allow(clippy::disallowed_methods)]
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use candle_core::Device;
use clap::{Parser, Subcommand};
use g1_sim::progress::{bar, default_jobs};
use train::data::{split_by_world, Dataset};
use train::export::{fold, DESC_FILE, WEIGHTS_FILE};
use train::fit::{fit, FitConfig, LAMBDA_CLS, LAMBDA_D, LAMBDA_H, LAMBDA_YAW};

/// Terrain CNN for the G1: BEV grid (6×60×60) → terrain token (class, step height, step depth, yaw).
///
/// Typical use: `g1-dataset export --worlds 4000 --poses-per-world 8 --out data/train`, then
/// `g1-train fit --data data/train --out runs/cnn`, then
/// `g1-train eval-terrain --worlds 1000 --weights runs/cnn --report eval.json`.
#[derive(Parser, Debug)]
#[command(name = "g1-train", version, about, long_about)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand, Debug)]
enum Cmd {
    /// Train on g1-dataset exports; writes the firmware export (terrain_cnn.safetensors + .toml),
    /// checkpoint.safetensors (unfolded; rewritten after every epoch, so an interrupted run can
    /// go on with --init), history.json and training.png into --out.
    Fit {
        /// Dataset directories (g1-dataset export --out); repeat for several.
        #[arg(long, required = true)]
        data: Vec<PathBuf>,
        /// Output directory (created): the export, checkpoint, history.json, training.png
        #[arg(long)]
        out: PathBuf,
        #[arg(long, default_value_t = 30)]
        epochs: usize,
        #[arg(long, default_value_t = 64)]
        batch: usize,
        /// Peak learning rate (AdamW; cosine decay).
        #[arg(long, default_value_t = 2e-3)]
        lr: f64,
        /// Fraction of worlds (by seed) held out for validation.
        #[arg(long, default_value_t = 0.1)]
        val_fraction: f64,
        /// Train only on samples whose true step height is at most this (m): the out-of-range
        /// experiment (paper Table III) trains at ≤ 0.16 and tests up to 0.22.
        #[arg(long)]
        max_train_h: Option<f32>,
        /// Stop after this many optimiser steps (smoke tests).
        #[arg(long, default_value_t = 0)]
        max_steps: usize,
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Continue from this checkpoint (checkpoint.safetensors of an earlier fit), with a fresh schedule
        #[arg(long)]
        init: Option<PathBuf>,
        /// No left–right mirror augmentation.
        #[arg(long)]
        no_mirror: bool,
        /// Write into an --out that already holds files (an earlier run's export and checkpoint
        /// are replaced).
        #[arg(long)]
        force: bool,
        #[arg(long)]
        quiet: bool,
    },
    /// Fold a checkpoint (checkpoint.safetensors from `fit`) into the firmware's format again.
    Export {
        #[arg(long)]
        checkpoint: PathBuf,
        /// Directory for terrain_cnn.safetensors and terrain_cnn.toml.
        #[arg(long)]
        out: PathBuf,
        /// Also write the parity fixture (terrain_cnn_parity.safetensors) from grids of this
        /// dataset (g1-dataset export directory).
        #[arg(long)]
        data: Option<PathBuf>,
    },
    /// Evaluate the CNN (run by the firmware's executor) and the geometric baseline side by side
    /// on held-out rendered worlds; prints MAE(h) cm, MAE(d) cm, MAE(yaw) deg and class accuracy.
    ///
    /// --worlds N renders World::random(1 000 000 + SEED + i), i < N (never used in training:
    /// exports start at seed 0); --worlds FILE.toml,PRESET,... evaluates scenario files or presets
    /// (flat, stairs-up, stairs-down, outdoor, random:SEED) instead.
    EvalTerrain {
        /// N (random held-out worlds) or a comma-separated list of scenario files / presets.
        #[arg(long, default_value = "1000")]
        worlds: String,
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Evaluate on the export's own world seeds (World::random(SEED + i), the worlds
        /// `g1-dataset export --seed SEED` renders) instead of held-out ones: the fit check.
        /// Errors here close to the held-out ones mean the network underfits, not overfits.
        #[arg(long)]
        training_worlds: bool,
        #[arg(long, default_value_t = 2)]
        poses_per_world: usize,
        /// standing, walking or mixed.
        #[arg(long, default_value = "mixed")]
        mode: g1_sim::dataset::ModeChoice,
        /// BEV memory keyframes of the grids (0: single-frame); must match what the weights were
        /// trained with. Default: that of the firmware's built-in network.
        #[arg(long, value_parser = sensor_io::bev_memory::parse_keyframes, default_value_t = g1_sim::dataset::MemoryConfig::BUILTIN.keyframes)]
        memory_keyframes: usize,
        /// Scale of the memory keyframes' simulated odometry drift (1: the renderer's model; 0:
        /// perfect odometry, the upper bound of what the memory gives).
        #[arg(long, default_value_t = 1.0)]
        odometry_drift: f64,
        /// Directory holding terrain_cnn.safetensors + terrain_cnn.toml (default: the weights
        /// built into the firmware).
        #[arg(long)]
        weights: Option<PathBuf>,
        /// Write the figures (and every sample's truth and estimates) as JSON here.
        #[arg(long)]
        report: Option<PathBuf>,
        /// Plot of the errors versus true step height (PNG); a second one, `<stem>_by_riser.png`
        /// beside it, plots them versus the labelled riser's distance ahead. None when not given.
        #[arg(long)]
        plot: Option<PathBuf>,
        #[arg(long, default_value_t = default_jobs())]
        jobs: usize,
        #[arg(long)]
        quiet: bool,
    },
    /// Train the stair policy with PPO on in-process MuJoCo environments (docs/stair_results.md).
    ///
    /// Observations, action rules and the actor's executor are the firmware's own, built from
    /// --spec. Writes into --out: checkpoint.safetensors + state.json (re-running the same
    /// command resumes), history.json and curves.png (learning curves), the actor as g1fw loads it
    /// under the spec's weights file name (`g1-train ppo-export` puts it beside the spec).
    Ppo {
        /// The deploy spec to train (its observation, gains, rates and network layout).
        #[arg(long, default_value = "specs/stairs/g1_stairs_lstm.toml")]
        spec: PathBuf,
        /// g1-12dof (default), g1-29dof (upper body held by the spec's [[held]] groups) or an MJCF.
        #[arg(long, default_value = "g1-12dof")]
        model: g1_sim::ModelChoice,
        /// Run directory: created if missing; a run whose directory holds a checkpoint resumes from it
        #[arg(long)]
        out: PathBuf,
        /// Parallel environments.
        #[arg(long, default_value_t = 256)]
        envs: usize,
        /// Worker threads stepping environments (default: every core).
        #[arg(long, default_value_t = default_jobs())]
        threads: usize,
        /// Total PPO iterations (a resumed run continues up to this count).
        #[arg(long, default_value_t = 1000)]
        iterations: usize,
        /// Policy steps per environment and iteration.
        #[arg(long, default_value_t = 24)]
        steps: usize,
        /// Passes over each rollout.
        #[arg(long, default_value_t = 4)]
        epochs: usize,
        /// Minibatches per pass (of whole environment sequences), as rsl_rl.
        #[arg(long, default_value_t = 4)]
        minibatches: usize,
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Warm start: an actor with the tensor names of the spec's [policy.network] (its input is
        /// widened with zero columns for the token), e.g. the peer walker
        /// ../shared/peer_policy/unitree_g1_lstm/policy.safetensors for the LSTM spec. Ignored when
        /// resuming.
        #[arg(long)]
        init_actor: Option<PathBuf>,
        /// Hidden sizes of a fresh actor, one per linear/lstm layer of the spec's network but the
        /// last, e.g. 128,64,64 for specs/stairs/g1_stairs_mlp.toml or 64,32 for the LSTM spec.
        /// Needed without --init-actor on a new run; resuming and warm starts take the weights'.
        #[arg(long, value_delimiter = ',')]
        actor_hidden: Vec<usize>,
        /// Also learn every transition mirrored left–right (the G1's symmetry: twice the data per
        /// simulated step; feed-forward actors only).
        #[arg(long)]
        symmetry: bool,
        /// Initial action noise standard deviation (actions are in units of action_scale).
        #[arg(long, default_value_t = 0.3)]
        init_std: f64,
        /// Iterations that train only the critic (after a warm start).
        #[arg(long, default_value_t = 10)]
        critic_warmup: usize,
        /// Starting learning rate (adaptive KL from there).
        #[arg(long, default_value_t = 1e-4)]
        lr: f64,
        #[arg(long, default_value_t = 0.005)]
        entropy_coef: f64,
        /// Episode length, s (long enough for the longest staircase at the slowest command:
        /// up to 2 m + 8 × 0.4 m + 0.5 m at 0.4 m/s is 14 s).
        #[arg(long, default_value_t = 20.0)]
        episode_s: f64,
        /// Highest curriculum level environments start at (0: 5 cm steps … 10: 26 cm).
        #[arg(long, default_value_t = 2)]
        max_init_level: usize,
        /// Forward speed commands, m/s, drawn uniformly per episode: MIN,MAX (runs up to 11 used
        /// 0.4,0.8; below 0.4 such policies stood at the first riser).
        #[arg(long, value_name = "MIN,MAX", default_value = "0.3,0.8", value_parser = parse_vx_range)]
        vx: (f64, f64),
        /// No observation/token noise, latency or pushes (tests).
        #[arg(long)]
        no_randomization: bool,
        /// Train on one terrain column only (default: the curriculum's mix of flat 15 %, stairs
        /// up 30 %, down 30 %, irregular outdoor up and down 12.5 % each).
        #[arg(long, value_enum)]
        only: Option<train::ppo::env::Column>,
        /// Checkpoint at least this often, s.
        #[arg(long, default_value_t = 120.0)]
        checkpoint_every: f64,
        /// Stop (after a checkpoint) once this run has spent this many seconds.
        #[arg(long, default_value_t = f64::INFINITY)]
        max_wall: f64,
        /// Judge every Nth checkpoint through g1fw (up and down at 12, 16 and 20 cm, 2 episodes
        /// each, and a flat run, with perception and the spec's terrain estimator; ~1 min):
        /// judge.json, best.safetensors and the points in curves.png. 0: never.
        #[arg(long, default_value_t = 5)]
        judge_every: usize,
        #[arg(long)]
        quiet: bool,
    },
    /// Evaluate an actor in the training environment itself (its physics, worlds, starts, token and
    /// walls), with the mean action, at held curriculum levels: splits a gap between training's
    /// figures and `g1fw eval` into the environment's part and the policy's.
    PpoEval {
        /// The deploy spec the actor was trained with.
        #[arg(long, default_value = "specs/stairs/g1_stairs_lstm.toml")]
        spec: PathBuf,
        /// The actor (default: the spec's weights), e.g. a run's actors/actor_<steps>.safetensors.
        #[arg(long)]
        weights: Option<PathBuf>,
        #[arg(long, default_value = "g1-12dof")]
        model: g1_sim::ModelChoice,
        /// Terrain columns to run, e.g. up,down.
        #[arg(long, value_enum, value_delimiter = ',', default_value = "up,down")]
        columns: Vec<train::ppo::env::Column>,
        /// Curriculum levels (step height 5 + 2.1·level cm), e.g. 1,3,5.
        #[arg(long, value_delimiter = ',', default_value = "1,3,5")]
        levels: Vec<usize>,
        /// Episodes per column and level.
        #[arg(long, default_value_t = 16)]
        episodes: usize,
        /// Commanded forward speed, m/s.
        #[arg(long, default_value_t = 0.5)]
        vx: f32,
        /// Training's randomisation (noise, latency, pushes, dynamics) on; default off.
        #[arg(long)]
        randomization: bool,
        #[arg(long, default_value_t = 20.0)]
        episode_s: f64,
        #[arg(long, default_value_t = 0)]
        seed: u64,
        #[arg(long, default_value_t = default_jobs())]
        threads: usize,
        /// Also write the results as JSON here.
        #[arg(long)]
        json: Option<PathBuf>,
    },
    /// Write a PPO checkpoint's actor as the weights file its deploy spec names.
    PpoExport {
        /// `checkpoint.safetensors` in a `g1-train ppo --out` directory (its actor is written)
        #[arg(long)]
        checkpoint: PathBuf,
        /// Deploy spec whose `[policy] weights` file receives the actor (overwritten)
        #[arg(long, default_value = "specs/stairs/g1_stairs_lstm.toml")]
        spec: PathBuf,
    },
}

fn load_net(weights: Option<&std::path::Path>) -> anyhow::Result<firmware::terrain_net::TerrainNet> {
    Ok(match weights {
        None => firmware::terrain_net::TerrainNet::embedded()?,
        Some(dir) => firmware::terrain_net::TerrainNet::load(&dir.join(DESC_FILE), &dir.join(WEIGHTS_FILE))
            .with_context(|| {
                format!(
                    "loading the terrain CNN from {} (written by `g1-train fit`)",
                    dir.display()
                )
            })?,
    })
}

/// glibc hands every freed block over 128 KiB back to the kernel and maps it again on the next
/// step, so each training step page-faults its tensors (a few MB each at batch 64) back in: a third
/// of the step time here. Keeping them in the heap trains 1.5–2× faster (measured A/B, same data).
/// An explicit `MALLOC_MMAP_THRESHOLD_` in the environment wins.
fn keep_freed_tensors_in_the_heap() {
    if std::env::var_os("MALLOC_MMAP_THRESHOLD_").is_some() {
        return;
    }
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only sets glibc allocator thresholds; it runs first thing in main, before any
    // other thread exists, and its failure (return 0) leaves the defaults in place.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, i32::MAX);
        libc::mallopt(libc::M_TOP_PAD, 64 << 20);
    }
}

/// `fit` writes its export and checkpoint into `out`: refuse to replace an earlier run's files
/// unless forced, and never let an output be one of the run's inputs.
fn fit_output_is_free(out: &Path, data: &[PathBuf], init: Option<&Path>, force: bool) -> anyhow::Result<()> {
    let abs = |p: &Path| {
        std::fs::canonicalize(p)
            .or_else(|_| std::path::absolute(p))
            .unwrap_or(p.into())
    };
    for d in data {
        anyhow::ensure!(
            abs(d) != abs(out),
            "--out {} is also a --data directory: write the training run elsewhere",
            out.display()
        );
    }
    if let Some(init) = init {
        anyhow::ensure!(
            abs(init) != abs(&out.join("checkpoint.safetensors")),
            "--init {} would be overwritten by this run's checkpoint: copy it elsewhere or choose another --out",
            init.display()
        );
    }
    let occupied = std::fs::read_dir(out).is_ok_and(|mut d| d.next().is_some());
    anyhow::ensure!(
        !occupied || force,
        "{} exists and is not empty: choose a new --out, or pass --force to replace the run there",
        out.display()
    );
    Ok(())
}

fn main() -> anyhow::Result<()> {
    keep_freed_tensors_in_the_heap();
    g1_sim::no_mujoco_log_file();
    let cli = Cli::parse();
    match cli.cmd {
        Cmd::Ppo {
            spec,
            model,
            out,
            envs,
            threads,
            iterations,
            steps,
            epochs,
            minibatches,
            seed,
            init_actor,
            actor_hidden,
            symmetry,
            init_std,
            critic_warmup,
            lr,
            entropy_coef,
            episode_s,
            max_init_level,
            vx,
            no_randomization,
            only,
            checkpoint_every,
            max_wall,
            judge_every,
            quiet,
        } => {
            tracing_subscriber::fmt().with_writer(std::io::stderr).init();
            // Counts that size allocations are bounded before anything is built: each environment
            // holds its own MuJoCo model (~80 MB), each rollout steps × envs rows.
            let bounded = |flag: &str, v: usize, lo: usize, hi: usize| -> anyhow::Result<()> {
                anyhow::ensure!((lo..=hi).contains(&v), "{flag} must be {lo} to {hi} (got {v})");
                Ok(())
            };
            bounded("--envs", envs, 2, 4096)?;
            bounded("--threads", threads, 1, 256)?;
            bounded("--steps", steps, 1, 10_000)?;
            bounded("--epochs", epochs, 1, 100)?;
            bounded("--minibatches", minibatches, 1, envs)?;
            anyhow::ensure!(
                lr.is_finite()
                    && lr > 0.0
                    && init_std.is_finite()
                    && init_std > 0.0
                    && episode_s.is_finite()
                    && episode_s > 0.0,
                "--lr, --init-std and --episode-s must be positive numbers"
            );
            let judge_model = model.to_string();
            let cfg = train::ppo::runner::RunConfig {
                spec,
                model,
                out: out.clone(),
                envs,
                threads,
                iterations,
                seed,
                init_actor,
                actor_hidden,
                symmetry,
                init_std,
                critic_warmup,
                episode_s,
                ppo: train::ppo::algo::PpoConfig {
                    steps,
                    epochs,
                    minibatches,
                    lr,
                    entropy_coef,
                    ..Default::default()
                },
                random: if no_randomization {
                    train::ppo::env::Randomization::NONE
                } else {
                    train::ppo::env::Randomization::DEFAULT
                },
                max_init_level,
                vx,
                only,
                checkpoint_every_s: checkpoint_every,
                quiet,
                max_wall_s: max_wall,
                judge: train::ppo::judge::JudgeConfig::standard(judge_every, &judge_model),
            };
            let history = train::ppo::runner::train(&cfg)?;
            if let Some(l) = history.last() {
                println!(
                    "iteration {}: {} env steps in {:.0} s ({:.0} steps/s, learner {:.0} % of wall time); \
                     reward/step {:+.3}, level {:.2}; curves in {}",
                    l.iteration,
                    l.env_steps,
                    l.wall_s,
                    l.env_steps_per_s,
                    100.0 * l.learner_share,
                    l.mean_reward_per_step,
                    l.mean_level,
                    out.join(train::ppo::runner::CURVES).display()
                );
            }
        }
        Cmd::PpoEval {
            spec,
            weights,
            model,
            columns,
            levels,
            episodes,
            vx,
            randomization,
            episode_s,
            seed,
            threads,
            json,
        } => {
            anyhow::ensure!((1..=100_000).contains(&episodes), "--episodes must be 1 to 100000");
            anyhow::ensure!(
                levels.iter().all(|&l| l < train::ppo::env::LEVELS),
                "--levels must be 0 to {}",
                train::ppo::env::LEVELS - 1
            );
            anyhow::ensure!(
                vx.is_finite() && episode_s.is_finite() && episode_s > 0.0,
                "--vx and --episode-s must be numbers (--episode-s positive)"
            );
            let deploy = firmware::spec::DeploySpec::load(&spec)
                .with_context(|| format!("loading the deploy spec {}", spec.display()))?;
            let wpath = weights.unwrap_or_else(|| deploy.weights_path());
            let bytes = firmware::read_capped(&wpath, firmware::nn::MAX_WEIGHTS_BYTES)
                .with_context(|| format!("reading the actor {}", wpath.display()))?;
            let deploy = std::sync::Arc::new(deploy);
            let mut reports = Vec::new();
            println!("column  level  step cm  episodes  success  falls (tilt/speed/height/spin)  timeouts  mean s");
            for &column in &columns {
                for &level in &levels {
                    let r = train::ppo::in_env::evaluate(
                        &train::ppo::in_env::InEnvOptions {
                            model: model.clone(),
                            spec: deploy.clone(),
                            column,
                            level,
                            vx,
                            episodes,
                            random: if randomization {
                                train::ppo::env::Randomization::DEFAULT
                            } else {
                                train::ppo::env::Randomization::NONE
                            },
                            episode_s,
                            seed,
                            threads,
                        },
                        &bytes,
                    )?;
                    let causes: Vec<String> = r.fall_causes.iter().map(|(_, n)| n.to_string()).collect();
                    println!(
                        "{:<7} {:>5}  {:>7.1}  {:>8}  {:>7}  {:>5} ({})  {:>8}  {:>6.1}",
                        r.column,
                        r.level,
                        100.0 * r.step_height_m,
                        r.episodes,
                        r.successes,
                        r.falls,
                        causes.join("/"),
                        r.timeouts,
                        r.mean_steps / deploy.rates.policy_hz as f64
                    );
                    reports.push(r);
                }
            }
            if let Some(path) = json {
                std::fs::write(&path, serde_json::to_string_pretty(&reports)?)
                    .with_context(|| format!("writing {}", path.display()))?;
            }
        }
        Cmd::PpoExport { checkpoint, spec } => {
            let path = train::ppo::runner::export(&checkpoint, &spec)?;
            println!("wrote {}", path.display());
        }
        Cmd::Fit {
            data,
            out,
            epochs,
            batch,
            lr,
            val_fraction,
            max_train_h,
            max_steps,
            seed,
            init,
            no_mirror,
            force,
            quiet,
        } => {
            fit_output_is_free(&out, &data, init.as_deref(), force)?;
            let t_load = Instant::now();
            let ds = Dataset::load_dirs(&data)?;
            let (mut tr, val) = split_by_world(&ds, val_fraction);
            if let Some(hmax) = max_train_h {
                tr.retain(|&i| ds.step_height[i] <= hmax);
            }
            println!(
                "{} samples loaded in {:.1} s: {} train, {} validation (split by world seed)",
                ds.len(),
                t_load.elapsed().as_secs_f64(),
                tr.len(),
                val.len()
            );
            std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
            let cfg = FitConfig {
                epochs,
                batch,
                lr,
                seed,
                mirror: !no_mirror,
                max_steps,
                init,
                checkpoint: Some(out.join("checkpoint.safetensors")),
                ..FitConfig::default()
            };
            let dev = Device::Cpu;
            let steps = (epochs * tr.len().div_ceil(batch)).min(if max_steps > 0 { max_steps } else { usize::MAX });
            let pb = bar(steps, quiet, "steps");
            let t = Instant::now();
            let (varmap, model, history) = fit(
                &cfg,
                &ds,
                &tr,
                &val,
                &dev,
                &mut |s, _, l| {
                    pb.set_position(s as u64);
                    if s % 20 == 0 {
                        pb.set_message(format!("loss {l:.3}"));
                    }
                },
                &mut |e| {
                    let v = e.val.as_ref().map_or(String::new(), |v| {
                        format!(
                            " | val: class {:.2} %, MAE h {:.2} cm, d {:.2} cm, yaw {:.2} deg",
                            100.0 * v.class_accuracy,
                            v.mae_h_cm,
                            v.mae_d_cm,
                            v.mae_yaw_deg
                        )
                    });
                    let line = format!(
                        "epoch {:>3} ({:.0} s) loss {:.4} (ce {:.4} h {:.3} d {:.3} yaw {:.3}){v}",
                        e.epoch, e.seconds, e.train.total, e.train.ce, e.train.h, e.train.d, e.train.yaw
                    );
                    if pb.is_hidden() {
                        println!("{line}");
                    } else {
                        pb.println(line);
                    }
                },
            )?;
            pb.finish_and_clear();
            // fit() wrote checkpoint.safetensors after the last epoch.
            let secs = t.elapsed().as_secs_f64();
            let mut meta = BTreeMap::new();
            meta.insert("format".into(), "g1-train terrain CNN v1 (BatchNorm folded)".into());
            meta.insert("train_samples".into(), tr.len().to_string());
            meta.insert("steps".into(), history.last().map_or(0, |e| e.steps).to_string());
            meta.insert("fit".into(), serde_json::to_string(&cfg)?);
            meta.insert(
                "loss".into(),
                format!("{LAMBDA_CLS}*CE + {LAMBDA_H}*SmoothL1(h cm) + {LAMBDA_D}*SmoothL1(d cm) + {LAMBDA_YAW}*SmoothL1(yaw vector deg)"),
            );
            let sha = fold(&varmap)?.write(&out, &meta)?;
            let pool = if val.is_empty() { &tr } else { &val };
            train::export::parity_fixture_from(&model, &ds, pool, &dev, &out.join(train::export::PARITY_FILE), &sha)?;
            train::plot::training_png(&out.join("training.png"), &history)?;
            let hist = serde_json::json!({ "config": cfg, "train_seconds": secs, "epochs": history });
            std::fs::write(out.join("history.json"), serde_json::to_string_pretty(&hist)? + "\n")?;
            println!(
                "trained {} steps in {:.1} s ({:.0} samples/s); wrote {}/{{{WEIGHTS_FILE}, {DESC_FILE}, checkpoint.safetensors, history.json}}",
                history.last().map_or(0, |e| e.steps),
                secs,
                history.last().map_or(0, |e| e.steps) as f64 * batch as f64 / secs,
                out.display()
            );
        }
        Cmd::Export { checkpoint, out, data } => {
            let mut vm = candle_nn::VarMap::new();
            let model = train::model::TerrainCnn::new(candle_nn::VarBuilder::from_varmap(
                &vm,
                candle_core::DType::F32,
                &Device::Cpu,
            ))?;
            vm.load(&checkpoint)
                .with_context(|| format!("loading {}", checkpoint.display()))?;
            let mut meta = BTreeMap::new();
            meta.insert("format".into(), "g1-train terrain CNN v1 (BatchNorm folded)".into());
            let sha = fold(&vm)?.write(&out, &meta)?;
            println!("wrote {}/{{{WEIGHTS_FILE}, {DESC_FILE}}}", out.display());
            if let Some(d) = data {
                let ds = Dataset::load_dir(&d)?;
                let (_, val) = split_by_world(&ds, 0.1);
                let path = out.join(train::export::PARITY_FILE);
                train::export::parity_fixture_from(&model, &ds, &val, &Device::Cpu, &path, &sha)?;
                println!("wrote {}", path.display());
            }
        }
        Cmd::EvalTerrain {
            worlds,
            seed,
            training_worlds,
            poses_per_world,
            mode,
            memory_keyframes,
            odometry_drift,
            weights,
            report,
            plot,
            jobs,
            quiet,
        } => {
            use g1_sim::dataset::{DatasetConfig, WorldSet, EVAL_SEED_BASE};
            let base = if training_worlds {
                eprintln!(
                    "note: --training-worlds: world seeds {seed}.. are the ones `g1-dataset export --seed {seed}` \
                     renders, NOT held out; these figures measure the fit, not generalisation"
                );
                0
            } else {
                EVAL_SEED_BASE
            };
            let first = base
                .checked_add(seed)
                .with_context(|| format!("--seed {seed}: held-out seeds start at {base} + SEED, past u64"))?;
            let set = match worlds.trim().parse::<usize>() {
                Ok(count) => WorldSet::Random {
                    first_seed: first,
                    count,
                },
                Err(_) => WorldSet::Named {
                    args: worlds
                        .split(',')
                        .map(|w| w.trim().to_string())
                        .filter(|w| !w.is_empty())
                        .collect(),
                    seed: first,
                },
            };
            set.check().context("--worlds/--seed")?;
            anyhow::ensure!(
                poses_per_world > 0,
                "--poses-per-world 0 evaluates nothing: give at least 1"
            );
            let mut net = load_net(weights.as_deref())?;
            let cfg = DatasetConfig {
                mode,
                memory: g1_sim::dataset::MemoryConfig::with_keyframes(memory_keyframes),
                odometry_drift,
                ..DatasetConfig::default()
            };
            let pb = bar(set.len() * poses_per_world, quiet, "samples");
            let r = train::eval::evaluate(&set, poses_per_world, cfg, jobs, &mut net, &|| pb.inc(1))?;
            pb.finish_and_clear();
            print!("{r}");
            let title = format!(
                "terrain token errors vs step height: {} ({} samples)",
                r.world_set, r.cnn.samples
            );
            if let Some(plot) = &plot {
                train::plot::error_vs_height_png(plot, &r.by_step_height, &title)?;
                println!("plot: {}", plot.display());
                let riser_plot = plot.with_file_name(format!(
                    "{}_by_riser.png",
                    plot.file_stem().and_then(|s| s.to_str()).unwrap_or("eval_terrain")
                ));
                let title = format!(
                    "terrain token errors vs the labelled riser's distance: {} ({} samples)",
                    r.world_set, r.cnn.samples
                );
                train::plot::error_vs_riser_png(&riser_plot, &r.by_riser_ahead, &title)?;
                println!("plot: {}", riser_plot.display());
            }
            if let Some(path) = report {
                train::eval::write_report(&path, &r)?;
                println!("report: {}", path.display());
            }
        }
    }
    Ok(())
}

/// `--vx MIN,MAX`: a forward speed range, m/s.
fn parse_vx_range(s: &str) -> Result<(f64, f64), String> {
    let bad = || format!("'{s}': give MIN,MAX in m/s with 0 <= MIN <= MAX <= 2, e.g. 0.3,0.8");
    let (a, b) = s.split_once(',').ok_or_else(bad)?;
    let (a, b): (f64, f64) = (
        a.trim().parse().map_err(|_| bad())?,
        b.trim().parse().map_err(|_| bad())?,
    );
    if !(0.0..=2.0).contains(&a) || !(a..=2.0).contains(&b) {
        return Err(bad());
    }
    Ok((a, b))
}
