"""The render request: every input a selection depends on, frozen, built once per run; the one cache key.

A :class:`RenderRequest` names the data (its files' identity: resolved path, size and modification time; or,
for arrays in memory, an identity the caller gives, e.g. a hash of their bytes) and the scene's settings that
a :class:`~isplat.selection.Selection` is made from: the transfer function (in density codes, with the units,
preset and window it was written in, and its unit distance), shading on or off (normals read or not) and the
gradient modulation the transfer function asks for, method, technique (``render.classification``), spacing,
the index axes of the views, the slab of slices and ``render.mode`` (a composite scene's post holds its bricks as a
pool, an intensity projection whole-shape channels). What changes only a frame (camera, image size and
background, lights, cuts, threads, early termination, precision, footprint, sheets, supersampling) is not in
it, so frames that differ only in those reuse a selection. :class:`isplat.renderer.Renderer`,
:func:`isplat.render` and the Dask workers (:mod:`isplat.distributed`) key their selections by it: a frozen
dataclass, compared by value, hashable and picklable.

>>> from isplat.scene import parse_scene
>>> def req(*keys):
...     scene = parse_scene("[transfer]\\nopacity = [[100, 0], [200, 0.8]]", ".", "s", keys, data_required=False)
...     return RenderRequest.from_arrays(scene, ("arrays", "v1"), (8, 8, 8), (1.0, 1.0, 1.0), 1.0, "k")
>>> req() == req("camera.azimuth=40", "image.width=64")       # a frame's settings: the same selection
True
>>> req() == req("transfer.unit_distance=4.0"), req() == req('render.classification="pre"')
(False, False)
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

from .errors import IsplatError


def file_identity(path) -> tuple:
    """What identifies a file across machines sharing storage: resolved path, size, modification time (ns)."""
    p = Path(path)
    try:
        st = p.stat()
    except OSError as exc:
        raise IsplatError(f"{path}: cannot read ({exc.strerror})") from None
    return str(p.resolve()), int(st.st_size), int(st.st_mtime_ns)


def _identity_or_path(path) -> tuple | None:
    """:func:`file_identity`, or for a file that cannot be stat'ed its path alone (opening it names the
    problem)."""
    if path is None:
        return None
    try:
        return file_identity(path)
    except IsplatError:
        return (str(path), None, None)


@dataclass(frozen=True)
class RenderRequest:
    """Every input a selection depends on (module docstring); ``slab`` (axis-free runs ``((s0, s1), ...)`` of
    the slices kept) only for a selection of a slab of slices (:mod:`isplat.slabs`)."""

    source: tuple                    # the data's identity: ("files", augmented identity, index identity or None)
                                     # or ("arrays", the caller's identity of the arrays)
    augmented: Path | None           # where the files are (None: arrays in memory)
    index: Path | None               # (None for the full method, which reads no index)
    shape: tuple[int, int, int]      # (n_k, n_j, n_i), of the data (the files' or the arrays')
    spacing_ijk: tuple[float, float, float]   # the scene's volume.spacing, else the data's
    gradient_magnitude_scale: float  # of the data
    transfer: object                 # scene.Transfer: codes, unit distance, and the units they were written in
    shading: bool                    # shading.enabled: normals are read
    method: str                      # "indexed" or "full"
    classification: str              # "pre" or "post"
    axes: str                        # the index axes of the views, in i, j, k order
    slab: tuple | None = None        # runs of slices of the one axis, or None: every slice
    labels: tuple = ()               # the segmentation labels shown (scene_schema.LabelStyle), () for none
    mode: str = "composite"          # render.mode: post's bricks are held as a pool for "composite" only (an
                                     # intensity projection reads whole-shape channels, isplat.splat.mip)

    @property
    def unit_distance(self) -> float:
        return float(self.transfer.unit_distance)

    @property
    def gradient(self) -> bool:
        """The transfer function modulates opacity by gradient magnitude (that channel is read)."""
        return len(self.transfer.gradient_opacity) > 0

    @property
    def post(self) -> bool:
        return self.classification == "post"

    @property
    def slices(self):
        """The slab's slice numbers (int64), or None."""
        if self.slab is None:
            return None
        import numpy as np

        return np.concatenate([np.arange(a, b, dtype=np.int64) for a, b in self.slab] or [np.zeros(0, np.int64)])

    @classmethod
    def from_files(cls, scene, aug, axes: str, method: str | None = None, slices=None) -> "RenderRequest":
        """The request of ``scene``'s files (``aug``: its augmented file, open) for views along ``axes``;
        ``slices``: a slab's slices of the one axis of ``axes``."""
        method = _method(method or scene.render.method)
        index = scene.data.index if method == "indexed" else None
        source = ("files", _identity_or_path(aug.path), _identity_or_path(index))
        return cls._make(scene, source, Path(aug.path), index, aug.shape, scene.volume.spacing or aug.spacing_ijk,
                         aug.gradient_magnitude_scale, axes, method, slices)

    @classmethod
    def from_arrays(cls, scene, identity, shape, spacing_ijk, gradient_magnitude_scale, axes: str,
                    method: str | None = None) -> "RenderRequest":
        """The request of arrays in memory (``identity``: what identifies their values, or None: no cache may
        reuse a selection by this request's source)."""
        return cls._make(scene, ("arrays", identity), None, None, shape, spacing_ijk, gradient_magnitude_scale,
                         axes, _method(method or scene.render.method), None)

    @classmethod
    def _make(cls, scene, source, augmented, index, shape, spacing, gscale, axes, method, slices):
        slab = None
        if slices is not None:
            from .index.build import slice_runs

            slab = tuple((int(a), int(b)) for a, b in slice_runs(slices, 1 << 62))
        return cls(source, augmented, None if index is None else Path(index), tuple(int(x) for x in shape),
                   tuple(float(x) for x in spacing), float(gscale), scene.transfer,
                   bool(scene.shading.enabled) and scene.render.mode == "composite",
                   method, scene.render.classification, "".join(sorted(axes)), slab,
                   tuple(getattr(getattr(scene, "labels", None), "shown", ())), scene.render.mode)


def _method(method: str) -> str:
    if method not in ("indexed", "full"):
        raise IsplatError(f"render.method = {method!r}: expected 'indexed' or 'full'")
    return method


class SelectionCache:
    """The last ``size`` selections by request, each with the band learning of its frames
    (:class:`isplat.frame.BandLearning`): what :func:`isplat.render` and a Dask worker keep between calls.
    ``get`` is safe from several threads (a selection is made once per request)."""

    def __init__(self, size: int = 4):
        self.size = size
        self._items: OrderedDict = OrderedDict()
        self._lock = threading.Lock()

    def get(self, request: RenderRequest, make):
        """``(selection, band learning)`` of ``request``: kept, or ``make()`` (the selection) now."""
        from .frame import BandLearning

        with self._lock:
            if request in self._items:
                self._items.move_to_end(request)
                return self._items[request]
            value = (make(), BandLearning())
            self._items[request] = value
            while len(self._items) > self.size:
                self._items.popitem(last=False)
            return value

    def peek(self, request: RenderRequest):
        """The kept ``(selection, band learning)`` of ``request``, or None."""
        with self._lock:
            return self._items.get(request)

    def items(self) -> list:
        """``[(request, (selection, band learning)), ...]``, oldest first."""
        with self._lock:
            return list(self._items.items())

    def clear(self) -> None:
        with self._lock:
            self._items.clear()

    def __len__(self) -> int:
        return len(self._items)
