"""Reading only the voxels of interest: ``python -m benchmarks selective_read [--quick]`` writes
``selective-read.md``.

For each scene (the paper's H1 and E2 on isplat's synthetic samples, the real MRI head of ``make data`` when
present, the head sample at 512^3) two index files of the same volume are compared, side by side in one run:

* **before**: format version 2, written as isplat wrote it before version 3 (no channel values; the chunk sizes
  of then: 16 KiB tables, 64 KiB blocks), so a scene gathers its normals from the augmented file's
  position-ordered channel in slabs of 8 k-slices;
* **after**: format version 3 (``isplat index`` now): the channel values stored once more by density, so a
  scene reads one row range per interval.

Both techniques are measured: the before/after comparison is of the paper's pre-classified splatting
(``render.classification = "pre"``), which reads only the voxels of interest's values; the default since scene
version 4, post-classification, is loaded from the same version-3 index in the same interleaved rounds, and
reads the whole channels (its table says how much more that is).

Bytes read are counted below h5py, at the file object HDF5 reads through (whole chunks with their checksums,
and the metadata, the files' opening included): ``LoadReport.file_bytes``. Bytes needed are the voxels of
interest times the bytes per voxel of the channels the scene uses, plus the index blocks and table rows of
its intervals (``LoadReport.bytes_needed``). Load time is ``select_from_files`` (open both files, read,
decode, select, gather) for the scene's one view, before and after interleaved, median of several runs.
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from . import _doc

TECHNIQUES = ["pre", "post"]     # render.classification of its rows (the page's stamp)
SOURCES = _doc.sources(_doc.READ, _doc.AUGMENT, _doc.SAMPLES, ("isplat/scene.py", "isplat/frame.py",
                       "benchmarks/paper.py", "benchmarks/selective_read.py"))

ROOT = Path(__file__).resolve().parents[1]
REPEATS, REPEATS_QUICK = 7, 2
OLD_CHUNKS = {"TABLE_CHUNK": 1 << 14, "BYTES_CHUNK": 1 << 16, "PTR_CHUNK": 1 << 14}   # before version 3


def _log(msg):
    print(f"[selective_read] {msg}", file=sys.stderr, flush=True)


@contextmanager
def _no_context():
    yield


@contextmanager
def _old_chunks():
    """The chunk sizes isplat wrote before format version 3."""
    from isplat.index import store

    saved = {k: getattr(store, k) for k in OLD_CHUNKS}
    for k, v in OLD_CHUNKS.items():
        setattr(store, k, v)
    try:
        yield
    finally:
        for k, v in saved.items():
            setattr(store, k, v)


def augment_sample(name: str, shape, out: Path) -> Path:
    """Augment isplat sample ``name`` at ``shape`` (n_i, n_j, n_k) into ``out`` (run in a subprocess for the
    big one, so this process does not keep its peak memory)."""
    from isplat.augfile import write_augmented
    from isplat.augment import augment_array
    from isplat.samples import make_sample

    arr, spacing = make_sample(name, shape=shape)
    a = augment_array(arr, spacing)
    del arr
    write_augmented(out, a["density"], a["gradient_magnitude"], a["normal"], a["spacing_ijk"], a["density_window"],
                    a["gradient_magnitude_scale"], {"source": f"isplat sample {name}"})
    return out


def _augment(name, shape, out: Path, quick: bool) -> None:
    if quick:                              # small volumes: in this process (the smoke test stays a few seconds)
        augment_sample(name, shape, out)
        return
    subprocess.run([sys.executable, "-c", "from benchmarks.selective_read import augment_sample; "
                    f"augment_sample({name!r}, {tuple(shape)!r}, __import__('pathlib').Path({str(out)!r}))"],
                   check=True, cwd=ROOT)


def _build(aug: Path, out: Path, values: bool, quick: bool) -> tuple[float | None, float]:
    """Peak RSS (MB) and wall time (s) of building an index in a fresh process: ``isplat index`` (after), or
    the same without channel values in the old chunk sizes (before, isplat's ``index`` up to version 2).
    ``quick``: in this process, RSS not measured."""
    if quick:
        from isplat.index import build_index_file

        t = time.perf_counter()
        with (_old_chunks() if not values else _no_context()):
            build_index_file(aug, out, force=True, values=values)
        return None, time.perf_counter() - t
    if values:
        cmd = [sys.executable, "-m", "isplat", "index", str(aug), "-o", str(out), "-q", "--force"]
    else:
        cmd = [sys.executable, "-c", "from benchmarks.selective_read import _old_chunks; "
               "from isplat.index import build_index_file\nwith _old_chunks(): "
               f"build_index_file({str(aug)!r}, {str(out)!r}, force=True, values=False)"]
    wrapper = ("import resource, subprocess, sys, time; t = time.perf_counter(); "
               f"subprocess.run({cmd!r}, check=True, cwd={str(ROOT)!r}); dt = time.perf_counter() - t; "
               "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, dt)")
    out_text = subprocess.run([sys.executable, "-c", wrapper], check=True, capture_output=True, text=True).stdout
    kib, dt = out_text.split()
    return int(kib) / 1024.0, float(dt)


def _scene(work: Path, name: str, tf: str, aug: Path, idx: Path, azimuth=0.0, elevation=10.0,
           technique: str = "pre") -> Path:
    from .paper import _COMMON

    p = work / f"{name}-{idx.stem}-{technique}.toml"
    p.write_text(f'version = 4\n\n[data]\naugmented = "{aug}"\nindex = "{idx}"\n'
                 + _COMMON.format(size=256, azimuth=azimuth, elevation=elevation, threads=1, technique=technique)
                 + "\n" + tf)
    return p


def cases(work: Path, quick: bool) -> list[dict]:
    """The volumes and scenes: name, what, aug path, transfer function, view."""
    from .paper import TF_BOLTS, TF_BONE, TF_MRI

    f = 4 if quick else 1
    out = []
    head = work / "head.aug.h5"
    _augment("head", (256 // f, 256 // f, 225 // f), head, quick)
    out.append(dict(name="H1", what="head sample, bone", aug=head, tf=TF_BONE, source="isplat sample head"))
    eng = work / "engine.aug.h5"
    _augment("engine", (256 // f, 256 // f, 110 // f), eng, quick)
    out.append(dict(name="E2", what="engine sample, bolts", aug=eng, tf=TF_BOLTS, azimuth=35, elevation=25,
                    source="isplat sample engine"))
    real = Path(os.environ.get("ISPLAT_DATA", ROOT / "data")) / "mri-head.aug.h5"
    if real.exists() and not quick:
        out.append(dict(name="B1", what="MRI head (real, `make data`), skin and brain", aug=real, tf=TF_MRI,
                        azimuth=180, source="data/mri-head.aug.h5 (pydeface 2.1.0 mean T1, `make data`)"))
    else:
        why = "--quick" if quick else "data/mri-head.aug.h5 not found (run `make data`)"
        mri = work / "mr-head.aug.h5"
        _augment("mr-head", (256 // f, 256 // f, 167 // f), mri, quick)
        out.append(dict(name="B1", what=f"SYNTHETIC MRI head (isplat sample mr-head; {why})", aug=mri, tf=TF_MRI,
                        source="isplat sample mr-head"))
    n = 96 if quick else 512
    big = work / "head512.aug.h5"
    _augment("head", (n, n, n), big, quick)
    out.append(dict(name=f"H1-{n}", what=f"head sample at {n}^3, bone", aug=big, tf=TF_BONE,
                    source=f"isplat sample head --shape {n},{n},{n}", big=True))
    return out


BRICKS = (8, 16, 32)


def brick_bytes(density, intervals, edge: int, itemsize: int = 2) -> int:
    """Bytes of normals a brick layout would read for these intervals: every ``edge``^3 brick (HDF5 chunk) of
    the normal channel holding a voxel of interest, whole, with its 4-byte checksum.

    >>> d = np.zeros((4, 4, 4), np.uint8); d[0, 0, 0] = d[3, 3, 3] = 9
    >>> brick_bytes(d, [(9, 9)], 2)        # two 2^3 bricks of 8 normals (16 B) and a checksum each
    40
    """
    inside = np.zeros(256, dtype=bool)
    for lo, hi in intervals:
        inside[lo:hi + 1] = True
    n_k, n_j, n_i = density.shape
    pad = [(0, -n % edge) for n in density.shape]
    touched = 0
    step = edge * max(1, (1 << 24) // max(1, edge * n_j * n_i))
    for k0 in range(0, n_k, step):
        m = np.pad(inside[density[k0:k0 + step]], [(0, -min(step, n_k - k0) % edge)] + pad[1:])
        kk, jj, ii = (n // edge for n in m.shape)
        touched += int(m.reshape(kk, edge, jj, edge, ii, edge).any(axis=(1, 3, 5)).sum())
    return touched * (edge ** 3 * itemsize + 4)


def measure(c: dict, work: Path, repeats: int, quick: bool = False) -> dict:
    from isplat.frame import axes_of, views_for
    from isplat.augfile import open_augmented
    from isplat.scene import load_scene
    from isplat.selection import select_from_files

    before, after = work / f"{c['name']}.v2.idx.h5", work / f"{c['name']}.v3.idx.h5"
    rss_b, t_b = _build(c["aug"], before, False, quick)
    rss_a, t_a = _build(c["aug"], after, True, quick)
    coarse = work / f"{c['name']}.v3-coarse.idx.h5"          # version 3 in the chunk sizes of version 2
    from isplat.index import build_index_file

    with _old_chunks():
        build_index_file(c["aug"], coarse, force=True, values=True)
    scenes = {k: load_scene(_scene(work, c["name"], c["tf"], c["aug"], p, c.get("azimuth", 0.0),
                                   c.get("elevation", 10.0), tech))
              for k, p, tech in (("before", before, "pre"), ("after", after, "pre"), ("post", after, "post"))}
    axes = axes_of(views_for(scenes["after"], open_augmented(c["aug"])))
    reports, times = {}, {"before": [], "after": [], "post": []}
    coarse_rep = select_from_files(load_scene(_scene(work, c["name"], c["tf"], c["aug"], coarse,
                                                     c.get("azimuth", 0.0), c.get("elevation", 10.0))), axes).report
    for n in range(repeats + 1):                       # the first round warms up (numba, page cache)
        order = ("before", "after", "post")
        for k in order[n % 3:] + order[:n % 3]:
            t = time.perf_counter()
            sel = select_from_files(scenes[k], axes)
            dt = time.perf_counter() - t
            if n:
                times[k].append(dt)
            reports[k] = (sel.report, sel.held_bytes())
            del sel
    aug = open_augmented(c["aug"])
    nk, nj, ni = aug.shape
    density = aug.read("density")
    bricks = {e: brick_bytes(density, reports["after"][0].intervals, e) for e in BRICKS}
    del density
    row = dict(name=c["name"], what=c["what"], source=c["source"], axes="".join(axes), shape=f"{ni} x {nj} x {nk}",
               aug_bytes=os.path.getsize(c["aug"]), idx_before=os.path.getsize(before),
               idx_after=os.path.getsize(after), rss_before=rss_b, rss_after=rss_a, build_before=t_b,
               build_after=t_a, ratio_time=[b / a for b, a in zip(times["before"], times["after"])],
               coarse_ratio=coarse_rep.read_ratio, coarse_size=os.path.getsize(coarse), bricks=bricks)
    for k in ("before", "after", "post"):
        rep, held = reports[k]
        row[k] = dict(read=rep.file_bytes, aug_read=rep.augmented_file_bytes, idx_read=rep.index_file_bytes,
                      requested=rep.augmented_bytes + rep.index_bytes, needed=rep.bytes_needed,
                      ratio=rep.read_ratio, voi=rep.voxels_of_interest, channels=list(rep.channels),
                      values_from=rep.values_from, held=held, time=statistics.median(times[k]),
                      intervals=rep.intervals, version=rep.index_format_version)
    for p in (before, after, coarse):
        p.unlink()
    return row


def run(out_dir: Path, quick: bool) -> Path:
    repeats = REPEATS_QUICK if quick else REPEATS
    t0 = time.perf_counter()
    rows = []
    with tempfile.TemporaryDirectory(prefix="isplat-selective-") as t:
        work = Path(t)
        for c in cases(work, quick):
            _log(f"{c['name']}: {c['what']}")
            rows.append(measure(c, work, repeats, quick))
            r = rows[-1]
            _log(f"  pre: read/needed before {r['before']['ratio']:.2f}, after {r['after']['ratio']:.2f}; load "
                 f"{1000 * r['before']['time']:.0f} ms -> {1000 * r['after']['time']:.0f} ms; post: read/needed "
                 f"{r['post']['ratio']:.2f}, load {1000 * r['post']['time']:.0f} ms")
    path = Path(out_dir) / "selective-read.md"
    path.write_text(render_doc(rows, quick, repeats, time.perf_counter() - t0))
    return path


def _rss(mb) -> str:
    return "not measured (--quick)" if mb is None else f"{mb:.0f}"


def _kb(n) -> str:
    return f"{n / 1e3:.1f}"


def _mb(n) -> str:
    return f"{n / 1e6:.2f}"


def render_doc(rows, quick: bool, repeats: int, seconds: float) -> str:
    cmd = "python -m benchmarks selective_read" + (" --quick" if quick else "")
    L = [
        "# Reading only the voxels of interest",
        "",
        f"Made by `{cmd}` on {_doc.machine_line()}, git {_doc.git_rev()}, in {seconds:.0f} s. Do not edit: "
        "rerun the command. Design and alternatives: [design.md](design.md#reading-only-the-voxels-of-interest); "
        "format: formats/index.md §9.",
    ]
    if quick:
        L += ["", "**QUICK RUN (smoke test): volumes at 1/4 resolution (96^3 for the big one), 2 runs, builds in "
                  "this process; not the reference numbers.**"]
    L += [
        "",
        "Each scene is the paper's setup (one orthographic view, shaded: the scene reads the normals of its voxels "
        "of interest, 2 B each; the index carries the densities). **Technique**: the before/after tables are of "
        "the paper's pre-classified splatting (`render.classification = \"pre\"`); the default since scene "
        "version 4, post-classification, reads the whole channels and has its own table below. "
        "**Before**: an index of format version 2 as "
        "isplat wrote it until now (no channel values; 16 KiB table chunks, 64 KiB block chunks): the normals "
        "come from the augmented file's position-ordered channel, in slabs of 8 k-slices that hold a voxel of "
        "interest. **After**: format version 3 (`isplat index` now): the normals of the transfer function's "
        "intervals are one row range each in the index's `/values` (2 KiB table chunks, 4 KiB block and value "
        "chunks). *Read*: bytes HDF5 read from both files (counted at the file object: whole chunks with their "
        "4-byte checksums, and metadata, opening included). *Needed*: voxels of interest x 2 B + the index "
        "blocks and table rows of the intervals (+ the 2 KiB pointer table of `/values`, after). Target: read "
        "<= 1.3 x needed.",
        "",
        "## Bytes read against bytes needed",
        "",
        "| scene | technique | volume (i x j x k) | intervals | axes | voxels of interest | needed (MB) "
        "| before: read (MB) | before: read / needed | after: read (MB) | after: read / needed | target |",
        "|---|---|---|---|---|---:|---:|---:|---:|---:|---:|---|",
    ]
    for r in rows:
        b, a = r["before"], r["after"]
        ivs = ", ".join(f"{lo}..{hi}" for lo, hi in a["intervals"])
        L.append(f"| {r['name']}: {r['what']} | pre | {r['shape']} | {ivs} | {r['axes']} | {a['voi']:,} | "
                 f"{_mb(a['needed'])} | {_mb(b['read'])} | {b['ratio']:.2f} | {_mb(a['read'])} | "
                 f"**{a['ratio']:.3f}** | <= 1.3 |")
    L += [
        "",
        "Of which (after): " + "; ".join(
            f"{r['name']} {_mb(r['after']['idx_read'])} MB from the index and {_kb(r['after']['aug_read'])} kB "
            f"from the augmented file (its attributes)" for r in rows) + ". Before, the augmented file gave "
        + "; ".join(f"{r['name']} {_mb(r['before']['aug_read'])} MB" for r in rows) + ".",
        "",
        "## By technique: the paper's splatting (pre) against the default (post), format 3",
        "",
        "The same scene and index (version 3), loaded with each technique in the same interleaved rounds. *pre* "
        "reads the index blocks of the intervals and the voxels of interest's values from `/values`; *post* reads "
        "the index blocks and the whole channels it samples around the voxels of interest (density and normal, "
        "by position: isplat/selection.py). *Needed* counts the voxels of interest's bytes for the channels each "
        "reads (so post's includes the density).",
        "",
        "| scene | technique | channels read | read (MB) | needed (MB) | read / needed | load (ms) | held (MB) |",
        "|---|---|---|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        for tech, k in (("pre", "after"), ("post (default)", "post")):
            x = r[k]
            L.append(f"| {r['name']} | {tech} | {', '.join(x['channels']) or '-'} | {_mb(x['read'])} | "
                     f"{_mb(x['needed'])} | {x['ratio']:.2f} | {1000 * x['time']:.1f} | {_mb(x['held'])} |")
    L += [
        "",
        "## Load time, before and after (one run, interleaved; pre)",
        "",
        f"`select_from_files` for the scene's view: open both files, read, decode the blocks, select, gather the "
        f"normals. Median of {repeats} runs each after a warm-up round, before, after and post (the table above) "
        f"in a rotating order; ratio = median of the per-round ratios before / after.",
        "",
        "| scene | technique | before (ms) | after (ms) | before / after | held after (MB) "
        "| held per voxel of interest (B) |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        b, a = r["before"], r["after"]
        L.append(f"| {r['name']} | pre | {1000 * b['time']:.1f} | {1000 * a['time']:.1f} | "
                 f"{statistics.median(r['ratio_time']):.2f} | {_mb(a['held'])} | {a['held'] / max(1, a['voi']):.2f} |")
    L += [
        "",
        "## File sizes, before and after",
        "",
        "The index of all densities (`isplat index` defaults). After, it holds the normal and gradient magnitude "
        "of every indexed voxel once more (3 B per voxel, in density order): the augmented file is unchanged. "
        "Build: peak RSS and wall time of the build in a fresh process (before: isplat's index of version 2, "
        "`build_index_file(..., values=False)` with the old chunk sizes; after: `isplat index`).",
        "",
        "| scene | augmented (MB) | index before (MB) | index after (MB) | after / before | both files before "
        "(MB) | both files after (MB) | build before: RSS (MB), s | build after: RSS (MB), s |",
        "|---|---:|---:|---:|---:|---:|---:|---|---|",
    ]
    for r in rows:
        L.append(f"| {r['name']} | {_mb(r['aug_bytes'])} | {_mb(r['idx_before'])} | {_mb(r['idx_after'])} | "
                 f"{r['idx_after'] / r['idx_before']:.2f} | {_mb(r['aug_bytes'] + r['idx_before'])} | "
                 f"{_mb(r['aug_bytes'] + r['idx_after'])} | {_rss(r['rss_before'])}, {r['build_before']:.1f} | "
                 f"{_rss(r['rss_after'])}, {r['build_after']:.1f} |")
    L += [
        "",
        "## The alternatives, measured on the same scenes (what pre reads)",
        "",
        "*Chunk sizes*: version 3 written in version 2's chunk sizes (16 KiB tables, 64 KiB blocks and values) "
        "reads more around each range, which matters for a small scene. *Bricks*: no index values at all, but "
        "the augmented normal channel chunked in edge^3 bricks (HDF5 chunks), reading every brick that holds a "
        "voxel of interest, whole (computed from the density channel: bricks touched x (edge^3 x 2 B + 4 B "
        "checksum); the index blocks would come on top). *Per-axis copies* and *values in the blocks* store the "
        "3 B of values once per indexed axis (9 B per voxel for three axes) instead of once: the extra size is "
        "three times the one above, for the same bytes read.",
        "",
        "| scene | normals needed (MB) | after, 16/64 KiB chunks: read / needed | index after, 16/64 KiB chunks (MB) | "
        + " | ".join(f"bricks {e}^3: normals read (MB), x needed" for e in BRICKS) + " |",
        "|---|---:|---:|---:|" + "---:|" * len(BRICKS),
    ]
    for r in rows:
        need = 2 * r["after"]["voi"]
        L.append(f"| {r['name']} | {_mb(need)} | {r['coarse_ratio']:.3f} | {_mb(r['coarse_size'])} | "
                 + " | ".join(f"{_mb(r['bricks'][e])}, {r['bricks'][e] / max(1, need):.1f}x" for e in BRICKS) + " |")
    L += ["", "Sources: " + "; ".join(f"{r['name']}: {r['source']}" for r in rows) + ".", ""]
    return "\n".join(L)
