//! Fixed allocation: after start-up, 10,000+ control ticks including policy steps, ramp, hold and
//! the damping path allocate and free nothing (counted per thread by a wrapping global allocator).
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::path::Path;

use firmware::controller::{Controller, DampingReason, Mode};
use firmware::spec::DeploySpec;
use hal::{LowCommand, LowState, TickTime};

thread_local! {
    static COUNT: Cell<(usize, usize)> = const { Cell::new((0, 0)) };
}

/// Counts allocations and deallocations per thread (parallel tests do not interfere).
struct Counting;

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        COUNT.with(|c| c.set((c.get().0 + 1, c.get().1)));
        // SAFETY: forwarded unchanged to the system allocator.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        COUNT.with(|c| c.set((c.get().0, c.get().1 + 1)));
        // SAFETY: forwarded unchanged to the system allocator.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        COUNT.with(|c| c.set((c.get().0 + 1, c.get().1 + 1)));
        // SAFETY: forwarded unchanged to the system allocator.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn run_ticks(spec_path: &Path) {
    let spec = DeploySpec::load(spec_path).expect("spec loads");
    let mut c = Controller::new(spec).expect("controller builds");
    let mut state = LowState::default();
    let mut cmd = LowCommand::default();
    let before = COUNT.with(|c| c.get());
    let n = 12_000u64;
    for k in 0..n {
        // Deterministic, varying joint readings so the policy sees changing inputs.
        for (i, m) in state.motors.iter_mut().enumerate() {
            m.q = ((k as f32 * 0.01 + i as f32).sin()) * 0.2;
            m.dq = ((k as f32 * 0.02 + i as f32).cos()) * 0.5;
        }
        if k == n - 1000 {
            c.enter_damping(DampingReason::Requested);
        }
        c.tick(
            &state,
            TickTime {
                index: k,
                time_ns: k * 2_000_000,
            },
            [0.5, 0.0, 0.2],
            &mut cmd,
        );
    }
    let after = COUNT.with(|c| c.get());
    assert!(c.policy_steps() > 1000, "policy ran {} times", c.policy_steps());
    assert!(matches!(c.mode(), Mode::Damping(_)));
    assert_eq!(
        after, before,
        "allocations/deallocations during {n} ticks: {:?} -> {:?}",
        before, after
    );
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
