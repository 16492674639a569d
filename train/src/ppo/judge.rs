//! Checkpoints judged through `g1fw` itself (issue 29: training's own metrics once ranked a worse
//! checkpoint above a better one): a fixed small set of episodes run by `firmware::eval` — the
//! lock-stepped 500 Hz loop with perception and the spec's terrain estimator, each episode its own
//! `g1-sim` — on random staircases up and down at 12, 16 and 20 cm, and a flat run. The same set
//! (same seed) every time, so the points are comparable along a run.
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use anyhow::Context;
use firmware::eval::{random_sweep, run_eval, EpisodeWorld, EvalOptions};
use serde::{Deserialize, Serialize};

/// What to run at a judged checkpoint.
#[derive(Clone, Debug)]
pub struct JudgeConfig {
    /// Judge every this many checkpoints (0: never).
    pub every: usize,
    pub heights: Vec<f64>,
    pub per_height: usize,
    pub seed: u64,
    /// `g1-sim` to run (default: beside the running executable, as `g1fw eval` finds it).
    pub sim_bin: Option<PathBuf>,
    /// Robot model of the judged runs (`g1fw eval --model`).
    pub model: String,
    /// More models the same set runs on (rows labelled `up/MODEL`, `down/MODEL`, `flat/MODEL`).
    pub also_models: Vec<String>,
    /// The deployed policy's spec (with its own weights), judged once on the same set into
    /// `reference.json`: the level a run must pass (a line in `curves.png`).
    pub reference: Option<PathBuf>,
}

impl JudgeConfig {
    /// Up and down at 12, 16, 20 and 22 cm, 2 episodes each, and a flat run: 17 episodes.
    pub fn standard(every: usize, model: &str) -> Self {
        Self {
            every,
            heights: vec![0.12, 0.16, 0.20, 0.22],
            per_height: 2,
            seed: 29,
            sim_bin: None,
            model: model.to_string(),
            also_models: Vec::new(),
            reference: None,
        }
    }
}

/// One judged checkpoint (a line of `judge.json`).
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct Judgement {
    pub env_steps: u64,
    pub wall_s: f64,
    /// The actor judged (`actors/actor_<steps>.safetensors`).
    pub actor: String,
    /// Per row of the sweep: kind (`up`/`down`/`flat`), step height (cm), successes, episodes.
    pub rows: Vec<(String, u32, u64, u64)>,
    /// Success over the stair episodes.
    pub stair_success: f64,
    /// The flat run ended without a fall or trip.
    pub flat_ok: bool,
    /// The flat run's mean speed along its heading, m/s, for a command of [`JUDGE_VX`]: a policy
    /// that overshoots the command on flat ground shows here (issue 29's tracking criterion).
    #[serde(default)]
    pub flat_speed_mps: Option<f64>,
    /// Ranking: stair successes, plus one for a clean flat run.
    pub score: f64,
    pub eval_wall_s: f64,
}

/// The forward speed every judged episode is commanded, m/s.
pub const JUDGE_VX: f32 = 0.5;

/// Runs the judged set on `actor` (weights for `spec`), on `cfg.model` and each of
/// `cfg.also_models`: one judgement whose rows name the other models, whose stair success and
/// score count every model, and whose flat run is clean only when it is on every model.
pub fn judge(cfg: &JudgeConfig, spec: &Path, actor: &Path, env_steps: u64, wall_s: f64) -> anyhow::Result<Judgement> {
    let mut j = judge_one(cfg, &cfg.model, spec, actor, env_steps, wall_s)?;
    for model in &cfg.also_models {
        let o = judge_one(cfg, model, spec, actor, env_steps, wall_s)?;
        j.rows.extend(
            o.rows
                .into_iter()
                .map(|(kind, cm, s, e)| (format!("{kind}/{model}"), cm, s, e)),
        );
        j.flat_ok &= o.flat_ok;
        j.eval_wall_s += o.eval_wall_s;
    }
    // Over every model: stair successes per episode, and one point when every flat run is clean.
    let (ok, n) = j
        .rows
        .iter()
        .filter(|r| !r.0.starts_with("flat"))
        .fold((0u64, 0u64), |(a, b), r| (a + r.2, b + r.3));
    j.stair_success = if n > 0 { ok as f64 / n as f64 } else { 0.0 };
    j.score = ok as f64 + j.flat_ok as u8 as f64;
    Ok(j)
}

fn judge_one(
    cfg: &JudgeConfig,
    model: &str,
    spec: &Path,
    actor: &Path,
    env_steps: u64,
    wall_s: f64,
) -> anyhow::Result<Judgement> {
    let (mut episodes, _scratch) = random_sweep(
        &cfg.heights,
        &[true, false],
        cfg.per_height,
        cfg.seed,
        &std::env::temp_dir(),
    )?;
    episodes.push(EpisodeWorld {
        world: "flat".into(),
        drawn: None,
    });
    let opts = EvalOptions {
        spec: spec.to_path_buf(),
        weights: Some(actor.to_path_buf()),
        model: model.to_string(),
        terrain_source: None,
        vx: JUDGE_VX,
        time_limit_s: 20.0,
        jobs: 1,
        seed: cfg.seed,
        episodes,
        stop_after_landing_s: Some(1.0),
        sim_bin: cfg.sim_bin.clone(),
        physics: None,
        hold_line: false,
        progress: false,
        stop: Arc::new(AtomicBool::new(false)),
    };
    let report = run_eval(&opts).with_context(|| format!("judging {} through g1fw eval", actor.display()))?;
    let rows: Vec<(String, u32, u64, u64)> = report
        .table
        .iter()
        .map(|r| (r.kind.clone(), r.step_height_cm, r.successes, r.episodes))
        .collect();
    let (mut ok, mut n) = (0u64, 0u64);
    let mut flat_ok = false;
    for (kind, _, s, e) in &rows {
        if kind == "flat" {
            flat_ok = *s == *e && *e > 0;
        } else {
            ok += s;
            n += e;
        }
    }
    let flat_speed_mps = report
        .results
        .iter()
        .find(|e| e.kind == "flat" && e.time_s > 0.0)
        .map(|e| e.progress_m / e.time_s);
    let stair_success = if n > 0 { ok as f64 / n as f64 } else { 0.0 };
    Ok(Judgement {
        env_steps,
        wall_s,
        actor: actor.display().to_string(),
        rows,
        stair_success,
        flat_ok,
        flat_speed_mps,
        score: ok as f64 + flat_ok as u8 as f64,
        eval_wall_s: report.wall_s,
    })
}
