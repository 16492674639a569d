//! The perception path end to end: `g1fw sim --world` → simulated MID-360 (Livox packets over the
//! bridge) → decoder → motion-compensated BEV → terrain token, logged for Foxglove, and rendered.
//! Uses the 29-dof model and the committed rl_lab-style spec (holding its pose), so it needs nothing
//! from ../shared.
use std::process::Command;

use firmware::bev_render::grid_from_foxglove;
use integration_tests::*;
use runlog::log::channels as ch;
use runlog::log::LogFile;
use sensor_io::bev::{BevGrid, BEV_CELLS, CH_MAX, CH_MEAN};

fn run(world: &str, log: Option<&std::path::Path>, report: &std::path::Path) -> serde_json::Value {
    let mut args = vec![
        "sim",
        "--model",
        "g1-29dof",
        "--spec",
        "specs/test/rl_lab_style.toml",
        "--hold",
        "--ramp",
        "2",
        "--duration",
        "2.0",
        "--quiet",
        "--keep-going",
        "--world",
        world,
        "--report",
        report.to_str().unwrap(),
    ];
    if let Some(l) = log {
        args.extend(["--log", l.to_str().unwrap()]);
    }
    let out = g1fw(&args);
    assert!(
        ran(&out),
        "g1fw sim --world {world} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_str(&std::fs::read_to_string(report).unwrap()).unwrap()
}

#[test]
fn stairs_world_is_seen_logged_and_rendered() {
    let dir = scratch_dir("perception");
    let (log, report) = (dir.join("stairs.mcap"), dir.join("r.json"));
    let r = run("stairs-up", Some(&log), &report);
    let t = &r["terrain"];
    println!("terrain report: {t}");
    let frames = t["frames"].as_u64().unwrap();
    assert!((18..=20).contains(&frames), "10 Hz frames in 2 s: {frames}");
    let pts = t["mean_points"].as_f64().unwrap();
    // 20k fired per frame less dropouts and rays into the sky, which depend on how the torso
    // pitches: at least 14k with the explicit motor law (the old bound), 13,966 with the implicit
    // PD actuators.
    assert!((13_000.0..=20_000.0).contains(&pts), "points per frame {pts}");
    assert_eq!(t["lidar_malformed_packets"], 0);
    assert_eq!(t["lidar_lost_packets"], 0);
    assert_eq!(
        t["truth_classes"][1].as_u64(),
        Some(frames),
        "the robot faces the stairs"
    );
    // (Holding the ramped pose without a policy, the robot sinks after ~1.3 s; the checks on
    // the grid use a frame from before that.)

    // Every perception frame is in the log on all four channels.
    let file = LogFile::open(&log).unwrap();
    let mut counts = std::collections::BTreeMap::new();
    let mut last_grid = None;
    file.scan(|topic, t, data| {
        *counts.entry(topic.to_string()).or_insert(0u64) += 1;
        if topic == ch::PERCEPTION_BEV && t == 400_000_000 {
            let v: serde_json::Value = serde_json::from_slice(data).unwrap();
            use base64::Engine as _;
            let bytes = base64::engine::general_purpose::STANDARD
                .decode(v["data"].as_str().unwrap())
                .unwrap();
            last_grid = Some(grid_from_foxglove(&bytes).unwrap());
        }
    });
    for topic in [
        ch::LIDAR_POINTS,
        ch::PERCEPTION_BEV,
        ch::PERCEPTION_TERRAIN,
        ch::TRUTH_TERRAIN,
    ] {
        assert_eq!(counts.get(topic).copied(), Some(frames), "{topic}: {counts:?}");
    }
    // The grid's geometry at 0.4 s (the robot still upright, 5 cm ahead of its start): the floor
    // before the stairs at z ≈ 0, the first tread (risers at x = 1.2 m and 1.5 m) at 0.15 m.
    let g: Box<BevGrid> = last_grid.expect("a perception frame at t = 0.4 s");
    let (mut floor, mut tread) = (Vec::new(), Vec::new());
    for ix in 0..BEV_CELLS {
        for iy in 20..40 {
            let (x, _) = BevGrid::cell_center(ix, iy);
            if !g.occupied(ix, iy) {
                continue;
            }
            if (0.6..1.05).contains(&x) {
                floor.push(g.get(CH_MEAN, ix, iy));
            } else if (1.22..1.38).contains(&x) {
                tread.push(g.get(CH_MAX, ix, iy));
            }
        }
    }
    let median = |v: &mut Vec<f32>| {
        v.sort_by(f32::total_cmp);
        v[v.len() / 2]
    };
    assert!(
        floor.len() > 50 && tread.len() > 10,
        "{} floor, {} tread cells",
        floor.len(),
        tread.len()
    );
    let (f, s) = (median(&mut floor), median(&mut tread));
    println!("floor median {f:.3} m, first tread median {s:.3} m");
    assert!(f.abs() < 0.03, "floor at {f}");
    assert!((s - 0.15).abs() < 0.03, "first tread at {s}");

    // Foxglove's schemas, read by the independent Python reader.
    if let Some(py) = venv_python("perception log schemas") {
        let script = r#"
import sys, json, base64
from mcap.reader import make_reader
r = make_reader(open(sys.argv[1], "rb"))
s = r.get_summary()
names = {c.topic: s.schemas[c.schema_id].name for c in s.channels.values()}
n = None
for schema, channel, message in r.iter_messages(topics=["/lidar/points"]):
    m = json.loads(message.data)
    n = len(base64.b64decode(m["data"])) // m["point_stride"]
print(json.dumps({"names": names, "points": n}))
"#;
        let out = Command::new(py).arg("-c").arg(script).arg(&log).output().unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        assert_eq!(v["names"]["/lidar/points"], "foxglove.PointCloud");
        assert_eq!(v["names"]["/perception/bev"], "foxglove.Grid");
        assert!(v["points"].as_u64().unwrap() > 5_000, "{v}");
    }

    // The PNG render of a frame.
    let png = dir.join("bev.png");
    let out = g1fw(&["bev", log.to_str().unwrap(), "--at", "1.0", "-o", png.to_str().unwrap()]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let bytes = std::fs::read(&png).unwrap();
    assert_eq!(&bytes[1..4], b"PNG");
    // A log without perception says what to do.
    let plain = dir.join("plain.mcap");
    let out = g1fw(&[
        "sim",
        "--model",
        "g1-29dof",
        "--spec",
        "specs/test/rl_lab_style.toml",
        "--hold",
        "--ramp",
        "2",
        "--duration",
        "0.2",
        "--quiet",
        "--log",
        plain.to_str().unwrap(),
    ]);
    assert!(out.status.success());
    let out = g1fw(&["bev", plain.to_str().unwrap(), "-o", png.to_str().unwrap()]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--world"));
}

#[test]
fn perception_runs_are_deterministic() {
    let dir = scratch_dir("perception-det");
    let a = run("outdoor", None, &dir.join("a.json"));
    let b = run("outdoor", None, &dir.join("b.json"));
    assert_eq!(a["state_trace_sha256"], b["state_trace_sha256"]);
    assert_eq!(a["terrain"], b["terrain"]);
    assert!(a["terrain"]["frames"].as_u64().unwrap() > 10);
}

#[test]
fn a_bad_world_is_a_clear_error() {
    let out = g1fw(&[
        "sim",
        "--model",
        "g1-29dof",
        "--spec",
        "specs/test/rl_lab_style.toml",
        "--hold",
        "--duration",
        "0.1",
        "--quiet",
        "--world",
        "moon",
    ]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("stairs-up"), "lists the presets: {err}");
}
