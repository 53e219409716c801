"""Reliability: a seeded fuzzer over index and augmented files, the catalogue of bad inputs with the message each
gets, and what the checksums cost (docs/reliability.md).

    python -m isplat.bench.reliability --out docs [--fuzz-seconds 120] [--seed 0]

The fuzzer mutates the bytes of a small head's augmented and index files (bit flips, random bytes, zeroed runs,
truncation) and renders each mutant through the CLI, in process, and runs ``isplat stats --json`` on it: every run
must end in one ``isplat: error:`` line with a non-zero exit, or in images and figures equal to the unmutated
ones. tests/test_fuzz.py runs it for a bounded time; ``make fuzz-boundscheck`` runs it with numba bounds checking
on (a fresh NUMBA_CACHE_DIR).
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

def scene_toml(aug: Path, idx: Path, method: str = "indexed") -> str:
    """Three views (one per principal axis), every density visible, shading and gradient-modulated opacity:
    a render reads every index axis, every block, and the normal and gradient-magnitude channels."""
    return f"""version = 1
[data]
augmented = "{aug}"
index = "{idx}"
[image]
width = {IMAGE}
height = {IMAGE}
[transfer]
opacity = [[0, 0.02], [255, 0.6]]
gradient_opacity = [[0, 0.5], [255, 1.0]]
[shading]
ambient = 0.3
diffuse = 0.7
[render]
method = "{method}"
[views]
list = [{{azimuth = 0, elevation = 0}}, {{azimuth = 90, elevation = 0}}, {{azimuth = 0, elevation = 90}}]
"""


def make_fixture(folder: Path, aug: Path | None = None, idx: Path | None = None) -> dict:
    """A small head (or given files): augmented and index files, an indexed and a full scene, and their
    reference images."""
    from ..augfile import write_augmented
    from ..augment import augment_array
    from ..index import build_index_file
    from ..samples import make_sample

    folder.mkdir(parents=True, exist_ok=True)
    if aug is None:
        arr, spacing = make_sample("head", SHAPE_IJK, 0)
        a = augment_array(arr, spacing)
        aug = folder / "head.aug.h5"
        write_augmented(aug, a["density"], a["gradient_magnitude"], a["normal"], a["spacing_ijk"],
                        a["density_window"], a["gradient_magnitude_scale"])
    if idx is None:
        idx = folder / "head.idx.h5"
        build_index_file(aug, idx, force=True)
    fx = {"aug": aug, "idx": idx, "folder": folder}
    for method in ("indexed", "full"):
        sc = folder / f"{method}.toml"
        sc.write_text(scene_toml(aug, idx, method))
        fx[method] = sc
        code, err, images = run_render(sc, folder / f"ref_{method}")
        if code != 0:
            raise RuntimeError(f"reference render failed: {err}")
        fx[f"ref_{method}"] = images
    code, out, err = run_cli(["stats", str(aug), str(idx), "--json"])
    if code != 0:
        raise RuntimeError(f"reference stats failed: {err}")
    fx["ref_stats"] = out
    return fx


def run_cli(argv) -> tuple[int, str, str]:
    """Run ``isplat ARGV`` in this process; return (exit code, stdout, stderr)."""
    from ..cli.main import main

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


def check_mutant(fx: dict, target: str, data: bytes, mutation: str, limit: float = 20.0) -> Outcome:
    """Write the mutant over the fixture's ``target`` file, render both scenes and run ``stats --json``, restore
    the file. Each must end in one error line and a non-zero exit, or give the unmutated images and figures."""
    path = fx[target]
    original = path.read_bytes()
    if data == original:
        return Outcome(target, mutation, "unchanged")
    path.write_bytes(data)
    old = signal.signal(signal.SIGALRM, _alarm)
    signal.setitimer(signal.ITIMER_REAL, limit)
    try:
        for method in ("indexed", "full"):
            code, err, images = run_render(fx[method], fx["folder"] / f"mut_{method}")
            lines = err.strip().splitlines()
            if code == 0 and images == fx[f"ref_{method}"]:
                continue
            if code != 0 and len(lines) == 1 and lines[0].startswith("isplat: error: ") and not images:
                return Outcome(target, mutation, "error", lines[0])
            what = "different image" if code == 0 else f"exit {code}, {len(lines)} stderr lines"
            return Outcome(target, mutation, f"FAIL ({method}: {what})", err[-2000:])
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


def fuzz(fx: dict, seconds: float, seed: int = 0, max_runs: int | None = None) -> FuzzReport:
    """Mutate the index and augmented files alternately for ``seconds`` (or ``max_runs`` mutants)."""
    rng = np.random.default_rng(seed)
    originals = {t: fx[t].read_bytes() for t in ("idx", "aug")}
    rep = FuzzReport(0.0)
    t0 = time.perf_counter()
    n = 0
    while time.perf_counter() - t0 < seconds and (max_runs is None or n < max_runs):
        target = ("idx", "aug")[n % 2]
        data, what = mutate(originals[target], rng)
        rep.outcomes.append(check_mutant(fx, target, data, what))
        n += 1
    rep.seconds = time.perf_counter() - t0
    return rep


# ------------------------------------------------------------------------------ named corruptions (the walk)

REQUIRED = {"aug": {"format", "format_version", "shape", "spacing_ijk", "density_window", "gradient_magnitude_scale",
                    "density_sha256", "created_by", "density", "gradient_magnitude", "normal"},
            "idx": {"format", "format_version", "shape", "density_sha256", "density_ranges", "created_by", "axis",
                    "n_slices",
                    "in_slice_axes", "n_a", "n_b", "escape_width", "density_entry_ptr", "entry_slice",
                    "entry_voxel_count", "entry_byte_offset", "bytes"}}
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
            at = (ds.id.get_chunk_info(0).byte_offset if op == "flip_chunk" and ds.id.get_num_chunks()
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

    from ..fileio import create_hdf5

    with h5py.File(src, "r") as a, create_hdf5(dst) as b:
        def copy(ga, gb):
            for k, v in ga.attrs.items():
                gb.attrs[k] = v
            for name, obj in ga.items():
                if isinstance(obj, h5py.Group):
                    copy(obj, gb.create_group(name))
                else:
                    gb.create_dataset(name, data=obj[()])
        copy(a, b)


def chunk_rounding(idx_path: Path, interval=(170, 255)) -> dict:
    """Bytes a bone-interval load requests from the index, and the bytes of the chunks HDF5 reads (and checks)
    for them: whole chunks, so a read of a row range is rounded out to chunk boundaries."""
    from unittest import mock

    from ..index import open_index, store

    real = store.IndexFile._read
    seen = {"requested": 0, "chunks": 0}

    def counting(self, g, name, lo, hi):
        ds = g[name]
        step, item = ds.chunks[0], ds.dtype.itemsize
        if hi > lo:
            seen["requested"] += (hi - lo) * item
            seen["chunks"] += ((hi - 1) // step - lo // step + 1) * step * item
        return real(self, g, name, lo, hi)

    with mock.patch.object(store.IndexFile, "_read", counting):
        ix = open_index(idx_path)
        for ax in "ijk":
            ix.load_axis(ax, [interval])
    return {"bone_requested_bytes": seen["requested"], "bone_chunk_bytes": seen["chunks"]}


def checksum_cost(folder: Path, shape_ijk=(256, 256, 160), repeats: int = 7) -> dict:
    """Median load time of a bone scene (index blocks + normals) and of whole channels, with and without
    checksums, interleaved in one run."""
    from unittest import mock

    from .. import augfile, fileio
    from ..augfile import open_augmented, write_augmented
    from ..augment import augment_array
    from ..index import build_index_file, open_index
    from ..index import store
    from ..samples import make_sample

    arr, spacing = make_sample("head", shape_ijk, 0)
    a = augment_array(arr, spacing)
    aug, idx = folder / "cost.aug.h5", folder / "cost.idx.h5"
    write_augmented(aug, a["density"], a["gradient_magnitude"], a["normal"], a["spacing_ijk"],
                    a["density_window"], a["gradient_magnitude_scale"])
    build_index_file(aug, idx, force=True)
    aug0, idx0 = folder / "cost0.aug.h5", folder / "cost0.idx.h5"
    _rewrite_unchecked(aug, aug0)
    _rewrite_unchecked(idx, idx0)
    no_check = [mock.patch.object(m, "check_checked_dataset", lambda *a: None) for m in (augfile, store)]

    def load_scene_data(aug_path, idx_path):
        ix = open_index(idx_path)
        for ax in "ijk":
            ix.load_axis(ax, [(170, 255)])
        av = open_augmented(aug_path)
        for k0 in range(0, av.shape[0], 8):
            av.read("normal", k0, k0 + 8)

    def whole(aug_path, idx_path):
        av = open_augmented(aug_path)
        for ch in ("density", "gradient_magnitude", "normal"):
            av.read(ch)
        ix = open_index(idx_path)
        for ax in "ijk":
            ix.load_axis(ax, [(0, 255)])

    def render_first_frame(aug_path, idx_path):
        from ..render import Renderer
        from ..scene import parse_scene

        text = (f'version = 1\n[data]\naugmented = "{aug_path}"\nindex = "{idx_path}"\n[image]\nwidth = 256\n'
                'height = 256\n[transfer]\nopacity = [[170, 0.0], [200, 1.0], [255, 1.0]]\n[shading]\n'
                'ambient = 0.2\n[render]\nmethod = "indexed"\n')
        Renderer(parse_scene(text, folder, "bench.toml")).render_view(0)

    render_first_frame(aug, idx)            # compile and warm the page cache before timing
    times = {(w, v): [] for w in ("scene", "whole", "frame") for v in ("checked", "unchecked")}
    with contextlib.ExitStack() as st:
        for p in no_check:
            st.enter_context(p)
        for _ in range(repeats):
            for w, fn in (("scene", load_scene_data), ("whole", whole), ("frame", render_first_frame)):
                for v, (ap, ip) in (("checked", (aug, idx)), ("unchecked", (aug0, idx0))):
                    t = time.perf_counter()
                    fn(ap, ip)
                    times[(w, v)].append(time.perf_counter() - t)
    med = {f"{w}_{v}": statistics.median(ts) for (w, v), ts in times.items()}
    med.update(chunk_rounding(idx))
    med.update(shape_ijk=list(shape_ijk), repeats=repeats, aug_bytes=aug.stat().st_size,
               aug_bytes_unchecked=aug0.stat().st_size, idx_bytes=idx.stat().st_size,
               idx_bytes_unchecked=idx0.stat().st_size, chunk_target=fileio.MAX_CHUNK_BYTES)
    return med


# ----------------------------------------------------------------------------------------------- catalogue

def _pair_cases(fx: dict) -> list[tuple[str, str, str, str]]:
    """(input, target, object, op): named corruptions of the fixture's files, each rendered."""
    cases = [
        ("index block byte flipped on disk", "idx", "/axes/k/bytes", "flip_chunk"),
        ("index table byte flipped on disk", "idx", "/axes/j/entry_voxel_count", "flip_chunk"),
        ("index offsets byte flipped on disk", "idx", "/axes/i/entry_byte_offset", "flip_chunk"),
        ("index density_entry_ptr byte flipped", "idx", "/axes/k/density_entry_ptr", "flip_chunk"),
        ("normal channel byte flipped on disk", "aug", "/normal", "flip_chunk"),
        ("gradient magnitude byte flipped on disk", "aug", "/gradient_magnitude", "flip_chunk"),
        ("density channel byte flipped on disk", "aug", "/density", "flip_chunk"),
        ("index dataset header (dataspace) corrupted", "idx", "/axes/k/entry_slice", "dataspace"),
        ("augmented dataset header (dataspace) corrupted", "aug", "/normal", "dataspace"),
        ("augmented attribute bytes flipped (spacing)", "aug", "/@spacing_ijk", "flip_header"),
        ("index attribute bytes flipped (n_a)", "idx", "/axes/k@n_a", "flip_header"),
        ("index root attribute bytes flipped (shape)", "idx", "/@shape", "flip_header"),
    ]
    for target, objs in (("aug", ["/normal", "/density"]), ("idx", ["/axes/k/bytes", "/axes/i/entry_slice"])):
        for obj in objs:
            for op in ("delete", "dtype", "shape", "contiguous", "gzip"):
                cases.append((f"dataset {obj}: {op}", target, obj, op))
    for target, obj in (("aug", "/@format_version"), ("aug", "/@spacing_ijk"), ("aug", "/@density_window"),
                        ("idx", "/@format_version"), ("idx", "/@density_ranges"), ("idx", "/axes/j@escape_width")):
        for op in ("delete", "as_string", "as_float", "as_int32", "as_array", "nan"):
            cases.append((f"attribute {obj}: {op}", target, obj, op))
    return cases


def _cli_cases(fx: dict, w: Path) -> list[tuple[str, list]]:
    """(input, argv): misuse of the command line and of the pipeline."""
    aug, idx, sc = str(fx["aug"]), str(fx["idx"]), str(fx["indexed"])
    (w / "exists.png").write_bytes(b"")
    (w / "const.npy").write_bytes(b"")
    import numpy as _np
    _np.save(w / "const.npy", _np.zeros((4, 4, 4), _np.float32))
    (w / "not.h5").write_text("not hdf5")
    other = w / "other.idx.h5"
    if not other.exists():
        from ..index import build_index, write_index
        vol = _np.zeros((16, 18, 20), _np.uint8)
        vol[3, 3, 3] = 9
        write_index(other, build_index(vol, "ijk"), vol.shape, "0" * 64, force=True)
    orbit = w / "orbit.toml"
    orbit.write_text(fx["indexed"].read_text().split("[views]")[0] + "[views]\norbit_steps = 720\n")
    part = w / "part.idx.h5"
    if not part.exists():
        from ..index import build_index_file
        build_index_file(aug, part, ranges=[(200, 255)], force=True)
    return [
        ("unknown subcommand", ["bogus"]),
        ("unknown sample name", ["sample", "bogus", "-o", str(w / "x.npy")]),
        ("missing argument", ["render"]),
        ("unknown option", ["render", sc, "--nope"]),
        ("too many arguments", ["stats", aug, idx, "extra"]),
        ("scene file missing", ["render", str(w / "missing.toml")]),
        ("output exists without --force", ["render", sc, "--view", "0", "-o", str(w / "exists.png")]),
        ("output folder missing", ["render", sc, "--view", "0", "-o", str(w / "no" / "x.png")]),
        ("unknown image type", ["render", sc, "--view", "0", "-o", str(w / "x.bmp")]),
        ("batch of views to stdout", ["render", sc, "-o", "-"]),
        ("--json with -o -", ["render", sc, "--view", "0", "--json", "-o", "-"]),
        ("--view out of range", ["render", sc, "--view", "7", "-o", str(w / "x.png")]),
        ("--set without '='", ["render", sc, "--set", "camera.azimuth", "-o", str(w / "x.png")]),
        ("--set of an unknown key", ["render", sc, "--set", "camera.azimut=3", "-o", str(w / "x.png")]),
        ("stats --set without --scene", ["stats", aug, "--set", "camera.azimuth=3"]),
        ("volume.spacing = [1e-300, 1, 1]", ["render", sc, "--set", "volume.spacing=[1e-300,1,1]", "-o",
                                             str(w / "x.png")]),
        ("volume.spacing ratio 1e7", ["render", sc, "--set", "volume.spacing=[1e-4,1,1000]", "-o", str(w / "x.png")]),
        ("perspective camera.fov = 179.9", ["render", sc, "--set", "camera.projection=perspective", "--set",
                                            "camera.fov=179.9", "-o", str(w / "x.png")]),
        ("image buffers beyond the memory available (8192^2, 720 views, GIF)",
         ["render", str(orbit), "--set", "image.width=8192", "--set", "image.height=8192", "-o", str(w / "x.gif")]),
        ("augment: input missing", ["augment", str(w / "missing.npy"), "-o", str(w / "m.aug.h5")]),
        ("augment: constant volume", ["augment", str(w / "const.npy"), "-o", str(w / "c.aug.h5")]),
        ("index: input is not HDF5", ["index", str(w / "not.h5"), "-o", str(w / "n.idx.h5")]),
        ("index: input is an index file", ["index", idx, "-o", str(w / "n.idx.h5")]),
        ("stats: index of another volume", ["stats", aug, str(other)]),
        ("render: transfer function outside the indexed densities",
         ["render", sc, "--set", f"data.index=\"{part}\"", "-o", str(w / "x.png")]),
        ("version-1 augmented file (no checksums)",
         ["stats", str(Path(__file__).resolve().parents[2] / "formats/examples/augmented/invalid-version-1.aug.h5")]),
    ]


def catalogue(fx: dict, w: Path) -> list[dict]:
    """Every bad input with its exit status and message (temporary folders shown as W/)."""
    rows = []

    repo = str(Path(__file__).resolve().parents[2]) + "/"

    def clean(text):
        return text.strip().replace(str(w) + "/", "W/").replace(str(fx["folder"]) + "/", "W/").replace(repo, "")

    for what, target, obj, op in _pair_cases(fx):
        path = fx[target]
        original = path.read_bytes()
        try:
            corrupt(path, obj, op)
            mutant = path.read_bytes()
        finally:
            path.write_bytes(original)
        o = check_mutant(fx, target, mutant, op)
        rows.append({"input": what, "command": f"render ({target} file corrupted)", "result": o.result,
                     "message": clean(o.message) if o.message else f"({o.result})"})
    for what, argv in _cli_cases(fx, w):
        code, _, err = run_cli(argv)
        rows.append({"input": what, "command": " ".join(argv[:1]), "result": f"exit {code}",
                     "message": clean(err) or "(no message)"})
    root = Path(__file__).resolve().parents[2] / "formats/examples/scene/invalid"
    for toml in sorted(root.glob("*.toml")):
        code, _, err = run_cli(["render", str(toml), "-o", str(w / "x.png")])
        rows.append({"input": f"scene {toml.name}", "command": "render", "result": f"exit {code}",
                     "message": clean(err).replace(str(root) + "/", "")})
    return rows


# ------------------------------------------------------------------------------------------------- report

def fuzz_figures(seconds: float, seed: int) -> dict:
    """Fuzz for ``seconds`` in a fresh fixture; the counts by outcome."""
    with tempfile.TemporaryDirectory() as td:
        fx = make_fixture(Path(td))
        rep = fuzz(fx, seconds, seed)
    by = {}
    for o in rep.outcomes:
        key = o.result if not o.result.startswith("FAIL") else "failure"
        by[key] = by.get(key, 0) + 1
    return {"seconds": round(rep.seconds, 1), "seed": seed, "runs": len(rep.outcomes), "by_result": by,
            "boundscheck": os.environ.get("NUMBA_BOUNDSCHECK", "0") == "1",
            "failures": [f"{o.target}: {o.mutation}: {o.result}" for o in rep.failures][:20]}


def fuzz_boundscheck(seconds: float, seed: int) -> dict:
    """The same fuzzing in a child process with NUMBA_BOUNDSCHECK=1 and a fresh NUMBA_CACHE_DIR."""
    import json
    import subprocess
    import sys

    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_BOUNDSCHECK="1", NUMBA_CACHE_DIR=cache, ISPLAT_PROGRESS="0")
        t = time.perf_counter()
        r = subprocess.run([sys.executable, "-m", "isplat.bench.reliability", "--fuzz-json", str(seconds),
                            "--seed", str(seed)], env=env, capture_output=True, text=True)
        if r.returncode != 0:
            raise RuntimeError(f"bounds-checked fuzzing failed: {r.stderr[-2000:]}")
        out = json.loads(r.stdout.strip().splitlines()[-1])
        out["wall_seconds_with_compilation"] = round(time.perf_counter() - t, 1)
        return out


def _fuzz_table(rows: list[dict]) -> str:
    lines = ["| run | bounds checking | seed | seconds | mutants | one error line | same images | bytes unchanged | "
             "failures |", "|---|---|---|---|---|---|---|---|---|"]
    for name, f in rows:
        b = f["by_result"]
        lines.append(f"| {name} | {'on' if f['boundscheck'] else 'off'} | {f['seed']} | {f['seconds']} | {f['runs']} | "
                     f"{b.get('error', 0)} | {b.get('equal', 0)} | {b.get('unchanged', 0)} | {b.get('failure', 0)} |")
    return "\n".join(lines)


def _md(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def write_report(out: Path, cat: list[dict], fz: list, cost: dict) -> Path:
    from ._doc import git_rev, machine_line, update_section

    c = cost
    body = [
        "Made by `python -m isplat.bench.reliability --out docs` (`make reliability`) at commit "
        f"{git_rev()} on {machine_line()}. Every figure below is measured by that command.",
        "",
        "## Fuzzing",
        "",
        "Mutants of a small head's augmented and index files (`SHAPE_IJK` "
        f"{'x'.join(map(str, SHAPE_IJK))}, alternately): a bit flip (half of them), a random byte, a zeroed run of "
        "1-64 bytes or a truncation, at a uniformly random position. Each mutant is rendered through the CLI with "
        "both methods (three views, one per axis, every density visible, shading and gradient-modulated opacity, "
        "so every dataset is read), then `isplat stats AUG IDX --json` runs on it. A run passes if it ends in "
        "exactly one `isplat: error:` line, a non-zero exit and no output, or in PNGs byte-equal to the unmutated "
        "ones and the same figures; a failure is anything else (another image or figure, a traceback, a hang of "
        "20 s).",
        "",
        _fuzz_table(fz),
        "",
        "The bounds-checked run is a child process with `NUMBA_BOUNDSCHECK=1` and a fresh `NUMBA_CACHE_DIR` "
        "(numba would otherwise reuse kernels compiled without checks); its wall time including compilation was "
        f"{fz[-1][1].get('wall_seconds_with_compilation', '?')} s. `make test` fuzzes for 45 s "
        "(tests/test_fuzz.py); `make fuzz-boundscheck` runs that test with bounds checking.",
        "",
        "## What the checksums cost",
        "",
        f"A head of {'x'.join(map(str, c['shape_ijk']))} voxels; median of {c['repeats']} interleaved runs. "
        "*checked*: the files as isplat writes them (Fletcher-32 chunks of about "
        f"{c['chunk_target'] // 1024} KiB in the channels, 16 KiB in the index tables, 64 KiB in its bytes); "
        "*unchecked*: the same files rewritten with contiguous, "
        "unfiltered datasets (metadata checksums kept), read with the layout check switched off.",
        "",
        "| load | checked | unchecked | ratio |",
        "|---|---|---|---|",
        f"| bone scene: index blocks of densities 170..255 on three axes, normals in 8-slice slabs | "
        f"{1000 * c['scene_checked']:.1f} ms | {1000 * c['scene_unchecked']:.1f} ms | "
        f"{c['scene_checked'] / c['scene_unchecked']:.2f} |",
        f"| bone scene end to end: Renderer (load, decode, select, gather) and its first 256x256 frame | "
        f"{1000 * c['frame_checked']:.1f} ms | {1000 * c['frame_unchecked']:.1f} ms | "
        f"{c['frame_checked'] / c['frame_unchecked']:.2f} |",
        f"| everything: three whole channels, all densities on three axes | {1000 * c['whole_checked']:.1f} ms | "
        f"{1000 * c['whole_unchecked']:.1f} ms | {c['whole_checked'] / c['whole_unchecked']:.2f} |",
        "| index bytes a bone load reads: whole chunks, read and checked (checked) against the rows and bytes "
        "requested (unchecked) | "
        f"{c['bone_chunk_bytes']:,} B | {c['bone_requested_bytes']:,} B | "
        f"{c['bone_chunk_bytes'] / c['bone_requested_bytes']:.2f} |",
        f"| augmented file size | {c['aug_bytes']:,} B | {c['aug_bytes_unchecked']:,} B | "
        f"{c['aug_bytes'] / c['aug_bytes_unchecked']:.3f} |",
        f"| index file size | {c['idx_bytes']:,} B | {c['idx_bytes_unchecked']:,} B | "
        f"{c['idx_bytes'] / c['idx_bytes_unchecked']:.3f} |",
        "",
        f"## Catalogue of bad inputs ({len(cat)})",
        "",
        "Each row was run by the command above; `W/` is its temporary folder. Corrupted files are rendered "
        "(both methods); the result is `error` when the run ended in one error line and a non-zero exit.",
        "",
        "| # | input | command | result | message |",
        "|---|---|---|---|---|",
    ]
    for n, r in enumerate(cat, 1):
        body.append(f"| {n} | {_md(r['input'])} | {r['command']} | {r['result']} | {_md(r['message'])[:400]} |")
    out.mkdir(parents=True, exist_ok=True)
    return update_section(out / "reliability.md", "reliability", "\n".join(body), title="Reliability: bad input, "
                          "corrupted files, interruptions")


def run(out: Path, quick: bool = False, fuzz_seconds: float | None = None, seed: int = 0) -> Path:
    secs = fuzz_seconds if fuzz_seconds is not None else (10.0 if quick else 120.0)
    with tempfile.TemporaryDirectory() as td:
        w = Path(td)
        fx = make_fixture(w / "fx")
        cat = catalogue(fx, w)
        cost = checksum_cost(w, (64, 64, 48) if quick else (256, 256, 160), 3 if quick else 7)
    fz = [("in process", fuzz_figures(secs, seed)), ("child process", fuzz_boundscheck(secs, seed))]
    return write_report(Path(out), cat, fz, cost)


def main(argv=None) -> int:
    import json
    import sys

    ap = argparse.ArgumentParser(prog="python -m isplat.bench.reliability", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="docs", type=Path)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--fuzz-seconds", type=float, default=None)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--fuzz-json", type=float, default=None, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    os.environ.setdefault("ISPLAT_PROGRESS", "0")
    if a.fuzz_json is not None:
        print(json.dumps(fuzz_figures(a.fuzz_json, a.seed)))
        return 0
    print(run(a.out, a.quick, a.fuzz_seconds, a.seed), file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
