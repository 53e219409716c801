"""Best-effort copies of thick-slice data on a thin grid, for docs/thick-slices.md (benchmarks/thick.py).

Each reconstruction uses only the thick data: the value at a point between slices is a fixed linear combination
of the slices along the thick axis (array axis 0, ``[k, j, i]``), so each is a matrix ``W`` (thin slices x thick
slices) applied along that axis (:func:`weights`, :func:`resample`). The thin grid is the object's (the sample's
normalised coordinates put both grids on the same box, centred: isplat.camera.volume_geometry), so a copy renders
at the same camera as the object and can be compared with it pixel for pixel.

Reconstructions (:data:`METHODS`):

- ``bspline3``, ``bspline5``: interpolating B-splines of degree 3 and 5 (Unser 1999; what
  ``scipy.ndimage.zoom(order=3|5, mode="mirror")`` computes along one axis): coefficients ``c`` solving
  ``v[k] = sum_j c[j] beta(k - j)`` on the data mirrored :data:`PAD` slices past each end (the mirrored data is
  what the prefilter's boundary condition assumes; the filter's poles, 0.27 and 0.43, make the truncation past
  ``PAD`` slices negligible), evaluated as ``sum_j c[j] beta(x - j)``;
- ``lanczos3``: windowed sinc, ``sinc(d) sinc(d / 3)`` over the six nearest slices, normalised to sum 1 (indices
  clamped at the ends);
- ``catmull-rom``: the cubic isplat's post-classified sampler evaluates between thick slices
  (isplat.splat.post.cubic, kind 1), here as a copy: the same density, the normals differenced on the thin grid.

:func:`blend_gradients` gives a copy the thick file's own normals instead, mixed along k with the cubic
B-spline's weights as the sampler's shading between thick slices does: a copy with the default's shading and
another density (benchmarks/thick.py ``best_effort_images``, methods ending in ``+shading``).
"""

from __future__ import annotations

import math

import numpy as np

METHODS = ("bspline3", "bspline5", "lanczos3", "catmull-rom")
PAD = 24           # mirrored slices past each end for the B-spline's coefficients


def positions(n_thick: int, step_thick: float, n_thin: int, step_thin: float) -> np.ndarray:
    """The thin slices' positions in thick-slice index units (both grids centred on the same point)."""
    world = (np.arange(n_thin) - (n_thin - 1) / 2.0) * step_thin
    return world / step_thick + (n_thick - 1) / 2.0


def bspline_basis(x, degree: int) -> np.ndarray:
    """The centred B-spline of ``degree`` at ``x``: (1/d!) sum_k (-1)^k C(d+1, k) max(0, x + (d+1)/2 - k)^d."""
    x = np.asarray(x, np.float64)
    d = degree
    out = np.zeros_like(x)
    for k in range(d + 2):
        out += (-1) ** k * math.comb(d + 1, k) * np.maximum(0.0, x + (d + 1) / 2.0 - k) ** d
    return out / math.factorial(d)


def _mirror(n: int, pad: int) -> np.ndarray:
    """The (n + 2 pad) x n matrix that mirrors n samples about their end samples (numpy's "reflect")."""
    idx = np.arange(-pad, n + pad)
    period = 2 * (n - 1)
    idx = np.mod(idx, period)
    idx = np.where(idx >= n, period - idx, idx)
    M = np.zeros((n + 2 * pad, n))
    M[np.arange(n + 2 * pad), idx] = 1.0
    return M


def _bspline(n: int, x: np.ndarray, degree: int) -> np.ndarray:
    pad = PAD
    N = n + 2 * pad
    j = np.arange(N)
    A = bspline_basis(j[:, None] - j[None, :], degree)              # collocation: A c = mirrored data
    E = bspline_basis((np.clip(x, 0, n - 1) + pad)[:, None] - j[None, :], degree)
    return E @ np.linalg.solve(A, _mirror(n, pad))


def _lanczos(n: int, x: np.ndarray, a: int = 3) -> np.ndarray:
    W = np.zeros((len(x), n))
    for r, p in enumerate(np.clip(x, 0, n - 1)):
        base = math.floor(p)
        js = np.arange(base - a + 1, base + a + 1)
        d = p - js
        w = np.sinc(d) * np.sinc(d / a)
        np.add.at(W[r], np.clip(js, 0, n - 1), w / w.sum())
    return W


def _catmull_rom(n: int, x: np.ndarray) -> np.ndarray:
    W = np.zeros((len(x), n))
    for r, p in enumerate(np.clip(x, 0, n - 1)):
        k = min(int(math.floor(p)), n - 2)
        t = p - k
        w = ((-t ** 3 + 2 * t * t - t) / 2, (3 * t ** 3 - 5 * t * t + 2) / 2, (-3 * t ** 3 + 4 * t * t + t) / 2,
             (t ** 3 - t * t) / 2)
        for dj, wj in zip((-1, 0, 1, 2), w):
            W[r, min(max(k + dj, 0), n - 1)] += wj
    return W


def bspline_smoothing(n: int, x: np.ndarray) -> np.ndarray:
    """The cubic B-spline's own weights ``beta3(x - j)`` over the four nearest slices (indices clamped): not
    interpolating; what isplat's post-classified sampler mixes the Phong factors of four thick slices with
    (isplat/splat/post.py ``_shade_between``)."""
    W = np.zeros((len(x), n))
    for r, p in enumerate(np.clip(x, 0, n - 1)):
        b = math.floor(p)
        for j in range(b - 1, b + 3):
            W[r, min(max(j, 0), n - 1)] += bspline_basis(p - j, 3)
    return W


def blend_gradients(normal_codes, gm, step_thick: float, n_thin: int, step_thin: float):
    """The thick file's gradients (its normal codes times its gradient magnitude codes, [k, j, i]) on the thin
    slices by :func:`bspline_smoothing` along k: ``(normal codes, gradient magnitude codes)`` of the thin grid,
    the normals the blended gradients' directions. A copy's stand-in for the sampler's shading between thick
    slices (which mixes the Phong factors, not the gradients, with these weights)."""
    from isplat import normals

    n = normal_codes.shape[0]
    W = bspline_smoothing(n, positions(n, step_thick, n_thin, step_thin)).astype(np.float32)
    g = normals.decode(normal_codes).astype(np.float32) * gm[..., None].astype(np.float32)
    nrm = np.empty((n_thin,) + normal_codes.shape[1:], np.uint16)
    mag = np.empty((n_thin,) + normal_codes.shape[1:], np.uint8)
    for k0 in range(0, n_thin, 32):
        gr = np.tensordot(W[k0:k0 + 32], g, axes=(1, 0))
        ln = np.linalg.norm(gr, axis=-1)
        nrm[k0:k0 + 32] = normals.encode(gr / np.maximum(ln, 1e-12)[..., None])
        mag[k0:k0 + 32] = np.clip(np.rint(np.tensordot(W[k0:k0 + 32], gm.astype(np.float32), axes=(1, 0))), 0, 255)
    return nrm, mag


def weights(method: str, n: int, x: np.ndarray) -> np.ndarray:
    """The matrix (len(x) x n) of ``method`` (:data:`METHODS`) from ``n`` slices to the positions ``x`` (thick
    index units; clamped to [0, n - 1]: the ends repeat the end slices' reconstruction)."""
    if method == "bspline3":
        return _bspline(n, x, 3)
    if method == "bspline5":
        return _bspline(n, x, 5)
    if method == "lanczos3":
        return _lanczos(n, x)
    if method == "catmull-rom":
        return _catmull_rom(n, x)
    raise ValueError(f"unknown reconstruction {method!r}; expected one of {METHODS}")


def resample(vol, step_thick: float, n_thin: int, step_thin: float, method: str) -> np.ndarray:
    """``vol`` [k, j, i] (slices ``step_thick`` apart along k) on ``n_thin`` slices ``step_thin`` apart, by
    ``method``: float32, values clipped to ``vol``'s range (the higher-order kernels overshoot at edges)."""
    v = np.asarray(vol, np.float32)
    n = v.shape[0]
    W = weights(method, n, positions(n, step_thick, n_thin, step_thin)).astype(np.float32)
    out = np.tensordot(W, v, axes=(1, 0))
    np.clip(out, v.min(), v.max(), out=out)
    return np.ascontiguousarray(out, dtype=np.float32)
