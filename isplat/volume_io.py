"""Read a scalar volume from .npy, raw binary (file or stdin), NRRD, NIfTI, TIFF, a DICOM series, MetaImage
(.mha/.mhd), VTK image data (.vti), an InVesalius project (.inv3) or a Zarr / OME-Zarr store.

Every reader returns ``Volume(array[k, j, i], spacing_ijk, meta)``. Memory-mappable inputs (.npy, raw
files) are mapped, never copied, and Zarr stores are read lazily chunk by chunk (:class:`LazyZarr`), so a
volume larger than memory can be augmented slab by slab. ``meta["hounsfield"]`` is True when the file says
its values are Hounsfield units (a CT DICOM series with a rescale, a NIfTI with the CT rescale intercept).
The format libraries are optional extras; a missing one gives one error line naming the extra.
"""

from __future__ import annotations

import logging
import os
import re
import sys
import tempfile
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import IsplatError
from .fileio import check_regular

log = logging.getLogger(__name__)

RAW_DTYPES = ("uint8", "int8", "uint16", "int16", "uint32", "int32", "float32", "float64")
BYTE_ORDERS = {"little": "<", "big": ">"}
# rescale intercepts that mark CT stored values converted to Hounsfield units
HOUNSFIELD_INTERCEPTS = (-1024.0, -2048.0, -3024.0)
# numeric dtypes accepted from self-describing formats (bool and complex are not densities)
_ACCEPTED_KINDS = "uif"


@dataclass
class Volume:
    """A scalar volume indexed ``[k, j, i]`` (i fastest) with its voxel spacing in i, j, k order."""

    array: np.ndarray
    spacing_ijk: tuple[float, float, float]
    meta: dict = field(default_factory=dict)


def _need(module: str, package: str, extra: str, what: str, path):
    try:
        return __import__(module)
    except ImportError:
        raise IsplatError(f"{path}: reading {what} needs {package}: pip install 'isplat[{extra}]'") from None


def _check_spacing(path, spacing, source):
    try:
        s = tuple(float(x) for x in spacing)
    except (TypeError, ValueError):
        raise IsplatError(f"{path}: spacing {spacing!r} from {source} is not numeric") from None
    if len(s) != 3 or not all(np.isfinite(s)) or min(s) <= 0:
        raise IsplatError(f"{path}: spacing {s} from {source} invalid; expected three positive numbers"
                          " (override with --spacing SX,SY,SZ)")
    from .scene import spacing_problem            # the scene reader's and renderer's rule, so no file is unreadable

    problem = spacing_problem(s)
    if problem:
        raise IsplatError(f"{path}: spacing {','.join(f'{x:g}' for x in s)} from {source}: {problem}"
                          f"{' (override with --spacing SX,SY,SZ)' if source != '--spacing' else ''}")
    return s


def _check_array(path, arr, source):
    if arr.ndim != 3:
        raise IsplatError(f"{path}: {source} data has {arr.ndim} dimension(s) {arr.shape}; expected a 3-D volume")
    if arr.dtype.kind not in _ACCEPTED_KINDS:
        raise IsplatError(f"{path}: {source} data type {arr.dtype} is not supported; "
                          f"expected one of {', '.join(RAW_DTYPES)}")
    if min(arr.shape) < 1:
        raise IsplatError(f"{path}: {source} data has an empty axis {arr.shape}")
    return arr


def parse_numbers(text: str, what: str, n: int = 3, cast=float):
    """Parse ``'A,B,...'`` into an ``n``-tuple, or raise a one-line error naming ``what``."""
    parts = [p.strip() for p in str(text).split(",")]
    try:
        vals = tuple(cast(p) for p in parts)
    except ValueError:
        vals = ()
    if len(vals) != n:
        names = {2: "two", 3: "three"}.get(n, str(n))
        raise IsplatError(f"{what} {text!r} invalid; expected {names} comma-separated numbers")
    return vals


def parse_triple(text: str, what: str, cast=float):
    """Parse ``'A,B,C'`` into a 3-tuple, or raise a one-line error naming ``what``."""
    return parse_numbers(text, what, 3, cast)


def read_volume(path, shape=None, dtype=None, byte_order="little", header_bytes=0, spacing=None,
                level=None, series=None, stream: bool = False) -> Volume:
    """Read the volume at ``path`` (``'-'`` = raw data on stdin).

    Raw input needs ``shape=(n_i, n_j, n_k)`` and ``dtype``; a ``.raw``/``.bin`` file or ``-`` is raw, and
    so is any file when ``shape`` is given. ``spacing`` (i, j, k) overrides the file's spacing. ``level``
    picks an OME-Zarr multiscale level (0 = full resolution); ``series`` a DICOM SeriesInstanceUID.
    ``stream``: a raw or C-order .npy file is read with plain file reads as it is indexed (:class:`LazyFile`),
    not memory-mapped, so a volume larger than the process's address space can be read slab by slab.
    """
    vol = _read_any(path, shape, dtype, byte_order, header_bytes, level, series, stream)
    name = str(path)
    if level is not None and vol.meta.get("format") != "zarr":
        raise IsplatError(f"{name}: --level {level} applies to Zarr / OME-Zarr input only")
    if series is not None and vol.meta.get("format") != "dicom":
        raise IsplatError(f"{name}: --series applies to a DICOM folder only")
    _check_array(name, vol.array, vol.meta.get("format", "input"))
    if spacing is not None:
        vol.spacing_ijk = _check_spacing(name, spacing, "--spacing")
        vol.meta["spacing_source"] = "--spacing"
    else:
        vol.spacing_ijk = _check_spacing(name, vol.spacing_ijk, vol.meta.get("spacing_source", "the file"))
    return vol


def _read_any(path, shape, dtype, byte_order, header_bytes, level, series, stream=False) -> Volume:
    raw = shape is not None or dtype is not None or header_bytes
    name = str(path)
    p = Path(name)
    if name == "-":
        vol = _read_raw_stdin(shape, dtype, byte_order, header_bytes)
    else:
        if not p.exists():
            raise IsplatError(f"{p}: input does not exist")
        if not os.access(p, os.R_OK):
            raise IsplatError(f"{p}: input is not readable")
        check_regular(p, "input")               # a fifo or device would block or never end ('-' reads stdin)
        low = p.name.lower()
        if p.is_dir():
            if raw:
                raise IsplatError(f"{p}: raw options (--shape/--dtype/--header-bytes) need a file, got a folder")
            if _is_zarr(p):
                return _read_zarr(p, level)
            vol = _read_folder(p, series)
        elif raw or low.endswith((".raw", ".bin", ".dat")):
            vol = _read_raw_file(p, shape, dtype, byte_order, header_bytes, stream)
        elif low.endswith(".npy"):
            vol = _read_npy(p, stream)
        elif low.endswith((".nrrd", ".nhdr")):
            vol = _read_nrrd(p)
        elif low.endswith((".nii", ".nii.gz")):
            vol = _read_nifti(p)
        elif low.endswith((".tif", ".tiff")):
            vol = _read_tiff(p)
        elif low.endswith(".dcm"):
            vol = _read_dicom([p], p)
        elif low.endswith((".mha", ".mhd")):
            vol = _read_metaimage(p)
        elif low.endswith(".vti"):
            vol = _read_vti(p)
        elif low.endswith(".inv3"):
            vol = _read_inv3(p)
        else:
            raise IsplatError(f"{p}: unknown input format; expected .npy, .nrrd, .nhdr, .nii, .nii.gz, .tif, "
                              ".tiff, .mha, .mhd, .vti, .inv3, a TIFF or DICOM folder, a Zarr / OME-Zarr folder, "
                              "or raw data with --shape and --dtype")
    return vol


# --- raw -------------------------------------------------------------------------------------------------------

def _raw_dtype(path, shape, dtype, byte_order, header_bytes):
    if shape is None or dtype is None:
        raise IsplatError(f"{path}: raw input needs --shape NI,NJ,NK and --dtype")
    if dtype not in RAW_DTYPES:
        raise IsplatError(f"{path}: dtype {dtype!r} unknown; expected one of {', '.join(RAW_DTYPES)}")
    if byte_order not in BYTE_ORDERS:
        raise IsplatError(f"{path}: byte order {byte_order!r} unknown; expected little or big")
    shape = tuple(int(x) for x in shape)
    if len(shape) != 3 or min(shape) < 1:
        raise IsplatError(f"{path}: --shape {shape} invalid; expected three positive sizes NI,NJ,NK")
    if int(header_bytes) < 0:
        raise IsplatError(f"{path}: --header-bytes {header_bytes} invalid; expected >= 0")
    dt = np.dtype(dtype).newbyteorder(BYTE_ORDERS[byte_order])
    ni, nj, nk = shape
    return dt, (nk, nj, ni), ni * nj * nk * dt.itemsize


def _raw_meta(dt, shape, header_bytes, byte_order):
    return {"format": "raw", "source_dtype": dt.name, "byte_order": byte_order, "header_bytes": int(header_bytes),
            "spacing_source": "default 1,1,1"}


def _read_raw_file(p, shape, dtype, byte_order, header_bytes, stream=False):
    dt, kji, nbytes = _raw_dtype(p, shape, dtype, byte_order, header_bytes)
    size = p.stat().st_size
    if size != header_bytes + nbytes:
        raise IsplatError(f"{p}: file has {size} bytes; --shape {','.join(map(str, shape))} --dtype {dtype} "
                          f"with --header-bytes {header_bytes} needs {header_bytes + nbytes} bytes")
    if stream:
        arr = LazyFile(p, int(header_bytes), dt, kji)
    else:
        arr = np.memmap(p, dtype=dt, mode="r", offset=int(header_bytes), shape=kji)
    return Volume(arr, (1.0, 1.0, 1.0), _raw_meta(dt, shape, header_bytes, byte_order))


def _read_raw_stdin(shape, dtype, byte_order, header_bytes):
    dt, kji, nbytes = _raw_dtype("-", shape, dtype, byte_order, header_bytes)
    stream = getattr(sys.stdin, "buffer", sys.stdin)
    data = stream.read()
    if isinstance(data, str):
        data = data.encode("latin-1")
    if len(data) != header_bytes + nbytes:
        raise IsplatError(f"-: stdin had {len(data)} bytes; --shape {','.join(map(str, shape))} --dtype {dtype} "
                          f"with --header-bytes {header_bytes} needs {header_bytes + nbytes} bytes")
    arr = np.frombuffer(data, dtype=dt, offset=int(header_bytes)).reshape(kji)
    meta = _raw_meta(dt, shape, header_bytes, byte_order)
    meta["format"] = "raw (stdin)"
    return Volume(arr, (1.0, 1.0, 1.0), meta)


# --- npy -------------------------------------------------------------------------------------------------------

def _read_npy(p, stream=False):
    try:
        arr = _npy_stream(p) if stream else None
        arr = np.load(p, mmap_mode="r", allow_pickle=False) if arr is None else arr
    except (ValueError, OSError, EOFError) as exc:
        raise IsplatError(f"{p}: not a readable .npy file ({_short(exc)}; truncated?)") from None
    if not isinstance(arr, (np.ndarray, LazyFile)):
        raise IsplatError(f"{p}: .npy holds no array")
    return Volume(arr, (1.0, 1.0, 1.0), {"format": "npy", "source_dtype": arr.dtype.name,
                                         "spacing_source": "default 1,1,1 (.npy has no spacing)"})


def _npy_stream(p):
    """A :class:`LazyFile` over a C-order .npy file (None for Fortran order: memory-mapped then)."""
    with open(p, "rb") as fh:
        fmt = np.lib.format
        version = fmt.read_magic(fh)
        if version not in ((1, 0), (2, 0)):
            return None
        read_header = fmt.read_array_header_1_0 if version == (1, 0) else fmt.read_array_header_2_0
        shape, fortran, dtype = read_header(fh)
        offset = fh.tell()
    if fortran or dtype.hasobject or len(shape) != 3:
        return None
    need = offset + int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
    if p.stat().st_size < need:
        raise ValueError(f"file has {p.stat().st_size} bytes, the header needs {need}")
    return LazyFile(p, offset, dtype, tuple(int(n) for n in shape))


def _short(exc):
    msg = str(exc).strip().splitlines()
    return f"{exc.__class__.__name__}: {msg[0] if msg else ''}".rstrip(": ")


# --- NRRD ------------------------------------------------------------------------------------------------------

def _read_nrrd(p):
    nrrd = _need("nrrd", "pynrrd", "nrrd", ".nrrd", p)
    try:
        data, header = nrrd.read(str(p), index_order="C")
    except Exception as exc:  # pynrrd raises several types for malformed or truncated files
        raise IsplatError(f"{p}: not a readable NRRD file ({_short(exc)})") from None
    spacing, source = (1.0, 1.0, 1.0), "default 1,1,1 (no spacing in the NRRD header)"
    dirs = header.get("space directions")
    if dirs is not None:
        rows = [np.asarray(r, dtype=np.float64) for r in dirs
                if r is not None and np.all(np.isfinite(np.asarray(r, dtype=np.float64)))]
        if len(rows) == 3:
            spacing, source = tuple(float(np.linalg.norm(r)) for r in rows), "NRRD 'space directions'"
    elif header.get("spacings") is not None:
        sp = [float(x) for x in header["spacings"]]
        if len(sp) == 3 and all(np.isfinite(sp)):
            spacing, source = tuple(sp), "NRRD 'spacings'"
    meta = {"format": "nrrd", "source_dtype": data.dtype.name, "spacing_source": source}
    _set_axes(meta, p, lambda: _nrrd_axes(header))
    return Volume(data, spacing, meta)


def _nrrd_axes(header):
    """LPS axes from 'space directions' and a patient 'space' (RAS, LAS or LPS); None otherwise."""
    from .orientation import in_lps

    space, dirs = header.get("space"), header.get("space directions")
    if space is None or dirs is None or str(space).lower() not in (
            "left-posterior-superior", "right-anterior-superior", "left-anterior-superior"):
        return None
    rows = [np.asarray(r, dtype=np.float64) for r in dirs if r is not None]
    if len(rows) != 3 or not all(np.all(np.isfinite(r)) and r.shape == (3,) for r in rows):
        return None
    return in_lps(rows, space, "NRRD 'space directions'")


def _set_axes(meta, p, compute):
    """``meta["axes_lps"]`` from ``compute()`` (None: no orientation). A degenerate or unreadable matrix does not
    stop the read: one warning line, and the orientation is unknown."""
    try:
        axes = compute()
    except IsplatError as exc:
        axes = log.warning(f"isplat: warning: {p}: {exc}; the orientation is taken as unknown")
    except (TypeError, ValueError, IndexError) as exc:
        axes = log.warning(f"isplat: warning: {p}: orientation unreadable ({_short(exc)}); taken as unknown")
    if axes is not None:
        meta["axes_lps"] = axes


# --- NIfTI -----------------------------------------------------------------------------------------------------

def _read_nifti(p):
    nib = _need("nibabel", "nibabel", "nifti", ".nii/.nii.gz", p)
    try:
        img = nib.load(str(p))
        data = np.asanyarray(img.dataobj)
        zooms = img.header.get_zooms()
        inter = getattr(img.dataobj, "inter", None)
        # NIfTI method 1 (both codes 0) has no orientation; else nibabel's best affine (sform, then qform)
        coded = int(img.header.get("sform_code", 0)) > 0 or int(img.header.get("qform_code", 0)) > 0
        affine = np.asarray(img.affine, dtype=np.float64) if coded else None
    except Exception as exc:
        raise IsplatError(f"{p}: not a readable NIfTI file ({_short(exc)})") from None
    if data.ndim == 4 and data.shape[3] == 1:
        data = data[..., 0]
    if data.ndim != 3:
        raise IsplatError(f"{p}: NIfTI data has shape {data.shape}; expected a 3-D volume")
    # NIfTI stores [x, y, z] with x fastest on disk; isplat indexes [k, j, i] = [z, y, x]
    arr = data.transpose(2, 1, 0)
    meta = {"format": "nifti", "source_dtype": arr.dtype.name, "spacing_source": "NIfTI pixdim (zooms)",
            # dcm2niix and ITK store CT as stored values plus the scanner's rescale intercept
            "hounsfield": inter is not None and float(inter) in HOUNSFIELD_INTERCEPTS}
    # the affine's columns x, y, z (= i, j, k) are in RAS
    _set_axes(meta, p, lambda: None if affine is None else _in_lps(affine[:3, :3].T, "ras", "NIfTI affine"))
    return Volume(arr, tuple(float(z) for z in zooms[:3]), meta)


def _in_lps(rows, space, what):
    from .orientation import in_lps

    return in_lps(rows, space, what)


# --- TIFF ------------------------------------------------------------------------------------------------------

def _natural_key(path: Path):
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", path.name)]


def _read_tiff(p, files=None):
    tifffile = _need("tifffile", "tifffile", "tiff", "TIFF", p)
    try:
        if files is None:
            data = tifffile.imread(str(p))
        else:
            pages = []
            for f in files:
                img = tifffile.imread(str(f))
                if pages and img.shape != pages[0].shape:
                    raise IsplatError(f"{f}: image shape {img.shape} differs from {files[0].name} {pages[0].shape}")
                if img.ndim != 2:
                    raise IsplatError(f"{f}: TIFF image has shape {img.shape}; expected one 2-D slice per file")
                pages.append(img)
            data = np.stack(pages)
    except IsplatError:
        raise
    except Exception as exc:
        raise IsplatError(f"{p}: not a readable TIFF ({_short(exc)})") from None
    # pages are k slices, each page [row = j, column = i]; TIFF carries no reliable slice spacing
    return Volume(np.asarray(data), (1.0, 1.0, 1.0),
                  {"format": "tiff", "source_dtype": data.dtype.name, "spacing_source": "default 1,1,1 (TIFF)"})


# --- folders and DICOM ------------------------------------------------------------------------------------------

def _is_dicom(f: Path) -> bool:
    try:
        with open(f, "rb") as fh:
            fh.seek(128)
            return fh.read(4) == b"DICM"
    except OSError:
        return False


def _read_folder(p, series=None):
    files = sorted((f for f in p.iterdir() if f.is_file() and not f.name.startswith(".")), key=_natural_key)
    tifs = [f for f in files if f.suffix.lower() in (".tif", ".tiff")]
    if tifs:
        return _read_tiff(p, tifs)
    dcm = [f for f in files if _is_dicom(f)]
    if dcm:
        return _read_dicom(dcm, p, series)
    raise IsplatError(f"{p}: folder holds no .tif/.tiff files and no DICOM files (checked {len(files)} files)")


def _pick_series(slices, p, series):
    """The slices of one series: the only one, or ``series`` (a SeriesInstanceUID); else one line listing them."""
    groups: dict[str, list] = {}
    for f, ds in slices:
        groups.setdefault(str(ds.get("SeriesInstanceUID", "")), []).append((f, ds))
    if series is not None:
        if series not in groups:
            raise IsplatError(f"{p}: no DICOM series with --series {series}; the folder holds {_series_list(groups)}")
        return groups[series]
    if len(groups) > 1:
        raise IsplatError(f"{p}: the folder holds {len(groups)} DICOM series; choose one with --series UID: "
                          f"{_series_list(groups)}")
    return slices


def _series_list(groups) -> str:
    def one(uid, members):
        desc = str(members[0][1].get("SeriesDescription", "") or "").strip()
        return f"{uid or '(no UID)'} ({len(members)} slices{', ' + desc if desc else ''})"
    return "; ".join(one(uid, m) for uid, m in sorted(groups.items()))


def _read_dicom(files, p, series=None):
    pydicom = _need("pydicom", "pydicom", "dicom", "DICOM", p)
    slices = []
    for f in files:
        try:
            ds = pydicom.dcmread(str(f))
            ds.PixelData  # noqa: B018 - fail early on a header-only file
        except Exception as exc:
            raise IsplatError(f"{f}: not a readable DICOM image ({_short(exc)})") from None
        slices.append((f, ds))
    slices = _pick_series(slices, p, series)
    f0, d0 = slices[0]
    for tag in ("Rows", "Columns", "PixelSpacing"):
        if tag not in d0:
            raise IsplatError(f"{f0}: DICOM tag {tag} is missing")
    iop = np.asarray(d0.get("ImageOrientationPatient", [1, 0, 0, 0, 1, 0]), dtype=np.float64)
    if iop.shape != (6,):
        raise IsplatError(f"{f0}: ImageOrientationPatient has {iop.size} values, expected 6")
    # slice normal = row direction x column direction; slices are ordered by their position along it
    normal = np.cross(iop[:3], iop[3:])
    order, step = _dicom_order(slices, p, iop, normal)
    slopes = [float(ds.get("RescaleSlope", 1) or 1) for _, ds in slices]
    inters = [float(ds.get("RescaleIntercept", 0) or 0) for _, ds in slices]
    rescale = any(s != 1 for s in slopes) or any(i != 0 for i in inters)
    try:
        first = slices[order[0]][1].pixel_array
    except Exception as exc:
        raise IsplatError(f"{slices[order[0]][0]}: cannot decode DICOM pixels ({_short(exc)})") from None
    out_dtype = np.float32 if rescale else first.dtype
    arr = np.empty((len(slices), int(d0.Rows), int(d0.Columns)), dtype=out_dtype)
    for k, idx in enumerate(order):
        f, ds = slices[idx]
        try:
            px = ds.pixel_array
        except Exception as exc:
            raise IsplatError(f"{f}: cannot decode DICOM pixels ({_short(exc)})") from None
        if px.shape != arr.shape[1:]:
            raise IsplatError(f"{f}: pixel array shape {px.shape}, expected {arr.shape[1:]}")
        arr[k] = px * np.float32(slopes[idx]) + np.float32(inters[idx]) if rescale else px
    # PixelSpacing = [spacing between rows (j), spacing between columns (i)]
    ps = [float(x) for x in d0.PixelSpacing]
    if len(ps) != 2:
        raise IsplatError(f"{f0}: PixelSpacing has {len(ps)} values, expected 2")
    hounsfield = str(d0.get("Modality", "")).upper() == "CT" and ("RescaleIntercept" in d0 or rescale)
    meta = {"format": "dicom", "source_dtype": str(first.dtype),
            "spacing_source": "DICOM PixelSpacing and slice positions", "hounsfield": hounsfield}
    # i along a row (IOP's first vector), j down a column, k the slice normal: positions are sorted along it
    if "ImageOrientationPatient" in d0:
        _set_axes(meta, f0, lambda: _in_lps([iop[:3], iop[3:], normal], "lps", "ImageOrientationPatient"))
    return Volume(arr, (ps[1], ps[0], step), meta)


def _dicom_order(slices, p, iop, normal):
    """The slices' order along their ``normal`` (from ImagePositionPatient) and the step between them; the
    series must be one uniform stack of images of one size and orientation."""
    f0, d0 = slices[0]
    pos = []
    for f, ds in slices:
        if (ds.Rows, ds.Columns) != (d0.Rows, d0.Columns):
            raise IsplatError(f"{f}: DICOM image is {ds.Rows}x{ds.Columns}, {f0.name} is {d0.Rows}x{d0.Columns}")
        if "ImagePositionPatient" not in ds:
            if len(slices) > 1:
                raise IsplatError(f"{f}: DICOM tag ImagePositionPatient is missing; cannot order the slices")
            pos.append(0.0)
            continue
        io = np.asarray(ds.get("ImageOrientationPatient", iop), dtype=np.float64)
        if not np.allclose(io, iop, atol=1e-4):
            raise IsplatError(f"{f}: ImageOrientationPatient {list(io)} differs from {f0.name} {list(iop)}")
        pos.append(float(np.dot(np.asarray(ds.ImagePositionPatient, dtype=np.float64), normal)))
    order = np.argsort(pos, kind="stable")
    pos = np.asarray(pos)[order]
    if len(pos) > 1:
        steps = np.diff(pos)
        if np.any(steps <= 1e-6):
            raise IsplatError(f"{p}: two DICOM slices share a position; expected one series")
        # mean step from the end slices; each slice must sit on that grid to within 2% of a step plus
        # 0.1 mm, which allows the 0.1 mm rounding many scanners write into ImagePositionPatient
        step = float((pos[-1] - pos[0]) / (len(pos) - 1))
        resid = pos - (pos[0] + step * np.arange(len(pos)))
        if np.max(np.abs(resid)) > 0.02 * step + 0.1:
            raise IsplatError(f"{p}: DICOM slice positions are not evenly spaced (steps {steps.min():g} "
                              f"to {steps.max():g}); expected one uniform series")
    else:
        step = float(d0.get("SliceThickness", 1.0) or 1.0)
    return order, step


# --- MetaImage (.mha/.mhd) through SimpleITK ---------------------------------------------------------------------

@contextmanager
def _c_stderr_captured():
    """Capture what C/C++ code writes to file descriptor 2 (ITK's MetaIO prints its parse errors there);
    yields a list that holds the captured lines afterwards."""
    lines: list[str] = []
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield lines
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            lines.extend(x for x in tmp.read().decode("utf-8", "replace").splitlines() if x.strip())


def _read_metaimage(p):
    sitk = _need("SimpleITK", "SimpleITK", "metaimage", ".mha/.mhd", p)
    try:
        with _c_stderr_captured() as said:
            img = sitk.ReadImage(str(p))
    except Exception as exc:  # SimpleITK raises RuntimeError naming only its own source line; MetaIO said why
        why = said[0].strip() if said else _short(exc)
        raise IsplatError(f"{p}: not a readable MetaImage file ({why})") from None
    if img.GetNumberOfComponentsPerPixel() != 1 or img.GetDimension() != 3:
        raise IsplatError(f"{p}: MetaImage has {img.GetDimension()} dimensions and "
                          f"{img.GetNumberOfComponentsPerPixel()} components per voxel; expected a 3-D scalar volume")
    arr = sitk.GetArrayFromImage(img)  # [z, y, x] = [k, j, i]
    meta = {"format": "metaimage", "source_dtype": arr.dtype.name, "spacing_source": "MetaImage ElementSpacing"}
    # ITK's direction: row-major, its columns the x, y, z (= i, j, k) axes in LPS
    direction = np.asarray(img.GetDirection(), dtype=np.float64).reshape(3, 3)
    _set_axes(meta, p, lambda: _in_lps(direction.T, "lps", "MetaImage TransformMatrix"))
    return Volume(arr, tuple(float(s) for s in img.GetSpacing()), meta)


# --- VTK image data (.vti) through VTK's own XML reader --------------------------------------------------------

def _read_vti(p):
    _need("vtkmodules", "vtk", "vtk", ".vti", p)
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkIOXML import vtkXMLImageDataReader

    reader = vtkXMLImageDataReader()
    if not reader.CanReadFile(str(p)):
        raise IsplatError(f"{p}: not a readable VTK image data (.vti) file")
    reader.SetFileName(str(p))
    with _c_stderr_captured() as said:   # VTK logs its errors on file descriptor 2
        reader.Update()
    errors = [re.sub(r"\x1b\[[0-9;]*m", "", x) for x in said if "ERR|" in x]
    if errors:
        why = errors[0].split("ERR|", 1)[1].split("): ", 1)[-1].strip()
        raise IsplatError(f"{p}: not a readable VTK image data (.vti) file ({why})")
    img = reader.GetOutput()
    scalars = img.GetPointData().GetScalars() if img is not None else None
    if scalars is None:
        arrays = img.GetPointData() if img is not None else None
        if arrays is None or arrays.GetNumberOfArrays() != 1:
            raise IsplatError(f"{p}: .vti holds no point scalars (and not exactly one point data array)")
        scalars = arrays.GetArray(0)
    if scalars.GetNumberOfComponents() != 1:
        raise IsplatError(f"{p}: .vti array {scalars.GetName()!r} has {scalars.GetNumberOfComponents()} "
                          "components; expected a scalar volume")
    ni, nj, nk = img.GetDimensions()
    arr = vtk_to_numpy(scalars).reshape(nk, nj, ni)  # VTK point order: x fastest
    return Volume(arr, tuple(float(s) for s in img.GetSpacing()),
                  {"format": "vti", "source_dtype": arr.dtype.name, "spacing_source": "VTK ImageData Spacing"})


# --- InVesalius project (.inv3): a tar (gzip or plain) of main.plist and the raw array it names -----------------

def _read_inv3(p):
    """The image of an InVesalius 3 project: main.plist's ``matrix`` (``filename``, ``shape`` [z, y, x] =
    [k, j, i], ``dtype``; native little-endian) and ``spacing`` (x, y, z = i, j, k). Masks and surfaces are
    ignored; the orientation is not recorded (InVesalius keeps its own reoriented matrix)."""
    import plistlib
    import tarfile

    try:
        with tarfile.open(p, "r:*") as tar:
            members = {m.name.rsplit("/", 1)[-1]: m for m in tar.getmembers() if m.isfile()}
            if "main.plist" not in members:
                raise IsplatError(f"{p}: InVesalius project without main.plist")
            plist = plistlib.loads(tar.extractfile(members["main.plist"]).read())
            name, dt, kji = _inv3_matrix(p, plist)
            m = members.get(name)
            need = int(np.prod(kji)) * dt.itemsize
            if m is None or m.size != need:
                raise IsplatError(f"{p}: InVesalius matrix {name!r} " + ("is missing" if m is None else
                                  f"has {m.size} bytes; shape {list(kji)} of {dt.name} needs {need}"))
            arr = np.frombuffer(tar.extractfile(m).read(), dtype=dt).reshape(kji)
    except IsplatError:
        raise
    except Exception as exc:  # tarfile, gzip, zlib and plistlib raise many types for damaged files
        raise IsplatError(f"{p}: not a readable InVesalius project ({_short(exc)})") from None
    sp = plist.get("spacing")
    return Volume(arr, sp if sp is not None else (1.0, 1.0, 1.0),
                  {"format": "inv3", "source_dtype": dt.name, "spacing_source": "InVesalius project spacing"
                   if sp is not None else "default 1,1,1 (no spacing in the InVesalius project)"})


def _inv3_matrix(p, plist):
    mat = plist.get("matrix") if isinstance(plist, dict) else None
    try:
        name, shape, dtype = str(mat["filename"]), tuple(int(n) for n in mat["shape"]), str(mat["dtype"])
    except (TypeError, KeyError, ValueError):
        raise IsplatError(f"{p}: main.plist has no valid 'matrix' (filename, shape, dtype)") from None
    if dtype not in RAW_DTYPES or len(shape) != 3 or min(shape) < 1:
        raise IsplatError(f"{p}: InVesalius matrix of shape {list(shape)} and dtype {dtype!r}; expected a 3-D "
                          f"volume of {', '.join(RAW_DTYPES)}")
    return name.rsplit("/", 1)[-1], np.dtype(dtype).newbyteorder("<"), shape


# --- Zarr and OME-Zarr, read lazily --------------------------------------------------------------------------------

def _is_zarr(p: Path) -> bool:
    return p.suffix.lower() == ".zarr" or any((p / n).exists() for n in ("zarr.json", ".zarray", ".zgroup"))


class LazyFile:
    """A 3-D ``[k, j, i]`` C-order array in a file at byte ``offset``, read with plain file reads as it is
    indexed (whole k-planes, then the j, i part): ``augment`` streams it slab by slab and needs no address
    space for the whole file, as a memory map would.

    >>> import tempfile, pathlib
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "v.raw"
    >>> a = np.arange(60, dtype=">u2").reshape(3, 4, 5); p.write_bytes(b"xx" + a.tobytes())
    122
    >>> lf = LazyFile(p, 2, a.dtype, a.shape)
    >>> bool(np.array_equal(lf[1:3], a[1:3]) and np.array_equal(lf[::2, 1::2, ::3], a[::2, 1::2, ::3]))
    True
    """

    def __init__(self, path, offset: int, dtype, shape):
        self.path, self.offset = Path(path), int(offset)
        self.dtype, self.shape, self.ndim = np.dtype(dtype), tuple(int(n) for n in shape), 3
        self.plane = self.shape[1] * self.shape[2]

    def _planes(self, k0: int, k1: int) -> np.ndarray:
        n = max(0, k1 - k0) * self.plane
        with open(self.path, "rb") as fh:
            fh.seek(self.offset + k0 * self.plane * self.dtype.itemsize)
            out = np.fromfile(fh, dtype=self.dtype, count=n)
        if out.shape[0] != n:
            raise IsplatError(f"{self.path}: file ended inside plane k={k0 + out.shape[0] // self.plane}; truncated?")
        return out.reshape(max(0, k1 - k0), self.shape[1], self.shape[2])

    def __getitem__(self, key):
        key = key if isinstance(key, tuple) else (key,)
        key = key + (slice(None),) * (3 - len(key))
        kk, rest = key[0], key[1:]
        if isinstance(kk, (int, np.integer)):
            k = range(self.shape[0])[kk]
            return self._planes(k, k + 1)[0][rest]
        ks = range(self.shape[0])[kk]
        if ks.step == 1 or len(ks) <= 1:
            k0 = ks.start if len(ks) else 0
            return self._planes(k0, k0 + len(ks))[(slice(None),) + rest]
        return np.stack([self._planes(k, k + 1)[0][rest] for k in ks])

    def __array__(self, dtype=None, copy=None):
        return np.asarray(self[:, :, :], dtype=dtype)


class LazyZarr:
    """A 3-D ``[k, j, i]`` view of a Zarr array whose other axes (OME-Zarr t, c) have size 1.

    Indexing reads only the chunks it touches, so ``augment`` streams the store slab by slab.
    """

    def __init__(self, array, spatial: tuple[int, int, int]):
        self.array, self.spatial = array, spatial
        self.shape = tuple(int(array.shape[a]) for a in spatial)
        self.dtype = np.dtype(array.dtype)
        self.ndim = 3

    def __getitem__(self, key):
        key = key if isinstance(key, tuple) else (key,)
        key = key + (slice(None),) * (3 - len(key))
        full = [0] * len(self.array.shape)
        for a, k in zip(self.spatial, key):
            full[a] = k
        return np.asarray(self.array[tuple(full)])

    def __array__(self, dtype=None, copy=None):
        return np.asarray(self[:, :, :], dtype=dtype)


def _read_zarr(p, level):
    zarr = _need("zarr", "zarr", "zarr", "Zarr / OME-Zarr", p)
    try:
        node = zarr.open(str(p), mode="r")
    except Exception as exc:
        raise IsplatError(f"{p}: not a readable Zarr store ({_short(exc)})") from None
    if hasattr(node, "shape"):  # a plain array
        if level not in (None, 0):
            raise IsplatError(f"{p}: --level {level}: a plain Zarr array has one level (0)")
        if len(node.shape) != 3:
            raise IsplatError(f"{p}: Zarr array has shape {tuple(node.shape)}; expected a 3-D volume [z, y, x]")
        return Volume(LazyZarr(node, (0, 1, 2)), (1.0, 1.0, 1.0),
                      {"format": "zarr", "source_dtype": np.dtype(node.dtype).name,
                       "spacing_source": "default 1,1,1 (a plain Zarr array has no spacing)"})
    return _read_ome_zarr(p, node, level)


def _ome_multiscale(p, group):
    attrs = dict(group.attrs)
    ms = attrs.get("multiscales") or attrs.get("ome", {}).get("multiscales")
    if not ms:
        raise IsplatError(f"{p}: Zarr group without OME-Zarr 'multiscales' metadata; give the array inside "
                          f"it instead (e.g. {p}/0)")
    return ms[0]


def _read_ome_zarr(p, group, level):
    ms = _ome_multiscale(p, group)
    datasets = ms.get("datasets", [])
    level = 0 if level is None else int(level)
    if not 0 <= level < len(datasets):
        raise IsplatError(f"{p}: --level {level} invalid; this OME-Zarr has levels 0..{len(datasets) - 1}")
    ds = datasets[level]
    arr = group[ds["path"]]
    axes = ms.get("axes") or [{"name": n} for n in "tczyx"[-len(arr.shape):]]
    names = [a["name"] if isinstance(a, dict) else str(a) for a in axes]
    spatial = tuple(n for n, a in enumerate(axes) if (a.get("type") if isinstance(a, dict) else None) == "space"
                    or names[n] in ("z", "y", "x"))
    if len(spatial) != 3 or len(names) != len(arr.shape):
        raise IsplatError(f"{p}: OME-Zarr axes {names} do not give three spatial axes for shape {tuple(arr.shape)}")
    for n, size in enumerate(arr.shape):
        if n not in spatial and size != 1:
            raise IsplatError(f"{p}: OME-Zarr axis {names[n]!r} has {size} entries; isplat reads one scalar "
                              "volume (t and c of size 1)")
    scale = [1.0] * len(arr.shape)
    for tr in ds.get("coordinateTransformations", []):
        if tr.get("type") == "scale":
            scale = [float(x) for x in tr["scale"]]
    sp = tuple(scale[a] for a in reversed(spatial))  # i = x (last spatial axis)
    return Volume(LazyZarr(arr, spatial), sp, {
        "format": "zarr", "source_dtype": np.dtype(arr.dtype).name, "zarr_level": level,
        "spacing_source": f"OME-Zarr level {level} scale"})
