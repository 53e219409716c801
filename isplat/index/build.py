"""Build the per-axis density index in memory (paper §2.1, encoding §2.3; layout in formats/index.md)."""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from .. import progress
from ..errors import IsplatError
from ..grid import AXES, IN_SLICE_AXES, slice_coefficients, slice_shape
from . import codec

MAX_IN_SLICE = 65536                                # reach of the 2-byte escape
MAX_POSITIONS = 2**31 - 1                           # LoadedAxis positions are int32
SLAB_VOXELS = 1 << 22                               # voxels per kernel call (progress granularity)


@dataclass
class AxisIndex:
    """One axis of an index, the arrays exactly as stored under ``/axes/<axis>``."""

    axis: str
    n_slices: int
    n_a: int
    n_b: int
    escape_width: int
    density_entry_ptr: np.ndarray    # int64[257]
    entry_slice: np.ndarray          # uint32[E]
    entry_voxel_count: np.ndarray    # uint32[E]
    entry_byte_offset: np.ndarray    # int64[E + 1]
    bytes: np.ndarray                # uint8[B]

    @property
    def in_slice_axes(self) -> str:
        return IN_SLICE_AXES[self.axis]

    @property
    def n_entries(self) -> int:
        return int(self.entry_slice.shape[0])

    @property
    def nbytes(self) -> int:
        """Bytes of blocks and tables."""
        return sum(int(a.nbytes) for a in (self.density_entry_ptr, self.entry_slice, self.entry_voxel_count,
                                           self.entry_byte_offset, self.bytes))

    def block(self, density: int, slice_: int) -> bytes:
        """The encoded block of (density, slice), b"" when it has no entry."""
        r0, r1 = self.density_entry_ptr[density], self.density_entry_ptr[density + 1]
        rows = np.flatnonzero(self.entry_slice[r0:r1] == slice_)
        if rows.size == 0:
            return b""
        e = r0 + rows[0]
        return self.bytes[self.entry_byte_offset[e]:self.entry_byte_offset[e + 1]].tobytes()


axis_geometry = slice_shape      # ``(n_slices, n_a, n_b)`` of an axis (isplat.grid)


def escape_width(n_a: int, n_b: int) -> int:
    """1 (the paper's 0x00, i, j) when both in-slice sizes are <= 256, else 2 (§2.3, widened)."""
    if n_a > MAX_IN_SLICE or n_b > MAX_IN_SLICE:
        raise IsplatError(f"in-slice size {n_a}x{n_b} exceeds {MAX_IN_SLICE}, the reach of the escape")
    if n_a * n_b > MAX_POSITIONS:
        raise IsplatError(f"in-slice size {n_a}x{n_b} has more than 2^31-1 positions")
    return 1 if n_a <= 256 and n_b <= 256 else 2


def parse_axes(text: str) -> str:
    """Validate an ``--axes`` value (a non-empty subset of 'ijk'); return it in i, j, k order."""
    if not isinstance(text, str) or not text:
        raise IsplatError("--axes: expected a non-empty subset of 'ijk', e.g. 'ijk' or 'k'")
    bad = sorted(set(text) - set(AXES))
    if bad:
        raise IsplatError(f"--axes {text!r}: unknown axis letter {bad[0]!r}; expected letters from 'ijk'")
    if len(set(text)) != len(text):
        raise IsplatError(f"--axes {text!r}: an axis letter is repeated")
    return "".join(a for a in AXES if a in text)


def normalize_ranges(ranges) -> list[tuple[int, int]]:
    """Validate inclusive density ranges (0..255, lo <= hi); sort and merge overlapping or touching ones.

    ``None`` means everything: ``[(0, 255)]``.
    """
    if ranges is None:
        return [(0, 255)]
    out = []
    for r in ranges:
        try:
            lo, hi = r
        except (TypeError, ValueError):
            raise IsplatError(f"density range {r!r}: expected a pair (lo, hi)") from None
        if isinstance(lo, (bool, np.bool_)) or isinstance(hi, (bool, np.bool_)) or \
                not all(isinstance(x, (int, np.integer)) for x in (lo, hi)):
            raise IsplatError(f"density range {r!r}: expected whole numbers")
        lo, hi = int(lo), int(hi)
        if not (0 <= lo <= 255 and 0 <= hi <= 255):
            raise IsplatError(f"density range {lo}:{hi}: densities are 0..255")
        if lo > hi:
            raise IsplatError(f"density range {lo}:{hi}: reversed (LO must be <= HI)")
        out.append((lo, hi))
    out.sort()
    merged: list[tuple[int, int]] = []
    for lo, hi in out:
        if merged and lo <= merged[-1][1] + 1:
            merged[-1] = (merged[-1][0], max(merged[-1][1], hi))
        else:
            merged.append((lo, hi))
    return merged


_RANGE_RE = re.compile(r"^\s*(\d{1,3})\s*(?::\s*(\d{1,3})\s*)?$")


def parse_ranges(text: str) -> list[tuple[int, int]]:
    """Parse ``--densities LO:HI[,LO:HI...]`` (a single ``D`` means ``D:D``) into merged ranges."""
    if text is None or not str(text).strip():
        raise IsplatError("--densities: empty; expected LO:HI[,LO:HI...] with 0 <= LO <= HI <= 255")
    ranges = []
    for part in str(text).split(","):
        m = _RANGE_RE.match(part)
        if not m:
            raise IsplatError(f"--densities: {part.strip()!r} is not LO:HI (whole numbers 0..255)")
        lo = int(m.group(1))
        hi = int(m.group(2)) if m.group(2) is not None else lo
        ranges.append((lo, hi))
    return normalize_ranges(ranges)


def ranges_mask(ranges) -> np.ndarray:
    """bool[256], True for the densities inside ``ranges``."""
    m = np.zeros(256, dtype=np.bool_)
    for lo, hi in normalize_ranges(ranges):
        m[lo:hi + 1] = True
    return m


def _slabs(n_k: int, n_ji: int):
    step = max(1, SLAB_VOXELS // max(1, n_ji))
    return [(k0, min(n_k, k0 + step)) for k0 in range(0, n_k, step)]


def build_axis(density: np.ndarray, axis: str, ranges=None) -> AxisIndex:
    """Index one axis of ``density[k, j, i]`` (uint8) for the densities in ``ranges`` (§2.1, §2.3).

    Two passes over the volume: the first measures every (density, slice) block, which fixes the
    density-major layout; the second writes each block's bytes in place.
    """
    density = _check_density(density)
    n_slices, n_a, n_b = axis_geometry(density.shape, axis)
    ew = escape_width(n_a, n_b)
    coef = slice_coefficients(density.shape, axis)
    indexed = ranges_mask(ranges)
    slabs = _slabs(density.shape[0], density.shape[1] * density.shape[2])

    prev = np.full((n_slices, 256), -1, dtype=np.int64)
    counts = np.zeros((256, n_slices), dtype=np.int64)
    lengths = np.zeros((256, n_slices), dtype=np.int64)
    with progress.bar(total=2 * density.shape[0], desc=f"index {axis}", unit="slice") as pb:
        for k0, k1 in slabs:
            codec.measure_slab(density, k0, k1, coef, indexed, codec.escape_cost(ew), prev, counts, lengths)
            pb.update(k1 - k0)

        # density-major entries: by density, then by slice (formats/index.md)
        present = counts > 0
        ptr = np.zeros(257, dtype=np.int64)
        np.cumsum(present.sum(axis=1), out=ptr[1:])
        d_idx, s_idx = np.nonzero(present)
        del d_idx
        offsets = np.zeros(s_idx.size + 1, dtype=np.int64)
        np.cumsum(lengths[present], out=offsets[1:])
        if int(counts.max(initial=0)) > np.iinfo(np.uint32).max:
            raise IsplatError("a block holds more than 2^32-1 voxels")
        cursor = np.zeros((256, n_slices), dtype=np.int64)
        cursor[present] = offsets[:-1]
        out = np.empty(int(offsets[-1]), dtype=np.uint8)

        prev.fill(-1)
        for k0, k1 in slabs:
            codec.encode_slab(density, k0, k1, coef, indexed, n_a, ew, prev, cursor, out)
            pb.update(k1 - k0)
    if not np.array_equal(cursor[present], offsets[1:]):   # every block filled exactly
        raise AssertionError("index encoder: block lengths disagree between passes")
    return AxisIndex(axis, n_slices, n_a, n_b, ew, ptr, s_idx.astype(np.uint32),
                     counts[present].astype(np.uint32), offsets, out)


@dataclass
class ChannelValues:
    """The channel values of the indexed voxels, stored once under ``/values`` (formats/index.md §9): voxels
    ordered by density, then by flat position ``i + n_i * (j + n_j * k)``; the values of density ``d`` are rows
    ``density_voxel_ptr[d] .. density_voxel_ptr[d + 1] - 1``. ``spacing_ijk`` and ``gradient_magnitude_scale``
    are those of the augmented file the values were copied from."""

    density_voxel_ptr: np.ndarray    # int64[257]
    gradient_magnitude: np.ndarray   # uint8[V]
    normal: np.ndarray               # uint16[V]
    spacing_ijk: tuple
    gradient_magnitude_scale: float


def value_rows(density_flat: np.ndarray, indexed: np.ndarray, cursor: np.ndarray):
    """For one run of voxels in position order (a k-slab, flattened): the offsets of those whose density is
    ``indexed`` (bool[256]) and their rows in the values arrays, density-major then by position, where
    ``cursor[d]`` (int64[256]) is the next row of density ``d``; advances ``cursor``.

    >>> cur = np.array([0] * 5 + [3] + [0] * 250, np.int64)     # density 5 starts at row 3
    >>> off, rows = value_rows(np.array([5, 0, 3, 5, 3], np.uint8), np.arange(256) > 0, cur)
    >>> off.tolist(), rows.tolist(), int(cur[3]), int(cur[5])
    ([2, 4, 0, 3], [0, 1, 3, 4], 2, 5)
    """
    off = np.flatnonzero(indexed[density_flat])
    d = density_flat[off]
    order = np.argsort(d, kind="stable")           # radix sort of uint8: O(n), keeps position order per density
    off, d = off[order], d[order]
    counts = np.bincount(d, minlength=256).astype(np.int64)
    first = np.zeros(256, dtype=np.int64)
    np.cumsum(counts[:-1], out=first[1:])
    rows = np.arange(d.size, dtype=np.int64) + (cursor - first)[d]
    cursor += counts
    return off, rows


def order_values(density, gradient_magnitude, normal, ranges=None, spacing_ijk=(1.0, 1.0, 1.0),
                 gradient_magnitude_scale=1.0) -> ChannelValues:
    """The :class:`ChannelValues` of volumes held in memory (``[k, j, i]``) for the densities in ``ranges``."""
    density = _check_density(density)
    d = density.ravel()
    indexed = ranges_mask(ranges)
    counts = np.where(indexed, np.bincount(d, minlength=256), 0).astype(np.int64)
    ptr = np.zeros(257, dtype=np.int64)
    np.cumsum(counts, out=ptr[1:])
    off, rows = value_rows(d, indexed, ptr[:-1].copy())
    gm = np.empty(int(ptr[-1]), dtype=np.uint8)
    nrm = np.empty(int(ptr[-1]), dtype=np.uint16)
    gm[rows] = np.asarray(gradient_magnitude, dtype=np.uint8).reshape(-1)[off]
    nrm[rows] = np.asarray(normal, dtype=np.uint16).reshape(-1)[off]
    return ChannelValues(ptr, gm, nrm, tuple(float(x) for x in spacing_ijk), float(gradient_magnitude_scale))


def build_index(density: np.ndarray, axes: str = "ijk", ranges=None) -> dict[str, AxisIndex]:
    """Index ``density[k, j, i]`` (uint8) along each of ``axes`` for the densities in ``ranges``."""
    axes = parse_axes(axes)
    density = _check_density(density)
    return {a: build_axis(density, a, ranges) for a in axes}


def _check_density(density) -> np.ndarray:
    d = np.asarray(density)
    if d.ndim != 3 or min(d.shape) < 1:
        raise IsplatError(f"density must be a non-empty 3-D array [k, j, i], got shape {d.shape}")
    if d.dtype != np.uint8:
        raise IsplatError(f"density must be uint8, got {d.dtype}")
    return np.ascontiguousarray(d)
