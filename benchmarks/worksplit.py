"""Work per frame: what hidden material costs, and how the frame is shared out between threads.

``python -m benchmarks worksplit [--quick]`` (part of ``make bench``) writes docs/worksplit.md.

1. Hidden material: per frame, the voxels of interest in the slices traversed, those in the cells left after
   the occlusion tests (not skipped with their region, block or cell of the slice), and the voxels splatted or
   samples composited.
   These are counts, not times: they do not depend on the machine's load.
2. Threads: the image is cut into bands of rows (isplat.frame.band_rows: evenly for a first frame, then where
   the frames before found equal work), a free thread takes the next band (at equal speed every n-th) and
   each band walks the slices on its own. The work that is repeated is that of cells that cross a band's edge
   (visited by both bands): counted for the bands that 1 to 64 threads use. The work that is serial is the
   calling thread's CPU time outside the kernels (set-up, finishing). From both, the speed-up on N cores is
   predicted (Amdahl's law with the repeated work added to the parallel part), and on this machine 2 threads
   are timed against 1, in wall time and in each thread's CPU time, and against the machine's own ceiling
   measured in the same rounds (two one-thread copies at once; tests/ceiling_rounds.py).
"""

from __future__ import annotations

import itertools
import statistics
import sys
import time
from pathlib import Path

from . import _doc

# the per-round ceiling statistics (shared with their tests, which must not import benchmarks; see its docstring)
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import ceiling_rounds as CR  # noqa: E402

TECHNIQUES = ["post"]     # render.classification of its rows (the page's stamp)
SOURCES = _doc.sources(_doc.RENDER, _doc.READ, _doc.SAMPLES, ("isplat/augment.py", "examples/*.toml",
                       "tests/ceiling_rounds.py", "tests/paired_times.py", "benchmarks/worksplit.py"))
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
    """The frame's bands and counters on ``threads`` threads, on even bands (a first frame: the counts depend
    on the bands only)."""
    from isplat import frame as F

    view = on_threads(r.views[0], threads)
    r.bands.costs.clear()
    return len(F.image_bands(view.frame.height, threads)), F.render_frame(r.selection, view, None, r.bands)[1]


def cpu_frame(r, view) -> dict:
    """One frame of ``view``: its wall time; the CPU time of the thread that made it outside the parallel parts
    (the serial part: set-up, binning); and per parallel part (each thread's kernel, then finishing its bands'
    rows; a supersampled frame is finished in a part of its own) each thread's CPU time in it
    (``time.thread_time``, which does not count time a thread waits for a core: on a shared machine the CPU
    times hold where wall times do not)."""
    from isplat import frame as F

    import threading

    parts, orig, overlapped, here = [], F.run_parallel, [], []
    caller = threading.get_ident()

    def timed(fn, items, threads, meanwhile=None):
        part = []
        parts.append(part)

        def one(x):
            t = time.thread_time()
            out = fn(x)
            part.append(time.thread_time() - t)
            if threading.get_ident() == caller:     # counted in the calling thread's time too
                here.append(part[-1])
            return out

        def aside():                # learning the bands of the frame before, while the threads render
            t = time.thread_time()
            meanwhile()
            overlapped.append(time.thread_time() - t)
        return orig(one, items, threads, None if meanwhile is None else aside)

    F.run_parallel = timed
    try:
        t0, c0 = time.perf_counter(), time.thread_time()
        F.render_frame(r.selection, view, None, r.bands)
        wall, main = time.perf_counter() - t0, time.thread_time() - c0
    finally:
        F.run_parallel = orig
    inline = view.render.threads <= 1                 # one thread: the parallel parts ran in this thread
    # the calling thread's work while the threads render is not serial (with one thread it is: it runs after);
    # the items it rendered itself (all of them on one thread) are the parallel parts'
    aside = 0.0 if inline else sum(overlapped)
    return dict(wall=wall, serial=main - aside - sum(here), threads=parts[0],
                rest=sum(map(sum, parts[1:])), rest_busiest=sum(max(p, default=0.0) for p in parts[1:]))


def pair_frame(copies, views) -> float:
    """Wall seconds of two one-thread frames at once, one per renderer of ``copies`` (independent copies of the
    same work, nothing shared): what this machine's two cores give two programs that need no coordination."""
    from isplat import frame as F
    from isplat.threads import run_parallel

    t = time.perf_counter()
    run_parallel(lambda k: F.render_frame(copies[k].selection, views[k], None, copies[k].bands), [0, 1], 2)
    return time.perf_counter() - t


ORDERS = list(itertools.permutations(("1", "2", "pair")))   # a round's order of the three it compares


def round_order(i: int) -> list[str]:
    """The kinds of frame of round ``i``, in the order they are timed: the three that the ceiling compares
    (1 thread, 2 threads, two copies) back to back, in each of their 6 orders in turn, then "2e".

    >>> round_order(0), round_order(7)
    (['1', '2', 'pair', '2e'], ['1', 'pair', '2', '2e'])
    """
    return [*ORDERS[i % len(ORDERS)], "2e"]


def timings(r, twin, frames: int) -> dict:
    """Medians over rounds of frames on 1 and 2 threads: wall time, serial CPU time, the threads' CPU time in
    the kernels (total and the busiest thread's); and the set-up alone (``prepare``); and under "rounds" each
    round's wall times of "1", "2" and "pair" (for :func:`ceiling_rounds.ceiling`). Frames "2" cut their
    bands by the frames before them (``isplat.frame.band_rows``; the first round, not counted, learns); frames
    "2e" always take even bands, as a first frame does. Each timed frame follows an untimed one of its kind, as
    a run of frames does (a frame after one of another kind runs on caches that frame left: a 2-thread frame
    after a 1-thread one took measurably longer); the kinds' order turns from round to round
    (:func:`round_order`). "pair": two one-thread frames at once, one of ``r`` and one of ``twin`` (a second
    renderer of the same scene, :func:`pair_frame`)."""
    from isplat import frame as F

    views = {"1": on_threads(r.views[0], 1), "2": on_threads(r.views[0], 2), "2e": on_threads(r.views[0], 2)}
    runs = {key: [] for key in views}
    learned = {key: {} for key in views}      # what each kind's frames learned of their bands ("2e": nothing)
    prep, pairs = [], []
    pair_views = (views["1"], on_threads(twin.views[0], 1))
    for i in range(frames + 1):
        for key in round_order(i):
            for timed in (False, True):   # after a frame of the same kind: not paying for the caches another left
                if key == "pair":
                    r.bands.costs = learned["1"]
                    dt = pair_frame((r, twin), pair_views)
                    if timed:
                        pairs.append(dt)
                    continue
                if key == "2e":
                    learned[key].clear()                            # even bands, as a first frame
                r.bands.costs = learned[key]
                if timed:
                    runs[key].append(cpu_frame(r, views[key]))
                else:
                    F.render_frame(r.selection, views[key], None, r.bands)
        r.bands.costs = learned["2"]
        t = time.perf_counter()
        F.prepare(r.selection, views["2"], None, r.bands)
        prep.append(time.perf_counter() - t)
    med = statistics.median
    out = {"prepare": med(prep[1:]), "pair": med(pairs[1:]),
           "rounds": {"1": [x["wall"] for x in runs["1"][1:]], "2": [x["wall"] for x in runs["2"][1:]],
                      "pair": pairs[1:]}}
    for key, rs in runs.items():
        rs = rs[1:]
        out[key] = med(x["wall"] for x in rs)
        out[f"serial{key}"] = med(x["serial"] for x in rs)
        out[f"work{key}"] = med(sum(x["threads"]) for x in rs)
        out[f"busiest{key}"] = med(max(x["threads"]) for x in rs)
        out[f"imbalance{key}"] = med(max(x["threads"]) * len(x["threads"]) / sum(x["threads"]) for x in rs)
        out[f"rest{key}"] = med(x["rest"] for x in rs)
        out[f"rest_busiest{key}"] = med(x["rest_busiest"] for x in rs)
    for key in ("2", "2e"):
        out[f"cpu_speedup{key}"] = (out["serial1"] + out["work1"] + out["rest1"]) / (
            out[f"serial{key}"] + out[f"busiest{key}"] + out[f"rest_busiest{key}"])
    return out


def over_passes(passes: list[dict]) -> dict:
    """The median over passes of each of :func:`timings`' figures, and each CPU speed-up's range over them.

    >>> over_passes([{"a": 1.0, "cpu_speedup2": 1.5}, {"a": 3.0, "cpu_speedup2": 1.9}, {"a": 2.0, "cpu_speedup2": 1.8}])
    {'a': 2.0, 'cpu_speedup2': 1.8, 'cpu_speedup2_range': (1.5, 1.9)}
    """
    out = {key: statistics.median(p[key] for p in passes) for key in passes[0]}
    for key in [k for k in out if k.startswith("cpu_speedup")]:
        out[f"{key}_range"] = (min(p[key] for p in passes), max(p[key] for p in passes))
    return out


def predicted(serial: float, repeated: float, n: int, bands: int) -> float:
    """Speed-up on ``n`` cores: the serial share stays, the rest (with its repeated work) is shared out between
    at most ``bands`` threads (a band is one thread's)."""
    return 1.0 / (serial + (1.0 - serial) * (1.0 + repeated) / min(n, bands))


PASSES = 3     # the timings of every scene, measured this many times, a pass over all scenes after another


def run(out_dir: Path, quick: bool) -> Path:
    t0 = time.perf_counter()
    scenes = []
    for name, scene, aug, idx, size, extra in cases(quick):
        _log(name)
        r = _renderer(scene, aug, idx, size, *extra)
        per = {t: counts(r, t) for t in THREADS}
        scenes.append((name, size, per, r, _renderer(scene, aug, idx, size, *extra)))
    passes = [[] for _ in scenes]
    for k in range(1 if quick else PASSES):     # the host's load changes over seconds: passes spread over them
        for (name, _, _, r, twin), got in zip(scenes, passes):
            _log(f"timings, pass {k + 1}: {name}")
            got.append(timings(r, twin, 3 if quick else 11))
    rows = [(name, size, per, over_passes([{k: v for k, v in p.items() if k != "rounds"} for p in got]),
             r.selection.axes[per[1][1].axis].n_voxels,
             CR.ceiling(*([x for p in got for x in p["rounds"][k]] for k in ("1", "2", "pair"))))
            for (name, size, per, r, _), got in zip(scenes, passes)]
    body = doc(rows, quick, time.perf_counter() - t0)
    path = out_dir / "worksplit.md"
    path.write_text(body + "\n")
    return path


FEW = 5     # fewer rounds with two cores than this say too little: one slow 1-thread frame makes a round's gain


def _q(pair) -> str:
    return "{:.2f}-{:.2f}".format(*pair)


def ceiling_section(rows) -> list[str]:
    """The table of the machine's own ceiling, round by round (tests/ceiling_rounds.py), and issue 27 item 5's
    sentence per scene."""
    fl = CR.FLOOR
    L = ["", "### Two cores: the machine's own ceiling, round by round", "",
         "This machine's two vCPUs do not always give two cores' work: what they give two programs that share "
         "nothing swings between runs and within one (from under 1 to over 2). So every round times, back to "
         "back (each after an untimed frame of its kind, the three in each of their 6 orders in turn): the "
         "1-thread frame, the 2-thread frame and *two copies*, two one-thread frames of the same view at once, "
         "one per renderer of its own. Per round: the 2-thread *wall speed-up* (1 thread's wall time over 2 "
         "threads'), the *two copies: gain* (twice the 1-thread frame's wall time over the pair's: the "
         "machine's own ceiling in that round) and *of that*, speed-up over gain (what isplat makes of the cores "
         "the machine gave in that round). The table gives medians over the rounds of every pass (the first "
         "round of a pass, which learns the bands, left out), with of that's quartiles and range. A round whose "
         f"gain is below {fl} had less than two cores and says nothing about a speed-up of {fl} (issue 27 item "
         f"5): the last columns take the rounds with gain >= {fl} alone. A round's gain rests on one 1-thread frame "
         "and one pair, so a burst of load on the 1-thread frame alone can make one round look like two cores: "
         f"fewer than {FEW} such rounds say too little.", "",
         "| scene | rounds | wall speed-up, per round | two copies: gain | wall speed-up, of that | "
         "of that: quartiles | "
         f"of that: least-most | rounds with gain >= {fl} | there: wall speed-up | there: quartiles | "
         "there: of that |", "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for name, size, per, tm, n_vox, c in rows:
        there = ("| - | - | - |" if c.speedup_two_cores is None else
                 f"| {c.speedup_two_cores:.2f} | {_q(c.speedup_two_cores_quartiles)} | {c.of_two_cores:.2f} |")
        L.append(f"| {name}, {per[1][1].classification} | {c.rounds} | {c.speedup:.2f} | {c.gain:.2f} | {c.of:.2f} | "
                 f"{_q(c.of_quartiles)} | {_q(c.of_range)} | {c.two_cores} ({100 * c.share_two_cores:.0f}%) "
                 + there)
    L += ["", f"Issue 27 item 5 (2 threads at least {fl}x one thread):", ""]
    for name, size, per, tm, n_vox, c in rows:
        if c.speedup_two_cores is None:
            L.append(f"- {name}: in none of the {c.rounds} rounds did the machine give two cores (gain >= {fl}); "
                     "not shown either way.")
        else:
            spread = ("one round" if c.two_cores == 1 else
                      f"median; quartiles {_q(c.speedup_two_cores_quartiles)}")
            if c.two_cores < FEW:
                spread += f"; fewer than {FEW} rounds, too few to say"
            L.append(f"- {name}: where the machine gave two cores (rounds with gain >= {fl}: {c.two_cores} of "
                     f"{c.rounds}), the 2-thread speed-up was {c.speedup_two_cores:.2f} ({spread}), "
                     f"{c.of_two_cores:.2f} of the gain.")
    return L


def doc(rows, quick: bool, seconds: float) -> str:
    TECHNIQUES[:] = sorted({per[1][1].classification for _, _, per, _, _, _ in rows})    # the stamp's techniques
    L = ["# Work per frame: hidden material and threads", "",
         f"Made by `python -m benchmarks worksplit{' --quick' if quick else ''}` (part of `make bench`) on "
         f"{_doc.machine_line()}, git {_doc.git_rev()}, in {seconds:.0f} s. Do not edit: rerun the command.", "",
         "Counts are exact and do not depend on the machine's load; times are medians of frames interleaved in "
         "one run (this machine is shared, so the times are noisy, the counts are not). The head from the "
         "front, orthographic; the engine as examples/engine.toml shows it; square images; early "
         "termination at 0.99.", "",
         "## Hidden material costs one test per region, block or cell", "",
         "| scene | classification | image | voxels of interest | in slices traversed | in cells left | "
         "splatted or sampled | left / splatted or sampled |", "|---|---|---:|---:|---:|---:|---:|---:|"]
    for name, size, per, tm, n_vox, _ in rows:
        st = per[1][1]
        L.append(f"| {name} | {st.classification} | {size} | {n_vox:,} | {st.voxels_examined:,} | {st.voxels_tested:,} | "
                 f"{st.drawn:,} | {st.voxels_tested / max(st.drawn, 1):.2f} |")
    L += ["", "A voxel's cell (4 x 4 voxels of a slice) is left, and its voxels (pre-classified) or the quads "
          "they touch (post-classified) are visited, only when the cell, its block (16 x 16) and its region "
          "(64 x 64) can reach a pixel of the band that is not yet saturated; the rest cost one test per square, "
          "against a summed-area table of the whole tiles (8 x 8 pixels) whose pixels are all saturated. "
          "*Splatted or sampled*: voxels splatted (pre) or samples composited (post: one per pixel and slice "
          "where a quad of interest is seen).",
          "", "## Threads: repeated and serial work", "",
          "| scene | threads | bands | voxels tested | repeated work | predicted speed-up |",
          "|---|---:|---:|---:|---:|---:|"]
    for name, size, per, tm, n_vox, _ in rows:
        base = per[1][1].voxels_tested
        serial = tm["serial1"] / (tm["serial1"] + tm["work1"] + tm["rest1"])
        for t in THREADS:
            nb, st = per[t]
            rep = st.voxels_tested / max(base, 1) - 1.0
            L.append(f"| {name}, {per[1][1].classification} | {t} | {nb} | {st.voxels_tested:,} | {100 * rep:.1f}% | "
                     f"{predicted(serial, rep, t, nb):.2f} |")
    L += ["", "Measured on this machine, 1 thread against 2 (medians of interleaved frames, each timed frame after "
          "an untimed one of its kind, as in a run of frames; every scene measured in "
          f"{1 if quick else PASSES} passes over all the scenes, one after another, and the median of the passes "
          "given, with the CPU speed-up's range over them in the last column). Wall times suffer when other jobs "
          "take a core; CPU times (``time.thread_time`` of each rendering thread, and of the calling thread "
          "outside the parallel parts: the serial part) do not count waiting for a core, so the CPU "
          "speed-up is what 2 free cores would give, memory bandwidth aside. But this machine's two vCPUs do not "
          "always give twice the work of one, even when no other job is seen and no steal time is reported: "
          "between runs of this benchmark the CPU speed-ups differ widely, the threads' CPU times inflated "
          "when both run (the host's load, which the guest does not see). What the machine gives two cores is "
          "measured round by round below (*Two cores: the machine's own ceiling*).", "",
          "| scene | 1 thread (ms) | 2 threads (ms) | wall speed-up | threads' CPU, 1 thread (ms) | threads' CPU, "
          "2 threads: sum / busiest (ms) | imbalance | serial CPU, 2 threads (ms) | CPU speed-up | even bands: "
          "2 threads (ms) | imbalance | CPU speed-up | CPU speed-up, passes: least-most |",
          "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for name, size, per, tm, n_vox, _ in rows:
        L.append(f"| {name}, {per[1][1].classification} | {1e3 * tm['1']:.1f} | {1e3 * tm['2']:.1f} | {tm['1'] / tm['2']:.2f} | "
                 f"{1e3 * (tm['work1'] + tm['rest1']):.1f} | {1e3 * (tm['work2'] + tm['rest2']):.1f} / "
                 f"{1e3 * (tm['busiest2'] + tm['rest_busiest2']):.1f} | {tm['imbalance2']:.2f} | "
                 f"{1e3 * tm['serial2']:.2f} | {tm['cpu_speedup2']:.2f} | {1e3 * tm['2e']:.1f} | "
                 f"{tm['imbalance2e']:.2f} | {tm['cpu_speedup2e']:.2f} | "
                 "{:.2f}-{:.2f} |".format(*tm["cpu_speedup2_range"]))
    L += ["", "2 threads: each frame's bands cut where the frames before it found equal work "
          "(``isplat.frame.band_rows``: the CPU time of each band, spread over its rows; the first frame, "
          "not counted, cuts evenly). *Even bands*: frames that learn nothing, as the first frame of a process "
          "is (bands of one height, a free thread taking the next)."]
    L += ceiling_section(rows)
    L += ["", "| scene | ns per voxel of interest | ns per voxel splatted or sample | set-up per frame (ms) | "
          "serial share |", "|---|---:|---:|---:|---:|"]
    for name, size, per, tm, n_vox, _ in rows:
        L.append(f"| {name}, {per[1][1].classification} | {1e9 * tm['1'] / max(n_vox, 1):.1f} | "
                 f"{1e9 * tm['1'] / max(per[1][1].drawn, 1):.0f} | {1e3 * tm['prepare']:.2f} | "
                 f"{100 * tm['serial1'] / (tm['serial1'] + tm['work1'] + tm['rest1']):.1f}% |")
    L += ["", "If the frame's cost follows what is visible, the time per voxel splatted or sample stays about the same from "
          "scene to scene however much lies hidden, while the time per voxel of interest falls as more of them "
          "are hidden.", "", "Repeated work: the voxels in cells left, summed over the bands, over those with one band, "
          "minus one (a cell that crosses a band's edge is visited by both; post-classified, each band samples "
          "only its own pixels, so what is repeated is the per-cell and per-square set-up, not the samples). "
          "Serial share: the calling thread's CPU time outside the parallel parts (``isplat.frame.prepare``: "
          "tables, binning the regions to the bands) over the one-thread frame's CPU time; the parallel part is "
          "each thread's kernel and then finishing its bands' rows (premultiplied to straight over the "
          "background; ``isplat.frame.render_slab``'s ``finished``). "
          "Imbalance: the busiest thread's CPU time over the mean. Predicted speed-up on N cores: "
          "1 / (serial + (1 - serial) "
          "(1 + repeated) / min(N, bands)): a band is rendered by one thread, and bands are at least "
          "4 tiles (32 rows) high, so a 256-row image keeps at most 8 threads busy and a 1024-row one 32. "
          "Not counted in the prediction: memory bandwidth, which all cores share, and load imbalance "
          "between threads (measured above for 2 threads, with even and with learned bands; learned bands "
          "are two per thread, each thread's first twice its second, the large ones the image's middle and "
          "the small ones its top and bottom (``isplat.frame.band_layout``), as many cuts as the even bands "
          "counted here)."]
    return "\n".join(L)
