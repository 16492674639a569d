//! State estimation for the G1, every fast tick, from the unitree_hg `LowState` alone:
//!
//! - [`kinematics`]: foot positions and Jacobians relative to the pelvis, read from the robot's
//!   MJCF at start-up;
//! - [`contact`]: foot contact from joint torques through the foot Jacobian, with hysteresis;
//! - [`filter`]: a linear Kalman filter (MIT Cheetah 3 style) for base position, velocity and
//!   foot positions, driven by the accelerometer and corrected by leg kinematics;
//! - [`attitude`]: the IMU's quaternion (or a complementary filter when it is invalid) and the
//!   signals policies use (projected gravity, roll/pitch/yaw);
//! - [`state`]: [`StateEstimator`], all of the above in the firmware's per-tick order;
//! - [`baseline`]: the naive estimator it is compared with (integrated accelerometer);
//! - [`terrain`]: the geometric (no learning) terrain token from a BEV grid, the CNN's fallback.
pub mod attitude;
pub mod baseline;
pub mod contact;
pub mod filter;
pub mod kinematics;
pub mod state;
pub mod terrain;
pub mod terrain_cnn;

pub use attitude::{projected_gravity, rpy, tilt_rad};
pub use kinematics::{KinematicsError, LegKinematics, Side};
pub use state::{AttitudeSource, BaseEstimate, EstimatorConfig, StateEstimator};
pub use terrain::{plausible, GeometricTerrainConfig, GeometricTerrainEstimator, TerrainEstimate};
