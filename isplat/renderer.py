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
>>> rgba.shape, stats.voxels_splatted, r.report.axes
((256, 256, 4), 18256, ['j'])

What a scene needs, and nothing more, is read: the index axes its views use, only the blocks in the transfer
function's non-zero-opacity intervals, the ``normal`` channel only when shading is on, the
``gradient_magnitude`` channel only when the transfer function modulates opacity by it, and the ``density``
channel only for the ``full`` method (the index already carries densities). See :mod:`isplat.selection` for
the selection and :mod:`isplat.frame` for a frame.
"""

from __future__ import annotations

from .frame import FrameStats, axes_of, render_frame, views_for  # noqa: F401  (FrameStats: public here too)
from .selection import LoadReport, select_from_files  # noqa: F401


class Renderer:
    """A scene's views and the selection they need: ``select_from_files`` once, ``render_frame`` per view."""

    def __init__(self, scene, views=None, method: str | None = None):
        from .augfile import open_augmented

        self.scene = scene
        aug = open_augmented(scene.data.augmented)
        self.views = views_for(scene, aug, views)
        self.selection = select_from_files(scene, axes_of(self.views), method, aug)
        self.method = self.selection.method

    @property
    def report(self) -> LoadReport:
        """What was read: bytes of channels and of the index, channels, axes, intervals."""
        return self.selection.report

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

    def held_bytes(self) -> int:
        """Bytes of volume data kept for the frames (selection and gathered values, or whole channels)."""
        return self.selection.held_bytes()

    def render_view(self, view_index: int = 0, et: float | None = None):
        """Render view ``view_index``; returns (rgba float array (H, W, 4), FrameStats)."""
        return render_frame(self.selection, self.views[view_index], et)
