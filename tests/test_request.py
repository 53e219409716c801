"""The render request (isplat.request) as the one cache key of a selection, over the scene schema.

Every key a selection depends on changes the request (and the image); every other key leaves the request as it
is, so the selection is reused; and whatever the order of the renders through one cache, each image is the
image of a renderer made afresh (what a new process draws).
"""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conftest import scene_text, write_volume
from isplat.renderer import Renderer
from isplat.request import RenderRequest, SelectionCache
from isplat.scene import parse_scene

# keys the selection depends on, each with two values (the first is the base scene's)
SELECTION_KEYS = {
    "transfer.opacity": ("[[50, 0.0], [60, 0.4], [200, 0.9]]", "[[90, 0.0], [130, 0.3], [200, 0.6]]"),
    "transfer.color": ("[[0, 1, 0.5, 0], [255, 0.2, 0.6, 1]]", "[[0, 0, 1, 0], [255, 1, 0, 0.5]]"),
    "transfer.gradient_opacity": ("[[0, 1], [255, 1]]", "[[0, 0.1], [200, 1]]"),
    "transfer.unit_distance": ("1.0", "4.0"),
    "shading.enabled": ("true", "false"),
    "render.classification": ('"post"', '"pre"'),
    "render.method": ('"indexed"', '"full"'),
    "volume.spacing": ("[1, 1, 1]", "[1, 1.4, 0.8]"),
    "data": ("v", "w"),                                 # another volume's files
}
# keys of a frame only: the selection is reused
FRAME_KEYS = {
    "camera.azimuth": ("20", "24"),
    "camera.elevation": ("12", "16"),
    "camera.zoom": ("1.0", "1.3"),
    "camera.projection": ('"orthographic"', '"perspective"'),
    "image.width": ("24", "30"),
    "image.height": ("20", "26"),
    "image.background": ("[0, 0, 0, 1]", "[1, 1, 1, 1]"),
    "render.threads": ("1", "2"),
    "render.early_termination": ("1.0", "0.95"),
    "render.precision": ('"float32"', '"float64"'),
    "shading.ambient": ("0.1", "0.35"),
}
# the indexed and the full method draw the same image by design (tests/test_render.py): only their requests differ
SAME_IMAGE = {"render.method"}


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """Two small volumes, ``v`` and ``w``, with random gradient magnitudes and normals."""
    from isplat.normals import encode

    tmp = tmp_path_factory.mktemp("request")
    for name, seed in (("v", 1), ("w", 2)):
        r = np.random.default_rng(seed)
        shape = (9, 11, 10)
        dens = r.choice(np.array([0, 60, 120, 200], np.uint8), size=shape, p=[0.5, 0.2, 0.15, 0.15])
        write_volume(tmp, dens, name=name, gm=r.integers(0, 256, shape), normal=encode(r.normal(size=shape + (3,))),
                     gscale=0.5)
    return tmp


def scene_of(files, choice: dict):
    """The scene whose key ``k`` takes value ``choice[k]`` (0 or 1) of SELECTION_KEYS or FRAME_KEYS."""
    keys = {**SELECTION_KEYS, **FRAME_KEYS}
    name = keys["data"][choice.get("data", 0)]
    over = [f"{k}={v[choice.get(k, 0)]}" for k, v in keys.items() if k != "data"]
    return parse_scene(scene_text(f"{name}.aug.h5", f"{name}.idx.h5"), files, "s.toml", over)


def fresh(scene):
    return Renderer(scene).render_view(0)[0]


@pytest.mark.parametrize("key", list(SELECTION_KEYS) + list(FRAME_KEYS))
def test_each_key_changes_the_request_and_the_image_or_neither(files, key):
    """One key changed from the base scene: a key of the selection changes the request, makes a new selection
    and changes the image (but the method, whose image is the same); a frame's key keeps the request, and the
    selection is reused. Either way the image is a fresh renderer's."""
    cache = SelectionCache()
    a = Renderer(scene_of(files, {}), cache=cache)
    img_a = a.render_view(0)[0]
    b = Renderer(scene_of(files, {key: 1}), cache=cache)
    img_b = b.render_view(0)[0]
    assert np.array_equal(img_b, fresh(b.scene))
    if key in SELECTION_KEYS:
        assert a.request != b.request and hash(a.request) != hash(b.request)
        assert b.selection is not a.selection and len(cache) == 2
        assert np.array_equal(img_a, img_b) == (key in SAME_IMAGE)
    else:
        assert a.request == b.request and b.selection is a.selection and len(cache) == 1
        assert not np.array_equal(img_a, img_b) or key == "render.threads"    # threads: the same image


ALL_KEYS = sorted({**SELECTION_KEYS, **FRAME_KEYS})
choices = st.fixed_dictionaries({k: st.integers(0, 1) for k in ALL_KEYS})


@settings(max_examples=24, derandomize=True, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(first=choices, flips=st.sets(st.sampled_from(ALL_KEYS), min_size=1, max_size=3))
def test_renders_through_one_cache_are_fresh_renders(files, first, flips):
    """Any scene of the schema, then the scene with up to three keys changed, rendered one after the other
    through one cache: the second image is the image a fresh renderer draws, and the selection is reused
    exactly when no key of the selection differs (and the views' principal axes are the same)."""
    second = {k: v ^ (k in flips) for k, v in first.items()}
    cache = SelectionCache()
    a = Renderer(scene_of(files, first), cache=cache)
    a.render_view(0)
    b = Renderer(scene_of(files, second), cache=cache)
    assert np.array_equal(b.render_view(0)[0], fresh(b.scene))
    same = all(first[k] == second[k] for k in SELECTION_KEYS) and a.request.axes == b.request.axes
    assert (a.request == b.request) == same == (b.selection is a.selection)


def test_a_file_changed_on_disk_is_another_request(files, tmp_path):
    """The files' identity (path, size, modification time) is in the request: a file rewritten in place is a
    new request, so no cache serves the old selection."""
    import os
    import shutil

    for ext in (".aug.h5", ".idx.h5"):
        shutil.copy(files / f"v{ext}", tmp_path / f"v{ext}")
    scene = parse_scene(scene_text("v.aug.h5", "v.idx.h5", transfer="opacity = [[50, 0], [200, 0.9]]"), tmp_path,
                        "s.toml")
    before = Renderer(scene).request
    os.utime(tmp_path / "v.aug.h5", ns=(1, 1))
    assert Renderer(scene).request != before


def test_the_notebook_sequence_gives_the_fresh_images():
    """issue 25: isplat.render() with transfer.unit_distance changed returned the image before (its cache key
    left the unit distance out), and render.classification = "pre" after a post-classified call was refused.
    Through the request both give what a fresh process (empty caches) draws."""
    import isplat
    from isplat import api
    from isplat.samples import make_sample

    ct, spacing = make_sample("ct-head", (40, 40, 36))
    calls = [[], ["transfer.unit_distance=4.0"], ['render.classification="pre"'], []]

    def render(keys):
        return isplat.render(ct, preset="ct-bone", spacing=spacing, size=40, set=keys)

    api._CACHE.clear()
    api._SELECTIONS.clear()
    seq = [render(keys) for keys in calls]
    assert len(api._SELECTIONS) == 3
    for keys, got in zip(calls, seq):
        api._CACHE.clear()
        api._SELECTIONS.clear()
        assert np.array_equal(got, render(keys)), keys
    assert not np.array_equal(seq[0], seq[1]) and not np.array_equal(seq[0], seq[2])
    assert np.array_equal(seq[0], seq[3])


def test_a_request_is_made_from_the_scene_and_its_files_alone(files):
    """What the request holds: resolved paths with size and modification time, the data's attributes, and the
    scene's transfer function as given (in codes)."""
    scene = scene_of(files, {})
    r = Renderer(scene).request
    assert isinstance(r, RenderRequest) and r.source[0] == "files"
    assert r.source[1][0] == str((files / "v.aug.h5").resolve()) and r.source[1][1] > 0
    assert r.transfer == scene.transfer and r.unit_distance == 1.0 and r.post and r.gradient
    full = Renderer(scene, method="full").request
    assert full.index is None and full.source[2] is None        # the full method reads no index


@pytest.mark.parametrize("units", ["codes", "data"])
@pytest.mark.parametrize("slabs", [None, 2])
def test_a_render_opens_each_file_once(files, tmp_path, monkeypatch, slabs, units):
    """isplat render (a scene in density codes, or in data units: its window read from the augmented file, which
    the Renderer then takes as it is): the augmented file is opened once, and the
    index once, by the selection (the memory check needs no index when even the whole volume would fit), or in
    slabs for all the slabs' selections."""
    from isplat import augfile, index
    from isplat.cli.main import main

    opened = {"aug": 0, "idx": 0}
    real_aug, real_idx = augfile.open_augmented, index.open_index
    def counted(name, real):
        return lambda p, **kw: opened.__setitem__(name, opened[name] + 1) or real(p, **kw)
    monkeypatch.setattr(augfile, "open_augmented", counted("aug", real_aug))
    monkeypatch.setattr(index, "open_index", counted("idx", real_idx))
    (tmp_path / "s.toml").write_text(scene_text(files / "v.aug.h5", files / "v.idx.h5", image="width = 16\nheight = 16",
                                                transfer="opacity = [[50, 0], [200, 0.9]]" + (
                                                    '\nunits = "data"' if units == "data" else "")))
    with pytest.raises(SystemExit) as exc:
        main(["render", str(tmp_path / "s.toml"), "-o", str(tmp_path / "a.png"), "-q",
              *([] if slabs is None else ["--slabs", str(slabs)])])
    assert exc.value.code in (0, None)
    assert opened == {"aug": 1, "idx": 1}
