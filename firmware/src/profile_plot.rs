//! The stair profile picture (`g1fw sim --profile-plot`): base (pelvis) height and the ground
//! height under the base against distance along the staircase axis (along world x on flat ground),
//! from the simulator's ground truth. The ground line draws the steps as the robot met them.
// Only draws pictures for people, never feeds control: std's math is fine here (see clippy.toml).
#![allow(clippy::disallowed_methods)]

use std::path::Path;

use plotters::prelude::*;

use crate::plot::{ensure_font, PlotError};

/// One tick of the profile.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ProfileSample {
    /// Distance along the staircase axis from the first riser (or world x on flat ground), m.
    pub s: f64,
    /// Base height, m (world z).
    pub base_z: f64,
    /// Ground height under the base, m.
    pub ground_z: f64,
}

/// A run's profile and what to say about it.
#[derive(Clone, Debug, Default)]
pub struct Profile {
    pub title: String,
    /// "along the staircase axis from its first riser" or "along world x".
    pub axis_label: String,
    pub samples: Vec<ProfileSample>,
    /// Where the base reached the end landing (axis position), if it did.
    pub landing_at: Option<f64>,
    /// Where the run's fall or safety trip happened, and which.
    pub event: Option<(f64, String)>,
}

const W: u32 = 1400;
const H: u32 = 600;

/// Renders the profile to `path` (PNG).
pub fn profile_png(path: &Path, p: &Profile) -> Result<(), PlotError> {
    if !path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("png"))
    {
        return Err(PlotError::NotPng { path: path.into() });
    }
    let pts: Vec<&ProfileSample> = p
        .samples
        .iter()
        .filter(|q| q.s.is_finite() && q.base_z.is_finite() && q.ground_z.is_finite())
        .collect();
    if pts.is_empty() {
        return Err(PlotError::Empty);
    }
    ensure_font()?;
    let (mut s0, mut s1, mut z1) = (f64::INFINITY, f64::NEG_INFINITY, 0.0f64);
    for q in &pts {
        s0 = s0.min(q.s);
        s1 = s1.max(q.s);
        z1 = z1.max(q.base_z).max(q.ground_z);
    }
    if s1 - s0 < 0.5 {
        s1 = s0 + 0.5;
    }
    let draw_err = |e: Box<dyn std::error::Error + Send + Sync>| PlotError::Draw {
        path: path.into(),
        cause: e,
    };
    // Through a temporary file: a failed or killed write leaves an older plot as it was.
    let r = output_file::write_through(path, |tmp| -> Result<(), Box<dyn std::error::Error + Send + Sync>> {
        let root = BitMapBackend::new(tmp, (W, H)).into_drawing_area();
        root.fill(&WHITE)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(&p.title, ("sans-serif", 26))
            .margin(15)
            .x_label_area_size(50)
            .y_label_area_size(70)
            .build_cartesian_2d((s0 - 0.1)..(s1 + 0.1), -0.05..(z1 + 0.15))?;
        chart
            .configure_mesh()
            .x_desc(format!("distance {} (m)", p.axis_label))
            .y_desc("height (m)")
            .label_style(("sans-serif", 18))
            .draw()?;
        // The ground as a function of position (sorted, so walking back does not scribble).
        let mut ground: Vec<(f64, f64)> = pts.iter().map(|q| (q.s, q.ground_z)).collect();
        ground.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut fill = ground.clone();
        fill.push((ground[ground.len() - 1].0, -0.05));
        fill.push((ground[0].0, -0.05));
        chart
            .draw_series([Polygon::new(fill, RGBColor(200, 200, 200).mix(0.6).filled())])?
            .label("ground under the base")
            .legend(|(x, y)| Rectangle::new([(x, y - 5), (x + 20, y + 5)], RGBColor(160, 160, 160).filled()));
        chart.draw_series(LineSeries::new(ground, RGBColor(90, 90, 90).stroke_width(2)))?;
        chart
            .draw_series(LineSeries::new(
                pts.iter().map(|q| (q.s, q.base_z)),
                RGBColor(31, 119, 180).stroke_width(3),
            ))?
            .label("base (pelvis) height")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], RGBColor(31, 119, 180).stroke_width(3)));
        if let Some(s) = p.landing_at {
            chart
                .draw_series(LineSeries::new(
                    [(s, -0.05), (s, z1 + 0.15)],
                    RGBColor(44, 160, 44).stroke_width(2),
                ))?
                .label("reached the end landing")
                .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], RGBColor(44, 160, 44).stroke_width(2)));
        }
        if let Some((s, what)) = &p.event {
            chart.draw_series(LineSeries::new(
                [(*s, -0.05), (*s, z1 + 0.15)],
                RGBColor(214, 39, 40).stroke_width(2),
            ))?;
            chart.draw_series([Text::new(
                what.clone(),
                (*s, z1 + 0.08),
                ("sans-serif", 18).into_font().color(&RGBColor(214, 39, 40)),
            )])?;
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font(("sans-serif", 18))
            .position(SeriesLabelPosition::UpperLeft)
            .draw()?;
        root.present()?;
        Ok(())
    });
    r.map_err(draw_err)
}
