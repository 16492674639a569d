//! Foot contact from joint torques: the ground's force on the foot is what the leg's measured
//! torques push against. With the 6×6 foot Jacobian `J` (pelvis frame), the motors' torques `τ`
//! balance an external wrench `F` at the foot as `τ = −Jᵀ F` (leg inertia and weight neglected);
//! its vertical component in the world frame is the contact force. A swinging leg's own weight
//! reads as a small *downward* force, a stance leg carries a share of the robot's ~315 N.
//! Hysteresis between two thresholds keeps the decision from chattering at touchdown and lift-off.
//!
//! Torques alone mislabel two moments of every step (measured on the peer policy's gait): the
//! toe still grazes the ground for a few ticks after the leg unloads, and a swing leg decelerating
//! before touchdown reads as a load. Where the ground is known to be flat, the foot's height
//! settles both: a foot enters contact only when loaded *and* low, and stays in contact while
//! loaded *or* on the ground.
use nalgebra::{Matrix6, UnitQuaternion, Vector6};

use crate::kinematics::LegPose;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ContactConfig {
    /// A foot not in contact enters contact above this vertical force, N.
    pub on_force_n: f64,
    /// A foot in contact leaves it below this vertical force, N.
    pub off_force_n: f64,
    /// With a foot height (flat ground): a foot enters contact only below this height, m.
    pub touchdown_height_m: f64,
    /// With a foot height: a foot below this height stays in contact however light, m.
    pub stance_height_m: f64,
}

impl Default for ContactConfig {
    fn default() -> Self {
        Self {
            on_force_n: 40.0,
            off_force_n: 10.0,
            touchdown_height_m: 0.003,
            stance_height_m: 0.0005,
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
    /// Force hysteresis alone: the foot carries load.
    loaded: [bool; 2],
    force: [f64; 2],
}

impl ContactDetector {
    pub fn new(cfg: ContactConfig) -> Self {
        Self {
            cfg,
            // Start standing: the robot is put down on both feet.
            contact: [true; 2],
            loaded: [true; 2],
            force: [0.0; 2],
        }
    }
    /// Feeds this tick's vertical forces (`None`: keep the previous decision) and, where the
    /// ground is known, the feet's sole heights above it.
    pub fn update(&mut self, force: [Option<f64>; 2], height: [Option<f64>; 2]) -> [bool; 2] {
        let c = &self.cfg;
        for (i, f) in force.into_iter().enumerate() {
            let Some(f) = f else { continue };
            self.force[i] = f;
            self.loaded[i] = if self.loaded[i] {
                f > c.off_force_n
            } else {
                f > c.on_force_n
            };
            let h = height[i].filter(|h| h.is_finite());
            self.contact[i] = match (self.contact[i], h) {
                (true, None) => f > c.off_force_n,
                (true, Some(h)) => f > c.off_force_n || h < c.stance_height_m,
                (false, None) => f > c.on_force_n,
                (false, Some(h)) => (f > c.on_force_n && h < c.touchdown_height_m) || h < c.stance_height_m,
            };
        }
        self.contact
    }
    pub fn contact(&self) -> [bool; 2] {
        self.contact
    }
    /// In contact and carrying load: a foot the filter may treat as a fixed support.
    pub fn support(&self) -> [bool; 2] {
        [self.contact[0] && self.loaded[0], self.contact[1] && self.loaded[1]]
    }
    /// Last vertical forces, N.
    pub fn force(&self) -> [f64; 2] {
        self.force
    }
}

snapshot::snapshot_fields!(ContactDetector { contact, loaded, force });

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hysteresis_holds_between_thresholds() {
        let mut c = ContactDetector::new(ContactConfig::default());
        assert_eq!(c.update([Some(5.0), Some(100.0)], [None; 2]), [false, true]);
        assert_eq!(c.update([Some(30.0), Some(30.0)], [None; 2]), [false, true]);
        assert_eq!(c.update([Some(50.0), Some(5.0)], [None; 2]), [true, false]);
        assert_eq!(c.update([None, None], [None; 2]), [true, false]);
    }

    #[test]
    fn height_gates_touchdown_and_holds_a_light_stance() {
        let mut c = ContactDetector::new(ContactConfig::default());
        c.update([Some(-50.0), Some(-50.0)], [Some(0.03), Some(0.03)]);
        c.update([Some(100.0), Some(100.0)], [Some(0.0), Some(0.0)]);
        // Unloaded but still on the ground (toe-off): stays in contact; lifted: leaves.
        assert_eq!(
            c.update([Some(-50.0), Some(-50.0)], [Some(0.0002), Some(0.02)]),
            [true, false]
        );
        // Loaded in the air (swing deceleration): no contact until the foot is low; on the ground
        // it is in contact before the load arrives.
        assert_eq!(
            c.update([Some(-50.0), Some(80.0)], [Some(0.03), Some(0.05)]),
            [false, false]
        );
        assert_eq!(
            c.update([Some(-50.0), Some(80.0)], [Some(0.03), Some(0.002)]),
            [false, true]
        );
        assert_eq!(
            c.update([Some(-50.0), Some(80.0)], [Some(0.0002), Some(0.002)]),
            [true, true]
        );
    }
}
