"""Render a scene's views from its files: the selection once, then each frame (paper §2.2, §3).

>>> import numpy as np, tempfile, pathlib
>>> from isplat.augfile import write_augmented
>>> from isplat.index import build_index_file
>>> from isplat.scene import parse_scene
>>> tmp = pathlib.Path(tempfile.mkdtemp())
>>> vol = np.zeros((8, 8, 8), np.uint8); vol[2:6, 2:6, 2:6] = 200
>>> write_augmented(tmp / "v.aug.h5", vol, np.zeros_like(vol), np.full(vol.shape, 0x8080, np.uint16),
...                 (1.0, 1.0, 1.0), (0.0, 255.0), 1.0)
>>> _ = build_index_file(tmp / "v.aug.h5", tmp / "v.idx.h5")
>>> scene = parse_scene('[data]\\naugmented = "v.aug.h5"\\nindex = "v.idx.h5"\\n'
...                     '[transfer]\\nopacity = [[100, 0], [200, 0.8]]', tmp, "scene.toml")
>>> r = Renderer(scene)
>>> rgba, stats = r.render_view(0)          # float (H, W, 4), straight alpha over the background
>>> rgba.shape, stats.samples, r.report.axes
((256, 256, 4), 18256, ['j'])

What a scene needs, and nothing more, is read: the index axes its views use, only the blocks in the transfer
function's non-zero-opacity intervals, the ``normal`` channel only when shading is on, the
``gradient_magnitude`` channel only when the transfer function modulates opacity by it, and the ``density``
channel only for the ``full`` method (the index already carries densities). See :mod:`isplat.selection` for
the selection and :mod:`isplat.frame` for a frame.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

from .errors import IsplatError
from .frame import BandLearning, FrameStats, axes_of, render_frame, views_for  # noqa: F401  (FrameStats: public)
from .request import RenderRequest
from .selection import LoadReport, select, select_arrays, select_from_files  # noqa: F401

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class InMemory:
    """A volume in memory as a :class:`Renderer` takes it: augmented ``channels`` (``{name: array [k, j, i]}``,
    density codes and the channels the scenes use), its spacing (i, j, k), gradient magnitude scale,
    ``identity``: what identifies the values (the request's source; a cache reuses selections by it), and
    ``axes_lps``: its orientation in the patient (rows i, j, k in LPS), None when unknown."""

    channels: dict
    spacing_ijk: tuple
    gradient_magnitude_scale: float
    identity: object = None
    axes_lps: object = None

    @property
    def shape(self) -> tuple:
        return tuple(int(x) for x in self.channels["density"].shape)


class Renderer:
    """A scene's views and the one driver of their frames: in this process from one selection
    (``select`` once, ``render_frame`` per view), front to back in slabs one slab's selection at a time
    (``slabs`` > 1 without a ``scheduler``; by default as many as a selection too large for the memory left
    needs, :func:`isplat.slabs.slabs_needed`), or on Dask (``scheduler``: ``local:N``, ``tcp://HOST:PORT``, or a
    ``distributed.Client``).

    ``views``: cameras (default the scene's); ``method``: instead of ``render.method``; ``arrays``: an
    :class:`InMemory` volume instead of the scene's files (this process only); ``cache``: a
    :class:`~isplat.request.SelectionCache` that keeps selections (and their frames' band learning) across
    renderers by :attr:`request`. The augmented file is opened once, here."""

    def __init__(self, scene, views=None, method: str | None = None, *, slabs: int | None = None,
                 scheduler=None, arrays: InMemory | None = None, cache=None, opened: dict | None = None):
        from .augfile import open_augmented

        if arrays is not None and (scheduler is not None or (slabs or 1) > 1):
            raise IsplatError("a volume in memory renders in this process, in one slab")
        self.scene, self.scheduler = scene, scheduler
        if scene.render.sheets == "image":
            log.warning('isplat: warning: render.sheets = "image" splats pre-classified (the paper\'s splatting, '
                        'render.classification = "pre"), at about 5-10x the time of the default axis sheets '
                        '(docs/sheets.md)')
        # ``opened``: files the run has open already (the scene's window read from the augmented file)
        self.data = arrays if arrays is not None else \
            (opened or {}).get(scene.data.augmented) or open_augmented(scene.data.augmented)
        self.views = views_for(scene, self.data, views)
        axes = axes_of(self.views)
        if arrays is not None:
            self.request = RenderRequest.from_arrays(scene, arrays.identity, arrays.shape, scene.volume.spacing or
                                                     arrays.spacing_ijk, arrays.gradient_magnitude_scale, axes, method)
        else:
            self.request = RenderRequest.from_files(scene, self.data, axes, method)
        self.method = self.request.method
        self.slabs = slabs or (1 if scheduler is not None or arrays is not None else self._auto_slabs())
        if scene.render.mode != "composite" and self.slabs > 1:
            raise IsplatError(f'render.mode = "{scene.render.mode}" renders each frame in one pass: slabs (--slabs '
                              f'{self.slabs}{"" if slabs else ", chosen for the memory left"}) do not apply (an '
                              'extreme is not composited front to back); leave --slabs out or free memory')
        self.selection, self.bands, self._report = None, BandLearning(), None
        if scheduler is None and self.slabs == 1:
            make = (lambda: select_arrays(self.request, arrays.channels)) if arrays is not None else \
                (lambda: select(self.request, self.data))
            self.selection, self.bands = (make(), self.bands) if cache is None else cache.get(self.request, make)
            self._report = self.selection.report

    def _auto_slabs(self) -> int:
        """The slabs a frame needs to fit in the memory left (:func:`isplat.slabs.slabs_needed`); 1 when it fits."""
        from .slabs import PEAK_PER_VOXEL, fits_anyway, memory_room, slabs_needed

        room = memory_room()
        if room is None or self.method != "indexed" or fits_anyway(self.scene, self.data, room):
            return 1                # (the index is then opened once, by the selection)
        k, voxels = slabs_needed(self.scene, self.views, self.data, room, self.request)
        if k > 1:
            log.info(f"isplat render: the selection ({voxels:,} voxels of interest, about "
                     f"{voxels * PEAK_PER_VOXEL / 2**30:.2f} GiB while it is made) does not fit the "
                     f"{room / 2**30:.2f} GiB of memory left: each frame in {k} slabs front to back (--slabs {k})")
        return k

    @property
    def mode(self) -> str:
        """How frames run: "local", "streamed" (slabs here) or "dask"."""
        return "dask" if self.scheduler is not None else "streamed" if self.slabs > 1 else "local"

    @property
    def report(self) -> LoadReport | None:
        """What was read: bytes of channels and of the index, channels, axes, intervals (streamed or on Dask: the
        last frame's, None before the first)."""
        return self._report

    @property
    def frames(self):
        """The resolved camera frame of each view."""
        return [v.frame for v in self.views]

    @property
    def geom(self):
        return self.views[0].geom

    @property
    def threads(self) -> int:
        """Threads a frame uses (``render.threads``, 0: every core this process may use)."""
        from .threads import default_threads

        return self.scene.render.threads or default_threads()

    def held_bytes(self) -> int | None:
        """Bytes of volume data kept for the frames (selection and gathered values, or whole channels); None
        when selections are held one slab at a time or by the Dask workers."""
        return None if self.selection is None else self.selection.held_bytes()

    def render_view(self, view_index: int = 0, et: float | None = None):
        """Render view ``view_index``; returns (rgba float array (H, W, 4), FrameStats)."""
        if self.mode == "local":
            return render_frame(self.selection, self.views[view_index], et, self.bands)
        (_, rgba, stats, _), = self.render_views([view_index], et)
        return rgba, stats

    def render_views(self, which=None, et: float | None = None, bar=None):
        """Render views ``which`` (default all); yields ``(n, rgba, FrameStats, LoadReport)`` in view order.
        ``bar``: a progress bar to update once per frame."""
        which = range(len(self.views)) if which is None else list(which)
        if self.mode == "dask":
            yield from self._dask_frames(which, et, bar)
            return
        for n in which:
            if self.mode == "local":
                rgba, st = render_frame(self.selection, self.views[n], et, self.bands)
            else:
                from .slabs import render_streamed

                rgba, st, self._report = render_streamed(self.request, self.views[n], self.slabs, self.data, et)
            if bar is not None:
                bar.update(1)
            yield n, rgba, st, self._report

    def _dask_frames(self, which, et, bar):
        import contextlib

        from . import distributed

        spec = isinstance(self.scheduler, str)          # local:N, tcp://HOST:PORT; else a Client, connected
        with distributed.connect(self.scheduler) if spec else contextlib.nullcontext(self.scheduler) as client:
            for n, rgba, st, rep in distributed.render_views(client, self.request, [self.views[n] for n in which],
                                                             slabs=self.slabs, et=et, bar=bar):
                self._report = rep
                yield which[n], rgba, st, rep
