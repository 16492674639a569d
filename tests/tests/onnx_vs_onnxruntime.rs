//! `policy_import` against onnxruntime on random models: small MLPs built by
//! `tests/python/onnx_vs_onnxruntime.py` (onnx.helper, no project code) with random widths, depths, Gemm forms,
//! MatMul + Add, Elu/Relu/Tanh, normalisers, action scales, shape ops, bias shapes ONNX broadcasts,
//! and opsets; about a third with one fault injected (an opset outside 7..28, a float64 or int64
//! constant, a bias that broadcasts the value to a matrix, a Reshape that moves the features).
//! A well-formed model imports and its network, stepped in the firmware's executor, gives
//! onnxruntime's outputs; a faulty one is refused, naming what is wrong. Also the three
//! reproductions, with what onnxruntime does with each.
#![allow(clippy::disallowed_methods)]
use std::path::Path;

use integration_tests::{repo_root, scratch_dir, venv_python};

const MODELS: usize = 300;
const SEED: u64 = 20_261_207;
/// Float32 sums in another order (the importer folds normalisers and `alpha` into the weights).
const TOLERANCE: f64 = 2e-5;

/// The peer's JSON, or `None` (said loudly; a failure under CI) without the project's Python.
fn peer(dir: &Path) -> Option<serde_json::Value> {
    let py = venv_python("the importer-vs-onnxruntime property test (onnx, onnxruntime)")?;
    let script = repo_root().join("tests/python/onnx_vs_onnxruntime.py");
    let out = std::process::Command::new(py)
        .arg(&script)
        .arg(dir)
        .arg(MODELS.to_string())
        .arg(SEED.to_string())
        .output()
        .expect("the project's Python runs");
    assert!(
        out.status.success(),
        "{} failed (onnx and onnxruntime come from scripts/install.sh): {}",
        script.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    Some(serde_json::from_slice(&out.stdout).expect("the peer prints JSON"))
}

fn floats(v: &serde_json::Value) -> Vec<f64> {
    v.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect()
}

/// Imports `name`.onnx and steps it through onnxruntime's inputs; the largest difference from its
/// outputs.
fn max_error(dir: &Path, m: &serde_json::Value) -> Result<f64, String> {
    let name = m["name"].as_str().unwrap();
    let net = policy_import::import_file(&dir.join(format!("{name}.onnx"))).map_err(|e| e.to_string())?;
    let bytes = net.safetensors_bytes().unwrap();
    let mut exec = control::nn::Network::from_safetensors_bytes(&net.desc, &bytes)
        .unwrap_or_else(|e| panic!("{name}: the imported network does not load: {e}"));
    let mut out = vec![0f32; exec.output_dim()];
    let mut worst = 0f64;
    let (ins, outs) = (m["inputs"].as_array().unwrap(), m["outputs"].as_array().unwrap());
    assert!(!ins.is_empty(), "{name}: no steps");
    for (x, y) in ins.iter().zip(outs) {
        let x: Vec<f32> = floats(x).into_iter().map(|v| v as f32).collect();
        exec.step(&x, &mut out).unwrap();
        let y = floats(y);
        assert_eq!(
            y.len(),
            out.len(),
            "{name}: onnxruntime gives {} values, the imported network {}",
            y.len(),
            out.len()
        );
        for (a, b) in out.iter().zip(&y) {
            worst = worst.max((*a as f64 - b).abs());
        }
    }
    Ok(worst)
}

#[test]
fn imported_random_models_equal_onnxruntime_and_faulty_ones_are_refused() {
    let dir = scratch_dir("onnx-vs-ort");
    let Some(peer) = peer(&dir) else { return };
    let models = peer["models"].as_array().unwrap();
    assert_eq!(models.len(), MODELS);
    let (mut matched, mut steps, mut worst) = (0usize, 0usize, 0f64);
    let mut refused: std::collections::BTreeMap<&str, (usize, usize)> = Default::default();
    for m in models {
        let name = m["name"].as_str().unwrap();
        let ort_error = m["ort_error"].as_str();
        match m["fault"].as_str() {
            None => {
                assert!(
                    ort_error.is_none(),
                    "{name}: a well-formed model onnxruntime refuses: {ort_error:?}"
                );
                let e = max_error(&dir, m).unwrap_or_else(|e| panic!("{name}: a well-formed model is refused: {e}"));
                assert!(
                    e <= TOLERANCE,
                    "{name}: max |imported − onnxruntime| = {e:e} > {TOLERANCE:e}"
                );
                worst = worst.max(e);
                matched += 1;
                steps += m["inputs"].as_array().unwrap().len();
            }
            Some(fault) => {
                let e = match policy_import::import_file(&dir.join(format!("{name}.onnx"))) {
                    Ok(_) => match ort_error {
                        Some(o) => {
                            panic!("{name}: imported despite its fault ({fault}), which onnxruntime refuses: {o}")
                        }
                        None => panic!(
                            "{name}: imported despite its fault ({fault}); onnxruntime computes an output of shape {}",
                            m["out_shape"]
                        ),
                    },
                    Err(e) => e.to_string(),
                };
                let says: &[&str] = match fault {
                    "opset" => &["opset", "7 to 28"],
                    "float64" => &["float64", "float32", "re-export"],
                    "int64" => &["int64"],
                    "matrix_bias" | "batch_bias" => &["broadcast", "give it shape ["],
                    "reshape" => &["reshapes", "last axis"],
                    f => panic!("unknown fault {f}"),
                };
                assert!(says.iter().all(|s| e.contains(s)), "{name} ({fault}): {e}");
                let r = refused.entry(fault).or_default();
                r.0 += 1;
                r.1 += usize::from(ort_error.is_some());
            }
        }
    }
    eprintln!(
        "{matched} of {MODELS} random models (onnxruntime {}) imported and equal onnxruntime over {steps} inputs: \
         max |imported − onnxruntime| = {worst:.2e}",
        peer["onnxruntime"]
    );
    for (fault, (n, by_ort)) in &refused {
        eprintln!("  {fault}: {n} refused ({by_ort} refused by onnxruntime too, the rest computed as a non-vector)");
    }
    assert!(matched >= MODELS / 2, "only {matched} well-formed models");
    for fault in ["opset", "float64", "int64", "matrix_bias", "batch_bias", "reshape"] {
        assert!(
            refused.contains_key(fault),
            "no model with fault {fault}: the generator changed"
        );
    }
}

/// The three models of the report: opset 99 and a float64 weight in a float32 Gemm, which
/// onnxruntime refuses, and an Add bias of shape [5, 1], which onnxruntime broadcasts to a [5, 5]
/// output. Each is refused, saying why and what to do.
#[test]
fn the_reported_models_are_refused_as_onnxruntime_refuses_them() {
    let dir = scratch_dir("onnx-vs-ort-repro");
    let Some(peer) = peer(&dir) else { return };
    let r = &peer["repro"];
    let import = |name: &str| match policy_import::import_file(&dir.join(format!("{name}.onnx"))) {
        Ok(_) => panic!("{name} imported"),
        Err(e) => e.to_string(),
    };

    let ort = r["opset99"]["ort_error"]
        .as_str()
        .expect("onnxruntime refuses opset 99");
    assert!(ort.contains("Opset 99"), "{ort}");
    let e = import("opset99");
    assert!(
        e.contains("opset99.onnx") && e.contains("opset 99") && e.contains("7 to 28") && e.contains("opset_version"),
        "{e}"
    );

    let ort = r["float64_gemm"]["ort_error"]
        .as_str()
        .expect("onnxruntime refuses the float64 weight");
    assert!(ort.contains("tensor(double)"), "{ort}");
    let e = import("float64_gemm");
    assert!(
        e.contains("actor.0") && e.contains("'w0'") && e.contains("float64") && e.contains("policy.float()"),
        "{e}"
    );

    assert!(r["bias_h1"]["ort_error"].is_null(), "{}", r["bias_h1"]["ort_error"]);
    assert_eq!(
        r["bias_h1"]["out_shape"],
        serde_json::json!([5, 5]),
        "onnxruntime's output"
    );
    let e = import("bias_h1");
    assert!(
        e.contains("actor.2/Add") && e.contains("'b1'") && e.contains("[5, 1]") && e.contains("[5, 5]"),
        "{e}"
    );
}
