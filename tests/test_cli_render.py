"""isplat render through the command line: outputs, batches, reports, and one-line errors."""

import json
import os
import subprocess
import sys

import imageio.v3 as iio
import numpy as np
import pytest

from conftest import scene_text, write_volume
from isplat.scene_schema import SCENE_VERSION


def run(*args, cwd=None, input=None):
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTEST")}
    env["ISPLAT_PROGRESS"] = "0"
    return subprocess.run([sys.executable, "-m", "isplat", *map(str, args)], capture_output=True, cwd=cwd,
                          input=input, env=env)


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("render")
    z, y, x = np.mgrid[:12, :14, :16]
    dens = (((x - 7.5) ** 2 + (y - 6.5) ** 2 + (z - 5.5) ** 2) < 25).astype(np.uint8) * 200
    dens[1:4, 1:4, 11:15] = 250                 # off-centre, so the views of an orbit differ
    aug, idx = write_volume(tmp, dens, name="ball")
    (tmp / "scene.toml").write_text(scene_text("ball.aug.h5", "ball.idx.h5",
                                               image="width = 32\nheight = 24",
                                               transfer="opacity = [[100, 0], [150, 0.8], [255, 0.8]]"))
    (tmp / "orbit.toml").write_text(scene_text("ball.aug.h5", "ball.idx.h5", image="width = 16\nheight = 16",
                                               transfer="opacity = [[100, 0], [150, 0.8], [255, 0.8]]",
                                               views="orbit_steps = 4"))
    return tmp


def error_line(res):
    err = res.stderr.decode().strip().splitlines()
    assert res.returncode != 0 and len(err) == 1 and err[0].startswith("isplat: error:"), res.stderr
    return err[0]


def test_png_file_and_verbose_report(data):
    res = run("render", "scene.toml", "-o", "a.png", "-v", cwd=data)
    assert res.returncode == 0, res.stderr
    img = iio.imread(data / "a.png")
    assert img.shape == (24, 32, 3) and img.dtype == np.uint8 and img.max() > 30
    err = res.stderr.decode()
    assert "bytes of index axes" in err and "view 0" in err and res.stdout == b""
    # read against needed, labelled by technique (docs/stats.md): post counts the voxels its quads read
    import re

    m = re.search(r"(pre|post): \d+ bytes read from the files .* for \d+ needed \(\d+ voxels (its quads read "
                  r"on axis [ijk]|of interest) x \d+ B \+ \d+ B of index; read/needed [0-9.]+x; in \d+ bytes of 4 KB pages, [0-9.]+x\)", err)
    assert m, err
    assert (m.group(1) == "post") == m.group(2).startswith("its quads")


def test_verbose_report_says_where_pre_read_its_values(data):
    """render -v with pre: the values file beside the index (its path and bytes), or, without it, the augmented
    file, said once with the command that writes it."""
    import shutil

    res = run("render", "scene.toml", "-o", "p.png", "-v", "--set", 'render.classification="pre"', cwd=data)
    assert res.returncode == 0, res.stderr
    err = res.stderr.decode()
    assert "channel values from values file " in err and ".values.idx.h5 (" in err, err
    vals = next(data.glob("*.values.idx.h5"))
    shutil.move(vals, data / "aside.h5")
    try:
        res = run("render", "scene.toml", "-o", "q.png", "-v", "--set", 'render.classification="pre"', cwd=data)
    finally:
        shutil.move(data / "aside.h5", vals)
    err = res.stderr.decode()
    assert res.returncode == 0 and "channel values from augmented bricks" in err, err
    assert err.count("has no values file") == 1 and "--force writes it" in err, err
    assert np.array_equal(iio.imread(data / "p.png"), iio.imread(data / "q.png"))      # the same image


def test_png_on_stdout_matches_the_file(data):
    run("render", "scene.toml", "-o", "b.png", cwd=data)
    res = run("render", "scene.toml", "-o", "-", cwd=data)
    assert res.returncode == 0 and res.stdout[:8] == b"\x89PNG\r\n\x1a\n"
    assert np.array_equal(iio.imread(res.stdout, extension=".png"), iio.imread(data / "b.png"))


def test_sixteen_bit_png_and_float_tiff(data):
    assert run("render", "scene.toml", "-o", "c.png", "--set", "image.bit_depth=16", cwd=data).returncode == 0
    import png
    w, h, rows, info = png.Reader(filename=str(data / "c.png")).read()
    assert info["bitdepth"] == 16 and (w, h) == (32, 24)
    assert run("render", "scene.toml", "-o", "c.tif", cwd=data).returncode == 0
    t = iio.imread(data / "c.tif")
    assert t.dtype == np.float32 and 0 <= t.min() and t.max() <= 1


def test_full_and_indexed_give_the_same_png(data):
    run("render", "scene.toml", "-o", "i.png", cwd=data)
    run("render", "scene.toml", "-o", "f.png", "--set", "render.method=full", cwd=data)
    assert np.array_equal(iio.imread(data / "i.png"), iio.imread(data / "f.png"))


def test_batch_numbered_frames_gif_and_view(data):
    assert run("render", "orbit.toml", "-o", "frame.png", cwd=data).returncode == 0
    assert sorted(p.name for p in data.glob("frame_*.png")) == [f"frame_{i:03d}.png" for i in range(4)]
    assert run("render", "orbit.toml", "-o", "orbit.gif", cwd=data).returncode == 0
    assert iio.imread(data / "orbit.gif", index=None).shape[0] == 4
    res = run("render", "orbit.toml", "--view", "2", "-o", "v2.png", "--json", cwd=data)
    rep = json.loads(res.stdout)
    assert rep["views"][0]["view"] == 2 and rep["method"] == "indexed"
    assert set(rep) >= {"axes_loaded", "channels_loaded", "intervals", "augmented_bytes_read", "index_bytes_read"}
    assert np.array_equal(iio.imread(data / "v2.png"), iio.imread(data / "frame_002.png"))


@pytest.mark.parametrize("args,needle", [
    (("render", "missing.toml"), "missing.toml"),
    (("render", "scene.toml", "--set", "camera.fov=abc", "-o", "x.png"), "camera.fov"),
    (("render", "scene.toml", "--set", "image.widht=3", "-o", "x.png"), "image.widht"),
    (("render", "scene.toml", "-o", "x.bmp"), ".bmp"),
    (("render", "orbit.toml", "-o", "-"), "standard output"),
    (("render", "orbit.toml", "--view", "9", "-o", "x.png"), "--view 9"),
    (("render", "scene.toml", "-o", "nofolder/x.png"), "does not exist"),
    (("render", "scene.toml", "--set", "data.index=ball.aug.h5", "-o", "x.png"), "isplat-index"),
    (("render", "scene.toml", "--set", "data.augmented=nothere.h5", "-o", "x.png"), "nothere.h5"),
])
def test_bad_input_is_one_line_and_leaves_nothing(data, args, needle):
    before = set(data.iterdir())
    line = error_line(run(*args, cwd=data))
    assert needle in line
    assert set(data.iterdir()) == before


def test_existing_output_needs_force(data):
    (data / "keep.png").write_bytes(b"mine")
    line = error_line(run("render", "scene.toml", "-o", "keep.png", cwd=data))
    assert "--force" in line and (data / "keep.png").read_bytes() == b"mine"
    assert run("render", "scene.toml", "-o", "keep.png", "--force", cwd=data).returncode == 0
    assert (data / "keep.png").read_bytes()[:4] == b"\x89PNG"


def test_scene_line_is_reported(data):
    (data / "bad.toml").write_text(scene_text("ball.aug.h5", "ball.idx.h5", camera="fov = 500"))
    line = error_line(run("render", "bad.toml", "-o", "x.png", cwd=data))
    assert "bad.toml:" in line and "camera.fov" in line and "500" in line


def test_an_old_version_says_once_which_defaults_it_keeps(data):
    """A scene that says an older version: one line on stderr per command (not per view) naming the defaults it
    keeps; the same scene without version (the current defaults) or with them set says nothing of the kind."""
    text = (data / "orbit.toml").read_text()
    (data / "orbit_v1.toml").write_text("version = 1\n" + text)
    res = run("render", "orbit_v1.toml", "-o", "v1.gif", cwd=data)
    assert res.returncode == 0, res.stderr
    notes = [ln for ln in res.stderr.decode().splitlines() if "keeps version-1 defaults" in ln]
    assert len(notes) == 1 and notes[0].startswith("orbit_v1.toml: version = 1 keeps version-1 defaults: "), notes
    assert 'render.classification = "pre"' in notes[0] and f"say version = {SCENE_VERSION}" in notes[0]
    assert "4 views, pre-classified" in res.stderr.decode()
    res = run("render", "orbit.toml", "-o", "v5.gif", cwd=data)
    assert res.returncode == 0 and b"keeps version-" not in res.stderr and b"post-classified" in res.stderr
    res = run("stats", "ball.aug.h5", "ball.idx.h5", "--scene", "orbit_v1.toml", "--json", cwd=data)
    assert res.returncode == 0, res.stderr
    notes = [ln for ln in res.stderr.decode().splitlines() if "keeps version-1 defaults" in ln]
    assert len(notes) == 1 and json.loads(res.stdout)["scene"] is not None, res.stderr
    res = run("render", "orbit_v1.toml", "-o", "v4.gif", "--set", "version=4", "--set", "camera.up=[0,0,1]",
              "--set", "volume.axes=[[1,0,0],[0,1,0],[0,0,1]]", cwd=data)
    assert res.returncode == 0 and b"post-classified" in res.stderr, res.stderr
    notes = [ln for ln in res.stderr.decode().splitlines() if "keeps version-4 defaults" in ln]
    # camera and axes set: only version 7's termination is kept (a version-4 file cannot set it)
    assert len(notes) == 1 and "render.termination" in notes[0] and "camera.view" not in notes[0] \
        and "volume.axes" not in notes[0], notes
    res = run("render", "orbit_v1.toml", "-o", "v6.gif", "--set", "version=6", "--set", "camera.up=[0,0,1]",
              "--set", "volume.axes=[[1,0,0],[0,1,0],[0,0,1]]", "--set", 'render.classification="pre"', cwd=data)
    assert res.returncode == 0 and b"keeps version-" not in res.stderr and b"pre-classified" in res.stderr, \
        res.stderr


@pytest.mark.parametrize("flags, built", [((), False), (("-q",), False), (("-v",), True), (("--json",), True)])
def test_the_report_is_built_only_when_printed(data, monkeypatch, flags, built):
    """The report's bytes needed take a pass over the selection (tens of ms of a one-frame process): a run
    that prints neither -v's lines nor --json's object does not build it."""
    import isplat.cli.render as cli_render
    from isplat.cli.main import main

    calls = []
    real = cli_render._report
    monkeypatch.setattr(cli_render, "_report", lambda *a: calls.append(1) or real(*a))
    monkeypatch.chdir(data)
    with pytest.raises(SystemExit) as exc:
        main(["render", "scene.toml", "-o", f"r{len(flags)}{''.join(flags)}.png", "--force", *flags])
    assert exc.value.code == 0
    assert bool(calls) == built
