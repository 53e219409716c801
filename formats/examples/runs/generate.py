"""Write the .runs.idx.h5 files of this folder from the hand-written *.json examples.

    .venv/bin/python formats/examples/runs/generate.py

The JSON files are the specification (their tables and position bytes were derived by hand from formats/runs.md);
this script only writes the binary companions with the isplat writer under test: NAME.runs.idx.h5 (format
version 2; ``density_sha256`` that of the example's density as isplat.augfile computes it, no augmented file, so
``augmented_chunk_hash_check`` is empty), and invalid-flipped-byte.runs.idx.h5 (tiny's file with one byte of
``runs/density`` changed), which readers refuse. tests/test_runs.py checks that the writer reproduces the JSON
tables and bytes and that the committed files read back. An example whose JSON says ``"format_version": 1``
(v1-bitmap) is of the version before (formats/runs.md §7): its file was written by that version's writer and is
kept, not written here; readers still read it.
"""

import json
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def channels(example: dict):
    """(density, normal, gradient magnitude) [k, j, i] of an example."""
    shape = tuple(example["shape"])
    if "density_kji" in example:
        return (np.asarray(example["density_kji"], np.uint8), np.asarray(example["normal_kji"], np.uint16),
                np.asarray(example["gradient_magnitude_kji"], np.uint8))
    flat = np.arange(int(np.prod(shape))).reshape(shape)
    return (np.full(shape, example["density_fill"], np.uint8), (flat * 7 + 1).astype(np.uint16),
            (flat % 251).astype(np.uint8))


def cut(example: dict):
    from isplat.runs import Cut

    return Cut(np.asarray(example["lo_first"], np.int64), np.asarray(example["hi_first"], np.int64), "example")


def write(example: dict, path: Path) -> None:
    from isplat.augfile import density_sha256
    from isplat.fileio import create_hdf5
    from isplat.runs import build_runs
    from isplat.runsfile import write_runs_arrays

    d, n, g = channels(example)
    c, runs = build_runs(d, n, g, cut(example))
    with create_hdf5(path) as f:
        write_runs_arrays(f, d.shape, density_sha256(d), "", c, runs)


def flip(path: Path, dataset: str) -> None:
    import h5py

    with h5py.File(path, "r") as f:
        off = f[dataset].id.get_chunk_info(0).byte_offset
    data = bytearray(path.read_bytes())
    data[off] ^= 0x01
    path.write_bytes(bytes(data))


def main() -> int:
    sys.path.insert(0, str(HERE.parents[2]))
    for name in ("tiny", "masks"):
        write(json.loads((HERE / f"{name}.json").read_text()), HERE / f"{name}.runs.idx.h5")
    bad = HERE / "invalid-flipped-byte.runs.idx.h5"
    bad.write_bytes((HERE / "tiny.runs.idx.h5").read_bytes())
    flip(bad, "runs/density")
    return 0


if __name__ == "__main__":
    sys.exit(main())
