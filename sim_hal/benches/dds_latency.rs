//! LowState → LowCmd latency over DDS on loopback, beside the simulator bridge's Unix socket, in the
//! same run (the machine is shared: compare the ratio, not the absolute figures).
//!
//! A robot thread sends a LowState and times until a LowCmd comes back; the controller thread does
//! what `g1fw`'s HAL does per tick minus the control itself: wait for the state, decode it (CDR →
//! C layout → CRC), encode a command (C layout + CRC → CDR) and send it. Also timed on the
//! controller: arrival (the wait returning) → command handed to the transport.
//!
//!     cargo bench -p sim_hal --bench dds_latency [-- SAMPLES]
// Test data from std's math on the host; this never runs on the robot.
#![allow(clippy::disallowed_methods)]
use std::io::{BufReader, Write};
use std::os::unix::net::UnixStream;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use hal::{LowCommand, LowLevel, LowState, TimeBase};
use robot_io::dds::{DdsLink, Endpoint, ROBOT, SAMPLE_CAP};
use robot_io::{DdsHal, DdsHalConfig};
use sensor_io::unitree_hg::cdr::{low_state_to_cdr, LOW_STATE_CDR_LEN};
use sensor_io::unitree_hg::{
    decode_low_cmd, decode_low_state, encode_low_cmd, encode_low_state, LOW_CMD_LEN, LOW_STATE_LEN,
};
use sim_hal::bridge::protocol::{read_msg, write_msg, Kind};

fn state(k: u32) -> [u8; LOW_STATE_LEN] {
    let mut s = LowState {
        tick: k,
        ..Default::default()
    };
    s.imu.quaternion = [1.0, 0.0, 0.0, 0.0];
    for (i, m) in s.motors.iter_mut().enumerate() {
        m.q = (k as f32 * 0.01 + i as f32).sin();
    }
    let mut b = [0u8; LOW_STATE_LEN];
    encode_low_state(&s, &mut b);
    b
}

fn percentiles(name: &str, v: &mut [f64]) -> [f64; 3] {
    v.sort_by(f64::total_cmp);
    let p = |q: f64| v[((v.len() - 1) as f64 * q).round() as usize];
    let r = [p(0.5), p(0.99), *v.last().unwrap()];
    println!(
        "{name:<48} p50 {:>7.1} µs   p99 {:>7.1} µs   max {:>8.1} µs   (n = {})",
        r[0],
        r[1],
        r[2],
        v.len()
    );
    r
}

fn dds(samples: usize) -> ([f64; 3], [f64; 3]) {
    let endpoint = Endpoint {
        interface: "lo".into(),
        domain: 150 + (std::process::id() % 50) as u16,
    };
    let stop = Arc::new(AtomicBool::new(false));
    let controller = {
        let (endpoint, stop) = (endpoint.clone(), stop.clone());
        std::thread::spawn(move || {
            let mut cfg = DdsHalConfig::new(endpoint, 2_000_000);
            cfg.discovery = Duration::from_millis(300);
            cfg.tick_timeout = Duration::from_millis(50);
            let mut hal = DdsHal::open(cfg).expect("DDS HAL");
            let (mut st, cmd) = (LowState::default(), LowCommand::default());
            let mut inner = Vec::with_capacity(samples);
            while !stop.load(Ordering::Relaxed) {
                hal.wait_tick().unwrap();
                let t = Instant::now();
                if hal.read_state(&mut st).unwrap_or(false) {
                    hal.write_command(&cmd).unwrap();
                    inner.push(t.elapsed().as_secs_f64() * 1e6);
                }
            }
            inner
        })
    };
    let link = DdsLink::open(&endpoint, ROBOT, Duration::from_millis(300), false).expect("robot side");
    let mut cdr = [0u8; LOW_STATE_CDR_LEN];
    let mut raw = vec![0u8; SAMPLE_CAP];
    let (mut seen, mut rtt) = (0u64, Vec::with_capacity(samples));
    // Warm-up until the two have found each other, then the measured samples.
    let mut k = 0u32;
    while rtt.len() < samples {
        low_state_to_cdr(&state(k), &mut cdr);
        let t = Instant::now();
        link.send(&cdr).unwrap();
        if let Some((seq, _)) = link.wait_newer(seen, Duration::from_millis(100), &mut raw).unwrap() {
            seen = seq;
            if k >= 200 {
                rtt.push(t.elapsed().as_secs_f64() * 1e6);
            }
        }
        k += 1;
        // The robot publishes at 500 Hz; do not measure a flood.
        std::thread::sleep(Duration::from_micros(500));
    }
    stop.store(true, Ordering::Relaxed);
    let mut inner = controller.join().unwrap();
    // The controller also answered the warm-up states.
    inner.drain(..inner.len().saturating_sub(samples));
    (
        percentiles("DDS round trip (robot: state out → cmd in)", &mut rtt),
        percentiles("DDS controller (state arrived → cmd handed on)", &mut inner),
    )
}

fn bridge(samples: usize) -> ([f64; 3], [f64; 3]) {
    let (robot, ctrl) = UnixStream::pair().unwrap();
    let controller = std::thread::spawn(move || {
        let mut r = BufReader::new(ctrl.try_clone().unwrap());
        let mut w = ctrl;
        let (mut payload, mut scratch) = (Vec::with_capacity(4096), Vec::with_capacity(4096));
        let (mut st, cmd) = (LowState::default(), LowCommand::default());
        let mut out = [0u8; LOW_CMD_LEN];
        let mut inner = Vec::with_capacity(samples);
        while let Ok(kind) = read_msg(&mut r, &mut payload) {
            if kind != Kind::LowState {
                break;
            }
            let t = Instant::now();
            decode_low_state(&payload, &mut st).unwrap();
            encode_low_cmd(&cmd, &mut out);
            write_msg(&mut w, Kind::LowCmd, &out, &mut scratch).unwrap();
            inner.push(t.elapsed().as_secs_f64() * 1e6);
        }
        inner
    });
    let mut r = BufReader::new(robot.try_clone().unwrap());
    let mut w = robot;
    let (mut payload, mut scratch) = (Vec::with_capacity(4096), Vec::with_capacity(4096));
    let mut rtt = Vec::with_capacity(samples);
    let mut got = LowCommand::default();
    for k in 0..samples as u32 + 200 {
        let s = state(k);
        let t = Instant::now();
        write_msg(&mut w, Kind::LowState, &s, &mut scratch).unwrap();
        assert_eq!(read_msg(&mut r, &mut payload).unwrap(), Kind::LowCmd);
        let dt = t.elapsed().as_secs_f64() * 1e6;
        decode_low_cmd(&payload, &mut got).unwrap();
        if k >= 200 {
            rtt.push(dt);
        }
        std::thread::sleep(Duration::from_micros(500));
    }
    w.write_all(&[]).unwrap();
    drop(w);
    drop(r);
    let mut inner = controller.join().unwrap();
    inner.drain(..200.min(inner.len()));
    (
        percentiles("bridge round trip (Unix socket, same work)", &mut rtt),
        percentiles("bridge controller (state read → cmd written)", &mut inner),
    )
}

fn main() {
    let samples: usize = std::env::args().skip(1).find_map(|a| a.parse().ok()).unwrap_or(3000);
    println!("LowState → LowCmd over loopback, {samples} samples each, one every ~0.5 ms");
    let (d_rtt, d_in) = dds(samples);
    let (b_rtt, b_in) = bridge(samples);
    println!(
        "ratio DDS / bridge, round trip: p50 {:.1}×  p99 {:.1}×  max {:.1}×;  controller side: p50 {:.1}×",
        d_rtt[0] / b_rtt[0],
        d_rtt[1] / b_rtt[1],
        d_rtt[2] / b_rtt[2],
        d_in[0] / b_in[0]
    );
}
