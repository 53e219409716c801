"""Places a packed pool takes per voxel of interest, and the time to pack it, for several windows of the first fit
(isplat.runsplace.pack_rows, PACK_WINDOW; docs/design.md "A packed pool"), on the runs each case of the
selective-read benchmark reads: the voxels loaded counted from the volumes, no file written.

    .venv/bin/python scripts/pool_pack.py [--quick] [--cases H1,E2,B1,H1-512,C1] [--windows 0,16,64,256,1024]

For each case (benchmarks.selective_read's volumes, transfer functions and bins, as scripts/position_forms.py),
the voxels of the runs meeting the scene's intervals (what post from the runs file loads) as a pool's rows (a
row of 512 places per 8^3 brick holding one, in brick order); per window, the packed pool's places per voxel of
interest (4 B a place held, shaded: density, normal, gradient magnitude) and the median of 7 packings' time.
Window 0 lays the rows one after the other (the pool before packing).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def loaded_rows(density: np.ndarray, intervals) -> np.ndarray:
    """The voxels of the runs meeting ``intervals`` as a pool's loaded bits (uint64, 8 words a row, row 0 none,
    the rows in brick order): what isplat.runsfile.RunsFile.place makes of them."""
    from isplat import runs as R

    lo, hi = R.union_key(density)
    cut = R.dp_cut(lo, hi, *R.DEFAULT_BINS)
    read = R.runs_meeting([tuple(iv) for iv in intervals], cut)[R.run_of(lo, hi, cut)]
    g = [-(-n // 8) for n in density.shape]
    pad = np.zeros([8 * n for n in g], bool)
    pad[tuple(slice(0, n) for n in density.shape)] = read
    bricks = pad.reshape(g[0], 8, g[1], 8, g[2], 8).transpose(0, 2, 4, 1, 3, 5).reshape(-1, 512)
    rows = bricks[bricks.any(axis=1)]
    bits = np.concatenate([np.zeros((1, 512), bool), rows]).reshape(-1)
    return np.packbits(bits, bitorder="little").view("<u8")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="scripts/pool_pack.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="volumes at 1/4 resolution")
    ap.add_argument("--cases", default="H1,E2,B1,H1-512,C1")
    ap.add_argument("--windows", default="0,16,64,256,1024")
    a = ap.parse_args(argv)
    from benchmarks.selective_read import cases
    from isplat.augfile import open_augmented
    from isplat.runsplace import pack_rows
    from position_forms import intervals_of

    windows = [int(w) for w in a.windows.split(",")]
    print("| case | voxels of interest | voxels loaded / of interest | rows | "
          + " | ".join(f"window {w}: places / of interest, ms" for w in windows) + " |")
    print("|---|---:|---:|---:|" + "---:|" * len(windows))
    pack_rows(np.zeros(16, np.uint64))                      # (compiled before the clock)
    with tempfile.TemporaryDirectory(prefix="isplat-pack-") as t:
        for case in cases(Path(t), a.quick, only=a.cases.split(",")):
            density = open_augmented(case["aug"]).read("density")
            ivs = intervals_of(case["tf"])
            voi = int(sum(np.count_nonzero((density >= lo) & (density <= hi)) for lo, hi in ivs))
            loaded = loaded_rows(density, ivs)
            n_loaded = int(np.unpackbits(loaded.view(np.uint8)).sum())
            cells = []
            for w in windows:
                times = []
                for _ in range(7):
                    t0 = time.perf_counter()
                    _, places = pack_rows(loaded, w)
                    times.append(time.perf_counter() - t0)
                cells.append(f"{places / voi:.3f}, {1000 * statistics.median(times):.2f}")
            print(f"| {case['name']} | {voi:,} | {n_loaded / voi:.3f} | {loaded.size // 8 - 1:,} | "
                  + " | ".join(cells) + " |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
