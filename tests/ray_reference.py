"""A converged ray-casting reference, independent of splatting: shared by the tests and benchmarks/reference.py.

The image is the emission-absorption volume-rendering integral along one ray per pixel centre, in float64:

    I = integral of T(t) c(t) sigma(t) dt,  T(t) = exp(-integral of sigma),  sigma = -log(1 - a(d)) / unit_distance

where ``d`` is the density *reconstructed first* (trilinear interpolation of the 8-bit density codes, or the exact
Marschner-Lobb function) and the transfer function is applied to that continuous value afterwards
(post-classification: ``a(d)`` and ``c(d)`` are the scene's piecewise-linear points evaluated at the real number
``d``, opacity zero beyond the first and last point, colour clamped). isplat's splatting does the opposite
(pre-classification): it classifies each voxel's integer code, then spreads the classified colour and opacity with
a Gaussian footprint, so a sharp transfer-function edge is blurred over the footprint and a thin feature whose
voxels straddle an opacity edge lights up or vanishes as a whole; that difference is part of what the reference
measures.

Discretisation: each ray is clipped to the volume's extent, taken as its voxel boxes (grid coordinates
``[-0.5, n - 0.5]`` per axis, the extent isplat gives a volume: ``n`` slices of one spacing each; in the outer half
voxel the trilinear field is clamped to the edge value), and cut into ``N = ceil(length / step)`` equal pieces,
sampled at their midpoints; piece ``m`` has opacity ``1 - exp(-sigma dt)`` and colour ``c * shading``, composited
front to back. A constant field is therefore integrated exactly (any ``N``). A ray stops when its transmittance
falls below ``T_MIN`` (1e-9: the colour it could still add is below 1e-9). Blocks of ``BLOCK``^3 cells whose
corner densities span only zero opacity are not sampled (their samples would add exactly nothing), which changes
no value.

Shading (when the scene's shading is on): the Phong terms of :mod:`isplat.splat.shade` with the same lights,
ambient, diffuse, specular, shininess and two-sidedness, an infinite viewer (half vector with ``w``) as there,
and the normal of the reconstructed field: for the grid, central differences of the density codes in physical
units (one-sided at the borders), trilinearly interpolated; for Marschner-Lobb the exact gradient. A zero gradient
gives ambient only (as isplat's NO_NORMAL).
"""

from __future__ import annotations

import math

import numba
import numpy as np

T_MIN = 1e-9           # a ray stops when its transmittance falls below this
BLOCK = 8              # cells per side of the empty-space blocks
ALPHA_MAX = 1.0 - 2.0 ** -40      # as isplat.transfer: alpha 1 stays finite in the log
GRID, MARSCHNER_LOBB = 0, 1

_JIT = dict(nogil=True, cache=True)


# ---- the field ------------------------------------------------------------------------------------------------
@numba.njit(**_JIT)
def _trilinear(vol, gi, gj, gk):
    nk, nj, ni = vol.shape
    gi = min(max(gi, 0.0), ni - 1.0)
    gj = min(max(gj, 0.0), nj - 1.0)
    gk = min(max(gk, 0.0), nk - 1.0)
    i0 = min(int(gi), ni - 2)
    j0 = min(int(gj), nj - 2)
    k0 = min(int(gk), nk - 2)
    fi, fj, fk = gi - i0, gj - j0, gk - k0
    c00 = vol[k0, j0, i0] * (1 - fi) + vol[k0, j0, i0 + 1] * fi
    c01 = vol[k0, j0 + 1, i0] * (1 - fi) + vol[k0, j0 + 1, i0 + 1] * fi
    c10 = vol[k0 + 1, j0, i0] * (1 - fi) + vol[k0 + 1, j0, i0 + 1] * fi
    c11 = vol[k0 + 1, j0 + 1, i0] * (1 - fi) + vol[k0 + 1, j0 + 1, i0 + 1] * fi
    return (c00 * (1 - fj) + c01 * fj) * (1 - fk) + (c10 * (1 - fj) + c11 * fj) * fk


@numba.njit(**_JIT)
def _ml(gi, gj, gk, p):
    """Marschner-Lobb density code and its gradient per grid step at grid point (gi, gj, gk).

    ``p`` = (fm, alpha, lo, hi, ni, nj, nk): the sample's signal on [-1, 1]^3 sampled at both ends of each axis,
    mapped to codes by ``(f - lo) * 255 / (hi - lo)`` clipped to [0, 255] (isplat augment, without the rounding)."""
    fm, al, lo, hi = p[0], p[1], p[2], p[3]
    hx, hy, hz = 2.0 / (p[4] - 1.0), 2.0 / (p[5] - 1.0), 2.0 / (p[6] - 1.0)
    x, y, z = -1.0 + gi * hx, -1.0 + gj * hy, -1.0 + gk * hz
    r = math.sqrt(x * x + y * y)
    ph = 2.0 * math.pi * fm * math.cos(math.pi * r / 2.0)
    f = (1.0 - math.sin(math.pi * z / 2.0) + al * (1.0 + math.cos(ph))) / (2.0 * (1.0 + al))
    scale = 255.0 / (hi - lo)
    code = (f - lo) * scale
    if code <= 0.0 or code >= 255.0:
        return min(max(code, 0.0), 255.0), 0.0, 0.0, 0.0
    dfdz = -(math.pi / 2.0) * math.cos(math.pi * z / 2.0) / (2.0 * (1.0 + al))
    drho = math.sin(ph) * 2.0 * math.pi * fm * (math.pi / 2.0) * math.sin(math.pi * r / 2.0)
    k = al / (2.0 * (1.0 + al)) * drho
    dfdx = k * x / r if r > 0.0 else 0.0
    dfdy = k * y / r if r > 0.0 else 0.0
    return code, dfdx * hx * scale, dfdy * hy * scale, dfdz * hz * scale


# ---- classification and shading ------------------------------------------------------------------------------
@numba.njit(**_JIT)
def _pwl(xs, ys, x, outside_zero):
    """Piecewise-linear points (xs ascending, ys) at x: 0 beyond the ends when outside_zero, else clamped."""
    n = xs.shape[0]
    if x < xs[0]:
        return 0.0 if outside_zero else ys[0]
    if x > xs[n - 1]:
        return 0.0 if outside_zero else ys[n - 1]
    for m in range(1, n):
        if x <= xs[m]:
            x0, x1 = xs[m - 1], xs[m]
            if x1 == x0:
                return ys[m]
            return ys[m - 1] + (ys[m] - ys[m - 1]) * (x - x0) / (x1 - x0)
    return ys[n - 1]


@numba.njit(**_JIT)
def _phong(nx, ny, nz, lights, sh):
    """(diffuse r, g, b, specular r, g, b) for normal n (volume axes) as isplat.splat.shade.shade_codes."""
    ambient, diffuse, specular, shininess, two_sided = sh[0], sh[1], sh[2], sh[3], sh[4] > 0.5
    out = np.empty(6)
    for ch in range(3):
        out[ch] = ambient
        out[3 + ch] = 0.0
    for li in range(lights.shape[0]):
        ndl = nx * lights[li, 0] + ny * lights[li, 1] + nz * lights[li, 2]
        ndh = nx * lights[li, 3] + ny * lights[li, 4] + nz * lights[li, 5]
        if two_sided:
            ndl = abs(ndl)
            ndh = abs(ndh)
        else:
            if ndl <= 0.0:
                ndl = 0.0
                ndh = 0.0
            ndh = max(ndh, 0.0)
        sp = specular * ndh ** shininess if ndh > 0.0 and specular != 0.0 else 0.0
        for ch in range(3):
            out[ch] += diffuse * ndl * lights[li, 6 + ch]
            out[3 + ch] += sp * lights[li, 6 + ch]
    return out


# ---- the integral ---------------------------------------------------------------------------------------------
@numba.njit(**_JIT)
def _box_range(o, d, n, t_lo):
    """[t0, t1] of the ray o + t d (grid coordinates) inside [-0.5, n - 0.5]^3, from t_lo on."""
    t0, t1 = t_lo, np.inf
    for a in range(3):
        lo, hi = -0.5, n[a] - 0.5
        if d[a] == 0.0:
            if o[a] < lo or o[a] > hi:
                return 1.0, 0.0
        else:
            ta, tb = (lo - o[a]) / d[a], (hi - o[a]) / d[a]
            if ta > tb:
                ta, tb = tb, ta
            t0 = max(t0, ta)
            t1 = min(t1, tb)
    return t0, t1


@numba.njit(**_JIT)
def _sample(kind, vol, grad, mlp, gi, gj, gk, need_grad, sp):
    """Density code and (when need_grad) the gradient in physical units along i, j, k."""
    if kind == GRID:
        d = _trilinear(vol, gi, gj, gk)
        if not need_grad:
            return d, 0.0, 0.0, 0.0
        return d, _trilinear(grad[0], gi, gj, gk), _trilinear(grad[1], gi, gj, gk), _trilinear(grad[2], gi, gj, gk)
    d, a, b, c = _ml(gi, gj, gk, mlp)
    return d, a / sp[0], b / sp[1], c / sp[2]


@numba.njit(parallel=True, **_JIT)
def integrate(kind, vol, grad, empty, mlp, orig, dirs, t_lo, n, sp, step, ox, oy, cx, cy, unit, use_shade,
              lights, sh, out):
    """Premultiplied RGBA of each ray into ``out[r, 4]``.

    Rays: ``orig[r]`` and ``dirs[r]`` in grid coordinates (``dirs`` per world unit, so t is world length), from
    ``t_lo[r]`` on. ``n`` = (n_i, n_j, n_k), ``sp`` the spacing, ``step`` the longest piece in world units.
    ``empty[bk, bj, bi]`` flags blocks of BLOCK^3 cells of zero opacity (GRID only; ignored for Marschner-Lobb)."""
    for r in numba.prange(orig.shape[0]):
        o = orig[r]
        d = dirs[r]
        t0, t1 = _box_range(o, d, n, t_lo[r])
        acc_r = 0.0
        acc_g = 0.0
        acc_b = 0.0
        T = 1.0
        if t1 > t0:
            nseg = max(1, int(math.ceil((t1 - t0) / step)))
            dt = (t1 - t0) / nseg
            for m in range(nseg):
                t = t0 + (m + 0.5) * dt
                gi = o[0] + t * d[0]
                gj = o[1] + t * d[1]
                gk = o[2] + t * d[2]
                if kind == GRID:
                    bi = min(int(min(max(gi, 0.0), n[0] - 1.0)), int(n[0]) - 2) // BLOCK
                    bj = min(int(min(max(gj, 0.0), n[1] - 1.0)), int(n[1]) - 2) // BLOCK
                    bk = min(int(min(max(gk, 0.0), n[2] - 1.0)), int(n[2]) - 2) // BLOCK
                    if empty[bk, bj, bi]:
                        continue
                dens, g0, g1, g2 = _sample(kind, vol, grad, mlp, gi, gj, gk, False, sp)
                a = _pwl(ox, oy, dens, True)
                if a <= 0.0:
                    continue
                sigma = -math.log1p(-min(min(a, 1.0), ALPHA_MAX)) / unit
                alpha = -math.expm1(-sigma * dt)
                cr = _pwl(cx, cy[:, 0], dens, False)
                cg = _pwl(cx, cy[:, 1], dens, False)
                cb = _pwl(cx, cy[:, 2], dens, False)
                if use_shade:
                    dens, g0, g1, g2 = _sample(kind, vol, grad, mlp, gi, gj, gk, True, sp)
                    gn = math.sqrt(g0 * g0 + g1 * g1 + g2 * g2)
                    if gn > 0.0:
                        f = _phong(g0 / gn, g1 / gn, g2 / gn, lights, sh)
                    else:
                        f = _phong(0.0, 0.0, 0.0, lights, sh)
                    cr = cr * f[0] + f[3]
                    cg = cg * f[1] + f[4]
                    cb = cb * f[2] + f[5]
                w = T * alpha
                acc_r += w * cr
                acc_g += w * cg
                acc_b += w * cb
                T *= 1.0 - alpha
                if T < T_MIN:
                    break
        out[r, 0] = acc_r
        out[r, 1] = acc_g
        out[r, 2] = acc_b
        out[r, 3] = 1.0 - T


@numba.njit(parallel=True, **_JIT)
def _block_range(vol, nb_k, nb_j, nb_i):
    """Min and max density over the corner voxels of each block of BLOCK^3 cells."""
    nk, nj, ni = vol.shape
    mn = np.empty((nb_k, nb_j, nb_i))
    mx = np.empty((nb_k, nb_j, nb_i))
    for bk in numba.prange(nb_k):
        for bj in range(nb_j):
            for bi in range(nb_i):
                lo, hi = np.inf, -np.inf
                for k in range(bk * BLOCK, min(nk, bk * BLOCK + BLOCK + 1)):
                    for j in range(bj * BLOCK, min(nj, bj * BLOCK + BLOCK + 1)):
                        for i in range(bi * BLOCK, min(ni, bi * BLOCK + BLOCK + 1)):
                            v = vol[k, j, i]
                            lo = min(lo, v)
                            hi = max(hi, v)
                mn[bk, bj, bi] = lo
                mx[bk, bj, bi] = hi
    return mn, mx


# ---- from isplat's views to rays ------------------------------------------------------------------------------
def rays(view):
    """One ray per pixel centre of ``view`` (an isplat.frame.View): (origins, directions) in grid coordinates,
    directions per world unit, and the smallest t (orthographic: the whole line; perspective: from the eye)."""
    f, g = view.frame, view.geom
    H, W = f.height, f.width
    cx, cy = W / 2.0 - 0.5, H / 2.0 - 0.5
    xs = (np.arange(W) - cx) * f.pixel_size
    ys = (np.arange(H) - cy) * f.pixel_size
    plane = f.p[None, None, :] + xs[None, :, None] * f.u[None, None, :] - ys[:, None, None] * f.v[None, None, :]
    plane = plane.reshape(-1, 3)
    if f.projection == "orthographic":
        d = np.broadcast_to(-f.w, plane.shape)
        o, t_lo = plane, np.full(len(plane), -np.inf)
    else:
        d = plane - f.e
        d = d / np.linalg.norm(d, axis=1, keepdims=True)
        o, t_lo = np.broadcast_to(f.e, plane.shape), np.zeros(len(plane))
    to_grid = g.unit_axes / g.spacing[:, None]            # world vector -> grid steps
    og = (o - g.q) @ to_grid.T
    dg = d @ to_grid.T
    return np.ascontiguousarray(og), np.ascontiguousarray(dg), t_lo


def light_rows(shading, frame, geom) -> np.ndarray:
    """Lights as isplat.splat.shade.shade_table builds them: (L, H, rgb) in volume axes."""
    R = np.stack([frame.u, frame.v, frame.w])
    view = geom.unit_axes @ frame.w
    rows = []
    for light in shading.lights:
        lw = np.asarray(light.direction, float) @ R
        lv = geom.unit_axes @ (lw / np.linalg.norm(lw))
        h = lv + view
        h /= max(np.linalg.norm(h), 1e-12)
        rows.append([*lv, *h, *(light.intensity * np.asarray(light.color, float))])
    return np.asarray(rows, dtype=np.float64).reshape(-1, 9)


def central_gradient(vol, spacing):
    """float32[3, k, j, i]: d(density)/d(physical length) along i, j, k (numpy.gradient, edge_order 1)."""
    v = np.asarray(vol, np.float64)
    gk, gj, gi = np.gradient(v, spacing[2], spacing[1], spacing[0], edge_order=1)
    return np.ascontiguousarray(np.stack([gi, gj, gk]).astype(np.float32))


def max_opacity(transfer, lo, hi):
    """Largest opacity of the transfer function's points over each interval [lo, hi] (arrays)."""
    pts = np.asarray(transfer.opacity, float)
    xs, ys = pts[:, 0], pts[:, 1]

    def at(x):
        v = np.interp(x, xs, ys)
        return np.where((x < xs[0]) | (x > xs[-1]), 0.0, v)
    m = np.maximum(at(lo), at(hi))
    for x, y in zip(xs, ys):
        m = np.where((lo <= x) & (x <= hi), np.maximum(m, y), m)
    return m


def render(view, transfer, shading, *, density=None, ml=None, unit=None, step=0.05, threads=None):
    """The reference image of ``view`` as straight RGBA float64 (H, W, 4) over the view's background.

    Exactly one of ``density`` (uint8 or float array [k, j, i] of density codes; the GRID reference) and ``ml``
    (``(fm, alpha, lo, hi)``: the analytic Marschner-Lobb reference on the view's grid) is given. ``step`` is the
    longest piece of a ray in voxels of the smallest spacing; ``unit`` the opacity unit distance (default: the
    transfer function's, else the smallest spacing, as isplat)."""
    from isplat.splat.composite import finish

    if (density is None) == (ml is None):
        raise ValueError("give exactly one of density and ml")
    if len(transfer.gradient_opacity):
        raise ValueError("the ray reference does not model gradient-modulated opacity")
    f, g = view.frame, view.geom
    n = np.asarray(g.n_ijk, dtype=np.float64)
    if min(n) < 2:
        raise ValueError("the ray reference needs at least 2 voxels along every axis")
    sp = np.asarray(g.spacing, np.float64)
    unit = float(unit or transfer.unit_distance or sp.min())
    use_shade = bool(shading.enabled and len(shading.lights))
    if density is not None:
        kind, mlp = GRID, np.zeros(7)
        vol = np.asarray(density)
        vol = np.ascontiguousarray(vol, dtype=vol.dtype if vol.dtype in (np.uint8, np.float32) else np.float32)
        if vol.shape != tuple(g.shape):
            raise ValueError(f"density shape {vol.shape} is not the view's {g.shape}")
        grad = central_gradient(vol, sp) if use_shade else np.zeros((3, 2, 2, 2), np.float32)
        nb = [max(1, -(-(s - 1) // BLOCK)) for s in vol.shape]
        mn, mx = _block_range(vol, *nb)
        empty = (max_opacity(transfer, mn, mx) <= 0.0).astype(np.uint8)
    else:
        kind = MARSCHNER_LOBB
        mlp = np.array([*map(float, ml), *n], dtype=np.float64)
        vol, grad, empty = np.zeros((2, 2, 2), np.float32), np.zeros((3, 2, 2, 2), np.float32), np.zeros((1, 1, 1), np.uint8)
    op = np.asarray(transfer.opacity, np.float64)
    col = np.asarray(transfer.color, np.float64)
    sh = np.array([shading.ambient, shading.diffuse, shading.specular, shading.shininess,
                   1.0 if shading.two_sided else 0.0], np.float64)
    lights = light_rows(shading, f, g) if use_shade else np.zeros((0, 9))
    o, d, t_lo = rays(view)
    out = np.empty((len(o), 4))
    old = numba.get_num_threads()
    if threads:
        numba.set_num_threads(min(int(threads), numba.config.NUMBA_NUM_THREADS))
    try:
        integrate(kind, vol, grad, empty, mlp, o, d, t_lo, n, sp, float(step) * float(sp.min()),
                  np.ascontiguousarray(op[:, 0]), np.ascontiguousarray(op[:, 1]), np.ascontiguousarray(col[:, 0]),
                  np.ascontiguousarray(col[:, 1:4]), unit, use_shade, lights, sh, out)
    finally:
        numba.set_num_threads(old)
    img = out.reshape(f.height, f.width, 4)
    rgba = np.empty_like(img)
    if not finish(img, np.asarray(view.background, dtype=np.float64), rgba):
        raise FloatingPointError("the ray reference produced a non-finite pixel")
    return rgba
