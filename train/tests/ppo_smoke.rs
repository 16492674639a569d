//! PPO learns: on a small budget, from a random actor on flat ground, the mean reward per policy
//! step rises (falling early costs the termination penalty; PPO quickly learns to stay up longer).
//! And training is deterministic for a seed: the same run twice, or on another thread count, writes
//! the same weights.
mod common;
use common::have_12dof_model;
use std::path::{Path, PathBuf};

use train::ppo::env::EnvSettings;
use train::ppo::runner::{train, RunConfig, ACTORS, CHECKPOINT, CURVES, HISTORY};

#[test]
fn ppo_return_rises_on_a_small_budget_and_resumes() {
    let root = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/.."));
    if !have_12dof_model() {
        return;
    }
    let out = std::env::temp_dir().join(format!("g1_ppo_smoke_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    // The MLP spec, fresh, with symmetry augmentation. Random actions this wide (2 × the action
    // scale) drive joints past their motors' limits within a few steps: PPO must learn to keep
    // them inside, which raises the reward per step at once.
    let mut cfg = RunConfig {
        spec: root.join("specs/stairs/g1_stairs_mlp.toml"),
        model: g1_sim::ModelChoice::G1_12Dof,
        mixed_model: None,
        out: out.clone(),
        envs: 32,
        threads: 2,
        iterations: 30,
        seed: 1,
        init_actor: None,
        init_critic: None,
        actor_hidden: vec![64, 64, 64],
        symmetry: true,
        init_std: Some(2.0),
        rate_noise: train::ppo::runner::RateNoise::PER_STEP,
        critic_warmup: 0,
        ppo: train::ppo::algo::PpoConfig {
            lr: 1e-3,
            ..Default::default()
        },
        env: common::flat_settings(2.0),
        checkpoint_every: usize::MAX,
        accept_recipe_change: false,
        quiet: true,
        max_wall_s: f64::INFINITY,
        judge: train::ppo::judge::JudgeConfig::standard(0, "g1-12dof"),
    };
    let h = train(&cfg).expect("training runs");
    let mean =
        |s: &[train::ppo::runner::IterLog]| s.iter().map(|l| l.mean_reward_per_step).sum::<f64>() / s.len() as f64;
    let (first, last) = (mean(&h[..4]), mean(&h[h.len() - 4..]));
    eprintln!(
        "reward/step: first 4 iterations {first:.4}, last 4 {last:.4}; per iteration {:?}",
        h.iter()
            .map(|l| (l.mean_reward_per_step * 1000.0).round() / 1000.0)
            .collect::<Vec<_>>()
    );
    eprintln!(
        "std {:?}\nkl {:?}\nlr {:?}\nfalls {:?}",
        h.iter()
            .map(|l| (l.update.mean_std * 100.0).round() / 100.0)
            .collect::<Vec<_>>(),
        h.iter().map(|l| l.update.kl).collect::<Vec<_>>(),
        h.iter().map(|l| l.update.lr).collect::<Vec<_>>(),
        h.iter().map(|l| l.fall_causes.clone()).collect::<Vec<_>>()
    );
    assert!(last > first + 0.1, "PPO did not learn: {first:.4} -> {last:.4}");
    for f in [CHECKPOINT, HISTORY, CURVES, "state.json", "g1_stairs_mlp.safetensors"] {
        assert!(out.join(f).exists(), "{f} not written");
    }
    // Resume: two more iterations continue the count and the history.
    cfg.iterations = 32;
    let h2 = train(&cfg).expect("resumes");
    // --max-wall: a run out of time stops at its next checkpoint (here after every iteration).
    let mut capped = cfg.clone();
    capped.out = out.with_extension("capped");
    capped.iterations = 1000;
    capped.max_wall_s = 0.0;
    capped.checkpoint_every = 1;
    let _ = std::fs::remove_dir_all(&capped.out);
    let hc = train(&capped).expect("a capped run");
    assert_eq!(hc.len(), 1, "--max-wall 0 stops after the first iteration");
    assert!(capped.out.join(CHECKPOINT).exists());
    std::fs::remove_dir_all(&capped.out).unwrap();
    assert_eq!(h2.len(), 32);
    assert_eq!(h2.last().unwrap().iteration, 32);
    assert!(h2[31].env_steps > h[29].env_steps);
    // Each checkpoint's actor is kept, named by its env steps, and equals the export at that point.
    let mut actors: Vec<_> = std::fs::read_dir(out.join(ACTORS))
        .expect("actors/ written")
        .map(|e| e.unwrap().path())
        .filter(|p| !p.to_string_lossy().ends_with(".critic.safetensors"))
        .collect();
    actors.sort();
    // Each actor has its critic beside it (weights, normaliser, action noise).
    for a in &actors {
        assert!(
            train::ppo::critic_file::beside(a).exists(),
            "no critic beside {}",
            a.display()
        );
    }
    assert_eq!(
        actors.len(),
        2,
        "one actor per checkpoint (end of each run): {actors:?}"
    );
    assert!(
        actors[1].ends_with(format!("actor_{:012}.safetensors", h2[31].env_steps)),
        "{actors:?}"
    );
    assert_eq!(
        std::fs::read(&actors[1]).unwrap(),
        std::fs::read(out.join("g1_stairs_mlp.safetensors")).unwrap()
    );
    // A fine-tune from the export with --init-critic continues the critic: its normaliser keeps
    // counting from the 32 iterations behind it, and the recipe says where the critic came from.
    let export = out.join("g1_stairs_mlp.safetensors");
    let tuned = RunConfig {
        out: out.with_extension("tuned"),
        iterations: 1,
        init_actor: Some(export.clone()),
        init_critic: Some(train::ppo::critic_file::beside(&export)),
        ..cfg.clone()
    };
    let _ = std::fs::remove_dir_all(&tuned.out);
    // Without --init-std the action noise is the file's (where the 32 iterations left it); with it,
    // the flag's.
    let tuned = RunConfig {
        init_std: None,
        ..tuned
    };
    let ht = train(&tuned).expect("a fine-tune with --init-critic");
    let std_then = h2.last().unwrap().update.mean_std;
    let std_now = ht[0].update.mean_std;
    assert!(
        (std_now / std_then - 1.0).abs() < 0.05,
        "noise {std_now} after the file's {std_then}"
    );
    let loud = RunConfig {
        out: out.with_extension("loud"),
        init_std: Some(0.05),
        ..tuned.clone()
    };
    let _ = std::fs::remove_dir_all(&loud.out);
    let hl = train(&loud).expect("a fine-tune with --init-critic and --init-std");
    assert!(
        (hl[0].update.mean_std / 0.05 - 1.0).abs() < 0.05 && (std_then / 0.05 - 1.0).abs() > 0.5,
        "--init-std 0.05 gave noise {} (the file's {std_then})",
        hl[0].update.mean_std
    );
    let said: train::ppo::runner::RunState =
        serde_json::from_str(&std::fs::read_to_string(loud.out.join("state.json")).unwrap()).unwrap();
    let said = said.started_from;
    assert!(
        said.contains("critic and normaliser from") && said.contains("action noise 0.05 (--init-std)"),
        "{said}"
    );
    std::fs::remove_dir_all(&loud.out).unwrap();
    let state = |dir: &Path| -> train::ppo::runner::RunState {
        serde_json::from_str(&std::fs::read_to_string(dir.join("state.json")).unwrap()).unwrap()
    };
    let (before, after) = (state(&out), state(&tuned.out));
    assert!(
        after.normalizer.count > before.normalizer.count,
        "the normaliser restarted: {} rows after, {} before",
        after.normalizer.count,
        before.normalizer.count
    );
    assert!(
        after.started_from.contains("critic, normaliser and action noise from"),
        "{}",
        after.started_from
    );
    std::fs::remove_dir_all(&tuned.out).unwrap();
    std::fs::remove_dir_all(&out).unwrap();
}

/// A short run on the full curriculum mix with every randomisation on; returns the exported actor.
fn short_run(out: &Path, threads: usize) -> (Vec<u8>, Vec<f64>) {
    let root = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/.."));
    let _ = std::fs::remove_dir_all(out);
    let cfg = RunConfig {
        spec: root.join("specs/stairs/g1_stairs_lstm.toml"),
        model: g1_sim::ModelChoice::G1_12Dof,
        mixed_model: None,
        out: out.to_path_buf(),
        envs: 8,
        threads,
        iterations: 4,
        seed: 7,
        init_actor: None,
        init_critic: None,
        actor_hidden: vec![64, 32],
        symmetry: false,
        init_std: Some(0.5),
        rate_noise: train::ppo::runner::RateNoise::PER_STEP,
        critic_warmup: 1,
        ppo: Default::default(),
        env: EnvSettings {
            episode_s: 1.0,
            max_init_level: 10,
            vx: (0.4, 0.8),
            ..EnvSettings::DEFAULT
        },
        checkpoint_every: usize::MAX,
        accept_recipe_change: false,
        quiet: true,
        max_wall_s: f64::INFINITY,
        judge: train::ppo::judge::JudgeConfig::standard(0, "g1-12dof"),
    };
    let h = train(&cfg).expect("training runs");
    let weights = std::fs::read(out.join("g1_stairs_lstm.safetensors")).expect("exported actor");
    std::fs::remove_dir_all(out).unwrap();
    (weights, h.iter().map(|l| l.mean_reward_per_step).collect())
}

#[test]
fn training_is_deterministic_for_a_seed_and_any_thread_count() {
    if !have_12dof_model() {
        return;
    }
    let dir = std::env::temp_dir().join(format!("g1_ppo_det_{}", std::process::id()));
    let (a, ra) = short_run(&dir.join("a"), 2);
    let (b, rb) = short_run(&dir.join("b"), 2);
    let (c, rc) = short_run(&dir.join("c"), 1);
    eprintln!("reward/step per iteration: {ra:?}");
    assert!(ra.iter().all(|r| r.is_finite()) && ra.len() == 4, "{ra:?}");
    assert_eq!(ra, rb, "same seed, same threads: different rewards");
    assert!(a == b, "same seed, same threads: different weights");
    assert_eq!(ra, rc, "1 thread vs 2: different rewards");
    assert!(a == c, "1 thread vs 2: different weights");
    let _ = std::fs::remove_dir_all(&dir);
}
