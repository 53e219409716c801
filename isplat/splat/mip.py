"""Maximum- and minimum-intensity projection (``render.mode = "mip"`` / ``"minip"``) by the index.

Reconstruction is the default technique's (:mod:`isplat.splat.post`): along each pixel's ray the density is
sampled where the ray crosses the slice planes of the principal axis, bilinearly in each slice (the trilinear
field at the slice planes; the edge voxel repeated half a voxel beyond the outer centres), at the quads (squares
between four voxels) one of whose voxels is of interest (a density of non-zero opacity); on a grid whose thicker
in-slice axis is at least :data:`isplat.splat.post.THICK_RATIO` times the finest, the post technique's cubic
along that axis (Catmull-Rom, clamped to the codes: :func:`isplat.splat.post._density_at`), so a MIP of thick
slices shows no terraces of them either (docs/thick-slices.md). The pixel keeps the largest (MIP) or smallest
(MinIP) sample: what a ray caster's MIP shows at the same sampling.

The order is the index's, not the slices': the unit of work is a cell of the selection (4 x 4 voxels of one slice,
the voxels of interest among them) with the quads it owns (those whose first corner of interest is one of its
voxels, so that each quad belongs to one unit), and its *bound*, the highest density of those quads' corners
(MIP; the lowest for MinIP): no sample of the unit can exceed it, since a bilinear sample lies between its
corners (along a thick axis, where the density is the post-classified technique's cubic between slices, those
corners' and the cubic's neighbours' extremes widened by what the cubic can overshoot them, :func:`_cubic_bounds`).
The units of a selection's axis are made once (:func:`units_of`, kept beside the selection) and copied
in order of bound, from high to low (MIP) or from low to high (MinIP), so a frame visits the high densities
first and reads the units in sequence. A unit is skipped when every pixel it reaches already holds at least
its bound: such pixels are finished for it and for every unit after it, whose bounds are no higher, so a tile
of pixels once found finished stays so (:data:`Held`, :func:`_tiles_hold`: a few tests per unit), else its
pixels are looked at one by one (:func:`_unit`) and its quads sampled at the pixels that are not finished.
Exact whatever the order: a skipped unit cannot raise any pixel. Each band lists the units that reach its rows
first, then walks them with the next units' densities prefetched (they lie anywhere in the volume). Early
termination, footprints, shading and slab compositing do not apply
(docs/mip.md).

A technique of :mod:`isplat.splat.traverse`: its plan (:data:`MipPlan`) has one "sheet" (the frame's one pass
over the sorted units), its slice stage (:func:`_slice`) walks the units for one band of image rows and writes
the band's pixels, and it reuses the traversal's per-slice bases, cuts and the post technique's pixel scan
(:func:`isplat.splat.post._cell_pixels`, ``_row_pixels``, ``_pixel_quad``, ``_ortho_inverse``). Counters:
``stats[band, 0]`` the voxels of interest of the frame's slices, ``[band, 1]`` those in units visited (not
skipped) in the band, ``[band, 2]`` samples taken.
"""

from __future__ import annotations

import math
import weakref
from collections import namedtuple

import numpy as np

from ..jit import jit, leaf, prefetch, stage
from .composite import TILE
from .select import BLOCK, CELL, cell_origins
from .traverse import X0, XA, XB, XC, Y0, YA, YB, YC, cut_away, register, slice_bases
from .post import (SPLINE_OVERSHOOT, SPLINE_REACH, _between, _cell_pixels, _density_at, _ortho_inverse, _pixel_box,
                   _pixel_quad, _row_pixels, _taps)

Units = namedtuple("Units", "c a0 b0 owned ext count hi lo")
Units.__doc__ = """The units of one axis of a selection (one row per cell holding a voxel of interest): slice
``c``, the cell's first voxel ``(a0, b0)``, ``owned`` the quads it samples (bit ``5 (qb - b0 + 1) + qa - a0 + 1``
of the 5 x 5 quads from (a0 - 1, b0 - 1); :func:`_put`), ``ext`` the columns and rows of the 5 x 5 that hold
an owned quad (first and one past the last, 3 bits each: ka0, ka1, kb0, kb1), ``count`` its voxels of interest, and
the highest
(``hi``) and lowest (``lo``) density of its quads' corners (int32 each)."""
MipPlan = namedtuple("MipPlan", "units in_frame whole geo sign window color use_color held between")
MipPlan.__doc__ = """A frame's tables: ``units`` (:data:`Units`) by bound (high to low for MIP, low to high for
MinIP, :func:`sorted_units`), ``in_frame`` uint8 per slice (1: a slice of the view's order), ``whole`` the whole
channels (:data:`isplat.splat.traverse.WholeVolume`), ``geo`` :data:`isplat.splat.traverse.SliceGeometry`,
``sign`` 1.0 (MIP) or -1.0 (MinIP; a pixel holds ``sign * density``), ``window`` (lo, hi) the codes mapped to
black and white, ``color`` float64[256, 6] the transfer function's colour with its steps to the next code
(:func:`isplat.splat.post.lerp_tables`) and ``use_color``; ``held`` (:data:`Held`), shared by the threads (each
writes its bands' rows, whole tiles); ``between`` the reconstruction between thick slices, as the post-classified
technique's ``PostClassify.between``: None, bilinear (numba then compiles the frame without the cubic, by type:
:func:`isplat.splat.post._taps`); else :func:`isplat.splat.post.between_slices`' cubic along the thick in-slice
axis (:func:`isplat.splat.post._density_at`)."""
Held = namedtuple("Held", "px tile_done")
Held.__doc__ = """What the pixels hold: ``px`` float64 (H, W) each pixel's ``sign *`` extreme so far (-inf: no
sample); per TILE x TILE tile ``tile_done`` how many of its pixels, in row order, are known to hold the bound of
the unit being drawn (TILE * TILE: all, the tile is finished). Held values only grow and the bounds only fall
as a frame goes on, so a pixel once found finished stays finished: the count only grows (:func:`_tiles_hold`,
each pixel looked at about once per frame), and a unit whose tiles are all finished is skipped with a few
tests instead of a scan of its pixels."""


# ---- the units, once per selection and axis ---------------------------------------------------------------------
_UNITS = {}             # (id(selection), axis, sign) -> Units, dropped with the selection
AHEAD = 4               # units prefetched ahead of the one sampled


def units_of(sel, axis: str, sign: float, thick: int = 0, kind: int = 1) -> Units:
    """The :data:`Units` of ``axis`` of the selection ``sel`` (the index's voxels of interest; with the full method
    every voxel of a density of interest) in the frame's order for ``sign`` 1 (MIP) or -1 (MinIP)
    (:func:`sorted_units`), so that a frame reads them in sequence, their bounds those of the cubic along the
    in-slice axis ``thick`` (1 a, 2 b; 0 bilinear) of kind ``kind`` (:data:`isplat.splat.post.CUBIC_KINDS`); made
    once and kept while the selection lives."""
    key = (id(sel), axis, sign, thick, kind)
    got = _UNITS.get(key)
    if got is None:
        units = make_units(sel, axis, thick, kind)
        got = Units(*(np.ascontiguousarray(x[sorted_units(units, sign)]) for x in units))
        _UNITS[key] = got
        weakref.finalize(sel, _UNITS.pop, key, None)
    return got


def make_units(sel, axis: str, thick: int = 0, kind: int = 1) -> Units:
    """The :data:`Units` of ``axis`` of ``sel`` in the selection's order (slice, region, block, cell); ``thick``
    and ``kind`` as :func:`units_of`."""
    w = sel.whole_volume(axis)
    interest = interest_table(sel.luts.intervals)
    if sel.method == "full":
        return Units(*_full_units(w.density, interest, w.strides, w.n_a, w.n_b, _n_slices(sel, axis), thick,
                                   kind))
    v = sel.voxels(axis)
    return Units(*_indexed_units(v.slice_ptr, v.region_ptr, v.region_id, v.block_pos, v.block_ptr, v.block_voxel,
                                 v.cell_pos, v.cell_count, v.offset, w.density, interest, w.strides, w.n_a, w.n_b,
                                 thick, kind))


def interest_table(intervals) -> np.ndarray:
    """uint8[256]: 1 for the densities of interest (the transfer function's intervals ``[lo, hi]``, inclusive)."""
    table = np.zeros(256, np.uint8)
    for lo, hi in np.asarray(intervals, np.int64).reshape(-1, 2):
        table[max(lo, 0):min(hi, 255) + 1] = 1
    return table


def _n_slices(sel, axis: str) -> int:
    from .. import grid

    return int(grid.slice_shape(sel.shape, axis)[0])


@jit
def _indexed_units(slice_ptr, region_ptr, region_id, block_pos, block_ptr, block_voxel, cell_pos, cell_count,
                   offset, density, interest, strides, n_a, n_b, thick, kind):
    """:data:`Units` from the index's hierarchy of one axis (slices, regions, blocks, cells, voxels: the cells in
    order, :func:`isplat.splat.select.cell_origins`); ``thick`` the axis of the cubic between slices
    (:func:`_put`)."""
    cc, ca, cb, cv = cell_origins(slice_ptr, region_id, region_ptr, block_pos, block_ptr, block_voxel, cell_pos,
                                  cell_count, n_a)
    c_of, a_of, b_of, owned, ext, count, hi, lo = _unit_arrays(cc.shape[0])
    for q in range(cc.shape[0]):
        m = 0
        for t in range(cv[q], cv[q] + cell_count[q]):
            m |= 1 << offset[t]
        _put(q, cc[q], ca[q], cb[q], m, density, interest, strides, n_a, n_b, thick, kind, c_of, a_of, b_of, owned,
             ext, count, hi, lo)
    return c_of, a_of, b_of, owned, ext, count, hi, lo


@jit
def _full_units(density, interest, strides, n_a, n_b, n_slices, thick, kind):
    """:data:`Units` of every voxel whose density is of interest (``interest`` uint8[256]), for the full method;
    ``thick`` the axis of the cubic between slices (:func:`_put`)."""
    nca = (n_a + CELL - 1) // CELL
    ncb = (n_b + CELL - 1) // CELL
    c_of, a_of, b_of, owned, ext, count, hi, lo = _unit_arrays(n_slices * nca * ncb)
    nu = 0
    for c in range(n_slices):
        cbase = c * strides[2] + strides[3]
        for cb in range(ncb):
            for ca in range(nca):
                m = 0
                for b in range(cb * CELL, min(cb * CELL + CELL, n_b)):
                    for a in range(ca * CELL, min(ca * CELL + CELL, n_a)):
                        if interest[density[cbase + a * strides[0] + b * strides[1]]]:
                            m |= 1 << ((b - cb * CELL) * CELL + a - ca * CELL)
                if m:
                    _put(nu, c, ca * CELL, cb * CELL, m, density, interest, strides, n_a, n_b, thick, kind, c_of,
                         a_of, b_of, owned, ext, count, hi, lo)
                    nu += 1
    return c_of[:nu], a_of[:nu], b_of[:nu], owned[:nu], ext[:nu], count[:nu], hi[:nu], lo[:nu]


@stage
def _unit_arrays(n):
    return (np.empty(n, np.int32), np.empty(n, np.int32), np.empty(n, np.int32), np.empty(n, np.int32),
            np.empty(n, np.int32), np.empty(n, np.int32), np.empty(n, np.int32), np.empty(n, np.int32))


@leaf
def _put(u, c, a0, b0, m, density, interest, strides, n_a, n_b, thick, kind, c_of, a_of, b_of, owned, ext, count, hi,
         lo):
    """Unit ``u``: the cell from (a0, b0) of slice ``c`` with voxels of interest ``m``. Its quads are those whose
    first corner of interest (in the order (qa, qb), (qa + 1, qb), (qa, qb + 1), (qa + 1, qb + 1), clamped at
    the slice's edge) is one of its voxels, so every quad with a corner of interest belongs to exactly one unit
    (the quads from (a0 - 1, b0 - 1) to (a0 + 3, b0 + 3) are the only ones that can); its bounds are the extremes
    of those quads' corners, or with a cubic along a thick axis (``thick`` 1 a, 2 b: :func:`_cubic_bounds`)
    of the samples the cubic can make of them."""
    cbase = c * strides[2] + strides[3]
    sa, sb = strides[0], strides[1]
    dmax = 0
    dmin = 255
    bits = 0
    for qb in range(max(b0 - 1, 0), min(b0 + CELL, n_b)):
        for qa in range(max(a0 - 1, 0), min(a0 + CELL, n_a)):
            first = -1
            dq_max = 0
            dq_min = 255
            for corner in range(4):
                ca = min(qa + (corner & 1), n_a - 1)
                cb = min(qb + (corner >> 1), n_b - 1)
                d = np.int32(density[cbase + ca * sa + cb * sb])
                dq_max = max(dq_max, d)
                dq_min = min(dq_min, d)
                if first < 0 and interest[d]:
                    first = corner
                    mine = a0 <= ca < a0 + CELL and b0 <= cb < b0 + CELL
            if first >= 0 and mine:
                if thick != 0:
                    dq_max, dq_min = _cubic_bounds(density, cbase, sa, sb, qa, qb, n_a, n_b, thick, kind)
                bits |= 1 << ((qb - b0 + 1) * 5 + qa - a0 + 1)
                dmax = max(dmax, dq_max)
                dmin = min(dmin, dq_min)
    k = 0
    for t in range(CELL * CELL):
        k += (m >> t) & 1
    ka0, ka1, kb0, kb1 = _owned_extent(bits)
    c_of[u], a_of[u], b_of[u], owned[u], count[u], hi[u], lo[u] = c, a0, b0, bits, k, dmax, dmin
    ext[u] = ka0 | (ka1 << 3) | (kb0 << 6) | (kb1 << 9)


@leaf
def _cubic_bounds(density, cbase, sa, sb, qa, qb, n_a, n_b, thick, kind=1):
    """The highest and lowest density the cubic along the thick axis (``thick`` 1 a, 2 b) can make in quad (qa, qb)
    (:func:`isplat.splat.post._density_at`): each of its two rows is a cubic through four voxels (clamped at the
    slice's edges) whose weights sum to 1 and whose negative ones (Catmull-Rom's, the monotone kind has none) sum
    to at least -1/8, so it lies within the eight voxels' extremes P, Q widened by (P - Q) / 8 (and the codes);
    the linear mix of the two rows too. ``kind`` 2, the interpolating spline
    (:func:`isplat.splat.post._spline_at`): its 2 SPLINE_REACH voxels in each row, widened by SPLINE_OVERSHOOT
    times P - Q."""
    dmax = 0
    dmin = 255
    k0, k1 = (1 - SPLINE_REACH, SPLINE_REACH + 1) if kind == 2 else (-1, 3)
    for k in range(k0, k1):
        for j in range(2):
            a, b = (qa + k, qb + j) if thick == 1 else (qa + j, qb + k)
            a = min(max(a, 0), n_a - 1)
            b = min(max(b, 0), n_b - 1)
            d = np.int32(density[cbase + a * sa + b * sb])
            dmax = max(dmax, d)
            dmin = min(dmin, d)
    over = (dmax - dmin + 7) // 8
    if kind == 2:
        over = int(math.ceil((dmax - dmin) * SPLINE_OVERSHOOT))
    return min(dmax + over, 255), max(dmin - over, 0)


def sorted_units(units: Units, sign: float) -> np.ndarray:
    """The units by bound: highest ``hi`` first (``sign`` 1, MIP) or lowest ``lo`` first (-1, MinIP); within a
    bound in the selection's order (slice, region, block, cell), which keeps neighbours together."""
    key = -units.hi if sign > 0 else units.lo
    return np.argsort(key, kind="stable").astype(np.int64)


# ---- the frame ----------------------------------------------------------------------------------------------------
def plan(tables):
    """The frame's :data:`MipPlan`, each thread's (empty) scratch and the frame's one sheet, from
    :class:`isplat.frame.FrameTables`."""
    from ..errors import IsplatError
    from .post import between_slices, lerp_tables

    sel, view = tables.sel, tables.view
    ro = view.render
    if not sel.post or sel.whole is None or any(s.cells_only for s in sel.axes.values()):
        raise IsplatError(f"render.mode = {ro.mode!r} needs a selection made for it (the whole density channel "
                          "and the voxels of interest)")
    sign = 1.0 if ro.mode == "mip" else -1.0
    between = between_slices(view.geom.spacing, tables.axis)
    units = units_of(sel, tables.axis, sign, between[0], between[1])
    in_frame = np.zeros(_n_slices(sel, tables.axis), np.uint8)
    in_frame[view.order] = 1
    _, color = lerp_tables(tables.atab, sel.luts.color)
    window = tuple(float(x) for x in (ro.window or (0.0, 255.0)))
    H, W = view.frame.height, view.frame.width
    held = Held(np.empty((H, W), np.float64), np.empty((-(-H // TILE), -(-W // TILE)), np.int32))
    p = MipPlan(units, in_frame, sel.whole_volume(tables.axis), tables.geo, sign, window,
                color, ro.intensity_color == "transfer", held, between if between[0] else None)   # None: bilinear
    return p, [np.empty(0, np.int64) for _ in range(tables.threads)], np.zeros(1, np.int64)


@stage
def _scratch(plan):
    """The cutting planes' offsets of a slice, and the list of the units that reach a band."""
    return np.empty(max(plan.geo.cuts.shape[0], 1), dtype=np.float64), np.empty(plan.units.c.shape[0], np.int32)


@leaf(inline="always")    # numba inlines its IR, not LLVM: see isplat.jit.leaf
def _slice(plan, lists, scratch, c, pos, buf, band):
    """The frame's one sheet for one band: every unit (:func:`_band_units`), then the band's pixels."""
    _band_units(plan, scratch[0], scratch[1], buf, band)


@leaf
def _band_units(plan, cs, mine, buf, band):
    """Walk the units by bound for the band's rows (first listing, into ``mine``, those of the frame's slices that
    reach the band), then write its pixels (:func:`_write_band`)."""
    bi, y0b, y1b = band[0], band[1], band[2]
    held = plan.held
    for y in range(y0b, y1b):
        for x in range(held.px.shape[1]):
            held.px[y, x] = -math.inf
    for ty in range(y0b // TILE, (y1b + TILE - 1) // TILE):
        for tx in range(held.tile_done.shape[1]):
            held.tile_done[ty, tx] = 0
    units, w = plan.units, plan.whole
    img_w = buf.img.shape[1]
    total = 0
    visited = 0
    samples = 0
    nm = 0
    coef = plan.geo.coef
    # orthographic: a unit's 5 x 5 quads lie within 2.5 steps along a and b of its middle, so its rows are within
    # that reach (and a pixel of rounding) of its middle's row; its exact pixels are _unit's
    reach = 2.5 * (abs(coef[YA]) + abs(coef[YB])) + 1.0
    for u in range(units.c.shape[0]):
        c = units.c[u]
        if plan.in_frame[c] == 0:
            continue
        total += units.count[u]
        if plan.geo.persp:
            _, _, _, _, _, x0, x1, y0, y1 = _unit_box(c, units.a0[u], units.b0[u], units.ext[u], w, plan.geo, cs,
                                                      img_w, y0b, y1b)
            if x0 > x1 or y0 > y1:
                continue
        else:
            ym = coef[Y0] + (units.a0[u] + 1.5) * coef[YA] + (units.b0[u] + 1.5) * coef[YB] + c * coef[YC]
            if ym + reach < y0b or ym - reach > y1b - 1:
                continue
        mine[nm] = u
        nm += 1
    la = 0                          # the next unit to look at ahead
    for t in range(nm):
        while la < nm and la <= t + AHEAD:  # the voxels of the units ahead come from memory while this one is drawn
            la = _look_ahead(plan, mine, la, nm, cs, held, img_w, y0b, y1b)
        u = mine[t]
        if u < 0:
            continue                # its tiles were finished when looked at ahead, and stay so
        bound = plan.sign * (units.hi[u] if plan.sign > 0 else units.lo[u])
        n = _unit(units.c[u], units.a0[u], units.b0[u], units.owned[u], units.ext[u], bound, w, plan.geo, plan.sign,
                  cs, held, img_w, y0b, y1b, plan.between)
        if n >= 0:
            visited += units.count[u]
            samples += n
    buf.stats[bi, 0] += total
    buf.stats[bi, 1] += visited
    buf.stats[bi, 2] += samples
    buf.stats[bi, 3] += 1
    _write_band(held.px, plan.sign, plan.window, plan.color, plan.use_color, buf.img, y0b, y1b)


@leaf(forceinline=True)
def _look_ahead(plan, mine, t, nm, cs, held, img_w, y0b, y1b):
    """Look at the unit ``mine[t]``, a few ahead of the one drawn, and return the next to look at. When it starts a
    run of units of one block (16 x 16 voxels) of one slice (orthographic) whose box reaches only tiles known
    finished, the whole run is marked skipped (``-1 - u``: tiles stay finished, and every unit's box lies in its
    block's); else the unit alone, or its densities are asked for (:func:`_prefetch_unit`), so that units skipped
    at once cost no memory traffic. Only looks: the tiles' counts advance with the bound of the unit being drawn
    (:func:`_tiles_hold`), never with a later, lower one."""
    units, w = plan.units, plan.whole
    u = mine[t]
    if not plan.geo.persp:
        e = _run_end(units, mine, t, nm)
        if e - t > 1:
            c = units.c[u]
            ba0 = units.a0[u] // BLOCK * BLOCK
            bb0 = units.b0[u] // BLOCK * BLOCK
            x0, x1, y0, y1 = _ortho_rect_box(c, -0.5 if ba0 == 0 else ba0 - 1.0, min(ba0 + BLOCK, w.n_a - 0.5),
                                             -0.5 if bb0 == 0 else bb0 - 1.0, min(bb0 + BLOCK, w.n_b - 0.5),
                                             plan.geo.coef, img_w, y0b, y1b)
            if x0 > x1 or y0 > y1 or _tiles_finished(held, x0, x1, y0, y1):
                for k in range(t, e):
                    mine[k] = -1 - mine[k]
                return e
        _, _, _, _, x0, x1, y0, y1 = _ortho_box(units.c[u], units.a0[u], units.b0[u], units.ext[u], w, plan.geo.coef,
                                                img_w, y0b, y1b)
    else:
        _, _, _, _, _, x0, x1, y0, y1 = _unit_box(units.c[u], units.a0[u], units.b0[u], units.ext[u], w, plan.geo,
                                                  cs, img_w, y0b, y1b)
    if x0 > x1 or y0 > y1 or _tiles_finished(held, x0, x1, y0, y1):
        mine[t] = -1 - u
    else:
        _prefetch_unit(units.c[u], units.a0[u], units.b0[u], w, _between(plan.between)[0])
    return t + 1


@leaf(forceinline=True)
def _run_end(units, mine, t, nm):
    """The end of the run of units from ``mine[t]`` in the same block of the same slice when ``mine[t]`` starts
    one (the one before is elsewhere), else t + 1; at most 64 units."""
    u = mine[t]
    c, ka, kb = units.c[u], units.a0[u] // BLOCK, units.b0[u] // BLOCK
    if t > 0:
        p = mine[t - 1]
        p = -1 - p if p < 0 else p
        if units.c[p] == c and units.a0[p] // BLOCK == ka and units.b0[p] // BLOCK == kb:
            return t + 1
    e = t + 1
    while e < nm and e - t < 64:
        k = mine[e]
        if units.c[k] != c or units.a0[k] // BLOCK != ka or units.b0[k] // BLOCK != kb:
            break
        e += 1
    return e


@leaf(inline="always")    # numba inlines its IR, not LLVM: see isplat.jit.leaf
def _prefetch_unit(c, a0, b0, w, thick):
    """Ask the CPU for the cache lines of the densities a unit's quads read (rows b0 - 1 .. b0 + 4 of its slice,
    columns a0 - 1 .. a0 + 4; one more each side along a thick axis ``thick``, 1 a, 2 b, for the cubic): the
    units go by bound, not by place, so each unit's rows are lines of their own (as
    :func:`isplat.splat.post._prefetch_square`)."""
    sa, sb = w.strides[0], w.strides[1]
    cbase = c * w.strides[2] + w.strides[3]
    ea, eb = int(thick == 1), int(thick == 2)
    a_lo = max(a0 - 1 - ea, 0)
    a_hi = min(a0 + CELL + ea, w.n_a - 1)
    da = max(1, 32 // sa)
    for b in range(max(b0 - 1 - eb, 0), min(b0 + CELL + eb, w.n_b - 1) + 1):
        row = cbase + b * sb
        for a in range(a_lo, a_hi + da, da):
            prefetch(w.density, np.uint64(row + min(a, a_hi) * sa))


@leaf(forceinline=True)
def _unit(c, a0, b0, owned, ext, bound, w, geo, sign, cs, held, img_w, y0b, y1b, between):
    """Sample the quads ``owned`` by one unit (:func:`_put`; the cell from (a0, b0) of slice ``c``) at the pixels
    of rows ``[y0b, y1b)`` that do not yet hold ``bound`` (``sign *`` density); returns the samples taken, or -1
    when every pixel it reaches already held its bound (skipped). The density is the post-classified technique's
    (:func:`isplat.splat.post._density_at`: bilinear, or the cubic along a thick axis, ``between``). One function
    of over 60 lines: the per-pixel scan is its inner loop, as :func:`isplat.splat.post._sample_square`'s."""
    n_a, n_b = w.n_a, w.n_b
    coef, persp = geo.coef, geo.persp
    if persp:
        base, u0, u1, v0, v1, x0, x1, y0, y1 = _unit_box(c, a0, b0, ext, w, geo, cs, img_w, y0b, y1b)
    else:
        u0, u1, v0, v1, x0, x1, y0, y1 = _ortho_box(c, a0, b0, ext, w, coef, img_w, y0b, y1b)
    if x0 > x1 or y0 > y1 or _tiles_hold(held, x0, x1, y0, y1, bound):
        return -1
    if not persp:
        base = slice_bases(c, geo, cs)
    px = held.px
    inv = _ortho_inverse(base, coef)
    sa, sb = w.strides[0], w.strides[1]
    cbase = c * w.strides[2] + w.strides[3]
    density = w.density
    voxel = (density, w.gm, w.nrm, (w.offs[0], w.offs[1], w.offs[2][c], w.offs[3], w.table), n_a, n_b, c, between)
    open_ = False
    n = 0
    for y in range(y0, y1 + 1):
        xa, xb = _row_pixels(y, persp, u0, u1, v0, v1, inv, x0, x1)
        for x in range(xa, xb + 1):
            h = px[np.uint64(y), np.uint64(x)]
            if h >= bound:
                continue                                # finished for this unit and every one after it
            ok, u, v, qa, qb = _pixel_quad(x, y, persp, base, coef, inv, u0, u1, v0, v1)
            if not ok:
                continue
            open_ = True
            la = qa - a0 + 1
            lb = qb - b0 + 1
            if la < 0 or la > 4 or lb < 0 or lb > 4 or (owned >> (lb * 5 + la)) & 1 == 0:
                continue                                # another unit's quad, or one with no corner of interest
            if geo.cuts.shape[0] > 0 and cut_away(u, v, geo.cuts, cs):
                continue
            fu = max(u - qa, 0.0)
            fv = max(v - qb, 0.0)
            d = _density_at(density, cbase + qa * sa + qb * sb, sa if qa + 1 < n_a else 0,
                            sb if qb + 1 < n_b else 0, fu, fv, _taps(qa, qb, voxel), w.table)
            n += 1
            if sign * d > h:
                px[np.uint64(y), np.uint64(x)] = sign * d
    return n if open_ else -1


@leaf(forceinline=True)
def _unit_box(c, a0, b0, ext, w, geo, cs, img_w, y0b, y1b):
    """The slice's bases, the part ``[u0, u1) x [v0, v1)`` of the slice plane a unit's quads cover (``ext``, see
    :data:`Units`), and its pixels ``x0, x1, y0, y1`` in the band (empty: x0 > x1)."""
    u0 = -0.5 if a0 - 1 + (ext & 7) <= 0 else a0 - 1.0 + (ext & 7)
    v0 = -0.5 if b0 - 1 + ((ext >> 6) & 7) <= 0 else b0 - 1.0 + ((ext >> 6) & 7)
    u1 = min(a0 - 1.0 + ((ext >> 3) & 7), w.n_a - 0.5)
    v1 = min(b0 - 1.0 + ((ext >> 9) & 7), w.n_b - 0.5)
    base = slice_bases(c, geo, cs)
    x0, x1, y0, y1 = _cell_pixels(u0, u1, v0, v1, base, geo.coef, geo.persp, img_w, y0b, y1b)
    return base, u0, u1, v0, v1, x0, x1, y0, y1


@leaf(forceinline=True)
def _ortho_box(c, a0, b0, ext, w, coef, img_w, y0b, y1b):
    """:func:`_unit_box` of an orthographic view without the slice's bases and cuts (the same numbers), for the
    units that are only tested: ``u0, u1, v0, v1, x0, x1, y0, y1``."""
    u0 = -0.5 if a0 - 1 + (ext & 7) <= 0 else a0 - 1.0 + (ext & 7)
    v0 = -0.5 if b0 - 1 + ((ext >> 6) & 7) <= 0 else b0 - 1.0 + ((ext >> 6) & 7)
    u1 = min(a0 - 1.0 + ((ext >> 3) & 7), w.n_a - 0.5)
    v1 = min(b0 - 1.0 + ((ext >> 9) & 7), w.n_b - 0.5)
    x0, x1, y0, y1 = _ortho_rect_box(c, u0, u1, v0, v1, coef, img_w, y0b, y1b)
    return u0, u1, v0, v1, x0, x1, y0, y1


@leaf(forceinline=True)
def _ortho_rect_box(c, u0, u1, v0, v1, coef, img_w, y0b, y1b):
    """The pixels of the band (rows ``[y0b, y1b)``) whose centres can see ``[u0, u1) x [v0, v1)`` of slice ``c``,
    orthographic: :func:`isplat.splat.post._cell_pixels` written out from the coefficients (the slice's bases'
    first two terms), the same numbers; empty: x0 > x1."""
    xs = coef[X0] + c * coef[XC]
    ys = coef[Y0] + c * coef[YC]
    xa0, xa1 = u0 * coef[XA], u1 * coef[XA]
    xb0, xb1 = v0 * coef[XB], v1 * coef[XB]
    ya0, ya1 = u0 * coef[YA], u1 * coef[YA]
    yb0, yb1 = v0 * coef[YB], v1 * coef[YB]
    cx0 = xs + min(xa0, xa1) + min(xb0, xb1)
    cx1 = xs + max(xa0, xa1) + max(xb0, xb1)
    cy0 = ys + min(ya0, ya1) + min(yb0, yb1)
    cy1 = ys + max(ya0, ya1) + max(yb0, yb1)
    return _pixel_box(cx0, cx1, cy0, cy1, img_w, y0b, y1b)


@leaf
def _owned_extent(owned):
    """The first and one-past-last column and row (0..5) of the 5 x 5 quads that hold an owned quad."""
    ka0, ka1, kb0, kb1 = 5, 0, 5, 0
    for k in range(25):
        if (owned >> k) & 1:
            ka0 = min(ka0, k % 5)
            ka1 = max(ka1, k % 5 + 1)
            kb0 = min(kb0, k // 5)
            kb1 = max(kb1, k // 5 + 1)
    return ka0, ka1, kb0, kb1


@leaf
def _tiles_finished(held, x0, x1, y0, y1):
    """True when every tile the box [x0, x1] x [y0, y1] touches is known finished (all its pixels counted)."""
    for ty in range(y0 // TILE, y1 // TILE + 1):
        for tx in range(x0 // TILE, x1 // TILE + 1):
            if held.tile_done[ty, tx] < TILE * TILE:
                return False
    return True


@leaf
def _tiles_hold(held, x0, x1, y0, y1, bound):
    """True when every pixel of the tiles that the box [x0, x1] x [y0, y1] (inside one band) touches holds at least
    ``bound`` (bounds must not grow from one call to the next within a band: see :data:`Held`)."""
    done, px = held.tile_done, held.px
    h, w = px.shape[0], px.shape[1]
    for ty in range(y0 // TILE, y1 // TILE + 1):
        for tx in range(x0 // TILE, x1 // TILE + 1):
            k = done[ty, tx]
            while k < TILE * TILE:
                y = ty * TILE + k // TILE
                x = tx * TILE + k % TILE
                if y < h and x < w and px[y, x] < bound:
                    break
                k += 1
            done[ty, tx] = k
            if k < TILE * TILE:
                return False
    return True


@leaf
def _write_band(held, sign, window, color, use_color, img, y0b, y1b):
    """The band's pixels, premultiplied RGBA: where a sample was taken, the held density through the window as
    grey (or the transfer function's colour at it), opaque; elsewhere nothing (the background)."""
    lo, hi = window
    scale = 1.0 / (hi - lo)
    for y in range(y0b, y1b):
        for x in range(held.shape[1]):
            h = held[y, x]
            if h == -math.inf:
                for k in range(4):
                    img[y, x, k] = 0.0
                continue
            d = sign * h
            if use_color:
                k = min(int(d), 254)
                f = d - k
                img[y, x, 0] = color[k, 0] + f * color[k, 3]
                img[y, x, 1] = color[k, 1] + f * color[k, 4]
                img[y, x, 2] = color[k, 2] + f * color[k, 5]
            else:
                g = min(max((d - lo) * scale, 0.0), 1.0)
                img[y, x, 0] = g
                img[y, x, 1] = g
                img[y, x, 2] = g
            img[y, x, 3] = 1.0


register(MipPlan, _scratch, _slice)
