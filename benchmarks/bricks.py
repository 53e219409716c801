"""Bricked channels, measured before choosing (issue 26): ``python -m benchmarks bricks [--quick]`` writes the
section "bricks" of ``design.md``.

For the five cases of ``benchmarks/selective_read.py`` and brick shapes 8^3, 16^3, 16 x 16 x 8 (i x j x k) and
32^3, counted from the density channel and the scene's transfer function:

* **post, bricked**: the bricks holding a voxel of interest or one of its neighbours (the one-voxel apron: the
  3 x 3 x 3 cube around each voxel of interest, which holds the in-slice neighbours post's quads read for a view
  along any axis), read whole in each of the channels post reads (density, normal, gradient magnitude: 4 B per
  voxel), each chunk with its 4-byte Fletcher-32 checksum; against post's bytes needed (docs/stats.md: the
  voxels its quads read on the view's axis x 4 B);
* **pre, bricked** (no ``/values``): the bricks holding a voxel of interest, of the normal channel (2 B per
  voxel, + 4 B each); against pre's bytes needed (voxels of interest x 2 B);
* the tables: a (min, max) density per brick (2 B), isplat's chunk hash per chunk (16 B per chunk and channel);
* **held** by a packed in-memory form (the post bricks of interest, 4 B per voxel, + a brick table of 4 B per
  brick of the grid) per voxel of interest, against issue 26's 8 B;
* **HDF5's cost per chunk**: the normal channel written chunked in that brick shape with Fletcher-32; reading
  the post bricks one chunk at a time (h5py slicing, checksums verified; and ``id.read_direct_chunk``, the raw
  chunk) against reading the whole channel; median of several runs, page cache warm, on a shared machine.

The index blocks (read by both techniques) are not counted here: ``selective_read`` reports them.
"""

from __future__ import annotations

import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from . import _doc

SECTION = "bricks"
TECHNIQUES = ["pre", "post"]
SOURCES = _doc.sources(_doc.AUGMENT, _doc.SAMPLES, ("isplat/stats.py", "benchmarks/bricks.py",
                                                     "benchmarks/selective_read.py"))
# (k, j, i) brick shapes, and their names (i x j x k)
SHAPES = {"4^3": (4, 4, 4), "8^3": (8, 8, 8), "16^3": (16, 16, 16), "16x16x8": (8, 16, 16), "32^3": (32, 32, 32)}
UNTIMED = ("4^3",)              # too many chunks for HDF5 (a brick table of isplat's own would hold them)
TIMED = ("H1", "C1")            # the cases whose HDF5 reads are timed (the others are counted only)
REPEATS, REPEATS_QUICK = 5, 2
POST_BYTES, PRE_BYTES = 4, 2    # per voxel: density + normal + gradient magnitude (post, shaded); normal (pre)
CHECKSUM, HASH, MINMAX, SLOT = 4, 16, 2, 4


def _log(msg):
    print(f"[bricks] {msg}", file=sys.stderr, flush=True)


def touched(mask: np.ndarray, shape) -> np.ndarray:
    """bool[bricks along k, j, i]: the bricks of ``shape`` (k, j, i) holding a True voxel of ``mask``.

    >>> m = np.zeros((4, 4, 4), bool); m[0, 0, 0] = m[3, 3, 3] = True
    >>> int(touched(m, (2, 2, 2)).sum()), touched(m, (2, 2, 2)).shape
    (2, (2, 2, 2))
    """
    pad = [(0, -n % e) for n, e in zip(mask.shape, shape)]
    m = np.pad(mask, pad)
    (kk, jj, ii), (ek, ej, ei) = [n // e for n, e in zip(m.shape, shape)], shape
    return m.reshape(kk, ek, jj, ej, ii, ei).any(axis=(1, 3, 5))


def apron(mask: np.ndarray) -> np.ndarray:
    """``mask`` grown by one voxel along each axis (the 3 x 3 x 3 cube around each True voxel)."""
    from isplat.stats import dilate_in_slice

    return dilate_in_slice(dilate_in_slice(mask, (1, 2)), (0,))


def count(density, intervals, view_axis: str) -> dict:
    """The byte counts of every brick shape for one case (module docstring)."""
    from isplat.stats import IN_SLICE_DIMS, dilate_in_slice, interest_mask, quad_footprint_per_slice

    mask = interest_mask(intervals)[density]
    grown = apron(mask)
    in_slice = dilate_in_slice(mask, IN_SLICE_DIMS[view_axis])
    voi = int(mask.sum())
    need_post = int(quad_footprint_per_slice(density, intervals, view_axis).sum()) * POST_BYTES
    out = dict(voi=voi, need_post=need_post, need_pre=voi * PRE_BYTES, shapes={},
               whole_ratio=density.size * POST_BYTES / max(1, need_post))
    for name, sh in SHAPES.items():
        v = int(np.prod(sh))
        tp, tq = touched(grown, sh), touched(mask, sh)
        n_all, n_post, n_pre = tp.size, int(tp.sum()), int(tq.sum())
        post = n_post * (v * POST_BYTES + 3 * CHECKSUM)
        pre = n_pre * (v * PRE_BYTES + CHECKSUM)
        n_view = int(touched(in_slice, sh).sum())     # the view's own apron (in its slices) only
        stored = int(np.prod([e + 2 for e in sh]))    # the apron stored in each brick: only bricks of interest
        post_apron = n_pre * (stored * POST_BYTES + 3 * CHECKSUM)
        out["shapes"][name] = dict(bricks=n_all, post_bricks=n_post, pre_bricks=n_pre, post_read=post,
                                   post_apron_ratio=post_apron / max(1, need_post), apron_size=stored / v,
                                   post_view_ratio=n_view * (v * POST_BYTES + 3 * CHECKSUM) / max(1, need_post),
                                   pre_read=pre, post_ratio=post / max(1, need_post), pre_ratio=pre / max(1, voi * 2),
                                   minmax=n_all * MINMAX, hashes=n_all * 3 * HASH,
                                   held=(n_post * v * POST_BYTES + n_all * SLOT) / max(1, voi), selected=tp)
    return out


def pack_bricks(channels: dict, selected: np.ndarray, shape) -> tuple[np.ndarray, dict]:
    """The compact in-memory form (a prototype): the ``selected`` bricks of each channel (``{name: [k, j, i]}``)
    packed one after another (``[n, ek, ej, ei]``, edge bricks padded), and the brick table: int32 per brick of
    the grid, its row in the packed arrays or -1.

    >>> d = np.arange(64, dtype=np.uint8).reshape(4, 4, 4); sel = np.zeros((2, 2, 2), bool); sel[1, 0, 1] = True
    >>> table, packed = pack_bricks({"density": d}, sel, (2, 2, 2))
    >>> int(table[1, 0, 1]), int(lookup(table, packed["density"], (2, 2, 2), 3, 1, 2)), int(d[3, 1, 2])
    (0, 54, 54)
    """
    table = np.full(selected.shape, -1, dtype=np.int32)
    where = np.argwhere(selected)
    table[tuple(where.T)] = np.arange(len(where), dtype=np.int32)
    packed = {}
    for name, arr in channels.items():
        pad = np.pad(arr, [(0, -n % e) for n, e in zip(arr.shape, shape)])
        (kk, jj, ii), (ek, ej, ei) = [n // e for n, e in zip(pad.shape, shape)], shape
        grid = pad.reshape(kk, ek, jj, ej, ii, ei).transpose(0, 2, 4, 1, 3, 5)
        packed[name] = np.ascontiguousarray(grid[tuple(where.T)])
    return table, packed


def lookup(table, packed, shape, k, j, i):
    """A voxel's value in the packed form (-1's brick is not held: IndexError)."""
    row = table[k // shape[0], j // shape[1], i // shape[2]]
    if row < 0:
        raise IndexError(f"voxel ({k}, {j}, {i}) is in no packed brick")
    return packed[row, k % shape[0], j % shape[1], i % shape[2]]


def time_chunks(normal: np.ndarray, shape, selected: np.ndarray, work: Path, repeats: int) -> dict:
    """Seconds to read the ``selected`` bricks of the normal channel chunked in ``shape`` (by slicing and by
    ``read_direct_chunk``) and the whole channel, medians of ``repeats``."""
    import h5py

    path = work / "bricks.h5"
    with h5py.File(path, "w") as f:
        f.create_dataset("normal", data=normal, chunks=shape, fletcher32=True)
    offsets = [tuple(int(x) * e for x, e in zip(ix, shape)) for ix in np.argwhere(selected)]
    times = {"whole": [], "sliced": [], "direct": []}
    with h5py.File(path, "r") as f:
        d = f["normal"]
        for _ in range(repeats + 1):
            t = time.perf_counter()
            d[...]
            times["whole"].append(time.perf_counter() - t)
            t = time.perf_counter()
            for o in offsets:
                d[o[0]:o[0] + shape[0], o[1]:o[1] + shape[1], o[2]:o[2] + shape[2]]
            times["sliced"].append(time.perf_counter() - t)
            t = time.perf_counter()
            for o in offsets:
                d.id.read_direct_chunk(o)
            times["direct"].append(time.perf_counter() - t)
    path.unlink()
    med = {k: statistics.median(v[1:]) for k, v in times.items()}
    n = max(1, len(offsets))
    return dict(n=len(offsets), whole=med["whole"], sliced=med["sliced"], direct=med["direct"],
                us_sliced=1e6 * med["sliced"] / n, us_direct=1e6 * med["direct"] / n)


def packed_held(aug, row) -> dict:
    """Bytes per voxel of interest the packed form (:func:`pack_bricks`) holds for post's bricks, per shape."""
    chans = {c: aug.read(c) for c in ("density", "normal", "gradient_magnitude")}
    out = {}
    for name, sh in SHAPES.items():
        table, packed = pack_bricks(chans, row["shapes"][name]["selected"], sh)
        out[name] = (table.nbytes + sum(a.nbytes for a in packed.values())) / max(1, row["voi"])
        del packed
    return out


def _intervals_and_axis(c: dict, work: Path):
    """The case's transfer-function intervals and its view's principal axis."""
    from isplat.augfile import open_augmented
    from isplat.frame import views_for
    from isplat.scene import load_scene
    from isplat.transfer import build_luts

    from .selective_read import _scene

    p = _scene(work, c, work / "none.idx.h5", "post")
    p.write_text(p.read_text().replace('method = "indexed"', 'method = "full"').replace(
        f'index = "{work / "none.idx.h5"}"\n', ""))
    scene = load_scene(p)
    aug = open_augmented(c["aug"])
    ivs = [tuple(map(int, iv)) for iv in build_luts(scene.transfer, aug.gradient_magnitude_scale).intervals]
    return ivs, views_for(scene, aug)[0].axis_sign[0]


def measure(c: dict, work: Path, repeats: int) -> dict:
    from isplat.augfile import open_augmented

    ivs, axis = _intervals_and_axis(c, work)
    aug = open_augmented(c["aug"])
    row = dict(name=c["name"], what=c["what"], axis=axis, intervals=ivs, voxels=aug.n_voxels,
               **count(aug.read("density"), ivs, axis))
    if c["name"] == "H1":           # the prototype's memory, for the shaded post head scene (issue 26, item 4)
        row["packed"] = packed_held(aug, row)
    if c["name"] in TIMED:
        normal = aug.read("normal")
        for name, sh in SHAPES.items():
            if name in UNTIMED:
                continue
            row["shapes"][name]["hdf5"] = time_chunks(normal, sh, row["shapes"][name]["selected"], work, repeats)
    for s in row["shapes"].values():
        s.pop("selected")
    return row


def run(out_dir: Path, quick: bool) -> Path:
    from .selective_read import cases

    repeats = REPEATS_QUICK if quick else REPEATS
    t0 = time.perf_counter()
    rows = []
    with tempfile.TemporaryDirectory(prefix="isplat-bricks-") as t:
        work = Path(t)
        for c in cases(work, quick):
            _log(f"{c['name']}: {c['what']}")
            rows.append(measure(c, work, repeats))
            if c["aug"].parent == work:
                c["aug"].unlink()
    body = render(rows, quick, repeats, time.perf_counter() - t0)
    return _doc.update_section(Path(out_dir) / "design.md", SECTION, body)


def _mb(n) -> str:
    return f"{n / 1e6:.2f}"


def render(rows, quick: bool, repeats: int, seconds: float) -> str:
    cmd = "python -m benchmarks bricks" + (" --quick" if quick else "")
    L = [f"Made by `{cmd}` on {_doc.machine_line()}, git {_doc.git_rev()}, in {seconds:.0f} s (under load: a "
         "machine shared with other work). Do not edit: rerun the command."]
    if quick:
        L += ["", "**QUICK RUN: volumes at 1/4 resolution; not the reference numbers.**"]
    L += ["", "Bytes a bricked layout would read against each technique's bytes needed (channels only; "
          "[stats.md](stats.md#bytes-needed-per-technique)); post, shaded: density + normal + gradient magnitude "
          "(4 B per voxel) of the bricks touching the one-voxel apron of the voxels of interest; pre: the normal "
          "(2 B) of the bricks holding a voxel of interest. Held: a packed in-memory form (post's bricks, 4 B per "
          "voxel, + 4 B per brick of the grid) per voxel of interest.", "",
          "| case | bricks | post: bricks read | post: read (MB) | post: needed (MB) | post: read / needed | "
          "post, the view's apron only: read / needed | post, apron stored in each brick: read / needed (file x) | "
          "pre: read / needed | held per voxel of interest (B) | (min, max) table (kB) | chunk hashes (kB) |",
          "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        for name, s in r["shapes"].items():
            L.append(f"| {r['name']} | {name} | {s['post_bricks']:,} of {s['bricks']:,} | {_mb(s['post_read'])} | "
                     f"{_mb(r['need_post'])} | **{s['post_ratio']:.2f}** | {s['post_view_ratio']:.2f} | "
                     f"{s['post_apron_ratio']:.2f} ({s['apron_size']:.2f}) | "
                     f"{s['pre_ratio']:.2f} | {s['held']:.1f} | "
                     f"{s['minmax'] / 1e3:.1f} | {s['hashes'] / 1e3:.1f} |")
    held = next((r["packed"] for r in rows if "packed" in r), None)
    if held:
        L += ["", "The packed in-memory form prototyped (`benchmarks.bricks.pack_bricks`: post's bricks of the "
              "three channels packed, + the int32 brick table), built for H1 (shaded post head scene): "
              + ", ".join(f"{name} {v:.1f} B" for name, v in held.items())
              + " held per voxel of interest (issue 26's target: 8 B; today's whole channels: the post rows of "
              "docs/selective-read.md)."]
    L += ["", f"HDF5's cost per chunk (h5py, the normal channel chunked in the brick shape with Fletcher-32; the post "
          f"bricks of the case read one chunk at a time, sliced (checksum verified) and with `read_direct_chunk` "
          f"(raw), against the whole channel; median of {repeats}, page cache warm):", "",
          "| case | bricks | chunks read | sliced (ms) | per chunk, sliced (us) | direct (ms) | per chunk, direct "
          "(us) | whole channel (ms) | sliced / whole |",
          "|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        for name, s in r["shapes"].items():
            h = s.get("hdf5")
            if h:
                L.append(f"| {r['name']} | {name} | {h['n']:,} | {1e3 * h['sliced']:.1f} | {h['us_sliced']:.1f} | "
                         f"{1e3 * h['direct']:.1f} | {h['us_direct']:.1f} | {1e3 * h['whole']:.1f} | "
                         f"{h['sliced'] / max(1e-9, h['whole']):.2f} |")
    L += ["", "Cases: " + "; ".join(f"{r['name']}: {r['what']}, view axis {r['axis']}, intervals "
                                    + ", ".join(f"{lo}..{hi}" for lo, hi in r["intervals"])
                                    + f", {r['voi']:,} voxels of interest of {r['voxels']:,}; post today (whole "
                                    f"channels): {r['whole_ratio']:.2f} x its channel bytes needed" for r in rows)
          + ". *The view's apron only*: the bricks touching the voxels of interest and their neighbours in the "
          "view's slices (a scene with views along several axes reads the union). *Apron stored*: each brick "
          "stores its one-voxel apron too ((e + 2)^3 voxels; the file grows by "
          "the factor in parentheses), so post reads only the bricks holding a voxel of interest."]
    return "\n".join(L)


def check_packed(seed: int) -> bool:
    """The packed prototype holds every voxel post's quads read, and the counts are its bricks' bytes, on a random
    volume (``seed``: its shape, brick shape and densities); raises AssertionError where not. A doctest (run by
    ``make bench-check``: the tests do not import the benchmarks):

    >>> all(check_packed(s) for s in range(24))
    True
    """
    from isplat.stats import interest_mask, quad_footprint_per_slice

    rng = np.random.default_rng(seed)
    shape = tuple(int(n) for n in rng.integers(1, 21, 3))
    brick = list(SHAPES.values())[seed % len(SHAPES)]
    d = np.where(rng.random(shape) < 0.05, 200, rng.integers(0, 150, shape)).astype(np.uint8)
    ivs = [(180, 255)]
    grown = apron(interest_mask(ivs)[d])
    for axis in "ijk":              # the apron holds every voxel post's quads read, for a view along any axis
        assert int(quad_footprint_per_slice(d, ivs, axis).sum()) <= int(grown.sum())
    table, packed = pack_bricks({"density": d}, touched(grown, brick), brick)
    for k, j, i in np.argwhere(grown):
        assert lookup(table, packed["density"], brick, k, j, i) == d[k, j, i]
    name = next(n for n, s in SHAPES.items() if s == brick)     # the bricks packed: 4 B a voxel, 12 B of checksums
    c = count(d, ivs, "k")["shapes"][name]
    assert c["post_bricks"] == packed["density"].shape[0]
    assert c["post_read"] == c["post_bricks"] * (int(np.prod(brick)) * 4 + 12)
    return True
