"""The frame kernel: splat slices of one principal axis front to back into an image (paper §2.2, §3).

Arrays in, arrays out, no I/O. A frame is cut into named stages, each a small compiled function:

1. per slice, the traversal: which voxels reach the pipeline. :func:`render_indexed` streams the voxels the
   index selected (:func:`isplat.splat.select.select_voxels`); :func:`render_full` visits every voxel
   (:func:`_full_slice`). Both hand the slice's voxels on as a hierarchy of squares of the slice: regions of
   64 x 64 voxels, blocks of 16 x 16, cells of 4 x 4;
2. the occlusion test (:func:`_visible_cells`, :func:`_hidden`): a region, block or cell whose footprints can
   reach no pixel of the band, or (early termination) only saturated ones, is skipped with one test, so
   hidden material costs one test per square rather than one per voxel;
3. per voxel, classify, cut, project (§3) and shade (:func:`_splat_cells`: :func:`_cut_away`,
   :func:`_project`, :func:`_path_alpha`, :func:`_shade`);
4. the splat into the slice's sheet (:func:`_splat`; next to the eye in perspective :func:`_splat_rays`, the
   opacity along each pixel's own ray), and the sheet composited into the image
   (:func:`isplat.splat.composite.composite_sheet`).

Within a slice contributions are summed into a sheet buffer, so both traversals give the same image up to
float rounding (the order of the sums), and the speed-up measures indexing alone.

Threads: the image is cut into bands of rows of whole tiles (:func:`isplat.frame.band_rows`: where the frames
before found equal work); each band walks the slices on its own, visiting only the regions that
:func:`bin_regions` found to reach its rows (once per frame), and a thread renders its bands one after the other
(one call per band, timed). The image does not depend on the bands: a pixel is written by
one band, which sums the same voxels in the same order whatever the bands are.

The kernels take a few grouped arguments, named tuples built by :mod:`isplat.frame`:

- ``vox``: the voxels, :data:`IndexedVoxels` (one axis of a selection) or :data:`WholeVolume` (full method);
- ``bins``: :data:`Bins`, the regions of each slice that reach each band (indexed method);
- ``cls``: :data:`Classify`, the transfer function's and shading's tables for this frame;
- ``geo``: :data:`SliceGeometry`, the §3 coefficients and what perspective and cutting planes need;
- ``fp``: :data:`FootprintTable`, the splat kernel as a 1-D table (:mod:`isplat.splat.footprint`);
- ``buf``: :data:`Buffers`, the image and its saturation state (shared by the bands), the sheet, this
  thread's scratch lists and the counters per band;
- ``bands``: :data:`Bands`, every band's rows, the bands this call renders and the early-termination opacity.

Early termination: a square or voxel whose footprints cover only saturated pixels (opacity at the threshold)
is skipped; TILE x TILE tiles whose pixels are all saturated answer that test at once, through a summed-area
table of the band's whole tiles (one look-up for any box), made again after a slice saturates new pixels. A
band stops when all its tiles are whole; that is checked before each slice, so rendering the slices in
several calls (a progress bar, slabs) counts and draws exactly what one call does.
"""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np

from ..jit import jit, leaf, stage
from .composite import TILE, composite_sheet
from .select import BLOCK, CELL, KEYS, REGION

# coef layout (camera.Projection.coef)
X0, XA, XB, XC, Y0, YA, YB, YC, W0, WA, WB, WC, CX, CY, WPE, NEAR = range(16)
# footprint params
QA, QB, QC, EX, EY, R2, TSCALE = range(7)

IndexedVoxels = namedtuple("IndexedVoxels", "slice_ptr region_id region_ptr block_pos block_ptr block_voxel "
                                            "cell_pos cell_count offset density gm nrm n_a n_b")
IndexedVoxels.__doc__ = """One axis of a selection, in the hierarchy of :mod:`isplat.splat.select` (slices, regions,
blocks, cells, voxels), with the gathered channel values ``gm`` (gradient magnitude codes) and ``nrm`` (normal
codes) per voxel, empty when unused."""
WholeVolume = namedtuple("WholeVolume", "density gm nrm strides n_a n_b")
WholeVolume.__doc__ = """Whole channels, flat ``[k, j, i]`` (full method, post-classification); ``strides``: flat
steps along a, b, c and an offset added to every flat index (post-classification of a slab whose channels hold
only its slices; 0 otherwise)."""
Classify = namedtuple("Classify", "alpha color shade use_gm use_shade")
Classify.__doc__ = """``alpha`` float[256, G]: opacity per (density, gradient code), corrected for the slice's
path length (orthographic) or as ``log1p(-alpha)`` (perspective); ``color`` float32[256, 3]; ``shade``
float32[65536, 2 or 6]: Phong factors per normal code (:mod:`isplat.splat.shade`). Post-classified frames
take float64 tables with each code's step to the next beside it, ``alpha`` [256, 2G] and ``color`` [256, 6]
(:func:`isplat.splat.post.lerp_tables`)."""
SliceGeometry = namedtuple("SliceGeometry", "coef steps qe persp inv_unit normal_off slice_step cuts eye")
SliceGeometry.__doc__ = """``coef`` 16 floats (camera.Projection.coef); ``steps`` rows A, B, C (3 x 3 floats);
``qe`` volume origin minus eye (3 floats); tuples rather than arrays, so the per-voxel stages take no arrays; ``cuts`` rows (g0, ga, gb, gc), a voxel kept where ``g0 + a*ga + b*gb + c*gc >= 0``;
``eye`` (perspective, :func:`_path_alpha` and :func:`_splat_rays`) 9 floats, see EY_DS..EY_F2."""
# geo.eye layout: slice spacing; distance from the eye to the volume's box along the slice normal (0 inside);
# camera.clip; the smallest cosine between a ray and the slice normal (slice spacing / box diagonal: a ray runs
# inside one slab for at most the box's diagonal); the footprint radius in pixels above which a voxel's opacity
# is corrected per pixel (its footprint spans a wide angle); a pixel ray's slice-normal component
# gx (x - cx) + gy (y - cy) + g0 and its squared length (x - cx)^2 + (y - cy)^2 + f2, in pixels
EY_DS, EY_H0, EY_CLIP, EY_COSMIN, EY_WIDE, EY_GX, EY_GY, EY_G0, EY_F2 = range(9)
FootprintTable = namedtuple("FootprintTable", "table params")
Buffers = namedtuple("Buffers", "img sheet sat tile_sat tile_npix dirty_px dirty cells stats")
Buffers.__doc__ = """``img`` (H, W, 4) premultiplied; ``sat`` uint8 (H, W) saturated pixels; ``tile_sat`` their
count per tile, ``tile_npix`` the pixels per tile; ``sheet``, ``dirty_px`` and ``dirty`` the slice's buffer and
its touched pixels (``dirty``: this thread's list); ``cells`` int64[C, 4] this thread's list of a slice's
visible cells; ``stats`` int64[bands, 4]: per band the voxels in the slices
it traversed, the voxels it tested one by one, the voxels splatted, the slices done."""
Bands = namedtuple("Bands", "rows mine et")
Bands.__doc__ = """``rows`` int64[bands, 2]: each band's image rows ``[y0, y1)`` (whole tiles); ``mine``: the bands
this call renders, one after the other; ``et`` the early-termination opacity (>= 1: off)."""
Bins = namedtuple("Bins", "ptr regions")
Bins.__doc__ = """The regions each band must visit (:func:`bin_regions`): band ``bi``'s regions of the slice at
position ``oi`` of the frame's order are ``regions[ptr[bi, oi]:ptr[bi, oi + 1]]``."""


@jit
def render_indexed(order, o0, bins, vox, cls, geo, fp, buf, bands):
    """Render the slices ``order`` (front to back; ``o0``: the position of ``order[0]`` in the frame's
    order) of the index's selection ``vox`` into ``buf.img``, for the bands ``bands.mine``."""
    hier = (vox.region_id, vox.region_ptr, vox.block_pos, vox.block_ptr, vox.block_voxel, vox.cell_pos,
            vox.cell_count, vox.offset, vox.density)
    vals = (vox.gm, vox.nrm, np.empty(0, dtype=np.int64), True)
    for bi in bands.mine:
        band = _band(bi, bands, buf)
        for oi in range(order.shape[0]):
            if _band_saturated(band):
                break
            c = order[oi]
            r0 = vox.region_ptr[vox.slice_ptr[c]]
            r1 = vox.region_ptr[vox.slice_ptr[c + 1]]
            buf.stats[bi, 0] += vox.block_voxel[r1] - vox.block_voxel[r0]
            p0, p1 = bins.ptr[bi, o0 + oi], bins.ptr[bi, o0 + oi + 1]
            _render_slice(c, bins.regions, p0, p1, hier, vals, vox.n_a, vox.n_b, cls, geo, fp, buf, band)


@jit
def render_full(order, o0, bins, vox, cls, geo, fp, buf, bands):
    """Render the slices ``order`` (front to back) of the whole volume ``vox`` into ``buf.img``: every voxel of
    every slice is classified (the no-index baseline), in the hierarchy the index's selection has."""
    scratch = full_scratch(vox.n_a, vox.n_b)
    hier, index, all_regions, _ = scratch
    for bi in bands.mine:
        band = _band(bi, bands, buf)
        for oi in range(order.shape[0]):
            if _band_saturated(band):
                break
            c = order[oi]
            n_regions = full_slice_regions(c, vox, cls, geo, fp, buf, band, scratch)
            _render_slice(c, all_regions, 0, n_regions, hier, (vox.gm, vox.nrm, index, False), vox.n_a, vox.n_b, cls,
                          geo, fp, buf, band)


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
def full_slice_regions(c, vox, cls, geo, fp, buf, band, scratch):
    """Stage 1 of the full method for slice ``c`` and one band: every voxel of the regions whose footprints can
    reach the band's rows classified, those not transparent put in the hierarchy (``scratch``,
    :func:`full_scratch`); returns the number of regions."""
    hier, index, _, wanted = scratch
    n_a, n_b = vox.n_a, vox.n_b
    nra = (n_a + REGION - 1) // REGION
    cs = np.empty(max(geo.cuts.shape[0], 1), dtype=np.float64)
    box_args = _box_args(n_a, n_b, _slice_bases(c, geo, cs), geo, fp, buf, band, False)
    for rid in range(wanted.shape[0]):
        wanted[rid] = not _hidden((rid % nra) * REGION, (rid // nra) * REGION, REGION, box_args, band[4], buf.sat,
                                  False)
    buf.stats[band[0], 0] += n_a * n_b
    return _full_slice(c, vox, cls, hier, index, wanted)


@stage
def _band(bi, bands, buf):
    """Band ``bi``'s state: (index, first row, end row, et, summed-area table of its whole tiles, first tile row)."""
    y0, y1 = bands.rows[bi, 0], bands.rows[bi, 1]
    ty0 = y0 // TILE
    ty1 = (y1 + TILE - 1) // TILE
    satab = np.zeros((ty1 - ty0 + 1, buf.tile_sat.shape[1] + 1), dtype=np.int32)
    band = (bi, y0, y1, bands.et, satab, ty0)
    if bands.et < 1.0:
        _build_sat(buf.tile_sat, buf.tile_npix, ty0, satab)
    return band


@leaf
def _build_sat(tile_sat, tile_npix, ty0, satab):
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
def _band_saturated(band):
    """True when early termination is on and every pixel of the band is saturated."""
    satab = band[4]
    if band[3] >= 1.0:
        return False
    return satab[-1, -1] == (satab.shape[0] - 1) * (satab.shape[1] - 1)


@stage
def _full_slice(c, vox, cls, hier, index, wanted):
    """Traversal of the full method: every voxel of slice ``c`` that is not transparent, in the regions
    ``wanted``, in the hierarchy (regions, blocks, cells) of the index's selection, into ``hier`` and
    ``index`` (flat positions); returns the number of regions."""
    region_id, region_ptr, block_pos, block_ptr, block_voxel, cell_pos, cell_count, offset, dens = hier
    density, gm, strides, n_a, n_b = vox.density, vox.gm, vox.strides, vox.n_a, vox.n_b
    alpha, use_gm = cls.alpha, cls.use_gm
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


@leaf
def _slice_bases(c, geo, cs):
    """§3.1: the per-slice bases, two additions per slice: (xs, ys, ws, pb0, pb1, pb2, hc); ``cs`` gets the
    cutting planes' offsets for this slice."""
    coef = geo.coef
    for ci in range(geo.cuts.shape[0]):
        cs[ci] = geo.cuts[ci, 0] + c * geo.cuts[ci, 3]
    return (coef[X0] + c * coef[XC], coef[Y0] + c * coef[YC], coef[W0] + c * coef[WC],
            geo.qe[0] + c * geo.steps[2][0], geo.qe[1] + c * geo.steps[2][1], geo.qe[2] + c * geo.steps[2][2],
            abs(geo.normal_off + c * geo.slice_step))


@stage
def _render_slice(c, regions, p0, p1, hier, vals, n_a, n_b, cls, geo, fp, buf, band):
    """Stages 2-4 for slice ``c`` and one band: the regions ``regions[p0:p1]``, their blocks and cells tested
    for occlusion (stage 2, :func:`_visible_cells`), each voxel of the cells left classified, cut, projected
    and shaded (stage 3) and splatted into the sheet (stage 4, :func:`_splat_cells`); then the sheet
    composited into the image. Within a slice the tests see the saturation of the slices in front only, so
    the cells can be picked first and splatted after. ``vals = (gm, nrm, index, direct)``: a voxel's channel
    values are at its own row (``direct``) or at ``index[row]``."""
    bi, y0b, y1b, et, satab, ty0 = band
    cs = np.empty(max(geo.cuts.shape[0], 1), dtype=np.float64)
    base = _slice_bases(c, geo, cs)
    box_args = _box_args(n_a, n_b, base, geo, fp, buf, band, et < 1.0)
    cells = buf.cells
    nc = _visible_cells(regions, p0, p1, hier[:7], n_a, box_args, satab, buf.sat, cells)
    nd = _splat_cells(cells, nc, hier[7], hier[8], vals, base, cs, cls, geo, fp, buf, band)
    if composite_sheet(buf.img, buf.sheet, buf.sat, buf.tile_sat, buf.dirty_px, buf.dirty, nd, et) > 0:
        _build_sat(buf.tile_sat, buf.tile_npix, ty0, satab)
    buf.stats[bi, 3] += 1


@stage(forceinline=True)
def _box_args(n_a, n_b, base, geo, fp, buf, band, et_on):
    """What :func:`_hidden` needs of a slice and a band (``et_on``: test saturation, not only the band)."""
    return (n_a, n_b, base, geo.coef, geo.persp, fp.params[EX], fp.params[EY], buf.img.shape[1], band[1], band[2],
            band[5], et_on)


@leaf
def _visible_cells(regions, p0, p1, hier, n_a, box_args, satab, sat, cells):
    """Stage 2: the cells of regions ``regions[p0:p1]`` whose footprints can reach an unsaturated pixel of the
    band, as rows ``(first voxel, end voxel, a0, b0)`` of ``cells``; a hidden region or block is skipped with
    one test (whole tiles), a cell with one test of its tiles or pixels. Returns the number of cells."""
    region_id, region_ptr, block_pos, block_ptr, block_voxel, cell_pos, cell_count = hier
    nra = (n_a + REGION - 1) // REGION
    nc = 0
    for gi in range(p0, p1):
        g = regions[gi]
        ra0 = (region_id[g] % nra) * REGION
        rb0 = (region_id[g] // nra) * REGION
        if _hidden(ra0, rb0, REGION, box_args, satab, sat, False):
            continue
        for r in range(region_ptr[g], region_ptr[g + 1]):
            ba0 = ra0 + (block_pos[r] % 4) * BLOCK
            bb0 = rb0 + (block_pos[r] // 4) * BLOCK
            if _hidden(ba0, bb0, BLOCK, box_args, satab, sat, False):
                continue
            n = block_voxel[r]
            for q in range(block_ptr[r], block_ptr[r + 1]):
                n1 = n + cell_count[q]
                ca0 = ba0 + (cell_pos[q] % 4) * CELL
                cb0 = bb0 + (cell_pos[q] // 4) * CELL
                if not _hidden(ca0, cb0, CELL, box_args, satab, sat, True):
                    cells[nc, 0] = n
                    cells[nc, 1] = n1
                    cells[nc, 2] = ca0
                    cells[nc, 3] = cb0
                    nc += 1
                n = n1
    return nc


@stage
def _splat_cells(cells, nc, offset, dens, vals, base, cs, cls, geo, fp, buf, band):
    """Stages 3 and 4 for the voxels of the cells ``cells[:nc]``; returns the sheet's touched-pixel count.

    The per-voxel stages take single arrays, not the grouped tuples: numba counts references to every array
    handed to a function, and a tuple of eight arrays per voxel costs more than the voxel's splat.
    """
    gm, nrm, index, direct = vals
    alpha_tab, color, shade, use_gm, use_shade = cls
    coef, steps, cuts, persp, eye = geo.coef, geo.steps, geo.cuts, geo.persp, geo.eye
    sheet, sat, dirty_px, dirty, stats = buf.sheet, buf.sat, buf.dirty_px, buf.dirty, buf.stats
    bi, y0b, y1b, et, satab, ty0 = band
    et_on = et < 1.0
    img_w = sheet.shape[1]
    table = fp.table
    fpc = (fp.params[QA], 2.0 * fp.params[QB], fp.params[QC], fp.params[R2], fp.params[TSCALE])
    ex, ey = fp.params[EX], fp.params[EY]
    wide_s = eye[EY_WIDE] / max(ex, ey) if persp else 0.0     # a larger perspective scale: a wide footprint
    ncut = cuts.shape[0]
    nd = 0
    for k in range(nc):
        ca0, cb0 = cells[k, 2], cells[k, 3]
        stats[bi, 1] += cells[k, 1] - cells[k, 0]
        for n in range(cells[k, 0], cells[k, 1]):
            fi = n if direct else index[n]
            a = ca0 + np.int64(offset[n] % CELL)
            b = cb0 + np.int64(offset[n] // CELL)
            d = dens[n]
            L = alpha_tab[d, gm[fi] if use_gm else 0]
            if L == 0.0 or (ncut > 0 and _cut_away(a, b, cuts, cs)):
                continue
            ok, px, py, s, box = _project(a, b, base, coef, persp, ex, ey, y0b, y1b, img_w)
            if not ok or (et_on and _covered(satab, ty0, sat, box[0], box[1], box[2], box[3])):
                continue
            alpha, r = _path_alpha(L, a, b, base, steps, persp, geo.inv_unit, coef, eye)
            if persp and s > wide_s:
                # next to the eye: the opacity along each pixel's own ray
                cr, cg, cb = _shade(d, nrm[fi] if use_shade else 0, 1.0, color, shade, use_shade)
                nd = _splat_rays(px, py, s, box, cr, cg, cb, r * L, fpc, table, coef, eye, sheet, dirty_px, dirty,
                                 nd)
            else:
                cr, cg, cb = _shade(d, nrm[fi] if use_shade else 0, alpha, color, shade, use_shade)
                nd = _splat(px, py, s, box, cr, cg, cb, alpha, fpc, table, sheet, dirty_px, dirty, nd)
            # a voxel spanning two bands is counted by the band holding its first image row
            if max(int(math.ceil(py - ey * s)), 0) >= y0b:
                stats[bi, 2] += 1
    return nd


@leaf(inline="always")    # numba inlines its IR, not LLVM: see isplat.jit.leaf
def _hidden(a0, b0, size, box_args, satab, sat, pixels):
    """Stage 2: True when the footprints of the voxels of the square ``[a0, a0 + size) x [b0, b0 + size)`` of
    the slice can reach no pixel of the band, or (early termination on) only saturated ones: whole tiles
    answer at once, and with ``pixels`` the pixels themselves (worth it for a cell, not for larger squares)."""
    n_a, n_b, base, coef, persp, ex, ey, img_w, y0b, y1b, ty0, et_on = box_args
    ok, box = _rect_box(a0, min(a0 + size, n_a) - 1, b0, min(b0 + size, n_b) - 1, base, coef, persp, ex, ey)
    if not ok:
        return False
    gx0, gx1 = max(box[0], 0), min(box[1], img_w - 1)
    gy0, gy1 = max(box[2], y0b), min(box[3], y1b - 1)
    if gy0 > gy1 or gx0 > gx1:
        return True
    if not et_on:
        return False
    if pixels:
        return _covered(satab, ty0, sat, gx0, gx1, gy0, gy1)
    return _tiles_whole(satab, ty0, gx0, gx1, gy0, gy1)


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
def _covered(satab, ty0, sat, x0, x1, y0, y1):
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
    occlusion tests then run per band on only those. Returns :data:`Bins`' ``(ptr, regions)``: two passes,
    the first counts the regions per band and slice into ``ptr``, the second puts them at
    ``regions[pos[...]]``. (One function: a stage called with ``fill`` False and True would be compiled twice,
    for each literal.)"""
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
    pos = ptr
    regions = np.empty(0, dtype=np.int64)
    for fill in range(2):
        if fill:
            start = 0
            for bi in range(nbands):            # counts -> offsets, band after band
                for oi in range(order.shape[0] + 1):
                    ptr[bi, oi], start = start, start + ptr[bi, oi]
            regions = np.empty(start, dtype=np.int64)
            pos = ptr.copy()
        for oi in range(order.shape[0]):
            c = order[oi]
            base = _slice_bases(c, geo, cs)
            for g in range(vox.slice_ptr[c], vox.slice_ptr[c + 1]):
                a0 = (vox.region_id[g] % nra) * REGION
                b0 = (vox.region_id[g] // nra) * REGION
                ok, box = _rect_box(a0, min(a0 + REGION, vox.n_a) - 1, b0, min(b0 + REGION, vox.n_b) - 1, base,
                                    geo.coef, geo.persp, ex, ey)
                if ok and (box[1] < 0 or box[0] > img_w - 1 or box[3] < 0 or box[2] > img_h - 1):
                    continue
                first = of_tile[max(box[2], 0) // TILE] if ok else 0
                last = of_tile[min(box[3], img_h - 1) // TILE] if ok else nbands - 1
                for bi in range(first, last + 1):
                    if fill:
                        regions[pos[bi, oi]] = g
                        pos[bi, oi] += 1
                    else:
                        ptr[bi, oi] += 1
    return ptr, regions


@leaf
def _cut_away(a, b, cuts, cs):
    """Stage 3a: True when a cutting plane removes the voxel at (a, b) of the slice (``cs``: the planes'
    offsets for this slice)."""
    for ci in range(cuts.shape[0]):
        if cs[ci] + a * cuts[ci, 1] + b * cuts[ci, 2] < 0.0:
            return True
    return False


@leaf
def _project(a, b, base, coef, persp, ex, ey, y0b, y1b, img_w):
    """Stage 3b, §3: the voxel's pixel position (two multiply-adds per coordinate from the slice's bases),
    perspective scale and footprint box ``(x0, x1, y0, y1)`` clipped to the image and the band of rows
    ``y0b:y1b``; ``ok`` is False when the voxel is culled or its footprint misses the band."""
    xs, ys, ws = base[0], base[1], base[2]
    none = (0, 0, 0, 0)
    # y first, so a voxel outside this thread's band of rows costs no more
    Y = ys + a * coef[YA] + b * coef[YB]
    s = 1.0
    if persp:
        D = ws + a * coef[WA] + b * coef[WB]
        if -D < coef[NEAR]:
            return False, 0.0, 0.0, s, none        # at or behind the near plane: culled
        s = coef[WPE] / D                          # t0 of §3.2
        py = coef[CY] + s * Y
    else:
        py = Y
    ry = ey * s
    if py + ry < y0b or py - ry > y1b - 1:
        return False, 0.0, py, s, none
    X = xs + a * coef[XA] + b * coef[XB]
    px = coef[CX] + s * X if persp else X
    ok, box = footprint_box(px, py, ex * s, ry, y0b, y1b, img_w)
    return ok, px, py, s, box


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
def _path_alpha(L, a, b, base, steps, persp, inv_unit, coef, eye):
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


@leaf(forceinline=True)
def _footprint_form(fpc, s):
    """The footprint's quadratic form in table units (q * tscale), with the voxel's perspective scale ``s``
    folded in: ``(A, B, C, T)``, the cut-off ``T``."""
    Qa, Qb2, Qc, R2v, tscale = fpc
    k = tscale / (s * s)
    return Qa * k, Qb2 * k, Qc * k, R2v * tscale


@leaf
def _splat_rays(px, py, s, box, cr, cg, cb, rL, fpc, table, coef, eye, sheet, dirty_px, dirty, nd):
    """Stage 4 for a voxel next to the eye, whose footprint spans a wide angle: as :func:`_splat`, but the
    opacity is corrected per pixel for the path through the slab along that pixel's own ray (``rL``: r times
    log1p(-alpha) of :func:`_path_alpha`; ``cr, cg, cb`` straight colour). The voxel's own ray would give the
    pixels around it the path of a ray far off theirs (a uniform slab seen from inside it would come out
    denser at the centre than it is)."""
    x0, x1, y0, y1 = box
    img_w = sheet.shape[1]
    A, B, C, T = _footprint_form(fpc, s)
    gx, cmin = eye[EY_GX], eye[EY_COSMIN]
    for y in range(y0, y1 + 1):
        dy = y - py
        ty = C * dy * dy
        txy = B * dy
        ry = y - coef[CY]
        ny = eye[EY_GY] * ry + eye[EY_G0]
        r2y = ry * ry + eye[EY_F2]
        for x in range(x0, x1 + 1):
            dx = x - px
            wgt = table[int(min((A * dx + txy) * dx + ty, T))]
            dirty[nd] = y * img_w + x
            nd += 1 - dirty_px[y, x]
            dirty_px[y, x] = 1
            if wgt == 0.0:
                continue
            rx = x - coef[CX]
            cosang = max(abs(gx * rx + ny) / math.sqrt(rx * rx + r2y), cmin)
            wa = wgt * -math.expm1(rL / cosang)
            sheet[y, x, 0] += wa * cr
            sheet[y, x, 1] += wa * cg
            sheet[y, x, 2] += wa * cb
            sheet[y, x, 3] += wa
    return nd


@leaf
def _shade(d, code, alpha, color, shade, use_shade):
    """Stage 3d: premultiplied colour of density ``d`` (Phong factors of normal ``code`` from the per-code
    table when shading is on)."""
    cr = color[d, 0]
    cg = color[d, 1]
    cb = color[d, 2]
    if use_shade:
        if shade.shape[1] == 2:
            # white lights: one diffuse and one specular factor per code (a smaller table, which matters:
            # it is read at random codes)
            dif = shade[code, 0]
            spe = shade[code, 1]
            cr = cr * dif + spe
            cg = cg * dif + spe
            cb = cb * dif + spe
        else:
            cr = cr * shade[code, 0] + shade[code, 3]
            cg = cg * shade[code, 1] + shade[code, 4]
            cb = cb * shade[code, 2] + shade[code, 5]
    return cr * alpha, cg * alpha, cb * alpha


@leaf
def _splat(px, py, s, box, cr, cg, cb, alpha, fpc, table, sheet, dirty_px, dirty, nd):
    """Stage 4: add the voxel's footprint into the sheet over ``box``; returns the new touched-pixel count.

    Branch-free on purpose: the indexed traversal feeds voxels density by density, in no spatial order, and a
    per-pixel branch here mispredicts (it cost 25% on the semi-transparent engine). q at or past the cut-off
    reads the table's trailing zero; the dirty list always stores the pixel and advances only on its first touch.
    """
    x0, x1, y0, y1 = box
    img_w = sheet.shape[1]
    A, B, C, T = _footprint_form(fpc, s)
    for y in range(y0, y1 + 1):
        dy = y - py
        ty = C * dy * dy
        txy = B * dy
        for x in range(x0, x1 + 1):
            dx = x - px
            wgt = table[int(min((A * dx + txy) * dx + ty, T))]
            dirty[nd] = y * img_w + x
            nd += 1 - dirty_px[y, x]
            dirty_px[y, x] = 1
            sheet[y, x, 0] += wgt * cr
            sheet[y, x, 1] += wgt * cg
            sheet[y, x, 2] += wgt * cb
            sheet[y, x, 3] += wgt * alpha
    return nd
