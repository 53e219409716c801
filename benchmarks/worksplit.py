"""Work per frame: what hidden material costs, and how the frame is shared out between threads.

``python -m benchmarks worksplit [--quick]`` (part of ``make bench``) writes docs/worksplit.md.

1. Hidden material: per frame, the voxels of interest in the slices traversed, the voxels that reached the
   per-voxel stages (not skipped with their region, block or cell of the slice), and the voxels splatted.
   These are counts, not times: they do not depend on the machine's load.
2. Threads: the image is cut into bands of rows (isplat.frame.image_bands), threads take every n-th band and
   each band walks the slices on its own. The work that is repeated is that of voxels whose footprint crosses
   a band's edge (tested, shaded and splatted by both bands): counted for the bands that 1 to 64 threads use.
   The work that is serial is the frame's set-up (tables, binning the regions to the bands; ``prepare``)
   measured beside the frame. From both, the speed-up on N cores is predicted (Amdahl's law with the
   repeated work added to the parallel part), and on this machine 2 threads are timed against 1.
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

from . import _doc
from .render import ROOT, SCENE, ensure_head, overrides

SEMI = "transfer.opacity=[[0,0],[99,0],[130,0.1],[200,0.5],[255,0.7]]"
THREADS = (1, 2, 4, 8, 16, 64)


def _log(msg):
    print(f"[worksplit] {msg}", file=sys.stderr, flush=True)


def _renderer(scene, aug, idx, size, *extra):
    from isplat.renderer import Renderer
    from isplat.scene import load_scene

    ov = [o for o in overrides(aug, idx, *extra) if not o.startswith("image.")]
    return Renderer(load_scene(scene, [*ov, f"image.width={size}", f"image.height={size}"]))


def cases(quick: bool):
    """(name, scene, augmented, index, image size, scene overrides)."""
    aug, idx = ensure_head()
    eng = ensure_head(None, "engine")
    big = (128, 128, 128) if quick else (512, 512, 512)
    aug_b, idx_b = ensure_head(big)
    size = 256 if quick else 512
    engine = ROOT / "examples" / "engine.toml"
    return [("head 256x256x225, bone, shaded", SCENE, aug, idx, size, ()),
            ("head 256x256x225, semi-opaque skin over bone", SCENE, aug, idx, size, (SEMI, "shading.enabled=false")),
            ("engine 256x256x110 (examples/engine.toml, perspective)", engine, *eng, size, ()),
            (f"head {big[0]}^3, semi-opaque skin over bone", SCENE, aug_b, idx_b, size,
             (SEMI, "shading.enabled=false"))]


def on_threads(view, threads: int):
    """``view`` rendered on ``threads`` threads (and so with their bands)."""
    from dataclasses import replace

    return replace(view, render=replace(view.render, threads=threads))


def counts(r, threads: int):
    """The frame's bands and counters on ``threads`` threads (the counts depend on the bands only)."""
    from isplat import frame as F

    view = on_threads(r.views[0], threads)
    return len(F.image_bands(view.frame.height, threads)), F.render_frame(r.selection, view)[1]


def timings(r, frames: int) -> dict:
    """Median seconds of the frame on 1 and 2 threads and of its set-up (``prepare``), interleaved."""
    from isplat import frame as F

    views = {"1": on_threads(r.views[0], 1), "2": on_threads(r.views[0], 2)}
    out = {"1": [], "2": [], "prepare": []}
    for _ in range(frames + 1):
        for key, view in views.items():
            t = time.perf_counter()
            F.render_frame(r.selection, view)
            out[key].append(time.perf_counter() - t)
        t = time.perf_counter()
        F.prepare(r.selection, views["2"])
        out["prepare"].append(time.perf_counter() - t)
    return {k: statistics.median(v[1:]) for k, v in out.items()}


def predicted(serial: float, repeated: float, n: int, bands: int) -> float:
    """Speed-up on ``n`` cores: the serial share stays, the rest (with its repeated work) is shared out between
    at most ``bands`` threads (a band is one thread's)."""
    return 1.0 / (serial + (1.0 - serial) * (1.0 + repeated) / min(n, bands))


def run(out_dir: Path, quick: bool) -> Path:
    t0 = time.perf_counter()
    rows = []
    for name, scene, aug, idx, size, extra in cases(quick):
        _log(name)
        r = _renderer(scene, aug, idx, size, *extra)
        per = {t: counts(r, t) for t in THREADS}
        tm = timings(r, 3 if quick else 11)
        rows.append((name, size, per, tm, r.selection.axes[per[1][1].axis].n_voxels))
    body = doc(rows, quick, time.perf_counter() - t0)
    path = out_dir / "worksplit.md"
    path.write_text(body + "\n")
    return path


def doc(rows, quick: bool, seconds: float) -> str:
    L = ["# Work per frame: hidden material and threads", "",
         f"Made by `python -m benchmarks worksplit{' --quick' if quick else ''}` (part of `make bench`) on "
         f"{_doc.machine_line()}, git {_doc.git_rev()}, in {seconds:.0f} s. Do not edit: rerun the command.", "",
         "Counts are exact and do not depend on the machine's load; times are medians of frames interleaved in "
         "one run (this machine is shared, so the times are noisy, the counts are not). The head from the "
         "front, orthographic; the engine as examples/engine.toml shows it; square images; early "
         "termination at 0.99.", "",
         "## Hidden material costs one test per region, block or cell", "",
         "| scene | image | voxels of interest | in slices traversed | tested one by one | splatted | "
         "tested / splatted |", "|---|---:|---:|---:|---:|---:|---:|"]
    for name, size, per, tm, n_vox in rows:
        st = per[1][1]
        L.append(f"| {name} | {size} | {n_vox:,} | {st.voxels_examined:,} | {st.voxels_tested:,} | "
                 f"{st.voxels_splatted:,} | {st.voxels_tested / max(st.voxels_splatted, 1):.2f} |")
    L += ["", "A voxel is tested one by one only when its cell (4 x 4 voxels of a slice), block (16 x 16) and "
          "region (64 x 64) can reach a pixel of the band that is not yet saturated; the rest cost one test per "
          "square, against a summed-area table of the whole tiles (8 x 8 pixels) whose pixels are all saturated.",
          "", "## Threads: repeated and serial work", "",
          "| scene | threads | bands | voxels tested | repeated work | predicted speed-up |",
          "|---|---:|---:|---:|---:|---:|"]
    for name, size, per, tm, n_vox in rows:
        base = per[1][1].voxels_tested
        serial = tm["prepare"] / tm["1"]
        for t in THREADS:
            nb, st = per[t]
            rep = st.voxels_tested / max(base, 1) - 1.0
            L.append(f"| {name} | {t} | {nb} | {st.voxels_tested:,} | {100 * rep:.1f}% | "
                     f"{predicted(serial, rep, t, nb):.2f} |")
    L += ["", "| scene | 1 thread (ms) | ns per voxel of interest | ns per voxel splatted | 2 threads (ms) | "
          "speed-up | set-up per frame (ms) | serial share |", "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for name, size, per, tm, n_vox in rows:
        L.append(f"| {name} | {1e3 * tm['1']:.1f} | {1e9 * tm['1'] / max(n_vox, 1):.1f} | "
                 f"{1e9 * tm['1'] / max(per[1][1].voxels_splatted, 1):.0f} | {1e3 * tm['2']:.1f} | "
                 f"{tm['1'] / tm['2']:.2f} | {1e3 * tm['prepare']:.2f} | {100 * tm['prepare'] / tm['1']:.1f}% |")
    L += ["", "If the frame's cost follows what is visible, the time per voxel splatted stays about the same from "
          "scene to scene however much lies hidden, while the time per voxel of interest falls as more of them "
          "are hidden.", "", "Repeated work: the voxels tested by all bands together over those tested with one band, minus "
          "one (a voxel whose footprint crosses a band's edge is tested, and partly splatted, by both). "
          "Serial share: the frame's set-up (``isplat.frame.prepare``: opacity and shading tables, footprint, "
          "binning the regions to the bands) over the one-thread frame; the shading table is itself shared "
          "between threads, so this overstates it. Predicted speed-up on N cores: 1 / (serial + (1 - serial) "
          "(1 + repeated) / min(N, bands)): a band is rendered by one thread, and bands are at least "
          "4 tiles (32 rows) high, so a 256-row image keeps at most 8 threads busy and a 1024-row one 32. "
          "Not counted: memory bandwidth, which all cores share, and load imbalance "
          "between bands (threads take every n-th band to even it out)."]
    return "\n".join(L)
