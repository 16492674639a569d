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

/// Panics with instructions when `scripts/install.sh` has not been run (the 29-dof model it
/// installs into .deps/ is missing).
pub fn require_deps() {
    if let Err(what) = g1_sim::model::check_installed() {
        panic!("{what}");
    }
}

/// Flat ground only, no randomization, forward commands of 0.4-0.8 m/s: the short training runs
/// of the smoke and judge tests.
pub fn flat_settings(episode_s: f64) -> train::ppo::env::EnvSettings {
    use train::ppo::env::{Column, EnvSettings, Randomization};
    EnvSettings {
        episode_s,
        random: Randomization::NONE,
        max_init_level: 0,
        vx: (0.4, 0.8),
        only: Some(Column::Flat),
        ..EnvSettings::DEFAULT
    }
}
