"""The brick edge of augmented format 6 (formats/augmented.md §2.3), by measurement: ``python -m benchmarks.brick_edge
[--quick] [--cases H1,E2,...] [--repeats N]`` prints a table (not a docs page).

For each case of :mod:`benchmarks.selective_read` the same volume is written as format 6 with 4^3 and 8^3 bricks and
as format 4 (whole rows), indexed once, and post's scene (one view, one thread) is loaded from each, the three
interleaved in rotating order after a warm-up round (page cache warm), median of ``--repeats``: post's bytes read
from the augmented file / its bytes needed, held bytes per voxel of interest, load and frame time, and the load
ratios against format 4 (median of the per-round ratios).
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
from pathlib import Path

from .selective_read import _index, _once, _scene, as_version


def main(argv=None) -> int:
    from isplat.scene import load_scene

    ap = argparse.ArgumentParser(prog="python -m benchmarks.brick_edge", description=__doc__)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--cases", default="H1,E2,B1,H1-512,C1")
    ap.add_argument("--repeats", type=int, default=5)
    a = ap.parse_args(argv)
    want = a.cases.split(",")
    print("| case | file | augmented file (MB) | values from | read / needed | held per voxel of interest (B) | "
          "load (ms) | load / format 4 | frame (ms) |\n|---|---|---:|---|---:|---:|---:|---:|---:|", flush=True)
    with tempfile.TemporaryDirectory(prefix="isplat-edge-") as t:
        work = Path(t)
        for c in _cases(work, a.quick, want):
            files = {"format 6, 4^3": as_version(c["aug"], work / "e4.aug.h5", 6, 4),
                     "format 6, 8^3": as_version(c["aug"], work / "e8.aug.h5", 6, 8),
                     "format 4": as_version(c["aug"], work / "v4.aug.h5", 4)}
            idx = work / f"{c['name']}.idx.h5"
            _index(files["format 4"], idx, a.quick)
            scenes = {}
            for k, f in files.items():
                c["aug"], c["aug_v4"] = f, f
                scenes[k] = load_scene(_scene(work, c, idx, "post"))
            order = list(files)
            loads, frames, last = {k: [] for k in order}, {k: [] for k in order}, {}
            for n in range(a.repeats + 1):
                for k in order[n % 3:] + order[:n % 3]:
                    load, frame, rep, held = _once(scenes[k])
                    if n:
                        loads[k].append(load)
                        frames[k].append(frame)
                    last[k] = (rep, held)
            for k in order:
                rep, held = last[k]
                ratio = statistics.median(x / y for x, y in zip(loads[k], loads["format 4"]))
                size = files[k].stat().st_size
                print(f"| {c['name']} | {k} | {size / 1e6:.1f} | {rep.values_from} | "
                      f"{rep.read_ratio:.2f} (channels {rep.augmented_file_bytes / max(1, rep.channel_bytes_needed):.2f}) | {held / max(1, rep.voxels_of_interest):.1f} | "
                      f"{1000 * statistics.median(loads[k]):.0f} | {ratio:.2f} | "
                      f"{1000 * statistics.median(frames[k]):.0f} |", flush=True)
            for f in list(files.values()) + [idx, Path(str(idx).replace(".idx.h5", ".values.idx.h5"))]:
                f.unlink(missing_ok=True)
    return 0


def _cases(work, quick, want):
    """The cases of :func:`benchmarks.selective_read.cases` named in ``want``, augmented one at a time (B1: the
    synthetic mr-head sample)."""
    from . import selective_read as S
    from .paper import TF_BOLTS, TF_BONE, TF_MRI

    f = 4 if quick else 1
    specs = {"H1": ("head", (256, 256, 225), TF_BONE, {}, {}),
             "E2": ("engine", (256, 256, 110), TF_BOLTS, dict(azimuth=35, elevation=25), {}),
             "B1": ("mr-head", (256, 256, 167), TF_MRI, dict(azimuth=180), {}),
             "H1-512": ("head", (512, 512, 512), TF_BONE, {}, {}),
             "C1": ("ct-chest", (512, 512, 133), S.TF_CHEST, dict(azimuth=0, elevation=10), S.CHEST)}
    for name in want:
        sample, shape, tf, view, kw = specs[name]
        small = tuple(max(8, n // f) for n in shape)
        aug = work / f"{name}.aug.h5"
        S._augment(sample, small, aug, quick, **kw)
        yield dict(name=name, what=name, aug=aug, tf=tf, **view, source=sample)
        aug.unlink()


if __name__ == "__main__":
    raise SystemExit(main())
