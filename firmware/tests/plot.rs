//! `plot::velocity_tracking_png` end to end: render, decode the PNG, check it has content.
// Test inputs come from std's math on the host; this never runs on the robot.
#![allow(clippy::disallowed_methods)]

use std::path::PathBuf;

use firmware::plot::{velocity_tracking_png, PlotError, VelocitySeries};

const DT: f64 = 0.02;

fn out_path(name: &str) -> PathBuf {
    let p = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("plot_{name}.png"));
    let _ = std::fs::remove_file(&p);
    p
}

/// vx command steps 0 → 0.5 → 0.3 m/s, wz steps 0 → 0.4 rad/s; the robot follows with a
/// first-order lag plus a deterministic wiggle, and the estimate is the measurement with a
/// small bias. One safety event near the end.
fn synthetic() -> VelocitySeries {
    let n = 750; // 15 s at 50 Hz
    let tau = 0.3;
    let mut t = Vec::with_capacity(n);
    let mut commanded = Vec::with_capacity(n);
    let mut measured = Vec::with_capacity(n);
    let mut estimated = Vec::with_capacity(n);
    let mut lag = [0.0f64; 3];
    for i in 0..n {
        let ti = i as f64 * DT;
        let vx = if ti < 3.0 {
            0.0
        } else if ti < 8.0 {
            0.5
        } else {
            0.3
        };
        let wz = if ti < 5.0 { 0.0 } else { 0.4 };
        let cmd = [vx, 0.0f32, wz];
        let mut m = [0.0f64; 3];
        for k in 0..3 {
            lag[k] += (f64::from(cmd[k]) - lag[k]) * DT / tau;
            let wiggle = 0.02 * (2.0 * std::f64::consts::PI * (1.7 + 0.3 * k as f64) * ti).sin();
            m[k] = lag[k] + wiggle;
        }
        t.push(ti);
        commanded.push(cmd);
        measured.push(m);
        estimated.push([m[0] + 0.03, m[1] - 0.01, m[2] + 0.02]);
    }
    VelocitySeries {
        title: "Velocity tracking (synthetic)".into(),
        t,
        commanded,
        measured,
        estimated,
        events: vec![(12.5, "damping: tilt".into())],
        marks: vec![(3.0, "riser 1".into()), (4.0, "end landing".into())],
    }
}

struct Decoded {
    width: u32,
    height: u32,
    rgb: Vec<[u8; 3]>,
}

fn decode(path: &std::path::Path) -> Decoded {
    let bytes = std::fs::read(path).expect("read png");
    assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n", "PNG magic bytes");
    let mut reader = png::Decoder::new(bytes.as_slice()).read_info().expect("png header");
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).expect("png frame");
    assert_eq!(info.bit_depth, png::BitDepth::Eight);
    let channels = match info.color_type {
        png::ColorType::Rgb => 3,
        png::ColorType::Rgba => 4,
        other => panic!("unexpected colour type {other:?}"),
    };
    let rgb = buf[..info.buffer_size()]
        .chunks_exact(channels)
        .map(|p| [p[0], p[1], p[2]])
        .collect();
    Decoded {
        width: info.width,
        height: info.height,
        rgb,
    }
}

/// Pixels of rows `y0..y1`.
fn band(img: &Decoded, y0: u32, y1: u32) -> &[[u8; 3]] {
    let w = img.width as usize;
    &img.rgb[y0 as usize * w..y1 as usize * w]
}

#[test]
fn renders_three_non_blank_panels() {
    let path = out_path("synthetic");
    velocity_tracking_png(&path, &synthetic()).expect("render");
    let img = decode(&path);
    assert_eq!((img.width, img.height), (1400, 1000));

    // Below the title the height splits into three equal panels; stay inside each.
    let top = 50;
    let h = (img.height - top) / 3;
    for p in 0..3 {
        let px = band(&img, top + p * h + 5, top + (p + 1) * h - 5);
        let non_white = px.iter().filter(|c| **c != [255, 255, 255]).count();
        let distinct: std::collections::HashSet<_> = px.iter().collect();
        // Measured velocity is drawn in blue; anti-aliasing blends it toward white.
        let blue = px
            .iter()
            .filter(|c| c[2] as i32 > c[0] as i32 + 60 && c[2] as i32 > c[1] as i32 + 30)
            .count();
        assert!(
            non_white * 50 > px.len(),
            "panel {p}: only {non_white} non-white pixels of {}",
            px.len()
        );
        assert!(distinct.len() > 30, "panel {p}: {} colours", distinct.len());
        assert!(blue > 500, "panel {p}: {blue} measured-line pixels");
    }
}

#[test]
fn length_mismatch_is_an_error() {
    let path = out_path("mismatch");
    let mut s = synthetic();
    s.commanded.pop();
    let err = velocity_tracking_png(&path, &s).unwrap_err();
    assert!(
        matches!(
            err,
            PlotError::LengthMismatch {
                series: "commanded",
                ..
            }
        ),
        "{err}"
    );
    assert!(!path.exists(), "no file on bad input");

    let mut s = synthetic();
    s.estimated.truncate(10);
    assert!(matches!(
        velocity_tracking_png(&path, &s),
        Err(PlotError::LengthMismatch {
            series: "estimated",
            ..
        })
    ));
}

#[test]
fn bad_input_is_an_error() {
    let path = out_path("bad");
    let empty = VelocitySeries::default();
    assert!(matches!(velocity_tracking_png(&path, &empty), Err(PlotError::Empty)));

    let mut s = synthetic();
    s.t.swap(10, 11);
    assert!(matches!(
        velocity_tracking_png(&path, &s),
        Err(PlotError::NotMonotonic { index: 11, .. })
    ));

    let jpg = path.with_extension("jpg");
    assert!(matches!(
        velocity_tracking_png(&jpg, &synthetic()),
        Err(PlotError::NotPng { .. })
    ));
    assert!(!jpg.exists());
}

#[test]
fn all_nan_measured_still_renders() {
    let path = out_path("nan");
    let mut s = synthetic();
    s.measured.iter_mut().for_each(|m| *m = [f64::NAN; 3]);
    s.estimated.clear();
    // A few non-finite times and commands as well, as a log from a reset robot might have.
    s.t[100] = f64::NAN;
    s.commanded[200] = [f32::INFINITY, f32::NAN, 0.0];
    s.events.push((f64::NAN, "never drawn".into()));
    velocity_tracking_png(&path, &s).expect("render with all-NaN measured");
    let img = decode(&path);
    assert_eq!((img.width, img.height), (1400, 1000));
}
