"""Segmentation labels in the post-classified technique (docs/labels.md): per sample, which shown label the point
belongs to and that label's surface normal, then its colour composited in front of the density's sample.

Labels are never blended: at a sample (the point ``(a0 + fu, b0 + fv)`` of slice ``c``, in the quad of voxels
``(a0, b0) .. (a0 + 1, b0 + 1)``) each shown label ``L`` among the quad's four voxels gets the bilinear weight of
its indicator (the sum of the weights of the corners whose id is ``L``); the point belongs to the label of the
largest weight when that weight is above 1/2, else to none. So a label's boundary is the 1/2 level line of its
interpolated indicator: smooth, not the voxels' squares. Its shading: each voxel of a shown label carries the
normal of its label's indicator smoothed by a Gaussian of one voxel (:func:`isplat.labels.label_normals`,
computed when the selection is made), and a sample takes the Phong factors of its quad's corners of that label,
interpolated with their bilinear weights (renormalised), as the density's sample does with its corners. The
gradient of the plain (unsmoothed) indicator takes a handful of directions on a binary mask and shows every voxel
step as a facet; a one-voxel Gaussian first gives normals within a few degrees of the true surface's
(tests/test_labels.py).

The tuple ``lab`` the kernels take: ``(ids uint16[n] (the whole label channel, flat [k, j, i]; empty: no
labels), table float64[L, 4] (per id: r, g, b and the opacity as the frame's opacity table holds it: corrected
for the slices' path when orthographic, ``log1p(-opacity)`` in perspective; 0 for labels not shown), steps
int64[4] (the flat steps of a, b and c, and the number of slices), normals uint16[n] (oct16 codes, flat
[k, j, i]; empty when shading is off))``.
"""

from __future__ import annotations

import numpy as np

from ..jit import leaf
from .composite import saturated
from .traverse import path_alpha

NO_NORMAL = 0x8080


def no_labels():
    """The ``lab`` tuple of a frame without labels (the same types as one with them: one compilation)."""
    return np.zeros(0, np.uint16), np.zeros((1, 4), np.float64), np.zeros(4, np.int64), np.zeros(0, np.uint16)


@leaf
def label_at(ids, table, steps, n_a, n_b, a0, b0, c, fu, fv):
    """The shown label at the point ``(a0 + fu, b0 + fv)`` of slice ``c`` and its weight: ``(id, weight)``, id
    -1 when the point belongs to no shown label (the largest weight is not above 1/2). At the volume's last
    voxel along a or b the corner beyond is the edge voxel again (as the density's sample)."""
    sa, sb, sc = steps[0], steps[1], steps[2]
    da = sa if a0 + 1 < n_a else 0
    db = sb if b0 + 1 < n_b else 0
    i00 = c * sc + a0 * sa + b0 * sb
    best, bw = -1, 0.0
    for n in range(4):
        i = i00 + (da if n & 1 else 0) + (db if n & 2 else 0)
        lid = np.int64(ids[np.uint64(i)])
        if table[lid, 3] == 0.0 or lid == best:
            continue
        w = 0.0
        for m in range(4):
            j = i00 + (da if m & 1 else 0) + (db if m & 2 else 0)
            if np.int64(ids[np.uint64(j)]) == lid:
                w += (fu if m & 1 else 1.0 - fu) * (fv if m & 2 else 1.0 - fv)
        if w > bw:
            best, bw = lid, w
    if bw > 0.5:
        return best, bw
    return -1, bw


@leaf
def sample_label(x, y, fu, fv, qa, qb, c, u, v, lab, n_a, n_b, shade, use_shade, base, geo, img, sat, tile_sat,
                 et, fill):
    """Composite the shown label at the sample (if any) over pixel (x, y), shaded by its indicator's normal.
    Returns 0 (no label here), 1 (composited) or 2 (the pixel then reached the early-termination opacity,
    :func:`isplat.splat.composite.saturated` with ``fill``)."""
    ids, table, steps, nrm = lab
    lid, _ = label_at(ids, table, steps, n_a, n_b, qa, qb, c, fu, fv)
    if lid < 0:
        return 0
    a, _ = path_alpha(table[lid, 3], u, v, base, geo.steps, geo.persp, geo.inv_unit, geo.coef, geo.eye)
    cr, cg, cb = table[lid, 0], table[lid, 1], table[lid, 2]
    if use_shade:
        s0, s1, s2, s3, s4, s5 = _label_shade(ids, nrm, steps, shade, n_a, n_b, qa, qb, c, fu, fv, lid)
        if shade.shape[1] == 6:
            cr, cg, cb = cr * s0 + s3, cg * s1 + s4, cb * s2 + s5
        else:
            cr, cg, cb = cr * s0 + s1, cg * s0 + s1, cb * s0 + s1
    uy, ux = np.uint64(y), np.uint64(x)
    ai = img[uy, ux, 3]
    ta = (1.0 - ai) * a
    img[uy, ux, 0] += ta * cr
    img[uy, ux, 1] += ta * cg
    img[uy, ux, 2] += ta * cb
    img[uy, ux, 3] = ai + ta
    if ai < et and ai + ta >= et:
        saturated(img, sat, tile_sat, x, y, ai + ta, cr, cg, cb, fill)
        return 2
    return 1


@leaf
def _label_shade(ids, nrm, steps, shade, n_a, n_b, a0, b0, c, fu, fv, lid):
    """The Phong factors of label ``lid`` at the point: those of its corners of that label (their normals from
    :func:`isplat.labels.label_normals`), interpolated with their bilinear weights renormalised."""
    sa, sb, sc = steps[0], steps[1], steps[2]
    da = sa if a0 + 1 < n_a else 0
    db = sb if b0 + 1 < n_b else 0
    i00 = c * sc + a0 * sa + b0 * sb
    wsum, s0, s1, s2, s3, s4, s5 = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    wide = shade.shape[1] == 6
    for m in range(4):
        i = np.uint64(i00 + (da if m & 1 else 0) + (db if m & 2 else 0))
        if np.int64(ids[i]) != lid:
            continue
        w = (fu if m & 1 else 1.0 - fu) * (fv if m & 2 else 1.0 - fv)
        n = np.uint64(nrm[i])
        wsum += w
        s0 += w * shade[n, 0]
        s1 += w * shade[n, 1]
        if wide:
            s2 += w * shade[n, 2]
            s3 += w * shade[n, 3]
            s4 += w * shade[n, 4]
            s5 += w * shade[n, 5]
    if wsum > 0.0:
        r = 1.0 / wsum
        return s0 * r, s1 * r, s2 * r, s3 * r, s4 * r, s5 * r
    return s0, s1, s2, s3, s4, s5


def frame_table(table: np.ndarray, persp: bool, r: float) -> np.ndarray:
    """The label table (r, g, b, opacity per id) as a frame takes it: opacity corrected for the path length
    ``r`` unit distances (orthographic), or ``log1p(-opacity)`` (perspective), as the density's table."""
    from ..transfer import _ALPHA_MAX, corrected_alpha

    out = np.array(table, dtype=np.float64, copy=True)
    op = np.minimum(out[:, 3], _ALPHA_MAX)
    out[:, 3] = np.log1p(-op) if persp else corrected_alpha(op, r)
    return out
