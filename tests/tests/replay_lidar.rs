//! Replay with perception: a run with a world logs the raw lidar frames the perception group
//! consumed (`/lidar/frame`), and `g1fw replay` feeds them back on the same ticks, so the terrain
//! token, and a policy that observes it, replay bit for bit. A log without the channel still
//! replays when the policy does not observe the token, and is refused, naming the channel, when it
//! does. Also: the tick path with lidar frames and their logging allocates nothing.
//!
//! Uses the 29-dof model installed by scripts/install.sh and the committed rl_lab-style spec (and a
//! variant of it that observes the terrain token), so it needs nothing from ../shared.
// Integration tests never run on the robot: std's math is fine here (see clippy.toml).
#![allow(clippy::disallowed_methods)]
use control::alloc_probe::{counts, CountingAlloc};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use integration_tests::*;
use runlog::log::channels as ch;
use runlog::log::LogFile;

/// The rl_lab-style spec with the terrain token in its observation: the velocity command keeps one
/// frame instead of five, and three frames of the token (12 values) take the other 12, so the
/// observation stays 480 wide and the committed test MLP still fits. Written into `dir` with
/// absolute paths to the weights and the model.
fn terrain_spec(dir: &Path) -> PathBuf {
    let root = repo_root();
    let text = std::fs::read_to_string(root.join("specs/test/rl_lab_style.toml")).unwrap();
    let swaps = [
        (
            r#"name = "rl_lab_style_test""#,
            r#"name = "rl_lab_style_terrain_test""#.to_string(),
        ),
        (
            r#"weights = "mlp_480_29.safetensors""#,
            format!("weights = {:?}", root.join("specs/test/mlp_480_29.safetensors")),
        ),
        (
            r#"{ kind = "velocity_command", history = 5, clip = 100.0 },"#,
            r#"{ kind = "velocity_command", history = 1, clip = 100.0 },
  { kind = "terrain_token", history = 3 },"#
                .to_string(),
        ),
        (
            r#"model = "../../.deps/g1_29dof/g1.xml""#,
            format!("model = {:?}", root.join(".deps/g1_29dof/g1.xml")),
        ),
    ];
    let mut text = text;
    for (from, to) in swaps {
        assert!(text.contains(from), "the rl_lab-style spec changed: no {from}");
        text = text.replace(from, &to);
    }
    let p = dir.join("terrain_token.toml");
    std::fs::write(&p, text).unwrap();
    p
}

/// Where the terrain token's three frames sit in that spec's observation (term-major: angular
/// velocity 15, gravity 15, command 3, then the token).
const TOKEN_OBS: std::ops::Range<usize> = 33..45;

/// `g1fw sim --world WORLD` for 2 s with a log; `extra` adds flags (`--hold`).
fn sim_with_world(spec: &Path, world: &str, log: &Path, extra: &[&str]) {
    let mut args = vec![
        "sim",
        "--model",
        "g1-29dof",
        "--spec",
        spec.to_str().unwrap(),
        "--duration",
        "2.0",
        "--quiet",
        "--keep-going",
        "--world",
        world,
        "--log",
        log.to_str().unwrap(),
    ];
    args.extend(extra);
    let out = g1fw(&args);
    assert!(
        ran(&out),
        "g1fw sim --world {world} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// `g1fw replay LOG --report`: exit code, stderr and the report (when written).
fn replay_cli(log: &Path) -> (Option<i32>, String, Option<serde_json::Value>) {
    let report = log.with_extension("replay.json");
    let _ = std::fs::remove_file(&report);
    let out = g1fw(&["replay", log.to_str().unwrap(), "--report", report.to_str().unwrap()]);
    let r = std::fs::read(&report).ok().map(|b| serde_json::from_slice(&b).unwrap());
    (out.status.code(), String::from_utf8_lossy(&out.stderr).into_owned(), r)
}

fn topic_counts(log: &Path) -> BTreeMap<String, u64> {
    let mut counts = BTreeMap::new();
    LogFile::open(log).unwrap().scan(|topic, _, _| {
        *counts.entry(topic.to_string()).or_insert(0u64) += 1;
    });
    counts
}

/// Copies `src` to `dst` without `topic`'s messages (the run metadata first, as g1fw writes it):
/// what a log from before the channel existed looks like.
fn strip_topic(src: &Path, dst: &Path, topic: &str) {
    let file = LogFile::open(src).unwrap();
    let meta = file.run_metadata().unwrap();
    let out = std::io::BufWriter::new(std::fs::File::create(dst).unwrap());
    let mut w = mcap::WriteOptions::new()
        .compression(Some(mcap::Compression::Lz4))
        .profile("")
        .create(out)
        .unwrap();
    w.write_metadata(&mcap::records::Metadata {
        name: ch::RUN_METADATA.into(),
        metadata: meta,
    })
    .unwrap();
    let mut kept = 0u64;
    for m in mcap::MessageStream::new(&file.bytes).unwrap() {
        let m = m.unwrap();
        if m.channel.topic == topic {
            continue;
        }
        w.write(&m).unwrap();
        kept += 1;
    }
    w.finish().unwrap();
    assert!(kept > 0);
}

#[test]
fn a_terrain_policy_replays_bit_exact_from_its_lidar_frames_and_without_them_is_refused() {
    let dir = scratch_dir("replay-lidar");
    let spec = terrain_spec(&dir);
    let log = dir.join("terrain.mcap");
    sim_with_world(&spec, "stairs-up", &log, &[]);

    // One raw frame per perception step that had one, beside its terrain estimate.
    let counts = topic_counts(&log);
    let frames = counts.get(ch::LIDAR_FRAME).copied().unwrap_or(0);
    assert!((18..=20).contains(&frames), "10 Hz frames in 2 s: {counts:?}");
    assert_eq!(counts.get(ch::PERCEPTION_TERRAIN).copied(), Some(frames), "{counts:?}");

    // The token really is in the policy's input, and not just flat zeros.
    let mut token_values = Vec::new();
    LogFile::open(&log).unwrap().scan(|topic, _, data| {
        if topic == ch::OBSERVATION {
            let v: serde_json::Value = serde_json::from_slice(data).unwrap();
            let values = v["values"].as_array().unwrap();
            assert_eq!(values.len(), 480);
            token_values.extend(values[TOKEN_OBS].iter().map(|x| x.as_f64().unwrap_or(f64::NAN)));
        }
    });
    assert!(token_values.len() > 20 * 12, "{} token values", token_values.len());
    assert!(
        token_values.iter().any(|&x| x != 0.0),
        "the terrain token never left flat: the test would not show that frames matter"
    );

    // Replay: every frame fed back, every perception step and command bit-exact.
    let (code, stderr, r) = replay_cli(&log);
    assert_eq!(code, Some(0), "replay: {stderr}");
    let r = r.expect("report");
    println!("replay report: {r}");
    assert!(r["divergence"].is_null(), "{r}");
    assert_eq!(r["ticks"], 1001);
    assert_eq!(r["perception_frames_fed"].as_u64(), Some(frames), "{r}");
    assert_eq!(r["compared_perception_steps"].as_u64(), Some(frames), "{r}");
    assert!(r["compared_policy_steps"].as_u64().unwrap() > 20, "{r}");
    assert_eq!(r["notes"].as_array().map(Vec::len), Some(0), "{r}");

    // The same log without /lidar/frame cannot reproduce the token: refused, naming the channel.
    let stripped = dir.join("stripped.mcap");
    strip_topic(&log, &stripped, ch::LIDAR_FRAME);
    assert_eq!(topic_counts(&stripped).get(ch::LIDAR_FRAME), None);
    let (code, stderr, _) = replay_cli(&stripped);
    assert_eq!(code, Some(2), "could-not-replay exit: {stderr}");
    assert!(
        stderr.contains("cannot reproduce perception")
            && stderr.contains("'/lidar/frame'")
            && stderr.contains("terrain_token"),
        "{stderr}"
    );
}

#[test]
fn a_world_log_without_lidar_frames_still_replays_when_the_policy_ignores_the_token() {
    let dir = scratch_dir("replay-lidar-old");
    let log = dir.join("hold.mcap");
    let spec = repo_root().join("specs/test/rl_lab_style.toml");
    sim_with_world(&spec, "outdoor", &log, &["--hold", "--ramp", "2"]);
    let frames = topic_counts(&log).get(ch::LIDAR_FRAME).copied().unwrap_or(0);
    assert!(frames >= 18, "{frames} frames");

    // With the frames: perception is re-run and compared.
    let (code, stderr, r) = replay_cli(&log);
    assert_eq!(code, Some(0), "replay: {stderr}");
    let r = r.unwrap();
    assert_eq!(r["perception_frames_fed"].as_u64(), Some(frames), "{r}");
    assert_eq!(r["compared_perception_steps"].as_u64(), Some(frames), "{r}");

    // As a log from before /lidar/frame: commands still replay, with a note saying perception
    // was not reproduced.
    let old = dir.join("old.mcap");
    strip_topic(&log, &old, ch::LIDAR_FRAME);
    let (code, stderr, r) = replay_cli(&old);
    assert_eq!(code, Some(0), "replay of the old-style log: {stderr}");
    let r = r.unwrap();
    assert!(r["divergence"].is_null(), "{r}");
    assert_eq!(r["perception_frames_fed"], 0);
    assert_eq!(r["compared_perception_steps"], 0);
    assert_eq!(r["compared_commands"], r["ticks"]);
    let notes = r["notes"].to_string();
    assert!(
        notes.contains("/lidar/frame") && notes.contains("not compared"),
        "{notes}"
    );
}

// ---- The tick path with lidar frames and their logging does not allocate. ----

#[global_allocator]
static GLOBAL: CountingAlloc = CountingAlloc;

/// Standing still on flat ground, with a lidar frame of a floor and a step every 50 ticks.
struct LidarHal {
    k: u64,
    started: bool,
    frame: [u8; sensor_io::unitree_hg::LOW_STATE_LEN],
    state: hal::LowState,
    fresh: bool,
    /// Frames of a staircase ahead whose step height changes from frame to frame (else the floor
    /// grid of [`synthetic_point`]).
    stairs: bool,
}

impl LidarHal {
    fn new(stairs: bool) -> Self {
        Self {
            k: 0,
            started: false,
            frame: [0; sensor_io::unitree_hg::LOW_STATE_LEN],
            state: hal::LowState::default(),
            fresh: false,
            stairs,
        }
    }
}

impl hal::TimeBase for LidarHal {
    type Error = sensor_io::unitree_hg::DecodeError;
    fn wait_tick(&mut self) -> Result<hal::TickTime, Self::Error> {
        if self.started {
            self.k += 1;
        }
        self.started = true;
        let mut s = hal::LowState {
            tick: self.k as u32,
            ..Default::default()
        };
        s.imu.quaternion = [1.0, 0.0, 0.0, 0.0];
        s.imu.accelerometer = [0.0, 0.0, 9.81];
        for (i, m) in s.motors.iter_mut().enumerate() {
            m.q = (self.k as f32 * 0.01 + i as f32).sin() * 0.05;
            m.temperature = [40, 45];
        }
        sensor_io::unitree_hg::encode_low_state(&s, &mut self.frame);
        self.fresh = true;
        Ok(hal::TickTime {
            index: self.k,
            time_ns: self.k * 2_000_000,
        })
    }
    fn period_ns(&self) -> u64 {
        2_000_000
    }
}

impl hal::LowLevel for LidarHal {
    type Error = sensor_io::unitree_hg::DecodeError;
    fn read_state(&mut self, out: &mut hal::LowState) -> Result<bool, Self::Error> {
        let fresh = std::mem::take(&mut self.fresh);
        if fresh {
            sensor_io::unitree_hg::decode_low_state(&self.frame, &mut self.state)?;
        }
        *out = self.state;
        Ok(fresh)
    }
    fn write_command(&mut self, _cmd: &hal::LowCommand) -> Result<(), Self::Error> {
        Ok(())
    }
}

impl control::runtime::FrameSource for LidarHal {
    fn received_frame(&self) -> Option<&[u8]> {
        Some(&self.frame)
    }
    fn read_lidar(&mut self, out: &mut control::perception::LidarFrame) -> bool {
        // A grid of returns ahead of the sensor, varying per frame (the sensor frame of the
        // upside-down mount does not matter for allocation).
        out.clear(self.k * 2_000_000);
        if self.stairs {
            for i in 0..STAIR_POINTS {
                out.push(stair_point(i, self.k));
            }
            return true;
        }
        for i in 0..synthetic_points(self.k) {
            out.push(synthetic_point(i));
        }
        true
    }
}

const STAIR_POINTS: usize = 100 * 80;

/// Stairs up in the robot frame (risers 1.0, 1.3, 1.6 m ahead, 10-18 cm depending on the tick,
/// 2 m wide), put into the sensor frame of the default upside-down mount for a base 0.75 m up.
fn stair_point(i: usize, tick: u64) -> hal::LidarPoint {
    let h = 0.10 + 0.02 * ((tick / 50) % 5) as f64;
    let (x, y) = (0.8 + 0.01 * (i / 80) as f64, -0.8 + 0.02 * (i % 80) as f64);
    let z = h * [1.0, 1.3, 1.6].iter().filter(|&&r| x >= r).count() as f64;
    let m = sensor_io::bev::MountPose::G1_MID360_DEFAULT;
    let r = sensor_io::bev::rpy_rotation(m.rpy.map(f64::from));
    let b = [x - m.xyz[0] as f64, y - m.xyz[1] as f64, z - 0.75 - m.xyz[2] as f64];
    // p_sensor = Rᵀ (p_base − t)
    let ps: [f64; 3] = std::array::from_fn(|c| (0..3).map(|row| r[row][c] * b[row]).sum());
    hal::LidarPoint {
        xyz: ps.map(|v| v as f32),
        reflectivity: 60,
        tag: 0,
        offset_ns: (i as u32) * 10_000,
    }
}

fn synthetic_points(tick: u64) -> usize {
    12_000 + (tick % 7) as usize * 100
}

/// A floor with a 15 cm step, in rows of 120 returns.
fn synthetic_point(i: usize) -> hal::LidarPoint {
    let (a, b) = ((i % 120) as f32, (i / 120) as f32);
    hal::LidarPoint {
        xyz: [
            0.5 + 0.02 * b,
            -1.2 + 0.02 * a,
            -0.7 + if b > 40.0 { 0.15 } else { 0.0 },
        ],
        reflectivity: 60,
        tag: (i % 3) as u8,
        offset_ns: (i as u32) * 5_000,
    }
}

#[test]
fn tick_path_with_lidar_frames_and_logging_does_not_allocate() {
    use control::controller::Controller;
    use control::runtime::{run_loop, LoopEnd, Runtime};
    use runlog::log::{LogOptions, Logger, RunMeta};

    let dir = scratch_dir("replay-lidar-noalloc");
    let spec = control::spec::DeploySpec::load(&terrain_spec(&dir)).expect("spec loads");
    let (obs, act) = (spec.observation_dim(), spec.num_joints());
    let mut rt = Runtime::new(Controller::new(spec).expect("controller builds"));
    let log = dir.join("noalloc.mcap");
    let mut logger = Logger::create(&log, &RunMeta::default(), obs, act, LogOptions::default()).unwrap();
    let schedule = control::operator::CommandSchedule::constant([0.0; 3]);
    let mut operator = schedule.source(2_000_000);
    let _ = control::operator::OperatorSource::at(&mut operator, hal::TickTime::default());
    let mut operator = schedule.source(2_000_000);
    let mut hal = LidarHal::new(false);
    let n = 3_000u64;
    let (mut fresh_steps, mut policy_steps) = (0u64, 0u64);
    let before = counts();
    let end = run_loop(&mut hal, &mut rt, &mut operator, n, |v| {
        fresh_steps += v.summary.perception.is_some_and(|p| p.fresh) as u64;
        policy_steps += v.summary.policy_step as u64;
        logger.push(v);
        true
    });
    let after = counts();
    assert!(matches!(end, LoopEnd::Completed { ticks } if ticks == n), "{end:?}");
    assert_eq!(fresh_steps, n / 50 + 1, "a fresh frame on every perception tick");
    assert!(policy_steps > 200, "{policy_steps} policy steps");
    assert_eq!(
        after, before,
        "allocations/deallocations on the control thread during {n} ticks with lidar: {before:?} -> {after:?}"
    );
    logger.finish().unwrap();
    // Every frame reached the log, exactly as delivered.
    let file = LogFile::open(&log).unwrap();
    let mut frame: Box<control::perception::LidarFrame> = sensor_io::livox::boxed_point_frame();
    let mut logged = 0u64;
    file.scan(|topic, _, data| {
        if topic == ch::LIDAR_FRAME {
            let h = ch::decode_lidar_frame(data, &mut frame).unwrap();
            assert_eq!(h.points, synthetic_points(h.tick));
            assert_eq!(frame.timestamp_ns, h.tick * 2_000_000);
            assert!(frame
                .as_slice()
                .iter()
                .enumerate()
                .all(|(i, p)| *p == synthetic_point(i)));
            logged += 1;
        }
    });
    assert_eq!(logged, fresh_steps);
}

/// The perception group runs after the command is out (runtime step 6), so a token reaches the
/// policy from the next policy step on: a policy step on a perception tick still observes the
/// previous token. Checked on the values themselves (a new step height's bit pattern is absent
/// from that tick's observation and present in the next policy step's).
#[test]
fn a_new_terrain_token_reaches_the_policy_at_the_next_policy_step() {
    use control::controller::Controller;
    use control::runtime::{run_loop, Runtime};

    let dir = scratch_dir("token-latency");
    let spec = control::spec::DeploySpec::load(&terrain_spec(&dir)).expect("spec loads");
    let mut rt = Runtime::new(Controller::new(spec).expect("controller builds"));
    let schedule = control::operator::CommandSchedule::constant([0.0; 3]);
    let mut operator = schedule.source(2_000_000);
    let mut hal = LidarHal::new(true);
    let mut tokens: Vec<(u64, u32)> = Vec::new();
    let mut observed: Vec<(u64, Vec<u32>)> = Vec::new();
    run_loop(&mut hal, &mut rt, &mut operator, 1_500, |v| {
        let k = v.summary.tick.index;
        if v.summary.policy_step {
            let obs = &v.runtime.controller().observation()[TOKEN_OBS];
            observed.push((k, obs.iter().map(|x| x.to_bits()).collect()));
        }
        if let Some(p) = v.summary.perception.filter(|p| p.fresh) {
            tokens.push((k, p.token.step_height_m.to_bits()));
        }
        true
    });
    let policy_at = |k: u64| observed.iter().find(|(t, _)| *t == k).map(|(_, o)| o);
    let next_policy_after = |k: u64| observed.iter().find(|(t, _)| *t > k).map(|(_, o)| o);
    let mut checked = 0;
    for w in tokens.windows(2) {
        let ((_, old), (k, new)) = (w[0], w[1]);
        let (Some(now), Some(next)) = (policy_at(k), next_policy_after(k)) else {
            continue;
        };
        if old == new {
            continue;
        }
        assert!(
            now.contains(&old),
            "tick {k}: the policy should still see the previous token"
        );
        assert!(
            !now.contains(&new),
            "tick {k}: the policy saw this tick's token before the command went out"
        );
        assert!(
            next.contains(&new),
            "the policy step after tick {k} should see its token"
        );
        checked += 1;
    }
    assert!(
        checked >= 10,
        "only {checked} token changes on policy ticks: {tokens:?}"
    );
}
