//! `cargo xtask image`: the deploy image `target/image/g1fw-aarch64.tar.gz`, byte-identical when
//! built twice from the same sources.
//!
//! Contents, under one top-level `g1fw/` directory (unpacked into `/opt`, it becomes [`INSTALL_DIR`]):
//! the aarch64 `g1fw` (release, stripped, host paths remapped: see `cross::build_aarch64`), every
//! deploy spec under `specs/peer/` with the files it references copied in and its paths rewritten
//! to them (the peer policy's weights and MJCF come from `../shared`, so they land under `shared/`
//! in the image, with their LICENSE files), the bus layouts `specs/can/*.toml`, the terrain CNN
//! (`weights/`), the systemd unit [`UNIT_NAME`] and a README for the robot.
//!
//! Reproducible: entries sorted, mtime from `SOURCE_DATE_EPOCH` (default: the last commit's time,
//! else 0), uid/gid 0, modes 0755/0644, gzip header without a timestamp or OS.
use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use sha2::{Digest, Sha256};

use crate::cross;

/// Where the image is unpacked on the robot (`tar -xzf … -C /opt`).
pub const INSTALL_DIR: &str = "/opt/g1fw";
/// The image's top-level directory.
const PREFIX: &str = "g1fw";
pub const UNIT_NAME: &str = "g1fw.service";
/// The spec the unit runs (image-relative): the peer policy drives the 12 leg motors.
const UNIT_SPEC: &str = "specs/peer/unitree_g1_lstm.toml";
/// The robot's DDS: the onboard computer's Ethernet port (192.168.123.0/24) and domain 0.
const UNIT_DDS: &str = "eth0,0";
const UNIT_DDS_IFACE: &str = "eth0";
/// Spec keys that name files, relative to the spec.
const SPEC_PATH_KEYS: [(&str, &str); 4] = [
    ("policy", "weights"),
    ("estimator", "model"),
    ("perception", "terrain_network"),
    ("perception", "terrain_weights"),
];

#[derive(clap::Args)]
pub struct Args {
    /// Output file (default: target/image/g1fw-aarch64.tar.gz).
    #[arg(long, value_name = "FILE")]
    out: Option<PathBuf>,
    /// Package the aarch64 g1fw that is already built instead of running cargo.
    #[arg(long)]
    no_build: bool,
}

/// One file of the image: path below [`PREFIX`], contents, mode.
struct Entry {
    data: Vec<u8>,
    mode: u32,
}

/// Image path → entry; a BTreeMap keeps them sorted and rejects nothing twice silently.
#[derive(Default)]
struct Files(BTreeMap<String, Entry>);

impl Files {
    fn add(&mut self, path: String, data: Vec<u8>, mode: u32) -> Result<()> {
        if self.0.insert(path.clone(), Entry { data, mode }).is_some() {
            bail!("two files want the image path {path}");
        }
        Ok(())
    }
    fn add_file(&mut self, path: String, src: &Path, mode: u32) -> Result<()> {
        let data = std::fs::read(src).with_context(|| format!("reading {}", src.display()))?;
        self.add(path, data, mode)
    }
}

/// `SOURCE_DATE_EPOCH`, else the last commit's time, else 0.
fn source_date_epoch(root: &Path) -> Result<u64> {
    if let Some(v) = std::env::var_os("SOURCE_DATE_EPOCH") {
        let s = v.to_string_lossy();
        return s
            .trim()
            .parse()
            .with_context(|| format!("SOURCE_DATE_EPOCH={s} is not a number of seconds"));
    }
    let out = Command::new("git")
        .args(["log", "-1", "--format=%ct"])
        .current_dir(root)
        .output();
    Ok(out
        .ok()
        .filter(|o| o.status.success())
        .and_then(|o| String::from_utf8_lossy(&o.stdout).trim().parse().ok())
        .unwrap_or(0))
}

/// `rel` (a path below the image root) as seen from the directory `from_dir` (also below it).
fn relative_to(from_dir: &str, rel: &str) -> String {
    let up = Path::new(from_dir).components().count();
    format!("{}{rel}", "../".repeat(up))
}

fn slash(p: &Path) -> Result<String> {
    let parts: Option<Vec<&str>> = p.components().map(|c| c.as_os_str().to_str()).collect();
    Ok(parts
        .with_context(|| format!("{} is not UTF-8", p.display()))?
        .join("/"))
}

/// Where a file a spec references goes in the image: `shared/…` for `../shared`, else its path in
/// the checkout. Anything else is refused (the image must not depend on the build machine).
fn image_path_of(src: &Path, root: &Path, shared: Option<&Path>) -> Result<String> {
    if let Some(rel) = shared.and_then(|s| src.strip_prefix(s).ok()) {
        return Ok(format!("shared/{}", slash(rel)?));
    }
    if let Ok(rel) = src.strip_prefix(root) {
        return slash(rel);
    }
    bail!(
        "{} is neither in the checkout nor in ../shared: the image cannot carry it",
        src.display()
    )
}

/// Adds `specs/peer/<name>.toml` with every referenced file, the spec's paths rewritten to them.
fn add_spec(files: &mut Files, root: &Path, shared: Option<&Path>, spec: &Path) -> Result<()> {
    let text = std::fs::read_to_string(spec).with_context(|| format!("reading {}", spec.display()))?;
    let value: toml::Table = text
        .parse()
        .with_context(|| format!("{} is not valid TOML", spec.display()))?;
    let spec_rel = slash(spec.strip_prefix(root).context("spec outside the checkout")?)?;
    let spec_dir = spec_rel.rsplit_once('/').map_or("", |(d, _)| d).to_string();
    let mut out = format!(
        "# Packaged by `cargo xtask image` from {spec_rel}: the file paths below point into this image.\n{text}"
    );
    let mut rewritten = Vec::new();
    for (table, key) in SPEC_PATH_KEYS {
        let Some(orig) = value.get(table).and_then(|t| t.get(key)).and_then(|v| v.as_str()) else {
            continue;
        };
        let src = spec.parent().unwrap_or(root).join(orig);
        let src = src
            .canonicalize()
            .with_context(|| format!("{spec_rel}: [{table}] {key} = {orig:?}: {} not found", src.display()))?;
        let dest = image_path_of(&src, root, shared)?;
        if !files.0.contains_key(&dest) {
            files.add_file(dest.clone(), &src, 0o644)?;
            // Unitree's files are BSD-3: their licence travels with them.
            if let Some(dir) = src.parent() {
                let lic = dir.join("LICENSE");
                let lic_dest = format!("{}/LICENSE", dest.rsplit_once('/').map_or("", |(d, _)| d));
                if lic.is_file() && !files.0.contains_key(&lic_dest) {
                    files.add_file(lic_dest, &lic, 0o644)?;
                }
            }
        }
        let new = relative_to(&spec_dir, &dest);
        let quoted: Vec<String> = vec![format!("\"{orig}\""), format!("'{orig}'")];
        let hits: usize = quoted.iter().map(|q| out.matches(q.as_str()).count()).sum();
        if hits != 1 {
            bail!("{spec_rel}: [{table}] {key} = {orig:?} appears {hits} times in the text; cannot rewrite it");
        }
        for q in &quoted {
            out = out.replace(q.as_str(), &format!("\"{new}\""));
        }
        rewritten.push((table, key, new));
    }
    // The rewrite must mean what it says.
    let check: toml::Table = out.parse().context("rewritten spec is not valid TOML")?;
    for (table, key, new) in &rewritten {
        let got = check.get(*table).and_then(|t| t.get(*key)).and_then(|v| v.as_str());
        if got != Some(new.as_str()) {
            bail!("{spec_rel}: rewriting [{table}] {key} gave {got:?}, wanted {new:?}");
        }
    }
    files.add(spec_rel, out.into_bytes(), 0o644)
}

/// The systemd unit. Real-time scheduling is set by systemd for the whole process (every thread
/// inherits it); a trip, a crash or a stop leaves the robot down until a person starts it again.
fn unit_text() -> String {
    format!(
        "\
# g1fw on the G1: rt/lowstate and rt/lowcmd over DDS (domain 0) on {UNIT_DDS_IFACE}, the peer walking policy.
# Install: see {INSTALL_DIR}/README.md. Started by hand only.
[Unit]
Description=G1 control firmware (g1fw) over DDS
Documentation=file:{INSTALL_DIR}/README.md
Requires=sys-subsystem-net-devices-{UNIT_DDS_IFACE}.device
After=sys-subsystem-net-devices-{UNIT_DDS_IFACE}.device network-online.target

[Service]
Type=simple
WorkingDirectory={INSTALL_DIR}
ExecStart={INSTALL_DIR}/bin/g1fw run --dds {UNIT_DDS} --spec {INSTALL_DIR}/{UNIT_SPEC} --mlockall
# Never restart by itself: a robot that tripped (exit 3), failed or fell stays damped until a person
# has looked at it and starts the service again.
Restart=no
# g1fw damps every motor on SIGTERM before it exits.
KillSignal=SIGTERM
TimeoutStopSec=5
# Real time: SCHED_FIFO for the control loop, memory locked (--mlockall, allowed by LimitMEMLOCK), on
# the cores kept for it (match these to the kernel's isolcpus= on the robot's computer).
CPUSchedulingPolicy=fifo
CPUSchedulingPriority=80
LimitRTPRIO=80
LimitMEMLOCK=infinity
CPUAffinity=2 3
# Logs: stdout (the JSON run report) and stderr (events, safety trips) go to the journal; add
# --log /var/log/g1fw/run.mcap with `systemctl edit g1fw` for an MCAP log.
StandardOutput=journal
StandardError=journal
LogsDirectory=g1fw
NoNewPrivileges=yes
ProtectHome=yes
ProtectSystem=full
# No [Install] section on purpose: the unit cannot be enabled at boot.
"
    )
}

fn readme_text(commit: &str, epoch: u64, files: &Files) -> String {
    let mut list = String::new();
    for (path, e) in &files.0 {
        list.push_str(&format!("    {:o}  {:>9}  {path}\n", e.mode, e.data.len()));
    }
    format!(
        "\
# g1fw deploy image (aarch64)

The G1 control firmware, built by `cargo xtask image` from commit {commit} (SOURCE_DATE_EPOCH
{epoch}). Building the same sources again with the same toolchain gives the same bytes.

- `bin/g1fw`: the firmware, aarch64 Linux (glibc), release, stripped.
- `{UNIT_SPEC}`: the deploy spec the service runs. The policy weights and the MJCF it reads
  the leg kinematics from are under `shared/` (Unitree, BSD-3: see the LICENSE files there).
- `specs/can/*.toml`: CAN bus layouts for the vcan bench (`g1fw run --can-config`); the G1
  itself is reached over DDS.
- `weights/`: the terrain CNN (the same network is built into `g1fw`).
- `{UNIT_NAME}`: the systemd unit; `README.md`: this file.
- `{LINKED_CRATES}`: every crate `bin/g1fw` links (no plotting, progress bars or simulator tooling:
  those are the lab commands, which this build leaves out).

## Install

    sudo tar -xzf g1fw-aarch64.tar.gz -C /opt          # gives {INSTALL_DIR}
    sudo cp {INSTALL_DIR}/{UNIT_NAME} /etc/systemd/system/
    sudo systemctl daemon-reload

The unit talks to the robot over DDS on `{UNIT_DDS_IFACE}`, domain 0: that interface needs an
address in 192.168.123.0/24 (the onboard computer is usually 192.168.123.164). If yours is named
otherwise, change `--dds {UNIT_DDS}` with `sudo systemctl edit --full g1fw`. Before starting,
release Unitree's own locomotion (the app, or MotionSwitcher `ReleaseMode`): `g1fw` refuses to
start while another program publishes `rt/lowcmd`, and damps if one appears. Check the unit's
`CPUAffinity=` against the cores the kernel keeps free (`isolcpus=`). For the stair policy, add
`--lidar-udp 0.0.0.0:56301` (the MID-360's points).

## Check the configuration

    {INSTALL_DIR}/bin/g1fw --version
    {INSTALL_DIR}/bin/g1fw check-spec --spec {INSTALL_DIR}/{UNIT_SPEC}

`check-spec` loads the spec, its weights and the MJCF and prints the weights' sha256; it exits
non-zero naming the field on any error. The bus layout is checked when the service starts.

## Start and stop

Hang the robot in its gantry first: the firmware ramps to the default pose, holds, then walks on
the policy's commands (zero velocity by default).

    sudo systemctl start g1fw
    sudo systemctl stop g1fw        # SIGTERM: the firmware damps every motor, then exits
    systemctl status g1fw

The service never restarts by itself and is not enabled at boot: after a safety trip the motors
stay damped and `g1fw` exits with status 3 when stopped; a person looks at the robot and starts
it again.

## Logs

    journalctl -u g1fw              # events and safety trips (stderr), the JSON run report (stdout)

For an MCAP log (every tick; replay it anywhere with `g1fw replay`), add
`--log /var/log/g1fw/run.mcap` to `ExecStart` with `sudo systemctl edit --full g1fw`
(`/var/log/g1fw` is the unit's `LogsDirectory`).

## Files

    mode   bytes      path (below {INSTALL_DIR})
{list}"
    )
}

/// The list of crates `bin/g1fw` links.
pub const LINKED_CRATES: &str = "LINKED_CRATES.txt";

/// Every file of the image except the README (which lists them).
fn collect(root: &Path, bin: &Path) -> Result<Files> {
    let mut files = Files::default();
    files.add_file("bin/g1fw".into(), bin, 0o755)?;

    let shared = cross::shared_dir(root).map(|s| s.canonicalize()).transpose()?;
    let root_c = root.canonicalize()?;
    let peer_dir = root_c.join("specs/peer");
    let mut specs: Vec<PathBuf> = std::fs::read_dir(&peer_dir)
        .with_context(|| format!("reading {}", peer_dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    specs.sort();
    if shared.is_none() {
        bail!(
            "the image needs the peer policy from ../shared beside the checkout (its weights and MJCF); \
             it is not there (set G1_SHARED_DIR if it lives elsewhere)"
        );
    }
    for spec in &specs {
        add_spec(&mut files, &root_c, shared.as_deref(), spec)?;
    }
    if !files.0.contains_key(UNIT_SPEC) {
        bail!("{UNIT_SPEC}, which the unit runs, is missing");
    }

    // Whatever bus layouts exist at build time (the vcan bench; the unit itself speaks DDS).
    let can_dir = root_c.join("specs/can");
    let mut cans: Vec<PathBuf> = match std::fs::read_dir(&can_dir) {
        Ok(d) => d
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|e| e == "toml"))
            .collect(),
        Err(_) => Vec::new(),
    };
    cans.sort();
    for c in &cans {
        files.add_file(slash(c.strip_prefix(&root_c)?)?, c, 0o644)?;
    }

    // The terrain CNN; its parity fixture is test data and stays behind.
    let wdir = root_c.join("control/weights");
    let mut weights: Vec<PathBuf> = std::fs::read_dir(&wdir)
        .with_context(|| format!("reading {}", wdir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file() && !p.to_string_lossy().contains("parity"))
        .collect();
    weights.sort();
    for w in &weights {
        let name = w.file_name().and_then(|n| n.to_str()).context("weights file name")?;
        files.add_file(format!("weights/{name}"), w, 0o644)?;
    }
    files.add(UNIT_NAME.into(), unit_text().into_bytes(), 0o644)?;
    files.add(LINKED_CRATES.into(), cross::linked_crates(root)?.into_bytes(), 0o644)?;
    Ok(files)
}

/// The gzipped tarball of `files` below [`PREFIX`], with their parent directories.
fn pack(files: &Files, mtime: u64) -> Result<Vec<u8>> {
    // Directories first in component order, each before its contents.
    let mut entries: BTreeMap<Vec<String>, Option<&Entry>> = BTreeMap::new();
    for (path, e) in &files.0 {
        let mut comps: Vec<String> = vec![PREFIX.to_string()];
        comps.extend(path.split('/').map(str::to_string));
        for i in 1..comps.len() {
            entries.entry(comps[..i].to_vec()).or_insert(None);
        }
        entries.insert(comps, Some(e));
    }
    let mut tar = tar::Builder::new(Vec::new());
    for (comps, e) in &entries {
        let mut h = tar::Header::new_gnu();
        h.set_uid(0);
        h.set_gid(0);
        h.set_username("root")?;
        h.set_groupname("root")?;
        h.set_mtime(mtime);
        let path = comps.join("/");
        match e {
            None => {
                h.set_entry_type(tar::EntryType::Directory);
                h.set_mode(0o755);
                h.set_size(0);
                tar.append_data(&mut h, format!("{path}/"), std::io::empty())?;
            }
            Some(e) => {
                h.set_entry_type(tar::EntryType::Regular);
                h.set_mode(e.mode);
                h.set_size(e.data.len() as u64);
                tar.append_data(&mut h, &path, e.data.as_slice())?;
            }
        }
    }
    let tar = tar.into_inner()?;
    // No file name, no timestamp, "unknown" OS: the header depends on nothing but the data.
    let mut gz = flate2::GzBuilder::new()
        .mtime(0)
        .operating_system(255)
        .write(Vec::new(), flate2::Compression::best());
    gz.write_all(&tar)?;
    Ok(gz.finish()?)
}

pub fn run(args: Args) -> Result<()> {
    let root = cross::repo_root();
    let t0 = Instant::now();
    let bin = if args.no_build {
        let bin = cross::aarch64_bin(&root);
        if !bin.is_file() {
            bail!(
                "{} is not built: run `cargo xtask image` without --no-build",
                bin.display()
            );
        }
        bin
    } else {
        cross::build_aarch64(&root)?.bin
    };
    let t_pack = Instant::now();
    let epoch = source_date_epoch(&root)?;
    // "-dirty": the working tree had uncommitted changes, which the image carries.
    let commit = Command::new("git")
        .args(["describe", "--always", "--abbrev=12", "--dirty=-dirty"])
        .current_dir(&root)
        .output()
        .ok()
        .filter(|o| o.status.success())
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
        .unwrap_or_else(|| "(unknown)".into());
    let mut files = collect(&root, &bin)?;
    let readme = readme_text(&commit, epoch, &files);
    files.add("README.md".into(), readme.into_bytes(), 0o644)?;
    let bytes = pack(&files, epoch)?;

    let out = args
        .out
        .unwrap_or_else(|| cross::target_dir(&root).join("image/g1fw-aarch64.tar.gz"));
    let out = if out.is_absolute() { out } else { root.join(out) };
    if let Some(dir) = out.parent() {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    std::fs::write(&out, &bytes).with_context(|| format!("writing {}", out.display()))?;
    let sha = Sha256::digest(&bytes);
    let sha: String = sha.iter().map(|b| format!("{b:02x}")).collect();
    for (path, e) in &files.0 {
        println!("{:o} {:>9} {PREFIX}/{path}", e.mode, e.data.len());
    }
    println!(
        "{} ({} bytes, {} files, mtime {epoch}, packed in {:.2} s, {:.1} s in all)",
        out.display(),
        bytes.len(),
        files.0.len(),
        t_pack.elapsed().as_secs_f64(),
        t0.elapsed().as_secs_f64()
    );
    println!("sha256 {sha}");
    Ok(())
}
