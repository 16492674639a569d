#!/bin/busybox sh
# /init of the QEMU HIL guest's initramfs (built by `cargo xtask hil`, see xtask/src/hil/qemu.rs).
# Not meant to run on a host.
#
# Debian's kernel has virtio, 9p and CAN as modules, and the host root is not a disk, so this small
# stage loads them from /lib/modules (flat, in dependency order as listed in /modules), mounts the host
# / read-only over virtio-9p (tag hostroot) and switches to it, running scripts/hil/guest_init.sh (the
# same init UML runs) as PID 1. Its failures are reported with the same console protocol:
#   HIL:ERROR <message>
B=/bin/busybox

fail() {
  echo "HIL:ERROR (initramfs) $*"
  $B sync
  echo o >/proc/sysrq-trigger
  $B sleep 10
  exit 1
}

$B mount -t proc proc /proc || fail "cannot mount /proc"
$B mount -t sysfs sysfs /sys || fail "cannot mount /sys"
$B mount -t devtmpfs devtmpfs /dev || fail "cannot mount /dev"
while read -r m; do
  [ -n "$m" ] || continue
  $B insmod "/lib/modules/$m.ko" || fail "insmod $m.ko failed"
done </modules
[ -n "${hil_init:-}" ] || fail "hil_init= missing from the kernel command line"
# cache=loose: the root is read-only for the whole run, so the guest may cache it (binaries and
# Python's modules load several times faster than with cache=none).
$B mount -t 9p -o trans=virtio,version=9p2000.L,ro,cache=loose,msize=262144 hostroot /newroot \
  || fail "cannot mount the host root (virtio-9p tag hostroot)"
[ -x "/newroot$hil_init" ] || fail "$hil_init not found on the host root"
$B umount /proc /sys
$B mount --move /dev /newroot/dev || fail "cannot move /dev to the new root"
exec $B switch_root /newroot "$hil_init"
