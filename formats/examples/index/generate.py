"""Regenerate the .npy volumes and .idx.h5 files of this folder from the hand-written *.json examples.

    .venv/bin/python formats/examples/index/generate.py

The JSON files are the specification (their block bytes were derived by hand from formats/index.md);
this script only writes the binary companions, with the isplat writer under test. tests/test_index_conformance.py
checks that the writer reproduces the JSON bytes and that the committed .idx.h5 files decode back.
"""

import json
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def volume(example: dict) -> np.ndarray:
    """The uint8 [k, j, i] volume of an example (``values_kji`` or ``background`` + ``voxels_kjid``)."""
    if "values_kji" in example:
        return np.asarray(example["values_kji"], dtype=np.uint8)
    v = np.full(example["shape"], example["background"], dtype=np.uint8)
    for k, j, i, d in example["voxels_kjid"]:
        v[k, j, i] = d
    return v


def main() -> int:
    from isplat.augfile import density_sha256
    from isplat.index import build_index, write_index

    for src in sorted(HERE.glob("*.json")):
        ex = json.loads(src.read_text())
        vol = volume(ex)
        ranges = [tuple(r) for r in ex["density_ranges"]]
        np.save(HERE / f"{ex['name']}.npy", vol)
        index = build_index(vol, "".join(ex["axes"]), ranges)
        write_index(HERE / f"{ex['name']}.idx.h5", index, vol.shape, density_sha256(vol), ranges, force=True)
        print(f"wrote {ex['name']}.npy, {ex['name']}.idx.h5", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
