//! State estimation for the G1. For now: attitude-derived signals the policy and the safety checks
//! need (projected gravity, tilt); the filters of the estimator work grow here.

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
    (-g[2]).clamp(-1.0, 1.0).acos()
}

/// Roll, pitch, yaw (ZYX) from a quaternion (w, x, y, z).
pub fn rpy(q: [f32; 4]) -> [f32; 3] {
    let [w, x, y, z] = q;
    let roll = (2.0 * (w * x + y * z)).atan2(1.0 - 2.0 * (x * x + y * y));
    let pitch = (2.0 * (w * y - z * x)).clamp(-1.0, 1.0).asin();
    let yaw = (2.0 * (w * z + x * y)).atan2(1.0 - 2.0 * (y * y + z * z));
    [roll, pitch, yaw]
}

#[cfg(test)]
mod tests {
    use super::*;

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
}
