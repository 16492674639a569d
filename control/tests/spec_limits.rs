//! No setting switches a guard off: every numeric field of a deploy spec (those its file writes and
//! every bounded one), set through `--set` to hostile values, is either refused by name or leaves a
//! supervisor that still trips on each fault within the loosest bound's time, and a control period a
//! stop can interrupt.
// Test inputs come from std's math on the host; this never runs on the robot.
#![allow(clippy::disallowed_methods)]
mod common;
use common::healthy;
use std::path::{Path, PathBuf};

use control::spec::limits::{markdown_table, BOUNDS};
use control::spec::DeploySpec;
use control::supervisor::{DampingReason, FrameStatus, Supervisor};
use hal::{ErrorKind, LowState, NUM_MOTORS};

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

const HOSTILE: &[&str] = &[
    "0",
    "-1",
    "1e-9",
    "0.5",
    "3.14159",
    "7",
    "1e3",
    "32767",
    "4e9",
    "1e30",
    "nan",
    "inf",
    "-inf",
    "4294967295",
    "18446744073709551615",
];

/// Every numeric leaf of a TOML table, as dotted keys (arrays as a whole: `--set` replaces them).
fn numeric_leaves(t: &toml::Table, prefix: &str, out: &mut Vec<(String, usize)>) {
    for (k, v) in t {
        let key = if prefix.is_empty() {
            k.clone()
        } else {
            format!("{prefix}.{k}")
        };
        match v {
            toml::Value::Integer(_) | toml::Value::Float(_) => out.push((key, 0)),
            toml::Value::Array(a) if a.iter().all(|x| x.is_integer() || x.is_float()) && !a.is_empty() => {
                out.push((key, a.len()))
            }
            toml::Value::Table(t) => numeric_leaves(t, &key, out),
            _ => {}
        }
    }
}

/// The first trip of a fresh supervisor fed healthy states, then `bad` for at most `ticks` ticks.
fn trips_within(spec: &DeploySpec, ticks: u64, bad: impl Fn(u64) -> (FrameStatus, LowState)) -> Option<DampingReason> {
    let mut sup = Supervisor::new(spec, [true; NUM_MOTORS]);
    for k in 0..20 {
        assert_eq!(
            sup.check_frame(k, FrameStatus::Fresh, &healthy(k)),
            None,
            "a healthy state tripped"
        );
    }
    (20..20 + ticks).find_map(|k| {
        let (f, s) = bad(k);
        sup.check_frame(k, f, &s)
    })
}

/// Each guard still trips, within the time its loosest allowed setting takes.
fn guards_hold(spec: &DeploySpec, what: &str) {
    let hz = spec.rates.control_hz as f64;
    assert!(
        (1e-3..=2e-2).contains(&spec.control_dt()),
        "{what}: a control period of {} s",
        spec.control_dt()
    );
    let bound = |field: &str| BOUNDS.iter().find(|b| b.field == field).unwrap().hi;
    let ticks = |s: f64| (s * hz).ceil() as u64 + 2;
    let frame_ticks = |n: f64| n as u64 + 2;
    let trip = trips_within(spec, ticks(bound("safety.state_timeout_s")), |_| {
        (FrameStatus::NoFrame, LowState::default())
    });
    assert_eq!(trip, Some(DampingReason::StateTimeout), "{what}: silence");
    // The robot frozen: the same frame again and again (its counter stops).
    let trip = trips_within(spec, ticks(bound("safety.state_timeout_s")), |_| {
        (FrameStatus::Fresh, healthy(19))
    });
    assert_eq!(trip, Some(DampingReason::StateTimeout), "{what}: a frozen robot");
    let trip = trips_within(spec, frame_ticks(bound("safety.crc_failure_streak")), |_| {
        (FrameStatus::Bad(ErrorKind::Checksum), LowState::default())
    });
    assert_eq!(trip, Some(DampingReason::CrcStreak), "{what}: damaged frames");
    let tilt = bound("safety.tilt_limit_rad") as f32 + 0.05;
    let trip = trips_within(spec, 1, |k| {
        let mut s = healthy(k);
        s.imu.quaternion = [(tilt / 2.0).cos(), (tilt / 2.0).sin(), 0.0, 0.0];
        (FrameStatus::Fresh, s)
    });
    assert_eq!(trip, Some(DampingReason::Tilt), "{what}: lying down");
    let spin = bound("safety.base_ang_speed_limit_rad_s") as f32 + 0.5;
    let trip = trips_within(spec, 1, |k| {
        let mut s = healthy(k);
        s.imu.gyroscope = [0.0, 0.0, spin];
        (FrameStatus::Fresh, s)
    });
    assert_eq!(trip, Some(DampingReason::BaseAngularSpeed), "{what}: spinning");
    for (field, i) in [("safety.motor_casing_limit_c", 0), ("safety.motor_winding_limit_c", 1)] {
        let hot = bound(field) as i16 + 1;
        let trip = trips_within(spec, 1, |k| {
            let mut s = healthy(k);
            s.motors[3].temperature[i] = hot;
            (FrameStatus::Fresh, s)
        });
        assert_eq!(
            trip,
            Some(DampingReason::MotorTemperature { slot: 3 }),
            "{what}: {field}"
        );
    }
    let fast = bound("safety.joint_speed_limit_rad_s") as f32 + 1.0;
    let trip = trips_within(spec, 1, |k| {
        let mut s = healthy(k);
        s.motors[3].dq = fast;
        (FrameStatus::Fresh, s)
    });
    assert_eq!(
        trip,
        Some(DampingReason::JointSpeed { slot: 3 }),
        "{what}: a joint too fast"
    );
    let slot = spec.policy.joint_ids_map[0] as u8;
    let trip = trips_within(spec, frame_ticks(bound("safety.frozen_state_frames")), |k| {
        let mut s = healthy(k);
        let still = healthy(19).motors[slot as usize];
        s.motors[slot as usize] = still;
        (FrameStatus::Fresh, s)
    });
    assert_eq!(
        trip,
        Some(DampingReason::FrozenJoint { slot }),
        "{what}: a frozen joint"
    );
}

#[test]
fn no_setting_switches_a_guard_off() {
    let path = root().join("specs/test/rl_lab_style.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    let table: toml::Table = toml::from_str(&text).unwrap();
    let mut fields = Vec::new();
    numeric_leaves(&table, "", &mut fields);
    for b in BOUNDS {
        if !fields.iter().any(|(f, _)| f == b.field) {
            fields.push((b.field.to_string(), 0));
        }
    }
    assert!(fields.len() > 20, "walked only {} fields", fields.len());
    guards_hold(&DeploySpec::load(&path).unwrap(), "the spec as written");
    let (mut accepted, mut refused) = (0, 0);
    for (field, len) in &fields {
        for v in HOSTILE {
            let value = if *len == 0 {
                v.to_string()
            } else {
                format!("[{}]", vec![*v; *len].join(", "))
            };
            let set = format!("{field}={value}");
            match DeploySpec::load_with_overrides(&path, std::slice::from_ref(&set)) {
                Ok(spec) => {
                    guards_hold(&spec, &set);
                    accepted += 1;
                }
                Err(e) => {
                    let e = e.to_string();
                    // Refused by name (a value TOML cannot hold is refused by the parser, naming it).
                    let leaf = field.rsplit('.').next().unwrap();
                    assert!(
                        e.contains(leaf) || e.contains(field.as_str()) || e.contains("invalid"),
                        "{set}: {e}"
                    );
                    refused += 1;
                }
            }
        }
    }
    assert!(
        accepted > 0 && refused > accepted,
        "accepted {accepted}, refused {refused}"
    );
}

#[test]
fn each_bound_is_refused_just_outside_and_accepted_at_its_edges() {
    let path = root().join("specs/test/rl_lab_style.toml");
    for b in BOUNDS {
        // Rates must also divide each other: their edges are checked by the walk above.
        if b.field.starts_with("rates.") {
            let e =
                DeploySpec::load_with_overrides(&path, &[format!("{}={}", b.field, (b.hi as u64) * 2)]).unwrap_err();
            assert!(
                e.to_string().contains(b.field.rsplit('.').next().unwrap()),
                "{}: {e}",
                b.field
            );
            continue;
        }
        let integer = matches!(
            b.field,
            "safety.motor_winding_limit_c"
                | "safety.motor_casing_limit_c"
                | "safety.crc_failure_streak"
                | "safety.frozen_state_frames"
        );
        let fmt = |v: f64| {
            if integer {
                format!("{}", v as i64)
            } else {
                format!("{v:?}")
            }
        };
        for edge in [b.lo, b.hi] {
            DeploySpec::load_with_overrides(&path, &[format!("{}={}", b.field, fmt(edge))])
                .unwrap_or_else(|e| panic!("{} = {edge} is within bounds: {e}", b.field));
        }
        let step = if integer { 1.0 } else { (b.hi - b.lo).max(1e-3) * 0.01 };
        let over = DeploySpec::load_with_overrides(&path, &[format!("{}={}", b.field, fmt(b.hi + step))]).unwrap_err();
        assert!(over.to_string().contains(b.field), "{}: {over}", b.field);
        if b.lo > 0.0 {
            let under = DeploySpec::load_with_overrides(&path, &[format!("{}={}", b.field, fmt(b.lo - step))]);
            assert!(under.is_err(), "{} = {} below its bound loaded", b.field, b.lo - step);
        }
    }
}

#[test]
fn docs_list_every_bound() {
    let doc = std::fs::read_to_string(root().join("docs/spec_limits.md")).expect("docs/spec_limits.md");
    let table = markdown_table();
    assert!(
        doc.contains(&table),
        "docs/spec_limits.md must hold control::spec::limits::markdown_table() verbatim; paste this:\n{table}"
    );
}
