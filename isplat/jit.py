"""The numba options of every compiled kernel, defined once (as datashader's ``ngjit``).

``jit`` compiles in nopython mode, releases the GIL (threads render image bands side by side) and caches the
machine code on disk. ``ISPLAT_BOUNDSCHECK=1`` in the environment turns numba's bounds checking on for a test
run: an index outside an array then raises ``IndexError`` instead of reading stray memory. numba's cache does
not tell apart code compiled with and without checks, so such a run keeps its cache in a folder of its own
(``NUMBA_CACHE_DIR``, set here unless the caller set it).

A kernel's cache is made when first used and loaded without numba's registry refresh (:class:`_CacheLoad`).
"""

from __future__ import annotations

import logging
import os
import tempfile

BOUNDSCHECK = os.environ.get("ISPLAT_BOUNDSCHECK", "") == "1"
if BOUNDSCHECK:
    os.environ.setdefault("NUMBA_CACHE_DIR", os.path.join(tempfile.gettempdir(), "isplat-numba-boundscheck"))

import numba as nb  # noqa: E402  (after NUMBA_CACHE_DIR is settled)

OPTIONS = {"nopython": True, "nogil": True, "cache": True, "boundscheck": BOUNDSCHECK or None}


_ANNOUNCED = []


def _announce_compile(cache_path: str) -> None:
    """Say once per process, as an INFO log line (shown by the command line unless ``-q``), that kernels are
    being compiled: the first run on a machine spends about half a minute there before any output."""
    if not _ANNOUNCED:
        _ANNOUNCED.append(cache_path)
        logging.getLogger(__name__).info(
            f"isplat: compiling the kernels for this machine, once (about half a minute; later runs load them from "
            f"numba's cache, {cache_path})")


try:
    from numba.core.caching import FunctionCache
    from numba.core.runtime import rtsys

    class _CacheLoad(FunctionCache):
        """numba's cache of a function's machine code, made when first used and loaded without numba's
        ``target_context.refresh()``.

        * Before loading a cached kernel numba refreshes its target: it imports and installs every typing and
          lowering registry (the numpy, random, typed-container and datetime implementations), which only
          compiling needs; that took 0.1-0.2 s of a one-frame ``isplat render`` (docs/startup.md). Running
          cached code needs numba's runtime (NRT, the allocator the kernels call) initialised, which is the part
          of the refresh done here. Compiling still refreshes: numba's compiler does so on every compile
          (``CompilerBase.__init__``), so a miss or a new signature compiles as before.
        * numba makes a function's cache when it is decorated (finding and testing its cache folder); of the
          70-odd compiled functions a frame calls about six from Python (the rest are compiled into those), so
          the cache is made on first use (``__getattr__`` runs only for attributes not yet set)."""

        def __init__(self, py_func):            # noqa: D107 (FunctionCache.__init__ deferred)
            self._deferred = py_func

        def __getattr__(self, name):
            if name == "_deferred":
                raise AttributeError(name)
            FunctionCache.__init__(self, self._deferred)
            return object.__getattribute__(self, name)

        def load_overload(self, sig, target_context):
            rtsys.initialize(target_context)
            found = None
            with self._guard_against_spurious_io_errors():
                found = self._load_overload(sig, target_context)
            if found is None:
                _announce_compile(self._cache_path)
            return found

    # ISPLAT_NUMBA_STOCK_LOAD=1: numba's own cache object, refresh included (docs/startup.md measures both)
    _FAST_LOAD = (all(hasattr(FunctionCache, a) for a in ("_load_overload", "_guard_against_spurious_io_errors"))
                  and os.environ.get("ISPLAT_NUMBA_STOCK_LOAD", "") != "1")
except ImportError:               # another numba layout: its own cache, refresh included
    _FAST_LOAD = False


def _compiled(options: dict, fn):
    """``numba.jit(**options)(fn)``; with ``cache``, :class:`_CacheLoad` as its cache where numba allows."""
    if not (_FAST_LOAD and options.get("cache")):
        return nb.jit(**options)(fn)
    disp = nb.jit(**{**options, "cache": False})(fn)
    if hasattr(disp, "py_func"):        # NUMBA_DISABLE_JIT=1 gives back the plain function: nothing to cache
        disp._cache = _CacheLoad(disp.py_func)
    return disp


def jit(fn=None, **extra):
    """``numba.njit`` with isplat's options; ``@jit`` or ``@jit(inline="always")``."""
    if fn is None:
        return lambda f: _compiled({**OPTIONS, **extra}, f)
    return _compiled(OPTIONS, fn)


def leaf(fn=None, **extra):
    """``@jit`` for a small per-voxel stage that allocates nothing: compiled without numba's reference
    counting, so the arrays it takes cost nothing per call (with it, each array handed to a function in the
    per-voxel loop costs an atomic increment and decrement, which made the staged kernel 2.4x slower than one
    big function). LLVM then inlines such a stage into the loop that calls it, or (``@leaf(inline="always")``,
    for a per-pixel stage with many arguments) numba does, before LLVM sees a call."""
    if fn is None:
        return lambda f: _compiled({**OPTIONS, "_nrt": False, **extra}, f)
    return _compiled({**OPTIONS, "_nrt": False}, fn)
