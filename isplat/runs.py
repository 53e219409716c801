"""Range runs (formats/runs.md; docs/design.md, "Runs ordered by the neighbourhood's density range"): the channel
bytes of each voxel stored in the run of its key's (lo bin, hi bin), so that a scene reads only the runs whose bin
rectangle meets one of its intervals of non-zero opacity.

Kernels (arrays in, arrays out; numpy, nothing compiled indexes with what a file holds):

- :func:`union_key`: per voxel the least and greatest density over the voxels it shares a quad with in any of the
  three slice lattices (the 3 x 3 x 3 cube without its 8 corners);
- :func:`dp_cut`: the bins (first codes of 8 lo bins and 8 hi bins by default) of least mean voxels read over every
  interval, from the (lo, hi) histogram of the volume alone;
- :func:`layer_runs` / :func:`build_runs`: the layout (runs hi bin major; inside a run by brick number, then by
  place in the brick), the positions per (run, brick) as nested masks: a byte of the brick's 8 planes (dk) that
  hold a voxel of the run, a byte of rows (dj) per plane held, a byte of voxels (di) per row held;
- the inverse: :func:`isplat.runsplace.place_runs` (tests/runs_reference.py: the slow NumPy decoding).

The file (write, open, read, validate) is :mod:`isplat.runsfile`.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .errors import IsplatError
from .jit import jit, leaf

BRICK = 8                       # bricks of 8^3 voxels, numbered in C order over the brick grid (bk, bj, bi)
BRICK_VOXELS = BRICK ** 3       # a voxel's place in its brick: (dk * 8 + dj) * 8 + di
MOST_POSITION_BYTES = 1 + BRICK + BRICK * BRICK    # a (run, brick)'s masks: of its planes, rows and voxels
BITMAP_BYTES = BRICK_VOXELS // 8    # format version 1 (read only): a 64-byte bitmap above V1_LIST_MAX voxels,
V1_LIST_MAX = BITMAP_BYTES // 2     # else 2 B a voxel
IN_SLICE_DIMS = {"k": (1, 2), "j": (0, 2), "i": (0, 1)}     # as isplat.stats.IN_SLICE_DIMS
DEFAULT_BINS = (8, 8)


# ------------------------------------------------------------------------------------------------- keys

def step3(a: np.ndarray, d: int, op) -> np.ndarray:
    """``op`` over a voxel and its neighbours at -1, +1 along dimension ``d`` (cut at the edge).

    >>> step3(np.array([[[3, 1, 2, 5]]], np.uint8), 2, np.minimum).tolist()
    [[[1, 1, 1, 2]]]
    """
    out = a.copy()
    lo, hi = [slice(None)] * 3, [slice(None)] * 3
    lo[d], hi[d] = slice(None, -1), slice(1, None)
    op(out[tuple(hi)], a[tuple(lo)], out=out[tuple(hi)])
    op(out[tuple(lo)], a[tuple(hi)], out=out[tuple(lo)])
    return out


def plane_ops(a: np.ndarray, dims, op, step=step3) -> np.ndarray:
    """``step`` along each dimension of ``dims`` in turn (a square of a slice lattice)."""
    for d in dims:
        a = step(a, d, op)
    return a


def union_key(density: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi), uint8 [k, j, i]: per voxel the least and greatest density over the in-slice 3 x 3 squares of the
    three slice axes united (19 voxels: the 3 x 3 x 3 cube without its 8 corners, cut at the volume's edge)."""
    density = np.ascontiguousarray(density, dtype=np.uint8)
    out = []
    for op in (np.minimum, np.maximum):
        acc = None
        for dims in IN_SLICE_DIMS.values():
            m = plane_ops(density, dims, op)
            acc = m if acc is None else op(acc, m, out=acc)
        out.append(acc)
    return out[0], out[1]


def layer_key(density: np.ndarray, k0: int, k1: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`union_key` of planes ``k0 .. k1 - 1`` alone, from ``density`` planes ``k0 - 1 .. k1`` (those in the
    volume): equal to the whole volume's key there."""
    a, b = max(0, k0 - 1), min(density.shape[0], k1 + 1)
    lo, hi = union_key(density[a:b])
    return lo[k0 - a:k1 - a], hi[k0 - a:k1 - a]


# ------------------------------------------------------------------------------------------------- bins

class Cut(NamedTuple):
    """Bins cut by the data: ``lo`` / ``hi`` the first code of each lo / hi bin (increasing, from 0); every pair
    (lo bin, hi bin) a run, hi bin major (run = hi bin * lo bins + lo bin), the pairs that cannot hold a voxel (lo
    bin above hi bin) empty. ``label``: how it was cut (``q64x16``, ``dp8x8``)."""
    lo: np.ndarray
    hi: np.ndarray
    label: str


def bin_lut(first: np.ndarray) -> np.ndarray:
    """int32 [256]: each code's bin, the bins starting at codes ``first``."""
    return (np.searchsorted(np.asarray(first), np.arange(256), side="right") - 1).astype(np.int32)


def interval_weights(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The typical scenes a :func:`dp_cut` serves, from the volume alone: every interval [t0, t1], 1 <= t0 <= t1
    <= 255, each weighted by 1 / its voxels (those a key at one bin a code would read, lo <= t1 and hi >= t0; at
    least 1/1000 of the volume), so that the sum is the mean read / ideal. Returns (C, W): C [257, 257] with
    C[e, s] = voxels with lo < e and hi >= s; W [t1, t0]."""
    return weights_of_histogram(key_histogram(lo, hi))


def key_histogram(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """int64 [256, 256]: voxels per (lo, hi) (summed over the layers when a volume is read in layers)."""
    return np.bincount(np.asarray(lo).ravel().astype(np.int64) * 256 + np.asarray(hi).ravel(),
                       minlength=65536).reshape(256, 256)


def weights_of_histogram(h2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`interval_weights` from the (lo, hi) histogram ``h2``."""
    total = int(h2.sum())
    C = np.zeros((257, 257))
    C[1:, :256] = np.cumsum(h2, 0)[:, ::-1].cumsum(1)[:, ::-1]
    t1, t0 = np.meshgrid(np.arange(256), np.arange(256), indexing="ij")
    ideal = C[t1 + 1, t0]
    W = np.where((t0 >= 1) & (t0 <= t1), 1.0 / np.maximum(ideal, max(1.0, total / 1000)), 0.0)
    return C, W


def cut_cost(C: np.ndarray, W: np.ndarray, lo_first, hi_first) -> float:
    """Sum over the weighted intervals of the voxels read: per [t0, t1], those with lo below the end of t1's lo
    bin and hi at or above the start of t0's hi bin."""
    end = np.append(np.asarray(lo_first)[1:], 256)[bin_lut(lo_first)]       # [t1]
    start = np.asarray(hi_first)[bin_lut(hi_first)]                        # [t0]
    return float((W * C[end[:, None], start[None, :]]).sum())


def best_bins(cost: np.ndarray, n: int) -> np.ndarray:
    """First codes of the ``n`` bins [a, b) covering 0 .. 256 of least total ``cost[a, b]`` (dynamic
    programming; a bin at least one code)."""
    F = np.full(257, np.inf)
    F[0] = 0.0
    back = []
    for _ in range(n):
        tot = F[:, None] + cost                     # [a, b]
        a = np.argmin(tot, axis=0)
        F = tot[a, np.arange(257)]
        back.append(a)
    first, b = [], 256
    for a in reversed(back):
        b = int(a[b])
        first.append(b)
    return np.array(first[::-1], np.int64)


def dp_cut(lo: np.ndarray, hi: np.ndarray, n_lo: int, n_hi: int, rounds: int = 4) -> Cut:
    """Bins of least :func:`cut_cost` over :func:`interval_weights`' intervals: from uniform bins, the lo edges
    best for the hi edges (exactly, by :func:`best_bins`), then the hi edges best for those, ``rounds`` times
    (each step can only lower the cost)."""
    return dp_cut_of(key_histogram(lo, hi), n_lo, n_hi, rounds)


def dp_cut_of(h2: np.ndarray, n_lo: int, n_hi: int, rounds: int = 4) -> Cut:
    """:func:`dp_cut` from the (lo, hi) histogram ``h2`` (:func:`key_histogram`)."""
    if not (1 <= n_lo <= 256 and 1 <= n_hi <= 256):
        raise IsplatError(f"bins {n_lo}x{n_hi}: expected 1 to 256 lo bins and hi bins")
    C, W = weights_of_histogram(h2)
    lo_first = np.arange(n_lo) * 256 // n_lo
    hi_first = np.arange(n_hi) * 256 // n_hi
    a, b = np.meshgrid(np.arange(257), np.arange(257), indexing="ij")
    bad = a >= b
    for _ in range(rounds):
        start = hi_first[bin_lut(hi_first)]
        G = W @ C[:, start].T                                # G[t1, e] = sum_t0 W[t1, t0] C[e, S(t0)]
        P = np.vstack([np.zeros(257), np.cumsum(G, 0)])      # P[x, e] = sum_{t1 < x} G[t1, e]
        cost = np.where(bad, np.inf, P[b, b] - P[a, b])
        lo_first = best_bins(cost, n_lo)
        end = np.append(lo_first[1:], 256)[bin_lut(lo_first)]
        K = W.T @ C[end, :]                                  # K[t0, s] = sum_t1 W[t1, t0] C[E(t1), s]
        Q = np.vstack([np.zeros(257), np.cumsum(K, 0)])      # Q[x, s] = sum_{t0 < x} K[t0, s]
        cost = np.where(bad, np.inf, Q[b, a] - Q[a, a])
        hi_first = best_bins(cost, n_hi)
    return Cut(lo_first, hi_first, f"dp{n_lo}x{n_hi}")


def n_runs(cut: Cut) -> int:
    return len(cut.lo) * len(cut.hi)


def run_of(lo: np.ndarray, hi: np.ndarray, cut: Cut) -> np.ndarray:
    """int32, ``lo``'s shape: each voxel's run, hi bin major, lo bin minor.

    >>> cut = Cut(np.r_[0, 128], np.r_[0, 64, 128, 192], "")
    >>> run_of(np.array([0, 0, 64, 255]), np.array([0, 255, 200, 255]), cut).tolist()
    [0, 6, 6, 7]
    """
    return bin_lut(cut.hi)[hi] * len(cut.lo) + bin_lut(cut.lo)[lo]


def run_codes(cut: Cut) -> tuple[np.ndarray, np.ndarray]:
    """Per run, the least code of its lo bin and the greatest of its hi bin."""
    r = np.arange(n_runs(cut))
    hi_last = np.append(np.asarray(cut.hi)[1:], 256) - 1
    return np.asarray(cut.lo)[r % len(cut.lo)], hi_last[r // len(cut.lo)]


def runs_meeting(intervals, cut: Cut) -> np.ndarray:
    """bool [runs]: the runs whose bin rectangle can meet one of the inclusive code ``intervals`` (with some
    lo <= hi in it)."""
    lo_first, hi_last = run_codes(cut)
    out = np.zeros(n_runs(cut), dtype=bool)
    for t0, t1 in intervals:
        out |= (lo_first <= int(t1)) & (hi_last >= int(t0))
    return out & (lo_first <= hi_last)


# ------------------------------------------------------------------------------------------------- layout

class Runs(NamedTuple):
    """The runs of a volume or of one layer of bricks (formats/runs.md §3): per run ``r`` its voxels
    ``run_voxel_ptr[r] .. [r + 1]`` of ``density``, ``normal``, ``gradient_magnitude``; its bricks
    ``run_brick_ptr[r] .. [r + 1]`` of ``brick_number`` (increasing) and ``brick_voxel_count``; its positions'
    bytes ``run_position_ptr[r] .. [r + 1]`` of ``positions`` (per brick its nested masks)."""
    run_voxel_ptr: np.ndarray
    run_brick_ptr: np.ndarray
    run_position_ptr: np.ndarray
    brick_number: np.ndarray
    brick_voxel_count: np.ndarray
    positions: np.ndarray
    density: np.ndarray
    normal: np.ndarray
    gradient_magnitude: np.ndarray


RUN_ARRAYS = ("brick_number", "brick_voxel_count", "positions", "density", "normal", "gradient_magnitude")
PTR_OF = {"brick_number": "run_brick_ptr", "brick_voxel_count": "run_brick_ptr", "positions": "run_position_ptr",
          "density": "run_voxel_ptr", "normal": "run_voxel_ptr", "gradient_magnitude": "run_voxel_ptr"}


def brick_grid(shape) -> tuple[int, int, int]:
    return tuple(-(-int(n) // BRICK) for n in shape)


def position_bytes(planes: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """int64: bytes of the positions of (run, brick)s whose voxels lie in ``planes`` of the brick's planes (dk)
    and ``rows`` of its rows (dk, dj) (formats/runs.md §4): the plane mask, a row mask per plane, a voxel mask per
    row.

    >>> position_bytes([1, 2, 8], [1, 3, 64]).tolist()
    [3, 6, 73]
    """
    return 1 + np.asarray(planes, dtype=np.int64) + np.asarray(rows, dtype=np.int64)


def layer_runs(run: np.ndarray, k0: int, shape, density: np.ndarray, normal: np.ndarray,
               gradient_magnitude: np.ndarray, n_run: int) -> Runs:
    """The runs of one layer of bricks (planes ``k0 .. k0 + len(run) - 1``, ``k0`` a multiple of 8; ``run`` the
    voxels' runs, the channels the layer's planes), brick numbers those of the whole volume's grid: two passes of
    :func:`_layer_runs` over the layer's bricks (a counting sort by run; tests/test_runs.py holds the NumPy
    reference, a stable sort by run, brick and place)."""
    _, gj, gi = brick_grid(shape)
    run = np.ascontiguousarray(run, dtype=np.int32)
    if run.size and (int(run.min()) < 0 or int(run.max()) >= n_run):
        raise ValueError(f"runs {int(run.min())}..{int(run.max())} of a layer, expected 0..{n_run - 1}")
    out = _layer_runs(run, int(n_run), int(k0) // BRICK * gj * gi, np.ascontiguousarray(density),
                      np.ascontiguousarray(normal), np.ascontiguousarray(gradient_magnitude))
    return Runs(*out)


def layer_pointers(run: np.ndarray, n_run: int) -> Runs:
    """:class:`Runs` of a layer with only its three pointer tables (the other fields None): the sizes alone."""
    size = _layer_sizes(np.ascontiguousarray(run, dtype=np.int32), int(n_run))
    return Runs(*(_ptr(size[x]) for x in range(3)), *([None] * len(RUN_ARRAYS)))


@jit
def _layer_sizes(run, n_run):
    """Per run: its voxels, its bricks and its position bytes in the layer ``run`` (int64 [3, n_run])."""
    nl, nj, ni = run.shape
    size = np.zeros((3, n_run), dtype=np.int64)
    tally = np.empty((5, n_run), dtype=np.int64)
    _new_tally(tally)
    touched = np.empty(BRICK_VOXELS, dtype=np.int64)
    for j0 in range(0, nj, BRICK):
        for i0 in range(0, ni, BRICK):
            nt = _tally(run, j0, i0, tally, touched)
            for t in range(nt):
                r = touched[t]
                size[0, r] += tally[0, r]
                size[1, r] += 1
                size[2, r] += 1 + tally[1, r] + tally[2, r]
                _reset(tally, r)
    return size


@leaf
def _new_tally(tally):
    """Per run (columns of ``tally``, int64 [5, runs]): voxels, planes and rows met in a brick, the last plane and
    row met (-1: none yet); all reset."""
    for r in range(tally.shape[1]):
        _reset(tally, r)


@leaf
def _reset(tally, r):
    tally[0, r], tally[1, r], tally[2, r], tally[3, r], tally[4, r] = 0, 0, 0, -1, -1


@leaf
def _tally(run, j0, i0, tally, touched):
    """Per run, in the brick at (j0, i0) of the layer: its voxels into ``tally[0]``, the brick's planes (dk) and
    rows (dk, dj) that hold them into ``tally[1]`` and ``tally[2]`` (``tally[3]``, ``tally[4]``: the last plane
    and row met, :func:`_new_tally`); the runs met (first met first) into ``touched``; returns how many."""
    nl, nj, ni = run.shape
    nt = 0
    for dk in range(nl):
        for j in range(j0, min(nj, j0 + BRICK)):
            row = dk * BRICK + j - j0
            for i in range(i0, min(ni, i0 + BRICK)):
                r = run[dk, j, i]
                if tally[0, r] == 0:
                    touched[nt] = r
                    nt += 1
                tally[0, r] += 1
                if tally[4, r] != row:
                    tally[2, r] += 1
                    tally[4, r] = row
                    if tally[3, r] != dk:
                        tally[1, r] += 1
                        tally[3, r] = dk
    return nt


@jit
def _layer_runs(run, n_run, first_brick, density, normal, gm):
    """:func:`layer_runs`: the sizes (:func:`_layer_sizes`), then each brick's voxels written run by run at
    each run's cursor (brick numbers from ``first_brick``, the layer's first)."""
    nl, nj, ni = run.shape
    size = _layer_sizes(run, n_run)
    ptr = np.zeros((3, n_run + 1), dtype=np.int64)
    for x in range(3):
        for r in range(n_run):
            ptr[x, r + 1] = ptr[x, r] + size[x, r]
    number = np.empty(ptr[1, n_run], dtype=np.uint32)
    count = np.empty(ptr[1, n_run], dtype=np.uint16)
    pos = np.zeros(ptr[2, n_run], dtype=np.uint8)
    d = np.empty(ptr[0, n_run], dtype=density.dtype)
    nrm = np.empty(ptr[0, n_run], dtype=normal.dtype)
    g = np.empty(ptr[0, n_run], dtype=gm.dtype)
    cur = ptr[:, :n_run].copy()
    tally = np.empty((5, n_run), dtype=np.int64)
    _new_tally(tally)
    touched = np.empty(BRICK_VOXELS, dtype=np.int64)
    at = np.zeros((3, n_run), dtype=np.int64)       # the brick's plane mask; its plane's row mask, row's voxel mask
    gi = (ni + BRICK - 1) // BRICK
    for j0 in range(0, nj, BRICK):
        for i0 in range(0, ni, BRICK):
            nt = _tally(run, j0, i0, tally, touched)
            for t in range(nt):
                r = touched[t]
                number[cur[1, r]] = first_brick + j0 // BRICK * gi + i0 // BRICK
                count[cur[1, r]] = tally[0, r]
                cur[1, r] += 1
                at[0, r], at[1, r], at[2, r] = cur[2, r], cur[2, r], cur[2, r] + tally[1, r]
                cur[2, r] += 1 + tally[1, r] + tally[2, r]
                tally[3, r], tally[4, r] = -1, -1
            for dk in range(nl):
                for j in range(j0, min(nj, j0 + BRICK)):
                    row = dk * BRICK + j - j0
                    for i in range(i0, min(ni, i0 + BRICK)):
                        r = run[dk, j, i]
                        v = cur[0, r]
                        d[v], nrm[v], g[v] = density[dk, j, i], normal[dk, j, i], gm[dk, j, i]
                        cur[0, r] += 1
                        if tally[4, r] != row:          # a row (and perhaps a plane) new to this run's brick
                            tally[4, r] = row
                            at[2, r] += 1
                            if tally[3, r] != dk:
                                tally[3, r] = dk
                                at[1, r] += 1
                                pos[at[0, r]] |= np.uint8(1 << dk)
                            pos[at[1, r]] |= np.uint8(1 << (j - j0))
                        pos[at[2, r]] |= np.uint8(1 << (i - i0))
            for t in range(nt):
                _reset(tally, touched[t])
    return ptr[0], ptr[1], ptr[2], number, count, pos, d, nrm, g


def _ptr(counts: np.ndarray) -> np.ndarray:
    out = np.zeros(counts.size + 1, dtype=np.int64)
    np.cumsum(counts, out=out[1:])
    return out


def layers(shape):
    """(k0, k1) of each layer of bricks."""
    nk = int(shape[0])
    return [(k0, min(nk, k0 + BRICK)) for k0 in range(0, nk, BRICK)]


def assemble(parts, ptrs, out: dict) -> None:
    """Write the layers' runs ``parts`` (an iterable of :class:`Runs`, layer after layer) into ``out`` (name ->
    a 1-D array or dataset taking slice assignment, as long as the whole volume's pointers ``ptrs``
    (:func:`total_pointers`) say): run by run, each layer's piece after the earlier layers' pieces of that run."""
    totals = dict(zip(("run_voxel_ptr", "run_brick_ptr", "run_position_ptr"), ptrs))
    cursor = {name: np.array(totals[PTR_OF[name]][:-1]) for name in RUN_ARRAYS}
    for part in parts:
        for name in RUN_ARRAYS:
            src, ptr, cur = getattr(part, name), getattr(part, PTR_OF[name]), cursor[name]
            for r in np.flatnonzero(np.diff(ptr)):
                a, b = int(ptr[r]), int(ptr[r + 1])
                out[name][int(cur[r]):int(cur[r]) + b - a] = src[a:b]
                cur[r] += b - a


def total_pointers(parts) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The whole volume's run_voxel_ptr, run_brick_ptr, run_position_ptr from its layers' runs."""
    sums = None
    for p in parts:
        d = [np.diff(getattr(p, n)) for n in ("run_voxel_ptr", "run_brick_ptr", "run_position_ptr")]
        sums = d if sums is None else [s + x for s, x in zip(sums, d)]
    return tuple(_ptr(s) for s in sums)


def build_runs(density: np.ndarray, normal: np.ndarray, gradient_magnitude: np.ndarray,
               cut: Cut | None = None) -> tuple[Cut, Runs]:
    """The cut (default :func:`dp_cut` 8 x 8 of the volume's keys) and the runs of a whole volume in memory."""
    lo, hi = union_key(density)
    cut = dp_cut(lo, hi, *DEFAULT_BINS) if cut is None else cut
    run = run_of(lo, hi, cut)
    parts = [layer_runs(run[k0:k1], k0, density.shape, density[k0:k1], normal[k0:k1],
                        gradient_magnitude[k0:k1], n_runs(cut)) for k0, k1 in layers(density.shape)]
    ptrs = total_pointers(parts)
    size = {"brick_number": ptrs[1], "brick_voxel_count": ptrs[1], "positions": ptrs[2]}
    out = {n: np.empty(int(size.get(n, ptrs[0])[-1]), dtype=parts[0]._asdict()[n].dtype) for n in RUN_ARRAYS}
    assemble(parts, ptrs, out)
    return cut, Runs(*ptrs, *(out[n] for n in RUN_ARRAYS))
