//! Velocity-tracking plots (PNG) for `g1fw plot`: commanded vs measured base velocity.
//!
//! Three stacked panels (vx, vy, wz) share one time axis. Commands are drawn as steps because
//! the operator holds each command until the next sample; measured velocity is a solid line and
//! the optional estimate a thinner dashed one. Each panel caption carries the RMSE of measured
//! vs commanded. Non-finite samples are skipped (the line breaks there) rather than rejected,
//! since logs from a fallen or reset robot routinely contain them.
//!
//! Text uses plotters' `ab_glyph` backend so the build needs no fontconfig/freetype; a TTF is
//! loaded at run time instead (see [`FONT_CANDIDATES`]).
// Only draws pictures for people, never feeds control: std's math is fine here (see clippy.toml).
#![allow(clippy::disallowed_methods)]

use std::error::Error as StdError;
use std::path::{Path, PathBuf};
use std::sync::{Mutex, PoisonError};

use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::element::DashedPathElement;
use plotters::prelude::*;
use plotters::style::register_font;

/// Output size, px.
const WIDTH: u32 = 1400;
const HEIGHT: u32 = 1000;

/// Set to a TTF/OTF path to override the font search.
pub const FONT_ENV: &str = "G1FW_PLOT_FONT";

/// Fonts tried in order when [`FONT_ENV`] is unset (Debian/Ubuntu, Arch, Fedora, then Liberation).
pub const FONT_CANDIDATES: &[&str] = &[
    "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/TTF/DejaVuSans.ttf",
    "/usr/share/fonts/dejavu-sans-fonts/DejaVuSans.ttf",
    "/usr/share/fonts/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf",
];

const COMMANDED: RGBColor = RGBColor(0, 0, 0);
const MEASURED: RGBColor = RGBColor(31, 119, 180);
const ESTIMATED: RGBColor = RGBColor(255, 127, 14);
const EVENT: RGBColor = RGBColor(214, 39, 40);
const MARK: RGBColor = RGBColor(120, 120, 120);

/// One velocity-tracking run to plot. All per-sample vectors are indexed like `t`.
#[derive(Debug, Clone, Default)]
pub struct VelocitySeries {
    pub title: String,
    /// Sample times, s (monotonic).
    pub t: Vec<f64>,
    /// Operator command per sample: vx, vy (m/s), wz (rad/s).
    pub commanded: Vec<[f32; 3]>,
    /// Measured body-frame velocity per sample: vx, vy, wz.
    pub measured: Vec<[f64; 3]>,
    /// Optional second measured series (e.g. the firmware's estimate), drawn dashed/thinner; may be empty.
    pub estimated: Vec<[f64; 3]>,
    /// Times of safety events to mark with a vertical line and label (e.g. "damping: tilt").
    pub events: Vec<(f64, String)>,
    /// Times of terrain milestones (a riser passed, the end landing reached), drawn as thin grey lines.
    pub marks: Vec<(f64, String)>,
}

/// Why a plot could not be written.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    #[error("{series} has {len} samples but t has {expected}")]
    LengthMismatch {
        series: &'static str,
        len: usize,
        expected: usize,
    },
    #[error("nothing to plot: no samples with a finite time")]
    Empty,
    #[error("sample times must not decrease: t[{index}] = {t} after {prev}")]
    NotMonotonic { index: usize, prev: f64, t: f64 },
    #[error("time span {t0}..{t1} s is too wide to plot")]
    TimeSpan { t0: f64, t1: f64 },
    #[error("{} does not end in .png (the encoder picks the format from the extension)", path.display())]
    NotPng { path: PathBuf },
    #[error("no usable font: {0}")]
    Font(String),
    // The cause is in the message and not a `source` link, so `{:#}` chains print it once.
    #[error("drawing the plot for {}: {cause}", path.display())]
    Draw {
        path: PathBuf,
        cause: Box<dyn StdError + Send + Sync>,
    },
    #[error("writing {}: {cause}", path.display())]
    Write {
        path: PathBuf,
        cause: Box<dyn StdError + Send + Sync>,
    },
}

/// Renders `s` as a 1400×1000 PNG at `path` (which must end in `.png`).
///
/// The image is drawn in memory first, so a drawing failure leaves no half-written file.
pub fn velocity_tracking_png(path: &Path, s: &VelocitySeries) -> Result<(), PlotError> {
    let (t0, t1) = validate(s)?;
    let is_png = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("png"));
    if !is_png {
        return Err(PlotError::NotPng {
            path: path.to_path_buf(),
        });
    }
    ensure_font()?;

    let mut rgb = vec![0u8; WIDTH as usize * HEIGHT as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut rgb, (WIDTH, HEIGHT)).into_drawing_area();
        draw(&root, s, (t0, t1)).map_err(|e| PlotError::Draw {
            path: path.to_path_buf(),
            cause: e,
        })?;
    }

    let write_err = |e: Box<dyn StdError + Send + Sync>| PlotError::Write {
        path: path.to_path_buf(),
        cause: e,
    };
    // Through a temporary file: a failed or killed write leaves an older plot as it was.
    output_file::write_through(path, |tmp| -> Result<(), Box<dyn StdError + Send + Sync>> {
        let mut file = BitMapBackend::new(tmp, (WIDTH, HEIGHT));
        file.blit_bitmap((0, 0), (WIDTH, HEIGHT), &rgb)
            .map_err(|e| Box::new(DrawingAreaErrorKind::BackendError(e)))?;
        file.present()
            .map_err(|e| Box::new(DrawingAreaErrorKind::BackendError(e)))?;
        Ok(())
    })
    .map_err(write_err)
}

/// Checks shapes and time order; returns the finite time span.
fn validate(s: &VelocitySeries) -> Result<(f64, f64), PlotError> {
    let n = s.t.len();
    let check = |series, len| {
        if len == n {
            Ok(())
        } else {
            Err(PlotError::LengthMismatch {
                series,
                len,
                expected: n,
            })
        }
    };
    check("commanded", s.commanded.len())?;
    check("measured", s.measured.len())?;
    if !s.estimated.is_empty() {
        check("estimated", s.estimated.len())?;
    }

    let mut span: Option<(f64, f64)> = None;
    for (index, &t) in s.t.iter().enumerate() {
        if !t.is_finite() {
            continue;
        }
        span = match span {
            Some((_, prev)) if t < prev => return Err(PlotError::NotMonotonic { index, prev, t }),
            Some((first, _)) => Some((first, t)),
            None => Some((t, t)),
        };
    }
    let (t0, t1) = span.ok_or(PlotError::Empty)?;
    // plotters never returns on an infinite axis range.
    if !(t1 - t0).is_finite() {
        return Err(PlotError::TimeSpan { t0, t1 });
    }
    // A single instant still needs a non-degenerate axis.
    Ok(if t1 > t0 { (t0, t1) } else { (t0 - 0.5, t0 + 0.5) })
}

/// Registers a sans-serif TTF with plotters once per process.
pub fn ensure_font() -> Result<(), PlotError> {
    static READY: Mutex<bool> = Mutex::new(false);
    let mut ready = READY.lock().unwrap_or_else(PoisonError::into_inner);
    if *ready {
        return Ok(());
    }

    let override_path = std::env::var_os(FONT_ENV).map(PathBuf::from);
    let candidates: Vec<PathBuf> = match &override_path {
        Some(p) => vec![p.clone()],
        None => FONT_CANDIDATES.iter().map(PathBuf::from).collect(),
    };
    let mut rejected = Vec::new();
    for path in &candidates {
        // A font is a few MB; $G1_PLOT_FONT naming a FIFO or a device must not hang a plot.
        let Ok(bytes) = input_file::read_capped(path, 64 << 20) else {
            continue;
        };
        // plotters keeps `&'static` font data; leaking is bounded by the READY guard.
        let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
        // Plotters' mesh/legend defaults ask for "sans-serif"; the others guard against a
        // family name slipping in elsewhere and failing at draw time.
        let ok = ["sans-serif", "serif", "monospace"]
            .iter()
            .all(|family| register_font(family, FontStyle::Normal, bytes).is_ok());
        if ok {
            *ready = true;
            return Ok(());
        }
        rejected.push(path.display().to_string());
    }

    Err(PlotError::Font(match override_path {
        Some(p) => format!("{FONT_ENV}={} is not a readable TrueType/OpenType font", p.display()),
        None if rejected.is_empty() => format!(
            "none of {} exists; install one with `apt install fonts-dejavu-core` \
             or point {FONT_ENV} at a .ttf",
            FONT_CANDIDATES.join(", ")
        ),
        None => format!(
            "{} could not be parsed; reinstall with `apt install --reinstall fonts-dejavu-core` \
             or point {FONT_ENV} at a .ttf",
            rejected.join(", ")
        ),
    }))
}

type DrawResult = Result<(), Box<dyn StdError + Send + Sync>>;

fn draw<DB>(root: &DrawingArea<DB, Shift>, s: &VelocitySeries, (t0, t1): (f64, f64)) -> DrawResult
where
    DB: DrawingBackend,
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    // Margin keeps the title off the top edge (ab_glyph lays text out tighter than fontconfig).
    let body = root.margin(10, 5, 5, 15).titled(&s.title, ("sans-serif", 28))?;
    let panels = body.split_evenly((3, 1));
    let names = [("vx", "m/s"), ("vy", "m/s"), ("wz", "rad/s")];
    for (axis, (panel, &(name, unit))) in panels.iter().zip(names.iter()).enumerate() {
        draw_panel(panel, s, axis, name, unit, (t0, t1), axis == 2)?;
    }
    root.present()?;
    Ok(())
}

fn draw_panel<DB>(
    area: &DrawingArea<DB, Shift>,
    s: &VelocitySeries,
    axis: usize,
    name: &str,
    unit: &str,
    (t0, t1): (f64, f64),
    bottom: bool,
) -> DrawResult
where
    DB: DrawingBackend,
    DB::ErrorType: 'static,
{
    let cmd: Vec<f64> = s.commanded.iter().map(|c| f64::from(c[axis])).collect();
    let meas: Vec<f64> = s.measured.iter().map(|m| m[axis]).collect();
    let est: Vec<f64> = s.estimated.iter().map(|m| m[axis]).collect();

    let caption = match rmse(&s.t, &cmd, &meas) {
        Some((r, n)) => format!("{name}: RMSE measured vs commanded = {r:.3} {unit} (n = {n})"),
        None => format!("{name}: RMSE n/a (no finite measured/commanded pairs)"),
    };
    let (y0, y1) = y_range(&s.t, [&cmd, &meas, &est]);

    let mut chart = ChartBuilder::on(area)
        .margin(8)
        .caption(caption, ("sans-serif", 20))
        .x_label_area_size(if bottom { 50 } else { 28 })
        .y_label_area_size(80)
        .build_cartesian_2d(t0..t1, y0..y1)?;

    let mut mesh = chart.configure_mesh();
    mesh.y_desc(format!("{name} ({unit})"))
        .label_style(("sans-serif", 15))
        .axis_desc_style(("sans-serif", 17))
        .max_light_lines(2)
        .light_line_style(RGBColor(240, 240, 240));
    if bottom {
        mesh.x_desc("time (s)");
    }
    mesh.draw()?;

    // Marks and events go first so the data lines are drawn over them. Labels only in the top
    // panel; event labels are staggered so nearby events don't overprint.
    let labels = axis == 0;
    let mark = VerticalLines {
        color: MARK,
        width: 1,
        legend: "stairs: riser passed / end landing",
        font_size: 13,
        label_y: |_| y0 + (y1 - y0) * 0.08,
    };
    mark.draw(&mut chart, &s.marks, (t0, t1), (y0, y1), labels)?;
    let event = VerticalLines {
        color: EVENT,
        width: 2,
        legend: "safety event",
        font_size: 15,
        label_y: |i| y1 - (y1 - y0) * (0.04 + 0.09 * (i % 3) as f64),
    };
    event.draw(&mut chart, &s.events, (t0, t1), (y0, y1), labels)?;

    let cmd_style = COMMANDED.stroke_width(2);
    legend_entry(&mut chart, "commanded", cmd_style, false)?;
    let y = (y0, y1);
    for run in finite_runs(&s.t, &cmd, y) {
        chart.draw_series(LineSeries::new(steps(&run), cmd_style))?;
    }

    let meas_style = MEASURED.stroke_width(2);
    legend_entry(&mut chart, "measured", meas_style, false)?;
    draw_runs(&mut chart, finite_runs(&s.t, &meas, y), meas_style)?;

    if !est.is_empty() {
        let est_style = ESTIMATED.stroke_width(1);
        legend_entry(&mut chart, "estimated", est_style, true)?;
        for run in finite_runs(&s.t, &est, y) {
            if run.len() == 1 {
                draw_runs(&mut chart, vec![run], est_style)?;
            } else {
                chart.draw_series(DashedLineSeries::new(run, 6, 4, est_style))?;
            }
        }
    }

    // One legend for all panels. Upper left is usually free: runs start at rest with a zero
    // command, and events (falls) tend to come late.
    if axis == 0 {
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperLeft)
            .label_font(("sans-serif", 14))
            .background_style(WHITE.mix(0.8))
            .border_style(RGBColor(180, 180, 180))
            .draw()?;
    }
    Ok(())
}

type Chart<'a, DB> = ChartContext<'a, DB, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// Labelled vertical lines across a panel at given times (safety events, stair milestones).
struct VerticalLines<F> {
    color: RGBColor,
    width: u32,
    legend: &'static str,
    font_size: u32,
    /// Where the i-th label sits.
    label_y: F,
}

impl<F: Fn(usize) -> f64> VerticalLines<F> {
    /// Draws the times of `items` inside the time range (non-finite ones dropped), with one legend
    /// entry, and their labels when `labels`.
    fn draw<DB>(
        &self,
        chart: &mut Chart<'_, DB>,
        items: &[(f64, String)],
        (t0, t1): (f64, f64),
        (y0, y1): (f64, f64),
        labels: bool,
    ) -> DrawResult
    where
        DB: DrawingBackend,
        DB::ErrorType: 'static,
    {
        let shown: Vec<(f64, &str)> = items
            .iter()
            .filter(|(te, _)| te.is_finite() && (t0..=t1).contains(te))
            .map(|(te, label)| (*te, label.as_str()))
            .collect();
        if shown.is_empty() {
            return Ok(());
        }
        let style = self.color.stroke_width(self.width);
        chart
            .draw_series(
                shown
                    .iter()
                    .map(|&(te, _)| PathElement::new(vec![(te, y0), (te, y1)], style)),
            )?
            .label(self.legend)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style));
        if labels {
            let font = ("sans-serif", self.font_size).into_font().color(&self.color);
            chart.draw_series(
                shown
                    .iter()
                    .enumerate()
                    .map(|(i, &(te, label))| Text::new(format!(" {label}"), (te, (self.label_y)(i)), font.clone())),
            )?;
        }
        Ok(())
    }
}

/// An empty series that only carries a legend entry, so the legend shows every series even
/// when its data is all non-finite or split into several runs.
fn legend_entry<DB>(chart: &mut Chart<'_, DB>, label: &str, style: ShapeStyle, dashed: bool) -> DrawResult
where
    DB: DrawingBackend,
    DB::ErrorType: 'static,
{
    let anno = chart
        .draw_series(LineSeries::new(std::iter::empty::<(f64, f64)>(), style))?
        .label(label);
    if dashed {
        anno.legend(move |(x, y)| DashedPathElement::new(vec![(x, y), (x + 20, y)], 5, 3, style));
    } else {
        anno.legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style));
    }
    Ok(())
}

/// Draws each run as a line; a lone finite sample between gaps becomes a dot so it isn't lost.
fn draw_runs<DB>(chart: &mut Chart<'_, DB>, runs: Vec<Vec<(f64, f64)>>, style: ShapeStyle) -> DrawResult
where
    DB: DrawingBackend,
    DB::ErrorType: 'static,
{
    for run in runs {
        if run.len() == 1 {
            chart.draw_series(run.iter().map(|&p| Circle::new(p, 2, style.filled())))?;
        } else {
            chart.draw_series(LineSeries::new(run, style))?;
        }
    }
    Ok(())
}

/// Maximal runs of consecutive samples where both time and value are finite; a skipped
/// sample ends a run so gaps show as gaps instead of being bridged. Values are clamped to
/// the axis range so absurd spikes end at the panel edge.
fn finite_runs(t: &[f64], v: &[f64], (lo, hi): (f64, f64)) -> Vec<Vec<(f64, f64)>> {
    let mut runs = Vec::new();
    let mut cur = Vec::new();
    for (&ti, &vi) in t.iter().zip(v) {
        if ti.is_finite() && vi.is_finite() {
            cur.push((ti, vi.clamp(lo, hi)));
        } else if !cur.is_empty() {
            runs.push(std::mem::take(&mut cur));
        }
    }
    if !cur.is_empty() {
        runs.push(cur);
    }
    runs
}

/// Zero-order-hold path through `run`: each value holds until the next sample time.
fn steps(run: &[(f64, f64)]) -> Vec<(f64, f64)> {
    let mut out = Vec::with_capacity(run.len() * 2);
    for (i, &(t, v)) in run.iter().enumerate() {
        if i > 0 {
            out.push((t, run[i - 1].1));
        }
        out.push((t, v));
    }
    out
}

/// RMSE of `meas` vs `cmd` over samples where time and both values are finite, with the count.
fn rmse(t: &[f64], cmd: &[f64], meas: &[f64]) -> Option<(f64, usize)> {
    let (sum, n) = t
        .iter()
        .zip(cmd.iter().zip(meas))
        .filter(|(ti, (c, m))| ti.is_finite() && c.is_finite() && m.is_finite())
        .fold((0.0, 0usize), |(sum, n), (_, (c, m))| (sum + (m - c) * (m - c), n + 1));
    (n > 0).then(|| ((sum / n as f64).sqrt(), n))
}

/// Y span covering every finite value with a margin; falls back to ±1 when nothing is finite.
fn y_range(t: &[f64], series: [&[f64]; 3]) -> (f64, f64) {
    let mut lo = f64::INFINITY;
    let mut hi = f64::NEG_INFINITY;
    for v in series {
        for (&ti, &vi) in t.iter().zip(v) {
            if ti.is_finite() && vi.is_finite() {
                lo = lo.min(vi);
                hi = hi.max(vi);
            }
        }
    }
    if lo > hi {
        return (-1.0, 1.0);
    }
    // Keeps span and padding finite: plotters never returns on an infinite axis range.
    const LIMIT: f64 = f64::MAX / 4.0;
    let (lo, hi) = (lo.max(-LIMIT), hi.min(LIMIT));
    let span = hi - lo;
    // Flat data (e.g. a zero command held throughout) still gets a readable band.
    let pad = if span < 1e-6 { 0.5 } else { 0.08 * span };
    (lo - pad, hi + pad)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn steps_hold_until_next_sample() {
        let s = steps(&[(0.0, 0.0), (1.0, 0.5), (2.0, 0.3)]);
        assert_eq!(s, vec![(0.0, 0.0), (1.0, 0.0), (1.0, 0.5), (2.0, 0.5), (2.0, 0.3)]);
    }

    #[test]
    fn runs_break_at_non_finite() {
        let t = [0.0, 1.0, 2.0, 3.0, f64::NAN, 5.0];
        let v = [1.0, f64::NAN, 2.0, 3.0, 4.0, f64::INFINITY];
        assert_eq!(
            finite_runs(&t, &v, (0.0, 2.5)),
            vec![vec![(0.0, 1.0)], vec![(2.0, 2.0), (3.0, 2.5)]]
        );
    }

    #[test]
    fn y_range_stays_finite() {
        let t = [0.0, 1.0];
        let (lo, hi) = y_range(&t, [&[f64::MIN, f64::MAX], &[], &[]]);
        assert!(lo.is_finite() && hi.is_finite() && (hi - lo).is_finite());
        assert_eq!(y_range(&t, [&[0.0, 0.0], &[], &[]]), (-0.5, 0.5));
        assert_eq!(y_range(&t, [&[f64::NAN; 2], &[], &[]]), (-1.0, 1.0));
    }

    #[test]
    fn rmse_skips_non_finite() {
        let t = [0.0, 1.0, 2.0];
        let (r, n) = rmse(&t, &[1.0, 1.0, f64::NAN], &[0.0, 2.0, 5.0]).unwrap();
        assert_eq!(n, 2);
        assert!((r - 1.0).abs() < 1e-12);
        assert!(rmse(&t, &[f64::NAN; 3], &[0.0; 3]).is_none());
    }
}
