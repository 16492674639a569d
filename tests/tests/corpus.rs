//! Replay regression: every log in tests/corpus replays bit-exact through today's firmware, and a
//! perturbed weight file makes the replay fail naming the first divergent tick, channel and field.
use std::path::PathBuf;

use integration_tests::*;
use runlog::replay::{replay, ReplayOptions};

fn corpus() -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(repo_root().join("tests/corpus"))
        .expect("tests/corpus exists")
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "mcap"))
        .collect();
    v.sort();
    v
}

#[test]
fn corpus_replays_bit_exact() {
    let logs = corpus();
    assert!(logs.len() >= 4, "corpus: {logs:?}");
    for log in logs {
        let name = log.file_name().unwrap().to_string_lossy().to_string();
        if name.starts_with("peer_") && shared_dir().is_none() {
            skip_or_fail(&format!("replaying {name}"));
            continue;
        }
        let r = replay(&log, &ReplayOptions::default()).unwrap_or_else(|e| panic!("{name}: {e:#}"));
        assert!(r.divergence.is_none(), "{name}: {}", r.divergence.unwrap());
        assert!(r.truncated.is_none(), "{name}");
        // The perception log is short (0.8 s) to stay small; every lidar frame it holds must be
        // re-computed and compared.
        let perception = name.contains("terrain");
        let min_ticks = if perception { 400 } else { 900 };
        assert!(r.ticks >= min_ticks && r.compared_commands == r.ticks, "{name}: {r:?}");
        assert!(r.compared_policy_steps > 20, "{name}: {r:?}");
        if perception {
            assert!(r.compared_perception_steps >= 5, "{name}: {r:?}");
            assert_eq!(r.compared_perception_steps, r.perception_frames_fed, "{name}: {r:?}");
        }
        eprintln!(
            "{name}: {} ticks, {} policy steps, {} perception steps bit-exact, {:.0}x real time",
            r.ticks, r.compared_policy_steps, r.compared_perception_steps, r.sim_seconds_per_wall_second
        );
    }
}

#[test]
fn perturbed_peer_weights_diverge_at_the_first_policy_step() {
    let Some(shared) = shared_dir() else {
        return skip_or_fail("perturbed-weights replay");
    };
    let weights = shared.join("peer_policy/unitree_g1_lstm/policy.safetensors");
    let dir = scratch_dir("perturb");
    let perturbed = dir.join("policy.safetensors");
    std::fs::write(&perturbed, perturb_first_weight(&std::fs::read(&weights).unwrap())).unwrap();

    let log = repo_root().join("tests/corpus/peer_walk_12dof.mcap");
    let opts = ReplayOptions {
        weights: Some(perturbed.clone()),
        ..Default::default()
    };
    let e = replay(&log, &opts).unwrap_err().to_string();
    assert!(e.contains("sha256") && e.contains("--allow-mismatch"), "{e}");
    let r = replay(
        &log,
        &ReplayOptions {
            allow_mismatch: true,
            ..opts
        },
    )
    .unwrap();
    let d = r.divergence.expect("a perturbed weight changes the outputs");
    assert_eq!(d.channel, "/policy/action", "{d}");
    assert!(d.field.starts_with("values["), "{d}");
    // Start-up is 0.6 s (300 ticks): the first policy step is at tick 310.
    assert_eq!(d.tick, 310, "{d}");
}
