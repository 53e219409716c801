"""The ray-casting reference (tests/ray_reference.py) against closed forms and an obvious numpy integral.

A constant field (or a transfer function constant over every density) has a closed-form integral per pixel:
opacity ``1 - (1 - a)^(L / unit)`` and colour ``c`` times that, ``L`` the length of the pixel's ray inside the
volume's voxel boxes. Both references (the trilinear grid and the analytic Marschner-Lobb field) must give it to
1e-6 in orthographic and perspective views, eye outside and inside.
"""

import math

import numpy as np
import pytest

from ray_reference import render

from isplat.frame import views_for
from isplat.scene import parse_scene


def scene_for(shape, spacing, camera, transfer, shading="enabled = false", size=24, background="[0, 0, 0, 0]"):
    text = (f"[image]\nwidth = {size}\nheight = {size}\nbackground = {background}\n"
            f"[volume]\nspacing = {list(map(float, spacing))}\n"
            f"[camera]\n{camera}\n[transfer]\n{transfer}\n[shading]\n{shading}\n")
    scene = parse_scene(text, ".", "test.toml", data_required=False)

    class Data:
        pass
    data = Data()
    data.shape, data.spacing_ijk = shape, tuple(spacing)
    return scene, views_for(scene, data)[0]


def path_lengths(view):
    """Length of each pixel's ray inside the box of voxel boxes, in world units, by plane intersections in the
    world (independent of the reference's grid-coordinate clipping)."""
    f, g = view.frame, view.geom
    cx, cy = f.width / 2 - 0.5, f.height / 2 - 0.5
    L = np.zeros((f.height, f.width))
    lo = g.q - 0.5 * g.steps.sum(axis=0)      # corner of the voxel boxes
    for y in range(f.height):
        for x in range(f.width):
            P = f.p + (x - cx) * f.pixel_size * f.u - (y - cy) * f.pixel_size * f.v
            if f.projection == "orthographic":
                o, d, t0 = P, -f.w, -math.inf
            else:
                d = (P - f.e) / np.linalg.norm(P - f.e)
                o, t0 = f.e, 0.0
            t1 = math.inf
            for a in range(3):
                nrm = g.unit_axes[a]
                width = g.n_ijk[a] * g.spacing[a]
                s0 = (o - lo) @ nrm                   # position along the axis
                ds = d @ nrm
                if abs(ds) < 1e-300:
                    if not 0 <= s0 <= width:
                        t0, t1 = 1.0, 0.0
                    continue
                ta, tb = sorted(((0 - s0) / ds, (width - s0) / ds))
                t0, t1 = max(t0, ta), min(t1, tb)
            L[y, x] = max(0.0, t1 - t0)
    return L


CAMERAS = {
    "orthographic oblique": 'projection = "orthographic"\nazimuth = 31\nelevation = 17\nzoom = 1.2',
    "perspective outside": 'projection = "perspective"\nazimuth = -52\nelevation = 33\nfov = 40',
    "perspective, eye inside": ('projection = "perspective"\nposition = [0.3, -0.7, 0.2]\nlook_at = [2.0, 1.0, 3.0]\n'
                                'up = [0, 0, 1]\nfov = 90'),
}
A, UNIT, COLOUR = 0.07, 0.8, (0.3, 0.6, 0.9)


def expected(view, bg=(0.0, 0.0, 0.0)):
    L = path_lengths(view)
    alpha = 1.0 - (1.0 - A) ** (L / UNIT)
    out = np.zeros(L.shape + (4,))
    out[..., 3] = alpha
    for ch in range(3):
        out[..., ch] = np.where(alpha > 0, COLOUR[ch], 0.0)
    return out


@pytest.mark.parametrize("cam", CAMERAS)
@pytest.mark.parametrize("spacing", [(1.0, 1.0, 1.0), (0.9, 1.3, 2.5)])
def test_constant_volume_closed_form_grid(cam, spacing):
    shape = (7, 9, 11)
    tf = (f"opacity = [[150, 0.0], [200, {A}], [250, 0.0]]\ncolor = [[0, {COLOUR[0]}, {COLOUR[1]}, {COLOUR[2]}]]\n"
          f"unit_distance = {UNIT}")
    scene, view = scene_for(shape, spacing, CAMERAS[cam], tf)
    img = render(view, scene.transfer, scene.shading, density=np.full(shape, 200, np.uint8), step=0.05)
    exp = expected(view)
    assert (exp[..., 3] > 0).mean() > 0.2          # the volume covers a good part of the image
    np.testing.assert_allclose(img, exp, atol=1e-6, rtol=0)


@pytest.mark.parametrize("cam", CAMERAS)
def test_constant_transfer_function_closed_form_marschner_lobb(cam):
    """The analytic field with a transfer function constant over all 256 codes: only the path length counts."""
    shape = (9, 9, 9)
    tf = (f"opacity = [[0, {A}], [255, {A}]]\ncolor = [[0, {COLOUR[0]}, {COLOUR[1]}, {COLOUR[2]}]]\n"
          f"unit_distance = {UNIT}")
    scene, view = scene_for(shape, (0.25, 0.25, 0.25), CAMERAS[cam].replace("[2.0, 1.0, 3.0]", "[0.5, 0.25, 0.75]")
                            .replace("[0.3, -0.7, 0.2]", "[0.07, -0.17, 0.05]"), tf)
    img = render(view, scene.transfer, scene.shading, ml=(6.0, 0.25, 0.0, 1.0), step=0.05)
    np.testing.assert_allclose(img, expected(view), atol=1e-6, rtol=0)


def test_constant_volume_shaded_is_ambient_only():
    shape = (8, 8, 8)
    tf = f"opacity = [[150, 0.0], [200, {A}], [250, 0.0]]\ncolor = [[0, 0.8, 0.8, 0.8]]\nunit_distance = {UNIT}"
    shading = "enabled = true\nambient = 0.25\ndiffuse = 0.75\nspecular = 0.3\n[[shading.light]]\ndirection = [0, 0, 1]"
    scene, view = scene_for(shape, (1, 1, 1), CAMERAS["orthographic oblique"], tf, shading)
    img = render(view, scene.transfer, scene.shading, density=np.full(shape, 200, np.uint8))
    exp = expected(view)
    inside = exp[..., 3] > 0
    np.testing.assert_allclose(img[..., 0][inside], 0.2, atol=1e-6)
    np.testing.assert_allclose(img[..., 3], exp[..., 3], atol=1e-6)


def obvious_integral(vol, o, d, t0, t1, n_steps, xs, ys, col, unit):
    """numpy: midpoint samples, trilinear by hand (clamped to the edge), TF by np.interp, front-to-back 'over'."""
    nk, nj, ni = vol.shape
    dt = (t1 - t0) / n_steps
    T, acc = 1.0, np.zeros(3)
    for m in range(n_steps):
        p = o + (t0 + (m + 0.5) * dt) * d
        p = np.clip(p, 0, np.array([ni, nj, nk]) - 1.0)
        i0, j0, k0 = (min(int(p[a]), s - 2) for a, s in enumerate((ni, nj, nk)))
        fi, fj, fk = p[0] - i0, p[1] - j0, p[2] - k0
        v = 0.0
        for dk, wk in ((0, 1 - fk), (1, fk)):
            for dj, wj in ((0, 1 - fj), (1, fj)):
                for di, wi in ((0, 1 - fi), (1, fi)):
                    v += wk * wj * wi * float(vol[k0 + dk, j0 + dj, i0 + di])
        a = 0.0 if (v < xs[0] or v > xs[-1]) else float(np.interp(v, xs, ys))
        alpha = 1.0 - (1.0 - min(a, 1 - 2.0 ** -40)) ** (dt / unit)
        acc += T * alpha * col
        T *= 1.0 - alpha
    return acc, 1.0 - T


def test_random_volume_matches_an_obvious_integral():
    """Trilinear reconstruction, post-classification and compositing on a random volume: a few rays of the
    compiled reference against the obvious numpy loop with the same number of pieces."""
    rng = np.random.default_rng(3)
    shape = (6, 7, 8)
    vol = rng.integers(0, 256, shape).astype(np.uint8)
    tf = "opacity = [[40, 0.0], [120, 0.6], [200, 0.1], [230, 0.0]]\ncolor = [[0, 0.5, 0.5, 0.5]]\nunit_distance = 1.0"
    scene, view = scene_for(shape, (1, 1, 1), CAMERAS["orthographic oblique"], tf, size=12)
    img = render(view, scene.transfer, scene.shading, density=vol, step=0.05)
    from ray_reference import _box_range, rays

    o, d, t_lo = rays(view)
    n = np.array(view.geom.n_ijk, float)
    pts = np.asarray(scene.transfer.opacity)
    checked = 0
    for r in range(0, len(o), 7):
        t0, t1 = _box_range(o[r], d[r], n, t_lo[r])
        if t1 <= t0:
            continue
        steps = max(1, math.ceil((t1 - t0) / 0.05))
        rgb, alpha = obvious_integral(vol, o[r], d[r], t0, t1, steps, pts[:, 0], pts[:, 1], 0.5, 1.0)
        y, x = divmod(r, 12)
        assert img[y, x, 3] == pytest.approx(alpha, abs=1e-9)
        if alpha > 0:
            assert img[y, x, 0] == pytest.approx(rgb[0] / alpha, abs=1e-9)
        checked += 1
    assert checked > 5


def test_refuses_gradient_opacity():
    tf = "opacity = [[0, 0.5], [255, 0.5]]\ngradient_opacity = [[0, 0.0], [10, 1.0]]"
    scene, view = scene_for((4, 4, 4), (1, 1, 1), CAMERAS["orthographic oblique"], tf)
    with pytest.raises(ValueError, match="gradient"):
        render(view, scene.transfer, scene.shading, density=np.zeros((4, 4, 4), np.uint8))


def test_marschner_lobb_field_matches_the_sample_at_the_grid_points():
    """The analytic field is the `isplat sample marschner-lobb` signal (fm 6, alpha 0.25) through the window:
    at the grid points it equals the sample's windowed values (float32 rounding only), and its gradient matches
    central differences of a finely sampled copy."""
    from ray_reference import _ml

    from isplat.samples import make_sample

    n = 9
    arr, sp = make_sample("marschner-lobb", (n, n, n))
    lo, hi = 0.05, 0.9
    p = np.array([6.0, 0.25, lo, hi, n, n, n], float)
    want = np.clip((arr.astype(np.float64) - lo) * 255 / (hi - lo), 0, 255)
    got = np.array([[[_ml(i, j, k, p)[0] for i in range(n)] for j in range(n)] for k in range(n)])
    np.testing.assert_allclose(got, want, atol=1e-4)
    h = 1e-5
    for gi, gj, gk in [(2.3, 5.1, 3.7), (6.6, 1.2, 4.4)]:
        c, *g = _ml(gi, gj, gk, p)
        num = [(_ml(gi + h * (a == 0), gj + h * (a == 1), gk + h * (a == 2), p)[0]
                - _ml(gi - h * (a == 0), gj - h * (a == 1), gk - h * (a == 2), p)[0]) / (2 * h) for a in range(3)]
        assert 0 < c < 255
        np.testing.assert_allclose(g, num, rtol=1e-5, atol=1e-6)
