//! `g1fw bev`: one perception frame of a log to PNG — the six BEV channels, the robot-centred cloud
//! from above and from the side, and the terrain token against ground truth.
// Only draws pictures for people, never feeds control: std's math is fine here (see clippy.toml).
#![allow(clippy::disallowed_methods)]
use std::path::Path;

use anyhow::{bail, Context, Result};
use base64::Engine as _;
use plotters::prelude::*;
use sensor_io::bev::{BevGrid, BEV_CELLS, BEV_CHANNELS, BEV_HALF_EXTENT_M, CHANNEL_NAMES, CH_DENSITY};

use runlog::log::channels as ch;
use runlog::log::LogFile;

/// What was drawn.
#[derive(Debug, Clone, serde::Serialize)]
pub struct RenderInfo {
    pub time_s: f64,
    pub points: usize,
    pub occupied_cells: usize,
    pub terrain: Option<serde_json::Value>,
    pub truth: Option<serde_json::Value>,
}

#[derive(Default)]
struct Frame {
    time_ns: u64,
    grid: Option<Vec<u8>>,
    points: Option<Vec<u8>>,
    terrain: Option<serde_json::Value>,
    truth: Option<serde_json::Value>,
}

fn data_field(msg: &[u8]) -> Result<Vec<u8>> {
    let v: serde_json::Value = serde_json::from_slice(msg).context("message is not JSON")?;
    let s = v["data"].as_str().context("message has no `data` string")?;
    base64::engine::general_purpose::STANDARD
        .decode(s)
        .context("`data` is not base64")
}

/// Renders the perception frame nearest to `at_s` (seconds of log time; the last frame when
/// `None`) of a `g1fw sim --world` log.
pub fn render_bev_png(log: &Path, at_s: Option<f64>, out: &Path) -> Result<RenderInfo> {
    if let Some(t) = at_s.filter(|t| !(t.is_finite() && *t >= 0.0)) {
        bail!("--at {t}: give a time in seconds from the start of the log (finite, ≥ 0)");
    }
    let file = LogFile::open(log)?;
    // Frame times first (and every check of the log), then the chosen one's messages.
    let mut times = Vec::new();
    file.undamaged(file.scan(|topic, t, _| {
        if topic == ch::PERCEPTION_BEV {
            times.push(t);
        }
    }))?;
    if times.is_empty() {
        bail!(
            "{} has no {} messages: record it with `g1fw sim --world PRESET --log FILE`",
            log.display(),
            ch::PERCEPTION_BEV
        );
    }
    let want = match at_s {
        Some(s) => {
            let ns = (s * 1e9).max(0.0) as u64;
            *times.iter().min_by_key(|t| t.abs_diff(ns)).expect("non-empty")
        }
        None => *times.iter().max().expect("non-empty"),
    };
    let mut f = Frame {
        time_ns: want,
        ..Frame::default()
    };
    let mut err = None;
    file.scan(|topic, t, data| {
        if t != want || err.is_some() {
            return;
        }
        let r = match topic {
            ch::PERCEPTION_BEV => data_field(data).map(|d| f.grid = Some(d)),
            ch::LIDAR_POINTS => data_field(data).map(|d| f.points = Some(d)),
            ch::PERCEPTION_TERRAIN => {
                f.terrain = serde_json::from_slice(data).ok();
                Ok(())
            }
            ch::TRUTH_TERRAIN => {
                f.truth = serde_json::from_slice(data).ok();
                Ok(())
            }
            _ => Ok(()),
        };
        if let Err(e) = r {
            err = Some(e.context(format!("decoding {topic} at {t} ns")));
        }
    });
    if let Some(e) = err {
        return Err(e);
    }
    let grid_bytes = f.grid.take().context("the chosen frame lost its grid")?;
    let grid = grid_from_foxglove(&grid_bytes)?;
    let points = f.points.take().map(|b| points_from_foxglove(&b)).unwrap_or_default();
    output_file::write_through(out, |tmp| draw(tmp, &grid, &points, &f))
        .map_err(|e| anyhow::anyhow!("drawing {}: {e}", out.display()))?;
    let occupied = (0..BEV_CELLS * BEV_CELLS)
        .filter(|i| grid.data[CH_DENSITY * BEV_CELLS * BEV_CELLS + i] > 0.0)
        .count();
    Ok(RenderInfo {
        time_s: f.time_ns as f64 * 1e-9,
        points: points.len(),
        occupied_cells: occupied,
        terrain: f.terrain,
        truth: f.truth,
    })
}

/// The log's foxglove.Grid layout (rows along y, columns along x, six f32 per cell) back into
/// the BEV layout.
pub fn grid_from_foxglove(bytes: &[u8]) -> Result<Box<BevGrid>> {
    let need = BEV_CELLS * BEV_CELLS * BEV_CHANNELS * 4;
    if bytes.len() != need {
        bail!("grid data is {} bytes, expected {need}", bytes.len());
    }
    let mut g = Box::new(BevGrid::zeroed());
    for iy in 0..BEV_CELLS {
        for ix in 0..BEV_CELLS {
            for c in 0..BEV_CHANNELS {
                let o = ((iy * BEV_CELLS + ix) * BEV_CHANNELS + c) * 4;
                g.data[BevGrid::index(c, ix, iy)] = f32::from_le_bytes(bytes[o..o + 4].try_into().expect("4 bytes"));
            }
        }
    }
    Ok(g)
}

fn points_from_foxglove(bytes: &[u8]) -> Vec<[f32; 3]> {
    bytes
        .chunks_exact(16)
        .map(|c| {
            let f = |i: usize| f32::from_le_bytes(c[i..i + 4].try_into().expect("4 bytes"));
            [f(0), f(4), f(8)]
        })
        .collect()
}

/// A perceptual blue→green→yellow ramp for t in [0, 1].
fn ramp(t: f64) -> RGBColor {
    let t = t.clamp(0.0, 1.0);
    let stops = [
        (68.0, 1.0, 84.0),
        (59.0, 82.0, 139.0),
        (33.0, 145.0, 140.0),
        (94.0, 201.0, 98.0),
        (253.0, 231.0, 37.0),
    ];
    let x = t * (stops.len() - 1) as f64;
    let i = (x.floor() as usize).min(stops.len() - 2);
    let u = x - i as f64;
    let (a, b) = (stops[i], stops[i + 1]);
    let l = |p: f64, q: f64| (p + (q - p) * u) as u8;
    RGBColor(l(a.0, b.0), l(a.1, b.1), l(a.2, b.2))
}

type DrawResult = Result<(), Box<dyn std::error::Error + Send + Sync>>;

fn token_line(v: &Option<serde_json::Value>) -> String {
    match v {
        Some(v) => format!(
            "{} h {:.3} m  d {:.3} m  yaw {:+.1}°",
            v["class"].as_str().unwrap_or("?"),
            v["step_height_m"].as_f64().unwrap_or(f64::NAN),
            v["step_depth_m"].as_f64().unwrap_or(f64::NAN),
            v["yaw_deg"].as_f64().unwrap_or(f64::NAN)
        ),
        None => "-".into(),
    }
}

fn draw(out: &Path, grid: &BevGrid, points: &[[f32; 3]], f: &Frame) -> DrawResult {
    crate::plot::ensure_font().map_err(|e| e.to_string())?;
    let (w, h) = (1500u32, 760u32);
    let root = BitMapBackend::new(out, (w, h)).into_drawing_area();
    root.fill(&WHITE)?;
    let title = format!(
        "t = {:.2} s   estimate: {}   truth: {}",
        f.time_ns as f64 * 1e-9,
        token_line(&f.terrain),
        token_line(&f.truth)
    );
    root.draw(&Text::new(title, (20, 12), ("sans-serif", 20).into_font()))?;
    let cell = 4i32;
    let size = cell * BEV_CELLS as i32;
    // Six channels, 3 × 2, row 0 (x = −1.5 m) at the bottom so forward is up; y to the left.
    for (c, name) in CHANNEL_NAMES.iter().enumerate() {
        let (ox, oy) = (20 + (c as i32 % 3) * (size + 40), 70 + (c as i32 / 3) * (size + 60));
        let vals: Vec<f32> = (0..BEV_CELLS * BEV_CELLS)
            .map(|i| grid.data[c * BEV_CELLS * BEV_CELLS + i])
            .collect();
        let occ = |ix: usize, iy: usize| grid.occupied(ix, iy);
        let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
        for ix in 0..BEV_CELLS {
            for iy in 0..BEV_CELLS {
                if occ(ix, iy) {
                    lo = lo.min(vals[ix * BEV_CELLS + iy]);
                    hi = hi.max(vals[ix * BEV_CELLS + iy]);
                }
            }
        }
        root.draw(&Text::new(
            format!("{name} [{lo:.2}, {hi:.2}]"),
            (ox, oy - 22),
            ("sans-serif", 15).into_font(),
        ))?;
        for ix in 0..BEV_CELLS {
            for iy in 0..BEV_CELLS {
                let color = if occ(ix, iy) {
                    let v = vals[ix * BEV_CELLS + iy];
                    ramp(if hi > lo { ((v - lo) / (hi - lo)) as f64 } else { 0.5 })
                } else {
                    RGBColor(40, 40, 40)
                };
                let px = ox + (BEV_CELLS - 1 - iy) as i32 * cell;
                let py = oy + (BEV_CELLS - 1 - ix) as i32 * cell;
                root.draw(&Rectangle::new([(px, py), (px + cell, py + cell)], color.filled()))?;
            }
        }
        // The robot at the centre, facing up.
        let (cx, cy) = (ox + size / 2, oy + size / 2);
        root.draw(&Polygon::new(
            vec![(cx, cy - 8), (cx - 5, cy + 5), (cx + 5, cy + 5)],
            RED.filled(),
        ))?;
    }
    // Cloud from above (colour = z) and from the side (x–z), robot frame.
    let top = root.clone().shrink((3 * (size + 40) + 20, 50), (520, 330));
    let (zlo, zhi) = points.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), p| {
        (a.min(p[2]), b.max(p[2]))
    });
    let ext = BEV_HALF_EXTENT_M as f64 + 1.0;
    let mut chart = ChartBuilder::on(&top)
        .caption("cloud from above (x forward, y left; colour = z)", ("sans-serif", 15))
        .x_label_area_size(25)
        .y_label_area_size(35)
        .build_cartesian_2d(ext..-ext, -ext..ext)?;
    chart.configure_mesh().x_desc("y (m)").y_desc("x (m)").draw()?;
    chart.draw_series(points.iter().map(|p| {
        let t = if zhi > zlo {
            ((p[2] - zlo) / (zhi - zlo)) as f64
        } else {
            0.5
        };
        Pixel::new((p[1] as f64, p[0] as f64), ramp(t))
    }))?;
    let b = BEV_HALF_EXTENT_M as f64;
    chart.draw_series(std::iter::once(PathElement::new(
        vec![(-b, -b), (-b, b), (b, b), (b, -b), (-b, -b)],
        RED.stroke_width(1),
    )))?;
    let side = root.clone().shrink((3 * (size + 40) + 20, 400), (520, 340));
    let mut chart = ChartBuilder::on(&side)
        .caption("side view, |y| < 0.5 m (x forward, z up)", ("sans-serif", 15))
        .x_label_area_size(25)
        .y_label_area_size(35)
        .build_cartesian_2d(-ext..ext, -1.0..1.5)?;
    chart.configure_mesh().x_desc("x (m)").y_desc("z (m)").draw()?;
    chart.draw_series(
        points
            .iter()
            .filter(|p| p[1].abs() < 0.5)
            .map(|p| Pixel::new((p[0] as f64, p[2] as f64), BLUE)),
    )?;
    root.present()?;
    Ok(())
}
