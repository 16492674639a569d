//! The deploy image (`cargo xtask image`): packing twice gives the same bytes; the listing, modes,
//! owners and mtime are normalised; the systemd unit has its real-time settings and the ExecStart
//! shape; and unpacked, its aarch64 `g1fw` runs under qemu-aarch64 (`--version`, `check-spec` on
//! the packaged spec, which must read its weights from the image and nowhere else).
//!
//! It packs with the aarch64 `g1fw` that `cargo xtask cross-replay` / `cargo xtask image` build,
//! so it is `#[ignore]`d in the plain `cargo test` and scripts/test.sh runs it right after them:
//! `cargo test --release -p integration_tests --test image -- --ignored`.
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::Command;

use integration_tests::*;

const SYSROOT: &str = "/usr/aarch64-linux-gnu";

/// Loud skip outside CI, a failure in CI, when a tool the test needs is missing.
fn skip_or_fail_tool(what: &str, install: &str) {
    skip_loudly_or_fail(&format!(
        "SKIP: the deploy image test needs {what}; install {install} (scripts/install.sh does)"
    ));
}

fn qemu_ok() -> bool {
    Command::new("qemu-aarch64")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success())
        && Path::new(SYSROOT).join("lib/ld-linux-aarch64.so.1").exists()
}

struct Item {
    path: String,
    dir: bool,
    mode: u32,
    uid: u64,
    gid: u64,
    mtime: u64,
    data: Vec<u8>,
}

fn list(gz: &[u8]) -> Vec<Item> {
    let mut tar = tar::Archive::new(flate2::read::GzDecoder::new(gz));
    let mut out = Vec::new();
    for e in tar.entries().expect("a tar stream") {
        let mut e = e.expect("a tar entry");
        let h = e.header().clone();
        let path = e.path().expect("entry path").to_string_lossy().to_string();
        let mut data = Vec::new();
        e.read_to_end(&mut data).expect("entry data");
        out.push(Item {
            path,
            dir: h.entry_type().is_dir(),
            mode: h.mode().unwrap(),
            uid: h.uid().unwrap(),
            gid: h.gid().unwrap(),
            mtime: h.mtime().unwrap(),
            data,
        });
    }
    out
}

fn qemu(bin: &Path, args: &[&str], cwd: &Path) -> std::process::Output {
    Command::new("qemu-aarch64")
        .args(["-L", SYSROOT])
        .arg(bin)
        .args(args)
        .current_dir(cwd)
        .output()
        .expect("qemu-aarch64 runs")
}

fn value_of<'a>(unit: &'a str, key: &str) -> Option<&'a str> {
    unit.lines()
        .find_map(|l| l.strip_prefix(key).and_then(|r| r.strip_prefix('=')))
        .map(str::trim)
}

#[test]
#[ignore = "needs the aarch64 g1fw: scripts/test.sh runs it after `cargo xtask image` (`-- --ignored`)"]
fn deploy_image_is_reproducible_complete_and_runs_under_qemu() {
    let Some(shared) = shared_dir() else {
        return skip_or_fail("the deploy image (it carries the peer policy)");
    };
    if !qemu_ok() {
        return skip_or_fail_tool("qemu-aarch64 and the aarch64 libc", "qemu-user libc6-dev-arm64-cross");
    }
    let root = repo_root();
    let aarch64 = root.join("target/aarch64-unknown-linux-gnu/release/g1fw");
    assert!(
        aarch64.is_file(),
        "{} is not built: run `cargo xtask image` (or `cargo xtask cross-replay`) first",
        aarch64.display()
    );

    // Packed twice: the same bytes.
    let dir = scratch_dir("image");
    let pack = |out: &Path| {
        let o = Command::new(built_bin("xtask"))
            .args(["image", "--no-build", "--out"])
            .arg(out)
            .current_dir(&root)
            .output()
            .expect("xtask runs");
        assert!(
            o.status.success(),
            "xtask image failed: {}{}",
            String::from_utf8_lossy(&o.stdout),
            String::from_utf8_lossy(&o.stderr)
        );
        String::from_utf8_lossy(&o.stdout).to_string()
    };
    let (a, b) = (dir.join("a.tar.gz"), dir.join("b.tar.gz"));
    let said = pack(&a);
    pack(&b);
    let bytes = std::fs::read(&a).unwrap();
    assert!(bytes == std::fs::read(&b).unwrap(), "two packs differ");
    let sha = control::nn::sha256_hex(&bytes);
    assert!(
        said.contains(&format!("sha256 {sha}")),
        "xtask printed no/the wrong sha256:\n{said}"
    );
    // gzip header: no timestamp, OS "unknown".
    assert_eq!(&bytes[..3], &[0x1f, 0x8b, 8]);
    assert_eq!(&bytes[4..8], &[0, 0, 0, 0], "gzip mtime");
    assert_eq!(bytes[9], 255, "gzip OS byte");

    // Listing: sorted, each directory before its contents, normalised owners, modes and mtime.
    let items = list(&bytes);
    let paths: Vec<&str> = items.iter().map(|i| i.path.trim_end_matches('/')).collect();
    let mut sorted = paths.clone();
    sorted.sort_by(|x, y| x.split('/').cmp(y.split('/')));
    assert_eq!(paths, sorted, "entries are not in sorted order");
    let mtime = items[0].mtime;
    let commit_time: u64 = String::from_utf8(
        Command::new("git")
            .args(["log", "-1", "--format=%ct"])
            .current_dir(&root)
            .output()
            .unwrap()
            .stdout,
    )
    .unwrap()
    .trim()
    .parse()
    .unwrap_or(0);
    let want_mtime = std::env::var("SOURCE_DATE_EPOCH")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(commit_time);
    assert_eq!(
        mtime, want_mtime,
        "mtime is SOURCE_DATE_EPOCH or the last commit's time"
    );
    for i in &items {
        assert!(i.path.starts_with("g1fw/"), "{} outside g1fw/", i.path);
        assert_eq!((i.uid, i.gid, i.mtime), (0, 0, mtime), "{}", i.path);
        let want = if i.dir || i.path == "g1fw/bin/g1fw" {
            0o755
        } else {
            0o644
        };
        assert_eq!(i.mode, want, "{}: mode {:o}", i.path, i.mode);
        if !i.dir {
            let parent = i.path.rsplit_once('/').unwrap().0;
            assert!(paths.contains(&parent), "{}: no entry for its directory", i.path);
        }
    }
    let file = |p: &str| -> &[u8] {
        &items
            .iter()
            .find(|i| i.path == p && !i.dir)
            .unwrap_or_else(|| panic!("{p} missing from the image: {paths:?}"))
            .data
    };
    assert!(
        file("g1fw/bin/g1fw") == std::fs::read(&aarch64).unwrap(),
        "bin/g1fw is not the aarch64 build"
    );
    let policy = std::fs::read(shared.join("peer_policy/unitree_g1_lstm/policy.safetensors")).unwrap();
    assert!(file("g1fw/shared/peer_policy/unitree_g1_lstm/policy.safetensors") == policy);
    file("g1fw/shared/peer_policy/unitree_g1_lstm/LICENSE");
    file("g1fw/shared/assets/unitree_g1_12dof/g1_12dof.xml");
    file("g1fw/shared/assets/unitree_g1_12dof/LICENSE");
    let weights = std::fs::read(root.join("control/weights/terrain_cnn.safetensors")).unwrap();
    assert!(file("g1fw/weights/terrain_cnn.safetensors") == weights);
    file("g1fw/weights/terrain_cnn.toml");
    file("g1fw/README.md");
    // The robot's g1fw links no lab tooling (issue 32): no plotting, no progress bars, no simulator
    // bridge (sim_hal); the robot's own transports (robot_io: DDS, the lidar's UDP, CAN) it does.
    let linked = String::from_utf8(file("g1fw/LINKED_CRATES.txt").to_vec()).unwrap();
    assert!(linked.lines().any(|l| l.starts_with("firmware ")), "{linked}");
    assert!(linked.lines().any(|l| l.starts_with("robot_io ")), "{linked}");
    for lab in ["plotters", "indicatif", "sim_hal"] {
        assert!(
            !linked.lines().any(|l| l.split(' ').next() == Some(lab)),
            "the image's g1fw links {lab}: {linked}"
        );
    }
    let mut cans: Vec<PathBuf> = std::fs::read_dir(root.join("specs/can"))
        .map(|d| d.map(|e| e.unwrap().path()).collect())
        .unwrap_or_default();
    cans.retain(|p| p.extension().is_some_and(|e| e == "toml"));
    for c in &cans {
        let name = c.file_name().unwrap().to_string_lossy();
        assert!(file(&format!("g1fw/specs/can/{name}")) == std::fs::read(c).unwrap());
    }
    let spec = String::from_utf8(file("g1fw/specs/peer/unitree_g1_lstm.toml").to_vec()).unwrap();
    assert!(
        !spec.contains("../../../shared"),
        "the packaged spec still points outside the image"
    );

    // No host path in the binary (remapped at build time, symbols stripped).
    let bin = file("g1fw/bin/g1fw");
    let mut host = vec![root.to_string_lossy().to_string()];
    if let Some(home) = std::env::var_os("HOME") {
        host.push(format!("{}/.cargo", home.to_string_lossy()));
    }
    for h in &host {
        assert!(
            !bin.windows(h.len()).any(|w| w == h.as_bytes()),
            "the binary contains the host path {h}"
        );
    }

    // The unit: real-time settings, no automatic restart, the ExecStart shape, files in the image.
    let unit = String::from_utf8(file("g1fw/g1fw.service").to_vec()).unwrap();
    assert_eq!(value_of(&unit, "CPUSchedulingPolicy"), Some("fifo"), "{unit}");
    let prio: u32 = value_of(&unit, "CPUSchedulingPriority").unwrap().parse().unwrap();
    assert!((1..=99).contains(&prio), "{prio}");
    let rtprio: u32 = value_of(&unit, "LimitRTPRIO").unwrap().parse().unwrap();
    assert!(rtprio >= prio, "LimitRTPRIO {rtprio} < priority {prio}");
    assert_eq!(value_of(&unit, "LimitMEMLOCK"), Some("infinity"));
    let cpus = value_of(&unit, "CPUAffinity").unwrap();
    assert!(
        !cpus.is_empty() && cpus.split_whitespace().all(|c| c.parse::<u32>().is_ok()),
        "{cpus}"
    );
    assert_eq!(value_of(&unit, "Restart"), Some("no"));
    assert!(
        !unit.lines().any(|l| l.trim() == "[Install]"),
        "the unit must not be enabled at boot"
    );
    let exec: Vec<&str> = value_of(&unit, "ExecStart").unwrap().split_whitespace().collect();
    assert_eq!(exec.len(), 7, "{exec:?}");
    assert_eq!(
        exec[6], "--mlockall",
        "the control loop must never page-fault: {exec:?}"
    );
    // On the robot the unit speaks DDS on its Ethernet port, domain 0 (CAN is the bench).
    assert_eq!(
        [exec[0], exec[1], exec[2], exec[3], exec[4]],
        ["/opt/g1fw/bin/g1fw", "run", "--dds", "eth0,0", "--spec"],
        "{exec:?}"
    );
    let in_image = |p: &str| format!("g1fw/{}", p.strip_prefix("/opt/g1fw/").expect("under /opt/g1fw"));
    file(&in_image(exec[5]));

    // Unpacked: the binary runs under qemu and checks the packaged spec from inside the image.
    let unpacked = dir.join("unpacked");
    tar::Archive::new(flate2::read::GzDecoder::new(bytes.as_slice()))
        .unpack(&unpacked)
        .unwrap();
    let g1fw = unpacked.join("g1fw/bin/g1fw");
    let v = qemu(&g1fw, &["--version"], &dir);
    assert!(v.status.success(), "{v:?}");
    assert_eq!(
        String::from_utf8_lossy(&v.stdout).trim(),
        format!("g1fw {}", env!("CARGO_PKG_VERSION"))
    );
    let spec_path = unpacked.join("g1fw/specs/peer/unitree_g1_lstm.toml");
    let spec_arg = spec_path.to_str().unwrap();
    let c = qemu(&g1fw, &["check-spec", "--spec", spec_arg], &dir);
    let said = String::from_utf8_lossy(&c.stdout);
    assert!(
        c.status.success(),
        "check-spec in the image: {said}{}",
        String::from_utf8_lossy(&c.stderr)
    );
    assert!(
        said.contains("ok: unitree_g1_lstm") && said.contains(&control::nn::sha256_hex(&policy)),
        "{said}"
    );
    // It read the image's weights: without them it fails.
    std::fs::remove_file(unpacked.join("g1fw/shared/peer_policy/unitree_g1_lstm/policy.safetensors")).unwrap();
    let c = qemu(&g1fw, &["check-spec", "--spec", spec_arg], &dir);
    assert!(!c.status.success(), "check-spec passed without the image's weights");
}
