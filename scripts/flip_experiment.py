#!/usr/bin/env python3
"""The random-flip experiment of issue 22, through the command line as a user meets it.

Changes one random byte of a committed log N times and runs `g1fw replay`, `g1fw log-info` and
`g1fw plot` on each copy. Counts exit codes, aborts (killed by a signal, exit 101 = panic, 134 =
abort) and whether every tool named the log as damaged (exit 2 and "damaged" on stderr).

    scripts/flip_experiment.py [--flips 1000] [--seed 22] [--log tests/corpus/rl_lab_estop_29dof.mcap]

Needs a release build (`cargo build --release -p firmware`). Copies live under target/ so that
replay finds the spec the log pins (specs/... above the copy).
"""
import argparse
import collections
import json
import os
import random
import shutil
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--flips", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=22)
    ap.add_argument("--log", default="tests/corpus/rl_lab_estop_29dof.mcap")
    a = ap.parse_args()
    g1fw = os.path.join(ROOT, "target/release/g1fw")
    if not os.path.exists(g1fw):
        sys.exit(f"{g1fw} not found: run `cargo build --release -p firmware` first")
    good = open(os.path.join(ROOT, a.log), "rb").read()
    work = os.path.join(ROOT, "target/flip-experiment")
    shutil.rmtree(work, ignore_errors=True)
    os.makedirs(work)
    rng = random.Random(a.seed)
    codes = {t: collections.Counter() for t in ("replay", "log-info", "plot")}
    aborts, unnamed = [], []
    for i in range(a.flips):
        at = rng.randrange(len(good))
        new = rng.choice([b for b in range(256) if b != good[at]])
        data = bytearray(good)
        data[at] = new
        path = os.path.join(work, "flipped.mcap")
        open(path, "wb").write(data)
        for tool, args in (
            ("replay", ["replay", path]),
            ("log-info", ["log-info", path]),
            ("plot", ["plot", path, "--out", os.path.join(work, "p.png")]),
        ):
            p = subprocess.run([g1fw, *args], cwd=ROOT, capture_output=True, text=True)
            rc = p.returncode
            codes[tool][rc] += 1
            if rc < 0 or rc in (101, 134):
                aborts.append((i, at, tool, rc, p.stderr[-300:]))
            elif rc != 2 or "damaged" not in p.stderr.lower():
                unnamed.append((i, at, tool, rc, p.stderr[-300:]))
        if (i + 1) % 100 == 0:
            print(f"{i + 1}/{a.flips} flips: {len(aborts)} aborts, {len(unnamed)} not named as damaged",
                  file=sys.stderr)
    shutil.rmtree(work, ignore_errors=True)
    summary = {
        "log": a.log,
        "bytes": len(good),
        "flips": a.flips,
        "seed": a.seed,
        "exit_codes": {t: dict(sorted(c.items())) for t, c in codes.items()},
        "aborts_or_panics": len(aborts),
        "not_named_damaged": len(unnamed),
        "examples": [list(x) for x in (aborts + unnamed)[:5]],
    }
    print(json.dumps(summary, indent=2))
    sys.exit(1 if aborts or unnamed else 0)


if __name__ == "__main__":
    main()
