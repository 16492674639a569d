//! `g1-train ppo`: the training loop (rollouts on worker threads, the update on the main thread),
//! checkpoints that resume, learning curves (JSON + PNG) and the export `g1fw` runs.
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use anyhow::Context;
use control::spec::DeploySpec;
use g1_sim::ModelChoice;
use labkit::rng::Rng;
use serde::{Deserialize, Serialize};

use super::algo::{compute_gae, EnvRollout, Learner, Normalizer, PpoConfig, UpdateStats};
use super::env::{EnvConfig, StairEnv, CRITIC_EXTRA};
use super::judge::Judgement;
use super::policy::{ActorArch, ActorCritic, Sizes};
use super::rollout::{rollout, NoiseHold, Slot};

/// The action noise σ of a run that is not told otherwise (in units of the action scale).
pub const DEFAULT_INIT_STD: f64 = 0.3;
pub const CHECKPOINT: &str = "checkpoint.safetensors";
/// Folder of the actor at every checkpoint, named by env steps (`g1fw eval --weights`).
pub const ACTORS: &str = "actors";
pub const STATE: &str = "state.json";
pub const HISTORY: &str = "history.json";
pub const CURVES: &str = "curves.png";
/// Checkpoints judged through `g1fw` ([`super::judge`]), and the best of them.
pub const JUDGE: &str = "judge.json";
pub const BEST: &str = "best.safetensors";
/// The deployed policy judged on the same set ([`super::judge::JudgeConfig::reference`]).
pub const REFERENCE: &str = "reference.json";

#[derive(Clone, Debug)]
pub struct RunConfig {
    pub spec: PathBuf,
    pub model: ModelChoice,
    /// A second robot model and its share of the environments (spread evenly over the columns
    /// and both pipeline halves), so one actor learns both bodies it is deployed on.
    pub mixed_model: Option<(ModelChoice, f64)>,
    pub out: PathBuf,
    pub envs: usize,
    pub threads: usize,
    pub iterations: usize,
    pub seed: u64,
    /// Warm start: an actor in the spec's layout (its input widened with zero columns).
    pub init_actor: Option<PathBuf>,
    /// The critic, its input normaliser and the action noise that go with the actor
    /// ([`super::critic_file`]), so a fine-tune continues instead of training a new critic.
    pub init_critic: Option<PathBuf>,
    /// Hidden sizes of a fresh actor (one per linear/lstm layer of the spec's network but the
    /// last); unused when resuming or warm-starting, where the weights give them.
    pub actor_hidden: Vec<usize>,
    /// Learn every transition mirrored too (left–right symmetry; feed-forward actors only).
    pub symmetry: bool,
    /// Initial action noise σ; `None`: [`DEFAULT_INIT_STD`], or the noise in `init_critic`'s file.
    /// Given with `init_critic`, it replaces the file's noise.
    pub init_std: Option<f64>,
    /// Exploration of the gait clock's rate output (a spec with `[phase] rate`): its own initial σ
    /// (after `init_std` or the critic file's) and its noise held over several policy steps.
    pub rate_noise: RateNoise,
    pub critic_warmup: usize,
    pub ppo: PpoConfig,
    /// How environments are drawn, commanded and rewarded.
    pub env: super::env::EnvSettings,
    /// Checkpoint every this many iterations. Each checkpoint restarts every environment (see
    /// [`super::checkpoint`]), so this is part of the recipe: the grid is what makes a resumed
    /// run the run that went on.
    pub checkpoint_every: usize,
    pub quiet: bool,
    /// Stop at the first checkpoint after this many seconds of wall time.
    pub max_wall_s: f64,
    /// Resume even though the checkpoint was written under other settings (a change of recipe
    /// mid-run, on purpose); otherwise such a resume is refused, naming the difference.
    pub accept_recipe_change: bool,
    /// Judge checkpoints through `g1fw` (`judge.json`, `best.safetensors`); `every` 0: never.
    pub judge: super::judge::JudgeConfig,
}

pub use super::iter_log::IterLog;

/// How the gait clock's rate output explores ([`RunConfig::rate_noise`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RateNoise {
    /// Its initial σ on a new run; `None`: as the joints'.
    pub std: Option<f64>,
    /// Policy steps its noise is held ([`NoiseHold::every`]); 1: drawn each step, as the joints'.
    pub hold: usize,
}

impl RateNoise {
    pub const PER_STEP: RateNoise = RateNoise { std: None, hold: 1 };
}

/// PPO's rollout workers already take every core, with the learner beside them. candle splits each
/// matrix product over all cores through rayon, whose workers then spin between the update's
/// small products on the cores the rollouts need: with the learner on one thread an update took
/// 0.17 s instead of 0.23 s, and the loop ran 10.2k env steps/s instead of 8.8k (A/B, 2 cores).
/// Call first thing in `main`, before any thread exists; an explicit `RAYON_NUM_THREADS` wins.
pub fn learner_on_one_thread() {
    if std::env::var_os("RAYON_NUM_THREADS").is_none() {
        std::env::set_var("RAYON_NUM_THREADS", "1");
    }
}

/// What resumes a run (beside the weights in checkpoint.safetensors).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct RunState {
    pub iteration: usize,
    pub env_steps: u64,
    pub wall_s: f64,
    pub lr: f64,
    pub normalizer: Normalizer,
    pub levels: Vec<usize>,
    /// Where the run started from (the recipe).
    pub started_from: String,
}

/// The settings that decide what a run computes, one per line (the checkpoint keeps them; a resume
/// under others is refused, naming the lines). What only decides how long, where, on how many
/// threads, or how it is judged, is left out: none of it changes a bit of the run.
pub fn recipe_text(cfg: &RunConfig) -> String {
    let mut c = cfg.clone();
    c.out = PathBuf::new();
    c.threads = 0;
    c.iterations = 0;
    c.max_wall_s = 0.0;
    c.quiet = false;
    c.accept_recipe_change = false;
    // The spec counts by its content (its sha256, checked beside); the start's files only start.
    c.spec = PathBuf::new();
    c.init_actor = None;
    c.init_critic = None;
    without_added_defaults(&without_judge(&format!("{c:#?}")))
}

/// Settings added after runs began, at their defaults: left out of the recipe's text, so a run
/// whose checkpoint predates them resumes as before (set, they show as a change).
const ADDED_AT_DEFAULT: [&str; 1] = ["max_std: None,"];

fn without_added_defaults(recipe: &str) -> String {
    recipe
        .lines()
        .filter(|l| !ADDED_AT_DEFAULT.contains(&l.trim()))
        .map(|l| format!("{l}\n"))
        .collect()
}

/// A recipe's text without its `judge` block (how a run is judged changes nothing it computes;
/// checkpoints written before it was left out hold it).
fn without_judge(recipe: &str) -> String {
    let mut out = String::new();
    let mut skipping = false;
    for line in recipe.lines() {
        if line.starts_with("    judge: ") {
            skipping = !line.ends_with(',');
            continue;
        }
        if skipping {
            skipping = line != "    },";
            continue;
        }
        out.push_str(line);
        out.push('\n');
    }
    out
}

/// The training loop: start (or resume), then iterations of a pipelined rollout and update, each
/// logged, checkpointed every `checkpoint_every` iterations and judged through `g1fw` every few
/// checkpoints.
pub fn train(cfg: &RunConfig) -> anyhow::Result<Vec<IterLog>> {
    anyhow::ensure!(
        cfg.checkpoint_every > 0,
        "--checkpoint-every must be at least 1 iteration"
    );
    std::fs::create_dir_all(&cfg.out).with_context(|| format!("creating {}", cfg.out.display()))?;
    let spec =
        DeploySpec::load(&cfg.spec).with_context(|| format!("loading the deploy spec {}", cfg.spec.display()))?;
    let dims = Dims {
        obs: spec.observation_dim(),
        act: spec.action_dim(),
        joints: spec.num_joints(),
        critic: spec.observation_dim() + CRITIC_EXTRA,
        state: 0,
    };
    anyhow::ensure!(
        dims.act > dims.joints || cfg.rate_noise == RateNoise::PER_STEP,
        "--rate-std and --rate-hold need a spec whose policy sets its gait clock ([phase] rate); {} has none",
        cfg.spec.display()
    );
    let spec_sha256 = control::nn::sha256_hex(
        &input_file::read_capped(&cfg.spec, control::spec::MAX_SPEC_BYTES as u64)
            .with_context(|| format!("reading {}", cfg.spec.display()))?,
    );
    let recipe = recipe_text(cfg);
    let (ac, mut state, mut history, loaded) = start_or_resume(cfg, &spec, dims, &recipe, &spec_sha256)?;
    let dims = Dims {
        state: ac.state_len(),
        ..dims
    };
    let mirror = if cfg.symmetry {
        Some(super::symmetry::Mirror::from_spec(
            &spec,
            &StairEnv::critic_extra_mirror(),
        )?)
    } else {
        None
    };
    // The export beside the checkpoint carries the spec's weights file name.
    let weights_name = spec
        .policy
        .weights
        .file_name()
        .map_or_else(|| "policy.safetensors".into(), |n| n.to_os_string());
    let note = match &loaded {
        None => format!("new run: {}", state.started_from),
        Some(l) if without_judge(&l.recipe) != recipe => format!(
            "resumed under a changed recipe: {}",
            super::checkpoint::recipe_difference(&without_judge(&l.recipe), &recipe, 8).join("; ")
        ),
        Some(_) => "resumed".to_string(),
    };
    let mut chunks = super::chunks::read(&cfg.out);
    chunks.push(super::chunks::Chunk {
        started_utc: super::chunks::now_utc(),
        commit: super::chunks::commit(&cfg.out),
        cpu: super::chunks::cpu_model(),
        threads: cfg.threads,
        from_iteration: state.iteration,
        to_iteration: state.iteration,
        from_env_steps: state.env_steps,
        to_env_steps: state.env_steps,
        wall_s: 0.0,
        note,
    });
    let mut learner = Learner::new(&ac, cfg.ppo, cfg.seed, mirror)?;
    learner.lr = state.lr;
    if let Some(l) = &loaded {
        state.normalizer = l.apply(&ac, &mut learner)?;
        state.lr = learner.lr;
    }
    drop(loaded);
    let mut slots = make_envs(cfg, spec, &ac, &state)?;
    restart_envs(cfg, &mut slots, &state, dims)?;
    let mut pipe = Pipeline::new(slots.len(), state.iteration)?;
    let identity = super::checkpoint::Identity {
        recipe: &recipe,
        spec_sha256: &spec_sha256,
    };

    let start = Instant::now();
    let wall0 = state.wall_s;
    let bar = labkit::progress::bar(cfg.iterations, cfg.quiet, "PPO");
    bar.set_position(state.iteration.min(cfg.iterations) as u64);
    while state.iteration < cfg.iterations {
        // Assisted episodes that start from now on get the strength the run's env steps leave.
        let strength = cfg.env.assist.strength(state.env_steps);
        for s in slots.iter_mut() {
            s.env.set_assist_strength(strength);
        }
        let Some(step) = pipe.step(cfg, &mut slots, &ac, &mut learner, &mut state, dims)? else {
            continue; // nothing learned yet: the first half-rollout only primes the pipeline
        };
        state.env_steps += step.env_steps;
        state.iteration += 1;
        state.lr = learner.lr;
        let log = iteration_log(
            &mut slots,
            &state,
            step,
            strength,
            wall0 + start.elapsed().as_secs_f64(),
        );
        bar.set_message(log.summary());
        bar.inc(1);
        if cfg.quiet {
            tracing::info!(?log, "iteration");
        }
        history.push(log);
        thin_history(&mut history);
        // This run's own time (`--max-wall`), not the total across resumed chunks; it stops at
        // the next checkpoint, so a stop for time falls on the grid like any other.
        let out_of_time = start.elapsed().as_secs_f64() > cfg.max_wall_s;
        state.wall_s = wall0 + start.elapsed().as_secs_f64();
        let on_grid = state.iteration.is_multiple_of(cfg.checkpoint_every);
        if on_grid || state.iteration == cfg.iterations {
            // The pending half-rollout is dropped and every episode restarts, here as in the
            // run that resumes from this checkpoint.
            restart_envs(cfg, &mut slots, &state, dims)?;
            pipe = Pipeline::new(slots.len(), state.iteration)?;
            state.levels = slots.iter().map(|s| s.env.level).collect();
            let actor = save(&ac, &learner, &state, &history, &cfg.out, &weights_name, &identity)?;
            if let Some(c) = chunks.last_mut() {
                c.to_iteration = state.iteration;
                c.to_env_steps = state.env_steps;
                c.wall_s = start.elapsed().as_secs_f64();
            }
            super::chunks::write(&cfg.out, &chunks)?;
            // Every `every`th checkpoint of the run's grid (counted from its start, so a run that
            // is stopped and resumed often is judged as one that is not).
            let grid_index = state.iteration / cfg.checkpoint_every;
            if cfg.judge.every > 0 && grid_index.is_multiple_of(cfg.judge.every) {
                // A judge that cannot run (a missing g1-sim, a full disk) must not end hours of
                // training: say so, and go on; the checkpoint is written.
                if let Err(e) = judge_checkpoint(cfg, &actor, &state, &history) {
                    tracing::warn!(
                        "judging {} through g1fw failed, training goes on: {e:#}",
                        actor.display()
                    );
                }
            }
        }
        if out_of_time && on_grid {
            tracing::warn!("wall-time limit reached; checkpoint written, resume with the same command");
            break;
        }
    }
    bar.finish();
    if state.iteration >= cfg.iterations {
        // The default count (1000) ends a run long before most `--max-wall` limits.
        tracing::info!(
            "stopped at --iterations {} ({} env steps); checkpoint written, resume with a larger --iterations",
            cfg.iterations,
            state.env_steps
        );
    }
    Ok(history)
}

/// Iterations of the history kept whole; before them, one in [`HISTORY_STRIDE`]. A run of
/// ~200 000 iterations keeps its curves in ~1.5 MB (each iteration's line is ~650 bytes).
pub const HISTORY_RECENT: usize = 2000;
pub const HISTORY_STRIDE: usize = 100;

/// Drops the older iterations' lines but every [`HISTORY_STRIDE`]th (the curves keep their shape;
/// the file stays small enough for a run that lives in the repository).
fn thin_history(history: &mut Vec<IterLog>) {
    let Some(last) = history.last().map(|l| l.iteration) else {
        return;
    };
    let cutoff = last.saturating_sub(HISTORY_RECENT);
    history.retain(|l| l.iteration >= cutoff || l.iteration.is_multiple_of(HISTORY_STRIDE));
}

/// Widths of the actor's observation, the action and the critic's observation.
#[derive(Clone, Copy)]
struct Dims {
    obs: usize,
    act: usize,
    /// The joint outputs; `act` has the clock's rate beyond them.
    joints: usize,
    critic: usize,
    /// The actor's recurrent state (the rollout's `state0`); 0 for an MLP.
    state: usize,
}

/// The actor-critic, run state and history: from `--out`'s checkpoint when there is one, else new
/// (warm-started from `--init-actor` when given).
type Started = (ActorCritic, RunState, Vec<IterLog>, Option<super::checkpoint::Loaded>);

fn start_or_resume(
    cfg: &RunConfig,
    spec: &DeploySpec,
    dims: Dims,
    recipe: &str,
    spec_sha256: &str,
) -> anyhow::Result<Started> {
    let ckpt = cfg.out.join(CHECKPOINT);
    let resuming = ckpt.exists();
    let loaded = if resuming {
        let l = super::checkpoint::read(&ckpt)?;
        anyhow::ensure!(
            l.spec_sha256 == spec_sha256,
            "{} was trained under a deploy spec with sha256 {}, and {} has {spec_sha256}: resume with the spec it was trained with",
            ckpt.display(),
            l.spec_sha256,
            cfg.spec.display()
        );
        if without_judge(&l.recipe) != recipe {
            let diff = super::checkpoint::recipe_difference(&without_judge(&l.recipe), recipe, 8);
            anyhow::ensure!(
                cfg.accept_recipe_change,
                "{} was trained under other settings ({}); resume with the run's own recipe, or pass --accept-recipe-change to change it mid-run on purpose",
                ckpt.display(),
                diff.join("; ")
            );
            tracing::warn!(
                "resuming {} under a changed recipe: {}",
                ckpt.display(),
                diff.join("; ")
            );
        }
        Some(l)
    } else {
        None
    };
    // The actor's layers are the spec's; their sizes come from the weights it continues from.
    let sized_by = if resuming {
        Some(ckpt.clone())
    } else {
        cfg.init_actor.clone()
    };
    let bytes = match &sized_by {
        Some(p) => Some(
            input_file::read_capped(p, control::nn::MAX_WEIGHTS_BYTES)
                .with_context(|| format!("reading {}", p.display()))?,
        ),
        None => None,
    };
    let sizes = match &bytes {
        Some(b) => Sizes::Weights(b),
        None => Sizes::Hidden(&cfg.actor_hidden),
    };
    let arch = ActorArch::from_desc(&spec.policy.network, dims.act, sizes)
        .with_context(|| format!("the actor of {}", cfg.spec.display()))?;
    let mut ac = ActorCritic::with_arch(arch, dims.critic, cfg.init_std.unwrap_or(DEFAULT_INIT_STD), cfg.seed)?;
    ac.recurrence = cfg.ppo.recurrence;
    // The policy as the spec runs it: with `mirror = "average"` the update replays the twin too.
    ac.mirror = control::spec::mirror::PolicyMirror::averaged_with(spec)?;
    if let Some(l) = loaded {
        let c = &l.counters;
        let mut st = RunState {
            iteration: c.iteration,
            env_steps: c.env_steps,
            wall_s: c.wall_s,
            lr: f64::from_bits(c.lr_bits),
            normalizer: Normalizer::new(dims.critic), // the checkpoint's, once the learner exists
            levels: c.levels.clone(),
            started_from: c.started_from.clone(),
        };
        if st.levels.len() != cfg.envs {
            anyhow::ensure!(
                cfg.accept_recipe_change && !st.levels.is_empty(),
                "{} holds {} environments' levels and the recipe asks for {} environments \
                 (--accept-recipe-change resumes with the levels repeated or cut)",
                ckpt.display(),
                st.levels.len(),
                cfg.envs
            );
            // More environments start at the levels the run had reached, in turn; fewer keep the first.
            st.levels = (0..cfg.envs).map(|i| st.levels[i % st.levels.len()]).collect();
        }
        // The history is the curves' record; the checkpoint's own counters say where it stands.
        // A damaged record is refused here, not read as empty (and then overwritten).
        let history: Vec<IterLog> = read_run_json(&cfg.out, HISTORY)?.unwrap_or_default();
        let history = history.into_iter().filter(|h| h.iteration <= st.iteration).collect();
        read_judgements(&cfg.out)?;
        read_reference(&cfg.out)?;
        tracing::info!(
            "resuming {} at iteration {} ({} env steps)",
            cfg.out.display(),
            st.iteration,
            st.env_steps
        );
        return Ok((ac, st, history, Some(l)));
    }
    let started_from = match &cfg.init_actor {
        Some(p) => {
            let w = ac.load_actor_widened(p)?;
            let mut s = format!("actor warm-started from {}", p.display());
            if w.inputs > 0 {
                s += &format!(" (input widened by {} zero columns: the token)", w.inputs);
            }
            if w.outputs > 0 {
                s += &format!(
                    " (output widened by {} zero rows: the gait clock's rate, at 1)",
                    w.outputs
                );
            }
            s
        }
        None => "random initialisation".to_string(),
    };
    let (normalizer, started_from) = match &cfg.init_critic {
        None => (Normalizer::new(dims.critic), started_from),
        Some(p) => {
            let (normalizer, from) = super::critic_file::load(&ac, p)?;
            if let Some(std) = cfg.init_std {
                // An explicit --init-std wins over the file's noise (e.g. more exploration).
                ac.set_action_std(std)?;
            }
            let actor_sha = control::nn::sha256_hex(&ac.actor_safetensors()?);
            if from.actor_sha256 != actor_sha {
                // Allowed (a critic of a related actor beats a new one), but never silently.
                tracing::warn!(
                    "{} was trained with actor sha256 {}, not this run's start actor ({actor_sha})",
                    p.display(),
                    from.actor_sha256
                );
            }
            let (what, noise) = match cfg.init_std {
                None => ("critic, normaliser and action noise", String::new()),
                Some(std) => ("critic and normaliser", format!(", action noise {std} (--init-std)")),
            };
            let s = format!(
                "{started_from}; {what} from {} (written at {} env steps){noise}",
                p.display(),
                from.env_steps
            );
            (normalizer, s)
        }
    };
    let started_from = match cfg.rate_noise.std {
        None => started_from,
        Some(std) => {
            ac.set_action_std_from(dims.joints, std)?;
            format!("{started_from}; the clock rate's action noise {std} (--rate-std)")
        }
    };
    let state = RunState {
        iteration: 0,
        env_steps: 0,
        wall_s: 0.0,
        lr: cfg.ppo.lr,
        normalizer,
        levels: Vec::new(),
        started_from,
    };
    Ok((ac, state, Vec::new(), None))
}

/// `cfg.envs` environments with the actor's weights, at the levels a resumed run left them.
fn make_envs(cfg: &RunConfig, spec: DeploySpec, ac: &ActorCritic, state: &RunState) -> anyhow::Result<Vec<Slot>> {
    let weights = ac.actor_safetensors()?;
    let env_cfg = EnvConfig {
        model: cfg.model.clone(),
        spec: Arc::new(spec),
        settings: cfg.env,
    };
    let bar = labkit::progress::bar(cfg.envs, cfg.quiet, "creating environments");
    let mut slots = Vec::with_capacity(cfg.envs);
    for i in 0..cfg.envs {
        let seed = cfg.seed.wrapping_mul(1_000_003).wrapping_add(i as u64);
        let cfg_i = match &cfg.mixed_model {
            Some((model, share)) if takes_mixed_model(i, *share) => EnvConfig {
                model: model.clone(),
                ..env_cfg.clone()
            },
            _ => env_cfg.clone(),
        };
        let mut env = StairEnv::new(cfg_i, seed, &weights)?;
        // A new run's level is the one the environment drew; a resumed run's, the checkpoint's.
        // `restart_envs` places it.
        if let Some(&level) = state.levels.get(i) {
            env.level = level;
        }
        slots.push(Slot {
            env,
            roll: EnvRollout::new(0, 0, 0, 0, 0),
            rng: Rng(0),
            ends: Vec::new(),
            held: Vec::new(),
            held_left: 0,
        });
        bar.inc(1);
    }
    bar.finish_and_clear();
    if let Some((model, share)) = &cfg.mixed_model {
        let mixed = (0..cfg.envs).filter(|&i| takes_mixed_model(i, *share)).count();
        tracing::info!(
            "environments: {} on {}, {mixed} on {model}",
            cfg.envs - mixed,
            cfg.model
        );
    }
    Ok(slots)
}

/// Restarts every environment at its column and level with random streams drawn from (run seed,
/// environment, iteration), and empties its rollout buffer and noise: at the start of a run and at
/// every checkpoint, so that a run resumed from a checkpoint and the run that went on past it
/// continue from the same state.
fn restart_envs(cfg: &RunConfig, slots: &mut [Slot], state: &RunState, dims: Dims) -> anyhow::Result<()> {
    let strength = cfg.env.assist.strength(state.env_steps);
    let state_len = dims.state;
    for (i, s) in slots.iter_mut().enumerate() {
        let seed = cfg
            .seed
            .wrapping_mul(1_000_003)
            .wrapping_add(i as u64)
            .wrapping_add((state.iteration as u64).wrapping_mul(0x9E37_79B9));
        let column = super::curriculum::Column::for_env(i, cfg.envs, cfg.env.only, cfg.env.mix);
        s.env.set_assist_strength(strength);
        let level = s.env.level;
        s.env.restart(seed, column, level)?;
        s.rng = Rng(seed ^ 0xAC7_10A5);
        s.held.clear();
        s.held_left = 0;
        s.ends.clear();
        s.roll = EnvRollout::new(cfg.ppo.steps, dims.obs, dims.critic, dims.act, state_len);
    }
    Ok(())
}

/// Whether environment `i` runs the mixed-in model at `share` of the environments: spread evenly
/// by index (as a line is drawn on a pixel grid), so every column and both pipeline halves, which
/// are contiguous index ranges, get their share of it.
pub fn takes_mixed_model(i: usize, share: f64) -> bool {
    ((i + 1) as f64 * share).floor() > (i as f64 * share).floor()
}

/// What one pipelined step learned, and how long its parts took.
struct Step {
    env_steps: u64,
    stats: UpdateStats,
    mean_reward: f64,
    t_iter: f64,
    t_rollout: f64,
    t_learn: f64,
}

/// The environments form two halves that take turns: while one half rolls out on the worker
/// threads with the newest weights, the learner (this thread) updates on the other half's rollout,
/// which is one update old (PPO's ratio and clip take the lag). There is a worker per core, so a
/// cheap update (an MLP) leaves every core to the simulation, and an expensive one (the LSTM's
/// recurrent replay) still overlaps it.
struct Pipeline {
    half: usize,
    have_data: [bool; 2],
    turn: usize,
}

impl Pipeline {
    fn new(envs: usize, iteration: usize) -> anyhow::Result<Self> {
        let half = envs / 2;
        anyhow::ensure!(half > 0, "--envs must be at least 2 (two halves take turns)");
        Ok(Self {
            half,
            have_data: [false; 2],
            turn: iteration % 2,
        })
    }

    /// One half rolls out while the learner updates on the other; `None` until both halves have
    /// data (the first call only primes the pipeline).
    fn step(
        &mut self,
        cfg: &RunConfig,
        slots: &mut [Slot],
        ac: &ActorCritic,
        learner: &mut Learner,
        state: &mut RunState,
        dims: Dims,
    ) -> anyhow::Result<Option<Step>> {
        let t0 = Instant::now();
        let log_std: Vec<f32> = ac.log_std().to_vec1()?;
        // The outputs past the joints (the clock's rate) explore with held noise.
        let hold = NoiseHold {
            from: dims.joints,
            every: cfg.rate_noise.hold,
        };
        let (first, second) = slots.split_at_mut(self.half);
        let (rolling, learning) = if self.turn == 0 {
            (first, second)
        } else {
            (second, first)
        };
        let learn_idx = 1 - self.turn;
        let mut rolls: Vec<EnvRollout> = learning
            .iter_mut()
            .map(|s| std::mem::replace(&mut s.roll, EnvRollout::new(0, 0, 0, 0, 0)))
            .collect();
        let per = rolling.len().div_ceil(cfg.threads.max(1));
        let critic_only = state.iteration < cfg.critic_warmup;
        let have_data = self.have_data[learn_idx];
        let (results, learned) = std::thread::scope(|s| {
            let handles: Vec<_> = rolling
                .chunks_mut(per)
                .map(|chunk| {
                    let ls = &log_std;
                    s.spawn(move || {
                        let t = Instant::now();
                        let r = rollout(chunk, ls, hold, cfg.ppo.steps, dims.obs, dims.critic);
                        (r, t.elapsed().as_secs_f64())
                    })
                })
                .collect();
            let learned = have_data.then(|| {
                let t1 = Instant::now();
                let r = (|| -> anyhow::Result<UpdateStats> {
                    for r in &rolls {
                        state.normalizer.update(&r.critic_obs);
                    }
                    compute_gae(ac, &state.normalizer, &mut rolls, &cfg.ppo)?;
                    Ok(learner.update(ac, &state.normalizer, &rolls, critic_only)?)
                })();
                (r, t1.elapsed().as_secs_f64())
            });
            let results: Vec<(anyhow::Result<()>, f64)> = handles
                .into_iter()
                .map(|h| h.join().expect("rollout worker panicked"))
                .collect();
            (results, learned)
        });
        let mut t_rollout = 0.0f64;
        for (r, t) in results {
            r?;
            t_rollout = t_rollout.max(t);
        }
        self.have_data[self.turn] = true;
        let t_iter = t0.elapsed().as_secs_f64();
        let (stats, t_learn) = match learned {
            Some((r, t)) => (r?, t),
            None => (UpdateStats::default(), 0.0),
        };
        if t_learn > 0.0 {
            // Loaded once and cloned: loading packs and hashes the weights, 128 times an update.
            let weights = ac.actor_safetensors()?;
            let desc = slots[0].env.network_desc().clone();
            let net = control::nn::Network::from_safetensors_bytes(&desc, &weights)?;
            for s in slots.iter_mut() {
                s.env.set_actor(&net);
            }
        }
        let mean_reward = rolls.iter().flat_map(|r| &r.rewards).map(|&x| x as f64).sum::<f64>()
            / ((cfg.ppo.steps * rolls.len()) as f64).max(1.0);
        let learned_envs: &mut [Slot] = if self.turn == 0 {
            &mut slots[self.half..]
        } else {
            &mut slots[..self.half]
        };
        for (s, r) in learned_envs.iter_mut().zip(rolls.drain(..)) {
            s.roll = r;
        }
        self.turn = 1 - self.turn;
        Ok((t_learn > 0.0).then(|| Step {
            env_steps: (cfg.ppo.steps * self.half) as u64,
            stats,
            mean_reward,
            t_iter,
            t_rollout,
            t_learn,
        }))
    }
}

/// The iteration's figures, from the episodes that ended since the last one.
/// `assist_strength`: what this iteration's assisted episodes started with.
fn iteration_log(slots: &mut [Slot], state: &RunState, step: Step, assist_strength: f64, wall_s: f64) -> IterLog {
    let ends: Vec<_> = slots.iter_mut().flat_map(|s| s.ends.drain(..)).collect();
    use super::curriculum::Column;
    // Stand commands have no success to score; reviews are below the frontier these rates follow,
    // and assisted climbs are helped.
    let stair_ends: Vec<_> = ends
        .iter()
        .filter(|e| e.column != Some(Column::Flat) && !e.standing && !e.review && !e.assisted)
        .collect();
    let assisted: Vec<_> = ends.iter().filter(|e| e.assisted).collect();
    let going_up = |c: Option<Column>| c.is_some_and(Column::climbs);
    let going_down = |c: Option<Column>| matches!(c, Some(Column::Down | Column::OutdoorDown));
    let rate = |which: &dyn Fn(Option<Column>) -> bool| {
        let n = stair_ends.iter().filter(|e| which(e.column)).count();
        (n > 0).then(|| stair_ends.iter().filter(|e| which(e.column) && e.success).count() as f64 / n as f64)
    };
    let level = |which: &dyn Fn(Option<Column>) -> bool| {
        let l: Vec<f64> = slots
            .iter()
            .filter(|s| which(Some(s.env.column)))
            .map(|s| s.env.level as f64)
            .collect();
        (!l.is_empty()).then(|| l.iter().sum::<f64>() / l.len() as f64)
    };
    IterLog {
        iteration: state.iteration,
        env_steps: state.env_steps,
        wall_s,
        mean_reward_per_step: step.mean_reward,
        episodes: ends.len(),
        mean_episode_return: (!ends.is_empty()).then(|| ends.iter().map(|e| e.ret).sum::<f64>() / ends.len() as f64),
        success_rate: (!stair_ends.is_empty())
            .then(|| stair_ends.iter().filter(|e| e.success).count() as f64 / stair_ends.len() as f64),
        success_up: rate(&going_up),
        success_down: rate(&going_down),
        fall_rate: (!ends.is_empty()).then(|| ends.iter().filter(|e| e.fell).count() as f64 / ends.len() as f64),
        fall_causes: (0..super::env::FALL_CAUSES.len())
            .map(|c| ends.iter().filter(|e| e.fell && e.cause == c).count())
            .collect(),
        mean_level: slots.iter().map(|s| s.env.level as f64).sum::<f64>() / slots.len() as f64,
        level_up: level(&going_up),
        level_down: level(&going_down),
        success_assisted: (!assisted.is_empty())
            .then(|| assisted.iter().filter(|e| e.success).count() as f64 / assisted.len() as f64),
        assist_strength,
        env_steps_per_s: step.env_steps as f64 / step.t_iter,
        learner_share: step.t_learn / step.t_iter,
        rollout_s: step.t_rollout,
        update_s: step.t_learn,
        update: step.stats,
        return_by_term: return_by_term(&ends),
    }
}

/// The mean return per episode by reward term over `ends`, the terms that are not zero, to 1e-4
/// (the history keeps thousands of these).
fn return_by_term(ends: &[super::env::EpisodeEnd]) -> std::collections::BTreeMap<String, f64> {
    if ends.is_empty() {
        return Default::default();
    }
    super::reward::Terms::default()
        .named()
        .iter()
        .enumerate()
        .map(|(k, (name, _))| {
            let mean = ends.iter().map(|e| e.ret_by_term[k]).sum::<f64>() / ends.len() as f64;
            (name.to_string(), (mean * 1e4).round() / 1e4)
        })
        .filter(|(_, v)| *v != 0.0)
        .collect()
}

impl IterLog {
    /// One line for the progress bar.
    fn summary(&self) -> String {
        format!(
            "{:.0} steps/s  reward/step {:+.3}  return {}  level {:.2}  success {} (up {}, down {})  falls {}",
            self.env_steps_per_s,
            self.mean_reward_per_step,
            self.mean_episode_return.map_or("-".into(), |v| format!("{v:.2}")),
            self.mean_level,
            self.success_rate.map_or("-".into(), |v| format!("{:.0}%", 100.0 * v)),
            self.success_up.map_or("-".into(), |v| format!("{:.0}%", 100.0 * v)),
            self.success_down.map_or("-".into(), |v| format!("{:.0}%", 100.0 * v)),
            self.fall_rate.map_or("-".into(), |v| format!("{:.0}%", 100.0 * v)),
        )
    }
}

fn save(
    ac: &ActorCritic,
    learner: &Learner,
    state: &RunState,
    history: &[IterLog],
    out: &Path,
    weights_name: &std::ffi::OsStr,
    identity: &super::checkpoint::Identity,
) -> anyhow::Result<PathBuf> {
    // The history first: a run killed between the two resumes from the older checkpoint and
    // drops the history's newer lines.
    write_atomically(&out.join(HISTORY), serde_json::to_string(history)?.as_bytes())?;
    let counters = super::checkpoint::Counters {
        iteration: state.iteration,
        env_steps: state.env_steps,
        wall_s: state.wall_s,
        lr_bits: learner.lr.to_bits(),
        learner_rng: learner.rng.0,
        adam_step: learner.opt.step,
        critic_adam_step: learner.critic_opt.step,
        normalizer_count_bits: state.normalizer.count.to_bits(),
        levels: state.levels.clone(),
        started_from: state.started_from.clone(),
    };
    super::checkpoint::write(
        &out.join(CHECKPOINT),
        ac,
        learner,
        &state.normalizer,
        &counters,
        identity,
    )?;
    // For people: the counters in plain JSON (resuming reads the checkpoint alone).
    write_atomically(&out.join(STATE), serde_json::to_string_pretty(state)?.as_bytes())?;
    let actor = ac.actor_safetensors()?;
    std::fs::write(out.join(weights_name), &actor)?;
    let from = super::critic_file::Provenance {
        actor_sha256: control::nn::sha256_hex(&actor),
        env_steps: state.env_steps,
    };
    super::critic_file::save(
        &super::critic_file::beside(&out.join(weights_name)),
        ac,
        &state.normalizer,
        &from,
    )?;
    // Every checkpoint's actor is kept (130 KB each): training's own success rate does not rank
    // checkpoints as `g1fw eval` does (docs/stair_policy.md), so the choice is made afterwards.
    let actors = out.join(ACTORS);
    std::fs::create_dir_all(&actors)?;
    let kept = actors.join(format!("actor_{:012}.safetensors", state.env_steps));
    std::fs::write(&kept, &actor)?;
    // Its critic beside it: whichever actor is committed keeps the critic to fine-tune it with.
    super::critic_file::save(&super::critic_file::beside(&kept), ac, &state.normalizer, &from)?;
    crate::plot::ppo_curves_png(
        &out.join(CURVES),
        history,
        // Checked on resuming; here a record damaged since is drawn without (and not rewritten).
        &read_judgements(out).unwrap_or_default(),
        read_reference(out).ok().flatten().as_ref(),
    )?;
    Ok(kept)
}

/// Writes `bytes` to a temporary file beside `path`, then renames it over `path` (a run killed
/// mid-write keeps the previous file): every file a run writes goes through here.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    output_file::write_atomically(path, bytes).with_context(|| format!("writing {}", path.display()))
}

/// A JSON record of the run in `out`: `None` when the file is absent; an error naming it when it
/// cannot be read or parsed (a truncated `judge.json` read as empty would let a worse actor become
/// `best.safetensors`).
fn read_run_json<T: serde::de::DeserializeOwned>(out: &Path, name: &str) -> anyhow::Result<Option<T>> {
    let path = out.join(name);
    if !path.exists() {
        return Ok(None);
    }
    let damaged = |why: String| {
        anyhow::anyhow!(
            "{} is damaged ({why}); restore it (e.g. `git checkout -- {}`) or move it away to start that record afresh",
            path.display(),
            path.display()
        )
    };
    let text = input_file::read_text_capped(&path, 256 << 20).map_err(|e| damaged(e.to_string()))?;
    serde_json::from_str(&text)
        .map(Some)
        .map_err(|e| damaged(e.to_string()))
}

/// The deployed policy judged on the run's set (`reference.json`), if it has been.
pub fn read_reference(out: &Path) -> anyhow::Result<Option<Judgement>> {
    read_run_json(out, REFERENCE)
}

/// The judged checkpoints of a run so far (`judge.json`; none if absent).
pub fn read_judgements(out: &Path) -> anyhow::Result<Vec<Judgement>> {
    Ok(read_run_json(out, JUDGE)?.unwrap_or_default())
}

/// Runs the judged set on a checkpoint's actor, appends it to `judge.json`, keeps the best actor as
/// `best.safetensors` (+ `best.json`), and redraws the curves with the point.
fn judge_checkpoint(cfg: &RunConfig, actor: &Path, state: &RunState, history: &[IterLog]) -> anyhow::Result<()> {
    // The deployed policy on the same set, once per run.
    let mut reference = read_reference(&cfg.out)?;
    if let (None, Some(spec)) = (&reference, &cfg.judge.reference) {
        let weights = DeploySpec::load(spec)
            .with_context(|| format!("the judge's reference spec {}", spec.display()))?
            .weights_path();
        let r = super::judge::judge(&cfg.judge, spec, &weights, 0, 0.0)?;
        tracing::info!(
            "g1fw judged the deployed policy {}: stair success {:.0} %",
            spec.display(),
            100.0 * r.stair_success
        );
        write_atomically(&cfg.out.join(REFERENCE), serde_json::to_string_pretty(&r)?.as_bytes())?;
        reference = Some(r);
    }
    let j = super::judge::judge(&cfg.judge, &cfg.spec, actor, state.env_steps, state.wall_s)?;
    tracing::info!(
        "g1fw judged {} env steps: stair success {:.0} %, flat {}, score {} ({:.0} s)",
        j.env_steps,
        100.0 * j.stair_success,
        if j.flat_ok { "ok" } else { "failed" },
        j.score,
        j.eval_wall_s
    );
    let mut all = read_judgements(&cfg.out)?;
    let best = all.iter().map(|b| b.score).fold(f64::NEG_INFINITY, f64::max);
    if j.score > best {
        write_atomically(
            &cfg.out.join(BEST),
            &input_file::read_capped(actor, control::nn::MAX_WEIGHTS_BYTES)?,
        )?;
        write_atomically(&cfg.out.join("best.json"), serde_json::to_string_pretty(&j)?.as_bytes())?;
    }
    all.push(j);
    write_atomically(&cfg.out.join(JUDGE), serde_json::to_string_pretty(&all)?.as_bytes())?;
    crate::plot::ppo_curves_png(&cfg.out.join(CURVES), history, &all, reference.as_ref())?;
    Ok(())
}

/// Writes the actor of `checkpoint` as the weights file of `spec` (what `g1fw` loads).
pub fn export(checkpoint: &Path, spec_path: &Path) -> anyhow::Result<PathBuf> {
    let spec = DeploySpec::load(spec_path)?;
    let obs = spec.observation_dim();
    let bytes = input_file::read_capped(checkpoint, control::nn::MAX_WEIGHTS_BYTES)
        .with_context(|| format!("reading {}", checkpoint.display()))?;
    let arch = ActorArch::from_desc(&spec.policy.network, spec.action_dim(), Sizes::Weights(&bytes))?;
    let mut ac = ActorCritic::with_arch(arch, obs + CRITIC_EXTRA, 1.0, 0)?;
    ac.load(checkpoint)?;
    let path = spec.weights_path();
    std::fs::write(&path, ac.actor_safetensors()?)?;
    Ok(path)
}

#[cfg(test)]
mod tests {
    use super::super::curriculum::{Column, ColumnMix};
    use super::*;

    #[test]
    fn the_recipe_leaves_the_judge_out() {
        let text = "RunConfig {\n    envs: 4,\n    judge: JudgeConfig {\n        every: 5,\n        heights: [\n            0.12,\n        ],\n    },\n    quiet: false,\n}";
        assert_eq!(without_judge(text), "RunConfig {\n    envs: 4,\n    quiet: false,\n}\n");
    }

    #[test]
    fn a_setting_added_later_is_in_the_recipe_only_when_set() {
        let text = |max_std: Option<f64>| {
            let c = crate::ppo::algo::PpoConfig {
                max_std,
                ..Default::default()
            };
            without_added_defaults(&format!("RunConfig {{\n    ppo: {c:#?},\n}}"))
        };
        let (unset, set) = (text(None), text(Some(1.0)));
        assert!(!unset.contains("max_std"), "{unset}");
        assert!(
            set.contains("max_std: Some(\n") || set.contains("max_std: Some("),
            "{set}"
        );
        assert_eq!(
            unset.lines().count() + 3,
            set.lines().count(),
            "only the setting's own lines differ:\n{unset}\n{set}"
        );
    }

    #[test]
    fn the_history_keeps_recent_iterations_whole_and_one_in_a_stride_before() {
        let mut h = Vec::new();
        for i in 1..=(HISTORY_RECENT + 5 * HISTORY_STRIDE) {
            h.push(IterLog {
                iteration: i,
                ..Default::default()
            });
            thin_history(&mut h);
        }
        assert_eq!(h.len(), HISTORY_RECENT + 1 + 4, "the last 2001 and 100, 200, 300, 400");
        assert_eq!(h[0].iteration, HISTORY_STRIDE);
        assert!(h.windows(2).all(|w| w[0].iteration < w[1].iteration));
        assert_eq!(h.last().unwrap().iteration, HISTORY_RECENT + 5 * HISTORY_STRIDE);
    }

    #[test]
    fn a_mixed_model_gets_its_share_of_every_column_and_of_both_pipeline_halves() {
        let n = 256;
        for share in [0.25, 0.5, 0.3] {
            let mixed: Vec<usize> = (0..n).filter(|&i| takes_mixed_model(i, share)).collect();
            let want = (n as f64 * share).floor() as usize;
            assert_eq!(mixed.len(), want, "share {share}");
            let first_half = mixed.iter().filter(|&&i| i < n / 2).count();
            assert!(
                first_half.abs_diff(want - first_half) <= 1,
                "share {share}: {first_half} of {want}"
            );
            for column in [
                Column::Flat,
                Column::Up,
                Column::Down,
                Column::OutdoorUp,
                Column::OutdoorDown,
            ] {
                let of = |v: &mut dyn Iterator<Item = usize>| {
                    v.filter(|&i| Column::for_env(i, n, None, ColumnMix::default()) == column)
                        .count() as f64
                };
                let (all, in_mix) = (of(&mut (0..n)), of(&mut mixed.iter().copied()));
                assert!(
                    (in_mix - all * share).abs() <= 1.0,
                    "share {share}, {column:?}: {in_mix} of {all}"
                );
            }
        }
    }
}
