//! Linear Kalman filter for base position, base velocity and foot positions, after the MIT
//! Cheetah 3 estimator (Bledt et al., 2018): the IMU's acceleration drives the process model; leg
//! kinematics measure where each foot is relative to the base and, for a foot in contact, the
//! base velocity; contact decides how much a foot may move.
//!
//! State (world frame = the IMU's heading frame, 18 values): base position `p`, base velocity
//! `v`, left foot `f_L`, right foot `f_R`. Orientation is not a state: it comes from the attitude
//! source every tick, which keeps the filter linear.
//!
//! Updates are sequential scalar updates (the measurement noise is diagonal, so this equals the
//! batch update) and need no matrix inverse; everything lives in fixed-size arrays.
use nalgebra::{SMatrix, SVector, Vector3};

pub const N: usize = 18;
const P: usize = 0;
const V: usize = 3;
/// First state index of foot `i`.
const fn foot(i: usize) -> usize {
    6 + 3 * i
}

/// Noise model of the filter. Standard deviations; `_rate` ones are per √s.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FilterConfig {
    /// Process noise on the base acceleration (IMU error and unmodelled terms), m/s² per √Hz.
    pub accel_noise: f64,
    /// Process noise on the base position, m/√s.
    pub position_rate: f64,
    /// Random walk of a foot in contact (slip), m/√s.
    pub stance_foot_rate: f64,
    /// Random walk of a foot in the air: large, so kinematics alone place it.
    pub swing_foot_rate: f64,
    /// Foot position relative to the base from kinematics (encoders, link lengths), m.
    pub kinematic_noise: f64,
    /// Base velocity from a stance leg's odometry, m/s.
    pub leg_velocity_noise: f64,
    /// Flat-ground prior: a foot in contact is at height 0 with this standard deviation (m).
    /// `None` turns it off (height then comes from leg odometry alone, e.g. on stairs).
    pub ground_height_noise: Option<f64>,
    /// Stance velocity measurements whose normalised innovation exceeds this many standard
    /// deviations are dropped as slips.
    pub velocity_gate_sigma: f64,
    /// How far a loaded sole sinks per newton of vertical load (rubber sole and ground), m/N. A
    /// foot carrying the robot sits a few millimetres lower than an unloaded one.
    pub sole_compliance_m_per_n: f64,
}

impl Default for FilterConfig {
    fn default() -> Self {
        Self {
            accel_noise: 0.5,
            position_rate: 0.002,
            stance_foot_rate: 0.01,
            swing_foot_rate: 2.0,
            kinematic_noise: 0.003,
            leg_velocity_noise: 0.06,
            ground_height_noise: Some(0.003),
            velocity_gate_sigma: 5.0,
            // Measured no better on the simulator's soft contacts; kept for real soles.
            sole_compliance_m_per_n: 0.0,
        }
    }
}

/// The filter's state and covariance.
#[derive(Clone, Debug)]
pub struct BaseFilter {
    cfg: FilterConfig,
    x: SVector<f64, N>,
    p: SMatrix<f64, N, N>,
    /// Velocity measurements dropped by the gate since start.
    rejected: u64,
}

impl BaseFilter {
    /// A filter at rest: base at `base`, feet at `feet` (world frame).
    pub fn new(cfg: FilterConfig, base: Vector3<f64>, feet: [Vector3<f64>; 2]) -> Self {
        let mut x = SVector::<f64, N>::zeros();
        x.fixed_rows_mut::<3>(P).copy_from(&base);
        for (i, f) in feet.iter().enumerate() {
            x.fixed_rows_mut::<3>(foot(i)).copy_from(f);
        }
        let mut p = SMatrix::<f64, N, N>::zeros();
        for i in 0..N {
            p[(i, i)] = match i {
                0..3 => 1e-4,
                3..6 => 0.1 * 0.1,
                _ => 1e-4,
            };
        }
        Self { cfg, x, p, rejected: 0 }
    }

    pub fn config(&self) -> &FilterConfig {
        &self.cfg
    }
    pub fn position(&self) -> Vector3<f64> {
        self.x.fixed_rows::<3>(P).into()
    }
    pub fn velocity(&self) -> Vector3<f64> {
        self.x.fixed_rows::<3>(V).into()
    }
    pub fn foot(&self, i: usize) -> Vector3<f64> {
        self.x.fixed_rows::<3>(foot(i)).into()
    }
    /// Standard deviation of state `i`.
    pub fn std(&self, i: usize) -> f64 {
        self.p[(i, i)].max(0.0).sqrt()
    }
    pub fn velocity_std(&self) -> Vector3<f64> {
        Vector3::new(self.std(V), self.std(V + 1), self.std(V + 2))
    }
    pub fn rejected_velocity_updates(&self) -> u64 {
        self.rejected
    }
    /// Every state and covariance entry is finite.
    pub fn is_finite(&self) -> bool {
        self.x.iter().all(|v| v.is_finite()) && self.p.iter().all(|v| v.is_finite())
    }

    /// Process step over `dt` with world acceleration `acc` (gravity removed); `contact` sets
    /// each foot's process noise.
    pub fn predict(&mut self, dt: f64, acc: &Vector3<f64>, contact: [bool; 2]) {
        for a in 0..3 {
            self.x[P + a] += self.x[V + a] * dt + 0.5 * acc[a] * dt * dt;
            self.x[V + a] += acc[a] * dt;
        }
        // P ← F P Fᵀ with F = I + dt·(p ← v): a row operation, then the same on columns.
        for j in 0..N {
            for a in 0..3 {
                let v = self.p[(V + a, j)];
                self.p[(P + a, j)] += dt * v;
            }
        }
        for i in 0..N {
            for a in 0..3 {
                let v = self.p[(i, V + a)];
                self.p[(i, P + a)] += dt * v;
            }
        }
        let c = &self.cfg;
        for a in 0..3 {
            self.p[(P + a, P + a)] += c.position_rate * c.position_rate * dt;
            self.p[(V + a, V + a)] += c.accel_noise * c.accel_noise * dt;
            for (i, &in_contact) in contact.iter().enumerate() {
                let r = if in_contact {
                    c.stance_foot_rate
                } else {
                    c.swing_foot_rate
                };
                self.p[(foot(i) + a, foot(i) + a)] += r * r * dt;
            }
        }
    }

    /// Scalar update of `y = x[a] − x[b]` (or `x[a]` when `b` is `None`) with variance `r`.
    /// Returns false (and changes nothing) when the innovation fails the gate.
    fn update(&mut self, a: usize, b: Option<usize>, y: f64, r: f64, gate_sigma: Option<f64>) -> bool {
        let mut ph = [0.0f64; N];
        for (i, v) in ph.iter_mut().enumerate() {
            *v = self.p[(i, a)] - b.map_or(0.0, |b| self.p[(i, b)]);
        }
        let s = ph[a] - b.map_or(0.0, |b| ph[b]) + r;
        let innovation = y - (self.x[a] - b.map_or(0.0, |b| self.x[b]));
        if s.is_nan() || s <= 0.0 || !innovation.is_finite() {
            return false;
        }
        if let Some(g) = gate_sigma {
            if innovation * innovation > g * g * s {
                return false;
            }
        }
        for i in 0..N {
            let k = ph[i] / s;
            self.x[i] += k * innovation;
            for (j, phj) in ph.iter().enumerate() {
                self.p[(i, j)] -= k * phj;
            }
        }
        true
    }

    /// Foot `i` sits at `rel` from the base (world frame, from kinematics).
    pub fn update_foot_position(&mut self, i: usize, rel: &Vector3<f64>) {
        let r = self.cfg.kinematic_noise * self.cfg.kinematic_noise;
        for a in 0..3 {
            self.update(foot(i) + a, Some(P + a), rel[a], r, None);
        }
    }

    /// A foot in contact says the base moves at `v` (world frame, from leg odometry). Returns the
    /// number of axes the gate dropped.
    pub fn update_stance_velocity(&mut self, v: &Vector3<f64>) -> u32 {
        let r = self.cfg.leg_velocity_noise * self.cfg.leg_velocity_noise;
        let gate = Some(self.cfg.velocity_gate_sigma);
        let mut dropped = 0;
        for a in 0..3 {
            if !self.update(V + a, None, v[a], r, gate) {
                dropped += 1;
            }
        }
        self.rejected += dropped as u64;
        dropped
    }

    /// Flat-ground prior for a foot in contact (no-op when the config turns it off).
    pub fn update_ground_height(&mut self, i: usize, ground_z: f64) {
        if let Some(s) = self.cfg.ground_height_noise {
            self.update(foot(i) + 2, None, ground_z, s * s, None);
        }
    }

    /// Restores exact symmetry lost to rounding in the updates.
    pub fn symmetrize(&mut self) {
        for i in 0..N {
            for j in i + 1..N {
                let m = 0.5 * (self.p[(i, j)] + self.p[(j, i)]);
                self.p[(i, j)] = m;
                self.p[(j, i)] = m;
            }
        }
    }
}

/// The state and its covariance (and the rejections counted).
impl snapshot::Snapshot for BaseFilter {
    fn save(&self, out: &mut Vec<u8>) {
        self.x.as_slice().save(out);
        self.p.as_slice().save(out);
        self.rejected.save(out);
    }

    fn restore(&mut self, input: &mut &[u8]) -> Result<(), snapshot::SnapshotError> {
        self.x.as_mut_slice().restore(input)?;
        self.p.as_mut_slice().restore(input)?;
        self.rejected.restore(input)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn constant_acceleration_is_integrated() {
        let mut f = BaseFilter::new(FilterConfig::default(), Vector3::zeros(), [Vector3::zeros(); 2]);
        let a = Vector3::new(1.0, 0.0, 0.0);
        for _ in 0..500 {
            f.predict(0.002, &a, [false; 2]);
        }
        assert!((f.velocity().x - 1.0).abs() < 1e-9);
        assert!((f.position().x - 0.5).abs() < 1e-9);
        assert!(f.std(V) > f.std(P + 2) || f.std(V) > 0.0);
    }

    #[test]
    fn stance_odometry_pulls_velocity_and_gate_drops_outliers() {
        let mut f = BaseFilter::new(FilterConfig::default(), Vector3::zeros(), [Vector3::zeros(); 2]);
        let truth = Vector3::new(0.4, -0.1, 0.0);
        for _ in 0..200 {
            f.predict(0.002, &Vector3::zeros(), [true, true]);
            f.update_stance_velocity(&truth);
        }
        assert!((f.velocity() - truth).norm() < 1e-3, "{}", f.velocity());
        let before = f.velocity();
        // A slipping foot claims 3 m/s: far outside the gate.
        assert_eq!(f.update_stance_velocity(&Vector3::new(3.0, 0.0, 0.0)), 1);
        assert!((f.velocity().x - before.x).abs() < 1e-12);
        assert_eq!(f.rejected_velocity_updates(), 1);
    }

    #[test]
    fn stationary_foot_fixes_the_base() {
        // The foot is 0.7 m below the base; the base drifts in the process model but kinematics and
        // the ground prior bring its height back.
        let mut f = BaseFilter::new(
            FilterConfig::default(),
            Vector3::new(0.0, 0.0, 0.8),
            [Vector3::new(0.0, 0.1, 0.0), Vector3::new(0.0, -0.1, 0.0)],
        );
        for _ in 0..1000 {
            f.predict(0.002, &Vector3::new(0.0, 0.0, 0.3), [true, true]);
            f.update_foot_position(0, &Vector3::new(0.0, 0.1, -0.7));
            f.update_foot_position(1, &Vector3::new(0.0, -0.1, -0.7));
            f.update_ground_height(0, 0.0);
            f.update_ground_height(1, 0.0);
            f.symmetrize();
        }
        assert!((f.position().z - 0.7).abs() < 0.01, "{}", f.position());
        assert!(f.velocity().norm() < 0.05, "{}", f.velocity());
        assert!(f.is_finite());
    }
}
