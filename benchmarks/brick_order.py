"""The order of the bricks in the brick store, by the pages a scene touches: ``python -m benchmarks.brick_order
[--quick] [--cases H1,E2,...]`` prints a table (not a docs page).

Augmented format 6 stores each channel's 8^3 bricks in C order of the brick grid (formats/augmented.md §2.3), so
the bricks sharing a 4 KB page of the density (512 B a brick) are 8 neighbours along i: a page holds a 64 x 8 x 8
block of voxels. For the bricks post reads for each case of :mod:`benchmarks.selective_read` (its scene, first
view: :func:`isplat.selection.post_bricks`), this counts the distinct 4 KB pages of the channels' bricks (the
hashes left out) in that order, in Morton (Z) order of the grid (a page of the density: a 16^3 block), and with the
three channels interleaved per brick (2 KB a brick, in either order), against the bytes of the bricks alone. A
count, not a timing: what a layout would touch, before changing the format.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

from isplat.fileio import PAGE



def morton_rank(grid) -> np.ndarray:
    """int64 over the grid's bricks in C order: each brick's place in Morton order (the bits of k, j, i
    interleaved, k highest).

    >>> morton_rank((2, 2, 2)).tolist()
    [0, 1, 2, 3, 4, 5, 6, 7]
    >>> morton_rank((1, 2, 4)).tolist()          # (j, i): 0 1 | 4 5 over 2 3 | 6 7, ranked
    [0, 1, 4, 5, 2, 3, 6, 7]
    """
    ix = np.argwhere(np.ones(tuple(grid), dtype=bool)).astype(np.int64)
    code = np.zeros(len(ix), np.int64)
    for bit in range(int(max(grid)).bit_length()):
        for d in range(3):
            code |= ((ix[:, d] >> bit) & 1) << (3 * bit + (2 - d))
    rank = np.empty(len(ix), np.int64)
    rank[np.argsort(code, kind="stable")] = np.arange(len(ix))
    return rank


def pages(rows: np.ndarray, size: int) -> int:
    """Distinct pages that rows ``rows`` of ``size`` bytes each (from offset 0) lie in, as isplat counts the
    pages of its reads (:class:`isplat.fileio.ReadCounter`).

    >>> pages(np.array([0, 1, 8, 9]), 512), pages(np.array([0, 1]), 2048), pages(np.array([1]), 4096)
    (2, 1, 1)
    """
    from isplat.fileio import ReadCounter

    c = ReadCounter()
    c.touch_rows(0, size, rows)
    return c.page_bytes() // PAGE


def figures(need: np.ndarray, sizes) -> dict:
    """Bytes counted and bytes of pages touched, per order, for the bricks ``need`` (bool over the grid) of
    channels of ``sizes`` bytes a brick."""
    c_rows = np.flatnonzero(need.reshape(-1))
    m_rows = morton_rank(need.shape)[c_rows]
    out = {"bricks": int(c_rows.size), "counted": int(c_rows.size * sum(sizes))}
    for name, rows in (("C", c_rows), ("Morton", m_rows)):
        out[name] = sum(pages(rows, s) for s in sizes) * PAGE
        out[name + " interleaved"] = pages(rows, sum(sizes)) * PAGE
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.brick_order", description=__doc__)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--cases", default="H1,E2,B1,H1-512,C1")
    a = ap.parse_args(argv)
    from isplat.augfile import open_augmented
    from isplat.renderer import Renderer
    from isplat.scene import load_scene
    from isplat.selection import post_bricks

    from .selective_read import _index, _scene, cases

    print("| case | channels | bricks | counted (MB) | pages, C order (MB) | pages, Morton (MB) | Morton / C | "
          "interleaved, C (MB) | interleaved, Morton (MB) |\n|---|---|---:|---:|---:|---:|---:|---:|---:|")
    with tempfile.TemporaryDirectory(prefix="isplat-order-") as t:
        work = Path(t)
        for c in cases(work, a.quick, only=a.cases.split(",")):
            idx = work / f"{c['name']}.idx.h5"
            _index(c["aug"], idx, a.quick)
            sc = load_scene(_scene(work, c, idx, "post"))
            for shaded in (True, False):
                sc1 = sc if shaded else _unshaded(sc)
                r = Renderer(sc1, (sc1.views[0],), slabs=1)
                need = post_bricks(r.selection, open_augmented(c["aug"]).bricks)
                e3 = int(np.prod(open_augmented(c["aug"]).bricks))
                sizes = [e3, 2 * e3, e3] if shaded else [e3]
                f = figures(need, sizes)
                mb = {k: f"{v / 1e6:.2f}" for k, v in f.items() if k != "bricks"}
                print(f"| {c['name']} | {'density, normal, gradient' if shaded else 'density'} | {f['bricks']:,} | "
                      f"{mb['counted']} | {mb['C']} | {mb['Morton']} | {f['Morton'] / max(1, f['C']):.2f} | "
                      f"{mb['C interleaved']} | {mb['Morton interleaved']} |", flush=True)
    return 0


def _unshaded(scene):
    """``scene`` with shading off (post then reads the density alone)."""
    from dataclasses import replace

    return replace(scene, shading=replace(scene.shading, enabled=False, lights=()))


if __name__ == "__main__":
    sys.exit(main())
