"""The range-runs layout's positions decoded the slow, obvious way, in NumPy (isplat.runsplace.place_runs is the
compiled reader; formats/runs.md §4): the tests' reference for it and for the writer's encoding."""

from __future__ import annotations

import numpy as np

from isplat.errors import IsplatError
from isplat.runs import BITMAP_BYTES, BRICK, BRICK_VOXELS, V1_LIST_MAX, brick_grid


def encode_group(places, version: int = 2) -> bytes:
    """The positions of one (run, brick) of increasing ``places`` (formats/runs.md §4). Version 2: the plane mask
    (bit dk set when plane dk = p // 64 holds a place), then for each plane set, in order, its row mask (bit dj =
    p // 8 % 8), then for each row set, in order (plane by plane), its voxel mask (bit di = p % 8). Version 1: at
    most V1_LIST_MAX places as uint16 little-endian, more as a bitmap of 64 bytes (place p at bit p % 8 of byte
    p // 8)."""
    places = [int(p) for p in places]
    if version == 1:
        if len(places) <= V1_LIST_MAX:
            return b"".join(p.to_bytes(2, "little") for p in places)
        bm = bytearray(BITMAP_BYTES)
        for p in places:
            bm[p // 8] |= 1 << (p % 8)
        return bytes(bm)
    plane_mask, rows, voxels = 0, {}, {}
    for p in places:
        plane_mask |= 1 << (p // 64)
        rows[p // 64] = rows.get(p // 64, 0) | 1 << (p // 8 % 8)
        voxels[p // 8] = voxels.get(p // 8, 0) | 1 << (p % 8)
    return bytes([plane_mask] + [rows[k] for k in sorted(rows)] + [voxels[r] for r in sorted(voxels)])


def encode_positions(group: np.ndarray, local: np.ndarray, counts: np.ndarray, version: int = 2) -> np.ndarray:
    """uint8: the positions of consecutive groups (each a (run, brick)): ``group`` [n] each voxel's group
    (0 .. len(counts) - 1, non-decreasing), ``local`` [n] its place in the brick (increasing within a group),
    ``counts`` each group's voxels; each group as :func:`encode_group`."""
    first = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    out = b"".join(encode_group(local[first[g]:first[g + 1]], version) for g in range(len(counts)))
    return np.frombuffer(out, dtype=np.uint8).copy()


def _bits(byte) -> list:
    return [t for t in range(8) if int(byte) >> t & 1]


def decode_positions(counts: np.ndarray, data: np.ndarray, where: str = "positions", version: int = 2) -> np.ndarray:
    """int64: each voxel's place in its brick, group after group, from ``counts`` (each group's voxels) and
    ``data`` (:func:`encode_positions`' bytes), one group after the other. Refuses (IsplatError naming ``where``)
    counts not 1..512, a length that does not match, masks or a bitmap whose voxels are not its count, a plane or
    row set without a bit below it, and a list's places not strictly increasing or not below 512."""
    counts = np.asarray(counts, dtype=np.int64)
    data = np.asarray(data, dtype=np.uint8)
    if (counts < 1).any() or (counts > BRICK_VOXELS).any():
        bad = int(np.flatnonzero((counts < 1) | (counts > BRICK_VOXELS))[0])
        raise IsplatError(f"{where}: brick {bad} of the run has {int(counts[bad])} voxels, expected 1 to 512")
    forms = "counts" if version == 1 else "masks"
    starts = [0]
    for c in counts.tolist():                   # first every brick's bytes, as the compiled reader checks them
        n = _group_bytes(data, starts[-1], c, version)
        if n is None:
            raise IsplatError(f"{where}: {data.size} bytes of positions, the bricks' {forms} make more")
        starts.append(starts[-1] + n)
    if starts[-1] != data.size:
        raise IsplatError(f"{where}: {data.size} bytes of positions, the bricks' {forms} make {starts[-1]}")
    out = [_decode_group(data[starts[b]:starts[b + 1]], c, version, f"{where}: brick {b} of the run")
           for b, c in enumerate(counts.tolist())]
    return np.concatenate(out) if out else np.zeros(0, dtype=np.int64)


def _group_bytes(data, q: int, c: int, version: int):
    """Bytes of the group from byte ``q``, or None when they pass the end of ``data``."""
    if version == 1:
        n = 2 * c if c <= V1_LIST_MAX else BITMAP_BYTES
    elif q >= data.size or q + 1 + len(_bits(data[q])) > data.size:
        return None
    else:
        planes = len(_bits(data[q]))
        n = 1 + planes + sum(len(_bits(x)) for x in data[q + 1:q + 1 + planes])
    return n if q + n <= data.size else None


def _decode_group(raw: np.ndarray, c: int, version: int, where: str) -> np.ndarray:
    if version == 1 and c <= V1_LIST_MAX:
        place = raw.view("<u2").astype(np.int64)
        if (place >= BRICK_VOXELS).any() or (np.diff(place) <= 0).any():
            n = int(np.flatnonzero((place >= BRICK_VOXELS) | np.r_[False, np.diff(place) <= 0])[0])
            raise IsplatError(f"{where}: place {int(place[n])}, expected places below 512, strictly increasing "
                              f"within the brick")
        return place
    if version == 1:
        places = [8 * y + t for y in range(BITMAP_BYTES) for t in _bits(raw[y])]
    else:
        planes = _bits(raw[0])
        row_masks, voxel_masks = list(raw[1:1 + len(planes)]), list(raw[1 + len(planes):])
        rows = []
        for dk, m in zip(planes, row_masks):
            if m == 0:
                raise IsplatError(f"{where}: plane {dk} is set in its masks but holds no voxel")
            rows += [dk * 8 + dj for dj in _bits(m)]
        places = []
        for row, m in zip(rows, voxel_masks):
            if m == 0:
                raise IsplatError(f"{where}: row ({row // 8}, {row % 8}) (dk, dj) is set in its masks but holds "
                                  f"no voxel")
            places += [row * 8 + di for di in _bits(m)]
    if len(places) != c:
        raise IsplatError(f"{where}: its positions hold {len(places)} voxels, its count says {c}")
    return np.array(places, dtype=np.int64)


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
