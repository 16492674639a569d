//! `g1fw eval`: a stair policy evaluated through the real firmware loop. Every episode is exactly a
//! `g1fw sim` run ([`crate::sim_run::run_sim`]: 500 Hz, lock-stepped bridge to its own `g1-sim`,
//! perception on) with a forward command and the heading correction pointed along the staircase
//! axis, scored from the simulator's ground truth:
//!
//! - **stairs**: success = the base reached the end landing (0.25 m past the last riser's edge,
//!   within the stair width; [`crate::sim_run::StairsReport`]) within the time limit, with no fall
//!   and no safety trip;
//! - **flat** (no landing): success = no fall, no trip, and the base walked at least
//!   [`FLAT_SUCCESS_FRACTION`] · vx · (time under policy control) along the target heading.
//!
//! Failure causes: `safety trip` (with its reason) or `fell`, whichever came first; else `stalled` (the base
//! gained less than [`STALL_PROGRESS_M`] along the course in the last [`STALL_WINDOW_S`]), `timeout`
//! (still moving when the time ran out), `short` (flat only: walked too little). Beside the cause,
//! a failure on a drawn staircase is marked `ended_off_side` when the base ended more than half the
//! stair width from its axis: it walked off the side (the table's `off side` column). Episodes are
//! deterministic: episode `i` runs with simulator seed `seed + i` whatever `--jobs` is.
// Evaluation tooling, never on the robot's control path: std's math is fine here (see clippy.toml).
#![allow(clippy::disallowed_methods)]

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

use anyhow::{bail, Context, Result};
use serde::{Deserialize, Serialize};

use crate::sim_run::{run_sim, Heading, SimOptions};
use control::operator::CommandSchedule;
use control::perception::TerrainSource;
use control::spec::DeploySpec;

/// How long the base must stand on the end landing, s, before a stair episode counts as climbed
/// (`--stop-after-landing`'s default, and the trainer's success: a policy that dives across the
/// line and falls has not climbed).
pub const LANDING_HOLD_S: f64 = 1.0;

/// Flat-ground success: walked at least this fraction of vx · time under policy control.
pub const FLAT_SUCCESS_FRACTION: f64 = 0.8;
/// Stalled: less than this progress along the course ...
pub const STALL_PROGRESS_M: f64 = 0.1;
/// ... over the run's last this many seconds.
pub const STALL_WINDOW_S: f64 = 3.0;

/// Watches progress along a course for a stall: less than [`STALL_PROGRESS_M`] gained in the last
/// [`STALL_WINDOW_S`]. `g1fw eval` scores its episodes with it, and the trainer ends stalled
/// episodes with it (`g1-train ppo --end-stalled`).
#[derive(Clone, Copy, Debug)]
pub struct StallWatch {
    /// The farthest point that counted as progress, and when.
    best_s: f64,
    best_t: f64,
    last_t: f64,
}

impl Default for StallWatch {
    fn default() -> Self {
        Self {
            best_s: f64::NEG_INFINITY,
            best_t: 0.0,
            last_t: 0.0,
        }
    }
}

impl StallWatch {
    /// The base at `s` along the course at time `t` (s).
    pub fn observe(&mut self, s: f64, t: f64) {
        if s > self.best_s + STALL_PROGRESS_M {
            self.best_s = s;
            self.best_t = t;
        }
        self.last_t = t;
    }

    /// Counts this moment as progress whatever the distance (e.g. standing on the end landing).
    pub fn excuse(&mut self, s: f64, t: f64) {
        self.best_s = self.best_s.max(s);
        self.best_t = t;
        self.last_t = t;
    }

    /// Whether the last [`STALL_WINDOW_S`] up to the latest observation gained too little.
    pub fn stalled(&self) -> bool {
        self.last_t - self.best_t >= STALL_WINDOW_S
    }
}

/// One world to run an episode on.
#[derive(Clone, Debug, Serialize)]
pub struct EpisodeWorld {
    /// What `g1-sim --world` gets: a preset, a scenario file or `random:SEED`.
    pub world: String,
    /// The drawn scenario (random sweeps only).
    pub drawn: Option<DrawnStairs>,
}

/// A staircase drawn by the random sweep (written as a scenario file for the simulator).
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
pub struct DrawnStairs {
    pub up: bool,
    pub step_height: f64,
    pub step_depth: f64,
    pub steps: u32,
    pub width: f64,
    pub yaw_deg: f64,
    pub start_distance: f64,
}

impl DrawnStairs {
    /// The scenario file (`specs/worlds/` format, `g1_sim::world::TerrainSpec`).
    pub fn toml(&self, name: &str) -> String {
        format!(
            "name = \"{name}\"\n\n[terrain]\nkind = \"{}\"\nstep_height = {}\nstep_depth = {}\nsteps = {}\n\
             width = {}\nyaw_deg = {}\nstart_distance = {}\nlateral_offset = 0.0\nlanding_before = {}\n\
             landing_after = 2.5\n",
            if self.up { "stairs-up" } else { "stairs-down" },
            self.step_height,
            self.step_depth,
            self.steps,
            self.width,
            self.yaw_deg,
            self.start_distance,
            self.start_distance + 1.5,
        )
    }

    /// Draws depth 0.22–0.40 m, yaw ±30°, start distance 0.6–2.0 m, 3–8 steps, width 1.2–2.0 m.
    pub fn draw(rng: &mut hal::XorShift64, up: bool, step_height: f64) -> Self {
        let r2 = |rng: &mut hal::XorShift64, lo: f64, hi: f64| lo + (hi - lo) * rng.unit() as f64;
        Self {
            up,
            step_height,
            // Centimetre / 0.1° grids keep the scenario files readable.
            step_depth: round(r2(rng, 0.22, 0.40), 100.0),
            steps: 3 + rng.below(6) as u32,
            width: round(r2(rng, 1.2, 2.0), 100.0),
            yaw_deg: round(r2(rng, -30.0, 30.0), 10.0),
            start_distance: round(r2(rng, 0.6, 2.0), 100.0),
        }
    }
}

fn round(v: f64, per: f64) -> f64 {
    (v * per).round() / per
}

/// Everything `g1fw eval` needs.
#[derive(Clone, Debug)]
pub struct EvalOptions {
    pub spec: PathBuf,
    /// Weights instead of the spec's file (e.g. a checkpoint's actor).
    pub weights: Option<PathBuf>,
    pub model: String,
    pub terrain_source: Option<TerrainSource>,
    pub vx: f32,
    pub time_limit_s: f64,
    pub jobs: usize,
    pub seed: u64,
    pub episodes: Vec<EpisodeWorld>,
    /// Stop an episode once it has stood on the end landing this long (s).
    pub stop_after_landing_s: Option<f64>,
    pub sim_bin: Option<PathBuf>,
    /// The simulator's physics profile (`g1-sim --physics`; `None`: deploy).
    pub physics: Option<String>,
    /// The operator also steers back to the staircase's centre line (`g1fw sim --hold-line`).
    pub hold_line: bool,
    pub progress: bool,
    /// Set by SIGINT/SIGTERM: running episodes stop at their next tick (their simulators are
    /// stopped and reaped) and are not scored; no new one starts; the report covers what finished.
    pub stop: Arc<AtomicBool>,
}

/// One episode's result.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Episode {
    pub index: usize,
    pub world: String,
    pub drawn: Option<DrawnStairs>,
    pub seed: u64,
    /// `flat`, `up` or `down`.
    pub kind: String,
    /// Mean riser height, m (0 on flat).
    pub step_height_m: f64,
    pub success: bool,
    /// `null` on success; else `fell`, `safety trip: REASON`, `stalled`, `timeout` or `short`.
    pub cause: Option<String>,
    pub risers: u16,
    pub risers_passed: u16,
    pub reached_end_landing_at_s: Option<f64>,
    /// Progress along the course (staircase axis from the start, or along the heading on flat), m.
    pub progress_m: f64,
    /// Farthest the base got from the staircase axis, sideways, m (0 on flat): beyond half the
    /// stair width it has walked off the side.
    #[serde(default)]
    pub max_off_axis_m: f64,
    /// Sideways from the staircase axis where the episode ended (signed, + left), m.
    #[serde(default)]
    pub off_axis_at_end_m: f64,
    /// The episode ended beside the staircase (more than half its width off the axis): it walked
    /// off the side. Known for drawn staircases (`--heights`), whose width the eval chose.
    #[serde(default)]
    pub ended_off_side: Option<bool>,
    pub time_s: f64,
    pub fell_at_s: Option<f64>,
    pub trip: Option<String>,
    pub end: String,
    pub state_trace_sha256: String,
}

/// A row of the per-height table.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct Row {
    pub kind: String,
    pub step_height_cm: u32,
    pub episodes: u64,
    pub successes: u64,
    pub success_rate: f64,
    /// Episodes per failure cause (`safety trip` merged over reasons).
    pub causes: BTreeMap<String, u64>,
    /// Failures that ended beside the staircase (walked off its side; drawn staircases only).
    #[serde(default)]
    pub failed_off_side: u64,
    pub mean_risers_passed: f64,
}

/// The JSON report of `g1fw eval`.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct EvalReport {
    pub spec: String,
    pub model: String,
    pub terrain_source: String,
    /// The simulator's physics profile (reports from before this field ran `deploy`).
    #[serde(default = "deploy_physics")]
    pub physics: String,
    pub vx: f32,
    pub time_limit_s: f64,
    pub seed: u64,
    pub episodes: u64,
    pub successes: u64,
    pub success_rate: f64,
    pub causes: BTreeMap<String, u64>,
    pub table: Vec<Row>,
    pub results: Vec<Episode>,
    pub wall_s: f64,
    /// Stopped by a signal: `episodes` finished of `episodes_planned`.
    pub interrupted: bool,
    pub episodes_planned: u64,
}

fn deploy_physics() -> String {
    "deploy".into()
}

/// Runs every episode (up to `jobs` at once, each with its own simulator) and scores them.
pub fn run_eval(opts: &EvalOptions) -> Result<EvalReport> {
    if opts.episodes.is_empty() {
        bail!("no episodes: give --worlds LIST or --heights H,... (with --kinds and --episodes-per-height)");
    }
    // Fail on a bad spec or weights file once, before starting any simulator.
    let mut spec = DeploySpec::load(&opts.spec)?;
    if let Some(w) = &opts.weights {
        spec = spec.with_weights(w)?;
    }
    control::controller::Controller::new(spec.clone())
        .with_context(|| format!("loading the policy of {}", opts.spec.display()))?;
    let wall = std::time::Instant::now();
    let n = opts.episodes.len();
    let next = AtomicUsize::new(0);
    // Per episode: not run yet (`None`), failed to run, interrupted (`Ok(None)`), or its result.
    type Slot = Option<Result<Option<Episode>, String>>;
    let results: Mutex<Vec<Slot>> = Mutex::new(vec![None; n]);
    let successes = AtomicUsize::new(0);
    let pb = opts.progress.then(|| {
        let pb = indicatif::ProgressBar::new(n as u64);
        pb.set_style(
            indicatif::ProgressStyle::with_template(
                "{spinner} eval {pos}/{len} [{bar:30}] {msg} ({elapsed}, eta {eta})",
            )
            .expect("valid template")
            .progress_chars("=> "),
        );
        pb
    });
    std::thread::scope(|scope| {
        for _ in 0..opts.jobs.min(n).max(1) {
            scope.spawn(|| loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                if i >= n || opts.stop.load(Ordering::Relaxed) {
                    break;
                }
                let r = episode(&spec, opts, i).map_err(|e| format!("{e:#}"));
                if matches!(&r, Ok(Some(e)) if e.success) {
                    successes.fetch_add(1, Ordering::Relaxed);
                }
                results.lock().unwrap_or_else(std::sync::PoisonError::into_inner)[i] = Some(r);
                if let Some(pb) = &pb {
                    pb.inc(1);
                    pb.set_message(format!("{} successes", successes.load(Ordering::Relaxed)));
                }
            });
        }
    });
    if let Some(pb) = pb {
        pb.finish_and_clear();
    }
    let mut episodes = Vec::with_capacity(n);
    for (i, r) in results
        .into_inner()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
        .into_iter()
        .enumerate()
    {
        let interrupted = opts.stop.load(Ordering::Relaxed);
        match r {
            Some(Ok(Some(e))) => episodes.push(e),
            Some(Ok(None)) | None if interrupted => {}
            Some(Err(e)) => bail!("episode {i} ({}) failed to run: {e}", opts.episodes[i].world),
            Some(Ok(None)) | None => bail!("episode {i} did not run"),
        }
    }
    let mut report = summarise(opts, episodes, wall.elapsed().as_secs_f64());
    report.interrupted = opts.stop.load(Ordering::Relaxed);
    Ok(report)
}

/// `None`: interrupted by a signal (not scored).
fn episode(spec: &DeploySpec, opts: &EvalOptions, i: usize) -> Result<Option<Episode>> {
    let w = &opts.episodes[i];
    let seed = opts.seed.wrapping_add(i as u64);
    let sim = SimOptions {
        model: opts.model.clone(),
        schedule: CommandSchedule::constant([opts.vx, 0.0, 0.0]),
        duration_s: opts.time_limit_s,
        seed,
        sim_bin: opts.sim_bin.clone(),
        physics: opts.physics.clone(),
        stop_on_fall: true,
        world: Some(w.world.clone()),
        terrain_source: opts.terrain_source,
        heading: Some(Heading::StairAxis),
        hold_line: opts.hold_line,
        stop_after_landing_s: opts.stop_after_landing_s,
        stop: opts.stop.clone(),
        ..SimOptions::default()
    };
    // Progress along the course (the staircase axis; world x on flat ground, where the target
    // heading is 0), and whether it stalled.
    let mut s0: Option<f64> = None;
    let (mut watch, mut progress) = (StallWatch::default(), 0.0);
    let (mut max_off_axis, mut off_axis) = (0.0f64, 0.0f64);
    let report = run_sim(spec.clone(), &sim, |v| {
        let Some(t) = v.truth else { return };
        if let Some(p) = t.stairs {
            off_axis = p.axis_t;
            max_off_axis = max_off_axis.max(p.axis_t.abs());
        }
        let s = t.stairs.map_or(t.base_pos[0], |p| p.axis_s);
        progress = s - *s0.get_or_insert(s);
        watch.observe(s, t.sim_time_s);
    })
    .with_context(|| format!("episode {i} on {}", w.world))?;
    let stalled = watch.stalled();
    if report.interrupted {
        return Ok(None);
    }
    let trip = report.trip.as_ref().map(|t| t.reason.clone());
    let (kind, h, risers, passed, reached_at, stairs_ok) = match &report.stairs {
        Some(s) => (
            s.kind.clone(),
            s.mean_step_height_m,
            s.risers,
            s.risers_passed,
            s.reached_end_landing_at_s,
            s.success,
        ),
        None => ("flat".to_string(), 0.0, 0, 0, None, false),
    };
    let flat_ok = report.stairs.is_none()
        && report.fell_at_s.is_none()
        && trip.is_none()
        && progress >= FLAT_SUCCESS_FRACTION * opts.vx as f64 * report.policy_time_s;
    let success = stairs_ok || flat_ok;
    let cause = (!success).then(|| {
        // The first of a fall and a trip is the cause (a trip damps the motors, and a fall follows).
        let trip_first = match (&report.trip, report.fell_at_s) {
            (Some(t), Some(f)) => t.time_s <= f,
            (Some(_), None) => true,
            _ => false,
        };
        if trip_first {
            format!("safety trip: {}", trip.as_deref().unwrap_or(""))
        } else if report.fell {
            "fell".to_string()
        } else if stalled {
            "stalled".to_string()
        } else if report.stairs.is_some() {
            "timeout".to_string()
        } else {
            "short".to_string()
        }
    });
    Ok(Some(Episode {
        index: i,
        world: w.world.clone(),
        drawn: w.drawn,
        seed,
        kind,
        step_height_m: h,
        success,
        cause,
        risers,
        risers_passed: passed,
        reached_end_landing_at_s: reached_at,
        progress_m: progress,
        max_off_axis_m: max_off_axis,
        off_axis_at_end_m: off_axis,
        ended_off_side: w.drawn.map(|d| off_axis.abs() > 0.5 * d.width),
        time_s: report.time_s,
        fell_at_s: report.fell_at_s,
        trip,
        end: report.end,
        state_trace_sha256: report.state_trace_sha256,
    }))
}

fn cause_key(c: &str) -> String {
    if c.starts_with("safety trip") {
        "safety trip".into()
    } else {
        c.into()
    }
}

fn summarise(opts: &EvalOptions, results: Vec<Episode>, wall_s: f64) -> EvalReport {
    let mut rows: BTreeMap<(String, u32), (Row, u64)> = BTreeMap::new();
    let mut causes = BTreeMap::new();
    for e in &results {
        let h_cm = (e.step_height_m * 100.0).round() as u32;
        let (row, passed) = rows.entry((e.kind.clone(), h_cm)).or_insert_with(|| {
            (
                Row {
                    kind: e.kind.clone(),
                    step_height_cm: h_cm,
                    ..Row::default()
                },
                0,
            )
        });
        row.episodes += 1;
        row.successes += e.success as u64;
        *passed += e.risers_passed as u64;
        if let Some(c) = &e.cause {
            row.failed_off_side += (e.ended_off_side == Some(true)) as u64;
            *row.causes.entry(cause_key(c)).or_insert(0) += 1;
            *causes.entry(c.clone()).or_insert(0) += 1;
        }
    }
    let table = rows
        .into_values()
        .map(|(mut r, passed)| {
            r.success_rate = r.successes as f64 / r.episodes as f64;
            r.mean_risers_passed = passed as f64 / r.episodes as f64;
            r
        })
        .collect();
    let successes = results.iter().filter(|e| e.success).count() as u64;
    EvalReport {
        spec: opts.spec.display().to_string(),
        model: opts.model.clone(),
        terrain_source: opts.terrain_source.map_or("spec".into(), |s| s.as_str().into()),
        physics: opts.physics.clone().unwrap_or_else(deploy_physics),
        vx: opts.vx,
        time_limit_s: opts.time_limit_s,
        seed: opts.seed,
        episodes: results.len() as u64,
        successes,
        success_rate: successes as f64 / results.len().max(1) as f64,
        causes,
        table,
        results,
        wall_s,
        interrupted: false,
        episodes_planned: opts.episodes.len() as u64,
    }
}

impl EvalReport {
    /// The human summary: totals, causes, and the per-kind, per-height table.
    pub fn text(&self) -> String {
        let mut s = format!(
            "{} of {} episodes succeeded ({:.1} %) — spec {}, model {}, terrain source {}, vx {} m/s, limit {} s\n",
            self.successes,
            self.episodes,
            100.0 * self.success_rate,
            self.spec,
            self.model,
            self.terrain_source,
            self.vx,
            self.time_limit_s
        );
        for (c, k) in &self.causes {
            s += &format!("  {k:>5} × {c}\n");
        }
        s += "\nkind  height  episodes  success  fell  trip  stalled  timeout  short  off side  risers passed (mean)\n";
        for r in &self.table {
            let c = |k: &str| r.causes.get(k).copied().unwrap_or(0);
            s += &format!(
                "{:<5} {:>4} cm  {:>8}  {:>6.1}%  {:>4}  {:>4}  {:>7}  {:>7}  {:>5}  {:>8}  {:.2}\n",
                r.kind,
                r.step_height_cm,
                r.episodes,
                100.0 * r.success_rate,
                c("fell"),
                c("safety trip"),
                c("stalled"),
                c("timeout"),
                c("short"),
                r.failed_off_side,
                r.mean_risers_passed
            );
        }
        s
    }
}

/// A scratch directory for drawn scenario files, removed on drop.
pub struct ScenarioDir(pub PathBuf);

impl Drop for ScenarioDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// The random sweep: `per_height` episodes for every (kind, height), drawn from `seed`; writes the
/// scenario files into a fresh directory under `parent` (removed when the returned guard drops).
pub fn random_sweep(
    heights: &[f64],
    kinds_up: &[bool],
    per_height: usize,
    seed: u64,
    parent: &Path,
) -> Result<(Vec<EpisodeWorld>, ScenarioDir)> {
    for &h in heights {
        if !(0.03..=0.30).contains(&h) {
            bail!("--heights: {h} m is outside the simulator's 0.03..0.30 m");
        }
    }
    let dir = parent.join(format!("g1fw-eval-{}-{seed}", std::process::id()));
    std::fs::create_dir_all(&dir).with_context(|| format!("creating scratch dir {}", dir.display()))?;
    let guard = ScenarioDir(dir.clone());
    let mut out = Vec::new();
    for &up in kinds_up {
        for (hi, &h) in heights.iter().enumerate() {
            for e in 0..per_height {
                // One generator per episode, so an episode's world does not depend on the others.
                let key = seed ^ ((up as u64) << 63) ^ ((hi as u64) << 40) ^ (e as u64).wrapping_mul(0x9E37_79B9);
                let mut rng = hal::XorShift64(key.wrapping_mul(0x2545_F491_4F6C_DD1D) | 1);
                let d = DrawnStairs::draw(&mut rng, up, h);
                let name = format!("{}-{:02}cm-{e:04}", if up { "up" } else { "down" }, (h * 100.0).round());
                let path = dir.join(format!("{name}.toml"));
                std::fs::write(&path, d.toml(&name)).with_context(|| format!("writing {}", path.display()))?;
                out.push(EpisodeWorld {
                    world: path.display().to_string(),
                    drawn: Some(d),
                });
            }
        }
    }
    Ok((out, guard))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sweep_draws_in_range_reproducibly_and_cleans_up() {
        let tmp = std::env::temp_dir().join(format!("g1fw-eval-unit-{}", std::process::id()));
        std::fs::create_dir_all(&tmp).unwrap();
        let (a, guard) = random_sweep(&[0.12, 0.2], &[true, false], 5, 7, &tmp).unwrap();
        assert_eq!(a.len(), 20);
        for w in &a {
            let d = w.drawn.unwrap();
            assert!(
                (0.22..=0.40).contains(&d.step_depth) && (3..=8).contains(&d.steps),
                "{d:?}"
            );
            assert!(
                d.yaw_deg.abs() <= 30.0 && (0.6..=2.0).contains(&d.start_distance),
                "{d:?}"
            );
            assert!((1.2..=2.0).contains(&d.width), "{d:?}");
            let text = std::fs::read_to_string(&w.world).unwrap();
            assert!(text.contains(&format!("step_height = {}", d.step_height)), "{text}");
        }
        let dir = guard.0.clone();
        drop(guard);
        assert!(!dir.exists(), "the scratch scenarios are removed");
        let (b, _g) = random_sweep(&[0.12, 0.2], &[true, false], 5, 7, &tmp).unwrap();
        let key = |v: &[EpisodeWorld]| v.iter().map(|w| format!("{:?}", w.drawn)).collect::<Vec<_>>();
        assert_eq!(key(&a), key(&b), "same seed, same worlds");
        let (c, _g2) = random_sweep(&[0.12, 0.2], &[true, false], 5, 8, &tmp).unwrap();
        assert_ne!(key(&a), key(&c));
        assert!(random_sweep(&[0.5], &[true], 1, 0, &tmp).is_err());
        let _ = std::fs::remove_dir_all(&tmp);
    }

    #[test]
    fn the_table_counts_failures_that_ended_off_the_side() {
        let ep = |success: bool, off: Option<bool>| Episode {
            index: 0,
            world: "w.toml".into(),
            drawn: None,
            seed: 0,
            kind: "up".into(),
            step_height_m: 0.14,
            success,
            cause: (!success).then(|| "safety trip: tilt".to_string()),
            risers: 5,
            risers_passed: 3,
            reached_end_landing_at_s: None,
            progress_m: 1.0,
            max_off_axis_m: 1.2,
            off_axis_at_end_m: 1.1,
            ended_off_side: off,
            time_s: 5.0,
            fell_at_s: None,
            trip: None,
            end: String::new(),
            state_trace_sha256: String::new(),
        };
        let opts = EvalOptions {
            spec: "s.toml".into(),
            weights: None,
            model: "g1-12dof".into(),
            terrain_source: None,
            vx: 0.5,
            time_limit_s: 20.0,
            jobs: 1,
            seed: 0,
            episodes: Vec::new(),
            stop_after_landing_s: None,
            sim_bin: None,
            physics: None,
            hold_line: false,
            progress: false,
            stop: Arc::default(),
        };
        // A success that ended off the side (it left after the landing) is no failure; a
        // failure with an unknown width is not counted.
        let r = summarise(
            &opts,
            vec![
                ep(true, Some(true)),
                ep(false, Some(true)),
                ep(false, Some(false)),
                ep(false, None),
            ],
            1.0,
        );
        assert_eq!(r.table.len(), 1);
        assert_eq!(r.table[0].failed_off_side, 1);
        assert_eq!(r.table[0].causes["safety trip"], 3);
        let text = r.text();
        assert!(text.contains("off side"), "{text}");
        let row = text.lines().find(|l| l.starts_with("up")).unwrap();
        assert!(row.split_whitespace().any(|c| c == "1"), "{row}");
    }
}
