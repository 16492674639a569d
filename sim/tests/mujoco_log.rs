//! MuJoCo writes its warnings to `MUJOCO_LOG.TXT` in the working directory by default; our
//! binaries turn that off (issue 22: no command writes into the working directory unless asked).
//! One test in its own process: it changes the working directory.
use mujoco_rs::wrappers::mj_logging::log_warning;

#[test]
fn mujoco_warnings_leave_no_log_file_in_the_working_directory() {
    let dir = std::env::temp_dir().join(format!("g1-mujoco-log-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::env::set_current_dir(&dir).unwrap();
    // MuJoCo's default: the file appears (so this test can fail).
    log_warning("g1 test: default handler");
    assert!(
        dir.join("MUJOCO_LOG.TXT").exists(),
        "MuJoCo's default no longer writes the file"
    );
    std::fs::remove_file(dir.join("MUJOCO_LOG.TXT")).unwrap();
    g1_sim::no_mujoco_log_file();
    log_warning("g1 test: after no_mujoco_log_file");
    assert!(!dir.join("MUJOCO_LOG.TXT").exists());
    std::fs::remove_dir_all(&dir).unwrap();
}
