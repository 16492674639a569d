//! g1-train runs MuJoCo in process (PPO environments, eval-terrain's worlds): its binaries get the
//! rpath to the MuJoCo library that `g1_sim`'s build script found and hands on.
fn main() {
    println!("cargo:rerun-if-env-changed=DEP_G1_SIM_MUJOCO_LIB_DIR");
    let dir = std::env::var("DEP_G1_SIM_MUJOCO_LIB_DIR")
        .expect("g1_sim's build script sets DEP_G1_SIM_MUJOCO_LIB_DIR (links = \"g1_sim_mujoco\")");
    println!("cargo:rustc-link-arg=-Wl,-rpath,{dir}");
}
