//! Warm-starting a policy-set gait clock (`[phase] rate`) from an actor of the fixed clock: the
//! trainer adds a zero row for the rate (rate 1, the clock the actor was trained on) and one entry
//! of action noise, and the firmware runs the export with the joints' targets as before.
// Test expectations use std's math on the host; this never runs on the robot.
#![allow(clippy::disallowed_methods)]
use std::path::{Path, PathBuf};

use control::controller::Controller;
use control::spec::DeploySpec;
use hal::{LowState, TerrainToken};
use train::ppo::policy::{ActorArch, ActorCritic, Sizes};

fn spec(rate: bool) -> DeploySpec {
    let path = PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../specs/stairs/g1_stairs_lstm.toml"
    ));
    let text = std::fs::read_to_string(&path).unwrap();
    let anchor = "first_step_time_s = 0.02\n";
    assert!(
        text.contains(anchor),
        "the stair spec's [phase] changed; update this test"
    );
    let text = if rate {
        text.replacen(anchor, &format!("{anchor}rate = {{ min = 0.5, max = 1.5 }}\n"), 1)
    } else {
        text
    };
    DeploySpec::from_toml(&text, &path).unwrap()
}

fn state(k: u64) -> LowState {
    let mut s = LowState::default();
    s.imu.quaternion = [1.0, 0.0, 0.0, 0.0];
    for (i, m) in s.motors.iter_mut().enumerate() {
        // A varied, platform-independent state (no libm): a sawtooth per joint.
        let x = ((k * 7 + i as u64 * 3) % 17) as f32 / 17.0 - 0.5;
        (m.q, m.dq) = (x * 0.2, -x);
    }
    s
}

#[test]
fn a_fixed_clock_actor_warm_starts_a_policy_set_clock_at_rate_one() {
    let (fixed, set) = (spec(false), spec(true));
    let n = fixed.num_joints();
    let committed = fixed.weights_path();
    let weights = std::fs::read(&committed).unwrap();
    let arch = ActorArch::from_desc(&set.policy.network, set.action_dim(), Sizes::Weights(&weights)).unwrap();
    let ac = ActorCritic::with_arch(arch, set.observation_dim() + train::ppo::env::CRITIC_EXTRA, 0.3, 0).unwrap();
    assert_eq!(ac.act_dim, n + 1);
    let w = ac.load_actor_widened(&committed).unwrap();
    assert_eq!(
        (w.inputs, w.outputs),
        (0, 1),
        "same observation layout, one more output"
    );

    // The action noise: the rate starts at the mean of the joints' noise.
    train::ppo::critic_file::load(&ac, &train::ppo::critic_file::beside(&committed)).unwrap();
    let log_std: Vec<f32> = ac.log_std().to_vec1().unwrap();
    assert_eq!(log_std.len(), n + 1);
    let mean = log_std[..n].iter().sum::<f32>() / n as f32;
    assert!((log_std[n] - mean).abs() < 1e-6, "{log_std:?}");

    // The export runs in the firmware: targets as the committed actor's, clock as the fixed one.
    let dir = std::env::temp_dir().join(format!("g1_policy_clock_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let export = dir.join("clock.safetensors");
    std::fs::write(&export, ac.actor_safetensors().unwrap()).unwrap();
    let mut c_fixed = Controller::new(fixed).unwrap();
    let mut c_set = Controller::new(set.with_weights(Path::new(&export)).unwrap()).unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
    let token = TerrainToken::FLAT;
    let mut worst = 0.0f32;
    for k in 0..200 {
        let s = state(k);
        c_fixed.policy_step(&s, [0.5, 0.0, 0.0], token).unwrap();
        c_set.policy_step(&s, [0.5, 0.0, 0.0], token).unwrap();
        for (a, b) in c_fixed.target_q().iter().zip(c_set.target_q()) {
            worst = worst.max((a - b).abs());
        }
    }
    assert!(worst < 1e-4, "targets differ by up to {worst} rad");
}

#[test]
fn the_rate_takes_its_own_action_noise_and_the_joints_keep_theirs() {
    let set = spec(true);
    let n = set.num_joints();
    let weights = std::fs::read(set.weights_path()).unwrap();
    let arch = ActorArch::from_desc(&set.policy.network, set.action_dim(), Sizes::Weights(&weights)).unwrap();
    let ac = ActorCritic::with_arch(arch, set.observation_dim() + train::ppo::env::CRITIC_EXTRA, 0.1, 0).unwrap();
    ac.set_action_std_from(n, 0.3).unwrap();
    let log_std: Vec<f32> = ac.log_std().to_vec1().unwrap();
    assert!((log_std[n] - 0.3f32.ln()).abs() < 1e-6, "{log_std:?}");
    assert!(
        log_std[..n].iter().all(|&l| (l - 0.1f32.ln()).abs() < 1e-6),
        "{log_std:?}"
    );
    assert!(ac.set_action_std_from(n + 1, 0.3).is_err(), "no output past the rate");
    assert!(ac.set_action_std_from(n, f64::NAN).is_err());
}
