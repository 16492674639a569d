//! Deploy spec TOML (validation and what check-spec builds) and a safetensors weight file (`control::controller::fuzz_deploy_spec` holds the invariants).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    control::controller::fuzz_deploy_spec(data);
});
