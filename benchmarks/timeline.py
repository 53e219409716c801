"""Where a frame's wall time goes besides the kernel: a timeline of the frame's threads.

``python -m benchmarks timeline [--out docs] [--quick]`` writes the section ``timeline`` of ``performance.md``. On
a few cases of :mod:`benchmarks.peers` (isplat's defaults, all cores), every frame of a run of frames is timed
from the inside: ``isplat.frame.render_frame``'s call, its ``prepare`` (the frame's tables, in the calling thread
before any band), and each band's kernel (``isplat.splat.traverse.render``) and finishing
(``isplat.splat.composite.finish``) in the thread that takes it (the functions are wrapped with a clock read
before and after; a few microseconds a frame). Per frame: the frame's wall time; the kernels' time summed over
the threads and divided by their number (the frame a perfect split of the kernels alone would take); and what
makes up the difference: the time before the first band starts (prepare, handing the bands to the threads),
the time from the last band's end to the return, and the threads' idle time between their bands and at the end
(the busiest thread against the others). Medians over the frames. The question it answers: how much of a frame
is not the kernel, so how much a faster kernel can give, and what else there is to take.
"""

from __future__ import annotations

import statistics
import threading
import time
from pathlib import Path

from . import _doc

SECTION = "timeline"
TECHNIQUES = ["post"]
SOURCES = _doc.sources(_doc.RENDER, _doc.READ, _doc.SAMPLES, ("benchmarks/timeline.py", "benchmarks/peers.py",
                                                              "benchmarks/reference.py"))
CASES = (("head translucent", 256), ("head opaque", 256), ("chest", 512), ("chest shaded", 512))
FRAMES, QUICK_FRAMES = 60, 4
WARM = 8


class Clocks:
    """Wraps functions of modules so that each call records (name, thread, start, end) into ``events``."""

    def __init__(self):
        self.events, self._undo = [], []

    def wrap(self, module, name: str) -> None:
        fn = getattr(module, name)

        def timed(*args, **kw):
            t0 = time.perf_counter()
            try:
                return fn(*args, **kw)
            finally:
                self.events.append((name, threading.get_ident(), t0, time.perf_counter()))

        setattr(module, name, timed)
        self._undo.append((module, name, fn))

    def restore(self) -> None:
        for module, name, fn in reversed(self._undo):
            setattr(module, name, fn)
        self._undo.clear()


def frame_parts(events, t0: float, t1: float, threads: int) -> dict:
    """One frame's parts (seconds) from its ``events`` (:class:`Clocks`), its call's start and end and the
    frame's thread count. They add up: frame = before + kernels / threads + finishing + idle + after.

    >>> ev = [("prepare", 1, 0.0, 0.3), ("render", 1, 0.4, 5.4), ("finish", 1, 5.4, 5.5),
    ...       ("render", 2, 0.5, 4.5), ("finish", 2, 4.5, 4.6), ("render", 2, 4.7, 5.6), ("finish", 2, 5.6, 5.7)]
    >>> p = frame_parts(ev, 0.0, 5.8, 2)
    >>> [round(p[k], 3) for k in ("before", "ideal", "finish", "idle", "tail", "prepare")], p["took"], p["bands"]
    ([0.4, 4.95, 0.15, 0.2, 0.1, 0.3], 2, 3)
    >>> round(p["before"] + p["ideal"] + p["finish"] + p["idle"] + p["tail"], 9) == p["frame"]
    True
    """
    kernels = [(a, b) for name, _, a, b in events if name == "render"]
    first = min(a for a, _ in kernels)
    last = max(b for name, _, _, b in events if name in ("render", "finish"))
    ideal = sum(b - a for a, b in kernels) / threads
    finish = sum(b - a for name, _, a, b in events if name == "finish") / threads
    # per thread, the time from the first band's start anywhere to the last band's end anywhere that is neither
    # kernel nor finishing (a thread that took no band was idle throughout)
    idle = (last - first) - ideal - finish
    return dict(frame=t1 - t0, ideal=ideal, prepare=sum(b - a for name, _, a, b in events if name == "prepare"),
                before=first - t0, finish=finish, idle=idle, tail=t1 - last,
                took=len({tid for name, tid, _, _ in events if name == "render"}), bands=len(kernels))


def measure(name: str, size: int, quick: bool) -> dict:
    """One case: the medians of :func:`frame_parts` over a run of frames."""
    import isplat.frame as F
    from isplat.frame import BandLearning, views_for
    from isplat.renderer import Renderer
    from isplat.threads import default_threads

    from . import peers as P

    size = min(P.CASES[name][5]) if quick else size
    scene = P.peer_scene(name, size, quick)
    sel = Renderer(scene).selection
    view = views_for(scene, sel)[0]
    bands = BandLearning()
    threads = view.render.threads or default_threads()
    for _ in range(WARM):
        F.render_frame(sel, view, None, bands)
    clocks = Clocks()
    for module, fn in ((F, "prepare"), (F.T, "render"), (F, "finish")):
        clocks.wrap(module, fn)
    rows = []
    try:
        for _ in range(QUICK_FRAMES if quick else FRAMES):
            clocks.events.clear()
            t0 = time.perf_counter()
            F.render_frame(sel, view, None, bands)
            rows.append(frame_parts(list(clocks.events), t0, time.perf_counter(), threads))
    finally:
        clocks.restore()
    med = {k: statistics.median(r[k] for r in rows) for k in rows[0]}
    return dict(case=name, size=size, threads=threads, **med)


def body(results, command: str, frames: int) -> str:
    L = ["### A frame's timeline: the kernels and what is around them", "",
         f"`{command}` ({_doc.machine_line()}; technique **post**, isplat's defaults, all cores; {frames} frames "
         f"of a run after {WARM} warm ones, medians per column). *kernels / threads*: the bands' kernel time "
         "summed and divided by the threads, the frame a perfect split of the kernels alone would take. Around "
         "them: *before*, from the call to the first band's start (*prepare*, the frame's tables, is part of it); "
         "*finishing*, the bands' conversion to straight colour over the background, per thread; *idle*, a "
         "thread's time from its first band's start to the last band's end anywhere that is neither kernel nor "
         "finishing (handing over between bands, waiting for the other thread at the end), per thread; *after*, "
         "from the last band's end to the return. In each frame these add up to its time; the columns are "
         "medians, each of its own. *took*: the threads that took a band (median).", "",
         "| case | pixels | threads | took | bands | frame ms | kernels / threads ms | before ms | of it prepare ms | "
         "finishing ms | idle ms | after ms | not kernel |",
         "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in results:
        around = r["frame"] - r["ideal"]
        L.append(f"| {r['case']} | {r['size']} | {r['threads']} | {r['took']:.0f} | {r['bands']:.0f} | {1e3 * r['frame']:.2f} | "
                 f"{1e3 * r['ideal']:.2f} | {1e3 * r['before']:.2f} | {1e3 * r['prepare']:.2f} | "
                 f"{1e3 * r['finish']:.2f} | {1e3 * r['idle']:.2f} | {1e3 * r['tail']:.2f} | "
                 f"{around / r['frame']:.0%} |")
    worst = max(results, key=lambda r: (r["frame"] - r["ideal"]) / r["frame"])
    parts = {"before the first band": worst["before"], "finishing": worst["finish"], "idle": worst["idle"],
             "after the last band": worst["tail"]}
    big = max(parts, key=parts.get)
    L += ["", f"- The share of a frame that is not the kernels is largest on the {worst['case']} at "
              f"{worst['size']} px: {(worst['frame'] - worst['ideal']) / worst['frame']:.0%} "
              f"({1e3 * (worst['frame'] - worst['ideal']):.2f} of {1e3 * worst['frame']:.2f} ms), most of it "
              f"{big} ({1e3 * parts[big]:.2f} ms; prepare {1e3 * worst['prepare']:.2f} ms of the "
              f"{1e3 * worst['before']:.2f} before the first band). A kernel twice as fast would leave that frame "
              f"at {(worst['frame'] - worst['ideal'] / 2) / worst['frame']:.2f}x its time, not 0.5x."]
    return "\n".join(L) + "\n"


def run(out_dir: Path, quick: bool = False) -> Path:
    results = [measure(name, size, quick) for name, size in CASES]
    command = "python -m benchmarks timeline" + (" --quick" if quick else "")
    return _doc.update_section(Path(out_dir) / "performance.md", SECTION,
                               body(results, command, QUICK_FRAMES if quick else FRAMES))
