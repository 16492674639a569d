//! Fixed allocation: after start-up, 12,000 control ticks through the full loop — HAL decode,
//! supervisor, policy, command, and the logger's copy into its pool — allocate and free nothing on
//! the control thread (counted per thread by a wrapping global allocator). The run includes ramp,
//! hold, policy, an operator e-stop (damping) and a reset back through start-up.
// Test inputs come from std's math on the host; this never runs on the robot.
#![allow(clippy::disallowed_methods)]
use control::alloc_probe::{counts, CountingAlloc};
use std::path::Path;

use control::controller::{Controller, Mode};
use control::operator::{CommandSchedule, OperatorSource};
use control::perception_worker::PerceptionExec;
use control::runtime::{run_loop, FrameSource, LoopEnd, Runtime};
use control::spec::DeploySpec;
use hal::{LowCommand, LowLevel, LowState, TickTime, TimeBase};
use runlog::log::{LogOptions, Logger, RunMeta};
use sensor_io::unitree_hg::{decode_low_state, encode_low_state, DecodeError, LOW_STATE_LEN};

#[global_allocator]
static GLOBAL: CountingAlloc = CountingAlloc;

/// A HAL that synthesises valid, changing LowState frames and decodes them like a real one.
struct SyntheticHal {
    k: u64,
    started: bool,
    frame: [u8; LOW_STATE_LEN],
    state: LowState,
    scratch: LowState,
    fresh: bool,
}

impl SyntheticHal {
    fn new() -> Self {
        Self {
            k: 0,
            started: false,
            frame: [0; LOW_STATE_LEN],
            state: LowState::default(),
            scratch: LowState::default(),
            fresh: false,
        }
    }
    fn synthesise(&mut self) {
        let k = self.k as f32;
        let mut s = LowState {
            tick: self.k as u32,
            ..Default::default()
        };
        s.imu.quaternion = [1.0, 0.0, 0.0, 0.0];
        s.imu.gyroscope = [(k * 0.05).sin() * 0.1, 0.0, 0.0];
        for (i, m) in s.motors.iter_mut().enumerate() {
            m.q = (k * 0.01 + i as f32).sin() * 0.2;
            m.dq = (k * 0.02 + i as f32).cos() * 0.5;
            m.tau_est = (k * 0.03 + i as f32).sin();
            m.temperature = [40, 45];
        }
        encode_low_state(&s, &mut self.frame);
    }
}

impl TimeBase for SyntheticHal {
    type Error = DecodeError;
    fn wait_tick(&mut self) -> Result<TickTime, DecodeError> {
        if self.started {
            self.k += 1;
        }
        self.started = true;
        self.synthesise();
        self.fresh = true;
        Ok(TickTime {
            index: self.k,
            time_ns: self.k * 2_000_000,
        })
    }
    fn period_ns(&self) -> u64 {
        2_000_000
    }
}

impl LowLevel for SyntheticHal {
    type Error = DecodeError;
    fn read_state(&mut self, out: &mut LowState) -> Result<bool, DecodeError> {
        let fresh = std::mem::take(&mut self.fresh);
        if fresh {
            decode_low_state(&self.frame, &mut self.scratch)?;
            self.state = self.scratch;
        }
        *out = self.state;
        Ok(fresh)
    }
    fn write_command(&mut self, _cmd: &LowCommand) -> Result<(), DecodeError> {
        Ok(())
    }
}

impl FrameSource for SyntheticHal {
    fn received_frame(&self) -> Option<&[u8]> {
        Some(&self.frame)
    }
}

fn run_ticks(spec_path: &Path) {
    run_ticks_on(spec_path, &mut SyntheticHal::new(), PerceptionExec::Inline);
}

/// What perception did over the counted ticks.
#[derive(Debug, Default)]
struct PerceptionSeen {
    /// Fresh-frame results (consumed or late).
    results: u64,
    late: u64,
}

fn run_ticks_on<H: TimeBase + LowLevel + FrameSource>(
    spec_path: &Path,
    hal: &mut H,
    exec: PerceptionExec,
) -> PerceptionSeen {
    let spec = DeploySpec::load(spec_path).expect("spec loads");
    let (obs, act) = (spec.observation_dim(), spec.num_joints());
    // One directory per test: the tests run in parallel, and each removes its directory at the end
    // (a shared one was removed under the other test's open log: a flaky NotFound).
    let test = std::thread::current().name().unwrap_or("main").replace("::", "-");
    let dir = std::env::temp_dir().join(format!("g1fw-noalloc-{}-{test}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let log_path = dir.join(format!("{}.mcap", spec.meta.name));
    let mut rt = Runtime::new(Controller::new(spec).expect("controller builds"));
    rt.set_perception_exec(exec).expect("perception thread");
    let mut seen = PerceptionSeen::default();
    let mut logger = Logger::create(&log_path, &RunMeta::default(), obs, act, LogOptions::default()).unwrap();
    let schedule =
        CommandSchedule::parse("0 0.5 0 0.2\n10 0.3 0 0\n21 estop\n22 reset\n", Path::new("inline")).unwrap();
    let mut operator = schedule.source(2_000_000);
    let n = 12_000u64;
    // Start-up (first tick, lazily initialised statics) is allowed to allocate: warm up one
    // operator query and one encode outside the counted window.
    let _ = operator.at(TickTime::default());
    let mut operator = schedule.source(2_000_000);

    let (mut policy_ticks, mut damping_ticks, mut reset_seen, mut pushed) = (0u64, 0u64, false, 0u64);
    let before = counts();
    let end = run_loop(hal, &mut rt, &mut operator, n, |v| {
        policy_ticks += v.summary.policy_step as u64;
        damping_ticks += matches!(v.summary.mode, Mode::Damping(_)) as u64;
        reset_seen |= v.summary.reset;
        if let Some(p) = v.summary.perception.filter(|p| p.fresh) {
            seen.results += 1;
            seen.late += p.late as u64;
        }
        pushed += logger.push(v) as u64;
        true
    });
    let after = counts();
    assert!(matches!(end, LoopEnd::Completed { ticks } if ticks == n), "{end:?}");
    assert!(policy_ticks > 1000, "policy ran {policy_ticks} times");
    assert!(damping_ticks >= 400, "damping for {damping_ticks} ticks");
    assert!(reset_seen, "the operator reset left damping");
    assert_eq!(rt.mode(), Mode::Policy, "back under policy control after the reset");
    assert_eq!(pushed, n + 1, "every tick was logged");
    assert_eq!(
        after, before,
        "allocations/deallocations on the control thread during {n} ticks: {before:?} -> {after:?}"
    );
    let stats = logger.finish().unwrap();
    assert_eq!(stats.records, n + 1);
    assert_eq!(stats.dropped_records, 0);
    let _ = std::fs::remove_dir_all(&dir);
    seen
}

#[test]
fn rl_lab_style_tick_path_does_not_allocate() {
    run_ticks(&Path::new(env!("CARGO_MANIFEST_DIR")).join("../specs/test/rl_lab_style.toml"));
}

#[test]
fn peer_lstm_tick_path_does_not_allocate() {
    let spec = Path::new(env!("CARGO_MANIFEST_DIR")).join("../specs/peer/unitree_g1_lstm.toml");
    let weights =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/peer_policy/unitree_g1_lstm/policy.safetensors");
    if !weights.is_file() {
        let msg = "SKIP: peer_lstm_tick_path_does_not_allocate needs ../shared (the peer policy weights)";
        assert!(std::env::var_os("CI").is_none(), "{msg} — and CI must have it");
        eprintln!("\n!!!!!!!! {msg} !!!!!!!!\n");
        return;
    }
    run_ticks(&spec);
}

/// The motors and IMU on an in-thread bus with a fixed ring buffer: the emulator's logic answers
/// every command set at once from a first-order plant, so `CanHal` is measured, not the transport.
struct LoopbackMotors {
    emu: sim_hal::can::MotorEmulator,
    plant: LowState,
    ring: [(usize, sensor_io::can::CanFrame); 256],
    head: usize,
    len: usize,
}

impl LoopbackMotors {
    fn push(
        ring: &mut [(usize, sensor_io::can::CanFrame); 256],
        head: usize,
        len: &mut usize,
        item: (usize, sensor_io::can::CanFrame),
    ) {
        assert!(*len < ring.len(), "loopback ring full");
        ring[(head + *len) % 256] = item;
        *len += 1;
    }
}

impl sim_hal::can::CanBuses for LoopbackMotors {
    fn count(&self) -> usize {
        2
    }
    fn send(&mut self, bus: usize, frame: &sensor_io::can::CanFrame) -> Result<bool, sim_hal::can::BusError> {
        let (ring, head, len) = (&mut self.ring, self.head, &mut self.len);
        let ev = self
            .emu
            .on_frame(bus, frame, &self.plant, &mut |b, f| Self::push(ring, head, len, (b, f)));
        if ev == sim_hal::can::EmuEvent::Step {
            let cmd = self.emu.low_command();
            for (m, c) in self.plant.motors.iter_mut().zip(cmd.motors.iter()) {
                let dq = 0.2 * (c.q - m.q) / 0.002;
                m.q += 0.2 * (c.q - m.q);
                m.dq = dq.clamp(-30.0, 30.0);
                m.tau_est = c.kp * (c.q - m.q) - c.kd * m.dq;
            }
            self.plant.imu.accelerometer = [0.0, 0.0, 9.81];
            let (ring, head, len) = (&mut self.ring, self.head, &mut self.len);
            self.emu
                .publish(&self.plant, &mut |b, f| Self::push(ring, head, len, (b, f)));
        }
        Ok(true)
    }
    fn recv(
        &mut self,
        _timeout: std::time::Duration,
    ) -> Result<Option<(usize, sensor_io::can::CanFrame)>, sim_hal::can::BusError> {
        if self.len == 0 {
            return Ok(None);
        }
        let item = self.ring[self.head];
        self.head = (self.head + 1) % 256;
        self.len -= 1;
        Ok(Some(item))
    }
}

/// The CAN HAL's tick path (frame classification, IMU assembly, silence bookkeeping, state
/// encoding for the log, command encoding) allocates nothing either.
#[test]
fn can_hal_tick_path_does_not_allocate() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let spec = DeploySpec::load(&root.join("specs/test/rl_lab_style.toml")).expect("spec loads");
    let layout = sensor_io::can::BusLayout::load(&root.join("specs/can/g1_12dof.toml")).expect("layout");
    let (obs, act) = (spec.observation_dim(), spec.num_joints());
    let dir = std::env::temp_dir().join(format!("g1fw-noalloc-can-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut logger = Logger::create(
        &dir.join("can.mcap"),
        &RunMeta::default(),
        obs,
        act,
        LogOptions::default(),
    )
    .unwrap();
    let bus = LoopbackMotors {
        emu: sim_hal::can::MotorEmulator::new(layout.clone()),
        plant: LowState::default(),
        ring: [(0, sensor_io::can::CanFrame::default()); 256],
        head: 0,
        len: 0,
    };
    let mut hal = robot_io::can::CanHal::open(bus, layout, 2_000_000, std::time::Duration::from_secs(1)).unwrap();
    let mut rt = Runtime::new(Controller::new(spec).expect("controller builds"));
    rt.disable_frozen_check();
    let schedule = CommandSchedule::constant([0.3, 0.0, 0.0]);
    let _ = schedule.source(2_000_000).at(TickTime::default());
    let mut operator = schedule.source(2_000_000);
    let n = 5_000u64;
    let mut policy_ticks = 0u64;
    let before = counts();
    let end = run_loop(&mut hal, &mut rt, &mut operator, n, |v| {
        policy_ticks += v.summary.policy_step as u64;
        logger.push(v);
        true
    });
    let after = counts();
    assert!(matches!(end, LoopEnd::Completed { ticks } if ticks == n), "{end:?}");
    assert!(policy_ticks > 400, "policy ran {policy_ticks} times");
    let c = hal.counters();
    assert_eq!((c.malformed, c.foreign, c.missing_replies), (0, 0, 0), "{c:?}");
    assert_eq!(
        after, before,
        "allocations/deallocations on the control thread during {n} CAN ticks: {before:?} -> {after:?}"
    );
    logger.finish().unwrap();
    let _ = std::fs::remove_dir_all(&dir);
}

/// The probe itself can fail the tests above: an allocation on this thread is counted.
/// The MID-360 over UDP beside the state HAL (`g1fw run --lidar-udp`): every tick drains the socket
/// into the assembler and stages completed frames, without allocating, while another thread
/// streams Livox packets at the lidar's rate.
#[test]
fn udp_lidar_tick_path_does_not_allocate() {
    udp_lidar_ticks(PerceptionExec::Inline);
}

/// The same with perception on its worker thread, as `g1fw run` does it: hand-over and collection
/// allocate nothing. The synthetic HAL ticks far faster than 500 Hz, so most results come back
/// late: the late path (token held, perception coming home later, ticks skipped meanwhile) is
/// covered too.
#[test]
fn threaded_perception_tick_path_does_not_allocate() {
    let seen = udp_lidar_ticks(PerceptionExec::Threaded {
        consume_after: 10,
        wait: false,
    });
    assert!(seen.results >= 3, "perception results came back: {seen:?}");
}

fn udp_lidar_ticks(exec: PerceptionExec) -> PerceptionSeen {
    use control::lidar_source::WithLidar;
    use robot_io::{UdpLidar, UdpLidarConfig};
    use std::sync::atomic::{AtomicBool, Ordering};
    let lidar = UdpLidar::<{ hal::LIDAR_FRAME_CAP }>::open(UdpLidarConfig {
        bind: "127.0.0.1:0".parse().unwrap(),
        lidar: None,
        ..UdpLidarConfig::default()
    })
    .unwrap();
    let to = lidar.local_addr();
    let stop = std::sync::Arc::new(AtomicBool::new(false));
    let sender = {
        let stop = stop.clone();
        std::thread::spawn(move || {
            let tx = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
            tx.connect(to).unwrap();
            let mut writer = sensor_io::livox::PacketWriter::new();
            let mut buf = vec![0u8; writer.max_packet_len()];
            let points: Vec<hal::LidarPoint> = (0..2000)
                .map(|i| hal::LidarPoint {
                    xyz: [1.0 + (i % 50) as f32 * 0.1, (i / 50) as f32 * 0.05 - 1.0, -0.5],
                    reflectivity: 10,
                    tag: 0,
                    offset_ns: 0,
                })
                .collect();
            let mut t = 0u64;
            while !stop.load(Ordering::Relaxed) {
                writer
                    .write_frame(&points, t, &mut buf, |d| {
                        let _ = tx.send(d);
                        std::thread::sleep(std::time::Duration::from_micros(200));
                    })
                    .unwrap();
                t += 100_000_000;
            }
        })
    };
    let mut hal = WithLidar::new(SyntheticHal::new(), Some(lidar));
    let seen = run_ticks_on(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("../specs/test/rl_lab_style.toml"),
        &mut hal,
        exec,
    );
    stop.store(true, Ordering::Relaxed);
    sender.join().unwrap();
    let c = hal.lidar.as_ref().unwrap().counters();
    assert!(
        c.datagrams > 50 && c.frames > 2,
        "the lidar stream reached the tick path: {c:?}"
    );
    assert_eq!(c.malformed, 0);
    seen
}

#[test]
fn the_probe_counts_this_threads_allocations() {
    let before = counts();
    let v = std::hint::black_box(vec![1u8; 64]);
    drop(v);
    let after = counts();
    assert_eq!((after.0 - before.0, after.1 - before.1), (1, 1));
}

/// The DDS HAL's tick path (`g1fw run --dds`): waiting on the transport thread's inbox, CDR →
/// C layout → decode, command encode → CDR → outbox, with threaded perception, allocates nothing
/// on the control thread. A robot on another thread of this process (rustdds on `lo`, a domain of
/// its own) answers every command with the next synthetic state, lock-stepped like `g1-sim --dds`.
#[test]
fn dds_hal_tick_path_does_not_allocate() {
    use robot_io::dds::{DdsLink, Endpoint, ROBOT, SAMPLE_CAP};
    use robot_io::{DdsHal, DdsHalConfig};
    use sensor_io::unitree_hg::cdr::{low_state_to_cdr, LOW_STATE_CDR_LEN};
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::sync::Arc;
    // Parallel test runs must not hear each other: a domain per process.
    let endpoint = Endpoint {
        interface: "lo".into(),
        domain: 100 + (std::process::id() % 100) as u16,
    };
    let stop = Arc::new(AtomicBool::new(false));
    let robot = {
        let (stop, endpoint) = (stop.clone(), endpoint.clone());
        std::thread::spawn(move || {
            let link = DdsLink::open(&endpoint, ROBOT, std::time::Duration::from_millis(200), false).unwrap();
            let mut synth = SyntheticHal::new();
            let mut cdr = [0u8; LOW_STATE_CDR_LEN];
            let mut raw = vec![0u8; SAMPLE_CAP];
            let mut seen = 0;
            let _ = synth.wait_tick();
            while !stop.load(Ordering::Relaxed) {
                low_state_to_cdr(&synth.frame, &mut cdr);
                link.send(&cdr).unwrap();
                if let Some((seq, _)) = link
                    .wait_newer(seen, std::time::Duration::from_millis(20), &mut raw)
                    .unwrap()
                {
                    seen = seq;
                    let _ = synth.wait_tick();
                }
            }
        })
    };
    let mut cfg = DdsHalConfig::new(endpoint, 2_000_000);
    cfg.discovery = std::time::Duration::from_millis(500);
    cfg.tick_timeout = std::time::Duration::from_millis(100);
    // The robot above answers commands (lock-step): tick on its states, not on the clock, or a
    // loaded machine turns late answers into stale states and a state timeout.
    cfg.pace = robot_io::dds::Pace::State;
    let mut hal = DdsHal::open(cfg).expect("DDS HAL");
    let seen = run_ticks_on(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("../specs/test/rl_lab_style.toml"),
        &mut hal,
        PerceptionExec::Threaded {
            consume_after: 10,
            wait: false,
        },
    );
    stop.store(true, Ordering::Relaxed);
    robot.join().unwrap();
    let c = hal.counters();
    assert!(
        c.link.samples_in >= 12_000 && c.link.samples_out + c.link.coalesced >= 12_000,
        "{c:?}"
    );
    assert_eq!(c.rejected, 0, "{c:?}");
    // No lidar here: perception ran its no-frame steps only.
    assert_eq!(seen.results, 0);
}
