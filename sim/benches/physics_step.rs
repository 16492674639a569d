//! µs per `mj_step` of the G1 standing under its PD, dt 0.005 (the training setting), for:
//!
//! - bare: the 12-dof MJCF as shipped (`MjModel::from_xml`: mesh collisions, joint friction loss,
//!   Euler, 100 / 50 solver iterations) with the PD computed in the loop into its motors — the
//!   alternative a trainer would otherwise step;
//! - Deploy: [`g1_sim::Simulator`] with `PhysicsProfile::Deploy` (the model's contacts and solver,
//!   implicit PD actuators, implicitfast);
//! - Training: `PhysicsProfile::Training` (feet and shins against the world only, frictionloss 0,
//!   10 / 20 iterations);
//! - Training + terrain pool: the same with 24 pooled boxes holding the `stairs-up` world;
//! - and, on that last setting, what reading the base costs beside a step: `truth()` (contacts,
//!   terrain token and stair progress as well) against `base_kinematics()` (pose and velocities
//!   only), which the trainer reads at every physics step.
//!
//! Each figure is the median of 5 runs of 4000 steps after 200 warm-up steps. Run:
//! `cargo bench -p g1_sim --bench physics_step` (figures on stdout).
use std::time::Instant;

use g1_sim::model::deps_dir;
use g1_sim::world::World;
use g1_sim::{slots, ModelChoice, PhysicsProfile, SimConfig, Simulator};
use mujoco_rs::prelude::*;

const DT: f64 = 0.005;
const STEPS: usize = 4000;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Median µs per call of `step` over 5 × `STEPS` calls.
fn time_us(mut step: impl FnMut()) -> f64 {
    for _ in 0..200 {
        step();
    }
    median(
        (0..5)
            .map(|_| {
                let t = Instant::now();
                for _ in 0..STEPS {
                    step();
                }
                t.elapsed().as_secs_f64() * 1e6 / STEPS as f64
            })
            .collect(),
    )
}

fn sim_us(choice: ModelChoice, physics: PhysicsProfile, pool: bool) -> (f64, usize) {
    let config = SimConfig {
        physics_dt: DT,
        control_dt: DT,
        physics,
        ..SimConfig::default()
    };
    let mut sim = if pool {
        let mut s = Simulator::load_with_terrain_capacity(choice, config, 24, 0).unwrap();
        s.set_world(&World::preset("stairs-up").unwrap()).unwrap();
        s.reset();
        s
    } else {
        Simulator::load(choice, config).unwrap()
    };
    sim.apply_command(&sim.hold_initial_pose_command()).unwrap();
    let us = time_us(|| sim.step_control_tick());
    let z = sim.truth().base_pos[2];
    assert!(z > 0.6, "the robot fell during the benchmark (z {z})");
    (us, sim.data().contact().len())
}

/// µs per `mj_step`, per `truth()` and per `base_kinematics()` on the training profile over the
/// pooled `stairs-up` world, the robot standing at its start.
fn readout_us() -> (f64, f64, f64) {
    let config = SimConfig {
        physics_dt: DT,
        control_dt: DT,
        physics: PhysicsProfile::Training,
        ..SimConfig::default()
    };
    let mut sim = Simulator::load_with_terrain_capacity(ModelChoice::G1_12Dof, config, 24, 0).unwrap();
    sim.set_world(&World::preset("stairs-up").unwrap()).unwrap();
    sim.reset();
    sim.apply_command(&sim.hold_initial_pose_command()).unwrap();
    let step = time_us(|| sim.step_control_tick());
    let mut sink = 0.0;
    let truth = time_us(|| sink += std::hint::black_box(sim.truth()).base_pos[2]);
    let base = time_us(|| sink += std::hint::black_box(sim.base_kinematics()).pos[2]);
    assert!(sink.is_finite());
    (step, truth, base)
}

/// The shipped 12-dof MJCF with the PD computed in the loop (what `g1_sim` did before, minus
/// its edits).
fn bare_12dof_us() -> (f64, usize) {
    let mut model = MjModel::from_xml(ModelChoice::G1_12Dof.path()).unwrap();
    model.opt_mut().timestep = DT;
    let mut data = MjData::new(Box::new(model));
    let q0: Vec<f64> = data.qpos()[7..19].to_vec();
    let gains: Vec<(f64, f64)> = (0..12)
        .map(|s| {
            let (kp, kd) = slots::hold_gains(s);
            (kp as f64, kd as f64)
        })
        .collect();
    let us = time_us(|| {
        let mut tau = [0.0; 12];
        let (q, v) = (data.qpos(), data.qvel());
        for (i, t) in tau.iter_mut().enumerate() {
            *t = gains[i].0 * (q0[i] - q[7 + i]) - gains[i].1 * v[6 + i];
        }
        data.ctrl_mut()[..12].copy_from_slice(&tau);
        data.step();
    });
    assert!(data.qpos()[2] > 0.6, "the bare model fell during the benchmark");
    (us, data.contact().len())
}

fn main() {
    if !deps_dir().join("g1_29dof/g1.xml").exists() || !ModelChoice::G1_12Dof.path().exists() {
        eprintln!("physics_step bench: needs .deps (scripts/install.sh) and ../shared; skipped");
        return;
    }
    println!("µs per mj_step, G1 standing under PD, dt {DT} (median of 5 × {STEPS} steps)");
    let (bare, bare_c) = bare_12dof_us();
    println!("12-dof bare (shipped MJCF, PD in the loop)   {bare:7.2} µs  ({bare_c} contacts)");
    for choice in [ModelChoice::G1_12Dof, ModelChoice::G1_29Dof] {
        let (dep, dep_c) = sim_us(choice.clone(), PhysicsProfile::Deploy, false);
        let (tr, tr_c) = sim_us(choice.clone(), PhysicsProfile::Training, false);
        let (trp, trp_c) = sim_us(choice.clone(), PhysicsProfile::Training, true);
        println!("{choice} Deploy                               {dep:7.2} µs  ({dep_c} contacts)");
        println!("{choice} Training                             {tr:7.2} µs  ({tr_c} contacts)");
        println!("{choice} Training + 24-box pool (stairs-up)   {trp:7.2} µs  ({trp_c} contacts)");
        println!(
            "{choice} Deploy / Training = {:.2}x{}",
            dep / tr,
            if choice == ModelChoice::G1_12Dof {
                format!(", bare / Training = {:.2}x", bare / tr)
            } else {
                String::new()
            }
        );
    }
    let (step, truth, base) = readout_us();
    println!(
        "12-dof Training + pool: truth() {truth:.3} µs ({:.1} % of a step), base_kinematics() {base:.3} µs \
         ({:.1} %); truth / base_kinematics = {:.1}x",
        100.0 * truth / step,
        100.0 * base / step,
        truth / base
    );
}
