"""isplat.jit: its use of numba's private cache API (issue 25, item 8: pinned, checked, and a loud fallback), and
over4, the compositing step in vector lanes (issue 27)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import numba
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from isplat import jit as J

ROOT = Path(__file__).resolve().parents[1]


def test_numba_cache_internals_are_as_tested():
    """Fails loudly (not silently slower) when numba's internals move: every private name and signature the
    fast cache loader uses is as it was tested on, and the installed numba is in the range pyproject.toml pins
    (widen the pin only after this suite passes on the new version)."""
    assert J.private_api_problem() is None
    assert J._CACHE in (J._CacheLoad, J._Stamped) and J._MOVED is None
    deps = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    spec = next(d for d in deps if d.startswith("numba"))
    lo, hi = re.fullmatch(r"numba>=([\d.]+),<([\d.]+)", spec).groups()
    have = tuple(int(x) for x in numba.__version__.split(".")[:2])
    assert tuple(map(int, lo.split("."))) <= have < tuple(map(int, hi.split("."))), (spec, numba.__version__)


MOVED = r"""
import numba.core.caching as c
old = c.FunctionCache._index_key                            # as if a numba release had changed its signature
c.FunctionCache._index_key = lambda self, sig, codegen, flags=None: old(self, sig, codegen)
import numpy as np
from isplat.jit import jit

@jit
def twice(x):
    return 2 * x

print(twice(np.arange(3.0)).tolist())
"""


def test_moved_internals_fall_back_to_numbas_loading_with_one_line(tmp_path):
    """With a private signature changed, kernels still compile and run through numba's own cache, and the process says
    so once (a warning naming what moved), however many kernels it makes."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    script = MOVED.replace("print(", "@jit\ndef thrice(x):\n    return 3 * x\n\nprint(thrice(1.0), ")
    (tmp_path / "moved.py").write_text("import logging; logging.basicConfig()\n" + script)   # numba caches files
    out = subprocess.run([sys.executable, str(tmp_path / "moved.py")], env=env, capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "3.0 [0.0, 2.0, 4.0]"
    said = [line for line in out.stderr.splitlines() if "cache internals" in line]
    assert len(said) == 1 and "_index_key takes (self, sig, codegen, flags)" in said[0], out.stderr


def _over4_scalar(img, y, x, a, cr, cg, cb):
    """The compositing step as post._composite wrote it before isplat.jit.over4: four scalar updates."""
    ai = img[y, x, 3]
    ta = (1.0 - ai) * a
    img[y, x, 0] += ta * cr
    img[y, x, 1] += ta * cg
    img[y, x, 2] += ta * cb
    an = ai + ta
    img[y, x, 3] = an
    return float(ai), float(an)


_over4_scalar_jit = numba.njit(_over4_scalar)


@numba.njit
def _over4_run(img, ys, xs, a, c):
    out = np.empty((ys.shape[0], 2))
    for t in range(ys.shape[0]):
        out[t, 0], out[t, 1] = J.over4(img, np.uint64(ys[t]), np.uint64(xs[t]), a[t], c[t, 0], c[t, 1], c[t, 2])
    return out


@numba.njit
def _scalar_run(img, ys, xs, a, c):
    out = np.empty((ys.shape[0], 2))
    for t in range(ys.shape[0]):
        out[t, 0], out[t, 1] = _over4_scalar_jit(img, ys[t], xs[t], a[t], c[t, 0], c[t, 1], c[t, 2])
    return out


@given(st.integers(0, 2 ** 32 - 1), st.sampled_from(["float32", "float64"]))
@settings(max_examples=40, deadline=None)
def test_over4_composites_bit_for_bit_as_the_scalar_updates(seed, dtype):
    """over4 (one vector of the pixel's four channels) gives the images and opacities of the four scalar updates
    bit for bit, compiled and as Python, over runs of samples that hit the same pixels again (front to back)."""
    rng = np.random.default_rng(seed)
    img = (rng.random((3, 5, 4)) * rng.choice([0.0, 0.5, 1.0], (3, 5, 1))).astype(dtype)
    n = 60
    ys, xs = rng.integers(0, 3, n), rng.integers(0, 5, n)
    a = rng.choice([0.0, 1e-9, 0.03, 0.5, 1.0], n) * rng.random(n)
    c = rng.random((n, 3)) * 1.5
    want_img = img.copy()
    want = _scalar_run(want_img, ys, xs, a, c)
    got_img = img.copy()
    got = _over4_run(got_img, ys.astype(np.uint64), xs.astype(np.uint64), a, c)
    assert np.array_equal(got, want) and np.array_equal(got_img, want_img)
    py_img = img.copy()
    py = np.array([J._over4_python(py_img, int(y), int(x), float(s), *map(float, cc))
                   for y, x, s, cc in zip(ys, xs, a, c)])
    assert np.array_equal(py, want) and np.array_equal(py_img, want_img)
