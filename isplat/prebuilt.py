"""Kernels compiled ahead of time for a portable CPU level, so that a first run on a new machine loads them.

    python -m isplat.prebuilt OUT          # make demo and make wheel put them in isplat/_prebuilt

A first ``isplat render`` on a machine compiles its kernels with numba (seconds: docs/startup.md, "Cold"). This
compiles them once, in a child process, for ``x86-64-v3`` (the x86-64 level with AVX2 and FMA: Intel since
2013, AMD since 2015) rather than for the building machine's own CPU, runs a workload that calls every kernel
with the argument types isplat's commands use, and keeps, per module, numba's cache files of the functions
Python calls (the stages they call are compiled into them). A manifest records what they fit: numba, llvmlite
and Python, the CPU level, and a digest of the contents of every file of compiled functions
(:func:`isplat.jit.kernel_sources_digest`).

At run time (:class:`isplat.jit._CacheLoad`) numba's own cache comes first; on a miss, a prebuilt kernel is
loaded when the manifest fits (same versions, same sources, a CPU with every feature of the level); otherwise
the kernel is compiled as before. The kernels are then those of the portable level, not tuned for this CPU:
docs/startup.md times frames of both.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile

PORTABLE_CPU = "x86-64-v3"
PORTABLE_FEATURES = ("+64bit,+avx,+avx2,+bmi,+bmi2,+cmov,+cx16,+cx8,+f16c,+fma,+fxsr,+lzcnt,+mmx,+movbe,+popcnt,"
                     "+sahf,+sse,+sse2,+sse3,+sse4.1,+sse4.2,+ssse3,+xsave")


def build(out: str, workload: str = "isplat.prebuilt:isplat_workload", modules=None) -> dict:
    """Compile the kernels that ``workload`` (``module:function``) calls, for the portable CPU level, in a child
    process with a numba cache of its own, and write the entry points of ``modules`` (default: every module of
    isplat's compiled functions) with a manifest into ``out`` (replaced). Returns the manifest."""
    modules = list(modules or _isplat_modules())
    with tempfile.TemporaryDirectory(prefix="isplat-prebuild-") as tmp:
        env = dict(os.environ, NUMBA_CACHE_DIR=os.path.join(tmp, "cache"), NUMBA_CPU_NAME=PORTABLE_CPU,
                   NUMBA_CPU_FEATURES=PORTABLE_FEATURES, ISPLAT_PREBUILT="none", ISPLAT_PROGRESS="0")
        env.pop("ISPLAT_NUMBA_STOCK_LOAD", None)
        staged = os.path.join(tmp, "out")
        child = subprocess.run([sys.executable, "-m", "isplat.prebuilt", "--child", staged, workload, *modules],
                               env=env, cwd=tmp, capture_output=True, text=True)
        if child.returncode != 0:
            raise RuntimeError(f"isplat.prebuilt: the compiling process failed: {child.stderr.strip()[-2000:]}")
        if os.path.exists(out):
            shutil.rmtree(out)
        shutil.copytree(staged, out)
    with open(os.path.join(out, "manifest.json"), encoding="utf-8") as f:
        return json.load(f)


def _isplat_modules() -> list[str]:
    from .jit import KERNEL_SOURCES

    return ["isplat." + name[:-3].replace("/", ".") for name in KERNEL_SOURCES if name != "jit.py"]


def _child(out: str, workload: str, modules: list[str]) -> None:
    """In the child: run the workload, then copy each module's entry points' cache files for the portable CPU
    level to ``out/<module path>/``, with an index stamped by the sources' digest, and the manifest."""
    import importlib

    import llvmlite
    import llvmlite.binding as ll
    import numba
    from numba.core.caching import IndexDataCacheFile

    from .jit import _Stage, kernel_sources_digest

    mod_name, fn_name = workload.split(":")
    getattr(importlib.import_module(mod_name), fn_name)()
    digest = kernel_sources_digest()
    magic = (ll.get_process_triple(), PORTABLE_CPU, PORTABLE_FEATURES)
    kept = 0
    for name in modules:
        folder = os.path.join(out, *name.split("."))
        for disp in vars(importlib.import_module(name)).values():
            cache = getattr(disp, "_cache", None)
            if (type(disp) is _Stage or getattr(disp, "py_func", None) is None or cache is None
                    or disp.py_func.__module__ != name or not hasattr(cache, "_cache_file")):
                continue
            index = cache._cache_file._load_index()
            entries = {k: v for k, v in index.items() if k[1] == magic}
            if not entries:
                continue
            os.makedirs(folder, exist_ok=True)
            for data_name in entries.values():
                shutil.copy2(os.path.join(cache._cache_path, data_name), os.path.join(folder, data_name))
            IndexDataCacheFile(cache_path=folder, filename_base=cache._impl.filename_base,
                               source_stamp=("prebuilt", digest))._save_index(entries)
            kept += len(entries)
    manifest = {"format": 1, "numba": numba.__version__, "llvmlite": llvmlite.__version__,
                "python": sys.implementation.cache_tag, "triple": magic[0], "cpu": PORTABLE_CPU,
                "features": PORTABLE_FEATURES, "sources": digest, "kernels": kept}
    os.makedirs(out, exist_ok=True)
    with open(os.path.join(out, "manifest.json"), "w", encoding="utf-8") as f:
        json.dump(manifest, f, indent=1)


# what the commands render: post- and pre-classified, indexed and full, orthographic and perspective, image
# sheets, float64, a cut, gradient-modulated opacity, slabs, intensity projections (render.mode)
VARIANTS = ([], ['render.classification="pre"'], ['render.method="full"'],
            ['render.method="full"', 'render.classification="pre"'], ['camera.projection="perspective"'],
            ['render.classification="pre"', 'render.sheets="image"'], ['render.precision="float64"'],
            ['render.precision="float64"', 'render.classification="pre"'],
            ['render.precision="float64"', 'render.method="full"'],
            ['transfer.gradient_opacity=[[0, 0.2], [255, 1.0]]'],
            ['transfer.gradient_opacity=[[0, 0.2], [255, 1.0]]', 'render.classification="pre"'],
            ['shading.enabled=true', 'render.classification="pre"'],
            ['render.method="full"', 'render.classification="pre"', 'render.sheets="image"'],
            ['shading.enabled=false', 'render.threads=1'], ['version=6', 'render.mode="mip"'],
            ['version=6', 'render.mode="minip"', 'render.method="full"'],
            ['version=6', 'render.mode="mip"', 'render.precision="float64"'])
# the same sample with slices 5 times thicker along k, seen from the front (j's slices, a thick in-slice axis): the
# post-classified kernel with the cubic between slices, a type of its own (isplat.splat.post._taps)
THICK_VARIANTS = ([], ['render.method="full"'], ['render.precision="float64"'], ['camera.projection="perspective"'])


def isplat_workload() -> None:
    """The commands a user runs, on a small sample: sample, augment, index, stats, render in every kind of frame
    (``VARIANTS``), in slabs and on a local Dask cluster, and ``isplat.render`` on an array, in one process, so
    each kernel is compiled for the argument types they give it."""
    from .cli.main import _run as run_cli

    def _run(args):
        try:
            run_cli(args)
        except SystemExit as exc:            # the command line's way out, also when all went well
            if exc.code not in (0, None):
                raise RuntimeError(f"isplat {' '.join(args)}: exit status {exc.code}") from None

    here = tempfile.mkdtemp(prefix="isplat-workload-")
    try:
        os.chdir(here)
        _run(["-q", "sample", "engine", "-o", "e.npy", "--shape", "40,36,24"])
        _run(["-q", "augment", "e.npy", "-o", "e.aug.h5"])
        _run(["-q", "index", "e.aug.h5", "-o", "e.idx.h5"])
        _run(["-q", "augment", "e.npy", "-o", "t.aug.h5", "--spacing", "1,1,5", "--index"])
        _run(["-q", "sample", "ct-head", "-o", "c.npy", "--shape", "32,32,24"])      # int16 Hounsfield units
        _run(["-q", "augment", "c.npy", "-o", "c.aug.h5"])
        with open("s.toml", "w", encoding="utf-8") as f:
            f.write('version = 4\n[data]\naugmented = "e.aug.h5"\nindex = "e.idx.h5"\n[image]\nwidth = 48\n'
                    'height = 40\n[transfer]\nopacity = [[60, 0.0], [120, 0.6], [255, 0.9]]\n')
        for i, sets in enumerate(VARIANTS):
            _run(["-q", "render", "s.toml", "-o", f"{i}.png", *[f"--set={s}" for s in sets]])
        thick = ['--set=data.augmented="t.aug.h5"', '--set=data.index="t.idx.h5"']
        for i, sets in enumerate(THICK_VARIANTS):
            _run(["-q", "render", "s.toml", "-o", f"t{i}.png", *thick, *[f"--set={s}" for s in sets]])
        # the bolts alone: few of the bricks, read into a pool (post's kernels with a brick table)
        _run(["-q", "render", "s.toml", "-o", "pool.png", "--set=transfer.opacity=[[215, 0.0], [255, 1.0]]"])
        _run(["-q", "render", "s.toml", "-o", "slabs.png", "--slabs", "3"])
        _run(["-q", "render", "s.toml", "-o", "dask.png", "--slabs", "2", "--scheduler", "local:2"])
        _run(["-q", "stats", "e.aug.h5", "e.idx.h5", "--scene", "s.toml"])
        import numpy as np

        from . import render                                # the notebook call: a volume augmented in memory
        render(np.load("c.npy"), preset="ct-bone", size=32)
    finally:
        os.chdir(tempfile.gettempdir())
        shutil.rmtree(here, ignore_errors=True)


def portable_here() -> bool:
    """True on an x86-64 CPU with every feature of the portable level (where the kernels can be built and run)."""
    from .jit import cpu_has

    return cpu_has(PORTABLE_FEATURES)


def main(argv=None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "--child":
        _child(argv[1], argv[2], argv[3:])
        return
    if len(argv) != 1 or argv[0].startswith("-"):
        sys.exit("usage: python -m isplat.prebuilt OUT")
    if not portable_here():
        print(f"isplat.prebuilt: this CPU is not {PORTABLE_CPU}: nothing built (kernels compile on first use)",
              file=sys.stderr)
        return
    m = build(argv[0])
    print(f"isplat.prebuilt: wrote {m['kernels']} kernels for {m['cpu']} to {argv[0]}", file=sys.stderr)


if __name__ == "__main__":
    main()
