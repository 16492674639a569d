//! In-environment evaluation (`g1-train ppo-eval`): an actor run in the training environment itself
//! — the same physics profile, worlds, starts, token and walls as training — with its mean action,
//! at a held curriculum level and forward command. Training's own success rate mixes levels and
//! sampled actions; this measures one cell at a time, so a gap between training and `g1fw eval` can
//! be split into what the training environment does differently and what the policy does.
//!
//! Deterministic: episodes run in a fixed number of lanes (each its own environment and seed),
//! whatever the thread count.
use std::sync::Arc;

use serde::Serialize;

use super::env::{Column, EnvConfig, Randomization, StairEnv, FALL_CAUSES};

/// Lanes (environments) an evaluation runs its episodes in, independent of threads.
pub const LANES: usize = 8;

/// What to evaluate.
#[derive(Clone, Debug)]
pub struct InEnvOptions {
    pub model: g1_sim::ModelChoice,
    pub spec: Arc<control::spec::DeploySpec>,
    pub column: Column,
    pub level: usize,
    pub vx: f32,
    pub episodes: usize,
    pub random: Randomization,
    pub episode_s: f64,
    /// Every episode assisted at this strength ([`super::assist`]); 0: none, as on the robot.
    pub assist: f64,
    pub seed: u64,
    pub threads: usize,
}

/// One cell's outcome.
#[derive(Clone, Debug, Default, Serialize)]
pub struct InEnvReport {
    pub column: String,
    pub level: usize,
    pub step_height_m: f64,
    pub episodes: usize,
    pub successes: usize,
    pub falls: usize,
    /// Falls per cause, in the order of [`FALL_CAUSES`].
    pub fall_causes: Vec<(String, usize)>,
    /// Neither success nor fall: the episode's time ran out.
    pub timeouts: usize,
    pub mean_steps: f64,
    pub mean_return: f64,
    /// The mean return per episode split by reward term (weight · value · dt summed over the
    /// episode), in [`super::reward::Terms::named`]'s order.
    pub mean_return_by_term: Vec<(String, f64)>,
}

/// Runs `opts.episodes` episodes of `weights` (the actor, safetensors in the spec's layout).
pub fn evaluate(opts: &InEnvOptions, weights: &[u8]) -> anyhow::Result<InEnvReport> {
    let cfg = EnvConfig {
        model: opts.model.clone(),
        spec: opts.spec.clone(),
        settings: super::env::EnvSettings {
            episode_s: opts.episode_s,
            random: opts.random,
            vx: (opts.vx as f64, opts.vx as f64),
            max_init_level: 0,
            only: Some(opts.column),
            ..super::env::EnvSettings::DEFAULT
        },
    };
    let lanes = LANES.min(opts.episodes.max(1));
    let per_lane: Vec<usize> = (0..lanes)
        .map(|l| opts.episodes / lanes + usize::from(l < opts.episodes % lanes))
        .collect();
    let threads = opts.threads.clamp(1, lanes);
    let lane_ids: Vec<usize> = (0..lanes).collect();
    let chunk = lanes.div_ceil(threads);
    let ends = std::thread::scope(|s| {
        let handles: Vec<_> = lane_ids
            .chunks(chunk)
            .map(|ids| {
                let cfg = cfg.clone();
                let per_lane = &per_lane;
                s.spawn(move || -> anyhow::Result<Vec<super::env::EpisodeEnd>> {
                    let mut out = Vec::new();
                    for &lane in ids {
                        let seed = opts.seed.wrapping_mul(1_000_003).wrapping_add(lane as u64);
                        let mut env = StairEnv::new(cfg.clone(), seed, weights)?;
                        env.hold_assist(opts.assist);
                        env.hold(opts.level, opts.vx)?;
                        let mut mean = vec![0.0f32; env.net.output_dim()];
                        let mut done = 0;
                        while done < per_lane[lane] {
                            env.observe_and_act(&mut mean)?;
                            let o = env.step(&mean)?;
                            if o.terminated || o.truncated {
                                env.reset()?;
                                if let Some(e) = env.last_end.take() {
                                    if std::env::var_os("G1_IN_ENV_VERBOSE").is_some() {
                                        eprintln!(
                                            "lane {lane} success {} fell {} cause {} steps {} progress {:.2} goal {:.2} start {:.2} return {:.3} (by term {:.3})",
                                            e.success, e.fell, e.cause, e.steps, e.progress_m, e.goal_m, e.start_m, e.ret, e.ret_by_term.iter().sum::<f64>()
                                        );
                                    }
                                    out.push(e);
                                }
                                done += 1;
                            }
                        }
                    }
                    Ok(out)
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().expect("evaluation worker panicked"))
            .collect::<anyhow::Result<Vec<_>>>()
    })?;
    let ends: Vec<_> = ends.into_iter().flatten().collect();
    let n = ends.len().max(1) as f64;
    let falls = ends.iter().filter(|e| e.fell).count();
    Ok(InEnvReport {
        column: format!("{:?}", opts.column),
        level: opts.level,
        step_height_m: super::env::level_height(opts.level),
        episodes: ends.len(),
        successes: ends.iter().filter(|e| e.success).count(),
        falls,
        fall_causes: FALL_CAUSES
            .iter()
            .enumerate()
            .map(|(c, name)| (name.to_string(), ends.iter().filter(|e| e.fell && e.cause == c).count()))
            .collect(),
        timeouts: ends.iter().filter(|e| !e.fell && !e.success).count(),
        mean_steps: ends.iter().map(|e| e.steps as f64).sum::<f64>() / n,
        mean_return: ends.iter().map(|e| e.ret).sum::<f64>() / n,
        mean_return_by_term: super::reward::Terms::default()
            .named()
            .iter()
            .enumerate()
            .map(|(k, (name, _))| (name.to_string(), ends.iter().map(|e| e.ret_by_term[k]).sum::<f64>() / n))
            .collect(),
    })
}
