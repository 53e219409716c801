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


def slice_runs(slices, n_slices: int) -> list[tuple[int, int]]:
    """The distinct slice indices of ``slices`` as sorted runs ``[s0, s1)`` of consecutive indices."""
    s = np.unique(np.asarray(slices, dtype=np.int64))
    if s.size and (s[0] < 0 or s[-1] >= n_slices):
        raise IsplatError(f"slab slices {int(s[0])}..{int(s[-1])} outside 0..{n_slices - 1}")
    if s.size == 0:
        return []
    breaks = np.flatnonzero(np.diff(s) != 1) + 1
    starts = np.r_[s[0], s[breaks]]
    stops = np.r_[s[breaks - 1] + 1, s[-1] + 1]
    return [(int(a), int(b)) for a, b in zip(starts, stops)]


def ranges_mask(ranges) -> np.ndarray:
    """bool[256], True for the densities inside ``ranges``."""
    m = np.zeros(256, dtype=np.bool_)
    for lo, hi in normalize_ranges(ranges):
        m[lo:hi + 1] = True
    return m


def k_slabs(n_k: int, plane: int, voxels: int = SLAB_VOXELS, align: int = 1) -> list[tuple[int, int]]:
    """Runs ``(k0, k1)`` of whole k-planes of about ``voxels`` voxels (at least one plane) covering ``0 .. n_k``;
    ``align``: each run a whole number of layers of that many planes (a bricked file's brick layers, which it
    reads whole: a slab inside a layer would read and check the layer again for each slab)."""
    step = max(1, int(voxels) // max(1, int(plane)))
    step = -(-step // max(1, int(align))) * max(1, int(align))
    return [(k0, min(n_k, k0 + step)) for k0 in range(0, n_k, step)]


@dataclass
class AxisLayout:
    """What the measuring pass fixes for one axis: its tables (density-major entries, formats/index.md §4) and
    where each (density, slice) block starts and ends in the byte stream (``block_start``/``block_end``
    int64[256, n_slices], 0 for absent blocks)."""

    axis: str
    n_slices: int
    n_a: int
    n_b: int
    escape_width: int
    coef: np.ndarray
    indexed: np.ndarray              # bool[256]
    present: np.ndarray              # bool[256, n_slices]
    block_start: np.ndarray
    block_end: np.ndarray
    density_entry_ptr: np.ndarray
    entry_slice: np.ndarray
    entry_voxel_count: np.ndarray
    entry_byte_offset: np.ndarray

    @property
    def n_bytes(self) -> int:
        return int(self.entry_byte_offset[-1])

    def tables(self, data: np.ndarray | None = None) -> AxisIndex:
        """The axis as an :class:`AxisIndex` with byte stream ``data`` (empty placeholder when None)."""
        return AxisIndex(self.axis, self.n_slices, self.n_a, self.n_b, self.escape_width, self.density_entry_ptr,
                         self.entry_slice, self.entry_voxel_count, self.entry_byte_offset,
                         np.zeros(0, np.uint8) if data is None else data)


def measure_axes(read, shape, axes: str, ranges=None, slabs=None) -> dict[str, AxisLayout]:
    """One pass over the k-slabs ``read(k0, k1)`` (uint8 planes ``k0:k1`` of a volume of ``shape``) measures
    every (density, slice) block of each of ``axes``: voxel counts and encoded lengths, hence the tables."""
    axes = parse_axes(axes)
    indexed = ranges_mask(ranges)
    slabs = slabs or k_slabs(shape[0], shape[1] * shape[2])
    state = {}
    for a in axes:
        n_slices, n_a, n_b = axis_geometry(shape, a)
        ew = escape_width(n_a, n_b)
        state[a] = (slice_coefficients(shape, a), codec.escape_cost(ew), np.full((n_slices, 256), -1, np.int64),
                    np.zeros((256, n_slices), np.int64), np.zeros((256, n_slices), np.int64))
    with progress.bar(total=int(shape[0]), desc=f"index {axes}: measure", unit="slice") as pb:
        for k0, k1 in slabs:
            planes = _check_planes(read(k0, k1), k1 - k0, shape)
            for coef, esc, prev, counts, lengths in state.values():
                codec.measure_slab(planes, k0, coef, indexed, esc, prev, counts, lengths)
            pb.update(k1 - k0)
    out = {}
    for a, (coef, _, prev, counts, lengths) in state.items():
        del prev
        n_slices, n_a, n_b = axis_geometry(shape, a)
        if int(counts.max(initial=0)) > np.iinfo(np.uint32).max:
            raise IsplatError("a block holds more than 2^32-1 voxels")
        present = counts > 0
        ptr = np.zeros(257, dtype=np.int64)
        np.cumsum(present.sum(axis=1), out=ptr[1:])
        s_idx = np.nonzero(present)[1]                      # density-major: by density, then slice
        offsets = np.zeros(s_idx.size + 1, dtype=np.int64)
        np.cumsum(lengths[present], out=offsets[1:])
        start = np.zeros((256, n_slices), np.int64)
        end = np.zeros((256, n_slices), np.int64)
        start[present], end[present] = offsets[:-1], offsets[1:]
        out[a] = AxisLayout(a, n_slices, n_a, n_b, escape_width(n_a, n_b), coef, indexed, present, start, end, ptr,
                            s_idx.astype(np.uint32), counts[present].astype(np.uint32), offsets)
    return out


def encode_windows(read, shape, layout: AxisLayout, budget: int | None = None, slabs=None):
    """The byte stream of ``layout``'s axis in windows of at most ``budget`` bytes (None: one window), in order:
    yields ``(first byte, uint8 window)``. Each window is one pass over the k-slabs ``read(k0, k1)`` that hold
    a block reaching into it, encoding only the densities whose blocks do (codec.encode_slab keeps the bytes
    inside the window); along axis k a block lies in one k-plane, so only those planes are read."""
    lay = layout
    slabs = slabs or k_slabs(shape[0], shape[1] * shape[2])
    total = lay.n_bytes
    width = max(1, total if budget is None else int(budget))
    prev = np.full((lay.n_slices, 256), -1, np.int64)
    cursor = np.zeros((256, lay.n_slices), np.int64)
    with progress.bar(total=int(shape[0]) * -(-total // width), desc=f"index {lay.axis}", unit="slice") as pb:
        for o0 in range(0, total, width):
            o1 = min(total, o0 + width)
            hit = lay.present & (lay.block_start < o1) & (lay.block_end > o0)
            active = lay.indexed & hit.any(axis=1)
            planes_hit = hit.any(axis=0) if lay.axis == "k" else None
            prev.fill(-1)
            cursor[...] = lay.block_start
            out = np.empty(o1 - o0, dtype=np.uint8)
            for k0, k1 in slabs:
                if planes_hit is None or planes_hit[k0:k1].any():
                    planes = _check_planes(read(k0, k1), k1 - k0, shape)
                    codec.encode_slab(planes, k0, lay.coef, active, lay.n_a, lay.escape_width, prev, cursor, out, o0)
                pb.update(k1 - k0)
            if not np.array_equal(cursor[hit], lay.block_end[hit]):      # every block of the window filled exactly
                raise AssertionError("index encoder: block lengths disagree between passes")
            yield o0, out
            del out                                  # the caller has written it: one window alive at a time


def build_axis(density: np.ndarray, axis: str, ranges=None) -> AxisIndex:
    """Index one axis of ``density[k, j, i]`` (uint8) for the densities in ``ranges`` (§2.1, §2.3).

    Two passes over the volume: the first measures every (density, slice) block, which fixes the
    density-major layout; the second writes each block's bytes in place.
    """
    density = _check_density(density)
    read = lambda k0, k1: density[k0:k1]        # noqa: E731
    lay = measure_axes(read, density.shape, axis, ranges)[axis]
    parts = [w for _, w in encode_windows(read, density.shape, lay)]
    return lay.tables(parts[0] if parts else np.zeros(0, np.uint8))


def _check_planes(planes, n: int, shape) -> np.ndarray:
    planes = np.ascontiguousarray(planes)
    if planes.dtype != np.uint8 or planes.shape != (n, shape[1], shape[2]):
        raise IsplatError(f"density slab of shape {planes.shape} ({planes.dtype}), expected {(n, *shape[1:])} uint8")
    return planes


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
