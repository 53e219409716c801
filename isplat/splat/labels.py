"""Segmentation labels in the post-classified technique (docs/labels.md): per sample, which shown label the point
belongs to and that label's surface normal, then its colour composited in front of the density's sample.

Labels are never blended: at a sample (the point ``(a0 + fu, b0 + fv)`` of slice ``c``, in the quad of voxels
``(a0, b0) .. (a0 + 1, b0 + 1)``) each shown label ``L`` among the quad's four voxels gets the bilinear weight of
its indicator (the sum of the weights of the corners whose id is ``L``); the point belongs to the label of the
largest weight when that weight is above 1/2, else to none. So a label's boundary is the 1/2 level line of its
interpolated indicator: smooth, not the voxels' squares. Its normal is the gradient of the indicator, taken at
each corner by central differences (one-sided at the volume's edge) in physical units and interpolated with the
same bilinear weights (as a ray caster shades with gradients interpolated from the grid), encoded as an oct16
code so the frame's Phong table (:mod:`isplat.splat.shade`) shades it like a density normal.

The tuple ``lab`` the kernels take: ``(ids uint16[n] (the whole label channel, flat [k, j, i]; empty: no
labels), table float64[L, 4] (per id: r, g, b and the opacity as the frame's opacity table holds it: corrected
for the slices' path when orthographic, ``log1p(-opacity)`` in perspective; 0 for labels not shown), steps
int64[4] (the flat steps of a, b and c, and the number of slices), spacing float64[3] (of a, b, c), perm int64[3]
(which of i, j, k the axes a, b, c are))``.
"""

from __future__ import annotations

import numpy as np

from ..jit import leaf
from .composite import TILE
from .traverse import path_alpha

NO_NORMAL = 0x8080


def no_labels():
    """The ``lab`` tuple of a frame without labels (the same types as one with them: one compilation)."""
    return (np.zeros(0, np.uint16), np.zeros((1, 4), np.float64), np.zeros(4, np.int64), np.ones(3, np.float64),
            np.arange(3, dtype=np.int64))


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
def label_gradient(ids, steps, spacing, perm, n_a, n_b, a0, b0, c, fu, fv, lid):
    """The gradient of label ``lid``'s indicator at the point, along i, j, k in physical units: central
    differences at the quad's four corners (one-sided at the volume's edges), interpolated bilinearly."""
    g0, g1, g2 = 0.0, 0.0, 0.0      # along i, j, k (no arrays: a leaf allocates nothing)
    size = (n_a, n_b, steps[3])
    for m in range(4):
        w = (fu if m & 1 else 1.0 - fu) * (fv if m & 2 else 1.0 - fv)
        if w == 0.0:
            continue
        pos = (min(a0 + (m & 1), n_a - 1), min(b0 + (m >> 1), n_b - 1), c)
        here = pos[0] * steps[0] + pos[1] * steps[1] + c * steps[2]
        for ax in range(3):
            lo = max(pos[ax] - 1, 0)
            hi = min(pos[ax] + 1, size[ax] - 1)
            if hi == lo:
                continue
            base = here - pos[ax] * steps[ax]
            up = 1.0 if np.int64(ids[np.uint64(base + hi * steps[ax])]) == lid else 0.0
            down = 1.0 if np.int64(ids[np.uint64(base + lo * steps[ax])]) == lid else 0.0
            d = w * (up - down) / ((hi - lo) * spacing[ax])
            if perm[ax] == 0:
                g0 += d
            elif perm[ax] == 1:
                g1 += d
            else:
                g2 += d
    return g0, g1, g2


@leaf
def oct16(x, y, z):
    """The oct16 code of direction (x, y, z) (formats/augmented.md §5; rounded, not the precise encoder):
    NO_NORMAL for a zero vector."""
    s = abs(x) + abs(y) + abs(z)
    if s == 0.0:
        return NO_NORMAL
    px, py = x / s, y / s
    if z < 0.0:
        px, py = (1.0 - abs(py)) * (1.0 if px >= 0.0 else -1.0), (1.0 - abs(px)) * (1.0 if py >= 0.0 else -1.0)
    u = min(max(int(round(px * 127.0)), -127), 127)
    v = min(max(int(round(py * 127.0)), -127), 127)
    return ((u & 0xFF) << 8) | (v & 0xFF)


@leaf
def sample_label(x, y, fu, fv, qa, qb, c, u, v, lab, n_a, n_b, shade, use_shade, base, geo, img, sat, tile_sat,
                 et):
    """Composite the shown label at the sample (if any) over pixel (x, y), shaded by its indicator's normal.
    Returns 0 (no label here), 1 (composited) or 2 (the pixel then reached the early-termination opacity)."""
    ids, table, steps, spacing, perm = lab
    lid, _ = label_at(ids, table, steps, n_a, n_b, qa, qb, c, fu, fv)
    if lid < 0:
        return 0
    a, _ = path_alpha(table[lid, 3], u, v, base, geo.steps, geo.persp, geo.inv_unit, geo.coef, geo.eye)
    cr, cg, cb = table[lid, 0], table[lid, 1], table[lid, 2]
    if use_shade:
        g0, g1, g2 = label_gradient(ids, steps, spacing, perm, n_a, n_b, qa, qb, c, fu, fv, lid)
        n = np.uint64(oct16(g0, g1, g2))
        if shade.shape[1] == 6:
            cr = cr * shade[n, 0] + shade[n, 3]
            cg = cg * shade[n, 1] + shade[n, 4]
            cb = cb * shade[n, 2] + shade[n, 5]
        else:
            cr, cg, cb = cr * shade[n, 0] + shade[n, 1], cg * shade[n, 0] + shade[n, 1], cb * shade[n, 0] + shade[n, 1]
    uy, ux = np.uint64(y), np.uint64(x)
    ai = img[uy, ux, 3]
    ta = (1.0 - ai) * a
    img[uy, ux, 0] += ta * cr
    img[uy, ux, 1] += ta * cg
    img[uy, ux, 2] += ta * cb
    img[uy, ux, 3] = ai + ta
    if ai < et and ai + ta >= et:
        sat[uy, ux] = 1
        tile_sat[y // TILE, x // TILE] += 1
        return 2
    return 1


def frame_table(table: np.ndarray, persp: bool, r: float) -> np.ndarray:
    """The label table (r, g, b, opacity per id) as a frame takes it: opacity corrected for the path length
    ``r`` unit distances (orthographic), or ``log1p(-opacity)`` (perspective), as the density's table."""
    from ..transfer import _ALPHA_MAX, corrected_alpha

    out = np.array(table, dtype=np.float64, copy=True)
    op = np.minimum(out[:, 3], _ALPHA_MAX)
    out[:, 3] = np.log1p(-op) if persp else corrected_alpha(op, r)
    return out
