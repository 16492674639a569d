//! `[policy] mirror = "average"`: the policy the spec runs is left–right symmetric by construction,
//! whatever its weights, and a spec that cannot be mirrored is refused with the reason.
use std::path::Path;

use control::actor::Actor;
use control::nn::Network;
use control::spec::mirror::PolicyMirror;
use control::spec::{DeploySpec, MirrorMode};

fn stair_spec() -> DeploySpec {
    DeploySpec::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("../specs/stairs/g1_stairs_lstm.toml"))
        .expect("stair spec")
}

fn stair_network(spec: &DeploySpec) -> Network {
    Network::load(&spec.policy.network, &spec.weights_path()).expect("committed stair weights")
}

/// A deterministic observation sequence with every value moving (a plausible range per value is
/// not needed: the property holds for any input).
fn observations(dim: usize, steps: usize) -> Vec<Vec<f32>> {
    let mut x = 0x2545_F491_4F6C_DD1Du64;
    (0..steps)
        .map(|_| {
            (0..dim)
                .map(|_| {
                    x ^= x << 13;
                    x ^= x >> 7;
                    x ^= x << 17;
                    ((x >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
                })
                .collect()
        })
        .collect()
}

#[test]
fn an_averaged_policy_answers_a_mirrored_world_with_the_mirrored_action_bit_for_bit() {
    let mut spec = stair_spec();
    let net = stair_network(&spec);
    let m = PolicyMirror::from_spec(&spec).unwrap();
    let (o, a) = (spec.observation_dim(), spec.num_joints());
    let seq = observations(o, 60);

    // The committed network alone is not symmetric: the check can fail.
    spec.policy.mirror = MirrorMode::None;
    let mut plain = Actor::new(&spec, net.clone()).unwrap();
    let mut plain_m = Actor::new(&spec, net.clone()).unwrap();
    spec.policy.mirror = MirrorMode::Average;
    let mut avg = Actor::new(&spec, net.clone()).unwrap();
    let mut avg_m = Actor::new(&spec, net).unwrap();

    let (mut act, mut act_m, mut mirrored, mut obs_m) = (vec![0.0; a], vec![0.0; a], vec![0.0; a], vec![0.0; o]);
    let (mut worst_plain, mut worst_avg) = (0.0f32, 0.0f32);
    for (s, x) in seq.iter().enumerate() {
        if s == 40 {
            avg.reset();
            avg_m.reset();
            plain.reset();
            plain_m.reset();
        }
        m.obs.apply(x, &mut obs_m);
        for (p, pm, worst) in [
            (&mut plain, &mut plain_m, &mut worst_plain),
            (&mut avg, &mut avg_m, &mut worst_avg),
        ] {
            p.step(x, &mut act).unwrap();
            pm.step(&obs_m, &mut act_m).unwrap();
            m.action.apply(&act, &mut mirrored);
            for (u, v) in mirrored.iter().zip(&act_m) {
                *worst = worst.max((u - v).abs());
            }
        }
    }
    assert!(
        worst_plain > 1e-3,
        "the committed network is already symmetric ({worst_plain}): nothing to check"
    );
    assert_eq!(
        worst_avg, 0.0,
        "averaged policy: mirrored world, action off its mirror by {worst_avg}"
    );
}

#[test]
fn the_twin_keeps_its_own_state_and_a_reset_clears_both() {
    let mut spec = stair_spec();
    spec.policy.mirror = MirrorMode::Average;
    let net = stair_network(&spec);
    let mut actor = Actor::new(&spec, net.clone()).unwrap();
    let mut plain = net;
    assert_eq!(actor.state_len(), 2 * plain.state_len());
    let seq = observations(spec.observation_dim(), 10);
    let mut a = vec![0.0; spec.num_joints()];
    for x in &seq {
        actor.step(x, &mut a).unwrap();
    }
    let mut state = vec![0.0; actor.state_len()];
    actor.read_state(&mut state);
    let half = plain.state_len();
    assert!(state[half..].iter().any(|&v| v != 0.0), "the twin's state did not move");
    assert_ne!(
        state[..half],
        state[half..],
        "the twin ran on the same inputs as the network"
    );
    // The network's half is exactly what the network alone reaches on the same inputs.
    for x in &seq {
        plain.step(x, &mut a).unwrap();
    }
    let mut alone = vec![0.0; half];
    plain.read_state(&mut alone);
    assert_eq!(state[..half], alone[..]);
    actor.reset();
    actor.read_state(&mut state);
    assert!(state.iter().all(|&v| v == 0.0));
    // write_state restores what read_state gave.
    let probe: Vec<f32> = (0..state.len()).map(|i| i as f32 * 1e-3).collect();
    actor.write_state(&probe);
    actor.read_state(&mut state);
    assert_eq!(state, probe);
}

#[test]
fn a_spec_that_cannot_be_mirrored_is_refused_naming_the_joint() {
    let text =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../specs/stairs/g1_stairs_lstm.toml"))
            .unwrap()
            // The MJCF path is relative to the spec's own folder; these copies live elsewhere.
            .replace("model = \"../../.deps/g1_29dof/g1.xml\"", "");
    let dir = std::env::temp_dir().join(format!("g1-mirror-spec-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    // The committed spec averages, and loads as it is ...
    assert!(text.contains("mirror = \"average\""));
    let ok = dir.join("ok.toml");
    std::fs::write(&ok, &text).unwrap();
    assert_eq!(DeploySpec::load(&ok).unwrap().policy.mirror, MirrorMode::Average);
    // ... and not with an unmirrored default pose (left hip roll 0.1, right 0).
    let bad = dir.join("bad.toml");
    std::fs::write(
        &bad,
        text.replace("default_pose = [-0.1, 0.0, 0.0,", "default_pose = [-0.1, 0.1, 0.0,"),
    )
    .unwrap();
    let e = DeploySpec::load(&bad).unwrap_err().to_string();
    assert!(
        e.contains("policy.mirror") && e.contains("left_hip_roll_joint"),
        "unexpected error: {e}"
    );
    // An unknown mode is a parse error naming the field's values.
    let odd = dir.join("odd.toml");
    std::fs::write(&odd, text.replace("mirror = \"average\"", "mirror = \"mean\"")).unwrap();
    let e = DeploySpec::load(&odd).unwrap_err().to_string();
    assert!(e.contains("average"), "unexpected error: {e}");
    std::fs::remove_dir_all(&dir).ok();
}
