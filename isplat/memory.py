"""Volumes already in memory as the renderer's channels (for notebooks, tests and Dask chunks)."""

from __future__ import annotations

import numpy as np

from .errors import IsplatError


def check_volume(volume, spacing, who: str = "array") -> tuple[np.ndarray, tuple[float, float, float]]:
    """``volume`` as a non-empty 3-D array ``[k, j, i]`` and ``spacing`` (i, j, k; None: 1) as three positive
    floats; anything else is one :class:`IsplatError` line starting with ``who``."""
    arr = np.asarray(volume)
    if arr.ndim != 3 or min(arr.shape) < 1:
        raise IsplatError(f"{who}: expected a non-empty 3-D volume [k, j, i], got shape {arr.shape}")
    try:
        sp = tuple(float(s) for s in (spacing or (1.0, 1.0, 1.0)))
    except (TypeError, ValueError):
        sp = (float("nan"),)
    if len(sp) != 3 or not all(np.isfinite(sp)) or min(sp) <= 0:
        raise IsplatError(f"{who}: spacing {spacing!r} invalid; expected three positive numbers (i, j, k)")
    return arr, sp


def channels_in_memory(density, scene, normal=None, gradient_magnitude=None, gradient_magnitude_scale=None,
                       spacing=None, window=None):
    """``({channel: array [k, j, i]}, gradient_magnitude_scale, spacing_ijk)`` for :meth:`Selection.from_arrays`.

    Augmented codes are taken as they are when every channel the scene needs is given; anything else (a float
    or wider volume, or missing channels) is augmented first, with ``window`` (see
    :func:`isplat.augment.augment_array`). Spacing: ``spacing``, else the scene's ``volume.spacing``, else 1.
    """
    arr, sp = check_volume(density, spacing or scene.volume.spacing)
    needs_normal = bool(scene.shading.enabled)
    needs_gm = len(scene.transfer.gradient_opacity) > 0
    wanted = (("normal", normal, needs_normal), ("gradient_magnitude", gradient_magnitude, needs_gm))
    missing = [name for name, value, need in wanted if need and value is None]
    if missing and (normal is not None or gradient_magnitude is not None):
        raise IsplatError(f"array: the scene needs {missing[0]} codes too; pass them, or pass no channels and "
                          "let isplat augment the volume")
    if arr.dtype != np.uint8 or missing:
        from .augment import augment_array

        if arr.dtype == np.uint8 and window is None:
            window = (0.0, 255.0)                   # codes stay codes
        out = augment_array(arr, sp, window)
        chans = {ch: out[ch] for ch in ("density", "gradient_magnitude", "normal")}
        return chans, float(out["gradient_magnitude_scale"]), sp
    chans = {"density": np.ascontiguousarray(arr)}
    for name, value, dt in (("normal", normal, np.uint16), ("gradient_magnitude", gradient_magnitude, np.uint8)):
        if value is None:
            continue
        v = np.asarray(value)
        if v.shape != arr.shape or v.dtype != dt:
            raise IsplatError(f"array: {name} has shape {v.shape} and dtype {v.dtype}; expected {arr.shape} "
                              f"and {np.dtype(dt)} (augmented codes)")
        chans[name] = np.ascontiguousarray(v)
    gscale = 1.0 if gradient_magnitude_scale is None else float(gradient_magnitude_scale)
    if not np.isfinite(gscale) or gscale < 0:
        raise IsplatError(f"array: gradient_magnitude_scale = {gscale}; expected a finite number >= 0")
    return chans, gscale, sp
