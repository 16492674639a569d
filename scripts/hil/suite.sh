#!/usr/bin/env bash
# The CAN hardware-in-loop suite. Runs inside the VM (User-Mode Linux or QEMU) booted by `cargo xtask hil`
# (as root, cwd = repository root, vcan0 and vcan1 up, env from the host in $HIL_DIR/env.sh).
#   1. smoke: the plumbing — can-utils and python-can round trips on both buses;
#   2. tests/hil/peer_test.py: the independent python-can peer drives g1fw and g1-can-emu.
set -euo pipefail

if [ -z "${HIL_DIR:-}" ] || ! ip link show vcan0 >/dev/null 2>&1; then
  echo "suite.sh runs inside the HIL VM: use \`cargo xtask hil\` (vcan0 and HIL_DIR are missing here)" >&2
  exit 2
fi
py=.venv/bin/python
t_suite=$(date +%s.%N)
since() { awk -v a="$1" -v b="$(date +%s.%N)" 'BEGIN { printf "%.2f", b - a }'; }
say() { printf '[suite] %s\n' "$*"; }

# --- 1. smoke -------------------------------------------------------------------------------------
t=$(date +%s.%N)
for bus in vcan0 vcan1; do
  for frame in "123#DEADBEEF" "7FF#0011223344556677" "001#"; do
    out="$HIL_DIR/smoke_$bus.txt"
    # candump -n 1 exits after one frame; wait until its socket is bound before sending
    # (a fixed sleep is not enough under emulation).
    candump -n 1 -T 10000 -L "$bus" >"$out" &
    pid=$!
    for _ in $(seq 1 200); do
      grep -qE "^ +$bus .* raw\$" /proc/net/can/rcvlist_all 2>/dev/null && break
      sleep 0.05
    done
    cansend "$bus" "$frame"
    wait "$pid" || { say "FAIL: candump on $bus got nothing for $frame"; exit 1; }
    got=$(awk '{print $3}' "$out")
    [ "$got" = "$frame" ] || { say "FAIL: sent $frame on $bus, candump saw '$got'"; exit 1; }
  done
  say "ok   can-utils round trip on $bus (3 frames: DLC 4, 8, 0; ids 0x001, 0x123, 0x7FF)"
done
say "smoke can-utils: $(since "$t") s"

t=$(date +%s.%N)
"$py" - <<'EOF'
import threading, time
import can

N = 1000
for bus_name in ("vcan0", "vcan1"):
    rx = can.Bus(interface="socketcan", channel=bus_name, receive_own_messages=False)
    tx = can.Bus(interface="socketcan", channel=bus_name)
    got = []
    ready = threading.Event()

    def reader():
        ready.set()
        while len(got) < N:
            m = rx.recv(timeout=10.0)
            if m is None:
                return
            got.append(m)

    th = threading.Thread(target=reader)
    th.start()
    ready.wait()  # the socket is bound at construction; this only orders the thread start
    t0 = time.monotonic()
    for i in range(N):
        tx.send(can.Message(arbitration_id=0x100 + (i % 0x7F), data=i.to_bytes(2, "big") + bytes(6), is_extended_id=False))
    th.join(30.0)
    dt = time.monotonic() - t0
    rx.shutdown()
    tx.shutdown()
    assert len(got) == N, f"{bus_name}: python-can received {len(got)} of {N} frames"
    for i, m in enumerate(got):
        assert m.arbitration_id == 0x100 + (i % 0x7F) and int.from_bytes(m.data[:2], "big") == i and m.dlc == 8, (
            f"{bus_name}: frame {i} is {m}")
    print(f"[suite] ok   python-can {N} frames in order on {bus_name} ({dt:.2f} s)")
EOF
say "smoke python-can: $(since "$t") s"

# --- 2. the python-can peer test ------------------------------------------------------------------
if [ "${HIL_SMOKE_ONLY:-0}" = 1 ]; then
  say "HIL_SMOKE_ONLY=1: skipping the peer test"
else
  # Every run starts its own g1-sim (under g1-can-emu); compile the model once per suite, not per
  # run (80-90 s each under QEMU's emulation, ~1 s on UML; g1-sim --help, G1_SIM_MODEL_CACHE).
  export G1_SIM_MODEL_CACHE="$HIL_DIR/model-cache"
  "$py" tests/hil/peer_test.py
fi
say "suite passed in $(since "$t_suite") s"
