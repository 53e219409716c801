"""Regenerate the .npy volumes and .idx.h5 files of this folder from the hand-written *.json examples.

    .venv/bin/python formats/examples/index/generate.py

The JSON files are the specification (their block bytes and the order of their channel values were derived by
hand from formats/index.md); this script only writes the binary companions, with the isplat writer under test:
NAME.idx.h5 (format version 7) and its values file NAME.values.idx.h5 (the channel values of the volume augmented
as ``augment_array(volume, spacing (1, 1, 1), window (0, 255))`` does, so density codes equal the volume's values).
Kept as isplat wrote them before: gaps.v6.idx.h5 and full.v6.idx.h5 with their values files gaps.v6.values.idx.h5
and full.v6.values.idx.h5 (format version 6, Fletcher-32 chunks), gaps.v4.idx.h5 and full.v4.idx.h5 (format
version 4, the channel values inside, in ``/values``), which readers still read, and gaps.v2.idx.h5 (format version 2: no channel values, no chunk
hashes), which readers refuse with the command that rebuilds it.
tests/test_index_conformance.py checks that the writer reproduces the JSON bytes and that the committed .idx.h5
files decode back.
"""

import json
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
SPACING = (1.0, 1.0, 1.0)
WINDOW = (0.0, 255.0)


def volume(example: dict) -> np.ndarray:
    """The uint8 [k, j, i] volume of an example (``values_kji`` or ``background`` + ``voxels_kjid``)."""
    if "values_kji" in example:
        return np.asarray(example["values_kji"], dtype=np.uint8)
    v = np.full(example["shape"], example["background"], dtype=np.uint8)
    for k, j, i, d in example["voxels_kjid"]:
        v[k, j, i] = d
    return v


def channel_values(vol: np.ndarray, ranges):
    """The example's ``/values``: its volume augmented with spacing 1 and window 0..255, in density order."""
    from isplat.augment import augment_array
    from isplat.index.build import order_values

    aug = augment_array(vol, SPACING, WINDOW)
    assert np.array_equal(aug["density"], vol)
    return order_values(aug["density"], aug["gradient_magnitude"], aug["normal"], ranges, aug["spacing_ijk"],
                        aug["gradient_magnitude_scale"]), aug


def main() -> int:
    from isplat.augfile import density_sha256
    from isplat.index import build_index, write_index

    for src in sorted(HERE.glob("*.json")):
        ex = json.loads(src.read_text())
        vol = volume(ex)
        ranges = [tuple(r) for r in ex["density_ranges"]]
        np.save(HERE / f"{ex['name']}.npy", vol)
        index = build_index(vol, "".join(ex["axes"]), ranges)
        values, _ = channel_values(vol, ranges)
        write_index(HERE / f"{ex['name']}.idx.h5", index, vol.shape, density_sha256(vol), ranges, force=True,
                    values=values)
        print(f"wrote {ex['name']}.npy, {ex['name']}.idx.h5, {ex['name']}.values.idx.h5", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
