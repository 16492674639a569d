//! A long run that must stay healthy (issue 73): `g1fw run --dds` against `g1-sim --dds` on its
//! gantry, a fault every few minutes, each tripping damping and each recovered by an operator
//! reset. Measured: the controller's resident memory over the run, the tick's compute time and
//! clock lateness per window, every trip and reset, and a bit-exact replay of every file of the
//! log, which is split at a size (`--log-split-mb`).
//!
//! The bench (`cargo bench --workspace --bench soak`, an hour) and the test (three minutes) run
//! this same code; `docs/reliability.md` keeps the bench's figures.
use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::{Duration, Instant};

use crate::{built_bin, g1_sim_dds, peer_spec_path, read_json, shared_dir, skip_loudly_or_fail, skip_or_fail, Netns};

/// Faults the soak cycles through: `g1-sim --fault` kind (with its slot), how long it lasts, and
/// the safety trip it must cause.
pub const FAULTS: [(&str, f64, &str); 5] = [
    ("drop", 0.2, "state_timeout"),
    ("corrupt", 0.1, "crc_streak"),
    ("imu-nan", 0.02, "non_finite_input"),
    ("overheat:3", 0.1, "motor_temperature"),
    ("freeze-joint:3", 0.2, "frozen_joint"),
];

/// Seconds from a fault's start to the operator's reset (the trip, then the robot settling on its
/// rope).
pub const RESET_AFTER_S: f64 = 2.0;

/// How long to soak and how often to fault.
#[derive(Clone, Copy, Debug)]
pub struct SoakPlan {
    pub duration_s: f64,
    /// The first fault comes after one interval, then one per interval.
    pub fault_every_s: f64,
    /// How often the controller's resident memory is sampled.
    pub rss_every_s: f64,
    /// Windows the tick timing is summarised in (first against last shows a drift).
    pub windows: usize,
    /// `g1fw run --log-split-mb`.
    pub split_mb: f64,
}

/// Compute time of the tick (all three groups) and clock lateness in one window, µs.
#[derive(Clone, Debug, serde::Serialize)]
pub struct TimingWindow {
    pub from_s: f64,
    pub to_s: f64,
    pub ticks: usize,
    pub compute_p50_us: f64,
    pub compute_p99_us: f64,
    pub compute_max_us: f64,
    pub overruns: u64,
}

/// What a soak measured.
#[derive(Clone, Debug, serde::Serialize)]
pub struct SoakFigures {
    pub duration_s: f64,
    pub ticks: u64,
    /// (start s, `--fault` spec) of every fault injected.
    pub faults: Vec<(f64, String)>,
    /// (time s, reason) of every safety trip, from the log's `/safety/event`.
    pub trips: Vec<(f64, String)>,
    /// Times of the operator's resets, s.
    pub resets: Vec<f64>,
    /// Start-ups that reached the policy again after a reset.
    pub back_to_policy: usize,
    /// (wall s since start, resident MiB) of `g1fw`.
    pub rss_mib: Vec<(f64, f64)>,
    /// Least-squares slope of the resident memory after the first tenth of the run, MiB per hour.
    pub rss_slope_mib_per_h: f64,
    /// Largest resident memory after the first tenth minus the first sample there, MiB.
    pub rss_growth_mib: f64,
    pub timing: Vec<TimingWindow>,
    /// The report's clock lateness over the whole run.
    pub period_jitter: serde_json::Value,
    pub report_end: String,
    /// All files of the log together.
    pub log_bytes: u64,
    pub log_files: u64,
    /// Files whose replay (each on its own) was bit-exact.
    pub files_replayed_identical: u64,
    /// Replay's wall time, all files.
    pub replay_s: f64,
}

/// The `--fault` specs and the operator schedule of a plan: fault `i` starts at (i + 1) × every,
/// and the reset follows it by [`RESET_AFTER_S`].
pub fn schedule(plan: &SoakPlan) -> (Vec<(f64, String)>, String) {
    let mut faults = Vec::new();
    let mut ops = String::from("0 0 0 0\n");
    let mut i = 0;
    loop {
        let t = (i + 1) as f64 * plan.fault_every_s;
        if t + RESET_AFTER_S + 1.0 >= plan.duration_s {
            break;
        }
        let (kind, dur, _) = FAULTS[i % FAULTS.len()];
        let (name, arg) = match kind.split_once(':') {
            Some((n, a)) => (n, format!(":{a}")),
            None => (kind, String::new()),
        };
        faults.push((t, format!("{name}@{t}+{dur}{arg}")));
        ops.push_str(&format!("{} reset\n", t + RESET_AFTER_S));
        i += 1;
    }
    (faults, ops)
}

/// Resident memory of process `pid`, MiB (`VmRSS`).
fn rss_mib(pid: u32) -> Option<f64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let kb: f64 = status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))?
        .trim()
        .trim_end_matches("kB")
        .trim()
        .parse()
        .ok()?;
    Some(kb / 1024.0)
}

/// Least-squares slope of `(x, y)`.
fn slope(points: &[(f64, f64)]) -> f64 {
    let n = points.len() as f64;
    if n < 2.0 {
        return 0.0;
    }
    let (mx, my) = (
        points.iter().map(|p| p.0).sum::<f64>() / n,
        points.iter().map(|p| p.1).sum::<f64>() / n,
    );
    let sxy: f64 = points.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let sxx: f64 = points.iter().map(|p| (p.0 - mx).powi(2)).sum();
    if sxx == 0.0 {
        0.0
    } else {
        sxy / sxx
    }
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    sorted[((p * (sorted.len() - 1) as f64).round() as usize).min(sorted.len() - 1)]
}

/// The log's per-tick timing in `windows` equal windows, its trips and its resets (all files).
fn read_log(files: &[PathBuf], windows: usize) -> (Vec<TimingWindow>, Vec<(f64, String)>, Vec<f64>) {
    let mut ticks: Vec<(f64, f64, u64)> = Vec::new();
    let (mut trips, mut resets) = (Vec::new(), Vec::new());
    for log in files {
        let file = runlog::log::reader::LogFile::open(log).unwrap_or_else(|e| panic!("{}: {e}", log.display()));
        let end = file.scan(|topic, time_ns, data| match topic {
            runlog::log::channels::TIMING => {
                let v: serde_json::Value = serde_json::from_slice(data).expect("timing JSON");
                let ns = ["fast_ns", "perception_ns", "policy_ns"]
                    .iter()
                    .map(|k| v[k].as_f64().unwrap_or(0.0))
                    .sum::<f64>();
                ticks.push((time_ns as f64 * 1e-9, ns * 1e-3, v["overruns"].as_u64().unwrap_or(0)));
            }
            runlog::log::channels::SAFETY_EVENT => {
                let v: serde_json::Value = serde_json::from_slice(data).expect("safety event JSON");
                let t = v["time_s"].as_f64().unwrap_or(f64::NAN);
                match v["event"].as_str() {
                    Some("trip") => trips.push((t, v["reason"].as_str().unwrap_or("?").to_string())),
                    Some("reset") => resets.push(t),
                    _ => {}
                }
            }
            _ => {}
        });
        file.undamaged(end).expect("the soak's log is whole");
    }
    let span = ticks.last().map_or(0.0, |t| t.0);
    let mut out = Vec::new();
    for w in 0..windows {
        let (from, to) = (span * w as f64 / windows as f64, span * (w + 1) as f64 / windows as f64);
        let inside: Vec<&(f64, f64, u64)> = ticks
            .iter()
            .filter(|t| t.0 >= from && (t.0 < to || w + 1 == windows))
            .collect();
        let mut c: Vec<f64> = inside.iter().map(|t| t.1).collect();
        c.sort_by(f64::total_cmp);
        out.push(TimingWindow {
            from_s: from,
            to_s: to,
            ticks: c.len(),
            compute_p50_us: percentile(&c, 0.5),
            compute_p99_us: percentile(&c, 0.99),
            compute_max_us: c.last().copied().unwrap_or(f64::NAN),
            overruns: inside.iter().map(|t| t.2).sum(),
        });
    }
    (out, trips, resets)
}

/// Runs a soak in `dir`; `None` (said loudly, a failure under CI) when `../shared` or a network
/// namespace is missing.
pub fn soak(dir: &Path, plan: SoakPlan) -> Option<SoakFigures> {
    if shared_dir().is_none() {
        skip_or_fail("the soak (the peer policy and the 12-dof model)");
        return None;
    }
    let Some(ns) = Netns::new("g1soak") else {
        skip_loudly_or_fail("SKIP: the soak needs a network namespace (`ip netns add`, as root)");
        return None;
    };
    let (faults, ops) = schedule(&plan);
    let ops_file = dir.join("operator.txt");
    std::fs::write(&ops_file, ops).expect("operator schedule");
    // Free-running, as the robot: its clock is the wall's, as g1fw's is, so a fault and its reset
    // come in order. Lock-stepped, the simulator falls behind by every command the DDS reader
    // drops: on a loaded machine 1.4 s in the first 2 minutes and over 2 s by the fourth, so
    // resets came before their faults.
    let mut sim_args = vec!["--gantry".to_string(), "--dds-free-run".to_string()];
    for (_, f) in &faults {
        sim_args.extend(["--fault".to_string(), f.clone()]);
    }
    let sim_args: Vec<&str> = sim_args.iter().map(String::as_str).collect();
    let sim = g1_sim_dds(&ns, &sim_args);
    let (report, log) = (dir.join("report.json"), dir.join("soak.mcap"));
    let duration = plan.duration_s.to_string();
    let mut fw = ns
        .command(&built_bin("g1fw"))
        .current_dir(crate::repo_root())
        .args(["run", "--dds", "lo,1", "--spec"])
        .arg(peer_spec_path())
        // Both sides pace on a shared VM's clock, whose stalls reach 8-17 ms (docs/robot.md).
        .args(["--set", "safety.state_timeout_s=0.1"])
        // A slower start-up than the spec's 0.5 s: after a reset the robot starts from the rope.
        .args(["--ramp", "1.5", "--cmd-schedule"])
        .arg(&ops_file)
        .args(["--log-split-mb", &plan.split_mb.to_string()])
        .args(["--duration", &duration, "--report"])
        .arg(&report)
        .arg("--log")
        .arg(&log)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("g1fw run --dds");
    let pid = fw.id();
    let start = Instant::now();
    let mut rss = Vec::new();
    let mut stderr_tail = String::new();
    let status = loop {
        if let Some(s) = fw.try_wait().expect("g1fw") {
            break s;
        }
        if let Some(m) = rss_mib(pid) {
            rss.push((start.elapsed().as_secs_f64(), m));
        }
        std::thread::sleep(Duration::from_secs_f64(plan.rss_every_s));
    };
    if let Some(mut e) = fw.stderr.take() {
        use std::io::Read;
        let _ = e.read_to_string(&mut stderr_tail);
    }
    let sim_out = sim.wait_json("g1-sim --dds --gantry");
    assert!(
        report.exists(),
        "g1fw wrote no report (status {status}): {stderr_tail}\nsim {sim_out}"
    );
    let r = read_json(&report);
    let transitions = crate::transitions(&r);
    let back_to_policy = transitions
        .windows(2)
        .filter(|w| w[0].0 == "startup" && w[0].1 == "reset" && w[1].0 == "policy")
        .count();
    let settled: Vec<(f64, f64)> = rss.iter().copied().filter(|p| p.0 >= plan.duration_s / 10.0).collect();
    let rss_growth_mib = match settled.first() {
        Some(first) => settled.iter().map(|p| p.1).fold(f64::MIN, f64::max) - first.1,
        None => f64::NAN,
    };
    let log_files = r["log"]["files"].as_u64().unwrap_or(0);
    let files: Vec<PathBuf> = (0..log_files).map(|n| runlog::log::split_path(&log, n)).collect();
    let (timing, trips, resets) = read_log(&files, plan.windows);
    let t0 = Instant::now();
    let mut files_replayed_identical = 0;
    for f in &files {
        let (identical, text) = crate::replays_identical(f);
        if identical {
            files_replayed_identical += 1;
        } else {
            eprintln!("soak replay of {}: {text}", f.display());
        }
    }
    let replay_s = t0.elapsed().as_secs_f64();
    Some(SoakFigures {
        duration_s: plan.duration_s,
        ticks: r["ticks"].as_u64().unwrap_or(0),
        faults,
        trips,
        resets,
        back_to_policy,
        rss_slope_mib_per_h: slope(&settled) * 3600.0,
        rss_growth_mib,
        rss_mib: rss,
        timing,
        period_jitter: r["period_jitter"].clone(),
        report_end: r["end"].as_str().unwrap_or("?").to_string(),
        log_bytes: r["log"]["bytes"].as_u64().unwrap_or(0),
        log_files,
        files_replayed_identical,
        replay_s,
    })
}

/// The checks both the test and the bench make: every fault tripped the damping it should before
/// its reset, every reset brought the policy back, the run ended as planned, and the log replays.
/// (Fault times are the simulator's, whose clock starts at g1fw's first command: a trip is placed
/// between its fault and its reset.)
pub fn check(f: &SoakFigures) {
    let ctx = format!("{f:#?}");
    assert_eq!(f.report_end, "completed", "{ctx}");
    assert_eq!(f.trips.len(), f.faults.len(), "one trip per fault: {ctx}");
    for (i, ((start, spec), (at, reason))) in f.faults.iter().zip(&f.trips).enumerate() {
        let want = FAULTS[i % FAULTS.len()].2;
        assert_eq!(reason, want, "fault {spec}: {ctx}");
        assert!(
            *at >= *start && *at < start + RESET_AFTER_S,
            "fault {spec} tripped at {at} s: {ctx}"
        );
    }
    assert_eq!(f.resets.len(), f.faults.len(), "{ctx}");
    assert_eq!(
        f.back_to_policy,
        f.faults.len(),
        "every reset back to the policy: {ctx}"
    );
    assert!(f.log_files >= 1, "{ctx}");
    assert_eq!(
        f.files_replayed_identical, f.log_files,
        "every file replays on its own: {ctx}"
    );
}

/// Where a soak keeps its files: `$G1_SOAK_DIR` or a fresh folder under the system's temp.
pub fn soak_dir(name: &str) -> PathBuf {
    std::env::var_os("G1_SOAK_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| std::env::temp_dir().join(format!("g1-{name}-{}", std::process::id())))
}
