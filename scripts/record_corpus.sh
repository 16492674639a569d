#!/usr/bin/env bash
# Re-records the replay regression corpus in tests/corpus/ (see its README).
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release -p firmware -p g1_sim --bins
G=target/release/g1fw
# g1fw sim exits 3 when a safety trip latched: the fault and e-stop runs record one on purpose.
tripped_ok() { "$@" || [ $? -eq 3 ]; }
out=tests/corpus
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
printf '0 0.3 0 0\n1.5 0.5 0 0.3\n' > "$tmp/steps.txt"
printf '0 0.3 0 0\n1.0 estop\n1.2 reset\n' > "$tmp/estop.txt"
$G sim --quiet --model g1-12dof --spec specs/peer/unitree_g1_lstm.toml --duration 3 \
  --cmd-schedule "$tmp/steps.txt" --log "$out/peer_walk_12dof.mcap" > /dev/null
tripped_ok $G sim --quiet --model g1-12dof --spec specs/peer/unitree_g1_lstm.toml --duration 2.5 \
  --fault corrupt@1.5+0.1 --log "$out/peer_crc_fault_12dof.mcap" > /dev/null
tripped_ok $G sim --quiet --model g1-29dof --spec specs/test/rl_lab_style.toml --duration 2 --keep-going \
  --cmd-schedule "$tmp/estop.txt" --log "$out/rl_lab_estop_29dof.mcap" > /dev/null
# Perception into the policy: lidar over the bridge, BEV, the built-in terrain CNN, the token decode
# (atan2 of a 25-degree yaw) and a spec that observes terrain_token. 0.8 s keeps it under 5 MB.
tripped_ok $G sim --quiet --model g1-29dof --spec specs/test/rl_lab_terrain.toml --duration 0.8 --ramp 0.3 --keep-going \
  --world specs/worlds/yawed_outdoor.toml --seed 0 --log "$out/rl_lab_terrain_cnn_29dof.mcap" > /dev/null
for f in "$out"/*.mcap; do
  $G replay "$f" > /dev/null
done
ls -la "$out"
