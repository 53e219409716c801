"""Thick slices made thin: linear interpolation along an axis whose spacing is much larger than the others.

Why (docs/sheets.md, "Thick slices"): isplat classifies each voxel before reconstruction (pre-classified
splatting), and its kernel is a Gaussian in grid steps, so a voxel of a 7 mm slice is a 7 mm tall footprint of
one colour and opacity. Between two slices the image is a cross-fade of the two slices' classified footprints,
composited in the order of their depths, instead of the interpolated density classified: the boundaries of
structures do not move smoothly from one slice to the next but jump, with vertical edges where the two
slices' boundaries differ (streaks along the slice axis in a side view), and pre-shaded colours of
neighbouring slices mix in an order that changes from column to column. Interpolating the scan's values
along the thick axis first, and augmenting (classifying, shading) the interpolated grid, is the reconstruction
a trilinear ray caster applies; on an integer refinement it is exactly the trilinear field of the original
grid, so no information is invented or lost.

``thin_slices(array, spacing)`` refines every axis whose spacing exceeds ``max_ratio`` times the smallest by
the integer factor ``f = ceil(spacing / (max_ratio * smallest))``: ``n`` samples become ``(n - 1) f + 1``,
the original samples kept at every ``f``-th position (voxel 0 and the volume's extent do not move), spacing
``spacing / f``.
"""

from __future__ import annotations

import math

import numpy as np

from .errors import IsplatError

THICK_RATIO = 2.0        # slices thicker than this many times the smallest spacing are refined
MAX_VOXELS = 2 ** 31     # the renderer's limit (isplat.samples, the index)


def thin_factors(spacing_ijk, max_ratio: float = THICK_RATIO) -> tuple[int, int, int]:
    """The integer refinement of each axis (i, j, k): 1 unless its spacing exceeds ``max_ratio`` times the
    smallest."""
    sp = [float(s) for s in spacing_ijk]
    if not max_ratio >= 1.0:
        raise IsplatError(f"thin slices: ratio {max_ratio!r}; expected a number >= 1")
    lo = min(sp)
    return tuple(max(1, math.ceil(s / (max_ratio * lo) - 1e-9)) for s in sp)


def thin_slices(array, spacing_ijk, max_ratio: float = THICK_RATIO, who: str = "volume"):
    """``(array [k, j, i], spacing_ijk)`` with thick axes refined by linear interpolation (module docstring);
    the input unchanged when no axis is thick. The result is float32 (float64 for a float64 input)."""
    factors = thin_factors(spacing_ijk, max_ratio)
    if factors == (1, 1, 1):
        return array, tuple(float(s) for s in spacing_ijk)
    shape = list(np.shape(array))
    new = [(n - 1) * f + 1 if n > 1 else 1 for n, f in zip(shape, factors[::-1])]
    if math.prod(new) > MAX_VOXELS:
        raise IsplatError(f"{who}: thin slices would make {'x'.join(map(str, new[::-1]))} voxels (NI,NJ,NK), more "
                          f"than {MAX_VOXELS:,}; crop the volume first")
    out = np.asarray(array)
    if out.dtype != np.float64:
        out = out.astype(np.float32)
    for axis, f in zip((2, 1, 0), factors):          # i, j, k are array axes 2, 1, 0
        if f > 1 and out.shape[axis] > 1:
            out = _refine(out, axis, f)
    spacing = tuple(float(s) / f if n > 1 else float(s) for s, f, n in zip(spacing_ijk, factors, shape[::-1]))
    return np.ascontiguousarray(out), spacing


def _refine(a: np.ndarray, axis: int, f: int) -> np.ndarray:
    """Linear interpolation of ``a`` along ``axis`` at every 1/f of a step (the samples kept)."""
    n = a.shape[axis]
    m = np.arange((n - 1) * f + 1)
    i0 = np.minimum(m // f, n - 2)
    t = ((m - i0 * f) / f).astype(a.dtype)
    shape = [1] * a.ndim
    shape[axis] = -1
    t = t.reshape(shape)
    lo = np.take(a, i0, axis=axis)
    lo *= 1 - t                                   # (1 - t) lo + t hi: exact at t = 0 and t = 1
    hi = np.take(a, i0 + 1, axis=axis)
    hi *= t
    lo += hi
    return lo


def thin_volume(vol, max_ratio: float = THICK_RATIO, who: str = "volume"):
    """A :class:`isplat.volume_io.Volume` with thick slices refined (``meta["thinned_from"]``: the original
    spacing and shape), or ``vol`` itself when none is thick."""
    arr, sp = thin_slices(vol.array, vol.spacing_ijk, max_ratio, who)
    if arr is vol.array:
        return vol
    meta = dict(vol.meta, thinned_from={"spacing_ijk": list(vol.spacing_ijk),
                                        "shape_ijk": list(np.shape(vol.array)[::-1])})
    return type(vol)(arr, sp, meta)
