#!/usr/bin/env bash
# README command 1: install everything, build, and run the main job: this project's stair policy
# (specs/stairs/g1_stairs_lstm.toml, weights committed) walking the 29-dof G1 up a staircase and then
# down one, with perception in the loop (simulated MID-360 -> Livox packets -> BEV -> terrain CNN ->
# token -> policy -> PD), through the firmware's 500 Hz lock-stepped loop. Writes per staircase a
# JSON report and a picture of base height against distance with the steps drawn (out/demo_*).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
scripts/install.sh
echo "[demo] building (release)…" >&2
cargo build --release --workspace --bins
mkdir -p out
spec=specs/stairs/g1_stairs_lstm.toml
status=0
# The low staircases, then the 15 cm presets (docs/results.md): every run reports what
# happened.
for world in specs/worlds/stairs_up_low.toml specs/worlds/stairs_down_low.toml stairs-up stairs-down; do
  name=$(basename "$world" .toml)
  echo "[demo] $name: 29-dof G1, vx 0.5 m/s with heading hold, the terrain CNN's token" >&2
  target/release/g1fw sim --model g1-29dof --spec "$spec" --world "$world" --cmd 0.5,0,0 --heading 0 \
    --duration 20 --stop-after-landing 1 --seed 0 --report "out/demo_$name.json" \
    --profile-plot "out/demo_$name.png" "$@" || { rc=$?; [ "$rc" -eq 3 ] || status=$rc; }  # 3: a trip, reported below
  python3 - "out/demo_$name.json" <<'PY' || true
import json, sys
r = json.load(open(sys.argv[1]))
s = r.get("stairs") or {}
trip = (r.get("trip") or {}).get("reason", "none")
print(f"[demo]   {s.get('kind')}: {s.get('risers_passed')}/{s.get('risers')} risers, "
      f"landing reached: {s.get('reached_end_landing')}, success: {s.get('success')}, "
      f"fell: {r['fell']}, trip: {trip}", file=sys.stderr)
PY
done
echo "[demo] reports and profile plots in out/demo_{stairs_up_low,stairs_down_low,stairs-up,stairs-down}.{json,png}" >&2
exit $status
