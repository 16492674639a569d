//! Lock-stepped round trips through the Unix-socket server (in-process server thread), holding
//! the initial pose: `cargo run -p g1_sim --release --example bridge_loop -- [MODEL] [SECONDS] [SPIN_US]`.
//! Prints the same JSON shape as `g1-sim --bench-bare`, for comparing bridge overhead.
use std::os::unix::net::UnixStream;
use std::time::{Duration, Instant};

use g1_sim::server::{serve_unix, ServeOptions};
use g1_sim::{ModelChoice, SimConfig, Simulator};
use hal::LowState;
use sensor_io::unitree_hg::{decode_low_state, encode_low_cmd, LOW_CMD_LEN};
use sim_hal::bridge::{read_msg, write_msg, Kind, PROTOCOL_VERSION};

fn main() {
    let mut args = std::env::args().skip(1);
    let model: ModelChoice = args.next().unwrap_or_else(|| "g1-29dof".into()).parse().unwrap();
    let seconds: f64 = args.next().map_or(10.0, |s| s.parse().unwrap());
    let spin_us: u64 = args.next().map_or(20, |s| s.parse().unwrap());
    let mut sim = Simulator::load(model, SimConfig::default()).unwrap();
    let cmd = sim.hold_initial_pose_command();
    let ticks = (seconds / sim.config().control_dt).round() as u64;
    let path = std::env::temp_dir().join(format!("g1-bridge-loop-{}.sock", std::process::id()));
    let p2 = path.clone();
    let opts = ServeOptions {
        spin: Duration::from_micros(spin_us),
        quiet: true,
        ..ServeOptions::default()
    };
    let (tx, rx) = std::sync::mpsc::channel();
    let server = std::thread::spawn(move || serve_unix(&p2, &mut sim, &opts, || tx.send(()).unwrap()));
    rx.recv().unwrap();
    let mut s = UnixStream::connect(&path).unwrap();
    let (mut payload, mut scratch) = (Vec::new(), Vec::new());
    let mut hello = [0u8; 8];
    hello[..4].copy_from_slice(&PROTOCOL_VERSION.to_le_bytes());
    write_msg(&mut s, Kind::Hello, &hello, &mut scratch).unwrap();
    assert_eq!(read_msg(&mut s, &mut payload).unwrap(), Kind::Welcome);
    assert_eq!(read_msg(&mut s, &mut payload).unwrap(), Kind::LowState);
    let (mut bytes, mut st) = ([0u8; LOW_CMD_LEN], LowState::default());
    encode_low_cmd(&cmd, &mut bytes);
    let t0 = Instant::now();
    for _ in 0..ticks {
        write_msg(&mut s, Kind::LowCmd, &bytes, &mut scratch).unwrap();
        assert_eq!(read_msg(&mut s, &mut payload).unwrap(), Kind::LowState);
        decode_low_state(&payload, &mut st).unwrap();
    }
    let wall = t0.elapsed().as_secs_f64();
    write_msg(&mut s, Kind::Bye, &[], &mut scratch).unwrap();
    let summary = server.join().unwrap().unwrap();
    println!(
        "{{\"sim_seconds_per_wall_second\": {:.3}, \"steps\": {}, \"spin_us\": {spin_us}}}",
        summary.sim_time_s / wall,
        st.tick
    );
}
