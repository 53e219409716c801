"""Fast checks of numerical stability on stiff and extreme cases (docs/stability.md has the full table)."""

import numpy as np
import pytest

from isplat.bench.stability import FINE, Lab, centre, column, opacity_tf, ortho_down_k


@pytest.fixture
def lab(tmp_path):
    return Lab(tmp_path)


@pytest.mark.parametrize("precision", ["float32", "float64"])
@pytest.mark.parametrize("a, unit, n", [(1e-7, 1.0, 1024), (1e-9, 1e-6, 32), (0.5, 1e6, 32), (1 - 1e-12, 1.0, 4),
                                        (1.0, 1.0, 4)])
def test_slab_opacity_matches_the_stable_formula(lab, precision, a, unit, n):
    vol = lab.volume(np.full((n, 16, 16), 200, np.uint8))
    cam, _ = ortho_down_k(16, n)
    img, _, ok = lab.render(vol, camera=cam, transfer=opacity_tf(a, unit), precision=precision)
    assert ok
    expect = column(a, n / unit)
    assert abs(centre(img) - expect) <= 1e-4 * expect + 1e-12


@pytest.mark.parametrize("pos", [(0.0, 0.0, 0.0), (0.5, 0.5, 0.0), (0.0, 0.0, -0.5), (0.0, 0.0, -1e-9)])
def test_eye_on_a_voxel_or_slice_plane_is_finite(lab, pos):
    vol = lab.volume(np.full((9, 9, 9), 200, np.uint8))
    near = "\nnear = 1e-12" if pos[2] == -1e-9 else ""
    cam = (f'projection = "perspective"\nposition = [{pos[0]}, {pos[1]}, {pos[2]!r}]\n'
           f'look_at = [{pos[0]}, {pos[1]}, 10.0]\nup = [0, 1, 0]\nfov = 170{near}')
    img, _, ok = lab.render(vol, size=17, camera=cam, transfer=opacity_tf(0.3, 1.0))
    assert ok and 0.0 < img[8, 8, 3] <= 1.0


def test_early_termination_just_below_one_matches_off(lab):
    vol = lab.volume(np.full((32, 16, 16), 200, np.uint8))
    cam, _ = ortho_down_k(16, 32)
    imgs = [lab.render(vol, camera=cam, transfer=opacity_tf(0.5, 1.0),
                       render=FINE.replace("early_termination = 1.0", f"early_termination = {et}"))[0]
            for et in (1.0, 0.999999)]
    assert np.abs(imgs[0] - imgs[1]).max() <= 2e-6


def test_constant_volume_with_shading_is_lit_by_ambient_only(lab):
    vol = lab.augmented(np.full((8, 8, 8), 200.0, np.float32))
    cam, _ = ortho_down_k(8, 8, size=8)
    img, _, ok = lab.render(vol, size=8, camera=cam, transfer=opacity_tf(0.05, 1.0, color=(0.8, 0.8, 0.8)),
                            shading="enabled = true\nambient = 0.25")
    assert ok and abs(img[4, 4, 0] - 0.2) < 1e-5


def test_threads_do_not_change_the_image_with_early_termination(lab):
    rng = np.random.default_rng(3)
    dens = rng.choice(np.array([0, 200], np.uint8), size=(24, 48, 48), p=[0.3, 0.7])
    vol = lab.volume(dens)
    cam = 'projection = "orthographic"\nazimuth = 20\nelevation = 10'
    imgs = [lab.render(vol, size=64, camera=cam, transfer=opacity_tf(0.6, 1.0),
                       render=f"early_termination = 0.9\nthreads = {t}\n")[0] for t in (1, 2)]
    assert np.array_equal(imgs[0], imgs[1])
