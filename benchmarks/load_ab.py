"""Post's load from a bricked augmented file (format 6), an older commit against the working tree, interleaved:

    python -m benchmarks.load_ab [--old main] [--rounds 9] [--cases H1,C1,H1-512,whole-H1] [--work out/load_ab]
    python -m benchmarks.load_ab --cli [--old main] [--rounds 7] [--cases H1,C1]

Cases (benchmarks/selective_read.py makes the same volumes): H1, the head sample at 256 x 256 x 225 with the bone
scene; C1, the ``ct-chest`` sample at 512 x 512 x 133 (spacing 0.703125, 0.703125, 2.5; window -1000..2000) with
its fat/skin veil and bone; H1-512, the head at 512^3, bone. Each is augmented (format 6, 8^3 bricks) once into
``--work`` (kept for later runs) and indexed by each version (``isplat index``, its index and runs file in a folder
of its own: the old commit's kept under its sha, the working tree's written again each run), so that each reads
the files its own writer makes (the runs file's format changed at version 2). *Load*: constructing
``isplat.renderer.Renderer`` for the scene's first view (open both files, read the index blocks, select, read the
bricks post needs), as ``isplat render`` does before its first frame; then one frame is rendered (its thread CPU
time measured too: the frame code is the same, so its ratio shows the noise) and its image compared between the
versions, bit for bit. *whole-X*:
``open_augmented`` and ``read`` of the three whole channels of case X's file (the arrays compared).

``--cli``: instead, ``python -m isplat render SCENE -o PNG`` of each case's scene, one process per picture as users
run it (start, imports, kernels loaded from their caches, load, frame, PNG written), its wall time, the versions
alternating per round; the PNGs compared byte for byte.

Each version runs in a worker process of its own (the old one from ``git archive`` of its ``isplat/`` under
``--work``/trees, its kernels compiled there once); per round the versions go in turn (the order alternating), so
the shared machine's load falls on both alike. Printed per case: the median times and the median of the per-round
ratios new / old, after one warm-up round (compiles, page cache).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CASES = {"H1": ("head", (256, 256, 225), "bone", {}),
         "C1": ("ct-chest", (512, 512, 133), "chest",
                dict(spacing=(0.703125, 0.703125, 2.5), window=(-1000.0, 2000.0))),
         "H1-512": ("head", (512, 512, 512), "bone", {})}

WORKER = r"""
import hashlib, json, sys, time
import numpy as np
sys.path.insert(0, sys.argv[1])
from isplat.augfile import open_augmented
from isplat.renderer import Renderer
from isplat.scene import load_scene

for line in sys.stdin:
    kind, arg = json.loads(line)
    if kind == "load":
        scene = load_scene(arg)
        t = time.perf_counter()
        r = Renderer(scene, (scene.views[0],), slabs=1)
        dt = time.perf_counter() - t
        t = time.thread_time()
        img, _ = r.render_view(0)
        frame = time.thread_time() - t
        digest = hashlib.sha256(np.ascontiguousarray(img).tobytes()).hexdigest()
        del r
    else:
        t = time.perf_counter()
        a = open_augmented(arg)
        chans = [a.read(ch) for ch in ("density", "gradient_magnitude", "normal")]
        dt = time.perf_counter() - t
        h = hashlib.sha256()
        for c in chans:
            h.update(c.tobytes())
        digest, frame = h.hexdigest(), 0.0
        del chans
    print(json.dumps([dt, digest, frame]), flush=True)
"""


def make_case(name: str, work: Path, root: Path, again: bool) -> tuple[Path, Path, Path]:
    """Case ``name``'s augmented file (in ``work``), and its index and post scene (in ``work``/``root``'s folder
    name) as ``root``'s ``isplat index`` writes them (made once, in subprocesses; ``again``: the index written
    again)."""
    from .paper import _COMMON, TF_BONE
    from .selective_read import TF_CHEST

    sample, shape, tf, kw = CASES[name]
    own = work / ("new" if root == ROOT else root.name)
    own.mkdir(parents=True, exist_ok=True)
    aug, idx, scene = work / f"{name}.aug.h5", own / f"{name}.idx.h5", own / f"{name}-post.toml"
    if not aug.exists():
        subprocess.run([sys.executable, "-c", "from benchmarks.selective_read import augment_sample; from pathlib "
                        f"import Path; augment_sample({sample!r}, {shape!r}, Path({str(aug)!r}), **{kw!r})"],
                       check=True, cwd=ROOT)
    if again or not idx.exists():
        subprocess.run([sys.executable, "-m", "isplat", "index", str(aug), "-o", str(idx), "-q", "--force"],
                       check=True, cwd=root)
    view = dict(azimuth=0, elevation=10)
    scene.write_text(f'version = 4\n\n[data]\naugmented = "{aug}"\nindex = "{idx}"\n'
                     + _COMMON.format(size=256, threads=1, technique="post", **view) + "\n"
                     + (TF_BONE if tf == "bone" else TF_CHEST))
    return aug, idx, scene


def tree(rev: str, work: Path) -> Path:
    """``isplat/`` at ``rev`` under ``work``/trees/<sha> (kept, with its compiled kernels)."""
    from .sampler import old_tree

    return old_tree(rev, work / "trees")


class Worker:
    def __init__(self, root: Path):
        self.p = subprocess.Popen([sys.executable, "-c", WORKER, str(root)], stdin=subprocess.PIPE,
                                  stdout=subprocess.PIPE, text=True, cwd=str(root))

    def run(self, job) -> tuple[float, str, float]:
        self.p.stdin.write(json.dumps(job) + "\n")
        self.p.stdin.flush()
        line = self.p.stdout.readline()
        if not line:
            raise RuntimeError(f"worker failed on {job}")
        return tuple(json.loads(line))

    def close(self):
        self.p.stdin.close()
        self.p.wait()


def cli_rounds(cases, trees: dict, rounds: int, work: Path) -> None:
    """``--cli``: one ``isplat render`` process per picture, per version (``cases``: per case, each version's
    scene), alternating; prints medians and ratios."""
    import time

    times = {(c, v): [] for c in cases for v in trees}
    same = {c: True for c in cases}
    for n in range(rounds + 1):                         # round 0 warms up (compiles into each tree's caches)
        for c, scene in cases.items():
            png = {}
            for v in (("old", "new") if n % 2 else ("new", "old")):
                png[v] = work / f"cli-{c}-{v}.png"
                t = time.perf_counter()
                subprocess.run([sys.executable, "-m", "isplat", "render", str(scene[v]), "-o", str(png[v]), "-q",
                                "--force"], check=True, cwd=str(trees[v]))
                if n:
                    times[(c, v)].append(time.perf_counter() - t)
            same[c] &= png["old"].read_bytes() == png["new"].read_bytes()
        print(f"round {n} done", file=sys.stderr, flush=True)
    print(f"isplat render, one process per picture, {rounds} rounds (median; ratio: median of per-round new / old):")
    for c in cases:
        old, new = times[(c, "old")], times[(c, "new")]
        ratio = statistics.median(x / y for x, y in zip(new, old))
        print(f"  {c:>9}: old {1000 * statistics.median(old):7.1f} ms  new {1000 * statistics.median(new):7.1f} ms  "
              f"new / old x{ratio:.3f}  {'same PNG' if same[c] else 'DIFFERENT'}")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--old", default="main")
    ap.add_argument("--rounds", type=int, default=9)
    ap.add_argument("--cases", default="H1,C1,H1-512,whole-H1")
    ap.add_argument("--work", type=Path, default=ROOT / "out" / "load_ab")
    ap.add_argument("--cli", action="store_true", help="time `isplat render` processes, one per picture")
    a = ap.parse_args(argv)
    a.work.mkdir(parents=True, exist_ok=True)
    roots = {"old": tree(a.old, a.work), "new": ROOT}
    bases = {c.removeprefix("whole-") for c in a.cases.split(",")}
    per = {(b, v): make_case(b, a.work, root, again=v == "new") for b in sorted(bases) for v, root in roots.items()}
    made = {(c, v): per[(c.removeprefix("whole-"), v)] for c in a.cases.split(",") for v in roots}
    if a.cli:
        cases = {c: {v: made[(c, v)][2] for v in roots} for c in a.cases.split(",") if not c.startswith("whole-")}
        cli_rounds(cases, roots, a.rounds, a.work)
        return
    jobs = {(c, v): ["whole", str(made[(c, v)][0])] if c.startswith("whole-") else ["load", str(made[(c, v)][2])]
            for c, v in made}
    workers = {v: Worker(root) for v, root in roots.items()}
    times = {cv: [] for cv in jobs}
    frames = {cv: [] for cv in jobs}
    kinds = {c: job[0] for (c, _), job in jobs.items()}
    same = dict.fromkeys(kinds, True)
    try:
        for n in range(a.rounds + 1):                   # round 0 warms up (compiles, page cache)
            for c in kinds:
                got = {}
                for v in (("old", "new") if n % 2 else ("new", "old")):
                    got[v] = workers[v].run(jobs[(c, v)])
                    if n:
                        times[(c, v)].append(got[v][0])
                        frames[(c, v)].append(got[v][2])
                same[c] &= got["old"][1] == got["new"][1]
            print(f"round {n} done", file=sys.stderr, flush=True)
    finally:
        for w in workers.values():
            w.close()
    print(f"old {a.old} against the working tree, {a.rounds} rounds (median; ratio: median of per-round new / old):")
    for c in kinds:
        old, new = times[(c, "old")], times[(c, "new")]
        ratio = statistics.median(x / y for x, y in zip(new, old))
        frame = ""
        if kinds[c] == "load":
            fo, fn = frames[(c, "old")], frames[(c, "new")]
            frame = (f"  frame old {1000 * statistics.median(fo):.1f} ms new {1000 * statistics.median(fn):.1f} ms "
                     f"x{statistics.median(x / y for x, y in zip(fn, fo)):.3f}")
        same_text = ("same " + ("image" if kinds[c] == "load" else "arrays")) if same[c] else "DIFFERENT"
        print(f"  {c:>9}: load old {1000 * statistics.median(old):7.1f} ms  new {1000 * statistics.median(new):7.1f} "
              f"ms  new / old x{ratio:.3f}  {same_text}{frame}")


if __name__ == "__main__":
    main()
