"""A slow, obvious reference for image-aligned sheets (isplat.splat.sheets): every voxel, every slab, every
pixel, float64, no tables, no buckets.

The same model as the compiled kernel, computed directly: positions through camera.project_points, depth as
the distance along the view direction, the kernel's 3-D covariance in (pixel, pixel, depth) coordinates from
finite differences of that projection, its marginal footprint (widened to MIN_SIGMA_PIXELS) from the Gaussian
formula, the depth given the pixel offset from the conditional Gaussian, the slab integral from the error
function (math.erf), shading from decoded normals and the Phong formula.
"""

from __future__ import annotations

import math

import numpy as np

erf = np.vectorize(math.erf)

from isplat import camera as C
from isplat.augfile import open_augmented
from isplat.normals import decode
from isplat.splat.footprint import MIN_SIGMA_PIXELS
from isplat.transfer import piecewise_linear
from phong_reference import camera_lights, phong


def _covariance(frame, geom, sigma, origin):
    """sigma^2 J3 J3^T with J3 the motion of (x, y, depth) per grid step (i, j, k), by finite differences at
    the view's reference point."""
    h = 1e-6

    def xyz(X):
        x, y = C.project_points(frame, [X])[0]
        return np.array([x, y, -float((X - origin) @ frame.w)])

    p0 = xyz(frame.p)
    J3 = np.stack([(xyz(frame.p + h * geom.steps[ax]) - p0) / h for ax in range(3)], axis=1)
    return sigma ** 2 * (J3 @ J3.T), abs(np.linalg.det(J3))


def reference_sheets(scene, view=0, et=1.0):
    aug = open_augmented(scene.data.augmented)
    dens = aug.read("density").astype(np.int64)
    gm = aug.read("gradient_magnitude").astype(np.int64)
    nrm = aug.read("normal")
    sp = scene.volume.spacing or aug.spacing_ijk
    geom = C.volume_geometry(aug.shape, sp, scene.volume.origin, scene.volume.axes)
    W, H = scene.image.width, scene.image.height
    frame = C.view_frame(scene.views[view], geom, W, H)
    tr, ro, sh = scene.transfer, scene.render, scene.shading
    unit = tr.unit_distance or float(geom.spacing.min())
    persp = frame.projection == "perspective"
    origin = frame.e if persp else frame.p
    d_img = float((frame.e - frame.p) @ frame.w) if persp else 1.0

    M, V = _covariance(frame, geom, ro.footprint_sigma, origin)
    lam, vec = np.linalg.eigh(M[:2, :2])
    Sxy = (vec * np.maximum(lam, MIN_SIGMA_PIXELS ** 2)) @ vec.T
    Qi = np.linalg.inv(Sxy)
    g = np.linalg.solve(Sxy, M[:2, 2])
    s_c = math.sqrt(M[2, 2] - g @ M[:2, 2])
    R = ro.footprint_radius
    ext = R * (s_c + math.sqrt(g @ Sxy @ g))
    thick = float(geom.spacing.min())
    assert 2 * ext / thick <= 48, "the reference does not thicken slabs"
    norm = V / thick / (2 * math.pi * math.sqrt(np.linalg.det(Sxy))) / (1 - math.exp(-R * R / 2))

    def cdf(t):       # the normal CDF cut at +-R, rescaled to 0..1
        u = np.clip(t, -R, R)
        return (erf(u / math.sqrt(2)) + erf(R / math.sqrt(2))) / (2 * erf(R / math.sqrt(2)))

    d = np.arange(256.0)
    opac = np.clip(piecewise_linear(tr.opacity, d, True)[:, 0], 0, 1)
    col = np.clip(piecewise_linear(tr.color, d, False), 0, 1)
    gfac = None
    if len(tr.gradient_opacity):
        gfac = np.clip(piecewise_linear(tr.gradient_opacity, d * aug.gradient_magnitude_scale, False)[:, 0], 0, 1)
    lights = camera_lights(sh, frame)

    # every voxel that is drawn: (depth, pixel position, scale, premultiplied colour, opacity)
    splats = []
    n_k, n_j, n_i = aug.shape
    for k in range(n_k):
        for j in range(n_j):
            for i in range(n_i):
                dv = dens[k, j, i]
                alpha = opac[dv] * (gfac[gm[k, j, i]] if gfac is not None else 1.0)
                if alpha <= 0:
                    continue
                X = geom.q + i * geom.steps[0] + j * geom.steps[1] + k * geom.steps[2]
                if any((X - np.asarray(cut.point)) @ np.asarray(cut.normal) < 0 for cut in scene.cuts):
                    continue
                z = -float((X - origin) @ frame.w)
                s, path = 1.0, thick
                if persp:
                    if z < frame.near:
                        continue
                    s = d_img / z
                    path = thick / max(z / np.linalg.norm(X - frame.e), 0.25)
                alpha = 1 - (1 - min(alpha, 1 - 2.0 ** -40)) ** (path / unit)
                rgb = col[dv].copy()
                if sh.enabled:
                    nw = decode(np.array([nrm[k, j, i]]))[0].astype(float) @ geom.unit_axes
                    diff, spec = phong(nw, sh, lights)
                    rgb = rgb * diff + spec
                px, py = C.project_points(frame, [X])[0]
                splats.append((z, px, py, s, rgb * alpha, alpha))

    img = np.zeros((H, W, 4))
    if not splats:
        return _finish(img, scene)
    zs = np.array([t[0] for t in splats])
    # slabs [z_lo + n thick, z_lo + (n + 1) thick), boundaries at the middle depth of the volume's voxel
    # centres plus whole slabs (as the kernel's)
    zmid = _volume_mid_depth(geom, frame, origin)
    z_lo = zmid + thick * math.floor((zs.min() - ext - zmid) / thick)
    n_slabs = int(math.floor((zs.max() + ext - z_lo) / thick)) + 1
    ys, xs = np.mgrid[0:H, 0:W].astype(float)
    for n in range(n_slabs):
        z0 = z_lo + n * thick
        sheet = np.zeros((H, W, 4))
        for z, px, py, s, prgb, alpha in splats:
            dx, dy = (xs - px) / s, (ys - py) / s
            q = Qi[0, 0] * dx * dx + 2 * Qi[0, 1] * dx * dy + Qi[1, 1] * dy * dy
            m = z + g[0] * dx + g[1] * dy                  # the kernel's depth given the pixel
            slab = cdf((z0 + thick - m) / s_c) - cdf((z0 - m) / s_c)
            wgt = np.where(q < R * R, norm * np.exp(-0.5 * q), 0.0) * slab
            sheet[..., :3] += wgt[..., None] * prgb
            sheet[..., 3] += wgt * alpha
        sa = sheet[..., 3]
        scale = np.where(sa > 1, 1 / np.maximum(sa, 1e-300), 1.0)
        sheet[..., :3] *= scale[..., None]
        sa = np.minimum(sa, 1.0)
        t1 = (1 - img[..., 3]) * (img[..., 3] < et)
        img[..., :3] += t1[..., None] * sheet[..., :3]
        img[..., 3] += t1 * sa
    return _finish(img, scene)


def _volume_mid_depth(geom, frame, origin):
    n = geom.n_ijk - 1
    corners = [geom.q + np.array([x, y, z]) @ geom.steps for x in (0, n[0]) for y in (0, n[1]) for z in (0, n[2])]
    zs = [-float((X - origin) @ frame.w) for X in corners]
    return 0.5 * (min(zs) + max(zs))


def _finish(img, scene):
    bg = np.asarray(scene.image.background)
    A = img[..., 3:4]
    rgb = img[..., :3] + (1 - A) * bg[:3] * bg[3]
    alpha = A + (1 - A) * bg[3]
    return np.clip(np.concatenate([np.where(alpha > 0, rgb / np.maximum(alpha, 1e-30), 0), alpha], -1), 0, 1)
