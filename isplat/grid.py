"""The voxel grid's axis conventions, in one place (docs/design.md, "Axes and names").

Arrays are indexed ``[k, j, i]`` with i fastest. A slice perpendicular to axis ``c`` has two in-slice axes,
``a`` (fastest) and ``b``, which keep their memory order, so a slice's scan-line order is its memory order
and the paper's in-slice position is ``ind = a + b * n_a``:

====  ===  ===  =================
c     a    b    ind
====  ===  ===  =================
k     i    j    ``i + j * n_i``
j     i    k    ``i + k * n_i``
i     j    k    ``j + k * n_j``
====  ===  ===  =================

>>> slice_shape((4, 5, 6), "j")          # (n_slices, n_a, n_b) of a volume [k=4, j=5, i=6]
(5, 6, 4)
>>> flat_strides((4, 5, 6), "j").tolist()  # flat [k, j, i] steps along a, b, c
[1, 30, 6]
"""

from __future__ import annotations

import numpy as np

AXES = "ijk"
# slice axis -> (a, b, c) as indices into (i, j, k)
SLICE_AXES = {"k": (0, 1, 2), "j": (0, 2, 1), "i": (1, 2, 0)}
# slice axis -> the names of its in-slice axes a, b
IN_SLICE_AXES = {c: AXES[ia] + AXES[ib] for c, (ia, ib, _) in SLICE_AXES.items()}

def shape_ijk(shape_kji) -> tuple[int, int, int]:
    """``(n_i, n_j, n_k)`` of an array shape ``(n_k, n_j, n_i)``."""
    n_k, n_j, n_i = (int(x) for x in shape_kji)
    return n_i, n_j, n_k

def slice_shape(shape_kji, axis: str) -> tuple[int, int, int]:
    """``(n_slices, n_a, n_b)`` of the slices perpendicular to ``axis``."""
    n = shape_ijk(shape_kji)
    ia, ib, ic = SLICE_AXES[axis]
    return n[ic], n[ia], n[ib]

def slice_coefficients(shape_kji, axis: str) -> tuple[int, ...]:
    """``(si, sj, sk, pi, pj, pk)``: voxel ``(i, j, k)`` lies in slice ``i*si + j*sj + k*sk`` of ``axis`` at
    in-slice position ``ind = i*pi + j*pj + k*pk`` (for compiled code, which takes no dictionaries).

    >>> slice_coefficients((4, 5, 6), "i")      # slice i, ind = j + k * n_j
    (1, 0, 0, 0, 1, 5)
    """
    ia, ib, ic = SLICE_AXES[axis]
    n = shape_ijk(shape_kji)
    s, p = [0, 0, 0], [0, 0, 0]
    s[ic] = 1
    p[ia] = 1
    p[ib] = n[ia]
    return (*s, *p)

POOL_EDGE = 8                       # voxels a side of a pool's bricks (format 6's bricks): isplat.selection
POOL_SHIFT = 9                      # log2(POOL_EDGE ** 3): a flat brick-major index >> POOL_SHIFT is its brick


def flat_offsets(shape_kji, axis: str, edge: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(oa, ob, oc)``: int64 tables of each voxel's share of the flat index along a, b and c of ``axis``'s
    slices, so that voxel (a, b, c) is at ``oa[a] + ob[b] + oc[c]``. ``edge`` 0: the flat ``[k, j, i]`` (C order,
    :func:`flat_strides`); else brick-major: bricks of ``edge``^3 voxels in C order of the brick grid (the volume
    padded to whole bricks), each brick's voxels in C order: the order of formats/augmented.md §2.3's store, in
    which the index stays a sum of one term per axis."""
    n_i, n_j, n_k = shape_ijk(shape_kji)
    ns = (n_i, n_j, n_k)
    if edge:
        g_i, g_j = -(-n_i // edge), -(-n_j // edge)
        per_brick, inner = edge ** 3, (1, edge, edge * edge)
        outer = (per_brick, g_i * per_brick, g_i * g_j * per_brick)
        per = [(np.arange(n) // edge) * o + (np.arange(n) % edge) * i for n, o, i in zip(ns, outer, inner)]
    else:
        per = [np.arange(n) * s for n, s in zip(ns, (1, n_i, n_i * n_j))]
    return tuple(per[x].astype(np.int64) for x in SLICE_AXES[axis])


def flat_strides(shape_kji, axis: str) -> np.ndarray:
    """int64[3]: steps of the flat ``[k, j, i]`` index along ``a``, ``b`` and ``c`` of ``axis``'s slices."""
    n_i, n_j, _ = shape_ijk(shape_kji)
    per_axis = (1, n_i, n_i * n_j)                      # i, j, k
    return np.array([per_axis[x] for x in SLICE_AXES[axis]], dtype=np.int64)
