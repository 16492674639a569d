//! `cargo xtask hil`: the CAN hardware-in-loop suite, inside a User-Mode Linux VM.
//!
//! The host kernel of the development and CI machines has no CAN (`CONFIG_CAN` unset), so the suite
//! runs in a UML guest (`/usr/bin/linux`, Debian package `user-mode-linux`): the kernel is an ordinary
//! process, its root is the host `/` read-only through hostfs, and the guest's init is
//! `scripts/hil/guest_init.sh`. That script loads the CAN modules shipped with the UML kernel, brings
//! up `vcan0` and `vcan1`, runs the suite and powers the guest off. The host and the guest talk
//! through one host directory, `<target>/hil/run-<pid>/`, mounted read-write in the guest at the
//! same path (`env.sh` in, `suite.log`, `status` and whatever the suite writes out), and through
//! marker lines on the guest console (the UML process's stdout; see the init script).
use anyhow::{anyhow, bail, Context, Result};
use std::fmt::Write as _;
use std::fs;
use std::io::{BufRead, BufReader, Write as _};
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::atomic::{AtomicI32, Ordering};
use std::sync::mpsc::{self, RecvTimeoutError};
use std::time::{Duration, Instant};

const LONG_HELP: &str = "\
What it does:
  1. checks the tools: User-Mode Linux (/usr/bin/linux and its CAN modules under /usr/lib/uml/modules),
     insmod (kmod), ip (iproute2), can-utils, and python-can in .venv (scripts/install.sh installs all);
  2. builds the host binaries the suite runs (cargo build --release -p firmware -p g1_sim -p sim_hal
     --bins: g1fw, g1-sim, g1-can-emu), unless --no-build;
  3. boots UML (root = the host / read-only through hostfs, init = scripts/hil/guest_init.sh): the
     guest mounts proc/sys and tmpfs on /run (TMPDIR=/run/tmp; the host's /tmp stays visible),
     loads can, can-raw, can-gw, can-dev, vcan, creates vcan0-vcan3, raises the socket receive
     buffers (net.core.rmem_max/rmem_default), then runs the suite as root with the repository root
     as its working directory;
  4. streams the suite's output, and prints the boot time (spawn -> vcan up, host clock, and the guest's
     uptime at that point), the suite's wall time and the total.

The suite is scripts/hil/suite.sh: a smoke test of the plumbing (candump/cansend on both buses, a
python-can round trip) followed by tests/hil/peer_test.py, the independent python-can implementation
of docs/can.md that drives g1fw and g1-can-emu on vcan0/vcan1. `--suite FILE` runs another bash script,
`cargo xtask hil -- CMD ARGS...` any command (e.g. `cargo xtask hil -- ip -details link`).

The guest sees no host environment except what is written to <run dir>/env.sh: PATH (with .venv/bin
and the release binaries first), HIL_DIR (the writable run directory), HIL_REPO, HIL_BIN_DIR, and the
host's CI, RUST_LOG, RUST_BACKTRACE and every HIL_* variable (e.g. HIL_WALK_S=20 for the peer test).

Output lands in <target>/hil/run-<pid>/ (target/hil/last points at the newest): console.log (the whole
guest console), suite.log, status, summary.json (timings) and what the suite writes there.

Exit status: the suite's. 124 if the watchdog (--timeout-min) killed the VM, 125 if the guest ended
without reporting a status (the reason and the console's tail are printed), 130 on Ctrl-C.";

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
    /// Guest memory (UML `mem=`); the suite runs MuJoCo, the firmware and python-can at once.
    #[arg(long, value_name = "SIZE", default_value = "1024M")]
    mem: String,
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

/// Set by SIGINT/SIGTERM/SIGHUP: the VM runs in its own process group, so the terminal's Ctrl-C does
/// not reach it; the main loop kills the group instead.
static SIGNAL: AtomicI32 = AtomicI32::new(0);

extern "C" fn on_signal(sig: libc::c_int) {
    SIGNAL.store(sig, Ordering::SeqCst);
}

const UML: &str = "/usr/bin/linux";
const UML_MODULES: &str = "/usr/lib/uml/modules";

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
    fs::write(run_dir.join("env.sh"), guest_env(&repo, &run_dir, &bin_dir, &suite))
        .with_context(|| format!("writing {}/env.sh", run_dir.display()))?;

    let timeout = Duration::from_secs_f64(args.timeout_min * 60.0);
    eprintln!(
        "[hil] booting User-Mode Linux (mem={}, watchdog {:.0} min), run dir {}",
        args.mem,
        args.timeout_min,
        run_dir.display()
    );
    eprintln!("[hil] guest runs: {}", suite.join(" "));
    let outcome = boot(&args, &repo, &run_dir, &init, timeout)?;
    report(&run_dir, &outcome, t_all.elapsed(), args.verbose)
}

/// Everything the guest needs is on the host `/` (the guest's root): check it here, where the error
/// can say what to install, rather than in a guest that can only fail.
fn preflight(repo: &Path) -> Result<()> {
    let install = "run scripts/install.sh";
    if !Path::new(UML).is_file() {
        bail!(
            "User-Mode Linux is not installed ({UML} not found): {install}, or `sudo apt-get install user-mode-linux`"
        );
    }
    let vcan = fs::read_dir(UML_MODULES)
        .ok()
        .into_iter()
        .flatten()
        .flatten()
        .any(|e| e.path().join("kernel/drivers/net/can/vcan.ko").is_file());
    if !vcan {
        bail!(
            "no vcan module for the UML kernel under {UML_MODULES}/<version>/kernel/drivers/net/can/: \
             reinstall user-mode-linux (`sudo apt-get install --reinstall user-mode-linux`)"
        );
    }
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
    let pkgs = ["-p", "firmware", "-p", "g1_sim", "-p", "sim_hal"];
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
fn guest_env(repo: &Path, run_dir: &Path, bin_dir: &Path, suite: &[String]) -> String {
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
    signal: i32,
    vcan_up_host: Option<Duration>,
    vcan_up_guest: Option<f64>,
    suite_start: Option<Duration>,
    suite_end: Option<Duration>,
    /// (status, guest wall seconds) from the `HIL:SUITE_EXIT` console line.
    console_exit: Option<(i32, f64)>,
    guest_error: Option<String>,
    console_tail: Vec<String>,
    total: Duration,
}

enum Event {
    Line(String),
    Eof,
}

fn boot(args: &Args, repo: &Path, run_dir: &Path, init: &Path, timeout: Duration) -> Result<Outcome> {
    let console_path = run_dir.join("console.log");
    let mut console =
        fs::File::create(&console_path).with_context(|| format!("creating {}", console_path.display()))?;
    let stderr = fs::File::create(run_dir.join("uml_stderr.log"))?;
    let umid = format!("g1hil-{}", std::process::id());
    let mut cmd = Command::new(UML);
    cmd.arg(format!("mem={}", args.mem))
        .args(["root=/dev/root", "rootfstype=hostfs", "rootflags=/", "ro"])
        .arg(format!("init={}", init.display()))
        // Unknown `key=value` parameters reach init as environment variables.
        .arg(format!("hil_dir={}", run_dir.display()))
        .arg(format!("hil_repo={}", repo.display()))
        .arg(format!("umid={umid}"))
        .arg(format!("uml_dir={}", run_dir.display()))
        .args(["con=null", "con0=fd:0,fd:1", "quiet"])
        .current_dir(run_dir)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::from(stderr))
        // UML forks helper processes; its own group lets the watchdog kill them all.
        .process_group(0);
    // SAFETY: plain syscall; makes the VM's helpers our children if its main process is killed.
    unsafe {
        libc::prctl(libc::PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0);
    }
    let t0 = Instant::now();
    let mut child = cmd.spawn().with_context(|| format!("starting {UML}"))?;
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
                if let Some(rest) = line.strip_prefix("HIL:VCAN_UP ") {
                    o.vcan_up_host = Some(now);
                    o.vcan_up_guest = rest.trim().parse().ok();
                    eprintln!(
                        "[hil] vcan0/vcan1 up {:.2} s after spawn (guest uptime {})",
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
                    eprintln!("[hil] guest set-up failed: {rest}");
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

fn report(run_dir: &Path, o: &Outcome, total: Duration, verbose: bool) -> Result<()> {
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
    let fmt_opt = |v: Option<f64>| v.map_or("null".to_string(), |v| format!("{v:.3}"));
    let summary = format!(
        "{{\"vcan_up_host_s\": {}, \"vcan_up_guest_uptime_s\": {}, \"suite_host_s\": {}, \"suite_guest_s\": {}, \
         \"vm_s\": {:.3}, \"total_s\": {:.3}, \"status\": {}, \"watchdog\": {}}}\n",
        fmt_opt(o.vcan_up_host.map(|d| d.as_secs_f64())),
        fmt_opt(o.vcan_up_guest),
        fmt_opt(suite_host),
        fmt_opt(status.map(|s| s.1).filter(|w| w.is_finite())),
        o.total.as_secs_f64(),
        total.as_secs_f64(),
        status.map_or("null".to_string(), |s| s.0.to_string()),
        o.watchdog
    );
    let _ = fs::write(run_dir.join("summary.json"), &summary);

    eprintln!("[hil] ---------------------------------------------------------------");
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
        let mut why = String::from("the guest ended without reporting the suite's status: ");
        if let Some(e) = &guest_error {
            let _ = write!(why, "its init failed: {e}");
        } else if o.vcan_up_host.is_none() {
            why.push_str("it never brought vcan up (see the console below and uml_stderr.log)");
        } else {
            why.push_str("it died while the suite ran (see the console below)");
        }
        if let Some(st) = o.exit {
            let _ = write!(why, "; UML exited with {st}");
        }
        Some((125, why))
    } else {
        None
    };
    if let Some((code, why)) = reason {
        if !verbose {
            eprintln!("[hil] last console lines:");
            for l in &o.console_tail {
                eprintln!("[hil] | {l}");
            }
            if let Ok(e) = fs::read_to_string(run_dir.join("uml_stderr.log")) {
                for l in e.lines().rev().take(20).collect::<Vec<_>>().into_iter().rev() {
                    eprintln!("[hil] stderr | {l}");
                }
            }
        }
        eprintln!("[hil] FAILED: {why}");
        std::process::exit(code);
    }
    let (st, _) = status.ok_or_else(|| anyhow!("unreachable: no status"))?;
    if st == 0 {
        eprintln!("[hil] suite passed");
    } else {
        eprintln!("[hil] FAILED: the suite exited with status {st} (its output is above and in suite.log)");
    }
    std::process::exit(st);
}
