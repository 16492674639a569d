//! The HIL's first VM: User-Mode Linux (Debian package `user-mode-linux`). The kernel runs as an
//! ordinary process, its root is the host `/` read-only through hostfs, and its init is
//! `scripts/hil/guest_init.sh`, which loads the CAN modules shipped with the UML kernel.
use anyhow::{bail, Result};
use std::fs;
use std::path::Path;
use std::process::Command;

pub const BINARY: &str = "/usr/bin/linux";
const MODULES: &str = "/usr/lib/uml/modules";

/// UML and its vcan module are installed, or what to do about it.
pub fn preflight() -> Result<()> {
    if !Path::new(BINARY).is_file() {
        bail!(
            "User-Mode Linux is not installed ({BINARY} not found): run scripts/install.sh, or `sudo apt-get install user-mode-linux`"
        );
    }
    let vcan = fs::read_dir(MODULES)
        .ok()
        .into_iter()
        .flatten()
        .flatten()
        .any(|e| e.path().join("kernel/drivers/net/can/vcan.ko").is_file());
    if !vcan {
        bail!(
            "no vcan module for the UML kernel under {MODULES}/<version>/kernel/drivers/net/can/: \
             reinstall user-mode-linux (`sudo apt-get install --reinstall user-mode-linux`)"
        );
    }
    Ok(())
}

/// The UML command. `params` are the `key=value` words every guest gets (unknown ones reach init as
/// environment variables). With `fail_at_boot`, init is `/bin/false`: it exits at once and the kernel
/// panics ("Attempted to kill init!"), as UML does on a CPU it cannot run on.
pub fn command(mem: &str, init: &Path, run_dir: &Path, params: &[String], fail_at_boot: bool) -> Command {
    let umid = format!("g1hil-{}", std::process::id());
    let mut cmd = Command::new(BINARY);
    cmd.arg(format!("mem={mem}"))
        .args(["root=/dev/root", "rootfstype=hostfs", "rootflags=/", "ro"])
        .arg(if fail_at_boot {
            "init=/bin/false".to_string()
        } else {
            format!("init={}", init.display())
        })
        .args(params)
        .arg(format!("umid={umid}"))
        .arg(format!("uml_dir={}", run_dir.display()))
        .args(["con=null", "con0=fd:0,fd:1", "quiet"]);
    cmd
}
