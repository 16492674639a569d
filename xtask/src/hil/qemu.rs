//! The HIL's second VM: QEMU in software emulation (TCG), for hosts where User-Mode Linux cannot boot
//! (on an AMX Xeon with kernel 6.18, Debian's UML 6.1 dies at once with "ptrace set fp regs failed").
//!
//! Everything comes from Debian's packages, unpacked by `scripts/install.sh` into `.deps/hil-qemu/`
//! (not installed, so the host's packages are untouched): `root/` holds qemu-system-x86 with its
//! firmware and the libraries the host lacks, and busybox-static; `kernel/` holds Debian's kernel
//! (`boot/vmlinuz-*`) and only the modules the guest loads. The guest boots a small initramfs built
//! here (busybox, those modules, `scripts/hil/qemu_initramfs_init.sh` as `/init`), which mounts the
//! host `/` read-only over virtio-9p and switches to it, running `scripts/hil/guest_init.sh` as UML
//! does. The run directory is a second, writable 9p share (tag `hildir`).
use super::cpio::{self, Entry};
use anyhow::{bail, Context, Result};
use std::fs;
use std::path::{Path, PathBuf};
use std::process::Command;

/// The modules the guest loads, in dependency order (`modinfo -F depends` on Debian's 6.1 kernel):
/// PCI virtio, the 9p filesystem over it, then CAN and vcan.
const MODULES: &[&str] = &[
    "drivers/virtio/virtio_ring",
    "drivers/virtio/virtio",
    "drivers/virtio/virtio_pci_modern_dev",
    "drivers/virtio/virtio_pci_legacy_dev",
    "drivers/virtio/virtio_pci",
    "fs/netfs/netfs",
    "fs/fscache/fscache",
    "net/9p/9pnet",
    "net/9p/9pnet_virtio",
    "fs/9p/9p",
    "net/can/can",
    "net/can/can-raw",
    "net/can/can-gw",
    "drivers/net/can/dev/can-dev",
    "drivers/net/can/vcan",
];

/// What `scripts/install.sh` unpacked.
pub struct Qemu {
    dir: PathBuf,
    binary: PathBuf,
    kernel: PathBuf,
    modules: PathBuf,
}

impl Qemu {
    /// Finds the unpacked QEMU set, or says how to get it.
    pub fn find(repo: &Path) -> Result<Qemu> {
        let dir = repo.join(".deps/hil-qemu");
        let fix = "run scripts/install.sh (it unpacks Debian's qemu-system-x86, kernel and busybox-static there)";
        if !dir.join("ready").is_file() {
            bail!("{} is missing or incomplete: {fix}", dir.display());
        }
        let binary = dir.join("root/usr/bin/qemu-system-x86_64");
        if !binary.is_file() {
            bail!("{} not found: {fix}", binary.display());
        }
        let boot = dir.join("kernel/boot");
        let kernel = fs::read_dir(&boot)
            .with_context(|| format!("reading {}: {fix}", boot.display()))?
            .flatten()
            .map(|e| e.path())
            .find(|p| {
                p.file_name()
                    .is_some_and(|n| n.to_string_lossy().starts_with("vmlinuz-"))
            })
            .with_context(|| format!("no vmlinuz-* in {}: {fix}", boot.display()))?;
        let ver = kernel.file_name().unwrap_or_default().to_string_lossy()["vmlinuz-".len()..].to_string();
        let modules = dir.join("kernel/lib/modules").join(&ver);
        if !modules.is_dir() {
            bail!("no modules for kernel {ver} in {}: {fix}", modules.display());
        }
        if !dir.join("root/bin/busybox").is_file() {
            bail!("{} not found: {fix}", dir.join("root/bin/busybox").display());
        }
        Ok(Qemu {
            dir,
            binary,
            kernel,
            modules,
        })
    }

    fn lib_path(&self) -> String {
        let r = self.dir.join("root");
        format!(
            "{}:{}",
            r.join("usr/lib/x86_64-linux-gnu").display(),
            r.join("lib/x86_64-linux-gnu").display()
        )
    }

    /// The guest's initramfs: busybox, the modules (flat, with `/modules` listing their load order),
    /// the init script, and the mount points it needs.
    pub fn initramfs(&self, init_script: &Path) -> Result<Vec<u8>> {
        let busybox = fs::read(self.dir.join("root/bin/busybox")).context("reading busybox")?;
        let init = fs::read(init_script).with_context(|| format!("reading {}", init_script.display()))?;
        let builtin = fs::read_to_string(self.modules.join("modules.builtin")).unwrap_or_default();
        let mut kos: Vec<(String, Vec<u8>)> = Vec::new();
        for m in MODULES {
            let rel = format!("kernel/{m}.ko");
            let path = self.modules.join(&rel);
            match fs::read(&path) {
                Ok(b) => kos.push((m.rsplit('/').next().unwrap_or(m).to_string(), b)),
                // A later Debian kernel may build one of them in: nothing to load then.
                Err(_) if builtin.lines().any(|l| l == rel) => {}
                Err(e) => bail!(
                    "{}: {e}; the kernel in .deps/hil-qemu lacks a module the guest needs \
                     (rm -rf .deps/hil-qemu and run scripts/install.sh again)",
                    path.display()
                ),
            }
        }
        let order: String = kos.iter().map(|(n, _)| format!("{n}\n")).collect();
        let names: Vec<String> = kos.iter().map(|(n, _)| format!("lib/modules/{n}.ko")).collect();
        let mut entries = vec![
            Entry::Dir("bin"),
            Entry::Dir("dev"),
            Entry::CharDev("dev/console", 0o600, 5, 1),
            Entry::Dir("proc"),
            Entry::Dir("sys"),
            Entry::Dir("newroot"),
            Entry::Dir("lib"),
            Entry::Dir("lib/modules"),
            Entry::File("bin/busybox", 0o755, &busybox),
            Entry::File("init", 0o755, &init),
            Entry::File("modules", 0o644, order.as_bytes()),
        ];
        for ((_, b), name) in kos.iter().zip(&names) {
            entries.push(Entry::File(name, 0o644, b));
        }
        Ok(cpio::archive(&entries))
    }

    /// The QEMU command: one vCPU (two on a two-core host were ten times slower), `pc` machine (never
    /// hung at boot, unlike `microvm`), the host `/` read-only and the run directory read-write over
    /// virtio-9p, the serial console on stdout, no network, no reboot (a guest panic ends QEMU).
    pub fn command(&self, mem: &str, initrd: &Path, run_dir: &Path, append: &str) -> Command {
        let share = self.dir.join("root/usr/share");
        let mut c = Command::new(&self.binary);
        c.env("LD_LIBRARY_PATH", self.lib_path())
            .arg("-L")
            .arg(share.join("qemu"))
            .arg("-L")
            .arg(share.join("seabios"))
            // -cpu max: the MuJoCo library and our binaries need AVX (qemu64 dies with SIGILL).
            .args([
                "-M",
                "pc",
                "-accel",
                "tcg,tb-size=256",
                "-cpu",
                "max",
                "-smp",
                "1",
                "-m",
            ])
            .arg(mem)
            .args(["-nodefaults", "-no-user-config", "-display", "none", "-no-reboot"])
            .args(["-chardev", "stdio,id=console,signal=off", "-serial", "chardev:console"])
            .args(["-monitor", "none", "-nic", "none"])
            .arg("-kernel")
            .arg(&self.kernel)
            .arg("-initrd")
            .arg(initrd)
            .arg("-append")
            .arg(append)
            .args([
                "-fsdev",
                "local,id=hostroot,path=/,security_model=none,readonly=on,multidevs=remap",
            ])
            .args(["-device", "virtio-9p-pci,fsdev=hostroot,mount_tag=hostroot"])
            .arg("-fsdev")
            // A comma inside an option value is written twice.
            .arg(format!(
                "local,id=hildir,path={},security_model=none",
                run_dir.display().to_string().replace(',', ",,")
            ))
            .args(["-device", "virtio-9p-pci,fsdev=hildir,mount_tag=hildir"]);
        c
    }
}
