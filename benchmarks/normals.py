"""Octahedral 16-bit normals: angular error of decode(encode(v)) over random unit vectors, and codec speed."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from isplat import normals as N

from . import _doc

TECHNIQUES = []     # render.classification of its rows (the page's stamp)
SOURCES = _doc.sources(("isplat/normals.py", "benchmarks/normals.py"))



def _errors(v):
    d = N.decode(N.encode(v)).astype(np.float64)
    c = np.clip((d * v).sum(-1), -1.0, 1.0)
    return np.degrees(np.arccos(c))


def run(out_dir: Path, quick: bool) -> Path:
    n = 100_000 if quick else 4_000_000
    rng = np.random.default_rng(20240601)
    v = rng.standard_normal((n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    N.encode(v[:10])  # compile outside the timing
    err = _errors(v)
    t_enc = []
    for _ in range(3):
        t0 = time.perf_counter()
        codes = N.encode(v)
        t_enc.append(time.perf_counter() - t0)
    t_dec = []
    for _ in range(3):
        t0 = time.perf_counter()
        N.decode(codes)
        t_dec.append(time.perf_counter() - t0)
    allc = N.decode(np.arange(65536, dtype=np.uint16))
    used = np.unique(N.encode(allc)).size
    p = Path(out_dir) / "normals.md"
    p.write_text(f"""```
python -m benchmarks normals{' --quick' if quick else ''}
```

# Octahedral 16-bit normals: accuracy

Machine: {_doc.machine_line()}; isplat {_doc.git_rev()} (shared with other work while measured: the times are
of this run, the errors exact). No rendering.

{n:,} unit vectors, uniformly distributed on the sphere (normalised Gaussian triples, numpy seed 20240601),
encoded with the precise oct16 encoder (`isplat.normals.encode`) and decoded (`isplat.normals.decode`):

| measure                              | value |
|--------------------------------------|-------|
| max angular error                    | {err.max():.4f} deg |
| mean angular error                   | {err.mean():.4f} deg |
| 99.9th percentile                    | {np.percentile(err, 99.9):.4f} deg |
| distinct codes encode(decode(c)) over all 65,536 c | {used:,} (incl. NO_NORMAL; seam duplicates and -128 bytes collapse) |
| encode time (median of 3)            | {np.median(t_enc) * 1e9 / n:.1f} ns/vector |
| decode time (LUT gather, median of 3) | {np.median(t_dec) * 1e9 / n:.1f} ns/vector |

Cigolle et al. (2014) report about 0.64 degrees max for oct16 with the precise encoder; the paper's
two-byte normals (§4) are this size. The property tests (tests/test_normals.py) assert < 0.65 degrees.
""")
    return p
