//! A checkpoint is the whole run: N iterations, a checkpoint, a resume and N more give bit for bit
//! the weights, optimizer state, counters and curves of 2N iterations straight. A damaged, a
//! truncated and a mismatched checkpoint are each refused, naming the file and what is wrong.
mod common;
use common::have_12dof_model;
use std::path::{Path, PathBuf};

use train::ppo::env::EnvSettings;
use train::ppo::runner::{train, IterLog, RunConfig, CHECKPOINT};

fn root() -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/.."))
}

/// The from-scratch recipe in small: the MLP spec with symmetry, the whole curriculum with every
/// randomisation, a critic warm-up and assisted climbs (so every stream and optimizer is used).
fn recipe(out: &Path, iterations: usize) -> RunConfig {
    RunConfig {
        spec: root().join("specs/stairs/g1_stairs_mlp.toml"),
        model: g1_sim::ModelChoice::G1_12Dof,
        mixed_model: None,
        out: out.to_path_buf(),
        envs: 8,
        threads: 2,
        iterations,
        seed: 11,
        init_actor: None,
        init_critic: None,
        actor_hidden: vec![32, 32, 32],
        symmetry: true,
        init_std: Some(0.8),
        rate_noise: train::ppo::runner::RateNoise::PER_STEP,
        critic_warmup: 2,
        ppo: train::ppo::algo::PpoConfig {
            steps: 8,
            epochs: 2,
            minibatches: 2,
            lr: 1e-3,
            ..Default::default()
        },
        env: EnvSettings {
            episode_s: 0.5,
            max_init_level: 6,
            assist: train::ppo::assist::Assist {
                share: 0.5,
                levels: (3, 5),
                decay_steps: 1000,
            },
            ..EnvSettings::DEFAULT
        },
        checkpoint_every: 3,
        accept_recipe_change: false,
        quiet: true,
        max_wall_s: f64::INFINITY,
        judge: train::ppo::judge::JudgeConfig::standard(0, "g1-12dof"),
    }
}

/// The checkpoint's header: the sha256 of its data, and its counters without the wall time.
fn checkpoint_identity(dir: &Path) -> (String, serde_json::Value) {
    let bytes = std::fs::read(dir.join(CHECKPOINT)).unwrap();
    let (_, header) = safetensors::SafeTensors::read_metadata(&bytes).unwrap();
    let meta = header.metadata().clone().unwrap();
    let mut state: serde_json::Value = serde_json::from_str(&meta["state"]).unwrap();
    state.as_object_mut().unwrap().remove("wall_s");
    (meta["data_sha256"].clone(), state)
}

/// The curves without the timings (the only figures a machine's load may change).
fn curves(h: &[IterLog]) -> Vec<serde_json::Value> {
    h.iter()
        .map(|l| {
            let mut v = serde_json::to_value(l).unwrap();
            for k in ["wall_s", "env_steps_per_s", "learner_share", "rollout_s", "update_s"] {
                v.as_object_mut().unwrap().remove(k);
            }
            v
        })
        .collect()
}

#[test]
fn a_resumed_run_is_bit_for_bit_the_run_that_went_on() {
    if !have_12dof_model() {
        return;
    }
    let dir = std::env::temp_dir().join(format!("g1_ppo_resume_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let (straight, chunked) = (dir.join("straight"), dir.join("chunked"));
    let h_straight = train(&recipe(&straight, 6)).expect("6 iterations straight");
    let h_first = train(&recipe(&chunked, 3)).expect("3 iterations");
    assert_eq!(h_first.len(), 3);
    let h_chunked = train(&recipe(&chunked, 6)).expect("3 more, resumed");
    assert_eq!(h_chunked.len(), 6, "the history goes on across the resume");
    assert_eq!(curves(&h_straight), curves(&h_chunked), "curves differ");
    let (a, b) = (checkpoint_identity(&straight), checkpoint_identity(&chunked));
    assert_eq!(a, b, "weights, optimizer moments, normaliser or counters differ");
    assert_eq!(a.1["iteration"], 6);
    assert!(a.1["adam_step"].as_u64().unwrap() > 0 && a.1["critic_adam_step"].as_u64().unwrap() > 0);
    assert_eq!(
        std::fs::read(straight.join("g1_stairs_mlp.safetensors")).unwrap(),
        std::fs::read(chunked.join("g1_stairs_mlp.safetensors")).unwrap()
    );
    // Training moved the weights (the test would pass on a run that learns nothing otherwise).
    let h = &h_straight;
    assert!(h.iter().skip(2).all(|l| l.update.kl > 0.0), "the actor never stepped");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_damaged_truncated_or_mismatched_checkpoint_is_refused_by_name() {
    if !have_12dof_model() {
        return;
    }
    let dir = std::env::temp_dir().join(format!("g1_ppo_refuse_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let run = dir.join("run");
    let mut cfg = recipe(&run, 3);
    cfg.envs = 4;
    train(&cfg).expect("3 iterations");
    let ckpt = run.join(CHECKPOINT);
    let good = std::fs::read(&ckpt).unwrap();
    assert!(good.len() < 5 << 20, "an MLP run's checkpoint is {} bytes", good.len());
    let resume = |c: &RunConfig| {
        let mut c = c.clone();
        c.iterations = 4;
        train(&c).map(|_| ()).unwrap_err().to_string()
    };

    // A byte flipped in the data: the sha256 finds it.
    let mut damaged = good.clone();
    let n = damaged.len();
    damaged[n - 100] ^= 0x40;
    std::fs::write(&ckpt, &damaged).unwrap();
    let e = resume(&cfg);
    assert!(e.contains(&ckpt.display().to_string()) && e.contains("damaged"), "{e}");

    // Cut short (a machine lost mid-copy).
    std::fs::write(&ckpt, &good[..good.len() / 2]).unwrap();
    let e = resume(&cfg);
    assert!(
        e.contains("damaged or truncated") && e.contains(&ckpt.display().to_string()),
        "{e}"
    );

    // Another recipe: refused naming the setting, accepted when asked.
    std::fs::write(&ckpt, &good).unwrap();
    let mut other = cfg.clone();
    other.ppo.entropy_coef = 0.01;
    let e = resume(&other);
    assert!(
        e.contains("entropy_coef: 0.005") && e.contains("entropy_coef: 0.01"),
        "{e}"
    );
    assert!(e.contains("--accept-recipe-change"), "{e}");
    let mut more = cfg.clone();
    more.envs = 6;
    let e = resume(&more);
    assert!(e.contains("envs: 4") && e.contains("envs: 6"), "{e}");

    // Another deploy spec (same path, other content).
    let spec = dir.join("spec.toml");
    let text = std::fs::read_to_string(&cfg.spec).unwrap();
    let weights = cfg.spec.parent().unwrap().join("g1_stairs_mlp.safetensors");
    std::fs::write(
        &spec,
        text.replace("g1_stairs_mlp.safetensors", &weights.display().to_string())
            .replace("\"../../", &format!("\"{}/", root().display()))
            + "\n# edited\n",
    )
    .unwrap();
    let mut moved = cfg.clone();
    moved.spec = spec.clone();
    let e = resume(&moved);
    assert!(e.contains("sha256") && e.contains(&spec.display().to_string()), "{e}");

    // Not a run checkpoint at all (an older trainer's weights alone).
    std::fs::copy(run.join("g1_stairs_mlp.safetensors"), &ckpt).unwrap();
    let e = resume(&cfg);
    assert!(e.contains("not a run checkpoint"), "{e}");

    // A damaged record beside a good checkpoint: refused by name, not read as empty.
    std::fs::write(&ckpt, &good).unwrap();
    let history = run.join(train::ppo::runner::HISTORY);
    let whole = std::fs::read(&history).unwrap();
    std::fs::write(&history, &whole[..whole.len() / 2]).unwrap();
    let e = resume(&cfg);
    assert!(e.contains("history.json is damaged"), "{e}");
    std::fs::write(&history, &whole).unwrap();
    let judged = run.join(train::ppo::runner::JUDGE);
    std::fs::write(&judged, "[{\"env_steps\": 12").unwrap();
    let e = resume(&cfg);
    assert!(e.contains("judge.json is damaged"), "{e}");
    std::fs::remove_file(&judged).unwrap();

    // The good one still resumes, and a changed recipe does with --accept-recipe-change.
    other.accept_recipe_change = true;
    other.iterations = 4;
    let h = train(&other).expect("resumes on purpose");
    assert_eq!(h.last().unwrap().iteration, 4);
    // More environments on purpose (the field's batch, reached mid-run): they start at the levels
    // the run had reached.
    more.accept_recipe_change = true;
    more.iterations = 5;
    let h = train(&more).expect("resumes with more environments on purpose");
    assert_eq!(h.last().unwrap().iteration, 5);
    std::fs::remove_dir_all(&dir).unwrap();
}
