"""How bins cut by the data serve scenes other than the benchmarks' (branch rangebins, a one-off count): per case
of benchmarks/selective_read.py, over every interval [t0, t1] (1 <= t0 <= t1 <= 255) holding at least 1/1000 of
the volume in the union key's ideal read set (lo <= t1, hi >= t0), the voxels the runs of a binning read over that
ideal set: median, 90th percentile, maximum; and over the thresholds [t, 255] alone. Voxels only (no positions).

    python scripts/range_spread.py H1,E2,B1,C1
"""
import sys
import tempfile
from pathlib import Path

import numpy as np

SPECS = ["64x16", "dp64x16", "dp16x16", "dp8x8", "dp4x8"]


def edges(R, spec, lo, hi):
    b = R._bins(spec)
    if isinstance(b, tuple) and not isinstance(b[0], str):
        return np.arange(b[0]) * 256 // b[0], np.arange(b[1]) * 256 // b[1]
    cut = R.resolve(b, lo, hi)
    return cut.lo, cut.hi


def main(argv=None) -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
    from benchmarks import range_runs as R
    from benchmarks.selective_read import cases
    from isplat.augfile import open_augmented

    names = (argv or sys.argv[1:] or ["H1,E2,B1,C1"])[0].split(",")
    with tempfile.TemporaryDirectory() as t:
        for c in cases(Path(t), False, only=names):
            d = open_augmented(c["aug"]).read("density")
            lo, hi = R.range_key(d, "union")
            C, _ = R.interval_weights(lo, hi)
            t1, t0 = np.meshgrid(np.arange(256), np.arange(256), indexing="ij")
            ideal = C[t1 + 1, t0]
            ok = (t0 >= 1) & (t0 <= t1) & (ideal >= d.size / 1000)
            print(c["name"], f"({int(ok.sum())} intervals)")
            for spec in SPECS:
                lf, hf = edges(R, spec, lo, hi)
                end = np.append(np.asarray(lf)[1:], 256)[R._bin_lut(lf)]
                start = np.asarray(hf)[R._bin_lut(hf)]
                ratio = C[end[:, None], start[None, :]][ok] / ideal[ok]
                th = np.array([C[256, start[x]] / C[256, x] for x in range(1, 256) if C[256, x] >= d.size / 1000])
                print(f"  {spec}: all intervals median {np.median(ratio):.3f} p90 {np.percentile(ratio, 90):.3f} "
                      f"max {ratio.max():.2f}; thresholds median {np.median(th):.3f} p90 {np.percentile(th, 90):.3f} "
                      f"max {th.max():.2f}", flush=True)


if __name__ == "__main__":
    main()
