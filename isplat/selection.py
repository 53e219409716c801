"""What a scene's frames need, in memory, and nothing else: the selection (paper §2.2).

A :class:`Selection` holds, per index axis its views use, the voxels of the transfer function's densities in
the order frames stream them (slice by slice, cell by cell) with their channel values, plus the tables that
depend only on the transfer function. It is made once, from files (:func:`select_from_files`: only the index
blocks of the transfer function's intervals and the channels the scene uses are read) or from arrays already
in memory (:meth:`Selection.from_arrays`: the index is built in memory), and then every frame is rendered from
it without file I/O (:func:`isplat.frame.render_frame`).

>>> import numpy as np
>>> from isplat.scene import parse_scene
>>> vol = np.zeros((8, 8, 8), np.uint8); vol[2:6, 2:6, 2:6] = 200
>>> scene = parse_scene("[transfer]\\nopacity = [[100, 0], [200, 0.8]]\\n[shading]\\nenabled = false",
...                     ".", "example", data_required=False)
>>> sel = Selection.from_arrays(vol, scene)
>>> sel.axes["k"].n_voxels, sel.held_bytes() > 0
(64, True)
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np

from . import grid
from .errors import IsplatError
from .fileio import PAGE
from .splat.kernels import IndexedVoxels, WholeVolume
from .transfer import TransferLUTs, build_luts

log = logging.getLogger(__name__)
_EMPTY_U8 = np.zeros(0, dtype=np.uint8)
_EMPTY_U16 = np.zeros(0, dtype=np.uint16)
_EMPTY_U32 = np.zeros(0, dtype=np.uint32)
_EMPTY_U64 = np.zeros(0, dtype=np.uint64)
_EMPTY_I64 = np.zeros(0, dtype=np.int64)
GATHER_SLAB = 8      # k-slices read at a time when gathering channel values
MAX_IN_SLICE = 65535  # in-slice coordinates are uint16


@dataclass
class LoadReport:
    """What a selection read. ``*_bytes``: the arrays requested; ``*_file_bytes``: what the HDF5 library read
    from each file for them (whole chunks with their checksums, and the metadata that locates them; for the
    index its opening too), counted at the file object (:class:`isplat.fileio.ReadCounter`)."""

    augmented_bytes: int = 0          # bytes requested from the augmented file's channels
    index_bytes: int = 0              # bytes requested from the index file (blocks, tables; version 4: values)
    augmented_file_bytes: int = 0     # bytes HDF5 read from the augmented file while selecting
    index_file_bytes: int = 0         # bytes HDF5 read from the index file (opened for this selection)
    values_bytes: int = 0             # bytes requested from the index's values file (version 6; pre only)
    values_file_bytes: int = 0        # bytes HDF5 read from the values file (its opening included)
    augmented_file_pages: int = 0     # bytes of the distinct 4 KB pages of each file those reads lie in
    index_file_pages: int = 0         # (ReadCounter.page_bytes; -1: not known, format 5's bricks; a frame
    values_file_pages: int = 0        # in slabs: each file's pages over all its slabs)
    runs_file_bytes: int = 0          # bytes HDF5 read from the runs file (post; its opening included)
    runs_file_pages: int = 0
    index_decoded_bytes: int = 0      # the decoded blocks (LoadedAxis arrays), before selection
    index_block_bytes: int = 0        # requested index blocks and table rows of the intervals, all axes (a slab
    #                                   of a streamed frame: its own rows, the tables the slabs share counted once)
    index_format_version: int = 0     # 0: no index read
    voxels_of_interest: int = 0       # voxels whose density lies in the intervals
    technique: str = ""               # render.classification: "pre", "post", "mip", "minip"
    channel_bytes_per_voxel: int = 0  # bytes per voxel of the channels the technique reads (density included
    #                                   when it is read from the augmented file)
    index_bytes_needed: int = 0       # the index blocks and table rows of the intervals (+ /values' table)
    footprint: object = field(default=None, repr=False, compare=False)   # post: () -> (axis, voxels), lazy
    _needed: tuple | None = field(default=None, repr=False, compare=False)
    values_from: str = "none"         # "values file", "index", "augmented bricks", "augmented slabs",
    #                                   "whole channels", "slab's channels", post's "bricks (N of M)" and
    #                                   "runs file (N of M runs)", or "none"
    values_path: str = ""             # the values file read ("values file"), the index ("index"), the runs file
    channels: list = field(default_factory=list)
    axes: list = field(default_factory=list)
    intervals: list = field(default_factory=list)

    @property
    def needed_voxels(self) -> int:
        """The voxels whose channel values the technique needs (docs/stats.md): pre, the voxels of interest;
        post, the voxels its quads read, for the loaded axis where they are most (:attr:`needed_axis`)."""
        return self._resolve()[1]

    @property
    def needed_axis(self) -> str:
        """The slice axis :attr:`needed_voxels` counts post's quads of ("" when not post)."""
        return self._resolve()[0]

    def _resolve(self) -> tuple[str, int]:
        if self._needed is None:        # post's footprint is counted when first asked for (not at load time)
            self._needed = self.footprint() if self.footprint is not None else ("", self.voxels_of_interest)
            self.footprint = None
        return self._needed

    def __getstate__(self):
        """Pickled (a Dask worker's report) with the footprint counted, not the density it is counted from."""
        self._resolve()
        return self.__dict__

    SUMMED = ("augmented_bytes", "index_bytes", "augmented_file_bytes", "index_file_bytes", "values_bytes",
              "values_file_bytes", "index_decoded_bytes", "index_block_bytes", "voxels_of_interest",
              "index_bytes_needed", "runs_file_bytes")

    PAGES = ("augmented_file_pages", "index_file_pages", "values_file_pages", "runs_file_pages")

    def plus(self, other: "LoadReport") -> "LoadReport":
        """The report of two slabs of one frame (streamed, or on Dask workers): what each read, requested and
        needed, added up (pages too: a page two slabs share counted twice, unless the caller counts them over
        the frame); the rest (technique, channels, axes, intervals) is the same for every slab."""
        (axis, n), (axis2, n2) = self._resolve(), other._resolve()
        out = replace(self, footprint=None, _needed=(axis or axis2, n + n2))
        for name in self.SUMMED:
            setattr(out, name, getattr(self, name) + getattr(other, name))
        for name in self.PAGES:
            a, b = getattr(self, name), getattr(other, name)
            setattr(out, name, -1 if min(a, b) < 0 else a + b)
        return out

    @property
    def channel_bytes_needed(self) -> int:
        return self.needed_voxels * self.channel_bytes_per_voxel

    @property
    def bytes_needed(self) -> int:
        """The technique's bytes needed (docs/stats.md): :attr:`needed_voxels` x the bytes per voxel of the
        channels it reads, + the index blocks and table rows of the intervals."""
        return self.channel_bytes_needed + self.index_bytes_needed

    @property
    def file_bytes(self) -> int:
        """Bytes read from the files at the HDF5 layer (augmented, index, its values file and its runs file)."""
        return self.augmented_file_bytes + self.index_file_bytes + self.values_file_bytes + self.runs_file_bytes

    @property
    def read_ratio(self) -> float:
        """Bytes read from the files over bytes needed (0 when nothing is needed)."""
        return self.file_bytes / self.bytes_needed if self.bytes_needed else 0.0

    @property
    def file_pages(self) -> int:
        """Bytes of the distinct 4 KB pages of the files those reads lie in (-1: not known)."""
        pages = [getattr(self, name) for name in self.PAGES]
        return -1 if min(pages) < 0 else sum(pages)

    @property
    def page_ratio(self) -> float:
        """:attr:`file_pages` over bytes needed (0 when nothing is needed, -1 when not known)."""
        if self.file_pages < 0:
            return -1.0
        return self.file_pages / self.bytes_needed if self.bytes_needed else 0.0


@dataclass(frozen=True)
class AxisSelection:
    """The selected voxels of one index axis, in traversal order: slices, regions, blocks, cells (see
    :mod:`isplat.splat.select`), and their gathered channel values (empty arrays for channels the scene does
    not use). A voxel costs 2 bytes (its square in its cell, its density) plus its channel values, and
    2 bytes per cell and 17 per block of 16 x 16 voxels. A post-classified composite selection holds no
    ``offset`` and ``density`` (empty): its frames sample the channels at the cells' quads, and its voxels are
    counted by ``block_voxel``."""

    axis: str
    n_slices: int
    n_a: int
    n_b: int
    slice_ptr: np.ndarray           # int64[n_slices + 1]: regions of each slice
    region_id: np.ndarray           # int32[G]
    region_ptr: np.ndarray          # int64[G + 1]: blocks of each region
    block_pos: np.ndarray           # uint8[R]
    block_ptr: np.ndarray           # int64[R + 1]: cells of each block
    block_voxel: np.ndarray         # int64[R + 1]: first voxel of each block
    cell_pos: np.ndarray            # uint8[Q]
    cell_count: np.ndarray          # uint8[Q]
    offset: np.ndarray              # uint8[N]: the voxel's square in its cell
    density: np.ndarray             # uint8[N]
    gradient_magnitude: np.ndarray  # uint8[N] or empty
    normal: np.ndarray              # uint16[N] or empty

    @property
    def n_voxels(self) -> int:
        return int(self.block_voxel[-1]) if self.block_voxel.size else int(self.offset.shape[0])

    @property
    def cells_only(self) -> bool:
        """True when the voxels' squares and densities are not held (a post-classified composite selection):
        pre-classified and intensity-projection frames, which read them, refuse it."""
        return self.offset.shape[0] != self.n_voxels

    def voxels(self) -> IndexedVoxels:
        """The arrays as the frame kernel takes them."""
        return IndexedVoxels(*self.arrays(), self.n_a, self.n_b)

    @cached_property
    def max_cells(self) -> int:
        """The most cells of one slice (the size of a thread's list of visible cells; worked out once)."""
        if not self.n_slices:
            return 0
        return int(np.diff(self.block_ptr[self.region_ptr[self.slice_ptr]]).max(initial=0))

    def arrays(self) -> list[np.ndarray]:
        return [self.slice_ptr, self.region_id, self.region_ptr, self.block_pos, self.block_ptr, self.block_voxel,
                self.cell_pos, self.cell_count, self.offset, self.density, self.gradient_magnitude, self.normal]

    def coordinates(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every voxel's slice and in-slice coordinates ``(c, a, b)`` (int64, in traversal order): for tests and
        tools, not for frames; refused for a selection of the cells alone (:attr:`cells_only`)."""
        if self.cells_only:
            raise IsplatError(f"axis {self.axis}: this selection holds the cells alone (made for a post-classified "
                              "composite frame), not the voxels' coordinates")
        from .splat.select import expand_coordinates

        return expand_coordinates(self.slice_ptr, self.region_id, self.region_ptr, self.block_pos, self.block_ptr,
                                  self.block_voxel, self.cell_pos, self.cell_count, self.offset, self.n_a)


@dataclass(frozen=True)
class WholeChannels:
    """The full method's data: whole channels, flat ``[k, j, i]`` (empty when unused); or, with a brick ``table``
    (post's bricks from a format 6 file), a pool: the channels hold only the bricks read, one row of
    ``POOL_EDGE``^3 voxels each (row 0 zeros), and ``table`` (uint32 per brick of the volume's grid, C order)
    gives each brick's row, 0 for a brick not read (isplat.grid.flat_offsets: brick-major); the sampler reads
    through :meth:`value_deltas`, made from it when a frame first asks. A packed pool (the range runs' reader,
    isplat.runsplace.pack_rows): the rows share places, row ``r``'s place ``p`` at ``bases[r] + p``, and
    ``loaded`` (uint64, 8 words a row, the rows' layout) says which of a row's places it holds; post's bits of
    the quads held keep the rows' layout (isplat.splat.post._row_place)."""

    density: np.ndarray
    gradient_magnitude: np.ndarray
    normal: np.ndarray
    held: int = -1          # bricks read (post, version 5): the bytes of the memory pages they filled; -1: nbytes
    table: np.ndarray = field(default_factory=lambda: _EMPTY_U32)
    shape: tuple = ()       # the volume's (k, j, i), for a pool
    bases: np.ndarray = field(default_factory=lambda: _EMPTY_I64)      # a packed pool: each row's first place
    loaded: np.ndarray = field(default_factory=lambda: _EMPTY_U64)     # a packed pool: its rows' loaded bits
    _flat: dict = field(default_factory=dict, repr=False)

    @property
    def pooled(self) -> bool:
        return self.table.size > 0

    def arrays(self) -> list[np.ndarray]:
        return [self.density, self.gradient_magnitude, self.normal]

    def held_bytes(self) -> int:
        if self.pooled:
            return int(sum(a.nbytes for a in self.arrays()) + self.table.nbytes + self.bases.nbytes
                       + self.loaded.nbytes + sum(a.nbytes for a in self._flat.values()))
        return self.held if self.held >= 0 else int(sum(a.nbytes for a in self.arrays()))

    def deltas(self) -> np.ndarray:
        """uint64 per brick: its pool row's first voxel minus its own first brick-major flat index, modulo 2^64
        (``(row - brick) << POOL_SHIFT``): post's sampler finds voxel ``i`` at ``i + deltas[i >> POOL_SHIFT]``,
        one add (post._phys). Made once, held beside the table (8 bytes a brick of the volume's grid)."""
        if "delta" not in self._flat:
            n = np.arange(self.table.size, dtype=np.int64)
            self._flat["delta"] = ((self.table.astype(np.int64) - n) << grid.POOL_SHIFT).view(np.uint64)
        return self._flat["delta"]

    def value_deltas(self) -> np.ndarray:
        """:meth:`deltas` of the channels' places: the same for rows laid one after the other; a packed pool's
        ``bases[row] - (brick << POOL_SHIFT)`` (modulo 2^64; a brick not in the pool: ``bases[0]`` = 0, so its
        places fall in the pool's first 512, which no frame reads: its quads are not held)."""
        if not self.bases.size:
            return self.deltas()
        if "value_delta" not in self._flat:
            n = np.arange(self.table.size, dtype=np.int64)
            self._flat["value_delta"] = (self.bases[self.table] - (n << grid.POOL_SHIFT)).view(np.uint64)
        return self._flat["value_delta"]

    @property
    def _packing(self):
        return (self.bases, self.loaded) if self.bases.size else None

    def flat(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The channels flat ``[k, j, i]``: themselves, or a pool's bricks placed into zeroed whole-shape arrays
        (made once: ``isplat stats``' footprint and tests; the frames read the pool, MIP whole channels)."""
        if not self.pooled:
            return self.density, self.gradient_magnitude, self.normal
        if "d" not in self._flat:
            for name, a in zip(("d", "g", "n"), self.arrays()):
                self._flat[name] = _unpool(a, self.table, self.shape, self._packing) if a.size else a
        return self._flat["d"], self._flat["g"], self._flat["n"]


def _unpool(pool: np.ndarray, table: np.ndarray, shape, packing=None) -> np.ndarray:
    """The whole-shape channel ``[k, j, i]`` (flat) of a pool's rows (zeros where no brick was read)."""
    return np.ascontiguousarray(_unpool_box(pool, table, shape, [(0, int(n)) for n in shape], packing)).reshape(-1)


def _unpool_box(pool: np.ndarray, table: np.ndarray, shape, box, packing=None) -> np.ndarray:
    """The box ``[k0:k1, j0:j1, i0:i1]`` (``box``: a (lo, hi) per dimension) of a pool's channel (zeros where no
    brick was read): only the bricks that meet it are gathered. ``packing``: a packed pool's ``(bases, loaded)``
    (:class:`WholeChannels`), its rows' places not loaded zero."""
    e = grid.POOL_EDGE
    g = [-(-int(n) // e) for n in shape]
    cut = tuple(slice(lo // e, -(-hi // e)) for lo, hi in box)
    t = table.reshape(g)[cut]
    if packing is None:
        bricks = pool.reshape(-1, e, e, e)[t]
    else:
        bases, loaded = packing
        rows = t.reshape(-1).astype(np.int64)
        bits = np.unpackbits(loaded.view(np.uint8), bitorder="little").reshape(-1, e ** 3)[rows].astype(bool)
        vals = pool[bases[rows][:, None] + np.arange(e ** 3)]
        bricks = np.where(bits, vals, 0).astype(pool.dtype).reshape(*t.shape, e, e, e)
    full = bricks.transpose(0, 3, 1, 4, 2, 5).reshape([n * e for n in t.shape])
    return full[tuple(slice(lo - c.start * e, hi - c.start * e) for (lo, hi), c in zip(box, cut))]


class _PoolVolume:
    """A pool's channel seen as the ``[k, j, i]`` volume of ``shape`` cut to ``box`` (a (lo, hi) per dimension),
    unpooled a few planes at a time as it is sliced along k: what isplat.stats.quad_footprint_per_slice reads, so
    the footprint is counted without the whole volume in memory (1 GiB a channel at 1024^3)."""

    def __init__(self, pool, table, shape, box, packing=None):
        self._args, self.box = (pool, table, tuple(int(n) for n in shape)), [tuple(map(int, b)) for b in box]
        self._packing = packing
        self.shape = tuple(b - a for a, b in self.box)

    def __getitem__(self, ks: slice) -> np.ndarray:
        k0, k1, step = ks.indices(self.shape[0])
        if step != 1:
            raise ValueError("a pool volume is read in planes k0:k1")
        a = self.box[0][0]
        return _unpool_box(*self._args, [(a + k0, a + max(k0, k1)), *self.box[1:]], self._packing)


@dataclass(frozen=True, eq=False)
class Selection:
    """What the frames of one transfer function need (module docstring). ``axes`` for the indexed method,
    ``whole`` for the full one and for post-classification (which samples the neighbours of the voxels of
    interest, whatever their density). Made from a :class:`~isplat.request.RenderRequest` (``request``) and not
    changed after: frames keep what they learn (their bands) elsewhere (:class:`isplat.frame.BandLearning`), so
    one selection serves any number of threads and renderers."""

    method: str
    shape: tuple[int, int, int]            # (n_k, n_j, n_i)
    spacing_ijk: tuple[float, float, float]
    luts: TransferLUTs
    unit_distance: float                   # 0: the renderer's default (the smallest spacing)
    use_shade: bool
    use_gm: bool
    post: bool = False                     # post-classified: the whole channels too (isplat.splat.post)
    axes: dict[str, AxisSelection] = field(default_factory=dict)
    whole: WholeChannels | None = None
    report: LoadReport = field(default_factory=LoadReport)
    slab: tuple | None = None              # (axis, c0, c1): ``whole`` holds only these slices (post, a slab)
    request: object = field(default=None, repr=False)   # the RenderRequest it was made from
    labels: object = None                  # label_select.LabelSelection: the labels shown, or None
    # post from range runs (:func:`_read_post_runs`): per axis, the bits of the quads whose four corners ``whole``
    # holds (isplat.splat.post.held_quads); None: it holds every voxel the quads read
    held: dict | None = field(default=None, repr=False)

    @property
    def empty(self) -> bool:
        """True when the transfer function makes every density transparent and no label is shown."""
        return len(self.luts.intervals) == 0 and not _shows_labels(self.request)

    def voxels(self, axis: str):
        """The kernel's view of the voxels of ``axis``: IndexedVoxels or WholeVolume."""
        if self.method == "full":
            return self.whole_volume(axis)
        if axis not in self.axes:
            raise IsplatError(f"axis {axis} was not selected (selected: {sorted(self.axes) or 'none'}); "
                              "select the axes of every view to be rendered")
        return self.axes[axis].voxels()

    def whole_volume(self, axis: str, pool: bool = False) -> WholeVolume:
        """The whole channels as the kernels take them: the flat steps of ``axis``'s slices, and a fourth entry
        added to every flat index (not 0 when the channels hold only a slab's slices, ``slab``); the same as
        per-axis tables (``offs``). ``pool``: the caller reads through a brick table (isplat.splat.post), so a
        pool is given as it is; else a pool's channels are given flat (:meth:`WholeChannels.flat`)."""
        _, n_a, n_b = grid.slice_shape(self.shape, axis)
        w = self.whole
        shape, base = self.shape, 0
        if self.slab is not None:
            ax, c0, c1 = self.slab
            if ax != axis:
                raise IsplatError(f"this selection holds the channels of slices {c0}..{c1 - 1} of axis {ax}, "
                                  f"not of axis {axis}")
            if not w.pooled:            # (a pool's table spans the volume's grid, a slab's or not: flat, whole)
                shape = _slab_shape(self.shape, axis, c1 - c0)
        steps = grid.flat_strides(shape, axis)
        if self.slab is not None and not w.pooled:
            base = -self.slab[1] * int(steps[2])
        n_c = grid.slice_shape(self.shape, axis)[0]
        oc = np.arange(n_c, dtype=np.int64) * int(steps[2]) + base        # each slice's first voxel
        if pool and w.pooled:           # a pool: brick-major tables and the brick table
            oa, ob, oc = grid.flat_offsets(shape, axis, grid.POOL_EDGE)
            # one entry more, the last repeated: the sampler's step past the edge voxel is 0 (post._step); no
            # prefetch (post._prefetch_square), so no voxels per prefetch
            oa, ob = np.append(oa, oa[-1]), np.append(ob, ob[-1])
            return WholeVolume(w.density, w.gradient_magnitude, w.normal, np.append(steps, base), n_a, n_b,
                               (oa, ob, oc, 0), w.value_deltas())
        sa, sb = int(steps[0]), int(steps[1])       # strides: the kernel multiplies (post._at)
        return WholeVolume(*w.flat(), np.append(steps, base), n_a, n_b, (sa, sb, oc, max(1, 32 // sa)), None)

    def held_bytes(self) -> int:
        """Bytes of volume data held for the frames (selection and gathered values, or whole channels, and the
        bits of the quads held)."""
        held = self.whole.held_bytes() if self.whole is not None else 0
        held += sum(int(b.nbytes) for b in (self.held or {}).values())
        return held + int(sum(a.nbytes for s in self.axes.values() for a in s.arrays()))

    def held_quads(self, axis: str):
        """post's test of quads (isplat.splat.post.PostPlan ``held``): None when ``whole`` holds every voxel the
        quads read, else the bits of ``axis``'s quads with all four corners held."""
        if self.held is None:
            return None
        if axis not in self.held:
            raise IsplatError(f"axis {axis} was not selected (selected: {sorted(self.held)}); select the axes of "
                              "every view to be rendered")
        return self.held[axis]

    @classmethod
    def from_arrays(cls, density, scene, normal=None, gradient_magnitude=None, gradient_magnitude_scale=None,
                    spacing=None, window=None, axes: str = "ijk", method: str | None = None,
                    identity=None) -> "Selection":
        """Select from a volume in memory for ``scene``'s transfer function, shading and method.

        ``density``: the augmented density codes (uint8 ``[k, j, i]``) with, where the scene needs them,
        ``normal`` (uint16 oct16 codes) and ``gradient_magnitude`` (uint8 codes, with their
        ``gradient_magnitude_scale``); or any scalar volume, which is augmented first
        (:func:`isplat.augment.augment_array`, with ``window``). ``axes``: the index axes to select (the
        principal axes of the views to be rendered). The index is built in memory. ``identity``: what
        identifies the arrays' values in the selection's request (:class:`~isplat.request.RenderRequest`).
        """
        from .memory import channels_in_memory
        from .request import RenderRequest

        chans, gscale, sp = channels_in_memory(density, scene, normal, gradient_magnitude,
                                               gradient_magnitude_scale, spacing, window)
        req = RenderRequest.from_arrays(scene, identity, chans["density"].shape, sp, gscale,
                                        "".join(a for a in grid.AXES if a in axes), method)
        return select_arrays(req, chans)


def _shows_labels(request) -> bool:
    return bool(getattr(request, "labels", ()))


def select_arrays(request, chans: dict) -> Selection:
    """The selection of ``request`` from channels in memory (``{channel: array [k, j, i]}``, the channels the
    request uses): the index built in memory (:func:`isplat.index.memory.load_axis_in_memory`)."""
    if _shows_labels(request):
        raise IsplatError("labels are shown from an augmented file with a label channel (isplat augment "
                          "--labels), not from arrays in memory")
    sel = _empty_selection(request)
    if not sel.use_gm and "gradient_magnitude" in sel.report.channels and chans.get("gradient_magnitude") is None:
        sel.report.channels.remove("gradient_magnitude")    # only the shading's weights: optional (splat.post)
    read = lambda ch, k0, k1: chans[ch][k0:k1]      # noqa: E731
    if sel.method == "full" or sel.post:
        sel = replace(sel, whole=_whole(sel, read))
    if sel.method == "indexed" and not sel.empty:
        from .index.memory import load_axis_in_memory

        loaded = {ax: load_axis_in_memory(chans["density"], ax, sel.luts.intervals) for ax in request.axes}
        _select(sel, loaded, lambda lo, ch, sh: gather_channels(read, lo, ch, sh), "array")
        sel.report.voxels_of_interest = next(iter(loaded.values())).n_voxels if loaded else 0
    sel.report.axes = sorted(request.axes)
    _needed(sel, count_full=False)      # (no pass over a full selection's density here, as before)
    return sel


def _empty_selection(request) -> Selection:
    """A selection of ``request`` with nothing selected yet: its tables, what it reads, its report."""
    luts = build_luts(request.transfer, request.gradient_magnitude_scale)
    empty = len(luts.intervals) == 0 and not _shows_labels(request)
    sel = Selection(request.method, request.shape, request.spacing_ijk, luts, request.unit_distance,
                    request.shading and not empty, luts.gradient is not None and not empty, request.post,
                    request=request)
    sel.report.intervals = luts.intervals.tolist()
    # post-classified and shaded: the gradient magnitudes too, which weight the corners' Phong factors
    # (isplat.splat.post._sample)
    gm = sel.use_gm or (sel.use_shade and request.post)
    sel.report.channels = (["normal"] if sel.use_shade else []) + (["gradient_magnitude"] if gm else [])
    return sel


def _whole(sel: Selection, read) -> WholeChannels:
    """The full method's channels: every voxel is visited, so whole channels, indexed by flat position."""
    if sel.empty:
        return WholeChannels(_EMPTY_U8, _EMPTY_U8, _EMPTY_U16)
    if "density" not in sel.report.channels:
        sel.report.channels.insert(0, "density")
    n = int(np.prod(sel.shape))
    whole = {ch: read(ch, 0, sel.shape[0]).reshape(n) for ch in sel.report.channels}
    return WholeChannels(whole["density"], whole.get("gradient_magnitude", _EMPTY_U8), whole.get("normal", _EMPTY_U16))


def _select(sel: Selection, loaded: dict, gather, source: str, intervals=None) -> None:
    """Select the voxels of every loaded axis (``{axis: LoadedAxis}``) and gather their channel values with
    ``gather(loaded, channels, shape)`` (:func:`gather_channels` or :func:`gather_from_index`); none when the
    selection is post-classified (its frames read the whole channels). ``intervals``: the codes the loaded blocks
    are selected by, when not the transfer function's (labels: :mod:`isplat.label_select`)."""
    from .splat.select import select_voxels

    channels = [] if sel.post else [ch for ch in sel.report.channels if ch != "density"]
    # post's composite frames read the cells alone (isplat.splat.post: the quads of the cells' voxels, sampled
    # from the channels), not each voxel's square and density: 2 bytes a voxel of interest not held
    cells_only = sel.post and intervals is None and getattr(sel.request, "mode", "") == "composite"
    ivs = (sel.luts.intervals if intervals is None else np.asarray(intervals)).astype(np.int64).reshape(-1, 2)
    picked = {}
    for ax, la in loaded.items():
        if max(la.n_a, la.n_b) > MAX_IN_SLICE:
            raise IsplatError(f"{source}: axis {ax} slices are {la.n_a}x{la.n_b}; the renderer takes at most "
                              f"{MAX_IN_SLICE} voxels per in-slice axis")
        try:
            picked[ax] = select_voxels(la.slice_block_ptr, la.block_density, la.block_voxel_ptr, la.positions,
                                       ivs, la.n_a, la.n_b,
                                       _index_like(la.positions.shape[0], bool(channels)))
        except ValueError as exc:
            raise IsplatError(f"{source}: axis {ax}: {exc}") from None
    gathered = gather(loaded, channels, sel.shape) if channels else {ax: {} for ax in loaded}
    for ax, (*hier, src) in picked.items():
        g = gathered[ax]            # in the order of the decoded positions; the selection's order is ``src``
        gm = g["gradient_magnitude"][src] if "gradient_magnitude" in g else _EMPTY_U8
        nrm = g["normal"][src] if "normal" in g else _EMPTY_U16
        la = loaded[ax]
        if cells_only:
            hier[-2:] = _EMPTY_U8, _EMPTY_U8
        sel.axes[ax] = AxisSelection(ax, la.n_slices, la.n_a, la.n_b, *hier, gm, nrm)
    # the decoded blocks have served: frames need only the selection and the gathered values
    sel.report.index_decoded_bytes = int(sum(
        la.slice_block_ptr.nbytes + la.block_density.nbytes + la.block_voxel_ptr.nbytes + la.positions.nbytes
        for la in loaded.values()))


def _index_like(n: int, wanted: bool) -> np.ndarray:
    """select_voxels' ``src_like``: the smallest integer type that indexes ``n`` items (int32 or int64), and
    whether the voxels' source rows are wanted (empty array) or not (one item)."""
    return np.zeros(0 if wanted else 1, np.int32 if n < 2 ** 31 else np.int64)


def gather_channels(read, loaded: dict, channels, shape) -> dict:
    """For every loaded index axis, the channel values of just its voxels, in the order of its ``positions``.

    ``read(channel, k0, k1)`` returns the k-slab ``k0:k1`` of a channel. Channels are read in slabs of
    GATHER_SLAB k-slices and only the slabs that hold a voxel of interest are read, so a scene that sees a
    small part of the volume reads a small part of the file.
    """
    from .splat.select import flat_indices

    n_k = shape[0]
    plane = int(shape[1]) * int(shape[2])
    fis = {ax: flat_indices(la.slice_block_ptr, la.block_voxel_ptr, la.positions, la.n_a,
                            grid.flat_strides(shape, ax)) for ax, la in loaded.items()}
    out = {ax: {} for ax in loaded}
    if not channels or not fis:
        return out
    all_fi = np.concatenate(list(fis.values()))
    order = np.argsort(all_fi, kind="stable")
    sorted_fi = all_fi[order]
    bounds = np.searchsorted(sorted_fi, np.arange(0, n_k + GATHER_SLAB, GATHER_SLAB) * plane)
    for ch in channels:
        vals = np.empty(all_fi.shape[0], dtype=np.uint16 if ch == "normal" else np.uint8)
        for s_i, k0 in enumerate(range(0, n_k, GATHER_SLAB)):
            lo, hi = bounds[s_i], bounds[s_i + 1]
            if hi > lo:
                slab = read(ch, k0, min(n_k, k0 + GATHER_SLAB)).ravel()
                vals[order[lo:hi]] = slab[sorted_fi[lo:hi] - k0 * plane]
        _split(out, ch, vals, fis)
    return out


def _split(out: dict, ch: str, vals: np.ndarray, fis: dict) -> None:
    """``out[axis][ch]``: each axis's part of ``vals``, the values of the axes' voxels concatenated in ``fis``'
    order."""
    start = 0
    for ax, fi in fis.items():
        out[ax][ch] = vals[start:start + fi.shape[0]]
        start += fi.shape[0]


def gather_bricks(aug, loaded: dict, channels, shape, box=None) -> dict:
    """:func:`gather_channels` from a bricked augmented file: only the bricks that hold a loaded voxel are read
    (each checked, :meth:`isplat.augfile.AugmentedFile.read_bricks`), a layer of bricks (their height of k) at a
    time, within ``box`` (``(lo, hi)``, element bounds (k, j, i): a slab's block; the whole volume if None). Held
    besides the values: 24 bytes per voxel (its flat index, sorted, and their order), as gather_channels."""
    from .splat.select import flat_indices

    fis = {ax: flat_indices(la.slice_block_ptr, la.block_voxel_ptr, la.positions, la.n_a,
                            grid.flat_strides(shape, ax)) for ax, la in loaded.items()}
    out = {ax: {} for ax in loaded}
    if not channels or not fis:
        return out
    lo, hi = box if box is not None else ((0, 0, 0), tuple(shape))
    edge = np.asarray(aug.bricks, dtype=np.int64)
    fi = np.concatenate(list(fis.values()))
    order = np.argsort(fi, kind="stable")
    srt = fi[order]
    plane, layer = int(shape[1]) * int(shape[2]), int(edge[0])           # k-slices per read: one layer of bricks
    cuts = np.searchsorted(srt, np.arange(lo[0] - lo[0] % layer, hi[0] + layer, layer) * plane)
    vals = {ch: np.empty(fi.shape[0], dtype=np.uint16 if ch == "normal" else np.uint8) for ch in channels}
    bgrid = -(-np.asarray(shape, dtype=np.int64) // edge)
    for a, b in zip(cuts[:-1], cuts[1:]):
        if b <= a:
            continue
        at = np.stack(np.unravel_index(srt[a:b], tuple(shape)), axis=1)       # this layer's voxels only
        if ((at < np.asarray(lo)) | (at >= np.asarray(hi))).any():
            raise IsplatError(f"{aug.path}: the index places a voxel outside the slab's block {lo}..{hi}")
        k0 = max(int(lo[0]), int(at[0, 0]) - int(at[0, 0]) % layer)
        sub = ((k0, *lo[1:]), (min(int(hi[0]), k0 + layer), *hi[1:]))
        ids = np.unique(np.ravel_multi_index(tuple((at // edge).T), tuple(bgrid)))
        bricks = np.stack(np.unravel_index(ids, tuple(bgrid)), axis=1)
        at -= np.asarray(sub[0])
        for ch in channels:                       # the block holds only these bricks (zero pages elsewhere)
            vals[ch][order[a:b]] = aug.read_bricks(ch, bricks, sub)[tuple(at.T)]
    for ch in channels:
        _split(out, ch, vals[ch], fis)
    return out


def value_order(la, shape) -> np.ndarray:
    """The permutation that puts the voxels of loaded axis ``la`` (in the order of its ``positions``) in the
    order of the index's ``/values``: by density, then by flat position ``i + n_i * (j + n_j * k)``.

    Loaded voxels run slice by slice, by density within a slice, by position within a block (Figure 1), so
    a stable sort by the fields that rank above the slice in (density, k, j, i) is enough: the density for
    axis k; density and k for axis j; density, k and j for axis i (a radix sort when the key fits 16 bits).
    """
    dens = np.repeat(la.block_density, np.diff(la.block_voxel_ptr))
    if la.axis == "k":
        key = dens
    else:
        pos = la.positions.astype(np.int64)
        key = dens.astype(np.int64) * int(shape[0]) + pos // la.n_a          # b is k for axes j and i
        if la.axis == "i":
            key = key * int(shape[1]) + pos % la.n_a                          # a is j for axis i
        if key.size and key.max() < 65536:
            key = key.astype(np.uint16)
    return np.argsort(key, kind="stable")


def gather_from_index(values, loaded: dict, channels, shape, source="index") -> dict:
    """For every loaded index axis, the channel values of just its voxels, in the order of its ``positions``,
    from ``values = IndexFile.read_values(channels, intervals)`` (format version 3: the values of the
    transfer function's intervals are one contiguous row range per interval and channel, read once for all
    axes), put in each axis's order in memory (:func:`value_order`)."""
    out = {ax: {} for ax in loaded}
    if not channels or not loaded:
        return out
    ivs = next(iter(loaded.values())).intervals
    ptr, vals = values
    want = np.diff(ptr)
    for ax, la in loaded.items():
        have = np.bincount(la.block_density, weights=np.diff(la.block_voxel_ptr), minlength=256).astype(np.int64)
        bad = np.flatnonzero((have != want) & _in_intervals(ivs))
        if bad.size:
            d = int(bad[0])
            raise IsplatError(f"{source}: /values holds {int(want[d]):,} voxels of density {d}, the blocks of "
                              f"axis {ax} {int(have[d]):,}: corrupt index; rebuild it with isplat index")
        perm = value_order(la, shape)
        for ch in channels:
            v = np.empty(perm.size, dtype=vals[ch].dtype)
            v[perm] = vals[ch]
            out[ax][ch] = v
    return out


def _in_intervals(ivs) -> np.ndarray:
    m = np.zeros(256, dtype=bool)
    for lo, hi in ivs:
        m[lo:hi + 1] = True
    return m


def select_from_files(scene, axes: str, method: str | None = None, aug=None, slices=None) -> Selection:
    """Read what ``scene`` needs for frames along ``axes`` from its files: :func:`select` of the scene's
    request (:meth:`RenderRequest.from_files <isplat.request.RenderRequest.from_files>`). ``aug``: the scene's
    augmented file, if already open; ``slices``: a slab's slices (see :func:`select`)."""
    from .augfile import open_augmented
    from .request import RenderRequest

    aug = aug or open_augmented(scene.data.augmented)
    return select(RenderRequest.from_files(scene, aug, axes, method, slices), aug)


def _channels(sel: Selection, aug, axes, slices) -> Selection:
    """The channels read before the index, when not from bricks: a slab's slices (post, indexed, one axis), the
    whole channels (full method, or post on a file without bricks), or none (pre: ``/values``, with the index)."""
    if sel.post and sel.method == "indexed" and slices is not None and len(axes) == 1 and not sel.empty:
        whole, slab = _slab_channels(sel, aug, axes, slices)     # post: only the slab's slices
        sel.report.values_from = "slab's channels"
        return replace(sel, whole=whole, slab=slab)
    if sel.method == "full" or sel.post:
        sel = replace(sel, whole=_whole(sel, aug.read))        # (which notes the channels it read)
        sel.report.values_from = "whole channels" if sel.report.channels else "none"
    return sel


def select(request, aug=None, idx=None) -> Selection:
    """Read what ``request`` needs from its files: only the index blocks of the transfer function's intervals
    (indexed method) and the channels the request uses (module docstring). ``aug``, ``idx``: the augmented file
    and the index, if already open (the report then counts the index's reads since). A slab
    (``request.slab``): only those slices' index blocks are read and decoded (``load_axis(..., slices=)``) and
    the channel values of the slab's voxels alone gathered from the augmented file's k-slabs (the index's
    ``/values`` hold a whole interval's)."""
    from .augfile import open_augmented

    aug = aug or open_augmented(request.augmented)
    if _shows_labels(request):
        from .label_select import select_labels

        return select_labels(request, aug)
    sel = _empty_selection(request)
    axes, slices = request.axes, request.slices
    sel.report.axes = sorted(axes)
    rep = sel.report
    runs = _runs_file(sel, aug, slices)     # post: the range runs its quads can read, beside the index's reads
    bricked = runs is None and _reads_bricks(sel, aug)   # post, version 5: the bricks its quads read, after it
    pending = _start_post_runs(sel, aug, runs) if runs is not None else None
    if runs is None and not bricked:
        sel = _channels(sel, aug, axes, slices)
    if sel.method == "indexed":
        read0, io0 = (idx.bytes_read, idx.io.bytes) if idx is not None else (0, 0)  # (an index opened before:
        mark0 = idx.io.mark() if idx is not None else None                           # this selection's reads)
        idx = _open_matching_index(request, aug, idx)
        rep.index_format_version = idx.version
        v0, vio0 = idx.values_counts(), idx.values_io()
        vmark0 = vio0.mark() if vio0 is not None else None
        if not sel.post:
            rep.values_from = "none" if not rep.channels or sel.empty else _values_source(idx, aug, slices)
        if not sel.empty:
            _select_indexed(sel, aug, idx, slices)
        rep.index_bytes = int(idx.bytes_read - read0)
        rep.index_file_bytes = int(idx.io.bytes - io0)
        rep.values_bytes, rep.values_file_bytes = (b - a for a, b in zip(v0, idx.values_counts()))
        rep.index_file_pages = idx.io.page_bytes(mark0)
        vio = idx.values_io()
        rep.values_file_pages = 0 if vio is None else vio.page_bytes(vmark0 if vio is vio0 else None)
    if bricked:
        sel = _read_post_bricks(sel, aug, axes, slices)
    if pending is not None:
        sel = _read_post_runs(sel, pending)
    rep.augmented_bytes = int(aug.bytes_read)
    rep.augmented_file_bytes = int(aug.io.bytes)        # everything read through ``aug``, its opening included
    rep.augmented_file_pages = aug.io.page_bytes()
    _needed(sel)
    return sel


def _select_indexed(sel: Selection, aug, idx, slices) -> None:
    """The indexed method's part of :func:`select`: the intervals' index blocks (of ``slices`` only, if given),
    decoded, selected, their channel values gathered (from the index's ``/values``, or the augmented file)."""
    rep, axes = sel.report, sel.request.axes
    ivs = [tuple(map(int, iv)) for iv in sel.luts.intervals]
    values = None
    from_values = rep.values_from in ("index", "values file") and slices is None and not sel.post
    with idx.session():
        loaded = {ax: idx.load_axis(ax, ivs, slices=slices) for ax in sorted(axes)}
        if from_values:
            values = idx.read_values(rep.channels, ivs)
    rep.index_block_bytes = int(sum(la.bytes_read if la.bytes_needed is None else la.bytes_needed
                                    for la in loaded.values()))
    if from_values:
        source = idx.path if rep.values_from == "index" else idx.values_file.path
        rep.values_path = str(source)
        gather = lambda lo, ch, sh: gather_from_index(values, lo, ch, sh, source)    # noqa: E731
    elif aug.bricked:            # no values file (or a slab): the bricks that hold a voxel of interest
        box = None if slices is None else _slab_box(aug, axes, slices)
        gather = lambda lo, ch, sh: gather_bricks(aug, lo, ch, sh, box)            # noqa: E731
    else:                        # no values file: the position-ordered channels, in k-slabs
        read = aug.read if slices is None else _slab_reader(aug, axes, slices)
        gather = lambda lo, ch, sh: gather_channels(read, lo, ch, sh)              # noqa: E731
    if not from_values and not sel.post and rep.channels:
        rep.values_from = "augmented bricks" if aug.bricked else "augmented slabs"
    _select(sel, loaded, gather, str(sel.request.index))
    rep.voxels_of_interest = next(iter(loaded.values())).n_voxels if loaded else 0


def _slab_shape(shape, axis: str, n: int) -> tuple[int, int, int]:
    """``shape`` (k, j, i) with ``axis``'s extent ``n``."""
    out = list(shape)
    out[2 - grid.AXES.index(axis)] = n
    return tuple(out)


def _slab_channels(sel: Selection, aug, axis: str, slices) -> tuple[WholeChannels, tuple]:
    """Post-classification of a slab: the channels of just the slab's slices (the tent kernel reaches no other
    slice), read as a block of the file (``[k0:k1]``, ``[:, j0:j1]`` or ``[:, :, i0:i1]``); and the slab."""
    s = np.asarray(list(slices), dtype=np.int64)
    n = grid.slice_shape(sel.shape, axis)[0]
    c0, c1 = (int(s.min()), int(s.max()) + 1) if s.size else (0, 0)
    if c0 < 0 or c1 > n:
        raise IsplatError(f"{aug.path}: slices {c0}..{c1 - 1} of axis {axis}: the axis has {n}")
    if "density" not in sel.report.channels:
        sel.report.channels.insert(0, "density")
    block = (slice(None),) * (2 - grid.AXES.index(axis)) + (slice(c0, c1),)
    out = {}
    for ch in sel.report.channels:      # each chunk read is checked against the file's chunk hashes
        out[ch] = aug.read_block(ch, block).reshape(-1)
    return (WholeChannels(out["density"], out.get("gradient_magnitude", _EMPTY_U8), out.get("normal", _EMPTY_U16)),
            (axis, c0, c1))


# post reads bricks when at most this share of the volume's (or slab's) bricks is needed, else whole channels.
# Measured on the head sample (3 channels, page cache warm, a loaded 2-core machine): bricks scattered at random
# read as fast as the whole channels at about 20% of them, row-contiguous ones beyond 80%; post's bricks (shells
# with their apron) lie between; 0.5 keeps the bytes read low where the time is about even.
BRICK_SHARE = 0.5
# a 4 x 4 cell at a0 has quads reading a0 - 1 .. a0 + 4, the cubics between slices one more, the interpolating
# spline (isplat.splat.post.SPLINE_REACH = 3) one more again: its taps q - 2 .. q + 3 of quad q
QUAD_REACH = (3, 6)


def _reads_bricks(sel: Selection, aug) -> bool:
    """Post-classified, indexed, from a bricked file (version 5), something to show, and no density code 0 of
    interest (the bricks not read hold zeros, which must then never be of interest)."""
    return bool(sel.post and sel.method == "indexed" and getattr(aug, "bricked", False) and not sel.empty
                and sel.labels is None and not any(int(lo) == 0 for lo, _ in sel.report.intervals))


def _runs_file(sel: Selection, aug, slices):
    """The runs file (isplat.runsfile.runs_path) post reads instead of bricks or whole channels, or None:
    post-classified, indexed, not a slab (``--slabs`` and Dask's slab workers read bricks or the slab's
    channels for now), something to show, no labels, no density code 0 of interest (the voxels not read are
    zeros, which the bytes needed count from the density must never take for voxels of interest), no thick
    axis on the axes read (the cubic between slices reads beyond the quad's corners), and the file present
    beside the index (else bricks or whole channels, as without it)."""
    from .runsfile import runs_path
    from .splat.post import between_slices

    req = sel.request
    if not (sel.post and sel.method == "indexed" and slices is None and not sel.empty and sel.labels is None
            and req is not None and req.index is not None and req.mode == "composite"):
        return None         # (MIP reads whole-shape channels)
    if any(int(lo) == 0 for lo, _ in sel.report.intervals):
        return None
    if any(between_slices(sel.spacing_ijk, ax)[0] for ax in req.axes):
        return None
    path = runs_path(req.index)
    return path if path.exists() else None


def post_runs_bytes(request, aug, voxels_of_interest: int | None = None) -> int | None:
    """At most the bytes a one-pass post frame from the runs file holds while it loads (isplat.slabs counts it
    before the load), from the runs file's pointer tables: the runs the intervals meet, read (their voxels'
    channels, positions and brick rows) and placed (a pool row for each brick they hold voxels of, with the loaded
    bits and each axis' quad bits: their ``brick_number`` rows read to count them; the pool packed, its rows'
    places at most), and the brick table with the sampler's deltas, and the channels placed whole-shape beside
    them when they will be (:func:`whole_shape_fits`); None when the frame would not read the runs file
    (:func:`_runs_file`). ``voxels_of_interest``: the selection's count when the caller has it (isplat.slabs
    counts it from the same index), else counted here (:func:`_voxels_of_interest`)."""
    from .runsfile import open_runs
    from .stats import bytes_per_voxel

    if _shows_labels(request):
        return None
    sel = _empty_selection(request)
    path = _runs_file(sel, aug, None)
    if path is None:
        return None
    with open_runs(path) as rf:
        runs = rf.runs_for(sel.luts.intervals)
        nv, nb, npos = (int(np.diff(p)[runs].sum()) for p in rf.ptrs)
        rows = rf.bricks_of(sel.luts.intervals) + 1
    chan = bytes_per_voxel({"density", *sel.report.channels})
    bricks = int(np.prod([-(-int(n) // grid.POOL_EDGE) for n in sel.shape]))
    voxels = rows * grid.POOL_EDGE ** 3
    pool = nv * chan + npos + 6 * nb + voxels * chan + voxels // 8 * (1 + len(request.axes)) + 8 * rows + 12 * bricks
    if voxels_of_interest is None:
        voxels_of_interest = _voxels_of_interest(request, sel.luts.intervals)
    if not whole_shape_fits(sel.shape, chan, len(request.axes), voxels_of_interest):
        return pool
    # placed whole-shape beside the pool (_read_post_runs), with its loaded bits while the quads' are made
    return pool + flat_bytes(sel.shape, chan, len(request.axes)) + flat_bytes(sel.shape, 0, 1)


def _voxels_of_interest(request, intervals) -> int:
    """The voxels of interest a selection of ``request`` will count (its report's), from the index's counts per
    density (isplat.index.IndexStore.voxel_counts) of its first axis."""
    from .index import open_index

    counts = open_index(request.index).voxel_counts(sorted(request.axes)[0])
    return int(sum(int(counts[int(lo):int(hi) + 1].sum()) for lo, hi in intervals))


def _start_post_runs(sel: Selection, aug, path):
    """Post from the range runs (formats/runs.md): the runs meeting the intervals of non-zero opacity, of the
    channels the scene uses (the density always), read and checked against their hashes here, then placed on a
    thread of its own (:func:`_place_runs`) while the caller reads and selects the index: the runs depend on the
    transfer function's intervals only, and placing is compiled code that releases the GIL. The runs file is
    checked to be written from ``aug`` (shape, density hash, chunk hash check); any problem is one IsplatError
    naming the command that rebuilds it (isplat.runsfile.refusal), never a fall back to bricks. The future's
    result goes to :func:`_read_post_runs`."""
    from .chunkhash import CHECK_ATTR
    from .runsfile import VALUE_CHANNELS, open_runs, refusal

    rep = sel.report
    if "density" not in rep.channels:
        rep.channels.insert(0, "density")
    ivs = [tuple(map(int, iv)) for iv in sel.luts.intervals]
    with refusal(path, aug.path, sel.request.index), \
            open_runs(path, shape=sel.shape, density_sha256=aug.density_sha256,
                      augmented_chunk_hash_check=str(aug.attrs.get(CHECK_ATTR, ""))) as rf:
        got = rf.fetch(ivs, [ch for ch in VALUE_CHANNELS if ch in rep.channels])
    return _in_daemon_thread(_place_runs, got, sel.request, aug.path)


def _in_daemon_thread(fn, *args):
    """A Future of ``fn(*args)`` run on a daemon thread of its own: an interrupted load (Ctrl-C) exits at once, where
    a ThreadPoolExecutor's thread would be joined at exit, after its task (the placing: seconds at 1024^3)."""
    import threading
    from concurrent.futures import Future

    future = Future()

    def run():
        if future.set_running_or_notify_cancel():
            try:
                future.set_result(fn(*args))
            except BaseException as exc:            # (the caller's result() raises it)
                future.set_exception(exc)

    threading.Thread(target=run, name="isplat-runs", daemon=True).start()
    return future


def _place_runs(got, request, aug_path):
    """The runs ``got`` (isplat.runsfile.RunsFile.fetch) checked and placed into a pool (:class:`WholeChannels`
    with a brick table: a row of 8^3 places for each brick the runs read, the rows packed so that they share
    places, isplat.runsfile.RunsFile.place), and per axis read the bits of the quads whose four corners they
    hold, in the rows' layout (isplat.splat.post.held_pool), which the sampler tests (a quad with a corner not
    held is transparent in truth; its places may hold another row's voxels). Returns (whole, bits, fetched)."""
    from .runsfile import RunsFile, refusal
    from .splat.post import held_pool

    with refusal(got.path, aug_path, request.index):
        placed = RunsFile.place(got)
    bits = {ax: held_pool(placed.loaded, placed.table, got.shape, ax) for ax in sorted(request.axes)}
    out = dict(zip(("density", "normal", "gradient_magnitude"), placed.placed))
    whole = WholeChannels(out["density"], out.get("gradient_magnitude", _EMPTY_U8), out.get("normal", _EMPTY_U16),
                          table=placed.table, shape=got.shape, bases=placed.bases, loaded=placed.loaded)
    return whole, bits, got


def _read_post_runs(sel: Selection, pending) -> Selection:
    """The selection with the range runs' pool and quad bits (:func:`_place_runs`, ``pending`` its future), or
    the channels whole-shape when that is within FLAT_BYTES_PER_VOXEL (:func:`_unpooled`), and their reads in
    the report."""
    whole, bits, got = pending.result()
    rep = sel.report
    rep.runs_file_bytes, rep.runs_file_pages = got.bytes_read, got.pages_read
    rep.values_from = f"runs file ({int(got.runs.sum()):,} of {got.runs.size:,} runs)"
    rep.values_path = str(got.path)
    if _whole_shape_fits(sel, len(bits)):
        whole, bits = _unpooled(whole, sorted(bits))
        rep.values_from += ", held whole-shape"
    return replace(sel, whole=whole, held=bits)


# Post's pool (the runs file's, or a format 6 file's bricks) is placed whole-shape (flat [k, j, i], zeros where
# nothing was read) when that takes at most this many bytes per voxel of interest, issue 26's bound on what a
# selection holds: the sampler then finds a sample's four voxels with no brick table between (docs/design.md
# "Whole-shape channels when they fit issue 26's bound"; python -m benchmarks layout). A volume whose voxels of
# interest are few keeps the pool.
FLAT_BYTES_PER_VOXEL = 8


def flat_bytes(shape, per_voxel: int, n_axes: int) -> int:
    """Bytes of whole-shape channels of ``per_voxel`` bytes a voxel of a volume of ``shape``, and the bits of the
    quads held of ``n_axes`` axes (1 bit a voxel each)."""
    n = int(np.prod(shape, dtype=np.int64))
    return n * int(per_voxel) + n_axes * ((n + 7) // 8)


def whole_shape_fits(shape, per_voxel: int, n_axes: int, voxels_of_interest: int) -> bool:
    """The rule for placing a pool whole-shape: its channels of ``per_voxel`` bytes a voxel of a volume of
    ``shape`` (and ``n_axes`` axes' bits of the quads held) take at most FLAT_BYTES_PER_VOXEL a voxel of
    interest. The same rule before the load (:func:`post_runs_bytes`) and after it (:func:`_whole_shape_fits`).

    >>> whole_shape_fits((10, 10, 10), 1, 3, 172), whole_shape_fits((10, 10, 10), 1, 3, 171)   # 1,375 B
    (True, False)
    """
    return flat_bytes(shape, per_voxel, n_axes) <= FLAT_BYTES_PER_VOXEL * int(voxels_of_interest)


def _whole_shape_fits(sel: Selection, n_axes: int) -> bool:
    """:func:`whole_shape_fits` for ``sel``'s channels and the voxels of interest its report counts."""
    from .stats import bytes_per_voxel

    return whole_shape_fits(sel.shape, bytes_per_voxel({"density", *sel.report.channels}), n_axes,
                            sel.report.voxels_of_interest)


def _unpooled(whole: WholeChannels, axes=()) -> tuple[WholeChannels, dict]:
    """A pool's channels placed whole-shape (isplat.runsplace.unpool: a packed pool's places not loaded, and
    bricks not read, zeros), and per axis of ``axes`` the bits of the quads whose four corners they hold in that
    layout (isplat.splat.post.held_quads)."""
    from .runsplace import BRICK_VOXELS, unpool
    from .splat.post import held_quads

    rows = whole.density.size // BRICK_VOXELS
    bases = whole.bases if whole.bases.size else np.arange(rows, dtype=np.int64) * BRICK_VOXELS
    loaded = whole.loaded if whole.loaded.size else np.full(8 * rows, np.iinfo(np.uint64).max, np.uint64)
    outs, words = unpool(whole.table, bases, loaded, whole.shape, whole.arrays())
    return WholeChannels(*outs), {ax: held_quads(words, whole.shape, ax) for ax in axes}


def cell_origins(s: AxisSelection) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every cell's slice and first voxel ``(c, a0, b0)`` (int64, the hierarchy's order): the walk of
    :func:`isplat.splat.select.cell_origins`, which also checks the cell table."""
    from .splat.select import cell_origins_py as walk

    c, a0, b0, _ = walk(s.slice_ptr, s.region_id, s.region_ptr, s.block_pos, s.block_ptr, s.block_voxel,
                        s.cell_pos, s.cell_count, s.n_a)
    return c, a0, b0


def post_bricks(sel: Selection, bricks) -> np.ndarray:
    """bool[gk, gj, gi]: the bricks (of ``bricks`` voxels (k, j, i)) post's sampler may read for the selected
    cells of every axis: each cell's quads and their in-slice neighbours, the cubic's extra taps included
    (QUAD_REACH), in the cell's slice (isplat.splat.post reads no other slice)."""
    from .brickstore import mark_reach

    shape = sel.shape
    grid_n = tuple(-(-int(n) // int(b)) for n, b in zip(shape, bricks))
    out = np.zeros(grid_n, dtype=bool)
    flat = out.reshape(-1)
    strides = np.asarray(out.strides, dtype=np.int64)       # bool: bytes are elements
    back, ahead = QUAD_REACH
    for ax, s in sel.axes.items():
        c, a0, b0 = cell_origins(s)
        kc, ka, kb = {"k": (0, 2, 1), "j": (1, 2, 0), "i": (2, 1, 0)}[ax]   # (k, j, i) dims of c, a, b
        dims = [kc, ka, kb]
        n = np.asarray([shape[d] for d in dims], dtype=np.int64)
        bad = mark_reach(flat, c, a0, b0, n, back, ahead, np.asarray([bricks[d] for d in dims], dtype=np.int64),
                         strides[dims])
        if bad >= 0:
            where = sel.request.index if sel.request is not None else "index"
            raise IsplatError(f"{where}: axis {ax}: the index places a cell at slice {int(c[bad])}, ({int(a0[bad])}, "
                              f"{int(b0[bad])}), outside the volume's {n[0]} slices of {n[1]} x {n[2]}")
    return out


def _read_post_bricks(sel: Selection, aug, axes, slices) -> Selection:
    """Post from a bricked file: the channels holding just the bricks its quads read (:func:`post_bricks`), the
    rest zeros (never read by the sampler); whole channels when more than BRICK_SHARE of the bricks (of the
    slab's slices, for a slab) are needed. A slab (``slices``): its slices' channels only, as
    :func:`_slab_channels`."""
    rep = sel.report
    if "density" not in rep.channels:
        rep.channels.insert(0, "density")
    need = post_bricks(sel, aug.bricks)
    slab = None
    if slices is not None and len(axes) == 1:
        s = np.asarray(list(slices), dtype=np.int64)
        ax = next(iter(axes))
        c0, c1 = (int(s.min()), int(s.max()) + 1) if s.size else (0, 0)
        if c0 < 0 or c1 > grid.slice_shape(sel.shape, ax)[0]:
            raise IsplatError(f"{aug.path}: slices {c0}..{c1 - 1} of axis {ax}: out of the volume")
        slab = (ax, c0, c1)
    lo, hi = [0, 0, 0], list(sel.shape)
    if slab is not None:
        d = 2 - grid.AXES.index(slab[0])
        lo[d], hi[d] = slab[1], slab[2]
    b = aug.bricks
    box = tuple(slice(l // e, -(-h // e)) for l, h, e in zip(lo, hi, b))
    within = np.zeros_like(need)
    within[box] = True
    need &= within
    share = need.sum() / max(1, within.sum())
    if share > BRICK_SHARE:
        if slab is None:
            whole = _whole(sel, aug.read)
            rep.values_from = "whole channels"
        else:
            whole, slab = _slab_channels(sel, aug, slab[0], range(slab[1], slab[2]))
            rep.values_from = "slab's channels"
        return replace(sel, whole=whole, slab=slab)
    bricks = np.argwhere(need)
    composite = sel.request is None or sel.request.mode == "composite"     # (MIP reads whole-shape channels)
    if composite and getattr(aug, "store", None) is not None and tuple(b) == (grid.POOL_EDGE,) * 3:
        whole = _pool(sel, aug, bricks, need.shape)        # (a slab's bricks: its own)
        if slab is None and _whole_shape_fits(sel, 0):
            whole = _unpooled(whole)[0]
            rep.values_from += ", held whole-shape"
        return replace(sel, whole=whole, slab=slab)
    out = {ch: aug.read_bricks(ch, bricks, (tuple(lo), tuple(hi))).reshape(-1) for ch in rep.channels}
    rep.values_from = f"bricks ({len(bricks):,} of {int(np.prod(need.shape)):,})"
    box = tuple(h - l for l, h in zip(lo, hi))
    per = {n: pages_filled(bricks, b, lo, box, n) for n in {a.itemsize for a in out.values()}}
    held = sum(per[a.itemsize] for a in out.values())
    whole = WholeChannels(out["density"], out.get("gradient_magnitude", _EMPTY_U8), out.get("normal", _EMPTY_U16),
                          held)
    return replace(sel, whole=whole, slab=slab)


def _pool(sel: Selection, aug, bricks: np.ndarray, grid_shape) -> WholeChannels:
    """Post's bricks of a format 6 file held as a pool (:class:`WholeChannels`): the bricks read, one row each,
    behind a brick table; what is held is what was read (issue 26 item 4), placed by whole bricks."""
    rep = sel.report
    out = {ch: aug.read_pool(ch, bricks) for ch in rep.channels}
    if bricks.shape[0] >= np.iinfo(np.uint32).max:              # (a uint32 row each)
        raise IsplatError(f"{aug.path}: {bricks.shape[0]:,} bricks do not fit a pool's table")
    table = np.zeros(grid_shape, dtype=np.uint32)
    table[tuple(bricks.T)] = np.arange(1, bricks.shape[0] + 1, dtype=np.uint32)
    rep.values_from = f"bricks ({len(bricks):,} of {table.size:,})"
    return WholeChannels(out["density"], out.get("gradient_magnitude", _EMPTY_U8), out.get("normal", _EMPTY_U16),
                         table=table.reshape(-1), shape=tuple(sel.shape))


PAGE_SHIFT = PAGE.bit_length() - 1      # the pages held, as isplat.fileio counts the pages read


def pages_filled(bricks: np.ndarray, size, lo, shape, itemsize: int) -> int:
    """Bytes of the memory pages that bricks (grid indices, bricks of ``size`` (k, j, i)) written into a zeroed
    C-order array of ``shape`` holding the block from element ``lo`` touch: what the operating system holds of
    an ``np.zeros`` array once they are written (pages never written are not allocated)."""
    from .brickstore import pages_touched

    i64 = lambda x: np.asarray(x, dtype=np.int64)      # noqa: E731
    return pages_touched(i64(bricks).reshape(-1, 3), i64(size), i64(lo), i64(shape), itemsize, PAGE_SHIFT) * PAGE


def _slab_box(aug, axes, slices) -> tuple:
    """The element bounds ``(lo, hi)`` (k, j, i) of a slab's slices of its one axis, checked against the volume."""
    s = np.asarray(list(slices), dtype=np.int64)
    axis, = axes
    d = 2 - grid.AXES.index(axis)
    c0, c1 = (int(s.min()), int(s.max()) + 1) if s.size else (0, 0)
    if c0 < 0 or c1 > aug.shape[d]:
        raise IsplatError(f"{aug.path}: slices {c0}..{c1 - 1} of axis {axis}: the axis has {aug.shape[d]}")
    lo, hi = [0, 0, 0], list(aug.shape)
    lo[d], hi[d] = c0, c1
    return tuple(lo), tuple(hi)


def _slab_reader(aug, axes, slices):
    """``read(channel, k0, k1)`` for gathering a slab's values: ``aug.read``, or for a slab of j-slices (rows of
    every k-plane) the k-planes with only the slab's rows read and the others zero (never gathered), so HDF5
    reads only the chunks that hold those rows (the channels are chunked by rows of whole i-lines)."""
    s = np.asarray(list(slices), dtype=np.int64)
    if "".join(sorted(axes)) != "j" or s.size == 0:
        return aug.read
    j0, j1 = int(s.min()), int(s.max()) + 1
    if j0 < 0 or j1 > aug.shape[1] or j1 - j0 == aug.shape[1]:
        return aug.read
    from .augfile import CHANNELS

    def read(ch, k0, k1):
        out = np.zeros((k1 - k0,) + tuple(aug.shape[1:]), dtype=CHANNELS[ch])
        out[:, j0:j1] = aug.read_block(ch, (slice(k0, k1), slice(j0, j1)))    # chunks checked, bytes counted
        return out
    return read


def _needed(sel: Selection, count_full: bool = True) -> None:
    """The report's bytes needed (docs/stats.md, :attr:`LoadReport.bytes_needed`): its channels' bytes per voxel,
    the index blocks and table rows of the intervals (and the 257-row table of ``/values``), and for post the
    quads' footprint, counted lazily from the density the selection holds. Full method: the voxels of interest
    counted from the whole density (which, without an index, is read too)."""
    rep = sel.report
    rep.technique = sel.request.classification if sel.request is not None else ("post" if sel.post else "pre")
    rep.channel_bytes_per_voxel = sum(2 if ch == "normal" else 1 for ch in rep.channels)
    has_density = sel.whole is not None and sel.whole.density.size > 0
    if sel.method == "full" and has_density and count_full:
        hist = np.bincount(sel.whole.density, minlength=256)
        rep.voxels_of_interest = int(sum(int(hist[lo:hi + 1].sum()) for lo, hi in rep.intervals))
    tables = 257 * 8 if rep.values_from in ("index", "values file") else 0
    rep.index_bytes_needed = 0 if sel.method == "full" else rep.index_block_bytes + tables
    rep._needed = rep.footprint = None
    if sel.post and has_density and sel.labels is None and rep.intervals:
        rep.footprint = _footprint(sel)


def _footprint(sel: Selection):
    """``() -> (axis, voxels)``: the voxels post's quads read (isplat.stats.quad_footprint_per_slice) on the
    report's axis where they are most, of the slices the selection holds."""
    density, intervals, axes = sel.whole.density, list(sel.report.intervals), list(sel.report.axes) or ["k"]
    shape = sel.shape if sel.slab is None else _slab_shape(sel.shape, sel.slab[0], sel.slab[2] - sel.slab[1])
    if sel.slab is not None:
        axes = [sel.slab[0]]

    def count():
        from .stats import quad_footprint_per_slice

        w = sel.whole          # a pool read a few planes at a time (a slab's pool spans the volume's grid:
        if w.pooled:           # its slices alone)
            box = [(0, int(n)) for n in sel.shape]
            if sel.slab is not None:
                box[2 - grid.AXES.index(sel.slab[0])] = sel.slab[1:]
            vol = _PoolVolume(density, w.table, sel.shape, box, w._packing)
        else:
            vol = density.reshape(shape)
        per = {ax: int(quad_footprint_per_slice(vol, intervals, ax).sum()) for ax in axes}
        ax = max(per, key=per.get)
        return ax, per[ax]
    return count


_SAID_NO_VALUES: set = set()       # indexes whose missing values file was said (once per process)


def _values_source(idx, aug, slices) -> str:
    """Where pre-classification reads the channel values of the voxels of interest: ``"index"`` (``/values`` of
    a version-4 index), ``"values file"`` (beside a version-6 index; checked to be copied from ``aug``'s
    channels), else ``"augmented slabs"`` (a slab, or no values file: said in one log line with the command that
    writes it)."""
    if slices is not None:
        return "augmented slabs"
    source = idx.values_source
    if source == "none":
        if idx.version >= 6 and idx.channel == "density" and str(idx.path) not in _SAID_NO_VALUES:
            from .index.store import values_path

            _SAID_NO_VALUES.add(str(idx.path))
            log.info(f"isplat: {idx.path} has no values file ({values_path(idx.path).name}): pre-classification "
                     f"gathers the channel values from {aug.path} "
                     f"{'(the bricks that hold them)' if aug.bricked else 'in k-slabs'}; "
                     f"isplat index {aug.path} -o {idx.path} "
                     f"--force writes it")
        return "augmented slabs"
    _check_values_match(idx.values_meta, idx.path if source == "index" else idx.values_file.path, aug,
                        idx.path)
    return source


def _check_values_match(v, where, aug, index) -> None:
    """The values were copied from ``aug``'s channels: the same ``spacing_ijk`` and gradient magnitude scale."""
    if v is not None and (v.spacing_ijk != tuple(aug.spacing_ijk)
                          or v.gradient_magnitude_scale != aug.gradient_magnitude_scale):
        raise IsplatError(f"{where}: its channel values were copied from an augmented file with "
                          f"spacing_ijk {v.spacing_ijk} and gradient_magnitude_scale {v.gradient_magnitude_scale}, "
                          f"{aug.path.name} has {tuple(aug.spacing_ijk)} and {aug.gradient_magnitude_scale}; "
                          f"rebuild it: isplat index {aug.path} -o {index} --force")


def _open_matching_index(request, aug, idx=None):
    """The request's index (``idx``, if already open), checked to be made from ``aug``'s volume."""
    from .index import open_index

    if request.index is None:
        raise IsplatError("scene: data.index is required for render.method = 'indexed'")
    idx = idx or open_index(request.index, keep_open=True)      # its first session (the load) uses the opening
    index = request.index
    if getattr(idx, "channel", "density") != "density":
        raise IsplatError(f"{index}: an index of the {idx.channel}, not of the density; data.index names the "
                          f"density's index (NAME.idx.h5)")
    if tuple(idx.shape) != tuple(aug.shape) or idx.density_sha256 != aug.density_sha256:
        raise IsplatError(f"{index}: index was built from another volume "
                          f"(density_sha256 {idx.density_sha256[:12]}..., {aug.path.name} has "
                          f"{aug.density_sha256[:12]}...); rebuild it with isplat index")
    _check_values_match(idx.values, index, aug, index)      # /values inside (version 4)
    return idx
