//! The command envelope, the last check before the motors, on any LowCmd (`control::envelope::fuzz_command_envelope` holds the invariants).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    control::envelope::fuzz_command_envelope(data);
});
