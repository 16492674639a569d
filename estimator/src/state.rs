//! The state estimator the firmware runs every fast tick: attitude → leg kinematics → contact →
//! Kalman filter, from one `LowState`. Fixed size; nothing allocates after construction.
use hal::LowState;
use nalgebra::{UnitQuaternion, Vector3};

use crate::attitude::{valid_quaternion, AttitudeFilter};
use crate::baseline::GRAVITY;
use crate::contact::{vertical_force, ContactConfig, ContactDetector};
use crate::filter::{BaseFilter, FilterConfig};
use crate::kinematics::{LegKinematics, LegPose, LEGS};

/// Everything tunable, with defaults that walk the G1 in simulation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EstimatorConfig {
    pub filter: FilterConfig,
    pub contact: ContactConfig,
    /// IMU position in the pelvis frame, m (lever arm for the accelerometer).
    pub imu_position: [f64; 3],
    /// Gain of the fallback attitude filter, 1/s.
    pub attitude_gain: f64,
}

impl Default for EstimatorConfig {
    fn default() -> Self {
        Self {
            filter: FilterConfig::default(),
            contact: ContactConfig::default(),
            imu_position: hal::G1_PELVIS_IMU_POS,
            attitude_gain: 1.0,
        }
    }
}

/// Where the attitude of a tick came from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum AttitudeSource {
    /// No valid input yet.
    #[default]
    None,
    /// The IMU's own quaternion.
    Imu,
    /// The fallback complementary filter (the IMU quaternion was invalid).
    Filter,
}

/// One tick's estimate. Single precision: it is logged and fed to policies.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BaseEstimate {
    /// The filter ran on this tick's inputs (false before the first valid frame, without leg
    /// kinematics, and on ticks whose inputs were not finite).
    pub valid: bool,
    pub attitude_source: AttitudeSource,
    /// Base orientation w, x, y, z (heading frame).
    pub quat: [f32; 4],
    pub rpy: [f32; 3],
    pub projected_gravity: [f32; 3],
    /// Base linear velocity, heading frame and body frame, m/s.
    pub lin_vel_world: [f32; 3],
    pub lin_vel_body: [f32; 3],
    /// Base angular velocity, body frame (the gyro), rad/s.
    pub ang_vel_body: [f32; 3],
    /// Standard deviation of the world-frame velocity, m/s.
    pub lin_vel_std: [f32; 3],
    /// Base position in the heading frame, m; z is the height above the ground the robot
    /// started on.
    pub position: [f32; 3],
    pub height_std: f32,
    /// Foot points (sole centres) in the heading frame, m.
    pub foot_pos: [[f32; 3]; 2],
    /// Left, right.
    pub contact: [bool; 2],
    /// Vertical ground force estimated from joint torques, N.
    pub contact_force: [f32; 2],
    /// Height of each sole's lowest point above the ground (flat-ground estimate), m.
    pub sole_height: [f32; 2],
    /// Waist yaw, roll and pitch as measured (rad; 0 where the robot has no such joint or it read
    /// non-finite): the torso's pose on the pelvis, which the torso-mounted lidar follows.
    pub waist: [f32; 3],
}

/// The waist's motor slots (yaw, roll, pitch), looked up by name in `hal`'s slot table.
const WAIST_SLOTS: [usize; 3] = [
    hal::g1_motor_slot_const("waist_yaw"),
    hal::g1_motor_slot_const("waist_roll"),
    hal::g1_motor_slot_const("waist_pitch"),
];

/// The waist joints of `state` (see [`BaseEstimate::waist`]).
fn waist_joints(state: &LowState) -> [f32; 3] {
    let missing = hal::g1_variant(state.mode_machine).map_or(&[][..], |v| v.missing);
    WAIST_SLOTS.map(|slot| {
        let q = state.motors[slot].q;
        if missing.contains(&slot) || !q.is_finite() {
            0.0
        } else {
            q
        }
    })
}

fn f32x3(v: &Vector3<f64>) -> [f32; 3] {
    [v.x as f32, v.y as f32, v.z as f32]
}

/// Leg joint positions, velocities and torques of one leg from a `LowState`.
pub fn leg_joints(state: &LowState, leg: usize) -> ([f64; 6], [f64; 6], [f64; 6]) {
    let (mut q, mut dq, mut tau) = ([0.0; 6], [0.0; 6], [0.0; 6]);
    for j in 0..6 {
        let m = &state.motors[LEGS[leg].first_slot() + j];
        q[j] = m.q as f64;
        dq[j] = m.dq as f64;
        tau[j] = m.tau_est as f64;
    }
    (q, dq, tau)
}

pub struct StateEstimator {
    kinematics: Option<LegKinematics>,
    cfg: EstimatorConfig,
    tick_dt: f64,
    attitude: AttitudeFilter,
    contact: ContactDetector,
    filter: Option<BaseFilter>,
    last_tick: Option<u64>,
    out: BaseEstimate,
}

impl StateEstimator {
    /// `kinematics` `None` runs attitude only (no velocity, height or contact). `tick_dt` is the
    /// control period, s.
    pub fn new(kinematics: Option<LegKinematics>, cfg: EstimatorConfig, tick_dt: f64) -> Self {
        Self {
            kinematics,
            cfg,
            tick_dt,
            attitude: AttitudeFilter::new(cfg.attitude_gain),
            contact: ContactDetector::new(cfg.contact),
            filter: None,
            last_tick: None,
            out: BaseEstimate::default(),
        }
    }

    pub fn has_kinematics(&self) -> bool {
        self.kinematics.is_some()
    }
    pub fn estimate(&self) -> &BaseEstimate {
        &self.out
    }
    pub fn filter(&self) -> Option<&BaseFilter> {
        self.filter.as_ref()
    }

    /// Folds in the newest accepted state of control tick `tick`. Call once per fresh frame; ticks
    /// without one are bridged by the time step of the next call.
    pub fn update(&mut self, tick: u64, state: &LowState) -> &BaseEstimate {
        let dt = match self.last_tick {
            Some(t) if tick > t => (tick - t) as f64 * self.tick_dt,
            Some(_) => return &self.out,
            None => self.tick_dt,
        };
        let imu = &state.imu;
        let gyro = Vector3::new(
            imu.gyroscope[0] as f64,
            imu.gyroscope[1] as f64,
            imu.gyroscope[2] as f64,
        );
        let acc = Vector3::new(
            imu.accelerometer[0] as f64,
            imu.accelerometer[1] as f64,
            imu.accelerometer[2] as f64,
        );
        let imu_ok = gyro.iter().chain(acc.iter()).all(|v| v.is_finite());
        // Attitude: the IMU's quaternion when valid; otherwise the complementary filter carries on
        // from the last good one.
        let source = match valid_quaternion(imu.quaternion) {
            Some(q) => {
                self.attitude.sync(q);
                AttitudeSource::Imu
            }
            None if imu_ok && self.last_tick.is_some() => {
                self.attitude.step(dt, &gyro, &acc);
                AttitudeSource::Filter
            }
            None => {
                self.out.valid = false;
                return &self.out;
            }
        };
        self.last_tick = Some(tick);
        if imu_ok {
            self.out.ang_vel_body = f32x3(&gyro);
        }
        let rot = self.attitude.attitude();
        self.out.attitude_source = source;
        self.write_attitude(&rot);
        self.out.waist = waist_joints(state);

        let Some(kin) = &self.kinematics else {
            self.out.valid = false;
            return &self.out;
        };
        let mut poses = [None::<LegPose>; 2];
        let mut joints = [([0.0; 6], [0.0; 6], [0.0; 6]); 2];
        for (i, leg) in LEGS.iter().enumerate() {
            joints[i] = leg_joints(state, i);
            let (q, dq, tau) = &joints[i];
            if q.iter().chain(dq).chain(tau).all(|v| v.is_finite()) {
                poses[i] = Some(kin.leg(*leg).pose(q));
            }
        }
        let (Some(pl), Some(pr)) = (poses[0], poses[1]) else {
            self.out.valid = false;
            return &self.out;
        };
        if !imu_ok {
            self.out.valid = false;
            return &self.out;
        }
        let poses = [pl, pr];
        // Foot positions relative to the base, heading frame.
        let rel = [0, 1].map(|i| rot * poses[i].foot);
        let forces = [0, 1].map(|i| vertical_force(&poses[i], &rot, &joints[i].2));
        // On flat ground, the sole height above it from the filter's base height (its prior for
        // this tick) and kinematics.
        let sole_low = [0, 1].map(|i| poses[i].sole_min_z(&rot));
        let heights = match (&self.filter, self.cfg.filter.ground_height_noise) {
            (Some(f), Some(_)) => [0, 1].map(|i| Some(f.position().z + sole_low[i])),
            _ => [None; 2],
        };
        let contact = self.contact.update(forces, heights);
        let support = self.contact.support();

        let filter = self.filter.get_or_insert_with(|| {
            // Start at rest with the lower foot on the ground (height 0).
            let ground = rel[0].z.min(rel[1].z);
            let base = Vector3::new(0.0, 0.0, -ground);
            BaseFilter::new(self.cfg.filter, base, [base + rel[0], base + rel[1]])
        });

        // Base acceleration at the pelvis origin: the accelerometer minus the centripetal term of
        // its lever arm (the tangential term needs dω/dt and is left in the process noise).
        let r_imu = Vector3::from(self.cfg.imu_position);
        let a_body = acc - gyro.cross(&gyro.cross(&r_imu));
        let a_world = rot * a_body - Vector3::new(0.0, 0.0, GRAVITY);
        filter.predict(dt, &a_world, support);
        for i in 0..2 {
            filter.update_foot_position(i, &rel[i]);
            if support[i] {
                // A foot that stays put moves, seen from the base, at −(ω × r + J q̇).
                let foot_vel_body =
                    gyro.cross(&poses[i].foot) + poses[i].position_jacobian() * nalgebra::Vector6::from(joints[i].1);
                filter.update_stance_velocity(&(rot * -foot_vel_body));
                // The sole's lowest point is on the ground: the foot point sits that far above it.
                // A loaded sole sinks in by its compliance.
                let sink = self.cfg.filter.sole_compliance_m_per_n * forces[i].unwrap_or(0.0).max(0.0);
                filter.update_ground_height(i, rel[i].z - sole_low[i] - sink);
            }
        }
        filter.symmetrize();
        if !filter.is_finite() {
            // Never let a poisoned filter stick: start again from the next frame.
            self.filter = None;
            self.out.valid = false;
            return &self.out;
        }
        let v = filter.velocity();
        self.out.valid = true;
        self.out.lin_vel_world = f32x3(&v);
        self.out.lin_vel_body = f32x3(&(rot.inverse() * v));
        self.out.lin_vel_std = f32x3(&filter.velocity_std());
        self.out.position = f32x3(&filter.position());
        self.out.height_std = filter.std(2) as f32;
        self.out.foot_pos = [f32x3(&filter.foot(0)), f32x3(&filter.foot(1))];
        self.out.contact = contact;
        let z = filter.position().z;
        self.out.sole_height = [(z + sole_low[0]) as f32, (z + sole_low[1]) as f32];
        let f = self.contact.force();
        self.out.contact_force = [f[0] as f32, f[1] as f32];
        &self.out
    }

    fn write_attitude(&mut self, rot: &UnitQuaternion<f64>) {
        let q = rot.quaternion();
        let qf = [q.w as f32, q.i as f32, q.j as f32, q.k as f32];
        self.out.quat = qf;
        self.out.rpy = crate::attitude::rpy(qf);
        self.out.projected_gravity = crate::attitude::projected_gravity(qf);
    }
}

impl snapshot::Snapshot for AttitudeSource {
    fn save(&self, out: &mut Vec<u8>) {
        out.push(*self as u8);
    }

    fn restore(&mut self, input: &mut &[u8]) -> Result<(), snapshot::SnapshotError> {
        let v = snapshot::take::<1>(input, "attitude source")?[0];
        *self = [AttitudeSource::None, AttitudeSource::Imu, AttitudeSource::Filter]
            .get(v as usize)
            .copied()
            .ok_or(snapshot::SnapshotError::Invalid {
                what: "attitude source",
                value: v as u64,
            })?;
        Ok(())
    }
}

snapshot::snapshot_fields!(BaseEstimate {
    valid,
    attitude_source,
    quat,
    rpy,
    projected_gravity,
    lin_vel_world,
    lin_vel_body,
    ang_vel_body,
    lin_vel_std,
    position,
    height_std,
    foot_pos,
    contact,
    contact_force,
    sole_height,
    waist,
});

/// Everything the estimator carries from tick to tick (the filter, once the first tick with legs
/// has made it).
impl snapshot::Snapshot for StateEstimator {
    fn save(&self, out: &mut Vec<u8>) {
        self.attitude.save(out);
        self.contact.save(out);
        self.filter.is_some().save(out);
        if let Some(f) = &self.filter {
            f.save(out);
        }
        self.last_tick.save(out);
        self.out.save(out);
    }

    fn restore(&mut self, input: &mut &[u8]) -> Result<(), snapshot::SnapshotError> {
        self.attitude.restore(input)?;
        self.contact.restore(input)?;
        let mut has_filter = false;
        has_filter.restore(input)?;
        if has_filter {
            // Made on the first tick with legs; its configuration is the spec's, its state the snapshot's.
            let f = self
                .filter
                .get_or_insert_with(|| BaseFilter::new(self.cfg.filter, Vector3::zeros(), [Vector3::zeros(); 2]));
            f.restore(input)?;
        } else {
            self.filter = None;
        }
        self.last_tick.restore(input)?;
        self.out.restore(input)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn standing() -> LowState {
        let mut s = LowState::default();
        s.imu.quaternion = [1.0, 0.0, 0.0, 0.0];
        s.imu.accelerometer = [0.0, 0.0, 9.81];
        for leg in 0..2 {
            let m = &mut s.motors[6 * leg..6 * leg + 6];
            m[3].q = 0.3;
            m[3].tau_est = -60.0; // the knee holds the robot up
        }
        s
    }

    #[test]
    fn the_waist_is_read_as_measured_except_where_the_robot_has_none() {
        let mut s = standing();
        s.mode_machine = hal::mode_machine::G1_29DOF_REV_1_0;
        s.motors[12].q = 0.1;
        s.motors[13].q = -0.03;
        s.motors[14].q = f32::NAN;
        let mut e = StateEstimator::new(None, EstimatorConfig::default(), 0.002);
        assert_eq!(e.update(0, &s).waist, [0.1, -0.03, 0.0]);
        // A locked waist reports whatever its slots hold: roll and pitch are zero.
        s.mode_machine = hal::mode_machine::LOCK_WAIST_REV_1_0;
        s.motors[14].q = 0.2;
        assert_eq!(e.update(1, &s).waist, [0.1, 0.0, 0.0]);
    }

    #[test]
    fn standing_still_stays_put_and_bad_input_never_poisons_the_filter() {
        let kin = LegKinematics::from_mjcf(crate::kinematics::TEST_LEGS_MJCF).unwrap();
        let mut e = StateEstimator::new(Some(kin), EstimatorConfig::default(), 0.002);
        let good = standing();
        for k in 0..500 {
            e.update(k, &good);
        }
        let est = *e.estimate();
        assert!(est.valid && est.attitude_source == AttitudeSource::Imu);
        assert!(est.lin_vel_body.iter().all(|v| v.abs() < 1e-3), "{est:?}");
        assert!(est.position[2] > 0.7 && est.position[2] < 0.9, "{est:?}");

        // NaN in a joint or the gyro: the tick is skipped, not folded in.
        let mut bad = good;
        bad.motors[3].dq = f32::NAN;
        assert!(!e.update(500, &bad).valid);
        let mut bad = good;
        bad.imu.gyroscope[1] = f32::INFINITY;
        assert!(!e.update(501, &bad).valid);
        // An invalid quaternion falls back to the complementary filter.
        let mut bad = good;
        bad.imu.quaternion = [f32::NAN; 4];
        let fb = *e.update(502, &bad);
        assert!(fb.valid && fb.attitude_source == AttitudeSource::Filter, "{fb:?}");
        // Good input again: finite and where it was.
        let after = *e.update(503, &good);
        assert!(after.valid && e.filter().unwrap().is_finite());
        assert!((after.position[2] - est.position[2]).abs() < 1e-3);
        // A repeated tick index changes nothing.
        assert_eq!(*e.update(503, &good), after);
    }

    #[test]
    fn attitude_only_without_kinematics() {
        let mut e = StateEstimator::new(None, EstimatorConfig::default(), 0.002);
        let out = *e.update(0, &standing());
        assert!(!out.valid);
        assert_eq!(out.projected_gravity, [0.0, 0.0, -1.0]);
    }
}
