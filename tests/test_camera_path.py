"""Camera paths: keyframes interpolated at constant angular speed; first and last frames are the keyframes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from isplat.camera import orbit_direction
from isplat.camera_path import angles_between, spline
from isplat.errors import IsplatError
from isplat.scene import parse_scene

BASE = '[data]\naugmented = "a.h5"\nindex = "i.h5"\n[transfer]\nopacity = [[0, 1]]\n'


def views(text):
    return parse_scene(BASE + text, Path("/s"), "s.toml").views


def eye_dirs(cams):
    if cams[0].mode == "orbit":
        return np.array([orbit_direction(c.azimuth, c.elevation, c.up) for c in cams])
    w = np.array([np.subtract(c.position, c.look_at) for c in cams])
    return w / np.linalg.norm(w, axis=1)[:, None]


def _toml(keys):
    return "[" + ", ".join("{" + ", ".join(f"{k} = {v!r}".replace("(", "[").replace(")", "]") for k, v in d.items())
                           + "}" for d in keys) + "]"


orbit_key = st.fixed_dictionaries({"azimuth": st.floats(10, 120), "elevation": st.floats(-40, 40),
                                   "zoom": st.floats(0.5, 3)})


@settings(max_examples=40, deadline=None)
@given(keys=st.lists(orbit_key, min_size=2, max_size=4), start=st.floats(-400, 400), frames=st.integers(3, 80))
def test_orbit_path_ends_on_keyframes_with_constant_angular_step(keys, start, frames):
    # a path that goes round (azimuth increasing by 10..120 degrees a keyframe) and up and down
    az = start + np.cumsum([0.0] + [k["azimuth"] for k in keys[1:]])
    keys = [dict(k, azimuth=float(a)) for k, a in zip(keys, az)]
    turning = True
    cams = views(f"[views]\nframes = {frames}\npath = {_toml(keys)}\n")
    assert len(cams) == frames
    for cam, key in ((cams[0], keys[0]), (cams[-1], keys[-1])):
        assert (cam.azimuth, cam.elevation, cam.zoom) == (key["azimuth"], key["elevation"], key["zoom"])
    steps = angles_between(eye_dirs(cams)[:-1], eye_dirs(cams)[1:])
    # a path that turns, sampled finely enough that the angle between frames follows it (a path that doubles
    # back within one frame cannot have equal chords): every frame turns by the same angle
    if turning and steps.sum() > np.radians(5) and steps.mean() < np.radians(10):
        assert steps.max() - steps.min() <= 2e-3 * steps.mean() + 1e-9
    if len(keys) == 2:   # between two keyframes the zoom stays between theirs
        lo, hi = sorted((keys[0]["zoom"], keys[1]["zoom"]))
        assert all(lo * (1 - 1e-9) <= c.zoom <= hi * (1 + 1e-9) for c in cams)


@settings(max_examples=25, deadline=None)
@given(turns=st.lists(st.tuples(st.floats(15, 100), st.floats(20, 200), st.floats(-40, 40)), min_size=2, max_size=4),
       frames=st.integers(3, 30))
# up to a high keyframe and down again: the chord across its sharp turn starts at half the others, and used to
# make the re-timing give up on equal angles although the path never turns back
@example(turns=[(15, 20, 0), (15, 20, 34), (15, 20, 0)], frames=14)
def test_look_at_path(turns, frames):
    """Eyes going round the point looked at (each keyframe 15..100 degrees further), at any radius and height."""
    ang = np.radians(np.cumsum([t[0] for t in turns]))
    pos = [(1 + r * np.cos(a), 2 + r * np.sin(a), 3 + h) for a, (_, r, h) in zip(ang, turns)]
    keys = [{"position": tuple(float(x) for x in p), "look_at": (1.0, 2.0, 3.0)} for p in pos]
    cams = views(f"[camera]\nprojection = \"perspective\"\n[views]\nframes = {frames}\npath = {_toml(keys)}\n")
    assert cams[0].position == keys[0]["position"] and cams[-1].position == keys[-1]["position"]
    steps = angles_between(eye_dirs(cams)[:-1], eye_dirs(cams)[1:])
    if steps.mean() < np.radians(10):
        assert steps.max() - steps.min() <= 2e-3 * steps.mean() + 1e-9


def test_full_turn_and_smoothness():
    cams = views("[views]\nframes = 37\npath = [{azimuth = 0}, {azimuth = 180}, {azimuth = 360}]\n")
    az = np.array([c.azimuth for c in cams])
    assert az[-1] == 360 and np.allclose(np.diff(az), 10, atol=0.02)   # a full turn, 10 degrees a frame
    # C1 through the middle keyframe: no kink in the spline's velocity
    pts = np.array([[0.0, 0.0], [90.0, 30.0], [100.0, -10.0], [0.0, 0.0]])
    left = spline(pts, [1 - 1e-6, 1])
    right = spline(pts, [1, 1 + 1e-6])
    assert np.allclose((left[1] - left[0]), (right[1] - right[0]), atol=1e-9)


def test_zoom_only_stretch_gets_frames():
    cams = views("[views]\nframes = 21\npath = [{azimuth = 0}, {azimuth = 90}, {azimuth = 90, zoom = 3}]\n")
    zooms = [c.zoom for c in cams]
    assert sum(1 for z in zooms if 1.05 < z < 2.9) >= 5


@pytest.mark.parametrize("text, message", [
    ("[views]\npath = [{azimuth = 0}]", "expected an array of at least 2 camera tables"),
    ("[views]\nframes = 10", "views.frames = 10: needs views.path"),
    ("[views]\nframes = 1\npath = [{azimuth = 0}, {azimuth = 9}]", "expected an integer number of frames >= 2"),
    ("[views]\norbit_steps = 4\npath = [{azimuth = 0}, {azimuth = 9}]", "cannot be combined with views.orbit_steps"),
    ("[views]\npath = [{azimuth = 0}, {position = [0, -9, 0], look_at = [0, 0, 0]}]",
     's.toml:7: views.path[1] = {position = [0, -9, 0], look_at = [0, 0, 0]}: every keyframe of a path needs the '
     'same mode (keyframe 0 has "orbit", this one "look_at")'),
    ("[views]\npath = [{azimuth = 0}, {azimuth = 9, target = [1, 2, 3]}]", "give target in every keyframe or in none"),
    ("[views]\npath = [{azimuth = 0}, {azimuth = 9, fov = 200}]", "views.path[1].fov = 200"),
])
def test_path_errors(text, message):
    with pytest.raises(IsplatError) as info:
        views(text + "\n")
    assert message in str(info.value)


def test_render_path_to_numbered_frames(tmp_path):
    from conftest import scene_text, write_volume
    from isplat.cli.main import main

    d = np.zeros((8, 8, 8), np.uint8)
    d[2:6, 2:6, 2:6] = 200
    aug, idx = write_volume(tmp_path, d)
    scene = tmp_path / "p.toml"
    scene.write_text(scene_text(aug, idx, transfer="opacity = [[100, 0], [200, 1]]",
                                image="width = 16\nheight = 16",
                                views="frames = 3\npath = [{azimuth = 0}, {azimuth = 90}]"))
    with pytest.raises(SystemExit) as e:
        main(["render", str(scene), "-o", str(tmp_path / "f.png"), "-q"])
    assert e.value.code == 0
    assert sorted(p.name for p in tmp_path.glob("f_*.png")) == ["f_000.png", "f_001.png", "f_002.png"]


@pytest.mark.parametrize("ext", [".gif", ".mp4"])
def test_render_path_to_movie(tmp_path, ext):
    import imageio.v3 as iio

    from conftest import scene_text, write_volume
    from isplat.cli.main import main

    if ext == ".mp4":
        pytest.importorskip("imageio_ffmpeg")
    d = np.zeros((8, 8, 8), np.uint8)
    d[2:6, 2:6, 2:6] = 200
    aug, idx = write_volume(tmp_path, d)
    scene = tmp_path / "p.toml"
    scene.write_text(scene_text(aug, idx, transfer="opacity = [[100, 0], [200, 1]]",
                                image="width = 16\nheight = 16",
                                views="frames = 4\nfps = 8\npath = [{azimuth = 0}, {azimuth = 90, zoom = 2}]"))
    with pytest.raises(SystemExit) as e:
        main(["render", str(scene), "-o", str(tmp_path / f"p{ext}"), "-q"])
    assert e.value.code == 0
    frames = iio.imread(tmp_path / f"p{ext}", index=None)
    assert frames.shape[0] == 4
    meta = iio.immeta(tmp_path / f"p{ext}")
    assert abs(meta["duration"] - 125) <= 10 if ext == ".gif" else meta["fps"] == 8   # GIF: centiseconds
