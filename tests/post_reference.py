"""A slow, obvious reference for post-classified splatting (isplat.splat.post): per pixel, per slice, float64.

Its own rays (pixel centres on the image plane, the eye for perspective), their crossings with the slice
planes of the principal axis, bilinear interpolation of the density in the slice (the edge voxel repeated up
to half a voxel beyond the outer centres), the transfer function from its control points (tabulated per code,
corrected for the path through the slice, and interpolated between codes, as the model says), Phong shading of
each corner's decoded normal weighted by its bilinear weight times its gradient magnitude code (normalised; the
bilinear weights alone when the four codes are 0; ``weighted=False``: the bilinear weights, as before), and
'over' front to back. On an anisotropic grid (the thicker in-slice axis at least isplat.splat.post.THICK_RATIO
times the finest spacing, isplat.splat.post.BETWEEN_SLICES not "linear") the density along that axis is a cubic
Hermite through the four voxels around the point (indices clamped to the volume) in each of the two rows, then
linear across them: monotone (Fritsch-Butland slopes) or Catmull-Rom clamped to 0..255; or ("b-spline") the
interpolating cubic spline (sum of the cubic B-spline at the voxels' prefiltered coefficients, the prefilter's
impulse response sqrt(3) (sqrt(3) - 2)^|m|) through the 2 SPLINE_REACH voxels around the point, its weights
renormalised to sum to 1, clamped to 0..255; and the shading mixes
the Phong factors of those eight voxels, weighted by the cubic B-spline's weights along the thick axis times the
linear weights across (times the gradient magnitude codes, normalised, as the four corners' otherwise). A quad (the square between
four voxels) is sampled only when one of its voxels has a density of non-zero opacity. With
``render.slice_stride`` N > 1 only the slices whose index is a multiple of N are sampled, each for a path N
slices long (the opacity 1 - (1 - alpha)^(N r) of one slice's r; in perspective the first slab kept reaches back
N slices too, and the cosine's bound is N slice spacings over the box's diagonal).
"""

from __future__ import annotations

import math

import numpy as np

from isplat import camera as C
from isplat.augfile import open_augmented
from isplat.normals import decode
from isplat.transfer import piecewise_linear
from phong_reference import camera_lights, phong

ALPHA_MAX = 1 - 2.0 ** -40


def post_reference(scene, view=0, et=1.0, weighted=True, between=None, stride=None):
    """Straight RGBA (H, W, 4) over the scene's background. ``between``: "linear", "monotone", "catmull-rom" or
    "b-spline"
    (None: isplat.splat.post.BETWEEN_SLICES); ``stride``: every n-th slice (None: render.slice_stride). A pixel
    that reaches ``et`` stops; with ``render.termination = "fill"`` the rest of its transmittance takes the colour
    of the sample that took it there."""
    stride = scene.render.slice_stride if stride is None else stride
    fill = scene.render.termination == "fill"
    aug = open_augmented(scene.data.augmented)
    dens = aug.read("density").astype(np.float64)
    nrm = aug.read("normal")
    gm = aug.read("gradient_magnitude").astype(np.float64) if weighted else None
    sp = scene.volume.spacing or aug.spacing_ijk
    geom = C.volume_geometry(aug.shape, sp, scene.volume.origin, scene.volume.axes)
    W, H = scene.image.width, scene.image.height
    frame = C.view_frame(scene.views[view], geom, W, H)
    axis, _ = C.principal_axis(frame, geom)
    ia, ib, ic = C.SLICE_AXES[axis]
    along = _thick_axis(geom.spacing, ia, ib, between)
    tr, sh = scene.transfer, scene.shading
    unit = tr.unit_distance or float(geom.spacing.min())
    n_ijk = aug.shape[::-1]
    persp = frame.projection == "perspective"
    codes = np.arange(256.0)
    opac = np.minimum(np.clip(piecewise_linear(tr.opacity, codes, True)[:, 0], 0, 1), ALPHA_MAX)
    col = np.clip(piecewise_linear(tr.color, codes, False), 0, 1)
    lights = camera_lights(sh, frame)
    normal_axis = geom.unit_axes[ic]
    cos_ortho = abs(frame.w @ normal_axis)
    cos_min = min(1.0, stride * geom.spacing[ic] / float(np.linalg.norm(geom.n_ijk * geom.spacing)))
    if persp:
        ce = geom.to_grid(frame.e)[ic]
        h0 = max(-0.5 - ce, ce - (n_ijk[ic] - 0.5), 0.0) * geom.spacing[ic]
    img = np.zeros((H, W, 4))
    for y in range(H):
        for x in range(W):
            d, og, dg = pixel_ray(frame, geom, x, y)
            if abs(dg[ic]) < 1e-15:
                continue
            hits = sorted(((c - og[ic]) / dg[ic], c) for c in range(0, n_ijk[ic], stride))
            acc = np.zeros(4)
            for t, c in hits:
                if acc[3] >= et:
                    break
                g = ray_point(frame, geom, scene.cuts, d, og, dg, t)
                if g is None:
                    continue
                s = _sample(dens, nrm, g[ia], g[ib], c, (ia, ib, ic), n_ijk, opac, col, sh, lights, geom, gm, along)
                if s is None:
                    continue
                lo, hi, f, rgb = s
                thick = stride * geom.spacing[ic]
                if persp:
                    # as the splatting reference: the first slab kept reaches back to the eye (or a set near
                    # plane, not in front of the box); the cosine bounded by slice spacing / box diagonal
                    cos = max(abs(d @ normal_axis), cos_min)
                    hc = abs(c - og[ic]) * geom.spacing[ic]
                    depth = t * float(-(d @ frame.w))
                    if depth * (hc - thick) < frame.near * hc:
                        thick = max(hc + 0.5 * thick - max(h0, frame.clip * hc / depth), 0.0)
                else:
                    cos = cos_ortho
                a = _alpha(lo, hi, f, thick / cos / unit, persp)
                acc[:3] += (1 - acc[3]) * rgb * a
                acc[3] += (1 - acc[3]) * a
                if fill and acc[3] >= et:       # render.termination = "fill": the rest takes this sample's colour
                    acc[:3] += (1 - acc[3]) * rgb
                    acc[3] = 1.0
            img[y, x] = acc
    bg = np.asarray(scene.image.background, float)
    A = img[..., 3:4]
    rgb = img[..., :3] + (1 - A) * bg[:3] * bg[3]
    alpha = A + (1 - A) * bg[3]
    out = np.concatenate([np.where(alpha > 0, rgb / np.maximum(alpha, 1e-300), 0.0), alpha], axis=-1)
    return np.clip(out, 0, 1)


def pixel_ray(frame, geom, x, y):
    """Pixel (x, y)'s own ray: its unit direction ``d`` (world), and its origin and direction in grid units
    (``og + t dg`` is the grid point at distance t along it): from the pixel centre on the image plane along the
    view (orthographic), or from the eye through it (perspective)."""
    cx, cy = frame.width / 2.0 - 0.5, frame.height / 2.0 - 0.5
    P = frame.p + (x - cx) * frame.pixel_size * frame.u - (y - cy) * frame.pixel_size * frame.v
    o, d = (frame.e, P - frame.e) if frame.projection == "perspective" else (P, -frame.w)
    d = d / np.linalg.norm(d)
    to_grid = geom.unit_axes / geom.spacing[:, None]
    return d, (o - geom.q) @ to_grid.T, d @ to_grid.T


def ray_point(frame, geom, cuts, d, og, dg, t):
    """The grid point at distance ``t`` along a :func:`pixel_ray`, or None when it is nearer than the near plane
    (perspective) or a cutting plane cuts it away."""
    if frame.projection == "perspective" and t * float(-(d @ frame.w)) < frame.near:
        return None
    g = og + t * dg
    X = geom.q + g @ geom.steps
    if any((X - np.asarray(cut.point)) @ np.asarray(cut.normal) < 0 for cut in cuts):
        return None
    return g


def _thick_axis(spacing, ia, ib, between):
    """(0 for a or 1 for b, the cubic's name, whether the shading follows: isplat.splat.post.SHADE_BETWEEN) of the
    slices' thick in-slice axis, or None: bilinear."""
    from isplat.splat import post

    kind = between or post.BETWEEN_SLICES
    sp = [float(x) for x in spacing]
    if kind == "linear" or max(sp[ia], sp[ib]) < post.THICK_RATIO * min(sp):
        return None
    return (0 if sp[ia] >= sp[ib] else 1), kind, post.SHADE_BETWEEN


def _hermite(p, t, kind):
    """The cubic between p[1] and p[2] at t in [0, 1] with neighbours p[0] and p[3]."""
    d = [p[1] - p[0], p[2] - p[1], p[3] - p[2]]
    if kind == "monotone":
        m = [2 * x * y / (x + y) if x * y > 0 else 0.0 for x, y in ((d[0], d[1]), (d[1], d[2]))]
    else:
        m = [(p[2] - p[0]) / 2, (p[3] - p[1]) / 2]
    h = [2 * t**3 - 3 * t**2 + 1, t**3 - 2 * t**2 + t, -2 * t**3 + 3 * t**2, t**3 - t**2]
    return float(np.clip(h[0] * p[1] + h[1] * m[0] + h[2] * p[2] + h[3] * m[1], 0, 255))


def _spline_taps():
    """The voxels' offsets along the thick axis the spline reads from a quad's first corner."""
    from isplat.splat.post import SPLINE_REACH

    return range(1 - SPLINE_REACH, SPLINE_REACH + 1)


def _bspline(x):
    """The centred cubic B-spline."""
    x = abs(x)
    if x < 1:
        return 2 / 3 - x * x + x**3 / 2
    return (2 - x) ** 3 / 6 if x < 2 else 0.0


def _cardinal(p, f):
    """The interpolating cubic spline through the voxels ``p`` (at :func:`_spline_taps`) at ``f`` past offset 0:
    each voxel weighted by the spline's kernel eta(f - k) = sum_m h(m) beta3(f - k - m) (h the prefilter, summed to
    |m| <= 40), the weights renormalised, the value clamped to the codes."""
    z = np.sqrt(3) - 2
    w = [sum(np.sqrt(3) * z ** abs(m) * _bspline(f - k - m) for m in range(-40, 41)) for k in _spline_taps()]
    return float(np.clip(sum(wi * pi for wi, pi in zip(w, p)) / sum(w), 0, 255))


def _density(dens, qa, qb, fu, fv, c, axes, n_ijk, thick):
    """The density at (qa + fu, qb + fv) of slice c: bilinear, or cubic along the thick axis (``thick``)."""
    ia, ib, ic = axes

    def at(a, b):
        ijk = [0, 0, 0]
        ijk[ia], ijk[ib], ijk[ic] = min(max(a, 0), n_ijk[ia] - 1), min(max(b, 0), n_ijk[ib] - 1), c
        return dens[ijk[2], ijk[1], ijk[0]]

    if thick is None:
        return sum(w * at(qa + da, qb + db) for da, db, w in ((0, 0, (1 - fu) * (1 - fv)), (1, 0, fu * (1 - fv)),
                                                                ((0, 1, (1 - fu) * fv)), (1, 1, fu * fv)))
    if thick[1] == "b-spline":
        f, g = (fu, fv) if thick[0] == 0 else (fv, fu)
        lines = []
        for across in (0, 1):
            p = [at(qa + k, qb + across) if thick[0] == 0 else at(qa + across, qb + k) for k in _spline_taps()]
            lines.append(_cardinal(p, f))
        return (1 - g) * lines[0] + g * lines[1]
    if thick[0] == 0:
        rows = [_hermite([at(qa + k, qb + db) for k in (-1, 0, 1, 2)], fu, thick[1]) for db in (0, 1)]
        return (1 - fv) * rows[0] + fv * rows[1]
    cols = [_hermite([at(qa + da, qb + k) for k in (-1, 0, 1, 2)], fv, thick[1]) for da in (0, 1)]
    return (1 - fu) * cols[0] + fu * cols[1]


def _sample(dens, nrm, u, v, c, axes, n_ijk, opac, col, sh, lights, geom, gm=None, thick=None):
    """The sample at (u, v) of slice c: the opacities of the two codes around the interpolated density, the
    fraction between them and the shaded colour; None when outside the volume, in a quad of no interest, or
    transparent."""
    quad = quad_corners(u, v, c, axes, n_ijk)
    if quad is None:
        return None
    qa, qb, fu, fv, corners, weights = quad
    if not any(opac[int(dens[k])] > 0 for k in corners):
        return None
    d = _density(dens, qa, qb, fu, fv, c, axes, n_ijk, thick)
    di = min(int(d), 254)
    f = d - di
    if opac[di] == 0 and opac[di + 1] == 0:
        return None
    rgb = col[di] + f * (col[di + 1] - col[di])
    if sh.enabled:
        diff, spec = np.zeros(3), np.zeros(3)
        if thick is not None and thick[2]:
            corners, weights = _bspline_corners(qa, qb, fu, fv, c, axes, n_ijk, thick[0])
        if gm is not None and sum(w * gm[k] for w, k in zip(weights, corners)) > 0:
            total = sum(w * gm[k] for w, k in zip(weights, corners))
            weights = [w * gm[k] / total for w, k in zip(weights, corners)]
        for w, k in zip(weights, corners):
            n = decode(np.array([nrm[k]]))[0].astype(float) @ geom.unit_axes
            dd, ss = phong(n, sh, lights)
            diff += w * dd
            spec += w * ss
        rgb = rgb * diff + spec
    return opac[di], opac[di + 1], f, rgb


def quad_corners(u, v, c, axes, n_ijk):
    """The quad of slice c that holds (u, v): ``(qa, qb, fu, fv, corners, weights)``, its first voxel, the point's
    place in it, its four voxels' (k, j, i) indices (clamped: the edge voxel repeated up to half a voxel beyond
    the outer centres) and their bilinear weights; None outside the slice."""
    ia, ib, ic = axes
    n_a, n_b = n_ijk[ia], n_ijk[ib]
    if not (-0.5 <= u < n_a - 0.5 and -0.5 <= v < n_b - 0.5):
        return None
    qa, qb = max(math.floor(u), 0), max(math.floor(v), 0)
    fu, fv = max(u - qa, 0.0), max(v - qb, 0.0)
    corners, weights = [], []
    for da, db, w in ((0, 0, (1 - fu) * (1 - fv)), (1, 0, fu * (1 - fv)), (0, 1, (1 - fu) * fv), (1, 1, fu * fv)):
        ijk = [0, 0, 0]
        ijk[ia], ijk[ib], ijk[ic] = min(qa + da, n_a - 1), min(qb + db, n_b - 1), c
        corners.append((ijk[2], ijk[1], ijk[0]))
        weights.append(w)
    return qa, qb, fu, fv, corners, weights


def _bspline_corners(qa, qb, fu, fv, c, axes, n_ijk, along):
    """The eight voxels whose Phong factors shade a sample between thick slices (``along`` 0: a, 1: b) and their
    weights: the cubic B-spline's along the thick axis (indices clamped to the volume), linear across."""
    ia, ib, ic = axes
    f, g = (fu, fv) if along == 0 else (fv, fu)
    bw = [(1 - f) ** 3 / 6, (3 * f**3 - 6 * f**2 + 4) / 6, (-3 * f**3 + 3 * f**2 + 3 * f + 1) / 6, f**3 / 6]
    corners, weights = [], []
    for across, wr in ((0, 1 - g), (1, g)):
        for k, w in zip((-1, 0, 1, 2), bw):
            da, db = (k, across) if along == 0 else (across, k)
            ijk = [0, 0, 0]
            ijk[ia] = min(max(qa + da, 0), n_ijk[ia] - 1)
            ijk[ib] = min(max(qb + db, 0), n_ijk[ib] - 1)
            ijk[ic] = c
            corners.append((ijk[2], ijk[1], ijk[0]))
            weights.append(wr * w)
    return corners, weights


def _alpha(lo, hi, f, r, persp):
    """The sample's opacity for path ratio ``r``: perspective interpolates log(1 - alpha) between the codes and
    corrects after; orthographic corrects each code's opacity and interpolates."""
    if persp:
        return -math.expm1(r * (math.log1p(-lo) + f * (math.log1p(-hi) - math.log1p(-lo))))
    lo_r, hi_r = 1 - (1 - lo) ** r, 1 - (1 - hi) ** r
    return lo_r + f * (hi_r - lo_r)


def kernel_offsets(strides, n_a: int, n_b: int, c: int) -> tuple:
    """The sampler's ``voxel[3]`` (isplat.splat.post) for whole channels in C order of flat steps ``strides``
    (along a, b, c and an offset added to every index), as isplat.selection.Selection.whole_volume gives it:
    ``(stride along a, along b, slice c's first voxel, voxels along a per prefetch, no brick table)``."""
    sa, sb, sc, off = (int(x) for x in strides)
    return sa, sb, c * sc + off, max(1, 32 // max(sa, 1)), NO_TABLE


NO_TABLE = None          # whole channels: no brick table (isplat.splat.post._phys)
