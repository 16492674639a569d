//! A gait clock the policy sets (`[phase] rate`): the network's output after the joints sets the
//! clock's rate from the next policy step on, clamped to the spec's range. It reaches no motor, a
//! zero output keeps the fixed clock, the mirror maps it to itself, and a network without it is
//! refused by name.
// Test inputs come from std's math on the host (`common::healthy`); this never runs on the robot.
#![allow(clippy::disallowed_methods)]
mod common;
use std::path::{Path, PathBuf};

use control::controller::Controller;
use control::policy_io::PolicyIo;
use control::spec::mirror::PolicyMirror;
use control::spec::DeploySpec;
use hal::{TerrainToken, NUM_MOTORS};

fn stair_spec_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../specs/stairs/g1_stairs_lstm.toml")
}

/// The committed stair spec, with `rate = …` added to its `[phase]` when given.
fn stair_spec(rate: Option<&str>) -> Result<DeploySpec, control::spec::SpecError> {
    let path = stair_spec_path();
    let text = std::fs::read_to_string(&path).unwrap();
    let text = match rate {
        Some(r) => {
            let anchor = "first_step_time_s = 0.02\n";
            assert!(
                text.contains(anchor),
                "the stair spec's [phase] changed; update this test"
            );
            text.replacen(anchor, &format!("{anchor}rate = {r}\n"), 1)
        }
        None => text,
    };
    DeploySpec::from_toml(&text, &path)
}

const RANGE: &str = "{ min = 0.5, max = 1.5 }";

/// Distance between two phases on the unit circle.
fn circular(a: f32, b: f32) -> f32 {
    let d = (a - b).rem_euclid(1.0);
    d.min(1.0 - d)
}

#[test]
fn a_rate_adds_one_output_and_a_bad_range_is_refused_by_name() {
    let fixed = stair_spec(None).unwrap();
    let set = stair_spec(Some(RANGE)).unwrap();
    assert_eq!(fixed.action_dim(), fixed.num_joints());
    assert_eq!(set.action_dim(), set.num_joints() + 1);
    for bad in [
        "{ min = 0.0, max = 1.5 }",
        "{ min = 1.2, max = 1.5 }",
        "{ min = 0.5, max = 0.9 }",
        "{ min = 0.5, max = 5.0 }",
        "{ min = nan, max = 1.5 }",
        "{ min = 0.5, max = inf }",
    ] {
        let err = stair_spec(Some(bad))
            .err()
            .unwrap_or_else(|| panic!("{bad} was accepted"));
        assert!(err.to_string().contains("phase.rate"), "{bad}: {err}");
    }
    assert!(stair_spec(Some("{ min = 0.5 }")).is_err(), "a range needs both ends");
}

#[test]
fn a_zero_rate_output_keeps_the_fixed_clock_and_no_rate_output_reaches_a_motor() {
    let fixed_spec = stair_spec(None).unwrap();
    let set_spec = stair_spec(Some(RANGE)).unwrap();
    let n = fixed_spec.num_joints();
    let (mut fixed, mut set, mut set_fast) = (
        PolicyIo::new(&fixed_spec),
        PolicyIo::new(&set_spec),
        PolicyIo::new(&set_spec),
    );
    let mut worst = 0.0f32;
    for k in 0..400u64 {
        let s = common::healthy(k * 10);
        let cmd = [0.5, 0.0, 0.0];
        let of = fixed.observe(&s, cmd, TerrainToken::FLAT).to_vec();
        let os = set.observe(&s, cmd, TerrainToken::FLAT).to_vec();
        set_fast.observe(&s, cmd, TerrainToken::FLAT);
        worst = worst.max(circular(fixed.phase(), set.phase()));
        // Everything but the two clock values agrees bit for bit.
        let differing = of.iter().zip(&os).filter(|(a, b)| a.to_bits() != b.to_bits()).count();
        assert!(differing <= 2, "step {k}: {differing} values differ");
        let joints: Vec<f32> = (0..n).map(|i| ((k + 5 * i as u64) % 13) as f32 / 6.0 - 1.0).collect();
        let (mut tf, mut ts, mut tfast) = ([0.0; NUM_MOTORS], [0.0; NUM_MOTORS], [0.0; NUM_MOTORS]);
        fixed.apply_action(&joints, &mut tf);
        let with = |r: f32| joints.iter().copied().chain([r]).collect::<Vec<_>>();
        set.apply_action(&with(0.0), &mut ts);
        set_fast.apply_action(&with(0.4), &mut tfast);
        assert_eq!(tf.map(f32::to_bits), ts.map(f32::to_bits), "step {k}");
        assert_eq!(
            tf.map(f32::to_bits),
            tfast.map(f32::to_bits),
            "step {k}: the rate reached a target"
        );
        assert_eq!(
            set_fast.last_action().len(),
            n,
            "the rate is no part of the next last action"
        );
        assert_eq!(set.clock_rate(), 1.0);
        assert_eq!(set_fast.clock_rate(), 1.0 + 0.4f32 as f64);
    }
    assert!(
        worst < 1e-5,
        "zero rate output: the phase strays {worst} from the fixed clock's"
    );
    // The faster clock has run 0.4 × 399 steps / (0.8 s · 50 Hz) periods ahead (the rate
    // counts from the step after the action that set it).
    let hz = set_spec.rates.policy_hz as f32;
    let period = set_spec.phase.as_ref().unwrap().period_s as f32;
    let ahead = 0.4 * 399.0 / (period * hz);
    assert!(
        circular(set_fast.phase() - set.phase(), ahead) < 1e-4,
        "ahead by {} periods, want {ahead}",
        (set_fast.phase() - set.phase()).rem_euclid(1.0)
    );
}

#[test]
fn the_rate_is_clamped_to_its_range_applies_from_the_next_step_and_resets() {
    let spec = stair_spec(Some(RANGE)).unwrap();
    let n = spec.num_joints();
    let step = 1.0 / (spec.phase.as_ref().unwrap().period_s as f32 * spec.rates.policy_hz as f32);
    let mut io = PolicyIo::new(&spec);
    let s = common::healthy(0);
    let mut t = [0.0; NUM_MOTORS];
    io.observe(&s, [0.0; 3], TerrainToken::FLAT);
    let start = io.phase();
    for (raw, rate) in [
        (3.0, 1.5),
        (-3.0, 0.5),
        (f32::NAN, 0.5),
        (0.25, 1.25),
        (f32::INFINITY, 1.5),
    ] {
        let mut a = vec![0.0; n + 1];
        a[n] = raw;
        let before = io.phase();
        io.apply_action(&a, &mut t);
        assert_eq!(io.clock_rate(), rate, "output {raw}");
        io.observe(&s, [0.0; 3], TerrainToken::FLAT);
        assert!(
            circular(io.phase() - before, step * rate as f32) < 1e-6,
            "output {raw}: advanced {}, want {}",
            io.phase() - before,
            step * rate as f32
        );
    }
    io.reset();
    assert_eq!(io.clock_rate(), 1.0);
    io.observe(&s, [0.0; 3], TerrainToken::FLAT);
    assert_eq!(io.phase(), start, "a reset restarts the clock where it began");
}

#[test]
fn the_mirror_maps_the_rate_to_itself() {
    let spec = stair_spec(Some(RANGE)).unwrap();
    let n = spec.num_joints();
    let with = PolicyMirror::from_spec(&spec).unwrap().action;
    let without = PolicyMirror::from_spec(&stair_spec(None).unwrap()).unwrap().action;
    assert_eq!(with.len(), n + 1);
    assert_eq!((with.source[n], with.factor[n]), (n, 1.0));
    assert_eq!(with.source[..n], without.source[..]);
    assert_eq!(with.factor[..n], without.factor[..]);
}

#[test]
fn a_network_without_the_rate_output_is_refused() {
    // The committed stair weights have one output per joint.
    let spec = stair_spec(Some(RANGE)).unwrap();
    let err = match Controller::new(spec) {
        Ok(_) => panic!("a network with one output too few was accepted"),
        Err(e) => e.to_string(),
    };
    assert!(err.contains("output"), "{err}");
    Controller::new(stair_spec(None).unwrap()).expect("the fixed clock's spec takes them");
}
