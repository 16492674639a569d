//! `g1-train success-curve`: stair success through `g1fw eval` against env steps, as a PNG and a
//! markdown table against the paper.
use std::path::PathBuf;

use anyhow::Context;
use train::ppo::success_curve::{self, CurvePoint};

#[derive(clap::Args, Debug)]
pub struct Args {
    /// One actor's evaluation: `[LABEL@]STEPS=REPORT.json`, STEPS the env steps behind the actor
    /// (e.g. 82.9M), REPORT a `g1fw eval --report` file. Repeat it; every point must come from the
    /// same evaluation (model, token source, vx, seed, heights and episodes per cell)
    #[arg(long = "point", required = true)]
    points: Vec<String>,
    /// A larger `g1fw eval` report for the per-height panel and table (default: the last point's)
    #[arg(long)]
    table: Option<PathBuf>,
    /// The figure to write (PNG)
    #[arg(long, default_value = "out/stair_success.png")]
    out: PathBuf,
    /// Also write the per-height table (markdown) here; it is always printed
    #[arg(long)]
    markdown: Option<PathBuf>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let reports: Vec<std::path::PathBuf> = args
        .points
        .iter()
        .map(|a| success_curve::parse_point_arg(a).map(|(_, _, p)| p))
        .collect::<anyhow::Result<_>>()?;
    let mut inputs: Vec<(&str, Option<&std::path::Path>)> =
        reports.iter().map(|p| ("a report", Some(p.as_path()))).collect();
    inputs.push(("--table", args.table.as_deref()));
    crate::outputs::refuse_clashes(
        &[
            ("--out", Some(&args.out), crate::outputs::Kind::File),
            ("--markdown", args.markdown.as_deref(), crate::outputs::Kind::File),
        ],
        &inputs,
        None,
    )?;
    let mut points = Vec::with_capacity(args.points.len());
    for arg in &args.points {
        let (label, env_steps, path) = success_curve::parse_point_arg(arg)?;
        let report = success_curve::load_report(&path)?;
        points.push(CurvePoint {
            env_steps,
            label,
            report,
        });
    }
    success_curve::check_points(&mut points)?;
    let table = match &args.table {
        Some(p) => success_curve::load_report(p)?,
        None => points.last().expect("checked: at least one point").report.clone(),
    };
    if let Some(dir) = args.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    train::plot::success_curve_png(&args.out, &points, &table)?;
    for p in &points {
        let t = success_curve::tally(&p.report, None);
        println!(
            "{:>8.1} M  {:<24} {}/{} ({:.1} %)",
            p.env_steps / 1e6,
            p.label,
            t.successes,
            t.episodes,
            t.percent().unwrap_or(0.0)
        );
    }
    let md = success_curve::markdown_table(&table);
    println!("\n{md}");
    if let Some(path) = &args.markdown {
        std::fs::write(path, &md).with_context(|| format!("writing {}", path.display()))?;
    }
    println!("wrote {}", args.out.display());
    Ok(())
}
