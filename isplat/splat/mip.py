"""Maximum- and minimum-intensity projection (``render.mode = "mip"`` / ``"minip"``) by the index.

Reconstruction is the default technique's (:mod:`isplat.splat.post`): along each pixel's ray the density is
sampled where the ray crosses the slice planes of the principal axis, bilinearly in each slice (the trilinear
field at the slice planes; the edge voxel repeated half a voxel beyond the outer centres), at the quads (squares
between four voxels) one of whose voxels is of interest (a density of non-zero opacity). The pixel keeps the
largest (MIP) or smallest (MinIP) sample: what a ray caster's MIP shows at the same sampling.

The order is the index's, not the slices': the unit of work is a cell of the selection (4 x 4 voxels of one slice,
the voxels of interest among them as a 16-bit mask) with the quads that touch its voxels of interest, and its
*bound*, the highest density of those quads' corners (MIP; the lowest for MinIP): no sample of the unit can
exceed it, since a bilinear sample lies between its corners. The units of a selection's axis are listed once
(:func:`units_of`, kept beside the selection) and sorted by bound, from high to low (MIP) or from low to high
(MinIP), so a frame visits the high densities first. A unit is skipped when every pixel it reaches already
holds at least its bound (:func:`_unit`: such pixels are finished for it and for every unit after it, whose
bounds are no higher); otherwise its quads are sampled at the pixels that are not. Exact whatever the order: a
skipped unit cannot raise any pixel. Early termination, footprints, shading and slab compositing do not apply
(docs/mip.md).

A technique of :mod:`isplat.splat.traverse`: its plan (:data:`MipPlan`) has one "sheet" (the frame's one pass
over the sorted units), its slice stage (:func:`_slice`) walks the units for one band of image rows and writes
the band's pixels, and it reuses the traversal's per-slice bases, cuts and the post technique's pixel scan
(:func:`isplat.splat.post._cell_pixels`, ``_row_span``, ``_slice_point``, ``_ortho_inverse``). Counters:
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
from .select import BLOCK, CELL, REGION
from .traverse import cut_away, register, slice_bases
from .post import _cell_pixels, _ortho_inverse, _row_span, _slice_point

Units = namedtuple("Units", "c a0 b0 mask count hi lo")
Units.__doc__ = """The units of one axis of a selection (one row per cell holding a voxel of interest): slice
``c``, the cell's first voxel ``(a0, b0)``, ``mask`` its voxels of interest (bit ``4 b + a`` in the cell),
``count`` how many, and the highest (``hi``) and lowest (``lo``) density of the corners of the quads that touch
them (int32 each)."""
MipPlan = namedtuple("MipPlan", "units in_frame whole geo sign window color use_color held")
MipPlan.__doc__ = """A frame's tables: ``units`` (:data:`Units`) by bound (high to low for MIP, low to high for
MinIP, :func:`sorted_units`), ``in_frame`` uint8 per slice (1: a slice of the view's order), ``whole`` the whole
channels (:data:`isplat.splat.traverse.WholeVolume`), ``geo`` :data:`isplat.splat.traverse.SliceGeometry`,
``sign`` 1.0 (MIP) or -1.0 (MinIP; a pixel holds ``sign * density``), ``window`` (lo, hi) the codes mapped to
black and white, ``color`` float64[256, 6] the transfer function's colour with its steps to the next code
(:func:`isplat.splat.post.lerp_tables`) and ``use_color``; ``held`` (:data:`Held`), shared by the threads (each
writes its bands' rows, whole tiles)."""
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


def units_of(sel, axis: str, sign: float = 0.0) -> Units:
    """The :data:`Units` of ``axis`` of the selection ``sel`` (the index's voxels of interest; with the full method
    every voxel whose opacity is not zero), made once and kept while the selection lives; with ``sign`` 1 (MIP) or
    -1 (MinIP) in the frame's order (:func:`sorted_units`), a copy, so that a frame reads them in sequence."""
    key = (id(sel), axis, sign)
    got = _UNITS.get(key)
    if got is not None:
        return got
    if sign != 0.0:
        units = units_of(sel, axis)
        order = sorted_units(units, sign)
        out = Units(*(np.ascontiguousarray(x[order]) for x in units))
        _UNITS[key] = out
        weakref.finalize(sel, _UNITS.pop, key, None)
        return out
    w = sel.whole_volume(axis)
    if sel.method == "full":
        from ..transfer import alpha_table

        table = (alpha_table(sel.luts, 1.0) != 0).astype(np.uint8)
        gm = w.gm if sel.use_gm else np.zeros(0, np.uint8)
        out = Units(*_full_units(w.density, gm, table, w.strides, w.n_a, w.n_b, _n_slices(sel, axis)))
    else:
        v = sel.voxels(axis)
        out = Units(*_indexed_units(v.slice_ptr, v.region_ptr, v.region_id, v.block_pos, v.block_ptr,
                                    v.block_voxel, v.cell_pos, v.cell_count, v.offset, w.density, w.strides,
                                    w.n_a, w.n_b))
    _UNITS[key] = out
    weakref.finalize(sel, _UNITS.pop, key, None)
    return out


def _n_slices(sel, axis: str) -> int:
    from .. import grid

    return int(grid.slice_shape(sel.shape, axis)[0])


@jit
def _indexed_units(slice_ptr, region_ptr, region_id, block_pos, block_ptr, block_voxel, cell_pos, cell_count,
                   offset, density, strides, n_a, n_b):
    """:data:`Units` from the index's hierarchy of one axis (slices, regions, blocks, cells, voxels)."""
    n_cells = block_ptr[region_ptr[slice_ptr[slice_ptr.shape[0] - 1]]]
    if n_cells < 0 or n_cells > cell_pos.shape[0]:
        raise ValueError("mip: the selection's cell table is inconsistent")
    c_of, a_of, b_of, mask, count, hi, lo = _unit_arrays(n_cells)
    nra = (n_a + REGION - 1) // REGION
    for c in range(slice_ptr.shape[0] - 1):
        for g in range(slice_ptr[c], slice_ptr[c + 1]):
            ra0 = (region_id[g] % nra) * REGION
            rb0 = (region_id[g] // nra) * REGION
            for r in range(region_ptr[g], region_ptr[g + 1]):
                ba0 = ra0 + (block_pos[r] % 4) * BLOCK
                bb0 = rb0 + (block_pos[r] // 4) * BLOCK
                n = block_voxel[r]
                for q in range(block_ptr[r], block_ptr[r + 1]):
                    m = 0
                    for t in range(n, n + cell_count[q]):
                        m |= 1 << offset[t]
                    n += cell_count[q]
                    _put(q, c, ba0 + (cell_pos[q] % 4) * CELL, bb0 + (cell_pos[q] // 4) * CELL, m, density, strides,
                         n_a, n_b, c_of, a_of, b_of, mask, count, hi, lo)
    return c_of, a_of, b_of, mask, count, hi, lo


@jit
def _full_units(density, gm, table, strides, n_a, n_b, n_slices):
    """:data:`Units` of every voxel whose opacity is not zero (``table`` uint8[256, G]: 1 where not; the
    gradient code from ``gm`` when given), for the full method."""
    nca = (n_a + CELL - 1) // CELL
    ncb = (n_b + CELL - 1) // CELL
    c_of, a_of, b_of, mask, count, hi, lo = _unit_arrays(n_slices * nca * ncb)
    nu = 0
    for c in range(n_slices):
        cbase = c * strides[2] + strides[3]
        for cb in range(ncb):
            for ca in range(nca):
                m = 0
                for b in range(cb * CELL, min(cb * CELL + CELL, n_b)):
                    for a in range(ca * CELL, min(ca * CELL + CELL, n_a)):
                        fi = cbase + a * strides[0] + b * strides[1]
                        if table[density[fi], gm[fi] if gm.shape[0] else 0]:
                            m |= 1 << ((b - cb * CELL) * CELL + a - ca * CELL)
                if m:
                    _put(nu, c, ca * CELL, cb * CELL, m, density, strides, n_a, n_b, c_of, a_of, b_of, mask, count,
                         hi, lo)
                    nu += 1
    return c_of[:nu], a_of[:nu], b_of[:nu], mask[:nu], count[:nu], hi[:nu], lo[:nu]


@stage
def _unit_arrays(n):
    return (np.empty(n, np.int32), np.empty(n, np.int32), np.empty(n, np.int32), np.empty(n, np.int32),
            np.empty(n, np.int32), np.empty(n, np.int32), np.empty(n, np.int32))


@leaf
def _put(u, c, a0, b0, m, density, strides, n_a, n_b, c_of, a_of, b_of, mask, count, hi, lo):
    """Unit ``u``: the cell from (a0, b0) of slice ``c`` with voxels of interest ``m``; its bounds are the
    extremes of the 3 x 3 voxels around each (the corners of the four quads it is a corner of)."""
    cbase = c * strides[2] + strides[3]
    dmax = 0
    dmin = 255
    k = 0
    for t in range(CELL * CELL):
        if m & (1 << t) == 0:
            continue
        k += 1
        a = a0 + t % CELL
        b = b0 + t // CELL
        for bb in range(max(b - 1, 0), min(b + 2, n_b)):
            for aa in range(max(a - 1, 0), min(a + 2, n_a)):
                d = np.int32(density[cbase + aa * strides[0] + bb * strides[1]])
                dmax = max(dmax, d)
                dmin = min(dmin, d)
    c_of[u], a_of[u], b_of[u], mask[u], count[u], hi[u], lo[u] = c, a0, b0, m, k, dmax, dmin


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
    from .post import lerp_tables

    sel, view = tables.sel, tables.view
    ro = view.render
    if not sel.post or sel.whole is None:
        raise IsplatError(f"render.mode = {ro.mode!r} needs a selection made for it (the whole density channel)")
    sign = 1.0 if ro.mode == "mip" else -1.0
    units = units_of(sel, tables.axis, sign)
    in_frame = np.zeros(_n_slices(sel, tables.axis), np.uint8)
    in_frame[view.order] = 1
    _, color = lerp_tables(tables.atab, sel.luts.color)
    window = tuple(float(x) for x in (ro.window or (0.0, 255.0)))
    H, W = view.frame.height, view.frame.width
    held = Held(np.empty((H, W), np.float64), np.empty((-(-H // TILE), -(-W // TILE)), np.int32))
    p = MipPlan(units, in_frame, sel.whole_volume(tables.axis), tables.geo, sign, window,
                color, ro.intensity_color == "transfer", held)
    return p, [np.empty(0, np.int64) for _ in range(tables.threads)], np.zeros(1, np.int64)


@stage
def _scratch(plan):
    """The cutting planes' offsets of a slice."""
    return np.empty(max(plan.geo.cuts.shape[0], 1), dtype=np.float64)


@leaf(inline="always")    # numba inlines its IR, not LLVM: see isplat.jit.leaf
def _slice(plan, lists, cs, c, pos, buf, band):
    """The frame's one sheet for one band: every unit (:func:`_band_units`), then the band's pixels."""
    _band_units(plan, cs, buf, band)


@leaf
def _band_units(plan, cs, buf, band):
    """Walk the units by bound for the band's rows, then write its pixels (:func:`_write_band`)."""
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
    n_units = units.c.shape[0]
    for u in range(n_units):
        c = units.c[u]
        if plan.in_frame[c] == 0:
            continue
        if u + AHEAD < n_units:     # the voxels of the units ahead come from memory while this one is sampled
            _prefetch_unit(units.c[u + AHEAD], units.a0[u + AHEAD], units.b0[u + AHEAD], w)
        total += units.count[u]
        bound = plan.sign * (units.hi[u] if plan.sign > 0 else units.lo[u])
        n = _unit(c, units.a0[u], units.b0[u], units.mask[u], bound, w, plan.geo, plan.sign, cs, held, img_w,
                  y0b, y1b)
        if n >= 0:
            visited += units.count[u]
            samples += n
    buf.stats[bi, 0] += total
    buf.stats[bi, 1] += visited
    buf.stats[bi, 2] += samples
    buf.stats[bi, 3] += 1
    _write_band(held.px, plan.sign, plan.window, plan.color, plan.use_color, buf.img, y0b, y1b)


@leaf(inline="always")    # numba inlines its IR, not LLVM: see isplat.jit.leaf
def _prefetch_unit(c, a0, b0, w):
    """Ask the CPU for the cache lines of the densities a unit's quads read (rows b0 - 1 .. b0 + 4 of its slice,
    columns a0 - 1 .. a0 + 4): the units go by bound, not by place, so each unit's rows are lines of their own
    (as :func:`isplat.splat.post._prefetch_square`)."""
    sa, sb = w.strides[0], w.strides[1]
    cbase = c * w.strides[2] + w.strides[3]
    a_lo = max(a0 - 1, 0)
    a_hi = min(a0 + CELL, w.n_a - 1)
    da = max(1, 32 // sa)
    for b in range(max(b0 - 1, 0), min(b0 + CELL, w.n_b - 1) + 1):
        row = cbase + b * sb
        for a in range(a_lo, a_hi + da, da):
            prefetch(w.density, np.uint64(row + min(a, a_hi) * sa))


@leaf(forceinline=True)
def _unit(c, a0, b0, m, bound, w, geo, sign, cs, held, img_w, y0b, y1b):
    """Sample the quads of one unit (the cell from (a0, b0) of slice ``c``, voxels of interest ``m``) at the
    pixels of rows ``[y0b, y1b)`` that do not yet hold ``bound`` (``sign *`` density); returns the samples
    taken, or -1 when every pixel it reaches already held its bound (skipped). One function of over 60 lines: the
    per-pixel scan is its inner loop, as :func:`isplat.splat.post._sample_square`'s."""
    n_a, n_b = w.n_a, w.n_b
    u0 = -0.5 if a0 == 0 else a0 - 1.0          # its quads: from the one before the cell to its last voxel's
    v0 = -0.5 if b0 == 0 else b0 - 1.0
    u1 = min(a0 + CELL, n_a - 0.5)
    v1 = min(b0 + CELL, n_b - 0.5)
    base = slice_bases(c, geo, cs)
    coef, persp = geo.coef, geo.persp
    x0, x1, y0, y1 = _cell_pixels(u0, u1, v0, v1, base, coef, persp, img_w, y0b, y1b)
    if x0 > x1 or y0 > y1 or _tiles_hold(held, x0, x1, y0, y1, bound):
        return -1
    px = held.px
    inv = _ortho_inverse(base, coef)
    sa, sb = w.strides[0], w.strides[1]
    cbase = c * w.strides[2] + w.strides[3]
    density = w.density
    open_ = False
    n = 0
    for y in range(y0, y1 + 1):
        xa, xb = x0, x1
        if not persp:
            xa, xb = _row_span(y, u0, u1, v0, v1, inv, x0, x1)
        for x in range(xa, xb + 1):
            h = px[np.uint64(y), np.uint64(x)]
            if h >= bound:
                continue                                # finished for this unit and every one after it
            if persp:
                ok, u, v = _slice_point(x, y, base, coef)
                if not ok:
                    continue
            else:
                u = inv[0] + x * inv[1] + y * inv[2]
                v = inv[3] + x * inv[4] + y * inv[5]
            if u < u0 or u >= u1 or v < v0 or v >= v1:
                continue
            open_ = True
            qa = max(int(u + 1.0) - 1, 0)               # floor: u, v >= -0.5 here
            qb = max(int(v + 1.0) - 1, 0)
            qa1 = min(qa + 1, n_a - 1)
            qb1 = min(qb + 1, n_b - 1)
            if not _touches(m, qa - a0, qa1 - a0, qb - b0, qb1 - b0):
                continue                                # a quad none of this unit's voxels of interest is in
            if geo.cuts.shape[0] > 0 and cut_away(u, v, geo.cuts, cs):
                continue
            fu = max(u - qa, 0.0)
            fv = max(v - qb, 0.0)
            i00 = np.uint64(cbase + qa * sa + qb * sb)
            i10 = np.uint64(cbase + qa1 * sa + qb * sb)
            i01 = np.uint64(cbase + qa * sa + qb1 * sb)
            i11 = np.uint64(cbase + qa1 * sa + qb1 * sb)
            d = ((1.0 - fu) * (1.0 - fv) * density[i00] + fu * (1.0 - fv) * density[i10]
                 + (1.0 - fu) * fv * density[i01] + fu * fv * density[i11])
            n += 1
            if sign * d > h:
                px[np.uint64(y), np.uint64(x)] = sign * d
    return n if open_ else -1


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


@leaf(inline="always")    # numba inlines its IR, not LLVM: see isplat.jit.leaf
def _touches(m, la0, la1, lb0, lb1):
    """True when one of the quad's corners (cell-local columns la0, la1 and rows lb0, lb1) is in the mask."""
    for lb in (lb0, lb1):
        if 0 <= lb < CELL:
            for la in (la0, la1):
                if 0 <= la < CELL and m & (1 << (lb * CELL + la)):
                    return True
    return False


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
