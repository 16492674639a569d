//! PNG figures: errors versus true step height (CNN vs geometric baseline) and training curves.
use std::path::Path;

use anyhow::Context;
use plotters::prelude::*;

use crate::cnn::eval::Bin;
use crate::cnn::fit::EpochLog;

const CNN: RGBColor = RGBColor(31, 119, 180);
const BASE: RGBColor = RGBColor(255, 127, 14);
/// Staircases up and down, apart (PPO curves).
const UP: RGBColor = RGBColor(44, 160, 44);
const DOWN: RGBColor = RGBColor(148, 103, 189);
const LIMIT: RGBColor = RGBColor(120, 120, 120);

fn check_png(path: &Path) -> anyhow::Result<()> {
    anyhow::ensure!(
        path.extension().is_some_and(|e| e.eq_ignore_ascii_case("png")),
        "{} must end in .png",
        path.display()
    );
    firmware::plot::ensure_font().map_err(|e| anyhow::anyhow!("{e}"))
}

type Series<'a> = (&'a str, RGBColor, Vec<(f64, f64)>);

fn panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    title: &str,
    x_label: &str,
    (x0, x1): (f64, f64),
    series: &[Series],
    limit: Option<(f64, &str)>,
    log_y: bool,
) -> anyhow::Result<()>
where
    DB::ErrorType: 'static,
{
    let ys = series
        .iter()
        .flat_map(|s| s.2.iter().map(|p| p.1))
        .filter(|v| v.is_finite());
    let (mut lo, mut hi) = ys.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| (a.min(v), b.max(v)));
    if let Some((l, _)) = limit {
        lo = lo.min(l);
        hi = hi.max(l);
    }
    if !lo.is_finite() {
        (lo, hi) = (0.0, 1.0);
    }
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| anyhow::anyhow!("drawing {title}: {e:?}");
    macro_rules! draw {
        ($chart:expr) => {{
            let mut chart = $chart;
            chart
                .configure_mesh()
                .x_desc(x_label)
                .light_line_style(WHITE.mix(0.0))
                .draw()
                .map_err(err)?;
            if let Some((l, name)) = limit {
                chart
                    .draw_series(LineSeries::new([(x0, l), (x1, l)], LIMIT.stroke_width(1)))
                    .map_err(err)?
                    .label(name)
                    .legend(|(x, y)| PathElement::new([(x, y), (x + 16, y)], LIMIT));
            }
            for (name, color, pts) in series {
                let pts: Vec<(f64, f64)> = pts.iter().copied().filter(|p| p.1.is_finite()).collect();
                let c = *color;
                chart
                    .draw_series(LineSeries::new(pts.clone(), c.stroke_width(2)))
                    .map_err(err)?
                    .label(*name)
                    .legend(move |(x, y)| PathElement::new([(x, y), (x + 16, y)], c.stroke_width(2)));
                chart
                    .draw_series(pts.iter().map(|&p| Circle::new(p, 3, c.filled())))
                    .map_err(err)?;
            }
            chart
                .configure_series_labels()
                .background_style(WHITE.mix(0.8))
                .border_style(BLACK)
                .position(SeriesLabelPosition::UpperRight)
                .draw()
                .map_err(err)?;
        }};
    }
    let mut b = ChartBuilder::on(area);
    b.caption(title, ("sans-serif", 20))
        .margin(10)
        .x_label_area_size(35)
        .y_label_area_size(55);
    if log_y {
        let lo = lo.max(1e-3) * 0.8;
        draw!(b.build_cartesian_2d(x0..x1, (lo..hi * 1.25).log_scale()).map_err(err)?);
    } else {
        let pad = 0.08 * (hi - lo).max(1e-6);
        draw!(b.build_cartesian_2d(x0..x1, (lo - pad)..(hi + pad)).map_err(err)?);
    }
    Ok(())
}

/// Four panels (MAE h, MAE d, MAE yaw, class accuracy) over true step height, CNN vs baseline,
/// with the paper's Table II figures as grey lines.
pub fn error_vs_height_png(path: &Path, bins: &[Bin], title: &str) -> anyhow::Result<()> {
    error_bins_png(path, bins, title, "true step height (cm)", 100.0, (4.0, 26.0))
}

/// The same four panels over the labelled riser's distance ahead (m; negative: behind): where in
/// the look-ahead box the errors come from.
pub fn error_vs_riser_png(path: &Path, bins: &[Bin], title: &str) -> anyhow::Result<()> {
    error_bins_png(
        path,
        bins,
        title,
        "labelled riser ahead of the robot (m)",
        1.0,
        (-0.5, 1.5),
    )
}

/// Four panels over binned stairs samples; a bin sits at `scale` × its centre on the x axis.
fn error_bins_png(path: &Path, bins: &[Bin], title: &str, xl: &str, scale: f64, x: (f64, f64)) -> anyhow::Result<()> {
    // Through a temporary file: a failed or killed write leaves an older plot as it was.
    output_file::write_through(path, |tmp| draw_error_bins_png(tmp, bins, title, xl, scale, x))
}

fn draw_error_bins_png(
    path: &Path,
    bins: &[Bin],
    title: &str,
    xl: &str,
    scale: f64,
    x: (f64, f64),
) -> anyhow::Result<()> {
    check_png(path)?;
    let root = BitMapBackend::new(path, (1400, 1000)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let root = root
        .titled(title, ("sans-serif", 24))
        .map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let areas = root.split_evenly((2, 2));
    let used: Vec<&Bin> = bins.iter().filter(|b| b.samples > 0).collect();
    let mid = |b: &Bin| scale * 0.5 * (b.lo + b.hi) as f64;
    let pick = |f: fn(&crate::cnn::eval::BinErr) -> f64| -> [Vec<(f64, f64)>; 2] {
        [
            used.iter().map(|b| (mid(b), f(&b.cnn))).collect(),
            used.iter().map(|b| (mid(b), f(&b.baseline))).collect(),
        ]
    };
    type Panel<'a> = (
        &'a str,
        fn(&crate::cnn::eval::BinErr) -> f64,
        Option<(f64, &'a str)>,
        bool,
    );
    let panels: [Panel; 4] = [
        (
            "MAE step height (cm)",
            |e| e.mae_h_cm,
            Some((0.6, "paper 0.6 cm")),
            true,
        ),
        ("MAE step depth (cm)", |e| e.mae_d_cm, Some((0.7, "paper 0.7 cm")), true),
        ("MAE yaw (deg)", |e| e.mae_yaw_deg, Some((1.8, "paper 1.8°")), true),
        (
            "class accuracy (%)",
            |e| 100.0 * e.class_acc,
            Some((99.1, "paper 99.1 %")),
            false,
        ),
    ];
    for (area, (name, f, limit, log_y)) in areas.iter().zip(panels) {
        let [c, b] = pick(f);
        panel(
            area,
            name,
            xl,
            x,
            &[("CNN", CNN, c), ("geometric", BASE, b)],
            limit,
            log_y,
        )?;
    }
    root.present().with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}

/// Training loss and validation errors per epoch.
pub fn training_png(path: &Path, log: &[EpochLog]) -> anyhow::Result<()> {
    // Through a temporary file: a failed or killed write leaves an older plot as it was.
    output_file::write_through(path, |tmp| draw_training_png(tmp, log))
}

fn draw_training_png(path: &Path, log: &[EpochLog]) -> anyhow::Result<()> {
    check_png(path)?;
    let root = BitMapBackend::new(path, (1400, 1000)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let areas = root.split_evenly((2, 2));
    let x = (0.0, log.len().max(2) as f64 - 1.0);
    let ep = |f: &dyn Fn(&EpochLog) -> Option<f64>| -> Vec<(f64, f64)> {
        log.iter().filter_map(|e| f(e).map(|v| (e.epoch as f64, v))).collect()
    };
    let loss = ep(&|e| Some(e.train.total));
    let ce = ep(&|e| Some(e.train.ce));
    panel(
        &areas[0],
        "training loss",
        "epoch",
        x,
        &[("total", CNN, loss), ("CE", BASE, ce)],
        None,
        true,
    )?;
    let vh = ep(&|e| e.val.as_ref().map(|v| v.mae_h_cm));
    let vd = ep(&|e| e.val.as_ref().map(|v| v.mae_d_cm));
    panel(
        &areas[1],
        "validation MAE (cm)",
        "epoch",
        x,
        &[("h", CNN, vh), ("d", BASE, vd)],
        Some((0.6, "0.6 cm")),
        true,
    )?;
    let vy = ep(&|e| e.val.as_ref().map(|v| v.mae_yaw_deg));
    panel(
        &areas[2],
        "validation MAE yaw (deg)",
        "epoch",
        x,
        &[("yaw", CNN, vy)],
        Some((1.8, "1.8°")),
        true,
    )?;
    let vc = ep(&|e| e.val.as_ref().map(|v| 100.0 * v.class_accuracy));
    panel(
        &areas[3],
        "validation class accuracy (%)",
        "epoch",
        x,
        &[("class", CNN, vc)],
        Some((99.1, "99.1 %")),
        false,
    )?;
    root.present().with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}

/// Exponential moving average, for the smoothed line over a noisy per-iteration series.
fn smooth(pts: &[(f64, f64)], alpha: f64) -> Vec<(f64, f64)> {
    let mut out = Vec::with_capacity(pts.len());
    let mut m: Option<f64> = None;
    for &(x, y) in pts {
        let v = match m {
            Some(prev) => prev + alpha * (y - prev),
            None => y,
        };
        m = Some(v);
        out.push((x, v));
    }
    out
}

/// One PPO panel: every series raw (faint) and smoothed (solid); x ticks read env steps and the
/// wall time at that point (`wall` maps env steps (M) to hours).
fn ppo_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    title: &str,
    (x0, x1): (f64, f64),
    series: &[Series],
    wall: &dyn Fn(f64) -> f64,
    points_only: bool,
    y_range: Option<(f64, f64)>,
) -> anyhow::Result<()>
where
    DB::ErrorType: 'static,
{
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| anyhow::anyhow!("drawing {title}: {e:?}");
    let (lo, hi) = y_range.unwrap_or_else(|| {
        let (lo, hi) = series
            .iter()
            .flat_map(|s| s.2.iter().map(|p| p.1))
            .filter(|v| v.is_finite())
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| (a.min(v), b.max(v)));
        if lo.is_finite() {
            let pad = 0.08 * (hi - lo).max(1e-6);
            (lo - pad, hi + pad)
        } else {
            (0.0, 1.0)
        }
    });
    let mut chart = ChartBuilder::on(area)
        .caption(title, ("sans-serif", 20))
        .margin(10)
        .x_label_area_size(35)
        .y_label_area_size(55)
        .build_cartesian_2d(x0..x1, lo..hi)
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc("env steps (M) / wall time")
        .x_label_formatter(&|x| {
            let h = wall(*x);
            if wall(x1) < 2.0 {
                format!("{x:.1}M / {:.0} min", 60.0 * h)
            } else {
                format!("{x:.1}M / {h:.1} h")
            }
        })
        .x_labels(6)
        .light_line_style(WHITE.mix(0.0))
        .draw()
        .map_err(err)?;
    for (name, color, pts) in series {
        let pts: Vec<(f64, f64)> = pts.iter().copied().filter(|p| p.1.is_finite()).collect();
        let c = *color;
        if points_only {
            chart
                .draw_series(pts.iter().map(|&p| Circle::new(p, 5, c.filled())))
                .map_err(err)?
                .label(*name)
                .legend(move |(x, y)| Circle::new((x + 8, y), 5, c.filled()));
            chart
                .draw_series(LineSeries::new(pts.clone(), c.mix(0.4).stroke_width(1)))
                .map_err(err)?;
            continue;
        }
        chart
            .draw_series(LineSeries::new(pts.clone(), c.mix(0.2).stroke_width(1)))
            .map_err(err)?;
        chart
            .draw_series(LineSeries::new(smooth(&pts, 0.1), c.stroke_width(2)))
            .map_err(err)?
            .label(*name)
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 16, y)], c.stroke_width(2)));
    }
    if series.iter().any(|s| !s.2.is_empty()) {
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .position(SeriesLabelPosition::UpperLeft)
            .draw()
            .map_err(err)?;
    } else {
        chart
            .draw_series(std::iter::once(Text::new(
                if points_only {
                    "no checkpoint judged yet (g1-train ppo --judge-every)"
                } else {
                    "no episode has ended yet"
                },
                (x0 + 0.05 * (x1 - x0), lo + 0.5 * (hi - lo)),
                ("sans-serif", 16),
            )))
            .map_err(err)?;
    }
    Ok(())
}

/// The PPO run at a glance (`curves.png`): reward, stair success and falls, curriculum level,
/// episode return (raw faint, smoothed solid), and the checkpoints judged through `g1fw` (success
/// per kind and step height, points on their own axis, and the flat run's mean speed against its
/// command); x: env steps and wall time.
/// `reference`: the deployed policy judged on the same set, drawn as a level line.
pub fn ppo_curves_png(
    path: &Path,
    log: &[crate::ppo::iter_log::IterLog],
    judged: &[crate::ppo::judge::Judgement],
    reference: Option<&crate::ppo::judge::Judgement>,
) -> anyhow::Result<()> {
    // Through a temporary file: a failed or killed write leaves an older plot as it was.
    output_file::write_through(path, |tmp| draw_ppo_curves_png(tmp, log, judged, reference))
}

fn draw_ppo_curves_png(
    path: &Path,
    log: &[crate::ppo::iter_log::IterLog],
    judged: &[crate::ppo::judge::Judgement],
    reference: Option<&crate::ppo::judge::Judgement>,
) -> anyhow::Result<()> {
    check_png(path)?;
    let root = BitMapBackend::new(path, (1500, 1300)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let areas = root.split_evenly((3, 2));
    let xmax = log.last().map_or(1.0, |l| l.env_steps as f64 / 1e6).max(1e-3);
    let x = (0.0, xmax);
    let series = |f: &dyn Fn(&crate::ppo::iter_log::IterLog) -> Option<f64>| -> Vec<(f64, f64)> {
        log.iter()
            .filter_map(|l| f(l).map(|v| (l.env_steps as f64 / 1e6, v)))
            .collect()
    };
    // Wall time at an env-step count, interpolated from the history.
    let marks: Vec<(f64, f64)> = log
        .iter()
        .map(|l| (l.env_steps as f64 / 1e6, l.wall_s / 3600.0))
        .collect();
    let wall = move |m: f64| -> f64 {
        match marks.iter().position(|p| p.0 >= m) {
            Some(0) => marks[0].1 * m / marks[0].0.max(1e-9),
            Some(i) => {
                let (a, b) = (marks[i - 1], marks[i]);
                a.1 + (b.1 - a.1) * (m - a.0) / (b.0 - a.0).max(1e-9)
            }
            None => marks.last().map_or(0.0, |p| p.1),
        }
    };
    ppo_panel(
        &areas[0],
        "mean reward per policy step",
        x,
        &[("reward/step", CNN, series(&|l| Some(l.mean_reward_per_step)))],
        &wall,
        false,
        None,
    )?;
    ppo_panel(
        &areas[1],
        "training: stair success / falls (%)",
        x,
        &[
            ("success", CNN, series(&|l| l.success_rate.map(|v| 100.0 * v))),
            ("up", UP, series(&|l| l.success_up.map(|v| 100.0 * v))),
            ("down", DOWN, series(&|l| l.success_down.map(|v| 100.0 * v))),
            ("falls (all)", BASE, series(&|l| l.fall_rate.map(|v| 100.0 * v))),
        ],
        &wall,
        false,
        Some((-3.0, 103.0)),
    )?;
    ppo_panel(
        &areas[2],
        "mean terrain level (0: 5 cm … 10: 26 cm)",
        x,
        &[
            ("level", CNN, series(&|l| Some(l.mean_level))),
            ("up", UP, series(&|l| l.level_up)),
            ("down", DOWN, series(&|l| l.level_down)),
        ],
        &wall,
        false,
        None,
    )?;
    ppo_panel(
        &areas[3],
        "episode return",
        x,
        &[("return", CNN, series(&|l| l.mean_episode_return))],
        &wall,
        false,
        None,
    )?;
    // g1fw's verdict: one series per (kind, height) row of the judged set.
    let mut keys: Vec<(String, u32)> = judged
        .iter()
        .flat_map(|j| j.rows.iter().map(|r| (r.0.clone(), r.1)))
        .collect();
    keys.sort();
    keys.dedup();
    let palette = [
        CNN,
        BASE,
        RGBColor(44, 160, 44),
        RGBColor(214, 39, 40),
        RGBColor(148, 103, 189),
        RGBColor(140, 86, 75),
        LIMIT,
    ];
    let names: Vec<String> = keys
        .iter()
        .map(|(k, h)| {
            if k == "flat" {
                "flat".to_string()
            } else {
                format!("{k} {h} cm")
            }
        })
        .collect();
    let mut judged_series: Vec<Series> = keys
        .iter()
        .enumerate()
        .map(|(i, (k, h))| {
            let pts = judged
                .iter()
                .filter_map(|j| {
                    j.rows
                        .iter()
                        .find(|r| &r.0 == k && r.1 == *h)
                        .map(|r| (j.env_steps as f64 / 1e6, 100.0 * r.2 as f64 / (r.3.max(1)) as f64))
                })
                .collect();
            (names[i].as_str(), palette[i % palette.len()], pts)
        })
        .collect();
    // Every stair row together, the run's and the deployed policy's (a level line across).
    let all: Vec<(f64, f64)> = judged
        .iter()
        .map(|j| (j.env_steps as f64 / 1e6, 100.0 * j.stair_success))
        .collect();
    judged_series.push(("all stairs", BLACK, all));
    if let (Some(r), Some(first), Some(last)) = (reference, judged.first(), judged.last()) {
        let level = 100.0 * r.stair_success;
        let line = vec![
            (first.env_steps as f64 / 1e6, level),
            (last.env_steps as f64 / 1e6, level),
        ];
        judged_series.push(("deployed policy, all stairs", RGBColor(127, 127, 127), line));
    }
    ppo_panel(
        &areas[4],
        "g1fw eval of checkpoints: success (%)",
        x,
        &judged_series,
        &wall,
        true,
        Some((-5.0, 105.0)),
    )?;
    let flat_speed: Vec<(f64, f64)> = judged
        .iter()
        .filter_map(|j| j.flat_speed_mps.map(|v| (j.env_steps as f64 / 1e6, v)))
        .collect();
    let vx = f64::from(crate::ppo::judge::JUDGE_VX);
    ppo_panel(
        &areas[5],
        &format!("g1fw eval, flat run: mean speed (m/s; command {vx})"),
        x,
        &[("flat speed", CNN, flat_speed)],
        &wall,
        true,
        Some((0.0, 2.0 * vx)),
    )?;
    root.present().with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}

/// Stair success through `g1fw eval` against env steps (left: up, down and both per actor, each
/// with its 95 % Wilson interval, and the paper's mean as a dashed line) and per riser height for
/// `table` (right: up and down against the paper's figure per height).
/// A chart with f64 axes on both sides.
type XyChart<'a, DB> =
    ChartContext<'a, DB, Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>>;

/// A success panel (y: 0–100 %) with its axes drawn, for [`success_curve_png`].
fn success_axes<'a, DB: DrawingBackend + 'a>(
    area: &'a DrawingArea<DB, plotters::coord::Shift>,
    caption: String,
    x: std::ops::Range<f64>,
    x_desc: &str,
) -> Result<XyChart<'a, DB>, DrawingAreaErrorKind<DB::ErrorType>> {
    let mut chart = ChartBuilder::on(area)
        .caption(caption, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(55)
        .build_cartesian_2d(x, -3.0..103.0)?;
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc("success (%)")
        .y_label_formatter(&|y| format!("{y:.0}"))
        .x_label_formatter(&|x| format!("{x:.0}"))
        .light_line_style(WHITE.mix(0.0))
        .draw()?;
    Ok(chart)
}

pub fn success_curve_png(
    path: &Path,
    points: &[crate::ppo::success_curve::CurvePoint],
    table: &firmware::eval::EvalReport,
) -> anyhow::Result<()> {
    // Through a temporary file: a failed or killed write leaves an older plot as it was.
    output_file::write_through(path, |tmp| draw_success_curve_png(tmp, points, table))
}

fn draw_success_curve_png(
    path: &Path,
    points: &[crate::ppo::success_curve::CurvePoint],
    table: &firmware::eval::EvalReport,
) -> anyhow::Result<()> {
    use crate::ppo::success_curve::{by_height, tally, Tally, PAPER_SUCCESS};
    check_png(path)?;
    anyhow::ensure!(!points.is_empty(), "no points to plot");
    let root = BitMapBackend::new(path, (1600, 650)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let (left, right) = root.split_horizontally(900);
    let shown = path.display().to_string();
    let err = |e: &dyn std::fmt::Debug| anyhow::anyhow!("drawing {shown}: {e:?}");
    let paper_mean = PAPER_SUCCESS.iter().map(|p| p.1).sum::<f64>() / PAPER_SUCCESS.len() as f64;
    // Draws each (x, tally) as a marker on a line, with its 95 % interval as a bar.
    fn with_interval<DB: DrawingBackend>(
        chart: &mut XyChart<DB>,
        pts: &[(f64, Tally)],
        c: RGBColor,
        name: &str,
    ) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
        let xy: Vec<(f64, f64)> = pts.iter().filter_map(|(x, t)| t.percent().map(|p| (*x, p))).collect();
        chart
            .draw_series(LineSeries::new(xy.clone(), c.stroke_width(2)))?
            .label(name)
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 16, y)], c.stroke_width(2)));
        chart.draw_series(xy.iter().map(|&p| Circle::new(p, 4, c.filled())))?;
        chart.draw_series(pts.iter().filter_map(|(x, t)| {
            t.wilson95()
                .map(|(lo, hi)| PathElement::new([(*x, lo), (*x, hi)], c.mix(0.5).stroke_width(2)))
        }))?;
        Ok(())
    }

    // From 0 when the points span most of the chain; zoomed onto them when they are the last
    // stretch of a long one (the whole chain would squeeze them into one column).
    let (first, last) = (
        points.first().map_or(0.0, |p| p.env_steps / 1e6),
        points.last().map_or(1.0, |p| p.env_steps / 1e6),
    );
    let (x0, x1) = if first > 0.5 * last {
        let pad = 0.08 * (last - first) + 1.0;
        (first - pad, last + pad)
    } else {
        (0.0, last * 1.08 + 1.0)
    };
    let r0 = &points[0].report;
    let heights: Vec<u32> = by_height(r0).keys().copied().collect();
    let caption = format!(
        "g1fw eval success vs training (risers {}–{} cm, {} per cell, {}, {} token)",
        heights.first().unwrap_or(&0),
        heights.last().unwrap_or(&0),
        r0.table.first().map_or(0, |r| r.episodes),
        r0.model,
        r0.terrain_source
    );
    let mut chart = success_axes(
        &left,
        caption,
        x0..x1,
        "env steps of training (M, the whole warm-start chain)",
    )
    .map_err(|e| err(&e))?;
    chart
        .draw_series(DashedLineSeries::new(
            [(x0, paper_mean), (x1, paper_mean)],
            8,
            6,
            LIMIT.stroke_width(2),
        ))
        .map_err(|e| err(&e))?
        .label(format!("paper, mean of 12–22 cm ({paper_mean:.1} %)"))
        .legend(|(x, y)| PathElement::new([(x, y), (x + 16, y)], LIMIT.stroke_width(2)));
    let dx = 0.006 * (x1 - x0);
    for (kind, c, name, off) in [
        (Some("up"), UP, "up", -dx),
        (Some("down"), DOWN, "down", dx),
        (None, CNN, "up and down", 0.0),
    ] {
        let pts: Vec<(f64, Tally)> = points
            .iter()
            .map(|p| (p.env_steps / 1e6 + off, tally(&p.report, kind)))
            .collect();
        with_interval(&mut chart, &pts, c, name).map_err(|e| err(&e))?;
    }
    chart
        .draw_series(points.iter().enumerate().map(|(i, p)| {
            // Alternate heights, so the labels of close points do not overlap.
            let y = if i % 2 == 0 { 86.0 } else { 81.0 };
            Text::new(
                p.label.clone(),
                (p.env_steps / 1e6, y),
                ("sans-serif", 13).into_font().color(&BLACK),
            )
        }))
        .map_err(|e| err(&e))?;
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(SeriesLabelPosition::UpperLeft)
        .draw()
        .map_err(|e| err(&e))?;

    let rows = by_height(table);
    let (h0, h1) = (
        rows.keys().next().copied().unwrap_or(12).min(12) as f64 - 1.0,
        rows.keys().last().copied().unwrap_or(22).max(22) as f64 + 1.0,
    );
    let mut chart = success_axes(
        &right,
        format!("per riser height: {} episodes, {}", table.episodes, table.model),
        h0..h1,
        "riser height (cm)",
    )
    .map_err(|e| err(&e))?;
    let paper: Vec<(f64, f64)> = PAPER_SUCCESS.iter().map(|&(h, p)| (h as f64, p)).collect();
    chart
        .draw_series(DashedLineSeries::new(paper.clone(), 8, 6, LIMIT.stroke_width(2)))
        .map_err(|e| err(&e))?
        .label("paper")
        .legend(|(x, y)| PathElement::new([(x, y), (x + 16, y)], LIMIT.stroke_width(2)));
    chart
        .draw_series(paper.iter().map(|&p| Circle::new(p, 4, LIMIT.filled())))
        .map_err(|e| err(&e))?;
    let up: Vec<(f64, Tally)> = rows.iter().map(|(h, t)| (*h as f64 - 0.1, t.0)).collect();
    let down: Vec<(f64, Tally)> = rows.iter().map(|(h, t)| (*h as f64 + 0.1, t.1)).collect();
    with_interval(&mut chart, &up, UP, "up").map_err(|e| err(&e))?;
    with_interval(&mut chart, &down, DOWN, "down").map_err(|e| err(&e))?;
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(SeriesLabelPosition::MiddleLeft)
        .draw()
        .map_err(|e| err(&e))?;
    root.present()
        .map_err(|e| anyhow::anyhow!("writing {}: {e:?}", path.display()))?;
    Ok(())
}
