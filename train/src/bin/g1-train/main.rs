//! `g1-train`: train, export and evaluate the terrain CNN and the stair policy, one file per
//! subcommand beside this one. See the crate docs and `--help`.
// The trainer never runs on the robot: std's math is fine here (see clippy.toml).
#![allow(clippy::disallowed_methods)]
mod average_actors;
mod eval_terrain;
mod export;
mod fit;
mod outputs;
mod ppo;
mod ppo_eval;
mod ppo_export;
mod recipe;
mod success_curve;
mod widen_actor;

use clap::{Parser, Subcommand};

/// Trainer for the G1: the terrain CNN (BEV grid 6×60×60 → terrain token: class, step height, step
/// depth, yaw) and the stair policy (PPO on in-process MuJoCo).
///
/// Terrain CNN: `g1-dataset export --worlds 4000 --poses-per-world 8 --out data/train`, then
/// `g1-train fit --data data/train --out runs/cnn`, then
/// `g1-train eval-terrain --worlds 1000 --weights runs/cnn --report eval.json`. Stair policy:
/// `g1-train ppo --out runs/ppo`, then `g1-train ppo-export --checkpoint runs/ppo/checkpoint.safetensors`
/// and `g1fw eval` (docs/stair_policy.md).
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
    Fit(fit::Args),
    /// Fold a checkpoint (checkpoint.safetensors from `fit`) into the firmware's format again.
    Export(export::Args),
    /// Evaluate the CNN (run by the firmware's executor) and the geometric baseline side by side
    /// on held-out rendered worlds; prints MAE(h) cm, MAE(d) cm, MAE(yaw) deg and class accuracy.
    ///
    /// --worlds N renders World::random(1 000 000 + SEED + i), i < N (never used in training:
    /// exports start at seed 0); --worlds FILE.toml,PRESET,... evaluates scenario files or presets
    /// (flat, stairs-up, stairs-down, outdoor, random:SEED) instead.
    EvalTerrain(eval_terrain::Args),
    /// Train the stair policy with PPO on in-process MuJoCo environments (docs/stair_policy.md).
    ///
    /// Observations, action rules and the actor's executor are the firmware's own, built from
    /// --spec. Writes into --out: checkpoint.safetensors + state.json (re-running the same
    /// command resumes), history.json and curves.png (learning curves), the actor as g1fw loads it
    /// under the spec's weights file name (`g1-train ppo-export` puts it beside the spec).
    // Boxed: its many options would make every other command as large.
    Ppo(Box<ppo::Args>),
    /// Evaluate an actor in the training environment itself (its physics, worlds, starts, token and
    /// walls), with the mean action, at held curriculum levels: splits a gap between training's
    /// figures and `g1fw eval` into the environment's part and the policy's.
    PpoEval(ppo_eval::Args),
    /// Write a PPO checkpoint's actor as the weights file its deploy spec names.
    PpoExport(ppo_export::Args),
    /// Stair success through `g1fw eval` against env steps (one report per actor) and per riser
    /// height against the paper: a PNG and a markdown table (docs/results.md).
    SuccessCurve(success_curve::Args),
    /// Widen an actor's hidden layers so that it still computes what it did (new units start
    /// unread), to fine-tune it with more capacity: `g1-train ppo --init-actor` takes the result.
    WidenActor(widen_actor::Args),
    /// Average snapshots of one fine-tune, tensor by tensor (a "model soup"): weights a user can
    /// run with `g1fw --weights`. Only actors fine-tuned from one start average into a working one.
    AverageActors(average_actors::Args),
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

fn main() -> anyhow::Result<()> {
    keep_freed_tensors_in_the_heap();
    g1_sim::no_mujoco_log_file();
    // `ppo --resume DIR` and `ppo --recipe FILE` become the recipe's options.
    let argv = recipe::expand(std::env::args_os().collect())?;
    let cli = Cli::parse_from(&argv);
    // The README's commands are checked against the parser in CI (tests/tests/readme.rs).
    if std::env::var_os("G1_CHECK_ARGS").is_some() {
        eprintln!("G1_CHECK_ARGS is set: the arguments parse; nothing was run");
        return Ok(());
    }
    match cli.cmd {
        Cmd::Fit(args) => fit::run(args),
        Cmd::Export(args) => export::run(args),
        Cmd::EvalTerrain(args) => eval_terrain::run(args),
        Cmd::Ppo(args) => {
            train::ppo::runner::learner_on_one_thread();
            ppo::run(*args, &argv[2..])
        }
        Cmd::PpoEval(args) => ppo_eval::run(args),
        Cmd::PpoExport(args) => ppo_export::run(args),
        Cmd::SuccessCurve(args) => success_curve::run(args),
        Cmd::WidenActor(args) => widen_actor::run(args),
        Cmd::AverageActors(args) => average_actors::run(args),
    }
}
