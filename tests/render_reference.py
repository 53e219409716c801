"""A slow, obvious reference splatter for the tests: every voxel, every pixel, float64, no tables.

It follows the same model as the compiled kernel (Gaussian footprint of the grid-space kernel, sheet per
slice, premultiplied front-to-back 'over', opacity corrected for the path through a slice) but computes
everything directly: positions through the 4x4 matrix of camera.project_points, the footprint from the
Gaussian formula, shading from decoded normals and the Phong formula, the order of slices by sorting.
"""

from __future__ import annotations

import math

import numpy as np

from isplat import camera as C
from isplat.augfile import open_augmented
from isplat.frame import WIDE_ANGLE
from isplat.normals import decode
from isplat.splat.footprint import MIN_SIGMA_PIXELS
from isplat.transfer import piecewise_linear
from phong_reference import camera_lights, phong


def reference_render(scene, view=0, et=1.0):
    aug = open_augmented(scene.data.augmented)
    dens = aug.read("density").astype(np.int64)
    gm = aug.read("gradient_magnitude").astype(np.int64)
    nrm = aug.read("normal")
    sp = scene.volume.spacing or aug.spacing_ijk
    geom = C.volume_geometry(aug.shape, sp, scene.volume.origin, scene.volume.axes)
    W, H = scene.image.width, scene.image.height
    frame = C.view_frame(scene.views[view], geom, W, H)
    axis, sign = C.principal_axis(frame, geom)
    ia, ib, ic = C.SLICE_AXES[axis]
    steps = geom.steps
    tr, ro, sh = scene.transfer, scene.render, scene.shading
    unit = tr.unit_distance or float(geom.spacing.min())
    n_ijk = aug.shape[::-1]
    persp = frame.projection == "perspective"

    def world(i, j, k):
        return geom.q + i * steps[0] + j * steps[1] + k * steps[2]

    # footprint covariance: derivative of the direct projection, by finite differences at the view
    # reference point p (on the image plane, where t0 = 1)
    h = 1e-6
    p0 = C.project_points(frame, [frame.p])[0]
    J = np.stack([(C.project_points(frame, [frame.p + h * steps[ax]])[0] - p0) / h for ax in (ia, ib, ic)], axis=1)
    if persp:
        d_img = float((frame.e - frame.p) @ frame.w)
    Sigma = ro.footprint_sigma ** 2 * (J @ J.T)
    lam, V = np.linalg.eigh(Sigma)
    Sigma = (V * np.maximum(lam, MIN_SIGMA_PIXELS ** 2)) @ V.T
    Qi = np.linalg.inv(Sigma)
    a_cell = abs(np.linalg.det(J[:, :2]))
    R2 = ro.footprint_radius ** 2
    norm = a_cell / (2 * math.pi * math.sqrt(np.linalg.det(Sigma))) / (1 - math.exp(-R2 / 2))
    if persp:
        # next to the eye (a footprint's sigma wider than WIDE_ANGLE seen from the eye) the opacity is taken along each
        # pixel's own ray: the secant of every pixel's ray against the slice normal, bounded by the box diagonal
        nrm_c = geom.unit_axes[ic]
        ds_c = float(geom.spacing[ic])
        cos_min = min(1.0, ds_c / float(np.linalg.norm(geom.n_ijk * geom.spacing)))
        wide_px = WIDE_ANGLE * d_img / frame.pixel_size
        extent = math.sqrt(max(Sigma[0, 0], Sigma[1, 1]))         # the footprint's sigma in pixels at t0 = 1
        pc = C.project_points(frame, [frame.e - frame.w])[0]          # the principal point
        ys_, xs_ = np.mgrid[0:H, 0:W].astype(float)
        rays = (((xs_ - pc[0]) * frame.pixel_size)[..., None] * frame.u
                - ((ys_ - pc[1]) * frame.pixel_size)[..., None] * frame.v - d_img * frame.w)
        pix_cos = np.maximum(np.abs(rays @ nrm_c) / np.linalg.norm(rays, axis=-1), cos_min)
        ce = geom.to_grid(frame.e)[ic]
        h0 = max(-0.5 - ce, ce - (n_ijk[ic] - 0.5), 0.0) * ds_c

    d = np.arange(256.0)
    opac = np.clip(piecewise_linear(tr.opacity, d, True)[:, 0], 0, 1)
    col = np.clip(piecewise_linear(tr.color, d, False), 0, 1)
    gfac = None
    if len(tr.gradient_opacity):
        gfac = np.clip(piecewise_linear(tr.gradient_opacity, d * aug.gradient_magnitude_scale, False)[:, 0], 0, 1)

    lights = camera_lights(sh, frame)

    n_c = n_ijk[ic]
    if persp:
        ce = geom.to_grid(frame.e)[ic]
        order = sorted(range(n_c), key=lambda c: (abs(c - ce), c))
    else:
        order = list(range(n_c)) if sign > 0 else list(range(n_c - 1, -1, -1))

    img = np.zeros((H, W, 4))
    ys, xs = np.mgrid[0:H, 0:W].astype(float)
    for c in order:
        sheet = np.zeros((H, W, 4))
        for b in range(n_ijk[ib]):
            for a in range(n_ijk[ia]):
                ijk = [0, 0, 0]
                ijk[ia], ijk[ib], ijk[ic] = a, b, c
                i, j, k = ijk
                dv = dens[k, j, i]
                alpha = opac[dv] * (gfac[gm[k, j, i]] if gfac is not None else 1.0)
                if alpha <= 0:
                    continue
                X = world(i, j, k)
                if any((X - np.asarray(cut.point)) @ np.asarray(cut.normal) < 0 for cut in scene.cuts):
                    continue
                s = 1.0
                if persp:
                    depth = float((frame.e - X) @ frame.w)
                    if depth < frame.near:
                        continue
                    s = d_img / depth
                    ray = X - frame.e
                    hc = abs(ray @ nrm_c)
                    thick = ds_c
                    if depth * (hc - ds_c) / max(hc, 1e-300) < frame.near:
                        # the slab in front along this ray is culled: this one reaches back to camera.clip
                        lower = max(h0, frame.clip * hc / depth)
                        thick = max(hc + 0.5 * ds_c - lower, 0.0)
                    cosang = max(hc / np.linalg.norm(ray), cos_min)
                    if s * extent > wide_px:
                        cosang = pix_cos
                    ds = thick / cosang
                else:
                    ds = geom.spacing[ic] / abs(frame.w @ geom.unit_axes[ic])
                alpha = 1 - (1 - min(alpha, 1 - 2.0 ** -40)) ** (ds / unit)
                rgb = col[dv].copy()
                if sh.enabled:
                    n = decode(np.array([nrm[k, j, i]]))[0].astype(float)
                    nw = n @ geom.unit_axes
                    diff, spec = phong(nw, sh, lights)
                    rgb = rgb * diff + spec
                px, py = C.project_points(frame, [X])[0]
                dx, dy = xs - px, ys - py
                q = (Qi[0, 0] * dx * dx + 2 * Qi[0, 1] * dx * dy + Qi[1, 1] * dy * dy) / (s * s)
                wgt = np.where(q < R2, norm * np.exp(-0.5 * q), 0.0)
                sheet[..., :3] += (wgt * alpha)[..., None] * rgb
                sheet[..., 3] += wgt * alpha
        sa = sheet[..., 3]
        scale = np.where(sa > 1, 1 / np.maximum(sa, 1e-300), 1.0)
        sheet[..., :3] *= scale[..., None]
        sa = np.minimum(sa, 1.0)
        open_ = img[..., 3] < et
        t1 = (1 - img[..., 3]) * open_
        img[..., :3] += t1[..., None] * sheet[..., :3]
        img[..., 3] += t1 * sa
    bg = np.asarray(scene.image.background)
    A = img[..., 3:4]
    rgb = img[..., :3] + (1 - A) * bg[:3] * bg[3]
    alpha = A + (1 - A) * bg[3]
    return np.clip(np.concatenate([np.where(alpha > 0, rgb / np.maximum(alpha, 1e-30), 0), alpha], -1), 0, 1)
