"""The decoded index of a volume in memory, without bytes or files (for arrays already in memory).

The result is what :meth:`isplat.index.IndexFile.load_axis` returns for a file: per slice, the densities
present in increasing order (Figure 1), each a block of increasing in-slice positions. It is built here
directly by sorting, not by encoding and decoding §2.3's bytes, so the tests can check the file path
(encode, write, read, decode) against it.
"""

from __future__ import annotations

import numpy as np

from .. import grid
from .store import LoadedAxis


def load_axis_in_memory(density: np.ndarray, axis: str, intervals) -> LoadedAxis:
    """The blocks of ``axis`` of ``density[k, j, i]`` (uint8) whose densities lie in inclusive ``intervals``."""
    n_slices, n_a, n_b = grid.slice_shape(density.shape, axis)
    ia, ib, ic = grid.SLICE_AXES[axis]
    # array dimension of grid axis x (i, j, k = 0, 1, 2) is 2 - x: view the volume as [c, b, a]
    per_slice = np.ascontiguousarray(density.transpose(2 - ic, 2 - ib, 2 - ia)).reshape(n_slices, n_a * n_b)
    wanted = np.zeros(256, dtype=bool)
    for lo, hi in np.asarray(intervals, dtype=np.int64).reshape(-1, 2):
        wanted[lo:hi + 1] = True
    sl, pos = np.nonzero(wanted[per_slice])                # by slice, then position
    dens = per_slice[sl, pos]
    order = np.argsort(sl.astype(np.int64) * 256 + dens, kind="stable")   # by slice, density, position
    sl, pos, dens = sl[order], pos[order], dens[order]
    starts = np.flatnonzero(np.r_[True, (sl[1:] != sl[:-1]) | (dens[1:] != dens[:-1])]) if sl.size else \
        np.zeros(0, dtype=np.int64)
    block_voxel_ptr = np.r_[starts, sl.size].astype(np.int64)
    slice_block_ptr = np.zeros(n_slices + 1, dtype=np.int64)
    np.cumsum(np.bincount(sl[starts], minlength=n_slices), out=slice_block_ptr[1:])
    ivs = [(int(lo), int(hi)) for lo, hi in np.asarray(intervals).reshape(-1, 2)]
    return LoadedAxis(axis, n_slices, n_a, n_b, slice_block_ptr, dens[starts].astype(np.uint8), block_voxel_ptr,
                      pos.astype(np.int32), 0, ivs)
