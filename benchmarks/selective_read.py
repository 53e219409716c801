"""What each technique reads against what it needs: ``python -m benchmarks selective_read [--quick]`` writes
``selective-read.md``.

Five cases (issue 26): the head sample's bone (the paper's H1), the engine sample's bolts (E2), the MRI head of
``make data`` (the synthetic ``mr-head`` sample when it is absent, and the row says so), the head sample at
512^3, and the ``ct-chest`` sample at 512 x 512 x 133 (spacing 0.703125, 0.703125, 2.5; window -1000..2000) with
a fat/skin veil and bone. Each is indexed with ``isplat index`` (the current format) and rendered by scenes of
the current scene version, one per technique, ``render.classification = "pre"`` (the paper's splatting) and
``"post"`` (the default): one row per (case, technique).

*Read*: bytes HDF5 read from both files, counted below h5py at the file object (whole chunks with their 4-byte
checksums, and metadata, the files' opening included; ``LoadReport.file_bytes``). *Needed*: the technique's
bytes needed (docs/stats.md: pre, the voxels of interest x the channel bytes it reads; post, the voxels its
quads read on the view's axis x the channel bytes it reads; both + the index blocks and table rows of the
intervals). *Load*: constructing the :class:`isplat.renderer.Renderer` (open both files, read, decode, select);
*frame*: one frame rendered from it (one thread). Techniques interleaved in rotating order, median of several
rounds after a warm-up round. *Held*: ``Renderer.held_bytes()`` over the voxels of interest.

Post is measured three times (issue 26, interleaved with pre in one run): from the index's runs file
(``NAME.runs.idx.h5``, formats/runs.md: the runs meeting the intervals), from the augmented file of format 6 with the
runs file moved aside (channels in 8^3 bricks of isplat's own store: post reads the bricks its quads touch) and
from the same volume written as format 4 (``isplat.augfile.write_augmented(..., version=4)``: chunks of whole rows,
read as whole channels; the runs file moved aside too, it is tied to the format-6 file).
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from . import _doc

TECHNIQUES = ["pre", "post"]     # render.classification of its rows (the page's stamp)
# rows: post from the runs file beside the index, from bricks (the runs file moved aside), and from a version-4 file
VARIANTS = {"pre": "pre", "post": "post", "post-bricks": "post", "post-v4": "post"}
LABELS = {"pre": "pre", "post": "post (runs file)", "post-bricks": "post (format 6: bricks)",
          "post-v4": "post (format 4: whole channels)"}
SOURCES = _doc.sources(_doc.READ, _doc.AUGMENT, _doc.SAMPLES, _doc.RENDER, ("isplat/stats.py",
                       "isplat/runsfile.py", "isplat/runs.py", "benchmarks/paper.py", "benchmarks/selective_read.py"))

ROOT = Path(__file__).resolve().parents[1]
REPEATS, REPEATS_QUICK = 5, 2
BAR = {"pre": 1.3, "post": 1.5}             # issue 26: read at most this many times the bytes needed
HELD_TARGET = ("H1", "post", 8.0)           # issue 26 item 4: at most 8 B held per voxel of interest, H1's post
TF_CHEST = """[transfer]
opacity = [[50, 0.0], [62, 0.03], [78, 0.03], [82, 0.0], [110, 0.0], [140, 1.0], [255, 1.0]]
color = [[62, 0.90, 0.70, 0.55], [140, 1.0, 0.97, 0.90]]
unit_distance = 1.0
"""
CHEST = dict(spacing=(0.703125, 0.703125, 2.5), window=(-1000.0, 2000.0))


def _log(msg):
    print(f"[selective_read] {msg}", file=sys.stderr, flush=True)


def augment_sample(name: str, shape, out: Path, spacing=None, window=None) -> Path:
    """Augment isplat sample ``name`` at ``shape`` (n_i, n_j, n_k) into ``out``; ``spacing``, ``window`` as
    ``isplat augment --spacing``, ``--window`` (None: the sample's spacing, the default window)."""
    from isplat.augfile import write_augmented
    from isplat.augment import augment_array
    from isplat.samples import make_sample

    arr, sp = make_sample(name, shape=shape)
    a = augment_array(arr, spacing or sp, window=window)
    del arr
    write_augmented(out, a["density"], a["gradient_magnitude"], a["normal"], a["spacing_ijk"], a["density_window"],
                    a["gradient_magnitude_scale"], {"source": f"isplat sample {name}"})
    return out


def _augment(name, shape, out: Path, quick: bool, **kw) -> None:
    """In this process when ``quick``; else in a subprocess (this one does not keep the big volumes' peak)."""
    if quick:
        augment_sample(name, shape, out, **kw)
        return
    subprocess.run([sys.executable, "-c", "from benchmarks.selective_read import augment_sample; from pathlib "
                    f"import Path; augment_sample({name!r}, {tuple(shape)!r}, Path({str(out)!r}), "
                    f"**{kw!r})"], check=True, cwd=ROOT)


def cases(work: Path, quick: bool, only=None) -> list[dict]:
    """The five cases (``only``: those named): name, what, augmented file, transfer function, view, source."""
    from .paper import TF_BOLTS, TF_BONE, TF_MRI

    f = 4 if quick else 1
    out = []
    specs = [("H1", "head sample, bone", "head", (256, 256, 225), TF_BONE, {}, {}),
             ("E2", "engine sample, bolts", "engine", (256, 256, 110), TF_BOLTS, dict(azimuth=35, elevation=25), {}),
             ("B1", None, "mr-head", (256, 256, 167), TF_MRI, dict(azimuth=180), {}),
             ("H1-512", "head sample, the 512^3 case, bone", "head", (512, 512, 512), TF_BONE, {}, {}),
             ("C1", "ct-chest sample, fat/skin veil and bone", "ct-chest", (512, 512, 133),
              TF_CHEST, dict(azimuth=0, elevation=10), CHEST)]
    real = Path(os.environ.get("ISPLAT_DATA", ROOT / "data")) / "mri-head.aug.h5"
    for name, what, sample, shape, tf, view, kw in specs:
        if only is not None and name not in only:
            continue
        if name == "B1" and real.exists() and not quick:
            out.append(dict(name=name, what="MRI head (real, `make data`), skin and brain", aug=real, tf=tf, **view,
                            source="data/mri-head.aug.h5 (pydeface 2.1.0 mean T1, `make data`)"))
            continue
        if name == "B1":
            why = "--quick" if quick else "data/mri-head.aug.h5 not found: run `make data`"
            what = f"SYNTHETIC MRI head (isplat sample mr-head; {why})"
        small = tuple(max(8, n // f) for n in shape)
        aug = work / f"{name}.aug.h5"
        _log(f"augment {name}: {sample} {small}")
        _augment(sample, small, aug, quick, **kw)
        extra = (f", --spacing {','.join(map(str, kw['spacing']))} --window={kw['window'][0]:g},"
                 f"{kw['window'][1]:g}") if kw else ""
        out.append(dict(name=name, what=what, aug=aug, tf=tf, **view,
                        source=f"isplat sample {sample} --shape {','.join(map(str, small))}{extra}"))
    return out


def as_version4(aug: Path, out: Path) -> Path:
    """``aug`` written again as an augmented file of format 4 (chunks of whole rows), k-slab by k-slab."""
    return as_version(aug, out, 4)


def as_version(aug: Path, out: Path, version: int, edge: int | None = None) -> Path:
    """``aug`` written again as an augmented file of ``version`` (6: bricks of ``edge``), k-slab by k-slab."""
    from isplat.augfile import (BRICK_EDGE, HASHED_ATTRIBUTES, ChannelWriter, create_augmented, finish_augmented,
                                open_augmented)
    from isplat.fileio import create_hdf5

    a = open_augmented(aug)
    keep = {n: a.attrs[n] for _, n in HASHED_ATTRIBUTES[7:] if n in a.attrs and n != "labels_sha256"}
    with create_hdf5(out) as f:
        create_augmented(f, a.shape, a.spacing_ijk, a.density_window, a.gradient_magnitude_scale,
                         a.density_sha256, keep, version=version, edge=edge or BRICK_EDGE)
        w = ChannelWriter(f)
        step = max(8, (1 << 24) // max(1, a.shape[1] * a.shape[2]) // 8 * 8)
        for k0 in range(0, a.shape[0], step):
            for ch in ("density", "gradient_magnitude", "normal"):
                w.write(ch, k0, min(a.shape[0], k0 + step), a.read(ch, k0, k0 + step))
        finish_augmented(f)
    return out


def _scene(work: Path, c: dict, idx: Path, variant: str) -> Path:
    from isplat.scene_schema import SCENE_VERSION

    from .paper import _COMMON

    technique = VARIANTS[variant]
    aug = c["aug_v4"] if variant == "post-v4" else c["aug"]
    p = work / f"{c['name']}-{variant}.toml"
    p.write_text(f'version = {SCENE_VERSION}\n\n[data]\naugmented = "{aug}"\nindex = "{idx}"\n'
                 + _COMMON.format(size=256, azimuth=c.get("azimuth", 0.0), elevation=c.get("elevation", 10.0),
                                  threads=1, technique=technique) + "\n" + c["tf"])
    return p


def _index(aug: Path, out: Path, quick: bool) -> None:
    if quick:
        from isplat.index import build_index_file

        from isplat.runsfile import build_runs_file

        build_index_file(aug, out, force=True)
        build_runs_file(aug, out, force=True)           # as isplat index does
        return
    subprocess.run([sys.executable, "-m", "isplat", "index", str(aug), "-o", str(out), "-q", "--force"], check=True,
                   cwd=ROOT)


def index_figures(idx_path: Path) -> dict:
    """The index's size: its file in all and per indexed voxel per axis, its axes' tables and blocks, and the
    values file beside it (formats 6 and 7; ``/values`` inside, format 4)."""
    from isplat.index import open_index

    idx = open_index(idx_path)
    vox = int(idx.voxel_counts(idx.axes[0]).sum())
    axes_bytes = sum(int(idx.nbytes(a)) for a in idx.axes)
    vf = idx.values_file
    values = os.path.getsize(vf.path) if vf is not None else \
        257 * 8 + 3 * idx.values.n_voxels if idx.values is not None else 0
    size = os.path.getsize(idx_path)
    return dict(file=size, per_voxel_axis=size / max(1, vox * len(idx.axes)),
                axes_per_voxel_axis=axes_bytes / max(1, vox * len(idx.axes)), values=values, version=idx.version)


def _once(scene, runs: bool = True) -> tuple[float, float, object, int]:
    """Load (s), frame (s), the report and the held bytes of one renderer of ``scene``'s first view (``runs``
    False: the index's runs file moved aside for the load)."""
    from isplat.renderer import Renderer
    from isplat.runsfile import runs_path

    if not runs:
        p = runs_path(scene.data.index)
        aside = p.with_name(p.name + ".aside")
        p.rename(aside)
        try:
            return _once(scene)
        finally:
            aside.rename(p)
    t = time.perf_counter()
    r = Renderer(scene, (scene.views[0],), slabs=1)
    load = time.perf_counter() - t
    _, st = r.render_view(0)
    return load, st.seconds, r.report, r.held_bytes()


def measure(c: dict, work: Path, repeats: int, quick: bool) -> list[dict]:
    """One row per technique for case ``c``."""
    from isplat.scene import load_scene

    idx = work / f"{c['name']}.idx.h5"
    _index(c["aug"], idx, quick)
    ixf = index_figures(idx)
    c["aug_v4"] = as_version4(c["aug"], work / f"{c['name']}.v4.aug.h5")
    order = list(VARIANTS)
    scenes = {t: load_scene(_scene(work, c, idx, t)) for t in order}
    times = {t: ([], []) for t in order}
    last = {}
    for n in range(repeats + 1):                       # the first round warms up (numba, page cache)
        for t in order[n % len(order):] + order[:n % len(order)]:
            load, frame, rep, held = _once(scenes[t], runs=t == "post")
            if n:
                times[t][0].append(load)
                times[t][1].append(frame)
            last[t] = (rep, held)
    rows = []
    for t in order:
        rep, held = last[t]
        rows.append(dict(name=c["name"], what=c["what"], source=c["source"], technique=VARIANTS[t], variant=t,
                         shape=_shape(c["aug"]),
                         intervals=rep.intervals, axis=rep.needed_axis, voi=rep.voxels_of_interest,
                         needed_voxels=rep.needed_voxels, per_voxel=rep.channel_bytes_per_voxel,
                         channels=list(rep.channels), values_from=rep.values_from, read=rep.file_bytes,
                         aug_read=rep.augmented_file_bytes, idx_read=rep.index_file_bytes, needed=rep.bytes_needed,
                         runs_read=rep.runs_file_bytes,
                         ratio=rep.read_ratio, pages=rep.file_pages, page_ratio=rep.page_ratio, held=held, load=statistics.median(times[t][0]),
                         frame=statistics.median(times[t][1]), index=ixf))
    idx.unlink()
    Path(str(idx).replace(".idx.h5", ".values.idx.h5")).unlink(missing_ok=True)
    Path(str(idx).replace(".idx.h5", ".runs.idx.h5")).unlink(missing_ok=True)
    c["aug_v4"].unlink()
    return rows


def _shape(aug) -> str:
    from isplat.augfile import open_augmented

    nk, nj, ni = open_augmented(aug).shape
    return f"{ni} x {nj} x {nk}"


def run(out_dir: Path, quick: bool) -> Path:
    repeats = REPEATS_QUICK if quick else REPEATS
    t0 = time.perf_counter()
    rows = []
    with tempfile.TemporaryDirectory(prefix="isplat-selective-") as t:
        work = Path(t)
        for c in cases(work, quick):
            _log(f"{c['name']}: {c['what']}")
            rows += measure(c, work, repeats, quick)
            for r in rows[-len(VARIANTS):]:
                _log(f"  {LABELS[r['variant']]}: read {_mb(r['read'])} MB for {_mb(r['needed'])} MB needed "
                     f"({r['ratio']:.2f}x; pages {_mb(r['pages'])} MB), held {r['held'] / max(1, r['voi']):.1f} B per voxel of interest, load "
                     f"{1000 * r['load']:.0f} ms, frame {1000 * r['frame']:.0f} ms")
            if c["aug"].parent == work:
                c["aug"].unlink()
    path = Path(out_dir) / "selective-read.md"
    path.write_text(render_doc(rows, quick, repeats, time.perf_counter() - t0))
    return path


def _mb(n) -> str:
    return f"{n / 1e6:.2f}"


def render_doc(rows, quick: bool, repeats: int, seconds: float) -> str:
    cmd = "python -m benchmarks selective_read" + (" --quick" if quick else "")
    L = ["# What each technique reads, against what it needs", "",
         f"Made by `{cmd}` on {_doc.machine_line()}, git {_doc.git_rev()}, in {seconds:.0f} s. Do not edit: "
         "rerun the command. Bytes needed: [stats.md](stats.md#bytes-needed-per-technique); the bricked layout "
         "measured for both: [design.md](design.md#bricked-channels-issue-26-the-measured-choice)."]
    if quick:
        L += ["", "**QUICK RUN (smoke test): volumes at 1/4 resolution, 2 rounds, builds in this process; not the "
                  "reference numbers.**"]
    L += ["", *_explanation(repeats), "", *_table(rows), "", *_old_new(rows), "", *_index_table(rows), "",
          "Sources: " + "; ".join(dict.fromkeys(f"{r['name']}: {r['source']}" for r in rows)) + ".", ""]
    return "\n".join(L)


def _explanation(repeats: int) -> list[str]:
    return [
        "What is read, per technique (format of `isplat index` and the augmented file as they are):",
        "",
        "- **pre** (the paper's pre-classified splatting, `render.classification = \"pre\"`): the index blocks "
        "and table rows of the transfer function's intervals, and the voxels of interest's normals (and gradient "
        "magnitudes, when the transfer function uses them) from the index's values file (`NAME.values.idx.h5`, "
        "since index format 6), one row range per interval (format 7: chunks without a chunk index, sized by the "
        "dataset, formats/index.md §1.1). Only the voxels of interest are read; *read* includes the "
        "values file's opening.",
        "- **post (runs file)** (the default technique, with the index's runs file `NAME.runs.idx.h5` beside it, "
        "as `isplat index` writes it): the same index blocks, and of the channels it samples only the runs "
        "meeting the intervals (formats/runs.md: every voxel whose quads can meet an interval, with its "
        "positions); the quads with a corner not read are skipped. *Read* includes the runs file's opening.",
        "- **post (format 6: bricks)** (the default technique without the runs file, post-classification, from a "
        "file written by "
        "`isplat augment`): the same index blocks, and of the "
        "channels it samples (the density, and when shaded the normal and the gradient magnitude) only the 8^3 "
        "bricks its quads can read: for each 4 x 4 cell of interest of the index, its quads, their in-slice "
        "neighbours and the cubic's taps between thick slices, in the cell's slice (each brick checked against "
        "its brick hash, the density's against `/brick_range`). Whole channels when more than "
        "`isplat.selection.BRICK_SHARE` of the bricks are needed.",
        "- **post (format 4: whole channels)**: the same volume written as format 4 (chunks of whole rows, the layout "
        "`isplat augment --rows` writes): the "
        "whole channels (4 B per voxel of the volume when shaded). Post never reads the "
        "values file.",
        "",
        "*Needed* is each technique's own ([stats.md](stats.md#bytes-needed-per-technique)): pre, the voxels of "
        "interest x the channel bytes it reads; post, the voxels its quads read on the view's axis (the voxels of "
        "interest and their in-slice neighbours; `axis`) x the channel bytes it reads; both + the index blocks and "
        "table rows of the intervals. *Read*: bytes HDF5 read from both files (whole chunks with their checksums, "
        "metadata, opening included). *Pages*: the bytes of the distinct 4 KB pages of the files those reads lie "
        "in (each once, however often read; the whole page, however little of it is read): what the operating "
        "system brings in from the disk at the least, since it reads whole pages (`scene.loaded.file_pages_read` "
        "of `isplat stats --json`). Bar (issue 26, on *read*): post <= 1.5 x needed, pre <= 1.3 x. *Held*: what the "
        f"renderer keeps for its frames, per voxel of interest (target, issue 26: at most {HELD_TARGET[2]:g} B for "
        f"{HELD_TARGET[0]}'s post scene, shaded, from the runs file). *Load*, *frame* (one thread): median of "
        f"{repeats} rounds after a warm-up, the techniques interleaved, on a machine shared with other work (under "
        "load).",
    ]


def _table(rows) -> list[str]:
    L = ["| case | technique | volume (i x j x k) | intervals | voxels of interest | needed voxels (axis) | "
         "channels read | needed (MB) | read (MB) | read / needed | bar | pages (MB) | pages / needed | "
         "held per voxel of interest (B) | load (ms) | frame (ms) |",
         "|---|---|---|---|---:|---:|---|---:|---:|---:|---|---:|---:|---:|---:|---:|"]
    for r in rows:
        ivs = ", ".join(f"{lo}..{hi}" for lo, hi in r["intervals"])
        tech = LABELS[r["variant"]]
        ok = "met" if r["ratio"] <= BAR[r["technique"]] else "**not met**"
        if f"{r['ratio']:.2f}" == f"{BAR[r['technique']]:.2f}":        # on the bar at two decimals: say which side
            ok += f" ({r['ratio']:.4f})"
        axis = f" ({r['axis']})" if r["axis"] else ""
        L.append(f"| {r['name']}: {r['what']} | {tech} | {r['shape']} | {ivs} | {r['voi']:,} | "
                 f"{r['needed_voxels']:,}{axis} | {', '.join(r['channels']) or '-'} ({r['per_voxel']} B) | "
                 f"{_mb(r['needed'])} | {_mb(r['read'])} | **{r['ratio']:.2f}** | <= {BAR[r['technique']]} {ok} | "
                 f"{_pages(r)} | "
                 f"{r['held'] / max(1, r['voi']):.1f} | {1000 * r['load']:.0f} | {1000 * r['frame']:.0f} |")
    name, variant, most = HELD_TARGET
    for r in (r for r in rows if r["name"] == name and r["variant"] == variant):
        held = r["held"] / max(1, r["voi"])
        L += ["", f"Held, {name} {LABELS[variant]}: {held:.2f} B per voxel of interest, target at most {most:g} B: "
                  + ("met." if held <= most else "**not met**.")]
    return L


def _pages(r) -> str:
    return "- | -" if r["pages"] < 0 else f"{_mb(r['pages'])} | {r['page_ratio']:.2f}"


def _old_new(rows) -> list[str]:
    """Post from the runs file and from bricks against post from whole channels, per case: bytes read, load and
    frame time."""
    L = ["Post from the runs file, and format 6 (bricks), against format 4 (whole channels), the same volume and "
         "scene, interleaved: "
         "bytes read from the augmented file, held, load and frame time (medians), and the ratios new / old.", "",
         "| case | channel values from | augmented (+ runs file) read, new / old (MB) | read / needed, new / old | "
         "held per voxel "
         "of interest, new / old (B) | load new / old (ms) | load ratio | frame new / old (ms) | frame ratio |",
         "|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    by = {(r["name"], r["variant"]): r for r in rows}
    for name, new in ((name, new) for name in dict.fromkeys(r["name"] for r in rows) for new in ("post",
                                                                                                  "post-bricks")):
        n, o = by.get((name, new)), by.get((name, "post-v4"))
        if n is None or o is None:
            continue
        voi = max(1, n["voi"])
        L.append(f"| {name} | {n['values_from']} | {_mb(n['aug_read'] + n.get('runs_read', 0))} / "
                 f"{_mb(o['aug_read'])} | "
                 f"{n['ratio']:.2f} / {o['ratio']:.2f} | {n['held'] / voi:.1f} / {o['held'] / voi:.1f} | "
                 f"{1000 * n['load']:.0f} / {1000 * o['load']:.0f} | {n['load'] / max(1e-9, o['load']):.2f} | "
                 f"{1000 * n['frame']:.0f} / {1000 * o['frame']:.0f} | {n['frame'] / max(1e-9, o['frame']):.2f} |")
    return L


def _index_table(rows) -> list[str]:
    L = ["The index (`isplat index` of all densities): its file, bytes per indexed voxel per axis (issue 26's "
         "target: 1.3), of which the axes' tables and blocks, and the values file beside it (since format 6, "
         "`NAME.values.idx.h5`: 3 B per indexed voxel, read by pre only; `isplat index --no-values` leaves it "
         "out).", "",
         "| case | index format | index file (MB) | B per indexed voxel per axis | of which axes | values file (MB) |",
         "|---|---:|---:|---:|---:|---:|"]
    for r in [r for r in rows if r["variant"] == "pre"]:
        ix = r["index"]
        L.append(f"| {r['name']} | {ix['version']} | {_mb(ix['file'])} | {ix['per_voxel_axis']:.2f} | "
                 f"{ix['axes_per_voxel_axis']:.2f} | {_mb(ix['values'])} |")
    return L
