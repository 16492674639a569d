//! The fused update of a feed-forward actor ([`train::ppo::mlp_update`]) against candle's ops on
//! the same batch: the same losses, gradient norm and Adam steps, within float tolerance, with and
//! without symmetry augmentation and through the critic's warm-up.
// The trainer never runs on the robot: std's math is fine here (see clippy.toml).
#![allow(clippy::disallowed_methods)]
use labkit::rng::Rng;
use train::ppo::algo::{compute_gae, gaussian_logp, EnvRollout, Learner, Normalizer, PpoConfig, UpdateStats};
use train::ppo::policy::{ActorArch, ActorCritic, ActorLayer};
use train::ppo::symmetry::{Mirror, SignedPermutation};

const OBS: usize = 10;
const ACT: usize = 4;
const CRITIC: usize = 13;
const T: usize = 8;
const ENVS: usize = 6;

fn arch() -> ActorArch {
    let lin = |i: usize, input: usize, output: usize| ActorLayer::Linear {
        weight: format!("actor.{i}.weight"),
        bias: format!("actor.{i}.bias"),
        input,
        output,
    };
    ActorArch {
        layers: vec![
            lin(0, OBS, 32),
            ActorLayer::Elu { alpha: 1.0 },
            lin(2, 32, 16),
            ActorLayer::Elu { alpha: 1.0 },
            lin(4, 16, ACT),
        ],
    }
}

/// A swap of the first two halves of each width with a sign flip on the last element (a mirror).
fn mirror_of(n: usize) -> SignedPermutation {
    let h = n / 2;
    SignedPermutation {
        source: (0..n)
            .map(|i| {
                if i < h {
                    i + h
                } else if i < 2 * h {
                    i - h
                } else {
                    i
                }
            })
            .collect(),
        factor: (0..n).map(|i| if i == n - 1 { -1.0 } else { 1.0 }).collect(),
    }
}

/// Rollouts of the actor with exploration noise, random rewards and episode ends, GAE filled.
fn rollouts(ac: &ActorCritic, norm: &mut Normalizer, cfg: &PpoConfig) -> Vec<EnvRollout> {
    let mut rng = Rng(5);
    let log_std: Vec<f32> = ac.log_std().to_vec1().unwrap();
    let mut rolls = Vec::new();
    for _ in 0..ENVS {
        let mut r = EnvRollout::new(T, OBS, CRITIC, ACT, 0);
        for x in r.obs.iter_mut() {
            *x = rng.gaussian() as f32;
        }
        for s in 0..T {
            let o = &r.obs[s * OBS..(s + 1) * OBS];
            let c = &mut r.critic_obs[s * CRITIC..(s + 1) * CRITIC];
            c[..OBS].copy_from_slice(o);
            for x in c[OBS..].iter_mut() {
                *x = rng.gaussian() as f32;
            }
        }
        let obs = candle_core::Tensor::from_vec(r.obs.clone(), (T, 1, OBS), &candle_core::Device::Cpu).unwrap();
        let masks = candle_core::Tensor::ones((T, 1, 1), candle_core::DType::F32, &candle_core::Device::Cpu).unwrap();
        let mean: Vec<f32> = ac
            .policy_sequence(&obs, None, None, &masks)
            .unwrap()
            .flatten_all()
            .unwrap()
            .to_vec1()
            .unwrap();
        for s in 0..T {
            for (j, ls) in log_std.iter().enumerate() {
                let k = s * ACT + j;
                r.means[k] = mean[k];
                r.actions[k] = mean[k] + (*ls as f64).exp() as f32 * rng.gaussian() as f32;
            }
            r.logp[s] = gaussian_logp(
                &r.actions[s * ACT..(s + 1) * ACT],
                &r.means[s * ACT..(s + 1) * ACT],
                &log_std,
            );
            r.rewards[s] = rng.gaussian() as f32;
            r.terminated[s] = rng.chance(0.1);
        }
        for x in r.next_critic_obs.iter_mut() {
            *x = rng.gaussian() as f32;
        }
        norm.update(&r.critic_obs);
        rolls.push(r);
    }
    compute_gae(ac, norm, &mut rolls, cfg).unwrap();
    rolls
}

/// Every variable's name and values.
type Params = Vec<(String, Vec<f32>)>;

fn params(ac: &ActorCritic) -> Params {
    ac.named_vars()
        .into_iter()
        .map(|(n, v)| (n, v.as_tensor().flatten_all().unwrap().to_vec1().unwrap()))
        .collect()
}

/// One update by each path from the same actor-critic; returns both stats and parameters.
fn both(cfg: PpoConfig, symmetry: bool, critic_only: bool) -> [(UpdateStats, Params); 2] {
    let mut norm = Normalizer::new(CRITIC);
    let probe = ActorCritic::with_arch(arch(), CRITIC, 0.6, 3).unwrap();
    let rolls = rollouts(&probe, &mut norm, &cfg);
    [false, true].map(|fused| {
        let ac = ActorCritic::with_arch(arch(), CRITIC, 0.6, 3).unwrap();
        let mirror = symmetry.then(|| Mirror {
            obs: mirror_of(OBS),
            critic: mirror_of(CRITIC),
            action: mirror_of(ACT),
        });
        let mut learner = Learner::new(
            &ac,
            PpoConfig {
                fused_mlp: fused,
                ..cfg
            },
            9,
            mirror,
        )
        .unwrap();
        let stats = learner.update(&ac, &norm, &rolls, critic_only).unwrap();
        (stats, params(&ac))
    })
}

fn close(what: &str, a: f64, b: f64, rel: f64) {
    assert!(
        (a - b).abs() <= rel * a.abs().max(b.abs()) + 1e-6,
        "{what}: candle {a}, fused {b}"
    );
}

fn compare(cfg: PpoConfig, symmetry: bool, critic_only: bool, steps: usize) {
    let [(sa, pa), (sb, pb)] = both(cfg, symmetry, critic_only);
    eprintln!("candle {sa:?}\nfused  {sb:?}");
    close("value loss", sa.value_loss, sb.value_loss, 1e-4);
    close("gradient norm", sa.grad_norm, sb.grad_norm, 1e-4);
    if !critic_only {
        close("surrogate", sa.surrogate, sb.surrogate, 1e-3);
        close("entropy", sa.entropy, sb.entropy, 1e-5);
        close("kl", sa.kl, sb.kl, 1e-3);
        close("learning rate", sa.lr, sb.lr, 1e-9);
        // The KL is measured before each step: an update of one step measures none.
        assert_eq!(sa.kl > 0.0, steps > 1, "the actor's steps show in the KL");
    }
    // Adam moves each parameter by at most lr per step, in the gradient's direction: the two paths
    // agree to a small part of that (a gradient element near zero may take either sign).
    let lr = cfg.lr as f32;
    let mut moved = 0;
    for ((name, a), (_, b)) in pa.iter().zip(&pb) {
        let worst = a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0f32, f32::max);
        let mean = a.iter().zip(b).map(|(x, y)| (x - y).abs()).sum::<f32>() / a.len() as f32;
        assert!(
            worst <= 2.0 * lr * steps as f32 && mean <= 0.05 * lr * steps as f32,
            "{name}: worst {worst}, mean {mean}"
        );
        moved += 1;
    }
    assert_eq!(moved, pa.len());
    let (critic_moved, actor_moved) = {
        let probe = params(&ActorCritic::with_arch(arch(), CRITIC, 0.6, 3).unwrap());
        let differs = |prefix: &str| {
            pb.iter()
                .zip(&probe)
                .filter(|((n, _), _)| n.starts_with(prefix))
                .any(|((_, x), (_, y))| x != y)
        };
        (differs("critic."), differs("actor."))
    };
    assert!(critic_moved, "the critic stepped");
    assert_eq!(
        actor_moved, !critic_only,
        "the actor steps unless only the critic warms up"
    );
}

#[test]
fn one_step_equals_candles() {
    let cfg = PpoConfig {
        steps: T,
        epochs: 1,
        minibatches: 1,
        lr: 1e-3,
        ..Default::default()
    };
    compare(cfg, false, false, 1);
}

#[test]
fn a_whole_update_with_symmetry_equals_candles() {
    let cfg = PpoConfig {
        steps: T,
        epochs: 3,
        minibatches: 2,
        lr: 1e-3,
        desired_kl: 1e-4,
        ..Default::default()
    };
    compare(cfg, true, false, 6);
}

#[test]
fn the_critic_warm_up_equals_candles() {
    let cfg = PpoConfig {
        steps: T,
        epochs: 2,
        minibatches: 2,
        lr: 1e-3,
        ..Default::default()
    };
    compare(cfg, true, true, 4);
}

/// `max_std` caps the action noise after the update, by either path: the actors start at σ 0.6,
/// the cap is 0.5, and every output ends at or below it (those the update lowered further stay).
#[test]
fn the_noise_cap_holds_after_an_update_by_either_path() {
    let cfg = PpoConfig {
        steps: T,
        epochs: 1,
        minibatches: 1,
        max_std: Some(0.5),
        lr: 1e-3,
        ..PpoConfig::default()
    };
    for (stats, p) in both(cfg, false, false) {
        let ls = &p.iter().find(|(n, _)| n == "log_std").expect("log_std").1;
        assert!(ls.iter().all(|&l| l <= 0.5f32.ln()), "{ls:?}");
        assert!(ls.iter().any(|&l| l == 0.5f32.ln()), "the cap applied: {ls:?}");
        assert!(stats.mean_std <= 0.5 + 1e-6, "{stats:?}");
    }
}
