//! Evaluation on rendered worlds: the exported CNN (run by the firmware's executor, exactly as on
//! the robot) next to the geometric baseline, on the same grids.
use std::path::Path;

use crate::cnn::dataset::{render_worlds, token_array, DatasetConfig, EvalStats, WorldSet};
use control::terrain_net::TerrainNet;
use estimator::terrain::{GeometricTerrainConfig, GeometricTerrainEstimator};
use hal::TerrainToken;
use serde::Serialize;

/// Errors of one estimator, in the report's shape.
#[derive(Clone, Debug, Serialize)]
pub struct Summary {
    /// Over all samples (flat counts as h = d = 0, as the paper's flat token), cm.
    pub mae_h_cm: f64,
    pub mae_d_cm: f64,
    /// Over samples whose true class is stairs, degrees.
    pub mae_yaw_deg: f64,
    pub class_acc: f64,
    /// h and d over stairs samples only, cm (the stricter reading).
    pub mae_h_cm_stairs: f64,
    pub mae_d_cm_stairs: f64,
    pub samples: usize,
    pub stairs_samples: usize,
    /// `confusion[true][predicted]`: flat, stairs-up, stairs-down.
    pub confusion: [[usize; 3]; 3],
}

impl Summary {
    pub fn of(s: &EvalStats) -> Self {
        Summary {
            mae_h_cm: s.mae_h_cm,
            mae_d_cm: s.mae_d_cm,
            mae_yaw_deg: s.mae_yaw_deg,
            class_acc: s.class_accuracy,
            mae_h_cm_stairs: s.mae_h_cm_stairs,
            mae_d_cm_stairs: s.mae_d_cm_stairs,
            samples: s.samples,
            stairs_samples: s.stairs_samples,
            confusion: s.confusion,
        }
    }
}

/// One evaluated sample (for the plot and the report).
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Record {
    pub world_seed: u64,
    /// class, h, d, yaw.
    pub truth: [f32; 4],
    pub cnn: [f32; 4],
    pub baseline: [f32; 4],
    /// Where the robot stood: pelvis world x, y (m) and heading (rad).
    pub pose: [f64; 3],
    /// The riser the truth describes (none on flat labels): its index, the staircase's riser
    /// count and its robot-frame distance ahead (m, < 0 behind): finds the hard cases.
    pub riser: Option<(usize, usize, f64)>,
    /// The world is the outdoor variant (per-step jitter, sloped treads, rounded nosings).
    pub outdoor: bool,
    /// The robot was walking (else standing).
    pub walking: bool,
    /// Keyframes in the BEV memory (0: a single-frame grid).
    pub keyframes: usize,
}

/// The report `--report` writes.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    pub cnn: Summary,
    pub baseline: Summary,
    pub worlds: usize,
    pub poses_per_world: usize,
    pub world_set: String,
    pub cnn_weights_sha256: String,
    /// Errors of stairs samples binned by true step height (`lo`, `hi` in m).
    pub by_step_height: Vec<Bin>,
    /// Errors of stairs samples binned by the labelled riser's robot-frame distance ahead (`lo`,
    /// `hi` in m; negative: behind).
    pub by_riser_ahead: Vec<Bin>,
    pub seconds: f64,
    pub records: Vec<Record>,
}

/// Errors of the stairs samples whose binned quantity (see the report field) falls in `[lo, hi)`.
#[derive(Clone, Debug, Serialize)]
pub struct Bin {
    pub lo: f32,
    pub hi: f32,
    pub samples: usize,
    pub cnn: BinErr,
    pub baseline: BinErr,
}

#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct BinErr {
    pub mae_h_cm: f64,
    pub mae_d_cm: f64,
    pub mae_yaw_deg: f64,
    pub class_acc: f64,
}

/// Stairs samples binned by `key` (none: left out) at `edges`.
fn bin_stairs(records: &[Record], edges: &[f32], key: impl Fn(&Record) -> Option<f32>) -> Vec<Bin> {
    edges
        .windows(2)
        .map(|w| {
            let inside: Vec<&Record> = records
                .iter()
                .filter(|r| r.truth[0] != 0.0 && key(r).is_some_and(|k| k >= w[0] && k < w[1]))
                .collect();
            let err = |pick: fn(&Record) -> [f32; 4]| {
                let n = inside.len().max(1) as f64;
                let mut e = BinErr::default();
                for r in &inside {
                    let p = pick(r);
                    e.mae_h_cm += 100.0 * (p[1] - r.truth[1]).abs() as f64 / n;
                    e.mae_d_cm += 100.0 * (p[2] - r.truth[2]).abs() as f64 / n;
                    e.mae_yaw_deg += hal::wrap_angle((p[3] - r.truth[3]) as f64).abs().to_degrees() / n;
                    e.class_acc += if p[0] == r.truth[0] { 1.0 / n } else { 0.0 };
                }
                e
            };
            Bin {
                lo: w[0],
                hi: w[1],
                samples: inside.len(),
                cnn: err(|r| r.cnn),
                baseline: err(|r| r.baseline),
            }
        })
        .collect()
}

/// Bins of 2 cm of true step height from 4 to 26 cm.
pub fn bin_by_height(records: &[Record]) -> Vec<Bin> {
    let edges: Vec<f32> = (0..=11).map(|k| 0.04 + 0.02 * k as f32).collect();
    bin_stairs(records, &edges, |r| Some(r.truth[1]))
}

/// Bins of 25 cm of the labelled riser's distance ahead, from 0.5 m behind to the look-ahead
/// box's far edge (1.5 m): where in the box the errors come from.
pub fn bin_by_riser_ahead(records: &[Record]) -> Vec<Bin> {
    let edges: Vec<f32> = (0..=8).map(|k| -0.5 + 0.25 * k as f32).collect();
    // The clipped midpoint lies in the box, [-0.5, 1.5] m: the far edge itself goes in the last bin.
    bin_stairs(records, &edges, |r| r.riser.map(|(_, _, x)| (x as f32).min(1.499_999)))
}

/// Renders `set` and scores the CNN and the geometric baseline on every grid.
pub fn evaluate(
    set: &WorldSet,
    poses_per_world: usize,
    cfg: DatasetConfig,
    jobs: usize,
    net: &mut TerrainNet,
    progress: &dyn Fn(),
) -> anyhow::Result<Report> {
    let t0 = std::time::Instant::now();
    let mut geo = GeometricTerrainEstimator::new(GeometricTerrainConfig::default());
    let (mut cnn, mut base) = (EvalStats::default(), EvalStats::default());
    let mut records = Vec::new();
    let mut worlds = 0;
    render_worlds(set, poses_per_world, cfg, jobs, |wi, seed, s| {
        worlds = worlds.max(wi + 1);
        let heading = s.meta.pose.yaw as f32;
        // A non-finite output (never seen) scores as flat: the firmware would hold its last token.
        let c = net.estimate(&s.bev, heading).unwrap_or(TerrainToken {
            yaw_rad: heading,
            ..TerrainToken::FLAT
        });
        let g = geo.estimate(&s.bev).token;
        cnn.add(&s.truth, &c);
        base.add(&s.truth, &g);
        records.push(Record {
            world_seed: seed,
            truth: token_array(&s.truth),
            cnn: token_array(&c),
            baseline: token_array(&g),
            pose: [s.meta.pelvis[0], s.meta.pelvis[1], s.meta.pose.yaw],
            riser: s.meta.riser.map(|r| (r.index, r.count, r.mid_x_m)),
            outdoor: s.meta.outdoor,
            walking: s.meta.pose.mode == crate::cnn::dataset::Mode::Walking,
            keyframes: s.meta.keyframes,
        });
        progress();
        Ok(())
    })?;
    Ok(Report {
        cnn: Summary::of(&cnn),
        baseline: Summary::of(&base),
        worlds,
        poses_per_world,
        world_set: match set {
            WorldSet::Random { first_seed, count } => {
                format!("random worlds {first_seed}..{}", first_seed + *count as u64)
            }
            WorldSet::Named { args, .. } => args.join(", "),
        },
        cnn_weights_sha256: net.weights_sha256().to_string(),
        by_step_height: bin_by_height(&records),
        by_riser_ahead: bin_by_riser_ahead(&records),
        seconds: t0.elapsed().as_secs_f64(),
        records,
    })
}

impl std::fmt::Display for Report {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "{} ({} worlds × {} poses = {} samples, {} stairs)",
            self.world_set, self.worlds, self.poses_per_world, self.cnn.samples, self.cnn.stairs_samples
        )?;
        writeln!(f, "{:<22} {:>12} {:>12}", "", "CNN", "geometric")?;
        let rows: [(&str, f64, f64); 6] = [
            ("MAE h (cm)", self.cnn.mae_h_cm, self.baseline.mae_h_cm),
            ("MAE d (cm)", self.cnn.mae_d_cm, self.baseline.mae_d_cm),
            ("MAE yaw (deg)", self.cnn.mae_yaw_deg, self.baseline.mae_yaw_deg),
            (
                "class accuracy (%)",
                100.0 * self.cnn.class_acc,
                100.0 * self.baseline.class_acc,
            ),
            (
                "MAE h, stairs (cm)",
                self.cnn.mae_h_cm_stairs,
                self.baseline.mae_h_cm_stairs,
            ),
            (
                "MAE d, stairs (cm)",
                self.cnn.mae_d_cm_stairs,
                self.baseline.mae_d_cm_stairs,
            ),
        ];
        for (name, a, b) in rows {
            writeln!(f, "{name:<22} {a:>12.3} {b:>12.3}")?;
        }
        writeln!(f, "CNN by the labelled riser's distance ahead (stairs samples):")?;
        writeln!(
            f,
            "{:<16} {:>7} {:>8} {:>9} {:>9}",
            "riser ahead (m)", "samples", "class %", "MAE h cm", "MAE d cm"
        )?;
        for b in self.by_riser_ahead.iter().filter(|b| b.samples > 0) {
            writeln!(
                f,
                "{:<16} {:>7} {:>8.2} {:>9.2} {:>9.2}",
                format!("{:+.2} .. {:+.2}", b.lo, b.hi),
                b.samples,
                100.0 * b.cnn.class_acc,
                b.cnn.mae_h_cm,
                b.cnn.mae_d_cm
            )?;
        }
        Ok(())
    }
}

/// Writes the report as JSON.
pub fn write_report(path: &Path, r: &Report) -> anyhow::Result<()> {
    std::fs::write(path, serde_json::to_string_pretty(r)? + "\n")
        .map_err(|e| anyhow::anyhow!("writing {}: {e}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rec(truth: [f32; 4], cnn: [f32; 4], riser: Option<f64>) -> Record {
        Record {
            world_seed: 0,
            truth,
            cnn,
            baseline: truth,
            pose: [0.0; 3],
            riser: riser.map(|x| (0, 4, x)),
            outdoor: false,
            walking: false,
            keyframes: 0,
        }
    }

    #[test]
    fn riser_bins_average_the_stairs_samples_inside_them() {
        let up = [1.0, 0.15, 0.30, 0.0];
        let records = [
            rec(up, [1.0, 0.16, 0.30, 0.0], Some(0.10)), // h off by 1 cm
            rec(up, [1.0, 0.12, 0.34, 0.0], Some(0.20)), // h 3 cm, d 4 cm
            rec(up, [0.0, 0.0, 0.0, 0.0], Some(-0.30)),  // wrong class, behind
            rec(up, [1.0, 0.0, 0.0, 0.0], Some(1.50)),   // on the box's far edge: last bin
            rec([0.0; 4], [1.0, 0.1, 0.1, 0.0], None),   // flat label: not binned
        ];
        let bins = bin_by_riser_ahead(&records);
        assert_eq!(bins.len(), 8);
        assert_eq!((bins[0].lo, bins[7].hi), (-0.5, 1.5));
        assert_eq!(bins.iter().map(|b| b.samples).sum::<usize>(), 4);
        assert_eq!(bins[7].samples, 1);
        let near = &bins[2];
        assert_eq!((near.lo, near.hi, near.samples), (0.0, 0.25, 2));
        assert!((near.cnn.mae_h_cm - 2.0).abs() < 1e-4, "{near:?}");
        assert!((near.cnn.mae_d_cm - 2.0).abs() < 1e-4, "{near:?}");
        assert_eq!(near.cnn.class_acc, 1.0);
        assert_eq!(near.baseline.mae_h_cm, 0.0);
        let behind = &bins[0];
        assert_eq!((behind.samples, behind.cnn.class_acc), (1, 0.0));
    }
}
