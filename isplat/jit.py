"""The numba options of every compiled kernel, defined once (as datashader's ``ngjit``).

``jit`` compiles in nopython mode, releases the GIL (threads render image bands side by side) and caches the
machine code on disk. ``ISPLAT_BOUNDSCHECK=1`` in the environment turns numba's bounds checking on for a test
run: an index outside an array then raises ``IndexError`` instead of reading stray memory. numba's cache does
not tell apart code compiled with and without checks, so such a run keeps its cache in a folder of its own
(``NUMBA_CACHE_DIR``, set here unless the caller set it).

A kernel's cache is made when first used and loaded without numba's registry refresh (:class:`_CacheLoad`);
on a miss, from the kernels prebuilt for a portable CPU level when the package holds them (:mod:`isplat.prebuilt`).
Functions called only from compiled code are made without Python's wrappers (:func:`stage`, :func:`leaf`).
"""

from __future__ import annotations

import functools
import logging
import os
import sys
import tempfile

BOUNDSCHECK = os.environ.get("ISPLAT_BOUNDSCHECK", "") == "1"
if BOUNDSCHECK:
    os.environ.setdefault("NUMBA_CACHE_DIR", os.path.join(tempfile.gettempdir(), "isplat-numba-boundscheck"))

import numba as nb  # noqa: E402  (after NUMBA_CACHE_DIR is settled)
from numba.core.registry import CPUDispatcher  # noqa: E402

from .interrupts import defer_numba_compiles  # noqa: E402

defer_numba_compiles(CPUDispatcher)    # SIGINT/SIGTERM held while a kernel loads or compiles (isplat.interrupts)

# forceinline given (False unless asked for): numba would otherwise let a function first compiled from within
# a forceinline one inherit it, so how a stage is compiled would depend on which caller compiled it first
OPTIONS = {"nopython": True, "nogil": True, "cache": True, "boundscheck": BOUNDSCHECK or None, "forceinline": False}


_ANNOUNCED = []


def _announce_compile(cache_path: str) -> None:
    """Say once per process, as an INFO log line (shown by the command line unless ``-q``), that kernels are
    being compiled: the first run on a machine spends seconds there before any output (measured in one place,
    docs/startup.md, "Cold")."""
    if not _ANNOUNCED:
        _ANNOUNCED.append(cache_path)
        logging.getLogger(__name__).info(
            f"isplat: compiling the kernels for this machine, once (seconds, not a fraction of one: docs/startup.md; "
            f"later runs load them from numba's cache, {cache_path})")


# Every module with compiled functions (a test checks the list). numba keeps a function's machine code while
# its own file is unchanged, but a compiled function holds the code of the stages it calls from other files
# (every technique's kernel inlines traverse.py's occlusion tests): a cached kernel is fresh only while all of
# them are.
KERNEL_SOURCES = ("jit.py", "augment.py", "brickstore.py", "normals.py", "runs.py", "runsplace.py", "samples.py",
                  "index/codec.py", "splat/composite.py", "splat/labels.py", "splat/mip.py", "splat/post.py",
                  "splat/pre.py", "splat/select.py", "splat/shade.py", "splat/sheets.py", "splat/traverse.py")
_HERE = os.path.dirname(os.path.abspath(__file__))


@functools.cache
def kernel_sources_stamp() -> tuple:
    """(modification time, size) of each of ``KERNEL_SOURCES``, once per process: the freshness of every cached
    kernel (numba's own stamp is its file's alone)."""
    return tuple((name, *_file_stamp(os.path.join(_HERE, name))) for name in KERNEL_SOURCES)


def _file_stamp(path) -> tuple:
    try:
        st = os.stat(path)
    except OSError:
        return ()
    return st.st_mtime, st.st_size


def kernel_sources_digest() -> str:
    """SHA-256 of the contents of ``KERNEL_SOURCES``: what prebuilt kernels were compiled from (file times
    change when a package is installed, contents do not)."""
    import hashlib

    h = hashlib.sha256()
    for name in KERNEL_SOURCES:
        with open(os.path.join(_HERE, name), "rb") as f:
            h.update(name.encode() + b"\0" + f.read() + b"\0")
    return h.hexdigest()


def cpu_has(features: str) -> bool:
    """True when this process runs on x86-64 with every LLVM feature of ``features`` ("+avx2,+fma,...")."""
    import llvmlite.binding as ll

    host = set(ll.get_host_cpu_features().flatten().split(","))
    return ll.get_process_triple().startswith("x86_64") and set(features.split(",")) <= host


@functools.cache
def prebuilt() -> dict | None:
    """The package's kernels compiled ahead of time (:mod:`isplat.prebuilt`), once per process: their folder
    (``ISPLAT_PREBUILT`` in the environment, else ``isplat/_prebuilt``; ``ISPLAT_PREBUILT=none``: not used),
    the CPU description they were compiled for and the stamp of the sources they were compiled from, or None
    when there are none, or they were made from other sources, another numba, llvmlite or Python, or for a
    CPU this one is not, or bounds checks are on."""
    import json

    folder = os.environ.get("ISPLAT_PREBUILT") or os.path.join(_HERE, "_prebuilt")
    if BOUNDSCHECK or os.environ.get("NUMBA_BOUNDSCHECK", "") == "1":
        return None                     # compiled without bounds checks
    try:
        with open(os.path.join(folder, "manifest.json"), encoding="utf-8") as f:
            m = json.load(f)
        import llvmlite
        import llvmlite.binding as ll

        fits = (m["format"] == 1 and m["numba"] == nb.__version__ and m["llvmlite"] == llvmlite.__version__
                and m["python"] == sys.implementation.cache_tag and m["triple"] == ll.get_process_triple()
                and cpu_has(m["features"]) and m["sources"] == kernel_sources_digest())
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if not fits:
        return None
    return {"dir": folder, "magic": (m["triple"], m["cpu"], m["features"]), "stamp": ("prebuilt", m["sources"])}


try:
    from numba.core.caching import FunctionCache, IndexDataCacheFile
    from numba.core.runtime import rtsys

    class _Stamped(FunctionCache):
        """numba's cache of a function's machine code, fresh while the function's file (numba's stamp) and every
        file of compiled functions (:func:`kernel_sources_stamp`) are unchanged: a kernel holds the code of the
        stages it calls from other files, which numba's stamp alone does not follow."""

        def __init__(self, py_func):
            super().__init__(py_func)
            self._cache_file._source_stamp = (self._cache_file._source_stamp, kernel_sources_stamp())

    class _CacheLoad(_Stamped):
        """:class:`_Stamped`, made when first used and loaded without numba's ``target_context.refresh()``.

        * Before loading a cached kernel numba refreshes its target: it imports and installs every typing and
          lowering registry (the numpy, random, typed-container and datetime implementations), which only
          compiling needs; that took 0.1-0.2 s of a one-frame ``isplat render`` (docs/startup.md). Running
          cached code needs numba's runtime (NRT, the allocator the kernels call) initialised, which is the part
          of the refresh done here. Compiling still refreshes: numba's compiler does so on every compile
          (``CompilerBase.__init__``), so a miss or a new signature compiles as before.
        * numba makes a function's cache when it is decorated (finding and testing its cache folder); of the
          70-odd compiled functions a frame calls about six from Python (the rest are compiled into those), so
          the cache is made on first use (``__getattr__`` runs only for attributes not yet set)."""

        def __init__(self, py_func):            # noqa: D107 (_Stamped.__init__ deferred)
            self._deferred = py_func

        def __getattr__(self, name):
            if name == "_deferred":
                raise AttributeError(name)
            _Stamped.__init__(self, self._deferred)
            return object.__getattribute__(self, name)

        def load_overload(self, sig, target_context):
            rtsys.initialize(target_context)
            found = None
            with self._guard_against_spurious_io_errors():
                found = self._load_overload(sig, target_context)
                if found is None:
                    found = self._load_prebuilt(sig, target_context)
            if found is None:
                _announce_compile(self._cache_path)
            return found

        def _load_prebuilt(self, sig, target_context):
            """The kernel compiled ahead of time for a portable CPU level (:mod:`isplat.prebuilt`), when the
            package holds it and it fits this install and this CPU."""
            pre = prebuilt()
            if pre is None:
                return None
            folder = os.path.join(pre["dir"], *self._py_func.__module__.split("."))
            files = IndexDataCacheFile(cache_path=folder, filename_base=self._impl.filename_base,
                                       source_stamp=pre["stamp"])
            sig_key, _, code_key = self._index_key(sig, target_context.codegen())
            data = files.load((sig_key, pre["magic"], code_key))
            return None if data is None else self._impl.rebuild(target_context, data)

    # ISPLAT_NUMBA_STOCK_LOAD=1: numba's own loading, refresh included (docs/startup.md measures both)
    _CACHE = _CacheLoad
except ImportError:               # another numba layout: its own cache, refresh included
    _CACHE = None


# numba's private cache API that _Stamped and _CacheLoad use, as (owner, attribute, its parameters); tested on
# the numba versions pyproject.toml admits (tests/test_frame.py: test_numba_cache_internals_are_as_tested)
_PRIVATE_API = (
    ("numba.core.caching.FunctionCache", "__init__", ("self", "py_func")),
    ("numba.core.caching.FunctionCache", "_load_overload", ("self", "sig", "target_context")),
    ("numba.core.caching.FunctionCache", "_guard_against_spurious_io_errors", ("self",)),
    ("numba.core.caching.FunctionCache", "_index_key", ("self", "sig", "codegen")),
    ("numba.core.caching.FunctionCache", "_impl_class", None),
    ("numba.core.caching.FunctionCache", "_cache_path", None),
    ("numba.core.caching.FunctionCache", "_cache_file", None),
    ("numba.core.caching.CompileResultCacheImpl", "rebuild", ("self", "target_context", "payload")),
    ("numba.core.caching.CompileResultCacheImpl", "filename_base", None),
    ("numba.core.caching.IndexDataCacheFile", "__init__", ("self", "cache_path", "filename_base", "source_stamp")),
    ("numba.core.caching.IndexDataCacheFile", "load", ("self", "key")),
    ("numba.core.caching.IndexDataCacheFile", "_source_stamp", None),
    ("numba.core.runtime.rtsys", "initialize", ("ctx",)),
)


def private_api_problem() -> str | None:
    """What of numba's private cache API (``_PRIVATE_API``) is not as isplat was tested on, or None. When not
    None, kernels load through numba's own cache object (registries refreshed: a slower start, the same
    code), and :func:`_compiled` says so once as a log line."""
    import importlib
    import inspect

    for owner, attr, params in _PRIVATE_API:
        mod, _, name = owner.rpartition(".")
        try:
            obj = getattr(importlib.import_module(mod), name)
        except (ImportError, AttributeError):
            return f"{owner} is missing"
        if not hasattr(obj, attr) and f"self.{attr} =" not in _init_source(obj):     # set in __init__
            return f"{owner}.{attr} is missing"
        if params is not None:
            try:
                got = tuple(inspect.signature(getattr(obj, attr)).parameters)
            except (TypeError, ValueError):
                return f"{owner}.{attr} has no signature"
            if got != params:
                return f"{owner}.{attr} takes ({', '.join(got)}), not ({', '.join(params)})"
    return None


def _init_source(cls) -> str:
    """The source of ``cls.__init__`` (an attribute set there, like ``filename_base``, is not on the class)."""
    import inspect

    try:
        return inspect.getsource(cls.__init__)
    except (OSError, TypeError):
        return ""


_MOVED = private_api_problem() if _CACHE is not None else "numba.core.caching is missing"
_FAST_LOAD = _MOVED is None and os.environ.get("ISPLAT_NUMBA_STOCK_LOAD", "") != "1"
if _MOVED is not None:
    _CACHE = None                   # numba's own cache (its own stamp: a changed stage's callers may stay stale)
elif not _FAST_LOAD:
    _CACHE = _Stamped
_SAID_MOVED = []


def _say_moved() -> None:
    """One log line per process when numba's internals are not as tested (:func:`private_api_problem`)."""
    if _MOVED is not None and not _SAID_MOVED:
        _SAID_MOVED.append(True)
        import numba

        logging.getLogger(__name__).warning(
            f"isplat: numba {numba.__version__}'s cache internals are not those isplat was tested on ({_MOVED}); "
            f"kernels load through numba's own cache (a slower start). pyproject.toml lists the numba "
            f"versions tested")


INTERNAL = {"no_cpython_wrapper": True, "no_cfunc_wrapper": True}
STRICT = os.environ.get("ISPLAT_STRICT_STAGES", "") == "1"


class _Stage(CPUDispatcher):
    """A compiled function made without the wrappers that let Python call it (``INTERNAL``): numba makes
    those for every compiled function, also one only ever called from compiled code, and making them is a good
    part of a first run's compile (docs/design.md, "Compiling the kernels"). Without them numba's own call from
    Python would jump to a null address, so a call from Python (the tests' reference checks) goes through a
    small compiled function made for it, uncached; ``ISPLAT_STRICT_STAGES=1`` makes such a call an error instead
    (a test runs the command line so, to show that isplat itself never calls a stage from Python)."""

    def __call__(self, *args):
        if STRICT:
            raise RuntimeError(f"{self.py_func.__qualname__} is a compiled stage, called from Python")
        calls = self.__dict__.setdefault("_python_calls", {})
        if len(args) not in calls:
            names = ", ".join(f"a{i}" for i in range(len(args)))
            scope = {"stage": self}
            exec(f"def call({names}):\n    return stage({names})\n", scope)
            calls[len(args)] = nb.njit(scope["call"])
        return calls[len(args)](*args)


# a stage's dispatcher becomes a _Stage (its class swapped): only where numba's is the CPUDispatcher it
# subclasses; otherwise stages keep their wrappers
_STAGES = type(nb.njit(lambda: 0)) is CPUDispatcher


def _compiled(options: dict, fn, stage: bool = False):
    """``numba.jit(**options)(fn)``; with ``cache``, :class:`_CacheLoad` (or :class:`_Stamped`) as its cache; a
    ``stage`` (called from compiled code only) without Python's wrappers (:class:`_Stage`)."""
    stage = stage and _STAGES
    _say_moved()
    if stage:
        options = {**options, **INTERNAL}
    cached = _CACHE is not None and options.get("cache")
    disp = nb.jit(**{**options, "cache": options.get("cache") and not cached})(fn)
    if not hasattr(disp, "py_func"):    # NUMBA_DISABLE_JIT=1 gives back the plain function: nothing to cache
        return disp
    if cached:
        disp._cache = _CACHE(disp.py_func)
    if stage:
        disp.__class__ = _Stage
    return disp


def jit(fn=None, **extra):
    """``numba.njit`` with isplat's options, for a kernel called from Python; ``@jit`` or ``@jit(**options)``,
    for example ``forceinline=True`` (LLVM inlines it wherever it is called)."""
    if fn is None:
        return lambda f: _compiled({**OPTIONS, **extra}, f)
    return _compiled(OPTIONS, fn)


def stage(fn=None, **extra):
    """``@jit`` for a function called only from other compiled functions (:class:`_Stage`). With numba's
    reference counting always (``_nrt`` given): numba would otherwise let a stage first compiled from within a
    :func:`leaf` inherit the leaf's lack of it, and a stage that allocates would not compile."""
    if fn is None:
        return lambda f: _compiled({**OPTIONS, "_nrt": True, **extra}, f, stage=True)
    return _compiled({**OPTIONS, "_nrt": True}, fn, stage=True)


def leaf(fn=None, **extra):
    """``@stage`` for a small per-voxel stage that allocates nothing: compiled without numba's reference
    counting, so the arrays it takes cost nothing per call (with it, each array handed to a function in the
    per-voxel loop costs an atomic increment and decrement, which made the staged kernel 2.4x slower than one
    big function). LLVM then inlines such a stage into the loop that calls it when it judges that cheap.

    Two ways to make sure a stage is inlined, measured side by side (scripts/ab.py) for the first run's
    compile and the frames' time:

    * ``@leaf(forceinline=True)``: LLVM's ``alwaysinline``; the stage is compiled once, and inlined wherever
      it is called;
    * ``@leaf(inline="always")``: numba inlines the stage's IR at each call site before typing. numba copies
      the IR for each call site, deep-copying all its variables once per block, so for a large stage this
      costs seconds of a first run's compile (7 of 24 s when every such stage was inlined this way). With
      LLVM's instead, frames were 3-5% slower for the small per-pixel helpers of the post-classified scan
      (``_row_span``, ``_span``, ``_slice_point`` in :mod:`isplat.splat.post`) and the occlusion test
      (:func:`isplat.splat.traverse._hidden`), which keep numba's (measured as a group, not one by one), and
      as fast for the larger per-pixel sample (``_sample``) and per-square scan (``_sample_square``).
    """
    if fn is None:
        return lambda f: _compiled({**OPTIONS, "_nrt": False, **extra}, f, stage=True)
    return _compiled({**OPTIONS, "_nrt": False}, fn, stage=True)


def _prefetch_intrinsic():
    """:func:`prefetch` as numba compiles it: LLVM's ``llvm.prefetch`` (read, keep in every cache level, data),
    which x86 compiles to one PREFETCHT0."""
    from llvmlite import ir
    from numba import types
    from numba.core import cgutils
    from numba.extending import intrinsic

    @intrinsic
    def prefetch(typingctx, arr, i):
        if not (isinstance(arr, types.Array) and arr.ndim == 1 and isinstance(i, types.Integer)):
            return None

        def codegen(context, builder, sig, args):
            data = context.make_array(sig.args[0])(context, builder, args[0]).data
            byte = ir.IntType(8).as_pointer()
            i32 = ir.IntType(32)
            fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(ir.VoidType(), [byte, i32, i32, i32]),
                                                "llvm.prefetch." + byte.intrinsic_name)
            builder.call(fn, [builder.bitcast(builder.gep(data, [args[1]]), byte), i32(0), i32(3), i32(1)])
            return context.get_dummy_value()

        return types.void(arr, i), codegen

    return prefetch


def _over4_intrinsic():
    """:func:`over4` as numba compiles it: the pixel's four channels loaded as one vector, widened to float64,
    ``old + ta * (cr, cg, cb, 1)`` in four lanes (a multiply, then an add: no fused multiply-add, so each lane
    rounds as the scalar expression does), narrowed back and stored as one vector."""
    from llvmlite import ir
    from numba import types
    from numba.core import cgutils
    from numba.extending import intrinsic

    @intrinsic
    def over4(typingctx, img, y, x, a, cr, cg, cb):
        if not (isinstance(img, types.Array) and img.ndim == 3 and img.layout == "C"
                and img.dtype in (types.float32, types.float64)):
            return None
        f64 = ir.DoubleType()
        v4 = ir.VectorType(f64, 4)

        def codegen(context, builder, sig, args):
            aryty = sig.args[0]
            ary = context.make_array(aryty)(context, builder, args[0])
            i64 = ir.IntType(64)
            at = [context.cast(builder, v, t, types.intp) for v, t in zip(args[1:3], sig.args[1:3])]
            ptr = cgutils.get_item_pointer(context, builder, aryty, ary, [*at, i64(0)])
            elem = context.get_data_type(aryty.dtype)
            vp = builder.bitcast(ptr, ir.VectorType(elem, 4).as_pointer())
            old = builder.load(vp, align=aryty.dtype.bitwidth // 8)
            if aryty.dtype == types.float32:
                old = builder.fpext(old, v4)
            fa, fr, fg, fb = (context.cast(builder, v, t, types.float64) for v, t in zip(args[3:], sig.args[3:]))
            ai = builder.extract_element(old, i64(3))
            ta = builder.fmul(builder.fsub(f64(1.0), ai), fa)
            col = ir.Constant(v4, [0.0, 0.0, 0.0, 1.0])
            for lane, v in enumerate((fr, fg, fb)):
                col = builder.insert_element(col, v, i64(lane))
            tv = builder.insert_element(ir.Constant(v4, ir.Undefined), ta, i64(0))
            tv = builder.shuffle_vector(tv, ir.Constant(v4, ir.Undefined), ir.Constant(ir.VectorType(ir.IntType(32), 4),
                                                                                         [0, 0, 0, 0]))
            new = builder.fadd(old, builder.fmul(tv, col))
            an = builder.extract_element(new, i64(3))
            out = builder.fptrunc(new, ir.VectorType(elem, 4)) if aryty.dtype == types.float32 else new
            builder.store(out, vp, align=aryty.dtype.bitwidth // 8)
            return context.make_tuple(builder, sig.return_type, [ai, an])

        return types.UniTuple(types.float64, 2)(img, y, x, a, cr, cg, cb), codegen

    return over4


def _over4_python(img, y, x, a, cr, cg, cb):
    """:func:`over4` run as Python (``NUMBA_DISABLE_JIT=1``): the same values, one channel at a time."""
    ai = float(img[y, x, 3])
    ta = (1.0 - ai) * a
    for ch, c in enumerate((cr, cg, cb)):
        img[y, x, ch] = float(img[y, x, ch]) + ta * c
    an = ai + ta
    img[y, x, 3] = an
    return ai, an


def _prefetch_python(arr, i):
    """:func:`prefetch` run as Python (``NUMBA_DISABLE_JIT=1``): nothing to do."""


# prefetch(arr, i), in compiled code: ask the CPU to bring element i of the 1-D array arr into its caches, so that
# a later load of it does not wait for memory. A hint only: it changes no value and never faults, whatever i is.
prefetch = _prefetch_python if nb.config.DISABLE_JIT else _prefetch_intrinsic()
# over4(img, y, x, a, cr, cg, cb), in compiled code: composite opacity a and colour (cr, cg, cb) front to back over
# pixel (x, y) of the C-ordered float32 or float64 RGBA image img[H, W, 4], its four channels in the lanes of one
# vector (one load, one store); returns (the pixel's opacity before, after), both float64. The same values, bit
# for bit, as the four scalar updates (_over4_python; tests/test_jit.py).
over4 = _over4_python if nb.config.DISABLE_JIT else _over4_intrinsic()
