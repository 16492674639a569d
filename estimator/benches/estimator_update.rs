//! Estimator cost per fast tick, and the filter's sequential scalar updates against the textbook
//! batch Kalman update (S = H P Hᵀ + R inverted, K = P Hᵀ S⁻¹) on the same 18-state problem.
//! `cargo bench -p estimator --bench estimator_update`; prints medians and their ratio.
// Benchmark inputs come from std's math on the host; this never runs on the robot.
#![allow(clippy::disallowed_methods)]
use std::hint::black_box;
use std::path::PathBuf;
use std::time::Instant;

use estimator::filter::{BaseFilter, FilterConfig};
use estimator::{EstimatorConfig, LegKinematics, StateEstimator};
use hal::LowState;
use nalgebra::{SMatrix, SVector, Vector3};

/// Median ns per call of `f` over `reps` batches of `n` calls.
fn median_ns(reps: usize, n: usize, mut f: impl FnMut(usize)) -> f64 {
    let mut v: Vec<f64> = (0..reps)
        .map(|_| {
            let t = Instant::now();
            for i in 0..n {
                f(i);
            }
            t.elapsed().as_nanos() as f64 / n as f64
        })
        .collect();
    v.sort_by(f64::total_cmp);
    v[reps / 2]
}

fn kinematics() -> LegKinematics {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..");
    let candidates = [
        root.join("../shared/assets/unitree_g1_12dof/g1_12dof.xml"),
        root.join(".deps/g1_29dof/g1.xml"),
    ];
    for c in &candidates {
        if c.exists() {
            return LegKinematics::from_mjcf_file(c).expect("G1 MJCF parses");
        }
    }
    panic!("no G1 MJCF found at {candidates:?}: run scripts/install.sh with ../shared beside the checkout");
}

/// A walking-like state at tick `k`: legs swinging sinusoidally, IMU upright.
fn state(k: usize) -> LowState {
    let mut s = LowState::default();
    let t = k as f32 * 0.002;
    let w = std::f32::consts::TAU / 0.8;
    let base = [-0.1, 0.0, 0.0, 0.3, -0.2, 0.0];
    for leg in 0..2 {
        let ph = t * w + leg as f32 * std::f32::consts::PI;
        for (j, b) in base.iter().enumerate() {
            let m = &mut s.motors[leg * 6 + j];
            m.q = b + 0.2 * ph.sin() * if j == 3 { 1.0 } else { 0.3 };
            m.dq = 0.2 * w * ph.cos();
            m.tau_est = 20.0 * ph.cos() + if j == 3 { 40.0 } else { 0.0 };
        }
    }
    s.imu.quaternion = [1.0, 0.0, 0.0, 0.0];
    s.imu.accelerometer = [0.0, 0.0, 9.81];
    s.imu.gyroscope = [0.01, -0.02, 0.1];
    s
}

const N: usize = 18;
const M: usize = 14;

/// The textbook batch update of the same measurement set (6 relative foot coordinates, 6 stance
/// velocities, 2 ground heights).
fn batch_update(x: &mut SVector<f64, N>, p: &mut SMatrix<f64, N, N>, y: &SVector<f64, M>, r: &SVector<f64, M>) {
    let mut h = SMatrix::<f64, M, N>::zeros();
    for leg in 0..2 {
        for a in 0..3 {
            h[(3 * leg + a, 6 + 3 * leg + a)] = 1.0;
            h[(3 * leg + a, a)] = -1.0;
            h[(6 + 3 * leg + a, 3 + a)] = 1.0;
        }
        h[(12 + leg, 6 + 3 * leg + 2)] = 1.0;
    }
    let s = h * *p * h.transpose() + SMatrix::<f64, M, M>::from_diagonal(r);
    let s_inv = s.cholesky().expect("S is positive definite").inverse();
    let k = *p * h.transpose() * s_inv;
    *x += k * (y - h * *x);
    *p = (SMatrix::<f64, N, N>::identity() - k * h) * *p;
}

fn main() {
    let kin = kinematics();
    let states: Vec<LowState> = (0..4000).map(state).collect();

    let mut est = StateEstimator::new(Some(kin.clone()), EstimatorConfig::default(), 0.002);
    let mut tick = 0u64;
    let full = median_ns(9, 4000, |i| {
        tick += 1;
        black_box(est.update(tick, black_box(&states[i % states.len()])));
    });

    let mut att = StateEstimator::new(None, EstimatorConfig::default(), 0.002);
    let mut tick = 0u64;
    let attitude_only = median_ns(9, 4000, |i| {
        tick += 1;
        black_box(att.update(tick, black_box(&states[i % states.len()])));
    });

    let cfg = FilterConfig::default();
    let mut f = BaseFilter::new(cfg, Vector3::new(0.0, 0.0, 0.75), [Vector3::zeros(); 2]);
    let rel = [Vector3::new(0.0, 0.1, -0.72), Vector3::new(0.05, -0.1, -0.71)];
    let v = Vector3::new(0.5, 0.0, 0.0);
    let acc = Vector3::new(0.1, 0.0, 0.05);
    let sequential = median_ns(9, 20000, |_| {
        f.predict(0.002, &acc, [true, true]);
        for (i, r) in rel.iter().enumerate() {
            f.update_foot_position(i, r);
            f.update_stance_velocity(&v);
            f.update_ground_height(i, 0.03);
        }
        f.symmetrize();
        black_box(f.velocity());
    });

    let mut x = SVector::<f64, N>::zeros();
    let mut p = SMatrix::<f64, N, N>::identity() * 1e-3;
    let mut y = SVector::<f64, M>::zeros();
    for leg in 0..2 {
        for a in 0..3 {
            y[3 * leg + a] = rel[leg][a];
            y[6 + 3 * leg + a] = v[a];
        }
        y[12 + leg] = 0.03;
    }
    let mut r = SVector::<f64, M>::zeros();
    r.fixed_rows_mut::<6>(0).fill(cfg.kinematic_noise.powi(2));
    r.fixed_rows_mut::<6>(6).fill(cfg.leg_velocity_noise.powi(2));
    r.fixed_rows_mut::<2>(12)
        .fill(cfg.ground_height_noise.unwrap_or(0.01).powi(2));
    let batch = median_ns(9, 20000, |_| {
        // The same process step (as a dense F P Fᵀ + Q) then the batch update.
        let mut fm = SMatrix::<f64, N, N>::identity();
        for a in 0..3 {
            fm[(a, 3 + a)] = 0.002;
        }
        p = fm * p * fm.transpose() + SMatrix::<f64, N, N>::identity() * 1e-6;
        batch_update(&mut x, &mut p, &y, &r);
        black_box(x[3]);
    });

    println!("estimator update per fast tick (median of 9 batches):");
    println!("  full (kinematics, contact, Kalman filter): {:8.2} µs", full / 1e3);
    println!(
        "  attitude only (no kinematics):             {:8.2} µs",
        attitude_only / 1e3
    );
    println!(
        "  filter step, sequential scalar updates:    {:8.2} µs",
        sequential / 1e3
    );
    println!("  filter step, textbook batch update:        {:8.2} µs", batch / 1e3);
    println!(
        "  batch / sequential: {:.2}x;  full tick is {:.1} % of the 200 µs fast-group budget",
        batch / sequential,
        full / 2e5 * 100.0
    );
}
