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


def restrict_axis(ax: AxisSelection, slices) -> AxisSelection:
    """``ax`` with only the voxels (and cells) of ``slices``; other slices keep their index and hold nothing."""
    runs = slice_runs(slices, ax.n_slices)
    counts = np.zeros(ax.n_slices, dtype=np.int64)
    cells, voxels, starts = [], [], []
    offset = 0
    for s0, s1 in runs:
        c0, c1 = int(ax.cell_ptr[s0]), int(ax.cell_ptr[s1])
        v0, v1 = int(ax.cell_start[c0]), int(ax.cell_start[c1])
        counts[s0:s1] = np.diff(ax.cell_ptr[s0:s1 + 1])
        cells.append((c0, c1))
        voxels.append((v0, v1))
        starts.append(ax.cell_start[c0:c1] - v0 + offset)
        offset += v1 - v0
    cell_ptr = np.zeros(ax.n_slices + 1, dtype=ax.cell_ptr.dtype)
    np.cumsum(counts, out=cell_ptr[1:])
    cell_start = np.concatenate(starts + [np.asarray([offset], dtype=ax.cell_start.dtype)]).astype(
        ax.cell_start.dtype, copy=False)

    def take(arr, ranges):
        if arr.shape[0] == 0:            # a channel the scene does not use
            return arr
        return np.concatenate([arr[a:b] for a, b in ranges] or [arr[:0]])

    return AxisSelection(ax.axis, ax.n_slices, ax.n_a, ax.n_b, cell_ptr, cell_start, take(ax.cell_id, cells),
                         *(take(x, voxels) for x in (ax.a, ax.b, ax.density, ax.gradient_magnitude, ax.normal)))


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
