#!/usr/bin/env bash
# README command 1: install everything, build, and run the sim-to-sim demo on the 29-dof G1:
# the peer walking policy at 0.5 m/s for 20 s when ../shared is beside the checkout, otherwise the
# firmware ramps to and holds the default pose (and says how to give it a policy).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
scripts/install.sh
echo "[demo] building (release)…" >&2
cargo build --release --workspace --bins
mkdir -p out
weights="${G1_SHARED_DIR:-$root/../shared}/peer_policy/unitree_g1_lstm/policy.safetensors"
if [ -f "$weights" ]; then
  echo "[demo] peer policy found: walking the 29-dof G1 at vx 0.5 m/s for 20 s" >&2
  target/release/g1fw sim --model g1-29dof --spec specs/peer/unitree_g1_lstm.toml --cmd 0.5,0,0 \
    --duration 20 --seed 0 --report out/demo_report.json "$@"
else
  echo "[demo] no policy: $weights is missing (../shared is not beside this checkout)." >&2
  echo "[demo] holding the default pose instead. To walk, put ../shared beside the checkout or pass" >&2
  echo "[demo]   target/release/g1fw sim --spec YOUR_SPEC.toml   (see specs/ for the format)" >&2
  target/release/g1fw sim --model g1-29dof --spec specs/peer/unitree_g1_lstm.toml --hold --ramp 2 --duration 10 \
    --report out/demo_report.json "$@"
fi
echo "[demo] report written to out/demo_report.json" >&2
