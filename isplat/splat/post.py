"""Post-classified splatting (``render.classification = "post"``): reconstruct the density, then classify.

The pre-classified technique (:mod:`isplat.splat.pre`) looks each voxel up in the transfer function and
spreads its colour and opacity with a Gaussian footprint, which blurs a sharp transfer-function edge and widens
an opaque surface by the footprint's reach (Mueller, Moeller and Crawfis 1999, "Splatting without the blur").
Here each slice's *densities* are splatted with the tent kernel of the slice's lattice (the linear B-spline,
one voxel step in each in-slice direction), whose sum at a point of the slice plane is exactly the bilinear
interpolation of the four voxels around it; the sum is then classified, shaded and composited. The tent
footprint is evaluated in its gather form: each pixel of a quad's projection (the square between four voxels)
takes its point on the slice plane and interpolates there. Along every pixel's ray the samples are then exactly
the trilinear reconstruction at the slice planes, classified after reconstruction, as in a ray caster whose
step is the slice spacing.

What the index decides: which quads are sampled. A quad is sampled when one of its four voxels is of interest
(its density is in the transfer function's non-zero intervals) and its cell is not hidden (the occlusion tests
of :mod:`isplat.splat.traverse`). A quad none of whose voxels is of interest is skipped, though the bilinear
density inside can still cross an interval (a thin material between two others, say skin at the boundary of
bone and air); the reconstruction of such a quad is what a ray caster shows as a thin false layer.

The four voxels' densities come from the whole density channel (one byte per voxel; the normals and gradient codes
too when the scene uses them): the neighbours of the voxels of interest have any density, and the index does not
hold them. Read from the range runs (isplat.selection, formats/runs.md) the channels (a pool of bricks) hold only
the voxels whose neighbourhood can meet an interval, zeros elsewhere; the sampler then skips every quad with a
corner not held (:data:`PostPlan`'s ``held``, :func:`held_pool`), whose field meets no interval. Classification
interpolates the 256-entry tables linearly between codes (the transfer function is applied to the interpolated
value, not to a truncated code). Shading interpolates the four voxels' Phong factors (the shading of a trilinear ray
caster that shades its grid points), each weighted by its bilinear weight times its gradient magnitude code
(normalised; the bilinear weights alone where all four are 0): on slices much thicker than the pixels a corner just
off a surface nearly parallel to the slices (air, a short gradient whose direction is mostly along the slice axis)
otherwise shades as much as the corner on it, which draws rings of the slices on the surface (docs/thick-slices.md).

Between thick slices. When the thicker in-slice axis' spacing is at least :data:`THICK_RATIO` times the volume's
finest (slices 5-7 mm thick over 1 mm pixels seen from the side, say; not a CT's 2.5 mm slices over 0.7 mm, where
the linear reconstruction is already at the object's own streak, docs/thick-slices.md), the density along that axis
is a cubic through the four voxels around the sample instead of the line through two (:func:`_density_at`;
Catmull-Rom by default, :data:`BETWEEN_SLICES`), then linear across: with the line an isosurface is piecewise planar
with a kink at every slice, and its shading and silhouettes step (terraces). The Phong factors then mix the same
eight voxels' with the cubic B-spline's weights along the thick axis (:func:`_shade_between`,
:data:`SHADE_BETWEEN`). Only the gather reads the extra voxels (:func:`_taps`: the voxel before the quad and the one
after, clamped to the volume; a slab holds whole slices, so the in-slice axes reach the volume's edges there too);
which quads are sampled is decided as before, by their four corners. The view's own axis is not interpolated: the
samples lie on its slices. Isotropic grids and grids below the ratio take the bilinear sampler, bit for bit as
before.

Each pixel samples a slice at most once (it belongs to one quad), so a sample is composited straight into the
image: no sheet. Images do not depend on the thread bands. Counters: ``stats[band, 1]`` the voxels of interest
in the cells left after the occlusion tests, ``stats[band, 2]`` the samples composited.

A technique of :mod:`isplat.splat.traverse` (which walks the bands and slices, and the regions, blocks and cells
the occlusion tests leave): this module is its per-frame plan (:data:`PostPlan`, :func:`plan`: no footprint,
the tent's reach instead; no sheet) and its per-slice stages (:func:`_slice`).
"""

from __future__ import annotations

import math
import os
from collections import namedtuple

import numpy as np
from numba import types
from numba.extending import overload

from ..grid import POOL_EDGE, POOL_SHIFT
from ..jit import jit, leaf, over4, prefetch, stage
from .composite import TILE, saturated
from .labels import sample_label
from .select import BLOCK, CELL
from .traverse import (CX, CY, NEAR, WA, WB, WPE, XA, XB, YA, YB, box_args, build_sat, cut_away, indexed_source,
                       max_cells, path_alpha, rect_hull, register, slice_bases, slice_regions, source_scratch,
                       visible_cells)

SCAN_PIXELS = 48          # the fewest pixels a scanned square should cover (scan_unit)
# pixels a square's box and row spans are grown by: the forward projection of the square's corners and the
# inverse map of each pixel round differently (about 1e-12 of the pixel coordinates); far more than that, far
# less than a pixel, so the scan visits hardly a pixel outside the square
SPAN_MARGIN = 1e-4
AHEAD = 1                 # squares prefetched ahead of the one sampled (_sample_squares; 2 measured alike)
# shading weights each corner's Phong factors by its bilinear weight times its gradient magnitude code (_sample);
# False: by the bilinear weight only, as before (python -m benchmarks thick renders both; docs/thick-slices.md)
WEIGHTED_SHADING = True
# the density between slices along a thick in-slice axis (_density_at): "monotone" a monotone cubic (Fritsch-Butland
# slopes: C1, interpolates the voxels, never outside the two voxels around it), "catmull-rom" (clamped to the
# codes), "b-spline" the interpolating (cardinal) cubic spline, the cubic B-spline through prefiltered coefficients,
# as its kernel truncated to SPLINE_REACH slices each way (_spline_weights; clamped to the codes), "linear" the
# bilinear of the quad as before; used when the thicker in-slice axis' spacing is at least
# THICK_RATIO times the volume's finest (docs/thick-slices.md: why 4: below it the cubic hardly changes the picture,
# at 1.2-1.8x the frame time). The default, "b-spline": RMSE against the object lower than Catmull-Rom's on every
# 7 mm case, the largest streak (MRI, oblique) 1.71x the object's -> 1.16x, the side views' within 10% of it
# (docs/design.md, "The interpolating cubic spline between thick slices"), at 1.14x the time per sample
BETWEEN_SLICES = "b-spline"
THICK_RATIO = 4.0
CUBIC_KINDS = {"monotone": 0, "catmull-rom": 1, "b-spline": 2}
# "b-spline": the taps on each side of the sample along the thick axis (2 SPLINE_REACH in all, clamped to the
# volume); the kernel left out beyond them is below 2.5% of the weights at 3 (0.7% at 4, 9% at 2). 3 rather than 4:
# 1.14x Catmull-Rom's time per sample against 1.25x, and less streak on side views (docs/design.md, "The
# interpolating cubic spline between thick slices"). What post reads of a bricked file reaches this far
# (isplat.selection.QUAD_REACH), and MIP's bounds cover its overshoot (SPLINE_OVERSHOOT, isplat.splat.mip).
SPLINE_REACH = 3


def spline_kernel(reach: int = SPLINE_REACH) -> np.ndarray:
    """float64[2 reach, 4]: the interpolating cubic spline's weights of the voxels ``j = 1 - reach .. reach``
    slices from the quad's first corner at fraction f along the thick axis, as cubics in f (coefficients of 1, f,
    f^2, f^3): the cubic B-spline's basis convolved with its prefilter's impulse response sqrt(3) (sqrt(3) - 2)^|m|
    (Unser 1999), so w_j(f) = sum_i B_i(f) h(j - i); w_j(0) is 1 at j = 0 and 0 elsewhere (up to rounding)."""
    z = math.sqrt(3.0) - 2.0
    basis = np.array([[1, -3, 3, -1], [4, 0, -6, 3], [1, 3, 3, -3], [0, 0, 0, 1]], np.float64) / 6.0  # i = -1..2
    out = np.zeros((2 * reach, 4))
    for r, j in enumerate(range(1 - reach, reach + 1)):
        for i in range(-1, 3):
            out[r] += basis[i + 1] * math.sqrt(3.0) * z ** abs(j - i)
    return out


SPLINE_KERNEL = spline_kernel()
# the most the renormalised kernel's negative weights add up to at any f (0.274 at reach 4, 0.251 at 3; 1/8 for
# Catmull-Rom): a sample lies within its taps' extremes P, Q widened by this times P - Q (isplat.splat.mip)
SPLINE_OVERSHOOT = 0.3
# with a cubic between slices, the Phong factors of the eight voxels around the sample with the cubic B-spline's
# weights along the thick axis (_shade_between); False: the quad's four corners' as between thin slices
SHADE_BETWEEN = True
# where a sample stops, for measuring the stages' shares only (python -m benchmarks sampler, each value with numba's
# cache in a folder of its own): 0 after the scan, 1 after the density gather, 2 after the opacity and its
# compositing, 3 the whole sample; none of these saturates a pixel (so that all do the same pixels and slices);
# 4 (the default) the whole sample with early termination. 0-3 draw wrong images.
SAMPLE_STAGES = int(os.environ.get("ISPLAT_SAMPLE_STAGES", "4"))
if SAMPLE_STAGES != 4 and not os.environ.get("NUMBA_CACHE_DIR"):
    # numba's cache does not tell the copies apart: one compiled here would be loaded by later ordinary runs
    raise RuntimeError("ISPLAT_SAMPLE_STAGES (for measuring only) needs a NUMBA_CACHE_DIR of its own")

PostClassify = namedtuple("PostClassify", "alpha color shade use_gm use_shade lab between fill")
PostClassify.__doc__ = """The transfer function's and shading's tables as :func:`_sample` takes them: ``alpha``
float64[256, 2G] (opacities per density and gradient code, corrected for the slice's path length when
orthographic, ``log1p(-alpha)`` in perspective, then their steps to the next code) and ``color`` float64[256, 6]
(:func:`lerp_tables`); ``shade`` float32[65536, 2 or 6] Phong factors per normal code
(:mod:`isplat.splat.shade`); ``use_shade`` 0 unshaded, 1 the corners' Phong factors weighted bilinearly, 2
weighted by the bilinear weights times the corners' gradient magnitude codes (:data:`WEIGHTED_SHADING`);
``lab`` the segmentation labels shown (:mod:`isplat.splat.labels`: the label
channel, the colour table, steps; empty without labels); ``between`` (axis, kind, shade): the in-slice axis along
which the density is a cubic between voxels (1 a, 2 b), the cubic's kind and whether the shading follows it (1:
:func:`_shade_between`) (:func:`between_slices`, :func:`_density_at`), or None on a grid that takes the bilinear
sampler: a type of its own, so that numba compiles that frame's kernel with no cubic in it (:func:`_taps`,
:func:`_between`); ``fill`` True when a pixel that reaches the early-termination opacity is filled with the colour
of the sample that reached it (``render.termination = "fill"``, :func:`isplat.splat.composite.saturated`)."""
PostPlan = namedtuple("PostPlan", "source whole unit cls geo reach stride held")
PostPlan.__doc__ = """A post-classified frame's tables: ``source`` which quads to sample (the index's selection and
its bins, :data:`isplat.splat.traverse.Indexed`, or without an index the whole channels,
:data:`isplat.splat.traverse.WholeVolume`, each voxel classified); ``whole`` the whole channels
(:data:`isplat.splat.traverse.WholeVolume`), which give the four densities of each sample; ``unit`` the side of
the squares scanned together (:func:`scan_unit`); ``cls`` :data:`PostClassify`; ``geo``
:data:`isplat.splat.traverse.SliceGeometry`; ``reach`` the tent's reach in pixels (:func:`reach`), which the
occlusion tests and the bins take; ``stride`` ``render.slice_stride``: only the slices whose index is a multiple of
it are sampled (:func:`_slice`; ``cls`` and ``geo`` corrected for the path of that many slices); ``held`` None when
the channels hold every voxel the quads read (whole channels, bricks), else ``(bits, table)``, the bits of
:func:`held_quads` (or :func:`held_pool`, with a pool's brick table as ``table``): a reader of range runs
(isplat.selection, formats/runs.md) loads only the voxels whose neighbourhood can meet an interval, so a quad
with a corner not loaded is skipped (its field is transparent in truth; the places of the voxels not loaded
hold zeros, or another row's voxels in a packed pool; :func:`_corners_held`). A thread's scratch
is its list of a slice's visible cells (int64[C, 4])."""


def loaded_bits(loaded: np.ndarray) -> np.ndarray:
    """uint64 words: the bit set (bit ``p % 64`` of word ``p // 64``, one per voxel of the flat ``[k, j, i]``
    layout) of ``loaded`` (uint8 or bool, any shape, non-zero where the channels hold the voxel)."""
    packed = np.packbits(np.asarray(loaded).reshape(-1) != 0, bitorder="little")
    return np.concatenate([packed, np.zeros(-packed.size % 8, np.uint8)]).view("<u8")


def held_quads(loaded: np.ndarray, shape, axis: str) -> np.ndarray:
    """uint8 [ceil(n / 8)]: the bits (little-endian bit order, one per voxel of whole-shape channels' flat
    ``[k, j, i]`` layout; a pool's are :func:`held_pool`'s) of :data:`PostPlan`'s ``held`` for ``axis``'s slices:
    set when the quad of the slice whose first corner the voxel is has all four corners loaded (the edge voxel
    repeated at the volume's edge, as the sampler clamps). ``loaded``: the voxels the channels hold, as
    :func:`loaded_bits`' words (uint64), or a mask. Whole words at a time: the loaded bits and those one step on
    along a, along b and along both, ANDed (:func:`_held_words`); then the last line along a and along b set again
    voxel by voxel (:func:`_held_edges`)."""
    from ..grid import SLICE_AXES, shape_ijk

    words = loaded if loaded.dtype == np.uint64 else loaded_bits(loaded)
    ia, ib, _ = SLICE_AXES[axis]
    n = np.asarray(shape_ijk(shape), dtype=np.int64)
    if words.size * 64 < int(np.prod(n)):
        raise ValueError(f"{words.size} words of loaded bits for {int(np.prod(n))} voxels")
    step = (1, int(n[0]), int(n[0] * n[1]))
    held = _held_words(words, step[ia], step[ib])
    _held_edges(words, held, n, int(ia), int(ib))
    return held.view(np.uint8)[:(int(np.prod(n)) + 7) // 8]


@jit
def _held_words(words, sa, sb):
    """Per 64-bit word: the loaded bits ANDed with those ``sa``, ``sb`` and ``sa + sb`` voxels on (zero beyond the
    last word), in one pass."""
    out = np.empty_like(words)
    for w in range(words.shape[0]):
        out[w] = words[w] & _bits_from(words, w, sa) & _bits_from(words, w, sb) & _bits_from(words, w, sa + sb)
    return out


@leaf
def _bits_from(words, w, s):
    """The 64 bits of ``words`` from bit ``64 w + s`` on (zeros past the end)."""
    q, r = w + (s >> 6), np.uint64(s & 63)
    lo = words[q] if q < words.shape[0] else np.uint64(0)
    if r == 0:
        return lo
    hi = words[q + 1] if q + 1 < words.shape[0] else np.uint64(0)
    return (lo >> r) | (hi << (np.uint64(64) - r))


@jit
def _held_edges(words, held, n, ia, ib):
    """:func:`held_quads`' bits of the voxels of the last line along a and along b (``n``: the volume's extents
    along i, j, k; ``ia``, ``ib``: which of them a and b are), the next voxel past the edge being the edge voxel."""
    step = np.array([1, n[0], n[0] * n[1]], dtype=np.int64)
    sa, sb, oc = step[ia], step[ib], 3 - ia - ib
    for edge in range(2):
        e, f = (ia, ib) if edge == 0 else (ib, ia)
        for u in range(n[f]):
            for w in range(n[oc]):
                p = (n[e] - 1) * step[e] + u * step[f] + w * step[oc]
                da = sa if p // sa % n[ia] + 1 < n[ia] else 0
                db = sb if p // sb % n[ib] + 1 < n[ib] else 0
                ok = True
                for q in (p, p + da, p + db, p + da + db):
                    ok = ok and (words[q >> 6] >> np.uint64(q & 63)) & np.uint64(1) != 0
                bit = np.uint64(1) << np.uint64(p & 63)
                held[p >> 6] = held[p >> 6] | bit if ok else held[p >> 6] & ~bit


def held_pool(loaded: np.ndarray, table: np.ndarray, shape, axis: str) -> np.ndarray:
    """uint8 [rows * 64]: :func:`held_quads`' bits for a pool (isplat.selection.WholeChannels with a ``table``):
    bit ``q % 8`` of byte ``q // 8`` for the voxel at the pool's place ``q = row * 512 + place in its brick``, set
    when the quad whose first corner it is has all four corners loaded (the edge voxel repeated at the volume's
    edge). ``loaded``: the pool's loaded bits (uint64, 8 words a row, row 0 none: isplat.runsfile's ``pool``);
    ``table``: each brick's row (0: not in the pool, none of its voxels loaded). A brick's eight words (one per
    k-layer, bit ``8 jj + ii``) at a time (:func:`_held_rows`); rows never written stay clear."""
    from ..grid import SLICE_AXES

    ia, ib, _ = SLICE_AXES[axis]
    g = np.array([-(-int(n) // POOL_EDGE) for n in shape], dtype=np.int64)          # (k, j, i) bricks
    if table.size != int(np.prod(g)) or loaded.size % 8 or loaded.size < 8 * (int(table.max(initial=0)) + 1):
        raise ValueError(f"a pool's {loaded.size} words of loaded bits and {table.size} bricks for shape {shape}")
    held = np.zeros_like(loaded)
    _held_rows(loaded, table, np.asarray(shape, dtype=np.int64), g, int(ia), int(ib), held)
    return held.view(np.uint8)


M01 = np.uint64(0x0101010101010101)     # bit 0 of every byte: a brick's ii = 0 across its eight jj rows
M7F = np.uint64(0x7F7F7F7F7F7F7F7F)


@jit
def _held_rows(loaded, table, shape, g, ia, ib, held):
    """:func:`held_pool`'s bits: for each brick in the pool, its loaded words ANDed with those one step on along
    a, along b and along both (:func:`_shifted`, the neighbour bricks' words through ``table``)."""
    w = np.zeros((6, 8), np.uint64)
    cur, na, sb, nsb, tmp, sab = w[0], w[1], w[2], w[3], w[4], w[5]
    at = np.zeros(3, np.int64)
    for n in range(table.shape[0]):
        r = np.int64(table[n])
        if r == 0:
            continue
        at[2], at[1], at[0] = n // (g[1] * g[2]), n // g[2] % g[1], n % g[2]           # (i, j, k) of the brick
        _brick_words(loaded, table, at, shape, g, cur)
        _shifted(loaded, table, at, ib, shape, g, cur, tmp, sb)                   # loaded at p + b
        at[ia] += 1
        inside = _brick_words(loaded, table, at, shape, g, na)
        if inside:
            _shifted(loaded, table, at, ib, shape, g, na, tmp, nsb)               # the a-neighbour's, at p + b
        at[ia] -= 1
        _shift_by(ia, sb, nsb, inside, sab)                                       # loaded at p + a + b
        _shift_by(ia, cur, na, inside, tmp)                                       # loaded at p + a
        for kk in range(8):
            held[8 * r + kk] = cur[kk] & tmp[kk] & sb[kk] & sab[kk]


@leaf
def _brick_words(loaded, table, at, shape, g, out):
    """The loaded words of the brick at ``at`` (i, j, k brick places) into ``out``, the places past the volume's
    edge set as the edge voxel (so a step past the edge finds the edge voxel, as the sampler clamps); False (and
    ``out`` untouched) when the brick lies beyond the grid."""
    if at[0] >= g[2] or at[1] >= g[1] or at[2] >= g[0]:
        return False
    r = np.int64(table[(at[2] * g[1] + at[1]) * g[2] + at[0]])
    for kk in range(8):
        out[kk] = loaded[8 * r + kk]
    ei = min(shape[2] - at[0] * POOL_EDGE, POOL_EDGE)
    ej = min(shape[1] - at[1] * POOL_EDGE, POOL_EDGE)
    ek = min(shape[0] - at[2] * POOL_EDGE, POOL_EDGE)
    if ei < POOL_EDGE:
        fill = np.uint64((0xFF << ei) & 0xFF) * M01
        for kk in range(8):
            edge = (out[kk] >> np.uint64(ei - 1)) & M01
            out[kk] = (out[kk] & ~fill) | (edge * np.uint64((0xFF << ei) & 0xFF))
    if ej < POOL_EDGE:
        keep = (np.uint64(1) << np.uint64(8 * ej)) - np.uint64(1)
        for kk in range(8):
            line = (out[kk] >> np.uint64(8 * (ej - 1))) & np.uint64(0xFF)
            out[kk] = (out[kk] & keep) | (line * (M01 & ~keep))
    for kk in range(ek, 8):
        out[kk] = out[ek - 1]
    return True


@leaf
def _shifted(loaded, table, at, d, shape, g, cur, tmp, out):
    """The loaded bits one step on along axis ``d`` (0 i, 1 j, 2 k) of every voxel of the brick at ``at``, whose
    words are ``cur`` (``tmp``: scratch for the neighbour's)."""
    at[d] += 1
    inside = _brick_words(loaded, table, at, shape, g, tmp)
    at[d] -= 1
    _shift_by(d, cur, tmp, inside, out)


@leaf
def _shift_by(d, cur, nxt, inside, out):
    """A brick's words ``cur`` one step on along ``d``: within the brick a shift, the last place from the next
    brick's words ``nxt`` (beyond the grid, ``inside`` False: the brick's own last place, the edge repeated)."""
    for kk in range(8):
        w = cur[kk]
        if d == 0:
            nb = nxt[kk] if inside else w >> np.uint64(7)
            out[kk] = ((w >> np.uint64(1)) & M7F) | ((nb & M01) << np.uint64(7))
        elif d == 1:
            nb = nxt[kk] if inside else w >> np.uint64(56)
            out[kk] = (w >> np.uint64(8)) | (nb << np.uint64(56))
        elif kk < 7:
            out[kk] = cur[kk + 1]
        else:
            out[kk] = nxt[0] if inside else w


def reach(coef) -> tuple[float, float]:
    """How far (pixels, x and y) a voxel's tent reaches at perspective scale 1: one step along a and b."""
    return abs(coef[XA]) + abs(coef[XB]), abs(coef[YA]) + abs(coef[YB])


def plan(tables):
    """The frame's :data:`PostPlan`, each thread's list of visible cells and None (the view's slices), from what
    :func:`isplat.frame.prepare` works out for every technique (``tables``, :class:`isplat.frame.FrameTables`)."""
    from ..errors import IsplatError

    sel, view = tables.sel, tables.view
    if not sel.post or sel.whole is None:
        raise IsplatError("render.classification = 'post' needs a selection made for it (the whole channels)")
    # the tables with their steps between codes (the full method's search reads the opacities, the first half
    # of the columns)
    alpha, color = lerp_tables(tables.atab, sel.luts.color)
    whole = sel.whole_volume(tables.axis, pool=True)
    # 2: the corners' Phong factors weighted by their gradient magnitudes too (_sample), when those were read
    shading = (2 if WEIGHTED_SHADING and whole.gm.shape[0] > 0 else 1) if sel.use_shade else 0
    between = between_slices(tables.view.geom.spacing, tables.axis)
    cls = PostClassify(alpha, color, tables.shade, sel.use_gm, shading, _labels_of(tables),
                       between if between[0] else None,     # None: the bilinear kernel (_taps)
                       view.render.termination == "fill")
    ex, ey = reach(tables.proj.coef)
    tent = (float(ex), float(ey))
    source = whole if sel.method == "full" else \
        indexed_source(view.order, sel.voxels(tables.axis), tables.geo, tent, tables.rows, view.frame.width)
    n_cells = max_cells(sel, tables.axis)
    lists = [np.empty((n_cells, 4), np.int64) for _ in range(tables.threads)]
    stride = int(tables.view.render.slice_stride)
    held = sel.held_quads(tables.axis)
    if held is not None:        # the bits, and a pool's brick table: the bits keep the rows' layout (_row_place)
        held = (held, sel.whole.table if sel.whole.pooled else None)
    if held is not None and cls.between is not None:
        raise IsplatError("a selection holding only some voxels (range runs) cannot take the cubic between thick "
                          "slices, whose taps reach beyond the quad")
    return PostPlan(source, whole, scan_unit(tables.proj.jac), cls, tables.geo, tent, stride, held), lists, None


def between_slices(spacing, axis: str, kind: str | None = None, ratio: float | None = None) -> tuple[int, int, int]:
    """``(axis, kind, shade)`` of :data:`PostClassify`'s ``between``: the thicker in-slice axis of ``axis``'s
    slices (1 a, 2 b; a when equal) when its spacing is at least ``ratio`` (:data:`THICK_RATIO`) times the finest
    of the three and ``kind`` (:data:`BETWEEN_SLICES`) is not "linear", else 0; the kind's code; 1 when the
    shading follows (:data:`SHADE_BETWEEN`). Along the view's axis nothing is interpolated: the samples lie on
    the slices."""
    from ..grid import SLICE_AXES

    kind = BETWEEN_SLICES if kind is None else kind
    ratio = THICK_RATIO if ratio is None else ratio
    sp = [float(x) for x in spacing]
    ia, ib, _ = SLICE_AXES[axis]
    t = 1 if sp[ia] >= sp[ib] else 2
    if kind == "linear" or max(sp[ia], sp[ib]) < ratio * min(sp):
        return 0, 0, 0
    return t, CUBIC_KINDS[kind], int(bool(SHADE_BETWEEN))


def _between(between):
    """:data:`PostClassify`'s ``between`` as :func:`_prefetch_square` reads it: (0, 0, 0), the bilinear
    sampler's, when None. Compiled (the overload below), None is a type of its own: the kernel of a frame without
    a thick axis is compiled with these constants, and LLVM leaves the branches out; a thick grid's frames compile
    a kernel of their own, from the same source (:func:`_taps`)."""
    return (0, 0, 0) if between is None else between


@overload(_between, inline="always")
def _typed_between(between):
    if isinstance(between, types.NoneType):
        return lambda between: (0, 0, 0)
    return lambda between: between


def _labels_of(tables):
    """The frame's ``lab`` tuple (:mod:`isplat.splat.labels`): the selection's labels with their opacities
    corrected for this view's path length, or none."""
    from .labels import frame_table, no_labels

    lab = getattr(tables.sel, "labels", None)
    if lab is None:
        return no_labels()
    r = None if tables.geo.persp else float(tables.view.render.slice_stride * tables.proj.ds / tables.unit)
    return lab.ids, frame_table(lab.table, tables.geo.persp, r), lab.frame_steps(tables.axis), lab.normals


@stage
def _scratch(plan):
    """What a call allocates once: the traversal's (:func:`isplat.splat.traverse.source_scratch`), the slice's
    marks (:func:`_marks`) and its small arrays (:func:`_slice_scratch`)."""
    return source_scratch(plan.source), _marks(plan.whole.n_a, plan.whole.n_b), _slice_scratch(plan.geo)


@leaf(inline="always")    # numba inlines its IR, not LLVM: see isplat.jit.leaf
def _slice(plan, cells, scratch, c, pos, buf, band):
    """Slice ``c`` for one band: its regions (:func:`isplat.splat.traverse.slice_regions`), then
    :func:`_post_slice`; nothing when ``c`` is not a multiple of ``plan.stride`` (``render.slice_stride``: by the
    slice's index, so a frame cut into slabs samples the same slices)."""
    if c % plan.stride != 0:
        return
    regions, p0, p1, hier, _, _, _ = slice_regions(plan.source, scratch[0], c, pos, plan.cls.alpha, plan.cls.use_gm,
                                                   plan.geo, plan.reach, buf, band)
    _post_slice(c, regions, p0, p1, hier[:7], plan.whole, plan.unit, plan.cls, plan.geo, plan.reach, cells, buf,
                band, scratch[1], scratch[2], plan.held)


@stage
def _marks(n_a, n_b):
    """A slice's cell flags (zeroed), the list of flagged cells, the flagged cells per square of
    :func:`scan_unit` (zeroed) and the list of those squares (see :func:`_mark_cells`), and what is scanned
    (see :func:`_plan_squares`)."""
    n = ((n_a + CELL - 1) // CELL) * ((n_b + CELL - 1) // CELL)
    return (np.zeros(n, np.uint8), np.empty(n, np.int64), np.zeros(n, np.uint8), np.empty((n, 3), np.int64),
            np.empty((n, 4), np.int64))


@stage
def _slice_scratch(geo):
    """What :func:`_post_slice` fills per slice: the cut planes' offsets, and (samples composited, pixels newly
    saturated)."""
    return np.empty(max(geo.cuts.shape[0], 1), dtype=np.float64), np.zeros(2, np.int64)


def lerp_tables(alpha, color) -> tuple[np.ndarray, np.ndarray]:
    """The transfer tables as :func:`_sample` takes them, float64 (the per-sample lerps run in float64: no
    conversion per load): ``alpha`` (256, G) -> (256, 2G), each code's opacities and then their steps to the
    next code's; ``color`` (256, 3) -> (256, 6) the same. A sample at density ``k + f`` is ``t[k] + f step[k]``,
    the same value as ``t[k] + f (t[k + 1] - t[k])`` with one subtraction fewer per sample (the steps of code
    255 are 0; a sample's ``k`` is at most 254)."""
    out = []
    for t in (np.asarray(alpha, np.float64), np.asarray(color, np.float64)):
        step = np.zeros_like(t)
        step[:-1] = t[1:] - t[:-1]
        out.append(np.ascontiguousarray(np.concatenate([t, step], axis=1)))
    return out[0], out[1]


def scan_unit(jac, target: float = SCAN_PIXELS) -> int:
    """The side, in voxels, of the squares of the slice whose pixels are scanned together: a cell (4 voxels) when
    a cell covers at least ``target`` pixels, else 8 or 16, so that the per-square costs (its projected box,
    its rows' spans) are shared by enough pixels when voxels are smaller than pixels (a square with few cells
    flagged is scanned cell by cell all the same, :func:`_plan_squares`)."""
    area = abs(float(jac[0][0]) * float(jac[1][1]) - float(jac[0][1]) * float(jac[1][0]))   # pixels per voxel
    unit = CELL
    while unit < BLOCK and unit * unit * area < target:
        unit *= 2
    return unit


@leaf
def _post_slice(c, regions, p0, p1, hier, whole, unit, cls, geo, reach, cells, buf, band, marks, scratch, held):
    """One slice and one band: the cells of interest left by the occlusion tests, the quads that touch their
    voxels sampled, classified and composited into the image. A leaf of its own, called once per slice: as
    fast or faster than inlined into :func:`_slice` (scripts/ab.py, 1-4%), and numba 0.68 inlined it there
    wrongly (its ``buf.stats[bi, k] += n`` were dropped, unless ``buf.stats`` was first given a name)."""
    bi, y0b, y1b, et, satab, ty0 = band
    cs, counts = scratch
    counts[0] = 0
    counts[1] = 0
    base = slice_bases(c, geo, cs)
    boxes = box_args(whole.n_a, whole.n_b, base, geo, reach, buf.img.shape[1], band, et < 1.0)
    nc = visible_cells(regions, p0, p1, hier, whole.n_a, boxes, satab, buf.sat, buf.tile_sat, cells)
    for k in range(nc):
        buf.stats[bi, 1] += cells[k, 1] - cells[k, 0]
    mark, marked, smark, squares, todo = marks
    nca = (whole.n_a + CELL - 1) // CELL
    nsa = (whole.n_a + unit - 1) // unit
    nm, ns = _mark_cells(cells, nc, nca, unit, nsa, mark, marked, smark, squares)
    nt = _plan_squares(squares, ns, smark, mark, nca, (whole.n_b + CELL - 1) // CELL, unit, todo)
    oa, ob, oc, da = whole.offs
    tab = whole.table
    voxel = (whole.density, whole.gm, whole.nrm, (oa, ob, oc[c], da, tab), whole.n_a, whole.n_b, c, cls.between)
    inv = _ortho_inverse(base, geo.coef)
    _sample_squares(todo, nt, mark, voxel, cls.alpha, cls.color, cls.shade, cls.use_gm, cls.use_shade, base,
                    cs, geo, inv, buf.img, buf.sat, buf.tile_sat, band, counts, cls.lab, held, cls.fill)
    for t in range(nm):
        mark[marked[t]] = 0
    for t in range(ns):
        smark[squares[t, 0]] = 0
    buf.stats[bi, 2] += counts[0]
    if counts[1] > 0:
        build_sat(buf.tile_sat, buf.tile_npix, ty0, satab)
    buf.stats[bi, 3] += 1


@leaf
def _mark_cells(cells, nc, nca, unit, nsa, mark, marked, smark, squares):
    """Flag the cells whose quads touch a voxel of a visible cell: bit 1 the cell itself, bit 2 its neighbour
    at +a, bit 4 at +b, bit 8 at +a+b (a quad is the square from its voxel to the next along a and b, so the
    cells at -a, -b and -a-b hold quads that reach this cell's voxels), listed in ``marked``; and the squares
    of ``unit`` voxels that hold them, listed once each as rows ``(index, column, row)`` of ``squares`` in the
    order of their first flagged cell, with their number of flagged cells in ``smark``. Returns the numbers of
    flagged cells and of squares. (No division: a square is found by shifting its cell's column and row.)"""
    shift = 0 if unit == CELL else (1 if unit == 2 * CELL else 2)     # scan_unit: 1, 2 or 4 cells a side
    nm = 0
    ns = 0
    for k in range(nc):
        ci = cells[k, 2] // CELL
        cj = cells[k, 3] // CELL
        for da in range(2):
            for db in range(2):
                if ci - da < 0 or cj - db < 0:
                    continue
                q = (cj - db) * nca + ci - da
                if mark[q] == 0:
                    marked[nm] = q
                    nm += 1
                    sa = (ci - da) >> shift
                    sb = (cj - db) >> shift
                    s = sb * nsa + sa
                    if smark[s] == 0:
                        squares[ns, 0] = s
                        squares[ns, 1] = sa
                        squares[ns, 2] = sb
                        ns += 1
                    smark[s] += 1
                mark[q] |= 1 << (da + 2 * db)
    return nm, ns


@leaf
def _plan_squares(squares, ns, smark, mark, nca, ncb, unit, todo):
    """What is scanned, as rows ``(index, side, a0, b0)`` of ``todo`` (a square of ``unit`` voxels or a cell,
    and its first voxel); returns their number. A square with enough of its cells flagged (all 4 of a square of
    2 x 2 cells, half of one of 4 x 4) is scanned whole, its per-square costs shared by many pixels; one with
    fewer, its flagged cells one by one, so as not to visit the pixels of cells none of whose quads is sampled
    (most of them where an opaque surface in front has saturated the pixels around a few visible cells). The
    thresholds are measured (docs/design.md)."""
    per = unit // CELL
    need = per * per if per <= 2 else per * per // 2
    nt = 0
    for t in range(ns):
        s = squares[t, 0]
        if smark[s] >= need:
            todo[nt, 0] = s
            todo[nt, 1] = unit
            todo[nt, 2] = squares[t, 1] * unit
            todo[nt, 3] = squares[t, 2] * unit
            nt += 1
            continue
        ca0 = squares[t, 1] * per
        cb0 = squares[t, 2] * per
        for cb in range(cb0, min(cb0 + per, ncb)):
            for ca in range(ca0, min(ca0 + per, nca)):
                if mark[cb * nca + ca] != 0:
                    todo[nt, 0] = cb * nca + ca
                    todo[nt, 1] = CELL
                    todo[nt, 2] = ca * CELL
                    todo[nt, 3] = cb * CELL
                    nt += 1
    return nt


@leaf(inline="always")
def _sample_squares(todo, nt, mark, voxel, alpha, color, shade, use_gm, use_shade, base, cs, geo, inv, img,
                    sat, tile_sat, band, counts, lab, held, fill):
    """Sample the squares and cells ``todo[:nt]`` (:func:`_sample_square`). One call per slice: the per-square
    stage is inlined here, since handing a stage this many arrays costs more than a small square."""
    for t in range(min(nt, AHEAD)):
        _prefetch_square(todo[t, 1], todo[t, 2], todo[t, 3], voxel, use_gm, use_shade)
    for t in range(nt):
        if t + AHEAD < nt:          # the voxels of squares ahead come from memory while this one is sampled
            _prefetch_square(todo[t + AHEAD, 1], todo[t + AHEAD, 2], todo[t + AHEAD, 3], voxel, use_gm, use_shade)
        _sample_square(todo[t, 0], todo[t, 1], todo[t, 2], todo[t, 3], mark, voxel, alpha, color, shade, use_gm,
                       use_shade, base, cs, geo, inv, img, sat, tile_sat, band, counts, lab, held, fill)


@leaf(inline="always")    # numba inlines its IR, not LLVM: see isplat.jit.leaf
def _prefetch_square(unit, a0, b0, voxel, use_gm, use_shade):
    """Ask the CPU to fetch the cache lines of the voxels that the quads of the square of ``unit`` voxels from
    (a0, b0) read (its voxels and the next along a and b), in the channels the samples read. A slice's rows
    along b lie a plane or a row of the volume apart, so each row of the square is lines of its own that the
    CPU's own prefetchers do not foresee: without this the samples wait for memory (most of a frame's time on a
    volume larger than the caches, docs/design.md). Every ``da``-th voxel along a (``voxel[3]``: half a line).
    Whole channels only: a pool's bricks hold a square's voxels in a few lines, and fetching them through the
    brick table cost more than it saved (docs/design.md, "The brick pool")."""
    density, gm, nrm, offs, n_a, n_b, c, thick = voxel
    between = _between(thick)
    oa, ob, cbase, da, tab = offs
    if tab is not None:             # a pool (a type of its own: the test is the compiler's)
        return
    a1 = min(a0 + unit, n_a - 1)
    b1 = min(b0 + unit, n_b - 1)
    if between[0] == 1:             # the cubic along a reads a voxel before and one more after (_density_at)
        a0, a1 = max(a0 - 1, 0), min(a1 + 1, n_a - 1)
    elif between[0] == 2:           # along b a row before and one more after
        b0, b1 = max(b0 - 1, 0), min(b1 + 1, n_b - 1)
    for b in range(b0, b1 + 1):
        row = cbase + _at(ob, b)
        for a in range(a0, a1 + da, da):
            i = np.uint64(row + _at(oa, min(a, a1)))
            prefetch(density, i)
            if use_shade:
                prefetch(nrm, i)    # 2 bytes a voxel: hence the half lines
            if use_gm or use_shade == 2:
                prefetch(gm, i)


@leaf(forceinline=True)
def _sample_square(sq, unit, a0, b0, mark, voxel, alpha, color, shade, use_gm, use_shade, base, cs, geo, inv, img,
                   sat, tile_sat, band, counts, lab, held, fill):
    """Sample the quads of square ``sq`` (``unit`` voxels a side, from voxel (a0, b0); a cell's index when
    ``unit`` is a cell) that their cells' flags ask for, at the pixels
    whose point on the slice plane lies in them (each pixel of the slice falls in one quad), and composite the
    samples front to back. ``inv``: the slice's inverse projection when orthographic (:func:`_ortho_inverse`).
    One function of over 60 lines: its per-pixel loop is the scan's inner loop, inlined by LLVM, with the
    flags' test and the sample (:func:`_sample`) in it."""
    density, gm, nrm, offs, n_a, n_b, c, _ = voxel
    oa, ob, cbase, tab = offs[0], offs[1], offs[2], offs[4]
    bi, y0b, y1b, et, satab, ty0 = band
    coef, persp = geo.coef, geo.persp
    nca = (n_a + CELL - 1) // CELL
    # the square's part of the slice plane: its quads [a0, a0 + unit) (the first from -0.5, the last to n - 0.5),
    # or a cell's last column or row only, when just a neighbour's voxels need them
    u0 = -0.5 if a0 == 0 else float(a0)
    u1 = min(float(a0 + unit), n_a - 0.5)
    v0 = -0.5 if b0 == 0 else float(b0)
    v1 = min(float(b0 + unit), n_b - 0.5)
    every = False                   # every quad of the square is needed: no per-pixel look-up of the flags
    if unit == CELL:
        flags = mark[sq]
        every = flags & 1 != 0
        if flags & 5 == 0:
            u0 = float(a0 + CELL - 1)
        if flags & 3 == 0:
            v0 = float(b0 + CELL - 1)
    if u0 >= u1 or v0 >= v1:
        return
    x0, x1, y0, y1 = _cell_pixels(u0, u1, v0, v1, base, coef, persp, img.shape[1], y0b, y1b)
    drawn = 0
    newly = 0
    for y in range(y0, y1 + 1):
        xa, xb = _row_pixels(y, persp, u0, u1, v0, v1, inv, x0, x1)
        for x in range(xa, xb + 1):
            if sat[np.uint64(y), np.uint64(x)] != 0:      # unsigned: no negative-index wrap-around
                continue
            ok, u, v, qa, qb = _pixel_quad(x, y, persp, base, coef, inv, u0, u1, v0, v1)
            if not ok:
                continue                    # another square's quad, or behind the near plane
            if not every:
                flags = mark[np.uint64((qb // CELL) * nca + qa // CELL)]
                la = qa % CELL
                lb = qb % CELL
                if not (flags & 1 or (la == CELL - 1 and flags & 2) or (lb == CELL - 1 and flags & 4)
                        or (la == CELL - 1 and lb == CELL - 1 and flags & 8)):
                    continue                # a quad no voxel of interest touches
            if geo.cuts.shape[0] > 0 and cut_away(u, v, geo.cuts, cs):
                continue
            if not _corners_held(held, np.uint64(cbase + _at(oa, qa) + _at(ob, qb))):
                continue                # a corner not loaded: the quad is transparent in truth
            fu, fv = max(u - qa, 0.0), max(v - qb, 0.0)
            done = 0            # a shown label's sample in front of the density's (isplat.splat.labels)
            if lab[0].shape[0] > 0:
                done = sample_label(x, y, fu, fv, qa, qb, c, u, v, lab, n_a, n_b, shade, use_shade, base, geo, img,
                                    sat, tile_sat, et, fill)
            if done < 2:
                done = max(done, _sample(x, y, fu, fv, cbase + _at(oa, qa) + _at(ob, qb),
                                         _step(oa, qa, n_a), _step(ob, qb, n_b), u, v,
                                         density, gm, nrm, alpha, color, shade, use_gm, use_shade, base, geo, img,
                                         sat, tile_sat, et, fill, _taps(qa, qb, voxel), tab))
            drawn += done > 0
            newly += done > 1
    counts[0] += drawn
    counts[1] += newly


def _corners_held(held, i00):
    """Whether the four corners of the quad whose first corner is the voxel of flat index ``i00`` (brick-major
    for a pool) are loaded: its bit in ``held = (bits, table)``, at the voxel's place in the bits' layout
    (:func:`_row_place`; ``table`` a pool's brick table, None for whole-shape channels); the bits
    :func:`held_pool`'s (the rows' layout, also when the channels' rows are packed) or :func:`held_quads`'; one
    load of 1/8 byte a voxel, tested on every quad sampled. Compiled, the choice is the type's (the overload
    below): with ``held`` None (every voxel loaded) the test is the constant True, and the frames' kernel is the
    one without it, bit for bit as before."""
    if held is None:
        return True
    i = _row_place(held[1], np.uint64(i00))
    return (held[0][i >> np.uint64(3)] >> (i & np.uint64(7))) & np.uint8(1) != 0


@overload(_corners_held, inline="always")
def _typed_corners_held(held, i00):
    if isinstance(held, types.NoneType):
        return lambda held, i00: True

    def test(held, i00):
        i = _row_place(held[1], np.uint64(i00))
        return (held[0][i >> np.uint64(3)] >> (i & np.uint64(7))) & np.uint8(1) != 0
    return test


def _row_place(table, i):
    """The place of the voxel of flat index ``i`` (uint64) in a pool's rows' layout: its brick's row
    (``table``, uint32 per brick, isplat.selection.WholeChannels) times 512 plus its place in the brick; ``i``
    itself without a table (None, whole-shape channels). (A table rather than :meth:`deltas`: 4 bytes a brick
    held, not 8, for one shift and an or more.)"""
    if table is None:
        return i
    return np.uint64(int(table[int(i) >> POOL_SHIFT]) << POOL_SHIFT | (int(i) & (POOL_EDGE ** 3 - 1)))


@overload(_row_place, inline="always")
def _typed_row_place(table, i):
    if isinstance(table, types.NoneType):
        return lambda table, i: i
    return lambda table, i: (np.uint64(table[i >> np.uint64(POOL_SHIFT)]) << np.uint64(POOL_SHIFT)) | (
        i & np.uint64(POOL_EDGE ** 3 - 1))


@leaf(inline="always")    # numba inlines its IR, not LLVM: see isplat.jit.leaf
def _row_pixels(y, persp, u0, u1, v0, v1, inv, x0, x1):
    """The pixels ``xa, xb`` of row ``y`` of the box [x0, x1] that a scan of [u0, u1) x [v0, v1) of the slice
    plane looks at: all in perspective, :func:`_row_span`'s when orthographic (the per-row span of
    :func:`_sample_square` and :func:`isplat.splat.mip._unit`)."""
    if persp:
        return x0, x1
    return _row_span(y, u0, u1, v0, v1, inv, x0, x1)


@leaf(inline="always")    # numba inlines its IR, not LLVM: see isplat.jit.leaf
def _pixel_quad(x, y, persp, base, coef, inv, u0, u1, v0, v1):
    """The exact per-pixel test of a scan (:func:`_sample_square`, :func:`isplat.splat.mip._unit`): ``ok, u, v,
    qa, qb``, the point (u, v) of the slice plane that pixel (x, y) sees (perspective: :func:`_slice_point`;
    orthographic: the inverse map ``inv``, :func:`_ortho_inverse`) and the quad (qa, qb) that holds it; ``ok``
    False (and no quad) when it is not in [u0, u1) x [v0, v1) or is at or behind the near plane."""
    if persp:
        ok, u, v = _slice_point(x, y, base, coef)
        if not ok:
            return False, u, v, 0, 0
    else:
        u = inv[0] + x * inv[1] + y * inv[2]
        v = inv[3] + x * inv[4] + y * inv[5]
    if u < u0 or u >= u1 or v < v0 or v >= v1:
        return False, u, v, 0, 0
    return True, u, v, max(int(u + 1.0) - 1, 0), max(int(v + 1.0) - 1, 0)     # floor: u, v >= -0.5 here


@leaf(inline="always")    # numba inlines its IR, not LLVM: see isplat.jit.leaf
def _row_span(y, u0, u1, v0, v1, inv, x0, x1):
    """The pixels of row ``y`` (within [x0, x1]) whose point on the slice plane can lie in [u0, u1) x [v0, v1)
    (orthographic; SPAN_MARGIN pixels of margin on each side for rounding, the exact test is per pixel)."""
    lo, hi = _span(inv[0] + y * inv[2], inv[1], inv[6], u0, u1, float(x0), float(x1))
    lo, hi = _span(inv[3] + y * inv[5], inv[4], inv[7], v0, v1, lo, hi)
    if lo > hi:
        return 1, 0
    return max(int(math.ceil(lo)), x0), min(int(math.floor(hi)), x1)


@leaf(inline="always")    # numba inlines its IR, not LLVM: see isplat.jit.leaf
def _span(o, d, r, a, b, lo, hi):
    """[lo, hi] cut to the x where ``o + x d`` lies in [a, b) (``r = 1 / d``, 0 when d is about 0), with
    SPAN_MARGIN pixels of margin."""
    if r != 0.0:
        t0 = (a - o) * r
        t1 = (b - o) * r
        return max(lo, min(t0, t1) - SPAN_MARGIN), min(hi, max(t0, t1) + SPAN_MARGIN)
    if o < a or o >= b:
        return 1.0, 0.0
    return lo, hi


def _phys(tab, i):
    """Where the voxel of flat index ``i`` (uint64) is in the channels: ``i`` itself without a brick table
    (``tab`` None), else in its brick's row of the pool: ``i`` plus its brick's entry of the pool's delta table
    (uint64, modulo 2^64: :meth:`isplat.selection.WholeChannels.deltas`; a shift, a load and an add). Compiled
    (the overload below), None is a type of its own: the kernel of whole channels is compiled without the table,
    the pool's with it. Tried, and slower (docs/design.md): a table of rows (two more operations a corner), a
    branch per quad for the corners in one brick, a quad's corners kept for its next pixels."""
    if tab is None:
        return i
    return np.uint64((int(i) + int(tab[int(i) >> POOL_SHIFT])) % 2 ** 64)


@overload(_phys, inline="always")
def _typed_phys(tab, i):
    if isinstance(tab, types.NoneType):
        return lambda tab, i: i
    return lambda tab, i: i + tab[i >> np.uint64(POOL_SHIFT)]


def _at(o, q):
    """The flat index's share of place ``q`` along an axis: ``o[q]`` of a table (isplat.grid.flat_offsets), or
    ``q * o`` of a stride (whole channels in C order: the kernel then multiplies, as before the pools)."""
    return q * o if isinstance(o, (int, np.integer)) else o[q]


def _step(o, q, n):
    """The flat index's step from place ``q`` to ``q + 1`` along an axis of ``n`` places, 0 at the last (the edge
    voxel repeated): a table's (isplat.selection's have one more entry, the last repeated) or a stride's."""
    if isinstance(o, (int, np.integer)):
        return o * (q + 1 < n)
    return o[q + 1] - o[q]


@overload(_step, inline="always")
def _typed_step(o, q, n):
    if isinstance(o, types.Integer):        # (no conditional expression: numba's inlined IR warns of its phi)
        return lambda o, q, n: o * (q + 1 < n)
    return lambda o, q, n: o[q + 1] - o[q]


@overload(_at, inline="always")
def _typed_at(o, q):
    if isinstance(o, types.Integer):
        return lambda o, q: q * o
    return lambda o, q: o[q]


@leaf(forceinline=True)
def _sample(x, y, fu, fv, i00, sa, sb, u, v, density, gm, nrm, alpha, color, shade, use_gm, use_shade, base, geo,
            img, sat, tile_sat, et, fill, taps, tab):
    """One sample: the density of the quad at ``i00`` (next voxels ``sa``, ``sb`` away: 0 at the
    volume's edge, which repeats the edge voxel) at (fu, fv) in it (bilinear, or cubic along a thick axis:
    ``taps``, :func:`_taps`, :func:`_density_at`), classified with the tables interpolated
    between codes, shaded with the corners' Phong factors (weighted by their gradient magnitudes too when
    ``use_shade == 2``), composited over pixel (x, y). Returns 0 when
    transparent, 1 when composited, 2 when the pixel then reached the early-termination opacity (``fill``:
    :func:`isplat.splat.composite.saturated`)."""
    if SAMPLE_STAGES == 0:
        return 0
    if SAMPLE_STAGES < 4:
        et = 2.0                        # no pixel saturates
    vi00 = np.uint64(i00)
    vi10 = vi00 + np.uint64(sa)
    vi01 = vi00 + np.uint64(sb)
    vi11 = vi01 + np.uint64(sa)
    i00, i10, i01, i11 = _phys(tab, vi00), _phys(tab, vi10), _phys(tab, vi01), _phys(tab, vi11)
    if taps is None:            # _density_at's bilinear, on the corners translated once for every channel
        d = ((1.0 - fu) * (1.0 - fv) * density[i00] + fu * (1.0 - fv) * density[i10]
             + (1.0 - fu) * fv * density[i01] + fu * fv * density[i11])
    else:
        d = _density_at(density, vi00, sa, sb, fu, fv, taps, tab)
    if SAMPLE_STAGES == 1:
        return 1 if d == 300.5 else 0      # never: keeps the gather without compositing
    # unsigned indices: numba adds no negative-index wrap-around to them (all are >= 0 here)
    w00 = (1.0 - fu) * (1.0 - fv)
    w10 = fu * (1.0 - fv)
    w01 = (1.0 - fu) * fv
    w11 = fu * fv
    k = min(int(d), 254)
    f = d - k                   # from the signed code: one conversion (an unsigned one takes five)
    di = np.uint64(k)
    ng = np.uint64(alpha.shape[1] // 2)     # (:func:`lerp_tables`) opacities, then their steps to the next code
    g = np.uint64(0)
    if use_gm:
        g = np.uint64(min(int(w00 * gm[i00] + w10 * gm[i10] + w01 * gm[i01] + w11 * gm[i11] + 0.5),
                          alpha.shape[1] // 2 - 1))
    L = alpha[di, g] + f * alpha[di, ng + g]
    if L == 0.0:
        return 0
    a = L                       # orthographic: the table is corrected for the slices' path already
    if geo.persp:
        a, _ = path_alpha(L, u, v, base, geo.steps, geo.persp, geo.inv_unit, geo.coef, geo.eye)
    c0, c1, c2 = np.uint64(0), np.uint64(1), np.uint64(2)
    if SAMPLE_STAGES == 2:         # the opacity alone composited (for measuring only)
        return _composite(img, sat, tile_sat, x, y, a, et, fill, 0.0, 0.0, 0.0, False)
    cr = color[di, c0] + f * color[di, np.uint64(3)]
    cg = color[di, c1] + f * color[di, np.uint64(4)]
    cb = color[di, c2] + f * color[di, np.uint64(5)]
    if use_shade and taps is not None and taps[4] != 0:   # a thick axis: the B-spline's weights along it
        cr, cg, cb = _shade_between(cr, cg, cb, nrm, gm, shade, vi00, vi10, vi01, vi11, fu, fv, taps, use_shade,
                                    tab)
    elif use_shade:
        n00, n10, n01, n11 = nrm[i00], nrm[i10], nrm[i01], nrm[i11]
        if use_shade == 2:      # weighted by the gradient magnitudes: a corner off the surface (air, a short
            v00 = w00 * gm[i00]     # gradient whose direction is mostly the slices') counts for little
            v10 = w10 * gm[i10]
            v01 = w01 * gm[i01]
            v11 = w11 * gm[i11]
            wsum = v00 + v10 + v01 + v11
            if wsum > 0.0:
                r = 1.0 / wsum
                w00, w10, w01, w11 = v00 * r, v10 * r, v01 * r, v11 * r
        s0 = w00 * shade[n00, 0] + w10 * shade[n10, 0] + w01 * shade[n01, 0] + w11 * shade[n11, 0]
        s1 = w00 * shade[n00, 1] + w10 * shade[n10, 1] + w01 * shade[n01, 1] + w11 * shade[n11, 1]
        if shade.shape[1] == 6:
            s2 = w00 * shade[n00, 2] + w10 * shade[n10, 2] + w01 * shade[n01, 2] + w11 * shade[n11, 2]
            s3 = w00 * shade[n00, 3] + w10 * shade[n10, 3] + w01 * shade[n01, 3] + w11 * shade[n11, 3]
            s4 = w00 * shade[n00, 4] + w10 * shade[n10, 4] + w01 * shade[n01, 4] + w11 * shade[n11, 4]
            s5 = w00 * shade[n00, 5] + w10 * shade[n10, 5] + w01 * shade[n01, 5] + w11 * shade[n11, 5]
            cr, cg, cb = cr * s0 + s3, cg * s1 + s4, cb * s2 + s5
        else:
            cr, cg, cb = cr * s0 + s1, cg * s0 + s1, cb * s0 + s1
    return _composite(img, sat, tile_sat, x, y, a, et, fill, cr, cg, cb, True)


@leaf(inline="always")    # numba inlines its IR, not LLVM: see isplat.jit.leaf
def _composite(img, sat, tile_sat, x, y, a, et, fill, cr, cg, cb, colour):
    """Composite opacity ``a`` (and, ``colour`` True, the colour (cr, cg, cb) times it) over pixel (x, y), front
    to back; 2 when the pixel then reached the early-termination opacity ``et`` (marked in ``sat`` and its tile's
    count, the rest filled with the colour when ``fill``: :func:`isplat.splat.composite.saturated`), else 1.
    ``colour`` False: the opacity alone (``SAMPLE_STAGES == 2``, for measuring only)."""
    uy, ux = np.uint64(y), np.uint64(x)
    if colour:                  # the four channels in the lanes of one vector (isplat.jit.over4)
        ai, an = over4(img, uy, ux, a, cr, cg, cb)
    else:
        ai = float(img[uy, ux, np.uint64(3)])
        an = ai + (1.0 - ai) * a
        img[uy, ux, np.uint64(3)] = an
    if ai < et and an >= et:
        saturated(img, sat, tile_sat, x, y, an, cr, cg, cb, fill)
        return 2
    return 1


def _taps(qa, qb, voxel):
    """What :func:`_density_at` needs of quad (qa, qb) beyond its corners (:func:`_thick_taps`), or None
    without a thick axis (``voxel[7]``, :data:`PostClassify`'s ``between``, None). Compiled, the choice is the
    type's (the overload below): a sample of a frame without a thick axis is compiled with ``taps`` None, and
    numba prunes the branches on ``taps is None`` (:func:`_sample`, :func:`_density_at`) before typing it."""
    return None if voxel[7] is None else _thick_taps(qa, qb, voxel)


@overload(_taps, inline="always")
def _typed_taps(qa, qb, voxel):
    if isinstance(voxel[7], types.NoneType):
        return lambda qa, qb, voxel: None
    return lambda qa, qb, voxel: _thick_taps(qa, qb, voxel)


@leaf(inline="always")    # numba inlines its IR, not LLVM: see isplat.jit.leaf
def _thick_taps(qa, qb, voxel):
    """:func:`_taps` along a thick axis: ``(axis, kind, back, fwd, shade, q, n, s)``, the thick axis and the
    cubic's kind (``voxel[7]``), the steps from the quad's first corner to the voxel before it and to the voxel two
    after it along that axis, clamped to the volume (the edge voxel repeated; 0 steps back at the first voxel),
    whether the shading follows (:func:`_shade_between`), and the quad's place along that axis, the voxels along
    it and its offsets table (``voxel[3]``'s ``oa`` or ``ob``: the spline's wider taps, :func:`_spline_at`). The
    steps are differences of that table (brick-major channels have no one stride), and hold for any row across:
    the index is a sum of one term per axis (isplat.grid.flat_offsets). (0, ..., 0): bilinear. The slices of a
    slab (:mod:`isplat.slabs`) hold whole slices, so a and b reach the volume's edges there too."""
    offs, n_a, n_b, between = voxel[3], voxel[4], voxel[5], voxel[7]
    t = between[0]
    s = offs[0]
    if t == 0:
        return 0, 0, 0, 0, 0, 0, 1, s
    q, n = qa, n_a
    if t == 2:
        q, n, s = qb, n_b, offs[1]
    q = min(max(q, 0), n - 1)
    return (t, between[1], _at(s, q) - _at(s, q - 1) if q > 0 else 0, _at(s, min(q + 2, n - 1)) - _at(s, q),
            between[2], q, n, s)


@leaf(forceinline=True)
def _density_at(density, i00, sa, sb, fu, fv, taps, tab):
    """The density of the quad whose first voxel is at ``i00`` of the density channel (its next voxels ``sa``
    and ``sb`` away; 0 at the volume's edge) at (fu, fv) in [0, 1) in it: the one place a sample reads the
    densities. Bilinear when ``taps`` is None or ``taps[0]`` is 0 (isotropic data render bit for bit as
    before; None: numba prunes the cubic out before typing); else a cubic
    (:func:`cubic`, kind ``taps[1]``) along the thick axis (1 a, 2 b) through the voxel before the quad
    (``taps[2]`` back), its two corners and the voxel after (``taps[3]`` on) in each of the quad's two rows (or
    columns), then linear between those two (:func:`_taps`); kind 2 the interpolating spline through the
    2 SPLINE_REACH voxels around the sample in each (:func:`_spline_at`)."""
    i00 = np.uint64(i00)                # unsigned: no negative-index wrap-around (all are >= 0 here)
    i10 = i00 + np.uint64(sa)
    i01 = i00 + np.uint64(sb)
    i11 = i01 + np.uint64(sa)
    if taps is None or taps[0] == 0:
        return ((1.0 - fu) * (1.0 - fv) * density[_phys(tab, i00)] + fu * (1.0 - fv) * density[_phys(tab, i10)]
                + (1.0 - fu) * fv * density[_phys(tab, i01)] + fu * fv * density[_phys(tab, i11)])
    if taps[1] == 2:      # the interpolating spline: the two rows (or columns) across, then linear
        if taps[0] == 1:
            r0, r1 = _spline_at(density, i00, i01, fu, taps, tab)
            return (1.0 - fv) * r0 + fv * r1
        c0, c1 = _spline_at(density, i00, i10, fv, taps, tab)
        return (1.0 - fu) * c0 + fu * c1
    back, fwd = np.uint64(taps[2]), np.uint64(taps[3])
    if taps[0] == 1:      # rows along a from i00 and from i01, then linear along b
        r0 = cubic(density[_phys(tab, i00 - back)], density[_phys(tab, i00)], density[_phys(tab, i10)],
                   density[_phys(tab, i00 + fwd)], fu, taps[1])
        r1 = cubic(density[_phys(tab, i01 - back)], density[_phys(tab, i01)], density[_phys(tab, i11)],
                   density[_phys(tab, i01 + fwd)], fu, taps[1])
        return (1.0 - fv) * r0 + fv * r1
    c0 = cubic(density[_phys(tab, i00 - back)], density[_phys(tab, i00)], density[_phys(tab, i01)],
               density[_phys(tab, i00 + fwd)], fv, taps[1])
    c1 = cubic(density[_phys(tab, i10 - back)], density[_phys(tab, i10)], density[_phys(tab, i11)],
               density[_phys(tab, i10 + fwd)], fv, taps[1])
    return (1.0 - fu) * c0 + fu * c1


@leaf(inline="always")    # numba inlines its IR, not LLVM: see isplat.jit.leaf
def _spline_at(density, i0, i1, f, taps, tab):
    """The interpolating cubic spline (:data:`SPLINE_KERNEL`) along the thick axis at fraction ``f`` past the
    voxels at ``i0`` and ``i1`` (two rows, or columns; the quad's place ``taps[5]`` of ``taps[6]`` voxels along
    it, offsets table ``taps[7]``; each voxel through the brick table ``tab``, :func:`_phys`): the 2 SPLINE_REACH
    voxels around each (clamped to the volume, the edge voxel repeated)
    with the kernel's weights renormalised to sum to 1 (the voxel itself at f = 0), clamped to the codes 0..255."""
    q, n, s = taps[5], taps[6], taps[7]
    f2 = f * f
    f3 = f2 * f
    v0 = v1 = wsum = 0.0
    for r in range(2 * SPLINE_REACH):
        w = SPLINE_KERNEL[r, 0] + f * SPLINE_KERNEL[r, 1] + f2 * SPLINE_KERNEL[r, 2] + f3 * SPLINE_KERNEL[r, 3]
        off = _at(s, min(max(q + r + 1 - SPLINE_REACH, 0), n - 1)) - _at(s, q)
        v0 += w * density[_phys(tab, np.uint64(np.int64(i0) + off))]
        v1 += w * density[_phys(tab, np.uint64(np.int64(i1) + off))]
        wsum += w
    r = 1.0 / wsum
    return min(max(v0 * r, 0.0), 255.0), min(max(v1 * r, 0.0), 255.0)


@leaf(inline="always")    # numba inlines its IR, not LLVM: see isplat.jit.leaf
def _shade_between(cr, cg, cb, nrm, gm, shade, i00, i10, i01, i11, fu, fv, taps, use_shade, tab):
    """The colour shaded with the Phong factors of the eight voxels around the sample along a thick axis
    (``taps``, :func:`_taps`): the cubic B-spline's weights along it (positive, C2: the shading has no kink at
    the slices), linear across, each times the voxel's gradient magnitude code when ``use_shade`` is 2
    (normalised; unweighted where all are 0)."""
    back, fwd = np.uint64(taps[2]), np.uint64(taps[3])
    f, g, r1, o1 = fu, fv, i01, i10 - i00
    if taps[0] == 2:
        f, g, r1, o1 = fv, fu, i10, i01 - i00
    f2 = f * f
    f3 = f2 * f
    bw = ((1.0 - f) * (1.0 - f) * (1.0 - f) / 6.0, (3.0 * f3 - 6.0 * f2 + 4.0) / 6.0,
          (-3.0 * f3 + 3.0 * f2 + 3.0 * f + 1.0) / 6.0, f3 / 6.0)
    ra, rb = i00, r1
    idx = (ra - back, ra, ra + o1, ra + fwd, rb - back, rb, rb + o1, rb + fwd)
    wts = ((1.0 - g) * bw[0], (1.0 - g) * bw[1], (1.0 - g) * bw[2], (1.0 - g) * bw[3], g * bw[0], g * bw[1],
           g * bw[2], g * bw[3])
    s0 = s1 = s2 = s3 = s4 = s5 = wsum = 0.0
    for p in range(2):          # weighted by the gradient magnitudes; unweighted where those weights are all 0
        weighted = use_shade == 2 and p == 0
        s0 = s1 = s2 = s3 = s4 = s5 = wsum = 0.0
        for k in range(8):
            i = _phys(tab, idx[k])
            w = wts[k] * gm[i] if weighted else wts[k]
            n = nrm[i]
            wsum += w
            s0 += w * shade[n, 0]
            s1 += w * shade[n, 1]
            if shade.shape[1] == 6:
                s2 += w * shade[n, 2]
                s3 += w * shade[n, 3]
                s4 += w * shade[n, 4]
                s5 += w * shade[n, 5]
        if wsum > 0.0:
            break
    r = 1.0 / wsum
    if shade.shape[1] == 6:
        return cr * s0 * r + s3 * r, cg * s1 * r + s4 * r, cb * s2 * r + s5 * r
    return cr * s0 * r + s1 * r, cg * s0 * r + s1 * r, cb * s0 * r + s1 * r


@leaf(inline="always")    # numba inlines its IR, not LLVM: see isplat.jit.leaf
def cubic(pm, p0, p1, p2, t, kind):
    """The cubic Hermite between ``p0`` (t = 0) and ``p1`` (t = 1) with neighbours ``pm`` before and ``p2``
    after. ``kind`` 0: monotone (Fritsch and Butland 1984: each knot's slope the harmonic mean of its two
    secants, 0 where they differ in sign; at most twice the smaller secant, so the curve is C1 and never leaves
    [min(p0, p1), max(p0, p1)]); 1: Catmull-Rom (slopes the central differences), clamped to the codes 0..255."""
    pm, p0, p1, p2 = float(pm), float(p0), float(p1), float(p2)
    d0, d1, d2 = p0 - pm, p1 - p0, p2 - p1
    if kind == 0:
        m0 = 2.0 * d0 * d1 / (d0 + d1) if d0 * d1 > 0.0 else 0.0
        m1 = 2.0 * d1 * d2 / (d1 + d2) if d1 * d2 > 0.0 else 0.0
    else:
        m0, m1 = 0.5 * (d0 + d1), 0.5 * (d1 + d2)
    t2 = t * t
    t3 = t2 * t
    v = (2.0 * t3 - 3.0 * t2 + 1.0) * p0 + (t3 - 2.0 * t2 + t) * m0 + (3.0 * t2 - 2.0 * t3) * p1 + (t3 - t2) * m1
    return min(max(v, 0.0), 255.0)


@leaf(inline="always")    # numba inlines its IR, not LLVM: see isplat.jit.leaf
def _slice_point(x, y, base, coef):
    """The point (u, v) of the slice plane (in-slice voxel coordinates a, b) that pixel (x, y) sees in
    perspective: the §3 projection inverted; ``ok`` False when it is at or behind the near plane."""
    xs, ys, ws = base[0], base[1], base[2]
    X = x - coef[CX]
    Y = y - coef[CY]
    m00 = X * coef[WA] - coef[WPE] * coef[XA]
    m01 = X * coef[WB] - coef[WPE] * coef[XB]
    m10 = Y * coef[WA] - coef[WPE] * coef[YA]
    m11 = Y * coef[WB] - coef[WPE] * coef[YB]
    r0 = coef[WPE] * xs - X * ws
    r1 = coef[WPE] * ys - Y * ws
    det = m00 * m11 - m01 * m10
    if det == 0.0:
        return False, 0.0, 0.0
    u = (r0 * m11 - m01 * r1) / det
    v = (m00 * r1 - m10 * r0) / det
    return -(ws + u * coef[WA] + v * coef[WB]) >= coef[NEAR], u, v


@leaf
def _ortho_inverse(base, coef):
    """The orthographic slice's pixel -> (u, v) map ``(u0, du/dx, du/dy, v0, dv/dx, dv/dy)`` and the
    reciprocals of du/dx and dv/dx (0 when about 0)."""
    det = coef[XA] * coef[YB] - coef[XB] * coef[YA]
    if det == 0.0:
        return (0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0)    # the slice is seen edge-on: no pixel sees it
    ux, uy = coef[YB] / det, -coef[XB] / det
    vx, vy = -coef[YA] / det, coef[XA] / det
    return (-(ux * base[0] + uy * base[1]), ux, uy, -(vx * base[0] + vy * base[1]), vx, vy,
            1.0 / ux if abs(ux) > 1e-12 else 0.0, 1.0 / vx if abs(vx) > 1e-12 else 0.0)


@leaf
def _cell_pixels(u0, u1, v0, v1, base, coef, persp, img_w, y0b, y1b):
    """The pixels (x0, x1, y0, y1) whose centres can see the part [u0, u1) x [v0, v1) of the slice plane, with up
    to a pixel of margin, clipped to the image and the band (the whole band when a corner is behind the near
    plane); empty when x0 > x1."""
    ok, cx0, cx1, cy0, cy1, _ = rect_hull(u0, u1, v0, v1, base, coef, persp)
    if not ok:
        return 0, img_w - 1, y0b, y1b - 1
    return _pixel_box(cx0, cx1, cy0, cy1, img_w, y0b, y1b)


@leaf(inline="always")    # numba inlines its IR, not LLVM: see isplat.jit.leaf
def _pixel_box(cx0, cx1, cy0, cy1, img_w, y0b, y1b):
    """The pixels (x0, x1, y0, y1) of the image and the band (rows [y0b, y1b)) whose centres lie in the box
    [cx0, cx1] x [cy0, cy1] of the image plane, grown by SPAN_MARGIN for rounding (a pixel centre on the edge
    belongs to the square by the exact test per pixel, which the inverse map decides); empty: x0 > x1
    (:func:`_cell_pixels`, :func:`isplat.splat.mip._ortho_rect_box`)."""
    if cx1 < 0.0 or cy1 < y0b or cx0 > img_w - 1 or cy0 > y1b - 1:
        return 1, 0, 1, 0
    return (max(int(math.ceil(cx0 - SPAN_MARGIN)), 0), min(int(math.floor(cx1 + SPAN_MARGIN)), img_w - 1),
            max(int(math.ceil(cy0 - SPAN_MARGIN)), y0b), min(int(math.floor(cy1 + SPAN_MARGIN)), y1b - 1))


register(PostPlan, _scratch, _slice)
