"""Transfer-function points in data units (Hounsfield units for CT) to the augmented file's density codes.

The augment window ``(LO, HI)`` maps a value ``x`` to the code ``(x - LO) * 255 / (HI - LO)`` (formats/augmented.md
§4, before rounding); a gradient magnitude in data units per world unit scales by ``255 / (HI - LO)``.
"""

from __future__ import annotations

import numpy as np

CODE_TOLERANCE = 1e-9   # codes within this of 0 or 255 count as inside the window (float rounding)


def to_code(x, window):
    """Density code of data value(s) ``x`` through ``window = (LO, HI)`` (no clipping)."""
    lo, hi = window
    return (np.asarray(x, dtype=np.float64) - lo) * 255.0 / (hi - lo)


def to_data(code, window):
    """Data value of density code(s): the inverse of :func:`to_code`."""
    lo, hi = window
    return lo + np.asarray(code, dtype=np.float64) * ((hi - lo) / 255.0)


def gradient_to_code(magnitude, window):
    """A gradient magnitude in data units per world unit as density codes per world unit."""
    lo, hi = window
    return np.asarray(magnitude, dtype=np.float64) * (255.0 / (hi - lo))


def inside(code) -> bool:
    return -CODE_TOLERANCE <= code <= 255.0 + CODE_TOLERANCE


def clip_points(points, zero_outside: bool) -> tuple:
    """Restrict a piecewise-linear map ``[(code, values...)]`` (increasing codes) to codes 0..255.

    Points outside are dropped and replaced by the map's value at the window's end, so the map over 0..255 is
    unchanged. With ``zero_outside`` (opacity) a map wholly outside gives ``()``; otherwise (colour, clamped
    beyond its ends) the nearest end value is kept at 0 or 255.
    """
    pts = np.asarray(points, dtype=np.float64)
    xs = pts[:, 0]
    if xs[-1] < 0 or xs[0] > 255:
        if zero_outside:
            return ()
        end = pts[-1] if xs[-1] < 0 else pts[0]
        return ((0.0 if xs[-1] < 0 else 255.0, *end[1:]),)
    out = []
    for edge in (0.0, 255.0):
        if xs[0] < edge < xs[-1] and not np.any(xs == edge):
            out.append([edge, *(np.interp(edge, xs, pts[:, c]) for c in range(1, pts.shape[1]))])
    keep = pts[(xs >= 0.0) & (xs <= 255.0)]
    rows = sorted([list(r) for r in keep] + out, key=lambda r: r[0])
    return tuple(tuple(float(v) for v in r) for r in rows)
