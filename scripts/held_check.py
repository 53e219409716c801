"""Check (issue 26): post's image with only the needed voxels loaded equals the image of
the full channels, bit for bit, on a benchmarks/peers.py case (as scripts/ab.py renders it).

    python scripts/held_check.py [--case chest] [--size 512] [--bins dp64x16]

Needed: the voxels whose range key (benchmarks/range_runs.py, ``union``: one file for every view) meets an interval
of the scene, exactly (``--bins exact``) or as the runs of a binning read them (``--bins 64x16``, ``dp64x16``: a
superset). The rest of the density, gradient and normal channels is zeroed, as a reader of the runs would leave
it, and marked not loaded (the selection's ``held``, isplat.splat.post.held_quads); the sampler then skips quads with a
corner not loaded. Printed: voxels loaded, quads held per axis, the images' equality, and, for contrast, the image
with the zeros marked loaded (no quad skipped).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--case", default="chest")
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--bins", default="exact", help="exact, or a binning of benchmarks.range_runs (64x16, dp64x16)")
    a = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    from benchmarks import peers as PE
    from benchmarks import range_runs as RR
    from benchmarks import reference as REF
    from isplat.renderer import Renderer
    from isplat.scene import load_scene
    from isplat.splat import post as P

    sample, (aug, idx) = PE.case_data(a.case)
    path, ov0, _ = REF.CASES[sample]
    sets = [f'data.augmented="{aug}"', f'data.index="{idx}"', f"image.width={a.size}", f"image.height={a.size}",
            *ov0, *PE.UNSHADED, *PE.CASES[a.case][3], *REF.render_overrides({"threads": 1})]
    scene = load_scene(REF.REPO / path, sets)
    r0 = Renderer(scene)
    full, _ = r0.render_view(0)
    sel = r0.selection
    intervals = [tuple(int(x) for x in iv) for iv in r0.report.intervals]
    density = sel.whole.density.reshape(sel.shape)
    lo, hi = RR.range_key(density, "union")
    if a.bins == "exact":
        held = np.zeros(density.shape, bool)
        for t0, t1 in intervals:
            held |= (lo <= t1) & (hi >= t0)
    else:
        bins = RR.resolve(RR._bins(a.bins), lo, hi)
        held = RR.runs_meeting(intervals, bins)[RR.run_of(lo, hi, bins)]
    print(f"{a.case}, {a.size} px, intervals {intervals}, bins {a.bins}: {int(held.sum()):,} of {held.size:,} voxels "
          f"loaded ({held.mean():.3f})")
    from dataclasses import replace
    for mark in (True, False):
        r = Renderer(scene)
        sel = r.selection
        w = sel.whole
        keep = held.reshape(-1)
        for ch in (w.density, w.gradient_magnitude, w.normal):
            if ch.shape[0]:
                ch[~keep] = 0
        bits = {ax: P.held_quads(held if mark else np.ones_like(held), sel.shape, ax) for ax in sel.request.axes}
        r.selection = replace(sel, held=bits)
        img, _ = r.render_view(0)
        if mark:
            for ax, b in bits.items():
                n = int(np.unpackbits(b, bitorder="little")[:held.size].sum())
                print(f"  axis {ax}: quads held {n:,} of {held.size:,}")
        diff = np.abs(img - full)
        print(f"  {'quads with a corner not loaded skipped' if mark else 'zeros marked loaded (no skip)'}: "
              f"same image bit for bit: {np.array_equal(img, full)} (pixels differing {int((diff.max(-1) > 0).sum())}, "
              f"max |diff| {float(diff.max()):.3g})")


if __name__ == "__main__":
    main()
