"""Whole reads of an augmented file, format 6 (isplat's brick store) and format 5 (8^3 bricks as HDF5 chunks)
against the same volume as format 4 (chunks of whole rows): ``python -m benchmarks.whole_read [--shape NI,NJ,NK]
[--repeats N]`` prints a table (not a docs page).

Per format, interleaved in rotating order after a warm-up round (page cache warm), median of ``--repeats``:
*read*: the three channels read whole (``AugmentedVolume.read``, every chunk checked); *stats*: ``isplat stats``'s
chunk check (``AugmentedVolume.verify_all``); *index*: ``isplat index`` (``build_index_file``, in this process).
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path


def _read(aug_path):
    from isplat.augfile import open_augmented

    a = open_augmented(aug_path)
    for ch in ("density", "gradient_magnitude", "normal"):
        a.read(ch)


def _stats(aug_path):
    from isplat.augfile import open_augmented

    open_augmented(aug_path).verify_all()


def _index(aug_path):
    from isplat.index import build_index_file

    build_index_file(aug_path, Path(str(aug_path).replace(".aug.h5", ".idx.h5")), force=True)


TASKS = {"read": _read, "stats": _stats, "index": _index}


def measure(files: dict, repeats: int) -> dict:
    """{(task, format): [seconds]}: each task on each file, formats in rotating order, first round discarded."""
    times = {(t, v): [] for t in TASKS for v in files}
    order = list(files)
    for n in range(repeats + 1):
        for task, fn in TASKS.items():
            for v in order[n % len(order):] + order[:n % len(order)]:
                t0 = time.perf_counter()
                fn(files[v])
                if n:
                    times[(task, v)].append(time.perf_counter() - t0)
    return times


def main(argv=None) -> int:
    from .selective_read import as_version, augment_sample

    ap = argparse.ArgumentParser(prog="python -m benchmarks.whole_read", description=__doc__)
    ap.add_argument("--shape", default="256,256,225", help="the head sample's shape NI,NJ,NK")
    ap.add_argument("--repeats", type=int, default=5)
    a = ap.parse_args(argv)
    shape = tuple(int(x) for x in a.shape.split(","))
    with tempfile.TemporaryDirectory() as d:
        v6 = augment_sample("head", shape, Path(d) / "v6.aug.h5")
        files = {"format 6": v6, "format 5": as_version(v6, Path(d) / "v5.aug.h5", 5),
                 "format 4": as_version(v6, Path(d) / "v4.aug.h5", 4)}
        times = measure(files, a.repeats)
    print(f"head sample {shape}, median of {a.repeats} (s); ratios: median of the rounds' format N / format 4")
    print("| task | format 4 | format 5 | format 6 | 5 / 4 | 6 / 4 |\n|---|---|---|---|---|---|")
    for task in TASKS:
        t = {v: statistics.median(times[(task, v)]) for v in files}
        r = {v: statistics.median(x / y for x, y in zip(times[(task, v)], times[(task, "format 4")])) for v in files}
        print(f"| {task} | {t['format 4']:.3f} | {t['format 5']:.3f} | {t['format 6']:.3f} | {r['format 5']:.2f} | "
              f"{r['format 6']:.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
