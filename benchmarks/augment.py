"""`isplat augment` on the 256x256x225 head (.npy) and a 512^3 volume: wall time, peak memory, index estimate."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from isplat.samples import make_sample

from . import _doc

TECHNIQUES = []     # render.classification of its rows (the page's stamp)
SOURCES = _doc.sources(_doc.AUGMENT, _doc.SAMPLES, ("isplat/cli/**", "benchmarks/augment.py"))



def _run(cmd):
    """Run ``cmd``; return (seconds, max RSS of the child in bytes or None)."""
    timer = shutil.which("time") or ("/usr/bin/time" if os.path.exists("/usr/bin/time") else None)
    full = [timer, "-v", *cmd] if timer else cmd
    env = dict(os.environ, ISPLAT_PROGRESS="0")
    t0 = time.perf_counter()
    r = subprocess.run(full, capture_output=True, text=True, env=env)
    dt = time.perf_counter() - t0
    if r.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed: {r.stderr.strip()[-500:]}")
    m = re.search(r"Maximum resident set size \(kbytes\): (\d+)", r.stderr) if timer else None
    return dt, (int(m.group(1)) * 1024 if m else None)


def _augment_cmd(inp, out):
    return [sys.executable, "-m", "isplat", "augment", str(inp), "-o", str(out), "--force", "-q"]


def index_estimate(d: np.ndarray) -> tuple[float, int]:
    """Paper §2.3 index size along k: 1 byte per voxel + 2 per gap > 255 in a (slice, density) block (from -1)."""
    flat = d.reshape(d.shape[0], -1)
    big = 0
    for row in flat:
        order = np.argsort(row, kind="stable")
        dens = row[order]
        prev = np.r_[-1, order[:-1]]
        prev[np.r_[True, dens[1:] != dens[:-1]]] = -1
        big += int(((order - prev) > 255).sum())
    return (d.size + 2 * big) / d.size, big


def run(out_dir: Path, quick: bool) -> Path:
    from isplat.augfile import open_augmented

    head_shape = (64, 64, 56) if quick else (256, 256, 225)
    big_n = 128 if quick else 512
    repeats = 1 if quick else 3
    with tempfile.TemporaryDirectory(prefix="isplat-bench-") as td:
        td = Path(td)
        x, s = make_sample("head", head_shape)
        np.save(td / "head.npy", x)
        _run(_augment_cmd(td / "head.npy", td / "head.aug.h5"))  # warm the numba cache and page cache
        runs = [_run(_augment_cmd(td / "head.npy", td / "head.aug.h5")) for _ in range(repeats)]
        t_head = float(np.median([r[0] for r in runs]))
        rss_head = max((r[1] or 0) for r in runs)
        aug = open_augmented(td / "head.aug.h5")
        d = aug.read("density")
        est, big = index_estimate(d)
        window = aug.density_window
        bone = float((x > 1650).mean())
        del x, d
        # import cost of a bare augment run, for reading the numbers above
        t_help, _ = _run([sys.executable, "-c", "import isplat.augment"])

        x, _ = make_sample("head", (big_n,) * 3)
        np.save(td / "big.npy", x)
        big_bytes = x.nbytes
        del x
        t_big, rss_big = _run(_augment_cmd(td / "big.npy", td / "big.aug.h5"))

    n_head = int(np.prod(head_shape))
    mb = 1 / 2**20
    rss = (lambda b: f"{b * mb:.0f} MiB" if b else "n/a")
    p = Path(out_dir) / "augment.md"
    p.write_text(f"""```
python -m benchmarks augment{' --quick' if quick else ''}
```

# `isplat augment`: time and memory

Each run is `python -m isplat augment IN.npy -o OUT.aug.h5 --force -q` in a subprocess (input memory-mapped,
processed in slabs of ~4 M voxels with a one-slice halo, two passes). Peak memory is the child's maximum resident
set size from `/usr/bin/time -v` (it includes the Python interpreter, numpy, h5py and numba, and the mapped input
pages it touched). Machine: {_doc.machine_line()}; isplat {_doc.git_rev()} (shared with other work while measured).

| volume | input | wall time | peak RSS |
|--------|-------|-----------|----------|
| head sample {'x'.join(map(str, head_shape))} (n_i x n_j x n_k), uint16 | {n_head * 2 * mb:.1f} MiB .npy | {t_head:.2f} s (median of {repeats}) | {rss(rss_head)} |
| head sample {big_n}^3, uint16 | {big_bytes * mb:.0f} MiB .npy | {t_big:.2f} s (1 run) | {rss(rss_big)} |

`python -c "import isplat.augment"` alone takes {t_help:.2f} s (interpreter, numpy, h5py, numba; kernels come from
numba's on-disk cache).

## Head sample: density index estimate

Default window (robust 0.1 / 99.9 percentiles): {window[0]:g} .. {window[1]:g}; bone (> 1650) is {bone:.1%} of the
voxels (the paper's H1 renders bone and muscle at a spatial ratio of 0.072).

Paper §2.3 encoding of the k-axis index for all densities: 1 byte per voxel, plus 2 more whenever the next voxel of
the same (slice, density) block is more than 255 positions after the previous one (counting from position -1):
{big:,} such gaps over {n_head:,} voxels, so **{est:.3f} bytes per indexed voxel** (target <= 1.3).
""")
    return p
