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
        write_msg(wire, Kind::Truth, &sim.truth().encode(), &mut scratch).unwrap();
    };
    tick(&mut sim, &mut wire); // warm-up: buffers reach their size
    ARMED.with(|a| a.set(true));
    for _ in 0..200 {
        tick(&mut sim, &mut wire);
    }
    ARMED.with(|a| a.set(false));
    assert_eq!(COUNT.with(|c| c.get()), 0, "allocations on the per-tick path");
}
