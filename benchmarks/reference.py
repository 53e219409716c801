"""References independent of splatting, cached, and how converged they are.

``python -m benchmarks reference [--out docs] [--quick]`` writes ``reference.md``: for each benchmark case the
reference at the standard step and at half of it, and what halving changes (the references' own error bound).

Two references (the integrator is ``tests/ray_reference.py``, shared with its tests the way ``tests/fuzzlab.py`` is
shared with ``benchmarks/reliability.py``; its docstring has the model):

(a) ``grid``: the converged ray integral of the augmented file's 8-bit densities, trilinear reconstruction, the
    transfer function applied to the interpolated density (post-classification), float64, step ``STEP`` = 0.05
    voxel (of the smallest spacing), shaded with isplat's lights from the gradient of the reconstructed density;
(b) ``analytic`` (Marschner-Lobb only): the same integral of the exact Marschner-Lobb function, mapped to density
    codes through the augmented file's window exactly as ``isplat augment`` maps the samples (without rounding to
    8 bits), with its exact gradient; no grid at all; step ``STEP_ANALYTIC`` = 0.01 voxel (the signal is close to
    the grid's Nyquist limit and the transfer function's ramp is crossed within a fraction of a voxel).

Images are cached under ``out/references/`` keyed by a hash of every input (density SHA-256 or Marschner-Lobb
parameters, geometry, camera frame, transfer function, shading, background, step and the integrator's source),
since a 512-pixel reference takes seconds to minutes.
"""

from __future__ import annotations

import hashlib
import inspect
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

from . import _doc

TECHNIQUES = []     # render.classification of its rows (the page's stamp)
SOURCES = _doc.sources(_doc.SAMPLES, ("isplat/augment.py", "isplat/scene.py", "examples/*.toml",
                       "tests/ray_reference.py", "benchmarks/reference.py"))

REPO = Path(__file__).resolve().parents[1]
TESTS = REPO / "tests"       # the integrator lives in tests/ray_reference.py, shared with its tests


def _rr():
    """tests/ray_reference.py (imported on first use: it compiles with numba, which a VTK-only child process of
    the peers benchmark must not load)."""
    if str(TESTS) not in sys.path:
        sys.path.insert(0, str(TESTS))
    import ray_reference

    return ray_reference

STEP = 0.05                          # voxels of the smallest spacing: reference (a)
STEP_ANALYTIC = 0.01                 # reference (b): the analytic signal is sampled without a grid, near Nyquist
STEPS = {"grid": STEP, "analytic": STEP_ANALYTIC}
CACHE = REPO / "out" / "references"
DATA = REPO / "bench-out"

ML_SCENE = """
[image]
width = 256
height = 256
background = [0.0, 0.0, 0.0]
[camera]
projection = "orthographic"
azimuth = 30
elevation = 25
zoom = 1.0
[transfer]
# the isosurface f = 0.5 of the Marschner-Lobb signal as an opaque ramp (codes ~ 255 f through the window)
opacity = [[104, 0.0], [128, 1.0], [255, 1.0]]
color = [[104, 0.85, 0.85, 0.95], [255, 0.95, 0.90, 0.80]]
unit_distance = 0.05
[shading]
ambient = 0.2
diffuse = 0.75
specular = 0.35
shininess = 30
[[shading.light]]
direction = [-0.4, 0.6, 1.0]
"""
# case -> (scene file or None for ML_SCENE, overrides, note)
CASES = {
    "head": ("examples/head.toml", [], "bone, opaque, shaded (examples/head.toml, orthographic)"),
    "engine": ("examples/engine.toml", ["camera.projection=orthographic", "image.background=[0.0, 0.0, 0.0]"],
               "semi-transparent aluminium, steel, bolts, shaded two-sided (examples/engine.toml made orthographic, "
               "black background)"),
    "marschner-lobb": (None, [], "Marschner-Lobb 41^3, the f = 0.5 isosurface as an opaque ramp (codes 104..128), "
                                 "shaded (azimuth 30, elevation 25)"),
}
QUICK_SHAPES = {"head": (64, 64, 56), "engine": (64, 64, 28), "marschner-lobb": (41, 41, 41)}


def _log(msg):
    print(f"[reference] {msg}", file=sys.stderr, flush=True)


# ---- data and scenes ---------------------------------------------------------------------------------------------
def _readable(aug: Path, idx: Path) -> bool:
    from isplat.augfile import open_augmented
    from isplat.errors import IsplatError
    from isplat.index import open_index

    try:
        open_augmented(aug)
        open_index(idx)
    except IsplatError:
        return False
    return True


def sample_data(name: str, shape=None, cache: Path = DATA) -> tuple[Path, Path]:
    """The augmented and indexed sample ``name`` (``shape`` (n_i, n_j, n_k) or its default) in ``cache``, built
    once and reused."""
    from isplat.augment import augment_array
    from isplat.samples import make_sample

    tag = name if shape is None else f"{name}-{'x'.join(map(str, shape))}"
    aug, idx = cache / f"{tag}.aug.h5", cache / f"{tag}.idx.h5"
    if aug.exists() and idx.exists() and _readable(aug, idx):
        return aug, idx
    cache.mkdir(parents=True, exist_ok=True)
    arr, sp = make_sample(name, shape)
    o = augment_array(arr, sp)
    write_pair(aug, idx, o["density"], o["gradient_magnitude"], o["normal"], o["spacing_ijk"], o["density_window"],
               o["gradient_magnitude_scale"], f"isplat sample {name}")
    return aug, idx


def write_pair(aug: Path, idx: Path, density, gradient_magnitude, normal, spacing, window, gm_scale, source: str):
    """Write the augmented file ``aug`` and its index ``idx``, both or neither (temporary names, then renamed)."""
    from isplat.augfile import write_augmented
    from isplat.index import build_index_file

    tmp_aug, tmp_idx = (p.with_name(f".{p.name}.{os.getpid()}") for p in (aug, idx))
    try:
        write_augmented(tmp_aug, density, gradient_magnitude, normal, spacing, window, gm_scale, {"source": source})
        build_index_file(tmp_aug, tmp_idx)
        os.replace(tmp_aug, aug)
        os.replace(tmp_idx, idx)
    finally:
        for p in (tmp_aug, tmp_idx):
            p.unlink(missing_ok=True)


def render_overrides(render: dict) -> list[str]:
    return [f'render.{k}="{v}"' if isinstance(v, str) else f"render.{k}={v}" for k, v in render.items()]


def make_scene(case: str, size: int, render: dict | None = None, extra=(), shape=None, data=None):
    """The scene of ``case`` at ``size`` x ``size`` on its sample (``data``: (aug, idx) to use instead), as a
    scene of the current version (that of the isplat imported: an older tree's, run by benchmarks.threadload,
    gets its own), so that its defaults are the current ones, with the case's own orbit camera
    (``camera.view = "none"``: version 5's anatomical default would turn the engine, whose file says version 4)."""
    from isplat.scene import SCENE_VERSION, load_scene, parse_scene

    path, ov0, _ = CASES[case]
    aug, idx = data or sample_data(case, shape)
    ov = [f"version={SCENE_VERSION}", 'camera.view="none"', f'data.augmented="{aug}"', f'data.index="{idx}"',
          f"image.width={size}", f"image.height={size}",
          *ov0, *extra, *render_overrides(render or {})]
    if path is None:
        return parse_scene(ML_SCENE, REPO, "marschner-lobb scene", ov)
    return load_scene(REPO / path, ov)


def ml_parameters(aug) -> tuple[float, float, float, float]:
    """(fm, alpha, lo, hi): the sample's Marschner-Lobb parameters (isplat.samples) and the file's window."""
    from isplat.samples import _marschner_lobb

    sig = inspect.signature(_marschner_lobb).parameters
    lo, hi = aug.density_window
    return float(sig["fm"].default), float(sig["alpha"].default), float(lo), float(hi)


# ---- the references, cached --------------------------------------------------------------------------------------
def _key(kind, aug, view, transfer, shading, step) -> str:
    f, g = view.frame, view.geom
    src = (TESTS / "ray_reference.py").read_bytes()
    parts = {
        "kind": kind, "data": aug.density_sha256 if kind == "grid" else ml_parameters(aug),
        "shape": list(g.shape), "spacing": g.spacing.tolist(), "q": g.q.tolist(), "axes": g.unit_axes.tolist(),
        "frame": [f.projection, f.p.tolist(), f.u.tolist(), f.v.tolist(), f.w.tolist(),
                  None if f.e is None else f.e.tolist(), f.pixel_size, f.width, f.height],
        "background": list(view.background), "transfer": [transfer.opacity, transfer.color, transfer.unit_distance,
                                                          transfer.gradient_opacity],
        "shading": repr(shading) if shading.enabled else "off", "step": step,
        "code": hashlib.sha256(src).hexdigest(),
    }
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=repr).encode()).hexdigest()[:32]


def reference(scene, view_index: int = 0, kind: str = "grid", step: float | None = None, views=None,
              cache: Path = CACHE, threads: int | None = None):
    """Reference ``kind`` ("grid" = (a), "analytic" = (b)) of view ``view_index`` of ``scene`` (or of the camera
    ``views[view_index]``): (straight RGBA float64 (H, W, 4), seconds it took to compute (also when read from the
    cache; nan if unknown), True when read from the cache)."""
    from isplat.augfile import open_augmented
    from isplat.frame import views_for

    step = STEPS[kind] if step is None else step
    aug = open_augmented(scene.data.augmented)
    view = views_for(scene, aug, views)[view_index]
    key = _key(kind, aug, view, scene.transfer, scene.shading, step)
    path = Path(cache) / f"{kind}-{key}.npy"
    took = path.with_suffix(".seconds")
    if path.exists():
        return np.load(path), (float(took.read_text()) if took.exists() else float("nan")), True
    t0 = time.perf_counter()
    unit = scene.transfer.unit_distance or float(view.geom.spacing.min())
    if kind == "grid":
        img = _rr().render(view, scene.transfer, scene.shading, density=aug.read("density"), unit=unit, step=step,
                        threads=threads)
    elif kind == "analytic":
        img = _rr().render(view, scene.transfer, scene.shading, ml=ml_parameters(aug), unit=unit, step=step,
                        threads=threads)
    else:
        raise ValueError(f"reference kind {kind!r}: expected grid or analytic")
    dt = time.perf_counter() - t0
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".{os.getpid()}.tmp.npy")
    np.save(tmp, img)
    os.replace(tmp, path)
    took.write_text(f"{dt:.3f}\n")
    return img, dt, False


def kinds_for(case: str) -> list[str]:
    return ["grid", "analytic"] if case == "marschner-lobb" else ["grid"]


# ---- measures ------------------------------------------------------------------------------------------------------
def errors(img, ref) -> dict:
    """Error of ``img`` against ``ref`` over RGB in [0, 1]: max abs, RMSE, PSNR (peak 1) and the share of pixels
    whose 8-bit value (any channel) differs."""
    d = np.abs(np.asarray(img)[..., :3].astype(np.float64) - np.asarray(ref)[..., :3].astype(np.float64))
    rmse = float(np.sqrt(np.mean(d * d)))
    q8 = np.any(np.rint(np.asarray(img)[..., :3].astype(np.float64) * 255) !=
                np.rint(np.asarray(ref)[..., :3].astype(np.float64) * 255), -1)
    return {"max": float(d.max()), "rmse": rmse, "psnr": (float("inf") if rmse == 0 else -20 * np.log10(rmse)),
            "px8": float(q8.mean())}


def convergence(scene, kind: str, step: float | None = None) -> dict:
    """The reference at ``step`` (default: its kind's) against ``step / 2``: what halving the step changes."""
    step = STEPS[kind] if step is None else step
    a, ta, ca = reference(scene, kind=kind, step=step)
    b, tb, cb = reference(scene, kind=kind, step=step / 2)
    return dict(errors(a, b), seconds=(ta, tb), cached=(ca, cb), step=step)


# ---- page ----------------------------------------------------------------------------------------------------------
def run(out_dir: Path, quick: bool) -> Path:
    t0 = time.time()
    size = 48 if quick else 256
    rows = []
    for case in CASES:
        shape = QUICK_SHAPES[case] if quick else None
        for persp in (False, True):
            extra = ['camera.projection="perspective"'] if persp else []
            scene = make_scene(case, size, extra=extra, shape=shape)
            for kind in kinds_for(case):
                for shaded in (True, False):
                    sc = scene if shaded else make_scene(case, size, extra=extra + ["shading.enabled=false"],
                                                         shape=shape)
                    _log(f"{case} {kind} {'perspective' if persp else 'orthographic'} "
                         f"{'shaded' if shaded else 'unshaded'}")
                    rows.append(dict(case=case, kind=kind, proj="perspective" if persp else "orthographic",
                                     shaded=shaded, **convergence(sc, kind)))
    p = Path(out_dir) / "reference.md"
    p.write_text(render_doc(rows, quick, size, time.time() - t0))
    return p


def _secs(pair) -> str:
    return ", ".join("n/a" if x != x else f"{x:.1f}" for x in pair)


def render_doc(rows, quick, size, seconds) -> str:
    cmd = "python -m benchmarks reference" + (" --quick" if quick else "")
    worst = max(r["max"] for r in rows)
    L = [f"```\n{cmd}\n```\n", "# References independent of splatting, and how converged they are\n",
         f"Machine: {_doc.machine_line()}; git {_doc.git_rev()}; the page took {seconds:.0f} s (references are "
         f"cached under out/references/, so a rerun with nothing changed reads them).\n",
         (__doc__.split("\n\n", 2)[2]).strip() + "\n",
         "The integrator's model (tests/ray_reference.py): one ray per pixel centre; the ray clipped to the voxel "
         "boxes (`[-0.5, n - 0.5]` in grid coordinates, the extent isplat gives a volume; the trilinear field is "
         "clamped to its edge value in the outer half voxel) and cut into equal pieces of at most the step, each "
         "sampled at its midpoint with opacity `1 - exp(-sigma dt)`, `sigma = -ln(1 - a(d)) / unit_distance`, "
         "composited front to back in float64; a ray stops below transmittance 1e-9. A constant field is "
         "integrated exactly whatever the step (tests/test_ray_reference.py checks 1e-6 against the closed form, "
         "orthographic and perspective, eye outside and inside, for both references). VTK's extent is the hull "
         "of the voxel centres instead, half a voxel thinner on each face; that matters only where material "
         "touches the volume's faces (the Marschner-Lobb signal does, the head's bone and the engine do not).\n",
         f"## Convergence: halving the step ({STEP:g} -> {STEP / 2:g} voxel for (a), {STEP_ANALYTIC:g} -> "
         f"{STEP_ANALYTIC / 2:g} for (b))\n",
         f"Each case at {size}x{size}; errors over RGB in [0, 1] between the reference at its step and at half of it "
         "(the same measures the benchmarks report: max abs, RMSE, PSNR, share of pixels whose 8-bit value "
         "changes). Seconds: what the two renders took to compute on this machine (2 threads; a rerun reads them "
         "from the cache), n/a when not recorded.\n",
         "| case | reference | projection | shading | step (voxel) | max abs | RMSE | PSNR dB | 8-bit px changed "
         "| seconds (step, half) |", "|---|---|---|---|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        L.append(f"| {r['case']} | {'(a) grid' if r['kind'] == 'grid' else '(b) analytic'} | {r['proj']} | "
                 f"{'on' if r['shaded'] else 'off'} | {r['step']:g} | {r['max']:.2e} | {r['rmse']:.2e} | "
                 f"{r['psnr']:.1f} | {100 * r['px8']:.3f}% | {_secs(r['seconds'])} |")
    L.append("")
    worst_rmse = max(r["rmse"] for r in rows)
    n_big = sum(r["max"] >= 0.5 / 255 for r in rows)
    L.append(f"Halving the step changes the RMSE of no case by more than {worst_rmse:.2e}; in {n_big} of "
             f"{len(rows)} cases at least one pixel moves by half an 8-bit level (1.96e-03) or more, and the largest "
             f"single-pixel change "
             f"is {worst:.2e}. So the references resolve errors in RMSE well above these figures; a max-abs error below "
             "a case's max abs here is not resolved. docs/accuracy.md quotes these figures next to its errors.\n")
    return "\n".join(L) + "\n"
