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

import numba
import numpy as np

SEED_MESSAGE = b"isplat brick hashes 6"
GOLDEN = np.uint64(0x9E3779B97F4A7C15)
MIX1 = np.uint64(0xFF51AFD7ED558CCD)
MIX2 = np.uint64(0xC4CEB9FE1A85EC53)


def channel_seed(file_key: bytes, channel: str) -> int:
    """The channel's seed: the first 8 bytes, little-endian, of BLAKE2b-64 keyed with the file key (the chunk
    hashes' key, isplat.chunkhash.file_key) over ``"isplat brick hashes 6" NUL channel NUL``."""
    h = hashlib.blake2b(SEED_MESSAGE + b"\0" + channel.encode("utf-8") + b"\0", digest_size=8, key=file_key)
    return int.from_bytes(h.digest(), "little")


@numba.njit(cache=True, nogil=True)
def hash_bricks(words: np.ndarray, rows: np.ndarray, seed: np.uint64) -> np.ndarray:
    """uint64[n]: the hash of each brick ``words[n]`` (its bytes as uint64 words) stored at row ``rows[n]``."""
    n, m = words.shape
    out = np.empty(n, dtype=np.uint64)
    for r in range(n):
        h = seed ^ ((np.uint64(rows[r]) + np.uint64(1)) * GOLDEN)
        for c in range(m):
            h ^= words[r, c]
            h *= MIX1
            h ^= h >> np.uint64(32)
        h ^= h >> np.uint64(33)
        h *= MIX2
        h ^= h >> np.uint64(33)
        out[r] = h
    return out


@numba.njit(cache=True, nogil=True)
def brick_minmax(data: np.ndarray, ext: np.ndarray) -> np.ndarray:
    """uint8[n, 2]: the smallest and largest of each brick ``data[n]`` (uint8, [n, e, e, e]) within its part
    inside the volume (``ext[n]``: its extent along k, j, i, each 1..e)."""
    n = data.shape[0]
    out = np.empty((n, 2), dtype=np.uint8)
    for r in range(n):
        lo, hi = 255, 0
        for k in range(ext[r, 0]):
            for j in range(ext[r, 1]):
                for i in range(ext[r, 2]):
                    v = data[r, k, j, i]
                    lo = min(lo, v)
                    hi = max(hi, v)
        out[r, 0], out[r, 1] = lo, hi
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


def from_bricks(data: np.ndarray, grid, shape) -> np.ndarray:
    """The inverse of :func:`to_bricks`: ``data`` [gk * gj * gi, e, e, e] (whole layers of the grid ``grid``) as
    the block of ``shape`` (k, j, i) they hold (the padding cut)."""
    e = data.shape[1]
    whole = data.reshape(tuple(grid) + (e, e, e)).transpose(0, 3, 1, 4, 2, 5).reshape([g * e for g in grid])
    return whole[:shape[0], :shape[1], :shape[2]]


@numba.njit(cache=True, nogil=True)
def place_bricks(out: np.ndarray, data: np.ndarray, offs: np.ndarray, ext: np.ndarray, lo: np.ndarray) -> None:
    """Write bricks ``data`` [n, e, e, e] (brick ``r``'s first voxel at ``offs[r]`` (k, j, i), its part inside
    the volume ``ext[r]``) into ``out``, the block of the volume from voxel ``lo``: each brick clipped to the block
    here (every index written lies inside ``out`` by construction, whatever ``offs``)."""
    n0, n1, n2 = out.shape
    for r in range(data.shape[0]):
        o0, o1, o2 = offs[r, 0] - lo[0], offs[r, 1] - lo[1], offs[r, 2] - lo[2]
        z0, z1 = max(0, -o0), min(ext[r, 0], n0 - o0)
        y0, y1 = max(0, -o1), min(ext[r, 1], n1 - o1)
        x0, x1 = max(0, -o2), min(ext[r, 2], n2 - o2)
        for z in range(z0, z1):
            for y in range(y0, y1):
                for x in range(x0, x1):
                    out[o0 + z, o1 + y, o2 + x] = data[r, z, y, x]
