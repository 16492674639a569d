#!/usr/bin/env bash
# Runs the cargo-fuzz targets of fuzz/ (every decoder and parser; docs/reliability.md) on stable Rust:
# RUSTC_BOOTSTRAP lets cargo-fuzz pass its -Z flags; no sanitizer (libFuzzer's coverage only), but
# debug assertions and overflow checks on (-a), so arithmetic overflow is a crash too.
#   scripts/fuzz.sh [SECONDS] [TARGET...]     default: 600 s, every target
# Each target stops at FUZZ_RUNS executions (default 10,000,000) or SECONDS, whichever comes first,
# one target at a time. The committed seeds (fuzz/corpus/<target>) are read, never written: the grown
# corpus is fuzz/target/corpus/<target> (kept between runs), crashes go to fuzz/artifacts/<target>.
# Prints per target: executions, fuzzing time, exec/s, crashes, corpus size; the table is also in
# fuzz/target/fuzz-summary.md. Exits 1 if any target crashed.
set -euo pipefail
secs="${1:-600}"
shift || true
runs="${FUZZ_RUNS:-10000000}"
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
command -v cargo-fuzz >/dev/null 2>&1 || cargo install cargo-fuzz
mapfile -t all < <(sed -n 's/^name = "\(.*\)"$/\1/p' fuzz/Cargo.toml | grep -v '^g1-fuzz$')
targets=("$@")
(( ${#targets[@]} )) || targets=("${all[@]}")
for t in "${targets[@]}"; do
  printf '%s\n' "${all[@]}" | grep -qx "$t" || { echo "[fuzz] unknown target '$t' (have: ${all[*]})" >&2; exit 2; }
  [ -n "$(ls -A "fuzz/corpus/$t" 2>/dev/null)" ] || { echo "[fuzz] no seeds in fuzz/corpus/$t" >&2; exit 2; }
done
export RUSTC_BOOTSTRAP=1
flags=(-O -a --sanitizer none)
nice -n 10 cargo fuzz build "${flags[@]}"
summary=fuzz/target/fuzz-summary.md
mkdir -p fuzz/target
{
  echo "| target | executions | time | exec/s | crashes | corpus (seeds → final) |"
  echo "|---|---:|---:|---:|---:|---:|"
} >"$summary"
failed=0
for t in "${targets[@]}"; do
  work="fuzz/target/corpus/$t"
  art="fuzz/artifacts/$t"
  log="fuzz/target/fuzz-$t.log"
  mkdir -p "$work" "$art"
  seeds=$(ls "fuzz/corpus/$t" | wc -l)
  before=$(ls "$art" | wc -l)
  echo "[fuzz] $t: up to $runs executions or $secs s" >&2
  start=$(date +%s.%N)
  set +e
  nice -n 10 cargo fuzz run "${flags[@]}" "$t" "$work" "fuzz/corpus/$t" -- \
    -runs="$runs" -max_total_time="$secs" -timeout=10 -rss_limit_mb=2048 -print_final_stats=1 >"$log" 2>&1
  rc=$?
  set -e
  # Fuzzing time as libFuzzer reports it (cargo fuzz run may rebuild first); else the wall clock.
  wall=$(sed -n 's/^Done [0-9]* runs in \([0-9]*\) second.*/\1/p' "$log" | tail -1)
  [ -n "$wall" ] || wall=$(awk -v a="$start" -v b="$(date +%s.%N)" 'BEGIN { print b - a }')
  execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -1)
  rate=$(sed -n 's/^stat::average_exec_per_sec: *//p' "$log" | tail -1)
  crashes=$(( $(ls "$art" | wc -l) - before ))
  corpus=$(ls "$work" | wc -l)
  if (( rc != 0 )); then
    failed=1
    (( crashes > 0 )) || crashes="exit $rc"
    echo "[fuzz] $t FAILED (rc $rc); see $log and $art/" >&2
    grep -m5 -E "panicked|ERROR|SUMMARY" "$log" >&2 || true
  fi
  row=$(printf '| `%s` | %s | %.0f s | %s | %s | %s → %s |' "$t" "${execs:-?}" "$wall" "${rate:-?}" "$crashes" "$seeds" "$corpus")
  echo "$row" >>"$summary"
  echo "[fuzz] $row" >&2
done
cat "$summary"
exit "$failed"
