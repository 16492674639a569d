//! State estimator acceptance: the peer policy walks 20 s (vx 0.5, then turning at wz 0.5) on the
//! 12-dof model, with and without realistic IMU errors, and the firmware's estimate is judged
//! against the simulator's ground truth beside the naive baseline (integrated accelerometer).
use control::operator::CommandSchedule;
use control::spec::DeploySpec;
use firmware::sim_run::{run_sim, Report, SimOptions};
use integration_tests::*;

fn walk(cmd: [f32; 3], imu_noise: Option<&str>) -> Option<Report> {
    if shared_dir().is_none() {
        skip_or_fail("estimator acceptance walks (the peer policy lives in ../shared)");
        return None;
    }
    let spec = DeploySpec::load(&peer_spec_path()).expect("peer spec");
    assert!(
        spec.kinematics.is_some(),
        "the peer spec names the MJCF for leg kinematics"
    );
    let opts = SimOptions {
        model: "g1-12dof".into(),
        schedule: CommandSchedule::constant(cmd),
        duration_s: 20.0,
        seed: 11,
        imu_noise: imu_noise.map(str::to_string),
        sim_bin: Some(built_bin("g1-sim")),
        ..SimOptions::default()
    };
    let r = run_sim(spec, &opts, |_| {}).expect("run completes");
    let e = &r.estimator;
    eprintln!(
        "cmd {cmd:?} noise {imu_noise:?}: est vel rmse x {:.4} y {:.4} height {:.4} m contact {:.4} \
         (per foot {:?}, both feet {:.4}) | baseline vel x {:.3} y {:.3} height {:.3} m contact {:.4}",
        e.est_vel_rmse_x.unwrap(),
        e.est_vel_rmse_y.unwrap(),
        e.est_height_rmse_m.unwrap(),
        e.est_contact_agreement.unwrap(),
        e.est_contact_agreement_feet.unwrap(),
        e.est_contact_agreement_both_feet.unwrap(),
        e.baseline_vel_rmse_x.unwrap(),
        e.baseline_vel_rmse_y.unwrap(),
        e.baseline_height_rmse_m.unwrap(),
        e.baseline_contact_agreement.unwrap(),
    );
    assert!(!r.fell, "{cmd:?}: the robot fell");
    assert!(r.trip.is_none(), "{cmd:?}: false trip {:?}", r.trip);
    // Every tick from the first one carried a valid estimate.
    assert!(e.est_ticks >= r.ticks, "{} estimated ticks of {}", e.est_ticks, r.ticks);
    Some(r)
}

fn check_clean(r: &Report, what: &str) {
    let e = &r.estimator;
    let (vx, vy) = (e.est_vel_rmse_x.unwrap(), e.est_vel_rmse_y.unwrap());
    assert!(
        vx <= 0.05 && vy <= 0.05,
        "{what}: velocity RMSE x {vx} y {vy} > 0.05 m/s"
    );
    let h = e.est_height_rmse_m.unwrap();
    assert!(h <= 0.02, "{what}: height RMSE {h} m > 2 cm");
    let c = e.est_contact_agreement.unwrap();
    assert!(c >= 0.97, "{what}: contact agreement {c} < 97 % of foot-ticks");
    // Both feet right at once: the strictest reading, held to a looser bar (see docs/results.md).
    let both = e.est_contact_agreement_both_feet.unwrap();
    assert!(both >= 0.95, "{what}: both-feet contact agreement {both} < 95 %");
    // The naive contact rule is worse.
    assert!(
        c > e.baseline_contact_agreement.unwrap(),
        "{what}: no better than the lower-foot rule"
    );
}

#[test]
fn estimates_walking_forward() {
    if let Some(r) = walk([0.5, 0.0, 0.0], None) {
        check_clean(&r, "vx 0.5");
    }
}

#[test]
fn estimates_turning() {
    if let Some(r) = walk([0.0, 0.0, 0.5], None) {
        check_clean(&r, "wz 0.5");
    }
}

#[test]
fn estimates_with_realistic_imu_errors() {
    for cmd in [[0.5, 0.0, 0.0], [0.0, 0.0, 0.5]] {
        let Some(r) = walk(cmd, Some("realistic")) else { return };
        let e = &r.estimator;
        let (vx, vy) = (e.est_vel_rmse_x.unwrap(), e.est_vel_rmse_y.unwrap());
        assert!(
            vx <= 0.08 && vy <= 0.08,
            "{cmd:?} noisy IMU: velocity RMSE x {vx} y {vy} > 0.08"
        );
        let h = e.est_height_rmse_m.unwrap();
        assert!(h <= 0.02, "{cmd:?} noisy IMU: height RMSE {h}");
        // Integrating a biased accelerometer drifts; the filter does not.
        let (bx, by) = (e.baseline_vel_rmse_x.unwrap(), e.baseline_vel_rmse_y.unwrap());
        assert!(
            bx > 5.0 * vx && by > 5.0 * vy,
            "{cmd:?}: baseline {bx} {by} vs filter {vx} {vy}"
        );
    }
}

/// Without `[estimator] model` the firmware runs attitude only and the report says so with nulls.
#[test]
fn spec_without_kinematics_reports_no_estimator_figures() {
    if shared_dir().is_none() {
        return skip_or_fail("attitude-only estimator run");
    }
    let path = peer_spec_path();
    let text = std::fs::read_to_string(&path).unwrap();
    let cut = text.find("[estimator]").expect("peer spec has [estimator]");
    let mut spec = DeploySpec::from_toml(&text[..cut], &path).expect("spec without [estimator]");
    assert!(spec.kinematics.is_none());
    spec.startup.ramp_s = 0.1;
    let opts = SimOptions {
        model: "g1-12dof".into(),
        duration_s: 0.5,
        sim_bin: Some(built_bin("g1-sim")),
        ..SimOptions::default()
    };
    let r = run_sim(spec, &opts, |v| {
        assert!(!v.summary.estimate.valid);
        assert!(
            v.summary.estimate.projected_gravity[2] < -0.9,
            "attitude still estimated"
        );
    })
    .unwrap();
    assert_eq!(r.estimator.est_ticks, 0);
    assert!(r.estimator.est_vel_rmse_x.is_none());
    let json = serde_json::to_value(&r).unwrap();
    assert!(json["est_vel_rmse_x"].is_null(), "{json}");

    // A wrong MJCF path is a clear load-time error naming the field.
    let bad = text.replace("g1_12dof.xml", "no_such_model.xml");
    let err = DeploySpec::from_toml(&bad, &path).unwrap_err().to_string();
    assert!(
        err.contains("estimator.model") && err.contains("no_such_model.xml"),
        "{err}"
    );
}
