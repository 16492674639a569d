//! Evaluation on rendered worlds: the exported CNN (run by the firmware's executor, exactly as on
//! the robot) next to the geometric baseline, on the same grids.
use std::path::Path;

use estimator::terrain::{GeometricTerrainConfig, GeometricTerrainEstimator};
use firmware::terrain_net::TerrainNet;
use g1_sim::dataset::{render_worlds, token_array, DatasetConfig, EvalStats, WorldSet};
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
    /// Errors binned by true step height (stairs samples).
    pub by_step_height: Vec<HeightBin>,
    pub seconds: f64,
    pub records: Vec<Record>,
}

/// Errors of stairs samples whose true h falls in `[h_lo_m, h_hi_m)`.
#[derive(Clone, Debug, Serialize)]
pub struct HeightBin {
    pub h_lo_m: f32,
    pub h_hi_m: f32,
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

/// Bins of 2 cm from 4 to 26 cm.
pub fn bin_by_height(records: &[Record]) -> Vec<HeightBin> {
    let edges: Vec<f32> = (0..=11).map(|k| 0.04 + 0.02 * k as f32).collect();
    edges
        .windows(2)
        .map(|w| {
            let inside: Vec<&Record> = records
                .iter()
                .filter(|r| r.truth[0] != 0.0 && r.truth[1] >= w[0] && r.truth[1] < w[1])
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
            HeightBin {
                h_lo_m: w[0],
                h_hi_m: w[1],
                samples: inside.len(),
                cnn: err(|r| r.cnn),
                baseline: err(|r| r.baseline),
            }
        })
        .collect()
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
        Ok(())
    }
}

/// Writes the report as JSON.
pub fn write_report(path: &Path, r: &Report) -> anyhow::Result<()> {
    std::fs::write(path, serde_json::to_string_pretty(r)? + "\n")
        .map_err(|e| anyhow::anyhow!("writing {}: {e}", path.display()))
}
