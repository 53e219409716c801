"""Frame times of isplat at several git revisions, in one process, frames interleaved (a developer's tool).

    python scripts/ab.py REV [REV ...] [--case "head translucent"] [--size 512] [--threads 1] [--rounds 15]
                         [--set KEY=VALUE ...] [--scene SCENE.toml]

This machine is shared, and the same frame's time differs by up to 1.5x between processes, so A/B runs in
separate processes cannot show a change of a few percent. Here each revision's ``isplat/`` is extracted
(``git archive``) as a package of its own (``isplat_0``, ``isplat_1``, ...; isplat imports itself only
relatively), each renders the same benchmarks/peers.py case from its own selection, and the frames go in turn,
round after round. Every copy compiles its kernels on the first run (into its own folder under
``out/ab/``), later runs load them.

In-process copies are not equal either. Every copy's frames are slower than the same frames in a process with
one isplat (its compiled code and the others' take turns in the caches and branch predictors), and the copy
loaded first measured 1-30% faster than an identical copy loaded after it (the cause is not known; three
selections of one package in one process render alike). So the times here are for comparing revisions with
one another, not for quoting, and the first revision given is a calibration copy, loaded first and left out
of the comparison: give the baseline twice (``python scripts/ab.py main main HEAD``) and compare the later
two, and swap their order to check. Printed: median time per revision and the median of the per-round
ratios to the second revision, with the images' equality to it (bit for bit).
"""

from __future__ import annotations

import argparse
import importlib
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "out" / "ab"


def extract(rev: str, name: str) -> Path:
    """``isplat/`` at ``rev`` as package ``name`` under out/ab/<sha>/ (kept: its compiled kernels too)."""
    sha = subprocess.run(["git", "rev-parse", "--short=12", rev], cwd=ROOT, capture_output=True, text=True,
                         check=True).stdout.strip()
    home = OUT / f"{sha}-{name}"
    if not (home / name).exists():
        home.mkdir(parents=True, exist_ok=True)
        tar = subprocess.run(["git", "archive", sha, "isplat"], cwd=ROOT, capture_output=True, check=True).stdout
        subprocess.run(["tar", "-x", "-C", str(home)], input=tar, check=True)
        (home / "isplat").rename(home / name)
    return home


def load(name: str, home: Path, sets: list[str], path: Path):
    sys.path.insert(0, str(home))
    scene_mod = importlib.import_module(name + ".scene")
    frame = importlib.import_module(name + ".frame")
    renderer = importlib.import_module(name + ".renderer")
    scene = scene_mod.load_scene(path, sets)
    r = renderer.Renderer(scene)
    img, _ = r.render_view(0)           # (the API every revision has; its frames learn their bands)
    return frame, r, r.views[0], img


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("revs", nargs="+", help="git revisions; the first is the calibration copy")
    ap.add_argument("--case", default="head translucent")
    ap.add_argument("--scene", type=Path, help="a scene file instead of a case (its data as it names them; "
                    "--size and --threads still apply)")
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--rounds", type=int, default=15)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a scene override after the case's, e.g. render.classification=\"pre\"")
    a = ap.parse_args(argv)
    if len(a.revs) < 3:
        ap.error("give a calibration revision, then at least two to compare")
    sys.path.insert(0, str(ROOT))
    from benchmarks import peers as P
    from benchmarks import reference as REF

    size = [f"image.width={a.size}", f"image.height={a.size}"]
    if a.scene is not None:
        path, sets = a.scene.resolve(), [*size, f"render.threads={a.threads}", *a.set]
        a.case = a.scene.name
    else:
        ov = P.CASES[a.case][3]
        sample, (aug, idx) = P.case_data(a.case)
        rel, ov0, _ = REF.CASES[sample]
        path = REF.REPO / rel
        sets = [f'data.augmented="{aug}"', f'data.index="{idx}"', *size, *ov0, *P.UNSHADED, *ov,
                *REF.render_overrides({"threads": a.threads}), *a.set]
    names = [f"isplat_{i}" for i in range(len(a.revs))]
    runs = {n: load(n, extract(rev, n), sets, path) for n, rev in zip(names, a.revs)}
    clock = time.thread_time if a.threads == 1 else time.perf_counter     # wall time when threads run
    times = {n: [] for n in names}
    for i in range(a.rounds):
        for n in (names if i % 2 == 0 else names[::-1]):
            r = runs[n][1]
            t = clock()
            r.render_view(0)
            times[n].append(clock() - t)
    base = names[1]
    print(f"{a.case}, {a.size} px, {a.threads} thread(s), {a.rounds} rounds "
          f"({'thread CPU' if a.threads == 1 else 'wall'} time):")
    for n, rev in zip(names, a.revs):
        ratios = sorted(x / y for x, y in zip(times[n], times[base]))
        note = "calibration, left out" if n == names[0] else \
            f"x{ratios[len(ratios) // 2]:.3f} of {a.revs[1]} (per-round median), same image: " \
            f"{np.array_equal(runs[n][3], runs[base][3])}"
        print(f"  {rev:>12}: {1e3 * statistics.median(times[n]):8.2f} ms  {note}")


if __name__ == "__main__":
    main()
