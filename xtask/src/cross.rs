//! `cargo xtask cross-replay`: cross-build `g1fw` for the robot's CPU (aarch64-unknown-linux-gnu,
//! release) and replay every log of the regression corpus (`tests/corpus/*.mcap`) with it under
//! `qemu-aarch64`. The logs were recorded on x86-64 and `g1fw replay` compares every output with the
//! recorded one bit for bit, so exit 0 for each log means the aarch64 build computes the same bits.
//!
//! The build is shared with `cargo xtask image` ([`build_aarch64`]): same flags, so the second
//! command finds it up to date. Its flags make it reproducible: host paths remapped, symbols and
//! debug info stripped.
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::{bail, Context, Result};

pub const TARGET: &str = "aarch64-unknown-linux-gnu";
/// Where Debian's cross libc lives (`libc6-arm64-cross`): qemu-aarch64's `-L`.
pub const SYSROOT: &str = "/usr/aarch64-linux-gnu";
/// What the C part (lz4-sys) and the final link need.
const CROSS_GCC: &str = "aarch64-linux-gnu-gcc";
const CROSS_AR: &str = "aarch64-linux-gnu-ar";
const APT_HINT: &str =
    "apt-get install gcc-aarch64-linux-gnu libc6-dev-arm64-cross qemu-user (scripts/install.sh installs them)";

#[derive(clap::Args)]
pub struct Args {
    /// Replay only these logs (default: every tests/corpus/*.mcap).
    #[arg(long = "log", value_name = "MCAP")]
    logs: Vec<PathBuf>,
    /// Use the aarch64 g1fw that is already built instead of running cargo.
    #[arg(long)]
    no_build: bool,
}

/// The repository root (xtask/..).
pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("xtask/ has a parent")
        .to_path_buf()
}

/// Cargo's target directory (`CARGO_TARGET_DIR` or `target/`).
pub fn target_dir(root: &Path) -> PathBuf {
    std::env::var_os("CARGO_TARGET_DIR")
        .map(|d| root.join(d))
        .unwrap_or_else(|| root.join("target"))
}

/// The aarch64 `g1fw` that [`build_aarch64`] produces.
pub fn aarch64_bin(root: &Path) -> PathBuf {
    target_dir(root).join(TARGET).join("release/g1fw")
}

/// Fails with what to install when `tool --version` cannot run.
fn require_tool(tool: &str, package: &str) -> Result<()> {
    match Command::new(tool).arg("--version").output() {
        Ok(o) if o.status.success() => Ok(()),
        Ok(o) => bail!(
            "`{tool} --version` failed ({}): reinstall {package} ({APT_HINT})",
            o.status
        ),
        Err(e) => bail!("{tool} not found ({e}): install {package}: {APT_HINT}"),
    }
}

/// Checks for the aarch64 Rust standard library, the cross compiler and archiver.
fn check_build_tools() -> Result<()> {
    let sysroot = Command::new("rustc")
        .args(["--print", "sysroot"])
        .output()
        .context("running rustc --print sysroot")?;
    let sysroot = PathBuf::from(String::from_utf8_lossy(&sysroot.stdout).trim());
    if !sysroot.join("lib/rustlib").join(TARGET).join("lib").is_dir() {
        bail!(
            "the Rust standard library for {TARGET} is not installed in {}: run `rustup target add {TARGET}` \
             (scripts/install.sh does)",
            sysroot.display()
        );
    }
    require_tool(CROSS_GCC, "gcc-aarch64-linux-gnu")?;
    require_tool(
        CROSS_AR,
        "binutils-aarch64-linux-gnu (comes with gcc-aarch64-linux-gnu)",
    )
}

/// Checks for qemu-aarch64 and the aarch64 libc it loads the dynamically linked g1fw with.
pub fn check_qemu() -> Result<()> {
    require_tool("qemu-aarch64", "qemu-user")?;
    let loader = Path::new(SYSROOT).join("lib/ld-linux-aarch64.so.1");
    if !loader.exists() {
        bail!(
            "{} is missing: install libc6-arm64-cross ({APT_HINT})",
            loader.display()
        );
    }
    Ok(())
}

/// The aarch64 `g1fw` and how long cargo took for it.
pub struct Built {
    pub bin: PathBuf,
    pub seconds: f64,
}

/// Cross-builds `g1fw` in release for [`TARGET`]. Host paths (the checkout, the cargo home, the
/// target dir) are remapped in Rust and C code and symbols are stripped, so the binary depends on
/// the sources only (checked by the image test). Incremental: a second call is a no-op.
pub fn build_aarch64(root: &Path) -> Result<Built> {
    check_build_tools()?;
    let cargo_home = std::env::var_os("CARGO_HOME")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cargo")))
        .context("neither CARGO_HOME nor HOME is set")?;
    // Most specific last: rustc and gcc both apply the last prefix that matches (the target dir
    // usually sits inside the checkout).
    let maps = [
        (cargo_home, "/cargo"),
        (root.to_path_buf(), "/g1fw"),
        (target_dir(root), "/target"),
    ];
    let mut rustflags: Vec<String> = maps
        .iter()
        .map(|(from, to)| format!("--remap-path-prefix={}={to}", from.display()))
        .collect();
    // Stripped anyway: not generating debug info saves build time.
    rustflags.extend(["-Cstrip=symbols".into(), "-Cdebuginfo=0".into()]);
    let cflags: Vec<String> = maps
        .iter()
        .map(|(from, to)| format!("-ffile-prefix-map={}={to}", from.display()))
        .collect();
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let t0 = Instant::now();
    let status = Command::new(cargo)
        .current_dir(root)
        .args([
            "build",
            "--release",
            "--target",
            TARGET,
            "-p",
            "firmware",
            "--bin",
            "g1fw",
            // The robot's binary without the lab commands (sim, eval, plot, bev) and what only
            // they link (plotters, indicatif, the simulator bridge in sim_hal).
            "--no-default-features",
        ])
        // With --target, these reach the aarch64 artifacts only, never build scripts or proc
        // macros, so the host build in the same target dir is not invalidated.
        .env("CARGO_ENCODED_RUSTFLAGS", rustflags.join("\u{1f}"))
        .env("CARGO_TARGET_AARCH64_UNKNOWN_LINUX_GNU_LINKER", CROSS_GCC)
        .env("CC_aarch64_unknown_linux_gnu", CROSS_GCC)
        .env("AR_aarch64_unknown_linux_gnu", CROSS_AR)
        .env("CFLAGS_aarch64_unknown_linux_gnu", cflags.join(" "))
        .status()
        .context("running cargo build for aarch64")?;
    if !status.success() {
        bail!("cargo build --release --target {TARGET} -p firmware --bin g1fw --no-default-features failed ({status})");
    }
    let seconds = t0.elapsed().as_secs_f64();
    let bin = aarch64_bin(root);
    if !bin.is_file() {
        bail!("cargo finished but {} is not there", bin.display());
    }
    eprintln!("[cross] aarch64 g1fw built in {seconds:.1} s: {}", bin.display());
    Ok(Built { bin, seconds })
}

/// `../shared` beside the checkout (the peer policy the `peer_*` logs need), if present.
pub fn shared_dir(root: &Path) -> Option<PathBuf> {
    let p = std::env::var_os("G1_SHARED_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| root.join("../shared"));
    p.join("peer_policy").is_dir().then_some(p)
}

fn in_ci() -> bool {
    std::env::var_os("CI").is_some()
}

/// One replayed log.
struct Row {
    name: String,
    ticks: u64,
    policy_steps: u64,
    perception_steps: u64,
    wall_s: f64,
}

fn corpus(root: &Path) -> Result<Vec<PathBuf>> {
    let dir = root.join("tests/corpus");
    let mut logs: Vec<PathBuf> = std::fs::read_dir(&dir)
        .with_context(|| format!("reading {}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "mcap"))
        .collect();
    logs.sort();
    Ok(logs)
}

/// Replays `log` with the aarch64 `bin` under qemu; `Err` carries the divergence or the error.
fn replay_one(root: &Path, bin: &Path, log: &Path, report_dir: &Path) -> Result<Row> {
    let name = log.file_name().unwrap_or_default().to_string_lossy().to_string();
    let report = report_dir.join(format!("{name}.json"));
    let _ = std::fs::remove_file(&report);
    let t0 = Instant::now();
    let out = Command::new("qemu-aarch64")
        .args(["-L", SYSROOT])
        .arg(bin)
        .arg("replay")
        .arg(log)
        .arg("--report")
        .arg(&report)
        // Logs name their spec relative to the checkout.
        .current_dir(root)
        .output()
        .context("running qemu-aarch64")?;
    let wall_s = t0.elapsed().as_secs_f64();
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    let parsed: Option<serde_json::Value> = std::fs::read(&report)
        .ok()
        .and_then(|b| serde_json::from_slice(&b).ok());
    match out.status.code() {
        Some(0) => {}
        Some(1) => {
            let divergence = parsed
                .as_ref()
                .and_then(|r| r.get("divergence"))
                .map(|d| serde_json::to_string_pretty(d).unwrap_or_default())
                .unwrap_or_else(|| "(no report)".into());
            bail!(
                "{name}: aarch64 output DIVERGES from the x86-64 recording\n  first divergence: {divergence}\n  \
                 replay output (tail):\n{}",
                tail(&text, 30)
            );
        }
        _ => bail!(
            "{name}: replay under qemu-aarch64 could not run ({}):\n{}",
            out.status,
            tail(&text, 30)
        ),
    }
    let r = parsed.with_context(|| format!("{name}: replay exited 0 but wrote no readable report"))?;
    let num = |k: &str| r.get(k).and_then(|v| v.as_u64()).unwrap_or(0);
    if num("compared_commands") != num("ticks") || num("ticks") == 0 {
        bail!(
            "{name}: replay compared {} commands over {} ticks",
            num("compared_commands"),
            num("ticks")
        );
    }
    Ok(Row {
        name,
        ticks: num("ticks"),
        policy_steps: num("compared_policy_steps"),
        perception_steps: num("compared_perception_steps"),
        wall_s,
    })
}

fn tail(text: &str, lines: usize) -> String {
    let v: Vec<&str> = text.lines().collect();
    v[v.len().saturating_sub(lines)..]
        .iter()
        .map(|l| format!("    {l}"))
        .collect::<Vec<_>>()
        .join("\n")
}

pub fn run(args: Args) -> Result<()> {
    let root = repo_root();
    check_qemu()?;
    let (bin, build_s) = if args.no_build {
        let bin = aarch64_bin(&root);
        if !bin.is_file() {
            bail!(
                "{} is not built: run `cargo xtask cross-replay` without --no-build",
                bin.display()
            );
        }
        (bin, None)
    } else {
        let b = build_aarch64(&root)?;
        (b.bin, Some(b.seconds))
    };
    let logs = if args.logs.is_empty() {
        corpus(&root)?
    } else {
        args.logs.iter().map(|l| root.join(l)).collect()
    };
    if logs.is_empty() {
        bail!("no logs to replay in tests/corpus");
    }
    let report_dir = target_dir(&root).join("cross-replay");
    std::fs::create_dir_all(&report_dir).with_context(|| format!("creating {}", report_dir.display()))?;
    let shared = shared_dir(&root);

    let t0 = Instant::now();
    let mut rows = Vec::new();
    let mut failures = Vec::new();
    let mut skipped = Vec::new();
    for log in &logs {
        let name = log.file_name().unwrap_or_default().to_string_lossy().to_string();
        if name.starts_with("peer_") && shared.is_none() {
            let msg = format!("{name} needs ../shared beside the checkout (the peer policy); it is not there");
            if in_ci() {
                failures.push(format!("{msg} — and CI must have it"));
            } else {
                eprintln!("\n!!!!!!!! SKIP: {msg} !!!!!!!!\n");
                skipped.push(name);
            }
            continue;
        }
        match replay_one(&root, &bin, log, &report_dir) {
            Ok(row) => rows.push(row),
            Err(e) => failures.push(format!("{e:#}")),
        }
    }
    let total_s = t0.elapsed().as_secs_f64();

    println!(
        "aarch64 g1fw under qemu-aarch64 vs the x86-64 recordings (reports in {}):",
        report_dir.display()
    );
    println!(
        "{:<34} {:>7} {:>13} {:>17} {:>8}",
        "log", "ticks", "policy steps", "perception steps", "wall s"
    );
    for r in &rows {
        println!(
            "{:<34} {:>7} {:>13} {:>17} {:>8.2}",
            r.name, r.ticks, r.policy_steps, r.perception_steps, r.wall_s
        );
    }
    for s in &skipped {
        println!("{s:<34} SKIPPED (no ../shared)");
    }
    match build_s {
        Some(s) => println!("cross build {s:.1} s, replays {total_s:.1} s"),
        None => println!("replays {total_s:.1} s (build skipped)"),
    }
    if !failures.is_empty() {
        for f in &failures {
            eprintln!("\nFAIL: {f}");
        }
        bail!(
            "{} of {} logs are not bit-identical on aarch64 (or could not be replayed)",
            failures.len(),
            logs.len()
        );
    }
    println!(
        "all {} logs bit-identical on aarch64{}",
        rows.len(),
        if skipped.is_empty() {
            ""
        } else {
            " (some SKIPPED, see above)"
        }
    );
    Ok(())
}

/// The crates the robot's `g1fw` links (normal dependencies of `firmware` for aarch64 without the
/// lab feature), one `name version` per line, sorted: the image lists them (`LINKED_CRATES`).
pub fn linked_crates(root: &Path) -> Result<String> {
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let out = Command::new(cargo)
        .current_dir(root)
        .args([
            "tree",
            "--target",
            TARGET,
            "-p",
            "firmware",
            "--no-default-features",
            "-e",
            "normal",
            "--prefix",
            "none",
            "--format",
            "{p}",
        ])
        .output()
        .context("running cargo tree")?;
    if !out.status.success() {
        bail!("cargo tree failed: {}", String::from_utf8_lossy(&out.stderr));
    }
    let mut lines: Vec<String> = String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|l| {
            // "name v1.2.3 (/path)" or "name v1.2.3 (*)": keep name and version, no host paths.
            let mut w = l.split_whitespace();
            format!("{} {}", w.next().unwrap_or(""), w.next().unwrap_or(""))
        })
        .filter(|l| !l.trim().is_empty())
        .collect();
    lines.sort();
    lines.dedup();
    Ok(lines.join("\n") + "\n")
}
