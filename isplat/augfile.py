"""The augmented-volume container (formats/augmented.md), version 4 (version 3, without labels, read too).

Three datasets of one shape ``(n_k, n_j, n_i)``, C order, i fastest (the paper's ``ind = i + j * n_i``):

* ``density``             uint8  -- the windowed density (§2.1, one byte)
* ``gradient_magnitude``  uint8  -- |grad| quantised, ``code * gradient_magnitude_scale``
* ``normal``              uint16 -- octahedral 16-bit code of the gradient direction (:mod:`isplat.normals`)

and, OPTIONAL since version 4, ``labels`` (uint8 or uint16, a segmentation's label id per voxel, 0 = none) with
``label_voxels`` (int64[L + 1], the voxels of each id). Together the first three are the paper's 4-byte
augmented voxel, stored as three channels so that a scene reads
only the channels it uses (no normals when shading is off, no magnitudes when the transfer function
ignores them).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from . import chunkhash
from .errors import IsplatError
from .fileio import (ReadCounter, attr_array, attr_string, check_checked_dataset, check_string_attrs,
                     create_checked_dataset, create_hdf5, hdf5_errors, open_counted, open_hdf5, set_string_attr)
from .orientation import check_axes_lps

FORMAT_NAME = "isplat-augmented"
FORMAT_VERSION = 4              # version 4: + the optional label channel (formats/augmented.md §2.1)
OLDER_VERSIONS = (3,)           # version 3: + /chunk_hashes, a keyed hash per chunk (§1.1); read (it has no labels)
LABELS = "labels"
LABEL_VOXELS = "label_voxels"
LABEL_DTYPES = {"|u1": np.uint8, "<u2": np.uint16}
CHANNELS = {"density": np.uint8, "gradient_magnitude": np.uint8, "normal": np.uint16}
CHANNEL_DTYPES = {"density": "|u1", "gradient_magnitude": "|u1", "normal": "<u2"}
OPTIONAL_STRINGS = ("source", "source_format", "source_dtype", "density_window_method", "labels_sha256")
# the attributes the file key covers (formats/augmented.md §1.1): every attribute of §3 but created_by, in its order
HASHED_ATTRIBUTES = tuple(("", n) for n in (
    "format", "format_version", "shape", "spacing_ijk", "density_window", "gradient_magnitude_scale", "density_sha256",
    "source", "source_format", "source_dtype", "density_window_method", "density_units",
    "density_clipped_fraction", "axes_lps", "labels_sha256"))


def labels_sha256(labels: np.ndarray) -> str:
    """Identity of a label channel: SHA-256 of its shape (3 little-endian int64) then its ids as little-endian
    uint16 in C order (whatever the stored type), so an index of the labels can be tied to them."""
    h = hashlib.sha256(np.asarray(labels.shape, dtype="<i8").tobytes())
    a = np.asarray(labels)
    step = max(1, (1 << 25) // max(1, a[0].size))
    for k0 in range(0, a.shape[0], step):
        h.update(np.ascontiguousarray(a[k0:k0 + step], dtype="<u2").tobytes())
    return h.hexdigest()


def density_sha256(density: np.ndarray) -> str:
    """Identity of a density channel: SHA-256 of its shape (3 little-endian int64) then its bytes in C order."""
    h = hashlib.sha256(np.asarray(density.shape, dtype="<i8").tobytes())
    d = np.ascontiguousarray(density, dtype=np.uint8)
    # hash slab by slab so that a memory map is never copied whole
    step = max(1, (1 << 26) // max(1, d[0].size))
    for k0 in range(0, d.shape[0], step):
        h.update(np.ascontiguousarray(d[k0:k0 + step]).tobytes())
    return h.hexdigest()


@dataclass
class AugmentedVolume:
    """An open augmented file: metadata read eagerly, channels read on demand (and counted)."""

    path: Path
    shape: tuple[int, int, int]                  # (n_k, n_j, n_i)
    spacing_ijk: tuple[float, float, float]
    density_window: tuple[float, float]
    gradient_magnitude_scale: float
    density_sha256: str
    attrs: dict = field(default_factory=dict)
    bytes_read: int = 0                          # bytes of the channel slabs requested
    io: ReadCounter = field(default_factory=ReadCounter)   # what HDF5 read from the file (opening included)
    axes_lps: np.ndarray | None = None           # rows: LPS unit vectors of i, j, k; None = orientation unknown
    verifier: object = None                      # isplat.chunkhash.Verifier: checks each chunk read
    label_voxels: np.ndarray | None = None       # int64[L + 1]: voxels per label id; None: the file has no labels
    format_version: int = FORMAT_VERSION

    @property
    def has_labels(self) -> bool:
        return self.label_voxels is not None

    def labels_present(self) -> np.ndarray:
        """The label ids (> 0) that some voxel has, increasing (empty without labels)."""
        if self.label_voxels is None:
            return np.zeros(0, np.int64)
        return np.flatnonzero(self.label_voxels[1:] > 0) + 1

    @property
    def n_voxels(self) -> int:
        return int(np.prod(self.shape))

    def read(self, channel: str, k0: int = 0, k1: int | None = None) -> np.ndarray:
        """Read one channel (optionally the k-slab ``k0:k1``) into memory; adds to :attr:`bytes_read`."""
        return self.read_block(channel, (slice(k0, k1),))

    def read_block(self, channel: str, block=()) -> np.ndarray:
        """``channel[block]`` (a tuple of slices with step 1, e.g. ``(slice(None), slice(j0, j1))``) into memory,
        every chunk it touches checked against the file's chunk hashes; adds to :attr:`bytes_read`."""
        if channel == LABELS and self.has_labels:
            return self._read_labels(block)
        if channel not in CHANNELS:
            raise IsplatError(f"{self.path}: unknown channel {channel!r}; expected one of {sorted(CHANNELS)}")
        with hdf5_errors(self.path, f"dataset {channel!r}"):
            with open_counted(self.path, self.io) as f:
                arr = self.verifier.read(f, channel, tuple(block))
        arr = np.ascontiguousarray(arr, dtype=CHANNELS[channel])
        self.bytes_read += arr.nbytes
        return arr

    def _read_labels(self, block) -> np.ndarray:
        """``labels[block]`` as uint16 (whatever the stored type), each chunk checked, and every id checked to be
        one ``label_voxels`` counts (< its length): compiled code may index tables by them."""
        with hdf5_errors(self.path, f"dataset {LABELS!r}"):
            with open_counted(self.path, self.io) as f:
                arr = self.verifier.read(f, LABELS, tuple(block))
        self.bytes_read += arr.nbytes
        arr = np.ascontiguousarray(arr, dtype=np.uint16)
        if arr.size and int(arr.max()) >= self.label_voxels.shape[0]:
            raise IsplatError(f"{self.path}: dataset 'labels' holds id {int(arr.max())}, expected ids below "
                              f"{self.label_voxels.shape[0]} (the length of 'label_voxels')")
        return arr

    def verify_all(self) -> None:
        """Check every chunk of the channels against the file's chunk hashes (``isplat stats``)."""
        with hdf5_errors(self.path, "channels"), open_counted(self.path, self.io) as f:
            for ch in hashed_datasets(self.has_labels):
                self.verifier.verify_all(f, ch)


def hashed_datasets(labels: bool) -> list[str]:
    """The datasets the chunk hashes cover, in the file key's order (formats/augmented.md §1.1)."""
    return list(CHANNELS) + ([LABELS, LABEL_VOXELS] if labels else [])


def _rebuild_hint(p, f) -> str:
    src = attr_string(f.attrs, "source") if f is not None else None
    return f"isplat augment {src if src else 'SOURCE'} -o {p} --force"


def open_augmented(path) -> AugmentedVolume:
    """Open and validate an augmented file; raise :class:`IsplatError` naming any problem."""
    counter = ReadCounter()
    p, f = open_hdf5(path, "augmented volume", FORMAT_NAME, FORMAT_VERSION, rebuild=_rebuild_hint,
                     older=OLDER_VERSIONS, counter=counter)
    with f, hdf5_errors(p, "attributes and datasets"):
        a = f.attrs
        shape = tuple(int(x) for x in attr_array(p, a, "shape", "i", (3,)))
        spacing = tuple(float(x) for x in attr_array(p, a, "spacing_ijk", "f", (3,)))
        window = tuple(float(x) for x in attr_array(p, a, "density_window", "f", (2,)))
        gscale = float(attr_array(p, a, "gradient_magnitude_scale", "f"))
        check_string_attrs(p, a, ("density_sha256", "created_by"), OPTIONAL_STRINGS)
        if "density_clipped_fraction" in a:          # optional, but typed as formats/augmented.md says
            clipped = attr_array(p, a, "density_clipped_fraction", "f", (2,))
            if not (np.all(clipped >= 0) and np.all(clipped <= 1) and clipped.sum() <= 1 + 1e-9):
                raise IsplatError(f"{p}: attribute 'density_clipped_fraction' is {clipped.tolist()}, expected two "
                                  f"shares in 0..1")
        sha = attr_string(a, "density_sha256")
        if sha is None or len(sha) != 64 or any(c not in "0123456789abcdef" for c in sha):
            raise IsplatError(f"{p}: attribute 'density_sha256' is {a['density_sha256']!r}, expected 64 lower-case "
                              f"hex digits")
        if min(shape) < 1:
            raise IsplatError(f"{p}: attribute 'shape' is {shape}, expected three positive sizes")
        if min(spacing) <= 0:
            raise IsplatError(f"{p}: attribute 'spacing_ijk' is {spacing}, expected three positive numbers")
        if not window[0] < window[1]:
            raise IsplatError(f"{p}: attribute 'density_window' is {window}, expected LO < HI")
        if gscale < 0:
            raise IsplatError(f"{p}: attribute 'gradient_magnitude_scale' is {gscale}, expected a finite number >= 0")
        for name, dt in CHANNEL_DTYPES.items():
            if name not in f or not isinstance(f[name], h5py.Dataset):
                raise IsplatError(f"{p}: dataset {name!r} is missing")
            ds = f[name]
            if tuple(ds.shape) != shape:
                raise IsplatError(f"{p}: dataset {name!r} has shape {ds.shape}, attribute 'shape' says {shape}")
            if ds.dtype != np.dtype(dt):
                raise IsplatError(f"{p}: dataset {name!r} has dtype {ds.dtype}, expected {np.dtype(dt)}")
            check_checked_dataset(f"{p}: dataset {name!r}", ds)
        axes = check_axes_lps(p, attr_array(p, a, "axes_lps", "f", (3, 3))) if "axes_lps" in a else None
        attrs = {k: (attr_string(a, k) if attr_string(a, k) is not None else v) for k, v in a.items()}
        version = int(a["format_version"])
        has_labels = version >= 4 and (LABELS in f or LABEL_VOXELS in f)
        verifier = chunkhash.open_verifier(p, f, sha, hashed_datasets(has_labels),
                                           chunkhash.attributes_of(f, HASHED_ATTRIBUTES), _rebuild_hint(p, f))
        counts = _check_labels(p, f, shape, verifier) if has_labels else None
    return AugmentedVolume(p, shape, spacing, window, gscale, sha, attrs, io=counter, axes_lps=axes,
                           verifier=verifier, label_voxels=counts, format_version=version)


def _check_labels(p, f, shape, verifier) -> np.ndarray:
    """The label datasets' types and shapes (formats/augmented.md §2.1); returns ``label_voxels`` (read and
    checked against its chunk hashes): non-negative counts summing to the voxels, at most 256 entries for uint8
    labels and 65,536 for uint16."""
    for name in (LABELS, LABEL_VOXELS):
        if name not in f or not isinstance(f[name], h5py.Dataset):
            raise IsplatError(f"{p}: dataset {name!r} is missing (a file with labels has both 'labels' and "
                              f"'label_voxels')")
    ds = f[LABELS]
    if tuple(ds.shape) != shape:
        raise IsplatError(f"{p}: dataset 'labels' has shape {ds.shape}, attribute 'shape' says {shape}")
    if ds.dtype.str not in LABEL_DTYPES:
        raise IsplatError(f"{p}: dataset 'labels' has dtype {ds.dtype}, expected uint8 or uint16 (little-endian)")
    check_checked_dataset(f"{p}: dataset 'labels'", ds)
    cv = f[LABEL_VOXELS]
    most = 256 if ds.dtype.itemsize == 1 else 65536
    if cv.ndim != 1 or cv.dtype != np.dtype("<i8") or not 2 <= cv.shape[0] <= most:
        raise IsplatError(f"{p}: dataset 'label_voxels' is {cv.dtype} {tuple(cv.shape)}, expected int64 (L + 1,) "
                          f"with 1 <= L < {most} (the largest label id)")
    check_checked_dataset(f"{p}: dataset 'label_voxels'", cv)
    counts = np.asarray(verifier.read(f, LABEL_VOXELS), dtype=np.int64)
    sha = attr_string(f.attrs, "labels_sha256") if "labels_sha256" in f.attrs else None
    if sha is None or len(sha) != 64 or any(c not in "0123456789abcdef" for c in sha):
        raise IsplatError(f"{p}: attribute 'labels_sha256' is missing or not 64 lower-case hex digits (a file with "
                          f"labels has it)")
    if counts.min() < 0 or int(counts.sum()) != int(np.prod(shape)):
        raise IsplatError(f"{p}: dataset 'label_voxels' holds counts summing to {int(counts.sum())} (smallest "
                          f"{int(counts.min())}), expected non-negative counts of the {int(np.prod(shape))} voxels")
    return counts



def write_augmented(path, density, gradient_magnitude, normal, spacing_ijk, density_window,
                    gradient_magnitude_scale, extra_attrs: dict | None = None, labels=None) -> None:
    """Write a complete augmented file at ``path`` (the caller makes it atomic); ``labels``: an integer array
    of the same shape (ids 0..65535), stored as the label channel."""
    shape = tuple(int(x) for x in density.shape)
    with create_hdf5(path) as f:
        create_augmented(f, shape, spacing_ijk, density_window, gradient_magnitude_scale,
                         density_sha256(density), extra_attrs)
        f["density"][...] = density
        f["gradient_magnitude"][...] = gradient_magnitude
        f["normal"][...] = normal
        if labels is not None:
            write_labels(f, labels)
        finish_augmented(f)


def label_dtype(largest: int) -> str:
    """The stored type of labels whose largest id is ``largest``: uint8 up to 255, else uint16."""
    if not 0 <= largest <= 65535:
        raise IsplatError(f"label id {largest}: expected ids 0..65535")
    return "|u1" if largest <= 255 else "<u2"


def write_labels(f: h5py.File, labels, counts=None) -> None:
    """The label channel (formats/augmented.md §2.1) of open file ``f``: ``labels`` whole (an array), or, with
    ``counts`` (the voxels per id, int64), an iterable of ``(k0, k1, slab)``."""
    shape = tuple(int(x) for x in f.attrs["shape"])
    if counts is None:
        arr = np.asarray(labels)
        counts = label_counts(arr)
        labels = [(0, shape[0], arr)]
    ds = create_checked_dataset(f, LABELS, shape, label_dtype(len(counts) - 1))
    h = hashlib.sha256(np.asarray(shape, dtype="<i8").tobytes())
    for k0, k1, slab in labels:
        ds[k0:k1] = slab
        h.update(np.ascontiguousarray(slab, dtype="<u2").tobytes())
    create_checked_dataset(f, LABEL_VOXELS, (len(counts),), "<i8", np.asarray(counts, "<i8"))
    set_string_attr(f, "labels_sha256", h.hexdigest())


def label_counts(arr) -> np.ndarray:
    """Voxels per label id, 0 .. the largest (at least two entries: ids 0 and 1)."""
    a = np.asarray(arr)
    if a.size and (a.min() < 0 or a.max() > 65535):
        raise IsplatError(f"labels: ids {int(a.min())}..{int(a.max())}, expected 0..65535")
    c = np.bincount(a.reshape(-1).astype(np.int64), minlength=2)
    return c[:max(2, int(np.flatnonzero(c).max()) + 1 if c.any() else 2)]


def finish_augmented(f: h5py.File) -> None:
    """Write the chunk hashes of open file ``f`` once its channels are written (formats/augmented.md §1.1)."""
    chunkhash.write_tables(f, attr_string(f.attrs, "density_sha256"), hashed_datasets(LABELS in f),
                           chunkhash.attributes_of(f, HASHED_ATTRIBUTES))


def create_augmented(f: h5py.File, shape, spacing_ijk, density_window, gradient_magnitude_scale,
                     sha: str, extra_attrs: dict | None = None) -> None:
    """Create the attributes and empty channel datasets of an augmented file in open file ``f``."""
    from . import __version__

    set_string_attr(f, "format", FORMAT_NAME)
    f.attrs["format_version"] = np.int64(FORMAT_VERSION)
    f.attrs["shape"] = np.asarray(shape, dtype="<i8")
    f.attrs["spacing_ijk"] = np.asarray(spacing_ijk, dtype="<f8")
    f.attrs["density_window"] = np.asarray(density_window, dtype="<f8")
    f.attrs["gradient_magnitude_scale"] = np.float64(gradient_magnitude_scale)
    set_string_attr(f, "density_sha256", sha)
    set_string_attr(f, "created_by", f"isplat {__version__}")
    for k, v in (extra_attrs or {}).items():
        if isinstance(v, str):
            set_string_attr(f, k, v)
        else:
            f.attrs[k] = v
    for name, dt in CHANNEL_DTYPES.items():
        create_checked_dataset(f, name, shape, dt)
