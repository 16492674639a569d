//! Stair success against env steps, measured through `g1fw eval` (issue 29: while the policy falls
//! short of the paper, docs/results.md shows the per-height table and this curve, so the gap reads at a
//! glance). Each point is one `g1fw eval` report of one actor; every point must come from the same
//! evaluation (model, token source, command, seed, heights, episodes per cell), or the curve would
//! compare different tests.
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{bail, ensure, Context, Result};
use firmware::eval::EvalReport;

/// The paper's success on randomised stairs per riser height (cm, %): the bar issue 29 sets.
pub const PAPER_SUCCESS: [(u32, f64); 6] = [(12, 99.7), (14, 99.4), (16, 97.5), (18, 92.3), (20, 87.6), (22, 82.7)];

/// The paper's success at `height_cm`, if it reports one.
pub fn paper_success(height_cm: u32) -> Option<f64> {
    PAPER_SUCCESS.iter().find(|p| p.0 == height_cm).map(|p| p.1)
}

/// One actor's evaluation at a point of training.
#[derive(Clone, Debug)]
pub struct CurvePoint {
    /// Env steps of training behind the actor (the whole chain of warm starts).
    pub env_steps: f64,
    pub label: String,
    pub report: EvalReport,
}

/// Successes and episodes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Tally {
    pub successes: u64,
    pub episodes: u64,
}

impl Tally {
    pub fn percent(self) -> Option<f64> {
        (self.episodes > 0).then(|| 100.0 * self.successes as f64 / self.episodes as f64)
    }

    /// The Wilson score interval at 95 % (percent): with 10 episodes a cell, one success more or
    /// less is 10 points, so the curve shows how far apart two points really are.
    pub fn wilson95(self) -> Option<(f64, f64)> {
        if self.episodes == 0 {
            return None;
        }
        let n = self.episodes as f64;
        let p = self.successes as f64 / n;
        let z = 1.96_f64;
        let centre = (p + z * z / (2.0 * n)) / (1.0 + z * z / n);
        let half = z * (p * (1.0 - p) / n + z * z / (4.0 * n * n)).sqrt() / (1.0 + z * z / n);
        Some((100.0 * (centre - half).max(0.0), 100.0 * (centre + half).min(1.0)))
    }
}

/// The report's stair rows of `kind` (`up`, `down`, or both for `None`), summed.
pub fn tally(report: &EvalReport, kind: Option<&str>) -> Tally {
    report
        .table
        .iter()
        .filter(|r| r.kind != "flat" && kind.is_none_or(|k| r.kind == k))
        .fold(Tally::default(), |t, r| Tally {
            successes: t.successes + r.successes,
            episodes: t.episodes + r.episodes,
        })
}

/// Per riser height (cm): up and down.
pub fn by_height(report: &EvalReport) -> BTreeMap<u32, (Tally, Tally)> {
    let mut out: BTreeMap<u32, (Tally, Tally)> = BTreeMap::new();
    for r in report.table.iter().filter(|r| r.kind != "flat") {
        let e = out.entry(r.step_height_cm).or_default();
        let t = if r.kind == "up" { &mut e.0 } else { &mut e.1 };
        t.successes += r.successes;
        t.episodes += r.episodes;
    }
    out
}

/// Env steps written as `82.9M`, `500k`, `1.2e6` or `1200000`.
pub fn parse_steps(s: &str) -> Result<f64> {
    let t = s.trim();
    let (num, mult) = match t.chars().last() {
        Some('M' | 'm') => (&t[..t.len() - 1], 1e6),
        Some('k' | 'K') => (&t[..t.len() - 1], 1e3),
        Some('G' | 'g' | 'B' | 'b') => (&t[..t.len() - 1], 1e9),
        _ => (t, 1.0),
    };
    let v: f64 = num
        .parse()
        .with_context(|| format!("env steps {s:?}: expected a number like 82.9M, 500k or 1.2e6"))?;
    ensure!(v.is_finite() && v >= 0.0, "env steps {s:?} must be a finite number ≥ 0");
    Ok(v * mult)
}

/// `[LABEL@]STEPS=REPORT.json` → (label, env steps, report path); the label defaults to the
/// report's file stem.
pub fn parse_point_arg(arg: &str) -> Result<(String, f64, PathBuf)> {
    let Some((head, path)) = arg.split_once('=') else {
        bail!("--point {arg:?}: expected [LABEL@]STEPS=REPORT.json, e.g. \"run 14@82.9M=out/eval.json\"");
    };
    let (label, steps) = match head.rsplit_once('@') {
        Some((l, s)) => (Some(l.to_string()), s),
        None => (None, head),
    };
    let path = PathBuf::from(path);
    let label = label.unwrap_or_else(|| {
        path.file_stem()
            .map_or_else(|| path.display().to_string(), |s| s.to_string_lossy().into_owned())
    });
    Ok((label, parse_steps(steps)?, path))
}

/// Reads a `g1fw eval --report` file.
pub fn load_report(path: &Path) -> Result<EvalReport> {
    let text = input_file::read_text_capped(path, crate::MAX_TEXT_BYTES)
        .with_context(|| format!("reading {}", path.display()))?;
    let report: EvalReport = serde_json::from_str(&text)
        .with_context(|| format!("{} is not a `g1fw eval --report` JSON file", path.display()))?;
    ensure!(
        report.table.iter().any(|r| r.kind != "flat"),
        "{} has no staircase episodes: run `g1fw eval --heights ... --kinds up,down`",
        path.display()
    );
    Ok(report)
}

/// What must be equal for two reports to be points of one curve.
fn protocol(r: &EvalReport) -> String {
    let cells: Vec<String> = r
        .table
        .iter()
        .map(|row| format!("{} {} cm × {}", row.kind, row.step_height_cm, row.episodes))
        .collect();
    format!(
        "model {}, token {}, physics {}, vx {}, seed {}, time limit {} s, cells [{}]",
        r.model,
        r.terrain_source,
        r.physics,
        r.vx,
        r.seed,
        r.time_limit_s,
        cells.join(", ")
    )
}

/// Checks that every point ran the same evaluation, and orders them by env steps.
pub fn check_points(points: &mut [CurvePoint]) -> Result<()> {
    ensure!(
        !points.is_empty(),
        "no points: give --point STEPS=REPORT.json at least once"
    );
    let first = protocol(&points[0].report);
    for p in points.iter() {
        ensure!(
            !p.report.interrupted,
            "point {:?}: its evaluation was interrupted",
            p.label
        );
        let this = protocol(&p.report);
        ensure!(
            this == first,
            "point {:?} ran a different evaluation than {:?}:\n  {this}\n  {first}\nrerun `g1fw eval` with the same \
             --model, --terrain-source, --sim-physics, --vx, --seed, --heights, --kinds and --episodes-per-height",
            p.label,
            points[0].label
        );
    }
    points.sort_by(|a, b| a.env_steps.total_cmp(&b.env_steps));
    Ok(())
}

/// The per-height table against the paper (markdown), with the evaluation it came from.
pub fn markdown_table(report: &EvalReport) -> String {
    let cell = |t: Tally| match t.percent() {
        Some(p) => format!("{}/{} ({p:.0} %)", t.successes, t.episodes),
        None => "–".to_string(),
    };
    let mut s = String::from("| riser | up | down | up and down | paper |\n|---|---|---|---|---|\n");
    for (h, (up, down)) in by_height(report) {
        let both = Tally {
            successes: up.successes + down.successes,
            episodes: up.episodes + down.episodes,
        };
        let paper = paper_success(h).map_or("–".to_string(), |p| format!("{p} %"));
        s += &format!(
            "| {h} cm | {} | {} | {} | {paper} |\n",
            cell(up),
            cell(down),
            cell(both)
        );
    }
    s += &format!(
        "| all | {} | {} | {} | |\n",
        cell(tally(report, Some("up"))),
        cell(tally(report, Some("down"))),
        cell(tally(report, None))
    );
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn steps_take_suffixes_and_refuse_garbage() {
        assert_eq!(parse_steps("82.9M").unwrap(), 82.9e6);
        assert_eq!(parse_steps("500k").unwrap(), 500e3);
        assert_eq!(parse_steps("1.2e6").unwrap(), 1.2e6);
        assert!(parse_steps("fast").is_err());
        assert!(parse_steps("-3M").is_err());
        let (label, steps, path) = parse_point_arg("run 14@82.9M=out/a.json").unwrap();
        assert_eq!(
            (label.as_str(), steps, path),
            ("run 14", 82.9e6, PathBuf::from("out/a.json"))
        );
        let (label, _, _) = parse_point_arg("10M=out/b.json").unwrap();
        assert_eq!(label, "b");
        assert!(parse_point_arg("out/b.json").is_err());
    }

    #[test]
    fn wilson_interval_brackets_the_rate() {
        let t = Tally {
            successes: 3,
            episodes: 10,
        };
        let (lo, hi) = t.wilson95().unwrap();
        assert!(lo < 30.0 && 30.0 < hi, "{lo} {hi}");
        assert!((lo - 10.8).abs() < 0.1 && (hi - 60.3).abs() < 0.1, "{lo} {hi}");
        let none = Tally {
            successes: 0,
            episodes: 10,
        };
        assert_eq!(none.wilson95().unwrap().0, 0.0);
        assert_eq!(Tally::default().wilson95(), None);
    }
}
