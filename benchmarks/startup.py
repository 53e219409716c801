"""Start-up: ``python -m benchmarks startup [--quick]`` (part of ``make bench``) writes docs/startup.md.

Where the time of a one-frame ``isplat render`` process goes, and what the first run on a new machine compiles:

1. Warm (numba's cache present): a child process runs the steps of ``isplat render`` one after the other and
   stamps each (import numpy, the CLI, the scene, numba, the renderer's modules, ``Renderer`` (index, selection,
   the first cached kernels), the first frame, a second frame, the PNG), then leaves with ``os._exit`` as the
   ``isplat`` command does, or through Python's normal teardown; the parent times the whole process, so the
   teardown is the time after the last stamp. A third kind of run loads the kernels as numba does
   (``ISPLAT_NUMBA_STOCK_LOAD=1``: its target refreshed first). Repeated, the three interleaved.
2. Cold (an empty ``NUMBA_CACHE_DIR``, no prebuilt kernels): the same child with numba's ``Dispatcher.compile``
   timed per top-level function, once at numba's default optimisation and once at ``NUMBA_OPT=0`` (how much of
   the compile time is LLVM's optimiser).
3. Cold with the kernels prebuilt for x86-64-v3 (:mod:`isplat.prebuilt`, built into a temporary folder and
   timed): the same child with an empty numba cache, repeated; and, interleaved with the warm runs, warm
   children that take their kernels from the prebuilt folder, so the second frame of the portable kernels
   compares with the second frame of kernels compiled for this CPU.

Both with Python's bytecode cache on, as a package installed by pip has it.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from . import _doc

TECHNIQUES = ["post"]     # render.classification of its rows (the page's stamp)
SOURCES = _doc.sources(("isplat/**", "examples/head.toml", "benchmarks/startup.py"))
from .render import ROOT, SCENE, ensure_head

SIZE = 512
CHILD = r'''
import json, os, sys, time
T = [("start", time.time())]
def mark(name):
    T.append((name, time.time()))
compiles = []
if os.environ.get("STARTUP_COMPILES") == "1":
    import numba.core.dispatcher as D
    orig, depth = D.Dispatcher.compile, [0]
    def compile(self, sig):
        depth[0] += 1
        t = time.perf_counter()
        try:
            return orig(self, sig)
        finally:
            depth[0] -= 1
            if depth[0] == 0:
                compiles.append((self.py_func.__module__ + "." + self.py_func.__name__, time.perf_counter() - t))
    D.Dispatcher.compile = compile
    mark("numba (for timing compiles)")
import numpy
mark("import numpy")
import isplat.cli.main, isplat.cli.render
mark("import the CLI (click)")
from isplat.scene import load_scene
scene = load_scene(sys.argv[1], sys.argv[3:])
mark("read the scene")
import numba
mark("import numba")
from isplat.renderer import Renderer
from isplat.output import write_still
mark("import the renderer")
r = Renderer(scene, scene.views)
mark("Renderer: index, selection, first kernels")
rgba, st = r.render_view(0)
mark("first frame")
r.render_view(0)
mark("second frame (for comparison)")
write_still(sys.argv[2], rgba, scene.image.bit_depth, True)
mark("write the PNG")
print(json.dumps({"marks": T, "compiles": compiles}), flush=True)
if os.environ.get("STARTUP_EXIT") == "os":
    sys.stdout.flush()
    os._exit(0)
'''


def _log(msg):
    print(f"[startup] {msg}", file=sys.stderr, flush=True)


def child_run(scene_args, env_extra: dict) -> dict:
    """One child process: its stamps, compile times, and the teardown (process end after the last stamp)."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env.update(env_extra)
    with tempfile.TemporaryDirectory(prefix="isplat-startup-") as tmp:
        t0 = time.time()
        r = subprocess.run([sys.executable, "-c", CHILD, str(SCENE), str(Path(tmp) / "f.png"), *scene_args],
                           capture_output=True, text=True, env=env, cwd=ROOT)
        t1 = time.time()
    if r.returncode != 0:
        raise RuntimeError(f"startup child failed: {r.stderr.strip()[-500:]}")
    d = json.loads(r.stdout.strip().splitlines()[-1])
    marks = [("interpreter start", t0)] + d["marks"][1:]       # "start" is the first line of the child
    steps = [(name, b - a) for (_, a), (name, b) in zip(marks, marks[1:])]
    return dict(steps=steps, teardown=t1 - marks[-1][1], total=t1 - t0, compiles=d["compiles"])


def run(out_dir: Path, quick: bool) -> Path:
    t_start = time.perf_counter()
    aug, idx = ensure_head((64, 64, 56) if quick else None)
    size = 64 if quick else SIZE
    args = [f'data.augmented="{aug}"', f'data.index="{idx}"', f"image.width={size}", f"image.height={size}"]
    repeats = 1 if quick else 5
    from isplat import prebuilt as PB

    with tempfile.TemporaryDirectory(prefix="isplat-prebuilt-") as tmp:
        pre = None
        if not quick and PB.portable_here():
            _log("prebuilt kernels (python -m isplat.prebuilt)")
            t = time.perf_counter()
            PB.build(str(Path(tmp) / "pre"))
            pre = dict(build=time.perf_counter() - t, cold=[])
        _log("warm")
        host = {"ISPLAT_PREBUILT": "none"}
        child_run(args, host)                                   # numba's cache and .pyc files made
        warm = {"os": [], "normal": [], "stock": [], "prebuilt": []}
        env = {"os": {"STARTUP_EXIT": "os", **host}, "normal": {"STARTUP_EXIT": "normal", **host},
               "stock": {"STARTUP_EXIT": "os", "ISPLAT_NUMBA_STOCK_LOAD": "1", **host},
               "prebuilt": {"STARTUP_EXIT": "os", "ISPLAT_PREBUILT": str(Path(tmp) / "pre"),
                            "NUMBA_CACHE_DIR": str(Path(tmp) / "user")}}
        kinds = ("os", "normal", "stock") + (("prebuilt",) if pre else ())
        if pre:
            child_run(args, env["prebuilt"])                    # what was not prebuilt (stages) compiled once
        for i in range(repeats):
            for how in (kinds if i % 2 == 0 else kinds[::-1]):
                warm[how].append(child_run(args, env[how]))
        cold = {}
        for opt in ((None,) if quick else (None, "0")):
            _log(f"cold, NUMBA_OPT={opt or 'default'}")
            with tempfile.TemporaryDirectory(prefix="isplat-numba-empty-") as cache:
                env = {"NUMBA_CACHE_DIR": cache, "STARTUP_COMPILES": "1", "STARTUP_EXIT": "os", **host}
                if opt is not None:
                    env["NUMBA_OPT"] = opt
                cold[opt or "default"] = child_run(args, env)
        for _ in range(repeats if pre else 0):
            _log("cold, prebuilt kernels")
            with tempfile.TemporaryDirectory(prefix="isplat-numba-empty-") as cache:
                pre["cold"].append(child_run(args, {"NUMBA_CACHE_DIR": cache, "STARTUP_COMPILES": "1",
                                                    "STARTUP_EXIT": "os", "ISPLAT_PREBUILT": str(Path(tmp) / "pre")}))
    body = doc(warm, cold, size, quick, time.perf_counter() - t_start, pre)
    path = out_dir / "startup.md"
    path.write_text(body + "\n")
    return path


def _med(xs) -> float:
    return statistics.median(xs)


def scene_technique(path=SCENE) -> str:
    """render.classification of the scene the processes render ("post": the default since scene version 4)."""
    from isplat.scene import load_scene

    return load_scene(path).render.classification


def doc(warm, cold, size, quick, seconds, pre=None) -> str:
    runs = warm["os"]
    tech = scene_technique()
    TECHNIQUES[:] = [tech]                  # the stamp names the technique examples/head.toml renders with
    names = [n for n, _ in runs[0]["steps"]]
    L = ["# Start-up: one frame as a process, and the first run on a machine", "",
         f"Made by `python -m benchmarks startup{' --quick' if quick else ''}` (part of `make bench`) on "
         f"{_doc.machine_line()}, git {_doc.git_rev()}, in {seconds:.0f} s. Do not edit: rerun the command.", "",
         f"The steps of `isplat render examples/head.toml` (the head sample, {size} x {size}, shaded bone; "
         f"technique {tech}, `render.classification = \"{tech}\"`, in every run below) in a "
         "child process, each stamped; the parent times the whole process, so *teardown* is from the last stamp "
         "to the process's end. Medians of "
         f"{len(runs)} runs of each kind (leaving with `os._exit` or through Python's normal exit, and the "
         "kernels loaded as numba does it, below), the kinds interleaved; Python's bytecode cache on, as "
         "installed by pip.",
         "", "## Warm: numba's cache present", "",
         "| step | ms (median) | range |", "|---|---:|---:|"]
    for k, name in enumerate(names):
        xs = [1e3 * r["steps"][k][1] for r in runs]
        L.append(f"| {name} | {_med(xs):.0f} | {min(xs):.0f}-{max(xs):.0f} |")
    for how, label in (("os", "teardown, `os._exit` (as the `isplat` command leaves)"),
                       ("normal", "teardown, Python's normal exit")):
        xs = [1e3 * r["teardown"] for r in warm[how]]
        L.append(f"| {label} | {_med(xs):.0f} | {min(xs):.0f}-{max(xs):.0f} |")
    for how, label in (("os", "whole process, `os._exit`"), ("normal", "whole process, normal exit")):
        xs = [1e3 * r["total"] for r in warm[how]]
        L.append(f"| **{label}** | **{_med(xs):.0f}** | {min(xs):.0f}-{max(xs):.0f} |")
    renderer = names.index("Renderer: index, selection, first kernels")
    stock = {k: [1e3 * r[k] for r in warm["stock"]] for k in ("total",)}
    stock["renderer"] = [1e3 * r["steps"][renderer][1] for r in warm["stock"]]
    ours = [1e3 * r["steps"][renderer][1] for r in runs]
    L += ["", "numba costs a one-frame process three things: its import, loading each kernel's machine code (the "
          "first frame is slower than the second by the kernels it loads), and, as numba does it, setting up its "
          "compiler target before the first kernel is loaded from the cache: it imports and installs every typing "
          "and lowering registry, which only compiling needs. isplat loads its kernels without that refresh "
          "(`isplat.jit._CacheLoad`: numba's runtime is initialised, nothing else; a compile still refreshes). "
          f"Loaded as numba does it (`ISPLAT_NUMBA_STOCK_LOAD=1`, interleaved with the runs above): the "
          f"*Renderer* step takes {_med(stock['renderer']):.0f} ms against {_med(ours):.0f} ms, the whole "
          f"process (`os._exit`) {_med(stock['total']):.0f} ms (range {min(stock['total']):.0f}-"
          f"{max(stock['total']):.0f}) against {_med([1e3 * r['total'] for r in runs]):.0f} ms.", "",
          "## Cold: an empty numba cache (the first run on a machine)", "",
          "| | " + " | ".join(f"NUMBA_OPT={k}" for k in cold) + " |",
          "|---|" + "---:|" * len(cold)]
    L.append("| whole process (s) | " + " | ".join(f"{c['total']:.1f}" for c in cold.values()) + " |")
    first_run = next(iter(cold.values()))["total"]
    L[-3:-3] = [f"**The first run on a machine compiles: {first_run:.1f} s** for the whole process (technique "
                f"{tech}, numba's default optimisation, no prebuilt kernels). This is the one place that figure is "
                "measured: the README, docs/design.md, docs/performance.md and isplat's own \"compiling the "
                "kernels\" line refer here rather than repeat it.", ""]
    L.append("| compiling, all top-level kernels (s) | " +
             " | ".join(f"{sum(t for _, t in c['compiles']):.1f}" for c in cold.values()) + " |")
    first = next(iter(cold.values()))["compiles"]
    L += ["", "Top-level kernels compiled (each with the functions it calls), at numba's default optimisation:", "",
          "| kernel | s |", "|---|---:|"]
    for name, t in sorted(first, key=lambda x: -x[1]):
        L.append(f"| `{name}` | {t:.2f} |")
    L += ["", "With `NUMBA_OPT=0` LLVM hardly optimises, so the difference between the columns is LLVM's share; "
          "the rest is numba's typing and lowering, which grows with the number of compiled functions and "
          "their argument types (each distinct set of argument types is compiled again)."]
    return "\n".join(L + (_prebuilt_doc(warm, pre) if pre else []))


def _prebuilt_doc(warm, pre) -> list[str]:
    second = [n for n, _ in warm["os"][0]["steps"]].index("second frame (for comparison)")
    frame = {k: [1e3 * r["steps"][second][1] for r in warm[k]] for k in ("os", "prebuilt")}
    total = [r["total"] for r in pre["cold"]]
    compiled = [sum(t for _, t in r["compiles"]) for r in pre["cold"]]
    return ["", "## Cold with prebuilt kernels (`make prebuilt`; `make demo` makes them too)", "",
            f"`python -m isplat.prebuilt` compiled the kernels for x86-64-v3 in {pre['build']:.0f} s. With them "
            "in the package and an empty numba cache, the first run on a machine (medians of "
            f"{len(total)}):", "", "| | s (median) | range |", "|---|---:|---:|",
            f"| **whole process** | **{_med(total):.2f}** | {min(total):.2f}-{max(total):.2f} |",
            f"| in numba's compile calls (loading the prebuilt kernels; compiling what was not prebuilt) | "
            f"{_med(compiled):.2f} | {min(compiled):.2f}-{max(compiled):.2f} |",
            "", "The portable kernels against kernels compiled for this CPU, the second frame of the warm runs above "
            f"(interleaved): {_med(frame['prebuilt']):.1f} ms (range {min(frame['prebuilt']):.1f}-"
            f"{max(frame['prebuilt']):.1f}) against {_med(frame['os']):.1f} ms ({min(frame['os']):.1f}-"
            f"{max(frame['os']):.1f})."]
