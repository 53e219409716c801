"""render.supersample: frames at N times the image's size, box-filtered down (premultiplied)."""

import numpy as np
import pytest

from conftest import scene_text, write_volume
from isplat.errors import IsplatError
from isplat.renderer import Renderer
from isplat.scene import parse_scene


def box_down(rgba, n):
    """A finished (straight, over the background) image box-filtered by n: the means of the premultiplied
    values of each n x n block, straight again."""
    a = rgba[..., 3:4].astype(np.float64)
    pre = np.concatenate([rgba[..., :3] * a, a], axis=-1)
    h, w = rgba.shape[0] // n, rgba.shape[1] // n
    pre = pre.reshape(h, n, w, n, 4).mean(axis=(1, 3))
    return np.concatenate([np.where(pre[..., 3:] > 0, pre[..., :3] / np.maximum(pre[..., 3:], 1e-300), 0),
                           pre[..., 3:]], axis=-1)


@pytest.fixture(scope="module")
def volume(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("supersample")
    rng = np.random.default_rng(7)
    dens = rng.choice(np.array([0, 90, 160, 230], np.uint8), size=(9, 10, 11))
    return tmp, write_volume(tmp, dens, spacing=(1.0, 1.2, 0.8))


@pytest.mark.parametrize("n", [2, 3])
@pytest.mark.parametrize("camera", ['projection = "orthographic"\nazimuth = 30\nelevation = 20',
                                    'projection = "perspective"\nazimuth = 200\nelevation = -35\nfov = 40'])
def test_supersampled_scene_is_the_finer_render_box_filtered(volume, n, camera):
    tmp, (aug, idx) = volume

    def render(width, height, extra):
        text = scene_text(aug, idx, image=f"width = {width}\nheight = {height}\nbackground = [0.2, 0.3, 0.4, 0.5]",
                          camera=camera, transfer="opacity = [[80, 0.0], [100, 0.4], [255, 0.9]]\n"
                                                   "color = [[0, 1, 0.2, 0.1], [255, 0.1, 0.6, 1]]",
                          render=f"early_termination = 0.95\n{extra}")
        return Renderer(parse_scene(text, tmp, "s.toml")).render_view(0)[0]

    coarse = render(20, 14, f"supersample = {n}")
    fine = render(20 * n, 14 * n, "")
    assert coarse.shape == (14, 20, 4)
    assert np.abs(coarse - box_down(fine, n)).max() <= 2e-6
    assert np.abs(coarse - render(20, 14, "")).max() > 1e-2        # and it is not the plain render


@pytest.mark.parametrize("value, got", [("0", ""), ("9", ""), ("2.0", " (got a float)"), ('"2"', " (got a string)"),
                                        ("true", " (got a boolean)")])
def test_bad_supersample_is_one_clear_line(value, got):
    with pytest.raises(IsplatError) as info:
        parse_scene(f"[transfer]\nopacity = [[0, 0.0], [255, 1.0]]\n[render]\nsupersample = {value}\n", ".", "s.toml",
                    data_required=False)
    assert str(info.value) == (f"s.toml:4: render.supersample = {value}: expected an integer 1..8 (render at N times "
                               f"the width and height, box-filtered down; 1 = off){got}")


def test_streamed_frames_are_box_filtered_too(volume):
    """The slab-by-slab path (isplat render --slabs) box-filters the finer frame as one pass does."""

    tmp, (aug, idx) = volume
    text = scene_text(aug, idx, image="width = 16\nheight = 12\nbackground = [0, 0, 0, 0]",
                      transfer="opacity = [[80, 0.0], [100, 0.4], [255, 0.9]]",
                      render="early_termination = 1.0\nsupersample = 2")
    scene = parse_scene(text, tmp, "s.toml")
    one = Renderer(scene).render_view(0)[0]
    (_, streamed, _, _), = list(Renderer(scene, slabs=3).render_views())
    assert streamed.shape == one.shape and np.abs(streamed - one).max() <= 1e-5
