"""Augment a scalar volume into the paper's 4-byte voxels (§2.1, §4): density, gradient magnitude, normal.

* density ``d = clip(rint((x - LO) * (255 / (HI - LO))), 0, 255)`` (float64 arithmetic, ties to even), with the
  window ``LO, HI`` given or robust (0.1 and 99.9 percentiles of a strided subsample, see :func:`robust_window`).
* gradient: central differences in physical units (one-sided at the borders, ``numpy.gradient`` with
  ``edge_order=1``) of the *windowed* density before rounding, ``t = clip((x - LO) * 255 / (HI - LO), 0, 255)`` in
  float32. Classification and shading live in density space, and out-of-window values (metal, air outside a
  CT's field of view) would otherwise dominate the magnitude scale and leave 8 bits for nothing else.
* gradient magnitude code ``rint(min(|g| / gmax, 1) * 255)``, ``gmax`` the largest ``|g|`` in the volume (first
  pass), attribute ``gradient_magnitude_scale = gmax / 255`` (0 for a flat volume).
* normal: the gradient direction (towards increasing density) as an oct16 code (:mod:`isplat.normals`);
  a zero gradient gives ``NO_NORMAL``. On thick slices (the largest spacing more than ``NORMAL_RATIO`` times the
  smallest) the normal's gradient is taken of the windowed density smoothed along the thinner axes first
  (:func:`normal_sigmas`, a Gaussian of ``NORMAL_SMOOTHING * sqrt(s_max^2 - s_a^2)`` mm along axis ``a``), so that
  it has about the same resolution along every axis; the gradient magnitude stays that of the plain differences.
  Without it the in-slice part of the normal is differenced over one in-plane voxel and the part along the slices
  over two thick slices, and the normal's direction swings from slice to slice: terraces on shaded surfaces
  (docs/thick-slices.md).

The volume is processed in slabs of k-slices with a one-slice halo, so memory stays bounded whatever its size.
"""

from __future__ import annotations

import hashlib
import logging
import math

import numba
import numpy as np

from . import progress
from .augfile import (FORMAT_VERSION, ROWS_VERSION, ChannelWriter, create_augmented, finish_augmented, label_counts,
                      write_labels)
from .errors import IsplatError
from .fileio import atomic_output, check_output, create_hdf5
from .jit import jit, stage
from .normals import NO_NORMAL, _encode_one
from .volume_io import Volume, read_volume

log = logging.getLogger(__name__)

SLAB_VOXELS = 1 << 22      # voxels per slab (about 4 M: ~100 MB of temporaries)
NORMAL_RATIO = 4.0         # normal_sigmas: slices more than this many times thicker than the smallest spacing
NORMAL_SMOOTHING = 0.5     # normal_sigmas: sigma = this * sqrt(s_max^2 - s_a^2) (docs/thick-slices.md measures both)
SUBSAMPLE_PER_AXIS = 64    # robust window: at most 64 samples per axis
WINDOW_PERCENTILES = (0.1, 99.9)


# --- kernels ---------------------------------------------------------------------------------------------------

@jit(parallel=True)
def _window_kernel(x, lo, scale, t_out, d_out):
    """Windowed density of a float64 slab: ``t_out`` float32 clipped to 0..255, ``d_out`` its rint as uint8.

    Returns the flat index of the first non-finite value, or -1.
    """
    nk, nj, ni = x.shape
    bad = np.full(nk, -1, dtype=np.int64)
    for k in numba.prange(nk):
        for j in range(nj):
            for i in range(ni):
                v = x[k, j, i]
                if not np.isfinite(v):
                    if bad[k] < 0:
                        bad[k] = (k * nj + j) * ni + i
                    v = lo
                t = (v - lo) * scale
                t = min(max(t, 0.0), 255.0)
                t_out[k, j, i] = np.float32(t)
                d_out[k, j, i] = np.uint8(np.rint(t))
    for k in range(nk):
        if bad[k] >= 0:
            return bad[k]
    return -1


@jit(parallel=True)
def _gradient_kernel(f, r0, nrows, kg0, nk, si, sj, sk, g):
    """Gradient of rows ``r0 : r0 + nrows`` of slab ``f`` (float32, with halo rows) into ``g[3, nrows, nj, ni]``.

    ``kg0`` is the global k of row ``r0``; ``numpy.gradient`` semantics, edge_order=1 (one-sided at the
    volume's borders, zero along an axis of length 1). Components in i, j, k order, per physical unit.
    """
    _, nj, ni = f.shape
    ci, cj, ck = np.float32(2.0 * si), np.float32(2.0 * sj), np.float32(2.0 * sk)
    oi, oj, ok = np.float32(si), np.float32(sj), np.float32(sk)
    for rr in numba.prange(nrows):
        r = r0 + rr
        kg = kg0 + rr
        for j in range(nj):
            for i in range(ni):
                if ni == 1:
                    gi = np.float32(0.0)
                elif i == 0:
                    gi = (f[r, j, 1] - f[r, j, 0]) / oi
                elif i == ni - 1:
                    gi = (f[r, j, i] - f[r, j, i - 1]) / oi
                else:
                    gi = (f[r, j, i + 1] - f[r, j, i - 1]) / ci
                if nj == 1:
                    gj = np.float32(0.0)
                elif j == 0:
                    gj = (f[r, 1, i] - f[r, 0, i]) / oj
                elif j == nj - 1:
                    gj = (f[r, j, i] - f[r, j - 1, i]) / oj
                else:
                    gj = (f[r, j + 1, i] - f[r, j - 1, i]) / cj
                if nk == 1:
                    gk = np.float32(0.0)
                elif kg == 0:
                    gk = (f[r + 1, j, i] - f[r, j, i]) / ok
                elif kg == nk - 1:
                    gk = (f[r, j, i] - f[r - 1, j, i]) / ok
                else:
                    gk = (f[r + 1, j, i] - f[r - 1, j, i]) / ck
                g[0, rr, j, i] = gi
                g[1, rr, j, i] = gj
                g[2, rr, j, i] = gk


@stage
def _magnitude(g, r, j, i):
    """|g| at (r, j, i) of a gradient slab ``g[3, ...]``, in float64."""
    a = np.float64(g[0, r, j, i])
    b = np.float64(g[1, r, j, i])
    c = np.float64(g[2, r, j, i])
    return math.sqrt(a * a + b * b + c * c)


@jit(parallel=True)
def _magnitude_max(g):
    n = g.shape[1]
    m = np.zeros(n, dtype=np.float64)
    for r in numba.prange(n):
        best = 0.0
        for j in range(g.shape[2]):
            for i in range(g.shape[3]):
                s = _magnitude(g, r, j, i)
                if s > best:
                    best = s
        m[r] = best
    return m.max() if n else 0.0


@jit(parallel=True)
def _encode_kernel(g, gn, gmax, mag_out, nrm_out):
    """Magnitude codes ``rint(min(|g|/gmax, 1) * 255)`` of gradients ``g[3, ...]`` and oct16 normal codes of
    gradients ``gn`` (``g`` itself, or the smoothed gradient of thick slices)."""
    n = g.shape[1]
    for r in numba.prange(n):
        for j in range(g.shape[2]):
            for i in range(g.shape[3]):
                s = _magnitude(g, r, j, i)
                if gmax > 0.0 and s > 0.0:
                    mag_out[r, j, i] = np.uint8(np.rint(min(s / gmax, 1.0) * 255.0))
                else:
                    mag_out[r, j, i] = 0
                if gmax > 0.0 and _magnitude(gn, r, j, i) > 0.0:
                    nrm_out[r, j, i] = _encode_one(np.float64(gn[0, r, j, i]), np.float64(gn[1, r, j, i]),
                                                   np.float64(gn[2, r, j, i]))
                else:
                    nrm_out[r, j, i] = NO_NORMAL


# --- window ----------------------------------------------------------------------------------------------------

def _slab_float64(arr, k0, k1):
    """Slab ``arr[k0:k1]`` as a native float64 array (copies one slab only)."""
    return np.asarray(arr[k0:k1], dtype=np.float64)


def _slab_step(arr) -> int:
    return max(1, SLAB_VOXELS // max(1, arr.shape[1] * arr.shape[2]))


def _raise_nonfinite(name, arr, k0, flat):
    """Raise the error for the non-finite value at flat index ``flat`` of the slab starting at ``k0``."""
    nj, ni = arr.shape[1], arr.shape[2]
    kk, rem = divmod(int(flat), nj * ni)
    j, i = divmod(rem, ni)
    v = arr[k0 + kk, j, i]
    raise IsplatError(f"{name}: value {v} at voxel (i={i}, j={j}, k={k0 + kk}); expected finite numbers "
                      "(no NaN or Inf)")


def robust_window(arr, name="input", sub=None) -> tuple[float, float]:
    """Default window: the 0.1 and 99.9 percentiles (numpy 'linear') of ``arr[::sk, ::sj, ::si]``.

    ``s = ceil(n / 64)`` per axis (at most 64^3 samples, deterministic). If they are equal, the subsample's
    min and max; if still equal, the whole volume's min and max; a constant volume has no window. ``sub`` is
    that subsample when the caller already has it.
    """
    sub = _subsample(arr, name) if sub is None else sub
    lo, hi = (float(x) for x in np.percentile(sub, WINDOW_PERCENTILES))
    if lo == hi:
        lo, hi = float(sub.min()), float(sub.max())
    if lo == hi:
        lo, hi = math.inf, -math.inf
        step = _slab_step(arr)
        for k0 in range(0, arr.shape[0], step):
            s = _slab_float64(arr, k0, k0 + step)
            if not np.all(np.isfinite(s)):
                _raise_nonfinite(name, arr, k0, np.flatnonzero(~np.isfinite(s))[0])
            lo, hi = min(lo, float(s.min())), max(hi, float(s.max()))
    if lo == hi:
        raise IsplatError(f"{name}: constant volume (every voxel is {lo:g}); no density window can be derived; "
                          "give one with --window LO,HI")
    return lo, hi


# Named windows (LO, HI) in Hounsfield units. ct-full is the 12-bit range CT scanners store (-1024..3071); the others
# are the common radiology display windows written as width/level: W2000/L300 bone, W400/L40 soft tissue,
# W1500/L-600 lung, W80/L40 brain (formats/augmented.md §4).
NAMED_WINDOWS = {
    "ct-full": (-1024.0, 3071.0),
    "ct-bone": (-700.0, 1300.0),
    "ct-soft-tissue": (-160.0, 240.0),
    "ct-lung": (-1350.0, 150.0),
    "ct-brain": (0.0, 80.0),
}
HOUNSFIELD_PADDING = (-1024.0, -2048.0, -3024.0)   # values scanners write outside the field of view
HOUNSFIELD_DEFAULT = "ct-full"                     # keeps bone (< ~2000 HU) below metal (> 3000 HU)


def _subsample(arr, name):
    steps = [max(1, -(-n // SUBSAMPLE_PER_AXIS)) for n in arr.shape]
    sub = np.asarray(arr[::steps[0], ::steps[1], ::steps[2]], dtype=np.float64)
    bad = np.flatnonzero(~np.isfinite(sub))
    if bad.size:
        kk, jj, ii = np.unravel_index(bad[0], sub.shape)
        raise IsplatError(f"{name}: value {sub[kk, jj, ii]} at voxel (i={ii * steps[2]}, j={jj * steps[1]}, "
                          f"k={kk * steps[0]}); expected finite numbers (no NaN or Inf)")
    return sub


def looks_hounsfield(sub, meta) -> str | None:
    """Why the data are taken as Hounsfield units (the file says so, or air / padding at -1024 or -2048), or None."""
    if meta.get("hounsfield"):
        return f"{meta.get('format', 'file')} rescale"
    lo, hi = float(sub.min()), float(sub.max())
    if hi > 0 and (lo in HOUNSFIELD_PADDING or -1100.0 <= lo <= -950.0):
        return f"values start at {lo:g}"
    return None


def parse_window(text: str, name="input"):
    """``--window`` text: a name of :data:`NAMED_WINDOWS`, or ``LO,HI`` where each end is a number or ``pX``
    (the X-th percentile). Returns ``(lo, hi)`` with floats or ``("p", X)`` ends, or a window name."""
    t = str(text).strip()
    if t in NAMED_WINDOWS:
        return t
    parts = [x.strip() for x in t.split(",")]
    expected = (f"expected LO,HI (numbers or percentiles such as p0.5,p99.9) or a name: "
                f"{', '.join(NAMED_WINDOWS)}")
    if len(parts) != 2:
        raise IsplatError(f"{name}: --window {t!r} invalid; {expected}")
    ends = []
    for x in parts:
        try:
            ends.append(("p", float(x[1:])) if x[:1].lower() == "p" else float(x))
        except ValueError:
            raise IsplatError(f"{name}: --window {t!r} invalid; {expected}") from None
        if isinstance(ends[-1], tuple) and not 0.0 <= ends[-1][1] <= 100.0:
            raise IsplatError(f"{name}: --window {t!r}: percentile {x} outside p0..p100")
    return tuple(ends)


def resolve_window(window, arr, meta=None, name="input") -> tuple[tuple[float, float], str]:
    """The density window for ``arr`` and how it was chosen.

    ``window`` is None (default: ``ct-full`` for Hounsfield data, else :func:`robust_window`), a name, a
    ``--window`` string, or a pair whose ends are numbers or ``("p", X)`` percentiles of the subsample.
    """
    if isinstance(window, str):
        window = parse_window(window, name)
    if isinstance(window, str):
        lo, hi = NAMED_WINDOWS[window]
        return (lo, hi), f"named {window}"
    if window is None:
        sub = _subsample(arr, name)   # read once: a lazy (Zarr) input touches every chunk for it
        why = looks_hounsfield(sub, meta or {})
        if why:
            return NAMED_WINDOWS[HOUNSFIELD_DEFAULT], f"Hounsfield data ({why}): {HOUNSFIELD_DEFAULT}"
        return robust_window(arr, name, sub), "robust 0.1/99.9 percentiles"
    ends = list(window)
    if any(isinstance(e, tuple) for e in ends) and len(ends) == 2:
        sub = _subsample(arr, name)
        ends = [float(np.percentile(sub, e[1])) if isinstance(e, tuple) else e for e in ends]
        text = "/".join(f"p{e[1]:g}" if isinstance(e, tuple) else f"{e:g}" for e in window)
        return check_window(ends, name, f"{text} -> "), f"percentiles {text}"
    return check_window(ends, name), "given"


def check_window(window, name="input", prefix="") -> tuple[float, float]:
    try:
        lo, hi = (float(x) for x in window)
    except (TypeError, ValueError):
        raise IsplatError(f"{name}: --window {window!r} invalid; expected LO,HI") from None
    if not (np.isfinite(lo) and np.isfinite(hi) and hi > lo):
        raise IsplatError(f"{name}: --window {prefix}{lo:g},{hi:g} invalid; expected finite LO < HI")
    problem = window_problem(lo, hi)
    if problem:
        raise IsplatError(f"{name}: --window {prefix}{lo:g},{hi:g}: {problem}")
    return lo, hi


def window_problem(lo: float, hi: float) -> str | None:
    """Why a window makes a degenerate density channel (None when it does not): a width that overflows (every
    density 0) or too narrow for float64 to tell its 256 levels apart at that magnitude."""
    width = hi - lo
    if not np.isfinite(width) or not np.isfinite(255.0 / width) or 255.0 / width == 0.0:
        return (f"the width HI - LO = {width:g} overflows (every density would be 0); expected a window narrower "
                f"than 1e300")
    if width / 255.0 <= 2.0 ** -40 * max(abs(lo), abs(hi)):
        return (f"the width {width:g} is below what float64 resolves at {max(abs(lo), abs(hi)):g} (the 256 "
                f"densities would merge); expected a wider window")
    return None


# --- the two passes --------------------------------------------------------------------------------------------

def normal_sigmas(spacing_ijk, ratio: float | None = None, factor: float | None = None):
    """Gaussian sigmas (mm, along i, j, k) the windowed density is smoothed with before the normals' differences:
    ``factor * sqrt(s_max^2 - s_a^2)`` along axis ``a`` when the largest spacing exceeds ``ratio`` times the
    smallest (thick slices; ``ratio`` and ``factor`` default to ``NORMAL_RATIO`` and ``NORMAL_SMOOTHING``), else None
    (no smoothing: the normals are the plain central differences').

    Central differences span two voxels along each axis, so on slices 7 times thicker than the pixels the
    normal's part along the slices is resolved over 14 mm and its in-slice part over 2 mm: where a surface
    crosses a slice its in-slice gradient is large, half-way between slices (where the voxels of the two
    slices lie off the surface) small, and the shaded surface changes slice by slice (terraces). Smoothing the
    thinner axes to about the thick axis' resolution (the Gaussians add variance ``s_max^2 - s_a^2``, scaled)
    makes the estimate's resolution about the same along every axis. Not below ``NORMAL_RATIO``: at 2.5 mm slices
    of 0.7 mm pixels (3.6:1) the samples showed no terraces to remove, and the smoothed normals of noisy tissue,
    whose in-slice noise the smoothing takes away but not the noise between slices, pointed along the slices
    (speckle on a semi-transparent soft-tissue render; docs/thick-slices.md).

    >>> normal_sigmas((1.0, 1.0, 1.0)) is None
    True
    >>> [round(s, 3) for s in normal_sigmas((1.0, 1.0, 7.0))]
    [3.464, 3.464, 0.0]
    """
    ratio = NORMAL_RATIO if ratio is None else ratio
    factor = NORMAL_SMOOTHING if factor is None else factor
    sp = [float(s) for s in spacing_ijk]
    if not factor > 0.0 or not max(sp) > ratio * min(sp):
        return None
    top = max(sp)
    return tuple(factor * math.sqrt(max(0.0, top * top - s * s)) for s in sp)


def _gauss_weights(sigma_voxels: float) -> np.ndarray:
    r = max(1, int(math.ceil(3.0 * sigma_voxels)))
    x = np.arange(-r, r + 1, dtype=np.float64)
    w = np.exp(-0.5 * (x / sigma_voxels) ** 2)
    return (w / w.sum()).astype(np.float32)


def _smooth_axis(t: np.ndarray, sigma_voxels: float, axis: int) -> np.ndarray:
    """``t`` convolved along ``axis`` with a normalised Gaussian (3 sigma), continued past its ends by odd
    reflection (``2 t[0] - t[m]``), which keeps a linear field linear up to the volume's borders."""
    if not sigma_voxels > 0.05:
        return t
    w = _gauss_weights(sigma_voxels)
    r = len(w) // 2
    pad = [(0, 0)] * t.ndim
    pad[axis] = (r, r)
    p = np.pad(t, pad, mode="reflect", reflect_type="odd") if t.shape[axis] > 1 else np.pad(t, pad, mode="edge")
    out = np.zeros_like(t)
    n = t.shape[axis]
    for m, wm in enumerate(w):
        out += wm * np.take(p, np.arange(m, m + n), axis=axis)
    return out


class _Slabber:
    """Window and gradient of k-slabs of ``arr`` with a one-slice halo (more when the normals of thick slices
    smooth along k: :func:`normal_sigmas`)."""

    def __init__(self, arr, spacing_ijk, window, name, smooth_normals=True):
        self.arr, self.name = arr, name
        self.nk, self.nj, self.ni = arr.shape
        self.si, self.sj, self.sk = (float(s) for s in spacing_ijk)
        sig = normal_sigmas((self.si, self.sj, self.sk)) if smooth_normals else None
        # sigmas in voxels along k, j, i (the slab's axes), and the halo the smoothing along k needs
        self.normal_sigma = None if sig is None else (sig[2] / self.sk, sig[1] / self.sj, sig[0] / self.si)
        self.halo = 1 + (0 if sig is None or not sig[2] / self.sk > 0.05
                         else int(math.ceil(3.0 * sig[2] / self.sk)))
        self.lo, self.hi = window
        self.scale = 255.0 / (self.hi - self.lo)
        self.step = _slab_step(arr)
        self.ranges = [(k0, min(self.nk, k0 + self.step)) for k0 in range(0, self.nk, self.step)]

    def slab(self, k0, k1, normals=False):
        """Return ``(density[k0:k1] uint8, gradient float32[3, k1-k0, nj, ni])``, and with ``normals`` the
        gradient the normals are made of (the same array, or that of the smoothed density on thick slices)."""
        e0, e1 = max(0, k0 - self.halo), min(self.nk, k1 + self.halo)
        x = _slab_float64(self.arr, e0, e1)
        t = np.empty(x.shape, dtype=np.float32)
        d = np.empty(x.shape, dtype=np.uint8)
        bad = _window_kernel(x, self.lo, self.scale, t, d)
        if bad >= 0:
            _raise_nonfinite(self.name, self.arr, e0, bad)
        g = np.empty((3, k1 - k0, self.nj, self.ni), dtype=np.float32)
        _gradient_kernel(t, k0 - e0, k1 - k0, k0, self.nk, self.si, self.sj, self.sk, g)
        self.last_clipped = _count_clipped(x[k0 - e0:k1 - e0], self.lo, self.hi)
        if not normals:
            return d[k0 - e0:k1 - e0], g
        gn = g
        if self.normal_sigma is not None:
            ts = t
            for axis, sv in enumerate(self.normal_sigma):
                ts = _smooth_axis(ts, sv, axis)     # the halo's rows are real data; past the volume, reflected
            gn = np.empty_like(g)
            _gradient_kernel(np.ascontiguousarray(ts), k0 - e0, k1 - k0, k0, self.nk, self.si, self.sj, self.sk, gn)
        return d[k0 - e0:k1 - e0], g, gn


@jit
def _count_clipped(x, lo, hi):
    below = above = 0
    for v in x.ravel():
        if v < lo:
            below += 1
        elif v > hi:
            above += 1
    return below, above


def _first_pass(sl: _Slabber, bar):
    """Max gradient magnitude and the density hash (augfile.density_sha256 semantics, slab by slab); counts the
    voxels below and above the window into ``sl.clipped``."""
    h = hashlib.sha256(np.asarray(sl.arr.shape, dtype="<i8").tobytes())
    gmax = 0.0
    sl.clipped = [0, 0]
    for k0, k1 in sl.ranges:
        d, g = sl.slab(k0, k1)
        h.update(np.ascontiguousarray(d).tobytes())
        gmax = max(gmax, float(_magnitude_max(g)))
        sl.clipped = [a + b for a, b in zip(sl.clipped, sl.last_clipped)]
        bar.update(1)
    return gmax, h.hexdigest()


def _second_pass(sl: _Slabber, gmax, bar):
    """Yield ``(k0, k1, density, magnitude_code, normal_code)`` per slab."""
    for k0, k1 in sl.ranges:
        d, g, gn = sl.slab(k0, k1, normals=True)
        mag = np.empty(g.shape[1:], dtype=np.uint8)
        nrm = np.empty(g.shape[1:], dtype=np.uint16)
        _encode_kernel(g, gn, gmax, mag, nrm)
        bar.update(1)
        yield k0, k1, d, mag, nrm


def _prepare(vol: Volume, window, name, method=None, smooth_normals=True):
    """The slabber of ``vol`` with its window: ``window`` resolved here, or already resolved (numbers) when
    ``method`` says how it was chosen."""
    arr = vol.array
    if arr.ndim != 3:
        raise IsplatError(f"{name}: data has shape {arr.shape}; expected a 3-D volume [k, j, i]")
    if arr.dtype.kind not in "uif":
        raise IsplatError(f"{name}: data type {arr.dtype} is not supported; expected integers or floats")
    win, method = resolve_window(window, arr, vol.meta, name) if method is None else (tuple(window), method)
    sl = _Slabber(arr, vol.spacing_ijk, win, name, smooth_normals)
    sl.method = method
    return sl


def _clipped_shares(sl: _Slabber) -> tuple[float, float]:
    n = max(1, sl.nk * sl.nj * sl.ni)
    return sl.clipped[0] / n, sl.clipped[1] / n


def augment_array(array, spacing_ijk=(1.0, 1.0, 1.0), window=None, smooth_normals=True) -> dict:
    """Augment an in-memory volume ``[k, j, i]``; return the three channels and the attributes as a dict.

    ``smooth_normals=False`` keeps the plain central differences' normals on thick slices too (the normals before
    :func:`normal_sigmas`; for comparisons)."""
    arr = np.asarray(array)
    sl = _prepare(Volume(arr, tuple(float(s) for s in spacing_ijk), {}), window, "array",
                  smooth_normals=smooth_normals)
    with progress.bar(total=2 * len(sl.ranges), desc="augment", unit="slab") as bar:
        gmax, sha = _first_pass(sl, bar)
        out = {"density": np.empty(arr.shape, np.uint8), "gradient_magnitude": np.empty(arr.shape, np.uint8),
               "normal": np.empty(arr.shape, np.uint16)}
        for k0, k1, d, mag, nrm in _second_pass(sl, gmax, bar):
            out["density"][k0:k1] = d
            out["gradient_magnitude"][k0:k1] = mag
            out["normal"][k0:k1] = nrm
    out.update(spacing_ijk=(sl.si, sl.sj, sl.sk), density_window=(sl.lo, sl.hi),
               gradient_magnitude_scale=gmax / 255.0, density_sha256=sha, density_window_method=sl.method,
               clipped=_clipped_shares(sl))
    return out


def augment_file(inp, out, force=False, window=None, spacing=None, shape=None, dtype=None,
                 byte_order="little", header_bytes=0, level=None, series=None, thin_slices=None,
                 orientation=None, labels=None, bricks=True) -> dict:
    """Augment the volume at ``inp`` (see :func:`isplat.volume_io.read_volume`) into ``out`` atomically.

    ``thin_slices``: a ratio (e.g. :data:`isplat.resample.THICK_RATIO`): axes whose spacing exceeds it times
    the smallest are first refined by linear interpolation (:func:`isplat.resample.thin_slices`; the volume
    is then held in memory); the window is chosen on the scan as read, so it is the one the scan gets without
    them. ``orientation``: a code such as ``LPS`` (:mod:`isplat.orientation`) giving the patient directions
    of i, j, k, over the file's. ``labels``: a label map on the scan's grid (:func:`isplat.labels.read_label_volume`),
    stored as the label channel (formats/augmented.md §2.1). ``bricks``: write format 6 (the channels in 8^3
    bricks of isplat's own store, which the post technique reads only where its scene needs them), else format 4
    (chunks of whole rows, read whole; docs/selective-read.md). Returns a
    summary dict (shape, window, gradient scale, sha256, ``axes_lps`` or None, ``hounsfield`` (why the data are
    taken as Hounsfield units, or None), and where spacing and
    orientation came from).
    """
    check_output(out, force)  # fail before any work
    axes = None
    if orientation is not None:
        from .orientation import axes_from_code

        axes = axes_from_code(orientation, "--orientation")   # before reading: a bad code costs nothing
    vol = read_volume(inp, shape=shape, dtype=dtype, byte_order=byte_order, header_bytes=header_bytes,
                      spacing=spacing, level=level, series=series, stream=True)
    name = str(inp)
    if axes is not None:
        vol.meta.update(axes_lps=axes, orientation_source="--orientation")
    win, method = resolve_window(window, vol.array, vol.meta, name)
    hounsfield = hounsfield_reason(window, method, vol.array, vol.meta, name)
    lab = _labels_for(labels, vol, thin_slices)
    if thin_slices:
        from .resample import thin_volume

        vol = thin_volume(vol, thin_slices, name)
    sl = _prepare(vol, win, name, method)
    extra = _file_attrs(vol, sl, name, hounsfield)
    log.debug(f"isplat augment: read {name} ({extra['source_format']}, {extra['source_dtype']}, NI,NJ,NK="
              f"{','.join(map(str, vol.array.shape[::-1]))}); window {sl.lo:g},{sl.hi:g} "
              f"({sl.method}); {len(sl.ranges)} slabs")
    with progress.bar(total=2 * len(sl.ranges), desc="augment", unit="slab") as bar:
        gmax, sha = _first_pass(sl, bar)
        extra["density_clipped_fraction"] = np.asarray(_clipped_shares(sl), dtype="<f8")
        with atomic_output(out, force) as tmp:
            with create_hdf5(tmp) as f:
                create_augmented(f, vol.array.shape, (sl.si, sl.sj, sl.sk), (sl.lo, sl.hi), gmax / 255.0,
                                 sha, extra, FORMAT_VERSION if bricks else ROWS_VERSION)
                w = ChannelWriter(f)
                for k0, k1, d, mag, nrm in _second_pass(sl, gmax, bar):
                    w.write("density", k0, k1, d)
                    w.write("gradient_magnitude", k0, k1, mag)
                    w.write("normal", k0, k1, nrm)
                if lab is not None:
                    write_labels(f, lab)
                finish_augmented(f)
    return {"shape_ijk": tuple(reversed(vol.array.shape)), "spacing_ijk": (sl.si, sl.sj, sl.sk),
            "density_window": (sl.lo, sl.hi), "gradient_magnitude_scale": gmax / 255.0, "density_sha256": sha,
            "density_window_method": sl.method, "clipped": _clipped_shares(sl), "hounsfield": hounsfield,
            "axes_lps": vol.meta.get("axes_lps"), "source_format": extra["source_format"],
            "spacing_source": vol.meta.get("spacing_source", "the file"),
            "orientation_source": vol.meta.get("orientation_source", f"the {extra['source_format']} header"),
            "thinned_from": vol.meta.get("thinned_from"),
            "labels": None if lab is None else label_counts(lab)}


def _labels_for(labels, vol: Volume, thin_slices):
    """The label map of ``--labels`` (None without), checked against the scan's grid before any work."""
    if labels is None:
        return None
    if thin_slices:
        raise IsplatError(f"{labels}: --labels with --thin-slices: label ids cannot be interpolated; augment "
                          f"without --thin-slices (the default, post-classified rendering does not need it)")
    from .labels import read_label_volume

    return read_label_volume(labels, vol)


def _file_attrs(vol: Volume, sl: _Slabber, name: str, hounsfield) -> dict:
    """The optional attributes of the augmented file (formats/augmented.md §3) but the clipped shares."""
    extra = {"source": name, "source_format": vol.meta.get("format", "unknown"),
             "source_dtype": str(vol.meta.get("source_dtype", vol.array.dtype.name)),
             "density_window_method": sl.method}
    if hounsfield:
        extra["density_units"] = "HU"
    if vol.meta.get("axes_lps") is not None:
        extra["axes_lps"] = np.asarray(vol.meta["axes_lps"], dtype="<f8")
    return extra


def hounsfield_reason(window, method: str, arr, meta, name="input") -> str | None:
    """Why the data are taken as Hounsfield units, whatever window was chosen, or None: the default window
    found them so, the reader says so, the values look so (:func:`looks_hounsfield`), or ``window`` is one of
    the named CT windows (which are in Hounsfield units). Unless the window or the reader already decided, this
    reads the strided subsample of :func:`resolve_window` (at most 64 values per axis)."""
    if method.startswith("Hounsfield data ("):
        return method.split(": ")[0][len("Hounsfield data ("):-1]
    if meta.get("hounsfield"):
        return f"{meta.get('format', 'file')} rescale"
    if window is None:
        return None                                   # the default window looked at the values already
    why = looks_hounsfield(_subsample(arr, name), meta)
    if why:
        return why
    if isinstance(window, str) and window.strip() in NAMED_WINDOWS:
        return f"--window {window.strip()} is in Hounsfield units"
    return None


# what lies beyond a Hounsfield window's ends: (upper bound in HU, tissue) in increasing order
HU_CLASSES = ((-950.0, "air"), (-200.0, "lung"), (-20.0, "fat"), (100.0, "soft tissue or fluid"),
              (400.0, "contrast or spongy bone"), (1900.0, "bone"), (3000.0, "teeth, dense bone or contrast"),
              (math.inf, "metal"))


def clipped_note(side: str, edge: float, hounsfield: bool) -> str:
    """What the voxels clipped below (``side="below"``) or above a window end ``edge`` probably are.

    >>> clipped_note("above", 2000, True), clipped_note("below", -160, True)
    ('teeth, dense bone or contrast, or metal?', 'fat, lung or air?')
    """
    if not hounsfield:
        if side == "above":
            return ("all map to density 255: small bright parts such as wires or metal? --window=LO,p100 keeps "
                    "them apart")
        return "all map to density 0"
    if side == "above":
        first = next(name for top, name in HU_CLASSES if top > edge)
        return "metal?" if first == "metal" else f"{first}, or metal?"
    lows = [name for (bottom, _), (_, name) in zip(((-math.inf, ""),) + HU_CLASSES, HU_CLASSES) if bottom < edge]
    if lows == ["air"]:
        return "air or padding outside the scan?"
    lows = lows[::-1]
    return (", ".join(lows[:-1]) + " or " + lows[-1] + "?") if len(lows) > 1 else f"{lows[0]}?"
