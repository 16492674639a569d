use super::*;
use proptest::prelude::*;

fn sample_cmd(seed: u32) -> LowCommand {
    let mut c = LowCommand {
        mode_pr: 1,
        mode_machine: 5,
        reserve: [1, 2, 3, seed],
        ..Default::default()
    };
    for (i, m) in c.motors.iter_mut().enumerate() {
        let f = i as f32 + seed as f32 * 0.001;
        *m = MotorCommand {
            mode: 1,
            q: f * 0.1,
            dq: -f,
            tau: f * 2.0,
            kp: 100.0 + f,
            kd: 2.5,
            reserve: i as u32,
        };
    }
    c
}

fn sample_state(seed: u32) -> LowState {
    let mut s = LowState {
        version: [7, seed],
        mode_pr: 0,
        mode_machine: 5,
        tick: 123_456 + seed,
        ..Default::default()
    };
    s.imu = ImuState {
        quaternion: [0.9, 0.1, -0.2, 0.3],
        gyroscope: [0.5, -0.25, 1.0],
        accelerometer: [0.1, 0.2, 9.81],
        rpy: [0.01, 0.02, 0.03],
        temperature: -3,
    };
    for (i, m) in s.motors.iter_mut().enumerate() {
        let f = i as f32;
        *m = MotorState {
            mode: 1,
            q: f * 0.01,
            dq: -f,
            ddq: f * 3.0,
            tau_est: f * 0.5,
            temperature: [30 + i as i16, 40 - i as i16],
            voltage: 48.5,
            sensor: [i as u32, seed],
            motor_state: 0,
            reserve: [1, 2, 3, 4],
        };
    }
    s.wireless_remote = core::array::from_fn(|i| i as u8);
    s.reserve = [9, 8, 7, 6];
    s
}

#[test]
fn sizes_match_the_sdk() {
    assert_eq!(LOW_CMD_LEN, 4 + 35 * 28 + 16 + 4);
    assert_eq!(LOW_STATE_LEN, LOW_STATE_REMOTE_AT + 40 + 16 + 4);
}

#[test]
fn low_cmd_field_offsets() {
    let mut buf = [0u8; LOW_CMD_LEN];
    let cmd = sample_cmd(0);
    encode_low_cmd(&cmd, &mut buf);
    assert_eq!(buf[0], 1);
    assert_eq!(buf[1], 5);
    assert_eq!(&buf[2..4], &[0, 0], "padding must be zero");
    // motor_cmd[3].kp at 4 + 3*28 + 16
    assert_eq!(rd_f32(&buf, 4 + 3 * 28 + 16), cmd.motors[3].kp);
    assert_eq!(&buf[4 + 3 * 28 + 1..4 + 3 * 28 + 4], &[0, 0, 0]);
    assert_eq!(rd_u32(&buf, 984 + 12), 0, "reserve[3] of seed 0");
    assert_eq!(rd_u32(&buf, 1000), crc32_words(&buf[..1000]));
}

#[test]
fn low_state_field_offsets() {
    let mut buf = [0u8; LOW_STATE_LEN];
    let s = sample_state(1);
    encode_low_state(&s, &mut buf);
    assert_eq!(rd_u32(&buf, 12), s.tick);
    assert_eq!(rd_f32(&buf, 16), 0.9, "quaternion w first");
    assert_eq!(rd_i16(&buf, 16 + 52), -3, "imu temperature");
    assert_eq!(&buf[16 + 54..72], &[0, 0], "imu padding");
    assert_eq!(rd_f32(&buf, 72 + 2 * 56 + 4), s.motors[2].q);
    assert_eq!(rd_i16(&buf, 72 + 2 * 56 + 22), s.motors[2].temperature[1]);
    assert_eq!(buf[2032 + 39], 39, "last remote byte");
}

#[test]
fn round_trips() {
    let mut cb = [0u8; LOW_CMD_LEN];
    let cmd = sample_cmd(42);
    encode_low_cmd(&cmd, &mut cb);
    let mut back = LowCommand::default();
    decode_low_cmd(&cb, &mut back).unwrap();
    assert_eq!(back, cmd);

    let mut sb = [0u8; LOW_STATE_LEN];
    let s = sample_state(42);
    encode_low_state(&s, &mut sb);
    let mut back = LowState::default();
    decode_low_state(&sb, &mut back).unwrap();
    assert_eq!(back, s);
}

#[test]
fn short_frame_is_a_length_error() {
    let mut sb = [0u8; LOW_STATE_LEN];
    encode_low_state(&sample_state(0), &mut sb);
    let mut out = LowState::default();
    let e = decode_low_state(&sb[..100], &mut out).unwrap_err();
    assert!(
        matches!(
            e,
            DecodeError::Length {
                expected: LOW_STATE_LEN,
                got: 100,
                ..
            }
        ),
        "{e}"
    );
    let e = decode_low_cmd(&[], &mut LowCommand::default()).unwrap_err();
    assert!(matches!(e, DecodeError::Length { got: 0, .. }));
}

#[test]
fn flipped_bit_is_a_crc_error_and_leaves_output_untouched() {
    let mut sb = [0u8; LOW_STATE_LEN];
    encode_low_state(&sample_state(0), &mut sb);
    sb[500] ^= 0x10;
    let mut out = LowState::default();
    let e = decode_low_state(&sb, &mut out).unwrap_err();
    assert!(matches!(e, DecodeError::Crc { .. }), "{e}");
    assert_eq!(out, LowState::default());
}

#[test]
fn dirty_padding_changes_the_crc() {
    let mut cb = [0u8; LOW_CMD_LEN];
    encode_low_cmd(&sample_cmd(0), &mut cb);
    cb[2] = 0xAA;
    assert!(matches!(
        decode_low_cmd(&cb, &mut LowCommand::default()),
        Err(DecodeError::Crc { .. })
    ));
}

#[test]
fn nan_fields_are_rejected_by_name() {
    let mut s = sample_state(0);
    s.imu.gyroscope[1] = f32::NAN;
    let mut sb = [0u8; LOW_STATE_LEN];
    encode_low_state(&s, &mut sb);
    let e = decode_low_state(&sb, &mut LowState::default()).unwrap_err();
    assert_eq!(
        e,
        DecodeError::NonFinite {
            message: "LowState_",
            field: "imu_state.gyroscope",
            index: 1
        }
    );

    let mut s = sample_state(0);
    s.motors[7].dq = f32::INFINITY;
    encode_low_state(&s, &mut sb);
    let e = decode_low_state(&sb, &mut LowState::default()).unwrap_err();
    assert_eq!(
        e,
        DecodeError::NonFinite {
            message: "LowState_",
            field: "motor_state",
            index: 7
        }
    );

    let mut c = sample_cmd(0);
    c.motors[4].kd = f32::NAN;
    let mut cb = [0u8; LOW_CMD_LEN];
    encode_low_cmd(&c, &mut cb);
    let e = decode_low_cmd(&cb, &mut LowCommand::default()).unwrap_err();
    assert_eq!(
        e,
        DecodeError::NonFinite {
            message: "LowCmd_",
            field: "motor_cmd",
            index: 4
        }
    );
    assert!(e.to_string().contains("motor_cmd[4]"));
}

proptest! {
    #[test]
    fn arbitrary_bytes_never_panic(data in proptest::collection::vec(any::<u8>(), 0..2200)) {
        let _ = decode_low_state(&data, &mut LowState::default());
        let _ = decode_low_cmd(&data, &mut LowCommand::default());
    }

    #[test]
    fn arbitrary_bytes_with_valid_crc_never_panic(mut data in proptest::collection::vec(any::<u8>(), LOW_STATE_LEN..=LOW_STATE_LEN)) {
        seal(&mut data);
        let _ = decode_low_state(&data, &mut LowState::default());
        let mut c = data[..LOW_CMD_LEN].to_vec();
        seal(&mut c);
        let _ = decode_low_cmd(&c, &mut LowCommand::default());
    }
}
