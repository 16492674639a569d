//! Terrain worlds: ground-truth labels on hand-built scenarios, scenario-file errors, and the MuJoCo
//! geometry agreeing with the analytic ground height (seen through the simulated lidar).
// The simulator never runs on the robot: std's math is fine here (see clippy.toml).
#![allow(clippy::disallowed_methods)]
mod common;

use std::f64::consts::PI;

use g1_sim::lidar::{LidarConfig, LidarSim};
use g1_sim::world::{RandomRanges, TerrainKind, World, WorldError};
use g1_sim::{ModelChoice, SimConfig, Simulator};
use hal::TerrainClass;

fn near(a: f32, b: f64, tol: f64) -> bool {
    (a as f64 - b).abs() <= tol
}

#[test]
fn stairs_up_preset_labels() {
    let w = World::preset("stairs-up").unwrap();
    // First riser 1.2 m ahead: inside the look-ahead box.
    let z = w.truth(0.0, 0.0, 0.0);
    assert_eq!(z.class, TerrainClass::StairsUp);
    assert!(
        near(z.step_height_m, 0.15, 1e-6) && near(z.step_depth_m, 0.30, 1e-6),
        "{z:?}"
    );
    assert!(near(z.yaw_rad, 0.0, 1e-9));
    // Turned left by 0.3 rad: θ = +0.3.
    assert!(near(w.truth(0.0, 0.0, 0.3).yaw_rad, 0.3, 1e-6));
    // 2.2 m before the first riser: nothing in view.
    let z = w.truth(-1.0, 0.0, 0.0);
    assert_eq!(z.class, TerrainClass::Flat);
    assert_eq!((z.step_height_m, z.step_depth_m), (0.0, 0.0));
    // Mid-staircase (between risers at 1.8 and 2.1 m): the next riser ahead.
    let z = w.truth(1.95, 0.0, 0.0);
    assert_eq!(z.class, TerrainClass::StairsUp);
    assert!(near(z.step_height_m, 0.15, 1e-6));
    assert!((w.ground_height(1.95, 0.0) - 0.45).abs() < 1e-9);
    // On the top landing facing back down: stairs-down, θ relative to the downhill direction.
    let z = w.truth(3.5, 0.0, PI);
    assert_eq!(z.class, TerrainClass::StairsDown);
    assert!(near(z.yaw_rad, 0.0, 1e-6) && near(z.step_depth_m, 0.30, 1e-6), "{z:?}");
    // Far along the top landing, stairs behind: flat.
    assert_eq!(w.truth(4.6, 0.0, 0.0).class, TerrainClass::Flat);
    // Beside the staircase: flat.
    assert_eq!(w.truth(1.5, 1.7, 0.0).class, TerrainClass::Flat);
    assert_eq!(w.ground_height(1.95, 1.7), 0.0);
}

#[test]
fn the_labelled_riser_is_the_one_the_truth_describes() {
    let w = World::preset("stairs-up").unwrap();
    // Risers at 1.2, 1.5, 1.8, 2.1 m, ...: from the origin the first, 1.2 m ahead.
    let r = w.labelled_riser(0.0, 0.0, 0.0).expect("a riser in the box");
    assert_eq!(r.index, 0);
    assert!((r.mid_x_m - 1.2).abs() < 1e-9, "{r:?}");
    // Between the risers at 1.8 and 2.1 m: the next one ahead, 0.15 m away.
    let r = w.labelled_riser(1.95, 0.0, 0.0).unwrap();
    assert_eq!(r.index, 3);
    assert!((r.mid_x_m - 0.15).abs() < 1e-9, "{r:?}");
    // On the top landing facing back down: the last riser, ahead.
    let r = w.labelled_riser(3.5, 0.0, PI).unwrap();
    assert_eq!(r.index, r.count - 1);
    assert!(r.mid_x_m > 0.0, "{r:?}");
    // Nothing in view, and the flat preset: none (the truth is flat).
    assert_eq!(w.labelled_riser(-1.0, 0.0, 0.0), None);
    assert_eq!(World::preset("flat").unwrap().labelled_riser(0.0, 0.0, 0.0), None);
}

#[test]
fn stairs_down_and_flat_presets() {
    let w = World::preset("stairs-down").unwrap();
    assert!(
        (w.start()[2] - 0.9).abs() < 1e-9,
        "robot starts on the 6 × 0.15 m platform"
    );
    let z = w.truth(0.0, 0.0, 0.0);
    assert_eq!(z.class, TerrainClass::StairsDown);
    assert!(near(z.step_height_m, 0.15, 1e-6));
    // Walking back up it from the bottom landing.
    let z = w.truth(3.6, 0.0, PI);
    assert_eq!(z.class, TerrainClass::StairsUp);
    let f = World::preset("flat").unwrap();
    let z = f.truth(3.0, -2.0, 0.7);
    assert_eq!(z.class, TerrainClass::Flat);
    assert!(near(z.yaw_rad, 0.7, 1e-6), "flat keeps the heading");
    assert!(f.primitives().is_empty());
}

#[test]
fn yawed_staircase_from_a_scenario_file() {
    let w = World::from_toml(
        r#"
name = "yawed"
[terrain]
kind = "stairs-up"
step_height = 0.12
step_depth = 0.28
steps = 5
yaw_deg = 30.0
start_distance = 1.0
"#,
        "inline",
    )
    .unwrap();
    assert_eq!(w.name, "yawed");
    let z = w.truth(0.0, 0.0, 0.0);
    assert_eq!(z.class, TerrainClass::StairsUp);
    // Robot heading 0, stairs at +30°: the robot is turned 30° right of them.
    assert!(near(z.yaw_rad, -30f64.to_radians(), 1e-6), "{z:?}");
    assert!(near(z.step_height_m, 0.12, 1e-6) && near(z.step_depth_m, 0.28, 1e-6));
    // A point on the second tread, along the axis.
    let (c, s) = (30f64.to_radians().cos(), 30f64.to_radians().sin());
    let on = 1.0 + 0.28 + 0.14;
    assert!((w.ground_height(c * on, s * on) - 0.24).abs() < 1e-9);
}

#[test]
fn outdoor_steps_vary_and_labels_follow_the_step() {
    let w = World::preset("outdoor").unwrap();
    let st = w.stairs.as_ref().unwrap();
    let heights: Vec<f64> = st.risers.iter().map(|r| r.level_after - r.level_before).collect();
    let depths: Vec<f64> = st.risers.iter().map(|r| r.depth_after).collect();
    assert!(heights.iter().all(|h| (h - 0.13).abs() <= 0.013 + 1e-9), "{heights:?}");
    assert!(heights.windows(2).any(|p| (p[0] - p[1]).abs() > 1e-4), "jitter");
    assert!(depths.iter().all(|d| (d - 0.35).abs() <= 0.035 + 1e-9));
    assert!(st.slopes.iter().any(|s| *s != 0.0), "tread slopes");
    // Cylinders for the rounded nosings.
    assert!(w
        .primitives()
        .iter()
        .any(|p| matches!(p, g1_sim::world::Primitive::Cylinder { .. })));
    // The label is the upcoming step's own height.
    let (c, s) = (st.yaw.cos(), st.yaw.sin());
    for (i, r) in st.risers.iter().enumerate().take(5) {
        let before = st.origin[0] + c * (r.s - 0.1);
        let before_y = st.origin[1] + s * (r.s - 0.1);
        let z = w.truth(before, before_y, st.yaw);
        assert_eq!(z.class, TerrainClass::StairsUp, "step {i}");
        assert!(
            near(z.step_height_m, heights[i], 1e-6),
            "step {i}: {z:?} vs {}",
            heights[i]
        );
        assert!(near(z.step_depth_m, depths[i], 1e-6));
    }
}

#[test]
fn random_worlds_are_reproducible_and_in_range() {
    let r = RandomRanges::default();
    let mut kinds = [0; 3];
    for seed in 0..300 {
        let w = World::random(seed, &r);
        assert_eq!(w, World::random(seed, &r));
        kinds[w.spec.kind as usize] += 1;
        if w.spec.kind != TerrainKind::Flat {
            assert!((0.05..=0.25).contains(&w.spec.step_height) && (0.20..=0.45).contains(&w.spec.step_depth));
            assert!(w.spec.yaw_deg.abs() <= 45.0);
            // The robot's start is on flat ground before the first riser.
            let z = w.truth(0.0, 0.0, 0.0);
            assert!(z.yaw_rad.abs() <= 45f32.to_radians() + 1e-6 || z.class == TerrainClass::Flat);
        }
    }
    assert!(kinds.iter().all(|k| *k > 10), "all kinds drawn: {kinds:?}");
}

#[test]
fn bad_scenarios_say_what_is_wrong() {
    let e = World::from_toml("[terrain]\nkind = \"stairs-up\"\nstep_height = 0.9\n", "a.toml").unwrap_err();
    assert!(
        matches!(
            e,
            WorldError::Invalid {
                field: "step_height",
                ..
            }
        ),
        "{e}"
    );
    assert!(e.to_string().contains("step_height"));
    let e = World::from_toml("[terrain]\nkind = \"stairs-up\"\nstep_hieght = 0.1\n", "b.toml").unwrap_err();
    assert!(e.to_string().contains("step_hieght"), "{e}");
    let e = World::from_toml("[terrain]\nkind = \"ramp\"\n", "c.toml").unwrap_err();
    assert!(e.to_string().contains("c.toml"), "{e}");
    let e = World::resolve("nowhere").unwrap_err();
    assert!(e.to_string().contains("stairs-up"), "lists the presets: {e}");
    assert!(World::resolve("/nonexistent/x.toml").is_err());
    assert!(World::resolve("random:12").is_ok());
    // The robot must start on the landing.
    let e = World::from_toml(
        "[terrain]\nkind = \"stairs-down\"\nstart_distance = 2.0\nlanding_before = 1.0\n",
        "d.toml",
    )
    .unwrap_err();
    assert!(
        matches!(
            e,
            WorldError::Invalid {
                field: "landing_before",
                ..
            }
        ),
        "{e}"
    );
}

/// Every lidar return that hits the terrain lies on the analytic surface (treads) or on a riser.
#[test]
fn mujoco_geometry_matches_the_analytic_world() {
    common::require_deps();
    let model = ModelChoice::G1_29Dof;
    for name in ["stairs-up", "stairs-down", "outdoor"] {
        let world = World::preset(name).unwrap();
        let mut sim = Simulator::load_in(model.clone(), SimConfig::default(), Some(&world)).unwrap();
        let cfg = LidarConfig {
            range_noise_std: 0.0,
            dropout: 0.0,
            ..LidarConfig::default()
        };
        let mut lidar = LidarSim::new(sim.data().model(), cfg, 20_000).unwrap();
        let mut out = Vec::with_capacity(20_000);
        lidar.scan(sim.data_mut(), 0, 100_000_000, &mut out);
        assert_eq!(out.len(), 20_000);
        // Sensor pose from the MuJoCo body and the mount, to bring points to the world.
        let d = sim.data();
        let body = d
            .model()
            .name_to_id(mujoco_rs::prelude::MjtObjBase::mjOBJ_BODY, "torso_link")
            .unwrap();
        let (xp, xm) = (d.xpos()[body], d.xmat()[body]);
        let (mp, mount_rot) = (cfg.mount_xyz, g1_sim::lidar::rpy_matrix(cfg.mount_rpy));
        let (mut on_surface, mut on_riser, mut off, mut terrain_hits) = (0, 0, 0, 0);
        for r in &out {
            if r.geom < 0 {
                continue;
            }
            let gname = d
                .model()
                .id_to_name(mujoco_rs::prelude::MjtObjBase::mjOBJ_GEOM, r.geom as usize);
            if !gname.is_some_and(|n| n.starts_with("terrain_") || n == "floor") {
                continue;
            }
            terrain_hits += 1;
            let p = r.xyz.map(f64::from);
            let pb = mv(&mount_rot, p);
            let pb = [pb[0] + mp[0], pb[1] + mp[1], pb[2] + mp[2]];
            let w = mv(&xm, pb);
            let w = [w[0] + xp[0], w[1] + xp[1], w[2] + xp[2]];
            let g = world.ground_height(w[0], w[1]);
            if (w[2] - g).abs() < 0.003 {
                on_surface += 1;
            } else if w[2] < g + 0.003 || near_riser(&world, w) {
                on_riser += 1;
            } else {
                off += 1;
            }
        }
        println!(
            "{name}: {terrain_hits} terrain hits, {on_surface} on treads, {on_riser} on risers/nosings, {off} off"
        );
        assert!(
            terrain_hits > 5_000,
            "{name}: the sensor sees the ground ({terrain_hits})"
        );
        assert!(
            off as f64 <= 0.01 * terrain_hits as f64,
            "{name}: {off} points off the analytic surface"
        );
        assert!(on_surface as f64 >= 0.8 * terrain_hits as f64, "{name}");
    }
}

fn mv(m: &[f64; 9], v: [f64; 3]) -> [f64; 3] {
    [
        m[0] * v[0] + m[1] * v[1] + m[2] * v[2],
        m[3] * v[0] + m[4] * v[1] + m[5] * v[2],
        m[6] * v[0] + m[7] * v[1] + m[8] * v[2],
    ]
}

/// Within 5 cm (nosing radius, slope) of a riser plane, along the axis.
fn near_riser(world: &World, w: [f64; 3]) -> bool {
    let Some(st) = &world.stairs else { return false };
    let (s, _) = st.to_axis(w[0], w[1]);
    st.risers.iter().any(|r| (s - r.s).abs() < 0.05)
}

#[test]
fn committed_scenario_files_load() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../specs/worlds");
    let mut n = 0;
    for entry in std::fs::read_dir(&dir).expect("specs/worlds exists") {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "toml") {
            let w = World::from_file(&path).unwrap_or_else(|e| panic!("{e}"));
            assert!(w.stairs.is_some(), "{}", path.display());
            n += 1;
        }
    }
    assert!(n >= 2, "scenario examples in {}", dir.display());
}

/// Stair progress for `g1fw eval`: risers passed and the end landing, on scripted base positions
/// along a yawed, offset staircase (4 steps of 0.3 m from s = 0; end landing 1.5 m long).
#[test]
fn stair_progress_counts_risers_and_finds_the_end_landing() {
    use sim_hal::bridge::END_LANDING_MARGIN_M;
    let w = World::from_toml(
        "[terrain]\nkind = \"stairs-up\"\nsteps = 4\nstep_depth = 0.3\nstep_height = 0.12\nyaw_deg = 20.0\n\
         start_distance = 1.0\nlateral_offset = 0.2\nwidth = 1.2\nlanding_after = 1.5\n",
        "progress",
    )
    .unwrap();
    let yaw = 20f64.to_radians();
    let (u, v) = ([yaw.cos(), yaw.sin()], [-yaw.sin(), yaw.cos()]);
    // World point at axis coordinates (s, t): origin is 1.0 m along u and 0.2 m along v.
    let at = |s: f64, t: f64| {
        let (a, b) = (1.0 + s, 0.2 + t);
        [u[0] * a + v[0] * b, u[1] * a + v[1] * b]
    };
    let p = |s: f64, t: f64| {
        let q = at(s, t);
        w.stair_progress(q[0], q[1]).unwrap()
    };
    // At the start pose: 1 m before the first riser, on the axis (t = −0.2).
    let start = w.stair_progress(0.0, 0.0).unwrap();
    assert!(
        (start.axis_s + 1.0).abs() < 1e-9 && (start.axis_t + 0.2).abs() < 1e-9,
        "{start:?}"
    );
    assert_eq!((start.risers, start.risers_passed, start.on_end_landing), (4, 0, false));
    assert!((start.axis_yaw_rad as f64 - yaw).abs() < 1e-6 && (start.rise_m - 0.48).abs() < 1e-6);
    for (s, passed) in [
        (-0.01, 0),
        (0.01, 1),
        (0.29, 1),
        (0.31, 2),
        (0.61, 3),
        (0.95, 4),
        (2.0, 4),
    ] {
        assert_eq!(p(s, 0.1).risers_passed, passed, "s = {s}");
    }
    // The end landing: last riser at s = 0.9, landing to s = 2.4.
    assert!(!p(0.9 + END_LANDING_MARGIN_M - 0.01, 0.0).on_end_landing);
    assert!(p(0.9 + END_LANDING_MARGIN_M + 0.01, 0.0).on_end_landing);
    assert!(p(2.39, 0.5).on_end_landing);
    assert!(!p(2.41, 0.0).on_end_landing, "past the landing's far end");
    // Beside the staircase nothing counts.
    let beside = p(1.5, 0.7);
    assert_eq!((beside.risers_passed, beside.on_end_landing), (0, false));
    // Ground height under the base follows the steps.
    let g = |s: f64| {
        let q = at(s, 0.0);
        w.ground_height(q[0], q[1])
    };
    assert!((g(-0.5) - 0.0).abs() < 1e-9 && (g(0.45) - 0.24).abs() < 1e-9 && (g(1.5) - 0.48).abs() < 1e-9);
    // Flat worlds have no progress.
    assert!(World::preset("flat").unwrap().stair_progress(1.0, 0.0).is_none());
}
