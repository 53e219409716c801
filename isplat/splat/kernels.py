"""The frame kernel: splat slices of one principal axis front to back into an image (paper §2.2, §3).

Arrays in, arrays out, no I/O. A frame is cut into named stages, each a small compiled function:

1. per slice, the traversal: which voxels reach the pipeline. :func:`render_indexed` streams the voxels the
   index selected (:func:`isplat.splat.select.select_voxels`); :func:`render_full` visits every voxel
   (:func:`_full_cells`). Both hand the slice's voxels on grouped in cells of CELL x CELL voxels;
2. per cell, the occlusion test (:func:`_cell_box`, :func:`_saturated`): a cell whose footprints can reach only saturated
   pixels, or none of this thread's band, is skipped with one test;
3. per voxel, classify, cut, project (§3) and shade (:func:`_classify`, :func:`_project`, :func:`_shade`);
4. the splat into the slice's sheet (:func:`_splat`), and the sheet composited into the image
   (:func:`isplat.splat.composite.composite_sheet`).

Within a slice contributions are summed into a sheet buffer (order-independent), so both traversals give
the same image up to float rounding, and the speed-up measures indexing alone.

The kernels take a few grouped arguments, named tuples built by :mod:`isplat.frame`:

- ``vox``: the voxels, :data:`IndexedVoxels` (one axis of a selection) or :data:`WholeVolume` (full method);
- ``cls``: :data:`Classify`, the transfer function's and shading's tables for this frame;
- ``geo``: :data:`SliceGeometry`, the §3 coefficients and what perspective and cutting planes need;
- ``fp``: :data:`FootprintTable`, the splat kernel as a 1-D table (:mod:`isplat.splat.footprint`);
- ``buf``: :data:`Buffers`, the image and its saturation state (shared by the threads' bands), the sheet,
  this band's list of touched pixels and counters;
- ``band``: :data:`Band`, the image rows this call writes and the early-termination opacity.

Early termination: a voxel whose footprint covers only saturated pixels (opacity at the threshold) is
skipped before shading; TILE x TILE tiles whose pixels are all saturated answer that test at once. A band
stops when all its tiles are saturated; that is checked before each slice, so rendering the slices in several
calls (a progress bar, slabs) counts and draws exactly what one call does.
"""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np

from ..jit import jit, leaf
from .composite import TILE, composite_sheet
from .select import CELL

# coef layout (camera.Projection.coef)
X0, XA, XB, XC, Y0, YA, YB, YC, W0, WA, WB, WC, CX, CY, WPE, NEAR = range(16)
# footprint params
QA, QB, QC, EX, EY, R2, TSCALE = range(7)

IndexedVoxels = namedtuple("IndexedVoxels", "cell_ptr cell_start cell_id a b density gm nrm n_a n_b")
IndexedVoxels.__doc__ = """One axis of a selection: slice ``c`` holds cells ``cell_ptr[c]:cell_ptr[c+1]``, cell
``q`` the voxels ``cell_start[q]:cell_start[q+1]`` of ``a, b, density`` and of the gathered channel values
``gm`` (gradient magnitude codes) and ``nrm`` (normal codes), empty when unused."""
WholeVolume = namedtuple("WholeVolume", "density gm nrm strides n_a n_b")
WholeVolume.__doc__ = """Whole channels, flat ``[k, j, i]`` (full method); ``strides``: flat steps along a, b, c."""
Classify = namedtuple("Classify", "alpha color shade use_gm use_shade")
Classify.__doc__ = """``alpha`` float[256, G]: opacity per (density, gradient code), corrected for the slice's
path length (orthographic) or as ``log1p(-alpha)`` (perspective); ``color`` float32[256, 3]; ``shade``
float32[65536, 2 or 6]: Phong factors per normal code (:mod:`isplat.splat.shade`)."""
SliceGeometry = namedtuple("SliceGeometry", "coef steps qe persp inv_unit normal_off slice_step cuts")
SliceGeometry.__doc__ = """``coef`` 16 floats (camera.Projection.coef); ``steps`` rows A, B, C (3 x 3 floats);
``qe`` volume origin minus eye (3 floats); tuples rather than arrays, so the per-voxel stages take no arrays; ``cuts`` rows (g0, ga, gb, gc), a voxel kept where ``g0 + a*ga + b*gb + c*gc >= 0``."""
FootprintTable = namedtuple("FootprintTable", "table params")
Buffers = namedtuple("Buffers", "img sheet sat tile_sat tile_npix dirty_px dirty stats")
Buffers.__doc__ = """``img`` (H, W, 4) premultiplied; ``sat`` uint8 (H, W) saturated pixels; ``tile_sat`` their
count per tile, ``tile_npix`` the pixels per tile; ``sheet``, ``dirty_px`` and ``dirty`` the slice's buffer and
its touched pixels; ``stats`` int64[3]: voxels examined, voxels splatted, slices done."""
Band = namedtuple("Band", "y0 y1 et")


@jit
def render_indexed(order, vox, cls, geo, fp, buf, band):
    """Render slices ``order`` (front to back) of the index's selection ``vox`` into ``buf.img``."""
    no_index = np.empty(0, dtype=np.int64)
    for oi in range(order.shape[0]):
        if _band_saturated(buf, band):
            break
        c = order[oi]
        q0 = vox.cell_ptr[c]
        q1 = vox.cell_ptr[c + 1]
        buf.stats[0] += vox.cell_start[q1] - vox.cell_start[q0]
        cells = (q0, q1, vox.cell_start, vox.cell_id, vox.a, vox.b, vox.density, vox.gm, vox.nrm, no_index, True)
        _render_slice(c, cells, vox.n_a, vox.n_b, cls, geo, fp, buf, band)


@jit
def render_full(order, vox, cls, geo, fp, buf, band):
    """Render slices ``order`` (front to back) of the whole volume ``vox`` into ``buf.img``."""
    m = vox.n_a * vox.n_b
    nca = (vox.n_a + CELL - 1) // CELL
    ncb = (vox.n_b + CELL - 1) // CELL
    cell_start = np.empty(nca * ncb + 1, dtype=np.int64)
    cell_id = np.empty(nca * ncb, dtype=np.int32)
    cand = (np.empty(m, dtype=np.int64), np.empty(m, dtype=np.uint16), np.empty(m, dtype=np.uint16),
            np.empty(m, dtype=np.uint8))
    for oi in range(order.shape[0]):
        if _band_saturated(buf, band):
            break
        c = order[oi]
        nq = _full_cells(c, vox, cls, cand, cell_start, cell_id)
        buf.stats[0] += m
        cells = (0, nq, cell_start, cell_id, cand[1], cand[2], cand[3], vox.gm, vox.nrm, cand[0], False)
        _render_slice(c, cells, vox.n_a, vox.n_b, cls, geo, fp, buf, band)


@jit
def _band_saturated(buf, band):
    """True when early termination is on and every pixel of this band is saturated."""
    if band.et >= 1.0:
        return False
    for ty in range(band.y0 // TILE, (band.y1 + TILE - 1) // TILE):
        for tx in range(buf.tile_npix.shape[1]):
            if buf.tile_sat[ty, tx] < buf.tile_npix[ty, tx]:
                return False
    return True


@jit
def _full_cells(c, vox, cls, cand, cell_start, cell_id):
    """Traversal of the full method: every voxel of slice ``c`` that is not transparent, cell by cell (the
    grouping the index's selection has), into ``cand = (flat index, a, b, density)``; returns the cells."""
    cand_fi, cand_a, cand_b, cand_d = cand
    density, gm, strides, n_a, n_b = vox.density, vox.gm, vox.strides, vox.n_a, vox.n_b
    alpha, use_gm = cls.alpha, cls.use_gm
    nca = (n_a + CELL - 1) // CELL
    ncb = (n_b + CELL - 1) // CELL
    cbase = c * strides[2]
    ncand = 0
    nq = 0
    for qb in range(ncb):
        for qa in range(nca):
            first = ncand
            for b in range(qb * CELL, min(n_b, qb * CELL + CELL)):
                for a in range(qa * CELL, min(n_a, qa * CELL + CELL)):
                    fi = cbase + a * strides[0] + b * strides[1]
                    d = density[fi]
                    if alpha[d, gm[fi] if use_gm else 0] != 0.0:
                        cand_fi[ncand] = fi
                        cand_a[ncand] = a
                        cand_b[ncand] = b
                        cand_d[ncand] = d
                        ncand += 1
            if ncand > first:
                cell_start[nq] = first
                cell_id[nq] = qb * nca + qa
                nq += 1
    cell_start[nq] = ncand
    return nq


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


@jit
def _render_slice(c, cells, n_a, n_b, cls, geo, fp, buf, band):
    """Stages 2-4 for slice ``c``: occlusion test per cell, classify/project/shade per voxel, splat into the
    sheet, composite the sheet. ``cells = (q0, q1, cell_start, cell_id, a, b, density, gm, nrm, index,
    direct)``: a voxel's channel values are at its own row (``direct``) or at ``index[row]``.

    The per-voxel stages take single arrays, not the grouped tuples: numba counts references to every array
    handed to a function, and a tuple of eight arrays per voxel costs more than the voxel's splat.
    """
    q0, q1, cstart, cid, src_a, src_b, src_d, gm, nrm, index, direct = cells
    alpha_tab, color, shade, use_gm, use_shade = cls
    coef, steps, cuts, persp = geo.coef, geo.steps, geo.cuts, geo.persp
    sheet, sat, tile_sat, tile_npix, dirty_px, dirty, stats = buf.sheet, buf.sat, buf.tile_sat, buf.tile_npix, \
        buf.dirty_px, buf.dirty, buf.stats
    y0b, y1b, et = band
    et_on = et < 1.0
    img_w = sheet.shape[1]
    table = fp.table
    fpc = (fp.params[QA], 2.0 * fp.params[QB], fp.params[QC], fp.params[R2], fp.params[TSCALE])
    ex, ey = fp.params[EX], fp.params[EY]
    ncut = cuts.shape[0]
    cs = np.empty(max(ncut, 1), dtype=np.float64)
    base = _slice_bases(c, geo, cs)
    test_cells = et_on or y0b > 0 or y1b < sheet.shape[0]
    nd = 0
    for q in range(q0, q1):
        if test_cells:
            # stage 2: skip a cell whose footprints reach no pixel of this band, or only saturated ones
            ok, box = _cell_box(cid[q], n_a, n_b, base, coef, persp, ex, ey)
            if ok:
                gx0, gx1 = max(box[0], 0), min(box[1], img_w - 1)
                gy0, gy1 = max(box[2], y0b), min(box[3], y1b - 1)
                if gy0 > gy1 or gx0 > gx1 or (et_on and _saturated(tile_sat, tile_npix, sat, gx0, gx1, gy0, gy1)):
                    continue
        for n in range(cstart[q], cstart[q + 1]):
            fi = n if direct else index[n]
            a = np.int64(src_a[n])
            b = np.int64(src_b[n])
            d = src_d[n]
            L = alpha_tab[d, gm[fi] if use_gm else 0]
            if L == 0.0 or (ncut > 0 and _cut_away(a, b, cuts, cs)):
                continue
            ok, px, py, s, box = _project(a, b, base, coef, persp, ex, ey, y0b, y1b, img_w)
            if not ok or (et_on and _saturated(tile_sat, tile_npix, sat, box[0], box[1], box[2], box[3])):
                continue
            alpha = _path_alpha(L, a, b, base, s, steps, persp, geo.inv_unit)
            cr, cg, cb = _shade(d, nrm[fi] if use_shade else 0, alpha, color, shade, use_shade)
            nd = _splat(px, py, s, box, cr, cg, cb, alpha, fpc, table, sheet, dirty_px, dirty, nd)
            # a voxel spanning two bands is counted by the band holding its first image row
            if max(int(math.ceil(py - ey * s)), 0) >= y0b:
                stats[1] += 1
    composite_sheet(buf.img, sheet, sat, tile_sat, dirty_px, dirty, nd, et)
    stats[2] += 1


@jit(inline="always")
def _cell_box(cell, n_a, n_b, base, coef, persp, ex, ey):
    """Stage 2: the pixel box ``(x0, x1, y0, y1)`` that the footprints of the cell's voxels can reach, from
    the cell's corners (the projection of a planar rectangle is the hull of its corners' projections) grown
    by the footprint's radius at the largest perspective scale; ``ok`` False when a corner is behind the near
    plane (then its voxels are tested one by one)."""
    xs, ys, ws = base[0], base[1], base[2]
    nca = (n_a + CELL - 1) // CELL
    qa0 = (cell % nca) * CELL
    qb0 = (cell // nca) * CELL
    qa1 = min(qa0 + CELL - 1, n_a - 1)
    qb1 = min(qb0 + CELL - 1, n_b - 1)
    cx0 = 1e300
    cx1 = -1e300
    cy0 = 1e300
    cy1 = -1e300
    smax = 1.0
    for corner in range(4):
        ka = qa0 if corner & 1 == 0 else qa1
        kb = qb0 if corner & 2 == 0 else qb1
        kx = xs + ka * coef[XA] + kb * coef[XB]
        ky = ys + ka * coef[YA] + kb * coef[YB]
        if persp:
            kd = ws + ka * coef[WA] + kb * coef[WB]
            if -kd < coef[NEAR]:
                return False, (0, 0, 0, 0)
            ks = coef[WPE] / kd
            smax = max(smax, ks) if corner > 0 else ks
            kx = coef[CX] + ks * kx
            ky = coef[CY] + ks * ky
        cx0 = min(cx0, kx)
        cx1 = max(cx1, kx)
        cy0 = min(cy0, ky)
        cy1 = max(cy1, ky)
    return True, (int(math.ceil(cx0 - ex * smax)), int(math.floor(cx1 + ex * smax)),
                  int(math.ceil(cy0 - ey * smax)), int(math.floor(cy1 + ey * smax)))


@leaf
def _saturated(tile_sat, tile_npix, sat, x0, x1, y0, y1):
    """True when every pixel of the box [x0, x1] x [y0, y1] has reached the early-termination opacity.

    Tiles whose pixels are all saturated answer at once; otherwise the byte mask (small, stays in cache) does.
    """
    whole = True
    for ty in range(y0 // TILE, y1 // TILE + 1):
        for tx in range(x0 // TILE, x1 // TILE + 1):
            if tile_sat[ty, tx] < tile_npix[ty, tx]:
                whole = False
                break
        if not whole:
            break
    if whole:
        return True
    for y in range(y0, y1 + 1):
        for x in range(x0, x1 + 1):
            if sat[y, x] == 0:
                return False
    return True


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
    rx = ex * s
    fx0 = math.ceil(px - rx)
    fx1 = math.floor(px + rx)
    fy0 = math.ceil(py - ry)
    fy1 = math.floor(py + ry)
    if fx1 < 0 or fy1 < y0b or fx0 > img_w - 1 or fy0 > y1b - 1:
        return False, px, py, s, none
    box = (max(int(fx0), 0), min(int(fx1), img_w - 1), max(int(fy0), y0b), min(int(fy1), y1b - 1))
    return box[2] <= box[3], px, py, s, box


@leaf
def _path_alpha(L, a, b, base, s, steps, persp, inv_unit):
    """Stage 3c: the voxel's opacity. Orthographic: ``L`` (already corrected for the path length).
    Perspective: corrected here for the path length through the slab along this voxel's ray."""
    if not persp:
        return L
    vx = base[3] + a * steps[0][0] + b * steps[1][0]
    vy = base[4] + a * steps[0][1] + b * steps[1][1]
    vz = base[5] + a * steps[0][2] + b * steps[1][2]
    dist = math.sqrt(vx * vx + vy * vy + vz * vz)
    # cosine between the ray and the slice normal, bounded (a ray ~75 degrees off the normal, which only
    # happens next to an eye inside the volume) so the path length stays finite
    cosang = max(base[6] / max(dist, 1e-300), 0.25)
    return -math.expm1(inv_unit / cosang * L)   # inv_unit = slice spacing / unit distance


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
    Qa, Qb2, Qc, R2v, tscale = fpc
    img_w = sheet.shape[1]
    inv_s2 = 1.0 / (s * s)
    for y in range(y0, y1 + 1):
        dy = y - py
        qy = Qc * dy * dy
        qxy = Qb2 * dy
        for x in range(x0, x1 + 1):
            dx = x - px
            q = (Qa * dx * dx + qxy * dx + qy) * inv_s2
            wgt = table[int(min(q, R2v) * tscale)]
            dirty[nd] = y * img_w + x
            nd += 1 - dirty_px[y, x]
            dirty_px[y, x] = 1
            sheet[y, x, 0] += wgt * cr
            sheet[y, x, 1] += wgt * cg
            sheet[y, x, 2] += wgt * cb
            sheet[y, x, 3] += wgt * alpha
    return nd
