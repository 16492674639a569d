//! The PPO environment against the firmware: the warm start walks in it, and trainer and firmware
//! build identical observations and actions for the same states (parity by construction, checked).
use std::path::PathBuf;
use std::sync::Arc;

use control::controller::Controller;
use control::spec::DeploySpec;
use train::ppo::env::{Column, EnvConfig, EnvSettings, Randomization, StairEnv};
use train::ppo::policy::ActorCritic;

fn root() -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/.."))
}

fn peer_weights() -> Option<PathBuf> {
    let p = g1_sim::model::shared_dir().join("peer_policy/unitree_g1_lstm/policy.safetensors");
    if p.exists() {
        Some(p)
    } else {
        eprintln!(
            "SKIPPED: {} is missing (../shared must sit beside the checkout; CI has it)",
            p.display()
        );
        None
    }
}

fn stair_spec() -> DeploySpec {
    DeploySpec::load(&root().join("specs/stairs/g1_stairs_lstm.toml")).expect("stair spec")
}

/// The peer walker widened by the token at zero weight, as `g1-train ppo --init-actor` starts.
fn warm_start(spec: &DeploySpec, peer: &std::path::Path) -> (ActorCritic, Vec<u8>) {
    let obs = spec.observation_dim();
    let ac = ActorCritic::new(obs, obs + train::ppo::env::CRITIC_EXTRA, spec.num_joints(), 0.3, 0).unwrap();
    ac.load_actor_widened(peer).unwrap();
    let w = ac.actor_safetensors().unwrap();
    (ac, w)
}

fn env(spec: DeploySpec, weights: &[u8], seed: u64, only: Column) -> StairEnv {
    env_on(g1_sim::ModelChoice::G1_12Dof, spec, weights, seed, only)
}

fn env_on(model: g1_sim::ModelChoice, spec: DeploySpec, weights: &[u8], seed: u64, only: Column) -> StairEnv {
    StairEnv::new(test_cfg(model, spec, only), seed, weights).unwrap()
}

/// The tests' environment: 10 s episodes at vx 0.5, no randomisation, one column, training's
/// defaults otherwise (tests override single fields).
fn test_cfg(model: g1_sim::ModelChoice, spec: DeploySpec, only: Column) -> EnvConfig {
    EnvConfig {
        model,
        spec: Arc::new(spec),
        settings: EnvSettings {
            episode_s: 10.0,
            random: Randomization::NONE,
            vx: (0.5, 0.5),
            max_init_level: 0,
            only: Some(only),
            ..EnvSettings::DEFAULT
        },
    }
}

#[test]
fn warm_started_actor_walks_in_the_training_environment() {
    for model in [g1_sim::ModelChoice::G1_12Dof, g1_sim::ModelChoice::G1_29Dof] {
        walks_on(model);
    }
}

/// On the 29-dof model the spec's `[[held]]` groups hold waist and arms, as in the firmware.
fn walks_on(model: g1_sim::ModelChoice) {
    let Some(peer) = peer_weights() else { return };
    let spec = stair_spec();
    let (_, w) = warm_start(&spec, &peer);
    let mut e = env_on(model, spec, &w, 1, Column::Flat);
    let mut mean = vec![0.0; 12];
    let mut steps = 0;
    for _ in 0..400 {
        e.observe_and_act(&mut mean).unwrap();
        let out = e.step(&mean.clone()).unwrap();
        steps += 1;
        if out.terminated || out.truncated {
            break;
        }
    }
    let end = e.debug_summary();
    eprintln!("{steps} steps: {end}");
    assert_eq!(steps, 400, "the warm start fell or ended early: {end}");
    assert!(e.progress() > 3.0, "8 s at 0.5 m/s: {end}");
}

/// Trainer and firmware observe identically: the environment's observation of each state equals,
/// bit for bit, the one the firmware's `Controller` builds from the same `LowState`, command and
/// terrain token (both run `control::policy_io`; this checks nothing else slipped in between).
#[test]
fn trainer_and_firmware_build_identical_observations() {
    let Some(peer) = peer_weights() else { return };
    let spec = stair_spec();
    let (_, w) = warm_start(&spec, &peer);
    let mut e = env(spec.clone(), &w, 3, Column::Up);
    // The firmware's controller runs the same weights from a file, as g1fw would.
    let dir = std::env::temp_dir().join(format!("g1_ppo_parity_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut fw_spec = spec.clone();
    fw_spec.policy.weights = dir.join("actor.safetensors");
    std::fs::write(&fw_spec.policy.weights, &w).unwrap();
    let mut ctl = Controller::new(fw_spec).unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
    let mut mean = vec![0.0; 12];
    let mut stairs_tokens = 0;
    for step in 0..150 {
        let (state, cmd, token) = (*e.low_state(), e.operator_command(), e.token());
        stairs_tokens += (token.class != hal::TerrainClass::Flat) as usize;
        let obs = e.observe_and_act(&mut mean).unwrap().to_vec();
        ctl.policy_step(&state, cmd, token).unwrap();
        assert_eq!(obs, ctl.observation(), "observation differs at step {step}");
        assert_eq!(mean, ctl.last_action(), "action differs at step {step}");
        let out = e.step(&mean.clone()).unwrap();
        if out.terminated || out.truncated {
            break;
        }
    }
    assert!(
        stairs_tokens > 0,
        "the staircase never showed in the token: the test checks nothing"
    );
}

/// `t` policy steps of `e` acting on its actor's mean, with the actor reset before step `reset_at`
/// (mask 0 there, as a rollout marks an episode start): observations, means and masks.
fn record(e: &mut StairEnv, t: usize, reset_at: usize) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    let (mut obs, mut means, mut masks) = (Vec::new(), Vec::new(), vec![1.0f32; t]);
    let mut mean = vec![0.0; e.net.output_dim()];
    for (s, mask) in masks.iter_mut().enumerate() {
        if s == reset_at {
            e.net.reset();
            *mask = 0.0;
        }
        obs.extend_from_slice(e.observe_and_act(&mut mean).unwrap());
        means.extend_from_slice(&mean);
        e.step(&mean.clone()).unwrap();
    }
    (obs, means, masks)
}

/// The PPO update replays rollouts through candle; its actor must match the firmware's executor
/// (which produced the rollout's actions) across a sequence, including an LSTM reset mid-way.
#[test]
fn candle_actor_matches_the_firmware_executor() {
    use candle_core::{Device, Tensor};
    let Some(peer) = peer_weights() else { return };
    // The network alone (the averaged policy has its own test below).
    let mut spec = stair_spec();
    spec.policy.mirror = control::spec::MirrorMode::None;
    let (ac, w) = warm_start(&spec, &peer);
    let mut e = env(spec.clone(), &w, 5, Column::Flat);
    let (t, o) = (40, spec.observation_dim());
    let (obs, means, masks) = record(&mut e, t, 25);
    let dev = Device::Cpu;
    let zeros = Tensor::zeros((1, 64), candle_core::DType::F32, &dev).unwrap();
    let got = ac
        .actor_sequence(
            &Tensor::from_vec(obs, (t, 1, o), &dev).unwrap(),
            Some((&zeros, &zeros)),
            &Tensor::from_vec(masks, (t, 1, 1), &dev).unwrap(),
        )
        .unwrap();
    let got: Vec<f32> = got.flatten_all().unwrap().to_vec1().unwrap();
    let worst = got
        .iter()
        .zip(&means)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    eprintln!("candle vs firmware executor over {t} steps: max |Δ| = {worst:.2e}");
    assert!(worst < 1e-5, "actor mismatch {worst}");
}

/// With `[policy] mirror = "average"` the rollout's actor is the firmware's `Actor` (network and
/// mirrored twin); the update's replay (`policy_sequence`, from the state `Actor::read_state`
/// stored, with a reset mid-way) must give the same means, and they must differ from the network's alone.
#[test]
fn candle_replays_the_mirror_averaged_policy_as_the_firmware_runs_it() {
    use candle_core::{Device, Tensor};
    let mut spec = stair_spec();
    spec.policy.mirror = control::spec::MirrorMode::Average;
    let w = std::fs::read(spec.weights_path()).unwrap();
    let obs_dim = spec.observation_dim();
    let mut ac = ActorCritic::new(
        obs_dim,
        obs_dim + train::ppo::env::CRITIC_EXTRA,
        spec.num_joints(),
        0.3,
        0,
    )
    .unwrap();
    ac.load_actor_widened(&spec.weights_path()).unwrap();
    ac.mirror = Some(control::spec::mirror::PolicyMirror::from_spec(&spec).unwrap());
    let mut e = env(spec.clone(), &w, 5, Column::Flat);
    let mut mean = vec![0.0; 12];
    // Start the replayed window mid-episode, from a non-zero state of both networks.
    for _ in 0..15 {
        e.observe_and_act(&mut mean).unwrap();
        e.step(&mean.clone()).unwrap();
    }
    let mut state0 = vec![0.0; ac.state_len()];
    assert_eq!(e.net.state_len(), ac.state_len());
    e.net.read_state(&mut state0);
    let (t, h) = (30, 64);
    let (obs, means, masks) = record(&mut e, t, 20);
    let dev = Device::Cpu;
    let part = |at: usize| Tensor::from_vec(state0[at..at + h].to_vec(), (1, h), &dev).unwrap();
    let (h0, c0, h1, c1) = (part(0), part(h), part(2 * h), part(3 * h));
    let obs = Tensor::from_vec(obs, (t, 1, obs_dim), &dev).unwrap();
    let masks = Tensor::from_vec(masks, (t, 1, 1), &dev).unwrap();
    let flat = |x: Tensor| -> Vec<f32> { x.flatten_all().unwrap().to_vec1().unwrap() };
    let got = flat(
        ac.policy_sequence(&obs, Some((&h0, &c0)), Some((&h1, &c1)), &masks)
            .unwrap(),
    );
    let alone = flat(ac.actor_sequence(&obs, Some((&h0, &c0)), &masks).unwrap());
    let diff = |x: &[f32]| x.iter().zip(&means).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
    eprintln!("mirror-averaged replay vs firmware Actor over {t} steps: max |Δ| = {:.2e}; the network alone differs by {:.2e}", diff(&got), diff(&alone));
    assert!(diff(&got) < 1e-5, "replay mismatch {}", diff(&got));
    assert!(diff(&alone) > 1e-3, "the twin changed nothing ({})", diff(&alone));
}

/// Limits, rates and the token scale reach the trainer only through the spec, as they reach the
/// firmware: change them in the spec and both follow (issue 29: nothing hard-coded in `train/`).
#[test]
fn trainer_and_firmware_follow_the_spec_s_limits_rates_and_token_scale() {
    use control::spec::{ObsKind, Scale};
    use control::supervisor::{MotionLimits, Supervisor};
    use train::ppo::env::FALL_CAUSES;
    let Some(peer) = peer_weights() else { return };
    let base = stair_spec();
    let (_, w) = warm_start(&base, &peer);

    // The defaults: each motor's own velocity limit, 50 Hz policy, 10 Hz token.
    let e = env(base.clone(), &w, 3, Column::Up);
    let lim = MotionLimits::from_spec(&base);
    assert_eq!(*e.limits(), lim);
    assert_eq!(lim.joint_speed_rad_s[3], 20.0, "left knee: its motor's 20 rad/s");
    assert_eq!(lim.joint_speed_rad_s[0], 32.0, "left hip pitch: its motor's 32 rad/s");
    assert_eq!((e.timing().decimation, e.timing().token_period), (4, 5));

    // A stricter spec: both sides take it.
    let mut strict = base.clone();
    strict.safety.joint_speed_limit_rad_s = Some(0.05);
    strict.safety.tilt_limit_rad = 0.6;
    strict.rates.policy_hz = 25;
    strict.rates.perception_hz = 5;
    let term = strict
        .observation
        .terms
        .iter_mut()
        .find(|t| t.kind == ObsKind::TerrainToken)
        .expect("the stair spec observes the token");
    term.scale = Scale::PerElement(vec![2.0, 10.0, 5.0, 2.0]);
    let mut e2 = env(strict.clone(), &w, 3, Column::Up);
    let lim2 = MotionLimits::from_spec(&strict);
    assert_eq!(*e2.limits(), lim2);
    assert_eq!(*Supervisor::new(&strict, [true; hal::NUM_MOTORS]).limits(), lim2);
    assert!(lim2.joint_speed_rad_s.iter().all(|&v| v == 0.05) && lim2.tilt_rad == 0.6);
    assert_eq!((e2.timing().decimation, e2.timing().token_period), (8, 5));
    assert!((e2.timing().policy_dt - 0.04).abs() < 1e-12);

    // The critic's true token is scaled by the spec's term scale: twice the scale, twice the values
    // (to 1e-3: the slower policy rate settles the start pose a little longer, so yaw may differ).
    let n = train::ppo::env::CRITIC_EXTRA;
    let (mut a, mut b) = (vec![0.0; n], vec![0.0; n]);
    e.critic_extra(&mut a);
    e2.critic_extra(&mut b);
    let token = 4..8; // after body velocity (3) and base height (1)
    assert!(a[token.clone()].iter().any(|&v| v != 0.0), "no token to scale: {a:?}");
    for i in token {
        assert!(
            (b[i] - 2.0 * a[i]).abs() < 1e-3,
            "critic token value {i}: {} vs 2 × {}",
            b[i],
            a[i]
        );
    }

    // The episode ends on the spec's joint-speed wall (0.05 rad/s: the first steps of walking).
    let mut mean = vec![0.0; 12];
    let mut ended = false;
    for _ in 0..25 {
        e2.observe_and_act(&mut mean).unwrap();
        let out = e2.step(&mean.clone()).unwrap();
        if out.terminated {
            ended = true;
            break;
        }
    }
    assert!(ended, "a 0.05 rad/s joint-speed limit never ended the episode");
    e2.reset().unwrap();
    let end = e2.last_end.expect("an episode ended");
    assert_eq!(FALL_CAUSES[end.cause], "joint_speed", "{end:?}");
}

/// `g1-train ppo-eval`'s evaluation: the committed stair policy, in its own training environment
/// at a held level (7 cm steps down), with its mean action. It descended 8 of 8 there when measured
/// (2026-11-26); each episode ends exactly once, as a success, a fall or a time-out.
#[test]
fn in_environment_evaluation_holds_the_level_and_counts_each_episode_once() {
    if peer_weights().is_none() {
        return; // the model's meshes come from ../shared too
    }
    let spec = stair_spec();
    let weights = std::fs::read(spec.weights_path()).unwrap();
    let opts = train::ppo::in_env::InEnvOptions {
        model: g1_sim::ModelChoice::G1_12Dof,
        spec: Arc::new(spec),
        column: Column::Down,
        level: 1,
        vx: 0.5,
        episodes: 4,
        random: Randomization::NONE,
        episode_s: 20.0,
        assist: 0.0,
        seed: 0,
        threads: 2,
    };
    let r = train::ppo::in_env::evaluate(&opts, &weights).unwrap();
    assert_eq!(r.episodes, 4);
    assert!((r.step_height_m - 0.071).abs() < 1e-9, "{r:?}");
    // A fall is never a success (not even one that carries the base past the landing).
    assert_eq!(r.successes + r.falls + r.timeouts, 4, "{r:?}");
    assert!(
        r.successes >= 2,
        "the committed policy descends 7 cm steps in training: {r:?}"
    );
    // The return split by term (`ppo-eval --terms`) adds up to the return, and names what paid.
    let by_term: f64 = r.mean_return_by_term.iter().map(|(_, v)| v).sum();
    assert!(
        (by_term - r.mean_return).abs() < 1e-6 * r.mean_return.abs().max(1.0),
        "{by_term} vs {r:?}"
    );
    let term = |name: &str| r.mean_return_by_term.iter().find(|(n, _)| n == name).unwrap().1;
    assert!(term("track_lin_vel_xy") > 0.0 && term("action_rate") < 0.0, "{r:?}");
    // Each success is paid its bonus once (a bonus asked for after the step's clock advanced
    // was never paid).
    let bonus = train::ppo::reward::WEIGHTS.success * r.successes as f64 / r.episodes as f64;
    assert!(
        (term("success") - bonus).abs() < 1e-9,
        "{} vs {bonus}: {r:?}",
        term("success")
    );
    // Same seed, other thread count: the same episodes.
    let again =
        train::ppo::in_env::evaluate(&train::ppo::in_env::InEnvOptions { threads: 1, ..opts }, &weights).unwrap();
    assert_eq!(
        (again.successes, again.falls, again.mean_steps),
        (r.successes, r.falls, r.mean_steps)
    );
}

/// Success in training is `g1fw eval`'s: standing on the end landing for
/// [`firmware::eval::LANDING_HOLD_S`] without a break, not crossing a line. Ending the episode at
/// a line taught run 14's policy to dive across it: through `g1fw`, 10 of 16 climbs of 12 cm passed
/// every riser and then tripped on tilt within 0.4 s of reaching the landing.
#[test]
fn training_success_is_the_landing_held_as_g1fw_eval_scores_it() {
    if peer_weights().is_none() {
        return; // the model's meshes come from ../shared too
    }
    let spec = stair_spec();
    let weights = std::fs::read(spec.weights_path()).unwrap();
    let mut cfg = test_cfg(g1_sim::ModelChoice::G1_12Dof, spec, Column::Down);
    cfg.settings.episode_s = 20.0;
    let mut e = StairEnv::new(cfg, 5, &weights).unwrap();
    e.hold(1, 0.5).unwrap();
    let dt = e.timing().policy_dt;
    let mut mean = vec![0.0f32; 12];
    let mut successes = 0;
    // A few staircases: the policy sometimes stops at an edge (a stall ends no episode here).
    for episode in 0..8 {
        let last_riser = e.world().stairs.as_ref().unwrap().risers.last().unwrap().s;
        let line = last_riser + sim_hal::bridge::END_LANDING_MARGIN_M;
        let mut crossed_at = None;
        for k in 0usize.. {
            e.observe_and_act(&mut mean).unwrap();
            let o = e.step(&mean).unwrap();
            if crossed_at.is_none() && e.progress() >= line {
                crossed_at = Some(k);
            }
            if o.terminated || o.truncated {
                if e.success() {
                    let on_landing_s = (k - crossed_at.unwrap()) as f64 * dt;
                    assert!(
                        on_landing_s >= firmware::eval::LANDING_HOLD_S - 1e-9,
                        "episode {episode}: success {on_landing_s:.2} s after reaching the landing"
                    );
                    successes += 1;
                }
                break;
            }
        }
        e.reset().unwrap();
    }
    eprintln!("{successes} of 8 descents of 7 cm succeeded");
    assert!(successes >= 2, "the committed policy descends 7 cm steps in training");
}

/// An environment keeps its curriculum column across episodes, and its level moves within it
/// (IsaacLab's terrain types). With a column drawn per episode, successes going down promoted
/// environments that then failed every staircase up at that height.
#[test]
fn an_environment_keeps_its_column_and_moves_within_its_levels() {
    let Some(peer) = peer_weights() else { return };
    let spec = stair_spec();
    let (_, w) = warm_start(&spec, &peer);
    let mut e = env(spec, &w, 11, Column::Down);
    e.place(Column::Up, 4).unwrap();
    assert_eq!((e.column, e.level), (Column::Up, 4));
    let zero = vec![0.0f32; 12];
    for episode in 0..3 {
        // A few steps standing in front of the staircase: not halfway up, so a level down.
        for _ in 0..5 {
            e.step(&zero).unwrap();
        }
        e.reset().unwrap();
        assert_eq!(e.column, Column::Up, "episode {episode} changed the column");
    }
    assert_eq!(e.level, 1, "three failures short of halfway: 4 → 1");
}

/// `--up-level-floor`: the climbing columns never train below the floor, whatever the episodes
/// give; the descending ones are not held by it.
#[test]
fn the_climbing_columns_stay_at_or_above_the_level_floor() {
    let Some(peer) = peer_weights() else { return };
    let spec = stair_spec();
    let (_, w) = warm_start(&spec, &peer);
    let mut cfg = test_cfg(g1_sim::ModelChoice::G1_12Dof, spec, Column::Up);
    cfg.settings.up_level_floor = 3;
    cfg.settings.stand_share = 0.0; // a stand never moves the level
    let mut e = StairEnv::new(cfg, 11, &w).unwrap();
    e.place(Column::Up, 1).unwrap();
    assert_eq!(e.level, 3, "placed under the floor: raised to it");
    e.place(Column::Up, 5).unwrap();
    let zero = vec![0.0f32; 12];
    let fail_short = |e: &mut StairEnv| {
        for _ in 0..5 {
            e.step(&zero).unwrap();
        }
        e.reset().unwrap();
    };
    for _ in 0..4 {
        fail_short(&mut e);
    }
    assert_eq!(e.level, 3, "four failures short of halfway: 5 → 3, and no lower");
    e.place(Column::Down, 2).unwrap();
    for _ in 0..3 {
        fail_short(&mut e);
    }
    assert_eq!(e.level, 0, "the floor holds only the climbing columns");
}

/// `--review-share`: a review episode is drawn at or below the curriculum level, moves no level
/// whatever it gives, and says so in its end; without reviews the same failures demote.
#[test]
fn review_episodes_draw_at_or_below_the_frontier_and_move_no_level() {
    let Some(peer) = peer_weights() else { return };
    let spec = stair_spec();
    let (_, w) = warm_start(&spec, &peer);
    let mut cfg = test_cfg(g1_sim::ModelChoice::G1_12Dof, spec, Column::Down);
    cfg.settings.stand_share = 0.0;
    cfg.settings.review_share = 1.0;
    let mut e = StairEnv::new(cfg, 5, &w).unwrap();
    e.place(Column::Down, 6).unwrap();
    let zero = vec![0.0f32; 12];
    let mut drawn = Vec::new();
    for _ in 0..12 {
        for _ in 0..5 {
            e.step(&zero).unwrap();
        }
        e.reset().unwrap();
        let end = e.last_end.unwrap();
        assert!(end.review, "every episode reviews at share 1");
        assert!(!end.success);
        drawn.push(end.level);
    }
    assert_eq!(e.level, 6, "twelve failed reviews moved the level: {drawn:?}");
    assert!(drawn.iter().all(|&l| l <= 6), "{drawn:?}");
    assert!(drawn.iter().any(|&l| l < 6), "no review below the frontier: {drawn:?}");
    let h = e.world().spec.step_height;
    assert!(h <= train::ppo::env::level_height(6) + 0.0101, "step height {h}");
}

/// `--assist-share`: assisted climbs draw their staircase from the assist levels, move no level,
/// carry the strength the runner set when they started, and that strength acts: the assistant
/// holds up a robot that falls alone.
#[test]
fn assisted_climbs_draw_their_levels_move_none_and_hold_the_robot_up() {
    let Some(peer) = peer_weights() else { return };
    let spec = stair_spec();
    let (_, w) = warm_start(&spec, &peer);
    let assisted_env = |strength: f64| {
        let mut cfg = test_cfg(g1_sim::ModelChoice::G1_12Dof, spec.clone(), Column::Up);
        cfg.settings.stand_share = 0.0;
        cfg.settings.assist = train::ppo::assist::Assist {
            share: 1.0,
            levels: (6, 8),
            decay_steps: 1_000_000,
        };
        let mut e = StairEnv::new(cfg, 9, &w).unwrap();
        e.set_assist_strength(strength);
        e.place(Column::Up, 2).unwrap();
        e
    };
    let zero = vec![0.0f32; 12];
    let mut e = assisted_env(0.7);
    let mut drawn = Vec::new();
    for _ in 0..8 {
        assert_eq!(e.assist(), (true, 0.7));
        e.step(&zero).unwrap();
        e.reset().unwrap();
        let end = e.last_end.unwrap();
        assert!(end.assisted && !end.review);
        drawn.push(end.level);
    }
    assert_eq!(e.level, 2, "assisted episodes moved the level: {drawn:?}");
    assert!(drawn.iter().all(|l| (6..=8).contains(l)), "{drawn:?}");
    let h = e.world().spec.step_height;
    assert!(h >= train::ppo::env::level_height(6) - 0.0101, "step height {h}");
    // The same episode (same seed) with the zero action, helped and not: the limp-armed default
    // pose tips over alone; the assistant holds it upright.
    let lowest_up = |strength: f64| {
        let mut e = assisted_env(strength);
        e.reset().unwrap();
        let mut lowest = 1.0f32;
        for _ in 0..50 {
            if e.step(&zero).unwrap().terminated {
                return 0.0;
            }
            let [_, x, y, _] = e.low_state().imu.quaternion;
            lowest = lowest.min(1.0 - 2.0 * (x * x + y * y));
        }
        lowest
    };
    let (helped, alone) = (lowest_up(1.0), lowest_up(0.0));
    assert!(helped > 0.95, "the helped base tilted to up_z {helped} (alone {alone})");
    assert!(alone < helped - 0.05, "alone up_z {alone}, helped {helped}");
}

/// Joystick episodes on flat ground (`--joystick-share`): the command is a constant (vx, vy, wz)
/// within the documented ranges, whatever the robot's yaw does, as `g1fw sim` without
/// `--heading` sends it; heading-hold episodes never command a lateral speed. Trained only with
/// heading hold, the policy turned when asked to walk straight without it (issue 29, item 5).
#[test]
fn joystick_episodes_hold_a_constant_command_without_heading_hold() {
    if peer_weights().is_none() {
        return;
    }
    let spec = stair_spec();
    let weights = std::fs::read(spec.weights_path()).unwrap();
    let cfg = |share: f64| {
        let mut c = test_cfg(g1_sim::ModelChoice::G1_12Dof, spec.clone(), Column::Flat);
        c.settings.joystick_share = share;
        c
    };
    let mut mean = vec![0.0f32; 12];
    let mut joystick = StairEnv::new(cfg(1.0), 3, &weights).unwrap();
    let mut drawn = Vec::new();
    for _ in 0..4 {
        joystick.reset().unwrap();
        let first = joystick.operator_command();
        assert!(
            first[0] == 0.5 || first[0] == 0.0,
            "forward speed from --vx (or a 5 % stand): {first:?}"
        );
        assert!(first[1].abs() <= train::ppo::env::JOYSTICK_VY as f32, "{first:?}");
        assert!(first[2].abs() <= train::ppo::env::JOYSTICK_WZ as f32, "{first:?}");
        for _ in 0..25 {
            joystick.observe_and_act(&mut mean).unwrap();
            joystick.step(&mean).unwrap();
            assert_eq!(joystick.operator_command(), first, "a joystick command stays put");
        }
        drawn.push(first);
    }
    assert!(
        drawn.windows(2).any(|w| w[0] != w[1]),
        "each episode draws its own command: {drawn:?}"
    );

    // --joystick-vx: joystick episodes draw their forward speed from their own range, backwards
    // included, and it is what the policy is told.
    let mut backwards = StairEnv::new(
        {
            let mut c = cfg(1.0);
            c.settings.joystick_vx = Some((-0.5, -0.2));
            c
        },
        3,
        &weights,
    )
    .unwrap();
    for _ in 0..4 {
        backwards.reset().unwrap();
        let c = backwards.operator_command();
        assert!((-0.5..=-0.2).contains(&c[0]), "forward speed from --joystick-vx: {c:?}");
    }

    let mut held = StairEnv::new(cfg(0.0), 3, &weights).unwrap();
    held.reset().unwrap();
    let mut turn_rates = Vec::new();
    for _ in 0..50 {
        held.observe_and_act(&mut mean).unwrap();
        held.step(&mean).unwrap();
        let c = held.operator_command();
        assert_eq!(c[1], 0.0, "heading hold commands no lateral speed");
        turn_rates.push(c[2]);
    }
    assert!(
        turn_rates.windows(2).any(|w| w[0] != w[1]),
        "heading hold corrects the turn rate as the yaw drifts"
    );
}

/// The supervisor's walls hold at every physics step, not only at policy steps: `g1fw`'s
/// supervisor checks every 2 ms tick, so a knee-speed spike at a foot strike that is over before
/// the 20 ms policy step ends still trips the robot. Knee-speed trips were most of the committed
/// actor's failures through `g1fw` (44 of 91 for run 16's best on 12–22 cm staircases).
/// A limit set between a joint's fastest speed at the policy steps and its fastest at the physics
/// steps must end the same (deterministic) episode.
#[test]
fn supervisor_walls_hold_at_every_physics_step() {
    use train::ppo::env::FALL_CAUSES;
    if peer_weights().is_none() {
        return;
    }
    let base = stair_spec();
    let weights = std::fs::read(base.weights_path()).unwrap();
    let run = |spec: DeploySpec| {
        let mut e = env(spec, &weights, 11, Column::Up);
        e.hold(1, 0.5).unwrap();
        let mut mean = vec![0.0f32; 12];
        let (mut at_steps, mut peaks) = ([0.0f32; hal::NUM_MOTORS], [0.0f32; hal::NUM_MOTORS]);
        let mut ended = false;
        for _ in 0..150 {
            e.observe_and_act(&mut mean).unwrap();
            let out = e.step(&mean).unwrap();
            for s in 0..hal::NUM_MOTORS {
                at_steps[s] = at_steps[s].max(e.low_state().motors[s].dq.abs());
                peaks[s] = peaks[s].max(e.peak_joint_speed(s));
            }
            if out.terminated || out.truncated {
                ended = out.terminated;
                break;
            }
        }
        e.reset().unwrap();
        (at_steps, peaks, ended.then(|| e.last_end.unwrap()))
    };
    let (at_steps, peaks, _) = run(base.clone());
    let limits = control::supervisor::MotionLimits::from_spec(&base);
    // The joint whose physics steps outran its policy steps the most, under its motor's limit.
    let slot = (0..hal::NUM_MOTORS)
        .filter(|&s| peaks[s] < limits.joint_speed_rad_s[s])
        .max_by(|&a, &b| (peaks[a] / at_steps[a].max(1e-3)).total_cmp(&(peaks[b] / at_steps[b].max(1e-3))))
        .unwrap();
    assert!(
        peaks[slot] > at_steps[slot] * 1.02,
        "no joint moved faster between policy steps than at them: {peaks:?} vs {at_steps:?}"
    );
    let limit = 0.5 * (peaks[slot] + at_steps[slot]);
    let mut strict = base.clone();
    strict
        .safety
        .joint_speed_limits_rad_s
        .insert(hal::G1_MOTOR_NAMES[slot].to_string(), limit);
    let (at_steps2, _, end) = run(strict);
    let end = end.unwrap_or_else(|| {
        panic!(
            "{} at {limit:.2} rad/s (policy steps reach {:.2}, physics steps {:.2}) never ended the episode",
            hal::G1_MOTOR_NAMES[slot],
            at_steps[slot],
            peaks[slot]
        )
    });
    assert_eq!(FALL_CAUSES[end.cause], "joint_speed", "{end:?}");
    assert!(
        at_steps2[slot] < limit,
        "the trip came between policy steps, not at one"
    );
}

/// One walk as [`rewards_and_joint`] returns it: the reward per step and one joint's angle.
type Walk = (Vec<f32>, Vec<f32>);

/// The committed actor's mean action for up to `steps` policy steps on the 12-dof model, on one
/// column, under the tests' settings changed by `set`: each step's reward and joint `slot`'s
/// position (the reward tests compare two settings: a reward-only change leaves the motion as it was).
fn rewards_and_joint(only: Column, seed: u64, steps: usize, slot: usize, set: impl FnOnce(&mut EnvSettings)) -> Walk {
    let spec = stair_spec();
    let weights = std::fs::read(spec.weights_path()).unwrap();
    let mut cfg = test_cfg(g1_sim::ModelChoice::G1_12Dof, spec, only);
    set(&mut cfg.settings);
    let mut e = StairEnv::new(cfg, seed, &weights).unwrap();
    let mut mean = vec![0.0f32; 12];
    let (mut rewards, mut q) = (Vec::new(), Vec::new());
    for _ in 0..steps {
        e.observe_and_act(&mut mean).unwrap();
        let out = e.step(&mean).unwrap();
        rewards.push(out.reward);
        q.push(e.low_state().motors[slot].q);
        if out.terminated || out.truncated {
            break;
        }
    }
    (rewards, q)
}

/// Two walks of one episode (same seed, same actions) under two reward settings, as
/// [`rewards_and_joint`] returns them: the motion is the same, and `charged` earns no more than
/// `base` at any step and at least `margin` less in all. `what` names the change in the messages.
fn assert_charges_more(base: &Walk, charged: &Walk, margin: f32, what: &str) {
    assert_eq!(base.1, charged.1, "{what} changed the motion, not only the reward");
    for (i, (b, c)) in base.0.iter().zip(&charged.0).enumerate() {
        assert!(c <= b, "step {i}: {what} paid {c} against {b}");
    }
    let (sum_b, sum_c): (f32, f32) = (base.0.iter().sum(), charged.0.iter().sum());
    assert!(
        sum_c < sum_b - margin,
        "{what} cost less than {margin} in all: {sum_c} vs {sum_b}"
    );
}

/// `--soft-joint-speed` moves where the soft penalty starts and nothing else: the same episode
/// (same seed, same actions) earns less at every step when the penalty starts lower, and the
/// robot moves identically.
#[test]
fn soft_joint_speed_share_moves_where_the_penalty_starts() {
    if peer_weights().is_none() {
        return;
    }
    let run = |share: f32| rewards_and_joint(Column::Up, 5, 60, 3, |s| s.soft_joint_speed = share);
    assert_charges_more(
        &run(train::ppo::env::SOFT_JOINT_SPEED),
        &run(0.05),
        0.01,
        "a penalty from 5 % of each limit (1 rad/s at the knee)",
    );
}

/// `--tracking-std` changes only what tracking pays: the same flat episode (same seed, same
/// actions, the same motion) earns less at every step under a tighter kernel, because the robot
/// never walks at exactly the commanded speed.
#[test]
fn tighter_tracking_kernel_pays_less_for_the_same_walk() {
    if peer_weights().is_none() {
        return;
    }
    let run = |std: f64| rewards_and_joint(Column::Flat, 3, 100, 0, |s| s.tracking_std = std);
    let default = run(train::ppo::reward::TRACKING_STD);
    assert_eq!(default.0.len(), 100, "the committed actor fell on flat ground");
    assert_charges_more(
        &default,
        &run(0.1),
        0.1,
        "a 0.1 m/s kernel, against 0.5 m/s, over a 2 s walk,",
    );
}

/// `--drift-penalty` changes only what a drift across the target heading's line costs: the same
/// heading-hold walk (same seed, same actions, the same motion) earns less at every step it has
/// drifted, never more, and at most the cap's worth less; a joystick episode, which has no line,
/// earns exactly the same.
#[test]
fn drift_penalty_charges_heading_hold_walks_for_leaving_their_line_and_nothing_else() {
    if peer_weights().is_none() {
        return;
    }
    let run = |penalty: f64, joystick_share: f64| {
        rewards_and_joint(Column::Flat, 3, 150, 0, |s| {
            s.drift_weight = -penalty;
            s.joystick_share = joystick_share;
        })
    };
    let (r_off, q_off) = run(0.0, 0.0);
    let (r_on, q_on) = run(2.0, 0.0);
    assert_eq!(q_off, q_on, "the penalty changed the motion, not only the reward");
    assert_eq!(r_off.len(), 150, "the committed actor fell on flat ground");
    let dt = 1.0 / stair_spec().rates.policy_hz as f64;
    let cap = 2.0 * train::ppo::reward::MAX_DRIFT_M * dt;
    for (i, (off, on)) in r_off.iter().zip(&r_on).enumerate() {
        let cost = (off - on) as f64;
        assert!(
            (-1e-6..=cap + 1e-6).contains(&cost),
            "step {i}: the drift cost {cost}, outside 0 … {cap}"
        );
    }
    let total: f32 = r_off.iter().zip(&r_on).map(|(a, b)| a - b).sum();
    assert!(
        total > 1e-4,
        "a 3 s walk with heading hold never left its line: cost {total}"
    );
    let (j_off, _) = run(0.0, 1.0);
    let (j_on, _) = run(2.0, 1.0);
    assert_eq!(
        j_off, j_on,
        "a joystick episode paid for drifting from a line it does not have"
    );
}

/// `--yaw-error-penalty`: the same staircase walk (same seed, same actions, the same motion) earns
/// less at a step by P times its squared turn-rate error: never more, twice as much less at twice
/// the penalty, and less in all over a walk whose turn rate never matches the command exactly.
#[test]
fn yaw_error_penalty_charges_the_squared_turn_rate_error_and_nothing_else() {
    if peer_weights().is_none() {
        return;
    }
    let run = |penalty: f64| rewards_and_joint(Column::Up, 5, 150, 0, |s| s.yaw_error_weight = -penalty);
    let (r0, q0) = run(0.0);
    let (r1, q1) = run(1.0);
    let (r2, q2) = run(2.0);
    assert_eq!(q0, q1, "the penalty changed the motion, not only the reward");
    assert_eq!(q0, q2);
    assert!(r0.len() > 50, "the committed actor fell within {} steps", r0.len());
    let mut total = 0.0;
    for i in 0..r0.len() {
        let (c1, c2) = ((r0[i] - r1[i]) as f64, (r0[i] - r2[i]) as f64);
        assert!(c1 >= -1e-6, "step {i}: the penalty paid {c1}");
        assert!(
            (c2 - 2.0 * c1).abs() <= 1e-5 + 1e-3 * c1.abs(),
            "step {i}: P 1 cost {c1}, P 2 cost {c2}"
        );
        total += c1;
    }
    assert!(
        total > 1e-4,
        "a staircase walk never missed its turn rate: cost {total}"
    );
}

/// `--clearance-lookahead`: the same climb (same seed, same actions, the same motion) costs at
/// least as much at every step when the clearance term looks further ahead, and more in all on a
/// staircase, where a riser ahead of the toe now counts before the toe is over it.
#[test]
fn a_longer_clearance_lookahead_charges_risers_before_the_toe_reaches_them() {
    if peer_weights().is_none() {
        return;
    }
    let run = |la: f64| rewards_and_joint(Column::Up, 5, 250, 0, |s| s.clearance_lookahead = la);
    let toe = run(train::ppo::reward::CLEARANCE_LOOKAHEAD);
    assert!(
        toe.0.len() > 100,
        "the committed actor fell within {} steps",
        toe.0.len()
    );
    assert_charges_more(&toe, &run(0.24), 1e-3, "seeing the riser 0.12 m earlier");
}

/// One penalty term's weight set to −`p` against off, on the same walks (same seed, same actions,
/// the same motion): on an up flight the committed actor keeps walking and the term costs at least
/// as much at every step and more in all; on each of `free` (columns the term has nothing to charge
/// on) the rewards are exactly the same. Returns the up flight's two walks.
fn assert_term_charges_up_flights_only(
    set_weight: fn(&mut EnvSettings, f64),
    p: f64,
    free: &[Column],
    what: &str,
) -> (Walk, Walk) {
    let run = |col: Column, p: f64| rewards_and_joint(col, 5, 250, 0, |s| set_weight(s, -p));
    let off = run(Column::Up, 0.0);
    assert!(
        off.0.len() > 100,
        "the committed actor fell within {} steps",
        off.0.len()
    );
    let on = run(Column::Up, p);
    assert_charges_more(&off, &on, 1e-3, &format!("the {what} term on"));
    for &col in free {
        let (r_off, _) = run(col, 0.0);
        let (r_on, _) = run(col, p);
        assert_eq!(
            r_off, r_on,
            "{col:?}: the {what} term charged a walk it has nothing to charge on"
        );
    }
    (off, on)
}

/// `--riser-clearance`: charged on a staircase, nothing on flat ground, where no higher tread lies
/// ahead.
#[test]
fn riser_clearance_charges_low_swings_on_up_flights_and_nothing_on_flat_ground() {
    if peer_weights().is_none() {
        return;
    }
    assert_term_charges_up_flights_only(
        |s, w| s.riser_clearance_weight = w,
        10.0,
        &[Column::Flat],
        "riser-clearance",
    );
}

/// `--foothold-edge`: charged on a staircase, where feet land across tread edges, nothing on flat
/// ground, which has no edge.
#[test]
fn foothold_edge_charges_feet_across_tread_edges_and_nothing_on_flat_ground() {
    if peer_weights().is_none() {
        return;
    }
    assert_term_charges_up_flights_only(|s, w| s.foothold_edge_weight = w, 2.0, &[Column::Flat], "foothold-edge");
}

/// `--token-clearance`: charged on an up flight, whose token reads up; flat ground and down
/// flights, whose tokens do not, pay exactly the same.
#[test]
fn token_clearance_charges_low_swings_while_the_token_reads_up_and_nothing_else() {
    if peer_weights().is_none() {
        return;
    }
    assert_term_charges_up_flights_only(
        |s, w| s.token_clearance_weight = w,
        5.0,
        &[Column::Flat, Column::Down],
        "token-clearance",
    );
}

/// How many steps of the walk `on` (the term on) earned less than the same steps of `off`.
fn charged_steps(off: &Walk, on: &Walk) -> usize {
    off.0.iter().zip(&on.0).filter(|(a, b)| a > b).count()
}

/// A term charged once per swing, at touchdown, while the token reads up: as
/// [`assert_term_charges_up_flights_only`] with flat ground and down flights free, and the walk
/// with it on costs more at some steps, and at fewer than a quarter of them.
fn assert_touchdown_term_charges_up_flights_only(set_weight: fn(&mut EnvSettings, f64), p: f64, what: &str) {
    let (off, on) = assert_term_charges_up_flights_only(set_weight, p, &[Column::Flat, Column::Down], what);
    let charged = charged_steps(&off, &on);
    assert!(
        charged > 0 && charged * 4 < off.0.len(),
        "charged at {charged} of {} steps: not once per swing",
        off.0.len()
    );
}

/// `--swing-apex`: as `--token-clearance`, and the cost comes only at touchdowns, as lumps.
#[test]
fn swing_apex_charges_low_swings_at_touchdown_while_the_token_reads_up_and_nothing_else() {
    if peer_weights().is_none() {
        return;
    }
    assert_touchdown_term_charges_up_flights_only(|s, w| s.swing_apex_weight = w, 3.0, "swing-apex");
}

/// `--swing-advance`: charged at touchdowns on an up flight (the first steps from standing and
/// the short ones at the riser carry the foot less than a tread); flat ground and down flights,
/// whose tokens do not read up, pay exactly the same.
#[test]
fn swing_advance_charges_short_swings_at_touchdown_while_the_token_reads_up_and_nothing_else() {
    if peer_weights().is_none() {
        return;
    }
    assert_touchdown_term_charges_up_flights_only(|s, w| s.swing_advance_weight = w, 2.0, "swing-advance");
}

/// `--swing-overshoot`: charged at touchdowns on an up flight for the swings that rose more than
/// 0.10 m above the asked apex; flat ground and down flights, whose tokens do not read up, pay
/// exactly the same.
#[test]
fn swing_overshoot_charges_high_swings_at_touchdown_while_the_token_reads_up_and_nothing_else() {
    if peer_weights().is_none() {
        return;
    }
    assert_touchdown_term_charges_up_flights_only(|s, w| s.swing_overshoot_weight = w, 4.0, "swing-overshoot");
}

/// `--base-height`: charged on an up flight, where the body rides low over the feet's treads at
/// times; flat ground and down flights, whose tokens do not read up, pay exactly the same.
#[test]
fn base_height_charges_a_low_body_while_the_token_reads_up_and_nothing_else() {
    if peer_weights().is_none() {
        return;
    }
    assert_term_charges_up_flights_only(
        |s, w| s.base_height_weight = w,
        5.0,
        &[Column::Flat, Column::Down],
        "base-height",
    );
}

/// `--up-lean`: charged on an up flight, where the committed actor walks pitched back (3–8°);
/// flat ground and down flights, whose tokens do not read up, pay exactly the same.
#[test]
fn up_lean_charges_a_body_pitched_back_while_the_token_reads_up_and_nothing_else() {
    if peer_weights().is_none() {
        return;
    }
    let (off, on) = assert_term_charges_up_flights_only(
        |s, w| s.up_lean_weight = w,
        4.0,
        &[Column::Flat, Column::Down],
        "up-lean",
    );
    // The committed actor leans back on the flight, so most steps with the token up pay.
    let charged = charged_steps(&off, &on);
    assert!(
        charged * 4 > off.0.len(),
        "charged at only {charged} of {} steps",
        off.0.len()
    );
}

/// `--stance-lead`: charged on an up flight, where the committed actor at times stands on one foot
/// more than 0.05 m (at most 0.10 m) ahead of its base; flat ground and down flights, whose tokens
/// do not read up, pay exactly the same.
#[test]
fn stance_lead_charges_a_lone_foot_far_ahead_while_the_token_reads_up_and_nothing_else() {
    if peer_weights().is_none() {
        return;
    }
    assert_term_charges_up_flights_only(
        |s, w| s.stance_lead_weight = w,
        5.0,
        &[Column::Flat, Column::Down],
        "stance-lead",
    );
}

/// `--hold-line`: the trainer's operator steers back to the line through the start by the
/// firmware's rule, so a heading-hold walk that drifts off its line under heading hold alone ends
/// closer to it, and the command differs only by turning back toward the line.
#[test]
fn hold_line_steers_training_walks_back_to_their_line() {
    if peer_weights().is_none() {
        return;
    }
    let spec = stair_spec();
    let weights = std::fs::read(spec.weights_path()).unwrap();
    let walk = |hold_line: bool| {
        let mut cfg = test_cfg(g1_sim::ModelChoice::G1_12Dof, spec.clone(), Column::Flat);
        cfg.settings.hold_line = hold_line;
        let mut e = StairEnv::new(cfg, 3, &weights).unwrap();
        let mut mean = vec![0.0f32; 12];
        let mut turned_back = 0;
        for _ in 0..450 {
            let [x, y, _] = e.base_position();
            let h = e.target_heading();
            let left = control::operator::left_of_line(h as f32, x as f32, y as f32);
            let yaw = control::operator::imu_yaw(e.low_state());
            let plain = control::operator::heading_command(0.5, h as f32, yaw)[2];
            let cmd = e.operator_command()[2];
            if hold_line && left.abs() > 0.02 {
                // Left of the line: turn right of what heading hold asks (and the reverse).
                assert!(
                    (cmd - plain) * left as f32 <= 0.0,
                    "{left} m off: {cmd} vs heading hold's {plain}"
                );
                turned_back += ((cmd - plain).abs() > 1e-4) as usize;
            } else if !hold_line {
                assert_eq!(cmd, plain);
            }
            e.observe_and_act(&mut mean).unwrap();
            let out = e.step(&mean).unwrap();
            assert!(!out.terminated, "fell on flat ground");
            if out.truncated {
                break;
            }
        }
        let [x, y, _] = e.base_position();
        let h = e.target_heading();
        (
            control::operator::left_of_line(h as f32, x as f32, y as f32).abs(),
            turned_back,
        )
    };
    let (plain_off, _) = walk(false);
    let (held_off, turned_back) = walk(true);
    eprintln!("off the line after the walk: {plain_off:.3} m with heading hold, {held_off:.3} m with the line hold ({turned_back} commands turned back)");
    assert!(turned_back > 0, "the line hold never changed a command");
    assert!(
        held_off < plain_off,
        "the line hold ended {held_off:.3} m off the line, heading hold alone {plain_off:.3} m"
    );
}

/// `--stair-turns`: a staircase episode's target heading leaves the axis once and comes back, so
/// the command differs from holding the axis only for a while, and always to one side; flat
/// episodes and runs without the flag hold the axis at every step.
#[test]
fn stair_turns_command_one_turn_off_the_axis_on_staircases_only() {
    if peer_weights().is_none() {
        return;
    }
    let spec = stair_spec();
    let weights = std::fs::read(spec.weights_path()).unwrap();
    // Per step: the command's turn rate minus heading hold's toward the axis.
    let walk = |share: f64, only: Column, seed: u64| {
        let mut cfg = test_cfg(g1_sim::ModelChoice::G1_12Dof, spec.clone(), only);
        cfg.settings.stair_turn_share = share;
        let mut e = StairEnv::new(cfg, seed, &weights).unwrap();
        let mut mean = vec![0.0f32; 12];
        let mut diffs = Vec::new();
        for _ in 0..450 {
            let yaw = control::operator::imu_yaw(e.low_state());
            let cmd = e.operator_command();
            let axis = control::operator::heading_command(cmd[0], e.target_heading() as f32, yaw);
            assert_eq!(cmd[..2], axis[..2], "a turn changed the speed command");
            diffs.push(cmd[2] - axis[2]);
            e.observe_and_act(&mut mean).unwrap();
            let out = e.step(&mean).unwrap();
            if out.terminated || out.truncated {
                break;
            }
        }
        diffs
    };
    let mut turned_episodes = 0;
    for seed in 0..3 {
        let diffs = walk(1.0, Column::Up, seed);
        let turned: Vec<f32> = diffs.iter().copied().filter(|d| d.abs() > 1e-6).collect();
        let (left, right) = (
            turned.iter().filter(|&&d| d > 0.0).count(),
            turned.iter().filter(|&&d| d < 0.0).count(),
        );
        eprintln!("seed {seed}: {} steps, {left} turned left, {right} right", diffs.len());
        assert!(
            left == 0 || right == 0,
            "seed {seed}: one turn went both ways ({left} left, {right} right)"
        );
        // A turn lasts 1–2.5 s (50–125 policy steps) once the episode reaches it; heading hold
        // saturates at the same limit on both sides now and then, so a few steps may match.
        if !turned.is_empty() {
            turned_episodes += 1;
            assert!(
                turned.len() <= 126,
                "seed {seed}: off the axis for {} steps",
                turned.len()
            );
        }
        assert!(turned.len() < diffs.len(), "seed {seed}: never on the axis");
    }
    assert!(turned_episodes > 0, "no staircase episode turned");
    for (share, only) in [(1.0, Column::Flat), (0.0, Column::Up)] {
        let diffs = walk(share, only, 0);
        assert!(
            diffs.iter().all(|&d| d == 0.0),
            "share {share} on {only:?}: the command left the axis"
        );
    }
}

/// `--end-stalled`: a robot that makes no progress towards a staircase (Unitree's walker, trained on
/// backward commands, told to back away at 0.3 m/s; the stair policies never saw one and walk on)
/// fails once it has gained less than
/// `g1fw eval`'s 0.1 m in 3 s, as a stall (cause `stalled`, terminated, not truncated); on flat
/// ground, and without the flag, it is no failure.
#[test]
fn end_stalled_fails_a_robot_making_no_progress_at_the_stairs_as_g1fw_eval_calls_it() {
    use train::ppo::env::FALL_CAUSES;
    let Some(peer) = peer_weights() else { return };
    let spec = stair_spec();
    let (_, weights) = warm_start(&spec, &peer);
    let stand = |column: Column, end_stalled: bool| {
        let mut cfg = test_cfg(g1_sim::ModelChoice::G1_12Dof, spec.clone(), column);
        cfg.settings.end_stalled = end_stalled;
        let mut e = StairEnv::new(cfg, 3, &weights).unwrap();
        e.hold(0, -0.3).unwrap();
        let dt = e.timing().policy_dt;
        let mut mean = vec![0.0f32; 12];
        for step in 1..=(5.0 / dt) as usize {
            e.observe_and_act(&mut mean).unwrap();
            let out = e.step(&mean).unwrap();
            if out.terminated || out.truncated {
                e.reset().unwrap();
                let end = e.last_end.unwrap();
                return Some((step as f64 * dt, out.terminated, FALL_CAUSES[end.cause], end.fell));
            }
        }
        None
    };
    let (t, terminated, cause, fell) = stand(Column::Up, true).expect("backing away from the stairs never ended");
    assert!(
        terminated && fell && cause == "stalled",
        "{t} s: terminated {terminated}, cause {cause}"
    );
    assert!(
        t >= firmware::eval::STALL_WINDOW_S,
        "ended at {t} s, before g1fw eval's {} s window could pass",
        firmware::eval::STALL_WINDOW_S
    );
    assert_eq!(
        stand(Column::Up, false),
        None,
        "without --end-stalled backing away is no failure"
    );
    assert_eq!(
        stand(Column::Flat, true),
        None,
        "flat ground has no staircase to stall on"
    );
}

/// A stand command on a staircase (IsaacLab's standing envs) asks the robot to stay put: with
/// `--end-stalled` it is no stall, it scores no success and it moves no curriculum level. Until run
/// 21 it ended as a stall and paid the success bonus for crossing anyway, which taught the stair
/// policy to walk at 0.27 m/s when told to stop.
#[test]
fn a_stand_command_on_stairs_is_neither_a_stall_nor_a_success_and_keeps_the_level() {
    let Some(peer) = peer_weights() else { return };
    let spec = stair_spec();
    let (_, weights) = warm_start(&spec, &peer);
    let mut cfg = test_cfg(g1_sim::ModelChoice::G1_12Dof, spec.clone(), Column::Up);
    cfg.settings.end_stalled = true;
    cfg.settings.stand_share = 1.0;
    cfg.settings.episode_s = 5.0;
    let mut e = StairEnv::new(cfg, 3, &weights).unwrap();
    e.place(Column::Up, 3).unwrap();
    assert!(e.standing(), "stand share 1: {:?}", e.operator_command());
    assert_eq!(e.operator_command()[0], 0.0);
    let dt = e.timing().policy_dt;
    let mut progress = Vec::new();
    let mut mean = vec![0.0f32; 12];
    let mut steps = 0;
    loop {
        e.observe_and_act(&mut mean).unwrap();
        let out = e.step(&mean).unwrap();
        steps += 1;
        progress.push(e.progress());
        assert!(
            !out.terminated,
            "ended at {} s: {}",
            steps as f64 * dt,
            e.debug_summary()
        );
        if out.truncated {
            break;
        }
    }
    assert!(
        steps as f64 * dt > firmware::eval::STALL_WINDOW_S,
        "the episode ({steps} steps) was shorter than the stall window"
    );
    // It did stand: some stall window passed with less progress than a walking command needs.
    let window = (firmware::eval::STALL_WINDOW_S / dt).round() as usize;
    let least = progress
        .windows(window + 1)
        .map(|w| w[window] - w[0])
        .fold(f64::INFINITY, f64::min);
    assert!(
        least < firmware::eval::STALL_PROGRESS_M,
        "the peer gained at least {least} m in every stall window when told to stand"
    );
    e.reset().unwrap();
    let end = e.last_end.unwrap();
    assert!(end.standing && !end.success && !end.fell, "{end:?}");
    assert_eq!(end.level, 3);
    assert_eq!(e.level, 3, "a stand that did not get halfway demoted the environment");
}
