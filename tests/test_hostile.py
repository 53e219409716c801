"""Hostile input by hand (issue #30, item 6): outputs that are not regular files, inputs that would block, folders
that take no files, deep TOML, huge counts, racing writers, signals (also inside numba's load or compile), extreme
camera and volume numbers, augment options that make unreadable files, attribute types. Each ends in one line
naming the problem (or the right result), leaves nothing behind and overwrites nothing."""

import os
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from conftest import scene_text, write_volume
from fuzzlab import rehash

ROOT = Path(__file__).resolve().parents[1]


def run(*args, cwd=None, env=None, timeout=120):
    e = {k: v for k, v in os.environ.items() if not k.startswith("PYTEST")}
    e["ISPLAT_PROGRESS"] = "0"
    e.update(env or {})
    res = subprocess.run([sys.executable, "-m", "isplat", *map(str, args)], capture_output=True, cwd=cwd, env=e,
                         timeout=timeout)
    res.stderr = not_compiling(res.stderr.decode()).encode()
    return res


def not_compiling(err: str) -> str:
    """``err`` without the line that says kernels are being compiled: it depends on the kernel cache (stale
    after a kernel's file changed), not on the input under test (test_frame checks it)."""
    return "".join(line for line in err.splitlines(keepends=True) if "compiling the kernels" not in line)


def one_line(res, *needles, code=2):
    err = res.stderr.decode()
    assert res.returncode == code and err.count("\n") == 1 and err.startswith("isplat: error: "), err
    for n in needles:
        assert n in err, err
    return err


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("hostile")
    z, y, x = np.mgrid[:10, :12, :14]
    dens = (((x - 6.5) ** 2 + (y - 5.5) ** 2 + (z - 4.5) ** 2) < 16).astype(np.uint8) * 200
    write_volume(tmp, dens, name="ball")
    (tmp / "scene.toml").write_text(scene_text("ball.aug.h5", "ball.idx.h5", image="width = 16\nheight = 12",
                                               transfer="opacity = [[100, 0], [150, 0.8], [255, 0.8]]"))
    np.save(tmp / "scan.npy", dens)
    return tmp


def _write_cmds(data, out):
    """Every command that writes, each to ``out``."""
    return {"render": ["render", data / "scene.toml", "-o", out],
            "augment": ["augment", data / "scan.npy", "-o", out, "--spacing", "1,1,1"],
            "index": ["index", data / "ball.aug.h5", "-o", out],
            "sample": ["sample", "sphere", "-o", out, "--shape", "8,8,8"]}


NAMES = {"render": "o.png", "augment": "o.aug.h5", "index": "o.idx.h5", "sample": "o.npy"}


# ---------------------------------------------------------------------------------------------- 1. output nodes

@pytest.mark.parametrize("cmd", sorted(NAMES))
@pytest.mark.parametrize("node", ["fifo", "folder"])
@pytest.mark.parametrize("force", [False, True])
def test_output_that_is_not_a_regular_file_is_refused_even_with_force(data, tmp_path, cmd, node, force):
    out = tmp_path / NAMES[cmd]
    if node == "fifo":
        os.mkfifo(out)
    else:
        out.mkdir()
    args = _write_cmds(data, out)[cmd] + (["--force"] if force else [])
    one_line(run(*args), str(out), "folder" if node == "folder" else "fifo")
    mode = os.lstat(out).st_mode
    assert (stat.S_ISFIFO(mode) if node == "fifo" else stat.S_ISDIR(mode))
    assert sorted(p.name for p in tmp_path.iterdir()) == [out.name]         # no temporary file left
    if node == "folder":
        assert list(out.iterdir()) == []


@pytest.mark.parametrize("cmd", sorted(NAMES))
@pytest.mark.parametrize("force", [False, True])
def test_character_device_is_never_replaced(data, cmd, force):
    """/dev/null is refused before anything is written next to it or over it, with or without --force (the check
    is the first thing a writer does; /dev/null stays the system's character device)."""
    before = os.stat("/dev/null")
    args = _write_cmds(data, "/dev/null")[cmd] + (["--force"] if force else [])
    res = run(*args)
    # render and sample refuse the name first (no image or volume extension); the others for what it is
    one_line(res, "/dev/null", *(() if cmd in ("render", "sample") else ("character device",)))
    after = os.stat("/dev/null")
    assert stat.S_ISCHR(after.st_mode) and after.st_rdev == before.st_rdev and after.st_ino == before.st_ino


@pytest.mark.parametrize("cmd", sorted(NAMES))
def test_link_to_a_character_device_is_refused(data, tmp_path, cmd):
    """A name with the right extension that links to /dev/null: refused for what it points to, with --force."""
    link = tmp_path / NAMES[cmd]
    link.symlink_to("/dev/null")
    one_line(run(*_write_cmds(data, link)[cmd], "--force"), str(link), "character device")
    assert link.is_symlink() and os.readlink(link) == "/dev/null" and stat.S_ISCHR(os.stat("/dev/null").st_mode)
    assert sorted(p.name for p in tmp_path.iterdir()) == [link.name]


def test_character_device_named_like_an_image(data, monkeypatch, tmp_path):
    """A device whose name has an image's extension gets past the format check and is still refused (the check
    itself, with os.stat reporting a character device for that name)."""
    from isplat import fileio
    from isplat.errors import IsplatError

    target = tmp_path / "dev.png"
    target.write_bytes(b"")
    real = os.stat

    class Dev:
        st_mode = stat.S_IFCHR | 0o666

    monkeypatch.setattr(fileio.os, "stat", lambda p, *a, **k: Dev() if Path(p) == target else real(p, *a, **k))
    with pytest.raises(IsplatError, match="character device"):
        fileio.check_output(target, force=True)
    with pytest.raises(IsplatError, match="character device"):
        with fileio.atomic_output(target, force=True):
            pass
    assert target.read_bytes() == b"" and sorted(p.name for p in tmp_path.iterdir()) == ["dev.png"]


def test_stdout_still_takes_an_image(data):
    res = subprocess.run([sys.executable, "-m", "isplat", "render", "scene.toml", "-o", "-"], cwd=data,
                         capture_output=True, env={**os.environ, "ISPLAT_PROGRESS": "0"})
    assert res.returncode == 0 and res.stdout.startswith(b"\x89PNG")


# ---------------------------------------------------------------------------------------------- 2. input nodes

@pytest.mark.parametrize("what", ["scene", "augmented", "index", "stats", "stats-index", "augment", "set-data"])
def test_fifo_input_is_refused_at_once(data, tmp_path, what):
    fifo = tmp_path / {"scene": "s.toml", "augment": "scan.npy"}.get(what, "f.h5")
    os.mkfifo(fifo)
    args = {"scene": ["render", fifo, "-o", tmp_path / "o.png"],
            "augmented": ["index", fifo, "-o", tmp_path / "o.idx.h5"],
            "index": ["stats", data / "ball.aug.h5", fifo],
            "stats": ["stats", fifo],
            "stats-index": ["stats", data / "ball.aug.h5", fifo, "--json"],
            "augment": ["augment", fifo, "-o", tmp_path / "o.aug.h5", "--spacing", "1,1,1"],
            "set-data": ["render", data / "scene.toml", "--set", f"data.augmented={fifo}", "-o",
                         tmp_path / "o.png"]}[what]
    one_line(run(*args, timeout=60), str(fifo), "fifo")
    assert sorted(p.name for p in tmp_path.iterdir()) == [fifo.name]


# ---------------------------------------------------------------------------------------------- 3. output folders

@pytest.mark.parametrize("cmd", sorted(NAMES))
def test_folder_that_takes_no_files_is_refused_before_work(data, cmd):
    out = f"/proc/{NAMES[cmd]}"
    t = time.monotonic()
    one_line(run(*_write_cmds(data, out)[cmd]), out, "output folder /proc")
    assert time.monotonic() - t < 60


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes in read-only folders")
def test_read_only_folder_refused(data, tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir(mode=0o500)
    one_line(run("render", data / "scene.toml", "-o", ro / "x.png"), "cannot create files")


def test_write_failure_in_the_block_is_one_line(tmp_path):
    """An OSError while the output is written (a full disk) is one IsplatError naming the output; nothing is
    left."""
    import errno

    from isplat.errors import IsplatError
    from isplat.fileio import atomic_output

    with pytest.raises(IsplatError, match=r"o\.bin: writing failed \(No space left on device\)"):
        with atomic_output(tmp_path / "o.bin") as tmp:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------------------------------- 4. TOML nesting

@pytest.mark.parametrize("text", ["a = " + "[" * 5000 + "]" * 5000, "a = " + "{b = " * 5000 + "1" + "}" * 5000,
                                  "a = " + "[" * 5000])
def test_deeply_nested_scene_is_one_line(tmp_path, text):
    (tmp_path / "deep.toml").write_text(text)
    one_line(run("render", tmp_path / "deep.toml", "-o", tmp_path / "x.png"), "deep.toml:1", "nested 33 deep")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["deep.toml"]


def test_deeply_nested_override_is_one_line(data, tmp_path):
    one_line(run("render", data / "scene.toml", "--set", "camera.azimuth=" + "[" * 3000 + "]" * 3000, "-o",
                 tmp_path / "x.png"), "--set camera.azimuth=", "nested")


def test_huge_scene_is_refused_unread(tmp_path, monkeypatch):
    from isplat import limits
    from isplat.errors import IsplatError
    from isplat.scene import load_scene

    (tmp_path / "big.toml").write_text("# " + "x" * 5000 + "\n")
    monkeypatch.setattr("isplat.scene.MAX_SCENE_BYTES", 1000)
    with pytest.raises(IsplatError, match="big.toml: scene file is 5003 bytes, more than the 1000"):
        load_scene(tmp_path / "big.toml")
    assert limits.MAX_SCENE_BYTES >= 1 << 20


def test_nesting_scan_ignores_strings_and_comments():
    from isplat.limits import check_toml_text

    deep = "[" * 100
    check_toml_text("s", f'a = "{deep}"\nb = \'{deep}\'\nc = """\n{deep}\n"""\nd = \'\'\'{deep}\'\'\'\n# {deep}\n'
                         f'e = "\\"{deep}"\n[[f]]\n[g.h]\ni = [[1, 2], [3, {{j = [4]}}]]\n')


# ---------------------------------------------------------------------------------------------- 5. counts

@pytest.mark.parametrize("setting,key", [("views.orbit_steps=1000000000", "views.orbit_steps"),
                                         ("views.frames=1000000000", "views.frames")])
def test_view_counts_refused_before_they_grow(data, tmp_path, setting, key):
    extra = ["--set", "views.path=[{azimuth = 0}, {azimuth = 90}]"] if key == "views.frames" else []
    t = time.monotonic()
    one_line(run("render", data / "scene.toml", *extra, "--set", setting, "-o", tmp_path / "o.gif"), key,
             "at most 100000")
    assert time.monotonic() - t < 30 and list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------------------------------- 6. exclusive outputs

def test_output_that_appears_meanwhile_is_not_replaced(tmp_path):
    from isplat.errors import IsplatError
    from isplat.fileio import atomic_output

    out = tmp_path / "o.idx.h5"
    with pytest.raises(IsplatError, match="appeared while isplat was writing it"):
        with atomic_output(out) as tmp:
            Path(tmp).write_bytes(b"second")
            out.write_bytes(b"first")                   # another writer finished first
    assert out.read_bytes() == b"first" and sorted(p.name for p in tmp_path.iterdir()) == ["o.idx.h5"]
    with atomic_output(out, force=True) as tmp:         # --force replaces it
        Path(tmp).write_bytes(b"forced")
    assert out.read_bytes() == b"forced" and sorted(p.name for p in tmp_path.iterdir()) == ["o.idx.h5"]


def test_exclusive_without_hard_links(tmp_path, monkeypatch):
    """Where the file system has no hard links, an O_EXCL placeholder takes the name."""
    import errno

    from isplat import fileio
    from isplat.errors import IsplatError

    def no_link(a, b):
        raise OSError(errno.EPERM, "Operation not permitted")

    monkeypatch.setattr(fileio.os, "link", no_link)
    out = tmp_path / "o.bin"
    with fileio.atomic_output(out) as tmp:
        Path(tmp).write_bytes(b"one")
    assert out.read_bytes() == b"one"
    out.unlink()
    with pytest.raises(IsplatError, match="appeared"):
        with fileio.atomic_output(out) as tmp:
            Path(tmp).write_bytes(b"two")
            out.write_bytes(b"other")
    assert out.read_bytes() == b"other" and sorted(p.name for p in tmp_path.iterdir()) == ["o.bin"]


def test_two_index_runs_to_one_new_path(data, tmp_path):
    """Both start while the path is new; one writes it, the other fails with one line and leaves it alone."""
    out = tmp_path / "o.idx.h5"
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTEST")}
    procs = [subprocess.Popen([sys.executable, "-m", "isplat", "index", str(data / "ball.aug.h5"), "-o", str(out),
                               "-q"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env) for _ in range(2)]
    results = [(p.wait(timeout=120), p.stderr.read().decode()) for p in procs]
    codes = sorted(c for c, _ in results)
    assert codes == [0, 2], results
    err = next(e for c, e in results if c == 2)
    assert err.count("\n") == 1 and ("appeared while" in err or "output exists" in err), err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o.idx.h5", "o.runs.idx.h5", "o.values.idx.h5"]
    from isplat.index import open_index
    from isplat.runsfile import open_runs

    idx = open_index(out)
    assert idx.values_file is not None      # the winner's pair: the values file matches its index
    open_runs(tmp_path / "o.runs.idx.h5", shape=idx.shape, density_sha256=idx.density_sha256).close()


# ---------------------------------------------------------------------------------------------- 7. signals

def _popen(args, env=None, script=None, cwd=None):
    e = {k: v for k, v in os.environ.items() if not k.startswith("PYTEST")}
    e["ISPLAT_PROGRESS"] = "0"
    e.update(env or {})
    head = [sys.executable, "-c", script] if script else [sys.executable, "-m", "isplat"]
    # SIGINT as an interactive shell leaves it: a test run started in the background (``make test &``, CI under
    # some runners) hands its children SIGINT ignored, and isplat rightly keeps an ignored SIGINT ignored
    return subprocess.Popen(head + [str(a) for a in args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            env=e, cwd=cwd, text=True, preexec_fn=_default_sigint)


def _default_sigint():
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _interrupted(p, sig, timeout=180):
    _, err = p.communicate(timeout=timeout)
    lines = err.strip().splitlines()
    assert p.returncode == 128 + sig, (p.returncode, err)
    assert lines and lines[-1].startswith(f"isplat: interrupted ({signal.Signals(sig).name})"), err
    assert "Traceback" not in err and "compiled object" not in err, err
    assert all(line.startswith("isplat: ") for line in lines), err
    return lines[-1]


@pytest.mark.parametrize("sig,delay", [(signal.SIGINT, 1.5), (signal.SIGTERM, 1.5), (signal.SIGINT, 4.0)])
def test_signal_during_kernel_compile(data, tmp_path, sig, delay):
    """An empty numba cache (and no prebuilt kernels) forces the first render to compile: a signal delivered
    meanwhile is held until the kernel being compiled is whole, then ends the run: 130/143, one line, no
    segfault, nothing written."""
    cache = tmp_path / "cache"
    cache.mkdir()
    out = tmp_path / "o.gif"
    p = _popen(["render", data / "scene.toml", "--set", "views.orbit_steps=2", "-o", out],
               env={"NUMBA_CACHE_DIR": str(cache), "ISPLAT_PREBUILT": "none"})
    time.sleep(delay)
    p.send_signal(sig)
    line = _interrupted(p, sig)
    assert "removed" not in line or "o.gif" in line
    assert sorted(x.name for x in tmp_path.iterdir()) == ["cache"]


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
@pytest.mark.parametrize("delay", [0.4, 0.8])
def test_signal_while_the_command_starts(data, tmp_path, sig, delay):
    """Handlers are installed by the first lines of isplat.cli.main: a signal while click, numpy, h5py and the
    stages are imported is one line and 130/143, not a traceback or a bare -15."""
    p = _popen(["render", data / "scene.toml", "-o", tmp_path / "o.png"])
    time.sleep(delay)
    p.send_signal(sig)
    err = not_compiling(p.communicate(timeout=120)[1])
    if p.returncode == 0:                       # the render finished before the signal came
        return
    assert p.returncode == 128 + sig and err.count("\n") == 1, err
    assert err.startswith(f"isplat: interrupted ({signal.Signals(sig).name})"), err
    assert [x.name for x in tmp_path.iterdir()] in ([], ["o.png"])    # the image whole, or nothing


SLOW_INDEX_LOG = """
import sys, time
import isplat.index as ix
real = ix.open_index
def slow(path):
    print("renamed", flush=True)
    time.sleep(30)
    return real(path)
ix.open_index = slow
from isplat.cli.main import main
main(sys.argv[1:])
"""


def _slowed(module: str, name: str, word: str) -> str:
    """A script that runs the CLI with ``module.name`` printing ``word`` and sleeping 30 s before it works."""
    return f"""
import sys, time
import {module} as m
real = m.{name}
def slow(*a, **k):
    print("{word}", flush=True)
    time.sleep(30)
    return real(*a, **k)
m.{name} = slow
from isplat.cli.main import main
main(sys.argv[1:])
"""


SLOW_VALUES = _slowed("isplat.index.store", "copy_values", "values")


def test_sigint_while_the_values_file_is_written_leaves_neither_file(data, tmp_path):
    """The index and its values file are committed together at the end (index first): a signal while the values
    are copied leaves neither, nor their temporary files (formats/index.md §9.1)."""
    out = tmp_path / "o.idx.h5"
    p = _popen(["index", data / "ball.aug.h5", "-o", out], script=SLOW_VALUES)
    assert p.stdout.readline().strip() == "values"
    p.send_signal(signal.SIGINT)
    _interrupted(p, signal.SIGINT, timeout=60)
    assert sorted(x.name for x in tmp_path.iterdir()) == []


SLOW_RUNS = _slowed("isplat.runsfile", "write_runs", "runs")


def test_sigint_while_the_runs_file_is_written_leaves_the_index_alone(data, tmp_path):
    """The runs file is written after the index and its values file are in place: a signal while it is written
    leaves those two, and no runs file nor its temporary file (formats/runs.md §1)."""
    out = tmp_path / "o.idx.h5"
    p = _popen(["index", data / "ball.aug.h5", "-o", out], script=SLOW_RUNS)
    assert p.stdout.readline().strip() == "runs"
    p.send_signal(signal.SIGINT)
    _interrupted(p, signal.SIGINT, timeout=60)
    assert sorted(x.name for x in tmp_path.iterdir()) == ["o.idx.h5", "o.values.idx.h5"]


def test_sigint_after_the_output_is_in_place_says_no_removal(data, tmp_path):
    out = tmp_path / "o.idx.h5"
    p = _popen(["index", data / "ball.aug.h5", "-o", out], script=SLOW_INDEX_LOG)
    assert p.stdout.readline().strip() == "renamed"
    p.send_signal(signal.SIGINT)
    line = _interrupted(p, signal.SIGINT, timeout=60)
    assert line == "isplat: interrupted (SIGINT)"
    from isplat.index import open_index

    assert open_index(out).values_file is not None
    assert sorted(x.name for x in tmp_path.iterdir()) == ["o.idx.h5", "o.runs.idx.h5", "o.values.idx.h5"]


SWALLOWING_WRITE = """
import sys, time
import imageio.v3 as iio
real = iio.imwrite
def swallowing(*a, **k):
    real(*a, **k)
    print("writing", flush=True)
    try:
        time.sleep(30)
    except BaseException:
        pass                                      # a library that swallows the interrupt
iio.imwrite = swallowing
from isplat.cli.main import main
main(sys.argv[1:])
"""


def test_sigterm_swallowed_on_the_way_still_ends_the_run(data, tmp_path):
    """A SIGTERM whose exception some code swallows is not lost: nothing is moved into place after it (the GIF
    already there under --force stays), and the exit is 143."""
    out = tmp_path / "o.gif"
    out.write_bytes(b"old")
    p = _popen(["render", data / "scene.toml", "--set", "views.orbit_steps=2", "-o", out, "--force", "-q"],
               script=SWALLOWING_WRITE)
    assert p.stdout.readline().strip() == "writing"
    p.send_signal(signal.SIGTERM)
    line = _interrupted(p, signal.SIGTERM, timeout=60)
    assert "incomplete outputs removed" in line and "o.gif" in line
    assert out.read_bytes() == b"old" and sorted(x.name for x in tmp_path.iterdir()) == ["o.gif"]


def test_signal_turned_into_another_error_by_compiled_code_is_the_signal(data, tmp_path, monkeypatch, capsys):
    """h5py's lock turns a Terminated raised inside its attribute-iteration callback into ``SystemError: ...
    returned a result with an exception set`` (seen in CI): the signal behind it still ends the run in one line
    with 130, not a traceback."""
    from isplat import chunkhash, interrupts
    from isplat.cli.main import main

    def interrupted(*args, **kwargs):
        try:
            raise interrupts.Terminated(signal.SIGINT)
        except interrupts.Terminated as exc:
            raise SystemError("<cyfunction FastRLock.__exit__> returned a result with an exception set") from exc

    monkeypatch.setattr(chunkhash, "attributes_of", interrupted)
    with pytest.raises(SystemExit) as code:
        main(["render", str(data / "scene.toml"), "-o", str(tmp_path / "o.png")])
    err = capsys.readouterr().err
    assert code.value.code == 130 and err.startswith("isplat: interrupted (SIGINT)") and err.count("\n") == 1, err
    assert list(tmp_path.iterdir()) == []
    interrupts.reset()


def test_other_errors_are_not_taken_for_signals():
    from isplat import interrupts

    try:
        try:
            raise ValueError("a")
        except ValueError as inner:
            raise SystemError("b") from inner
    except SystemError as exc:
        assert interrupts.signal_behind(exc) is None
        assert interrupts.signal_behind(exc.__cause__) is None


def test_deferred_signal_is_raised_when_the_block_ends():
    from isplat import interrupts

    previous = interrupts.install()
    try:
        interrupts.reset()
        with pytest.raises(interrupts.Terminated) as exc:
            with interrupts.deferred():
                os.kill(os.getpid(), signal.SIGTERM)
                time.sleep(0.05)
                reached = True
        assert reached and exc.value.signum == signal.SIGTERM
    finally:
        interrupts.restore(previous)
        interrupts.reset()


# ---------------------------------------------------------------------------------------------- 8. extreme numbers

@pytest.mark.parametrize("settings,needles", [
    (["camera.zoom=1e308"], ["camera.zoom = 1e+308", "float64 precision"]),
    (["camera.zoom=1e13"], ["camera.zoom = 1e+13", "expected a zoom between"]),
    (["camera.zoom=1e-320"], ["camera.zoom", "float64 precision"]),
    (["volume.origin=[1e308, 0, 0]"], ["volume.origin", "lose float64 precision"]),
    (["volume.origin=[1e17, 0, 0]"], ["volume.origin", "lose float64 precision"]),
    (["camera.projection=\"perspective\"", "camera.mode=\"look_at\"", "camera.position=[1e300, 0, 0]",
      "camera.look_at=[0, 0, 0]"],
     ["camera's target, position or distance"]),
])
def test_camera_and_volume_numbers_that_lose_precision(data, tmp_path, settings, needles):
    args = [a for s in settings for a in ("--set", s)]
    res = run("render", data / "scene.toml", *args, "-o", tmp_path / "o.png")
    one_line(res, *needles)                              # one line: no numpy RuntimeWarning either
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("settings", [["camera.projection=\"perspective\"", "camera.fov=170"],
                                      ["camera.projection=\"perspective\"", "camera.fov=179.82"],
                                      ["camera.zoom=1e-9"],
                                      ["camera.target=[1000, 0, 0]"]])
def test_empty_frame_is_said(data, tmp_path, settings):
    args = [a for s in settings for a in ("--set", s)]
    res = run("render", data / "scene.toml", *args, "-o", tmp_path / "o.png")
    err = res.stderr.decode()
    # the warning, then render's one-line summary
    lines = err.splitlines()
    assert res.returncode == 0 and len(lines) == 2 and lines[0].startswith("isplat: warning: "), err
    assert lines[1].startswith("isplat render: "), err
    assert "the frame is empty or nearly" in err and (tmp_path / "o.png").exists()


def test_ordinary_views_say_nothing(data, tmp_path):
    res = run("render", data / "scene.toml", "--set", "views.orbit_steps=4", "--set", "camera.zoom=4",
              "-o", tmp_path / "o.gif")
    # nothing but render's one-line summary: no warning
    assert res.returncode == 0 and res.stderr.decode().startswith("isplat render: "), res.stderr
    assert res.stderr.count(b"\n") == 1, res.stderr


@pytest.mark.parametrize("args,needles", [
    (["--spacing", "1e-300,1,1"], ["spacing 1e-300,1,1 from --spacing", "1e-30..1e+30"]),
    (["--spacing", "1e300,1e300,1e300"], ["1e-30..1e+30"]),
    (["--spacing", "1e-4,1,1000"], ["ratio"]),
    (["--window=-1e308,1e308"], ["--window -1e+308,1e+308", "overflows"]),
    (["--window=1e15,1.0000000001e15"], ["float64 resolves"]),
])
def test_augment_refuses_what_makes_unreadable_or_degenerate_files(data, tmp_path, args, needles):
    base = ["--spacing", "1,1,1"] if "--spacing" not in args else []
    one_line(run("augment", data / "scan.npy", "-o", tmp_path / "o.aug.h5", *base, *args), *needles)
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------------------------------- 9. attribute types

EXAMPLES = ROOT / "formats" / "examples"


def _retyped(tmp_path, rel, obj, name, make):
    import shutil

    import h5py

    dst = tmp_path / Path(rel).name
    shutil.copy(EXAMPLES / rel, dst)
    with h5py.File(dst, "r+") as f:
        o = f[obj]
        value = o.attrs[name]
        del o.attrs[name]
        make(o.attrs, name, value)
    return dst


def _ascii(attrs, name, value):
    import h5py

    s = bytes(np.asarray(value)[()])
    attrs.create(name, s, dtype=h5py.string_dtype("ascii", len(s)))


def _big_endian(attrs, name, value):
    arr = np.asarray(value)
    attrs.create(name, arr.astype(arr.dtype.newbyteorder(">")))


@pytest.mark.parametrize("rel,obj,name,make,needle", [
    ("augmented/valid.aug.h5", "/", "format", _ascii, "ASCII string"),
    ("augmented/valid.aug.h5", "/", "density_sha256", _ascii, "ASCII string"),
    ("augmented/valid.aug.h5", "/", "format_version", _big_endian, "H5T_STD_I64BE"),
    ("augmented/valid.aug.h5", "/", "gradient_magnitude_scale", _big_endian, "H5T_IEEE_F64BE"),
    ("index/full.idx.h5", "/", "format_version", _big_endian, "H5T_STD_I64BE"),
    ("index/full.idx.h5", "axes/k", "n_slices", _big_endian, "H5T_STD_I64BE"),
    ("index/full.idx.h5", "axes/k", "axis", _ascii, "ASCII string"),
    ("index/full.v4.idx.h5", "values", "gradient_magnitude_scale", _big_endian, "H5T_IEEE_F64BE"),
])
def test_attribute_types_exactly_as_formats_say(tmp_path, rel, obj, name, make, needle):
    from isplat.augfile import open_augmented
    from isplat.errors import IsplatError
    from isplat.index import open_index

    path = _retyped(tmp_path, rel, obj, name, make)
    with pytest.raises(IsplatError, match=needle) as exc:
        (open_augmented if rel.startswith("augmented") else open_index)(path)
    assert name in str(exc.value)


@pytest.mark.parametrize("value,needle", [(np.array([0.1, 0.2], "<f4"), "float32"),
                                          (np.float64(0.1), "shape ()"),
                                          (np.array([0.1, 0.2], ">f8"), ">f8"),
                                          (np.array([0.7, 0.9]), "shares in 0..1")])
def test_density_clipped_fraction_typed(tmp_path, value, needle):
    import shutil

    import h5py

    from isplat.augfile import open_augmented
    from isplat.errors import IsplatError

    path = tmp_path / "c.aug.h5"
    shutil.copy(EXAMPLES / "augmented" / "valid.aug.h5", path)
    with h5py.File(path, "r+") as f:
        f.attrs.create("density_clipped_fraction", value)
    rehash(path)        # as an editor that knows the format would: the attribute's own check is what is tested
    with pytest.raises(IsplatError, match="density_clipped_fraction") as exc:
        open_augmented(path)
    assert needle in str(exc.value)
    with h5py.File(path, "r+") as f:
        del f.attrs["density_clipped_fraction"]
        f.attrs.create("density_clipped_fraction", np.array([0.1, 0.2], "<f8"))
    rehash(path)
    open_augmented(path)


def test_signal_held_by_a_compile_in_another_thread_reaches_the_main_thread():
    """numba may compile a kernel first called from a render thread: the held signal is sent again when that
    compile ends, and the main thread raises it."""
    import threading

    from isplat import interrupts

    previous = interrupts.install()
    try:
        interrupts.reset()

        def work():
            with interrupts.deferred():
                os.kill(os.getpid(), signal.SIGTERM)
                time.sleep(0.2)

        t = threading.Thread(target=work)
        with pytest.raises(interrupts.Terminated):
            t.start()
            t.join()
            time.sleep(2)
        t.join()
    finally:
        interrupts.restore(previous)
        interrupts.reset()


GC_CALLBACK_SIGNAL = r"""
import os, signal, sys, weakref
from isplat import interrupts

interrupts.install()


class Thing:
    pass


def callback(_):
    os.kill(os.getpid(), signal.SIGTERM)     # the handler runs here, inside the garbage collector's callback
    for _ in range(1000):
        pass


t = Thing()
r = weakref.ref(t, callback)
try:
    del t
    for _ in range(10 ** 7):
        pass
    print("not raised", file=sys.stderr)
except interrupts.Terminated as e:
    print(f"raised {e.signum}", file=sys.stderr)
"""


HALF_MADE_AFTER_SIGNAL = r"""
import os, signal, sys
from isplat import interrupts

interrupts.install()


class HalfMade:                              # as llvmlite's OutputString when a signal came inside its __init__
    def __init__(self):
        os.kill(os.getpid(), signal.SIGTERM)
        self._ptr = None

    def __del__(self):
        if self._ptr is not None:
            pass


try:
    HalfMade()
except interrupts.Terminated as e:
    print(f"raised {e.signum}", file=sys.stderr)


class Broken:
    def __del__(self):
        raise ValueError("after the signal")


Broken()
"""


def test_an_object_a_signal_cut_off_half_made_fails_in_its_finalizer_unprinted():
    """Once a signal has ended the run, an exception in a finalizer (an object whose __init__ the signal cut
    short: llvmlite's during a compile, seen in test_signal_while_the_command_starts) is not printed after the
    run's one line; before any signal, Python's hook prints it as ever."""
    p = subprocess.run([sys.executable, "-c", HALF_MADE_AFTER_SIGNAL], capture_output=True, text=True, timeout=120)
    assert p.stderr.strip() == f"raised {int(signal.SIGTERM)}", p.stderr
    p = subprocess.run([sys.executable, "-c", "from isplat import interrupts\ninterrupts.install()\n"
                        "class Broken:\n    def __del__(self):\n        raise ValueError('no signal')\nBroken()\n"],
                       capture_output=True, text=True, timeout=120)
    assert "ValueError: no signal" in p.stderr, p.stderr


def test_a_signal_inside_a_gc_callback_is_raised_after_it_not_printed():
    """A signal whose handler runs inside a weakref callback (where Python prints an exception as "Exception
    ignored in ..." with a traceback, and goes on) is not printed: it is sent again and raised after the
    callback (isplat.interrupts._unraisable)."""
    p = subprocess.run([sys.executable, "-c", GC_CALLBACK_SIGNAL], capture_output=True, text=True, timeout=120)
    assert p.stderr.strip() == f"raised {int(signal.SIGTERM)}", p.stderr
