"""Variants of the post-classified sampler against a commit, one thread, interleaved (prints a table).

``python -m benchmarks.sampler_trees [--old REV] [--rounds N] [--cases 1,2,4] PATCH...`` (from the repository
root): each PATCH (a unified diff of isplat/, paths from the repository root, e.g.
benchmarks/table_layouts/A.patch) is applied with ``patch -p1`` to ``git archive REV isplat`` under
out/bench-sampler/trees/<patch name>/, and its frames are taken in
turn with REV's, round after round (the order reversed every other round), in worker processes of
:mod:`benchmarks.sampler` (its data, cases and worker; two more cases here, 4: the shaded chest with a coloured
light, whose Phong table has 6 columns, and 5: benchmarks/peers.py's translucent head at 256 px, unshaded, where
isplat's default was slower than VTK). Per case and patch: ns per sample of both, the median of the per-round
ratios, in how many rounds the patch was faster and the ratios' range, and whether the images are bit for bit
REV's (else the largest difference and the RMSE). Not part of ``python -m benchmarks all``.
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import subprocess
from pathlib import Path

import numpy as np

from benchmarks import sampler as S

COLOURED = ("chest veil + bone, shaded, coloured light", "chest",
            [*S.CHEST_TF, "shading.light=[{direction=[-0.4, 0.6, 1.0], color=[1.0, 0.85, 0.7]}]"])
# indices of --cases: benchmarks.sampler.CASES' first four, the coloured light, then the rest (5: benchmarks/peers.py's
# translucent head at 256 px)
ALL_CASES = [*S.CASES[:4], COLOURED, *S.CASES[4:]]


def tree(rev: str, patch: Path) -> Path:
    """``isplat/`` of ``rev`` with ``patch`` applied, under out/bench-sampler/trees/<name>/ (made afresh)."""
    home = S.WORK / "trees" / patch.stem
    shutil.rmtree(home, ignore_errors=True)
    home.mkdir(parents=True)
    shutil.copytree(S.old_tree(rev) / "isplat", home / "isplat", ignore=shutil.ignore_patterns("__pycache__"))
    subprocess.run(["patch", "-p1", "--quiet", "-i", str(patch.resolve())], cwd=home, check=True)
    return home


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m benchmarks.sampler_trees", description=__doc__.split("\n")[0])
    ap.add_argument("patches", nargs="+", type=Path)
    ap.add_argument("--old", default="HEAD", help="the commit the patches apply to and are measured against")
    ap.add_argument("--rounds", type=int, default=11)
    ap.add_argument("--cases", default="0,1,2,3", help="indices of benchmarks.sampler.CASES, 4: coloured light, "
                    "5: peers' head translucent at 256 px")
    a = ap.parse_args(argv)
    cases = [ALL_CASES[int(i)] for i in a.cases.split(",")]
    old = S.old_tree(a.old)
    files = S.data(False, old)
    workers = {"old": S.Worker(old)}
    names = [p.stem for p in a.patches]
    trees = {p.stem: tree(a.old, p) for p in a.patches}
    for n in names:
        workers[n] = S.Worker(trees[n])
    try:
        res = S.interleaved(workers, cases, files, a.rounds)
    finally:
        for w in workers.values():
            w.close()
    print(f"old = {a.old}, {a.rounds} rounds; ratio = median of the per-round ratios new / old")
    print("| case | variant | ns/sample old | new | ratio | rounds faster | ratios' range | images |")
    print("|---|---|---|---|---|---|---|---|")
    for ci, (cname, _, _) in enumerate(cases):
        for n in names:
            r = S.compare(res["old"][ci], res[n][ci])
            per = [y / x for x, y in zip(res["old"][ci]["s"], res[n][ci]["s"])]
            x, y = (np.load(res[w][ci]["image"]).astype(np.float64) for w in ("old", n))
            img = "bit for bit equal" if r["equal"] else \
                f"max difference {r['maxdiff']:.2e}, RMSE {float(np.sqrt(np.mean((x - y) ** 2))):.2e}"
            print(f"| {cname} | {n} | {r['old_ns']:.1f} | {r['new_ns']:.1f} | {statistics.median(per):.3f} | "
                  f"{sum(p < 1 for p in per)}/{len(per)} | {min(per):.3f}-{max(per):.3f} | {img} |", flush=True)


if __name__ == "__main__":
    main()
