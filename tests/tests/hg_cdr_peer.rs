//! The unitree_hg messages as DDS carries them (XCDR1), checked against an independent peer:
//! CycloneDDS's own Python serializer with its own copy of the IDL, and Unitree's CRC computed the
//! way unitree_sdk2py does (tests/python/hg_cdr_peer.py). Our LowCmd_ CDR must deserialize there to
//! the values we encoded, with a CRC that matches the C layout; the peer's LowState_ CDR must decode
//! here (CRC checked by our decoder) to the values it wrote.
use hal::{LowCommand, LowState, MotorCommand};
use integration_tests::*;
use sensor_io::unitree_hg::cdr::{low_cmd_to_cdr, low_state_from_cdr, LOW_CMD_CDR_LEN};
use sensor_io::unitree_hg::{decode_low_state, encode_low_cmd, LOW_CMD_LEN, LOW_STATE_LEN};

fn peer(args: &[&str]) -> Option<serde_json::Value> {
    let py = venv_python("the CDR peer (cyclonedds.idl)")?;
    Some(python_json(&py, "hg_cdr_peer.py", args))
}

fn f(v: &serde_json::Value) -> f32 {
    v.as_f64().unwrap() as f32
}

#[test]
fn our_low_cmd_cdr_reads_back_in_cyclonedds_with_a_valid_crc() {
    let mut cmd = LowCommand {
        mode_pr: 0,
        mode_machine: 5,
        ..Default::default()
    };
    for (i, m) in cmd.motors.iter_mut().enumerate() {
        let x = i as f32;
        *m = MotorCommand {
            mode: (i % 2) as u8,
            q: 0.1 * x - 1.3,
            dq: -0.01 * x,
            tau: 0.25 * x,
            kp: 40.0 + x,
            kd: 1.0 + 0.1 * x,
            reserve: 0,
        };
    }
    let mut c = [0u8; LOW_CMD_LEN];
    encode_low_cmd(&cmd, &mut c);
    let mut cdr = [0u8; LOW_CMD_CDR_LEN];
    low_cmd_to_cdr(&c, &mut cdr);
    let dir = scratch_dir("hg-cdr-cmd");
    let file = dir.join("lowcmd.cdr");
    std::fs::write(&file, cdr).unwrap();
    let Some(r) = peer(&["check-cmd", file.to_str().unwrap()]) else {
        return;
    };
    assert_eq!(r["header"], "00010000", "plain CDR, little-endian");
    assert_eq!(r["len"], 1004);
    assert_eq!(r["mode_machine"], 5);
    assert_eq!(r["crc_ok"], true, "{r}");
    assert_eq!(
        r["crc"].as_u64().unwrap() as u32,
        u32::from_le_bytes(c[1000..].try_into().unwrap())
    );
    for (i, (m, p)) in cmd.motors.iter().zip(r["motors"].as_array().unwrap()).enumerate() {
        let p = p.as_array().unwrap();
        assert_eq!(p[0].as_u64().unwrap() as u8, m.mode, "motor {i}");
        assert_eq!(
            [f(&p[1]), f(&p[2]), f(&p[3]), f(&p[4]), f(&p[5])],
            [m.q, m.dq, m.tau, m.kp, m.kd],
            "motor {i}"
        );
    }
}

#[test]
fn cyclonedds_low_state_cdr_decodes_here_with_its_crc() {
    let dir = scratch_dir("hg-cdr-state");
    for seed in [1, 42, 7777] {
        let file = dir.join(format!("lowstate-{seed}.cdr"));
        let Some(r) = peer(&["make-state", &seed.to_string(), file.to_str().unwrap()]) else {
            return;
        };
        let cdr = std::fs::read(&file).unwrap();
        assert_eq!(cdr.len(), 2092);
        let mut c = [0u8; LOW_STATE_LEN];
        low_state_from_cdr(&cdr, &mut c).expect("CDR → C layout");
        let mut s = LowState::default();
        decode_low_state(&c, &mut s).expect("the peer's CRC matches our C layout");
        assert_eq!(s.mode_machine as u64, r["mode_machine"].as_u64().unwrap());
        assert_eq!(s.tick as u64, r["tick"].as_u64().unwrap());
        let q: Vec<f32> = r["quaternion"].as_array().unwrap().iter().map(f).collect();
        assert_eq!(s.imu.quaternion.to_vec(), q);
        let g: Vec<f32> = r["gyroscope"].as_array().unwrap().iter().map(f).collect();
        assert_eq!(s.imu.gyroscope.to_vec(), g);
        assert_eq!(s.imu.temperature as i64, r["imu_temperature"].as_i64().unwrap());
        for (i, (m, p)) in s.motors.iter().zip(r["motors"].as_array().unwrap()).enumerate() {
            let p = p.as_array().unwrap();
            assert_eq!(m.mode as u64, p[0].as_u64().unwrap(), "motor {i}");
            assert_eq!([m.q, m.dq, m.tau_est], [f(&p[1]), f(&p[2]), f(&p[3])], "motor {i}");
            assert_eq!(
                [m.temperature[0] as i64, m.temperature[1] as i64],
                [p[4].as_i64().unwrap(), p[5].as_i64().unwrap()],
                "motor {i}"
            );
        }
        let w: Vec<u8> = r["wireless_remote"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_u64().unwrap() as u8)
            .collect();
        assert_eq!(s.wireless_remote.to_vec(), w);
    }
}
