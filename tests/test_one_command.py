"""isplat render AUG.h5: one command from an augmented file to a picture (issue 28 item 2), --print-scene, and the
scene-file render it equals bit for bit."""

import os
import tomllib

import numpy as np
import pytest

from conftest import scene_text, write_volume
from isplat.cli.main import main
from isplat.scene_input import index_beside, output_stem, to_toml

OPACITY = "[[100, 0], [150, 0.8], [255, 0.8]]"


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("onecmd")
    z, y, x = np.mgrid[:12, :14, :16]
    dens = (((x - 7.5) ** 2 + (y - 6.5) ** 2 + (z - 5.5) ** 2) < 25).astype(np.uint8) * 200
    dens[1:4, 1:4, 11:15] = 250                 # off-centre, so views differ
    write_volume(tmp, dens, name="ball")
    write_volume(tmp, dens, name="lone", index=False)
    return tmp


def run(capsys, monkeypatch, folder, *args):
    monkeypatch.chdir(folder)
    with pytest.raises(SystemExit) as exc:
        main(["render", *map(str, args)])
    cap = capsys.readouterr()
    return exc.value.code, cap.out, cap.err


def test_one_command_equals_the_scene_file(data, capsys, monkeypatch):
    """The augmented file with options, its --print-scene, and a scene file written by hand: the same PNG bytes."""
    opts = ("--set", f"transfer.opacity={OPACITY}", "--size", "40x30", "--set", "camera.azimuth=30")
    code, _, err = run(capsys, monkeypatch, data, "ball.aug.h5", *opts, "-o", "one.png", "--force")
    assert code == 0, err
    (data / "hand.toml").write_text(scene_text("ball.aug.h5", "ball.idx.h5", image="width = 40\nheight = 30",
                                               camera="azimuth = 30", transfer=f"opacity = {OPACITY}"))
    code, _, err = run(capsys, monkeypatch, data, "hand.toml", "-o", "hand.png", "--force")
    assert code == 0, err
    code, printed, err = run(capsys, monkeypatch, data, "ball.aug.h5", *opts, "--print-scene")
    assert code == 0 and not (data / "ball.png").exists(), err      # nothing rendered without -o
    tree = tomllib.loads(printed)
    assert tree["data"]["index"] == str(data / "ball.idx.h5") and tree["image"] == {"width": 40, "height": 30}
    (data / "printed.toml").write_text(printed)
    code, _, err = run(capsys, monkeypatch, data, "printed.toml", "-o", "printed.png", "--force")
    assert code == 0, err
    one = (data / "one.png").read_bytes()
    assert one == (data / "hand.png").read_bytes() == (data / "printed.png").read_bytes()


def test_print_scene_of_a_scene_file_renders_the_same(data, capsys, monkeypatch, tmp_path):
    """--print-scene of a scene file with --set: the overrides applied, the paths absolute (it renders anywhere)."""
    (data / "batch.toml").write_text(scene_text("ball.aug.h5", "ball.idx.h5", image="width = 20\nheight = 16",
                                                transfer=f"opacity = {OPACITY}", views="orbit_steps = 4"))
    code, _, err = run(capsys, monkeypatch, data, "batch.toml", "--view", "2", "--set", "camera.zoom=1.5", "-o",
                       "v2.png", "--force", "--print-scene")
    assert code == 0, err
    code, printed, err = run(capsys, monkeypatch, data, "batch.toml", "--set", "camera.zoom=1.5", "--print-scene")
    (tmp_path / "elsewhere.toml").write_text(printed)
    code, _, err = run(capsys, monkeypatch, tmp_path, "elsewhere.toml", "--view", "2", "-o", "p2.png")
    assert code == 0, err
    assert (data / "v2.png").read_bytes() == (tmp_path / "p2.png").read_bytes()


def test_index_beside_given_or_none(data, capsys, monkeypatch):
    opts = ("--set", f"transfer.opacity={OPACITY}", "--size", "24", "--print-scene")
    tree = tomllib.loads(run(capsys, monkeypatch, data, "ball.aug.h5", *opts)[1])
    assert tree["data"]["index"] == str(data / "ball.idx.h5") and "render" not in tree
    tree = tomllib.loads(run(capsys, monkeypatch, data, "lone.aug.h5", *opts, "--index", "ball.idx.h5")[1])
    assert tree["data"]["index"] == str(data / "ball.idx.h5")
    code, out, err = run(capsys, monkeypatch, data, "lone.aug.h5", *opts)
    tree = tomllib.loads(out)
    assert code == 0 and "index" not in tree["data"] and tree["render"]["method"] == "full"
    assert "no index beside lone.aug.h5" in err and "isplat index lone.aug.h5" in err
    code, _, err = run(capsys, monkeypatch, data, "lone.aug.h5", *opts[:-1], "-o", "lone.png", "--force")
    assert code == 0 and (data / "lone.png").exists(), err


@pytest.mark.parametrize("args, needle", [
    (("ball.aug.h5", "-o", "x.png"), "--preset"),
    (("ball.aug.h5", "--preset", "ct-bone", "--size", "0x5", "-o", "x.png"), "--size 0x5"),
    (("ball.aug.h5", "--preset", "ct-bone", "--print-scene", "-o", "-"), "stdout"),
    (("gone.aug.h5", "--preset", "ct-bone", "-o", "x.png"), "gone.aug.h5: augmented file does not exist"),
    (("ball.aug.h5", "--preset", "ct-bon", "-o", "x.png"), "did you mean 'ct-bone'"),
])
def test_bad_input_one_line(data, capsys, monkeypatch, args, needle):
    code, out, err = run(capsys, monkeypatch, data, *args, "-q")
    lines = err.strip().splitlines()
    assert code == 2 and out == "" and len(lines) == 1 and lines[0].startswith("isplat: error:"), err
    assert needle in lines[0], err
    assert not (data / "x.png").exists()


def test_names_and_toml_writer():
    assert output_stem("a/ct.aug.h5") == "ct" and output_stem("s.toml") == "s" and output_stem("x.h5") == "x"
    assert index_beside("a/mr.h5").name == "mr.idx.h5"
    tree = {"version": 5, "data": {"augmented": 'we"ird\\path\x7f'}, "cut": [{"point": [0.5, 1e300, -2.0]}],
            "shading": {"enabled": False, "light": [{"intensity": 0.5}]}, "a b": {"c": {"d": 1}}}
    assert tomllib.loads(to_toml(tree)) == tree


def test_image_sheets_say_they_splat_pre_classified(data, capsys, monkeypatch):
    """render.sheets = "image" says in one line that it is the paper's (pre-classified) splatting, and slower."""
    opts = ("ball.aug.h5", "--set", f"transfer.opacity={OPACITY}", "--size", "16", "-q", "--force")
    code, _, err = run(capsys, monkeypatch, data, *opts, "--set", "render.sheets=image", "-o", "sheets.png")
    assert code == 0 and err.count("\n") == 1 and "paper's splatting" in err and "render.sheets" in err, err
    code, _, err = run(capsys, monkeypatch, data, *opts, "-o", "axis.png")
    assert code == 0 and err == "", err


def test_a_fifo_is_refused_unopened(tmp_path, capsys, monkeypatch):
    """A fifo as the argument, named like a scene, like an augmented file or neither: one line, nothing blocks."""
    for name in ("pipe", "pipe.toml", "pipe.aug.h5"):
        os.mkfifo(tmp_path / name)
        code, _, err = run(capsys, monkeypatch, tmp_path, name, "--preset", "ct-bone", "-o", "x.png")
        assert code == 2 and err.count("\n") == 1 and "fifo" in err, err
