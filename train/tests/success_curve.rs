//! `g1-train success-curve`: the figure and table of stair success through `g1fw eval` against
//! env steps, from report files as `g1fw eval --report` writes them.
use std::collections::BTreeMap;

use firmware::eval::{EvalReport, Row};
use train::ppo::success_curve::{self, CurvePoint};

fn row(kind: &str, cm: u32, successes: u64, episodes: u64) -> Row {
    Row {
        kind: kind.into(),
        step_height_cm: cm,
        episodes,
        successes,
        success_rate: successes as f64 / episodes as f64,
        causes: BTreeMap::new(),
        failed_off_side: 0,
        mean_risers_passed: 0.0,
    }
}

fn report(seed: u64, cells: &[(&str, u32, u64)], per_cell: u64) -> EvalReport {
    let table: Vec<Row> = cells.iter().map(|&(k, cm, s)| row(k, cm, s, per_cell)).collect();
    let successes = table.iter().map(|r| r.successes).sum();
    let episodes = table.iter().map(|r| r.episodes).sum();
    EvalReport {
        spec: "specs/stairs/g1_stairs_lstm.toml".into(),
        model: "g1-12dof".into(),
        terrain_source: "cnn".into(),
        physics: "deploy".into(),
        vx: 0.5,
        time_limit_s: 20.0,
        seed,
        episodes,
        successes,
        success_rate: successes as f64 / episodes as f64,
        causes: BTreeMap::new(),
        table,
        results: Vec::new(),
        wall_s: 1.0,
        interrupted: false,
        episodes_planned: episodes,
    }
}

/// A scratch directory of its own per test (removed when dropped).
struct Scratch(std::path::PathBuf);

impl Scratch {
    fn new(name: &str) -> Self {
        let d = std::env::temp_dir().join(format!("g1_success_curve_{name}_{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        Self(d)
    }
    fn path(&self) -> &std::path::Path {
        &self.0
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn point(label: &str, steps: f64, r: EvalReport) -> CurvePoint {
    CurvePoint {
        env_steps: steps,
        label: label.into(),
        report: r,
    }
}

#[test]
fn table_counts_each_height_and_kind_against_the_paper() {
    let r = report(
        300,
        &[("down", 12, 7), ("down", 16, 6), ("up", 12, 4), ("up", 16, 0)],
        10,
    );
    let up = success_curve::tally(&r, Some("up"));
    let both = success_curve::tally(&r, None);
    assert_eq!((up.successes, up.episodes), (4, 20));
    assert_eq!((both.successes, both.episodes), (17, 40));
    let md = success_curve::markdown_table(&r);
    assert!(
        md.contains("| 12 cm | 4/10 (40 %) | 7/10 (70 %) | 11/20 (55 %) | 99.7 % |"),
        "{md}"
    );
    assert!(
        md.contains("| 16 cm | 0/10 (0 %) | 6/10 (60 %) | 6/20 (30 %) | 97.5 % |"),
        "{md}"
    );
    assert!(
        md.contains("| all | 4/20 (20 %) | 13/20 (65 %) | 17/40 (42 %) | |"),
        "{md}"
    );
}

#[test]
fn points_from_different_evaluations_are_refused_and_equal_ones_plotted_in_step_order() {
    let cells = |a, b| [("down", 12, a), ("up", 12, b)];
    let mut mixed = vec![
        point("a", 10e6, report(300, &cells(3, 1), 10)),
        point("b", 20e6, report(301, &cells(5, 2), 10)),
    ];
    let e = success_curve::check_points(&mut mixed).unwrap_err().to_string();
    assert!(e.contains("different evaluation") && e.contains("seed 301"), "{e}");

    let mut fewer = vec![
        point("a", 10e6, report(300, &cells(3, 1), 10)),
        point("b", 20e6, report(300, &cells(5, 2), 4)),
    ];
    assert!(success_curve::check_points(&mut fewer).is_err());

    // The training physics profile is another evaluation, not another point of the curve.
    let mut lean = report(300, &cells(5, 2), 10);
    lean.physics = "training".into();
    let mut physics = vec![point("a", 10e6, report(300, &cells(3, 1), 10)), point("b", 20e6, lean)];
    let e = success_curve::check_points(&mut physics).unwrap_err().to_string();
    assert!(e.contains("physics training") && e.contains("--sim-physics"), "{e}");

    let mut ok = vec![
        point("late", 20e6, report(300, &cells(5, 2), 10)),
        point("early", 10e6, report(300, &cells(3, 1), 10)),
    ];
    success_curve::check_points(&mut ok).unwrap();
    assert_eq!(ok[0].label, "early");

    let dir = Scratch::new("png");
    let png = dir.path().join("curve.png");
    let big = report(7, &cells(60, 20), 100);
    train::plot::success_curve_png(&png, &ok, &big).unwrap();
    let bytes = std::fs::read(&png).unwrap();
    assert!(
        bytes.starts_with(b"\x89PNG") && bytes.len() > 10_000,
        "{} bytes",
        bytes.len()
    );
    assert!(train::plot::success_curve_png(&dir.path().join("curve.svg"), &ok, &big).is_err());
}

#[test]
fn report_files_load_and_bad_ones_say_what_they_are() {
    let dir = Scratch::new("load");
    let good = dir.path().join("eval.json");
    std::fs::write(&good, serde_json::to_string(&report(0, &[("up", 14, 2)], 10)).unwrap()).unwrap();
    let r = success_curve::load_report(&good).unwrap();
    assert_eq!(r.table[0].step_height_cm, 14);

    // Reports written before `physics` existed ran the deploy profile.
    let mut old: serde_json::Value = serde_json::to_value(report(0, &[("up", 14, 2)], 10)).unwrap();
    old.as_object_mut().unwrap().remove("physics");
    let old_path = dir.path().join("old.json");
    std::fs::write(&old_path, old.to_string()).unwrap();
    assert_eq!(success_curve::load_report(&old_path).unwrap().physics, "deploy");

    let flat_only = dir.path().join("flat.json");
    std::fs::write(
        &flat_only,
        serde_json::to_string(&report(0, &[("flat", 0, 1)], 1)).unwrap(),
    )
    .unwrap();
    let e = format!("{:#}", success_curve::load_report(&flat_only).unwrap_err());
    assert!(e.contains("no staircase episodes"), "{e}");

    let junk = dir.path().join("junk.json");
    std::fs::write(&junk, "{\"model\": 3}").unwrap();
    let e = format!("{:#}", success_curve::load_report(&junk).unwrap_err());
    assert!(e.contains("is not a `g1fw eval --report` JSON file"), "{e}");
}
