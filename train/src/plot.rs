//! PNG figures: errors versus true step height (CNN vs geometric baseline) and training curves.
use std::path::Path;

use anyhow::Context;
use plotters::prelude::*;

use crate::eval::Bin;
use crate::fit::EpochLog;

const CNN: RGBColor = RGBColor(31, 119, 180);
const BASE: RGBColor = RGBColor(255, 127, 14);
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
    check_png(path)?;
    let root = BitMapBackend::new(path, (1400, 1000)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let root = root
        .titled(title, ("sans-serif", 24))
        .map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let areas = root.split_evenly((2, 2));
    let used: Vec<&Bin> = bins.iter().filter(|b| b.samples > 0).collect();
    let mid = |b: &Bin| scale * 0.5 * (b.lo + b.hi) as f64;
    let pick = |f: fn(&crate::eval::BinErr) -> f64| -> [Vec<(f64, f64)>; 2] {
        [
            used.iter().map(|b| (mid(b), f(&b.cnn))).collect(),
            used.iter().map(|b| (mid(b), f(&b.baseline))).collect(),
        ]
    };
    type Panel<'a> = (&'a str, fn(&crate::eval::BinErr) -> f64, Option<(f64, &'a str)>, bool);
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

/// PPO learning curves against env steps (millions): return, success, level, falls.
pub fn ppo_curves_png(path: &Path, log: &[crate::ppo::runner::IterLog]) -> anyhow::Result<()> {
    check_png(path)?;
    let root = BitMapBackend::new(path, (1400, 1000)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let areas = root.split_evenly((2, 2));
    let xmax = log.last().map_or(1.0, |l| l.env_steps as f64 / 1e6).max(1e-3);
    let x = (0.0, xmax);
    let series = |f: &dyn Fn(&crate::ppo::runner::IterLog) -> Option<f64>| -> Vec<(f64, f64)> {
        log.iter()
            .filter_map(|l| f(l).map(|v| (l.env_steps as f64 / 1e6, v)))
            .collect()
    };
    let xl = "env steps (M)";
    panel(
        &areas[0],
        "mean reward per policy step",
        xl,
        x,
        &[("reward/step", CNN, series(&|l| Some(l.mean_reward_per_step)))],
        None,
        false,
    )?;
    panel(
        &areas[1],
        "stair episodes: success / falls (%)",
        xl,
        x,
        &[
            ("success", CNN, series(&|l| l.success_rate.map(|v| 100.0 * v))),
            ("falls (all)", BASE, series(&|l| l.fall_rate.map(|v| 100.0 * v))),
        ],
        None,
        false,
    )?;
    panel(
        &areas[2],
        "mean terrain level (0: 5 cm … 10: 26 cm)",
        xl,
        x,
        &[("level", CNN, series(&|l| Some(l.mean_level)))],
        None,
        false,
    )?;
    panel(
        &areas[3],
        "episode return",
        xl,
        x,
        &[("return", CNN, series(&|l| l.mean_episode_return))],
        None,
        false,
    )?;
    root.present().with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}
