"""Figures about a volume, its index and a scene: the quantities of the paper's Figure 5 (docs/stats.md).

>>> s = collect("head.aug.h5", "head.idx.h5", scene="head.toml")     # doctest: +SKIP
>>> s["scene"]["spatial_ratio"], s["index"]["bytes"]                  # doctest: +SKIP

``collect`` returns one plain dict (the JSON of ``isplat stats --json``, keys documented in docs/stats.md);
``format_table`` renders it as readable text. Everything is counted, nothing estimated: voxel counts come from
the index's per-density tables or the density channel, byte counts from the files' tables and from what the
renderer actually read (:class:`isplat.selection.LoadReport`).

The paper's *spatial ratio* is the number of voxels whose density lies in the transfer function's non-zero
opacity intervals over all voxels (§4, "the spatial ratios of the number of voxels that were actually visited to
the whole number of voxels"). It is a property of the volume and the transfer function; how many of those
voxels a view really splats (after cutting planes, gradient modulation and early termination) is measured by
rendering the view.
"""

from __future__ import annotations

import os
import tomllib
from pathlib import Path

import numpy as np

from .augfile import CHANNELS, open_augmented
from .errors import IsplatError

STATS_VERSION = 9


def density_histogram(aug) -> np.ndarray:
    """int64[256]: voxels per density code, counted from the density channel slab by slab."""
    nk = aug.shape[0]
    step = max(1, (1 << 24) // max(1, aug.shape[1] * aug.shape[2]))
    h = np.zeros(256, dtype=np.int64)
    for k0 in range(0, nk, step):
        h += np.bincount(aug.read("density", k0, min(nk, k0 + step)).ravel(), minlength=256)
    return h


def decoded_axis_bytes(n_slices: int, n_blocks: int, n_voxels: int) -> int:
    """Size of a :class:`isplat.index.LoadedAxis` holding ``n_blocks`` blocks and ``n_voxels`` voxels:
    slice_block_ptr int64, block_density uint8, block_voxel_ptr int64, positions int32."""
    return 8 * (n_slices + 1) + n_blocks + 8 * (n_blocks + 1) + 4 * n_voxels


def loaded_axis_bytes(la) -> int:
    """Bytes of the decoded arrays of a loaded axis (what the renderer holds for it)."""
    return int(la.slice_block_ptr.nbytes + la.block_density.nbytes + la.block_voxel_ptr.nbytes
               + la.positions.nbytes)


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return Path(os.path.abspath(a)) == Path(os.path.abspath(b))


def _ratio(a, b) -> float:
    return float(a) / float(b) if b else 0.0


# ------------------------------------------------------------------------------------------- bytes needed

# slice axis -> the array dimensions (of [k, j, i]) that lie in its slices
IN_SLICE_DIMS = {"k": (1, 2), "j": (0, 2), "i": (0, 1)}
FOOTPRINT_SLAB = 16          # k-planes dilated at a time (plus one on each side when k lies in the slices)


def interest_mask(intervals) -> np.ndarray:
    """bool[256]: True at the density codes of the inclusive ``intervals``."""
    m = np.zeros(256, dtype=bool)
    for lo, hi in intervals:
        m[int(lo):int(hi) + 1] = True
    return m


def dilate_in_slice(m: np.ndarray, dims) -> np.ndarray:
    """``m`` grown by one voxel along each of ``dims`` (separably: the 3 x 3 square in the slice)."""
    for d in dims:
        out = m.copy()
        a, b = [slice(None)] * 3, [slice(None)] * 3
        a[d], b[d] = slice(1, None), slice(None, -1)
        out[tuple(a)] |= m[tuple(b)]
        out[tuple(b)] |= m[tuple(a)]
        m = out
    return m


def quad_footprint_per_slice(density: np.ndarray, intervals, axis: str) -> np.ndarray:
    """int64[slices of ``axis``]: per slice perpendicular to ``axis``, the voxels the post-classified sampler
    reads (isplat.splat.post): a quad (the square from voxel (a, b) to (a + 1, b + 1) of the slice) is sampled
    when one of its four voxels is of interest, and reads its four voxels; so the voxels read are those of
    interest and their neighbours at -1, 0, +1 in a and in b (the 3 x 3 square around each, in its slice).
    ``density``: uint8 [k, j, i] (or a slab of ``axis``'s slices, which are independent)."""
    lut = interest_mask(intervals)
    dims = IN_SLICE_DIMS[axis]
    nk = density.shape[0]
    out = np.zeros(density.shape[2 - "ijk".index(axis)], dtype=np.int64)
    halo = 1 if 0 in dims else 0
    for k0 in range(0, nk, FOOTPRINT_SLAB):
        k1 = min(nk, k0 + FOOTPRINT_SLAB)
        lo, hi = max(0, k0 - halo), min(nk, k1 + halo)
        grown = dilate_in_slice(lut[density[lo:hi]], dims)[k0 - lo:k0 - lo + (k1 - k0)]
        if axis == "k":
            out[k0:k1] += grown.sum(axis=(1, 2))
        else:
            out += grown.sum(axis=(0, 2) if axis == "j" else (0, 1))
    return out


def bytes_per_voxel(channels) -> int:
    """Bytes per voxel of the augmented channels named (normal 2 B, the others 1 B)."""
    return int(sum(np.dtype(CHANNELS.get(c, np.uint8)).itemsize for c in channels))


# ------------------------------------------------------------------------------------------------ sections

def augmented_section(aug) -> dict:
    n = aug.n_voxels
    nk, nj, ni = aug.shape
    channel_bytes = {c: n * np.dtype(t).itemsize for c, t in CHANNELS.items()}
    lo, hi = aug.density_window
    return {
        "path": str(aug.path),
        "file_bytes": int(Path(aug.path).stat().st_size),
        "shape_ijk": [ni, nj, nk],
        "voxels": n,
        "spacing_ijk": list(aug.spacing_ijk),
        "density_window": [lo, hi],
        "density_step": (hi - lo) / 255.0,
        "gradient_magnitude_scale": aug.gradient_magnitude_scale,
        "density_sha256": aug.density_sha256,
        "source": aug.attrs.get("source"),
        "source_format": aug.attrs.get("source_format"),
        "axes_lps": None if aug.axes_lps is None else aug.axes_lps.tolist(),
        "channel_bytes": channel_bytes,
        "bytes": int(sum(channel_bytes.values())),
        "bytes_per_voxel": int(sum(np.dtype(t).itemsize for t in CHANNELS.values())),
    }


def check_counts(idx, counts: dict, n_voxels: int) -> None:
    """The index's per-density voxel counts agree between axes and with the volume, before any is printed."""
    axes = list(counts)
    for a in axes[1:]:
        bad = np.flatnonzero(counts[a] != counts[axes[0]])
        if bad.size:
            d = int(bad[0])
            raise IsplatError(f"{idx.path}: axis {a} indexes {int(counts[a][d]):,} voxels of density {d}, axis "
                              f"{axes[0]} {int(counts[axes[0]][d]):,}: the tables disagree (corrupt index); "
                              f"rebuild it with isplat index")
    total = int(counts[axes[0]].sum())
    full = [tuple(r) for r in idx.density_ranges] == [(0, 255)]
    if total > n_voxels or (full and total != n_voxels):
        raise IsplatError(f"{idx.path}: the index holds {total:,} voxels, the volume {n_voxels:,}"
                          f"{' (all densities are indexed, so they must be equal)' if full else ''}: corrupt index; "
                          f"rebuild it with isplat index")


def index_section(idx, aug) -> dict:
    per_axis, counts = {}, {}
    for a in idx.axes:
        counts[a] = idx.voxel_counts(a)
    check_counts(idx, counts, aug.n_voxels)
    if idx.has_values:
        per_density = np.diff(idx.value_ptr())
        a = idx.axes[0]
        bad = np.flatnonzero(per_density != counts[a])
        if bad.size:
            d = int(bad[0])
            raise IsplatError(f"{idx.path}: /values holds {int(per_density[d]):,} voxels of density {d}, axis {a} "
                              f"{int(counts[a][d]):,}: the tables disagree (corrupt index); rebuild it with "
                              f"isplat index")
    for a in idx.axes:
        info = idx.axis_info(a)
        c = counts[a]
        nbytes = idx.nbytes(a)
        vox = int(c.sum())
        per_axis[a] = {
            "bytes": int(nbytes),
            "block_bytes": int(info["n_bytes"]),
            "entries": int(info["n_entries"]),
            "voxels": vox,
            "escape_width": int(info["escape_width"]),
            "bytes_per_voxel": _ratio(nbytes, vox),
            "block_bytes_per_voxel": _ratio(info["n_bytes"], vox),
            "decoded_bytes": decoded_axis_bytes(info["n_slices"], info["n_entries"], vox),
        }
    ranges = []
    for lo, hi in idx.density_ranges:
        ranges.append(_range_entry(idx, counts, lo, hi, aug.n_voxels))
    total = sum(v["bytes"] for v in per_axis.values())
    vox = sum(v["voxels"] for v in per_axis.values())
    first = next(iter(counts.values()))
    file_bytes = int(Path(idx.path).stat().st_size)
    return {
        "path": str(idx.path),
        "file_bytes": file_bytes,
        "file_bytes_per_voxel": _ratio(file_bytes, vox),
        "axes": idx.axes,
        "density_ranges": [[int(lo), int(hi)] for lo, hi in idx.density_ranges],
        "voxels_indexed": int(first.sum()),
        "bytes": int(total),
        "bytes_per_voxel": _ratio(total, vox),
        "bytes_per_volume_voxel": _ratio(total, aug.n_voxels),
        "decoded_bytes": int(sum(v["decoded_bytes"] for v in per_axis.values())),
        "per_axis": per_axis,
        "per_density_range": ranges,
        "format_version": idx.version,
        "values": _values_entry(idx),
    }


def _values_entry(idx) -> dict | None:
    """Where the indexed voxels' channel values are (``/values`` inside a version-4 index, or the values file
    beside a version-6 one), their voxels and bytes, and the values file's size; None without them."""
    if not idx.has_values:
        return None
    n = int(idx.values_meta.n_voxels)
    vf = idx.values_file if idx.values is None else None
    return {"in": idx.values_source, "path": str(vf.path if vf is not None else idx.path), "voxels": n,
            "bytes": 257 * 8 + 3 * n, "file_bytes": int(Path(vf.path).stat().st_size) if vf is not None else None}


def runs_entry(aug, idx_path) -> dict | None:
    """The runs file beside the index (formats/runs.md), as a render would open it, tied to ``aug`` (shape,
    density hash, chunk hash check), its pointer tables and every chunk checked against its hash; None when
    there is none. A runs file that fails is refused with one line naming it and the command that rebuilds it,
    as a post-classified render reading it would be (it does not fall back to bricks)."""
    from .chunkhash import CHECK_ATTR
    from .runsfile import FORMAT_VERSION, open_runs, refusal, runs_path

    path = runs_path(idx_path)
    if not path.exists():
        return None
    with refusal(path, aug.path, idx_path), \
            open_runs(path, shape=aug.shape, density_sha256=aug.density_sha256,
                      augmented_chunk_hash_check=str(aug.attrs.get(CHECK_ATTR, ""))) as rf:
        rf.verify_all()
        per_run = np.diff(rf.ptrs[0])
        return {"path": str(path), "file_bytes": int(path.stat().st_size), "format_version": FORMAT_VERSION,
                "runs": int(per_run.size), "runs_with_voxels": int(np.count_nonzero(per_run)),
                "bins": [int(rf.cut.lo.size), int(rf.cut.hi.size)], "voxels": int(per_run.sum()), "tied": True}


def _range_entry(idx, counts, lo, hi, n_voxels) -> dict:
    per_axis = {a: int(idx.nbytes(a, [(int(lo), int(hi))])) for a in idx.axes}
    vox = int(next(iter(counts.values()))[lo:hi + 1].sum())
    return {"densities": [int(lo), int(hi)], "voxels": vox, "fraction": _ratio(vox, n_voxels),
            "bytes": int(sum(per_axis.values())), "bytes_per_axis": per_axis}


def _covered(idx, intervals) -> bool:
    ok = np.zeros(256, dtype=bool)
    for lo, hi in idx.density_ranges:
        ok[lo:hi + 1] = True
    return all(ok[lo:hi + 1].all() for lo, hi in intervals)


# -------------------------------------------------------------------------------------------------- scene

def scene_overrides(scene_path, overrides, aug_path: Path, idx_path: Path | None) -> list[str]:
    """``overrides`` and after them those that make the scene describe the command line's files: ``data.augmented``
    is AUG.h5; ``data.index`` is IDX.h5, or when none is given the scene's own (if the scene names AUG.h5, or a
    ``--set data.index`` does), else the index beside AUG.h5 (the same stem, ``.idx.h5``) if there is one."""
    from .scene_input import index_beside, toml_string

    extra = ["data.augmented=" + toml_string(os.path.abspath(aug_path))]
    if idx_path is None and not any(o.split("=", 1)[0].strip() == "data.index" for o in overrides):
        try:
            tree = tomllib.loads(Path(scene_path).read_text(encoding="utf-8-sig"))
        except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
            tree = {}                                  # load_scene reports the problem with its line
        data = tree.get("data") if isinstance(tree, dict) else None
        data = data if isinstance(data, dict) else {}
        named = data.get("augmented")
        own = isinstance(named, str) and _same_file(Path(scene_path).parent / os.path.expanduser(named), aug_path)
        if not (own and "index" in data) and index_beside(aug_path).is_file():
            idx_path = index_beside(aug_path)
    if idx_path is not None:
        extra.append("data.index=" + toml_string(os.path.abspath(idx_path)))
    return list(overrides) + extra


def scene_section(scene_file, overrides, aug, aug_path: Path, idx, hist_from_index, view: int) -> tuple[dict, object]:
    """The ``scene`` section of the JSON (docs/stats.md) and the frame's stats. Over 60 lines: one flat dict
    literal, a line per documented key in the order of docs/stats.md, which reads better whole than cut up."""
    from .renderer import Renderer
    from .scene import load_scene
    from .transfer import build_luts

    # (overrides: scene_overrides, the command line's files); an older version's defaults said here, once
    scene = load_scene(scene_file, overrides, say_old_defaults=True)
    if not 0 <= view < len(scene.views):
        raise IsplatError(f"--view {view}: the scene has {len(scene.views)} view(s) (0..{len(scene.views) - 1})")
    luts = build_luts(scene.transfer, aug.gradient_magnitude_scale)
    intervals = [[int(lo), int(hi)] for lo, hi in luts.intervals]
    if idx is not None and hist_from_index is not None and _covered(idx, intervals):
        hist, source = hist_from_index, "index"
    else:
        hist, source = density_histogram(open_augmented(aug_path)), "augmented density"
    voi = int(sum(int(hist[lo:hi + 1].sum()) for lo, hi in intervals))
    n = aug.n_voxels
    lo_w, hi_w = aug.density_window
    step = (hi_w - lo_w) / 255.0

    r = Renderer(scene, (scene.views[view],), slabs=1)      # the whole selection: its held bytes are reported
    _, st = r.render_view(0)
    rep = r.report
    labels = _labels_entry(scene, aug)
    if labels:                  # the voxels of the shown labels are of interest too (isplat.label_select)
        voi, source = int(rep.voxels_of_interest), "labels and augmented density"
    decoded = int(rep.index_decoded_bytes)
    held = r.held_bytes()
    return {
        "path": str(scene_file),
        "view": view,
        "method": r.method,
        "projection": scene.views[view].projection,
        "image": [scene.image.width, scene.image.height],
        "intervals": intervals,
        "intervals_input_units": [[lo_w + lo * step, lo_w + hi * step] for lo, hi in intervals],
        "ratio_source": source,
        "voxels_of_interest": voi,
        "spatial_ratio": _ratio(voi, n),
        "axis": ("+" if st.sign > 0 else "-") + st.axis,
        "slices": st.slices,
        "voxels_examined": st.voxels_examined,
        "classification": st.classification,
        "voxels_splatted": st.voxels_splatted,        # pre-classified; 0 under post
        "splatted_ratio": _ratio(st.voxels_splatted, n),
        "samples": st.samples,                        # post-classified (mip/minip: samples taken); 0 under pre
        **({"voxels_visited": st.voxels_tested} if st.classification in ("mip", "minip") else {}),
        "render_seconds": st.seconds,
        "loaded": {
            "channels": list(rep.channels),
            "axes": list(rep.axes),
            "values_from": rep.values_from,
            "augmented_bytes": int(rep.augmented_bytes),
            "index_bytes": int(rep.index_bytes),
            "values_bytes": int(rep.values_bytes),
            "bytes": int(rep.augmented_bytes + rep.index_bytes + rep.values_bytes),
            "augmented_file_bytes_read": int(rep.augmented_file_bytes),
            "index_file_bytes_read": int(rep.index_file_bytes),
            "values_file_bytes_read": int(rep.values_file_bytes),
            "runs_file_bytes_read": int(rep.runs_file_bytes),
            "runs_path": rep.values_path if rep.runs_file_bytes else "",
            "file_bytes_read": int(rep.file_bytes),
            "technique": rep.technique,
            "needed_voxels": int(rep.needed_voxels),
            "needed_axis": rep.needed_axis,
            "channel_bytes_per_voxel": int(rep.channel_bytes_per_voxel),
            "channel_bytes_needed": int(rep.channel_bytes_needed),
            "index_bytes_needed": int(rep.index_bytes_needed),
            "bytes_needed": int(rep.bytes_needed),
            "read_ratio": rep.read_ratio,
            "file_pages_read": int(rep.file_pages),
            "page_ratio": rep.page_ratio,
            "index_decoded_bytes": decoded,
            "held_bytes": int(held),
            "held_bytes_per_voxel_of_interest": _ratio(held, voi),
        },
        "labels": labels,
    }, scene


def _labels_entry(scene, aug) -> list:
    """The scene's shown labels with their voxels in the file (``[]`` without labels)."""
    counts = aug.label_voxels if aug.has_labels else np.zeros(0, np.int64)
    return [{"id": st.id, "name": st.name, "voxels": int(counts[st.id]) if st.id < counts.shape[0] else 0}
            for st in scene.labels.shown]


def collect(augmented, index=None, scene=None, overrides=(), view: int = 0) -> dict:
    """All figures for ``augmented`` (and ``index``, and ``scene`` rendered at view ``view``) as one dict."""
    aug_path = Path(augmented)
    aug = open_augmented(aug_path)
    open_augmented(aug_path).verify_all()      # every chunk of every channel against its hash (own counters)
    idx_path = Path(index) if index is not None else None
    if scene is not None:
        overrides = scene_overrides(scene, list(overrides), aug_path, idx_path)
        idx_path = idx_path or _scene_index(scene, overrides)
    idx = None
    out = {"stats_version": STATS_VERSION, "augmented": augmented_section(aug), "index": None, "scene": None}
    hist_from_index = None
    if idx_path is not None:
        from .index import open_index

        idx = open_index(idx_path)
        again = open_index(idx_path)
        again.verify_all()      # every chunk of every table, block stream and value channel
        if again.values_file is not None:
            again.values_file.verify_all()     # the values file beside (version 6), checked to belong to it
        if tuple(idx.shape) != tuple(aug.shape) or idx.density_sha256 != aug.density_sha256:
            raise IsplatError(f"{idx_path}: index was built from another volume (density_sha256 "
                              f"{idx.density_sha256[:12]}..., {aug_path.name} has {aug.density_sha256[:12]}...); "
                              f"rebuild it with isplat index {aug_path}")
        out["index"] = index_section(idx, aug)
        out["index"]["runs"] = runs_entry(aug, idx_path)
        hist_from_index = idx.voxel_counts(idx.axes[0])
    if scene is not None:
        out["scene"], _ = scene_section(scene, overrides, aug, aug_path, idx, hist_from_index, view)
        # against the whole: channels and index tables as counted above, and the files on disk
        s, a, ix = out["scene"]["loaded"], out["augmented"], out["index"]
        s["augmented_fraction"] = _ratio(s["augmented_bytes"], a["bytes"])
        s["index_fraction"] = _ratio(s["index_bytes"], ix["bytes"]) if ix else 0.0
        whole = a["file_bytes"] + (ix["file_bytes"] if ix else 0) + \
            ((ix["values"]["file_bytes"] or 0) if ix and ix["values"] else 0)
        s["files_bytes"] = int(whole)
        s["files_fraction"] = _ratio(s["bytes"], whole)
    return out


def _scene_index(scene_file, overrides) -> Path | None:
    """The index a scene names (to report on it when no IDX is given), or None."""
    from .scene import load_scene

    try:
        return load_scene(scene_file, list(overrides)).data.index
    except IsplatError:
        return None                                    # reported when the scene is loaded for real


# -------------------------------------------------------------------------------------------------- table

def _b(n) -> str:
    """Bytes, human-readable, with the exact count."""
    n = int(n)
    for unit, f in (("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)):
        if n >= f:
            return f"{n / f:.2f} {unit} ({n:,} B)"
    return f"{n:,} B"


def _pct(x) -> str:
    return f"{100 * x:.2f}%"


VALUES_WORDS = {
    "index": "the index's /values (only the voxels of interest)",
    "values file": "the index's values file (only the voxels of interest)",
    "augmented slabs": "the augmented file, in slabs of 8 k-slices (no values file; isplat index writes it, to read "
                       "only theirs)",
    "augmented bricks": "the augmented file, the bricks that hold a voxel of interest (a slab, or no values file; "
                        "isplat index writes it, to read only theirs)",
    "whole channels": "the augmented file, whole channels (full method, or post-classification: the neighbours of "
                      "the voxels of interest are sampled too)",
    "slab's channels": "the augmented file, the slab's slices of the channels",
    "none": "nowhere (no channel needed)"}


def _values_words(values_from: str) -> str:
    """``scene.loaded.values_from`` in words; post's ``bricks (N of M)`` and ``runs file (R of N runs)`` with
    their counts."""
    if values_from.startswith("runs file"):
        return (f"the index's runs file, {values_from[len('runs file '):].strip('()')} (post-classification: the "
                f"voxels whose quads can meet an interval; the quads with a corner not read are skipped)")
    if values_from.startswith("bricks"):
        return f"the augmented file, {values_from} (post-classification: the bricks of 8^3 its quads can read)"
    return VALUES_WORDS[values_from]


def needed_words(ld: dict) -> str:
    """How ``scene.loaded.bytes_needed`` was counted, in words (docs/stats.md)."""
    what = (f"{ld['needed_voxels']:,} voxels its quads read on axis {ld['needed_axis']} (the voxels of interest "
            f"and their in-slice neighbours)" if ld["needed_axis"] else f"{ld['needed_voxels']:,} voxels of interest")
    return (f"{what} x {ld['channel_bytes_per_voxel']} B of channels ({', '.join(ld['channels']) or 'none'}) + "
            f"{ld['index_bytes_needed']:,} B of index blocks and tables of the intervals")


def format_table(s: dict) -> str:
    """The figures of :func:`collect` as aligned text, one section per input (over 60 lines: a row per figure,
    in the order the table prints them)."""
    rows: list[tuple[str, str]] = []

    def head(t):
        rows.append((t, None))

    def row(k, v):
        rows.append((k, v))

    a = s["augmented"]
    head(f"augmented volume  {a['path']}")
    ni, nj, nk = a["shape_ijk"]
    row("dimensions (i x j x k)", f"{ni} x {nj} x {nk}")
    row("voxels", f"{a['voxels']:,}")
    row("spacing (i, j, k)", ", ".join(f"{x:g}" for x in a["spacing_ijk"]))
    lo, hi = a["density_window"]
    row("density window", f"{lo:g} .. {hi:g} -> 0 .. 255 ({a['density_step']:g} input units per density code)")
    if a.get("source"):
        row("source", f"{a['source']} ({a.get('source_format') or '?'})")
    from .orientation import describe

    row("orientation", describe(a.get("axes_lps")).removeprefix("orientation ") +
        ("" if a.get("axes_lps") is not None else " (no axes_lps: named views unavailable)"))
    for c, nb in a["channel_bytes"].items():
        row(f"channel {c}", _b(nb))
    row("channels total", f"{_b(a['bytes'])}, {a['bytes_per_voxel']} B/voxel")
    row("file size", _b(a["file_bytes"]))
    ix = s.get("index")
    if ix:
        head(f"index  {ix['path']}")
        row("axes", ix["axes"])
        row("density ranges indexed", ", ".join(f"{lo}..{hi}" for lo, hi in ix["density_ranges"]))
        row("voxels indexed (per axis)", f"{ix['voxels_indexed']:,} ({_pct(ix['voxels_indexed'] / a['voxels'])})")
        row("index total", f"{_b(ix['bytes'])}, {ix['bytes_per_voxel']:.3f} B per indexed voxel per axis, "
                           f"{ix['bytes_per_volume_voxel']:.3f} B per volume voxel (without the channel values)")
        for ax, v in ix["per_axis"].items():
            row(f"axis {ax}", f"{_b(v['bytes'])}: {v['entries']:,} blocks, {v['block_bytes_per_voxel']:.3f} B/voxel "
                              f"in blocks, {v['bytes_per_voxel']:.3f} B/voxel with tables, decoded "
                              f"{_b(v['decoded_bytes'])}")
        for rg in ix["per_density_range"]:
            lo, hi = rg["densities"]
            row(f"densities {lo}..{hi}", f"{rg['voxels']:,} voxels ({_pct(rg['fraction'])}), "
                                        f"{_b(rg['bytes'])} over all axes")
        row("decoded, all axes", _b(ix["decoded_bytes"]))
        row("file size", f"{_b(ix['file_bytes'])}, {ix['file_bytes_per_voxel']:.3f} B per indexed voxel per axis "
                         f"(format {ix['format_version']})")
        v = ix["values"]
        if v and v["in"] == "values file":
            row("channel values", f"{v['path']}: {_b(v['file_bytes'])} on disk, {_b(v['bytes'])} of normals and "
                                  f"gradient magnitudes of the {v['voxels']:,} indexed voxels, by density (read by "
                                  f"pre-classification only)")
        elif v:
            row("channel values", f"{_b(v['bytes'])} inside the index (/values, format {ix['format_version']}): "
                                  f"normal and gradient magnitude of the {v['voxels']:,} indexed voxels, by density")
        else:
            row("channel values", "no values file (isplat index --no-values): pre-classification reads them from "
                                  "the augmented file; isplat index AUG.h5 -o IDX.h5 --force writes it")
        r = ix.get("runs")
        if r:
            row("runs file", f"{r['path']}: {_b(r['file_bytes'])} on disk, {r['runs']} runs ({r['bins'][0]} x "
                             f"{r['bins'][1]} bins, {r['runs_with_voxels']} holding voxels), {r['voxels']:,} voxels; "
                             f"tied to this augmented file, every chunk checked (read by post-classified scenes "
                             f"that qualify, formats/runs.md §6)")
        else:
            row("runs file", f"none beside the index (isplat index --no-runs): post-classification reads the "
                             f"augmented file's bricks or channels; isplat index AUG.h5 -o IDX.h5 --force writes it")
    sc = s.get("scene")
    if sc:
        head(f"scene  {sc['path']}  (view {sc['view']}, method {sc['method']}, {sc['projection']}, "
             f"{sc['image'][0]}x{sc['image'][1]})")
        ivs = ", ".join(f"{lo}..{hi}" for lo, hi in sc["intervals"]) or "none (the transfer function selects nothing)"
        row("opacity > 0 at densities", ivs)
        if sc["intervals"]:
            row("  in input units", ", ".join(f"{lo:g}..{hi:g}" for lo, hi in sc["intervals_input_units"]))
        row("voxels of interest", f"{sc['voxels_of_interest']:,} (counted from the {sc['ratio_source']})")
        for lab in sc.get("labels") or []:
            row(f"  label {lab['id']}{' ' + lab['name'] if lab['name'] else ''}", f"{lab['voxels']:,} voxels")
        row("spatial ratio", f"{sc['spatial_ratio']:.4f}")
        if "voxels_visited" in sc:          # an intensity projection (render.mode): the leave-out figure
            row("view axis", f"{sc['axis']} ({sc['classification']}: one pass over the cells by bound)")
            row("voxels visited", f"{sc['voxels_visited']:,} of {sc['voxels_examined']:,} voxels of interest "
                                  "(cells not skipped, summed over image bands)")
            row("samples taken", f"{sc['samples']:,}")
        else:
            row("view axis", f"{sc['axis']} ({sc['slices']} slices composited)")
            row("voxels examined", f"{sc['voxels_examined']:,}")
        if "voxels_visited" in sc:
            pass
        elif sc["classification"] == "pre":
            row("voxels splatted", f"{sc['voxels_splatted']:,} ({_pct(sc['splatted_ratio'])} of all voxels)")
        else:
            row("samples composited", f"{sc['samples']:,} (post-classified: one per pixel and slice "
                                       "where a quad of interest is seen)")
        ld = sc["loaded"]
        row("loaded: channels", ", ".join(ld["channels"]) or "none")
        row("loaded: augmented", f"{_b(ld['augmented_bytes'])} = {_pct(ld['augmented_fraction'])} of the channels")
        if ld["axes"] and sc["method"] == "indexed":
            row("loaded: index", f"{_b(ld['index_bytes'])} = {_pct(ld['index_fraction'])} of the index, axes "
                                 f"{''.join(ld['axes'])}, decoded {_b(ld['index_decoded_bytes'])}")
        row("loaded: total", f"{_b(ld['bytes'])} = {_pct(ld['files_fraction'])} of {_b(ld['files_bytes'])} on disk")
        if ld.get("values_file_bytes_read"):
            row("loaded: values file", f"{_b(ld['values_bytes'])} ({_b(ld['values_file_bytes_read'])} read)")
        if ld.get("runs_file_bytes_read"):
            row("loaded: runs file", f"{ld['runs_path']} ({_b(ld['runs_file_bytes_read'])} read)")
        row("channel values from", _values_words(ld["values_from"]))
        row("bytes read from the files", f"{_b(ld['file_bytes_read'])} (HDF5's reads: whole chunks with checksums, "
                                         f"and metadata)")
        row(f"bytes needed ({ld['technique']})", f"{_b(ld['bytes_needed'])}: {needed_words(ld)}")
        row(f"read / needed ({ld['technique']})", f"{ld['read_ratio']:.3f}")
        if ld.get("file_pages_read", -1) >= 0:
            row("4 KB pages of the files read", f"{_b(ld['file_pages_read'])} (the pages those reads lie in, each "
                                                f"once), {ld['page_ratio']:.3f} x the bytes needed")
        row("held for rendering", f"{_b(ld['held_bytes'])} (selected voxels and their channel values, or "
                                  f"whole channels for the full method and post-classification), "
                                  f"{ld['held_bytes_per_voxel_of_interest']:.2f} B per voxel of interest")
    width = max(len(k) for k, v in rows if v is not None) + 2
    lines = []
    for k, v in rows:
        if v is None:
            if lines:
                lines.append("")
            lines.append(k)
        else:
            lines.append(f"  {k.ljust(width)}{v}")
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------------------------- histogram

HISTOGRAM_PERCENTILES = (1, 5, 25, 50, 75, 95, 99)


def code_edges(window, codes) -> np.ndarray:
    """Data values where the density codes ``codes`` begin (and where the next one begins after the last):
    code ``d`` holds the values that round to it, ``LO + (d - 0.5) * step`` up to ``LO + (d + 0.5) * step``
    (code 0 and 255 also hold the values clipped below LO and above HI)."""
    lo, hi = window
    return lo + (np.asarray(codes, dtype=np.float64) - 0.5) * ((hi - lo) / 255.0)


def histogram_section(aug, bins: int = 32) -> dict:
    """The density histogram in data units: ``bins`` bins of ``256 / bins`` codes each, every code's count,
    and percentiles (the data value ``LO + d * step`` of the first code ``d`` whose cumulative share reaches
    them: numpy's ``inverted_cdf`` percentile of the codes' values)."""
    if bins not in (1, 2, 4, 8, 16, 32, 64, 128, 256):
        raise IsplatError(f"--bins {bins} invalid; expected a power of two from 1 to 256 (each bin holds "
                          f"256/N density codes)")
    codes = density_histogram(aug)
    per = 256 // bins
    counts = codes.reshape(bins, per).sum(axis=1)
    n = int(codes.sum())
    cum = np.cumsum(codes) / max(1, n)
    lo, hi = aug.density_window
    pct = {f"p{q:g}": float(lo + int(np.searchsorted(cum, q / 100.0)) * (hi - lo) / 255.0)
           for q in HISTOGRAM_PERCENTILES}
    clipped = aug.attrs.get("density_clipped_fraction")
    from .presets import tissue_range

    start, top = tissue_range(codes)
    return {"tissue_range": [float(lo + start * (hi - lo) / 255.0), float(lo + top * (hi - lo) / 255.0)],
            "units": "HU" if aug.attrs.get("density_units") == "HU" else "input units",
            "density_window": list(aug.density_window), "bins": bins, "codes_per_bin": per,
            "edges": code_edges(aug.density_window, np.arange(0, 257, per)).tolist(),
            "counts": counts.tolist(), "code_counts": codes.tolist(), "voxels": n, "percentiles": pct,
            "clipped_fraction": None if clipped is None else [float(x) for x in np.asarray(clipped)]}


def format_histogram(h: dict) -> str:
    """The histogram as text: one line per bin, its data-unit range, voxels, share and a bar."""
    lo, hi = h["density_window"]
    unit = h["units"]
    clip = h["clipped_fraction"]
    lines = [f"density histogram ({unit}; window {lo:g} .. {hi:g}, {h['bins']} bins of {h['codes_per_bin']} "
             f"density codes; the first and last bins also hold the voxels outside the window"
             + (f": {_pct(clip[0])} below, {_pct(clip[1])} above" if clip else "") + ")"]
    top = max(1, max(h["counts"]))
    n = max(1, h["voxels"])
    width = max(len(f"{x:.6g}") for x in h["edges"])
    for a, b, c in zip(h["edges"], h["edges"][1:], h["counts"]):
        bar = "#" * int(round(40 * c / top))
        lines.append(f"  {a:>{width}.6g} .. {b:>{width}.6g}  {c:>12,}  {100 * c / n:6.2f}%  {bar}")
    lines.append("  percentiles: " + ", ".join(f"{k} {v:.6g}" for k, v in h["percentiles"].items()))
    if h["units"] != "HU" and "tissue_range" in h:
        a, b = h["tissue_range"]
        lines.append(f"  tissue range (where an MRI preset is placed: Otsu's background threshold .. the 99th "
                     f"percentile above it): {a:.6g} .. {b:.6g}")
    return "\n".join(lines) + "\n"


def preset_ramps(h: dict) -> dict:
    """Opacity ramps of the presets that apply to the data, in data units: the CT presets (Hounsfield units)
    for Hounsfield data, else the window presets (fractions of the window) and the MRI presets placed on this
    histogram as a scene would place them (isplat.presets.place). {name: (values, opacities)}."""
    from .presets import PRESETS, place

    lo, hi = h["density_window"]
    want = ("data",) if h["units"] == "HU" else ("window", "tissue")
    step = (hi - lo) / 255.0
    out = {}
    for p in PRESETS.values():
        if p.units not in want:
            continue
        xs = np.array([r[0] for r in p.opacity], dtype=np.float64)
        if p.units == "window":
            xs = lo + xs * (hi - lo)
        elif p.units == "tissue":
            xs = lo + np.array([r[0] for r in place(p.opacity, h["code_counts"])]) * step
        out[p.name] = (xs.tolist(), [r[1] for r in p.opacity])
    return out


def plot_histogram(h: dict, path, force: bool = False, title: str = "") -> None:
    """Write the histogram (log counts, data units) with the presets' opacity ramps over it as an image."""
    from .fileio import atomic_output, check_output

    try:
        import matplotlib
    except ImportError:
        raise IsplatError(f"{path}: --plot needs matplotlib: pip install 'isplat[plot]'") from None
    check_output(path, force)
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 4.5), dpi=100)
    suffix = Path(str(path)).suffix.lstrip(".").lower()
    if suffix not in fig.canvas.get_supported_filetypes():
        plt.close(fig)
        raise IsplatError(f"{path}: --plot writes {', '.join(sorted(fig.canvas.get_supported_filetypes()))} "
                          f"(by the extension), not {suffix or 'a file without an extension'}")
    codes = np.asarray(h["code_counts"], dtype=np.float64)
    ax.stairs(np.maximum(codes, 0.5), code_edges(h["density_window"], np.arange(257)), fill=True,
              color="0.6", label="voxels per density code", baseline=0.5)
    ax.set_yscale("log")
    ax.set_xlabel(f"value ({h['units']})")
    ax.set_ylabel("voxels")
    ax.set_title(title, fontsize=9)
    op = ax.twinx()
    for name, (xs, ys) in preset_ramps(h).items():
        op.plot(xs, ys, lw=1.2, label=name)
    op.set_ylim(0, 1.05)
    op.set_ylabel("preset opacity")
    ax.set_xlim(*code_edges(h["density_window"], [0, 256]))
    hands = [*ax.get_legend_handles_labels()[0], *op.get_legend_handles_labels()[0]]
    op.legend(hands, [x.get_label() for x in hands], fontsize=7, loc="upper right")
    fig.tight_layout()
    with atomic_output(path, force) as tmp:
        with open(tmp, "wb") as fh:
            fig.savefig(fh, format=suffix)
    plt.close(fig)
