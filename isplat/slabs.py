"""A selection restricted to a slab of slices: what one worker of a frame split into slabs holds.

A frame's slab is ``view.order[start:stop]``, a run of the principal axis' slices in visibility order
(:func:`isplat.frame.slab_bounds`). :func:`restrict` keeps, of a :class:`~isplat.selection.Selection`, only the
selected voxels of those slices (with their gathered channel values), in the same traversal order and with the
same slice numbering, so ``render_slab`` on the restricted selection draws exactly what it draws on the whole
one for those slices: bit for bit the same partial image.

>>> import numpy as np
>>> from isplat.scene import parse_scene
>>> from isplat.selection import Selection
>>> vol = np.zeros((8, 8, 8), np.uint8); vol[2:6, 2:6, 2:6] = 200
>>> scene = parse_scene("[transfer]\\nopacity = [[100, 0], [200, 0.8]]\\n[shading]\\nenabled = false",
...                     ".", "example", data_required=False)
>>> sel = Selection.from_arrays(vol, scene, axes="k")
>>> part = restrict(sel, "k", [0, 1, 2, 3])          # slices 2 and 3 hold 16 voxels each
>>> part.axes["k"].n_voxels, part.held_bytes() < sel.held_bytes()
(32, True)
"""

from __future__ import annotations

import contextlib
import dataclasses

import numpy as np

from .errors import IsplatError
from .index.build import slice_runs
from .selection import AxisSelection, Selection

__all__ = ["restrict", "restrict_axis", "restrict_loaded", "render_streamed", "slice_runs"]


def _ranges(ptr, ranges):
    """The rows that ``ptr`` points to from each range of ``ranges``."""
    return [(int(ptr[a]), int(ptr[b])) for a, b in ranges]


def _rebase(ptr, ranges):
    """``ptr`` (a CSR pointer) for the rows in ``ranges`` only, counted from 0: its entries ``a:b`` of each
    range shifted to follow the rows kept before, and the total at the end."""
    parts, off = [], 0
    for a, b in ranges:
        parts.append(ptr[a:b] - ptr[a] + off)
        off += int(ptr[b] - ptr[a])
    return np.concatenate(parts + [np.asarray([off], dtype=ptr.dtype)]).astype(ptr.dtype, copy=False)


def _slice_ptr(ptr, runs, n):
    """The per-slice pointer keeping the rows of the slices in ``runs`` (other slices hold none)."""
    counts = np.zeros(n, dtype=np.int64)
    for s0, s1 in runs:
        counts[s0:s1] = np.diff(ptr[s0:s1 + 1])
    out = np.zeros(n + 1, dtype=ptr.dtype)
    np.cumsum(counts, out=out[1:])
    return out


def _take(arr, ranges):
    if arr.shape[0] == 0:            # a channel the scene does not use
        return arr
    return np.concatenate([arr[a:b] for a, b in ranges] or [arr[:0]])


def restrict_axis(ax: AxisSelection, slices) -> AxisSelection:
    """``ax`` with only the voxels (regions, blocks, cells) of ``slices``; other slices keep their index and
    hold nothing."""
    runs = slice_runs(slices, ax.n_slices)
    g = _ranges(ax.slice_ptr, runs)                  # regions
    r = _ranges(ax.region_ptr, g)                    # blocks
    q = _ranges(ax.block_ptr, r)                     # cells
    v = _ranges(ax.block_voxel, r)                   # voxels
    return dataclasses.replace(
        ax, slice_ptr=_slice_ptr(ax.slice_ptr, runs, ax.n_slices), region_id=_take(ax.region_id, g),
        region_ptr=_rebase(ax.region_ptr, g), block_pos=_take(ax.block_pos, r), block_ptr=_rebase(ax.block_ptr, r),
        block_voxel=_rebase(ax.block_voxel, r), cell_pos=_take(ax.cell_pos, q), cell_count=_take(ax.cell_count, q),
        **{name: _take(getattr(ax, name), v) for name in ("offset", "density", "gradient_magnitude", "normal")})


def restrict_loaded(la, slices):
    """A decoded index axis (:class:`isplat.index.store.LoadedAxis`) with only the blocks of ``slices``, cut
    from the whole axis in memory: what ``IndexFile.load_axis(..., slices=)`` reads directly from the file (the
    tests check one against the other)."""
    runs = slice_runs(slices, la.n_slices)
    rows = _ranges(la.slice_block_ptr, runs)
    return dataclasses.replace(la, slice_block_ptr=_slice_ptr(la.slice_block_ptr, runs, la.n_slices),
                               block_density=_take(la.block_density, rows),
                               block_voxel_ptr=_rebase(la.block_voxel_ptr, rows),
                               positions=_take(la.positions, _ranges(la.block_voxel_ptr, rows)))


def restrict(sel: Selection, axis: str, slices) -> Selection:
    """The part of ``sel`` that renders ``slices`` of ``axis``: for the indexed method only that axis, with
    only those slices' voxels; the full method's whole channels are shared as they are (it indexes them by
    position, so a slab of it holds the whole volume)."""
    if sel.method == "full" or sel.empty:
        return sel
    if axis not in sel.axes:
        raise IsplatError(f"axis {axis} was not selected (selected: {sorted(sel.axes) or 'none'})")
    req = None if sel.request is None else \
        dataclasses.replace(sel.request, axes=axis, slab=tuple(slice_runs(slices, sel.axes[axis].n_slices)))
    return dataclasses.replace(sel, axes={axis: restrict_axis(sel.axes[axis], slices)},
                               report=dataclasses.replace(sel.report), request=req)


PEAK_PER_VOXEL = 56     # bytes per voxel of interest while a selection is made (docs/scale.md, "Larger than memory")
ROOM_SHARE = 0.5        # a slab's selection may take this share of the memory left


def memory_room() -> int | None:
    """Bytes this process can still allocate: the machine's available memory and, under an address-space limit
    (``ulimit -v``, ``prlimit --as``), the address space left below it; None when neither is known."""
    import resource

    from .output import memory_available

    room = memory_available()
    soft = resource.getrlimit(resource.RLIMIT_AS)[0]
    if soft != resource.RLIM_INFINITY:
        try:
            with open("/proc/self/status") as fh:
                used = next(int(ln.split()[1]) * 1024 for ln in fh if ln.startswith("VmSize:"))
        except (OSError, StopIteration, ValueError, IndexError):
            used = 0
        left = max(0, int(soft) - used)
        room = left if room is None else min(room, left)
    return room


def slabs_needed(scene, views, aug, room: int | None = None, request=None) -> tuple[int, int]:
    """``(K, voxels)``: the slabs each of ``views`` (isplat.frame.View) needs so that one slab's selection takes
    at most ROOM_SHARE of ``room`` (default :func:`memory_room`), from the voxels of interest of the views'
    principal axes (the index's per-density counts, read from its tables) and, post-classified, the channels of
    the volume, which slabs cut too (K = 1 when it fits, and for the full method, whose whole channels a slab
    does not cut). With ``request`` (the frames' :class:`~isplat.request.RenderRequest`), a post frame that reads
    the runs file in one pass counts what it holds (:func:`isplat.selection.post_runs_bytes`) instead of whole
    channels: K = 1 when that fits."""
    from .frame import axes_of
    from .index import open_index
    from .selection import post_runs_bytes
    from .transfer import build_luts

    room = memory_room() if room is None else room
    if scene.render.method != "indexed" or room is None or scene.data.index is None:
        return 1, 0
    whole = int(np.prod(aug.shape)) * _channel_bytes(scene)     # (post's pool counted as whole channels: see
    ivs = build_luts(scene.transfer, aug.gradient_magnitude_scale).intervals   # docs/design.md, a slab's bricks)
    idx = open_index(scene.data.index)
    share = max(1, int(room * ROOM_SHARE))
    k, most, counted = 1, 0, []
    for axis in axes_of(views):
        if axis not in idx.axes:
            continue                                # the render names the missing axis
        counts = idx.voxel_counts(axis)
        n = int(sum(int(counts[lo:hi + 1].sum()) for lo, hi in ivs))
        most = max(most, n)
        counted.append(n)
        need = -(-(n * PEAK_PER_VOXEL + whole) // share)
        k = max(k, min(int(need), idx.n_slices(axis)))
    if k > 1 and whole and request is not None:    # (the runs file opened only when whole channels do not fit)
        runs = post_runs_bytes(request, aug, most)
        if runs is not None and sum(counted) * PEAK_PER_VOXEL + runs <= share:
            return 1, most                          # one pass from the runs file fits (every axis selected)
    return k, most


def _channel_bytes(scene) -> int:
    """Bytes per voxel of the volume a post-classified slab holds besides its selection: its slices' channels,
    density, and normals (2 B) when shaded, gradient magnitudes when used (by the transfer function, or by the
    shading, which weights the corners' Phong factors by them: isplat.selection._empty_selection); 0
    pre-classified."""
    if scene.render.classification != "post":
        return 0
    shaded = bool(scene.shading.enabled)
    return 1 + (2 if shaded else 0) + (1 if scene.transfer.gradient_opacity or shaded else 0)


def fits_anyway(scene, aug, room: int) -> bool:
    """True when one selection would fit even if every voxel of the volume were of interest: what
    :func:`slabs_needed` would find (one slab) without opening the index to count the voxels of interest."""
    n = int(np.prod(aug.shape))
    return n * (PEAK_PER_VOXEL + _channel_bytes(scene)) <= max(1, int(room * ROOM_SHARE))


def render_streamed(request, view, n_slabs: int, aug=None, et: float | None = None):
    """Render ``view`` from the files of ``request`` (:class:`~isplat.request.RenderRequest`) in ``n_slabs``
    slabs front to back, each slab's selection made (:func:`isplat.selection.select` of the request for the
    slab's slices), rendered over the partial image of the slabs in front and dropped: the one-pass frame
    exactly (same image and counters, early termination included), holding one slab's selection at a time.
    Returns (straight RGBA (H, W, 4), FrameStats, LoadReport of all the slabs: bytes read, requested and needed
    added up, :meth:`isplat.selection.LoadReport.plus`).

    Each slab reads and decodes only its slices' index blocks; the index's tables (each interval's rows) are read
    once for all the slabs (:meth:`isplat.index.store.IndexFile.shared_tables`). What is still whole: the full
    method's channels (read once, kept for every slab); for the i and j axes each slab's channel values are
    gathered from every k-plane (along j only the slab's rows of each plane), so the channels are read once per
    slab (docs/scale.md).
    """
    import time

    from .augfile import open_augmented
    from .frame import finish_image, frame_stats
    from .threads import default_threads

    t0 = time.perf_counter()
    aug = aug or open_augmented(request.augmented)
    idx = None                         # the index, opened once for every slab
    if request.method == "indexed" and request.index is not None:
        from .index import open_index

        idx = open_index(request.index)
    with idx.shared_tables() if idx is not None else contextlib.nullcontext():   # tables read once, shared
        opened = idx.io.bytes if idx is not None else 0        # (each slab counts its own reads of the index)
        part, report = _slabs(request, view, n_slabs, aug, idx, opened, et)
    threads = view.render.threads or default_threads()
    return (finish_image(part.img, view.background, view.render.supersample, threads),
            frame_stats(view, part, time.perf_counter() - t0), report)


def _slabs(request, view, n_slabs, aug, idx, opened, et):
    """The loop of :func:`render_streamed`: each slab selected, rendered over the slabs in front, dropped."""
    from .frame import blank, prepare, render_slab, slab_bounds
    from .index.build import slice_runs
    from .selection import select

    axis = view.axis_sign[0]
    part = report = whole = None
    for a, b in slab_bounds(len(view.order), n_slabs):
        if whole is not None:          # the full method reads whole channels: once, for every slab
            sel = whole
        else:
            runs = tuple(slice_runs(view.order[a:b], 1 << 62))
            start = (aug.bytes_read, aug.io.bytes)      # ``aug`` counts from its opening: this slab's share
            sel = select(dataclasses.replace(request, axes=axis, slab=runs), aug, idx)
            sel.report.augmented_bytes = int(aug.bytes_read - start[0])
            sel.report.augmented_file_bytes = int(aug.io.bytes - start[1])
            if report is None:         # (the files' openings, counted once, with the first slab)
                sel.report.augmented_bytes += int(start[0])
                sel.report.augmented_file_bytes += int(start[1])
                sel.report.index_file_bytes += int(opened)
            report = sel.report if report is None else report.plus(sel.report)   # each slab's footprint counted
            whole = sel if sel.method == "full" else None                          # now, its density dropped
        setup = prepare(sel, view, et)
        part = blank(setup) if part is None else part
        render_slab(setup, a, b, part)
        del sel, setup
    if report is not None:             # each file's pages over the frame (a page two slabs read counted once)
        report.augmented_file_pages = aug.io.page_bytes()
        report.index_file_pages = idx.io.page_bytes() if idx is not None else 0
        vio = idx.values_io() if idx is not None else None
        report.values_file_pages = vio.page_bytes() if vio is not None else 0
    return part, report
