#!/bin/bash
# PID 1 of the HIL guest (see xtask/src/hil/). Not meant to run on a host. Both VMs run it:
#   - User-Mode Linux: the kernel starts it directly (root = the host / through hostfs);
#   - QEMU: scripts/hil/qemu_initramfs_init.sh loads the virtio, 9p and CAN modules, mounts the host /
#     over virtio-9p and switches to it, then execs this script.
#
# The host passes values on the kernel command line, which the kernel hands to init as environment
# variables: hil_vm (uml or qemu), hil_dir (a host directory, mounted read-write at the same path:
# hostfs in UML, the 9p tag "hildir" in QEMU; everything the host reads back lands there) and
# hil_repo (the repository root).
# Everything else (the suite to run, CI, PATH, …) comes from "$hil_dir/env.sh", written by the host.
#
# Protocol on the console (the UML process's stdout), read by the host:
#   HIL:VCAN_UP <guest uptime s>      vcan0..vcan3 are up
#   HIL:SUITE_START                   the suite's output follows (also in $hil_dir/suite.log)
#   HIL:SUITE_EXIT <status> <wall s>  the suite ended (also in $hil_dir/status)
#   HIL:ERROR <message>               the guest could not set itself up (also in $hil_dir/error)
# Then the guest powers off.
export PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin

poweroff() {
  sync
  echo o >/proc/sysrq-trigger
  sleep 10
  exit 1 # never reached: the kernel is gone
}

fail() {
  echo "HIL:ERROR $*"
  [ -n "${hil_dir:-}" ] && [ -w "${hil_dir}" ] && echo "$*" >"$hil_dir/error"
  poweroff
}

mount -t proc proc /proc || fail "cannot mount /proc"
mount -t sysfs sysfs /sys || fail "cannot mount /sys"
mount -t devtmpfs devtmpfs /dev 2>/dev/null || true # usually automounted (CONFIG_DEVTMPFS_MOUNT)
mkdir -p /dev/pts /dev/shm 2>/dev/null
mount -t devpts devpts /dev/pts 2>/dev/null || true
mount -t tmpfs -o mode=1777 tmpfs /dev/shm || fail "cannot mount /dev/shm"
mount -t tmpfs -o mode=755 tmpfs /run || fail "cannot mount /run"
# Scratch space is /run/tmp (TMPDIR, HOME), not a tmpfs over /tmp: the checkout (and ../shared beside
# it) may itself live under the host's /tmp, which the guest must still see.
mkdir -p -m 1777 /run/tmp || fail "cannot create /run/tmp"
export TMPDIR=/run/tmp

[ -n "${hil_dir:-}" ] || fail "hil_dir= missing from the kernel command line"
[ -n "${hil_repo:-}" ] || fail "hil_repo= missing from the kernel command line"
case "${hil_vm:-uml}" in
  uml) mount -t hostfs -o "$hil_dir" hostfs "$hil_dir" || fail "cannot mount the host directory $hil_dir (hostfs)" ;;
  qemu) mount -t 9p -o trans=virtio,version=9p2000.L,msize=262144 hildir "$hil_dir" \
    || fail "cannot mount the host directory $hil_dir (virtio-9p tag hildir)" ;;
  *) fail "unknown hil_vm=$hil_vm (uml or qemu)" ;;
esac
[ -f "$hil_dir/env.sh" ] || fail "$hil_dir/env.sh not found (written by cargo xtask hil)"

# CAN, in dependency order (can-raw and can-gw need can, vcan needs can-dev). can-gw lets a test put a
# gateway between the firmware's buses (vcan0/vcan1) and the emulator's (vcan2/vcan3), so it can talk
# to one side only. UML's modules ship with the UML kernel; QEMU's initramfs has loaded them already.
if [ "${hil_vm:-uml}" = uml ]; then
  kver=$(uname -r)
  moddir=/usr/lib/uml/modules/$kver/kernel
  for m in net/can/can.ko net/can/can-raw.ko net/can/can-gw.ko drivers/net/can/dev/can-dev.ko drivers/net/can/vcan.ko; do
    [ -f "$moddir/$m" ] || fail "kernel module $moddir/$m not found (package user-mode-linux for kernel $kver)"
    insmod "$moddir/$m" || fail "insmod $moddir/$m failed"
  done
fi
ip link set lo up
for dev in vcan0 vcan1 vcan2 vcan3; do
  ip link add dev "$dev" type vcan || fail "ip link add $dev type vcan failed"
  ip link set "$dev" up || fail "ip link set $dev up failed"
done
# vcan has no flow control: a slow reader loses frames once its receive buffer is full.
sysctl -q -w net.core.rmem_max=16777216 net.core.rmem_default=8388608 net.core.wmem_max=16777216 \
  || fail "cannot raise the socket buffer limits"
read -r up _ </proc/uptime
echo "HIL:VCAN_UP $up"
echo "$up" >"$hil_dir/vcan_up_uptime"

# shellcheck source=/dev/null
. "$hil_dir/env.sh"
cd "$hil_repo" || fail "cannot cd to $hil_repo"
echo "HIL:SUITE_START"
start=$(cut -d' ' -f1 /proc/uptime)
set -o pipefail
"${HIL_SUITE[@]}" 2>&1 </dev/null | tee "$hil_dir/suite.log"
status=$?
end=$(cut -d' ' -f1 /proc/uptime)
wall=$(awk -v a="$start" -v b="$end" 'BEGIN { printf "%.2f", b - a }')
echo "$status $wall" >"$hil_dir/status"
echo "HIL:SUITE_EXIT $status $wall"
poweroff
