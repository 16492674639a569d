//! Terrain worlds: flat ground or one staircase (up or down, regular or "irregular outdoor"), from a
//! scenario file (TOML), a preset name or a seed, with privileged ground truth for any robot pose.
//!
//! Frame: world x is the robot's start heading, z up, the floor at z = 0. The robot starts at the
//! origin facing +x. A staircase runs along its axis `u` at `yaw_deg` from +x; its first riser is
//! `start_distance` ahead of the robot along `u`. Levels are solid boxes from the floor up, so the
//! same numbers describe the MuJoCo geometry ([`World::primitives`]), the analytic ground height
//! ([`World::ground_height`]) and the labels ([`World::truth`]).
//!
//! Ground truth follows the paper's token z = (class, h, d, θ) ([`hal::TerrainToken`]):
//! - a riser counts when it crosses the look-ahead box in the robot's frame, x ∈ [−0.5, 1.5] m,
//!   |y| ≤ 0.75 m (what the head lidar's BEV window shows ahead of and under the robot);
//! - none → flat: h = d = 0, θ = the robot's heading relative to world +x;
//! - else the riser the robot is about to take (nearest ahead, or the last one behind when all
//!   are behind) gives h (its height) and d (the tread after it in the direction of travel); the
//!   direction of travel is along `u` or against it, whichever the robot faces; the class is
//!   stairs-up when that riser rises in the direction of travel, and θ = heading − travel direction.
use std::f64::consts::PI;
use std::path::Path;

use hal::{wrap_angle, TerrainClass, TerrainToken};
use serde::{Deserialize, Serialize};

use crate::quat_mul;
use labkit::rng::Rng;

/// Largest scenario (world) file read, bytes.
pub const MAX_WORLD_BYTES: u64 = 1 << 20;

/// Look-ahead box for labels, robot frame: x range, half width (m).
pub const LOOKAHEAD_X: (f64, f64) = (-0.5, 1.5);
pub const LOOKAHEAD_HALF_Y: f64 = 0.75;

/// Preset names for `--world`.
pub const PRESETS: [&str; 4] = ["flat", "stairs-up", "stairs-down", "outdoor"];

#[derive(Debug, thiserror::Error)]
pub enum WorldError {
    #[error("reading scenario {path}")]
    Io { path: String, source: std::io::Error },
    #[error("scenario {path}: {message}")]
    Parse { path: String, message: String },
    #[error("scenario field `{field}` = {value}: {expected}")]
    Invalid {
        field: &'static str,
        value: f64,
        expected: &'static str,
    },
    #[error("unknown world `{0}`: give a scenario file (.toml), a preset ({presets}) or `random:SEED`", presets = PRESETS.join(", "))]
    Unknown(String),
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TerrainKind {
    Flat,
    StairsUp,
    StairsDown,
}

/// Irregular outdoor steps.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Outdoor {
    /// Per-step height jitter, fraction of the nominal height (uniform ±).
    #[serde(default = "d_jitter")]
    pub height_jitter: f64,
    /// Per-step depth jitter, fraction of the nominal depth (uniform ±).
    #[serde(default = "d_jitter")]
    pub depth_jitter: f64,
    /// Largest tread slope, degrees (each tread draws uniform ±; positive rises away from the nosing).
    #[serde(default = "d_slope")]
    pub tread_slope_deg: f64,
    /// Nosing radius, m (0: sharp edges).
    #[serde(default = "d_nosing")]
    pub nosing_radius: f64,
    /// Seeds the jitter.
    #[serde(default)]
    pub seed: u64,
}

fn d_jitter() -> f64 {
    0.1
}
fn d_slope() -> f64 {
    2.0
}
fn d_nosing() -> f64 {
    0.02
}

/// What a scenario file's `[terrain]` table holds. Defaults make `kind = "stairs-up"` alone valid.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TerrainSpec {
    pub kind: TerrainKind,
    /// Nominal riser height, m (0.05–0.25).
    #[serde(default = "d_h")]
    pub step_height: f64,
    /// Nominal tread depth, m (0.20–0.45).
    #[serde(default = "d_d")]
    pub step_depth: f64,
    #[serde(default = "d_steps")]
    pub steps: usize,
    /// Staircase width, m.
    #[serde(default = "d_width")]
    pub width: f64,
    /// Staircase direction relative to the robot's start heading, degrees (±45).
    #[serde(default)]
    pub yaw_deg: f64,
    /// Robot start to the first riser along the staircase axis, m.
    #[serde(default = "d_start")]
    pub start_distance: f64,
    /// Sideways offset of the staircase axis from the robot, m.
    #[serde(default)]
    pub lateral_offset: f64,
    /// Flat length before the first riser (the robot starts on it), m.
    #[serde(default = "d_landing_before")]
    pub landing_before: f64,
    /// Flat length after the last riser, m.
    #[serde(default = "d_landing_after")]
    pub landing_after: f64,
    pub outdoor: Option<Outdoor>,
}

fn d_h() -> f64 {
    0.15
}
fn d_d() -> f64 {
    0.30
}
fn d_steps() -> usize {
    6
}
fn d_width() -> f64 {
    1.6
}
fn d_start() -> f64 {
    1.2
}
fn d_landing_before() -> f64 {
    2.5
}
fn d_landing_after() -> f64 {
    2.5
}

/// A scenario file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scenario {
    #[serde(default)]
    pub name: String,
    pub terrain: TerrainSpec,
}

/// Ranges [`World::random`] draws from (the ranges by default).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RandomRanges {
    pub step_height: (f64, f64),
    pub step_depth: (f64, f64),
    pub steps: (usize, usize),
    pub width: (f64, f64),
    pub yaw_deg: f64,
    pub start_distance: (f64, f64),
    /// Probabilities of flat and of the outdoor variant (the rest split evenly up/down).
    pub p_flat: f64,
    pub p_outdoor: f64,
}

impl Default for RandomRanges {
    fn default() -> Self {
        Self {
            step_height: (0.05, 0.25),
            step_depth: (0.20, 0.45),
            steps: (3, 10),
            width: (1.2, 2.5),
            yaw_deg: 45.0,
            start_distance: (0.6, 2.0),
            p_flat: 0.1,
            p_outdoor: 0.3,
        }
    }
}

/// One riser of the built staircase, in axis coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Riser {
    /// Position along the axis (from the first riser), m.
    pub s: f64,
    /// Level before and after it (along +u), m.
    pub level_before: f64,
    pub level_after: f64,
    /// Tread depth after it (along +u) and before it, m (the nominal depth at the ends).
    pub depth_after: f64,
    pub depth_before: f64,
}

/// A static MuJoCo geom: a box (half sizes) or a cylinder (radius, half length), pose in the world.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Primitive {
    Box {
        pos: [f64; 3],
        quat: [f64; 4],
        half: [f64; 3],
    },
    Cylinder {
        pos: [f64; 3],
        quat: [f64; 4],
        radius: f64,
        half_len: f64,
    },
}

/// A built staircase.
#[derive(Clone, Debug, PartialEq)]
pub struct Staircase {
    /// First riser's centre on the floor, world.
    pub origin: [f64; 2],
    /// Axis direction (+u), rad from world +x.
    pub yaw: f64,
    pub width: f64,
    pub risers: Vec<Riser>,
    /// Tread slope per level segment (levels.len() = risers + 1), rad.
    pub slopes: Vec<f64>,
    /// Levels from the start landing to the end landing.
    pub levels: Vec<f64>,
    /// Axis extent of the landings: start landing begins at `-landing_before`, end landing ends at
    /// `end_s`.
    pub landing_before: f64,
    pub end_s: f64,
    pub nosing_radius: f64,
}

/// A built world.
#[derive(Clone, Debug, PartialEq)]
pub struct World {
    pub name: String,
    pub spec: TerrainSpec,
    pub stairs: Option<Staircase>,
}

impl Outdoor {
    fn validate(&self) -> Result<(), WorldError> {
        check("outdoor.height_jitter", self.height_jitter, 0.0, 0.3)?;
        check("outdoor.depth_jitter", self.depth_jitter, 0.0, 0.3)?;
        check("outdoor.tread_slope_deg", self.tread_slope_deg, 0.0, 8.0)?;
        check("outdoor.nosing_radius", self.nosing_radius, 0.0, 0.04)
    }
}

fn check(field: &'static str, value: f64, lo: f64, hi: f64) -> Result<(), WorldError> {
    if value.is_finite() && value >= lo && value <= hi {
        Ok(())
    } else {
        Err(WorldError::Invalid {
            field,
            value,
            expected: match (lo, hi) {
                _ if field == "step_height" => "must be within 0.03..0.30 m",
                _ if field == "step_depth" => "must be within 0.15..0.60 m",
                _ if field == "yaw_deg" => "must be within ±60 degrees",
                _ => "out of range (see the scenario documentation in sim/src/world.rs)",
            },
        })
    }
}

impl TerrainSpec {
    pub fn validate(&self) -> Result<(), WorldError> {
        if self.kind == TerrainKind::Flat {
            return Ok(());
        }
        check("step_height", self.step_height, 0.03, 0.30)?;
        check("step_depth", self.step_depth, 0.15, 0.60)?;
        check("steps", self.steps as f64, 1.0, 40.0)?;
        check("width", self.width, 0.6, 10.0)?;
        check("yaw_deg", self.yaw_deg, -60.0, 60.0)?;
        check("start_distance", self.start_distance, 0.3, 10.0)?;
        check(
            "lateral_offset",
            self.lateral_offset,
            -0.5 * self.width,
            0.5 * self.width,
        )?;
        check("landing_after", self.landing_after, 0.5, 20.0)?;
        // The robot starts on the first landing (it must hold its feet).
        check("landing_before", self.landing_before, self.start_distance + 0.4, 20.0)?;
        if let Some(o) = &self.outdoor {
            o.validate()?;
        }
        Ok(())
    }
}

impl World {
    /// A preset, a scenario file (anything ending in `.toml`, or any path that exists: a FIFO or
    /// a directory is then refused as such) or `random:SEED`.
    pub fn resolve(arg: &str) -> Result<World, WorldError> {
        if arg.ends_with(".toml") || (!PRESETS.contains(&arg) && Path::new(arg).symlink_metadata().is_ok()) {
            return World::from_file(Path::new(arg));
        }
        if let Some(seed) = arg.strip_prefix("random:") {
            let seed = seed.parse::<u64>().map_err(|_| WorldError::Unknown(arg.to_string()))?;
            return Ok(World::random(seed, &RandomRanges::default()));
        }
        World::preset(arg).ok_or_else(|| WorldError::Unknown(arg.to_string()))
    }

    pub fn preset(name: &str) -> Option<World> {
        let base = TerrainSpec {
            kind: TerrainKind::StairsUp,
            step_height: d_h(),
            step_depth: d_d(),
            steps: d_steps(),
            width: d_width(),
            yaw_deg: 0.0,
            start_distance: d_start(),
            lateral_offset: 0.0,
            landing_before: d_landing_before(),
            landing_after: d_landing_after(),
            outdoor: None,
        };
        let spec = match name {
            "flat" => TerrainSpec {
                kind: TerrainKind::Flat,
                ..base
            },
            "stairs-up" => base,
            "stairs-down" => TerrainSpec {
                kind: TerrainKind::StairsDown,
                ..base
            },
            "outdoor" => TerrainSpec {
                step_height: 0.13,
                step_depth: 0.35,
                steps: 10,
                width: 2.0,
                yaw_deg: 10.0,
                outdoor: Some(Outdoor {
                    height_jitter: 0.1,
                    depth_jitter: 0.1,
                    tread_slope_deg: 2.0,
                    nosing_radius: 0.02,
                    seed: 33,
                }),
                ..base
            },
            _ => return None,
        };
        Some(World::build(name, spec).expect("presets are valid"))
    }

    /// Reads a scenario file (at most [`MAX_WORLD_BYTES`]).
    pub fn from_file(path: &Path) -> Result<World, WorldError> {
        let text = input_file::read_text_capped(path, MAX_WORLD_BYTES).map_err(|source| WorldError::Io {
            path: path.display().to_string(),
            source,
        })?;
        World::from_toml(&text, &path.display().to_string())
    }

    pub fn from_toml(text: &str, origin: &str) -> Result<World, WorldError> {
        let sc: Scenario = toml::from_str(text).map_err(|e| WorldError::Parse {
            path: origin.to_string(),
            message: input_file::text::for_terminal(&e.to_string(), input_file::text::MAX_QUOTED_LINE, true),
        })?;
        let name = if sc.name.is_empty() {
            origin.to_string()
        } else {
            sc.name
        };
        World::build(&name, sc.terrain)
    }

    /// A world drawn from `seed` (same seed → same world on every machine).
    pub fn random(seed: u64, r: &RandomRanges) -> World {
        let mut rng = Rng(seed ^ 0x0000_5EED_0F57_A1B5);
        let kind = if rng.chance(r.p_flat) {
            TerrainKind::Flat
        } else if rng.chance(0.5) {
            TerrainKind::StairsUp
        } else {
            TerrainKind::StairsDown
        };
        let start_distance = rng.range(r.start_distance.0, r.start_distance.1);
        let width = rng.range(r.width.0, r.width.1);
        let spec = TerrainSpec {
            kind,
            step_height: rng.range(r.step_height.0, r.step_height.1),
            step_depth: rng.range(r.step_depth.0, r.step_depth.1),
            steps: rng.int(r.steps.0 as u64, r.steps.1 as u64) as usize,
            width,
            yaw_deg: rng.range(-r.yaw_deg, r.yaw_deg),
            start_distance,
            lateral_offset: rng.range(-0.2, 0.2) * width,
            landing_before: start_distance + rng.range(1.0, 2.5),
            landing_after: rng.range(1.5, 3.0),
            outdoor: rng.chance(r.p_outdoor).then(|| Outdoor {
                height_jitter: 0.1,
                depth_jitter: 0.1,
                tread_slope_deg: rng.range(0.0, 3.0),
                nosing_radius: rng.range(0.0, 0.03),
                seed: rng.next_u64(),
            }),
        };
        World::build(&format!("random:{seed}"), spec).expect("random ranges are valid")
    }

    /// Validates `spec` and lays out the staircase.
    pub fn build(name: &str, spec: TerrainSpec) -> Result<World, WorldError> {
        spec.validate()?;
        let stairs = (spec.kind != TerrainKind::Flat).then(|| Staircase::layout(&spec));
        Ok(World {
            name: name.to_string(),
            spec,
            stairs,
        })
    }

    /// Height of the walking surface at (x, y), m (floor = 0).
    pub fn ground_height(&self, x: f64, y: f64) -> f64 {
        self.stairs.as_ref().map_or(0.0, |s| s.height_at(x, y))
    }

    /// Ground-truth token for a robot at (x, y) with heading `yaw` (rad).
    pub fn truth(&self, x: f64, y: f64, yaw: f64) -> TerrainToken {
        self.labelled_truth(x, y, yaw).0
    }

    /// [`Self::truth`] and the riser it describes ([`Self::labelled_riser`]), from one search.
    pub fn labelled_truth(&self, x: f64, y: f64, yaw: f64) -> (TerrainToken, Option<LabelledRiser>) {
        let riser = self.labelled_riser(x, y, yaw);
        (self.token_of(riser, yaw), riser)
    }

    /// The token describing `riser` to a robot heading `yaw`; flat when there is none.
    fn token_of(&self, riser: Option<LabelledRiser>, yaw: f64) -> TerrainToken {
        let flat = TerrainToken {
            yaw_rad: wrap_angle(yaw) as f32,
            ..TerrainToken::FLAT
        };
        let (Some(st), Some(lr)) = (&self.stairs, riser) else {
            return flat;
        };
        let r = st.risers[lr.index];
        let along_u = (yaw - st.yaw).cos() >= 0.0;
        let travel = if along_u { st.yaw } else { st.yaw + PI };
        let rise = if along_u {
            r.level_after - r.level_before
        } else {
            r.level_before - r.level_after
        };
        TerrainToken {
            class: if rise > 0.0 {
                TerrainClass::StairsUp
            } else {
                TerrainClass::StairsDown
            },
            step_height_m: rise.abs() as f32,
            step_depth_m: if along_u { r.depth_after } else { r.depth_before } as f32,
            yaw_rad: wrap_angle(yaw - travel) as f32,
        }
    }

    /// The riser [`Self::truth`] describes for a robot at (x, y) with heading `yaw`: the nearest
    /// one ahead inside the look-ahead box (smallest x ≥ 0 of its clipped midpoint, robot frame),
    /// else the nearest behind; `None` when no riser is in the box (the label is flat).
    pub fn labelled_riser(&self, x: f64, y: f64, yaw: f64) -> Option<LabelledRiser> {
        let st = self.stairs.as_ref()?;
        let (c, s) = (yaw.cos(), yaw.sin());
        let to_robot = |p: [f64; 2]| {
            let (dx, dy) = (p[0] - x, p[1] - y);
            [c * dx + s * dy, -s * dx + c * dy]
        };
        let mut ahead: Option<(f64, usize)> = None;
        let mut behind: Option<(f64, usize)> = None;
        for (i, r) in st.risers.iter().enumerate() {
            let (a, b) = st.riser_ends(r.s);
            if let Some(mid_x) = clip_to_lookahead(to_robot(a), to_robot(b)) {
                if mid_x >= 0.0 {
                    if ahead.is_none_or(|(best, _)| mid_x < best) {
                        ahead = Some((mid_x, i));
                    }
                } else if behind.is_none_or(|(best, _)| mid_x > best) {
                    behind = Some((mid_x, i));
                }
            }
        }
        let (mid_x_m, index) = ahead.or(behind)?;
        Some(LabelledRiser {
            index,
            count: st.risers.len(),
            mid_x_m,
        })
    }

    /// The static geoms that make this world in MuJoCo (the floor plane is the model's own).
    pub fn primitives(&self) -> Vec<Primitive> {
        self.stairs.as_ref().map_or_else(Vec::new, Staircase::primitives)
    }

    /// The base's progress over the staircase at world (x, y) (`None` without a staircase): axis
    /// coordinates, risers passed (edge behind the base while the base is within the stair
    /// width) and whether the base is on the end landing ([`sim_hal::bridge::END_LANDING_MARGIN_M`]
    /// past the last riser, not beyond the landing's far end, within the width). Evaluation only.
    pub fn stair_progress(&self, x: f64, y: f64) -> Option<sim_hal::bridge::StairProgress> {
        let st = self.stairs.as_ref()?;
        let (s, t) = st.to_axis(x, y);
        let within = t.abs() <= 0.5 * st.width;
        let passed = if within {
            st.risers.partition_point(|r| r.s < s)
        } else {
            0
        };
        let last = st.risers.last().map_or(0.0, |r| r.s);
        Some(sim_hal::bridge::StairProgress {
            axis_s: s,
            axis_t: t,
            axis_yaw_rad: st.yaw as f32,
            rise_m: (st.levels.last().copied().unwrap_or(0.0) - st.levels[0]) as f32,
            risers: st.risers.len().min(u16::MAX as usize) as u16,
            risers_passed: passed.min(u16::MAX as usize) as u16,
            on_end_landing: within && s >= last + sim_hal::bridge::END_LANDING_MARGIN_M && s <= st.end_s,
        })
    }

    /// Where the robot starts: (x, y, ground height, yaw).
    pub fn start(&self) -> [f64; 4] {
        [0.0, 0.0, self.ground_height(0.0, 0.0), 0.0]
    }
}

/// Which riser a ground-truth token describes (see [`World::labelled_riser`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct LabelledRiser {
    /// Index along the staircase axis (0 = the first riser from the start landing).
    pub index: usize,
    /// Risers in the staircase.
    pub count: usize,
    /// Robot-frame x of the riser's midpoint clipped to the look-ahead box, m (< 0: behind).
    pub mid_x_m: f64,
}

/// Clips segment a–b (robot frame) to the look-ahead box; the clipped midpoint's x, if any part is
/// inside (Liang–Barsky).
fn clip_to_lookahead(a: [f64; 2], b: [f64; 2]) -> Option<f64> {
    let (mut t0, mut t1) = (0.0f64, 1.0f64);
    let d = [b[0] - a[0], b[1] - a[1]];
    let bounds = [
        (-d[0], a[0] - LOOKAHEAD_X.0),
        (d[0], LOOKAHEAD_X.1 - a[0]),
        (-d[1], a[1] + LOOKAHEAD_HALF_Y),
        (d[1], LOOKAHEAD_HALF_Y - a[1]),
    ];
    for (p, q) in bounds {
        if p == 0.0 {
            if q < 0.0 {
                return None;
            }
        } else {
            let t = q / p;
            if p < 0.0 {
                t0 = t0.max(t);
            } else {
                t1 = t1.min(t);
            }
        }
    }
    (t0 <= t1).then(|| a[0] + d[0] * 0.5 * (t0 + t1))
}

impl Staircase {
    fn layout(spec: &TerrainSpec) -> Staircase {
        let n = spec.steps;
        let mut rng = Rng(spec.outdoor.map_or(0, |o| o.seed) ^ 0xA5A5_5A5A);
        let (mut heights, mut depths, mut slopes) =
            (vec![spec.step_height; n], vec![spec.step_depth; n], vec![0.0; n + 1]);
        if let Some(o) = &spec.outdoor {
            for i in 0..n {
                heights[i] *= 1.0 + rng.range(-o.height_jitter, o.height_jitter);
                depths[i] *= 1.0 + rng.range(-o.depth_jitter, o.depth_jitter);
            }
            // Treads only (not the landings): a slope on a landing would move the robot's start.
            for s in slopes.iter_mut().take(n).skip(1) {
                *s = rng.range(-o.tread_slope_deg, o.tread_slope_deg).to_radians();
            }
        }
        let up = spec.kind == TerrainKind::StairsUp;
        let total: f64 = heights.iter().sum();
        let mut levels = Vec::with_capacity(n + 1);
        levels.push(if up { 0.0 } else { total });
        for h in &heights {
            let last = *levels.last().expect("non-empty");
            levels.push(if up { last + h } else { (last - h).max(0.0) });
        }
        let mut risers = Vec::with_capacity(n);
        let mut s = 0.0;
        for i in 0..n {
            risers.push(Riser {
                s,
                level_before: levels[i],
                level_after: levels[i + 1],
                depth_after: depths[i],
                depth_before: if i == 0 { depths[0] } else { depths[i - 1] },
            });
            s += depths[i];
        }
        // The last riser's tread runs into the end landing.
        let last_s = risers.last().map_or(0.0, |r| r.s);
        let yaw = spec.yaw_deg.to_radians();
        let (u, v) = ([yaw.cos(), yaw.sin()], [-yaw.sin(), yaw.cos()]);
        Staircase {
            origin: [
                u[0] * spec.start_distance + v[0] * spec.lateral_offset,
                u[1] * spec.start_distance + v[1] * spec.lateral_offset,
            ],
            yaw,
            width: spec.width,
            risers,
            slopes,
            levels,
            landing_before: spec.landing_before,
            end_s: last_s + spec.landing_after,
            nosing_radius: spec.outdoor.map_or(0.0, |o| o.nosing_radius),
        }
    }

    /// World point → axis coordinates (s along u from the first riser, t to the left).
    pub fn to_axis(&self, x: f64, y: f64) -> (f64, f64) {
        let (c, s) = (self.yaw.cos(), self.yaw.sin());
        let (dx, dy) = (x - self.origin[0], y - self.origin[1]);
        (c * dx + s * dy, -s * dx + c * dy)
    }

    fn to_world(&self, s_ax: f64, t: f64) -> [f64; 2] {
        let (c, s) = (self.yaw.cos(), self.yaw.sin());
        [self.origin[0] + c * s_ax - s * t, self.origin[1] + s * s_ax + c * t]
    }

    fn riser_ends(&self, s: f64) -> ([f64; 2], [f64; 2]) {
        (self.to_world(s, -0.5 * self.width), self.to_world(s, 0.5 * self.width))
    }

    /// Axis range of level segment `k` (0 = start landing, n = end landing).
    fn segment(&self, k: usize) -> (f64, f64) {
        let n = self.risers.len();
        let a = if k == 0 {
            -self.landing_before
        } else {
            self.risers[k - 1].s
        };
        let b = if k == n { self.end_s } else { self.risers[k].s };
        (a, b)
    }

    /// The segment's top surface starts at its level at the nosing end (the riser edge that is up)
    /// and slopes from there.
    fn pivot(&self, k: usize) -> f64 {
        let (a, b) = self.segment(k);
        let lvl = self.levels[k];
        // Rising into this segment (level higher than the previous one): the nosing is at its start.
        let rising_in = k > 0 && lvl > self.levels[k - 1];
        if rising_in || k == self.risers.len() {
            a
        } else {
            b
        }
    }

    pub fn height_at(&self, x: f64, y: f64) -> f64 {
        let (s, t) = self.to_axis(x, y);
        if t.abs() > 0.5 * self.width || s < -self.landing_before || s > self.end_s {
            return 0.0;
        }
        let k = self.risers.partition_point(|r| r.s <= s);
        let pivot = self.pivot(k);
        let sign = if pivot == self.segment(k).0 { 1.0 } else { -1.0 };
        (self.levels[k] + sign * (s - pivot) * self.slopes[k].tan()).max(0.0)
    }

    fn primitives(&self) -> Vec<Primitive> {
        let mut out = Vec::new();
        let half_w = 0.5 * self.width;
        let yaw_q = quat_z(self.yaw);
        let r = self.nosing_radius;
        for k in 0..self.levels.len() {
            let lvl = self.levels[k];
            if lvl <= 1e-9 {
                continue;
            }
            let (a, b) = self.segment(k);
            // Rounded nosings: the riser edges of this (higher) segment get a cylinder, and the box
            // steps back by r above `lvl − r`.
            let prev_lower = k > 0 && self.levels[k - 1] < lvl;
            let next_lower = k < self.risers.len() && self.levels[k + 1] < lvl;
            let (mut a_top, mut b_top) = (a, b);
            if r > 0.0 {
                if prev_lower {
                    a_top = a + r;
                    out.push(self.cylinder(a + r, lvl - r, r, half_w, yaw_q));
                }
                if next_lower {
                    b_top = b - r;
                    out.push(self.cylinder(b - r, lvl - r, r, half_w, yaw_q));
                }
            }
            let slope = self.slopes[k];
            if slope != 0.0 {
                // A slab on top pivoting at the nosing; the body below it reaches just under.
                let pivot = self.pivot(k);
                let sign = if pivot == a { 1.0 } else { -1.0 };
                let (len, thick) = (b_top - a_top, 0.06);
                let mid = 0.5 * (a_top + b_top);
                let top_mid = lvl + sign * (mid - pivot) * slope.tan();
                // Normal of the top surface in (s, z): (−sign·sinα, cosα); centre thick/2 below it.
                let ang = sign * slope;
                let centre_s = mid + 0.5 * thick * ang.sin();
                let centre_z = top_mid - 0.5 * thick * ang.cos();
                let c = self.to_world(centre_s, 0.0);
                // Rotation about the stair's lateral axis v by −ang (a rise along +u is a negative
                // rotation about +v = left).
                let q = quat_mul(yaw_q, quat_y(-ang));
                out.push(Primitive::Box {
                    pos: [c[0], c[1], centre_z],
                    quat: q,
                    half: [0.5 * len / ang.cos(), half_w, 0.5 * thick],
                });
                let body_top = lvl.min(top_mid.min(lvl + sign * (b_top - pivot) * slope.tan())) - 0.5 * thick;
                if body_top > 1e-6 {
                    out.push(self.slab(a, b, body_top, half_w, yaw_q));
                }
            } else {
                if r > 0.0 && (prev_lower || next_lower) {
                    out.push(self.slab(a_top, b_top, lvl, half_w, yaw_q));
                    if lvl - r > 1e-6 {
                        out.push(self.slab(a, b, lvl - r, half_w, yaw_q));
                    }
                    continue;
                }
                out.push(self.slab(a, b, lvl, half_w, yaw_q));
            }
        }
        out
    }

    /// A box from the floor to `top` over axis range [a, b].
    fn slab(&self, a: f64, b: f64, top: f64, half_w: f64, yaw_q: [f64; 4]) -> Primitive {
        let c = self.to_world(0.5 * (a + b), 0.0);
        Primitive::Box {
            pos: [c[0], c[1], 0.5 * top],
            quat: yaw_q,
            half: [0.5 * (b - a), half_w, 0.5 * top],
        }
    }

    fn cylinder(&self, s: f64, z: f64, radius: f64, half_w: f64, yaw_q: [f64; 4]) -> Primitive {
        let c = self.to_world(s, 0.0);
        // A cylinder's axis is its local z; turn it onto the stair's lateral axis.
        Primitive::Cylinder {
            pos: [c[0], c[1], z],
            quat: quat_mul(yaw_q, quat_x(-0.5 * PI)),
            radius,
            half_len: half_w,
        }
    }
}

fn quat_z(a: f64) -> [f64; 4] {
    [(0.5 * a).cos(), 0.0, 0.0, (0.5 * a).sin()]
}
fn quat_y(a: f64) -> [f64; 4] {
    [(0.5 * a).cos(), 0.0, (0.5 * a).sin(), 0.0]
}
fn quat_x(a: f64) -> [f64; 4] {
    [(0.5 * a).cos(), (0.5 * a).sin(), 0.0, 0.0]
}
