"""The range-runs layout's positions decoded the slow, obvious way, in NumPy (isplat.runsplace.place_runs is the
compiled reader; formats/runs.md §4): the tests' reference for it and for the writer's encoding."""

from __future__ import annotations

import numpy as np

from isplat.errors import IsplatError
from isplat.runs import BITMAP_BYTES, BRICK, BRICK_VOXELS, LIST_MAX, brick_grid, position_bytes


def encode_positions(group: np.ndarray, local: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """uint8: the positions of consecutive groups (each a (run, brick)): ``group`` [n] each voxel's group
    (0 .. len(counts) - 1, non-decreasing), ``local`` [n] its place in the brick (increasing within a group),
    ``counts`` each group's voxels. A group of at most LIST_MAX voxels: its places as uint16 little-endian; of more:
    a bitmap of 64 bytes, place p at bit p % 8 (least significant first) of byte p // 8."""
    size = position_bytes(counts)
    start = np.concatenate([[0], np.cumsum(size)])
    out = np.zeros(int(start[-1]), dtype=np.uint8)
    is_map = counts > LIST_MAX
    vmap = is_map[group]
    if vmap.any():
        maps = np.flatnonzero(is_map)
        row = np.searchsorted(maps, group[vmap])
        bits = np.zeros((maps.size, BRICK_VOXELS), dtype=bool)
        bits[row, local[vmap]] = True
        packed = np.packbits(bits, axis=1, bitorder="little")
        out[(start[maps][:, None] + np.arange(BITMAP_BYTES)).ravel()] = packed.ravel()
    if (~vmap).any():
        g = group[~vmap]
        first = np.concatenate([[0], np.cumsum(counts)])[:-1]
        rank = np.arange(group.size)[~vmap] - first[g]
        at = start[g] + 2 * rank
        v = local[~vmap].astype("<u2").view(np.uint8).reshape(-1, 2)
        out[at], out[at + 1] = v[:, 0], v[:, 1]
    return out


def decode_positions(counts: np.ndarray, data: np.ndarray, where: str = "positions") -> np.ndarray:
    """int64: each voxel's place in its brick, group after group, from ``counts`` (each group's voxels) and
    ``data`` (:func:`encode_positions`' bytes). Refuses (IsplatError naming ``where``) a length that does not
    match, a bitmap whose bits are not its count, and places not strictly increasing within a group or not
    below 512."""
    counts = np.asarray(counts, dtype=np.int64)
    size = position_bytes(counts)
    if (counts < 1).any() or (counts > BRICK_VOXELS).any():
        bad = int(np.flatnonzero((counts < 1) | (counts > BRICK_VOXELS))[0])
        raise IsplatError(f"{where}: brick {bad} of the run has {int(counts[bad])} voxels, expected 1 to 512")
    if int(size.sum()) != data.size:
        raise IsplatError(f"{where}: {data.size} bytes of positions, the bricks' counts make {int(size.sum())}")
    start = np.concatenate([[0], np.cumsum(size)])
    vfirst = np.concatenate([[0], np.cumsum(counts)])
    out = np.empty(int(vfirst[-1]), dtype=np.int64)
    is_map = counts > LIST_MAX
    if is_map.any():
        maps = np.flatnonzero(is_map)
        raw = data[(start[maps][:, None] + np.arange(BITMAP_BYTES)).ravel()].reshape(-1, BITMAP_BYTES)
        bits = np.unpackbits(raw, axis=1, bitorder="little").astype(bool)
        have = bits.sum(axis=1)
        if (have != counts[maps]).any():
            bad = int(np.flatnonzero(have != counts[maps])[0])
            raise IsplatError(f"{where}: brick {int(maps[bad])} of the run: its bitmap holds {int(have[bad])} "
                              f"voxels, its count says {int(counts[maps[bad]])}")
        _, place = np.nonzero(bits)                     # row-major: group after group, places increasing
        out[_ranges(vfirst[maps], counts[maps])] = place
    if (~is_map).any():
        lists = np.flatnonzero(~is_map)
        at = _ranges(start[lists], 2 * counts[lists])
        place = data[at].view("<u2").astype(np.int64)
        dest = _ranges(vfirst[lists], counts[lists])
        grp = np.repeat(np.arange(lists.size), counts[lists])
        bad = place >= BRICK_VOXELS
        step = np.ones(place.size, dtype=bool)
        step[1:] = (grp[1:] != grp[:-1]) | (place[1:] > place[:-1])
        if bad.any() or not step.all():
            n = int(np.flatnonzero(bad | ~step)[0])
            raise IsplatError(f"{where}: brick {int(lists[grp[n]])} of the run: place {int(place[n])}, expected "
                              f"places below 512, strictly increasing within the brick")
        out[dest] = place
    return out


def _ranges(starts: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """int64: the concatenated ranges ``starts[g] .. starts[g] + lengths[g] - 1``."""
    lengths = np.asarray(lengths, dtype=np.int64)
    total = int(lengths.sum())
    if total == 0:
        return np.zeros(0, dtype=np.int64)
    first = np.concatenate([[0], np.cumsum(lengths)])[:-1]
    return np.repeat(np.asarray(starts, dtype=np.int64) - first, lengths) + np.arange(total)


def flat_positions(brick_number: np.ndarray, counts: np.ndarray, place: np.ndarray, shape,
                   where: str = "positions") -> np.ndarray:
    """int64: each voxel's flat position ``i + n_i * (j + n_j * k)`` from its brick's number (C order over
    :func:`brick_grid`) and its place in the brick. Refuses a brick number beyond the grid and a voxel beyond
    the volume (a place in the part of an edge brick outside it)."""
    nk, nj, ni = (int(n) for n in shape)
    gk, gj, gi = brick_grid(shape)
    b = np.asarray(brick_number, dtype=np.int64)
    if (b >= gk * gj * gi).any():
        bad = int(np.flatnonzero(b >= gk * gj * gi)[0])
        raise IsplatError(f"{where}: brick number {int(b[bad])}, beyond the {gk * gj * gi} bricks of shape "
                          f"{tuple(shape)}")
    bv = np.repeat(b, counts)
    k = (bv // (gj * gi)) * BRICK + place // (BRICK * BRICK)
    j = (bv // gi % gj) * BRICK + place // BRICK % BRICK
    i = (bv % gi) * BRICK + place % BRICK
    out = (k >= nk) | (j >= nj) | (i >= ni)
    if out.any():
        n = int(np.flatnonzero(out)[0])
        raise IsplatError(f"{where}: voxel ({int(k[n])}, {int(j[n])}, {int(i[n])}) (k, j, i) of brick {int(bv[n])} "
                          f"lies outside the volume of shape {tuple(shape)}")
    return i + ni * (j + nj * k)


def place(shape, positions: np.ndarray, values: np.ndarray, fill=0) -> np.ndarray:
    """A full-shape array holding ``values`` at flat ``positions`` and ``fill`` elsewhere (positions checked in
    bounds by numpy)."""
    out = np.full(int(np.prod(shape)), fill, dtype=values.dtype)
    out[positions] = values
    return out.reshape(tuple(int(n) for n in shape))
