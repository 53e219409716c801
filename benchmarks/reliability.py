"""Reliability: a seeded fuzzer over index and augmented files (and the index's values and runs files), the
catalogue of bad inputs with the message each gets, and what the checksums cost (docs/reliability.md).

    python -m benchmarks reliability --out docs [--fuzz-seconds 120] [--seed 0]

The fuzzer mutates the bytes of a small head's augmented and index files and of the index's values and runs files
(bit flips, random bytes, zeroed runs, truncation) and renders each mutant through the CLI, in process, and runs
``isplat stats --json`` on it: every run must end in one ``isplat: error:`` line with a non-zero exit, or in images
and figures equal to the unmutated ones. tests/test_fuzz.py runs it for a bounded time; ``make fuzz-boundscheck``
runs it with numba bounds checking on (a fresh NUMBA_CACHE_DIR).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

# the fuzzer and the corruptions are the tests' (tests/fuzzlab.py); this page runs them for longer
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from fuzzlab import (RUNS_PAIR_CASES, SHAPE_IJK, TECHNIQUES as FUZZ_SCENES, make_fixture, run_cli,  # noqa: E402
                     mutate, runs_cases, check_mutant, fuzz, corrupt, scene_label, _rewrite_unchecked)

from . import _doc  # noqa: E402

SECTION = "reliability"        # the section of its page this benchmark writes
STAMPS_ITSELF = True     # write_report stamps its section
TECHNIQUES = ["pre", "post"]     # render.classification of its rows (the page's stamp)
SOURCES = _doc.sources(("isplat/**", "formats/examples/**", "tests/fuzzlab.py", "benchmarks/reliability.py"))



def chunk_rounding(idx_path: Path, interval=(170, 255)) -> dict:
    """Bytes a bone-interval load requests from the index, and the bytes of the chunks HDF5 reads (and checks)
    for them: whole chunks, so a read of a row range is rounded out to chunk boundaries."""
    from unittest import mock

    from isplat.index import open_index, store

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


def read_whole(aug_path, idx_path, values: bool = False) -> None:
    """Read every channel of the augmented file and every block of the index's three axes (and, with
    ``values``, the index's /values), as a load that touches all of both files."""
    from isplat.augfile import open_augmented
    from isplat.index import open_index

    av = open_augmented(aug_path)
    for ch in ("density", "gradient_magnitude", "normal"):
        av.read(ch)
    ix = open_index(idx_path)
    for ax in "ijk":
        ix.load_axis(ax, [(0, 255)])
    if values:
        ix.read_values(["normal", "gradient_magnitude"], [(0, 255)])


def checksum_cost(folder: Path, shape_ijk=(256, 256, 160), repeats: int = 7) -> dict:
    """Median load time of a bone scene (index blocks + normals) and of whole channels, with and without
    checksums, interleaved in one run."""
    from unittest import mock

    from isplat import augfile, fileio
    from isplat.augfile import ROWS_VERSION, open_augmented, write_augmented
    from isplat.augment import augment_array
    from isplat.index import build_index_file, open_index, values_path
    from isplat.index import store
    from isplat.samples import make_sample

    arr, spacing = make_sample("head", shape_ijk, 0)
    a = augment_array(arr, spacing)
    aug, idx = folder / "cost.aug.h5", folder / "cost.idx.h5"
    write_augmented(aug, a["density"], a["gradient_magnitude"], a["normal"], a["spacing_ijk"],
                    a["density_window"], a["gradient_magnitude_scale"], version=ROWS_VERSION)
    build_index_file(aug, idx, force=True)
    aug0, idx0 = folder / "cost0.aug.h5", folder / "cost0.idx.h5"
    _rewrite_unchecked(aug, aug0)
    _rewrite_unchecked(idx, idx0)
    _rewrite_unchecked(values_path(idx), values_path(idx0))     # pre's values, beside the index (index format 6)
    no_check = [mock.patch.object(m, "check_checked_dataset", lambda *a: None) for m in (augfile, store)]
    no_check.append(mock.patch.object(store, "check_hashed_dataset", lambda *a: None))   # index format 7
    no_check.append(no_chunk_hashes())      # the unchecked copies have no chunks, so no chunk hashes to check

    def load_scene_data(aug_path, idx_path):
        ix = open_index(idx_path)
        for ax in "ijk":
            ix.load_axis(ax, [(170, 255)])
        av = open_augmented(aug_path)
        for k0 in range(0, av.shape[0], 8):
            av.read("normal", k0, k0 + 8)

    def whole(aug_path, idx_path):
        read_whole(aug_path, idx_path)

    def render_first_frame(aug_path, idx_path, technique):
        from isplat.renderer import Renderer
        from isplat.scene import parse_scene

        text = (f'version = 4\n[data]\naugmented = "{aug_path}"\nindex = "{idx_path}"\n[image]\nwidth = 256\n'
                'height = 256\n[transfer]\nopacity = [[170, 0.0], [200, 1.0], [255, 1.0]]\n[shading]\n'
                f'ambient = 0.2\n[render]\nmethod = "indexed"\nclassification = "{technique}"\n')
        Renderer(parse_scene(text, folder, "bench.toml")).render_view(0)

    def frame_pre(aug_path, idx_path):
        render_first_frame(aug_path, idx_path, "pre")

    def frame_post(aug_path, idx_path):
        render_first_frame(aug_path, idx_path, "post")

    frame_pre(aug, idx)                     # compile and warm the page cache before timing
    frame_post(aug, idx)
    jobs = (("scene", load_scene_data), ("whole", whole), ("frame_pre", frame_pre), ("frame_post", frame_post))
    times = {(w, v): [] for w, _ in jobs for v in ("checked", "unchecked")}
    with contextlib.ExitStack() as st:
        for p in no_check:
            st.enter_context(p)
        for _ in range(repeats):
            for w, fn in jobs:
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


class _PlainReads:
    """A stand-in for :class:`isplat.chunkhash.Verifier` that reads through HDF5 without checking the chunk hashes
    (only what HDF5 checks itself: Fletcher-32 where a dataset has it; index format 7 has none). The brick hashes
    of an augmented file of format 6 are not the verifier's (isplat.brickstore) and are still checked."""

    chunks_verified = 0

    def read(self, f, dataset, sel=None, check=None, fetch=None):
        ds = f[dataset]
        return ds[tuple(sel)] if sel else ds[()]

    def verify_all(self, f, dataset):
        f[dataset][()]              # read it all, as the check would, without hashing


@contextlib.contextmanager
def no_chunk_hashes():
    """Inside the block, readers open files without checking chunk hashes (their Fletcher-32 is still checked)."""
    from unittest import mock

    from isplat import chunkhash

    with mock.patch.object(chunkhash, "open_verifier", lambda *a, **k: _PlainReads()):
        yield


FILE_NAMES = {"aug": "augmented", "idx": "index", "values": "values file", "runs": "runs file"}
HASH_SECTION = "reliability-chunk-hashes"
HASH_SOURCES = _doc.sources(("isplat/chunkhash.py", "isplat/augfile.py", "isplat/index/store.py",
                             "isplat/selection.py", "isplat/fileio.py", "benchmarks/reliability.py"))


def chunk_hash_cost(folder: Path, shape_ijk=(128, 128, 96), repeats: int = 5) -> dict:
    """Median times of the loads a render makes (the selection of a bone scene, both techniques; every channel and
    axis whole), of ``isplat stats``'s check of every chunk, and of writing the files, with the chunk hashes
    checked (as isplat reads) and not checked (the same files, Fletcher-32 only), interleaved in one run; and the
    bytes HDF5 read for the selection each way."""
    from isplat.augfile import ROWS_VERSION, open_augmented, write_augmented
    from isplat.augment import augment_array
    from isplat.index import build_index_file, open_index
    from isplat.samples import make_sample
    from isplat.scene import parse_scene
    from isplat.selection import select_from_files

    arr, spacing = make_sample("head", shape_ijk, 0)
    a = augment_array(arr, spacing)
    aug, idx = folder / "hash.aug.h5", folder / "hash.idx.h5"

    def write_files():
        write_augmented(aug, a["density"], a["gradient_magnitude"], a["normal"], a["spacing_ijk"],
                        a["density_window"], a["gradient_magnitude_scale"], version=ROWS_VERSION)
        build_index_file(aug, idx, force=True)

    def write_files_without_tables():
        from unittest import mock

        from isplat import chunkhash
        with mock.patch.object(chunkhash, "write_tables", lambda *x, **k: None), no_chunk_hashes():
            write_files()

    def scene(technique):
        text = (f'version = 4\n[data]\naugmented = "{aug}"\nindex = "{idx}"\n[image]\nwidth = 256\n'
                'height = 256\n[transfer]\nopacity = [[170, 0.0], [200, 1.0], [255, 1.0]]\n[shading]\n'
                f'ambient = 0.2\n[render]\nmethod = "indexed"\nclassification = "{technique}"\n')
        return parse_scene(text, folder, "bench.toml")

    scenes = {t: scene(t) for t in ("pre", "post")}
    seen = {}

    def selection(t):
        def job():
            sel = select_from_files(scenes[t], "k")
            seen[t] = sel.report.augmented_file_bytes + sel.report.index_file_bytes
        return job

    def whole():
        read_whole(aug, idx, values=True)

    def check_all():
        open_augmented(aug).verify_all()
        open_index(idx).verify_all()

    write_files()
    for t in scenes:                                 # compile and warm the page cache before timing
        selection(t)()
    jobs = (("selection_pre", selection("pre")), ("selection_post", selection("post")), ("whole", whole),
            ("stats_check", check_all))
    times = {(w, v): [] for w, _ in jobs for v in ("hashed", "plain")}
    read_bytes = {}
    for _ in range(repeats):
        for w, fn in jobs:
            for v in ("hashed", "plain"):
                with contextlib.ExitStack() as st:
                    if v == "plain":
                        st.enter_context(no_chunk_hashes())
                    t0 = time.perf_counter()
                    fn()
                    times[(w, v)].append(time.perf_counter() - t0)
                    if w.startswith("selection"):
                        read_bytes[(w, v)] = seen[w.split("_")[1]]
    writes = {"hashed": [], "plain": []}
    for _ in range(max(1, repeats // 2)):
        for v, fn in (("hashed", write_files), ("plain", write_files_without_tables)):
            t0 = time.perf_counter()
            fn()
            writes[v].append(time.perf_counter() - t0)
    write_files()
    med = {f"{w}_{v}": statistics.median(ts) for (w, v), ts in times.items()}
    med.update({f"write_{v}": statistics.median(ts) for v, ts in writes.items()})
    med.update({f"{w}_{v}_bytes": b for (w, v), b in read_bytes.items()})
    import h5py
    with h5py.File(aug, "r") as fa, h5py.File(idx, "r") as fi:
        med["aug_table_bytes"] = sum(int(d.size) for d in fa["chunk_hashes"].values())
        med["idx_table_bytes"] = sum(int(d.size) for d in fi["chunk_hashes"].values())
        med["idx_chunks"] = sum(int(d.shape[0]) for d in fi["chunk_hashes"].values())
        med["aug_chunks"] = sum(int(d.shape[0]) for d in fa["chunk_hashes"].values())
    med.update(shape_ijk=list(shape_ijk), repeats=repeats, aug_bytes=aug.stat().st_size, idx_bytes=idx.stat().st_size)
    return med


def class_fuzz_figures(folder: Path, per_class: int, seed: int) -> dict:
    """fuzzlab's mutant classes (tests/fuzzlab.py ``MUTANT_CLASSES``) on the fuzzer's small head, each mutant
    rendered with every fixture scene (both techniques) and ``stats --json``: {class: {target: {result: n}}}."""
    from fuzzlab import fuzz_classes

    fx = make_fixture(folder / "classes")
    t0 = time.perf_counter()
    res = fuzz_classes(fx, per_class, seed)
    out = {}
    for cls, outcomes in res.items():
        for o in outcomes:
            r = "failure" if o.result.startswith("FAIL") else o.result
            out.setdefault(cls, {}).setdefault(o.target, {}).setdefault(r, 0)
            out[cls][o.target][r] += 1
            if r == "failure":
                out.setdefault("_failures", []).append(f"{o.mutation}: {o.result}")
    out["_seconds"] = round(time.perf_counter() - t0, 1)
    out["_scenes"] = [scene_label(n) for n in fx["scenes"]]
    return out


def write_hash_cost(out: Path, c: dict, note: str = "") -> Path:
    """The section ``reliability-chunk-hashes`` of docs/reliability.md, stamped."""
    from ._doc import git_rev, machine_line, update_section

    shape = "x".join(map(str, c["shape_ijk"]))
    command = (f"python -m benchmarks.reliability --chunk-hash-cost {shape.replace('x', ',')} --repeats "
               f"{c['repeats']} --per-class {c.get('per_class', 0)} --out docs")

    def row(label, key, unit="ms"):
        h, p = c[f"{key}_hashed"], c[f"{key}_plain"]
        return f"| {label} | {1000 * h:.1f} ms | {1000 * p:.1f} ms | {h / p:.2f} |"

    body = [
        "## What the chunk hashes cost",
        "",
        f"Made by `{command}` at commit {git_rev()} on {machine_line()}.{(' ' + note) if note else ''}",
        "",
        f"A head of {shape} voxels (augmented file of format 4, the layout `isplat augment` writes by default "
        f"(format 5's cost per brick: docs/design.md, \"Bricked channels\"), {c['aug_bytes']:,} B in "
        f"{c['aug_chunks']} chunks, index "
        f"{c['idx_bytes']:,} B in {c['idx_chunks']:,} chunks); median of {c['repeats']} interleaved runs. "
        "*hashed*: as isplat reads (formats/augmented.md §1.1: every chunk a read touches is read whole, hashed "
        "with BLAKE2b and compared with its row of the file's table, which is read too); *Fletcher-32 only*: the "
        "same files with the chunk-hash check switched off (HDF5's Fletcher-32 and metadata checksums still "
        "checked). The selection is `isplat.selection.select_from_files` of a bone scene (densities 170..255, "
        "shaded) for axis k: what `isplat render` loads before its first frame.",
        "",
        "| load | hashed | Fletcher-32 only | ratio |",
        "|---|---|---|---|",
        row("selection of the bone scene, pre (index blocks and the index's values of 170..255)", "selection_pre"),
        row("selection of the bone scene, post (index blocks and the whole channels)", "selection_post"),
        row("everything: three whole channels, all densities on three axes, all values", "whole"),
        row("`isplat stats`'s check of every chunk of both files (hashed: read and hash; Fletcher-32 only: read)",
            "stats_check"),
        row("writing both files (`write_augmented` and `build_index_file`): hashed includes the tables' pass",
            "write"),
        f"| bytes HDF5 read for the pre selection | {c['selection_pre_hashed_bytes']:,} B | "
        f"{c['selection_pre_plain_bytes']:,} B | "
        f"{c['selection_pre_hashed_bytes'] / c['selection_pre_plain_bytes']:.2f} |",
        f"| bytes HDF5 read for the post selection | {c['selection_post_hashed_bytes']:,} B | "
        f"{c['selection_post_plain_bytes']:,} B | "
        f"{c['selection_post_hashed_bytes'] / c['selection_post_plain_bytes']:.2f} |",
        f"| hash tables in the files (16 B per chunk) | {c['aug_table_bytes'] + c['idx_table_bytes']:,} B | 0 B | |",
        "",
        "The extra reads are the table rows of the chunks read and, for a read that starts or ends inside a chunk, "
        "the rest of that chunk (HDF5 reads it whole anyway, so the file bytes barely change); the time is "
        "BLAKE2b over the chunks read (about 1 GB/s on one core) and Python's per-chunk loop (4 KiB chunks in the "
        "index). What the hashes catch is below, and in tests/test_integrity.py "
        "(`test_mutant_classes_are_refused_with_one_line`).",
    ]
    fz = c.get("classes")
    if fz:
        body += [
            "",
            "### Mutant classes that Fletcher-32 cannot see",
            "",
            f"tests/fuzzlab.py's `MUTANT_CLASSES`, {c['per_class']} mutants per class (in turn of the augmented "
            f"file, the index, its values file and its runs file, those a class applies to; seed {c['seed']}) of "
            f"the fuzzer's small head ({'x'.join(map(str, SHAPE_IJK))}), each "
            f"rendered with the scenes {', '.join(fz['_scenes'])} and run through `isplat stats --json`, "
            f"{fz['_seconds']} s in all. *error*: one `isplat: error:` line, a non-zero exit, no image; *equal*: the "
            "unmutated images and figures; *unchanged*: the mutation left the bytes as they were; *failure*: "
            "anything else (a different image, a traceback, a hang).",
            "",
            "| class | file | error | equal | unchanged | failure |",
            "|---|---|---|---|---|---|",
        ]
        for cls, per in fz.items():
            if cls.startswith("_"):
                continue
            for target, r in sorted(per.items()):
                body.append(f"| {cls} | {FILE_NAMES.get(target, target)} | {r.get('error', 0)} | "
                            f"{r.get('equal', 0)} | {r.get('unchanged', 0)} | {r.get('failure', 0)} |")
        for line in fz.get("_failures", [])[:20]:
            body.append(f"\nFailure: {_md(line)}")
    page = Path(out) / "reliability.md"
    update_section(page, HASH_SECTION, "\n".join(body))
    return _doc.put_stamp(page, _doc.stamp(HASH_SECTION, command, ["pre", "post"], HASH_SOURCES), HASH_SECTION)


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
        # the index's runs file (formats/runs.md), read by the post scene that does not see code 0
        *RUNS_PAIR_CASES,
    ]
    # the layout op breaks the format's rule for the dataset: the index's datasets MUST be chunked, the augmented
    # channels of format 6 (isplat augment's default) MUST be contiguous (formats/augmented.md §2.3)
    for target, objs, layout in (("aug", ["/normal", "/density"], "chunked"),
                                 ("idx", ["/axes/k/bytes", "/axes/i/entry_slice"], "contiguous")):
        for obj in objs:
            for op in ("delete", "dtype", "shape", layout, "gzip"):
                cases.append((f"dataset {obj}: {op}", target, obj, op))
    for target, obj in (("aug", "/@format_version"), ("aug", "/@spacing_ijk"), ("aug", "/@density_window"),
                        ("idx", "/@format_version"), ("idx", "/@density_ranges"), ("idx", "/axes/j@escape_width")):
        for op in ("delete", "as_string", "as_float", "as_int32", "as_array", "nan"):
            cases.append((f"attribute {obj}: {op}", target, obj, op))
    return cases


def _cli_cases(fx: dict, w: Path) -> list[tuple[str, list]]:
    """(input, argv): misuse of the command line and of the pipeline."""
    aug, idx, sc = str(fx["aug"]), str(fx["idx"]), str(fx["post"])      # the default technique's scene
    (w / "exists.png").write_bytes(b"")
    (w / "const.npy").write_bytes(b"")
    import numpy as _np
    _np.save(w / "const.npy", _np.zeros((4, 4, 4), _np.float32))
    (w / "not.h5").write_text("not hdf5")
    other = w / "other.idx.h5"
    if not other.exists():
        from isplat.index import build_index, write_index
        vol = _np.zeros((16, 18, 20), _np.uint8)
        vol[3, 3, 3] = 9
        write_index(other, build_index(vol, "ijk"), vol.shape, "0" * 64, force=True)
    orbit = w / "orbit.toml"
    orbit.write_text(fx["post"].read_text().split("[views]")[0] + "[views]\norbit_steps = 720\n")
    part = w / "part.idx.h5"
    if not part.exists():
        from isplat.index import build_index_file
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
        *_hostile_cases(fx, w, sc),
        ("version-1 augmented file (no checksums)",
         ["stats", str(Path(__file__).resolve().parents[1] / "formats/examples/augmented/invalid-version-1.aug.h5")]),
        *[(what, argv) for what, argv, _ in runs_cases(fx, w)],
    ]


def _hostile_cases(fx: dict, w: Path, sc: str) -> list[tuple[str, list]]:
    """(input, argv): issue 30's hand-made hostile inputs (tests/test_hostile.py checks each in full)."""
    import os

    (w / "nested.toml").write_text("a = " + "[" * 5000 + "]" * 5000 + "\n")
    for name in ("fifo.toml", "fifo.aug.h5", "fifo-out.png"):
        if not (w / name).exists():
            os.mkfifo(w / name)
    import numpy as np

    np.save(w / "ramp.npy", np.arange(6 * 5 * 4, dtype=np.float32).reshape(4, 5, 6))
    npy = str(w / "ramp.npy")

    fresh = iter(range(1000))
    if not (w / "dev.png").is_symlink():
        (w / "dev.png").symlink_to("/dev/null")

    def render(*sets, out=None):      # each case its own new output (an image one case wrote refuses the next)
        out = out or str(w / f"h{next(fresh)}.png")
        return ["render", sc, "--view", "0", *[a for s in sets for a in ("--set", s)], "-o", out]
    return [
        ("scene of 5,000 nested arrays", ["render", str(w / "nested.toml"), "-o", str(w / "n.png")]),
        ("-o /proc/x.png", render(out="/proc/x.png")),
        ("views.orbit_steps = 1000000000", ["render", sc, "--set", "views.orbit_steps=1000000000", "-o",
                                            str(w / "x.gif")]),
        ("a fifo as the scene", ["render", str(w / "fifo.toml"), "-o", str(w / "f.png")]),
        ("a fifo as the augmented file", render(f'data.augmented="{w / "fifo.aug.h5"}"')),
        ("a fifo given to stats", ["stats", str(w / "fifo.aug.h5")]),
        ("camera.zoom = 1e308", render("camera.zoom=1e308")),
        ("perspective camera.fov = 170", render('camera.projection="perspective"', "camera.fov=170")),
        ("perspective camera.fov = 179.82", render('camera.projection="perspective"', "camera.fov=179.82")),
        ("volume.origin = [1e308, 0, 0]", render("volume.origin=[1e308, 0, 0]")),
        ("volume.origin = [1e17, 0, 0]", render("volume.origin=[1e17, 0, 0]")),
        ("-o /dev/null with --force", [*render(out="/dev/null"), "--force"]),
        ("-o a link to /dev/null named like an image, with --force", [*render(out=str(w / "dev.png")), "--force"]),
        ("-o a fifo with --force", [*render(out=str(w / "fifo-out.png")), "--force"]),
        ("augment --spacing 1e-300,1,1", ["augment", npy, "-o", str(w / "s.aug.h5"), "--spacing", "1e-300,1,1"]),
        ("augment --spacing 1e300,1e300,1e300", ["augment", npy, "-o", str(w / "s.aug.h5"), "--spacing",
                                                 "1e300,1e300,1e300"]),
        ("augment --window=-1e308,1e308", ["augment", npy, "-o", str(w / "s.aug.h5"), "--spacing", "1,1,1",
                                           "--window=-1e308,1e308"]),
    ]


def catalogue(fx: dict, w: Path) -> list[dict]:
    """Every bad input with its exit status and message (temporary folders shown as W/)."""
    rows = []

    repo = str(Path(__file__).resolve().parents[1]) + "/"

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
        rows.append({"input": what, "command": f"render, pre and post ({target} file corrupted)", "result": o.result,
                     "message": clean(o.message) if o.message else f"({o.result})"})
    sc, orbit = str(fx["post"]), w / "orbit.toml"
    from isplat import camera

    for what, argv in _cli_cases(fx, w):
        camera._WARNED.clear()      # the empty-frame warning is once per process: each case stands for a process
        code, _, err = run_cli(argv)
        cmd = " ".join(argv[:1]) + (" (post scene)" if sc in argv or str(orbit) in argv else
                                    " (post scene that reads the runs file)" if str(fx.get("post_runs")) in argv
                                    else "")
        rows.append({"input": what, "command": cmd, "result": f"exit {code}",
                     "message": clean(err) or "(no message)"})
    root = Path(__file__).resolve().parents[1] / "formats/examples/scene/invalid"
    tomls = sorted(root.glob("*.toml"))
    if not tomls:       # a wrong path would otherwise shrink the catalogue without a word
        raise SystemExit(f"reliability: no invalid scene examples in {root}")
    for toml in tomls:
        code, _, err = run_cli(["render", str(toml), "-o", str(w / "x.png")])
        rows.append({"input": f"scene {toml.name}", "command": "render", "result": f"exit {code}",
                     "message": clean(err).replace(str(root) + "/", "")})
    return rows


# ------------------------------------------------------------------------------------------------- report

def fuzz_figures(seconds: float, seed: int, technique: str) -> dict:
    """Fuzz for ``seconds`` in a fresh fixture whose scenes are those of ``technique`` ("pre": the paper's
    splatting, indexed and full methods; "post": the default, post-classified, shaded); the counts by outcome."""
    with tempfile.TemporaryDirectory() as td:
        fx = make_fixture(Path(td), scenes=FUZZ_SCENES[technique])
        rep = fuzz(fx, seconds, seed)
    by = {}
    for o in rep.outcomes:
        key = o.result if not o.result.startswith("FAIL") else "failure"
        by[key] = by.get(key, 0) + 1
    return {"technique": technique, "scenes": [scene_label(s) for s in FUZZ_SCENES[technique]],
            "seconds": round(rep.seconds, 1), "seed": seed, "runs": len(rep.outcomes), "by_result": by,
            "boundscheck": os.environ.get("NUMBA_BOUNDSCHECK", "0") == "1",
            "failures": [f"{o.target}: {o.mutation}: {o.result}" for o in rep.failures][:20]}


def fuzz_boundscheck(seconds: float, seed: int) -> list[dict]:
    """The same fuzzing, both techniques one after the other, in a child process with NUMBA_BOUNDSCHECK=1 and a
    fresh NUMBA_CACHE_DIR; each result carries the child's wall time (compilation included)."""
    import json
    import subprocess
    import sys

    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_BOUNDSCHECK="1", NUMBA_CACHE_DIR=cache, ISPLAT_PROGRESS="0")
        t = time.perf_counter()
        r = subprocess.run([sys.executable, "-m", "benchmarks.reliability", "--fuzz-json", str(seconds),
                            "--seed", str(seed)], env=env, capture_output=True, text=True)
        if r.returncode != 0:
            raise RuntimeError(f"bounds-checked fuzzing failed: {r.stderr[-2000:]}")
        out = json.loads(r.stdout.strip().splitlines()[-1])
        for o in out:
            o["wall_seconds_with_compilation"] = round(time.perf_counter() - t, 1)
        return out


def _fuzz_table(rows: list[dict]) -> str:
    lines = ["| run | technique (scenes rendered) | bounds checking | seed | seconds | mutants | one error line | "
             "same images | bytes unchanged | failures |", "|---|---|---|---|---|---|---|---|---|---|"]
    for name, f in rows:
        b = f["by_result"]
        lines.append(f"| {name} | {f['technique']} ({', '.join(f['scenes'])}) | {'on' if f['boundscheck'] else 'off'} "
                     f"| {f['seed']} | {f['seconds']} | {f['runs']} | "
                     f"{b.get('error', 0)} | {b.get('equal', 0)} | {b.get('unchanged', 0)} | {b.get('failure', 0)} |")
    return "\n".join(lines)


def _md(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def write_report(out: Path, cat: list[dict], fz: list, cost: dict, quick: bool = False) -> Path:
    from ._doc import git_rev, machine_line, update_section

    c = cost
    body = [
        f"Made by `python -m benchmarks.reliability --out docs{' --quick' if quick else ''}` (`make reliability`) "
        f"at commit {git_rev()} on {machine_line()}. Every figure below is measured by that command.",
        "",
        "## Fuzzing",
        "",
        "Mutants of a small head's augmented and index files and of the index's values and runs files (`SHAPE_IJK` "
        f"{'x'.join(map(str, SHAPE_IJK))}, in turn): a bit flip (half of them), a random byte, a zeroed run of "
        "1-64 bytes or a truncation, at a uniformly random position. Each mutant is rendered through the CLI with "
        "the row's technique (three views, one per axis, every density visible, shading and gradient-modulated "
        "opacity, so every dataset is read): *pre*, the paper's pre-classified splatting, with the indexed and the "
        "full method; *post*, post-classification (the default from scene version 4), with the indexed method, "
        "once seeing density 0 (which reads the index blocks and the whole channels) and once not (which reads "
        "the runs file beside the index, formats/runs.md §6); then `isplat stats AUG IDX --json` runs on it."
        " A run passes if it ends in "
        "exactly one `isplat: error:` line, a non-zero exit and no output, or in PNGs byte-equal to the unmutated "
        "ones and the same figures; a failure is anything else (another image or figure, a traceback, a hang of "
        "20 s).",
        "",
        _fuzz_table(fz),
        "",
        "The bounds-checked run is a child process with `NUMBA_BOUNDSCHECK=1` and a fresh `NUMBA_CACHE_DIR` "
        "(numba would otherwise reuse kernels compiled without checks); its wall time including compilation was "
        f"{fz[-1][1].get('wall_seconds_with_compilation', '?')} s for both techniques. `make test` fuzzes for 45 s "
        "(tests/test_fuzz.py), every mutant with both techniques' scenes; `make fuzz-boundscheck` runs that test "
        "with bounds checking (CI: 30 s).",
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
        *(f"| bone scene end to end, {t}: Renderer (load, decode, select, gather) and its first 256x256 frame | "
          f"{1000 * c[f'frame_{t}_checked']:.1f} ms | {1000 * c[f'frame_{t}_unchecked']:.1f} ms | "
          f"{c[f'frame_{t}_checked'] / c[f'frame_{t}_unchecked']:.2f} |" for t in ("pre", "post")),
        f"| everything: the three channels whole (as the full method reads them, and post from a file without "
        f"bricks), all densities on three "
        f"axes | {1000 * c['whole_checked']:.1f} ms | "
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
        "(both techniques: pre indexed, pre full, post indexed, post indexed from the runs file); the result is "
        "`error` when the run ended in one error line and a non-zero exit.",
        "",
        "| # | input | command | result | message |",
        "|---|---|---|---|---|",
    ]
    for n, r in enumerate(cat, 1):
        body.append(f"| {n} | {_md(r['input'])} | {r['command']} | {r['result']} | {_md(r['message'])[:400]} |")
    out.mkdir(parents=True, exist_ok=True)
    path = update_section(out / "reliability.md", SECTION, "\n".join(body), title="Reliability: bad input, "
                          "corrupted files, interruptions")
    command = "python -m benchmarks.reliability --out docs" + (" --quick" if quick else "") + " (make reliability)"
    return _doc.put_stamp(path, _doc.stamp(SECTION, command, TECHNIQUES, SOURCES), SECTION)


def run(out: Path, quick: bool = False, fuzz_seconds: float | None = None, seed: int = 0) -> Path:
    # per technique: a quick run (CI's bench-check) fuzzes each for 5 s, as long as it fuzzed one technique before
    secs = fuzz_seconds if fuzz_seconds is not None else (5.0 if quick else 120.0)
    with tempfile.TemporaryDirectory() as td:
        w = Path(td)
        fx = make_fixture(w / "fx")
        cat = catalogue(fx, w)
        cost = checksum_cost(w, (64, 64, 48) if quick else (256, 256, 160), 3 if quick else 7)
    fz = ([("in process", fuzz_figures(secs, seed, t)) for t in FUZZ_SCENES]
          + [("child process", f) for f in fuzz_boundscheck(secs, seed)])
    return write_report(Path(out), cat, fz, cost, quick)


def main(argv=None) -> int:
    import json
    import sys

    ap = argparse.ArgumentParser(prog="python -m benchmarks.reliability", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="docs", type=Path)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--fuzz-seconds", type=float, default=None)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--fuzz-json", type=float, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--chunk-hash-cost", metavar="NI,NJ,NK", default=None,
                    help="only measure what the chunk hashes cost, on a head of this size (its own section)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--note", default="", help="a sentence added to the section's setup line")
    ap.add_argument("--per-class", type=int, default=40, help="mutants per class for --chunk-hash-cost")
    a = ap.parse_args(argv)
    os.environ.setdefault("ISPLAT_PROGRESS", "0")
    if a.chunk_hash_cost is not None:
        shape = tuple(int(x) for x in a.chunk_hash_cost.split(","))
        with tempfile.TemporaryDirectory() as td:
            c = chunk_hash_cost(Path(td), shape, a.repeats)
            if a.per_class > 0:
                c.update(classes=class_fuzz_figures(Path(td), a.per_class, a.seed), per_class=a.per_class,
                         seed=a.seed)
        print(json.dumps(c), file=sys.stderr)
        print(write_hash_cost(a.out, c, a.note), file=sys.stderr)
        return 0
    if a.fuzz_json is not None:
        print(json.dumps([fuzz_figures(a.fuzz_json, a.seed, t) for t in FUZZ_SCENES]))
        return 0
    print(run(a.out, a.quick, a.fuzz_seconds, a.seed), file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
