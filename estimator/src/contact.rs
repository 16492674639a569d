//! Foot contact from joint torques: the ground's force on the foot is what the leg's measured
//! torques push against. With the 6×6 foot Jacobian `J` (pelvis frame), the motors' torques `τ`
//! balance an external wrench `F` at the foot as `τ = −Jᵀ F` (leg inertia and weight neglected);
//! its vertical component in the world frame is the contact force. A swinging leg's own weight
//! reads as a small *downward* force, a stance leg carries a share of the robot's ~315 N.
//! Hysteresis between two thresholds keeps the decision from chattering at touchdown and lift-off.
use nalgebra::{Matrix6, UnitQuaternion, Vector6};

use crate::kinematics::LegPose;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ContactConfig {
    /// A foot not in contact enters contact above this vertical force, N.
    pub on_force_n: f64,
    /// A foot in contact leaves it below this vertical force, N.
    pub off_force_n: f64,
}

impl Default for ContactConfig {
    fn default() -> Self {
        Self {
            on_force_n: 40.0,
            off_force_n: 25.0,
        }
    }
}

/// Vertical ground force on a foot (world frame, N, up positive) from the leg's joint torques.
/// `None` when the Jacobian is singular (leg fully stretched) or the inputs are not finite.
pub fn vertical_force(pose: &LegPose, base_rot: &UnitQuaternion<f64>, tau: &[f64; 6]) -> Option<f64> {
    let j = pose.spatial_jacobian();
    let t = Vector6::from_column_slice(tau);
    // Solve Jᵀ F = −τ through the damped normal equations (J Jᵀ + λI) F = −J τ; λ keeps a
    // near-singular leg from producing huge forces.
    let a: Matrix6<f64> = j * j.transpose() + Matrix6::identity() * 1e-6;
    let rhs = -(j * t);
    let f = a.cholesky()?.solve(&rhs);
    let fz = (base_rot * f.fixed_rows::<3>(0).into_owned()).z;
    fz.is_finite().then_some(fz)
}

/// Per-foot contact state with hysteresis.
#[derive(Clone, Copy, Debug, Default)]
pub struct ContactDetector {
    cfg: ContactConfig,
    contact: [bool; 2],
    force: [f64; 2],
}

impl ContactDetector {
    pub fn new(cfg: ContactConfig) -> Self {
        Self {
            cfg,
            // Start standing: the robot is put down on both feet.
            contact: [true; 2],
            force: [0.0; 2],
        }
    }
    /// Feeds this tick's vertical forces (`None`: keep the previous decision).
    pub fn update(&mut self, force: [Option<f64>; 2]) -> [bool; 2] {
        for (i, f) in force.into_iter().enumerate() {
            if let Some(f) = f {
                self.force[i] = f;
                self.contact[i] = if self.contact[i] {
                    f > self.cfg.off_force_n
                } else {
                    f > self.cfg.on_force_n
                };
            }
        }
        self.contact
    }
    pub fn contact(&self) -> [bool; 2] {
        self.contact
    }
    /// Last vertical forces, N.
    pub fn force(&self) -> [f64; 2] {
        self.force
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hysteresis_holds_between_thresholds() {
        let mut c = ContactDetector::new(ContactConfig::default());
        assert_eq!(c.update([Some(10.0), Some(100.0)]), [false, true]);
        assert_eq!(c.update([Some(30.0), Some(30.0)]), [false, true]);
        assert_eq!(c.update([Some(50.0), Some(20.0)]), [true, false]);
        assert_eq!(c.update([None, None]), [true, false]);
    }
}
