"""Renderer: the compiled indexed and full methods against each other and against the reference."""

import math
import pathlib
import tempfile

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from conftest import write_volume
from isplat import camera as C
from isplat.renderer import Renderer
from render_reference import reference_render

# these tests are about the paper's (pre-classified) splatting: its footprint, its reference (render_reference)
BIG_TABLE = 'footprint_table = 1048576\nclassification = "pre"\n'


def rng_volume(seed, shape, levels=(0, 60, 120, 200)):
    r = np.random.default_rng(seed)
    return r.choice(np.array(levels, np.uint8), size=shape, p=[0.55, 0.15, 0.15, 0.15])


def random_normals(seed, shape):
    from isplat.normals import encode
    v = np.random.default_rng(seed + 1).normal(size=shape + (3,))
    return encode(v)


def render(scene, method=None, et=None):
    r = Renderer(scene, method=method)
    return r.render_view(0, et=et)


CAMERAS = [
    "azimuth = 0\nelevation = 0", "azimuth = 90\nelevation = 0", "azimuth = 180\nelevation = 0",
    "azimuth = 270\nelevation = 0", "azimuth = 0\nelevation = 90", "azimuth = 0\nelevation = -90",
    "azimuth = 33\nelevation = 21", "azimuth = 150\nelevation = -40",
]


@pytest.mark.parametrize("cam", CAMERAS)
@pytest.mark.parametrize("proj", ["orthographic", "perspective"])
def test_reference_agrees_with_both_methods(tmp_path, make_scene, cam, proj):
    shape = (5, 6, 7)
    dens = rng_volume(1, shape)
    aug, idx = write_volume(tmp_path, dens, spacing=(1.0, 1.2, 0.8), normal=random_normals(1, shape))
    sc = make_scene(aug, idx, image="width = 24\nheight = 20",
                    camera=f'projection = "{proj}"\n{cam}',
                    transfer="opacity = [[50, 0.0], [60, 0.3], [130, 0.1], [200, 0.9]]\n"
                             "color = [[0, 1, 0, 0], [255, 0, 0.5, 1]]",
                    shading="enabled = true",
                    render=BIG_TABLE + "early_termination = 1.0")
    ref = reference_render(sc)
    ind, _ = render(sc, "indexed")
    full, _ = render(sc, "full")
    assert np.abs(ind - full).max() <= 1e-5
    assert np.abs(ind - ref).max() <= 2e-4
    assert ref[..., 3].max() > 0.2          # something was rendered


def test_reference_with_cut_gradient_and_early_termination(tmp_path, make_scene):
    shape = (6, 5, 6)
    dens = rng_volume(2, shape)
    gm = np.random.default_rng(3).integers(0, 256, shape).astype(np.uint8)
    # coloured lights (the full r, g, b shading table), one-sided Phong, gradient-modulated opacity
    aug, idx = write_volume(tmp_path, dens, gm=gm, gscale=0.5, normal=random_normals(2, shape))
    sc = make_scene(aug, idx, image="width = 20\nheight = 20",
                    camera="azimuth = 20\nelevation = 30",
                    transfer="opacity = [[55, 0.0], [60, 0.95], [255, 0.95]]\n"
                             "gradient_opacity = [[0, 0.2], [100, 1.0]]",
                    cut="point = [0.3, 0.0, 0.0]\nnormal = [1.0, 0.2, 0.0]",
                    shading="enabled = true\ntwo_sided = false\nspecular = 0.5",
                    shading__light="direction = [0.3, 0.5, 1.0]\ncolor = [1.0, 0.6, 0.2]\n"
                                   "[[shading.light]]\ndirection = [-1.0, 0.2, 0.4]\nintensity = 0.5",
                    render=BIG_TABLE + "early_termination = 0.9")
    ref = reference_render(sc, et=0.9)
    ind, st_i = render(sc, "indexed")
    full, st_f = render(sc, "full")
    # early termination decides per pixel between slices: both methods decide identically
    assert np.abs(ind - full).max() <= 1e-5
    assert np.abs(ind - ref).max() <= 2e-4
    assert st_i.drawn == st_f.drawn


@pytest.mark.parametrize("cam", CAMERAS)
@pytest.mark.parametrize("proj", ["orthographic", "perspective"])
def test_single_voxel_is_the_footprint_at_its_projection(tmp_path, make_scene, cam, proj):
    shape = (9, 9, 9)
    dens = np.zeros(shape, np.uint8)
    pos = (3, 5, 4)                            # (k, j, i)
    dens[pos] = 200
    aug, idx = write_volume(tmp_path, dens)
    # perspective from 60 units, where the footprint is narrow seen from the eye (the voxel's own ray gives its
    # opacity; next to the eye see test_wide_voxel_next_to_the_eye_takes_each_pixels_own_ray)
    far = "\ndistance = 60\nfov = 12" if proj == "perspective" else ""
    sc = make_scene(aug, idx, image="width = 96\nheight = 96\nbackground = [0, 0, 0, 0]",
                    camera=f'projection = "{proj}"\n{cam}\nzoom = 0.6{far}',
                    transfer="opacity = [[199, 0], [200, 0.5], [201, 0]]", shading="enabled = false",
                    render=BIG_TABLE + "footprint_radius = 4.0")
    img, stats = render(sc)
    assert stats.drawn == 1
    r = Renderer(sc)
    frame, geom = r.frames[0], r.geom
    X = geom.q + np.array(pos[::-1]) @ geom.steps
    px, py = C.project_points(frame, [X])[0]
    a = img[..., 3]
    ys, xs = np.mgrid[0:96, 0:96]
    cx, cy = (a * xs).sum() / a.sum(), (a * ys).sum() / a.sum()
    assert a[0].max() == a[-1].max() == a[:, 0].max() == a[:, -1].max() == 0    # not clipped
    assert abs(cx - px) < 0.01 and abs(cy - py) < 0.01
    # the footprint keeps the voxel's opacity: its weights integrate to the projected cell area
    assert a.max() <= 0.5


@pytest.mark.parametrize("ijk", [(4, 4, 6), (5, 4, 7)])
def test_wide_voxel_next_to_the_eye_takes_each_pixels_own_ray(tmp_path, make_scene, ijk):
    """A single voxel 3 units in front of the eye (its footprint spans tens of degrees): the opacity at each
    pixel is the footprint's weight times the opacity of the slab along that pixel's ray, 1 - (1 - a)^(1/cos);
    the weights so recovered are centred on the voxel's projection and sum to its projected cell area."""
    shape = (9, 9, 9)
    dens = np.zeros(shape, np.uint8)
    dens[ijk[::-1]] = 200                       # world (i - 4, j - 4, k - 4): (0, 0, 2) or off the axis
    aug, idx = write_volume(tmp_path, dens)
    sc = make_scene(aug, idx, image="width = 64\nheight = 64\nbackground = [0, 0, 0, 0]",
                    camera='projection = "perspective"\nposition = [0.0, 0.0, -1.0]\nlook_at = [0.0, 0.0, 10.0]\n'
                           'up = [0, 1, 0]\nfov = 100',
                    transfer="opacity = [[199, 0], [200, 0.5], [201, 0]]\nunit_distance = 1.0",
                    shading="enabled = false", render=BIG_TABLE + "footprint_radius = 4.0")
    img, stats = render(sc)
    assert stats.drawn == 1 and stats.axis == "k"
    frame = Renderer(sc).frames[0]
    X = np.array(ijk, float) - 4.0
    px, py = C.project_points(frame, [X])[0]
    pc = C.project_points(frame, [frame.e - frame.w])[0]
    d_img = float((frame.e - frame.p) @ frame.w)
    ys, xs = np.mgrid[0:64, 0:64].astype(float)
    rays = (((xs - pc[0]) * frame.pixel_size)[..., None] * frame.u
            - ((ys - pc[1]) * frame.pixel_size)[..., None] * frame.v - d_img * frame.w)
    cos = np.abs(rays[..., 2]) / np.linalg.norm(rays, axis=-1)
    a = img[..., 3]
    wgt = a / (1 - 0.5 ** (1 / cos))
    assert a[0].max() == a[-1].max() == a[:, 0].max() == a[:, -1].max() == 0    # not clipped
    cx, cy = (wgt * xs).sum() / wgt.sum(), (wgt * ys).sum() / wgt.sum()
    assert abs(cx - px) < 0.01 and abs(cy - py) < 0.01
    # partition of unity: the weights integrate to the voxel's projected cell area, (d_img / depth / pix)^2
    depth = float((frame.e - X) @ frame.w)
    assert abs(wgt.sum() / (d_img / depth / frame.pixel_size) ** 2 - 1) < 1e-3
    # the voxel's own ray would give every pixel the same slab opacity: the corner rays are much longer here
    assert cos.min() < 0.75


@pytest.mark.parametrize("spacing", [(1.0, 1.0, 1.0), (0.7, 1.0, 2.5), (2.0, 0.5, 1.0)])
@pytest.mark.parametrize("cam", ["azimuth = 0\nelevation = 0", "azimuth = 90\nelevation = 0",
                                 "azimuth = 0\nelevation = 90", "azimuth = 40\nelevation = 25"])
def test_sphere_is_round_with_anisotropic_spacing(tmp_path, make_scene, spacing, cam):
    """A smooth ball sampled on an anisotropic grid, faint emission-absorption: the image is the ball's
    projected chord length, radially symmetric, with second moment R^2/5 (plus the footprint's blur)."""
    radius = 9.0
    n = [int(2 * radius / s) + 7 for s in spacing]          # i, j, k counts
    i, j, k = np.meshgrid(*[(np.arange(m) - (m - 1) / 2) * s for m, s in zip(n, spacing)], indexing="ij")
    r = np.sqrt(i * i + j * j + k * k)
    dens = np.round(200 * np.clip(radius - r + 0.5, 0, 1)).astype(np.uint8)
    aug, idx = write_volume(tmp_path, dens.transpose(2, 1, 0), spacing=spacing)
    sc = make_scene(aug, idx, image="width = 64\nheight = 64\nbackground = [0, 0, 0, 0]", camera=cam,
                    transfer="opacity = [[0, 0], [200, 0.002]]\nunit_distance = 1.0",
                    shading="enabled = false", render='early_termination = 1.0\nclassification = "pre"')
    img, _ = render(sc)
    a = img[..., 3]
    ys, xs = np.mgrid[0:64, 0:64]
    m = a.sum()
    cx, cy = (a * xs).sum() / m, (a * ys).sum() / m
    cov = np.array([[(a * (xs - cx) ** 2).sum(), (a * (xs - cx) * (ys - cy)).sum()],
                    [(a * (xs - cx) * (ys - cy)).sum(), (a * (ys - cy) ** 2).sum()]]) / m
    # the image is the ball's projection convolved with the footprint (isotropic in grid space, so
    # stretched along a thick axis in the world): take the footprint's covariance out, the ball remains
    from isplat.splat.footprint import make_footprint
    rr = Renderer(sc)
    frame, geom = rr.frames[0], rr.geom
    axis, _ = C.principal_axis(frame, geom)
    fp = make_footprint(C.projection(frame, geom, axis).jac, 0.7, 2.0, 1024)
    Qa, Qb, Qc = fp.params[:3]
    # variance of a 2-D Gaussian cut off at R sigmas: sigma^2 (1 - (R^2/2) e^(-R^2/2) / (1 - e^(-R^2/2)))
    R2 = 4.0
    cut = 1 - (R2 / 2) * math.exp(-R2 / 2) / (1 - math.exp(-R2 / 2))
    sigma_fp = cut * np.linalg.inv(np.array([[Qa, Qb], [Qb, Qc]]))
    ev = np.linalg.eigvalsh(cov - sigma_fp)
    # round, not an ellipse (the sampled ball itself is isotropic to about 3% on these grids)
    assert ev[0] / ev[1] > 0.96, ev
    assert abs(math.sqrt(5 * ev.mean()) * frame.pixel_size / radius - 1) < 0.05


@settings(max_examples=60, deadline=None)
@given(az=st.floats(-180, 180), el=st.floats(-89, 89), dist=st.floats(10, 200), fov=st.floats(5, 120),
       axis=st.sampled_from("ijk"), zoom=st.floats(0.3, 3), pts=st.lists(
           st.tuples(st.floats(-5, 12), st.floats(-5, 12), st.floats(-5, 12)), min_size=1, max_size=5))
def test_perspective_formulas_match_a_4x4_projection(az, el, dist, fov, axis, zoom, pts):
    """§3.2's per-slice incremental formulas give the same pixel as a direct 4x4 matrix projection."""
    from types import SimpleNamespace as NS
    geom = C.volume_geometry((8, 9, 10), (1.0, 0.8, 1.5))
    cam = NS(projection="perspective", mode="orbit", azimuth=az, elevation=el, distance=dist, roll=0.0,
             target=None, up=(0, 0, 1), zoom=zoom, fov=fov, near=0.0)
    frame = C.view_frame(cam, geom, 50, 40)
    proj = C.projection(frame, geom, axis)
    ia, ib, ic = C.SLICE_AXES[axis]
    c = proj.coef
    for g in pts:
        a, b, s_ = g[ia], g[ib], g[ic]
        X = geom.q + np.asarray(g) @ geom.steps
        if (frame.e - X) @ frame.w < 1e-3:
            continue
        D = (c[8] + s_ * c[11]) + a * c[9] + b * c[10]
        t0 = c[14] / D
        x = c[12] + t0 * ((c[0] + s_ * c[3]) + a * c[1] + b * c[2])
        y = c[13] + t0 * ((c[4] + s_ * c[7]) + a * c[5] + b * c[6])
        ref = C.project_points(frame, [X])[0]
        assert np.allclose([x, y], ref, rtol=1e-9, atol=1e-6 * max(1.0, abs(ref).max()))


@settings(max_examples=60, deadline=None)
@given(az=st.floats(-180, 180), el=st.floats(-90, 90), roll=st.floats(-180, 180), axis=st.sampled_from("ijk"),
       pts=st.lists(st.tuples(st.floats(-5, 12), st.floats(-5, 12), st.floats(-5, 12)), min_size=1, max_size=5))
def test_orthographic_formulas_match_a_4x4_projection(az, el, roll, axis, pts):
    from types import SimpleNamespace as NS
    geom = C.volume_geometry((8, 9, 10), (1.3, 0.8, 1.0), axes=[[0, 1, 0], [-1, 0, 0], [0, 0, 1]])
    cam = NS(projection="orthographic", mode="orbit", azimuth=az, elevation=el, distance=None, roll=roll,
             target=None, up=(0, 0, 1), zoom=1.0, fov=30.0, near=0.0)
    frame = C.view_frame(cam, geom, 30, 40)
    c = C.projection(frame, geom, axis).coef
    ia, ib, ic = C.SLICE_AXES[axis]
    for g in pts:
        a, b, s_ = g[ia], g[ib], g[ic]
        x = (c[0] + s_ * c[3]) + a * c[1] + b * c[2]
        y = (c[4] + s_ * c[7]) + a * c[5] + b * c[6]
        ref = C.project_points(frame, [geom.q + np.asarray(g) @ geom.steps])[0]
        assert np.allclose([x, y], ref, atol=1e-9)
    # the frame is orthonormal and right-handed
    R = np.stack([frame.u, frame.v, frame.w])
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-12) and np.isclose(np.linalg.det(R), 1.0)


@pytest.mark.parametrize("d", [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)])
def test_principal_axis_and_front_to_back_order(d):
    from types import SimpleNamespace as NS
    geom = C.volume_geometry((4, 5, 6), (1, 1, 1))
    cam = NS(projection="orthographic", mode="look_at", position=tuple(-10 * np.array(d, float)),
             look_at=(0, 0, 0), up=(0, 1, 0) if d[1] == 0 else (0, 0, 1), roll=0.0, zoom=1.0, fov=30, near=0)
    frame = C.view_frame(cam, geom, 8, 8)
    axis, sign = C.principal_axis(frame, geom)
    c = int(np.flatnonzero(d)[0])
    assert axis == "ijk"[c] and sign == d[c]
    order = C.slice_order(frame, geom, axis, sign)
    # the first slice is the one nearest the camera
    assert (order[0] == 0) == (d[c] > 0)


def test_principal_axis_accounts_for_spacing():
    """A view 40 degrees off k but with thick k slices crosses i planes faster: axis i."""
    from types import SimpleNamespace as NS
    geom = C.volume_geometry((10, 10, 10), (1.0, 1.0, 3.0))
    t = math.radians(40)
    cam = NS(projection="orthographic", mode="look_at", position=(-10 * math.sin(t), 0, -10 * math.cos(t)),
             look_at=(0, 0, 0), up=(0, 1, 0), roll=0.0, zoom=1.0, fov=30, near=0)
    frame = C.view_frame(cam, geom, 8, 8)
    assert C.principal_axis(frame, geom)[0] == "i"


def test_uniform_slab_gives_the_corrected_opacity(tmp_path, make_scene):
    """n slices of opacity alpha per unit distance: 1 - (1 - alpha)^n in the middle of the image."""
    shape = (12, 16, 16)
    dens = np.full(shape, 200, np.uint8)
    aug, idx = write_volume(tmp_path, dens, spacing=(1.0, 1.0, 0.5))
    alpha = 0.05
    sc = make_scene(aug, idx, image="width = 32\nheight = 32\nbackground = [0, 0, 0, 0]",
                    camera="azimuth = 0\nelevation = 90\nzoom = 1.5",
                    transfer=f"opacity = [[199, 0], [200, {alpha}], [201, 0]]\nunit_distance = 1.0",
                    shading="enabled = false", render=BIG_TABLE + "footprint_radius = 3.0")
    img, _ = render(sc)
    expect = 1 - (1 - alpha) ** (12 * 0.5)          # 12 slices of 0.5 units: 6 unit distances
    assert abs(img[16, 16, 3] - expect) < 2e-3


def test_eye_inside_the_volume_renders_finite(tmp_path, make_scene):
    shape = (10, 10, 10)
    dens = rng_volume(5, shape)
    aug, idx = write_volume(tmp_path, dens)
    for pos in ["[0.2, 0.3, 0.1]", "[0.0, 0.0, 4.6]", "[4.6, 0.0, 0.0]"]:
        sc = make_scene(aug, idx, image="width = 24\nheight = 24",
                        camera=f'projection = "perspective"\nposition = {pos}\nlook_at = [3, 2, 1]\nfov = 90',
                        transfer="opacity = [[50, 0], [60, 0.4], [255, 0.4]]", shading="enabled = false",
                        render=BIG_TABLE + "early_termination = 1.0")
        ind, _ = render(sc, "indexed")
        full, _ = render(sc, "full")
        ref = reference_render(sc)
        assert np.all(np.isfinite(ind))
        assert np.abs(ind - full).max() <= 1e-5
        assert np.abs(ind - ref).max() <= 2e-4


def test_empty_transfer_function_renders_background_and_reads_nothing(tmp_path, make_scene):
    aug, idx = write_volume(tmp_path, rng_volume(6, (4, 4, 4)))
    sc = make_scene(aug, idx, image="width = 8\nheight = 8\nbackground = [0.25, 0.5, 0.75]",
                    transfer="opacity = [[250, 0], [255, 0]]")
    r = Renderer(sc)
    img, st_ = r.render_view(0)
    assert np.allclose(img[..., :3], [0.25, 0.5, 0.75]) and st_.voxels_examined == 0
    assert r.report.index_bytes == 0 and r.report.augmented_bytes == 0


def test_only_needed_channels_and_axes_are_read(tmp_path, make_scene):
    shape = (6, 7, 8)
    aug, idx = write_volume(tmp_path, rng_volume(7, shape))
    base = dict(image="width = 8\nheight = 8", transfer="opacity = [[190, 0], [200, 1]]",
                render='classification = "pre"')
    r = Renderer(make_scene(aug, idx, shading="enabled = false", **base))
    assert r.report.channels == [] and r.report.axes == ["j"]
    assert r.report.augmented_bytes == 0 and r.report.index_bytes > 0
    blocks, voi = r.report.index_bytes, r.report.voxels_of_interest
    assert r.report.bytes_needed == blocks and r.report.values_from == "none"
    r = Renderer(make_scene(aug, idx, shading="enabled = true", **base))
    # the normals of just the voxels of interest, from the index's values file (format 6): one pointer table and
    # 2 B each
    assert r.report.channels == ["normal"] and r.report.augmented_bytes == 0
    assert r.report.index_bytes == blocks and r.report.values_from == "values file"
    assert r.report.values_bytes == 257 * 8 + 2 * voi
    assert r.report.bytes_needed == r.report.index_bytes + r.report.values_bytes
    r = Renderer(make_scene(aug, idx, overrides=["render.method=full", "shading.enabled=false"], **base))
    assert r.report.channels == ["density"] and r.report.index_bytes == 0
    r = Renderer(make_scene(aug, idx, views="list = [{azimuth = 0}, {azimuth = 90}]", **base))
    assert r.report.axes == ["i", "j"]
    # post-classification (the default) samples the neighbours of the voxels of interest too: the whole
    # density channel, and the normals and gradient magnitudes (which weight the shading) when shaded; from the
    # index only the blocks, no values
    del base["render"]
    r = Renderer(make_scene(aug, idx, shading="enabled = true", **base))
    assert r.report.channels == ["density", "normal", "gradient_magnitude"]
    assert r.report.values_from == "whole channels"
    assert r.report.augmented_bytes == 4 * dens_size(shape) and r.report.index_bytes == blocks


def dens_size(shape):
    return int(np.prod(shape))


def test_index_of_another_volume_is_refused(tmp_path, make_scene):
    from isplat.errors import IsplatError
    aug, idx = write_volume(tmp_path, rng_volume(8, (4, 4, 4)), name="a")
    aug2, idx2 = write_volume(tmp_path, rng_volume(9, (4, 4, 4)), name="b")
    with pytest.raises(IsplatError, match="another volume"):
        Renderer(make_scene(aug, idx2, transfer="opacity = [[0, 1], [255, 1]]"))


@pytest.mark.parametrize("alpha", [1e-7, 1e-3, 0.5, 1.0])
@pytest.mark.parametrize("precision", ["float32", "float64"])
def test_extreme_opacities_stay_finite_and_agree(tmp_path, make_scene, alpha, precision):
    shape = (16, 16, 16)
    aug, idx = write_volume(tmp_path, np.full(shape, 200, np.uint8))
    sc = make_scene(aug, idx, image="width = 16\nheight = 16\nbackground = [0, 0, 0, 0]",
                    camera="azimuth = 10\nelevation = 5\nzoom = 2",
                    transfer=f"opacity = [[0, {alpha}], [255, {alpha}]]\nunit_distance = 0.01",
                    shading="enabled = false", render=f'precision = "{precision}"\nearly_termination = 1.0')
    img, _ = render(sc)
    assert np.all(np.isfinite(img))
    # tiny alphas over a long path: 1 - (1 - a)^(16/0.01 / cos) must not be lost to rounding
    expect = -math.expm1(16 / 0.01 / math.cos(math.radians(10)) / math.cos(math.radians(5)) * math.log1p(-min(alpha, 1 - 2 ** -40)))
    assert abs(img[8, 8, 3] - expect) < 5e-3 * max(expect, 1e-6) + 1e-6


def test_select_voxels_refuses_a_slice_with_more_voxels_than_positions():
    """A crafted index listing the same positions under two densities of one 2x2 slice must not overrun."""
    from isplat.splat.select import select_voxels
    with pytest.raises(ValueError, match="more voxels than it has positions"):
        select_voxels(np.array([0, 2]), np.array([1, 2], np.uint8), np.array([0, 4, 8]),
                      np.array([0, 1, 2, 3, 0, 1, 2, 3], np.int32), np.array([[0, 255]]), 2, 2,
                      np.empty(0, np.int32))


def _walk_hierarchy(sel, n_a):
    """Slow, obvious reading of select_voxels' output: per voxel (slice, a, b, density, source, key), where the
    key is the (region, block, cell) path a frame walks; the module docstring of isplat.splat.select in Python."""
    from isplat.splat.select import BLOCK, CELL, REGION
    slice_ptr, region_id, region_ptr, block_pos, block_ptr, block_voxel, cell_pos, cell_count, off, d, src = sel
    nra = -(-n_a // REGION)
    out = []
    for c in range(len(slice_ptr) - 1):
        for g in range(slice_ptr[c], slice_ptr[c + 1]):
            for r in range(region_ptr[g], region_ptr[g + 1]):
                v = block_voxel[r]
                for q in range(block_ptr[r], block_ptr[r + 1]):
                    assert 1 <= cell_count[q] <= 16
                    for _ in range(cell_count[q]):
                        a = (region_id[g] % nra) * REGION + (block_pos[r] % 4) * BLOCK + (cell_pos[q] % 4) * CELL + off[v] % CELL
                        b = (region_id[g] // nra) * REGION + (block_pos[r] // 4) * BLOCK + (cell_pos[q] // 4) * CELL + off[v] // CELL
                        out.append((c, a, b, int(d[v]), int(src[v]), (int(region_id[g]), int(block_pos[r]), int(cell_pos[q]))))
                        v += 1
                assert v == block_voxel[r + 1]
    return out


@settings(max_examples=25, deadline=None)
@given(st.tuples(st.integers(1, 4), st.integers(1, 140), st.integers(1, 90)), st.integers(0, 2 ** 32 - 1),
       st.integers(1, 255))
def test_select_voxels_keeps_every_voxel_once_in_its_region_block_and_cell(shape, seed, lo):
    """Every selected voxel appears once, in its slice, at the coordinates its region, block, cell and offset
    give, with its density; slices, regions, blocks and cells come in increasing order, and within a cell
    the voxels keep the index's density order (the order the blocks list them)."""
    from isplat.index.memory import load_axis_in_memory
    from isplat.splat.select import select_voxels
    dens = np.random.default_rng(seed).integers(0, 256, shape).astype(np.uint8)
    la = load_axis_in_memory(dens, "k", [(lo, 255)])
    sel = select_voxels(la.slice_block_ptr, la.block_density, la.block_voxel_ptr, la.positions,
                        np.array([[lo, 255]]), la.n_a, la.n_b, np.empty(0, np.int64))
    got = _walk_hierarchy(sel, la.n_a)
    want = sorted((c, int(i), int(j)) for c, j, i in zip(*np.nonzero(dens >= lo)))
    assert sorted((c, a, b) for c, a, b, *_ in got) == want
    assert all(dens[c, b, a] == dv for c, a, b, dv, *_ in got)
    assert all(la.positions[s] == a + b * la.n_a for c, a, b, _, s, _ in got)
    keys = [(c, key) for c, a, b, dv, s, key in got]
    assert keys == sorted(keys)
    assert all(s0 < s1 for (c0, *_, s0, k0), (c1, *_, s1, k1) in zip(got, got[1:]) if (c0, k0) == (c1, k1))


def test_slices_in_chunks_give_the_same_image(tmp_path, make_scene, monkeypatch):
    """With a progress bar the slices are rendered in chunks; the kernel's state carries over exactly."""
    import isplat.progress
    aug, idx = write_volume(tmp_path, rng_volume(12, (48, 10, 12)))
    sc = make_scene(aug, idx, image="width = 24\nheight = 24", camera="azimuth = 0\nelevation = 80",
                    transfer="opacity = [[50, 0], [60, 0.3], [255, 0.9]]")
    one, s1 = render(sc)
    monkeypatch.setattr(isplat.progress, "enabled", lambda: True)
    chunked, s2 = render(sc)
    assert np.array_equal(one, chunked) and s1.drawn == s2.drawn


@pytest.mark.parametrize("proj", ["orthographic", "perspective"])
def test_hidden_regions_blocks_and_cells_skipped_exactly_for_any_bands_and_threads(tmp_path, make_scene, monkeypatch,
                                                                                    proj):
    """A volume wider than a region (64 voxels), an opaque wall in front of random material, early termination
    on: the regions, blocks and cells behind the wall are skipped with one test each, and the image is that of
    the slow reference (which splats every voxel), bit for bit the same for 1, 2 or 3 threads and for bands
    of one tile, of the whole image or cut unevenly; hiding the material costs far fewer per-voxel tests than it
    has voxels."""
    from isplat import frame as F
    shape = (24, 10, 70)                                   # (k, j, i): slices of j are 70 x 24, 2 regions
    dens = rng_volume(5, shape)
    dens[:, :2, :] = 250                                   # the wall: the first j-slices, seen from -y
    aug, idx = write_volume(tmp_path, dens)
    sc = make_scene(aug, idx, image="width = 100\nheight = 72",
                    camera=f'projection = "{proj}"\nazimuth = 4\nelevation = 3\nzoom = 1.0',
                    transfer="opacity = [[55, 0.0], [60, 0.6], [249, 0.6], [250, 1.0]]", shading="enabled = false",
                    render=BIG_TABLE + "early_termination = 0.9")
    ref = reference_render(sc, et=0.9)
    images = []
    for threads, per, least in [(1, 1, 1000), (1, 1, 1), (2, 2, 1), (3, 2, 4), (3, 5, 1), (2, 0, 0)]:      # (per 0: bands cut unevenly, as learned ones are)
        monkeypatch.setattr(F, "BANDS_PER_THREAD", per or 2)
        monkeypatch.setattr(F, "MIN_BAND_TILES", least or 1)
        if not per:
            monkeypatch.setattr(F, "band_rows", lambda *_: np.array([[0, 8], [8, 16], [16, 48], [48, 72]], np.int64))
        sc_t = make_scene(aug, idx, image="width = 100\nheight = 72",
                          camera=f'projection = "{proj}"\nazimuth = 4\nelevation = 3\nzoom = 1.0',
                          transfer="opacity = [[55, 0.0], [60, 0.6], [249, 0.6], [250, 1.0]]",
                          shading="enabled = false", render=BIG_TABLE + f"early_termination = 0.9\nthreads = {threads}")
        img, st_ = render(sc_t)
        images.append(img)
        assert st_.axis == "j"
        if least == 1000:       # one band: each voxel tested at most once
            behind = (dens[:, 2:] >= 55).sum()
            assert st_.voxels_tested - dens[:, :2].size < 0.3 * behind     # most material behind the wall is skipped
    assert all(np.array_equal(images[0], im) for im in images[1:])
    assert np.abs(images[0] - ref).max() <= 2e-4
