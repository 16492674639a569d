//! Helpers shared by the trainer's integration tests.
#![allow(dead_code)]

/// Whether the 12-dof model in `../shared` is there; outside CI a missing one skips loudly, in CI
/// it fails (CI always has it).
pub fn have_12dof_model() -> bool {
    if g1_sim::ModelChoice::G1_12Dof.path().exists() {
        return true;
    }
    assert!(
        std::env::var_os("CI").is_none(),
        "the 12-dof model in ../shared is missing, and CI must have it"
    );
    eprintln!("*** SKIPPED: the 12-dof model in ../shared is missing (CI has it) ***");
    false
}
