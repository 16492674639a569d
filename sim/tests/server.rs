//! Bridge server end to end: in-process over a Unix socket, and the `g1-sim` binary.
mod common;

use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::{load29, require_deps};
use g1_sim::server::{serve_unix, ServeError, ServeOptions, SessionEnd};
use hal::{LowCommand, LowState};
use sensor_io::unitree_hg::{decode_low_state, encode_low_cmd, LOW_CMD_LEN};
use sim_hal::bridge::{read_msg, write_msg, Kind, ProtocolError, Welcome, PROTOCOL_VERSION};

fn sock_path(tag: &str) -> PathBuf {
    std::env::temp_dir().join(format!("g1-sim-test-{tag}-{}.sock", std::process::id()))
}

fn connect(path: &Path) -> UnixStream {
    let t0 = Instant::now();
    loop {
        match UnixStream::connect(path) {
            Ok(s) => return s,
            Err(e) if t0.elapsed() < Duration::from_secs(20) => {
                let _ = e;
                std::thread::sleep(Duration::from_millis(5));
            }
            Err(e) => panic!("cannot connect to {}: {e}", path.display()),
        }
    }
}

struct Client {
    s: UnixStream,
    payload: Vec<u8>,
    scratch: Vec<u8>,
}

impl Client {
    fn hello(path: &Path, want_truth: bool) -> (Self, Welcome) {
        let mut c = Client {
            s: connect(path),
            payload: Vec::new(),
            scratch: Vec::new(),
        };
        let mut hello = [0u8; 8];
        hello[..4].copy_from_slice(&PROTOCOL_VERSION.to_le_bytes());
        hello[4] = want_truth as u8;
        c.send(Kind::Hello, &hello);
        assert_eq!(c.recv().unwrap(), Kind::Welcome);
        let w = Welcome::decode(&c.payload).unwrap();
        (c, w)
    }
    fn send(&mut self, kind: Kind, payload: &[u8]) {
        write_msg(&mut self.s, kind, payload, &mut self.scratch).unwrap();
    }
    fn recv(&mut self) -> Result<Kind, ProtocolError> {
        read_msg(&mut self.s, &mut self.payload)
    }
    fn recv_state(&mut self, st: &mut LowState) {
        assert_eq!(self.recv().unwrap(), Kind::LowState);
        decode_low_state(&self.payload, st).unwrap();
    }
}

#[test]
fn unix_socket_connection_hello_lowcmd_lowstate_bye() {
    let mut sim = load29();
    let hold = sim.hold_initial_pose_command();
    let path = sock_path("e2e");
    let p2 = path.clone();
    let server = std::thread::spawn(move || serve_unix(&p2, &mut sim, &ServeOptions::default(), || {}));

    let (mut c, w) = Client::hello(&path, true);
    assert_eq!(w.protocol_version, PROTOCOL_VERSION);
    assert_eq!(w.motor_slots_present, (1 << 29) - 1);
    assert_eq!(w.mode_machine, 5);
    assert_eq!((w.physics_dt_ns, w.control_dt_ns), (2_000_000, 2_000_000));
    let mut st = LowState::default();
    c.recv_state(&mut st);
    assert_eq!(st.tick, 0);
    assert_eq!(st.motors[3].q, 0.3);
    assert_eq!(c.recv().unwrap(), Kind::Truth);
    assert_eq!(sim_hal::bridge::decode_truth(&c.payload).unwrap().base_pos[2], 0.7837);

    let mut bytes = [0u8; LOW_CMD_LEN];
    encode_low_cmd(&hold, &mut bytes);
    for tick in 1..=10 {
        c.send(Kind::LowCmd, &bytes);
        c.recv_state(&mut st);
        assert_eq!(st.tick, tick);
        assert_eq!(c.recv().unwrap(), Kind::Truth);
        let t = sim_hal::bridge::decode_truth(&c.payload).unwrap();
        assert!((t.sim_time_s - 0.002 * tick as f64).abs() < 1e-12);
    }
    assert!(st.motors[3].tau_est != 0.0, "PD is acting");
    c.send(Kind::Bye, &[]);
    let summary = server.join().unwrap().unwrap();
    assert_eq!(summary.end, SessionEnd::Bye);
    assert_eq!(summary.ticks, 10);
    assert!(!path.exists(), "socket file removed on exit");
}

#[test]
fn malformed_lowcmd_gets_error_reply() {
    let mut sim = load29();
    let path = sock_path("bad");
    let p2 = path.clone();
    let server = std::thread::spawn(move || serve_unix(&p2, &mut sim, &ServeOptions::default(), || {}));
    let (mut c, _) = Client::hello(&path, false);
    let mut st = LowState::default();
    c.recv_state(&mut st);
    let mut bytes = [0u8; LOW_CMD_LEN];
    encode_low_cmd(&LowCommand::default(), &mut bytes);
    bytes[10] ^= 0xFF; // breaks the CRC
    c.send(Kind::LowCmd, &bytes);
    match c.recv() {
        Err(ProtocolError::Remote(msg)) => assert!(msg.contains("CRC"), "{msg}"),
        other => panic!("expected an Error message, got {other:?}"),
    }
    let err = server.join().unwrap().unwrap_err();
    assert!(matches!(err, ServeError::MalformedCmd(_)), "{err}");
    assert_eq!(err.exit_code(), 3);
    assert!(!path.exists());
}

#[test]
fn client_disconnect_ends_connection_cleanly() {
    let mut sim = load29();
    let path = sock_path("disc");
    let p2 = path.clone();
    let server = std::thread::spawn(move || serve_unix(&p2, &mut sim, &ServeOptions::default(), || {}));
    let (mut c, _) = Client::hello(&path, false);
    let mut st = LowState::default();
    c.recv_state(&mut st);
    drop(c);
    let s = server.join().unwrap().unwrap();
    assert_eq!(s.end, SessionEnd::Disconnected);
}

fn g1_sim() -> Command {
    Command::new(env!("CARGO_BIN_EXE_g1-sim"))
}

#[test]
fn binary_refuses_non_loopback_tcp() {
    require_deps();
    let out = g1_sim().args(["--tcp", "0.0.0.0:7000", "--quiet"]).output().unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("not a loopback address"), "{err}");
}

#[test]
fn binary_exits_3_on_nan_lowcmd() {
    require_deps();
    let path = sock_path("bin");
    let child = g1_sim()
        .args(["--quiet", "--socket"])
        .arg(&path)
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let (mut c, _) = Client::hello(&path, false);
    let mut st = LowState::default();
    c.recv_state(&mut st);
    // A NaN with a valid CRC: the decoder must catch it, not the CRC.
    let mut cmd = LowCommand::default();
    cmd.motors[4].q = f32::NAN;
    let mut bytes = [0u8; LOW_CMD_LEN];
    encode_low_cmd(&cmd, &mut bytes);
    c.send(Kind::LowCmd, &bytes);
    match c.recv() {
        Err(ProtocolError::Remote(msg)) => assert!(msg.contains("non-finite"), "{msg}"),
        other => panic!("expected an Error message, got {other:?}"),
    }
    let out = child.wait_with_output().unwrap();
    assert_eq!(out.status.code(), Some(3), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(!path.exists(), "socket file removed on exit");
}

#[test]
fn binary_bench_bare_prints_json() {
    require_deps();
    let out = g1_sim().args(["--bench-bare", "0.2"]).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let line = String::from_utf8(out.stdout).unwrap();
    assert!(line.starts_with("{\"sim_seconds_per_wall_second\": "), "{line}");
    assert!(line.trim_end().ends_with("\"steps\": 100}"), "{line}");
}
