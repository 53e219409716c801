"""Side by side with what users would pick instead: isplat against VTK's CPU ray caster, both against the truth.

``python -m benchmarks.peers [--out docs] [--quick]`` (``make bench-peers``, which first runs ``pip install vtk``)
writes the section ``peers`` of ``performance.md``, ``peers.csv`` and ``img/peers_pareto.png``:

* frame time: ``vtkFixedPointVolumeRayCastMapper`` (offscreen, the same thread count) at sample distances 2, 1
  (its default), 0.5 and 0.25 voxel, and isplat at its defaults and its speed knobs, all rendered in turn, round
  after round, in one process (interleaved), each timed frame right after one of the same renderer and settings
  (as in a run of frames; the first of the two, right after the other renderer's frames, gives the cold-cache
  ratio beside it), on the head sample at 256, 512 and 1024 pixels with an opaque and a
  translucent transfer function, an oblique view, the engine, the hidden-material case (the head sampled at
  512^3, opacity 0 up to 99, 0.1 at 130, 0.5 at 200, 0.7 at 255: skin and soft tissue semi-opaque in front of
  bone), and the cases that stand for real scans (issue 27): the ``ct-chest`` sample at 512x512x133 with a
  scanner's spacing (0.703125, 0.703125, 2.5) and window (-1000..2000 HU), a thin veil (0.03 from code 62 to 78)
  and opaque bone (from 140), from -y, the same shaded, and an oblique view of it; and the head's bone shaded;
  medians and the median of the per-round ratios; isplat's default (post) and the paper's splatting (pre) in
  every table;
* image error of BOTH renderers against reference (a) of :mod:`benchmarks.reference` (the converged float64 ray
  integral, trilinear, post-classified, step 0.05 voxel), and between the two;
* peak memory of each renderer drawing one frame in a process of its own (``ru_maxrss``);
* one frame as a process: ``isplat render`` to a PNG against a minimal VTK script doing the same, interleaved, and
  the first ``isplat render`` on a machine (an empty numba cache);
* with ``--load``, the same frames of isplat (post, pre) and VTK (steps 1, 0.5) also timed while a child process
  spins on one core (:class:`BusyCore`), in turn with the quiet ones, and what each loses; ``--cases`` runs some
  cases only (no memory or process rows, no MIP page), e.g. ``--cases "chest,chest shaded" --load``;
* then maximum-intensity projection against VTK's MIP (``--mip-only`` for that alone, ``--cases`` to choose
  among its cases): :mod:`benchmarks.peers_mip`, which writes ``docs/mip.md``.

Not part of ``make test`` or CI: VTK is a large optional download and needs an OpenGL context even for its
CPU mapper (Mesa's EGL or OSMesa; see :func:`offscreen_window_class`). Under ``python -m benchmarks all``
the benchmark is skipped with a note when VTK is not installed or no context can be made; run on its own it
fails with a message naming the Debian packages.

How the semantics are matched (the point is the same picture, not a similar one): VTK gets the augmented file's
8-bit ``density`` channel (what isplat classifies), the same spacing and voxel positions (origin ``q``, axes via
the volume's user matrix); the same opacity points, with explicit zeros just outside the first and last (isplat's
opacity is zero there, VTK clamps), ``SetScalarOpacityUnitDistance(unit_distance)`` so both apply
``1 - (1 - a) ** (ds / unit_distance)``; the same colour points; a parallel camera with parallel scale = half the
image height in world units, focal point ``p``, view-up ``v``; black background; trilinear interpolation; one ray
per pixel; automatic sample-distance adjustment off. Shading (the shaded cases; the others unshaded, as in the
first issue's measurements): ``ShadeOn`` with the scene's ambient, diffuse, specular and shininess as VTK's
ambient, diffuse, specular and specular power, no light kit (automatic light creation off), each isplat light a
VTK scene light in the same direction (a mirror light for two-sided shading), see :class:`VTKView`; reference
(a) shades with isplat's Phong model and lights from the gradient of its trilinear field, so both shaded
pictures are measured against it.
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import json
import os
import re
import resource
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from isplat.augfile import open_augmented
from isplat.threads import default_threads

from . import _doc

STAMPS_ITSELF = True     # run() stamps its section (it may skip without writing)
TECHNIQUES = ["pre", "post"]     # render.classification of its rows (the page's stamp)
SOURCES = _doc.sources(_doc.RENDER, _doc.READ, _doc.SAMPLES, ("isplat/augment.py", "isplat/prebuilt.py",
                       "isplat/cli/**", "examples/head.toml", "examples/engine.toml", "tests/ray_reference.py",
                       "benchmarks/reference.py", "benchmarks/peers.py"))


def _unit(renderer) -> float:
    """The opacity unit distance the renderer uses: the scene's, else the smallest spacing."""
    return float(renderer.selection.unit_distance or renderer.geom.spacing.min())


SECTION = "peers"
REPO = Path(__file__).resolve().parents[1]
SAMPLE_DISTANCE = 1.0        # VTK's default ray step, in units of the smallest voxel spacing
VTK_STEPS = [2.0, 1.0, 0.5, 0.25]
WARMUP = 2
DEBIAN_EGL = "libegl1 libegl-mesa0 libgl1-mesa-dri libgbm1"
DEBIAN_OSMESA = "libosmesa6"
WINDOW_CLASSES = ("vtkEGLRenderWindow", "vtkOSOpenGLRenderWindow")

_PROBE = """
import vtkmodules.vtkRenderingOpenGL2
from vtkmodules.vtkRenderingCore import vtkRenderWindow, vtkRenderer
rw = vtkRenderWindow()
rw.SetOffScreenRendering(1)
rw.AddRenderer(vtkRenderer())
rw.SetSize(8, 8)
rw.Render()
print(rw.GetClassName(), int(rw.SupportsOpenGL()))
"""


class PeerUnavailable(RuntimeError):
    """VTK or an offscreen OpenGL context is missing; the message says what to install."""


# ---- VTK: availability and the offscreen context ----------------------------------------------------------
def vtk_version() -> str:
    try:
        from vtkmodules.vtkCommonCore import vtkVersion
    except ImportError:
        raise PeerUnavailable("VTK is not installed in this environment; run `make bench-peers` "
                              f"(it runs `pip install vtk`) or `{sys.executable} -m pip install vtk`") from None
    return vtkVersion.GetVTKVersion()


def offscreen_window_class() -> str:
    """The first render-window class that gives an offscreen OpenGL context here (probed in a child
    process, since a failing context can abort the process). ``VTK_DEFAULT_OPENGL_WINDOW`` is honoured if set."""
    wanted = os.environ.get("VTK_DEFAULT_OPENGL_WINDOW")
    tried = []
    for cls in ([wanted] if wanted else list(WINDOW_CLASSES)):
        env = dict(os.environ, VTK_DEFAULT_OPENGL_WINDOW=cls)
        try:
            r = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True, timeout=120)
            out = r.stdout.strip().splitlines()
            if r.returncode == 0 and out and out[-1] == f"{cls} 1":
                return cls
            err = re.sub(r"\x1b\[[0-9;]*m", "", r.stderr).strip().splitlines()
            last = (err or ["exit status %d" % r.returncode])[-1]
        except subprocess.TimeoutExpired:
            last = "timed out"
        tried.append(f"{cls}: {last.split('| ', 1)[-1][-200:]}")
    raise PeerUnavailable(
        "VTK cannot create an offscreen OpenGL context (tried " + "; ".join(tried) + ").\n"
        "VTK's CPU ray caster still needs one. On Debian/Ubuntu install Mesa's EGL (software rendering, no GPU "
        f"needed):\n    apt-get install -y {DEBIAN_EGL}\nor OSMesa:\n    apt-get install -y {DEBIAN_OSMESA}\n"
        "then rerun; to force one, set VTK_DEFAULT_OPENGL_WINDOW=vtkEGLRenderWindow or vtkOSOpenGLRenderWindow.")


# ---- the VTK side of one view -------------------------------------------------------------------------------
def _opacity_points(points):
    """isplat's opacity points, plus explicit zeros just outside the first and last (isplat: zero outside)."""
    pts = [(float(d), float(a)) for d, a in points]
    eps = 0.01
    if pts[0][1] > 0 and pts[0][0] > 0:
        pts.insert(0, (pts[0][0] - eps, 0.0))
    if pts[-1][1] > 0 and pts[-1][0] < 255:
        pts.append((pts[-1][0] + eps, 0.0))
    return pts


class VTKView:
    """vtkFixedPointVolumeRayCastMapper set up to draw view ``view_index`` of an isplat Renderer (or of a scene:
    ``VTKView.for_scene``), at ``sample_distance`` voxels of the smallest spacing, with ``threads`` threads
    (default: isplat's thread count)."""

    @classmethod
    def for_scene(cls, scene, view_index: int = 0, sample_distance: float = 1.0, threads: int | None = None,
                  density=None):
        """Without an isplat Renderer (no selection loaded: for measuring VTK's own memory)."""
        from isplat.frame import views_for

        aug = open_augmented(scene.data.augmented)
        view = views_for(scene, aug)[view_index]
        shim = type("Shim", (), {})()
        shim.scene, shim.geom, shim.frames = scene, view.geom, [view.frame]
        shim.use_shade = bool(scene.shading.enabled and len(scene.shading.lights))
        shim.unit = float(scene.transfer.unit_distance or view.geom.spacing.min())
        shim.threads = scene.render.threads or default_threads()
        return cls(shim, 0, sample_distance, threads, density)

    def __init__(self, renderer, view_index: int = 0, sample_distance: float = SAMPLE_DISTANCE,
                 threads: int | None = None, density=None):
        import vtkmodules.vtkRenderingOpenGL2  # noqa: F401  (OpenGL render window factory)
        import vtkmodules.vtkRenderingVolumeOpenGL2  # noqa: F401  (ray-cast image display helper)
        from vtkmodules.util.numpy_support import numpy_to_vtk
        from vtkmodules.vtkCommonDataModel import vtkImageData, vtkPiecewiseFunction
        from vtkmodules.vtkCommonMath import vtkMatrix4x4
        from vtkmodules.vtkRenderingCore import (vtkColorTransferFunction, vtkLight, vtkRenderer, vtkRenderWindow,
                                                 vtkVolume, vtkVolumeProperty, vtkWindowToImageFilter)
        from vtkmodules.vtkRenderingVolume import vtkFixedPointVolumeRayCastMapper

        scene, geom = renderer.scene, renderer.geom
        frame = renderer.frames[view_index]
        self.geom_frame = (geom, frame)
        if frame.projection != "orthographic":
            raise ValueError("peers bench: only orthographic views are matched")
        # data: the same 8-bit density codes, spacing and voxel positions
        if density is None:
            density = open_augmented(scene.data.augmented).read("density")
        dens = np.ascontiguousarray(density, dtype=np.uint8)
        nk, nj, ni = dens.shape
        img = vtkImageData()
        img.SetDimensions(ni, nj, nk)
        img.SetSpacing(*map(float, geom.spacing))
        img.SetOrigin(0.0, 0.0, 0.0)
        arr = numpy_to_vtk(dens.ravel(), deep=1)
        arr.SetName("density")
        img.GetPointData().SetScalars(arr)
        self._keep = (img, arr)
        volume = vtkVolume()
        m = vtkMatrix4x4()
        for r in range(3):               # world = q + R @ (i s_i, j s_j, k s_k), columns of R = axes i, j, k
            for c in range(3):
                m.SetElement(r, c, float(geom.unit_axes[c, r]))
            m.SetElement(r, 3, float(geom.q[r]))
        volume.SetUserMatrix(m)

        tr = scene.transfer
        otf = vtkPiecewiseFunction()
        for d, a in _opacity_points(tr.opacity):
            otf.AddPoint(d, a)
        ctf = vtkColorTransferFunction()
        for d, r_, g, b in tr.color:
            ctf.AddRGBPoint(float(d), float(r_), float(g), float(b))
        ctf.ClampingOn()
        prop = vtkVolumeProperty()
        prop.SetScalarOpacity(otf)
        prop.SetColor(ctf)
        prop.SetScalarOpacityUnitDistance(getattr(renderer, "unit", None) or _unit(renderer))
        prop.SetInterpolationTypeToLinear()
        sh = scene.shading
        use_shade = renderer.use_shade if hasattr(renderer, "use_shade") else renderer.selection.use_shade
        if use_shade:
            prop.ShadeOn()
            prop.SetAmbient(float(sh.ambient))
            prop.SetDiffuse(float(sh.diffuse))
            prop.SetSpecular(float(sh.specular))
            prop.SetSpecularPower(float(sh.shininess))
        else:
            prop.ShadeOff()
        if len(tr.gradient_opacity):
            raise ValueError("peers bench: gradient opacity is not matched")
        volume.SetProperty(prop)

        mapper = vtkFixedPointVolumeRayCastMapper()
        mapper.SetInputData(img)
        mapper.AutoAdjustSampleDistancesOff()
        mapper.LockSampleDistanceToInputSpacingOff()
        self.voxel = float(geom.spacing.min())
        self.sample_distance = sample_distance * self.voxel
        mapper.SetSampleDistance(self.sample_distance)
        mapper.SetInteractiveSampleDistance(self.sample_distance)
        mapper.SetNumberOfThreads(int(threads or renderer.threads))
        mapper.SetImageSampleDistance(1.0)
        mapper.SetMinimumImageSampleDistance(1.0)
        mapper.SetMaximumImageSampleDistance(1.0)
        volume.SetMapper(mapper)
        self.mapper = mapper

        ren = vtkRenderer()
        bg = scene.image.background
        ren.SetBackground(float(bg[0]), float(bg[1]), float(bg[2]))
        ren.AddVolume(volume)
        ren.AutomaticLightCreationOff()
        ren.RemoveAllLights()
        ren.SetTwoSidedLighting(bool(sh.two_sided))
        R = np.stack([frame.u, frame.v, frame.w])
        ambient_done = False
        self.mirror_lights = []
        for light in sh.lights:
            lw = np.asarray(light.direction, float) @ R           # camera space -> world, towards the light
            lw /= np.linalg.norm(lw)
            col = [float(x) for x in light.color]
            inten = float(light.intensity)
            for sign in ((1.0, -1.0) if sh.two_sided else (1.0,)):
                L = vtkLight()
                L.SetLightTypeToSceneLight()
                L.PositionalOff()
                L.SetFocalPoint(0.0, 0.0, 0.0)
                L.SetPosition(*(sign * lw))
                L.SetIntensity(inten)
                L.SetDiffuseColor(*col)
                L.SetSpecularColor(*(col if sign > 0 else (0.0, 0.0, 0.0)))
                if sign > 0 and not ambient_done and inten > 0:
                    L.SetAmbientColor(1.0 / inten, 1.0 / inten, 1.0 / inten)
                    ambient_done = True
                else:
                    L.SetAmbientColor(0.0, 0.0, 0.0)
                if sign < 0:
                    self.mirror_lights.append(L)
                ren.AddLight(L)
        if use_shade and not ambient_done:     # no lit light: ambient only, through a dark light
            L = vtkLight()
            L.SetIntensity(1.0)
            L.SetDiffuseColor(0.0, 0.0, 0.0)
            L.SetSpecularColor(0.0, 0.0, 0.0)
            L.SetAmbientColor(1.0, 1.0, 1.0)
            ren.AddLight(L)

        cam = ren.GetActiveCamera()
        cam.ParallelProjectionOn()
        cam.SetFocalPoint(*map(float, frame.p))
        cam.SetPosition(*map(float, frame.p + 3.0 * geom.radius * frame.w))
        cam.SetViewUp(*map(float, frame.v))
        cam.SetParallelScale(0.5 * frame.height * frame.pixel_size)
        ren.ResetCameraClippingRange()

        rw = vtkRenderWindow()
        rw.SetOffScreenRendering(1)
        rw.SetMultiSamples(0)
        rw.AddRenderer(ren)
        rw.SetSize(frame.width, frame.height)
        self.window, self.renderer, self.camera = rw, ren, cam
        self._grab = vtkWindowToImageFilter()
        self._grab.SetInput(rw)
        self._grab.SetInputBufferTypeToRGB()
        self._grab.ReadFrontBufferOff()

    def render(self) -> float:
        """One frame; returns its wall time in seconds (the ray casting and drawing the image)."""
        t = time.perf_counter()
        self.window.Render()
        return time.perf_counter() - t

    def set_step(self, voxels: float):
        """Ray step in voxels of the smallest spacing."""
        self.sample_distance = voxels * self.voxel
        self.mapper.SetSampleDistance(self.sample_distance)
        self.mapper.SetInteractiveSampleDistance(self.sample_distance)

    def image_float(self) -> np.ndarray:
        """The last frame as float RGB in [0, 1] (H, W, 3)."""
        return self.image().astype(np.float64) / 255.0

    def image(self) -> np.ndarray:
        """The last frame as uint8 RGB (H, W, 3), row 0 at the top."""
        from vtkmodules.util.numpy_support import vtk_to_numpy

        self._grab.Modified()
        self._grab.Update()
        out = self._grab.GetOutput()
        w, h, _ = out.GetDimensions()
        rgb = vtk_to_numpy(out.GetPointData().GetScalars()).reshape(h, w, -1)[:, :, :3]
        return np.ascontiguousarray(rgb[::-1])

    @property
    def threads(self) -> int:
        return int(self.mapper.GetNumberOfThreads())



# ---- the cases ----------------------------------------------------------------------------------------------
UNSHADED = ["shading.enabled=false", "image.background=[0.0, 0.0, 0.0]"]
HEAD_TRANSLUCENT = ["transfer.opacity=[[95, 0.0], [110, 0.03], [160, 0.03], [175, 0.0], [185, 0.0], [215, 0.25], "
                    "[255, 0.25]]",
                    "transfer.color=[[95, 0.9, 0.65, 0.55], [160, 0.9, 0.7, 0.6], [200, 1.0, 0.98, 0.9], "
                    "[255, 1.0, 1.0, 1.0]]"]
HIDDEN_TF = ["transfer.opacity=[[99, 0.0], [130, 0.1], [200, 0.5], [255, 0.7]]",
             "transfer.color=[[99, 0.9, 0.6, 0.5], [130, 0.9, 0.7, 0.6], [200, 1.0, 0.97, 0.9], [255, 1.0, 1.0, 1.0]]"]
# name -> (sample, shape (quick shape), overrides, sizes (quick sizes), note)
CASES = {
    "head opaque": ("head", None, (64, 64, 56), [], [256, 512, 1024], [48],
                    "head sample 256x256x225, bone opaque (examples/head.toml's transfer function), front view"),
    "head translucent": ("head", None, (64, 64, 56), HEAD_TRANSLUCENT, [256, 512, 1024], [48],
                         "head sample, skin and soft tissue at 0.03, bone at 0.25 per voxel, front view"),
    "head oblique": ("head", None, (64, 64, 56), ["camera.azimuth=40", "camera.elevation=35"], [512], [48],
                     "head sample, bone opaque, azimuth 40, elevation 35"),
    "engine": ("engine", None, (64, 64, 28), [], [512], [48],
               "engine sample 256x256x110, examples/engine.toml's three translucent materials, orthographic"),
    "hidden material": ("head", (512, 512, 512), (96, 96, 96), HIDDEN_TF, [512], [64],
                        "head sample at 512^3, opacity 0 up to 99, 0.1 at 130, 0.5 at 200, 0.7 at 255: skin and "
                        "soft tissue semi-opaque in front of bone"),
}
HIDDEN_REMOVED = "isplat defaults, hidden voxels removed"

# ---- the real-scan cases (issue 27): the ct-chest sample as a scanner gives it --------------------------------
CHEST_SHAPE = (512, 512, 133)       # (n_i, n_j, n_k): 512 x 512 slices, 133 of them
CHEST_SPACING = (0.703125, 0.703125, 2.5)
CHEST_WINDOW = (-1000.0, 2000.0)    # Hounsfield units to codes 0..255 (`augment --window=-1000,2000`)
CHEST_QUICK = (64, 64, 17)
CHEST_TF = ["transfer.opacity=[[0, 0.0], [50, 0.0], [62, 0.03], [78, 0.03], [82, 0.0], [110, 0.0], [140, 1.0], "
            "[255, 1.0]]",
            "transfer.color=[[50, 0.9, 0.6, 0.5], [78, 0.9, 0.65, 0.55], [110, 0.95, 0.9, 0.8], "
            "[255, 1.0, 1.0, 0.95]]",
            "transfer.unit_distance=0.703125"]
FROM_MINUS_Y = ["camera.azimuth=0", "camera.elevation=0", "camera.zoom=1.0"]
SHADED = ["shading.enabled=true"]       # examples/head.toml's light and material (after UNSHADED: it wins)
CHEST = ("the ct-chest sample at 512x512x133, spacing 0.703125, 0.703125, 2.5 (`augment --spacing "
         "0.703125,0.703125,2.5 --window=-1000,2000`), opacity 0 up to code 50, 0.03 from 62 to 78 (the veil: fat "
         "and soft tissue), 0 from 82 to 110, 1 from 140 (bone)")
CASES.update({
    "chest": ("ct-chest", CHEST_SHAPE, CHEST_QUICK, [*CHEST_TF, *FROM_MINUS_Y], [512], [48],
              CHEST + ", orthographic from the -y side, unshaded"),
    "chest shaded": ("ct-chest", CHEST_SHAPE, CHEST_QUICK, [*CHEST_TF, *FROM_MINUS_Y, *SHADED], [512], [48],
                     "the chest case shaded (VTK `ShadeOn`; examples/head.toml's light and material, Phong)"),
    "chest oblique": ("ct-chest", CHEST_SHAPE, CHEST_QUICK, [*CHEST_TF, "camera.azimuth=30", "camera.elevation=20",
                                                             "camera.zoom=1.0"], [512], [48],
                      "the chest case, unshaded, azimuth 30, elevation 20 (rays oblique to the thick slices)"),
    "head shaded": ("head", None, (64, 64, 56), SHADED, [512], [48],
                    "head sample, bone opaque, shaded (examples/head.toml as it is: its light and material)"),
})


def chest_data(shape=CHEST_SHAPE) -> tuple[Path, Path]:
    """The ct-chest sample at ``shape`` with the scanner's spacing and the window -1000..2000 HU, augmented and
    indexed once into ``bench-out/`` (as `isplat sample ct-chest`, `isplat augment --spacing ... --window ...`)."""
    from isplat.augment import augment_array
    from isplat.samples import make_sample

    from . import reference as REF

    tag = f"ct-chest-{'x'.join(map(str, shape))}-aniso"
    aug, idx = REF.DATA / f"{tag}.aug.h5", REF.DATA / f"{tag}.idx.h5"
    if aug.exists() and idx.exists() and REF._readable(aug, idx):
        return aug, idx
    REF.DATA.mkdir(parents=True, exist_ok=True)
    arr, _ = make_sample("ct-chest", shape)
    o = augment_array(arr, CHEST_SPACING, window=CHEST_WINDOW)
    REF.write_pair(aug, idx, o["density"], o["gradient_magnitude"], o["normal"], o["spacing_ijk"],
                   o["density_window"], o["gradient_magnitude_scale"],
                   f"isplat sample ct-chest {shape}, spacing {CHEST_SPACING}, window {CHEST_WINDOW}")
    return aug, idx


def _who(who: str) -> str:
    """A point's renderer with isplat's technique named (every row about rendering names its technique).

    >>> _who("isplat defaults"), _who("isplat pre, radius 2"), _who("VTK 1")
    ('isplat post, defaults', 'isplat pre, radius 2', 'VTK 1')
    """
    if not who.startswith("isplat ") or who.startswith("isplat pre"):
        return who
    return "isplat post, " + who[len("isplat "):]
ISPLAT_POINTS = [("defaults", {}), ("ET 0.95", {"early_termination": 0.95}),
                 ("pre", {"classification": "pre"}),
                 ("pre, radius 2", {"classification": "pre", "footprint_radius": 2.0})]


def case_data(name: str, quick: bool = False, data=None) -> tuple[str, tuple]:
    """The sample whose scene (:data:`benchmarks.reference.CASES`) case ``name`` renders, and its (aug, idx)
    files (``data`` when given): the chest cases take examples/head.toml's camera, light and material on the
    chest's own data."""
    from . import reference as REF

    sample, shape, qshape, *_ = CASES[name]
    shape = qshape if quick else shape
    if sample == "ct-chest":
        return "head", data or chest_data(shape)
    return sample, data or REF.sample_data(sample, shape)


def peer_scene(name: str, size: int, quick: bool, render: dict | None = None, extra=(), data=None):
    from . import reference as REF

    sample, data = case_data(name, quick, data)
    return REF.make_scene(sample, size, render, [*UNSHADED, *CASES[name][3], *extra], data=data)


# ---- the hidden-material case with its hidden voxels removed -------------------------------------------------
HIDDEN_T = 1e-4         # a voxel is hidden when every ray near it has transmittance below this before reaching it
HIDDEN_MARGIN = 2       # ... within this many voxels sideways and in depth (bilinear reach, pixel offsets)


def hidden_voxels(density, opacity, dim: int, sign: int, slopes, step_over_unit: float, t_min: float = HIDDEN_T,
                  margin: int = HIDDEN_MARGIN):
    """Which voxels of ``density`` an orthographic view cannot see: rays cross the slices along array dimension
    ``dim`` in direction ``sign`` and move ``slopes`` voxels along the other two dimensions (in order) per slice.
    Each ray, nearest voxel per slice, has transmittance ``prod (1 - opacity[d]) ** step_over_unit``; a voxel is
    hidden when every ray within ``margin`` of it (sideways) is below ``t_min`` at least ``margin`` slices in
    front of it.

    >>> d = np.zeros((8, 1, 1), np.uint8); d[2:] = 255
    >>> op = np.r_[np.zeros(255), 1.0]
    >>> hidden_voxels(d, op, 0, 1, (0.0, 0.0), 1.0, margin=1).ravel().astype(int).tolist()
    [0, 0, 0, 0, 1, 1, 1, 1]
    >>> hidden_voxels(d, op, 0, -1, (0.0, 0.0), 1.0, margin=1).ravel().astype(int).tolist()
    [1, 1, 1, 1, 1, 1, 0, 0]
    """
    vol = np.moveaxis(density, dim, 0)
    alpha = 1.0 - (1.0 - np.clip(np.asarray(opacity, np.float64), 0.0, 1.0)) ** step_over_unit
    n, na, nb = vol.shape
    ea, eb = (int(np.ceil(abs(sl) * (n - 1))) for sl in slopes)
    ra, rb = np.arange(-ea, na + ea), np.arange(-eb, nb + eb)       # the rays, by where they cross the front slice
    T = np.ones((ra.size, rb.size))
    depth = np.full(T.shape, n, np.int64)
    front = np.arange(n) if sign > 0 else np.arange(n - 1, -1, -1)
    for t, sl in enumerate(front):
        ia = np.rint(ra + t * slopes[0]).astype(np.int64)
        ib = np.rint(rb + t * slopes[1]).astype(np.int64)
        ok_a, ok_b = (ia >= 0) & (ia < na), (ib >= 0) & (ib < nb)
        a_vox = np.zeros(T.shape)
        a_vox[np.ix_(ok_a, ok_b)] = alpha[vol[sl][np.ix_(ia[ok_a], ib[ok_b])]]
        T *= 1.0 - a_vox
        depth[(T < t_min) & (depth == n)] = t + 1
    reach = _neighbourhood_max(depth, margin) + margin                 # slices from the front still visible
    hidden = np.zeros(vol.shape, bool)
    for t, sl in enumerate(front):
        ja = np.clip(np.rint(np.arange(na) - t * slopes[0]).astype(np.int64) + ea, 0, ra.size - 1)
        jb = np.clip(np.rint(np.arange(nb) - t * slopes[1]).astype(np.int64) + eb, 0, rb.size - 1)
        hidden[sl] = t >= reach[np.ix_(ja, jb)]
    return np.moveaxis(hidden, 0, dim)


def _neighbourhood_max(a, r: int):
    """The maximum of ``a`` (2-D) over the (2r+1) x (2r+1) square around each element (edges clamped)."""
    p = np.pad(a, r, mode="edge")
    out = a.copy()
    for di in range(2 * r + 1):
        for dj in range(2 * r + 1):
            np.maximum(out, p[di:di + a.shape[0], dj:dj + a.shape[1]], out=out)
    return out


def hidden_removed_data(scene, view, tag: str) -> tuple[Path, Path, float]:
    """The scene's augmented and index files with the voxels ``view`` cannot see set to density 0
    (:func:`hidden_voxels` along the view's rays, from the voxels' own opacities), built once into
    ``bench-out/<tag>-visible-<key>.*``; and the share of the voxels of interest removed. Orthographic views of
    an axis-aligned volume only."""
    from isplat.augfile import open_augmented
    from isplat.grid import AXES

    from . import reference as REF

    axis, sign = view.axis_sign
    g = view.geom
    if view.frame.projection != "orthographic" or not np.allclose(g.unit_axes, np.eye(3)):
        raise RuntimeError("hidden_removed_data: only orthographic views of an axis-aligned volume")
    c = AXES.index(axis)
    d_grid = (g.unit_axes @ view.frame.direction) / g.spacing        # grid steps along i, j, k per world unit
    dims = [x for x in range(3) if x != 2 - c]                       # the other array dimensions ([k, j, i])
    slopes = [float(d_grid[2 - x] / abs(d_grid[c])) for x in dims]
    aug = open_augmented(scene.data.augmented)
    dens = aug.read("density")
    opacity = np.interp(np.arange(256), *np.asarray(scene.transfer.opacity, np.float64).T, left=0.0, right=0.0)
    unit = float(scene.transfer.unit_distance or g.spacing.min())
    step = float(np.linalg.norm(g.spacing * d_grid / abs(d_grid[c])))  # world length of a ray per slice
    hidden = hidden_voxels(dens, opacity, 2 - c, sign, slopes, step / unit)
    of_interest = opacity[dens] > 0
    removed = float((hidden & of_interest).sum() / max(1, of_interest.sum()))
    key = hashlib.sha1(repr((scene.transfer.opacity, unit, np.round(view.frame.direction, 9).tolist(), sign,
                             HIDDEN_T, HIDDEN_MARGIN)).encode()).hexdigest()[:10]
    out_aug, out_idx = (REF.DATA / f"{tag}-visible-{key}.{ext}.h5" for ext in ("aug", "idx"))
    if not (out_aug.exists() and out_idx.exists()):
        REF.write_pair(out_aug, out_idx, np.where(hidden, np.uint8(0), dens), aug.read("gradient_magnitude"),
                       aug.read("normal"), aug.spacing_ijk, aug.density_window, aug.gradient_magnitude_scale,
                       f"{scene.data.augmented} with the voxels hidden in one view set to 0")
    return out_aug, out_idx, removed


# ---- under load: another process takes one core ----------------------------------------------------------------
BUSY = "while True: pass"
LOAD_POINTS = ["isplat defaults", "isplat pre", "VTK 1", "VTK 0.5"]     # the renderers timed under load too


class BusyCore:
    """A child process spinning on one core (``python -c "while True: pass"``) while the with-block runs; started
    and killed here, by its own process id. ``cpu``: pinned to that core (else the system moves it)."""

    def __init__(self, cpu: int | None = None):
        self.cpu = cpu

    def __enter__(self):
        self.proc = subprocess.Popen([sys.executable, "-c", BUSY])
        if self.cpu is not None:
            os.sched_setaffinity(self.proc.pid, {self.cpu})
        time.sleep(0.2)                 # running before the first frame
        return self

    def __exit__(self, *exc):
        self.proc.kill()
        self.proc.wait()


def load_summary(quiet: dict, loaded: dict) -> dict:
    """Per renderer: quiet and loaded medians (ms) and the median of the per-round ratios loaded / quiet; and
    isplat / VTK 1 per round, quiet and loaded.

    >>> s = load_summary({"isplat defaults": [1.0, 1.0], "VTK 1": [2.0, 2.0]}, {"isplat defaults": [2.0, 2.0],
    ...                   "VTK 1": [3.0, 3.0]})
    >>> s["isplat defaults"]["loss"], s["ratio"]
    (2.0, {'quiet': 0.5, 'loaded': 0.6666666666666666})
    """
    med = statistics.median
    out = {lab: dict(quiet=_doc.median_ms(quiet[lab]), loaded=_doc.median_ms(loaded[lab]),
                     loss=med(b / a for a, b in zip(quiet[lab], loaded[lab]))) for lab in loaded}
    out["ratio"] = {k: med(a / b for a, b in zip(t["isplat defaults"], t["VTK 1"]))
                    for k, t in (("quiet", quiet), ("loaded", loaded))}
    return out


# ---- one case: frames interleaved, errors against the reference ----------------------------------------------
def measure(name: str, size: int, frames: int, quick: bool, load: bool = False) -> dict:
    from isplat.frame import BandLearning, render_frame, views_for
    from isplat.renderer import Renderer

    from . import reference as REF

    scene = peer_scene(name, size, quick)
    ref, ref_s, cached = REF.reference(scene)
    r0 = Renderer(scene)
    # the knobs act per frame (View.render): one selection serves every isplat point of a classification (a
    # pre-classified frame needs its voxels and their normals, which a post-classified selection leaves out)
    sels = {"post": r0.selection, "pre": Renderer(peer_scene(name, size, quick, {"classification": "pre"})).selection}
    knobs_of = [knobs for _, knobs in ISPLAT_POINTS]
    sel_of = [sels.get(k.get("classification", "post"), r0.selection) for k in knobs_of]
    views = [views_for(peer_scene(name, size, quick, k), s)[0] for k, s in zip(knobs_of, sel_of)]
    vtkv = VTKView(r0, 0, SAMPLE_DISTANCE)
    labels = [f"isplat {lab}" for lab, _ in ISPLAT_POINTS] + [f"VTK {s:g}" for s in VTK_STEPS]
    sel = {lab: (s, v, None, BandLearning()) for lab, v, s in zip(labels, views, sel_of)}
    removed = None
    if name == "hidden material":       # the same frame with the voxels this view cannot see removed
        tag = f"{CASES[name][0]}-{'x'.join(map(str, CASES[name][2 if quick else 1]))}"
        *vis, removed = hidden_removed_data(scene, views[0], tag)
        r_vis = Renderer(peer_scene(name, size, quick, data=vis))
        sel[HIDDEN_REMOVED] = (r_vis.selection, views_for(r_vis.scene, r_vis.selection)[0], None, BandLearning())
        labels.append(HIDDEN_REMOVED)
    times = {lab: [] for lab in labels}
    cold = {lab: [] for lab in labels}          # the untimed-as-such frame: right after another renderer's
    imgs, stats = {}, {}

    def job(lab, keep):
        if lab.startswith("VTK"):
            vtkv.set_step(float(lab.split()[1]))
            dt = vtkv.render()
            if keep:
                imgs[lab] = vtkv.image_float()
            return dt
        t0 = time.perf_counter()
        img, st = render_frame(*sel[lab])
        dt = time.perf_counter() - t0
        imgs[lab], stats[lab] = img, st
        return dt

    for _ in range(WARMUP):
        for lab in labels:
            job(lab, False)
    loaded = {lab: [] for lab in LOAD_POINTS}
    quiet = {lab: [] for lab in LOAD_POINTS}
    for rnd in range(frames):
        order = labels[rnd % len(labels):] + labels[:rnd % len(labels)]
        for busy in ((False, True) if rnd % 2 == 0 else (True, False)) if load else (False,):
            if busy:                # the same renderers with another process on one core, in turn with the quiet
                with BusyCore():
                    for lab in [x for x in order if x in LOAD_POINTS]:
                        job(lab, False)
                        loaded[lab].append(job(lab, False))
                continue
            for lab in order:           # each timed frame right after one of its own, as in a run of frames
                cold[lab].append(job(lab, False))
                times[lab].append(job(lab, rnd == frames - 1))
                if lab in quiet:
                    quiet[lab].append(times[lab][-1])
    pts = []
    for lab in labels:
        if lab != HIDDEN_REMOVED:
            pts.append(dict(case=name, size=size, who=lab, ms=_doc.median_ms(times[lab]),
                            err=REF.errors(imgs[lab], ref)))
    iso, v1, v05 = "isplat defaults", "VTK 1", "VTK 0.5"
    paired = {s: statistics.median(a / b for a, b in zip(times[iso], times[s])) for s in (v1, v05)}
    paired["pre / VTK 1"] = statistics.median(a / b for a, b in zip(times["isplat pre"], times[v1]))
    paired["VTK 1, cold"] = statistics.median(a / b for a, b in zip(cold[iso], cold[v1]))
    st = stats[iso]
    hid = None
    if removed is not None:
        sv = stats[HIDDEN_REMOVED]
        hid = dict(ms=_doc.median_ms(times[HIDDEN_REMOVED]), removed=removed, image=REF.errors(imgs[HIDDEN_REMOVED],
                   imgs[iso]), ratio=statistics.median(a / b for a, b in zip(times[iso], times[HIDDEN_REMOVED])),
                   examined=sv.voxels_examined, tested=sv.voxels_tested, splatted=sv.drawn)
    return dict(case=name, size=size, points=pts, paired=paired, ref_seconds=ref_s, ref_cached=cached, hidden=hid,
                between=REF.errors(imgs[iso], imgs[v1]), between05=REF.errors(imgs[iso], imgs[v05]),
                examined=st.voxels_examined, splatted=st.drawn, tested=st.voxels_tested,
                threads=(r0.threads, vtkv.threads), load=load_summary(quiet, loaded) if load else None)


# ---- peak memory: one frame in a process of its own -----------------------------------------------------------
def memory_child(who: str, name: str, size: int, quick: bool) -> dict:
    """Render one frame with ``who`` ("isplat" or "vtk") and report the process's peak resident set."""
    t0 = time.perf_counter()
    scene = peer_scene(name, size, quick)
    if who == "isplat":
        from isplat.renderer import Renderer

        Renderer(scene).render_view(0)
    else:
        v = VTKView.for_scene(scene, 0, SAMPLE_DISTANCE)
        v.render()
    return {"maxrss_mb": peak_rss_mb(), "seconds": time.perf_counter() - t0}


def peak_rss_mb() -> float:
    """This process's peak resident set: VmHWM (Linux; ``ru_maxrss`` is not used because it carries the parent's
    peak over fork and exec), else ``ru_maxrss``."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def measure_memory(name: str, size: int, quick: bool) -> dict:
    out = {}
    for who in ("isplat", "vtk"):
        cmd = [sys.executable, "-m", "benchmarks.peers", "--memory-child", who, name, str(size)] + \
              (["--quick"] if quick else [])
        r = subprocess.run(cmd, capture_output=True, text=True, cwd=REPO)
        if r.returncode != 0:
            raise RuntimeError(f"memory child {who} failed: {r.stderr.strip().splitlines()[-1:]}")
        out[who] = json.loads(r.stdout.strip().splitlines()[-1])
    return out


# ---- one frame as a process ------------------------------------------------------------------------------------
VTK_SCRIPT = '''"""One frame with VTK's CPU ray caster to a PNG: the minimal script isplat's process time is compared with."""
import json, sys
import numpy as np
import vtkmodules.vtkRenderingOpenGL2  # noqa: F401
import vtkmodules.vtkRenderingVolumeOpenGL2  # noqa: F401
from vtkmodules.util.numpy_support import numpy_to_vtk
from vtkmodules.vtkCommonDataModel import vtkImageData, vtkPiecewiseFunction
from vtkmodules.vtkIOImage import vtkPNGWriter
from vtkmodules.vtkRenderingCore import (vtkColorTransferFunction, vtkRenderer, vtkRenderWindow, vtkVolume,
                                         vtkVolumeProperty, vtkWindowToImageFilter)
from vtkmodules.vtkRenderingVolume import vtkFixedPointVolumeRayCastMapper

P = json.loads(%r)
d = np.load(P["density"])
img = vtkImageData()
img.SetDimensions(d.shape[2], d.shape[1], d.shape[0])
img.SetSpacing(*P["spacing"])
img.SetOrigin(*P["origin"])
img.GetPointData().SetScalars(numpy_to_vtk(d.ravel(), deep=1))
otf, ctf = vtkPiecewiseFunction(), vtkColorTransferFunction()
for x, a in P["opacity"]:
    otf.AddPoint(x, a)
for x, r, g, b in P["color"]:
    ctf.AddRGBPoint(x, r, g, b)
prop = vtkVolumeProperty()
prop.SetScalarOpacity(otf)
prop.SetColor(ctf)
prop.SetScalarOpacityUnitDistance(P["unit"])
prop.SetInterpolationTypeToLinear()
mapper = vtkFixedPointVolumeRayCastMapper()
mapper.SetInputData(img)
mapper.SetNumberOfThreads(P["threads"])
mapper.AutoAdjustSampleDistancesOff()
mapper.SetSampleDistance(P["step"])
vol = vtkVolume()
vol.SetMapper(mapper)
vol.SetProperty(prop)
ren = vtkRenderer()
ren.AddVolume(vol)
cam = ren.GetActiveCamera()
cam.ParallelProjectionOn()
cam.SetFocalPoint(*P["focal"])
cam.SetPosition(*P["position"])
cam.SetViewUp(*P["up"])
cam.SetParallelScale(P["scale"])
ren.ResetCameraClippingRange()
win = vtkRenderWindow()
win.SetOffScreenRendering(1)
win.AddRenderer(ren)
win.SetSize(P["size"], P["size"])
win.Render()
grab = vtkWindowToImageFilter()
grab.SetInput(win)
writer = vtkPNGWriter()
writer.SetFileName(sys.argv[1])
writer.SetInputConnection(grab.GetOutputPort())
writer.Write()
'''


def _isplat_cli() -> list[str]:
    exe = Path(sys.executable).parent / "isplat"
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "isplat"]


def process_commands(name: str, size: int, quick: bool, tmp: Path):
    """(isplat render command, VTK script command) drawing the same frame to a PNG."""
    from . import reference as REF

    sample, shape, qshape, ov, *_ = CASES[name]
    aug, idx = REF.sample_data(sample, qshape if quick else shape)
    path = REF.CASES[sample][0]
    sets = [f'data.augmented="{aug}"', f'data.index="{idx}"', f"image.width={size}", f"image.height={size}",
            *REF.CASES[sample][1], *UNSHADED, *ov]
    iso = _isplat_cli() + ["render", str(REPO / path), "-o", str(tmp / "isplat.png"), "--force", "-q"] + \
        [x for s in sets for x in ("--set", s)]
    scene = peer_scene(name, size, quick)
    v = VTKView.for_scene(scene, 0, SAMPLE_DISTANCE)
    dens = open_augmented(aug).read("density")
    np.save(tmp / "density.npy", dens)
    geom, frame = v.geom_frame
    if not np.allclose(geom.unit_axes, np.eye(3)):
        raise RuntimeError("the minimal VTK script places axis-aligned volumes only")
    P = dict(density=str(tmp / "density.npy"), spacing=list(map(float, geom.spacing)), origin=list(map(float, geom.q)),
             opacity=_opacity_points(scene.transfer.opacity), color=[list(map(float, c)) for c in scene.transfer.color],
             unit=float(scene.transfer.unit_distance or geom.spacing.min()), threads=v.threads,
             step=v.sample_distance, focal=list(map(float, frame.p)),
             position=list(map(float, frame.p + 3.0 * geom.radius * frame.w)), up=list(map(float, frame.v)),
             scale=0.5 * frame.height * frame.pixel_size, size=size)
    script = tmp / "vtk_one_frame.py"
    script.write_text(VTK_SCRIPT % json.dumps(P))
    return iso, [sys.executable, str(script), str(tmp / "vtk.png")]


def _timed(cmd, env=None) -> float:
    t0 = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=REPO)
    dt = time.perf_counter() - t0
    if r.returncode != 0:
        raise RuntimeError(f"{shlex.join(cmd[:3])} ... failed: {r.stderr.strip()[-300:]}")
    return dt


def measure_process(name: str, size: int, quick: bool, repeats: int) -> dict:
    with tempfile.TemporaryDirectory(prefix="isplat-peers-") as tmp:
        tmp = Path(tmp)
        iso, vtk = process_commands(name, size, quick, tmp)
        env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}   # as installed: .pyc kept
        env["ISPLAT_PREBUILT"] = "none"                 # kernels compiled for this CPU
        _timed(iso, env)
        _timed(vtk, env)                                # warm: numba's cache, .pyc files, the OS's file cache
        t = {"isplat": [], "vtk": []}
        for rep in range(repeats):
            for who in (("isplat", "vtk") if rep % 2 == 0 else ("vtk", "isplat")):
                t[who].append(_timed(iso if who == "isplat" else vtk, env))
        # the first run on a machine (an empty numba cache, with and without prebuilt kernels) is measured in
        # one place only, docs/startup.md (python -m benchmarks startup), which this page refers to
        return dict(isplat=statistics.median(t["isplat"]), vtk=statistics.median(t["vtk"]),
                    spread={k: (min(v), max(v)) for k, v in t.items()}, repeats=repeats,
                    command=shlex.join([Path(iso[0]).name] + iso[1:2] + ["examples/head.toml", "-o", "frame.png",
                                                                          "--set", "..."]))


# ---- plot --------------------------------------------------------------------------------------------------------
def plot(results, path: Path):
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("[peers] matplotlib missing (pip install 'isplat[plot]'): no plot", file=sys.stderr)
        return None
    sel = {}
    for r in results:                    # per case: its 512-pixel run (else its first)
        if r["case"] not in sel or r["size"] == 512:
            sel[r["case"]] = r
    sel = list(sel.values())
    ncol = 3
    nrow = -(-len(sel) // ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(5.0 * ncol, 4.2 * nrow), squeeze=False)
    for ax in axes.ravel()[len(sel):]:
        ax.set_visible(False)
    for ax, r in zip(axes.ravel(), sel):
        for who, colour, marker in (("isplat", "tab:blue", "o"), ("VTK", "tab:green", "s")):
            pts = [p for p in r["points"] if p["who"].startswith(who) and p["err"] is not None]
            ax.plot([p["ms"] for p in pts], [p["err"]["rmse"] for p in pts], marker, color=colour, label=who, ms=5)
            for p in pts:
                ax.annotate(p["who"].split(" ", 1)[1], (p["ms"], p["err"]["rmse"]), fontsize=6, xytext=(3, 2),
                            textcoords="offset points")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("median frame time (ms)")
        ax.set_ylabel("RMSE against reference (a)")
        ax.set_title(f"{r['case']}, {r['size']} px", fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


# ---- the report -------------------------------------------------------------------------------------------------
def _pt(r, who):
    return next(p for p in r["points"] if p["who"] == who)


def _psnr(e):
    return "exact" if e["psnr"] == float("inf") else f"{e['psnr']:.1f}"


def write_csv(results, path: Path):
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["case", "size", "renderer", "median_ms", "rmse_vs_reference_a", "psnr_db", "max_abs",
                    "share_8bit_pixels_changed"])
        for r in results:
            for p in r["points"]:
                e = p["err"] or {}
                w.writerow([r["case"], r["size"], p["who"], f"{p['ms']:.3f}", e.get("rmse", ""), e.get("psnr", ""),
                            e.get("max", ""), e.get("px8", "")])


def slower_text(results, mem, proc) -> list[str]:
    """Where isplat is slower than VTK at VTK's default step, and the measured reasons; follows the numbers."""
    L = []
    slow = [r for r in results if r["paired"]["VTK 1"] > 1.0]
    fast = [r for r in results if r["paired"]["VTK 1"] <= 1.0]
    L.append(f"- Against VTK at its default step (1 voxel), isplat's defaults are slower in {len(slow)} of "
             f"{len(results)} cases" + (": " + "; ".join(f"{r['case']} {r['size']} px {r['paired']['VTK 1']:.2f}x"
                                                      for r in slow) if slow else "") +
             (". Not slower in: " + "; ".join(f"{r['case']} {r['size']} px {r['paired']['VTK 1']:.2f}x"
                                             for r in fast) if fast else "") + ".")
    with_pre = [r for r in results if "pre / VTK 1" in r["paired"]]
    slow_pre = [r for r in with_pre if r["paired"]["pre / VTK 1"] > 1.0]
    if with_pre:
        L.append(f"- The paper's pre-classified splatting (*pre*) is slower than VTK at step 1 in {len(slow_pre)} of "
                 f"{len(with_pre)} cases" + (": " + "; ".join(f"{r['case']} {r['size']} px "
                                                             f"{r['paired']['pre / VTK 1']:.2f}x" for r in slow_pre)
                                             if slow_pre else "") + " (it splats every voxel of interest in front "
                 "of the saturated pixels with its footprint, where post takes one sample per pixel and slice).")
    cold = [r for r in results if "VTK 1, cold" in r["paired"]]
    slow_cold = [r for r in cold if r["paired"]["VTK 1, cold"] > 1.0]
    if cold:
        L.append(f"- With cold caches (each frame right after the other renderer's), slower in {len(slow_cold)} of "
                 f"{len(cold)} cases" + (": " + "; ".join(f"{r['case']} {r['size']} px "
                                                          f"{r['paired']['VTK 1, cold']:.2f}x" for r in slow_cold)
                                         if slow_cold else "") + ".")
    by_case = {}
    for r in results:
        by_case.setdefault(r["case"], {})[r["size"]] = r
    for case, rs in by_case.items():
        if 256 in rs and 1024 in rs:
            gi = _pt(rs[1024], "isplat defaults")["ms"] / _pt(rs[256], "isplat defaults")["ms"]
            gv = _pt(rs[1024], "VTK 1")["ms"] / _pt(rs[256], "VTK 1")["ms"]
            L.append(f"- {case}: from 256 to 1024 pixels (16x the pixels) isplat's frame time grows {gi:.1f}x, "
                     f"VTK's {gv:.1f}x: a ray caster's cost follows pixels times samples, isplat's the cells of "
                     f"interest it visits plus the pixels their quads cover in each slice (one sample per pixel "
                     f"and slice, as many as a ray caster takes at step 1 where the rays cross material), so "
                     f"isplat's ratio to VTK is "
                     f"{'worst' if rs[256]['paired']['VTK 1'] >= rs[1024]['paired']['VTK 1'] else 'best'} at 256 "
                     f"pixels ({rs[256]['paired']['VTK 1']:.2f}x against {rs[1024]['paired']['VTK 1']:.2f}x at 1024).")
    hid = [r for r in results if r["case"] == "hidden material"]
    for r in hid:
        tested = r.get("tested", r["examined"])
        L.append(f"- Hidden material ({r['size']} px): of {r['examined']:,} voxels of interest, {tested:,} "
                 f"({100 * tested / max(1, r['examined']):.0f}%) reached isplat's per-voxel stages (the rest were "
                 f"skipped a region, block or cell of a slice at a time, docs/worksplit.md) and {r['splatted']:,} "
                 f"({100 * r['splatted'] / max(1, r['examined']):.0f}%) is the number of samples composited "
                 f"(post-classification takes one sample per pixel and slice where a quad of interest is seen, as a "
                 f"ray caster takes one per pixel and step).")
        h = r.get("hidden")
        if h:
            L.append(f"- Hidden material against the same view without it ({r['size']} px): the voxels this view "
                     f"cannot see (every ray within {HIDDEN_MARGIN} voxels of them has transmittance below "
                     f"{HIDDEN_T:g} at least {HIDDEN_MARGIN} voxels in front, from the voxels' own opacities along the "
                     f"view's axis; `hidden_removed_data`) set to density 0: {100 * h['removed']:.0f}% of the voxels "
                     f"of interest. That frame takes {h['ms']:.1f} ms; with the hidden material it takes "
                     f"{h['ratio']:.2f}x as long (median of per-round ratios, interleaved; the issue's bar: within "
                     f"2x). The two images differ by RMSE {h['image']['rmse']:.1e} ({100 * h['image']['px8']:.2f}% of "
                     f"pixels differ in 8 bits), so only hidden voxels were removed. Voxels reaching the per-voxel "
                     f"stages: {tested:,} with the hidden material, {h['tested']:,} without.")
    for (case, size), m in mem.items():
        ratio = m["isplat"]["maxrss_mb"] / m["vtk"]["maxrss_mb"]
        L.append(f"- Peak memory ({case}, {size} px, one frame in a process of its own, peak resident set (VmHWM), interpreter and "
                 f"libraries included): isplat {m['isplat']['maxrss_mb']:.0f} MB, VTK {m['vtk']['maxrss_mb']:.0f} MB "
                 f"({ratio:.2f}x).")
    if proc:
        L.append(f"- One frame as a process (`isplat render` to a PNG against a minimal VTK script, median of "
                 f"{proc['repeats']} each, interleaved; both with Python's bytecode cache, as a package installed by "
                 f"pip has it, although this machine sets PYTHONDONTWRITEBYTECODE): isplat {proc['isplat']:.2f} s, "
                 f"VTK {proc['vtk']:.2f} s "
                 f"({proc['isplat'] / proc['vtk']:.2f}x), with numba's cache present; the first isplat run on a "
                 "machine (an empty numba cache, with and without the kernels prebuilt by `make prebuilt`) is "
                 "measured in docs/startup.md (`python -m benchmarks startup`, \"Cold\").")
    better = [r for r in results if _pt(r, "isplat defaults")["err"]["rmse"] < _pt(r, "VTK 1")["err"]["rmse"]]
    L.append(f"- Image error against reference (a): isplat's defaults are closer than VTK at step 1 in {len(better)} "
             f"of {len(results)} cases (" + "; ".join(
                 f"{r['case']} {r['size']} px: PSNR {_psnr(_pt(r, 'isplat defaults')['err'])} against "
                 f"{_psnr(_pt(r, 'VTK 1')['err'])} dB" for r in results) + ").")
    pre = [r for r in results if _pt(r, "isplat pre")["err"]["rmse"] < _pt(r, "VTK 1")["err"]["rmse"]]
    gain = [_pt(r, "isplat pre")["err"]["rmse"] / _pt(r, "isplat defaults")["err"]["rmse"] for r in results]
    spread_v = max(_pt(r, "VTK 1")["err"]["rmse"] / _pt(r, "VTK 0.25")["err"]["rmse"] for r in results)
    L.append(f"- Where the error comes from: the pre-classified splatting of the paper (*pre* rows, isplat's "
             f"default before scene version 4) is closer than VTK at step 1 in {len(pre)} of {len(results)} cases; "
             f"its RMSE is {min(gain):.1f}-{max(gain):.1f}x that of the post-classified default, the blur of sharp "
             "transfer-function edges by classifying before reconstructing (docs/accuracy.md). VTK's RMSE at step 1 "
             f"is at most {spread_v:.2f}x its RMSE at step 0.25, so its error is not mostly its step: rounding to "
             "an 8-bit image accounts for about 0.0011 (1 / (255 sqrt 12), uniform rounding); the rest is its "
             "fixed-point pipeline (classification looked up at an integer code, fixed-point compositing, its "
             "gradient table when shaded), which this benchmark does not separate.")
    return L


def load_text(results) -> list[str]:
    """The section's part under load (``--load``): each renderer's frame time quiet and with another process
    spinning on one core, from the same rounds."""
    rows = [r for r in results if r.get("load")]
    if not rows:
        return []
    L = ["#### Under load: another process on one core", "",
         "Run with `--load`: in every round the renderers below also draw their frames while a child process "
         f"(`python -c \"{BUSY}\"`, started and killed by the benchmark) spins on one of the cores, the quiet "
         "and the loaded frames in turn (quiet first in even rounds, loaded first in odd ones); each loaded frame "
         "timed right after an untimed one of its own. *loaded / quiet*: the median of the per-round ratios. Both "
         "renderers use all cores (isplat: threads taking the next band of image rows when free; VTK: its "
         "thread count), so both lose the core taken.", "",
         "| case | pixels | renderer | quiet ms | loaded ms | loaded / quiet |", "|---|---:|---|---:|---:|---:|"]
    for r in rows:
        for lab in LOAD_POINTS:
            x = r["load"][lab]
            L.append(f"| {r['case']} | {r['size']} | {_who(lab)} | {x['quiet']:.1f} | {x['loaded']:.1f} | "
                     f"{x['loss']:.2f} |")
    L += [""]
    more = [r for r in rows if r["load"]["isplat defaults"]["loss"] > r["load"]["VTK 1"]["loss"]]
    L.append(f"- isplat's default (post) loses more than VTK at step 1 under load in {len(more)} of {len(rows)} "
             "cases; isplat post / VTK 1, quiet -> loaded: " + "; ".join(
                 f"{r['case']} {r['size']} px {r['load']['ratio']['quiet']:.2f} -> {r['load']['ratio']['loaded']:.2f}"
                 for r in rows) + ".")
    return L + [""]


def body(results, mem, proc, command, window_cls, vtk_ver, frames, out_dir, quick) -> str:
    from isplat.scene_schema import SCENE_VERSION, RenderOptions, defaults

    fill_et = defaults(RenderOptions)["early_termination"]
    L = ["### Side by side with VTK's CPU ray caster, both against the truth", "", "```", command, "```", "",
         f"Machine: {_doc.machine_line()}; isplat {_doc.git_rev()}; VTK {vtk_ver} "
         f"(`vtkFixedPointVolumeRayCastMapper`, offscreen through `{window_cls}`). Generated: every number and "
         "sentence below comes from this run; rerun the command after changing the renderer.", "",
         f"Orthographic, emission-absorption (unshaded but for the shaded cases: Phong with the scene's light and "
         "material, VTK `ShadeOn` with the same, see below), black background, square images. Per case and size every "
         f"renderer draws {frames} timed frames after {WARMUP} warm-up frames, all in turn, round after round, in one "
         "process (interleaved), each timed frame right after one of the same renderer and settings (as in a run "
         "of frames: an orbit, a transfer-function edit); times are medians, and *isplat / VTK* is the median of "
         "the per-round ratios (frames of a round run back to back, so the ratio is less sensitive to other load "
         "on this shared machine than the absolute times). *cold*: the same ratio for the first frame of each "
         "pair, which finds the caches as the other renderer's frames left them (each renderer's data pushed out "
         "by the other's), a use neither renderer has on its own. isplat: `Renderer.render_view` (loading not "
         f"timed), threads = all cores, at the defaults of scene version {SCENE_VERSION} (a pixel that reaches "
         f"`early_termination = {fill_et:g}` filled with its last sample's colour, docs/termination.md; the engine's "
         "file sets 0.98); VTK: `renderWindow.Render()` with the same thread count. Error: RMSE and "
         "PSNR over RGB in [0, 1] against "
         "reference (a) (docs/reference.md: the converged float64 ray integral of the same 8-bit densities, "
         "trilinear, transfer function after interpolation, step 0.05 voxel), which is neither renderer; VTK's "
         "image is read back as 8 bits.", "",
         "| case | pixels | isplat post (its default) ms | VTK step 1 ms | post / VTK 1 | post / VTK 1, cold | "
         "VTK step 0.5 ms | post / VTK 0.5 | isplat pre (the paper's) ms | pre / VTK 1 | PSNR (a) post | PSNR (a) pre | "
         "PSNR (a) VTK 1 | PSNR (a) VTK 0.5 | PSNR post vs VTK 1 |",
         "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in results:
        i, v1, v05, pre = _pt(r, "isplat defaults"), _pt(r, "VTK 1"), _pt(r, "VTK 0.5"), _pt(r, "isplat pre")
        cold, pre_r = r["paired"].get("VTK 1, cold"), r["paired"].get("pre / VTK 1")
        L.append(f"| {r['case']} | {r['size']} | {i['ms']:.1f} | {v1['ms']:.1f} | {r['paired']['VTK 1']:.2f} | "
                 f"{'' if cold is None else f'{cold:.2f}'} | {v05['ms']:.1f} | {r['paired']['VTK 0.5']:.2f} | "
                 f"{pre['ms']:.1f} | {'' if pre_r is None else f'{pre_r:.2f}'} | {_psnr(i['err'])} | "
                 f"{_psnr(pre['err'])} | {_psnr(v1['err'])} | {_psnr(v05['err'])} | {_psnr(r['between'])} |")
    L += ["", "#### Where isplat is slower, and why", ""] + slower_text(results, mem, proc) + [""]
    L += load_text(results)
    L += ["#### Every point", "",
          "isplat at its defaults (post-classified) and `early_termination = 0.95`, and the paper's pre-classified "
          "splatting (`classification = \"pre\"`, at the default `footprint_radius = 2.5` and at 2), VTK at "
          "sample distances " + ", ".join(f"{s:g}" for s in VTK_STEPS) + " voxel. `peers.csv` has the same "
          "rows with max error and the share of changed 8-bit pixels.", "",
          "| case | pixels | renderer | ms | RMSE (a) | PSNR (a) dB |", "|---|---:|---|---:|---:|---:|"]
    for r in results:
        for p in r["points"]:
            e = p["err"]
            rmse = "" if e is None else f"{e['rmse']:.4f}"
            psnr = "" if e is None else _psnr(e)
            L.append(f"| {r['case']} | {r['size']} | {_who(p['who'])} | {p['ms']:.1f} | {rmse} | {psnr} |")
    L += ["", "![error against time](img/peers_pareto.png)", "",
          "`img/peers_pareto.png`: RMSE against reference (a) over median frame time, both renderers' points, one "
          "panel per case at 512 pixels.", "", "Cases:", ""]
    for name, c in CASES.items():
        L.append(f"- **{name}**: {c[6]}" + (" (quick run: a smaller sample)" if quick else "") + ".")
    L += ["", "Threads: isplat " + ", ".join(sorted({str(r['threads'][0]) for r in results})) + ", VTK " +
          ", ".join(sorted({str(r['threads'][1]) for r in results})) + ".", "",
          "How the two are made to draw the same picture: VTK is given the augmented file's 8-bit density channel, "
          "the same spacing and voxel positions, the same colour points, the same opacity points with explicit "
          "zeros just outside the first and last (isplat's opacity is zero there; VTK would clamp), "
          "`SetScalarOpacityUnitDistance` = isplat's `unit_distance`, trilinear interpolation, one ray per pixel, a "
          "parallel camera with parallel scale = half the image height in world units, focal point `p`, view-up "
          "`v`. What is not matched is what the errors measure: VTK interpolates the density along each ray at "
          "its step, then classifies it (truncated to an integer code); isplat's default interpolates it bilinearly "
          "in each slice at the ray's crossing and classifies it with the transfer function interpolated between "
          "codes; its *pre* points classify each voxel and spread it with a Gaussian footprint. "
          "The minimal VTK script of the process-time row is generated by `benchmarks/peers.py` (`VTK_SCRIPT`): it "
          "loads the density from a .npy file, sets up the same mapper, camera and transfer function at step 1, "
          "renders once and writes a PNG."]
    return "\n".join(L)


def run(out_dir: Path, quick: bool, required: bool = False, command: str | None = None,
        report_only: bool = False, reuse_frames: bool = False, cases=None, load: bool = False) -> Path:
    """Bench entry point (``python -m benchmarks peers``); without VTK or an OpenGL context it skips with a
    note, unless ``required``. ``cases``: only these of :data:`CASES` (no memory or process rows; its own
    results file)."""
    out_dir = Path(out_dir)
    doc = out_dir / "performance.md"
    try:
        ver = vtk_version()
        cls = offscreen_window_class()
    except PeerUnavailable as exc:
        if required:
            raise
        print(f"[peers] skipped: {exc}", file=sys.stderr)
        return doc
    os.environ["VTK_DEFAULT_OPENGL_WINDOW"] = cls
    out_dir.mkdir(parents=True, exist_ok=True)
    command = command or ("python -m benchmarks peers" + (" --quick" if quick else ""))
    raw = REPO / "out" / "bench-peers" / f"results{'-quick' if quick else ''}{'-some' if cases else ''}.json"
    if report_only:                     # rewrite the page from the last run's measurements (no new numbers)
        d = json.loads(raw.read_text())
        write_csv(d["results"], out_dir / "peers.csv")
        plot(d["results"], out_dir / "img" / "peers_pareto.png")
        mem = {tuple(k.split("|")): v for k, v in d["mem"].items()}
        mem = {(k[0], int(k[1])): v for k, v in mem.items()}
        _doc.update_section(doc, SECTION, body(d["results"], mem, d["proc"], command, cls, ver, d["frames"],
                                               out_dir, quick), title="Performance")
        return _doc.put_stamp(doc, _doc.stamp(SECTION, command + " --report-only", TECHNIQUES, SOURCES,
                                              commit=d.get("commit")), SECTION)
    t0 = time.time()
    frames = 2 if quick else 7
    results = []
    if reuse_frames:                     # keep the last run's frame measurements, measure memory and processes again
        d = json.loads(raw.read_text())
        results, frames = d["results"], d["frames"]
        for r in results:
            r["points"] = [p for p in r["points"] if p["err"] is not None]
    for name, c in ({} if reuse_frames else {k: v for k, v in CASES.items() if not cases or k in cases}).items():
        for size in (c[5] if quick else c[4]):
            print(f"[peers] {name} at {size} px", file=sys.stderr, flush=True)
            r = measure(name, size, frames, quick, load)
            results.append(r)
            took = "cached" if r["ref_cached"] else f"{r['ref_seconds']:.0f} s"
            print(f"[peers]   isplat {_pt(r, 'isplat defaults')['ms']:.1f} ms, VTK 1: {_pt(r, 'VTK 1')['ms']:.1f} ms "
                  f"(x{r['paired']['VTK 1']:.2f}); reference {took}", file=sys.stderr, flush=True)
    mem = {}
    for name, size in ([] if cases else [("head opaque", 48)] if quick else
                       [("head opaque", 512), ("hidden material", 512)]):
        print(f"[peers] peak memory: {name} {size} px", file=sys.stderr, flush=True)
        mem[(name, size)] = measure_memory(name, size, quick)
    if not cases:
        print("[peers] one frame as a process", file=sys.stderr, flush=True)
    proc = None if cases else measure_process("head opaque", 48 if quick else 512, quick, 1 if quick else 5)
    raw.parent.mkdir(parents=True, exist_ok=True)
    raw.write_text(json.dumps(dict(results=results, mem={f"{k[0]}|{k[1]}": v for k, v in mem.items()}, proc=proc,
                                   frames=frames, commit=_doc.git_rev()), default=float))
    write_csv(results, out_dir / "peers.csv")
    plot(results, out_dir / "img" / "peers_pareto.png")
    print(f"[peers] done in {time.time() - t0:.0f} s", file=sys.stderr)
    _doc.update_section(doc, SECTION, body(results, mem, proc, command, cls, ver, frames, out_dir, quick),
                        title="Performance")
    return _doc.put_stamp(doc, _doc.stamp(SECTION, command, TECHNIQUES, SOURCES), SECTION)


def _make_command(args: list[str]) -> str:
    """The stamp's rerun command: ``make bench-peers PEERS='...'`` runnable as it stands (docs_check runs it), what
    make runs in the remark in parentheses, which docs_check's ``runnable`` drops."""
    peers = " ".join(args)
    return ("make bench-peers" + (f" PEERS={shlex.quote(peers)}" if args else "") +
            f" (= pip install vtk; python -m benchmarks.peers {peers})".replace(" )", ")"))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.peers", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="docs", type=Path, help="folder of performance.md (images under OUT/img)")
    ap.add_argument("--quick", action="store_true", help="tiny volumes and images, 2 frames (a smoke test)")
    ap.add_argument("--report-only", action="store_true",
                    help="rewrite the section from the last run's measurements (out/bench-peers/results.json)")
    ap.add_argument("--reuse-frames", action="store_true",
                    help="keep the last run's frame times and errors; measure memory and process times again")
    ap.add_argument("--mip-only", action="store_true",
                    help="only the maximum-intensity projection against VTK's (benchmarks/peers_mip.py, docs/mip.md)")
    ap.add_argument("--cases", default=None, help="only these cases, comma-separated (with --mip-only: the MIP "
                    "cases, head,head-512); without --mip-only no memory or process rows and no MIP page")
    ap.add_argument("--load", action="store_true",
                    help="also time isplat and VTK with another process spinning on one core (in turn with the "
                         "quiet frames, same rounds)")
    ap.add_argument("--memory-child", nargs=3, metavar=("WHO", "CASE", "SIZE"), help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.memory_child:
        who, name, size = a.memory_child
        if who == "vtk":
            os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", offscreen_window_class())
        print(json.dumps(memory_child(who, name, int(size), a.quick)))
        return 0
    cmd = _make_command((["--quick"] if a.quick else []) + (["--load"] if a.load else []))   # (both pages' stamp:
    try:                                                                     # one rerun command for both)
        if not a.mip_only:
            some = a.cases.split(",") if a.cases else None
            path = run(a.out, a.quick, required=True, command=_make_command(
                           (["--quick"] if a.quick else []) + (["--cases", a.cases] if some else []) +
                           (["--load"] if a.load else [])), report_only=a.report_only, reuse_frames=a.reuse_frames,
                       cases=some, load=a.load)
            print(f"[peers] wrote {path}", file=sys.stderr)
        if not (a.report_only or a.reuse_frames or (a.cases and not a.mip_only)):        # the MIP page: benchmarks/peers_mip.py
            from . import peers_mip

            cases = a.cases.split(",") if a.cases else None
            path = peers_mip.run(a.out, a.quick, cases, None if a.mip_only else cmd)
    except PeerUnavailable as exc:
        print(f"benchmarks.peers: error: {exc}", file=sys.stderr)
        return 3
    print(f"[peers] wrote {path}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
