//! Deploy-spec validation and observation layout: the unitree_rl_lab-style test spec (history and
//! joint map) and the errors a broken spec gives.
use std::path::{Path, PathBuf};

use control::controller::{Controller, Mode};
use control::obs::{ObsInputs, ObservationBuilder};
use control::spec::DeploySpec;
use hal::{LowCommand, LowState, TickTime};

fn specs_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../specs")
}

fn rl_lab_spec() -> DeploySpec {
    DeploySpec::load(&specs_dir().join("test/rl_lab_style.toml")).expect("test spec loads")
}

#[test]
fn rl_lab_spec_has_480_inputs_and_isaaclab_joint_map() {
    let spec = rl_lab_spec();
    assert_eq!(spec.observation_dim(), 480);
    assert_eq!(spec.num_joints(), 29);
    assert_eq!(spec.decimation(), 10);
    // IsaacLab index 2 is the waist yaw, SDK slot 12.
    assert_eq!(spec.policy.joint_ids_map[2], 12);
}

/// Frame `k` puts value `k*1000 + element` in every term, so each output position reveals which
/// frame and element it came from.
fn push_frame(b: &mut ObservationBuilder, k: usize, out: &mut [f32]) {
    let v = |i: usize| (k * 1000 + i) as f32;
    let jp: Vec<f32> = (0..29).map(|i| v(100 + i)).collect();
    let jv: Vec<f32> = (0..29).map(|i| v(200 + i)).collect();
    let la: Vec<f32> = (0..29).map(|i| v(300 + i)).collect();
    let x = ObsInputs {
        gyro: [v(0), v(1), v(2)],
        quat: [1.0, 0.0, 0.0, 0.0],
        command: [v(10), v(11), v(12)],
        joint_pos_rel: &jp,
        joint_vel: &jv,
        last_action: &la,
        phase: 0.0,
        terrain: hal::TerrainToken::FLAT,
    };
    b.build(&x, out);
}

#[test]
fn terrain_token_term_is_the_papers_z() {
    let mut spec = rl_lab_spec();
    spec.observation.terms.push(control::spec::ObsTerm {
        kind: control::spec::ObsKind::TerrainToken,
        scale: control::spec::Scale::Scalar(1.0),
        clip: None,
        clip_before_scale: None,
        history: 1,
    });
    let mut b = ObservationBuilder::new(&spec);
    let mut out = vec![0.0; b.dim()];
    let z = hal::TerrainToken {
        class: hal::TerrainClass::StairsDown,
        step_height_m: 0.17,
        step_depth_m: 0.29,
        yaw_rad: -0.4,
    };
    let zeros = vec![0.0f32; 29];
    let x = ObsInputs {
        gyro: [0.0; 3],
        quat: [1.0, 0.0, 0.0, 0.0],
        command: [0.0; 3],
        joint_pos_rel: &zeros,
        joint_vel: &zeros,
        last_action: &zeros,
        phase: 0.0,
        terrain: z,
    };
    b.build(&x, &mut out);
    assert_eq!(out.len(), 480 + 4);
    assert_eq!(out[480..], [2.0, 0.17, 0.29, -0.4]);
}

#[test]
fn term_major_history_is_oldest_first_per_term_and_primed_by_the_first_frame() {
    let mut spec = rl_lab_spec();
    for t in &mut spec.observation.terms {
        t.clip = None;
        t.scale = control::spec::Scale::Scalar(1.0);
    }
    let mut b = ObservationBuilder::new(&spec);
    let mut out = vec![0.0; 480];
    push_frame(&mut b, 1, &mut out);
    // After one frame all 5 history slots hold frame 1.
    for h in 0..5 {
        assert_eq!(out[h * 3], 1000.0, "ang vel history slot {h}");
    }
    for k in 2..=7 {
        push_frame(&mut b, k, &mut out);
    }
    // Newest frame is 7; history holds 3,4,5,6,7, oldest first.
    // Term 0: base_ang_vel (3 × 5 = 15 values) at 0..15.
    assert_eq!(&out[0..3], &[3000.0, 3001.0, 3002.0]);
    assert_eq!(&out[12..15], &[7000.0, 7001.0, 7002.0]);
    // Term 1: projected gravity at 15..30, upright → (0, 0, −1) in every frame.
    assert_eq!(&out[15..18], &[0.0, 0.0, -1.0]);
    // Term 2: command at 30..45.
    assert_eq!(out[30], 3010.0);
    assert_eq!(out[42], 7010.0);
    // Term 3: joint_pos_rel at 45..190, 29 per frame.
    assert_eq!(out[45], 3100.0);
    assert_eq!(out[45 + 4 * 29 + 28], 7128.0);
    // Term 4: joint_vel at 190..335; term 5: last_action at 335..480.
    assert_eq!(out[190], 3200.0);
    assert_eq!(out[335 + 4 * 29], 7300.0);
    assert_eq!(out[479], 7328.0);
}

#[test]
fn scales_and_clips_apply_per_term() {
    let spec = rl_lab_spec();
    let mut b = ObservationBuilder::new(&spec);
    let mut out = vec![0.0; 480];
    push_frame(&mut b, 0, &mut out);
    // base_ang_vel scale 0.2: 2 * 0.2 (newest frame at 12..15).
    assert!((out[14] - 0.4).abs() < 1e-6);
    // joint_pos_rel element 28 is 128 → clipped to 100; element 0 is exactly 100.
    assert_eq!(out[45 + 28], 100.0);
    assert_eq!(out[45 + 27], 100.0);
    assert_eq!(out[45 + 4 * 29], 100.0);
    // base_ang_vel 1000 * 0.2 = 200 → clipped to 100.
    push_frame(&mut b, 1, &mut out);
    assert_eq!(out[12], 100.0);
}

#[test]
fn controller_reads_joints_through_the_map_and_writes_targets_to_slots() {
    let spec = rl_lab_spec();
    let mut c = Controller::new(spec.clone()).unwrap();
    let mut state = LowState::default();
    for (slot, m) in state.motors.iter_mut().enumerate() {
        m.q = slot as f32 * 0.01;
    }
    let mut cmd = LowCommand::default();
    let ticks_to_first_policy = (0.5 * 500.0) as u64 + 10;
    for k in 0..=ticks_to_first_policy {
        let info = c.tick(
            &state,
            TickTime {
                index: k,
                time_ns: k * 2_000_000,
            },
            [2.0, 0.0, 0.0],
            &mut cmd,
        );
        assert_eq!(info.policy_step, k == ticks_to_first_policy, "tick {k}");
    }
    assert_eq!(c.mode(), Mode::Policy);
    let obs = c.observation();
    // joint_pos_rel (newest frame, the whole history is primed): IsaacLab index 2 = slot 12.
    let newest = 45 + 4 * 29;
    assert!((obs[newest + 2] - (0.12 - spec.policy.default_pose[2])).abs() < 1e-6);
    // The command was clamped to max vx 1.0 before entering the observation.
    assert_eq!(obs[30 + 12], 1.0);
    // Targets land in the mapped slots: slot 12 gets IsaacLab joint 2's default + scaled action.
    let a = c.last_action()[2];
    let expected = spec.policy.default_pose[2] + 0.25 * a;
    assert!((cmd.motors[12].q - expected).abs() < 1e-6);
    assert_eq!(cmd.motors[12].kp, 300.0);
    assert_eq!(cmd.motors[29].mode, 0, "unused slots stay disabled");
}

#[test]
fn ramp_moves_linearly_from_the_measured_pose() {
    let spec = rl_lab_spec();
    let mut c = Controller::new(spec.clone()).unwrap();
    let state = LowState::default(); // all joints at 0
    let mut cmd = LowCommand::default();
    for k in 0..=125 {
        c.tick(&state, TickTime { index: k, time_ns: 0 }, [0.0; 3], &mut cmd);
    }
    // Halfway through a 250-tick ramp: half the default pose. Slot 3 = left knee, default 0.3.
    assert!((cmd.motors[3].q - 0.15).abs() < 1e-6, "{}", cmd.motors[3].q);
    assert_eq!(c.mode(), Mode::Startup);
}

fn load_err(text: &str) -> String {
    DeploySpec::from_toml(text, &specs_dir().join("test/x.toml"))
        .unwrap_err()
        .to_string()
}

#[test]
fn broken_specs_name_the_field() {
    let good = std::fs::read_to_string(specs_dir().join("test/rl_lab_style.toml")).unwrap();
    let e = load_err(&good.replace("input = 480", "input = 479"));
    assert!(
        e.contains("`observation`") && e.contains("480") && e.contains("479"),
        "{e}"
    );
    let e = load_err(&good.replace("action_scale = 0.25", "action_scale = [0.25, 0.25]"));
    assert!(e.contains("policy.action_scale"), "{e}");
    let e = load_err(&good.replace("policy_hz = 50", "policy_hz = 7"));
    assert!(e.contains("`rates`"), "{e}");
    let e = load_err(&good.replace("[0, 6, 12, 1,", "[0, 6, 13, 1,"));
    assert!(e.contains("joint_ids_map"), "{e}");
    let e = load_err(&good.replace(
        "\"waist_yaw_joint\", \"left_hip_roll_joint\"",
        "\"left_hip_roll_joint\", \"waist_yaw_joint\"",
    ));
    assert!(e.contains("policy.joint_names[2]"), "{e}");
    let e = load_err(&good.replace("kind = \"joint_vel\"", "kind = \"joint_jerk\""));
    assert!(
        e.contains("not valid TOML for a deploy spec") && e.contains("joint_jerk"),
        "{e}"
    );
    let e = load_err(&good.replace("[meta]", "[meta]\nbogus = 1"));
    assert!(e.contains("bogus"), "{e}");
}

#[test]
fn wrong_network_dimension_is_a_clear_error() {
    // Observation and network.input agree (481) but the weights take 480.
    let good = std::fs::read_to_string(specs_dir().join("test/rl_lab_style.toml")).unwrap();
    let text = good
        .replace("input = 480", "input = 482")
        .replace(
            "{ kind = \"last_action\", history = 5, clip = 100.0 },",
            "{ kind = \"last_action\", history = 5, clip = 100.0 },\n  { kind = \"gait_phase\" },",
        )
        .replace(
            "[observation]",
            "[phase]\nperiod_s = 0.8\nfirst_step_time_s = 0.02\n\n[observation]",
        );
    let spec = DeploySpec::from_toml(&text, &specs_dir().join("test/x.toml")).unwrap();
    let e = control::nn::with_causes(&Controller::new(spec).err().expect("dimension mismatch"));
    assert!(e.contains("482"), "{e}");
}

/// IsaacLab clips a term's raw value to `[low, high]` and then scales it (`clip_before_scale`);
/// this project's `clip` is symmetric and after scaling. Both orders, on the gyroscope term.
#[test]
fn clip_before_scale_is_isaaclabs_order() {
    let mut spec = rl_lab_spec();
    spec.observation.history_layout = control::spec::HistoryLayout::TermMajor;
    spec.observation.terms = vec![control::spec::ObsTerm {
        kind: control::spec::ObsKind::BaseAngVel,
        scale: control::spec::Scale::Scalar(0.5),
        clip: None,
        clip_before_scale: Some([-1.0, 2.0]),
        history: 1,
    }];
    let zeros = vec![0.0; 29];
    let frame = |gyro: [f32; 3]| ObsInputs {
        gyro,
        quat: [1.0, 0.0, 0.0, 0.0],
        command: [0.0; 3],
        joint_pos_rel: &zeros,
        joint_vel: &zeros,
        last_action: &zeros,
        phase: 0.0,
        terrain: hal::TerrainToken::FLAT,
    };
    let mut b = ObservationBuilder::new(&spec);
    let mut out = vec![0.0; 3];
    b.build(&frame([3.0, -3.0, 0.5]), &mut out);
    assert_eq!(out, [1.0, -0.5, 0.25]);
    spec.observation.terms[0].clip = Some(0.6);
    let mut b = ObservationBuilder::new(&spec);
    b.build(&frame([3.0, -3.0, 0.5]), &mut out);
    assert_eq!(out, [0.6, -0.5, 0.25]);
}

#[test]
fn clip_before_scale_bounds_must_be_ordered() {
    let good = std::fs::read_to_string(specs_dir().join("test/rl_lab_style.toml")).unwrap();
    let e = load_err(&good.replace(
        "{ kind = \"base_ang_vel\", scale = 0.2, history = 5, clip = 100.0 }",
        "{ kind = \"base_ang_vel\", scale = 0.2, history = 5, clip_before_scale = [1.0, -1.0] }",
    ));
    assert!(
        e.contains("observation.terms[0].clip_before_scale") && e.contains("low <= high"),
        "{e}"
    );
}

/// unitree_rl_lab's arm kd 10 is more than explicit PD at 500 Hz holds on the light distal joints
/// (kd·dt/I > 2); the test spec's own gains are not.
#[test]
fn explicit_pd_unstable_gains_are_warned() {
    let good = std::fs::read_to_string(specs_dir().join("test/rl_lab_style.toml")).unwrap();
    let spec = DeploySpec::from_toml(&good, &specs_dir().join("test/x.toml")).unwrap();
    assert!(
        spec.explicit_pd_warnings().is_empty(),
        "{:?}",
        spec.explicit_pd_warnings()
    );
    let kd10 = good.replace(
        "kd = [2, 2, 20, 2, 2, 20, 2, 2, 20, 4, 4, 5, 5, 2, 2, 5, 5, 2, 2, 2, 2, 2, 2, 2, 2, 2, 2, 2, 2]",
        "kd = [2, 2, 20, 2, 2, 20, 2, 2, 20, 4, 4, 10, 10, 2, 2, 10, 10, 2, 2, 10, 10, 10, 10, 10, 10, 10, 10, 10, 10]",
    );
    assert_ne!(kd10, good);
    let spec = DeploySpec::from_toml(&kd10, &specs_dir().join("test/x.toml")).unwrap();
    let w = spec.explicit_pd_warnings();
    // Both elbows and all six wrist joints; not the shoulders, waist or legs.
    assert_eq!(w.len(), 8, "{w:?}");
    assert!(
        w.iter()
            .any(|l| l.starts_with("left_wrist_pitch: kd 10") && l.contains("= 4.7 > 2")),
        "{w:?}"
    );
    assert!(
        !w.iter().any(|l| l.contains("waist") || l.contains("shoulder")),
        "{w:?}"
    );
}

/// The values that passed `check-spec` and then panicked or reached the motors (issue 22): each is
/// now refused at load, naming the field.
#[test]
fn out_of_range_values_are_refused_by_field() {
    let good = std::fs::read_to_string(specs_dir().join("test/rl_lab_style.toml")).unwrap();
    let cases: [(&str, &str, &str); 9] = [
        ("action_clip = 10.0", "action_clip = -5.0", "policy.action_clip"),
        ("action_clip = 10.0", "action_clip = nan", "policy.action_clip"),
        (
            "[safety]",
            "[safety]\njoint_range_margin_rad = 5.0",
            "safety.joint_range_margin_rad",
        ),
        ("kp = [100, 100, 300,", "kp = [-100, 100, 300,", "policy.kp[0]"),
        ("kp = [100, 100, 300,", "kp = [1e30, 100, 300,", "policy.kp[0]"),
        ("kd = [2, 2, 20,", "kd = [2, 2, 2000,", "policy.kd[2]"),
        (
            "default_pose = [-0.1,",
            "default_pose = [100.0,",
            "policy.default_pose[0]",
        ),
        ("action_scale = 0.25", "action_scale = inf", "policy.action_scale[0]"),
        (
            "scale = 0.2, history = 5",
            "scale = nan, history = 5",
            "observation.terms[0].scale",
        ),
    ];
    for (from, to, field) in cases {
        let text = if from == "[safety]" && !good.contains("[safety]") {
            format!("{good}\n[safety]\njoint_range_margin_rad = 5.0\n")
        } else {
            assert!(good.contains(from), "the test spec changed: {from}");
            good.replacen(from, to, 1)
        };
        let e = load_err(&text);
        assert!(e.contains(field), "{to}: {e}");
    }
}

/// `g1fw run --set`: a dotted key takes a TOML value, the spec's text is the overridden one (the log
/// keeps it, so replay runs what ran), and a misspelt key is refused as the file's would be.
#[test]
fn command_line_overrides_change_the_spec_and_its_text() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../specs/test/rl_lab_style.toml");
    let plain = DeploySpec::load(&path).unwrap();
    let set = DeploySpec::load_with_overrides(&path, &["safety.state_timeout_s=0.1".into()]).unwrap();
    assert_eq!(set.safety.state_timeout_s, 0.1);
    assert_ne!(plain.safety.state_timeout_s, 0.1);
    let again = DeploySpec::from_toml(&set.source_text, &path).unwrap();
    assert_eq!(again.safety.state_timeout_s, 0.1, "the kept text carries the override");
    assert!(set.source_text.starts_with('#') && set.source_text.contains("--set safety.state_timeout_s=0.1"));
    let typo = DeploySpec::load_with_overrides(&path, &["safety.state_timeout=0.1".into()]).unwrap_err();
    assert!(typo.to_string().contains("state_timeout"), "{typo}");
    let no_eq = DeploySpec::load_with_overrides(&path, &["safety.state_timeout_s".into()]).unwrap_err();
    assert!(no_eq.to_string().contains("KEY=VALUE"), "{no_eq}");
    let bad_value = DeploySpec::load_with_overrides(&path, &["safety.state_timeout_s=-1".into()]).unwrap_err();
    assert!(bad_value.to_string().contains("state_timeout_s"), "{bad_value}");
}
