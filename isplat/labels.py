"""Segmentation labels: an integer id per voxel (0 = none), stored beside the density (formats/augmented.md §2.1),
shown in colour by a scene's ``[labels]`` table (docs/labels.md).

This module reads a label map for ``isplat augment --labels`` (any reader isplat supports), checks it lies on
the scan's grid, and reads a names map (CSV or JSON: id -> name, e.g. TotalSegmentator's). The rendering side is
:mod:`isplat.splat.labels` (the sampling kernel) and :func:`label_table` (the scene's colours as a table).
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from .errors import IsplatError

MAX_LABEL = 65535
SPACING_TOLERANCE = 1e-3        # relative: spacings that differ by less are the same grid
AXES_TOLERANCE = 1e-3           # entries of the two axes_lps matrices


def read_label_volume(path, scan) -> np.ndarray:
    """The label map at ``path`` as an integer array ``[k, j, i]``, checked against ``scan`` (the
    :class:`isplat.volume_io.Volume` being augmented): the same shape; the same spacing and orientation where
    both files carry one; integer ids in 0..65535. Every problem is one line naming the file."""
    from .volume_io import read_volume

    lab = read_volume(path)
    name = str(path)
    arr = np.asarray(lab.array)
    check_same_grid(name, arr.shape, lab, scan)
    return label_ids(name, arr)


def check_same_grid(name: str, shape, lab, scan) -> None:
    """Refuse a label map whose grid differs from the scan's: shape, spacing (both from a file), orientation
    (both known)."""
    want = tuple(int(n) for n in scan.array.shape)
    if tuple(int(n) for n in shape) != want:
        raise IsplatError(f"{name}: labels have NI,NJ,NK={','.join(map(str, tuple(shape)[::-1]))}, the scan "
                          f"{','.join(map(str, want[::-1]))}; --labels needs a label map on the scan's grid")
    both = not _default_spacing(lab.meta) and not _default_spacing(scan.meta)
    a, b = np.asarray(lab.spacing_ijk, float), np.asarray(scan.spacing_ijk, float)
    if both and np.any(np.abs(a - b) > SPACING_TOLERANCE * np.maximum(np.abs(b), 1e-12)):
        raise IsplatError(f"{name}: labels have spacing {','.join(f'{s:g}' for s in a)}, the scan "
                          f"{','.join(f'{s:g}' for s in b)} (i, j, k); --labels needs a label map on the scan's grid")
    la, sa = lab.meta.get("axes_lps"), scan.meta.get("axes_lps")
    if la is not None and sa is not None and np.max(np.abs(np.asarray(la) - np.asarray(sa))) > AXES_TOLERANCE:
        from .orientation import code_of

        raise IsplatError(f"{name}: labels are oriented {code_of(np.asarray(la))}, the scan "
                          f"{code_of(np.asarray(sa))}; --labels needs a label map on the scan's grid")


def _default_spacing(meta) -> bool:
    return str(meta.get("spacing_source", "")).startswith("default")


def label_ids(name: str, arr) -> np.ndarray:
    """``arr`` as uint8 (ids up to 255) or uint16 ids, refusing values that are not integers in 0..65535."""
    a = np.asarray(arr)
    if a.dtype.kind == "b":
        a = a.astype(np.uint8)
    if a.dtype.kind not in "iuf":
        raise IsplatError(f"{name}: labels of type {a.dtype}, expected integer label ids")
    if a.size == 0:
        return a.astype(np.uint8)
    lo, hi = a.min(), a.max()
    if a.dtype.kind == "f" and not (np.isfinite(lo) and np.isfinite(hi) and np.all(a == np.rint(a))):
        raise IsplatError(f"{name}: labels hold non-integer values, expected integer label ids 0..{MAX_LABEL}")
    if lo < 0 or hi > MAX_LABEL:
        raise IsplatError(f"{name}: labels span {lo:g}..{hi:g}, expected ids 0..{MAX_LABEL}")
    return a.astype(np.uint8 if hi <= 255 else np.uint16)


def read_names(path) -> dict[str, int]:
    """A names map: JSON (``{"1": "spleen", ...}`` or ``{"spleen": 1, ...}``) or CSV (``id,name`` rows; a header
    row is skipped). Returns name -> id. One line naming the file for anything else."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise IsplatError(f"{path}: cannot read the label names ({exc.strerror})") from None
    except UnicodeDecodeError:
        raise IsplatError(f"{path}: label names are not UTF-8 text") from None
    pairs = _json_pairs(path, text) if p.suffix.lower() == ".json" else _csv_pairs(path, text)
    out = {}
    for ident, name in pairs:
        if not (isinstance(ident, int) and 0 < ident <= MAX_LABEL) or not name:
            raise IsplatError(f"{path}: label {name!r} = {ident!r}, expected a name and an id in 1..{MAX_LABEL}")
        out[str(name)] = ident
    return out


def _json_pairs(path, text):
    try:
        obj = json.loads(text)
    except json.JSONDecodeError as exc:
        raise IsplatError(f"{path}:{exc.lineno}: not JSON ({exc.msg})") from None
    if not isinstance(obj, dict):
        raise IsplatError(f"{path}: expected a JSON object of id -> name (or name -> id)")
    out = []
    for k, v in obj.items():
        if isinstance(v, str) and k.strip().isdigit():
            out.append((int(k), v))
        elif isinstance(v, int) and not isinstance(v, bool):
            out.append((v, k))
        else:
            raise IsplatError(f"{path}: entry {k!r}: {v!r}, expected \"ID\": \"name\" or \"name\": ID")
    return out


def _csv_pairs(path, text):
    out = []
    for n, row in enumerate(csv.reader(text.splitlines()), 1):
        if not row or not "".join(row).strip():
            continue
        if len(row) < 2:
            raise IsplatError(f"{path}:{n}: {','.join(row)!r}, expected ID,NAME")
        ident, name = row[0].strip(), row[1].strip()
        if not ident.isdigit():
            if n == 1:
                continue            # a header
            raise IsplatError(f"{path}:{n}: id {ident!r}, expected a whole number")
        out.append((int(ident), name))
    return out


SMOOTH_SIGMA = 1.0              # voxels: the Gaussian the indicator is smoothed with before its gradient
_RADIUS = 3


def label_normals(ids: np.ndarray, shown, spacing_ijk) -> np.ndarray:
    """uint16 ``[k, j, i]`` oct16 codes (formats/augmented.md §5): at each voxel of a shown label, the direction
    of the gradient of that label's indicator smoothed by a Gaussian of :data:`SMOOTH_SIGMA` voxels (central
    differences in physical units, along i, j, k); ``NO_NORMAL`` elsewhere. Each label is worked in its bounding
    box (with a margin), so small labels cost little."""
    from . import normals

    out = np.full(ids.shape, normals.NO_NORMAL, dtype=np.uint16)
    for lid in sorted({int(x) for x in shown}):
        mask = ids == lid
        box = _box(mask, _RADIUS + 1)
        if box is None:
            continue
        sub = _smooth(mask[box].astype(np.float32))
        gk, gj, gi = np.gradient(sub) if min(sub.shape) > 1 else _gradient_thin(sub)
        vec = np.stack([gi / spacing_ijk[0], gj / spacing_ijk[1], gk / spacing_ijk[2]], axis=-1)
        inside = mask[box]
        codes = out[box]
        codes[inside] = normals.encode(vec[inside])
        out[box] = codes
    return out


def _box(mask: np.ndarray, margin: int):
    """The slices of ``mask``'s bounding box grown by ``margin`` (None when empty)."""
    out = []
    for ax in range(3):
        other = tuple(x for x in range(3) if x != ax)
        hit = np.flatnonzero(mask.any(axis=other))
        if hit.size == 0:
            return None
        out.append(slice(max(0, hit[0] - margin), min(mask.shape[ax], hit[-1] + margin + 1)))
    return tuple(out)


def _smooth(a: np.ndarray) -> np.ndarray:
    """``a`` smoothed by a separable Gaussian of SMOOTH_SIGMA voxels (edges extended)."""
    x = np.arange(-_RADIUS, _RADIUS + 1, dtype=np.float64)
    w = np.exp(-0.5 * (x / SMOOTH_SIGMA) ** 2)
    w /= w.sum()
    for ax in range(3):
        pad = [(0, 0)] * 3
        pad[ax] = (_RADIUS, _RADIUS)
        p = np.pad(a, pad, mode="edge")
        acc = np.zeros_like(a)
        n = a.shape[ax]
        for t, wt in enumerate(w):
            acc += np.float32(wt) * np.take(p, np.arange(t, t + n), axis=ax)
        a = acc
    return a


def _gradient_thin(a: np.ndarray):
    """np.gradient of a volume with an axis of length 1 (zero along it)."""
    return tuple(np.gradient(a, axis=ax) if a.shape[ax] > 1 else np.zeros_like(a) for ax in range(3))
