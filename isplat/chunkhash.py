"""Content hashes bound to their place: one BLAKE2b hash per HDF5 chunk, kept in a table of the file.

Both containers (formats/augmented.md §1.1, formats/index.md §1.1) keep, for every chunked dataset ``D`` they
specify, a table ``/chunk_hashes/<D with '/' as '.'>`` of ``uint8[n_chunks, 16]``: row ``r`` is the hash of the
chunk whose grid index is ``r`` in C order. A chunk's hash is BLAKE2b (16-byte digest) keyed with the file key,
over the dataset's path, the chunk's offset and the chunk's elements:

    key  = BLAKE2b-256(person="isplat-chunks",
                       "isplat chunk hashes 1" NUL density_sha256 NUL
                       for each hashed dataset, in the spec's order: its path NUL
                       NUL
                       for each attribute the spec lists, in its order: "group@name" NUL, then 0x00 when absent,
                       else 0x01, the value's byte length as int64 LE and its bytes)
    hash = BLAKE2b-128(key=key, path NUL, offset as ndim int64 LE, the chunk's elements in C order, little-endian)

The range-runs file (formats/runs.md §2) hashes its chunks with XXH3-128 instead (``algorithm="xxh3"``), seeded
with the key's first 8 bytes (little-endian), over the same bytes: about 5 times BLAKE2b's speed, which made the
hashes a third of a post load from that file; the key and ``chunk_hash_check`` stay BLAKE2b.

Fletcher-32 cannot see a chunk copied over another (it carries its own valid checksum), a 16-bit word swapped
0x0000 <-> 0xFFFF, nor anything written through HDF5 (which recomputes it); the keyed hash sees all of them: a
chunk is bound to its dataset, its position and the file's identity (``density_sha256`` and the attributes that
steer reading, which the root attribute ``chunk_hash_check`` confirms at open). An edit that recomputes the table
is not caught: the key is derived from the file itself, not a secret (formats/augmented.md §1.1).
"""

from __future__ import annotations

import hashlib
import itertools
import struct
import sys

import numpy as np

from .errors import IsplatError

DIGEST = 16
GROUP = "chunk_hashes"
CHECK_ATTR = "chunk_hash_check"
_CHECK_MESSAGE = b"isplat chunk hashes 1"
TABLE_CHUNK_ROWS = 256               # 4 KiB chunks of the tables


def table_name(dataset: str) -> str:
    """The table of dataset ``axes/k/bytes`` is ``/chunk_hashes/axes.k.bytes``."""
    return dataset.strip("/").replace("/", ".")


def _attr_bytes(v) -> bytes:
    if isinstance(v, str):
        return v.encode("utf-8")
    a = np.asarray(v)
    if a.dtype.kind in "SUO":
        v = a[()] if a.shape == () else a.tolist()
        return bytes(v) if isinstance(v, bytes) else str(v).encode("utf-8")
    return np.ascontiguousarray(a, dtype=a.dtype.newbyteorder("<")).tobytes()


def file_key(density_sha256: str, datasets, attributes) -> bytes:
    """The file key: ``attributes`` is a list of ``(where, name, value or None)`` (strings as ``str``)."""
    h = hashlib.blake2b(digest_size=32, person=b"isplat-chunks")
    h.update(_CHECK_MESSAGE + b"\0" + density_sha256.encode("ascii") + b"\0")
    for d in datasets:
        h.update(d.encode("utf-8") + b"\0")
    h.update(b"\0")
    for where, name, value in attributes:
        h.update(f"{where}@{name}".encode("utf-8") + b"\0")
        if value is None:
            h.update(b"\0")
        else:
            raw = _attr_bytes(value)
            h.update(b"\1" + np.int64(len(raw)).astype("<i8").tobytes() + raw)
    return h.digest()


def check_value(key: bytes) -> str:
    """The root attribute ``chunk_hash_check``: 32 hex digits."""
    return hashlib.blake2b(_CHECK_MESSAGE, digest_size=DIGEST, key=key).hexdigest()


def hasher(key: bytes, algorithm: str = "blake2b"):
    """A fresh chunk-hash state for file key ``key``: BLAKE2b-128 keyed with it, or (``"xxh3"``) XXH3-128 seeded
    with its first 8 bytes as a little-endian uint64 (its ``digest()`` the canonical big-endian bytes)."""
    if algorithm == "xxh3":
        import xxhash

        return xxhash.xxh3_128(seed=int.from_bytes(key[:8], "little"))
    if algorithm != "blake2b":
        raise ValueError(f"chunk hash algorithm {algorithm!r}: expected 'blake2b' or 'xxh3'")
    return hashlib.blake2b(digest_size=DIGEST, key=key)


def chunk_hash(key: bytes, dataset: str, offset, data: np.ndarray, algorithm: str = "blake2b") -> bytes:
    h = hasher(key, algorithm)
    h.update(dataset.encode("utf-8") + b"\0" + np.asarray(offset, dtype="<i8").tobytes())
    a = np.ascontiguousarray(data, dtype=data.dtype.newbyteorder("<") if data.dtype.itemsize > 1 else data.dtype)
    h.update(memoryview(a).cast("B"))
    return h.digest()


def grid_shape(shape, chunks) -> tuple:
    return tuple(-(-int(n) // int(c)) for n, c in zip(shape, chunks))


def _layer_rows(shape, chunks) -> int:
    """Chunk layers (along axis 0) read at once: about 16 MiB."""
    per = int(np.prod([int(c) for c in chunks[:1]] + [int(n) for n in shape[1:]]))
    return max(1, (1 << 24) // max(1, per))


def uniform_pieces(arr: np.ndarray, chunks):
    """The chunks held by ``arr`` (a chunk-aligned block: it starts at a chunk's first element and ends at a chunk's
    end or the dataset's edge), as ``(grid, pieces)`` per run of equally shaped chunks: ``grid`` int64[n, ndim] their
    grid indices relative to the block's first chunk, ``pieces`` [n, elements] each chunk's elements in C order
    (contiguous: one reshape per run, not one copy per chunk; at most 2^ndim runs, the partial edge chunks)."""
    parts = []
    for e, c in zip(arr.shape, chunks):
        full = (int(e) // int(c)) * int(c)
        parts.append([(0, full, int(c))] if full == e else
                     ([(0, full, int(c))] if full else []) + [(full, int(e), int(e) - full)])
    for combo in itertools.product(*parts):
        sub = arr[tuple(slice(a, b) for a, b, _ in combo)]
        counts = [(b - a) // c for a, b, c in combo]
        split = [x for n, (_, _, c) in zip(counts, combo) for x in (n, c)]
        nd = len(combo)
        blocks = sub.reshape(split).transpose(list(range(0, 2 * nd, 2)) + list(range(1, 2 * nd, 2)))
        pieces = np.ascontiguousarray(blocks).reshape(int(np.prod(counts)), -1)
        grid = np.stack([g.reshape(-1) + a // c0 for g, (a, _, c), c0 in
                         zip(np.meshgrid(*[np.arange(n) for n in counts], indexing="ij"), combo, chunks)], axis=1)
        yield grid.astype(np.int64), pieces


def _le(a: np.ndarray) -> np.ndarray:
    if a.dtype.byteorder == ">" or (a.dtype.byteorder == "=" and sys.byteorder == "big"):
        return a.astype(a.dtype.newbyteorder("<"))
    return a


def hash_pieces(base, prefix: bytes, offsets: np.ndarray, pieces: np.ndarray) -> list[bytes]:
    """Chunk hashes of ``pieces`` (rows: chunks' elements) at element ``offsets`` (int64[n, ndim]); ``base``: a
    BLAKE2b state keyed with the file key."""
    out = []
    buf = memoryview(np.ascontiguousarray(_le(pieces))).cast("B")
    row = pieces.shape[1] * pieces.dtype.itemsize if pieces.ndim == 2 else 0
    offs = np.ascontiguousarray(offsets, dtype="<i8")
    for n in range(offs.shape[0]):
        h = base.copy()
        h.update(prefix + offs[n].tobytes())
        h.update(buf[n * row:(n + 1) * row])
        out.append(h.digest())
    return out


def _hash_layer(key, dataset, arr, base, chunks, grid, algorithm: str = "blake2b") -> np.ndarray:
    """uint8[chunks, 16]: the hashes of the chunks ``arr`` holds (a chunk-aligned block from element ``base``),
    in C order of the dataset's chunk grid ``grid``, as rows ``(row numbers, hashes)``."""
    h0 = hasher(key, algorithm)
    prefix = dataset.encode("utf-8") + b"\0"
    g0 = np.asarray([b // c for b, c in zip(base, chunks)], dtype=np.int64)
    rows, hashes = [], []
    for g, pieces in uniform_pieces(arr, chunks):
        g = g + g0
        rows.append(np.ravel_multi_index(tuple(g.T), grid))
        hashes.extend(hash_pieces(h0, prefix, g * np.asarray(chunks, dtype=np.int64), pieces))
    return np.concatenate(rows), np.frombuffer(b"".join(hashes), dtype=np.uint8).reshape(-1, DIGEST)


def write_tables(f, density_sha256: str, datasets, attributes, tables=None, create=None,
                 algorithm: str = "blake2b") -> None:
    """Write ``/chunk_hashes`` and the root ``chunk_hash_check`` of open file ``f``, whose ``datasets`` (paths)
    are complete and whose attributes are set. Reads every dataset back, a layer of chunks at a time. ``tables``:
    the datasets that get a table (default all; the key covers all ``datasets``). ``create``:
    ``(group, name, table)`` -> the table's dataset (default: chunked with Fletcher-32, 256 rows a chunk).
    ``algorithm``: the chunk hash (:func:`hasher`)."""
    from .fileio import create_checked_dataset, create_group, set_string_attr

    if create is None:
        def create(g, name, table):
            return create_checked_dataset(g, name, table.shape, "|u1", table, target=TABLE_CHUNK_ROWS * DIGEST)

    key = file_key(density_sha256, datasets, attributes)
    g = create_group(f, GROUP)
    for d in datasets if tables is None else tables:
        ds = f[d]
        table = np.zeros((int(np.prod(grid_shape(ds.shape, ds.chunks))), DIGEST), dtype=np.uint8)
        if table.shape[0]:
            grid = grid_shape(ds.shape, ds.chunks)
            step = _layer_rows(ds.shape, ds.chunks)
            for c0 in range(0, grid[0], step):
                c1 = min(grid[0], c0 + step)
                arr = ds[c0 * ds.chunks[0]:c1 * ds.chunks[0]]
                rows, hs = _hash_layer(key, d, arr, (c0 * ds.chunks[0],) + (0,) * (ds.ndim - 1), ds.chunks, grid,
                                       algorithm)
                table[rows] = hs
        create(g, table_name(d), table)
    set_string_attr(f, CHECK_ATTR, check_value(key))


class Verifier:
    """Checks what a reader reads against ``/chunk_hashes``: made at open (:func:`open_verifier`). Table rows are
    read a table chunk (256 rows) at a time and kept, so neighbouring reads do not read them again."""

    def __init__(self, path, key: bytes, rebuild: str, algorithm: str = "blake2b"):
        self.path = path
        self.key = key
        self.rebuild = rebuild
        self.algorithm = algorithm
        self.chunks_verified = 0
        self._base = hasher(key, algorithm)
        self._rows = {}                      # (dataset, table chunk index) -> bytes of its rows
        self._tables_checked = set()         # datasets whose table's presence and shape were checked
        self._places = {}                    # dataset -> int64[chunks]: each stored chunk's file offset (bulk reads)
        self._table_chunk_rows = {}          # dataset -> rows per chunk of its table (read in those units)
        self._handles = {}                   # object path -> (file, h5py object): looked up once per open file

    def __getstate__(self):                  # picklable (a hashlib state is not): rebuilt from the key
        return {k: (v if k not in ("_places", "_handles") else {}) for k, v in self.__dict__.items()
                if k != "_base"}

    def __setstate__(self, state):
        self.__dict__.update(state)
        self.__dict__.setdefault("_handles", {})
        self._base = hasher(self.key, self.__dict__.get("algorithm", "blake2b"))

    def fail(self, dataset: str, offset, why: str = "its content does not match its hash"):
        off = ", ".join(str(int(o)) for o in offset)
        raise IsplatError(f"{self.path}: dataset '{dataset}', chunk at ({off}): {why} in /{GROUP}/"
                          f"{table_name(dataset)} (changed, moved or copied from elsewhere); rebuild it: "
                          f"{self.rebuild}")

    def _obj(self, f, name: str):
        """``f[name]``, looked up once per open file ``f`` (an h5py lookup costs about 50 us; an opener's checks
        and first reads ask for the same datasets and tables several times)."""
        got = self._handles.get(name)
        if got is None or got[0] is not f:
            got = self._handles[name] = (f, f[name])
        return got[1]

    def remember(self, f, objects: dict) -> None:
        """Take ``{path: h5py object}`` of open file ``f`` as already looked up (an opener's checks did)."""
        self._handles.update((name, (f, obj)) for name, obj in objects.items())

    def _rows_per_chunk(self, f, dataset: str) -> int:
        """Rows per stored chunk of the dataset's table (256 as isplat writes them before index format 7)."""
        n = self._table_chunk_rows.get(dataset)
        if n is None:
            chunks = self._obj(f, f"{GROUP}/{table_name(dataset)}").chunks
            n = self._table_chunk_rows[dataset] = int(chunks[0]) if chunks else TABLE_CHUNK_ROWS
        return n

    def _table_chunk(self, f, dataset: str, c: int) -> bytes:
        """Table chunk ``c`` (rows ``c * rows per chunk`` on) of the dataset's table, as bytes, read once and kept."""
        rows = self._rows.get((dataset, c))
        if rows is None:
            n = self._rows_per_chunk(f, dataset)
            t = self._obj(f, f"{GROUP}/{table_name(dataset)}")
            rows = np.ascontiguousarray(t[c * n:(c + 1) * n], dtype=np.uint8).tobytes()
            self._rows[(dataset, c)] = rows
        return rows

    def _table_rows(self, f, dataset: str, r0: int, r1: int) -> bytes:
        """Rows ``r0:r1`` of the dataset's table, as bytes (16 per row): the table chunks not yet kept read in
        one request (from the first to the last missing one), then kept."""
        n = self._rows_per_chunk(f, dataset)
        missing = [c for c in range(r0 // n, (r1 - 1) // n + 1) if (dataset, c) not in self._rows]
        if len(missing) > 1:
            a, b = missing[0], missing[-1] + 1
            got = np.ascontiguousarray(self._obj(f, f"{GROUP}/{table_name(dataset)}")[a * n:b * n], dtype=np.uint8)
            for c in range(a, b):
                self._rows.setdefault((dataset, c), got[(c - a) * n:(c - a + 1) * n].tobytes())
        out = [self._table_chunk(f, dataset, c) for c in range(r0 // n, (r1 - 1) // n + 1)]
        base = (r0 // n) * n
        got = b"".join(out)[(r0 - base) * DIGEST:(r1 - base) * DIGEST]
        return got

    def _hash(self, prefix: bytes, offset, data: np.ndarray) -> bytes:
        h = self._base.copy()
        h.update(prefix + struct.pack(f"<{len(offset)}q", *offset))
        if data.dtype.byteorder == ">" or (data.dtype.byteorder == "=" and sys.byteorder == "big"):
            data = data.astype(data.dtype.newbyteorder("<"))
        h.update(memoryview(np.ascontiguousarray(data)).cast("B"))
        return h.digest()

    def read(self, f, dataset: str, sel=None, check=None, fetch=None) -> np.ndarray:
        """``f[dataset][sel]`` (``sel``: a tuple of slices with steps of 1, missing axes whole), after checking
        every chunk it touches: whole chunks are read (HDF5 reads them whole anyway) and hashed; the selection
        is returned (a copy for 3-D datasets, a view of the chunk-aligned read for 1-D ones). ``fetch(ds, lo,
        hi)``: 1-D only, the chunk-aligned rows ``lo:hi`` read otherwise than through HDF5 (or None: HDF5 reads)."""
        ds = self._obj(f, dataset)
        if dataset not in self._tables_checked:
            _check_table(self.path, f, dataset, ds, self.rebuild, self._obj)
            self._tables_checked.add(dataset)
        shape, chunks = tuple(int(n) for n in ds.shape), tuple(int(c) for c in ds.chunks)
        sel = tuple(sel or ()) + (slice(None),) * (len(shape) - len(sel or ()))
        bounds = [s.indices(n)[:2] for s, n in zip(sel, shape)]
        bounds = [(a, max(a, b)) for a, b in bounds]
        out_shape = tuple(b - a for a, b in bounds)
        if 0 in out_shape:
            return np.zeros(out_shape, dtype=ds.dtype.newbyteorder("="))
        prefix = dataset.encode("utf-8") + b"\0"
        g_lo = [a // c for (a, _), c in zip(bounds, chunks)]
        g_hi = [(b - 1) // c for (_, b), c in zip(bounds, chunks)]
        grid = grid_shape(shape, chunks)
        if len(shape) == 1:                       # the index's tables: one read, chunks back to back
            c = chunks[0]
            lo, hi = g_lo[0] * c, min(shape[0], (g_hi[0] + 1) * c)
            arr = fetch(ds, lo, hi) if fetch is not None else None
            arr = ds[lo:hi] if arr is None else arr
            want = self._table_rows(f, dataset, g_lo[0], g_hi[0] + 1)
            m = (hi - lo) // c                    # whole chunks hashed in bulk, then a partial last one
            offs = (np.arange(g_lo[0], g_lo[0] + m, dtype=np.int64) * c).reshape(-1, 1)
            got = b"".join(hash_pieces(self._base, prefix, offs, arr[:m * c].reshape(m, c))) if m else b""
            if m < g_hi[0] - g_lo[0] + 1:
                got += self._hash(prefix, ((g_lo[0] + m) * c,), arr[m * c:])
            if got != want:
                n = next(n for n in range(len(want) // DIGEST)
                         if got[n * DIGEST:(n + 1) * DIGEST] != want[n * DIGEST:(n + 1) * DIGEST])
                self.fail(dataset, ((g_lo[0] + n) * c,))
            self.chunks_verified += g_hi[0] - g_lo[0] + 1
            return arr[bounds[0][0] - lo:bounds[0][1] - lo]
        out = np.empty(out_shape, dtype=ds.dtype)
        step = _layer_rows(shape, chunks)
        inner = int(np.prod(grid[1:]))
        for c0 in range(g_lo[0], g_hi[0] + 1, step):
            c1 = min(g_hi[0], c0 + step - 1)
            lo = [c0 * chunks[0]] + [g * c for g, c in zip(g_lo[1:], chunks[1:])]
            hi = [min(shape[0], (c1 + 1) * chunks[0])] + [min(n, (g + 1) * c)
                                                          for g, c, n in zip(g_hi[1:], chunks[1:], shape[1:])]
            arr = ds[tuple(slice(a, b) for a, b in zip(lo, hi))]
            want = self._table_rows(f, dataset, c0 * inner, (c1 + 1) * inner)
            self._check_block(prefix, dataset, arr, lo, chunks, grid, want, c0 * inner)
            if check is not None:
                check(arr, lo)
            cut = tuple(slice(max(a, l) - l, min(b, h) - l) for (a, b), l, h in zip(bounds, lo, hi))
            k_a = max(bounds[0][0], lo[0]) - bounds[0][0]
            piece = arr[cut]
            out[k_a:k_a + piece.shape[0]] = piece
        return out

    def _check_block(self, prefix, dataset, arr, lo, chunks, grid, want: bytes, row0: int) -> None:
        """Hash every chunk of the chunk-aligned block ``arr`` (from element ``lo``) against ``want``, the table's
        rows from row ``row0``."""
        ch = np.asarray(chunks, dtype=np.int64)
        g0 = np.asarray(lo, dtype=np.int64) // ch
        for g, pieces in uniform_pieces(arr, chunks):
            g = g + g0
            rows = np.ravel_multi_index(tuple(g.T), grid) - row0
            got = hash_pieces(self._base, prefix, g * ch, pieces)
            for n, r in enumerate(rows.tolist()):
                if got[n] != want[r * DIGEST:(r + 1) * DIGEST]:
                    self.fail(dataset, tuple((g[n] * ch).tolist()))
            self.chunks_verified += len(got)

    def _rows_of(self, f, dataset: str, rows: np.ndarray) -> np.ndarray:
        """uint8[len(rows), 16]: the table's rows ``rows``, read a table chunk (256 rows) at a time and kept."""
        n = self._rows_per_chunk(f, dataset)
        chunks = np.unique(rows // n)
        parts = []
        for c in chunks.tolist():
            got = self._table_chunk(f, dataset, c)
            a = np.zeros((n, DIGEST), dtype=np.uint8)
            a.reshape(-1)[:len(got)] = np.frombuffer(got, dtype=np.uint8)
            parts.append(a)
        table = np.stack(parts)
        return table[np.searchsorted(chunks, rows // n), rows % n]

    def read_bricks_direct(self, f, dataset: str, bricks: np.ndarray, out: np.ndarray, origin=(0, 0, 0),
                           minmax: bool = False, bulk: bool = False):
        """Read the chunks (bricks) of 3-D ``dataset`` whose grid indices are the rows of ``bricks`` (int64[n, 3],
        unique) into ``out`` (the block from element ``origin``: what of each brick lies within it), each checked
        against its hash; returns the elements read, and with ``minmax`` uint8[n, 2] each brick's smallest and
        largest value (in ``bricks``' order). Each chunk is read raw (``H5Dread_chunk``: about 5 us a chunk, half a
        hyperslab's cost), its stored size and filter mask checked (the elements and
        the 4-byte Fletcher-32 checksum, which is not recomputed: the keyed chunk hash, stronger, covers every
        element), hashed and placed in bulk: one numpy call per class of equally cut bricks (at most 27), not
        one per brick. ``bricks`` must lie in the chunk grid (the caller's own computation; checked). ``bulk``
        (whole reads): the chunks' file offsets taken once from HDF5's chunk index (:meth:`_chunk_places`) and
        the chunks read from the file by run of neighbouring chunks (:meth:`_bulk_chunks`)."""
        ds = self._obj(f, dataset)
        if dataset not in self._tables_checked:
            _check_table(self.path, f, dataset, ds, self.rebuild, self._obj)
            self._tables_checked.add(dataset)
        shape, chunks = tuple(int(n) for n in ds.shape), tuple(int(c) for c in ds.chunks)
        grid = grid_shape(shape, chunks)
        n = bricks.shape[0]
        mm = np.zeros((n, 2), dtype=np.uint8) if minmax else None
        if n == 0:
            return (0, mm) if minmax else 0
        if bricks.min() < 0 or np.any(bricks.max(axis=0) >= np.asarray(grid)):
            raise IsplatError(f"{self.path}: dataset '{dataset}': a brick outside its grid {grid} was asked for")
        ch = np.asarray(chunks, dtype=np.int64)
        offs = np.ascontiguousarray(bricks * ch, dtype="<i8")
        rows = np.ravel_multi_index(tuple(bricks.T), grid)
        want = self._rows_of(f, dataset, rows)
        data = (self._bulk_chunks(ds, dataset, rows, chunks, grid) if bulk else
                self._raw_chunks(ds, dataset, offs, chunks))
        ext = np.minimum(ch, np.asarray(shape, dtype=np.int64) - offs)
        got = np.empty((n, DIGEST), dtype=np.uint8)
        prefix = dataset.encode("utf-8") + b"\0"
        key = _row_keys(ext)
        for k in np.unique(key):                       # whole bricks, then those cut by the volume's far edges
            m = np.flatnonzero(key == k)
            e = ext[m[0]]
            pieces = np.ascontiguousarray(data[m, :e[0], :e[1], :e[2]]).reshape(m.size, -1)
            got[m] = np.frombuffer(b"".join(hash_pieces(self._base, prefix, offs[m], pieces)),
                                   dtype=np.uint8).reshape(-1, DIGEST)
            if minmax:
                mm[m, 0], mm[m, 1] = pieces.min(axis=1), pieces.max(axis=1)
        bad = np.flatnonzero(np.any(got != want, axis=1))
        if bad.size:
            self.fail(dataset, tuple(offs[bad[0]].tolist()))
        self.chunks_verified += n
        place_bricks(out, data, offs, ext, origin)
        total = int(np.prod(ext, axis=1).sum())
        return (total, mm) if minmax else total

    def _raw_chunks(self, ds, dataset: str, offs: np.ndarray, chunks) -> np.ndarray:
        """[n, ck, cj, ci] (the dataset's type, little-endian): the stored chunks at element offsets ``offs``, each
        checked to be stored whole with its one filter (Fletcher-32) applied: elements then a 4-byte checksum."""
        size = int(np.prod(chunks)) * ds.dtype.itemsize
        dsid, parts = ds.id, []
        for o in offs.tolist():
            mask, b = dsid.read_direct_chunk(tuple(o))
            if mask or len(b) != size + 4:
                self.fail(dataset, o, f"stored as {len(b)} bytes with filter mask {mask}, expected {size + 4} "
                                      f"(elements and Fletcher-32), so it cannot be checked")
            parts.append(b)
        raw = np.frombuffer(b"".join(parts), dtype=np.uint8).reshape(len(parts), size + 4)[:, :size]
        return np.ascontiguousarray(raw).view(ds.dtype.newbyteorder("<")).reshape((len(parts),) + tuple(chunks))

    def _chunk_places(self, ds, dataset: str, chunks, grid) -> np.ndarray:
        """int64[chunks]: the file offset of each stored chunk, by grid row, from HDF5's chunk index (walked once
        per dataset: about 1.6 us a chunk, against 5 us for a raw read through HDF5), checked: every chunk
        listed once, at a chunk's offset in the grid, stored whole with its checksum (filter mask 0) and inside
        the file. What lies there is then checked by each chunk's hash."""
        import os

        size = int(np.prod(chunks)) * ds.dtype.itemsize + 4
        coords, where, bad = [], [], []

        def visit(si):
            coords.append(si.chunk_offset)
            where.append(si.byte_offset)
            if si.filter_mask or si.size != size:
                bad.append(si)
        ds.id.chunk_iter(visit)
        if bad:
            self.fail(dataset, bad[0].chunk_offset,
                      f"stored as {bad[0].size} bytes with filter mask {bad[0].filter_mask}, expected {size} "
                      f"(elements and Fletcher-32), so it cannot be checked")
        ch, g = np.asarray(chunks, dtype=np.int64), np.asarray(grid, dtype=np.int64)
        c = np.asarray(coords, dtype=np.int64).reshape(-1, 3)
        places = np.full(int(np.prod(grid)), -1, dtype=np.int64)
        if c.shape[0] == places.size and not np.any(c % ch) and c.min(initial=0) >= 0 and np.all(c // ch < g):
            places[np.ravel_multi_index(tuple((c // ch).T), grid)] = where
        end = os.path.getsize(self.path)
        if np.any(places < 0) or np.any(places > end - size):
            self.fail(dataset, (0, 0, 0), "HDF5's chunk index does not list each brick once, inside the file")
        return places

    def _bulk_chunks(self, ds, dataset: str, rows: np.ndarray, chunks, grid) -> np.ndarray:
        """As :meth:`_raw_chunks` for the chunks of grid rows ``rows``, read from a memory map of the file, one
        slice per run of chunks stored back to back (HDF5 writes them so, with its index nodes between runs)."""
        if dataset not in self._places:
            self._places[dataset] = self._chunk_places(ds, dataset, chunks, grid)
        size = int(np.prod(chunks)) * ds.dtype.itemsize
        at = self._places[dataset][rows]
        order = np.argsort(at, kind="stable")
        s = at[order]
        cut = np.flatnonzero(np.diff(s) != size + 4) + 1
        mm = np.memmap(self.path, dtype=np.uint8, mode="r")
        if mm.size < int(s[-1]) + size + 4:
            self.fail(dataset, (0, 0, 0), "the file is shorter than its chunk index says")
        raw = np.empty((rows.size, size), dtype=np.uint8)
        for a, b in zip(np.r_[0, cut].tolist(), np.r_[cut, rows.size].tolist()):
            raw[order[a:b]] = mm[int(s[a]):int(s[a]) + (b - a) * (size + 4)].reshape(b - a, size + 4)[:, :size]
        return raw.view(ds.dtype.newbyteorder("<")).reshape((rows.size,) + tuple(chunks))

    def verify_all(self, f, dataset: str) -> None:
        """Check every chunk of ``dataset`` (``isplat stats``)."""
        shape = f[dataset].shape
        if len(shape) == 1:
            step = max(1, (1 << 24) // max(1, f[dataset].dtype.itemsize))
            for a in range(0, int(shape[0]), step):
                self.read(f, dataset, (slice(a, a + step),))
        else:
            self.read(f, dataset)


def _check_table(path, f, dataset: str, ds, rebuild: str, lookup) -> None:
    """The table of ``dataset`` exists with one 16-byte row per chunk of ``ds`` (its layout is not checked: each
    row is keyed, so a table damaged or replaced fails when its rows are compared); ``lookup(f, name)`` looks it
    up (:meth:`Verifier._obj`)."""
    import h5py

    name = table_name(dataset)
    try:
        t = lookup(f, f"{GROUP}/{name}")
    except KeyError:
        t = None
    if not isinstance(t, h5py.Dataset):
        raise IsplatError(f"{path}: dataset '/{GROUP}/{name}' (the hashes of '{dataset}') is missing; rebuild it: "
                          f"{rebuild}")
    n = int(np.prod(grid_shape(ds.shape, ds.chunks)))
    if t.dtype != np.dtype("|u1") or tuple(t.shape) != (n, DIGEST):
        raise IsplatError(f"{path}: dataset '/{GROUP}/{name}' is {t.dtype} {tuple(t.shape)}, expected uint8 "
                          f"({n}, {DIGEST}) (one hash per chunk of '{dataset}'); rebuild it: {rebuild}")


def open_verifier(path, f, density_sha256: str, datasets, attributes, rebuild: str,
                  algorithm: str = "blake2b", root_attrs=None) -> Verifier:
    """At open: the file key from the file's attributes and datasets, checked against ``chunk_hash_check``, and
    the table group's presence (each table's shape is checked on the first read of its dataset). Refuses with one
    line naming the command that rebuilds the file. ``root_attrs``: the root's attributes if already read
    (:class:`isplat.fileio.ReadAttrs`), else ``f.attrs``."""
    from .fileio import attr_string, check_string_attrs

    key = file_key(density_sha256, datasets, attributes)
    a = f.attrs if root_attrs is None else root_attrs
    if CHECK_ATTR not in a:
        raise IsplatError(f"{path}: attribute '{CHECK_ATTR}' is missing; rebuild it: {rebuild}")
    check_string_attrs(path, a, (CHECK_ATTR,))
    if attr_string(a, CHECK_ATTR) != check_value(key):
        raise IsplatError(f"{path}: attribute '{CHECK_ATTR}' does not match the file's attributes and datasets "
                          f"(an attribute that steers reading was changed, a dataset added or removed, or the "
                          f"hashes come from another file); rebuild it: {rebuild}")
    import h5py

    if not isinstance(f.get(GROUP), h5py.Group):
        raise IsplatError(f"{path}: group '/{GROUP}' is missing; rebuild it: {rebuild}")
    return Verifier(path, key, rebuild, algorithm)


def attributes_of(f, spec, root_attrs=None) -> list:
    """``(where, name, value or None)`` for each ``(where, name)`` of ``spec`` (``where``: a group path, "" the
    root), read from open file ``f`` as stored (strings as their bytes, numbers little-endian). ``root_attrs``:
    the root's attributes if already read (:class:`isplat.fileio.ReadAttrs`)."""
    groups, out = {}, []
    for where, name in spec:
        if where not in groups:          # each group's attributes read once
            a = root_attrs if not where and root_attrs is not None else (f[where] if where else f).attrs
            groups[where] = dict(a.items())
        v = groups[where].get(name)
        out.append((where, name, None if v is None else np.asarray(v)))
    return out


def place_bricks(out: np.ndarray, data: np.ndarray, offs: np.ndarray, ext: np.ndarray, origin) -> None:
    """Write bricks ``data`` [n, ck, cj, ci] (first element at ``offs``, their parts inside the volume ``ext``)
    into ``out`` (the block from element ``origin``), each clipped to the block: one fancy assignment into a
    strided view of ``out`` (its brick grid) per class of equally clipped bricks, not one copy per brick."""
    from numpy.lib.stride_tricks import as_strided

    ch = np.asarray(data.shape[1:], dtype=np.int64)
    lo = np.asarray(origin, dtype=np.int64)
    a = np.maximum(lo - offs, 0)
    b = np.minimum(ext, lo + np.asarray(out.shape, dtype=np.int64) - offs)
    ok = np.flatnonzero(np.all(b > a, axis=1))
    cut = np.concatenate([a, b], axis=1)[ok]
    key = _row_keys(cut)
    for k in np.unique(key):
        m = ok[key == k]
        c = cut[np.flatnonzero(key == k)[0]]
        s0, e = c[:3], c[3:] - c[:3]
        dest = offs[m] + s0 - lo
        anchor = dest[0] % ch                        # the same for the class: bricks are ch apart, clipped ones at 0
        idx = (dest - anchor) // ch
        sub = out[anchor[0]:, anchor[1]:, anchor[2]:]
        cnt = (np.asarray(sub.shape, dtype=np.int64) - e) // ch + 1
        view = as_strided(sub, shape=tuple(int(x) for x in cnt) + tuple(int(x) for x in e),
                          strides=tuple(int(c_) * s for c_, s in zip(ch, sub.strides)) + sub.strides)
        view[idx[:, 0], idx[:, 1], idx[:, 2]] = data[m, s0[0]:c[3], s0[1]:c[4], s0[2]:c[5]]


def _row_keys(a: np.ndarray) -> np.ndarray:
    """int64[n]: one number per row of small non-negative ``a`` (int64[n, m]), equal exactly for equal rows."""
    key = np.zeros(a.shape[0], dtype=np.int64)
    for col in a.T:
        key = key * (int(a.max(initial=0)) + 1) + col
    return key
