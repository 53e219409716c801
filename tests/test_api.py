"""isplat.render: one call from an array or a scan's path to a picture (notebooks)."""

import numpy as np
import pytest

import isplat
from isplat import api
from isplat.errors import IsplatError
from isplat.samples import make_sample


@pytest.fixture(scope="module")
def ct():
    return make_sample("ct-head", (40, 40, 36))


def test_render_equals_the_file_pipeline(tmp_path, ct):
    """The same picture as augment + index + a scene file with the same preset and camera."""
    from isplat.augment import augment_file
    from isplat.index import build_index_file
    from isplat.renderer import Renderer
    from isplat.scene import SCENE_VERSION, load_scene

    vol, spacing = ct
    rgba = isplat.render(vol, preset="ct-bone", azimuth=40, elevation=10, spacing=spacing, size=(48, 40))
    np.save(tmp_path / "ct.npy", vol)
    augment_file(tmp_path / "ct.npy", tmp_path / "ct.aug.h5", spacing=spacing)
    build_index_file(tmp_path / "ct.aug.h5", tmp_path / "ct.idx.h5")
    (tmp_path / "s.toml").write_text(f'version = {SCENE_VERSION}\n[data]\naugmented = "ct.aug.h5"\n'
                                     'index = "ct.idx.h5"\n'
                                     '[image]\nwidth = 48\nheight = 40\n[camera]\nazimuth = 40\nelevation = 10\n'
                                     '[transfer]\npreset = "ct-bone"\n')
    ref, _ = Renderer(load_scene(tmp_path / "s.toml")).render_view(0)
    assert np.array_equal(rgba, ref)
    assert rgba[..., :3].max() > 0.5


def test_a_path_renders_like_its_array(tmp_path, ct):
    vol, spacing = ct
    np.save(tmp_path / "ct.npy", vol)
    a = isplat.render(vol, preset="ct-skin", size=32)
    b = isplat.render(str(tmp_path / "ct.npy"), preset="ct-skin", size=32)
    assert np.array_equal(a, b)


def test_opacity_points_are_in_the_scans_values(ct):
    vol, spacing = ct
    clear = dict(spacing=spacing, size=32, shading=False, background=[0, 0, 0, 0])
    bone = isplat.render(vol, opacity=[[200, 0], [400, 1], [3000, 1]], **clear)
    skin = isplat.render(vol, opacity=[[-600, 0], [-300, 1], [3000, 1]], **clear)
    # the skin surrounds the bone: it covers more of the picture
    assert (skin[..., 3] > 0.5).sum() > (bone[..., 3] > 0.5).sum() > 0


def test_views_of_one_volume_augment_and_select_once(ct, monkeypatch):
    vol, spacing = ct
    api._CACHE.clear()
    api._SELECTIONS.clear()
    calls = {"augment": 0}
    real = api._augment

    def counting(*args):
        calls["augment"] += 1
        return real(*args)
    monkeypatch.setattr(api, "_augment", counting)
    frames = [isplat.render(vol, preset="ct-bone", azimuth=a, size=24) for a in (0, 20, 40)]
    assert calls["augment"] == 1
    assert len(api._SELECTIONS) == 1      # azimuths 0..40 share the j axis: one request, one selection
    assert not np.array_equal(frames[0], frames[2])


@pytest.mark.parametrize("kwargs, message", [
    (dict(), "give preset="),
    (dict(preset="nope"), "nope"),
    (dict(opacity=[[0, "x"]]), "not numbers"),
    (dict(preset="ct-bone", set=["camera.fov=500"]), "camera.fov"),
    (dict(preset="ct-bone", spacing=(1, -1, 1)), "spacing"),
])
def test_bad_arguments_are_one_clear_error(ct, kwargs, message):
    with pytest.raises(IsplatError, match=message):
        isplat.render(ct[0], **kwargs)


def test_a_flat_array_is_refused():
    with pytest.raises(IsplatError, match="3-D"):
        isplat.render(np.zeros((4, 4)), preset="ct-bone")
