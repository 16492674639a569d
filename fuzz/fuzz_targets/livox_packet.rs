//! Arbitrary bytes into the Livox point-packet decoder and frame assembler (`sensor_io::livox::fuzz_livox` holds the invariants).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    sensor_io::livox::fuzz_livox(data);
});
