"""How the bands a run of frames learns behave: this checkout's band learning against an older commit's.

``python -m benchmarks.bandlearn --old REV [--runs N] [--frames N] [--cases NAME,...] [--quick]`` prints a
Markdown table (from the repository root; the peers cases' data as ``python -m benchmarks.peers`` makes it).

What it measures. The learning of image bands (:func:`isplat.frame.learn_bands`) is plain Python; the old
commit's is loaded from ``git show REV:isplat/frame.py`` as a module of its own beside this checkout's
(:func:`old_learning`) and put in its place for the old runs, so both versions render with the same kernels and
only the learning differs. Per case (isplat's defaults, post-classified, all cores): ``runs`` learning runs of
``frames`` frames per version, each a process of its own started fresh (as a user's ``isplat render`` of a run of
frames: its first frames find cold caches and fresh memory, which the learning sees), the versions' runs in turn
(old first in even runs). Per run, over its second half (after the learning has had
its frames): the median of the busiest thread's CPU time over the mean (the bands' times as
:func:`isplat.frame._thread_sums` schedules them: what the learning sees), the median frame time, the number of
band layouts the run used, and whether it ended off the first frame's even bands. Shown per version: the median
of those over the runs and the worst run's (a run whose bands drifted is one in several: the median hides it), and
the runs' frame times new over old, paired run by run (median).

A frame on this shared host now and then has a band slowed by other work; the learning moved bands on one
such frame until b4b9000 (docs/design.md, *Bands cut by what the frames before found*).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
import types
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
CASES = ("head translucent", "engine", "chest")
SIZES = {"head translucent": 256}       # the others at 512 pixels, as in the peers table


def short_sha(rev: str, n: int = 7) -> str:
    return subprocess.run(["git", "rev-parse", f"--short={n}", rev], cwd=REPO, capture_output=True, text=True,
                          check=True).stdout.strip()


def old_learning(rev: str):
    """The module ``isplat/frame.py`` of commit ``rev``, run from ``git show`` as ``isplat._frame_<sha>`` (its
    relative imports are this checkout's isplat)."""
    sha = short_sha(rev, 12)
    src = subprocess.run(["git", "show", f"{sha}:isplat/frame.py"], cwd=REPO, capture_output=True, text=True,
                         check=True).stdout
    mod = types.ModuleType(f"isplat._frame_{sha}")
    mod.__package__ = "isplat"
    sys.modules[mod.__name__] = mod             # (its dataclasses look their module up there)
    exec(compile(src, f"{sha}:isplat/frame.py", "exec"), mod.__dict__)
    return mod


def one_run(sel, view, frames: int, learn) -> dict:
    """``frames`` frames from a fresh BandLearning with ``learn`` as isplat.frame.learn_bands."""
    from isplat import frame as F

    keep = F.learn_bands
    F.learn_bands = learn
    try:
        bands, ms, ratio, layouts = F.BandLearning(), [], [], set()
        for _ in range(frames):
            t = time.perf_counter()
            F.render_frame(sel, view, None, bands)
            ms.append(1e3 * (time.perf_counter() - t))
            bt = bands.pending[-1]
            per = F._thread_sums(bt.band_seconds, bt.threads, bt.queue)
            ratio.append(float(per.max() / per.mean()))
            layouts.add((tuple(bt.rows[:, 0].tolist()), tuple(bt.queue.tolist())))
        even = tuple(F.image_bands(view.frame.height, bt.threads)[:, 0].tolist())
    finally:
        F.learn_bands = keep
    half = frames // 2
    return dict(ms=statistics.median(ms[half:]), ratio=statistics.median(ratio[half:]), layouts=len(layouts),
                moved=tuple(bt.rows[:, 0].tolist()) != even)


def child(case: str, version: str, rev: str, frames: int, quick: bool) -> dict:
    """One run in this process, started fresh as a user's ``isplat render`` of a run of frames is: the scene
    loaded, then ``frames`` frames (the first ones finding cold caches and fresh memory, as a user's do)."""
    from isplat import frame as F
    from isplat.renderer import Renderer

    from . import peers

    scene = peers.peer_scene(case, 48 if quick else SIZES.get(case, 512), quick)
    r = Renderer(scene)
    view = F.views_for(scene, r.selection)[0]
    learn = old_learning(rev).learn_bands if version == "old" else F.learn_bands
    return one_run(r.selection, view, frames, learn)


def measure(case: str, rev: str, runs: int, frames: int, quick: bool) -> dict:
    """``runs`` runs per version, each a process of its own (:func:`child`), the versions in turn."""
    out = {"old": [], "new": []}
    for i in range(runs):
        for v in (("old", "new") if i % 2 == 0 else ("new", "old")):
            cmd = [sys.executable, "-m", "benchmarks.bandlearn", "--child", case, v, "--old", rev,
                   "--frames", str(frames)] + (["--quick"] if quick else [])
            got = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, check=True).stdout
            out[v].append(json.loads(got.strip().splitlines()[-1]))
    print(f"[bandlearn] {case}: " + ", ".join(
        f"{v} {statistics.median(x['ms'] for x in out[v]):.2f} ms" for v in out), file=sys.stderr)
    return out


def table(results: dict, sha: str, head: str, runs: int, frames: int) -> str:
    """The Markdown table of :func:`measure`'s results per case.

    >>> run = lambda ms, moved: dict(ms=ms, ratio=1.02, layouts=1 + moved, moved=moved)
    >>> print(table({"c": {"old": [run(10.0, True), run(9.0, False)], "new": [run(9.5, False), run(9.0, False)]}},
    ...             "abc1234", "def5678", 2, 10).splitlines()[3])
    | c | def5678 (this checkout) | 0 of 2 | 1 | 1.020; 1.020 | 9.25; 9.50 | 0.975 |
    """
    med = statistics.median
    rows = ["| case | version | runs ended off the even bands | layouts used (median) | busiest thread / mean, "
            "second half (median of runs; worst run) | frame ms, second half (median of runs; worst run) | new / old "
            "frame, paired runs (median) |", "|---|---|---:|---:|---:|---:|---:|"]
    for case, out in results.items():
        paired = med(b["ms"] / a["ms"] for a, b in zip(out["old"], out["new"]))
        for v, label in (("old", f"{sha} (old)"), ("new", f"{head} (this checkout)")):
            x = out[v]
            rows.append(f"| {case} | {label} | {sum(r['moved'] for r in x)} of {len(x)} | "
                        f"{med(r['layouts'] for r in x):g} | {med(r['ratio'] for r in x):.3f}; {max(r['ratio'] for r in x):.3f} | "
                        f"{med(r['ms'] for r in x):.2f}; {max(r['ms'] for r in x):.2f} | "
                        f"{'' if v == 'old' else f'{paired:.3f}'} |")
    return "\n".join(rows) + (f"\n\n{runs} runs of {frames} frames per version and case, the versions' runs in turn; "
                              "per run the medians over its second half.")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.bandlearn", description=__doc__.split("\n\n")[0])
    ap.add_argument("--old", required=True, help="the commit whose band learning is compared")
    ap.add_argument("--runs", type=int, default=6)
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--cases", default=",".join(CASES), help="peers cases, comma-separated")
    ap.add_argument("--quick", action="store_true", help="tiny volumes and images, 2 runs of 8 frames")
    ap.add_argument("--child", nargs=2, metavar=("CASE", "VERSION"), help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    runs, frames = (2, 8) if a.quick else (a.runs, a.frames)
    if a.child:
        print(json.dumps(child(*a.child, a.old, frames, a.quick)))
        return 0
    sha = short_sha(a.old, 12)
    results = {c: measure(c, sha, runs, frames, a.quick) for c in a.cases.split(",")}
    print(table(results, sha[:7], short_sha("HEAD"), runs, frames))
    return 0


if __name__ == "__main__":
    sys.exit(main())
