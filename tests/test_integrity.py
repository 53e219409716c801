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
    """Since the chunk hashes (formats/augmented.md §1.1) every object of the examples is covered: the datasets by
    their hashes, every attribute the format specifies but ``created_by`` by the file key (``created_by`` is
    required), the tables by their shapes and keyed rows. So every corruption of the walk is refused, but one: a
    hash table rewritten with its rows unchanged in another layout (contiguous, compressed) reads the same rows,
    which readers do not refuse (the images are then equal; stats gives another file size); and a dataset of the
    brick store (augmented format 6: the channels, the labels, the brick hashes, all contiguous) rewritten
    contiguous holds the same bytes elsewhere, which is the same file to a reader."""
    store = obj.lstrip("/") in ("density", "gradient_magnitude", "normal", "labels") or obj.startswith("/brick_hashes/")
    return not ((obj.startswith("/chunk_hashes/") and op in ("contiguous", "gzip")) or
                (target == "aug" and store and op == "contiguous"))


@pytest.mark.parametrize("target,obj,op", _walk_cases())
def test_every_corruption_of_the_examples(examples, tmp_path, target, obj, op):
    """One error line and a non-zero exit for each (before the chunk hashes, deleting an optional attribute could
    leave the images equal)."""
    fx = examples[target]
    path = fx[target]
    mutant = R.corrupted_bytes(path, obj, op)
    out = R.check_mutant(fx, target, mutant, f"{op} {obj}")
    # (the exception: the same images, and stats' figures but the file's size)
    assert out.result == "error" if _expect_error(target, obj, op) else \
        out.result in ("error", "equal", "FAIL (stats: other figures)"), out


@pytest.mark.parametrize("obj", ["/density", "/gradient_magnitude", "/normal"])
def test_a_brick_store_channel_rewritten_chunked_is_refused(examples, tmp_path, obj):
    """Format 6's channels MUST be contiguous (formats/augmented.md §2.3): the same bricks in HDF5 chunks are
    refused with one line (the catalogue's "chunked" row; the walk's "contiguous" leaves such a file valid)."""
    fx = examples["aug"]
    path = fx["aug"]
    original = path.read_bytes()
    try:
        R.corrupt(path, obj, "chunked")
        mutant = path.read_bytes()
    finally:
        path.write_bytes(original)
    out = R.check_mutant(fx, "aug", mutant, f"chunked {obj}")
    assert out.result == "error" and "contiguous" in out.message, out


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


def _target(fx, target):
    """The file of ``target``: ``aug``, ``idx``, ``values`` (the index's values file, index format 6) or ``runs``
    (the index's runs file, formats/runs.md)."""
    from isplat.index.store import values_path

    return values_path(fx["idx"]) if target == "values" else fx[target]


@pytest.mark.parametrize("target,obj,method,name", [("aug", "/normal", "full", "'normal'"),
                                                    ("values", "/values/normal", "indexed", "'values/normal'")])
def test_message_names_file_and_dataset(examples, target, obj, method, name):
    """The full method reads the augmented file's normals; the indexed one (pre) the index's values file."""
    fx = examples["aug"]
    path = _target(fx, target)
    original = path.read_bytes()
    try:
        R.corrupt(path, obj, "flip_chunk")
        code, _, err = R.run_cli(["render", str(fx[method]), "-o", str(fx["folder"] / "x.png"), "-q"])
    finally:
        path.write_bytes(original)
    assert code == 2 and err.count("\n") == 1
    assert str(path) in err and name in err
    # the augmented file's bricks (version 6) are refused by their brick hash (formats/augmented.md §2.3);
    # the values file's chunks (index format 7: no Fletcher-32) by their chunk hash (formats/index.md §1.1)
    assert ("brick 0 at (0, 0, 0): its content does not match" if target == "aug"
            else "chunk at (0): its content does not match") in err


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
    assert code == 2 and out == "" and "dataset 'axes/i/entry_voxel_count', chunk at (0)" in err
    R.rehash(idx)           # an editor who recomputes the chunk hashes: the count check behind them
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
    R.rehash(idx)           # with the chunk hashes recomputed: the cross-axis check behind them
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


# --------------------------------------------------------------------------- content bound to its place (i30)

@pytest.fixture(scope="module")
def head(tmp_path_factory):
    """The fuzzer's small head (two chunks per channel, many per index table), both techniques' scenes; and a
    second volume's files of the same layout (for datasets brought in from another file)."""
    from isplat.augfile import write_augmented
    from isplat.augment import augment_array
    from isplat.index import build_index_file
    from isplat.samples import make_sample

    base = tmp_path_factory.mktemp("head")
    fx = R.make_fixture(base / "head")
    arr, spacing = make_sample("head", R.SHAPE_IJK, 0)
    a = augment_array(np.ascontiguousarray(arr[::-1]), spacing)          # another volume, the same layout
    other = base / "other.aug.h5"
    write_augmented(other, a["density"], a["gradient_magnitude"], a["normal"], a["spacing_ijk"],
                    a["density_window"], a["gradient_magnitude_scale"])
    build_index_file(other, base / "other.idx.h5")
    fx["other_aug"], fx["other_idx"] = other, base / "other.idx.h5"
    return fx


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("cls, target", [(c, t) for c in sorted(R.MUTANT_CLASSES)
                                         for t in ("aug", "idx", "values", "runs") if R.applies_to(c, t)])
def test_mutant_classes_are_refused_with_one_line(head, cls, target, seed):
    """Whole chunks copied with their Fletcher-32, Fletcher-blind words, edits through h5py (values, swaps, links):
    every mutant of both files is refused with one line (no image, in any scene; nor stats); the chunk-level ones
    name the file, the dataset and the chunk's position."""
    # (swaps and links need two datasets of one type, which the values file does not have)
    data, what = R.class_mutant(head, target, cls, np.random.default_rng(seed))
    out = R.check_mutant(head, target, data, what)
    assert out.result == "error" and str(head[target]) in out.message, out
    if cls in ("whole-chunk transplant", "Fletcher-blind word", "h5py value edit"):
        name = what.split(": ")[1]       # (augmented format 6's channels: a brick, formats/augmented.md §2.3)
        assert (f"dataset '{name}', chunk at (" in out.message or f"dataset '{name}', brick " in out.message) and \
            "rebuild it: isplat " in out.message, (what, out)


def _runs_walk_cases():
    return [(obj, op) for kind, obj in R.objects(EXAMPLES / "runs" / "tiny.runs.idx.h5")
            for op in (R.ATTRIBUTE_OPS if kind == "attribute" else R.DATASET_OPS)]


@pytest.mark.parametrize("obj,op", _runs_walk_cases())
def test_every_corruption_of_the_runs_file(head, obj, op):
    """Every named corruption of every dataset and attribute of the fixture's runs file (formats/runs.md): one
    error line naming the file, from the scene that reads it or from stats (which checks every chunk), but the
    hash tables rewritten in another layout with the same rows (as for the other files, _expect_error)."""
    path = head["runs"]
    mutant = R.corrupted_bytes(path, obj, op)
    out = R.check_mutant(head, "runs", mutant, f"{op} {obj}", scenes=R.RUNS_SCENES)
    if obj.startswith("/chunk_hashes/") and op in ("contiguous", "gzip"):
        assert out.result in ("error", "equal", "FAIL (stats: other figures)"), out
    else:
        assert out.result == "error" and str(path) in out.message and "isplat index " in out.message, out


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("target", ["aug", "idx"])
def test_a_dataset_and_its_hashes_from_another_file_are_refused(head, target, seed):
    """A dataset copied from another volume's file together with its hash table: the table is keyed by the
    file's identity (density_sha256 and the attributes that steer reading), so its rows do not verify."""
    path = head[target]
    original = path.read_bytes()
    try:
        what = R.foreign_dataset(path, np.random.default_rng(seed), target, head[f"other_{target}"])
        data = path.read_bytes()
    finally:
        path.write_bytes(original)
    out = R.check_mutant(head, target, data, what)
    assert out.result in ("error", "unchanged"), out
    if out.result == "error":
        assert ("chunk at (" in out.message or "brick " in out.message) and "rebuild it" in out.message, out


def test_an_edit_that_recomputes_the_hashes_is_not_caught(head):
    """What formats/augmented.md §1.1 says the hashes cannot do: an editor that recomputes the table after an
    in-range value edit makes a file that reads (a signature would be needed)."""
    path = head["aug"]
    original = path.read_bytes()
    try:
        with h5py.File(path, "r+") as f:
            ds = f["gradient_magnitude"]          # (format 6: brick 0's voxel (3, 4, 5); formats/augmented.md §2.3)
            at = (3, 4, 5) if ds.ndim == 3 else (0, 3, 4, 5)
            ds[at] = (int(ds[at]) + 7) % 256
        assert R.run_render(head["full"], head["folder"] / "edited")[0] == 2
        R.rehash(path)
        code, _, images = R.run_render(head["full"], head["folder"] / "edited")
        assert code == 0 and images
    finally:
        path.write_bytes(original)


def test_old_files_are_refused_with_the_rebuild_command(tmp_path):
    """Format versions before the chunk hashes: augmented 2, index 2 (a committed example) and 3."""
    code, _, err = R.run_cli(["stats", str(EXAMPLES / "augmented" / "invalid-version-2.aug.h5")])
    assert code == 2 and "version 2 lack this version's checksums, rebuild it: isplat augment" in err
    assert err.count("\n") == 1
    code, _, err = R.run_cli(["stats", str(EXAMPLES / "augmented" / "valid.aug.h5"),
                              str(EXAMPLES / "index" / "gaps.v2.idx.h5")])
    assert code == 2 and "rebuild it: isplat index" in err and err.count("\n") == 1


def _spec_key(f, datasets, attributes) -> bytes:
    """The file key exactly as formats/augmented.md §1.1 writes it, from hashlib and the raw attributes."""
    import hashlib

    h = hashlib.blake2b(digest_size=32, person=b"isplat-chunks")
    h.update(b"isplat chunk hashes 1\0" + bytes(f.attrs["density_sha256"]) + b"\0")
    h.update(b"".join(d.encode() + b"\0" for d in datasets) + b"\0")
    for where, name in attributes:
        obj = f[where] if where else f
        h.update(f"{where}@{name}".encode() + b"\0")
        if name not in obj.attrs:
            h.update(b"\0")
            continue
        v = np.asarray(obj.attrs[name])
        raw = bytes(v[()]) if v.dtype.kind == "S" else v.astype(v.dtype.newbyteorder("<")).tobytes()
        h.update(b"\1" + len(raw).to_bytes(8, "little") + raw)
    return h.digest()


@pytest.mark.parametrize("rel", ["augmented/valid.aug.h5", "augmented/valid-v5.aug.h5", "augmented/valid-v4.aug.h5", "augmented/valid-v3.aug.h5",
                                 "index/gaps.idx.h5", "index/gaps.values.idx.h5", "index/gaps.v4.idx.h5",
                                 "index/full.values.idx.h5", "augmented/valid.labels.idx.h5"])
def test_chunk_hashes_follow_the_spec(rel):
    """Every row of every table of the committed examples, recomputed from the spec's text (not isplat's code)."""
    import hashlib

    aug_attrs = ["format", "format_version", "shape", "spacing_ijk", "density_window", "gradient_magnitude_scale",
                 "density_sha256", "source", "source_format", "source_dtype", "density_window_method",
                 "density_units", "density_clipped_fraction", "axes_lps", "labels_sha256"]
    with h5py.File(EXAMPLES / rel, "r") as f:
        if rel.startswith("augmented") and not rel.endswith(".idx.h5"):
            datasets, attributes = ["density", "gradient_magnitude", "normal"], [("", n) for n in aug_attrs]
            datasets += ["brick_range"] if int(f.attrs["format_version"]) >= 5 else []     # version 5: §2.2
            datasets += ["labels", "label_voxels"] if "labels" in f else []
            attributes += [("", "brick_edge")] if int(f.attrs["format_version"]) >= 6 else []  # version 6: §2.3
        else:
            datasets = [f"values/{n}" for n in ("density_voxel_ptr", "gradient_magnitude", "normal") if "values" in f]
            attributes = [("", n) for n in ("format", "format_version", "shape", "density_sha256", "density_ranges")]
            attributes += [("", n) for n in ("channel", "labels_sha256") if "channel" in f.attrs]   # version 5
            if f.attrs["format"] == b"isplat-index-values":                                       # §9, version 6
                attributes += [("", "index_chunk_hash_check")]
            attributes += [("values", n) for n in ("spacing_ijk", "gradient_magnitude_scale") if "values" in f]
            for a in "ijk":
                if "axes" in f and a in f["axes"]:
                    datasets += [f"axes/{a}/{n}" for n in ("density_entry_ptr", "entry_slice", "entry_voxel_count",
                                                           "entry_byte_offset", "bytes")]
                    attributes += [(f"axes/{a}", n) for n in ("axis", "n_slices", "in_slice_axes", "n_a", "n_b",
                                                             "escape_width")]
        key = _spec_key(f, datasets, attributes)
        assert bytes(f.attrs["chunk_hash_check"]).decode() == \
            hashlib.blake2b(b"isplat chunk hashes 1", digest_size=16, key=key).hexdigest()
        if "brick_hashes" in f:                      # version 6: the channels' brick hashes (§2.3), from the text
            _check_brick_hashes(f, key, [d for d in datasets if d in ("density", "gradient_magnitude", "normal",
                                                                         "labels")])
            datasets = [d for d in datasets if d in ("brick_range", "label_voxels")]
        for d in datasets:
            ds, table = f[d], f["chunk_hashes"][d.replace("/", ".")][()]
            grid = [-(-n // c) for n, c in zip(ds.shape, ds.chunks)]
            assert table.shape == (int(np.prod(grid)), 16) and table.dtype == np.uint8
            for row, g in enumerate(np.ndindex(*grid)):
                off = [i * c for i, c in zip(g, ds.chunks)]
                data = ds[tuple(slice(o, o + c) for o, c in zip(off, ds.chunks))]
                h = hashlib.blake2b(digest_size=16, key=key)
                h.update(d.encode() + b"\0" + b"".join(o.to_bytes(8, "little") for o in off))
                h.update(np.ascontiguousarray(data, dtype=data.dtype.newbyteorder("<")).tobytes())
                assert h.digest() == table[row].tobytes(), (rel, d, off)


def _check_brick_hashes(f, key: bytes, channels) -> None:
    """Every brick hash of a version-6 file, recomputed as formats/augmented.md §2.3 writes it."""
    import hashlib

    for name in channels:
        seed = int.from_bytes(hashlib.blake2b(b"isplat brick hashes 6\0" + name.encode() + b"\0", digest_size=8,
                                              key=key).digest(), "little")
        ds, table = f[name], f["brick_hashes"][name][()]
        assert ds.chunks is None and table.dtype == np.dtype("<u8") and table.shape == (ds.shape[0],)
        for b in range(ds.shape[0]):
            raw = np.ascontiguousarray(ds[b], dtype=ds.dtype.newbyteorder("<")).tobytes()
            assert R.brick_hash(raw, b, seed) == int(table[b]), (name, b)


@pytest.mark.parametrize("target,dataset", [("aug", "normal"), ("aug", "gradient_magnitude"),
                                            ("values", "values/normal"), ("idx", "axes/j/bytes")])
def test_stats_checks_every_chunk(head, tmp_path, target, dataset):
    """`isplat stats` (no scene) reads neither the normals, the magnitudes, the index's values nor its blocks for
    its figures, yet refuses an edit of any of them: it checks every chunk of the files first (and of the
    index's values file)."""
    path = _target(head, target)
    original = path.read_bytes()
    try:
        with h5py.File(path, "r+") as f:
            ds = f[dataset]
            idx = (ds.shape[0] - 1,) + (0,) * (ds.ndim - 1)
            ds[idx] = (int(ds[idx]) + 1) % 128
        code, out, err = _stats([head["aug"], head["idx"]])
    finally:
        path.write_bytes(original)
    assert code == 2 and out == "" and err.count("\n") == 1, err
    assert (f"{path}: dataset '{dataset}', chunk at (" in err or f"{path}: dataset '{dataset}', brick " in err) and \
        "rebuild it: isplat " in err, err
