"""The streak measure of docs/thick-slices.md (benchmarks/thick.py) and tests/test_thick_slices.py: how much a
shaded picture's fine luminance depends on where the surface lies between two thick slices.

Rings, terraces and streaks of thick slices are locked to the slices; the shapes' own shading and the object's
fine detail are not. Per pixel, :func:`surface_phase` finds where the ray's first surface point lies between two
thick slices (0..1), from the object made with thin slices; :func:`streak` averages the picture's high-frequency
luminance per eighth of that phase and returns the RMS of the eight means.
"""

from __future__ import annotations

import math

import numpy as np


def blur(L, sigma: float):
    """A Gaussian blur of ``L`` (2-D), separable, edges repeated."""
    r = max(1, int(math.ceil(3 * sigma)))
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    k /= k.sum()
    for axis in (0, 1):
        pad = [(0, 0), (0, 0)]
        pad[axis] = (r, r)
        P = np.pad(L, pad, mode="edge")
        n = L.shape[axis]
        L = sum(k[m] * (P[m:m + n] if axis == 0 else P[:, m:m + n]) for m in range(2 * r + 1))
    return L


def surface_phase(vo, vt, dens, level: float | None) -> np.ndarray:
    """Per pixel, where the first surface the ray meets lies between two of the *thick* slices: the fraction
    0..1 of the slice step at the object's first point whose density code reaches ``level`` (a march through the
    object, half a voxel a step, nearest voxel), in the thick grid's slice coordinate; NaN where the ray meets
    none. ``level`` None: the point of the ray's highest density instead (the first of equals; what a maximum
    intensity projection shows), NaN where the ray misses the box. ``vo``, ``vt``: the same view (isplat.frame.views_for) of the object and of the thick data, whose
    grids are placed on the same box, centred (isplat.camera.volume_geometry); ``dens``: the object's density
    codes [k, j, i]. Orthographic views only."""
    f, g, gt = vo.frame, vo.geom, vt.geom
    H, W = f.height, f.width
    cx, cy = W / 2.0 - 0.5, H / 2.0 - 0.5
    ys, xs = np.mgrid[0:H, 0:W]
    P = (f.p[None, None] + ((xs - cx) * f.pixel_size)[..., None] * f.u[None, None]
         - ((ys - cy) * f.pixel_size)[..., None] * f.v[None, None]).reshape(-1, 3)
    d = -np.asarray(f.w, float)
    to_grid = g.unit_axes / g.spacing[:, None]
    og, dg = (P - g.q) @ to_grid.T, d @ to_grid.T
    n = np.asarray(g.n_ijk, float)
    step = 0.5 / float(np.abs(dg).max())
    # the ray's entry and exit of the box [-0.5, n - 0.5] (slab method), then the march
    with np.errstate(divide="ignore", invalid="ignore"):
        t0 = np.where(dg != 0, (-0.5 - og) / dg, -np.inf)
        t1 = np.where(dg != 0, (n - 0.5 - og) / dg, np.inf)
    lo = np.nanmax(np.minimum(t0, t1), axis=1)
    hi = np.nanmin(np.maximum(t0, t1), axis=1)
    hit = np.full(len(P), np.nan)
    best = np.full(len(P), -1)
    t = lo.copy()
    live = hi > lo
    while live.any():
        idx = np.flatnonzero(live)
        q = og[idx] + t[idx, None] * dg[None]
        ijk = np.clip(np.rint(q).astype(np.int64), 0, (n - 1).astype(np.int64))
        val = dens[ijk[:, 2], ijk[:, 1], ijk[:, 0]].astype(np.int64)
        found = val > best[idx] if level is None else val >= level
        hit[idx[found]] = t[idx[found]]
        if level is None:
            best[idx[found]] = val[found]
        else:
            live[idx[found]] = False
        t[idx] += step
        live &= t < hi
    X = g.q + (og + hit[:, None] * dg[None]) @ g.steps          # world points
    kt = (X - gt.q) @ (gt.unit_axes / gt.spacing[:, None]).T
    return (kt[:, 2] - np.floor(kt[:, 2])).reshape(H, W)


def streak(img, phase, period_px: float, bins: int = 8) -> float:
    """Streak strength: how much the picture's high-frequency luminance (luminance minus its Gaussian blur of
    sigma two slice periods in pixels) depends on where between two thick slices the surface lies
    (:func:`surface_phase`): the RMS over ``bins`` bins of that phase of the mean high-frequency luminance of
    the drawn pixels in each bin (after their overall mean). Rings and terraces are locked to the slices, so they
    make the bins differ; the shapes' own shading and the object's fine detail are not, and average out (the
    object's own value is the floor)."""
    sigma = max(1.0, 2.0 * period_px)
    L = img[..., :3].mean(-1)
    hp = L - blur(L, sigma)
    ok = (img[..., 3] > 0.5) & np.isfinite(phase)
    if ok.sum() < 20 * bins:
        return 0.0
    v, ph = hp[ok] - hp[ok].mean(), phase[ok]
    b = np.minimum((ph * bins).astype(np.int64), bins - 1)
    m = [v[b == k].mean() for k in range(bins) if (b == k).sum() >= 20]
    return float(np.sqrt(np.mean(np.square(m))))
