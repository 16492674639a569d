//! `g1fw sim` (firmware ⇄ socket bridge ⇄ g1-sim) against a bare MuJoCo stepping loop of the same
//! model with the same motor PD law (`g1-sim --bench-bare`), interleaved in the same run.
//! Both hold the standing pose, so the physics work is the same; the policy case is reported beside.
//! Needs `cargo build --release --workspace --bins` (for g1-sim) and, for the policy rows, ../shared.
use std::path::{Path, PathBuf};
use std::process::Command;

fn bin(name: &str) -> PathBuf {
    let exe = std::env::current_exe().expect("current exe");
    let dir = exe.parent().and_then(Path::parent).expect("target dir");
    let p = dir.join(name);
    if !p.is_file() {
        eprintln!(
            "{} is missing: run `cargo build --release --workspace --bins` first",
            p.display()
        );
        std::process::exit(1);
    }
    p
}

fn json_field(out: &[u8], key: &str) -> f64 {
    let text = String::from_utf8_lossy(out);
    let v: serde_json::Value = serde_json::from_str(text.trim()).unwrap_or_else(|e| panic!("bad JSON ({e}): {text}"));
    v[key].as_f64().unwrap_or_else(|| panic!("no {key} in {text}"))
}

fn bare(model: &str, seconds: f64) -> f64 {
    let out = Command::new(bin("g1-sim"))
        .args(["--bench-bare", &seconds.to_string(), "--model", model])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    json_field(&out.stdout, "sim_seconds_per_wall_second")
}

fn firmware(model: &str, seconds: f64, policy: bool) -> f64 {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let mut cmd = Command::new(bin("g1fw"));
    cmd.current_dir(&root).args([
        "sim",
        "--quiet",
        "--keep-going",
        "--model",
        model,
        "--duration",
        &seconds.to_string(),
    ]);
    if !policy {
        cmd.args(["--hold", "--ramp", "2"]);
    }
    let out = cmd.output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    json_field(&out.stdout, "sim_seconds_per_wall_second")
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    // `cargo bench` passes --bench; nothing else to parse.
    let rounds = 3;
    let seconds = 30.0;
    let shared = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/peer_policy")
        .is_dir();
    println!("sim-seconds per wall-second, median of {rounds} interleaved rounds of {seconds} s each");
    println!(
        "{:<10} {:>10} {:>14} {:>8} {:>16}",
        "model", "bare loop", "g1fw sim hold", "ratio", "g1fw sim policy"
    );
    for model in ["g1-29dof", "g1-12dof"] {
        if model == "g1-12dof" && !shared {
            eprintln!("SKIP g1-12dof: ../shared is not beside the checkout");
            continue;
        }
        let (mut b, mut f, mut p) = (Vec::new(), Vec::new(), Vec::new());
        for _ in 0..rounds {
            b.push(bare(model, seconds));
            f.push(firmware(model, seconds, false));
            if shared {
                p.push(firmware(model, seconds, true));
            }
        }
        let (b, f) = (median(b), median(f));
        let p = if p.is_empty() {
            "n/a".to_string()
        } else {
            format!("{:.1}", median(p))
        };
        println!("{model:<10} {b:>10.1} {f:>14.1} {:>8.2} {p:>16}", f / b);
    }
}
