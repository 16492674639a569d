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
    let mut exec = firmware::nn::Network::from_safetensors_bytes(&net.desc, &bytes).expect("loads");
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
    let spec = firmware::spec::DeploySpec::load(&repo_root().join("specs/peer/unitree_g1_lstm.toml")).unwrap();
    let mut original = firmware::nn::Network::load(&spec.policy.network, &spec.weights_path()).unwrap();
    let net = policy_import::import_file(&dir.join("peer.onnx")).unwrap();
    let mut imported =
        firmware::nn::Network::from_safetensors_bytes(&net.desc, &net.safetensors_bytes().unwrap()).unwrap();
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
}
