//! Bakes an rpath to the MuJoCo library into every binary of this crate (the `g1-sim` server, its
//! tests and benches), so they run without `LD_LIBRARY_PATH`. The directory comes from
//! `MUJOCO_DYNAMIC_LINK_DIR`, which the workspace's `.cargo/config.toml` points at `.deps/mujoco/lib`;
//! it is also handed to dependents' build scripts (`train`) as `DEP_G1_SIM_MUJOCO_LIB_DIR`.
use std::path::Path;

fn fail(msg: &str) -> ! {
    eprintln!(
        "error: {msg}\n       Run `scripts/install.sh` from the repository root to install MuJoCo 3.17.0 into .deps/."
    );
    std::process::exit(1);
}

fn main() {
    println!("cargo:rerun-if-env-changed=MUJOCO_DYNAMIC_LINK_DIR");
    println!("cargo:rerun-if-changed=build.rs");
    let dir = match std::env::var("MUJOCO_DYNAMIC_LINK_DIR") {
        Ok(d) if !d.is_empty() => d,
        _ => fail("MUJOCO_DYNAMIC_LINK_DIR is not set (the workspace .cargo/config.toml sets it to .deps/mujoco/lib)."),
    };
    let lib = Path::new(&dir).join("libmujoco.so");
    if !lib.exists() {
        fail(&format!("MuJoCo library not found at {}.", lib.display()));
    }
    println!("cargo:rerun-if-changed={}", lib.display());
    let dir = Path::new(&dir)
        .canonicalize()
        .unwrap_or_else(|e| fail(&format!("cannot resolve {dir}: {e}")));
    println!("cargo:rustc-link-arg=-Wl,-rpath,{}", dir.display());
    // For dependents' build scripts (`links = "g1_sim_mujoco"`): DEP_G1_SIM_MUJOCO_LIB_DIR.
    println!("cargo:lib_dir={}", dir.display());
}
