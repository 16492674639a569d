#!/usr/bin/env bash
# Runs the cargo-fuzz target for the Livox point-packet codec on stable Rust (RUSTC_BOOTSTRAP lets
# cargo-fuzz pass its -Z flags; no sanitizer, libFuzzer's coverage only).
#   scripts/fuzz.sh [SECONDS] [extra libFuzzer args...]     default 60 s
# Seeds the corpus with valid packets (zlib CRC-32 == the packet's CRC-32/ISO-HDLC) on first run.
set -euo pipefail
secs="${1:-60}"
shift || true
cd "$(dirname "$0")/../sensor_io"
command -v cargo-fuzz >/dev/null 2>&1 || cargo install cargo-fuzz
corpus=fuzz/corpus/livox_packet
if [ ! -d "$corpus" ] || [ -z "$(ls -A "$corpus")" ]; then
  mkdir -p "$corpus"
  python3 - "$corpus" <<'PY'
import struct, sys, zlib
out = sys.argv[1]
def packet(udp, frame, ts, pts, dtype=1, ti=4800):
    if dtype == 1:
        body = b"".join(struct.pack("<iiiBB", x, y, z, 10, 0) for x, y, z in pts)
    elif dtype == 2:
        body = b"".join(struct.pack("<hhhBB", x // 10, y // 10, z // 10, 10, 0) for x, y, z in pts)
    else:
        body = struct.pack("<6f", 0.01, -0.02, 0.0, 0.0, 0.0, -1.0)
        pts = [0]
    n = len(pts)
    tail = struct.pack("<Q", ts) + body
    return struct.pack("<BHHHHBBB12sI", 0, 36 + len(body), ti, n, udp, frame, dtype, 0, bytes(12),
                       zlib.crc32(tail)) + tail
pts = [(1000 + 37 * i, -500 + 11 * i, -300 + i) for i in range(96)]
seeds = {
    "high96": packet(0, 0, 10**9, pts),
    "high3": packet(1, 0, 10**9 + 480000, pts[:3]),
    "low4": packet(2, 1, 2 * 10**9, pts[:4], dtype=2),
    "imu": packet(3, 0, 3 * 10**9, [], dtype=0),
    "zero": packet(4, 1, 0, [(0, 0, 0), (50, 0, 0)]),
}
seeds["stream"] = seeds["high3"] + seeds["zero"] + seeds["imu"] + seeds["high3"]
for name, data in seeds.items():
    open(f"{out}/{name}", "wb").write(data)
PY
fi
RUSTC_BOOTSTRAP=1 cargo fuzz run livox_packet --sanitizer none -- -max_total_time="$secs" "$@"
