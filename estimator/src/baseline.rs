//! The naive baseline the filter is judged against: dead reckoning from the accelerometer alone
//! (velocity and position integrated from rest, no leg information) and a "lower foot is down"
//! contact rule. Evaluation only; it never feeds control.
use nalgebra::{UnitQuaternion, Vector3};

/// Standard gravity, m/s².
pub const GRAVITY: f64 = 9.81;

/// Integrated accelerometer.
#[derive(Clone, Copy, Debug)]
pub struct DeadReckoning {
    pub velocity: Vector3<f64>,
    pub position: Vector3<f64>,
}

impl DeadReckoning {
    /// Starts at rest at `position`.
    pub fn new(position: Vector3<f64>) -> Self {
        Self {
            velocity: Vector3::zeros(),
            position,
        }
    }
    /// One step: `specific_force` is the accelerometer reading (body frame), `rot` the attitude.
    pub fn step(&mut self, dt: f64, rot: &UnitQuaternion<f64>, specific_force: &Vector3<f64>) {
        let a = rot * specific_force - Vector3::new(0.0, 0.0, GRAVITY);
        self.position += self.velocity * dt + 0.5 * a * dt * dt;
        self.velocity += a * dt;
    }
    /// Velocity in the body frame.
    pub fn body_velocity(&self, rot: &UnitQuaternion<f64>) -> Vector3<f64> {
        rot.inverse() * self.velocity
    }
}

/// The lower foot (gravity-aligned, relative to the base) is in contact; both are when their
/// heights differ by less than `tolerance_m`.
pub fn lower_foot_contact(foot_z: [f64; 2], tolerance_m: f64) -> [bool; 2] {
    let d = foot_z[0] - foot_z[1];
    if d.abs() < tolerance_m {
        [true, true]
    } else {
        [d < 0.0, d > 0.0]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn at_rest_the_accelerometer_reads_gravity_and_nothing_moves() {
        let mut d = DeadReckoning::new(Vector3::new(0.0, 0.0, 0.7));
        let r = UnitQuaternion::identity();
        for _ in 0..100 {
            d.step(0.002, &r, &Vector3::new(0.0, 0.0, GRAVITY));
        }
        assert!(d.velocity.norm() < 1e-12 && (d.position.z - 0.7).abs() < 1e-12);
        // A 0.1 m/s² bias grows linearly in velocity.
        for _ in 0..500 {
            d.step(0.002, &r, &Vector3::new(0.1, 0.0, GRAVITY));
        }
        assert!((d.velocity.x - 0.1).abs() < 1e-9);
    }

    #[test]
    fn lower_foot_rule() {
        assert_eq!(lower_foot_contact([-0.70, -0.60], 0.01), [true, false]);
        assert_eq!(lower_foot_contact([-0.60, -0.70], 0.01), [false, true]);
        assert_eq!(lower_foot_contact([-0.70, -0.705], 0.01), [true, true]);
    }
}
