"""The augmented-volume container (formats/augmented.md), version 6 (versions 5, 4 and 3 read too).

Three datasets of one shape ``(n_k, n_j, n_i)``, C order, i fastest (the paper's ``ind = i + j * n_i``):

* ``density``             uint8  -- the windowed density (§2.1, one byte)
* ``gradient_magnitude``  uint8  -- |grad| quantised, ``code * gradient_magnitude_scale``
* ``normal``              uint16 -- octahedral 16-bit code of the gradient direction (:mod:`isplat.normals`)

and, OPTIONAL since version 4, ``labels`` (uint8 or uint16, a segmentation's label id per voxel, 0 = none) with
``label_voxels`` (int64[L + 1], the voxels of each id). Together the first three are the paper's 4-byte
augmented voxel, stored as three channels so that a scene reads
only the channels it uses (no normals when shading is off, no magnitudes when the transfer function
ignores them).

Since version 6 each channel is stored as its bricks (``[n_bricks, e, e, e]``, contiguous, brick order) with a
64-bit hash per brick (:mod:`isplat.brickstore`, formats/augmented.md §2.3); readers see the same arrays.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from . import chunkhash
from .errors import IsplatError
from .fileio import (ReadAttrs, ReadCounter, attr_array, attr_string, attr_values, check_checked_dataset,
                     check_string_attrs, create_checked_dataset, create_hdf5, hdf5_errors, open_counted, open_hdf5,
                     set_string_attr)
from .orientation import check_axes_lps

FORMAT_NAME = "isplat-augmented"
FORMAT_VERSION = 6              # version 6: isplat's own brick store + /brick_hashes (formats/augmented.md §2.3)
ROWS_VERSION = 4                # what `isplat augment --rows` writes: chunks of whole rows (docs/design.md)
OLDER_VERSIONS = (5, 4, 3)      # 5: 8^3 bricks as HDF5 chunks (§2.2), read brick by brick; 4: + the optional label
                                # channel (§2.1); 3: + /chunk_hashes (§1.1); 4 and 3 read whole
BRICK = (8, 8, 8)               # (k, j, i) voxels of a brick: the channels' HDF5 chunk (version 5)
BRICK_EDGES = (4, 8)            # version 6: the brick edges a file may have (attribute brick_edge)
BRICK_EDGE = 8                  # version 6: the edge `isplat augment` writes (docs/design.md, "Bricked channels")
BRICK_HASHES = "brick_hashes"   # version 6: group of uint64[n_bricks] tables, one per stored channel
BRICK_RANGE = "brick_range"     # uint8[gk, gj, gi, 2]: each brick's smallest and largest density code
LABELS = "labels"
LABEL_VOXELS = "label_voxels"
LABEL_DTYPES = {"|u1": np.uint8, "<u2": np.uint16}
CHANNELS = {"density": np.uint8, "gradient_magnitude": np.uint8, "normal": np.uint16}
CHANNEL_DTYPES = {"density": "|u1", "gradient_magnitude": "|u1", "normal": "<u2"}
OPTIONAL_STRINGS = ("source", "source_format", "source_dtype", "density_window_method", "labels_sha256")
# the attributes the file key covers (formats/augmented.md §1.1): every attribute of §3 but created_by, in its order
HASHED_ATTRIBUTES = tuple(("", n) for n in (
    "format", "format_version", "shape", "spacing_ijk", "density_window", "gradient_magnitude_scale", "density_sha256",
    "source", "source_format", "source_dtype", "density_window_method", "density_units",
    "density_clipped_fraction", "axes_lps", "labels_sha256"))


def hashed_attributes(version: int) -> tuple:
    """The attributes the file key covers: version 6 adds ``brick_edge`` (formats/augmented.md §1.1)."""
    return HASHED_ATTRIBUTES + ((("", "brick_edge"),) if version >= 6 else ())


def labels_sha256(labels: np.ndarray) -> str:
    """Identity of a label channel: SHA-256 of its shape (3 little-endian int64) then its ids as little-endian
    uint16 in C order (whatever the stored type), so an index of the labels can be tied to them."""
    h = hashlib.sha256(np.asarray(labels.shape, dtype="<i8").tobytes())
    a = np.asarray(labels)
    step = max(1, (1 << 25) // max(1, a[0].size))
    for k0 in range(0, a.shape[0], step):
        h.update(np.ascontiguousarray(a[k0:k0 + step], dtype="<u2").tobytes())
    return h.hexdigest()


def density_sha256(density: np.ndarray) -> str:
    """Identity of a density channel: SHA-256 of its shape (3 little-endian int64) then its bytes in C order."""
    h = hashlib.sha256(np.asarray(density.shape, dtype="<i8").tobytes())
    d = np.ascontiguousarray(density, dtype=np.uint8)
    # hash slab by slab so that a memory map is never copied whole
    step = max(1, (1 << 26) // max(1, d[0].size))
    for k0 in range(0, d.shape[0], step):
        h.update(np.ascontiguousarray(d[k0:k0 + step]).tobytes())
    return h.hexdigest()


@dataclass
class AugmentedVolume:
    """An open augmented file: metadata read eagerly, channels read on demand (and counted)."""

    path: Path
    shape: tuple[int, int, int]                  # (n_k, n_j, n_i)
    spacing_ijk: tuple[float, float, float]
    density_window: tuple[float, float]
    gradient_magnitude_scale: float
    density_sha256: str
    attrs: dict = field(default_factory=dict)
    bytes_read: int = 0                          # bytes of the channel slabs requested
    io: ReadCounter = field(default_factory=ReadCounter)   # what HDF5 read from the file (opening included)
    axes_lps: np.ndarray | None = None           # rows: LPS unit vectors of i, j, k; None = orientation unknown
    verifier: object = None                      # isplat.chunkhash.Verifier: checks each chunk read
    label_voxels: np.ndarray | None = None       # int64[L + 1]: voxels per label id; None: the file has no labels
    format_version: int = FORMAT_VERSION
    brick_grid: tuple | None = None               # version 5, 6: (gk, gj, gi) bricks; None: channels read whole
    store: dict | None = None                     # version 6: channel -> (data offset, hash offset, dtype, seed)
    edge: int = 0                                 # version 6: the brick edge
    _brick_range: np.ndarray | None = field(default=None, repr=False)   # /brick_range once read

    @property
    def bricked(self) -> bool:
        """True when the channels are stored in bricks (version 5 or 6) and can be read brick by brick."""
        return self.brick_grid is not None

    @property
    def brick_range(self) -> np.ndarray | None:
        """uint8[gk, gj, gi, 2] (version 5, 6; None otherwise): each brick's smallest and largest density code,
        read from ``/brick_range`` on first use (a density brick read checks against it; pre reads no density
        brick, so never reads it), its chunks checked against their hashes and every row checked (min <= max);
        counted in :attr:`io`. Its presence, type and shape were checked at open."""
        if self._brick_range is None and self.bricked:
            with hdf5_errors(self.path, f"dataset {BRICK_RANGE!r}"), open_counted(self.path, self.io) as f:
                self._brick_range = _read_brick_range(self.path, f, self.verifier)
        return self._brick_range

    @property
    def bricks(self) -> tuple:
        """The brick shape (k, j, i) of a version-5 or -6 file."""
        return (self.edge,) * 3 if self.store is not None else brick_chunks(self.shape)

    def read_bricks(self, channel: str, bricks: np.ndarray, box=None) -> np.ndarray:
        """The whole ``channel`` (shape ``shape``) holding only the bricks whose grid indices are the rows of
        ``bricks`` (int64[n, 3], C order of the grid, unique), zero elsewhere (``np.zeros``: pages never written
        are not held: :func:`lazy_zeros`); each brick checked against its chunk hash, and the density's against
        ``brick_range``
        (its smallest and largest code). ``box``: ``(lo, hi)`` (k, j, i) element bounds: the array holds just
        that block (a slab's slices). Adds the bricks' bytes to :attr:`bytes_read`."""
        if channel not in CHANNELS:
            raise IsplatError(f"{self.path}: unknown channel {channel!r}; expected one of {sorted(CHANNELS)}")
        lo, hi = box if box is not None else ((0, 0, 0), self.shape)
        out = lazy_zeros(tuple(int(b) - int(a) for a, b in zip(lo, hi)), CHANNELS[channel])
        bricks = np.asarray(bricks, dtype=np.int64).reshape(-1, 3)
        with hdf5_errors(self.path, f"dataset {channel!r}"):
            with self._open_channels(channel) as f:
                n = self._read_into(f, channel, bricks, out, lo, bulk=self._bulk(channel, bricks.shape[0]))
        self.bytes_read += n * out.itemsize
        return out

    def read_pool(self, channel: str, bricks: np.ndarray) -> np.ndarray:
        """The bricks ``bricks`` (grid indices, int64[n, 3], C order of the grid, unique) of ``channel`` as the rows
        of a pool (isplat.selection.WholeChannels): flat, ``(n + 1) * edge^3`` elements, row 0 zeros, row ``r + 1``
        brick ``r`` in C order (its part outside the volume zeros). Checked as :meth:`read_bricks`; version 6
        only (isplat's brick store). Adds the bricks' bytes to :attr:`bytes_read`."""
        if channel not in CHANNELS or self.store is None:
            raise IsplatError(f"{self.path}: a pool of {channel!r} bricks needs a format 6 file with that channel")
        e, bricks = self.edge, np.asarray(bricks, dtype=np.int64).reshape(-1, 3)
        out = np.zeros(((bricks.shape[0] + 1) * e, e, e), dtype=CHANNELS[channel])
        to = np.zeros_like(bricks)
        to[:, 0] = (np.arange(bricks.shape[0]) + 1) * e        # brick r at row r + 1
        with hdf5_errors(self.path, f"dataset {channel!r}"):
            n = self._read_into(None, channel, bricks, out, (0, 0, 0), to=to)
        self.bytes_read += n * out.itemsize
        return out.reshape(-1)

    def _read_into(self, f, channel: str, bricks: np.ndarray, out: np.ndarray, lo, bulk: bool = False,
                   to=None) -> int:
        """Bricks ``bricks`` of ``channel`` into ``out`` (the block from element ``lo``; ``to``: each brick's
        first element there, when not its place in the volume: a pool's rows), each checked against its
        chunk hash and, for the density, against ``brick_range``; returns the elements read."""
        if self.store is not None:
            n, mm = self._read_store(channel, bricks, out, lo, to)
        else:
            n, mm = self.verifier.read_bricks_direct(f, channel, bricks, out, tuple(int(x) for x in lo),
                                                     minmax=True, bulk=bulk)
        if channel == "density" and bricks.shape[0]:
            want = self.brick_range[tuple(bricks.T)]
            bad = np.flatnonzero(np.any(mm != want, axis=1))
            if bad.size:
                self._range_error(bricks[bad[0]], mm[bad[0]], want[bad[0]])
        return n

    def _read_store(self, channel: str, bricks: np.ndarray, out: np.ndarray, lo, to=None):
        """Version 6: bricks ``bricks`` (grid indices) of ``channel`` from the brick store into ``out`` (the block
        from element ``lo``), read from memory maps of the file (offsets checked at open) by one compiled pass per
        window of the store (:func:`isplat.brickstore.check_place`: each brick hashed and compared with its stored
        hash, then ranged and placed straight into ``out``, no copy between); returns the elements read and, for the
        density, each brick's (min, max) within the volume."""
        from . import brickstore

        e, n = self.edge, bricks.shape[0]
        grid = tuple(-(-s // e) for s in self.shape)
        if n == 0:
            return 0, np.zeros((0, 2), np.uint8)
        if bricks.min() < 0 or np.any(bricks.max(axis=0) >= np.asarray(grid)):
            raise IsplatError(f"{self.path}: dataset '{channel}': a brick outside its grid {grid} was asked for")
        d_off, h_off, dt, seed = self.store[channel]
        nb, size = int(np.prod(grid)), e ** 3 * np.dtype(dt).itemsize
        rows = np.ravel_multi_index(tuple(bricks.T), grid)
        have = os.path.getsize(self.path)
        if have < max(d_off + nb * size, h_off + nb * 8):          # (checked at open; the file may have changed)
            raise IsplatError(f"{self.path}: dataset '{channel}': the file is {have} bytes, shorter than its "
                              f"bricks and hashes (changed since it was opened?); rebuild it: {self.verifier.rebuild}")
        offs = bricks * e
        ext = np.minimum(e, np.asarray(self.shape, dtype=np.int64) - offs)
        offs = offs if to is None else np.asarray(to, dtype=np.int64)
        mm_ = np.zeros((n if channel == "density" else 0, 2), np.uint8)
        bad, lo = -1, np.asarray(lo, dtype=np.int64)
        for r0, pick, data, stored in _store_windows(self.path, d_off, h_off, size, rows):
            got = brickstore.check_place(data.view(np.dtype(dt)).reshape(-1, e, e, e), data.view("<u8").reshape(
                -1, size // 8), stored, r0, rows, pick, np.uint64(seed), offs, ext, lo, out, mm_)
            if got == -2:
                raise AssertionError("a brick outside its window of the store")    # (windows are made from rows)
            bad = got if bad < 0 or 0 <= got < bad else bad
        if bad >= 0:
            at = ", ".join(str(int(x) * e) for x in bricks[bad])
            raise IsplatError(f"{self.path}: dataset '{channel}', brick {int(rows[bad])} at ({at}): its content "
                              f"does not match its hash in /{BRICK_HASHES}/{channel} (changed, moved or copied from "
                              f"elsewhere); rebuild it: {self.verifier.rebuild}")
        self.io.bytes += n * (size + 8)
        self.io.reads += 1
        self.io.touch_rows(d_off, size, rows)
        self.io.touch_rows(h_off, 8, rows)
        return int(np.prod(ext, axis=1).sum()), (mm_ if channel == "density" else None)

    def _bulk(self, channel: str, n: int) -> bool:
        """Read ``n`` bricks of ``channel`` through HDF5's chunk index walked once (about 1.6 us a brick of the
        channel) rather than each raw through HDF5 (about 5 us a brick read): for more than a quarter of the bricks,
        or once walked. (k-slabs of whole planes too: a sweep, as ``isplat index`` or pre with ``--slabs`` read.)"""
        return self.store is None and (4 * n > int(np.prod(self.brick_grid)) or channel in self.verifier._places)

    def _read_bricked_block(self, f, channel: str, block) -> np.ndarray:
        """``channel[block]`` of a version-5 file: the bricks the block touches, read raw a layer of bricks
        (about 16 MiB) at a time (:meth:`_read_into`)."""
        sel = tuple(block) + (slice(None),) * (3 - len(block))
        bounds = [s.indices(n)[:2] for s, n in zip(sel, self.shape)]
        lo = [a for a, _ in bounds]
        hi = [max(a, b) for a, b in bounds]
        dt = self.store[channel][2] if self.store is not None else f[channel].dtype
        out = np.empty(tuple(b - a for a, b in zip(lo, hi)), dtype=np.dtype(dt).newbyteorder("="))
        if out.size == 0:
            return out
        c = self.bricks
        g = [np.arange(a // e, -(-b // e)) for a, b, e in zip(lo, hi, c)]
        step = max(1, (1 << 24) // max(1, c[0] * out.shape[1] * out.shape[2] * out.itemsize))
        bulk = self._bulk(channel, g[0].size * g[1].size * g[2].size) or out.shape[1:] == tuple(self.shape[1:])
        for n0 in range(0, g[0].size, step):
            mesh = np.meshgrid(g[0][n0:n0 + step], g[1], g[2], indexing="ij")
            self._read_into(f, channel, np.stack([m.reshape(-1) for m in mesh], axis=1), out, lo, bulk=bulk)
        return out

    def _range_error(self, g, got, want):
        off = ", ".join(str(int(x) * int(e)) for x, e in zip(g, self.bricks))
        raise IsplatError(f"{self.path}: dataset 'density', brick at ({off}): densities {int(got[0])}..{int(got[1])}, "
                          f"/{BRICK_RANGE} says {int(want[0])}..{int(want[1])}; rebuild it: {self.verifier.rebuild}")

    @contextlib.contextmanager
    def _open_channels(self, channel: str = "density"):
        """The file opened to read channel chunks. Version 5: HDF5's own file driver (h5py's Python file object
        costs about 8 us per chunk, as much as the read, and a whole channel is 2,000 bricks per M voxels), the
        bytes read counted as the chunks checked times their stored size (elements + 4-byte checksum; the chunk
        index HDF5 reads to find them is not counted); older versions: counted at the file object."""
        if not self.bricked:
            with open_counted(self.path, self.io) as f:
                yield f
            return
        if self.store is not None:         # version 6: read by file offset, counted by _read_store
            yield None
            return
        n0 = self.verifier.chunks_verified
        size = int(np.prod(self.bricks)) * np.dtype(CHANNELS.get(channel, np.uint16)).itemsize + 4
        with h5py.File(self.path, "r") as f:
            if channel == LABELS:
                size = int(np.prod(self.bricks)) * f[LABELS].dtype.itemsize + 4
            try:
                yield f
            finally:
                n = self.verifier.chunks_verified - n0
                self.io.bytes += n * size
                self.io.reads += n
                self.io.pages_known = n == 0 and self.io.pages_known   # (where HDF5 put the chunks: not seen)

    @property
    def has_labels(self) -> bool:
        return self.label_voxels is not None

    def labels_present(self) -> np.ndarray:
        """The label ids (> 0) that some voxel has, increasing (empty without labels)."""
        if self.label_voxels is None:
            return np.zeros(0, np.int64)
        return np.flatnonzero(self.label_voxels[1:] > 0) + 1

    @property
    def n_voxels(self) -> int:
        return int(np.prod(self.shape))

    def read(self, channel: str, k0: int = 0, k1: int | None = None) -> np.ndarray:
        """Read one channel (optionally the k-slab ``k0:k1``) into memory; adds to :attr:`bytes_read`."""
        return self.read_block(channel, (slice(k0, k1),))

    def read_block(self, channel: str, block=()) -> np.ndarray:
        """``channel[block]`` (a tuple of slices with step 1, e.g. ``(slice(None), slice(j0, j1))``) into memory,
        every chunk it touches checked against the file's chunk hashes; adds to :attr:`bytes_read`."""
        if channel == LABELS and self.has_labels:
            return self._read_labels(block)
        if channel not in CHANNELS:
            raise IsplatError(f"{self.path}: unknown channel {channel!r}; expected one of {sorted(CHANNELS)}")
        with hdf5_errors(self.path, f"dataset {channel!r}"):
            with self._open_channels(channel) as f:
                arr = (self._read_bricked_block(f, channel, block) if self.bricked else
                       self.verifier.read(f, channel, tuple(block)))
        arr = np.ascontiguousarray(arr, dtype=CHANNELS[channel])
        self.bytes_read += arr.nbytes
        return arr

    def read_open(self, f, channel: str, block=()) -> np.ndarray:
        """``channel[block]`` from ``f``, this file already open (a builder's handle), checked as :meth:`read_block`
        checks it (bricks raw with their hashes and the density's ranges, or chunks through HDF5); not counted."""
        if self.bricked:
            return self._read_bricked_block(f, channel, block)
        return self.verifier.read(f, channel, tuple(block))

    def _read_labels(self, block) -> np.ndarray:
        """``labels[block]`` as uint16 (whatever the stored type), each chunk checked, and every id checked to be
        one ``label_voxels`` counts (< its length): compiled code may index tables by them."""
        with hdf5_errors(self.path, f"dataset {LABELS!r}"):
            with self._open_channels(LABELS) as f:
                arr = (self._read_bricked_block(f, LABELS, block) if self.bricked else
                       self.verifier.read(f, LABELS, tuple(block)))
        self.bytes_read += arr.nbytes
        arr = np.ascontiguousarray(arr, dtype=np.uint16)
        if arr.size and int(arr.max()) >= self.label_voxels.shape[0]:
            raise IsplatError(f"{self.path}: dataset 'labels' holds id {int(arr.max())}, expected ids below "
                              f"{self.label_voxels.shape[0]} (the length of 'label_voxels')")
        return arr

    def verify_all(self) -> None:
        """Check every chunk of the channels against the file's chunk hashes (``isplat stats``)."""
        if self.bricked:                  # the bricked datasets read raw, brick by brick (and the density's ranges)
            for ch in list(CHANNELS) + ([LABELS] if self.has_labels else []):
                self.read_block(ch) if ch != LABELS else self._read_labels(())
        with hdf5_errors(self.path, "channels"), open_counted(self.path, self.io) as f:
            for ch in hashed_datasets(self.has_labels, self.format_version):
                if not (self.bricked and ch in (*CHANNELS, LABELS)):
                    self.verifier.verify_all(f, ch)


STORE_WINDOW = 1 << 26      # bytes of a brick store mapped at a time: a read's address space stays small (a 1024^3
#                             volume's channels are 1-2 GiB; docs/scale.md runs each stage in 2 GiB of address space)


def _store_windows(path, d_off: int, h_off: int, size: int, rows: np.ndarray):
    """The bricks ``rows`` (rows of ``size`` bytes from file offset ``d_off``, their stored hashes uint64 from
    ``h_off``) by windows of the file of at most STORE_WINDOW bytes, in increasing rows: yields ``(r0, pick, data,
    stored)``, ``pick`` the indices into ``rows`` of the bricks in the window, ``data`` the window's bytes (rows
    ``r0`` on, uint8 [rows, size]) and ``stored`` its rows' hashes, both memory maps (copied when not 8-byte
    aligned in memory, which a file whose datasets lie at odd offsets would give). Offsets checked by the caller
    against the file's size."""
    order = np.argsort(rows, kind="stable")
    srt = rows[order]
    per, i = max(1, STORE_WINDOW // size), 0
    while i < srt.size:
        j = int(np.searchsorted(srt, srt[i] + per))
        r0, r1 = int(srt[i]), int(srt[j - 1]) + 1
        m = np.memmap(path, dtype=np.uint8, mode="r", offset=d_off + r0 * size, shape=((r1 - r0) * size,))
        h = np.memmap(path, dtype="<u8", mode="r", offset=h_off + r0 * 8, shape=(r1 - r0,))
        data, stored = (x.view(np.ndarray) if x.ctypes.data % 8 == 0 else np.array(x) for x in (m, h))
        yield r0, order[i:j], data.reshape(r1 - r0, size), stored
        del m, h, data, stored
        i = j


def lazy_zeros(shape, dtype) -> np.ndarray:
    """A zeroed array whose memory pages are allocated only when written: anonymous memory of 4 KiB pages (numpy
    asks the kernel for huge pages for large arrays, so that one brick written would fill 2 MiB)."""
    import mmap

    n = int(np.prod(shape)) * np.dtype(dtype).itemsize
    if n == 0:
        return np.zeros(shape, dtype)
    return np.frombuffer(mmap.mmap(-1, n), dtype=dtype).reshape(shape)


def hashed_datasets(labels: bool, version: int = FORMAT_VERSION) -> list[str]:
    """The datasets the chunk hashes cover, in the file key's order (formats/augmented.md §1.1)."""
    return list(CHANNELS) + ([BRICK_RANGE] if version >= 5 else []) + ([LABELS, LABEL_VOXELS] if labels else [])


def brick_chunks(shape) -> tuple:
    """The bricks of a version-5 volume of ``shape`` (k, j, i): 8^3, smaller along an axis shorter than 8."""
    return tuple(min(b, max(1, int(n))) for b, n in zip(BRICK, shape))


def brick_ranges(density: np.ndarray, chunks) -> np.ndarray:
    """uint8[gk, gj, gi, 2]: the smallest and largest code of each brick of ``density`` (a chunk-aligned block)."""
    from .chunkhash import grid_shape, uniform_pieces

    out = np.zeros(grid_shape(density.shape, chunks) + (2,), dtype=np.uint8)
    for g, pieces in uniform_pieces(density, chunks):
        idx = tuple(g.T)
        out[idx + (0,)] = pieces.min(axis=1)
        out[idx + (1,)] = pieces.max(axis=1)
    return out


def _write_brick_range(f: h5py.File) -> None:
    """``/brick_range`` of open version-5 file ``f`` from its density, read a layer of 8 k-planes at a time."""
    ds = f["density"]
    chunks = tuple(int(c) for c in ds.chunks)
    from .chunkhash import grid_shape

    out = np.zeros(grid_shape(ds.shape, chunks) + (2,), dtype=np.uint8)
    step = max(1, (1 << 24) // max(1, chunks[0] * ds.shape[1] * ds.shape[2])) * chunks[0]
    for k0 in range(0, ds.shape[0], step):
        out[k0 // chunks[0]:(k0 + step) // chunks[0]] = brick_ranges(ds[k0:k0 + step], chunks)
    create_checked_dataset(f, BRICK_RANGE, out.shape, "|u1", out)


def _rebuild_hint(p, f) -> str:
    src = attr_string(f.attrs, "source") if f is not None else None
    return f"isplat augment {src if src else 'SOURCE'} -o {p} --force"


def open_augmented(path) -> AugmentedVolume:
    """Open and validate an augmented file; raise :class:`IsplatError` naming any problem."""
    counter = ReadCounter()
    p, f = open_hdf5(path, "augmented volume", FORMAT_NAME, FORMAT_VERSION, rebuild=_rebuild_hint,
                     older=OLDER_VERSIONS, counter=counter)
    with f, hdf5_errors(p, "attributes and datasets"):
        a = ReadAttrs(f.attrs)
        shape = tuple(int(x) for x in attr_array(p, a, "shape", "i", (3,)))
        spacing = tuple(float(x) for x in attr_array(p, a, "spacing_ijk", "f", (3,)))
        window = tuple(float(x) for x in attr_array(p, a, "density_window", "f", (2,)))
        gscale = float(attr_array(p, a, "gradient_magnitude_scale", "f"))
        check_string_attrs(p, a, ("density_sha256", "created_by"), OPTIONAL_STRINGS)
        if "density_clipped_fraction" in a:          # optional, but typed as formats/augmented.md says
            clipped = attr_array(p, a, "density_clipped_fraction", "f", (2,))
            if not (np.all(clipped >= 0) and np.all(clipped <= 1) and clipped.sum() <= 1 + 1e-9):
                raise IsplatError(f"{p}: attribute 'density_clipped_fraction' is {clipped.tolist()}, expected two "
                                  f"shares in 0..1")
        sha = attr_string(a, "density_sha256")
        if sha is None or len(sha) != 64 or any(c not in "0123456789abcdef" for c in sha):
            raise IsplatError(f"{p}: attribute 'density_sha256' is {a['density_sha256']!r}, expected 64 lower-case "
                              f"hex digits")
        if min(shape) < 1:
            raise IsplatError(f"{p}: attribute 'shape' is {shape}, expected three positive sizes")
        if min(spacing) <= 0:
            raise IsplatError(f"{p}: attribute 'spacing_ijk' is {spacing}, expected three positive numbers")
        if not window[0] < window[1]:
            raise IsplatError(f"{p}: attribute 'density_window' is {window}, expected LO < HI")
        if gscale < 0:
            raise IsplatError(f"{p}: attribute 'gradient_magnitude_scale' is {gscale}, expected a finite number >= 0")
        version = int(a["format_version"])
        for name, dt in CHANNEL_DTYPES.items():
            if name not in f or not isinstance(f[name], h5py.Dataset):
                raise IsplatError(f"{p}: dataset {name!r} is missing")
            ds = f[name]
            if version >= 6:
                continue                                  # the brick store: checked by _check_store
            if tuple(ds.shape) != shape:
                raise IsplatError(f"{p}: dataset {name!r} has shape {ds.shape}, attribute 'shape' says {shape}")
            if ds.dtype != np.dtype(dt):
                raise IsplatError(f"{p}: dataset {name!r} has dtype {ds.dtype}, expected {np.dtype(dt)}")
            check_checked_dataset(f"{p}: dataset {name!r}", ds)
        axes = check_axes_lps(p, attr_array(p, a, "axes_lps", "f", (3, 3))) if "axes_lps" in a else None
        attrs = attr_values(a)
        has_labels = version >= 4 and (LABELS in f or LABEL_VOXELS in f)
        verifier = chunkhash.open_verifier(p, f, sha, hashed_datasets(has_labels, version),
                                           chunkhash.attributes_of(f, hashed_attributes(version), a),
                                           _rebuild_hint(p, f), root_attrs=a)
        store, edge = _check_store(p, f, shape, verifier.key, has_labels) if version >= 6 else (None, 0)
        grid = _check_bricks(p, f, shape, has_labels, edge) if version >= 5 else None
        counts = _check_labels(p, f, shape, verifier, version) if has_labels else None
    return AugmentedVolume(p, shape, spacing, window, gscale, sha, attrs, io=counter, axes_lps=axes,
                           verifier=verifier, label_voxels=counts, format_version=version, brick_grid=grid,
                           store=store, edge=edge)


def store_grid(shape, edge: int) -> tuple:
    """The brick grid (gk, gj, gi) of a version-6 volume of ``shape`` with bricks of ``edge``."""
    return tuple(-(-int(n) // edge) for n in shape)


def _check_store(p, f, shape, key: bytes, has_labels: bool):
    """Version 6 (formats/augmented.md §2.3): ``brick_edge`` one of BRICK_EDGES; each stored channel a contiguous
    dataset [n_bricks, e, e, e] of its type, wholly allocated inside the file, and its hash table
    ``/brick_hashes/<channel>`` uint64[n_bricks] likewise; returns ``({channel: (data offset, hash offset,
    dtype, seed)}, edge)``. Every offset and size is checked here, before any compiled code reads through them."""
    import os

    from .brickstore import channel_seed

    e = f.attrs.get("brick_edge")
    if e is None or np.asarray(e).shape != () or np.asarray(e).dtype.kind not in "iu" or int(e) not in BRICK_EDGES:
        raise IsplatError(f"{p}: attribute 'brick_edge' is {e!r}, expected one of {list(BRICK_EDGES)} (format "
                          f"version 6)")
    e = int(e)
    nb = int(np.prod(store_grid(shape, e)))
    end = os.path.getsize(p)
    names = dict(CHANNEL_DTYPES)
    if has_labels and LABELS in f:
        names[LABELS] = f[LABELS].dtype.str if f[LABELS].dtype.str in LABEL_DTYPES else "?"

    def placed(name, want_shape, dt):
        ds = f.get(name)
        if not isinstance(ds, h5py.Dataset):
            raise IsplatError(f"{p}: dataset {name!r} is missing")
        if ds.dtype.str != np.dtype(dt).str or tuple(ds.shape) != want_shape:
            raise IsplatError(f"{p}: dataset {name!r} is {ds.dtype} {tuple(ds.shape)}, expected {np.dtype(dt)} "
                              f"{want_shape} (format version 6, bricks of {e}^3)")
        off, size = ds.id.get_offset(), int(np.prod(want_shape)) * np.dtype(dt).itemsize
        if ds.chunks is not None or off is None or ds.id.get_storage_size() != size or off + size > end:
            raise IsplatError(f"{p}: dataset {name!r} is not stored contiguous, whole, inside the file (offset "
                              f"{off}, {ds.id.get_storage_size()} bytes stored, expected {size} of a {end}-byte file)")
        return int(off)

    store = {}
    for name, dt in names.items():
        if dt not in LABEL_DTYPES and dt not in CHANNEL_DTYPES.values():
            raise IsplatError(f"{p}: dataset 'labels' has dtype {f[LABELS].dtype}, expected uint8 or uint16")
        store[name] = (placed(name, (nb, e, e, e), dt), placed(f"{BRICK_HASHES}/{name}", (nb,), "<u8"),
                       np.dtype(dt).str, channel_seed(key, name))
    return store, e


def _check_bricks(p, f, shape, has_labels, edge: int = 0) -> tuple:
    """Version 5 (formats/augmented.md §2.2): the channels (and labels) chunked in the file's bricks, and
    ``/brick_range`` present as uint8[gk, gj, gi, 2], chunked with checksums (its values are read and checked on
    first use: :func:`_read_brick_range`). Version 6 (``edge``): the range table of its bricks (the store itself
    is checked by :func:`_check_store`). Returns the brick grid (gk, gj, gi)."""
    chunks = (edge,) * 3 if edge else brick_chunks(shape)
    for name in [] if edge else list(CHANNELS) + ([LABELS] if has_labels and LABELS in f else []):
        if tuple(f[name].chunks) != chunks:
            raise IsplatError(f"{p}: dataset {name!r} is chunked {tuple(f[name].chunks)}, expected bricks of "
                              f"{chunks} (format version 5)")
    want = chunkhash.grid_shape(shape, chunks) + (2,)
    if BRICK_RANGE not in f or not isinstance(f[BRICK_RANGE], h5py.Dataset):
        raise IsplatError(f"{p}: dataset {BRICK_RANGE!r} is missing")
    ds = f[BRICK_RANGE]
    if ds.dtype != np.dtype("|u1") or tuple(ds.shape) != want:
        raise IsplatError(f"{p}: dataset {BRICK_RANGE!r} is {ds.dtype} {tuple(ds.shape)}, expected uint8 {want} "
                          f"(the smallest and largest density of each brick)")
    check_checked_dataset(f"{p}: dataset {BRICK_RANGE!r}", ds)
    return want[:3]


def _read_brick_range(p, f, verifier) -> np.ndarray:
    """``/brick_range`` of open file ``f`` (its type and shape checked at open), its chunks checked against their
    hashes, every brick's smallest density at most its largest."""
    ranges = np.asarray(verifier.read(f, BRICK_RANGE), dtype=np.uint8)
    if ranges.size and not np.all(ranges[..., 0] <= ranges[..., 1]):
        raise IsplatError(f"{p}: dataset {BRICK_RANGE!r} holds a brick whose smallest density exceeds its largest")
    return ranges


def _check_labels(p, f, shape, verifier, version: int = FORMAT_VERSION) -> np.ndarray:
    """The label datasets' types and shapes (formats/augmented.md §2.1); returns ``label_voxels`` (read and
    checked against its chunk hashes): non-negative counts summing to the voxels, at most 256 entries for uint8
    labels and 65,536 for uint16."""
    for name in (LABELS, LABEL_VOXELS):
        if name not in f or not isinstance(f[name], h5py.Dataset):
            raise IsplatError(f"{p}: dataset {name!r} is missing (a file with labels has both 'labels' and "
                              f"'label_voxels')")
    ds = f[LABELS]
    if version < 6 and tuple(ds.shape) != shape:
        raise IsplatError(f"{p}: dataset 'labels' has shape {ds.shape}, attribute 'shape' says {shape}")
    if ds.dtype.str not in LABEL_DTYPES:
        raise IsplatError(f"{p}: dataset 'labels' has dtype {ds.dtype}, expected uint8 or uint16 (little-endian)")
    if version < 6:
        check_checked_dataset(f"{p}: dataset 'labels'", ds)
    cv = f[LABEL_VOXELS]
    most = 256 if ds.dtype.itemsize == 1 else 65536
    if cv.ndim != 1 or cv.dtype != np.dtype("<i8") or not 2 <= cv.shape[0] <= most:
        raise IsplatError(f"{p}: dataset 'label_voxels' is {cv.dtype} {tuple(cv.shape)}, expected int64 (L + 1,) "
                          f"with 1 <= L < {most} (the largest label id)")
    check_checked_dataset(f"{p}: dataset 'label_voxels'", cv)
    counts = np.asarray(verifier.read(f, LABEL_VOXELS), dtype=np.int64)
    sha = attr_string(f.attrs, "labels_sha256") if "labels_sha256" in f.attrs else None
    if sha is None or len(sha) != 64 or any(c not in "0123456789abcdef" for c in sha):
        raise IsplatError(f"{p}: attribute 'labels_sha256' is missing or not 64 lower-case hex digits (a file with "
                          f"labels has it)")
    if counts.min() < 0 or int(counts.sum()) != int(np.prod(shape)):
        raise IsplatError(f"{p}: dataset 'label_voxels' holds counts summing to {int(counts.sum())} (smallest "
                          f"{int(counts.min())}), expected non-negative counts of the {int(np.prod(shape))} voxels")
    return counts



def write_augmented(path, density, gradient_magnitude, normal, spacing_ijk, density_window,
                    gradient_magnitude_scale, extra_attrs: dict | None = None, labels=None,
                    version: int = FORMAT_VERSION, edge: int | None = None) -> None:
    """Write a complete augmented file at ``path`` (the caller makes it atomic); ``labels``: an integer array
    of the same shape (ids 0..65535), stored as the label channel."""
    shape = tuple(int(x) for x in density.shape)
    with create_hdf5(path) as f:
        create_augmented(f, shape, spacing_ijk, density_window, gradient_magnitude_scale,
                         density_sha256(density), extra_attrs, version, edge)
        w = ChannelWriter(f)
        for name, arr in (("density", density), ("gradient_magnitude", gradient_magnitude), ("normal", normal)):
            w.write(name, 0, shape[0], arr)
        if labels is not None:
            write_labels(f, labels)
        finish_augmented(f)


def label_dtype(largest: int) -> str:
    """The stored type of labels whose largest id is ``largest``: uint8 up to 255, else uint16."""
    if not 0 <= largest <= 65535:
        raise IsplatError(f"label id {largest}: expected ids 0..65535")
    return "|u1" if largest <= 255 else "<u2"


def write_labels(f: h5py.File, labels, counts=None) -> None:
    """The label channel (formats/augmented.md §2.1) of open file ``f``: ``labels`` whole (an array), or, with
    ``counts`` (the voxels per id, int64), an iterable of ``(k0, k1, slab)``."""
    shape = tuple(int(x) for x in f.attrs["shape"])
    if counts is None:
        arr = np.asarray(labels)
        counts = label_counts(arr)
        labels = [(0, shape[0], arr)]
    version = int(f.attrs["format_version"])
    if version >= 6:
        _create_store(f, LABELS, shape, label_dtype(len(counts) - 1))
    else:
        create_checked_dataset(f, LABELS, shape, label_dtype(len(counts) - 1),
                               chunks=brick_chunks(shape) if version >= 5 else None)
    h = hashlib.sha256(np.asarray(shape, dtype="<i8").tobytes())
    w = ChannelWriter(f)
    for k0, k1, slab in labels:
        w.write(LABELS, k0, k1, slab)
        h.update(np.ascontiguousarray(slab, dtype="<u2").tobytes())
    create_checked_dataset(f, LABEL_VOXELS, (len(counts),), "<i8", np.asarray(counts, "<i8"))
    set_string_attr(f, "labels_sha256", h.hexdigest())


def label_counts(arr) -> np.ndarray:
    """Voxels per label id, 0 .. the largest (at least two entries: ids 0 and 1)."""
    a = np.asarray(arr)
    if a.size and (a.min() < 0 or a.max() > 65535):
        raise IsplatError(f"labels: ids {int(a.min())}..{int(a.max())}, expected 0..65535")
    c = np.bincount(a.reshape(-1).astype(np.int64), minlength=2)
    return c[:max(2, int(np.flatnonzero(c).max()) + 1 if c.any() else 2)]


def finish_augmented(f: h5py.File) -> None:
    """Write the brick ranges (version 5, 6), the brick hashes (version 6) and the chunk hashes of open file ``f``
    once its channels are written (formats/augmented.md §1.1, §2.2, §2.3)."""
    version = int(f.attrs["format_version"])
    datasets = hashed_datasets(LABELS in f, version)
    attrs = chunkhash.attributes_of(f, hashed_attributes(version))
    sha = attr_string(f.attrs, "density_sha256")
    if version >= 6 and BRICK_HASHES not in f:
        _finish_store(f, chunkhash.file_key(sha, datasets, attrs))
    elif version >= 5 and BRICK_RANGE not in f:
        _write_brick_range(f)
    chunkhash.write_tables(f, sha, datasets, attrs,
                           tables=[d for d in datasets if version < 6 or d not in (*CHANNELS, LABELS)])


def _create_store(f: h5py.File, name: str, shape, dtype) -> None:
    """A version-6 channel: a contiguous dataset [n_bricks, e, e, e], allocated at creation (zeros)."""
    e = int(f.attrs["brick_edge"])
    _contiguous(f, name, (int(np.prod(store_grid(shape, e))), e, e, e), dtype)


def _contiguous(parent, name: str, shape, dtype):
    """A contiguous dataset (no chunks, no filters), its bytes allocated at creation, no timestamps."""
    dcpl = h5py.h5p.create(h5py.h5p.DATASET_CREATE)
    dcpl.set_layout(h5py.h5d.CONTIGUOUS)
    dcpl.set_alloc_time(h5py.h5d.ALLOC_TIME_EARLY)
    dcpl.set_obj_track_times(False)
    return h5py.h5d.create(parent.id, name.encode(), h5py.h5t.py_create(np.dtype(dtype)),
                           h5py.h5s.create_simple(tuple(int(n) for n in shape)), dcpl=dcpl)


def _finish_store(f: h5py.File, key: bytes) -> None:
    """Version 6: ``/brick_range`` and ``/brick_hashes/<channel>`` of open file ``f``, read back a layer of bricks
    (about 16 MiB) at a time."""
    from .brickstore import brick_minmax, channel_seed, hash_bricks
    from .fileio import create_group

    e = int(f.attrs["brick_edge"])
    shape = tuple(int(x) for x in f.attrs["shape"])
    grid = store_grid(shape, e)
    layer = grid[1] * grid[2]
    step = max(1, (1 << 24) // max(1, layer * e ** 3)) * layer
    g = create_group(f, BRICK_HASHES)
    ranges = np.zeros((int(np.prod(grid)), 2), dtype=np.uint8)
    for name in list(CHANNELS) + ([LABELS] if LABELS in f else []):
        ds, seed = f[name], np.uint64(channel_seed(key, name))
        table = np.zeros(ds.shape[0], dtype="<u8")
        for r0 in range(0, ds.shape[0], step):
            data = np.ascontiguousarray(ds[r0:r0 + step])
            rows = np.arange(r0, r0 + data.shape[0], dtype=np.int64)
            table[r0:r0 + data.shape[0]] = hash_bricks(data.reshape(data.shape[0], -1).view("<u8"), rows, seed)
            if name == "density":
                offs = np.stack(np.unravel_index(rows, grid), axis=1) * e
                ranges[r0:r0 + data.shape[0]] = brick_minmax(data, np.minimum(e, np.asarray(shape) - offs))
        _contiguous(g, name, table.shape, "<u8").write(h5py.h5s.ALL, h5py.h5s.ALL, table)
    if BRICK_RANGE not in f:
        create_checked_dataset(f, BRICK_RANGE, grid + (2,), "|u1", ranges.reshape(grid + (2,)))


class ChannelWriter:
    """Writes k-slabs ``[k0, k1)`` of the channels of an open augmented file of any version, in order; version 6
    stores them as bricks, keeping the planes of an unfinished layer of bricks until the next slab."""

    def __init__(self, f: h5py.File):
        self.f = f
        self.version = int(f.attrs["format_version"])
        self.shape = tuple(int(x) for x in f.attrs["shape"])
        self.edge = int(f.attrs["brick_edge"]) if self.version >= 6 else 0
        self.pending = {}

    def write(self, name: str, k0: int, k1: int, arr) -> None:
        if self.version < 6:
            self.f[name][k0:k1] = arr
            return
        from .brickstore import to_bricks

        e, nk = self.edge, self.shape[0]
        if name in self.pending:
            p0, parr = self.pending.pop(name)
            if p0 + parr.shape[0] != k0:
                raise ValueError(f"{name}: slab {k0}..{k1} does not follow {p0}..{p0 + parr.shape[0]}")
            arr, k0 = np.concatenate([parr, np.asarray(arr)]), p0
        if k0 % e:
            raise ValueError(f"{name}: slab {k0}..{k1} starts inside a layer of bricks")
        cut = k1 if k1 == nk else k0 + (k1 - k0) // e * e
        layer = int(np.prod(store_grid(self.shape, e)[1:]))
        step = max(e, (1 << 24) // max(1, self.shape[1] * self.shape[2]) // e * e)
        ds = self.f[name]
        for a in range(k0, cut, step):
            b = min(cut, a + step)
            bricks = to_bricks(np.asarray(arr[a - k0:b - k0], dtype=ds.dtype), e)
            ds[a // e * layer:a // e * layer + bricks.shape[0]] = bricks
        if cut < k1:
            self.pending[name] = (cut, np.array(arr[cut - k0:]))


def create_augmented(f: h5py.File, shape, spacing_ijk, density_window, gradient_magnitude_scale,
                     sha: str, extra_attrs: dict | None = None, version: int = FORMAT_VERSION,
                     edge: int | None = None) -> None:
    """Create the attributes and empty channel datasets of an augmented file in open file ``f`` (``version``:
    an older version's layout, 4 or 3, for tests and benchmarks)."""
    from . import __version__

    set_string_attr(f, "format", FORMAT_NAME)
    f.attrs["format_version"] = np.int64(version)
    f.attrs["shape"] = np.asarray(shape, dtype="<i8")
    f.attrs["spacing_ijk"] = np.asarray(spacing_ijk, dtype="<f8")
    f.attrs["density_window"] = np.asarray(density_window, dtype="<f8")
    f.attrs["gradient_magnitude_scale"] = np.float64(gradient_magnitude_scale)
    if version >= 6:
        f.attrs["brick_edge"] = np.int64(edge or BRICK_EDGE)
    set_string_attr(f, "density_sha256", sha)
    set_string_attr(f, "created_by", f"isplat {__version__}")
    for k, v in (extra_attrs or {}).items():
        if isinstance(v, str):
            set_string_attr(f, k, v)
        else:
            f.attrs[k] = v
    for name, dt in CHANNEL_DTYPES.items():
        if version >= 6:
            _create_store(f, name, shape, dt)
        else:
            create_checked_dataset(f, name, shape, dt, chunks=brick_chunks(shape) if version >= 5 else None)
