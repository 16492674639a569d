//! The cargo-fuzz targets of `fuzz/` on stable, for CI: every committed seed of every target
//! (`fuzz/corpus/<target>/`) and a deterministic batch of its mutations (bit flips, interesting
//! bytes, truncation, extension, length-field tampering, splices) through the very harness function
//! the target calls. A panic names the target and leaves the input in the temp directory for
//! `cargo fuzz run <target> <file>`. `FUZZ_SMOKE_INPUTS` overrides the mutation count per target.
//!
//! The seeds are written by our own encoders: `cargo test --release -p integration_tests --test
//! fuzz_smoke -- --ignored write_seed_corpus` (re-run it when a wire format changes).
use std::path::{Path, PathBuf};
use std::time::Instant;

use hal::XorShift64 as Rng;

fn corpus_dir(target: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../fuzz/corpus")
        .join(target)
}

/// The committed seeds of `target`; fails loudly when there are none (a moved or emptied corpus
/// must not turn the smoke test into a no-op).
fn seeds(target: &str) -> Vec<Vec<u8>> {
    let dir = corpus_dir(target);
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("fuzz seed corpus {} is missing: {e}", dir.display()))
        .map(|e| e.unwrap().path())
        .collect();
    files.sort();
    assert!(!files.is_empty(), "fuzz seed corpus {} is empty", dir.display());
    files.iter().map(|f| std::fs::read(f).unwrap()).collect()
}

const INTERESTING_U32: [u32; 9] = [0, 1, 2, 0x7F, 0xFF, 0xFFFF, 0x7FFF_FFFF, 0xFFFF_FFFF, 0x8000_0000];

fn mutate(rng: &mut Rng, seeds: &[Vec<u8>], buf: &mut Vec<u8>) {
    buf.clear();
    buf.extend_from_slice(&seeds[rng.below(seeds.len())]);
    for _ in 0..1 + rng.below(4) {
        let len = buf.len();
        match rng.below(8) {
            0 if len > 0 => {
                let i = rng.below(len);
                buf[i] ^= 1 << rng.below(8);
            }
            1 if len > 0 => {
                let i = rng.below(len);
                buf[i] = [0, 1, 0x7F, 0x80, 0xFF, b'0', b'9', b'"', b'[', b'\n'][rng.below(10)];
            }
            2 => buf.truncate(rng.below(len + 1)),
            3 => (0..1 + rng.below(32)).for_each(|_| buf.push(rng.next_u64() as u8)),
            4 if len >= 4 => {
                // A length or count field: a u32/u16/u64 at any offset, set to an extreme, the
                // buffer's own length, or off by one.
                let i = rng.below(len - 3);
                let v = match rng.below(3) {
                    0 => INTERESTING_U32[rng.below(INTERESTING_U32.len())],
                    1 => len as u32,
                    _ => u32::from_le_bytes(buf[i..i + 4].try_into().unwrap())
                        .wrapping_add(rng.below(3) as u32)
                        .wrapping_sub(1),
                };
                match rng.below(3) {
                    0 => buf[i..i + 2].copy_from_slice(&(v as u16).to_le_bytes()),
                    1 if i + 8 <= len => buf[i..i + 8]
                        .copy_from_slice(&(v as u64 | (rng.below(2) as u64 * (u64::MAX << 32))).to_le_bytes()),
                    _ => buf[i..i + 4].copy_from_slice(&v.to_le_bytes()),
                }
            }
            5 => {
                let other = &seeds[rng.below(seeds.len())];
                let cut = rng.below(len + 1);
                let from = rng.below(other.len() + 1);
                buf.truncate(cut);
                buf.extend_from_slice(&other[from..]);
            }
            6 if len > 0 => {
                // Duplicate or delete a chunk (repeated records, a lost record).
                let a = rng.below(len);
                let b = (a + 1 + rng.below(64)).min(len);
                if rng.chance(50) {
                    let chunk = buf[a..b].to_vec();
                    buf.splice(b..b, chunk);
                } else {
                    buf.drain(a..b);
                }
            }
            _ if len > 0 => {
                // Text: a digit run replaced by a huge or negative number.
                let i = rng.below(len);
                if buf[i].is_ascii_digit() {
                    let mut j = i;
                    while j < len && buf[j].is_ascii_digit() {
                        j += 1;
                    }
                    let n = [
                        "18446744073709551615",
                        "4294967296",
                        "-1",
                        "0",
                        "1e308",
                        "nan",
                        "99999999",
                    ][rng.below(7)];
                    buf.splice(i..j, n.bytes());
                }
            }
            _ => {}
        }
    }
}

fn smoke(target: &str, harness: fn(&[u8])) {
    let inputs: u64 = std::env::var("FUZZ_SMOKE_INPUTS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(if cfg!(debug_assertions) { 5_000 } else { 200_000 });
    let seeds = seeds(target);
    let start = Instant::now();
    let run = |data: &[u8], what: &str| {
        if std::panic::catch_unwind(|| harness(data)).is_err() {
            let file = std::env::temp_dir().join(format!("fuzz-smoke-{target}-crash"));
            std::fs::write(&file, data).unwrap();
            panic!(
                "{target}: {what} crashed the harness; input saved to {}",
                file.display()
            );
        }
    };
    for (i, s) in seeds.iter().enumerate() {
        run(s, &format!("seed #{i}"));
    }
    let mut rng = Rng(0xF022_5EED ^ target.len() as u64);
    let mut buf = Vec::new();
    for k in 0..inputs {
        mutate(&mut rng, &seeds, &mut buf);
        run(&buf, &format!("mutation #{k}"));
    }
    let secs = start.elapsed().as_secs_f64();
    println!("{target}: {} seeds + {inputs} mutations in {secs:.2} s", seeds.len());
}

#[test]
fn livox_packet() {
    smoke("livox_packet", sensor_io::livox::fuzz_livox);
}

#[test]
fn unitree_hg_low_state() {
    smoke("unitree_hg_low_state", sensor_io::unitree_hg::fuzz_low_state);
}

#[test]
fn unitree_hg_low_cmd() {
    smoke("unitree_hg_low_cmd", sensor_io::unitree_hg::fuzz_low_cmd);
}

#[test]
fn can_frame() {
    smoke("can_frame", sensor_io::can::fuzz_can);
}

#[test]
fn bridge_protocol() {
    smoke("bridge_protocol", sim_hal::bridge::protocol::fuzz_bridge);
}

#[test]
fn deploy_spec() {
    smoke("deploy_spec", control::controller::fuzz_deploy_spec);
}

#[test]
fn command_envelope() {
    smoke("command_envelope", control::envelope::fuzz_command_envelope);
}

#[test]
fn onnx_import() {
    smoke("onnx_import", policy_import::onnx::fuzz_onnx);
}

#[test]
fn mcap_log() {
    smoke("mcap_log", runlog::log::reader::fuzz_log);
}

/// Every target of fuzz/Cargo.toml has a smoke test here (a new target cannot be forgotten).
#[test]
fn every_fuzz_target_is_smoked() {
    let manifest = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../fuzz/Cargo.toml")).unwrap();
    let here = include_str!("fuzz_smoke.rs");
    for line in manifest.lines().filter_map(|l| l.strip_prefix("name = \"")) {
        let name = line.trim_end_matches('"');
        if name != "g1-fuzz" {
            assert!(
                here.contains(&format!("smoke(\"{name}\"")),
                "fuzz target {name} has no smoke test"
            );
            seeds(name);
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Seed corpus, from our encoders.

mod gen {
    use super::*;
    use hal::{LidarPoint, LowCommand, LowState, TerrainClass, TerrainToken};
    use prost::Message;
    use sensor_io::{can, livox, unitree_hg as hg};
    use sim_hal::bridge::protocol as bp;

    pub fn livox() -> Vec<(&'static str, Vec<u8>)> {
        let packet = |n: usize, udp: u16| {
            let pts: Vec<LidarPoint> = (0..n)
                .map(|i| LidarPoint {
                    xyz: [1.0 + 0.037 * i as f32, -0.5 + 0.011 * i as f32, -0.3],
                    reflectivity: 10,
                    tag: 0,
                    offset_ns: 0,
                })
                .collect();
            let meta = livox::PacketMeta {
                udp_cnt: udp,
                frame_cnt: 0,
                timestamp_ns: 1_000_000_000 + udp as u64 * 480_000,
                time_interval: 4800,
                time_type: 0,
            };
            let mut b = vec![0u8; livox::cartesian_high_len(n)];
            livox::encode_cartesian_high(&meta, &pts, &mut b).unwrap();
            b
        };
        let (a, b) = (packet(3, 1), packet(1, 2));
        vec![
            ("high3", a.clone()),
            ("high24", packet(24, 0)),
            ("stream", [a, b.clone(), b].concat()),
        ]
    }

    fn state() -> LowState {
        let mut s = LowState {
            tick: 12345,
            mode_machine: 5,
            ..LowState::default()
        };
        s.imu.quaternion = [0.99, 0.01, -0.02, 0.1];
        s.imu.accelerometer = [0.1, 0.0, 9.81];
        for (i, m) in s.motors.iter_mut().enumerate() {
            m.q = 0.01 * i as f32;
            m.dq = -0.1;
            m.tau_est = 1.5;
            m.temperature = [40, 38];
            m.voltage = 48.0;
        }
        s
    }

    fn command() -> LowCommand {
        let mut c = LowCommand {
            mode_machine: 5,
            ..LowCommand::default()
        };
        for (i, m) in c.motors.iter_mut().enumerate() {
            m.mode = 1;
            m.q = 0.02 * i as f32;
            m.kp = 100.0;
            m.kd = 2.0;
        }
        c
    }

    pub fn low_state() -> Vec<(&'static str, Vec<u8>)> {
        let mut c = [0u8; hg::LOW_STATE_LEN];
        hg::encode_low_state(&state(), &mut c);
        let mut cdr = [0u8; hg::cdr::LOW_STATE_CDR_LEN];
        hg::cdr::low_state_to_cdr(&c, &mut cdr);
        let mut nan = state();
        nan.motors[7].dq = f32::NAN;
        let mut n = [0u8; hg::LOW_STATE_LEN];
        hg::encode_low_state(&nan, &mut n);
        vec![
            ("c", [&[0u8][..], &c].concat()),
            ("resealed", [&[1u8][..], &n[..hg::LOW_STATE_LEN - 4]].concat()),
            ("cdr", [&[2u8][..], &cdr].concat()),
        ]
    }

    pub fn low_cmd() -> Vec<(&'static str, Vec<u8>)> {
        let mut c = [0u8; hg::LOW_CMD_LEN];
        hg::encode_low_cmd(&command(), &mut c);
        let mut cdr = [0u8; hg::cdr::LOW_CMD_CDR_LEN];
        hg::cdr::low_cmd_to_cdr(&c, &mut cdr);
        vec![
            ("c", [&[0u8][..], &c].concat()),
            ("resealed", [&[1u8][..], &c[..hg::LOW_CMD_LEN - 4]].concat()),
            ("cdr", [&[2u8][..], &cdr].concat()),
        ]
    }

    pub fn can_frames() -> Vec<(&'static str, Vec<u8>)> {
        let layout_text =
            std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../specs/can/g1_12dof.toml")).unwrap();
        let layout = can::BusLayout::from_toml(&layout_text).unwrap();
        let r = layout.motors[0].ranges;
        let frame = |f: can::CanFrame| {
            let mut b = f.id.to_le_bytes().to_vec();
            b.push(f.len);
            b.extend_from_slice(&f.data);
            b
        };
        let mut stream = vec![0u8];
        let cmd = can::MitCommand {
            q: 0.3,
            dq: -1.0,
            kp: 40.0,
            kd: 1.0,
            tau: 2.0,
        };
        stream.extend(frame(can::encode_command(1, &cmd, &r)));
        stream.extend(frame(can::encode_special(2, can::Special::EnterMotorMode)));
        stream.extend(frame(can::encode_reply(1, 0.3, -1.0, 2.0, &r)));
        for f in can::encode_imu(&state().imu, 7) {
            stream.extend(frame(f));
        }
        vec![
            ("frames", stream),
            ("layout", [b"\x01".as_slice(), layout_text.as_bytes()].concat()),
        ]
    }

    pub fn bridge() -> Vec<(&'static str, Vec<u8>)> {
        let mut s = Vec::new();
        let mut hello = [0u8; 8];
        hello[..4].copy_from_slice(&bp::PROTOCOL_VERSION.to_le_bytes());
        hello[4] = 1;
        hello[5] = 1;
        bp::append_msg(&mut s, bp::Kind::Hello, &hello);
        let w = bp::Welcome {
            protocol_version: bp::PROTOCOL_VERSION,
            motor_slots_present: (1 << 29) - 1,
            mode_machine: 5,
            physics_dt_ns: 1_000_000,
            control_dt_ns: 2_000_000,
        };
        bp::append_msg(&mut s, bp::Kind::Welcome, &w.encode());
        let mut st = [0u8; sensor_io::unitree_hg::LOW_STATE_LEN];
        sensor_io::unitree_hg::encode_low_state(&state(), &mut st);
        bp::append_msg(&mut s, bp::Kind::LowState, &st);
        let mut lidar = Vec::new();
        bp::append_datagram(&mut lidar, &livox()[0].1);
        bp::append_msg(&mut s, bp::Kind::LidarPackets, &lidar);
        let t = bp::Truth {
            sim_time_s: 1.5,
            base_pos: [1.0, 2.0, 0.78],
            base_quat: [1.0, 0.0, 0.0, 0.0],
            foot_contact: [true, false],
            terrain: Some(TerrainToken {
                class: TerrainClass::StairsUp,
                step_height_m: 0.15,
                step_depth_m: 0.3,
                yaw_rad: 0.1,
            }),
            ground_height_m: 0.3,
            stairs: Some(bp::StairProgress {
                axis_s: 1.2,
                risers: 6,
                risers_passed: 2,
                ..Default::default()
            }),
            ..Default::default()
        };
        bp::append_msg(&mut s, bp::Kind::Truth, &bp::encode_truth(&t));
        let mut cmd = [0u8; sensor_io::unitree_hg::LOW_CMD_LEN];
        sensor_io::unitree_hg::encode_low_cmd(&command(), &mut cmd);
        bp::append_msg(&mut s, bp::Kind::LowCmd, &cmd);
        bp::append_msg_flags(&mut s, bp::Kind::LowState, bp::FLAG_NO_FRAME, &[]);
        bp::append_msg(&mut s, bp::Kind::Bye, &[]);
        let mut err = Vec::new();
        bp::append_msg(&mut err, bp::Kind::Error, b"model not found");
        vec![("exchange", s), ("error", err)]
    }

    /// A 12-joint spec small enough to carry its weights (after a NUL) in a few KB.
    /// A margin byte and a LowCmd of 35 × (mode, q, dq, tau, kp, kd): a healthy policy command,
    /// damping, and one with every kind of breach.
    pub fn command_envelope() -> Vec<(&'static str, Vec<u8>)> {
        let cmd = |m: &dyn Fn(usize) -> (u8, [f32; 5])| -> Vec<u8> {
            let mut v = vec![20u8];
            for s in 0..hal::NUM_MOTORS {
                let (mode, f) = m(s);
                v.push(mode);
                f.iter().for_each(|x| v.extend_from_slice(&x.to_le_bytes()));
            }
            v
        };
        vec![
            (
                "policy",
                cmd(&|s| (if s < 29 { 0 } else { 0x80 }, [0.1, 0.0, 0.0, 100.0, 2.0])),
            ),
            ("damping", cmd(&|_| (0, [0.0, 0.0, 0.0, 0.0, 8.0]))),
            (
                "breaches",
                cmd(&|s| {
                    (
                        0,
                        [
                            [f32::NAN, 9.0, -9.0, 0.0, 1e6][s % 5],
                            [0.0, 1e9, f32::INFINITY, 0.0, 0.0][s % 5],
                            500.0,
                            5000.0,
                            -1.0,
                        ],
                    )
                }),
            ),
        ]
    }

    pub fn deploy_spec() -> Vec<(&'static str, Vec<u8>)> {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let spec = r#"[meta]
name = "fuzz_seed"

[rates]
control_hz = 500
policy_hz = 50

[policy]
weights = "w.safetensors"
joint_ids_map = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11]
default_pose = [-0.1, 0.0, 0.0, 0.3, -0.2, 0.0, -0.1, 0.0, 0.0, 0.3, -0.2, 0.0]
action_scale = 0.25
kp = [100, 100, 100, 150, 40, 40, 100, 100, 100, 150, 40, 40]
kd = [2, 2, 2, 4, 2, 2, 2, 2, 2, 4, 2, 2]

[policy.network]
input = 47
layers = [
  { type = "linear", weight = "a.w", bias = "a.b" },
  { type = "elu", alpha = 1.0 },
  { type = "linear", weight = "b.w", bias = "b.b" },
]

[[held]]
joints = ["waist_yaw"]
q = 0.0
kp = 200.0
kd = 5.0

[phase]
period_s = 0.8
first_step_time_s = 0.02

[observation]
terms = [
  { kind = "base_ang_vel", scale = 0.25 },
  { kind = "projected_gravity" },
  { kind = "velocity_command", scale = [2.0, 2.0, 0.25] },
  { kind = "joint_pos_rel" },
  { kind = "joint_vel", scale = 0.05, clip = 100.0 },
  { kind = "last_action", clip_before_scale = [-10.0, 10.0] },
  { kind = "gait_phase" },
]
"#;
        let t = |dims: Vec<usize>| {
            let n: usize = dims.iter().product();
            let data: Vec<u8> = (0..n)
                .flat_map(|i| ((i % 7) as f32 * 0.01 - 0.03).to_le_bytes())
                .collect();
            (dims, data)
        };
        let tensors = [
            ("a.w", t(vec![8, 47])),
            ("a.b", t(vec![8])),
            ("b.w", t(vec![12, 8])),
            ("b.b", t(vec![12])),
        ];
        let views: Vec<_> = tensors
            .iter()
            .map(|(n, (d, b))| {
                (
                    n.to_string(),
                    safetensors::tensor::TensorView::new(safetensors::Dtype::F32, d.clone(), b).unwrap(),
                )
            })
            .collect();
        let weights = safetensors::serialize(views, &None).unwrap();
        control::spec::DeploySpec::from_toml(spec, Path::new("/nonexistent/spec.toml"))
            .expect("the seed spec is valid");
        let mut out = vec![("small_with_weights", [spec.as_bytes(), b"\0", &weights].concat())];
        for (name, file) in [
            ("rl_lab_style", "specs/test/rl_lab_style.toml"),
            ("peer_lstm", "specs/peer/unitree_g1_lstm.toml"),
        ] {
            out.push((name, std::fs::read(root.join(file)).unwrap()));
        }
        out
    }

    /// Small logs in g1fw's layout (run metadata first, then chunks of messages on its topics),
    /// lz4-chunked as g1fw writes them and uncompressed, plus one cut short as a killed writer
    /// leaves it.
    pub fn mcap_log() -> Vec<(&'static str, Vec<u8>)> {
        use runlog::log::channels as ch;
        let write = |compression: Option<mcap::Compression>| {
            let mut out = std::io::Cursor::new(Vec::new());
            let mut w = mcap::WriteOptions::new()
                .compression(compression)
                .chunk_size(Some(1024))
                .create(&mut out)
                .unwrap();
            let meta = mcap::records::Metadata {
                name: ch::RUN_METADATA.into(),
                metadata: [
                    ("spec_name".to_string(), "fuzz_seed".to_string()),
                    ("control_hz".into(), "500".into()),
                ]
                .into(),
            };
            w.write_metadata(&meta).unwrap();
            let schema = w
                .add_schema("unitree_hg/msg/LowState", "ros2msg", ch::LOW_STATE_MSG.as_bytes())
                .unwrap();
            let state = w
                .add_channel(schema, ch::LOW_STATE, "cdr", &Default::default())
                .unwrap();
            let schema = w
                .add_schema("unitree_hg/msg/LowCmd", "ros2msg", ch::LOW_CMD_MSG.as_bytes())
                .unwrap();
            let cmd = w.add_channel(schema, ch::LOW_CMD, "cdr", &Default::default()).unwrap();
            let mut st = [0u8; sensor_io::unitree_hg::LOW_STATE_LEN];
            sensor_io::unitree_hg::encode_low_state(&state_(), &mut st);
            let mut c = [0u8; sensor_io::unitree_hg::LOW_CMD_LEN];
            sensor_io::unitree_hg::encode_low_cmd(&command(), &mut c);
            for tick in 0..3u32 {
                let t = tick as u64 * 2_000_000;
                let header = |channel_id, sequence| mcap::records::MessageHeader {
                    channel_id,
                    sequence,
                    log_time: t,
                    publish_time: t,
                };
                w.write_to_known_channel(&header(state, tick), &st[..256]).unwrap();
                w.write_to_known_channel(&header(cmd, tick), &c[..128]).unwrap();
            }
            w.finish().unwrap();
            drop(w);
            out.into_inner()
        };
        let lz4 = write(Some(mcap::Compression::Lz4));
        for bytes in [&lz4, &write(None)] {
            let log = runlog::log::LogFile::from_bytes(Path::new("seed.mcap"), bytes.clone()).unwrap();
            log.run_metadata().expect("the seed has run metadata");
            assert_eq!(log.scan(|_, _, _| {}).messages, 6, "the seed's messages read back");
        }
        let cut = lz4[..lz4.len() * 2 / 3].to_vec();
        vec![("lz4", lz4), ("plain", write(None)), ("killed", cut)]
    }

    fn state_() -> LowState {
        state()
    }

    pub fn onnx() -> Vec<(&'static str, Vec<u8>)> {
        use policy_import::onnx::proto::*;
        let f32_tensor = |name: &str, dims: &[i64], scale: f32| {
            let n: i64 = dims.iter().product();
            TensorProto {
                name: Some(name.into()),
                dims: dims.to_vec(),
                data_type: Some(tensor_proto::DataType::Float as i32),
                raw_data: Some(
                    (0..n)
                        .flat_map(|i| (((i % 5) as f32 - 2.5) * scale).to_le_bytes())
                        .collect(),
                ),
                ..Default::default()
            }
        };
        let value = |name: &str, dim: i64| ValueInfoProto {
            name: Some(name.into()),
            r#type: Some(TypeProto {
                value: Some(type_proto::Value::TensorType(type_proto::Tensor {
                    elem_type: Some(1),
                    shape: Some(TensorShapeProto {
                        dim: vec![
                            tensor_shape_proto::Dimension {
                                value: Some(tensor_shape_proto::dimension::Value::DimValue(1)),
                                ..Default::default()
                            },
                            tensor_shape_proto::Dimension {
                                value: Some(tensor_shape_proto::dimension::Value::DimValue(dim)),
                                ..Default::default()
                            },
                        ],
                    }),
                })),
                ..Default::default()
            }),
            ..Default::default()
        };
        let node = |op: &str, inputs: &[&str], out: &str, attrs: Vec<AttributeProto>| NodeProto {
            op_type: Some(op.into()),
            name: Some(format!("{op}_{out}")),
            input: inputs.iter().map(|s| s.to_string()).collect(),
            output: vec![out.into()],
            attribute: attrs,
            ..Default::default()
        };
        let int_attr = |name: &str, i: i64| AttributeProto {
            name: Some(name.into()),
            i: Some(i),
            r#type: Some(attribute_proto::AttributeType::Int as i32),
            ..Default::default()
        };
        let float_attr = |name: &str, f: f32| AttributeProto {
            name: Some(name.into()),
            f: Some(f),
            r#type: Some(attribute_proto::AttributeType::Float as i32),
            ..Default::default()
        };
        let model = |graph: GraphProto| {
            ModelProto {
                ir_version: Some(8),
                opset_import: vec![OperatorSetIdProto {
                    domain: Some(String::new()),
                    version: Some(17),
                }],
                graph: Some(graph),
                ..Default::default()
            }
            .encode_to_vec()
        };
        // rsl_rl's MLP: Gemm (transB) → Elu → Gemm, with a normaliser in front.
        let mlp = model(GraphProto {
            name: Some("mlp".into()),
            node: vec![
                node("Sub", &["obs", "mean"], "centred", vec![]),
                node("Div", &["centred", "std"], "normed", vec![]),
                node("Gemm", &["normed", "w0", "b0"], "h0", vec![int_attr("transB", 1)]),
                node("Elu", &["h0"], "a0", vec![float_attr("alpha", 1.0)]),
                node("Gemm", &["a0", "w1", "b1"], "actions", vec![int_attr("transB", 1)]),
            ],
            initializer: vec![
                f32_tensor("mean", &[6], 0.1),
                f32_tensor("std", &[6], -0.5),
                f32_tensor("w0", &[8, 6], 0.2),
                f32_tensor("b0", &[8], 0.1),
                f32_tensor("w1", &[3, 8], 0.3),
                f32_tensor("b1", &[3], 0.0),
            ],
            input: vec![value("obs", 6)],
            output: vec![value("actions", 3)],
            ..Default::default()
        });
        // IsaacLab's MatMul + Add form with a Tanh and an action scale after the last layer.
        let matmul = model(GraphProto {
            name: Some("matmul".into()),
            node: vec![
                node("MatMul", &["obs", "w0"], "m0", vec![]),
                node("Add", &["m0", "b0"], "h0", vec![]),
                node("Tanh", &["h0"], "a0", vec![]),
                node("Flatten", &["a0"], "f0", vec![]),
                node("MatMul", &["f0", "w1"], "m1", vec![]),
                node("Add", &["m1", "b1"], "h1", vec![]),
                node("Mul", &["h1", "scale"], "actions", vec![]),
            ],
            initializer: vec![
                f32_tensor("w0", &[5, 4], 0.2),
                f32_tensor("b0", &[4], 0.1),
                f32_tensor("w1", &[4, 2], 0.3),
                f32_tensor("b1", &[2], 0.0),
                f32_tensor("scale", &[1], 0.5),
            ],
            input: vec![value("obs", 5)],
            output: vec![value("actions", 2)],
            ..Default::default()
        });
        // A one-layer LSTM (ONNX gate order), state as graph inputs, then a Gemm.
        let (h, inp) = (3i64, 4i64);
        let lstm = model(GraphProto {
            name: Some("lstm".into()),
            node: vec![
                NodeProto {
                    op_type: Some("LSTM".into()),
                    name: Some("lstm".into()),
                    input: ["obs", "W", "R", "B", "", "h_in", "c_in"]
                        .iter()
                        .map(|s| s.to_string())
                        .collect(),
                    output: vec!["y".into(), "h_out".into(), "c_out".into()],
                    attribute: vec![int_attr("hidden_size", h)],
                    ..Default::default()
                },
                node("Squeeze", &["y"], "ys", vec![]),
                node("Gemm", &["ys", "w1", "b1"], "actions", vec![int_attr("transB", 1)]),
            ],
            initializer: vec![
                f32_tensor("W", &[1, 4 * h, inp], 0.1),
                f32_tensor("R", &[1, 4 * h, h], 0.1),
                f32_tensor("B", &[1, 8 * h], 0.05),
                f32_tensor("w1", &[2, h], 0.3),
                f32_tensor("b1", &[2], 0.0),
            ],
            input: vec![value("obs", inp), value("h_in", h), value("c_in", h)],
            output: vec![value("actions", 2), value("h_out", h), value("c_out", h)],
            ..Default::default()
        });
        let nets = [("mlp", mlp), ("matmul", matmul), ("lstm", lstm)];
        for (name, bytes) in &nets {
            if let Err(e) = policy_import::import_bytes(bytes) {
                panic!("seed model {name} does not import: {e}");
            }
        }
        nets.into()
    }
}

/// Writes fuzz/corpus/<target>/seed-<name> from the encoders above (run by hand; the files are
/// committed). Old `seed-*` files of a target are replaced.
#[test]
#[ignore]
fn write_seed_corpus() {
    type Seeds = Vec<(&'static str, Vec<u8>)>;
    let all: [(&str, Seeds); 9] = [
        ("livox_packet", gen::livox()),
        ("unitree_hg_low_state", gen::low_state()),
        ("unitree_hg_low_cmd", gen::low_cmd()),
        ("can_frame", gen::can_frames()),
        ("bridge_protocol", gen::bridge()),
        ("deploy_spec", gen::deploy_spec()),
        ("onnx_import", gen::onnx()),
        ("mcap_log", gen::mcap_log()),
        ("command_envelope", gen::command_envelope()),
    ];
    for (target, seeds) in all {
        let dir = corpus_dir(target);
        std::fs::create_dir_all(&dir).unwrap();
        for old in std::fs::read_dir(&dir).unwrap() {
            let p = old.unwrap().path();
            if p.file_name().unwrap().to_string_lossy().starts_with("seed-") {
                std::fs::remove_file(p).unwrap();
            }
        }
        for (name, bytes) in seeds {
            std::fs::write(dir.join(format!("seed-{name}")), bytes).unwrap();
        }
    }
}
