"""Safe output files: checked up front, written under a temporary name, renamed on success.

A failed run leaves nothing behind, and nothing the user had is overwritten without ``force``.
"""

from __future__ import annotations

import contextlib
import errno
import io
import os
import stat
import tempfile
from pathlib import Path

import numpy as np

from .errors import IsplatError


def node_kind(mode: int) -> str | None:
    """None for a regular file, else what the node is ('a folder', 'a fifo (named pipe)', ...)."""
    if stat.S_ISREG(mode):
        return None
    for test, name in ((stat.S_ISDIR, "a folder"), (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a fifo (named pipe)"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"


def check_regular(path: str | os.PathLike, what: str = "input", max_bytes: int | None = None) -> None:
    """Refuse, before anything opens it, an existing ``path`` that is a fifo, device or socket (opening a fifo
    blocks until a writer comes; a device never ends), or larger than ``max_bytes``. A missing path or a folder
    is left to the caller's own message."""
    try:
        st = os.stat(path)
    except OSError:
        return
    kind = node_kind(st.st_mode)
    if kind == "a folder":
        return
    if kind:
        raise IsplatError(f"{path}: {what} is {kind}, expected a regular file")
    if max_bytes is not None and st.st_size > max_bytes:
        raise IsplatError(f"{path}: {what} file is {st.st_size} bytes, more than the {max_bytes} a {what} "
                          f"file may have")


def check_input(path: str | os.PathLike, what: str = "input") -> Path:
    """Return ``path`` as a Path if it is a readable regular file, else raise a one-line error."""
    p = Path(path)
    named = what if what.endswith(" file") else f"{what} file"      # ("values file", "runs file": not twice)
    if not p.exists():
        raise IsplatError(f"{p}: {named} does not exist")
    if p.is_dir():
        raise IsplatError(f"{p}: {what} is a folder, expected a file")
    check_regular(p, what)
    if not os.access(p, os.R_OK):
        raise IsplatError(f"{p}: {named} is not readable")
    return p


def check_output(path: str | os.PathLike, force: bool = False, probe: bool = True) -> Path:
    """Check that ``path`` may be written: its folder exists and takes new files (``probe``: a file is created
    there and removed), and ``path`` is new, or a regular file and ``force`` given. A folder, device, fifo or
    socket is never replaced, even with ``force``."""
    p = Path(path)
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.exists():
        raise IsplatError(f"{p}: output folder {parent} does not exist")
    if not parent.is_dir():
        raise IsplatError(f"{p}: {parent} is not a folder")
    kind = _existing_kind(p)
    if kind == "a folder":
        raise IsplatError(f"{p}: output is a folder, expected a file name")
    if kind:
        raise IsplatError(f"{p}: output is {kind}; isplat writes only regular files, a new name or (with --force) "
                          f"an existing file, never over {kind} even with --force")
    if kind is not False and not force:
        raise IsplatError(f"{p}: output exists; use --force to overwrite")
    if probe:
        probe_folder(p)
    return p


def _existing_kind(p) -> str | None | bool:
    """False when ``p`` does not exist, None when it is a regular file (or a link to one, or a dangling link),
    else what it is."""
    try:
        st = os.stat(p)
    except FileNotFoundError:
        return None if os.path.lexists(p) else False
    except OSError as exc:
        raise IsplatError(f"{p}: cannot inspect the output ({exc.strerror or exc})") from None
    return node_kind(st.st_mode)


def probe_folder(path: str | os.PathLike) -> None:
    """Refuse, before any work, an output whose folder does not take new files (read-only, no permission,
    /proc, a full disk's inode table): a file is created beside ``path`` and removed."""
    from . import interrupts

    with interrupts.deferred():                       # a signal between the two steps would leave the probe
        tmp = _temp_beside(Path(path), ".probe")
        with contextlib.suppress(OSError):
            os.unlink(tmp)


def _temp_beside(p: Path, suffix: str) -> str:
    """A new empty file in ``p``'s folder named after it (``.NAME.XXXX{suffix}``); the folder refusing it is one
    IsplatError line."""
    parent = p.parent if str(p.parent) else Path(".")
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=suffix, dir=parent)
    except OSError as exc:
        raise IsplatError(f"{p}: cannot create files in the output folder {parent} ({exc.strerror or exc})") from None
    os.close(fd)
    return tmp


# errors of writing a file (not of reading an input): a block's OSError with one of these is the output's
_WRITE_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EFBIG, errno.EIO, errno.EACCES, errno.EPERM}


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike, force: bool = False):
    """Yield a temporary path beside ``path``; move it to ``path`` only if the block succeeds.

    Without ``force`` the name is taken exclusively: a file that appeared there meanwhile (another run writing
    the same new name) is not replaced, and the run fails. With ``force`` a regular file is replaced, never a
    folder, device or fifo. Nothing is moved after a SIGINT or SIGTERM (:func:`isplat.interrupts.check`); the
    temporary file is removed on every failure, and named by the interrupted message when it was.

    >>> with atomic_output("out.h5", force=True) as tmp:   # doctest: +SKIP
    ...     write_everything(tmp)
    """
    from . import interrupts

    p = check_output(path, force, probe=False)
    tmp, committed = None, False
    try:
        with interrupts.deferred():                   # the name is known before a signal can end the run
            tmp = _temp_beside(p, ".part")
            # mkstemp makes the file owner-only; give it the mode an ordinary new file would get
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(tmp, 0o666 & ~umask)
        try:
            yield Path(tmp)
        except OSError as exc:
            ours = str(exc.filename) == tmp if exc.filename is not None else exc.errno in _WRITE_ERRNOS
            if ours:
                raise IsplatError(f"{p}: writing failed ({exc.strerror or exc})") from None
            raise
        interrupts.check()
        with interrupts.deferred():               # a signal now is raised once the output is whole, in place
            committed = _commit(tmp, p, force)
    except BaseException:
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
                if not committed:
                    interrupts.REMOVED.append(str(p))
        raise


def _commit(tmp: str, p: Path, force: bool) -> bool:
    """Move ``tmp`` to ``p``: exclusively without ``force`` (a hard link, which fails if ``p`` exists, or where
    links are not supported an O_EXCL placeholder); over a regular file only with it. True once ``p`` holds it."""
    if force:
        kind = _existing_kind(p)
        if kind:
            raise IsplatError(f"{p}: output became {kind} while isplat wrote it; not replaced")
        _os_step(p, os.replace, tmp, p)
        return True
    appeared = IsplatError(f"{p}: output appeared while isplat was writing it (another run writing the same "
                           f"name?); it was not replaced; use --force to overwrite")
    try:
        os.link(tmp, p)
    except FileExistsError:
        raise appeared from None
    except OSError:                                   # no hard links here (some network and FUSE file systems)
        try:
            os.close(os.open(p, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
        except FileExistsError:
            raise appeared from None
        except OSError as exc:
            raise IsplatError(f"{p}: cannot create the output ({exc.strerror or exc})") from None
        try:
            _os_step(p, os.replace, tmp, p)
        except BaseException:
            with contextlib.suppress(OSError):
                os.unlink(p)
            raise
        return True
    with contextlib.suppress(OSError):
        os.unlink(tmp)
    return True


def _os_step(p, fn, *args):
    try:
        fn(*args)
    except OSError as exc:
        raise IsplatError(f"{p}: cannot write the output ({exc.strerror or exc})") from None


def open_hdf5(path, what: str, format_name: str, version: int, rebuild=None, older=(), counter=None):
    """Open an isplat HDF5 container read-only after checking its ``format`` and ``format_version``
    attributes (an int64 scalar) and that it carries HDF5 metadata checksums; return ``(path, h5py.File)``.
    Every problem is one :class:`IsplatError` line; ``rebuild(path, file)`` gives the command that remakes
    an old file. Versions in ``older`` are read too (the caller checks what differs). ``counter``: a
    :class:`ReadCounter` that counts what HDF5 reads from the file (see :func:`open_counted`)."""
    import h5py

    p = check_input(path, what)
    try:
        f = h5py.File(_CountingRaw(p, counter), "r") if counter is not None else h5py.File(p, "r")
    except (OSError, KeyError, ValueError, RuntimeError) as exc:
        why = str(exc).strip().splitlines()[0] if str(exc).strip() else exc.__class__.__name__
        raise IsplatError(f"{p}: not a readable HDF5 file: truncated, corrupted or not HDF5 ({why[:160]})") from None
    try:
        with hdf5_errors(p, "root attributes"):
            check_string_attrs(p, f.attrs, ("format",), ascii_ok=True)   # UTF-8 checked once the version is
            fmt = attr_string(f.attrs, "format", ascii_ok=True)           # known (version 1 files have ASCII)
            ver = f.attrs.get("format_version")
            superblock = f.id.get_create_plist().get_version()[0]
        if fmt != format_name:
            raise IsplatError(f"{p}: attribute 'format' is {fmt!r}, expected {format_name!r}")
        ver_arr = np.asarray(ver) if ver is not None else None
        if ver_arr is None or ver_arr.shape != () or ver_arr.dtype != np.dtype("<i8"):
            raise IsplatError(f"{p}: attribute 'format_version' is {ver!r}"
                              f"{'' if ver_arr is None else f' ({ver_arr.dtype})'}, expected the int64 scalar "
                              f"{version}")
        with hdf5_errors(p, "root attributes"):
            stored = h5_type_name(f.attrs, "format_version")       # a big-endian int64 reads as a native one
        if stored != "H5T_STD_I64LE":
            raise IsplatError(f"{p}: attribute 'format_version' is stored as {stored}, expected the int64 scalar "
                              f"{version} (H5T_STD_I64LE)")
        if int(ver_arr) != version and int(ver_arr) not in older:
            old = f"; files of version {int(ver_arr)} lack this version's checksums, rebuild it: {rebuild(p, f)}" \
                if 0 < int(ver_arr) < version and rebuild else ""
            reads = ", ".join(str(v) for v in sorted({version, *older}))
            raise IsplatError(f"{p}: attribute 'format_version' is {int(ver_arr)}, this isplat reads version"
                              f"{'s' if older else ''} {reads}{old}")
        with hdf5_errors(p, "root attributes"):
            check_string_attrs(p, f.attrs, ("format",))
        if superblock < 2:
            raise IsplatError(f"{p}: HDF5 superblock version {superblock} has no checksums; format version "
                              f"{int(ver_arr)} requires the HDF5 1.10 file format (superblock 2 or later)")
    except BaseException:
        f.close()
        raise
    return p, f


# ------------------------------------------------------------------------------- counting what HDF5 reads

PAGE = 4096        # the operating system's page: what a read from the file brings into memory at the least


class ReadAttrs:
    """An HDF5 object's attributes as the checks here read them (``name in``, ``[name]``, ``get``, ``get_id``,
    ``items``), each read from the file once: an opener checks a dozen attributes several ways each, and every
    h5py attribute access costs tens of microseconds. Read-only; values as h5py returns them."""

    def __init__(self, attrs):
        self._attrs, self._names = attrs, list(attrs.keys())
        self._values, self._ids = {}, {}

    def __contains__(self, name) -> bool:
        return name in self._names

    def __iter__(self):
        return iter(self._names)

    def __getitem__(self, name):
        if name not in self._values:
            self._values[name] = self._attrs[name]
        return self._values[name]

    def get(self, name, default=None):
        return self[name] if name in self._names else default

    def get_id(self, name):
        if name not in self._ids:
            self._ids[name] = self._attrs.get_id(name)
        return self._ids[name]

    def keys(self) -> list:
        return list(self._names)

    def items(self) -> list:
        return [(k, self[k]) for k in self._names]


class ReadCounter:
    """What the HDF5 library read from one file: bytes (chunks with their 4-byte checksums, and the metadata
    that finds them) and read calls, counted below h5py, at the file object, so nothing is estimated; and the
    distinct PAGE-byte pages of the file those reads lie in (:meth:`page_bytes`: bytes counted once however
    often they are read, and the rest of every page a small read touches), kept as one flag per page of the
    file (a 1 GiB file: 256 KiB of flags, however many reads)."""

    def __init__(self):
        self.bytes = 0
        self.reads = 0
        self.pages_known = True        # False once a read's file offsets were not seen (format 5's bricks)
        self._pages = np.zeros(0, dtype=bool)

    def __repr__(self):
        return f"ReadCounter(bytes={self.bytes}, reads={self.reads})"

    def _reach(self, n: int) -> None:
        if n > self._pages.size:
            grown = np.zeros(max(n, 2 * self._pages.size), dtype=bool)
            grown[:self._pages.size] = self._pages
            self._pages = grown

    def touch(self, offset: int, n: int) -> None:
        """Note a read of ``n`` bytes from file offset ``offset``."""
        if n > 0:
            last = (offset + n - 1) // PAGE + 1
            self._reach(last)
            self._pages[offset // PAGE:last] = True

    def touch_rows(self, offset: int, size: int, rows: np.ndarray) -> None:
        """Note reads of rows ``rows`` of ``size`` bytes each of a table that starts at file offset ``offset``."""
        rows = np.asarray(rows, dtype=np.int64).reshape(-1)
        if rows.size == 0 or size <= 0:
            return
        first = (offset + rows * size) // PAGE
        last = (offset + (rows + 1) * size - 1) // PAGE
        self._reach(int(last.max()) + 1)
        for s in range(int((last - first).max()) + 1):
            self._pages[np.minimum(first + s, last)] = True

    def mark(self) -> np.ndarray:
        """A mark for :meth:`page_bytes`: the pages read so far."""
        return self._pages.copy()

    def page_bytes(self, since: np.ndarray | None = None) -> int:
        """Bytes of the distinct pages read (after mark ``since``: pages not read before it; -1: not known)."""
        if not self.pages_known:
            return -1
        if since is None:
            return int(np.count_nonzero(self._pages)) * PAGE
        n = min(since.size, self._pages.size)
        return int(np.count_nonzero(self._pages[n:]) + np.count_nonzero(self._pages[:n] & ~since[:n])) * PAGE


class _CountingRaw(io.RawIOBase):
    """A read-only file object for h5py's ``fileobj`` driver that adds every read to a :class:`ReadCounter`."""

    def __init__(self, path, counter: ReadCounter):
        super().__init__()
        self._f = open(path, "rb", buffering=0)
        self._counter = counter

    def readable(self):
        return True

    def seekable(self):
        return True

    def seek(self, offset, whence=io.SEEK_SET):
        return self._f.seek(offset, whence)

    def tell(self):
        return self._f.tell()

    def readinto(self, buf):
        at = self._f.tell()
        n = self._f.readinto(buf)
        self._counter.bytes += n or 0
        self._counter.reads += 1
        self._counter.touch(at, n or 0)
        return n

    def close(self):
        if not self.closed:
            self._f.close()
        super().close()


@contextlib.contextmanager
def open_counted(path, counter: ReadCounter):
    """``h5py.File(path, "r")`` whose reads are added to ``counter`` (HDF5's own I/O, through a file object)."""
    import h5py

    raw = _CountingRaw(path, counter)
    try:
        with h5py.File(raw, "r") as f:
            yield f
    finally:
        raw.close()


# ------------------------------------------------------------------------------- HDF5 with checksums
#
# Version 2 of both containers (formats/augmented.md, formats/index.md) relies on HDF5's own checksums:
# files are written in the HDF5 1.10 file format (superblock v3, object headers v2: every piece of metadata,
# attributes included, carries a Jenkins lookup3 checksum) with attributes kept in the object header and
# fixed-length strings (so nothing lives in the unchecksummed global heap), and every dataset is chunked with
# the Fletcher-32 filter. HDF5 verifies both on every read; :func:`hdf5_errors` turns its failures into one line.

MAX_CHUNK_BYTES = 1 << 18          # writers' chunk size target; readers refuse chunks above READ_CHUNK_LIMIT
READ_CHUNK_LIMIT = 1 << 24
MAX_COMPACT_ATTRIBUTES = 64


def create_hdf5(path, chunk_cache: int = 0):
    """Create (truncate) an HDF5 file with metadata checksums and attributes kept in object headers;
    ``chunk_cache``: bytes of HDF5's chunk cache per dataset (0: HDF5's default, 1 MiB), for writers that fill
    many places of a dataset in turn."""
    import h5py

    fapl = h5py.h5p.create(h5py.h5p.FILE_ACCESS)
    fapl.set_libver_bounds(h5py.h5f.LIBVER_V110, h5py.h5f.LIBVER_LATEST)
    if chunk_cache:
        fapl.set_cache(0, 1_000_003, int(chunk_cache), 1.0)
    fcpl = h5py.h5p.create(h5py.h5p.FILE_CREATE)
    fcpl.set_attr_phase_change(MAX_COMPACT_ATTRIBUTES, 0)
    fcpl.set_obj_track_times(False)                  # no timestamps: the same content gives the same bytes
    return h5py.File(h5py.h5f.create(os.fsencode(str(path)), h5py.h5f.ACC_TRUNC, fcpl=fcpl, fapl=fapl))


def create_group(parent, name: str):
    """A subgroup without timestamps, attributes compact in its (checksummed) object header."""
    import h5py

    gcpl = h5py.h5p.create(h5py.h5p.GROUP_CREATE)
    gcpl.set_obj_track_times(False)
    gcpl.set_attr_phase_change(MAX_COMPACT_ATTRIBUTES, 0)
    return h5py.Group(h5py.h5g.create(parent.id, name.encode(), gcpl=gcpl))


def set_string_attr(obj, name: str, value: str) -> None:
    """A fixed-length UTF-8 string attribute (stored in the checksummed object header)."""
    import h5py

    data = str(value).encode("utf-8") or b"\0"
    obj.attrs.create(name, data=data, dtype=h5py.string_dtype("utf-8", len(data)))


def chunk_shape(shape, itemsize: int, target: int = MAX_CHUNK_BYTES) -> tuple:
    """Chunks of about ``target`` bytes, filled from the fastest axis outwards (whole rows, then whole planes).
    A volume's chunks hold at most 8 k-planes, a power of two when they do not hold all: the renderer reads
    8-plane slabs, which then align with chunks, and a partial last chunk (stored whole) wastes < 8 planes."""
    chunk, size = [1] * len(shape), int(itemsize)
    for ax in reversed(range(len(shape))):
        n, fit = max(1, int(shape[ax])), max(1, target // size)
        if ax == 0 and len(shape) == 3:
            fit = min(fit, 8)
        if n <= fit:
            chunk[ax], size = n, size * n
            continue
        chunk[ax] = 1 << (fit.bit_length() - 1) if ax == 0 else fit
        break
    return tuple(chunk)


def create_checked_dataset(group, name: str, shape, dtype, data=None, target: int = MAX_CHUNK_BYTES, chunks=None):
    """A chunked dataset with the Fletcher-32 filter, chunks of about ``target`` bytes or ``chunks`` (empty
    datasets are resizable, so a chunk fits)."""
    shape = tuple(int(n) for n in shape)
    dt = np.dtype(dtype)
    kw = {"maxshape": tuple(None if n == 0 else n for n in shape)} if 0 in shape else {}
    return group.create_dataset(name, shape=shape, dtype=dt, data=data,
                                chunks=tuple(chunks) if chunks else chunk_shape(shape, dt.itemsize, target),
                                fletcher32=True, track_times=False, **kw)


def read_chunk_span(path, counter: ReadCounter, ds, lo: int, hi: int):
    """Rows ``lo:hi`` (from a chunk's first row) of a 1-D dataset made by :func:`create_hashed_dataset` in one
    read of the file, when HDF5 stored their chunks back to back, whole and unfiltered; else None (HDF5 then
    reads them, a chunk at a time). Counted in ``counter`` as HDF5's reads through :class:`_CountingRaw` are; the
    caller checks each chunk's hash."""
    c, item = int(ds.chunks[0]), ds.dtype.itemsize
    first = ds.id.get_chunk_info_by_coord((lo,))
    last = ds.id.get_chunk_info_by_coord(((hi - 1) // c * c,))
    span = ((hi - 1) // c - lo // c) * c * item
    if first.byte_offset is None or last.byte_offset is None or first.filter_mask or last.filter_mask or \
            first.size != c * item or last.size != c * item or last.byte_offset != first.byte_offset + span:
        return None
    out = np.empty(hi - lo, dtype=ds.dtype)
    with contextlib.closing(_CountingRaw(path, counter)) as fh:
        fh.seek(first.byte_offset)
        n = fh.readinto(memoryview(out).cast("B"))
    return out if n == out.nbytes else None


def create_hashed_dataset(group, name: str, shape, dtype, data=None, chunks=None):
    """A chunked dataset without filters whose chunks are allocated when it is created (formats/index.md §1,
    version 7): HDF5 then keeps no chunk index (a chunk's place in the file follows from its number), so a read
    reads its chunks and nothing that locates them. Its chunks are checked by isplat's chunk hashes alone. An
    empty dataset has one-element chunks and an unlimited maximum size, as HDF5 requires."""
    import h5py

    shape = tuple(int(n) for n in shape)
    dt = np.dtype(dtype)
    if 0 in shape:
        return group.create_dataset(name, shape=shape, dtype=dt, chunks=(1,) * len(shape),
                                    maxshape=(None,) * len(shape), track_times=False)
    dcpl = h5py.h5p.create(h5py.h5p.DATASET_CREATE)
    dcpl.set_alloc_time(h5py.h5d.ALLOC_TIME_EARLY)
    dcpl.set_fill_time(h5py.h5d.FILL_TIME_NEVER)
    ds = group.create_dataset(name, shape=shape, dtype=dt, chunks=tuple(int(c) for c in chunks), dcpl=dcpl,
                              track_times=False)
    if data is not None:
        ds[...] = data
    return ds


def check_hashed_dataset(where: str, ds) -> None:
    """Refuse a dataset that is not chunked, has a filter, or has oversized chunks (:func:`create_hashed_dataset`)."""
    plist = ds.id.get_create_plist()
    if ds.chunks is None or plist.get_nfilters():
        layout = "contiguous" if ds.chunks is None else \
            f"chunked with filters {[plist.get_filter(n)[0] for n in range(plist.get_nfilters())]}"
        raise IsplatError(f"{where}: dataset is {layout}; this format version requires chunks without filters "
                          f"(each chunk is checked by its chunk hash)")
    if int(np.prod(ds.chunks)) * ds.dtype.itemsize > READ_CHUNK_LIMIT:
        raise IsplatError(f"{where}: chunks of {ds.chunks} exceed {READ_CHUNK_LIMIT} bytes")


def check_checked_dataset(where: str, ds) -> None:
    """Refuse a dataset that is not chunked with Fletcher-32 as its only filter, or has oversized chunks."""
    plist = ds.id.get_create_plist()
    filters = [plist.get_filter(n)[0] for n in range(plist.get_nfilters())]
    if ds.chunks is None or filters != [3]:          # H5Z_FILTER_FLETCHER32
        layout = "contiguous" if ds.chunks is None else f"chunked with filters {filters}"
        raise IsplatError(f"{where}: dataset is {layout}; isplat's formats (since version 2) require chunks with "
                          f"the Fletcher-32 filter only (checksums)")
    if int(np.prod(ds.chunks)) * ds.dtype.itemsize > READ_CHUNK_LIMIT:
        raise IsplatError(f"{where}: chunks of {ds.chunks} exceed {READ_CHUNK_LIMIT} bytes")


def _h5_reason(exc: BaseException) -> str:
    text = str(exc)
    if "fletcher32" in text.lower() or "filter returned failure" in text:   # Fletcher-32 is the only filter allowed
        return "checksum mismatch in its data (Fletcher-32): the file is corrupted"
    if "checksum" in text.lower():
        return "checksum mismatch in HDF5 metadata: the file is corrupted"
    first = text.strip().splitlines()[0] if text.strip() else exc.__class__.__name__
    return f"unreadable ({exc.__class__.__name__}: {first[:120]}): truncated or corrupt file"


@contextlib.contextmanager
def hdf5_errors(path, what: str = ""):
    """Turn any exception h5py raises inside the block into one :class:`IsplatError` line naming ``what``."""
    try:
        yield
    except IsplatError:
        raise
    except (OSError, KeyError, ValueError, TypeError, RuntimeError, IndexError, AttributeError) as exc:
        where = f"{path}: {what}" if what else f"{path}"
        raise IsplatError(f"{where}: {_h5_reason(exc)}") from None


def _string_type_problem(attrs, name: str, ascii_ok: bool = False) -> str | None:
    """Why attribute ``name`` is not a fixed-length UTF-8 scalar string, or None if it is one."""
    import h5py

    tid = attrs.get_id(name).get_type()
    if not isinstance(tid, h5py.h5t.TypeStringID):
        v = np.asarray(attrs[name])
        return f"has type {v.dtype} and shape {v.shape}, expected a fixed-length UTF-8 string"
    if tid.is_variable_str():
        return ("is a variable-length string; format version 2 stores fixed-length UTF-8 strings (in the "
                "checksummed object header)")
    if tid.get_cset() != h5py.h5t.CSET_UTF8 and not ascii_ok:
        return "is an ASCII string; format version 2 stores fixed-length UTF-8 strings (H5T_CSET_UTF8)"
    if np.asarray(attrs[name]).shape != ():
        return f"has shape {np.asarray(attrs[name]).shape}, expected a scalar string"
    return None


def attr_string(attrs, name: str, ascii_ok: bool = False):
    """A fixed-length string attribute as ``str``; None when absent, of another type or not UTF-8 (stored as
    UTF-8: ``ascii_ok`` takes an ASCII one too, as files before format version 2 have)."""
    if name not in attrs or _string_type_problem(attrs, name, ascii_ok):
        return None
    try:
        return bytes(np.asarray(attrs[name])[()]).decode("utf-8")
    except UnicodeDecodeError:
        return None


def attr_values(attrs) -> dict:
    """Every attribute: a UTF-8 string one as ``str`` (:func:`attr_string`, asked once per attribute), any other
    as h5py reads it."""
    out = {}
    for k, v in attrs.items():
        text = attr_string(attrs, k)
        out[k] = v if text is None else text
    return out


def attr_array(path, attrs, name: str, kind: str, shape: tuple | None = None):
    """A numeric attribute, checked: ``kind`` 'i' (int64) or 'f' (float64), exact ``shape`` (None = scalar)."""
    if name not in attrs:
        raise IsplatError(f"{path}: missing attribute {name!r}")
    want = np.dtype("<i8" if kind == "i" else "<f8")
    v = np.asarray(attrs[name])
    if v.dtype != want:
        raise IsplatError(f"{path}: attribute {name!r} has type {v.dtype}, expected {want.name}"
                          f" ({'H5T_STD_I64LE' if kind == 'i' else 'H5T_IEEE_F64LE'})")
    stored = h5_type_name(attrs, name)
    if stored != ("H5T_STD_I64LE" if kind == "i" else "H5T_IEEE_F64LE"):
        raise IsplatError(f"{path}: attribute {name!r} is stored as {stored}, expected {want.name}"
                          f" ({'H5T_STD_I64LE' if kind == 'i' else 'H5T_IEEE_F64LE'})")
    if shape is None and v.shape != ():
        raise IsplatError(f"{path}: attribute {name!r} has shape {v.shape}, expected a scalar")
    if shape is not None and len(v.shape) != len(shape) or shape is not None and any(
            s != -1 and s != n for s, n in zip(shape, v.shape)):
        raise IsplatError(f"{path}: attribute {name!r} has shape {v.shape}, expected {shape}")
    if kind == "f" and not np.all(np.isfinite(v)):
        raise IsplatError(f"{path}: attribute {name!r} is {v.tolist()}, expected finite numbers")
    return v.astype(want.newbyteorder("="))


def h5_type_name(attrs, name: str) -> str:
    """The HDF5 type an attribute is stored as, named as formats/ names it: ``H5T_STD_I64LE``,
    ``H5T_IEEE_F32BE``, ... (h5py reads a big-endian scalar as a native number, so its numpy type hides it)."""
    import h5py

    tid = attrs.get_id(name).get_type()
    if not isinstance(tid, (h5py.h5t.TypeIntegerID, h5py.h5t.TypeFloatID)):     # (no byte order: strings, ...)
        return f"an HDF5 type of class {tid.get_class()}"
    order = "BE" if tid.get_order() == h5py.h5t.ORDER_BE else "LE"
    if isinstance(tid, h5py.h5t.TypeIntegerID):
        sign = "I" if tid.get_sign() == h5py.h5t.SGN_2 else "U"
        return f"H5T_STD_{sign}{8 * tid.get_size()}{order}"
    return f"H5T_IEEE_F{8 * tid.get_size()}{order}"


def check_string_attrs(path, attrs, required=(), optional=(), ascii_ok: bool = False) -> None:
    """Refuse a missing required string attribute, or a required or optional one that is not a UTF-8 string."""
    for name in (*required, *optional):
        if name not in attrs:
            if name in required:
                raise IsplatError(f"{path}: missing attribute {name!r}")
            continue
        problem = _string_type_problem(attrs, name, ascii_ok)
        if problem:
            raise IsplatError(f"{path}: attribute {name!r} {problem}")
        if attr_string(attrs, name, ascii_ok) is None:
            raise IsplatError(f"{path}: attribute {name!r} is not valid UTF-8")
