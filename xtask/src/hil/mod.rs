//! `cargo xtask hil`: the CAN hardware-in-loop suite, inside a VM.
//!
//! The host kernel of the development and CI machines has no CAN (`CONFIG_CAN` unset), so the suite
//! runs in a guest with vcan. Two VMs can host it, and by default the first that boots is used:
//! 1. **User-Mode Linux** (`uml.rs`; `/usr/bin/linux`, Debian package `user-mode-linux`): the kernel is
//!    an ordinary process, its root is the host `/` read-only through hostfs. Boots in 2–5 s, but not
//!    on every CPU (an AMX Xeon's extended register state kills it at once).
//! 2. **QEMU, software emulation** (`qemu.rs`): Debian's kernel with a small initramfs that mounts the
//!    host `/` read-only over virtio-9p. Boots anywhere, in about 10 s, and runs the suite slower.
//!
//! Either way the guest's init is `scripts/hil/guest_init.sh`: it brings up `vcan0`..`vcan3`, runs the
//! suite and powers the guest off. The host and the guest talk through one host directory,
//! `<target>/hil/run-<pid>/`, mounted read-write in the guest at the same path (`env.sh` in,
//! `suite.log`, `status` and whatever the suite writes out), and through marker lines on the guest
//! console (the VM's stdout; see the init script). A VM that never brings vcan up has failed to boot;
//! that is told apart from a suite that fails.
use anyhow::{anyhow, bail, Context, Result};
use serde_json::json;
use std::fmt::Write as _;
use std::fs;
use std::io::{BufRead, BufReader, Write as _};
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::atomic::{AtomicI32, Ordering};
use std::sync::mpsc::{self, RecvTimeoutError};
use std::time::{Duration, Instant};

mod cpio;
mod qemu;
mod uml;

const LONG_HELP: &str = "\
What it does:
  1. checks the tools the guest runs from the host's /: insmod (kmod), ip (iproute2), can-utils, and
     python-can in .venv (scripts/install.sh installs all);
  2. builds the host binaries the suite runs (g1fw, g1-sim, g1-can-emu) with cargo build --release
     --workspace --bins, unless --no-build (the whole workspace, so features resolve as in
     scripts/test.sh's build and nothing is compiled twice);
  3. boots a VM (--vm, or HIL_VM; default auto):
       uml   User-Mode Linux (/usr/bin/linux, its CAN modules under /usr/lib/uml/modules): root = the
             host / read-only through hostfs, init = scripts/hil/guest_init.sh;
       qemu  QEMU software emulation (.deps/hil-qemu, unpacked by scripts/install.sh): Debian's kernel,
             an initramfs (busybox, virtio/9p/CAN modules, scripts/hil/qemu_initramfs_init.sh) that
             mounts the host / read-only over virtio-9p and runs the same guest_init.sh;
       auto  UML, and QEMU if UML is missing or fails to boot (\"UML failed to boot: ...; using QEMU\").
     A VM has booted once its guest reports vcan up; one that does not within its boot timeout (UML
     60 s, QEMU 240 s) or that ends first has failed to boot. In the guest: proc/sys and tmpfs on /run
     (TMPDIR=/run/tmp; the host's /tmp stays visible), CAN modules loaded, vcan0-vcan3 created, socket
     receive buffers raised (net.core.rmem_max/rmem_default), then the suite runs as root with the
     repository root as its working directory;
  4. streams the suite's output, and prints which VM ran, the boot time (spawn -> vcan up, host clock,
     and the guest's uptime at that point), the suite's wall time and the total.

The suite is scripts/hil/suite.sh: a smoke test of the plumbing (candump/cansend on both buses, a
python-can round trip) followed by tests/hil/peer_test.py, the independent python-can implementation
of docs/can.md that drives g1fw and g1-can-emu on vcan0/vcan1. `--suite FILE` runs another bash script,
`cargo xtask hil -- CMD ARGS...` any command (e.g. `cargo xtask hil -- ip -details link`).

The guest sees no host environment except what is written to <run dir>/env.sh: PATH (with .venv/bin
and the release binaries first), HIL_DIR (the writable run directory), HIL_REPO, HIL_BIN_DIR, HIL_VM
(the VM that runs), and the host's CI, RUST_LOG, RUST_BACKTRACE and every other HIL_* variable (e.g.
HIL_WALK_S=20 for the peer test).

Output lands in <target>/hil/run-<pid>/ (target/hil/last points at the newest): console-<vm>.log (the
whole guest console of each VM tried), stderr-<vm>.log, suite.log, status, summary.json (which VM ran,
every VM tried and why it failed to boot, timings) and what the suite writes there.

Exit status: the suite's when it ran. 125 if no VM booted (each one tried and why is printed), 126 if
the VM booted but ended without reporting the suite's status, 124 if the watchdog (--timeout-min)
killed the VM, 130 on Ctrl-C.";

#[derive(clap::Args)]
#[command(after_long_help = LONG_HELP)]
pub struct Args {
    /// Watchdog: kill the VM after this many minutes (exit status 124).
    #[arg(long, value_name = "MINUTES", default_value_t = 20.0)]
    timeout_min: f64,
    /// Run this bash script in the guest instead of scripts/hil/suite.sh (path relative to the
    /// repository root, or absolute).
    #[arg(long, value_name = "FILE", conflicts_with = "cmd")]
    suite: Option<PathBuf>,
    /// Guest memory (UML `mem=`, QEMU `-m`); the suite runs MuJoCo, the firmware and python-can at once.
    #[arg(long, value_name = "SIZE", default_value = "1024M")]
    mem: String,
    /// Which VM hosts the suite: uml, qemu, or auto (UML, then QEMU if UML cannot boot).
    #[arg(long, value_enum, env = "HIL_VM", default_value = "auto")]
    vm: VmChoice,
    /// Make UML fail at boot as it does on an AMX Xeon (its init exits at once, the kernel panics),
    /// to show the fallback to QEMU on a host where UML boots.
    #[arg(long, env = "HIL_SIMULATE_UML_BOOT_FAILURE", value_parser = clap::builder::BoolishValueParser::new(), default_value = "false")]
    simulate_uml_boot_failure: bool,
    /// Do not build the host binaries first (use what is in target/release).
    #[arg(long)]
    no_build: bool,
    /// Print the whole guest console (kernel messages, the init script), not only the suite's output.
    #[arg(long, short)]
    verbose: bool,
    /// A command to run in the guest instead of the suite (after `--`).
    #[arg(last = true, value_name = "CMD")]
    cmd: Vec<String>,
}

#[derive(Clone, Copy, PartialEq, Eq, Debug, clap::ValueEnum)]
enum VmChoice {
    Auto,
    Uml,
    Qemu,
}

/// A VM that can host the suite.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Vm {
    Uml,
    Qemu,
}

impl Vm {
    fn name(self) -> &'static str {
        match self {
            Vm::Uml => "UML",
            Vm::Qemu => "QEMU",
        }
    }
    fn key(self) -> &'static str {
        match self {
            Vm::Uml => "uml",
            Vm::Qemu => "qemu",
        }
    }
    /// How long the guest may take to report vcan up before the boot counts as failed.
    fn boot_timeout(self) -> Duration {
        match self {
            Vm::Uml => Duration::from_secs(60),
            Vm::Qemu => Duration::from_secs(240),
        }
    }
}

impl VmChoice {
    /// The VMs to try, in order.
    fn plan(self) -> &'static [Vm] {
        match self {
            VmChoice::Auto => &[Vm::Uml, Vm::Qemu],
            VmChoice::Uml => &[Vm::Uml],
            VmChoice::Qemu => &[Vm::Qemu],
        }
    }
}

/// One VM tried and why it did not host the suite.
struct Failed {
    vm: Vm,
    reason: String,
}

/// Set by SIGINT/SIGTERM/SIGHUP: the VM runs in its own process group, so the terminal's Ctrl-C does
/// not reach it; the main loop kills the group instead.
static SIGNAL: AtomicI32 = AtomicI32::new(0);

extern "C" fn on_signal(sig: libc::c_int) {
    SIGNAL.store(sig, Ordering::SeqCst);
}

pub fn run(args: Args) -> Result<()> {
    let t_all = Instant::now();
    let repo = Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .context("xtask lives in a subdirectory of the repository")?
        .to_path_buf();
    let target = match std::env::var_os("CARGO_TARGET_DIR") {
        Some(t) => {
            let t = PathBuf::from(t);
            if t.is_absolute() {
                t
            } else {
                repo.join(t)
            }
        }
        None => repo.join("target"),
    };
    let bin_dir = target.join("release");

    preflight(&repo)?;
    if !args.no_build {
        build(&repo)?;
    }
    let suite = suite_command(&repo, &args)?;

    let run_dir = prepare_run_dir(&target)?;
    for p in [&repo, &run_dir, &bin_dir] {
        kernel_cmdline_safe(p)?;
    }
    let init = repo.join("scripts/hil/guest_init.sh");
    if !init.is_file() {
        bail!(
            "{} is missing: the HIL guest cannot boot without its init script",
            init.display()
        );
    }
    let timeout = Duration::from_secs_f64(args.timeout_min * 60.0);
    eprintln!("[hil] guest runs: {}", suite.join(" "));
    if args.simulate_uml_boot_failure {
        eprintln!("[hil] HIL_SIMULATE_UML_BOOT_FAILURE: UML will boot with init=/bin/false and fail");
    }

    let plan = args.vm.plan();
    let mut failed: Vec<Failed> = Vec::new();
    let mut ran: Option<(Vm, Outcome)> = None;
    for (i, &vm) in plan.iter().enumerate() {
        let next = plan
            .get(i + 1)
            .map(|v| format!("; using {}", v.name()))
            .unwrap_or_default();
        let launch = match prepare_vm(vm, &args, &repo, &run_dir, &init) {
            Ok(l) => l,
            Err(e) => {
                eprintln!("[hil] {} is not available: {e:#}{next}", vm.name());
                failed.push(Failed {
                    vm,
                    reason: format!("not available: {e:#}"),
                });
                continue;
            }
        };
        fs::write(run_dir.join("env.sh"), guest_env(&repo, &run_dir, &bin_dir, &suite, vm))
            .with_context(|| format!("writing {}/env.sh", run_dir.display()))?;
        for stale in ["status", "error", "vcan_up_uptime"] {
            let _ = fs::remove_file(run_dir.join(stale));
        }
        eprintln!(
            "[hil] booting {} (mem={}, boot timeout {:.0} s, watchdog {:.0} min), run dir {}",
            vm.name(),
            args.mem,
            vm.boot_timeout().as_secs_f64(),
            args.timeout_min,
            run_dir.display()
        );
        let o = boot(vm, launch, &args, &run_dir, timeout)?;
        if let Some(why) = o.boot_failure() {
            eprintln!("[hil] {} failed to boot: {why}{next}", vm.name());
            if next.is_empty() || args.verbose {
                print_console_tail(vm, &run_dir, &o);
            }
            failed.push(Failed { vm, reason: why });
            continue;
        }
        ran = Some((vm, o));
        break;
    }
    report(&run_dir, ran, &failed, t_all.elapsed(), args.verbose)
}

/// The command that boots `vm`, after checking what it needs.
fn prepare_vm(vm: Vm, args: &Args, repo: &Path, run_dir: &Path, init: &Path) -> Result<Command> {
    let params = vec![
        format!("hil_vm={}", vm.key()),
        format!("hil_dir={}", run_dir.display()),
        format!("hil_repo={}", repo.display()),
    ];
    match vm {
        Vm::Uml => {
            uml::preflight()?;
            Ok(uml::command(
                &args.mem,
                init,
                run_dir,
                &params,
                args.simulate_uml_boot_failure,
            ))
        }
        Vm::Qemu => {
            let q = qemu::Qemu::find(repo)?;
            let initrd = run_dir.join("initramfs.cpio");
            let stage = repo.join("scripts/hil/qemu_initramfs_init.sh");
            fs::write(&initrd, q.initramfs(&stage)?).with_context(|| format!("writing {}", initrd.display()))?;
            // quiet: only warnings from the kernel on the console; panic=-1: a guest panic reboots,
            // and -no-reboot turns that into QEMU's exit.
            let append = format!(
                "console=ttyS0 quiet panic=-1 hil_init={} {}",
                init.display(),
                params.join(" ")
            );
            Ok(q.command(&args.mem, &initrd, run_dir, &append))
        }
    }
}

/// Everything the guest needs is on the host `/` (the guest's root): check it here, where the error
/// can say what to install, rather than in a guest that can only fail.
fn preflight(repo: &Path) -> Result<()> {
    let install = "run scripts/install.sh";
    for (tool, pkg) in [
        ("insmod", "kmod"),
        ("ip", "iproute2"),
        ("candump", "can-utils"),
        ("cansend", "can-utils"),
        ("cangen", "can-utils"),
        ("cangw", "can-utils"),
        ("bash", "bash"),
    ] {
        let found = ["/usr/sbin", "/usr/bin", "/sbin", "/bin"]
            .iter()
            .any(|d| Path::new(d).join(tool).is_file());
        if !found {
            bail!("`{tool}` not found (the HIL guest needs it): {install}, or `sudo apt-get install {pkg}`");
        }
    }
    let py = repo.join(".venv/bin/python");
    if !py.is_file() {
        bail!(
            "{} not found: {install} (it creates .venv with python-can)",
            py.display()
        );
    }
    let ok = Command::new(&py)
        .args(["-c", "import can"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .with_context(|| format!("running {}", py.display()))?
        .success();
    if !ok {
        bail!(
            "python-can is not installed in .venv: {install}, or `.venv/bin/pip install -r scripts/requirements.txt`"
        );
    }
    Ok(())
}

fn build(repo: &Path) -> Result<()> {
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    // The whole workspace: a `-p` subset resolves dependency features differently and rebuilds
    // them (68 s on a fresh clone after test.sh's workspace build).
    let pkgs = ["--workspace"];
    eprintln!("[hil] cargo build --release {} --bins", pkgs.join(" "));
    let t = Instant::now();
    let st = Command::new(cargo)
        .current_dir(repo)
        .args(["build", "--release"])
        .args(pkgs)
        .arg("--bins")
        .status()
        .context("running cargo build")?;
    if !st.success() {
        bail!("cargo build of the HIL binaries failed ({st}); fix the build, or pass --no-build to use what is built");
    }
    eprintln!("[hil] build: {:.1} s", t.elapsed().as_secs_f64());
    Ok(())
}

/// The guest's command line, as argv.
fn suite_command(repo: &Path, args: &Args) -> Result<Vec<String>> {
    if !args.cmd.is_empty() {
        return Ok(args.cmd.clone());
    }
    let script = args
        .suite
        .clone()
        .unwrap_or_else(|| PathBuf::from("scripts/hil/suite.sh"));
    let abs = if script.is_absolute() {
        script.clone()
    } else {
        repo.join(&script)
    };
    if !abs.is_file() {
        bail!("suite script {} not found", abs.display());
    }
    Ok(vec!["bash".into(), abs.to_string_lossy().into_owned()])
}

/// `<target>/hil/run-<pid>/`, fresh; run directories of processes that are gone are removed, and
/// `<target>/hil/last` points at this one.
fn prepare_run_dir(target: &Path) -> Result<PathBuf> {
    let hil = target.join("hil");
    fs::create_dir_all(&hil).with_context(|| format!("creating {}", hil.display()))?;
    for e in fs::read_dir(&hil)?.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        if let Some(pid) = name.strip_prefix("run-") {
            if !Path::new("/proc").join(pid).exists() {
                let _ = fs::remove_dir_all(e.path());
            }
        }
    }
    let dir = hil.join(format!("run-{}", std::process::id()));
    let _ = fs::remove_dir_all(&dir);
    fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let last = hil.join("last");
    let _ = fs::remove_file(&last);
    let _ = std::os::unix::fs::symlink(dir.file_name().expect("run dir has a name"), &last);
    Ok(dir)
}

/// The kernel command line is split at spaces and has no quoting the init script could rely on.
fn kernel_cmdline_safe(p: &Path) -> Result<()> {
    let s = p.to_str().with_context(|| format!("{} is not UTF-8", p.display()))?;
    if s.chars()
        .any(|c| c.is_whitespace() || c == '"' || c == '\'' || c.is_control())
    {
        bail!(
            "{s}: the HIL VM passes this path on the kernel command line, which cannot carry spaces or quotes; \
             move the checkout (or CARGO_TARGET_DIR) to a path without them"
        );
    }
    Ok(())
}

fn sh_quote(s: &str) -> String {
    format!("'{}'", s.replace('\'', r"'\''"))
}

/// `env.sh`, sourced by the guest's init before it runs `"${HIL_SUITE[@]}"`.
fn guest_env(repo: &Path, run_dir: &Path, bin_dir: &Path, suite: &[String], vm: Vm) -> String {
    let mut vars: Vec<(String, String)> = vec![
        (
            "PATH".into(),
            format!(
                "{}:{}:/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin",
                repo.join(".venv/bin").display(),
                bin_dir.display()
            ),
        ),
        // The guest's writable scratch (guest_init.sh): its /tmp is the host's, read-only.
        ("HOME".into(), "/run/tmp".into()),
        ("TMPDIR".into(), "/run/tmp".into()),
        ("LANG".into(), "C.UTF-8".into()),
        ("TERM".into(), "dumb".into()),
        ("PYTHONUNBUFFERED".into(), "1".into()),
        ("PYTHONDONTWRITEBYTECODE".into(), "1".into()),
        ("HIL_DIR".into(), run_dir.display().to_string()),
        ("HIL_REPO".into(), repo.display().to_string()),
        ("HIL_BIN_DIR".into(), bin_dir.display().to_string()),
        ("HIL_VM".into(), vm.key().into()),
    ];
    let ours: Vec<String> = vars.iter().map(|(k, _)| k.clone()).collect();
    let mut passed: Vec<(String, String)> = std::env::vars()
        .filter(|(k, _)| {
            (matches!(k.as_str(), "CI" | "RUST_LOG" | "RUST_BACKTRACE") || k.starts_with("HIL_")) && !ours.contains(k)
        })
        .filter(|(k, _)| k.chars().all(|c| c.is_ascii_alphanumeric() || c == '_'))
        .collect();
    passed.sort();
    vars.extend(passed);
    let mut s = String::from("# written by `cargo xtask hil`; sourced by scripts/hil/guest_init.sh in the guest\n");
    for (k, v) in &vars {
        let _ = writeln!(s, "export {k}={}", sh_quote(v));
    }
    let argv: Vec<String> = suite.iter().map(|a| sh_quote(a)).collect();
    let _ = writeln!(s, "HIL_SUITE=({})", argv.join(" "));
    s
}

/// What the host saw of one guest.
#[derive(Default)]
struct Outcome {
    exit: Option<ExitStatus>,
    watchdog: bool,
    /// Killed because vcan was not up within the VM's boot timeout.
    boot_timeout: bool,
    signal: i32,
    vcan_up_host: Option<Duration>,
    vcan_up_guest: Option<f64>,
    suite_start: Option<Duration>,
    suite_end: Option<Duration>,
    /// (status, guest wall seconds) from the `HIL:SUITE_EXIT` console line.
    console_exit: Option<(i32, f64)>,
    guest_error: Option<String>,
    /// The first console lines before vcan came up that say why the kernel or init died
    /// (`Kernel panic`, `failed`, ...), at most four.
    fatal_lines: Vec<String>,
    console_tail: Vec<String>,
    total: Duration,
}

impl Outcome {
    /// Why the VM did not boot, or `None` if it booted (vcan came up), or it was stopped by a signal
    /// or the watchdog (not the VM's fault).
    fn boot_failure(&self) -> Option<String> {
        if self.vcan_up_host.is_some() || self.signal != 0 || self.watchdog {
            return None;
        }
        let mut why = if self.boot_timeout {
            "vcan was not up within the boot timeout".to_string()
        } else if let Some(e) = &self.guest_error {
            format!("its init failed: {e}")
        } else {
            "it ended before vcan came up".to_string()
        };
        if !self.fatal_lines.is_empty() {
            let quoted: Vec<String> = self.fatal_lines.iter().map(|l| format!("\"{}\"", l.trim())).collect();
            let _ = write!(why, " (console: {})", quoted.join(", "));
        }
        if let Some(st) = self.exit.filter(|_| !self.boot_timeout) {
            let _ = write!(why, "; the VM exited with {st}");
        }
        Some(why)
    }
}

/// A console line that names why a boot died. UML prints two harmless "failed" lines on every boot
/// (no iomem region, no ubd disk file): they are not it.
fn is_fatal_line(l: &str) -> bool {
    let l = l.to_ascii_lowercase();
    let benign = ["mmapper_init - find_iomem failed", "failed to initialize ubd device"];
    !benign.iter().any(|b| l.contains(b))
        && ["kernel panic", "failed", "error", "not syncing", "unable to"]
            .iter()
            .any(|k| l.contains(k))
}

/// Keeps the first few fatal lines seen before vcan came up.
fn note_fatal(o: &mut Outcome, line: &str) {
    if o.vcan_up_host.is_none() && o.fatal_lines.len() < 4 && is_fatal_line(line) {
        o.fatal_lines.push(line.to_string());
    }
}

enum Event {
    Line(String),
    Eof,
}

fn boot(vm: Vm, mut cmd: Command, args: &Args, run_dir: &Path, timeout: Duration) -> Result<Outcome> {
    let console_path = run_dir.join(format!("console-{}.log", vm.key()));
    let mut console =
        fs::File::create(&console_path).with_context(|| format!("creating {}", console_path.display()))?;
    let stderr = fs::File::create(run_dir.join(format!("stderr-{}.log", vm.key())))?;
    cmd.current_dir(run_dir)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::from(stderr))
        // The VM may fork helper processes (UML does); its own group lets the watchdog kill them all.
        .process_group(0);
    // SAFETY: plain syscall; makes the VM's helpers our children if its main process is killed.
    unsafe {
        libc::prctl(libc::PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0);
    }
    let t0 = Instant::now();
    let mut child = cmd
        .spawn()
        .with_context(|| format!("starting {}", cmd.get_program().to_string_lossy()))?;
    install_signal_handlers();

    let stdout = child.stdout.take().expect("stdout is piped");
    let (tx, rx) = mpsc::channel();
    let reader = std::thread::spawn(move || {
        let mut r = BufReader::new(stdout);
        let mut buf = Vec::new();
        loop {
            buf.clear();
            match r.read_until(b'\n', &mut buf) {
                Ok(0) | Err(_) => break,
                Ok(_) => {
                    let line = String::from_utf8_lossy(&buf).trim_end_matches(['\n', '\r']).to_string();
                    if tx.send(Event::Line(line)).is_err() {
                        break;
                    }
                }
            }
        }
        let _ = tx.send(Event::Eof);
    });

    let mut o = Outcome::default();
    let mut in_suite = false;
    let mut tail: std::collections::VecDeque<String> = Default::default();
    let mut eof = false;
    let mut exited_at: Option<Instant> = None;
    let stdout = std::io::stdout();
    loop {
        match rx.recv_timeout(Duration::from_millis(100)) {
            Ok(Event::Line(line)) => {
                let _ = writeln!(console, "{line}");
                if tail.len() == 40 {
                    tail.pop_front();
                }
                tail.push_back(line.clone());
                let now = t0.elapsed();
                note_fatal(&mut o, &line);
                if let Some(rest) = line.strip_prefix("HIL:VCAN_UP ") {
                    o.vcan_up_host = Some(now);
                    o.vcan_up_guest = rest.trim().parse().ok();
                    eprintln!(
                        "[hil] {}: vcan0..vcan3 up {:.2} s after spawn (guest uptime {})",
                        vm.name(),
                        now.as_secs_f64(),
                        rest.trim()
                    );
                } else if line == "HIL:SUITE_START" {
                    o.suite_start = Some(now);
                    in_suite = true;
                } else if let Some(rest) = line.strip_prefix("HIL:SUITE_EXIT ") {
                    o.suite_end = Some(now);
                    in_suite = false;
                    let mut it = rest.split_whitespace();
                    let st = it.next().and_then(|s| s.parse().ok());
                    let wall = it.next().and_then(|s| s.parse().ok()).unwrap_or(f64::NAN);
                    o.console_exit = st.map(|s| (s, wall));
                } else if let Some(rest) = line.strip_prefix("HIL:ERROR ") {
                    o.guest_error = Some(rest.to_string());
                    eprintln!("[hil] {}: guest set-up failed: {rest}", vm.name());
                } else if in_suite || args.verbose {
                    let mut out = stdout.lock();
                    let _ = writeln!(out, "{line}");
                    let _ = out.flush();
                }
            }
            Ok(Event::Eof) | Err(RecvTimeoutError::Disconnected) => eof = true,
            Err(RecvTimeoutError::Timeout) => {}
        }
        if o.exit.is_none() {
            if let Some(st) = child.try_wait()? {
                o.exit = Some(st);
                exited_at = Some(Instant::now());
            }
        }
        if let Some(at) = exited_at {
            if eof || at.elapsed() > Duration::from_secs(3) {
                break;
            }
            if at.elapsed() > Duration::from_secs(1) {
                // Helpers that inherited the console pipe keep it open; they die with the group.
                kill_group(&child);
            }
            continue;
        }
        let sig = SIGNAL.load(Ordering::SeqCst);
        if sig != 0 {
            eprintln!("[hil] signal {sig}: killing the VM");
            o.signal = sig;
            kill_group(&child);
            o.exit = Some(child.wait()?);
            break;
        }
        if o.vcan_up_host.is_none() && t0.elapsed() > vm.boot_timeout() {
            eprintln!(
                "[hil] {}: vcan not up after {:.0} s; killing the VM",
                vm.name(),
                t0.elapsed().as_secs_f64()
            );
            o.boot_timeout = true;
            kill_group(&child);
            o.exit = Some(child.wait()?);
            break;
        }
        if t0.elapsed() > timeout {
            eprintln!(
                "[hil] watchdog: the VM ran for {:.0} s (--timeout-min {}); killing it",
                t0.elapsed().as_secs_f64(),
                args.timeout_min
            );
            o.watchdog = true;
            kill_group(&child);
            o.exit = Some(child.wait()?);
            break;
        }
    }
    drop(rx);
    let _ = reader.join();
    reap_orphans();
    o.total = t0.elapsed();
    o.console_tail = tail.into_iter().collect();
    Ok(o)
}

fn install_signal_handlers() {
    for sig in [libc::SIGINT, libc::SIGTERM, libc::SIGHUP] {
        // SAFETY: the handler only stores into an atomic, which is async-signal-safe.
        unsafe {
            libc::signal(sig, on_signal as *const () as libc::sighandler_t);
        }
    }
}

fn kill_group(child: &Child) {
    let pgid = child.id() as libc::pid_t;
    // SAFETY: plain syscall; the group is the VM's own (process_group(0) at spawn).
    unsafe {
        libc::kill(-pgid, libc::SIGKILL);
    }
}

/// Reaps the VM's helper processes, which were reparented to us (`PR_SET_CHILD_SUBREAPER`) when the
/// VM's main process died; cargo's build has finished by then, so every child left is the VM's.
fn reap_orphans() {
    for _ in 0..20 {
        // SAFETY: plain syscall with a null status pointer.
        let r = unsafe { libc::waitpid(-1, std::ptr::null_mut(), libc::WNOHANG) };
        match r {
            -1 => return, // no children left
            0 => std::thread::sleep(Duration::from_millis(50)),
            _ => {}
        }
    }
}

fn print_console_tail(vm: Vm, run_dir: &Path, o: &Outcome) {
    eprintln!("[hil] last console lines of {}:", vm.name());
    for l in &o.console_tail {
        eprintln!("[hil] | {l}");
    }
    if let Ok(e) = fs::read_to_string(run_dir.join(format!("stderr-{}.log", vm.key()))) {
        for l in e.lines().rev().take(20).collect::<Vec<_>>().into_iter().rev() {
            eprintln!("[hil] stderr | {l}");
        }
    }
}

/// Exit statuses other than the suite's own.
const EXIT_NO_VM_BOOTED: i32 = 125;
const EXIT_GUEST_DIED: i32 = 126;

fn report(run_dir: &Path, ran: Option<(Vm, Outcome)>, failed: &[Failed], total: Duration, verbose: bool) -> Result<()> {
    let tried: Vec<serde_json::Value> = failed
        .iter()
        .map(|f| json!({"vm": f.vm.key(), "booted": false, "reason": f.reason}))
        .collect();
    let Some((vm, o)) = ran else {
        let summary = json!({"vm": null, "tried": tried, "status": null, "total_s": total.as_secs_f64()});
        let _ = fs::write(run_dir.join("summary.json"), format!("{summary:#}\n"));
        let list: Vec<String> = failed
            .iter()
            .map(|f| format!("{} ({})", f.vm.name(), f.reason))
            .collect();
        eprintln!(
            "[hil] FAILED: no VM booted, so the suite did not run. Tried: {}. Logs in {}",
            list.join("; "),
            run_dir.display()
        );
        std::process::exit(EXIT_NO_VM_BOOTED);
    };
    // The status file is the guest's own record; the console line is the fallback.
    let from_file = fs::read_to_string(run_dir.join("status")).ok().and_then(|s| {
        let mut it = s.split_whitespace();
        let st: i32 = it.next()?.parse().ok()?;
        let wall: f64 = it.next().and_then(|w| w.parse().ok()).unwrap_or(f64::NAN);
        Some((st, wall))
    });
    let status = from_file.or(o.console_exit);
    let guest_error = o.guest_error.clone().or_else(|| {
        fs::read_to_string(run_dir.join("error"))
            .ok()
            .map(|s| s.trim().to_string())
    });

    let suite_host = match (o.suite_start, o.suite_end) {
        (Some(a), Some(b)) => Some(b.saturating_sub(a).as_secs_f64()),
        _ => None,
    };
    let mut tried = tried;
    tried.push(json!({"vm": vm.key(), "booted": o.vcan_up_host.is_some()}));
    let summary = json!({
        "vm": vm.key(),
        "tried": tried,
        "vcan_up_host_s": o.vcan_up_host.map(|d| d.as_secs_f64()),
        "vcan_up_guest_uptime_s": o.vcan_up_guest,
        "suite_host_s": suite_host,
        "suite_guest_s": status.map(|s| s.1).filter(|w| w.is_finite()),
        "vm_s": o.total.as_secs_f64(),
        "total_s": total.as_secs_f64(),
        "status": status.map(|s| s.0),
        "watchdog": o.watchdog,
    });
    let _ = fs::write(run_dir.join("summary.json"), format!("{summary:#}\n"));

    eprintln!("[hil] ---------------------------------------------------------------");
    let fell_back = failed
        .iter()
        .map(|f| format!(" (after {} failed to boot)", f.vm.name()))
        .collect::<String>();
    eprintln!("[hil] vm:    {}{fell_back}", vm.name());
    match (o.vcan_up_host, o.vcan_up_guest) {
        (Some(h), g) => eprintln!(
            "[hil] boot:  {:.2} s spawn -> vcan up (guest uptime {})",
            h.as_secs_f64(),
            g.map_or("?".into(), |g| format!("{g:.2} s"))
        ),
        (None, _) => eprintln!("[hil] boot:  vcan never came up"),
    }
    if let Some(s) = suite_host {
        let g = status.map(|s| s.1).filter(|w| w.is_finite());
        eprintln!(
            "[hil] suite: {s:.1} s (guest clock {})",
            g.map_or("?".into(), |g| format!("{g:.1} s"))
        );
    }
    eprintln!(
        "[hil] total: {:.1} s (VM {:.1} s); logs in {}",
        total.as_secs_f64(),
        o.total.as_secs_f64(),
        run_dir.display()
    );

    let reason = if o.signal != 0 {
        Some((130, format!("interrupted by signal {}", o.signal)))
    } else if o.watchdog {
        Some((
            124,
            "the watchdog killed the VM (raise --timeout-min if the suite is just slow)".to_string(),
        ))
    } else if status.is_none() {
        let mut why = format!(
            "{} booted (vcan up), but the guest ended without reporting the suite's status: ",
            vm.name()
        );
        if let Some(e) = &guest_error {
            let _ = write!(why, "its init failed: {e}");
        } else {
            why.push_str("it died while the suite ran (see the console below)");
        }
        if let Some(st) = o.exit {
            let _ = write!(why, "; the VM exited with {st}");
        }
        Some((EXIT_GUEST_DIED, why))
    } else {
        None
    };
    if let Some((code, why)) = reason {
        if !verbose {
            print_console_tail(vm, run_dir, &o);
        }
        eprintln!("[hil] FAILED: {why}");
        std::process::exit(code);
    }
    let (st, _) = status.ok_or_else(|| anyhow!("unreachable: no status"))?;
    if st == 0 {
        eprintln!("[hil] suite passed on {}", vm.name());
    } else {
        eprintln!(
            "[hil] FAILED: the suite exited with status {st} on {} (its output is above and in suite.log)",
            vm.name()
        );
    }
    std::process::exit(st);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn auto_tries_uml_then_qemu() {
        assert_eq!(VmChoice::Auto.plan(), &[Vm::Uml, Vm::Qemu]);
        assert_eq!(VmChoice::Uml.plan(), &[Vm::Uml]);
        assert_eq!(VmChoice::Qemu.plan(), &[Vm::Qemu]);
    }

    #[test]
    fn a_boot_failure_is_told_apart_from_a_booted_guest() {
        // The console of UML on the AMX Xeon (issue 28).
        let mut o = Outcome::default();
        for l in [
            "mmapper_init - find_iomem failed",
            "Failed to initialize ubd device 0 :Couldn't determine size of device's file",
            "userspace - ptrace set fp regs failed, errno = 14",
            "Kernel panic - not syncing: Attempted to kill init! exitcode=0x0000000b",
        ] {
            note_fatal(&mut o, l);
        }
        let why = o.boot_failure().expect("no vcan: a boot failure");
        assert!(why.contains("ended before vcan came up"), "{why}");
        assert!(
            why.contains("(console: \"userspace - ptrace set fp regs failed, errno = 14\", \"Kernel panic"),
            "the benign lines are skipped: {why}"
        );

        o.boot_timeout = true;
        assert!(o.boot_failure().unwrap().contains("boot timeout"));

        // Once vcan is up, whatever happens next is the suite's (or the guest's), not the boot's.
        o.vcan_up_host = Some(Duration::from_secs(3));
        assert_eq!(o.boot_failure(), None);
        // A signal or the watchdog is not the VM's fault either.
        let o = Outcome {
            signal: 2,
            ..Default::default()
        };
        assert_eq!(o.boot_failure(), None);
        let o = Outcome {
            watchdog: true,
            ..Default::default()
        };
        assert_eq!(o.boot_failure(), None);
        let o = Outcome {
            guest_error: Some("insmod vcan.ko failed".into()),
            ..Default::default()
        };
        assert!(o.boot_failure().unwrap().contains("insmod vcan.ko failed"));
    }
}
