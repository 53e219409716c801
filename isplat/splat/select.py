"""Select a transfer function's voxels from the decoded index, once per load (paper §2.2).

Arrays in, arrays out: the input is a :class:`isplat.index.LoadedAxis`'s arrays, the output the selection's
arrays in the order every frame streams them: slice by slice, and within a slice as a hierarchy of squares of
the slice, regions of REGION x REGION voxels, blocks of BLOCK x BLOCK, cells of CELL x CELL, each level 4 x 4 of
the next, so that a frame can skip a hidden region, block or cell with one test (:mod:`isplat.splat.traverse`).

The hierarchy is stored compactly (a few bits per position, the selection must stay small in memory):

- slice ``c`` holds regions ``slice_ptr[c]:slice_ptr[c+1]``; region ``g`` is square ``region_id[g]`` of its
  slice (``(b // REGION) * ceil(n_a / REGION) + a // REGION``) and holds blocks ``region_ptr[g]:region_ptr[g+1]``;
- block ``r`` is square ``block_pos[r]`` (0..15, row-major) of its region, holds cells
  ``block_ptr[r]:block_ptr[r+1]`` and its first voxel is ``block_voxel[r]``;
- cell ``q`` is square ``cell_pos[q]`` of its block and holds ``cell_count[q]`` voxels (1..16), which follow
  one another; a voxel's ``offset`` is its square in the cell (``(b % CELL) * CELL + a % CELL``).
"""

from __future__ import annotations

import numpy as np

from ..jit import jit, stage

CELL = 4         # voxels per side of a cell: the smallest group of a slice's voxels tested for occlusion
BLOCK = 16       # voxels per side of a block (4 x 4 cells)
REGION = 64      # voxels per side of a region (4 x 4 blocks)
KEYS = 256       # cells per region: a voxel's key in its slice is region * KEYS + block * 16 + cell


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


@stage
def _first_block(block_density, r0, r1, lo):
    """§2.2: binary search for the first block in rows r0:r1 with density >= lo."""
    while r0 < r1:
        m = (r0 + r1) >> 1
        if block_density[m] < lo:
            r0 = m + 1
        else:
            r1 = m
    return r0


@stage
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


@stage
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


@stage
def _voxel_key(a, b, nra):
    """The voxel's place in the hierarchy: region * KEYS + block position * 16 + cell position."""
    region = (b // REGION) * nra + a // REGION
    blk = ((b // BLOCK) % 4) * 4 + (a // BLOCK) % 4
    cell = ((b // CELL) % 4) * 4 + (a // CELL) % 4
    return region * KEYS + blk * 16 + cell


@stage
def _emit_slice(m, nra, ta, tb, td, tsrc, count, n, hier, sel, tops):
    """Append one slice's ``m`` voxels to ``sel = (offset, density, source)`` from row ``n``, in the order of
    their keys (a stable counting sort, so each cell keeps the blocks' density order), and the regions, blocks
    and cells they fill to ``hier``; ``tops = [regions, blocks, cells]`` so far, updated."""
    region_id, region_ptr, block_pos, block_ptr, block_voxel, cell_pos, cell_count = hier
    s_off, s_d, s_src = sel
    count[:] = 0
    for t in range(m):
        count[_voxel_key(np.int64(ta[t]), np.int64(tb[t]), nra) + 1] += 1
    ng, nb, nq = tops[0], tops[1], tops[2]
    last_region = -1
    last_block = -1
    for key in range(count.shape[0] - 1):
        cnt = count[key + 1]
        if cnt > 0:
            if key // KEYS != last_region:
                last_region = key // KEYS
                region_id[ng] = last_region
                region_ptr[ng] = nb
                ng += 1
            if key // 16 != last_block:
                last_block = key // 16
                block_pos[nb] = last_block % 16
                block_ptr[nb] = nq
                block_voxel[nb] = n + count[key]
                nb += 1
            cell_pos[nq] = key % 16
            cell_count[nq] = cnt
            nq += 1
        count[key + 1] += count[key]
    for t in range(m):
        a = np.int64(ta[t])
        b = np.int64(tb[t])
        k = _voxel_key(a, b, nra)
        p = n + count[k]
        count[k] += 1
        s_off[p] = (b % CELL) * CELL + a % CELL
        s_d[p] = td[t]
        if s_src.shape[0] > 0:
            s_src[p] = tsrc[t]
    tops[0], tops[1], tops[2] = ng, nb, nq


@jit
def select_voxels(slice_block_ptr, block_density, block_voxel_ptr, positions, intervals, n_a, n_b, src_like):
    """The voxels of each slice whose density lies in ``intervals`` (§2.2), in the hierarchy of the module
    docstring.

    Per slice, the densities present are sorted (Figure 1), so a binary search finds the first block of each
    interval and the blocks up to its upper bound are decoded into (a, b). This runs once per load (the
    selection depends on the transfer function, not on the view); every frame then streams the result.
    Returns ``(slice_ptr, region_id, region_ptr, block_pos, block_ptr, block_voxel, cell_pos, cell_count,
    offset, density, source)``; ``source`` is each voxel's index in ``positions``, of the integer type of
    ``src_like`` (int32 halves the largest array of a load when ``positions`` allows it); pass an empty array
    for it, or one of length 1 to skip ``source`` (returned empty: no channel values to gather).
    """
    n_slices = slice_block_ptr.shape[0] - 1
    nra = (n_a + REGION - 1) // REGION
    nregions = nra * ((n_b + REGION - 1) // REGION)
    total = _count_selected(slice_block_ptr, block_density, block_voxel_ptr, intervals, n_a * n_b)
    src = np.empty(total if src_like.shape[0] == 0 else 0, dtype=src_like.dtype)
    sel = (np.empty(total, dtype=np.uint8), np.empty(total, dtype=np.uint8), src)
    ng = min(total, n_slices * nregions)
    nb = min(total, ng * 16)
    nq = min(total, nb * 16)
    hier = (np.empty(ng, np.int32), np.empty(ng + 1, np.int64), np.empty(nb, np.uint8), np.empty(nb + 1, np.int64),
            np.empty(nb + 1, np.int64), np.empty(nq, np.uint8), np.empty(nq, np.uint8))
    # one slice's voxels before they are put in order
    ta = np.empty(n_a * n_b, dtype=np.uint16)
    tb = np.empty(n_a * n_b, dtype=np.uint16)
    td = np.empty(n_a * n_b, dtype=np.uint8)
    tsrc = np.empty(n_a * n_b, dtype=np.int64)
    count = np.zeros(nregions * KEYS + 1, dtype=np.int64)
    slice_ptr = np.zeros(n_slices + 1, dtype=np.int64)
    tops = np.zeros(3, dtype=np.int64)
    n = 0
    for c in range(n_slices):
        m = _decode_slice(c, slice_block_ptr, block_density, block_voxel_ptr, positions, intervals, n_a,
                          ta, tb, td, tsrc)
        _emit_slice(m, nra, ta, tb, td, tsrc, count, n, hier, sel, tops)
        n += m
        slice_ptr[c + 1] = tops[0]
    ng, nb, nq = tops[0], tops[1], tops[2]
    region_id, region_ptr, block_pos, block_ptr, block_voxel, cell_pos, cell_count = hier
    region_ptr[ng] = nb
    block_ptr[nb] = nq
    block_voxel[nb] = n
    return (slice_ptr, region_id[:ng].copy(), region_ptr[:ng + 1].copy(), block_pos[:nb].copy(),
            block_ptr[:nb + 1].copy(), block_voxel[:nb + 1].copy(), cell_pos[:nq].copy(), cell_count[:nq].copy(),
            sel[0], sel[1], sel[2])


@stage
def cell_origins(slice_ptr, region_id, region_ptr, block_pos, block_ptr, block_voxel, cell_pos, cell_count, n_a):
    """The hierarchy walked once: per cell, in order, its slice, first voxel ``(a0, b0)`` and first voxel's row
    in the selection (int64 arrays ``c, a0, b0, v0``), for :func:`expand_coordinates` and
    :func:`isplat.splat.mip.make_units`."""
    n_cells = block_ptr[region_ptr[slice_ptr[slice_ptr.shape[0] - 1]]]
    if n_cells < 0 or n_cells > cell_pos.shape[0]:
        raise ValueError("the selection's cell table is inconsistent")
    c_of = np.empty(n_cells, np.int64)
    a_of = np.empty(n_cells, np.int64)
    b_of = np.empty(n_cells, np.int64)
    v_of = np.empty(n_cells, np.int64)
    nra = (n_a + REGION - 1) // REGION
    for c in range(slice_ptr.shape[0] - 1):
        for g in range(slice_ptr[c], slice_ptr[c + 1]):
            ra0 = (region_id[g] % nra) * REGION
            rb0 = (region_id[g] // nra) * REGION
            for r in range(region_ptr[g], region_ptr[g + 1]):
                v = block_voxel[r]
                for q in range(block_ptr[r], block_ptr[r + 1]):
                    c_of[q] = c
                    a_of[q] = ra0 + (block_pos[r] % 4) * BLOCK + (cell_pos[q] % 4) * CELL
                    b_of[q] = rb0 + (block_pos[r] // 4) * BLOCK + (cell_pos[q] // 4) * CELL
                    v_of[q] = v
                    v += cell_count[q]
    return c_of, a_of, b_of, v_of


@jit
def cell_origins_py(slice_ptr, region_id, region_ptr, block_pos, block_ptr, block_voxel, cell_pos, cell_count, n_a):
    """:func:`cell_origins` for callers in Python (a stage is reached from compiled code only: isplat.jit)."""
    return cell_origins(slice_ptr, region_id, region_ptr, block_pos, block_ptr, block_voxel, cell_pos, cell_count,
                        n_a)


@jit
def expand_coordinates(slice_ptr, region_id, region_ptr, block_pos, block_ptr, block_voxel, cell_pos, cell_count,
                       offset, n_a):
    """Every voxel's ``(c, a, b)`` from the hierarchy (the inverse of :func:`select_voxels`' ordering)."""
    n = offset.shape[0]
    cc = np.empty(n, np.int64)
    aa = np.empty(n, np.int64)
    bb = np.empty(n, np.int64)
    c_of, a_of, b_of, v_of = cell_origins(slice_ptr, region_id, region_ptr, block_pos, block_ptr, block_voxel,
                                          cell_pos, cell_count, n_a)
    for q in range(c_of.shape[0]):
        v = v_of[q]
        for _ in range(cell_count[q]):
            cc[v] = c_of[q]
            aa[v] = a_of[q] + offset[v] % CELL
            bb[v] = b_of[q] + offset[v] // CELL
            v += 1
    return cc, aa, bb
