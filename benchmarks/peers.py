"""Side by side with what users would pick instead: isplat against VTK's CPU ray caster.

``python -m benchmarks.peers [--out docs] [--quick] [--data DIR]`` (``make bench-peers``, which first runs
``pip install vtk``) renders the same volumes, transfer functions, lights, views and image size with
``vtkFixedPointVolumeRayCastMapper`` (offscreen) and with isplat, timing both in one process, interleaved,
and writes the section ``peers`` of ``performance.md`` plus ``img/peers_<case>.png`` (isplat left, VTK right).

Not part of ``make test`` or CI: VTK is a large optional download and needs an OpenGL context even for its
CPU mapper (Mesa's EGL or OSMesa; see :func:`offscreen_window_class`). Under ``python -m benchmarks all``
the benchmark is skipped with a note when VTK is not installed or no context can be made; run on its own it
fails with a message naming the Debian packages.

How the semantics are matched (the point of the comparison is the same picture, not a similar one):

* data: VTK gets the augmented file's 8-bit ``density`` channel (what isplat classifies), the same spacing,
  and the voxel positions of :func:`isplat.camera.volume_geometry` (origin ``q``; rotated axes via the
  volume's user matrix);
* opacity: the same points, with explicit zero points just outside the first and last (isplat's opacity is
  zero there, VTK clamps to the end values), ``SetScalarOpacityUnitDistance(unit_distance)`` so both apply
  ``1 - (1 - a) ** (ds / unit_distance)``; colour: the same points (both clamp beyond the ends);
* shading: isplat's two-sided Phong is ``ambient + diffuse |n.l| + specular |n.h|^shininess`` with lights
  in camera space. VTK's shader (vtkEncodedGradientShader) flips n towards the viewer and lights only
  ``n.l > 0``; so each isplat light becomes a VTK scene light in the same world direction plus a mirror light
  (``-l``, diffuse only), which makes the diffuse term exactly ``|n.l|``; the specular term then equals
  ``|n.h|^s`` wherever it is not below ~1e-8. The ambient term is carried by the first light only (VTK adds
  ``ambient * intensity * ambient colour`` once per light);
* camera: parallel projection, parallel scale = half the image height in world units (the bounding-sphere
  radius / zoom for a square image, :func:`isplat.camera.view_frame`), focal point ``p``, position
  ``p + 3 R w``, view-up ``v``; black background;
* VTK samples at 0.5 voxel (``SAMPLE_DISTANCE`` x the smallest spacing), trilinear interpolation, one ray per
  pixel, automatic sample-distance adjustment off.

What cannot be matched (it is what makes the two methods differ): VTK interpolates the density and then
classifies and shades (post-classification, gradients from its own central differences of the 8-bit
density); isplat classifies each voxel and spreads it with a Gaussian footprint (pre-classification, the
augmented file's normals). The images are compared over RGB in [0, 1] after both are rounded to 8 bits (VTK's
image comes from an 8-bit framebuffer).
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from isplat.augfile import open_augmented
from isplat.threads import default_threads

from . import _doc


def _unit(renderer) -> float:
    """The opacity unit distance the renderer uses: the scene's, else the smallest spacing."""
    return float(renderer.selection.unit_distance or renderer.geom.spacing.min())

SECTION = "peers"
REPO = Path(__file__).resolve().parents[1]
SAMPLE_DISTANCE = 0.5        # VTK's ray step, in units of the smallest voxel spacing
SIZE = 256
REPEATS = 21                 # timed frames per renderer (after the warm-up), interleaved
WARMUP = 2

# case -> (example scene, overrides making it a 256x256 orthographic view on black)
CASES = {
    "head": ("examples/head.toml", []),
    "engine": ("examples/engine.toml", ["camera.projection=orthographic", "image.background=[0.0, 0.0, 0.0]"]),
}
CASE_NOTES = {
    "head": "bone, opaque (examples/head.toml)",
    "engine": "semi-transparent aluminium, liners, bolts (examples/engine.toml, orthographic, black background)",
}

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
    """vtkFixedPointVolumeRayCastMapper set up to draw view ``view_index`` of an isplat Renderer."""

    def __init__(self, renderer, view_index: int = 0):
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
        if frame.projection != "orthographic":
            raise ValueError("peers bench: only orthographic views are matched")
        # data: the same 8-bit density codes, spacing and voxel positions
        dens = np.ascontiguousarray(open_augmented(scene.data.augmented).read("density"), dtype=np.uint8)
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
        prop.SetScalarOpacityUnitDistance(_unit(renderer))
        prop.SetInterpolationTypeToLinear()
        sh = scene.shading
        if renderer.selection.use_shade:
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
        self.sample_distance = SAMPLE_DISTANCE * float(geom.spacing.min())
        mapper.SetSampleDistance(self.sample_distance)
        mapper.SetInteractiveSampleDistance(self.sample_distance)
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
        if renderer.selection.use_shade and not ambient_done:     # no lit light: ambient only, through a dark light
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


# ---- data ---------------------------------------------------------------------------------------------------
def ensure_data(data_dir: Path, names) -> dict:
    """``isplat sample NAME``, ``augment``, ``index`` into ``data_dir``, reusing files already there."""
    data_dir.mkdir(parents=True, exist_ok=True)
    out = {}
    for name in names:
        npy, aug, idx = (data_dir / f"{name}{ext}" for ext in (".npy", ".aug.h5", ".idx.h5"))
        steps = []
        if not aug.exists():
            steps += [["sample", name, "-o", str(npy), "--force"], ["augment", str(npy), "-o", str(aug), "--force"]]
        if not aug.exists() or not idx.exists():
            steps += [["index", str(aug), "-o", str(idx), "--force"]]
        for s in steps:
            print(f"[peers] isplat {' '.join(s)}", file=sys.stderr)
            subprocess.run([sys.executable, "-m", "isplat", *s, "-q"], check=True, stdout=subprocess.DEVNULL)
        if npy.exists() and aug.exists():
            npy.unlink()
        out[name] = (aug, idx)
    return out


def scene_for(case: str, aug: Path, idx: Path, size: int):
    from isplat.scene import load_scene

    path, extra = CASES[case]
    ov = [f'data.augmented="{aug.resolve()}"', f'data.index="{idx.resolve()}"',
          f"image.width={size}", f"image.height={size}", *extra]
    return load_scene(REPO / path, ov), ov


# ---- measuring ----------------------------------------------------------------------------------------------
def to8(rgb_float) -> np.ndarray:
    return np.round(np.clip(rgb_float, 0.0, 1.0) * 255.0).astype(np.uint8)


def compare(a8: np.ndarray, b8: np.ndarray) -> tuple[float, float, float]:
    """RMSE and PSNR (dB, peak 1) over RGB in [0, 1], and the largest channel difference."""
    d = a8.astype(np.float64) / 255.0 - b8.astype(np.float64) / 255.0
    rmse = float(np.sqrt(np.mean(d * d)))
    psnr = float("inf") if rmse == 0 else 20.0 * np.log10(1.0 / rmse)
    return rmse, psnr, float(np.abs(d).max())


def _dilate(m: np.ndarray, n: int) -> np.ndarray:
    """Grow a mask by ``n`` pixels (4-neighbourhood), not wrapping around the edges."""
    m = m.copy()
    for _ in range(n):
        g = m.copy()
        g[1:] |= m[:-1]
        g[:-1] |= m[1:]
        g[:, 1:] |= m[:, :-1]
        g[:, :-1] |= m[:, 1:]
        m = g
    return m


def measure_case(case: str, aug: Path, idx: Path, repeats: int, size: int, img_dir: Path | None):
    from isplat.renderer import Renderer

    scene, overrides = scene_for(case, aug, idx, size)
    r_idx = Renderer(scene)                      # the scene's defaults: method indexed, threads = all cores
    r_full = Renderer(scene, method="full")
    vtkv = VTKView(r_idx, 0)

    def isplat_frame(r):
        t = time.perf_counter()
        rgba, stats = r.render_view(0)
        return time.perf_counter() - t, rgba, stats

    for _ in range(WARMUP):                      # JIT, caches, VTK's gradient computation
        isplat_frame(r_idx)
        isplat_frame(r_full)
        vtkv.render()
    times = {"indexed": [], "full": [], "vtk": []}
    order = ["indexed", "full", "vtk"]
    for rep in range(repeats):
        for who in order[rep % 3:] + order[:rep % 3]:    # interleaved, rotating who goes first
            if who == "vtk":
                times["vtk"].append(vtkv.render())
            else:
                dt, rgba, stats = isplat_frame(r_idx if who == "indexed" else r_full)
                times[who].append(dt)
                if who == "indexed":
                    ours, ours_stats = rgba, stats
    theirs = vtkv.image()
    ours8 = to8(ours[..., :3])
    rmse, psnr, maxd = compare(ours8, theirs)
    # a camera mismatch shows as a much better fit one pixel off: report the best neighbour shift too
    best = min(((compare(ours8[1:-1, 1:-1], theirs[1 + dy:size - 1 + dy, 1 + dx:size - 1 + dx])[0], (dx, dy))
                for dy in (-1, 0, 1) for dx in (-1, 0, 1)))
    m_ours, m_theirs = ours8.max(axis=2) > 2, theirs.max(axis=2) > 2
    cov_ours, cov_theirs = float(m_ours.mean()), float(m_theirs.mean())
    # where the error is: a band 2 pixels either side of either image's silhouette, against the rest
    band = (_dilate(m_ours, 2) & _dilate(~m_ours, 2)) | (_dilate(m_theirs, 2) & _dilate(~m_theirs, 2))
    se = ((ours8.astype(np.float64) - theirs) / 255.0) ** 2
    se = se.sum(axis=2)
    band_share = float(se[band].sum() / max(se.sum(), 1e-300))
    rmse_rest = float(np.sqrt(se[~band].sum() / (3 * max(1, int((~band).sum())))))
    # sensitivity: how much of the difference the VTK ray step and the mirror lights account for
    sens = {}
    for step in (0.25, 1.0):
        vtkv.mapper.SetSampleDistance(step * float(r_idx.geom.spacing.min()))
        vtkv.render()
        sens[f"VTK step {step:g} voxel"] = compare(ours8, vtkv.image())[0]
    vtkv.mapper.SetSampleDistance(vtkv.sample_distance)
    if vtkv.mirror_lights:
        for light in vtkv.mirror_lights:
            light.SwitchOff()
        vtkv.render()
        sens["VTK without the mirror lights (plain two-sided lighting)"] = compare(ours8, vtkv.image())[0]
        for light in vtkv.mirror_lights:
            light.SwitchOn()
    png = None
    if img_dir is not None:
        import imageio.v3 as iio

        img_dir.mkdir(parents=True, exist_ok=True)
        png = img_dir / f"peers_{case}.png"
        iio.imwrite(png, np.concatenate([ours8, theirs], axis=1))
    # paired: the ratio within each round, whose frames ran back to back, then the median over rounds
    paired = statistics.median(a / b for a, b in zip(times["indexed"], times["vtk"]))
    return dict(case=case, overrides=overrides, ms={k: _doc.median_ms(v) for k, v in times.items()},
                paired=paired, sensitivity=sens,
                spread={k: (1000 * min(v), 1000 * max(v)) for k, v in times.items()},
                rmse=rmse, psnr=psnr, maxd=maxd, best_shift=best,
                band=(float(band.mean()), band_share, rmse_rest), coverage=(cov_ours, cov_theirs), png=png,
                threads=(r_idx.scene.render.threads or default_threads(), vtkv.threads), sample_distance=vtkv.sample_distance,
                splatted=ours_stats.voxels_splatted, axis=ours_stats.axis, unit=_unit(r_idx))


# ---- the report ---------------------------------------------------------------------------------------------
def _body(results, command, window_cls, vtk_ver, repeats, out_dir: Path) -> str:
    L = [f"### Side by side with VTK's CPU ray caster", "", "```", command, "```", "",
         f"Machine: {_doc.machine_line()}; isplat {_doc.git_rev()}; VTK {vtk_ver} "
         f"(`vtkFixedPointVolumeRayCastMapper`, offscreen through `{window_cls}`).", "",
         f"One {SIZE}x{SIZE} orthographic frame per renderer, both in one process, interleaved (rotating order); "
         f"median of {repeats} frames after {WARMUP} warm-up frames each, min-max in brackets. isplat: "
         "`Renderer.render_view` with the scene's defaults (method `indexed`, all cores), loading not timed; "
         "`full` visits every voxel, for context. VTK: `renderWindow.Render()`. Image difference: RMSE and PSNR "
         "over RGB in [0, 1], both images rounded to 8 bits. The time ratio is isplat indexed over VTK "
         "(above 1: isplat is slower): of the medians, and in brackets the median of the per-round ratios "
         "(frames of one round run back to back, so this one is less sensitive to other load on the machine: "
         "on a shared machine the absolute times of two runs can differ by up to 2x, the ratios much less).", "",
         "| case | isplat indexed ms | isplat full ms | VTK ms | time isplat / VTK (paired) | RMSE | PSNR dB "
         "| max diff |",
         "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for r in results:
        ms, sp = r["ms"], r["spread"]
        L.append(f"| {r['case']} | {ms['indexed']:.1f} [{sp['indexed'][0]:.1f}-{sp['indexed'][1]:.1f}] "
                 f"| {ms['full']:.1f} [{sp['full'][0]:.1f}-{sp['full'][1]:.1f}] "
                 f"| {ms['vtk']:.1f} [{sp['vtk'][0]:.1f}-{sp['vtk'][1]:.1f}] "
                 f"| {ms['indexed'] / ms['vtk']:.2f} ({r['paired']:.2f}) "
                 f"| {r['rmse']:.4f} | {r['psnr']:.1f} | {r['maxd']:.3f} |")
    L.append("")
    for r in results:
        rel = os.path.relpath(r["png"], out_dir) if r["png"] else None
        sh = r["best_shift"]
        L += [f"**{r['case']}**: {CASE_NOTES[r['case']]}; overrides `" + "`, `".join(
                  o for o in r["overrides"] if not o.startswith("data.")) + "`. "
              f"Threads: isplat {r['threads'][0]}, VTK {r['threads'][1]}. isplat splatted "
              f"{r['splatted']:,} voxels (slices along {r['axis']}). Pixels not black: isplat "
              f"{100 * r['coverage'][0]:.1f} %, VTK {100 * r['coverage'][1]:.1f} %. "
              f"{100 * r['band'][1]:.0f} % of the squared error lies within 2 pixels of a silhouette "
              f"({100 * r['band'][0]:.1f} % of the pixels); elsewhere the RMSE is {r['band'][2]:.4f}. "
              f"The best one-pixel shift is (dx, dy) = {sh[1]}, RMSE {sh[0]:.4f} "
              "(a camera mismatch would show as a shift that fits better). RMSE with one setting changed: "
              + "; ".join(f"{k} {v:.4f}" for k, v in r["sensitivity"].items()) + ".", ""]
        if rel:
            L += [f"![{r['case']}: isplat left, VTK right]({rel})", ""]
    sd = results[0]["sample_distance"] if results else SAMPLE_DISTANCE
    L += ["How the two are made to draw the same picture: VTK is given the augmented file's 8-bit density "
          "channel (the codes isplat classifies), the same spacing and voxel positions, the same colour points, the "
          "same opacity points with explicit zeros just outside the first and last (isplat's opacity is zero "
          "there; VTK would clamp), `SetScalarOpacityUnitDistance` = isplat's `unit_distance` (both correct "
          "opacity as `1 - (1 - a)^(ds / unit_distance)`), trilinear interpolation, a ray step of "
          f"{sd:g} world units ({SAMPLE_DISTANCE:g} voxel), one ray per pixel, a parallel camera with parallel "
          "scale = half the image height in world units (the bounding-sphere radius / zoom), focal point `p`, "
          "view-up `v`, and a black background. Shading: each isplat light becomes a VTK scene light in the same "
          "world direction plus a mirror light (diffuse only), because VTK's two-sided lighting flips the normal "
          "towards the viewer and lights only `n.l > 0`; the pair gives isplat's `diffuse |n.l|` exactly and "
          "`specular |n.h|^shininess` wherever that term exceeds ~1e-8. The ambient term rides on the first light "
          "only (VTK adds it once per light).", "",
          "What is not matched, and is what the RMSE measures: VTK interpolates the density, then classifies "
          "(post-classification) and shades with normals from its own central differences of the 8-bit "
          "density, quantised to its direction table, and looks the interpolated density up truncated to an "
          "integer code; isplat classifies each voxel and spreads it with a Gaussian footprint "
          "(sigma 0.7 voxel: pre-classification, slightly softer edges) with the augmented file's normals. Both "
          "stop a ray near full opacity (isplat at the scene's `early_termination`, VTK at its fixed-point "
          "limit). The differences concentrate on silhouettes and thin features, where one method's edge falls "
          "half a voxel from the other's."]
    return "\n".join(L)


def run(out_dir: Path, quick: bool, required: bool = False, data_dir: Path | None = None,
        command: str | None = None) -> Path:
    """Bench entry point (``python -m benchmarks peers``); without VTK or an OpenGL context it skips with a
    note, unless ``required``."""
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
    repeats = 3 if quick else REPEATS
    data_dir = Path(data_dir) if data_dir else REPO / "out" / "bench-peers"
    files = ensure_data(data_dir, CASES)
    results = []
    for case in CASES:
        aug, idx = files[case]
        print(f"[peers] {case}: {repeats} interleaved frames each", file=sys.stderr)
        results.append(measure_case(case, aug, idx, repeats, SIZE, out_dir / "img"))
        r = results[-1]
        print(f"[peers] {case}: isplat {r['ms']['indexed']:.1f} ms (full {r['ms']['full']:.1f}), "
              f"VTK {r['ms']['vtk']:.1f} ms; RMSE {r['rmse']:.4f}, PSNR {r['psnr']:.1f} dB", file=sys.stderr)
    command = command or ("python -m benchmarks peers" + (" --quick" if quick else ""))
    return _doc.update_section(doc, SECTION, _body(results, command, cls, ver, repeats, out_dir),
                               title="Performance")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.peers", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="docs", type=Path, help="folder of performance.md (images under OUT/img)")
    ap.add_argument("--quick", action="store_true", help="3 frames instead of 21 (a smoke test)")
    ap.add_argument("--data", type=Path, help="folder for the sample volumes (default out/bench-peers; reused)")
    a = ap.parse_args(argv)
    cmd = "make bench-peers   # = pip install vtk; python -m benchmarks.peers" + (" --quick" if a.quick else "")
    try:
        path = run(a.out, a.quick, required=True, data_dir=a.data, command=cmd)
    except PeerUnavailable as exc:
        print(f"benchmarks.peers: error: {exc}", file=sys.stderr)
        return 3
    print(f"[peers] wrote {path}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
