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

from dataclasses import dataclass, field

import numpy as np

from . import grid
from .errors import IsplatError
from .splat.kernels import IndexedVoxels, WholeVolume
from .transfer import TransferLUTs, build_luts

_EMPTY_U8 = np.zeros(0, dtype=np.uint8)
_EMPTY_U16 = np.zeros(0, dtype=np.uint16)
GATHER_SLAB = 8      # k-slices read at a time when gathering channel values
MAX_IN_SLICE = 65535  # in-slice coordinates are uint16


@dataclass
class LoadReport:
    augmented_bytes: int = 0          # bytes read from the augmented file's channels
    index_bytes: int = 0              # bytes read from the index file
    index_decoded_bytes: int = 0      # the decoded blocks (LoadedAxis arrays), before selection
    channels: list = field(default_factory=list)
    axes: list = field(default_factory=list)
    intervals: list = field(default_factory=list)


@dataclass(frozen=True)
class AxisSelection:
    """The selected voxels of one index axis, in traversal order (see :func:`select_voxels`), and their
    gathered channel values (empty arrays for channels the scene does not use)."""

    axis: str
    n_slices: int
    n_a: int
    n_b: int
    cell_ptr: np.ndarray            # int64[n_slices + 1]
    cell_start: np.ndarray          # int64[Q + 1]
    cell_id: np.ndarray             # int32[Q]
    a: np.ndarray                   # uint16[N]
    b: np.ndarray                   # uint16[N]
    density: np.ndarray             # uint8[N]
    gradient_magnitude: np.ndarray  # uint8[N] or empty
    normal: np.ndarray              # uint16[N] or empty

    @property
    def n_voxels(self) -> int:
        return int(self.a.shape[0])

    def voxels(self) -> IndexedVoxels:
        """The arrays as the frame kernel takes them."""
        return IndexedVoxels(self.cell_ptr, self.cell_start, self.cell_id, self.a, self.b, self.density,
                             self.gradient_magnitude, self.normal, self.n_a, self.n_b)

    def arrays(self) -> list[np.ndarray]:
        return [self.cell_ptr, self.cell_start, self.cell_id, self.a, self.b, self.density,
                self.gradient_magnitude, self.normal]


@dataclass(frozen=True)
class WholeChannels:
    """The full method's data: whole channels, flat ``[k, j, i]`` (empty when unused)."""

    density: np.ndarray
    gradient_magnitude: np.ndarray
    normal: np.ndarray

    def arrays(self) -> list[np.ndarray]:
        return [self.density, self.gradient_magnitude, self.normal]


@dataclass
class Selection:
    """What the frames of one transfer function need (module docstring). ``axes`` for the indexed method,
    ``whole`` for the full one."""

    method: str
    shape: tuple[int, int, int]            # (n_k, n_j, n_i)
    spacing_ijk: tuple[float, float, float]
    luts: TransferLUTs
    unit_distance: float                   # 0: the renderer's default (the smallest spacing)
    use_shade: bool
    use_gm: bool
    axes: dict[str, AxisSelection] = field(default_factory=dict)
    whole: WholeChannels | None = None
    report: LoadReport = field(default_factory=LoadReport)

    @property
    def empty(self) -> bool:
        """True when the transfer function makes every density transparent."""
        return len(self.luts.intervals) == 0

    def voxels(self, axis: str):
        """The kernel's view of the voxels of ``axis``: IndexedVoxels or WholeVolume."""
        if self.method == "full":
            _, n_a, n_b = grid.slice_shape(self.shape, axis)
            w = self.whole
            return WholeVolume(w.density, w.gradient_magnitude, w.normal, grid.flat_strides(self.shape, axis), n_a, n_b)
        if axis not in self.axes:
            raise IsplatError(f"axis {axis} was not selected (selected: {sorted(self.axes) or 'none'}); "
                              "select the axes of every view to be rendered")
        return self.axes[axis].voxels()

    def held_bytes(self) -> int:
        """Bytes of volume data held for the frames (selection and gathered values, or whole channels)."""
        arrays = self.whole.arrays() if self.whole is not None else []
        arrays += [a for s in self.axes.values() for a in s.arrays()]
        return int(sum(a.nbytes for a in arrays))

    @classmethod
    def from_arrays(cls, density, scene, normal=None, gradient_magnitude=None, gradient_magnitude_scale=None,
                    spacing=None, window=None, axes: str = "ijk", method: str | None = None) -> "Selection":
        """Select from a volume in memory for ``scene``'s transfer function, shading and method.

        ``density``: the augmented density codes (uint8 ``[k, j, i]``) with, where the scene needs them,
        ``normal`` (uint16 oct16 codes) and ``gradient_magnitude`` (uint8 codes, with their
        ``gradient_magnitude_scale``); or any scalar volume, which is augmented first
        (:func:`isplat.augment.augment_array`, with ``window``). ``axes``: the index axes to select (the
        principal axes of the views to be rendered). The index is built in memory.
        """
        from .memory import channels_in_memory

        chans, gscale, sp = channels_in_memory(density, scene, normal, gradient_magnitude,
                                               gradient_magnitude_scale, spacing, window)
        sel = _empty_selection(method or scene.render.method, chans["density"].shape, sp, scene, gscale)
        read = lambda ch, k0, k1: chans[ch][k0:k1]      # noqa: E731
        if sel.method == "full":
            sel.whole = _whole(sel, read)
        elif not sel.empty:
            from .index.memory import load_axis_in_memory

            loaded = {ax: load_axis_in_memory(chans["density"], ax, sel.luts.intervals) for ax in grid.AXES
                      if ax in axes}
            _select(sel, loaded, read, "array")
        return sel


def _empty_selection(method, shape, spacing_ijk, scene, gradient_magnitude_scale) -> Selection:
    if method not in ("indexed", "full"):
        raise IsplatError(f"render.method = {method!r}: expected 'indexed' or 'full'")
    luts = build_luts(scene.transfer, gradient_magnitude_scale)
    empty = len(luts.intervals) == 0
    sel = Selection(method, tuple(int(x) for x in shape), tuple(float(x) for x in spacing_ijk), luts,
                    float(scene.transfer.unit_distance), bool(scene.shading.enabled) and not empty,
                    luts.gradient is not None and not empty)
    sel.report.intervals = luts.intervals.tolist()
    sel.report.channels = (["normal"] if sel.use_shade else []) + (["gradient_magnitude"] if sel.use_gm else [])
    return sel


def _whole(sel: Selection, read) -> WholeChannels:
    """The full method's channels: every voxel is visited, so whole channels, indexed by flat position."""
    if sel.empty:
        return WholeChannels(_EMPTY_U8, _EMPTY_U8, _EMPTY_U16)
    sel.report.channels.insert(0, "density")
    n = int(np.prod(sel.shape))
    whole = {ch: read(ch, 0, sel.shape[0]).reshape(n) for ch in sel.report.channels}
    return WholeChannels(whole["density"], whole.get("gradient_magnitude", _EMPTY_U8), whole.get("normal", _EMPTY_U16))


def _select(sel: Selection, loaded: dict, read, source: str) -> None:
    """Select the voxels of every loaded axis (``{axis: LoadedAxis}``) and gather their channel values."""
    from .splat.select import select_voxels

    ivs = sel.luts.intervals.astype(np.int64)
    picked = {}
    for ax, la in loaded.items():
        if max(la.n_a, la.n_b) > MAX_IN_SLICE:
            raise IsplatError(f"{source}: axis {ax} slices are {la.n_a}x{la.n_b}; the renderer takes at most "
                              f"{MAX_IN_SLICE} voxels per in-slice axis")
        try:
            picked[ax] = select_voxels(la.slice_block_ptr, la.block_density, la.block_voxel_ptr, la.positions,
                                       ivs, la.n_a, la.n_b)
        except ValueError as exc:
            raise IsplatError(f"{source}: axis {ax}: {exc}") from None
    gathered = gather_channels(read, loaded, sel.report.channels, sel.shape)
    for ax, (cell_ptr, cell_start, cell_id, a, b, d, src) in picked.items():
        g = gathered[ax]            # in the order of the decoded positions; the selection's order is ``src``
        gm = g["gradient_magnitude"][src] if "gradient_magnitude" in g else _EMPTY_U8
        nrm = g["normal"][src] if "normal" in g else _EMPTY_U16
        la = loaded[ax]
        sel.axes[ax] = AxisSelection(ax, la.n_slices, la.n_a, la.n_b, cell_ptr, cell_start, cell_id, a, b, d, gm, nrm)
    # the decoded blocks have served: frames need only the selection and the gathered values
    sel.report.index_decoded_bytes = int(sum(
        la.slice_block_ptr.nbytes + la.block_density.nbytes + la.block_voxel_ptr.nbytes + la.positions.nbytes
        for la in loaded.values()))


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
        start = 0
        for ax, fi in fis.items():
            out[ax][ch] = vals[start:start + fi.shape[0]]
            start += fi.shape[0]
    return out


def select_from_files(scene, axes: str, method: str | None = None, aug=None, slices=None) -> Selection:
    """Read what ``scene`` needs for frames along ``axes`` from its files: only the index blocks of the
    transfer function's intervals (indexed method) and the channels the scene uses (module docstring).
    ``aug``: the scene's augmented file, if already open. ``slices``: keep only these slices of the axes
    (a slab, :func:`isplat.slabs.restrict_loaded`), gathering channel values for their voxels alone."""
    from .augfile import open_augmented

    aug = aug or open_augmented(scene.data.augmented)
    sp = scene.volume.spacing or aug.spacing_ijk
    sel = _empty_selection(method or scene.render.method, aug.shape, sp, scene, aug.gradient_magnitude_scale)
    sel.report.axes = sorted(axes)
    if sel.method == "full":
        sel.whole = _whole(sel, aug.read)
    else:
        idx = _open_matching_index(scene, aug)
        if not sel.empty:
            ivs = [tuple(map(int, iv)) for iv in sel.luts.intervals]
            loaded = {ax: idx.load_axis(ax, ivs) for ax in sorted(axes)}
            if slices is not None:
                from .slabs import restrict_loaded
                loaded = {ax: restrict_loaded(la, slices) for ax, la in loaded.items()}
            _select(sel, loaded, aug.read, str(scene.data.index))
        sel.report.index_bytes = int(idx.bytes_read)
    sel.report.augmented_bytes = int(aug.bytes_read)
    return sel


def _open_matching_index(scene, aug):
    from .index import open_index

    if scene.data.index is None:
        raise IsplatError("scene: data.index is required for render.method = 'indexed'")
    idx = open_index(scene.data.index)
    if tuple(idx.shape) != tuple(aug.shape) or idx.density_sha256 != aug.density_sha256:
        raise IsplatError(f"{scene.data.index}: index was built from another volume "
                          f"(density_sha256 {idx.density_sha256[:12]}..., {aug.path.name} has "
                          f"{aug.density_sha256[:12]}...); rebuild it with isplat index")
    return idx
