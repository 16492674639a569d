//! The mirror used for symmetry augmentation agrees with the firmware: the observation the
//! firmware's `PolicyIo` builds from a mirrored robot is the mirror of the original's observation,
//! and a mirrored action gives the mirrored PD targets.
use std::path::PathBuf;

use control::policy_io::PolicyIo;
use control::spec::DeploySpec;
use hal::{LowState, TerrainClass, TerrainToken, XorShift64, NUM_MOTORS};
use train::ppo::env::StairEnv;
use train::ppo::symmetry::Mirror;

fn spec(name: &str) -> DeploySpec {
    let p = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../specs/stairs")).join(name);
    DeploySpec::load(&p).expect("stair spec")
}

fn partner(spec: &DeploySpec, i: usize) -> (usize, f32) {
    let name = &spec.policy.joint_names[i];
    let other = if let Some(r) = name.strip_prefix("left_") {
        format!("right_{r}")
    } else if let Some(r) = name.strip_prefix("right_") {
        format!("left_{r}")
    } else {
        name.clone()
    };
    let j = spec.policy.joint_names.iter().position(|n| *n == other).unwrap();
    let sign = if name.contains("roll") || name.contains("yaw") {
        -1.0
    } else {
        1.0
    };
    (j, sign)
}

fn check(spec: &DeploySpec) {
    let mirror = Mirror::from_spec(spec, &StairEnv::critic_extra_mirror()).unwrap();
    let n = spec.num_joints();
    let ids = &spec.policy.joint_ids_map;
    let mut rng = XorShift64(7);
    let mut u = |k: f32| k * rng.signed();
    for trial in 0..20 {
        // A robot in some state, and its mirror image.
        let mut s = LowState::default();
        let mut m = LowState::default();
        let (w, x, y, z) = (1.0, u(0.2), u(0.2), u(0.5));
        let norm = (w * w + x * x + y * y + z * z).sqrt();
        s.imu.quaternion = [w / norm, x / norm, y / norm, z / norm];
        m.imu.quaternion = [w / norm, -x / norm, y / norm, -z / norm];
        let g = [u(2.0), u(2.0), u(2.0)];
        s.imu.gyroscope = g;
        m.imu.gyroscope = [-g[0], g[1], -g[2]];
        for i in 0..n {
            let (j, sign) = partner(spec, i);
            let (q, dq) = (spec.policy.default_pose[i] + u(0.3), u(5.0));
            s.motors[ids[i]].q = q;
            s.motors[ids[i]].dq = dq;
            m.motors[ids[j]].q = sign * q;
            m.motors[ids[j]].dq = sign * dq;
        }
        let cmd = [u(0.7), u(0.4), u(1.0)];
        let cmd_m = [cmd[0], -cmd[1], -cmd[2]];
        let token = TerrainToken {
            class: TerrainClass::StairsUp,
            step_height_m: 0.15,
            step_depth_m: 0.3,
            yaw_rad: u(0.5),
        };
        let token_m = TerrainToken {
            yaw_rad: -token.yaw_rad,
            ..token
        };
        let action: Vec<f32> = (0..n).map(|_| u(0.5)).collect();
        let mut action_m = Vec::new();
        mirror.action.apply_rows(&action, &mut action_m);

        // The same last action (mirrored) and a gait clock half a period apart (the other leg
        // leads): 0.8 s at 50 Hz is 40 steps, so the mirror observes 20 more frames of its state.
        let (mut io, mut io_m) = (PolicyIo::new(spec), PolicyIo::new(spec));
        let (mut tq, mut tq_m) = ([0.0f32; NUM_MOTORS], [0.0f32; NUM_MOTORS]);
        io.apply_action(&action, &mut tq);
        io_m.apply_action(&action_m, &mut tq_m);
        for i in 0..n {
            let (j, sign) = partner(spec, i);
            assert!(
                (tq_m[ids[j]] - sign * tq[ids[i]]).abs() < 1e-6,
                "PD target of joint {i}"
            );
        }
        let period_steps = (spec.phase.as_ref().unwrap().period_s * spec.rates.policy_hz as f64).round() as usize;
        for _ in 0..3 {
            io.observe(&s, cmd, token);
        }
        for _ in 0..3 + period_steps / 2 {
            io_m.observe(&m, cmd_m, token_m);
        }
        let mut want = Vec::new();
        mirror.obs.apply_rows(io.observation(), &mut want);
        let got = io_m.observation();
        assert_eq!(want.len(), got.len());
        for (k, (a, b)) in want.iter().zip(got).enumerate() {
            assert!(
                (a - b).abs() < 1e-5,
                "trial {trial}: observation value {k}: mirror {a} vs mirrored robot {b}"
            );
        }
    }
    // A mirror twice is the identity.
    let v: Vec<f32> = (0..mirror.critic.len()).map(|k| k as f32 + 1.0).collect();
    let (mut once, mut twice) = (Vec::new(), Vec::new());
    mirror.critic.apply_rows(&v, &mut once);
    mirror.critic.apply_rows(&once, &mut twice);
    assert_eq!(v, twice);
    assert_ne!(v, once);
}

#[test]
fn the_mirror_of_an_observation_is_the_observation_of_the_mirrored_robot() {
    check(&spec("g1_stairs_mlp.toml"));
    check(&spec("g1_stairs_lstm.toml"));
}
