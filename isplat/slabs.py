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

import dataclasses

import numpy as np

from .errors import IsplatError
from .selection import AxisSelection, Selection


def slice_runs(slices, n_slices: int) -> list[tuple[int, int]]:
    """The distinct slice indices of ``slices`` as sorted runs ``[s0, s1)`` of consecutive indices."""
    s = np.unique(np.asarray(slices, dtype=np.int64))
    if s.size and (s[0] < 0 or s[-1] >= n_slices):
        raise IsplatError(f"slab slices {int(s[0])}..{int(s[-1])} outside 0..{n_slices - 1}")
    if s.size == 0:
        return []
    breaks = np.flatnonzero(np.diff(s) != 1) + 1
    starts = np.r_[s[0], s[breaks]]
    stops = np.r_[s[breaks - 1] + 1, s[-1] + 1]
    return [(int(a), int(b)) for a, b in zip(starts, stops)]


def _take_runs(outer_ptr, inner_ptr, runs, n):
    """Of a two-level CSR layout (``outer_ptr[s]:outer_ptr[s+1]`` rows of slice s, ``inner_ptr[r]:inner_ptr[r+1]``
    leaves of row r), keep the slices in ``runs``: (new outer_ptr, row ranges, new inner_ptr, leaf ranges)."""
    counts = np.zeros(n, dtype=np.int64)
    rows, leaves, ptrs = [], [], []
    offset = 0
    for s0, s1 in runs:
        r0, r1 = int(outer_ptr[s0]), int(outer_ptr[s1])
        v0, v1 = int(inner_ptr[r0]), int(inner_ptr[r1])
        counts[s0:s1] = np.diff(outer_ptr[s0:s1 + 1])
        rows.append((r0, r1))
        leaves.append((v0, v1))
        ptrs.append(inner_ptr[r0:r1] - v0 + offset)
        offset += v1 - v0
    new_outer = np.zeros(n + 1, dtype=outer_ptr.dtype)
    np.cumsum(counts, out=new_outer[1:])
    new_inner = np.concatenate(ptrs + [np.asarray([offset], dtype=inner_ptr.dtype)]).astype(inner_ptr.dtype,
                                                                                           copy=False)
    return new_outer, rows, new_inner, leaves


def _take(arr, ranges):
    if arr.shape[0] == 0:            # a channel the scene does not use
        return arr
    return np.concatenate([arr[a:b] for a, b in ranges] or [arr[:0]])


def restrict_axis(ax: AxisSelection, slices) -> AxisSelection:
    """``ax`` with only the voxels (and cells) of ``slices``; other slices keep their index and hold nothing."""
    cell_ptr, cells, cell_start, voxels = _take_runs(ax.cell_ptr, ax.cell_start, slice_runs(slices, ax.n_slices),
                                                     ax.n_slices)
    return AxisSelection(ax.axis, ax.n_slices, ax.n_a, ax.n_b, cell_ptr, cell_start, _take(ax.cell_id, cells),
                         *(_take(x, voxels) for x in (ax.a, ax.b, ax.density, ax.gradient_magnitude, ax.normal)))


def restrict_loaded(la, slices):
    """A decoded index axis (:class:`isplat.index.store.LoadedAxis`) with only the blocks of ``slices``: what
    :func:`isplat.selection.select_from_files` selects from and gathers channel values for, when a worker
    makes just its slab's selection."""
    ptr, rows, vptr, voxels = _take_runs(la.slice_block_ptr, la.block_voxel_ptr, slice_runs(slices, la.n_slices),
                                         la.n_slices)
    return dataclasses.replace(la, slice_block_ptr=ptr, block_density=_take(la.block_density, rows),
                               block_voxel_ptr=vptr, positions=_take(la.positions, voxels))


def restrict(sel: Selection, axis: str, slices) -> Selection:
    """The part of ``sel`` that renders ``slices`` of ``axis``: for the indexed method only that axis, with
    only those slices' voxels; the full method's whole channels are shared as they are (it indexes them by
    position, so a slab of it holds the whole volume)."""
    if sel.method == "full" or sel.empty:
        return sel
    if axis not in sel.axes:
        raise IsplatError(f"axis {axis} was not selected (selected: {sorted(sel.axes) or 'none'})")
    return dataclasses.replace(sel, axes={axis: restrict_axis(sel.axes[axis], slices)},
                               report=dataclasses.replace(sel.report))


def render_streamed(scene, view, n_slabs: int, aug=None, et: float | None = None):
    """Render ``view`` of ``scene`` from its files in ``n_slabs`` slabs front to back, each slab's selection made
    (:func:`isplat.selection.select_from_files` with ``slices=``), rendered over the partial image of the slabs in
    front and dropped: the one-pass frame exactly (same image and counters, early termination included), holding
    one slab's selection at a time. Returns (straight RGBA (H, W, 4), FrameStats, LoadReport of all the slabs:
    bytes read added up).

    What is still whole: the full method's channels (read once, kept for every slab); the index blocks of the transfer function's densities along the frame's axis are
    decoded for each slab before its slices are kept, and for the i and j axes each slab's channel values are
    gathered from every k-plane (docs/scale.md).
    """
    import time

    from .augfile import open_augmented
    from .frame import blank, finish_image, frame_stats, prepare, render_slab, slab_bounds
    from .selection import select_from_files

    t0 = time.perf_counter()
    aug = aug or open_augmented(scene.data.augmented)
    axis = view.axis_sign[0]
    part = report = whole = None
    for a, b in slab_bounds(len(view.order), n_slabs):
        start = aug.bytes_read
        if whole is not None:          # the full method reads whole channels: once, for every slab
            sel = whole
        else:
            sel = select_from_files(scene, axis, aug=aug, slices=view.order[a:b])
            whole = sel if sel.method == "full" else None
        if report is None:
            report = dataclasses.replace(sel.report, augmented_bytes=0, index_bytes=0)
        report.augmented_bytes += int(aug.bytes_read - start)
        report.index_bytes += sel.report.index_bytes
        setup = prepare(sel, view, et)
        part = blank(setup) if part is None else part
        render_slab(setup, a, b, part)
        del sel, setup
    return finish_image(part.img, view.background), frame_stats(view, part, time.perf_counter() - t0), report
