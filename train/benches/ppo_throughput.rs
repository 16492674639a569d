//! PPO trainer throughput against the physics it is built on, in one run (ratios, because this
//! machine is shared and noisy): `cargo bench -p train --bench ppo_throughput`.
//!
//! 1. a bare `mj_step` loop of the training model (12-dof G1, training physics, a staircase);
//! 2. one training environment on one thread: observation (firmware `PolicyIo`), actor (firmware
//!    executor), 4 physics steps, rewards, resets — env steps/s and its ratio to (1) / 4;
//! 3. `g1-train ppo`'s loop with every core: env steps/s and the learner's share of wall time.
//!
//! Needs `../shared` (the 12-dof model and the peer walker for the warm start).
#![allow(clippy::disallowed_methods)]
use std::sync::Arc;
use std::time::Instant;

use firmware::spec::DeploySpec;
use g1_sim::world::World;
use g1_sim::{ModelChoice, SimConfig, Simulator};
use train::ppo::env::{EnvConfig, Randomization, StairEnv, DECIMATION, PHYSICS_DT};
use train::ppo::policy::ActorCritic;

fn main() -> anyhow::Result<()> {
    let root = std::path::PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/.."));
    let peer = g1_sim::model::shared_dir().join("peer_policy/unitree_g1_lstm/policy.safetensors");
    if !peer.exists() {
        anyhow::bail!("{} is missing: put ../shared beside the checkout", peer.display());
    }
    let spec_path = root.join("specs/stairs/g1_stairs_lstm.toml");
    let spec = DeploySpec::load(&spec_path)?;
    let obs = spec.observation_dim();

    // 1. Bare mj_step.
    let world = World::preset("stairs-up").expect("preset");
    let cfg = train::ppo::env::sim_config(0);
    let mut sim = Simulator::load_in(ModelChoice::G1_12Dof, cfg, Some(&world))?;
    let hold = sim.hold_initial_pose_command();
    sim.apply_command(&hold)?;
    let n = 20_000;
    let t = Instant::now();
    for _ in 0..n {
        sim.data_mut().step();
    }
    let mj_us = t.elapsed().as_secs_f64() * 1e6 / n as f64;
    let bare_env_steps = 1e6 / (mj_us * DECIMATION as f64);
    let _ = SimConfig::default();

    // 2. One environment, one thread (the warm-started actor on the curriculum's mix).
    let ac = ActorCritic::new(obs, obs + train::ppo::env::CRITIC_EXTRA, spec.num_joints(), 0.3, 0)?;
    ac.load_actor_widened(&peer)?;
    let weights = ac.actor_safetensors()?;
    let env_cfg = EnvConfig {
        model: ModelChoice::G1_12Dof,
        spec: Arc::new(spec),
        episode_s: 12.0,
        random: Randomization::DEFAULT,
        vx: (0.3, 0.8),
        max_init_level: 2,
        only: None,
    };
    let mut env = StairEnv::new(env_cfg, 1, &weights)?;
    let mut mean = vec![0.0; 12];
    let mut extra = vec![0.0; train::ppo::env::CRITIC_EXTRA];
    let (steps, mut resets) = (3000, 0);
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
    let env_rate = steps as f64 / t.elapsed().as_secs_f64();

    // 3. The whole loop.
    let out = std::env::temp_dir().join(format!("g1_ppo_bench_{}", std::process::id()));
    let threads = g1_sim::progress::default_jobs();
    let run = train::ppo::runner::RunConfig {
        spec: spec_path,
        model: ModelChoice::G1_12Dof,
        out: out.clone(),
        envs: 128,
        threads,
        iterations: 4,
        seed: 0,
        init_actor: Some(peer),
        init_std: 0.3,
        critic_warmup: 0,
        episode_s: 12.0,
        ppo: Default::default(),
        random: Randomization::DEFAULT,
        max_init_level: 2,
        only: None,
        checkpoint_every_s: f64::INFINITY,
        quiet: true,
        max_wall_s: f64::INFINITY,
    };
    let history = train::ppo::runner::train(&run)?;
    let _ = std::fs::remove_dir_all(&out);
    let tail = &history[1..];
    let loop_rate = tail.iter().map(|l| l.env_steps_per_s).sum::<f64>() / tail.len() as f64;
    let share = tail.iter().map(|l| l.learner_share).sum::<f64>() / tail.len() as f64;

    println!("PPO throughput (12-dof G1, physics dt {PHYSICS_DT} s, decimation {DECIMATION})");
    println!("  bare mj_step (stairs world)     {mj_us:8.1} µs/step  = {bare_env_steps:8.0} env steps/s (one core)");
    println!(
        "  one environment, one thread     {env_rate:8.0} env steps/s  = {:.2} × bare ({resets} resets in {steps} steps)",
        env_rate / bare_env_steps
    );
    println!(
        "  g1-train ppo, {threads} threads, 128 envs {loop_rate:8.0} env steps/s  = {:.2} × bare one core; learner {:.0} % of wall time",
        loop_rate / bare_env_steps,
        100.0 * share
    );
    Ok(())
}
