//! The hour-long soak (issue 73): `cargo bench --workspace --bench soak`. `G1_SOAK_S` sets the
//! duration (default 3600 s), `G1_SOAK_DIR` keeps the log and report there. Prints the figures as
//! JSON and as the table `docs/reliability.md` keeps; fails as the test does.
#![allow(clippy::disallowed_methods)]

use integration_tests::soak::{check, soak, soak_dir, SoakPlan};

fn main() {
    // `cargo bench` passes `--bench`; nothing else is taken.
    let duration_s: f64 = std::env::var("G1_SOAK_S")
        .ok()
        .map(|s| s.parse().expect("G1_SOAK_S: seconds"))
        .unwrap_or(3600.0);
    let dir = soak_dir("soak-bench");
    std::fs::create_dir_all(&dir).expect("soak dir");
    eprintln!("soak: {duration_s} s, files in {}", dir.display());
    let plan = SoakPlan {
        duration_s,
        fault_every_s: 120.0,
        rss_every_s: 5.0,
        windows: 6,
        // About 1.2 GB an hour: a dozen files.
        split_mb: 100.0,
    };
    let Some(f) = soak(&dir, plan) else { return };
    let json = serde_json::to_string_pretty(&f).unwrap();
    std::fs::write(dir.join("soak.json"), &json).expect("soak.json");
    println!("{json}");
    println!("\n| window | ticks | compute p50 µs | p99 µs | max µs | overruns |\n|---|---:|---:|---:|---:|---:|");
    for w in &f.timing {
        println!(
            "| {:.0}–{:.0} s | {} | {:.1} | {:.1} | {:.0} | {} |",
            w.from_s, w.to_s, w.ticks, w.compute_p50_us, w.compute_p99_us, w.compute_max_us, w.overruns
        );
    }
    let first = f
        .rss_mib
        .iter()
        .find(|p| p.0 >= duration_s / 10.0)
        .map_or(f64::NAN, |p| p.1);
    println!(
        "\nfaults {}, trips {}, resets back to the policy {}; g1fw resident {:.1} MiB after the first tenth, growth {:.2} MiB, slope {:.2} MiB/h; log {:.0} MB in {} files, {} replayed bit-exact ({:.0} s); clock lateness {}",
        f.faults.len(),
        f.trips.len(),
        f.back_to_policy,
        first,
        f.rss_growth_mib,
        f.rss_slope_mib_per_h,
        f.log_bytes as f64 / 1e6,
        f.log_files,
        f.files_replayed_identical,
        f.replay_s,
        f.period_jitter
    );
    check(&f);
}
