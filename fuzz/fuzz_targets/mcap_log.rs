//! MCAP run logs read the way `g1fw replay` reads them (`runlog::log::reader::fuzz_log` holds the
//! invariants).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    runlog::log::reader::fuzz_log(data);
});
