"""Write the example files of formats/augmented.md into formats/examples/augmented/.

    .venv/bin/python formats/examples/make_augmented_examples.py [OUT_DIR]

valid.aug.h5 is a 4 x 3 x 2 (n_i x n_j x n_k) ramp augmented by isplat; valid.expected.json lists every
value a reader must decode from it. The invalid files MUST be refused by readers.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import h5py
import numpy as np

from isplat import normals
from isplat.augfile import write_augmented
from isplat.augment import augment_array
from isplat.fileio import set_string_attr

HERE = Path(__file__).resolve().parent / "augmented"
SHAPE_IJK = (4, 3, 2)
SPACING_IJK = (1.0, 2.0, 0.5)
WINDOW = (0.0, 100.0)
# i to the patient's right, j anterior, k superior (NIfTI's identity affine), in LPS: a flipped, non-identity example
AXES_LPS = ((-1.0, 0.0, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, 1.0))


def example_volume() -> np.ndarray:
    """x[k, j, i] = 30 i j + 40 k [j == 2], float32: varied gradients, and a flat corner (NO_NORMAL at i=j=0)."""
    ni, nj, nk = SHAPE_IJK
    k, j, i = np.meshgrid(np.arange(nk), np.arange(nj), np.arange(ni), indexing="ij")
    return (30.0 * i * j + 40.0 * k * (j == 2)).astype(np.float32)


def example_labels() -> np.ndarray:
    """labels[k, j, i] = 1 + (i >= 2) in slice k = 1, 0 in slice k = 0 (uint8: ids 0, 1, 2)."""
    ni, nj, nk = SHAPE_IJK
    k, j, i = np.meshgrid(np.arange(nk), np.arange(nj), np.arange(ni), indexing="ij")
    return ((k == 1) * (1 + (i >= 2))).astype(np.uint8)


def _rehash(f) -> None:
    """Recompute the chunk hashes of open file ``f`` (an edit made as a writer would)."""
    from isplat.augfile import finish_augmented

    del f["chunk_hashes"]
    del f.attrs["chunk_hash_check"]
    if "brick_hashes" in f:
        del f["brick_hashes"]
    finish_augmented(f)


def build(out_dir: Path) -> list[Path]:
    """Write the valid and invalid examples and the expected values into ``out_dir``; return the paths."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    aug = augment_array(example_volume(), SPACING_IJK, WINDOW)
    extra = {"source": "formats/examples/make_augmented_examples.py", "source_format": "npy",
             "source_dtype": "float32", "density_window_method": "given",
             "axes_lps": np.asarray(AXES_LPS, dtype="<f8")}
    args = (aug["density"], aug["gradient_magnitude"], aug["normal"], aug["spacing_ijk"],
            aug["density_window"], aug["gradient_magnitude_scale"])
    valid = out_dir / "valid.aug.h5"
    write_augmented(valid, *args, extra_attrs=extra, labels=example_labels(), edge=8)
    # the tool version would make the file change with every release; pin it for the committed example
    with h5py.File(valid, "a") as f:
        set_string_attr(f, "created_by", "isplat 0.1.0")

    wrong_version = out_dir / "invalid-wrong-version.aug.h5"
    write_augmented(wrong_version, *args, extra_attrs=extra)
    with h5py.File(wrong_version, "a") as f:
        f.attrs["format_version"] = np.int64(7)
        set_string_attr(f, "created_by", "isplat 0.1.0")

    from isplat.augfile import open_augmented
    from isplat.index.labels import build_label_index_file

    label_index = out_dir / "valid.labels.idx.h5"    # the index of valid.aug.h5's labels (formats/index.md §10)
    build_label_index_file(open_augmented(valid), label_index, "ijk", force=True)
    with h5py.File(label_index, "a") as f:
        set_string_attr(f, "created_by", "isplat 0.1.0")

    v4 = out_dir / "valid-v4.aug.h5"                 # version 4 (labels, chunks of whole rows): still read
    write_augmented(v4, *args, extra_attrs=extra, labels=example_labels(), version=4)
    with h5py.File(v4, "a") as f:
        set_string_attr(f, "created_by", "isplat 0.1.0")

    v5 = out_dir / "valid-v5.aug.h5"                 # version 5 (labels, 8^3 bricks as HDF5 chunks): still read
    write_augmented(v5, *args, extra_attrs=extra, labels=example_labels(), version=5)
    with h5py.File(v5, "a") as f:
        set_string_attr(f, "created_by", "isplat 0.1.0")

    v3 = out_dir / "valid-v3.aug.h5"                 # version 3 (no labels): still read
    write_augmented(v3, *args, extra_attrs=extra, version=3)
    with h5py.File(v3, "a") as f:
        set_string_attr(f, "created_by", "isplat 0.1.0")

    bad_range = out_dir / "invalid-brick-range.aug.h5"   # a brick's range edited, hashes recomputed
    write_augmented(bad_range, *args, extra_attrs=extra)
    with h5py.File(bad_range, "a") as f:
        set_string_attr(f, "created_by", "isplat 0.1.0")
        f["brick_range"][0, 0, 0, 1] = int(f["brick_range"][0, 0, 0, 1]) - 1
        _rehash(f)

    bad_label = out_dir / "invalid-label-id.aug.h5"   # a label id beyond label_voxels, hashes recomputed
    write_augmented(bad_label, *args, extra_attrs=extra, labels=example_labels())
    with h5py.File(bad_label, "a") as f:
        set_string_attr(f, "created_by", "isplat 0.1.0")
        f["labels"][0, 1, 2, 3] = 7                  # brick 0, voxel (k, j, i) = (1, 2, 3)
        _rehash(f)

    wrong_name = out_dir / "invalid-wrong-format.aug.h5"
    write_augmented(wrong_name, *args, extra_attrs=extra)
    with h5py.File(wrong_name, "a") as f:
        set_string_attr(f, "format", "isplat-index")
        set_string_attr(f, "created_by", "isplat 0.1.0")

    missing = out_dir / "invalid-missing-normal.aug.h5"
    write_augmented(missing, *args, extra_attrs=extra)
    with h5py.File(missing, "a") as f:
        del f["normal"]
        set_string_attr(f, "created_by", "isplat 0.1.0")

    old = out_dir / "invalid-version-1.aug.h5"       # the layout of version 1: contiguous, no checksums
    with h5py.File(old, "w") as f:
        for k, v in h5py.File(valid, "r").attrs.items():
            f.attrs[k] = v
        f.attrs["format_version"] = np.int64(1)
        for name in ("density", "gradient_magnitude", "normal"):
            f.create_dataset(name, data=aug[name])

    flipped = out_dir / "invalid-flipped-bit.aug.h5"  # one bit of the normal channel flipped on disk
    write_augmented(flipped, *args, extra_attrs=extra)
    with h5py.File(flipped, "a") as f:
        set_string_attr(f, "created_by", "isplat 0.1.0")
        at = f["normal"].id.get_offset()
    data = bytearray(flipped.read_bytes())
    data[at + 3] ^= 0x04
    flipped.write_bytes(bytes(data))

    old2 = out_dir / "invalid-version-2.aug.h5"      # version 2: chunks with Fletcher-32, no chunk hashes
    write_augmented(old2, *args, extra_attrs=extra, version=4)
    with h5py.File(old2, "a") as f:
        del f["chunk_hashes"]
        del f.attrs["chunk_hash_check"]
        f.attrs["format_version"] = np.int64(2)
        set_string_attr(f, "created_by", "isplat 0.1.0")

    edited = out_dir / "invalid-edited-value.aug.h5"  # one density changed through HDF5: Fletcher-32 recomputed
    write_augmented(edited, *args, extra_attrs=extra)
    with h5py.File(edited, "a") as f:
        set_string_attr(f, "created_by", "isplat 0.1.0")
        f["density"][0, 1, 2, 3] = 255 - int(f["density"][0, 1, 2, 3])

    short = out_dir / "invalid-brick-hashes.aug.h5"  # a hash table one row short (not covered by the file key)
    write_augmented(short, *args, extra_attrs=extra)
    with h5py.File(short, "a") as f:
        set_string_attr(f, "created_by", "isplat 0.1.0")
        del f["brick_hashes/density"]
        f["brick_hashes"].create_dataset("density", data=np.zeros(0, "<u8"))

    bad_axes = out_dir / "invalid-axes-lps.aug.h5"    # an orientation whose rows are not orthonormal
    write_augmented(bad_axes, *args, extra_attrs=dict(extra, axes_lps=np.diag([1.0, 1.0, 2.0]).astype("<f8")))
    with h5py.File(bad_axes, "a") as f:
        set_string_attr(f, "created_by", "isplat 0.1.0")

    nrm = aug["normal"]
    expected = {
        "file": "valid.aug.h5",
        "shape": [int(x) for x in aug["density"].shape],
        "spacing_ijk": list(aug["spacing_ijk"]),
        "density_window": list(aug["density_window"]),
        "gradient_magnitude_scale": aug["gradient_magnitude_scale"],
        "density_sha256": aug["density_sha256"],
        "axes_lps": [list(r) for r in AXES_LPS],
        "density": aug["density"].tolist(),
        "gradient_magnitude": aug["gradient_magnitude"].tolist(),
        "normal": nrm.tolist(),
        "normal_decoded": np.round(normals.decode(nrm).astype(np.float64), 6).tolist(),
        "labels": example_labels().tolist(),
        "label_voxels": np.bincount(example_labels().reshape(-1)).tolist(),
        "brick_range": [[[[int(aug["density"].min()), int(aug["density"].max())]]]],
        "brick_edge": 8,
        "read": ["valid-v5.aug.h5", "valid-v4.aug.h5", "valid-v3.aug.h5"],
        "refused": {
            "invalid-wrong-version.aug.h5": "format_version",
            "invalid-wrong-format.aug.h5": "format",
            "invalid-missing-normal.aug.h5": "normal",
            "invalid-version-1.aug.h5": "format_version",
            "invalid-flipped-bit.aug.h5": "brick 0 at (0, 0, 0)",
            "invalid-axes-lps.aug.h5": "axes_lps",
            "invalid-version-2.aug.h5": "format_version",
            "invalid-edited-value.aug.h5": "brick 0 at (0, 0, 0)",
            "invalid-brick-hashes.aug.h5": "brick_hashes/density",
            "invalid-label-id.aug.h5": "labels",
            "invalid-brick-range.aug.h5": "brick_range",
        },
    }
    exp = out_dir / "valid.expected.json"
    exp.write_text(json.dumps(expected, indent=1) + "\n")
    return [valid, label_index, v5, v4, v3, short, bad_range, wrong_version, wrong_name, missing, old, old2, edited, flipped, bad_axes,
            bad_label, exp]


if __name__ == "__main__":
    for p in build(Path(sys.argv[1]) if len(sys.argv) > 1 else HERE):
        print(p)
