"""Transfer functions: piecewise-linear maps of density to float lookup tables.

Classification stays in float (never 8-bit opacity: an 8-bit alpha of 0.001 becomes 0 and a faint tissue
vanishes). The opacity correction for the path length ``ds`` through one slice is
``alpha' = 1 - (1 - alpha) ** (ds / unit_distance)``, evaluated as ``-expm1(r * log1p(-alpha))``, which stays
accurate for tiny alphas and exact at alpha = 1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# An alpha of exactly 1 has log1p(-1) = -inf; clamping keeps r * log stays finite (r > 0) while
# alpha' still rounds to 1 in float32.
_ALPHA_MAX = 1.0 - 2.0 ** -40


@dataclass(frozen=True)
class TransferLUTs:
    opacity: np.ndarray          # float64[256], opacity per unit_distance, 0 outside the points' range
    color: np.ndarray            # float32[256, 3]
    gradient: np.ndarray | None  # float64[256] factor per gradient-magnitude code, or None when unused
    intervals: np.ndarray        # int32[m, 2]: inclusive density runs where opacity > 0


def piecewise_linear(points, x, outside_zero: bool) -> np.ndarray:
    """Evaluate a piecewise-linear map given as rows ``[x, y...]`` at ``x``.

    Beyond the first and last point the value is 0 when ``outside_zero`` else the end value.
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or len(pts) == 0:
        raise ValueError("piecewise_linear needs at least one point")
    xs, ys = pts[:, 0], pts[:, 1:]
    x = np.asarray(x, dtype=np.float64)
    out = np.stack([np.interp(x, xs, ys[:, c]) for c in range(ys.shape[1])], axis=-1)
    if outside_zero:
        out[(x < xs[0]) | (x > xs[-1])] = 0.0
    return out


def nonzero_intervals(opacity: np.ndarray) -> np.ndarray:
    """Inclusive runs ``[lo, hi]`` of densities with opacity > 0 (a TF may have several disjoint ones)."""
    nz = np.concatenate([[False], opacity > 0, [False]])
    edges = np.flatnonzero(nz[1:] != nz[:-1])
    return np.stack([edges[0::2], edges[1::2] - 1], axis=1).astype(np.int32).reshape(-1, 2)


def build_luts(transfer, gradient_magnitude_scale: float) -> TransferLUTs:
    """Tabulate a scene's transfer functions for density codes 0..255 and gradient codes 0..255."""
    d = np.arange(256, dtype=np.float64)
    opacity = np.clip(piecewise_linear(transfer.opacity, d, outside_zero=True)[:, 0], 0.0, 1.0)
    color = np.clip(piecewise_linear(transfer.color, d, outside_zero=False), 0.0, 1.0).astype(np.float32)
    gradient = None
    if len(transfer.gradient_opacity):
        mags = d * float(gradient_magnitude_scale)
        gradient = np.clip(piecewise_linear(transfer.gradient_opacity, mags, outside_zero=False)[:, 0], 0.0, 1.0)
    return TransferLUTs(opacity, color, gradient, nonzero_intervals(opacity))


def corrected_alpha(alpha, r):
    """Opacity for path length ``r`` unit distances: ``1 - (1 - alpha)**r`` computed stably."""
    a = np.minimum(np.asarray(alpha, dtype=np.float64), _ALPHA_MAX)
    return -np.expm1(r * np.log1p(-a))


def alpha_table(luts: TransferLUTs, r: float | None) -> np.ndarray:
    """float32[256, G] table indexed by (density, gradient code), G = 1 without gradient modulation.

    With ``r`` (orthographic: one path length for every voxel) the table holds corrected opacities;
    with ``r=None`` (perspective: path length varies per voxel) it holds ``log1p(-alpha)`` and the kernel
    finishes the correction per voxel.
    """
    alpha = luts.opacity[:, None]
    if luts.gradient is not None:
        alpha = alpha * luts.gradient[None, :]
    alpha = np.minimum(alpha, _ALPHA_MAX)
    if r is None:
        return np.log1p(-alpha).astype(np.float32)
    return corrected_alpha(alpha, r).astype(np.float32)
