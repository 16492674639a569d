#!/usr/bin/env bash
# README command 2 (and CI): install what is missing, then build and run every test.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
scripts/install.sh
start=$(date +%s)
cargo fmt --all -- --check
cargo clippy --release --workspace --all-targets -- -D warnings
# Integration tests start the g1fw and g1-sim binaries: build them first.
cargo build --release --workspace --bins
cargo test --release --workspace
echo "[test] all tests passed in $(( $(date +%s) - start )) s" >&2
