"""Compositing: a slice's sheet into the image, partial images into each other, the image over its background.

Images are premultiplied RGBA, composited front to back with 'over': ``out = front + (1 - front.alpha) * back``,
which is associative, so slabs of slices rendered apart and composited in order give the one-pass frame.
"""

from __future__ import annotations

import numpy as np

from ..jit import jit, leaf, stage

TILE = 8         # pixels per side of the tiles that answer "all saturated?" at once


@stage
def composite_sheet(img, sheet, sat, tile_sat, dirty_px, dirty, nd, et):
    """Composite the slice's sheet over the image front to back (premultiplied 'over') at the ``nd`` pixels
    the slice touched (``dirty``), clear them, and count pixels that crossed the early-termination opacity
    (``sat``, ``tile_sat``); returns how many did."""
    w = img.shape[1]
    newly = 0
    for t in range(nd):
        p = dirty[t]
        y = p // w
        x = p - y * w
        dirty_px[y, x] = 0
        sa = sheet[y, x, 3]
        if sa > 0.0 and sat[y, x] == 0:
            scale = 1.0
            if sa > 1.0:
                # overlapping footprints can sum past 1: keep the colour/opacity ratio
                scale = 1.0 / sa
                sa = 1.0
            ai = img[y, x, 3]
            t1 = 1.0 - ai
            img[y, x, 0] += t1 * sheet[y, x, 0] * scale
            img[y, x, 1] += t1 * sheet[y, x, 1] * scale
            img[y, x, 2] += t1 * sheet[y, x, 2] * scale
            an = ai + t1 * sa
            img[y, x, 3] = an
            if ai < et and an >= et:
                tile_sat[y // TILE, x // TILE] += 1
                sat[y, x] = 1
                newly += 1
        sheet[y, x, 0] = 0.0
        sheet[y, x, 1] = 0.0
        sheet[y, x, 2] = 0.0
        sheet[y, x, 3] = 0.0
    return newly


@leaf(inline="always")    # numba inlines its IR, not LLVM: see isplat.jit.leaf
def saturated(img, sat, tile_sat, x, y, an, cr, cg, cb, fill):
    """Pixel (x, y) has just reached the early-termination opacity (its opacity now ``an``): mark it in ``sat``
    and its tile's count. ``fill`` True (``render.termination = "fill"``): the rest of its transmittance, which
    no later sample will reach, takes the colour (cr, cg, cb) of the sample that reached it, so the pixel becomes
    opaque: the estimate of what lies behind is the material the ray is in, not the background."""
    uy, ux = np.uint64(y), np.uint64(x)
    if fill:
        r = 1.0 - an
        img[uy, ux, np.uint64(0)] += r * cr
        img[uy, ux, np.uint64(1)] += r * cg
        img[uy, ux, np.uint64(2)] += r * cb
        img[uy, ux, np.uint64(3)] = 1.0
    sat[uy, ux] = 1
    tile_sat[y // TILE, x // TILE] += 1


@jit
def over(front, back, out):
    """``out = front over back`` for premultiplied RGBA images (H, W, 4); ``out`` may be ``front``."""
    for y in range(front.shape[0]):
        for x in range(front.shape[1]):
            t = 1.0 - front[y, x, 3]
            for ch in range(4):
                out[y, x, ch] = front[y, x, ch] + t * back[y, x, ch]


@jit
def saturation(img, et, sat, tile_sat):
    """The saturation state of image ``img``: ``sat[y, x] = 1`` where its opacity reached ``et`` (< 1), and
    ``tile_sat`` the number of such pixels per TILE x TILE tile."""
    tile_sat[:] = 0
    for y in range(img.shape[0]):
        for x in range(img.shape[1]):
            s = 1 if et < 1.0 and img[y, x, 3] >= et else 0
            sat[y, x] = s
            tile_sat[y // TILE, x // TILE] += s


@jit
def finish(img, bg, out):
    """Premultiplied RGBA over the background -> straight RGBA in [0, 1]; returns False on a non-finite
    pixel (which must never reach an image)."""
    ok = True
    for y in range(img.shape[0]):
        for x in range(img.shape[1]):
            a = np.float64(img[y, x, 3])
            t = (1.0 - a) * bg[3]
            alpha = a + t
            for ch in range(3):
                v = img[y, x, ch] + t * bg[ch]
                if alpha > 0.0:
                    v = v / alpha
                else:
                    v = 0.0
                if not np.isfinite(v):
                    ok = False
                out[y, x, ch] = min(max(v, 0.0), 1.0)
            if not np.isfinite(alpha):
                ok = False
            out[y, x, 3] = min(max(alpha, 0.0), 1.0)
    return ok
