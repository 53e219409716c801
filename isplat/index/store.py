"""The index container on disk (formats/index.md): write it atomically, open and validate it, load axes.

Files are inputs from strangers and the decoder is compiled without bounds checks, so every table a load
uses is checked here before :func:`isplat.index.codec.decode_blocks` sees it, and the decoder itself stops
at the first block that does not match its count or range.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from .. import chunkhash, progress
from ..errors import IsplatError
from ..fileio import (ReadAttrs, ReadCounter, attr_array, attr_string, attr_values, atomic_output,
                      check_checked_dataset, check_hashed_dataset, check_output, check_string_attrs,
                      create_checked_dataset, create_group, create_hashed_dataset, create_hdf5, hdf5_errors,
                      open_counted, open_hdf5, read_chunk_span, set_string_attr)
from . import codec
from .build import (AXES, IN_SLICE_AXES, AxisIndex, ChannelValues, axis_geometry, encode_windows, escape_width,
                    SLAB_VOXELS, k_slabs, measure_axes, normalize_ranges, parse_axes, ranges_mask, slice_runs)

FORMAT_NAME = "isplat-index"
FORMAT_VERSION = 7              # version 7: chunks without filters, allocated at creation (no chunk index), sized
                                # by their dataset (§1); version 6: no /values, the channel values beside (§9)
FORMAT_VERSION_VALUES_FILE = 6  # the first version with a values file (still read, with Fletcher-32 chunks)
FORMAT_VERSION_WITH_VALUES = 4  # version 4: + /chunk_hashes (a keyed hash per chunk); /values OPTIONAL (still read)
OLDER_VERSIONS = (4, 5, 6)      # versions 2 and 3 (no chunk hashes) are refused with the command that rebuilds them
FORMAT_VERSION_LABELS = 5       # version 5: an index of the labels (@channel = "labels", @labels_sha256; §10),
                                # read beside the density index
VALUES_FORMAT_NAME = "isplat-index-values"   # the values file beside a version-6 index (§9)
VALUES_FORMAT_VERSION = 7       # the values file's version: its index's (6 is read beside a version-6 index)
DATASET_DTYPES = {
    "density_entry_ptr": "<i8",
    "entry_slice": "<u4",
    "entry_voxel_count": "<u4",
    "entry_byte_offset": "<i8",
    "bytes": "|u1",
}
VALUE_DTYPES = {
    "density_voxel_ptr": "<i8",
    "gradient_magnitude": "|u1",
    "normal": "<u2",
}
VALUE_CHANNELS = ("gradient_magnitude", "normal")
# Chunk sizes (bytes). HDF5 reads whole chunks, so each range a load reads costs at most two partial chunks
# beyond its own bytes (a single-row read: one chunk), and the hash-table rows of its chunks. Version 7 (§1):
# chunks without filters, allocated at creation, so HDF5 reads no chunk index (with Fletcher-32, versions 4-6,
# a chunk index of more than 1,024 chunks is read in pages of about 14 KiB per range); their size follows the
# dataset's: the power of two nearest below sqrt(dataset bytes) / 2, between CHUNK_MIN and CHUNK_MAX (a range
# of about a 64th of the dataset then reads about as much in partial chunks as in hash-table rows), the hash
# tables' likewise. The two 257-row pointer tables are one chunk each.
CHUNK_MIN, CHUNK_MAX = 1 << 8, 1 << 16
PTR_CHUNK = 257 * 8             # density_entry_ptr, density_voxel_ptr: whole
TABLE_CHUNK = 1 << 11           # versions 4-6 (tests of old files): entry_slice, entry_voxel_count, entry_byte_offset
BYTES_CHUNK = 1 << 12           # versions 4-6: bytes (the encoded blocks)
VALUE_CHUNK = 1 << 12           # versions 4-6: gradient_magnitude, normal under /values
VALUE_SLAB_VOXELS = 1 << 20     # voxels per k-slab when copying values from the augmented file
BUILD_BUDGET = 1 << 29          # bytes of working arrays for isplat index: one window of an axis's bytes or values


# ----------------------------------------------------------------------------------------------- write

def values_path(index_path) -> Path:
    """The values file of an index: ``NAME.idx.h5`` -> ``NAME.values.idx.h5`` (else INDEX + ``.values.idx.h5``),
    named as the index of the labels is (formats/index.md §9, §10)."""
    s = str(index_path)
    return Path(s[: -len(".idx.h5")] + ".values.idx.h5" if s.endswith(".idx.h5") else s + ".values.idx.h5")


def _write_root(f: h5py.File, shape, sha: str, ranges, version: int = FORMAT_VERSION,
                format_name: str = FORMAT_NAME) -> None:
    """The root attributes (§2). ``version`` 4 or 6 only for tests of the old layouts (4: ``/values`` inside;
    both: Fletcher-32 chunks)."""
    from .. import __version__

    set_string_attr(f, "format", format_name)
    old = (FORMAT_VERSION_WITH_VALUES, FORMAT_VERSION_VALUES_FILE)
    f.attrs["format_version"] = np.int64(version if version in old else FORMAT_VERSION)
    f.attrs["shape"] = np.asarray(shape, dtype="<i8")
    set_string_attr(f, "density_sha256", str(sha))
    f.attrs["density_ranges"] = np.asarray(normalize_ranges(ranges), dtype="<i8").reshape(-1, 2)
    set_string_attr(f, "created_by", f"isplat {__version__}")
    if format_name == FORMAT_NAME:
        create_group(f, "axes")


def _write_values_root(f: h5py.File, shape, sha: str, ranges, index_check: str,
                       version: int = VALUES_FORMAT_VERSION) -> None:
    """The root of a values file (§9): the index's root attributes, its ``chunk_hash_check`` as
    ``index_chunk_hash_check`` (which enters the file key: the values of another index do not verify)."""
    _write_root(f, shape, sha, ranges, version, VALUES_FORMAT_NAME)
    set_string_attr(f, "index_chunk_hash_check", index_check)


def chunk_rows(n: int, itemsize: int) -> int:
    """Rows per chunk of a version-7 dataset of ``n`` rows of ``itemsize`` bytes (§1): the power of two nearest
    below sqrt(its bytes) / 2, between CHUNK_MIN and CHUNK_MAX bytes, at most its rows (at least 1)."""
    nbytes = max(1, int(n) * int(itemsize))
    target = min(CHUNK_MAX, max(CHUNK_MIN, int(nbytes ** 0.5) // 2))
    target = 1 << (target.bit_length() - 1)
    return max(1, min(int(n), target // int(itemsize)))


def _sized(f) -> bool:
    """True when open file ``f`` is written as version 7 (chunks sized by their dataset, no filters, §1)."""
    return int(f.file.attrs["format_version"]) >= FORMAT_VERSION


def _dataset(g, name: str, shape, dt, data=None, old_target: int = BYTES_CHUNK):
    """A dataset of the index or values file: version 7 (:func:`chunk_rows`, no filters, no chunk index); an
    older version (tests): Fletcher-32 chunks of about ``old_target`` bytes."""
    if not _sized(g):
        return create_checked_dataset(g, name, shape, dt, data, target=old_target)
    n = int(shape[0])
    rows = n if old_target == PTR_CHUNK else chunk_rows(n, np.dtype(dt).itemsize)
    return create_hashed_dataset(g, name, shape, dt, data, chunks=(max(1, rows),) + tuple(shape[1:]))


def _hash_table(g, name: str, table: np.ndarray):
    """A chunk-hash table (§1.1) of a version-7 file: sized as its datasets are."""
    return create_hashed_dataset(g, name, table.shape, "|u1", table,
                                 chunks=(chunk_rows(table.shape[0], chunkhash.DIGEST), chunkhash.DIGEST))


def _write_axis(f: h5py.File, ax: AxisIndex, n_bytes: int | None = None):
    """Write axis ``ax`` under ``/axes/<axis>``; with ``n_bytes`` its ``bytes`` dataset is made that long and
    left for the caller to fill (returned), else ``ax.bytes`` is written."""
    g = create_group(f["axes"], ax.axis)
    set_string_attr(g, "axis", ax.axis)
    g.attrs["n_slices"] = np.int64(ax.n_slices)
    set_string_attr(g, "in_slice_axes", ax.in_slice_axes)
    g.attrs["n_a"] = np.int64(ax.n_a)
    g.attrs["n_b"] = np.int64(ax.n_b)
    g.attrs["escape_width"] = np.int64(ax.escape_width)
    filled_later = None
    for name, dt in DATASET_DTYPES.items():
        # chunked (version 7: sized by the dataset, no filters; older: Fletcher-32), little-endian (§1)
        data = np.ascontiguousarray(getattr(ax, name), dtype=dt)
        shape = (int(n_bytes),) if name == "bytes" and n_bytes is not None else data.shape
        # small chunks: a load reads single rows of entry_byte_offset and row ranges, each rounded out to chunks
        ds = _dataset(g, name, shape, dt, old_target=BYTES_CHUNK if name == "bytes" else
                      PTR_CHUNK if name == "density_entry_ptr" else TABLE_CHUNK)
        if name == "bytes" and n_bytes is not None:
            filled_later = ds
        else:
            write_in_pieces(ds, data)
    return filled_later


WRITE_CHUNKS = 1024     # chunks per write call: HDF5 keeps a selection per chunk a write touches (~3 KiB each)


def write_in_pieces(ds, data: np.ndarray, start: int = 0) -> None:
    """``ds[start:start + len(data)] = data`` for a 1-D chunked dataset, at most WRITE_CHUNKS chunks per call,
    so that writing many small chunks does not hold HDF5's per-chunk bookkeeping for all of them at once."""
    step = WRITE_CHUNKS * ds.chunks[0]
    for r0 in range(0, data.shape[0], step):
        ds[start + r0:start + min(r0 + step, data.shape[0])] = data[r0:r0 + step]


def _values_group(f: h5py.File, ptr, spacing_ijk, gradient_magnitude_scale):
    g = create_group(f, "values")
    g.attrs["spacing_ijk"] = np.asarray(spacing_ijk, dtype="<f8")
    g.attrs["gradient_magnitude_scale"] = np.float64(gradient_magnitude_scale)
    _dataset(g, "density_voxel_ptr", (257,), "<i8", np.asarray(ptr, dtype="<i8"), old_target=PTR_CHUNK)
    n = int(ptr[256])
    return g, [_dataset(g, ch, (n,), VALUE_DTYPES[ch], old_target=VALUE_CHUNK) for ch in VALUE_CHANNELS]


def _write_values(f: h5py.File, v: ChannelValues) -> None:
    _, dsets = _values_group(f, v.density_voxel_ptr, v.spacing_ijk, v.gradient_magnitude_scale)
    for ds, ch in zip(dsets, VALUE_CHANNELS):
        if ds.shape[0]:
            ds[...] = getattr(v, ch)


def write_index(path, index: dict[str, AxisIndex], shape, density_sha256: str, ranges=None,
                force: bool = False, values: ChannelValues | None = None) -> Path:
    """Write the axes of ``index`` (from :func:`build_index`) to ``path`` and the channel ``values`` (from
    :func:`isplat.index.build.order_values`) to its values file (:func:`values_path`), atomically. Without
    ``values`` there is no values file (a renderer gathers the channel values from the augmented file). The chunk
    hashes are written last (formats/index.md §1.1)."""
    stale = values_path(path)
    check_output(stale, force)             # a values file there: replaced, or without values removed (--force)
    vpath = stale if values is not None else None
    with contextlib.ExitStack() as stack:
        vtmp = stack.enter_context(atomic_output(vpath, force)) if vpath is not None else None
        tmp = stack.enter_context(atomic_output(path, force))     # committed first: the index, then its values
        with create_hdf5(tmp) as f:
            _write_root(f, shape, density_sha256, ranges)
            for a in AXES:
                if a in index:
                    _write_axis(f, index[a])
            finish_index(f)
            check = attr_string(f.attrs, chunkhash.CHECK_ATTR)
        if vtmp is not None:
            with create_hdf5(vtmp) as g:
                _write_values_root(g, shape, density_sha256, ranges, check)
                _write_values(g, values)
                finish_index(g)
    if vpath is None and stale.is_file():
        stale.unlink()
    return Path(path)


def hashed_layout(f: h5py.File):
    """``(datasets, attributes)`` the chunk hashes of open index ``f`` cover (formats/index.md §1.1): ``/values``
    when present, then the present axes in i, j, k order, each dataset in the order of the spec's tables. A values
    file (§9): ``index_chunk_hash_check`` after the root attributes, then ``/values``."""
    datasets, attrs = [], [("", n) for n in ("format", "format_version", "shape", "density_sha256",
                                              "density_ranges")]
    if "channel" in f.attrs:            # version 5 (formats/index.md §10)
        attrs += [("", "channel"), ("", "labels_sha256")]
    if attr_string(f.attrs, "format", ascii_ok=True) == VALUES_FORMAT_NAME:
        attrs += [("", "index_chunk_hash_check")]
    if "values" in f:
        datasets += [f"values/{n}" for n in VALUE_DTYPES]
        attrs += [("values", "spacing_ijk"), ("values", "gradient_magnitude_scale")]
    for a in AXES:
        if "axes" in f and a in f["axes"]:
            datasets += [f"axes/{a}/{n}" for n in DATASET_DTYPES]
            attrs += [(f"axes/{a}", n) for n in ("axis", "n_slices", "in_slice_axes", "n_a", "n_b", "escape_width")]
    return datasets, attrs


def finish_index(f: h5py.File) -> None:
    """Write the chunk hashes of open index ``f`` once everything else is written."""
    datasets, attrs = hashed_layout(f)
    chunkhash.write_tables(f, attr_string(f.attrs, "density_sha256"), datasets, chunkhash.attributes_of(f, attrs),
                           create=_hash_table if _sized(f) else None)


def _slabs_of(aug, voxels: int = VALUE_SLAB_VOXELS):
    """The k-slabs of about ``voxels`` voxels in which the builder reads augmented volume ``aug``: whole brick
    layers when it is bricked (format 5, 6 read a brick layer whole; docs/design.md, "isplat index streams")."""
    shape = aug.shape
    return k_slabs(int(shape[0]), int(shape[1]) * int(shape[2]), voxels, aug.bricks[0] if aug.bricked else 1)


@contextlib.contextmanager
def _channel_reader(aug, density: np.ndarray | None = None):
    """``read(channel, k0, k1)``: k-planes of the augmented file ``aug`` (an open, validated
    :class:`isplat.augfile.AugmentedVolume`) through one open handle; the density from ``density`` when given."""
    from ..augfile import CHANNELS

    with hdf5_errors(aug.path, "open"):
        src = h5py.File(aug.path, "r")
    try:
        def read(ch, k0, k1):
            if ch == "density" and density is not None:
                return density[k0:k1]
            with hdf5_errors(aug.path, f"dataset {ch!r} [{k0}:{k1}]"):
                v = getattr(aug, "verifier", None)
                arr = aug.read_open(src, ch, (slice(k0, k1),)) if v is not None else src[ch][k0:k1]
                return np.ascontiguousarray(arr, dtype=CHANNELS[ch])
        yield read
    finally:
        src.close()


def copy_values(f: h5py.File, aug, density: np.ndarray | None, ranges, budget: int | None = None,
                slab_voxels: int = VALUE_SLAB_VOXELS) -> None:
    """Write ``/values`` of open index ``f`` from augmented volume ``aug`` (its ``density`` read slab by slab
    from the file, or taken from ``density`` when given).

    The rows (density-major, then by position) are filled in windows of at most ``budget`` bytes of values
    (default BUILD_BUDGET); each window is one pass over the k-slabs (of about ``slab_voxels``) that hold some
    of its rows, reading their channel slabs; a compiled counting scatter puts each slab's values in place.
    Written in pieces of WRITE_CHUNKS chunks. Memory: one window and one slab of each channel."""
    indexed = ranges_mask(ranges)
    slabs = _slabs_of(aug, slab_voxels)
    per_slab = np.zeros((len(slabs), 256), dtype=np.int64)
    with _channel_reader(aug, density) as read:
        for n, (k0, k1) in enumerate(slabs):
            per_slab[n] = np.bincount(read("density", k0, k1).reshape(-1), minlength=256)
        per_slab[:, ~indexed] = 0
        ptr = np.zeros(257, dtype=np.int64)
        np.cumsum(per_slab.sum(axis=0), out=ptr[1:])
        # first row of each (slab, density): the density's start plus the voxels of earlier slabs
        first = ptr[:-1] + np.cumsum(per_slab, axis=0) - per_slab
        _, (ds_gm, ds_nrm) = _values_group(f, ptr, aug.spacing_ijk, aug.gradient_magnitude_scale)
        total = int(ptr[256])
        width = max(1, (BUILD_BUDGET if budget is None else int(budget)) // 3)    # 1 + 2 bytes of values per row
        with progress.bar(total=total, desc="index values", unit="voxel") as pb:
            for r0 in range(0, total, width):
                r1 = min(total, r0 + width)
                gm = np.empty(r1 - r0, dtype=np.uint8)
                nrm = np.empty(r1 - r0, dtype=np.uint16)
                for n, (k0, k1) in enumerate(slabs):
                    hit = (per_slab[n] > 0) & (first[n] < r1) & (first[n] + per_slab[n] > r0)
                    if hit.any():
                        codec.scatter_values(read("density", k0, k1).reshape(-1),
                                             read("gradient_magnitude", k0, k1).reshape(-1),
                                             read("normal", k0, k1).reshape(-1), indexed & hit, first[n].copy(),
                                             r0, r1, gm, nrm)
                write_in_pieces(ds_gm, gm, r0)
                write_in_pieces(ds_nrm, nrm, r0)
                pb.update(r1 - r0)
                del gm, nrm


def build_index_file(aug_path, out_path, axes: str = "ijk", ranges=None, force: bool = False,
                     values: bool = True, budget: int = BUILD_BUDGET, slab_voxels: int | None = None,
                     labels: bool = True) -> Path:
    """Index the density channel of augmented file ``aug_path`` into ``out_path`` (atomic), and write the indexed
    voxels' channel values in density order to its values file (:func:`values_path`, formats/index.md §9);
    ``values=False`` writes no values file (the pre-classified technique then gathers them from the augmented
    file) and, with ``force``, removes one left there by an earlier build.

    Streams: the density is read in k-slabs (of about ``slab_voxels``), never whole. One pass measures every
    axis's blocks (which fixes the tables); then each axis's byte stream is encoded and written in windows of
    at most ``budget`` bytes, one pass over the slabs per window (docs/design.md, "isplat index streams"), and
    the values likewise. The files equal those of :func:`write_index` on the in-memory build. With ``labels`` and
    an augmented file with labels, the index of the labels is written beside (:mod:`isplat.index.labels`).
    Every output is checked before any work; the index is committed first, then its values file, so an
    interruption leaves either nothing new or a whole index (without values, which renders)."""
    from ..augfile import open_augmented
    from .labels import build_label_index_file, label_index_path

    axes = parse_axes(axes)
    ranges = normalize_ranges(ranges)
    aug = open_augmented(aug_path)
    labels = labels and aug.has_labels
    vpath = values_path(out_path)
    check_output(out_path, force)
    check_output(vpath, force)              # before any work: also without values (a stale one is removed)
    if labels:
        check_output(label_index_path(out_path), force)
    for a in axes:
        escape_width(*axis_geometry(aug.shape, a)[1:])     # refuse impossible sizes before any work
    slabs = _slabs_of(aug, SLAB_VOXELS if slab_voxels is None else slab_voxels)
    with contextlib.ExitStack() as stack:
        vtmp = stack.enter_context(atomic_output(vpath, force)) if values else None
        tmp = stack.enter_context(atomic_output(out_path, force))     # committed first, then the values file
        with create_hdf5(tmp) as f, _channel_reader(aug) as read:
            _write_root(f, aug.shape, aug.density_sha256, ranges)
            dens = lambda k0, k1: read("density", k0, k1)      # noqa: E731
            layouts = measure_axes(dens, aug.shape, axes, ranges, slabs)
            for a in axes:
                lay = layouts.pop(a)
                ds = _write_axis(f, lay.tables(), lay.n_bytes)
                for o0, window in encode_windows(dens, aug.shape, lay, budget, slabs):
                    write_in_pieces(ds, window, o0)
                    del window                           # before the next window is made
                del lay
            finish_index(f)
            check = attr_string(f.attrs, chunkhash.CHECK_ATTR)
        if values:
            with create_hdf5(vtmp) as g:
                _write_values_root(g, aug.shape, aug.density_sha256, ranges, check)
                copy_values(g, aug, None, ranges, budget, **({} if slab_voxels is None else
                                                            {"slab_voxels": slab_voxels}))
                finish_index(g)
    if not values and vpath.is_file():
        vpath.unlink()                          # another build's values (check_output allowed it: --force)
    if labels:
        build_label_index_file(aug, label_index_path(out_path), axes, force)
    return Path(out_path)


# ------------------------------------------------------------------------------------------------ read

@dataclass
class LoadedAxis:
    """Decoded blocks of one axis for some density intervals (contract: docs/design.md)."""

    axis: str
    n_slices: int
    n_a: int
    n_b: int
    slice_block_ptr: np.ndarray    # int64[n_slices + 1]
    block_density: np.ndarray      # uint8[n_blocks], increasing within a slice
    block_voxel_ptr: np.ndarray    # int64[n_blocks + 1]
    positions: np.ndarray          # int32[n_voxels], ind = a + b * n_a, increasing within a block
    bytes_read: int = 0
    intervals: list = field(default_factory=list)
    bytes_needed: int | None = None    # the blocks and table rows this load needs (None: ``bytes_read``; a slab of
    #                                    IndexFile.shared_tables: its own rows, the shared tables counted once)

    @property
    def n_blocks(self) -> int:
        return int(self.block_density.shape[0])

    @property
    def n_voxels(self) -> int:
        return int(self.positions.shape[0])

    def slice_positions(self, s: int, density: int | None = None) -> np.ndarray:
        """Positions of slice ``s`` (of one density, or of all loaded densities in block order)."""
        r0, r1 = self.slice_block_ptr[s], self.slice_block_ptr[s + 1]
        if density is None:
            return self.positions[self.block_voxel_ptr[r0]:self.block_voxel_ptr[r1]]
        r = r0 + np.searchsorted(self.block_density[r0:r1], density)
        if r < r1 and self.block_density[r] == density:
            return self.positions[self.block_voxel_ptr[r]:self.block_voxel_ptr[r + 1]]
        return self.positions[:0]


@dataclass
class _AxisMeta:
    axis: str
    n_slices: int
    n_a: int
    n_b: int
    escape_width: int
    n_entries: int
    n_bytes: int


@dataclass
class _ValuesMeta:
    n_voxels: int
    spacing_ijk: tuple
    gradient_magnitude_scale: float


class IndexFile:
    """An open, validated index file. Arrays are read on demand; :attr:`bytes_read` counts every request,
    :attr:`io` what HDF5 read from the file for them (whole chunks with checksums, metadata, the opening)."""

    def __init__(self, path: Path, shape, density_sha256: str, ranges, axes_meta: dict[str, _AxisMeta],
                 attrs: dict, version: int = FORMAT_VERSION, values: _ValuesMeta | None = None,
                 io: ReadCounter | None = None, verifier=None):
        self.path = path
        self.shape = shape
        self.density_sha256 = density_sha256
        self.density_ranges = ranges
        self._meta = axes_meta
        self.attrs = attrs
        self.version = int(version)
        self.channel = "density"       # "labels": an index of the label channel (version 5, formats/index.md §10)
        self.values = values           # /values in this file (version 4; a values file's own)
        self._values_file = None       # version 6: the values file beside it, opened on first use
        self._values_looked = False
        self.io = io if io is not None else ReadCounter()
        self.verifier = verifier       # isplat.chunkhash.Verifier: checks each chunk read
        self.bytes_read = 0
        self._handle = None
        self._kept = None              # the opening's h5py file, left open for the first session (keep_open)
        self.keep_open = False         # open the values file so too
        self._shared = None            # shared_tables(): tables and boundary chunks kept across slab loads
        self._gen = 0
        self._indexed = np.zeros(256, dtype=np.bool_)
        for lo, hi in ranges:
            self._indexed[lo:hi + 1] = True

    def __repr__(self):
        return f"IndexFile({str(self.path)!r}, shape={self.shape}, axes={self.axes!r})"

    def __getstate__(self):
        """Pickled (a Dask worker's copy) without open files."""
        state = dict(self.__dict__)
        state["_handle"] = state["_kept"] = state["_shared"] = None
        return state

    @contextlib.contextmanager
    def shared_tables(self):
        """Inside the block, loads of slices (a frame's slabs, one after the other) share what they all read:
        each interval's table rows (``density_entry_ptr``, ``entry_slice``, ``entry_voxel_count``, every row of
        ``entry_byte_offset``) are read and checked once, and the chunk of ``bytes`` where one slab's blocks end
        and the next one's begin is kept for the next load, so K slabs read the index about as one load does."""
        if self._shared is not None:
            yield self
            return
        self._shared = {}
        try:
            with self.session():
                yield self
        finally:
            self._shared = None

    @property
    def axes(self) -> str:
        """The indexed axes, in i, j, k order."""
        return "".join(a for a in AXES if a in self._meta)

    def _axis(self, axis: str) -> _AxisMeta:
        """The axis's attributes and table sizes; its datasets are checked on its first use (a load of one axis
        does not read the others' dataset headers)."""
        if axis not in self._meta:
            raise IsplatError(f"{self.path}: axis {axis!r} is not in this index (it has {self.axes!r})")
        m = self._meta[axis]
        if m.n_entries < 0:
            with self._open(axis) as g:
                m = self._meta[axis] = _check_axis_datasets(self.path, g, m, self.version)
        return m

    def n_slices(self, axis: str) -> int:
        return self._axis(axis).n_slices

    def axis_info(self, axis: str) -> dict:
        """``n_slices``, ``n_a``, ``n_b``, ``escape_width``, ``n_entries``, ``n_bytes`` of ``axis``."""
        m = self._axis(axis)
        return {k: getattr(m, k) for k in ("n_slices", "n_a", "n_b", "escape_width", "n_entries", "n_bytes")}

    # -- reading helpers
    def _fail(self, axis, msg, density=None, slice_=None):
        where = f"axis {axis}"
        if density is not None:
            where += f", density {int(density)}"
        if slice_ is not None:
            where += f", slice {int(slice_)}"
        raise IsplatError(f"{self.path}: {where}: {msg}")

    @contextlib.contextmanager
    def session(self):
        """Keep the file open for the reads inside the block (HDF5 then reads each object header and chunk
        index page once, not once per load)."""
        if self._handle is not None:
            yield self
            return
        kept, self._kept = self._kept, None
        if kept is not None:           # the opening's file (keep_open): its objects are not read again
            opened = contextlib.closing(kept)
            self._handle = kept
        else:
            with hdf5_errors(self.path, "open"):
                opened = open_counted(self.path, self.io)
                self._handle = opened.__enter__()
        try:
            yield self
        finally:
            self._handle = None
            opened.__exit__(None, None, None)

    @contextlib.contextmanager
    def _open(self, group):
        """Group ``/axes/<group>``, or ``/values`` for ``group="values"``, of the file opened for reading."""
        where = "/values" if group == "values" else f"/axes/{group}"
        with self.session(), hdf5_errors(self.path, where):
            f = self._handle
            yield f["values"] if group == "values" else f["axes"][group]

    def _read(self, g, name, lo, hi):
        fetch = self._fetch if self.version >= FORMAT_VERSION else None
        with hdf5_errors(self.path, f"dataset {g.name}/{name} [{lo}:{hi}]"):
            arr = self.verifier.read(g.file, f"{g.name.strip('/')}/{name}", (slice(lo, hi),), fetch=fetch)
        dt = DATASET_DTYPES.get(name) or VALUE_DTYPES[name]
        arr = np.ascontiguousarray(arr, dtype=np.dtype(dt).newbyteorder("="))
        self.bytes_read += int(arr.nbytes)
        return arr

    def _fetch(self, ds, lo: int, hi: int):
        """Rows ``lo:hi`` of a version-7 dataset in one read (:func:`isplat.fileio.read_chunk_span`), counted in
        :attr:`io`; the caller checks each chunk's hash."""
        return read_chunk_span(self.path, self.io, ds, lo, hi)

    # -- channel values (in the file: version 4; beside it: version 6, formats/index.md §9)
    @property
    def values_file(self):
        """The values file beside a version-6 index (an :class:`IndexFile` of format ``isplat-index-values``,
        checked to belong to this index), opened on first use; None when there is none (or values are inside)."""
        if not self._values_looked:
            self._values_looked = True
            p = values_path(self.path)
            if self.version >= FORMAT_VERSION_VALUES_FILE and self.channel == "density" and \
                    (p.exists() or p.is_symlink()):
                self._values_file = open_values(p, self, self.keep_open)
        return self._values_file

    def _values_holder(self):
        """The file whose ``/values`` hold this index's channel values (itself, its values file), or None."""
        return self if self.values is not None else self.values_file

    @property
    def has_values(self) -> bool:
        """True when the indexed voxels' channel values can be read: ``/values`` inside (version 4) or the values
        file beside (version 6)."""
        return self._values_holder() is not None

    @property
    def values_source(self) -> str:
        """Where the channel values are read: ``"index"`` (``/values`` inside), ``"values file"`` or ``"none"``."""
        return "index" if self.values is not None else "values file" if self.values_file is not None else "none"

    @property
    def values_meta(self):
        """The ``/values`` attributes and row count (``n_voxels``, ``spacing_ijk``, ``gradient_magnitude_scale``)
        of wherever the values are, or None."""
        h = self._values_holder()
        return None if h is None else h.values

    def values_io(self):
        """The values file's :class:`isplat.fileio.ReadCounter` (None while it is not open)."""
        return None if self._values_file is None else self._values_file.io

    def values_counts(self) -> tuple[int, int]:
        """``(bytes requested, bytes HDF5 read)`` from the values file so far (0, 0 without one)."""
        vf = self._values_file
        return (0, 0) if vf is None else (int(vf.bytes_read), int(vf.io.bytes))

    def verify_all(self) -> None:
        """Check every chunk of every dataset against the file's chunk hashes (``isplat stats``)."""
        with self.session(), hdf5_errors(self.path, "datasets"):
            for d in hashed_layout(self._handle)[0]:
                self.verifier.verify_all(self._handle, d)

    def _need_values(self):
        if self.values is None:
            raise IsplatError(f"{self.path}: this index holds no channel values (/values, built without them); "
                              f"rebuild it: {_rebuild_hint(self.path, None)}")
        return self.values

    def _delegate_values(self):
        """The values file to read from instead of this file (version 6), or None (read ``/values`` here);
        neither: the error naming the command that writes them."""
        if self.values is not None:
            return None
        vf = self.values_file
        if vf is None:
            where = f"no values file {values_path(self.path)}" if self.version >= FORMAT_VERSION_VALUES_FILE else \
                "no channel values (/values, built without them)"
            raise IsplatError(f"{self.path}: this index has {where}; rebuild it: {_rebuild_hint(self.path, None)}")
        return vf

    def value_ptr(self, g=None) -> np.ndarray:
        """int64[257], checked: the values of density ``d`` are rows ``ptr[d] .. ptr[d + 1] - 1``."""
        if g is None and self._delegate_values() is not None:
            return self._delegate_values().value_ptr()
        vm = self._need_values()
        if g is None:
            with self._open("values") as g:
                return self.value_ptr(g)
        ptr = self._read(g, "density_voxel_ptr", 0, 257)
        if ptr[0] != 0 or np.any(np.diff(ptr) < 0) or ptr[256] != vm.n_voxels:
            raise IsplatError(f"{self.path}: /values/density_voxel_ptr is not non-decreasing from 0 to the "
                              f"{vm.n_voxels} rows of the value datasets")
        stray = np.flatnonzero((np.diff(ptr) > 0) & ~self._indexed)
        if stray.size:
            raise IsplatError(f"{self.path}: /values/density_voxel_ptr has rows for density {int(stray[0])}, "
                              f"outside density_ranges")
        return ptr

    def read_values(self, channels, intervals) -> tuple[np.ndarray, dict]:
        """The values of ``channels`` for the voxels of inclusive density ``intervals``: per interval one
        contiguous row range of each channel, concatenated (density-major, then by position). Returns
        ``(ptr, {channel: values})``."""
        if self._delegate_values() is not None:
            return self._delegate_values().read_values(channels, intervals)
        self._need_values()
        ivs = self._intervals(intervals)
        out = {}
        with self._open("values") as g:
            ptr = self.value_ptr(g)
            for ch in channels:
                if ch not in VALUE_CHANNELS:
                    raise IsplatError(f"{self.path}: no channel {ch!r} in /values (it has {VALUE_CHANNELS})")
                parts = [self._read(g, ch, int(ptr[lo]), int(ptr[hi + 1])) for lo, hi in ivs]
                out[ch] = np.concatenate(parts) if parts else np.zeros(0, dtype=VALUE_DTYPES[ch])
        return ptr, out

    def _read_ptr(self, g, axis) -> np.ndarray:
        m = self._axis(axis)
        ptr = self._read(g, "density_entry_ptr", 0, 257)
        if ptr[0] != 0 or np.any(np.diff(ptr) < 0) or ptr[256] != m.n_entries:
            self._fail(axis, f"density_entry_ptr is not non-decreasing from 0 to {m.n_entries} entries")
        stray = np.flatnonzero((np.diff(ptr) > 0) & ~self._indexed)
        if stray.size:
            self._fail(axis, "has entries for a density outside density_ranges", density=stray[0])
        return ptr

    def _intervals(self, intervals) -> list[tuple[int, int]]:
        ivs = normalize_ranges(list(intervals))
        for lo, hi in ivs:
            if not self._indexed[lo:hi + 1].all():
                missing = lo + int(np.argmin(self._indexed[lo:hi + 1]))
                raise IsplatError(f"{self.path}: density {missing} (in {lo}:{hi}) was not indexed; this index "
                                  f"holds densities {_fmt_ranges(self.density_ranges)}; rebuild it with "
                                  f"isplat index --densities covering the transfer function")
        return ivs

    # -- public queries
    def voxel_counts(self, axis: str) -> np.ndarray:
        """int64[256]: indexed voxels per density along ``axis`` (0 for densities not indexed).

        Every table row of the axis is checked first (as a load with ``verify_offsets=True`` checks the rows it
        reads: slices, counts, offsets from 0 to the end of ``bytes``), so the figures are consistent ones."""
        m = self._axis(axis)
        with self._open(axis) as g:
            ptr = self._read_ptr(g, axis)
            sl = self._read(g, "entry_slice", 0, m.n_entries).astype(np.int64)
            cnt = self._read(g, "entry_voxel_count", 0, m.n_entries).astype(np.int64)
            off = self._read(g, "entry_byte_offset", 0, m.n_entries + 1)
        if off[0] != 0 or off[-1] != m.n_bytes:
            self._fail(axis, f"entry_byte_offset runs from {int(off[0])} to {int(off[-1])}, expected 0 to the "
                             f"{m.n_bytes} bytes of the blocks")
        dens = np.repeat(np.arange(256, dtype=np.int64), np.diff(ptr))
        self._check_entries(axis, m, dens, sl, cnt, off)
        cs = np.zeros(cnt.size + 1, dtype=np.int64)
        np.cumsum(cnt, out=cs[1:])
        return cs[ptr[1:]] - cs[ptr[:-1]]

    def nbytes(self, axis: str, intervals=None, verify_offsets: bool = False) -> int:
        """Bytes of blocks and tables: the whole axis, or exactly what ``load_axis(axis, intervals)`` reads."""
        m = self._axis(axis)
        if intervals is None:
            return 257 * 8 + m.n_entries * (4 + 4 + 8) + 8 + m.n_bytes
        ivs = self._intervals(intervals)
        total = 257 * 8
        with self._open(axis) as g:
            ptr = self._read_ptr(g, axis)
            for lo, hi in ivs:
                r0, r1 = int(ptr[lo]), int(ptr[hi + 1])
                if r1 > r0:
                    o0 = self._read(g, "entry_byte_offset", r0, r0 + 1)[0]
                    o1 = self._read(g, "entry_byte_offset", r1, r1 + 1)[0]
                    rows = (r1 - r0) * (4 + 4 + (8 if verify_offsets else 0))
                    total += rows + (8 if verify_offsets else 16) + max(0, int(o1) - int(o0))
        return total

    def load_axis(self, axis: str, intervals, verify_offsets: bool = False, slices=None) -> LoadedAxis:
        """Read and decode the blocks of ``axis`` whose densities fall in inclusive ``intervals``.

        Per interval (§2.2: the densities of interest are contiguous, so are their entries and blocks): one
        read of the rows of ``entry_slice`` and ``entry_voxel_count``, the two end rows of
        ``entry_byte_offset``, and one read of the byte range. Block boundaries inside the range follow from
        the counts; ``verify_offsets=True`` also reads every row of ``entry_byte_offset`` and checks each
        block against it.

        ``slices`` (slice indices, e.g. a slab of a frame): only the blocks of those slices are read and decoded
        (other slices hold none, their numbering kept). The interval's ``entry_slice`` rows are read and checked
        first; each run of rows whose slices are wanted (per density, the slices of a run of consecutive slice
        indices) is then read as an interval is: its counts, two end offsets and one byte range.
        """
        m = self._axis(axis)
        ivs = self._intervals(intervals)
        runs = None if slices is None else slice_runs(slices, m.n_slices)
        before = self.bytes_read
        dens_l, sl_l, cnt_l, st_l, en_l, buf_l = [], [], [], [], [], []
        base = 0
        shared = self._shared is not None and runs is not None
        self._gen += 1
        first, need = (self._shared.get("need", 0) if shared else 0), 0
        with self._open(axis) as g:
            ptr = self._shared_ptr(g, axis) if shared else self._read_ptr(g, axis)
            rows = self._shared_rows(g, axis, m, ptr, ivs, runs, verify_offsets) if shared else \
                self._rows(g, axis, m, ptr, ivs, runs, verify_offsets)
            for dens, sl, cnt, off in rows:
                self._check_entries(axis, m, dens, sl, cnt, off)
                buf = self._shared_bytes(g, axis, m, int(off[0]), int(off[-1])) if shared else \
                    self._read(g, "bytes", int(off[0]), int(off[-1]))
                need += cnt.size * 4 + off.size * 8 + buf.size     # its counts, offsets and blocks
                if buf.size != off[-1] - off[0]:
                    self._fail(axis, "bytes dataset is shorter than entry_byte_offset says", dens[-1], sl[-1])
                if verify_offsets:
                    st_l.append(off[:-1] - off[0] + base)
                    en_l.append(off[1:] - off[0] + base)
                    base += buf.size
                dens_l.append(dens)
                sl_l.append(sl)
                cnt_l.append(cnt)
                buf_l.append(buf)
        if shared:                     # boundary chunks the next slab did not take: dropped
            kept = self._shared.setdefault((axis, "chunks"), {})
            for ci in [ci for ci, (gen, _) in kept.items() if gen < self._gen]:
                del kept[ci]
            need += self._shared.get("need", 0) - first     # and the tables this load read first

        def cat(parts, dt):
            return np.concatenate(parts).astype(dt, copy=False) if parts else np.zeros(0, dtype=dt)

        dens, sl, cnt = cat(dens_l, np.int64), cat(sl_l, np.int64), cat(cnt_l, np.int64)
        # density-major entries -> slice-major blocks; the stable sort keeps densities increasing per slice (Fig. 1)
        order = np.argsort(sl, kind="stable")
        slice_block_ptr = np.zeros(m.n_slices + 1, dtype=np.int64)
        np.cumsum(np.bincount(sl, minlength=m.n_slices), out=slice_block_ptr[1:])
        block_voxel_ptr = np.zeros(sl.size + 1, dtype=np.int64)
        np.cumsum(cnt[order], out=block_voxel_ptr[1:])
        dest = np.empty(sl.size, dtype=np.int64)
        dest[order] = block_voxel_ptr[:-1]
        positions = np.empty(int(block_voxel_ptr[-1]), dtype=np.int32)
        if verify_offsets:
            bounds = (cat(st_l, np.int64), cat(en_l, np.int64))
            self._decode(axis, m, [cat(buf_l, np.uint8)], [cnt], dest, positions, dens, sl, bounds)
        else:
            self._decode(axis, m, buf_l, cnt_l, dest, positions, dens, sl)
        return LoadedAxis(axis, m.n_slices, m.n_a, m.n_b, slice_block_ptr, dens[order].astype(np.uint8),
                          block_voxel_ptr, positions, self.bytes_read - before, ivs, need if shared else None)

    def _rows(self, g, axis, m, ptr, ivs, runs, verify_offsets):
        """``(densities, slices, counts, offsets)`` of each run of entry rows to load (:meth:`_pieces`), read from
        the file: the counts, and every offset (``verify_offsets``) or the run's two end ones."""
        for r0, r1, dens, sl in self._pieces(g, axis, m, ptr, ivs, runs):
            cnt = self._read(g, "entry_voxel_count", r0, r1).astype(np.int64)
            if verify_offsets:
                off = self._read(g, "entry_byte_offset", r0, r1 + 1)
            else:
                off = np.array([self._read(g, "entry_byte_offset", r0, r0 + 1)[0],
                                self._read(g, "entry_byte_offset", r1, r1 + 1)[0]], dtype=np.int64)
            yield dens, sl, cnt, off

    def _shared_ptr(self, g, axis):
        key = (axis, "ptr")
        if key not in self._shared:
            self._shared[key] = self._read_ptr(g, axis)
            self._shared["need"] = self._shared.get("need", 0) + 257 * 8
        return self._shared[key]

    def _shared_rows(self, g, axis, m, ptr, ivs, runs, verify_offsets):
        """:meth:`_rows` from each interval's whole table rows, read and checked on the first load (shared)."""
        for lo, hi in ivs:
            key = (axis, lo, hi)
            if key not in self._shared:
                r0, r1 = int(ptr[lo]), int(ptr[hi + 1])
                dens = np.repeat(np.arange(lo, hi + 1, dtype=np.int64), np.diff(ptr[lo:hi + 2]))
                sl = self._read(g, "entry_slice", r0, r1).astype(np.int64)
                cnt = self._read(g, "entry_voxel_count", r0, r1).astype(np.int64)
                off = self._read(g, "entry_byte_offset", r0, r1 + 1).astype(np.int64)
                if r1 > r0:
                    self._check_entries(axis, m, dens, sl, cnt, off)
                self._shared[key] = (dens, sl, cnt, off)
                self._shared["need"] = self._shared.get("need", 0) + sl.size * 4     # its slices, needed once
            dens, sl, cnt, off = self._shared[key]
            for a, b in _kept_runs(sl, runs):
                yield dens[a:b], sl[a:b], cnt[a:b], (off[a:b + 1] if verify_offsets else off[[a, b]])

    def _shared_bytes(self, g, axis, m, o0: int, o1: int):
        """``bytes[o0:o1]``, in whole chunks: a chunk the previous load read at the edge of its range is taken
        from it (the slab before ends, or begins, within it) and this load's edge chunks are kept for the next."""
        if o1 <= o0:
            return np.zeros(0, dtype=np.uint8)
        c = int(g["bytes"].chunks[0])
        kept = self._shared.setdefault((axis, "chunks"), {})
        c0, c1 = o0 // c, (o1 - 1) // c
        head, tail = kept.pop(c0, (0, None))[1], kept.pop(c1, (0, None))[1]
        lo = (c0 + (head is not None)) * c
        hi = min(m.n_bytes, (c1 + 1) * c) if tail is None or c1 == c0 else c1 * c
        parts = [head] if head is not None else []
        if hi > lo:
            parts.append(self._read(g, "bytes", lo, hi))
        if tail is not None and c1 != c0:
            parts.append(tail)
        whole = np.concatenate(parts) if len(parts) > 1 else parts[0]
        kept[c0] = (self._gen, whole[:c])
        kept[c1] = (self._gen, whole[(c1 - c0) * c:])
        return whole[o0 - c0 * c:o1 - c0 * c]

    def _decode(self, axis, m: _AxisMeta, bufs, counts, dest, positions, dens, sl, bounds=None) -> None:
        """Decode the blocks of ``bufs`` (one contiguous run of blocks each, their voxel ``counts``) into
        ``positions`` at ``dest``; with ``bounds`` (every block's start and end in the one buffer, from
        ``entry_byte_offset``) each block is checked against them. A corrupt block fails naming its density and
        slice (``dens``, ``sl``: the blocks' own, in the order read)."""
        first = 0
        for buf, c in zip(bufs, counts):
            n = c.size
            if bounds is None:
                status, e = codec.decode_stream(buf, c, dest[first:first + n], m.n_a, m.n_b, m.escape_width,
                                                positions)
            else:
                status, e = codec.decode_blocks(buf, bounds[0], bounds[1], c, dest, m.n_a, m.n_b, m.escape_width,
                                                positions)
            if status != codec.OK:
                self._fail(axis, f"corrupt block: {codec.ERROR_TEXT[int(status)]}", dens[first + e], sl[first + e])
            first += n

    def _pieces(self, g, axis, m: _AxisMeta, ptr, ivs, runs):
        """``(r0, r1, densities, slices)`` of each contiguous run of entry rows to load: the whole row range of
        each interval, or (``runs`` of wanted slices) the runs of its rows whose slices are wanted."""
        for lo, hi in ivs:
            r0, r1 = int(ptr[lo]), int(ptr[hi + 1])
            if r1 == r0:
                continue
            dens = np.repeat(np.arange(lo, hi + 1, dtype=np.int64), np.diff(ptr[lo:hi + 2]))
            sl = self._read(g, "entry_slice", r0, r1).astype(np.int64)
            if runs is None:
                yield r0, r1, dens, sl
                continue
            self._check_slices(axis, m, dens, sl)
            for a, b in _kept_runs(sl, runs):
                yield r0 + a, r0 + b, dens[a:b], sl[a:b]

    def _check_slices(self, axis, m: _AxisMeta, dens, sl):
        """``entry_slice`` rows below ``n_slices`` and strictly increasing within each density."""
        bad = np.flatnonzero((sl >= m.n_slices) | (sl < 0))
        if bad.size:
            self._fail(axis, f"entry_slice is not below n_slices = {m.n_slices}", dens[bad[0]], sl[bad[0]])
        bad = np.flatnonzero((dens[1:] == dens[:-1]) & (sl[1:] <= sl[:-1]))
        if bad.size:
            self._fail(axis, "entry_slice is not increasing within the density", dens[bad[0] + 1], sl[bad[0] + 1])

    def _check_entries(self, axis, m: _AxisMeta, dens, sl, cnt, off):
        """Check one interval's entry rows before compiled code uses them (formats/index.md, Reading)."""
        def first(bad, msg):
            idx = np.flatnonzero(bad)
            if idx.size:
                e = idx[0]
                self._fail(axis, msg, dens[e], sl[e])

        first(sl >= m.n_slices, f"entry_slice is not below n_slices = {m.n_slices}")
        same = dens[1:] == dens[:-1]
        first(np.r_[False, same & (sl[1:] <= sl[:-1])], "entry_slice is not increasing within the density")
        first((cnt < 1) | (cnt > m.n_a * m.n_b), f"entry_voxel_count is not in 1..{m.n_a * m.n_b}")
        first((off[:-1] < 0) | (off[1:] < off[:-1]) | (off[1:] > m.n_bytes),
              f"entry_byte_offset is decreasing or outside 0..{m.n_bytes}")
        if off.size == cnt.size + 1:
            length = off[1:] - off[:-1]
            first((length < cnt) | (length > cnt * codec.escape_cost(m.escape_width)),
                  "block byte length does not fit its voxel count")
        else:   # only the interval's two end offsets
            length = int(off[-1] - off[0])
            if length < cnt.sum() or length > cnt.sum() * codec.escape_cost(m.escape_width):
                self._fail(axis, f"byte range {int(off[0])}:{int(off[-1])} does not fit the voxel counts "
                           f"of densities {int(dens[0])}..{int(dens[-1])}", dens[0], sl[0])
        # a load allocates sum(counts): bounded per density by n_slices * n_a * n_b
        per_density = np.bincount(dens - dens.min(), weights=cnt) if dens.size else np.zeros(0)
        if per_density.size and per_density.max() > m.n_slices * m.n_a * m.n_b:
            self._fail(axis, "voxel counts exceed the slices' size", dens.min() + int(np.argmax(per_density)))


def _kept_runs(sl, runs):
    """``(a, b)``: each run of consecutive rows of ``sl`` (entry slices) whose slices fall in ``runs``."""
    keep = np.zeros(sl.size + 2, dtype=np.int8)
    for s0, s1 in runs:
        keep[1:-1] |= (sl >= s0) & (sl < s1)
    edges = np.flatnonzero(np.diff(keep))            # starts and ends of the runs of kept rows
    return [(int(a), int(b)) for a, b in zip(edges[0::2], edges[1::2])]


def _fmt_ranges(ranges) -> str:
    return ",".join(f"{lo}:{hi}" for lo, hi in ranges)


def _rebuild_hint(p, f) -> str:
    return f"isplat index AUG.h5 -o {p} --force (AUG.h5: the augmented volume it was built from)"


def _stored_ranges(p, a) -> list[tuple[int, int]]:
    """``density_ranges`` exactly as §2 says: int64 (R, 2), in 0..255, sorted, disjoint and not touching."""
    raw = attr_array(p, a, "density_ranges", "i", (-1, 2))
    if raw.shape[0] < 1:
        raise IsplatError(f"{p}: attribute 'density_ranges' is empty, expected at least one range")
    ranges = [(int(lo), int(hi)) for lo, hi in raw]
    try:
        normal = normalize_ranges(ranges)
    except IsplatError as exc:
        raise IsplatError(f"{p}: attribute 'density_ranges': {exc}") from None
    if normal != ranges:
        raise IsplatError(f"{p}: attribute 'density_ranges' is {raw.tolist()}, expected sorted, disjoint ranges "
                          f"that do not touch (hi + 1 < next lo), e.g. {[list(r) for r in normal]}")
    return ranges


@contextlib.contextmanager
def _validating(f, keep: bool):
    """``f`` for the checks of an opening: closed after them, or (``keep``, when they pass) left open for the
    first :meth:`IndexFile.session` to use (HDF5 then does not read again the objects the checks read)."""
    try:
        yield f
    except BaseException:
        f.close()
        raise
    if not keep:
        f.close()


def open_index(path, keep_open: bool = False) -> IndexFile:
    """Open and validate an index file's attributes and dataset shapes; raise :class:`IsplatError` on any problem.
    ``keep_open``: the file stays open for the first :meth:`~IndexFile.session` (a load that follows at once; its
    values file likewise), which closes it."""
    counter = ReadCounter()
    p, f = open_hdf5(path, "index", FORMAT_NAME, FORMAT_VERSION, rebuild=_rebuild_hint, older=OLDER_VERSIONS,
                     counter=counter)
    with _validating(f, keep_open), hdf5_errors(p, "attributes and tables"):
        a = ReadAttrs(f.attrs)
        version = int(a["format_version"])
        shape = tuple(int(x) for x in attr_array(p, a, "shape", "i", (3,)))
        check_string_attrs(p, a, ("density_sha256", "created_by"))
        sha = attr_string(a, "density_sha256")
        if min(shape) < 1:
            raise IsplatError(f"{p}: attribute 'shape' is {shape}, expected three positive sizes")
        if sha is None or len(sha) != 64 or any(c not in "0123456789abcdef" for c in sha):
            raise IsplatError(f"{p}: attribute 'density_sha256' is not a SHA-256 hex digest (64 lower-case hex digits)")
        ranges = _stored_ranges(p, a)
        if "axes" not in f or not isinstance(f["axes"], h5py.Group):
            raise IsplatError(f"{p}: group '/axes' is missing")
        values = _check_values_group(p, f, ranges, version, shape)
        names = list(f["axes"].keys())
        if not names:
            raise IsplatError(f"{p}: group '/axes' holds no axis")
        meta = {}
        for name in names:
            if name not in AXES:
                raise IsplatError(f"{p}: unknown axis group '/axes/{name}'; expected i, j or k")
            meta[name] = _check_axis_group(p, f["axes"][name], name, shape, version)
        attrs = attr_values(a)
        channel = _check_channel(p, a, version, values)
        datasets, hashed = hashed_layout(f)
        verifier = chunkhash.open_verifier(p, f, sha, datasets, chunkhash.attributes_of(f, hashed, a),
                                           _rebuild_hint(p, f), root_attrs=a)
    idx = IndexFile(p, shape, sha, ranges, meta, attrs, version, values, counter, verifier)
    idx.channel = channel
    idx._kept, idx.keep_open = (f if keep_open else None), keep_open
    return idx


def open_values(path, idx: IndexFile, keep_open: bool = False) -> IndexFile:
    """Open and validate the values file ``path`` of version-6 index ``idx`` (formats/index.md §9): its format,
    its ``/values``, its chunk hashes' key, and that it belongs to ``idx`` (the same ``shape``, ``density_sha256``
    and ``density_ranges``, and ``index_chunk_hash_check`` equal to the index's ``chunk_hash_check``). Returns an
    :class:`IndexFile` without axes whose :meth:`~IndexFile.read_values` reads it."""
    counter = ReadCounter()
    hint = _rebuild_hint(idx.path, None)
    p, f = open_hdf5(path, "values file", VALUES_FORMAT_NAME, VALUES_FORMAT_VERSION, rebuild=lambda p, f: hint,
                     older=(FORMAT_VERSION_VALUES_FILE,), counter=counter)
    with _validating(f, keep_open), hdf5_errors(p, "attributes"):
        a = ReadAttrs(f.attrs)
        version = int(a["format_version"])
        if version != idx.version:
            raise IsplatError(f"{p}: format version {version} beside an index of version {idx.version}; rebuild "
                              f"both: {hint}")
        shape = tuple(int(x) for x in attr_array(p, a, "shape", "i", (3,)))
        check_string_attrs(p, a, ("density_sha256", "created_by", "index_chunk_hash_check"))
        sha, own = attr_string(a, "density_sha256"), attr_string(a, "index_chunk_hash_check")
        ranges = _stored_ranges(p, a)
        if (shape, sha, ranges, own) != (tuple(idx.shape), idx.density_sha256, list(idx.density_ranges),
                                         idx.attrs.get(chunkhash.CHECK_ATTR)):
            raise IsplatError(f"{p}: the channel values of another index than {idx.path} (another volume, density "
                              f"ranges or build); rebuild both: {hint}")
        if "values" not in f:
            raise IsplatError(f"{p}: group '/values' is missing; rebuild it: {hint}")
        values = _check_values_group(p, f, ranges, version, shape)
        datasets, hashed = hashed_layout(f)
        verifier = chunkhash.open_verifier(p, f, sha, datasets, chunkhash.attributes_of(f, hashed, a), hint,
                                           root_attrs=a)
        attrs = attr_values(a)
    vf = IndexFile(p, shape, sha, ranges, {}, attrs, version, values, counter, verifier)
    vf._kept = f if keep_open else None
    return vf


def _check_channel(p, a, version: int, values) -> str:
    """What the index indexes: ``"density"`` (version 4) or ``"labels"`` (version 5, formats/index.md §10: the
    attributes ``channel`` and ``labels_sha256``, no ``/values``)."""
    if version != FORMAT_VERSION_LABELS:
        return "density"
    check_string_attrs(p, a, ("channel", "labels_sha256"))
    channel, sha = attr_string(a, "channel"), attr_string(a, "labels_sha256")
    if channel != "labels":
        raise IsplatError(f"{p}: attribute 'channel' is {channel!r}, expected 'labels' (format version 5)")
    if len(sha) != 64 or any(c not in "0123456789abcdef" for c in sha):
        raise IsplatError(f"{p}: attribute 'labels_sha256' is not 64 lower-case hex digits")
    if values is not None:
        raise IsplatError(f"{p}: an index of the labels has no '/values'")
    return channel


def _check_values_group(p, f, ranges, version, shape) -> _ValuesMeta | None:
    """``/values`` as §9 says (OPTIONAL in version 4: absent, the renderer gathers the channel values from the
    augmented file; its absence is covered by the chunk hashes' key, so it cannot be deleted silently)."""
    if "values" not in f:
        return None
    if version >= FORMAT_VERSION_VALUES_FILE and attr_string(f.attrs, "format", ascii_ok=True) == FORMAT_NAME:
        raise IsplatError(f"{p}: a version-{version} index has no '/values' (its channel values are in "
                          f"{values_path(p).name}, beside it); rebuild it: {_rebuild_hint(p, f)}")
    if not isinstance(f["values"], h5py.Group):
        raise IsplatError(f"{p}: '/values' is not a group")
    g = f["values"]
    where = f"{p}: /values"
    spacing = tuple(float(x) for x in attr_array(where, g.attrs, "spacing_ijk", "f", (3,)))
    gscale = float(attr_array(where, g.attrs, "gradient_magnitude_scale", "f"))
    if min(spacing) <= 0 or gscale < 0:
        raise IsplatError(f"{where}: attributes 'spacing_ijk' {spacing} and 'gradient_magnitude_scale' {gscale}: "
                          f"expected positive spacings and a scale >= 0")
    _check_datasets(where, g, VALUE_DTYPES, version)
    if g["density_voxel_ptr"].shape[0] != 257:
        raise IsplatError(f"{where}/density_voxel_ptr: length {g['density_voxel_ptr'].shape[0]}, expected 257")
    n = int(g["normal"].shape[0])
    if g["gradient_magnitude"].shape[0] != n:
        raise IsplatError(f"{where}/gradient_magnitude: length {g['gradient_magnitude'].shape[0]}, expected "
                          f"{n} (the length of /values/normal)")
    if n > int(np.prod(shape, dtype=np.int64)):
        raise IsplatError(f"{where}/normal: {n} rows, more than the {int(np.prod(shape, dtype=np.int64))} voxels of "
                          f"shape {shape}")
    return _ValuesMeta(n, spacing, gscale)


def _check_datasets(where: str, g, dtypes: dict, version: int) -> None:
    """Every dataset of ``dtypes`` is in group ``g``: 1-D, of its dtype, chunked (version 7: without filters;
    older: with Fletcher-32 checksums, §1)."""
    check = check_hashed_dataset if version >= FORMAT_VERSION else check_checked_dataset
    for name, dt in dtypes.items():
        if name not in g or not isinstance(g[name], h5py.Dataset):
            raise IsplatError(f"{where}: dataset {name!r} is missing")
        ds = g[name]
        if ds.ndim != 1:
            raise IsplatError(f"{where}/{name}: expected 1-D, has shape {ds.shape}")
        if ds.dtype != np.dtype(dt):
            raise IsplatError(f"{where}/{name}: dtype {ds.dtype}, expected {np.dtype(dt)} ({dt})")
        check(f"{where}/{name}", ds)


def _check_axis_group(p, g, axis, shape, version: int) -> _AxisMeta:
    where = f"{p}: /axes/{axis}"
    if not isinstance(g, h5py.Group):
        raise IsplatError(f"{where} is not a group")
    n_slices, n_a, n_b = axis_geometry(shape, axis)
    try:
        ew_expected = escape_width(n_a, n_b)
    except IsplatError as exc:
        raise IsplatError(f"{where}: {exc}") from None
    expect = {"axis": axis, "n_slices": n_slices, "in_slice_axes": IN_SLICE_AXES[axis], "n_a": n_a, "n_b": n_b,
              "escape_width": ew_expected}
    ga = ReadAttrs(g.attrs)
    for key, want in expect.items():
        if key not in ga:
            raise IsplatError(f"{where}: missing attribute {key!r}")
        if isinstance(want, str):
            check_string_attrs(where, ga, (key,))
            got = attr_string(ga, key)
            ok = got == want
        else:
            got = int(attr_array(where, ga, key, "i"))
            ok = got == want
        if not ok:
            raise IsplatError(f"{where}: attribute {key!r} is {got!r}, expected {want!r} for shape {shape}")
    return _AxisMeta(axis, n_slices, n_a, n_b, ew_expected, -1, -1)


def _check_axis_datasets(p, g, m: _AxisMeta, version: int) -> _AxisMeta:
    """The datasets of axis group ``g`` (§4): present, typed, chunked as ``version`` says, of consistent lengths;
    ``m`` with the table sizes."""
    where = f"{p}: /axes/{m.axis}"
    _check_datasets(where, g, DATASET_DTYPES, version)
    n_e = g["entry_slice"].shape[0]
    if g["density_entry_ptr"].shape[0] != 257:
        raise IsplatError(f"{where}/density_entry_ptr: length {g['density_entry_ptr'].shape[0]}, expected 257")
    if g["entry_voxel_count"].shape[0] != n_e:
        raise IsplatError(f"{where}/entry_voxel_count: length {g['entry_voxel_count'].shape[0]}, expected {n_e}")
    if g["entry_byte_offset"].shape[0] != n_e + 1:
        raise IsplatError(f"{where}/entry_byte_offset: length {g['entry_byte_offset'].shape[0]}, expected {n_e + 1}")
    return _AxisMeta(m.axis, m.n_slices, m.n_a, m.n_b, m.escape_width, int(n_e), int(g["bytes"].shape[0]))
