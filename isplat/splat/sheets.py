"""Image-aligned sheet-buffered splatting (Mueller and Crawfis 1998): no popping at the principal-axis switch.

Axis-aligned sheets (:mod:`isplat.splat.pre`) sum each slice of the principal axis into a sheet, so the
sheets jump when the slice axis does. Here the sheets are slabs of constant depth along the view direction,
``thick`` world units each, and every voxel adds to each slab its kernel overlaps the kernel's integral over
that slab; slabs are composited front to back with the same premultiplied 'over' and early termination as
the axis-aligned sheets (:func:`isplat.splat.composite.composite_sheet`). Nothing depends on the slice axis
but the order voxels are read in, so the image changes continuously with the view.

The kernel. isplat's reconstruction kernel is a Gaussian of ``sigma`` grid steps in grid space. In the
coordinates (x, y) pixels and z depth (world units along the view direction) a grid step along a, b, c moves
by the columns of ``J3`` (3 x 3), so the kernel is a 3-D Gaussian of covariance ``M = sigma^2 J3 J3^T``.
Its marginal on the image is the usual footprint (:mod:`isplat.splat.footprint`, widened to at least
MIN_SIGMA_PIXELS and cut at ``footprint_radius``); given the pixel offset ``d``, depth is Gaussian with mean
``z_v + g.d`` and standard deviation ``s_c`` (``g = M_zxy M_xy^-1``, ``s_c^2 = M_zz - g M_xyz``). So a voxel's
weight in slab ``[z0, z0 + thick)`` at pixel offset ``d`` is

    footprint(d) * (F((z0 + thick - z_v - g.d) / s_c) - F((z0 - z_v - g.d) / s_c))

with ``F`` the normal CDF cut at +-``footprint_radius`` and rescaled to 0..1, so the slabs of one voxel sum
to exactly its footprint. With isotropic spacing ``g = 0`` and the depth factor is one number per voxel and
slab; anisotropic spacing (thick slices) gives the slab boundary inside the ellipsoid its true tilt.
Weights are normalised so that a uniform volume gives each slab the opacity of ``thick`` world units: the
footprint table is scaled by ``V / (thick A_cell)`` (``V = |det J3|`` the voxel's volume in pixel-pixel-depth
units, ``A_cell`` the projected slice cell the footprint table is normalised to). Opacities are corrected
for a path of ``thick`` world units (orthographic); in perspective for ``thick / cos`` of the voxel's ray to
the view direction, bounded at about 75 degrees like the axis-aligned sheets.

Perspective: the slabs are planes of constant depth; the footprint and the depth profile use the kernel's
projection along the central ray scaled by the voxel's ``t0`` (the same approximation as the axis-aligned
footprint), not the per-voxel perspective Jacobian.

The traversal: the selected voxels are bucketed once per frame by the first slab their kernel reaches
(:func:`bucket_indexed`, :func:`bucket_full`: a counting sort, O(N)); slab ``k`` then reads the buckets
``k - span .. k`` and keeps the voxels whose kernel reaches it. A voxel is projected, classified and shaded
again in each slab it reaches (a few table reads) rather than held in a per-frame list.

Slab thickness: the smallest spacing, or more when a kernel would otherwise reach more than
MAX_SLABS_PER_KERNEL slabs (a spacing far below the others, e.g. 1 x 1 x 100).

A technique of :mod:`isplat.splat.traverse`, which walks the bands and, in each, the slabs front to back
until the band saturates (its saturation tests too): this module is its per-frame plan (:data:`SheetsPlan`,
:func:`plan`) and its per-slab stage (:func:`_slab`). ``_shade``, ``_splat``, the sheet
(:data:`isplat.splat.pre.Sheet`) and the projection's tail are the pre-classified technique's
(:mod:`isplat.splat.pre`); the projection with the slice's terms per voxel (:func:`_slab_project`) and the
opacity for a slab (:func:`_slab_alpha`) are this module's own.
"""

from __future__ import annotations

import math
from collections import namedtuple
from functools import lru_cache

import numpy as np

from ..jit import jit, leaf, stage
from .composite import composite_sheet
from .pre import Classify, FootprintTable, _shade, _splat, add_to_sheet, footprint_at, sheet_buffers
from .select import CELL, cell_origins
from .traverse import (CY, EX, EY, NEAR, QA, QB, QC, R2, TSCALE, WPE, X0, XA, XB, XC, Y0, YA, YB, YC, build_sat,
                       covered, register)
# a kernel reaching more slabs than this gets thicker slabs (a spacing far below the others)
MAX_SLABS_PER_KERNEL = 48

SheetVoxels = namedtuple("SheetVoxels", "slab_ptr a b c row d gm nrm culled")
SheetVoxels.__doc__ = """The frame's voxels bucketed by first slab: bucket ``k`` holds rows
``slab_ptr[k]:slab_ptr[k+1]`` of ``a, b, c`` (slice coordinates), ``row`` (where the voxel's ``gm``/``nrm``
values are) and ``d`` (density); ``culled``: voxels examined but dropped when bucketing (transparent, cut
away, behind the near plane)."""
SheetGeometry = namedtuple("SheetGeometry", "coef zc qe steps persp inv_unit cuts z_lo thick span cond cdf")
SheetGeometry.__doc__ = """``coef`` 16 floats (camera.Projection.coef); ``zc`` (Z0, ZA, ZB, ZC): depth along
the view direction ``Z0 + a ZA + b ZB + c ZC`` (world units; in perspective the distance in front of the
eye); ``qe`` volume origin minus eye and ``steps`` the world steps along a, b, c (9 floats, perspective);
``inv_unit`` slab thickness / unit distance; ``cuts`` rows (g0, ga, gb,
gc); ``z_lo`` depth of slab 0's front; ``thick`` slab thickness; ``span``: a voxel of first slab ``f`` reaches
no slab after ``f + span``; ``cond`` (gx, gy, s_c, ext, flat): depth given the pixel offset (module
docstring), ``ext`` the kernel's reach in depth, ``flat`` True when ``g`` is negligible; ``cdf``: the cut
normal CDF ``F`` tabulated (:func:`cdf_table`)."""
# entries of the tabulated depth CDF; linear interpolation keeps its error below 1e-7
CDF_TABLE = 4096


# ---- bucketing ---------------------------------------------------------------------------------------------
@leaf
def _first_slab(z, geo, n_slabs):
    """First slab a kernel centred at depth ``z`` reaches (clipped to 0..n_slabs-1)."""
    f = int(math.floor((z - geo.cond[3] - geo.z_lo) / geo.thick))
    return min(max(f, 0), n_slabs - 1)


@leaf
def _keep(a, b, c, L, geo):
    """Depth of a voxel, or -inf when it is transparent, cut away or (perspective) in front of the near
    plane."""
    if L == 0.0:
        return -math.inf
    cuts = geo.cuts
    for ci in range(cuts.shape[0]):
        if cuts[ci, 0] + a * cuts[ci, 1] + b * cuts[ci, 2] + c * cuts[ci, 3] < 0.0:
            return -math.inf
    zc = geo.zc
    z = zc[0] + a * zc[1] + b * zc[2] + c * zc[3]
    if geo.persp and z < geo.coef[NEAR]:
        return -math.inf
    return z


@stage
def _place(first, n_slabs, src_a, src_b, src_c, src_row, src_d, nkeep):
    """Counting sort of the kept voxels (``first`` >= 0) by first slab into a SheetVoxels' arrays."""
    counts = np.zeros(n_slabs + 1, dtype=np.int64)
    for n in range(first.shape[0]):
        if first[n] >= 0:
            counts[first[n] + 1] += 1
    for k in range(n_slabs):
        counts[k + 1] += counts[k]
    ptr = counts.copy()
    a = np.empty(nkeep, dtype=np.uint16)
    b = np.empty(nkeep, dtype=np.uint16)
    c = np.empty(nkeep, dtype=np.int32)
    row = np.empty(nkeep, dtype=np.int64)
    d = np.empty(nkeep, dtype=np.uint8)
    for n in range(first.shape[0]):
        f = first[n]
        if f >= 0:
            p = counts[f]
            counts[f] += 1
            a[p] = src_a[n]
            b[p] = src_b[n]
            c[p] = src_c[n]
            row[p] = src_row[n]
            d[p] = src_d[n]
    return ptr, a, b, c, row, d


@jit
def bucket_indexed(vox, alpha, use_gm, geo, n_slabs):
    """Bucket the voxels of one axis of a selection (traverse.IndexedVoxels: slices, regions, blocks, cells,
    voxels) by first slab; returns (slab_ptr, a, b, c, row, d, culled) with ``row`` the voxel's row in the
    selection. The hierarchy is walked by :func:`isplat.splat.select.cell_origins` (per cell, not per voxel;
    it also checks the cell table)."""
    n = vox.offset.shape[0]
    first = np.full(n, -1, dtype=np.int32)
    ca = np.empty(n, dtype=np.uint16)
    cb = np.empty(n, dtype=np.uint16)
    cc = np.empty(n, dtype=np.int32)
    c_of, a_of, b_of, v_of = cell_origins(vox.slice_ptr, vox.region_id, vox.region_ptr, vox.block_pos, vox.block_ptr,
                                          vox.block_voxel, vox.cell_pos, vox.cell_count, vox.n_a)
    nkeep = 0
    for q in range(c_of.shape[0]):
        v, c = v_of[q], c_of[q]
        for _ in range(vox.cell_count[q]):
            a = a_of[q] + vox.offset[v] % CELL
            b = b_of[q] + vox.offset[v] // CELL
            ca[v], cb[v], cc[v] = a, b, c
            d = vox.density[v]
            z = _keep(a, b, c, alpha[d, vox.gm[v] if use_gm else 0], geo)
            if z > -math.inf:
                first[v] = _first_slab(z, geo, n_slabs)
                nkeep += 1
            v += 1
    ptr, sa, sb, sc, srow, sd = _place(first, n_slabs, ca, cb, cc, np.arange(n), vox.density, nkeep)
    return ptr, sa, sb, sc, srow, sd, n - nkeep


@jit
def bucket_full(density, gm, strides, n_a, n_b, n_c, alpha, use_gm, geo, n_slabs):
    """Bucket every voxel of whole channels (flat ``[k, j, i]``, traverse.WholeVolume) by first slab; returns
    (slab_ptr, a, b, c, row, d, culled) with ``row`` the flat index. Two passes over the volume (count, then
    place), so nothing per voxel of the whole volume is held."""
    counts = np.zeros(n_slabs + 1, dtype=np.int64)
    for rep in range(2):
        if rep == 1:
            for k in range(n_slabs):
                counts[k + 1] += counts[k]
            ptr = counts.copy()
            nkeep = counts[n_slabs]
            sa = np.empty(nkeep, dtype=np.uint16)
            sb = np.empty(nkeep, dtype=np.uint16)
            sc = np.empty(nkeep, dtype=np.int32)
            srow = np.empty(nkeep, dtype=np.int64)
            sd = np.empty(nkeep, dtype=np.uint8)
        for c in range(n_c):
            for b in range(n_b):
                for a in range(n_a):
                    fi = c * strides[2] + a * strides[0] + b * strides[1]
                    d = density[fi]
                    z = _keep(a, b, c, alpha[d, gm[fi] if use_gm else 0], geo)
                    if z > -math.inf:
                        f = _first_slab(z, geo, n_slabs)
                        if rep == 0:
                            counts[f + 1] += 1
                        else:
                            p = counts[f]
                            counts[f] += 1
                            sa[p], sb[p], sc[p], srow[p], sd[p] = a, b, c, fi, d
    return ptr, sa, sb, sc, srow, sd, n_a * n_b * n_c - nkeep


# ---- the frame kernel --------------------------------------------------------------------------------------
SheetsPlan = namedtuple("SheetsPlan", "vox cls geo fp sheet")
SheetsPlan.__doc__ = """An image-aligned frame's tables: ``vox`` the voxels bucketed by first slab
(:data:`SheetVoxels`), ``cls`` :data:`isplat.splat.pre.Classify` (opacities for a slab's thickness),
``geo`` :data:`SheetGeometry`, ``fp`` the footprint (:data:`isplat.splat.pre.FootprintTable`, its table scaled
for the slab), ``sheet`` the slab's buffer (:data:`isplat.splat.pre.Sheet`). A thread's scratch is its list of
the pixels a slab touched (int64)."""


@stage
def _scratch(plan):
    """Nothing: the slabs read the buckets, made once per frame (:func:`bucket_indexed`, :func:`bucket_full`)."""
    return None


@stage
def _slab(plan, dirty, scratch, k, pos, buf, band):
    """Slab ``k`` for one band: the voxels of the buckets ``k - span .. k`` whose kernels reach it splatted
    into the sheet (:func:`_splat_bucket`), then the sheet composited into the image; counters into
    ``buf.stats[band]`` (voxels examined, voxel visits past the depth test, voxels splatted, slabs)."""
    vox, geo, fp = plan.vox, plan.geo, plan.fp
    bi, et, satab, ty0 = band[0], band[3], band[4], band[5]
    stats = buf.stats[bi]
    rcut = math.sqrt(fp.params[R2])
    # t (standard deviations) -> table position: (t + rcut) * depth[1]; depth[0] = 1 / geo.cond[2]
    depth = (1.0 / geo.cond[2], (geo.cdf.shape[0] - 2) / (2.0 * rcut), rcut)
    fpc = (fp.params[QA], 2.0 * fp.params[QB], fp.params[QC], fp.params[R2], fp.params[TSCALE])
    if k == 0:
        stats[0] += vox.culled
    stats[0] += vox.slab_ptr[k + 1] - vox.slab_ptr[k]
    z0 = geo.z_lo + k * geo.thick
    nd = 0
    for kk in range(max(k - geo.span, 0), k + 1):
        nd = _splat_bucket(kk, kk == k, z0, vox, plan.cls, geo, fp, fpc, depth, plan.sheet, dirty, nd, buf, band)
    if composite_sheet(buf.img, plan.sheet.sheet, buf.sat, buf.tile_sat, plan.sheet.dirty_px, dirty, nd, et) > 0:
        build_sat(buf.tile_sat, buf.tile_npix, ty0, satab)
    stats[3] += 1


@leaf
def _splat_bucket(kk, first, z0, vox, cls, geo, fp, fpc, depth, sheet_buf, dirty, nd, buf, band):
    """The voxels of bucket ``kk`` whose kernels reach the slab from depth ``z0``, projected, classified, shaded
    and splatted into the sheet (``first``: the slab is the bucket's own, where a voxel is counted); returns
    the sheet's touched-pixel count."""
    alpha_tab, color, shade, use_gm, use_shade = cls
    sheet, dirty_px = sheet_buf
    bi, y0b, y1b, et, satab, ty0 = band
    stats = buf.stats[bi]
    et_on = et < 1.0
    img_w = sheet.shape[1]
    ex, ey = fp.params[EX], fp.params[EY]
    coef, zc, persp, thick = geo.coef, geo.zc, geo.persp, geo.thick
    gx, gy, s_c, ext, flat = geo.cond
    for n in range(vox.slab_ptr[kk], vox.slab_ptr[kk + 1]):
        a = np.int64(vox.a[n])
        b = np.int64(vox.b[n])
        c = np.int64(vox.c[n])
        z = zc[0] + a * zc[1] + b * zc[2] + c * zc[3]
        if z + ext <= z0:
            continue            # the kernel ended in front of this slab
        stats[1] += 1
        ok, px, py, s, box = _slab_project(a, b, c, z, coef, persp, ex, ey, y0b, y1b, img_w)
        if not ok or (et_on and covered(satab, ty0, buf.sat, box[0], box[1], box[2], box[3])):
            continue
        row = vox.row[n]
        d = vox.d[n]
        L = alpha_tab[d, vox.gm[row] if use_gm else 0]
        alpha = _slab_alpha(L, a, b, c, z, geo)
        cr, cg, cb = _shade(d, vox.nrm[row] if use_shade else 0, alpha, color, shade, use_shade)
        zrel = z - z0
        if flat:
            f = _slab_mass(zrel, thick, depth, geo.cdf)
            nd = _splat(px, py, s, box, cr * f, cg * f, cb * f, alpha * f, fpc, fp.table, sheet, dirty_px, dirty, nd)
        else:
            nd = _splat_tilted(px, py, s, box, cr, cg, cb, alpha, fpc, fp.table, (zrel, thick, gx, gy), depth,
                               geo.cdf, sheet, dirty_px, dirty, nd)
        # counted once: in its first slab, by the band holding its first image row
        if first and max(int(math.ceil(py - ey * s)), 0) >= y0b:
            stats[2] += 1
    return nd


@leaf
def _slab_project(a, b, c, z, coef, persp, ex, ey, y0b, y1b, img_w):
    """The voxel's pixel position, perspective scale and footprint box clipped to the image and the band
    (:func:`isplat.splat.pre._project` with the slice's terms per voxel; ``z`` the depth, in perspective -D)."""
    none = (0, 0, 0, 0)
    Y = coef[Y0] + c * coef[YC] + a * coef[YA] + b * coef[YB]
    s = 1.0
    if persp:
        s = -coef[WPE] / z                       # t0 of §3.2 (D = -z)
    py = coef[CY] + s * Y if persp else Y
    ry = ey * s
    if py + ry < y0b or py - ry > y1b - 1:
        return False, 0.0, py, s, none
    return footprint_at(coef[X0] + c * coef[XC] + a * coef[XA] + b * coef[XB], py, s, ry, coef, persp, ex, y0b, y1b,
                        img_w)


@leaf
def _slab_alpha(L, a, b, c, z, geo):
    """The voxel's opacity for one slab: ``L`` (orthographic, corrected already) or, in perspective,
    ``-expm1(thick / cos / unit * L)`` with ``cos`` between the voxel's ray and the view direction."""
    if not geo.persp:
        return L
    qe = geo.qe
    steps = geo.steps
    vx = qe[0] + a * steps[0] + b * steps[3] + c * steps[6]
    vy = qe[1] + a * steps[1] + b * steps[4] + c * steps[7]
    vz = qe[2] + a * steps[2] + b * steps[5] + c * steps[8]
    dist = math.sqrt(vx * vx + vy * vy + vz * vz)
    cosang = max(z / max(dist, 1e-300), 0.25)
    return -math.expm1(geo.inv_unit / cosang * L)


@lru_cache(maxsize=8)
def cdf_table(radius: float, n: int = CDF_TABLE) -> np.ndarray:
    """The normal CDF cut at +-``radius`` standard deviations and rescaled to 0..1, at ``n + 1`` equally
    spaced points of [-radius, radius], plus a trailing 1 (read when t is at the top end)."""
    t = np.linspace(-radius, radius, n + 1)
    e = np.array([math.erf(x / math.sqrt(2.0)) for x in t])
    er = math.erf(radius / math.sqrt(2.0))
    out = np.append((e + er) / (2.0 * er), 1.0)
    out.flags.writeable = False
    return out


@leaf
def _cdf(t, depth, cdf):
    """The cut normal CDF at ``t`` standard deviations, linearly interpolated in the table ``cdf``."""
    x = (min(max(t, -depth[2]), depth[2]) + depth[2]) * depth[1]
    i = int(x)
    fr = x - i
    return cdf[i] + fr * (cdf[i + 1] - cdf[i])


@leaf
def _slab_mass(zrel, thick, depth, cdf):
    """Share of a voxel's kernel (centred ``zrel`` behind the slab's front) inside the slab: the depth
    factor of an untilted kernel."""
    return _cdf((thick - zrel) * depth[0], depth, cdf) - _cdf(-zrel * depth[0], depth, cdf)


@leaf
def _splat_tilted(px, py, s, box, cr, cg, cb, alpha, fpc, table, slab, depth, cdf, sheet, dirty_px, dirty, nd):
    """``_splat`` with the depth factor per pixel: the kernel's depth given the pixel offset moves by
    ``g.d`` (``slab = (zrel, thick, gx, gy)``, offsets in pixels at ``t0 = 1``)."""
    x0, x1, y0, y1 = box
    Qa, Qb2, Qc, R2v, tscale = fpc
    zrel, thick, gx, gy = slab
    img_w = sheet.shape[1]
    inv_s = 1.0 / s
    inv_s2 = inv_s * inv_s
    for y in range(y0, y1 + 1):
        dy = y - py
        qy = Qc * dy * dy
        qxy = Qb2 * dy
        zy = zrel + gy * dy * inv_s
        for x in range(x0, x1 + 1):
            dx = x - px
            q = (Qa * dx * dx + qxy * dx + qy) * inv_s2
            wgt = table[int(min(q, R2v) * tscale)] * _slab_mass(zy + gx * dx * inv_s, thick, depth, cdf)
            nd = add_to_sheet(sheet, dirty_px, dirty, nd, x, y, img_w, wgt, cr, cg, cb, alpha)
    return nd


# ---- the frame's tables ------------------------------------------------------------------------------------


def depth_kernel(jac, zrow, sigma, radius):
    """The kernel's depth given the pixel offset (module docstring): ``(g, s_c, ext, V)`` for the pixel
    Jacobian ``jac`` (2 x 3) and the depth per grid step ``zrow`` (3), with the footprint widened as
    :func:`isplat.splat.footprint.make_footprint` widens it. ``ext``: the kernel's reach in depth over its
    footprint; ``V = |det J3|``."""
    from .footprint import MIN_SIGMA_PIXELS

    J = np.asarray(jac, dtype=np.float64)
    z = np.asarray(zrow, dtype=np.float64)
    Sigma = sigma * sigma * (J @ J.T)
    lam, vec = np.linalg.eigh(Sigma)
    Sigma = (vec * np.maximum(lam, MIN_SIGMA_PIXELS ** 2)) @ vec.T
    m_xz = sigma * sigma * (J @ z)
    m_zz = sigma * sigma * float(z @ z)
    g = np.linalg.solve(Sigma, m_xz)
    s_c = math.sqrt(max(m_zz - float(g @ m_xz), 0.0))
    tilt = math.sqrt(max(float(g @ Sigma @ g), 0.0))
    V = abs(float(np.linalg.det(np.vstack([J, z]))))
    return g, s_c, float(radius) * (s_c + tilt), V, tilt


def slab_range(z0, zrow, n_abc, thick, ext, near=None):
    """``(z_lo, n_slabs)``: the slabs covering every kernel of a grid of ``n_abc`` voxels whose centres have
    depth ``z0 + (a, b, c) . zrow`` (in perspective not nearer than ``near``), slab boundaries anchored to
    the middle depth of the grid's corners (so they move with the volume, not with the near plane)."""
    n = np.asarray(n_abc) - 1
    corners = np.array([[x, y, w] for x in (0, n[0]) for y in (0, n[1]) for w in (0, n[2])], dtype=np.float64)
    zs = z0 + corners @ np.asarray(zrow, dtype=np.float64)
    zmid = 0.5 * (float(zs.min()) + float(zs.max()))
    zmin = float(zs.min()) if near is None else max(float(zs.min()), near)
    zmax = max(float(zs.max()), zmin)
    z_lo = zmid + thick * math.floor((zmin - ext - zmid) / thick)
    return z_lo, max(1, int(math.floor((zmax + ext - z_lo) / thick)) + 1)


def plan(tables):
    """The frame's :data:`SheetsPlan`, each thread's touched-pixel list and the slabs in front-to-back order,
    from what :func:`isplat.frame.prepare` works out for every technique (``tables``,
    :class:`isplat.frame.FrameTables`: its shading table, and its cutting planes' rows in slice coordinates of the
    view's principal axis)."""
    sel, view, dtype, shade, cuts = tables.sel, tables.view, tables.dtype, tables.shade, tables.cuts
    from .. import camera as cam_mod
    from .. import grid
    from ..errors import IsplatError
    from ..transfer import alpha_table
    from .footprint import make_footprint

    ro, geom, frame = view.render, view.geom, view.frame
    axis = view.axis_sign[0]
    ia, ib, ic = grid.SLICE_AXES[axis]
    proj = cam_mod.projection(frame, geom, axis)
    persp = frame.projection == "perspective"
    S = proj.steps
    zrow = -(S @ frame.w)
    origin = frame.e if persp else frame.p
    z0 = -float((geom.q - origin) @ frame.w)
    g, s_c, ext, V, tilt = depth_kernel(proj.jac, zrow, ro.footprint_sigma, ro.footprint_radius)
    if not s_c > 0.0 or not math.isfinite(ext):
        raise IsplatError("render.sheets = 'image': the kernel has no depth in this view; use sheets = 'axis'")
    thick = max(float(geom.spacing.min()), 2.0 * ext / MAX_SLABS_PER_KERNEL)
    z_lo, n_slabs = slab_range(z0, zrow, geom.n_ijk[[ia, ib, ic]], thick, ext, frame.near if persp else None)
    span = int(math.ceil(2.0 * ext / thick)) + 1
    fp = make_footprint(proj.jac, ro.footprint_sigma, ro.footprint_radius, ro.footprint_table, dtype)
    a_cell = abs(float(np.linalg.det(proj.jac[:, :2])))
    table = (fp.table.astype(np.float64) * (V / (thick * a_cell))).astype(dtype)
    unit = sel.unit_distance or float(geom.spacing.min())
    coef = tuple(float(x) for x in proj.coef)
    zc = (z0, *(float(x) for x in zrow))
    qe = tuple(float(x) for x in (geom.q - frame.e)) if persp else (0.0, 0.0, 0.0)
    geo = SheetGeometry(coef, zc, qe, tuple(float(x) for x in S.ravel()), persp, thick / unit,
                        np.ascontiguousarray(cuts, dtype=np.float64), float(z_lo), float(thick), span,
                        (float(g[0]), float(g[1]), float(s_c), float(ext), bool(tilt <= 1e-9 * s_c)),
                        cdf_table(float(ro.footprint_radius)))
    atab = alpha_table(sel.luts, None if persp else thick / unit)
    cls = Classify(atab, sel.luts.color, shade, sel.use_gm, sel.use_shade)
    vox = sel.voxels(axis)
    if sel.method == "full":
        n_c = int(geom.n_ijk[ic])
        out = bucket_full(vox.density, vox.gm, np.asarray(vox.strides, np.int64), vox.n_a, vox.n_b, n_c, atab,
                          sel.use_gm, geo, n_slabs)
    else:
        out = bucket_indexed(vox, atab, sel.use_gm, geo, n_slabs)
    svox = SheetVoxels(*out[:6], vox.gm, vox.nrm, int(out[6]))
    lists = [np.empty(tables.band_px + 1, np.int64) for _ in range(tables.threads)]
    sheet = sheet_buffers(frame.height, frame.width, dtype)
    return (SheetsPlan(svox, cls, geo, FootprintTable(table, fp.params), sheet), lists,
            np.arange(n_slabs, dtype=np.int64))


register(SheetsPlan, _scratch, _slab)
