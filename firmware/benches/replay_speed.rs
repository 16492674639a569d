//! Replay speed and tick compute, printed as figures (a bench binary, not criterion: a replay is
//! one long measurement, not a micro-benchmark).
//!
//! 1. Replay of each corpus log, end to end (read, decompress, re-execute, compare), median of 5,
//!    in sim-seconds per wall-second; and the re-execution alone.
//! 2. The real alternative in the same run: re-simulating the same 3 s walk with `g1fw sim`
//!    (MuJoCo over the bridge, no log) — the ratio says how much faster a regression check is.
//! 3. Fast-group and whole-tick compute p50/p99/p99.9/max over a 20 s walk under the simulator.
//!
//! Needs the release binaries (`cargo build --release --workspace --bins`) and ../shared.
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use runlog::replay::{replay, ReplayOptions};

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap().to_path_buf()
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let root = root();
    let g1fw = root.join("target/release/g1fw");
    if !root.join("../shared").is_dir() || !g1fw.is_file() {
        eprintln!("replay_speed needs ../shared and `cargo build --release --workspace --bins`; skipping");
        return;
    }
    println!("== replay, end to end (median of 5) ==");
    let mut e2e_walk = 0.0;
    for name in ["peer_walk_12dof", "peer_crc_fault_12dof", "rl_lab_estop_29dof"] {
        let log = root.join(format!("tests/corpus/{name}.mcap"));
        let (mut e2e, mut run) = (Vec::new(), Vec::new());
        let mut last = None;
        for _ in 0..5 {
            let r = replay(&log, &ReplayOptions::default()).expect("replays");
            assert!(r.divergence.is_none());
            e2e.push(r.sim_seconds_per_wall_second);
            run.push(r.run_sim_seconds_per_wall_second);
            last = Some(r);
        }
        let r = last.unwrap();
        let m = median(e2e);
        if name == "peer_walk_12dof" {
            e2e_walk = m;
        }
        println!(
            "{name:24} {:5} ticks  end-to-end {:7.0}x  re-execution alone {:7.0}x  load {:5.1} ms  \
             tick p50 {:.2} µs p99 {:.2} µs",
            r.ticks,
            m,
            median(run),
            r.load_seconds * 1e3,
            r.tick_compute_us.p50_us,
            r.tick_compute_us.p99_us
        );
    }

    println!("\n== the alternative: re-simulate the same 3 s walk (median of 3) ==");
    let steps = std::env::temp_dir().join("g1fw-bench-steps.txt");
    std::fs::write(&steps, "0 0.3 0 0\n1.5 0.5 0 0.3\n").unwrap();
    let mut sim = Vec::new();
    for _ in 0..3 {
        let t = Instant::now();
        let out = Command::new(&g1fw)
            .args([
                "sim",
                "--quiet",
                "--model",
                "g1-12dof",
                "--duration",
                "3",
                "--cmd-schedule",
            ])
            .arg(&steps)
            .current_dir(&root)
            .output()
            .expect("g1fw sim runs");
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        sim.push(3.0 / t.elapsed().as_secs_f64());
    }
    let sim = median(sim);
    println!("g1fw sim (process incl. start-up)  {sim:7.1}x real time");
    println!("replay / re-simulation ratio       {:7.1}", e2e_walk / sim);

    println!("\n== tick compute under the simulator, 20 s walk ==");
    let out = Command::new(&g1fw)
        .args([
            "sim",
            "--quiet",
            "--model",
            "g1-12dof",
            "--duration",
            "20",
            "--cmd-schedule",
        ])
        .arg(root.join("specs/schedules/velocity_steps.txt"))
        .current_dir(&root)
        .output()
        .expect("g1fw sim runs");
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).expect("report");
    for k in ["fast_group_us", "tick_compute_us"] {
        let s = &v[k];
        println!(
            "{k:16} ticks {}  p50 {:.2}  p99 {:.2}  p99.9 {:.2}  max {:.2} µs",
            s["ticks"],
            s["p50_us"].as_f64().unwrap(),
            s["p99_us"].as_f64().unwrap(),
            s["p999_us"].as_f64().unwrap(),
            s["max_us"].as_f64().unwrap()
        );
    }
    println!("overruns {}", v["safety"]["overruns"]);
    println!("velocity tracking RMSE (vx, vy, wz) {}", v["tracking"]["rmse"]);
}
