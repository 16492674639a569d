#!/usr/bin/env bash
# Installs everything the project needs on a fresh Debian machine (idempotent):
#   apt packages, a Python venv with the test-side tools, MuJoCo 3.17.0 (library + headers from the
#   pinned PyPI wheel) and the 29-dof G1 MJCF + meshes from the pinned mjlab wheel, both sha256-checked.
# Everything lands in .deps/ and .venv/ inside the checkout; nothing is copied from ../shared.
#
#   scripts/install.sh              everything
#   scripts/install.sh --for-build  only what `cargo build` needs (the C toolchain, Rust's aarch64
#                                   target, MuJoCo), so scripts/test.sh can start compiling while a
#                                   second call fetches the rest (test tools, models, the HIL's QEMU)
set -euo pipefail
for_build=0
case "${1:-}" in
  "") ;;
  --for-build) for_build=1 ;;
  *) echo "usage: $0 [--for-build]" >&2; exit 2 ;;
esac
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
deps="$root/.deps"
mkdir -p "$deps"

say() { printf '[install] %s\n' "$*" >&2; }

# --- apt -----------------------------------------------------------------------------------------
# user-mode-linux, kmod, iproute2, can-utils: the CAN HIL VM (`cargo xtask hil`; the host kernel has no CAN)
# gcc-aarch64-linux-gnu, libc6-dev-arm64-cross, qemu-user: the robot's CPU (`cargo xtask cross-replay`, `image`)
# tmux: the keyboard operator's test drives `g1fw run --keyboard` in a pane (tests/tests/keyboard_tmux.rs)
# libddsc0debian, cyclonedds-dev, cyclonedds-tools: CycloneDDS 0.10.2, the robot's DDS, as the
#   independent peer of `g1fw run --dds` (tests/tests/dds_peer.rs builds its C peer with idlc + gcc)
# The first line is what `cargo build` and the MuJoCo download need; the rest only the tests need.
apt_pkgs=(build-essential pkg-config python3 python3-venv python3-pip unzip ca-certificates)
((for_build)) || apt_pkgs+=(fonts-dejavu-core
  user-mode-linux kmod iproute2 can-utils
  gcc-aarch64-linux-gnu libc6-dev-arm64-cross qemu-user
  libddsc0debian cyclonedds-dev cyclonedds-tools
  tmux)
missing=()
for p in "${apt_pkgs[@]}"; do dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p"); done
if ((${#missing[@]})); then
  say "apt: installing ${missing[*]}"
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${missing[@]}" >/dev/null
fi

# --- Rust ----------------------------------------------------------------------------------------
if ! command -v cargo >/dev/null 2>&1; then
  echo "error: cargo not found. Install Rust stable (>= 1.95, e.g. with rustup) and re-run $0." >&2
  exit 1
fi
# The robot's target (aarch64) for the cross-replay and the deploy image.
aarch64_std="$(rustc --print sysroot)/lib/rustlib/aarch64-unknown-linux-gnu/lib"
if [ ! -d "$aarch64_std" ]; then
  if command -v rustup >/dev/null 2>&1; then
    say "rust: adding the aarch64-unknown-linux-gnu target"
    rustup target add aarch64-unknown-linux-gnu
  else
    echo "error: the Rust target aarch64-unknown-linux-gnu is missing and rustup is not here to add it;" \
      "install its standard library with your Rust toolchain and re-run $0." >&2
    exit 1
  fi
fi

# --- Python venv (test-side tools only; the firmware never needs Python) --------------------------
py="$root/.venv/bin/python"
if [ ! -x "$py" ]; then
  say "python: creating .venv"
  /usr/bin/env python3 -m venv "$root/.venv"
fi
if ((!for_build)) && ! "$py" -c 'import numpy, safetensors, onnx, onnxruntime, mcap, can, cyclonedds.idl' 2>/dev/null; then
  say "python: installing test tools into .venv"
  "$py" -m pip install -q --disable-pip-version-check -r "$root/scripts/requirements.txt"
fi

# --- pinned wheels ------------------------------------------------------------------------------
fetch_wheel() { # name==version sha256 python-tag platform
  local spec="$1" sha="$2" dir="$deps/wheels"
  mkdir -p "$dir"
  local f
  f=$(ls "$dir"/"${spec%%==*}"-"${spec##*==}"-*.whl 2>/dev/null | head -n1 || true)
  if [ -z "$f" ]; then
    say "downloading $spec"
    "$py" -m pip download -q --disable-pip-version-check --no-deps --only-binary=:all: "${@:3}" -d "$dir" "$spec"
    f=$(ls "$dir"/"${spec%%==*}"-"${spec##*==}"-*.whl | head -n1)
  fi
  local got
  got=$(sha256sum "$f" | cut -d' ' -f1)
  if [ "$got" != "$sha" ]; then
    echo "error: $f has sha256 $got, expected $sha; delete it and re-run." >&2
    exit 1
  fi
  echo "$f"
}

mj_whl=$(fetch_wheel mujoco==3.17.0 d66928d86a2d1b601bbaa4dc11db50214d17d5301bb8afd84721313b67ff0874 \
  --python-version 3.11 --implementation cp --abi cp311 --platform manylinux_2_28_x86_64)
if [ ! -f "$deps/mujoco/lib/libmujoco.so.3.17.0" ]; then
  say "unpacking MuJoCo 3.17.0 library and headers"
  rm -rf "$deps/mujoco" "$deps/tmp" && mkdir -p "$deps/mujoco/lib" "$deps/tmp"
  unzip -q -o "$mj_whl" 'mujoco/libmujoco.so.3.17.0' 'mujoco/include/*' -d "$deps/tmp"
  mv "$deps/tmp/mujoco/libmujoco.so.3.17.0" "$deps/mujoco/lib/"
  mv "$deps/tmp/mujoco/include" "$deps/mujoco/include"
  ln -sf libmujoco.so.3.17.0 "$deps/mujoco/lib/libmujoco.so"
  rm -rf "$deps/tmp"
fi

if ((for_build)); then
  say "ready to build (MuJoCo in .deps/mujoco); the rest comes with scripts/install.sh"
  exit 0
fi

mjlab_whl=$(fetch_wheel mjlab==1.6.0 03d003854e2f44c48330c6dcf4c2253ff7641bb569747846825a21b9efa8540b)
if [ ! -f "$deps/g1_29dof/g1.xml" ]; then
  say "extracting the 29-dof G1 MJCF and meshes from mjlab 1.6.0"
  rm -rf "$deps/g1_29dof" "$deps/tmp" && mkdir -p "$deps/tmp"
  unzip -q -o "$mjlab_whl" 'mjlab/asset_zoo/robots/unitree_g1/xmls/*' -d "$deps/tmp"
  mv "$deps/tmp/mjlab/asset_zoo/robots/unitree_g1/xmls" "$deps/g1_29dof"
  rm -rf "$deps/tmp"
fi
# --- Unitree's simulator as a test peer (tests/tests/unitree_mujoco.rs) ---------------------------
# unitree_mujoco's simulate_python and unitree_sdk2py (read in place from ../shared/peers) want the
# Python cyclonedds 0.10.x: no wheel exists for this Python, so its sdist (sha256-pinned) is built
# against Debian's cyclonedds-dev 0.10.2, through a prefix that lays Debian's files out as its build
# looks for them. Its own venv: the test tools' venv holds cyclonedds 11 (the CDR codec's peer).
uvenv="$root/.venv-unitree"
upy="$uvenv/bin/python"
if ! "$upy" -c 'import cyclonedds.domain, mujoco, pygame, numpy' 2>/dev/null; then
  say "python: building .venv-unitree (CycloneDDS 0.10.2 for Python, MuJoCo 3.17.0, pygame) for Unitree's simulator"
  [ -x "$upy" ] || /usr/bin/env python3 -m venv "$uvenv"
  prefix="$deps/cyclonedds-prefix"
  mkdir -p "$prefix"
  ln -sfn /usr/include "$prefix/include"
  ln -sfn /usr/bin "$prefix/bin"
  ln -sfn "/usr/lib/$(gcc -print-multiarch)" "$prefix/lib"
  sdist="$deps/wheels/cyclonedds-0.10.2.tar.gz"
  if [ ! -f "$sdist" ]; then
    CYCLONEDDS_HOME="$prefix" "$upy" -m pip download -q --disable-pip-version-check --no-deps --no-binary=:all: \
      -d "$deps/wheels" cyclonedds==0.10.2
  fi
  got=$(sha256sum "$sdist" | cut -d' ' -f1)
  if [ "$got" != f834962eabbdcdf4e9cd75cf87222f3c5ef22d9cb9e7ed651d9a8710fe984a30 ]; then
    echo "error: $sdist has sha256 $got, not the pinned cyclonedds 0.10.2 sdist's; delete it and re-run." >&2
    exit 1
  fi
  CYCLONEDDS_HOME="$prefix" "$upy" -m pip install -q --disable-pip-version-check "$sdist" numpy pygame "$mj_whl"
fi

# --- the CAN HIL's second VM: QEMU software emulation -------------------------------------------
# User-Mode Linux does not boot on every CPU of our machines (on an AMX Xeon it dies at once with
# "ptrace set fp regs failed"), so `cargo xtask hil` falls back to QEMU (ARCHITECTURE.md, "The HIL VM"): Debian's
# qemu-system-x86 (+ -common: TCG is a loadable module), its kernel (vmlinuz + the virtio/9p/CAN modules) and busybox-static, unpacked from
# their .debs into .deps/hil-qemu/ rather than installed (`apt-get install qemu-system-x86` would
# remove the preinstalled backports qemu-utils 10.0). Libraries the host already has are not fetched.
qdir="$deps/hil-qemu"
if [ ! -f "$qdir/ready" ]; then
  say "HIL: fetching QEMU, a Debian kernel and busybox into .deps/hil-qemu (about 85 MB)"
  rm -rf "$qdir" && mkdir -p "$qdir/debs" "$qdir/root" "$qdir/kernel"
  installed() { [ "$(dpkg-query -W -f='${Status}' "$1" 2>/dev/null)" = "install ok installed" ]; }
  lib_deps() { # the lib* packages $1 depends on that this host lacks
    apt-cache depends --no-recommends --no-suggests --no-conflicts --no-breaks --no-replaces --no-enhances "$1" \
      | awk '/^ *\|?(Pre)?Depends: lib/ && !/</ {print $2}' | sort -u \
      | while read -r d; do installed "$d" || echo "$d"; done
  }
  kpkg=$(apt-cache depends linux-image-amd64 | awk '/Depends: linux-image-[0-9]/ {print $2; exit}')
  [ -n "$kpkg" ] || { echo "error: apt knows no linux-image-amd64 kernel; run apt-get update and re-run $0." >&2; exit 1; }
  l1=$(lib_deps qemu-system-x86)
  l2=$(for d in $l1; do lib_deps "$d"; done | sort -u)
  pkgs=(qemu-system-x86 qemu-system-common qemu-system-data seabios busybox-static "$kpkg" $l1 $l2)
  fetch() { (cd "$qdir/debs" && apt-get download -q -o APT::Sandbox::User=root "${pkgs[@]}" >/dev/null); }
  if ! fetch; then
    SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    $SUDO apt-get update -qq && fetch
  fi
  for deb in "$qdir"/debs/*.deb; do
    case "$(basename "$deb")" in
      linux-image-*) # the kernel and only the modules the guest loads (docs/hil.md lists them)
        dpkg-deb --fsys-tarfile "$deb" | tar -x -C "$qdir/kernel" --wildcards './boot/vmlinuz-*' \
          './lib/modules/*/kernel/drivers/virtio/virtio*.ko' './lib/modules/*/kernel/net/9p/9pnet*.ko' \
          './lib/modules/*/kernel/fs/9p/*' './lib/modules/*/kernel/fs/netfs/*' './lib/modules/*/kernel/fs/fscache/*' \
          './lib/modules/*/kernel/net/can/can*.ko' './lib/modules/*/kernel/drivers/net/can/vcan.ko' \
          './lib/modules/*/kernel/drivers/net/can/dev/*' './lib/modules/*/modules.builtin' ;;
      *) dpkg-deb -x "$deb" "$qdir/root" ;;
    esac
  done
  rm -rf "$qdir/debs"
  ld="$qdir/root/usr/lib/x86_64-linux-gnu:$qdir/root/lib/x86_64-linux-gnu"
  missing_libs=$(LD_LIBRARY_PATH="$ld" ldd "$qdir/root/usr/bin/qemu-system-x86_64" | awk '/not found/ {print $1}' | sort -u)
  if [ -n "$missing_libs" ]; then
    echo "error: the unpacked qemu-system-x86_64 lacks libraries: $missing_libs; install the packages that provide them" \
      "(apt-get install ...) and re-run $0." >&2
    exit 1
  fi
  LD_LIBRARY_PATH="$ld" "$qdir/root/usr/bin/qemu-system-x86_64" --version | head -n1 >"$qdir/qemu_version"
  echo "$kpkg" >"$qdir/kernel_package"
  touch "$qdir/ready"
  say "HIL: $(cat "$qdir/qemu_version"), kernel $kpkg"
fi

say "dependencies ready in .deps/ and .venv/"
