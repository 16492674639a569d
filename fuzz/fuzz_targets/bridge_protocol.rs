//! The simulator bridge's byte stream: framing and every payload decoder (`sim_hal::bridge::protocol::fuzz_bridge` holds the invariants).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    sim_hal::bridge::protocol::fuzz_bridge(data);
});
