//! Helpers shared by the control core's integration tests.
#![allow(dead_code)]
use hal::{LowState, TickTime};

/// A healthy, upright, slowly changing state for tick `k`.
pub fn healthy(k: u64) -> LowState {
    let mut s = LowState {
        tick: k as u32,
        ..Default::default()
    };
    s.imu.quaternion = [1.0, 0.0, 0.0, 0.0];
    for (i, m) in s.motors.iter_mut().enumerate() {
        let x = k as f32 * 0.01 + i as f32;
        (m.q, m.dq, m.tau_est) = (x.sin() * 0.1, x.cos() * 0.2, x.sin());
        m.temperature = [40, 45];
    }
    s
}

/// Tick `k` of a 500 Hz loop.
pub fn tick(k: u64) -> TickTime {
    TickTime {
        index: k,
        time_ns: k * 2_000_000,
    }
}
