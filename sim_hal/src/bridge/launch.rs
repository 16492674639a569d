//! Starting `g1-sim` as a child process and connecting to it over the bridge: the one launcher
//! that `g1fw sim`, `g1-can-emu` and the tests share. The simulator is always another process, so
//! nothing that uses this links MuJoCo.
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use super::client::{BridgeError, BridgeHal, Wants};

#[derive(Debug, thiserror::Error)]
pub enum LaunchError {
    #[error(
        "cannot find the simulator binary g1-sim next to {exe}; build it with \
         `cargo build --release -p g1_sim` or pass --sim-bin PATH (or set G1_SIM_BIN)"
    )]
    NotFound { exe: String },
    #[error("locating this executable: {0}")]
    CurrentExe(std::io::Error),
    #[error("starting the simulator {bin}")]
    Spawn { bin: String, source: std::io::Error },
    #[error(transparent)]
    Bridge(#[from] BridgeError),
}

/// Locates the `g1-sim` binary: `explicit`, `$G1_SIM_BIN`, or beside this executable (also one
/// level up, for test binaries in `target/*/deps`).
pub fn find_sim_bin(explicit: Option<&Path>) -> Result<PathBuf, LaunchError> {
    if let Some(p) = explicit {
        return Ok(p.to_path_buf());
    }
    if let Some(p) = std::env::var_os("G1_SIM_BIN") {
        return Ok(PathBuf::from(p));
    }
    let exe = std::env::current_exe().map_err(LaunchError::CurrentExe)?;
    let dir = exe.parent().unwrap_or(Path::new("."));
    for d in [Some(dir), dir.parent()].into_iter().flatten() {
        let c = d.join("g1-sim");
        if c.is_file() {
            return Ok(c);
        }
    }
    Err(LaunchError::NotFound {
        exe: exe.display().to_string(),
    })
}

/// `g1-sim`'s command line.
#[derive(Clone, Debug, PartialEq)]
pub struct SimLaunch {
    /// The binary (`None`: [`find_sim_bin`]).
    pub bin: Option<PathBuf>,
    /// `g1-29dof`, `g1-12dof` or an MJCF path.
    pub model: String,
    pub seed: u64,
    pub physics_dt: f64,
    pub control_dt: f64,
    /// `--fault` specs.
    pub faults: Vec<String>,
    /// `--imu-noise`.
    pub imu_noise: Option<String>,
    /// `--world` (a preset, scenario file or random:SEED); also turns the lidar on.
    pub world: Option<String>,
    /// `--integrator` (`implicitfast`, the default, or `euler`: the explicit motor law of
    /// Unitree's reference loop).
    pub integrator: Option<String>,
    /// `--physics` (`deploy`, the default: the model's contacts and solver; or `training`: the
    /// trainer's lean profile, to measure the gap between the two through the firmware).
    pub physics: Option<String>,
}

impl SimLaunch {
    /// `model` at `control_dt`, everything else at g1-sim's defaults.
    pub fn new(model: &str, control_dt: f64) -> Self {
        Self {
            bin: None,
            model: model.to_string(),
            seed: 0,
            physics_dt: 0.002,
            control_dt,
            faults: Vec::new(),
            imu_noise: None,
            world: None,
            integrator: None,
            physics: None,
        }
    }

    /// Starts the simulator on a fresh socket in the temp directory (named after `tag`) and
    /// connects to it within `timeout`; fails early, with its exit status, if it dies first.
    pub fn start(&self, tag: &str, wants: Wants, timeout: Duration) -> Result<(SimProcess, BridgeHal), LaunchError> {
        static N: AtomicU64 = AtomicU64::new(0);
        let bin = find_sim_bin(self.bin.as_deref())?;
        let socket = std::env::temp_dir().join(format!(
            "{tag}-{}-{}.sock",
            std::process::id(),
            N.fetch_add(1, Ordering::Relaxed)
        ));
        let _ = std::fs::remove_file(&socket);
        let mut cmd = Command::new(&bin);
        let parent = nix::unistd::getpid();
        // SAFETY: the closure runs in the child between fork and exec and only calls prctl(2) and
        // getppid(2), which are async-signal-safe; it allocates nothing and touches no lock.
        unsafe {
            cmd.pre_exec(move || {
                // If g1fw dies before it connects (kill -9), the simulator would wait in accept()
                // forever; this ends it with its parent.
                nix::sys::prctl::set_pdeathsig(nix::sys::signal::Signal::SIGTERM)?;
                // The parent may have died before the line above: then no signal will come.
                if nix::unistd::getppid() != parent {
                    return Err(std::io::Error::from(std::io::ErrorKind::BrokenPipe));
                }
                Ok(())
            });
        }
        let child = cmd
            .arg("--socket")
            .arg(&socket)
            .args(["--model", &self.model])
            .args(["--seed", &self.seed.to_string()])
            .args(["--physics-dt", &self.physics_dt.to_string()])
            .args(["--control-dt", &self.control_dt.to_string()])
            .args(self.faults.iter().flat_map(|f| ["--fault", f.as_str()]))
            .args(self.imu_noise.iter().flat_map(|n| ["--imu-noise", n.as_str()]))
            .args(self.world.iter().flat_map(|w| ["--world", w.as_str(), "--lidar"]))
            .args(self.integrator.iter().flat_map(|i| ["--integrator", i.as_str()]))
            .args(self.physics.iter().flat_map(|p| ["--physics", p.as_str()]))
            .arg("--quiet")
            .stdin(Stdio::null())
            // Its own process group: a terminal's Ctrl-C reaches g1fw only, which stops the run,
            // closes its log and then stops the simulator (instead of losing it mid-tick).
            .process_group(0)
            .spawn()
            .map_err(|source| LaunchError::Spawn {
                bin: bin.display().to_string(),
                source,
            })?;
        let mut sim = SimProcess { child, socket };
        let socket = sim.socket.clone();
        let hal = BridgeHal::connect_unix(&socket, wants, timeout, || sim.alive())?;
        Ok((sim, hal))
    }
}

/// A running simulator; dropping it gives it a moment to exit after the bridge's goodbye, then
/// kills it and removes its socket.
pub struct SimProcess {
    child: Child,
    socket: PathBuf,
}

impl SimProcess {
    /// `Err` with the exit status once the process has exited.
    pub fn alive(&mut self) -> Result<(), String> {
        match self.child.try_wait() {
            Ok(Some(status)) => Err(exit_in_words(status)),
            Ok(None) => Ok(()),
            Err(e) => Err(format!("cannot poll the simulator process: {e}")),
        }
    }
}

/// Why the simulator is gone, without pointing at a message it may never have printed: a signal
/// kills it silently, a failing g1-sim prints its own error on the shared stderr first.
fn exit_in_words(status: std::process::ExitStatus) -> String {
    use std::os::unix::process::ExitStatusExt;
    match (status.code(), status.signal()) {
        (_, Some(sig)) => {
            let name =
                nix::sys::signal::Signal::try_from(sig).map_or_else(|_| format!("signal {sig}"), |s| s.to_string());
            format!("the simulator (g1-sim) was killed by {name}: it printed nothing; was it stopped by hand, or out of memory?")
        }
        (Some(0), _) => {
            "the simulator (g1-sim) exited early with status 0 (it does only when told to stop)".to_string()
        }
        (Some(code), _) => format!(
            "the simulator (g1-sim) failed with exit code {code}: its error is the line printed before this one"
        ),
        (None, None) => format!("the simulator (g1-sim) ended ({status})"),
    }
}

impl Drop for SimProcess {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            for _ in 0..100 {
                if let Ok(Some(_)) = self.child.try_wait() {
                    break;
                }
                std::thread::sleep(Duration::from_millis(5));
            }
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
        let _ = std::fs::remove_file(&self.socket);
    }
}

#[cfg(test)]
mod exit_words {
    use std::os::unix::process::ExitStatusExt;

    #[test]
    fn a_killed_simulator_is_not_said_to_have_printed_anything() {
        let killed = super::exit_in_words(std::process::ExitStatus::from_raw(9));
        assert!(
            killed.contains("killed by SIGKILL") && !killed.contains("above"),
            "{killed}"
        );
        let failed = super::exit_in_words(std::process::ExitStatus::from_raw(2 << 8));
        assert!(failed.contains("exit code 2"), "{failed}");
    }
}
