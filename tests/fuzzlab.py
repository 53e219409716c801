"""The fuzzer and the corruptions shared by tests/test_fuzz.py, tests/test_integrity.py and the reliability
benchmark (benchmarks/reliability.py, which writes docs/reliability.md).

The fuzzer mutates the bytes of a small head's augmented and index files and of the index's values and runs files
(bit flips, random bytes, zeroed runs, truncation; ``TARGETS``) and renders each mutant through the CLI, in
process, with both techniques (``SCENES``: the paper's pre-classified splatting with the indexed and the full
method, and the default, post-classification, shaded, from whole channels and from the runs file), and runs
``isplat stats --json`` on it: every run must end in one ``isplat: error:`` line with a non-zero exit, or in
images and figures equal to the unmutated ones. ``make fuzz-boundscheck`` runs the fuzz test with numba bounds
checking on (a fresh NUMBA_CACHE_DIR).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import signal
import statistics
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

SHAPE_IJK = (20, 18, 16)
IMAGE = 40


# ------------------------------------------------------------------------------------------------- fixture

# the fixture's scenes: name -> (render.method, render.classification). "pre" is the paper's splatting, "post"
# the default from scene version 4; the names "indexed" and "full" are the pre-classified scenes of before.
# "post" sees density code 0, so it reads whole channels; "post_runs" does not (opacity 0 at code 0), so it reads the
# range-runs file beside the index (formats/runs.md §6), which make_fixture writes as isplat index does.
SCENES = {"indexed": ("indexed", "pre"), "full": ("full", "pre"), "post": ("indexed", "post"),
          "post_runs": ("indexed", "post")}
TECHNIQUES = {"pre": ("indexed", "full"), "post": ("post", "post_runs")}
RUNS_SCENES = ("post_runs",)         # the scenes that read the runs file (make_fixture checks that they do)
# the fixture's files: the augmented file, the index, and beside it the index's values file and runs file
TARGETS = ("idx", "aug", "values", "runs")


def scene_label(name: str) -> str:
    """'pre indexed', 'pre full', 'post indexed', 'post indexed (runs file)': the technique and method of a
    fixture scene."""
    method, technique = SCENES[name]
    return f"{technique} {method}" + (" (runs file)" if name in RUNS_SCENES else "")


def scene_toml(aug: Path, idx: Path, method: str = "indexed", technique: str = "pre", runs: bool = False) -> str:
    """Three views (one per principal axis), every density visible, shading and gradient-modulated opacity:
    a render reads every index axis, every block, and the normal and gradient-magnitude channels. ``technique``
    is written out (render.classification), not left to the scene version's default; the version is the
    current one (an older one would add its note on the defaults it keeps to every stderr). ``runs``: every
    density but code 0 visible (a post scene then reads the runs file, every run of it but those of code 0)."""
    from isplat.scene_schema import SCENE_VERSION

    opacity = "[[0, 0.0], [1, 0.02], [255, 0.6]]" if runs else "[[0, 0.02], [255, 0.6]]"

    return f"""version = {SCENE_VERSION}
[data]
augmented = "{aug}"
index = "{idx}"
[image]
width = {IMAGE}
height = {IMAGE}
[transfer]
opacity = {opacity}
gradient_opacity = [[0, 0.5], [255, 1.0]]
[shading]
ambient = 0.3
diffuse = 0.7
[render]
method = "{method}"
classification = "{technique}"
[views]
list = [{{azimuth = 0, elevation = 0}}, {{azimuth = 90, elevation = 0}}, {{azimuth = 0, elevation = 90}}]
"""


def make_fixture(folder: Path, aug: Path | None = None, idx: Path | None = None, scenes=tuple(SCENES)) -> dict:
    """A small head (or given files): augmented and index files, the index's values file and its runs file
    (written from the augmented file as isplat index does, unless one is beside the index), the ``scenes``
    (names of ``SCENES``: both techniques by default) and their reference images; ``fx["scenes"]`` names them."""
    from isplat.augfile import write_augmented
    from isplat.augment import augment_array
    from isplat.index import build_index_file
    from isplat.runsfile import build_runs_file, runs_path
    from isplat.samples import make_sample

    folder.mkdir(parents=True, exist_ok=True)
    own = aug is None          # the small head, whose post_runs scene must read the runs file (given files may
    if aug is None:            # not qualify: a thick axis, formats/runs.md §6)
        arr, spacing = make_sample("head", SHAPE_IJK, 0)
        a = augment_array(arr, spacing)
        aug = folder / "head.aug.h5"
        write_augmented(aug, a["density"], a["gradient_magnitude"], a["normal"], a["spacing_ijk"],
                        a["density_window"], a["gradient_magnitude_scale"])
    if idx is None:
        idx = folder / "head.idx.h5"
        build_index_file(aug, idx, force=True)
    fx = {"aug": aug, "idx": idx, "folder": folder, "scenes": list(scenes)}
    values = Path(str(idx).replace(".idx.h5", ".values.idx.h5"))
    if values.is_file():
        fx["values"] = values               # the index's values file (index format 6)
    if not runs_path(idx).exists():
        build_runs_file(aug, idx)
    fx["runs"] = runs_path(idx)             # the index's runs file (formats/runs.md), read by the "post_runs" scene
    for name in scenes:
        sc = folder / f"{name}.toml"
        sc.write_text(scene_toml(aug, idx, *SCENES[name], runs=name in RUNS_SCENES))
        fx[name] = sc
        code, err, images = run_render(sc, folder / f"ref_{name}")
        if code != 0:
            raise RuntimeError(f"reference render failed ({scene_label(name)}): {err}")
        fx[f"ref_{name}"] = images
        if own and name in RUNS_SCENES and not reads_runs(sc):
            raise RuntimeError(f"{sc}: the scene {scene_label(name)} does not read the runs file {fx['runs']}")
    code, out, err = run_cli(["stats", str(aug), str(idx), "--json"])
    if code != 0:
        raise RuntimeError(f"reference stats failed: {err}")
    fx["ref_stats"] = out
    return fx


def reads_runs(scene: Path) -> bool:
    """Whether the scene's frames (each axis) read the runs file beside its index (formats/runs.md §6)."""
    from isplat.scene import load_scene
    from isplat.selection import select_from_files

    sc = load_scene(scene, [])
    return all(select_from_files(sc, ax).report.values_from.startswith("runs file") for ax in "ijk")


def run_cli(argv) -> tuple[int, str, str]:
    """Run ``isplat ARGV`` in this process; return (exit code, stdout, stderr)."""
    from isplat.cli.main import main

    out, err = io.StringIO(), io.StringIO()
    code = 0
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            main(list(argv))
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else 1
    return code, out.getvalue(), err.getvalue()


def run_render(scene: Path, out_stem: Path) -> tuple[int, str, list[bytes]]:
    """Render the scene's views to numbered PNGs; return (exit code, stderr, the PNG files' bytes)."""
    for old in out_stem.parent.glob(out_stem.name + "_*.png"):
        old.unlink()
    code, _, err = run_cli(["render", str(scene), "-o", f"{out_stem}.png", "-q", "--force"])
    images = [p.read_bytes() for p in sorted(out_stem.parent.glob(out_stem.name + "_*.png"))]
    return code, err, images


# ------------------------------------------------------------------------------------------------- mutator

def mutate(data: bytes, rng: np.random.Generator) -> tuple[bytes, str]:
    """One random mutation of a file's bytes, and its description."""
    b = bytearray(data)
    kind = rng.choice(["flip", "byte", "zero", "truncate"], p=[0.5, 0.25, 0.15, 0.1])
    pos = int(rng.integers(0, len(b)))
    if kind == "flip":
        bit = int(rng.integers(0, 8))
        b[pos] ^= 1 << bit
        return bytes(b), f"flip bit {bit} of byte {pos}"
    if kind == "byte":
        val = int(rng.integers(0, 256))
        b[pos] = val
        return bytes(b), f"byte {pos} = {val:#04x}"
    if kind == "zero":
        n = int(rng.integers(1, 65))
        b[pos:pos + n] = bytes(len(b[pos:pos + n]))
        return bytes(b), f"zero bytes {pos}..{pos + n - 1}"
    return bytes(b[:pos]), f"truncate to {pos} bytes"


@dataclass
class Outcome:
    target: str
    mutation: str
    result: str           # "error", "equal", "unchanged" (mutation left the bytes as they were) or a failure
    message: str = ""


class _Timeout(BaseException):
    pass


def _alarm(signum, frame):
    raise _Timeout()


def check_mutant(fx: dict, target: str, data: bytes, mutation: str, limit: float = 20.0, scenes=None) -> Outcome:
    """Write the mutant over the fixture's ``target`` file, render the fixture's scenes (or ``scenes``: both
    techniques by default) and run ``stats --json``, restore the file. Each must end in one error line and a
    non-zero exit, or give the unmutated images and figures; a failure names the scene's technique and method."""
    path = fx[target]
    original = path.read_bytes()
    if data == original:
        return Outcome(target, mutation, "unchanged")
    path.write_bytes(data)
    old = signal.signal(signal.SIGALRM, _alarm)
    signal.setitimer(signal.ITIMER_REAL, limit)
    try:
        for name in (fx["scenes"] if scenes is None else scenes):
            code, err, images = run_render(fx[name], fx["folder"] / f"mut_{name}")
            lines = err.strip().splitlines()
            if code == 0 and images == fx[f"ref_{name}"]:
                continue
            if code != 0 and len(lines) == 1 and lines[0].startswith("isplat: error: ") and not images:
                return Outcome(target, mutation, "error", lines[0])
            what = "different image" if code == 0 else f"exit {code}, {len(lines)} stderr lines"
            return Outcome(target, mutation, f"FAIL ({scene_label(name)}: {what})", err[-2000:])
        code, out, err = run_cli(["stats", str(fx["aug"]), str(fx["idx"]), "--json"])
        lines = err.strip().splitlines()
        if code != 0 and len(lines) == 1 and lines[0].startswith("isplat: error: ") and not out:
            return Outcome(target, mutation, "error", lines[0])
        if code != 0 or out != fx["ref_stats"]:
            return Outcome(target, mutation, "FAIL (stats: " + ("other figures)" if code == 0 else f"exit {code})"),
                           err[-2000:] or out[-2000:])
        return Outcome(target, mutation, "equal")
    except _Timeout:
        return Outcome(target, mutation, "FAIL (hang)", f"no answer in {limit:g} s")
    except Exception as exc:      # a crash of the fuzzed code is a finding, not a crash of the fuzzer
        return Outcome(target, mutation, f"FAIL ({exc.__class__.__name__})", str(exc)[:2000])
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
        path.write_bytes(original)


@dataclass
class FuzzReport:
    seconds: float
    outcomes: list = field(default_factory=list)

    def count(self, pred) -> int:
        return sum(1 for o in self.outcomes if pred(o))

    @property
    def failures(self) -> list:
        return [o for o in self.outcomes if o.result.startswith("FAIL")]


def fuzz(fx: dict, seconds: float, seed: int = 0, max_runs: int | None = None, scenes=None) -> FuzzReport:
    """Mutate the fixture's files (``TARGETS``: the index, the augmented file, the values file and the runs file
    beside the index, those the fixture has) in turn for ``seconds`` (or ``max_runs`` mutants); each mutant is
    rendered with the fixture's scenes (or ``scenes``)."""
    rng = np.random.default_rng(seed)
    targets = [t for t in TARGETS if t in fx]
    originals = {t: fx[t].read_bytes() for t in targets}
    rep = FuzzReport(0.0)
    t0 = time.perf_counter()
    n = 0
    while time.perf_counter() - t0 < seconds and (max_runs is None or n < max_runs):
        target = targets[n % len(targets)]
        data, what = mutate(originals[target], rng)
        rep.outcomes.append(check_mutant(fx, target, data, what, scenes=scenes))
        n += 1
    rep.seconds = time.perf_counter() - t0
    return rep


# ------------------------------------------------------------------------------ named corruptions (the walk)

REQUIRED = {"aug": {"format", "format_version", "shape", "spacing_ijk", "density_window", "gradient_magnitude_scale",
                    "density_sha256", "created_by", "density", "gradient_magnitude", "normal"},
            "idx": {"format", "format_version", "shape", "density_sha256", "density_ranges", "created_by", "axis",
                    "n_slices",
                    "in_slice_axes", "n_a", "n_b", "escape_width", "density_entry_ptr", "entry_slice",
                    "entry_voxel_count", "entry_byte_offset", "bytes",
                    # /values (format version 3)
                    "spacing_ijk", "gradient_magnitude_scale", "density_voxel_ptr", "gradient_magnitude", "normal"}}
DATASET_OPS = ("flip_chunk", "flip_header", "delete", "dtype", "shape", "contiguous", "gzip", "dataspace")
ATTRIBUTE_OPS = ("delete", "as_string", "as_float", "as_int32", "as_array", "nan", "flip_header")


def objects(path: Path) -> list[tuple[str, str]]:
    """Every (kind, HDF5 path) of a file: attributes as 'group@name', datasets as their path."""
    import h5py

    out = []
    with h5py.File(path, "r") as f:
        def visit(g):
            out.extend(("attribute", f"{g.name}@{k}") for k in g.attrs)
            for name, obj in g.items():
                if isinstance(obj, h5py.Group):
                    visit(obj)
                else:
                    out.append(("dataset", obj.name))
        visit(f)
    return out


def _flip_at(path: Path, offset: int) -> None:
    data = bytearray(path.read_bytes())
    data[offset] ^= 0x10
    path.write_bytes(bytes(data))


def corrupted_bytes(path: Path, obj: str, op: str) -> bytes:
    """The bytes of ``path`` with :func:`corrupt` ``op`` applied to ``obj``; the file itself left as it was."""
    original = path.read_bytes()
    try:
        corrupt(path, obj, op)
        return path.read_bytes()
    finally:
        path.write_bytes(original)


def corrupt(path: Path, obj: str, op: str) -> None:
    """Apply the named corruption ``op`` to attribute ``group@name`` or dataset ``obj`` of ``path``, in place."""
    import h5py

    if "@" in obj:
        gname, name = obj.split("@")
        with h5py.File(path, "r+") as f:
            attrs = f[gname or "/"].attrs
            v = attrs[name]
            if op == "delete":
                del attrs[name]
            elif op == "as_string":
                attrs[name] = str(v.tolist() if isinstance(v, np.ndarray) else v)
            elif op == "as_float":
                kind = np.asarray(v).dtype.kind        # floats become float32: another type than the spec's
                attrs[name] = np.asarray(v, dtype=np.float32 if kind == "f" else np.float64) if kind in "iuf" else 1.5
            elif op == "as_int32":
                attrs[name] = np.asarray(v).astype(np.int32) if np.asarray(v).dtype.kind in "iuf" else np.int32(7)
            elif op == "as_array":
                attrs[name] = np.stack([np.asarray(v)] * 2)
            elif op == "big_endian":                   # the same number stored big-endian (h5py reads it native)
                arr = np.asarray(v)
                del attrs[name]
                attrs.create(name, arr.astype(arr.dtype.newbyteorder(">")))
            elif op == "ascii":                        # the same text as a fixed-length ASCII string
                text = bytes(np.asarray(v)[()])
                del attrs[name]
                attrs.create(name, text, dtype=h5py.string_dtype("ascii", len(text)))
            elif op == "nan":
                attrs[name] = np.full(np.shape(v), np.nan) if np.asarray(v).dtype.kind in "iuf" else "nan"
            elif op == "flip_header":
                addr = h5py.h5o.get_info(f[gname or "/"].id).addr
        if op == "flip_header":         # a byte of the attribute's value, inside the checksummed object header
            data = path.read_bytes()
            at = data.find(name.encode() + b"\0", addr)
            _flip_at(path, at + len(name) + 8 if at >= 0 else addr + 16)
        return
    with h5py.File(path, "r+") as f:
        ds = f[obj]
        if op in ("flip_chunk", "flip_header", "dataspace"):
            chunked = ds.chunks is not None and ds.id.get_num_chunks()
            at = (ds.id.get_chunk_info(0).byte_offset if op == "flip_chunk" and chunked else
                  ds.id.get_offset() if op == "flip_chunk" and ds.chunks is None and ds.id.get_offset() is not None
                  else h5py.h5o.get_info(ds.id).addr + (16 if op == "flip_header" else 40))
        else:
            data, parent, name = ds[()], ds.parent, ds.name.rsplit("/", 1)[1]
            del parent[name]
            if op == "dtype":
                parent.create_dataset(name, data=data.astype(np.float32), chunks=True, fletcher32=True)
            elif op == "shape":
                parent.create_dataset(name, data=data.reshape(-1)[:-1] if data.size else np.zeros(1, data.dtype),
                                      chunks=True, fletcher32=True)
            elif op == "contiguous":
                parent.create_dataset(name, data=data)
            elif op == "chunked":       # what a format-6 brick store (contiguous, formats/augmented.md §2.3) must not be
                parent.create_dataset(name, data=data, chunks=True, fletcher32=True)
            elif op == "gzip" and data.size:
                parent.create_dataset(name, data=data, chunks=True, compression="gzip", fletcher32=True)
            elif op == "gzip":
                parent.create_dataset(name, data=data, chunks=(1,), maxshape=(None,), compression="gzip")
            return
    _flip_at(path, at)


# ---------------------------------------------------------------------------------------------- checksums

def _rewrite_unchecked(src: Path, dst: Path) -> None:
    """A copy of an isplat file with every dataset contiguous and unfiltered: metadata checksums only."""
    import h5py

    from isplat.fileio import create_hdf5

    with h5py.File(src, "r") as a, create_hdf5(dst) as b:
        def copy(ga, gb):
            for k in ga.attrs:                   # each attribute with its stored type (UTF-8 stays UTF-8)
                aid = ga.attrs.get_id(k)
                buf = np.empty(aid.shape, dtype=aid.dtype)
                aid.read(buf)
                h5py.h5a.create(gb.id, k.encode(), aid.get_type(), aid.get_space()).write(buf)
            for name, obj in ga.items():
                if isinstance(obj, h5py.Group):
                    copy(obj, gb.create_group(name))
                else:
                    gb.create_dataset(name, data=obj[()])
        copy(a, b)




# ------------------------------------------------------------------------------------- chunk hashes (i30)

def rehash(path: Path) -> None:
    """Recompute the chunk-hash table and ``chunk_hash_check`` of an isplat file in place, as an editor that
    knows the format would after an edit (formats/augmented.md §1.1: such an edit cannot be caught without a
    signature). Tests use it to reach the structural checks behind the hashes."""
    import h5py

    from isplat import chunkhash
    from isplat.augfile import finish_augmented
    from isplat.index.store import finish_index

    with h5py.File(path, "r+") as f:
        if chunkhash.GROUP in f:
            del f[chunkhash.GROUP]
        if "brick_hashes" in f:                    # augmented format 6: the brick hashes too (formats/augmented.md §2.3)
            del f["brick_hashes"]
        if chunkhash.CHECK_ATTR in f.attrs:
            del f.attrs[chunkhash.CHECK_ATTR]
        if f.attrs["format"] == b"isplat-runs":
            from isplat.runsfile import _finish as finish_runs

            finish_runs(f)
        else:
            (finish_index if f.attrs["format"] in (b"isplat-index", b"isplat-index-values") else finish_augmented)(f)


# Mutant classes that byte damage below HDF5 does not make, and that Fletcher-32 cannot see (issue 30): each is
# ``fn(path, rng) -> description`` applied in place to a copy of a fixture file; every mutant must be refused
# (the chunk hashes) with one line, never rendered.
HASHED = {"aug": ("density", "gradient_magnitude", "normal", "brick_range"),
          "idx": ("axes/k/bytes", "axes/k/entry_slice", "axes/k/entry_voxel_count", "axes/k/entry_byte_offset",
                  "axes/i/bytes", "axes/j/density_entry_ptr"),
          # the index's values file (index format 6, formats/index.md §9.1), read by the pre technique
          "values": ("values/normal", "values/gradient_magnitude", "values/density_voxel_ptr"),
          # the index's runs file (formats/runs.md), read by the post_runs scene
          "runs": ("runs/run_voxel_ptr", "runs/brick_number", "runs/brick_voxel_count", "runs/positions",
                   "runs/density", "runs/normal", "runs/gradient_magnitude")}
# pairs of same-typed datasets (a swap or a link passes every type and shape check)
PAIRS = {"aug": (("density", "gradient_magnitude"),),
         "idx": (("axes/k/entry_slice", "axes/k/entry_voxel_count"), ("axes/i/bytes", "axes/j/bytes"),
                 ("axes/i/density_entry_ptr", "axes/k/density_entry_ptr")),
         "values": (),          # no two datasets of one type: swaps and links need another file (see the test)
         "runs": (("runs/run_voxel_ptr", "runs/run_position_ptr"), ("runs/density", "runs/gradient_magnitude"))}


def _chunks(ds):
    """The stored chunks of ``ds``; for a brick store (augmented format 6: contiguous [B, e, e, e]) its bricks, as
    chunk infos (byte_offset, size, chunk_offset = (brick row, 0, 0, 0))."""
    if ds.chunks is None and ds.ndim == 4:
        from types import SimpleNamespace

        size = int(np.prod(ds.shape[1:])) * ds.dtype.itemsize
        return [SimpleNamespace(byte_offset=ds.id.get_offset() + b * size, size=size, chunk_offset=(b, 0, 0, 0))
                for b in range(ds.shape[0])]
    return [ds.id.get_chunk_info(n) for n in range(ds.id.get_num_chunks())]


def transplant_chunk(path: Path, rng, target: str) -> str:
    """Copy a whole chunk, with its own valid Fletcher-32, over another chunk of the same stored size (on disk)."""
    import h5py

    with h5py.File(path, "r") as f:
        options = []
        for name in HASHED[target]:
            info = _chunks(f[name])
            for a in range(len(info)):
                for b in range(len(info)):
                    if a != b and info[a].size == info[b].size:
                        options.append((name, info[a], info[b]))
    if not options:
        raise ValueError(f"{path}: no two chunks of one size to transplant")
    name, src, dst = options[int(rng.integers(len(options)))]
    data = bytearray(path.read_bytes())
    if data[src.byte_offset:src.byte_offset + src.size] == data[dst.byte_offset:dst.byte_offset + dst.size]:
        return "unchanged"
    data[dst.byte_offset:dst.byte_offset + dst.size] = data[src.byte_offset:src.byte_offset + src.size]
    path.write_bytes(bytes(data))
    return f"{name}: chunk at {src.chunk_offset} copied over chunk at {dst.chunk_offset}"


def fletcher_blind_word(path: Path, rng, target: str) -> str:
    """Turn an aligned 16-bit word 0x0000 of a chunk into 0xFFFF (or back): Fletcher-32 sums words modulo 65535,
    so it cannot tell them apart."""
    import h5py

    def logical_words(ds, c):       # the chunk's words within elements inside the dataset (the rest is padding,
        if ds.chunks is None:       # never read); a brick store's bricks: every word (the padding is hashed too)
            return np.ones(int(np.prod(ds.shape[1:])) * ds.dtype.itemsize // 2, bool)
        inside = [min(int(k), int(n) - int(o)) for k, n, o in zip(ds.chunks, ds.shape, c.chunk_offset)]  # never read)
        m = np.zeros(tuple(int(k) for k in ds.chunks), bool)
        m[tuple(slice(0, n) for n in inside)] = True
        b = np.repeat(m.reshape(-1), ds.dtype.itemsize)
        return b[0:b.size - b.size % 2:2] & b[1::2]

    with h5py.File(path, "r") as f:
        spots = [(name, c, logical_words(f[name], c)) for name in HASHED[target] if name in f
                 for c in _chunks(f[name])]
    data = bytearray(path.read_bytes())
    for n in rng.permutation(len(spots)):
        name, c, ok = spots[int(n)]
        words = np.frombuffer(bytes(data[c.byte_offset:c.byte_offset + 2 * ok.size]), dtype=">u2")
        hits = np.flatnonzero(((words == 0) | (words == 0xFFFF)) & ok)
        if hits.size:
            w = int(hits[int(rng.integers(hits.size))])
            at = c.byte_offset + 2 * w
            old = data[at]
            data[at:at + 2] = b"\xff\xff" if old == 0 else b"\x00\x00"
            path.write_bytes(bytes(data))
            new = (~old) & 0xFF
            return f"{name}: word {w} of chunk at {c.chunk_offset}: {old:#04x}{old:02x} -> {new:#04x}{new:02x}"
    raise ValueError(f"{path}: no 0x0000 or 0xFFFF word")


def h5py_value_edit(path: Path, rng, target: str) -> str:
    """Change one element through HDF5 (which writes a valid Fletcher-32)."""
    import h5py

    with h5py.File(path, "r+") as f:
        names = [n for n in HASHED[target] if f[n].size]
        name = names[int(rng.integers(len(names)))]
        ds = f[name]
        flat = int(rng.integers(ds.size))
        idx = np.unravel_index(flat, ds.shape)
        v = ds[idx]
        ds[idx] = (int(v) + 1 + int(rng.integers(3))) % (1 << (8 * ds.dtype.itemsize - 1))
        return f"{name}: element {list(map(int, idx))}: {v} -> {ds[idx]}"


def h5py_dataset_swap(path: Path, rng, target: str) -> str:
    """Swap two datasets of the same type through HDF5 (renames: each passes every type and shape check)."""
    import h5py

    with h5py.File(path, "r+") as f:
        pairs = [(a, b) for a, b in PAIRS[target] if a in f and b in f]
        a, b = pairs[int(rng.integers(len(pairs)))]
        f.move(a, a + ".tmp")
        f.move(b, a)
        f.move(a + ".tmp", b)
    return f"{a} <-> {b}"


def h5py_link(path: Path, rng, target: str) -> str:
    """Replace a dataset by a link (hard or soft) to another of the same type."""
    import h5py

    with h5py.File(path, "r+") as f:
        pairs = [(a, b) for a, b in PAIRS[target] if a in f and b in f]
        a, b = pairs[int(rng.integers(len(pairs)))]
        soft = bool(rng.integers(2))
        del f[a]
        f[a] = h5py.SoftLink("/" + b) if soft else f[b]
    return f"{a} -> {'soft' if soft else 'hard'} link to {b}"


def foreign_dataset(path: Path, rng, target: str, other: Path | None = None) -> str:
    """Replace a dataset and its hash table by those of another file of the same layout (another volume)."""
    import h5py

    from isplat.chunkhash import GROUP, table_name

    with h5py.File(other, "r") as o, h5py.File(path, "r+") as f:
        names = [n for n in HASHED[target] if n in o and n in f and o[n].shape == f[n].shape]
        name = names[int(rng.integers(len(names)))]
        if np.array_equal(o[name][()], f[name][()]):
            return "unchanged"
        table = f"brick_hashes/{name}" if f"brick_hashes/{name}" in f else f"{GROUP}/{table_name(name)}"
        for n in (name, table):
            del f[n]
            o.copy(o[n], f[n.rsplit("/", 1)[0]] if "/" in n else f, name=n.rsplit("/", 1)[-1])
    return f"{name} and its hashes from {Path(other).name}"


MUTANT_CLASSES = {
    "whole-chunk transplant": transplant_chunk,
    "Fletcher-blind word": fletcher_blind_word,
    "h5py value edit": h5py_value_edit,
    "h5py dataset swap": h5py_dataset_swap,
    "h5py link": h5py_link,
}


def class_mutant(fx: dict, target: str, cls: str, rng) -> tuple[bytes, str]:
    """A mutant of the fixture's ``target`` file of mutant class ``cls`` (its bytes and description)."""
    path = fx[target]
    original = path.read_bytes()
    try:
        what = MUTANT_CLASSES[cls](path, rng, target)
        return path.read_bytes(), f"{cls}: {what}"
    finally:
        path.write_bytes(original)


def applies_to_values(cls: str) -> bool:
    """Whether mutant class ``cls`` applies to the values file (swaps and links need two datasets of a type)."""
    return applies_to(cls, "values")


def applies_to(cls: str, target: str) -> bool:
    """Whether mutant class ``cls`` applies to the fixture's file ``target`` (swaps and links need two datasets
    of a type: ``PAIRS``)."""
    return bool(PAIRS[target]) or cls not in ("h5py dataset swap", "h5py link")


def fuzz_classes(fx: dict, per_class: int, seed: int = 0, scenes=None) -> dict:
    """``per_class`` mutants of each class of MUTANT_CLASSES on each file (the augmented file, the index, its
    values file and its runs file, in turn): {class: [Outcome, ...]}."""
    rng = np.random.default_rng(seed)
    out = {}
    for cls in MUTANT_CLASSES:
        out[cls] = []
        for n in range(per_class):
            targets = ("aug", "idx") + tuple(t for t in ("values", "runs") if t in fx and applies_to(cls, t))
            target = targets[n % len(targets)]
            data, what = class_mutant(fx, target, cls, rng)
            out[cls].append(check_mutant(fx, target, data, what, scenes=scenes))
    return out


def brick_hash(data: bytes, row: int, seed: int) -> int:
    """The brick hash of formats/augmented.md §2.3 in plain Python, from the text (the compiled one,
    isplat.brickstore.hash_bricks, must agree): ``data`` the brick's bytes (little-endian), ``row`` its row."""
    mask = (1 << 64) - 1
    h = seed ^ (((row + 1) * 0x9E3779B97F4A7C15) & mask)
    for o in range(0, len(data), 8):
        h ^= int.from_bytes(data[o:o + 8], "little")
        h = (h * 0xFF51AFD7ED558CCD) & mask
        h ^= h >> 32
    h ^= h >> 33
    h = (h * 0xC4CEB9FE1A85EC53) & mask
    return h ^ (h >> 33)


# the catalogue's named corruptions of the runs file (benchmarks/reliability.py, tests/test_reliability.py):
# (input, target, object, op), rendered with the scene that reads the runs file
RUNS_PAIR_CASES = [
    ("runs file density chunk byte flipped on disk", "runs", "/runs/density", "flip_chunk"),
    ("runs file pointer table byte flipped on disk", "runs", "/runs/run_voxel_ptr", "flip_chunk"),
    ("runs file positions chunk byte flipped on disk", "runs", "/runs/positions", "flip_chunk"),
    ("runs file attribute bytes flipped (lo_first)", "runs", "/@lo_first", "flip_header"),
    ("runs file dataset /runs/normal deleted", "runs", "/runs/normal", "delete"),
    ("runs file dataset /runs/density contiguous", "runs", "/runs/density", "contiguous"),
]


def runs_cases(fx: dict, w: Path) -> list[tuple[str, list, str]]:
    """(input, argv, words the message must hold): runs files beside an index (formats/runs.md) that a stranger
    can make, each in a folder of its own with copies of the fixture's index and values file, rendered with the
    scene that reads the runs file (or run through stats). tests/test_reliability.py checks each; the
    reliability benchmark's catalogue (benchmarks/reliability.py) lists them."""
    import shutil

    import h5py
    import numpy as np

    from isplat.runsfile import FORMAT_VERSION as RUNS_FORMAT_VERSION, build_runs_file, runs_path

    def folder(name, runs=True):
        d = w / f"runs-{name}"
        d.mkdir(exist_ok=True)
        idx = d / fx["idx"].name
        for src in (fx["idx"], fx.get("values")):
            if src is not None:
                shutil.copy(src, d / src.name)
        if runs:
            shutil.copy(fx["runs"], runs_path(idx))
        return idx, runs_path(idx)

    fresh = iter(range(1000))

    def render(idx, aug=None):
        sets = [f'data.index="{idx}"'] + ([f'data.augmented="{aug}"'] if aug else [])
        return ["render", str(fx["post_runs"]), "--view", "0", *[a for s in sets for a in ("--set", s)], "-o",
                str(w / f"r{next(fresh)}.png")]

    cases = []
    idx, rp = folder("other")                   # the runs of another volume: another density_sha256
    other = w / "runs-other" / "other.aug.h5"
    if not other.exists():
        from isplat.augfile import write_augmented
        from isplat.augment import augment_array
        from isplat.samples import make_sample

        arr, spacing = make_sample("head", SHAPE_IJK, 0)
        a = augment_array(np.ascontiguousarray(arr[::-1]), spacing)
        write_augmented(other, a["density"], a["gradient_magnitude"], a["normal"], a["spacing_ijk"],
                        a["density_window"], a["gradient_magnitude_scale"])
    rp.unlink()
    build_runs_file(other, idx)
    cases.append(("runs file of another volume beside the index", render(idx), "another volume"))
    idx, rp = folder("truncated")
    rp.write_bytes(fx["runs"].read_bytes()[: fx["runs"].stat().st_size // 2])
    cases.append(("runs file truncated to half its size", render(idx), "truncated"))
    idx, rp = folder("version")
    with h5py.File(rp, "r+") as f:
        f.attrs["format_version"] = np.int64(RUNS_FORMAT_VERSION + 1)
    cases.append((f"runs file of format version {RUNS_FORMAT_VERSION + 1}", render(idx), "version"))
    idx, rp = folder("folder", runs=False)
    rp.mkdir(exist_ok=True)
    cases.append(("runs file name taken by a folder", render(idx), "folder"))
    idx, rp = folder("fifo", runs=False)
    if not rp.exists():
        os.mkfifo(rp)
    cases.append(("runs file name taken by a fifo", render(idx), "fifo"))
    idx, rp = folder("reaugmented")             # isplat augment --force again, other spacing, without --index
    aug2 = idx.parent / fx["aug"].name
    if not aug2.exists():
        from isplat.augfile import open_augmented, write_augmented

        a = open_augmented(fx["aug"])
        write_augmented(aug2, a.read("density"), a.read("gradient_magnitude"), a.read("normal"),
                        tuple(2 * x for x in a.spacing_ijk), a.density_window, a.gradient_magnitude_scale)
    cases.append(("runs file left from before re-augmenting with another spacing (same densities)",
                  render(idx, aug2), "another augmentation"))
    idx, rp = folder("stats")
    with h5py.File(rp, "r+") as f:
        ds = f["runs/normal"]
        ds[0] = (int(ds[0]) + 1) % 65536          # a valid HDF5 edit: the chunk hash no longer matches
    cases.append(("stats: runs file beside the index edited (one normal)", ["stats", str(fx["aug"]), str(idx)],
                  "runs/normal"))
    idx, rp = folder("left", runs=True)
    idx.unlink()
    cases.append(("index --no-runs with a runs file left beside the new index (no --force)",
                  ["index", str(fx["aug"]), "-o", str(idx), "--no-runs"], "--force"))
    return cases
