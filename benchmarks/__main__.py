"""python -m benchmarks NAME|all [--out docs] [--quick]   (from the repository root)"""

import argparse
import importlib
import pkgutil
import sys
from pathlib import Path

import benchmarks as pkg
from benchmarks import _doc


# not part of `all`: compares two versions of isplat, run as `python benchmarks/commits.py --old REV`;
# `python -m benchmarks.threadload` (threads quiet and under load, on any checkout through PYTHONPATH); and
# `python -m benchmarks.contour_shift` (a prototype between thick slices, measured against the cubic; prints a table);
# `python -m benchmarks.whole_read` (whole reads, stats and index of format 5 against 4; prints a table);
# `python -m benchmarks.simd_span` (a prototype of the SIMD row span, benchmarks/_simd.py, against the scalar sample)
# `python -m benchmarks.thick_spline` (the interpolating spline between thick slices against Catmull-Rom; a table)
# `python -m benchmarks.brick_edge` (format 6 at 4^3 and 8^3 bricks against format 4: reads, loads, held; a table)
# `python -m benchmarks.sampler_trees` (sampler variants as patches, benchmarks/table_layouts, against a commit)
# `python -m benchmarks.load_ab` (post's load from format 6, an older commit against the working tree; prints a table)
# `python -m benchmarks.brick_order` (the 4 KB pages post's bricks touch in C and Morton order; prints a table)
# `python -m benchmarks.range_runs` (post's channels in runs by neighbourhood density range: reads, pages; a table)
# `python -m benchmarks.bandlearn --old REV` (the band learning of an older commit against this one's; a table)
STANDALONE = ("commits", "threadload", "contour_shift", "whole_read", "simd_span", "thick_spline", "brick_edge",
              "sampler_trees", "load_ab", "brick_order", "range_runs", "bandlearn")
# run by name only, not in `all` (so not in CI's bench-check): compiles an older commit's kernels (~4 min)
BY_NAME_ONLY = ("sampler",)


def names(by_name: bool = False):
    skip = STANDALONE if by_name else STANDALONE + BY_NAME_ONLY
    return sorted(m.name for m in pkgutil.iter_modules(pkg.__path__)
                  if not m.name.startswith(("_", "test_")) and m.name not in skip)     # test_*: pytest's


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m benchmarks", description=__doc__)
    ap.add_argument("name", help="benchmark name or 'all' (all but " + ", ".join(BY_NAME_ONLY) + "): "
                    + ", ".join(names(by_name=True)))
    ap.add_argument("--out", default="docs", type=Path, help="folder for the Markdown results")
    ap.add_argument("--quick", action="store_true", help="smaller sizes, fewer repeats (for a smoke test)")
    a = ap.parse_args(argv)
    todo = names() if a.name == "all" else [a.name]
    for n in todo:
        if n not in names(by_name=True):
            print(f"benchmarks: error: unknown benchmark {n!r}; expected one of {names(by_name=True)}",
                  file=sys.stderr)
            return 2
    a.out.mkdir(parents=True, exist_ok=True)
    for n in todo:
        print(f"[bench] {n}", file=sys.stderr)
        mod = importlib.import_module(f"benchmarks.{n}")
        path = mod.run(a.out, a.quick)
        if not getattr(mod, "STAMPS_ITSELF", False):
            _doc.stamp_output(path, mod, f"python -m benchmarks {n}" + (" --quick" if a.quick else ""))
        print(f"[bench] wrote {path}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
