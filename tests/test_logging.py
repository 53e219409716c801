"""Log lines through `logging` on stderr: shown by default, hidden by -q, debug detail with -v; never on stdout."""

import logging
import os
import subprocess
import sys

import numpy as np
import pytest

from conftest import scene_text, write_volume
from isplat import progress
from isplat.cli.main import main
from isplat.cli.options import set_verbosity


def run(capsys, *argv):
    """Run ``isplat argv`` in-process; return (exit code, stdout, stderr)."""
    with pytest.raises(SystemExit) as e:
        main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return e.value.code, out, err


@pytest.fixture(autouse=True)
def isplat_logger():
    """Put the ``isplat`` logger back as it was: the CLI configures it for the whole process."""
    logger = logging.getLogger("isplat")
    saved = logger.level, list(logger.handlers), logger.propagate
    yield logger
    logger.setLevel(saved[0])
    logger.handlers[:] = saved[1]
    logger.propagate = saved[2]


def sample(capsys, tmp_path, *flags, after=()):
    """``isplat FLAGS sample ... AFTER``, a tiny sample; returns (exit code, stdout, stderr)."""
    return run(capsys, *flags, "sample", "sphere", "-o", tmp_path / "s.npy", "--shape", "6,5,4", "--force", *after)


def test_default_shows_the_wrote_line_on_stderr_only(capsys, tmp_path):
    code, out, err = sample(capsys, tmp_path)
    assert code == 0 and err.startswith("isplat sample: wrote ") and err.count("\n") == 1
    assert out.startswith("isplat augment ") and out.count("\n") == 1 and "isplat sample" not in out


@pytest.mark.parametrize("flags", [("-q",), ("--quiet",)])
def test_quiet_on_the_group_or_the_subcommand_silences_log_lines(capsys, tmp_path, flags):
    assert sample(capsys, tmp_path, *flags)[2] == ""
    code, out, err = sample(capsys, tmp_path, after=flags)
    assert code == 0 and err == "" and out.startswith("isplat augment ")


def test_quiet_does_not_hide_errors(capsys, tmp_path):
    code, _, err = run(capsys, "-qq", "augment", tmp_path / "missing.npy", "-o", tmp_path / "m.aug.h5")
    assert code != 0 and err.startswith("isplat: error: ")


def test_verbose_adds_debug_detail(capsys, tmp_path):
    sample(capsys, tmp_path)
    args = ("augment", tmp_path / "s.npy", "-o", tmp_path / "s.aug.h5", "--force")
    code, _, plain = run(capsys, *args)
    assert code == 0 and "isplat augment: wrote" in plain and "read" not in plain
    code, out, err = run(capsys, "-v", *args)
    assert code == 0 and out == ""
    assert "isplat augment: read " in err and "slabs" in err and "isplat augment: wrote" in err


def test_verbose_and_quiet_counts_add_up(capsys, tmp_path):
    for flags, after in [(("-v", "-q"), ()), (("-vq",), ()), (("-v",), ("-q",))]:
        assert sample(capsys, tmp_path, *flags, after=after)[2].startswith("isplat sample: wrote")
    assert sample(capsys, tmp_path, "-q", after=("-q",))[2] == ""


def test_levels_and_progress_bars(isplat_logger, monkeypatch):
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True, raising=False)
    monkeypatch.delenv("ISPLAT_PROGRESS", raising=False)
    for verbosity, level, bars in [(1, logging.DEBUG, True), (0, logging.INFO, True), (-1, logging.WARNING, False),
                                   (-5, logging.CRITICAL, False), (5, logging.DEBUG, True)]:
        set_verbosity(verbosity)
        assert isplat_logger.level == level and progress.enabled() is bars
    monkeypatch.setenv("ISPLAT_PROGRESS", "0")
    assert not progress.enabled()


def test_library_use_shows_no_bars_until_logging_is_configured(isplat_logger, monkeypatch):
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True, raising=False)
    monkeypatch.delenv("ISPLAT_PROGRESS", raising=False)
    isplat_logger.setLevel(logging.NOTSET)          # as in a program that never touched logging (root: WARNING)
    assert not progress.enabled()
    isplat_logger.setLevel(logging.INFO)
    assert progress.enabled()


@pytest.mark.parametrize("where", ["group", "subcommand"])
def test_render_report_goes_to_stderr_and_the_image_to_stdout(tmp_path, where):
    dens = np.zeros((8, 8, 8), np.uint8)
    dens[2:6, 2:6, 2:6] = 200
    write_volume(tmp_path, dens, name="cube")
    (tmp_path / "s.toml").write_text(scene_text("cube.aug.h5", "cube.idx.h5", image="width = 8\nheight = 8",
                                                transfer="opacity = [[100, 0], [200, 0.5]]"))
    flags = ["-v", "render", "s.toml", "-o", "-"] if where == "group" else ["render", "s.toml", "-o", "-", "-v"]
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTEST")}
    res = subprocess.run([sys.executable, "-m", "isplat", *flags], capture_output=True, cwd=tmp_path, env=env)
    assert res.returncode == 0, res.stderr
    assert res.stdout.startswith(b"\x89PNG\r\n\x1a\n") and b"view 0" not in res.stdout
    err = res.stderr.decode().splitlines()
    assert err[0].startswith("read: ") and err[1].startswith("view 0: axis ") and len(err) == 3
    assert err[2].startswith("isplat render: stdout: 1 view, post-classified, indexed method, ")  # the summary
