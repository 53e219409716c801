"""Integrity (issue #13): every corruption of every dataset and attribute of the example files, the corpus of
corruptions that found bugs, and the rough edges of bad input (usage, signals, terminals, geometry, memory)."""

import json
import shutil
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import h5py
import numpy as np
import pytest

import fuzzlab as R

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "formats" / "examples"
CORPUS = json.loads((Path(__file__).parent / "corpus" / "mutations.json").read_text())


@pytest.fixture(scope="module")
def examples(tmp_path_factory):
    """The example files (valid.aug.h5 with an index built from it; full.idx.h5 with its volume augmented),
    each pair with rendered reference images."""
    from isplat.augment import augment_file
    from isplat.index import build_index_file

    out = {}
    base = tmp_path_factory.mktemp("examples")
    a = base / "aug"
    a.mkdir()
    shutil.copy(EXAMPLES / "augmented" / "valid.aug.h5", a / "valid.aug.h5")
    build_index_file(a / "valid.aug.h5", a / "valid.idx.h5")
    out["aug"] = R.make_fixture(a, a / "valid.aug.h5", a / "valid.idx.h5")
    i = base / "idx"
    i.mkdir()
    shutil.copy(EXAMPLES / "index" / "full.idx.h5", i / "full.idx.h5")
    augment_file(EXAMPLES / "index" / "full.npy", i / "full.aug.h5", window=(0.0, 255.0), spacing=(1.0, 1.0, 1.0))
    out["idx"] = R.make_fixture(i, i / "full.aug.h5", i / "full.idx.h5")
    return out


def _walk_cases():
    cases = []
    for target, rel in (("aug", "augmented/valid.aug.h5"), ("idx", "index/full.idx.h5")):
        for kind, obj in R.objects(EXAMPLES / rel):
            for op in (R.ATTRIBUTE_OPS if kind == "attribute" else R.DATASET_OPS):
                cases.append((target, obj, op))
    return cases


def _expect_error(target, obj, op) -> bool:
    name = obj.rsplit("@", 1)[-1].rsplit("/", 1)[-1]
    return name in R.REQUIRED[target] or op.startswith("flip") or op == "dataspace"



@pytest.mark.parametrize("target,obj,op", _walk_cases())
def test_every_corruption_of_the_examples(examples, tmp_path, target, obj, op):
    """One error line and a non-zero exit for each; optional attributes may instead leave the images equal."""
    fx = examples[target]
    path = fx[target]
    original = path.read_bytes()
    try:
        R.corrupt(path, obj, op)
        mutant = path.read_bytes()
    finally:
        path.write_bytes(original)
    out = R.check_mutant(fx, target, mutant, f"{op} {obj}")
    if _expect_error(target, obj, op):
        assert out.result == "error", out
    elif op == "delete":       # an optional attribute: the same images; stats reports it missing
        assert out.result in ("equal", "FAIL (stats: other figures)"), out
    else:                      # an optional string attribute of another type is refused
        assert out.result == "error", out


@pytest.mark.parametrize("case", CORPUS["cases"], ids=lambda c: f"{c['target']}:{c['object']}:{c['op']}")
def test_corpus_of_bugs(examples, case):
    fx = examples["aug"]
    path = fx[case["target"]]
    original = path.read_bytes()
    try:
        R.corrupt(path, case["object"], case["op"])
        mutant = path.read_bytes()
    finally:
        path.write_bytes(original)
    out = R.check_mutant(fx, case["target"], mutant, case["op"])
    assert out.result == "error", out


@pytest.mark.parametrize("target,obj,method,name", [("aug", "/normal", "full", "'normal'"),
                                                    ("idx", "/values/normal", "indexed", "/values/normal")])
def test_message_names_file_and_dataset(examples, target, obj, method, name):
    """The full method reads the augmented file's normals; the indexed one the index's (format 3)."""
    fx = examples["aug"]
    original = fx[target].read_bytes()
    try:
        R.corrupt(fx[target], obj, "flip_chunk")
        code, _, err = R.run_cli(["render", str(fx[method]), "-o", str(fx["folder"] / "x.png"), "-q"])
    finally:
        fx[target].write_bytes(original)
    assert code == 2 and err.count("\n") == 1
    assert str(fx[target]) in err and name in err and "Fletcher-32" in err


# ---------------------------------------------------------------------------------------------- stats

def _stats(args):
    return R.run_cli(["stats", *map(str, args)])


def test_stats_refuses_an_impossible_count_on_an_unused_axis(examples, tmp_path):
    """0xFFFFFFFF voxels in one block (rewritten with a valid checksum) is refused, not summed."""
    fx = examples["aug"]
    idx = tmp_path / "i.idx.h5"
    shutil.copy(fx["idx"], idx)
    with h5py.File(idx, "r+") as f:
        f["axes/i/entry_voxel_count"][0] = 0xFFFFFFFF
    code, out, err = _stats([fx["aug"], idx, "--json"])
    assert code == 2 and out == "" and "entry_voxel_count is not in 1.." in err and err.count("\n") == 1


def test_stats_refuses_axes_that_disagree(examples, tmp_path):
    """Two blocks of one axis swap a voxel between densities: each table is plausible, the axes disagree."""
    fx = examples["idx"]
    idx = tmp_path / "i.idx.h5"
    shutil.copy(fx["idx"], idx)
    with h5py.File(idx, "r+") as f:
        ptr = f["axes/k/density_entry_ptr"][()]
        d = int(np.flatnonzero(np.diff(ptr))[0])
        f["axes/k/density_entry_ptr"][d + 1] = ptr[d + 1] + 1      # the next density's first entry becomes d's
    code, out, err = _stats([fx["aug"], idx])
    assert code == 2 and out == "" and err.count("\n") == 1, err


def test_stats_json_is_strict(examples):
    fx = examples["aug"]
    code, out, _ = _stats([fx["aug"], fx["idx"], "--scene", fx["indexed"], "--json"])
    assert code == 0
    json.loads(out, parse_constant=lambda c: pytest.fail(f"non-standard JSON constant {c}"))


# ---------------------------------------------------------------------------------------------- readers

def test_touching_ranges_refused(examples, tmp_path):
    idx = tmp_path / "i.idx.h5"
    shutil.copy(examples["idx"]["idx"], idx)
    with h5py.File(idx, "r+") as f:
        f.attrs["density_ranges"] = np.array([[0, 100], [101, 255]], "<i8")
    code, _, err = _stats([examples["idx"]["aug"], idx])
    assert code == 2 and "do not touch" in err


def test_version_1_refused_with_the_rebuild_command():
    code, _, err = R.run_cli(["stats", str(EXAMPLES / "augmented" / "invalid-version-1.aug.h5")])
    assert code == 2 and "rebuild it: isplat augment" in err and err.count("\n") == 1


# ---------------------------------------------------------------------------------------------- CLI edges

@pytest.mark.parametrize("argv", [["sample", "bogus", "-o", "x.npy"], ["render"], ["bogus"],
                                  ["render", "--nope", "x.toml"], ["stats", "a", "b", "c"]])
def test_usage_errors_are_one_line(argv):
    code, out, err = R.run_cli(argv)
    assert code == 2 and out == "" and err.count("\n") == 1 and err.startswith("isplat: error: "), err


def test_stdout_terminal_refused(examples, monkeypatch, capsys):
    import io

    from isplat.cli.main import main

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    monkeypatch.setattr(sys, "stdout", Terminal())
    with pytest.raises(SystemExit) as exc:
        main(["render", str(examples["aug"]["indexed"]), "--view", "0", "-o", "-"])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "terminal" in err and sys.stdout.getvalue() == ""


@pytest.mark.parametrize("setting,word", [("volume.spacing=[1e-300,1,1]", "spacing"),
                                          ("volume.spacing=[1e-4,1,1000]", "ratio"),
                                          ("camera.fov=179.9", "fov")])
def test_degenerate_geometry_refused(examples, tmp_path, setting, word):
    code, _, err = R.run_cli(["render", str(examples["aug"]["indexed"]), "--set", "camera.projection=perspective",
                              "--set", setting, "-o", str(tmp_path / "x.png")])
    assert code == 2 and word in err and err.count("\n") == 1 and not list(tmp_path.iterdir())


def test_degenerate_spacing_in_the_file_refused(tmp_path, make_scene):
    from conftest import write_volume
    from isplat.errors import IsplatError
    from isplat.renderer import Renderer

    aug, idx = write_volume(tmp_path, np.full((4, 4, 4), 200, np.uint8), spacing=(1e-7, 1.0, 1.0))
    scene = make_scene(aug, idx, transfer="opacity = [[0, 0.5], [255, 0.5]]")
    with pytest.raises(IsplatError, match="'spacing_ijk'.*ratio 1e\\+07"):
        Renderer(scene)


def test_image_buffers_beyond_memory_refused(examples, tmp_path, monkeypatch):
    from isplat import output

    monkeypatch.setattr(output, "memory_available", lambda: 10 << 20)
    code, _, err = R.run_cli(["render", str(examples["aug"]["indexed"]), "--set", "image.width=4096",
                              "--set", "image.height=4096", "--view", "0", "-o", str(tmp_path / "x.tif")])
    assert code == 2 and "GiB of image buffers" in err and not list(tmp_path.iterdir())


SLOW_WRITE = textwrap.dedent("""
    import sys, time
    import imageio.v3 as iio
    real = iio.imwrite
    def slow(*a, **k):
        real(*a, **k)
        print("writing", flush=True)
        time.sleep(30)
    iio.imwrite = slow
    from isplat.cli.main import main
    main(sys.argv[1:])
""")


@pytest.mark.parametrize("sig,code", [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_signal_during_gif_write_leaves_nothing(examples, tmp_path, sig, code):
    """The signal arrives while the GIF is being written under its temporary name."""
    out = tmp_path / "o.gif"
    p = subprocess.Popen([sys.executable, "-c", SLOW_WRITE, "render", str(examples["aug"]["indexed"]), "-o",
                          str(out), "-q"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))   # as tests/test_hostile
    assert p.stdout.readline().strip() == "writing"
    p.send_signal(sig)
    _, err = p.communicate(timeout=60)
    assert p.returncode == code
    assert err.count("\n") == 1 and "incomplete outputs removed" in err
    assert list(tmp_path.iterdir()) == []
