"""The traversal every technique shares: the layouts, the band and slice loop, the region -> block -> cell walk
and the occlusion tests, written once (docs/design.md, "The kernels' structure").

A frame is one call of :func:`render` per thread: ``render(order, o0, plan, lists, buf, bands)`` walks the
bands ``bands.mine`` one after the other and, in each, the slices ``order`` front to back until the band
saturates. What a technique does with a slice is its own: the technique's module (:mod:`isplat.splat.pre`,
:mod:`isplat.splat.post`, :mod:`isplat.splat.sheets`) defines its per-frame plan (a named tuple of its tables)
and registers, for that tuple's class, two compiled stages (:func:`register`):

- ``scratch(plan)``: what a call allocates once (a slice's marks, the full method's hierarchy, ...);
- ``slice(plan, lists, scratch, c, pos, buf, band)``: slice ``c`` (at position ``pos`` of the frame's order)
  for one band; ``lists`` is the calling thread's own scratch (its touched-pixel and visible-cell lists).

numba picks the technique's stages by the plan's type when it compiles :func:`render` for it (an ``overload``
of :func:`call_scratch` and :func:`render_slice`), so each technique's kernel is compiled and cached on its
own, with its stages inlined as before: no function pointer, no branch per technique. Adding a technique
(maximum-intensity projection, say) is adding a module: its plan tuple, ``plan(tables)`` making it from
:class:`isplat.frame.FrameTables`, its two stages registered here, and its line in ``isplat.frame.TECHNIQUES``.

Threads: the image is cut into bands of rows of whole tiles (:func:`isplat.frame.band_rows`); each band walks
the slices on its own, and a thread renders its bands one after the other (one call per band, timed). The
image does not depend on the bands.

The axis-aligned techniques (pre- and post-classified) share more: which regions of a slice a band visits and
their hierarchy (:func:`slice_regions`: the index's selection binned per band, :func:`bin_regions`, or every
voxel of the slice classified, :func:`full_slice_regions`), the occlusion tests (:func:`visible_cells`,
:func:`_hidden`: a region, block or cell whose footprints reach no pixel of the band, or only saturated ones, is
skipped with one test), the per-slice bases (:func:`slice_bases`) and the slab's opacity along a ray
(:func:`path_alpha`).

Early termination: TILE x TILE tiles whose pixels are all saturated answer "all saturated?" at once, through a
summed-area table of the band's whole tiles (:func:`build_sat`, one look-up for any box), made again after a
slice saturates new pixels. A band stops when all its tiles are whole; that is checked before each slice, so
rendering the slices in several calls (a progress bar, slabs) counts and draws exactly what one call does.
"""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np
from numba import types
from numba.extending import overload

from ..jit import jit, leaf, stage
from .composite import TILE
from .select import BLOCK, CELL, KEYS, REGION

# coef layout (camera.Projection.coef)
X0, XA, XB, XC, Y0, YA, YB, YC, W0, WA, WB, WC, CX, CY, WPE, NEAR = range(16)
# footprint params (footprint.Footprint.params)
QA, QB, QC, EX, EY, R2, TSCALE = range(7)
# SliceGeometry.eye layout: slice spacing; distance from the eye to the volume's box along the slice normal (0
# inside); camera.clip; the smallest cosine between a ray and the slice normal (slice spacing / box diagonal: a
# ray runs inside one slab for at most the box's diagonal); the footprint radius in pixels above which a voxel's
# opacity is corrected per pixel (its footprint spans a wide angle); a pixel ray's slice-normal component
# gx (x - cx) + gy (y - cy) + g0 and its squared length (x - cx)^2 + (y - cy)^2 + f2, in pixels
EY_DS, EY_H0, EY_CLIP, EY_COSMIN, EY_WIDE, EY_GX, EY_GY, EY_G0, EY_F2 = range(9)

IndexedVoxels = namedtuple("IndexedVoxels", "slice_ptr region_id region_ptr block_pos block_ptr block_voxel "
                                            "cell_pos cell_count offset density gm nrm n_a n_b")
IndexedVoxels.__doc__ = """One axis of a selection, in the hierarchy of :mod:`isplat.splat.select` (slices, regions,
blocks, cells, voxels), with the gathered channel values ``gm`` (gradient magnitude codes) and ``nrm`` (normal
codes) per voxel, empty when unused."""
WholeVolume = namedtuple("WholeVolume", "density gm nrm strides n_a n_b offs table")
WholeVolume.__doc__ = """Whole channels, flat ``[k, j, i]`` (full method, post-classification); ``strides``: flat
steps along a, b, c and an offset added to every flat index (post-classification of a slab whose channels hold
only its slices; 0 otherwise). ``offs``: ``(oa, ob, oc, da)``, the same index as a sum of per-axis terms and
the voxels along a per prefetch: whole channels give ``oa`` and ``ob`` as strides (ints), ``oc`` as a table;
a pool gives brick-major tables (:func:`isplat.grid.flat_offsets`, ``oa`` and ``ob`` one entry longer, the last
repeated). ``table``: None for whole channels; a pool's delta table (``WholeChannels.deltas``,
:mod:`isplat.selection`): the channels then hold only the pool's bricks, and the voxel of flat brick-major
index ``i`` is at ``i + table[i >> POOL_SHIFT]`` (isplat.splat.post reads them so; ``strides`` then do not
apply)."""
Indexed = namedtuple("Indexed", "vox bins")
Indexed.__doc__ = """The indexed method's voxels (:data:`IndexedVoxels`) with the regions of each slice that reach
each band (:data:`Bins`); the full method's are a :data:`WholeVolume` (:func:`slice_regions`)."""
SliceGeometry = namedtuple("SliceGeometry", "coef steps qe persp inv_unit normal_off slice_step cuts eye")
SliceGeometry.__doc__ = """``coef`` 16 floats (camera.Projection.coef); ``steps`` rows A, B, C (3 x 3 floats);
``qe`` volume origin minus eye (3 floats); tuples rather than arrays, so the per-voxel stages take no arrays;
``cuts`` rows (g0, ga, gb, gc), a voxel kept where ``g0 + a*ga + b*gb + c*gc >= 0``; ``eye`` (perspective,
:func:`path_alpha` and :func:`isplat.splat.pre._splat_rays`) 9 floats, see EY_DS..EY_F2."""
Buffers = namedtuple("Buffers", "img sat tile_sat tile_npix stats")
Buffers.__doc__ = """``img`` (H, W, 4) premultiplied; ``sat`` uint8 (H, W) saturated pixels; ``tile_sat`` their
count per tile, ``tile_npix`` the pixels per tile; ``stats`` int64[bands, 4]: per band the voxels in the slices
it traversed, the voxels it tested one by one, the voxels splatted (samples composited, post), the slices
done. Shared by the threads (each writes its bands' rows)."""
Bands = namedtuple("Bands", "rows mine et")
Bands.__doc__ = """``rows`` int64[bands, 2]: each band's image rows ``[y0, y1)`` (whole tiles); ``mine``: the bands
this call renders, one after the other; ``et`` the early-termination opacity (>= 1: off)."""
Bins = namedtuple("Bins", "ptr regions")
Bins.__doc__ = """The regions each band must visit (:func:`bin_regions`): band ``bi``'s regions of the slice at
position ``oi`` of the frame's order are ``regions[ptr[bi, oi]:ptr[bi, oi + 1]]``."""


# ---- techniques ----------------------------------------------------------------------------------------------
TECHNIQUES = {}         # plan class -> (scratch stage, slice stage), see register


def register(plan_class, scratch, slice_stage) -> None:
    """Make ``plan_class`` (a named tuple, a technique's per-frame plan) renderable by :func:`render`:
    ``scratch(plan)`` is called once per call, ``slice_stage(plan, lists, scratch, c, pos, buf, band)`` once per
    slice and band (both compiled stages of the technique's module)."""
    TECHNIQUES[plan_class] = (scratch, slice_stage)


def call_scratch(plan):
    """The technique's scratch for one call of :func:`render` (its registered ``scratch``; as Python, with
    ``NUMBA_DISABLE_JIT=1``)."""
    return TECHNIQUES[type(plan)][0](plan)


def render_slice(plan, lists, scratch, c, pos, buf, band):
    """Slice ``c`` for one band, by the plan's technique (its registered ``slice`` stage)."""
    TECHNIQUES[type(plan)][1](plan, lists, scratch, c, pos, buf, band)


def _technique(plan):
    """The registered stages of a plan's numba type (a named tuple of a registered class), or None."""
    return TECHNIQUES.get(getattr(plan, "instance_class", None))


@overload(call_scratch, inline="always")
def _typed_call_scratch(plan):
    found = _technique(plan)
    if found is None:
        return None
    scratch = found[0]

    def impl(plan):
        return scratch(plan)
    return impl


@overload(render_slice, inline="always")
def _typed_render_slice(plan, lists, scratch, c, pos, buf, band):
    found = _technique(plan)
    if found is None:
        return None
    stage_fn = found[1]

    def impl(plan, lists, scratch, c, pos, buf, band):
        stage_fn(plan, lists, scratch, c, pos, buf, band)
    return impl


@jit
def render(order, o0, plan, lists, buf, bands):
    """Render the slices ``order`` (front to back; ``o0``: the position of ``order[0]`` in the frame's order)
    with the technique of ``plan`` into ``buf.img``, for the bands ``bands.mine`` one after the other;
    ``lists`` is this thread's scratch. What allocates is here, once per call; the bands' slice loops are
    leaves (:func:`_band_slices`)."""
    scratch = call_scratch(plan)
    for bi in bands.mine:
        band = _band(bi, bands, buf)
        _band_slices(order, o0, plan, lists, scratch, buf, band)


@leaf
def _band_slices(order, o0, plan, lists, scratch, buf, band):
    """One band's slices, front to back until the band saturates. A leaf: without reference counting, the
    arrays this loop hands on per slice cost no atomic increments and decrements of counters that every
    thread's loop shares."""
    for oi in range(order.shape[0]):
        if band_saturated(band):
            break
        render_slice(plan, lists, scratch, order[oi], o0 + oi, buf, band)


# ---- which regions of a slice a band visits (axis-aligned techniques) ----------------------------------------
def source_scratch(source):
    """What :func:`slice_regions` needs per call: nothing of its own for the indexed method (an empty index: the
    channel values are at the voxels' own rows), the hierarchy's arrays for the full method
    (:func:`full_scratch`)."""
    if isinstance(source, Indexed):
        return (np.empty(0, dtype=np.int64),)
    return full_scratch(source.n_a, source.n_b)


def slice_regions(source, scratch, c, pos, alpha, use_gm, geo, reach, buf, band):
    """The regions of slice ``c`` that band ``band`` visits, in the hierarchy of :mod:`isplat.splat.select`:
    ``(regions, p0, p1, hier, vals, n_a, n_b)``, the regions ``regions[p0:p1]`` of ``hier`` (region_id,
    region_ptr, block_pos, block_ptr, block_voxel, cell_pos, cell_count, offset, density) and ``vals = (gm, nrm,
    index, direct)``: a voxel's channel values are at its own row (``direct``) or at ``index[row]``.

    ``source``: :data:`Indexed` (the index's selection and the bins of the frame's order, ``pos`` the slice's
    position there) or :data:`WholeVolume` (the full method: every voxel of the regions that reach the band
    classified with ``alpha``, :func:`full_slice_regions`). Counts the slice's voxels into ``buf.stats``."""
    if isinstance(source, Indexed):
        return _indexed_regions(source, scratch, c, pos, buf, band)
    return _full_regions(source, scratch, c, alpha, use_gm, geo, reach, buf, band)


@leaf
def _indexed_regions(source, scratch, c, pos, buf, band):
    """:func:`slice_regions` of the indexed method."""
    vox, bins = source
    bi = band[0]
    r0 = vox.region_ptr[vox.slice_ptr[c]]
    r1 = vox.region_ptr[vox.slice_ptr[c + 1]]
    buf.stats[bi, 0] += vox.block_voxel[r1] - vox.block_voxel[r0]
    hier = (vox.region_id, vox.region_ptr, vox.block_pos, vox.block_ptr, vox.block_voxel, vox.cell_pos,
            vox.cell_count, vox.offset, vox.density)
    return (bins.regions, bins.ptr[bi, pos], bins.ptr[bi, pos + 1], hier, (vox.gm, vox.nrm, scratch[0], True),
            vox.n_a, vox.n_b)


@leaf
def _full_regions(vox, scratch, c, alpha, use_gm, geo, reach, buf, band):
    """:func:`slice_regions` of the full method."""
    hier, index, all_regions, _ = scratch
    n_regions = full_slice_regions(c, vox, alpha, use_gm, geo, reach, buf, band, scratch)
    return all_regions, 0, n_regions, hier, (vox.gm, vox.nrm, index, False), vox.n_a, vox.n_b


def _is_indexed(source) -> bool:
    return isinstance(source, types.BaseNamedTuple) and source.instance_class is Indexed


@overload(source_scratch, inline="always")
def _typed_source_scratch(source):
    if _is_indexed(source):
        return lambda source: (np.empty(0, dtype=np.int64),)
    return lambda source: full_scratch(source.n_a, source.n_b)


@overload(slice_regions, inline="always")
def _typed_slice_regions(source, scratch, c, pos, alpha, use_gm, geo, reach, buf, band):
    if _is_indexed(source):
        def impl(source, scratch, c, pos, alpha, use_gm, geo, reach, buf, band):
            return _indexed_regions(source, scratch, c, pos, buf, band)
        return impl

    def impl_full(source, scratch, c, pos, alpha, use_gm, geo, reach, buf, band):
        return _full_regions(source, scratch, c, alpha, use_gm, geo, reach, buf, band)
    return impl_full


# ---- a band's saturation state ---------------------------------------------------------------------------------
@stage
def _band(bi, bands, buf):
    """Band ``bi``'s state: (index, first row, end row, et, summed-area table of its whole tiles, first tile row)."""
    y0, y1 = bands.rows[bi, 0], bands.rows[bi, 1]
    ty0 = y0 // TILE
    ty1 = (y1 + TILE - 1) // TILE
    satab = np.zeros((ty1 - ty0 + 1, buf.tile_sat.shape[1] + 1), dtype=np.int32)
    band = (bi, y0, y1, bands.et, satab, ty0)
    if bands.et < 1.0:
        build_sat(buf.tile_sat, buf.tile_npix, ty0, satab)
    return band


@leaf
def build_sat(tile_sat, tile_npix, ty0, satab):
    """The summed-area table of the band's whole tiles (every pixel saturated): ``satab[y + 1, x + 1]`` counts
    the whole tiles in tile rows ``ty0 .. ty0 + y`` and columns ``0 .. x``."""
    for y in range(satab.shape[0] - 1):
        row = 0
        for x in range(satab.shape[1] - 1):
            row += 1 if tile_sat[ty0 + y, x] >= tile_npix[ty0 + y, x] else 0
            satab[y + 1, x + 1] = satab[y, x + 1] + row


@leaf
def _tiles_whole(satab, ty0, x0, x1, y0, y1):
    """True when every tile the pixel box [x0, x1] x [y0, y1] (inside the band) touches is whole."""
    tx0 = np.uint64(x0) // np.uint64(TILE)          # unsigned: all >= 0 here, no wrap-around or sign fix-ups
    tx1 = np.uint64(x1) // np.uint64(TILE) + np.uint64(1)
    r0 = np.uint64(y0) // np.uint64(TILE) - np.uint64(ty0)
    r1 = np.uint64(y1) // np.uint64(TILE) - np.uint64(ty0) + np.uint64(1)
    whole = satab[r1, tx1] - satab[r0, tx1] - satab[r1, tx0] + satab[r0, tx0]
    return whole == np.int64((r1 - r0) * (tx1 - tx0))


@leaf
def band_saturated(band):
    """True when early termination is on and every pixel of the band is saturated."""
    satab = band[4]
    if band[3] >= 1.0:
        return False
    return satab[-1, -1] == (satab.shape[0] - 1) * (satab.shape[1] - 1)




# ---- the region -> block -> cell walk and the occlusion tests --------------------------------------------------
@leaf
def slice_bases(c, geo, cs):
    """§3.1: the per-slice bases, two additions per slice: (xs, ys, ws, pb0, pb1, pb2, hc); ``cs`` gets the
    cutting planes' offsets for this slice."""
    coef = geo.coef
    for ci in range(geo.cuts.shape[0]):
        cs[ci] = geo.cuts[ci, 0] + c * geo.cuts[ci, 3]
    return (coef[X0] + c * coef[XC], coef[Y0] + c * coef[YC], coef[W0] + c * coef[WC],
            geo.qe[0] + c * geo.steps[2][0], geo.qe[1] + c * geo.steps[2][1], geo.qe[2] + c * geo.steps[2][2],
            abs(geo.normal_off + c * geo.slice_step))


@stage(forceinline=True)
def box_args(n_a, n_b, base, geo, reach, img_w, band, et_on):
    """What :func:`_hidden` needs of a slice and a band: ``reach`` (x, y) how far a voxel's footprint reaches
    at perspective scale 1, in pixels; ``img_w`` the image's width; ``et_on``: test saturation, not only the
    band."""
    return (n_a, n_b, base, geo.coef, geo.persp, reach[0], reach[1], img_w, band[1], band[2], band[5], et_on)


@leaf
def visible_cells(regions, p0, p1, hier, n_a, boxes, satab, sat, tile_sat, cells):
    """Stage 2: the cells of regions ``regions[p0:p1]`` whose footprints can reach an unsaturated pixel of the
    band, as rows ``(first voxel, end voxel, a0, b0)`` of ``cells``; a hidden region or block is skipped with
    one test (whole tiles), a cell with one test of its tiles or pixels, and the cells of a block that
    :func:`_block_test` finds in the clear (``tile_sat``: the saturated pixels per tile) are kept without
    theirs. Returns the number of cells."""
    region_id, region_ptr, block_pos, block_ptr, block_voxel, cell_pos, cell_count = hier
    nra = (n_a + REGION - 1) // REGION
    nc = 0
    for gi in range(p0, p1):
        g = regions[gi]
        ra0 = (region_id[g] % nra) * REGION
        rb0 = (region_id[g] // nra) * REGION
        if _hidden(ra0, rb0, REGION, boxes, satab, sat, False):
            continue
        for r in range(region_ptr[g], region_ptr[g + 1]):
            ba0 = ra0 + (block_pos[r] % 4) * BLOCK
            bb0 = rb0 + (block_pos[r] // 4) * BLOCK
            hidden, clear = _block_test(ba0, bb0, boxes, satab, tile_sat)
            if hidden:
                continue
            n = block_voxel[r]
            for q in range(block_ptr[r], block_ptr[r + 1]):
                n1 = n + cell_count[q]
                ca0 = ba0 + (cell_pos[q] % 4) * CELL
                cb0 = bb0 + (cell_pos[q] // 4) * CELL
                if clear or not _hidden(ca0, cb0, CELL, boxes, satab, sat, True):
                    cells[nc, 0] = n
                    cells[nc, 1] = n1
                    cells[nc, 2] = ca0
                    cells[nc, 3] = cb0
                    nc += 1
                n = n1
    return nc


# the least footprint reach (pixels, x and y) for which _block_test vouches for a cell's box: over half a pixel
# and the coordinates' rounding, so that every cell's box (at least 2 reach wide) holds a pixel
CLEAR_REACH = 0.5 + 1e-6


@leaf(inline="always")    # numba inlines its IR, not LLVM: see isplat.jit.leaf
def _block_test(a0, b0, boxes, satab, tile_sat):
    """``(hidden, clear)`` of the block from voxel (a0, b0), from one box: ``hidden`` as :func:`_hidden` tests a
    block (whole tiles); ``clear`` True when :func:`_hidden` would find none of its cells hidden, so they need no
    test of their own: orthographic (a cell's box then lies in its block's, bounds computed alike and rounding
    monotonic, :func:`rect_hull`), the block's box inside the image and the band, no saturated pixel in the tiles
    it touches (``tile_sat``; or early termination off), and a footprint reach over half a pixel each way
    (:data:`CLEAR_REACH`: no cell's box is empty). ``clear`` False when unsure: the cells are then tested."""
    n_a, n_b, base, coef, persp, ex, ey, img_w, y0b, y1b, ty0, et_on = boxes
    ok, box = _rect_box(a0, min(a0 + BLOCK, n_a) - 1, b0, min(b0 + BLOCK, n_b) - 1, base, coef, persp, ex, ey)
    if not ok:
        return False, False
    empty, gx0, gx1, gy0, gy1 = _band_box(box, img_w, y0b, y1b)
    if empty or (et_on and _tiles_whole(satab, ty0, gx0, gx1, gy0, gy1)):
        return True, False
    if (persp or ex < CLEAR_REACH or ey < CLEAR_REACH or box[0] < 0 or box[1] > img_w - 1 or box[2] < y0b
            or box[3] > y1b - 1):
        return False, False
    if et_on:
        for ty in range(box[2] // TILE, box[3] // TILE + 1):
            for tx in range(box[0] // TILE, box[1] // TILE + 1):
                if tile_sat[ty, tx] != 0:
                    return False, False
    return False, True


@leaf(inline="always")    # numba inlines its IR, not LLVM: see isplat.jit.leaf
def _hidden(a0, b0, size, boxes, satab, sat, pixels):
    """Stage 2: True when the footprints of the voxels of the square ``[a0, a0 + size) x [b0, b0 + size)`` of
    the slice can reach no pixel of the band, or (early termination on) only saturated ones: whole tiles
    answer at once, and with ``pixels`` the pixels themselves (worth it for a cell, not for larger squares)."""
    n_a, n_b, base, coef, persp, ex, ey, img_w, y0b, y1b, ty0, et_on = boxes
    ok, box = _rect_box(a0, min(a0 + size, n_a) - 1, b0, min(b0 + size, n_b) - 1, base, coef, persp, ex, ey)
    if not ok:
        return False
    empty, gx0, gx1, gy0, gy1 = _band_box(box, img_w, y0b, y1b)
    if empty:
        return True
    if not et_on:
        return False
    if pixels:
        return covered(satab, ty0, sat, gx0, gx1, gy0, gy1)
    return _tiles_whole(satab, ty0, gx0, gx1, gy0, gy1)


@leaf(inline="always")    # numba inlines its IR, not LLVM: see isplat.jit.leaf
def _band_box(box, img_w, y0b, y1b):
    """``(empty, x0, x1, y0, y1)``: the pixel box ``box`` (x0, x1, y0, y1) clipped to the image and the band
    (rows [y0b, y1b)), and whether nothing is left (:func:`_hidden`, :func:`_block_test`)."""
    gx0, gx1 = max(box[0], 0), min(box[1], img_w - 1)
    gy0, gy1 = max(box[2], y0b), min(box[3], y1b - 1)
    return gy0 > gy1 or gx0 > gx1, gx0, gx1, gy0, gy1


@leaf(forceinline=True)
def _rect_box(a0, a1, b0, b1, base, coef, persp, ex, ey):
    """The pixel box ``(x0, x1, y0, y1)`` that the footprints of voxels in the rectangle [a0, a1] x [b0, b1]
    of the slice can reach: the hull of its corners' projections (:func:`rect_hull`) grown by the footprint's
    radius at the largest perspective scale; ``ok`` False when a corner is behind the near plane (then its
    voxels are tested one by one)."""
    ok, cx0, cx1, cy0, cy1, smax = rect_hull(a0, a1, b0, b1, base, coef, persp)
    if not ok:
        return False, (0, 0, 0, 0)
    return True, (int(math.ceil(cx0 - ex * smax)), int(math.floor(cx1 + ex * smax)),
                  int(math.ceil(cy0 - ey * smax)), int(math.floor(cy1 + ey * smax)))


@leaf(forceinline=True)
def rect_hull(a0, a1, b0, b1, base, coef, persp):
    """The pixel bounds ``(ok, x0, x1, y0, y1, largest perspective scale)`` of the rectangle [a0, a1] x [b0, b1]
    of the slice plane (the projection of a planar rectangle is the hull of its corners' projections); ``ok``
    False when a corner is at or behind the near plane."""
    xs, ys, ws = base[0], base[1], base[2]
    if not persp:       # x and y are sums of a term in a and one in b, and rounding is monotonic: each bound is
        xa0, xa1 = a0 * coef[XA], a1 * coef[XA]     # that of the corner with the least (greatest) terms, as below
        xb0, xb1 = b0 * coef[XB], b1 * coef[XB]
        ya0, ya1 = a0 * coef[YA], a1 * coef[YA]
        yb0, yb1 = b0 * coef[YB], b1 * coef[YB]
        return (True, xs + min(xa0, xa1) + min(xb0, xb1), xs + max(xa0, xa1) + max(xb0, xb1),
                ys + min(ya0, ya1) + min(yb0, yb1), ys + max(ya0, ya1) + max(yb0, yb1), 1.0)
    cx0 = 1e300
    cx1 = -1e300
    cy0 = 1e300
    cy1 = -1e300
    smax = 1.0
    for corner in range(4):
        ka = a0 if corner & 1 == 0 else a1
        kb = b0 if corner & 2 == 0 else b1
        kx = xs + ka * coef[XA] + kb * coef[XB]
        ky = ys + ka * coef[YA] + kb * coef[YB]
        if persp:
            kd = ws + ka * coef[WA] + kb * coef[WB]
            if -kd < coef[NEAR]:
                return False, 0.0, 0.0, 0.0, 0.0, 1.0
            ks = coef[WPE] / kd
            smax = max(smax, ks) if corner > 0 else ks
            kx = coef[CX] + ks * kx
            ky = coef[CY] + ks * ky
        cx0 = min(cx0, kx)
        cx1 = max(cx1, kx)
        cy0 = min(cy0, ky)
        cy1 = max(cy1, ky)
    return True, cx0, cx1, cy0, cy1, smax


@leaf
def covered(satab, ty0, sat, x0, x1, y0, y1):
    """True when every pixel of the box [x0, x1] x [y0, y1] (inside the band) has reached the
    early-termination opacity: whole tiles answer at once; otherwise the byte mask (small, stays in cache)."""
    return _tiles_whole(satab, ty0, x0, x1, y0, y1) or pixels_saturated(sat, x0, x1, y0, y1)


@leaf
def pixels_saturated(sat, x0, x1, y0, y1):
    """True when every pixel of the box [x0, x1] x [y0, y1] is marked in the byte mask ``sat``."""
    for y in range(y0, y1 + 1):
        row = np.uint64(y)
        for x in range(x0, x1 + 1):
            if sat[row, np.uint64(x)] == 0:     # unsigned: no negative-index wrap-around (x, y >= 0 here)
                return False
    return True


@jit
def bin_regions(order, vox, geo, ex, ey, rows, img_w):
    """Per frame, before any slice: for every band (``rows``: image rows ``[y0, y1)``, whole tiles, tiling the
    image's rows from 0) the regions of each slice of ``order`` whose footprints can reach its rows; the
    occlusion tests then run per band on only those. Returns :data:`Bins`' ``(ptr, regions)``: the first pass
    finds each region's first and last band (its box, once) and counts the regions per band and slice into
    ``ptr``, the second puts them at ``regions[pos[...]]``."""
    nbands = rows.shape[0]
    img_h = rows[nbands - 1, 1]
    of_tile = np.empty((img_h + TILE - 1) // TILE, dtype=np.int64)      # tile row -> its band
    for bi in range(nbands):
        if (rows[bi, 0] != (rows[bi - 1, 1] if bi else 0) or rows[bi, 1] <= rows[bi, 0] or rows[bi, 0] % TILE
                or (bi < nbands - 1 and rows[bi, 1] % TILE)):
            raise ValueError("bin_regions: the bands must tile the image's rows from 0 in whole tiles "
                             "(frame.image_bands)")
        of_tile[rows[bi, 0] // TILE:(rows[bi, 1] + TILE - 1) // TILE] = bi
    nra = (vox.n_a + REGION - 1) // REGION
    cs = np.empty(max(geo.cuts.shape[0], 1), dtype=np.float64)
    ptr = np.zeros((nbands, order.shape[0] + 1), dtype=np.int64)
    n_regions = 0
    for oi in range(order.shape[0]):
        n_regions += vox.slice_ptr[order[oi] + 1] - vox.slice_ptr[order[oi]]
    span = np.empty((n_regions, 2), dtype=np.int32)     # per region in the order's sequence: first, last band
    k = 0
    for oi in range(order.shape[0]):
        c = order[oi]
        base = slice_bases(c, geo, cs)
        for g in range(vox.slice_ptr[c], vox.slice_ptr[c + 1]):
            a0 = (vox.region_id[g] % nra) * REGION
            b0 = (vox.region_id[g] // nra) * REGION
            ok, box = _rect_box(a0, min(a0 + REGION, vox.n_a) - 1, b0, min(b0 + REGION, vox.n_b) - 1, base,
                                geo.coef, geo.persp, ex, ey)
            if ok and (box[1] < 0 or box[0] > img_w - 1 or box[3] < 0 or box[2] > img_h - 1):
                first, last = 0, -1                     # off the image: in no band
            else:
                first = of_tile[max(box[2], 0) // TILE] if ok else 0
                last = of_tile[min(box[3], img_h - 1) // TILE] if ok else nbands - 1
            span[k, 0] = first
            span[k, 1] = last
            k += 1
            for bi in range(first, last + 1):
                ptr[bi, oi] += 1
    start = 0
    for bi in range(nbands):            # counts -> offsets, band after band
        for oi in range(order.shape[0] + 1):
            ptr[bi, oi], start = start, start + ptr[bi, oi]
    regions = np.empty(start, dtype=np.int64)
    pos = ptr.copy()
    k = 0
    for oi in range(order.shape[0]):
        c = order[oi]
        for g in range(vox.slice_ptr[c], vox.slice_ptr[c + 1]):
            for bi in range(span[k, 0], span[k, 1] + 1):
                regions[pos[bi, oi]] = g
                pos[bi, oi] += 1
            k += 1
    return ptr, regions




# ---- per voxel or sample, shared by the axis-aligned techniques ------------------------------------------------
@leaf
def cut_away(a, b, cuts, cs):
    """Stage 3a: True when a cutting plane removes the voxel at (a, b) of the slice (``cs``: the planes'
    offsets for this slice)."""
    for ci in range(cuts.shape[0]):
        if cs[ci] + a * cuts[ci, 1] + b * cuts[ci, 2] < 0.0:
            return True
    return False


@leaf
def footprint_box(px, py, rx, ry, y0b, y1b, img_w):
    """The pixel box ``(x0, x1, y0, y1)`` of a footprint at (px, py) with half-extents (rx, ry), clipped to the
    image and the band of rows ``y0b:y1b``; ``ok`` is False when it misses them."""
    fx0 = math.ceil(px - rx)
    fx1 = math.floor(px + rx)
    fy0 = math.ceil(py - ry)
    fy1 = math.floor(py + ry)
    if fx1 < 0 or fy1 < y0b or fx0 > img_w - 1 or fy0 > y1b - 1:
        return False, (0, 0, 0, 0)
    box = (max(int(fx0), 0), min(int(fx1), img_w - 1), max(int(fy0), y0b), min(int(fy1), y1b - 1))
    return box[2] <= box[3], box


@leaf
def path_alpha(L, a, b, base, steps, persp, inv_unit, coef, eye):
    """Stage 3c: the voxel's opacity and ``r``, its slab's thickness along the slice normal in unit distances
    (perspective; 0 orthographic). Orthographic: ``L`` (already corrected for the path length). Perspective:
    corrected here for the path ``r / cos`` through the slab along this voxel's ray. The slab is the slice
    spacing, except for the first slab kept along the ray (the one in front is behind the eye or nearer than the
    near plane): it reaches back to where the integral starts (camera.clip: the eye or a set near plane; not in
    front of the volume's box), so neither the eye's own slab nor the culled ones are lost or counted whole."""
    if not persp:
        return L, 0.0
    vx = base[3] + a * steps[0][0] + b * steps[1][0]
    vy = base[4] + a * steps[0][1] + b * steps[1][1]
    vz = base[5] + a * steps[0][2] + b * steps[1][2]
    dist = math.sqrt(vx * vx + vy * vy + vz * vz)
    hc = base[6]                               # distance from the eye to the slice's plane, along the normal
    ds = eye[EY_DS]
    r = inv_unit                               # = slice spacing / unit distance
    depth = -(base[2] + a * coef[WA] + b * coef[WB])      # -D: in front of the eye along -w
    # this ray crosses the slice plane in front at depth depth * (hc - ds) / hc: culled there?
    if depth * (hc - ds) < coef[NEAR] * hc:
        lower = max(eye[EY_H0], eye[EY_CLIP] * hc / depth)
        r = inv_unit * max(hc + 0.5 * ds - lower, 0.0) / ds
    # the cosine between the ray and the slice normal, bounded so a ray runs inside one slab for at most the
    # volume's diagonal
    cosang = max(hc / max(dist, 1e-300), eye[EY_COSMIN])
    return -math.expm1(r / cosang * L), r




# ---- the full method: every voxel of a slice classified into the hierarchy -------------------------------------
@stage
def full_scratch(n_a, n_b):
    """The full method's scratch for a slice of ``n_a`` x ``n_b`` voxels: the hierarchy's arrays (as
    :data:`IndexedVoxels` has them), the voxels' flat positions, every region's id and the regions wanted."""
    nra = (n_a + REGION - 1) // REGION
    ng = nra * ((n_b + REGION - 1) // REGION)
    m = n_a * n_b
    hier = (np.empty(ng, np.int32), np.empty(ng + 1, np.int64), np.empty(ng * 16, np.uint8),
            np.empty(ng * 16 + 1, np.int64), np.empty(ng * 16 + 1, np.int64), np.empty(ng * KEYS, np.uint8),
            np.empty(ng * KEYS, np.uint8), np.empty(m, np.uint8), np.empty(m, np.uint8))
    return hier, np.empty(m, np.int64), np.arange(ng), np.empty(ng, np.bool_)


@stage
def full_slice_regions(c, vox, alpha, use_gm, geo, reach, buf, band, scratch):
    """Stage 1 of the full method for slice ``c`` and one band: every voxel of the regions whose footprints can
    reach the band's rows classified with the opacities ``alpha``, those not transparent put in the hierarchy
    (``scratch``, :func:`full_scratch`); returns the number of regions."""
    hier, index, _, wanted = scratch
    n_a, n_b = vox.n_a, vox.n_b
    nra = (n_a + REGION - 1) // REGION
    cs = np.empty(max(geo.cuts.shape[0], 1), dtype=np.float64)
    boxes = box_args(n_a, n_b, slice_bases(c, geo, cs), geo, reach, buf.img.shape[1], band, False)
    for rid in range(wanted.shape[0]):
        wanted[rid] = not _hidden((rid % nra) * REGION, (rid // nra) * REGION, REGION, boxes, band[4], buf.sat,
                                  False)
    buf.stats[band[0], 0] += n_a * n_b
    return _full_slice(c, vox, alpha, use_gm, hier, index, wanted)


@stage
def _full_slice(c, vox, alpha, use_gm, hier, index, wanted):
    """Traversal of the full method: every voxel of slice ``c`` that is not transparent, in the regions
    ``wanted``, in the hierarchy (regions, blocks, cells) of the index's selection, into ``hier`` and
    ``index`` (flat positions); returns the number of regions."""
    region_id, region_ptr, block_pos, block_ptr, block_voxel, cell_pos, cell_count, offset, dens = hier
    density, gm, strides, n_a, n_b = vox.density, vox.gm, vox.strides, vox.n_a, vox.n_b
    nra = (n_a + REGION - 1) // REGION
    cbase = c * strides[2]
    n = 0
    ng = 0
    nb = 0
    nq = 0
    for rid in range(nra * ((n_b + REGION - 1) // REGION)):
        if not wanted[rid]:
            continue
        ra0, rb0 = (rid % nra) * REGION, (rid // nra) * REGION
        region_id[ng] = rid
        region_ptr[ng] = nb
        for bp in range(16):
            ba0, bb0 = ra0 + (bp % 4) * BLOCK, rb0 + (bp // 4) * BLOCK
            block_pos[nb] = bp
            block_ptr[nb] = nq
            block_voxel[nb] = n
            for cp in range(16):
                ca0, cb0 = ba0 + (cp % 4) * CELL, bb0 + (cp // 4) * CELL
                first = n
                for b in range(cb0, min(n_b, cb0 + CELL)):
                    for a in range(ca0, min(n_a, ca0 + CELL)):
                        fi = cbase + a * strides[0] + b * strides[1]
                        d = density[fi]
                        if alpha[d, gm[fi] if use_gm else 0] != 0.0:
                            index[n] = fi
                            offset[n] = (b - cb0) * CELL + a - ca0
                            dens[n] = d
                            n += 1
                if n > first:
                    cell_pos[nq] = cp
                    cell_count[nq] = n - first
                    nq += 1
            nb += 1 if block_ptr[nb] < nq else 0
        ng += 1 if region_ptr[ng] < nb else 0
    region_ptr[ng] = nb
    block_ptr[nb] = nq
    block_voxel[nb] = n
    return ng


# ---- Python: a frame's tables for the walk -------------------------------------------------------------------
def indexed_source(order, vox, geo, reach, rows, img_w) -> Indexed:
    """The indexed method's :data:`Indexed`: one axis of a selection and, for the frame's slice ``order``, the
    regions of each slice that reach each band of ``rows`` (:func:`bin_regions`; ``reach`` as
    :func:`box_args`)."""
    return Indexed(vox, Bins(*bin_regions(order, vox, geo, reach[0], reach[1], rows, img_w)))


def max_cells(sel, axis: str) -> int:
    """The most cells one slice of ``axis`` can have (the size of a thread's list of visible cells)."""
    from .. import grid

    if sel.empty or (sel.method != "full" and axis not in sel.axes):
        return 0            # (an axis not selected is refused by sel.voxels)
    if sel.method == "full":
        _, n_a, n_b = grid.slice_shape(sel.shape, axis)
        return -(-n_a // CELL) * -(-n_b // CELL)
    return sel.axes[axis].max_cells
