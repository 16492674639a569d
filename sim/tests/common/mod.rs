//! Shared test helpers: the installed dependencies are required, never silently skipped.
#![allow(dead_code)]
use g1_sim::model::shared_dir;
use g1_sim::{ModelChoice, SimConfig, Simulator};

/// Panics with instructions when `scripts/install.sh` has not been run.
pub fn require_deps() {
    if let Err(what) = g1_sim::model::check_installed() {
        panic!("{what}");
    }
}

/// `true` when the 12-dof model is available; prints a loud SKIP when `../shared` is absent.
/// A present `shared` directory without the model is a failure, not a skip.
pub fn have_12dof(test: &str) -> bool {
    let dir = shared_dir();
    if !dir.exists() {
        // CI must run every test; a skip there would hide a broken checkout.
        assert!(
            std::env::var_os("CI").is_none(),
            "{test}: {} is absent and $CI is set; the 12-dof model is required there",
            dir.display()
        );
        // Through the stderr handle, not eprintln!: libtest captures the macros, and a skip must
        // be visible in a normal `cargo test` run.
        use std::io::Write;
        let _ = writeln!(
            std::io::stderr(),
            "\n*** SKIP {test}: {} is absent, so the 12-dof G1 model cannot be tested \
             (set G1_SHARED_DIR to run it). ***\n",
            dir.display()
        );
        return false;
    }
    let xml = ModelChoice::G1_12Dof.path();
    assert!(
        xml.exists(),
        "{} exists but has no 12-dof model at {}",
        dir.display(),
        xml.display()
    );
    true
}

pub fn load(choice: ModelChoice) -> Simulator {
    Simulator::load(choice, SimConfig::default()).expect("model loads")
}

pub fn load29() -> Simulator {
    require_deps();
    load(ModelChoice::G1_29Dof)
}
