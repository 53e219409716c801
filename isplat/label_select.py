"""The selection of a scene that shows segmentation labels (docs/labels.md).

The post-classified technique samples the quads that touch a voxel of interest; with labels, a voxel is of
interest when its density lies in the transfer function's intervals *or* its label is shown. The label channel
is read whole (its ids are the neighbours' too: a sample's label comes from its quad's corners, and a label's
normals from its indicator smoothed over its neighbours, :func:`isplat.labels.label_normals`), each chunk
checked against the file's chunk hashes and every id against ``label_voxels``
(:meth:`isplat.augfile.AugmentedVolume.read`), so the numba kernels index the colour table only with ids it has.
With an index of the labels beside the scene's index (``NAME.labels.idx.h5``, :mod:`isplat.index.labels`) the
shown labels' voxels come from its blocks of those ids alone and the label channel is not read. The voxels of
interest are then listed in memory (:func:`isplat.index.memory.load_axis_in_memory` of the
interest mask), as the index lists those of a density interval.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from . import grid
from .errors import IsplatError


@dataclass(frozen=True, eq=False)
class LabelSelection:
    """The label channel (flat ``[k, j, i]``, uint16) and the colour table of the shown labels (float64[L + 1,
    4]: r, g, b, opacity; opacity 0 for ids not shown)."""

    ids: np.ndarray
    table: np.ndarray
    shape: tuple[int, int, int]
    normals: np.ndarray             # uint16, flat: the labels' own normals (isplat.labels.label_normals), or empty

    def frame_steps(self, axis: str) -> np.ndarray:
        """The ``steps`` of :mod:`isplat.splat.labels` for slices along ``axis``: the flat steps of a, b, c and
        the number of slices."""
        steps = np.append(grid.flat_strides(self.shape, axis), grid.slice_shape(self.shape, axis)[0])
        return steps.astype(np.int64)


def label_table(shown, counts: np.ndarray, path) -> np.ndarray:
    """The colour table of ``shown`` (LabelStyle) for a file whose ``label_voxels`` are ``counts``: refuses a
    label no voxel has, naming where the scene gave it."""
    table = np.zeros((counts.shape[0], 4), dtype=np.float64)
    for st in shown:
        if st.id >= counts.shape[0] or counts[st.id] == 0:
            present = np.flatnonzero(counts[1:] > 0) + 1
            listed = ", ".join(str(int(i)) for i in present[:12]) + (", ..." if present.size > 12 else "")
            raise IsplatError(f"{st.where or 'scene'}: label {st.id}{f' ({st.name})' if st.name else ''} is not in "
                              f"{path} (ids present: {listed or 'none'})")
        table[st.id] = (*st.color, st.opacity)
    return table


def select_labels(request, aug):
    """The selection of ``request`` (which shows labels) from the open augmented file ``aug``."""
    from .index.memory import load_axis_in_memory
    from .selection import _empty_selection, _needed, _select, _whole

    if not aug.has_labels:
        where = request.labels[0].where or "scene"
        raise IsplatError(f"{where}: {aug.path} has no label channel; add one: isplat augment SCAN -o "
                          f"{aug.path} --labels MASK --force")
    if not request.post:
        raise IsplatError("labels are shown by the post-classified technique only: set render.classification = "
                          "\"post\" (render.sheets = \"axis\")")
    if request.slab is not None:
        raise IsplatError("labels: a frame is rendered in one piece (no --slabs, no --scheduler)")
    table = label_table(request.labels, aug.label_voxels, aug.path)
    sel = _empty_selection(request)
    sel = replace(sel, method="indexed", whole=_whole(sel, aug.read))
    ids, from_index = _label_ids(request, aug, sel.report)
    interest = _interest(sel, ids, table, request.shape)
    loaded = {ax: load_axis_in_memory(interest, ax, [(1, 1)]) for ax in request.axes}
    _select(sel, loaded, None, str(aug.path), [(1, 1)])
    nrm = np.zeros(0, np.uint16)
    if sel.use_shade:
        from .labels import label_normals

        nrm = label_normals(ids.reshape(request.shape), [st.id for st in request.labels],
                            request.spacing_ijk).reshape(-1)
    sel = replace(sel, labels=LabelSelection(ids, table, request.shape, nrm))
    rep = sel.report
    rep.axes = sorted(request.axes)
    rep.values_from = "whole channels"
    rep.channels = rep.channels + ([] if from_index else ["labels"])
    rep.voxels_of_interest = int(next(iter(loaded.values())).n_voxels) if loaded else 0
    rep.augmented_bytes = int(aug.bytes_read)
    rep.augmented_file_bytes = int(aug.io.bytes)
    rep.augmented_file_pages = aug.io.page_bytes()
    _needed(sel)
    return sel


def _label_ids(request, aug, rep) -> tuple[np.ndarray, bool]:
    """The label ids the frames need, flat: from the index of the labels beside the request's index (the blocks of
    the shown ids alone; every other voxel 0, which the kernels treat as an id not shown), else the label channel
    whole. Returns them and whether they came from the index."""
    from .index.labels import label_index_path, open_label_index, shown_ids_volume

    path = label_index_path(request.index) if request.index is not None else None
    if path is None or not path.exists():
        return aug.read("labels").reshape(-1), False
    idx = open_label_index(path, aug)
    with idx.session():
        ids, _ = shown_ids_volume(idx, sorted(request.axes)[0], [st.id for st in request.labels], request.shape)
    rep.index_bytes = int(idx.bytes_read)
    rep.index_file_bytes = int(idx.io.bytes)
    rep.index_file_pages = idx.io.page_bytes()
    rep.index_block_bytes = int(idx.bytes_read)
    rep.index_format_version = idx.version
    return ids, True


def _interest(sel, ids: np.ndarray, table: np.ndarray, shape) -> np.ndarray:
    """uint8 ``[k, j, i]``: 1 where the density is in the intervals or the label is shown."""
    mask = table[:, 3] > 0
    out = mask[ids]
    if sel.whole.density.size:
        wanted = np.zeros(256, dtype=bool)
        for lo, hi in sel.luts.intervals:
            wanted[int(lo):int(hi) + 1] = True
        out |= wanted[sel.whole.density]
    return out.astype(np.uint8).reshape(shape)
