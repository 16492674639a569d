//! An operated run in the simulator, as an operator drives the robot: passive at start, then the
//! schedule's requests (what the remote's buttons will send) stand it up, walk it 3 m, stand it and
//! sit it down to passive. Every change of state is in the log, and the run replays bit for bit.
use integration_tests::*;
use runlog::log::LogFile;

#[test]
fn the_operator_stands_walks_stands_and_sits_the_robot_and_replay_agrees() {
    let dir = scratch_dir("operated");
    let (schedule, log, report) = (dir.join("ops.txt"), dir.join("run.mcap"), dir.join("report.json"));
    std::fs::write(
        &schedule,
        "0.0 stand_up\n0.7 walk\n0.72 0.5 0 0\n6.0 0 0 0\n7.0 stand\n7.7 sit_down\n",
    )
    .unwrap();
    let out = g1fw(&[
        "sim",
        "--spec",
        "specs/peer/unitree_g1_lstm.toml",
        "--operated",
        "--cmd-schedule",
        schedule.to_str().unwrap(),
        "--duration",
        "8.25",
        "--quiet",
        "--log",
        log.to_str().unwrap(),
        "--report",
        report.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let r = read_json(&report);
    assert_eq!(r["final_mode"], "Passive", "{r}");
    assert_eq!(r["fell"], false, "{r}");
    assert!(r["distance_x_m"].as_f64().unwrap() > 2.5, "{r}");
    assert!(r["policy_steps"].as_u64().unwrap() > 250, "{r}");
    // The report names each change, its source and time.
    let changes = transitions(&r);
    let want = [
        ("startup", "schedule", 0.0),
        ("stand", "ramp", 0.6),
        ("policy", "schedule", 0.7),
        ("startup", "schedule", 7.0),
        ("stand", "ramp", 7.6),
        ("sit_down", "schedule", 7.7),
        ("passive", "ramp", 8.2),
    ];
    assert_eq!(changes.len(), want.len(), "{changes:?}");
    for ((to, source, t), (wto, wsource, wt)) in changes.iter().zip(want) {
        assert_eq!((to.as_str(), source.as_str()), (wto, wsource), "{changes:?}");
        assert!((t - wt).abs() < 0.01, "{changes:?}");
    }
    // The log's mode at each change, in order.
    let mut modes: Vec<String> = Vec::new();
    LogFile::open(&log).unwrap().scan(|channel, _, data| {
        if channel == "/safety/state" {
            let v: serde_json::Value = serde_json::from_slice(data).unwrap();
            let m = v["mode"].as_str().unwrap().to_string();
            if modes.last() != Some(&m) {
                modes.push(m);
            }
        }
    });
    assert_eq!(
        modes,
        ["startup", "stand", "policy", "startup", "stand", "sit_down", "passive"],
        "the log's modes"
    );
    let replay = g1fw(&["replay", log.to_str().unwrap()]);
    assert!(replay.status.success(), "{}", String::from_utf8_lossy(&replay.stderr));
}
