"""Bytes of the runs file's positions in each form, on the runs each case of the selective-read benchmark reads
(formats/runs.md §4, docs/design.md "Positions as nested masks"): a count from the volumes, no file written.

    .venv/bin/python scripts/position_forms.py [--quick] [--cases H1,E2,B1,H1-512,C1]

For each case (benchmarks.selective_read's volumes, transfer functions and bins: the union key, dp8x8), the
(run, brick) pairs of the runs meeting the scene's intervals, with c voxels of the run in P planes (dk) and W rows
(dk, dj) of the brick; per pair:
- ``v1``: format version 1, c uint16 places up to 32 voxels, else a 64-byte bitmap;
- ``masks``: format version 2, nested masks, 1 + P + W bytes;
- ``rows``: a list up to 6 voxels (its best threshold), else an 8-byte mask of the 64 rows and a byte a row;
- ``best``: the fewest of v1 and masks per pair (a form byte not counted: a bound, not a layout).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import tomllib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def intervals_of(tf_toml: str) -> np.ndarray:
    """The inclusive code intervals of non-zero opacity of a ``[transfer]`` table (as isplat.transfer makes them)."""
    from isplat.transfer import nonzero_intervals, piecewise_linear

    t = tomllib.loads(tf_toml)["transfer"]
    opacity = np.clip(piecewise_linear(t["opacity"], np.arange(256.0), outside_zero=True)[:, 0], 0.0, 1.0)
    return nonzero_intervals(opacity)


def pair_counts(density: np.ndarray, intervals) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per (run, brick) pair of the runs meeting ``intervals``: its voxels, planes and rows (int64 each)."""
    from isplat import runs as R

    lo, hi = R.union_key(density)
    cut = R.dp_cut(lo, hi, *R.DEFAULT_BINS)
    run = R.run_of(lo, hi, cut)
    del lo, hi
    read = R.runs_meeting([tuple(iv) for iv in intervals], cut)[run]
    k, j, i = (x.astype(np.int64) for x in np.nonzero(read))
    r = run[read].astype(np.int64)
    _, gj, gi = R.brick_grid(density.shape)
    pair = r * (1 << 40) + (k // 8 * gj + j // 8) * gi + i // 8
    u, c = np.unique(pair, return_counts=True)
    planes = np.bincount(np.searchsorted(u, np.unique(pair * 8 + k % 8) // 8), minlength=u.size)
    rows = np.bincount(np.searchsorted(u, np.unique(pair * 64 + (k % 8) * 8 + j % 8) // 64), minlength=u.size)
    return c, planes, rows


def forms(c, planes, rows) -> dict:
    v1 = np.where(c <= 32, 2 * c, 64)
    masks = 1 + planes + rows
    return dict(v1=int(v1.sum()), masks=int(masks.sum()), rows=int(np.where(c <= 6, 2 * c, 8 + rows).sum()),
                best=int(np.minimum(v1, masks).sum()))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="scripts/position_forms.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="volumes at 1/4 resolution")
    ap.add_argument("--cases", default="H1,E2,B1,H1-512,C1")
    a = ap.parse_args(argv)
    from benchmarks.selective_read import cases
    from isplat.augfile import open_augmented

    print("| case | pairs read | voxels read | v1 (B) | masks (B) | masks / v1 | rows (B) | best of v1, masks (B) |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    with tempfile.TemporaryDirectory(prefix="isplat-forms-") as t:
        for case in cases(Path(t), a.quick, only=a.cases.split(",")):
            density = open_augmented(case["aug"]).read("density")
            c, planes, rows = pair_counts(density, intervals_of(case["tf"]))
            f = forms(c, planes, rows)
            print(f"| {case['name']} | {c.size:,} | {int(c.sum()):,} | {f['v1']:,} | {f['masks']:,} | "
                  f"{f['masks'] / f['v1']:.3f} | {f['rows']:,} | {f['best']:,} |", flush=True)
            if case["aug"].parent == Path(t):
                case["aug"].unlink()
    return 0


if __name__ == "__main__":
    sys.exit(main())
