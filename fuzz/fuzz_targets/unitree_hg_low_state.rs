//! unitree_hg `LowState_`: the C-layout decoder, behind a fresh CRC, and the DDS CDR path (`sensor_io::unitree_hg::fuzz_low_state` holds the invariants).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    sensor_io::unitree_hg::fuzz_low_state(data);
});
