"""Augmented format 6's brick store (formats/augmented.md §2.3): each channel one contiguous HDF5 dataset of its
bricks in brick-major order (C order of the brick grid, each brick's elements in C order, the volume padded with
zeros to whole bricks), read by file offset (a memory map: no HDF5 call per brick), and a keyed 64-bit hash per
brick (``/brick_hashes/<channel>``, uint64) computed and checked by one compiled call for many bricks.

The brick hash (all arithmetic modulo 2^64; ``w`` the brick's stored bytes as little-endian uint64 words)::

    h = seed ^ ((b + 1) * 0x9E3779B97F4A7C15)           b: the brick's row (grid index in C order)
    for each word w:  h ^= w;  h *= 0xFF51AFD7ED558CCD;  h ^= h >> 32
    h ^= h >> 33;  h *= 0xC4CEB9FE1A85EC53;  h ^= h >> 33

Every step is a bijection of ``h`` for a given word, so a brick whose bytes differ from the stored ones in one
8-byte word, or a brick moved to another row, always gives another hash. ``seed`` (per channel) binds it to the
file: :func:`channel_seed`.
"""

from __future__ import annotations

import hashlib

import numpy as np

from .jit import jit, stage

SEED_MESSAGE = b"isplat brick hashes 6"
GOLDEN = np.uint64(0x9E3779B97F4A7C15)
MIX1 = np.uint64(0xFF51AFD7ED558CCD)
MIX2 = np.uint64(0xC4CEB9FE1A85EC53)


def channel_seed(file_key: bytes, channel: str) -> int:
    """The channel's seed: the first 8 bytes, little-endian, of BLAKE2b-64 keyed with the file key (the chunk
    hashes' key, isplat.chunkhash.file_key) over ``"isplat brick hashes 6" NUL channel NUL``."""
    h = hashlib.blake2b(SEED_MESSAGE + b"\0" + channel.encode("utf-8") + b"\0", digest_size=8, key=file_key)
    return int.from_bytes(h.digest(), "little")


@stage
def _brick_hash(words: np.ndarray, w: int, row, seed: np.uint64) -> np.uint64:
    """The hash of brick ``words[w]`` (its bytes as uint64 words) stored at row ``row`` (module docstring)."""
    h = seed ^ ((np.uint64(row) + np.uint64(1)) * GOLDEN)
    for c in range(words.shape[1]):
        h ^= words[w, c]
        h *= MIX1
        h ^= h >> np.uint64(32)
    h ^= h >> np.uint64(33)
    h *= MIX2
    h ^= h >> np.uint64(33)
    return h


@jit
def hash_bricks(words: np.ndarray, rows: np.ndarray, seed: np.uint64) -> np.ndarray:
    """uint64[n]: the hash of each brick ``words[n]`` (its bytes as uint64 words) stored at row ``rows[n]``."""
    out = np.empty(words.shape[0], dtype=np.uint64)
    for r in range(words.shape[0]):
        out[r] = _brick_hash(words, r, rows[r], seed)
    return out


@stage
def _minmax(flat: np.ndarray, w: int, e: int, e0: int, e1: int, e2: int):
    """The smallest and largest element of brick ``w`` of ``flat`` (uint8: density codes; bricks of ``e``^3
    elements, one after another, each in C order) within its first ``e0`` x ``e1`` x ``e2`` elements; a whole brick
    as one run."""
    lo, hi = np.uint8(255), np.uint8(0)
    if e0 == e and e1 == e and e2 == e:
        s = np.uint64(w * e * e * e)
        for x in range(e * e * e):                        # (unsigned indices: no wraparound, so it vectorizes)
            v = flat[s + np.uint64(x)]
            lo, hi = min(lo, v), max(hi, v)
        return lo, hi
    for k in range(e0):
        for j in range(e1):
            s = np.uint64(((w * e + k) * e + j) * e)
            for i in range(e2):
                v = flat[s + np.uint64(i)]
                lo, hi = min(lo, v), max(hi, v)
    return lo, hi


@jit
def brick_minmax(data: np.ndarray, ext: np.ndarray) -> np.ndarray:
    """uint8[n, 2]: the smallest and largest of each brick ``data[n]`` (uint8, [n, e, e, e], C order) within its
    part inside the volume (``ext[n]``: its extent along k, j, i, each 1..e)."""
    n, e = data.shape[0], data.shape[1]
    flat = data.reshape(-1)
    out = np.empty((n, 2), dtype=np.uint8)
    for r in range(n):
        out[r, 0], out[r, 1] = _minmax(flat, r, e, ext[r, 0], ext[r, 1], ext[r, 2])
    return out


def to_bricks(block: np.ndarray, edge: int) -> np.ndarray:
    """[gk * gj * gi, e, e, e]: the bricks of ``block`` (k-planes starting at a brick layer, the volume's whole j
    and i extent), zero-padded to whole bricks, in brick-major order."""
    nk, nj, ni = block.shape
    g = [-(-n // edge) for n in block.shape]
    pad = np.zeros([x * edge for x in g], dtype=block.dtype)
    pad[:nk, :nj, :ni] = block
    return np.ascontiguousarray(pad.reshape(g[0], edge, g[1], edge, g[2], edge).transpose(0, 2, 4, 1, 3, 5)
                                ).reshape(-1, edge, edge, edge)


@jit
def check_place(data: np.ndarray, words: np.ndarray, stored: np.ndarray, r0: int, rows: np.ndarray,
                pick: np.ndarray, seed: np.uint64, offs: np.ndarray, ext: np.ndarray, lo: np.ndarray, out: np.ndarray,
                mm: np.ndarray) -> int:
    """One pass over bricks ``pick`` (indices into ``rows``, ``offs``, ``ext``, ``mm``) of a window of the store
    holding rows ``r0`` .. ``r0 + len(data) - 1``: each brick ``b`` (row ``rows[b]``) hashed from the window
    (``words``: the window as uint64 words [rows, size / 8]; ``data``: the same bytes as the channel's elements
    [rows, e, e, e]) and compared with its stored hash ``stored[rows[b] - r0]``; if equal, its smallest and
    largest element within ``ext[b]`` written to ``mm[b]`` (when ``mm`` has rows: the density), and its elements
    written into ``out``, the block of the volume from element ``lo`` (brick ``b``'s first element at ``offs[b]``,
    clipped to its part inside the volume ``ext[b]`` and to the block: every index written lies inside ``out``).
    Returns the smallest ``b`` whose hash differs (that brick neither placed nor ranged), -1 if none, -2 if a
    row lies outside the window (nothing read through it)."""
    e = data.shape[1]
    n0, n1, n2 = out.shape
    src, dst = data.reshape(-1), out.reshape(-1)         # flat, unsigned indices: no wraparound checks per element
    bad = -1
    for t in range(pick.shape[0]):
        b = pick[t]
        w = rows[b] - r0
        if w < 0 or w >= data.shape[0]:
            return -2
        if _brick_hash(words, w, rows[b], seed) != stored[w]:
            bad = b if bad < 0 else min(bad, b)
            continue
        if mm.shape[0]:
            mm[b, 0], mm[b, 1] = _minmax(src, w, e, ext[b, 0], ext[b, 1], ext[b, 2])
        o0, o1, o2 = offs[b, 0] - lo[0], offs[b, 1] - lo[1], offs[b, 2] - lo[2]
        z0, z1 = max(0, -o0), min(ext[b, 0], n0 - o0, e)
        y0, y1 = max(0, -o1), min(ext[b, 1], n1 - o1, e)
        x0, x1 = max(0, -o2), min(ext[b, 2], n2 - o2, e)
        for z in range(z0, z1):
            for y in range(y0, y1):
                s = np.uint64(((w * e + z) * e + y) * e + x0)
                d = np.uint64(((o0 + z) * n1 + o1 + y) * n2 + o2 + x0)
                for x in range(x1 - x0):
                    dst[d + np.uint64(x)] = src[s + np.uint64(x)]
    return bad


@jit
def mark_reach(out: np.ndarray, c: np.ndarray, a0: np.ndarray, b0: np.ndarray, n: np.ndarray, back: int, ahead: int,
               edge: np.ndarray, step: np.ndarray) -> int:
    """Mark in ``out`` (bool, a brick grid, flat) every brick that holds a voxel ``(c[q], a, b)`` with ``a`` in
    ``a0[q] - back .. a0[q] + ahead`` and ``b`` in ``b0[q] - back .. b0[q] + ahead``, both clipped to the slice
    (``n``: the extents of c, a, b; ``edge``: the bricks' extents along c, a, b; ``step``: the flat strides of
    ``out`` along c, a, b). Returns -1, or the first ``q`` whose cell lies outside the volume (nothing marked for
    it or after it)."""
    for q in range(c.shape[0]):
        if not (0 <= c[q] < n[0] and 0 <= a0[q] < n[1] and 0 <= b0[q] < n[2]):
            return q
        base = c[q] // edge[0] * step[0]
        for ga in range(max(a0[q] - back, 0) // edge[1], min(a0[q] + ahead, n[1] - 1) // edge[1] + 1):
            for gb in range(max(b0[q] - back, 0) // edge[2], min(b0[q] + ahead, n[2] - 1) // edge[2] + 1):
                out[base + ga * step[1] + gb * step[2]] = True
    return -1


@jit
def pages_touched(bricks: np.ndarray, size: np.ndarray, lo: np.ndarray, shape: np.ndarray, itemsize: int,
                  shift: int) -> int:
    """The memory pages (of ``2 ** shift`` bytes) of a C-order array of ``shape`` (the block from element ``lo``, of
    ``itemsize``-byte elements) that bricks ``bricks`` (grid indices; bricks of ``size`` (k, j, i) elements)
    written into it, each clipped to the block, touch."""
    n = shape[0] * shape[1] * shape[2] * itemsize
    marks = np.zeros((n + (1 << shift) - 1) >> shift, dtype=np.bool_)
    for r in range(bricks.shape[0]):
        k0, j0, i0 = bricks[r, 0] * size[0] - lo[0], bricks[r, 1] * size[1] - lo[1], bricks[r, 2] * size[2] - lo[2]
        x0, x1 = max(i0, 0), min(i0 + size[2], shape[2])
        if x1 <= x0:
            continue
        y0, y1 = max(j0, 0), min(j0 + size[1], shape[1])
        for k in range(max(k0, 0), min(k0 + size[0], shape[0])):
            if y1 <= y0:
                break
            if shape[2] * itemsize <= 1 << shift:
                # rows at most a page apart: every page from the first row's first byte to the last row's last
                # byte holds a byte of some row (a page wholly between them holds a row's start)
                first = ((k * shape[1] + y0) * shape[2] + x0) * itemsize >> shift
                last = (((k * shape[1] + y1 - 1) * shape[2] + x1) * itemsize - 1) >> shift
                marks[first:last + 1] = True
                continue
            for j in range(y0, y1):
                row = (k * shape[1] + j) * shape[2]
                marks[(row + x0) * itemsize >> shift] = True         # a row of a brick: at most two pages
                marks[((row + x1) * itemsize - 1) >> shift] = True
    return int(np.count_nonzero(marks))
