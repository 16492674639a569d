//! CAN motor command, reply and IMU frames, and the bus layout TOML (`sensor_io::can::fuzz_can` holds the invariants).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    sensor_io::can::fuzz_can(data);
});
