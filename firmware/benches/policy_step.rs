//! Peer-policy step latency: our `control::nn` executor versus ONNX Runtime on the same network.
//!
//! Plain bench binary (`harness = false`): `cargo bench -p firmware --bench policy_step`.
//! Times every step individually after warm-up and prints median/p99; then runs
//! `scripts/bench/ort_lstm.py` (which first checks its ONNX graph against the golden actions)
//! and prints ORT's figures and the ratio ours/ORT. Target: ratio <= 0.5.
// Benchmark inputs come from std's math on the host; this never runs on the robot.
#![allow(clippy::disallowed_methods)]

mod common;

use common::{loud, percentile, workspace_root};
use control::nn::{Network, NetworkDesc};
use std::ffi::OsStr;
use std::hint::black_box;
use std::path::{Path, PathBuf};
use std::time::Instant;

const WARMUP: usize = 20_000;
const ITERS: usize = 200_000;

/// Observation rows to cycle through: golden_random `obs` if available, else a fixed pattern.
fn observations(policy_dir: &Path) -> Vec<[f32; 47]> {
    let from_file = || -> Option<Vec<[f32; 47]>> {
        let bytes = std::fs::read(policy_dir.join("golden_random.safetensors")).ok()?;
        let st = safetensors::SafeTensors::deserialize(&bytes).ok()?;
        let data: Vec<f32> = st
            .tensor("obs")
            .ok()?
            .data()
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect();
        Some(data.chunks_exact(47).map(|r| r.try_into().expect("47 wide")).collect())
    };
    from_file().unwrap_or_else(|| {
        (0..200)
            .map(|t| std::array::from_fn(|k| ((t * 47 + k) as f32 * 0.37).sin()))
            .collect()
    })
}

struct Figures {
    median_us: f64,
    p99_us: f64,
    mean_us: f64,
    min_us: f64,
}

fn time_ours(net: &mut Network, obs: &[[f32; 47]]) -> Figures {
    let mut out = [0.0f32; 12];
    for i in 0..WARMUP {
        net.step(black_box(&obs[i % obs.len()]), &mut out).unwrap();
        black_box(&out);
    }
    let mut times = Vec::with_capacity(ITERS);
    for i in 0..ITERS {
        let x = &obs[i % obs.len()];
        let t0 = Instant::now();
        net.step(black_box(x), &mut out).unwrap();
        black_box(&out);
        times.push(t0.elapsed().as_secs_f64() * 1e6);
    }
    // Mean without per-step timer overhead.
    let t0 = Instant::now();
    for i in 0..ITERS {
        net.step(black_box(&obs[i % obs.len()]), &mut out).unwrap();
        black_box(&out);
    }
    let mean_us = t0.elapsed().as_secs_f64() * 1e6 / ITERS as f64;
    times.sort_by(f64::total_cmp);
    Figures {
        median_us: percentile(&times, 0.5),
        p99_us: percentile(&times, 0.99),
        mean_us,
        min_us: times[0],
    }
}

fn timer_overhead_us() -> f64 {
    let mut v: Vec<f64> = (0..10_000)
        .map(|_| {
            let t0 = Instant::now();
            black_box(());
            t0.elapsed().as_secs_f64() * 1e6
        })
        .collect();
    v.sort_by(f64::total_cmp);
    percentile(&v, 0.5)
}

/// Runs the ORT baseline script; `None` (after saying why, loudly) if it cannot.
fn time_ort(policy_dir: &Path) -> Option<serde_json::Value> {
    let python = common::venv_python()?;
    common::run_ort_script(&python, "ort_lstm.py", [OsStr::new("--dir"), policy_dir.as_os_str()])
}

fn main() {
    let shared = std::env::var_os("G1_SHARED_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| workspace_root().join("../shared"));
    let policy_dir = shared.join("peer_policy/unitree_g1_lstm");
    let spec = workspace_root().join("specs/peer/unitree_g1_lstm.toml");
    let desc: NetworkDesc = control::spec::DeploySpec::load(&spec)
        .expect("peer spec loads")
        .policy
        .network;
    let Ok(mut net) = Network::load(&desc, &policy_dir.join("policy.safetensors")) else {
        loud(&format!(
            "SKIP: policy_step needs ../shared: {} not loadable. Set G1_SHARED_DIR.",
            policy_dir.join("policy.safetensors").display()
        ));
        return;
    };
    let obs = observations(&policy_dir);

    println!(
        "peer policy LSTM(47->64)->Linear(64->32)->ELU->Linear(32->12), {} params, sha256 {}",
        net.param_count(),
        &net.weights_sha256()[..16]
    );
    println!("timer overhead (Instant pair, median): {:.3} us", timer_overhead_us());
    let ours = time_ours(&mut net, &obs);
    println!(
        "ours: median {:.3} us  p99 {:.3} us  min {:.3} us  mean(untimed loop) {:.3} us  [{ITERS} steps after {WARMUP} warm-up]",
        ours.median_us, ours.p99_us, ours.min_us, ours.mean_us
    );

    let Some(ort) = time_ort(&policy_dir) else {
        println!("ORT: unavailable (see above); only our figures reported");
        return;
    };
    let get = |k: &str| ort[k].as_f64().unwrap_or(f64::NAN);
    let (ort_med, ort_p99) = (get("median_us"), get("p99_us"));
    println!(
        "ORT {} (1 thread, InferenceSession.run from Python): median {:.3} us  p99 {:.3} us  min {:.3} us  [{} steps; golden max err {:.2e}]",
        ort["ort_version"].as_str().unwrap_or("?"),
        ort_med,
        ort_p99,
        get("min_us"),
        get("iters"),
        get("golden_max_abs_err"),
    );
    let ratio = ours.median_us / ort_med;
    println!(
        "ratio ours/ORT: median {:.3}  p99 {:.3}  (target <= 0.5: {})",
        ratio,
        ours.p99_us / ort_p99,
        if ratio <= 0.5 { "MET" } else { "NOT MET" }
    );
}
