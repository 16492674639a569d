//! The estimator's leg kinematics (parsed from the MJCF without MuJoCo) against MuJoCo's own
//! forward kinematics, on random joint configurations and random base poses, for both G1 models.
mod common;

use common::{have_12dof, require_deps};
use estimator::kinematics::{LegKinematics, Side, LEGS, LEG_JOINTS};
use g1_sim::model::{deps_dir, shared_dir};
use mujoco_rs::prelude::*;
use nalgebra::{Quaternion, UnitQuaternion, Vector3};

/// SplitMix64: a seeded, dependency-free source of test configurations.
struct Rng(u64);
impl Rng {
    fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        lo + (hi - lo) * ((z >> 11) as f64 / (1u64 << 53) as f64)
    }
}

fn v3(a: [f64; 3]) -> Vector3<f64> {
    Vector3::new(a[0], a[1], a[2])
}
fn uq(a: [f64; 4]) -> UnitQuaternion<f64> {
    UnitQuaternion::from_quaternion(Quaternion::new(a[0], a[1], a[2], a[3]))
}

/// Puts the free joint at `free_adr` at a random position (±2 m) and attitude (roll and pitch
/// ±`tilt` rad, any heading).
fn random_base_pose(qpos: &mut [f64], free_adr: usize, rng: &mut Rng, tilt: f64) {
    for a in 0..3 {
        qpos[free_adr + a] = rng.uniform(-2.0, 2.0);
    }
    let r = UnitQuaternion::from_euler_angles(
        rng.uniform(-tilt, tilt),
        rng.uniform(-tilt, tilt),
        rng.uniform(-3.0, 3.0),
    );
    let rq = r.quaternion();
    qpos[free_adr + 3..free_adr + 7].copy_from_slice(&[rq.w, rq.i, rq.j, rq.k]);
}

struct Errors {
    ankle_pos_m: f64,
    ankle_rot_rad: f64,
    foot_m: f64,
    jacobian: f64,
}

/// Compares `kin` with MuJoCo on `mjcf` for `n` random configurations; returns the worst errors.
fn compare(mjcf: &std::path::Path, kin: &LegKinematics, n: usize, seed: u64) -> Errors {
    let model = MjModel::from_xml(mjcf).unwrap_or_else(|e| panic!("{}: {e}", mjcf.display()));
    let mut d = MjData::new(Box::new(model));
    let m = d.model();
    let pelvis = m.name_to_id(MjtObjBase::mjOBJ_BODY, "pelvis").expect("pelvis");
    let free_adr = m.jnt_qposadr()[m.body_jntadr()[pelvis] as usize] as usize;
    let mut joints = [[(0usize, 0.0f64, 0.0f64); 6]; 2];
    let mut ankles = [0usize; 2];
    let mut feet_site = [None; 2];
    for (l, side) in LEGS.iter().enumerate() {
        for (j, name) in LEG_JOINTS.iter().enumerate() {
            let id = m
                .name_to_id(MjtObjBase::mjOBJ_JOINT, &format!("{}_{name}", side.prefix()))
                .expect("leg joint") as usize;
            let [lo, hi] = m.jnt_range()[id];
            joints[l][j] = (m.jnt_qposadr()[id] as usize, lo, hi);
        }
        ankles[l] = m
            .name_to_id(MjtObjBase::mjOBJ_BODY, &format!("{}_ankle_roll_link", side.prefix()))
            .expect("ankle") as usize;
        feet_site[l] = m.name_to_id(MjtObjBase::mjOBJ_SITE, &format!("{}_foot", side.prefix()));
    }
    let mut rng = Rng(seed);
    let mut worst = Errors {
        ankle_pos_m: 0.0,
        ankle_rot_rad: 0.0,
        foot_m: 0.0,
        jacobian: 0.0,
    };
    for _ in 0..n {
        let mut q = [[0.0; 6]; 2];
        {
            let qpos = d.qpos_mut();
            // A random base pose: the comparison happens in the pelvis frame.
            random_base_pose(qpos, free_adr, &mut rng, 1.0);
            for l in 0..2 {
                for j in 0..6 {
                    let (adr, lo, hi) = joints[l][j];
                    q[l][j] = rng.uniform(lo, hi);
                    qpos[adr] = q[l][j];
                }
            }
        }
        d.kinematics();
        let (xp, xq) = (d.xpos(), d.xquat());
        let base_p = v3(xp[pelvis]);
        let base_r = uq(xq[pelvis]);
        let to_pelvis = |w: Vector3<f64>| base_r.inverse() * (w - base_p);
        for (l, side) in LEGS.iter().enumerate() {
            let leg = kin.leg(*side);
            let pose = leg.pose(&q[l]);
            let ankle_mj = to_pelvis(v3(xp[ankles[l]]));
            worst.ankle_pos_m = worst.ankle_pos_m.max((pose.ankle - ankle_mj).norm());
            let rot_mj = base_r.inverse() * uq(xq[ankles[l]]);
            worst.ankle_rot_rad = worst.ankle_rot_rad.max(rot_mj.angle_to(&pose.foot_rot));
            // The foot point: MuJoCo's site where the model has one, else the ankle frame carried
            // to the parsed offset.
            let foot_mj = match feet_site[l] {
                Some(s) => to_pelvis(v3(d.site_xpos()[s])),
                None => ankle_mj + rot_mj * leg.foot_offset(),
            };
            worst.foot_m = worst.foot_m.max((pose.foot - foot_mj).norm());
            // Jacobian against finite differences of our FK (checked against MuJoCo above).
            let jac = pose.position_jacobian();
            for j in 0..6 {
                let mut qp = q[l];
                qp[j] += 1e-7;
                let fd = (leg.foot_position(&qp) - pose.foot) / 1e-7;
                worst.jacobian = worst.jacobian.max((fd - jac.column(j)).norm());
            }
        }
    }
    worst
}

fn check(name: &str, e: &Errors) {
    println!(
        "{name}: worst ankle position {:.2e} m, ankle orientation {:.2e} rad, foot point {:.2e} m, Jacobian {:.2e}",
        e.ankle_pos_m, e.ankle_rot_rad, e.foot_m, e.jacobian
    );
    assert!(
        e.ankle_pos_m <= 1e-3,
        "{name}: ankle position off by {} m",
        e.ankle_pos_m
    );
    assert!(e.foot_m <= 1e-3, "{name}: foot point off by {} m", e.foot_m);
    assert!(
        e.ankle_rot_rad <= 1e-3,
        "{name}: ankle orientation off by {} rad",
        e.ankle_rot_rad
    );
    assert!(e.jacobian <= 1e-5, "{name}: Jacobian off by {}", e.jacobian);
}

#[test]
fn leg_kinematics_match_mujoco_29dof() {
    require_deps();
    let xml = deps_dir().join("g1_29dof/g1.xml");
    let kin = LegKinematics::from_mjcf_file(&xml).expect("29-dof kinematics");
    // The mjlab model names its foot sites: the foot point is the site.
    assert!((kin.leg(Side::Left).foot_offset() - Vector3::new(0.04, 0.0, -0.037)).norm() < 1e-12);
    check("g1-29dof", &compare(&xml, &kin, 500, 1));
}

#[test]
fn leg_kinematics_match_mujoco_12dof() {
    require_deps();
    if !have_12dof("leg_kinematics_match_mujoco_12dof") {
        return;
    }
    let dir = shared_dir().join("assets/unitree_g1_12dof");
    let kin = LegKinematics::from_mjcf_file(&dir.join("g1_12dof.xml")).expect("12-dof kinematics");
    // Four contact spheres of radius 5 mm at z -0.03: the sole centre.
    let f = kin.leg(Side::Right).foot_offset();
    assert!((f - Vector3::new(0.035, 0.0, -0.035)).norm() < 1e-12, "{f}");
    check("g1-12dof", &compare(&dir.join("scene.xml"), &kin, 500, 2));
}

#[test]
fn both_models_share_the_leg_chain() {
    require_deps();
    if !have_12dof("both_models_share_the_leg_chain") {
        return;
    }
    let k12 = LegKinematics::from_mjcf_file(&shared_dir().join("assets/unitree_g1_12dof/g1_12dof.xml")).unwrap();
    let k29 = LegKinematics::from_mjcf_file(&deps_dir().join("g1_29dof/g1.xml")).unwrap();
    let q = [0.2, 0.1, -0.1, 0.6, -0.3, 0.05];
    for side in LEGS {
        let (a, b) = (k12.leg(side).pose(&q), k29.leg(side).pose(&q));
        assert!((a.ankle - b.ankle).norm() < 1e-9, "{side:?}: the ankles differ");
    }
}

/// The firmware places lidar points through the waist joints as measured
/// (`sensor_io::bev::WaistChain::G1`, `[perception] mount_on_torso`); MuJoCo carries the simulated
/// MID-360 on `torso_link`. Random waist angles and base poses: the same sensor points must land on
/// the same pelvis-frame points.
#[test]
fn the_lidar_on_the_torso_follows_the_waist_as_in_mujoco() {
    use sensor_io::bev::{MountPose, RobotFrame, WaistChain};
    require_deps();
    let xml = deps_dir().join("g1_29dof/g1.xml");
    let model = MjModel::from_xml(&xml).unwrap_or_else(|e| panic!("{}: {e}", xml.display()));
    let mut d = MjData::new(Box::new(model));
    let m = d.model();
    let body = |n: &str| m.name_to_id(MjtObjBase::mjOBJ_BODY, n).expect(n) as usize;
    let (pelvis, torso) = (body("pelvis"), body("torso_link"));
    let free_adr = m.jnt_qposadr()[m.body_jntadr()[pelvis] as usize] as usize;
    let waist: Vec<(usize, f64, f64)> = ["waist_yaw_joint", "waist_roll_joint", "waist_pitch_joint"]
        .iter()
        .map(|n| {
            let id = m.name_to_id(MjtObjBase::mjOBJ_JOINT, n).expect(n) as usize;
            let [lo, hi] = m.jnt_range()[id];
            (m.jnt_qposadr()[id] as usize, lo, hi)
        })
        .collect();
    let lidar = g1_sim::lidar::LidarConfig::default();
    let (xyz, rpy) = lidar.mount_in_pelvis();
    let mount = MountPose {
        xyz: xyz.map(|v| v as f32),
        rpy: rpy.map(|v| v as f32),
    };
    let on_torso = UnitQuaternion::from_euler_angles(lidar.mount_rpy[0], lidar.mount_rpy[1], lidar.mount_rpy[2]);
    let points = [[2.0, 0.0, 0.0], [0.0, -1.5, 0.3], [1.0, 1.0, -2.0], [0.0, 0.0, 0.0]];
    let mut rng = Rng(7);
    let (mut worst, mut worst_fixed) = (0.0f64, 0.0f64);
    for _ in 0..200 {
        let mut q = [0.0f32; 3];
        {
            let qpos = d.qpos_mut();
            random_base_pose(qpos, free_adr, &mut rng, 0.5);
            for (k, &(adr, lo, hi)) in waist.iter().enumerate() {
                q[k] = rng.uniform(lo.max(-0.5), hi.min(0.5)) as f32;
                qpos[adr] = q[k] as f64;
            }
        }
        d.kinematics();
        let (xp, xq) = (d.xpos(), d.xquat());
        let (base_p, base_r) = (v3(xp[pelvis]), uq(xq[pelvis]));
        let (torso_p, torso_r) = (v3(xp[torso]), uq(xq[torso]));
        let ours = RobotFrame::on_waist(&mount, &WaistChain::G1, q, 0.0, 0.0, 0.0);
        let fixed = RobotFrame::new(&mount, 0.0, 0.0, 0.0);
        for p in points {
            let sensor = torso_p + torso_r * (v3(lidar.mount_xyz) + on_torso * v3(p));
            let want = base_r.inverse() * (sensor - base_p);
            let got = ours.apply(p.map(|v| v as f32)).map(f64::from);
            worst = worst.max((v3(got) - want).norm());
            let at_zero = fixed.apply(p.map(|v| v as f32)).map(f64::from);
            worst_fixed = worst_fixed.max((v3(at_zero) - want).norm());
        }
    }
    println!("lidar points through the waist: worst {worst:.2e} m (a mount fixed to the pelvis: {worst_fixed:.3} m)");
    assert!(worst < 2e-5, "the waist chain is off MuJoCo's by {worst} m");
    // The check can fail: ignoring the waist misplaces the same points by decimetres.
    assert!(worst_fixed > 0.1, "{worst_fixed}");
}
