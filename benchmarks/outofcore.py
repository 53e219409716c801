"""Volumes larger than memory on one machine: the `head` sample at 1024^3 through augment, index and render
with the process limited to 2 GiB of address space. ``python -m benchmarks outofcore [--quick]`` (part of
``make bench``; --quick: 128^3, the same limit).

Each stage runs as ``isplat ...`` in a subprocess under ``setrlimit(RLIMIT_AS, 2 GiB)`` (what ``prlimit --as`` and
``ulimit -v`` set) and ``/usr/bin/time -v`` (wall time, peak resident set). A stage that fails under the limit is
recorded with its error line, then run without the limit (so the next stages have their input) and its peak
memory recorded: that is the measure of what still has to stream. The plain renders choose their slabs when the
selection does not fit (isplat.slabs.slabs_needed, said on stderr); the next two render the same frames in a set
number of slabs (``isplat render --slabs K``, isplat.slabs.render_streamed), under the limit only; the last renders
the bone frame in one pass without the limit, the reference the streamed frames are compared with. The 1024^3
files (about 12 GB) are deleted at the end.

Writes the section "outofcore" of docs/scale.md.
"""

from __future__ import annotations

import json
import os
import re
import resource
import subprocess
import sys
import time
from pathlib import Path

from . import _doc

SECTION = "outofcore"        # the section of its page this benchmark writes
TECHNIQUES = ["pre", "post"]     # render.classification of its rows (the page's stamp)
SOURCES = _doc.sources(_doc.RENDER, _doc.READ, _doc.AUGMENT, _doc.SAMPLES, ("isplat/slabs.py", "isplat/memory.py",
                       "isplat/cli/**", "examples/head.toml", "benchmarks/outofcore.py"))
from .render import ROOT

LIMIT = 2 << 30
WORK = ROOT / "out" / "bench"


def _log(msg):
    print(f"[outofcore] {msg}", file=sys.stderr, flush=True)


def _limit():
    resource.setrlimit(resource.RLIMIT_AS, (LIMIT, LIMIT))


ONE_PASS = "render, opaque (bone), `--slabs 1` (one pass, the reference)"
AUTO = re.compile(r"each frame in (\d+) slabs front to back")


def run_stage(args, limited: bool, cwd):
    """``isplat ARGS`` in a subprocess: (ok, seconds, peak RSS bytes or None, last stderr line, the slabs a
    render chose by itself or None, a render's ``--json`` report or None)."""
    cmd = ["/usr/bin/time", "-v", sys.executable, "-m", "isplat", *map(str, args)]
    env = dict(os.environ, ISPLAT_PROGRESS="0")
    t0 = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True, cwd=cwd, env=env, preexec_fn=_limit if limited else None)
    dt = time.perf_counter() - t0
    m = re.search(r"Maximum resident set size \(kbytes\): (\d+)", r.stderr)
    auto = AUTO.search(r.stderr)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip() and not ln.startswith(("\t", "Command"))]
    try:
        report = json.loads(r.stdout) if r.returncode == 0 and "--json" in map(str, args) else None
    except ValueError:
        report = None
    return (r.returncode == 0, dt, (int(m.group(1)) * 1024 if m else None), (lines[-1] if lines else ""),
            int(auto.group(1)) if auto else None, report)


SEMI = ["transfer.opacity=[[60, 0.0], [110, 0.02], [170, 0.02], [200, 0.6], [255, 0.6]]",
        "transfer.color=[[60, 0.9, 0.6, 0.5], [170, 0.9, 0.6, 0.5], [200, 1, 1, 0.95]]"]


def _aug_format(aug: Path) -> str:
    """The augmented file's format, as the table's caption names it."""
    if not aug.exists():
        return "not written"
    import h5py
    with h5py.File(aug, "r") as f:
        return f"format {int(f.attrs['format_version'])}"


def run(out_dir: Path, quick: bool) -> Path:
    n = 128 if quick else 1024
    work = WORK / f"outofcore-{n}"
    work.mkdir(parents=True, exist_ok=True)
    npy, aug, idx = work / "head.npy", work / "head.aug.h5", work / "head.idx.h5"
    if not npy.exists():
        _log(f"sample head {n}^3 (not limited)")
        ok, *_, err, _, _ = run_stage(["sample", "head", "-o", npy, "--shape", f"{n},{n},{n}", "--force", "-q"], False,
                                   work)
        if not ok:
            raise RuntimeError(f"isplat sample failed: {err}")
    # the pre-classified rows first (the paper's splatting), then the default, post-classified: a slab holds
    # its slices' channels (density and normals, 3 bytes a voxel, 3 GiB at 1024^3) besides its selection
    post = [f'data.augmented="{aug}"', f'data.index="{idx}"', "image.width=512", "image.height=512"]
    scene = post + ['render.classification="pre"']
    def render(png, sets, *extra):
        return ["render", ROOT / "examples/head.toml", "-o", work / png, "--force", "--json", *extra,
                *sum((["--set", s] for s in sets), [])]
    stages = [("augment", ["augment", npy, "-o", aug, "--force", "-q"], True),
              ("index", ["index", aug, "-o", idx, "--force", "-q"], True),
              ("render, opaque (bone)", render("bone.png", scene), True),
              ("render, semi-transparent (veil + bone)", render("veil.png", scene + SEMI), True),
              ("render, opaque (bone), `--slabs 8` (streamed)", render("bone8.png", scene, "--slabs", "8"), False),
              ("render, semi-transparent, `--slabs 32` (streamed)", render("veil32.png", scene + SEMI, "--slabs", "32"),
               False),
              (ONE_PASS, render("bone1.png", scene, "--slabs", "1"), False),
              ("render, opaque (bone), post-classified", render("bone_post.png", post), True),
              ("render, semi-transparent (veil + bone), post-classified", render("veil_post.png", post + SEMI), True)]
    for png in ("bone.png", "veil.png", "bone8.png", "veil32.png", "bone1.png", "bone_post.png", "veil_post.png"):
        (work / png).unlink(missing_ok=True)          # compare only what this run wrote
    rows = []
    for name, args, again in stages:
        limited = name != ONE_PASS
        _log(f"{name} (limited to {LIMIT >> 30} GiB)" if limited else f"{name} (not limited)")
        ok, dt, rss, err, auto, report = run_stage(args, limited, work)
        row = [name, ok, dt, rss, err, None, auto, report]
        if not ok and again:
            _log(f"{name} failed under the limit ({err}); again without it")
            row[5] = run_stage(args, False, work)
        rows.append(row)

    size = npy.stat().st_size
    sizes = {p: p.stat().st_size if p.exists() else None for p in (aug, idx)}
    gib = lambda b: f"{b / 2**30:.2f} GiB" if b else "n/a"            # noqa: E731

    def read(report):
        """Bytes read from the files for the frame, and over the technique's bytes needed (docs/stats.md)."""
        if not report:
            return " | "
        got, need = report["file_bytes_read"], report["bytes_needed"]
        return f"{got / 2**20:,.0f} MiB | " + (f"{got / need:.2f}" if need else "")

    def line(r):
        name, ok, dt, rss, err, again, auto, report = r
        shown = name                            # every row about rendering names its technique
        if name.startswith("render") and "post-classified" not in name:
            shown = name + ", pre-classified"
        if name == ONE_PASS:
            return (f"| {shown} | not limited | {dt:.1f} s | {gib(rss)} | {read(report)} | "
                    f"{'' if ok else 'fails: `' + err[:160] + '`'} |")
        if ok:
            note = f"in {auto} slabs, chosen by itself (the selection does not fit)" if auto else ""
            return f"| {shown} | ok | {dt:.1f} s | {gib(rss)} | {read(report)} | {note} |"
        note = f"fails: `{err[:160]}`"
        if again:
            note += (f"; without the limit {again[1]:.1f} s, peak RSS {gib(again[2])}" if again[0]
                     else f"; fails without the limit too: `{again[3][:120]}`")
        return f"| {shown} | **no** | {dt:.1f} s | {gib(rss)} | {read(None)} | {note} |"
    body = f"""```
python -m benchmarks outofcore{' --quick' if quick else ''}
```
Machine: {_doc.machine_line()}; isplat {_doc.git_rev()}. The `head` sample at {n}^3 (`isplat sample head --shape
{n},{n},{n}`: {size / 2**30:.2f} GiB of uint16 .npy; augmented {gib(sizes[aug])}, index {gib(sizes[idx])}),
each stage a process limited to {LIMIT >> 30} GiB of address space (`setrlimit(RLIMIT_AS)`, as `prlimit --as` or
`ulimit -v`). Peak RSS from `/usr/bin/time -v` (with the interpreter, numpy, h5py, numba). Scenes:
examples/head.toml at 512 x 512 (bone), and the same with a faint veil of soft tissue over the bone,
pre-classified (`render.classification = "pre"`, the paper's splatting) and, in the last two rows,
post-classified (the default: a frame, or each slab of it, then also holds a pool of the 8^3 bricks its quads
read, density, normals and gradient magnitudes, 4 bytes a voxel of those bricks; when it chooses the slabs,
`isplat render` counts what a one-pass frame from the index's runs file holds, from the runs file's tables
(`isplat.selection.post_runs_bytes`), and else post's channels whole, 4 bytes a voxel of the volume, in slabs
that read bricks, `isplat.slabs.slabs_needed`). *Read*: the bytes a render read from the
augmented file ({_aug_format(aug)}) and the index (`isplat render --json`'s `file_bytes_read`, every slab's
summed), and that over the technique's bytes needed (`bytes_needed`, docs/stats.md).

| stage | under {LIMIT >> 30} GiB | wall time | peak RSS | read | read / needed | note |
|---|---|---|---|---:|---:|---|
""" + "\n".join(line(r) for r in rows) + "\n"
    def same(a, b):
        if not all((work / f).exists() for f in (a, b)):
            return "n/a"
        import imageio.v3 as iio
        import numpy as np
        return "yes" if np.array_equal(iio.imread(work / a), iio.imread(work / b)) else "NO"
    body += (f"\nThe frames of the plain renders (slabs chosen by themselves) equal those rendered in a set number of "
             f"slabs, bit for bit: bone (`--slabs 8`) **{same('bone.png', 'bone8.png')}**, veil (`--slabs 32`) "
             f"**{same('veil.png', 'veil32.png')}**; the plain bone frame equals the one-pass frame (the `--slabs 1` row, "
             f"not limited) bit for bit: **{same('bone.png', 'bone1.png')}**. Post-classified, the frames differ from "
             f"the pre-classified ones by the model, not by the slabs (the post-classified slabs are tested against "
             f"one pass in tests/test_slabs.py). (A frame "
             f"rendered front to back in slabs is the one-pass frame, same image and counters, early termination "
             f"included: tests/test_slabs.py. The veil's one-pass selection would take well over 10 GiB, so it is "
             f"not rendered here.)\n")
    if not quick:
        for big in (npy, aug, idx, *work.glob("head.*.idx.h5")):   # ~20 GB at 1024^3 with the index's values
            big.unlink(missing_ok=True)                               # and runs files: made again by the next run
    return _doc.update_section(Path(out_dir) / "scale.md", "outofcore", body, title="isplat at scale: Dask")
