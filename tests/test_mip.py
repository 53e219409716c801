"""Maximum- and minimum-intensity projection (render.mode = "mip" / "minip", isplat.splat.mip) against the slow
brute-force reference (tests/mip_reference.py), the window's grey ramp, the scene's checks and the command line."""

import os
import subprocess
import sys

import imageio.v3 as iio
import numpy as np
import pytest
from conftest import post_setting, scene_text, write_volume
from hypothesis import given, settings
from hypothesis import strategies as st
from mip_reference import grey, mip_bounds, mip_reference

from isplat.errors import IsplatError
from isplat.frame import render_frame, views_for
from isplat.renderer import Renderer
from isplat.scene import parse_scene
from isplat.selection import Selection

TF = "opacity = [[0, 0.0], [99, 0.0], [100, 1.0], [255, 1.0]]"
TOL = 2e-6          # float32 image of d / 255 against the float64 reference


def lumpy(seed, shape):
    """Random densities with structure: smooth blobs plus noise, so that high values occlude and units get skipped."""
    r = np.random.default_rng(seed)
    z, y, x = np.meshgrid(*(np.linspace(-1, 1, n) for n in shape), indexing="ij")
    d = 60 + 180 * np.exp(-((x - r.uniform(-.5, .5)) ** 2 + (y - r.uniform(-.5, .5)) ** 2 + z ** 2) * 4)
    return np.clip(d + r.normal(0, 25, shape), 0, 255).astype(np.uint8)


def scene_for(aug, idx, tmp, mode="mip", camera="", cut="", render="", transfer=TF, image="width = 26\nheight = 22"):
    sections = dict(image=image, camera=camera, transfer=transfer, render=f'mode = "{mode}"\n{render}')
    if cut:
        sections["cut"] = cut
    return parse_scene(scene_text(aug, idx, **sections), tmp, "test.toml")


def within(rgba, dens, view, scene, mode):
    """The image (default window: grey = density / 255) lies between what rounding may make of the brute-force
    projection (tests/mip_reference.py, mip_bounds): equal to it but where a crossing lies on a quad's edge."""
    strict, loose, span = mip_bounds(dens, view, scene, mode)
    v = rgba[..., 0].astype(np.float64) * 255.0
    tol = TOL * 255
    lo, hi = (strict, loose) if mode == "mip" else (loose, strict)
    ok_nan = np.isnan(strict) | ~np.isnan(loose)        # strict sampled implies loose sampled
    assert ok_nan.all()
    sampled = ~np.isnan(loose)
    bg = grey(np.full(strict.shape, np.nan), scene.image.background)
    # no sample on any side: the background; sampled on every side: a value between the bounds
    assert np.abs(rgba[~sampled] - bg[~sampled]).max(initial=0) <= TOL
    must = ~np.isnan(strict)
    assert (v[must] >= lo[must] - tol).all() and (v[must] <= hi[must] + tol).all()
    maybe = sampled & ~must                    # sampled or not by a hair: the background or within the bounds
    ok = np.all(np.abs(rgba[maybe] - bg[maybe]) <= TOL, axis=-1) | (
        (v[maybe] >= span[0][maybe] - tol) & (v[maybe] <= span[1][maybe] + tol))
    assert ok.all()


def check(scene, dens, n=0):
    r = Renderer(scene)
    rgba, st_ = r.render_view(n)
    ref = grey(mip_reference(dens, r.views[n], scene, scene.render.mode), scene.image.background)
    assert np.abs(rgba - ref).max() <= TOL
    within(rgba, dens, r.views[n], scene, scene.render.mode)
    return st_


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("mip")
    dens = lumpy(3, (11, 12, 13))
    aug, idx = write_volume(tmp, dens, spacing=(1.0, 1.2, 0.9), name="lumpy")
    return tmp, aug, idx, dens


CAMERAS = ["azimuth = 0\nelevation = 0", "azimuth = 90\nelevation = 0", "azimuth = 33\nelevation = 21",
           "azimuth = 150\nelevation = -40", "azimuth = 0\nelevation = 90"]
CUT = "point = [0.0, 0.0, 0.0]\nnormal = [1.0, 0.4, -0.2]"


@pytest.mark.parametrize("cam", CAMERAS)
@pytest.mark.parametrize("proj", ["orthographic", "perspective"])
@pytest.mark.parametrize("mode", ["mip", "minip"])
def test_equals_the_brute_force_reference(data, cam, proj, mode):
    tmp, aug, idx, dens = data
    check(scene_for(aug, idx, tmp, mode, f'projection = "{proj}"\n{cam}'), dens)


@pytest.mark.parametrize("proj", ["orthographic", "perspective"])
@pytest.mark.parametrize("mode", ["mip", "minip"])
def test_with_a_cut_and_the_full_method(data, proj, mode):
    tmp, aug, idx, dens = data
    cam = f'projection = "{proj}"\nazimuth = 40\nelevation = 15'
    check(scene_for(aug, idx, tmp, mode, cam, cut=CUT), dens)
    check(scene_for(aug, idx, tmp, mode, cam, cut=CUT, render='method = "full"'), dens)


def test_perspective_eye_inside_the_volume(data):
    tmp, aug, idx, dens = data
    check(scene_for(aug, idx, tmp, "mip", 'projection = "perspective"\nmode = "look_at"\nposition = [6.0, 5.0, 4.0]\n'
                                          'look_at = [0.0, 0.0, 0.0]\nfov = 60'), dens)


def test_threads_and_views_give_the_same_pixels(data):
    tmp, aug, idx, dens = data
    imgs = []
    for threads in (1, 2, 3):
        sc = scene_for(aug, idx, tmp, "mip", "azimuth = 20\nelevation = 10", render=f"threads = {threads}")
        imgs.append(Renderer(sc).render_view(0)[0])
    assert all(np.array_equal(imgs[0], im) for im in imgs[1:])
    sc = parse_scene(scene_text(aug, idx, image="width = 20\nheight = 20", transfer=TF, render='mode = "mip"',
                                views="orbit_steps = 3"), tmp, "test.toml")
    for n in range(3):
        check(sc, dens, n)


def test_index_leaves_out_voxels_below_what_pixels_hold(tmp_path):
    """A bright slab in front of dimmer material: most units are skipped, and the image is still exact."""
    dens = np.full((16, 16, 16), 120, np.uint8)
    dens[:, :, 2:14] = np.random.default_rng(0).integers(110, 180, (16, 16, 12))
    dens[:, 2:14, 2:14][:, :, 0] = 250                  # a bright plane across the view
    dens[:, 0, :] = 250
    aug, idx = write_volume(tmp_path, dens, name="slab")
    sc = scene_for(aug, idx, tmp_path, "mip", "azimuth = 0\nelevation = 0", image="width = 24\nheight = 24")
    st_ = check(sc, dens)
    assert st_.classification == "mip" and st_.voxels_tested < 0.5 * st_.voxels_examined, st_
    assert st_.voxels_examined == int((dens >= 100).sum())


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10 ** 6), az=st.floats(-180, 180), el=st.floats(-89, 89),
       persp=st.booleans(), minip=st.booleans(), lo=st.integers(1, 200), shape=st.tuples(*[st.integers(2, 7)] * 3))
def test_random_volumes_and_views(seed, az, el, persp, minip, lo, shape):
    dens = np.random.default_rng(seed).integers(0, 256, shape).astype(np.uint8)
    _random_frame_within(dens, az, el, persp, minip, lo)


def _random_frame_within(dens, az, el, persp, minip, lo, spacing=None):
    """A 17 x 13 frame of ``dens`` (one thread; opacity 1 from code ``lo + 1``) from (az, el), equal to the
    reference but where a crossing is on a quad's edge (:func:`within`)."""
    mode = "minip" if minip else "mip"
    tf = f"opacity = [[0, 0.0], [{lo}, 0.0], [{lo + 1}, 1.0], [255, 1.0]]"
    text = (f'[image]\nwidth = 17\nheight = 13\n[camera]\nprojection = "{"perspective" if persp else "orthographic"}"'
            f'\nazimuth = {az}\nelevation = {el}\n[transfer]\n{tf}\n[render]\nmode = "{mode}"\nthreads = 1\n')
    scene = parse_scene(text, ".", "h.toml", data_required=False)
    sel = Selection.from_arrays(dens, scene, spacing=spacing)
    view = views_for(scene, sel)[0]
    rgba, _ = render_frame(sel, view)
    within(rgba, dens, view, scene, mode)


# ---- between thick slices: the post technique's cubic along the thick in-slice axis -----------------------------
def _between(kind):
    """Context: isplat.splat.post.BETWEEN_SLICES set to ``kind`` (which MIP follows, as the post technique)."""
    return post_setting("BETWEEN_SLICES", kind)


THICK = (1.0, 0.9, 4.5)         # spacing i, j, k: k five times the finest (isplat.splat.post.THICK_RATIO: 4)


@pytest.fixture(scope="module")
def thick_data(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("mip-thick")
    dens = lumpy(5, (6, 12, 13))
    aug, idx = write_volume(tmp, dens, spacing=THICK, name="thick")
    return tmp, aug, idx, dens


@pytest.mark.parametrize("cam", CAMERAS)
@pytest.mark.parametrize("proj", ["orthographic", "perspective"])
@pytest.mark.parametrize("mode", ["mip", "minip"])
def test_thick_slices_take_the_cubic_as_the_reference(thick_data, cam, proj, mode):
    """Slices 5 times thicker than the finest spacing: the image is the reference's with the cubic between the
    slices (indexed and full methods), and (views not along k) not the bilinear reference's."""
    tmp, aug, idx, dens = thick_data
    sc = scene_for(aug, idx, tmp, mode, f'projection = "{proj}"\n{cam}')
    check(sc, dens)
    check(scene_for(aug, idx, tmp, mode, f'projection = "{proj}"\n{cam}', render='method = "full"'), dens)
    if "elevation = 90" not in cam:          # the view along k: samples on the slices, nothing between them
        r = Renderer(sc)
        rgba = r.render_view(0)[0]
        with _between("linear"):
            lin = grey(mip_reference(dens, r.views[0], sc, mode), sc.image.background)
        assert np.abs(rgba - lin).max() > 1e-3


@pytest.mark.parametrize("cam", CAMERAS)
@pytest.mark.parametrize("mode", ["mip", "minip"])
def test_thick_slices_take_the_spline_as_the_reference(thick_data, cam, mode):
    """BETWEEN_SLICES "b-spline": the image is the reference's with the interpolating spline between the slices
    (its wider taps, MIP's bounds widened for its overshoot), indexed and full."""
    tmp, aug, idx, dens = thick_data
    with _between("b-spline"):
        check(scene_for(aug, idx, tmp, mode, cam), dens)
        check(scene_for(aug, idx, tmp, mode, cam, render='method = "full"'), dens)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10 ** 6), az=st.floats(-180, 180), el=st.floats(-89, 89), persp=st.booleans(),
       minip=st.booleans(), lo=st.integers(1, 200), shape=st.tuples(*[st.integers(2, 7)] * 3),
       thick=st.integers(0, 2), ratio=st.floats(4.0, 10.0), smooth=st.booleans())
def test_random_thick_volumes_and_views(seed, az, el, persp, minip, lo, shape, thick, ratio, smooth):
    """Random volumes (noise, or lumps whose cubic overshoots little) on grids with one axis ``ratio`` >= 4 times the
    others, any view, MIP and MinIP: the image is the cubic reference's but where a crossing is on a quad's edge
    (the units' bounds, widened for the cubic's overshoot, never skip a unit that would raise a pixel)."""
    dens = lumpy(seed, shape) if smooth else np.random.default_rng(seed).integers(0, 256, shape).astype(np.uint8)
    spacing = [1.0, 1.0, 1.0]
    spacing[thick] = ratio
    _random_frame_within(dens, az, el, persp, minip, lo, tuple(spacing))


@settings(max_examples=500, deadline=None)
@given(taps=st.lists(st.integers(0, 255), min_size=20, max_size=20), t=st.floats(0.0, 1.0), g=st.floats(0.0, 1.0),
       kind=st.sampled_from([0, 1, 2]), along=st.sampled_from([1, 2]), q=st.integers(0, 9),
       extreme=st.booleans())
def test_cubic_bounds_hold_every_sample_of_the_quad(taps, t, g, kind, along, q, extreme):
    """isplat.splat.mip._cubic_bounds: every density the post technique's cubic (any kind: the spline's wider
    taps too, clamped at the slice's ends) makes in a quad (any point) lies within the unit's bound, which is what
    lets a unit be skipped. ``extreme``: codes 0 and 255 only (the largest overshoots)."""
    from isplat.splat.mip import _cubic_bounds
    from isplat.splat.post import _density_at, _taps

    # a 10 x 2 slice (along a) or 2 x 10 (along b); the quad q along the thick axis
    n = 10
    n_a, n_b = (n, 2) if along == 1 else (2, n)
    vals = [255 * (x >= 128) for x in taps] if extreme else taps
    grid = np.asarray(vals, np.uint8).reshape(2, n)          # [row across, position along]
    density = np.ascontiguousarray(grid if along == 1 else grid.T).ravel()
    strides = np.array([1, n_a, n_a * n_b, 0], np.int64)
    qa, qb = (q, 0) if along == 1 else (0, q)
    from post_reference import NO_TABLE, kernel_offsets

    voxel = (density, density, density, kernel_offsets(strides, n_a, n_b, 0), n_a, n_b, 0, (along, kind, 0))
    fu, fv = (t, g) if along == 1 else (g, t)
    sa = strides[0] if qa + 1 < n_a else 0
    sb = strides[1] if qb + 1 < n_b else 0
    d = _density_at(density, qa * strides[0] + qb * strides[1], sa, sb, fu, fv, _taps(qa, qb, voxel), NO_TABLE)
    hi, lo = _cubic_bounds(density, 0, strides[0], strides[1], qa, qb, n_a, n_b, along, kind)
    assert lo - 1e-9 <= d <= hi + 1e-9, (d, lo, hi)


@pytest.mark.parametrize("spacing", [(1.0, 1.0, 1.0), (1.0, 1.2, 0.8), (0.7, 0.7, 2.5), (1.0, 1.0, 3.99)])
def test_below_the_ratio_images_are_the_bilinear_ones_bit_for_bit(tmp_path, spacing):
    """Isotropic data and grids less anisotropic than THICK_RATIO: the same bilinear samples as before, bit for
    bit, whatever BETWEEN_SLICES says; at 4.5:1 the cubic changes the picture (the switch is the ratio)."""
    dens = lumpy(9, (7, 8, 9))
    images = {}
    for sp in (spacing, (1.0, 1.0, 4.5)):
        aug, idx = write_volume(tmp_path, dens, spacing=sp, name=f"r{sp[2]}")
        sc = scene_for(aug, idx, tmp_path, "mip", "azimuth = 30\nelevation = 20")
        for kind in ("linear", "catmull-rom"):
            with _between(kind):
                images[sp, kind] = Renderer(sc).render_view(0)[0]
    assert images[spacing, "linear"][..., 0].max() > 0.3
    assert np.array_equal(images[spacing, "linear"], images[spacing, "catmull-rom"])
    assert not np.array_equal(images[(1.0, 1.0, 4.5), "linear"], images[(1.0, 1.0, 4.5), "catmull-rom"])


# ---- the window and the colours ----------------------------------------------------------------------------------
def _one(mode="mip", render="", tf=TF, dens=None):
    dens = np.full((3, 3, 3), 150, np.uint8) if dens is None else dens
    text = f'[image]\nwidth = 8\nheight = 8\n[transfer]\n{tf}\n[render]\nmode = "{mode}"\n{render}'
    scene = parse_scene(text, ".", "w.toml", data_required=False, density_window=(-1000.0, 1550.0))
    sel = Selection.from_arrays(dens, scene)
    return render_frame(sel, views_for(scene, sel)[0])[0][4, 4]


def test_window_default_is_the_whole_range():
    assert np.allclose(_one()[:3], 150 / 255, atol=1e-6)


def test_window_in_codes_data_units_and_by_name():
    assert np.allclose(_one(render="window = [100, 200]")[:3], 0.5, atol=1e-6)
    # data units: codes = (x + 1000) * 255 / 2550, so 150 is x = 500; [0, 1000] is codes 100..200
    tfd = 'units = "data"\nopacity = [[-1000, 0.0], [0, 0.0], [1, 1.0], [1550, 1.0]]'
    assert np.allclose(_one(render="window = [0, 1000]", tf=tfd)[:3], 0.5, atol=1e-6)
    # ct-bone is -700..1300 HU: codes 30..230, so 150 is 0.6
    assert np.allclose(_one(render='window = "ct-bone"')[:3], 0.6, atol=1e-6)
    assert np.allclose(_one(render="window = [160, 200]")[:3], 0.0) and _one(render="window = [0, 10]")[0] == 1.0


def test_transfer_colour_when_asked():
    tf = TF + "\ncolor = [[0, 1, 0, 0], [255, 0, 0, 1]]"
    px = _one(render='intensity_color = "transfer"', tf=tf)
    assert np.allclose(px[:3], [105 / 255, 0, 150 / 255], atol=1e-6) and px[3] == 1.0


# ---- the scene's checks: one line each -----------------------------------------------------------------------------
BASE = "[image]\nwidth = 8\nheight = 8\n[transfer]\nopacity = [[0, 0], [255, 1]]\n"


@pytest.mark.parametrize("text, needle", [
    ('[render]\nmode = "max"', 'test.toml:7: render.mode = "max": expected one of "composite", "mip", "minip"'),
    ('version = 5\n' + BASE + '[render]\nmode = "mip"',
     'render.mode = "mip": this key is new in scene version 6; the file says version = 5'),
    ('[render]\nwindow = [0, 100]', 'render.window applies to render.mode = "mip" or "minip"'),
    ('[render]\nmode = "mip"\nwindow = [100, 100]', "render.window = [100, 100]: expected [LO, HI] with LO < HI"),
    ('[render]\nmode = "mip"\nwindow = "ct-nope"', "expected [LO, HI] or a named window: ct-full, ct-bone"),
    ('[render]\nmode = "mip"\nclassification = "pre"', 'reconstructs the density as render.classification = "post"'),
    ('[render]\nmode = "minip"\nsheets = "image"', 'samples the slices of the principal axis; it takes render.sheets'),
    ('[render]\nmode = "mip"\nintensity_color = "red"', 'render.intensity_color = "red": expected one of'),
])
def test_scene_messages(text, needle):
    full = text if text.startswith("version") else BASE + text
    with pytest.raises(IsplatError) as exc:
        parse_scene(full, ".", "test.toml", data_required=False)
    msg = str(exc.value)
    assert needle in msg and "\n" not in msg, msg


def test_options_that_do_not_apply_warn(caplog):
    parse_scene(BASE + '[shading]\nenabled = true\n[render]\nmode = "mip"', ".", "t.toml", data_required=False)
    assert not caplog.records               # shading on is the default: nothing to say
    parse_scene(BASE + '[shading]\nambient = 0.5\n[render]\nmode = "mip"\nearly_termination = 0.5', ".", "t.toml",
                data_required=False)
    lines = [r.getMessage() for r in caplog.records]
    assert any("t.toml:7: shading.ambient does not apply to render.mode" in m for m in lines), lines
    assert any("render.early_termination does not apply" in m for m in lines), lines
    caplog.clear()
    parse_scene(BASE + '[render]\nmode = "mip"\ntermination = "stop"', ".", "t.toml", data_required=False)
    assert any("render.termination does not apply" in m for m in (r.getMessage() for r in caplog.records))
    with pytest.raises(IsplatError, match='a pixel is filled with the colour of its post-classified sample'):
        parse_scene(BASE + '[render]\nmode = "mip"\ntermination = "fill"', ".", "t.toml", data_required=False)


# ---- the command line -----------------------------------------------------------------------------------------------
def run(*args, cwd=None):
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTEST")}
    env["ISPLAT_PROGRESS"] = "0"
    return subprocess.run([sys.executable, "-m", "isplat", *map(str, args)], capture_output=True, cwd=cwd, env=env)


def test_cli_set_mode_reports_the_leave_out_figure(data):
    tmp, aug, idx, dens = data
    (tmp / "s.toml").write_text(scene_text(aug.name, idx.name, image="width = 26\nheight = 22", transfer=TF))
    res = run("render", "s.toml", "--set", 'render.mode="mip"', "-o", "m.png", "-v", cwd=tmp)
    assert res.returncode == 0, res.stderr
    err = res.stderr.decode()
    assert "voxels visited of" in err and "voxels of interest" in err and "(mip)" in err, err
    assert "1 view, mip, indexed method" in err
    img = iio.imread(tmp / "m.png")
    r = Renderer(scene_for(aug, idx, tmp, "mip", image="width = 26\nheight = 22"))
    ref = grey(mip_reference(dens, r.views[0], r.scene, "mip"), r.scene.image.background)
    assert np.abs(img / 255.0 - ref[..., :3]).max() <= 0.5 / 255 + 1e-9
    res = run("render", "s.toml", "--set", 'render.mode="mip"', "--slabs", "2", "-o", "n.png", cwd=tmp)
    err = res.stderr.decode().strip().splitlines()
    assert res.returncode != 0 and len(err) == 1 and "renders each frame in one pass" in err[0], err


@pytest.mark.parametrize("proj", ["orthographic", "perspective"])
@pytest.mark.parametrize("mode", ["mip", "minip"])
def test_vectorized_reference_is_the_slow_one(data, proj, mode):
    """The benchmark's reference (numpy, a slice's pixels at once) against the per-pixel one."""
    from mip_reference import mip_reference_vectorized
    from isplat.transfer import piecewise_linear

    tmp, aug, idx, dens = data
    sc = scene_for(aug, idx, tmp, mode, f'projection = "{proj}"\nazimuth = 40\nelevation = 15', cut=CUT)
    view = Renderer(sc).views[0]
    interest = piecewise_linear(sc.transfer.opacity, np.arange(256.0), True)[:, 0] > 0
    a = mip_reference(dens, view, sc, mode)
    b = mip_reference_vectorized(dens, view, interest, mode, sc.cuts)
    assert np.array_equal(np.isnan(a), np.isnan(b)) and np.nanmax(np.abs(a - b)) < 1e-9
