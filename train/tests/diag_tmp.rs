use std::sync::Arc;
use train::ppo::env::*;
use train::ppo::policy::ActorCritic;
#[test]
fn diag() {
    let spec = firmware::spec::DeploySpec::load(std::path::Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../specs/stairs/g1_stairs_lstm.toml"
    )))
    .unwrap();
    let peer = g1_sim::model::shared_dir().join("peer_policy/unitree_g1_lstm/policy.safetensors");
    let obs = spec.observation_dim();
    let ac = ActorCritic::new(obs, obs + CRITIC_EXTRA, 12, 0.3, 0).unwrap();
    ac.load_actor_widened(&peer).unwrap();
    let w = ac.actor_safetensors().unwrap();
    for (col, rnd) in [
        (Column::Flat, Randomization::DEFAULT),
        (Column::Up, Randomization::NONE),
        (Column::Down, Randomization::NONE),
        (Column::Up, Randomization::DEFAULT),
    ] {
        let cfg = EnvConfig {
            model: g1_sim::ModelChoice::G1_12Dof,
            spec: Arc::new(spec.clone()),
            episode_s: 12.0,
            random: rnd,
            vx: (0.5, 0.5),
            max_init_level: 0,
            only: Some(col),
        };
        let mut e = StairEnv::new(cfg, 7, &w).unwrap();
        let mut mean = vec![0.0; 12];
        let mut n = 0;
        let mut fails = 0;
        let mut succ = 0;
        let mut causes = [0; 3];
        let mut steps = 0;
        while n < 8 {
            e.observe_and_act(&mut mean).unwrap();
            let o = e.step(&mean.clone()).unwrap();
            steps += 1;
            if o.terminated || o.truncated {
                e.reset().unwrap();
                let end = e.last_end.unwrap();
                n += 1;
                if end.fell {
                    fails += 1;
                    causes[end.cause] += 1;
                }
                if end.success {
                    succ += 1;
                }
            }
        }
        eprintln!("{col:?}: 8 episodes {steps} steps, fell {fails} causes {causes:?}, success {succ}");
    }
}
