"""The Gaussian reconstruction kernel and its projected footprint (Westover 1990), as a 1-D table.

The kernel is an isotropic Gaussian of ``sigma`` grid steps in *grid* space, so with anisotropic spacing it
is an ellipsoid in the world, and its projection is an elliptical 2-D Gaussian with covariance
``Sigma = sigma^2 J J^T`` (J: pixel motion per grid step along a, b, c). The table is indexed by the squared
Mahalanobis distance ``q = [dx dy] Sigma^-1 [dx dy]^T`` in ``[0, radius^2)``, so one table serves every
orientation and (in perspective) every depth, scaled by ``1/t0^2``.

Weights are normalised so that a slice of voxels of equal opacity gives that opacity in the sheet
(partition of unity over the projected slice lattice): ``A_cell / (2 pi sqrt(det Sigma))`` with ``A_cell`` the
projected area of one lattice cell of the slice, divided by the kernel mass kept inside the cut-off radius.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# Below about half a pixel a footprint falls between pixel centres and the sheet stops summing to the slice's
# opacity (aliasing); the footprint is widened to at least this many pixels (Swan et al. 1997 widen the kernel
# when the image samples the volume too coarsely).
MIN_SIGMA_PIXELS = 0.5


@dataclass(frozen=True)
class Footprint:
    table: np.ndarray      # float32[T + 1]: weight at q in [t/tscale, (t+1)/tscale); table[T] = 0
    params: np.ndarray     # float64[7]: Qa, Qb, Qc, ex, ey, R2, tscale


def make_footprint(jac: np.ndarray, sigma: float, radius: float, table_size: int,
                   dtype=np.float32) -> Footprint:
    """Footprint for a projection with pixel Jacobian ``jac`` (2x3: per grid step along a, b, c)."""
    J = np.asarray(jac, dtype=np.float64)
    Sigma = sigma * sigma * (J @ J.T)
    lam, V = np.linalg.eigh(Sigma)
    lam = np.maximum(lam, MIN_SIGMA_PIXELS ** 2)
    Sigma = (V * lam) @ V.T
    Q = np.linalg.inv(Sigma)
    det = float(np.linalg.det(Sigma))
    a_cell = abs(J[0, 0] * J[1, 1] - J[0, 1] * J[1, 0])
    R2 = float(radius) ** 2
    kept = -math.expm1(-0.5 * R2)            # kernel mass inside the cut-off
    norm = a_cell / (2.0 * math.pi * math.sqrt(det)) / kept
    tscale = table_size / R2
    t = (np.arange(table_size) + 0.5) / tscale
    # one trailing zero: the kernel clamps q to radius^2 and reads 0 there, without a branch
    table = np.append(norm * np.exp(-0.5 * t), 0.0).astype(dtype)
    ex = radius * math.sqrt(Sigma[0, 0])
    ey = radius * math.sqrt(Sigma[1, 1])
    params = np.array([Q[0, 0], Q[0, 1], Q[1, 1], ex, ey, R2, tscale], dtype=np.float64)
    return Footprint(table, params)


def footprint_weight(fp: Footprint, dx, dy, s=1.0):
    """Weight of the footprint at pixel offset (dx, dy) for scale ``s`` (numpy; for tests)."""
    Qa, Qb, Qc, _, _, R2, tscale = fp.params
    q = (Qa * dx * dx + 2 * Qb * dx * dy + Qc * dy * dy) / (s * s)
    idx = np.minimum((q * tscale).astype(np.int64), len(fp.table) - 2)
    return np.where(q < R2, fp.table[idx], 0.0)
