"""The placing of two runs files of one volume by this tree's reader, interleaved (a developer's tool; docs/design.md,
"Positions as nested masks"): say the same volume's runs file of format 1 and of format 2.

    .venv/bin/python scripts/place_ab.py A.runs.idx.h5 B.runs.idx.h5 [--interval 171,255 ...] [--rounds 25]

``python -m benchmarks.load_ab --old cb90d4a`` leaves such a pair in out/load_ab: ``<sha>/NAME.runs.idx.h5``
written by the old commit (format 1) and ``new/NAME.runs.idx.h5`` by the working tree. Per round each file's runs
meeting the intervals are fetched (read and hashed, not timed) and placed into a pool
(``isplat.runsfile.RunsFile.place``, timed), the order alternating; prints the medians and the median of the
per-round ratios B / A, after one warm-up of each.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def place_once(path, intervals) -> float:
    """Seconds to place ``path``'s runs meeting ``intervals`` (after fetching them)."""
    from isplat.runsfile import RunsFile, open_runs

    with open_runs(path) as rf:
        got = rf.fetch(intervals)
        t = time.perf_counter()
        RunsFile.place(got, True)
        return time.perf_counter() - t


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="scripts/place_ab.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("a", type=Path)
    ap.add_argument("b", type=Path)
    ap.add_argument("--interval", action="append", default=[], help="LO,HI (inclusive codes); default 171,255")
    ap.add_argument("--rounds", type=int, default=25)
    a = ap.parse_args(argv)
    intervals = [tuple(int(x) for x in iv.split(",")) for iv in a.interval] or [(171, 255)]
    place_once(a.a, intervals), place_once(a.b, intervals)
    ta, tb, ratio = [], [], []
    for n in range(a.rounds):
        if n % 2:
            x, y = place_once(a.a, intervals), place_once(a.b, intervals)
        else:
            y, x = place_once(a.b, intervals), place_once(a.a, intervals)
        ta.append(x)
        tb.append(y)
        ratio.append(y / x)
    print(f"A {1e3 * statistics.median(ta):.1f} ms  B {1e3 * statistics.median(tb):.1f} ms  B / A per round "
          f"{statistics.median(ratio):.3f} ({a.rounds} rounds)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
