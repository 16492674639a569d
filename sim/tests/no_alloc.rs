//! The per-tick path allocates nothing: command in, physics, state and truth out, framed.
mod common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use hal::LowState;
use sensor_io::unitree_hg::{encode_low_state, LOW_STATE_LEN};
use sim_hal::bridge::{write_msg, Kind};

/// Counts allocations made by the current thread while armed.
struct Counting;
thread_local! {
    static ARMED: Cell<bool> = const { Cell::new(false) };
    static COUNT: Cell<u64> = const { Cell::new(0) };
}
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        if ARMED.with(|a| a.get()) {
            COUNT.with(|c| c.set(c.get() + 1));
        }
        // SAFETY: forwards the caller's contract unchanged to the system allocator.
        unsafe { System.alloc(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        // SAFETY: `p` was allocated by `System` with layout `l` (see `alloc`).
        unsafe { System.dealloc(p, l) }
    }
}
#[global_allocator]
static A: Counting = Counting;

#[test]
fn control_tick_path_does_not_allocate() {
    let mut sim = common::load29();
    let cmd = sim.hold_initial_pose_command();
    let (mut st, mut bytes) = (LowState::default(), [0u8; LOW_STATE_LEN]);
    let (mut wire, mut scratch) = (Vec::with_capacity(1 << 16), Vec::with_capacity(4096));
    let mut tick = |sim: &mut g1_sim::Simulator, wire: &mut Vec<u8>| {
        sim.apply_command(&cmd).unwrap();
        sim.step_control_tick();
        sim.low_state(&mut st);
        encode_low_state(&st, &mut bytes);
        wire.clear();
        write_msg(wire, Kind::LowState, &bytes, &mut scratch).unwrap();
        write_msg(
            wire,
            Kind::Truth,
            &sim_hal::bridge::encode_truth(&sim.truth()),
            &mut scratch,
        )
        .unwrap();
    };
    tick(&mut sim, &mut wire); // warm-up: buffers reach their size
    ARMED.with(|a| a.set(true));
    for _ in 0..200 {
        tick(&mut sim, &mut wire);
    }
    ARMED.with(|a| a.set(false));
    assert_eq!(COUNT.with(|c| c.get()), 0, "allocations on the per-tick path");
}

#[test]
fn fault_injector_does_not_allocate_per_tick() {
    use g1_sim::faults::{FaultInjector, FaultPlan};
    let mut sim = common::load29();
    let cmd = sim.hold_initial_pose_command();
    sim.apply_command(&cmd).unwrap();
    let plan = FaultPlan::parse([
        "drop@0.01+0.01",
        "delay@0.02+0.02:5",
        "corrupt@0.05+0.01",
        "imu-nan@0.07+0.01",
        "freeze-joint@0.02+0.1:3",
        "motor-dead@0.04:20",
        "overheat@0:1",
    ])
    .unwrap();
    let mut inj = FaultInjector::new(&plan, 0.002, sim.motor_slots_present())
        .unwrap()
        .unwrap();
    let (mut st, mut bytes) = (LowState::default(), [0u8; LOW_STATE_LEN]);
    ARMED.with(|a| a.set(true));
    for k in 0..200 {
        sim.low_state(&mut st);
        inj.apply(k, &mut sim, &mut st, &mut bytes);
        sim.step_control_tick();
    }
    ARMED.with(|a| a.set(false));
    assert_eq!(COUNT.with(|c| c.get()), 0, "allocations while injecting faults");
}

#[test]
fn bridge_client_does_not_allocate_per_tick_even_with_faults() {
    use g1_sim::faults::FaultPlan;
    use g1_sim::server::{serve_unix, ServeOptions};
    use hal::{LowLevel, TimeBase};
    use sim_hal::bridge::BridgeHal;
    use std::time::Duration;
    let mut sim = common::load29();
    let cmd = sim.hold_initial_pose_command();
    let opts = ServeOptions {
        faults: FaultPlan::parse(["drop@0.02+0.02", "corrupt@0.06+0.02", "delay@0.1+0.02:3"]).unwrap(),
        ..ServeOptions::default()
    };
    let path = std::env::temp_dir().join(format!("g1-sim-noalloc-{}.sock", std::process::id()));
    let p2 = path.clone();
    // The server thread's allocations are not counted (the counter is per thread).
    let server = std::thread::spawn(move || serve_unix(&p2, &mut sim, &opts, || {}));
    let mut hal = BridgeHal::connect_unix(&path, true, Duration::from_secs(20), || Ok(())).unwrap();
    let mut st = LowState::default();
    let mut tick = |hal: &mut BridgeHal| {
        hal.wait_tick().unwrap();
        let _ = hal.read_state(&mut st);
        hal.write_command(&cmd).unwrap();
    };
    tick(&mut hal); // warm-up: buffers reach their size
    ARMED.with(|a| a.set(true));
    for _ in 0..100 {
        tick(&mut hal);
    }
    ARMED.with(|a| a.set(false));
    assert_eq!(COUNT.with(|c| c.get()), 0, "allocations on the client's per-tick path");
    hal.wait_tick().unwrap();
    hal.close();
    server.join().unwrap().unwrap();
}
