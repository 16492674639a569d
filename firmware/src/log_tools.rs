//! Tools over recorded logs: a summary (`g1fw log-info`) and the velocity-tracking plot
//! (`g1fw plot`).
use std::collections::BTreeMap;
use std::path::Path;

use anyhow::Result;
#[cfg(feature = "lab")]
use anyhow::{bail, Context};
use serde::Serialize;

#[cfg(feature = "lab")]
use crate::plot::{velocity_tracking_png, VelocitySeries};
use runlog::log::channels as ch;
use runlog::log::LogFile;

#[derive(Debug, Serialize)]
pub struct LogInfo {
    pub path: String,
    pub bytes: u64,
    pub metadata: BTreeMap<String, String>,
    pub messages: BTreeMap<String, u64>,
    pub first_tick: Option<u64>,
    pub last_tick: Option<u64>,
    pub safety_events: Vec<serde_json::Value>,
    pub hal_events: Vec<serde_json::Value>,
    /// Set when the log ends without its summary (the writer was killed).
    pub truncated: Option<String>,
    /// Set when the log fails a check; what is listed is what precedes the damage.
    pub damaged: Option<runlog::log::reader::Damage>,
}

pub fn log_info(path: &Path) -> Result<LogInfo> {
    let log = LogFile::open(path)?;
    let mut metadata = log.run_metadata()?;
    if let Some(t) = metadata.get_mut(runlog::replay::key::SPEC_TOML) {
        *t = format!("<{} bytes of TOML>", t.len());
    }
    let mut messages = BTreeMap::new();
    let (mut first, mut last) = (None, None);
    let (mut safety, mut hal) = (Vec::new(), Vec::new());
    let end = log.scan(|topic, _t, data| {
        *messages.entry(topic.to_string()).or_insert(0u64) += 1;
        match topic {
            ch::LOW_STATE => {
                if let Some(f) = ch::decode_low_state_frame(data) {
                    first.get_or_insert(f.tick);
                    last = Some(f.tick);
                }
            }
            ch::SAFETY_EVENT => safety.extend(serde_json::from_slice::<serde_json::Value>(data).ok()),
            ch::HAL_EVENT => hal.extend(serde_json::from_slice::<serde_json::Value>(data).ok()),
            _ => {}
        }
    });
    Ok(LogInfo {
        path: path.display().to_string(),
        bytes: log.bytes.len() as u64,
        metadata,
        messages,
        first_tick: first,
        last_tick: last,
        safety_events: safety,
        hal_events: hal,
        truncated: end.truncated,
        damaged: end.damaged,
    })
}

/// Commanded (operator channel) vs measured (simulator truth) body velocity, with safety events.
#[cfg(feature = "lab")]
pub fn plot_log(path: &Path, out: &Path) -> Result<()> {
    let log = LogFile::open(path)?;
    let meta = log.run_metadata()?;
    let mut s = VelocitySeries {
        title: format!(
            "{} — {} on {}",
            path.file_name()
                .map_or(String::new(), |n| n.to_string_lossy().into_owned()),
            meta.get("spec_path").map_or("?", String::as_str),
            meta.get("model").map_or("?", String::as_str)
        ),
        t: Vec::new(),
        commanded: Vec::new(),
        measured: Vec::new(),
        estimated: Vec::new(),
        events: Vec::new(),
        marks: Vec::new(),
    };
    let mut command = [0f32; 3];
    // The newest valid estimate, paired with the truth of the same tick (written after it).
    let mut estimate: Option<[f64; 3]> = None;
    let mut any_estimate = false;
    #[derive(serde::Deserialize)]
    struct Xy {
        x: f64,
        y: f64,
    }
    #[derive(serde::Deserialize)]
    struct Z {
        z: f64,
    }
    #[derive(serde::Deserialize)]
    struct Stairs {
        risers_passed: u16,
        on_end_landing: bool,
    }
    #[derive(serde::Deserialize)]
    struct Truth {
        lin_vel_body: Xy,
        ang_vel_body: Z,
        #[serde(default)]
        stairs: Option<Stairs>,
    }
    // On a staircase, each riser passed and the arrival on the end landing are marked.
    let (mut risers_passed, mut landed) = (0u16, false);
    #[derive(serde::Deserialize)]
    struct Est {
        valid: bool,
        lin_vel_body: Xy,
        ang_vel_body: Z,
    }
    #[derive(serde::Deserialize)]
    struct Op {
        vx: f32,
        vy: f32,
        wz: f32,
    }
    #[derive(serde::Deserialize)]
    struct Ev {
        time_s: f64,
        event: String,
        reason: String,
        joint: String,
    }
    // Nothing is drawn from a damaged log.
    log.undamaged(log.scan(|topic, t_ns, data| match topic {
        ch::OPERATOR => {
            if let Ok(o) = serde_json::from_slice::<Op>(data) {
                command = [o.vx, o.vy, o.wz];
            }
        }
        ch::ESTIMATOR => {
            estimate = serde_json::from_slice::<Est>(data)
                .ok()
                .filter(|e| e.valid)
                .map(|e| [e.lin_vel_body.x, e.lin_vel_body.y, e.ang_vel_body.z]);
        }
        ch::TRUTH => {
            if let Ok(tr) = serde_json::from_slice::<Truth>(data) {
                let m = [tr.lin_vel_body.x, tr.lin_vel_body.y, tr.ang_vel_body.z];
                any_estimate |= estimate.is_some();
                s.estimated.push(estimate.unwrap_or(m));
                s.t.push(t_ns as f64 * 1e-9);
                s.commanded.push(command);
                s.measured
                    .push([tr.lin_vel_body.x, tr.lin_vel_body.y, tr.ang_vel_body.z]);
                if let Some(st) = tr.stairs {
                    let t = t_ns as f64 * 1e-9;
                    if st.risers_passed > risers_passed {
                        risers_passed = st.risers_passed;
                        s.marks.push((t, format!("riser {risers_passed}")));
                    }
                    if st.on_end_landing && !landed {
                        landed = true;
                        s.marks.push((t, "end landing".into()));
                    }
                }
            }
        }
        ch::SAFETY_EVENT => {
            if let Ok(e) = serde_json::from_slice::<Ev>(data) {
                let label = if e.joint.is_empty() {
                    format!("{}: {}", e.event, e.reason)
                } else {
                    format!("{}: {} ({})", e.event, e.reason, e.joint)
                };
                s.events.push((e.time_s, label));
            }
        }
        _ => {}
    }))?;
    if !any_estimate {
        // Logs from specs without leg kinematics: no estimate to draw.
        s.estimated.clear();
    }
    if s.t.is_empty() {
        bail!(
            "{} has no simulator ground truth ({}); only logs of `g1fw sim` runs can be plotted",
            path.display(),
            ch::TRUTH
        );
    }
    velocity_tracking_png(out, &s).with_context(|| format!("plotting {}", path.display()))?;
    Ok(())
}
