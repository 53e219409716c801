"""Whole-shape channels against the pool: what the sampler gains when no brick table stands between a sample and
its voxels, and what it costs in memory.

``python -m benchmarks layout [--out docs] [--quick]`` writes the section ``layout`` of ``performance.md``. On the
cases of :mod:`benchmarks.peers` (isplat's defaults, all cores, post), each case is selected twice in one process:
with the channels as a pool of the bricks read behind a brick table (``isplat.selection.FLAT_BYTES_PER_VOXEL`` set
to 0), and with isplat's own choice (whole-shape when that holds at most ``FLAT_BYTES_PER_VOXEL`` bytes a voxel of
interest, issue 26's bound). Frames of the two alternate, in rounds whose order alternates too; per case the
median of each round's ratio, the rounds the default was faster in, the paired sign test of tests/paired_times.py
(*faster* only past its 3% margin at level 0.01), the bytes each holds, and whether the images are bit for bit
equal (they must be: the layout changes where the voxels are, not what is sampled).
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

from . import _doc

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
import paired_times as PT  # noqa: E402

SECTION = "layout"
TECHNIQUES = ["post"]
SOURCES = _doc.sources(_doc.RENDER, _doc.READ, _doc.SAMPLES, ("benchmarks/layout.py", "benchmarks/peers.py",
                                                              "benchmarks/reference.py", "tests/paired_times.py"))
ROUNDS, QUICK_ROUNDS = 25, 3
PER_ROUND = 4           # frames of each per round (their median is the round's time)
WARM = 6


def cases(quick: bool) -> list[tuple[str, int]]:
    """Every case of benchmarks.peers at each of its sizes (the smallest, quick)."""
    from . import peers as P

    return [(name, size) for name, c in P.CASES.items() for size in (c[5][:1] if quick else c[4])]


def selections(name: str, size: int, quick: bool):
    """The case's scene, and its selection as a pool and as isplat chooses (with each one's report)."""
    import isplat.selection as S
    from isplat.renderer import Renderer

    from . import peers as P

    scene = P.peer_scene(name, size, quick)
    keep = S.FLAT_BYTES_PER_VOXEL
    try:
        S.FLAT_BYTES_PER_VOXEL = 0
        pool = Renderer(scene).selection
    finally:
        S.FLAT_BYTES_PER_VOXEL = keep
    return scene, pool, Renderer(scene).selection


def measure(name: str, size: int, quick: bool) -> dict:
    """One case: its two selections' frames, interleaved (:func:`selections`)."""
    import numpy as np

    from isplat.frame import BandLearning, render_frame, views_for

    scene, pool, chosen = selections(name, size, quick)
    runs = {key: dict(sel=sel, view=views_for(scene, sel)[0], bands=BandLearning(), times=[])
            for key, sel in (("pool", pool), ("default", chosen))}
    for run in runs.values():
        for _ in range(WARM):
            run["img"] = render_frame(run["sel"], run["view"], None, run["bands"])[0]
    for r in range(QUICK_ROUNDS if quick else ROUNDS):
        for key in (("pool", "default") if r % 2 == 0 else ("default", "pool")):
            run, ts = runs[key], []
            for _ in range(PER_ROUND):
                t0 = time.perf_counter()
                render_frame(run["sel"], run["view"], None, run["bands"])
                ts.append(time.perf_counter() - t0)
            run["times"].append(statistics.median(ts))
    a, b = runs["default"]["times"], runs["pool"]["times"]
    cmp = PT.compare(a, b)
    return dict(case=name, size=size, whole=not chosen.whole.pooled, values=chosen.report.values_from,
                voi=chosen.report.voxels_of_interest, held_pool=pool.held_bytes(), held=chosen.held_bytes(),
                ms_pool=1e3 * statistics.median(b), ms=1e3 * statistics.median(a), ratio=cmp.ratio, wins=cmp.wins,
                n=cmp.n, faster=cmp.faster, slower=PT.faster(b, a),
                equal=bool(np.array_equal(runs["pool"]["img"], runs["default"]["img"])))


def body(results, command: str, rounds: int) -> str:
    import isplat.selection as S

    L = ["### Whole-shape channels or the pool (issue 27)", "",
         f"`{command}` ({_doc.machine_line()}; technique **post**, isplat's defaults, all cores; {rounds} rounds of "
         f"{PER_ROUND} frames of each after {WARM} warm ones, alternating). *pool*: the channels as the bricks read "
         "behind a brick table (`FLAT_BYTES_PER_VOXEL = 0`); *default*: isplat's choice, whole-shape (flat "
         f"`[k, j, i]`, zeros where nothing was read) when that holds at most {S.FLAT_BYTES_PER_VOXEL} B a voxel "
         "of interest, else the same pool. A case read as whole channels (more than `BRICK_SHARE` of its bricks "
         "needed) is whole-shape either way. *x pool*: the median over the rounds of the default's frame over the "
         "pool's; *faster* by the paired sign test of tests/paired_times.py (3% margin, level 0.01).", "",
         "| case | pixels | default layout | voxels of interest | held, pool MB | held, default MB | B / voxel of "
         "interest | pool ms | default ms | x pool | rounds faster | images |",
         "|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---|"]
    for r in results:
        layout = "whole-shape" if r["whole"] else "pool"
        verdict = " (faster)" if r["faster"] else " (slower)" if r["slower"] else ""
        L.append(f"| {r['case']} | {r['size']} | {layout} | {r['voi']:,} | {r['held_pool'] / 2 ** 20:.1f} | "
                 f"{r['held'] / 2 ** 20:.1f} | {r['held'] / max(1, r['voi']):.2f} | {r['ms_pool']:.2f} | "
                 f"{r['ms']:.2f} | {r['ratio']:.3f}{verdict} | {r['wins']}/{r['n']} | "
                 f"{'bit for bit equal' if r['equal'] else '**differ**'} |")
    moved = [r for r in results if r["whole"] and r["held_pool"] != r["held"]]
    L.append("")
    if moved:
        lo, hi = min(moved, key=lambda r: r["ratio"]), max(moved, key=lambda r: r["ratio"])
        L.append(f"- Whole-shape where the pool was read ({len(moved)} of {len(results)} cases): frames "
                 f"{lo['ratio']:.3f}x ({lo['case']}, {lo['size']} px) to {hi['ratio']:.3f}x ({hi['case']}, "
                 f"{hi['size']} px) the pool's; faster by the test in "
                 f"{sum(r['faster'] for r in moved)}, slower in {sum(r['slower'] for r in moved)}. Held: "
                 f"{min(r['held'] / r['held_pool'] for r in moved):.1f}x to "
                 f"{max(r['held'] / r['held_pool'] for r in moved):.1f}x the pool's bytes, at most "
                 f"{max(r['held'] / max(1, r['voi']) for r in moved):.2f} B a voxel of interest.")
    else:
        L.append("- No case was held whole-shape instead of a pool.")
    if not all(r["equal"] for r in results):
        L.append("- **Some images differ between the layouts: a defect.**")
    return "\n".join(L) + "\n"


def run(out_dir: Path, quick: bool = False) -> Path:
    results = [measure(name, size, quick) for name, size in cases(quick)]
    command = "python -m benchmarks layout" + (" --quick" if quick else "")
    return _doc.update_section(Path(out_dir) / "performance.md", SECTION,
                               body(results, command, QUICK_ROUNDS if quick else ROUNDS))
