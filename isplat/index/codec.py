"""Compiled kernels of the density index: measure, encode and decode blocks (paper §2.1, §2.3).

A block holds the in-slice positions ``ind = a + b * n_a`` of the voxels of one density in one slice, in
increasing (scan-line) order. Each position is stored as its offset from the previous one (the first from a
virtual predecessor at -1): one byte ``off`` when ``1 <= off <= 255``, else the escape ``0x00`` followed by
``a`` then ``b``, each ``escape_width`` bytes little-endian (§2.3; width 2 is isplat's wider escape).

The volume kernels walk the array in memory order ``[k, j, i]``; for every slice axis this visits the
positions of each slice in increasing order, so one pass keeps a ``prev`` per (slice, density).
"""

from __future__ import annotations

import numpy as np

from ..jit import jit, leaf, stage

# decoder status codes
OK = 0
ERR_TOO_MANY = 1       # bytes remain after `count` voxels
ERR_TOO_FEW = 2        # the byte range ends before `count` voxels
ERR_TRUNCATED = 3      # an escape runs past the block's byte range
ERR_COORD = 4          # an escape coordinate a >= n_a or b >= n_b
ERR_ORDER = 5          # a position not above its predecessor
ERR_RANGE = 6          # a position >= n_a * n_b

ERROR_TEXT = {
    ERR_TOO_MANY: "decodes to more voxels than its count",
    ERR_TOO_FEW: "decodes to fewer voxels than its count",
    ERR_TRUNCATED: "an escape runs past the end of the block",
    ERR_COORD: "an escape coordinate is outside the slice",
    ERR_ORDER: "positions are not increasing",
    ERR_RANGE: "a position is outside the slice",
}


def escape_cost(escape_width: int) -> int:
    """Bytes of one escaped position: the 0x00 marker and two coordinates (§2.3)."""
    return 1 + 2 * escape_width


@stage
def _slice_pos(coef, k, j, i):
    """(slice, in-slice position) of voxel (i, j, k); ``coef`` from :func:`isplat.grid.slice_coefficients`."""
    return (i * coef[0] + j * coef[1] + k * coef[2], i * coef[3] + j * coef[4] + k * coef[5])


@jit
def measure_slab(planes, k0, coef, indexed, esc, prev, counts, lengths):
    """Add the voxel counts and encoded byte lengths of k-planes ``planes`` (k-planes ``k0, k0 + 1, ...`` of the
    volume) to ``counts``/``lengths[d, s]``.

    ``prev[s, d]`` (start at -1) carries the last position across slabs; ``esc`` is the escape's byte cost.
    """
    n_j = planes.shape[1]
    n_i = planes.shape[2]
    for t in range(planes.shape[0]):
        k = k0 + t
        for j in range(n_j):
            for i in range(n_i):
                d = planes[t, j, i]
                if not indexed[d]:
                    continue
                s, p = _slice_pos(coef, k, j, i)
                off = p - prev[s, d]
                if off <= 255:
                    lengths[d, s] += 1
                else:
                    lengths[d, s] += esc
                prev[s, d] = p
                counts[d, s] += 1


@leaf
def _put(out, o0, c, value):
    """Byte ``c`` of the stream into window ``out`` (stream bytes ``o0 .. o0 + len(out) - 1``), if inside."""
    w = c - o0
    if 0 <= w < out.shape[0]:
        out[w] = value


@jit
def encode_slab(planes, k0, coef, indexed, n_a, escape_width, prev, cursor, out, o0):
    """Encode k-planes ``planes`` (``k0, k0 + 1, ...``): the next byte of block (d, s) is stream byte
    ``cursor[d, s]`` (§2.3), stored at ``out[cursor[d, s] - o0]`` when it falls in the window ``out`` (stream
    bytes ``o0 .. o0 + len(out) - 1``) and skipped otherwise; ``prev`` and ``cursor`` advance either way."""
    n_j = planes.shape[1]
    n_i = planes.shape[2]
    for t in range(planes.shape[0]):
        k = k0 + t
        for j in range(n_j):
            for i in range(n_i):
                d = planes[t, j, i]
                if not indexed[d]:
                    continue
                s, p = _slice_pos(coef, k, j, i)
                off = p - prev[s, d]
                c = cursor[d, s]
                if off <= 255:
                    _put(out, o0, c, off)
                    c += 1
                else:
                    # §2.3: a zero byte, then the explicit in-slice coordinates
                    a = p % n_a
                    b = p // n_a
                    _put(out, o0, c, 0)
                    if escape_width == 1:
                        _put(out, o0, c + 1, a)
                        _put(out, o0, c + 2, b)
                        c += 3
                    else:
                        _put(out, o0, c + 1, a & 0xFF)
                        _put(out, o0, c + 2, a >> 8)
                        _put(out, o0, c + 3, b & 0xFF)
                        _put(out, o0, c + 4, b >> 8)
                        c += 5
                cursor[d, s] = c
                prev[s, d] = p


@stage
def _escape_coords(buf, c, escape_width):
    """The explicit in-slice coordinates (a, b) after the escape byte at ``buf[c]``, little-endian."""
    if escape_width == 1:
        return np.int64(buf[c + 1]), np.int64(buf[c + 2])
    return (np.int64(buf[c + 1]) | (np.int64(buf[c + 2]) << 8),
            np.int64(buf[c + 3]) | (np.int64(buf[c + 4]) << 8))


@stage
def _next_position(buf, c, end, prev, n_a, n_b, n_pos, escape_width):
    """Read the position at ``buf[c]`` (an offset byte from ``prev``, or an escape; §2.3) without reading
    past ``end``; return ``(status, position, next c)``, status OK or the error found."""
    v = np.int64(buf[c])
    if v != 0:
        p = prev + v
        c += 1
    else:
        if c + 1 + 2 * escape_width > end:
            return ERR_TRUNCATED, prev, c
        a, b = _escape_coords(buf, c, escape_width)
        c += 1 + 2 * escape_width
        if a >= n_a or b >= n_b:
            return ERR_COORD, prev, c
        p = a + b * n_a
    if p <= prev:
        return ERR_ORDER, prev, c
    if p >= n_pos:
        return ERR_RANGE, prev, c
    return OK, p, c


@jit
def decode_blocks(buf, starts, ends, counts, dest, n_a, n_b, escape_width, out):
    """Decode block e = ``buf[starts[e]:ends[e]]`` into ``out[dest[e] : dest[e] + counts[e]]``.

    Return ``(status, e)``: ``(OK, -1)`` or the first error code and the failing block. Never writes
    outside a block's ``counts[e]`` slots, never reads outside its byte range.
    """
    n_pos = np.int64(n_a) * np.int64(n_b)
    for e in range(starts.shape[0]):
        c = np.int64(starts[e])
        end = np.int64(ends[e])
        cnt = np.int64(counts[e])
        w = np.int64(dest[e])
        prev = np.int64(-1)
        n = np.int64(0)
        while c < end:
            if n >= cnt:
                return ERR_TOO_MANY, e
            status, p, c = _next_position(buf, c, end, prev, n_a, n_b, n_pos, escape_width)
            if status != OK:
                return status, e
            out[w + n] = p
            n += 1
            prev = p
        if n != cnt:
            return ERR_TOO_FEW, e
    return OK, -1


@jit
def decode_stream(buf, counts, dest, n_a, n_b, escape_width, out):
    """Decode consecutive blocks from ``buf``: block e is the next ``counts[e]`` positions, into ``out[dest[e]:]``.

    The blocks of a density interval are contiguous (formats/index.md), so their boundaries follow from the
    counts and only the interval's two end offsets are needed. Return ``(status, e)`` like
    :func:`decode_blocks`; bytes left after the last block are ``ERR_TOO_MANY`` of the last block.
    """
    n_pos = np.int64(n_a) * np.int64(n_b)
    end = np.int64(buf.shape[0])
    c = np.int64(0)
    for e in range(counts.shape[0]):
        cnt = np.int64(counts[e])
        w = np.int64(dest[e])
        prev = np.int64(-1)
        for n in range(cnt):
            if c >= end:
                return ERR_TOO_FEW, e
            status, p, c = _next_position(buf, c, end, prev, n_a, n_b, n_pos, escape_width)
            if status != OK:
                return status, e
            out[w + n] = p
            prev = p
    if c != end:
        return ERR_TOO_MANY, counts.shape[0] - 1
    return OK, -1


@jit
def scatter_values(density, gradient_magnitude, normal, indexed, cursor, r0, r1, gm_out, normal_out):
    """Copy the channel values of a run of voxels in position order into rows ``r0 .. r1 - 1`` of the values
    arrays (formats/index.md §9: density-major, then by position): a voxel of indexed density ``d`` takes row
    ``cursor[d]``, which then advances; rows outside the window are skipped. The caller sized ``cursor`` from
    the same densities, so ``cursor[d]`` stays below the next density's first row."""
    for v in range(density.shape[0]):
        d = density[v]
        if indexed[d]:
            r = cursor[d]
            cursor[d] = r + 1
            if r0 <= r < r1:
                gm_out[r - r0] = gradient_magnitude[v]
                normal_out[r - r0] = normal[v]
