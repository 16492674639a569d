//! PPO trainer throughput against the physics it is built on, in one run (ratios, because this
//! machine is shared and noisy): `cargo bench -p train --bench ppo_throughput`.
//!
//! 1. a bare `mj_step` loop of the training model (12-dof G1, training physics, a staircase), on one
//!    thread and on every thread at once (the machine's ceiling);
//! 2. one training environment on one thread: observation (firmware `PolicyIo`), actor (firmware
//!    executor), 4 physics steps, rewards, resets — env steps/s and its ratio to (1) / 4; for the
//!    LSTM spec and the MLP spec;
//! 3. `g1-train ppo`'s loop with every core, 128 environments: the warm-started LSTM with the
//!    runs' update (32 steps, 4 epochs × 2 minibatches), its recurrence differentiated by the fused
//!    op and by candle's ops step by step (the alternative it replaced), then with rsl_rl's update,
//!    and a fresh MLP with symmetry augmentation — env steps/s against the ceiling, rollout and
//!    update time per iteration, the share of the iteration the learner is busy (on the critical
//!    path when near 100 %) and its share of the machine's CPU time (one thread of all).
//!
//! Needs `../shared` (the 12-dof model and the peer walker for the warm start).
#![allow(clippy::disallowed_methods)]
use std::sync::Arc;
use std::time::Instant;

use control::spec::DeploySpec;
use g1_sim::world::World;
use g1_sim::{ModelChoice, SimConfig, Simulator};
use train::ppo::env::{EnvConfig, EnvSettings, StairEnv, Timing, PHYSICS_DT};
use train::ppo::policy::{ActorArch, ActorCritic, Sizes};

/// One training environment on one thread for `steps` policy steps: env steps/s.
fn one_env(spec: &DeploySpec, weights: &[u8], steps: usize) -> anyhow::Result<(f64, usize)> {
    let env_cfg = EnvConfig {
        model: ModelChoice::G1_12Dof,
        spec: Arc::new(spec.clone()),
        settings: EnvSettings {
            episode_s: 12.0,
            ..EnvSettings::DEFAULT
        },
    };
    let mut env = StairEnv::new(env_cfg, 1, weights)?;
    let a = spec.num_joints();
    let mut mean = vec![0.0; a];
    let mut extra = vec![0.0; train::ppo::env::CRITIC_EXTRA];
    let mut resets = 0;
    let t = Instant::now();
    for _ in 0..steps {
        env.observe_and_act(&mut mean)?;
        env.critic_extra(&mut extra);
        let out = env.step(&mean.clone())?;
        if out.terminated || out.truncated {
            env.reset()?;
            resets += 1;
        }
    }
    Ok((steps as f64 / t.elapsed().as_secs_f64(), resets))
}

/// `g1-train ppo`'s whole loop for a few iterations: (env steps/s, learner's share of wall time,
/// rollout s and update s per iteration).
fn whole_loop(
    spec_path: &std::path::Path,
    init_actor: Option<std::path::PathBuf>,
    actor_hidden: Vec<usize>,
    symmetry: bool,
    ppo: train::ppo::algo::PpoConfig,
    threads: usize,
    envs: usize,
) -> anyhow::Result<(f64, f64, f64, f64)> {
    let out = std::env::temp_dir().join(format!("g1_ppo_bench_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let run = train::ppo::runner::RunConfig {
        spec: spec_path.to_path_buf(),
        model: ModelChoice::G1_12Dof,
        mixed_model: None,
        out: out.clone(),
        envs,
        threads,
        iterations: 12,
        seed: 0,
        init_actor,
        init_critic: None,
        actor_hidden,
        symmetry,
        init_std: Some(0.3),
        rate_noise: train::ppo::runner::RateNoise::PER_STEP,
        critic_warmup: 0,
        ppo,
        env: EnvSettings {
            episode_s: 12.0,
            vx: (0.4, 0.8),
            ..EnvSettings::DEFAULT
        },
        checkpoint_every: usize::MAX,
        accept_recipe_change: false,
        quiet: true,
        max_wall_s: f64::INFINITY,
        judge: train::ppo::judge::JudgeConfig::standard(0, "g1-12dof"),
    };
    let history = train::ppo::runner::train(&run)?;
    let _ = std::fs::remove_dir_all(&out);
    let tail = &history[1..];
    let mean = |f: &dyn Fn(&train::ppo::runner::IterLog) -> f64| tail.iter().map(f).sum::<f64>() / tail.len() as f64;
    Ok((
        mean(&|l| l.env_steps_per_s),
        mean(&|l| l.learner_share),
        mean(&|l| l.rollout_s),
        mean(&|l| l.update_s),
    ))
}

fn main() -> anyhow::Result<()> {
    // As `g1-train ppo` runs.
    train::ppo::runner::learner_on_one_thread();
    let root = std::path::PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/.."));
    let peer = g1_sim::model::shared_dir().join("peer_policy/unitree_g1_lstm/policy.safetensors");
    if !peer.exists() {
        anyhow::bail!("{} is missing: put ../shared beside the checkout", peer.display());
    }
    let lstm_path = root.join("specs/stairs/g1_stairs_lstm.toml");
    let mlp_path = root.join("specs/stairs/g1_stairs_mlp.toml");
    let lstm = DeploySpec::load(&lstm_path)?;
    let mlp = DeploySpec::load(&mlp_path)?;
    let decimation = Timing::from_spec(&lstm)?.decimation;
    let threads = labkit::progress::default_jobs();

    // 1. Bare mj_step, one loop per thread at once (the ceiling of the machine).
    let bare = |n: usize| -> anyhow::Result<f64> {
        let world = World::preset("stairs-up").expect("preset");
        let cfg = train::ppo::env::sim_config(0);
        let mut sim = Simulator::load_in(ModelChoice::G1_12Dof, cfg, Some(&world))?;
        let hold = sim.hold_initial_pose_command();
        sim.apply_command(&hold)?;
        let t = Instant::now();
        for _ in 0..n {
            sim.data_mut().step();
        }
        Ok(t.elapsed().as_secs_f64() * 1e6 / n as f64)
    };
    let mj_us = bare(20_000)?;
    let bare_one = 1e6 / (mj_us * decimation as f64);
    let per_thread: Vec<f64> = std::thread::scope(|s| {
        let h: Vec<_> = (0..threads).map(|_| s.spawn(|| bare(20_000))).collect();
        h.into_iter()
            .map(|h| h.join().expect("bare loop"))
            .collect::<anyhow::Result<_>>()
    })?;
    let bare_all: f64 = per_thread.iter().map(|us| 1e6 / (us * decimation as f64)).sum();
    let _ = SimConfig::default();

    // 2. One environment, one thread: the warm-started LSTM, and a fresh MLP.
    let ac = ActorCritic::new(
        lstm.observation_dim(),
        lstm.observation_dim() + train::ppo::env::CRITIC_EXTRA,
        lstm.num_joints(),
        0.3,
        0,
    )?;
    ac.load_actor_widened(&peer)?;
    let (lstm_env, lstm_resets) = one_env(&lstm, &ac.actor_safetensors()?, 3000)?;
    let mlp_arch = ActorArch::from_desc(&mlp.policy.network, mlp.num_joints(), Sizes::Hidden(&MLP_HIDDEN))?;
    let mlp_ac = ActorCritic::with_arch(mlp_arch, mlp.observation_dim() + train::ppo::env::CRITIC_EXTRA, 0.3, 0)?;
    let (mlp_env, mlp_resets) = one_env(&mlp, &mlp_ac.actor_safetensors()?, 3000)?;

    // 3. The whole loop: the LSTM warm start as run 5 trained it; the MLP with symmetry, with the
    // field's update (5 epochs × 4 minibatches, [256, 128, 128]) and with the recipe this machine
    // affords (2 × 2, [128, 64, 64]).
    let field = train::ppo::algo::PpoConfig::default();
    let runs = train::ppo::algo::PpoConfig {
        steps: 32,
        epochs: 4,
        minibatches: 2,
        ..field
    };
    let step_by_step = train::ppo::algo::PpoConfig {
        recurrence: train::ppo::policy::Recurrence::StepByStep,
        ..runs
    };
    let lean = train::ppo::algo::PpoConfig {
        epochs: 2,
        minibatches: 2,
        ..field
    };
    let candle = |p: train::ppo::algo::PpoConfig| train::ppo::algo::PpoConfig { fused_mlp: false, ..p };
    let lstm = |ppo| whole_loop(&lstm_path, Some(peer.clone()), Vec::new(), false, ppo, threads, 128);
    let lstm_runs = lstm(runs)?;
    let lstm_steps = lstm(step_by_step)?;
    let mlp_run = |hidden: &[usize], ppo| whole_loop(&mlp_path, None, hidden.to_vec(), true, ppo, threads, 128);
    let mlp_loop = mlp_run(&MLP_HIDDEN, lean)?;
    let mlp_candle = mlp_run(&MLP_HIDDEN, candle(lean))?;
    let ref_loop = mlp_run(&MLP_HIDDEN, field)?;
    let ref_candle = mlp_run(&MLP_HIDDEN, candle(field))?;
    let big_loop = mlp_run(&[256, 128, 128], field)?;

    println!("PPO throughput (12-dof G1, physics dt {PHYSICS_DT} s, decimation {decimation}, {threads} threads)");
    println!("  bare mj_step (stairs world), one thread  {mj_us:8.1} µs/step  = {bare_one:8.0} env steps/s");
    println!("  bare mj_step, {threads} threads at once          {bare_all:8.0} env steps/s  (the ceiling)");
    println!(
        "  one environment, one thread, LSTM-64    {lstm_env:8.0} env steps/s  = {:.2} × bare ({lstm_resets} resets)",
        lstm_env / bare_one
    );
    println!(
        "  one environment, one thread, MLP {:?} {mlp_env:8.0} env steps/s  = {:.2} × bare ({mlp_resets} resets)",
        MLP_HIDDEN,
        mlp_env / bare_one
    );
    for (name, (rate, share, roll, upd)) in [
        ("LSTM-64, 32 steps, 4 × 2, fused recurrence (the runs)", lstm_runs),
        ("LSTM-64, 32 steps, 4 × 2, candle step by step        ", lstm_steps),
        ("MLP [128, 64, 64] + symmetry, 2 × 2, fused            ", mlp_loop),
        ("MLP [128, 64, 64] + symmetry, 2 × 2, candle's ops     ", mlp_candle),
        ("MLP [128, 64, 64] + symmetry, 5 × 4, fused            ", ref_loop),
        ("MLP [128, 64, 64] + symmetry, 5 × 4, candle's ops     ", ref_candle),
        ("MLP [256, 128, 128] + symmetry, 5 × 4, fused          ", big_loop),
    ] {
        println!(
            "  g1-train ppo, {name} {rate:6.0} env steps/s = {:.2} × the ceiling; per iteration rollout {roll:.3} s, update {upd:.3} s; learner busy {:.0} % of the iteration, {:.0} % of the CPU",
            rate / bare_all,
            100.0 * share,
            100.0 * share / threads as f64
        );
    }
    println!(
        "  fused / step-by-step recurrence: update {:.2}×, env steps/s {:.2}×",
        lstm_runs.3 / lstm_steps.3,
        lstm_runs.0 / lstm_steps.0
    );
    for (name, fused, candle, epochs, minibatches) in [
        ("2 × 2", mlp_loop, mlp_candle, lean.epochs, lean.minibatches),
        ("5 × 4", ref_loop, ref_candle, field.epochs, field.minibatches),
    ] {
        // Rows an update passes over: half the environments' rollout (the pipeline's half),
        // mirrored too; ≈ 6 flops per multiply-add and row (forward 2, backward 4).
        let rows = (field.steps * 64 * 2 * epochs) as f64;
        let gflop = rows * 6.0 * mlp_macs(mlp.observation_dim(), &MLP_HIDDEN, mlp.num_joints()) / 1e9;
        let m = field.steps * 64 * 2 / minibatches;
        println!(
            "  MLP {name}: fused / candle's ops: update {:.2}×, env steps/s {:.2}×; the update ≈ {gflop:.2} GFLOP, {:.1} GFLOP/s fused, {:.1} candle; a plain product of its layers' shapes ({m} rows), one core: {:.1} GFLOP/s",
            fused.3 / candle.3,
            fused.0 / candle.0,
            gflop / fused.3,
            gflop / candle.3,
            plain_gflops(m, mlp.observation_dim(), &MLP_HIDDEN, mlp.num_joints()),
        );
    }
    Ok(())
}

/// Multiply-adds of one row through the actor (`obs → hidden → act`) and the critic.
fn mlp_macs(obs: usize, hidden: &[usize], act: usize) -> f64 {
    let chain = |widths: &[usize]| widths.windows(2).map(|w| (w[0] * w[1]) as f64).sum::<f64>();
    let actor: Vec<usize> = std::iter::once(obs)
        .chain(hidden.iter().copied())
        .chain([act])
        .collect();
    let critic_in = obs + train::ppo::env::CRITIC_EXTRA;
    let critic: Vec<usize> = std::iter::once(critic_in)
        .chain(train::ppo::policy::CRITIC_HIDDEN)
        .chain([1])
        .collect();
    chain(&actor) + chain(&critic)
}

/// GFLOP/s of the forward products of the actor's and critic's layers over `m` rows on this
/// thread (the same kernel the fused update calls), the best of a few repetitions.
fn plain_gflops(m: usize, obs: usize, hidden: &[usize], act: usize) -> f64 {
    let mut widths: Vec<(usize, usize)> = Vec::new();
    let actor: Vec<usize> = std::iter::once(obs)
        .chain(hidden.iter().copied())
        .chain([act])
        .collect();
    let critic: Vec<usize> = std::iter::once(obs + train::ppo::env::CRITIC_EXTRA)
        .chain(train::ppo::policy::CRITIC_HIDDEN)
        .chain([1])
        .collect();
    for w in actor.windows(2).chain(critic.windows(2)) {
        widths.push((w[0], w[1]));
    }
    let bufs: Vec<(Vec<f32>, Vec<f32>, Vec<f32>)> = widths
        .iter()
        .map(|&(i, o)| (vec![0.5f32; m * i], vec![0.01f32; o * i], vec![0.0f32; m * o]))
        .collect();
    let mut bufs = bufs;
    let flops: f64 = widths.iter().map(|&(i, o)| 2.0 * (m * i * o) as f64).sum();
    let mut best = f64::INFINITY;
    for _ in 0..20 {
        let t = Instant::now();
        for ((i, o), (x, w, y)) in widths.iter().zip(bufs.iter_mut()) {
            train::ppo::matmul::MatMul {
                m,
                n: *o,
                k: *i,
                accumulate: false,
            }
            .run((y, *o, 1), (x, *i, 1), (w, 1, *i));
        }
        best = best.min(t.elapsed().as_secs_f64());
    }
    flops / best / 1e9
}

/// The MLP's hidden sizes in the recipe (docs/stair_policy.md).
const MLP_HIDDEN: [usize; 3] = [128, 64, 64];
