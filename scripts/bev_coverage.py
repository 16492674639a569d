#!/usr/bin/env python3
"""Where the lidar sees the ground: share of BEV cells holding points, by distance from the robot.

Reads `g1-dataset export` shards (tensor `bev`: N x 6 x 60 x 60, channel 5 = density) and prints the
occupied share of cells per 10 cm ring around the robot and along the strip |y| < 0.4 m ahead and
behind. The torso-mounted, upside-down MID-360 looks at most ~52 deg down, so the ground within about
0.8 m of the robot is never in a frame: risers there are invisible to a single-frame grid. Exports
with the BEV memory (the default) fill that disc from keyframes taken on the approach; compare with
an export rendered with memory off.

    .venv/bin/python scripts/bev_coverage.py DATASET_DIR [--max-shards N]
"""
import argparse
import pathlib
import sys

import numpy as np
from safetensors.numpy import load_file

CELLS, CELL_M, HALF_M, DENSITY = 60, 0.05, 1.5, 5


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("dataset", type=pathlib.Path, help="a g1-dataset export directory")
    ap.add_argument("--max-shards", type=int, default=2)
    a = ap.parse_args()
    shards = sorted(a.dataset.glob("shard-*.safetensors"))[: a.max_shards]
    if not shards:
        print(f"error: no shard-*.safetensors in {a.dataset} (make one with g1-dataset export)", file=sys.stderr)
        return 2
    occ = np.concatenate([load_file(str(s))["bev"][:, DENSITY] > 0 for s in shards]).mean(axis=0)
    centres = (np.arange(CELLS) + 0.5) * CELL_M - HALF_M
    x, y = np.meshgrid(centres, centres, indexing="ij")  # row = x (forward), column = y (left)
    r = np.hypot(x, y)
    print(f"{len(shards)} shard(s); occupied share of cells")
    print("ring around the robot:")
    for lo in np.arange(0.0, 1.5, 0.1):
        ring = (r >= lo) & (r < lo + 0.1)
        print(f"  r {lo:.1f}-{lo + 0.1:.1f} m  {100 * occ[ring].mean():5.1f} %")
    print("strip |y| < 0.4 m, by x (negative: behind):")
    for lo in np.arange(-1.5, 1.5, 0.1):
        strip = (x >= lo) & (x < lo + 0.1) & (np.abs(y) < 0.4)
        print(f"  x {lo:+.1f}..{lo + 0.1:+.1f} m  {100 * occ[strip].mean():5.1f} %")
    return 0


if __name__ == "__main__":
    sys.exit(main())
