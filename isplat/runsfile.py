"""The range-runs file ``NAME.runs.idx.h5`` beside an index (formats/runs.md): written by ``isplat index`` from
the augmented file, layer of bricks by layer (three passes: the keys' histogram, the runs' sizes, the runs);
opened and read by :func:`open_runs` / :func:`read_runs`, which check everything the format says before any
array is indexed with what the file holds.
"""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path
from typing import NamedTuple

import h5py
import numpy as np

from . import chunkhash, runs as R
from .errors import IsplatError
from .fileio import (ReadAttrs, ReadCounter, attr_array, attr_string, check_hashed_dataset, check_string_attrs,
                     create_group, create_hashed_dataset, hdf5_errors, open_hdf5, read_chunk_span,
                     set_string_attr)

FORMAT_NAME = "isplat-runs"
FORMAT_VERSION = 2
# read too: version 1's positions (lists, 64-byte bitmaps above 32 voxels; formats/runs.md §7)
OLDER_VERSIONS = (1,)
KEY = "union"
PTRS = ("run_voxel_ptr", "run_brick_ptr", "run_position_ptr")
DTYPES = {
    "run_voxel_ptr": "<i8", "run_brick_ptr": "<i8", "run_position_ptr": "<i8",
    "brick_number": "<u4", "brick_voxel_count": "<u2", "positions": "|u1",
    "density": "|u1", "normal": "<u2", "gradient_magnitude": "|u1",
}
DATASETS = tuple(f"runs/{n}" for n in DTYPES)
HASH = "xxh3"                                          # the chunk hash (formats/runs.md §2; isplat.chunkhash)
VALUE_CHANNELS = ("normal", "gradient_magnitude")     # read or not (RunsFile.read); the density always
HASHED_ATTRS = tuple(("", n) for n in ("format", "format_version", "shape", "density_sha256",
                                       "augmented_chunk_hash_check", "key", "brick", "lo_first", "hi_first"))


# HDF5's chunk cache per dataset while writing: each layer of bricks adds a piece to every run, so a dataset is
# written at up to R places in turn (64 runs by default); with HDF5's 1 MiB the partial chunks were read back and
# written again (the ct-chest sample, 512 x 512 x 133: the writes took 1.8 s of 6.2; 0.7 s with 64 MiB; 8 and
# 16 MiB timed alike, 8 MiB adds 64 MB to isplat index's peak memory there).
WRITE_CACHE = 8 << 20


def runs_path(index_path) -> Path:
    """``NAME.idx.h5`` -> ``NAME.runs.idx.h5`` (else INDEX + ``.runs.idx.h5``), as the values file is named."""
    s = str(index_path)
    return Path(s[: -len(".idx.h5")] + ".runs.idx.h5" if s.endswith(".idx.h5") else s + ".runs.idx.h5")


def _hint(p) -> str:
    return f"isplat index AUG.h5 -o INDEX.idx.h5 --force (AUG.h5: the augmented volume; {Path(p).name} is " \
           f"written beside INDEX.idx.h5)"


# ----------------------------------------------------------------------------------------------- write

def build_runs_file(aug_path, index_path, force: bool = False) -> Path:
    """Write the runs file of augmented file ``aug_path`` beside the index ``index_path`` (:func:`runs_path`),
    atomically (``isplat index`` does after the index and its values file; formats/runs.md §1)."""
    from .augfile import open_augmented
    from .fileio import atomic_output, create_hdf5
    from .index.store import _channel_reader

    aug = open_augmented(aug_path)
    path = runs_path(index_path)
    with atomic_output(path, force) as tmp:
        with create_hdf5(tmp, chunk_cache=WRITE_CACHE) as f, _channel_reader(aug) as read:
            write_runs(f, aug, read)
    return path


def write_runs(f: h5py.File, aug, read, bins=R.DEFAULT_BINS) -> R.Cut:
    """Write the runs of augmented volume ``aug`` (open, validated; ``read(channel, k0, k1)`` its k-planes) into
    the new HDF5 file ``f``: root attributes, ``/runs``, then the chunk hashes. Memory: a layer of bricks."""
    shape = tuple(int(n) for n in aug.shape)
    nk = shape[0]

    def keys(k0, k1):
        a, b = max(0, k0 - 1), min(nk, k1 + 1)
        return R.layer_key(read("density", a, b), k0 - a, k1 - a)

    h2 = np.zeros((256, 256), dtype=np.int64)
    for k0, k1 in R.layers(shape):
        h2 += R.key_histogram(*keys(k0, k1))
    cut = R.dp_cut_of(h2, *bins)
    n_run = R.n_runs(cut)

    def parts():
        for k0, k1 in R.layers(shape):
            run = R.run_of(*keys(k0, k1), cut)
            yield R.layer_runs(run, k0, shape, read("density", k0, k1), read("normal", k0, k1),
                               read("gradient_magnitude", k0, k1), n_run)

    ptrs = R.total_pointers(R.layer_pointers(R.run_of(*keys(k0, k1), cut), n_run) for k0, k1 in R.layers(shape))
    out = _create(f, aug.shape, aug.density_sha256, aug.attrs.get(chunkhash.CHECK_ATTR, ""), cut, ptrs)
    R.assemble(parts(), ptrs, out)
    _finish(f)
    return cut


def write_runs_arrays(f: h5py.File, shape, density_sha256: str, augmented_check: str, cut: R.Cut,
                      runs: R.Runs) -> None:
    """Write the runs ``runs`` (:func:`isplat.runs.build_runs`, or any arrays: tests of the reader's checks)
    into the new HDF5 file ``f``, with their chunk hashes."""
    out = _create(f, shape, density_sha256, augmented_check, cut, runs[:3])
    for name, ds in out.items():
        if ds.shape[0]:
            ds[...] = getattr(runs, name)
    _finish(f)


def chunk_rows(n: int, itemsize: int) -> int:
    """Rows per chunk of a dataset of ``/runs`` of ``n`` rows of ``itemsize`` bytes (formats/runs.md §1): the
    power of two at most 2 sqrt(its bytes), between 256 and 65,536 bytes, at most its rows (at least 1). Four
    times the index's chunks (formats/index.md §1.1): a post load reads and hashes every chunk of a few long
    spans, where the chunk hash's per-chunk cost showed (the 512 x 512 x 133 chest's runs: 54 ms against 30 read
    and hashed, 0.2% more bytes; docs/design.md)."""
    from .index.store import CHUNK_MAX, CHUNK_MIN

    nbytes = max(1, int(n) * int(itemsize))
    target = min(CHUNK_MAX, max(CHUNK_MIN, int(2 * nbytes ** 0.5)))
    target = 1 << (target.bit_length() - 1)
    return max(1, min(int(n), target // int(itemsize)))


def _create(f: h5py.File, shape, sha: str, check: str, cut: R.Cut, ptrs) -> dict:
    """The root attributes and ``/runs`` with its pointer tables written; the other datasets (returned by name)
    made to the lengths the pointers give, to be filled."""
    _write_root(f, shape, sha, check, cut)
    g = create_group(f, "runs")
    length = {n: int(ptrs[PTRS.index(R.PTR_OF[n])][-1]) for n in R.RUN_ARRAYS}
    out = {}
    for name, dt in DTYPES.items():
        n = len(ptrs[0]) if name in PTRS else length[name]
        ds = create_hashed_dataset(g, name, (n,), dt, chunks=(chunk_rows(n, np.dtype(dt).itemsize),))
        if name in PTRS:
            ds[...] = np.asarray(ptrs[PTRS.index(name)], dtype=dt)
        else:
            out[name] = ds
    return out


def _finish(f: h5py.File) -> None:
    """The chunk hashes (formats/runs.md §2), once everything else is written."""
    from .index.store import _hash_table

    chunkhash.write_tables(f, attr_string(f.attrs, "density_sha256"), DATASETS,
                           chunkhash.attributes_of(f, HASHED_ATTRS), create=_hash_table, algorithm=HASH)


def _write_root(f: h5py.File, shape, sha: str, check: str, cut: R.Cut) -> None:
    from . import __version__

    set_string_attr(f, "format", FORMAT_NAME)
    f.attrs["format_version"] = np.int64(FORMAT_VERSION)
    f.attrs["shape"] = np.asarray(shape, dtype="<i8")
    set_string_attr(f, "density_sha256", str(sha))
    set_string_attr(f, "augmented_chunk_hash_check", str(check))
    set_string_attr(f, "key", KEY)
    f.attrs["brick"] = np.int64(R.BRICK)
    f.attrs["lo_first"] = np.asarray(cut.lo, dtype="<i8")
    f.attrs["hi_first"] = np.asarray(cut.hi, dtype="<i8")
    set_string_attr(f, "created_by", f"isplat {__version__}")


# ----------------------------------------------------------------------------------------------- read

class RunsRead(NamedTuple):
    """What :meth:`RunsFile.read` returns: the voxels of the runs read (empty when placed), run after run (each
    by brick number, then place in the brick): flat positions ``i + n_i * (j + n_j * k)`` (int64), their density, normal
    (oct16) and gradient magnitude; ``bytes_read``: what HDF5 read from the file since it was opened
    (attributes, pointer tables, hash-table rows and the runs' chunks); ``runs``: the runs read (bool);
    ``table``: the pool's brick table (uint32 per brick of the volume's grid, C order: its row, 0 for a brick no
    run read); ``loaded``: the voxels read as a bit set in the rows' layout (uint64 words, bit ``s % 64`` of word
    ``s // 64`` for the voxel at ``s = row * 512 + place in the brick``); ``placed``: with ``place=True``, the
    density, normal and gradient magnitude as a packed pool (isplat.runsplace.pack_rows: the voxel at place ``p``
    of row ``r`` at ``bases[r] + p``; a place no voxel read takes holds zero; a channel not read: empty), else
    None; ``bases``: each row's first place (``row * 512`` when not placed)."""
    positions: np.ndarray
    density: np.ndarray
    normal: np.ndarray
    gradient_magnitude: np.ndarray
    bytes_read: int
    runs: np.ndarray
    loaded: np.ndarray | None = None
    placed: tuple | None = None
    table: np.ndarray | None = None
    bases: np.ndarray | None = None


def _pool_table(shape, read) -> np.ndarray:
    """uint32 per brick of ``shape``'s grid of 8^3 bricks (C order): the pool row of each brick the spans
    ``read`` name (1, 2, ... in brick order), 0 for the others. A number beyond the grid gets no row: the
    placing refuses it (:func:`isplat.runsplace.place_runs`) before anything is written."""
    from . import runsplace

    grid = int(np.prod([-(-int(n) // runsplace.BRICK) for n in shape]))
    nums = np.concatenate([np.asarray(g["brick_number"], dtype=np.int64) for g in read] or [np.zeros(0, np.int64)])
    used = np.zeros(grid, dtype=bool)
    used[nums[(nums >= 0) & (nums < grid)]] = True
    table = np.zeros(grid, dtype=np.uint32)
    table[used] = np.arange(1, int(used.sum()) + 1, dtype=np.uint32)
    return table


class Fetched(NamedTuple):
    """Runs read and checked against their hashes, not yet placed (:meth:`RunsFile.fetch`): the file's path and
    shape, its pointer tables and runs' codes, the runs read (bool), their spans and per span the arrays read,
    the channels read besides the density, and the bytes (and 4 KB pages) HDF5 read from the file so far."""
    path: Path
    shape: tuple
    ptrs: tuple
    codes: tuple
    runs: np.ndarray
    spans: list
    read: list
    channels: tuple
    bytes_read: int
    pages_read: int
    version: int


class RunsFile:
    """An open, validated runs file (:func:`open_runs`); :meth:`read` reads runs; close it (or use ``with``)."""

    def __init__(self, path, f, counter, shape, sha, cut, ptrs, verifier, version):
        self.path, self._f, self.counter = path, f, counter
        self.shape, self.density_sha256, self.cut = shape, sha, cut
        self.ptrs, self.verifier, self.version = ptrs, verifier, version

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        if self._f is not None:
            self._f.close()
            self._f = None

    def verify_all(self) -> None:
        """Check every chunk of every dataset against the file's chunk hashes (``isplat stats``)."""
        with hdf5_errors(self.path, "datasets"):
            for d in DATASETS:
                self.verifier.verify_all(self._f, d)

    def runs_for(self, intervals) -> np.ndarray:
        """bool [runs]: the runs whose bin rectangle meets one of the inclusive ``intervals`` (None: every run)."""
        if intervals is None:
            return np.ones(R.n_runs(self.cut), dtype=bool)
        ivs = [(int(a), int(b)) for a, b in intervals]
        if any(not 0 <= a <= b <= 255 for a, b in ivs):
            raise IsplatError(f"{self.path}: intervals {ivs}: expected inclusive code intervals within 0..255")
        return R.runs_meeting(ivs, self.cut)

    def bricks_of(self, intervals=None) -> int:
        """How many distinct 8^3 bricks the runs meeting ``intervals`` hold voxels of (the rows of the pool
        :meth:`read` would place them in, row 0 aside): their ``brick_number`` rows read, checked against their
        hashes (4 bytes a brick of each run)."""
        sel = self.runs_for(intervals)
        bp = self.ptrs[1]
        nums = [self._get("brick_number", int(bp[a]), int(bp[b]), f"runs {a}..{b - 1}")
                for a, b in _spans(sel & (np.diff(bp) > 0))]
        return int(np.unique(np.concatenate(nums)).size) if nums else 0

    def read(self, intervals=None, channels=VALUE_CHANNELS, place: bool = False) -> RunsRead:
        """The runs meeting ``intervals`` (None: all, then every voxel of the volume must be read exactly once),
        each checked against its hashes and formats/runs.md §5 as its voxels are placed
        (:func:`isplat.runsplace.place_runs`). ``channels``: which of the normal and the gradient magnitude to
        read besides the density (the others come back empty, their bytes not read). ``place``: return the voxels
        written into a pool, one row of 8^3 voxels per brick the runs read (row 0 zeros), with its brick table,
        instead of their positions and values run after run (:class:`RunsRead`). :meth:`fetch`, then
        :meth:`place` (which needs no open file: a thread can run it while the caller reads other files)."""
        return self.place(self.fetch(intervals, channels), place)

    def fetch(self, intervals=None, channels=VALUE_CHANNELS) -> "Fetched":
        """The runs meeting ``intervals`` read (their chunks checked against their hashes), not yet placed."""
        sel = self.runs_for(intervals)
        bad = set(channels) - set(VALUE_CHANNELS)
        if bad:
            raise ValueError(f"channels {sorted(bad)}: expected some of {VALUE_CHANNELS}")
        spans = _spans(sel & (np.diff(self.ptrs[0]) > 0))
        read = [self._read_span(a, b, tuple(channels)) for a, b in spans]
        return Fetched(self.path, tuple(self.shape), self.ptrs, R.run_codes(self.cut), sel, spans, read,
                       tuple(channels), int(self.counter.bytes), self.counter.page_bytes(), self.version)

    @staticmethod
    def place(got: "Fetched", place: bool = True) -> RunsRead:
        """The runs ``got`` (:meth:`fetch`) checked (formats/runs.md §5) and placed into a packed pool
        (``place``: the bricks' masks first, :func:`isplat.runsplace.mask_runs`, the rows packed by them,
        :func:`isplat.runsplace.pack_rows`, then the voxels placed), or their positions (:meth:`read`)."""
        from . import runsplace

        vp = got.ptrs[0]
        table = _pool_table(got.shape, got.read)
        rows = int(table.max(initial=0)) + 1
        pos = np.empty(0 if place else sum(int(vp[b] - vp[a]) for a, b in got.spans), dtype=np.int64)
        loaded = np.zeros(8 * rows, dtype=np.uint64)
        bases, n = np.arange(rows, dtype=np.int64) * runsplace.BRICK_VOXELS, 0
        checked = [np.zeros((3, 0), dtype=np.int64)] * len(got.spans)
        if place:
            for s, (a, b) in enumerate(got.spans):
                err, checked[s] = runsplace.mask_runs(*_span_args(got, a, b, got.read[s]), np.asarray(
                    got.shape, dtype=np.int64), table, loaded, got.version)
                _check(got, a, b, err)
            bases, n = runsplace.pack_rows(loaded)
            loaded[:] = 0                                   # (the placing's own: a voxel placed twice refused)
        outs = tuple(np.zeros(n if place and (name == "density" or name in got.channels) else 0, dtype=dt)
                     for name, dt in (("density", np.uint8), ("normal", np.uint16), ("gradient_magnitude", np.uint8)))
        at = 0
        for s, (a, b) in enumerate(got.spans):
            m = int(vp[b] - vp[a])
            _place(got, a, b, got.read[s], table, loaded, bases, pos[at:at + m], outs, checked[s])
            at += m
        voxels = int(np.prod(got.shape, dtype=np.int64))
        if got.runs.all() and at != voxels:
            raise IsplatError(f"{got.path}: the runs hold {at} voxels, the volume {voxels}")
        kept = [] if place else got.read
        if place:
            got.read.clear()                                # (placed: let go)
        cat = [np.concatenate([g[k] for g in kept]) if kept else np.zeros(0, dt)
               for k, dt in (("density", np.uint8), ("normal", np.uint16), ("gradient_magnitude", np.uint8))]
        return RunsRead(pos, *cat, got.bytes_read, got.runs, loaded, outs if place else None, table, bases)

    def _get(self, name: str, lo: int, hi: int, runs: str) -> np.ndarray:
        with hdf5_errors(self.path, f"dataset 'runs/{name}' [{lo}:{hi}] ({runs})"):
            try:
                return np.asarray(self.verifier.read(self._f, f"runs/{name}", (slice(lo, hi),), fetch=self._fetch))
            except IsplatError as exc:
                raise IsplatError(f"{exc} ({runs})") from None

    def _fetch(self, ds, lo: int, hi: int):
        return read_chunk_span(self.path, self.counter, ds, lo, hi)

    def _read_span(self, a: int, b: int, channels=VALUE_CHANNELS) -> dict:
        """Runs ``a .. b - 1`` (consecutive): one read per dataset (of ``channels`` besides the density and the
        positions; the others empty)."""
        vp, bp, pp = self.ptrs
        where = f"runs {a}..{b - 1}"
        names = (("brick_number", bp), ("brick_voxel_count", bp), ("positions", pp), ("density", vp),
                 ("normal", vp), ("gradient_magnitude", vp))
        return {n: self._get(n, int(ptr[a]), int(ptr[b]), where) if n not in VALUE_CHANNELS or n in channels
                else np.zeros(0, DTYPES[n]) for n, ptr in names}


def _span_args(got, a: int, b: int, g: dict) -> tuple:
    """Runs ``a .. b - 1``'s pointers (from 0) and their bricks' numbers, counts and position bytes (``g``)."""
    vp, bp, pp = (np.ascontiguousarray(p[a:b + 1] - p[a]) for p in got.ptrs)
    return bp, pp, vp, g["brick_number"], g["brick_voxel_count"], g["positions"]


def _place(got, a: int, b: int, g: dict, table, loaded, bases, pos, outs, checked) -> None:
    """Runs ``a .. b - 1`` read (``g``) checked (``checked``: their bricks' table from the masks' pass, or empty)
    and placed (:func:`isplat.runsplace.place_runs`)."""
    from . import runsplace

    bp, pp, vp, num, cnt, pdata = _span_args(got, a, b, g)
    lo_first, hi_last = (np.ascontiguousarray(x[a:b]) for x in got.codes)
    _check(got, a, b, runsplace.place_runs(bp, pp, vp, lo_first, hi_last, num, cnt, pdata, g["density"], g["normal"],
                                           g["gradient_magnitude"], np.asarray(got.shape, dtype=np.int64), table,
                                           loaded, bases, pos, *outs, got.version, checked))


def _check(got, a: int, b: int, err) -> None:
    """One line naming the file, the dataset and the fault of runs ``a .. b - 1``' error record ``err``, if any
    (:func:`isplat.runsplace.message`)."""
    from . import runsplace

    if err[0]:
        lo_first, hi_last = (np.ascontiguousarray(x[a:b]) for x in got.codes)
        name, text = runsplace.message(err, a, got.shape, lo_first, hi_last, got.version)
        raise IsplatError(f"{got.path}: dataset 'runs/{name}'{text}")


def _spans(sel: np.ndarray):
    """(a, b) of each stretch of consecutive True in ``sel``."""
    edges = np.diff(np.concatenate([[0], sel.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1).tolist(), np.flatnonzero(edges == -1).tolist()))


def open_runs(path, shape=None, density_sha256: str | None = None,
              augmented_chunk_hash_check: str | None = None) -> RunsFile:
    """Open and validate a runs file (formats/runs.md §4): its attributes, datasets, chunk hashes' key and
    pointer tables; with ``shape``, ``density_sha256``, ``augmented_chunk_hash_check`` (those of the augmented
    file it is read with), that it was written from that file. Every problem is one :class:`IsplatError`."""
    counter = ReadCounter()
    p, f = open_hdf5(path, "runs file", FORMAT_NAME, FORMAT_VERSION, older=OLDER_VERSIONS, counter=counter)
    try:
        with hdf5_errors(p, "attributes and pointer tables"):
            a = ReadAttrs(f.attrs)
            shape_f, sha, cut = _check_root(p, a)
            own = attr_string(a, "augmented_chunk_hash_check")
            for what, want, have in (("shape", None if shape is None else tuple(int(n) for n in shape), shape_f),
                                     ("density_sha256", density_sha256, sha),
                                     ("augmented_chunk_hash_check", augmented_chunk_hash_check, own)):
                if want is not None and want != have:
                    raise IsplatError(f"{p}: attribute {what!r} is {have}, the augmented file's {want}: the runs of "
                                      f"another volume or of another augmentation of it; rebuild it: {_hint(p)}")
            dsets = _check_datasets(p, f, shape_f, R.n_runs(cut))
            verifier = chunkhash.open_verifier(p, f, sha, DATASETS, chunkhash.attributes_of(f, HASHED_ATTRS, a),
                                               _hint(p), HASH, root_attrs=a)
            verifier.remember(f, {f"runs/{n}": ds for n, ds in dsets.items()})
            ptrs = tuple(_read_ptr(verifier, f, n) for n in PTRS)
            version = int(a["format_version"])
            _check_ptrs(p, dsets, ptrs, cut, version)
    except BaseException:
        f.close()
        raise
    return RunsFile(p, f, counter, shape_f, sha, cut, ptrs, verifier, version)


def _read_ptr(verifier, f, name: str) -> np.ndarray:
    """A pointer table, whole, its chunks checked (a failure names the runs whose rows the chunk holds)."""
    try:
        return np.asarray(verifier.read(f, f"runs/{name}"), dtype=np.int64)
    except IsplatError as exc:
        rows = int(f[f"runs/{name}"].chunks[0])
        off = str(exc).split("chunk at (", 1)[-1].split(")", 1)[0]
        runs = f"the offsets of runs {int(off)}..{int(off) + rows - 1}" if off.isdigit() else "the runs' offsets"
        raise IsplatError(f"{exc} ({runs})") from None


def read_runs(path, intervals=None, **tie):
    """``(flat positions, density, normal, gradient magnitude, bytes read)`` of the runs of ``path`` meeting
    ``intervals`` (inclusive code pairs; None: all), validated (:func:`open_runs`, :meth:`RunsFile.read`)."""
    with open_runs(path, **tie) as rf:
        got = rf.read(intervals)
    return got.positions, got.density, got.normal, got.gradient_magnitude, got.bytes_read


def _check_root(p, a):
    check_string_attrs(p, a, ("density_sha256", "created_by", "augmented_chunk_hash_check", "key"))
    shape = tuple(int(x) for x in attr_array(p, a, "shape", "i", (3,)))
    if min(shape) < 1:
        raise IsplatError(f"{p}: attribute 'shape' is {shape}, expected three positive sizes")
    sha = attr_string(a, "density_sha256")
    if len(sha) != 64 or any(c not in "0123456789abcdef" for c in sha):
        raise IsplatError(f"{p}: attribute 'density_sha256' is not a SHA-256 hex digest (64 lower-case hex digits)")
    own = attr_string(a, "augmented_chunk_hash_check")
    if own and (len(own) != 32 or any(c not in "0123456789abcdef" for c in own)):
        raise IsplatError(f"{p}: attribute 'augmented_chunk_hash_check' is not empty nor 32 lower-case hex digits")
    if attr_string(a, "key") != KEY:
        raise IsplatError(f"{p}: attribute 'key' is {attr_string(a, 'key')!r}, expected {KEY!r}")
    if int(attr_array(p, a, "brick", "i")) != R.BRICK:
        raise IsplatError(f"{p}: attribute 'brick' is {int(attr_array(p, a, 'brick', 'i'))}, expected {R.BRICK}")
    firsts = []
    for name in ("lo_first", "hi_first"):
        v = np.asarray(attr_array(p, a, name, "i", (-1,)), dtype=np.int64)
        if not 1 <= v.size <= 256 or v[0] != 0 or v[-1] > 255 or (v.size > 1 and not (np.diff(v) > 0).all()):
            raise IsplatError(f"{p}: attribute {name!r} is {v.tolist()[:8]}{'...' if v.size > 8 else ''}, expected "
                              f"1 to 256 bin edges from 0, strictly increasing, within 0..255")
        firsts.append(v)
    return shape, sha, R.Cut(firsts[0], firsts[1], f"{firsts[0].size}x{firsts[1].size}")


def _check_datasets(p, f, shape, n_run: int) -> dict:
    """``/runs``' datasets (formats/runs.md §4): present, 1-D, of their types, chunked without filters, of the
    lengths the shape and the runs give; returns ``{name: dataset}``."""
    g = f.get("runs")
    if not isinstance(g, h5py.Group):
        raise IsplatError(f"{p}: group '/runs' is missing; rebuild it: {_hint(p)}")
    dsets = {}
    for name, dt in DTYPES.items():
        ds = dsets[name] = g.get(name)
        if not isinstance(ds, h5py.Dataset):
            raise IsplatError(f"{p}: dataset 'runs/{name}' is missing; rebuild it: {_hint(p)}")
        if ds.ndim != 1 or ds.dtype != np.dtype(dt):
            raise IsplatError(f"{p}: dataset 'runs/{name}' is {ds.dtype} {ds.shape}, expected 1-D {np.dtype(dt)}")
        check_hashed_dataset(f"{p}: dataset 'runs/{name}'", ds)
    n = {name: int(ds.shape[0]) for name, ds in dsets.items()}
    want = dict.fromkeys(PTRS, n_run + 1)
    want.update(density=int(np.prod(shape, dtype=np.int64)), normal=n["density"], gradient_magnitude=n["density"],
                brick_voxel_count=n["brick_number"])
    for name, m in want.items():
        if n[name] != m:
            raise IsplatError(f"{p}: dataset 'runs/{name}' has {n[name]} rows, expected {m}")
    return dsets


def _check_ptrs(p, dsets: dict, ptrs, cut: R.Cut, version: int) -> None:
    """Each pointer table: from 0, non-decreasing, ending at its datasets' length (so every run's counts and
    offsets are non-negative, in bounds, not overlapping, summing to the length); a run that cannot hold a voxel
    (lo bin above hi bin) empty; a run's bricks at least one and at most its voxels, 512 voxels a brick at most;
    its position bytes 3 to 73 a brick (version 1: 2 to 64)."""
    lengths = {"run_voxel_ptr": dsets["density"].shape[0], "run_brick_ptr": dsets["brick_number"].shape[0],
               "run_position_ptr": dsets["positions"].shape[0]}
    for name, ptr in zip(PTRS, ptrs):
        step = np.diff(ptr)
        if ptr[0] != 0 or ptr[-1] != lengths[name] or (step < 0).any():
            r = int(np.flatnonzero(step < 0)[0]) if (step < 0).any() else (0 if ptr[0] != 0 else len(step) - 1)
            raise IsplatError(f"{p}: dataset 'runs/{name}', run {r}: offsets {int(ptr[r])}..{int(ptr[r + 1])}; "
                              f"expected from 0, non-decreasing, to the {lengths[name]} rows they point into")
    nv, nb, npos = (np.diff(x) for x in ptrs)
    lo_first, hi_last = R.run_codes(cut)
    least, most = (2, R.BITMAP_BYTES) if version == 1 else (3, R.MOST_POSITION_BYTES)
    for name, bad in (("run_voxel_ptr", (nv > 0) & (lo_first > hi_last)),
                      ("run_brick_ptr", ((nv > 0) != (nb > 0)) | (nb > nv) | (nv > R.BRICK_VOXELS * nb)),
                      ("run_position_ptr", (npos < least * nb) | (npos > most * nb))):
        if bad.any():
            r = int(np.flatnonzero(bad)[0])
            raise IsplatError(f"{p}: dataset 'runs/{name}', run {r}: {int(nv[r])} voxels in {int(nb[r])} bricks "
                              f"with {int(npos[r])} bytes of positions (codes {int(lo_first[r])}..{int(hi_last[r])}),"
                              f" which formats/runs.md §5 does not allow")


@contextmanager
def refusal(path, aug_path, index_path):
    """Inside the block, a problem with the runs file ``path`` (an :class:`IsplatError`, which names it) ends
    with the command that rebuilds it from ``aug_path`` beside ``index_path`` (formats/runs.md §6: a bad runs file
    is refused, never read around)."""
    try:
        yield
    except IsplatError as exc:
        text, cmd = str(exc), f"isplat index {aug_path} -o {index_path} --force"
        head, hint, tail = text.partition(f"; rebuild it: {_hint(path)}")
        if hint:                  # the reader's hint, last and with the files' names (after a read's "(runs a..b)")
            raise IsplatError(f"{head}{tail}; rebuild it: {cmd}") from None
        if "rebuild it" in text:
            raise
        p = Path(path)
        fix = f"remove it, then {cmd} writes it" if p.exists() and not p.is_file() else f"rebuild it: {cmd}"
        raise IsplatError(f"{text}; {fix}") from None
