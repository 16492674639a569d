//! `policy_import` (g1-import) against onnxruntime: ONNX networks built the way exporters write them
//! (`tests/python/onnx_models.py`, onnx.helper with seeded weights, no project code) are imported
//! and run step by step in the firmware's executor; every output matches onnxruntime's to ≤ 1e-5.
//! Also Unitree's G1 LSTM walker re-exported to ONNX, and the errors for a refused op and a
//! truncated file.
#![allow(clippy::disallowed_methods)]
use std::path::Path;

use integration_tests::{python_json, repo_root, scratch_dir, shared_dir, skip_or_fail, venv_python};

const TOLERANCE: f64 = 1e-5;

fn models(dir: &Path) -> Option<serde_json::Value> {
    let py = venv_python("the ONNX parity test (onnx, onnxruntime)")?;
    let mut args = vec![dir.to_str().unwrap().to_string()];
    match shared_dir() {
        Some(s) => args.push(
            s.join("peer_policy/unitree_g1_lstm/policy.safetensors")
                .to_str()
                .unwrap()
                .into(),
        ),
        None => skip_or_fail("the peer policy re-exported to ONNX"),
    }
    Some(python_json(&py, "onnx_models.py", &args))
}

/// Imports `name`.onnx and runs the recorded inputs through the executor; returns the largest
/// difference from onnxruntime.
fn max_error(dir: &Path, name: &str, reference: &serde_json::Value) -> f64 {
    let net = policy_import::import_file(&dir.join(format!("{name}.onnx"))).expect("imports");
    let bytes = net.safetensors_bytes().unwrap();
    let mut exec = control::nn::Network::from_safetensors_bytes(&net.desc, &bytes).expect("loads");
    let mut out = vec![0f32; exec.output_dim()];
    let mut worst = 0f64;
    let ins = reference["inputs"].as_array().unwrap();
    let outs = reference["outputs"].as_array().unwrap();
    assert!(ins.len() >= 20);
    for (x, y) in ins.iter().zip(outs) {
        let x: Vec<f32> = x
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap() as f32)
            .collect();
        exec.step(&x, &mut out).unwrap();
        let y = y.as_array().unwrap();
        assert_eq!(y.len(), out.len(), "{name}: output size");
        for (a, b) in out.iter().zip(y) {
            worst = worst.max((*a as f64 - b.as_f64().unwrap()).abs());
        }
    }
    worst
}

#[test]
fn imported_networks_match_onnxruntime() {
    let dir = scratch_dir("onnx-import");
    let Some(reference) = models(&dir) else { return };
    for name in ["mlp", "lstm", "peer"] {
        let Some(r) = reference.get(name) else { continue };
        let e = max_error(&dir, name, r);
        eprintln!(
            "{name}: max |executor − onnxruntime| = {e:.2e} over {} steps",
            r["inputs"].as_array().unwrap().len()
        );
        assert!(e <= TOLERANCE, "{name}: max error {e:e} > {TOLERANCE:e}");
    }
    // What the import saw: the normaliser folded, both Gemm forms, MatMul + Add, the action scale.
    let mlp = policy_import::import_file(&dir.join("mlp.onnx")).unwrap();
    assert_eq!(mlp.desc.input, 24);
    assert_eq!(mlp.output_dim, 8);
    assert_eq!(
        mlp.desc.layers.iter().map(|l| l.kind()).collect::<Vec<_>>(),
        ["linear", "elu", "linear", "relu", "linear", "tanh", "linear"]
    );
    assert!(mlp.metadata.iter().any(|(k, v)| k == "action_scale" && v == "0.25"));
    let lstm = policy_import::import_file(&dir.join("lstm.onnx")).unwrap();
    let rec = lstm.recurrent.expect("recurrent");
    assert_eq!(
        (rec.hidden, rec.h_in.as_deref(), rec.c_in.as_deref()),
        (6, Some("h_in"), Some("c_in"))
    );
}

/// The peer walker through its ONNX re-export gives what the spec's own weights give.
#[test]
fn the_peer_walker_reexported_to_onnx_equals_its_spec() {
    if shared_dir().is_none() {
        return skip_or_fail("the peer walker's ONNX re-export");
    }
    let dir = scratch_dir("onnx-peer");
    let Some(_) = models(&dir) else { return };
    let spec = control::spec::DeploySpec::load(&repo_root().join("specs/peer/unitree_g1_lstm.toml")).unwrap();
    let mut original = control::nn::Network::load(&spec.policy.network, &spec.weights_path()).unwrap();
    let net = policy_import::import_file(&dir.join("peer.onnx")).unwrap();
    let mut imported =
        control::nn::Network::from_safetensors_bytes(&net.desc, &net.safetensors_bytes().unwrap()).unwrap();
    assert_eq!(imported.input_dim(), 47);
    let (mut a, mut b) = (vec![0f32; 12], vec![0f32; 12]);
    let mut rng = hal::XorShift64(7);
    let mut worst = 0f32;
    for _ in 0..200 {
        let x: Vec<f32> = (0..47).map(|_| rng.signed()).collect();
        original.step(&x, &mut a).unwrap();
        imported.step(&x, &mut b).unwrap();
        for (p, q) in a.iter().zip(&b) {
            worst = worst.max((p - q).abs());
        }
    }
    assert!(worst <= 1e-5, "spec vs ONNX re-export: {worst:e}");
}

#[test]
fn a_refused_op_and_a_truncated_file_say_what_is_wrong() {
    let dir = scratch_dir("onnx-bad");
    let Some(_) = models(&dir) else { return };
    let e = policy_import::import_file(&dir.join("softmax.onnx"))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("'Softmax'") && e.contains("actor.3.softmax") && e.contains("#6"),
        "{e}"
    );
    let e = policy_import::import_file(&dir.join("truncated.onnx"))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("not a readable ONNX model") && e.contains("truncated"),
        "{e}"
    );
    let e = policy_import::import_file(&dir.join("missing.onnx"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("missing.onnx"), "{e}");
    // LSTM features the executor cannot represent: refused by name, never imported without them.
    for (variant, says) in [
        ("peephole", "peephole weights (input P)"),
        ("clip", "attribute 'clip'"),
        ("activations", "attribute 'activations'"),
        ("input_forget", "input_forget = 1"),
        ("reverse", "direction 'reverse'"),
    ] {
        let e = policy_import::import_file(&dir.join(format!("lstm_{variant}.onnx")))
            .map(|_| ())
            .unwrap_err();
        let e = control::nn::with_causes(&e);
        assert!(e.contains(says), "{variant}: {e}");
    }
}

fn g1_import(args: &[&std::ffi::OsStr]) -> std::process::Output {
    std::process::Command::new(integration_tests::built_bin("g1-import"))
        .args(args)
        .current_dir(repo_root())
        .output()
        .expect("g1-import runs")
}

/// Unitree's G1 walker, written out as a unitree_rl_lab export (`deploy.yaml` with SDK-order gains +
/// the ONNX re-export), imports in one command into a spec equal, field by field, to the
/// hand-written one, and walks as well: 20 s at 0.5 m/s on the 12-dof G1.
#[test]
fn an_rl_lab_export_imports_into_the_hand_checked_spec_and_walks() {
    let Some(shared) = shared_dir() else {
        return skip_or_fail("the peer walker as an rl_lab export");
    };
    let dir = scratch_dir("onnx-rl-lab");
    let Some(_) = models(&dir) else { return };
    let out = dir.join("imported");
    let mjcf = shared
        .join("assets/unitree_g1_12dof/g1_12dof.xml")
        .canonicalize()
        .unwrap();
    let o = g1_import(&[
        "rl-lab".as_ref(),
        "--deploy".as_ref(),
        dir.join("deploy.yaml").as_os_str(),
        "--onnx".as_ref(),
        dir.join("peer.onnx").as_os_str(),
        "--out".as_ref(),
        out.as_os_str(),
        "--estimator-model".as_ref(),
        mjcf.as_os_str(),
    ]);
    let text = String::from_utf8_lossy(&o.stdout).to_string();
    assert!(o.status.success(), "{text}{}", String::from_utf8_lossy(&o.stderr));
    // The table a person checks: SDK-order gains landed on the right joints.
    assert!(
        text.contains("left_knee") && text.contains("17 held motor(s)"),
        "{text}"
    );

    let hand = control::spec::DeploySpec::load(&repo_root().join("specs/peer/unitree_g1_lstm.toml")).unwrap();
    let imp = control::spec::DeploySpec::load(&out.join("policy.toml")).unwrap();
    let (h, i) = (&hand.policy, &imp.policy);
    assert_eq!(i.joint_ids_map, h.joint_ids_map);
    assert_eq!(i.joint_names, h.joint_names);
    assert_eq!(i.default_pose, h.default_pose);
    assert_eq!(i.kp, h.kp);
    assert_eq!(i.kd, h.kd);
    assert_eq!(i.action_scale.expand(12), h.action_scale.expand(12));
    assert_eq!(i.action_clip, h.action_clip);
    let (mh, mi) = (hand.motor_table(), imp.motor_table());
    assert_eq!(mi.kp, mh.kp, "driven and held gains per slot");
    assert_eq!(mi.kd, mh.kd);
    assert_eq!(mi.default_q, mh.default_q);
    assert_eq!(mi.enabled[..29], mh.enabled[..29]);
    assert_eq!(
        (imp.commands.min, imp.commands.max),
        (hand.commands.min, hand.commands.max)
    );
    assert_eq!(
        (imp.rates.control_hz, imp.rates.policy_hz),
        (hand.rates.control_hz, hand.rates.policy_hz)
    );
    let (ph, pi) = (hand.phase.as_ref().unwrap(), imp.phase.as_ref().unwrap());
    assert_eq!((pi.period_s, pi.first_step_time_s), (ph.period_s, ph.first_step_time_s));
    assert_eq!(imp.observation.history_layout, hand.observation.history_layout);
    assert_eq!(imp.observation.terms.len(), hand.observation.terms.len());
    for (a, b) in imp.observation.terms.iter().zip(&hand.observation.terms) {
        assert_eq!((a.kind, a.history), (b.kind, b.history));
        let n = a.kind.dim(12);
        assert_eq!(a.scale.expand(n), b.scale.expand(n), "{:?}", a.kind);
        assert_eq!(a.clip_before_scale, None);
    }
    assert_eq!(imp.observation_dim(), 47);

    // It walks as the hand-written spec does.
    let walk = |spec: &Path, name: &str| {
        let report = dir.join(format!("{name}.json"));
        let o = integration_tests::g1fw(&[
            "sim",
            "--model",
            "g1-12dof",
            "--spec",
            spec.to_str().unwrap(),
            "--cmd",
            "0.5,0,0",
            "--duration",
            "20",
            "--seed",
            "0",
            "--quiet",
            "--report",
            report.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{name}: {}", String::from_utf8_lossy(&o.stderr));
        integration_tests::read_json(&report)
    };
    let a = walk(&out.join("policy.toml"), "imported");
    let b = walk(&repo_root().join("specs/peer/unitree_g1_lstm.toml"), "hand");
    let (da, db) = (a["distance_x_m"].as_f64().unwrap(), b["distance_x_m"].as_f64().unwrap());
    eprintln!("imported: {da:.3} m, hand-written: {db:.3} m");
    assert_eq!(a["fell"], false);
    assert!(a["trip"].is_null(), "{}", a["trip"]);
    assert!(
        da >= 8.5 && (da - db).abs() < 0.3,
        "imported {da:.2} m vs hand-written {db:.2} m"
    );
}

/// Bad exports: the error names the field.
#[test]
fn bad_rl_lab_exports_name_the_field() {
    let dir = scratch_dir("onnx-rl-lab-bad");
    let Some(_) = models(&dir) else { return };
    if shared_dir().is_none() {
        return;
    }
    let good = std::fs::read_to_string(dir.join("deploy.yaml")).unwrap();
    let opts = policy_import::RlLabOptions::default();
    let try_yaml = |text: &str, onnx: &str| {
        let p = dir.join("bad.yaml");
        std::fs::write(&p, text).unwrap();
        match policy_import::import_rl_lab(&p, &dir.join(onnx), &opts) {
            Ok(_) => panic!("accepted: {text}"),
            Err(e) => e.to_string(),
        }
    };
    let e = try_yaml("joint_ids_map: [0, 1\nstep_dt: [", "peer.onnx");
    assert!(e.contains("bad.yaml") && e.contains("not valid YAML"), "{e}");
    let e = try_yaml(&good.replace("[0, 1, 2, 3,", "[0, 1, 2, 2,"), "peer.onnx");
    assert!(
        e.contains("joint_ids_map") && e.contains("mapped twice") && e.contains("2 and 3"),
        "{e}"
    );
    let e = try_yaml(&good.replacen("history_length: 1", "history_length: 5", 1), "peer.onnx");
    assert!(e.contains("59 values") && e.contains("takes 47"), "{e}");
    let e = try_yaml(&good.replace("step_dt: 0.02", "step_dt: 0.03"), "peer.onnx");
    assert!(e.contains("`step_dt`"), "{e}");
    let e = try_yaml(&good.replace("  last_action:", "  height_scan:"), "peer.onnx");
    assert!(
        e.contains("observations.height_scan") && e.contains("unknown term"),
        "{e}"
    );
    let e = try_yaml(&good, "truncated.onnx");
    assert!(
        e.contains("truncated.onnx") && e.contains("not a readable ONNX model"),
        "{e}"
    );
}

/// An ONNX with its deploy data in metadata_props (mjlab / BeyondMimic style) imports on its own:
/// joints found by name, gains and pose in the metadata's order, the missing parts said.
#[test]
fn an_onnx_with_mjlab_metadata_imports() {
    let dir = scratch_dir("onnx-mjlab");
    let Some(_) = models(&dir) else { return };
    let imp = policy_import::import_onnx_metadata(&dir.join("mjlab.onnx"), &Default::default()).expect("imports");
    // left/right interleaved: left_hip_pitch (slot 0), right_hip_pitch (6), left_hip_roll (1), …
    assert_eq!(imp.joint_ids_map, [0, 6, 1, 7, 2, 8, 3, 9, 4, 10, 5, 11]);
    assert_eq!(imp.kp, (0..12).map(|i| 100.0 + 10.0 * i as f32).collect::<Vec<_>>());
    assert_eq!(imp.kd, (0..12).map(|i| 2.0 + 0.5 * i as f32).collect::<Vec<_>>());
    assert!((imp.default_pose[3] - (-0.15)).abs() < 1e-6);
    assert!(imp.table.contains("no command ranges"), "{}", imp.table);
    let kinds: Vec<&str> = imp.terms.iter().map(|t| t.kind).collect();
    assert_eq!(
        kinds,
        [
            "base_ang_vel",
            "projected_gravity",
            "velocity_command",
            "joint_pos_rel",
            "joint_vel",
            "last_action"
        ]
    );
    // The spec it writes loads in the firmware (weights beside it).
    let out = dir.join("spec");
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(out.join("policy.toml"), &imp.spec_toml).unwrap();
    std::fs::write(out.join("policy.safetensors"), &imp.weights).unwrap();
    let spec = control::spec::DeploySpec::load(&out.join("policy.toml")).expect("the spec loads");
    assert_eq!(spec.observation_dim(), 45);
    assert_eq!(spec.motor_table().kd[29..], [0.0; 6]);
    control::controller::Controller::new(spec).expect("the policy loads");

    let e = policy_import::import_onnx_metadata(&dir.join("mjlab_bad.onnx"), &Default::default())
        .err()
        .expect("refused")
        .to_string();
    assert!(e.contains("joint_names[11]") && e.contains("left_tail_joint"), "{e}");
    let e = policy_import::import_onnx_metadata(&dir.join("lstm.onnx"), &Default::default())
        .err()
        .expect("refused")
        .to_string();
    assert!(
        e.contains("metadata_props.joint_names") && e.contains("deploy.yaml"),
        "{e}"
    );
}

/// The shape of unitree_rl_lab's official G1 29-dof velocity export (IsaacLab joint order, SDK-order
/// gains with arm kd 10, 6 terms × 5 frames = 480 inputs with IsaacLab clips, MLP 480-512-256-128-29
/// ELU): one command, the gains land on the right joints, the network matches onnxruntime, the
/// spec loads, and the arm kd 10 is flagged for explicit PD.
#[test]
fn an_rl_lab_29dof_export_imports() {
    let dir = scratch_dir("onnx-rl-lab-29");
    let Some(reference) = models(&dir) else { return };
    let e = max_error(&dir, "rl_lab_29", &reference["rl_lab_29"]);
    assert!(e <= TOLERANCE, "{e:e}");
    let out = dir.join("imported");
    let o = g1_import(&[
        "rl-lab".as_ref(),
        "--deploy".as_ref(),
        dir.join("rl_lab_29.yaml").as_os_str(),
        "--onnx".as_ref(),
        dir.join("rl_lab_29.onnx").as_os_str(),
        "--out".as_ref(),
        out.as_os_str(),
    ]);
    let text = String::from_utf8_lossy(&o.stdout).to_string();
    assert!(o.status.success(), "{text}{}", String::from_utf8_lossy(&o.stderr));
    assert!(text.contains("warning: left_wrist_pitch: kd 10"), "{text}");
    let spec = control::spec::DeploySpec::load(&out.join("policy.toml")).unwrap();
    assert_eq!(spec.observation_dim(), 480);
    assert_eq!(spec.num_joints(), 29);
    let p = &spec.policy;
    // IsaacLab index 2 is the waist yaw (SDK slot 12, kp 200 kd 5); index 9 the left knee (slot 3).
    assert_eq!((p.joint_ids_map[2], p.kp[2], p.kd[2]), (12, 200.0, 5.0));
    assert_eq!((p.joint_ids_map[9], p.kp[9], p.kd[9]), (3, 150.0, 4.0));
    assert_eq!((p.joint_ids_map[28], p.kp[28], p.kd[28]), (28, 40.0, 10.0));
    assert_eq!(p.default_pose[21], 0.97);
    let t = &spec.observation.terms;
    assert_eq!(t[0].clip_before_scale, Some([-100.0, 100.0]));
    assert_eq!(t[4].clip_before_scale, Some([-50.0, 50.0]));
    assert!(t.iter().all(|t| t.history == 5));
    assert_eq!(spec.commands.max, Some([1.0, 0.3, 0.2]));
    control::controller::Controller::new(spec).expect("loads");
}

/// Issue 30: an import never overwrites its own input (`--force` or not), and an imported spec
/// that does not load is an input error that leaves nothing in --out.
#[test]
fn an_import_never_overwrites_its_input_and_leaves_nothing_when_the_spec_does_not_load() {
    if shared_dir().is_none() {
        return skip_or_fail("import refusals (the peer walker as an rl_lab export)");
    }
    let dir = scratch_dir("onnx-refusals");
    let Some(_) = models(&dir) else { return };
    // The input is named like the output it would become.
    let same = dir.join("same");
    std::fs::create_dir_all(&same).unwrap();
    let input = same.join("policy.safetensors");
    std::fs::copy(dir.join("peer.onnx"), &input).unwrap();
    let before = std::fs::read(&input).unwrap();
    let o = g1_import(&[
        "network".as_ref(),
        input.as_os_str(),
        "--out".as_ref(),
        same.as_os_str(),
        "--force".as_ref(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("never overwrites what it reads"),
        "{err}"
    );
    assert_eq!(std::fs::read(&input).unwrap(), before, "the input was changed");

    let out = dir.join("bad-model");
    let o = g1_import(&[
        "rl-lab".as_ref(),
        "--deploy".as_ref(),
        dir.join("deploy.yaml").as_os_str(),
        "--onnx".as_ref(),
        dir.join("peer.onnx").as_os_str(),
        "--out".as_ref(),
        out.as_os_str(),
        "--estimator-model".as_ref(),
        "/nonexistent/g1.xml".as_ref(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(
        err.contains("nothing was written") && !err.contains("please report"),
        "{err}"
    );
    let left: Vec<_> = std::fs::read_dir(&out).unwrap().collect();
    assert!(left.is_empty(), "left in --out: {left:?}");
}
