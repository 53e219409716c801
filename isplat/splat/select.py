"""Select a transfer function's voxels from the decoded index, once per load (paper §2.2).

Arrays in, arrays out: the input is a :class:`isplat.index.LoadedAxis`'s arrays, the output the selection's
arrays in the order every frame streams them (slice by slice, cell by cell).
"""

from __future__ import annotations

import numpy as np

from ..jit import jit

CELL = 4         # voxels per side of the cells a slice's voxels are grouped in for early termination


@jit
def flat_indices(slice_block_ptr, block_voxel_ptr, positions, n_a, strides):
    """Flat [k, j, i] index of every voxel of a loaded axis (in the order of ``positions``)."""
    out = np.empty(positions.shape[0], dtype=np.int64)
    for c in range(slice_block_ptr.shape[0] - 1):
        base = c * strides[2]
        for r in range(slice_block_ptr[c], slice_block_ptr[c + 1]):
            for vi in range(block_voxel_ptr[r], block_voxel_ptr[r + 1]):
                ind = positions[vi]
                b = ind // n_a
                out[vi] = base + (ind - b * n_a) * strides[0] + b * strides[1]
    return out


@jit
def _first_block(block_density, r0, r1, lo):
    """§2.2: binary search for the first block in rows r0:r1 with density >= lo."""
    while r0 < r1:
        m = (r0 + r1) >> 1
        if block_density[m] < lo:
            r0 = m + 1
        else:
            r1 = m
    return r0


@jit
def _count_selected(slice_block_ptr, block_density, block_voxel_ptr, intervals, n_pos):
    """Voxels of all slices whose density lies in ``intervals``; raises on a slice listing more voxels than
    it has positions (a corrupt index, which would overrun the per-slice buffers)."""
    total = 0
    for c in range(slice_block_ptr.shape[0] - 1):
        in_slice = 0
        for iv in range(intervals.shape[0]):
            r = _first_block(block_density, slice_block_ptr[c], slice_block_ptr[c + 1], intervals[iv, 0])
            while r < slice_block_ptr[c + 1] and block_density[r] <= intervals[iv, 1]:
                in_slice += block_voxel_ptr[r + 1] - block_voxel_ptr[r]
                r += 1
        if in_slice > n_pos:
            raise ValueError("a slice of the index lists more voxels than it has positions")
        total += in_slice
    return total


@jit
def _decode_slice(c, slice_block_ptr, block_density, block_voxel_ptr, positions, intervals, n_a, ta, tb, td, tsrc):
    """The voxels of slice ``c`` in ``intervals`` into ``ta, tb, td, tsrc`` (a, b, density, index in
    ``positions``), block by block; returns how many."""
    r1 = slice_block_ptr[c + 1]
    m = 0
    for iv in range(intervals.shape[0]):
        r = _first_block(block_density, slice_block_ptr[c], r1, intervals[iv, 0])
        while r < r1 and block_density[r] <= intervals[iv, 1]:
            v0 = block_voxel_ptr[r]
            v1 = block_voxel_ptr[r + 1]
            # positions increase within a block: follow the row instead of dividing per voxel
            b = positions[v0] // n_a if v1 > v0 else 0
            row0 = b * n_a
            for vi in range(v0, v1):
                ind = positions[vi]
                while ind >= row0 + n_a:
                    row0 += n_a
                    b += 1
                ta[m] = ind - row0
                tb[m] = b
                td[m] = block_density[r]
                tsrc[m] = vi
                m += 1
            r += 1
    return m


@jit
def _group_by_cell(m, nca, ta, tb, td, tsrc, count, n, nq, sel, cell_start, cell_id):
    """Append one slice's ``m`` voxels to ``sel = (a, b, density, source)`` from row ``n``, grouped by cell
    (a stable counting sort, so each cell keeps the blocks' density order); new cells from ``nq``.
    Returns the new ``nq``."""
    sa, sb, sd, src = sel
    count[:] = 0
    for t in range(m):
        count[(tb[t] // CELL) * nca + ta[t] // CELL + 1] += 1
    for q in range(count.shape[0] - 1):
        if count[q + 1] > 0:
            cell_start[nq] = n + count[q]
            cell_id[nq] = q
            nq += 1
        count[q + 1] += count[q]
    for t in range(m):
        q = (tb[t] // CELL) * nca + ta[t] // CELL
        k = n + count[q]
        count[q] += 1
        sa[k] = ta[t]
        sb[k] = tb[t]
        sd[k] = td[t]
        src[k] = tsrc[t]
    return nq


@jit
def select_voxels(slice_block_ptr, block_density, block_voxel_ptr, positions, intervals, n_a, n_b):
    """The voxels of each slice whose density lies in ``intervals`` (§2.2), as in-slice coordinates,
    grouped in cells of CELL x CELL voxels of the slice.

    Per slice, the densities present are sorted (Figure 1), so a binary search finds the first block of each
    interval and the blocks up to its upper bound are decoded into (a, b). This runs once per load (the
    selection depends on the transfer function, not on the view); every frame then streams the result, and
    the cells let early termination skip a hidden cell with one test.
    Returns ``(cell_ptr int64[S+1], cell_start int64[Q+1], cell_id int32[Q], a uint16[N], b uint16[N],
    density uint8[N], source int64[N])``: slice ``c`` holds cells ``cell_ptr[c]:cell_ptr[c+1]``, cell ``q``
    (``cell_id = (b // CELL) * ceil(n_a / CELL) + a // CELL``) the voxels ``cell_start[q]:cell_start[q+1]``;
    ``source`` is each voxel's index in ``positions``.
    """
    n_slices = slice_block_ptr.shape[0] - 1
    nca = (n_a + CELL - 1) // CELL
    ncells = nca * ((n_b + CELL - 1) // CELL)
    total = _count_selected(slice_block_ptr, block_density, block_voxel_ptr, intervals, n_a * n_b)
    sel = (np.empty(total, dtype=np.uint16), np.empty(total, dtype=np.uint16), np.empty(total, dtype=np.uint8),
           np.empty(total, dtype=np.int64))
    # one slice's voxels before they are grouped by cell
    ta = np.empty(n_a * n_b, dtype=np.uint16)
    tb = np.empty(n_a * n_b, dtype=np.uint16)
    td = np.empty(n_a * n_b, dtype=np.uint8)
    tsrc = np.empty(n_a * n_b, dtype=np.int64)
    count = np.zeros(ncells + 1, dtype=np.int64)
    cell_ptr = np.zeros(n_slices + 1, dtype=np.int64)
    cell_start = np.empty(min(total, n_slices * ncells) + 1, dtype=np.int64)
    cell_id = np.empty(min(total, n_slices * ncells), dtype=np.int32)
    n = 0
    nq = 0
    for c in range(n_slices):
        m = _decode_slice(c, slice_block_ptr, block_density, block_voxel_ptr, positions, intervals, n_a,
                          ta, tb, td, tsrc)
        nq = _group_by_cell(m, nca, ta, tb, td, tsrc, count, n, nq, sel, cell_start, cell_id)
        n += m
        cell_ptr[c + 1] = nq
    cell_start[nq] = n
    return cell_ptr, cell_start[:nq + 1].copy(), cell_id[:nq].copy(), sel[0], sel[1], sel[2], sel[3]
