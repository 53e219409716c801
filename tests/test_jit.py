"""isplat.jit's use of numba's private cache API (issue 25, item 8): pinned, checked, and a loud fallback."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import numba

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
