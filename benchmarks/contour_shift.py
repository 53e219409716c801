"""A prototype, outside the renderer: contour-shift (shape-based) interpolation between thick slices, against the
Catmull-Rom cubic the post-classified technique uses (isplat/splat/post.py ``_density_at``).

``python -m benchmarks.contour_shift [--size N]`` prints one Markdown table (no page: a prototype measured, not a
feature; docs/thick-slices.md has the shipped reconstruction).

Between thick slices k and k + 1 (7 mm, the ``mr-head`` sample of benchmarks/thick.py), a contour of slice k
that lies at in-slice point x lies near x + delta in slice k + 1, with delta = -D g / (|g|^2 + eps^2): D the
through-slice difference S[k+1] - S[k] and g the in-slice gradient (both of the two slices smoothed by a
Gaussian of ``SIGMA`` pixels; eps regularises flat regions, and |delta| is capped at ``MAX_SHIFT`` pixels). At
fraction t the density is (1 - t) S[k](x - t delta) + t S[k+1](x + (1 - t) delta): each slice sampled
(bilinearly) where the contour through x came from or goes to, so a boundary oblique to the slices moves across
the gap instead of cross-fading (a terrace). Here the thick volume is refined to 1 mm slices that way (numpy) and
rendered by isplat's default technique at 1:1 (bilinear: nothing between the refined slices to speak of), beside the
same refinement by the Catmull-Rom cubic along k (what the renderer's cubic makes at the voxel columns), by linear
interpolation (``isplat augment --thin-slices``), and the renderer's own cubic on the thick grid. Measured: the
streak measure (tests/streak_measure.py) and the image RMSE against the object (the sample made with 1 mm slices),
post-classified, shaded, side and oblique views; and the density RMSE against the object's slices, in the
sample's units, over the refined slices between the thick ones.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

from benchmarks import thick

SIGMA = 3.0          # in-slice pixels: the smoothing of D and g (the scalp is 2-4 pixels thick)
MAX_SHIFT = 6.0      # in-slice pixels: the largest contour displacement across one gap
EPS = 0.005          # times the volume's range: the gradient magnitude below which shifts fade out


def _sample2(img, y, x):
    """Bilinear ``img`` (2-D) at float coordinates (edges repeated)."""
    ny, nx = img.shape
    y = np.clip(y, 0, ny - 1)
    x = np.clip(x, 0, nx - 1)
    y0 = np.minimum(np.floor(y).astype(np.int64), ny - 2)
    x0 = np.minimum(np.floor(x).astype(np.int64), nx - 2)
    fy, fx = y - y0, x - x0
    return ((1 - fy) * ((1 - fx) * img[y0, x0] + fx * img[y0, x0 + 1])
            + fy * ((1 - fx) * img[y0 + 1, x0] + fx * img[y0 + 1, x0 + 1]))


def _displacement(s0, s1, eps):
    """delta (dy, dx) in pixels: where a contour of ``s0`` lies in ``s1`` (module docstring)."""
    blur = thick._measure().blur
    a = blur((s0 + s1) / 2.0, SIGMA)
    d = blur(s1 - s0, SIGMA)
    gy, gx = np.gradient(a)
    k = -d / (gx * gx + gy * gy + eps * eps)
    dy, dx = k * gy, k * gx
    m = np.hypot(dy, dx)
    cap = np.where(m > MAX_SHIFT, MAX_SHIFT / np.maximum(m, 1e-12), 1.0)
    return dy * cap, dx * cap


def refine(vol, f: int, how: str) -> np.ndarray:
    """``vol`` [k, j, i] with ``f - 1`` slices put between each two along k (``(n - 1) f + 1`` slices): ``how``
    "linear", "cubic" (Catmull-Rom through four slices, clamped to the volume's range), "contour" (the module
    docstring's blend of two shifted slices) or "contour-cubic" (the four slices of the cubic, slice k + j sampled
    at x + (j - t) delta, the one displacement of the gap k, k + 1 extended to its neighbours)."""
    v = np.asarray(vol, np.float64)
    n, ny, nx = v.shape
    lo, hi = float(v.min()), float(v.max())
    out = np.empty(((n - 1) * f + 1, ny, nx), np.float32)
    yy, xx = np.mgrid[0:ny, 0:nx].astype(np.float64)
    for k in range(n - 1):
        s0, s1 = v[k], v[k + 1]
        if how.startswith("contour"):
            dy, dx = _displacement(s0, s1, EPS * (hi - lo))
        for m in range(f):
            t = m / f
            if how == "linear":
                s = (1 - t) * s0 + t * s1
            elif how == "cubic":
                pm, p2 = v[max(k - 1, 0)], v[min(k + 2, n - 1)]
                s = np.clip(((2 * t**3 - 3 * t**2 + 1) * s0 + (t**3 - 2 * t**2 + t) * (s1 - pm) / 2
                             + (3 * t**2 - 2 * t**3) * s1 + (t**3 - t**2) * (p2 - s0) / 2), lo, hi)
            elif how == "contour":
                s = ((1 - t) * _sample2(s0, yy - t * dy, xx - t * dx)
                     + t * _sample2(s1, yy + (1 - t) * dy, xx + (1 - t) * dx))
            else:           # "contour-cubic": the four slices each sampled where the contour through x lies
                q = [_sample2(v[min(max(k + j, 0), n - 1)], yy + (j - t) * dy, xx + (j - t) * dx)
                     for j in (-1, 0, 1, 2)]
                s = np.clip(((2 * t**3 - 3 * t**2 + 1) * q[1] + (t**3 - 2 * t**2 + t) * (q[2] - q[0]) / 2
                             + (3 * t**2 - 2 * t**3) * q[2] + (t**3 - t**2) * (q[3] - q[1]) / 2), lo, hi)
            out[k * f + m] = s
    out[-1] = v[-1]
    return out


def measure(size: int) -> list:
    from isplat.samples import make_sample

    tag, name, shape, sp, preset, nk_obj = thick.MIP_CASE
    f = int(round(sp[2] / sp[0]))
    vol = make_sample(name, shape)[0]
    obj_vol = make_sample(name, (shape[0], shape[1], nk_obj))[0].astype(np.float64)
    c = thick.channels(vol, sp, None)
    obj = thick.channels(obj_vol.astype(vol.dtype), (1.0, 1.0, 1.0), c["window"])
    refined = {how: refine(vol, f, how) for how in ("linear", "cubic", "contour", "contour-cubic")}
    off = (nk_obj - refined["linear"].shape[0]) // 2     # the refined slices' place among the object's (centred)
    truth = obj_vol[off:off + refined["linear"].shape[0]]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        aug = Path(tmp) / "scene.aug.h5"
        thick._write_aug(aug, c["raw"], name)
        for view in thick.VIEWS:
            sc = thick.scene(aug, preset, view, size)
            ref = thick.render(sc, obj)
            phase = thick.surface_phase(sc, obj, c, thick.level(sc))
            period = max(sp) / thick.pixel_size(sc, c)
            imgs = {"renderer's cubic (thick grid)": thick.render(sc, c)}
            for how, r in refined.items():
                imgs[f"refined: {how}"] = thick.render(sc, thick.channels(r, (1.0, 1.0, 1.0), c["window"]))
            for k, img in imgs.items():
                how = k.split(": ")[-1] if k.startswith("refined") else "cubic"
                d = refined[how] - truth
                rows.append(dict(view=view, what=k, streak=thick.streak(img, phase, period),
                                 object=thick.streak(ref, phase, period), rmse=thick.rmse(img, ref),
                                 density_rmse=float(np.sqrt(np.mean(d * d)))))
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m benchmarks.contour_shift", description=__doc__.split("\n")[0])
    ap.add_argument("--size", type=int, default=thick.SIZE)
    a = ap.parse_args(argv)
    rows = measure(a.size)
    print(f"mr-head 1 x 1 x 7 mm, post-classified, shaded, {a.size} x {a.size}, orthographic (SIGMA {SIGMA}, "
          f"MAX_SHIFT {MAX_SHIFT}, EPS {EPS})\n")
    print("| view | reconstruction between slices | streak | object | image RMSE | density RMSE |")
    print("|---|---|---:|---:|---:|---:|")
    for r in rows:
        print(f"| {r['view']} | {r['what']} | {r['streak']:.4f} | {r['object']:.4f} | {r['rmse']:.4f} | "
              f"{r['density_rmse']:.1f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
