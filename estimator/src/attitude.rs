//! Attitude: signals derived from a quaternion, and a complementary filter that stands in when the
//! IMU's own quaternion is missing or invalid.
//!
//! The G1's IMU reports an attitude quaternion from its own filter. Its roll and pitch are
//! gravity-referenced; its yaw drifts (no magnetometer). Everything the estimator reports is either
//! body-frame or vertical (velocity in the body frame, height), so a slowly drifting yaw only
//! rotates the estimator's world frame (its *heading frame*) and never biases those outputs.
use nalgebra::{Quaternion, UnitQuaternion, Vector3};

/// Gravity direction (0, 0, −1) expressed in the body frame, from a unit quaternion (w, x, y, z).
/// Same formula as unitree_rl_gym's deploy scripts.
pub fn projected_gravity(q: [f32; 4]) -> [f32; 3] {
    let [w, x, y, z] = q;
    [
        2.0 * (-z * x + w * y),
        -2.0 * (z * y + w * x),
        1.0 - 2.0 * (w * w + z * z),
    ]
}

/// Angle between the body z axis and the world z axis, radians.
pub fn tilt_rad(q: [f32; 4]) -> f32 {
    let g = projected_gravity(q);
    libm::acosf((-g[2]).clamp(-1.0, 1.0))
}

/// Roll, pitch, yaw (ZYX) from a quaternion (w, x, y, z).
pub fn rpy(q: [f32; 4]) -> [f32; 3] {
    let [w, x, y, z] = q;
    let roll = libm::atan2f(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y));
    let pitch = libm::asinf((2.0 * (w * y - z * x)).clamp(-1.0, 1.0));
    let yaw = libm::atan2f(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z));
    [roll, pitch, yaw]
}

/// The rotation by the angle `|v|` about the axis `v / |v|` (the exponential map), identity for a
/// tiny `v`. Same arithmetic as nalgebra's `UnitQuaternion::from_scaled_axis`, but its sine and cosine
/// come from `libm`, so the result has the same bits on every machine (nalgebra calls std's).
pub fn quat_from_scaled_axis(v: Vector3<f64>) -> UnitQuaternion<f64> {
    let half = v / 2.0;
    let nn = half.norm_squared();
    if nn <= f64::EPSILON * f64::EPSILON {
        return UnitQuaternion::identity();
    }
    let n = nn.sqrt();
    let (s, c) = libm::sincos(n);
    UnitQuaternion::new_unchecked(Quaternion::from_parts(c, half * (s / n)))
}

/// The IMU quaternion as a rotation, if it is finite and close to unit length.
pub fn valid_quaternion(q: [f32; 4]) -> Option<UnitQuaternion<f64>> {
    let q = Quaternion::new(q[0] as f64, q[1] as f64, q[2] as f64, q[3] as f64);
    let n = q.norm();
    (n.is_finite() && (n - 1.0).abs() < 0.05).then(|| UnitQuaternion::from_quaternion(q))
}

/// Mahony-style complementary filter (proportional only): integrates the gyro and pulls the
/// estimated gravity direction towards the accelerometer's. Yaw is unobservable and drifts.
#[derive(Clone, Copy, Debug)]
pub struct AttitudeFilter {
    q: UnitQuaternion<f64>,
    /// Correction gain, 1/s.
    gain: f64,
}

impl AttitudeFilter {
    pub fn new(gain: f64) -> Self {
        Self {
            q: UnitQuaternion::identity(),
            gain,
        }
    }
    pub fn attitude(&self) -> UnitQuaternion<f64> {
        self.q
    }
    /// Adopts an attitude from elsewhere (the IMU's quaternion while it is valid).
    pub fn sync(&mut self, q: UnitQuaternion<f64>) {
        self.q = q;
    }
    /// One step with body-frame gyro (rad/s) and accelerometer (m/s², specific force).
    pub fn step(&mut self, dt: f64, gyro: &Vector3<f64>, accel: &Vector3<f64>) {
        let mut w = *gyro;
        let n = accel.norm();
        // Trust the accelerometer's direction only near 1 g (not during impacts).
        if n.is_finite() && (n - 9.81).abs() < 3.0 {
            let up_measured = accel / n;
            let up_estimated = self.q.inverse() * Vector3::z();
            w += self.gain * up_measured.cross(&up_estimated);
        }
        if w.iter().all(|v| v.is_finite()) {
            self.q *= quat_from_scaled_axis(w * dt);
        }
    }
}

/// The filter's quaternion (w, x, y, z), re-normalised on restore only by its construction.
impl snapshot::Snapshot for AttitudeFilter {
    fn save(&self, out: &mut Vec<u8>) {
        let q = self.q.quaternion();
        [q.w, q.i, q.j, q.k].save(out);
    }

    fn restore(&mut self, input: &mut &[u8]) -> Result<(), snapshot::SnapshotError> {
        let mut c = [0.0f64; 4];
        c.restore(input)?;
        // The saved value was a unit quaternion: taken as is, so the restored filter is the saved one.
        self.q = UnitQuaternion::new_unchecked(Quaternion::new(c[0], c[1], c[2], c[3]));
        Ok(())
    }
}

#[cfg(test)]
// Tests build their inputs with std's math on the host; they never run on the robot.
#[allow(clippy::disallowed_methods)]
mod tests {
    use super::*;

    #[test]
    fn scaled_axis_matches_nalgebra() {
        for v in [
            Vector3::new(0.3, -0.2, 0.1),
            Vector3::new(0.0, 0.0, 3.0),
            Vector3::new(1e-3, 2e-3, -5e-4),
            Vector3::new(-2.5, 0.7, 1.9),
        ] {
            let ours = quat_from_scaled_axis(v);
            let theirs = UnitQuaternion::from_scaled_axis(v);
            assert!((ours.coords - theirs.coords).norm() < 1e-15, "{v}: {ours} vs {theirs}");
        }
        assert_eq!(quat_from_scaled_axis(Vector3::zeros()), UnitQuaternion::identity());
        assert_eq!(
            quat_from_scaled_axis(Vector3::new(1e-17, 0.0, 0.0)),
            UnitQuaternion::identity()
        );
    }

    #[test]
    fn upright_sees_gravity_down() {
        assert_eq!(projected_gravity([1.0, 0.0, 0.0, 0.0]), [0.0, 0.0, -1.0]);
        assert!(tilt_rad([1.0, 0.0, 0.0, 0.0]).abs() < 1e-6);
    }

    #[test]
    fn pitched_forward_sees_gravity_ahead() {
        // +0.3 rad pitch about y: gravity in the body frame tilts towards +x.
        let a = 0.3f32;
        let q = [(a / 2.0).cos(), 0.0, (a / 2.0).sin(), 0.0];
        let g = projected_gravity(q);
        assert!((g[0] - a.sin()).abs() < 1e-6 && (g[2] + a.cos()).abs() < 1e-6, "{g:?}");
        assert!((tilt_rad(q) - a).abs() < 1e-5);
        assert!((rpy(q)[1] - a).abs() < 1e-5);
    }

    #[test]
    fn complementary_filter_levels_out_from_a_wrong_start() {
        let mut f = AttitudeFilter::new(2.0);
        f.sync(UnitQuaternion::from_euler_angles(0.3, -0.2, 0.0));
        // Resting level robot: accelerometer reads +g up, gyro zero.
        for _ in 0..2000 {
            f.step(0.002, &Vector3::zeros(), &Vector3::new(0.0, 0.0, 9.81));
        }
        let (r, p, _) = f.attitude().euler_angles();
        assert!(r.abs() < 1e-3 && p.abs() < 1e-3, "{r} {p}");
        assert!(valid_quaternion([f32::NAN, 0.0, 0.0, 0.0]).is_none());
        assert!(valid_quaternion([0.5, 0.0, 0.0, 0.0]).is_none());
        assert!(valid_quaternion([1.0, 0.0, 0.0, 0.0]).is_some());
    }
}
