"""A slow, obvious reference for maximum- and minimum-intensity projection (isplat.splat.mip): per pixel, per slice.

Each pixel's own ray (the pixel centre on the image plane; from the eye in perspective), its crossing with every
slice plane of the principal axis (points nearer than the near plane left out), the cutting planes tested at the
crossing, and the bilinear density there (the edge voxel repeated up to half a voxel beyond the outer centres),
taken only in quads one of whose four voxels has a density of non-zero opacity; the pixel keeps the largest (MIP)
or smallest (MinIP). On a grid whose thicker in-slice axis is at least isplat.splat.post.THICK_RATIO times the
finest spacing (and BETWEEN_SLICES not "linear"), the density there is the post reference's cubic along that axis
instead (tests/post_reference.py ``_thick_axis``, ``_density``: a cubic Hermite through the four voxels around
the point in each of the quad's two rows, indices clamped to the volume, Catmull-Rom clamped to 0..255, then
linear across). No index, no ordering, no skipping: every slice of every ray.
"""

from __future__ import annotations


import numpy as np

from isplat import camera as C
from isplat.transfer import piecewise_linear
from post_reference import _density, _thick_axis, pixel_ray, quad_corners, ray_point


EDGE = 1e-7        # grid units: a crossing this near a quad's edge may fall in either quad (mip_bounds)


def mip_reference(density, view, scene, mode="mip"):
    """float64 (H, W): each pixel's extreme density along its ray at the slice planes; NaN where no sample."""
    return _reference(density, view, scene, mode, False)[0]


def mip_bounds(density, view, scene, mode="mip"):
    """What rounding may make of the projection: float64 (H, W) twice, the extreme over the crossings that are
    sampled whichever side of a quad's edge rounding puts them (``strict``) and over those sampled on some side
    (``loose``), each crossing moved by up to EDGE along the slice's axes. A crossing on the edge between a quad
    of interest and one of none (a pixel centre on a voxel's column, say) is sampled or not by a hair: the two
    differ there, and a renderer is right anywhere between them (MIP: strict <= it <= loose). NaN: no sample.
    Third, for pixels with no crossing sampled on every side: (least, greatest) of the crossings sampled on some
    side, between which the extreme of any of them lies."""
    return _reference(density, view, scene, mode, True)


def _reference(density, view, scene, mode, bounds):
    frame, geom = view.frame, view.geom
    axis, _ = C.principal_axis(frame, geom)
    ia, ib, ic = C.SLICE_AXES[axis]
    thick = _thick_axis(geom.spacing, ia, ib, None)
    density = np.asarray(density, np.float64)          # the cubic's differences: no uint8 wrap-around
    n_ijk = density.shape[::-1]
    opac = piecewise_linear(scene.transfer.opacity, np.arange(256.0), True)[:, 0]
    interest = opac > 0
    W, H = frame.width, frame.height
    pick = max if mode == "mip" else min
    out = np.full((H, W), np.nan)
    loose_out = np.full((H, W), np.nan)
    span = (np.full((H, W), np.nan), np.full((H, W), np.nan))
    shifts = [(du, dv) for du in (-EDGE, 0.0, EDGE) for dv in (-EDGE, 0.0, EDGE)] if bounds else [(0.0, 0.0)]
    for y in range(H):
        for x in range(W):
            d, og, dg = pixel_ray(frame, geom, x, y)
            if abs(dg[ic]) < 1e-15:
                continue
            best, loose = None, None
            for c in range(n_ijk[ic]):
                g = ray_point(frame, geom, scene.cuts, d, og, dg, (c - og[ic]) / dg[ic])
                if g is None:
                    continue
                got = [bilinear(density, g[ia] + du, g[ib] + dv, c, (ia, ib, ic), n_ijk, interest, thick)
                       for du, dv in shifts]
                found = [s for s in got if s is not None]
                if found and len(found) == len(got):
                    s = got[len(got) // 2]                  # the crossing itself
                    best = s if best is None else pick(best, s)
                if found:
                    s = pick(found)
                    loose = s if loose is None else pick(loose, s)
                    span[0][y, x] = np.fmin(span[0][y, x], min(found))
                    span[1][y, x] = np.fmax(span[1][y, x], max(found))
            if best is not None:
                out[y, x] = best
            if loose is not None:
                loose_out[y, x] = loose
    return out, loose_out, span


def bilinear(density, u, v, c, axes, n_ijk, interest, thick=None):
    """The bilinear density at (u, v) of slice c (or, ``thick`` not None, the post reference's cubic along the
    thick axis: tests/post_reference.py ``_density``), or None outside the slice or in a quad of no interest."""
    quad = quad_corners(u, v, c, axes, n_ijk)
    if quad is None:
        return None
    qa, qb, fu, fv, corners, weights = quad
    total, any_interest = 0.0, False
    for k, w in zip(corners, weights):
        val = int(density[k])
        any_interest |= bool(interest[val])
        total += w * val
    if any_interest and thick is not None:
        return _density(density, qa, qb, fu, fv, c, axes, n_ijk, thick)
    return total if any_interest else None


def grey(held, background, window=(0.0, 255.0)):
    """Straight RGBA over an opaque ``background``: the held density through ``window`` as grey, the background
    where there is no sample."""
    lo, hi = window
    g = np.clip((held - lo) / (hi - lo), 0, 1)
    out = np.empty(held.shape + (4,))
    out[..., :3] = np.where(np.isnan(held)[..., None], np.asarray(background[:3], float), g[..., None])
    out[..., 3] = 1.0
    return out


def mip_reference_vectorized(density, view, interest, mode="mip", cuts=()):
    """The same as :func:`mip_reference` (float64 (H, W), NaN where no sample) with the pixels of a slice at once
    (numpy), for benchmark sizes; ``interest`` bool[256]: the densities of non-zero opacity. The same obvious
    steps: every slice, every pixel, no skipping."""
    frame, geom = view.frame, view.geom
    axis, _ = C.principal_axis(frame, geom)
    ia, ib, ic = C.SLICE_AXES[axis]
    if _thick_axis(geom.spacing, ia, ib, None) is not None:
        raise ValueError("mip_reference_vectorized: bilinear only; a grid this thick takes the cubic (mip_reference)")
    n_ijk = density.shape[::-1]
    n_a, n_b = n_ijk[ia], n_ijk[ib]
    persp = frame.projection == "perspective"
    to_grid = geom.unit_axes / geom.spacing[:, None]
    W, H = frame.width, frame.height
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float64)
    P = (frame.p + ((xs - (W / 2.0 - 0.5)) * frame.pixel_size)[..., None] * frame.u
         - ((ys - (H / 2.0 - 0.5)) * frame.pixel_size)[..., None] * frame.v)
    if persp:
        d = P - frame.e
        o = np.broadcast_to(frame.e, P.shape)
    else:
        d = np.broadcast_to(-frame.w, P.shape)
        o = P
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    og, dg = (o - geom.q) @ to_grid.T, d @ to_grid.T
    sign = 1.0 if mode == "mip" else -1.0
    best = np.full((H, W), -np.inf)
    ok_ray = np.abs(dg[..., ic]) >= 1e-15
    for c in range(n_ijk[ic]):
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (c - og[..., ic]) / dg[..., ic]
        g = og + t[..., None] * dg
        u, v = g[..., ia], g[..., ib]
        ok = ok_ray & (u >= -0.5) & (u < n_a - 0.5) & (v >= -0.5) & (v < n_b - 0.5)
        if persp:
            ok &= t * (-(d @ frame.w)) >= frame.near
        if cuts:
            X = geom.q + g @ geom.steps
            for cut in cuts:
                ok &= (X - np.asarray(cut.point)) @ np.asarray(cut.normal) >= 0
        u, v = np.where(ok, u, 0.0), np.where(ok, v, 0.0)
        qa, qb = np.maximum(np.floor(u), 0).astype(np.int64), np.maximum(np.floor(v), 0).astype(np.int64)
        fu, fv = np.maximum(u - qa, 0.0), np.maximum(v - qb, 0.0)
        qa1, qb1 = np.minimum(qa + 1, n_a - 1), np.minimum(qb + 1, n_b - 1)
        total, hit = 0.0, np.zeros(ok.shape, bool)
        for a_, b_, w in ((qa, qb, (1 - fu) * (1 - fv)), (qa1, qb, fu * (1 - fv)), (qa, qb1, (1 - fu) * fv),
                          (qa1, qb1, fu * fv)):
            ijk = [None, None, None]
            ijk[ia], ijk[ib], ijk[ic] = a_, b_, c
            val = density[ijk[2], ijk[1], ijk[0]]
            hit |= interest[val]
            total = total + w * val
        ok &= hit
        best = np.where(ok, np.maximum(best, sign * total), best)
    return np.where(np.isinf(best), np.nan, sign * best)
