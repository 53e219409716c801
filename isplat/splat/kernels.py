"""Compiled splatting kernels: arrays in, arrays out, no I/O.

One kernel renders all slices of one principal axis front to back into an image (§2.2). The indexed and
the full traversal differ only in which voxels reach the shared per-voxel routine ``_voxel``; within a slice
contributions are summed into a sheet buffer (order-independent), so both give the same image up to float
rounding, and the speed-up measures indexing alone.

Early termination: a voxel whose footprint covers only saturated pixels (opacity at the threshold) is
skipped before shading; 8x8 tiles whose pixels are all saturated answer that test at once. Each slice
composites exactly the pixels its splats touched (a per-pixel dirty list).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

TILE = 8
CELL = 4         # voxels per side of the cells a slice's voxels are grouped in for early termination

# coef layout (camera.Projection.coef)
X0, XA, XB, XC, Y0, YA, YB, YC, W0, WA, WB, WC, CX, CY, WPE, NEAR = range(16)
# footprint params
QA, QB, QC, EX, EY, R2, TSCALE = range(7)


@nb.njit(cache=True, nogil=True)
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


@nb.njit(cache=True, nogil=True)
def _composite(img, sheet, sat, tile_sat, dirty_px, dirty, nd, et):
    """Composite the slice's sheet over the image front to back (premultiplied 'over') at the pixels the
    slice touched, clear them, and count pixels that crossed the early-termination threshold."""
    w = img.shape[1]
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
        sheet[y, x, 0] = 0.0
        sheet[y, x, 1] = 0.0
        sheet[y, x, 2] = 0.0
        sheet[y, x, 3] = 0.0


@nb.njit(cache=True, nogil=True)
def shade_codes(normals, lights, ambient, diffuse, specular, shininess, two_sided, out):
    """Phong terms per normal code: ``out[c] = (diffuse r, g, b, specular r, g, b)``, or, when ``out`` has two
    columns (every light white), ``(diffuse, specular)``.

    ``lights`` rows: (L_i, L_j, L_k, H_i, H_j, H_k, r, g, b) in volume axes, L towards the light, H the
    half vector with the viewer, rgb the light's colour times intensity (r for a white light).
    """
    mono = out.shape[1] == 2
    for c in range(normals.shape[0]):
        nx = normals[c, 0]
        ny = normals[c, 1]
        nz = normals[c, 2]
        dr = ambient
        dg = ambient
        db = ambient
        sr = 0.0
        sg = 0.0
        sb = 0.0
        for li in range(lights.shape[0]):
            ndl = nx * lights[li, 0] + ny * lights[li, 1] + nz * lights[li, 2]
            ndh = nx * lights[li, 3] + ny * lights[li, 4] + nz * lights[li, 5]
            if two_sided:
                ndl = abs(ndl)
                ndh = abs(ndh)
            else:
                if ndl <= 0.0:
                    ndl = 0.0
                    ndh = 0.0
                ndh = max(ndh, 0.0)
            sp = specular * ndh ** shininess if ndh > 0.0 and specular != 0.0 else 0.0
            dr += diffuse * ndl * lights[li, 6]
            sr += sp * lights[li, 6]
            if not mono:
                dg += diffuse * ndl * lights[li, 7]
                db += diffuse * ndl * lights[li, 8]
                sg += sp * lights[li, 7]
                sb += sp * lights[li, 8]
        out[c, 0] = dr
        if mono:
            out[c, 1] = sr
        else:
            out[c, 1] = dg
            out[c, 2] = db
            out[c, 3] = sr
            out[c, 4] = sg
            out[c, 5] = sb


@nb.njit(cache=True, nogil=True)
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


@nb.njit(cache=True, nogil=True)
def render_axis(order, full, sel_cell_ptr, sel_cell_start, sel_cell_id, sel_a, sel_b, sel_d,
                dens, gm, use_gm, nrm, use_shade, strides, n_a, n_b,
                alpha_tab, color_lut, shade_lut, persp, inv_unit, slice_normal_offset, slice_step,
                coef, steps, qe, cuts, fp_table, fp,
                img, sheet, sat, tile_sat, tile_npix, dirty_px, dirty, et, stats, band_y0, band_y1):
    """Render the slices ``order`` (front to back) of one axis into ``img`` (H, W, 4 premultiplied RGBA).

    ``full``: visit every voxel of each slice (density from ``dens``; ``gm`` and ``nrm`` are whole channels
    indexed by flat position). Otherwise visit only the voxels the index selected (:func:`select_voxels`),
    grouped in cells of CELL x CELL voxels of the slice: slice ``c`` holds the cells
    ``sel_cell_ptr[c]:sel_cell_ptr[c+1]``, cell ``q`` the voxels ``sel_*[sel_cell_start[q]:sel_cell_start[q+1]]``,
    with ``gm`` and ``nrm`` gathered per selected voxel in the same order.
    A cell whose voxels' footprints can only touch saturated pixels (or none of this band's) is skipped whole,
    before its voxels are projected: early termination at the cost of one test per cell.
    ``strides``: flat-index strides of a, b, c in the [k, j, i] channels; ``cuts`` rows: (g0, ga, gb, gc)
    with a voxel kept where ``g0 + a*ga + b*gb + c*gc >= 0``.
    Counters in ``stats``: [voxels examined, voxels splatted, slices done].

    Only image rows ``band_y0 <= y < band_y1`` (multiples of TILE) are written, so threads rendering
    disjoint bands share ``img``, ``sheet`` and the tile maps without races, and each band stops on its
    own when all its tiles are saturated.
    """
    et_on = et < 1.0
    ncut = cuts.shape[0]
    mono = shade_lut.shape[1] == 2
    cs = np.empty(max(ncut, 1), dtype=np.float64)
    sa_ = strides[0]
    sb_ = strides[1]
    sc_ = strides[2]
    m = n_a * n_b if full else 1
    nca = (n_a + CELL - 1) // CELL
    ncb = (n_b + CELL - 1) // CELL
    fcell_start = np.empty(nca * ncb + 1 if full else 1, dtype=np.int64)
    fcell_id = np.empty(nca * ncb if full else 1, dtype=np.int32)
    cand_ai = np.empty(m, dtype=np.int64)
    cand_a = np.empty(m, dtype=np.uint16)
    cand_b = np.empty(m, dtype=np.uint16)
    cand_d = np.empty(m, dtype=np.uint8)
    img_h = img.shape[0]
    img_w = img.shape[1]
    Qa = fp[QA]
    Qb2 = 2.0 * fp[QB]
    Qc = fp[QC]
    R2v = fp[R2]
    tscale = fp[TSCALE]
    ex = fp[EX]
    ey = fp[EY]
    bty0 = band_y0 // TILE
    bty1 = (band_y1 + TILE - 1) // TILE
    total_tiles = (bty1 - bty0) * tile_npix.shape[1]
    for oi in range(order.shape[0]):
        c = order[oi]
        # per slice: the paper's incremental bases (§3.1: two additions per slice)
        xs = coef[X0] + c * coef[XC]
        ys = coef[Y0] + c * coef[YC]
        ws = coef[W0] + c * coef[WC]
        pb0 = qe[0] + c * steps[2, 0]
        pb1 = qe[1] + c * steps[2, 1]
        pb2 = qe[2] + c * steps[2, 2]
        hc = abs(slice_normal_offset + c * slice_step)
        for ci in range(ncut):
            cs[ci] = cuts[ci, 0] + c * cuts[ci, 3]
        cbase = c * sc_
        # 1. traversal: which voxels of this slice reach the shared pipeline (the only difference
        #    between the full and the indexed method); transparent ones are dropped by one look-up
        ncand = 0
        if full:
            # every voxel, cell by cell (the same grouping the index's selection has)
            nq = 0
            for qb in range(ncb):
                for qa in range(nca):
                    first = ncand
                    for b in range(qb * CELL, min(n_b, qb * CELL + CELL)):
                        for a in range(qa * CELL, min(n_a, qa * CELL + CELL)):
                            fi = cbase + a * sa_ + b * sb_
                            d = dens[fi]
                            if alpha_tab[d, gm[fi] if use_gm else 0] != 0.0:
                                cand_ai[ncand] = fi
                                cand_a[ncand] = a
                                cand_b[ncand] = b
                                cand_d[ncand] = d
                                ncand += 1
                    if ncand > first:
                        fcell_start[nq] = first
                        fcell_id[nq] = qb * nca + qa
                        nq += 1
            fcell_start[nq] = ncand
            stats[0] += n_a * n_b
            q0 = 0
            q1 = nq
            cstart = fcell_start
            cid = fcell_id
            src_a = cand_a
            src_b = cand_b
            src_d = cand_d
        else:
            # the voxels the index selected for this slice (select_voxels), cell by cell
            q0 = sel_cell_ptr[c]
            q1 = sel_cell_ptr[c + 1]
            stats[0] += sel_cell_start[q1] - sel_cell_start[q0]
            cstart = sel_cell_start
            cid = sel_cell_id
            src_a = sel_a
            src_b = sel_b
            src_d = sel_d
        # 2. the shared per-voxel pipeline: classify, shade, project (§3), splat into the sheet
        nd = 0
        for q in range(q0, q1):
            if et_on or band_y0 > 0 or band_y1 < img_h:
                # the cell's footprint box: from its corners (the projection of a planar rectangle
                # is the hull of its corners' projections), grown by the footprint's radius
                qa0 = (cid[q] % nca) * CELL
                qb0 = (cid[q] // nca) * CELL
                qa1 = min(qa0 + CELL - 1, n_a - 1)
                qb1 = min(qb0 + CELL - 1, n_b - 1)
                cx0 = 1e300
                cx1 = -1e300
                cy0 = 1e300
                cy1 = -1e300
                smax = 1.0
                behind = False
                for corner in range(4):
                    ka = qa0 if corner & 1 == 0 else qa1
                    kb = qb0 if corner & 2 == 0 else qb1
                    kx = xs + ka * coef[XA] + kb * coef[XB]
                    ky = ys + ka * coef[YA] + kb * coef[YB]
                    if persp:
                        kd = ws + ka * coef[WA] + kb * coef[WB]
                        if -kd < coef[NEAR]:
                            behind = True
                            break
                        ks = coef[WPE] / kd
                        smax = max(smax, ks) if corner > 0 else ks
                        kx = coef[CX] + ks * kx
                        ky = coef[CY] + ks * ky
                    cx0 = min(cx0, kx)
                    cx1 = max(cx1, kx)
                    cy0 = min(cy0, ky)
                    cy1 = max(cy1, ky)
                if not behind:
                    gy0 = max(int(math.ceil(cy0 - ey * smax)), band_y0)
                    gy1 = min(int(math.floor(cy1 + ey * smax)), band_y1 - 1)
                    gx0 = max(int(math.ceil(cx0 - ex * smax)), 0)
                    gx1 = min(int(math.floor(cx1 + ex * smax)), img_w - 1)
                    if gy0 > gy1 or gx0 > gx1:
                        continue                    # no footprint of this cell reaches this band
                    if et_on and _saturated(tile_sat, tile_npix, sat, gx0, gx1, gy0, gy1):
                        continue                    # every pixel it could touch is saturated
            for n in range(cstart[q], cstart[q + 1]):
                a = np.int64(src_a[n])
                b = np.int64(src_b[n])
                d = src_d[n]
                # where this voxel's gradient magnitude and normal are: flat position in whole channels
                # (full), or its place in the per-voxel values gathered for the index (indexed)
                fi = cand_ai[n] if full else n
                g = 0
                if use_gm:
                    g = gm[fi]
                L = alpha_tab[d, g]
                if L == 0.0:
                    continue
                kept = True
                for ci in range(ncut):
                    if cs[ci] + a * cuts[ci, 1] + b * cuts[ci, 2] < 0.0:
                        kept = False
                        break
                if not kept:
                    continue
                # §3: projection with per-slice bases, two multiply-adds per coordinate; y first, so a voxel
                # outside this thread's band of rows costs no more
                Y = ys + a * coef[YA] + b * coef[YB]
                s = 1.0
                if persp:
                    D = ws + a * coef[WA] + b * coef[WB]
                    if -D < coef[NEAR]:
                        continue                       # at or behind the near plane: culled
                    s = coef[WPE] / D                   # t0 of §3.2
                    py = coef[CY] + s * Y
                else:
                    py = Y
                ry = ey * s
                if py + ry < band_y0 or py - ry > band_y1 - 1:
                    continue
                X = xs + a * coef[XA] + b * coef[XB]
                px = coef[CX] + s * X if persp else X
                rx = ex * s
                fx0 = math.ceil(px - rx)
                fx1 = math.floor(px + rx)
                fy0 = math.ceil(py - ry)
                fy1 = math.floor(py + ry)
                if fx1 < 0 or fy1 < band_y0 or fx0 > img_w - 1 or fy0 > band_y1 - 1:
                    continue
                x0 = max(int(fx0), 0)
                x1 = min(int(fx1), img_w - 1)
                y0 = max(int(fy0), band_y0)
                y1 = min(int(fy1), band_y1 - 1)
                if y0 > y1:
                    continue
                # skip the voxel when every pixel under its footprint is saturated: exact (such pixels take
                # no more contribution) and much cheaper than shading and splatting it
                if et_on and _saturated(tile_sat, tile_npix, sat, x0, x1, y0, y1):
                    continue
                if persp:
                    # path length through the slab along this voxel's ray, in unit distances
                    vx = pb0 + a * steps[0, 0] + b * steps[1, 0]
                    vy = pb1 + a * steps[0, 1] + b * steps[1, 1]
                    vz = pb2 + a * steps[0, 2] + b * steps[1, 2]
                    dist = math.sqrt(vx * vx + vy * vy + vz * vz)
                    # cosine between the ray and the slice normal, bounded (a ray ~75 degrees off the normal, which
                    # only happens next to an eye inside the volume) so the path length stays finite
                    cosang = max(hc / max(dist, 1e-300), 0.25)
                    alpha = -math.expm1(inv_unit / cosang * L)   # inv_unit = slice spacing / unit distance
                else:
                    alpha = L
                cr = color_lut[d, 0]
                cg = color_lut[d, 1]
                cb = color_lut[d, 2]
                if use_shade:
                    code = nrm[fi]
                    if mono:
                        # white lights: one diffuse and one specular factor per code (a smaller table,
                        # which matters: it is read at random codes)
                        dif = shade_lut[code, 0]
                        spe = shade_lut[code, 1]
                        cr = cr * dif + spe
                        cg = cg * dif + spe
                        cb = cb * dif + spe
                    else:
                        cr = cr * shade_lut[code, 0] + shade_lut[code, 3]
                        cg = cg * shade_lut[code, 1] + shade_lut[code, 4]
                        cb = cb * shade_lut[code, 2] + shade_lut[code, 5]
                cr *= alpha
                cg *= alpha
                cb *= alpha
                inv_s2 = 1.0 / (s * s)
                for y in range(y0, y1 + 1):
                    dy = y - py
                    qy = Qc * dy * dy
                    qxy = Qb2 * dy
                    for x in range(x0, x1 + 1):
                        dx = x - px
                        q = (Qa * dx * dx + qxy * dx + qy) * inv_s2
                        # Branch-free on purpose: the indexed traversal feeds voxels density by density, in
                        # no spatial order, and a per-pixel branch here mispredicts (it cost 25% on the
                        # semi-transparent engine). q at or past the cut-off reads the table's trailing zero;
                        # the dirty list always stores the pixel and advances only on its first touch.
                        wgt = fp_table[int(min(q, R2v) * tscale)]
                        dirty[nd] = y * img_w + x
                        nd += 1 - dirty_px[y, x]
                        dirty_px[y, x] = 1
                        sheet[y, x, 0] += wgt * cr
                        sheet[y, x, 1] += wgt * cg
                        sheet[y, x, 2] += wgt * cb
                        sheet[y, x, 3] += wgt * alpha
                # a voxel spanning two bands is counted by the band holding its first image row
                if max(int(fy0), 0) >= band_y0:
                    stats[1] += 1
        _composite(img, sheet, sat, tile_sat, dirty_px, dirty, nd, et)
        stats[2] += 1
        if et_on:
            done = 0
            for ty in range(bty0, bty1):
                for tx in range(tile_npix.shape[1]):
                    if tile_sat[ty, tx] >= tile_npix[ty, tx]:
                        done += 1
            if done == total_tiles:
                break


@nb.njit(cache=True, nogil=True)
def flat_indices(slice_block_ptr, block_voxel_ptr, positions, n_a, strides):
    """Flat [k, j, i] index of every voxel of a loaded axis (in the order of ``positions``)."""
    out = np.empty(positions.shape[0], dtype=np.int64)
    for c in range(slice_block_ptr.shape[0] - 1):
        base = c * strides[2]
        for r in range(slice_block_ptr[c], slice_block_ptr[c + 1]):
            for vi in range(block_voxel_ptr[r], block_voxel_ptr[r + 1]):
                ind = positions[vi]
                b = ind // n_a
                out[vi] = base + (ind - b * n_a) * strides[0] + b * strides[1]
    return out


@nb.njit(cache=True, nogil=True)
def select_voxels(slice_block_ptr, block_density, block_voxel_ptr, positions, intervals, n_a, n_b):
    """The voxels of each slice whose density lies in ``intervals`` (§2.2), as in-slice coordinates,
    grouped in cells of CELL x CELL voxels of the slice.

    Per slice, the densities present are sorted (Figure 1), so a binary search finds the first block of each
    interval and the blocks up to its upper bound are decoded into (a, b). This runs once per load (the
    selection depends on the transfer function, not on the view); every frame then streams the result, and
    the cells let early termination skip a hidden cell with one test.
    Returns ``(cell_ptr int64[S+1], cell_start int64[Q+1], cell_id int32[Q], a uint16[N], b uint16[N],
    density uint8[N], source int64[N])``: slice ``c`` holds cells ``cell_ptr[c]:cell_ptr[c+1]``, cell ``q``
    (``cell_id = (b // CELL) * ceil(n_a / CELL) + a // CELL``) the voxels ``cell_start[q]:cell_start[q+1]``;
    ``source`` is each voxel's index in ``positions``.
    """
    n_slices = slice_block_ptr.shape[0] - 1
    nca = (n_a + CELL - 1) // CELL
    ncells = nca * ((n_b + CELL - 1) // CELL)
    total = 0
    for c in range(n_slices):
        in_slice = 0
        for iv in range(intervals.shape[0]):
            r = _first_block(block_density, slice_block_ptr[c], slice_block_ptr[c + 1], intervals[iv, 0])
            while r < slice_block_ptr[c + 1] and block_density[r] <= intervals[iv, 1]:
                in_slice += block_voxel_ptr[r + 1] - block_voxel_ptr[r]
                r += 1
        # each position holds one density: more voxels than positions means a corrupt index (and would
        # overrun the per-slice buffers below)
        if in_slice > n_a * n_b:
            raise ValueError("a slice of the index lists more voxels than it has positions")
        total += in_slice
    sa = np.empty(total, dtype=np.uint16)
    sb = np.empty(total, dtype=np.uint16)
    sd = np.empty(total, dtype=np.uint8)
    src = np.empty(total, dtype=np.int64)
    # one slice's voxels before they are grouped by cell
    ta = np.empty(n_a * n_b, dtype=np.uint16)
    tb = np.empty(n_a * n_b, dtype=np.uint16)
    td = np.empty(n_a * n_b, dtype=np.uint8)
    tsrc = np.empty(n_a * n_b, dtype=np.int64)
    count = np.zeros(ncells + 1, dtype=np.int64)
    cell_ptr = np.zeros(n_slices + 1, dtype=np.int64)
    cell_start_l = np.empty(min(total, n_slices * ncells) + 1, dtype=np.int64)
    cell_id_l = np.empty(min(total, n_slices * ncells), dtype=np.int32)
    n = 0
    nq = 0
    for c in range(n_slices):
        r1 = slice_block_ptr[c + 1]
        m = 0
        for iv in range(intervals.shape[0]):
            r = _first_block(block_density, slice_block_ptr[c], r1, intervals[iv, 0])
            while r < r1 and block_density[r] <= intervals[iv, 1]:
                d = block_density[r]
                v0 = block_voxel_ptr[r]
                v1 = block_voxel_ptr[r + 1]
                # positions increase within a block: follow the row instead of dividing per voxel
                b = positions[v0] // n_a if v1 > v0 else 0
                row0 = b * n_a
                for vi in range(v0, v1):
                    ind = positions[vi]
                    while ind >= row0 + n_a:
                        row0 += n_a
                        b += 1
                    ta[m] = ind - row0
                    tb[m] = b
                    td[m] = d
                    tsrc[m] = vi
                    m += 1
                r += 1
        # group by cell: a counting sort, stable, so each cell keeps the blocks' density order
        for q in range(ncells + 1):
            count[q] = 0
        for t in range(m):
            count[(tb[t] // CELL) * nca + ta[t] // CELL + 1] += 1
        for q in range(ncells):
            if count[q + 1] > 0:
                cell_start_l[nq] = n + count[q]
                cell_id_l[nq] = q
                nq += 1
            count[q + 1] += count[q]
        for t in range(m):
            q = (tb[t] // CELL) * nca + ta[t] // CELL
            k = n + count[q]
            count[q] += 1
            sa[k] = ta[t]
            sb[k] = tb[t]
            sd[k] = td[t]
            src[k] = tsrc[t]
        n += m
        cell_ptr[c + 1] = nq
    cell_start_l[nq] = n
    return cell_ptr, cell_start_l[:nq + 1].copy(), cell_id_l[:nq].copy(), sa, sb, sd, src


@nb.njit(cache=True, nogil=True)
def _first_block(block_density, r0, r1, lo):
    """§2.2: binary search for the first block in rows r0:r1 with density >= lo."""
    while r0 < r1:
        m = (r0 + r1) >> 1
        if block_density[m] < lo:
            r0 = m + 1
        else:
            r1 = m
    return r0
