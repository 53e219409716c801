"""The index of a label channel (formats/index.md §10): the density index's structure (Ihm & Lee's Figure 1),
built over the label ids instead of the densities, in a file of its own beside the density index
(``NAME.idx.h5`` -> ``NAME.labels.idx.h5``), so that a scene showing 3 of 100 labels reads the blocks of those 3
labels alone and never the label channel (:mod:`isplat.label_select`).

Ids 1..255 (uint8 labels) are indexed; a file whose labels exceed 255 gets no label index (scenes then read its
label channel whole), said in one line.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from ..errors import IsplatError
from ..fileio import atomic_output, check_output, create_hdf5, set_string_attr

log = logging.getLogger(__name__)

CHANNEL = "labels"
MAX_INDEXED_ID = 255


def label_index_path(index_path) -> Path:
    """``NAME.idx.h5`` -> ``NAME.labels.idx.h5`` (else INDEX + ``.labels.idx.h5``)."""
    s = str(index_path)
    return Path(s[: -len(".idx.h5")] + ".labels.idx.h5" if s.endswith(".idx.h5") else s + ".labels.idx.h5")


def build_label_index_file(aug, out_path, axes: str = "ijk", force: bool = False) -> Path | None:
    """Index the label channel of open augmented file ``aug`` into ``out_path`` (atomic): version 5, ``channel =
    "labels"``, the ids 1..L as the indexed "densities" (no ``/values``). None (and one log line) when the file's
    labels exceed 255."""
    from .build import build_index
    from .store import FORMAT_VERSION_LABELS, _write_axis, _write_root, finish_index

    largest = int(aug.label_voxels.shape[0]) - 1
    if largest > MAX_INDEXED_ID:
        log.info(f"isplat index: labels of {aug.path} go up to {largest}; ids above {MAX_INDEXED_ID} are not indexed, "
                 f"so scenes read its label channel whole")
        return None
    check_output(out_path, force)
    lab = aug.read("labels").astype(np.uint8)
    index = build_index(lab, axes, [(1, max(1, largest))])
    with atomic_output(out_path, force) as tmp:
        with create_hdf5(tmp) as f:
            _write_root(f, aug.shape, aug.density_sha256, [(1, max(1, largest))])
            f.attrs["format_version"] = np.int64(FORMAT_VERSION_LABELS)
            set_string_attr(f, "channel", CHANNEL)
            set_string_attr(f, "labels_sha256", str(aug.attrs["labels_sha256"]))
            for a in "ijk":
                if a in index:
                    _write_axis(f, index[a])
            finish_index(f)
    return Path(out_path)


def open_label_index(path, aug):
    """The label index at ``path``, checked to index ``aug``'s labels (shape, density_sha256 and labels_sha256)."""
    from .store import open_index

    idx = open_index(path)
    if idx.channel != CHANNEL:
        raise IsplatError(f"{path}: an index of the {idx.channel}, expected an index of the labels "
                          f"(channel = \"labels\")")
    if tuple(idx.shape) != tuple(aug.shape) or idx.density_sha256 != aug.density_sha256 or \
            idx.attrs.get("labels_sha256") != aug.attrs.get("labels_sha256"):
        raise IsplatError(f"{path}: index of other labels than {aug.path.name}'s (labels_sha256 differs); rebuild "
                          f"it: isplat index {aug.path} -o {str(path).replace('.labels.idx.h5', '.idx.h5')} --force")
    return idx


def shown_ids_volume(idx, axis: str, ids, shape) -> tuple[np.ndarray, int]:
    """uint16 ``[k, j, i]`` flat: each voxel of a label in ``ids`` (from ``idx``'s blocks of ``axis``), 0
    elsewhere; and the bytes read. Only the blocks of those ids are read."""
    from .. import grid
    from ..splat.select import flat_indices

    out = np.zeros(int(np.prod(shape)), dtype=np.uint16)
    ivs = [(int(i), int(i)) for i in sorted(set(int(x) for x in ids))]
    if not ivs:
        return out, 0
    la = idx.load_axis(axis, ivs)
    fi = flat_indices(la.slice_block_ptr, la.block_voxel_ptr, la.positions, la.n_a,
                      grid.flat_strides(shape, axis))
    out[fi] = np.repeat(la.block_density, np.diff(la.block_voxel_ptr))
    return out, int(la.bytes_read)
