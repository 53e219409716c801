"""The paper's splatting (``render.classification = "pre"``): each voxel classified, then spread by a Gaussian
footprint into its slice's sheet (paper §2.2, §3).

A technique of :mod:`isplat.splat.traverse` (which walks the bands, the slices, and the regions, blocks and
cells the occlusion tests leave): this module is its per-frame plan (:data:`PrePlan`, made by :func:`plan`) and
its per-slice stages:

1. per voxel of the cells left, classify, cut, project (§3) and shade (:func:`_splat_cells`:
   :func:`isplat.splat.traverse.cut_away`, :func:`_project`, :func:`isplat.splat.traverse.path_alpha`,
   :func:`_shade`);
2. the splat into the slice's sheet (:func:`_splat`; next to the eye in perspective :func:`_splat_rays`, the
   opacity along each pixel's own ray), and the sheet composited into the image
   (:func:`isplat.splat.composite.composite_sheet`).

Within a slice contributions are summed into a sheet buffer, so both traversals (the index's selection or every
voxel, :func:`isplat.splat.traverse.slice_regions`) give the same image up to float rounding (the order of the
sums), and the speed-up measures indexing alone. The image does not depend on the bands: a pixel is written by
one band, which sums the same voxels in the same order whatever the bands are.

The plan's tables, named tuples built by :func:`plan`:

- ``source``: the voxels, :data:`isplat.splat.traverse.Indexed` (one axis of a selection and its bins) or
  :data:`isplat.splat.traverse.WholeVolume` (full method);
- ``cls``: :data:`Classify`, the transfer function's and shading's tables for this frame;
- ``geo``: :data:`isplat.splat.traverse.SliceGeometry`, the §3 coefficients and what perspective and cutting
  planes need;
- ``fp``: :data:`FootprintTable`, the splat kernel as a 1-D table (:mod:`isplat.splat.footprint`), and
  ``reach`` its extent in pixels;
- ``sheet``: :data:`Sheet`, the slice's buffer and its touched pixels (shared by the threads' bands);

and per thread :data:`PreLists`, its touched-pixel list and its list of a slice's visible cells.
"""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np

from ..jit import leaf, stage
from .composite import composite_sheet
from .select import CELL
from .traverse import (CX, CY, EX, EY, EY_COSMIN, EY_F2, EY_G0, EY_GX, EY_GY, EY_WIDE, NEAR, QA, QB, QC, R2,
                       TSCALE, WA, WB, WPE, XA, XB, YA, YB, box_args, build_sat, covered, cut_away,
                       footprint_box, indexed_source, max_cells, path_alpha, register, slice_bases, slice_regions,
                       source_scratch, visible_cells)

Classify = namedtuple("Classify", "alpha color shade use_gm use_shade")
Classify.__doc__ = """``alpha`` float[256, G]: opacity per (density, gradient code), corrected for the slice's
path length (orthographic) or as ``log1p(-alpha)`` (perspective); ``color`` float32[256, 3]; ``shade``
float32[65536, 2 or 6]: Phong factors per normal code (:mod:`isplat.splat.shade`)."""
FootprintTable = namedtuple("FootprintTable", "table params")
FootprintTable.__doc__ = """The footprint (:func:`isplat.splat.footprint.make_footprint`): ``table`` its weights by
squared distance (trailing zero), ``params`` float64[7] (layout QA..TSCALE of :mod:`isplat.splat.traverse`)."""
Sheet = namedtuple("Sheet", "sheet dirty_px")
Sheet.__doc__ = """A slice's buffer (H, W, 4), summed into and composited after the slice, and its touched pixels
(uint8 (H, W)); each thread's list of them is its own."""
PreLists = namedtuple("PreLists", "dirty cells")
PreLists.__doc__ = """A thread's scratch: ``dirty`` the pixels its slice touched (int64, a band's pixels + 1);
``cells`` int64[C, 4] its list of a slice's visible cells."""
PrePlan = namedtuple("PrePlan", "source cls geo fp reach sheet")
PrePlan.__doc__ = """A pre-classified frame's tables (module docstring)."""


def sheet_buffers(height: int, width: int, dtype) -> Sheet:
    """An empty :data:`Sheet` of an image ``height`` x ``width``."""
    return Sheet(np.zeros((height, width, 4), dtype), np.zeros((height, width), np.uint8))


def plan(tables):
    """The frame's :data:`PrePlan`, each thread's :data:`PreLists` and None (the view's slices), from what
    :func:`isplat.frame.prepare` works out for every technique (``tables``, :class:`isplat.frame.FrameTables`)."""
    from ..errors import IsplatError
    from .footprint import make_footprint

    sel, view, ro = tables.sel, tables.view, tables.view.render
    if sel.post and sel.method == "indexed" and (sel.use_shade or sel.use_gm):
        raise IsplatError("render.classification = 'pre' needs the channel values of the voxels of interest; this "
                          "selection was made for 'post' (make it with the pre-classified scene)")
    if any(s.cells_only for s in sel.axes.values()):    # (the kernel would index the voxels' empty arrays)
        raise IsplatError("render.classification = 'pre' needs the voxels of interest; this selection was made for "
                          "a post-classified composite frame, which holds the cells alone (make it with the "
                          "pre-classified scene)")
    cls = Classify(tables.atab, sel.luts.color, tables.shade, sel.use_gm, sel.use_shade)
    fp = make_footprint(tables.proj.jac, ro.footprint_sigma, ro.footprint_radius, ro.footprint_table, tables.dtype)
    reach = (float(fp.params[EX]), float(fp.params[EY]))
    vox = sel.voxels(tables.axis)
    source = vox if sel.method == "full" else \
        indexed_source(view.order, vox, tables.geo, reach, tables.rows, view.frame.width)
    n_cells = max_cells(sel, tables.axis)
    lists = [PreLists(np.empty(tables.band_px + 1, np.int64), np.empty((n_cells, 4), np.int64))
             for _ in range(tables.threads)]
    sheet = sheet_buffers(view.frame.height, view.frame.width, tables.dtype)
    return PrePlan(source, cls, tables.geo, FootprintTable(fp.table, fp.params), reach, sheet), lists, None


@stage
def _scratch(plan):
    """What a call allocates once: the traversal's (:func:`isplat.splat.traverse.source_scratch`)."""
    return source_scratch(plan.source)


@leaf(inline="always")    # numba inlines its IR, not LLVM: see isplat.jit.leaf
def _slice(plan, lists, scratch, c, pos, buf, band):
    """Slice ``c`` for one band: its regions (:func:`isplat.splat.traverse.slice_regions`), then
    :func:`_render_slice`."""
    regions, p0, p1, hier, vals, n_a, n_b = slice_regions(plan.source, scratch, c, pos, plan.cls.alpha,
                                                          plan.cls.use_gm, plan.geo, plan.reach, buf, band)
    _render_slice(c, regions, p0, p1, hier, vals, n_a, n_b, plan, lists, buf, band)


@stage
def _render_slice(c, regions, p0, p1, hier, vals, n_a, n_b, plan, lists, buf, band):
    """Slice ``c`` and one band: the regions ``regions[p0:p1]``, their blocks and cells tested for occlusion
    (:func:`isplat.splat.traverse.visible_cells`), each voxel of the cells left classified, cut, projected and
    shaded and splatted into the sheet (:func:`_splat_cells`); then the sheet composited into the image.
    Within a slice the tests see the saturation of the slices in front only, so the cells can be picked first
    and splatted after. ``vals = (gm, nrm, index, direct)``: a voxel's channel values are at its own row
    (``direct``) or at ``index[row]``."""
    bi, y0b, y1b, et, satab, ty0 = band
    geo = plan.geo
    cs = np.empty(max(geo.cuts.shape[0], 1), dtype=np.float64)
    base = slice_bases(c, geo, cs)
    boxes = box_args(n_a, n_b, base, geo, plan.reach, buf.img.shape[1], band, et < 1.0)
    cells = lists.cells
    nc = visible_cells(regions, p0, p1, hier[:7], n_a, boxes, satab, buf.sat, buf.tile_sat, cells)
    nd = _splat_cells(cells, nc, hier[7], hier[8], vals, base, cs, plan.cls, geo, plan.fp, plan.sheet, lists.dirty,
                      buf, band)
    if composite_sheet(buf.img, plan.sheet.sheet, buf.sat, buf.tile_sat, plan.sheet.dirty_px, lists.dirty, nd,
                       et) > 0:
        build_sat(buf.tile_sat, buf.tile_npix, ty0, satab)
    buf.stats[bi, 3] += 1


@stage
def _splat_cells(cells, nc, offset, dens, vals, base, cs, cls, geo, fp, sheet_buf, dirty, buf, band):
    """Classify, cut, project, shade and splat the voxels of the cells ``cells[:nc]`` into the sheet
    (``sheet_buf``, touched pixels listed in ``dirty``); returns the sheet's touched-pixel count.

    The per-voxel stages take single arrays, not the grouped tuples: numba counts references to every array
    handed to a function, and a tuple of eight arrays per voxel costs more than the voxel's splat.
    """
    gm, nrm, index, direct = vals
    alpha_tab, color, shade, use_gm, use_shade = cls
    coef, steps, cuts, persp, eye = geo.coef, geo.steps, geo.cuts, geo.persp, geo.eye
    sheet, dirty_px = sheet_buf
    sat, stats = buf.sat, buf.stats
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
            if L == 0.0 or (ncut > 0 and cut_away(a, b, cuts, cs)):
                continue
            ok, px, py, s, box = _project(a, b, base, coef, persp, ex, ey, y0b, y1b, img_w)
            if not ok or (et_on and covered(satab, ty0, sat, box[0], box[1], box[2], box[3])):
                continue
            alpha, r = path_alpha(L, a, b, base, steps, persp, geo.inv_unit, coef, eye)
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


@leaf
def _project(a, b, base, coef, persp, ex, ey, y0b, y1b, img_w):
    """§3: the voxel's pixel position (two multiply-adds per coordinate from the slice's bases),
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
    py = coef[CY] + s * Y if persp else Y
    ry = ey * s
    if py + ry < y0b or py - ry > y1b - 1:
        return False, 0.0, py, s, none
    return footprint_at(xs + a * coef[XA] + b * coef[XB], py, s, ry, coef, persp, ex, y0b, y1b, img_w)


@leaf(inline="always")    # numba inlines its IR, not LLVM: see isplat.jit.leaf
def footprint_at(X, py, s, ry, coef, persp, ex, y0b, y1b, img_w):
    """The rest of a projection once its row ``py`` is known to reach the band: the pixel column of ``X`` (the
    §3 x before the perspective division by ``s``), and the footprint's box, half-extents ``ex s`` and ``ry``
    (:func:`isplat.splat.traverse.footprint_box`); returns ``(ok, px, py, s, box)``."""
    px = coef[CX] + s * X if persp else X
    ok, box = footprint_box(px, py, ex * s, ry, y0b, y1b, img_w)
    return ok, px, py, s, box


@leaf(forceinline=True)
def _footprint_form(fpc, s):
    """The footprint's quadratic form in table units (q * tscale), with the voxel's perspective scale ``s``
    folded in: ``(A, B, C, T)``, the cut-off ``T``."""
    Qa, Qb2, Qc, R2v, tscale = fpc
    k = tscale / (s * s)
    return Qa * k, Qb2 * k, Qc * k, R2v * tscale


@leaf
def _splat_rays(px, py, s, box, cr, cg, cb, rL, fpc, table, coef, eye, sheet, dirty_px, dirty, nd):
    """The splat of a voxel next to the eye, whose footprint spans a wide angle: as :func:`_splat`, but the
    opacity is corrected per pixel for the path through the slab along that pixel's own ray (``rL``: r times
    log1p(-alpha) of :func:`isplat.splat.traverse.path_alpha`; ``cr, cg, cb`` straight colour). The voxel's
    own ray would give the pixels around it the path of a ray far off theirs (a uniform slab seen from inside
    it would come out denser at the centre than it is)."""
    gx, cmin = eye[EY_GX], eye[EY_COSMIN]
    x0, x1, y0, y1 = box
    img_w = sheet.shape[1]
    A, B, C, T = _footprint_form(fpc, s)
    for y in range(y0, y1 + 1):
        ry = y - coef[CY]
        ny = eye[EY_GY] * ry + eye[EY_G0]
        r2y = ry * ry + eye[EY_F2]
        dy = y - py
        ty = C * dy * dy
        txy = B * dy
        for x in range(x0, x1 + 1):
            dx = x - px
            wgt = table[int(min((A * dx + txy) * dx + ty, T))]
            nd = _touch(dirty_px, dirty, nd, x, y, img_w)
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
    """Premultiplied colour of density ``d`` (Phong factors of normal ``code`` from the per-code
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
    """Add the voxel's footprint into the sheet over ``box``; returns the new touched-pixel count.

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
            nd = add_to_sheet(sheet, dirty_px, dirty, nd, x, y, img_w, table[int(min((A * dx + txy) * dx + ty, T))],
                              cr, cg, cb, alpha)
    return nd


@leaf(inline="always")    # numba inlines its IR, not LLVM: see isplat.jit.leaf
def add_to_sheet(sheet, dirty_px, dirty, nd, x, y, img_w, wgt, cr, cg, cb, alpha):
    """Add ``wgt`` times the premultiplied colour and opacity (cr, cg, cb, alpha) to pixel (x, y) of the sheet
    (:func:`_touch`); returns the new touched-pixel count."""
    nd = _touch(dirty_px, dirty, nd, x, y, img_w)
    sheet[y, x, 0] += wgt * cr
    sheet[y, x, 1] += wgt * cg
    sheet[y, x, 2] += wgt * cb
    sheet[y, x, 3] += wgt * alpha
    return nd


@leaf(inline="always")    # numba inlines its IR, not LLVM: see isplat.jit.leaf
def _touch(dirty_px, dirty, nd, x, y, img_w):
    """List pixel (x, y) as touched: the list always stores it and advances only on its first touch (no branch);
    returns the new count."""
    dirty[nd] = y * img_w + x
    nd += 1 - dirty_px[y, x]
    dirty_px[y, x] = 1
    return nd


register(PrePlan, _scratch, _slice)
