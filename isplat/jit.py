"""The numba options of every compiled kernel, defined once (as datashader's ``ngjit``).

``jit`` compiles in nopython mode, releases the GIL (threads render image bands side by side) and caches the
machine code on disk. ``ISPLAT_BOUNDSCHECK=1`` in the environment turns numba's bounds checking on for a test
run: an index outside an array then raises ``IndexError`` instead of reading stray memory. numba's cache does
not tell apart code compiled with and without checks, so such a run keeps its cache in a folder of its own
(``NUMBA_CACHE_DIR``, set here unless the caller set it).
"""

from __future__ import annotations

import os
import tempfile

BOUNDSCHECK = os.environ.get("ISPLAT_BOUNDSCHECK", "") == "1"
if BOUNDSCHECK:
    os.environ.setdefault("NUMBA_CACHE_DIR", os.path.join(tempfile.gettempdir(), "isplat-numba-boundscheck"))

import numba as nb  # noqa: E402  (after NUMBA_CACHE_DIR is settled)

OPTIONS = {"nopython": True, "nogil": True, "cache": True, "boundscheck": BOUNDSCHECK or None}


def jit(fn=None, **extra):
    """``numba.njit`` with isplat's options; ``@jit`` or ``@jit(inline="always")``."""
    if fn is None:
        return lambda f: nb.jit(**OPTIONS, **extra)(f)
    return nb.jit(**OPTIONS)(fn)


def leaf(fn=None, **extra):
    """``@jit`` for a small per-voxel stage that allocates nothing: compiled without numba's reference
    counting, so the arrays it takes cost nothing per call (with it, each array handed to a function in the
    per-voxel loop costs an atomic increment and decrement, which made the staged kernel 2.4x slower than one
    big function). LLVM then inlines such a stage into the loop that calls it, or (``@leaf(inline="always")``,
    for a per-pixel stage with many arguments) numba does, before LLVM sees a call."""
    if fn is None:
        return lambda f: nb.jit(**OPTIONS, _nrt=False, **extra)(f)
    return nb.jit(**OPTIONS, _nrt=False)(fn)
