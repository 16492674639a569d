//! ONNX models into the policy importer, and its output into the firmware's executor (`policy_import::onnx::fuzz_onnx` holds the invariants).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    policy_import::onnx::fuzz_onnx(data);
});
